"""cmd_profile: drive the robot without writing code, by publishing an omega_T profile on ``cmd_omega``.

    cmd_profile constant 100 --rpm
    cmd_profile steps 50:20,100:20,150:20 --rpm --sim-time     # value:seconds pairs, timed on /clock
    cmd_profile ramp 0 250 60 --rpm
    cmd_profile square 0 250 10 3 --rpm                        # low high period [cycles]

Values are rad/s unless --rpm. With --sim-time the profile follows /clock (use it when the simulator runs
faster or slower than real time). At the end the last value is held, unless --exit-at-end.
"""
from __future__ import annotations

import argparse
import sys

import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from std_msgs.msg import Float64

from ..motor_profile import ProfileError, parse
from ..units import RPM
from .. import topics as names
from .bag_args import add_profile_arguments, script_parser
from .runtime import RosArgsError, run_node, user_args


def build_parser() -> argparse.ArgumentParser:
    return script_parser("cmd_profile", __doc__, add_profile_arguments,
                         formatter_class=argparse.RawDescriptionHelpFormatter)


class ProfileNode(Node):
    def __init__(self, profile, rate: float, sim_time: bool, exit_at_end: bool, quiet: bool,
                 t0: float | None = None):
        overrides = [Parameter("use_sim_time", Parameter.Type.BOOL, True)] if sim_time else []
        super().__init__("cmd_profile", parameter_overrides=overrides)
        self.profile = profile
        self.exit_at_end = exit_at_end
        self.quiet = quiet
        self.pub = self.create_publisher(Float64, names.CMD_OMEGA, QoSProfile(depth=10))
        self.t0 = t0
        self.last = None
        self.done = False
        self.create_timer(1.0 / rate, self._tick)

    def _tick(self) -> None:
        now = self.get_clock().now().nanoseconds * 1e-9
        if self.t0 is None:
            self.t0 = now
        t = now - self.t0
        w = self.profile.value(t)
        self.pub.publish(Float64(data=w))
        if w != self.last and not self.quiet:
            print(f"t = {t:8.3f} s  cmd_omega = {w:+.4f} rad/s ({w / RPM:+.2f} rpm)", flush=True)
        self.last = w
        if self.exit_at_end and not self.profile.loop and t >= self.profile.duration and not self.done:
            self.done = True
            rclpy.shutdown()


def main(argv: list[str] | None = None) -> int:
    process_exit = argv is None             # the console script / python -m: the process ends with this
    argv = sys.argv if argv is None else argv
    try:
        own = user_args(argv)
    except RosArgsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    args = build_parser().parse_args(own)
    if not (0.1 <= args.rate <= 1000.0):
        print(f"error: --rate must be within [0.1, 1000] Hz, got {args.rate:g}", file=sys.stderr)
        return 2
    try:
        profile = parse(args.kind, args.args, rpm=args.rpm, loop=args.loop)
    except ProfileError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return run_node(lambda: ProfileNode(profile, args.rate, args.sim_time, args.exit_at_end, args.quiet, args.t0),
                    argv, process_exit=process_exit)


if __name__ == "__main__":
    sys.exit(main())
