"""The node executables: `ros2 run srmosaic_ros <name> [args] [--ros-args ...]`.

Each is a console script installed beside `srmosaic` (in lib/srmosaic_ros by colcon, in the
environment's bin/ by pip), and `python -m srmosaic_ros.nodes.executables <name> ...` runs the same
(how `srmosaic launch` starts the nodes of a launch file). Parameters come from params/default.yaml
(found in the installed share/srmosaic_ros) and then from the command line's --ros-args.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable
from pathlib import Path

from ..errors import SrMosaicError

__all__ = ['EXECUTABLES', 'split_ros_args', 'run_executable', 'node_main', 'record_tiles_arguments', 'run_record_tiles',
           'play_arguments', 'run_play', 'player_main', 'tile_recorder_main', 'map_server_arguments', 'run_map_server',
           'map_server_main', 'main']

#: name -> 'module:function'; setup.py's console_scripts list the same (a test compares them).
EXECUTABLES = {
    'mosaic_node': 'srmosaic_ros.nodes.mosaic_node:main',
    'georef_node': 'srmosaic_ros.nodes.georef_node:main',
    'sr_node': 'srmosaic_ros.nodes.sr_node:main',
    'tile_recorder': 'srmosaic_ros.nodes.executables:tile_recorder_main',
    'player': 'srmosaic_ros.nodes.executables:player_main',
    'map_server': 'srmosaic_ros.nodes.executables:map_server_main',
}


def split_ros_args(argv: list[str]) -> tuple[list[str], list[str]]:
    """Split `... --ros-args ...` off a command line: rclpy takes what follows it."""
    if '--ros-args' in argv:
        i = argv.index('--ros-args')
        return argv[:i], argv[i:]
    return argv, []


def run_executable(prog: str, add_arguments: Callable[[argparse.ArgumentParser], None],
                   run: Callable[[argparse.Namespace], int], argv: list[str] | None = None,
                   description: str | None = None) -> int:
    """Parse the executable's own arguments (those before --ros-args), run it; its errors are one line."""
    own, ros_args = split_ros_args(list(sys.argv[1:] if argv is None else argv))
    parser = argparse.ArgumentParser(prog=prog, description=description,
                                     epilog='ROS arguments follow --ros-args (-r, -p, --params-file).')
    add_arguments(parser)
    args = parser.parse_args(own)
    args.ros_args = ros_args
    try:
        return int(run(args) or 0)
    except SrMosaicError as exc:
        print(f'{prog}: error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


def node_main(prog: str, node_class: type, argv: list[str] | None = None) -> int:
    """The main of an executable that runs one node class with no arguments of its own."""
    from .runner import run_nodes

    return run_executable(prog, lambda parser: None, lambda args: run_nodes([node_class], [prog, *args.ros_args]),
                          argv, description=(node_class.__doc__ or '').splitlines()[0])


def record_tiles_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('dir', type=Path, help='output folder (created): sr_tiles/*.tif, preview.tif')
    parser.add_argument('--preview', action='store_true', help='also keep the newest /srmosaic/mosaic_preview')


def run_record_tiles(args: argparse.Namespace) -> int:
    import functools

    from ..io.output_dir import check_output_dir
    from .runner import run_nodes
    from .tile_recorder import TileRecorderNode

    check_output_dir(args.dir, 'record-tiles DIR')  # before joining the graph, not at the first tile
    node = functools.partial(TileRecorderNode, args.dir, previews=args.preview)
    return run_nodes([node], ['tile_recorder', *args.ros_args])


#: Niceness the map server's process adds to its own: rendering tiles for a page must not take the CPU
#: from a mosaic node on the same machine (the SR node's worker runs at 10 for the same reason).
MAP_SERVER_NICENESS = 10


def lower_priority(increment: int) -> None:
    """Add ``increment`` to this process's niceness (nothing where the system refuses)."""
    import os

    try:
        os.nice(increment)
    except (OSError, AttributeError):  # no os.nice (Windows) or not allowed: run at the priority given
        pass


def map_server_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--port', type=int, default=None,
                        help='TCP port of the web map (default: live.map_port, 8080; 0: any free port)')
    parser.add_argument('--bind', default=None,
                        help='address to listen on (default: live.map_bind, 127.0.0.1: this machine only; '
                             '0.0.0.0: every interface, the network too)')


