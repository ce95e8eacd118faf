"""Time integration: integrators (implicit Euler, the paper's; BDF2, second order), Newton's method on the
sparse Jacobian with a line search, fixed steps with sub-stepping on failure, and error-controlled steps.

An integrator turns a committed state and a step size h into a :class:`~.model.StepPlan`: the trial velocity
and acceleration as affine functions of the trial DOFs. Implicit Euler (paper Eq. DER3D_EOM):

    v = (q - q_n) / h,    a = (v - v_n) / h.

:meth:`Stepper.step` always advances the state by exactly the requested dt. If Newton does not converge (or
produces a non-finite value) the attempt is discarded, the sub-step is halved and retried; after a success the
sub-step grows back by doubling. :meth:`Stepper.step_adaptive` takes one step whose local error estimate (each
integrator's Milne estimate) meets ``time.rtol`` / ``time.atol``, choosing its size. Below ``numerics.min_dt``
either fails loudly with :class:`StepFailed` and the caller keeps its last good state: a step never returns NaN
or Inf.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .frames import EdgeFrames, cross3
from .jit import kernel
from .linsolve import SingularJacobian, make_solver
from .model import RobotModel, State, StepPlan
from .newton import (CHORD_CONTRACTION, CHORD_DEEPEN, CHORD_MAX_MORE, LINEAR_HOLD, REUSE_DV_CHANGE, StepNewton,
                     error_sums, residual_norms, robot_pose, supported)
from .tiers import tiered

#: the kernel group of the predictor and the stepper's sums (their interpreted twins while it is deferred)
TS = "time_stepping"


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
    rejections: int = 0            # error control: attempts rejected for their error estimate
    jacobians: int = 0             # Jacobian evaluations + factorisations
    chord_rejections: int = 0      # corrections with a kept factorisation that contracted too slowly
    error: float = 0.0             # error control: the accepted step's error norm (<= 1)
    #: the step's estimated relative error of the velocity the medium sees (its last sub-step's), from the
    #: integrator's own local error estimate: every error-controlled step (which has the estimate anyway) and
    #: every VELOCITY_ERROR_EVERY-th fixed step; NaN on the others and before the integrator has the history it
    #: needs (see Stepper.velocity_error). Simulation.velocity_error and the error estimates of every result
    #: (physics/error_estimate.py) read it: a stepper must keep filling it
    velocity_error: float = math.nan


class ImplicitEuler:
    """First order, L-stable: the paper's integrator (and what reproduces its numerics).

    v = (q - q_n) / h,  a = (v - v_n) / h."""
    name = "implicit_euler"
    order = 1

    def plan(self, state: State, h: float, drive_angle: float) -> StepPlan:
        ih = 1.0 / h
        v0 = -ih * state.q
        return StepPlan(h=h, t=state.t + h, dv_dq=ih, v0=v0, da_dq=ih * ih, a0=ih * (v0 - state.v),
                        drive_angle=drive_angle)

    def error(self, state: State, h: float, q_new: np.ndarray) -> np.ndarray | None:
        """Local error estimate of q_new (Milne's device against a linear extrapolation); None without history.

        The extrapolation misses the solution by y''/2 h (h + h1) and implicit Euler by y''/2 h^2 on the other
        side, so err = (q_new - q_pred) h / (2 h + h1)."""
        if state.q_prev is None or state.h <= 0.0:
            return None
        h1 = state.h
        q_pred = state.q + (h / h1) * (state.q - state.q_prev)
        return (q_new - q_pred) * (h / (2.0 * h + h1))


class BDF2:
    """Second order, L-stable, variable step (the two-step backward differentiation formula).

    Why this one: the robot is a stiff elastic-viscous system (rigid parts 1e3 times stiffer than the flagella,
    overdamped by the medium), so the integrator must damp the stiff modes completely (L-stability: implicit
    midpoint and the trapezoidal rule are only A-stable and make them ring, sign-flipping every step); it must be
    second order where implicit Euler is first, because the velocity of a rotating part is what RFT and the head
    terms see and implicit Euler turns its direction by omega h / 2 per step; and it must cost one Newton solve
    per step with the Jacobian structure unchanged (TR-BDF2 and SDIRK methods need two or more). Its velocity is
    a three-point backward difference,

        v_(n+1) = [c0 q_(n+1) - (1 + w) q_n + w^2 / (1 + w) q_(n-1)] / h,   c0 = (1 + 2 w) / (1 + w), w = h / h_n,

    and the acceleration the same formula applied to v. Zero-stable for step ratios w < 1 + sqrt(2); the error
    control grows steps by at most 2. The first step (no history) is an implicit Euler step."""
    name = "bdf2"
    order = 2

    def plan(self, state: State, h: float, drive_angle: float) -> StepPlan:
        if state.q_prev is None or state.h <= 0.0:
            return ImplicitEuler.plan(self, state, h, drive_angle)
        w = h / state.h
        c0 = (1.0 + 2.0 * w) / (1.0 + w)
        c1 = -(1.0 + w)
        c2 = w * w / (1.0 + w)
        dv = c0 / h
        v0 = (c1 * state.q + c2 * state.q_prev) / h
        g = (c1 * state.v + c2 * state.v_prev) / h
        return StepPlan(h=h, t=state.t + h, dv_dq=dv, v0=v0, da_dq=dv * dv, a0=dv * v0 + g, drive_angle=drive_angle)

    def error(self, state: State, h: float, q_new: np.ndarray) -> np.ndarray | None:
        """Local error estimate of q_new (Milne's device against the quadratic through the last three states).

        With y3 the third derivative, the extrapolation misses the solution by y3/6 h (h + h1)(h + h1 + h2) and
        the BDF2 step by y3/6 h^2 (h + h1) / c0 on the other side, so
        err = (q_new - q_pred) (h / c0) / (h / c0 + h + h1 + h2): 2/11 of the difference at constant steps."""
        if state.q_prev2 is None or state.h <= 0.0 or state.h_prev <= 0.0:
            return None
        h1, h2 = state.h, state.h_prev
        T0, T1, x = -(h1 + h2), -h1, h                 # times of q_prev2, q_prev (q at 0), relative to t_n
        L0 = (x - T1) * x / ((T0 - T1) * T0)
        L1 = (x - T0) * x / ((T1 - T0) * T1)
        L2 = (x - T0) * (x - T1) / (T0 * T1)
        q_pred = L0 * state.q_prev2 + L1 * state.q_prev + L2 * state.q
        c0 = (1.0 + 2.0 * h / h1) / (1.0 + h / h1)
        f = (h / c0) / (h / c0 + h + h1 + h2)
        return (q_new - q_pred) * f


INTEGRATORS = {cls.name: cls for cls in (ImplicitEuler, BDF2)}

#: fixed steps estimate their velocity error (~25 us, 3-4% of a design-1 step) on every this-many-th step only: the
#: result's estimate is an average over the steady window (200 steps by default), which 1 in 4 samples as well
VELOCITY_ERROR_EVERY = 4
#: Stepper.velocity_error: the Milne estimate's share of the velocity error in steady rotation, inverted. BDF2's
#: estimate is 2/11 (omega h)^2 of the displacement where its velocity is (omega h)^2 / 3 too fast: 11/6 = 11/9
#: times c0 = 3/2 (at other step ratios c0 = (1 + 2w) / (1 + w)); implicit Euler's is (omega h) / 3 where its
#: velocity turns by omega h / 2: 3/2
VELOCITY_GAIN = {2: 11.0 / 9.0, 1: 1.5}



# ----------------------------------------------------------------------------------------------- predictor
@kernel
def _predict_cylindrical(x, xp, xpp, h, h1, h2, c1, c0, second, i0, i1, i2, out, out1):
    """Extrapolation of node positions in cylindrical coordinates about the robot axis (see :func:`continuations`),
    from the positions x, xp, xpp at t_n, t_n - h1, t_n - h1 - h2, by h: to second order into ``out`` (weights c1,
    c0 of the last two slopes) and, if ``second``, to first order (the last slope) into ``out1`` too. ``out`` and
    ``out1`` hold the Cartesian predictions on entry (kept for nodes on the axis)."""
    if i0 != i2:
        a0, a1, a2 = x[i2, 0] - x[i0, 0], x[i2, 1] - x[i0, 1], x[i2, 2] - x[i0, 2]
        na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        a0, a1, a2 = a0 / na, a1 / na, a2 / na
    else:
        a0, a1, a2 = 1.0, 0.0, 0.0
    cn0, cn1, cn2 = out[i1, 0], out[i1, 1], out[i1, 2]          # the centre, predicted on the axis
    cf0, cf1, cf2 = out1[i1, 0], out1[i1, 1], out1[i1, 2]       # (to first order)
    # by time (now, one step back, two steps back), each a row of three: the centre C, the node P, its distance
    # along the axis S, its radial vector R and that vector's length rn
    C = np.empty(9)
    for i in range(3):
        c_prev = xp[i1, i]
        C[i] = x[i1, i]
        C[3 + i] = c_prev
        C[6 + i] = xpp[i1, i] if second else c_prev
    P = np.empty(9)
    S = np.empty(3)
    R = np.empty(9)
    rn = np.empty(3)
    for k in range(x.shape[0]):
        for i in range(3):
            p_prev = xp[k, i]
            P[i] = x[k, i]
            P[3 + i] = p_prev
            P[6 + i] = xpp[k, i] if second else p_prev
        ok = True
        for j in range(3):
            o = 3 * j
            p0, p1, p2 = P[o] - C[o], P[o + 1] - C[o + 1], P[o + 2] - C[o + 2]
            s = p0 * a0 + p1 * a1 + p2 * a2
            S[j] = s
            r0, r1, r2 = p0 - s * a0, p1 - s * a1, p2 - s * a2
            R[o], R[o + 1], R[o + 2] = r0, r1, r2
            rj = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
            rn[j] = rj
            if rj <= 1e-9:
                ok = False
        if not ok:
            continue
        u0, u1, u2 = R[0], R[1], R[2]
        v0, v1, v2 = R[3], R[4], R[5]
        # turn from configuration j+1 to j about the axis
        x0, x1, x2 = cross3(v0, v1, v2, u0, u1, u2)
        dphi = math.atan2(x0 * a0 + x1 * a1 + x2 * a2, v0 * u0 + v1 * u1 + v2 * u2) / h1
        ds = (S[0] - S[1]) / h1
        dr = (rn[0] - rn[1]) / h1
        if second:
            w0, w1, w2 = R[6], R[7], R[8]
            y0, y1, y2 = cross3(w0, w1, w2, v0, v1, v2)
            dphi0 = math.atan2(y0 * a0 + y1 * a1 + y2 * a2, w0 * v0 + w1 * v1 + w2 * v2) / h2
            ds0 = (S[1] - S[2]) / h2
            dr0 = (rn[1] - rn[2]) / h2
        else:
            dphi0 = ds0 = dr0 = 0.0
        s_new = S[0] + c1 * ds + c0 * ds0
        r_new = rn[0] + c1 * dr + c0 * dr0
        phi = c1 * dphi + c0 * dphi0
        r0 = rn[0]
        u0, u1, u2 = u0 / r0, u1 / r0, u2 / r0
        w0, w1, w2 = cross3(a0, a1, a2, u0, u1, u2)
        cp, sp = math.cos(phi), math.sin(phi)
        out[k, 0] = cn0 + s_new * a0 + r_new * (cp * u0 + sp * w0)
        out[k, 1] = cn1 + s_new * a1 + r_new * (cp * u1 + sp * w1)
        out[k, 2] = cn2 + s_new * a2 + r_new * (cp * u2 + sp * w2)
        if second:
            s_new = S[0] + h * ds
            r_new = r0 + h * dr
            phi = h * dphi
            cp, sp = math.cos(phi), math.sin(phi)
            out1[k, 0] = cf0 + s_new * a0 + r_new * (cp * u0 + sp * w0)
            out1[k, 1] = cf1 + s_new * a1 + r_new * (cp * u1 + sp * w1)
            out1[k, 2] = cf2 + s_new * a2 + r_new * (cp * u2 + sp * w2)


def continuations(state: State, h: float, axis_nodes: tuple[int, int, int], n_nodes: int
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    """Newton's starting points: the last three states' motion continued to second order (Newton divided
    differences of the DOFs themselves, whatever the integrator's velocity formula), and to first order (the last
    step's motion; None without a third state, where the first is that already), in cylindrical coordinates
    (axial, radial, azimuth) about the robot axis (through the nodes ``axis_nodes``: front, centre, back) for
    every node off that axis. Every part of the robot turns about the axis, and for a steady rotation this is
    exact, where a Cartesian extrapolation cuts the chord and stretches the stiff plate by ~R (omega h)^3
    (design 2: several newtons of residual and two extra Newton iterations per step). Which of the two a step
    starts from: Stepper.predictions."""
    h1, h2 = state.h, state.h_prev
    if h1 <= 0.0 or state.q_prev is None:
        return state.q + h * state.v, None
    second = h2 > 0.0 and state.q_prev2 is not None
    d1 = (state.q - state.q_prev) / h1                          # slope over the last step
    d0 = (state.q_prev - state.q_prev2) / h2 if second else d1  # and over the one before
    # extrapolation weights for f(t_n + h) from the slopes d1 and d0
    c1 = h + (h * (h + h1) / (h1 + h2) if second else 0.0)
    c0 = -h * (h + h1) / (h1 + h2) if second else 0.0
    q = state.q + c1 * d1 + c0 * d0                             # twist angles, nodes on the axis
    q1 = state.q + h * d1 if second else q
    N = n_nodes
    x = state.q[: 3 * N].reshape(N, 3)
    x1 = state.q_prev[: 3 * N].reshape(N, 3)
    x2 = state.q_prev2[: 3 * N].reshape(N, 3) if second else x1
    i0, i1, i2 = axis_nodes
    tiered(TS, _predict_cylindrical)(x, x1, x2, h, h1, h2 if second else 0.0, c1, c0, second, i0, i1, i2,
                                     q[: 3 * N].reshape(N, 3), q1[: 3 * N].reshape(N, 3))
    return q, (q1 if second else None)


def axis_nodes(net) -> tuple[int, int, int]:
    """(front, centre, back) points of the robot axis for the predictor: the head, or the plate centre alone."""
    return tuple(int(i) for i in net.head_nodes) if len(net.head_nodes) else (int(net.joint_node),) * 3


class Stepper:
    """Advances a State: fixed steps (``step``) or error-controlled ones (``step_adaptive``).

    The scene's ``time`` section chooses the integrator (``time.integrator``), the error control (``time.rtol``
    > 0, with the absolute floor ``time.atol`` in metres) and the largest angle the drive may turn in one step
    (``time.max_turn``): a step never turns the motor further, so no speed aliases (at 5000 rpm and dt = 1e-2 s
    the motor would turn 5.2 rad per step and the run would show the 1000-rpm state mirrored)."""

    def __init__(self, model: RobotModel, integrator: str | None = None, compiled: bool = False):
        self.model = model
        tm = model.scene.time
        self.integrator = INTEGRATORS[integrator or tm.integrator]()
        self.rtol = float(tm.rtol)
        self.atol = float(tm.atol)
        self.max_turn = float(tm.max_turn)
        self.dt_max = float(tm.dt)
        num = model.scene.numerics
        net = model.net
        self.tol = model.force_tol
        self._norm = model.residual_norm
        self.max_iterations = num.max_iterations
        self.min_dt = num.min_dt
        self.pattern = model.pattern
        self.fixed = model.prescribed_dofs
        self._fix_slots, self._fix_diag = self.pattern.fix_rows_mask(self.fixed)
        self._scale = model.scale
        self.solver = make_solver(model, num.linear_solver)
        self._axis_nodes = axis_nodes(net)
        # error norm: per node (3 DOFs) and per twist angle, prescribed DOFs excluded
        N = net.n_nodes
        free = np.ones(net.ndof, bool)
        free[self.fixed] = False
        self._free_nodes = free[: 3 * N].reshape(N, 3).all(axis=1)
        # the free twist angles the norm counts: not the flagella's (see error_norm)
        self._norm_twist = free[3 * N:].copy()
        for edges in net.flagella_edges:
            self._norm_twist[np.asarray(edges, int)] = False
        # the norm's weight of every DOF: 1 on the free nodes' positions, the edge length squared on the counted
        # twist angles (in metres), 0 elsewhere; and how many nodes and angles it counts
        ell = model.length_scale
        self._norm_weights = np.concatenate([np.repeat(self._free_nodes.astype(float), 3),
                                             np.where(self._norm_twist, ell * ell, 0.0)])
        self._norm_count = int(self._free_nodes.sum() + self._norm_twist.sum())
        self._fixed_steps = 0             # fixed steps taken (the velocity error's sampling)
        # what the solver carries from step to step, shared with the compiled solve: [a factorisation kept (1) or
        # not (0), the integrator coefficient it was made for, Newton's start continued to first order (1) or to
        # second (0): see predictions], and the robot's pose the factorisation was made at (see _rotated_solve)
        self._kept = np.zeros(3)
        self._kept_pose = np.eye(3)
        self._rim = int(net.edges[net.plate_edges[0], 1])
        #: the compiled Newton solve of a step (newton.py) if ``compiled`` (its kernel loaded: the Simulation asks
        #: physics.warmup, which compiles it in the background on a first run), or None, also where it does not
        #: apply (scipy's sparse LU, an effect without a compiled term): then the Python loop of _attempt runs,
        #: with the same numbers to the last bit
        self._newton = None
        if compiled:
            self.use_compiled()

    def use_compiled(self) -> None:
        """Step with the compiled Newton solve from now on, where it applies (its kernels loaded: at
        construction, or mid-run once the background compile has delivered them, warmup.swap_in). The two share
        the kept factorisation and the pose it was made at, so the switch changes no number."""
        if self._newton is None and supported(self.model, self.solver):
            self._newton = StepNewton(self.model, self.solver, self._axis_nodes, self._rim, self._kept,
                                      self._kept_pose.reshape(9), _predict_cylindrical)

    @property
    def adaptive(self) -> bool:
        return self.rtol > 0.0

    def _turn_limit(self, omega: float) -> float:
        """Largest step (s) for which the drive, commanded at ``omega`` (rad/s), turns at most max_turn."""
        w = abs(omega) if self.model.driver is not None else 0.0
        return self.max_turn / w if w > 0.0 else math.inf

    # ------------------------------------------------------------------ fixed steps
    def step(self, state: State, dt: float, omega: float = 0.0, resume: StepStats | None = None,
             python_first: bool = False) -> tuple[State, StepStats]:
        """Advance by exactly dt with the drive commanded at ``omega`` (rad/s; ignored without a driver): in
        equal sub-steps if the drive would turn more than max_turn, halved (then grown back) where Newton
        fails. ``resume``: the stats of a first attempt at the whole dt that failed (in the compiled steps,
        :meth:`advance`), continued from there; ``python_first``: the first attempt in the Python loop (the
        compiled solve raised ZeroDivisionError in it)."""
        stats = StepStats(dt_min=dt) if resume is None else resume
        n_turn = max(1, math.ceil(dt / self._turn_limit(omega) - 1e-9))
        h_cap = dt / n_turn
        remaining = dt
        h = h_cap
        cur = state
        failed = resume is not None
        while remaining > 1e-12 * dt:
            h = min(h, remaining)
            if remaining - h < 1e-9 * dt:   # do not leave a sliver behind
                h = remaining
            new = None if failed else self._attempt(cur, h, stats, omega, python_first)
            failed = python_first = False
            if new is None:
                h *= 0.5
                stats.reductions += 1
                if h < self.min_dt:
                    raise self._failed(cur, 2 * h, stats)
                continue
            if remaining - h <= 1e-12 * dt and self._sample_velocity_error():
                stats.velocity_error = self.velocity_error(cur, h, new.q)
            cur = new
            remaining -= h
            stats.substeps += 1
            stats.substep_dts.append(h)
            stats.dt_min = min(stats.dt_min, h)
            h = min(2.0 * h, h_cap)
        return cur, stats

    # ------------------------------------------------------------------ many steps in one compiled call
    def can_advance(self, dt: float, omega: float) -> bool:
        """Whether :meth:`advance` runs the steps compiled: the compiled solve is loaded and applies, no effect
        prescribes DOFs (the clamp's values are Python), and a fixed step needs no sub-steps for max_turn."""
        if self._newton is None or len(self.fixed):
            return False
        return self.adaptive or math.ceil(dt / self._turn_limit(omega) - 1e-9) <= 1

    def advance(self, b: "StepBuffers", dt: float, omega: float, max_steps: int, t_end: float = math.inf,
                t_stop: float = math.inf, due_at: float = math.inf) -> int:
        """Up to ``max_steps`` steps (:meth:`step` by ``dt`` / :meth:`step_adaptive` towards ``t_end``) from the
        state in ``b``, the drive at ``omega``, and the observer's per-step work, in one compiled call
        (newton._advance: the same numbers as step by step, to the last bit). It stops before a step from a time
        >= ``t_stop`` and after the first step that ends at or after ``due_at``. Returns newton.ADVANCED, or
        FIXED_FAILED (a fixed step's Newton failed at dt: continue with ``step(resume=...)``) or BELOW_MIN_DT
        (raise :meth:`_failed`); b.icfg[8] steps were taken. Raises ZeroDivisionError (a folded configuration)
        with b holding the steps taken before it."""
        p = self.integrator.order
        b.cfg[:] = (dt if not self.adaptive else self.dt_max, self.tol, self.rtol, self.atol, self.min_dt,
                    self._turn_limit(omega), t_end, t_stop, due_at, omega, VELOCITY_GAIN[p])
        b.icfg[:8] = (p, self.max_iterations, int(self.adaptive), 0, self._fixed_steps,
                      int(self.model.driver is not None), self._norm_count, VELOCITY_ERROR_EVERY)
        try:
            return self._newton.advance(b, max_steps)
        finally:
            self._fixed_steps = int(b.icfg[4])

    def last_stats(self, b: "StepBuffers", failed: bool = False) -> StepStats:
        """The StepStats of the last step :meth:`advance` took or tried; ``failed`` (FIXED_FAILED): those of the
        failed first attempt of a fixed step, to resume the step with (``step(resume=...)``)."""
        L = b.last
        if failed:
            return StepStats(dt_min=float(L[9]), residual=float(L[1]), line_search_cuts=int(L[2]),
                             jacobians=int(L[3]), chord_rejections=int(L[4]))
        return StepStats(newton_iterations=int(L[0]), residual=float(L[1]), dt_min=float(L[8]), substeps=1,
                         reductions=int(L[5]), line_search_cuts=int(L[2]), substep_dts=[float(L[9])],
                         rejections=int(L[6]), jacobians=int(L[3]), chord_rejections=int(L[4]), error=float(L[7]),
                         velocity_error=float(L[10]))

    # ------------------------------------------------------------------ error-controlled steps
    def step_adaptive(self, state: State, t_end: float = math.inf, omega: float = 0.0,
                      python_first: bool = False) -> tuple[State, StepStats]:
        """One accepted step whose local error estimate is within (rtol, atol), the drive commanded at ``omega``
        (rad/s); its size is chosen by the controller (never beyond t_end, time.dt or the turn limit). The next
        size is proposed in the new state's ``h_next``."""
        p = self.integrator.order
        h = min(state.h_next or self.dt_max, self.dt_max, self._turn_limit(omega))
        h_end = t_end - state.t
        if h >= h_end:
            h = h_end
        elif h > 0.5 * h_end:
            h = 0.5 * h_end       # two similar steps rather than a long one and a sliver
        stats = StepStats(dt_min=h)
        while True:
            new = self._attempt(state, h, stats, omega, python_first)
            python_first = False
            if new is None:
                factor = 0.25
                stats.reductions += 1
            else:
                err = self.integrator.error(state, h, new.q)
                # the calibration of the estimate against the steady outputs (see error_norm): K, and BDF2's
                # velocity coefficient c0, which turns a position error into the velocity's
                gain = 3.0 if p == 2 else 2.0
                if p == 2 and state.q_prev is not None and state.h > 0.0:
                    w = h / state.h
                    gain *= (1.0 + 2.0 * w) / (1.0 + w)
                norm = self.error_norm(err, new.q, state.q, gain) if err is not None else 0.0
                if norm <= 1.0:
                    stats.velocity_error = self.velocity_error(state, h, new.q, err)
                    grow = 2.0 if norm == 0.0 else min(2.0, max(1.0, 0.9 * norm ** (-1.0 / (p + 1))))
                    new.h_next = min(grow * h, self.dt_max)
                    stats.error = norm
                    stats.substeps = 1
                    stats.substep_dts.append(h)
                    stats.dt_min = h
                    return new, stats
                factor = max(0.2, 0.9 * norm ** (-1.0 / (p + 1)))
                stats.rejections += 1
            h *= factor
            if h < self.min_dt:
                raise self._failed(state, h / factor, stats)

    def _sample_velocity_error(self) -> bool:
        """Whether this fixed step estimates its velocity error (every VELOCITY_ERROR_EVERY-th)."""
        self._fixed_steps += 1
        return self._fixed_steps % VELOCITY_ERROR_EVERY == 0

    def velocity_error(self, state: State, h: float, q_new: np.ndarray, err: np.ndarray | None = None) -> float:
        """The relative error of the velocity a step of size h from ``state`` to ``q_new`` gives the medium, as
        the integrator's local error estimate (``err``, computed here if not given) sees it: |err| / |q_new - q|
        over what :meth:`error_norm` counts, times VELOCITY_GAIN (BDF2: times c0 too), so that in steady
        rotation it is the velocity's relative error itself ((omega h)^2 / 3 for BDF2, omega h / 2 for implicit
        Euler). Cheap (no solve: the extrapolation of the last states). NaN without the history it needs."""
        if err is None:
            err = self.integrator.error(state, h, q_new)
        if err is None:
            return math.nan
        e2, d2, _ = self._error_sums(err, q_new, state.q)
        if d2 <= 0.0:
            return 0.0
        gain = VELOCITY_GAIN[self.integrator.order]
        if self.integrator.order == 2 and state.h > 0.0:
            w = h / state.h
            gain *= (1.0 + 2.0 * w) / (1.0 + w)
        return gain * math.sqrt(e2 / d2)

    def _error_sums(self, err: np.ndarray, q_new: np.ndarray, q_old: np.ndarray) -> tuple[float, float, int]:
        """(|err|^2, |q_new - q_old|^2, count) over the free nodes and the rigid parts' twist angles (in metres)."""
        e2, d2 = tiered(TS, error_sums)(self._norm_weights, err, q_new, q_old)   # the compiled steps' own sums
        return e2, d2, self._norm_count

    def error_norm(self, err: np.ndarray, q_new: np.ndarray, q_old: np.ndarray, gain: float = 1.0) -> float:
        """The step's relative velocity error, times the calibration ``gain``, over rtol (accepted if <= 1).

        gain |err| / (atol sqrt(n) + rtol |q_new - q_old|), Euclidean norms over the free node positions and
        the free twist angles of the rigid parts (head body, shaft, plate), the angles in metres (times the edge
        length: the displacement of the surface they stand for). |err| over the step's displacement is the
        relative error of the step's velocity, the quantity RFT, the head drag and torque see; as a ratio of
        norms it weighs each part by its motion, so slow parts (the head's axis, a barely moving base) need no
        absolute floor, and fast ones (the flagella) set the step. The flagella's twist angles are left out:
        RFT acts on the centreline, so their twist has no drag, only its tiny inertia, and rings at ~1 ms
        periods (slowly decaying) once a command change has made the steps small enough to resolve it;
        counted, it holds the steps there (a short clamped flagellum switched from 30 to 60 rpm: still 2e-4 s
        steps 1.5 s later, where the new steady step is 5e-3 s; without it 3e-3 s after 0.05 s). Their effect
        on the centreline, through the twisting moment, is in the positions' error. The head's spin (omega_h)
        is its body's twist angle, damped by the head torque: counted.

        Calibration (``gain`` = K, times BDF2's velocity coefficient c0 = (1 + 2w) / (1 + w), 3/2 at constant
        steps): in steady rotation at omega every part turns rigidly, and so does the discrete solution, so
        its error is in the shape, and the Milne estimate sees only the predictor's share of it: for BDF2
        2/11 (omega h)^2 of the displacement where the velocity is (omega h)^2 / 3 too fast (9/11 of it, times
        c0); for implicit Euler (omega h) / 3 where the velocity lags by the angle omega h / 2 (2/3 of it). The
        steady outputs respond to a velocity that is (1 + e) too fast by at most 2 e (the thrust of the
        clamped flagellum is quadratic in the speed in the linear regime), to implicit Euler's lag by at most
        ~1 e (the tip). Hence K >= 2 x 11/9 = 2.44 (BDF2) and >= 1.5 (implicit Euler); K = 3 and 2 leave a
        margin for the controller, which holds a steady step where the norm lies between 0.73 and 1.
        Measured (docs/accuracy.md: both designs' clamped flagellum at 0.5-2000 rpm, the free robot at 100 rpm;
        rtol 1e-2 to 1e-4): the largest error of the steady outputs is at most 0.71 rtol (BDF2) and 0.64 rtol
        (implicit Euler); the uncalibrated RMS of node-wise ratios gave 2.8 rtol."""
        e2, d2, n = self._error_sums(err, q_new, q_old)
        if n == 0:
            return 0.0
        return gain * math.sqrt(e2) / (self.atol * math.sqrt(n) + self.rtol * math.sqrt(d2))

    def _failed(self, state: State, h: float, stats: StepStats) -> StepFailed:
        return StepFailed(f"Newton did not converge at t = {state.t:.6g} s even with dt = {h:.3g} s "
                          f"(numerics.min_dt = {self.min_dt:g} s, last residual {stats.residual:.3g} N, "
                          f"tolerance {self.tol:.3g} N)")

    # ------------------------------------------------------------------
    def _trial(self, q: np.ndarray, state: State, plan: StepPlan):
        """(context, residual with the prescribed rows zeroed) of the trial configuration ``q``."""
        ctx = self.model.context(q, state, plan)
        r = self.model.residual(ctx)
        r[self.fixed] = 0.0
        return ctx, r

    def reset(self) -> None:
        """Forget the Jacobian kept from earlier steps (a run restarted from its beginning repeats itself)."""
        self._kept[0] = 0.0
        self._kept[2] = 0.0
        self._fixed_steps = 0

    def _pose(self, q: np.ndarray) -> np.ndarray:
        """Orthonormal frame (3x3, columns: axis, the first plate rim's direction from it, their cross product)
        that turns with the robot: what relates the Jacobian of two configurations of a turning robot."""
        i0, _, i2 = self._axis_nodes
        P = np.empty(9)
        tiered(TS, robot_pose)(q, i0, i2, self._rim, P)
        return P.reshape(3, 3)

    def _rotated_solve(self, r: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Solve with the kept factorisation of an earlier configuration, turned to the current one.

        The robot's Jacobian is equivariant under rotations (springs, RFT, the isotropic head drag and the masses
        all are), so the Jacobian of the configuration turned by R is R J R^T on the node blocks (twist angles
        are frame-relative and do not turn): J_now^-1 r = R J_then^-1 (R^T r). Without the turn, a factorisation
        a step old is off by the stiff parts' stiffness times omega h and contracts nothing."""
        N = self.model.net.n_nodes
        P, F = self._pose(q), self._kept_pose
        # R = P F^T, and the rows' turns below, as sums of products in the order the compiled solve forms them
        # (newton._rotated_solve), so that both give the same numbers to the last bit
        R = P[:, None, 0] * F[None, :, 0] + P[:, None, 1] * F[None, :, 1] + P[:, None, 2] * F[None, :, 2]
        b = r.copy()
        bx = b[: 3 * N].reshape(N, 3)
        bx[:] = bx[:, 0, None] * R[0] + bx[:, 1, None] * R[1] + bx[:, 2, None] * R[2]   # R^T on every node's row
        x = self.solver.solve(b)
        xx = x[: 3 * N].reshape(N, 3)
        xx[:] = xx[:, 0, None] * R[:, 0] + xx[:, 1, None] * R[:, 1] + xx[:, 2, None] * R[:, 2]
        return x

    def _reusable(self, plan: StepPlan) -> bool:
        """Whether the factorised Jacobian kept from an earlier step can serve this one: it was made for nearly
        the same integrator coefficient (the 1/h in dv/dq, which dominates how the Jacobian changes with h)."""
        return self._kept[0] > 0.0 and abs(plan.dv_dq / self._kept[1] - 1.0) < REUSE_DV_CHANGE

    def _factor(self, ctx, plan: StepPlan, stats: StepStats) -> bool:
        J = self.model.jacobian(ctx)
        J[self._fix_slots] = 0.0
        J[self._fix_diag] = 1.0
        stats.jacobians += 1
        self._kept[0] = 0.0
        try:
            self.solver.factor(J)
        except SingularJacobian:
            return False
        self._kept[:2] = 1.0, plan.dv_dq
        self._kept_pose[:] = self._pose(ctx.q)
        return True

    def _attempt(self, state: State, h: float, stats: StepStats, omega: float,
                 python_loop: bool = False) -> State | None:
        """One Newton solve of a step of size h from ``state``, the drive commanded at ``omega``; None if it
        does not converge.

        The Jacobian is evaluated and factorised lazily: most steps converge on the predictor and need none,
        and a factorisation made for an earlier step (the Jacobian of a steadily turning robot changes by
        ~omega h per step) serves as long as each correction with it shrinks the residual by CHORD_CONTRACTION;
        when one does not, that correction is discarded and a fresh Jacobian is factorised where the iterate is.
        Corrections with a fresh Jacobian are Newton steps with the line search."""
        model = self.model
        angle = state.drive_angle + (omega * h if model.driver is not None else 0.0)
        plan = self.integrator.plan(state, h, angle)
        q, both = self.predictions(state, h)
        model.prescribe(q, state, angle)
        if self._newton is not None and not python_loop:
            st = self._newton.stats
            st[:] = 0.0
            try:
                ok, its, q_new, v_new, (t, _, d1, d2, rt) = self._newton.solve(
                    q.copy(), state.frames, plan, self.tol, self.max_iterations)
            except ZeroDivisionError:
                pass            # a folded iterate: the loop below rejects it as a non-finite trial instead
            else:
                stats.residual = float(st[0])
                stats.line_search_cuts += int(st[1])
                stats.jacobians += int(st[2])
                stats.chord_rejections += int(st[3])
                if not ok:
                    return None
                self._choose_order(both, q_new)
                stats.newton_iterations += its
                return State(plan.t, q_new, v_new, EdgeFrames(t, d1, d2, rt), plan.drive_angle, plan.h, state.h,
                             state.q, state.v, state.q_prev)
        ctx, r = self._trial(q, state, plan)
        fresh = False                    # the factorisation in hand was made at an iterate of this attempt
        chord = self._reusable(plan)     # ... or, usable as it is, at an earlier step
        merit_start = None
        watchdog = 3
        for it in range(self.max_iterations + 1):
            rn = self._norm(r)
            stats.residual = rn
            if not math.isfinite(rn):
                return None
            if rn <= self.tol:
                if chord and rn > CHORD_DEEPEN * self.tol:
                    # one more correction with the kept factorisation (a residual and a solve, no Jacobian): the
                    # next step's predictor extrapolates this iterate, and one just inside the tolerance makes
                    # the next correction start too close to it to contract (then a fresh Jacobian is paid)
                    q_try = q - self._rotated_solve(r, q)
                    ctx_try, r_try = self._trial(q_try, state, plan)
                    if self._norm(r_try) < rn:
                        ctx = ctx_try
                    it += 1
                self._choose_order(both, ctx.q)
                return self._accept(state, plan, ctx, stats, it)
            if it == self.max_iterations:
                return None
            merit0 = tiered(TS, residual_norms)(r, self._scale)[1]
            if chord:
                dq = -self._rotated_solve(r, q)
                q_try = q + dq
                ctx_try, r_try = self._trial(q_try, state, plan)
                m_max, m = tiered(TS, residual_norms)(r_try, self._scale)
                # a correction that reaches the tolerance is taken whatever its contraction (a residual already
                # near the tolerance cannot shrink 4x above round-off: BDF2's predictor often starts there)
                if np.all(np.isfinite(dq)) and math.isfinite(m) and (m <= CHORD_CONTRACTION * merit0 or
                                                                     m_max <= self.tol):
                    q, r, ctx = q_try, r_try, ctx_try
                    # keep going with it only while it would reach the tolerance within a couple of corrections
                    # (each costs a residual and a solve; a fresh Jacobian about three of them)
                    rho = m / merit0
                    chord = m_max <= self.tol or (rho > 0.0 and
                                                  math.log(self.tol / m_max) / math.log(rho) <= CHORD_MAX_MORE)
                    continue
                chord = False            # too slow a contraction: a fresh Jacobian here, and Newton steps
                stats.chord_rejections += 1
                fresh = False            # (a factorisation from this attempt is refactorised here anyway)
            if not fresh:
                if not self._factor(ctx, plan, stats):
                    return None
                fresh = True
            dq = -self._rotated_solve(r, q)
            if not np.all(np.isfinite(dq)):
                return None
            if merit_start is None:
                merit_start = merit0
            alpha = 1.0
            while True:
                q_try = q + alpha * dq
                ctx_try, r_try = self._trial(q_try, state, plan)
                m = tiered(TS, residual_norms)(r_try, self._scale)[1]
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
            # the next correction may use this factorisation again (a chord step), while it contracts well
            chord = alpha == 1.0
            fresh = True
        return None

    def predictions(self, state: State, h: float) -> tuple[np.ndarray, tuple | None]:
        """(Newton's start for a step of size h from ``state``, (second-order, first-order continuation) where
        both were made, else None): :func:`continuations`.

        Both are made wherever the history has three states, and the start is the one the last steps favoured
        (``_kept[2]``, :meth:`_choose_order`). Second order is right while the motion changes; in a steady
        rotation (a swimmer at its speed: most of a long run) the motion about the axis is first order exactly,
        and the second differences of the converged states are only Newton's tolerance, which the second-order
        continuation amplifies (weights 3, -3, 1 against 2, -1): design 1, n = 3 at 150 rpm then needed 0.8
        Newton corrections per step with it and 0.37 with the first-order one, whose zero-correction steps also
        continue exactly on their line."""
        q2, q1 = continuations(state, h, self._axis_nodes, self.model.net.n_nodes)
        if q1 is None:
            return q2, None
        return (q1 if self._kept[2] > 0.0 else q2), (q2, q1)

    def _choose_order(self, both: tuple | None, q_new: np.ndarray) -> None:
        """After a converged solve from :meth:`predictions`' start: continue to first order from the next step on
        if that continuation lay nearer the converged state ``q_new`` (distances weighted as the error norm's,
        squared); back to second order only once the second-order continuation lies newton.LINEAR_HOLD (in
        squares) nearer. The hold keeps the first-order start through the steady rotation's noise; a change of
        motion large enough to matter shows as a second-order continuation that lands far nearer (a gentler one
        keeps the first-order start, which then still needs few corrections). The compiled steps
        (newton._choose_order) decide the same, to the last bit."""
        if both is None:
            return
        q2, q1 = both
        e_lin, e_quad, _ = self._error_sums(q_new - q1, q_new, q2)
        if self._kept[2] > 0.0:
            if e_quad < LINEAR_HOLD * e_lin:
                self._kept[2] = 0.0
        elif e_lin < e_quad:
            self._kept[2] = 1.0

    def _accept(self, state: State, plan: StepPlan, ctx, stats: StepStats, iterations: int) -> State:
        stats.newton_iterations += iterations
        return State(plan.t, ctx.q, ctx.v, EdgeFrames.of(ctx.frames), plan.drive_angle, plan.h, state.h, state.q,
                     state.v, state.q_prev)


class StepBuffers:
    """The arrays :meth:`Stepper.advance` runs its steps in (newton.py, _advance, has their layout): the state and
    the one before it, the observer's accumulators, one row per step taken. ``load`` fills them from Python
    objects, ``states`` reads them back."""

    def __init__(self, stepper: Stepper, observer, capacity: int = 4096):
        from .newton import LAST, OUT_COLS, Q_ROWS
        model = stepper.model
        net = model.net
        n, ne, nh = int(net.ndof), len(net.edges), len(net.hinge_edges)
        self.capacity = capacity
        self.Q = np.zeros((Q_ROWS, n))
        self.T, self.D1, self.D2 = np.zeros((2, ne, 3)), np.zeros((2, ne, 3)), np.zeros((2, ne, 3))
        self.RT = np.zeros((2, nh))
        self.sc = np.zeros(10)
        self.flags = np.zeros(4, np.int64)
        self.cfg = np.zeros(11)
        self.icfg = np.zeros(9, np.int64)
        self.pax = np.array(stepper._axis_nodes, np.int64)
        self.w_norm = np.ascontiguousarray(stepper._norm_weights, dtype=float)
        ob = observer
        head = ob.has_head
        self.obs_i = np.array([int(head), int(net.head_edge) if head else 0, int(net.shaft_edge) if head else 0,
                               int(net.head_nodes[1]) if head else int(net.joint_node),
                               int(net.head_nodes[0]) if head else 0, int(net.head_nodes[2]) if head else 0],
                              np.int64)
        self.ob = np.zeros(11)
        self.out = np.zeros((capacity, OUT_COLS))
        self.last = np.zeros(LAST)

    def load(self, state: State, prev: State | None, observer) -> None:
        """The state, the one before it and the observer's accumulators into the buffers."""
        Q, sc, fl = self.Q, self.sc, self.flags
        Q[0], Q[1] = state.q, state.v
        fl[:] = 0
        if state.q_prev is not None:
            Q[2], Q[3] = state.q_prev, state.v_prev
            fl[0] = 1
        if state.q_prev2 is not None:
            Q[4] = state.q_prev2
            fl[1] = 1
        f = state.frames
        self.T[0], self.D1[0], self.D2[0], self.RT[0] = f.t, f.d1, f.d2, f.ref_twist
        sc[:5] = state.t, state.drive_angle, state.h, state.h_prev, state.h_next
        if prev is not None:
            fl[3] = 1
            if prev.v_prev is not None:
                Q[5] = prev.v_prev
            if prev.q_prev2 is not None:
                Q[6] = prev.q_prev2
                fl[2] = 1
            g = prev.frames
            self.T[1], self.D1[1], self.D2[1], self.RT[1] = g.t, g.d1, g.d2, g.ref_twist
            sc[5:] = prev.t, prev.drive_angle, prev.h, prev.h_prev, prev.h_next
        o = self.ob
        o[:5] = observer.phi_h, observer.phi_t, observer.rate_h, observer.rate_t, observer.speed
        o[5:8] = observer.axis_now
        o[8:11] = observer._pos

    def states(self) -> tuple[State, State]:
        """(the state, the one before it) after steps were taken: new objects, sharing arrays as a step's
        State does (the new state's q_prev is the one before's q)."""
        Q, sc, fl = self.Q, self.sc, self.flags
        c = lambda i, have: Q[i].copy() if have else None     # noqa: E731
        prev = State(float(sc[5]), Q[2].copy(), Q[3].copy(),
                     EdgeFrames(self.T[1].copy(), self.D1[1].copy(), self.D2[1].copy(), self.RT[1].copy()),
                     float(sc[6]), float(sc[7]), float(sc[8]), c(4, fl[1]), c(5, fl[1]), c(6, fl[2]), float(sc[9]))
        new = State(float(sc[0]), Q[0].copy(), Q[1].copy(),
                    EdgeFrames(self.T[0].copy(), self.D1[0].copy(), self.D2[0].copy(), self.RT[0].copy()),
                    float(sc[1]), float(sc[2]), float(sc[3]), prev.q, prev.v, prev.q_prev, float(sc[4]))
        return new, prev
