"""Command-line arguments of the recorder (:mod:`.recorder`), the replayer (:mod:`.replay`) and the command
profile (:mod:`.cmd_profile`), and the frame of their console scripts.

Kept out of those modules because they import rclpy at load time, and ``flagbot``'s parser (which offers
``flagbot record`` and ``flagbot replay`` with these same arguments) and ``flagbot completion`` must not:
building it for ``flagbot run`` would cost the rclpy import. Both the console scripts and the commands
(:mod:`flagbot_sim.commands.record`, :mod:`flagbot_sim.commands.replay`) take the arguments from here; nothing
here imports either of them back.
"""
from __future__ import annotations

import argparse
import sys
from typing import Callable

from ..bag import BagError
from ..cliutil import add_version_argument


def add_record_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of :func:`flagbot_sim.ros.recorder.run`."""
    p.add_argument("topics", nargs="*", help="topics to record (relative names follow --namespace); default: every "
                                             "flagbot topic (flagbot_sim.topics.DEFAULT_RECORD_TOPICS)")
    p.add_argument("-o", "--output", help="output .mcap file (default: flagbot_YYYYmmdd_HHMMSS.mcap)")
    p.add_argument("-a", "--all", action="store_true", help="record every topic currently or later visible")
    p.add_argument("--exclude", action="append", metavar="REGEX", help="do not record topics matching REGEX")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (> 0)")
    p.add_argument("--scene", help="scene (built-in name or .toml) to store in the file's metadata")
    p.add_argument("--params-from", metavar="NODE", help="store all parameters of this node (e.g. /sim_node), and "
                                                         "the text of the scene its `scene` parameter names")
    p.add_argument("--metadata", action="append", metavar="KEY=VALUE", help="extra metadata to store")
    p.add_argument("--compression", choices=["zstd", "lz4", "none"], default="zstd", help="chunk compression")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.add_argument("--namespace", default="", help="namespace of the recorder node (relative topics resolve in it)")
    p.add_argument("--node-name", default="flagbot_recorder")


def add_replay_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of :func:`flagbot_sim.ros.replay.run` and, with ``--resimulate``, of
    :func:`flagbot_sim.commands.replay.cmd_resimulate`."""
    p.add_argument("bag", help="MCAP file (or a rosbag2 directory holding one)")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed factor (2 = twice as fast)")
    p.add_argument("--loop", action="store_true", help="start again at the end until interrupted")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="replay only these topics (names or regexes)")
    p.add_argument("--exclude", nargs="+", metavar="TOPIC", help="do not replay these topics (names or regexes)")
    p.add_argument("--start-offset", type=float, default=0.0, metavar="S",
                   help="start this many seconds after the first message")
    p.add_argument("--no-clock", action="store_true",
                   help="do not publish a /clock derived from log time when the recording has no /clock")
    p.add_argument("--clock-rate", type=float, default=100.0, metavar="HZ", help="rate of the derived /clock")
    p.add_argument("--wait-for-subscribers", type=float, default=0.0, metavar="S",
                   help="before starting, wait up to S seconds until every replayed topic has a subscriber")
    p.add_argument("--delay", type=float, default=0.0, metavar="S", help="sleep S seconds before starting")
    p.add_argument("--namespace", default="")
    p.add_argument("--node-name", default="flagbot_replay")
    p.add_argument("--resimulate", action="store_true",
                   help="no ROS: feed the recorded commands to a fresh simulator with the recorded scene, report "
                        "the largest difference in pose, omega_h and omega_t against the recording and a verdict "
                        "(exit 1 when it exceeds the solver tolerance)")
    p.add_argument("--json", action="store_true", help="with --resimulate: print the report as JSON")
    from ..view.args import add_view_arguments    # --view: no ROS, the recording played into the Foxglove view
    add_view_arguments(p, pacing=False)


def add_profile_arguments(ap: argparse.ArgumentParser) -> None:
    """Arguments of ``cmd_profile`` (:mod:`.cmd_profile`, which imports rclpy at load time)."""
    ap.add_argument("kind", choices=["constant", "steps", "ramp", "square"])
    ap.add_argument("args", nargs="+", help="the profile's values (see above)")
    ap.add_argument("--rpm", action="store_true", help="values are in rpm (default rad/s)")
    ap.add_argument("--rate", type=float, default=10.0, help="publication rate in Hz (default 10)")
    ap.add_argument("--sim-time", action="store_true", help="time the profile on /clock (use_sim_time)")
    ap.add_argument("--t0", type=float, default=None,
                    help="clock time at which the profile starts (default: the first tick)")
    ap.add_argument("--loop", action="store_true", help="repeat the profile")
    ap.add_argument("--exit-at-end", action="store_true", help="exit when the profile ends")
    ap.add_argument("--quiet", action="store_true", help="do not print the segments as they start")


def fail(exc: Exception) -> int:
    """A known error as one line on stderr; exit code 2."""
    print(f"error: {exc}", file=sys.stderr)
    return 2


def script_parser(prog: str, description: str, add_arguments: Callable[[argparse.ArgumentParser], None],
                  **kwargs) -> argparse.ArgumentParser:
    """The parser of the console script ``prog`` (``record``, ``replay``, ``cmd_profile``): its arguments and
    ``--version``. Also what ``flagbot completion`` reads (flagbot_sim/completion.py)."""
    parser = argparse.ArgumentParser(prog=prog, description=description, **kwargs)
    add_arguments(parser)
    add_version_argument(parser, prog)
    return parser


def console_main(prog: str, description: str, add_arguments: Callable[[argparse.ArgumentParser], None],
                 run: Callable[..., int], argv: list[str] | None) -> int:
    """The ``record`` / ``replay`` console scripts: argparse on the non-ROS arguments, ROS arguments passed on
    to ``run(args, ros_args=...)``."""
    from rclpy.utilities import remove_ros_args
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = script_parser(prog, description, add_arguments)
    args = parser.parse_args(remove_ros_args([prog] + argv)[1:])
    try:
        return run(args, ros_args=[prog] + argv)
    except BagError as exc:
        return fail(exc)
