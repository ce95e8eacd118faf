"""A live view in a process of its own, for measuring what clients cost it (tests/test_view_memory.py,
benchmarks/live_view_clients.py): its memory is then the server's alone, not the clients'.

As a script (``python tests/view_server_proc.py [--no-release]``) it serves design 2 (n = 3) on a free port of
127.0.0.1 and publishes it at 30 Hz from a thread, as ``flagbot run --view`` does; prints ``ready PORT``, then
answers each line on stdin: ``mem`` -> ``mem RSS_BYTES FREE_BYTES TRIMS CONNECTIONS`` (resident set; bytes malloc
holds free in its arenas, glibc's mallinfo2; times the view returned free memory; clients relayed now),
``quit`` -> exits. :class:`ServerProcess` runs it; :func:`churn` sends it clients that come and go.
"""
from __future__ import annotations

import asyncio
import ctypes
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


class _MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]


def rss_bytes() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS in /proc/self/status")


def malloc_free_bytes() -> int:
    """Bytes glibc's malloc holds free in all its arenas (``fordblks``); -1 where mallinfo2 is missing."""
    try:
        f = ctypes.CDLL(None).mallinfo2
    except AttributeError:
        return -1
    f.restype = _MallInfo2
    return int(f().fordblks)


class ServerProcess:
    """This file run as a child; :meth:`mem` asks it for (rss, malloc free, trims, connections)."""

    def __init__(self, release: bool = True):
        args = [sys.executable, __file__] + ([] if release else ["--no-release"])
        self.proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT)
        line = self.proc.stdout.readline().split()
        if not line or line[0] != "ready":
            self.proc.kill()
            raise RuntimeError(f"the view process did not start: {line}")
        self.url = f"ws://127.0.0.1:{int(line[1])}"

    def mem(self) -> tuple[int, int, int, int]:
        self.proc.stdin.write("mem\n")
        self.proc.stdin.flush()
        _, rss, free, trims, conns = self.proc.stdout.readline().split()
        return int(rss), int(free), int(trims), int(conns)

    def idle(self, timeout: float = 30.0) -> None:
        """Wait until no client is relayed any more (the view sees a departure a little after the client)."""
        end = time.monotonic() + timeout
        while self.mem()[3] and time.monotonic() < end:
            time.sleep(0.05)

    def settled(self) -> tuple[int, int, int, int]:
        """mem() once every client is gone and the view has had time to return memory (bridge.TRIM_DELAY)."""
        self.idle()
        time.sleep(1.5)
        return self.mem()

    def close(self) -> None:
        try:
            self.proc.stdin.write("quit\n")
            self.proc.stdin.flush()
            self.proc.wait(timeout=10)
        except Exception:  # noqa: BLE001 - a child that will not stop is killed
            self.proc.kill()
            self.proc.wait()

    def __enter__(self) -> "ServerProcess":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


async def _one_client(url: str, k: int) -> None:
    from foxglove_client import Client
    legacy = k % 2 == 0
    c = await Client.connect(url, timeout=30, subprotocol="foxglove.websocket.v1" if legacy else "foxglove.sdk.v1")
    await c.subscribe()
    for _ in range(3):
        await c.receive(timeout=30)
    if k % 4 == 3:
        c.ws.transport.abort()        # gone without a closing handshake (a killed browser tab)
    else:
        await c.close()


def churn(server: ServerProcess, n: int, wave: int, report_every: int = 200) -> list:
    """``n`` clients in waves of ``wave`` at once: each connects (alternately offering ``foxglove.websocket.v1``
    and ``foxglove.sdk.v1``), subscribes to every channel, receives 3 messages and leaves (every 4th drops its
    TCP connection without a closing handshake). [(clients so far, server.settled())], the baseline first."""
    async def waves(first: int, count: int) -> None:
        for start in range(first, first + count, wave):
            await asyncio.gather(*(_one_client(server.url, k) for k in range(start, min(start + wave, first + count))))
            server.idle()             # the next wave finds the previous one gone (the view serves 100 at most)
    asyncio.run(waves(0, 5))          # warm: the first connections allocate once-only state too
    rows = [(0, server.settled())]
    done = 0
    while done < n:
        k = min(report_every, n - done)
        asyncio.run(waves(done, k))
        done += k
        rows.append((done, server.settled()))
    return rows


def main() -> None:
    sys.path.insert(0, str(ROOT))
    from flagbot_sim.physics import Simulation
    from flagbot_sim.scene import load_scene
    from flagbot_sim.view.live import LiveView
    sim = Simulation(load_scene("design2", ["robot.n_flagella=3"]))
    for _ in range(3):
        sim.step()
    view = LiveView(port=0, release_memory="--no-release" not in sys.argv, log=lambda line: None)
    stop = threading.Event()

    def publish():
        while not stop.is_set():
            view.update(sim, force=True)
            time.sleep(1 / 30)
    t = threading.Thread(target=publish, daemon=True)
    t.start()
    print("ready", view.port, flush=True)
    for line in sys.stdin:
        if line.strip() == "mem":
            print("mem", rss_bytes(), malloc_free_bytes(), view.bridge.trims, view.bridge.connections, flush=True)
        elif line.strip() == "quit":
            break
    stop.set()
    t.join()
    view.close(linger=0)


if __name__ == "__main__":
    main()
