"""The paper's Fig. 1 (snapshots of the robot's shape) from a recording or a simulated scene: the rows, the two
layouts and the animation that ``flagbot render`` (:mod:`flagbot_sim.commands.render`) draws.

Two layouts (``--layout``). ``paper`` is the paper's Fig. simulationSnapshots: a row per design, (a) design 1 and
(b) design 2 as its caption says, each panel (a1), (a2), ... the side views of that design's n = 2 and n = 3 at one
time (:func:`paper_figure`). ``per-design`` (the default, :func:`figure`): one row per source (a recording, or a
scene simulated on the fly once per ``--n`` value), one column per snapshot time, panels numbered (1), (2), ...;
each column has a side view (world x to the right, z up, seen from -y) above an end view (seen from behind the
tail, looking along +x: -y to the right, z up). Everything is drawn to one scale, in metres of the world frame: the head
as a disc of radius R_h (a sphere projects to one) with its black spin marker when on the visible side, the plate
as the outline of its disc, each flagellum as a stroke through its nodes whose width is the flagellum's true
diameter 2 r0, flagellum 0's tip red (the experiments marked one flagellum red). A dashed line marks where the
head's front was at the row's first snapshot, so the swimming shows; the caption gives each row's omega_T, omega_h,
omega_t and v (steady values: the simulation's steady-state window, or the recording's command step).

Default times: once the run is steady (or at the end of ``--duration``), one revolution of the flagella
(2 pi / omega_t) split into ``--snapshots`` equal steps, so the columns show the flagella at equally spaced phases
of their turn; ``--times`` picks them instead (a recording: the nearest recorded markers). ``--gif`` animates the
same window (side and end view of every row).

The drawing functions return matplotlib ``Figure`` objects built with the object-oriented API (no pyplot state);
every drawn robot part carries a ``gid`` naming it (``flagellum/<i>``, ``head``, ``plate``, ``scalebar``) so tests
can compare the plotted coordinates with the state they came from.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..units import RPM
from .geometry import RobotGeometry

#: what each view's screen axes are in the world frame: (right, up), and the viewing direction (depth)
VIEWS = {"side": (np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])),
         "end": (np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))}
HEAD_FACE, HEAD_EDGE = "#f2cc1a", "#6b5a00"
FLAGELLUM = ["#14692f", "#2e8b57", "#4f7f1f", "#1f6f6f", "#5a7d2a"]
TIP = "#d41a1a"
PLATE_FACE, PLATE_EDGE = "#b9b9bf", "#55555a"
SCALE_BAR = 0.02          # m: the paper's black bar is 2 cm
MARGIN = 0.008            # m of blank around the drawn robot in each panel
DEFAULT_SNAPSHOTS = 5


class RenderError(ValueError):
    pass


@dataclass
class Row:
    """One row of the figure: the robot at the snapshot times (and, for a GIF, at the frame times)."""
    label: str                        # "n = 2" (or the recording's name)
    snapshots: list                   # RobotGeometry, one per column
    values: dict                      # steady omega_T, omega_h, omega_t, v (SI) for the caption
    steady: bool = True
    frames: list = field(default_factory=list)   # RobotGeometry for the animation
    note: str = ""
    source: str = ""                  # the recording's file name (shown in the caption)
    group: str = ""                   # the design (scene name) it belongs to: a row of the paper's layout
    scene: object = None              # its Scene, when known (the paper layout's row header gives its sizes)

    def caption(self) -> str:
        v = self.values
        s = (rf"{self.label}{f' ({self.source})' if self.source else ''}: $\omega_T$ = {v['omega_T'] / RPM:.0f} rpm ({v['omega_T']:.2f} rad/s), "
             rf"$\omega_h$ = {v['omega_h']:.3f} rad/s, $\omega_t$ = {v['omega_t']:.3f} rad/s, "
             rf"$v$ = {1e3 * v['v']:.3f} mm/s")
        if not self.steady:
            s += " (not steady yet)"
        return s + (f"; {self.note}" if self.note else "")


# ------------------------------------------------------------------------------------------------ the times
def revolution_times(t_start: float, omega_t: float, count: int) -> list[float]:
    """``count`` equally spaced times over one flagellar revolution from ``t_start`` (the phases 0, 1/count, ...
    of a turn); a robot whose flagella do not turn gets ``count`` steps of 1 s."""
    period = 2.0 * math.pi / abs(omega_t) if abs(omega_t) > 1e-6 else float(count)
    return [t_start + k * period / count for k in range(count)]


def _window(times: list[float], count: int) -> list[float]:
    """``count`` equally spaced times from the first snapshot to one snapshot step past the last (for the GIF)."""
    if len(times) == 1:
        return list(times)
    step = (times[-1] - times[0]) / (len(times) - 1)
    t_end = times[-1] + step
    return [times[0] + k * (t_end - times[0]) / count for k in range(count)]


# ------------------------------------------------------------------------------------------------ sources
def run_up(scene, *, duration: float | None = None, progress=None):
    """A simulation of ``scene`` run until steady, or for ``duration`` s (the scene's ``time.duration`` by
    default): (sim, its summary)."""
    from ..physics import Simulation, StepFailed
    sim = Simulation(scene)
    try:
        sim.run_until_steady(scene.time.duration if duration is None else duration, callback=progress)
    except StepFailed as exc:
        raise RenderError(f"n = {scene.robot.n_flagella}: the simulation failed at t = {sim.time:.3f} s: "
                          f"{exc}") from None
    return sim, sim.summary()


def take_row(sim, times: list[float], *, frames: int = 0, label: str | None = None, progress=None,
             out: dict | None = None) -> Row:
    """Step ``sim`` on to each of ``times`` (s, >= its time) and take the robot's shape there; ``frames`` > 0
    also collects that many equally spaced frames over the same window for an animation. The caption's values
    are those of ``out`` (the summary at the steady state, from :func:`run_up`), else of the run's summary when
    it is over."""
    from ..physics import StepFailed
    scene = sim.scene
    label = label or f"n = {scene.robot.n_flagella}"
    wanted = sorted(set(times) | set(_window(times, frames) if frames else ()))
    taken: dict[float, RobotGeometry] = {}
    dt = scene.time.dt
    try:
        for t in wanted:
            while sim.time < t - 0.5 * dt:
                sim.step()
                if progress is not None:
                    progress(sim)
            taken[t] = RobotGeometry.from_simulation(sim)
    except StepFailed as exc:
        raise RenderError(f"{label}: the simulation failed at t = {sim.time:.3f} s: {exc}") from None
    out = out if out is not None else sim.summary()
    values = {k: float(out[k]) for k in ("omega_T", "omega_h", "omega_t", "v")}
    return Row(label, [taken[t] for t in times], values, steady=bool(out["steady"]),
               frames=[taken[t] for t in _window(times, frames)] if frames else [], group=scene.scene.name,
               scene=scene)


def simulate_row(scene, *, times: list[float] | None = None, snapshots: int = DEFAULT_SNAPSHOTS,
                 duration: float | None = None, frames: int = 0, label: str | None = None,
                 progress=None) -> Row:
    """Simulate ``scene`` and take its shape at ``times`` (default: one revolution after the steady state is
    reached, or after ``duration`` s, the scene's ``time.duration`` by default); ``frames`` > 0 also collects that
    many equally spaced frames over the same window for an animation."""
    out = None
    if times is None:
        sim, out = run_up(scene, duration=duration, progress=progress)
        times = revolution_times(sim.time, out["omega_t"], snapshots)
    else:
        from ..physics import Simulation
        times = _checked_times(times)
        sim = Simulation(scene)
    return take_row(sim, times, frames=frames, label=label, progress=progress, out=out)


def common_times(sims: list, outs: list[dict], count: int) -> list[float]:
    """The snapshot times that rows simulated side by side share (the paper's layout: n = 2 and n = 3 of one
    design in one panel): from the latest of their steady times, one revolution of the slowest flagella (the
    longest 2 pi / omega_t) in ``count`` equal steps, so that each column compares them after the same time."""
    t0 = max(sim.time for sim in sims)
    periods = [2.0 * math.pi / abs(o["omega_t"]) for o in outs if abs(o["omega_t"]) > 1e-6]
    period = max(periods) if periods else float(count)
    return [t0 + k * period / count for k in range(count)]


def _checked_times(times) -> list[float]:
    times = sorted(float(t) for t in times)
    if times[0] < 0:
        raise RenderError(f"--times must be >= 0 s, got {times[0]}")
    return times


def recorded_row(path, *, times: list[float] | None = None, snapshots: int = DEFAULT_SNAPSHOTS, frames: int = 0,
                 namespace: str | None = None, label: str | None = None) -> Row:
    """A recording's shape at ``times`` (the nearest recorded markers; default: its last flagellar revolution),
    with the steady values of the command step that holds the last snapshot (``bag-summary``'s)."""
    from ..runs.summary import summarize
    from .recorded import load
    run = load(path, namespace)
    rec_times = run.times
    t_end = float(rec_times[-1])
    summary = summarize(path, namespace=namespace)
    steps = [s for s in summary["steps"] if s["samples"] > 0]
    if not steps:
        raise RenderError(f"{path}: no omega_h samples to take the steady values from")

    def step_at(t):
        for s in steps:
            if s["t_start"] <= t <= s["t_end"] + 1e-9:
                return s
        return steps[-1]
    if times is None:
        s = step_at(t_end)
        times = revolution_times(0.0, s["omega_t"], snapshots)
        times = [t_end - times[-1] + t for t in times]            # the revolution that ends the recording
        if times[0] < rec_times[0]:
            times = list(np.linspace(rec_times[0], t_end, snapshots))
    else:
        times = sorted(float(t) for t in times)
        bad = [t for t in times if not rec_times[0] - 0.5 <= t <= t_end + 0.5]
        if bad:
            raise RenderError(f"--times {bad} outside the recording ({rec_times[0]:.3f} to {t_end:.3f} s)")
    s = step_at(times[-1])
    values = {"omega_T": s["omega_T"], "omega_h": s["omega_h"], "omega_t": s["omega_t"], "v": s["v"]}
    n = run.frames[0].n
    note = "shape re-simulated" if run.source == "resimulated" else ""
    return Row(label or f"n = {n}", [run.at(t) for t in times], values, note=note, source=Path(path).name,
               frames=[run.at(t) for t in _window(times, frames)] if frames else [],
               group=run.scene.scene.name if run.scene is not None else Path(path).stem, scene=run.scene)


def is_recording(source: str) -> bool:
    p = Path(source)
    return p.suffix == ".mcap" or (p.is_dir() and any(p.glob("*.mcap")))


# ------------------------------------------------------------------------------------------------ drawing
def project(points, view: str) -> np.ndarray:
    """(m, 2) screen coordinates (right, up) of world points in ``view``."""
    right, up, _ = VIEWS[view]
    p = np.atleast_2d(np.asarray(points, float))
    return np.column_stack([p @ right, p @ up])


def _depth(points, view: str) -> float:
    return float(np.mean(np.atleast_2d(points) @ VIEWS[view][2]))


def _plate_outline(geom: RobotGeometry, view: str) -> np.ndarray:
    """The projected outline of the plate disc (convex hull of both faces' rims)."""
    from scipy.spatial import ConvexHull
    P = geom.plate_frame
    phi = np.linspace(0.0, 2.0 * math.pi, 72, endpoint=False)
    rim = geom.plate_radius * (np.outer(np.cos(phi), P[:, 0]) + np.outer(np.sin(phi), P[:, 1]))
    face = geom.joint + rim
    pts = project(np.vstack([face, face + geom.plate_thickness * P[:, 2]]), view)
    hull = ConvexHull(pts)
    return pts[hull.vertices]


def draw_robot(ax, geom: RobotGeometry, view: str, points_per_metre: float) -> None:
    """Draw ``geom`` in ``view`` on ``ax`` (data units: metres), far parts first."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle, Polygon
    items = []           # (depth, draw function)
    if geom.head_centre is not None:
        c = project(geom.head_centre, view)[0]

        def head():
            ax.add_patch(Circle(c, geom.head_radius, facecolor=HEAD_FACE, edgecolor=HEAD_EDGE, lw=0.8, gid="head"))
            if geom.head_rotation is not None:
                m = geom.head_centre + geom.head_radius * geom.head_rotation[:, 2]
                # on the side facing the viewer (clearly: seen edge-on, it would sit on the silhouette)
                if _depth(m, view) < _depth(geom.head_centre, view) - 0.3 * geom.head_radius:
                    ax.add_patch(Circle(project(m, view)[0], 0.2 * geom.head_radius, facecolor="black",
                                        edgecolor="none", gid="head_marker"))
        items.append((_depth(geom.head_centre, view), head))
    if geom.plate_arms:
        outline = _plate_outline(geom, view)
        items.append((_depth(geom.joint, view), lambda: ax.add_patch(Polygon(
            outline, closed=True, facecolor=PLATE_FACE, edgecolor=PLATE_EDGE, lw=0.6, gid="plate"))))
    lw = 2.0 * geom.flagellum_radius * points_per_metre
    for i, nodes in enumerate(geom.flagella):
        xy = project(nodes, view)

        def flag(i=i, xy=xy):
            ax.add_line(Line2D(xy[:, 0], xy[:, 1], lw=lw, color=FLAGELLUM[i % len(FLAGELLUM)],
                               solid_capstyle="butt", solid_joinstyle="round", gid=f"flagellum/{i}"))
            if i == 0:
                ax.add_patch(Circle(xy[-1], 1.15 * geom.flagellum_radius, facecolor=TIP, edgecolor="none",
                                    gid="tip_marker"))
        items.append((_depth(nodes, view), flag))
    for _, fn in sorted(items, key=lambda it: -it[0]):
        fn()


@dataclass
class Frame:
    """The panel geometry shared by a figure: metres per inch and each view's extent."""
    scale: float              # inches per metre
    side_width: float         # m
    half_height: float        # m: |z| (side) and |y|, |z| (end) extent from the axis
    x_lo: list                # per row: the side view's left edge (m, world x)

    @property
    def side_size(self) -> tuple[float, float]:
        return self.side_width * self.scale, 2 * self.half_height * self.scale

    @property
    def end_size(self) -> float:
        return 2 * self.half_height * self.scale


def _extents(rows: list[Row], column_width: float) -> Frame:
    geoms = [g for r in rows for g in (r.snapshots + r.frames)]
    pts = np.vstack([g.points() for g in geoms])
    half = float(np.max(np.abs(pts[:, 1:]))) + MARGIN
    x_lo, width = [], 0.0
    for r in rows:
        p = np.vstack([g.points() for g in r.snapshots + r.frames])
        x_lo.append(float(p[:, 0].min()) - MARGIN)
        width = max(width, float(p[:, 0].max()) + MARGIN - x_lo[-1])
    return Frame(scale=column_width / width, side_width=width, half_height=half, x_lo=x_lo)


def _panel(fig, rect_in, size_in, lim_x, lim_y):
    W, H = fig.get_size_inches()
    x, y = rect_in
    ax = fig.add_axes([x / W, y / H, size_in[0] / W, size_in[1] / H])
    ax.set_xlim(*lim_x)
    ax.set_ylim(*lim_y)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xticks([])
    ax.set_yticks([])
    for s in ax.spines.values():
        s.set_color("#c8c8c8")
        s.set_linewidth(0.6)
    return ax


def _scale_bar(ax, x0: float, y0: float, label_size: float) -> None:
    from matplotlib.lines import Line2D
    ax.add_line(Line2D([x0, x0 + SCALE_BAR], [y0, y0], color="black", lw=3.0, solid_capstyle="butt",
                       gid="scalebar", clip_on=False))
    ax.text(x0 + 0.5 * SCALE_BAR, y0 + 0.003, "2 cm", ha="center", va="bottom", fontsize=label_size)


def figure(rows: list[Row], *, title: str = "", width: float = 16.0, dpi: float = 150.0):
    """The per-design layout of ``rows`` (each with the same number of snapshots), ``width`` inches wide: a row
    per n (or recording), a side view above an end view in each column; panels numbered (1), (2), ... along a
    row. (The paper's own layout, rows by design with the letters (a), (b) of its Fig. 1: :func:`paper_figure`.)"""
    from matplotlib.figure import Figure
    if not rows or not rows[0].snapshots:
        raise RenderError("nothing to draw: no row or no snapshot")
    ncol = max(len(r.snapshots) for r in rows)
    left, right, gap, label_fs = 1.05, 0.15, 0.14, 9
    col_w = (width - left - right - (ncol - 1) * gap) / ncol
    fr = _extents(rows, col_w)
    side_w, side_h = fr.side_size
    end = fr.end_size
    top, title_h, row_gap, vgap = 0.15, 0.55 if title else 0.1, 0.32, 0.22
    caption_lines = len(rows) + 2
    bottom = 0.22 * caption_lines + 0.2
    row_h = 0.22 + side_h + vgap + end
    height = top + title_h + len(rows) * row_h + (len(rows) - 1) * row_gap + bottom
    fig = Figure(figsize=(width, height), dpi=dpi)
    if title:
        fig.text(0.5, 1 - (top + 0.2) / height, title, ha="center", va="center", fontsize=12)
    ppm = fr.scale * 72.0                      # points per metre
    y = height - top - title_h
    axes = []
    for ri, row in enumerate(rows):
        y_side = y - 0.22 - side_h
        y_end = y_side - vgap - end
        fig.text(0.12 / width, (y_side + 0.5 * side_h) / height, row.label, fontsize=12, fontweight="bold",
                 ha="left", va="center")
        fig.text(0.12 / width, (y_side + 0.5 * side_h) / height - 0.2 / height, "side view", fontsize=label_fs,
                 ha="left", va="center", color="#555555")
        fig.text(0.12 / width, (y_end + 0.5 * end) / height, "end view\n(from behind)", fontsize=label_fs,
                 ha="left", va="center", color="#555555")
        x_ref = row.snapshots[0].points()[:, 0].max()          # the head's front at the first snapshot
        for ci, g in enumerate(row.snapshots):
            x = left + ci * (col_w + gap)
            ax = _panel(fig, (x, y_side), (side_w, side_h), (fr.x_lo[ri], fr.x_lo[ri] + fr.side_width),
                        (-fr.half_height, fr.half_height))
            ax.axvline(x_ref, color="#888888", lw=0.6, ls=(0, (3, 3)), zorder=0)
            draw_robot(ax, g, "side", ppm)
            dx = g.points()[:, 0].max() - x_ref
            ax.set_title(f"({ci + 1})  t = {g.t:.2f} s,  $\\Delta x$ = {1e3 * dx:+.2f} mm",
                         fontsize=label_fs, loc="left", pad=3)
            ax_end = _panel(fig, (x + 0.5 * (col_w - end), y_end), (end, end), (-fr.half_height, fr.half_height),
                            (-fr.half_height, fr.half_height))
            draw_robot(ax_end, g, "end", ppm)
            axes.append((ri, ci, ax, ax_end))
        y = y_end - row_gap
    caption = ["Snapshots of the robot's shape, all drawn to one scale in the world frame (x forward).",
               "Dashed line: the robot's front at the row's first snapshot; black bar: 2 cm."] + \
        [r.caption() for r in rows]
    for k, line in enumerate(caption):
        fig.text(left / width, (bottom - 0.2 - 0.22 * k) / height, line, fontsize=label_fs + 1, ha="left",
                 va="top")
    # the 2 cm bar in the bottom-left corner, in axes of the panels' own scale (so it never covers the robot)
    bar_ax = _panel(fig, (0.12, bottom - 0.2 - 0.22 * (len(caption) - 1) - 0.05), (SCALE_BAR * fr.scale, 0.25),
                    (0.0, SCALE_BAR), (0.0, 0.25 / fr.scale))
    bar_ax.set_axis_off()
    _scale_bar(bar_ax, 0.0, 0.0, label_fs)
    fig.flagbot_axes = axes                     # (row, column, side axes, end axes), for tests
    fig.flagbot_frame = fr
    return fig


def design_name(name: str) -> str:
    """A scene's name as the paper writes it: design1 -> "design 1"."""
    m = re.fullmatch(r"design(\d+)", name)
    return f"design {m.group(1)}" if m else name


def groups_of(rows: list[Row]) -> dict[str, list[Row]]:
    """The rows by design (their ``group``), in the order the designs first appear."""
    out: dict[str, list[Row]] = {}
    for r in rows:
        out.setdefault(r.group or r.label, []).append(r)
    return out


def _sizes(scene) -> str:
    if scene is None:
        return ""
    head = f", $R_h$ = {1e3 * scene.head.radius:.0f} mm" if not scene.clamped else ""
    return f":  $L$ = {1e3 * scene.flagellum.length:.0f} mm{head}, $L_p$ = {1e3 * scene.plate.diameter:.0f} mm"


def paper_figure(rows: list[Row], *, title: str = "", width: float = 16.0, dpi: float = 150.0):
    """The paper's Fig. 1 layout: a row per design, (a) the first, (b) the second, ... as its caption says; in
    each panel (a1), (a2), ... the side views of that design's robots (n = 2 above n = 3) at one time, each with
    how far it swam since the row's first panel, all to one scale. Rows of one design share their times when they
    were simulated side by side (:func:`common_times`), so a column compares them after the same time."""
    from matplotlib.figure import Figure
    if not rows or not rows[0].snapshots:
        raise RenderError("nothing to draw: no row or no snapshot")
    groups = groups_of(rows)
    ncol = max(len(r.snapshots) for r in rows)
    left, right, gap, fs = 1.05, 0.15, 0.14, 9
    col_w = (width - left - right - (ncol - 1) * gap) / ncol
    fr = _extents(rows, col_w)
    side_w, side_h = fr.side_size
    top, title_h = 0.15, (0.55 if title else 0.1)
    header_h, ptitle_h, dx_h, strip_gap, group_gap = 0.32, 0.24, 0.24, 0.06, 0.3
    caption_lines = len(rows) + 2
    bottom = 0.22 * caption_lines + 0.2
    body = sum(header_h + ptitle_h + len(g) * (side_h + dx_h) + (len(g) - 1) * strip_gap for g in groups.values())
    height = top + title_h + body + (len(groups) - 1) * group_gap + bottom
    fig = Figure(figsize=(width, height), dpi=dpi)
    if title:
        fig.text(0.5, 1 - (top + 0.2) / height, title, ha="center", va="center", fontsize=12)
    ppm = fr.scale * 72.0
    index = {id(r): k for k, r in enumerate(rows)}
    y = height - top - title_h
    panels = []
    for gi, (name, members) in enumerate(groups.items()):
        letter = "abcdefghijklmnopqrstuvwxyz"[gi % 26]
        fig.text(0.12 / width, (y - 0.5 * header_h) / height, f"({letter})  {design_name(name)}"
                 + _sizes(members[0].scene), fontsize=11, fontweight="bold", ha="left", va="center")
        y -= header_h + ptitle_h
        for ri, row in enumerate(members):
            y_side = y - side_h
            fig.text(0.12 / width, (y_side + 0.5 * side_h) / height, row.label, fontsize=11, fontweight="bold",
                     ha="left", va="center")
            if row.source:
                fig.text(0.12 / width, (y_side + 0.5 * side_h) / height - 0.2 / height, row.source,
                         fontsize=fs - 2, ha="left", va="center", color="#555555")
            x_ref = row.snapshots[0].points()[:, 0].max()          # its front at the row's first snapshot
            for ci, g in enumerate(row.snapshots):
                x = left + ci * (col_w + gap)
                ax = _panel(fig, (x, y_side), (side_w, side_h),
                            (fr.x_lo[index[id(row)]], fr.x_lo[index[id(row)]] + fr.side_width),
                            (-fr.half_height, fr.half_height))
                ax.axvline(x_ref, color="#888888", lw=0.6, ls=(0, (3, 3)), zorder=0)
                draw_robot(ax, g, "side", ppm)
                shared = len({round(m.snapshots[ci].t, 6) for m in members if ci < len(m.snapshots)}) == 1
                if ri == 0:
                    ax.set_title(f"({letter}{ci + 1})" + (f"  t = {g.t:.2f} s" if shared else ""), fontsize=fs,
                                 loc="left", pad=3)
                dx = g.points()[:, 0].max() - x_ref
                fig.text(x / width, (y_side - 0.04) / height, f"{row.label}: $\\Delta x$ = {1e3 * dx:+.2f} mm"
                         + ("" if shared else f",  t = {g.t:.2f} s"), fontsize=fs - 1, ha="left", va="top")
                panels.append((gi, ri, ci, ax))
            y = y_side - dx_h - strip_gap
        y += strip_gap - group_gap
    caption = ["Side views of the robot's shape (world x forward), all drawn to one scale; in each panel the "
               "robots of one design at one time.",
               "Dashed line: each robot's front at the row's first panel; $\\Delta x$: how far it swam since; "
               "black bar: 2 cm."]
    for gi, (name, members) in enumerate(groups.items()):
        caption += [f"({'abcdefghijklmnopqrstuvwxyz'[gi % 26]}) {design_name(name)}, " + r.caption() for r in members]
    for k, line in enumerate(caption):
        fig.text(left / width, (bottom - 0.2 - 0.22 * k) / height, line, fontsize=fs + 1, ha="left", va="top")
    bar_ax = _panel(fig, (0.12, bottom - 0.2 - 0.22 * (len(caption) - 1) - 0.05), (SCALE_BAR * fr.scale, 0.25),
                    (0.0, SCALE_BAR), (0.0, 0.25 / fr.scale))
    bar_ax.set_axis_off()
    _scale_bar(bar_ax, 0.0, 0.0, fs)
    fig.flagbot_panels = panels                 # (design, row in it, column, side axes), for tests
    fig.flagbot_frame = fr
    return fig


#: the layouts of ``flagbot render --layout``
LAYOUTS = {"per-design": figure, "paper": paper_figure}


def animation(rows: list[Row], out: str | Path, *, fps: float = 10.0, dpi: float = 100.0, title: str = "") -> int:
    """A GIF of every row's frames (side and end views), one row per line, each row's time under its name (with
    its design when the rows are of several); the number of frames written."""
    from matplotlib.animation import PillowWriter
    from matplotlib.figure import Figure
    n = min(len(r.frames) for r in rows)
    if n == 0:
        raise RenderError("no frames to animate")
    col_w = 5.2
    fr = _extents(rows, col_w)
    side_w, side_h = fr.side_size
    end = fr.end_size
    several = len(groups_of(rows)) > 1
    names = [f"{design_name(r.group)}, {r.label}" if several and r.group else r.label for r in rows]
    lm = 1.8 if several else 1.0                    # the left margin holds the names
    width = lm + side_w + 0.3 + end + 0.2
    row_h = max(side_h, end) + 0.45
    height = (0.45 if title else 0.15) + len(rows) * row_h + 0.25
    fig = Figure(figsize=(width, height), dpi=dpi)
    ppm = fr.scale * 72.0
    panels, clocks = [], []
    for ri, row in enumerate(rows):
        y = height - (0.45 if title else 0.15) - (ri + 1) * row_h + 0.1
        fig.text(0.1 / width, (y + 0.5 * side_h + 0.1) / height, names[ri], fontsize=11, fontweight="bold",
                 va="center")
        clocks.append(fig.text(0.1 / width, (y + 0.5 * side_h - 0.12) / height, "", fontsize=9, va="center"))
        panels.append((row, (lm, y), (lm + side_w + 0.3, y + 0.5 * (side_h - end)), ri))
    if title:
        fig.text(0.5, 1 - 0.25 / height, title, ha="center", va="center", fontsize=11)
    writer = PillowWriter(fps=fps)
    with writer.saving(fig, str(out), dpi):
        for k in range(n):
            for ax in list(fig.axes):
                ax.remove()
            for row, side_at, end_at, ri in panels:
                g = row.frames[k]
                ax = _panel(fig, side_at, (side_w, side_h), (fr.x_lo[ri], fr.x_lo[ri] + fr.side_width),
                            (-fr.half_height, fr.half_height))
                draw_robot(ax, g, "side", ppm)
                if ri == len(panels) - 1:           # the 2 cm bar in the margin below the last row's label
                    bar_ax = _panel(fig, (0.1, side_at[1]), (SCALE_BAR * fr.scale, 0.25), (0.0, SCALE_BAR),
                                    (0.0, 0.25 / fr.scale))
                    bar_ax.set_axis_off()
                    _scale_bar(bar_ax, 0.0, 0.0, 8)
                draw_robot(_panel(fig, end_at, (end, end), (-fr.half_height, fr.half_height),
                                  (-fr.half_height, fr.half_height)), g, "end", ppm)
                clocks[ri].set_text(f"t = {g.t:.2f} s")
            writer.grab_frame()
    return n
