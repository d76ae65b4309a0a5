"""`srmosaic` command line: process, evaluate, simulate.

Every SrMosaicError ends the command with a one-line message on stderr and exit status 2;
nothing half-written is left under a final file name.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .errors import SrMosaicError

__all__ = ['main']


def _add_process(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('process', help='build a mosaic from a recorded flight (rosbag2 folder or ROS 1 bag)')
    p.add_argument('input', type=Path, help='rosbag2 folder (sqlite3 or mcap) or ROS 1 .bag file')
    p.add_argument('--out', type=Path, required=True, help='output directory (created)')
    p.add_argument('--params', type=Path, help='YAML parameter file overriding params/default.yaml')
    p.add_argument('--image-topic', default='/camera/image_raw',
                   help='sensor_msgs/Image topic (its /compressed variant is used if only that exists)')
    p.add_argument('--camera-info-topic', default='/camera/camera_info')
    p.add_argument('--fix-topic', default='/fix')
    p.add_argument('--imu-topic', default='/imu/data')
    p.add_argument('--blend', choices=['feather', 'multiband'], help='override mosaic.blend')
    p.add_argument('--device', choices=['auto', 'cpu', 'cuda'], help='override device')
    p.add_argument('--no-progress', action='store_true', help='no progress bar')
    p.set_defaults(func=_run_process)


def _run_process(args: argparse.Namespace) -> int:
    from .config import load_params, pipeline_config
    from .io.bags import TopicConfig
    from .offline import process_bag

    overrides = load_params(args.params) if args.params else {}
    if args.blend:
        overrides['mosaic.blend'] = args.blend
    if args.device:
        overrides['device'] = args.device
    config = pipeline_config(overrides)
    topics = TopicConfig(image=args.image_topic, camera_info=args.camera_info_topic, fix=args.fix_topic,
                         imu=args.imu_topic)
    report = process_bag(args.input, args.out, config, topics=topics, progress=not args.no_progress)
    print(f"{report['frames_registered']}/{report['frames_in']} frames in mosaic.png "
          f"({len(report['segments'])} segment(s)), {report['frames_per_s']} frames/s, "
          f"peak {report['peak_rss_mb']} MB -> {args.out}")
    return 0


def _add_evaluate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('evaluate', help='compare a process output with a simulated flight\'s ground truth')
    p.add_argument('dir', type=Path, help='output directory of `srmosaic process`')
    p.add_argument('--truth', type=Path, required=True, help='ground_truth.json written by `srmosaic simulate`')
    p.add_argument('--json', action='store_true', help='print the figures as JSON')
    p.set_defaults(func=_run_evaluate)


def _run_evaluate(args: argparse.Namespace) -> int:
    from .evaluate import evaluate_dir

    figures = evaluate_dir(args.dir, args.truth)
    if args.json:
        print(json.dumps(figures, indent=2))
    else:
        print(f"frames registered: {figures['frames_registered']}/{figures['frames_in']} "
              f"({100 * figures['fraction_registered']:.1f}%)")
        print(f"corner error of mosaic_H_frame: mean {figures['corner_error_mean_px']:.3f} px, "
              f"max {figures['corner_error_max_px']:.3f} px")
        if figures.get('pair_corner_error_mean_px') is not None:
            print(f"consecutive-frame corner error: mean {figures['pair_corner_error_mean_px']:.4f} px, "
                  f"p90 {figures['pair_corner_error_p90_px']:.4f} px")
    return 0


def _add_simulate(sub: argparse._SubParsersAction) -> None:
    from .sim import cli as sim_cli

    p = sub.add_parser('simulate', help='render a synthetic flight over an orthophoto into a bag with ground truth')
    sim_cli.add_arguments(p)
    p.set_defaults(func=sim_cli.run)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='srmosaic', description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest='command', required=True)
    _add_process(sub)
    _add_evaluate(sub)
    _add_simulate(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except SrMosaicError as exc:
        print(f'srmosaic {args.command}: error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'srmosaic {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
