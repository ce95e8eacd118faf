"""Steady rotation of the clamped flagellum as a geometrically exact Kirchhoff rod: a boundary-value problem.

An independent reference for the DER clamped-flagellum scene (issue 6): no discretisation in time, no discrete
rod, only the continuum equations and ``scipy.integrate.solve_bvp``.

The flagellum (length L, bending stiffness EI, stretching stiffness EA, isotropic, unshearable) is clamped at
radius R_d in a plate turning about the x axis at omega. In the frame turning with the plate its shape is steady,
and every material point moves in the lab on a circle, with velocity v = omega x_hat x r (r measured from the
axis) and acceleration a = omega x_hat x (omega x_hat x r) = -omega^2 (0, y, z). With isotropic bending and no
distributed torque the twist moment m.t is constant along the rod and vanishes at the free tip, so the rod is
twist-free and the Kirchhoff equations in the *undeformed* arc length s in [0, L] are

    r' = (1 + eps) t,    eps = (n.t) / EA,           (axial strain; EA = inf: inextensible, r' = t)
    t' = (m x t) / EI,                               (m = EI t x t', the bending moment)
    m' = -(1 + eps) t x n,                           (moment balance, no distributed torque: m' + r' x n = 0)
    n' = -f(r, t) + rho_A a(r),                       (force balance; rho_A = 0 drops the centrifugal term)

as the DER flagellum has them: its stretching springs store 1/2 EA (l/l0 - 1)^2 l0 (physics/elastic.py, tension
EA times the engineering strain l/l0 - 1, EA = E pi r0^2 as physics/network.py builds it), its bending springs
measure the turning angle per *rest* Voronoi length (EI t x t' with t' per undeformed length), and its drag and
mass are lumped over the rest lengths (loads per undeformed length, the tip at s = L).

with the resistive-force-theory load per unit length f = -eta_p v - (eta_t - eta_p)(v.t) t and the boundary
conditions r(0) = (0, R_d, 0), t(0) = x_hat (clamped), n(L) = 0, m(L) = 0 (free tip). The outputs are
Fx = int f_x ds (medium force along the axis; negative = thrust towards the head), Tx = int (r x f)_x ds (medium
torque about the axis) and the tip r(L) in the co-rotating frame: the same quantities and signs as
``Simulation.summary()`` of the ``clamped_flagellum`` scene (a positive omega makes the tip lag at negative z).

The DER scene has inertia (lumped masses, density from the scene), so at steady rotation its nodes carry the
centrifugal load rho A omega^2 (0, y, z); ``from_scene`` includes that term when the scene lists ``inertia``
(``rho_A = density * pi r0^2``). It is a 0.2% effect at 10 rpm for design 1's flagellum and grows as omega^2.
That load stretches the flagellum (design 1: mean strain 1.1e-4 at 100 rpm, 1.9e-3 at 2000 rpm), so
``from_scene`` gives the rod the scene's EA = E pi r0^2 (``extensible=False``: EA = inf, the inextensible rod);
``solve_clamped_rod``'s default is EA = inf.

Numerics. The problem is solved in normalised form (s = L xi, r = L r_bar, m = EI/L m_bar, n = EI/L^2 n_bar),
with two quadrature states for Fx and Tx so that they come from the same collocation as the shape, an analytic
Jacobian, continuation in omega from the linear-beam solution at small omega_bar = eta_p omega L^4 / EI, and a
mesh-refinement check: the converged solution is solved again on a mesh with every interval halved, and the
largest relative change of Fx, Tx and the tip is reported as ``error_estimate``. ``converged`` is True only if
both solves met solve_bvp's tolerance and the estimate is below ``check_rtol``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_bvp

from ..physics.medium import bending_stiffness, rft_coefficients
from ..physics.network import section

#: default solve_bvp relative residual tolerance
DEFAULT_TOL = 1.0e-8
#: initial number of mesh nodes of every solve
DEFAULT_NODES = 65
MAX_NODES = 200000
#: |omega_bar| up to which the linear-beam profile is a good enough first guess (the continuation's start)
START_OMEGA_BAR = 0.5
#: smallest continuation step, as a ratio of consecutive omega_bar values (ln)
MIN_LOG_STEP = 1.0e-3
#: largest relative change of Fx, Tx, tip under mesh halving still called converged
DEFAULT_CHECK_RTOL = 1.0e-6

_NSTATE = 14          # r(3) t(3) m(3) n(3) Fx Tx (normalised)


class RodBVPError(RuntimeError):
    """The steady rod problem could not be solved; the message says at which omega and why."""

    def __init__(self, omega: float, omega_bar: float, reason: str):
        self.omega = omega
        self.omega_bar = omega_bar
        self.reason = reason
        super().__init__(f"rod BVP failed at omega = {omega:.6g} rad/s (omega_bar = {omega_bar:.6g}): {reason}")


@dataclass
class RodSolution:
    """Steady shape and loads of the clamped rotating rod (SI units, co-rotating frame)."""

    omega: float                 # rad/s
    omega_bar: float             # eta_p omega L^4 / EI
    Fx: float                    # N, int f_x ds
    Tx: float                    # N m, int (r x f)_x ds
    tip: np.ndarray              # (3,) m, r(L)
    s: np.ndarray                # (M,) m, the final collocation mesh
    r: np.ndarray                # (3, M) m, centreline
    t: np.ndarray                # (3, M) unit tangent
    m: np.ndarray                # (3, M) N m, internal moment
    n: np.ndarray                # (3, M) N, internal force (exerted by the outer part s+ on the inner part)
    converged: bool
    message: str
    error_estimate: float        # largest relative change of Fx, Tx, tip under mesh halving
    nodes: int
    continuation: list = field(default_factory=list)   # omega_bar values solved on the way
    strain: np.ndarray | None = None                   # (M,) axial strain eps = (n.t) / EA (0 if inextensible)
    params: dict = field(default_factory=dict)
    _sol: object = field(default=None, repr=False)

    @property
    def tip_deflection(self) -> float:
        """|z| of the tip (m): the lag of the tip behind the clamp."""
        return abs(float(self.tip[2]))

    def state(self, s) -> np.ndarray:
        """(12, len(s)) SI state [r, t, m, n] at arc lengths s (m) from the collocation's C1 interpolant."""
        p = self.params
        L, EI = p["L"], p["EI"]
        y = self._sol(np.asarray(s, float) / L)[:12]
        return np.vstack([y[0:3] * L, y[3:6], y[6:9] * EI / L, y[9:12] * EI / L ** 2])

    def state_derivative(self, s) -> np.ndarray:
        """(12, len(s)) d/ds of :meth:`state` (SI), from the interpolant."""
        p = self.params
        L, EI = p["L"], p["EI"]
        y = self._sol.derivative()(np.asarray(s, float) / L)[:12]
        return np.vstack([y[0:3], y[3:6] / L, y[6:9] * EI / L ** 2, y[9:12] * EI / L ** 3])


