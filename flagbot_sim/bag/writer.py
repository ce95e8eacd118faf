"""Writing serialized ROS 2 messages to MCAP as rosbag2 does, flushed often enough to survive a SIGKILL.

Crash safety. Messages go into small chunks (zstd, CRC of the uncompressed data) and every chunk is closed and
flushed to the OS at least every ``flush_interval``: a SIGKILL loses only the chunk being filled plus whatever was
still in the middleware's queues. Schemas and channels are also written *outside* chunks, so any chunk can be
decoded on its own when an earlier one is damaged. The OS page cache survives SIGKILL; only a power cut needs
``fsync`` (``fsync_interval``).
"""
from __future__ import annotations

import errno
import io
import os
import struct
import tempfile
import threading
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, Callable, Mapping

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (Attachment, AttachmentIndex, Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, Metadata,
                          MetadataIndex, Schema, Statistics, SummaryOffset)

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


_MAGIC = b"\x89MCAP0\r\n"
_RECORD = struct.Struct("<BQ")                  # opcode, body length
_MESSAGE = struct.Struct("<BQHIQQ")             # ... channel id, sequence, log time, publish time (then the data)
_INDEX_ENTRY = struct.Struct("<QQ")             # message index: log time, offset in the chunk's records
_COPY_BLOCK = 1 << 16


def _record_bytes(record) -> bytes:
    b = RecordBuilder()
    record.write(b)
    return b.end()


