"""A long recording's memory is bounded: BagWriter's chunk indexes wait in a temporary file, not in memory.

The issue: sim_node / `flagbot record` grew ~0.64 MB per recorded minute. mcap's ``Writer`` keeps a ``ChunkIndex``
(with a dict of message-index offsets, one entry per channel in the chunk) for every chunk until ``finish()``;
with a chunk closed every 0.1 s that is ~1.4 KB per chunk, ~50 MB per recorded hour of a sim_node recording
(tracemalloc: the dicts of ChunkIndex.message_index_offsets, their int values, the ChunkIndex objects and their
times; nothing else grows). BagWriter now writes through ``McapStreamWriter``, which serializes each chunk index
into an unnamed temporary file beside the recording and copies it into the summary at close.

The recordings here replay a committed sample's messages (tests/bag_memory.py), with a flush, so a chunk,
every 0.1 s of log time. The same measurement with mcap's writer put back (``legacy_writer``) must exceed the bound
many times over: the test can fail, and does on the old code.
"""
import errno
import io
import os
import struct
import warnings
import zlib
from collections import Counter
from pathlib import Path

import pytest
from bag_memory import Recording, legacy_writer, load_sample, traced_growth
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Footer, SummaryOffset
from mcap.stream_reader import StreamReader

from flagbot_sim.bag import BagReader, BagWriteError, BagWriter, RunMetadata, recover, scan
from flagbot_sim.bag.writer import McapStreamWriter

#: Python memory (tracemalloc) a recording may gain between 30 s and 120 s of recording (900 chunks):
#: measured -11 kB with McapStreamWriter, +1230 kB with mcap's Writer (2-core VM, load 7)
BOUND = 128 * 1024


@pytest.fixture(scope="module")
def sample():
    return load_sample()


def test_memory_does_not_grow_with_the_number_of_chunks(tmp_path, sample):
    a, b = traced_growth(tmp_path / "long.mcap", sample, 30.0, 120.0)
    assert b - a < BOUND, (f"BagWriter's memory grew {(b - a) / 1e3:.0f} kB between 300 and 1200 chunks "
                           f"(bound {BOUND / 1e3:.0f} kB)")


def test_the_bound_fails_for_mcaps_writer_that_keeps_every_chunk_index(tmp_path, sample):
    """The control: the writer BagWriter used before, same recording, same measurement."""
    with legacy_writer():
        a, b = traced_growth(tmp_path / "legacy.mcap", sample, 30.0, 120.0)
    assert b - a > 5 * BOUND, f"mcap's writer grew only {(b - a) / 1e3:.0f} kB: the test no longer measures the issue"


def _records(path):
    with open(path, "rb") as f:
        return list(StreamReader(f, skip_magic=False, emit_chunks=True).records)


def _chunk_offsets(path) -> list[int]:
    """File offsets of every chunk record, walking the file record by record."""
    data = Path(path).read_bytes()
    pos, out = 8, []
    while pos < len(data) - 8:
        op, length = struct.unpack_from("<BQ", data, pos)
        if op == Opcode.CHUNK:
            out.append(pos)
        if op == Opcode.FOOTER:
            break
        pos += 9 + length
    return out


