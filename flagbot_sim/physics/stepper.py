"""Fully implicit Euler with Newton's method on the sparse Jacobian, line search and adaptive sub-stepping.

:meth:`Stepper.step` always advances the state by exactly the requested dt. If Newton does not converge (or
produces a non-finite value) the attempt is discarded, the sub-step is halved and retried; after a success the
sub-step grows back by doubling. Below ``numerics.min_dt`` the step fails loudly with :class:`StepFailed` and the
caller keeps its last good state: a step never returns NaN or Inf.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import kernels
from .frames import EdgeFrames
from .linsolve import SingularJacobian, make_solver
from .model import RobotModel, State


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


class Stepper:
    def __init__(self, model: RobotModel):
        self.model = model
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
        fixed = [e.prescribed_dofs for e in model.effects if hasattr(e, "prescribed_dofs")]
        self.fixed = np.unique(np.concatenate(fixed)) if fixed else np.zeros(0, np.int64)
        self._fix_slots, self._fix_diag = self.pattern.fix_rows_mask(self.fixed)
        self._scale = model.scale
        self._drivers = model.drivers
        self._prescribers = [e for e in model.effects if hasattr(e, "prescribed_dofs")]
        self.solver = make_solver(model, num.linear_solver)
        # (front, centre, back) points of the robot axis for the predictor: the head, or the plate centre alone
        self._axis_nodes = (tuple(net.head_nodes) if len(net.head_nodes) else (net.joint_node,) * 3)

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
                    self.model.restore(state)
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
    def _scaled(self, r: np.ndarray) -> np.ndarray:
        return r * self._scale

    def _attempt(self, state: State, h: float, stats: StepStats) -> State | None:
        model = self.model
        for d in self._drivers:
            d.begin_step(state, h)
        fixed = self.fixed
        q = self._start(self.predict(state, h))
        r, data, ctx = model.residual_and_jacobian(q, state, h)
        r[fixed] = 0.0
        merit_start = None
        watchdog = 3
        for it in range(self.max_iterations + 1):
            rs = self._scaled(r)
            rn = float(np.max(np.abs(rs))) if len(rs) else 0.0
            stats.residual = rn
            if not np.isfinite(rn):
                return None
            if rn <= self.tol:
                return self._accept(state, q, ctx, h, stats, it)
            if it == self.max_iterations:
                return None
            if data is None:                 # the trial point was not converged: now its Jacobian is needed
                r, data, ctx = model.residual_and_jacobian(q, state, h, ctx)
                r[fixed] = 0.0
            data[self._fix_slots] = 0.0
            data[self._fix_diag] = 1.0
            try:
                self.solver.factor(data)
                dq = -self.solver.solve(r)
            except SingularJacobian:
                return None
            if not np.all(np.isfinite(dq)):
                return None
            merit0 = float(np.linalg.norm(rs))
            if merit_start is None:
                merit_start = merit0
            alpha = 1.0
            while True:
                # the residual alone decides: most steps converge here and never need this point's Jacobian
                q_try = q + alpha * dq
                ctx_try = model.context(q_try, state, h)
                r_try = model.residual(q_try, state, h, ctx_try)
                r_try[fixed] = 0.0
                m = float(np.linalg.norm(self._scaled(r_try)))
                if np.isfinite(m) and m < (1.0 - 1e-4 * alpha) * merit0:
                    break
                # Watchdog: a full step along a rigid rotation stretches the stiff parts by R*angle^2/2, so the
                # residual can rise for one iteration although the next one removes it. Accept such a step (a
                # few times per attempt) while the residual stays below where this solve started.
                if alpha == 1.0 and watchdog > 0 and np.isfinite(m) and m < merit_start:
                    watchdog -= 1
                    break
                alpha *= 0.5
                stats.line_search_cuts += 1
                if alpha < 1.0 / 64.0:
                    return None
            q, r, ctx, data = q_try, r_try, ctx_try, None
        return None

    def predict(self, state: State, h: float) -> np.ndarray:
        """Newton's starting point: the last steps' motion continued to second order (Newton divided differences
        over the last three configurations), in cylindrical coordinates (axial, radial, azimuth) about the robot
        axis for every node off that axis. Every part of the robot turns about the axis, and for a steady
        rotation this is exact, where a Cartesian extrapolation cuts the chord and stretches the stiff plate by
        ~R (omega h)^3 (design 2: several newtons of residual and two extra Newton iterations per step)."""
        h1, h2 = state.h, state.h_prev
        if h1 <= 0.0:
            return state.q + h * state.v
        second = h2 > 0.0 and state.v_prev is not None
        # extrapolation weights for f(t_n + h) from the slopes d1 (last step) and d0 (the one before)
        c1 = h + (h * (h + h1) / (h1 + h2) if second else 0.0)      # coefficient of d1
        c0 = -h * (h + h1) / (h1 + h2) if second else 0.0             # coefficient of d0
        q = state.q + c1 * state.v + (c0 * state.v_prev if second else 0.0)   # twist angles, nodes on the axis
        N = self.model.net.n_nodes
        x = state.q[: 3 * N].reshape(N, 3)
        v = state.v[: 3 * N].reshape(N, 3)
        vp = state.v_prev[: 3 * N].reshape(N, 3) if second else v
        i0, i1, i2 = self._axis_nodes
        kernels.predict_cylindrical(x, v, vp, h1, h2 if second else 0.0, c1, c0, second, i0, i1, i2,
                                    q[: 3 * N].reshape(N, 3))
        return q

    def _start(self, q: np.ndarray) -> np.ndarray:
        """The predictor with the prescribed DOFs (clamp) set to their values at the end of the step."""
        for e in self._prescribers:
            idx, val = e.prescribed()
            q[idx] = val
        return q

    def _accept(self, state: State, q: np.ndarray, ctx, h: float, stats: StepStats, iterations: int) -> State:
        stats.newton_iterations += iterations
        v = (q - state.q) / h
        fr = EdgeFrames.committed(ctx.frames.t, ctx.frames.d1, ctx.frames.d2, ctx.frames.ref_twist)
        new = State(state.t + h, q, v, fr, dict(state.extras), h, state.h, state.v)
        for d in self._drivers:
            d.commit(new)
        return new
