"""Video files in and out (PyAV): frame selection as in the reference (section 4.3, Appendix A).

Selection modes (`--select`):
- ``all``: every decoded frame;
- ``every:N``: every N-th frame;
- ``iframes``: intra-coded frames only (the reference's MPEG I-frame mosaics); the decoder is told
  to skip non-key frames, so the others are not even decoded;
- ``overlap:F``: adaptive: the next frame is selected when its overlap with the last selected
  frame falls below F (0 < F < 1). The overlap is estimated from the global translation between
  the two frames by phase correlation on a downscaled grey image (cv2.phaseCorrelate), which is
  cheap and sufficient for the near-nadir translation-dominated motion of UAS video.

Interlaced video (``deinterlace``): ``auto`` keeps the top field of every frame the stream flags as
interlaced (io/deinterlace.py), ``on`` of every frame, ``off`` none.

Stamps: a frame's stamp_ns is its presentation time in ns from the first frame of the file.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from ..core.image_ops import to_gray_float01
from ..core.types import CameraIntrinsics, Frame
from ..errors import InputError
from .deinterlace import top_field

__all__ = ['VIDEO_SUFFIXES', 'DEINTERLACE_MODES', 'FrameSelection', 'VideoReader', 'camera_from_hfov', 'is_video', 'load_camera_yaml',
           'parse_selection', 'write_video']

DEINTERLACE_MODES = ('auto', 'on', 'off')
VIDEO_SUFFIXES = {'.mp4', '.m4v', '.mkv', '.avi', '.ts', '.mts', '.m2ts', '.mpg', '.mpeg', '.mov', '.webm'}

_LOG = logging.getLogger(__name__)


class VideoError(InputError):
    """A video file cannot be read (missing, empty, unsupported codec, truncated, size change)."""


def is_video(path: Path) -> bool:
    return Path(path).is_file() and Path(path).suffix.lower() in VIDEO_SUFFIXES


@dataclass(frozen=True)
class FrameSelection:
    mode: str  # 'all' | 'every' | 'iframes' | 'overlap'
    every: int = 1
    overlap: float = 0.0


def parse_selection(text: str) -> FrameSelection:
    """'all' | 'every:N' | 'iframes' | 'overlap:F' -> FrameSelection (InputError when malformed)."""
    mode, _, arg = text.partition(':')
    try:
        if mode == 'all' and not arg:
            return FrameSelection('all')
        if mode == 'iframes' and not arg:
            return FrameSelection('iframes')
        if mode == 'every' and int(arg) >= 1:
            return FrameSelection('every', every=int(arg))
        if mode == 'overlap' and 0.0 < float(arg) < 1.0:
            return FrameSelection('overlap', overlap=float(arg))
    except ValueError:
        pass
    msg = f"--select {text!r} is not valid; use all, every:N (N >= 1), iframes or overlap:F (0 < F < 1)."
    raise InputError(msg)


def camera_from_hfov(width: int, height: int, hfov_deg: float) -> CameraIntrinsics:
    """Square pixels, centred principal point, focal length from the horizontal field of view."""
    if not 1.0 <= hfov_deg < 179.0:
        msg = f'--hfov {hfov_deg} is not a field of view in degrees (1 .. 179).'
        raise InputError(msg)
    f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    return CameraIntrinsics(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)


def load_camera_yaml(path: Path) -> CameraIntrinsics:
    """A ROS camera_calibration YAML (image_width, image_height, camera_matrix, distortion_*), read
    with limits (bounded_yaml.py)."""
    import yaml

    from ..bounded_yaml import load_bounded

    try:
        doc = load_bounded(Path(path).read_text())
        k = [float(v) for v in doc['camera_matrix']['data']]
        dist = tuple(float(v) for v in (doc.get('distortion_coefficients') or {}).get('data', []))
        width, height = int(doc['image_width']), int(doc['image_height'])
        camera = CameraIntrinsics(width, height, k[0], k[4], k[2], k[5],
                                  str(doc.get('distortion_model', '') or ''), dist)
    except FileNotFoundError:
        msg = f'--camera {path} does not exist.'
        raise InputError(msg) from None
    except (KeyError, TypeError, ValueError, IndexError, yaml.YAMLError) as exc:
        said = ' '.join(str(exc).split())
        msg = (f'--camera {path} is not a camera calibration YAML (needs image_width, image_height, '
               f'camera_matrix.data): {said if len(said) <= 200 else said[:197] + "..."}')
        raise InputError(msg) from None
    bad = [what for what, ok in (('image_width and image_height must be positive', width > 0 and height > 0),
                                 ('fx and fy (camera_matrix.data[0], [4]) must be positive and finite',
                                  all(math.isfinite(v) and v > 0 for v in (camera.fx, camera.fy))),
                                 ('cx and cy must be finite', math.isfinite(camera.cx) and math.isfinite(camera.cy)),
                                 ('distortion coefficients must be finite', all(math.isfinite(v) for v in dist)))
           if not ok]
    if bad:
        msg = f'--camera {path}: {"; ".join(bad)} (a zero camera matrix is not a calibration).'
        raise InputError(msg)
    return camera


class _OverlapSelector:
    """Select a frame when its estimated overlap with the last selected frame falls below F."""

    def __init__(self, threshold: float, work_width: int = 160) -> None:
        self.threshold = threshold
        self.work_width = work_width
        self._ref: np.ndarray | None = None
        self._prev: np.ndarray | None = None
        self._shift = np.zeros(2)

    def _small(self, image: np.ndarray) -> np.ndarray:
        g = to_gray_float01(image)
        s = self.work_width / g.shape[1]
        small = cv2.resize(g, (self.work_width, max(8, round(g.shape[0] * s))), interpolation=cv2.INTER_AREA)
        return small.astype(np.float32)

    def __call__(self, image: np.ndarray) -> bool:
        cur = self._small(image)
        if self._ref is None:
            self._ref, self._prev, self._shift = cur, cur, np.zeros(2)
            return True
        # Chain frame-to-frame shifts (robust at small motion) back to the last selected frame.
        win = cv2.createHanningWindow(cur.shape[::-1], cv2.CV_32F)
        (dx, dy), _ = cv2.phaseCorrelate(self._prev, cur, win)
        self._shift += (dx, dy)
        self._prev = cur
        h, w = cur.shape
        overlap = max(0.0, w - abs(self._shift[0])) * max(0.0, h - abs(self._shift[1])) / (w * h)
        if overlap < self.threshold:
            self._ref, self._shift = cur, np.zeros(2)
            return True
        return False


class VideoReader:
    """Frames of a video file, selected (see module docstring); iterable, with counts for progress."""

    def __init__(self, path: str | Path, *, selection: FrameSelection = FrameSelection('all'),
                 camera: CameraIntrinsics | None = None, hfov_deg: float | None = None,
                 deinterlace: str = 'auto') -> None:
        import av

        self.path = Path(path)
        self.selection = selection
        if deinterlace not in DEINTERLACE_MODES:
            msg = f'deinterlace {deinterlace!r}: use one of {", ".join(DEINTERLACE_MODES)}.'
            raise InputError(msg)
        self.deinterlace = deinterlace
        if not self.path.is_file():
            msg = f'video {str(self.path)!r} does not exist; check the path.'
            raise VideoError(msg)
        if self.path.stat().st_size == 0:
            msg = f'video {str(self.path)!r} is empty (0 bytes); the recording did not finish or the copy failed.'
            raise VideoError(msg)
        try:
            with av.open(str(self.path)) as container:
                if not container.streams.video:
                    msg = f'{str(self.path)!r} has no video stream.'
                    raise VideoError(msg)
                stream = container.streams.video[0]
                self.codec = stream.codec_context.name
                self.width, self.height = stream.codec_context.width, stream.codec_context.height
                self.frames_declared = int(stream.frames or 0)
                rate = stream.average_rate or stream.guessed_rate
                self.fps = float(rate) if rate else float('nan')
                # what the header says the stream lasts (s; NaN: not said; MPEG-TS estimates it from the data)
                if stream.duration is not None and stream.time_base is not None:
                    self.duration_declared_s = float(stream.duration * stream.time_base)
                elif container.duration is not None:
                    self.duration_declared_s = container.duration / 1e6
                else:
                    self.duration_declared_s = float('nan')
        except VideoError:
            raise
        except Exception as exc:  # noqa: BLE001 - av.error.*: unsupported container or codec, corrupt header
            msg = (f'cannot open video {str(self.path)!r}: {exc}. The file is corrupt, truncated or uses a codec '
                   'FFmpeg does not decode; re-encode it (e.g. to H.264 MP4) or check the copy.')
            raise VideoError(msg) from None
        if camera is not None and (camera.width, camera.height) != (self.width, self.height):
            scaled = camera.scaled_to(self.width, self.height)
            if scaled is None:
                msg = (f'--camera is a calibration of {camera.width}x{camera.height} images, the video '
                       f'{self.path.name} is {self.width}x{self.height} (another aspect ratio); give the '
                       'calibration of this camera mode.')
                raise VideoError(msg)
            _LOG.warning('--camera is a calibration of %dx%d images, the video is %dx%d: its intrinsics are '
                         'scaled to the video.', camera.width, camera.height, self.width, self.height)
            camera = scaled
        if camera is not None:
            self.camera = camera
        elif hfov_deg is not None:
            self.camera = camera_from_hfov(self.width, self.height, hfov_deg)
        else:
            self.camera = None
        self.decoded = 0
        self.selected = 0
        self.deinterlaced = 0  # decoded frames of which only the top field was kept
        self.error: str = ''
        self.ended_early: str = ''  # the stream ended before what its header declares (a cut file)

    @property
    def duration_s(self) -> float:
        """How long the video lasts (s): its header's duration, else its frames over its rate (NaN: unknown)."""
        if math.isfinite(self.duration_declared_s) and self.duration_declared_s > 0:
            return self.duration_declared_s
        frames = self.frames_declared
        return frames / self.fps if frames and math.isfinite(self.fps) and self.fps > 0 else math.nan

    @property
    def frame_count(self) -> int | None:
        """Frames the file declares (all of them, before selection), or None when unknown."""
        return self.frames_declared or None

    def __iter__(self) -> Iterator[Frame]:
        import av

        sel = self.selection
        overlap = _OverlapSelector(sel.overlap) if sel.mode == 'overlap' else None
        self.decoded = self.selected = self.deinterlaced = 0
        self.error = self.ended_early = ''
        last_pts = None
        with av.open(str(self.path)) as container:
            stream = container.streams.video[0]
            stream.thread_type = 'AUTO'  # FFmpeg's frame and slice threads: HD decoding keeps up
            if sel.mode == 'iframes':
                stream.codec_context.skip_frame = 'NONKEY'
            time_base: Fraction = stream.time_base or Fraction(1, 90000)
            first_pts = None
            index = -1
            try:
                for vframe in container.decode(stream):
                    index += 1
                    self.decoded += 1
                    if sel.mode == 'iframes' and not vframe.key_frame:
                        continue
                    if sel.mode == 'every' and index % sel.every:
                        continue
                    if vframe.width != self.width or vframe.height != self.height:
                        msg = (f'{str(self.path)!r}: frame {index} is {vframe.width}x{vframe.height}, the stream '
                               f'started at {self.width}x{self.height}; split the file where the size changes.')
                        raise VideoError(msg)
                    pts = vframe.pts if vframe.pts is not None else index
                    if first_pts is None:
                        first_pts = pts
                    last_pts = pts
                    image = vframe.to_ndarray(format='rgb24')
                    if self.deinterlace == 'on' or (self.deinterlace == 'auto' and vframe.interlaced_frame):
                        image = top_field(image)
                        self.deinterlaced += 1
                    if overlap is not None and not overlap(image):
                        continue
                    self.selected += 1
                    stamp_ns = round(float((pts - first_pts) * time_base) * 1e9)
                    yield Frame(stamp_ns, image, self.camera, 'video')
            except VideoError:
                raise
            except Exception as exc:  # noqa: BLE001 - av.error.InvalidDataError etc.: damage mid-stream
                msg = (f'{str(self.path)!r} is damaged: decoding stopped after {self.decoded} frames ({exc}). '
                       'The frames before the damage were processed.')
                raise VideoError(msg) from None
        if self.decoded == 0:
            msg = f'{str(self.path)!r} holds no decodable video frame (codec {self.codec}); the file is truncated.'
            raise VideoError(msg)
        self._check_complete(None if last_pts is None or first_pts is None else
                             float((last_pts - first_pts) * time_base))

    def _check_complete(self, last_s: float | None) -> None:
        """Say (log, ``ended_early``) when decoding ended well before the frames or the duration the
        header declares: a file cut short decodes cleanly up to the cut, and would pass for whole."""
        period = 1.0 / self.fps if math.isfinite(self.fps) and self.fps > 0 else 0.04
        declared, said = self.duration_declared_s, ''
        if self.frames_declared and self.decoded < self.frames_declared - 1:
            said = f'{self.decoded} of the {self.frames_declared} frames its header declares'
        elif last_s is not None and math.isfinite(declared) and last_s + period < declared - max(1.0, 2 * period):
            said = f'{last_s + period:.1f} s of the {declared:.1f} s its header declares'
        if said:
            self.ended_early = (f'{self.path.name} ended after {said}: the file is cut short (a copy or a recording '
                                'that stopped); the frames up to there were processed')
            _LOG.warning('%s.', self.ended_early)


