"""MCAP recordings in rosbag2's layout: write, read (also damaged files), recover, and run metadata.

No ROS import here: the recorder/replay nodes in :mod:`flagbot_sim.ros` do the DDS side and hand serialized
(CDR) bytes to this module, and the analysis tools decode with ``mcap_ros2`` alone.

File layout, as rosbag2 (Jazzy) writes it (see ../shared/ROS_NOTES.md):

- header profile ``ros2``; one schema per message type, named ``pkg/msg/Type``, encoding ``ros2msg``, holding the
  type's own ``.msg`` text followed by every dependent type, each after a line of 80 ``=`` and ``MSG: pkg/Type``
  (the same regex, ordering and de-duplication as rosbag2's ``LocalMessageDefinitionSource``), read at run time
  from ``<prefix>/share/<pkg>/msg/*.msg`` of the installed interface packages;
- one channel per topic, message encoding ``cdr``, channel metadata ``offered_qos_profiles`` (rosbag2's version-9
  YAML) and ``topic_type_hash`` when known;
- message log time = receive time, publish time = the ``std_msgs/Header`` stamp for types whose first field is a
  header (read straight from the CDR bytes), else the receive time;
- a ``rosbag2`` metadata record (``serialized_metadata``, version 9) written at the *start*, so that a file that
  never got closed still tells rosbag2 how to parse the QoS strings, and a ``flagbot_sim`` metadata record with
  the scene, all parameters and the package version (:class:`RunMetadata`).

Crash safety. Messages go into small chunks (zstd, CRC of the uncompressed data) and every chunk is closed and
flushed to the OS at least every ``flush_interval`` (0.5 s): a SIGKILL loses only the chunk being filled plus
whatever was still in rclpy's queues. Schemas and channels are also written *outside* chunks, so any chunk can be
decoded on its own when an earlier one is damaged. The OS page cache survives SIGKILL; only a power cut needs
``fsync`` (``fsync_interval``).

Reading. :class:`BagReader` walks the records from the start instead of trusting the summary, so a truncated file
(killed writer, full disk) or a corrupt chunk costs only the damaged part: it skips a bad chunk by its length,
re-synchronises on the next chunk whose data decompresses and passes its CRC, and records every loss in a
:class:`ScanReport` that says which bytes, which log-time range and (when the summary survived) how many messages
were lost. :func:`recover` rewrites what was readable into a valid, indexed file. A file that is not MCAP at all
raises :class:`NotMcapError` with a message naming what it looks like instead.
"""
from __future__ import annotations

import dataclasses
import datetime as _dt
import functools
import heapq
import io
import json
import mmap
import os
import re
import struct
import sys
import threading
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Callable, Iterable, Iterator, Mapping

from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (Attachment, Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema,
                          Statistics)
from mcap.writer import CompressionType, Writer

from .topics import CLOCK, CMD_OMEGA  # plain names, no ROS import

MCAP_MAGIC = b"\x89MCAP0\r\n"
PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
#: name of the metadata record with the scene, parameters and package version
RUN_METADATA_NAME = "flagbot_sim"
#: name of the metadata record rosbag2 reads (key ``serialized_metadata``)
ROSBAG2_METADATA_NAME = "rosbag2"
RECOVERY_METADATA_NAME = "flagbot_sim.recovery"
LIBRARY = "flagbot_sim.bag"

#: chunks are closed at this size even between flushes (rosbag2 uses 768 KiB; smaller = less lost on a crash)
DEFAULT_CHUNK_SIZE = 256 * 1024
#: a chunk is closed and flushed to the OS at least this often (s): the most a SIGKILL can lose
DEFAULT_FLUSH_INTERVAL = 0.5

_DELIMITER = "=" * 80 + "\n"
# rosbag2's MSG_FIELD_TYPE_REGEX: the type at the start of each line, array suffix dropped
_MSG_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
_PRIMITIVES = frozenset({"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
                         "int32", "uint32", "int64", "uint64", "string"})
_NAME = r"[a-zA-Z][a-zA-Z0-9_]*"
_TYPE2 = re.compile(rf"^({_NAME})/({_NAME})$")
_TYPE3 = re.compile(rf"^({_NAME})/({_NAME})/({_NAME})$")


class BagError(Exception):
    """A recording cannot be read or written. The message says why, in terms a user can act on."""


class NotMcapError(BagError):
    """The file is not an MCAP file at all."""


class InterfaceNotFound(BagError):
    """The .msg definition of a type is not installed."""


# ----------------------------------------------------------------------------------------------------------------
# message definitions, as rosbag2 stores them


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


@functools.lru_cache(maxsize=None)
def _msg_text(type_name: str) -> str:
    pkg, ns, name = split_type(type_name)
    return find_interface_file(pkg, ns, name).read_text()


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


# ----------------------------------------------------------------------------------------------------------------
# QoS in rosbag2's version-9 YAML (channel metadata "offered_qos_profiles")

_INFINITE_NS = 0x7FFFFFFFFFFFFFFF  # RMW_DURATION_INFINITE


@dataclass(frozen=True)
class QosInfo:
    """The parts of a QoS profile a recorder/replayer needs (names as in rosbag2's YAML, lower case)."""
    history: str = "keep_last"
    depth: int = 10
    reliability: str = "reliable"
    durability: str = "volatile"
    liveliness: str = "automatic"
    deadline_ns: int = _INFINITE_NS
    lifespan_ns: int = _INFINITE_NS
    liveliness_lease_ns: int = _INFINITE_NS


def _yaml_duration(ns: int) -> str:
    ns = max(0, min(int(ns), _INFINITE_NS))
    return f"\n    sec: {ns // 1_000_000_000}\n    nsec: {ns % 1_000_000_000}"


