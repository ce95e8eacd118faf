"""Every result's error estimate: the stepper's velocity error is the analytic one in steady rotation, and the
estimated total error (time + space) is honest within a factor of 3 against the exact rod and the converged
free robot."""
import json
import math

import numpy as np
import pytest

from flagbot_sim.physics import Simulation, error_estimate as ee
from flagbot_sim.physics.model import RobotModel
from flagbot_sim.physics.network import flagellum_edge_count
from flagbot_sim.physics.steady import SteadySolver, summary
from flagbot_sim.physics.stepper import VELOCITY_ERROR_EVERY
from flagbot_sim.reference import rod_bvp
from flagbot_sim.scene import load_scene

from cli_helpers import flagbot

D2_CLAMPED = ["flagellum.length=0.089", "medium.mu=2.125", "plate.diameter=0.03"]


@pytest.mark.parametrize("integrator,expected", [("bdf2", lambda wh: wh * wh / 3.0),
                                                 ("implicit_euler", lambda wh: wh / 2.0)])
def test_the_steps_velocity_error_is_the_integrators_in_steady_rotation(integrator, expected):
    """The clamped flagellum turns rigidly at omega once steady: BDF2's velocity is (omega h)^2 / 3 too fast,
    implicit Euler's turned by omega h / 2, and that is what each step's estimate reports."""
    sc = load_scene("clamped_flagellum", ["motor.omega_rpm=100", f"time.integrator={integrator}",
                                          "flagellum.length=0.05"])
    sim = Simulation(sc)
    assert math.isnan(sim.step().velocity_error)          # no history yet
    sim.run(4.0)
    wh = sc.omega_T * sc.time.dt
    # fixed steps estimate it on every VELOCITY_ERROR_EVERY-th step
    sampled = [e for e in (sim.step().velocity_error for _ in range(VELOCITY_ERROR_EVERY)) if not math.isnan(e)]
    assert len(sampled) == 1 and sampled[0] == pytest.approx(expected(wh), rel=0.02)
    assert sim.velocity_error() == pytest.approx(expected(wh), rel=0.02)


def test_an_error_controlled_steps_velocity_error_is_reported_too():
    sc = load_scene("clamped_flagellum", ["motor.omega_rpm=100", "time.rtol=1e-3", "flagellum.length=0.05"])
    sim = Simulation(sc)
    sim.run(3.0)
    h = sim.last_stats.substep_dts[-1]
    assert sim.last_stats.velocity_error == pytest.approx((sc.omega_T * h) ** 2 / 3.0, rel=0.05)


def _true_clamped(out, sc):
    ref = rod_bvp.from_scene(sc)
    return ee.relative_errors(out, {"Fx": ref.Fx, "Tx": ref.Tx, "tip": list(ref.tip)}, sc)


@pytest.mark.parametrize("design,rpm", [("d1", 10), ("d1", 500), ("d2", 100), ("d2", 2000)])
def test_the_estimate_is_honest_against_the_exact_rod(design, rpm):
    """The clamped flagellum at the default discretisation (BDF2, dt = 1e-2 s, ~4.1 mm edges): the run's
    estimated error is within a factor of 3 of its true error against the rod BVP (the largest over Fx, Tx and the
    tip, as docs/accuracy.md measures a run), and no output's true error exceeds its estimate by 3x or more
    (one output's can be much smaller than its estimate, the sum of the parts' sizes, where its time and space
    errors have opposite signs and cancel)."""
    sc = load_scene("clamped_flagellum", (D2_CLAMPED if design == "d2" else []) + [f"motor.omega_rpm={rpm}"])
    sim = Simulation(sc)
    assert sim.run_until_steady(100.0)
    out = sim.summary()
    est = ee.for_run(sim, out)
    e = est["error_estimate"]
    true = _true_clamped(out, sc)
    assert set(e) == {"Fx", "Tx", "tip"}
    assert est["error_estimate_time"] and est["error_estimate_space"]
    for k in e:
        assert e[k] == pytest.approx(est["error_estimate_time"][k] + est["error_estimate_space"][k], rel=1e-12)
    assert 1 / 3 < max(true.values()) / max(e.values()) < 3
    for k in e:
        assert true[k] < 3 * e[k], k
    assert 1 / 3 < true["tip"] / e["tip"] < 3


