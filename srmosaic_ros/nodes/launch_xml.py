"""Read a ROS 2 launch XML file (the subset this package's launch files use) into node commands.

`srmosaic launch FILE.launch.xml [name:=value ...]` starts the nodes of a launch file where
`ros2 launch` is not installed, with the same file and the same arguments. Understood:

- ``<launch>``, ``<arg name default description>``, ``<let name value>``;
- ``<group>`` (scoped, with ``if``/``unless``) and ``<push-ros-namespace namespace>`` in it;
- ``<node pkg exec name namespace args output if unless>`` of this package's executables, with
  ``<param from="FILE"/>``, ``<param name value/>`` and ``<remap from to/>``;
- ``<lifecycle_node>`` (launch_ros's element for managed nodes: the same, with ``name`` required and
  ``autostart``): with autostart true the launcher configures, then activates, every such node
  (lifecycle_driver.py), as ros2 launch does;
- substitutions ``$(var NAME)``, ``$(env NAME [default])``, ``$(find-pkg-share srmosaic_ros)``.

Anything else is refused with its name, rather than skipped (a node that silently did not start
is worse than an error): use `ros2 launch` for the full language.
"""
from __future__ import annotations

import os
import re
import shlex
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import ConfigError

__all__ = ['LaunchNode', 'read_launch_xml', 'parse_launch_arguments', 'package_share']

PACKAGE = 'srmosaic_ros'
_SUBSTITUTION = re.compile(r'\$\(([a-z-]+)((?:\s+[^()\s]+)*)\s*\)')
_TRUE, _FALSE = {'true', '1'}, {'false', '0'}


@dataclass
class LaunchNode:
    """One node of a launch file: the executable and what its command line carries."""

    executable: str
    name: str | None = None
    namespace: str = '/'
    arguments: list[str] = field(default_factory=list)
    param_files: list[str] = field(default_factory=list)
    parameters: dict[str, str] = field(default_factory=dict)  # name -> value text (read as YAML, as rcl reads -p)
    remappings: list[tuple[str, str]] = field(default_factory=list)
    managed: bool = False  # a <lifecycle_node>
    autostart: bool = False  # the launcher brings it up (configure, activate)

    @property
    def label(self) -> str:
        ns = self.namespace.rstrip('/')
        return f'{ns}/{self.name or self.executable}'


