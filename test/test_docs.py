"""The documentation stays true: the generated reference pages are current and complete, the
parameter files and the nodes' declarations agree, the command line's help matches its reference,
and the getting-started page's commands run on the demo as shown.

docs/reference/*.md are written by `python -m srmosaic_ros.docs_reference` (make reference); the
site itself is built by `make docs` (mkdocs build --strict), which `make test` runs before pytest.
"""
from __future__ import annotations

import argparse
import math
import re
import shlex
import subprocess
import sys

import pytest

from repo_paths import REPO

REFERENCE = REPO / 'docs' / 'reference'
PARAM_FILES = sorted((REPO / 'params').glob('*.yaml'))
#: Keys no node declares: stills surveys are offline only (srmosaic process FOLDER).
OFFLINE_ONLY_PREFIXES = ('survey.',)


@pytest.fixture(scope='module')
def interfaces():
    """Every node built once in a private ROS context and asked what it declares."""
    from srmosaic_ros.docs_reference import node_interfaces

    return node_interfaces()


def test_reference_pages_are_what_the_generator_writes(interfaces, tmp_path):
    from srmosaic_ros.docs_reference import write_reference

    pages = write_reference(tmp_path, interfaces)
    for path, text in pages.items():
        committed = REFERENCE / path.name
        assert committed.is_file(), f'{committed} is missing: run `make reference`'
        assert committed.read_text() == text, f'{committed} is stale: run `make reference` and commit it'


def _code_names(page: str) -> set[str]:
    return set(re.findall(r'`([^`]+)`', (REFERENCE / page).read_text()))


@pytest.mark.parametrize('path', PARAM_FILES, ids=[p.name for p in PARAM_FILES])
def test_every_parameter_is_in_the_reference(path):
    from srmosaic_ros.param_files import load_params

    documented = _code_names('parameters.md')
    missing = sorted(set(load_params(path)) - documented)
    assert not missing, f'{path.name}: {missing} missing from docs/reference/parameters.md (run `make reference`)'


def test_every_topic_of_every_node_is_in_the_reference(interfaces):
    from srmosaic_ros.docs_reference import TOPIC_DOCS
    from srmosaic_ros.nodes.common import DIAGNOSTICS_TOPICS, TOPICS

    text = (REFERENCE / 'nodes.md').read_text()
    sections = dict(re.findall(r'^## (\S+)\n(.*?)(?=^## |\Z)', text, flags=re.S | re.M))
    for info in interfaces:
        assert info.executable in sections, f'{info.executable} has no section in docs/reference/nodes.md'
        section = sections[info.executable]
        for kind, tables in (('publishes', info.publishers), ('subscribes to', info.subscriptions)):
            for topics in tables.values():
                for topic in topics:
                    assert f'`{topic}`' in section, (f'{info.executable} {kind} {topic}, which its section of '
                                                     'docs/reference/nodes.md does not name')
                    assert TOPIC_DOCS.get(topic), f'{topic} has no description in docs_reference.TOPIC_DOCS'
    graph = {'/' + name for name in TOPICS.values()} | {'/' + name.lstrip('/') for name in DIAGNOSTICS_TOPICS}
    assert not graph - set(re.findall(r'`(/[^`]+)`', text)), graph - set(re.findall(r'`(/[^`]+)`', text))


def test_yaml_defaults_and_the_nodes_declared_parameters_agree(interfaces):
    """Every key of params/default.yaml and advanced.yaml is declared by a node (surveys excepted) with
    the YAML's default, inside the range the node declares, and nothing else of the pipeline is declared."""
    from srmosaic_ros.param_files import default_params

    defaults = default_params()
    declared: dict[str, list[str]] = {}
    for info in interfaces:
        for name, param in info.parameters.items():
            declared.setdefault(name, []).append(info.executable)
            if name in info.overrides:
                continue  # set here only to build the node without a worker process
            assert name in defaults, f'{info.executable} declares {name}, which no parameter file holds'
            want, got = defaults[name], param.value
            same = (list(got) == list(want) if isinstance(want, list) else
                    (math.isnan(want) and math.isnan(got)) if isinstance(want, float) and math.isnan(want) else
                    got == want and type(got) is type(want))
            assert same, f'{info.executable}: {name} declared as {got!r}, params/*.yaml say {want!r}'
            if param.range is not None:
                lo, hi = param.range
                assert lo <= want <= hi, f'{name}: the default {want!r} is outside the declared range {lo}..{hi}'
    undeclared = sorted(k for k in defaults if k not in declared and not k.startswith(OFFLINE_ONLY_PREFIXES))
    assert not undeclared, f'keys no node declares: {undeclared}'


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    from srmosaic_ros.cli import build_parser

    parser = build_parser()
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices


def test_every_subcommand_and_option_is_in_the_cli_reference():
    text = (REFERENCE / 'cli.md').read_text()
    for name, sub in _subcommands().items():
        assert f'## srmosaic {name}\n' in text, f'srmosaic {name} missing from docs/reference/cli.md'
        section = text.split(f'## srmosaic {name}\n', 1)[1].split('\n## ', 1)[0]
        for action in sub._actions:
            for option in action.option_strings:
                if option not in ('-h', '--help'):
                    assert f'`{option}`' in section, f'srmosaic {name} {option} missing from docs/reference/cli.md'


def test_every_subcommand_is_named_in_the_user_pages():
    pages = '\n'.join(p.read_text() for p in (REPO / 'docs').rglob('*.md') if p.parent.name != 'reference')
    for name in _subcommands():
        assert f'srmosaic {name}' in pages, f'no page but the reference shows `srmosaic {name}`'


def test_process_help_names_every_input_kind():
    help_text = ' '.join(_subcommands()['process'].format_help().split())
    for kind in ('rosbag2 folder', 'ROS 1', 'video', 'KLV', '.SRT', 'GPMF', 'folder of stills'):
        assert kind in help_text, f'`srmosaic process --help` does not name {kind!r}'


def _marked_block(text: str, marker: str) -> list[str]:
    """The lines of the fenced block right after the HTML comment that starts with `marker`."""
    m = re.search(rf'<!-- {marker}[^>]*-->\n```\w*\n(.*?)\n```', text, flags=re.S)
    assert m, f'docs/getting-started.md has no block marked <!-- {marker} -->'
    return [line for line in m.group(1).splitlines() if line.strip()]


def _shape(line: str) -> str:
    return re.sub(r'\d+(\.\d+)?', '#', line)


def test_getting_started_commands_run_on_the_demo(tmp_path):
    """The page's commands, as written, with out/ in a temporary folder; evaluate prints the lines
    the page shows (numbers may differ) and the demo's 60 of 60 frames."""
    text = (REPO / 'docs' / 'getting-started.md').read_text()
    commands = _marked_block(text, 'test:')
    shown = _marked_block(text, 'output:')
    outputs = []
    for command in commands:
        argv = shlex.split(command.split('#', 1)[0])
        assert argv[0] == '.venv/bin/srmosaic', command
        argv = [sys.executable, '-m', 'srmosaic_ros.cli', *(a.replace('out/', f'{tmp_path}/', 1) if a.startswith('out/')
                                                             else a for a in argv[1:])]
        done = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, f'{command}\n{done.stdout}\n{done.stderr}'
        outputs.append(done.stdout)
    printed = outputs[-1].splitlines()
    assert [_shape(line) for line in printed] == [_shape(line) for line in shown], '\n'.join(printed)
    assert printed[0].startswith('frames registered: 60/60'), printed[0]
    assert (tmp_path / 'demo' / 'mosaic.tif').is_file()