def test_the_estimate_is_honest_against_the_converged_free_robot():
    """Design 2's free robot at 300 rpm, time and space errors both ~0.5%: each output's estimated error is
    within a factor of 3 of its error against the converged answer (the steady solver at a quarter and an eighth
    of the edge length, Richardson-extrapolated); at 100 rpm, where they have opposite signs, the run's worst."""
    for rpm in (300, 100):
        true, e = _free_errors(load_scene("design2", [f"motor.omega_rpm={rpm}"]))
        if rpm == 300:
            for k in ("omega_h", "omega_t", "v"):
                assert 1 / 3 < true[k] / e[k] < 3, (k, true[k], e[k])
        assert 1 / 3 < max(true.values()) / max(e.values()) < 3
        for k in e:
            assert true[k] < 3 * e[k], k


def _free_errors(sc):
    sim = Simulation(sc)
    assert sim.run_until_steady(100.0)
    out = sim.summary()
    e = ee.for_run(sim, out)["error_estimate"]
    fine = []
    for f in (4, 8):
        s2 = sc.with_overrides({"flagellum.edge_length": sc.flagellum.edge_length / f})
        m = RobotModel(s2)
        fine.append((summary(m, SteadySolver(m).solve(sc.omega_T)), flagellum_edge_count(s2.flagellum.length,
                                                                                          s2.flagellum.edge_length)))
    (a, na), (b, nb) = fine
    r2 = (nb / na) ** 2
    converged = {k: b[k] + (b[k] - a[k]) / (r2 - 1) for k in ("omega_h", "omega_t", "v")}
    return ee.relative_errors(out, converged, sc), e


def test_richardson_recovers_the_rods_space_error():
    """The steady solver alone (no time error): its space estimate against the rod BVP, design 1 at 10 rpm."""
    sc = load_scene("clamped_flagellum", ["motor.omega_rpm=10"])
    m = RobotModel(sc)
    sol = SteadySolver(m).solve(sc.omega_T)
    row = summary(m, sol)
    est = ee.for_steady(m, sol, row)
    assert est["error_estimate_time"] is None and est["error_estimate"] == est["error_estimate_space"]
    true = _true_clamped(row, sc)
    for k in ("Fx", "Tx", "tip"):
        assert 0.8 < true[k] / est["error_estimate"][k] < 1.25, k


def test_flagbot_steady_and_run_report_their_errors(tmp_path):
    r = flagbot("steady", "clamped_flagellum", "--set", "motor.omega_rpm=2000", "--no-stability", "--json")
    assert r.returncode == 0, r.stderr
    row = json.loads(r.stdout)
    assert set(row["error_estimate"]) == {"Fx", "Tx", "tip"} and row["error_estimate_time"] is None
    assert max(row["error_estimate"].values()) < 0.01 and row["warnings"] == []
    r = flagbot("run", "clamped_flagellum", "--set", "motor.omega_rpm=500", "--set", "flagellum.length=0.05",
                "--duration", "5", "--quiet")
    assert r.returncode == 0, r.stderr
    # the default step at 500 rpm: the time error is over 1%, and the summary says so in one line
    assert "Fx  (axial force on the flagellum)  =" in r.stdout and " +/- " in r.stdout
    warning = [line for line in r.stdout.splitlines() if "estimated numerical error" in line]
    assert len(warning) == 1 and "time step" in warning[0]
    r = flagbot("run", "design1", "--duration", "2", "--json", "--quiet")
    out = json.loads(r.stdout)
    assert set(out["error_estimate"]) == {"omega_h", "omega_t", "v"}
    assert set(out["error_estimate_time"]) == set(out["error_estimate_space"]) == {"omega_h", "omega_t", "v"}
    # a run stopped before it settles: its error bars do not claim to bound the distance from the steady state
    assert out["steady"] is False
    r = flagbot("run", "design1", "--duration", "1", "--quiet")
    verdict = [line for line in r.stdout.splitlines() if "steady over the last" in line]
    assert " +/- " in r.stdout and len(verdict) == 1 and "numerical error alone" in verdict[0], r.stdout


