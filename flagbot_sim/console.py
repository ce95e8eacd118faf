"""Console-script targets of the ROS processes (setup.py ``entry_points``): without ROS 2 each prints one line
naming the ``[ros]`` extra (:func:`flagbot_sim.optional.missing_ros`) instead of a traceback, and exits with
:data:`flagbot_sim.optional.EXIT_CODE`. ``--version`` is answered here, before ROS 2 is imported, so that it
works (and is quick) on a machine without ROS 2 too.

Kept apart from :mod:`flagbot_sim.optional` so that that module stays a leaf: these targets load the ROS nodes by
name, and a module that may be imported by those nodes (the live view, through ``optional.require``) must not
depend on them back.
"""
from __future__ import annotations

import importlib
import sys

from .cliutil import broken_pipe_exit, version_text
from .optional import EXIT_CODE, MissingExtra, missing_ros, report_missing


def own_arguments(argv: list[str]) -> list[str]:
    """The program's own arguments: ``argv`` (without argv[0]) less its ``--ros-args ... [--]`` sections, by the
    rule ROS 2 documents for them. (The nodes themselves use rclpy's ``remove_ros_args``; this runs before rclpy
    is imported, to answer ``--version`` without ROS 2.)"""
    own, in_ros = [], False
    for a in argv:
        if a == "--ros-args":
            in_ros = True
        elif in_ros and a == "--":
            in_ros = False
        elif not in_ros:
            own.append(a)
    return own


def ros_entry(module: str, prog: str, needs: str | None = None):
    """A console-script ``main`` for a ROS process: ``--version`` prints :func:`~flagbot_sim.cliutil.version_text`;
    without ROS 2 it prints one line and exits :data:`~flagbot_sim.optional.EXIT_CODE` instead of a traceback;
    otherwise it runs ``module.main``. ``needs``: a ROS module imported first, for a ``module`` that imports ROS 2
    only when it runs (the ``replay`` command) but whose console script needs it either way."""
    def main() -> int:
        if "--version" in own_arguments(sys.argv[1:]):
            print(version_text(prog))
            return 0
        from .physics.blas import single_threaded_process
        single_threaded_process()          # small matrices everywhere: BLAS threads only spin (physics/blas.py)
        try:
            if needs is not None:
                importlib.import_module(needs)
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if (missing := missing_ros(exc, prog)) is None:
                raise
            return report_missing(missing)
        except ImportError as exc:
            if not _from_ros(exc):
                raise
            # rclpy is there but its C libraries do not load (e.g. the wheels' library path is not set up)
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            print(f"error: {prog}: ROS 2 is installed but cannot be loaded: {first} (see docs/install.md: "
                  "the ROS 2 wheels set their library path when Python starts)", file=sys.stderr)
            return EXIT_CODE                    # the [ros] extra is there but unusable: as if it were missing
        try:
            return mod.main()
        except BrokenPipeError:                 # sim_node --help | head -3
            return broken_pipe_exit()
        except MissingExtra as exc:             # replay --view without the [view] extra
            return report_missing(exc)
    main.__name__ = main.__qualname__ = prog
    return main


def _from_ros(exc: BaseException) -> bool:
    """Whether an ImportError was raised while importing ROS 2 itself (a frame inside rclpy or rpyutils)."""
    import traceback
    return any(("/rclpy/" in f.filename or "/rpyutils/" in f.filename)
               for f in traceback.extract_tb(exc.__traceback__))


# console-script targets (setup.py entry_points): the ROS processes go through ros_entry
sim_node = ros_entry("flagbot_sim.ros.sim_node", "sim_node")
beam_node = ros_entry("flagbot_sim.ros.beam_node", "beam_node")
cmd_profile = ros_entry("flagbot_sim.ros.cmd_profile", "cmd_profile")
record = ros_entry("flagbot_sim.ros.recorder", "record")
replay = ros_entry("flagbot_sim.commands.replay", "replay", needs="flagbot_sim.ros.replay")
