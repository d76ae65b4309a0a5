"""Simulated flights and `process` runs shared by the test files: each built once, not once per file.

Both are built once for the whole session, every pytest-xdist worker included, and keyed by the
settings that make them:

- ``shared_dir(factory, name, build)``: a folder on disk (a bag, a folder of stills, a run's
  outputs), under the session's common temporary folder, behind a file lock: the first worker to
  ask builds it while the others wait for it, then take it. Tests only read these folders; one that
  must change a file copies the folder first.
- ``simulated(factory, config)``: a ``SimulatedFlight``, simulated once and kept pickled in such a
  folder; each process loads it once. Its frames' images are read-only: a test that changed a
  shared flight would change it for the tests after it, so an attempt raises instead.

The fixtures at the end are the flights and runs that several files take; a plugin of
test/conftest.py, so any test can ask for them by name.
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
import pickle
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from repo_paths import REPO
from srmosaic_ros.sim import SimConfig, SimulatedFlight, save_truth, simulate
from srmosaic_ros.sim.record import write_drone_stills, write_stills_folder

DEMO = REPO / 'bags' / 'demo'
CALITERRA = REPO / 'data' / 'sequences' / 'caliterra'

#: The simulated DJI survey (EXIF/XMP stills): 20 stills 2 s apart over two lawnmower legs 50 m apart
#: (the legs overlap), 2 deg gusts; test_survey_process.py and test_stills_metadata.py process it.
DRONE_SURVEY = SimConfig(width=320, height=240, world_gsd_m=0.3, trajectory='lawnmower', legs=2, leg_length_m=160.0,
                         leg_spacing_m=50.0, speed_m_s=10.0, rate_hz=0.5, gust_deg=2.0, seed=3)
#: A hover: 10 stills whose GPS tags span a few metres (1 m/s for 9 s).
HOVER = SimConfig(width=320, height=240, world_gsd_m=0.3, trajectory='line', frames=10, rate_hz=1.0, speed_m_s=1.0,
                  fix_rate_hz=1.0, seed=4)


def _session_root(factory: pytest.TempPathFactory) -> Path:
    """The temporary folder all of this session's processes share: under xdist, the parent of the
    worker's own (pytest's folder for this run; a new session gets a new one, so nothing built by an
    earlier run is taken); without xdist, the session's own."""
    base = factory.getbasetemp()
    return base.parent if os.environ.get('PYTEST_XDIST_WORKER') else base


@contextmanager
def _locked(path: Path) -> Iterator[None]:
    """An exclusive lock on ``path`` (created), held by this process for the block."""
    with open(path, 'a') as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def shared_dir(factory: pytest.TempPathFactory, name: str, build: Callable[[Path], None]) -> Path:
    """The folder ``name``, made by ``build(folder)`` once for the session: the first process to ask
    builds it, the others wait on the lock and take it. A build that raised leaves no folder marked
    done: the next to ask builds it again (and meets the same error)."""
    shared = _session_root(factory) / 'shared'
    shared.mkdir(exist_ok=True)
    folder, done = shared / name, shared / f'{name}.done'
    with _locked(shared / f'{name}.lock'):
        if not done.exists():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            build(folder)
            done.touch()
    return folder


def settings_key(*parts: object) -> str:
    """A short digest of settings (JSON-able, paths as strings): the name of what they make."""
    text = json.dumps([str(p) if isinstance(p, Path) else p for p in parts], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def processed(factory: pytest.TempPathFactory, source: Path, overrides: dict | None = None,
              **process_kwargs: object) -> tuple[Path, dict]:
    """``process_input(source, out, pipeline_config(overrides), progress=False, **process_kwargs)``
    once for the session: (out, the report it returned). The returned report is kept pickled beside
    the outputs, so that a test can still compare it with report.json."""
    from srmosaic_ros.app.process import process_input
    from srmosaic_ros.config import pipeline_config

    overrides = dict(overrides or {})

    def build(folder: Path) -> None:
        report = process_input(source, folder / 'out', pipeline_config(overrides), progress=False, **process_kwargs)
        (folder / 'returned.pkl').write_bytes(pickle.dumps(report))

    name = f'run-{source.name}-{settings_key(source, overrides, process_kwargs)}'
    folder = shared_dir(factory, name, build)
    return folder / 'out', pickle.loads((folder / 'returned.pkl').read_bytes())


_LOADED: dict[SimConfig, SimulatedFlight] = {}  # the flights this process has loaded


def simulated(factory: pytest.TempPathFactory, config: SimConfig) -> SimulatedFlight:
    """``simulate(config)``, once for the session; its frames' images read-only (the flight is shared)."""
    if config not in _LOADED:
        def build(folder: Path) -> None:
            (folder / 'flight.pkl').write_bytes(pickle.dumps(simulate(config)))

        folder = shared_dir(factory, f'flight-{settings_key(repr(config))}', build)
        flight = pickle.loads((folder / 'flight.pkl').read_bytes())
        for frame in flight.frames:
            frame.image.flags.writeable = False
        _LOADED[config] = flight
    return _LOADED[config]


def stills_of(factory: pytest.TempPathFactory, config: SimConfig, *, drone: bool) -> Path:
    """A folder with the stills of ``config``'s flight in survey/ (EXIF/XMP only when ``drone``, else
    PNGs with telemetry_from_exif.csv) and its truth in truth.json, once for the session."""
    def build(root: Path) -> None:
        flight = simulated(factory, config)
        (write_drone_stills if drone else write_stills_folder)(flight, root / 'survey')
        save_truth(flight.truth, root / 'truth.json')

    kind = 'drone' if drone else 'stills'
    return shared_dir(factory, f'{kind}-{settings_key(repr(config))}', build)


@pytest.fixture(scope='session')
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """The bundled demo bag processed with the defaults, as `srmosaic process bags/demo --out DIR`
    runs it: (output folder, the report process_input returned). Read-only."""
    return processed(tmp_path_factory, DEMO)


@pytest.fixture(scope='session')
def caliterra_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """The bundled caliterra stills processed with the defaults (aligned globally): (output folder,
    report). Read-only."""
    return processed(tmp_path_factory, CALITERRA)


@pytest.fixture(scope='session')
def drone_survey(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """DRONE_SURVEY's stills with their metadata in EXIF and XMP only (survey/, gimbal angles with
    0.5 deg noise) and truth.json. Read-only."""
    return stills_of(tmp_path_factory, DRONE_SURVEY, drone=True)


@pytest.fixture(scope='session')
def hover_stills(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """HOVER's stills as PNGs with telemetry_from_exif.csv (survey/) and truth.json. Read-only."""
    return stills_of(tmp_path_factory, HOVER, drone=False) / 'survey'
