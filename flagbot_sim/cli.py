"""Command line: ``python -m flagbot_sim COMMAND ...`` (also the ``flagbot`` console script).

Each command is a module of :mod:`flagbot_sim.commands` that registers itself here through a
``register(subparsers)`` function; this module only assembles them and turns known errors into one-line messages.

Start-up time matters (``flagbot run`` is often a short job), so the command modules are imported lazily: the
parser imports only the module that provides the command being run. ``flagbot --help`` lists every command from
:data:`COMMANDS` without importing any of them (scipy.optimize for the beam estimator, matplotlib, dask, rclpy);
a test checks that the table names exactly the commands the modules register.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from .cliutil import add_version_argument, broken_pipe_exit, fast_exit

#: command -> (module whose register(subparsers) adds it, one-line help for ``flagbot --help``)
COMMANDS: dict[str, tuple[str, str]] = {
    "steady": ("flagbot_sim.commands.steady", "solve the steady state (relative equilibrium) directly, without "
                                              "time stepping; with its stability"),
    "beam": ("flagbot_sim.commands.beam", "beam-theory estimate (LB / NLB w/o head / NLB) of omega_h, omega_t and "
                                          "speed for motor speeds omega_T"),
    "demo": ("flagbot_sim.commands.demo", "run sim_node + beam_node + a command profile and compare DER with beam "
                                          "theory"),
    "bench": ("flagbot_sim.commands.bench", "benchmarks: accuracy vs time, throughput, start-up time"),
    "sweep": ("flagbot_sim.commands.sweep", "parameter sweep: DER to steady state and the beam balance at every "
                                            "grid point, one tidy CSV, resumable, plus the paper's figures"),
    "sweep-plot": ("flagbot_sim.commands.sweep", "redraw a sweep's figures and summary from DIR/results.csv alone"),
    "fit": ("flagbot_sim.commands.fit", "fit scene constants (C1, C2, mu, ...) to measured steady states, 95%% "
                                        "intervals"),
    "optimize": ("flagbot_sim.commands.fit", "search designs (n, L, omega_rpm, ...) for the fastest or most "
                                             "efficient robot"),
    "record": ("flagbot_sim.commands.record", "record flagbot topics to MCAP (rosbag2 layout) until Ctrl-C"),
    "replay": ("flagbot_sim.commands.replay", "replay an MCAP recording with its timing and /clock"),
    "bag-summary": ("flagbot_sim.commands.bag", "topics, counts, duration and the steady state of each omega_T step"),
    "bag-recover": ("flagbot_sim.commands.bag", "rewrite the readable part of a damaged MCAP file into a valid one"),
    "render": ("flagbot_sim.commands.render", "draw the paper's Fig. 1 snapshots of the robot's shape from a run, "
                                              "a recording or a scene (PNG, or GIF animation)"),
}

#: modules that contribute subcommands, in the order they are registered when all are wanted
COMMAND_MODULES = list(dict.fromkeys(module for module, _ in COMMANDS.values()))

#: longest error message printed (a refused 1e6-element array must not be echoed back)
MAX_ERROR_CHARS = 600


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
        from .scene import SceneError
        raise SceneError(f"flagbot {command}: the module that provides it ({module}) is not installed")
    return run


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``flagbot`` parser, importing only what ``command`` needs.

    ``command`` None (``flagbot --help``): every lazy command is listed with its help line from
    :data:`COMMANDS`, none imported. A command from the table: only its module is imported and registers its full
    sub-parser. ``"*"`` or an unknown name: every module is imported (the old behaviour; an unknown name then gets
    argparse's own "invalid choice" message listing everything).
    """
    from .commands import compile as compile_command, completion, run, scenes   # small, and always listed
    parser = argparse.ArgumentParser(prog="flagbot", description="flagbot_sim: soft flagellated robot simulator")
    add_version_argument(parser, "flagbot")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    run.register(sub, view_options=command is not None)   # flagbot --help: the commands only, none of their imports
    scenes.register(sub)
    compile_command.register(sub)
    completion.register(sub, lambda: build_parser("*"))     # every command module imported: the whole tree
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


def one_line(message: str, limit: int = MAX_ERROR_CHARS) -> str:
    """An error message as one line of at most ``limit`` characters."""
    text = " ".join(str(message).split())
    return text if len(text) <= limit else text[:limit - 15] + " ... (truncated)"


#: commands that hold no open resource when they return, so their process may skip the final garbage collection
FAST_EXIT = frozenset({"run", "scenes", "compile", "beam", "sweep", "sweep-plot", "completion"})


def main(argv: list[str] | None = None) -> int:
    """The ``flagbot`` command. With ``argv`` None (the process's own command line: the console script,
    ``python -m flagbot_sim``) the process ends after it, and the compute-only commands exit fast."""
    from_command_line = argv is None
    if from_command_line:
        from .physics.blas import single_threaded_process
        single_threaded_process()          # small matrices everywhere: BLAS threads only spin (physics/blas.py)
    argv = sys.argv[1:] if argv is None else list(argv)
    command = _command_in(argv)
    if from_command_line and command == "sweep":
        from . import workers
        if workers.wants_local_engine(argv[argv.index(command) + 1:]):
            workers.start()             # its workers load (~1.3 s) while this process imports and reads its scene
    from .scene import SceneError
    parser = build_parser(command)
    args = parser.parse_args(argv)
    try:
        rc = int(args.func(args) or 0)
        if from_command_line:
            sys.stdout.flush()         # a block-buffered stdout meets a reader gone away here, not at the exit
        return rc
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
