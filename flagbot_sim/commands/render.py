"""``flagbot render``: the paper's Fig. 1 (snapshots of the robot's shape) from recordings or scenes simulated on
the fly, drawn by :mod:`flagbot_sim.view.render` (the layouts, ``--layout``, and the default times are described
there)."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from ..scene import SceneError, load_scene
from ..units import RPM
from ..view.render import (DEFAULT_SNAPSHOTS, LAYOUTS, RenderError, animation, common_times, design_name, groups_of,
                           Row, is_recording, recorded_row, run_up, simulate_row, take_row)


def _floats(text: str, what: str) -> list[float]:
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise RenderError(f"{what} must be a comma list of numbers, got {text!r}") from None
    if not vals or not all(math.isfinite(v) for v in vals):
        raise RenderError(f"{what} must be a comma list of finite numbers, got {text!r}")
    return vals


def add_render_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("sources", nargs="+", metavar="RUN_OR_BAG",
                   help="a recording (.mcap, or a rosbag2 directory holding one), one row each; or a scene "
                        "(built-in name or .toml) simulated on the fly, one row per --n value")
    p.add_argument("--out", "-o", required=True, metavar="PNG", help="the figure (PNG, SVG or PDF by its suffix)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene value of the simulated sources, e.g. --set motor.omega_rpm=150")
    p.add_argument("--n", default=None, metavar="LIST",
                   help="numbers of flagella of the simulated rows (default 2,3 as in the paper; a clamped "
                        "scene: its own)")
    p.add_argument("--times", default=None, metavar="LIST",
                   help="snapshot times in simulated seconds, e.g. 10,12,14,16,18 (default: one flagellar "
                        "revolution once steady, in --snapshots equal steps)")
    p.add_argument("--snapshots", type=int, default=DEFAULT_SNAPSHOTS, metavar="K",
                   help=f"snapshots per row with the default times (default {DEFAULT_SNAPSHOTS})")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="a simulated source runs until steady or S seconds (default: the scene's time.duration) "
                        "before the snapshots")
    p.add_argument("--title", default=None, help="figure title (default: the design and the motor speed)")
    p.add_argument("--width", type=float, default=16.0, metavar="IN", help="figure width in inches (default 16)")
    p.add_argument("--dpi", type=float, default=150.0, help="resolution of a PNG (default 150)")
    p.add_argument("--gif", default=None, metavar="GIF", help="also write an animation of the same window")
    p.add_argument("--frames", type=int, default=40, metavar="K", help="frames of the --gif (default 40)")
    p.add_argument("--fps", type=float, default=10.0, help="frames per second of the --gif (default 10)")
    p.add_argument("--namespace", default=None, help="robot namespace in a recording (default: found)")
    p.add_argument("--layout", choices=list(LAYOUTS), default="per-design",
                   help="per-design (default): a row per n or recording, side and end views, panels (1), (2), ...; "
                        "paper: the paper's Fig. 1, a row per design ((a) design 1, (b) design 2, as its caption "
                        "says), each panel the side views of that design's n = 2 and n = 3 at one time")


def build_rows(args, log=None) -> tuple[list[Row], str]:
    """The rows the arguments ask for, and a default title. With ``--layout paper`` the rows of one scene are
    simulated side by side to their steady states and then share their snapshot times (:func:`common_times`)."""
    if args.snapshots < 1:
        raise RenderError(f"--snapshots must be >= 1, got {args.snapshots}")
    if args.frames < 0 or (args.gif and args.frames < 2):
        raise RenderError(f"--frames must be >= 2 with --gif, got {args.frames}")
    paper = getattr(args, "layout", "per-design") == "paper"
    times = _floats(args.times, "--times") if args.times else None
    frames = args.frames if args.gif else 0
    rows, titles = [], []
    for src in args.sources:
        if is_recording(src):
            rows.append(recorded_row(src, times=times, snapshots=args.snapshots, frames=frames,
                                     namespace=args.namespace))
            titles.append(f"recording {Path(src).name}")
            continue
        base = load_scene(src, args.overrides)
        ns = [int(n) for n in _floats(args.n, "--n")] if args.n else ([base.robot.n_flagella] if base.clamped
                                                                     else [2, 3])
        scenes = [base.with_overrides({"robot.n_flagella": n}) if n != base.robot.n_flagella else base for n in ns]
        if paper and times is None:
            ups = []
            for sc in scenes:
                if log is not None:
                    log(f"simulating {base.scene.name} with n = {sc.robot.n_flagella} ...")
                ups.append(run_up(sc, duration=args.duration))
            shared = common_times([sim for sim, _ in ups], [out for _, out in ups], args.snapshots)
            rows += [take_row(sim, shared, frames=frames, out=out) for sim, out in ups]
        else:
            for sc in scenes:
                if log is not None:
                    log(f"simulating {base.scene.name} with n = {sc.robot.n_flagella} ...")
                rows.append(simulate_row(sc, times=times, snapshots=args.snapshots, duration=args.duration,
                                         frames=frames))
        if paper:
            titles.append(f"{design_name(base.scene.name)} at $\\omega_T$ = {base.omega_T / RPM:.0f} rpm")
        else:
            head = f", $R_h$ = {1e3 * base.head.radius:.0f} mm" if not base.clamped else ""
            titles.append(f"scene {base.scene.name} ($L$ = {1e3 * base.flagellum.length:.0f} mm{head}, $L_p$ = "
                          f"{1e3 * base.plate.diameter:.0f} mm), $\\omega_T$ = {base.omega_T / RPM:.0f} rpm")
    if paper:
        when = ("at the times given" if times else "once steady, each design's robots at the same times, over "
                "one turn of the slower flagella")
        return rows, "Fig. 1, a row per design: " + "; ".join(titles) + "; " + when
    when = ("at the times given" if times else
            "over one flagellar revolution after the run-up to steady state (steps of $2\\pi/\\omega_t$)")
    return rows, "; ".join(titles) + ": " + when


def _saved_size(path, fig, dpi) -> tuple[int, int]:
    """Pixel size of the image as written (a PNG's header says; matplotlib rounds the inches x dpi down)."""
    import struct
    try:
        with open(path, "rb") as fh:
            head = fh.read(24)
        if head[:8] == b"\x89PNG\r\n\x1a\n":
            return struct.unpack(">II", head[16:24])
    except OSError:
        pass
    return int(fig.get_size_inches()[0] * dpi), int(fig.get_size_inches()[1] * dpi)


def check_outputs(args) -> None:
    """--out and --gif can be written (directory there, a format the suffix names), before anything is simulated
    or read: a bad path is one line and exit 2, not a traceback after the work."""
    from ..cliutil import check_figure_file, check_out_file
    check_figure_file(args.out, "--out")
    if args.gif:
        gif = check_out_file(args.gif, "--gif")
        if gif.suffix.lower() != ".gif":
            raise RenderError(f"--gif {gif}: the animation is a GIF; give a file name ending in .gif")
        if gif.resolve() == Path(args.out).resolve():
            raise RenderError(f"--gif {gif}: is the --out file too; give the animation its own name")


def cmd_render(args) -> int:
    try:
        check_outputs(args)
        rows, title = build_rows(args, log=lambda m: print(m, file=sys.stderr, flush=True))
        fig = LAYOUTS[args.layout](rows, title=args.title if args.title is not None else title, width=args.width,
                                   dpi=args.dpi)
        fig.savefig(args.out, dpi=args.dpi)
        w, h = _saved_size(args.out, fig, args.dpi)
        print(f"wrote {args.out}: {len(rows)} row(s) x {len(rows[0].snapshots)} snapshots, {w} x {h} px")
        several = len(groups_of(rows)) > 1
        for r in rows:
            print("  " + (f"{design_name(r.group)}, " if several else "")
                  + r.caption().replace("$", "").replace("\\omega", "omega"))
        if args.gif:
            n = animation(rows, args.gif, fps=args.fps, title=args.title or "")
            print(f"wrote {args.gif}: {n} frames at {args.fps:g} fps")
    except (RenderError, SceneError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:
        from ..bag import BagError
        from ..runs.resim import ResimulationError
        if isinstance(exc, (BagError, ResimulationError)):
            print(f"error: {exc}", file=sys.stderr)
            return 2
        raise
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "render", help="the paper's Fig. 1: snapshots of the robot's shape (side and end views, to scale, 2 cm bar)",
        description="Rows of snapshots of the robot's shape at chosen times, side and end views, drawn to scale from "
                    "the node positions of a recording (.mcap) or of a scene simulated on the fly (one row per "
                    "--n value), with omega_T, omega_h, omega_t and v in the caption. --gif writes an animation.")
    add_render_arguments(p)
    p.set_defaults(func=cmd_render)