def test_a_long_recording_reads_back_exactly_with_its_summary(tmp_path, sample):
    """mcap's reader (summary, chunk indexes, indexed reading), the footer's summary CRC and summary offsets, a
    full record-by-record pass, rosbags, and BagReader: every message back with its log time and bytes."""
    path = tmp_path / "long.mcap"
    rec = Recording.open(path, sample, keep=True, metadata=RunMetadata(scene_toml="[robot]\n"))
    rec.run_until(60_000_000_000)                            # a minute: 600 chunks, ~37 000 messages
    summary = rec.writer.close()
    expected = rec.expected
    n = sum(len(v) for v in expected.values())
    assert summary.closed and not summary.error and summary.messages == n
    chunks = _chunk_offsets(path)
    assert len(chunks) >= 550

    with open(path, "rb") as f:
        r = make_reader(f, validate_crcs=True)
        s = r.get_summary()
        topic_of = {cid: ch.topic for cid, ch in s.channels.items()}
        assert [ci.chunk_start_offset for ci in s.chunk_indexes] == chunks
        assert s.statistics.chunk_count == len(chunks) and s.statistics.message_count == n
        assert {topic_of[c]: k for c, k in s.statistics.channel_message_counts.items()} == \
            {t: len(v) for t, v in expected.items()}
        assert s.statistics.message_start_time == min(v[0][0] for v in expected.values())
        assert s.statistics.message_end_time == max(v[-1][0] for v in expected.values())
        assert s.statistics.channel_count == len(sample.topics) == len(s.channels)
        assert [m.name for m in s.metadata_indexes] == ["rosbag2", "flagbot_sim"]
        got = {}
        for _, ch, msg in r.iter_messages(log_time_order=False):     # through the chunk and message indexes
            got.setdefault(ch.topic, []).append((msg.log_time, bytes(msg.data)))
        assert got == expected
        # a time window read through the indexes alone: exactly the messages in it
        window = {t: [m for m in v if 20e9 <= m[0] - 10**12 < 21e9] for t, v in expected.items()}
        got = {}
        with warnings.catch_warnings():              # start_time/end_time: the names mcap 1.1 to 1.6 all take
            warnings.simplefilter("ignore", DeprecationWarning)
            for _, ch, msg in r.iter_messages(start_time=10**12 + 20 * 10**9, end_time=10**12 + 21 * 10**9):
                got.setdefault(ch.topic, []).append((msg.log_time, bytes(msg.data)))
        assert got == {t: v for t, v in window.items() if v}

    # footer: summary CRC over the summary section and the footer's first fields; each summary offset points at a
    # group of records of its opcode
    data = path.read_bytes()
    assert data.endswith(b"\x89MCAP0\r\n")
    foot = Footer.read(ReadDataStream(io.BytesIO(data[-8 - 20:-8])))
    assert data[-8 - 29] == Opcode.FOOTER
    crc = zlib.crc32(data[foot.summary_start:-8 - 29])
    crc = zlib.crc32(data[-8 - 29:-8 - 4], crc)
    assert foot.summary_crc == crc
    offsets = [rec for rec in _records(path) if isinstance(rec, SummaryOffset)]
    assert {o.group_opcode for o in offsets} >= {Opcode.SCHEMA, Opcode.CHANNEL, Opcode.STATISTICS,
                                                  Opcode.CHUNK_INDEX, Opcode.METADATA_INDEX}
    assert offsets[0].group_start == foot.summary_start
    for o in offsets:
        pos = o.group_start
        while pos < o.group_start + o.group_length:
            op, length = struct.unpack_from("<BQ", data, pos)
            assert op == o.group_opcode
            pos += 9 + length
        assert pos == o.group_start + o.group_length
    assert foot.summary_offset_start == offsets[-1].group_start + offsets[-1].group_length == \
        min(o.group_start for o in offsets) + sum(o.group_length for o in offsets)

    from rosbags.highlevel import AnyReader
    got = {}
    with AnyReader([path]) as ar:
        assert ar.message_count == n
        for conn, t, raw in ar.messages():
            got.setdefault(conn.topic, []).append((t, bytes(raw)))
    assert got == expected
    with BagReader(path) as br:
        assert br.report.ok and br.report.closed and br.report.messages == n
        assert {t: i.count for t, i in br.topics.items() if i.count} == {t: len(v) for t, v in expected.items()}


def test_same_file_as_mcaps_writer(tmp_path, sample):
    """Byte for byte what BagWriter wrote with mcap's Writer, for the same recording (zstd and uncompressed)."""
    for comp in ("zstd", "none"):
        files = []
        for legacy in (False, True):
            buf = io.BytesIO()
            with legacy_writer() if legacy else _nothing():
                rec = Recording.open(buf, sample, compression=comp, metadata=RunMetadata(scene_toml="[robot]\n",
                                                                                         created_utc="x",
                                                                                         command_line="x"))
                rec.run_until(5_000_000_000)
                rec.writer.add_metadata("late", {"k": "v"})
                rec.run_until(6_000_000_000)
                rec.writer.close()
            files.append(buf.getvalue())
        assert files[0] == files[1], comp


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def _open_fds() -> set[str]:
    return {os.readlink(f"/proc/self/fd/{fd}") for fd in os.listdir("/proc/self/fd")
            if os.path.exists(f"/proc/self/fd/{fd}")}


