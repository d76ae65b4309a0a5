"""One error hierarchy for the package.

Every message says what was wrong and what to try. Offline commands turn any
:class:`SrMosaicError` into a one-line message and a non-zero exit; nodes log it
(throttled) and keep spinning.
"""
from __future__ import annotations

import errno

__all__ = [
    'FULL_DISK_ERRNOS',
    'SrMosaicError',
    'ConfigError',
    'MessageError',
    'BagError',
    'InputError',
    'MetadataError',
    'OutputError',
    'RegistrationError',
    'SimulationError',
]


#: OSError numbers of a write that found no room: a full disk, a file size limit, a quota.
FULL_DISK_ERRNOS = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT)


class SrMosaicError(Exception):
    """Base of all errors raised on purpose by srmosaic_ros."""


class ConfigError(SrMosaicError):
    """A parameter or configuration file is invalid."""


class MessageError(SrMosaicError):
    """A ROS message cannot be converted (bad encoding, size mismatch, NaN field...)."""


class BagError(SrMosaicError):
    """A bag cannot be read or written (missing, truncated, corrupt, missing topic, unknown type)."""


class InputError(SrMosaicError):
    """An input file or argument is unusable (missing file, unreadable image...)."""


class MetadataError(InputError):
    """Metadata carried by an input (EXIF/XMP, MISB KLV, DJI SRT, GoPro GPMF) is unusable as a whole.

    A single bad record (a packet failing its checksum, an SRT block without GPS) is not an error:
    readers count and skip it, and say so in the report.
    """


class OutputError(SrMosaicError):
    """The output directory cannot take a run's files (a file in its place, no permission, a name too
    long, no space): found before any processing."""


class RegistrationError(SrMosaicError):
    """Registration cannot proceed at all (not a single failed frame: that is Registration.ok=False)."""


class SimulationError(SrMosaicError):
    """A synthetic flight cannot be generated with the given settings."""
