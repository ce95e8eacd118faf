"""`flagbot fit`: constants recovered from synthetic experiments within their 95% intervals, an unidentifiable
parameter reported as such, held-out predictions (the paper's n = 2 -> n = 3 protocol), a sweep's results.csv
accepted as data, and the command as users run it (a process, the local pool) giving the same numbers as the
in-process serial fit."""
import csv
import json
import math

import numpy as np
import pytest

from flagbot_sim.cli import main
from flagbot_sim.fit.data import DataError, read_data
from flagbot_sim.fit.evaluate import evaluate
from flagbot_sim.fit.fit import FitError, parse_parameters, predict, run_fit
from flagbot_sim.fit.pool import Engine
from flagbot_sim.scene import load_scene

from cli_helpers import flagbot

# design 2 with 50 mm flagella (a few ms per steady state); its paper constants are the truth
SHORT = ["flagellum.length=0.05"]
TRUTH = {"head.C1": 28.75, "head.C2": 0.938, "medium.mu": 2.125}
START = ["head.C1=20", "head.C2=1.5", "medium.mu=3.0"]
RPMS = [20, 40, 60, 80, 100, 120]
NOISE = 0.02                   # 2% scatter, its std given in the file


def simulate(rows_overrides):
    truth = load_scene("design2", SHORT)
    rows = [{"index": i, "overrides": o} for i, o in enumerate(rows_overrides)]
    return evaluate(Engine("serial"), truth, [{}], rows)[0]