def run_map_server(args: argparse.Namespace) -> int:
    import functools

    from .map_server import MapServerNode
    from .runner import run_nodes

    if args.port is not None and not 0 <= args.port <= 65535:
        msg = f'--port must be in 0..65535, got {args.port}.'
        raise SrMosaicError(msg)
    lower_priority(MAP_SERVER_NICENESS)  # the mosaic node on the same cores comes first (as the SR worker)
    node = functools.partial(MapServerNode, port=args.port, bind=args.bind)
    return run_nodes([node], ['map_server', *args.ros_args])


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0 (nan, inf, 0 and negatives refused)."""
    import math

    try:
        value = float(text)
    except ValueError:
        msg = f'{text!r} is not a number'
        raise argparse.ArgumentTypeError(msg) from None
    if not (math.isfinite(value) and value > 0):
        msg = f'must be a finite number > 0, got {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return value


def topic_count(text: str) -> tuple[str, int]:
    """argparse type of ``--subscribers``: 'TOPIC=N' with N >= 1 -> (TOPIC, N)."""
    topic, _, count = text.rpartition('=')
    if not topic or not count.isdigit() or int(count) < 1:
        msg = f'takes TOPIC=N with N >= 1 (e.g. /camera/image_raw=2), got {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return topic, int(count)


def play_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', type=Path, help='rosbag2 folder (sqlite3 or mcap) or ROS 1 .bag file')
    parser.add_argument('--rate', type=positive_float, default=1.0, help='playback speed factor (2 = twice real time)')
    parser.add_argument('--topics', nargs='+', help='only these topics')
    parser.add_argument('--loop', action='store_true', help='start again at the end (until Ctrl-C)')
    parser.add_argument('--delay', type=float, default=1.0,
                        help='at most this many seconds to wait for a subscriber on every topic before playing')
    parser.add_argument('--subscribers', action='append', default=[], metavar='TOPIC=N', type=topic_count,
                        help='wait (up to --delay) for N subscribers on TOPIC (a bag topic; repeatable) instead of '
                             'one: a graph whose nodes read the same topic starts to listen one node at a time')


def run_play(args: argparse.Namespace) -> int:
    from .player import play_bag

    n = play_bag(args.bag, rate=args.rate, topics=args.topics, start_delay_s=args.delay, loop=args.loop,
                 args=['player', *args.ros_args], subscribers=dict(args.subscribers))
    print(f'published {n} messages from {args.bag}')
    return 0


def tile_recorder_main(argv: list[str] | None = None) -> int:
    """`ros2 run srmosaic_ros tile_recorder DIR [--preview] [--ros-args ...]`."""
    return run_executable('tile_recorder', record_tiles_arguments, run_record_tiles, argv,
                          description='write the live SR tiles (and the preview) into a folder as GeoTIFFs')


def map_server_main(argv: list[str] | None = None) -> int:
    """`ros2 run srmosaic_ros map_server [--port N] [--bind ADDR] [--ros-args ...]`."""
    return run_executable('map_server', map_server_arguments, run_map_server, argv,
                          description='serve the live map (mosaic, SR tiles, aircraft, footprint) as a web page')


def player_main(argv: list[str] | None = None) -> int:
    """`ros2 run srmosaic_ros player BAG [--rate R] [--ros-args ...]`."""
    return run_executable('player', play_arguments, run_play, argv,
                          description='publish a bag on its topics (the stand-in for ros2 bag play)')


def main(argv: list[str] | None = None) -> int:
    """`python -m srmosaic_ros.nodes.executables NAME [args]`: run executable NAME."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in EXECUTABLES:
        print(f"usage: python -m srmosaic_ros.nodes.executables {{{','.join(EXECUTABLES)}}} [args] [--ros-args ...]",
              file=sys.stderr)
        return 2
    module, _, function = EXECUTABLES[argv[0]].partition(':')
    return int(getattr(importlib.import_module(module), function)(argv[1:]) or 0)


if __name__ == '__main__':
    sys.exit(main())
