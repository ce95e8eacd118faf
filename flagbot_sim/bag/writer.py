"""Writing serialized ROS 2 messages to MCAP as rosbag2 does, flushed often enough to survive a SIGKILL.

Crash safety. Messages go into small chunks (zstd, CRC of the uncompressed data) and every chunk is closed and
flushed to the OS at least every ``flush_interval``: a SIGKILL loses only the chunk being filled plus whatever was
still in the middleware's queues. Schemas and channels are also written *outside* chunks, so any chunk can be
decoded on its own when an earlier one is damaged. The OS page cache survives SIGKILL; only a power cut needs
``fsync`` (``fsync_interval``).
"""
from __future__ import annotations

import errno
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, Callable, Mapping

from mcap.data_stream import RecordBuilder
from mcap.records import Channel, Schema
from mcap.writer import CompressionType, Writer

from .format import (DEFAULT_CHUNK_SIZE, DEFAULT_FLUSH_INTERVAL, LIBRARY, MESSAGE_ENCODING, PROFILE,
                     ROSBAG2_METADATA_NAME, RUN_METADATA_NAME, SCHEMA_ENCODING, BagError, BagWriteError)
from .metadata import RunMetadata, rosbag2_serialized_metadata
from .schema import cdr_header_stamp_ns, has_header, message_definition, normalize_type


def _describe(exc: OSError) -> str:
    """'No space left on device (ENOSPC)' rather than '[Errno 28] No space left on device'."""
    name = errno.errorcode.get(exc.errno or 0, "")
    text = exc.strerror or str(exc)
    return f"{text} ({name})" if name else text


def _refuse_link(p: Path) -> None:
    """A symbolic link at ``p`` whose target is missing or not a regular file: opening it would create or write that
    target (another name, elsewhere) instead of ``p``. A link to an existing regular file is treated as that file."""
    if not p.is_symlink():
        return
    try:
        target = os.readlink(p)
    except OSError:
        target = "?"
    if not p.exists():
        raise BagWriteError(f"cannot record to {p}: it is a symbolic link to {target!r}, which does not exist: "
                            "recording would create that file instead; give the file's own name")
    if not p.is_file():
        raise BagWriteError(f"cannot record to {p}: it is a symbolic link to {target!r}, which is not a regular file")


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
    error: str = ""             # "" when every write succeeded
    lost: dict[str, int] = field(default_factory=dict)   # topic -> messages that never reached the recorder

    def format(self) -> str:
        lost = sum(self.lost.values())
        lines = [f"{self.path}: {self.messages} messages, {len(self.topics)} topics, {self.duration:.2f} s, "
                 f"{self.size_bytes / 1024:.1f} KiB, "
                 f"{'closed with summary and index' if self.closed else 'NOT closed'}"
                 + (f", {lost} messages LOST before reaching the recorder" if lost else "")]
        for t in sorted(self.topics.values(), key=lambda s: s.topic):
            n = self.lost.get(t.topic, 0)
            lines.append(f"  {t.topic:32s} {t.type_name:40s} {t.count:8d}" + (f"  {n} lost" if n else ""))
        if self.error:
            lines.append(f"  ERROR: {self.error}")
        return "\n".join(lines)


