"""Beam theory for one flagellum: LB closed form and the NLB boundary-value solver (paper section "Beam theory
based analysis of propulsion"). The balance of the whole robot is in test_beam_balance.py."""
import dataclasses
import math
import types

import numpy as np
import pytest
from scipy.integrate import simpson

from flagbot_sim.beam import (BeamParams, NLBSolveError, lb_deflection, lb_F_p, lb_F_x, lb_load, lb_tip_deflection,
                              solve_lb, solve_nlb, solve_nlb_coupled)
from flagbot_sim.beam import nonlinear
from flagbot_sim.physics.medium import relaxation_time
from flagbot_sim.scene import load_scene


@pytest.fixture(scope="module")
def params():
    return BeamParams.from_scene(load_scene("design1"))


def omega_for_load(params, A):
    """omega_t whose LB tip deflection is w(L)/L = A/8."""
    return params.omega_from_load_number(A)


def nlb_load(params, omega_t, v_h, slope):
    """p of Eq. force_withHead_withoutApprox, written out again here as the test's reference."""
    V = omega_t * params.R_d
    return params.eta_p * V + (params.eta_t - params.eta_p) * (V * slope ** 2 + v_h * slope) / (slope ** 2 + 1)


def nlb_propulsion(params, omega_t, v_h, slope):
    """q of Eq. FpPerLength_full with sin(theta) = w'/sqrt(1+w'^2), cos(theta) = 1/sqrt(1+w'^2)."""
    sin = slope / np.sqrt(1 + slope ** 2)
    cos = 1 / np.sqrt(1 + slope ** 2)
    return ((params.eta_p - params.eta_t) * (omega_t * params.R_d * sin * cos + v_h * cos ** 2)
            - params.eta_p * v_h)


# ---------------------------------------------------------------- LB

def test_lb_deflection_satisfies_the_beam_equation_and_the_four_boundary_conditions(params):
    """Eq. deflection solves EI w'''' = p_t with w(0) = w'(0) = 0 (clamp), w''(L) = w'''(L) = 0 (free tip),
    checked with finite differences of the closed form (a quartic, so the stencils are exact up to rounding)."""
    omega_t = 0.4
    L, EI, p_t = params.L, params.EI, lb_load(params, omega_t)
    h = L / 20

    def w(y):
        return lb_deflection(params, omega_t, y)

    def d1(y):
        return (w(y - 2 * h) - 8 * w(y - h) + 8 * w(y + h) - w(y + 2 * h)) / (12 * h)

    def d2(y):
        return (-w(y - 2 * h) + 16 * w(y - h) - 30 * w(y) + 16 * w(y + h) - w(y + 2 * h)) / (12 * h ** 2)

    def d3(y):
        return (-w(y - 2 * h) + 2 * w(y - h) - 2 * w(y + h) + w(y + 2 * h)) / (2 * h ** 3)

    def d4(y):
        return (w(y - 2 * h) - 4 * w(y - h) + 6 * w(y) - 4 * w(y + h) + w(y + 2 * h)) / h ** 4

    y = np.linspace(0.1, 0.9, 9) * L
    assert np.allclose(EI * d4(y), p_t, rtol=1e-6)
    w_scale = p_t * L ** 4 / EI           # the natural size of w, w' L, w'' L^2, w''' L^3
    assert abs(w(0.0)) < 1e-12 * w_scale
    assert abs(d1(0.0)) * L < 1e-9 * w_scale
    assert abs(d2(L)) * L ** 2 < 1e-9 * w_scale
    assert abs(d3(L)) * L ** 3 < 1e-6 * w_scale
    # and the load is not trivially zero: the tip deflection is the textbook cantilever p L^4 / 8EI
    assert w(L) == pytest.approx(p_t * L ** 4 / (8 * EI), rel=1e-12) and w(L) > 0


def test_lb_forces_are_the_integrals_of_their_loads(params):
    """Eq. linearFx = integral of p_t, and Eq. Fp_linear_solution = integral of Eq. Fp_linear_unit
    q = (eta_p - eta_t) omega_t R_d w'(y) - eta_t v_h, by quadrature of a numerically differentiated w."""
    omega_t, v_h = 0.3, 2e-4
    y = np.linspace(0, params.L, 2001)
    slope = np.gradient(lb_deflection(params, omega_t, y), y, edge_order=2)
    q = (params.eta_p - params.eta_t) * omega_t * params.R_d * slope - params.eta_t * v_h
    assert lb_F_p(params, omega_t, v_h) == pytest.approx(simpson(q, x=y), rel=1e-6)
    assert lb_F_x(params, omega_t) == pytest.approx(simpson(np.full_like(y, lb_load(params, omega_t)), x=y),
                                                    rel=1e-12)
    sol = solve_lb(params, omega_t, v_h)
    assert np.allclose(sol.deflection(y, 1), slope, rtol=0, atol=1e-6 * slope.max())


# ---------------------------------------------------------------- NLB solver

