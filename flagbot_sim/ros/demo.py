"""`flagbot demo`: the whole virtual device end to end, as separate ROS 2 processes on this machine.

Starts sim_node (as fast as possible, /clock published), beam_node and cmd_profile (a step profile of omega_T
timed on /clock), watches them with a monitor node in this process, then prints per omega_T step the simulated
steady omega_h, omega_t and speed next to the beam-theory prediction. DDS stays on this machine (the loopback
profile of :mod:`flagbot_sim.ros.dds`, for the monitor and the nodes alike), in the ROS domain given by
``--domain``, else an exported ROS_DOMAIN_ID, else one of its own.
"""
from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import tempfile
import time

from ..beam import REGIMES
from ..cliutil import finite_text
from ..progress import ProgressBar
from ..scene import RPM, load_scene, node_overrides


def register(sub) -> None:
    p = sub.add_parser("demo", help="run sim_node + beam_node + a command profile and compare DER with beam theory")
    p.add_argument("--scene", default="design1", help="scene name or .toml path (default design1)")
    p.add_argument("--n", type=int, default=0, help="number of flagella (default: the scene's)")
    p.add_argument("--rpm", default="50,100,150", help="omega_T steps in rpm (default 50,100,150)")
    p.add_argument("--step-duration", type=float, default=20.0, help="simulated seconds per step (default 20)")
    p.add_argument("--regime", default="nlb", choices=REGIMES, help="beam regime")
    p.add_argument("--real-time-factor", type=float, default=0.0, help="0 = as fast as possible (default)")
    p.add_argument("--domain", type=int, default=None,
                   help="ROS domain id, 0-232 (default: an exported ROS_DOMAIN_ID, else one derived from the pid)")
    p.add_argument("--record", default=None, help="also record the run to this MCAP file")
    p.add_argument("--json", action="store_true", help="print the table as JSON")
    p.set_defaults(func=cmd_demo)


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


def _use_demo_environment(domain: int) -> None:
    """DDS on this machine only, in the demo's domain, for the monitor in this process and the nodes it starts
    (they inherit the environment). A log directory is made only when ROS_LOG_DIR is not set."""
    from .dds import configure_dds
    configure_dds(os.environ)
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    if "ROS_LOG_DIR" not in os.environ:
        os.environ["ROS_LOG_DIR"] = tempfile.mkdtemp(prefix="flagbot_demo_log_")


def _check_alive(procs: dict) -> None:
    dead = [k for k, p in procs.items() if p.poll() is not None]
    if dead:
        raise RuntimeError(f"{', '.join(dead)} stopped early")


#: s of wall time between the monitor seeing every node and the start of simulated time
DISCOVERY_SETTLE = 1.0


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


def cmd_demo(args) -> int:
    from ..motor_profile import parse
    scene = load_scene(args.scene, node_overrides(args.n, []))
    n = scene.robot.n_flagella
    rpms = [float(x) for x in args.rpm.split(",") if x.strip()]
    spec = ",".join(f"{r:g}:{args.step_duration:g}" for r in rpms)
    profile = parse("steps", [spec], rpm=True)
    try:
        domain = demo_domain(args.domain, os.environ, os.getpid())
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    _use_demo_environment(domain)
    py = [sys.executable, "-m"]
    common = ["-p", f"scene:={args.scene}", "-p", f"n_flagella:={n}"]
    cmds = {
        "sim_node": py + ["flagbot_sim.ros.sim_node", "--ros-args", *common, "-p", "start_paused:=true",
                          "-p", f"real_time_factor:={args.real_time_factor}"],
        "beam_node": py + ["flagbot_sim.ros.beam_node", "--ros-args", *common, "-p", f"regime:={args.regime}",
                      "-p", "publish_rate:=50.0"],          # a prediction is confirmed on its second publication
        "cmd_profile": py + ["flagbot_sim.ros.cmd_profile", "steps", spec, "--rpm", "--sim-time", "--t0", "0",
                             "--quiet"],
    }
    if args.record:   # sim_node's own recorder: the resolved scene and every parameter go into the file
        cmds["sim_node"] += ["-p", f"record:={os.path.abspath(args.record)}"]
    logs = {k: tempfile.TemporaryFile(mode="w+") for k in cmds}
    procs = {k: subprocess.Popen(c, stdout=logs[k], stderr=subprocess.STDOUT) for k, c in cmds.items()}
    try:
        samples, beam = _monitor(profile.duration, procs, args.json, recording=bool(args.record))
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        codes = {}
        for k, p in procs.items():
            try:
                codes[k] = p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                codes[k] = "killed"
    problems = []
    for k, f in logs.items():
        f.seek(0)
        text = f.read()
        if codes[k] not in (0, -signal.SIGINT) or "Traceback" in text:
            problems.append(f"{k} exited with {codes[k]}:\n{text[-2000:]}")
    rows = step_table(samples, profile.segments(), beam)
    if args.json:
        from ..cliutil import json_output
        print(json_output({"scene": args.scene, "n_flagella": n, "regime": args.regime, "steps": rows}))
    else:
        print(format_table(rows, scene.scene.name, n, args.regime))
        if any(math.isnan(r[k]) for r in rows for k in ("omega_h", "beam_omega_h")):
            print(f"-- : nothing arrived for that step in time (sim_node runs as fast as it can: a "
                  f"{args.step_duration:g} s step lasts a fraction of a second; use a longer --step-duration)")
        if args.record:
            print(f"recorded to {args.record}")
    for p in problems:
        print(p, file=sys.stderr)
    return 1 if problems or any(math.isnan(r["omega_h"]) for r in rows) else 0


