"""Sweep figures and summary: drawn from the CSV alone, with the series, crossovers and steepest-slope points the
paper's figures have (SpeedVSFlagellaNumber, SpeedVSFlagellaLengthandNumber, comparison)."""
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
    # the CLI path with the simulator and the beam solver booby-trapped (other commands import them when they
    # register, so "not imported" cannot be asked of the CLI; "never called" can)
    code = ("import sys; from flagbot_sim.cli import main; import flagbot_sim.physics as ph, flagbot_sim.beam as bm\n"
            "def boom(*a, **k): raise AssertionError('sweep-plot ran a simulation')\n"
            "ph.Simulation.__init__ = boom; bm.balance.solve_balance = boom; bm.solve_balance = boom\n"
            "sys.exit(main(['sweep-plot', sys.argv[1]]))")
    res = python_c(code, str(copy))
    assert res.returncode == 0, res.stderr
    for L in ("50", "60"):
        for stem in ("speed_vs_omega", "head_spin", "deflection"):
            png = copy / f"{stem}_L{L}mm.png"
            assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert (copy / "speed_vs_length.png").stat().st_size > 10_000
    assert (copy / "summary.json").exists() and "n=3 overtakes n=2" in res.stdout
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
            ln = speed[f"{fw} n={n}"]
            fwk = {"DER": "der", "NLB w/o head": "nlb-nohead", "NLB": "nlb"}[fw]
            ref = sorted((r["omega_T_bar"], r["v_bar"]) for r in sel if r["framework"] == fwk and r["n"] == n)
            assert len(ref) == 3
            np.testing.assert_array_equal(ln.get_xdata(), [p[0] for p in ref])
            np.testing.assert_array_equal(ln.get_ydata(), [p[1] for p in ref])
    head = lines_by_label(figure_head_spin(sel, L))
    assert {"DER n=2", "DER n=3", "NLB n=2", "NLB w/o head n=3"} <= set(head)
    der2 = sorted((r["omega_T_bar"], r["omega_h_bar"]) for r in sel if r["framework"] == "der" and r["n"] == 2)
    ax_h, ax_share = figure_head_spin(sel, L).axes
    ln = {l.get_label(): l for l in ax_h.get_lines()}["DER n=2"]
    np.testing.assert_array_equal(ln.get_ydata(), [p[1] for p in der2])
    share = {l.get_label(): l for l in ax_share.get_lines()}["DER n=2"]
    np.testing.assert_allclose(share.get_ydata(), [p[1] / p[0] for p in der2], rtol=1e-15)
    defl = lines_by_label(figure_deflection(sel, L))
    assert {f"{fw} n={n}" for fw in ("LB", "NLB w/o head", "NLB") for n in (2, 3)} == set(defl)
    lb = sorted((r["omega_T_bar"], r["w_tip_over_L"]) for r in sel if r["framework"] == "lb" and r["n"] == 3)
    np.testing.assert_array_equal(defl["LB n=3"].get_ydata(), [p[1] for p in lb])
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
    assert marks[0].get_xdata()[0] == pytest.approx(5.0) and marks[0].get_ydata()[0] == pytest.approx(5.0)
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
    assert e == ["E: DER n=2 steepest slope at omega_T_bar=4"] and not any(lb.startswith("F:") for lb in labels)


def test_failed_points_are_left_out_of_the_curves():
    x = np.arange(4.0)
    rows = [row("nlb", 2, xi, xi) for xi in x]
    rows[2] = row("nlb", 2, 2.0, float("nan"), error="no steady state found")
    ln = lines_by_label(figure_speed(rows))["NLB n=2"]
    np.testing.assert_array_equal(ln.get_xdata(), [0.0, 1.0, 3.0])
