"""The package's layers import one way, and no module imports itself back through others.

    core (pure algorithm, and errors)  <-  io, msg_adapters (files, bags, messages)
        <-  pipeline (pipeline, config, sim)  <-  live/ (sr, raster)
        <-  app/ (process, sr_process, evaluate, survey, ...), web/ (tiles, page, map server)  <-  nodes/, cli

Every import statement counts, the lazy ones inside functions too (a lazy import hides a circle,
it does not remove it); those under ``if TYPE_CHECKING:`` (annotations only) do not.
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ('srmosaic_ros', 'msg_adapters')

#: Layer of a module: the first matching prefix wins (dotted module names). Every module must have one:
#: a new top-level module goes into a layer's folder (core/, io/, live/, app/, nodes/) or here.
LAYERS = [
    ('srmosaic_ros.errors', 0), ('srmosaic_ros.bounded_yaml', 0), ('srmosaic_ros.core', 0),
    ('srmosaic_ros.io', 1), ('msg_adapters', 1),
    ('srmosaic_ros.pipeline', 2), ('srmosaic_ros.config', 2), ('srmosaic_ros.param_files', 2),
    ('srmosaic_ros.malloc_tuning', 2), ('srmosaic_ros.sim', 2),
    ('srmosaic_ros.live', 3),
    ('srmosaic_ros.web', 4),  # tiles, the page and the map server: reads outputs (io) and the live raster (live)
    ('srmosaic_ros.app', 4),  # process, sr_process, evaluate*, survey, psf, checkpoint, georeference, inspect_tool
    ('srmosaic_ros.nodes', 5), ('srmosaic_ros.cli', 5),
    ('srmosaic_ros.docs_reference', 5),  # the generated reference pages: reads the nodes and the command line
]
NAMES = {0: 'core', 1: 'io', 2: 'pipeline', 3: 'live', 4: 'app', 5: 'nodes/cli'}


def layer(module: str) -> int:
    if module == 'srmosaic_ros':  # the package's __init__ (its version only)
        return 0
    for prefix, rank in LAYERS:
        if module == prefix or module.startswith(prefix + '.'):
            return rank
    raise AssertionError(f'no layer for {module}')


def modules() -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob('*.py')):
            parts = list(path.relative_to(ROOT).with_suffix('').parts)
            if parts[-1] == '__init__':
                parts = parts[:-1]
            out['.'.join(parts)] = path
    return out


def imports_of(name: str, path: Path, known: dict[str, Path], *, typing: bool = False) -> set[str]:
    """The package modules ``name`` imports (absolute names; a name imported from a package that is
    a module of it counts as that module); with ``typing``, those under ``if TYPE_CHECKING:`` too."""
    is_package = path.name == '__init__.py'
    base = name.split('.') if is_package else name.split('.')[:-1]
    found = set()
    tree = ast.parse(path.read_text())
    typing_only = {id(inner) for block in ast.walk(tree) if isinstance(block, ast.If) and _is_type_checking(block.test)
                   for stmt in block.body for inner in ast.walk(stmt)} if not typing else set()  # not imported when run
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        targets = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = base[:len(base) - (node.level - 1)] if node.level > 1 else base
                mod = '.'.join(anchor + ([node.module] if node.module else []))
            else:
                mod = node.module or ''
            targets = [f'{mod}.{alias.name}' if f'{mod}.{alias.name}' in known else mod for alias in node.names]
        for target in targets:
            while target and target not in known:
                target = target.rpartition('.')[0]
            if target and target != name and target.split('.')[0] in PACKAGES:
                found.add(target)
    return found


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == 'TYPE_CHECKING') or \
        (isinstance(test, ast.Attribute) and test.attr == 'TYPE_CHECKING')


def graph(*, typing: bool = False) -> dict[str, set[str]]:
    known = modules()
    return {name: imports_of(name, path, known, typing=typing) for name, path in known.items()}


def test_no_import_from_a_higher_layer():
    wrong = [f'{a} ({NAMES[layer(a)]}) imports {b} ({NAMES[layer(b)]})'
             for a, targets in graph().items() for b in sorted(targets)
             # a package's __init__ gathers its own modules
             if layer(b) > layer(a) and not b.startswith(a + '.')]
    assert not wrong, 'imports against the layers:\n' + '\n'.join(wrong)


def test_no_import_circles():
    # annotation-only imports count here too: two modules that name each other's types are one concern
    # split in the wrong place
    g = graph(typing=True)
    # a package __init__ importing its modules, which import siblings through the package, is not a circle
    edges = {a: {b for b in targets if not (a.startswith(b + '.') and (ROOT / Path(*b.split('.')) / '__init__.py').is_file())}
             for a, targets in g.items()}
    circles, state, stack = [], {}, []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(edges.get(node, ())):
            if state.get(nxt) == 1:
                circles.append(' -> '.join(stack[stack.index(nxt):] + [nxt]))
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for node in sorted(edges):
        if node not in state:
            visit(node)
    assert not circles, 'import circles:\n' + '\n'.join(circles)