def qos_to_yaml(profiles: Iterable[QosInfo]) -> str:
    """rosbag2 (metadata version 9) serialisation of the publishers' offered QoS profiles."""
    items = []
    for q in profiles:
        items.append(f"- history: {q.history}\n  depth: {q.depth}\n  reliability: {q.reliability}\n"
                     f"  durability: {q.durability}\n  deadline:{_yaml_duration(q.deadline_ns)}\n"
                     f"  lifespan:{_yaml_duration(q.lifespan_ns)}\n  liveliness: {q.liveliness}\n"
                     f"  liveliness_lease_duration:{_yaml_duration(q.liveliness_lease_ns)}\n"
                     f"  avoid_ros_namespace_conventions: false")
    return "\n".join(items)


_QOS_NAMES = {  # version-8 files store enum values
    "history": {0: "system_default", 1: "keep_last", 2: "keep_all", 3: "unknown"},
    "reliability": {0: "system_default", 1: "reliable", 2: "best_effort", 3: "unknown", 4: "best_available"},
    "durability": {0: "system_default", 1: "transient_local", 2: "volatile", 3: "unknown", 4: "best_available"},
    "liveliness": {0: "system_default", 1: "automatic", 3: "manual_by_topic", 4: "unknown", 5: "best_available"},
}


def qos_from_yaml(text: str) -> list[QosInfo]:
    """Parse ``offered_qos_profiles`` (version 8 or 9) loosely: policies and depth, one entry per publisher."""
    out = []
    for block in re.split(r"^- ", text or "", flags=re.MULTILINE):
        if not block.strip():
            continue
        kw = {}
        for key in ("history", "reliability", "durability", "liveliness"):
            m = re.search(rf"^\s*{key}:\s*(\S+)", block, re.MULTILINE)
            if m:
                v = m.group(1).strip("'\"")
                kw[key] = _QOS_NAMES[key].get(int(v), "unknown") if v.isdigit() else v.lower()
        m = re.search(r"^\s*depth:\s*(\d+)", block, re.MULTILINE)
        if m:
            kw["depth"] = int(m.group(1))
        out.append(QosInfo(**kw))
    return out


# ----------------------------------------------------------------------------------------------------------------
# run metadata


def package_version() -> str:
    """flagbot_sim's version: ``flagbot_sim.__version__`` of the imported source, else the installed metadata."""
    import flagbot_sim
    if getattr(flagbot_sim, "__version__", None):
        return str(flagbot_sim.__version__)
    try:
        from importlib.metadata import PackageNotFoundError, version
        try:
            return version("flagbot_sim")
        except PackageNotFoundError:
            pass
    except ImportError:
        pass
    xml = Path(__file__).resolve().parents[1] / "package.xml"
    m = re.search(r"<version>([^<]+)</version>", xml.read_text()) if xml.is_file() else None
    return m.group(1) if m else "unknown"


def source_revision() -> str:
    """``git describe`` of the source tree this package was imported from, or '' when not a checkout."""
    root = Path(__file__).resolve().parents[1]
    if not (root / ".git").exists():
        return ""
    import subprocess
    try:
        r = subprocess.run(["git", "-C", str(root), "describe", "--always", "--dirty", "--abbrev=12"],
                           capture_output=True, text=True, timeout=5)
        return r.stdout.strip() if r.returncode == 0 else ""
    except (OSError, subprocess.SubprocessError):
        return ""


def _json_default(o):
    from .cliutil import json_default
    try:
        return json_default(o)
    except TypeError:
        return str(o)