class BagWriter:
    """Write serialized ROS 2 messages to an MCAP file as rosbag2 does. Thread-safe.

    ``path`` is a file path (``.mcap`` is appended if missing) or a binary file object. ``metadata`` (a
    :class:`RunMetadata` or a plain string map) is written first, and flushed: a target that cannot be created or
    written (no such directory, no permission, a full disk, a file size limit) raises :class:`BagWriteError` (an
    ``OSError`` and a :class:`BagError`) right here and leaves no file behind. A write error later (e.g. disk full)
    stops the recording: :attr:`error` says why (once; it stays set), nothing more is written, and everything
    flushed before stays recoverable with :func:`recover`.

    Crash loss: the chunk being filled is closed and flushed when ``flush_interval`` has passed since the last
    flush, by the next :meth:`write` or by whoever calls :meth:`maybe_flush` at :meth:`seconds_to_flush` (the
    recorder's flush thread); and when it reaches ``chunk_size``.
    """

    def __init__(self, path: str | os.PathLike | BinaryIO, *, metadata: RunMetadata | Mapping[str, str] | None = None,
                 chunk_size: int = DEFAULT_CHUNK_SIZE, compression: str = "zstd",
                 flush_interval: float = DEFAULT_FLUSH_INTERVAL, fsync_interval: float | None = None,
                 overwrite: bool = False, clock: Callable[[], float] = time.monotonic):
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE,
                "": CompressionType.NONE}.get(compression)
        if comp is None:
            raise BagError(f"unknown compression {compression!r} (zstd, lz4, none)")
        run_record = None
        if metadata is not None:    # before the file exists: a bad key must not leave one behind
            run_record = metadata.to_record() if isinstance(metadata, RunMetadata) else dict(metadata)
        if isinstance(path, (str, os.PathLike)):
            p = Path(path)
            _refuse_link(p)         # the name given, and below the '.mcap' name made of it (sim_node's rule too)
            # a directory, FIFO or device: appending ".mcap" would quietly write beside it (/tmp -> /tmp.mcap)
            if p.is_dir():
                raise BagWriteError(f"cannot record to {p}: it is a directory; give a file name such as "
                                    f"{p / 'run.mcap'}")
            if p.exists() and not p.is_file():
                raise BagWriteError(f"cannot record to {p}: it is not a regular file")
            if p.suffix != ".mcap":
                p = p.with_name(p.name + ".mcap")
            _refuse_link(p)
            if p.exists() and not overwrite:
                raise BagWriteError(f"cannot record to {p}: it exists; choose another name or allow overwriting")
            if not p.parent.is_dir():
                raise BagWriteError(f"cannot record to {p}: directory {p.parent} does not exist")
            self.path = str(p)
            try:
                # "xb" (O_CREAT|O_EXCL) when nothing may be overwritten: it never follows a symbolic link, so a
                # link or file made after the checks above (a race) is refused, not written through
                self._file = open(p, "wb" if overwrite else "xb")
            except OSError as exc:
                raise BagWriteError(f"cannot record to {p}: {_describe(exc)}") from None
            self._owns_file = True
        else:
            self.path = getattr(path, "name", "<stream>")
            self._file = path
            self._owns_file = False
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
        self.error = ""
        self.closed = False
        self._guard(self._writer.start, PROFILE, LIBRARY)
        self._guard(self._writer.add_metadata, ROSBAG2_METADATA_NAME,
                    {"serialized_metadata": rosbag2_serialized_metadata(Path(self.path).name)})
        if run_record is not None:
            self.add_metadata(RUN_METADATA_NAME, run_record)
        self.flush()
        if self.error:
            self._abandon()
            raise BagWriteError(f"cannot record to {self.path}: {_describe(self._failure)}")

    # -- internals
    def _guard(self, fn, *args) -> bool:
        if self.error:
            return False
        try:
            fn(*args)
            return True
        except OSError as exc:  # disk full, file too large, I/O error: stop (once), keep what is on disk
            self._failure = exc
            self.error = (f"writing {self.path} failed after {self.message_count} messages: {_describe(exc)}; "
                          f"nothing more is recorded")
            return False

    def _abandon(self) -> None:
        """The file could not even take its header: close it and remove it (nothing in it is worth keeping)."""
        self.closed = True
        if self._owns_file:
            try:
                self._file.close()
            except OSError:
                pass
            try:
                os.unlink(self.path)
            except OSError:
                pass

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
            if self.closed or self.error:
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

    def seconds_to_flush(self) -> float:
        """Time until :meth:`maybe_flush` is due (0 when it is): when a flush thread should call it next."""
        with self._lock:
            return max(0.0, self._last_flush + self.flush_interval - self._clock())

    def maybe_flush(self) -> None:
        """Close the current chunk and flush if ``flush_interval`` has passed since the last flush; call it from a
        timer or thread too, at :meth:`seconds_to_flush`. With nothing pending the interval starts again, so a
        message written after a quiet spell is flushed at most ``flush_interval`` later."""
        with self._lock:
            now = self._clock()
            if now - self._last_flush >= self.flush_interval:
                if self._pending:
                    self.flush()
                else:
                    self._last_flush = now
            if self.fsync_interval is not None and now - self._last_fsync >= self.fsync_interval:
                self._last_fsync = now
                if self._owns_file and not self.error:
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
                            self.closed and not self.error, self.error)

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

