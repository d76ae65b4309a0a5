"""Benchmark: what starting each node process costs before it does any work (CPU seconds, peak RSS).

Each executable's process imports its node module and what its main imports before spinning
(nodes/executables.py); this runs those imports in a fresh interpreter per repetition, and reads its
own ``resource.getrusage``, and reports the median CPU seconds (user + system) and the
peak resident set of each, and which heavy libraries each process loaded (torch, filterpy, scipy).

``--baseline DIR`` (a checkout of another commit, e.g. ``git worktree add /tmp/base main``) times
the same imports from that tree (PYTHONPATH first), interleaved with this one's, and prints the
ratios, so both are measured under the same load.

    python bench/import_weight.py [--repeat 5] [--baseline /tmp/base]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

#: executable -> the modules its process imports before it spins (run_* in nodes/executables.py)
PROCESSES = {
    'georef_node': ['srmosaic_ros.nodes.georef_node', 'srmosaic_ros.nodes.runner'],
    'map_server': ['srmosaic_ros.nodes.map_server', 'srmosaic_ros.nodes.runner', 'srmosaic_ros.web.server'],
    'tile_recorder': ['srmosaic_ros.nodes.tile_recorder', 'srmosaic_ros.nodes.runner', 'srmosaic_ros.io.output_dir'],
    'mosaic_node': ['srmosaic_ros.nodes.mosaic_node', 'srmosaic_ros.nodes.runner'],
}
HEAVY = ('torch', 'filterpy', 'scipy')
_PROBE = ('import importlib, json, resource, sys\n'
          'for m in sys.argv[1:]: importlib.import_module(m)\n'
          'u = resource.getrusage(resource.RUSAGE_SELF)\n'
          'print(json.dumps([u.ru_utime + u.ru_stime, u.ru_maxrss / 1024.0, [h for h in {heavy!r} if h in sys.modules]]))\n')


def measure(modules: list[str], tree: Path | None) -> tuple[float, float, list[str]]:
    """(CPU s user + system, peak RSS MiB, heavy libraries loaded) of one fresh interpreter importing ``modules``
    (its own getrusage at the end: the interpreter's start included)."""
    env = dict(os.environ, OMP_NUM_THREADS='1')
    if tree is not None:
        env['PYTHONPATH'] = os.pathsep.join([str(tree), env.get('PYTHONPATH', '')]).rstrip(os.pathsep)
    out = subprocess.run([sys.executable, '-c', _PROBE.format(heavy=HEAVY), *modules], env=env, check=True,
                         capture_output=True, text=True, cwd=str(tree) if tree else None).stdout
    cpu, rss, heavy = json.loads(out.splitlines()[-1])
    return float(cpu), float(rss), list(heavy)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeat', type=int, default=5, help='fresh interpreters per process and tree (median)')
    parser.add_argument('--baseline', type=Path, default=None, help='another checkout to compare with (same run)')
    args = parser.parse_args()
    trees: list[tuple[str, Path | None]] = [('this', None)] + ([('baseline', args.baseline.resolve())] if args.baseline else [])
    results: dict[str, dict[str, dict[str, object]]] = {}
    for name, modules in PROCESSES.items():
        cpu: dict[str, list[float]] = {t: [] for t, _ in trees}
        rss: dict[str, list[float]] = {t: [] for t, _ in trees}
        heavy: dict[str, list[str]] = {}
        for _ in range(args.repeat):
            for label, tree in trees:  # interleaved: both trees see the same load
                c, r, h = measure(modules, tree)
                cpu[label].append(c)
                rss[label].append(r)
                heavy[label] = h
        results[name] = {label: {'cpu_s': statistics.median(cpu[label]), 'peak_rss_mib': statistics.median(rss[label]),
                                 'heavy': heavy[label]} for label, _ in trees}
    print(f"{'process':<14} {'tree':<9} {'CPU s':>6} {'RSS MiB':>8}  heavy imports")
    for name, per_tree in results.items():
        for label, r in per_tree.items():
            print(f"{name:<14} {label:<9} {r['cpu_s']:6.2f} {r['peak_rss_mib']:8.0f}  {', '.join(r['heavy']) or '-'}")
        if 'baseline' in per_tree:
            b, t = per_tree['baseline'], per_tree['this']
            print(f"{'':<14} {'ratio':<9} {t['cpu_s'] / b['cpu_s']:6.2f} {t['peak_rss_mib'] / b['peak_rss_mib']:8.2f}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
