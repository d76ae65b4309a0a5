"""Global alignment of a stills survey: every frame's ground homography from all pairwise
registrations and the GPS positions at once (the reference's "bundle adjustment against drift").

Model. Frame i has a homography G_i from its normalised image coordinates x^ = K^-1 (u, v, 1)
(intrinsics K; a nominal focal length when unknown) to local ground metres (east, north) of a
flat ground plane. For a nadir camera at height h whose image x axis points at angle a
(counter-clockwise from east), G_i = [[h cos a, h sin a, e], [h sin a, -h cos a, n], [0, 0, 1]]
(the image's y axis points down, the map's north up: a reflection); a tilt adds the projective
terms g6, g7 and the linear part leaves that form.

Least squares over the eight free entries of every G_i (g22 = 1), with residuals in metres
divided by their standard deviations:
- pairs: for a registration i_H_j (frame j -> frame i) and points p of frame j inside the
  overlap, G_i(i_H_j p) - G_j(p), with sd = s0 sqrt(sd_H(p)^2 + sd_model^2): sd_H(p) from the
  registration's covariance propagated to the transferred point (sd_model absorbs what the
  planar model lacks: lens distortion, relief);
- positions: G_i(0, 0) (where the principal ray meets the ground) - the GPS position, sd from
  the receiver and the unknown tilt;
- ground control (core/survey's GroundControl, io/gcp.py): for target X (east, north, metres)
  seen at normalised point x of frame k, G_k(x) - X, with sd sqrt((s0 sd_pick)^2 + sd_survey^2)
  (sd_pick: the pick's pixels over the focal length; s0 the frames' scale);
- shape: (g0 + g4) and (g1 - g3) over s0 (a reflected similarity has both zero), and g6, g7
  (small tilts), and the scale sqrt|det| - s0 over s0: weak priors that keep a frame with few
  constraints from folding;
with Huber's loss on every residual, minimised by Levenberg-Marquardt on the reweighted sparse
normal equations (an analytic Jacobian; see survey_lsq.levenberg_marquardt for why not scipy's solvers). A wrong match that survived RANSAC leaves
a pair whose residuals stand far out from the rest: pairs whose RMS residual exceeds
``reject_sigma`` (and three times the median pair's) are dropped and the solve repeated.

Ground control without GPS: each connected part of the survey is first solved on its root frame's
plane (the root held), then a similarity fit to its control observations (the two-target
hypothesis that most targets agree with, refitted on them) takes it to the ground, and the solve is
repeated with the control and without the roots held: the control fixes position, turn and scale,
and bends out the drift that chained registrations accumulate. The control's residuals are least
squares, not Huber's (a robust loss gives up on the targets that a drifted survey misses by more
than a few sd: they would pull with a bounded force and the drift would stay). A wrong pick or a
wrong target is found instead by leaving each target out in turn (ground_anchor.left_out_outlier: where the
others put it, against its surveyed position) and dropped, the worst first, one per solve.
A part of the survey with fewer than two targets is not placed.

Initialisation: a spanning tree of the registration graph (most inliers first) chains each
connected component, which a similarity fit to its GPS positions places on the ground; frames
in no pair are placed by their position, the survey's median scale and their heading (their own
attitude's, else the track direction plus the camera's median offset from it, or the default
mount's when no frame shows it), and stay fixed (``placed_by`` 'pose').

The jobs live in modules of their own: the data and the homography parametrisation
(:mod:`.survey_model`), the registration graph (:mod:`.pair_graph`), the initial placement
(:mod:`.initial_placement`), the least-squares problem and its solve (:mod:`.survey_lsq`) and the
ground control's anchoring (:mod:`.ground_anchor`); this module runs them (:func:`solve_survey`) and
keeps their public names importable from here.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from .ground_anchor import control_similarity, left_out_outlier
from .initial_placement import angle_scale, initial_placement, similarity_G
from .pair_graph import check_pairs_against_positions, estimate_scale, pair_components, pair_constraint
from .survey_lsq import SurveyProblem, levenberg_marquardt
from .survey_model import (GroundControl, PairConstraint, SurveyPriors, SurveySolution, attitude_ground_H, control_residuals, h8,
                           h8_matrix)

__all__ = ['GroundControl', 'PairConstraint', 'SurveyPriors', 'SurveySolution', 'attitude_ground_H', 'check_pairs_against_positions',
           'control_residuals', 'estimate_scale', 'pair_constraint', 'solve_survey']


def solve_survey(n: int, pairs: list[PairConstraint], priors: SurveyPriors, *, min_extent_m: float = 10.0,
                 reject_sigma: float = 5.0, rounds: int = 4, huber_sigma: float = 2.0,
                 control: GroundControl | None = None, control_reject_sigma: float = 5.0,
                 control_loss: str = 'squares') -> SurveySolution:
    """Solve every frame's ground homography (module docstring).

    Args:
        n: number of frames; pairs: registered pairs (PairConstraint, normalised coordinates);
        priors: positions, their sd, the nominal scale and the flight direction;
        min_extent_m: a component's GPS positions must spread this far (RMS) to fit its own similarity;
        reject_sigma: a pair whose RMS residual exceeds this many sd (and 3x the median pair's) is dropped;
        rounds: solves at most (each after dropping pairs); huber_sigma: Huber's threshold, in sd;
        control: ground control observations (None: none); control_reject_sigma: a control pick or
            target that the others place this many sd away (and three times further than the median
            target) is dropped, the worst first (left_out_outlier); control_loss: 'squares' (the
            survey bends to the control: the drift between targets is solved out) or 'huber' (each
            observation's residual in Huber's loss, dropped beyond control_reject_sigma: robust, but
            the control can no longer bend a survey that has drifted by more than a few sd).
    """
    use = np.ones(len(pairs), dtype=bool)
    pos = np.asarray(priors.position_m, dtype=np.float64)
    georeferenced = bool(np.isfinite(pos).all(axis=1).any())
    gross = 0
    rejected_positions: list[int] = []
    if georeferenced and math.isfinite(priors.scale_m):
        # A wrong match between look-alike places: its baseline disagrees with the GPS baseline.
        # A wrong position (a receiver's glitch): most of its still's pairs disagree; then the
        # position goes, not the pairs.
        sd = np.asarray(priors.position_sigma_m, dtype=np.float64)
        ok = check_pairs_against_positions(pairs, pos, sd, priors.scale_m)
        fails, count = np.zeros(n), np.zeros(n)
        for p, good in zip(pairs, ok):
            for k in (p.i, p.j):
                count[k] += 1
                fails[k] += not good
        rejected_positions = [k for k in range(n) if fails[k] >= 2 and fails[k] > 0.5 * count[k]]
        if rejected_positions:
            pos = pos.copy()
            pos[rejected_positions] = np.nan
            priors = dataclasses.replace(priors, position_m=pos)
            ok = check_pairs_against_positions(pairs, pos, sd, priors.scale_m)
        use &= ok
        gross = int((~use).sum())
    by_control = control is not None and not georeferenced
    G, placed_by = initial_placement(n, pairs, use, priors, min_extent_m, every_component=by_control)
    free = [k for k in range(n) if placed_by[k] == 'registration']
    rms = np.full(len(pairs), np.nan)
    ctl_use = None if control is None else np.asarray(control.use, dtype=bool).copy()
    ctl_rejected: list[int] = []
    state: dict = {'iterations': 0, 'converged': False, 'dropped': 0, 'left_out': {}}

    def run(held: bool, with_control: bool, max_rounds: int) -> None:
        nonlocal free
        scale = float(np.median([angle_scale(G[k])[1] for k in free])) if free else priors.scale_m
        for _ in range(max(max_rounds, 1)):
            if not free:
                break
            # held: each component's first frame holds its gauge
            anchor = {c[0]: G[c[0]].copy() for c in pair_components(n, pairs, use) if c[0] in free} if held else {}
            prob = SurveyProblem(free, pairs, use, priors, scale, anchor, control if with_control else None, ctl_use)
            x0 = np.concatenate([h8(G[k]) for k in free])
            x, iterations, state['converged'] = levenberg_marquardt(
                prob, x0, huber_sigma, plain=prob.control_rows() if control_loss == 'squares' else None)
            state['iterations'] += iterations
            sol = x.reshape(-1, 8)
            for c, k in enumerate(free):
                G[k] = h8_matrix(sol[c])
            pr = prob.pair_rms(x)
            idx = [k for k, (p, u) in enumerate(zip(pairs, use)) if u and p.i in prob.col and p.j in prob.col]
            rms[:] = np.nan
            rms[idx] = pr
            med = float(np.median(pr)) if len(pr) else 0.0
            bad = [k for k, r in zip(idx, pr) if r > reject_sigma and r > 3.0 * med]
            if with_control and not georeferenced:
                # nothing but the registrations holds a part of the survey to the rest: a pair whose
                # loss would cut it off stays (the control bends it instead)
                parts = len(pair_components(n, pairs, use))
                bad = [k for k in bad if len(pair_components(n, pairs, use & (np.arange(len(use)) != k))) == parts]
            wrong: list[int] = []
            if with_control and control_loss == 'squares' and not bad:
                wrong = left_out_outlier(prob, x, huber_sigma, control, ctl_use, control_reject_sigma,
                                          state['left_out'])
            elif with_control and control_loss == 'huber':
                cs = prob.control_sigmas(x)
                worst = int(np.argmax(cs)) if len(cs) else -1
                if worst >= 0 and cs[worst] > control_reject_sigma and cs[worst] > 3.0 * float(np.median(cs)) \
                        and len({control.target[m] for m in prob.ctl_index}) > 2:
                    wrong = [int(prob.ctl_index[worst])]
            ctl_bad = bool(wrong)
            for m in wrong:  # one pick or one target per solve: the others may have been bent by it
                ctl_use[m] = False
                ctl_rejected.append(m)
            if not bad and not ctl_bad:
                break
            use[bad] = False
            state['dropped'] += len(bad)
            # a frame left in no pair keeps its place from the last solve, as placed by its pose
            in_pair = {p.i for p, u in zip(pairs, use) if u} | {p.j for p, u in zip(pairs, use) if u}
            for k in free:
                if k not in in_pair:
                    placed_by[k] = 'pose'
            free = [k for k in free if k in in_pair]

    if by_control:
        # each component on its root's plane, then to the ground by its own control; a component
        # with fewer than two targets cannot be placed with the others
        run(True, False, rounds)
        placed_any = False
        for comp in pair_components(n, pairs, use):
            members = [k for k in comp if placed_by[k]]
            if not members:
                continue
            in_comp = np.isin(control.frame, members)
            S = control_similarity(G, placed_by, control, ctl_use & in_comp)
            if S is None:
                for k in members:
                    G[k], placed_by[k] = np.nan, ''
                continue
            placed_any = True
            for k in members:
                G[k] = S @ G[k]
        by_control = placed_any
        free = [k for k in range(n) if placed_by[k] == 'registration']
        if by_control:
            run(False, True, rounds + int(ctl_use.sum()))
        else:  # no component holds two targets: back to the largest, on its own plane
            G, placed_by = initial_placement(n, pairs, use, priors, min_extent_m)
            free = [k for k in range(n) if placed_by[k] == 'registration']
            run(True, False, rounds)
    else:
        run(not georeferenced, control is not None, rounds + (int(ctl_use.sum()) if control is not None else 0))
    solved = [k for k in range(n) if placed_by[k] == 'registration']
    if solved:  # frames placed by their pose take the solved survey's scale
        s_med = float(np.median([angle_scale(G[k])[1] for k in solved]))
        for k in range(n):
            if placed_by[k] == 'pose':
                angle, s_k = angle_scale(G[k])
                G[k] = similarity_G(s_med, angle, float(G[k][0, 2]), float(G[k][1, 2]))
    gps_res = []
    for k in range(n):
        if placed_by[k] and np.isfinite(pos[k]).all():
            gps_res.append(float(np.hypot(G[k][0, 2] / G[k][2, 2] - pos[k, 0], G[k][1, 2] / G[k][2, 2] - pos[k, 1])))
    figures = {'pairs': len(pairs), 'pairs_used': int(use.sum()), 'pairs_against_gps': gross,
               'pairs_dropped': state['dropped'], 'positions_rejected': rejected_positions,
               'frames_by_registration': placed_by.count('registration'), 'frames_by_pose': placed_by.count('pose'),
               'frames_not_placed': placed_by.count(''),
               'median_pair_rms_sigma': float(np.nanmedian(rms)) if np.isfinite(rms).any() else None,
               'position_residual_rms_m': float(np.sqrt(np.mean(np.square(gps_res)))) if gps_res else None,
               'solver_iterations': state['iterations'], 'solver_converged': state['converged']}
    if control is not None:
        figures['control_placed_survey'] = by_control  # no GPS: the control alone put it on the ground
        # each control target's residual when the solve leaves it out (metres east, north; the last test)
        figures['control_left_out_m'] = {t: [round(float(v), 4) for v in r] for t, r in state['left_out'].items()}
        figures['control_rejected'] = ctl_rejected
    return SurveySolution(G, placed_by, rms, use, figures, ctl_use)
