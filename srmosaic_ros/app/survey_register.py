"""A survey's registrations and priors, ready for the global solve (`process FOLDER`, steps 2-3).

Consecutive stills first, which give the survey's scale (GPS baseline over registered displacement),
then every pair whose predicted footprints overlap (core/survey/pairs.py); features described once
and kept in a bounded cache.
"""
from __future__ import annotations

import collections
import logging
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from tqdm import tqdm

from ..config import PipelineConfig
from ..core.georef.geotag_fit import GEOTAG_MIN_EXTENT_M
from ..core.image_decode import ImageRefused
from ..core.registration import make_registrar
from ..core.survey.global_align import GroundControl, PairConstraint, SurveyPriors, attitude_ground_H, estimate_scale, pair_constraint, solve_survey
from ..core.survey.pairs import predicted_pairs
from ..errors import InputError
from ..io.image_folder import ImageFolderReader
from ..io.metadata import RECORDED_ATTITUDE_SIGMA_DEG
from ..malloc_tuning import trim_heap
from .survey_read import reduction_for, read_reduced, working_K, metadata_scale
from .survey_still import SurveyStill

__all__ = ['register_survey', 'RegisteredSurvey', 'SECOND_OPINION_BELOW_PAIRS']

_LOG = logging.getLogger(__package__ + '.survey')  # the survey's one log, whichever step writes it
#: A pair by footprint that the torch registrar fails gets the OpenCV registrar's second opinion
#: when one of its stills has fewer registered pairs than this.
SECOND_OPINION_BELOW_PAIRS = 3


class _FeatureCache:
    """Features of the working-resolution stills, the last ``size`` described kept (LRU)."""

    def __init__(self, registrar: Any, stills: list[SurveyStill], reduction: list[int], size: int,
                 max_features: int, reader: ImageFolderReader) -> None:
        self.registrar, self.stills, self.reduction, self.size = registrar, stills, reduction, size
        self.reader = reader
        self.max_features = max_features
        self.cache: collections.OrderedDict[int, Any] = collections.OrderedDict()
        self.described = 0
        self.unreadable: dict[int, str] = {}

    def get(self, k: int) -> Any:
        if k in self.unreadable:
            return None
        if k in self.cache:
            self.cache.move_to_end(k)
            return self.cache[k]
        try:
            image = read_reduced(self.stills[k].file, self.reduction[k], self.reader.decoder_warning)
        except InputError as exc:
            self.unreadable[k] = exc.why if isinstance(exc, ImageRefused) else str(exc)
            if isinstance(exc, ImageRefused):
                self.reader.refused(exc)
            return None
        feats = _compact(self.registrar.describe(image), self.max_features)
        self.described += 1
        self.cache[k] = feats
        while len(self.cache) > self.size:
            self.cache.popitem(last=False)
        return feats


def _compact(features: Any, max_features: int) -> Any:
    """Torch features described up to max_features at once, without the scale-space gradients kept
    for describing more later (the larger part of a described still's memory): a cached still
    costs its pyramid, templates and descriptors only."""
    import dataclasses

    primary = getattr(features, 'primary', features)
    if hasattr(primary, 'candidates') and hasattr(primary, 'extend'):
        primary.extend(max_features)
        c = primary.candidates
        # new empty tensors: a slice would keep the whole buffer alive
        primary.candidates = dataclasses.replace(c, xy=c.xy[:0].clone(), sub_level=c.sub_level[:0].clone(),
                                                 octave=c.octave[:0].clone(), response=c.response[:0].clone(),
                                                 tall=c.tall[:, :, :0].clone(), count=None)
    return features


@dataclass


class RegisteredSurvey:
    """A survey's registrations and what the metadata says, ready for the solve: pairs (normalised
    coordinates) and priors; registrations: every pair tried (i, j) -> Registration; reduction:
    each still's working JPEG reduction; more: the pairs by footprint tried; the rest for the report."""

    pairs: list[PairConstraint]
    priors: SurveyPriors
    registrations: dict[tuple[int, int], Any]
    reduction: list[int]
    more: list[tuple[int, int]]
    second_opinions: list[list[int | bool]]
    described: int
    unreadable: dict[int, str]
    scale: float
    scale_source: str
    focal_known: bool
    has_gps: bool
    georef_note: str
    register_s: float
    scale_is_guess: bool = False


