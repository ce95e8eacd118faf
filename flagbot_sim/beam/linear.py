"""Linear beam (LB): the paper's closed form for one clamped flagellum (Eqs. deflection .. Fp_linear_solution).

Coordinates of the paper's Fig. "schematic": the flagellum leaves the plate along +y (y = 0 at the clamp, y = L
at the tip); the plate turns it through the medium towards -x at speed omega_t R_d, the medium pushes it back
along +x, so it bends to w > 0 (it trails). The robot moves head first along -y at v_h > 0, and F_p > 0 is the
propulsion along -y. All the quantities of this module are per flagellum.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from .params import BeamParams


@dataclass(frozen=True)
class FlagellumSolution:
    """One flagellum in steady rotation at omega_t, with the head speed v_h that its load includes.

    ``regime`` is "lb" (closed form) or "nlb" (solve_bvp); ``v_h`` is the head speed inside the load and the
    propulsion integrand (0 for NLB w/o head). ``F_x`` = integral of p over the flagellum (the +x drag that
    turns the head, Eq. Tp_flagella), ``F_p`` = integral of q (propulsion along -y, Eq. FpPerLength_full).
    """

    regime: str
    omega_t: float
    v_h: float
    F_x: float
    F_p: float
    w_tip: float
    L: float
    converged: bool = True
    message: str = ""
    nodes: int = 0
    # normalised profile: xi = y/L -> rows (u, u', u'', u''') with u = w/L, primes d/dxi
    profile: Callable[[np.ndarray], np.ndarray] = field(default=None, compare=False, repr=False)
    # solve_bvp state kept for warm starts (continuation in omega_t); None for LB
    bvp: Any = field(default=None, compare=False, repr=False)

    @property
    def w_tip_over_L(self) -> float:
        return self.w_tip / self.L

    def deflection(self, y, derivative: int = 0) -> np.ndarray:
        """d^k w / dy^k at y (m), k = 0..3."""
        if derivative not in (0, 1, 2, 3):
            raise ValueError(f"derivative must be 0, 1, 2 or 3, got {derivative!r}")
        y = np.asarray(y, dtype=float)
        u = self.profile(y / self.L)[derivative]
        # w = L u(y/L) gives d^k w/dy^k = L^(1-k) d^k u/dxi^k
        return u * self.L ** (1 - derivative)


def lb_load(params: BeamParams, omega_t: float) -> float:
    """p_t = eta_p omega_t R_d (Eq. linearunitFx), N/m: the sin^2 term of Eq. beamBending_withoutHead dropped."""
    return params.eta_p * omega_t * params.R_d


def lb_deflection(params: BeamParams, omega_t: float, y) -> np.ndarray:
    """w(y) = p_t y^2 (6 L^2 - 4 L y + y^2) / (24 EI) (Eq. deflection), m."""
    y = np.asarray(y, dtype=float)
    L = params.L
    return lb_load(params, omega_t) * y ** 2 * (6 * L ** 2 - 4 * L * y + y ** 2) / (24 * params.EI)


def lb_tip_deflection(params: BeamParams, omega_t: float) -> float:
    """w(L) = p_t L^4 / (8 EI)."""
    return lb_load(params, omega_t) * params.L ** 4 / (8 * params.EI)


def lb_F_x(params: BeamParams, omega_t: float) -> float:
    """F_x = eta_p omega_t R_d L (Eq. linearFx), N."""
    return lb_load(params, omega_t) * params.L


def lb_F_p(params: BeamParams, omega_t: float, v_h: float) -> float:
    """F_p = (eta_p - eta_t) omega_t R_d w(L) - eta_t v_h L (Eq. Fp_linear_solution), N.

    The -eta_t v_h L term is the small-slope limit of the NLB head term of q (Eq. FpPerLength_full with
    cos^2 = 1): (eta_p - eta_t) v_h - eta_p v_h = -eta_t v_h per length.
    """
    return ((params.eta_p - params.eta_t) * omega_t * params.R_d * lb_tip_deflection(params, omega_t)
            - params.eta_t * v_h * params.L)


def lb_profile(A: float) -> Callable[[np.ndarray], np.ndarray]:
    """Normalised LB profile (u, u', u'', u''') for the load number A = p_t L^3 / EI."""
    def profile(xi):
        xi = np.asarray(xi, dtype=float)
        return np.array([A * xi ** 2 * (6 - 4 * xi + xi ** 2) / 24,
                         A * xi * (3 - 3 * xi + xi ** 2) / 6,
                         A * (1 - xi) ** 2 / 2,
                         -A * (1 - xi)])
    return profile


def solve_lb(params: BeamParams, omega_t: float, v_h: float = 0.0) -> FlagellumSolution:
    """LB flagellum at omega_t; v_h enters only F_p (the LB deflection and F_x ignore the head)."""
    return FlagellumSolution(regime="lb", omega_t=float(omega_t), v_h=float(v_h), F_x=lb_F_x(params, omega_t),
                             F_p=lb_F_p(params, omega_t, v_h), w_tip=lb_tip_deflection(params, omega_t),
                             L=params.L, profile=lb_profile(params.load_number(omega_t)))
