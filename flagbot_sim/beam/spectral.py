"""The NLB flagellum by Chebyshev collocation of its integral equation: the torque balance as one small Newton solve.

The normalised slope s = u' (xi = y/L in [0, 1]) of the NLB beam (nonlinear.py) obeys s''' = P(s) with
s(0) = 0 and s'(1) = s''(1) = 0 (Eq. BC: u(0) = u'(0) = 0, u''(1) = u'''(1) = 0). Integrating three times with
those conditions turns the BVP into a second-kind equation,

    s = K P(s),   K = Q R R,   Q f = integral_0^xi f,   R f = integral_xi^1 f = (1 w^T - Q) f,

and u = Q s, u'' = R R P, u''' = -R P, I_x(1) = w . P, I_p(1) = w . Q_load. On the N + 1 Chebyshev points Q and
w integrate the degree-N interpolant exactly, so the error falls geometrically with N (the solution is analytic:
P is a rational function of s with its poles at s = +-i), and Newton's matrix I - K diag(dP/ds) stays well
conditioned at any N (K smooths; the third derivative's collocation matrix would grow as N^6).

``solve`` is the one-BVP torque balance of balance.solve_balance (and NLB's drag balance with it): A (omega_t) and,
for NLB, B (v_h) are unknowns beside s, fixed by the same two conditions nonlinear.solve_nlb_balanced states as
boundary conditions. It doubles N until the trailing Chebyshev coefficients of the slope, the load and the
propulsion are below TAIL of their largest, and returns None when Newton does not converge or N would pass MAX_N:
the caller then takes solve_bvp's path.
numpy only: no scipy import (the sweep's workers load it without scipy.integrate).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.polynomial import chebyshev as C

#: the first resolution (Chebyshev intervals); each retry doubles it, up to MAX_N
FIRST_N = 32
MAX_N = 256
#: accepted when the last three Chebyshev coefficients of the slope, the load P and the propulsion Q are below
#: this fraction of each one's largest
TAIL = 1.0e-12
#: Newton stops once an update moves every unknown by less than this (relative): the next would move it ~1e-22
STEP_TOL = 1.0e-11
MAX_ITERATIONS = 40


@dataclass(frozen=True)
class Basis:
    """Chebyshev points on [0, 1] (ascending) and the operators on values there, built once per N."""

    N: int
    x: np.ndarray          # N+1 points, x[0] = 0, x[-1] = 1
    to_coef: np.ndarray    # values -> Chebyshev coefficients (in t = 2 xi - 1)
    Q: np.ndarray          # values of f -> values of integral_0^xi f
    R: np.ndarray          # values of f -> values of integral_xi^1 f
    w: np.ndarray          # integral_0^1 f = w . f  (Clenshaw-Curtis weights)
    K: np.ndarray          # Q R R: P -> s


@lru_cache(maxsize=8)
def basis(N: int) -> Basis:
    t = -np.cos(np.pi * np.arange(N + 1) / N)           # ascending Chebyshev points of the second kind
    t[0], t[-1] = -1.0, 1.0
    if N % 2 == 0:
        t[N // 2] = 0.0
    to_coef = np.linalg.inv(C.chebvander(t, N))
    # integral from xi = 0 (t = -1) of the interpolant: chebint's antiderivative, evaluated at the points, halved
    # (dxi = dt / 2)
    Q = 0.5 * C.chebvander(t, N + 1) @ C.chebint(to_coef, lbnd=-1.0)
    w = Q[-1].copy()
    R = w[None, :] - Q
    Q.flags.writeable = R.flags.writeable = w.flags.writeable = to_coef.flags.writeable = False
    K = Q @ R @ R
    K.flags.writeable = False
    x = 0.5 * (t + 1.0)
    x.flags.writeable = False
    return Basis(N, x, to_coef, Q, R, w, K)


def load(s, A, B, kappa):
    """The normalised NLB load P and propulsion Q (Eq. force_withHead_withoutApprox and Eq. FpPerLength_full, as
    nonlinear.py's docstring writes them) and their derivatives with respect to s = u', B and A: the one
    implementation, which solve_bvp's path (nonlinear.py) uses too."""
    D = 1.0 + s * s
    P = A + (kappa - 1.0) * (A * s * s + B * s) / D
    Qf = (1.0 - kappa) * (A * s + B) / D - B
    dP_ds = (kappa - 1.0) * (2.0 * A * s + B * (1.0 - s * s)) / (D * D)
    dQ_ds = (1.0 - kappa) * (A * (1.0 - s * s) - 2.0 * B * s) / (D * D)
    dP_dB = (kappa - 1.0) * s / D
    dQ_dB = (1.0 - kappa) / D - 1.0
    dP_dA = 1.0 + (kappa - 1.0) * s * s / D
    dQ_dA = (1.0 - kappa) * s / D
    return P, Qf, dP_ds, dQ_ds, dP_dB, dQ_dB, dP_dA, dQ_dA


@dataclass(frozen=True)
class Problem:
    """What is solved: kappa; ``coupled_D`` = c_drag/(eta_p L) and ``n`` when B is unknown (NLB: coupled_D B =
    n I_p(1)), else B fixed at ``B``; ``balance`` = (a, c, W) when A is unknown (omega_t = A / a, and
    (A / a + c I_x(1)) / W = 1), else A fixed at ``A``."""

    kappa: float
    A: float = 0.0
    B: float = 0.0
    coupled_D: float | None = None
    n: int = 0
    balance: tuple[float, float, float] | None = None

    def unpack(self, z, N):
        s = z[: N + 1]
        k = N + 1
        B = z[k] if self.coupled_D is not None else self.B
        k += self.coupled_D is not None
        A = z[k] if self.balance is not None else self.A
        return s, A, B

    def residual(self, z, b: Basis, jacobian: bool = False):
        """F(z) (and dF/dz): s - K P(s), then the drag balance (coupled), then the torque balance."""
        N = b.N
        s, A, B = self.unpack(z, N)
        P, Qf, dP_ds, dQ_ds, dP_dB, dQ_dB, dP_dA, dQ_dA = load(s, A, B, self.kappa)
        F = [s - b.K @ P]
        coupled, free_A = self.coupled_D is not None, self.balance is not None
        if coupled:
            F.append([self.coupled_D * B - self.n * (b.w @ Qf)])
        if free_A:
            a, c, W = self.balance
            F.append([(A / a + c * (b.w @ P)) / W - 1.0])
        F = np.concatenate(F)
        if not jacobian:
            return F
        m = F.size
        J = np.zeros((m, m))
        J[: N + 1, : N + 1] = np.eye(N + 1) - b.K * dP_ds[None, :]
        col = N + 1
        if coupled:
            J[: N + 1, col] = -b.K @ dP_dB
            col += 1
        if free_A:
            J[: N + 1, col] = -b.K @ dP_dA
        row = N + 1
        if coupled:
            J[row, : N + 1] = -self.n * b.w * dQ_ds
            J[row, N + 1] = self.coupled_D - self.n * (b.w @ dQ_dB)
            if free_A:
                J[row, -1] = -self.n * (b.w @ dQ_dA)
            row += 1
        if free_A:
            a, c, W = self.balance
            J[row, : N + 1] = c * b.w * dP_ds / W
            if coupled:
                J[row, N + 1] = c * (b.w @ dP_dB) / W
            J[row, -1] = (1.0 / a + c * (b.w @ dP_dA)) / W
        return F, J


@dataclass(frozen=True)
class Solution:
    """A converged NLB flagellum: the profile on the Chebyshev points (rows u, u', u'', u''', I_x, I_p, as
    nonlinear.BVPState keeps them), A, B, N, the Newton iterations of the last resolution and the tail."""

    basis: Basis
    y: np.ndarray
    A: float
    B: float
    iterations: int
    tail: float

    @property
    def x(self) -> np.ndarray:
        return self.basis.x

    def profile(self, xi) -> np.ndarray:
        """Rows u, u', u'', u''' at xi (normalised), from the Chebyshev interpolant."""
        coef = self.basis.to_coef @ self.y[:4].T                      # (N+1, 4)
        xi = np.asarray(xi, dtype=float)
        return C.chebval(2.0 * xi - 1.0, coef)


def _newton(problem: Problem, b: Basis, z: np.ndarray):
    """Newton from z: (z, iterations), done when a step moves every unknown by less than STEP_TOL (relative; the
    step is taken), or None after MAX_ITERATIONS or on a singular or non-finite step. No damping: halving steps
    until the residual's max-norm decreased converged from fewer far starts (148 of 150, both designs, 100 to 1e4
    rpm, slopes -5 to 30 times the LB one, omega_t 0.01 to 100 times the root) than the plain iteration (150)."""
    for it in range(1, MAX_ITERATIONS + 1):
        F, J = problem.residual(z, b, jacobian=True)
        try:
            dz = np.linalg.solve(J, -F)
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(dz)):
            return None
        scale = np.maximum(np.abs(z), np.max(np.abs(z[: b.N + 1])) * 1e-3 + 1e-300)
        z = z + dz
        if np.max(np.abs(dz) / scale) <= STEP_TOL:
            return z, it
    return None


