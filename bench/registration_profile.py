"""Where the time of one frame's registration goes: per-stage wall time and tensor ops, on the CPU or a GPU.

The torch registrar's stages (describe: luminance, pyramid, detection, descriptors, photometric
templates; register: putative matching, RANSAC, guided matching, Levenberg-Marquardt, photometric
refinement, plausibility checks) are timed by wrapping the functions the registrar calls (on a GPU
with a device synchronisation after each, so that a stage's kernels are charged to it; the
synchronisations themselves slow the GPU run a little: bench/registration.py gives the plain
figure). Then one profiled pass counts, per frame, the operators torch dispatched (top-level aten
ops: what costs a kernel launch each on a GPU, where a 640x480 frame is launch-bound) and, on a
GPU, the CUDA kernels launched and the host-device synchronisations (aten::_local_scalar_dense and
aten::nonzero; each one waits for the queue to drain).

Frames: a textured synthetic flight (brighton) at 640x480 as in bench/registration.py (EO, small
motion, noise sigma 2).

    python bench/registration_profile.py [--device cpu|cuda] [--frames 30] [--threads 2] [--cuda-graphs]
"""
from __future__ import annotations

import argparse
import collections
import functools
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'bench'))

import registration as flights  # bench/registration.py: the same synthetic frames

from srmosaic_ros.core.registration import RegistrationConfig
from srmosaic_ros.core.registration import static_describe, torch_registrar

#: (module, function, stage label): the functions TorchRegistrar calls, in the order of a frame.
STAGES = [
    (torch_registrar, 'image_to_gray_tensor', 'describe: luminance'),
    (torch_registrar, 'build_pyramid', 'describe: pyramid'),
    (torch_registrar, 'detect', 'describe: DoH detection'),
    (torch_registrar, 'describe_candidates', 'describe: orientation + descriptors'),
    (torch_registrar, 'make_template', 'describe: photometric templates'),
    (static_describe.StaticDescriber, 'run', 'describe: fixed shapes (all of it)'),
    (torch_registrar, 'descriptor_sq_distances', 'register: descriptor distances'),
    (torch_registrar, 'mutual_ratio_matches', 'register: mutual ratio matches'),
    (torch_registrar, 'ransac_homography', 'register: RANSAC'),
    (torch_registrar, 'dlt_homography', 'register: DLT'),
    (torch_registrar, 'guided_matches', 'register: guided matching'),
    (torch_registrar, 'refine_lm', 'register: Levenberg-Marquardt'),
    (torch_registrar, 'refine_photometric', 'register: photometric refinement'),
    (torch_registrar, 'homography_covariance_ut', 'register: UT covariance'),
    (torch_registrar, 'check_homography', 'register: plausibility checks'),
]
SYNC_OPS = ('aten::_local_scalar_dense', 'aten::nonzero')


def _wrap(times: dict[str, float], counts: collections.Counter, device: torch.device) -> list:
    """Wrap the stage functions (returns what to restore)."""
    saved = []
    for mod, name, label in STAGES:
        f = getattr(mod, name)
        saved.append((mod, name, f))

        @functools.wraps(f)
        def timed(*a, _f=f, _label=label, **k):
            if device.type == 'cuda':
                torch.cuda.synchronize(device)
            t0 = time.perf_counter()
            out = _f(*a, **k)
            if device.type == 'cuda':
                torch.cuda.synchronize(device)
            times[_label] += time.perf_counter() - t0
            counts[_label] += 1
            return out

        setattr(mod, name, timed)
    return saved


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--device', default='cpu')
    ap.add_argument('--frames', type=int, default=30)
    ap.add_argument('--threads', type=int, default=2)
    ap.add_argument('--cuda-graphs', action='store_true', help='replay describe as a CUDA graph')
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    worlds = flights.load_worlds(path=flights.WORLDS['brighton'])
    poses = flights.flight(worlds['eo'].shape[:2], flights.SMALL, args.frames + 3, seed=100)
    rng = np.random.default_rng(200)
    frames = [flights.render(worlds['eo'], p, rng, ir=False) for p in poses]
    reg = torch_registrar.TorchRegistrar(RegistrationConfig(), device=args.device,
                                         options=torch_registrar.TorchRegistrarOptions(cuda_graphs=args.cuda_graphs))
    dev = reg.device
    prev = reg.describe(frames[0])
    for f in frames[1:3]:  # warm-up (allocator, kernels, caches)
        cur = reg.describe(f)
        reg.register(prev, cur)
        prev = cur
    times: dict[str, float] = collections.defaultdict(float)
    counts: collections.Counter = collections.Counter()
    saved = _wrap(times, counts, dev)
    n = len(frames) - 3
    try:
        t0 = time.perf_counter()
        for f in frames[3:]:
            cur = reg.describe(f)
            reg.register(prev, cur)
            prev = cur
        wall = time.perf_counter() - t0
    finally:
        for mod, name, f in saved:
            setattr(mod, name, f)
    what = torch.cuda.get_device_name(dev) if dev.type == 'cuda' else f'{torch.get_num_threads()} CPU threads'
    print(f'registration profile: {n} frames 640x480 (brighton, EO, small motion), device {dev} ({what}), '
          f'torch {torch.__version__}')
    print(f'describe + register: {1e3 * wall / n:.2f} ms per frame with a synchronisation after each stage')
    print('| stage | ms per frame | calls per frame |\n|---|---|---|')
    for _, _, label in STAGES:
        if counts[label]:
            print(f'| {label} | {1e3 * times[label] / n:.2f} | {counts[label] / n:.1f} |')
    staged = sum(times.values())
    print(f'| (outside the stages: glue, transfers, Python) | {1e3 * (wall - staged) / n:.2f} | |')

    from torch.profiler import ProfilerActivity, profile

    acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if dev.type == 'cuda' else [])
    k = min(n, 10)
    with profile(activities=acts) as prof:
        for f in frames[3:3 + k]:
            cur = reg.describe(f)
            reg.register(prev, cur)
            prev = cur
        if dev.type == 'cuda':
            torch.cuda.synchronize(dev)
    top = collections.Counter(e.name for e in prof.events() if e.cpu_parent is None and e.name.startswith('aten::'))
    views = {'aten::slice', 'aten::select', 'aten::view', 'aten::unsqueeze', 'aten::reshape', 'aten::narrow',
             'aten::transpose', 'aten::t', 'aten::permute', 'aten::expand', 'aten::squeeze', 'aten::as_strided',
             'aten::alias', 'aten::lift_fresh', 'aten::detach', 'aten::numpy_T'}
    syncs = sum(e.count for e in prof.key_averages() if e.key in SYNC_OPS)
    print(f'\nper frame (profiled pass of {k} frames): {sum(top.values()) / k:.0f} top-level aten ops, '
          f'{sum(v for op, v in top.items() if op not in views) / k:.0f} of them not views; '
          f'{syncs / k:.0f} host-device synchronisation points ({", ".join(SYNC_OPS)})')
    if dev.type == 'cuda':
        kernels = sum(1 for e in prof.events() if e.device_type == torch.autograd.DeviceType.CUDA)
        print(f'CUDA kernels and copies launched per frame: {kernels / k:.0f}')
    print('most frequent ops per frame:', ', '.join(f'{op[6:]} {v / k:.0f}' for op, v in top.most_common(12)))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
