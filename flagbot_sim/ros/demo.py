"""`flagbot demo`: the whole virtual device end to end, as separate ROS 2 processes on this machine (the command
itself, its arguments and its table: :mod:`flagbot_sim.commands.demo`).

Starts sim_node (as fast as possible, /clock published), beam_node and cmd_profile (a step profile of omega_T
timed on /clock), watches them with a monitor node in this process, then prints per omega_T step the simulated
steady omega_h, omega_t and speed next to the beam-theory prediction. DDS stays on this machine (the loopback
profile of :mod:`flagbot_sim.ros.dds`, for the monitor and the nodes alike), in the ROS domain given by
``--domain``, else an exported ROS_DOMAIN_ID, else one of its own.

Start-up is waited for by readiness, not by a fixed delay: on an empty kernel cache the kernels are compiled
first, in this process, as a step of their own (with its elapsed time), so that the nodes start warm; then each
node counts as ready when the monitor sees what it offers (sim_node's /clock and pause service, beam_node's
predictions, cmd_profile's commands), and until then the status line says what each one is doing (from its log:
"sim_node: compiling kernels (first run only)", "started, connecting"). Each node's output (stdout and stderr)
is kept in its own log file, ``--log-dir`` (default: a new directory under ROS_LOG_DIR). A node fails when its
process ends, or by the liveness rule of :class:`Liveness` (a node that is alive and still working is never
failed within the start limit); a failure is one ``error:`` line naming the node and its log, the log's last
lines, and exit status 1.
"""
from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import tempfile
import time

from pathlib import Path

from .. import topics as names
from ..cliutil import cpu_seconds, finite_text
from ..progress import ProgressBar, StatusLine, format_duration
from ..units import RPM

#: s a node may take to become ready before the liveness rule can fail it (``--start-timeout``): generous, since a
#: first start on a loaded 2-core machine (imports, DDS, a cold kernel compile) has been seen to take minutes
START_TIMEOUT = 600.0
#: s without a sign of work (CPU time used, output written) after which a node past the start limit is stuck
STALL = 60.0
#: a node still working at the start limit is waited for up to this many times the limit
HARD_LIMIT_FACTOR = 3
#: s of wall time without a new /clock during the run (sim_node alive) after which the simulation is stuck
CLOCK_STALL = 300.0
#: lines of a failed node's log printed under the error line
LOG_TAIL = 25


def demo_domain(arg: int | None, env, pid: int) -> int:
    """The ROS domain of the demo: ``--domain``, else an exported ROS_DOMAIN_ID, else 100 + pid % 100.

    Raises ValueError naming the source when the id is not an integer in 0-232 (ROS 2's valid range)."""
    if arg is not None:
        value, source = arg, "--domain"
    elif str(env.get("ROS_DOMAIN_ID", "")).strip():
        source = "ROS_DOMAIN_ID"
        try:
            value = int(str(env["ROS_DOMAIN_ID"]).strip())
        except ValueError:
            raise ValueError(f"ROS_DOMAIN_ID = {env['ROS_DOMAIN_ID']!r} is not an integer") from None
    else:
        return 100 + pid % 100
    if not 0 <= value <= 232:
        raise ValueError(f"{source} = {value} is out of range: a ROS domain id is 0-232")
    return value


def use_demo_environment(domain: int) -> None:
    """DDS on this machine only, in the demo's domain, for the monitor in this process and the nodes it starts
    (they inherit the environment). A log directory is made only when ROS_LOG_DIR is not set."""
    from .dds import configure_dds
    configure_dds(os.environ)
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    if "ROS_LOG_DIR" not in os.environ:
        os.environ["ROS_LOG_DIR"] = tempfile.mkdtemp(prefix="flagbot_demo_log_")


class DemoFailure(Exception):
    """The demo cannot go on: a one-line message and the node whose log says why (None: no node in particular)."""

    def __init__(self, message: str, node: "NodeProcess | None" = None):
        super().__init__(message)
        self.node = node


class Liveness:
    """The liveness rule for a node that is not ready yet: when it counts as failed.

    Never within ``limit`` seconds of its start (a cold first start on a loaded machine takes minutes). Past the
    limit, a node that has shown no sign of work for ``stall`` seconds (neither its CPU time nor its output grew:
    it sleeps, waits, or hangs) has failed; a node that is still working is given time up to ``factor`` times the
    limit. A node whose process ended has failed whatever this says (the monitor checks that first)."""

    def __init__(self, start: float, limit: float, stall: float = STALL, factor: float = HARD_LIMIT_FACTOR):
        self.start = start
        self.limit = limit
        self.stall = min(stall, limit)
        self.factor = factor
        self.activity = None
        self.last_change = start

    def observe(self, now: float, activity) -> None:
        """``activity``: anything that changes while the node works, e.g. (CPU seconds, bytes of output)."""
        if activity != self.activity:
            self.activity = activity
            self.last_change = now

    def verdict(self, now: float) -> str | None:
        """None while the node may still become ready, else why it has failed (one line)."""
        waited, idle = now - self.start, now - self.last_change
        if waited <= self.limit:
            return None
        if idle >= self.stall:
            return (f"not ready after {waited:.0f} s, and no sign of work (no CPU time used, no output) for the "
                    f"last {idle:.0f} s")
        if waited > self.factor * self.limit:
            return (f"not ready after {waited:.0f} s ({self.factor:g} x --start-timeout {self.limit:g} s), though "
                    f"still working")
        return None


