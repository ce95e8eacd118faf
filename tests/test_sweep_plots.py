"""Sweep figures and summary: drawn from the CSV alone, with the series, crossovers and steepest-slope points the
paper's figures have (SpeedVSFlagellaNumber, SpeedVSFlagellaLengthandNumber, comparison)."""
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from cli_helpers import ROOT

from flagbot_sim.cli import main
from flagbot_sim.sweep.plots import (crossovers, figure_deflection, figure_head_spin, figure_length, figure_speed,
                                     steepest_slope, summarise)
from flagbot_sim.sweep.store import read_results

FIGURES = ("speed_vs_omega.png", "head_spin.png", "deflection.png", "speed_vs_length.png")


def row(fw, n, x, y, L=0.1, **kw):
    base = {"point": f"n={n};x={x};L={L}", "framework": fw, "n": n, "L": L, "omega_T_bar": x, "v_bar": y,
            "omega_T_rpm": x, "v": y, "omega_h_bar": 0.8 * x, "w_tip_over_L": 0.01 * x, "error": "",
            "hit_cap": False, "converged": True}
    return {**base, **kw}


def lines_by_label(fig):
    return {ln.get_label(): ln for ax in fig.axes for ln in ax.get_lines()}


def python_c(code, *args):
    """``python -c CODE ARGS`` in a fresh interpreter from the checkout, matplotlib on Agg."""
    return subprocess.run([sys.executable, "-c", code, *args], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"})


# ---------------------------------------------------------------- from a real sweep directory
@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("plots") / "sweep"
    code = main(["sweep", "design2", "--grid", "n=2,3", "--grid", "rpm=40:100:30",
                 "--grid", "L=0.05,0.06", "--t-max", "8", "--window", "1", "--engine", "serial", "--quiet",
                 "--no-plot", "--out", str(d)])
    assert code == 0
    return d


def test_sweep_plot_needs_only_the_csv(sweep_dir, tmp_path):
    # a copy of just the manifest and the CSV, plotted in a fresh interpreter that must never load the simulator
    copy = tmp_path / "copy"
    copy.mkdir()
    for name in ("sweep.json", "results.csv"):
        (copy / name).write_bytes((sweep_dir / name).read_bytes())
    # the CLI path (commands are imported lazily): neither the simulator (its model, stepper, compiled springs:
    # the scene validator's effect registry, physics.effects, is allowed) nor the beam solver is even imported
    code = ("import sys; from flagbot_sim.cli import main; code = main(['sweep-plot', sys.argv[1]])\n"
            "bad = [m for m in ('flagbot_sim.physics.model', 'flagbot_sim.physics.simulation', "
            "'flagbot_sim.physics.elastic', 'flagbot_sim.beam', 'numba') if m in sys.modules]\n"
            "assert not bad, bad; sys.exit(code)")
    res = python_c(code, str(copy))
    assert res.returncode == 0, res.stderr
    for L in ("50", "60"):
        for stem in ("speed_vs_omega", "head_spin", "deflection"):
            png = copy / f"{stem}_L{L}mm.png"
            assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert (copy / "speed_vs_length.png").stat().st_size > 10_000
    assert (copy / "summary.json").exists() and "n=3 overtakes n=2" in res.stdout
    for name in ("summary.json", "sweep.json"):       # strict JSON: no NaN / Infinity tokens
        json.loads((copy / name).read_text(), parse_constant=lambda c: pytest.fail(f"{c} in {name}"))
    # the library path, in a fresh interpreter: plotting does not even import the simulator or the beam solver
    code = ("import sys; from flagbot_sim.sweep.plots import make_all; out = make_all(sys.argv[1]); "
            "bad = [m for m in ('flagbot_sim.physics.simulation', 'flagbot_sim.physics.model', 'flagbot_sim.beam') "
            "if m in sys.modules]; "
            "assert not bad, bad; print(len(out['figures']))")
    res = python_c(code, str(copy))
    assert res.returncode == 0 and res.stdout.strip() == "7", res.stderr


def test_figures_hold_every_series_with_the_csv_numbers(sweep_dir):
    rows = read_results(sweep_dir)
    L = 0.05
    sel = [r for r in rows if r["L"] == L]
    speed = lines_by_label(figure_speed(sel, L))
    for fw in ("DER", "NLB w/o head", "NLB"):
        for n in (2, 3):
            ln = speed[f"{fw} n={n}" + (" (pale band)" if fw == "NLB w/o head" else "")]
            fwk = {"DER": "der", "NLB w/o head": "nlb-nohead", "NLB": "nlb"}[fw]
            ref = sorted((r["omega_T_bar"], r["v_bar"]) for r in sel if r["framework"] == fwk and r["n"] == n)
            assert len(ref) == 3
            np.testing.assert_array_equal(ln.get_xdata(), [p[0] for p in ref])
            np.testing.assert_array_equal(ln.get_ydata(), [p[1] for p in ref])
    head = lines_by_label(figure_head_spin(sel, L))
    assert {"DER n=2", "DER n=3", "NLB n=2", "NLB w/o head n=3 (pale band)"} <= set(head)
    der2 = sorted((r["omega_T_bar"], r["omega_h_bar"]) for r in sel if r["framework"] == "der" and r["n"] == 2)
    ax_h, ax_share = figure_head_spin(sel, L).axes
    ln = {l.get_label(): l for l in ax_h.get_lines()}["DER n=2"]
    np.testing.assert_array_equal(ln.get_ydata(), [p[1] for p in der2])
    share = {l.get_label(): l for l in ax_share.get_lines()}["DER n=2"]
    np.testing.assert_allclose(share.get_ydata(), [p[1] / p[0] for p in der2], rtol=1e-15)
    defl = lines_by_label(figure_deflection(sel, L))
    looks = {"LB": " (wide band)", "NLB w/o head": " (band)", "NLB": ""}
    assert {f"{fw} n={n}{looks[fw]}" for fw in looks for n in (2, 3)} == set(defl)
    lb = sorted((r["omega_T_bar"], r["w_tip_over_L"]) for r in sel if r["framework"] == "lb" and r["n"] == 3)
    np.testing.assert_array_equal(defl["LB n=3 (wide band)"].get_ydata(), [p[1] for p in lb])
    length = lines_by_label(figure_length(rows))
    assert set(length) == {f"{c}{L}n{n}" for c in "DB" for L in (50, 60) for n in (2, 3)}
    d60 = sorted((r["omega_T_rpm"], 1e3 * r["v"]) for r in rows if r["framework"] == "der" and r["n"] == 3
                 and r["L"] == 0.06)
    np.testing.assert_array_equal(length["D60n3"].get_ydata(), [p[1] for p in d60])


# ---------------------------------------------------------------- marks: crossover and steepest slope
def test_crossover_marks_where_three_flagella_overtake_two():
    x = np.arange(0.0, 11.0)
    rows = [row("der", 2, xi, xi) for xi in x] + [row("der", 3, xi, 2 * xi - 5) for xi in x]
    rows += [row("nlb-nohead", 2, xi, xi) for xi in x] + [row("nlb-nohead", 3, xi, 0.5 * xi) for xi in x]
    fig = figure_speed(rows)
    marks = [l for l in fig.axes[0].get_lines() if l.get_label().startswith(("C:", "D:"))]
    assert len(marks) == 1                              # only DER crosses; beam n=3 stays slower throughout
    assert marks[0].get_label().startswith("C: DER crossover, n=3 overtakes n=2")
    # a vertical guide at the crossover (both curves pass 5 there), its letter at the top of the axes
    assert marks[0].get_gid() == "crossover/C" and list(marks[0].get_xdata()) == pytest.approx([5.0, 5.0])
    (letter,) = [t for t in fig.axes[0].texts if t.get_text() == "C"]
    assert letter.xy[0] == pytest.approx(5.0)
    s = summarise(rows)
    assert s["crossover"]["der"]["omega_T_bar"] == pytest.approx([5.0])
    assert s["crossover"]["nlb-nohead"]["omega_T_bar"] == []


def test_falling_behind_is_not_a_crossover():
    x = np.arange(5.0)
    assert crossovers(x, x, 2 - x) == []               # n=3 starts ahead and falls behind
    assert crossovers(x, x, 2 * x - 1.5) == pytest.approx([1.5])


def test_steepest_slope_point_is_marked_only_inside_the_range():
    x = np.linspace(0, 10, 21)
    s_curve = np.tanh(x - 4.0)                           # slope largest at x = 4 (the paper's point E)
    rows = [row("der", 2, xi, yi) for xi, yi in zip(x, s_curve)]
    rows += [row("der", 3, xi, xi ** 2) for xi in x]     # slope still growing at the end: no point F inside
    st = steepest_slope(x, s_curve)
    assert st["interior"] and st["x"] == pytest.approx(4.0)
    assert not steepest_slope(x, x ** 2)["interior"]
    labels = list(lines_by_label(figure_speed(rows)))
    e = [lb for lb in labels if lb.startswith("E:")]
    assert e == [r"E: DER n=2 steepest slope at $\bar\omega_T$ = 4"] and not any(lb.startswith("F:") for lb in labels)


def test_failed_points_are_left_out_of_the_curves():
    x = np.arange(4.0)
    rows = [row("nlb", 2, xi, xi) for xi in x]
    rows[2] = row("nlb", 2, 2.0, float("nan"), error="no steady state found")
    ln = lines_by_label(figure_speed(rows))["NLB n=2"]
    np.testing.assert_array_equal(ln.get_xdata(), [0.0, 1.0, 3.0])


# ---------------------------------------------------------------- figures a person can read
def test_every_mark_has_a_letter_of_its_own_and_every_figure_a_key():
    # both beam regimes cross as well as DER: three crossover guides, three letters, three looks
    x = np.arange(0.0, 11.0)
    rows = []
    for fw, at in (("der", 5.0), ("nlb-nohead", 3.0), ("nlb", 7.0)):
        rows += [row(fw, 2, xi, xi) for xi in x] + [row(fw, 3, xi, 2 * xi - at) for xi in x]
    fig = figure_speed(rows)
    ax = fig.axes[0]
    marks = [l for l in ax.get_lines() if "crossover" in l.get_label()]
    letters = [l.get_label().split(":")[0] for l in marks]
    assert sorted(letters) == ["C", "D", "D'"]
    looks = {str(l.get_linestyle()) for l in marks}
    assert len(looks) == 3
    (legend,) = fig.legends                             # one legend, outside the axes
    texts = [t.get_text() for t in legend.get_texts()]
    assert all(l.get_label() in texts for l in marks)
    # the letters are written at their guides too
    assert sorted(t.get_text() for t in ax.texts) == ["C", "D", "D'"]
    # head spin: one legend names the curves of both panels, and says how NLB and NLB w/o head are told apart
    (legend,) = figure_head_spin(rows).legends
    texts = [t.get_text() for t in legend.get_texts()]
    assert "DER n=2" in texts and "NLB n=3" in texts and "NLB w/o head n=2 (pale band)" in texts
    assert "pale" in legend.get_title().get_text()
    # the length figure's codes are explained in the legend's title
    length = figure_length([{**r, "L": 0.089} for r in rows])
    key = length.axes[0].get_legend().get_title().get_text()
    assert "D = DER" in key and "B = NLB" in key and "D89n2: DER, L = 89 mm, n = 2" in key


SHIPPED = ("design1", "design2", "design1_length", "design2_length")


@pytest.mark.parametrize("name", SHIPPED)
def test_the_shipped_sweeps_figures_hide_nothing(name):
    """The figures of the sweeps under docs/figures, as a reader sees them: every curve at least half visible
    (NLB and NLB w/o head agree to ~1e-4 in omega_h: the old dotted-on-dashed drawing hid one entirely), no two
    labels on one another, no letter on a star and no two stars on one another (design 2's C and E were)."""
    from figure_checks import hidden_curves, label_boxes, mark_boxes, overlapping
    rows = read_results(ROOT / "docs" / "figures" / name)
    figs = [figure_length(rows)]
    for L in sorted({r["L"] for r in rows}):
        sel = [r for r in rows if r["L"] == L]
        figs += [figure_speed(sel, L), figure_head_spin(sel, L), figure_deflection(sel, L)]
    for fig in figs:
        assert hidden_curves(fig) == []
        labels, stars = label_boxes(fig), mark_boxes(fig, "slope/")
        assert overlapping(labels + stars) == []
    # design 2's point C (DER crossover, 20.7) and point E (steepest slope, 19.6) are 1.1 apart: both shown
    if name == "design2":
        ax = figs[1].axes[0]
        assert {l.get_gid() for l in ax.lines} >= {"crossover/C", "slope/E", "slope/F"}
        assert {t.get_text() for t in ax.texts} >= {"C", "E", "F"}


def test_the_old_drawing_would_have_failed_the_visibility_check():
    """The check can fail: NLB dotted over NLB w/o head dashed, same width (the old head-spin figure)."""
    from matplotlib.figure import Figure
    from figure_checks import hidden_curves
    fig = Figure()
    ax = fig.add_subplot()
    x = np.linspace(0, 1, 30)
    ax.plot(x, x, ls="--", lw=1.5, label="NLB w/o head")
    ax.plot(x, x + 1e-6, ls=":", lw=1.5, label="NLB")
    assert [h[0] for h in hidden_curves(fig)] == ["'': NLB w/o head"]
    # and two letters on one spot are seen as overlapping
    from figure_checks import label_boxes, overlapping
    ax.annotate("C", (0.5, 0.5))
    ax.annotate("E", (0.5, 0.5))
    assert overlapping(label_boxes(fig)) == [("text 'C'", "text 'E'")]


def test_summary_json_is_strict_where_a_ratio_is_undefined(tmp_path):
    from flagbot_sim.cliutil import dumps
    x = np.arange(1.0, 4.0)
    rows = [row("der", 2, xi, 0.0) for xi in x] + [row("nlb", 2, xi, xi) for xi in x]   # DER at rest: 0/0
    s = summarise(rows)
    assert math.isnan(s["beam_vs_der"]["nlb n=2"]["relative_difference"][0])
    back = json.loads(dumps(s), parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))
    assert back["beam_vs_der"]["nlb n=2"]["relative_difference"] == [None, None, None]


