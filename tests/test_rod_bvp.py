"""The steady rotating-rod BVP (flagbot_sim.reference.rod_bvp): an independent reference for the DER clamped scene.

It must (1) solve the Kirchhoff equations it claims to solve (extensible, as the DER's flagellum is), with the
Jacobian of those equations, (2) reduce to linear beam theory at small omega_bar and to the inextensible rod as EA
grows, (3) use the DER's sign conventions, and (4) be what the DER clamped flagellum converges to as its edges and
time step shrink, at 2000 rpm too, where the flagellum's stretching is what an inextensible rod misses.
"""
import math

import numpy as np
import pytest

from flagbot_sim.physics import Simulation
from flagbot_sim.physics.medium import bending_stiffness, rft_coefficients
from flagbot_sim.physics.model import RobotModel
from flagbot_sim.physics.steady import SteadySolver, summary
from flagbot_sim.reference import RodBVPError, from_scene, solve_clamped_rod
from flagbot_sim.reference.rod_bvp import _make_problem, stretching_stiffness
from flagbot_sim.scene import load_scene

DESIGN1 = load_scene("clamped_flagellum")                      # L = 0.111 m, r0 = 3.2 mm, E = 1.2 MPa, R_d = 2 cm


def _params(sc):
    eta_t, eta_p = rft_coefficients(sc)
    return dict(L=sc.flagellum.length, R_d=sc.R_d, EI=bending_stiffness(sc), eta_t=eta_t, eta_p=eta_p)


# ---------------------------------------------------------------------------------------------- the equations
@pytest.fixture(scope="module")
def rod10():
    """Design 1's flagellum at 10 rpm (omega_bar ~ 29: strongly nonlinear), with the centrifugal load."""
    return from_scene(DESIGN1.with_overrides(["motor.omega_rpm=10"]))


def test_solution_is_converged_and_reports_it(rod10):
    assert rod10.converged
    assert rod10.error_estimate < 1e-6                        # outputs stable under halving of every interval
    assert rod10.continuation[-1] == pytest.approx(rod10.omega_bar)
    assert len(rod10.continuation) > 1                        # reached by continuation from the linear beam
    assert rod10.params["rho_A"] == pytest.approx(1000 * math.pi * DESIGN1.flagellum.radius ** 2)
    # the DER flagellum's stretching stiffness, E pi r0^2 (physics/network.py)
    assert rod10.params["EA"] == pytest.approx(DESIGN1.flagellum.youngs_modulus * math.pi * DESIGN1.flagellum.radius ** 2)
    assert from_scene(DESIGN1.with_overrides(["motor.omega_rpm=10"]), extensible=False).params["EA"] == math.inf