#: what a node's log says about its start-up, the later stage first: (text in the log, what the status shows)
START_PHASES = {
    "sim_node": [(f"waiting for {names.CMD_OMEGA}", "started, connecting"),
                 ("compiling kernels", "compiling kernels (first run only)")],
}


def start_phase(name: str, log: str, ready: bool) -> str:
    """What the status line says about node ``name`` while the demo waits for it."""
    if ready:
        return "ready"
    for text, phase in START_PHASES.get(name, []):
        if text in log:
            return phase
    return "starting"


class NodeProcess:
    """One node's process, its output (stdout and stderr together) kept in ``log_path``."""

    def __init__(self, name: str, cmd: list[str], log_path: Path, env: dict):
        self.name = name
        self.log_path = log_path
        self.interrupted = False        # SIGINT sent: a second one would cut the node's orderly stop short
        self._log = open(log_path, "w")
        try:
            self.proc = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT, env=env)
        except OSError:
            self._log.close()
            raise

    def log(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    def activity(self) -> tuple:
        try:
            size = self.log_path.stat().st_size
        except OSError:
            size = None
        return (cpu_seconds(self.proc.pid), size)

    def exit_code(self) -> int | None:
        return self.proc.poll()

    def interrupt(self) -> None:
        """Ask the node to stop (SIGINT), once: a node takes a second signal as "stop now", which would leave
        its recording without its last messages, summary and index."""
        if not self.interrupted and self.proc.poll() is None:
            self.interrupted = True
            self.proc.send_signal(signal.SIGINT)

    def stop(self, timeout: float = 20.0):
        """The exit code once the node has stopped (SIGINT, once, then SIGKILL after ``timeout``), or 'killed'."""
        self.interrupt()
        try:
            code = self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            code = "killed"
        self._log.close()
        return code

    def tail(self, n: int = LOG_TAIL) -> list[str]:
        return self.log().rstrip("\n").splitlines()[-n:] if self.log().strip() else []


def exit_text(code) -> str:
    if isinstance(code, int) and code < 0:
        try:
            return f"signal {signal.Signals(-code).name}"
        except ValueError:
            return f"signal {-code}"
    return f"exit code {code}"


def report_failure(exc: DemoFailure, log_dir: Path, stream=None) -> None:
    """One ``error:`` line, then the last lines of the failing node's log (the whole log stays in its file)."""
    stream = stream or sys.stderr
    node = exc.node
    where = f"its log: {node.log_path}" if node is not None else f"node logs: {log_dir}"
    print(f"error: {exc} ({where})", file=stream)
    lines = node.tail() if node is not None else []
    if lines:
        print(f"last {len(lines)} lines of {node.name}'s log:", file=stream)
        for line in lines:
            print("  | " + line, file=stream)
    elif node is not None:
        print(f"({node.name} wrote nothing)", file=stream)
    stream.flush()


def default_log_dir() -> Path:
    return Path(os.environ["ROS_LOG_DIR"]) / f"flagbot_demo_{time.strftime('%Y%m%d_%H%M%S')}_{os.getpid()}"


#: s of wall time between the monitor seeing every node and the start of simulated time
DISCOVERY_SETTLE = 1.0


class BeamConfirm:
    """The beam prediction from its three topics (omega_h, omega_t, speed), only when it is one prediction.

    The topics arrive one by one, so at a change a snapshot mixes the new prediction with the old, and one topic
    may deliver twice before another delivers at all (taking the snapshot after two equal deliveries once
    showed 150 rpm's speed beside 100 rpm's split). beam_node publishes the three at every tick, in the same
    order, on depth-1 queues: once a new value is out, each other topic delivers its old value at most once more.
    So a snapshot in which every topic has delivered its value twice since the last change is one prediction."""

    KEYS = ("h", "t", "v")

    def __init__(self) -> None:
        self.now = dict.fromkeys(self.KEYS, math.nan)
        self.seen: dict = {}          # topic -> deliveries of its current value since any of the three changed

    def feed(self, key: str, value: float) -> tuple | None:
        """One delivery; the (omega_h, omega_t, v) prediction when it is confirmed, else None."""
        if not (value == self.now[key]):
            self.now[key] = value
            self.seen.clear()
        self.seen[key] = self.seen.get(key, 0) + 1
        if len(self.seen) == 3 and min(self.seen.values()) >= 2:
            return tuple(self.now[k] for k in self.KEYS)
        return None


def step_table(samples: dict, segments: list, beam: list) -> list[dict]:
    """Average the stamped samples over the last quarter of each step; take the beam prediction of the step's
    omega_T (the one whose omega_h + omega_t equals it)."""
    rows = []
    for (t0, t1, w) in segments:
        a = t1 - 0.25 * (t1 - t0)

        def mean(key):
            xs = [v for (t, v) in samples[key] if a <= t <= t1]
            return sum(xs) / len(xs) if xs else math.nan
        # the beam prediction for this step's command is the (confirmed) one whose split adds up to it, whenever
        # it arrived: a short step can be over before it comes (sim_node runs as fast as it can)
        b = [v for (t, omega, v) in beam if abs(v[0] + v[1] - w) <= 1e-6 * max(1.0, abs(w))]
        bh, bt, bv = b[-1] if b else (math.nan, math.nan, math.nan)
        rows.append({"omega_T": w, "omega_h": mean("omega_h"), "omega_t": mean("omega_t"), "v": mean("v"),
                     "beam_omega_h": bh, "beam_omega_t": bt, "beam_v": bv, "t0": t0, "t1": t1})
    return rows


def format_table(rows: list[dict], scene: str, n: int, regime: str) -> str:
    lines = [f"{scene}, n = {n}: DER simulation (sim_node) vs beam theory ({regime}, beam_node); "
             "steady values over the last quarter of each step",
             f"{'omega_T':>14s} | {'omega_h (rad/s)':>17s} | {'omega_t (rad/s)':>17s} | {'v (mm/s)':>17s} | "
             f"{'omega_h/omega_T':>15s}",
             f"{'rad/s (rpm)':>14s} | {'DER':>8s} {'beam':>8s} | {'DER':>8s} {'beam':>8s} | {'DER':>8s} {'beam':>8s} | "
             f"{'DER':>7s} {'beam':>7s}"]
    def f(x, spec):        # a value that never arrived prints as '--', not nan, in the column's width
        return finite_text(x, spec).rjust(int(spec.split(".")[0]))

    for r in rows:
        w = r["omega_T"]
        share = (lambda x: 100 * x / w) if w else (lambda x: math.nan)
        lines.append(f"{w:7.3f} ({w / RPM:4.0f}) | {f(r['omega_h'], '8.4f')} {f(r['beam_omega_h'], '8.4f')} | "
                     f"{f(r['omega_t'], '8.4f')} {f(r['beam_omega_t'], '8.4f')} | {f(1e3 * r['v'], '8.4f')} "
                     f"{f(1e3 * r['beam_v'], '8.4f')} | {f(share(r['omega_h']), '6.1f')}% "
                     f"{f(share(r['beam_omega_h']), '6.1f')}%")
    return "\n".join(lines)


def _check_running(nodes: dict, when: str) -> None:
    for node in nodes.values():
        code = node.exit_code()
        if code is not None:
            raise DemoFailure(f"{node.name} ended with {exit_text(code)} {when}", node)


def monitor(duration: float, nodes: dict, quiet: bool, recording: bool = False,
             start_timeout: float = START_TIMEOUT):
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.node import Node, NodeNameNonExistentError
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    rclpy.init()
    node = Node("flagbot_demo_monitor")
    samples = {"omega_h": [], "omega_t": [], "v": []}
    beam_now = {"v": math.nan, "h": math.nan, "t": math.nan}
    beam: list = []
    state = {"clock": 0.0, "cmd": math.nan}

    def t_of(stamp):
        return stamp.sec + 1e-9 * stamp.nanosec

    def on_js(m):
        t = t_of(m.header.stamp)
        samples["omega_h"].append((t, m.velocity[0]))
        samples["omega_t"].append((t, m.velocity[1]))

    def on_odom(m):
        samples["v"].append((t_of(m.header.stamp), m.twist.twist.linear.x))

    confirm = BeamConfirm()

    def on_beam(key):
        def cb(m):
            snap = confirm.feed(key, m.data)
            if snap is not None:
                beam.append((state["clock"], state["cmd"], snap))
        return cb

    qos = QoSProfile(depth=50)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(JointState, names.JOINT_STATES, on_js, qos)
    node.create_subscription(Odometry, names.ODOM, on_odom, qos)
    node.create_subscription(Clock, names.CLOCK, lambda m: state.__setitem__("clock", t_of(m.clock)), qos)
    node.create_subscription(Float64, names.CMD_OMEGA, lambda m: state.__setitem__("cmd", m.data), qos)
    node.create_subscription(Float64, names.BEAM_SPEED, on_beam("v"), latched)
    node.create_subscription(Float64, names.BEAM_OMEGA_H, on_beam("h"), latched)
    node.create_subscription(Float64, names.BEAM_OMEGA_T, on_beam("t"), latched)
    from std_srvs.srv import SetBool
    pause = node.create_client(SetBool, "sim_node/" + names.PAUSE.removeprefix("~/"))   # sim_node's own service
    bar = None
    status = StatusLine()
    try:
        def recorder_ready():
            # sim_node subscribes to beam/ topics only to record them: once it has, the recorder is listening
            if not recording:
                return True
            if "sim_node" not in node.get_node_names():
                return False
            try:
                subs = {t for t, _ in node.get_subscriber_names_and_types_by_node("sim_node", "/")}
            except NodeNameNonExistentError:          # in the graph a moment later
                return False
            return {"/" + names.BEAM_SPEED, "/" + names.CMD_OMEGA} <= subs

        # a node is ready when the monitor sees what it offers: the readiness signal, however long it takes
        offers = {
            "sim_node": lambda: (node.count_publishers(names.CLOCK) >= 1 and pause.service_is_ready()
                                 and recorder_ready()),
            "beam_node": lambda: node.count_publishers(names.BEAM_SPEED) >= 1,
            "cmd_profile": lambda: node.count_publishers(names.CMD_OMEGA) >= 1,
        }
        t0 = time.monotonic()
        live = {k: Liveness(t0, start_timeout) for k in nodes}
        ready = {k: False for k in nodes}
        while True:
            rclpy.spin_once(node, timeout_sec=0.1)
            _check_running(nodes, "before it was ready")
            now = time.monotonic()
            for k, proc in nodes.items():
                ready[k] = ready[k] or offers[k]()
                if not ready[k]:
                    live[k].observe(now, proc.activity())
                    why = live[k].verdict(now)
                    if why is not None:
                        raise DemoFailure(f"{k} {why}", proc)
            if all(ready.values()):
                break
            status.update("waiting for the nodes: " + "; ".join(
                f"{k}: {start_phase(k, '' if ready[k] else proc.log(), ready[k])}" for k, proc in nodes.items()))
        status.close(f"nodes ready after {format_duration(time.monotonic() - t0)}")
        # the monitor sees every node, but each pair of nodes (cmd_profile <- /clock <- sim_node, sim_node <-
        # cmd_omega) discovers the other on its own: give them a moment, or with short steps the run could be
        # over before cmd_profile hears the clock (measured: every command lost in 1 of 3 runs of 4 s steps)
        settle = time.monotonic() + DISCOVERY_SETTLE
        while time.monotonic() < settle:
            rclpy.spin_once(node, timeout_sec=0.05)
        _unpause(node, pause, SetBool.Request(data=False), nodes)
        bar = ProgressBar(duration, label="demo (simulated time)", enabled=not quiet)
        last_clock, last_advance = state["clock"], time.monotonic()
        while rclpy.ok() and state["clock"] < duration + 0.2:
            rclpy.spin_once(node, timeout_sec=0.05)
            cmd = state["cmd"]
            bar.update(min(state["clock"], duration),
                       f"omega_T = {cmd:.3f} rad/s" if math.isfinite(cmd) else "omega_T = -- (no command yet)")
            _check_running(nodes, "during the run")
            now = time.monotonic()
            if state["clock"] != last_clock:
                last_clock, last_advance = state["clock"], now
            elif now - last_advance > CLOCK_STALL:
                raise DemoFailure(f"simulated time has not advanced for {CLOCK_STALL:.0f} s (no new /clock from "
                                  f"sim_node; stuck at t = {last_clock:.2f} s)", nodes["sim_node"])
    finally:
        status.close()
        if bar is not None:
            bar.close()
        node.destroy_node()
        rclpy.shutdown()
    # keep only beam values that belong to the command active when they arrived
    beam_rows = [(t, cmd, v) for (t, cmd, v) in beam if not any(math.isnan(x) for x in v)]
    return samples, beam_rows


def _unpause(node, pause, request, nodes: dict, attempt: float = 10.0) -> None:
    """Start simulated time through sim_node's pause service; a call that got no answer is sent again."""
    import rclpy
    t0 = time.monotonic()
    while True:
        future = pause.call_async(request)
        sent = time.monotonic()
        while not future.done() and time.monotonic() - sent < attempt:
            rclpy.spin_once(node, timeout_sec=0.05)
            _check_running(nodes, "before the run started")
        if future.done() and future.result() is not None:
            return
        if time.monotonic() - t0 > CLOCK_STALL:
            raise DemoFailure(f"sim_node did not answer its pause service (to start simulated time) within "
                              f"{CLOCK_STALL:.0f} s", nodes["sim_node"])
