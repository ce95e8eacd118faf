"""Figures and the summary of a sweep, made from its CSV alone (no simulation, no scene file needed).

Each ``figure_*`` function takes parsed CSV rows and returns a matplotlib ``Figure`` (object-oriented API, no
pyplot state), so tests can inspect its lines and labels before anything is saved:

* ``figure_speed``: v_bar vs omega_T_bar per n, DER and beam (paper Fig. SpeedVSFlagellaNumber a/c/e), with the
  crossover where the larger n overtakes the smaller (paper: C for DER, D for beam theory, here D for NLB w/o
  head and D' for NLB, each a vertical guide of its own dash, lettered at the top) and the point of steepest
  slope of each DER curve (paper: E for n = 2, F for n = 3), a star lettered where the letter covers nothing;
* ``figure_head_spin``: omega_h_bar vs omega_T_bar and omega_h / omega_T (panels b/d);
* ``figure_length``: v vs omega_T for every flagellum length and n, DER ("D") and beam ("B") with the paper's
  labels such as D130n2 (Fig. SpeedVSFlagellaLengthandNumber), explained in the legend's title;
* ``figure_deflection``: w(L)/L vs omega_T_bar for LB, NLB w/o head, NLB (Fig. comparison);
* ``figure_groups``: DER v vs omega_T for every group of the grid's other keys on one figure (e.g. helical vs
  straight flagella, granular vs viscous medium).
"""
from __future__ import annotations

import math
import os
from functools import partial
from pathlib import Path

import numpy as np

from ..cliutil import json_output
from .store import read_manifest, read_results
from .task import FRAMEWORK_LABELS, FRAMEWORKS

#: the beam regimes (beam.balance.REGIMES), taken from the sweep's frameworks so as not to import the beam solver
REGIMES = FRAMEWORKS[1:]

PLOT_KEYS = ("robot.n_flagella", "motor.omega_rpm", "flagellum.length")
#: beam regimes drawn next to DER in the speed and head-spin figures; the paper's beam curves are NLB w/o head
SPEED_REGIMES = ("nlb-nohead", "nlb")
#: the beam regime of the length figure (the paper: "DER and NLB")
LENGTH_REGIME = "nlb"
#: how each framework's curves are drawn. NLB and NLB w/o head agree to ~1e-4 in omega_h and a few % in v (the head
#: changes little there), so a line over the other would hide it: NLB w/o head is a wide pale band underneath and
#: NLB a dotted line on it, so that where they agree the dotted line runs inside the band. DER is on top, thinner
#: than the dots: where it meets NLB (design 1's head spin, ~97 % of omega_T in both) the dots show on its sides
STYLE = {"der": dict(ls="-", marker="o", ms=3.5, lw=1.3, zorder=4),
         "nlb-nohead": dict(ls="-", marker=None, lw=6.0, alpha=0.3, solid_capstyle="butt", zorder=2),
         "nlb": dict(ls=":", marker=None, lw=2.4, zorder=3),
         "lb": dict(ls="-.", marker=None, lw=1.2, zorder=3)}
#: the legend's words for the looks of STYLE that are not plain lines
LOOK_NOTE = {"nlb-nohead": " (pale band)"}
#: the crossover guide of each framework: its letter (the paper's C for DER, D for its beam curves, NLB w/o head)
#: and the dash of its vertical line, so that no two different guides share a letter or a look
CROSSOVER_MARKS = {"der": ("C", "-"), "nlb-nohead": ("D", "--"), "nlb": ("D'", ":"), "lb": ("D''", "-.")}
#: the steepest-slope stars (the paper's E, F, ...): marker size in points
STAR_SIZE = 12.0
N_COLOURS = ["tab:blue", "tab:red", "tab:green", "tab:purple", "tab:orange", "tab:brown"]


# ---------------------------------------------------------------- data
def curve(rows: list[dict], framework: str, n: int, L: float | None = None, x: str = "omega_T_bar",
          y: str = "v_bar") -> tuple[np.ndarray, np.ndarray]:
    """Sorted (x, y) of one framework and n (and L), leaving out failed or non-finite points."""
    pts = [(r[x], r[y]) for r in rows if r["framework"] == framework and r["n"] == n
           and (L is None or r["L"] == L) and not r["error"] and math.isfinite(r[x]) and math.isfinite(r[y])]
    pts.sort()
    return np.array([p[0] for p in pts], float), np.array([p[1] for p in pts], float)


