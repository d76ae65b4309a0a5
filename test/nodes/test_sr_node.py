"""The SR node in a live graph over real DDS on loopback: tiles when registrations lag, refreshes, Ctrl-C,
lens distortion, and its planning and worker process without ROS."""
from __future__ import annotations

import collections
import contextlib
import os
import signal
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest


from live_graph import (
    Listener,
    SR,
    children_of,
    cmdline_of,
    is_running,
    srmosaic,
    supervised,
    translation,
)

pytestmark = pytest.mark.ros


def sr_node_inputs(listener: Listener) -> tuple[Any, Any]:
    """Once the SR node is up: publishers of its camera images and of registrations (discovered)."""
    from sensor_msgs.msg import Image
    from std_msgs.msg import Float64MultiArray

    assert listener.wait_for(lambda: listener.diag_value('frames_received', SR) is not None, 60), 'no SR node'
    images = listener.publisher(Image, '/camera/image_raw')
    regs = listener.publisher(Float64MultiArray, '/srmosaic/registration')
    time.sleep(1.0)  # discovery of the two publishers
    return images, regs


def test_sr_node_says_when_registrations_come_after_their_images_were_dropped(ros_env):
    """The SR node alone with room for 3 images waiting for their registration: 6 images, then the
    registration of the first (dropped for room) and of the last: the first is counted as a rejection
    (diagnostics WARN, naming it), the way out is logged once, and the last still makes a frame."""
    from diagnostic_msgs.msg import DiagnosticStatus

    from msg_adapters import numpy_to_image
    from srmosaic_ros.nodes.common import encode_registration

    node = srmosaic('node', 'sr', '--ros-args', '-p', 'live.sr_period_s:=0.2', '-p', 'live.sr_worker:=thread',
                    '-p', 'live.sr_images_pending:=3', '-p', 'live.reliable_inputs:=true', env=ros_env)
    kind = 'rejected: registration after its image was dropped'
    with supervised(node=node) as sup:
        listener = sup.listener
        images, regs = sr_node_inputs(listener)
        stamps = [1_000_000_000 * (k + 1) for k in range(6)]
        for k, stamp in enumerate(stamps):
            images.publish(numpy_to_image(np.full((48, 64, 3), 20 * k, np.uint8), 'rgb8', stamp_ns=stamp, frame_id='camera'))
        assert listener.wait_for(lambda: listener.diag_value('frames_received', SR) == '6', 20), \
            listener.diag_value('frames_received', SR)
        for stamp in (stamps[0], stamps[-1]):
            regs.publish(encode_registration(stamp, True, 100, 0.1, 0, np.eye(3), np.eye(3), True, None))
        assert listener.wait_for(lambda: listener.diag_value(kind, SR) == '1', 20), listener.diag_value(kind, SR)
        assert listener.wait_for(lambda: listener.diag_value('frames_kept', SR) == '1', 20)
        warned = [st for msg in list(listener.diagnostics) for st in msg.status
                  if st.name == SR and st.level == DiagnosticStatus.WARN and 'registration after its image' in st.message]
        assert warned, 'diagnostics never said it'
    assert sup.logs['node'].count('raise it to the camera frames') == 1, sup.logs['node']


