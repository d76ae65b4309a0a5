"""The camera PSF measured on straight edges (core/sr/psf_estimate.py, `srmosaic psf`), against known blurs."""
from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
from scipy.special import ndtr

from srmosaic_ros.cli import main
from srmosaic_ros.core.sr.psf_estimate import PsfEstimationError, estimate_psf_sigma, fit_edge_profile
from srmosaic_ros.sim.chart import checkerboard, write_edge_chart
from srmosaic_ros.sim.config import SimConfig
from srmosaic_ros.sim.flight import simulate
from srmosaic_ros.sim.record import write_flight
from srmosaic_ros.sim.render import effective_sigma_px

ORIGIN = {'origin_lat_deg': 45.0, 'origin_lon_deg': 7.0}
# The chart's own anti-aliasing (a 1-world-px box, 0.16 frame px at the default 1.8 world px per
# frame px) and the renderer's bilinear sampling of the world add about 0.27 px in quadrature
# (measured at blurs 0.42, 0.76 and 1.23 px: the excess is the same): the estimate must lie in
# [sigma_eff, sqrt(sigma_eff^2 + 0.3^2)].
EXTRA_PX = 0.3


def _edge_image(sigma: float, angle_deg: float, *, size: int = 64, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """A point-sampled blurred step a + b Phi(d / sigma) through the image centre (the exact model)."""
    a = math.radians(angle_deg)
    n = np.array([-math.sin(a), math.cos(a)])
    ys, xs = np.mgrid[0:size, 0:size].astype(np.float64)
    d = (xs - size / 2 + 0.3) * n[0] + (ys - size / 2 - 0.2) * n[1]
    img = 0.2 + 0.5 * ndtr(d / sigma)
    img += np.random.default_rng(seed).normal(0.0, noise, img.shape)
    return np.clip(img, 0, 1)


def _segment(angle_deg: float, size: int = 64, half: float = 24.0) -> tuple[np.ndarray, np.ndarray]:
    a = math.radians(angle_deg)
    c = np.array([size / 2 - 0.3, size / 2 + 0.2])
    t = np.array([math.cos(a), math.sin(a)])
    return c - half * t, c + half * t


@pytest.mark.parametrize('sigma', [0.35, 0.8, 1.4])
def test_edge_fit_recovers_sigma_of_an_exact_slanted_edge(sigma: float) -> None:
    img = _edge_image(sigma, 7.0, noise=1.0 / 255)
    fit = fit_edge_profile(img, *_segment(7.0))
    assert fit is not None
    assert fit.sigma == pytest.approx(sigma, rel=0.04)
    assert fit.contrast == pytest.approx(0.5, abs=0.02)


def test_edge_fit_refuses_an_edge_on_the_pixel_grid() -> None:
    """Axis-aligned, the profile is sampled at one phase: no sub-pixel sigma, so no answer."""
    img = _edge_image(0.5, 0.0)
    assert fit_edge_profile(img, *_segment(0.0)) is None


@pytest.fixture(scope='module')
def chart_world(tmp_path_factory: pytest.TempPathFactory) -> str:
    return write_edge_chart(tmp_path_factory.mktemp('chart') / 'chart.png')


@pytest.mark.parametrize('psf', [0.3, 1.2])
def test_estimate_on_a_simulated_flight_over_a_chart(chart_world: str, psf: float) -> None:
    flight = simulate(SimConfig(world=chart_world, frames=3, psf_sigma_px=psf, seed=3, **ORIGIN))
    est = estimate_psf_sigma([f.image for f in flight.frames])
    eff = effective_sigma_px(psf)
    assert eff <= est.sigma <= math.hypot(eff, EXTRA_PX)
    assert est.edges >= 50
    assert not est.scene_limited  # all edges agree on a target


def test_estimate_on_a_turned_checkerboard(tmp_path) -> None:
    """The camera calibration's target serves too: its corners spoil the profiles only near them."""
    path = tmp_path / 'checker.png'
    cv2.imwrite(str(path), checkerboard())
    flight = simulate(SimConfig(world=str(path), frames=2, psf_sigma_px=0.7, seed=2, **ORIGIN))
    est = estimate_psf_sigma([f.image for f in flight.frames])
    eff = effective_sigma_px(0.7)
    assert eff <= est.sigma <= math.hypot(eff, EXTRA_PX)
    assert not est.scene_limited


def test_natural_terrain_is_flagged_as_an_upper_bound() -> None:
    """On the caliterra orthophoto the edges are the soil's: wide and disagreeing, whatever the camera."""
    flight = simulate(SimConfig(frames=3, psf_sigma_px=0.3, seed=3))
    est = estimate_psf_sigma([f.image for f in flight.frames])
    assert est.scene_limited
    assert est.sigma > effective_sigma_px(0.3)


def test_frames_without_edges_raise_naming_the_way_out() -> None:
    rng = np.random.default_rng(0)
    flat = [np.clip(rng.normal(120, 2, (120, 160)), 0, 255).astype(np.uint8) for _ in range(3)]
    with pytest.raises(PsfEstimationError, match='target with sharp straight edges'):
        estimate_psf_sigma(flat)


def test_cli_on_a_folder_and_on_a_bag(chart_world: str, tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    flight = simulate(SimConfig(world=chart_world, frames=3, psf_sigma_px=0.7, seed=5, **ORIGIN))
    folder = tmp_path / 'frames'
    folder.mkdir()
    for k, f in enumerate(flight.frames):
        cv2.imwrite(str(folder / f'f{k:03d}.png'), cv2.cvtColor(f.image, cv2.COLOR_RGB2BGR))
    eff = effective_sigma_px(0.7)
    assert main(['psf', str(folder)]) == 0
    out = capsys.readouterr().out
    assert 'psf_sigma:' in out and 'warning' not in out
    bag = write_flight(flight, tmp_path / 'bag')
    assert main(['psf', str(bag), '--json']) == 0
    figures = json.loads(capsys.readouterr().out)
    assert eff <= figures['sigma_px'] <= math.hypot(eff, EXTRA_PX)
    assert figures['frames'] == 3 and len(figures['edge_sigmas_px']) == figures['edges']


def test_cli_on_a_video(chart_world: str, tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    """H.264 at crf 18 keeps the edges: the video's frames measure as the stills do."""
    from srmosaic_ros.io.video import write_video

    flight = simulate(SimConfig(world=chart_world, frames=6, psf_sigma_px=0.7, seed=5, **ORIGIN))
    video = tmp_path / 'chart.mp4'
    write_video(video, (f.image for f in flight.frames), fps=4.0)
    assert main(['psf', str(video), '--max-frames', '3', '--json']) == 0
    figures = json.loads(capsys.readouterr().out)
    eff = effective_sigma_px(0.7)
    assert figures['frames'] == 3
    assert eff <= figures['sigma_px'] <= math.hypot(eff, EXTRA_PX) and not figures['scene_limited']


def test_cli_errors(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['psf', str(tmp_path / 'missing.png')]) == 2
    assert 'does not exist' in capsys.readouterr().err
    flat = tmp_path / 'flat.png'
    cv2.imwrite(str(flat), np.full((100, 100), 128, np.uint8))
    assert main(['psf', str(flat)]) == 2
    assert 'target with sharp straight edges' in capsys.readouterr().err
    assert main(['psf', str(flat), '--quantile', '1.5']) == 2