# ------------------------------------------------------------------------------------------------ equations
def _skew(a):
    """(3, 3, N) cross-product matrices [a]x of the columns of a (3, N)."""
    z = np.zeros_like(a[0])
    return np.array([[z, -a[2], a[1]], [a[2], z, -a[0]], [-a[1], a[0], z]])


def _make_problem(W: float, kappa: float, Rbar: float, C: float, e: float = 0.0):
    """fun, fun_jac, bc, bc_jac of the normalised problem.

    W = omega_bar, kappa = eta_t/eta_p, Rbar = R_d/L, C = rho_A omega^2 L^4 / EI (centrifugal number),
    e = EI / (EA L^2) (extensibility: eps = e n_bar.t; 0 = inextensible).
    Normalised load f_bar = f L^3/EI = -W [u + (kappa - 1)(u.t) t], u = x_hat x r_bar = (0, -z, y).
    """
    k1 = kappa - 1.0

    def load(y):
        r, t = y[0:3], y[3:6]
        u = np.array([np.zeros_like(r[0]), -r[2], r[1]])
        ut = np.einsum("in,in->n", u, t)
        f = -W * (u + k1 * ut * t)
        return r, t, u, ut, f

    def fun(x, y):
        r, t, u, ut, f = load(y)
        m, n = y[6:9], y[9:12]
        g = 1.0 + e * np.einsum("in,in->n", n, t)                     # 1 + eps: stretch ratio
        dn = -f
        dn[1] -= C * r[1]
        dn[2] -= C * r[2]
        return np.vstack([g * t, np.cross(m, t, axis=0), g * np.cross(n, t, axis=0), dn,
                          f[0][None], (r[1] * f[2] - r[2] * f[1])[None]])

    def fun_jac(x, y):
        r, t, u, ut, f = load(y)
        m, n = y[6:9], y[9:12]
        N = x.size
        I3 = np.eye(3)[:, :, None]
        A = I3 + k1 * t[:, None, :] * t[None, :, :]                    # (3, 3, N)
        df_dr = np.zeros((3, 3, N))
        df_dr[:, 1] = -W * A[:, 2]                                      # du/dr: u1 = -r2, u2 = r1
        df_dr[:, 2] = W * A[:, 1]
        df_dt = -W * k1 * (ut[None, None, :] * I3 + t[:, None, :] * u[None, :, :])
        g = 1.0 + e * np.einsum("in,in->n", n, t)
        nxt = np.cross(n, t, axis=0)
        J = np.zeros((_NSTATE, _NSTATE, N))
        J[0:3, 3:6] = g * I3 + e * t[:, None, :] * n[None, :, :]        # d(g t)/dt, dg/dt = e n
        J[0:3, 9:12] = e * t[:, None, :] * t[None, :, :]                # d(g t)/dn, dg/dn = e t
        J[3:6, 6:9] = -_skew(t)                                         # d(m x t)/dm
        J[3:6, 3:6] = _skew(m)                                          # d(m x t)/dt
        J[6:9, 9:12] = -g * _skew(t) + e * nxt[:, None, :] * t[None, :, :]   # d(g n x t)/dn
        J[6:9, 3:6] = g * _skew(n) + e * nxt[:, None, :] * n[None, :, :]     # d(g n x t)/dt
        J[9:12, 0:3] = -df_dr
        J[10, 1] -= C
        J[11, 2] -= C
        J[9:12, 3:6] = -df_dt
        J[12, 0:3] = df_dr[0]
        J[12, 3:6] = df_dt[0]
        J[13, 0:3] = r[1] * df_dr[2] - r[2] * df_dr[1]
        J[13, 1] += f[2]
        J[13, 2] -= f[1]
        J[13, 3:6] = r[1] * df_dt[2] - r[2] * df_dt[1]
        return J

    def bc(ya, yb):
        return np.concatenate([ya[0:3] - [0.0, Rbar, 0.0], ya[3:6] - [1.0, 0.0, 0.0], yb[6:9], yb[9:12],
                               ya[12:14]])

    Ja = np.zeros((_NSTATE, _NSTATE))
    Jb = np.zeros((_NSTATE, _NSTATE))
    Ja[0:6, 0:6] = np.eye(6)
    Jb[6:12, 6:12] = np.eye(6)
    Ja[12:14, 12:14] = np.eye(2)

    def bc_jac(ya, yb):
        return Ja, Jb

    return fun, fun_jac, bc, bc_jac