def test_sr_node_refreshes_a_tile_when_more_frames_cover_it(ros_env):
    """The SR node alone, fed frames and registrations over DDS by this test: an aircraft hovering
    over one spot. Each tile is published once 3 frames cover it, then again (same placement) once
    twice as many do (live.sr_refresh_growth 2), and counted as refreshed."""

    from imagery import view
    from msg_adapters import image_to_numpy, numpy_to_image
    from srmosaic_ros.nodes.common import encode_registration
    from srmosaic_ros.live.sr import SRTilePlacement

    # stamp_tolerance_s 0 (the gate off): the test's stamps advance 1 s a frame whatever its waits take
    # on a loaded machine, which the gate would rightly call a clock off the receive times
    node = srmosaic('node', 'sr', '--ros-args', '-p', 'live.sr_period_s:=0.2', '-p', 'live.sr_worker:=thread',
                    '-p', 'sr_tiles.tile_size:=64', '-p', 'sr_tiles.max_frames:=12', '-p', 'sr.iterations:=5',
                    '-p', 'stamp_tolerance_s:=0.0', env=ros_env)
    with supervised(node=node) as sup:
        listener = sup.listener
        images, regs = sr_node_inputs(listener)
        origin = np.array([300.0, 200.0])

        def state() -> str:
            return ', '.join(f'{k} {listener.diag_value(k, SR)}' for k in (
                'frames_received', 'frames_kept', 'registrations_without_image', 'tiles_published', 'tiles_refreshed'))

        for k in range(12):
            shift = np.array([10.0, 10.0]) + [0.37 * k % 2.0, 0.61 * k % 2.0]  # sub-pixel hovering
            plane_H_frame = translation(*shift)
            frame = view(translation(*(origin + shift)), 200, 140, noise=2.0, seed=k)
            stamp = 1_000_000_000 * (k + 1)
            images.publish(numpy_to_image(frame, 'rgb8', stamp_ns=stamp, frame_id='camera'))
            time.sleep(0.05)
            regs.publish(encode_registration(stamp, True, 100, 0.1, 0, plane_H_frame, np.eye(3), True, None))
            time.sleep(0.6)
            # The node's pace, not the test's: on a loaded machine a round may end after more frames
            # came, and a tile first published from 7 would never see the 14 that refresh it.
            if k == 2:
                assert listener.wait_for(lambda: int(listener.diag_value('tiles_published', SR) or 0) >= 2, 60), \
                    state()
            if k == 5:
                assert listener.wait_for(lambda: int(listener.diag_value('tiles_refreshed', SR) or 0) >= 2, 60), \
                    state()
        placements = collections.Counter(t.header.frame_id for t in listener.tiles)
        assert set(placements) == {'srmosaic_segment_0;x0=64;y0=64;width=64;height=64;factor=2',
                                   'srmosaic_segment_0;x0=128;y0=64;width=64;height=64;factor=2'}, placements
        assert all(n >= 2 for n in placements.values()), placements
        # every publication of a tile shows the ground at its stated placement (within a fraction of
        # what a 1 px misplacement costs), and the refreshed ones, made from more frames, no worse
        maes = collections.defaultdict(list)
        for tile in listener.tiles:
            place = SRTilePlacement.parse(tile.header.frame_id)
            world_H_tile = translation(*origin) @ place.plane_H_tile()
            got = image_to_numpy(tile).astype(float)
            mae = np.abs(got - view(world_H_tile, 128, 128))[8:-8, 8:-8].mean()
            misplaced = np.abs(got - view(world_H_tile @ translation(2.0, 0.0), 128, 128))[8:-8, 8:-8].mean()
            assert mae < 2.2 and mae < 0.75 * misplaced, (tile.header.frame_id, mae, misplaced)
            maes[tile.header.frame_id].append(mae)
        # (within 8 %: which frames a publication holds depends on DDS timing, and 5 solver
        # iterations leave a few hundredths of a grey level to chance; seen: 1.48 -> 1.53 under load.
        # Since sr.lambda_gamma 0.3 the first, 3-frame tile is closer to the truth than before, and with
        # the same frames offline the right-hand tile refreshed from 6 to 12 frames stays a few percent
        # above it, below the former 3-frame tile: the adaptive lambda (5.6) grows with the residual
        # that more frames leave, docs/results.md)
        assert all(m[-1] <= 1.08 * m[0] for m in maes.values()), dict(maes)


