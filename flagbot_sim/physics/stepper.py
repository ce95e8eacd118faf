"""Time integration: an integrator (implicit Euler, the paper's), Newton's method on the sparse Jacobian with a
line search, and adaptive sub-stepping on failure.

An integrator turns a committed state and a step size h into a :class:`~.model.StepPlan`: the trial velocity
and acceleration as affine functions of the trial DOFs. Implicit Euler (paper Eq. DER3D_EOM):

    v = (q - q_n) / h,    a = (v - v_n) / h.

:meth:`Stepper.step` always advances the state by exactly the requested dt. If Newton does not converge (or
produces a non-finite value) the attempt is discarded, the sub-step is halved and retried; after a success the
sub-step grows back by doubling. Below ``numerics.min_dt`` the step fails loudly with :class:`StepFailed` and the
caller keeps its last good state: a step never returns NaN or Inf.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from .frames import EdgeFrames, cross3
from .linsolve import SingularJacobian, make_solver
from .model import RobotModel, State, StepPlan


class StepFailed(RuntimeError):
    """Newton did not converge even at the smallest allowed sub-step."""


@dataclass
class StepStats:
    newton_iterations: int = 0     # total over the sub-steps of this step
    residual: float = 0.0          # final scaled residual norm (N), worst over sub-steps
    dt_min: float = 0.0            # smallest sub-step used (s)
    substeps: int = 0
    reductions: int = 0            # how many times the sub-step was halved
    line_search_cuts: int = 0
    substep_dts: list = field(default_factory=list)   # the accepted sub-steps, in order (s)


class ImplicitEuler:
    """First order, L-stable: the paper's integrator (and what reproduces its numerics)."""
    name = "implicit_euler"
    order = 1

    def plan(self, state: State, h: float, drive_angle: float) -> StepPlan:
        ih = 1.0 / h
        v0 = -ih * state.q
        return StepPlan(h=h, t=state.t + h, dv_dq=ih, v0=v0, da_dq=ih * ih, a0=ih * (v0 - state.v),
                        drive_angle=drive_angle)


INTEGRATORS = {ImplicitEuler.name: ImplicitEuler}


# ----------------------------------------------------------------------------------------------- predictor
@njit(cache=True)
def _predict_cylindrical(x, v, v_prev, h1, h2, c1, c0, second, i0, i1, i2, out):
    """Second-order extrapolation of node positions in cylindrical coordinates about the robot axis (see
    Stepper.predict). ``out`` holds the Cartesian prediction on entry (kept for nodes on the axis)."""
    if i0 != i2:
        a0, a1, a2 = x[i2, 0] - x[i0, 0], x[i2, 1] - x[i0, 1], x[i2, 2] - x[i0, 2]
        na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        a0, a1, a2 = a0 / na, a1 / na, a2 / na
    else:
        a0, a1, a2 = 1.0, 0.0, 0.0
    cn0, cn1, cn2 = out[i1, 0], out[i1, 1], out[i1, 2]          # the centre, predicted on the axis
    C = np.empty((3, 3))                                        # the centre at the three times
    for i in range(3):
        C[0, i] = x[i1, i]
        C[1, i] = C[0, i] - h1 * v[i1, i]
        C[2, i] = C[1, i] - h2 * v_prev[i1, i] if second else C[1, i]
    P = np.empty((3, 3))
    S = np.empty(3)
    R = np.empty((3, 3))
    rn = np.empty(3)
    for k in range(x.shape[0]):
        for i in range(3):
            P[0, i] = x[k, i]
            P[1, i] = P[0, i] - h1 * v[k, i]
            P[2, i] = P[1, i] - h2 * v_prev[k, i] if second else P[1, i]
        ok = True
        for j in range(3):
            p0, p1, p2 = P[j, 0] - C[j, 0], P[j, 1] - C[j, 1], P[j, 2] - C[j, 2]
            s = p0 * a0 + p1 * a1 + p2 * a2
            S[j] = s
            R[j, 0], R[j, 1], R[j, 2] = p0 - s * a0, p1 - s * a1, p2 - s * a2
            rn[j] = math.sqrt(R[j, 0] ** 2 + R[j, 1] ** 2 + R[j, 2] ** 2)
            if rn[j] <= 1e-9:
                ok = False
        if not ok:
            continue
        # turn from configuration j+1 to j about the axis
        x0, x1, x2 = cross3(R[1, 0], R[1, 1], R[1, 2], R[0, 0], R[0, 1], R[0, 2])
        dphi = math.atan2(x0 * a0 + x1 * a1 + x2 * a2, R[1, 0] * R[0, 0] + R[1, 1] * R[0, 1] + R[1, 2] * R[0, 2]) / h1
        ds = (S[0] - S[1]) / h1
        dr = (rn[0] - rn[1]) / h1
        if second:
            y0, y1, y2 = cross3(R[2, 0], R[2, 1], R[2, 2], R[1, 0], R[1, 1], R[1, 2])
            dphi0 = math.atan2(y0 * a0 + y1 * a1 + y2 * a2,
                               R[2, 0] * R[1, 0] + R[2, 1] * R[1, 1] + R[2, 2] * R[1, 2]) / h2
            ds0 = (S[1] - S[2]) / h2
            dr0 = (rn[1] - rn[2]) / h2
        else:
            dphi0 = ds0 = dr0 = 0.0
        s_new = S[0] + c1 * ds + c0 * ds0
        r_new = rn[0] + c1 * dr + c0 * dr0
        phi = c1 * dphi + c0 * dphi0
        u0, u1, u2 = R[0, 0] / rn[0], R[0, 1] / rn[0], R[0, 2] / rn[0]
        w0, w1, w2 = cross3(a0, a1, a2, u0, u1, u2)
        cp, sp = math.cos(phi), math.sin(phi)
        out[k, 0] = cn0 + s_new * a0 + r_new * (cp * u0 + sp * w0)
        out[k, 1] = cn1 + s_new * a1 + r_new * (cp * u1 + sp * w1)
        out[k, 2] = cn2 + s_new * a2 + r_new * (cp * u2 + sp * w2)


