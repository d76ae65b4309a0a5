"""The message types of one bag: each connection's own definition registered on its own, else the
release's (ROS 2 Jazzy's, ROS 1 Noetic's for a ROS 1 bag), and the ROS 1 -> CDR conversion types."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .bag_problems import _describe

if TYPE_CHECKING:
    from collections.abc import Iterable

    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

__all__: list[str] = []  # private to the bag layer: io/bags.py is the way in


class BagTypes:
    """Types of a bag's connections, registered per message type on demand (:meth:`prepare_types`).

    ``type_notes``: topic -> why the bag's own definition was not used (a release type was instead).
    """

    def __init__(self, *, ros1: bool) -> None:
        self.ros1 = ros1
        self.type_notes: dict[str, str] = {}
        self._note_of_type: dict[str, str] = {}
        self._stores: dict[str, Typestore] = {}
        self._default: Typestore | None = None
        self._shared: Typestore | None = None
        self._cdr_stores: dict[str, Typestore] = {}
        self._cdr_of_store: dict[int, Typestore] = {}

    def _default_store(self) -> Typestore:
        from rosbags.typesys import Stores, get_typestore

        if self._default is None:
            self._default = get_typestore(
                Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_JAZZY)
        return self._default

    def prepare_types(self, connections: Iterable[Connection]) -> dict[str, str]:
        """Make the types of ``connections`` deserialisable; topic -> why not, for those that fail.

        Each connection's own definition is parsed and registered on its own, so that one
        unparsable definition touches no other type (a definition conflicting with an earlier
        one gets a typestore of its own); without a usable definition, ROS 2 Jazzy's (ROS 1
        Noetic's) type is used, and where a definition failed that is noted in ``type_notes``.
        """
        from rosbags.interfaces import MessageDefinitionFormat

        problems: dict[str, str] = {}
        failed: dict[str, str] = {}
        for connection in connections:
            msgtype = connection.msgtype
            if msgtype in self._stores:
                if msgtype in self._note_of_type:
                    self.type_notes[connection.topic] = self._note_of_type[msgtype]
                continue
            if msgtype in failed:
                problems[connection.topic] = failed[msgtype]
                continue
            reason = ''
            if connection.msgdef.format != MessageDefinitionFormat.NONE:
                try:
                    store = self._register(_parse_definition(connection), msgtype)
                except Exception as exc:  # noqa: BLE001 - contained: this type only
                    reason = _definition_problem(connection, exc)
                else:
                    self._stores[msgtype] = store
                    continue
            default = self._default_store()
            if msgtype in default.fielddefs:
                self._stores[msgtype] = default
                release = 'ROS 1 Noetic' if self.ros1 else 'ROS 2 Jazzy'
                if reason:
                    self._note_of_type[msgtype] = f'{reason}; {release}\'s {msgtype} is used instead'
                    self.type_notes[connection.topic] = self._note_of_type[msgtype]
                continue
            if not reason:
                reason = (
                    f'the bag carries no definition of {msgtype} and '
                    f'{"ROS 1 Noetic" if self.ros1 else "ROS 2 Jazzy"} has no such type')
            failed[msgtype] = reason
            problems[connection.topic] = reason
        return problems

    def _register(self, types: dict[str, Any], msgtype: str) -> Typestore:
        """A store holding ``types``: the bag's shared one, or a store of their own on a conflict."""
        from rosbags.typesys import Stores, get_typestore

        if msgtype not in types:
            msg = f'the definition does not define {msgtype}'
            raise KeyError(msg)
        if self._shared is None:
            self._shared = get_typestore(Stores.EMPTY)
        try:
            self._shared.register(types)  # checks every type before adding any
        except Exception:  # noqa: BLE001 - two topics defining a type differently
            own = get_typestore(Stores.EMPTY)
            own.register(types)
            return own
        return self._shared

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        store = self._stores[msgtype]
        if self.ros1:
            return store.deserialize_ros1(raw, msgtype)
        return store.deserialize_cdr(raw, msgtype)

    def prepare_ros1_to_cdr(self, connections: Iterable[Connection]) -> dict[str, str]:
        """Like :meth:`prepare_types`, for converting ROS 1 messages to CDR (:meth:`ros1_to_cdr`).

        rosbags converts a ROS 1 std_msgs/Header (seq, stamp, frame_id) to ROS 2's (stamp,
        frame_id) only when its typestore holds ROS 2's Header, so the conversion types are the
        bag's with ROS 2 Jazzy's Header (and builtin_interfaces/Time) in its place.
        """
        from rosbags.typesys import Stores, get_typestore

        connections = list(connections)
        problems = self.prepare_types(connections)
        jazzy: Typestore | None = None
        for connection in connections:
            msgtype = connection.msgtype
            if connection.topic in problems or msgtype in self._cdr_stores:
                continue
            store = self._stores[msgtype]
            cdr = self._cdr_of_store.setdefault(id(store), get_typestore(Stores.EMPTY))
            if msgtype not in cdr.fielddefs:
                types = dict(store.fielddefs)
                if 'std_msgs/msg/Header' in types:
                    jazzy = jazzy or get_typestore(Stores.ROS2_JAZZY)
                    for name in ('std_msgs/msg/Header', 'builtin_interfaces/msg/Time'):
                        types[name] = jazzy.fielddefs[name]
                try:
                    cdr.register(types)
                except Exception as exc:  # noqa: BLE001 - contained: this type only
                    problems[connection.topic] = (
                        f'its type {msgtype} cannot be prepared for conversion to CDR ({_describe(exc)})')
                    continue
            self._cdr_stores[msgtype] = cdr
        return problems

    def ros1_to_cdr(self, raw: bytes, msgtype: str) -> bytes:
        return bytes(self._cdr_stores[msgtype].ros1_to_cdr(raw, msgtype))


def _parse_definition(connection: Connection) -> dict[str, Any]:
    """Types of a connection's own message definition (as rosbags' AnyReader parses them)."""
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    data = connection.msgdef.data
    if connection.msgdef.format == MessageDefinitionFormat.MSG:
        return dict(get_types_from_msg(data, connection.msgtype))
    sep = '=' * 80 + '\n'
    if data.startswith(f'{sep}IDL: '):
        types: dict[str, Any] = {}
        for part in data.split(sep)[1:]:
            _, idl = part.split('\n', 1)
            types.update(get_types_from_idl(idl))
        return types
    return dict(get_types_from_idl(data))


def _definition_problem(connection: Connection, exc: BaseException) -> str:
    if any(line.strip() == '---' for line in connection.msgdef.data.splitlines()):
        # rosbag2 (Jazzy) writes a service event topic's schema as the .srv text, request and
        # response parts split by '---', which is no message definition (ros2/rosbag2#2365).
        return (
            f'its definition of {connection.msgtype} in the bag is a service/action text with '
            "'---', not a message definition")
    return f'its definition of {connection.msgtype} in the bag cannot be parsed ({_describe(exc)})'