@dataclass
class RunMetadata:
    """What is needed to reproduce a run: the scene file text, every parameter value, the package version.

    Stored as the MCAP metadata record ``flagbot_sim`` (string map): ``scene_toml``, ``parameters`` (JSON object),
    ``package_version``, ``source_revision``, ``created_utc``, ``command_line`` and any ``extra`` keys.
    """
    scene_toml: str = ""
    parameters: dict[str, Any] = field(default_factory=dict)
    package_version: str = field(default_factory=package_version)
    source_revision: str = field(default_factory=source_revision)
    created_utc: str = field(default_factory=lambda: _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"))
    command_line: str = field(default_factory=lambda: " ".join(sys.argv))
    extra: dict[str, str] = field(default_factory=dict)

    _KEYS = ("scene_toml", "package_version", "source_revision", "created_utc", "command_line")

    def to_record(self) -> dict[str, str]:
        rec = {"package": "flagbot_sim",
               "parameters": json.dumps(self.parameters, sort_keys=True, default=_json_default)}
        for k in self._KEYS:
            rec[k] = str(getattr(self, k))
        for k, v in self.extra.items():
            if k in rec:
                raise BagError(f"metadata key {k!r} is reserved")
            rec[k] = str(v)
        return rec

    @classmethod
    def from_record(cls, rec: Mapping[str, str]) -> "RunMetadata":
        try:
            params = json.loads(rec.get("parameters", "{}") or "{}")
        except json.JSONDecodeError as exc:
            raise BagError(f"metadata 'parameters' is not valid JSON: {exc}") from None
        known = set(cls._KEYS) | {"parameters", "package"}
        return cls(parameters=params, extra={k: v for k, v in rec.items() if k not in known},
                   **{k: rec.get(k, "") for k in cls._KEYS})


def _rosbag2_serialized_metadata(file_name: str) -> str:
    """rosbag2's BagMetadata (version 9) as YAML. Counts and times are left at zero: rosbag2 takes them from the
    MCAP statistics; what matters is ``version: 9`` (QoS stored as strings) and ``ros_distro``."""
    distro = os.environ.get("ROS_DISTRO", "jazzy")
    return ("version: 9\nstorage_identifier: mcap\nduration:\n  nanoseconds: 0\nstarting_time:\n"
            "  nanoseconds_since_epoch: 0\nmessage_count: 0\ntopics_with_message_count: []\n"
            "compression_format: \"\"\ncompression_mode: \"\"\nrelative_file_paths:\n"
            f"  - {json.dumps(file_name)}\nfiles: []\ncustom_data: {{}}\nros_distro: {distro}\n")


# ----------------------------------------------------------------------------------------------------------------
# writing


@dataclass
class TopicStats:
    topic: str
    type_name: str
    count: int = 0
    first_log_ns: int | None = None
    last_log_ns: int | None = None


@dataclass
class WriteSummary:
    path: str
    messages: int
    topics: dict[str, TopicStats]
    duration: float
    size_bytes: int
    closed: bool
    error: str | None = None

    def format(self) -> str:
        lines = [f"{self.path}: {self.messages} messages, {len(self.topics)} topics, {self.duration:.2f} s, "
                 f"{self.size_bytes / 1024:.1f} KiB, "
                 f"{'closed with summary and index' if self.closed else 'NOT closed'}"]
        for t in sorted(self.topics.values(), key=lambda s: s.topic):
            lines.append(f"  {t.topic:32s} {t.type_name:40s} {t.count:8d}")
        if self.error:
            lines.append(f"  ERROR: {self.error}")
        return "\n".join(lines)


class BagWriter:
    """Write serialized ROS 2 messages to an MCAP file as rosbag2 does. Thread-safe.

    ``path`` is a file path (``.mcap`` is appended if missing) or a binary file object. ``metadata`` (a
    :class:`RunMetadata` or a plain string map) is written first. A write error (e.g. disk full) stops the
    recording: :attr:`error` says why, everything flushed before stays recoverable with :func:`recover`.
    """

    def __init__(self, path: str | os.PathLike | BinaryIO, *, metadata: RunMetadata | Mapping[str, str] | None = None,
                 chunk_size: int = DEFAULT_CHUNK_SIZE, compression: str = "zstd",
                 flush_interval: float = DEFAULT_FLUSH_INTERVAL, fsync_interval: float | None = None,
                 overwrite: bool = False, clock: Callable[[], float] = time.monotonic):
        if isinstance(path, (str, os.PathLike)):
            p = Path(path)
            if p.suffix != ".mcap":
                p = p.with_name(p.name + ".mcap")
            if p.exists() and not overwrite:
                raise BagError(f"{p} exists; choose another name or allow overwriting")
            p.parent.mkdir(parents=True, exist_ok=True)
            self.path = str(p)
            self._file = open(p, "wb")
            self._owns_file = True
        else:
            self.path = getattr(path, "name", "<stream>")
            self._file = path
            self._owns_file = False
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE,
                "": CompressionType.NONE}.get(compression)
        if comp is None:
            raise BagError(f"unknown compression {compression!r} (zstd, lz4, none)")
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=comp, enable_crcs=True)
        self._lock = threading.RLock()
        self._clock = clock
        self.flush_interval = flush_interval
        self.fsync_interval = fsync_interval
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._topic_types: dict[str, str] = {}
        self._header_types: dict[str, bool] = {}
        self.stats: dict[str, TopicStats] = {}
        self.message_count = 0
        self._pending = 0
        self._last_flush = clock()
        self._last_fsync = self._last_flush
        self.error: str | None = None
        self.closed = False
        self._guard(self._writer.start, PROFILE, LIBRARY)
        self._guard(self._writer.add_metadata, ROSBAG2_METADATA_NAME,
                    {"serialized_metadata": _rosbag2_serialized_metadata(Path(self.path).name)})
        if metadata is not None:
            self.add_metadata(RUN_METADATA_NAME, metadata.to_record() if isinstance(metadata, RunMetadata)
                              else dict(metadata))
        self.flush()

    # -- internals
    def _guard(self, fn, *args) -> bool:
        if self.error is not None:
            return False
        try:
            fn(*args)
            return True
        except OSError as exc:  # disk full, I/O error: stop, keep what is on disk
            self.error = f"write failed after {self.message_count} messages: {exc}"
            return False

    def _write_raw_record(self, record) -> None:
        # Schemas and channels are also written outside chunks: a chunk can then be decoded on its own
        # even if the chunk that first carried them is lost. MCAP allows identical duplicates.
        b = RecordBuilder()
        record.write(b)
        self._file.write(b.end())

    # -- API
    @property
    def topics(self) -> dict[str, str]:
        return dict(self._topic_types)

    def add_topic(self, topic: str, type_name: str, *, offered_qos_profiles: str = "", type_hash: str = "") -> int:
        """Register a topic (once); returns its channel id. Reads the full message definition of the type."""
        type_name = normalize_type(type_name)
        with self._lock:
            if topic in self._channels:
                if self._topic_types[topic] != type_name:
                    raise BagError(f"topic {topic} already recorded as {self._topic_types[topic]}, not {type_name}")
                return self._channels[topic]
            if type_name not in self._schemas:
                text = message_definition(type_name)
                sid = self._writer.register_schema(type_name, SCHEMA_ENCODING, text.encode())
                self._schemas[type_name] = sid
                self._guard(self._write_raw_record,
                            Schema(id=sid, name=type_name, encoding=SCHEMA_ENCODING, data=text.encode()))
            meta = {"offered_qos_profiles": offered_qos_profiles, "topic_type_hash": type_hash}
            cid = self._writer.register_channel(topic, MESSAGE_ENCODING, self._schemas[type_name], meta)
            self._guard(self._write_raw_record, Channel(id=cid, topic=topic, message_encoding=MESSAGE_ENCODING,
                                                               schema_id=self._schemas[type_name], metadata=meta))
            self._channels[topic] = cid
            self._topic_types[topic] = type_name
            self._header_types[topic] = has_header(type_name)
            self.stats[topic] = TopicStats(topic, type_name)
            return cid

    def write(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int | None = None,
              sequence: int = 0) -> bool:
        """Append one serialized message. ``publish_time_ns`` defaults to the header stamp (or the log time)."""
        with self._lock:
            if self.closed or self.error is not None:
                return False
            cid = self._channels.get(topic)
            if cid is None:
                raise BagError(f"topic {topic} not added (call add_topic first)")
            if publish_time_ns is None:
                publish_time_ns = (cdr_header_stamp_ns(data) if self._header_types[topic] else None) or log_time_ns
            if not self._guard(self._writer.add_message, cid, int(log_time_ns), bytes(data), int(publish_time_ns),
                               sequence & 0xFFFFFFFF):
                return False
            self.message_count += 1
            self._pending += 1
            st = self.stats[topic]
            st.count += 1
            if st.first_log_ns is None:
                st.first_log_ns = log_time_ns
            st.last_log_ns = log_time_ns
            self.maybe_flush()
            return True

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        with self._lock:
            self._guard(self._writer.add_metadata, name, {str(k): str(v) for k, v in data.items()})

    def maybe_flush(self) -> None:
        """Close the current chunk and flush if ``flush_interval`` has passed; call it from a timer too."""
        with self._lock:
            now = self._clock()
            if self._pending and now - self._last_flush >= self.flush_interval:
                self.flush()
            if self.fsync_interval is not None and now - self._last_fsync >= self.fsync_interval:
                self._last_fsync = now
                if self._owns_file and self.error is None:
                    try:
                        os.fsync(self._file.fileno())
                    except OSError:
                        pass

    def flush(self) -> None:
        with self._lock:
            if self.closed:
                return
            self._guard(self._writer.flush)
            self._pending = 0
            self._last_flush = self._clock()

    def summary(self) -> WriteSummary:
        firsts = [s.first_log_ns for s in self.stats.values() if s.first_log_ns is not None]
        lasts = [s.last_log_ns for s in self.stats.values() if s.last_log_ns is not None]
        size = os.path.getsize(self.path) if self._owns_file and os.path.exists(self.path) else 0
        return WriteSummary(self.path, self.message_count, dict(self.stats),
                            (max(lasts) - min(firsts)) * 1e-9 if firsts else 0.0, size,
                            self.closed and self.error is None, self.error)

    def close(self) -> WriteSummary:
        """Write the summary, indexes and footer (the file is then complete) and close it."""
        with self._lock:
            if not self.closed:
                self._guard(self._writer.finish)
                self.closed = True
                if self._owns_file:
                    try:
                        self._file.close()
                    except OSError as exc:
                        self.error = self.error or f"closing failed: {exc}"
            return self.summary()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# ----------------------------------------------------------------------------------------------------------------
