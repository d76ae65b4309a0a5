"""Checkpoints of a long offline run, so that `srmosaic process ... --resume` continues after a crash.

Every N frames the whole pipeline state (chain, segments and their canvases, records, telemetry,
and the mosaic-video recorder) is pickled to DIR/.checkpoint/state.pkl, written to a temporary
file and renamed into place, so a kill -9 at any moment leaves either the previous or the new
checkpoint, never a torn one. The checkpoint also records how many input items (frames and
telemetry) were consumed and a fingerprint of the input and settings; --resume refuses a
checkpoint of another input or other settings.
"""
from __future__ import annotations

import hashlib
import os
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import InputError
from .io.mosaic_files import atomic_path

__all__ = ['Checkpoint', 'checkpoint_path', 'fingerprint', 'load_checkpoint', 'save_checkpoint']

FORMAT = 1


@dataclass
class Checkpoint:
    fingerprint: str
    items_consumed: int
    frames_consumed: int
    pipeline: Any
    recorder: Any = None
    recent: dict[int, Any] | None = None
    format: int = FORMAT


def checkpoint_path(out: Path) -> Path:
    return Path(out) / '.checkpoint' / 'state.pkl'


def fingerprint(input_path: Path, settings: dict[str, Any]) -> str:
    """Identity of a run: the input's path, size and mtime (of the folder's files) and the settings."""
    p = Path(input_path)
    files = sorted(p.rglob('*')) if p.is_dir() else [p]
    h = hashlib.sha256(repr(sorted(settings.items())).encode())
    for f in files:
        if f.is_file():
            st = f.stat()
            h.update(f'{f.name}:{st.st_size}:{int(st.st_mtime)}'.encode())
    return h.hexdigest()[:16]


def save_checkpoint(out: Path, state: Checkpoint) -> None:
    path = checkpoint_path(out)
    with atomic_path(path) as tmp, open(tmp, 'wb') as handle:
        pickle.dump(state, handle, protocol=pickle.HIGHEST_PROTOCOL)
        handle.flush()
        os.fsync(handle.fileno())


def load_checkpoint(out: Path, expected_fingerprint: str) -> Checkpoint:
    path = checkpoint_path(out)
    if not path.is_file():
        msg = f'--resume: no checkpoint in {out} (a run writes one every --checkpoint-every frames); run without --resume.'
        raise InputError(msg)
    try:
        with open(path, 'rb') as handle:
            state = pickle.load(handle)  # noqa: S301 - our own file in the user's output directory
    except Exception as exc:  # noqa: BLE001
        msg = f'--resume: the checkpoint {path} is unreadable ({exc}); run without --resume.'
        raise InputError(msg) from None
    if not isinstance(state, Checkpoint) or state.format != FORMAT:
        msg = f'--resume: {path} is not a checkpoint of this version; run without --resume.'
        raise InputError(msg)
    if state.fingerprint != expected_fingerprint:
        msg = (f'--resume: the checkpoint in {out} belongs to another input or other settings; '
               'resume with the same command, or run without --resume.')
        raise InputError(msg)
    return state