def test_satisfies_the_kirchhoff_equations_and_boundary_conditions(rod10):
    """Residuals of the ODEs, written out here from the brief, on points that are not collocation points: the
    extensible rod in its undeformed arc length s, r' = (1 + eps) t with eps = (n.t) / EA."""
    sol, p = rod10, rod10.params
    L, EI, Rd, w = p["L"], p["EI"], p["R_d"], rod10.omega
    s = sol.s
    pts = np.concatenate([s[:-1] + 0.21 * np.diff(s), s[:-1] + 0.77 * np.diff(s)])
    y, dy = sol.state(pts), sol.state_derivative(pts)
    r, t, m, n = y[0:3], y[3:6], y[6:9], y[9:12]
    v = w * np.cross([1.0, 0.0, 0.0], r, axis=0)              # lab velocity omega x_hat x r
    vt = np.einsum("in,in->n", v, t)
    f = -p["eta_p"] * v - (p["eta_t"] - p["eta_p"]) * vt * t
    a = -w * w * np.array([np.zeros_like(r[0]), r[1], r[2]])  # centripetal acceleration
    eps = np.einsum("in,in->n", n, t) / p["EA"]
    assert 1e-6 < np.abs(eps).max() < 1e-4                    # at 10 rpm the thrust compresses the base a little
    rhs = [(1 + eps) * t, np.cross(m, t, axis=0) / EI, -(1 + eps) * np.cross(t, n, axis=0), -f + p["rho_A"] * a]
    for k, (name, g) in enumerate(zip("rtmn", rhs)):
        d = dy[3 * k: 3 * k + 3]
        scale = np.abs(g).max()
        assert np.abs(d - g).max() < 1e-6 * scale, f"ODE residual of {name}'"
    # unit tangent, twist-free (m.t = 0) everywhere
    assert np.abs(np.linalg.norm(t, axis=0) - 1.0).max() < 1e-8
    assert np.abs(np.einsum("in,in->n", m, t)).max() < 1e-8 * np.abs(m).max()
    # boundary conditions
    y0, yL = sol.state([0.0]), sol.state([L])
    assert np.allclose(y0[0:3, 0], [0.0, Rd, 0.0], atol=1e-12)
    assert np.allclose(y0[3:6, 0], [1.0, 0.0, 0.0], atol=1e-12)
    assert np.abs(yL[6:9]).max() < 1e-9 * np.abs(sol.m).max()
    assert np.abs(yL[9:12]).max() < 1e-9 * np.abs(sol.n).max()
    assert np.allclose(sol.tip, yL[0:3, 0], atol=1e-12)
    # the quadratures Fx, Tx agree with the loads at the clamp (global force and moment balance about x)
    assert sol.Fx == pytest.approx(y0[9, 0], rel=1e-7)
    Tx_clamp = y0[6, 0] + (y0[1, 0] * y0[11, 0] - y0[2, 0] * y0[10, 0])
    assert sol.Tx == pytest.approx(Tx_clamp, rel=1e-7)


def test_analytic_jacobian_matches_finite_differences():
    """fun_jac of the normalised equations (extensible, with the centrifugal term) against central differences
    of fun, at a random state with a non-unit tangent and large loads, so that every term is exercised."""
    rng = np.random.default_rng(7)
    fun, fun_jac, _, _ = _make_problem(W=30.0, kappa=2.3, Rbar=0.2, C=4.0, e=0.05)
    x = np.linspace(0.0, 1.0, 5)
    y = rng.normal(size=(14, x.size))
    J = fun_jac(x, y)
    h = 1e-6
    J_fd = np.zeros_like(J)
    for j in range(14):
        d = np.zeros_like(y)
        d[j] = h
        J_fd[:, j] = (fun(x, y + d) - fun(x, y - d)) / (2 * h)
    assert np.abs(J - J_fd).max() < 1e-7 * np.abs(J_fd).max()
    # the extensible terms are there: e = 0 gives a different Jacobian
    assert np.abs(_make_problem(W=30.0, kappa=2.3, Rbar=0.2, C=4.0, e=0.0)[1](x, y) - J).max() > 1e-2


def test_the_inextensible_rod_is_the_limit_of_growing_ea():
    """Design 1 at 500 rpm (mean strain ~5e-4): the outputs' difference from the EA = inf rod falls as 1/EA."""
    sc = DESIGN1.with_overrides(["motor.omega_rpm=500"])
    inext = from_scene(sc, extensible=False)
    EA = stretching_stiffness(sc)
    assert EA == pytest.approx(sc.flagellum.youngs_modulus * math.pi * sc.flagellum.radius ** 2)
    diffs = []
    for k in (1.0, 10.0, 100.0):
        sol = solve_clamped_rod(**_params(sc), omega=sc.omega_T, rho_A=inext.params["rho_A"], EA=k * EA, guess=inext)
        assert sol.converged
        if k == 1.0:
            assert np.trapezoid(sol.strain, sol.s) / sc.flagellum.length == pytest.approx(4.5e-4, rel=0.1)
            assert sol.strain.max() > sol.strain[-1] == pytest.approx(0.0, abs=1e-12)   # free tip: no tension
        diffs.append([abs(sol.Fx / inext.Fx - 1), abs(sol.Tx / inext.Tx - 1),
                      np.linalg.norm(sol.tip - inext.tip) / sc.flagellum.length])
    diffs = np.array(diffs)
    assert np.all(diffs[0] > 1e-4), diffs                    # stretching matters at the scene's EA
    ratios = diffs[:-1] / diffs[1:]
    assert np.all((ratios > 8) & (ratios < 12)), ratios      # first order in 1/EA
    assert diffs[-1].max() < 3e-5


