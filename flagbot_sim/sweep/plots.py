"""Figures and the summary of a sweep, made from its CSV alone (no simulation, no scene file needed).

Each ``figure_*`` function takes parsed CSV rows and returns a matplotlib ``Figure`` (object-oriented API, no
pyplot state), so tests can inspect its lines and labels before anything is saved:

* ``figure_speed``: v_bar vs omega_T_bar per n, DER and beam (paper Fig. SpeedVSFlagellaNumber a/c/e), with the
  crossover where the larger n overtakes the smaller (paper: C for DER, D for beam theory, here D for NLB w/o
  head and D' for NLB, each with a marker of its own) and the point of steepest slope of each DER curve (paper: E for n = 2, F for n = 3);
* ``figure_head_spin``: omega_h_bar vs omega_T_bar and omega_h / omega_T (panels b/d);
* ``figure_length``: v vs omega_T for every flagellum length and n, DER ("D") and beam ("B") with the paper's
  labels such as D130n2 (Fig. SpeedVSFlagellaLengthandNumber), explained in the legend's title;
* ``figure_deflection``: w(L)/L vs omega_T_bar for LB, NLB w/o head, NLB (Fig. comparison).
"""
from __future__ import annotations

import math
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
STYLE = {"der": dict(ls="-", marker="o", ms=3.5), "nlb-nohead": dict(ls="--", marker=None),
         "nlb": dict(ls=":", marker=None), "lb": dict(ls="-.", marker=None)}
#: the crossover mark of each framework: its letter (the paper's C for DER, D for its beam curves, NLB w/o head)
#: and a marker of its own, so that no two different marks share a letter or a look
CROSSOVER_MARKS = {"der": ("C", dict(marker="X", ms=11, mfc="gold")),
                   "nlb-nohead": ("D", dict(marker="P", ms=11, mfc="lightskyblue")),
                   "nlb": ("D'", dict(marker="h", ms=10, mfc="white")),
                   "lb": ("D''", dict(marker="s", ms=8, mfc="lightgray"))}
N_COLOURS = ["tab:blue", "tab:red", "tab:green", "tab:purple", "tab:orange", "tab:brown"]


# ---------------------------------------------------------------- data
def curve(rows: list[dict], framework: str, n: int, L: float | None = None, x: str = "omega_T_bar",
          y: str = "v_bar") -> tuple[np.ndarray, np.ndarray]:
    """Sorted (x, y) of one framework and n (and L), leaving out failed or non-finite points."""
    pts = [(r[x], r[y]) for r in rows if r["framework"] == framework and r["n"] == n
           and (L is None or r["L"] == L) and not r["error"] and math.isfinite(r[x]) and math.isfinite(r[y])]
    pts.sort()
    return np.array([p[0] for p in pts], float), np.array([p[1] for p in pts], float)


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


def _colour(ns: list[int], n: int) -> str:
    return N_COLOURS[ns.index(n) % len(N_COLOURS)]


# ---------------------------------------------------------------- figures
def _new_figure(ncols: int = 1, width: float = 6.4):
    from matplotlib.figure import Figure
    fig = Figure(figsize=(width * ncols, 4.6), layout="constrained")
    axes = [fig.add_subplot(1, ncols, i + 1) for i in range(ncols)]
    return fig, axes


