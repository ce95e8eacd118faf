"""Reading MCAP recordings record by record, also damaged ones, with a report of what was lost.

:class:`BagReader` walks the records from the start instead of trusting the summary, so a truncated file (killed
writer, full disk) or a corrupt chunk costs only the damaged part: it skips a bad chunk by its length,
re-synchronises on the next chunk whose data decompresses and passes its CRC, and records every loss in a
:class:`ScanReport` that says which bytes, which log-time range and (when the summary survived) how many messages
were lost; :func:`recover` rewrites what was readable into a valid, indexed file. A file that is not MCAP at all
raises :class:`NotMcapError` with a message naming what it looks like instead.
"""
from __future__ import annotations

import heapq
import io
import mmap
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (Attachment, Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema,
                          Statistics)

from .format import (DEFAULT_CHUNK_SIZE, LIBRARY, MCAP_MAGIC, MESSAGE_ENCODING, PROFILE, RECOVERY_METADATA_NAME,
                     RUN_METADATA_NAME, BagError, NotMcapError)
from .metadata import RunMetadata
from .qos import QosInfo, qos_from_yaml
from .writer import McapStreamWriter


@dataclass
class Damage:
    """One unreadable stretch of a file."""
    kind: str            # truncated | corrupt-chunk | unreadable | no-summary (cut between records) | summary
    offset: int          # first byte of the damaged stretch
    length: int          # bytes lost
    detail: str
    log_start_ns: int | None = None   # log-time range of the lost chunk, when its header survived
    log_end_ns: int | None = None
    messages: int | None = None       # messages lost in this stretch, when known (a chunk's message indexes)

    def describe(self, t0_ns: int | None = None) -> str:
        if self.kind == "no-summary":
            return f"file ends after a complete record at byte {self.offset} ({self.detail})"
        s = f"{self.kind} at byte {self.offset}: {self.length} bytes lost ({self.detail})"
        if self.messages is not None:
            s += f", {self.messages} messages"
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
    expected_messages: int | None = None  # message count the file says it holds up front (bag-recover writes it)
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
    def total_messages(self) -> int | None:
        """How many messages the file held when written: from the summary's statistics, else from the count a
        recovered file states at its start, else from the damaged chunks' message indexes when every lost stretch
        has one and the data section ends properly; None when unknown."""
        if self.summary_messages is not None:
            return self.summary_messages
        if self.expected_messages is not None:
            return self.expected_messages
        data_damage = [d for d in self.damage if d.kind != "summary"]
        if self.data_end and all(d.messages is not None for d in data_damage):
            return self.messages + sum(d.messages for d in data_damage)
        return None

    @property
    def lost_messages(self) -> int | None:
        """Exact count when :attr:`total_messages` is known, else None."""
        total = self.total_messages
        return None if total is None else max(0, total - self.messages)

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
            parts.append(f"{lost} of {self.total_messages} messages lost")
        elif self.damage:
            parts.append("number of lost messages unknown (no summary)")
        if self.messages:
            parts.append(f"recovered {self.messages} messages covering {self.duration:.3f} s "
                         f"(log time up to {self.end_ns * 1e-9:.3f})")
        else:
            parts.append("no message could be recovered")
        return f"{self.path}: " + "; ".join(parts) + "."


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
        after_chunk = False          # a chunk was seen (messages are then inside chunks)
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
            if op == Opcode.DATA_END and length != 4:
                # a data end is 4 bytes (a CRC); another record whose opcode bit flipped to it would end the data
                # section here and lose every chunk after it
                nxt = self._resync(pos + 1)
                if nxt < n:
                    rep.damage.append(Damage("unreadable", pos, nxt - pos, f"a record with a damaged opcode (data "
                                                                            f"end of {length} bytes)", messages=0))
                    pos = nxt
                    continue
            if op == Opcode.MESSAGE_INDEX and not self._index_shaped(pos + 9, length):
                # an index whose length field was hit would send the walk past good chunks into the middle of
                # a later record: not an index's layout, so look for the next record right after its start
                nxt = self._resync(pos + 1)
                rep.damage.append(Damage("unreadable", pos, nxt - pos, f"a message index record with a damaged "
                                                                        f"length ({length})", messages=0))
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
                after_chunk = True
                try:
                    inner = _chunk_records(rec)
                except _BadRecord as exc:
                    rep.damage.append(Damage("corrupt-chunk", pos, 9 + length, str(exc),
                                             rec.message_start_time, rec.message_end_time, self._indexed(end)))
                    pos = end
                    continue
                pos = end
                yield from inner
                continue
            if op == Opcode.DATA_END:
                rep.data_end = True
                self._read_summary(end, rep)
                return
            if op == Opcode.MESSAGE and after_chunk and self._index_shaped(pos + 9, length):
                # a message index (0x07) whose opcode bit flipped to a message (0x05): both start with a channel
                # id, and the index's layout makes it parse; a chunked file has no messages outside its chunks
                rep.damage.append(Damage("unreadable", pos, 9 + length, "a message index record with a damaged "
                                                                         "opcode", messages=0))
                pos = end
                continue
            if op in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.METADATA, Opcode.ATTACHMENT):
                yield rec
            pos = end

    def _index_shaped(self, body: int, length: int) -> bool:
        """The record body at ``body`` has a message index's layout (channel id, then an array of 16-byte
        entries filling the rest)."""
        if length < 6:
            return False
        (nbytes,) = struct.unpack_from("<I", self._buf, body + 2)
        return nbytes % 16 == 0 and 6 + nbytes == length

    def _indexed(self, pos: int) -> int | None:
        """Messages listed by the message index records that follow a chunk (from ``pos``, its end), None without
        any: how many a corrupt chunk held."""
        buf, n, count, seen = self._buf, self.size, 0, False
        while n - pos >= 15:
            op, length = _REC.unpack_from(buf, pos)
            if op != Opcode.MESSAGE_INDEX or pos + 9 + length > n or length < 6:
                break
            if not self._index_shaped(pos + 9, length):
                break
            count += (length - 6) // 16
            seen = True
            pos += 9 + length
        return count if seen else None

    def _read_summary(self, pos: int, rep: ScanReport) -> None:
        buf, n = self._buf, self.size
        while pos < n:
            if n - pos < 9:
                break
            op, length = _REC.unpack_from(buf, pos)
            end = pos + 9 + length
            if op not in _SUMMARY_OPCODES or end > n:
                rep.damage.append(Damage("summary", pos, n - pos, "summary section damaged", messages=0))
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
                    rep.damage.append(Damage("summary", pos, n - pos, "closing magic missing after the footer",
                                             messages=0))
                return
        rep.damage.append(Damage("summary", pos, n - pos, "summary section cut off", messages=0))

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
                    if rec.name == RECOVERY_METADATA_NAME and rep.expected_messages is None:
                        try:
                            rep.expected_messages = int(rec.metadata.get("recovered_messages", ""))
                        except ValueError:
                            pass
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


