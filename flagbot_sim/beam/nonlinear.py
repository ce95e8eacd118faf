"""Nonlinear beam (NLB, NLB w/o head): EI w'''' = p(w') with the full RFT load, solved with solve_bvp (at a
given omega_t) or by Chebyshev collocation (spectral.py: omega_t from the robot's torque balance).

Paper Eq. force_withHead_withoutApprox, with V = omega_t R_d:

    EI w'''' = p = eta_p V + (eta_t - eta_p) (V w'^2 + v_h w') / (1 + w'^2),
    w(0) = w'(0) = 0,  w''(L) = w'''(L) = 0                                   (Eq. BC)

and the propulsion per length (Eq. FpPerLength_full, sin theta cos theta = w'/(1+w'^2), cos^2 = 1/(1+w'^2)):

    q = (eta_p - eta_t) (V w' + v_h) / (1 + w'^2) - eta_p v_h.

"NLB w/o head" is the same problem with v_h = 0 in p and q. As in the paper, the beam operator stays the
small-deflection one (w(s) ~ w(y)); only the load keeps the exact angle.

It is solved in normalised form, xi = y/L, u = w/L:

    u'''' = P = A + (kappa - 1) (A u'^2 + B u') / (1 + u'^2),   A = eta_p omega_t R_d L^3/EI,  B = v_bar,
    Q = (1 - kappa) (A u' + B) / (1 + u'^2) - B,                 kappa = eta_t / eta_p,

with two quadrature states I_x' = P, I_p' = Q, I_x(0) = I_p(0) = 0, so that F_x = I_x(1) EI/L^2 and
F_p = I_p(1) EI/L^2 are integrals of p and q computed by the same collocation as the deflection.
In the coupled problem (NLB with the head) B is an unknown parameter of the BVP fixed by the head's drag
balance c_drag v_h = n F_p (Eq. vHead) as an extra boundary condition.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import spectral
from .linear import FlagellumSolution, lb_profile
from .params import BeamParams
from .spectral import load

#: solve_bvp's relative collocation-residual tolerance. Measured against a 2001-node, tol 1e-10 reference,
#: it gives w(L), F_x and F_p to ~1e-9 relative for load numbers A = 0.1 .. 3000 (docs/beam.md).
DEFAULT_TOL = 1.0e-6
INITIAL_NODES = 41
MAX_NODES = 10000
#: smallest continuation step (fraction of the way from the last converged omega_t to the target)
MIN_CONTINUATION_STEP = 1.0e-3


class BeamSolveError(RuntimeError):
    """The beam estimator could not produce a trustworthy answer; the message says where and why."""


class NLBSolveError(BeamSolveError):
    """solve_bvp did not converge for the NLB flagellum at ``omega_t``; ``reason`` is solve_bvp's message."""

    def __init__(self, omega_t: float, v_h: float | None, reason: str):
        self.omega_t = omega_t
        self.v_h = v_h
        self.reason = reason
        head = "v_h from the head drag balance" if v_h is None else f"v_h = {v_h:.6g} m/s"
        super().__init__(f"NLB solve failed at omega_t = {omega_t:.6g} rad/s ({head}): {reason}")


@dataclass(frozen=True)
class BVPState:
    """A converged normalised solution, kept to warm-start the next solve (continuation in omega_t)."""

    x: np.ndarray
    y: np.ndarray
    A: float
    B: float


def _linear_guess(x, A, B, kappa):
    """LB profile at (A, B), the start of every continuation; I_p from the LB q = (1-kappa) A u' - kappa B."""
    u, s, u2, u3 = lb_profile(A)(x)
    return np.vstack([u, s, u2, u3, A * x, (1 - kappa) * A * u - kappa * B * x])


def _lb_head_number(A, kappa, D, n):
    """The LB estimate of the head speed number B at load number A (D = c_drag/(eta_p L)):
    D B = n ((1-kappa) A^2/8 - kappa B)."""
    return n * (1 - kappa) * A * A / 8 / (D + n * kappa)


def _scaled_guess(state: BVPState, A: float):
    """Predictor from a converged neighbour: deflection ~ A, propulsion ~ A^2 (their small-slope scalings)."""
    r = A / state.A
    y = state.y.copy()
    y[:5] *= r
    y[5] *= r * r
    return state.x, y, state.B * r * r


