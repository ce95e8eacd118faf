#!/usr/bin/env python3
"""What :meth:`flagbot_sim.view.live.LiveView.update` costs per call, printed: without a client, when rate-limited,
and per publication to one subscribed WebSocket client on 127.0.0.1 (n = 2 and n = 3, design 2).

    .venv/bin/python benchmarks/live_view_cost.py
"""
import asyncio
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from foxglove_client import Client  # noqa: E402  (the tests' client: websockets + protobuf)

from flagbot_sim.physics import Simulation  # noqa: E402
from flagbot_sim.scene import load_scene  # noqa: E402
from flagbot_sim.view.live import LiveView  # noqa: E402


def per_call(fn, n: int) -> float:
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t0) / n


async def measure(n_flagella: int) -> None:
    sim = Simulation(load_scene("design2", [f"robot.n_flagella={n_flagella}"]))
    for _ in range(5):
        sim.step()
    with LiveView(port=0, max_rate=30.0) as view:
        unwatched = per_call(lambda: view.update(sim, force=True), 20000)     # force: past the rate limit
        c = await Client.connect(view.url)
        await c.subscribe()
        while not view.has_clients():
            await asyncio.sleep(0.01)
        view.update(sim, force=True)
        limited = per_call(lambda: view.update(sim), 20000)
        publish = per_call(lambda: view.update(sim, force=True), 300)
        await c.close()
    print(f"n = {n_flagella}: update() without a client {1e6 * unwatched:.2f} us; with one: a call inside the rate "
          f"limit {1e6 * limited:.2f} us, a publication {1e3 * publish:.3f} ms")


if __name__ == "__main__":
    for n in (2, 3):
        asyncio.run(measure(n))
