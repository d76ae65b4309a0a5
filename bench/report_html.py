"""Benchmark: what report.html costs a `srmosaic process` run (app/run_report.py).

Runs `srmosaic process INPUT --out DIR` (a child process, as a user would) ``--runs`` times and prints,
per run and as medians, from report.json: the page's own time (``report_html.time_s``, after its
matplotlib import and first figure were warmed on a thread during the mosaic files' writing), the
``outputs`` stage in all (mosaic files and page), the run's wall time, and the page's share of each;
and the page's size. The ratios, not the seconds, are what compare across hosts.

    python bench/report_html.py [INPUT] [--runs 3] [--work bench/out/report_html]

INPUT defaults to the bundled demo bag (bags/demo).
"""
from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('input', nargs='?', default=str(REPO / 'bags' / 'demo'))
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--work', default=str(REPO / 'bench' / 'out' / 'report_html'))
    args = parser.parse_args()
    out = Path(args.work) / 'run'
    rows = []
    for k in range(args.runs):
        shutil.rmtree(out, ignore_errors=True)
        subprocess.run([sys.executable, '-m', 'srmosaic_ros.cli', 'process', args.input, '--out', str(out),
                        '--no-progress'], check=True, capture_output=True, text=True)
        report = json.loads((out / 'report.json').read_text())
        page = report['report_html']['time_s']
        outputs = (report.get('stage_times') or {}).get('outputs', {}).get('total_s', float('nan'))
        rows.append((page, outputs, report['wall_s'], (out / 'report.html').stat().st_size / 1024))
        print(f'run {k + 1}: page {page:.3f} s, outputs {outputs:.3f} s, wall {report["wall_s"]:.3f} s; page / outputs '
              f'{page / outputs:.2f}, page / wall {page / report["wall_s"]:.3f}; {rows[-1][3]:.0f} KB, '
              f'{report["report_html"]["figures"]} figures')
    page, outputs, wall, kb = (statistics.median(c) for c in zip(*rows))
    print(f'median: page {page:.3f} s, outputs {outputs:.3f} s, wall {wall:.3f} s; page / outputs {page / outputs:.2f}, '
          f'page / wall {page / wall:.3f}; {kb:.0f} KB')


if __name__ == '__main__':
    main()