def tails(b: Basis, *rows: np.ndarray) -> float:
    """The largest, over ``rows`` (values on the points), of the last three Chebyshev coefficients' size relative to
    the row's largest coefficient."""
    worst = 0.0
    for row in rows:
        c = np.abs(b.to_coef @ row)
        top = c.max()
        if top > 0:
            worst = max(worst, float(c[-3:].max() / top))
    return worst


def solve(problem: Problem, s0, A0: float, B0: float = 0.0) -> Solution | None:
    """Solve ``problem`` from the slope guess s0 (a callable xi -> s) with A0, B0 as the unknowns' starts (the
    fixed ones are the problem's). None if Newton fails or the resolution would exceed MAX_N."""
    N = FIRST_N
    b = basis(N)
    z = np.concatenate([s0(b.x), [B0] if problem.coupled_D is not None else [],
                        [A0] if problem.balance is not None else []])
    while True:
        out = _newton(problem, b, z)
        if out is None:
            return None
        z, iterations = out
        s, A, B = problem.unpack(z, N)
        P, Qf, *_ = load(s, A, B, problem.kappa)
        # the outputs are integrals of s (w(L)), P (F_x) and Q (F_p, and v_h through the drag balance): P and Q,
        # three integrations rougher than s, decide the resolution
        tail = tails(b, s, P, Qf)
        if tail <= TAIL:
            break
        if 2 * N > MAX_N:
            return None
        coef = b.to_coef @ s
        N *= 2
        b = basis(N)
        z = np.concatenate([C.chebval(2.0 * b.x - 1.0, coef), z[b.N // 2 + 1:]])
    RP = b.R @ P
    y = np.vstack([b.Q @ s, s, b.R @ RP, -RP, b.Q @ P, b.Q @ Qf])
    return Solution(b, y, float(A), float(B), iterations, tail)


__all__ = ["Problem", "Solution", "basis", "load", "solve", "FIRST_N", "MAX_N", "TAIL"]
