"""The robot's force and torque balance in beam theory (Eqs. vHead, OHead, totalOmega) for LB, NLB w/o head
and NLB."""
import dataclasses

import numpy as np
import pytest

from flagbot_sim.beam import (REGIMES, BeamParams, BeamSolveError, NLBSolveError, balance_residual,
                              flagellum_state, lb_F_p, lb_F_x, solve_balance, solve_nlb)
from flagbot_sim.beam import balance as balance_module
from flagbot_sim.physics import medium
from flagbot_sim.scene import load_scene
from flagbot_sim.units import RPM


def design(name, n):
    return BeamParams.from_scene(load_scene(name, [f"robot.n_flagella={n}"]))


def independent_forces(params, res):
    """F_x, F_p of one flagellum at the result's omega_t, recomputed from scratch (no warm start, no reuse of
    the balance's own numbers), with the head speed the regime puts into the load."""
    if res.regime == "lb":
        return lb_F_x(params, res.omega_t), lb_F_p(params, res.omega_t, res.v_h)
    v_load = res.v_h if res.regime == "nlb" else 0.0
    fl = solve_nlb(params, res.omega_t, v_load, tol=1e-9)
    return fl.F_x, fl.F_p


@pytest.mark.parametrize("regime", REGIMES)
@pytest.mark.parametrize("name", ["design1", "design2"])
@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_balance_holds_for_n_2_to_5(name, n, regime):
    """omega_h + omega_t = omega_T, c_torque omega_h = n R_d F_x and c_drag v_h = n F_p, with F_x and F_p
    recomputed independently at the returned omega_t and v_h; head and flagella both turn forwards."""
    params = design(name, n)
    for rpm in (40.0, 150.0):
        omega_T = rpm * RPM
        res = solve_balance(params, omega_T, regime)
        assert res.converged, res.message
        assert res.omega_h + res.omega_t == pytest.approx(omega_T, rel=1e-12)
        assert 0 < res.omega_t < omega_T and res.omega_h > 0 and res.v_h > 0
        F_x, F_p = independent_forces(params, res)
        assert params.c_torque * res.omega_h == pytest.approx(n * params.R_d * F_x, rel=1e-7)
        assert params.c_drag * res.v_h == pytest.approx(n * F_p, rel=1e-7)
        assert res.F_x == pytest.approx(F_x, rel=1e-7) and res.F_p == pytest.approx(F_p, rel=1e-7)


@pytest.mark.parametrize("regime", ["nlb-nohead", "nlb"])
@pytest.mark.parametrize("name", ["design1", "design2"])
def test_balance_residual_is_monotone_in_omega_t(name, regime):
    """The bracketing solve is unique only if g(omega_t) = omega_t + n R_d F_x / c_torque - omega_T increases:
    check F_x (hence g) strictly increases with omega_t from 0.01 to 1000 rad/s (w(L)/L up to 50..400, far
    past what any scene's motor limit produces) for n = 2..5."""
    omega_t = np.logspace(-2, 3, 16)
    for n in (2, 3, 4, 5):
        params = design(name, n)
        F_x = np.array([flagellum_state(params, w, regime).F_x for w in omega_t])
        assert np.all(np.diff(F_x) > 0), (n, F_x)
        g = [balance_residual(params, w, 100 * RPM, regime) for w in omega_t[:6]]
        assert np.all(np.diff(g) > 0)


@pytest.mark.parametrize("regime", REGIMES)
def test_normalised_curves_do_not_depend_on_units_or_scale(regime):
    """Design 2 in metres, in millimetres (E and mu in N/mm^2 units), and a robot 2.5x larger in a 3x more
    viscous medium with 5x softer flagella: at equal omega_T_bar the normalised omega_h, omega_t, v and w(L)/L
    must coincide (the beam problem depends only on R_d/L, eta_t/eta_p, c_drag/(eta_p L) and
    c_torque/(eta_p L^3), which these changes keep), while the dimensional speeds differ."""
    base = load_scene("design2", ["robot.n_flagella=3"])
    lengths = ["flagellum.length", "flagellum.radius", "flagellum.edge_length", "head.radius", "plate.diameter",
               "plate.thickness"]

    def scaled(length, mu, E):
        flat = base.flat()
        over = {k: flat[k] * length for k in lengths}
        over["medium.mu"] = flat["medium.mu"] * mu
        over["flagellum.youngs_modulus"] = flat["flagellum.youngs_modulus"] * E
        return base.with_overrides(over)

    scenes = [base, scaled(1e3, 1e-6, 1e-6), scaled(2.5, 3.0, 0.2)]
    for omega_T_bar in (5.0, 40.0, 300.0):
        rows, speeds = [], []
        for scene in scenes:
            res = solve_balance(BeamParams.from_scene(scene), omega_T_bar / medium.relaxation_time(scene), regime)
            rows.append([res.omega_T_bar, res.omega_h_bar, res.omega_t_bar, res.v_bar, res.w_tip_over_L])
            speeds.append(res.v_h)
        rows = np.array(rows)
        assert np.allclose(rows, rows[0], rtol=1e-7, atol=0), rows
        assert abs(speeds[2] / speeds[0] - 1) > 0.1       # the third robot really is a different robot


