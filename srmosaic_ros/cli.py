"""`srmosaic` command line: process, evaluate, halve, inspect, simulate, launch, play, node, record-tiles,
map-server, psf, serve.

Every SrMosaicError ends the command with a one-line message on stderr and exit status 2;
nothing half-written is left under a final file name.
"""
from __future__ import annotations

import argparse
import gc
import json
import math
import os
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .core.sr_factors import SR_FACTORS
from .errors import ConfigError, SrMosaicError

__all__ = ['main']


def _add_process(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('process', help='build a mosaic from a recorded flight (rosbag2 folder, ROS 1 bag, video or '
                       'folder of stills)')
    p.add_argument('input', type=Path, help='rosbag2 folder (sqlite3 or mcap), ROS 1 .bag file, video (MP4, MKV, AVI, '
                   'MPEG-TS, ...; with its KLV, a DJI .SRT beside it or GoPro GPMF), or folder of stills (geotagged by '
                   'EXIF/XMP or a telemetry_from_exif.csv beside them)')
    p.add_argument('--out', type=Path, required=True, help='output directory (created)')
    p.add_argument('--params', type=Path, help='ROS 2 parameter file (YAML) overriding any key of params/default.yaml '
                   'and params/advanced.yaml')
    p.add_argument('--image-topic', default='/camera/image_raw',
                   help='bag: sensor_msgs/Image topic (its /compressed variant is used if only that exists)')
    p.add_argument('--camera-info-topic', default='/camera/camera_info', help='bag: sensor_msgs/CameraInfo topic')
    p.add_argument('--fix-topic', default='/fix', help='bag: sensor_msgs/NavSatFix topic')
    p.add_argument('--imu-topic', default='/imu/data', help='bag: sensor_msgs/Imu topic')
    p.add_argument('--blend', choices=['feather', 'multiband', 'bestview'], help='override mosaic.blend')
    p.add_argument('--device', choices=['auto', 'cpu', 'cuda'], help='override device')
    p.add_argument('--select', default='all', help='video frame selection: all, every:N, iframes (the '
                   "reference's MPEG I-frame mosaics) or overlap:F (next frame when overlap drops below F)")
    p.add_argument('--deinterlace', choices=['auto', 'on', 'off'], default='auto',
                   help='video: keep the top field of interlaced frames (auto: those the stream flags interlaced)')
    p.add_argument('--camera', type=Path, help='video: camera calibration YAML (ROS camera_calibration format)')
    p.add_argument('--hfov', type=float, help='video: horizontal field of view in degrees, between 0 and 180 '
                   '(square pixels, centred principal point)')
    p.add_argument('--telemetry', type=Path, help='video: flight log CSV (time_s,latitude,longitude,altitude,'
                   'roll,pitch,yaw), used instead of the telemetry the video carries')
    p.add_argument('--mosaic-video', action='store_true', help='also write mosaic.mp4, the mosaic growing '
                   'frame by frame with the current footprint outlined')
    p.add_argument('--checkpoint-every', type=int, default=100, metavar='N',
                   help='checkpoint the run state into DIR/.checkpoint every N frames (N >= 0; 0: never; default 100)')
    p.add_argument('--resume', action='store_true', help='continue an interrupted run from its last checkpoint')
    p.add_argument('--sr', action='store_true', help='also write super-resolved tiles of the mosaic to DIR/sr/')
    p.add_argument('--sr-factor', type=int, default=None,
                   help=f'SR factor ({", ".join(map(str, SR_FACTORS))}; default sr_tiles.factor, 2); implies --sr')
    p.add_argument('--gcp', type=Path, default=None, metavar='FILE',
                   help="ground control points in OpenDroneMap's gcp_list.txt format (stills: default a gcp_list.txt "
                   'inside or beside the folder; a video or a bag: picks name their frames as `srmosaic frames` writes them)')
    p.add_argument('--check-points', default=None, metavar='N|NAMES',
                   help='with ground control: hold out N targets (spread over the mosaic) or the named ones '
                   '(comma-separated) as check points; their residuals go to report.json gcp')
    p.add_argument('--tiles', nargs='?', const='png', choices=['png', 'webp'], default=None,
                   help='georeferenced runs: also write the web map, XYZ tiles (EPSG:3857, default png) in DIR/tiles/ '
                   '(and DIR/sr/ with --sr) with DIR/map.html, a page that opens offline')
    p.add_argument('--kmz', action='store_true', help='georeferenced runs: also write DIR/mosaic.kmz (Google Earth: the '
                   'mosaic as a ground overlay)')
    p.add_argument('--no-progress', action='store_true', help='no progress bar')
    p.set_defaults(func=_run_process)


def _run_process(args: argparse.Namespace) -> int:
    from .param_files import load_params

    overrides = load_params(args.params) if args.params else {}  # before the heavy imports: a bad file is said at once
    from .config import pipeline_config
    from .io.bags import TopicConfig
    from .app.process import process_input

    if getattr(args, 'console', False):
        # The imports' objects (torch, OpenCV, GDAL's bindings) live as long as the process: out of the
        # collector's reach, each full collection during the run and at exit no longer walks them.
        gc.freeze()
    if args.blend:
        overrides['mosaic.blend'] = args.blend
    if args.device:
        overrides['device'] = args.device
    config = pipeline_config(overrides)
    topics = TopicConfig(image=args.image_topic, camera_info=args.camera_info_topic, fix=args.fix_topic,
                         imu=args.imu_topic)
    report = process_input(args.input, args.out, config, topics=topics, select=args.select, camera_yaml=args.camera,
                           hfov_deg=args.hfov, telemetry_csv=args.telemetry, mosaic_video=args.mosaic_video,
                           checkpoint_every=args.checkpoint_every, resume=args.resume,
                           sr_factor=(args.sr_factor or config.sr_tiles.factor) if (args.sr or args.sr_factor) else None,
                           progress=not args.no_progress, deinterlace=args.deinterlace, gcp_file=args.gcp,
                           check_points=args.check_points, tiles=args.tiles, kmz=args.kmz)
    print(f"{report['frames_registered']}/{report['frames_in']} frames in mosaic.png "
          f"({len(report['segments'])} segment(s)), {report['frames_per_s']} frames/s, "
          f"peak {report['peak_rss_mb']} MB -> {args.out}")
    for name, figures in (report.get('map_outputs') or {}).items():
        if name == 'tiles':
            counts = ', '.join(f"{layer} {f['tiles']} (zoom {f['minzoom']}-{f['maxzoom']})" for layer, f in figures['layers'].items())
            print(f"web map: {args.out / 'map.html'} ({figures['format']} tiles: {counts}); or `srmosaic serve {args.out}`")
        elif name == 'kmz':
            print(f"KMZ: {args.out / figures['file']}")
    if left_out := report.get('images_left_out'):
        print(f"{len(left_out)} image(s) left out, neither placed nor painted: {', '.join(sorted(left_out))} "
              "(report.json images_left_out says why)")
    if (gcp := report.get('gcp')) is not None:
        for point in gcp['points']:
            what = (f"{point['error_m']:.3f} m ({point['error_gsd']} GSD)" if point['error_m'] is not None
                    else point.get('note', 'not measured'))
            print(f"  {point['name']} ({point['role']}): {what}")
        for role in ('control', 'check'):
            if gcp[f'{role}_rms_m'] is not None:
                print(f"ground control: {gcp[f'{role}_targets_measured']} {role} target(s) {gcp[f'{role}_rms_m']:.3f} m "
                      f"RMS ({gcp[f'{role}_rms_gsd']} GSD)")
    if (mount := report.get('mount_from_frames')) is not None:
        print(f"camera mount from the frames (no attitude measured): {-mount['elevation_deg']:g} deg below the horizon, "
              f"{mount['azimuth_deg']:g} deg from the direction of travel; the run started again with it "
              "(report.json mount_from_frames)")
    return 0


#: Every numeric flag's range, per command: (dest, flag, test, the range as the help says it). Checked
#: by check_ranges before any work; a flag's help states the same range.
FLAG_RANGES: dict[str, list[tuple[str, str, Callable[[Any], bool], str]]] = {
    'process': [
        ('sr_factor', '--sr-factor', lambda v: v in SR_FACTORS, f'one of {", ".join(map(str, SR_FACTORS))}'),
        ('checkpoint_every', '--checkpoint-every', lambda v: v >= 0, '>= 0 (0: never)'),
        ('hfov', '--hfov', lambda v: 0.0 < v < 180.0, 'between 0 and 180 degrees'),
    ],
    'psf': [
        ('max_frames', '--max-frames', lambda v: v >= 1, '>= 1'),
        ('quantile', '--quantile', lambda v: 0.0 < v < 1.0, 'between 0 and 1'),
    ],
    'simulate': [
        ('jpeg_quality', '--jpeg-quality', lambda v: 1 <= v <= 100, 'between 1 and 100'),
        ('gop', '--gop', lambda v: v >= 1, '>= 1'),
    ],
    'halve': [
        ('frames', '--frames', lambda v: v >= 1, '>= 1'),
    ],
    'play': [
        ('delay', '--delay', lambda v: v >= 0.0, '>= 0 seconds'),
    ],
    'serve': [
        ('port', '--port', lambda v: 1 <= v <= 65535, 'between 1 and 65535'),
    ],
}


def check_ranges(args: argparse.Namespace) -> None:
    """ConfigError naming the first flag of ``args.command`` outside its range (FLAG_RANGES)."""
    for dest, flag, test, text in FLAG_RANGES.get(getattr(args, 'command', ''), []):
        value = getattr(args, dest, None)
        if value is not None and not (math.isfinite(value) and test(value)):
            msg = f'{flag} {value:g} is out of range: it must be {text}. See srmosaic {args.command} --help.'
            raise ConfigError(msg)


def _add_evaluate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('evaluate', help='figures of a process output: truth-free ones for real footage, or against a '
                       'simulated flight\'s ground truth (--truth)')
    p.add_argument('dir', type=Path, help='output directory of `srmosaic process`')
    p.add_argument('--truth', type=Path, default=None,
                   help='ground_truth.json written by `srmosaic simulate`; without it, the truth-free figures of a real '
                   'run (frames in the main mosaic, frame-to-mosaic consistency, sharpness, position error against the '
                   'footage\'s own GPS/KLV)')
    p.add_argument('--input', type=Path, default=None, help='the input of the run, when it moved since `process`')
    p.add_argument('--camera', type=Path, default=None,
                   help='video: the camera calibration YAML the run was processed with, when it moved (default: the one '
                   'report.json names), so that the frames are compared undistorted as the run saw them')
    p.add_argument('--original', type=Path, default=None,
                   help='a run of a video halved by `srmosaic halve`: the full-size video it was halved from; scores every '
                   'SR tile against the original frames (the real-video SR protocol: against the bicubic of mosaic.png, of '
                   'the frame itself, and leave-one-out against the nearest other frame; luma PSNR and SSIM on static '
                   'pixels), writes DIR/sr/protocol.json and DIR/sr/protocol_compare.png')
    p.add_argument('--json', action='store_true', help='print the figures as JSON')
    p.add_argument('--no-progress', action='store_true', help='no progress bar')
    p.set_defaults(func=_run_evaluate)


def _add_halve(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('halve', help='halve a video (area filter, H.264 at high quality) for the real-video SR protocol: '
                       'process the halved copy with --sr, then `evaluate DIR --original VIDEO`')
    p.add_argument('video', type=Path, help='the full-size video')
    p.add_argument('out', type=Path, help='the halved video to write (e.g. halved.mp4)')
    p.add_argument('--frames', type=int, default=None, help='only the first N frames (>= 1; default: all)')
    p.set_defaults(func=_run_halve)


def _run_halve(args: argparse.Namespace) -> int:
    from .app.sr_protocol import halve_video

    n = halve_video(args.video, args.out, frames=args.frames)
    print(f'{n} frames halved into {args.out}; next: srmosaic process {args.out} --out DIR --sr, then '
          f'srmosaic evaluate DIR --original {args.video}')
    return 0


def _run_evaluate(args: argparse.Namespace) -> int:
    from .app.evaluate import evaluate_dir

    if args.original is not None:
        from .app.sr_protocol import format_protocol, score_sr_run

        result = score_sr_run(args.dir, args.original, input_path=args.input)
        print(json.dumps(result, indent=2) if args.json else '\n'.join(format_protocol(result)))
        return 0
    if args.truth is None:
        from .app.evaluate_real import evaluate_real, format_real_figures

        real = evaluate_real(args.dir, progress=not args.no_progress, input_path=args.input, camera_yaml=args.camera)
        print(json.dumps(real, indent=2, default=float) if args.json else '\n'.join(format_real_figures(real)))
        return 0
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
        if 'georef_error_rms_m' in figures:
            print(f"georeferencing error of mosaic points (EPSG:{figures['epsg']}): RMS "
                  f"{figures['georef_error_rms_m']:.2f} m, max {figures['georef_error_max_m']:.2f} m")
        if 'pose_rmse_horizontal_m' in figures:
            print(f"fused position error (poses.csv): horizontal RMS {figures['pose_rmse_horizontal_m']:.2f} m, "
                  f"vertical RMS {figures['pose_rmse_vertical_m']:.2f} m")
        sr = figures.get('sr')
        if sr and sr.get('tiles'):
            print(f"SR x{sr['factor']}, {sr['tiles']} tiles against the true ground: PSNR {sr['psnr_sr']:.2f} dB "
                  f"(bicubic of mosaic.png {sr['psnr_bicubic']:.2f} dB), gain {sr['gain_db']:+.2f} dB "
                  f"(per tile: median {sr['gain_db_median']:+.2f}, min {sr['gain_db_min']:+.2f}); "
                  f"SSIM {sr['ssim_sr']:.3f} (bicubic {sr['ssim_bicubic']:.3f}); "
                  f"bicubic | SR | truth: {Path(args.dir) / sr['compare']['file'] if 'compare' in sr else '-'}")
            used, true = sr.get('psf_sigma_px'), sr.get('psf_sigma_true_px')
            if used is not None and true is not None and abs(used - true) > 0.1:
                print(f'note: SR modelled the camera blur as {used:.2f} px, the simulated camera\'s is {true:.2f} px '
                      '(sr.psf_sigma; `srmosaic psf` measures it on frames of a target with straight edges)')
    return 0


def _add_simulate(sub: argparse._SubParsersAction) -> None:
    from .sim import cli as sim_cli

    p = sub.add_parser('simulate', help='render a synthetic flight over an orthophoto into a bag with ground truth')
    sim_cli.add_arguments(p)
    p.set_defaults(func=sim_cli.run)


def _add_node(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('node', help='run named nodes in this process (then --ros-args ...)')
    p.add_argument('nodes', nargs='+', help='node names: mosaic, georef, sr (see srmosaic_ros/nodes/launcher.py)')
    p.set_defaults(func=_run_node)


def _run_node(args: argparse.Namespace) -> int:
    from .nodes.launcher import run_named_nodes

    return run_named_nodes(args.nodes, ['srmosaic', *args.ros_args])


def _add_launch(sub: argparse._SubParsersAction) -> None:
    from .nodes import launcher

    p = sub.add_parser('launch', help='start the graph (all nodes in one process, a launch file, or a YAML description)',
                       description=launcher.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('description', nargs='?', type=Path,
                   help='a ROS 2 launch file (launch/srmosaic.launch.xml) or a YAML description (default: all nodes here)')
    p.add_argument('arguments', nargs='*', metavar='name:=value', help="the launch file's arguments (namespace:=uav1)")
    p.add_argument('--params', action='append', default=[], help='extra parameter file (repeatable)')
    p.set_defaults(func=_run_launch)


def _run_launch(args: argparse.Namespace) -> int:
    from .nodes.launcher import launch

    return launch(args.description, args.params, args.ros_args, args.arguments)


def _add_record_tiles(sub: argparse._SubParsersAction) -> None:
    from .nodes.executables import record_tiles_arguments, run_record_tiles

    p = sub.add_parser('record-tiles', help='write the live SR tiles (and the preview) into a folder as GeoTIFFs '
                       '(a ground station; then --ros-args ...)')
    record_tiles_arguments(p)
    p.set_defaults(func=run_record_tiles)


def _add_map_server(sub: argparse._SubParsersAction) -> None:
    from .nodes.executables import map_server_arguments, run_map_server

    p = sub.add_parser('map-server', help='serve the live map (mosaic, SR tiles, aircraft, footprint) as a web page '
                       '(a ground station; then --ros-args ...)')
    map_server_arguments(p)
    p.set_defaults(func=run_map_server)


def _add_play(sub: argparse._SubParsersAction) -> None:
    from .nodes.executables import play_arguments, run_play

    p = sub.add_parser('play', help='publish a bag on its topics (the stand-in for ros2 bag play)')
    play_arguments(p)
    p.set_defaults(func=run_play)


def _add_psf(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('psf', help="measure the camera's PSF (sr.psf_sigma) on straight edges of a target "
                       '(slanted-edge method)')
    p.add_argument('inputs', type=Path, nargs='+', help='image files, folders of images, a video or a bag')
    p.add_argument('--max-frames', type=int, default=20, help='frames taken per folder, video or bag (spread evenly; '
                   '>= 1)')
    p.add_argument('--quantile', type=float, default=0.25, help='quantile of the edge sigmas reported (between 0 and '
                   '1; default 0.25)')
    p.add_argument('--no-undistort', action='store_true', help='measure the raw frames of a bag or video '
                   '(default: with lens distortion removed, as SR sees them)')
    p.add_argument('--json', action='store_true', help='print the figures (and every edge sigma) as JSON')
    p.set_defaults(func=_run_psf)


def _run_psf(args: argparse.Namespace) -> int:
    from .app.psf import as_json, measure_psf, summary_lines

    est = measure_psf(args.inputs, max_frames=args.max_frames, undistort=not args.no_undistort,
                      quantile=args.quantile)
    if args.json:
        print(json.dumps(as_json(est), indent=2))
    else:
        print('\n'.join(summary_lines(est)))
    return 0


def _add_inspect(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('inspect', help='what an input carries (streams, KLV, SRT, GPMF, EXIF camera) and what '
                       '`process` will do with it')
    p.add_argument('input', type=Path, help='video file, folder of stills or bag')
    p.add_argument('--json', action='store_true', help='print as JSON')
    p.set_defaults(func=_run_inspect)


def _run_inspect(args: argparse.Namespace) -> int:
    from .app.inspect_tool import format_inspection, inspect_input

    info = inspect_input(args.input)
    print(json.dumps(info, indent=2, default=str) if args.json else '\n'.join(format_inspection(info)))
    return 0


def _add_serve(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('serve', help='serve a georeferenced process output as a web map (the mosaic and SR layers, the '
                       'track and the last footprint) at http://BIND:PORT/; read only')
    p.add_argument('dir', type=Path, help='output directory of `srmosaic process` (with mosaic.tif: a georeferenced run)')
    p.add_argument('--port', type=int, default=8080, help='TCP port, between 1 and 65535 (default 8080)')
    p.add_argument('--bind', default='127.0.0.1', help='address to listen on (default 127.0.0.1, this machine only; '
                   '0.0.0.0 opens the map to the network, without any login)')
    p.set_defaults(func=_run_serve)


def _run_serve(args: argparse.Namespace) -> int:
    from .web.run_source import RunSource
    from .web.server import serve

    source = RunSource(args.dir)
    if args.bind not in ('127.0.0.1', 'localhost', '::1'):
        print(f'srmosaic serve: the map is open to every host that reaches {args.bind} port {args.port}, without a login',
              file=sys.stderr)
    try:
        serve(source, port=args.port, bind=args.bind, page_config={'title': f'srmosaic map: {args.dir.resolve().name}'})
    except OSError as exc:
        msg = f'cannot listen on {args.bind} port {args.port} ({exc.strerror or exc}); give another --port or --bind.'
        raise ConfigError(msg) from None
    return 0


def _add_frames(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser('frames', help='write the frames of a video or a bag as images named by their stamps, to pick '
                       'ground control in (then process INPUT --gcp gcp_list.txt)')
    p.add_argument('input', type=Path, help='video file or bag')
    p.add_argument('out', type=Path, help='folder to write the frames into (created)')
    p.add_argument('--select', default='all', help='video frame selection, as process --select (default all)')
    p.add_argument('--every', type=int, default=1, metavar='N', help='write every N-th selected frame (N >= 1; default 1)')
    p.add_argument('--format', choices=['png', 'jpg'], default='png', help='image format (default png)')
    p.add_argument('--image-topic', default='/camera/image_raw', help='bag: sensor_msgs/Image topic')
    p.set_defaults(func=_run_frames)


def _run_frames(args: argparse.Namespace) -> int:
    from .app.export_frames import export_frames
    from .io.bags import TopicConfig

    written = export_frames(args.input, args.out, select=args.select, every=args.every,
                            topics=TopicConfig(image=args.image_topic), suffix=f'.{args.format}')
    print(f'{len(written)} frames -> {args.out}' + (f' ({written[0].name} ... {written[-1].name})' if written else ''))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='srmosaic', description=__doc__.splitlines()[0],
                                     epilog='Each command has --help. Documentation: docs/getting-started.md, and every '
                                     'option in docs/reference/cli.md (make docs builds the site into site/).')
    sub = parser.add_subparsers(dest='command', required=True)
    _add_process(sub)
    _add_evaluate(sub)
    _add_halve(sub)
    _add_inspect(sub)
    _add_frames(sub)
    _add_simulate(sub)
    _add_node(sub)
    _add_launch(sub)
    _add_play(sub)
    _add_psf(sub)
    _add_record_tiles(sub)
    _add_serve(sub)
    _add_map_server(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    return _main(argv)[0]


def _main(argv: list[str] | None, *, console: bool = False) -> tuple[int, str]:
    """(exit status, the command run); ``console``: run as the `srmosaic` program (console_main)."""
    parser = build_parser()
    from .nodes.executables import split_ros_args

    own, ros_args = split_ros_args(list(sys.argv[1:] if argv is None else argv))
    args = parser.parse_args(own)
    args.ros_args = ros_args
    args.console = console
    try:
        check_ranges(args)  # before any work
        return int(args.func(args) or 0), args.command
    except SrMosaicError as exc:
        print(f'srmosaic {args.command}: error: {exc}', file=sys.stderr)
        return 2, args.command
    except KeyboardInterrupt:
        print(f'srmosaic {args.command}: interrupted', file=sys.stderr)
        return 130, args.command


#: Commands whose program ends as soon as its exit handlers have run (console_main): their outputs are
#: complete and closed when the command returns.
QUICK_EXIT_COMMANDS = frozenset({'process'})


def console_main() -> int:
    """The `srmosaic` program: main(), then, after a QUICK_EXIT_COMMANDS command, the exit handlers
    (atexit: the canvas's spill folders removed, logs flushed) and an immediate exit: the
    interpreter's teardown (freeing every module's objects, and full collections over them) is
    work the user waits for and nothing needs. With a thread of its own still running, the usual exit."""
    rc, command = _main(None, console=True)
    if command not in QUICK_EXIT_COMMANDS or any(t.is_alive() and not t.daemon for t in threading.enumerate()
                                                 if t is not threading.main_thread()):
        return rc
    import atexit

    run_exit_handlers = getattr(atexit, '_run_exitfuncs', None)
    if run_exit_handlers is None:  # not CPython: the usual exit
        return rc
    run_exit_handlers()  # logging's among them
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(rc)


if __name__ == '__main__':
    sys.exit(console_main())
