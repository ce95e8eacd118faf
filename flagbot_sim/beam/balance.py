"""Force and torque balance of the whole robot: omega_h, omega_t and v_h for a motor speed omega_T.

Paper Eqs. vHead, OHead, totalOmega, for n identical flagella:

    c_torque omega_h = n R_d F_x(omega_t, v_h)       (head torque, C2 8 pi mu R_h^3, balances the flagella's)
    c_drag   v_h     = n F_p(omega_t, v_h)           (head drag, C1 6 pi mu R_h, balances the propulsion)
    omega_T          = omega_h + omega_t

Eliminating omega_h leaves one scalar equation in omega_t,

    g(omega_t) = omega_t + n R_d F_x(omega_t, v_h(omega_t)) / c_torque - omega_T = 0,

with g(0) = -omega_T < 0 and g increasing (F_x grows with omega_t; tests/test_beam_balance.py checks it on a
grid, and every solve re-checks it on the points the root finder visited), so a bracketing root finder (Brent)
finds the single root. For NLB, v_h(omega_t) comes from the coupled BVP (solve_nlb_coupled), so the drag
balance holds exactly at every omega_t the root finder tries, not only at the end.

Regimes (``REGIMES``):

* ``"lb"``: closed form. F_x = eta_p omega_t R_d L does not depend on v_h, so omega_t = omega_T / (1 + k) with
  k = n eta_p R_d^2 L / c_torque; v_h from c_drag v_h = n ((eta_p - eta_t) omega_t R_d w(L) - eta_t v_h L).
* ``"nlb-nohead"``: NLB with v_h = 0 in the flagellum's load and propulsion (the paper's NLB w/o head, used for
  its beam curves); the head speed follows as v_h = n F_p / c_drag.
* ``"nlb"``: NLB with v_h inside p and q, solved together with the drag balance.

Negative omega_T is the mirror image: omega_h, omega_t, F_x and w change sign, v_h and F_p do not.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable

from .linear import FlagellumSolution, lb_F_p, solve_lb
from .nonlinear import DEFAULT_TOL, BeamSolveError, NLBSolveError, solve_nlb, solve_nlb_balanced, solve_nlb_coupled
from .params import BeamParams
from ..units import RPM

REGIMES = ("lb", "nlb-nohead", "nlb")

#: relative tolerance of the root omega_t (Brent)
BALANCE_RTOL = 1.0e-10
#: a converged balance must satisfy the torque balance to this (relative to c_torque omega_T): far looser than
#: BALANCE_RTOL, far tighter than anything physical; a larger residual means the root finder was misled
BALANCE_CHECK = 1.0e-7


class BalanceError(BeamSolveError):
    """The balance equations could not be solved (no bracket, or a residual that is not monotone)."""


@dataclass(frozen=True)
class BalanceResult:
    """Steady state of the robot at omega_T in one regime (SI; forces per flagellum)."""

    regime: str
    n: int
    omega_T: float            # rad/s, motor speed
    omega_h: float            # rad/s, head spin (opposite to the flagella's)
    omega_t: float            # rad/s, flagella spin
    v_h: float                # m/s, positive = head first
    F_p: float                # N, propulsion of one flagellum along the direction of motion
    F_x: float                # N, drag of one flagellum against its rotation (turns the head)
    w_tip_over_L: float       # tip deflection w(L)/L
    converged: bool
    message: str
    omega_T_bar: float = math.nan    # omega eta_p L^4 / EI
    omega_h_bar: float = math.nan
    omega_t_bar: float = math.nan
    v_bar: float = math.nan          # v eta_p L^3 / EI
    torque_residual: float = math.nan   # (c_torque omega_h - n R_d F_x) / (c_torque omega_T)
    drag_residual: float = math.nan     # (c_drag v_h - n F_p) / (c_drag v_h)
    bvp_solves: int = 0
    flagellum: FlagellumSolution | None = field(default=None, compare=False, repr=False)

    def to_dict(self) -> dict:
        out = {k: getattr(self, k) for k in (
            "regime", "n", "omega_T", "omega_h", "omega_t", "v_h", "F_p", "F_x", "w_tip_over_L", "converged",
            "message", "omega_T_bar", "omega_h_bar", "omega_t_bar", "v_bar", "torque_residual", "drag_residual",
            "bvp_solves")}
        for k in ("omega_T", "omega_h", "omega_t"):
            out[k + "_rpm"] = getattr(self, k) / RPM
        return out


def _check_regime(regime: str) -> None:
    if regime not in REGIMES:
        raise ValueError(f"unknown beam regime {regime!r}; choose one of {', '.join(REGIMES)}")


def lb_head_speed(params: BeamParams, omega_t: float) -> float:
    """v_h of LB: c_drag v_h = n F_p(v_h) = n (F_p(0) - eta_t v_h L) (Eq. Fp_linear_solution), solved for v_h."""
    drive = lb_F_p(params, omega_t, 0.0)
    return params.n * drive / (params.c_drag + params.n * params.eta_t * params.L)


def flagellum_state(params: BeamParams, omega_t: float, regime: str = "nlb", *,
                    guess: FlagellumSolution | None = None, tol: float = DEFAULT_TOL) -> FlagellumSolution:
    """The flagellum at omega_t in ``regime``, with the head drag balance already satisfied where the regime
    couples v_h to the flagellum ("lb", "nlb"); for "nlb-nohead" the load has v_h = 0."""
    _check_regime(regime)
    if regime == "lb":
        return solve_lb(params, omega_t, lb_head_speed(params, omega_t))
    if regime == "nlb-nohead":
        return solve_nlb(params, omega_t, 0.0, guess=guess, tol=tol)
    return solve_nlb_coupled(params, omega_t, guess=guess, tol=tol)


def balance_residual(params: BeamParams, omega_t: float, omega_T: float, regime: str = "nlb") -> float:
    """g(omega_t) = omega_t + n R_d F_x / c_torque - omega_T (rad/s); its root is the steady omega_t."""
    if omega_t == 0:
        return -omega_T
    fl = flagellum_state(params, omega_t, regime)
    return omega_t + params.n * params.R_d * fl.F_x / params.c_torque - omega_T


def _result(params: BeamParams, regime: str, omega_T: float, omega_t: float, fl: FlagellumSolution,
            sign: float, solves: int, message: str) -> BalanceResult:
    n = params.n
    omega_h = omega_T - omega_t          # Eq. totalOmega holds exactly; the torque balance to the root's tolerance
    if regime == "nlb-nohead":
        v_h = n * fl.F_p / params.c_drag   # Eq. vHead, a posteriori: the flagellum's load does not see v_h
    else:
        v_h = fl.v_h
    torque_res = (params.c_torque * omega_h - n * params.R_d * fl.F_x) / (params.c_torque * omega_T)
    drag_res = (params.c_drag * v_h - n * fl.F_p) / (params.c_drag * v_h) if v_h != 0 else 0.0
    converged = abs(torque_res) <= BALANCE_CHECK and abs(drag_res) <= BALANCE_CHECK
    if not converged:
        message = (f"balance residuals too large: torque {torque_res:.3g}, drag {drag_res:.3g} "
                   f"(limit {BALANCE_CHECK:g}); {message}")
    return BalanceResult(
        regime=regime, n=n, omega_T=sign * omega_T, omega_h=sign * omega_h, omega_t=sign * omega_t, v_h=v_h,
        F_p=fl.F_p, F_x=sign * fl.F_x, w_tip_over_L=sign * fl.w_tip_over_L, converged=converged,
        message=message, omega_T_bar=params.normalise_omega(sign * omega_T),
        omega_h_bar=params.normalise_omega(sign * omega_h), omega_t_bar=params.normalise_omega(sign * omega_t),
        v_bar=params.normalise_speed(v_h), torque_residual=torque_res, drag_residual=drag_res, bvp_solves=solves,
        flagellum=fl)


def _failed(params: BeamParams, regime: str, omega_T: float, message: str, solves: int) -> BalanceResult:
    nan = math.nan
    return BalanceResult(regime=regime, n=params.n, omega_T=omega_T, omega_h=nan, omega_t=nan, v_h=nan, F_p=nan,
                         F_x=nan, w_tip_over_L=nan, converged=False, message=message,
                         omega_T_bar=params.normalise_omega(omega_T), bvp_solves=solves)


def solve_balance(params: BeamParams, omega_T: float, regime: str = "nlb", *,
                  guess: BalanceResult | None = None, raise_on_failure: bool = True,
                  rtol: float = BALANCE_RTOL, tol: float = DEFAULT_TOL) -> BalanceResult:
    """Steady omega_h, omega_t, v_h of the robot at motor speed omega_T (rad/s) in ``regime``.

    ``guess``: a result at a nearby omega_T (same params) to warm-start the NLB solves. ``tol``: solve_bvp's,
    for the root search; the one-BVP balance (Chebyshev collocation) is solved to round-off. On failure raises
    :class:`BeamSolveError` (:class:`NLBSolveError` names the omega_t at which solve_bvp failed and why), or
    with ``raise_on_failure=False`` returns a result with ``converged=False``, the reason and NaN values.
    """
    _check_regime(regime)
    if not math.isfinite(omega_T):
        raise ValueError(f"omega_T must be finite, got {omega_T!r}")
    sign, W = (1.0 if omega_T >= 0 else -1.0), abs(float(omega_T))
    if W == 0.0:
        fl = flagellum_state(params, 0.0, "lb")
        return BalanceResult(regime=regime, n=params.n, omega_T=0.0, omega_h=0.0, omega_t=0.0, v_h=0.0, F_p=0.0,
                             F_x=0.0, w_tip_over_L=0.0, converged=True, message="omega_T = 0: at rest",
                             omega_T_bar=0.0, omega_h_bar=0.0, omega_t_bar=0.0, v_bar=0.0, torque_residual=0.0,
                             drag_residual=0.0, flagellum=fl)
    k = params.linear_torque_ratio
    omega_t_lb = W / (1.0 + k)
    if regime == "lb":
        return _result(params, regime, W, omega_t_lb, flagellum_state(params, omega_t_lb, "lb"), sign, 0,
                       "closed form")

    first_guess = guess.flagellum if guess is not None and guess.flagellum is not None \
        and guess.flagellum.bvp is not None and guess.regime == regime else None
    # Bracket: for u' >= 0 and v_h >= 0 the NLB load lies between kappa*p_t and p_t (the sin^2 and head terms
    # only remove load), so g_NLB <= g_LB and the root lies in [omega_T/(1+k), omega_T/(1+kappa k)] (sorted,
    # since kappa > 1 for very stubby flagella).
    lo, hi = sorted((omega_t_lb, W / (1.0 + params.kappa * k)))
    # First the balance as a boundary condition of one BVP (nonlinear.solve_nlb_balanced: omega_t an unknown),
    # from the neighbour's solution or the LB profile: taken if it converges to a root inside the bracket and the
    # balance's checks hold (_result); else, or where it fails, the root search below, as before.
    start = first_guess.omega_t * W / abs(guess.omega_T) if first_guess is not None and guess.omega_T else omega_t_lb
    one = solve_nlb_balanced(params, W, regime == "nlb", start, guess=first_guess.bvp if first_guess else None)
    if one is not None and lo * (1.0 - 1e-9) <= one.omega_t <= hi * (1.0 + 1e-9):
        res = _result(params, regime, W, one.omega_t, one, sign, 1,
                      f"the torque balance as a boundary condition of one BVP (omega_t unknown; {one.message}), its "
                      f"root inside the bracket [{lo:.6g}, {hi:.6g}] rad/s")
        if res.converged:
            return res

    cache: dict[float, FlagellumSolution] = {}

    def state(omega_t: float) -> FlagellumSolution:
        if omega_t not in cache:
            near = min(cache, key=lambda w: abs(w - omega_t)) if cache else None
            start = cache[near] if near is not None else first_guess
            cache[omega_t] = flagellum_state(params, omega_t, regime, guess=start, tol=tol)
        return cache[omega_t]

    def g(omega_t: float) -> float:
        if omega_t == 0.0:
            return -W
        return omega_t + params.n * params.R_d * state(omega_t).F_x / params.c_torque - W

    try:
        # the bracket's ends are checked, and widened towards the always-valid bracket [0, omega_T] if wrong
        g_lo = g(lo)
        if g_lo > 0.0:
            lo, hi, g_lo = 0.0, lo, -W
        if g_lo < 0.0:
            g_hi = g(hi)
            widen = 0
            while g_hi < 0.0:
                if hi >= W:
                    raise BalanceError(f"no steady state found for omega_T = {W:.6g} rad/s in regime {regime}: "
                                       f"g(omega_t) <= 0 on the whole range 0 .. omega_T (F_x = "
                                       f"{state(W).F_x:.3g} N at omega_t = omega_T)")
                widen += 1
                lo, g_lo = hi, g_hi
                hi = W if widen >= 4 else hi + 0.5 * (W - hi)
                g_hi = g(hi)
            if g_hi == 0.0:
                root, iterations = hi, 0
            else:
                from scipy.optimize import brentq      # here: the one-BVP balance above rarely falls through to it
                root, info = brentq(g, lo, hi, xtol=rtol * W * 1e-3, rtol=rtol, full_output=True, disp=False)
                if not info.converged:
                    raise BalanceError(f"Brent's method did not converge for omega_T = {W:.6g} rad/s "
                                       f"({info.flag}) in [{lo:.6g}, {hi:.6g}] rad/s")
                iterations = info.iterations
        else:
            root, iterations = lo, 0
        fl = state(root)
        _check_monotone(cache, g, W, regime)
    except BeamSolveError as exc:
        if raise_on_failure:
            if isinstance(exc, NLBSolveError):
                raise NLBSolveError(exc.omega_t, exc.v_h, f"{exc.reason} [balance at omega_T = {W:.6g} rad/s, "
                                                          f"regime {regime}]") from exc
            raise
        return _failed(params, regime, sign * W, str(exc), len(cache))
    res = _result(params, regime, W, root, fl, sign, len(cache),
                  f"Brent: {iterations} iterations, {len(cache)} BVP solves")
    if not res.converged and raise_on_failure:
        raise BalanceError(f"balance at omega_T = {W:.6g} rad/s, regime {regime}: {res.message}")
    return res


def _check_monotone(cache: dict, g, W: float, regime: str) -> None:
    """Every (omega_t, g) the root finder visited must lie on an increasing curve, else the root may not be
    unique and the bracket argument fails: refuse to answer rather than return one of several roots."""
    points = sorted((w, g(w)) for w in cache)
    points.insert(0, (0.0, -W))
    noise = 1e-9 * W           # BVP accuracy ~1e-9 relative (nonlinear.DEFAULT_TOL)
    for (w0, g0), (w1, g1) in zip(points, points[1:]):
        if w1 > w0 and g1 < g0 - noise:
            raise BalanceError(f"balance residual is not monotone in omega_t for omega_T = {W:.6g} rad/s, regime "
                               f"{regime}: g({w0:.6g}) = {g0:.3g} > g({w1:.6g}) = {g1:.3g} rad/s")


def solve_balance_curve(params: BeamParams, omega_Ts: Iterable[float], regime: str = "nlb", *,
                        raise_on_failure: bool = True, **kwargs) -> list[BalanceResult]:
    """solve_balance for each omega_T in turn, each warm-started from the previous converged one."""
    out, prev = [], None
    for omega_T in omega_Ts:
        res = solve_balance(params, omega_T, regime, guess=prev, raise_on_failure=raise_on_failure, **kwargs)
        out.append(res)
        if res.converged and res.flagellum is not None and res.flagellum.bvp is not None:
            prev = res
    return out