#: a DER point's error bar is drawn where its half-height is at least this fraction of the axes' data span
VISIBLE_ERROR = 2e-3


def error_bars(ax, rows: list[dict], n: int, L: float | None, y: str, colour: str, ratio: bool = False) -> int:
    """The DER curve's estimated numerical errors (the rows' ``error_estimate_*`` column of ``y``'s output) as
    error bars, where they are visible (VISIBLE_ERROR); ``ratio``: y / x is plotted. Returns how many."""
    key = {"v_bar": "error_estimate_v", "omega_h_bar": "error_estimate_omega_h"}[y]
    pts = sorted((r["omega_T_bar"], r[y], r.get(key, math.nan)) for r in rows
                 if r["framework"] == "der" and r["n"] == n and (L is None or r["L"] == L) and not r["error"]
                 and math.isfinite(r["omega_T_bar"]) and math.isfinite(r[y]))
    if not pts:
        return 0
    x, v, e = (np.array(c, float) for c in zip(*pts))
    if ratio:
        keep = x != 0
        x, v, e = x[keep], v[keep] / x[keep], e[keep]
    span = float(np.ptp(v)) or float(np.max(np.abs(v))) or 1.0
    half = np.abs(v) * e
    show = np.isfinite(half) & (half >= VISIBLE_ERROR * span)
    if show.any():
        ax.errorbar(x[show], v[show], yerr=half[show], fmt="none", ecolor=colour, elinewidth=0.9, capsize=2.0,
                    zorder=4, gid=f"error/{n}")
    return int(show.sum())


def crossovers(x: np.ndarray, y_low: np.ndarray, y_high: np.ndarray) -> list[float]:
    """x where y_high - y_low changes sign from <= 0 to > 0 (y_high overtakes y_low), linearly interpolated."""
    d = np.asarray(y_high) - np.asarray(y_low)
    out = []
    for i in range(len(d) - 1):
        if d[i] <= 0 < d[i + 1]:
            out.append(float(x[i] if d[i] == 0 else x[i] - d[i] * (x[i + 1] - x[i]) / (d[i + 1] - d[i])))
    return out


def sign_changes(x: np.ndarray, d: np.ndarray) -> list[float]:
    """x where d changes sign (either way), interpolated: where two curves intersect (paper points A, B)."""
    out = []
    for i in range(len(d) - 1):
        if d[i] == 0:
            out.append(float(x[i]))
        elif d[i] * d[i + 1] < 0:
            out.append(float(x[i] - d[i] * (x[i + 1] - x[i]) / (d[i + 1] - d[i])))
    return out


def common(rows, fw_a, n_a, fw_b, n_b, L, x="omega_T_bar", y="v_bar"):
    """The two curves on their common x values (the grid's omega_T values are shared by every n and
    framework of one L, so this is an exact match, not an interpolation)."""
    xa, ya = curve(rows, fw_a, n_a, L, x, y)
    xb, yb = curve(rows, fw_b, n_b, L, x, y)
    xs = np.intersect1d(xa, xb)
    return xs, ya[np.searchsorted(xa, xs)], yb[np.searchsorted(xb, xs)]


def steepest_slope(x: np.ndarray, y: np.ndarray) -> dict | None:
    """The data point where dy/dx (central differences) is largest. ``interior`` is False when that is an end
    of the range: the slope was still growing (or only falling), so the range holds no E/F-type point."""
    if len(x) < 3:
        return None
    s = np.gradient(y, x)
    i = int(np.argmax(s))
    return {"x": float(x[i]), "y": float(y[i]), "slope": float(s[i]), "index": i,
            "interior": bool(0 < i < len(x) - 1)}


def frameworks_in(rows) -> list[str]:
    present = {r["framework"] for r in rows}
    return [fw for fw in FRAMEWORK_LABELS if fw in present]


def n_values(rows) -> list[int]:
    return sorted({r["n"] for r in rows})