def test_normalisation_uses_L4_for_every_angular_speed():
    """omega_bar = omega eta_p L^4 / EI for omega_T, omega_h and omega_t alike (dimensionless), so the
    normalised speeds add up like the dimensional ones; v_bar = v eta_p L^3 / EI."""
    scene = load_scene("design1")
    res = solve_balance(BeamParams.from_scene(scene), scene.omega_T, "nlb")
    eta_p, EI = medium.rft_coefficients(scene)[1], medium.bending_stiffness(scene)
    assert res.omega_h_bar == pytest.approx(res.omega_h * eta_p * scene.flagellum.length ** 4 / EI)
    assert res.omega_h_bar + res.omega_t_bar == pytest.approx(res.omega_T_bar, rel=1e-12)
    assert res.omega_T_bar == pytest.approx(medium.normalise_omega(scene, scene.omega_T))
    assert res.v_bar == pytest.approx(medium.normalise_speed(scene, res.v_h))


def test_nlb_balance_tends_to_lb_at_low_motor_speed():
    """omega_t of NLB w/o head and LB differ by O(omega_T^2) relative: halving omega_T quarters the
    difference, and at omega_T_bar ~ 1 it is below 1e-4."""
    params = design("design2", 3)
    diffs = []
    for omega_T_bar in (8.0, 4.0, 2.0, 1.0):
        omega_T = omega_T_bar / params.relaxation_time
        nl, lin = solve_balance(params, omega_T, "nlb-nohead"), solve_balance(params, omega_T, "lb")
        diffs.append(abs(nl.omega_t / lin.omega_t - 1))
    ratios = np.array(diffs[:-1]) / np.array(diffs[1:])
    assert np.all((ratios > 3.8) & (ratios < 4.2)), ratios
    assert diffs[-1] < 1e-4


def test_nlb_balance_equals_nohead_when_the_head_cannot_translate():
    """With c_drag -> infinity the head speed -> 0, so NLB (v_h in the load) must reproduce NLB w/o head's
    omega_h, omega_t, F_x and deflection."""
    params = design("design1", 3)
    pinned = dataclasses.replace(params, c_drag=params.c_drag * 1e9)
    a = solve_balance(pinned, 150 * RPM, "nlb")
    b = solve_balance(params, 150 * RPM, "nlb-nohead")
    for key in ("omega_h", "omega_t", "F_x", "w_tip_over_L"):
        assert getattr(a, key) == pytest.approx(getattr(b, key), rel=1e-8)


def test_paper_trends_in_n():
    """The paper's two designs: in design 1 two flagella are faster than three (all regimes, 100 rpm); in
    design 2 NLB w/o head predicts three flagella faster only beyond a crossover omega_T (its point D)."""
    for regime in REGIMES:
        v2 = solve_balance(design("design1", 2), 100 * RPM, regime).v_h
        v3 = solve_balance(design("design1", 3), 100 * RPM, regime).v_h
        assert v2 > v3
    slow = [solve_balance(design("design2", n), 50 * RPM, "nlb-nohead").v_h for n in (2, 3)]
    fast = [solve_balance(design("design2", n), 400 * RPM, "nlb-nohead").v_h for n in (2, 3)]
    assert slow[1] < slow[0] and fast[1] > fast[0]


def test_negative_motor_speed_is_the_mirror_image():
    """Reversing the motor reverses omega_h, omega_t, F_x and the deflection; propulsion does not change
    sign (q is even in the rotation direction), so the robot still moves head first."""
    params = design("design2", 2)
    for regime in REGIMES:
        fwd, back = solve_balance(params, 80 * RPM, regime), solve_balance(params, -80 * RPM, regime)
        for key in ("omega_h", "omega_t", "F_x", "w_tip_over_L"):
            assert getattr(back, key) == pytest.approx(-getattr(fwd, key), rel=1e-9)
        assert back.v_h == pytest.approx(fwd.v_h, rel=1e-9) and back.v_h > 0


