"""test/flights.py, the flights and runs the test files share: built once for the session (every
process included), rebuilt after a build that failed, and shared read-only."""
from __future__ import annotations

import multiprocessing
from pathlib import Path

import numpy as np
import pytest

import flights
from srmosaic_ros.sim import SimConfig


class _Factory:
    """The one method of pytest.TempPathFactory that flights.py asks for, over a folder of our own."""

    def __init__(self, base: Path) -> None:
        self.base = base

    def getbasetemp(self) -> Path:
        return self.base


def _append_pid(folder: Path) -> None:
    """A build that leaves a trace of who ran it, in a file beside the folder (it outlives a rebuild)."""
    import os

    with open(folder.parent / 'builds.txt', 'a') as handle:
        handle.write(f'{os.getpid()}\n')
    (folder / 'made').write_text('yes')


def _ask(base: str, go) -> None:
    go.wait()
    flights.shared_dir(_Factory(Path(base)), 'thing', _append_pid)


def test_a_shared_folder_is_built_once_by_the_processes_that_ask_at_once(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.delenv('PYTEST_XDIST_WORKER', raising=False)  # the factory's folder is the session's
    ctx = multiprocessing.get_context('fork')
    go = ctx.Event()
    procs = [ctx.Process(target=_ask, args=(str(tmp_path), go)) for _ in range(4)]
    for p in procs:
        p.start()
    go.set()  # all four ask together: one builds, three wait on the lock and take its folder
    for p in procs:
        p.join()
    assert [p.exitcode for p in procs] == [0] * 4
    assert len((tmp_path / 'shared' / 'builds.txt').read_text().split()) == 1
    folder = flights.shared_dir(_Factory(tmp_path), 'thing', _append_pid)  # and this process takes it too
    assert (folder / 'made').read_text() == 'yes'
    assert len((tmp_path / 'shared' / 'builds.txt').read_text().split()) == 1


def test_a_build_that_failed_is_built_again(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.delenv('PYTEST_XDIST_WORKER', raising=False)

    def broken(folder: Path) -> None:
        (folder / 'half').write_text('written before the error')
        raise RuntimeError('no')

    with pytest.raises(RuntimeError, match='no'):
        flights.shared_dir(_Factory(tmp_path), 'thing', broken)
    folder = flights.shared_dir(_Factory(tmp_path), 'thing', _append_pid)
    assert sorted(p.name for p in folder.iterdir()) == ['made']  # nothing left of the failed build


def test_under_xdist_the_workers_share_the_parent_of_their_folders(tmp_path: Path, monkeypatch) -> None:
    (tmp_path / 'gw0').mkdir()
    (tmp_path / 'gw1').mkdir()
    monkeypatch.setenv('PYTEST_XDIST_WORKER', 'gw0')
    a = flights.shared_dir(_Factory(tmp_path / 'gw0'), 'thing', _append_pid)
    monkeypatch.setenv('PYTEST_XDIST_WORKER', 'gw1')
    b = flights.shared_dir(_Factory(tmp_path / 'gw1'), 'thing', _append_pid)
    assert a == b == tmp_path / 'shared' / 'thing'
    assert len((tmp_path / 'shared' / 'builds.txt').read_text().split()) == 1


def test_settings_name_what_they_make() -> None:
    a = flights.settings_key(Path('/x/bag'), {'mosaic.blend': 'feather'}, {})
    assert a == flights.settings_key('/x/bag', {'mosaic.blend': 'feather'}, {})
    assert a != flights.settings_key(Path('/x/bag'), {'mosaic.blend': 'bestview'}, {})
    assert a != flights.settings_key(Path('/x/bag'), {'mosaic.blend': 'feather'}, {'sr_factor': 2})


def test_a_shared_flight_is_simulated_once_and_read_only(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.delenv('PYTEST_XDIST_WORKER', raising=False)
    monkeypatch.setattr(flights, '_LOADED', {})
    config = SimConfig(width=32, height=24, frames=2, seed=1)
    flight = flights.simulated(_Factory(tmp_path), config)
    assert flights.simulated(_Factory(tmp_path), config) is flight  # loaded once per process
    monkeypatch.setattr(flights, '_LOADED', {})  # another process: loads what the first simulated
    again = flights.simulated(_Factory(tmp_path), config)
    assert again is not flight and len(list((tmp_path / 'shared').glob('flight-*.done'))) == 1
    for a, b in zip(flight.frames, again.frames):
        np.testing.assert_array_equal(a.image, b.image)
    with pytest.raises(ValueError, match='read-only'):
        again.frames[0].image[0, 0] = 0
    other = flights.simulated(_Factory(tmp_path), SimConfig(width=32, height=24, frames=2, seed=2))
    assert len(list((tmp_path / 'shared').glob('flight-*.done'))) == 2
    assert not np.array_equal(other.frames[0].image, flight.frames[0].image)