def pair_of_n(ns: list[int]) -> tuple[int, int] | None:
    """The n pair whose crossover is marked: (2, 3) as in the paper, else the two smallest."""
    if 2 in ns and 3 in ns:
        return 2, 3
    return (ns[0], ns[1]) if len(ns) >= 2 else None


def _label(fw: str, n: int) -> str:
    return f"{FRAMEWORK_LABELS[fw]} n={n}"


def _legend_label(fw: str, n: int) -> str:
    """A curve's legend text: its name and, for a look that is not a plain line, what it looks like."""
    return _label(fw, n) + LOOK_NOTE.get(fw, "")


def _colour(ns: list[int], n: int) -> str:
    return N_COLOURS[ns.index(n) % len(N_COLOURS)]


# ---------------------------------------------------------------- figures
#: the figures' resolution, dots per inch: they are laid out and measured at the resolution they are saved at, so
#: the text measured for the layout (matplotlib caches it by resolution) is the text drawn
DPI = 120
#: zlib's level for the PNGs: 1 writes them ~7% larger than the default 6 in a fraction of its time
PNG_COMPRESSION = 1


def _new_figure(ncols: int = 1, width: float = 6.4):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=(width * ncols, 4.6), layout="constrained", dpi=DPI)
    FigureCanvasAgg(fig)                 # a renderer to measure labels with (plotlabels), before saving
    axes = [fig.add_subplot(1, ncols, i + 1) for i in range(ncols)]
    return fig, axes


def _finish(ax, xlabel: str, ylabel: str, title: str, legend: dict | None = None):
    """Axis labels, title, grid and legend (``legend``: its keyword arguments), the same on every figure."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, **(legend or {}))


def _outside_legend(fig, ax, title: str = "") -> None:
    """One legend for the figure, outside the axes on the right: it covers no curve, mark or letter."""
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right upper", fontsize=7, title=title or None, title_fontsize=7,
               alignment="left")


def _beam_note(fws) -> str:
    """The legend's title when NLB and NLB w/o head are both drawn: how to tell them apart where they agree."""
    if "nlb" in fws and "nlb-nohead" in fws:
        return "NLB (dotted) runs inside the pale\nNLB w/o head band where they agree"
    return ""


def _guide_letters(ax, guides: list[tuple[str, float]]) -> list:
    """The letter of each vertical guide at the top of the axes, each one step lower than the one before it
    while they would overlap (the renderer measures them)."""
    from matplotlib.transforms import blended_transform_factory

    from ..plotlabels import renderer_of, text_box
    r = renderer_of(ax.figure)
    at = blended_transform_factory(ax.transData, ax.transAxes)
    placed, boxes = [], []
    for name, x in sorted(guides, key=lambda g: g[1]):
        for level in range(6):
            t = ax.annotate(name, (x, 1.0), xycoords=at, xytext=(3, -4 - 13 * level), textcoords="offset points",
                            ha="left", va="top", fontsize=9, zorder=6,
                            bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.8))
            t.set_in_layout(False)
            box = text_box(t, r)
            if not any(box.overlaps(b) for b in boxes) or level == 5:
                break
            t.remove()
        placed.append(t)
        boxes.append(box)
    return placed


