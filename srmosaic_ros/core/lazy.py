"""PEP 562 lazy attributes for a package ``__init__``: names imported from their submodule on first
use, so a process that needs none of them (a node without torch) does not import it."""
from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

__all__ = ['lazy_attributes']


def lazy_attributes(package: str, lazy: dict[str, str],
                    names: dict[str, Any]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """(``__getattr__``, ``__dir__``) of ``package``: ``lazy`` maps a name to its submodule (relative,
    without the dot); ``names`` is the package's ``globals()``."""

    def getattr_(name: str) -> Any:
        if name in lazy:
            return getattr(importlib.import_module(f'.{lazy[name]}', package), name)
        msg = f'module {package!r} has no attribute {name!r}'
        raise AttributeError(msg)

    def dir_() -> list[str]:
        return sorted({*names, *lazy})

    return getattr_, dir_
