"""``flagbot bag-summary`` (:mod:`flagbot_sim.runs.summary`) and ``flagbot bag-recover``
(:func:`flagbot_sim.bag.recover`): recordings read from the MCAP file alone, no ROS."""
from __future__ import annotations

from pathlib import Path

from ..bag import BagError, recover
from ..cliutil import check_figure_file, check_out_file, json_output
from ..ros.bag_args import fail  # ROS-free: no rclpy import


def cmd_recover(args) -> int:
    out = args.output or str(Path(args.bag).with_suffix("")) + ".recovered.mcap"
    check_out_file(out, "--output")                   # before the damaged file is scanned
    try:
        rep = recover(args.bag, out, overwrite=args.overwrite)
    except BagError as exc:
        return fail(exc)
    print(rep.describe_loss() or f"{args.bag}: intact, nothing lost")
    print(f"wrote {out}: {rep.messages} messages, valid and indexed")
    return 0


def cmd_summary(args) -> int:
    from ..runs.summary import format_summary, plot_summary, summarize
    if args.plot:
        check_figure_file(args.plot, "--plot")       # before the file is read: a refusal is one line, exit 2
    try:
        s = summarize(args.bag, namespace=args.namespace, tail=args.tail, time_axis=args.time)
    except BagError as exc:
        return fail(exc)
    if args.plot:
        plot_summary(s, args.plot)
    if args.json:
        s = dict(s)
        s.pop("series")
        print(json_output(s))
    else:
        print(format_summary(s))
        if args.plot:
            print(f"plot: {args.plot}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser("bag-summary", help="topics, counts, duration and the steady state of each omega_T step")
    p.add_argument("bag")
    p.add_argument("--plot", metavar="PNG", help="write a plot of v, omega_h, omega_t over time")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--tail", type=float, default=0.25, help="fraction of each step averaged as steady (default 0.25)")
    p.add_argument("--time", choices=["auto", "sim", "log"], default="auto",
                   help="time axis: sim (from /clock), log (receive time) or auto (sim if /clock was recorded)")
    p.add_argument("--namespace", default=None, help="robot namespace (default: found from the topics)")
    p.set_defaults(func=cmd_summary)
    p = subparsers.add_parser("bag-recover", help="rewrite the readable part of a damaged MCAP file into a valid one")
    p.add_argument("bag")
    p.add_argument("-o", "--output", help="output file (default: BAG.recovered.mcap)")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=cmd_recover)
