"""Command line: ``python -m flagbot_sim COMMAND ...`` (also the ``flagbot`` console script).

Each command lives with the code it drives and registers itself here through a ``register(subparsers)``
function; this module only assembles them and turns known errors into one-line messages.

Start-up time matters (``flagbot run`` is often a short job), so the command modules are imported lazily: the
parser imports only the module that provides the command being run. ``flagbot --help`` lists every command from
:data:`COMMANDS` without importing any of them (scipy.optimize for the beam estimator, matplotlib, dask, rclpy);
a test checks that the table names exactly the commands the modules register.
"""
from __future__ import annotations

import argparse
import importlib
import math
import os
import sys
import time

from .cliutil import (add_scene_arguments, add_version_argument, broken_pipe_exit, fast_exit, finite_text,
                      json_output, process_age)
from .scene import RPM, SceneError, TimeSection, load_scene

#: command -> (module whose register(subparsers) adds it, one-line help for ``flagbot --help``)
COMMANDS: dict[str, tuple[str, str]] = {
    "steady": ("flagbot_sim.steady_cli", "solve the steady state (relative equilibrium) directly, without time "
                                         "stepping; with its stability"),
    "beam": ("flagbot_sim.beam.cli", "beam-theory estimate (LB / NLB w/o head / NLB) of omega_h, omega_t and "
                                     "speed for motor speeds omega_T"),
    "demo": ("flagbot_sim.ros.demo", "run sim_node + beam_node + a command profile and compare DER with beam "
                                     "theory"),
    "bench": ("flagbot_sim.bench", "benchmarks: accuracy vs time, throughput, start-up time"),
    "sweep": ("flagbot_sim.sweep", "parameter sweep: DER to steady state and the beam balance at every grid "
                                   "point, one tidy CSV, resumable, plus the paper's figures"),
    "sweep-plot": ("flagbot_sim.sweep", "redraw a sweep's figures and summary from DIR/results.csv alone"),
    "fit": ("flagbot_sim.fit", "fit scene constants (C1, C2, mu, ...) to measured steady states, 95%% intervals"),
    "optimize": ("flagbot_sim.fit", "search designs (n, L, omega_rpm, ...) for the fastest or most efficient robot"),
    "record": ("flagbot_sim.bagtools", "record flagbot topics to MCAP (rosbag2 layout) until Ctrl-C"),
    "replay": ("flagbot_sim.bagtools", "replay an MCAP recording with its timing and /clock"),
    "bag-summary": ("flagbot_sim.bagtools", "topics, counts, duration and the steady state of each omega_T step"),
    "bag-recover": ("flagbot_sim.bagtools", "rewrite the readable part of a damaged MCAP file into a valid one"),
    "render": ("flagbot_sim.view.render", "draw the paper's Fig. 1 snapshots of the robot's shape from a run, a "
                                          "recording or a scene (PNG, or GIF animation)"),
}

#: modules that contribute subcommands, in the order they are registered when all are wanted
COMMAND_MODULES = list(dict.fromkeys(module for module, _ in COMMANDS.values()))

#: longest error message printed (a refused 1e6-element array must not be echoed back)
MAX_ERROR_CHARS = 600


