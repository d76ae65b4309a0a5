"""`srmosaic launch`: start the graph, in one process or several (the stand-in for ros2 launch).

A ROS 2 launch file, `srmosaic launch launch/srmosaic.launch.xml namespace:=uav1 sr:=false`, starts
each of its nodes as a child process, as `ros2 launch srmosaic_ros srmosaic.launch.xml ...` does
(launch_xml.py says which part of the XML language it reads).

Nodes: mosaic (registration and mosaic; by default also the georeferencing filter), georef (the
filter in its own process; active when live.georef_standalone is true, idle otherwise), sr (SR
tiles on /srmosaic/sr_tile), and with the launch file's `map:=true` the map server (the live web
map, nodes/map_server.py). With no description, every node runs in this process with
params/default.yaml on the default topics; with launch arguments and no description
(`srmosaic launch map:=true`), the installed launch/srmosaic.launch.xml runs. A description is a YAML file:

    processes:
      - name: onboard                       # a label for logs
        nodes: [mosaic]                     # names from NODES
        params: [params/eo_camera.yaml]     # parameter files, applied after params/default.yaml
        parameters: {live.output_dir: /tmp/run}   # single overrides (-p name:=value)
        remappings: {/camera/image_raw: /cam0/image_raw}
      - name: ground
        nodes: [georef, sr]

Each process of a description is a child `srmosaic node ...`; --params FILE and --ros-args given
to `srmosaic launch` apply to every child. Ctrl-C (SIGINT) or SIGTERM is forwarded to all of them
and the launcher waits for their clean shutdown (a second one kills those still running); when one
child fails, the others are stopped.
"""
from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from ..bounded_yaml import load_bounded
from ..param_files import default_params_path, load_params, yaml_problem
from ..errors import ConfigError
from .launch_xml import LaunchNode, parse_launch_arguments, read_launch_xml
from .override_check import EXECUTABLE_KINDS, check_overrides, parse_overrides

__all__ = ['NODES', 'load_description', 'node_command', 'xml_node_command', 'launch']


def _node_classes() -> dict[str, type]:
    from .georef_node import GeorefNode
    from .mosaic_node import MosaicNode
    from .sr_node import SRNode

    return {'mosaic': MosaicNode, 'georef': GeorefNode, 'sr': SRNode}


#: The nodes of the graph: mosaic (registration + mosaic, and by default the georeferencing filter),
#: georef (the filter in a process of its own, active with live.georef_standalone: true), sr (SR tiles).
NODES = ('mosaic', 'georef', 'sr')


def load_description(path: Path) -> list[dict[str, Any]]:
    """Validate a launch description; returns its processes."""
    try:
        doc = load_bounded(Path(path).read_text())
    except FileNotFoundError:
        msg = f'launch description {path} does not exist.'
        raise ConfigError(msg) from None
    except yaml.YAMLError as exc:
        msg = f'launch description {path} is not valid YAML: {yaml_problem(exc)}'
        raise ConfigError(msg) from None
    if not isinstance(doc, dict) or not isinstance(doc.get('processes'), list) or not doc['processes']:
        msg = f'launch description {path} needs a non-empty list `processes:` (see `srmosaic launch --help`).'
        raise ConfigError(msg)
    known = {'name', 'nodes', 'params', 'parameters', 'remappings'}
    for i, proc in enumerate(doc['processes']):
        if not isinstance(proc, dict):
            msg = f'{path}: process {i} must be a mapping with nodes: [...]'
            raise ConfigError(msg)
        if unknown := set(proc) - known:
            msg = f'{path}: process {i} has unknown keys {sorted(unknown)}; known: {sorted(known)}.'
            raise ConfigError(msg)
        nodes = proc.get('nodes') or []
        if not nodes or any(n not in NODES for n in nodes):
            msg = f'{path}: process {i} nodes {nodes} must be a non-empty list of {list(NODES)}.'
            raise ConfigError(msg)
        for f in proc.get('params') or []:
            if not Path(f).is_file():
                msg = f'{path}: process {i} parameter file {f} does not exist.'
                raise ConfigError(msg)
            load_params(f)  # its YAML checked here, not by rcl in a child after the others started
    return doc['processes']


def ros_args(params: list[str], parameters: dict[str, Any] | None = None,
             remappings: dict[str, str] | None = None) -> list[str]:
    """--ros-args for params/default.yaml, then the given files, overrides and remappings."""
    args = ['--ros-args', '--params-file', str(default_params_path())]
    for f in params:
        args += ['--params-file', str(f)]
    for k, v in (parameters or {}).items():
        args += ['-p', f'{k}:={v}']
    for a, b in (remappings or {}).items():
        args += ['-r', f'{a}:={b}']
    return args