def test_chunk_indexes_wait_in_an_unnamed_file_beside_the_recording_that_close_releases(tmp_path, sample):
    before = _open_fds()
    rec = Recording.open(tmp_path / "run.mcap", sample)
    rec.run_until(2_000_000_000)
    new = _open_fds() - before
    assert len(new) == 2, new                                     # the recording and its chunk index file
    spill = new - {str(tmp_path / "run.mcap")}
    assert len(spill) == 1 and all(f.startswith(str(tmp_path) + "/") and f.endswith(" (deleted)") for f in spill), \
        new                                 # beside the recording, nameless (O_TMPFILE, or created and unlinked)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]
    rec.writer.close()
    assert _open_fds() - before == set()


class FullDisk(io.RawIOBase):
    """A file on a disk that fills up after ``room`` bytes (ENOSPC for the write that does not fit)."""

    def __init__(self, room):
        self.buf = bytearray()
        self.room = room

    def writable(self):
        return True

    def write(self, b):
        if len(self.buf) + len(b) > self.room:
            raise OSError(errno.ENOSPC, "No space left on device")
        self.buf += b
        return len(b)

    def tell(self):
        return len(self.buf)


def test_close_after_a_write_error_or_an_abandoned_start_is_as_before(tmp_path, sample):
    """A full disk mid-recording: the error is kept, close() reports the file not closed, writes nothing more,
    releases the temporary file, and what was flushed is recoverable. A target that cannot take its header: a
    BagWriteError, no file left behind, nothing left open. A recording killed before close (its bytes as they are
    on disk then) scans and recovers as before."""
    before = _open_fds()
    disk = FullDisk(400_000)
    rec = Recording.open(disk, sample)
    with pytest.raises(AssertionError, match="No space left on device"):
        rec.run_until(30_000_000_000)
    w = rec.writer
    size = len(disk.buf)
    summary = w.close()
    assert not summary.closed and "No space left on device (ENOSPC)" in summary.error
    assert len(disk.buf) == size and w.write(next(iter(sample.topics)), b"\0\1\0\0", 1) is False
    assert _open_fds() - before == set()
    damaged = tmp_path / "full.mcap"
    damaged.write_bytes(bytes(disk.buf))
    rep = recover(damaged, tmp_path / "fixed.mcap")
    assert not rep.closed and 0 < rep.messages <= w.message_count
    assert w.message_count - rep.messages < 2 * 615 * 0.1 + 50          # at most the chunk being filled lost
    assert scan(tmp_path / "fixed.mcap").ok

    with pytest.raises(BagWriteError, match="No space left on device"):
        BagWriter(FullDisk(40))
    with pytest.raises(BagWriteError, match="No space left on device"):
        BagWriter(FullDisk(300), metadata=RunMetadata(scene_toml="[robot]\n" + "# pad\n" * 100))
    assert _open_fds() - before == set()

    path = tmp_path / "killed.mcap"
    rec = Recording.open(path, sample, keep=True)
    rec.run_until(10_000_000_000)
    killed = tmp_path / "killed_copy.mcap"
    killed.write_bytes(path.read_bytes())           # what a SIGKILL now would leave
    rec.writer.close()
    with BagReader(killed) as r:
        assert not r.report.closed
        got = [(m.log_time_ns, bytes(m.data)) for m in r.messages()]
    everything = Counter((t, d) for v in rec.expected.values() for t, d in v)
    missing = everything - Counter(got)
    assert Counter(got) <= everything and 0 < missing.total() < 200
    assert max(t for t, _ in got) <= min(t for t, _ in missing)        # lost: the end only


def test_stream_writer_refuses_an_unknown_compression():
    from flagbot_sim.bag import BagError
    with pytest.raises(BagError, match="unknown compression"):
        McapStreamWriter(io.BytesIO(), compression="brotli")