def _finish(ax, xlabel: str, ylabel: str, title: str, legend: dict | None = None):
    """Axis labels, title, grid and legend (``legend``: its keyword arguments), the same on every figure."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, **(legend or {}))


def figure_speed(rows: list[dict], L: float | None = None, regimes=SPEED_REGIMES, title: str = ""):
    fig, (ax,) = _new_figure()
    ns = n_values(rows)
    fws = [fw for fw in ("der", *regimes) if fw in frameworks_in(rows)]
    for fw in fws:
        for n in ns:
            x, y = curve(rows, fw, n, L)
            if len(x):
                ax.plot(x, y, color=_colour(ns, n), label=_label(fw, n), **STYLE[fw])
    pair = pair_of_n(ns)
    if pair:
        for fw in fws:
            xs, y_lo, y_hi = common(rows, fw, pair[0], fw, pair[1], L)
            name, look = CROSSOVER_MARKS[fw]
            for xc in crossovers(xs, y_lo, y_hi):
                yc = float(np.interp(xc, xs, y_hi))
                ax.plot([xc], [yc], ls="none", color="k", **look,
                        label=f"{name}: {FRAMEWORK_LABELS[fw]} crossover, n={pair[1]} overtakes n={pair[0]} "
                              f"at omega_T_bar={xc:.3g}")
                ax.annotate(name, (xc, yc), textcoords="offset points", xytext=(6, -12))
    for n, name in zip(ns, "EFGHIJ"):
        st = steepest_slope(*curve(rows, "der", n, L))
        if st and st["interior"]:
            ax.plot([st["x"]], [st["y"]], ls="none", marker="*", ms=14, color=_colour(ns, n), mec="k",
                    label=f"{name}: DER n={n} steepest slope at omega_T_bar={st['x']:.3g}")
            ax.annotate(name, (st["x"], st["y"]), textcoords="offset points", xytext=(-12, 6))
    _finish(ax, r"$\bar\omega_T = \omega_T \eta_p L^4 / EI$", r"$\bar v = v \eta_p L^3 / EI$",
            title or "speed vs motor speed")
    return fig


def figure_head_spin(rows: list[dict], L: float | None = None, regimes=SPEED_REGIMES, title: str = ""):
    fig, (ax, ax2) = _new_figure(2, width=5.4)
    ns = n_values(rows)
    fws = [fw for fw in ("der", *regimes) if fw in frameworks_in(rows)]
    for fw in fws:
        for n in ns:
            x, y = curve(rows, fw, n, L, y="omega_h_bar")
            if len(x):
                ax.plot(x, y, color=_colour(ns, n), label=_label(fw, n), **STYLE[fw])
                keep = x != 0
                ax2.plot(x[keep], y[keep] / x[keep], color=_colour(ns, n), label=_label(fw, n), **STYLE[fw])
    xmax = max((r["omega_T_bar"] for r in rows if math.isfinite(r["omega_T_bar"])), default=1.0)
    ax.plot([0, xmax], [0, xmax], color="0.6", lw=0.8, label=r"$\omega_h = \omega_T$")
    ax.set_xlabel(r"$\bar\omega_T$")
    ax.set_ylabel(r"$\bar\omega_h = \omega_h \eta_p L^4 / EI$")
    ax2.set_xlabel(r"$\bar\omega_T$")
    ax2.set_ylabel(r"$\omega_h / \omega_T$")
    ax2.set_ylim(0, 1.05)
    ax.set_title(title or "head spin")
    ax2.set_title("share of the motor speed taken by the head")
    for a in (ax, ax2):
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
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
    fig, (ax,) = _new_figure()
    ns = n_values(rows)
    colours = {"lb": "tab:gray", "nlb-nohead": "tab:blue", "nlb": "tab:red"}
    lines = {n: ls for n, ls in zip(ns, ["-", "--", ":", "-."] * 3)}
    for fw in REGIMES:
        for n in ns:
            x, y = curve(rows, fw, n, L, y="w_tip_over_L")
            if len(x):
                # NLB w/o head is drawn wide and pale underneath: it nearly coincides with NLB (paper Fig.
                # comparison), and should stay visible where it does
                wide = fw == "nlb-nohead"
                ax.plot(x, y, color=colours[fw], ls=lines[n], lw=4 if wide else 1.5, alpha=0.45 if wide else 1.0,
                        label=_label(fw, n))
    _finish(ax, r"$\bar\omega_T$", r"tip deflection $w(L)/L$", title or "beam tip deflection in the three regimes")
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
                 "crossover": {}, "steepest_slope": {}, "omega_h_share": {}, "beam_vs_der": {}}
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


def _suffix(extra: tuple, L: float | None, several_L: bool) -> str:
    parts = [f"{k.split('.')[-1]}{v}" for k, v in extra]
    if several_L and L is not None:
        parts.append(f"L{1e3 * L:g}mm")
    return ("_" + "_".join(parts)) if parts else ""


def make_all(directory: str | Path, dpi: int = 120) -> dict:
    """Read DIR/results.csv (and the manifest, for the grid keys), write the PNGs and summary.json into DIR.
    Returns {"figures": [paths], "summary": {...}}."""
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
    figures, summary = [], {"scene": scene_name, "groups": []}
    for extra, grows in sorted(groups.items()):
        Ls = sorted({r["L"] for r in grows})
        tag = ", ".join(f"{k} = {v}" for k, v in extra)
        made = []
        for L in Ls:
            sfx = _suffix(extra, L, len(Ls) > 1)
            head = f"{scene_name}, L = {1e3 * L:g} mm" + (f", {tag}" if tag else "")
            Lrows = [r for r in grows if r["L"] == L]
            made += [(f"speed_vs_omega{sfx}.png", figure_speed(Lrows, L, title=f"speed: {head}")),
                     (f"head_spin{sfx}.png", figure_head_spin(Lrows, L, title=f"head spin: {head}")),
                     (f"deflection{sfx}.png", figure_deflection(Lrows, L, title=f"beam tip deflection: {head}"))]
            summary["groups"].append({"extra": dict(extra), **summarise(Lrows, L)})
        made.append((f"speed_vs_length{_suffix(extra, None, False)}.png",
                     figure_length(grows, title=f"{scene_name}: v vs omega_T by flagellum length"
                                                + (f", {tag}" if tag else ""))))
        for name, fig in made:
            path = directory / name
            fig.savefig(path, dpi=dpi)
            figures.append(str(path))
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
        for err in g["errors"][:5]:
            lines.append(f"    error: {err}")
    return "\n".join(lines)
