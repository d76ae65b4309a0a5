"""Benchmark: frame-to-frame registration, torch registrar against an OpenCV SIFT baseline.

Synthetic flights over two real orthophotos, each downscaled by 2 (camera blur sigma 0.7 px; pixel
integration by 3 x 3 supersampling): data/worlds/caliterra_IMG_9360.jpg (2000 x 1500, fields and
tracks: weak texture, OpenCV SIFT finds ~90 keypoints in a frame) and data/worlds/brighton_DJI_0025.jpg
(2000 x 1125, a beach town: the textured aerial frames the issue's baseline figures were taken on,
SIFT keeps its 1000). 640 x 480 frames, sensor noise sigma 2/255, EO (RGB) and IR-like (single channel, inverted non-linear
contrast, softer optics, per-frame gain drift), with small and large inter-frame motion (large:
translation up to 60 px, rotation up to 10 degrees, scale up to 1.2, slight perspective; zoom: scale
changes of 1.3 to 1.5 between frames, the descriptor's range), plus textureless frames (sea / cloud)
that must fail.

Every method sees the same frames in the same process, taking turns frame by frame (so that
load changes on a shared machine hit all alike); each frame is described once and registered to
the previous one (the previous frame's features are cached), and the time per frame is
describe + register. The baseline is timed as well without that cache (both frames of a pair
described, as a script registering consecutive frames with cv2 does; the issue's "about 10 frames
per second" is that figure on textured frames). Printed per method and scenario: median and p90 ms per frame,
frames per second, mean and p90 corner error against the true homography (registered frames),
the failure rate (ok = False), wrong registrations (ok = True but corner error > 2 px), and
the speed ratio of ours to the baseline.

    python bench/registration.py [--frames 40] [--device cpu|cuda|auto] [--threads 2] [--quick] [--repeat 3]
                                 [--cuda-graphs]
                                 [--worlds caliterra,brighton]
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from srmosaic_ros.core.image_ops import to_gray_u8
from srmosaic_ros.core.metrics import corner_error_px
from srmosaic_ros.core.registration import RegistrationConfig
from srmosaic_ros.core.registration.torch_registrar import TorchRegistrar, TorchRegistrarOptions

WORLDS = {'caliterra': ROOT / 'data' / 'worlds' / 'caliterra_IMG_9360.jpg',
          'brighton': ROOT / 'data' / 'worlds' / 'brighton_DJI_0025.jpg'}
WIDTH, HEIGHT = 640, 480
NOISE = 2.0            # sensor noise, of 255
SUPERSAMPLE = 3        # pixel integration by 3 x 3 supersampling
WRONG_PX = 2.0         # an ok registration farther than this from the truth is a silent failure


# --- synthetic flights ----------------------------------------------------------------------------

@dataclass(frozen=True)
class Motion:
    """Inter-frame motion ranges: |translation| px, |rotation| deg, scale factor (>= 1, either way),
    perspective (h20, h21 about the frame centre, 1/px)."""

    t_px: tuple[float, float]
    rot_deg: tuple[float, float]
    scale: tuple[float, float]
    persp: float


SMALL = Motion((2.0, 15.0), (0.0, 1.5), (1.0, 1.03), 1e-5)
LARGE = Motion((30.0, 60.0), (5.0, 10.0), (1.1, 1.2), 3e-5)
ZOOM = Motion((5.0, 30.0), (0.0, 5.0), (1.3, 1.5), 1e-5)   # the scale range for the descriptor: up to 1.5


def load_worlds(scale: float = 0.5, path: Path = WORLDS['caliterra']) -> dict[str, np.ndarray]:
    """EO world (RGB float32 in [0, 255]) and IR-like world (float32 in [0, 1]) at the given scale of the orthophoto."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        msg = f'cannot read the world image {path}'
        raise SystemExit(msg)
    bgr = cv2.resize(bgr, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    bgr = cv2.GaussianBlur(bgr, (0, 0), 0.7)                       # camera PSF
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    g = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    # IR-like: warm where dark (vegetation, asphalt), non-linear, compressed range, softer optics.
    ir = 0.2 + 0.6 * (1.0 - g) ** 1.6
    ir = cv2.GaussianBlur(ir, (0, 0), 1.0)
    return {'eo': rgb.astype(np.float32), 'ir': ir}


def _similarity(angle_deg: float, scale: float, tx: float, ty: float, cx: float, cy: float) -> np.ndarray:
    a = np.deg2rad(angle_deg)
    r = scale * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    h = np.eye(3)
    h[:2, :2] = r
    h[:2, 2] = np.array([cx, cy]) - r @ np.array([cx, cy]) + np.array([tx, ty])
    return h


def flight(world_shape: tuple[int, int], motion: Motion, frames: int, seed: int) -> list[np.ndarray]:
    """world_H_frame for a flight of `frames` frames; consecutive frames differ by `motion`.

    prev_H_cur = inv(world_H_prev) @ world_H_cur is drawn in the ranges of motion; the flight is
    steered toward the world centre near the edges and keeps its ground scale in [0.8, 1.25].
    """
    rng = np.random.default_rng(seed)
    wh, ww = world_shape
    cx, cy = (WIDTH - 1) / 2.0, (HEIGHT - 1) / 2.0
    world_H = _similarity(rng.uniform(0, 360), 1.0, ww / 2 - cx, wh / 2 - cy, cx, cy)
    out = [world_H]
    for _ in range(frames - 1):
        centre = world_H @ np.array([cx, cy, 1.0])
        centre = centre[:2] / centre[2]
        ground_scale = np.sqrt(abs(np.linalg.det(world_H[:2, :2])))
        # Heading toward the world centre when near the edges, else random.
        to_mid = np.array([ww / 2, wh / 2]) - centre
        margin = 0.5 * np.hypot(WIDTH, HEIGHT) * ground_scale + 80.0
        near_edge = (centre[0] < margin or centre[0] > ww - margin or centre[1] < margin or centre[1] > wh - margin)
        if near_edge:
            heading_world = np.arctan2(to_mid[1], to_mid[0]) + rng.normal(0, 0.3)
        else:
            heading_world = rng.uniform(0, 2 * np.pi)
        # Translation in frame pixels: rotate the world heading into the frame.
        frame_angle = np.arctan2(world_H[1, 0], world_H[0, 0])
        t = rng.uniform(*motion.t_px)
        tx, ty = t * np.cos(heading_world - frame_angle), t * np.sin(heading_world - frame_angle)
        rot = rng.uniform(*motion.rot_deg) * rng.choice([-1.0, 1.0])
        s = rng.uniform(*motion.scale)
        if ground_scale * s > 1.25 or (ground_scale / s >= 0.8 and rng.random() < 0.5):
            s = 1.0 / s
        delta = _similarity(rot, s, tx, ty, cx, cy)
        p = np.eye(3)
        p[2, :2] = rng.uniform(-motion.persp, motion.persp, 2)
        c = np.array([[1.0, 0, cx], [0, 1.0, cy], [0, 0, 1.0]])
        delta = delta @ c @ p @ np.linalg.inv(c)
        world_H = world_H @ delta
        world_H = world_H / world_H[2, 2]
        out.append(world_H)
    return out


def render(world: np.ndarray, world_H_frame: np.ndarray, rng: np.random.Generator, *,
           ir: bool) -> np.ndarray:
    """Frame pixel p shows world point world_H_frame @ p; EO -> RGB uint8, IR -> uint8 (H, W)."""
    # Pixel integration: render at SUPERSAMPLE x the resolution, then average SUPERSAMPLE**2 blocks.
    k = SUPERSAMPLE
    fine_from_frame = np.array([[k, 0.0, (k - 1) / 2.0], [0.0, k, (k - 1) / 2.0], [0.0, 0.0, 1.0]])
    world_H_fine = world_H_frame @ np.linalg.inv(fine_from_frame)
    fine = cv2.warpPerspective(world, world_H_fine, (WIDTH * k, HEIGHT * k),
                               flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT)
    frame = cv2.resize(fine, (WIDTH, HEIGHT), interpolation=cv2.INTER_AREA)
    if ir:
        gain, offset = 1.0 + rng.normal(0.0, 0.03), rng.normal(0.0, 0.01)   # automatic gain control drift
        frame = ((frame - 0.5) * gain + 0.5 + offset) * 255.0
    frame = frame + rng.normal(0.0, NOISE, frame.shape)
    return np.clip(frame + 0.5, 0, 255).astype(np.uint8)


def textureless(rng: np.random.Generator, kind: str) -> np.ndarray:
    """Sea (flat + noise + faint swell) or cloud (very smooth blobs + noise), uint8 RGB."""
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    if kind == 'sea':
        base = 90.0 + 1.5 * np.sin(xx / 37.0 + rng.uniform(0, 6)) * np.sin(yy / 23.0)
    else:
        base = cv2.GaussianBlur(rng.normal(0, 1, (HEIGHT, WIDTH)).astype(np.float32), (0, 0), 60.0)
        base = 200.0 + 15.0 * base / max(float(np.abs(base).max()), 1e-6)
    frame = base[..., None] + rng.normal(0.0, NOISE, (HEIGHT, WIDTH, 3))
    return np.clip(frame + 0.5, 0, 255).astype(np.uint8)


# --- methods ------------------------------------------------------------------------------------

class OpenCVBaseline:
    """SIFT (1000 features) + FLANN (kd-tree, ratio 0.8) + cv2.findHomography(USAC_MAGSAC)."""

    name = 'opencv-sift-magsac'

    def __init__(self, config: RegistrationConfig) -> None:
        self.config = config
        self.sift = cv2.SIFT_create(nfeatures=1000)
        self.flann = cv2.FlannBasedMatcher({'algorithm': 1, 'trees': 5}, {'checks': 50})

    def describe(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        kps, desc = self.sift.detectAndCompute(to_gray_u8(image), None)
        return np.array([k.pt for k in kps], np.float32).reshape(-1, 2), desc

    def register(self, prev, cur) -> tuple[bool, np.ndarray | None]:
        (pp, pd), (cp, cd) = prev, cur
        if pd is None or cd is None or len(pp) < 4 or len(cp) < 4:
            return False, None
        pairs = self.flann.knnMatch(cd, pd, k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < self.config.ratio * p[1].distance]
        if len(good) < self.config.min_inliers:
            return False, None
        src = cp[[m.queryIdx for m in good]]
        dst = pp[[m.trainIdx for m in good]]
        cfg = self.config
        h, mask = cv2.findHomography(src, dst, cv2.USAC_MAGSAC, cfg.ransac_threshold_px,
                                     maxIters=cfg.ransac_max_iterations, confidence=cfg.ransac_confidence)
        if h is None or mask is None or int(mask.sum()) < self.config.min_inliers:
            return False, h
        return True, h / h[2, 2]


class OpenCVBaselinePairs(OpenCVBaseline):
    """The same baseline without the feature cache: both frames of each pair are described."""

    name = 'opencv-sift-magsac, no cache'

    def describe(self, image: np.ndarray) -> np.ndarray:
        return image

    def register(self, prev, cur) -> tuple[bool, np.ndarray | None]:
        return super().register(super().describe(prev), super().describe(cur))


class Ours:
    def __init__(self, name: str, registrar: TorchRegistrar) -> None:
        self.name = name
        self.registrar = registrar

    def describe(self, image: np.ndarray):
        return self.registrar.describe(image)

    def register(self, prev, cur) -> tuple[bool, np.ndarray | None]:
        r = self.registrar.register(prev, cur)
        return r.ok, r.prev_H_cur


def _sync(device: torch.device) -> None:
    if device.type == 'cuda':
        torch.cuda.synchronize(device)


def run_methods(methods: list, frames: list[np.ndarray], truths: list[np.ndarray | None],
                device: torch.device, repeat: int = 1) -> list[dict]:
    """Describe every frame once, register each to the previous; time describe + register per frame.

    The methods take turns frame by frame, so that load changes on the machine hit them alike;
    with repeat > 1 each frame's describe + register is run that many times and the fastest
    counts (for shared machines, where other jobs come and go).
    """
    n = len(methods)
    times: list[list[float]] = [[] for _ in range(n)]
    errors: list[list[float]] = [[] for _ in range(n)]
    fails, wrong = [0] * n, [0] * n
    prev = [m.describe(frames[0]) for m in methods]
    for frame, truth in zip(frames[1:], truths[1:], strict=True):
        for i, m in enumerate(methods):
            best = float('inf')
            for _ in range(repeat):
                _sync(device)
                t0 = time.perf_counter()
                cur = m.describe(frame)
                ok, h = m.register(prev[i], cur)
                _sync(device)
                best = min(best, time.perf_counter() - t0)
            times[i].append(best)
            prev[i] = cur
            if not ok:
                fails[i] += 1
            elif truth is None:            # textureless: any ok is a silent failure
                wrong[i] += 1
            else:
                e = corner_error_px(h, truth, WIDTH, HEIGHT)
                if e > WRONG_PX:
                    wrong[i] += 1
                else:
                    errors[i].append(e)
    out = []
    for i in range(n):
        t = np.array(times[i]) * 1e3
        err = np.array(errors[i]) if errors[i] else np.array([np.nan])
        out.append({'median_ms': float(np.median(t)), 'p90_ms': float(np.percentile(t, 90)),
                    'fps': 1e3 / float(np.mean(t)), 'mean_err': float(np.mean(err)),
                    'p90_err': float(np.percentile(err, 90)) if errors[i] else float('nan'),
                    'fail': fails[i] / len(t), 'wrong': wrong[i] / len(t), 'n': len(t)})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--frames', type=int, default=40, help='frames per scenario (default 40)')
    ap.add_argument('--device', default='cpu', help='auto | cpu | cuda (default cpu)')
    ap.add_argument('--threads', type=int, default=2, help='torch and OpenCV threads (default 2)')
    ap.add_argument('--quick', action='store_true', help='12 frames per scenario')
    ap.add_argument('--no-baseline', action='store_true', help='skip the OpenCV baselines')
    ap.add_argument('--cuda-graphs', action='store_true',
                    help='on a GPU, replay describe as a CUDA graph (TorchRegistrarOptions.cuda_graphs)')
    ap.add_argument('--worlds', default='caliterra,brighton',
                    help=f'comma-separated orthophotos to fly over, of {", ".join(WORLDS)} (default both)')
    ap.add_argument('--repeat', type=int, default=1,
                    help='time each frame this many times and keep the fastest (shared machines; default 1)')
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    n = 12 if args.quick else args.frames
    config = RegistrationConfig()
    ours = TorchRegistrar(config, device=args.device, options=TorchRegistrarOptions(cuda_graphs=args.cuda_graphs))
    device = ours.device
    methods = [Ours(f'torch ({device.type})', ours),
               Ours(f'torch features only ({device.type})',
                    TorchRegistrar(config, device=device, options=TorchRegistrarOptions(
                        photometric=None, cuda_graphs=args.cuda_graphs)))]
    if not args.no_baseline:
        methods += [OpenCVBaseline(config), OpenCVBaselinePairs(config)]
    world_names = [w.strip() for w in args.worlds.split(',') if w.strip()]
    unknown = [w for w in world_names if w not in WORLDS]
    if unknown or not world_names:
        ap.error(f'unknown world(s) {unknown}; choose from {", ".join(WORLDS)}')
    t_start = time.perf_counter()
    scenarios: dict[str, tuple[list[np.ndarray], list[np.ndarray | None]]] = {}
    for wname in world_names:
        worlds = load_worlds(path=WORLDS[wname])
        shape = worlds['eo'].shape[:2]
        for i, (name, kind, motion) in enumerate([('eo-small', 'eo', SMALL), ('eo-large', 'eo', LARGE),
                                                  ('ir-small', 'ir', SMALL), ('ir-large', 'ir', LARGE),
                                                  ('eo-zoom', 'eo', ZOOM), ('ir-zoom', 'ir', ZOOM)]):
            poses = flight(shape, motion, n + 1, seed=100 + i)
            rng = np.random.default_rng(200 + i)
            frames = [render(worlds[kind], p, rng, ir=kind == 'ir') for p in poses]
            truths = [None] + [np.linalg.inv(a) @ b for a, b in zip(poses[:-1], poses[1:], strict=True)]
            scenarios[f'{wname[:5]}-{name}'] = (frames, [None if t is None else t / t[2, 2] for t in truths])
    rng = np.random.default_rng(300)
    tl = [textureless(rng, 'sea' if k % 2 else 'cloud') for k in range(max(6, n // 4) + 1)]
    scenarios['textureless'] = (tl, [None] * len(tl))
    # Warm-up (lazy initialisation, allocator, GPU kernels) on a few frames, untimed.
    warm_frames = next(iter(scenarios.values()))[0][:4]
    run_methods(methods, warm_frames, [None] * len(warm_frames), device)

    print(f'registration benchmark: {WIDTH}x{HEIGHT}, noise sigma {NOISE}/255, {n} frames per scenario, '
          f'device {device}, torch threads {torch.get_num_threads()}, torch {torch.__version__}, '
          f'OpenCV {cv2.__version__}, timing: fastest of {args.repeat} per frame')
    header = (f'{"method":<30} {"scenario":<16} {"med ms":>7} {"p90 ms":>7} {"fps":>6} {"mean err":>9} '
              f'{"p90 err":>8} {"fail":>6} {"wrong":>6}')
    print(header)
    print('-' * len(header))
    results: dict[tuple[str, str], dict] = {}
    for sname, (frames, truths) in scenarios.items():
        for m, r in zip(methods, run_methods(methods, frames, truths, device, args.repeat), strict=True):
            results[m.name, sname] = r
            print(f'{m.name:<30} {sname:<16} {r["median_ms"]:7.1f} {r["p90_ms"]:7.1f} {r["fps"]:6.1f} '
                  f'{r["mean_err"]:9.4f} {r["p90_err"]:8.4f} {100 * r["fail"]:5.1f}% {100 * r["wrong"]:5.1f}%',
                  flush=True)
    print()
    textured = [s for s in scenarios if s != 'textureless']
    groups = {w: [s for s in textured if s.startswith(w[:5])] for w in world_names}
    if len(world_names) > 1:
        groups['all worlds'] = textured
    for m in methods:
        for gname, subset in groups.items():
            rs = [results[m.name, s] for s in subset]
            frames_all = sum(r['n'] for r in rs)
            ms = sum(r['n'] * 1e3 / r['fps'] for r in rs) / frames_all
            err = np.nanmean([r['mean_err'] for r in rs])
            fail = sum(r['fail'] * r['n'] for r in rs) / frames_all
            wrong = sum(r['wrong'] * r['n'] for r in rs) / frames_all
            print(f'{m.name:<30} {gname:<10} {1e3 / ms:6.1f} fps, mean corner error {err:.4f} px, failures '
                  f'{100 * fail:.1f}%, wrong {100 * wrong:.1f}%')
        tl_r = results[m.name, 'textureless']
        print(f'{m.name:<30} textureless failed explicitly {100 * tl_r["fail"]:.0f}%')
    if not args.no_baseline:
        for base in (m.name for m in methods if m.name.startswith('opencv')):
            for m in (m for m in methods if not m.name.startswith('opencv')):
                for wname in world_names:
                    subset = [s for s in textured if s.startswith(wname[:5])]
                    ratios = [results[m.name, s]['fps'] / results[base, s]['fps'] for s in subset]
                    per = ', '.join(f'{s} {r:.1f}x' for s, r in zip(subset, ratios, strict=True))
                    gmean = float(np.exp(np.mean(np.log(ratios))))
                    print(f'speed ratio {m.name} / {base}, {wname}: {per}; geometric mean {gmean:.1f}x')
    print(f'bench wall time {time.perf_counter() - t_start:.0f} s')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