def _monitor(duration: float, procs: dict, quiet: bool, recording: bool = False):
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.node import Node, NodeNameNonExistentError
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from .. import topics as names

    rclpy.init()
    node = Node("flagbot_demo_monitor")
    samples = {"omega_h": [], "omega_t": [], "v": []}
    beam_now = {"v": math.nan, "h": math.nan, "t": math.nan}
    beam: list = []
    state = {"clock": 0.0, "cmd": math.nan, "beam_seen": None}

    def t_of(stamp):
        return stamp.sec + 1e-9 * stamp.nanosec

    def on_js(m):
        t = t_of(m.header.stamp)
        samples["omega_h"].append((t, m.velocity[0]))
        samples["omega_t"].append((t, m.velocity[1]))

    def on_odom(m):
        samples["v"].append((t_of(m.header.stamp), m.twist.twist.linear.x))

    def on_beam(key):
        def cb(m):
            # the three topics arrive one by one, so at a change a snapshot mixes the new prediction with the old;
            # beam_node re-publishes all three at its rate, so a snapshot seen twice in a row is one prediction
            beam_now[key] = m.data
            snap = (beam_now["h"], beam_now["t"], beam_now["v"])
            if snap == state["beam_seen"]:
                beam.append((state["clock"], state["cmd"], snap))
            state["beam_seen"] = snap
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
    bar = ProgressBar(duration, label="demo (simulated time)", enabled=not quiet)
    wall0 = time.monotonic()
    try:
        # everyone connected before simulated time starts: the command and beam streams, then unpause
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

        def ready():
            return (node.count_publishers(names.CMD_OMEGA) >= 1 and node.count_publishers(names.BEAM_SPEED) >= 1
                    and node.count_publishers(names.CLOCK) >= 1 and pause.service_is_ready() and recorder_ready())
        while not ready():
            rclpy.spin_once(node, timeout_sec=0.1)
            if time.monotonic() - wall0 > 60:
                raise RuntimeError("the nodes did not appear within 60 s")
            _check_alive(procs)
        # the monitor sees every node, but each pair of nodes (cmd_profile <- /clock <- sim_node, sim_node <-
        # cmd_omega) discovers the other on its own: give them a moment, or with short steps the run could be
        # over before cmd_profile hears the clock (measured: every command lost in 1 of 3 runs of 4 s steps)
        settle = time.monotonic() + DISCOVERY_SETTLE
        while time.monotonic() < settle:
            rclpy.spin_once(node, timeout_sec=0.05)
        future = pause.call_async(SetBool.Request(data=False))
        rclpy.spin_until_future_complete(node, future, timeout_sec=10)
        while rclpy.ok() and state["clock"] < duration + 0.2:
            rclpy.spin_once(node, timeout_sec=0.05)
            cmd = state["cmd"]
            bar.update(min(state["clock"], duration),
                       f"omega_T = {cmd:.3f} rad/s" if math.isfinite(cmd) else "omega_T = -- (no command yet)")
            _check_alive(procs)
            if time.monotonic() - wall0 > 60 + 20 * duration:
                raise RuntimeError("the simulation did not advance: no /clock from sim_node")
    finally:
        bar.close()
        node.destroy_node()
        rclpy.shutdown()
    # keep only beam values that belong to the command active when they arrived
    beam_rows = [(t, cmd, v) for (t, cmd, v) in beam if not any(math.isnan(x) for x in v)]
    return samples, beam_rows