def package_share() -> Path:
    """share/srmosaic_ros: from the ament index when installed by colcon, else params/'s parent
    (the source tree, or the environment's share/srmosaic_ros after pip)."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:
        pass
    else:
        try:
            return Path(get_package_share_directory(PACKAGE))
        except (PackageNotFoundError, OSError):  # not in the index, or no AMENT_PREFIX_PATH at all
            pass
    from ..param_files import default_params_path

    return default_params_path().parent.parent


def parse_launch_arguments(items: list[str]) -> dict[str, str]:
    """`name:=value` words of the command line (as `ros2 launch` takes them)."""
    out = {}
    for item in items:
        name, sep, value = item.partition(':=')
        if not sep or not name:
            msg = f'launch argument {item!r} must be name:=value (for example namespace:=uav1).'
            raise ConfigError(msg)
        out[name] = value
    return out


class _Reader:
    def __init__(self, path: Path, arguments: dict[str, str]) -> None:
        self.path = path
        self.given = dict(arguments)
        self.declared: dict[str, str | None] = {}
        self.nodes: list[LaunchNode] = []

    def fail(self, element: ET.Element, text: str) -> ConfigError:
        return ConfigError(f'{self.path}: <{element.tag}> {text}')

    def substitute(self, text: str, element: ET.Element, scope: dict[str, str]) -> str:
        def one(match: re.Match) -> str:
            kind, words = match.group(1), match.group(2).split()
            if kind == 'var' and len(words) == 1:
                if words[0] not in scope:
                    raise self.fail(element, f'uses $(var {words[0]}), which no <arg> or <let> before it defines.')
                return scope[words[0]]
            if kind == 'env' and len(words) in (1, 2):
                value = os.environ.get(words[0], words[1] if len(words) == 2 else None)
                if value is None:
                    raise self.fail(element, f'uses $(env {words[0]}), which is not set (give a default: $(env NAME default)).')
                return value
            if kind == 'find-pkg-share' and words == [PACKAGE]:
                return str(package_share())
            raise self.fail(element, f'uses the substitution {match.group(0)!r}, which srmosaic launch does not '
                            'know (known: $(var NAME), $(env NAME [default]), $(find-pkg-share srmosaic_ros)); '
                            'use ros2 launch for the full language.')

        return _SUBSTITUTION.sub(one, text)

    def attribute(self, element: ET.Element, name: str, scope: dict[str, str], *, required: bool = False,
                  default: str | None = None) -> str | None:
        if name not in element.attrib:
            if required:
                raise self.fail(element, f'needs the attribute {name}.')
            return default
        return self.substitute(element.attrib[name], element, scope)

    def condition(self, element: ET.Element, scope: dict[str, str]) -> bool:
        """if/unless: 'true'/'1' or 'false'/'0', as launch's evaluate_condition_expression."""
        result = True
        for key, wanted in (('if', True), ('unless', False)):
            text = self.attribute(element, key, scope)
            if text is None:
                continue
            value = text.strip().lower()
            if value not in _TRUE | _FALSE:
                raise self.fail(element, f'{key}={text!r} must be true, false, 1 or 0.')
            result = result and ((value in _TRUE) == wanted)
        return result

    def check_attributes(self, element: ET.Element, known: set[str]) -> None:
        if unknown := set(element.attrib) - known:
            raise self.fail(element, f'has attributes {sorted(unknown)} that srmosaic launch does not know '
                            f'(known: {sorted(known)}).')

    def read(self, root: ET.Element) -> list[LaunchNode]:
        if root.tag != 'launch':
            msg = f'{self.path}: the root element is <{root.tag}>, not <launch>.'
            raise ConfigError(msg)
        self.block(root, {}, '/')
        if unused := set(self.given) - set(self.declared):
            msg = (f'{self.path}: launch argument(s) {sorted(unused)} are not declared; '
                   f'its arguments: {sorted(self.declared)}.')
            raise ConfigError(msg)
        return self.nodes

    def block(self, parent: ET.Element, scope: dict[str, str], namespace: str) -> None:
        for element in parent:
            if not isinstance(element.tag, str):  # a comment
                continue
            if element.tag == 'arg':
                self.check_attributes(element, {'name', 'default', 'description'})
                name = self.attribute(element, 'name', scope, required=True)
                default = self.attribute(element, 'default', scope)
                self.declared[name] = default
                if name in self.given:
                    scope[name] = self.given[name]
                elif default is not None:
                    scope[name] = default
                else:
                    raise self.fail(element, f'{name} has no default: give it, {name}:=VALUE.')
            elif element.tag == 'let':
                self.check_attributes(element, {'name', 'value'})
                scope[self.attribute(element, 'name', scope, required=True)] = self.attribute(
                    element, 'value', scope, required=True)
            elif element.tag == 'group':
                self.check_attributes(element, {'if', 'unless', 'scoped'})
                if self.condition(element, scope):
                    self.block(element, dict(scope), namespace)
            elif element.tag == 'push-ros-namespace':
                self.check_attributes(element, {'namespace'})
                namespace = _join(namespace, self.attribute(element, 'namespace', scope, required=True))
            elif element.tag in ('node', 'lifecycle_node'):
                self.node(element, scope, namespace)
            else:
                raise self.fail(element, 'is not understood by srmosaic launch (known: arg, let, group, '
                                'push-ros-namespace, node and lifecycle_node with param and remap); use ros2 launch '
                                'for the full language.')

    def node(self, element: ET.Element, scope: dict[str, str], namespace: str) -> None:
        from .executables import EXECUTABLES

        managed = element.tag == 'lifecycle_node'
        self.check_attributes(element, {'pkg', 'exec', 'name', 'namespace', 'args', 'output', 'if', 'unless',
                                        *(('autostart',) if managed else ())})
        if not self.condition(element, scope):
            return
        autostart = False
        if managed:
            self.attribute(element, 'name', scope, required=True)  # the launcher finds its services by it
            text = self.attribute(element, 'autostart', scope, default='false').strip().lower()
            if text not in _TRUE | _FALSE:
                raise self.fail(element, f'autostart={text!r} must be true, false, 1 or 0.')
            autostart = text in _TRUE
        pkg = self.attribute(element, 'pkg', scope, required=True)
        executable = self.attribute(element, 'exec', scope, required=True)
        if pkg != PACKAGE or executable not in EXECUTABLES:
            raise self.fail(element, f'{pkg}/{executable}: srmosaic launch starts only the executables of '
                            f'{PACKAGE} ({sorted(EXECUTABLES)}).')
        node = LaunchNode(executable, name=self.attribute(element, 'name', scope) or None,
                          namespace=_join(namespace, self.attribute(element, 'namespace', scope, default='')),
                          arguments=shlex.split(self.attribute(element, 'args', scope, default='')),
                          managed=managed, autostart=autostart)
        for child in element:
            if not isinstance(child.tag, str):
                continue
            if child.tag == 'param':
                self.check_attributes(child, {'from', 'name', 'value'})
                if 'from' in child.attrib:
                    path = Path(self.attribute(child, 'from', scope))
                    if not path.is_file():
                        raise self.fail(child, f'from={str(path)!r}: no such parameter file.')
                    node.param_files.append(str(path))
                else:
                    node.parameters[self.attribute(child, 'name', scope, required=True)] = self.attribute(
                        child, 'value', scope, required=True)
            elif child.tag == 'remap':
                self.check_attributes(child, {'from', 'to'})
                node.remappings.append((self.attribute(child, 'from', scope, required=True),
                                        self.attribute(child, 'to', scope, required=True)))
            else:
                raise self.fail(child, f'inside <{element.tag}> is not understood by srmosaic launch (known: param, remap).')
        self.nodes.append(node)


def _join(namespace: str, inner: str | None) -> str:
    """A namespace pushed inside another ('/uav1' + 'cam' = '/uav1/cam'; an absolute one replaces it)."""
    inner = (inner or '').strip()
    if not inner:
        return namespace
    if inner.startswith('/'):
        return '/' + inner.strip('/')
    return '/' + '/'.join(p for p in (namespace.strip('/'), inner.strip('/')) if p)


def read_launch_xml(path: Path, arguments: dict[str, str] | None = None) -> list[LaunchNode]:
    """The nodes a launch file starts with these launch arguments (ConfigError on what it cannot read)."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except FileNotFoundError:
        msg = f'launch file {path} does not exist.'
        raise ConfigError(msg) from None
    except ET.ParseError as exc:
        msg = f'launch file {path} is not valid XML: {exc}.'
        raise ConfigError(msg) from None
    nodes = _Reader(path, arguments or {}).read(root)
    if not nodes:
        msg = f'{path} starts no node with these arguments.'
        raise ConfigError(msg)
    return nodes
