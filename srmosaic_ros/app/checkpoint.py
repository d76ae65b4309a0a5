"""Checkpoints of a long offline run, so that `srmosaic process ... --resume` continues after a crash.

Every N frames what a resumed run needs (Pipeline.state(): a versioned dict of the records,
segments and their canvases, telemetry, filter and held frames, by name; and the mosaic-video
recorder) is pickled to DIR/.checkpoint/state.pkl, written to a temporary
file and renamed into place, so a kill -9 at any moment leaves either the previous or the new
checkpoint, never a torn one. The checkpoint also records how many input items (frames and
telemetry) were consumed and a fingerprint of the input and settings; --resume refuses a
checkpoint of another input or other settings.

The file is a header line (magic, format, fingerprint, progress, SHA-256 of the payload) and the
pickled payload. --resume checks the header before it unpickles anything, and unpickles with an
allow-list of the classes the package writes (its own, numpy's, torch's tensors, filterpy's
filter), so a checkpoint made by hand cannot run code.
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..io.mosaic_files import atomic_path

__all__ = ['Checkpoint', 'checkpoint_path', 'fingerprint', 'load_checkpoint', 'read_header', 'save_checkpoint']

# 4: canvases hold a compositor; 5: the Georeferencer exists from the start (pipeline/telemetry_sync.py)
FORMAT = 5  # the payload holds the pipeline's state() (other formats are refused)
MAGIC = b'SRMOSAIC-CHECKPOINT '


@dataclass
class Checkpoint:
    fingerprint: str
    items_consumed: int
    frames_consumed: int
    pipeline: dict[str, Any]  # Pipeline.state()
    recorder: Any = None
    recent: dict[int, Any] | None = None
    format: int = FORMAT
    mount_restart: dict[str, Any] | None = None  # report.json's mount_from_frames, when the run started again


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
    payload = pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL)
    header = {'format': FORMAT, 'fingerprint': state.fingerprint, 'items_consumed': state.items_consumed,
              'frames_consumed': state.frames_consumed, 'sha256': hashlib.sha256(payload).hexdigest()}
    with atomic_path(path) as tmp, open(tmp, 'wb') as handle:
        handle.write(MAGIC + json.dumps(header).encode() + b'\n')
        handle.write(payload)
        handle.flush()
        os.fsync(handle.fileno())


def read_header(path: Path) -> dict[str, Any] | None:
    """The header of a checkpoint file (format, fingerprint, items_consumed, frames_consumed,
    sha256), or None when the file does not start like one (not a checkpoint, or another format)."""
    try:
        with open(path, 'rb') as handle:
            line = handle.readline(4096)
    except OSError:
        return None
    if not line.startswith(MAGIC) or not line.endswith(b'\n'):
        return None
    try:
        header = json.loads(line[len(MAGIC):])
    except ValueError:
        return None
    return header if isinstance(header, dict) else None


def load_checkpoint(out: Path, expected_fingerprint: str) -> Checkpoint:
    path = checkpoint_path(out)
    if not path.is_file():
        msg = f'--resume: no checkpoint in {out} (a run writes one every --checkpoint-every frames); run without --resume.'
        raise InputError(msg)
    header = read_header(path)
    if header is None or header.get('format') != FORMAT:
        msg = f'--resume: {path} is not a checkpoint of this version; run without --resume.'
        raise InputError(msg)
    if header.get('fingerprint') != expected_fingerprint:
        msg = (f'--resume: the checkpoint in {out} belongs to another input or other settings; '
               'resume with the same command, or run without --resume.')
        raise InputError(msg)
    with open(path, 'rb') as handle:
        handle.readline()
        payload = handle.read()
    if hashlib.sha256(payload).hexdigest() != header.get('sha256'):
        msg = f'--resume: the checkpoint {path} does not match its own checksum (damaged or edited); run without --resume.'
        raise InputError(msg)
    try:
        state = _CheckpointUnpickler(io.BytesIO(payload)).load()
    except pickle.UnpicklingError as exc:
        msg = f'--resume: the checkpoint {path} refers to {exc}, which a checkpoint never holds; run without --resume.'
        raise InputError(msg) from None
    except Exception as exc:  # noqa: BLE001
        msg = f'--resume: the checkpoint {path} is unreadable ({exc}); run without --resume.'
        raise InputError(msg) from None
    if not isinstance(state, Checkpoint) or state.format != FORMAT or state.fingerprint != expected_fingerprint:
        msg = f'--resume: {path} is not a checkpoint of this version; run without --resume.'
        raise InputError(msg)
    return state


def _tensor_storage_from_bytes(b: bytes) -> Any:
    """torch.storage._load_from_bytes, which unpickles with weights_only=False, made safe."""
    import torch

    return torch.load(io.BytesIO(b), weights_only=True)


# What the pipeline's state pickles to, beyond the package's own classes (found by listing the
# globals of checkpoints of bags, videos and stills). Anything else is refused before it is loaded.
_ALLOWED = {
    'builtins': {'set', 'frozenset', 'slice', 'range', 'complex', 'bytearray', 'list', 'dict', 'tuple', 'int',
                 'float', 'bool', 'str', 'bytes'},
    'collections': {'OrderedDict', 'deque', 'defaultdict', 'Counter'},
    'pathlib': {'Path', 'PosixPath', 'WindowsPath', 'PurePosixPath', 'PureWindowsPath'},
    'numpy.linalg': {'inv'},
    'scipy.linalg._decomp_cholesky': {'cholesky'},
    'torch._utils': {'_rebuild_tensor_v2', '_rebuild_parameter'},
    'filterpy.kalman.UKF': {'UnscentedKalmanFilter'},
    'filterpy.kalman.sigma_points': {'MerweScaledSigmaPoints', 'JulierSigmaPoints'},
}
_NUMPY_HELPERS = {'scalar', '_reconstruct', '_frombuffer', 'dtype', 'ndarray'}
_PACKAGE_FUNCTIONS = {('srmosaic_ros.core.georef.ukf', '_constant_velocity'),
                      ('srmosaic_ros.core.georef.ukf', '_slot_cur_position'),
                      ('srmosaic_ros.core.mosaic.tile_store', '_restore_store')}


class _CheckpointUnpickler(pickle.Unpickler):
    """Resolves only the globals a checkpoint of this package holds."""

    def find_class(self, module: str, name: str) -> Any:
        import numpy as np


        if module == 'torch.storage' and name == '_load_from_bytes':
            return _tensor_storage_from_bytes
        obj = None
        if name in _ALLOWED.get(module, ()):
            obj = super().find_class(module, name)
        elif module == 'srmosaic_ros' or module.startswith('srmosaic_ros.'):
            found = super().find_class(module, name)
            if isinstance(found, type) or (module, name) in _PACKAGE_FUNCTIONS:
                obj = found
        elif module.split('.')[0] == 'numpy':
            found = super().find_class(module, name)
            if name in _NUMPY_HELPERS or isinstance(found, (np.ufunc, np.dtype)) or (
                    isinstance(found, type) and issubclass(found, (np.generic, np.dtype))):
                obj = found
        elif module == 'torch':
            import torch

            found = super().find_class(module, name)
            if isinstance(found, (torch.dtype, torch.device)) or found in (torch.device, torch.Size, torch.dtype):
                obj = found
        if obj is None:
            raise pickle.UnpicklingError(f'{module}.{name}')
        return obj