def _attempt(A, B, kappa, x0, y0, coupled_D=None, n=None, B0=None, tol=DEFAULT_TOL, max_nodes=MAX_NODES,
             balance=None):
    """One solve_bvp call. With coupled_D (= c_drag/(eta_p L)) B is unknown: coupled_D B = n I_p(1). With
    ``balance`` = (a, c, W) A is unknown too (the last parameter, starting at ``A``), fixed by the robot's torque
    balance omega_t + n R_d F_x / c_torque = omega_T with omega_t = A / a and n R_d F_x / c_torque = c I_x(1),
    divided by W = omega_T: a boundary condition of the same BVP instead of a root search around it."""
    coupled = coupled_D is not None
    free_A = balance is not None
    n_p = int(coupled) + int(free_A)

    def numbers(p):
        return (p[-1] if free_A else A), (p[0] if coupled else B)

    def fun(x, y, p=None):
        a_num, b = numbers(p)
        P, Q, *_ = load(y[1], a_num, b, kappa)
        return np.vstack([y[1], y[2], y[3], P, P, Q])

    def fun_jac(x, y, p=None):
        a_num, b = numbers(p)
        _, _, dP_ds, dQ_ds, dP_dB, dQ_dB, dP_dA, dQ_dA = load(y[1], a_num, b, kappa)
        J = np.zeros((6, 6, x.size))
        J[0, 1] = J[1, 2] = J[2, 3] = 1.0
        J[3, 1] = J[4, 1] = dP_ds
        J[5, 1] = dQ_ds
        if not n_p:
            return J
        Jp = np.zeros((6, n_p, x.size))
        if coupled:
            Jp[3, 0] = Jp[4, 0] = dP_dB
            Jp[5, 0] = dQ_dB
        if free_A:
            Jp[3, -1] = Jp[4, -1] = dP_dA
            Jp[5, -1] = dQ_dA
        return J, Jp

    def bc(ya, yb, p=None):
        r = [ya[0], ya[1], yb[2], yb[3], ya[4], ya[5]]    # Eq. BC, and the quadratures start at the clamp
        if coupled:
            r.append(coupled_D * p[0] - n * yb[5])        # Eq. vHead: c_drag v_h = n F_p
        if free_A:
            a, c, W = balance
            r.append((p[-1] / a + c * yb[4]) / W - 1.0)   # Eq. OHead with Eq. totalOmega
        return np.array(r)

    def bc_jac(ya, yb, p=None):
        m = 6 + n_p
        Ja, Jb = np.zeros((m, 6)), np.zeros((m, 6))
        Ja[0, 0] = Ja[1, 1] = Ja[4, 4] = Ja[5, 5] = 1.0
        Jb[2, 2] = Jb[3, 3] = 1.0
        if not n_p:
            return Ja, Jb
        Jp = np.zeros((m, n_p))
        if coupled:
            Jb[6, 5] = -n
            Jp[6, 0] = coupled_D
        if free_A:
            a, c, W = balance
            Jb[m - 1, 4] = c / W
            Jp[m - 1, n_p - 1] = 1.0 / (a * W)
        return Ja, Jb, Jp

    from scipy.integrate import solve_bvp     # here: the one-BVP balance (spectral.py) does not need it
    kwargs = dict(fun_jac=fun_jac, bc_jac=bc_jac, tol=tol, max_nodes=max_nodes)
    if free_A:
        # the balance's own conditions to BALANCE_RTOL (Newton meets them to round-off once it converges)
        return solve_bvp(fun, bc, x0, y0, p=([B0] if coupled else []) + [A], bc_tol=1e-10, **kwargs)
    if coupled:
        return solve_bvp(fun, bc, x0, y0, p=[B0], **kwargs)
    return solve_bvp(fun, bc, x0, y0, **kwargs)


def _accepted(res) -> bool:
    return bool(res.status == 0 and np.all(np.isfinite(res.y)) and
                (res.p is None or np.all(np.isfinite(res.p))))