# reading


@dataclass
class Damage:
    """One unreadable stretch of a file."""
    kind: str            # truncated | corrupt-chunk | unreadable | no-summary (cut between records)
    offset: int          # first byte of the damaged stretch
    length: int          # bytes lost
    detail: str
    log_start_ns: int | None = None   # log-time range of the lost chunk, when its header survived
    log_end_ns: int | None = None

    def describe(self, t0_ns: int | None = None) -> str:
        if self.kind == "no-summary":
            return f"file ends after a complete record at byte {self.offset} ({self.detail})"
        s = f"{self.kind} at byte {self.offset}: {self.length} bytes lost ({self.detail})"
        if self.log_start_ns is not None and self.log_end_ns is not None and self.log_end_ns >= self.log_start_ns:
            if t0_ns is not None:
                s += (f"; messages logged {(self.log_start_ns - t0_ns) * 1e-9:.3f}-"
                      f"{(self.log_end_ns - t0_ns) * 1e-9:.3f} s")
            else:
                s += f"; messages logged at {self.log_start_ns}-{self.log_end_ns} ns"
        return s


@dataclass
class TopicInfo:
    topic: str
    type_name: str
    channel_id: int
    count: int = 0
    offered_qos: list[QosInfo] = field(default_factory=list)
    type_hash: str = ""
    first_log_ns: int | None = None
    last_log_ns: int | None = None


@dataclass
class ScanReport:
    """What a full pass over a file found: what was readable and what was lost."""
    path: str
    size: int
    profile: str = ""
    library: str = ""
    messages: int = 0
    start_ns: int | None = None
    end_ns: int | None = None
    topics: dict[str, TopicInfo] = field(default_factory=dict)
    data_end: bool = False           # the data section was terminated (writer got to finish())
    closed: bool = False             # summary, footer and closing magic present: the file was closed properly
    summary_messages: int | None = None  # message count in the summary's statistics, when it survived
    damage: list[Damage] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.closed and not self.damage

    @property
    def duration(self) -> float:
        return (self.end_ns - self.start_ns) * 1e-9 if self.messages else 0.0

    @property
    def lost_bytes(self) -> int:
        return sum(d.length for d in self.damage)

    @property
    def lost_messages(self) -> int | None:
        """Exact count when the summary survived, else unknown (None)."""
        if self.summary_messages is None:
            return None
        return max(0, self.summary_messages - self.messages)

    def describe_loss(self) -> str:
        """One paragraph a user can act on; '' for an intact file."""
        if self.ok:
            return ""
        parts = []
        if not self.closed:
            parts.append("the recording was not closed properly (no summary/index: writer killed, crashed or disk "
                         "full)")
        for d in self.damage:
            parts.append(d.describe(self.start_ns))
        lost = self.lost_messages
        if lost is not None:
            parts.append(f"{lost} of {self.summary_messages} messages lost")
        elif self.damage:
            parts.append("number of lost messages unknown (no summary)")
        if self.messages:
            parts.append(f"recovered {self.messages} messages covering {self.duration:.3f} s "
                         f"(log time up to {self.end_ns * 1e-9:.3f})")
        else:
            parts.append("no message could be recovered")
        return f"{self.path}: " + "; ".join(parts) + "."

    def to_json(self) -> dict:
        return {"path": self.path, "size": self.size, "messages": self.messages, "duration": self.duration,
                "start_ns": self.start_ns, "end_ns": self.end_ns, "closed": self.closed, "ok": self.ok,
                "lost_bytes": self.lost_bytes, "lost_messages": self.lost_messages,
                "damage": [dataclasses.asdict(d) for d in self.damage], "loss": self.describe_loss()}


@dataclass
class BagMessage:
    topic: str
    type_name: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes
    channel_id: int
    sequence: int = 0


_DATA_OPCODES = {Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.CHUNK, Opcode.MESSAGE_INDEX,
                 Opcode.ATTACHMENT, Opcode.METADATA, Opcode.DATA_END, Opcode.HEADER}
