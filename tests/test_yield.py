"""The granular yield (effect 'granular_yield'): the robot stays put below a threshold motor speed, swims above it.

The law F = -F_y v / sqrt(v^2 + v_eps^2) on the head, with the flagella's thrust T(omega_T) at rest, gives a
prediction free of fitted numbers: the robot stays put (creeps at ~v_eps) while T < F_y, and above the
threshold T(omega_T^s) = F_y it swims at v_free (1 - F_y / T), v_free the speed without the yield (the drag is
linear in the velocity, so the excess thrust drives it against the same drag that v_free meets). T comes from
the same model, the robot held by a yield force far above any thrust.
"""
import math

import numpy as np
import pytest

from flagbot_sim.fit.data import read_data
from flagbot_sim.fit.fit import parse_parameters, run_fit
from flagbot_sim.fit.pool import Engine
from flagbot_sim.physics import Simulation
from flagbot_sim.physics.medium import head_drag_coefficient
from flagbot_sim.physics.model import RobotModel
from flagbot_sim.physics.steady import SteadySolver
from flagbot_sim.scene import load_scene
from flagbot_sim.units import RPM

from fd import rel_err

YIELD = "scene.effects=['inertia','rft','head_drag','head_torque','motor','granular_yield']"
SHORT = ["flagellum.length=0.05"]                 # design 2 with short flagella: a few ms per steady state
RPMS = [20, 40, 50, 55, 58, 62, 65, 70, 80, 100, 120, 140]


def speeds(overrides, rpms=RPMS):
    """Steady speeds along the motor speeds (each continued from the one before), and the scene."""
    sc = load_scene("design2", [*SHORT, *overrides])
    solver = SteadySolver(RobotModel(sc))
    out, prev = [], None
    for rpm in rpms:
        prev = solver.solve(rpm * RPM, start=prev)
        out.append(prev.v)
    return sc, np.array(out)


@pytest.fixture(scope="module")
def thrust_and_free_speed():
    """T(omega_T): the yield force on a robot held by F_y = 10 N (creeping at ~1e-12 m/s); v_free."""
    sc, v_held = speeds([YIELD, "medium.yield_force=10.0"])
    eps = sc.medium.yield_speed
    assert np.all(np.abs(v_held) < 1e-3 * eps)           # held: the thrust is the yield force
    T = 10.0 * np.abs(v_held) / np.sqrt(v_held ** 2 + eps ** 2)
    _, v_free = speeds([])
    assert np.all(np.diff(T) > 0) and np.all(np.diff(v_free) > 0)
    return T, v_free, eps


@pytest.mark.parametrize("threshold_rpm", [60.0, 90.0])
def test_stays_put_below_the_threshold_and_swims_continuously_above(thrust_and_free_speed, threshold_rpm):
    """F_y set to the thrust at threshold_rpm: below it |v| stays within a few v_eps of 0 (whatever the robot
    would swim without the yield), above it v follows v_free (1 - F_y/T) continuously from 0; doubling the
    threshold's thrust moves the onset to where the thrust reaches the new F_y (90 rpm: T ~ 2.2 T(60 rpm))."""
    T, v_free, eps = thrust_and_free_speed
    F_y = float(np.interp(threshold_rpm, RPMS, T))
    sc, v = speeds([YIELD, f"medium.yield_force={F_y}"])
    assert sc.medium.yield_speed == eps == 1e-7
    predicted = v_free * np.clip(1.0 - F_y / T, 0.0, None)
    assert np.all(np.abs(v - predicted) < 3.0 * eps), (v, predicted)
    rpm = np.array(RPMS, float)
    below, above = rpm < 0.95 * threshold_rpm, rpm > 1.05 * threshold_rpm
    assert below.sum() >= 4 and above.sum() >= 3
    assert np.all(np.abs(v[below]) < 0.02 * v_free[below])       # essentially put: < 2% of its free speed
    assert np.all(v[above] > 0.05 * v_free[above]) and np.all(np.diff(v) > 0)
    # continuous onset: just above the threshold the speed is a small fraction of the free speed
    first = np.argmax(above)
    assert v[first] < 0.5 * v_free[first]


def test_steady_jacobian_of_the_yield_matches_finite_differences():
    """The bordered steady system's column dR/dU (forward speed) at |U| ~ v_eps, where the yield is most
    nonlinear: only the effects depend on U, so this column is the yield's dF/dv plus the linear drags'."""
    sc = load_scene("design2", [*SHORT, YIELD])
    m = RobotModel(sc)
    S = SteadySolver(m)
    q, wt, _ = S.initial_guess(sc.omega_T)
    c = m.elastic.frames0.copy()
    eps = sc.medium.yield_speed
    for U in (0.3 * eps, 2.0 * eps, 50.0 * eps):
        _, A, _ = S.system(q, c, sc.omega_T, wt, U)
        h = 1e-4 * eps
        col_fd = (S.residual(q, c, sc.omega_T, wt, U + h)[0] - S.residual(q, c, sc.omega_T, wt, U - h)[0]) / (2 * h)
        col = A.toarray()[: m.ndof, m.ndof + 1]
        assert rel_err(col, col_fd) < 1e-6
        head = m.net.node_dofs(m.net.head_nodes)[:, 0]
        drag = head_drag_coefficient(sc) / 3
        # on the head nodes: Stokes drag plus the yield's slope F_y/3 * eps^2 / (U^2 + eps^2)^1.5
        expected = drag + sc.medium.yield_force / 3 * eps ** 2 / (U * U + eps * eps) ** 1.5
        assert col[head] == pytest.approx(np.full(3, expected), rel=1e-9)