def figure_speed(rows: list[dict], L: float | None = None, regimes=SPEED_REGIMES, title: str = ""):
    """v_bar vs omega_T_bar: each (framework, n) curve; a vertical guide at each crossover (C, D, D': where the
    larger n overtakes the smaller), its letter at the top of the axes; a star at each DER curve's steepest slope
    (E, F, ...), its letter beside it where it overlaps nothing (plotlabels); the legend outside the axes."""
    fig, (ax,) = _new_figure(width=9.0)
    ns = n_values(rows)
    fws = [fw for fw in ("der", *regimes) if fw in frameworks_in(rows)]
    for fw in fws:
        for n in ns:
            x, y = curve(rows, fw, n, L)
            if len(x):
                ax.plot(x, y, color=_colour(ns, n), label=_legend_label(fw, n), **STYLE[fw])
    bars = sum(error_bars(ax, rows, n, L, "v_bar", _colour(ns, n)) for n in ns) if "der" in fws else 0
    if bars:
        ax.plot([], [], ls="none", marker="|", ms=8, color="0.3", label="DER estimated numerical error")
    guides, stars = [], []
    pair = pair_of_n(ns)
    if pair:
        for fw in fws:
            xs, y_lo, y_hi = common(rows, fw, pair[0], fw, pair[1], L)
            name, dash = CROSSOVER_MARKS[fw]
            for xc in crossovers(xs, y_lo, y_hi):
                ax.axvline(xc, color="0.3", lw=0.9, ls=dash, zorder=1, gid=f"crossover/{name}",
                           label=f"{name}: {FRAMEWORK_LABELS[fw]} crossover, n={pair[1]} overtakes n={pair[0]} "
                                 rf"at $\bar\omega_T$ = {xc:.3g}")
                guides.append((name, xc))
    for n, name in zip(ns, "EFGHIJ"):
        st = steepest_slope(*curve(rows, "der", n, L))
        if st and st["interior"]:
            ax.plot([st["x"]], [st["y"]], ls="none", marker="*", ms=STAR_SIZE, color=_colour(ns, n), mec="k",
                    zorder=5, gid=f"slope/{name}",
                    label=f"{name}: DER n={n} steepest slope at " rf"$\bar\omega_T$ = {st['x']:.3g}")
            stars.append((name, (st["x"], st["y"])))
    ax.set_xlabel(r"$\bar\omega_T = \omega_T \eta_p L^4 / EI$")
    ax.set_ylabel(r"$\bar v = v \eta_p L^3 / EI$")
    ax.set_title(title or "speed vs motor speed")
    ax.grid(alpha=0.3)
    _outside_legend(fig, ax, _beam_note(fws))
    fig.draw_without_rendering()           # the layout is final: the letters are measured where they will be
    from ..plotlabels import marker_box, place_labels, renderer_of, text_box
    letters = _guide_letters(ax, guides)
    r = renderer_of(fig)
    avoid = [marker_box(ax, x, y, STAR_SIZE) for _, (x, y) in stars] + [text_box(t, r) for t in letters]
    place_labels(ax, stars, avoid=avoid, fontsize=9)
    fig.set_layout_engine("none")          # the layout is done: saving keeps it instead of laying out again
    return fig


def figure_head_spin(rows: list[dict], L: float | None = None, regimes=SPEED_REGIMES, title: str = ""):
    """omega_h_bar vs omega_T_bar (left) and omega_h / omega_T (right), one legend for both, outside."""
    fig, (ax, ax2) = _new_figure(2, width=5.4)
    ns = n_values(rows)
    fws = [fw for fw in ("der", *regimes) if fw in frameworks_in(rows)]
    for fw in fws:
        for n in ns:
            x, y = curve(rows, fw, n, L, y="omega_h_bar")
            if len(x):
                ax.plot(x, y, color=_colour(ns, n), label=_legend_label(fw, n), **STYLE[fw])
                keep = x != 0
                ax2.plot(x[keep], y[keep] / x[keep], color=_colour(ns, n), label=_legend_label(fw, n), **STYLE[fw])
    if "der" in fws:
        bars = sum(error_bars(ax, rows, n, L, "omega_h_bar", _colour(ns, n))
                   + error_bars(ax2, rows, n, L, "omega_h_bar", _colour(ns, n), ratio=True) for n in ns)
        if bars:
            ax.plot([], [], ls="none", marker="|", ms=8, color="0.3", label="DER estimated numerical error")
    xmax = max((r["omega_T_bar"] for r in rows if math.isfinite(r["omega_T_bar"])), default=1.0)
    ax.plot([0, xmax], [0, xmax], color="0.6", lw=0.8, zorder=1, label=r"$\omega_h = \omega_T$")
    ax.set_xlabel(r"$\bar\omega_T$")
    ax.set_ylabel(r"$\bar\omega_h = \omega_h \eta_p L^4 / EI$")
    ax2.set_xlabel(r"$\bar\omega_T$")
    ax2.set_ylabel(r"$\omega_h / \omega_T$")
    ax2.margins(y=0.15)        # the data's own range: design 1's shares differ by a few % near 0.95
    ax.set_title(title or "head spin")
    ax2.set_title("share of the motor speed taken by the head")
    for a in (ax, ax2):
        a.grid(alpha=0.3)
    _outside_legend(fig, ax, _beam_note(fws))
    return fig


