"""A long synthetic recording through BagWriter, and the memory it takes (tests/test_bag_writer_memory.py and
benchmarks/bag_writer_memory.py).

The messages are a committed sample's (bags/design1_n3_steps.mcap: sim_node, beam_node and cmd_profile, 17
topics, ~615 messages and ~100 KB per second of recording), replayed in a loop with their log times shifted, so
the topics, sizes and rates are a real recorder's. The writer's clock follows the log time, so a chunk is closed
every flush interval (0.1 s) as in a real-time recording. ``thin=True`` writes one message of each topic per 0.1 s
instead (170 per second, every topic in every chunk): the same chunks and chunk indexes for a quarter of the work.

``legacy_writer()`` puts mcap's own ``mcap.writer.Writer`` back behind BagWriter, configured as BagWriter
configured it before (zstd chunks with CRCs, every index, statistics and summary offsets): the writer that kept
every chunk index in memory until ``finish()``, for side-by-side figures and for showing the bound can fail.
"""
from __future__ import annotations

import contextlib
import gc
import tracemalloc
from dataclasses import dataclass, field
from pathlib import Path

SAMPLE = Path(__file__).resolve().parents[1] / "bags" / "design1_n3_steps.mcap"
FLUSH_NS = 100_000_000
T0_NS = 1_000_000_000_000


@dataclass
class Sample:
    topics: dict[str, str]                                # topic -> type
    messages: list[tuple[str, bytes, int]]                # (topic, CDR bytes, log time - first log time) in order
    span_ns: int                                          # replay period (the sample's length plus one flush)


def load_sample(path: Path = SAMPLE) -> Sample:
    from flagbot_sim.bag import BagReader
    with BagReader(path) as r:
        topics = {t: info.type_name for t, info in r.topics.items() if info.count}
        msgs = [(m.topic, bytes(m.data), m.log_time_ns) for m in r.messages()]
    t0 = msgs[0][2]
    msgs = [(t, d, lt - t0) for t, d, lt in msgs]
    return Sample(topics, msgs, msgs[-1][2] + FLUSH_NS)


def thinned(sample: Sample) -> Sample:
    """One message of each topic per flush interval (the k-th of that topic in the k-th interval, cycling)."""
    per_topic: dict[str, list[bytes]] = {}
    for t, d, _ in sample.messages:
        per_topic.setdefault(t, []).append(d)
    n = max(len(v) for v in per_topic.values())
    msgs = [(t, v[k % len(v)], k * FLUSH_NS + 1000 * i)
            for k in range(n) for i, (t, v) in enumerate(sorted(per_topic.items()))]
    return Sample(sample.topics, msgs, n * FLUSH_NS)


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


@dataclass
class Recording:
    """A BagWriter fed the sample in a loop; :meth:`run_until` writes up to a log time."""
    writer: object
    sample: Sample
    clock: FakeClock
    now_ns: int = 0                   # log time (since the start) of the next message to write
    written: int = 0
    expected: dict[str, list[tuple[int, bytes]]] | None = field(default=None)   # topic -> (log ns, bytes), if kept

    @classmethod
    def open(cls, path, sample: Sample, *, keep: bool = False, **kw) -> "Recording":
        from flagbot_sim.bag import BagWriter
        clock = FakeClock()
        w = BagWriter(path, clock=clock, overwrite=True, **kw)
        for topic, type_name in sample.topics.items():
            w.add_topic(topic, type_name)
        return cls(w, sample, clock, expected={} if keep else None)

    def run_until(self, end_ns: int) -> None:
        msgs, span, w, exp = self.sample.messages, self.sample.span_ns, self.writer, self.expected
        n = len(msgs)
        while self.now_ns < end_ns:
            lap, i = divmod(self.written, n)
            topic, data, rel = msgs[i]
            t = lap * span + rel
            if t >= end_ns:
                self.now_ns = end_ns
                break
            self.clock.t = t * 1e-9
            assert w.write(topic, data, T0_NS + t), w.error
            if exp is not None:
                exp.setdefault(topic, []).append((T0_NS + t, data))
            self.written += 1
            self.now_ns = t


@contextlib.contextmanager
def legacy_writer():
    """BagWriter with mcap's ``Writer`` inside, as before McapStreamWriter (same arguments, same file)."""
    from mcap.data_stream import RecordBuilder
    from mcap.writer import CompressionType, Writer

    from flagbot_sim.bag import writer as bag_writer

    class McapWriter(Writer):
        def __init__(self, stream, *, chunk_size, compression, spill_dir=None):
            comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "": CompressionType.NONE}[compression]
            super().__init__(stream, chunk_size=chunk_size, compression=comp, enable_crcs=True)
            self._stream = stream

        def write_record(self, record):         # BagWriter wrote these to its file directly
            b = RecordBuilder()
            record.write(b)
            self._stream.write(b.end())

        def close(self):
            pass

    saved = bag_writer.McapStreamWriter
    bag_writer.McapStreamWriter = McapWriter
    try:
        yield
    finally:
        bag_writer.McapStreamWriter = saved


def traced_now() -> int:
    gc.collect()
    return tracemalloc.get_traced_memory()[0]


def traced_growth(path, sample: Sample, first_s: float, last_s: float) -> tuple[int, int]:
    """Python memory (tracemalloc, bytes) held after ``first_s`` and after ``last_s`` seconds of recording, the
    writer open throughout (tracemalloc is started here, after the sample is loaded)."""
    tracemalloc.start()
    try:
        rec = Recording.open(path, sample)
        rec.run_until(int(first_s * 1e9))
        a = traced_now()
        rec.run_until(int(last_s * 1e9))
        b = traced_now()
        rec.writer.close()
        return a, b
    finally:
        tracemalloc.stop()