#: bag-recover closes a chunk after this much log time (or DEFAULT_CHUNK_SIZE): damage to one loses only it
RECOVER_CHUNK_SECONDS = 0.1


def recover(src: str | os.PathLike, dst: str | os.PathLike, *, overwrite: bool = False,
            chunk_seconds: float = RECOVER_CHUNK_SECONDS) -> ScanReport:
    """Rewrite every readable schema, channel, message, metadata and attachment of ``src`` (e.g. a file cut
    short by a SIGKILL) into a new, valid, indexed MCAP file ``dst``. Returns the scan report of ``src``.

    ``dst`` is written as the recorder writes: chunks of at most ``chunk_seconds`` of log time (and
    DEFAULT_CHUNK_SIZE), each with a CRC, and schemas and channels also outside chunks, so damage to one chunk of
    ``dst`` loses that chunk only. A ``flagbot_sim.recovery`` metadata record at its start says what was lost and
    how many messages ``dst`` holds (``recovered_messages``): a later scan of a damaged ``dst`` counts its loss
    exactly even when the summary is gone."""
    from mcap.data_stream import RecordBuilder
    dst = Path(dst)
    if dst.exists() and not overwrite:
        raise BagError(f"{dst} exists; choose another name or allow overwriting")
    if Path(src).resolve() == dst.resolve():
        raise BagError("recover needs a different output file")
    with BagReader(src) as r:
        rep = r.report
        if rep.messages == 0 and not rep.ok:       # as bag-summary: no empty "valid" file that looks like success
            raise BagError(f"nothing recoverable: {rep.describe_loss()}")
        earlier = r.metadata_named(RECOVERY_METADATA_NAME)
        with open(dst, "wb") as f:
            # as BagWriter: chunk indexes wait in a temporary file beside dst, not in memory (a long file)
            w = McapStreamWriter(f, chunk_size=DEFAULT_CHUNK_SIZE, compression="zstd", spill_dir=dst.parent)
            w.start(rep.profile or PROFILE, rep.library or LIBRARY)

            def outside(record) -> None:       # as BagWriter: a chunk decodes without the one that had these
                b = RecordBuilder()
                record.write(b)
                f.write(b.end())

            def metadata(name: str, data: dict) -> None:
                w.add_metadata(name, data)
                w.flush()           # the record is buffered until flushed: out before anything written outside

            info = {"source": str(src), "loss": rep.describe_loss() or "nothing lost",
                    "lost_bytes": str(rep.lost_bytes), "recovered_messages": str(rep.messages)}
            if earlier:
                info["earlier_loss"] = earlier.get("loss", "")
            metadata(RECOVERY_METADATA_NAME, info)
            schema_map: dict[int, int] = {}
            channel_map: dict[int, int] = {}
            span = None                 # log-time range of the chunk being filled
            scratch = ScanReport(str(src), r.size)
            for kind, rec in r._records(scratch):
                if kind == "schema" and rec.id not in schema_map:
                    schema_map[rec.id] = sid = w.register_schema(rec.name, rec.encoding, rec.data)
                    outside(Schema(id=sid, name=rec.name, encoding=rec.encoding, data=rec.data))
                elif kind == "channel" and rec.id not in channel_map:
                    sid = schema_map.get(rec.schema_id, 0)
                    channel_map[rec.id] = cid = w.register_channel(rec.topic, rec.message_encoding, sid,
                                                                   rec.metadata)
                    outside(Channel(id=cid, topic=rec.topic, message_encoding=rec.message_encoding, schema_id=sid,
                                    metadata=rec.metadata))
                elif kind == "message" and rec.channel_id in channel_map:
                    t = rec.log_time_ns
                    if span is None or max(span[1], t) - min(span[0], t) >= chunk_seconds * 1e9:
                        w.flush()           # closes the chunk being filled (none at first)
                        span = (t, t)
                    span = (min(span[0], t), max(span[1], t))
                    w.add_message(channel_map[rec.channel_id], rec.log_time_ns, rec.data, rec.publish_time_ns,
                                  rec.sequence)
                elif kind == "metadata" and rec.name != RECOVERY_METADATA_NAME:   # the earlier one: in ours
                    metadata(rec.name, rec.metadata)
                elif kind == "attachment":
                    w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data)
                    w.flush()
            w.finish()
    return rep
