"""How much recorded time a ``kill -9`` of a recording process loses: the measurement behind docs/recording.md.

Used by tests/test_crash_loss.py (one kill at the worst moment per recorder) and, run as a script, the benchmark
that prints the distribution over many kills:

    python tests/crash_loss.py --runs 10                 # both recorders, worst and random moments
    python tests/crash_loss.py --runs 5 --kind sim_node --moment worst

One measurement:

1. start the recording process: the standalone ``record`` (``python -m flagbot_sim.ros.recorder``) with a 200 Hz
   Float64 stream whose every publish is logged with its wall time, or ``sim_node`` with ``record:=`` at
   real-time factor 1, with a separate process logging every /clock it receives (what was published);
2. watch the file's size (it changes only when the writer flushes: the OS file buffer is flushed with the
   chunk) and learn the flush period;
3. kill the process with SIGKILL either just before the next flush is due (the worst moment: a flush has just
   landed, wait one flush period less 10 ms, and start again if a flush lands meanwhile) or at a random moment;
4. keep publishing for 0.3 s, recover the file with ``flagbot bag-recover`` (the command users run), read it back
   and compare with what was published.

Loss (s): for ``record``, kill time minus the publish time of the last recovered message; for ``sim_node``, the
largest simulation time published on /clock (as the listener saw it) minus the last simulation time in the
recovered file, and at least kill time minus the receive time of the last recovered message (at real-time
factor 1 both are recorded simulated time). Recovered messages must be contiguous: nothing in the middle lost.
"""
from __future__ import annotations

import contextlib
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
if __name__ == "__main__":          # as a script: DDS on this machine, a domain of its own
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("ROS_DOMAIN_ID", str(100 + random.randrange(100)))
    os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="flagbot_roslog_"))
    sys.path.insert(0, str(HERE))
    sys.path.insert(0, str(ROOT))

from bag_testlib import DISCOVERY_TIMEOUT, ChildProcess, start_helper, wait_for  # noqa: E402

STREAM_RATE = 200.0          # Hz: 5 ms between messages, so the loss is resolved to a few ms
MARGIN = 0.010               # s: the worst-moment kill comes this long before the next flush is due
BURST = 0.020                # s: size changes this close together are one flush (a big chunk takes several writes)


@dataclass
class Kill:
    kind: str                # record | sim_node
    moment: str              # worst | random
    loss: float              # s of recorded time lost
    since_flush: float       # s from the last flush that landed to the kill
    period: float            # s, the flush period seen in the file
    recovered: int           # messages in the recovered file
    detail: str
    path: str = ""           # the killed recording
    recovered_path: str = ""  # what bag-recover made of it
    values: list | None = None  # record: the Float64 data of every recovered message, in order

    def line(self) -> str:
        return (f"{self.kind:8s} {self.moment:6s} loss {1e3 * self.loss:6.1f} ms  (kill "
                f"{1e3 * self.since_flush:5.1f} ms after a flush, flush period {1e3 * self.period:5.1f} ms, "
                f"{self.recovered} messages recovered; {self.detail})")


def _size(path: str) -> int:
    try:
        return os.stat(path).st_size
    except FileNotFoundError:
        return -1


def _flush_times(path: str, n: int, timeout: float, proc: ChildProcess) -> list[float]:
    """Monotonic times of the next ``n`` flushes landing in ``path``: the first size change of each burst."""
    times, last = [], _size(path)
    end = time.monotonic() + timeout
    while len(times) < n:
        if time.monotonic() > end:
            raise AssertionError(f"{path}: only {len(times)} flushes in {timeout:.0f} s\n{proc.output()}")
        if not proc.alive():
            raise AssertionError(f"the recorder exited:\n{proc.output()}")
        s = _size(path)
        now = time.monotonic()
        if s != last and s > 0:
            if not times or now - times[-1] > BURST:
                times.append(now)
            last = s
        time.sleep(0.001)
    _settle(path)
    return times


def _settle(path: str) -> None:
    """Wait until the burst of writes of the flush that just began is over."""
    last, t_change = _size(path), time.monotonic()
    while time.monotonic() - t_change < BURST:
        s = _size(path)
        if s != last:
            last, t_change = s, time.monotonic()
        time.sleep(0.001)


def _kill_at(path: str, moment: str, period: float, proc: ChildProcess, rng: random.Random) -> tuple[int, float]:
    """SIGKILL ``proc`` at the chosen moment after a flush; returns (kill wall time ns, s since that flush)."""
    while True:
        (t_flush,) = _flush_times(path, 1, 10.0, proc)
        delay = period - MARGIN if moment == "worst" else rng.uniform(0.0, period)
        size = _size(path)
        while time.monotonic() < t_flush + delay and _size(path) == size:
            time.sleep(0.001)
        if _size(path) != size:          # the next flush came early: start again from it
            continue
        t_kill = time.time_ns()
        since = time.monotonic() - t_flush
        proc.proc.send_signal(signal.SIGKILL)
        proc.proc.wait(timeout=10)
        return t_kill, since


def _recover(path: str, out: str) -> None:
    r = subprocess.run([sys.executable, "-m", "flagbot_sim", "bag-recover", path, "-o", out], capture_output=True,
                       text=True, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=120)
    if r.returncode != 0:
        raise AssertionError(f"bag-recover failed ({r.returncode}):\n{r.stdout}\n{r.stderr}")


@contextlib.contextmanager
def _private_domain():
    """Children started inside get a ROS domain of their own (221-232: not one conftest.py hands out): the
    participant of a SIGKILLed process lingers in the graph until its lease runs out, and a dead sim_node must
    not answer for a live one in the next test."""
    before = os.environ["ROS_DOMAIN_ID"]
    os.environ["ROS_DOMAIN_ID"] = str(221 + os.getpid() % 12)
    try:
        yield
    finally:
        os.environ["ROS_DOMAIN_ID"] = before


