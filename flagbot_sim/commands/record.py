"""``flagbot record``: record flagbot topics to MCAP (the ROS recorder, :mod:`flagbot_sim.ros.recorder`).

rclpy is imported only when the command runs; the arguments are those of the ``record`` console script
(:mod:`flagbot_sim.ros.bag_args`, ROS-free).
"""
from __future__ import annotations

from ..bag import BagError
from ..ros.bag_args import add_record_arguments, fail  # ROS-free: no rclpy import


def cmd_record(args) -> int:
    try:
        from ..ros.recorder import run
        return run(args, ros_args=["record"])
    except BagError as exc:
        return fail(exc)


def register(subparsers) -> None:
    p = subparsers.add_parser("record", help="record flagbot topics to MCAP (rosbag2 layout) until Ctrl-C")
    add_record_arguments(p)
    p.set_defaults(func=cmd_record)