def predict(state: State, h: float, axis_nodes: tuple[int, int, int], n_nodes: int) -> np.ndarray:
    """Newton's starting point: the last steps' motion continued to second order (Newton divided differences
    over the last three configurations), in cylindrical coordinates (axial, radial, azimuth) about the robot
    axis (through the nodes ``axis_nodes``: front, centre, back) for every node off that axis. Every part of the
    robot turns about the axis, and for a steady rotation this is exact, where a Cartesian extrapolation cuts
    the chord and stretches the stiff plate by ~R (omega h)^3 (design 2: several newtons of residual and two
    extra Newton iterations per step)."""
    h1, h2 = state.h, state.h_prev
    if h1 <= 0.0:
        return state.q + h * state.v
    second = h2 > 0.0 and state.v_prev is not None
    # extrapolation weights for f(t_n + h) from the slopes d1 (last step) and d0 (the one before)
    c1 = h + (h * (h + h1) / (h1 + h2) if second else 0.0)      # coefficient of d1
    c0 = -h * (h + h1) / (h1 + h2) if second else 0.0             # coefficient of d0
    q = state.q + c1 * state.v + (c0 * state.v_prev if second else 0.0)   # twist angles, nodes on the axis
    N = n_nodes
    x = state.q[: 3 * N].reshape(N, 3)
    v = state.v[: 3 * N].reshape(N, 3)
    vp = state.v_prev[: 3 * N].reshape(N, 3) if second else v
    i0, i1, i2 = axis_nodes
    _predict_cylindrical(x, v, vp, h1, h2 if second else 0.0, c1, c0, second, i0, i1, i2, q[: 3 * N].reshape(N, 3))
    return q


def axis_nodes(net) -> tuple[int, int, int]:
    """(front, centre, back) points of the robot axis for the predictor: the head, or the plate centre alone."""
    return tuple(int(i) for i in net.head_nodes) if len(net.head_nodes) else (int(net.joint_node),) * 3


