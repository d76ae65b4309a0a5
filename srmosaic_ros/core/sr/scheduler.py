"""The SR scheduler: which mosaic tiles to super-resolve, from which frames.

The mosaic is cut into square tiles of `tile_size` mosaic pixels on a grid anchored at mosaic
pixel (0, 0). A tile is scheduled when the mosaic covers it (at least `min_coverage` of its
pixels) and at least `min_frames` registered frames cover it entirely; it then takes
`max_frames` of them (:func:`choose_frames`): the reference (the frame whose footprint centre is
nearest the tile centre, the one the mosaic shows there) and either the others nearest the tile
(``frame_choice: nearest``) or others spread evenly in time over every frame that covers it
(``spread``). Video compression leaves each frame an error that the next frames inherit (motion-
compensated prediction copies it); frames far apart in time carry errors that are more nearly
independent, so the same number of frames averages more of it away (bench/sr_oracle.py).
Tiles are ordered by how many frames see them (the best-constrained first) and capped at
`max_tiles`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..metrics import apply_homography
from ..settings import check_settings, setting
from ..sr_factors import SR_FACTORS

__all__ = ['FRAME_CHOICES', 'SR_FACTORS', 'SRTileConfig', 'TilePlan', 'choose_frames', 'frame_centres', 'frame_holds_rect',
           'plan_tiles']

FRAME_CHOICES = ('nearest', 'spread')


@dataclass(frozen=True)
class SRTileConfig:
    """Keys under `sr_tiles.` in params/*.yaml (``factor``: one of SR_FACTORS; ``frame_choice``: one of
    FRAME_CHOICES, :func:`choose_frames`)."""

    factor: int = setting(2, choices=SR_FACTORS)
    tile_size: int = setting(128, lo=16, hi=2048, unit='mosaic px')
    min_frames: int = setting(3, lo=1, hi=1000)
    max_frames: int = setting(8, lo=1, hi=1000)
    max_tiles: int = setting(48, lo=1)
    min_coverage: float = setting(0.98, gt=0.0, hi=1.0)
    frame_choice: str = setting('nearest', choices=FRAME_CHOICES)

    def __post_init__(self) -> None:
        check_settings(self, 'sr_tiles')
        if self.max_frames < self.min_frames:
            msg = (f'invalid sr_tiles settings: sr_tiles.max_frames={self.max_frames!r} is below '
                   f'sr_tiles.min_frames={self.min_frames!r}; raise max_frames or lower min_frames.')
            raise ValueError(msg)


@dataclass(frozen=True)
class TilePlan:
    """A tile (x0, y0, width, height) in mosaic pixels and the frame indices chosen for it."""

    x0: int
    y0: int
    width: int
    height: int
    frames: tuple[int, ...]
    frames_covering: int


def frame_centres(plane_H_frames: list[np.ndarray], frame_sizes: list[tuple[int, int]]) -> np.ndarray:
    """(N, 2) plane points of the frames' centres; frame_sizes (width, height), pixel centres at integers.

    "The frame nearest a tile" (nearest centre) is the one the scheduler prefers, the mosaic shows
    there, and the consistency gate seeds its set with.
    """
    return np.array([apply_homography(H, np.array([[(w - 1) / 2, (h - 1) / 2]]))[0]
                     for H, (w, h) in zip(plane_H_frames, frame_sizes, strict=True)]).reshape(-1, 2)


def choose_frames(nearest_first: list[int], count: int, choice: str = 'nearest') -> list[int]:
    """``count`` of the frames ``nearest_first`` (frame indices in time order's numbering, the frame
    nearest the tile first), that first one (the reference) first in the result.

    'nearest': the first ``count``. 'spread': the reference and frames at evenly spaced positions of
    all of them sorted by index (time), the position nearest the reference's taken by it; the others
    follow in the order given.
    """
    if choice not in FRAME_CHOICES:
        msg = f'frame choice must be one of {FRAME_CHOICES}, got {choice!r}.'
        raise ValueError(msg)
    order = list(nearest_first)
    if choice == 'nearest' or count >= len(order) or count < 2:
        return order[:max(count, 0)]
    ref = order[0]
    timeline = sorted(order)
    # more frames than count: the spacing (n - 1) / (count - 1) > 1, so the rounded positions differ
    picks = [timeline[int(i)] for i in np.round(np.linspace(0, len(timeline) - 1, count))]
    picks[int(np.argmin([abs(k - ref) for k in picks]))] = ref
    chosen = set(picks)
    return [ref] + [k for k in order[1:] if k in chosen]


def frame_holds_rect(frame_H_mosaic: np.ndarray, frame_size: tuple[int, int],
                     rect: tuple[int, int, int, int]) -> bool:
    """True when the frame of ``frame_size`` (width, height) holds the corner pixels of the mosaic
    rectangle ``rect = (x0, y0, width, height)``; frame_H_mosaic maps mosaic pixels to frame pixels."""
    x0, y0, w, h = rect
    corners = np.array([[x0, y0], [x0 + w - 1, y0], [x0 + w - 1, y0 + h - 1], [x0, y0 + h - 1]], float)
    p = apply_homography(frame_H_mosaic, corners)
    fw, fh = frame_size
    return bool(np.all((p[:, 0] >= 0) & (p[:, 0] <= fw - 1) & (p[:, 1] >= 0) & (p[:, 1] <= fh - 1)))


def plan_tiles(mosaic_H_frames: dict[int, np.ndarray], frame_sizes: dict[int, tuple[int, int]],
               coverage: np.ndarray, config: SRTileConfig) -> list[TilePlan]:
    """Tiles to reconstruct. mosaic_H_frames: frame index -> (3, 3) frame pixels -> mosaic pixels;
    frame_sizes: index -> (width, height); coverage: (H, W) bool of the mosaic."""
    t = config.tile_size
    h, w = coverage.shape
    inverse = {k: np.linalg.inv(H) for k, H in mosaic_H_frames.items()}
    keys = list(mosaic_H_frames)
    centres = dict(zip(keys, frame_centres([mosaic_H_frames[k] for k in keys], [frame_sizes[k] for k in keys]),
                       strict=True))
    plans = []
    for y0 in range(0, h - t + 1, t):
        for x0 in range(0, w - t + 1, t):
            if coverage[y0:y0 + t, x0:x0 + t].mean() < config.min_coverage:
                continue
            covering = [k for k, frame_H_mosaic in inverse.items()
                        if frame_holds_rect(frame_H_mosaic, frame_sizes[k], (x0, y0, t, t))]
            if len(covering) < config.min_frames:
                continue
            c = np.array([x0 + (t - 1) / 2, y0 + (t - 1) / 2])
            nearest = sorted(covering, key=lambda k: float(np.linalg.norm(centres[k] - c)))
            chosen = choose_frames(nearest, config.max_frames, config.frame_choice)
            plans.append(TilePlan(x0, y0, t, t, tuple(sorted(chosen)), len(covering)))
    plans.sort(key=lambda p: (-p.frames_covering, p.y0, p.x0))
    return plans[:config.max_tiles]
