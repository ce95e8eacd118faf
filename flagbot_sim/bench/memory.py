"""Resident memory of long runs: `flagbot run` and `sim_node`, sampled from 10 to 60 minutes of simulated time.

The simulation (what `flagbot run` steps) runs in this process; `sim_node` runs as a separate process, as users
start it, as fast as it can. Resident set size (VmRSS in /proc/PID/status) is read at each mark of simulated
time (sim_node's from its /clock). The figure that matters is the growth between the 10-minute
and the 60-minute mark; before the history bound, `sim_node` grew ~119 MB per simulated hour.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile
import time

MARKS = (60.0, 600.0, 1800.0, 3600.0)        # s of simulated time


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError(f"no VmRSS for pid {pid}")


def _env() -> dict:
    from ..ros.dds import configure_dds
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    configure_dds(env)          # the loopback-only DDS profile, as every flagbot process (ros/dds.py)
    env.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))
    env.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="flagbot_bench_roslog_"))
    return env


def measure_run(scene: str = "design1", marks=MARKS) -> list[tuple[float, float]]:
    """RSS of this process while it runs what `flagbot run SCENE` runs (a Simulation stepped to each mark)."""
    from ..physics import Simulation
    from ..scene import load_scene
    sim = Simulation(load_scene(scene))
    out = []
    for mark in marks:
        while sim.time < mark - 1e-9:
            sim.step()
        out.append((mark, rss_mb(os.getpid())))
        print(f"  simulation:  t = {mark:6.0f} s  RSS {out[-1][1]:7.1f} MB", flush=True)
    return out


def measure_node(scene: str = "design1", marks=MARKS) -> list[tuple[float, float]]:
    """RSS of a sim_node running as fast as it can, read when /clock passes each mark."""
    import rclpy
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock
    env = _env()
    os.environ.update({k: env[k] for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_DOMAIN_ID", "ROS_LOG_DIR",
                                           "FASTRTPS_DEFAULT_PROFILES_FILE") if k in env})
    proc = subprocess.Popen([sys.executable, "-m", "flagbot_sim.ros.sim_node", "--ros-args", "-p", f"scene:={scene}",
                             "-p", "real_time_factor:=0.0", "-p", "initial_omega:=10.47"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    rclpy.init()
    node = Node("flagbot_memory_bench")
    now = [0.0]
    node.create_subscription(Clock, "/clock", lambda m: now.__setitem__(0, m.clock.sec + 1e-9 * m.clock.nanosec), 10)
    out, pending = [], list(marks)
    try:
        deadline = time.monotonic() + 3600.0
        while pending and proc.poll() is None and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.2)
            if now[0] >= pending[0]:
                out.append((pending.pop(0), rss_mb(proc.pid)))
                print(f"  sim_node:    t = {out[-1][0]:6.0f} s  RSS {out[-1][1]:7.1f} MB", flush=True)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        node.destroy_node()
        rclpy.shutdown()
    return out


def report(name: str, rows: list[tuple[float, float]]) -> str:
    by = dict(rows)
    grow = by.get(3600.0, float("nan")) - by.get(600.0, float("nan"))
    return (f"{name:12s} " + "  ".join(f"{t / 60:4.0f} min {mb:6.1f} MB" for t, mb in rows)
            + f"   growth 10 -> 60 min: {grow:+.1f} MB")


def run(args) -> int:
    lines = ["resident memory vs simulated time (design 1, n = 2, 100 rpm)"]
    if not args.node_only:
        lines.append(report("simulation", measure_run()))
    if not args.run_only:
        lines.append(report("sim_node", measure_node()))
    print("\n".join(lines), flush=True)
    return 0
