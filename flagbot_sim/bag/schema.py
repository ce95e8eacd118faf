"""Message definitions as rosbag2 stores them in a schema, and the header stamp read straight from CDR bytes.

A schema holds the type's own ``.msg`` text followed by every dependent type, each after a line of 80 ``=`` and
``MSG: pkg/Type`` (the same regex, ordering and de-duplication as rosbag2's ``LocalMessageDefinitionSource``),
read at run time from ``<prefix>/share/<pkg>/msg/*.msg`` of the installed interface packages. A few types the
recordings carry without their wheel (:data:`BUNDLED`: tf2_msgs/msg/TFMessage) have their own .msg text here,
used when the package is not installed; their nested types are read as above.
"""
from __future__ import annotations

import functools
import os
import re
import struct
import sys
from pathlib import Path

from .format import BagError, InterfaceNotFound

_DELIMITER = "=" * 80 + "\n"
# rosbag2's MSG_FIELD_TYPE_REGEX: the type at the start of each line, array suffix dropped
_MSG_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
_PRIMITIVES = frozenset({"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
                         "int32", "uint32", "int64", "uint64", "string"})
_NAME = r"[a-zA-Z][a-zA-Z0-9_]*"
_TYPE2 = re.compile(rf"^({_NAME})/({_NAME})$")
_TYPE3 = re.compile(rf"^({_NAME})/({_NAME})/({_NAME})$")


def split_type(type_name: str) -> tuple[str, str, str]:
    """``pkg/msg/Type`` or ``pkg/Type`` -> (pkg, 'msg', Type)."""
    m = _TYPE3.match(type_name)
    if m:
        return m.group(1), m.group(2), m.group(3)
    m = _TYPE2.match(type_name)
    if m:
        return m.group(1), "msg", m.group(2)
    raise BagError(f"not a ROS message type name: {type_name!r} (expected pkg/msg/Type)")


def normalize_type(type_name: str) -> str:
    """The ``pkg/msg/Type`` form used for schema names and by rclpy's graph queries."""
    return "/".join(split_type(type_name))


def interface_prefixes(package: str | None = None) -> list[Path]:
    """Install prefixes that may hold ``share/<pkg>/msg``: AMENT_PREFIX_PATH (a sourced or colcon install), this
    interpreter's prefix (the PyPI wheels install into the venv), and the prefix above the package's Python
    module (``<prefix>/lib/pythonX.Y/site-packages/<pkg>``)."""
    out: list[Path] = []
    for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if p:
            out.append(Path(p))
    out.append(Path(sys.prefix))
    if package:
        try:
            import importlib.util
            spec = importlib.util.find_spec(package)
        except (ImportError, ValueError):
            spec = None
        if spec is not None and spec.origin:
            out.append(Path(spec.origin).resolve().parents[4])
    seen, unique = set(), []
    for p in out:
        if p not in seen:
            seen.add(p)
            unique.append(p)
    return unique


def find_interface_file(package: str, namespace: str, name: str, ext: str = ".msg") -> Path:
    """Path of ``share/<package>/<namespace>/<name>.msg`` in the first prefix that has it."""
    tried = []
    try:  # the ament index, as rosbag2 uses it, when a prefix path is set
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
        try:
            p = Path(get_package_share_directory(package)) / namespace / (name + ext)
            if p.is_file():
                return p
            tried.append(str(p))
        except (PackageNotFoundError, OSError, ValueError, LookupError):
            pass
    except ImportError:
        pass
    for prefix in interface_prefixes(package):
        p = prefix / "share" / package / namespace / (name + ext)
        if p.is_file():
            return p
        tried.append(str(p))
    raise InterfaceNotFound(f"no definition of {package}/{namespace}/{name} installed (looked for {', '.join(tried)});"
                            f" install the interface package (e.g. pip install ros-jazzy-common-interfaces)")


def _bundled() -> dict[str, str]:
    from .tf import TF_MESSAGE, TF_MESSAGE_MSG
    return {TF_MESSAGE: TF_MESSAGE_MSG}


#: type -> its own .msg text, for types recorded where their interface package may be missing
BUNDLED = _bundled()


@functools.lru_cache(maxsize=None)
def _msg_text(type_name: str) -> str:
    pkg, ns, name = split_type(type_name)
    try:
        return find_interface_file(pkg, ns, name).read_text()
    except InterfaceNotFound:
        text = BUNDLED.get(f"{pkg}/{ns}/{name}")
        if text is None:
            raise
        return text


def _msg_dependencies(text: str, package: str) -> list[str]:
    deps = set()
    for m in _MSG_FIELD_TYPE.finditer(text):
        t = m.group(1)
        if t in _PRIMITIVES:
            continue
        deps.add(t if "/" in t else f"{package}/{t}")
    return sorted(deps)  # rosbag2 keeps them in a std::set


@functools.lru_cache(maxsize=None)
def message_definition(type_name: str) -> str:
    """Full ``ros2msg`` text of a type: its .msg text, then each dependency (depth first, sorted, each once)
    after the 80-'=' line and ``MSG: pkg/Type``, exactly as rosbag2 Jazzy writes it."""
    seen: set[str] = set()

    def rec(t: str, depth: int) -> str:
        if depth <= 0:
            raise BagError(f"message definition of {type_name} nests too deep")
        text = _msg_text(t)
        out = text
        for dep in _msg_dependencies(text, split_type(t)[0]):
            if dep not in seen:
                seen.add(dep)
                out += "\n" + _DELIMITER + "MSG: " + dep + "\n" + rec(dep, depth - 1)
        return out

    return rec(type_name, 50)


def _first_field_type(text: str) -> str | None:
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) >= 2 and "=" not in line:
            return parts[0]
    return None


@functools.lru_cache(maxsize=None)
def has_header(type_name: str) -> bool:
    """True when the type's first field is a std_msgs/Header (its stamp is then the first 8 CDR bytes)."""
    try:
        first = _first_field_type(_msg_text(type_name))
    except BagError:
        return False
    return first in ("std_msgs/Header", "std_msgs/msg/Header") or (first == "Header" and
                                                                   split_type(type_name)[0] == "std_msgs")


def cdr_header_stamp_ns(data: bytes) -> int | None:
    """Stamp of a leading std_msgs/Header in a CDR payload (4-byte encapsulation, then int32 sec, uint32
    nanosec), or None if absent or unset (0)."""
    if len(data) < 12:
        return None
    endian = "<" if data[1] & 1 else ">"
    sec, nsec = struct.unpack_from(endian + "iI", data, 4)
    if sec < 0 or nsec >= 1_000_000_000 or (sec == 0 and nsec == 0):
        return None
    return sec * 1_000_000_000 + nsec