def test_figures_drawn_by_two_processes_are_the_figures_drawn_by_one(sweep_dir, tmp_path):
    from flagbot_sim.sweep.plots import make_all
    outs = {}
    for k in (1, 2):
        d = tmp_path / f"p{k}"
        d.mkdir()
        for name in ("sweep.json", "results.csv"):
            (d / name).write_bytes((sweep_dir / name).read_bytes())
        outs[k] = (d, make_all(d, processes=k))
    (d1, o1), (d2, o2) = outs[1], outs[2]
    names = [os.path.basename(p) for p in o1["figures"]]
    assert names == [os.path.basename(p) for p in o2["figures"]] and len(names) == 7
    for name in names + ["summary.json"]:
        assert (d1 / name).read_bytes() == (d2 / name).read_bytes(), name


def test_the_speed_figure_is_saved_with_the_layout_its_letters_were_placed_in(tmp_path, monkeypatch):
    """figure_speed lays itself out (at the resolution it is saved at) to measure where its letters go; saving it
    then draws that layout as it is, without laying it out a second time (a third full drawing of the figure)."""
    from matplotlib.layout_engine import ConstrainedLayoutEngine

    from flagbot_sim.plotlabels import renderer_of, text_box
    from flagbot_sim.sweep.plots import DPI
    x = np.arange(0.0, 11.0)
    rows = [row("der", 2, xi, xi) for xi in x] + [row("der", 3, xi, 2 * xi - 5) for xi in x]
    fig = figure_speed(rows)
    assert fig.dpi == DPI
    ax = fig.axes[0]
    before = ax.get_position().bounds
    (letter,) = [t for t in ax.texts if t.get_text() == "C"]
    measured = text_box(letter, renderer_of(fig))
    layouts = []
    original = ConstrainedLayoutEngine.execute
    monkeypatch.setattr(ConstrainedLayoutEngine, "execute", lambda self, f: layouts.append(f) or original(self, f))
    fig.savefig(tmp_path / "speed.png", dpi=DPI)
    assert layouts == []
    assert ax.get_position().bounds == before
    saved = text_box(letter, renderer_of(fig))
    assert (saved.x0, saved.y0, saved.x1, saved.y1) == pytest.approx((measured.x0, measured.y0, measured.x1,
                                                                      measured.y1), abs=1e-9)