# ---------------------------------------------------------------------------------------------- linear limit
def test_reduces_to_linear_beam_theory_with_error_shrinking_as_omega_bar_squared():
    p = _params(DESIGN1)
    L, EI, Rd, eta_t, eta_p = p["L"], p["EI"], p["R_d"], p["eta_t"], p["eta_p"]
    errs = []
    for wbar in (0.05, 0.1, 0.2, 0.4):
        w = wbar * EI / (eta_p * L ** 4)
        sol = solve_clamped_rod(**p, omega=w)                  # massless: beam theory has no inertia
        p_t = eta_p * w * Rd
        w_L = p_t * L ** 4 / (8 * EI)
        F_p = (eta_p - eta_t) * w * Rd * w_L
        T_lin = Rd * eta_p * w * Rd * L
        e = [abs(-sol.tip[2] / w_L - 1), abs(-sol.Fx / F_p - 1), abs(-sol.Tx / T_lin - 1)]
        errs.append(e)
    errs = np.array(errs)
    assert errs[0].max() < 1e-4                               # omega_bar = 0.05: linear to 0.01%
    assert errs[-1].max() < 0.01
    ratios = errs[1:] / errs[:-1]                             # doubling omega_bar: errors x4
    assert np.all((ratios > 3.5) & (ratios < 4.5)), ratios


def test_sign_conventions_match_the_der(clamped_design2):
    """Positive omega: thrust towards the head (Fx < 0), resisting torque (Tx < 0), tip lagging at z < 0;
    reversing omega mirrors z and Tx and keeps Fx. The DER (design 2's flagellum at +-1 rpm) agrees."""
    for rpm in (1.0, -1.0):
        sc, out = clamped_design2(rpm)
        ref = from_scene(sc)
        sgn = math.copysign(1.0, rpm)
        assert ref.Fx < 0 and out["Fx"] < 0
        assert sgn * ref.Tx < 0 and sgn * out["Tx"] < 0
        assert sgn * ref.tip[2] < 0 and sgn * out["tip"][2] < 0
        assert ref.tip[0] < sc.flagellum.length and ref.tip[1] < sc.R_d
        assert out["Fx"] == pytest.approx(ref.Fx, rel=0.01)
        assert out["Tx"] == pytest.approx(ref.Tx, rel=0.01)
        assert out["tip"][2] == pytest.approx(ref.tip[2], rel=0.01)


def test_failure_raises_a_clear_error():
    p = _params(DESIGN1)
    with pytest.raises(RodBVPError, match=r"omega = .* rad/s \(omega_bar = .*\)"):
        solve_clamped_rod(**p, omega=5.0, max_nodes=20)
    sol = solve_clamped_rod(**p, omega=5.0, max_nodes=20, raise_on_failure=False)
    assert not sol.converged and math.isnan(sol.Fx) and "failed at omega" in sol.message
    with pytest.raises(ValueError, match="EI"):
        solve_clamped_rod(**{**p, "EI": -1.0}, omega=1.0)


