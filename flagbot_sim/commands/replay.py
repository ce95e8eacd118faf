"""``flagbot replay`` and the ``replay`` console script: one dispatch for both.

``replay BAG`` republishes a recording over ROS 2 (:mod:`flagbot_sim.ros.replay`); ``--resimulate`` re-runs its
commands through the simulator and compares the motion (:mod:`flagbot_sim.runs.resim`, no ROS); ``--view`` plays it
into the Foxglove live view (:mod:`flagbot_sim.view.replay`, no ROS). rclpy is imported only for the ROS replay.
"""
from __future__ import annotations

import math
import sys

from ..bag import BagError
from ..ros.bag_args import add_replay_arguments, console_main, fail  # ROS-free: no rclpy import


def cmd_replay(args, ros_args: list[str] | None = None) -> int:
    """A ROS replay, or with ``--resimulate`` a re-simulation, or with ``--view`` a replay into the live view (no
    ROS for either: rclpy is not loaded). ``ros_args``: the console script's command line, for rclpy."""
    if args.resimulate:
        return cmd_resimulate(args)
    if args.view:
        return cmd_replay_view(args)
    for flag in ("delay", "wait_for_subscribers"):      # before ROS starts: nothing to undo
        value = getattr(args, flag)
        if not (math.isfinite(value) and value >= 0.0):
            return fail(ValueError(f"--{flag.replace('_', '-')} must be a finite number of seconds >= 0, got {value}"))
    try:
        from ..ros.replay import run
        return run(args, ros_args=ros_args or ["replay"])
    except BagError as exc:
        return fail(exc)


def cmd_resimulate(args) -> int:
    """``replay --resimulate BAG [--json] [--namespace NS]``: the report and its verdict; exit 0 when the whole
    recording is reproduced, 1 when it differs or only part of it could be compared (PARTIAL, NOT CHECKED), 2 when
    it cannot be re-simulated."""
    from ..cliutil import json_output
    from ..progress import ProgressBar
    from ..runs.resim import ResimulationError, format_report, resimulate
    try:
        bar = ProgressBar(100.0, label="re-simulating", unit="%", enabled=not args.json)
        res = resimulate(args.bag, args.namespace or None, progress=lambda f: bar.update(100.0 * f))
        bar.close()
    except (BagError, ResimulationError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json_output({"bag": str(args.bag), **res.to_dict()}))
    else:
        print(format_report(res, args.bag))
    return 0 if res.reproduced else 1


def cmd_replay_view(args) -> int:
    """``replay BAG --view [--rate R] [--loop] [--start-offset S] [--view-port P] [--view-wait S]``."""
    from ..runs.resim import ResimulationError
    from ..view.cli import open_live_view, wait_or_note
    from ..view.recorded import load
    from ..view.replay import play
    try:
        run = load(args.bag, args.namespace or None)
    except (BagError, ResimulationError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for n in run.notes:
        print(f"note: {n}", file=sys.stderr)
    view = open_live_view(args)
    try:
        wait_or_note(view, args.view_wait, "playing")
        try:
            shown = play(run, view, rate=args.rate, loop=args.loop, start_offset=args.start_offset)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            shown = None
    finally:
        view.close()
    span = run.frames[-1].t - run.frames[0].t
    sent = "interrupted" if shown is None else f"sent {shown} of {len(run.frames)} frames to the view"
    print(f"{sent} ({run.source}, {span:.3f} s of simulated time)", flush=True)
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser("replay", help="replay an MCAP recording with its timing and /clock")
    add_replay_arguments(p)
    p.set_defaults(func=cmd_replay)


def main(argv: list[str] | None = None) -> int:
    """``replay`` console script: ``replay BAG [--rate R] [--loop] [--topics ...] [--exclude ...] [--ros-args ...]``
    (``--resimulate``, ``--view``: no ROS, as ``flagbot replay``)."""
    return console_main("replay", "Replay an MCAP recording with its timing.", add_replay_arguments, cmd_replay, argv)


if __name__ == "__main__":
    sys.exit(main())