def test_the_two_drawing_processes_get_halves_of_equal_cost():
    """The figures are split between the two drawing processes by their drawing time, the speed figure counted
    twice (FIGURE_COST), every figure in exactly one half, each half in the jobs' order: a one-length sweep's four
    figures go speed + length | head spin + deflection (every other one gave the speed and deflection figures,
    3 : 2, to one process), the 144-point sweep's ten split 7 : 6."""
    from functools import partial

    from flagbot_sim.sweep.plots import FIGURE_COST, _halves, figure_deflection, figure_head_spin, figure_length

    def jobs_of(lengths):
        jobs = []
        for L in lengths:
            jobs += [(f"speed{L}", partial(figure_speed, [])), (f"head{L}", partial(figure_head_spin, [])),
                     (f"defl{L}", partial(figure_deflection, []))]
        return jobs + [("length", partial(figure_length, []))]

    def cost(half):
        return sum(FIGURE_COST.get(j[1].func.__name__, 1.0) for j in half)

    a, b = _halves(jobs_of(["89"]))
    assert {tuple(j[0] for j in a), tuple(j[0] for j in b)} == {("speed89", "length"), ("head89", "defl89")}
    jobs = jobs_of(["70", "89", "110"])
    a, b = _halves(jobs)
    assert sorted(j[0] for j in a + b) == sorted(j[0] for j in jobs)
    assert sorted([cost(a), cost(b)]) == [6.0, 7.0]
    assert [j[0] for j in a] == [j[0] for j in jobs if j in a]