def cmd_run(args) -> int:
    scene = load_scene(args.scene, args.overrides)          # before the simulator's imports: a refusal is quick
    from .physics import Simulation, StepFailed
    from .progress import ProgressBar

    duration = args.duration if args.duration is not None else scene.time.duration
    longest = TimeSection.__dataclass_fields__["duration"].metadata["le"]
    if not (0 < duration <= longest):
        raise SceneError(f"--duration must be a positive number of seconds up to {longest:g}, got {duration!r}")
    if scene.time.rtol == 0.0 and duration < 0.5 * scene.time.dt:
        raise SceneError(f"--duration {duration:g} s is shorter than half a time step (time.dt = "
                         f"{scene.time.dt:g} s): fixed-step runs take whole steps")
    sim = Simulation(scene)
    startup = process_age()
    bar = ProgressBar(duration, label=scene.scene.name, enabled=not args.json and not args.quiet)
    n_steps = max(1, int(round(duration / scene.time.dt)))     # as Simulation.run counts them
    from .view.cli import RunView
    view = RunView.from_args(args)      # --view: the run served to the Foxglove app (view/cli.py), else None

    warnings: list[str] = []

    def progress(s) -> None:
        if view is not None:
            view.tick(s)
        if s.cutting and not warnings:        # once: what slows the run, with the numbers
            warnings.append(s.cutting_report())
            bar.note(f"warning: {warnings[0]}")
        k = s.steps - 1
        if k % 10 == 0 or k == n_steps - 1:
            ob = s.observer
            bar.update(s.time, lambda: f"newton {s.last_stats.newton_iterations}  "
                                       f"w_h {finite_text(ob.rate_h, '+.3f')}  w_t {finite_text(ob.rate_t, '+.3f')} "
                                       f"rad/s  v {finite_text(1e3 * ob.speed, '+.3f')} mm/s")

    error = None
    paced0 = None                        # when the live view's pacing starts (after it waited for a client)
    try:
        if view is not None:
            view.start(sim)
            paced0 = time.perf_counter()
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
    out.setdefault("startup_seconds", startup)
    if paced0 is not None:
        # the stepping's own wall time and real-time factor stay as they are; the view's pacing is apart
        paced = time.perf_counter() - paced0
        out["paced_wall_seconds"] = paced
        out["paced_real_time_factor"] = sim.time / paced if paced > 0 else None
    if warnings:
        out["warnings"] = warnings
    if error:
        out["error"] = error
    if args.json:
        print(json_output(out))
    else:
        print(format_summary(scene, out))
    return 1 if error else 0


def format_summary(scene, out: dict) -> str:
    """The human-readable run summary. Values that are missing (None: no step taken, no steady window yet) or
    not finite print as '--', never as 'nan'."""
    def g(key, spec, scale=1.0):
        v = out.get(key)
        return finite_text(None if v is None else scale * v, spec)

    omega_T = out["omega_T"]
    lines = [f"scene {out['scene']}  n = {out['n_flagella']}  omega_T = {g('omega_T', '.4f')} rad/s "
             f"({g('omega_T', '.1f', 1 / RPM)} rpm)  t = {g('time', '.3f')} s"]
    if scene.clamped:
        tip = out.get("tip") or []
        lines += [f"  Fx  (axial force on the flagellum)  = {g('Fx', '+.6e')} N",
                  f"  Tx  (torque about the axis)        = {g('Tx', '+.6e')} N m",
                  "  tip (co-rotating frame)            = [" + ", ".join(finite_text(v, "+.6f") for v in tip) + "] m"]
    else:
        omega_h, v = out.get("omega_h"), out.get("v")
        share = 100 * omega_h / omega_T if omega_h is not None and omega_T else None
        lines += [f"  omega_h = {g('omega_h', '+.5f')} rad/s ({g('omega_h', '+.2f', 1 / RPM)} rpm, "
                  f"{finite_text(share, '.1f')}% of omega_T)",
                  f"  omega_t = {g('omega_t', '+.5f')} rad/s ({g('omega_t', '+.2f', 1 / RPM)} rpm)",
                  f"  v       = {g('v', '+.6e')} m/s ({g('v', '+.4f', 1e3)} mm/s, positive = head first)",
                  f"  normalised: omega_T_bar = {finite_text(scene.normalise_omega(omega_T), '.2f')}, "
                  f"v_bar = {finite_text(None if v is None else scene.normalise_speed(v), '.4f')}"]
    lines.append(f"  steady over the last {g('window', '.2f')} s: {'yes' if out.get('steady') else 'NO (run longer)'}")
    timing = f"{g('wall_seconds', '.2f')} s wall, real-time factor {g('real_time_factor', '.2f')}"
    if out.get("startup_seconds") is not None:
        timing += f", start-up {g('startup_seconds', '.2f')} s"
        if (out.get("compile_seconds") or 0.0) >= 0.05:
            timing += f" (compiling or loading kernels: {g('compile_seconds', '.2f')} s of it)"
    if out.get("paced_wall_seconds") is not None:
        timing += (f"; paced for the live view: {g('paced_wall_seconds', '.2f')} s wall, real-time factor "
                   f"{g('paced_real_time_factor', '.2f')}")
    lines.append(f"  {out['steps']} steps, {out['newton_iterations']} Newton iterations, "
                 f"{out['dt_reductions']} dt reductions, {timing}")
    for w in out.get("warnings", []):
        lines.append(f"  WARNING: {w}")
    if "error" in out:
        lines.append(f"  ERROR: {out['error']}")
    return "\n".join(lines)