@pytest.mark.skipif(not Path('/proc/self/task').is_dir(), reason='reads child processes from /proc (Linux)')
def test_ctrl_c_abandons_the_sr_tile_in_progress(ros_env):
    """SIGINT while the SR worker process is inside a tile that would take a minute (tol 0, 10000
    iterations): the node ends within seconds, cleanly, says the tile was abandoned, and leaves no
    worker. It used to wait 60 s for the tile and then, at exit, for the worker (75 s on a loaded
    machine, past the launcher's and the tests' patience)."""
    from sensor_msgs.msg import Image
    from std_msgs.msg import Float64MultiArray

    from imagery import view
    from msg_adapters import numpy_to_image
    from srmosaic_ros.nodes.common import encode_registration

    node = srmosaic('node', 'sr', '--ros-args', '-p', 'live.sr_period_s:=0.2', '-p', 'sr_tiles.tile_size:=64',
                    '-p', 'sr.iterations:=10000', '-p', 'sr.tol:=0.0', '-p', 'sr.self_check:=0', env=ros_env)
    listener = Listener()
    try:
        assert listener.wait_for(lambda: listener.diag_value('frames_received', SR) is not None or node.poll() is not None,
                                 60) and node.poll() is None, f'no SR node: {node.communicate()[0] if node.poll() is not None else ""}'
        images = listener.publisher(Image, '/camera/image_raw')
        regs = listener.publisher(Float64MultiArray, '/srmosaic/registration')
        time.sleep(1.0)  # discovery of the two publishers
        for k in range(4):
            shift = np.array([10.0, 10.0]) + [0.37 * k % 2.0, 0.61 * k % 2.0]
            stamp = 1_000_000_000 * (k + 1)
            images.publish(numpy_to_image(view(translation(*(np.array([300.0, 200.0]) + shift)), 200, 140, seed=k),
                                          'rgb8', stamp_ns=stamp, frame_id='camera'))
            time.sleep(0.05)
            regs.publish(encode_registration(stamp, True, 100, 0.1, 0, translation(*shift), np.eye(3), True, None))
        workers = [w for w in children_of(node.pid) if 'spawn_main' in cmdline_of(w)]
        assert workers, 'no SR worker process'

        def busy_s() -> float:  # CPU seconds the workers have used (utime + stime)
            total = 0
            for w in workers:
                with contextlib.suppress(OSError), open(f'/proc/{w}/stat') as handle:
                    total += sum(int(v) for v in handle.read().rsplit(') ', 1)[1].split()[11:13])
            return total / os.sysconf('SC_CLK_TCK')

        start = busy_s()
        assert listener.wait_for(lambda: busy_s() > start + 3.0, 120), 'the worker never got to work on a tile'
        t0 = time.monotonic()
        node.send_signal(signal.SIGINT)
        out, _ = node.communicate(timeout=60)
        took = time.monotonic() - t0
    finally:
        if node.poll() is None:
            node.kill()
            node.communicate()
        listener.close()
    assert node.returncode == 0, out
    assert took < 20, (took, out)
    assert 'the tile in progress was abandoned' in out, out
    assert not listener.tiles
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and any(is_running(w) for w in workers):
        time.sleep(0.2)
    assert not any(is_running(w) for w in workers), 'the SR worker outlived its node'