def test_not_listed_builds_nothing_and_zero_yield_force_is_the_free_robot(thrust_and_free_speed):
    """A scene without the effect builds no yield object (nothing evaluated); listed with F_y = 0 it adds no
    force: the same steady speeds as without it."""
    _, v_free, _ = thrust_and_free_speed
    assert RobotModel(load_scene("design2", SHORT)).effect("granular_yield") is None
    m = RobotModel(load_scene("design2", [*SHORT, YIELD]))
    assert type(m.effect("granular_yield")).__name__ == "GranularYield"
    _, v = speeds([YIELD, "medium.yield_force=0.0"])
    assert v == pytest.approx(v_free, rel=1e-9)


@pytest.mark.parametrize("integrator", ["implicit_euler", "bdf2"])
def test_time_stepped_robot_agrees_with_the_steady_states(thrust_and_free_speed, integrator):
    """The time stepper with the yield: put below the threshold, the steady speed above it (to the paper's dt's
    own error of ~2%)."""
    T, v_free, eps = thrust_and_free_speed
    F_y = float(np.interp(60.0, RPMS, T))
    for rpm in (40.0, 100.0):
        sc = load_scene("design2", [*SHORT, YIELD, f"medium.yield_force={F_y}", f"motor.omega_rpm={rpm}",
                                    f"time.integrator='{integrator}'"])
        sim = Simulation(sc)
        sim.run(8.0)
        out = sim.summary()
        v_steady = SteadySolver(RobotModel(sc)).solve(sc.omega_T).v
        if rpm < 60:
            assert abs(out["v"]) < 3 * eps and abs(v_steady) < 3 * eps
        else:
            assert out["v"] == pytest.approx(v_steady, rel=3e-2) and v_steady > 0.3 * v_free[RPMS.index(100)]
        # BDF2 halves one step 8 times where the head breaks away (t = 0.03 s: the regularised Coulomb law turns
        # from stick to slip over v_eps = 1e-7 m/s, and its second-order history overshoots); none after it
        allowed = 0 if integrator == "implicit_euler" or rpm < 60 else 10
        assert out["dt_reductions"] <= allowed and out["newton_iterations"] <= 3 * out["steps"]


def test_yield_force_and_head_drag_fitted_from_data_with_zero_speed_rows(tmp_path, thrust_and_free_speed):
    """Experiments below the threshold record v = 0: with them and the moving rows, flagbot fit recovers the
    yield force (and C1, which sets the slope above the threshold) within their 95% intervals."""
    T, _, eps = thrust_and_free_speed
    F_true = float(np.interp(60.0, RPMS, T))
    truth = [YIELD, f"medium.yield_force={F_true}"]
    rpms = [30, 45, 55, 70, 85, 100, 120]
    _, v = speeds(truth, rpms)
    rng = np.random.default_rng(7)
    lines = ["omega_T_rpm,v,v_std"]
    for rpm, vi in zip(rpms, v):
        if rpm < 60:
            lines.append(f"{rpm},0.0,1e-6")              # "did not move", to the resolution of the measurement
        else:
            sd = 0.03 * vi
            lines.append(f"{rpm},{float(vi + sd * rng.standard_normal())!r},{float(sd)!r}")
    path = tmp_path / "yield.csv"
    path.write_text("\n".join(lines) + "\n")
    base = load_scene("design2", [*SHORT, YIELD, f"medium.yield_force={0.5 * F_true}", "head.C1=15"])
    params = parse_parameters("medium.yield_force,head.C1", base)
    data = read_data(path, base, exclude=tuple(p.key for p in params))
    res = run_fit(base, params, data, Engine("serial"))
    assert res.identified and res.success
    est = {e.key: e for e in res.estimates}
    for key, true in (("medium.yield_force", F_true), ("head.C1", 28.75)):
        lo, hi = est[key].ci95
        assert lo < true < hi and hi / lo < 1.5, (key, est[key])
    # the zero rows are fitted as zero: the model creeps at ~v_eps there
    for row in res.rows[:3]:
        assert abs(row["v"]["simulated"]) < 3 * eps
    assert math.isfinite(res.chi2) and res.dof == len(rpms) - 2
