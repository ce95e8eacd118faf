"""sim_node under a flood of valid motor commands: does the device keep its pace?

    flagbot bench flood                              # 0, 5k, 10k msg/s at real_time_factor 0, then /clock at 1
    flagbot bench flood --rates 0,2000,5000,10000 --repeat 3 --seconds 10

sim_node runs as a separate process, as users start it; the flood comes from another process (a plain rclpy
publisher of ``cmd_omega`` sending one valid value, the motor speed sim_node already runs at, so the physics does
the same work with and without the flood); this process only listens to ``/clock``. Figures:

* real_time_factor 0 (as fast as possible): simulated seconds per wall second over ``--seconds`` of wall time
  at each flood rate, the phases interleaved (0, 5k, 10k, 0, 5k, 10k, ...) so that a change of the host's load
  shows up as a difference between the unflooded phases; each flooded figure is also given as a ratio to the
  mean of the unflooded ones;
* real_time_factor 1: the /clock rate (Hz, against sim_node's ``publish_rate``), its longest gap and the
  simulated seconds per wall second, unflooded and at the highest flood rate.

The flooder's achieved rate is printed next to the requested one (on a loaded 2-core machine a Python publisher
may not reach 10k msg/s); so are sim_node's CPU seconds per wall second and the load average before and after.
"""
from __future__ import annotations

import json
import os
import signal
import statistics
import subprocess
import sys
import time

from .memory import _env
from .startup import load

#: the motor speed sim_node runs at, and the value every flood message carries (rad/s; 100 rpm)
OMEGA = 10.47
SETTLE = 1.0            # s of wall time between starting a flood and measuring (discovery, the queue filling)