def _solve_normalised(A, B, kappa, *, coupled_D=None, n=None, guess: BVPState | None = None,
                      tol=DEFAULT_TOL, max_nodes=MAX_NODES):
    """Solve at (A, B) from ``guess`` (or the LB profile); on failure continue in A from the guess (or from 0).

    Returns (res, None) on success or (last failed res, reason) when even the continuation fails.
    """
    coupled = coupled_D is not None

    def start(A_t, B_t, from_state):
        if from_state is None or from_state.A == 0:
            x = np.linspace(0.0, 1.0, INITIAL_NODES)
            if coupled:
                B_t = _lb_head_number(A_t, kappa, coupled_D, n)
            return x, _linear_guess(x, A_t, B_t, kappa), B_t
        return _scaled_guess(from_state, A_t)

    def attempt(A_t, B_t, from_state):
        x0, y0, B0 = start(A_t, B_t, from_state)
        return _attempt(A_t, B_t, kappa, x0, y0, coupled_D=coupled_D, n=n, B0=B0, tol=tol, max_nodes=max_nodes)

    res = attempt(A, B, guess)
    if _accepted(res):
        return res, None
    # Continuation in omega_t (i.e. in A), B moving with A when it is given: from the supplied neighbour if
    # there is one, else (or if that fails too) from the linear solution at omega_t = 0. The step halves on
    # failure and doubles on success.
    reasons = []
    for source in ([guess] if guess is not None else []) + [None]:
        A0, B0 = (source.A, source.B) if source is not None else (0.0, 0.0)
        state, t_done, step = source, 0.0, 0.25
        while t_done < 1.0:
            t = min(1.0, t_done + step)
            A_t, B_t = A0 + t * (A - A0), B0 + t * (B - B0)
            res = attempt(A_t, B_t, state)
            if _accepted(res):
                state = BVPState(res.x, res.y, A_t, float(res.p[0]) if coupled else B_t)
                t_done, step = t, min(2.0 * step, 1.0)
                continue
            step *= 0.5
            if step < MIN_CONTINUATION_STEP:
                origin = "the linear solution" if source is None else f"the neighbour at A = {A0:.4g}"
                reasons.append(f"{res.message} (continuation from {origin} stalled {100 * t_done:.1f}% of the "
                               f"way to the target)")
                break
        else:
            return res, None
    return res, "; ".join(reasons)


def _to_solution(params: BeamParams, omega_t: float, res, B: float, reason) -> FlagellumSolution:
    v_h = params.speed_from_number(B)
    if reason is not None:
        nan = float("nan")
        return FlagellumSolution(regime="nlb", omega_t=float(omega_t), v_h=v_h, F_x=nan, F_p=nan, w_tip=nan,
                                 L=params.L, converged=False, message=reason, nodes=int(res.x.size),
                                 profile=lambda xi: np.full((4,) + np.shape(xi), np.nan))
    force = params.EI / params.L ** 2
    sol = res.sol
    return FlagellumSolution(regime="nlb", omega_t=float(omega_t), v_h=v_h, F_x=float(res.y[4, -1] * force),
                             F_p=float(res.y[5, -1] * force), w_tip=float(res.y[0, -1] * params.L), L=params.L,
                             converged=True, message=res.message, nodes=int(res.x.size),
                             profile=lambda xi: sol(xi)[:4],
                             bvp=BVPState(res.x, res.y, params.load_number(omega_t), B))


def solve_nlb(params: BeamParams, omega_t: float, v_h: float = 0.0, *, guess: FlagellumSolution | None = None,
              tol: float = DEFAULT_TOL, max_nodes: int = MAX_NODES,
              raise_on_failure: bool = True) -> FlagellumSolution:
    """NLB flagellum at omega_t (rad/s) with a given head speed v_h (m/s) in the load; v_h = 0 is NLB w/o head.

    ``guess``: a converged neighbouring solution to start from (else the LB profile). Raises
    :class:`NLBSolveError` if solve_bvp does not converge even with continuation, or, with
    ``raise_on_failure=False``, returns a solution with ``converged=False``, the reason and NaN values.
    """
    A, B = params.load_number(omega_t), params.normalise_speed(v_h)
    res, reason = _solve_normalised(A, B, params.kappa, guess=guess.bvp if guess is not None else None,
                                    tol=tol, max_nodes=max_nodes)
    if reason is not None and raise_on_failure:
        raise NLBSolveError(omega_t, v_h, reason)
    return _to_solution(params, omega_t, res, B, reason)