@pytest.mark.parametrize("A, v_h", [(2.5, 0.0), (2.5, 4e-4), (40.0, 1e-3)])
def test_nlb_solution_satisfies_the_nonlinear_beam_equation(params, A, v_h):
    """The solve_bvp deflection satisfies EI w'''' = p(w') (Eq. force_withHead_withoutApprox, with v_h) and
    Eq. BC; F_x and F_p are the integrals of p and q (re-integrated here on a fine grid), and F_x equals the
    shear at the clamp -EI w'''(0) (equilibrium of the whole flagellum)."""
    omega_t = omega_for_load(params, A)
    sol = solve_nlb(params, omega_t, v_h)
    assert sol.converged
    L, EI = params.L, params.EI
    y = np.linspace(0, L, 4001)
    w1, w3 = sol.deflection(y, 1), sol.deflection(y, 3)
    w4 = np.gradient(w3, y, edge_order=2)
    p = nlb_load(params, omega_t, v_h, w1)
    interior = slice(50, -50)
    assert np.allclose(EI * w4[interior], p[interior], rtol=2e-4)
    scale = abs(sol.w_tip)
    assert abs(sol.deflection(0.0)) < 1e-10 * scale
    assert abs(sol.deflection(0.0, 1)) * L < 1e-10 * scale
    assert abs(sol.deflection(L, 2)) * L ** 2 < 1e-8 * scale
    assert abs(sol.deflection(L, 3)) * L ** 3 < 1e-8 * scale
    assert sol.F_x == pytest.approx(simpson(p, x=y), rel=1e-7)
    assert sol.F_x == pytest.approx(-EI * sol.deflection(0.0, 3), rel=1e-7)
    assert sol.F_p == pytest.approx(simpson(nlb_propulsion(params, omega_t, v_h, w1), x=y), rel=1e-7)


def test_nlb_tends_to_lb_with_a_relative_difference_of_order_omega_t_squared(params):
    """The NLB load differs from p_t = eta_p omega_t R_d by (eta_t - eta_p) omega_t R_d sin^2(theta) and
    sin^2 ~ w'^2 ~ omega_t^2, so halving omega_t must divide the relative differences by ~4 (NLB w/o head)."""
    diffs = []
    for A in (0.4, 0.2, 0.1, 0.05):
        omega_t = omega_for_load(params, A)
        nlb, lb = solve_nlb(params, omega_t, 0.0), solve_lb(params, omega_t, 0.0)
        diffs.append([abs(nlb.w_tip / lb.w_tip - 1), abs(nlb.F_x / lb.F_x - 1), abs(nlb.F_p / lb.F_p - 1)])
    diffs = np.array(diffs)
    ratios = diffs[:-1] / diffs[1:]
    assert np.all((ratios > 3.8) & (ratios < 4.2)), ratios
    assert np.all(diffs[-1] < 1e-3) and np.all(diffs[-1] > 0)


def test_lb_head_term_is_the_small_slope_limit_of_the_nlb_head_term(params):
    """LB's F_p carries -eta_t v_h L (Eq. Fp_linear_solution); NLB's q carries (eta_p - eta_t) v_h cos^2 -
    eta_p v_h. At small slopes with v_h ~ omega_t^2 (as the drag balance gives) they must agree to O(omega_t^2)
    relative: with -eta_p v_h L (or no head term) in LB the difference would not shrink."""
    diffs = []
    for A in (0.4, 0.2, 0.1):
        omega_t = omega_for_load(params, A)
        v_h = 0.5 * (params.eta_p - params.eta_t) * omega_t * params.R_d * lb_tip_deflection(params, omega_t) \
            / (params.eta_t * params.L)       # the head term cancels half of the LB drive
        nlb = solve_nlb(params, omega_t, v_h)
        diffs.append(abs(nlb.F_p / lb_F_p(params, omega_t, v_h) - 1))
    assert diffs[0] / diffs[1] > 3.5 and diffs[1] / diffs[2] > 3.5, diffs
    assert diffs[-1] < 2e-3


def test_nlb_without_head_equals_nlb_with_head_when_v_h_is_zero(params):
    """The coupled solver (v_h an unknown of the BVP, fixed by c_drag v_h = n F_p) with an immovable head
    (c_drag -> infinity, so v_h -> 0) must give the NLB w/o head flagellum."""
    omega_t = omega_for_load(params, 5.0)
    nohead = solve_nlb(params, omega_t, 0.0)
    pinned = solve_nlb_coupled(dataclasses.replace(params, c_drag=params.c_drag * 1e9), omega_t)
    assert 0 < pinned.v_h < 1e-8 * solve_nlb_coupled(params, omega_t).v_h
    assert pinned.w_tip == pytest.approx(nohead.w_tip, rel=1e-9)
    assert pinned.F_x == pytest.approx(nohead.F_x, rel=1e-9)
    assert pinned.F_p == pytest.approx(nohead.F_p, rel=1e-6)