def _command_in(argv: list[str]) -> str | None:
    """The subcommand named on the command line (the top-level parser's options, -h and --version, take no
    value)."""
    for item in argv:
        if not item.startswith("-"):
            return item
    return None


def _register_module(sub, name: str) -> bool:
    """Import command module ``name`` and let it add its subcommands; False when the module itself (or its
    package) is not installed. A missing dependency deeper down is a real error and propagates."""
    try:
        mod = importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name and name.startswith(exc.name):
            return False
        raise
    mod.register(sub)
    return True


def _placeholder(command: str, module: str):
    """``func`` of a command listed only for --help (never reached: the real parser is built when the
    command is on the command line)."""
    def run(args) -> int:
        raise SceneError(f"flagbot {command}: the module that provides it ({module}) is not installed")
    return run


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``flagbot`` parser, importing only what ``command`` needs.

    ``command`` None (``flagbot --help``): every lazy command is listed with its help line from
    :data:`COMMANDS`, none imported. A command from the table: only its module is imported and registers its full
    sub-parser. ``"*"`` or an unknown name: every module is imported (the old behaviour; an unknown name then gets
    argparse's own "invalid choice" message listing everything).
    """
    parser = argparse.ArgumentParser(prog="flagbot", description="flagbot_sim: soft flagellated robot simulator")
    add_version_argument(parser, "flagbot")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    p = sub.add_parser("run", help="run the DER simulation of a scene and report steady-state outputs")
    add_scene_arguments(p)
    p.add_argument("--duration", type=float, default=None, help="simulated seconds (default: the scene's)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a summary")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    if command is not None:             # flagbot --help lists the commands only: it imports nothing of them
        from .view.args import add_view_arguments
        add_view_arguments(p)
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("scenes", help="list built-in scenes and the scene keys with units and ranges")
    p.set_defaults(func=cmd_scenes)
    p = sub.add_parser("compile", help="compile the simulator's kernels into numba's on-disk cache now (first run "
                                       "only; later runs load them), saying how long it took",
                       description="Compile every kernel the simulator uses (or load them, when numba's on-disk "
                                   "cache already holds them) and say how long it took. Every command compiles on "
                                   "first use anyway; this makes it a step of its own, e.g. after an install, so "
                                   "that the first run, the demo's nodes and timed tests start warm. The cache is "
                                   "numba's: next to the package, or NUMBA_CACHE_DIR.")
    p.set_defaults(func=cmd_compile)
    p = sub.add_parser(
        "completion", help="print a bash or zsh completion script for flagbot and the ROS console scripts",
        description="Print a static shell completion script for flagbot, sim_node, beam_node, cmd_profile, record "
                    "and replay, generated from their argument parsers (docs/cli.md). bash: write it to a file and "
                    "source that from ~/.bashrc; zsh: the same from ~/.zshrc, after compinit.")
    p.add_argument("shell", choices=("bash", "zsh"), help="the shell to complete in")
    p.set_defaults(func=cmd_completion)
    if command in ("run", "scenes", "compile", "completion"):
        return parser
    if command is not None and command in COMMANDS:
        wanted = [COMMANDS[command][0]]
    elif command is None:
        wanted = []
    else:
        wanted = COMMAND_MODULES
    for name in wanted:
        _register_module(sub, name)
    present = set(sub.choices)
    for cmd, (module, help_text) in COMMANDS.items():
        if cmd not in present:
            q = sub.add_parser(cmd, help=help_text, add_help=False)
            q.set_defaults(func=_placeholder(cmd, module))
    return parser


def cmd_compile(args) -> int:
    from .kernels import compile_kernels, describe
    cache = os.environ.get("NUMBA_CACHE_DIR", "").strip()
    print(f"flagbot compile: every kernel of the simulator, into numba's cache "
          f"({'NUMBA_CACHE_DIR=' + cache if cache else 'its default: beside the package, or a per-user directory when that is read-only'})",
          flush=True)
    seconds, compiled = compile_kernels()
    print(describe(seconds, compiled))
    return 0


def cmd_scenes(args) -> int:
    import dataclasses

    from .scene import EFFECTS, SECTIONS, builtin_scenes, format_bounds
    print("built-in scenes:", ", ".join(builtin_scenes()))
    print("\neffects:")
    width = max(map(len, EFFECTS))
    for k, v in EFFECTS.items():
        print(f"  {k:{width}s}  {v}")
    rows = [("key", "default", "unit", "allowed", "meaning")]
    for s, cls in SECTIONS.items():
        for f in dataclasses.fields(cls):
            m = f.metadata
            default = f.default
            default = "[" + ", ".join(map(str, default)) + "]" if isinstance(default, tuple) else \
                (repr(default) if default == "" else str(default))
            if len(default) > 24:
                default = default[:21] + "..."
            rows.append((f"{s}.{f.name}", default, m["unit"] or "-", format_bounds(m) or "-", m["doc"]))
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    print("\nkeys:")
    for r in rows:
        print("  " + "  ".join(c.ljust(w) for c, w in zip(r[:4], widths)) + "  " + r[4])
    return 0


def cmd_completion(args) -> int:
    from .completion import script
    print(script(args.shell, build_parser("*")), end="")       # every command module imported: the whole tree
    return 0


def one_line(message: str, limit: int = MAX_ERROR_CHARS) -> str:
    """An error message as one line of at most ``limit`` characters."""
    text = " ".join(str(message).split())
    return text if len(text) <= limit else text[:limit - 15] + " ... (truncated)"


#: commands that hold no open resource when they return, so their process may skip the final garbage collection
FAST_EXIT = frozenset({"run", "scenes", "compile", "beam", "sweep-plot", "completion"})


def main(argv: list[str] | None = None) -> int:
    """The ``flagbot`` command. With ``argv`` None (the process's own command line: the console script,
    ``python -m flagbot_sim``) the process ends after it, and the compute-only commands exit fast."""
    from_command_line = argv is None
    argv = sys.argv[1:] if argv is None else list(argv)
    command = _command_in(argv)
    parser = build_parser(command)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except BrokenPipeError:
        return broken_pipe_exit()
    except KeyboardInterrupt:      # Ctrl-C anywhere else (e.g. during the first compile): one line, not numba's stack
        print(f"flagbot {args.command}: interrupted", file=sys.stderr)
        return 130
    except SceneError as exc:
        print(f"error: {one_line(exc)}", file=sys.stderr)
        return 2
    except ImportError as exc:     # an extra not installed (record, replay, demo without ROS 2; --view; dask)
        from .optional import MissingExtra, missing_ros, report_missing
        missing = exc if isinstance(exc, MissingExtra) else missing_ros(exc, f"flagbot {args.command}")
        if missing is None:
            raise
        return report_missing(missing)
    finally:
        if from_command_line and command in FAST_EXIT:
            fast_exit()