def overrides_last(ros_arguments: list[str], folder: Path) -> list[str]:
    """The same --ros-args with every ``-p name:=value`` (``--param``) moved into a parameter file
    written into ``folder`` and given last. rcl lets a --params-file beat a -p override whatever
    their order, so `srmosaic launch --ros-args -p registration.max_features:=lots` would keep the
    file's value without a word; as the last file the override wins, and a value of the wrong type
    ('lots', a quoted "false") is refused by the node at start. Values are read as YAML, as rcl reads -p."""
    import yaml

    rest, tree = [], {}
    args = [a for a in ros_arguments if a != '--ros-args']
    i = 0
    while i < len(args):
        if args[i] in ('-p', '--param') and i + 1 < len(args) and ':=' in args[i + 1]:
            name, _, text = args[i + 1].partition(':=')
            node = tree
            *parents, leaf = name.split('.')
            for part in parents:
                node = node.setdefault(part, {})
            node[leaf] = load_bounded(text) if text else ''
            i += 2
            continue
        rest.append(args[i])
        i += 1
    if not tree:
        return rest
    path = folder / 'command_line_overrides.yaml'
    path.write_text(yaml.safe_dump({'/**': {'ros__parameters': tree}}, sort_keys=False))
    return [*rest, '--params-file', str(path)]


def node_command(proc: dict[str, Any], extra_ros_args: list[str] | None = None, folder: Path | None = None) -> list[str]:
    """The child command of one process: the launcher's --ros-args (for every process) come before
    the process's own overrides and remappings, so the process's win. With ``folder``, the
    overrides travel as parameter files given last (see overrides_last: rcl lets any file beat -p)."""
    extra = [a for a in (extra_ros_args or []) if a != '--ros-args']
    own = ros_args([], proc.get('parameters'), proc.get('remappings'))[3:]  # without the defaults file
    if folder is not None:
        sub = folder / f"process_{proc.get('name', '+'.join(proc['nodes']))}"
        sub.mkdir(parents=True, exist_ok=True)
        own = overrides_last(own, sub)
    return [sys.executable, '-m', 'srmosaic_ros.cli', 'node', *proc['nodes'],
            *ros_args(proc.get('params') or []), *extra, *own]


def run_named_nodes(names: list[str], args: list[str] | None) -> int:
    from .runner import run_nodes

    classes = _node_classes()
    unknown = [n for n in names if n not in classes]
    if unknown:
        msg = f'unknown node(s) {unknown}; available: {sorted(classes)}.'
        raise ConfigError(msg)
    return run_nodes([classes[n] for n in names], args)


def xml_node_command(node: LaunchNode, extra_params: list[str], extra_ros_args: list[str], folder: Path) -> list[str]:
    """The child command of one node of a launch file: its executable and arguments, namespace and
    name, the node's parameter files, the launcher's --params files, the node's parameters and
    remappings, then the launcher's --ros-args: what the command line says wins. Overrides travel
    as parameter files (see overrides_last: rcl lets any file beat -p)."""
    own = ['--ros-args']
    for k, v in node.parameters.items():
        own += ['-p', f'{k}:={v}']
    for a, b in node.remappings:
        own += ['-r', f'{a}:={b}']
    sub = folder / ('node_' + node.label.strip('/').replace('/', '_'))
    sub.mkdir(parents=True, exist_ok=True)
    names = ['-r', f'__ns:={node.namespace}'] + (['-r', f'__node:={node.name}'] if node.name else [])
    files = [w for f in [*node.param_files, *extra_params] for w in ('--params-file', str(f))]
    extra = [a for a in extra_ros_args if a != '--ros-args']
    return [sys.executable, '-m', 'srmosaic_ros.nodes.executables', node.executable, *node.arguments,
            '--ros-args', *names, *files, *overrides_last(own, sub), *extra]


