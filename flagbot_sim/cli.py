"""Command line: ``python -m flagbot_sim COMMAND ...`` (also the ``flagbot`` console script).

Each command lives with the code it drives and registers itself here through a ``register(subparsers)``
function; this module only assembles them and turns known errors into one-line messages.
"""
from __future__ import annotations

import argparse
import importlib
import math
import sys

from .cliutil import add_scene_arguments, dumps
from .scene import RPM, SceneError, load_scene

#: modules that contribute subcommands (each has register(subparsers)); missing ones are skipped
COMMAND_MODULES = ["flagbot_sim.beam.cli", "flagbot_sim.ros.demo", "flagbot_sim.bench", "flagbot_sim.sweep",
                   "flagbot_sim.bagtools", "flagbot_sim.view.render"]


def cmd_run(args) -> int:
    from .physics import Simulation, StepFailed
    from .progress import ProgressBar

    scene = load_scene(args.scene, args.overrides)
    duration = args.duration if args.duration is not None else scene.time.duration
    if not (duration > 0 and math.isfinite(duration)):
        raise SceneError(f"--duration must be a positive number of seconds, got {duration!r}")
    sim = Simulation(scene)
    bar = ProgressBar(duration, label=scene.scene.name, enabled=not args.json and not args.quiet)
    n_steps = max(1, int(round(duration / scene.time.dt)))     # as Simulation.run counts them
    from .view.cli import RunView
    view = RunView.from_args(args)      # --view: the run served to the Foxglove app (view/cli.py), else None

    def progress(s) -> None:
        if view is not None:
            view.tick(s)
        k = s.steps - 1
        if k % 10 == 0 or k == n_steps - 1:
            ob = s.observer
            bar.update(s.time, f"newton {s.last_stats.newton_iterations}  w_h {ob.rate_h:+.3f}  "
                               f"w_t {ob.rate_t:+.3f} rad/s  v {1e3 * ob.speed:+.3f} mm/s")

    error = None
    try:
        if view is not None:
            view.start(sim)
        sim.run(duration, callback=progress)
    except StepFailed as exc:
        error = str(exc)
    except KeyboardInterrupt:
        error = f"interrupted at t = {sim.time:.3f} s"
    finally:
        if view is not None:
            view.close(sim)
    bar.close()
    out = sim.summary()
    if error:
        out["error"] = error
    if args.json:
        print(dumps(out))
    else:
        print(format_summary(scene, out))
    return 1 if error else 0


def format_summary(scene, out: dict) -> str:
    lines = [f"scene {out['scene']}  n = {out['n_flagella']}  omega_T = {out['omega_T']:.4f} rad/s "
             f"({out['omega_T'] / RPM:.1f} rpm)  t = {out['time']:.3f} s"]
    if scene.clamped:
        lines += [f"  Fx  (axial force on the flagellum)  = {out['Fx']:+.6e} N",
                  f"  Tx  (torque about the axis)        = {out['Tx']:+.6e} N m",
                  "  tip (co-rotating frame)            = [" + ", ".join(f"{v:+.6f}" for v in out["tip"]) + "] m"]
    else:
        wt = out["omega_T"] if out["omega_T"] else float("nan")
        lines += [f"  omega_h = {out['omega_h']:+.5f} rad/s ({out['omega_h'] / RPM:+.2f} rpm, "
                  f"{100 * out['omega_h'] / wt:.1f}% of omega_T)",
                  f"  omega_t = {out['omega_t']:+.5f} rad/s ({out['omega_t'] / RPM:+.2f} rpm)",
                  f"  v       = {out['v']:+.6e} m/s ({1e3 * out['v']:+.4f} mm/s, positive = head first)",
                  f"  normalised: omega_T_bar = {scene.normalise_omega(out['omega_T']):.2f}, "
                  f"v_bar = {scene.normalise_speed(out['v']):.4f}"]
    lines.append(f"  steady over the last {out['window']:.2f} s: {'yes' if out['steady'] else 'NO (run longer)'}")
    lines.append(f"  {out['steps']} steps, {out['newton_iterations']} Newton iterations, "
                 f"{out['dt_reductions']} dt reductions, {out['wall_seconds']:.2f} s wall, "
                 f"real-time factor {out['real_time_factor']:.2f}")
    if "error" in out:
        lines.append(f"  ERROR: {out['error']}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="flagbot", description="flagbot_sim: soft flagellated robot simulator")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("run", help="run the DER simulation of a scene and report steady-state outputs")
    add_scene_arguments(p)
    p.add_argument("--duration", type=float, default=None, help="simulated seconds (default: the scene's)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a summary")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    from .view.args import add_view_arguments
    add_view_arguments(p)
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("scenes", help="list built-in scenes and the scene keys with units and ranges")
    p.set_defaults(func=cmd_scenes)
    for name in COMMAND_MODULES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name and name.startswith(exc.name):
                continue
            raise
        mod.register(sub)
    return parser


def cmd_scenes(args) -> int:
    import dataclasses

    from .scene import EFFECTS, SECTIONS, builtin_scenes
    print("built-in scenes:", ", ".join(builtin_scenes()))
    print("\neffects:")
    for k, v in EFFECTS.items():
        print(f"  {k:12s} {v}")
    print("\nkeys:")
    for s, cls in SECTIONS.items():
        for f in dataclasses.fields(cls):
            m = f.metadata
            rng = " ".join(f"{op}{m[op]}" for op in ("gt", "ge", "lt", "le") if m.get(op) is not None)
            print(f"  {s}.{f.name:16s} {str(f.default):24s} {m['unit']:8s} {rng:22s} {m['doc']}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except SceneError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:      # record, replay, demo without ROS 2: one line naming the [ros] extra
        from .optional import missing_ros
        if (missing := missing_ros(exc, f"flagbot {args.command}")) is None:
            raise
        print(f"error: {missing}", file=sys.stderr)
        return 1
