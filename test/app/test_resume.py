"""A run killed with SIGKILL resumes from its checkpoint and produces the same mosaic."""
from __future__ import annotations

import json
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

from srmosaic_ros.app.checkpoint import read_header
from repo_paths import REPO

ROOT = REPO
DEMO = ROOT / 'bags' / 'demo'
CLI = [sys.executable, '-m', 'srmosaic_ros.cli']


def _checkpointed_frames(out: Path) -> int:
    header = read_header(out / '.checkpoint' / 'state.pkl')
    return int(header['frames_consumed']) if header else 0


def test_kill_9_then_resume_gives_the_same_mosaic(tmp_path, demo_run):
    """Against the uninterrupted run of the demo with the defaults, shared with other files (test/flights.py)."""
    full = demo_run[0]
    assert not (full / '.checkpoint').exists()  # a completed run leaves no checkpoint

    out = tmp_path / 'interrupted'
    proc = subprocess.Popen([*CLI, 'process', str(DEMO), '--out', str(out), '--checkpoint-every', '10',
                             '--no-progress'], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while _checkpointed_frames(out) < 20 and time.monotonic() < deadline:
        assert proc.poll() is None, 'the run finished before it could be killed'
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (out / 'mosaic.png').exists() and not (out / 'frames.csv').exists()  # nothing that looks complete

    resumed = subprocess.run([*CLI, 'process', str(DEMO), '--out', str(out), '--checkpoint-every', '10',
                              '--resume', '--no-progress'], capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    report = json.loads((out / 'report.json').read_text())
    assert report['resumed_after_frames']['input_items_skipped'] > 0
    assert not (out / '.checkpoint').exists()  # nor does a completed run that wrote some
    assert (out / 'frames.csv').read_bytes() == (full / 'frames.csv').read_bytes()
    assert (out / 'mosaic.png').read_bytes() == (full / 'mosaic.png').read_bytes()


def test_resume_refuses_other_input_or_missing_checkpoint(tmp_path):
    run = subprocess.run([*CLI, 'process', str(DEMO), '--out', str(tmp_path / 'none'), '--resume'],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and 'no checkpoint' in run.stderr


class _Crafted:
    """A hand-made 'checkpoint' whose unpickling runs a command."""

    def __init__(self, target: Path) -> None:
        self.target = target

    def __reduce__(self):
        return (os.system, (f'touch {self.target}',))


def test_resume_verifies_a_checkpoint_before_it_loads_code(tmp_path):
    """--resume used to unpickle state.pkl first: a crafted one ran code. The header (format,
    fingerprint, checksum) is checked first, and the payload's globals are allow-listed."""
    import hashlib

    out = tmp_path / 'run'
    proc = subprocess.Popen([*CLI, 'process', str(DEMO), '--out', str(out), '--checkpoint-every', '5',
                             '--no-progress'], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while _checkpointed_frames(out) < 5 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    path = out / '.checkpoint' / 'state.pkl'
    header = read_header(path)
    assert header is not None and header['frames_consumed'] >= 5
    pwned = tmp_path / 'PWNED'
    payload = pickle.dumps(_Crafted(pwned))
    magic = path.read_bytes().split(b'{', 1)[0]
    cases = {
        'checksum': (header, 'does not match its own checksum'),  # the payload replaced, the header kept
        'code': ({**header, 'sha256': hashlib.sha256(payload).hexdigest()}, 'which a checkpoint never holds'),
    }
    for name, (head, expect) in cases.items():
        path.write_bytes(magic + json.dumps(head).encode() + b'\n' + payload)
        run = subprocess.run([*CLI, 'process', str(DEMO), '--out', str(out), '--resume', '--no-progress'],
                             capture_output=True, text=True, timeout=300)
        assert run.returncode == 2 and expect in run.stderr, (name, run.stderr)
        assert 'Traceback' not in run.stderr and not pwned.exists(), name


def test_checkpoint_holds_the_pipeline_state_by_name(tmp_path):
    """A checkpoint holds Pipeline.state() (a versioned dict of what a resumed run needs), not the
    Pipeline object: a state of another version is refused by name, and one that round-trips through
    pickle continues the flight as the uninterrupted pipeline does."""
    import numpy as np
    import pytest

    from srmosaic_ros.config import pipeline_config
    from srmosaic_ros.io.bags import read_flight
    from srmosaic_ros.pipeline import STATE_VERSION, Pipeline

    items = list(read_flight(DEMO))
    cut = next(i for i, item in enumerate(items) if getattr(item, 'image', None) is not None and i > len(items) // 2)
    config = pipeline_config()
    whole = Pipeline(config)
    for item in items:
        whole.feed(item)
    first = Pipeline(config)
    for item in items[:cut]:
        first.feed(item)
    state = first.state()
    assert state['version'] == STATE_VERSION and 'segments' in state and 'registrar' not in state
    # every attribute of the pipeline and of each collaborator is either saved (its STATE) or rebuilt from
    # the config or handed over by the conductor: a new one must be added to its STATE (or here, when it is
    # rebuilt), or a resumed run would silently lose it
    from srmosaic_ros.pipeline import _STATE

    # (footprints: a cache of the segments' placements, filled again from them on demand)
    rebuilt = {first: {'config', 'undistorter', '_heap', 'telemetry', 'book', 'painter', 'revisits', 'settler', 'placer'},
               first.telemetry: {'config', 'clock'}, first.book: {'config'},
               first.placer: {'config', 'clock', 'registrar', 'telemetry', 'book', 'settler', 'revisits', 'painter'},
               first.settler: {'config', 'telemetry', 'book', 'painter'},
               first.revisits: {'config', 'clock', 'painter', 'footprints'},
               first.painter: {'config', 'clock', 'worker', 'input'}, first.painter.input: {'config'}}
    saved = {first: {'records', 'clock'}} | {part: {attr for _, attr in part.STATE} for part in rebuilt if part is not first}
    for part, names in rebuilt.items():
        assert set(vars(part)) == saved[part] | names, (type(part).__name__, set(vars(part)) ^ (saved[part] | names))
    assert sorted(_STATE) == sorted(['records', 'clock', *(key for part in saved if part is not first for key, _ in part.STATE)])
    # the checkpoint's keys are those written before the pipeline was split into collaborators: old ones load
    before_split = {'records', 'segments', 'fixes', 'imus', 'attitudes', 'georef', 'camera', 'clock', '_geo_canvas', '_active',
                    '_last_good', '_orphan', '_channels', '_waiting', '_first_fix_wait_over', '_latest_telemetry_ns',
                    '_settling', '_settling_seg', '_settled', '_fused', 'pose_check', '_settling_nis', '_unpainted', '_anchor',
                    '_tracker', '_thin', 'attitude_check'}
    assert set(state) == {'version', 'config'} | before_split and len(_STATE) == len(before_split)
    # ... and the classes they pickled by their names then (srmosaic_ros.pipeline._Held, .FrameRecord) still resolve
    import srmosaic_ros.pipeline as package
    from srmosaic_ros.pipeline.records import FrameRecord, Held

    assert package._Held is Held and package.FrameRecord is FrameRecord
    resumed = Pipeline.from_state(pickle.loads(pickle.dumps(state)))
    for item in items[cut:]:
        resumed.feed(item)
    a, b = whole.finish(), resumed.finish()
    assert [r.stamp_ns for r in a.records] == [r.stamp_ns for r in b.records]
    for ra, rb in zip(a.records, b.records, strict=True):
        assert ra.painted == rb.painted and ra.segment == rb.segment
        if ra.seg_H_frame is not None:
            assert np.array_equal(ra.seg_H_frame, rb.seg_H_frame)
    with pytest.raises(ValueError, match=f'version 0.*reads version {STATE_VERSION}'):
        Pipeline.from_state({**state, 'version': 0})
    with pytest.raises(ValueError, match='without'):
        Pipeline.from_state({'version': STATE_VERSION, 'config': config})
