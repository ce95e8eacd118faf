"""``flagbot demo``: sim_node + beam_node + a command profile as separate ROS 2 processes, and the table of DER
against beam theory per omega_T step. The processes, their liveness and the monitor are :mod:`flagbot_sim.ros.demo`
(what the demo does is described there); rclpy is imported only when the monitor starts.
"""
from __future__ import annotations

import math
import os
import signal
import sys

from ..beam import REGIMES
from ..cliutil import check_out_file, finite_float, make_out_dir
from ..ros.demo import (HARD_LIMIT_FACTOR, STALL, START_TIMEOUT, DemoFailure, NodeProcess, default_log_dir,
                        demo_domain, exit_text, format_table, monitor, report_failure, step_table,
                        use_demo_environment)
from ..topics import node_overrides
from ..scene import SceneError, load_scene
from ..units import RPM


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
    p.add_argument("--start-timeout", type=float, default=START_TIMEOUT, metavar="S",
                   help=f"seconds a node may take to become ready (default {START_TIMEOUT:g}); past it, a node "
                        f"that shows no sign of work for {STALL:g} s fails, one still working gets up to "
                        f"{HARD_LIMIT_FACTOR}x as long")
    p.add_argument("--log-dir", default=None, metavar="DIR",
                   help="directory for the nodes' logs, one file per node (default: a new one under ROS_LOG_DIR)")
    p.set_defaults(func=cmd_demo)


def cmd_demo(args) -> int:
    try:
        return _demo(args)
    except KeyboardInterrupt:
        print("error: interrupted (Ctrl-C)", file=sys.stderr)
        return 130


def _demo(args) -> int:
    from ..motor_profile import parse
    scene = load_scene(args.scene, node_overrides(args.n, []))
    n = scene.robot.n_flagella
    rpms = [finite_float(x, "--rpm", SceneError) for x in args.rpm.split(",") if x.strip()]
    if not rpms:
        raise SceneError(f"--rpm: give one or more motor speeds, e.g. 50,100,150 (got {args.rpm!r})")
    if not (args.start_timeout > 0 and math.isfinite(args.start_timeout)):
        raise SceneError(f"--start-timeout must be a positive number of seconds, got {args.start_timeout!r}")
    spec = ",".join(f"{r:g}:{args.step_duration:g}" for r in rpms)
    profile = parse("steps", [spec], rpm=True)
    try:
        domain = demo_domain(args.domain, os.environ, os.getpid())
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.record:
        check_out_file(args.record, "--record")
    use_demo_environment(domain)
    log_dir = make_out_dir(args.log_dir or default_log_dir(), "--log-dir")
    print(f"flagbot demo: ROS domain {domain}; the nodes' logs go to {log_dir}", file=sys.stderr, flush=True)

    from ..physics.warmup import cache_is_warm
    if not cache_is_warm():
        # compiled here, as a step with its own elapsed time, the kernels are in the cache when sim_node starts
        from ..kernels import compile_kernels, describe
        try:
            seconds, compiled = compile_kernels(prefix="demo: ")
        except Exception as exc:  # noqa: BLE001 - one line; sim_node would meet the same failure
            print(f"error: compiling the kernels failed: {type(exc).__name__}: {exc}", file=sys.stderr)
            return 1
        print("demo: " + describe(seconds, compiled), file=sys.stderr, flush=True)

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
    env = dict(os.environ, PYTHONUNBUFFERED="1")     # a node's prints reach its log as they happen
    nodes: dict[str, NodeProcess] = {}
    failure = None
    codes = {}
    try:
        for k, c in cmds.items():
            nodes[k] = NodeProcess(k, c, log_dir / f"{k}.log", env)
        samples, beam = monitor(profile.duration, nodes, args.json, recording=bool(args.record),
                                 start_timeout=args.start_timeout)
    except DemoFailure as exc:
        failure = exc
    finally:
        for node in nodes.values():          # all asked to stop at once, then waited for
            node.interrupt()
        codes = {k: node.stop() for k, node in nodes.items()}
    if failure is not None:
        report_failure(failure, log_dir)
        return 1
    problems = [DemoFailure(f"{k} {'printed a traceback and ' if 'Traceback' in node.log() else ''}ended with "
                            f"{exit_text(codes[k])}", node)
                for k, node in nodes.items()
                if codes[k] not in (0, -signal.SIGINT) or "Traceback" in node.log()]
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
    if problems:
        report_failure(problems[0], log_dir)
        for p in problems[1:]:
            print(f"  also: {p} (its log: {p.node.log_path})", file=sys.stderr)
        return 1
    missing = [f"{r['omega_T'] / RPM:g}" for r in rows if math.isnan(r["omega_h"])]
    if missing:
        print(f"error: no state from sim_node arrived in the last quarter of the step(s) at {', '.join(missing)} "
              f"rpm: a {args.step_duration:g} s step at full speed is over within a few publications; use a "
              f"longer --step-duration (node logs: {log_dir})", file=sys.stderr)
        return 1
    return 0
