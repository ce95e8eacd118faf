#!/usr/bin/env python3
"""What clients cost the live view, printed: its memory as many clients connect and leave, with and without
returning freed memory to the system, and the delay the subprotocol bridge adds to each message.

    .venv/bin/python benchmarks/live_view_clients.py [--clients 600] [--wave 50] [--latency 300]

Memory: a live view in a process of its own (tests/view_server_proc.py: design 2, n = 3, published at 30 Hz)
serves ``--clients`` clients in waves of ``--wave`` at once (view_server_proc.churn: each connects, alternately
offering ``foxglove.websocket.v1`` and ``foxglove.sdk.v1``, subscribes to every channel, receives 3 messages and
leaves; every 4th drops its TCP connection without a closing handshake). Printed after each 200: the resident set, the
bytes malloc holds free in its arenas (glibc mallinfo2 ``fordblks``) and how often the view returned them; once
with ``release_memory`` off (the SDK alone: freed client buffers stay in malloc's arenas), once on.

Latency: one view in this process publishes ``--latency`` times (every 20 ms) to two clients in one other process,
one through the bridge and one on the SDK's own port; each message's arrival (CLOCK_MONOTONIC, which both processes
share) minus its publication, per path, side by side.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from view_server_proc import ServerProcess, churn  # noqa: E402  (the view in a process of its own)

MB = 1e6


def print_memory(label: str, rows) -> None:
    (_, (rss0, free0, _, _)) = rows[0]
    print(f"{label}: baseline RSS {rss0 / MB:.1f} MB, malloc free {free0 / MB:.1f} MB")
    for done, (rss, free, trims, _) in rows[1:]:
        print(f"  after {done:4d} clients: RSS {rss / MB:7.1f} MB ({(rss - rss0) / MB:+6.1f}), malloc free "
              f"{free / MB:6.1f} MB ({(free - free0) / MB:+6.1f}), memory returned {trims} times")


LATENCY_CLIENT = r"""
import asyncio, json, sys, time
sys.path.insert(0, sys.argv[1])
from foxglove_client import Client
async def main(urls, last):
    cs = [await Client.connect(u) for u in urls]
    for c in cs:
        await c.subscribe({"/flagbot/state"})
    print("subscribed", flush=True)
    async def take(c):
        out = {}
        while last not in out:
            _, lt, _ = await c.receive(timeout=60)
            out[lt] = time.monotonic_ns()
        return out
    got = await asyncio.gather(*(take(c) for c in cs))
    for c in cs:
        await c.close()
    print(json.dumps(got), flush=True)
asyncio.run(main(sys.argv[2:4], int(sys.argv[4])))
"""


def latency(n: int) -> dict:
    """Per publication (log time): arrival minus publication in us, {"bridge": {...}, "direct": {...}}."""
    from flagbot_sim.physics import Simulation
    from flagbot_sim.scene import load_scene
    from flagbot_sim.view.geometry import RobotGeometry
    from flagbot_sim.view.live import LiveView
    sim = Simulation(load_scene("design2", ["robot.n_flagella=3"]))
    sim.step()
    geom = RobotGeometry.from_simulation(sim, None)
    with LiveView(port=0) as view:
        direct = f"ws://127.0.0.1:{view.bridge.backend_port}"
        p = subprocess.Popen([sys.executable, "-c", LATENCY_CLIENT, str(ROOT / "tests"), view.url, direct,
                              str(n * 1_000_000)], stdout=subprocess.PIPE, text=True)
        assert p.stdout.readline().strip() == "subscribed"
        time.sleep(1.0)                      # both subscriptions reach the server
        sent = {}
        for k in range(1, n + 1):
            g = dataclasses.replace(geom, t=k * 1e-3)
            sent[k * 1_000_000] = time.monotonic_ns()
            view.publish(g, force=True)
            time.sleep(0.02)
        got = json.loads(p.stdout.readline())
        p.wait(timeout=30)
    return {name: {int(lt): (arrived - sent[int(lt)]) / 1e3 for lt, arrived in rows.items()}
            for name, rows in zip(("bridge", "direct"), got)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--clients", type=int, default=600)
    ap.add_argument("--wave", type=int, default=90)
    ap.add_argument("--latency", type=int, default=300)
    a = ap.parse_args()
    print(f"host: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at start")
    for release in (False, True):
        s = ServerProcess(release=release)
        try:
            rows = churn(s, a.clients, a.wave)
        finally:
            s.close()
        print_memory(f"release_memory={release}", rows)
    if a.latency:
        lat = latency(a.latency)
        for name, us in lat.items():
            v = sorted(us.values())
            q = statistics.quantiles(v, n=100)
            print(f"latency {name:6s}: median {statistics.median(v):7.0f} us, p90 {q[89]:7.0f} us, "
                  f"p99 {q[98]:7.0f} us ({len(v)} messages)")
        both = sorted(set(lat["bridge"]) & set(lat["direct"]))
        print(f"  bridge - direct, median of the per-message differences over {len(both)} messages: "
              f"{statistics.median(lat['bridge'][t] - lat['direct'][t] for t in both):.0f} us")
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