def _linear_guess(x, W, Rbar):
    """Linear-beam solution (uniform load W Rbar towards -z) in the normalised variables."""
    P = W * Rbar
    N = x.size
    y = np.zeros((_NSTATE, N))
    w = P * x ** 2 * (6 - 4 * x + x ** 2) / 24
    y[0] = x
    y[1] = Rbar
    y[2] = -w
    y[3] = 1.0
    y[5] = -P * x * (3 - 3 * x + x ** 2) / 6
    y[7] = P * (1 - x) ** 2 / 2                       # m_y
    y[11] = -P * (1 - x)                              # n_z
    y[13] = -W * Rbar * Rbar * x                      # Tx = -W Rbar^2 xi (f_z = -W Rbar at y = Rbar)
    return y


def _refine(x):
    """Mesh with every interval halved."""
    mid = 0.5 * (x[:-1] + x[1:])
    out = np.empty(2 * x.size - 1)
    out[0::2] = x
    out[1::2] = mid
    return out


def _ok(res) -> bool:
    return bool(res.status == 0 and np.all(np.isfinite(res.y)))


def _outputs(y_end):
    return np.array([y_end[12], y_end[13], y_end[0], y_end[1], y_end[2]])


def solve_clamped_rod(L: float, R_d: float, EI: float, eta_t: float, eta_p: float, omega: float, *,
                      rho_A: float = 0.0, EA: float = math.inf, tol: float = DEFAULT_TOL, nodes: int = DEFAULT_NODES,
                      max_nodes: int = MAX_NODES, check_rtol: float = DEFAULT_CHECK_RTOL,
                      guess: RodSolution | None = None, raise_on_failure: bool = True) -> RodSolution:
    """Steady shape, Fx, Tx and tip of the clamped flagellum turning at omega (rad/s) about the x axis.

    L (m), R_d (m, clamp radius), EI (N m^2), eta_t, eta_p (N s/m^2, RFT coefficients), rho_A (kg/m, mass per
    undeformed length for the centrifugal load; 0 for a massless rod), EA (N, stretching stiffness; inf, the
    default, for an inextensible rod). ``guess``: a converged neighbouring solution to start
    the continuation from (else the linear beam at small omega_bar). ``nodes``: initial mesh size of each solve.

    Raises :class:`RodBVPError` (saying at which omega and why) if the continuation stalls, or, with
    ``raise_on_failure=False``, returns a solution with ``converged=False`` and the reason in ``message``.
    """
    for name, val in (("L", L), ("EI", EI), ("eta_t", eta_t), ("eta_p", eta_p)):
        if not (math.isfinite(val) and val > 0):
            raise ValueError(f"{name} must be finite and > 0, got {val!r}")
    if not (math.isfinite(R_d) and R_d >= 0):
        raise ValueError(f"R_d must be finite and >= 0, got {R_d!r}")
    if not math.isfinite(omega):
        raise ValueError(f"omega must be finite, got {omega!r}")
    if not (math.isfinite(rho_A) and rho_A >= 0):
        raise ValueError(f"rho_A must be finite and >= 0, got {rho_A!r}")
    if not (EA > 0 and not math.isnan(EA)):
        raise ValueError(f"EA must be > 0 (math.inf: inextensible), got {EA!r}")
    if nodes < 3:
        raise ValueError(f"nodes must be >= 3, got {nodes}")

    kappa = eta_t / eta_p
    Rbar = R_d / L
    W_target = eta_p * omega * L ** 4 / EI
    C_per_omega2 = rho_A * L ** 4 / EI       # C = rho_A omega^2 L^4 / EI = C_per_omega2 * omega^2
    W_per_omega = eta_p * L ** 4 / EI
    ext = EI / (EA * L ** 2)                 # eps = ext * n_bar.t (0 for EA = inf)
    params = dict(L=L, R_d=R_d, EI=EI, eta_t=eta_t, eta_p=eta_p, rho_A=rho_A, EA=EA, tol=tol, kappa=kappa)

    def attempt(W, x0, y0):
        om = W / W_per_omega
        fun, fun_jac, bc, bc_jac = _make_problem(W, kappa, Rbar, C_per_omega2 * om * om, ext)
        return solve_bvp(fun, bc, x0, y0, fun_jac=fun_jac, bc_jac=bc_jac, tol=tol, bc_tol=tol,
                         max_nodes=max_nodes)

    x_init = np.linspace(0.0, 1.0, nodes)
    path: list[float] = []

    # --- continuation in omega_bar: from the guess, or from the linear beam at a small omega_bar
    if guess is not None and guess.params.get("kappa") == kappa and guess._sol is not None \
            and np.sign(guess.omega_bar) == np.sign(W_target) and guess.omega_bar != 0:
        W0 = guess.omega_bar
        x0 = np.linspace(0.0, 1.0, max(nodes, guess.s.size))
        y0 = guess._sol(x0)
        res = attempt(W0, x0, y0)
    else:
        W0 = math.copysign(min(abs(W_target), START_OMEGA_BAR), W_target) if W_target != 0 else 0.0
        res = attempt(W0, x_init, _linear_guess(x_init, W0, Rbar))
    if not _ok(res):
        return _fail(omega, W0 / W_per_omega, W0, f"the first solve (at omega_bar = {W0:.4g}, from "
                     f"{'the guess' if guess is not None else 'the linear beam'}) did not converge: {res.message}",
                     raise_on_failure, params, res)
    path.append(W0)
    W_done = W0
    log_step = math.log(2.0)
    while W_done != W_target:
        ratio = W_target / W_done
        if ratio <= 0:
            return _fail(omega, W_done / W_per_omega, W_done, "continuation cannot change the sign of omega",
                         raise_on_failure, params, res)
        lr = math.log(ratio)
        W_next = W_target if abs(lr) <= log_step else W_done * math.exp(math.copysign(log_step, lr))
        x0 = res.x if res.x.size >= nodes else np.linspace(0.0, 1.0, nodes)
        trial = attempt(W_next, x0, res.sol(x0))
        if _ok(trial):
            res, W_done = trial, W_next
            path.append(W_done)
            log_step = min(2.0 * log_step, math.log(4.0))
            continue
        log_step *= 0.5
        if log_step < MIN_LOG_STEP:
            return _fail(omega, W_next / W_per_omega, W_next,
                         f"continuation stalled between omega_bar = {W_done:.6g} and {W_next:.6g}: "
                         f"{trial.message}", raise_on_failure, params, trial)

    # --- mesh-refinement check: halve every interval and solve again
    x_fine = _refine(res.x)
    fine = attempt(W_target, x_fine, res.sol(x_fine))
    if not _ok(fine):
        return _fail(omega, omega, W_target, f"re-solve on the halved mesh ({x_fine.size} nodes) did not "
                     f"converge: {fine.message}", raise_on_failure, params, fine)
    a, b = _outputs(res.y[:, -1]), _outputs(fine.y[:, -1])
    scale = np.array([abs(b[0]), abs(b[1]), 1.0, 1.0, 1.0])       # tip in units of L
    scale[0] = max(scale[0], 1e-300)
    scale[1] = max(scale[1], 1e-300)
    err = float(np.max(np.abs(a - b) / scale))
    converged = err <= check_rtol
    msg = (f"{fine.message} {fine.x.size} nodes, {len(path)} continuation step(s); outputs changed by "
           f"{err:.2e} (relative) under mesh halving")
    if not converged:
        msg += f" > check_rtol = {check_rtol:g}"
        if raise_on_failure:
            raise RodBVPError(omega, W_target, "not converged under mesh refinement: " + msg)
    return _build(omega, W_target, fine, params, converged, msg, err, path)


