"""The order test files start in: the longest first, so that no long file starts last, and the files
of DDS graphs taking turns with the others.

`make test` runs the files on pytest-xdist workers, a whole file per worker (``--dist loadfile``), in
collection order (``--no-loadscope-reorder``). Started last, a file of a few long tests (a DDS graph,
a whole run) is the run's tail while the other workers sit idle; started first, it overlaps the many
short files. Longest-first is the classic greedy schedule (LPT) for that. The files of test/nodes
spend most of their time waiting on messages between processes: taking turns with the files that
compute, they keep the cores busy, where all of them at once would leave the cores idle and all
the others at once would starve the graphs of CPU. The costs are each file's seconds in a whole
run, measured by ``bench/suite_costs.py`` into test/file_costs.json; a file not listed there (a new
one) counts as a short one.
"""
from __future__ import annotations

import json
from pathlib import Path

import pytest

COSTS = Path(__file__).with_name('file_costs.json')
NEW_FILE_S = 5.0  # a file the costs do not list yet: started among the short ones
GRAPH_FILES = 'test/nodes/'  # the files that run DDS graphs


def file_costs() -> dict[str, float]:
    """Seconds per test file (its path from the repository root, '/' separated)."""
    return json.loads(COSTS.read_text())['seconds'] if COSTS.exists() else {}


def start_order(files: list[str], costs: dict[str, float]) -> list[str]:
    """``files`` longest first, a graph file and then one that computes, in turns, until one kind runs out."""
    by_cost = sorted(files, key=lambda f: -costs.get(f, NEW_FILE_S))  # stable: collection order among equals
    graphs = [f for f in by_cost if f.startswith(GRAPH_FILES)]
    others = [f for f in by_cost if not f.startswith(GRAPH_FILES)]
    order: list[str] = []
    while graphs or others:
        order += [queue.pop(0) for queue in (graphs, others) if queue]
    return order


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    files = list(dict.fromkeys(item.nodeid.split('::')[0] for item in items))
    rank = {f: k for k, f in enumerate(start_order(files, file_costs()))}
    items.sort(key=lambda item: rank[item.nodeid.split('::')[0]])  # stable: each file keeps its own test order