def register_survey(stills: list[SurveyStill], config: PipelineConfig, *, progress: bool = True,
                    control: GroundControl | None = None, reader: ImageFolderReader | None = None) -> RegisteredSurvey:
    """Register a survey's pairs (consecutive stills, then those whose footprints overlap) and set its
    priors from the metadata (module docstring, steps 2-3). control: ground control; without GPS it
    places the chained stills (every stretch of them that sees two targets) to predict the pairs."""
    scfg = config.survey
    n = len(stills)
    reduction = [reduction_for(s.size[0], s.size[1], scfg.working_megapixels) for s in stills]
    registrar = make_registrar(config.registration, config.device)
    cache = _FeatureCache(registrar, stills, reduction, scfg.feature_cache_frames,
                          config.registration.max_features, reader)
    pos = np.array([s.position_m for s in stills])
    registrations: dict[tuple[int, int], Any] = {}
    has_second_opinion = getattr(registrar, 'has_second_opinion', False)

    def register(i: int, j: int, *, second_opinion: bool = True) -> PairConstraint | None:
        fi, fj = cache.get(i), cache.get(j)
        if fi is None or fj is None:
            return None
        if (i, j) in registrations:  # tried without a second opinion: only that is left to do
            reg = registrar.second_opinion(fi, fj, registrations[(i, j)])
        elif has_second_opinion:
            reg = registrar.register(fi, fj, second_opinion=second_opinion)
        else:
            reg = registrar.register(fi, fj)
        registrations[(i, j)] = reg
        if not reg.ok:
            return None
        wi, wj = (math.ceil(stills[i].size[0] / reduction[i]), math.ceil(stills[i].size[1] / reduction[i])), \
            (math.ceil(stills[j].size[0] / reduction[j]), math.ceil(stills[j].size[1] / reduction[j]))
        return pair_constraint(i, j, reg.prev_H_cur, reg.covariance, working_K(stills[i], reduction[i]),
                               working_K(stills[j], reduction[j]), wi, wj, inliers=reg.inliers,
                               model_px=scfg.model_px)

    sigma_gps = float(config.georef.gps_sigma_h_m)
    has_gps = bool(np.isfinite(pos).all(axis=1).sum() >= 3)
    georef_note = '' if has_gps else 'fewer than three stills carry a GPS position'
    if has_gps:
        known = pos[np.isfinite(pos).all(axis=1)]
        extent = float(np.sqrt(np.mean(np.sum((known - known.mean(axis=0)) ** 2, axis=1))))
        if extent < GEOTAG_MIN_EXTENT_M:
            # a hover or a pan: GNSS noise, not the flight, would set the mosaic's scale and rotation
            georef_note = (f'the stills\' GPS positions span {extent:.1f} m RMS, less than {GEOTAG_MIN_EXTENT_M:g} m: '
                           'their GNSS noise, not the flight, would set the mosaic\'s scale and rotation (a hover, '
                           'a pan)')
            has_gps = False
            pos = np.full_like(pos, np.nan)
    t_reg = time.perf_counter()
    found: dict[tuple[int, int], PairConstraint] = {}
    second_opinions: list[list[int | bool]] = []  # [i, j, registered] of the pairs given the second opinion
    bar = tqdm(total=max(n - 1, 0), unit='pair', desc='survey: consecutive pairs', disable=not progress)
    with bar:
        # With GPS, a consecutive pair the torch registrar fails (mostly a line turn, no overlap) gets
        # the OpenCV second opinion later, if its footprints overlap; without, the chain needs it now.
        for i in range(n - 1):
            c = register(i, i + 1, second_opinion=not has_gps)
            if c is not None:
                found[(i, i + 1)] = c
            bar.update(1)
    pairs = list(found.values())
    scale = estimate_scale(pairs, pos, min_baseline_m=3.0 * sigma_gps) if has_gps else math.nan
    focal_known = all(s.focal_known for s in stills)
    scale_source = 'GPS baselines over the registered displacements of consecutive stills'
    scale_is_guess = False
    if not math.isfinite(scale):
        why = ('no consecutive pair with a GPS baseline registered' if has_gps
               else 'the stills carry no usable GPS positions')
        scale, scale_source, scale_is_guess = metadata_scale(stills, config, reader, why=why)
    if scale_is_guess:
        # a warning where the GPS puts the survey on the ground at that guess; without GPS the survey is
        # not georeferenced, or ground control sets its scale
        _LOG.log(logging.WARNING if has_gps and control is None else logging.INFO,
                 'survey: the ground scale is a guess, %s; the mosaic\'s size on the ground may be wrong by the '
                 'ratio of the true height to it (set georef.nominal_agl_m, or georef.ground_altitude_m with GPS '
                 'altitudes).', scale_source)
    else:
        _LOG.info('survey: ground scale %.1f m from %s', scale, scale_source)
    # footprint on the ground at the survey's scale: width / fx x scale
    wh = np.array([[s.size[0] / s.K[0, 0] * scale, s.size[1] / s.K[1, 1] * scale] for s in stills])
    centres = pos
    if not has_gps:
        # No positions: the chain of consecutive pairs predicts the footprints (on the first
        # still's plane, in its height's units; with ground control, on the ground, each stretch of
        # the chain that sees two targets), so a line that comes back over old ground finds it.
        chain = solve_survey(n, pairs, SurveyPriors(np.full((n, 2), np.nan), np.full(n, np.nan), 1.0),
                             control=control)
        G = chain.ground_H_frame
        centres = np.array([G[k][:2, 2] / G[k][2, 2] if chain.placed_by[k] else [np.nan, np.nan] for k in range(n)])
        wh = np.array([[s.size[0] / s.K[0, 0], s.size[1] / s.K[1, 1]] for s in stills]) * np.array(
            [[math.sqrt(abs(np.linalg.det(G[k][:2, :2] / G[k][2, 2]))) if chain.placed_by[k] else np.nan]
             for k in range(n)])
    candidates = predicted_pairs(centres, wh, min_overlap=scfg.min_overlap, max_per_frame=scfg.max_pairs_per_frame)
    more = [(i, j) for i, j, _ in candidates if j != i + 1]
    bar = tqdm(total=len(more), unit='pair', desc='survey: pairs by footprint', disable=not progress)
    with bar:
        # Last stills first: the consecutive pass left their features in the cache. Without the
        # OpenCV second opinion (SIFT on both stills, then matching): a pair between lines that the
        # torch registrar fails is mostly one that SIFT fails too (caliterra: 6 of 117).
        for i, j in reversed(more):
            c = register(i, j, second_opinion=False)
            if c is not None:
                found[(i, j)] = c
            bar.update(1)
        if has_second_opinion:
            # ... except for a still that is short of pairs: its failed pairs that the footprints
            # say overlap get the second opinion
            count = collections.Counter(k for i, j in found for k in (i, j))
            for i, j, _ in candidates:
                reg = registrations.get((i, j))
                if reg is not None and not reg.ok and 'fallback_opencv' not in reg.extras \
                        and min(count[i], count[j]) < SECOND_OPINION_BELOW_PAIRS:
                    c = register(i, j)
                    second_opinions.append([i, j, c is not None])
                    if c is not None:
                        found[(i, j)] = c
                        count.update((i, j))
    # the solve sees the consecutive pairs first, then the others in (j, i) order
    pairs = [found[(i, i + 1)] for i in range(n - 1) if (i, i + 1) in found] + [found[p] for p in more if p in found]
    t_reg = time.perf_counter() - t_reg
    if n == 1:  # a still in no pair is judged (decoded) before it is placed
        cache.get(0)
    cache.cache.clear()  # the features are spent: the canvas gets the memory
    trim_heap()

    # Where each still's principal ray meets the ground: below the camera within the tilt allowance,
    # or, with gimbal angles, offset along the optical axis by the height (to within their 1 deg).
    target = pos.copy()
    sigma = np.full(n, float(np.hypot(sigma_gps, scale * math.tan(math.radians(scfg.tilt_allowance_deg)))))
    shape = {}
    att_sd = math.radians(RECORDED_ATTITUDE_SIGMA_DEG)
    for k, st in enumerate(stills):
        if st.R_enu_from_cam is None:
            continue
        axis = st.R_enu_from_cam[:, 2]
        if axis[2] >= -0.2:
            target[k] = np.nan  # looking at the horizon: its GPS position says little about its view
            continue
        height = st.height_m if math.isfinite(st.height_m) else scale
        target[k] = pos[k] - axis[:2] / axis[2] * height
        sigma[k] = float(np.hypot(sigma_gps, height * math.tan(att_sd)))
        if np.isfinite(target[k]).all() and st.focal_known:
            # the footprint's turn, scale and tilt from the attitude and the height: corner offsets of
            # about half the height, known to the attitude's sd (and the height's, 5 % when estimated)
            rel_height_sd = 0.01 if math.isfinite(st.height_m) else 0.05
            sd = 0.6 * height * float(np.hypot(att_sd * 1.5, rel_height_sd))
            shape[k] = (attitude_ground_H(st.R_enu_from_cam, target[k], height), max(sd, 0.05))
    track = np.full(n, np.nan)
    for k in range(n):
        a, b = pos[max(k - 1, 0)], pos[min(k + 1, n - 1)]
        if np.isfinite(a).all() and np.isfinite(b).all() and np.hypot(*(b - a)) >= 1.0:
            track[k] = math.atan2(b[1] - a[1], b[0] - a[0])
    priors = SurveyPriors(target, sigma, scale, track, shape)
    return RegisteredSurvey(pairs, priors, registrations, reduction, more, second_opinions, cache.described,
                            dict(cache.unreadable), scale, scale_source, focal_known, has_gps, georef_note, t_reg,
                            scale_is_guess)
