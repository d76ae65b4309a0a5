"""`srmosaic psf`: measure the camera's PSF (``sr.psf_sigma``) on frames of a target with straight edges.

Frames come from image files, folders of images, a video or a bag (the image topic; lens distortion
removed as the pipeline removes it, so the figure is the blur the SR stage sees). The measurement
is :func:`srmosaic_ros.core.sr.psf_estimate.estimate_psf_sigma`; read its module docstring for
what the figure means on natural terrain (an upper bound only).
"""
from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..core.image_decode import decode_file
from ..core.sr.psf_estimate import PsfEstimate, PsfEstimationError, estimate_psf_sigma
from ..core.types import Frame
from ..core.undistort import Undistorter
from ..errors import InputError
from ..io.image_folder import IMAGE_SUFFIXES

__all__ = ['as_json', 'collect_frames', 'measure_psf', 'summary_lines']


def _read_image(path: Path) -> np.ndarray:
    """An image file under the decoding guard (core/image_decode.py): a truncated or damaged image
    raises ImageRefused (an InputError) naming it; a flat one is left to the edge finder to refuse."""
    img = decode_file(path, cv2.IMREAD_UNCHANGED, content=False).pixels
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    return img


def _stream_frames(path: Path, max_frames: int, undistort: bool) -> Iterator[np.ndarray]:
    """Up to ``max_frames`` images of a folder, video or bag, spread evenly over it when its length is known."""
    from .process import open_source

    items, reader, _kind = open_source(path)
    total = getattr(reader, 'frame_count', None)
    stride = max(1, int(total) // max_frames) if total else 1
    undistorter = Undistorter(undistort)
    k = taken = 0
    for item in items:
        if not isinstance(item, Frame):
            continue
        if k % stride == 0:
            yield undistorter.frame(item).image
            taken += 1
            if taken >= max_frames:
                return
        k += 1


def collect_frames(inputs: Sequence[Path], *, max_frames: int = 20, undistort: bool = True) -> list[np.ndarray]:
    """The images to measure: image files, every image of a folder, or frames of a video / bag.

    Raises InputError for a path that does not exist or holds no image.
    """
    frames: list[np.ndarray] = []
    for path in inputs:
        if not path.exists():
            msg = f'{path} does not exist.'
            raise InputError(msg)
        if path.is_file() and path.suffix.lower() in IMAGE_SUFFIXES:
            frames.append(_read_image(path))
        else:  # a folder of images, a video or a bag: the readers `srmosaic process` uses
            frames.extend(_stream_frames(path, max_frames, undistort))
    if not frames:
        msg = f'no image in {", ".join(map(str, inputs))}.'
        raise InputError(msg)
    return frames


def measure_psf(inputs: Sequence[Path], *, max_frames: int = 20, undistort: bool = True,
                quantile: float = 0.25) -> PsfEstimate:
    """The PSF estimate of the frames of ``inputs`` (see :func:`collect_frames`).

    Raises InputError when too few clean straight edges are found (the message says what to image).
    """
    frames = collect_frames(inputs, max_frames=max_frames, undistort=undistort)
    try:
        return estimate_psf_sigma(frames, quantile=quantile)
    except PsfEstimationError as exc:
        raise InputError(str(exc)) from exc


def summary_lines(est: PsfEstimate) -> list[str]:
    """What `srmosaic psf` prints: the figure, its support, and the parameter to set."""
    q10, q50, q90 = np.quantile(est.edge_sigmas, [0.1, 0.5, 0.9])
    lines = [f'PSF sigma {est.sigma:.3f} px (lower quartile of {est.edges} straight edges in {est.frames} frames; '
             f'edge sigmas p10 {q10:.3f}, median {q50:.3f}, p90 {q90:.3f}, interquartile range {est.spread:.3f} px)']
    if est.scene_limited:
        lines.append(f'warning: the edges disagree by {est.spread:.2f} px (more than {est.max_spread:g}): their '
                     f"width is the scene's, so {est.sigma:.2f} px only bounds the camera's blur from above, and an "
                     'over-estimated PSF makes SR ring; measure on a target with sharp straight edges (a printed '
                     'chart, the calibration checkerboard).')
    else:
        lines.append(f'set in a params file:  sr: {{psf_sigma: {est.sigma:.2f}}}')
    return lines


def as_json(est: PsfEstimate) -> dict[str, Any]:
    """The figures and the per-edge sigmas."""
    out: dict[str, Any] = est.as_dict()
    out['edge_sigmas_px'] = [round(float(v), 4) for v in est.edge_sigmas]
    return out