def solve_nlb_coupled(params: BeamParams, omega_t: float, *, guess: FlagellumSolution | None = None,
                      tol: float = DEFAULT_TOL, max_nodes: int = MAX_NODES,
                      raise_on_failure: bool = True) -> FlagellumSolution:
    """NLB flagellum at omega_t with v_h solved together with the deflection from c_drag v_h = n F_p.

    v_h enters the load p and the propulsion q, and F_p depends on v_h, so the head speed is an unknown
    parameter of the same BVP rather than an outer iteration. The returned ``v_h`` satisfies the drag balance
    to solve_bvp's tolerance.
    """
    A = params.load_number(omega_t)
    res, reason = _solve_normalised(A, 0.0, params.kappa, coupled_D=params.head_drag_number, n=params.n,
                                    guess=guess.bvp if guess is not None else None, tol=tol,
                                    max_nodes=max_nodes)
    if reason is not None and raise_on_failure:
        raise NLBSolveError(omega_t, None, reason)
    B = float(res.p[0]) if res.p is not None and reason is None else float("nan")
    return _to_solution(params, omega_t, res, B, reason)


def solve_nlb_balanced(params: BeamParams, omega_T: float, coupled: bool, omega_t0: float, *,
                       guess: BVPState | None = None) -> FlagellumSolution | None:
    """The flagellum at the omega_t that balances the torques of the robot at motor speed omega_T > 0 (rad/s):
    omega_t an unknown (through A), fixed by omega_t + n R_d F_x / c_torque = omega_T, v_h too if ``coupled``
    (NLB; else NLB w/o head), by Chebyshev collocation of the BVP's integral equation (spectral.py) from
    ``guess`` (a converged neighbour, scaled to omega_t0) or from the LB slope at omega_t0. None if Newton does not
    converge or the resolution would pass spectral.MAX_N (balance.solve_balance then searches the root with
    solve_bvp). The solution's omega_t is the balance; its error is the interpolant's (trailing Chebyshev
    coefficients of the slope, the load and the propulsion below spectral.TAIL): within 3e-14 of solve_bvp at
    tol 1e-10 (docs/beam.md), where ``tol`` of the root search's solve_bvp does not apply."""
    A0 = params.load_number(omega_t0)
    kappa = params.kappa
    D, n = params.head_drag_number, params.n
    if guess is not None and guess.A > 0:
        gx, gy, B0 = _scaled_guess(guess, A0)

        def s0(xi):
            return np.interp(xi, gx, gy[1])
    else:
        def s0(xi):
            return lb_profile(A0)(xi)[1]                               # the LB slope
        B0 = _lb_head_number(A0, kappa, D, n) if coupled else 0.0
    a = params.load_number(1.0)                                       # A per rad/s of omega_t
    c = params.n * params.R_d * params.EI / (params.L ** 2 * params.c_torque)   # rad/s per unit of I_x(1)
    problem = spectral.Problem(kappa, coupled_D=D if coupled else None, n=n, balance=(a, c, float(omega_T)))
    sol = spectral.solve(problem, s0, A0, B0)
    if sol is None:
        return None
    force = params.EI / params.L ** 2
    B = sol.B if coupled else 0.0
    return FlagellumSolution(
        regime="nlb", omega_t=params.omega_from_load_number(sol.A), v_h=params.speed_from_number(B),
        F_x=float(sol.y[4, -1] * force), F_p=float(sol.y[5, -1] * force), w_tip=float(sol.y[0, -1] * params.L),
        L=params.L, converged=True, nodes=sol.basis.N + 1, profile=sol.profile,
        bvp=BVPState(sol.x, sol.y, sol.A, B),
        message=f"Chebyshev collocation on {sol.basis.N + 1} points, {sol.iterations} Newton iterations, trailing "
                f"coefficients {sol.tail:.1e} of the largest")


__all__ = ["BeamSolveError", "NLBSolveError", "solve_nlb", "solve_nlb_coupled", "solve_nlb_balanced", "DEFAULT_TOL",
           "BVPState"]