def test_lb_balance_is_the_closed_form():
    """LB: omega_t = omega_T / (1 + n eta_p R_d^2 L / c_torque) (Eqs. linearFx, OHead, totalOmega)."""
    params = design("design1", 2)
    res = solve_balance(params, 100 * RPM, "lb")
    k = params.n * params.eta_p * params.R_d ** 2 * params.L / params.c_torque
    assert res.omega_t == pytest.approx(100 * RPM / (1 + k), rel=1e-12)


def test_failed_flagellum_solve_is_reported_not_hidden(monkeypatch):
    """A failing NLB solve inside the balance raises an error naming omega_t, omega_T and the reason, or with
    raise_on_failure=False gives converged=False and NaN values."""
    params = design("design1", 2)

    def failing(params, omega_t, **kwargs):
        raise NLBSolveError(omega_t, None, "The maximum number of mesh nodes is exceeded.")

    monkeypatch.setattr(balance_module, "solve_nlb_coupled", failing)
    monkeypatch.setattr(balance_module, "solve_nlb_balanced", lambda *a, **k: None)   # the one-BVP solve fails too
    with pytest.raises(NLBSolveError, match=r"omega_t = .* rad/s .*mesh nodes.*omega_T = 10.472 rad/s"):
        solve_balance(params, 100 * RPM, "nlb")
    quiet = solve_balance(params, 100 * RPM, "nlb", raise_on_failure=False)
    assert not quiet.converged and "mesh nodes" in quiet.message
    assert np.isnan(quiet.omega_t) and np.isnan(quiet.v_h)
    assert isinstance(NLBSolveError(1.0, None, "x"), BeamSolveError)


@pytest.mark.parametrize("regime", ["nlb-nohead", "nlb"])
@pytest.mark.parametrize("name", ["design1", "design2"])
def test_the_balance_as_a_boundary_condition_is_the_root_of_the_search(name, regime, monkeypatch):
    """The torque balance solved as a boundary condition of one BVP (omega_t an unknown) gives the root the
    search over omega_t (Brent's method, one BVP per try) finds, to the BVP's accuracy, in one solve."""
    one, searched = [], []
    for n in (2, 3, 5):
        params = design(name, n)
        for rpm in (20.0, 100.0, 250.0):
            one.append(solve_balance(params, rpm * RPM, regime))
    monkeypatch.setattr(balance_module, "solve_nlb_balanced", lambda *a, **k: None)
    for n in (2, 3, 5):
        params = design(name, n)
        for rpm in (20.0, 100.0, 250.0):
            searched.append(solve_balance(params, rpm * RPM, regime))
    for a, b in zip(one, searched):
        assert a.converged and b.converged
        assert a.bvp_solves == 1 and "boundary condition of one BVP" in a.message
        assert "Brent" in b.message and b.bvp_solves >= 3
        for key in ("omega_t", "omega_h", "v_h", "F_x", "F_p", "w_tip_over_L"):
            assert getattr(a, key) == pytest.approx(getattr(b, key), rel=2e-8), key


def test_a_boundary_condition_root_outside_the_bracket_is_not_taken(monkeypatch):
    """The one-BVP solve is taken only with its root inside the bracket the loads prove; a root elsewhere (a
    solve that wandered) hands the balance to the root search."""
    params = design("design1", 3)
    real = balance_module.solve_nlb_balanced

    def wandered(params, omega_T, coupled, omega_t0, **kwargs):
        sol = real(params, omega_T, coupled, omega_t0, **kwargs)
        return dataclasses.replace(sol, omega_t=0.999 * omega_T)

    monkeypatch.setattr(balance_module, "solve_nlb_balanced", wandered)
    res = solve_balance(params, 100 * RPM, "nlb")
    assert res.converged and "Brent" in res.message
    monkeypatch.undo()
    assert res.omega_t == pytest.approx(solve_balance(params, 100 * RPM, "nlb").omega_t, rel=2e-8)


def test_unknown_regime_is_an_error():
    with pytest.raises(ValueError, match="nlb-nohead"):
        solve_balance(design("design1", 2), 1.0, "NLB")