def measure(kind: str, moment: str, tmp: str | Path, seed: int | None = None, warmup: float = 1.5) -> Kill:
    """One kill (see the module docstring); ``warmup`` s of recording before the flush period is learned."""
    with _private_domain():
        return _measure(kind, moment, tmp, seed, warmup)


def _measure(kind: str, moment: str, tmp: str | Path, seed: int | None, warmup: float) -> Kill:
    from flagbot_sim.bag import BagReader
    tmp = Path(tmp)
    out, fixed, log = str(tmp / f"{kind}.mcap"), str(tmp / f"{kind}.recovered.mcap"), str(tmp / f"{kind}.log")
    rng = random.Random(seed)
    if kind == "record":
        rec = ChildProcess("-m", "flagbot_sim.ros.recorder", "-o", out, "/t/omega_h")
        helper = start_helper("stream", "--topic", "/t/omega_h", "--rate", str(STREAM_RATE), "--log", log)
    elif kind == "sim_node":
        helper = start_helper("clocklog", "--topic", "/clock", "--log", log)
        wait_for(lambda: "clocklog ready" in helper.output(), DISCOVERY_TIMEOUT, "the /clock listener", helper)
        rec = ChildProcess("-m", "flagbot_sim.ros.sim_node", "--ros-args", "-p", f"record:={out}",
                           "-p", "real_time_factor:=1.0", "-p", "initial_omega:=5.0")
    else:
        raise ValueError(kind)
    try:
        # recording for real: the file has grown past its header, then learn the flush period
        _flush_times(out, 3, DISCOVERY_TIMEOUT + 30, rec)
        if kind == "sim_node":
            wait_for(lambda: os.path.getsize(log) > 0, DISCOVERY_TIMEOUT, "the listener receiving /clock", helper)
        time.sleep(warmup)
        times = _flush_times(out, 6, 20.0, rec)
        period = min(b - a for a, b in zip(times, times[1:]))
        t_kill, since = _kill_at(out, moment, period, rec, rng)
        time.sleep(0.3)                  # keep publishing: nothing after the kill may appear
    finally:
        helper.stop()
        rec.kill()
    from flagbot_sim.bag import scan
    rep = scan(out)
    inner = [d for d in rep.damage if d.kind not in ("truncated", "no-summary", "summary")]
    if inner or rep.closed:
        raise AssertionError(f"a killed recording should be cut off at its end, nothing else: {rep.describe_loss()}")
    _recover(out, fixed)
    with BagReader(fixed) as r:
        if kind == "record":
            ks = [int(r.decode(m).data) for m in r.messages(["/t/omega_h"])]
            published = {int(k): int(t) for k, t in (line.split() for line in open(log))}
            if ks != list(range(len(ks))) or not ks:
                raise AssertionError(f"recovered messages are not 0..n-1: {ks[:5]}...{ks[-5:]}")
            loss = (t_kill - published[ks[-1]]) * 1e-9
            detail = f"last recovered message {ks[-1]}, {len(published)} published"
            n = len(ks)
            values = ks
        else:
            rows = r.decoded("/clock")
            sims = [m.clock.sec * 1_000_000_000 + m.clock.nanosec for _, _, m in rows]
            if not sims or sims != sorted(sims):
                raise AssertionError("recovered /clock is empty or not monotonic")
            pub = [int(line.split()[0]) for line in open(log) if line.strip()]
            # nothing in the middle lost: every /clock the listener got within the recovered span is recovered (by
            # content: a bound on the gap between ticks is one a busy machine breaks without losing anything)
            have = set(sims)
            missing = [t for t in pub if sims[0] <= t <= sims[-1] and t not in have]
            if missing:
                raise AssertionError(f"recovered /clock lacks {len(missing)} ticks the listener got, from "
                                     f"{missing[0] * 1e-9:.3f} s")
            loss_sim = (max(pub) - sims[-1]) * 1e-9
            loss_wall = (t_kill - rows[-1][0]) * 1e-9
            loss = max(loss_sim, loss_wall)
            detail = (f"published /clock up to {max(pub) * 1e-9:.3f} s, recovered up to {sims[-1] * 1e-9:.3f} s; "
                      f"kill {1e3 * loss_wall:.0f} ms after the last recovered receive time")
            n = r.report.messages
            values = None
    return Kill(kind, moment, loss, since, period, n, detail, out, fixed, values)


def main(argv=None) -> int:
    import argparse
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=10, help="kills per (recorder, moment)")
    p.add_argument("--kind", choices=["record", "sim_node"], action="append")
    p.add_argument("--moment", choices=["worst", "random"], action="append")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)
    results: dict[tuple[str, str], list[Kill]] = {}
    for kind in args.kind or ["record", "sim_node"]:
        for moment in args.moment or ["worst", "random"]:
            for i in range(args.runs):
                with tempfile.TemporaryDirectory() as tmp:
                    k = measure(kind, moment, tmp, seed=args.seed + i)
                print(k.line(), flush=True)
                results.setdefault((kind, moment), []).append(k)
    print("\nloss of recorded time at a kill -9 (s):")
    for (kind, moment), ks in results.items():
        losses = [k.loss for k in ks]
        print(f"  {kind:8s} {moment:6s} n = {len(ks):3d}  median {statistics.median(losses):.3f}  "
              f"max {max(losses):.3f}  min {min(losses):.3f}  "
              f"(flush period {statistics.median(k.period for k in ks):.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