_SUMMARY_OPCODES = {Opcode.SCHEMA, Opcode.CHANNEL, Opcode.CHUNK_INDEX, Opcode.ATTACHMENT_INDEX,
                    Opcode.METADATA_INDEX, Opcode.STATISTICS, Opcode.SUMMARY_OFFSET, Opcode.FOOTER}
# records accepted as re-synchronisation points after unreadable bytes (each checked strictly)
_RESYNC_OPCODES = (Opcode.CHUNK, Opcode.METADATA, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.ATTACHMENT)
_REC = struct.Struct("<BQ")


class _BadRecord(Exception):
    pass


def _parse(op: int, body: bytes, exact: bool = True):
    """Parse one record body; raise _BadRecord if it does not parse (or, with ``exact``, has bytes left)."""
    s = ReadDataStream(io.BytesIO(body))
    try:
        if op == Opcode.MESSAGE:
            rec = Message.read(s, len(body))
        elif op == Opcode.CHUNK:
            rec = Chunk.read(s)
        else:
            cls = {Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel, Opcode.METADATA: Metadata,
                   Opcode.ATTACHMENT: Attachment, Opcode.HEADER: Header, Opcode.DATA_END: DataEnd,
                   Opcode.STATISTICS: Statistics, Opcode.FOOTER: Footer}.get(op)
            if cls is None:
                return None
            rec = cls.read(s)
    except (McapError, UnicodeDecodeError, struct.error, ValueError, OverflowError, MemoryError) as exc:
        raise _BadRecord(f"{Opcode(op).name if op in Opcode._value2member_map_ else hex(op)} record does not "
                         f"parse: {exc or type(exc).__name__}") from None
    if exact and s.count != len(body):
        raise _BadRecord(f"{Opcode(op).name} record has {len(body) - s.count} unexpected trailing bytes")
    return rec


def _chunk_records(chunk: Chunk) -> list:
    """Records inside a chunk; raises _BadRecord if its data does not decompress, fails its CRC or has a
    record that does not parse (then none of it is trusted)."""
    try:
        if chunk.compression == "zstd":
            import zstandard
            data = zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=chunk.uncompressed_size)
        elif chunk.compression == "lz4":
            import lz4.frame
            data = lz4.frame.decompress(chunk.data)
        elif chunk.compression == "":
            data = chunk.data
        else:
            raise _BadRecord(f"unsupported chunk compression {chunk.compression!r}")
    except _BadRecord:
        raise
    except Exception as exc:  # zstd/lz4 raise their own error types
        raise _BadRecord(f"chunk data does not decompress ({chunk.compression}): {exc}") from None
    if len(data) != chunk.uncompressed_size:
        raise _BadRecord(f"chunk decompresses to {len(data)} bytes, header says {chunk.uncompressed_size}")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise _BadRecord("chunk CRC mismatch")
    out, pos, n = [], 0, len(data)
    while pos < n:
        if n - pos < 9:
            raise _BadRecord("chunk ends inside a record header")
        op, length = _REC.unpack_from(data, pos)
        end = pos + 9 + length
        if end > n:
            raise _BadRecord("chunk record runs past the chunk end")
        if op in (Opcode.MESSAGE, Opcode.SCHEMA, Opcode.CHANNEL):
            out.append(_parse(op, data[pos + 9:end]))
        pos = end
    return out


def _open_bytes(path: str | os.PathLike) -> tuple[Path, Any, int]:
    p = Path(path)
    if p.is_dir():  # a rosbag2 directory: its single .mcap file
        files = sorted(p.glob("*.mcap"))
        if len(files) != 1:
            raise BagError(f"{p} is a directory with {len(files)} .mcap files; give the file itself")
        p = files[0]
    if not p.exists():
        raise BagError(f"{p}: no such file")
    size = p.stat().st_size
    with open(p, "rb") as f:
        head = f.read(16)
    if not head.startswith(MCAP_MAGIC):
        if not head:
            what = "the file is empty"
        elif head.startswith(b"SQLite format 3\0"):
            what = "it is an SQLite database (a rosbag2 .db3 bag?); convert it to MCAP first"
        elif head.startswith(b"#ROSBAG"):
            what = "it is a ROS 1 bag"
        elif MCAP_MAGIC[1:6] in head:
            what = "the MCAP magic is damaged"
        else:
            what = f"it starts with {head[:8]!r}"
        raise NotMcapError(f"{p} is not an MCAP file: {what} (an MCAP file starts with {MCAP_MAGIC!r})")
    f = open(p, "rb")
    buf = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if size else b""
    f.close()
    return p, buf, size


#: a recorder's executor can take messages slightly out of arrival order: log-time order is restored within this
_REORDER_WINDOW_NS = 2_000_000_000


def _log_time_order(msgs: Iterable[BagMessage]) -> Iterator[BagMessage]:
    """``msgs`` sorted by log time within the reorder window (ties keep their order)."""
    heap: list = []
    newest = None
    for k, m in enumerate(msgs):
        heapq.heappush(heap, (m.log_time_ns, k, m))
        newest = m.log_time_ns if newest is None else max(newest, m.log_time_ns)
        while heap and heap[0][0] < newest - _REORDER_WINDOW_NS:
            yield heapq.heappop(heap)[2]
    while heap:
        yield heapq.heappop(heap)[2]


