"""Seconds per test file of a whole run, for test/suite_order.py: the order `make test` starts the files in.

    .venv/bin/python -m pytest -n 3 --dist loadfile --junitxml /tmp/suite.xml
    .venv/bin/python bench/suite_costs.py /tmp/suite.xml   # writes test/file_costs.json

Each file's seconds are the sum of its tests' times (setup, call and teardown, as the junit report
gives them), module fixtures included.
"""
from __future__ import annotations

import argparse
import json
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def costs_from_junit(path: Path) -> dict[str, float]:
    """{test file path: seconds} from a pytest junit XML report."""
    seconds: dict[str, float] = defaultdict(float)
    for case in ET.parse(path).getroot().iter('testcase'):
        module = case.get('classname', '').split('.')
        # classname is the dotted path of the file (and class); the file is the longest prefix that exists
        for n in range(len(module), 0, -1):
            candidate = '/'.join(module[:n]) + '.py'
            if (REPO / candidate).exists():
                seconds[candidate] += float(case.get('time', 0.0))
                break
    return dict(seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('junit', type=Path, help='pytest --junitxml report of a whole run')
    parser.add_argument('--out', type=Path, default=REPO / 'test' / 'file_costs.json')
    args = parser.parse_args()
    costs = costs_from_junit(args.junit)
    ordered = dict(sorted(((k, round(v, 1)) for k, v in costs.items()), key=lambda kv: -kv[1]))
    args.out.write_text(json.dumps({'about': 'seconds per test file in one whole run (bench/suite_costs.py); '
                                    'test/suite_order.py starts the longest first', 'seconds': ordered}, indent=1) + '\n')
    print(f'{len(ordered)} files, {sum(ordered.values()):.0f} s in all -> {args.out}')


if __name__ == '__main__':
    main()