def figure_length(rows: list[dict], regime: str = LENGTH_REGIME, title: str = ""):
    """v (mm/s) vs omega_T (rpm) for every (L, n): DER "D<L mm>n<n>" solid, beam "B<L mm>n<n>" broken lines."""
    from matplotlib import colormaps
    fig, (ax,) = _new_figure(width=7.0)
    ns = n_values(rows)
    Ls = sorted({r["L"] for r in rows})
    cmap = colormaps["viridis"]
    markers = "os^Dv<>"
    beam_ls = ["--", ":", "-.", (0, (6, 1, 1, 1, 1, 1))]     # n told apart by dash pattern (beam), marker (DER)
    for i, L in enumerate(Ls):
        colour = cmap(0.85 * i / max(1, len(Ls) - 1))
        for j, n in enumerate(ns):
            for fw, letter, ls in (("der", "D", "-"), (regime, "B", beam_ls[j % len(beam_ls)])):
                x, y = curve(rows, fw, n, L, x="omega_T_rpm", y="v")
                if len(x):
                    ax.plot(x, 1e3 * y, ls=ls, color=colour, marker=markers[j % len(markers)] if fw == "der"
                            else None, ms=3.5, label=f"{letter}{1e3 * L:.0f}n{n}")
    # the paper's labels, with their key: the first letter is the framework, then L in mm, then n
    key = (f"D = DER, B = {FRAMEWORK_LABELS[regime]}; "
           + (f"e.g. D{1e3 * Ls[0]:.0f}n{ns[0]}: DER, L = {1e3 * Ls[0]:.0f} mm, n = {ns[0]}" if Ls and ns else ""))
    _finish(ax, r"$\omega_T$ (rpm)", r"$v$ (mm/s)",
            title or "speed vs motor speed for several flagellum lengths",
            legend=dict(ncol=2, title=key, title_fontsize=7))
    return fig


def figure_deflection(rows: list[dict], L: float | None = None, title: str = ""):
    """w(L)/L vs omega_T_bar, LB, NLB w/o head and NLB. The three nearly coincide (paper Fig. comparison), so they
    are nested: LB a wide pale band at the bottom, NLB w/o head a narrower one on it, NLB a line on top; where
    they agree, each shows inside the one below. n by dash (solid n = 2, dashed n = 3, ...)."""
    fig, (ax,) = _new_figure(width=7.4)
    ns = n_values(rows)
    looks = {"lb": dict(color="0.45", lw=7.0, alpha=0.3, zorder=1, solid_capstyle="butt"),
             "nlb-nohead": dict(color="tab:blue", lw=3.5, alpha=0.55, zorder=2, solid_capstyle="butt"),
             "nlb": dict(color="tab:red", lw=1.3, zorder=3)}
    notes = {"lb": " (wide band)", "nlb-nohead": " (band)", "nlb": ""}
    lines = {n: ls for n, ls in zip(ns, ["-", "--", ":", "-."] * 3)}
    for fw in REGIMES:
        for n in ns:
            x, y = curve(rows, fw, n, L, y="w_tip_over_L")
            if len(x):
                ax.plot(x, y, ls=lines[n], label=_label(fw, n) + notes[fw], **looks[fw])
    ax.set_xlabel(r"$\bar\omega_T$")
    ax.set_ylabel(r"tip deflection $w(L)/L$")
    ax.set_title(title or "beam tip deflection in the three regimes")
    ax.grid(alpha=0.3)
    _outside_legend(fig, ax, "nested where they agree:\nNLB inside NLB w/o head inside LB")
    return fig