def test_coupled_solve_is_the_fixed_speed_solve_at_its_own_head_speed(params):
    """solve_nlb_coupled returns v_h with c_drag v_h = n F_p, and the flagellum at that v_h, i.e. the same
    flagellum solve_nlb gives when told that v_h; the head slows the flagellum's propulsion (v_h > 0 and
    F_p below the w/o-head value)."""
    omega_t = omega_for_load(params, 5.0)
    coupled = solve_nlb_coupled(params, omega_t)
    fixed = solve_nlb(params, omega_t, coupled.v_h)
    assert coupled.v_h > 0
    assert params.c_drag * coupled.v_h == pytest.approx(params.n * coupled.F_p, rel=1e-9)
    assert fixed.F_p == pytest.approx(coupled.F_p, rel=1e-7)
    assert fixed.w_tip == pytest.approx(coupled.w_tip, rel=1e-9)
    assert coupled.F_p < solve_nlb(params, omega_t, 0.0).F_p


def test_clamped_flagellum_signs_agree_with_the_der_convention():
    """Design-2 flagellum clamped at omega_bar = 0.39, where the DER clamped scene matches
    w(L) = p_t L^4/8EI and F_p = (eta_p - eta_t) omega R_d w(L) to 0.1%: the NLB solver must give the same
    numbers, with w(L) > 0 (the flagellum trails), F_x > 0 (drag against the rotation) and F_p > 0."""
    scene = load_scene("clamped_flagellum", ["flagellum.length=0.089", "medium.mu=2.125", "plate.diameter=0.03",
                                             "motor.omega_rpm=1"])
    params = BeamParams.from_scene(scene)
    omega = 0.39 / relaxation_time(scene)
    sol = solve_nlb(params, omega, 0.0)
    w_L = lb_load(params, omega) * params.L ** 4 / (8 * params.EI)
    assert sol.w_tip > 0 and sol.F_x > 0 and sol.F_p > 0
    assert sol.w_tip == pytest.approx(w_L, rel=1e-3)
    assert sol.F_p == pytest.approx((params.eta_p - params.eta_t) * omega * params.R_d * w_L, rel=1e-3)
    assert sol.F_x == pytest.approx(params.eta_p * omega * params.R_d * params.L, rel=1e-3)


def test_default_mesh_is_converged(params):
    """solve_bvp's mesh refinement at the default tolerance gives the same answer as a much tighter solve
    at a large deflection (w(L)/L ~ 4), so the default is not the accuracy bottleneck."""
    omega_t = omega_for_load(params, 60.0)
    coarse = solve_nlb(params, omega_t, 1e-3)
    fine = solve_nlb(params, omega_t, 1e-3, tol=1e-10)
    assert fine.nodes > coarse.nodes
    for key in ("w_tip", "F_x", "F_p"):
        assert getattr(coarse, key) == pytest.approx(getattr(fine, key), rel=1e-7)


def test_failed_solve_raises_naming_omega_t_and_the_solver_reason(params):
    """A solve that cannot converge (mesh capped far below what the large deflection needs) must raise with
    omega_t and solve_bvp's message, or, when asked not to raise, say converged=False and give NaN, never a
    number."""
    omega_t = omega_for_load(params, 3000.0)
    with pytest.raises(NLBSolveError) as info:
        solve_nlb(params, omega_t, 0.0, max_nodes=45)
    msg = str(info.value)
    assert f"omega_t = {omega_t:.6g} rad/s" in msg
    assert "maximum number of mesh nodes" in msg
    assert info.value.omega_t == omega_t
    quiet = solve_nlb(params, omega_t, 0.0, max_nodes=45, raise_on_failure=False)
    assert not quiet.converged and "maximum number of mesh nodes" in quiet.message
    assert math.isnan(quiet.F_x) and math.isnan(quiet.F_p) and math.isnan(quiet.w_tip)


def test_continuation_in_omega_t_recovers_a_failed_direct_solve(params, monkeypatch):
    """When the direct solve from the LB profile fails, the solver continues in omega_t from the linear
    solution and must reach the same flagellum as a direct solve."""
    omega_t = omega_for_load(params, 30.0)
    direct = solve_nlb(params, omega_t, 2e-4)
    calls = []
    original = nonlinear._attempt

    def failing_first(A, *args, **kwargs):
        calls.append(A)
        if len(calls) == 1:
            return types.SimpleNamespace(status=1, x=np.linspace(0, 1, 5), y=np.full((6, 5), np.nan), p=None,
                                         message="forced failure")
        return original(A, *args, **kwargs)

    monkeypatch.setattr(nonlinear, "_attempt", failing_first)
    continued = solve_nlb(params, omega_t, 2e-4)
    assert len(calls) >= 3 and calls[1] < calls[0]         # it went back to smaller omega_t and marched up
    assert continued.converged
    for key in ("w_tip", "F_x", "F_p"):
        assert getattr(continued, key) == pytest.approx(getattr(direct, key), rel=1e-8)
