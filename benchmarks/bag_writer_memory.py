#!/usr/bin/env python3
"""A recorder's memory over a long recording, printed: BagWriter as it is (McapStreamWriter) and with mcap's own
Writer put back (as before), side by side in one run.

    .venv/bin/python benchmarks/bag_writer_memory.py [--minutes 60] [--every 10] [--trace]

Each writer records ``--minutes`` of recorded time in a process of its own (so the resident sets do not mix): the
committed sample bags/design1_n3_steps.mcap (sim_node + beam_node + cmd_profile, 17 topics, ~615 messages/s,
~100 KB/s) replayed in a loop, the writer's clock following the log time, so a chunk is closed every 0.1 s as in
a real-time recording (tests/bag_memory.py). Printed every ``--every`` recorded minutes: the resident set
(/proc/self/status VmRSS) and, with ``--trace``, the Python memory tracemalloc counts (slower); at the end the
growth per recorded hour, fitted from the second sample on, and the CPU time per recorded minute.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def child(legacy: bool, minutes: float, every: float, trace: bool) -> None:
    import contextlib
    import tracemalloc

    import bag_memory as bm
    sample = bm.load_sample()
    if trace:
        tracemalloc.start()
    rows = []
    with tempfile.TemporaryDirectory() as d, (bm.legacy_writer() if legacy else contextlib.nullcontext()):
        cpu0 = time.process_time()
        rec = bm.Recording.open(Path(d) / "long.mcap", sample)
        t = 0.0
        while t < minutes - 1e-9:
            t = min(minutes, t + every)
            rec.run_until(int(t * 60e9))
            rows.append((t, rss_mb(), bm.traced_now() / 2**20 if trace else None))
        cpu = time.process_time() - cpu0
        s = rec.writer.close()
        size = s.size_bytes
    print(json.dumps({"rows": rows, "cpu_s": cpu, "messages": s.messages, "size": size}))


def slope_per_hour(rows, k: int) -> float:
    """Least-squares slope of column ``k`` (1 RSS, 2 traced; MB) against recorded time, per hour, from the
    second sample on (the first holds the start-up: imports, buffers reaching their size)."""
    pts = [(row[0], row[k]) for row in rows[1:] if row[k] is not None]
    if len(pts) < 2:
        return float("nan")
    n = len(pts)
    mt = sum(t for t, _ in pts) / n
    my = sum(y for _, y in pts) / n
    return 60 * sum((t - mt) * (y - my) for t, y in pts) / sum((t - mt) ** 2 for t, _ in pts)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--minutes", type=float, default=60.0, help="recorded minutes per writer (default 60)")
    p.add_argument("--every", type=float, default=10.0, help="sample every this many recorded minutes")
    p.add_argument("--trace", action="store_true", help="also count Python memory with tracemalloc (slower)")
    p.add_argument("--child", choices=["stream", "legacy"], help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.child:
        child(a.child == "legacy", a.minutes, a.every, a.trace)
        return 0
    with open("/proc/loadavg") as f:
        print(f"host: {os.cpu_count()} cores, load {f.read().split()[0]} at start; {a.minutes:g} recorded minutes "
              f"per writer, {'with' if a.trace else 'without'} tracemalloc")
    for name in ("stream", "legacy"):
        out = subprocess.run([sys.executable, __file__, "--child", name, "--minutes", str(a.minutes), "--every",
                              str(a.every)] + (["--trace"] if a.trace else []), capture_output=True, text=True,
                             check=True).stdout
        r = json.loads(out.strip().splitlines()[-1])
        label = ("BagWriter (McapStreamWriter: chunk indexes in a temporary file)" if name == "stream"
                 else "BagWriter with mcap's Writer (before: every chunk index in memory)")
        print(f"{label}: {r['messages']} messages, {r['size'] / 1e6:.0f} MB file, "
              f"CPU {r['cpu_s'] / a.minutes:.2f} s per recorded minute")
        for t, rss, traced in r["rows"]:
            print(f"  {t:6.1f} min: RSS {rss:7.1f} MB" + (f", traced {traced:7.2f} MB" if traced is not None else ""))
        print(f"  growth: RSS {slope_per_hour(r['rows'], 1):+.1f} MB per recorded hour"
              + (f", traced {slope_per_hour(r['rows'], 2):+.2f} MB per recorded hour" if a.trace else ""))
    with open("/proc/loadavg") as f:
        print(f"load {f.read().split()[0]} at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
