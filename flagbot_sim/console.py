"""Console-script targets of the ROS processes (setup.py ``entry_points``): without ROS 2 each prints one line
naming the ``[ros]`` extra (:func:`flagbot_sim.optional.missing_ros`) instead of a traceback.

Kept apart from :mod:`flagbot_sim.optional` so that that module stays a leaf: these targets load the ROS nodes by
name, and a module that may be imported by those nodes (the live view, through ``optional.require``) must not
depend on them back.
"""
from __future__ import annotations

import importlib
import sys

from .cliutil import broken_pipe_exit
from .optional import missing_ros


def ros_entry(module: str, prog: str):
    """A console-script ``main`` for a ROS process: without ROS 2 it prints one line and exits 1 instead of a
    traceback; otherwise it runs ``module.main``."""
    def main() -> int:
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if (missing := missing_ros(exc, prog)) is None:
                raise
            print(missing, file=sys.stderr)
            return 1
        except ImportError as exc:
            if not _from_ros(exc):
                raise
            # rclpy is there but its C libraries do not load (e.g. the wheels' library path is not set up)
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            print(f"error: {prog}: ROS 2 is installed but cannot be loaded: {first} (see the README's Install "
                  "section: the ROS 2 wheels set their library path when Python starts)", file=sys.stderr)
            return 1
        try:
            return mod.main()
        except BrokenPipeError:                 # sim_node --help | head -3
            return broken_pipe_exit()
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
replay = ros_entry("flagbot_sim.ros.replay", "replay")