# ---------------------------------------------------------------- summary
def summarise(rows: list[dict], L: float | None = None) -> dict:
    """The numbers behind the figures: crossovers, steepest slopes, omega_h / omega_T, DER vs beam."""
    ns = n_values(rows)
    fws = frameworks_in(rows)
    sel = [r for r in rows if L is None or r["L"] == L]
    out: dict = {"L": L, "points": len({r["point"] for r in sel}),
                 "der_hit_cap": sorted(r["point"] for r in sel if r["framework"] == "der" and r["hit_cap"]),
                 "errors": [f"{r['point']} [{r['framework']}]: {r['error']}" for r in sel if r["error"]],
                 "crossover": {}, "steepest_slope": {}, "omega_h_share": {}, "beam_vs_der": {},
                 "der_error_estimate": _error_summary(sel)}
    pair = pair_of_n(ns)
    if pair:
        for fw in fws:
            xs, y_lo, y_hi = common(rows, fw, pair[0], fw, pair[1], L)
            if len(xs) == 0:
                continue
            d = y_hi - y_lo
            out["crossover"][fw] = {
                "pair": list(pair), "omega_T_bar": crossovers(xs, y_lo, y_hi),
                "larger_n_faster_at": [float(x) for x, di in zip(xs, d) if di > 0],
                "relative_difference_range": [float(np.min(d / np.abs(y_lo))), float(np.max(d / np.abs(y_lo)))]
                if np.all(y_lo != 0) else None}
    for fw in fws:
        for n in ns:
            x, y = curve(rows, fw, n, L)
            st = steepest_slope(x, y)
            if st:
                out["steepest_slope"][f"{fw} n={n}"] = st
            xh, yh = curve(rows, fw, n, L, y="omega_h_bar")
            keep = xh != 0                      # omega_T = 0: at rest, no share to speak of
            xh, yh = xh[keep], yh[keep]
            if len(xh):
                share = yh / xh
                out["omega_h_share"][f"{fw} n={n}"] = {"min": float(share.min()), "max": float(share.max()),
                                                       "mean": float(share.mean())}
    for fw in fws:
        if fw == "der":
            continue
        for n in ns:
            xs, v_der, v_b = common(rows, "der", n, fw, n, L)
            if len(xs) == 0:
                continue
            with np.errstate(divide="ignore", invalid="ignore"):
                rel = np.where(v_der != 0, (v_b - v_der) / np.abs(v_der), np.nan)
            out["beam_vs_der"][f"{fw} n={n}"] = {
                "omega_T_bar": xs.tolist(), "v_bar_der": v_der.tolist(), "v_bar_beam": v_b.tolist(),
                "relative_difference": rel.tolist(), "curves_cross_at": sign_changes(xs, v_b - v_der)}
    return out


def _error_summary(rows: list[dict]) -> dict:
    """The DER rows' largest estimated numerical errors (error_estimate_* columns; NaN where a CSV has none) and
    the points whose estimate exceeds 1%."""
    der = [r for r in rows if r["framework"] == "der" and not r["error"]]
    out = {}
    for k in ("omega_h", "omega_t", "v"):
        vals = [r.get(f"error_estimate_{k}", math.nan) for r in der]
        vals = [x for x in vals if math.isfinite(x)]
        out[k] = max(vals) if vals else None
    out["above_1_percent"] = sorted({r["point"] for r in der for k in ("omega_h", "omega_t", "v")
                                     if r.get(f"error_estimate_{k}", 0.0) > 0.01})
    return out


def figure_groups(rows: list[dict], extra_keys: list[str], title: str = ""):
    """v (mm/s) vs omega_T (rpm) of the DER for every group of the grid's other keys (those not drawn on an axis,
    e.g. flagellum.helix_pitch and medium.model), one colour per group, n by marker and dash: the groups compared
    on one figure (the per-group figures show each alone)."""
    from matplotlib import colormaps
    fig, (ax,) = _new_figure(width=7.4)
    ns = n_values(rows)
    groups = sorted({tuple(r[k] for k in extra_keys) for r in rows}, key=repr)
    Ls = sorted({r["L"] for r in rows})
    cmap = colormaps["tab10"]
    markers, dashes = "os^Dv<>", ["-", "--", ":", "-."]
    for i, g in enumerate(groups):
        grows = [r for r in rows if tuple(r[k] for k in extra_keys) == g]
        for L in Ls:
            for j, n in enumerate(ns):
                x, y = curve(grows, "der", n, L, x="omega_T_rpm", y="v")
                if len(x):
                    tag = ", ".join(f"{k.split('.')[-1]} {v}" for k, v in zip(extra_keys, g))
                    if len(Ls) > 1:
                        tag += f", L {1e3 * L:g} mm"
                    ax.plot(x, 1e3 * y, ls=dashes[j % len(dashes)], marker=markers[j % len(markers)], ms=3.0,
                            color=cmap(i % 10), label=f"{tag}, n={n}")
    _finish(ax, r"$\omega_T$ (rpm)", r"$v$ (mm/s, DER)", title or "speed vs motor speed by group",
            legend=dict(ncol=1))
    return fig