def test_percentages_read_as_the_summary_prints_them():
    assert ee.percent(0.001) == "0.1%" and ee.percent(0.0123) == "1.2%" and ee.percent(0.5) == "50%"
    assert ee.percent(1e-7) == "<0.001%" and ee.percent(math.nan) == "--" and ee.percent(None) == "--"
    assert ee.plus_minus({"error_estimate": {"v": 0.001}}, "v") == " +/- 0.1%"
    assert ee.plus_minus({}, "v") == ""
    assert ee.warning_line({"error_estimate": {"v": 0.009}}) is None
    assert "v exceeds 1%" in ee.warning_line({"error_estimate": {"v": 0.02}, "error_estimate_time": {"v": 0.019},
                                              "error_estimate_space": {"v": 0.001}})
    assert np.isclose(ee.total({"a": 1.0}, {"a": 2.0})["a"], 3.0) and ee.total(None, None) is None


def test_accuracy_rtol_chooses_the_discretisation_and_lands_within_it():
    """accuracy.rtol = 1e-3 on design 2's clamped flagellum at 100 rpm: BDF2 with time.rtol = 5e-4 and an edge
    length whose space error is 0.4 of the request; the time-stepped run lands within 0.1% of the exact rod in
    Fx, Tx and the tip (relative to its deflection, as docs/accuracy.md measures it)."""
    from flagbot_sim.scene import SceneError
    sc = load_scene("clamped_flagellum", D2_CLAMPED + ["motor.omega_rpm=100", "accuracy.rtol=1e-3"])
    sim = Simulation(sc)
    ch = sim.accuracy
    assert ch["time.integrator"] == "bdf2" and ch["time.rtol"] == pytest.approx(5e-4)
    assert sim.scene.time.rtol == pytest.approx(5e-4) and sim.scene.accuracy.rtol == 0.0
    assert sim.scene.flagellum.edge_length == ch["flagellum.edge_length"] < sc.flagellum.edge_length
    assert ch["space_error_estimate"] <= 0.4e-3 * 1.05
    assert sim.run_until_steady(100.0)
    out = sim.summary()
    assert out["accuracy"] == ch
    ref = rod_bvp.from_scene(sim.scene)
    straight = np.array([sc.flagellum.length, sc.R_d, 0.0])
    err = [abs(out["Fx"] / ref.Fx - 1), abs(out["Tx"] / ref.Tx - 1),
           np.linalg.norm(np.asarray(out["tip"]) - ref.tip) / np.linalg.norm(ref.tip - straight)]
    assert max(err) < 1e-3, err
    # it chooses what it names: setting one of them as well is refused, and so is a request below the floors
    for extra in ("time.rtol=1e-3", "flagellum.edge_length=0.002"):
        with pytest.raises(SceneError, match="accuracy.rtol"):
            load_scene("clamped_flagellum", ["accuracy.rtol=1e-3", extra])
    with pytest.raises(SceneError, match="at least 0.0001"):
        load_scene("clamped_flagellum", ["accuracy.rtol=1e-5"])


def test_a_sweeps_summary_names_its_largest_estimated_errors():
    from flagbot_sim.sweep.plots import _error_summary
    rows = [{"framework": "der", "error": "", "point": "a", "error_estimate_omega_h": 0.002,
             "error_estimate_omega_t": 0.001, "error_estimate_v": 0.02},
            {"framework": "der", "error": "", "point": "b", "error_estimate_omega_h": math.nan,
             "error_estimate_omega_t": 0.003, "error_estimate_v": 0.004},
            {"framework": "nlb", "error": "", "point": "a", "error_estimate_v": math.nan}]
    s = _error_summary(rows)
    assert s == {"omega_h": 0.002, "omega_t": 0.003, "v": 0.02, "above_1_percent": ["a"]}