def test_sr_node_removes_lens_distortion_like_the_mosaic_node(ros_env):
    """Frames through a wide barrel lens (k1 = -0.35: 5 px at 60 px from the centre) with their
    CameraInfo: the registrations refer to the undistorted pinhole frames (as the mosaic node's
    do), so the SR node must undistort the images the same way; its tiles then show the ground at
    their placement. With undistort:=false the same tiles are measurably worse."""
    import cv2
    from sensor_msgs.msg import CameraInfo, Image
    from std_msgs.msg import Float64MultiArray

    from imagery import view
    from msg_adapters import image_to_numpy, intrinsics_to_camera_info, numpy_to_image
    from srmosaic_ros.core.types import CameraIntrinsics
    from srmosaic_ros.core.undistort import pinhole_of
    from srmosaic_ros.nodes.common import encode_registration
    from srmosaic_ros.live.sr import SRTilePlacement

    lens = CameraIntrinsics(200, 140, 120.0, 120.0, 99.5, 69.5, 'plumb_bob', (-0.35, 0.1, 0.0, 0.0, 0.0))
    pinhole, _, _ = pinhole_of(lens)
    margin = 40
    grid = np.stack(np.meshgrid(np.arange(200.0), np.arange(140.0)), -1).reshape(-1, 1, 2)
    src = (cv2.undistortPoints(grid, lens.K, np.array(lens.distortion), P=pinhole.K).reshape(140, 200, 2)
           + margin).astype(np.float32)
    origin = np.array([300.0, 200.0])

    def run(undistort: bool, info: CameraIntrinsics = lens) -> float:
        node = srmosaic('node', 'sr', '--ros-args', '-p', 'live.sr_period_s:=0.2', '-p', 'live.sr_worker:=thread',
                        '-p', 'sr_tiles.tile_size:=64', '-p', 'sr_tiles.max_frames:=8', '-p', 'sr.iterations:=5',
                        '-p', 'live.sr_refresh_growth:=0.0', '-p', f'undistort:={str(undistort).lower()}', env=ros_env)
        with supervised(node=node) as sup:
            listener = sup.listener
            assert listener.wait_for(lambda: listener.diag_value('frames_received', SR) is not None, 60), 'no SR node'
            infos = listener.publisher(CameraInfo, '/camera/camera_info')
            images = listener.publisher(Image, '/camera/image_raw')
            regs = listener.publisher(Float64MultiArray, '/srmosaic/registration')
            time.sleep(1.0)
            for k in range(6):
                shift = np.array([10.0, 10.0]) + [0.37 * k % 2.0, 0.61 * k % 2.0]
                big = view(translation(*(origin + shift - margin)), 200 + 2 * margin, 140 + 2 * margin, noise=1.0,
                           seed=k)
                frame = cv2.remap(big, src[..., 0], src[..., 1], cv2.INTER_CUBIC)   # what the lens shows
                stamp = 1_000_000_000 * (k + 1)
                infos.publish(intrinsics_to_camera_info(info, stamp_ns=stamp, frame_id='camera'))
                time.sleep(0.05)
                images.publish(numpy_to_image(frame, 'rgb8', stamp_ns=stamp, frame_id='camera'))
                time.sleep(0.05)
                regs.publish(encode_registration(stamp, True, 100, 0.1, 0, translation(*shift), np.eye(3), True,
                                                 None))
                time.sleep(0.4)
            assert listener.wait_for(lambda: len(listener.tiles) >= 2, 30), 'no tiles'
            maes = []
            for tile in listener.tiles:
                place = SRTilePlacement.parse(tile.header.frame_id)
                truth = view(translation(*origin) @ place.plane_H_tile(), 128, 128)
                maes.append(np.abs(image_to_numpy(tile).astype(float) - truth)[8:-8, 8:-8].mean())
            if info is not lens:
                assert listener.diag_value('camera_info_scaled', SR), 'the scaled camera info is not counted'
        return float(np.mean(maes))

    fixed, raw = run(True), run(False)
    # the CameraInfo of the same lens at twice the size (a camera mode the images are not in): scaled
    # to the images as the mosaic node does (the images used to be refused, and no tile came)
    scaled = run(True, lens.scaled_to(400, 280))
    print(f"tile MAE against the truth: undistorted {fixed:.2f}, raw {raw:.2f}, info scaled {scaled:.2f} grey levels")
    assert fixed < 2.5 and raw > 1.5 * fixed, (fixed, raw)
    assert scaled < 1.1 * fixed + 0.1, (scaled, fixed)