class BagReader:
    """Read an MCAP recording record by record, tolerating truncation and corruption.

    ``messages()`` streams; ``report`` (one full pass, cached) tells what was readable and what was lost;
    ``topics``/``metadata`` come from the same pass. Use as a context manager or call :meth:`close`.
    """

    def __init__(self, path: str | os.PathLike):
        self.path, self._buf, self.size = _open_bytes(path)
        self._report: ScanReport | None = None
        self._metadata: list[tuple[str, dict[str, str]]] = []
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._decoders: dict[int, Callable] = {}
        self._factory = None

    # -- the record walk
    def _resync(self, start: int) -> int:
        """Offset of the next record that can be trusted at or after ``start`` (the file size if none)."""
        buf, n = self._buf, self.size
        candidates = []
        for op in _RESYNC_OPCODES:
            i = buf.find(bytes([op]), start)
            if i >= 0:
                candidates.append((i, op))
        heapq.heapify(candidates)
        while candidates:
            i, op = heapq.heappop(candidates)
            j = buf.find(bytes([op]), i + 1)
            if j >= 0:
                heapq.heappush(candidates, (j, op))
            if n - i < 9:
                continue
            _, length = _REC.unpack_from(buf, i)
            if i + 9 + length > n or length > n:
                continue
            try:
                rec = _parse(op, buf[i + 9:i + 9 + length])
                if op == Opcode.CHUNK:
                    _chunk_records(rec)
                elif i + 9 + length < n:  # weaker records must also be followed by a plausible record header
                    if n - (i + 9 + length) < 9:
                        continue
                    nop, nlen = _REC.unpack_from(buf, i + 9 + length)
                    if nop not in _DATA_OPCODES or i + 18 + length + nlen > n + (1 << 20):
                        continue
            except _BadRecord:
                continue
            return i
        return n

    def _walk(self, rep: ScanReport) -> Iterator[Any]:
        """Yield the Schema, Channel, Message, Metadata, Attachment records of the data section,
        chunks expanded; fill ``rep`` with damage, data-end and summary facts as it goes."""
        buf, n = self._buf, self.size
        pos = len(MCAP_MAGIC)
        if n >= 9 + pos:
            op, length = _REC.unpack_from(buf, pos)
            if op == Opcode.HEADER and pos + 9 + length <= n:
                try:
                    h = _parse(op, buf[pos + 9:pos + 9 + length], exact=False)
                    rep.profile, rep.library = h.profile, h.library
                    pos += 9 + length
                except _BadRecord:
                    pass
        while pos < n:
            if n - pos < 9:
                rep.damage.append(Damage("truncated", pos, n - pos, "file ends inside a record header"))
                break
            op, length = _REC.unpack_from(buf, pos)
            end = pos + 9 + length
            if op not in _DATA_OPCODES or op == Opcode.HEADER:
                nxt = self._resync(pos + 1)
                rep.damage.append(Damage("unreadable", pos, nxt - pos,
                                         f"no valid record (opcode 0x{op:02x}, length {length})"))
                pos = nxt
                continue
            if end > n:
                d = Damage("truncated", pos, n - pos, f"{Opcode(op).name.lower()} record of {9 + length} bytes cut "
                                                      f"off after {n - pos} bytes")
                if op == Opcode.CHUNK and n - pos >= 25:
                    d.log_start_ns, d.log_end_ns = struct.unpack_from("<QQ", buf, pos + 9)
                nxt = self._resync(pos + 1)
                d.length = nxt - pos
                if nxt < n:  # readable records follow: the length field was damaged, not the file cut short
                    d.kind, d.detail = "unreadable", f"record length {length} points past the end of the file"
                rep.damage.append(d)
                pos = nxt
                continue
            try:
                rec = _parse(op, buf[pos + 9:end], exact=op not in (Opcode.DATA_END,))
            except _BadRecord as exc:
                nxt = self._resync(pos + 1)
                rep.damage.append(Damage("unreadable", pos, nxt - pos, str(exc)))
                pos = nxt
                continue
            if op == Opcode.CHUNK:
                try:
                    inner = _chunk_records(rec)
                except _BadRecord as exc:
                    rep.damage.append(Damage("corrupt-chunk", pos, 9 + length, str(exc),
                                             rec.message_start_time, rec.message_end_time))
                    pos = end
                    continue
                pos = end
                yield from inner
                continue
            if op == Opcode.DATA_END:
                rep.data_end = True
                self._read_summary(end, rep)
                return
            if op in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.METADATA, Opcode.ATTACHMENT):
                yield rec
            pos = end

    def _read_summary(self, pos: int, rep: ScanReport) -> None:
        buf, n = self._buf, self.size
        while pos < n:
            if n - pos < 9:
                break
            op, length = _REC.unpack_from(buf, pos)
            end = pos + 9 + length
            if op not in _SUMMARY_OPCODES or end > n:
                rep.damage.append(Damage("unreadable", pos, n - pos, "summary section damaged"))
                return
            if op == Opcode.STATISTICS:
                try:
                    rep.summary_messages = _parse(op, buf[pos + 9:end], exact=False).message_count
                except _BadRecord:
                    pass
            pos = end
            if op == Opcode.FOOTER:
                if buf[pos:pos + 8] == MCAP_MAGIC and pos + 8 == n:
                    rep.closed = True
                else:
                    rep.damage.append(Damage("truncated", pos, n - pos, "closing magic missing after the footer"))
                return
        rep.damage.append(Damage("truncated", pos, n - pos, "summary section cut off"))

    def _records(self, rep: ScanReport) -> Iterator[tuple[str, Any]]:
        """Walk + bookkeeping of schemas/channels/metadata; yields ('message', BagMessage) and the other records."""
        for rec in self._walk(rep):
            if isinstance(rec, Message):
                ch = self._channels.get(rec.channel_id)
                if ch is None:
                    continue
                sch = self._schemas.get(ch.schema_id)
                yield "message", BagMessage(ch.topic, sch.name if sch else "", rec.log_time, rec.publish_time,
                                            rec.data, rec.channel_id, rec.sequence)
            elif isinstance(rec, Schema):
                self._schemas.setdefault(rec.id, rec)
                yield "schema", rec
            elif isinstance(rec, Channel):
                self._channels.setdefault(rec.id, rec)
                yield "channel", rec
            elif isinstance(rec, Metadata):
                yield "metadata", rec
            elif isinstance(rec, Attachment):
                yield "attachment", rec

    # -- API
    @property
    def report(self) -> ScanReport:
        if self._report is None:
            rep = ScanReport(str(self.path), self.size)
            topics: dict[int, TopicInfo] = {}
            metadata = []
            for kind, rec in self._records(rep):
                if kind == "message":
                    t = topics.get(rec.channel_id)
                    if t is None:
                        continue
                    t.count += 1
                    rep.messages += 1
                    if t.first_log_ns is None or rec.log_time_ns < t.first_log_ns:
                        t.first_log_ns = rec.log_time_ns
                    if t.last_log_ns is None or rec.log_time_ns > t.last_log_ns:
                        t.last_log_ns = rec.log_time_ns
                elif kind == "channel" and rec.id not in topics:
                    sch = self._schemas.get(rec.schema_id)
                    topics[rec.id] = TopicInfo(rec.topic, sch.name if sch else "", rec.id,
                                               offered_qos=qos_from_yaml(rec.metadata.get("offered_qos_profiles", "")),
                                               type_hash=rec.metadata.get("topic_type_hash", ""))
                elif kind == "metadata":
                    metadata.append((rec.name, dict(rec.metadata)))
            if not rep.data_end and not any(d.kind == "truncated" for d in rep.damage):
                rep.damage.append(Damage("no-summary", self.size, 0, "no summary or index; whatever the writer had "
                                                                     "not flushed yet is missing"))
            for t in topics.values():
                if t.topic in rep.topics:  # same topic on several channels: merge counts
                    m = rep.topics[t.topic]
                    m.count += t.count
                else:
                    rep.topics[t.topic] = t
            firsts = [t.first_log_ns for t in topics.values() if t.first_log_ns is not None]
            lasts = [t.last_log_ns for t in topics.values() if t.last_log_ns is not None]
            rep.start_ns = min(firsts) if firsts else None
            rep.end_ns = max(lasts) if lasts else None
            self._metadata = metadata
            self._report = rep
        return self._report

    @property
    def topics(self) -> dict[str, TopicInfo]:
        return self.report.topics

    @property
    def metadata(self) -> list[tuple[str, dict[str, str]]]:
        """All metadata records, in file order, as (name, string map)."""
        self.report
        return list(self._metadata)

    def metadata_named(self, name: str) -> dict[str, str] | None:
        found = [m for n, m in self.metadata if n == name]
        return found[-1] if found else None

    def run_metadata(self) -> RunMetadata | None:
        rec = self.metadata_named(RUN_METADATA_NAME)
        return RunMetadata.from_record(rec) if rec is not None else None

    def messages(self, topics: Iterable[str] | None = None, *, start_ns: int | None = None) -> Iterator[BagMessage]:
        """Stream messages in log-time order, optionally of some topics and from log time ``start_ns`` on.

        The order is restored within a bounded reorder window (a recorder's executor can take messages slightly
        out of arrival order). Damage is skipped; see :attr:`report`.
        """
        yield from _log_time_order(self._stored_messages(topics, start_ns))

    def _stored_messages(self, topics: Iterable[str] | None, start_ns: int | None = None) -> Iterator[BagMessage]:
        """Messages of ``topics`` (None: all) logged at or after ``start_ns``, in file order."""
        want = set(topics) if topics is not None else None
        rep = ScanReport(str(self.path), self.size)  # scratch report; the cached one comes from a full pass
        for kind, rec in self._records(rep):
            if kind != "message":
                continue
            if want is not None and rec.topic not in want:
                continue
            if start_ns is not None and rec.log_time_ns < start_ns:
                continue
            yield rec

    def decoder(self, type_name_or_msg) -> Callable[[bytes], Any]:
        """A function bytes -> decoded message (mcap_ros2's dynamic classes) for a type or a BagMessage."""
        from mcap_ros2.decoder import DecoderFactory
        self.report
        if self._factory is None:
            self._factory = DecoderFactory()
        type_name = type_name_or_msg.type_name if isinstance(type_name_or_msg, BagMessage) else type_name_or_msg
        for sid, sch in self._schemas.items():
            if sch.name == type_name:
                if sid not in self._decoders:
                    dec = self._factory.decoder_for(MESSAGE_ENCODING, sch)
                    if dec is None:
                        raise BagError(f"cannot decode {type_name}: schema encoding {sch.encoding!r}")
                    self._decoders[sid] = dec
                return self._decoders[sid]
        raise BagError(f"no schema for {type_name} in {self.path}")

    def decode(self, msg: BagMessage) -> Any:
        return self.decoder(msg)(msg.data)

    def decoded(self, topic: str) -> list[tuple[int, int, Any]]:
        """All messages of one topic as (log_time_ns, publish_time_ns, decoded message), in log-time order."""
        return self.decoded_many([topic])[topic]

    def decoded_many(self, topics: Iterable[str]) -> dict[str, list[tuple[int, int, Any]]]:
        """:meth:`decoded` of several topics in one pass over the file: topic -> rows (empty when absent).

        Each topic is put in log-time order on its own, so its rows are exactly what :meth:`decoded` gives."""
        stored: dict[str, list[BagMessage]] = {t: [] for t in topics}
        for m in self._stored_messages(stored):
            stored[m.topic].append(m)
        out = {}
        for topic, msgs in stored.items():
            dec = self.decoder(msgs[0]) if msgs else None
            out[topic] = [(m.log_time_ns, m.publish_time_ns, dec(m.data))
                          for m in _log_time_order(msgs)]
        return out

    def close(self) -> None:
        if isinstance(self._buf, mmap.mmap):
            self._buf.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def scan(path: str | os.PathLike) -> ScanReport:
    """Full pass over a file: what it holds and what was lost (raises NotMcapError for a non-MCAP file)."""
    with BagReader(path) as r:
        return r.report