def _suffix(extra: tuple, L: float | None, several_L: bool) -> str:
    parts = [f"{k.split('.')[-1]}{v}" for k, v in extra]
    if several_L and L is not None:
        parts.append(f"L{1e3 * L:g}mm")
    return ("_" + "_".join(parts)) if parts else ""


def _draw(jobs: list, dpi: int) -> None:
    for path, make in jobs:
        make().savefig(path, dpi=dpi, pil_kwargs={"compress_level": PNG_COMPRESSION})


#: drawing time of a figure relative to the others: the speed figure is laid out once more, to place its letters
#: (measured, design 2: 0.53 s against 0.25-0.37 s for the others)
FIGURE_COST = {"figure_speed": 2.0}


def _halves(jobs: list) -> tuple[list, list]:
    """The jobs in two halves of about equal drawing time (FIGURE_COST): the costliest first, each to the half
    with less so far; each half in the jobs' own order."""
    def cost(job):
        return FIGURE_COST.get(getattr(getattr(job[1], "func", None), "__name__", ""), 1.0)
    totals, halves = [0.0, 0.0], ([], [])
    for i in sorted(range(len(jobs)), key=lambda i: -cost(jobs[i])):
        k = 0 if totals[0] <= totals[1] else 1
        totals[k] += cost(jobs[i])
        halves[k].append(i)
    return tuple([jobs[i] for i in sorted(h)] for h in halves)


def _draw_all(jobs: list, dpi: int, processes: int) -> None:
    """Draw and save every (path, make_figure) job: the first half here, the other half in a forked copy of
    this process at the same time (each figure is independent; the drawing, not the data, is most of a sweep's
    last seconds). Where fork is missing or fails, or the copy fails, this process draws its half too."""
    if processes < 2 or len(jobs) < 2 or not hasattr(os, "fork"):
        _draw(jobs, dpi)
        return
    mine, theirs = _halves(jobs)
    try:
        pid = os.fork()
    except OSError:
        _draw(jobs, dpi)
        return
    if pid == 0:                                   # the copy: its half, then out without Python's exit handlers
        code = 1
        try:
            _draw(theirs, dpi)
            code = 0
        finally:
            os._exit(code)
    try:
        _draw(mine, dpi)
    finally:
        _, status = os.waitpid(pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        _draw(theirs, dpi)


def make_all(directory: str | Path, dpi: int = DPI, processes: int | None = None) -> dict:
    """Read DIR/results.csv (and the manifest, for the grid keys), write the PNGs and summary.json into DIR.
    Returns {"figures": [paths], "summary": {...}}. The figures are drawn by ``processes`` processes (default:
    two where there are two cores, else one)."""
    if processes is None:
        processes = 2 if (os.cpu_count() or 1) >= 2 else 1
    directory = Path(directory)
    rows = read_results(directory)
    if not rows:
        from .grid import SweepError
        raise SweepError(f"{directory}: the results CSV has no finished points yet")
    manifest = read_manifest(directory)
    extra_keys = [k for k in manifest["grid"] if k not in PLOT_KEYS]
    scene_name = manifest.get("scene", {}).get("scene.name", "")
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple((k, r[k]) for k in extra_keys), []).append(r)
    jobs, summary = [], {"scene": scene_name, "groups": []}
    for extra, grows in sorted(groups.items()):
        Ls = sorted({r["L"] for r in grows})
        tag = ", ".join(f"{k} = {v}" for k, v in extra)
        made = []
        for L in Ls:
            sfx = _suffix(extra, L, len(Ls) > 1)
            head = f"{scene_name}, L = {1e3 * L:g} mm" + (f", {tag}" if tag else "")
            Lrows = [r for r in grows if r["L"] == L]
            made += [(f"speed_vs_omega{sfx}.png", partial(figure_speed, Lrows, L, title=f"speed: {head}")),
                     (f"head_spin{sfx}.png", partial(figure_head_spin, Lrows, L, title=f"head spin: {head}")),
                     (f"deflection{sfx}.png", partial(figure_deflection, Lrows, L,
                                                      title=f"beam tip deflection: {head}"))]
            summary["groups"].append({"extra": dict(extra), **summarise(Lrows, L)})
        made.append((f"speed_vs_length{_suffix(extra, None, False)}.png",
                     partial(figure_length, grows, title=f"{scene_name}: v vs omega_T by flagellum length"
                                                         + (f", {tag}" if tag else ""))))
        jobs += [(directory / name, make) for name, make in made]
    if extra_keys and len(groups) > 1 and any(r["framework"] == "der" for r in rows):
        jobs.append((directory / "speed_by_group.png",
                     partial(figure_groups, rows, extra_keys,
                             title=f"{scene_name}: DER speed by " + ", ".join(extra_keys))))
    _draw_all(jobs, dpi, processes)
    figures = [str(path) for path, _ in jobs]
    (directory / "summary.json").write_text(json_output(summary, indent=1))     # strict JSON: NaN written as null
    return {"figures": figures, "summary": summary}