def test_sr_placement_and_live_planning_without_ros():
    """The ROS-free side of the SR node: placement text, the bounded frame store, tile planning."""
    from srmosaic_ros.core.sr.scheduler import SRTileConfig
    from srmosaic_ros.errors import SrMosaicError
    from srmosaic_ros.live.sr import LiveFrameStore, SRTilePlacement, plan_live_tiles

    place = SRTilePlacement(2, -128, 256, 128, 64, 3)
    assert SRTilePlacement.parse(place.frame_id()) == place
    np.testing.assert_allclose(place.plane_H_tile() @ [0, 0, 1], [-128 + 0.5 / 3 - 0.5, 256 + 0.5 / 3 - 0.5, 1])
    with pytest.raises(SrMosaicError, match='not an SR tile placement'):
        SRTilePlacement.parse('srmosaic_mosaic')

    store = LiveFrameStore(pending=3, kept=5)
    for k in range(4):
        store.add_image(k, f'image {k}')
    assert store.pending == 3  # the oldest went
    assert not store.add_registration(0, 0, np.eye(3)) and store.missed == 1
    assert store.missed_dropped == 1  # dropped for room: the store is too small for the registrations' delay
    assert not store.add_registration(9, 0, np.eye(3)) and (store.missed, store.missed_dropped) == (2, 1)  # never came
    assert not store.add_registration(1, -1, None)  # not painted: dropped
    for k in range(2, 10):
        store.add_image(k, f'image {k}')
        store.add_registration(k, 0, translation(-300.0 + 10 * k, -200.0))  # negative plane coordinates
    assert [f.stamp_ns for f in store.registered()] == [5, 6, 7, 8, 9]
    frames = store.registered()
    cfg = SRTileConfig(tile_size=64, min_frames=3, max_frames=4)
    plans = plan_live_tiles(frames, {f.stamp_ns: (320, 240) for f in frames}, cfg)
    assert plans
    for plan, used in plans:
        assert plan.x0 % 64 == 0 and plan.y0 % 64 == 0 and 3 <= len(used) <= 4
        for f in used:  # every chosen frame sees the whole tile
            corners = np.array([[plan.x0, plan.y0, 1], [plan.x0 + 63, plan.y0 + 63, 1]], float)
            p = np.linalg.solve(f.seg_H_frame, corners.T)
            assert np.all(p[0] >= 0) and np.all(p[0] <= 319) and np.all(p[1] >= 0) and np.all(p[1] <= 239)
    done = {(0, p.x0, p.y0) for p, _ in plans}
    assert plan_live_tiles(frames, {f.stamp_ns: (320, 240) for f in frames}, cfg, done) == []
    store.add_image(20, 'other scene')
    store.add_registration(20, 1, np.eye(3))  # a new segment: the older one's frames go
    assert [f.stamp_ns for f in store.registered()] == [20]


def test_sr_worker_process_gives_the_in_process_tile():
    """live.sr_worker process: a tile reconstructed in a spawned worker process (the SR node's
    default) is the tile reconstructed in this process; an SRError crosses the process boundary."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from srmosaic_ros.core.sr import SRConfig
    from srmosaic_ros.core.sr.scheduler import TilePlan
    from srmosaic_ros.live.sr import (SRError, init_sr_worker_process, reconstruct_live_tile,
                                      reconstruct_live_tile_image)

    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.uniform(0, 255, (80, 100)).astype(np.float32), (0, 0), 1.5)
    images = [np.clip(np.roll(base, (k, 2 * k), (0, 1)) + rng.normal(0, 2, base.shape), 0, 255).astype(np.uint8)
              for k in range(3)]
    hs = [translation(10.0 - 2 * k, 20.0 - k) for k in range(3)]  # the rolls undone: one picture
    plan = TilePlan(32, 32, 32, 32, (0, 1, 2), 3)
    config = SRConfig(iterations=3)
    here, place_here, _ = reconstruct_live_tile(plan, images, hs, 2, config, 4)
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context('spawn'), initializer=init_sr_worker_process,
                             initargs=(1,)) as pool:
        assert pool.submit(os.getpid).result() != os.getpid()
        there, place_there, stop = pool.submit(reconstruct_live_tile_image, plan, images, hs, 2, config, 4).result()
        far = TilePlan(5000, 5000, 32, 32, (0, 1, 2), 3)
        with pytest.raises(SRError):
            pool.submit(reconstruct_live_tile_image, far, images, hs, 2, config, 4).result()
    assert place_there == place_here and isinstance(stop, str) and stop
    assert there.shape == here.shape == (64, 64)
    assert np.abs(there.astype(int) - here.astype(int)).max() <= 1
