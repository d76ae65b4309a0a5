"""YAML that a user hands over (parameter files, launch descriptions, camera calibrations), read with limits.

PyYAML's safe loader builds any document it is given: ten anchors each holding nine aliases of the
last expand to 9^10 values (memory grows for minutes), and 5000 nested brackets overflow Python's
recursion in its composer (a traceback of thousands of lines). These files hold a few hundred
plain values, so the loader here refuses:

- aliases (``*name``): a parameter file has no use for them; anchors alone are harmless;
- nesting deeper than MAX_DEPTH collections, and documents of more than MAX_NODES nodes;
- files larger than MAX_BYTES.

Each refusal is a :class:`LimitError` (a ``yaml.YAMLError``) whose ``problem`` says which limit,
what to do, and where (line, column), so callers report it as they report any other YAML mistake. :func:`preview` shortens a value for
an error message.
"""
from __future__ import annotations

import reprlib
from typing import Any

import yaml
from yaml.composer import ComposerError

__all__ = ['MAX_BYTES', 'MAX_DEPTH', 'MAX_NODES', 'BoundedLoader', 'LimitError', 'load_bounded', 'preview']

#: Collections nested deeper than this are refused.
MAX_DEPTH = 32
#: Documents of more nodes (scalars and collections) than this are refused.
MAX_NODES = 100_000
#: Files larger than this (bytes) are refused.
MAX_BYTES = 4 << 20


class LimitError(ComposerError):
    """A document beyond the loader's limits (an alias, too deep, too many values, too large)."""

    def __init__(self, problem: str, mark: Any = None) -> None:
        super().__init__(None, None, problem, mark)


class BoundedLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader without aliases, with MAX_DEPTH and MAX_NODES (module docstring)."""

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        self._depth = 0
        self._nodes = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise LimitError(f'an alias (*{event.anchor}) is not allowed in a file of settings (write the value out)',
                             event.start_mark)
        self._nodes += 1
        if self._nodes > MAX_NODES:
            raise LimitError(f'more than {MAX_NODES} values in one document (a file of settings holds a few hundred)',
                             self.peek_event().start_mark)
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                raise LimitError(f'values nested more than {MAX_DEPTH} deep (a setting is a number, a string or a '
                                 'short list)', self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def load_bounded(text: str) -> Any:
    """The one YAML document of ``text``, within the limits (raises yaml.YAMLError otherwise)."""
    if len(text) > MAX_BYTES:
        raise LimitError(f'{len(text)} characters, more than the {MAX_BYTES} a file of settings may hold (is it the '
                         'right file?)')
    loader = BoundedLoader(text)
    try:
        return loader.get_single_data()
    finally:
        loader.dispose()


_SHORT = reprlib.Repr()
_SHORT.maxstring = 40
_SHORT.maxother = 40
_SHORT.maxlist = _SHORT.maxtuple = _SHORT.maxdict = _SHORT.maxset = 4
_SHORT.maxlevel = 2


def preview(value: Any, limit: int = 60) -> str:
    """``repr(value)`` shortened for an error message: nested and long values elided with '...', at most
    about ``limit`` characters."""
    text = _SHORT.repr(value)
    return text if len(text) <= limit else text[:limit - 3] + '...'