def format_summary(summary: dict) -> str:
    lines = [f"sweep summary: {summary['scene']}"]
    for g in summary["groups"]:
        head = f"L = {1e3 * g['L']:g} mm" + "".join(f", {k} = {v}" for k, v in g["extra"].items())
        lines.append(f"  {head}: {g['points']} points, {len(g['der_hit_cap'])} DER runs hit the time cap, "
                     f"{len(g['errors'])} errors")
        for fw, c in g["crossover"].items():
            where = ", ".join(f"{x:.4g}" for x in c["omega_T_bar"]) or "none"
            lines.append(f"    {FRAMEWORK_LABELS[fw]:13s} n={c['pair'][1]} overtakes n={c['pair'][0]} at "
                         f"omega_T_bar = {where}; faster at {len(c['larger_n_faster_at'])} of the points")
        for k, st in g["steepest_slope"].items():
            if k.startswith("der"):
                lines.append(f"    steepest v_bar slope, {k}: omega_T_bar = {st['x']:.4g} (slope {st['slope']:.3g})"
                             + ("" if st["interior"] else " [end of range: no interior maximum]"))
        for k, s in g["omega_h_share"].items():
            lines.append(f"    omega_h/omega_T {k:16s} {100 * s['min']:.1f}..{100 * s['max']:.1f}% "
                         f"(mean {100 * s['mean']:.1f}%)")
        for k, b in g["beam_vs_der"].items():
            rel = [r for r in b["relative_difference"] if r is not None and math.isfinite(r)]
            if not rel:
                continue
            fw, n = k.split(" ")
            cross = ", ".join(f"{x:.4g}" for x in b["curves_cross_at"]) or "none"
            lines.append(f"    v_bar {FRAMEWORK_LABELS[fw]} vs DER, {n}: {100 * rel[0]:+.1f}% at omega_T_bar = "
                         f"{b['omega_T_bar'][0]:.4g}, {100 * rel[-1]:+.1f}% at {b['omega_T_bar'][-1]:.4g}; "
                         f"max |diff| {100 * max(map(abs, rel)):.1f}%; curves cross at {cross}")
        est = g.get("der_error_estimate") or {}
        if any(est.get(k) is not None for k in ("omega_h", "omega_t", "v")):
            from ..physics.error_estimate import percent
            lines.append("    DER estimated numerical error: " + ", ".join(
                f"{k} up to {percent(est.get(k))}" for k in ("omega_h", "omega_t", "v")))
            if est.get("above_1_percent"):
                lines.append(f"    WARNING: {len(est['above_1_percent'])} point(s) estimated above 1% (e.g. "
                             f"{est['above_1_percent'][0]}): ask for accuracy with accuracy.rtol")
        for err in g["errors"][:5]:
            lines.append(f"    error: {err}")
    return "\n".join(lines)
