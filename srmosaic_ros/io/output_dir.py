"""The output folder of a run: checked before any work, written through a staging folder and a
lock so that a failed or concurrent run never leaves a mix of two runs' files."""
from __future__ import annotations

import json
import logging
import os
import shutil
from pathlib import Path
from typing import Any

from ..errors import OutputError, SrMosaicError

_LOG = logging.getLogger(__name__)

__all__ = ['RUN_OUTPUTS', 'OutputTransaction', 'check_output_dir']


#: What `process` writes into --out (and report.json); an earlier run's copy that this run did not write is removed.
RUN_OUTPUTS = ('mosaic.png', 'preview.png', 'moving.png', 'mosaic.tif', 'mosaic.kml', 'poses.csv', 'frames.csv', 'mosaic.mp4',
               'segments', 'sr', 'mosaic.kmz', 'tiles', 'map.html', 'map_config.js', 'map_files')


class OutputTransaction:
    """A run's outputs written into ``out``/.staging-PID and moved into ``out`` when the run ends.

    Entering takes ``out``/.srmosaic.lock (fcntl.flock): a second writer is refused with the other's
    pid. On a normal exit each of RUN_OUTPUTS and report.json is moved in (os.replace, report.json
    last); those that this run did not write are removed from ``out`` (``removed``). When the run
    raises with outputs in the staging folder (a damaged input: what was processed so far), they are
    moved in the same way unless ``out`` holds an earlier complete run (a report.json without an
    error): then they go to ``out``/failed_run/ and the earlier run stays. Files of other programs in
    ``out`` are never touched.
    """

    def __init__(self, out: Path) -> None:
        self.out = Path(out)
        self.stage = self.out / f'.staging-{os.getpid()}'
        self.removed: list[str] = []
        self._lock: Any = None

    def __enter__(self) -> OutputTransaction:
        import fcntl

        self._lock = open(self.out / '.srmosaic.lock', 'a+')  # held for the run
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._lock.seek(0)
            other = self._lock.read().strip() or 'unknown'
            self._lock.close()
            msg = (f'another srmosaic process (pid {other}) is writing {self.out}; wait for it to end or give '
                   'another --out.')
            raise OutputError(msg) from None
        self._lock.seek(0)
        self._lock.truncate()
        self._lock.write(str(os.getpid()))
        self._lock.flush()
        for left in self.out.glob('.staging-*'):  # of a run killed (kill -9): the lock says none is writing
            shutil.rmtree(left, ignore_errors=True)
        self.stage.mkdir()
        return self

    def __exit__(self, exc_type: type | None, exc: BaseException | None, tb: Any) -> None:
        try:
            if exc_type is None:
                self.removed = self._publish(self.out)
            elif isinstance(exc, SrMosaicError) and (self.stage / 'report.json').is_file():
                if self._earlier_complete_run():
                    failed = self.out / 'failed_run'
                    shutil.rmtree(failed, ignore_errors=True)
                    failed.mkdir()
                    self._publish(failed)
                    _LOG.warning('the earlier complete run in %s is kept; this run\'s partial outputs are in %s',
                                 self.out, failed)
                else:
                    self.removed = self._publish(self.out)
        finally:
            shutil.rmtree(self.stage, ignore_errors=True)
            (self.out / '.srmosaic.lock').unlink(missing_ok=True)  # still held: no other writer is inside
            self._lock.close()

    def _earlier_complete_run(self) -> bool:
        try:
            return 'error' not in json.loads((self.out / 'report.json').read_text())
        except (OSError, ValueError):
            return False

    def _publish(self, dst: Path) -> list[str]:
        """Move the staged outputs into ``dst``; remove there what this run did not write."""
        removed = []
        for name in (*RUN_OUTPUTS, 'report.json'):
            src, target = self.stage / name, dst / name
            if src.exists():
                if target.is_dir() and not target.is_symlink():
                    old = self.stage / f'.old-{name}'
                    os.replace(target, old)
                os.replace(src, target)
            elif target.is_dir() and not target.is_symlink():
                shutil.rmtree(target)
                removed.append(name)
            elif target.exists():
                target.unlink()
                removed.append(name)
        if removed:
            _LOG.info('removed the outputs of an earlier run that this one did not write: %s', ', '.join(removed))
        return removed


def check_output_dir(out: Path, what: str = '--out') -> None:
    """Make sure ``out`` can take a run's files before any work is done: it is (or is created as) a
    directory one can write into. Raises OutputError naming the problem and the way out."""
    import tempfile

    out = Path(out)
    too_long = [part for part in out.parts if len(os.fsencode(part)) > 255]
    if too_long:
        msg = f'{what} {out}: the name {too_long[0][:40]}... is longer than 255 bytes; give a shorter directory name.'
        raise OutputError(msg)
    if out.exists() and not out.is_dir():
        msg = f'{what} {out} is a file, not a directory; give a directory (it is created if missing).'
        raise OutputError(msg)
    parent = out
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        msg = f'{what} {out} lies under {parent}, which is a file; give a directory elsewhere.'
        raise OutputError(msg)
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix='.write-test.', dir=out)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        msg = f'{what} {out} cannot be written ({exc.strerror or exc}); give a directory you may write to.'
        raise OutputError(msg) from None