@pytest.fixture(scope="module")
def experiments(tmp_path_factory):
    """n = 2 'experiments' at six motor speeds (v and omega_h with 2% noise and their stds) and n = 3 held-out
    ones (the truth itself), as CSV files in the sweep CSV's shorthand columns."""
    d = tmp_path_factory.mktemp("fit")
    sims = simulate([{"motor.omega_rpm": float(r)} for r in RPMS])
    rng = np.random.default_rng(1)
    with open(d / "n2.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["n", "omega_T_rpm", "v", "v_std", "omega_h", "omega_h_std", "comment"])
        for r, s in zip(RPMS, sims):
            sv, sw = NOISE * abs(s["v"]), NOISE * abs(s["omega_h"])
            w.writerow([2, r, repr(s["v"] + sv * rng.standard_normal()), repr(sv),
                        repr(s["omega_h"] + sw * rng.standard_normal()), repr(sw), "trial"])
    held = simulate([{"motor.omega_rpm": float(r), "robot.n_flagella": 3} for r in (30, 60, 90)])
    with open(d / "n3.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["n", "omega_T_rpm", "v", "omega_h"])
        for r, s in zip((30, 60, 90), held):
            w.writerow([3, r, repr(s["v"]), repr(s["omega_h"])])
    base = load_scene("design2", [*SHORT, *START])
    params = parse_parameters("head.C1,head.C2,medium.mu", base)
    data = read_data(d / "n2.csv", base, exclude=tuple(p.key for p in params))
    result = run_fit(base, params, data, Engine("serial"))
    return d, base, result


def test_constants_are_recovered_within_their_95_percent_intervals(experiments):
    d, base, res = experiments
    assert res.success and res.identified and not res.warnings
    assert res.dof == 2 * len(RPMS) - 3
    # the scatter is the 2% given: s^2 = chi^2/dof of order 1
    assert 0.2 < res.s2 < 3.0
    for e in res.estimates:
        lo, hi = e.ci95
        assert lo < TRUTH[e.key] < hi, e
        assert lo < e.value < hi and e.log
    # the intervals are informative: C2 (set by omega_h directly) to a few %, C1 and mu (correlated: v depends
    # on the head drag C1 mu against the flagella's mu) within a factor of 1.6
    by = {e.key: e for e in res.estimates}
    assert by["head.C2"].ci95[1] / by["head.C2"].ci95[0] < 1.1
    assert all(by[k].ci95[1] / by[k].ci95[0] < 2.6 for k in ("head.C1", "medium.mu"))
    C = res.correlation
    assert C.shape == (3, 3) and np.allclose(C, C.T) and np.allclose(np.diag(C), 1.0)
    assert C[0, 2] > 0.9                      # C1 and mu trade off
    # residuals per row, both outputs, normalised by the stds from the file
    assert len(res.rows) == len(RPMS) and all(set(r) >= {"v", "omega_h", "line"} for r in res.rows)
    assert all(r["v"]["std_given"] and abs(r["v"]["residual"]) < 4 for r in res.rows)


def test_unidentifiable_parameter_is_reported_not_returned_as_a_number(experiments, tmp_path):
    """omega_h alone carries no information on C1 (the head's drag sets v): C1 is flagged, without an interval,
    while C2, which omega_h does determine, keeps its interval."""
    d, _, _ = experiments
    with open(d / "n2.csv") as f:
        rows = list(csv.DictReader(f))
    only_spin = tmp_path / "spin.csv"
    with open(only_spin, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["n", "omega_T_rpm", "omega_h", "omega_h_std"])
        for r in rows:
            w.writerow([r["n"], r["omega_T_rpm"], r["omega_h"], r["omega_h_std"]])
    base = load_scene("design2", [*SHORT, *START])
    params = parse_parameters("head.C1,head.C2", base)
    res = run_fit(base, params, read_data(only_spin, base), Engine("serial"))
    by = {e.key: e for e in res.estimates}
    assert not res.identified
    assert not by["head.C1"].identifiable and by["head.C1"].ci95 is None
    assert "not identifiable" in by["head.C1"].note and any("head.C1" in w for w in res.warnings)
    assert by["head.C2"].identifiable and by["head.C2"].ci95[0] < TRUTH["head.C2"] < by["head.C2"].ci95[1]
    assert res.singular_values[-1] < 1e-7 * res.singular_values[0]
    # alone, C1 gets an interval without bounds: (0, inf) for a log parameter
    res1 = run_fit(base, parse_parameters("head.C1", base), read_data(only_spin, base), Engine("serial"),
                   max_evaluations=8)
    (e,) = res1.estimates
    assert not e.identifiable and (e.ci95 is None or (e.ci95[0] < 1e-3 * e.value and e.ci95[1] > 1e3 * e.value))


def test_prediction_of_held_out_rows(experiments):
    """The fitted n = 2 constants predict the n = 3 robot (here: the truth) to the fit's own uncertainty."""
    d, base, res = experiments
    held = read_data(d / "n3.csv", base)
    pred = predict(res.fitted_scene(), held, Engine("serial"))
    assert [r["line"] for r in pred["rows"]] == [2, 3, 4] and not pred["failed_lines"]
    assert all(r["inputs"]["robot.n_flagella"] == 3 for r in pred["rows"])
    for o in ("v", "omega_h"):
        assert 0 < pred["summary"][o]["max_relative_error"] < 0.03
    # every predicted value carries its numerical error: the space part (a steady solve), as a steady solve of that
    # row's scene reports it
    from flagbot_sim.physics import error_estimate
    from flagbot_sim.physics.model import RobotModel
    from flagbot_sim.physics.steady import SteadySolver, summary
    row = pred["rows"][-1]
    sc = res.fitted_scene().with_overrides(row["inputs"])
    m = RobotModel(sc)
    sol = SteadySolver(m).solve(sc.omega_T)
    own = error_estimate.for_steady(m, sol, summary(m, sol))["error_estimate"]
    for o in ("v", "omega_h"):
        assert row[o]["error_estimate"] == pytest.approx(own[o], rel=1e-3)
        assert pred["summary"][o]["max_error_estimate"] == max(r[o]["error_estimate"] for r in pred["rows"])
    # and the prediction is a real evaluation: the start constants predict it much worse
    worse = predict(base, held, Engine("serial"))
    assert worse["summary"]["v"]["rms_relative_error"] > 5 * pred["summary"]["v"]["rms_relative_error"]


def test_a_sweep_results_csv_is_valid_input(tmp_path):
    """A real `flagbot sweep` directory's results.csv: the der rows are the data (the beam rows and the other
    columns ignored), and fitting C2 to them from a wrong start gives back the scene's own C2."""
    out = tmp_path / "sweep"
    assert main(["sweep", "design2", "--set", "flagellum.length=0.05", "--grid", "rpm=40,80,120", "--frameworks",
                 "der,lb", "--out", str(out), "--quiet", "--no-plot", "--engine", "serial"]) == 0
    base = load_scene("design2", [*SHORT, "head.C2=2.0"])
    data = read_data(out / "results.csv", base, exclude=("head.C2",))
    assert len(data.rows) == 3 and data.dropped == 3 and data.outputs == ["v", "omega_h"]
    assert {"motor.omega_rpm", "robot.n_flagella", "flagellum.length"} <= set(data.inputs)
    assert {"framework", "omega_t", "stable", "power"} <= set(data.ignored)
    res = run_fit(base, parse_parameters("head.C2", base), data, Engine("serial"))
    (e,) = res.estimates
    assert e.value == pytest.approx(TRUTH["head.C2"], rel=1e-5) and e.identifiable
    assert max(abs(r["omega_h"]["relative"]) for r in res.rows) < 1e-6


def test_bad_inputs_are_refused_with_the_reason(tmp_path):
    base = load_scene("design2", SHORT)
    bad = tmp_path / "bad.csv"
    bad.write_text("n,omega_T_rpm,head.C3,v\n2,40,1,1e-5\n")
    with pytest.raises(DataError, match="column 'head.C3' is not a scene key"):
        read_data(bad, base)
    bad.write_text("n,omega_T_rpm,v,v_std\n2,40,1e-5,0\n")
    with pytest.raises(DataError, match="line 2: v_std must be a positive number"):
        read_data(bad, base)
    bad.write_text("n,omega_T_rpm,omega_t\n2,40,1\n")
    with pytest.raises(DataError, match="no output column"):
        read_data(bad, base)
    bad.write_text("n,omega_T_rpm,v,head.C1\n2,40,1e-5,3\n")
    with pytest.raises(DataError, match="head.C1 is both a fitted parameter and a data column"):
        read_data(bad, base, exclude=("head.C1",))
    bad.write_text("n,omega_T_rpm,v\n0,40,1e-5\n")
    with pytest.raises(DataError, match="line 2: robot.n_flagella = 0 is out of range"):
        read_data(bad, base)
    with pytest.raises(FitError, match="robot.n_flagella: an integer"):
        parse_parameters("n", base)
    with pytest.raises(FitError, match="only real-valued"):
        parse_parameters("numerics.linear_solver", base)
    with pytest.raises(FitError, match="head.C1: the start value is 0"):
        parse_parameters("head.C1", base.with_overrides({"head.C1": 0.0}))


def test_flagbot_fit_as_users_run_it(experiments):
    """`flagbot fit` in its own process on the local pool (2 workers): the serial in-process fit's numbers to
    the last bit (tasks do not depend on the engine), strict JSON, a fitted scene that loads, a PNG, the
    held-out prediction; exit status 0 (every parameter identified)."""
    d, _, res = experiments
    out = d / "cli"
    p = flagbot("fit", "design2", str(d / "n2.csv"), "--set", SHORT[0], *sum((["--set", s] for s in START), []),
                "--fit", "head.C1,head.C2,medium.mu", "--predict", str(d / "n3.csv"), "--engine", "local",
                "--workers", "2", "--out", str(out), "--json", "--quiet")
    assert p.returncode == 0, p.stderr
    got = json.loads(p.stdout, parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))
    assert [q["estimate"] for q in got["parameters"]] == [e.value for e in res.estimates]
    assert [q["ci95"] for q in got["parameters"]] == [list(e.ci95) for e in res.estimates]
    assert got["identified"] and got["engine"]["workers"] == 2
    assert len(got["predict"]["rows"]) == 3
    fitted = load_scene(got["files"]["scene"])
    assert fitted.head.C1 == res.estimates[0].value and fitted.flagellum.length == 0.05
    import matplotlib.image
    img = matplotlib.image.imread(got["files"]["plot"])
    assert img.ndim == 3 and img.shape[0] > 300 and img.shape[1] > 600
    assert json.loads((out / "fit.json").read_text())["parameters"] == got["parameters"]
    assert math.isfinite(got["chi2"])