# ---------------------------------------------------------------------------------------------- the DER converges to it
def _der_errors(ref, edge, dt, duration=30.0):
    sc = DESIGN1.with_overrides(["motor.omega_rpm=10", f"flagellum.edge_length={edge}", f"time.dt={dt}"])
    sim = Simulation(sc)
    sim.run(duration)
    out = sim.summary()
    assert out["steady"]
    disp = np.linalg.norm(ref.tip - [sc.flagellum.length, sc.R_d, 0.0])
    return (np.array([out["Fx"] / ref.Fx - 1.0, out["Tx"] / ref.Tx - 1.0,
                      np.linalg.norm(np.array(out["tip"]) - ref.tip) / disp]),
            np.array([out["Fx"], out["Tx"], *out["tip"]]))


def test_der_clamped_flagellum_converges_to_the_rod_bvp(rod10):
    """10 rpm, design 1 (omega_bar ~ 29, tip deflected by 28 mm): refine edges and dt together, then
    Richardson-extrapolate (first order in dt, second in edge length) to the continuum limit."""
    runs = {(h, dt): _der_errors(rod10, h, dt) for h, dt in
            [(8.22e-3, 1e-2), (4.11e-3, 5e-3), (2.055e-3, 2.5e-3), (4.11e-3, 2.5e-3), (2.055e-3, 5e-3)]}
    path = [runs[k][0] for k in [(8.22e-3, 1e-2), (4.11e-3, 5e-3), (2.055e-3, 2.5e-3)]]
    e = np.abs(np.array(path))                                # rows: refinements; columns: Fx, Tx, tip
    assert np.all(e[0] < 0.01)                                # already within 1% on the coarsest
    assert np.all(e[:-1] / e[1:] > 2.0), e                    # each refinement shrinks every error
    assert np.all(e[-1] < 2e-3), e
    # Richardson: remove the O(dt) error at each edge length, then the O(h^2) error
    v = {k: r[1] for k, r in runs.items()}
    at_h = {h: 2 * v[(h, 2.5e-3)] - v[(h, 5e-3)] for h in (4.11e-3, 2.055e-3)}
    limit = (4 * at_h[2.055e-3] - at_h[4.11e-3]) / 3
    assert limit[0] == pytest.approx(rod10.Fx, rel=3e-4)
    assert limit[1] == pytest.approx(rod10.Tx, rel=3e-4)
    disp = np.linalg.norm(rod10.tip - [DESIGN1.flagellum.length, DESIGN1.R_d, 0.0])
    assert np.linalg.norm(limit[2:] - rod10.tip) < 3e-4 * disp


def test_at_2000_rpm_the_converged_der_is_the_extensible_rod():
    """Design 1 at 2000 rpm (mean strain 1.9e-3): the DER's steady state (the dt -> 0 limit of time stepping) at
    1.03 and 0.51 mm edges, Richardson-extrapolated (second order), is the extensible rod, within 0.01% (measured:
    3e-5), and an inextensible rod misses it by 0.5-1.2%: the flagellum's stretching was the difference."""
    sc = DESIGN1.with_overrides(["motor.omega_rpm=2000"])
    vals = []
    for edge in (1.0275e-3, 0.51375e-3):
        m = RobotModel(sc.with_overrides([f"flagellum.edge_length={edge}"]))
        st = summary(m, SteadySolver(m).solve(sc.omega_T))
        vals.append(np.array([st["Fx"], st["Tx"], *st["tip"]]))
    limit = vals[1] + (vals[1] - vals[0]) / 3.0
    straight = np.array([sc.flagellum.length, sc.R_d, 0.0])

    def err(ref):
        return np.array([abs(limit[0] / ref.Fx - 1), abs(limit[1] / ref.Tx - 1),
                         np.linalg.norm(limit[2:] - ref.tip) / np.linalg.norm(ref.tip - straight)])

    ext = from_scene(sc)
    inext = from_scene(sc, extensible=False)
    e_ext, e_inext = err(ext), err(inext)
    assert e_ext.max() < 1e-4, e_ext
    assert e_inext.max() > 5e-3, e_inext                      # the tip: ~1.2% of its deflection
    assert np.all(e_inext > 10 * e_ext), (e_ext, e_inext)