def write_video(path: str | Path, frames: Iterator[np.ndarray], *, fps: float, gop: int = 12,
                codec: str = 'libx264', crf: int = 18) -> int:
    """Encode RGB (H, W, 3) or mono uint8 frames to H.264 with a fixed GOP (I-frame every `gop`).

    No B-frames and no scene-cut keyframes, so I-frames fall exactly every `gop` frames. Returns
    the number of frames written. Width and height are cropped to even numbers (yuv420p).
    """
    import av

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n = 0
    with av.open(str(path), 'w') as container:
        stream = None
        for image in frames:
            if image.ndim == 2:
                image = np.repeat(image[:, :, None], 3, axis=2)
            h, w = image.shape[0] // 2 * 2, image.shape[1] // 2 * 2
            if stream is None:
                stream = container.add_stream(codec, rate=Fraction(fps).limit_denominator(1001))
                stream.width, stream.height, stream.pix_fmt = w, h, 'yuv420p'
                stream.codec_context.gop_size = gop
                stream.options = {'g': str(gop), 'keyint_min': str(gop), 'sc_threshold': '0', 'bf': '0',
                                  'crf': str(crf)}
            vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(image[:h, :w]), format='rgb24')
            for packet in stream.encode(vf):
                container.mux(packet)
            n += 1
        if stream is not None:
            for packet in stream.encode():
                container.mux(packet)
    return n