def recover(src: str | os.PathLike, dst: str | os.PathLike, *, overwrite: bool = False) -> ScanReport:
    """Rewrite every readable schema, channel, message, metadata and attachment of ``src`` (e.g. a file cut
    short by a SIGKILL) into a new, valid, indexed MCAP file ``dst``. Returns the scan report of ``src``; a
    ``flagbot_sim.recovery`` metadata record in ``dst`` repeats what was lost."""
    dst = Path(dst)
    if dst.exists() and not overwrite:
        raise BagError(f"{dst} exists; choose another name or allow overwriting")
    if Path(src).resolve() == dst.resolve():
        raise BagError("recover needs a different output file")
    with BagReader(src) as r:
        rep = r.report
        with open(dst, "wb") as f:
            w = Writer(f, chunk_size=DEFAULT_CHUNK_SIZE, compression=CompressionType.ZSTD)
            w.start(rep.profile or PROFILE, rep.library or LIBRARY)
            schema_map: dict[int, int] = {}
            channel_map: dict[int, int] = {}
            scratch = ScanReport(str(src), r.size)
            for kind, rec in r._records(scratch):
                if kind == "schema" and rec.id not in schema_map:
                    schema_map[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
                elif kind == "channel" and rec.id not in channel_map:
                    channel_map[rec.id] = w.register_channel(rec.topic, rec.message_encoding,
                                                             schema_map.get(rec.schema_id, 0), rec.metadata)
                elif kind == "message" and rec.channel_id in channel_map:
                    w.add_message(channel_map[rec.channel_id], rec.log_time_ns, rec.data, rec.publish_time_ns,
                                  rec.sequence)
                elif kind == "metadata":
                    w.add_metadata(rec.name, rec.metadata)
                elif kind == "attachment":
                    w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data)
            w.add_metadata(RECOVERY_METADATA_NAME, {"source": str(src), "loss": rep.describe_loss() or "nothing lost",
                                                    "lost_bytes": str(rep.lost_bytes),
                                                    "recovered_messages": str(rep.messages)})
            w.finish()
    return rep


