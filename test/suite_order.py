"""The order test files start in: the longest first, so that no long file starts last.

`make test` runs the files on pytest-xdist workers, a whole file per worker (``--dist loadfile``), in
collection order (``--no-loadscope-reorder``). Started last, a file of a few long tests (a DDS graph,
a whole run) is the run's tail while the other workers sit idle; started first, it overlaps the many
short files. Longest-first is the classic greedy schedule (LPT) for that. The costs are each file's
seconds in a whole run, measured by ``bench/suite_costs.py`` into test/file_costs.json; a file not
listed there (a new one) counts as a short one.
"""
from __future__ import annotations

import json
from pathlib import Path

import pytest

COSTS = Path(__file__).with_name('file_costs.json')
NEW_FILE_S = 5.0  # a file the costs do not list yet: started among the short ones


def file_costs() -> dict[str, float]:
    """Seconds per test file (its path from the repository root, '/' separated)."""
    return json.loads(COSTS.read_text())['seconds'] if COSTS.exists() else {}


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    costs = file_costs()
    first_seen: dict[str, int] = {}
    for item in items:
        first_seen.setdefault(item.nodeid.split('::')[0], len(first_seen))
    # sort by file, longest first, keeping each file's own test order (and collection order among equals)
    items.sort(key=lambda item: (-costs.get(item.nodeid.split('::')[0], NEW_FILE_S), first_seen[item.nodeid.split('::')[0]]))