class McapStreamWriter:
    """An MCAP writer whose memory does not grow with the length of the recording.

    It writes what ``mcap.writer.Writer`` (all indexes, statistics, repeated schemas and channels, summary offsets,
    summary CRC) writes, record for record, for the calls BagWriter and :func:`recover` make (``start``,
    ``register_schema``, ``register_channel``, ``add_message``, ``add_metadata``, ``add_attachment``, ``flush``,
    ``finish``) with the same arguments. The difference: mcap's writer keeps a ``ChunkIndex`` object (with a dict
    of message-index offsets, one per channel in the chunk) for every chunk until ``finish()``, ~1.4 KB per chunk
    for a sim_node recording's 17 topics, so with a chunk every 0.1 s the recorder grew by ~50 MB per recorded
    hour (docs/recording.md). Here each chunk index is serialized as soon as its chunk is written and appended to
    an anonymous temporary file (``spill_dir``, default the system's; BagWriter gives the recording's own
    directory: same disk, and not a tmpfs in RAM); ``finish()`` copies it into the summary section in blocks,
    computing the summary CRC as it goes. What stays in memory is bounded by the number of channels, schemas and
    metadata records and by the chunk being filled. The temporary file has no name (it disappears with the
    process, a crash included) and takes ~60 + 10 x (channels in the chunk) bytes per chunk until :meth:`close`.

    ``stream`` is a binary file object with ``tell()`` (a raw one is buffered, as mcap's writer does: then write
    other records with :meth:`write_record`, as BagWriter writes schemas and channels outside chunks; offsets are
    taken from ``tell()``).
    """

    def __init__(self, stream: BinaryIO, *, chunk_size: int = DEFAULT_CHUNK_SIZE, compression: str = "zstd",
                 spill_dir: str | os.PathLike | None = None):
        if compression == "zstd":
            import zstandard
            self._compress = zstandard.compress
        elif compression == "lz4":
            import lz4.frame
            self._compress = lz4.frame.compress
        elif compression == "":
            self._compress = None
        else:
            raise BagError(f"unknown compression {compression!r} (zstd, lz4 or '')")
        if isinstance(stream, io.RawIOBase):
            stream = io.BufferedWriter(stream)
        self._out = stream
        self._compression = compression
        self._chunk_size = chunk_size
        self._spill_dir = spill_dir
        self._spill: BinaryIO | None = None       # serialized ChunkIndex records, in file order
        self._spill_bytes = 0
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._metadata_indexes: list[MetadataIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._counts: dict[int, int] = {}          # channel id -> messages, in order of each channel's first message
        self.message_count = 0
        self.chunk_count = 0
        self._start_time = 0
        self._end_time = 0
        # the chunk being filled: its records (uncompressed), log-time range, messages and per-channel index
        self._chunk = bytearray()
        self._chunk_messages = 0
        self._chunk_start = 0
        self._chunk_end = 0
        self._chunk_index: dict[int, list[int]] = {}   # channel id -> flat [log time, offset, log time, offset, ...]
        self.finished = False

    # -- records outside chunks
    def _write(self, data: bytes) -> None:
        self._out.write(data)

    def write_record(self, record) -> None:
        """Write any record (an ``mcap.records`` object) where the file is now, outside chunks."""
        self._write(_record_bytes(record))

    def start(self, profile: str = "", library: str = "") -> None:
        self._open_spill()
        self._write(_MAGIC)
        self._write(_record_bytes(Header(profile=profile, library=library)))

    def _open_spill(self) -> None:
        if self._spill is not None:
            return
        try:
            self._spill = tempfile.TemporaryFile(prefix=".flagbot-chunk-index-", dir=self._spill_dir)
        except OSError:
            if self._spill_dir is None:
                raise
            self._spill = tempfile.TemporaryFile(prefix=".flagbot-chunk-index-")   # e.g. a directory not ours

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        offset = self._out.tell()
        record = _record_bytes(Metadata(name=name, metadata=dict(data)))
        self._write(record)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=len(record), name=name))

    def add_attachment(self, create_time: int, log_time: int, name: str, media_type: str, data: bytes) -> None:
        offset = self._out.tell()
        record = _record_bytes(Attachment(create_time=create_time, log_time=log_time, name=name,
                                          media_type=media_type, data=data))
        self._write(record)
        self._attachment_indexes.append(AttachmentIndex(offset=offset, length=len(record), log_time=log_time,
                                                        create_time=create_time, data_size=len(data), name=name,
                                                        media_type=media_type))

    # -- registrations (also put into the chunk being filled, as mcap's writer does)
    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = len(self._schemas) + 1
        schema = Schema(id=sid, name=name, encoding=encoding, data=data)
        self._schemas[sid] = schema
        self._chunk += _record_bytes(schema)
        self._maybe_finalize_chunk()
        return sid

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: Mapping[str, str] | None = None) -> int:
        cid = len(self._channels) + 1
        channel = Channel(id=cid, topic=topic, message_encoding=message_encoding, schema_id=schema_id,
                          metadata=dict(metadata or {}))
        self._channels[cid] = channel
        self._chunk += _record_bytes(channel)
        self._maybe_finalize_chunk()
        return cid

    # -- messages
    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0) -> None:
        if self.message_count == 0:
            self._start_time = self._end_time = log_time
        else:
            self._start_time = min(self._start_time, log_time)
            self._end_time = max(self._end_time, log_time)
        self._counts[channel_id] = self._counts.get(channel_id, 0) + 1
        self.message_count += 1
        if self._chunk_messages == 0:
            self._chunk_start = self._chunk_end = log_time
        else:
            self._chunk_start = min(self._chunk_start, log_time)
            self._chunk_end = max(self._chunk_end, log_time)
        entries = self._chunk_index.get(channel_id)
        if entries is None:
            entries = self._chunk_index[channel_id] = []
        entries += (log_time, len(self._chunk))
        self._chunk_messages += 1
        self._chunk += _MESSAGE.pack(Opcode.MESSAGE, 22 + len(data), channel_id, sequence, log_time, publish_time)
        self._chunk += data
        self._maybe_finalize_chunk()

    def _maybe_finalize_chunk(self) -> None:
        if len(self._chunk) > self._chunk_size:
            self._finalize_chunk()

    def _finalize_chunk(self) -> None:
        if self._chunk_messages == 0:
            return                      # (registrations alone stay for the next chunk, as in mcap's writer)
        raw = bytes(self._chunk)
        data = self._compress(raw) if self._compress else raw
        chunk = Chunk(compression=self._compression, data=data, message_start_time=self._chunk_start,
                      message_end_time=self._chunk_end, uncompressed_crc=zlib.crc32(raw), uncompressed_size=len(raw))
        record = _record_bytes(chunk)
        chunk_offset = self._out.tell()
        indexes, offsets = bytearray(), {}
        index_start = chunk_offset + len(record)
        for cid, entries in self._chunk_index.items():
            offsets[cid] = index_start + len(indexes)
            indexes += _RECORD.pack(Opcode.MESSAGE_INDEX, 6 + 8 * len(entries))
            indexes += struct.pack(f"<HI{len(entries)}Q", cid, 8 * len(entries), *entries)
        self._write(record)
        self._write(bytes(indexes))
        index = ChunkIndex(message_start_time=self._chunk_start, message_end_time=self._chunk_end,
                           chunk_start_offset=chunk_offset, chunk_length=len(record), message_index_offsets=offsets,
                           message_index_length=len(indexes), compression=self._compression,
                           compressed_size=len(data), uncompressed_size=len(raw))
        self._open_spill()
        spilled = _record_bytes(index)
        self._spill.write(spilled)
        self._spill_bytes += len(spilled)
        self.chunk_count += 1
        self._chunk = bytearray()
        self._chunk_messages = 0
        self._chunk_index = {}

    def flush(self) -> None:
        """Close the chunk being filled (if it has a message), write it and its message indexes, flush the stream
        to the OS (no fsync)."""
        self._finalize_chunk()
        self._out.flush()

    # -- the end
    def finish(self) -> None:
        """Close the last chunk, write the data end, the summary (schemas, channels, statistics, chunk indexes,
        attachment and metadata indexes, summary offsets), the footer with the summary CRC and the closing magic.
        Does not close ``stream``; does :meth:`close` the temporary file."""
        self._finalize_chunk()
        self._write(_record_bytes(DataEnd(data_section_crc=0)))
        summary_start = pos = self._out.tell()
        crc = 0
        offsets = []

        def put(data: bytes) -> None:
            nonlocal crc, pos
            self._write(data)
            crc = zlib.crc32(data, crc)
            pos += len(data)

        def group(opcode: Opcode, records) -> None:
            start = pos
            for r in records:
                put(_record_bytes(r))
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=start, group_length=pos - start))

        group(Opcode.SCHEMA, self._schemas.values())
        group(Opcode.CHANNEL, self._channels.values())
        group(Opcode.STATISTICS, [Statistics(
            attachment_count=len(self._attachment_indexes), channel_count=len(self._channels),
            channel_message_counts=self._counts, chunk_count=self.chunk_count, message_count=self.message_count,
            metadata_count=len(self._metadata_indexes), message_start_time=self._start_time,
            message_end_time=self._end_time, schema_count=len(self._schemas))])
        start = pos
        if self._spill is not None:
            self._spill.flush()
            self._spill.seek(0)
            left = self._spill_bytes
            while left > 0:
                block = self._spill.read(min(_COPY_BLOCK, left))
                if not block:
                    raise OSError(errno.EIO, "the temporary chunk index file ended early")
                put(block)
                left -= len(block)
        offsets.append(SummaryOffset(group_opcode=Opcode.CHUNK_INDEX, group_start=start, group_length=pos - start))
        group(Opcode.ATTACHMENT_INDEX, self._attachment_indexes)
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        offset_start = pos
        for o in offsets:
            put(_record_bytes(o))
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, offset_start), crc)
        self._write(_record_bytes(Footer(summary_start=summary_start, summary_offset_start=offset_start,
                                         summary_crc=crc)))
        self._write(_MAGIC)
        self._out.flush()
        self.finished = True
        self.close()

    def close(self) -> None:
        """Release the temporary chunk index file (the summary can then no longer be written)."""
        spill, self._spill = self._spill, None
        if spill is not None:
            try:
                spill.close()
            except OSError:
                pass


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
        comp = {"zstd": "zstd", "lz4": "lz4", "none": "", "": ""}.get(compression)
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
        # chunk indexes go to an unnamed temporary file beside the recording until close (McapStreamWriter)
        spill_dir = str(Path(self.path).parent) if self._owns_file else None
        self._writer = McapStreamWriter(self._file, chunk_size=chunk_size, compression=comp, spill_dir=spill_dir)
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
        self._writer.close()
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
        self._writer.write_record(record)

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
                self._writer.close()        # after an error too: the temporary chunk index file goes
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