def launch(description: Path | None, extra_params: list[str], extra_ros_args: list[str],
           launch_arguments: list[str] | None = None) -> int:
    import tempfile

    for f in extra_params:  # rcl would end on a bad file with a traceback of its own
        load_params(f)
    if description is not None and ':=' in str(description) and not Path(description).exists():
        launch_arguments = [str(description), *(launch_arguments or [])]  # `srmosaic launch map:=true`
        description = None
    if description is None and launch_arguments:  # the graph's launch file takes the arguments
        from .launch_xml import package_share

        description = package_share() / 'launch' / 'srmosaic.launch.xml'
    is_xml = description is not None and Path(description).name.endswith('.xml')
    if launch_arguments and not is_xml:
        msg = f'launch arguments {launch_arguments} need a launch file (FILE.launch.xml).'
        raise ConfigError(msg)
    overrides = parse_overrides(extra_ros_args)
    files = [*extra_params, *_params_files(extra_ros_args)]
    if description is None:
        check_overrides(overrides, {n: n for n in NODES}, {n: files for n in NODES})
    elif is_xml:
        nodes = read_launch_xml(description, parse_launch_arguments(launch_arguments or []))
        check_overrides(overrides, {node.label: EXECUTABLE_KINDS.get(node.executable, '') for node in nodes},
                        {node.label: [*node.param_files, *files] for node in nodes},
                        {node.label: {k: load_bounded(v) if v else '' for k, v in node.parameters.items()} for node in nodes})
    else:
        procs = load_description(description)
        labels = {(i, n): f"{proc.get('name', '+'.join(proc['nodes']))}/{n}" for i, proc in enumerate(procs) for n in proc['nodes']}
        check_overrides(overrides, {label: n for (_, n), label in labels.items()},
                        {label: [*files, *(procs[i].get('params') or [])] for (i, _), label in labels.items()},
                        {label: dict(procs[i].get('parameters') or {}) for (i, _), label in labels.items()})
    with tempfile.TemporaryDirectory(prefix='srmosaic-launch-') as tmp:
        extra_ros_args = overrides_last(extra_ros_args, Path(tmp))
        if description is None:
            return run_named_nodes(list(NODES), ['srmosaic', *ros_args(extra_params), *extra_ros_args])
        if is_xml:
            children = [(node.label, xml_node_command(node, extra_params, extra_ros_args, Path(tmp))) for node in nodes]
            managed = [node.label for node in nodes if node.managed and node.autostart]
            if managed:
                from .lifecycle_driver import LifecycleDriver

                return _supervise(children, LifecycleDriver(managed, log=_say))
        else:
            children = [(proc.get('name', '+'.join(proc['nodes'])),
                         node_command({**proc, 'params': [*extra_params, *(proc.get('params') or [])]},
                                      extra_ros_args, Path(tmp)))
                        for proc in procs]
        return _supervise(children)


def _params_files(ros_arguments: list[str]) -> list[str]:
    """The ``--params-file FILE`` of a --ros-args list, in order."""
    return [b for a, b in zip(ros_arguments, ros_arguments[1:]) if a == '--params-file']


def _say(text: str) -> None:
    print(f'srmosaic launch: {text}', file=sys.stderr)


def _supervise(commands: list[tuple[str, list[str]]], driver: Any = None) -> int:
    """Start the children, forward SIGINT/SIGTERM to them, stop all when one fails; their status.
    ``driver`` (a LifecycleDriver) brings the managed nodes up meanwhile; when it fails, the graph
    is stopped and the status is 2."""
    children = []
    for label, cmd in commands:
        _say(f"starting {label}: {' '.join(cmd[3:])}")
        children.append(subprocess.Popen(cmd))
    if driver is not None:
        driver.start()

    def forward(signum: int, frame: Any) -> None:
        for child in children:
            if child.poll() is None:
                child.send_signal(signal.SIGINT)

    def running() -> str:
        return ', '.join(label for (label, _), c in zip(commands, children) if c.poll() is None)

    user_stops = 0
    status = 0

    def on_signal(signum: int, frame: Any) -> None:
        # Ctrl-C / SIGTERM: the children stop cleanly (they write their outputs at shutdown, which
        # takes a while after a long flight, and ignore further signals meanwhile); a second one
        # kills those still running, as the user asked.
        nonlocal user_stops, status
        user_stops += 1
        if user_stops == 1:
            forward(signum, frame)
            _say(f'stopping; waiting for {running()} to finish (outputs are written at shutdown); '
                 'Ctrl-C again to kill them')
            return
        names = running()
        for child in children:
            if child.poll() is None:
                child.kill()
        if names:
            _say(f'killed {names} (outputs being written may be incomplete)')
            status = status or 1

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    try:
        while any(c.poll() is None for c in children):
            if driver is not None and driver.failure:
                _say(f'{driver.failure}; stopping the graph')
                status = 2
                forward(signal.SIGINT, None)
                break
            failed = [(label, c.returncode) for (label, _), c in zip(commands, children) if c.poll() not in (None, 0)]
            if failed and user_stops < 2:  # one failed: say which, stop the others
                label, code = failed[0]
                how = f'was killed by {signal.Signals(-code).name}' if code < 0 else f'exited with status {code}'
                _say(f'{label} {how}; stopping the others')
                forward(signal.SIGINT, None)
                break
            time.sleep(0.2)
    finally:
        if driver is not None:
            driver.stop()
        deadline = time.monotonic() + 30
        for child in children:
            try:
                child.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                child.kill()
            status = status or (child.returncode or 0)
    return status
