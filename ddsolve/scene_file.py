"""Reading a YAML scene file with hard limits: a regular file of at most :data:`MAX_SCENE_BYTES`,
UTF-8, and YAML within :class:`SceneLoader`'s bounds on nesting and alias expansion, so that a
hostile file is refused cheaply (one :class:`~ddsolve.errors.InputError`, field ``scene``).
:func:`read_scene` returns the mapping; :class:`ddsolve.spec.ProblemSpec` validates it.
"""
from __future__ import annotations

import os
import re
import stat
from typing import Any, Mapping

import yaml

from .errors import InputError, brief

__all__ = ["MAX_SCENE_BYTES", "PATH_FIELDS", "SceneLoader", "read_scene"]

#: Largest scene file read (bytes).
MAX_SCENE_BYTES = 1 << 20
#: File paths of a scene file, read relative to the scene file's directory.
PATH_FIELDS = ("mesh_file", "output")


class SceneLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` with bounds: nesting depth, number of nodes and alias-expanded size.

    The size of a node is the number of nodes it stands for once every alias is
    expanded (1 for a scalar, 1 + the sizes of the items for a collection); it
    is computed while composing, from the sizes of the already composed
    anchors, so an alias bomb ("billion laughs") is refused after reading a few
    hundred bytes and before anything is expanded. Exceeding a bound raises
    :class:`~ddsolve.errors.InputError` (field ``scene``).
    """

    #: Deepest nesting of collections.
    max_depth = 32
    #: Largest number of nodes of the document, as written and alias-expanded (a scene has 16 fields).
    max_nodes = 1000

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        self._depth = 0
        self._composed = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        self._depth += 1
        self._composed += 1
        try:
            if self._depth > self.max_depth:
                raise InputError("scene", f"nesting deeper than {self.max_depth} levels")
            if self._composed > self.max_nodes:
                raise InputError("scene", f"more than {self.max_nodes} values")
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        if not hasattr(node, "_ddsolve_size"):
            if isinstance(node, yaml.MappingNode):
                size = 1 + sum(getattr(k, "_ddsolve_size", 1) + getattr(v, "_ddsolve_size", 1)
                               for k, v in node.value)
            elif isinstance(node, yaml.SequenceNode):
                size = 1 + sum(getattr(v, "_ddsolve_size", 1) for v in node.value)
            else:
                size = 1
            if size > self.max_nodes:
                raise InputError("scene", f"more than {self.max_nodes} values once aliases are expanded "
                                          f"(an alias bomb?)")
            node._ddsolve_size = size
        return node

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        """A mapping; a key given twice is an error (YAML's loaders keep the last silently)."""
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            if isinstance(key, (str, int, float, bool)) and key in seen:
                raise InputError("scene", f"key {brief(key)} is given twice (lines {seen[key] + 1} and "
                                          f"{key_node.start_mark.line + 1})")
            if isinstance(key, (str, int, float, bool)):
                seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep=deep)

    def _strict_number(self, node: Any, pattern: Any, construct: Any) -> Any:
        """YAML 1.1 also reads 1:30 as 90, 1_0 as 10, 0x4 and 0b11: those stay text, so that the
        fields refuse them as the command line does (`subdomains: must be an integer ...`)."""
        text = self.construct_scalar(node)
        return construct(self, node) if pattern.fullmatch(text.strip()) else text

    def construct_strict_int(self, node: Any) -> Any:
        # int(text), not construct_yaml_int: YAML 1.1 reads 010 as octal 8, the flag --subdomains 010 is 10
        return self._strict_number(node, _PLAIN_INT, lambda loader, n: int(loader.construct_scalar(n).strip()))

    def construct_strict_float(self, node: Any) -> Any:
        return self._strict_number(node, _PLAIN_FLOAT, yaml.SafeLoader.construct_yaml_float)


_PLAIN_INT = re.compile(r"[-+]?[0-9]+")
_PLAIN_FLOAT = re.compile(r"[-+]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][-+]?[0-9]+)?")
SceneLoader.add_constructor("tag:yaml.org,2002:int", SceneLoader.construct_strict_int)
SceneLoader.add_constructor("tag:yaml.org,2002:float", SceneLoader.construct_strict_float)


def read_scene(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The mapping of a YAML scene file, read with hard limits.

    The file must be a regular file (checked with ``stat`` before it is opened:
    a FIFO, a device such as ``/dev/zero`` or a directory is refused unread) of
    at most :data:`MAX_SCENE_BYTES`, UTF-8, and YAML within
    :class:`SceneLoader`'s bounds. An empty file is an empty mapping.

    Raises
    ------
    InputError
        ``scene``, with one line saying why.
    """
    name = os.fspath(path) if not isinstance(path, (str, bytes)) else path
    if isinstance(name, bytes) or not isinstance(name, str):
        raise InputError("scene", f"must be a file path, got {brief(path)}")
    if not name.strip():
        raise InputError("scene", "empty file name")
    shown = brief(name)
    try:
        info = os.stat(name)
    except (OSError, ValueError) as exc:
        raise InputError("scene", f"cannot read {shown}: {getattr(exc, 'strerror', None) or exc}") from None
    if not stat.S_ISREG(info.st_mode):
        kind = "a directory" if stat.S_ISDIR(info.st_mode) else "not a regular file"
        raise InputError("scene", f"{shown} is {kind}")
    if info.st_size > MAX_SCENE_BYTES:
        raise InputError("scene", f"{shown} is larger than {MAX_SCENE_BYTES // 1024} KiB ({info.st_size} bytes)")
    try:
        fd = os.open(name, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0))
        with os.fdopen(fd, "rb") as stream:
            if not stat.S_ISREG(os.fstat(stream.fileno()).st_mode):   # replaced since the stat
                raise InputError("scene", f"{shown} is not a regular file")
            data = stream.read(MAX_SCENE_BYTES + 1)
    except OSError as exc:
        raise InputError("scene", f"cannot read {shown}: {exc.strerror or exc}") from None
    if len(data) > MAX_SCENE_BYTES:
        raise InputError("scene", f"{shown} is larger than {MAX_SCENE_BYTES // 1024} KiB")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError("scene", f"{shown} is not UTF-8 text (byte 0x{data[exc.start]:02x} at offset "
                                  f"{exc.start})") from None
    try:
        loaded = yaml.load(text, Loader=SceneLoader)   # a SafeLoader subclass: no arbitrary objects
    except InputError:
        raise
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        at = f" at line {where.line + 1}" if where is not None else ""
        raise InputError("scene", f"malformed YAML in {shown}{at}") from None
    except (ValueError, TypeError, OverflowError, RecursionError):   # e.g. an invalid timestamp
        raise InputError("scene", f"malformed YAML in {shown}") from None
    if loaded is None:
        return {}
    if not isinstance(loaded, Mapping):
        raise InputError("scene", f"{shown} must hold a mapping of fields, got {type(loaded).__name__}")
    out = dict(loaded)
    base = os.path.dirname(name)
    for key in PATH_FIELDS:      # relative to the scene file, not to the working directory
        value = out.get(key)
        if isinstance(value, str) and value.strip() and not os.path.isabs(value) and base:
            out[key] = os.path.join(base, value)
    return out