class Stepper:
    def __init__(self, model: RobotModel, integrator: str = "implicit_euler"):
        self.model = model
        self.integrator = INTEGRATORS[integrator]()
        num = model.scene.numerics
        # A residual cannot be resolved below the round-off of the stiffest spring: a relative error of machine
        # epsilon in an edge length times its stretching stiffness. Asking for less only burns iterations.
        net = model.net
        roundoff = 64.0 * np.finfo(float).eps * float(np.max(net.EA * np.abs(net.nodes).max()
                                                            / net.edge_rest_length))
        self.tol = max(num.force_tol * model.force_scale, roundoff)
        self.max_iterations = num.max_iterations
        self.min_dt = num.min_dt
        self.pattern = model.pattern
        self.fixed = model.prescribed_dofs
        self._fix_slots, self._fix_diag = self.pattern.fix_rows_mask(self.fixed)
        self._scale = model.scale
        self.solver = make_solver(model, num.linear_solver)
        self._axis_nodes = axis_nodes(net)

    # ------------------------------------------------------------------
    def step(self, state: State, dt: float) -> tuple[State, StepStats]:
        stats = StepStats(dt_min=dt)
        remaining = dt
        h = dt
        cur = state
        while remaining > 1e-12 * dt:
            h = min(h, remaining)
            if remaining - h < 1e-9 * dt:   # do not leave a sliver behind
                h = remaining
            new = self._attempt(cur, h, stats)
            if new is None:
                h *= 0.5
                stats.reductions += 1
                if h < self.min_dt:
                    raise StepFailed(
                        f"Newton did not converge at t = {cur.t:.6g} s even with dt = {2 * h:.3g} s "
                        f"(numerics.min_dt = {self.min_dt:g} s, last residual {stats.residual:.3g} N, "
                        f"tolerance {self.tol:.3g} N)")
                continue
            cur = new
            remaining -= h
            stats.substeps += 1
            stats.substep_dts.append(h)
            stats.dt_min = min(stats.dt_min, h)
            h = min(2.0 * h, dt)
        return cur, stats

    # ------------------------------------------------------------------
    def _norm(self, r: np.ndarray) -> float:
        return float(np.max(np.abs(r * self._scale))) if len(r) else 0.0

    def _attempt(self, state: State, h: float, stats: StepStats) -> State | None:
        model = self.model
        d = model.driver
        angle = state.drive_angle + (d.omega * h if d is not None else 0.0)
        plan = self.integrator.plan(state, h, angle)
        fixed = self.fixed
        q = self.predict(state, h)
        model.prescribe(q, state, angle)
        ctx = model.context(q, state, plan)
        r = model.residual(ctx)
        r[fixed] = 0.0
        merit_start = None
        watchdog = 3
        for it in range(self.max_iterations + 1):
            rn = self._norm(r)
            stats.residual = rn
            if not math.isfinite(rn):
                return None
            if rn <= self.tol:
                return self._accept(state, plan, ctx, stats, it)
            if it == self.max_iterations:
                return None
            # the residual alone decided so far: the Jacobian is needed only now (many steps converge on the
            # predictor and never pay for it)
            J = model.jacobian(ctx)
            J[self._fix_slots] = 0.0
            J[self._fix_diag] = 1.0
            try:
                self.solver.factor(J)
                dq = -self.solver.solve(r)
            except SingularJacobian:
                return None
            if not np.all(np.isfinite(dq)):
                return None
            merit0 = float(np.linalg.norm(r * self._scale))
            if merit_start is None:
                merit_start = merit0
            alpha = 1.0
            while True:
                q_try = q + alpha * dq
                ctx_try = model.context(q_try, state, plan)
                r_try = model.residual(ctx_try)
                r_try[fixed] = 0.0
                m = float(np.linalg.norm(r_try * self._scale))
                if math.isfinite(m) and m < (1.0 - 1e-4 * alpha) * merit0:
                    break
                # Watchdog: a full step along a rigid rotation stretches the stiff parts by R*angle^2/2, so the
                # residual can rise for one iteration although the next one removes it. Accept such a step (a
                # few times per attempt) while the residual stays below where this solve started.
                if alpha == 1.0 and watchdog > 0 and math.isfinite(m) and m < merit_start:
                    watchdog -= 1
                    break
                alpha *= 0.5
                stats.line_search_cuts += 1
                if alpha < 1.0 / 64.0:
                    return None
            q, r, ctx = q_try, r_try, ctx_try
        return None

    def predict(self, state: State, h: float) -> np.ndarray:
        return predict(state, h, self._axis_nodes, self.model.net.n_nodes)

    def _accept(self, state: State, plan: StepPlan, ctx, stats: StepStats, iterations: int) -> State:
        stats.newton_iterations += iterations
        return State(plan.t, ctx.q, ctx.v, EdgeFrames.of(ctx.frames), plan.drive_angle, plan.h, state.h, state.q,
                     state.v)