def _build(omega, W, res, params, converged, message, err, path) -> RodSolution:
    L, EI = params["L"], params["EI"]
    y = res.y
    return RodSolution(
        omega=float(omega), omega_bar=float(W),
        Fx=float(y[12, -1] * EI / L ** 2), Tx=float(y[13, -1] * EI / L), tip=y[0:3, -1] * L,
        s=res.x * L, r=y[0:3] * L, t=y[3:6].copy(), m=y[6:9] * EI / L, n=y[9:12] * EI / L ** 2,
        converged=bool(converged), message=message, error_estimate=float(err), nodes=int(res.x.size),
        continuation=list(path), params=params, _sol=res.sol,
        strain=np.einsum("in,in->n", y[9:12], y[3:6]) * (EI / L ** 2) / params["EA"])


def _fail(omega, omega_at, W_at, reason, raise_on_failure, params, res) -> RodSolution:
    if raise_on_failure:
        raise RodBVPError(omega_at, W_at, reason)
    nan = float("nan")
    return RodSolution(omega=float(omega), omega_bar=float(W_at), Fx=nan, Tx=nan, tip=np.full(3, nan),
                       s=res.x * params["L"], r=np.full((3, res.x.size), nan), t=np.full((3, res.x.size), nan),
                       m=np.full((3, res.x.size), nan), n=np.full((3, res.x.size), nan), converged=False,
                       message=f"failed at omega = {omega_at:.6g} rad/s (omega_bar = {W_at:.6g}): {reason}",
                       error_estimate=nan, nodes=int(res.x.size), params=params, _sol=None)