# ---------------------------------------------------------------------------------------------- the flooder
def flood(rate: float, seconds: float, omega: float = OMEGA) -> dict:
    """Publish ``cmd_omega`` = ``omega`` at ``rate`` messages per second for ``seconds`` once sim_node's
    subscription is matched (at most 20 s of waiting); the counts sent and the rate achieved."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64

    from ..topics import CMD_OMEGA
    rclpy.init()
    node = rclpy.create_node("flagbot_bench_flooder")
    pub = node.create_publisher(Float64, CMD_OMEGA, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    data = serialize_message(Float64(data=float(omega)))   # published as bytes: the flooder's cost is the send
    deadline = time.monotonic() + 20.0
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.02)
    print("ready", flush=True)
    sent = 0
    cpu0 = time.process_time()
    t0 = time.monotonic()
    end = t0 + seconds
    now = t0
    try:
        while now < end:
            due = min(int((now - t0) * rate), int(seconds * rate))
            while sent < due:
                pub.publish(data)
                sent += 1
            time.sleep(0.0005)
            now = time.monotonic()
    except KeyboardInterrupt:
        pass
    wall = time.monotonic() - t0
    cpu = time.process_time() - cpu0
    node.destroy_node()
    rclpy.try_shutdown()
    return {"sent": sent, "seconds": wall, "rate": sent / wall if wall > 0 else 0.0,
            "cpu_per_wall": cpu / wall if wall > 0 else 0.0}


class Flooder:
    """A flooding child process (``python -m flagbot_sim.bench.flood flooder RATE SECONDS``)."""

    def __init__(self, rate: float, seconds: float, env: dict):
        self.proc = subprocess.Popen([sys.executable, "-m", "flagbot_sim.bench.flood", "flooder", str(rate),
                                      str(seconds)], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        line = self.proc.stdout.readline()
        if line.strip() != "ready":
            raise RuntimeError(f"the flooder did not start: {line}{self.proc.stderr.read()[-500:]}")

    def result(self, timeout: float) -> dict:
        out, err = self.proc.communicate(timeout=timeout)
        if self.proc.returncode != 0:
            raise RuntimeError(f"the flooder failed (exit {self.proc.returncode}): {err.strip()[-500:]}")
        return json.loads(out.strip().splitlines()[-1])


# ---------------------------------------------------------------------------------------------- measuring
def cpu_seconds(pid: int, thread: int | None = None) -> float:
    """User + system CPU seconds of process ``pid`` (from /proc/PID/stat), or of its thread ``thread``."""
    with open(f"/proc/{pid}/stat" if thread is None else f"/proc/{pid}/task/{thread}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class ClockWatch:
    """/clock as this process receives it: (wall time of arrival, simulated time)."""

    def __init__(self, node):
        from rosgraph_msgs.msg import Clock

        from ..topics import CLOCK
        self.node = node
        self.samples: list[tuple[float, float]] = []
        node.create_subscription(Clock, CLOCK, self._on_clock, 100)

    def _on_clock(self, msg) -> None:
        self.samples.append((time.monotonic(), msg.clock.sec + 1e-9 * msg.clock.nanosec))

    def spin_for(self, seconds: float) -> list[tuple[float, float]]:
        """Spin for ``seconds`` of wall time; the samples that arrived meanwhile."""
        import rclpy
        start = len(self.samples)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(self.node, timeout_sec=0.01)
        return self.samples[start:]

    def wait_running(self, timeout: float = 60.0) -> None:
        import rclpy
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            rclpy.spin_once(self.node, timeout_sec=0.05)
            if len(self.samples) >= 2 and self.samples[-1][1] > self.samples[0][1]:
                return
        raise RuntimeError(f"sim_node published no advancing /clock within {timeout:.0f} s")


def figures(samples: list[tuple[float, float]]) -> dict:
    """Simulated seconds per wall second, /clock rate (Hz) and its longest gap (s) over ``samples``."""
    if len(samples) < 2:
        return {"sim_per_wall": 0.0, "clock_hz": 0.0, "max_gap": float("inf")}
    (w0, s0), (w1, s1) = samples[0], samples[-1]
    gaps = [b[0] - a[0] for a, b in zip(samples, samples[1:])]
    return {"sim_per_wall": (s1 - s0) / (w1 - w0), "clock_hz": (len(samples) - 1) / (w1 - w0),
            "max_gap": max(gaps)}


def start_sim_node(env: dict, scene: str, overrides: list[str], rtf: float, publish_rate: float):
    extra = ["-p", f"scene_overrides:={json.dumps(list(overrides))}"] if overrides else []
    return subprocess.Popen([sys.executable, "-m", "flagbot_sim.ros.sim_node", "--ros-args", "-p", f"scene:={scene}",
                             *extra, "-p", f"real_time_factor:={rtf}", "-p", f"initial_omega:={OMEGA}",
                             "-p", f"publish_rate:={publish_rate}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)


def stop(proc, timeout: float = 30.0) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def phase(watch: ClockWatch, sim_pid: int, rate: float, seconds: float, env: dict) -> dict:
    """One measurement: a flood at ``rate`` (0: none) for SETTLE + ``seconds``, the figures over the last
    ``seconds``."""
    flooder = Flooder(rate, SETTLE + seconds, env) if rate > 0 else None
    watch.spin_for(SETTLE)
    cpu0, main0, w0 = cpu_seconds(sim_pid), cpu_seconds(sim_pid, sim_pid), time.monotonic()
    samples = watch.spin_for(seconds)
    cpu, main, wall = cpu_seconds(sim_pid) - cpu0, cpu_seconds(sim_pid, sim_pid) - main0, time.monotonic() - w0
    out = figures(samples)
    out["cpu_per_wall"] = cpu / wall
    # what the flood costs sim_node itself, whatever else the host's cores are doing: CPU of the main thread
    # (executor, timer, stepping) per simulated second, and CPU of its other threads (the middleware's
    # reception) per wall second
    advance = samples[-1][1] - samples[0][1] if len(samples) >= 2 else 0.0
    out["main_per_sim"] = main / advance if advance > 0 else float("nan")
    out["others_per_wall"] = (cpu - main) / wall
    out["rate"] = rate
    res = flooder.result(timeout=60.0) if flooder is not None else {"rate": 0.0, "cpu_per_wall": 0.0}
    out["achieved"], out["flooder_cpu"] = res["rate"], res["cpu_per_wall"]
    return out


def measure(rates: list[float], seconds: float, repeat: int, rtf: float, scene: str, overrides: list[str],
            publish_rate: float) -> list[dict]:
    import rclpy
    env = _env()
    sim = start_sim_node(env, scene, overrides, rtf, publish_rate)
    os.environ.update({k: env[k] for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_DOMAIN_ID", "ROS_LOG_DIR",
                                           "FASTRTPS_DEFAULT_PROFILES_FILE") if k in env})
    rclpy.init()
    node = rclpy.create_node("flagbot_bench_flood")
    rows = []
    try:
        watch = ClockWatch(node)
        watch.wait_running()
        watch.spin_for(2.0)             # past the start-up transient
        for r in range(repeat):
            for rate in rates:
                if sim.poll() is not None:
                    raise RuntimeError(f"sim_node ended (exit {sim.returncode})")
                rows.append(dict(phase(watch, sim.pid, rate, seconds, env), repeat=r))
                print(f"  rtf {rtf:g}  flood {rate:7.0f} msg/s (sent {rows[-1]['achieved']:7.0f}): "
                      f"{rows[-1]['sim_per_wall']:.3f} sim s / wall s, /clock {rows[-1]['clock_hz']:.1f} Hz",
                      flush=True)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        stop(sim)
    return rows


def table(rows: list[dict], rtf: float, publish_rate: float) -> str:
    base = [r["sim_per_wall"] for r in rows if r["rate"] == 0]
    base_mean = statistics.mean(base) if base else float("nan")
    lines = [f"real_time_factor {rtf:g} (publish_rate {publish_rate:g} Hz): each phase, in the order run",
             "  flood msg/s   sent msg/s   sim s/wall s   vs unflooded   /clock Hz   longest gap s   "
             "sim_node CPU s/wall s   main thread CPU ms/sim s   other threads CPU s/wall s   flooder CPU s/wall s"]
    for r in rows:
        ratio = r["sim_per_wall"] / base_mean if base_mean else float("nan")
        lines.append(f"  {r['rate']:11.0f}  {r['achieved']:11.0f}  {r['sim_per_wall']:13.3f}  {ratio:13.3f}  "
                     f"{r['clock_hz']:10.1f}  {r['max_gap']:14.3f}  {r['cpu_per_wall']:21.2f}  "
                     f"{1e3 * r['main_per_sim']:25.1f}  {r['others_per_wall']:27.2f}  {r['flooder_cpu']:20.2f}")
    base_main = statistics.mean([r["main_per_sim"] for r in rows if r["rate"] == 0] or [float("nan")])
    for rate in sorted({r["rate"] for r in rows}):
        vals = [r["sim_per_wall"] for r in rows if r["rate"] == rate]
        main = statistics.median([r["main_per_sim"] for r in rows if r["rate"] == rate])
        lines.append(f"  median at {rate:7.0f} msg/s: {statistics.median(vals):.3f} sim s / wall s"
                     + (f" ({statistics.median(vals) / base_mean:.3f} of the unflooded mean)" if rate else "")
                     + f"; main thread {1e3 * main:.1f} CPU ms per sim s"
                     + (f" ({main / base_main:.3f} of unflooded)" if rate else ""))
    return "\n".join(lines)


def run(args) -> int:
    from ..scene import SceneError, load_scene
    try:
        rates = [float(x) for x in args.rates.split(",") if x.strip()]
    except ValueError:
        raise SceneError(f"--rates must be comma-separated numbers of messages per second, got {args.rates!r}") \
            from None
    if not rates or any(not (0 <= r <= 1e6) for r in rates):
        raise SceneError(f"--rates must list rates between 0 and 1e6 msg/s, got {args.rates!r}")
    if args.repeat < 1 or not (1.0 <= args.seconds <= 600.0):
        raise SceneError("--repeat must be at least 1 and --seconds between 1 and 600")
    load_scene(args.scene, args.overrides)          # a bad scene is refused before anything starts
    if 0.0 not in rates:
        rates = [0.0, *rates]
    scene = " ".join([args.scene, *(f"--set {o}" for o in args.overrides)])
    print(f"sim_node under a cmd_omega flood: scene {scene}, omega_T = {OMEGA} rad/s; {os.cpu_count()} cores, "
          f"{load()}", flush=True)
    scene_args = (args.scene, args.overrides, args.publish_rate)
    rows = measure(rates, args.seconds, args.repeat, 0.0, *scene_args)
    print(table(rows, 0.0, args.publish_rate), flush=True)
    if not args.no_realtime:
        rt = measure([0.0, max(rates)], args.seconds, args.repeat, 1.0, *scene_args)
        print(table(rt, 1.0, args.publish_rate), flush=True)
    print(f"({load()} after)")
    return 0


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["flooder"]:
        print(json.dumps(flood(float(argv[1]), float(argv[2]))), flush=True)
        return 0
    import argparse

    from . import flood_arguments
    ap = argparse.ArgumentParser(prog="bench flood", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    flood_arguments(ap)
    return run(ap.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
