"""Figures of fits and design searches (matplotlib's object-oriented API, no pyplot state; PNG files).

* :func:`figure_fit`: measured v and omega_h against the motor speed with the fitted model's curves, one colour
  per group of rows (rows that differ only in the motor speed), held-out rows (``--predict``) with open markers
  and dashed curves; a parity plot (measured vs simulated) where the rows do not vary the motor speed.
* :func:`figure_design`: the objective of a design search against each continuous variable, one line per value
  of the integer variables (the best over the other variables on the grid), the refined optima starred and
  unstable or infeasible grid points crossed out.
"""
from __future__ import annotations

import math

import numpy as np

from .evaluate import RPM_KEY

COLOURS = ["tab:blue", "tab:red", "tab:green", "tab:purple", "tab:orange", "tab:brown", "tab:pink", "tab:gray"]
LABELS = {"v": ("v (mm/s)", 1e3), "omega_h": ("omega_h (rad/s)", 1.0)}


def _group_label(inputs: dict) -> str:
    from .data import _fmt, _short_key
    items = [(k, v) for k, v in inputs.items() if k != RPM_KEY]
    return ", ".join(f"{_short_key(k)}={_fmt(v)}" for k, v in items) or "all rows"


def _groups(rows: list[dict]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for r in rows:
        out.setdefault(_group_label(r["inputs"]), []).append(r)
    return out


def figure_fit(fit: dict, predicted: dict | None = None, curves: dict | None = None, title: str = ""):
    """``fit``/``predicted``: the JSON dicts of a fit and a prediction (rows with measured and simulated
    values); ``curves``: {group label: (rpm array, {output: array})} of the fitted model."""
    from matplotlib.figure import Figure
    outputs = list(fit["outputs"])
    fig = Figure(figsize=(5.2 * len(outputs), 4.4), layout="constrained")
    axes = fig.subplots(1, len(outputs), squeeze=False)[0]
    sets = [("fit", fit["rows"], "o", "-")]
    if predicted is not None:
        sets.append(("predicted", predicted["rows"], "s", "--"))
    rpm_varies = len({r["inputs"].get(RPM_KEY) for r in fit["rows"]}) > 1
    labels = []
    for _, rows, _, _ in sets:
        for g in _groups(rows):
            if g not in labels:
                labels.append(g)
    colour = {g: COLOURS[i % len(COLOURS)] for i, g in enumerate(labels)}
    for ax, out in zip(axes, outputs):
        name, scale = LABELS[out]
        for kind, rows, marker, ls in sets:
            for g, members in _groups(rows).items():
                pts = [(r["inputs"].get(RPM_KEY, math.nan), r[out]) for r in members if out in r]
                if not pts:
                    continue
                c = colour[g]
                y = np.array([p[1]["measured"] for p in pts]) * scale
                s = np.array([p[1]["simulated"] for p in pts]) * scale
                err = np.array([p[1]["std"] if p[1]["std_given"] else 0.0 for p in pts]) * scale
                face = c if kind == "fit" else "white"
                if rpm_varies:
                    x = np.array([p[0] for p in pts], float)
                    ax.errorbar(x, y, yerr=err if err.any() else None, fmt=marker, color=c, mfc=face, ms=5,
                                capsize=2, label=f"{g}: measured" + (" (held out)" if kind != "fit" else ""))
                    if curves and g in curves:
                        cx, cy = curves[g]
                        ax.plot(cx, np.asarray(cy[out]) * scale, ls=ls, color=c,
                                label=f"{g}: " + ("fitted model" if kind == "fit" else "prediction"))
                    else:
                        order = np.argsort(x)
                        ax.plot(x[order], s[order], ls=ls, color=c, marker=".")
                else:
                    ax.errorbar(y, s, xerr=err if err.any() else None, fmt=marker, color=c, mfc=face, ms=5,
                                capsize=2, label=g + (" (held out)" if kind != "fit" else ""))
        if rpm_varies:
            ax.set_xlabel("omega_T (rpm)")
            ax.set_ylabel(name)
            ax.axhline(0.0, color="0.85", lw=0.6, zorder=0)
        else:
            (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
            lo, hi = min(x0, y0), max(x1, y1)
            ax.plot([lo, hi], [lo, hi], color="0.6", lw=0.8, label="simulated = measured")
            ax.set_xlabel(f"measured {name}")
            ax.set_ylabel(f"simulated {name}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    if title:
        fig.suptitle(title, fontsize=9)
    return fig


def figure_design(search: dict):
    """``search``: the JSON dict of a design search (its grid points, refined optima and variables)."""
    from matplotlib.figure import Figure
    cont = [v for v in search["variables"] if not v["integer"]]
    ints = [v["key"] for v in search["variables"] if v["integer"]]
    panels = cont or search["variables"][:1]
    fig = Figure(figsize=(5.0 * len(panels), 4.2), layout="constrained")
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    obj = search["objective"]
    for ax, var in zip(axes, panels):
        key = var["key"]
        combos: dict[tuple, dict] = {}
        for p in search["grid"]:
            c = tuple(p["design"][k] for k in ints)
            x = p["design"][key]
            slot = combos.setdefault(c, {})
            if p["feasible"]:
                if x not in slot or p["objective"] > slot[x][0]:
                    slot[x] = (p["objective"], True)
            else:
                slot.setdefault(x, (math.nan, False))
        crossed = False
        for i, (c, pts) in enumerate(sorted(combos.items())):
            colour = COLOURS[i % len(COLOURS)]
            label = ", ".join(f"{k.split('.')[-1]}={v}" for k, v in zip(ints, c)) or "grid"
            xs = np.array(sorted(pts))
            ys = np.array([pts[x][0] for x in xs])
            ax.plot(xs * var["display_scale"], ys * obj["display_scale"], "-o", color=colour, ms=4, label=label)
            bad = [x for x in xs if not pts[x][1]]
            if bad:
                crossed = True
                ax.plot(np.array(bad) * var["display_scale"], np.full(len(bad), np.nanmin(ys) if
                        np.isfinite(ys).any() else 0.0) * obj["display_scale"], "x", color=colour, ms=7)
            for opt in search["refined"]:
                if opt.get("design") and tuple(opt["design"][k] for k in ints) == c and opt["feasible"]:
                    ax.plot(opt["design"][key] * var["display_scale"], opt["objective"] * obj["display_scale"],
                            "*", color=colour, ms=14, mec="k")
        ax.set_xlabel(f"{key} ({var['display_unit']})" if var["display_unit"] else key)
        ax.set_ylabel(obj["label"])
        if var.get("log"):
            ax.set_xscale("log")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, title="x: no feasible design there" if crossed else None, title_fontsize=7)
    best = search.get("optimum")
    title = f"maximise {obj['label']}"
    if search.get("max_power") is not None:
        title += f" at P <= {search['max_power']:g} W"
    if best:
        title += ": " + ", ".join(f"{k.split('.')[-1]}={v:.4g}" for k, v in best["design"].items())
    fig.suptitle(title + " (grid: best over the other variables; star: refined optimum)", fontsize=9)
    return fig