def from_scene(scene, omega: float | None = None, *, inertia: bool | None = None, extensible: bool = True,
               **kwargs) -> RodSolution:
    """The reference for a (clamped-flagellum) scene: its L, R_d, EI, EA, eta_t, eta_p and omega (default the
    scene's motor.omega_rpm). ``inertia``: include the centrifugal load rho A omega^2 (default: when the scene
    lists the ``inertia`` effect, as the DER then has it). ``extensible``: the scene's EA = E pi r0^2, the DER
    flagellum's stretching stiffness (False: EA = inf, inextensible). Other keyword arguments go to
    solve_clamped_rod.

    The coefficients are the scene medium's (``medium.model``: the paper's granular RFT, or Gray-Hancock's for a
    straight rod in a viscous fluid). The rod is naturally straight: a helical scene is refused (ValueError)."""
    fl = scene.flagellum
    if fl.helix_pitch != 0.0:
        raise ValueError(f"flagellum.helix_pitch = {fl.helix_pitch:g} m: the rod BVP is of a naturally straight "
                         "flagellum (helix_pitch = 0)")
    if inertia is None:
        inertia = "inertia" in scene.effects
    rho_A = fl.density * section(fl)[0] if inertia else 0.0
    EA = stretching_stiffness(scene) if extensible else math.inf
    return solve_clamped_rod(fl.length, scene.R_d, bending_stiffness(scene), *rft_coefficients(scene),
                             scene.omega_T if omega is None else float(omega), rho_A=rho_A, EA=EA, **kwargs)


def stretching_stiffness(scene) -> float:
    """EA = E pi r0^2 (N) of the scene's flagellum: the stiffness of the DER's elastic stretching springs
    (physics/network.py build_network, from the same network.section)."""
    return scene.flagellum.youngs_modulus * section(scene.flagellum)[0]


__all__ = ["RodSolution", "RodBVPError", "solve_clamped_rod", "from_scene", "stretching_stiffness", "DEFAULT_TOL"]
