"""The NLB flagellum by Chebyshev collocation of its integral equation (flagbot_sim/beam/spectral.py): exact
integration of polynomials, the LB closed form where the load is linear, the Newton Jacobian against finite
differences, the beam equation at points between the nodes, agreement with a tight solve_bvp reference, the
resolution that grows until the coefficients have decayed, the motor limit, far starts, the warm start, and the
fallback to solve_bvp's root search."""
import numpy as np
import pytest
from numpy.polynomial import chebyshev as C

from flagbot_sim.beam import BeamParams, nonlinear, solve_balance, solve_balance_curve, spectral
from flagbot_sim.scene import load_scene
from flagbot_sim.units import RPM


def design(name, n):
    return BeamParams.from_scene(load_scene(name, [f"robot.n_flagella={n}"]))


@pytest.mark.parametrize("N", [8, 32, 64])
def test_integration_operators_are_exact_for_polynomials_of_degree_N(N):
    """Q x^k = x^(k+1)/(k+1), R x^k = (1 - x^(k+1))/(k+1), w . x^k = 1/(k+1) for k <= N (Clenshaw-Curtis)."""
    b = spectral.basis(N)
    for k in (0, 1, 3, N // 2, N):
        f = b.x ** k
        assert np.allclose(b.Q @ f, b.x ** (k + 1) / (k + 1), rtol=0, atol=1e-14)
        assert np.allclose(b.R @ f, (1 - b.x ** (k + 1)) / (k + 1), rtol=0, atol=1e-14)
        assert b.w @ f == pytest.approx(1 / (k + 1), abs=1e-14)
    assert b.x[0] == 0.0 and b.x[-1] == 1.0 and np.all(np.diff(b.x) > 0)


def test_a_load_that_does_not_depend_on_the_slope_gives_the_lb_closed_form():
    """kappa = 1: P = A whatever the slope, so the solution is the LB beam: u = A x^2 (6 - 4x + x^2)/24,
    u'' = A (1-x)^2/2, u''' = -A (1-x), I_x(1) = A, I_p(1) = -B (Q = -B)."""
    A, B = 3.7, 0.4
    sol = spectral.solve(spectral.Problem(1.0, A=A, B=B), lambda x: 0.0 * x, A, B)
    x = sol.x
    assert np.allclose(sol.y[0], A * x ** 2 * (6 - 4 * x + x ** 2) / 24, rtol=0, atol=1e-14)
    assert np.allclose(sol.y[1], A * x * (3 - 3 * x + x ** 2) / 6, rtol=0, atol=1e-14)
    assert np.allclose(sol.y[2], A * (1 - x) ** 2 / 2, rtol=0, atol=1e-14)
    assert np.allclose(sol.y[3], -A * (1 - x), rtol=0, atol=1e-14)
    assert sol.y[4, -1] == pytest.approx(A, rel=1e-14) and sol.y[5, -1] == pytest.approx(-B, rel=1e-14)
    xi = np.linspace(0, 1, 7)
    assert np.allclose(sol.profile(xi)[0], A * xi ** 2 * (6 - 4 * xi + xi ** 2) / 24, rtol=0, atol=1e-14)


@pytest.mark.parametrize("coupled, free_A", [(False, False), (True, False), (False, True), (True, True)])
def test_newton_jacobian_is_the_derivative_of_the_residual(coupled, free_A):
    """Every column of the Jacobian (the slope's nodes, B, A) against central differences of the residual."""
    rng = np.random.default_rng(3)
    N = 16
    b = spectral.basis(N)
    problem = spectral.Problem(0.45, A=2.0, B=0.3, coupled_D=1.7 if coupled else None, n=3,
                               balance=(0.8, 0.05, 4.0) if free_A else None)
    z = np.concatenate([rng.normal(scale=0.7, size=N + 1), [0.3] if coupled else [], [2.0] if free_A else []])
    _, J = problem.residual(z, b, jacobian=True)
    h = 1e-6
    for j in range(z.size):
        e = np.zeros_like(z)
        e[j] = h
        fd = (problem.residual(z + e, b) - problem.residual(z - e, b)) / (2 * h)
        assert np.allclose(J[:, j], fd, rtol=1e-7, atol=1e-8), j


@pytest.mark.parametrize("name", ["design1", "design2"])
@pytest.mark.parametrize("regime", ["nlb-nohead", "nlb"])
def test_spectral_balance_satisfies_the_beam_equation_between_the_nodes(name, regime):
    """u'''' = P(u') at points between the collocation nodes (the interpolant's derivative), u(0) = u'(0) = 0
    (u''(1) = u'''(1) = 0 hold by R's construction, which the operator test checks), and I_x(1), I_p(1) the
    integrals of P, Q by an independent quadrature."""
    params = design(name, 3)
    res = solve_balance(params, 150 * RPM, regime)
    assert res.converged and "Chebyshev collocation" in res.message
    st = res.flagellum.bvp
    A, B = st.A, st.B
    xi = np.linspace(0.013, 0.987, 41)
    u, s, u2, u3 = res.flagellum.profile(xi)
    coef = spectral.basis(st.x.size - 1).to_coef @ st.y[3]
    u4 = 2.0 * C.chebval(2 * xi - 1, C.chebder(coef))            # d/dxi of u''' (t = 2 xi - 1)
    P, Qf, *_ = spectral.load(s, A, B, params.kappa)
    assert np.allclose(u4, P, rtol=1e-9, atol=1e-9 * abs(A))
    end = res.flagellum.profile(np.array([0.0, 1.0]))
    assert abs(end[0, 0]) < 1e-14 * A and abs(end[1, 0]) < 1e-14 * A
    g = np.polynomial.legendre.leggauss(40)
    xg = 0.5 * (g[0] + 1)
    Pg, Qg, *_ = spectral.load(res.flagellum.profile(xg)[1], A, B, params.kappa)
    assert st.y[4, -1] == pytest.approx(0.5 * g[1] @ Pg, rel=1e-11)
    assert st.y[5, -1] == pytest.approx(0.5 * g[1] @ Qg, rel=1e-10, abs=1e-12 * abs(A))


@pytest.mark.parametrize("name", ["design1", "design2"])
@pytest.mark.parametrize("n", [2, 3])
@pytest.mark.parametrize("regime", ["nlb-nohead", "nlb"])
def test_spectral_balance_agrees_with_a_tight_solve_bvp_reference(name, n, regime):
    """At the balance's omega_t (and, for NLB, its v_h inside the load), solve_bvp at tol 1e-10 (its ~1e-12
    reference, docs/beam.md) gives the same F_x, F_p and w(L) to 1e-12, and NLB's v_h too: the spectral answer is
    that reference's, not solve_bvp's default 1e-6 (up to 2e-7 off it)."""
    params = design(name, n)
    for rpm in (20.0, 150.0, 1000.0):
        res = solve_balance(params, rpm * RPM, regime)
        if regime == "nlb":
            ref = nonlinear.solve_nlb_coupled(params, res.omega_t, tol=1e-10, max_nodes=100000)
            assert res.v_h == pytest.approx(ref.v_h, rel=1e-12)
        else:
            ref = nonlinear.solve_nlb(params, res.omega_t, 0.0, tol=1e-10, max_nodes=100000)
        assert res.F_x == pytest.approx(ref.F_x, rel=1e-12)
        assert res.F_p == pytest.approx(ref.F_p, rel=1e-12)
        assert res.w_tip_over_L * params.L == pytest.approx(ref.w_tip, rel=1e-12)


def _forced(monkeypatch, N, params, rpm, regime="nlb"):
    """The balance's flagellum solved at N intervals from the start (FIRST_N = N), or None."""
    with monkeypatch.context() as m:
        m.setattr(spectral, "FIRST_N", N)
        m.setattr(spectral, "MAX_N", max(N, spectral.MAX_N))
        return nonlinear.solve_nlb_balanced(params, rpm * RPM, regime == "nlb", rpm * RPM / 2)


def test_resolution_doubles_until_the_coefficients_have_decayed(monkeypatch):
    """At 1000 rpm (design 2, n = 2) the load's and the propulsion's coefficients at 33 and 65 points are not
    below TAIL: the solve goes on to 129 points, and its answer is that of 257 points to 1e-13. With MAX_N = 64
    the spectral solve gives up (None) and the balance is found by Brent's search over solve_bvp."""
    params = design("design2", 2)
    res = solve_balance(params, 1000 * RPM, "nlb")
    assert res.converged and res.flagellum.nodes == 129 and "129 points" in res.message
    st = res.flagellum.bvp
    for N in (32, 64):                                  # why fewer points were not enough
        b = spectral.basis(N)
        s = C.chebval(2 * b.x - 1, spectral.basis(128).to_coef @ st.y[1])
        P, Qf, *_ = spectral.load(s, st.A, st.B, params.kappa)
        assert spectral.tails(b, s, P, Qf) > spectral.TAIL
    fine = _forced(monkeypatch, 256, params, 1000)
    for key in ("omega_t", "v_h", "F_x", "F_p", "w_tip"):
        assert getattr(res.flagellum, key) == pytest.approx(getattr(fine, key), rel=1e-13), key
    monkeypatch.setattr(spectral, "MAX_N", 64)
    assert nonlinear.solve_nlb_balanced(params, 1000 * RPM, True, res.omega_t) is None
    searched = solve_balance(params, 1000 * RPM, "nlb")
    assert searched.converged and "Brent" in searched.message
    assert searched.omega_t == pytest.approx(res.omega_t, rel=1e-8)
    assert searched.v_h == pytest.approx(res.v_h, rel=1e-6)


@pytest.mark.parametrize("regime", ["nlb-nohead", "nlb"])
@pytest.mark.parametrize("n", [1, 3, 8])
def test_the_motor_limit_stays_on_the_spectral_path(regime, n, monkeypatch):
    """At the scenes' motor limit (1e4 rpm, design 1, w(L)/L up to ~20) the spectral solve converges (a damped
    Newton once stalled there at round-off for n = 1, handing a 3 ms solve to a 0.7 s search), to the 257-point
    answer."""
    params = design("design1", n)
    res = solve_balance(params, 1e4 * RPM, regime)
    assert res.converged and "Chebyshev collocation" in res.message
    fine = _forced(monkeypatch, 256, params, 1e4, regime)
    assert res.flagellum.F_p == pytest.approx(fine.F_p, rel=1e-12)
    assert res.omega_t == pytest.approx(fine.omega_t, rel=1e-12)


@pytest.mark.parametrize("slope, omega", [(0.0, 1.0), (-1.0, 1.0), (-5.0, 0.01), (30.0, 100.0)])
def test_far_starts_reach_the_same_balance(slope, omega):
    """From the zero slope, slopes of the wrong sign or 30 times too large, omega_t from 0.01 to 100 times the
    root (design 1, n = 3, 1000 rpm): Newton reaches the balance the LB start gives, to 1e-12."""
    params = design("design1", 3)
    W = 1000 * RPM
    ref = solve_balance(params, W, "nlb").flagellum.bvp
    a = params.load_number(1.0)
    c = params.n * params.R_d * params.EI / (params.L ** 2 * params.c_torque)
    problem = spectral.Problem(params.kappa, coupled_D=params.head_drag_number, n=params.n, balance=(a, c, W))
    sol = spectral.solve(problem, lambda x: slope * ref.A * x * (3 - 3 * x + x ** 2) / 6, omega * ref.A,
                         ref.B * omega ** 2)
    assert sol is not None
    assert sol.A == pytest.approx(ref.A, rel=1e-12) and sol.B == pytest.approx(ref.B, rel=1e-12)
    assert sol.y[5, -1] == pytest.approx(ref.y[5, -1], rel=1e-12)


def test_newton_that_does_not_converge_hands_over_to_the_root_search(monkeypatch):
    """One Newton iteration from the LB slope is not enough at 250 rpm: no answer from the spectral solve, and
    the balance comes from Brent's search, converged."""
    params = design("design1", 3)
    monkeypatch.setattr(spectral, "MAX_ITERATIONS", 1)
    assert nonlinear.solve_nlb_balanced(params, 250 * RPM, True, 200 * RPM / 2) is None
    res = solve_balance(params, 250 * RPM, "nlb")
    assert res.converged and "Brent" in res.message


def _iterations(res):
    return int(res.message.split(" Newton iterations")[0].rsplit(", ", 1)[-1])


def test_a_warm_start_is_used_and_changes_nothing():
    """solve_balance from a guess at the same speed starts from that solution: one or two iterations where the LB
    slope takes three or more, to the same numbers; and a curve started speed by speed from the last equals the
    speeds solved cold."""
    params = design("design2", 3)
    cold = solve_balance(params, 120 * RPM, "nlb")
    warm = solve_balance(params, 120 * RPM, "nlb", guess=cold)
    assert _iterations(cold) >= 3 and _iterations(warm) <= 2
    keys = ("omega_t", "v_h", "F_x", "F_p", "w_tip_over_L")
    for key in keys:
        assert getattr(warm, key) == pytest.approx(getattr(cold, key), rel=1e-12), key
    rpms = (30.0, 60.0, 120.0, 240.0)
    curve = solve_balance_curve(params, [r * RPM for r in rpms], "nlb")
    for r, res in zip(rpms, curve):
        alone = solve_balance(params, r * RPM, "nlb")
        for key in keys:
            assert getattr(res, key) == pytest.approx(getattr(alone, key), rel=1e-12), key


def test_balance_module_needs_no_scipy_integrate_or_optimize():
    """The sweep's workers load the beam solver: it imports neither scipy.integrate nor scipy.optimize until a
    balance falls back to them (a subprocess, so this session's imports do not count)."""
    import subprocess
    import sys
    code = ("import sys; import flagbot_sim.beam, flagbot_sim.sweep.task, flagbot_sim.physics.steady, "
            "flagbot_sim.physics.error_estimate; "
            "print(sorted(m for m in ('scipy.integrate', 'scipy.optimize') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "[]"
