"""One declaration per setting: its default, its valid range and what it means, on the config dataclass.

A section's dataclass (RegistrationConfig, GeorefConfig, ...) declares each key with :func:`setting`::

    max_features: int = setting(1000, lo=8, hi=100000, doc='keypoints kept per frame')
    gsd_m_per_px: float = setting(math.nan, gt=0, nan=True, unit='m/px')
    blend: str = setting('multiband', choices=('feather', 'multiband'))

and checks an instance with :func:`check_settings` in ``__post_init__``. The same :class:`Bounds` give
the ROS parameter descriptors' ranges (nodes/parameters.py) and the parameter reference (docs), so
the range a node advertises, the one the config refuses outside of, and the one the docs state
cannot disagree. params/*.yaml hold the defaults users read (a test keeps them equal to these).
"""
from __future__ import annotations

import math
from dataclasses import MISSING, dataclass, field, fields
from typing import Any

__all__ = ['Bounds', 'bounds_of', 'check_settings', 'setting']


@dataclass(frozen=True)
class Bounds:
    """The values a setting accepts.

    ``lo``/``hi``: inclusive bounds; ``gt``/``lt``: exclusive ones (None: unbounded). ``nan``: NaN
    ("not set") is accepted too; ``zero``: 0 ("off") is accepted besides the range; ``choices``: the
    only values accepted (strings); ``odd``: odd integers only; ``items``: for a tuple, the bounds of
    each item; ``length``: a tuple's length.
    """

    lo: float | None = None
    hi: float | None = None
    gt: float | None = None
    lt: float | None = None
    nan: bool = False
    zero: bool = False
    choices: tuple[Any, ...] = ()
    odd: bool = False
    items: Bounds | None = None
    length: int | None = None

    def holds(self, value: Any) -> bool:
        """Whether ``value`` is accepted."""
        if self.choices:
            return value in self.choices
        if isinstance(value, (tuple, list)):
            if self.length is not None and len(value) != self.length:
                return False
            return self.items is None or all(self.items.holds(v) for v in value)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return not self._numeric
        if isinstance(value, float) and math.isnan(value):
            return self.nan
        if self.zero and value == 0:
            return True
        if self.odd and (not float(value).is_integer() or int(value) % 2 == 0):
            return False
        return (math.isfinite(value) and (self.lo is None or value >= self.lo) and (self.hi is None or value <= self.hi)
                and (self.gt is None or value > self.gt) and (self.lt is None or value < self.lt))

    @property
    def _numeric(self) -> bool:
        return any(v is not None for v in (self.lo, self.hi, self.gt, self.lt)) or self.odd

    def text(self) -> str:
        """The range in words, e.g. '[0.05, 100]', '> 0 or NaN', 'one of huber, tukey'."""
        if self.choices:
            return 'one of ' + ', '.join(map(str, self.choices))
        if self.items is not None:
            n = f'{self.length} ' if self.length else ''
            return f'{n}values, each {self.items.text()}'
        lower = f'[{_num(self.lo)}' if self.lo is not None else f'({_num(self.gt)}' if self.gt is not None else None
        upper = f'{_num(self.hi)}]' if self.hi is not None else f'{_num(self.lt)})' if self.lt is not None else None
        if lower and upper:
            out = f'{lower}, {upper}'
        elif lower:
            out = f'>= {lower[1:]}' if self.lo is not None else f'> {lower[1:]}'
        elif upper:
            out = f'<= {upper[:-1]}' if self.hi is not None else f'< {upper[:-1]}'
        else:
            out = 'any number'
        if self.odd:
            out += ', odd'
        if self.zero:
            out = f'0 (off) or {out}'
        if self.nan:
            out += ' or NaN (not set)'
        return out

    def ros_range(self, integer: bool) -> tuple[float, float] | None:
        """The closed interval a ROS parameter descriptor can state (it has no open bounds, NaN, zero
        besides a range or choices; :meth:`holds` is checked after it), or None."""
        if self.choices and all(isinstance(c, int) and not isinstance(c, bool) for c in self.choices):
            return (min(self.choices), max(self.choices))
        if self.choices or self.items is not None or self.nan:
            return None
        lo = self.lo if self.lo is not None else self.gt
        hi = self.hi if self.hi is not None else self.lt
        if self.zero:
            lo = 0 if lo is None or lo > 0 else lo
        if lo is None and hi is None:
            return None
        big = 2**62 if integer else 1.7976931348623157e308
        return (-big if lo is None else lo, big if hi is None else hi)


def _num(v: float | None) -> str:
    return f'{v:g}' if isinstance(v, float) else str(v)


def setting(default: Any, *, doc: str = '', unit: str = '', **bounds: Any) -> Any:
    """A dataclass field with its default and its :class:`Bounds` (keyword arguments of Bounds)."""
    meta = {'bounds': Bounds(**bounds), 'doc': doc, 'unit': unit}
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=meta)
    return field(default=default, metadata=meta)


def bounds_of(cls: type) -> dict[str, Bounds]:
    """Field name -> Bounds of a config dataclass (the fields declared with :func:`setting`)."""
    return {f.name: f.metadata['bounds'] for f in fields(cls) if 'bounds' in f.metadata}


def default_of(cls: type, name: str) -> Any:
    """The declared default of field ``name`` of a config dataclass."""
    f = next(f for f in fields(cls) if f.name == name)
    return f.default if f.default is not MISSING else f.default_factory()  # type: ignore[misc]


def check_settings(obj: Any, section: str) -> None:
    """Raise ValueError naming every field of ``obj`` outside its declared range, with the range."""
    integers = {f.name for f in fields(obj) if f.type in ('int', int)}
    bad = [(name, b) for name, b in bounds_of(type(obj)).items() if not b.holds(getattr(obj, name))
           or (name in integers and not _is_integer(getattr(obj, name)))]
    if bad:
        said = '; '.join(f'{section}.{name}={getattr(obj, name)!r} (must be {"an integer, " if name in integers else ""}'
                         f'{b.text()})' for name, b in bad)
        msg = f'invalid {section} settings: {said}; see params/default.yaml and params/advanced.yaml.'
        raise ValueError(msg)


def _is_integer(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)