# ----------------------------------------------------------------------------------------------------------------
# what re-simulation and analysis need


@dataclass
class RunRecord:
    """A recorded run reduced to what a re-simulation needs: the scene, parameters, version, command stream.

    Times are in seconds: ``t`` = log (receive) time since the first message of the bag, ``sim_t`` = simulation
    time from the recorded /clock at that moment (None without /clock)."""
    path: str
    metadata: RunMetadata | None
    start_ns: int | None
    cmd_omega: list[tuple[float, float | None, float]]  # (t, sim_t, omega_T rad/s)
    report: ScanReport

    @property
    def scene_toml(self) -> str:
        return self.metadata.scene_toml if self.metadata else ""

    @property
    def parameters(self) -> dict[str, Any]:
        return self.metadata.parameters if self.metadata else {}


def find_topic(topics: Iterable[str], name: str, namespace: str | None = None) -> str | None:
    """The recorded topic for a flagbot name (``omega_h``, ``cmd_omega``, ``/clock``) in ``namespace`` (default:
    the only/first namespace that has it)."""
    topics = list(topics)
    if name.startswith("/"):
        return name if name in topics else None
    if namespace is not None:
        t = namespace.rstrip("/") + "/" + name
        t = t if t.startswith("/") else "/" + t
        return t if t in topics else None
    # prefer the shortest (/bot/omega_h over /bot/beam/omega_h), then the first by name
    cands = sorted((t for t in topics if t == "/" + name or t.endswith("/" + name)), key=lambda t: (t.count("/"), t))
    return cands[0] if cands else None


def namespace_of(topic: str, name: str) -> str:
    return topic[: -len(name) - 1] if topic.endswith("/" + name) else ""


class SimTimeMap:
    """Map log (receive) time to simulation time by interpolating recorded /clock messages."""

    def __init__(self, log_ns: list[int], clock_ns: list[int]):
        self.log_ns = log_ns
        self.clock_ns = clock_ns

    @classmethod
    def from_rows(cls, rows: Iterable[tuple[int, int, Any]]) -> "SimTimeMap":
        """From decoded /clock messages (:meth:`BagReader.decoded` rows)."""
        return cls([lt for lt, _, _ in rows], [m.clock.sec * 1_000_000_000 + m.clock.nanosec for _, _, m in rows])

    def __bool__(self):
        return bool(self.log_ns)

    def __call__(self, log_ns):
        import numpy as np
        return np.interp(np.asarray(log_ns, dtype=float), np.asarray(self.log_ns, dtype=float),
                         np.asarray(self.clock_ns, dtype=float)) * 1e-9


def sim_time_map(reader: BagReader, clock_topic: str = CLOCK) -> SimTimeMap:
    if clock_topic not in reader.topics:
        return SimTimeMap([], [])
    return SimTimeMap.from_rows(reader.decoded(clock_topic))


def read_run(path: str | os.PathLike, namespace: str | None = None) -> RunRecord:
    """Scene, parameters, package version and the decoded ``cmd_omega`` stream with times (for re-simulation)."""
    with BagReader(path) as r:
        rep = r.report
        meta = r.run_metadata()
        cmds = []
        topic = find_topic(r.topics, CMD_OMEGA, namespace)
        if topic is not None:
            rows = r.decoded_many([topic, CLOCK])
            smap = SimTimeMap.from_rows(rows[CLOCK])
            for lt, _, m in rows[topic]:
                cmds.append(((lt - rep.start_ns) * 1e-9, float(smap(lt)) if smap else None, float(m.data)))
        return RunRecord(str(r.path), meta, rep.start_ns, cmds, rep)


__all__ = ["BagError", "NotMcapError", "InterfaceNotFound", "BagWriter", "BagReader", "BagMessage", "RunMetadata",
           "RunRecord", "ScanReport", "Damage", "TopicInfo", "QosInfo", "WriteSummary", "message_definition",
           "normalize_type", "split_type", "has_header", "cdr_header_stamp_ns", "qos_to_yaml", "qos_from_yaml",
           "scan", "recover", "read_run", "find_topic", "sim_time_map", "package_version",
           "DEFAULT_FLUSH_INTERVAL", "DEFAULT_CHUNK_SIZE", "RUN_METADATA_NAME"]
