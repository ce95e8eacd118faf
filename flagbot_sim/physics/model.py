"""RobotModel: the rod network, its elastic springs and exactly the effects the scene lists.

The model turns a trial configuration into the residual of the equations of motion at the end of a step,

    r(q) = grad E(q) - sum_effects F(q, v(q), a(q))        (paper Eq. DER3D_EOM; inertia is an effect)

and its Jacobian J = Hess E - sum dF/dq on a sparse pattern fixed at construction. The time integrator decides
how the trial velocity v and acceleration a depend on q (a :class:`StepPlan`); the model knows nothing about
time stepping, and the :class:`~flagbot_sim.physics.stepper.Stepper` knows nothing about which effects exist.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .assembly import shared_pattern
from .effects import EFFECT_TYPES, Driver, Effect, StepContext
from .elastic import ElasticModel
from .frames import EdgeFrames
from .medium import force_scale
from .network import NEWTON_ROUNDOFFS, RodNetwork, build_network, flagellum_edge_count

TWO_PI = 2.0 * np.pi


@dataclass
class State:
    """Everything needed to continue a simulation: time, DOFs, velocities, committed frames, drive angle, and
    the step before (for the predictor and for multistep integrators)."""
    t: float
    q: np.ndarray
    v: np.ndarray
    frames: EdgeFrames
    drive_angle: float = 0.0      # the driver's integrated command (rad)
    h: float = 0.0                # size of the step that led to this state (0: none yet)
    h_prev: float = 0.0           # size of the step before that
    q_prev: np.ndarray | None = None   # DOFs and velocities one step back
    v_prev: np.ndarray | None = None
    q_prev2: np.ndarray | None = None  # DOFs two steps back (the error estimate of a second-order integrator)
    h_next: float = 0.0           # the step size error control proposes next (0: none yet)

    def copy(self) -> "State":
        c = lambda a: None if a is None else a.copy()   # noqa: E731
        return State(self.t, self.q.copy(), self.v.copy(), self.frames.copy(), self.drive_angle, self.h,
                     self.h_prev, c(self.q_prev), c(self.v_prev), c(self.q_prev2), self.h_next)


@dataclass
class StepPlan:
    """One trial step from a committed state, as the integrator sets it up: the trial velocity and acceleration
    are affine in the trial DOFs, v = dv_dq q + v0 and a = da_dq q + a0, and the driver's angle at the end."""
    h: float
    t: float
    dv_dq: float
    v0: np.ndarray
    da_dq: float
    a0: np.ndarray
    drive_angle: float


def build_effects(scene, net: RodNetwork, elastic: ElasticModel) -> list[Effect]:
    """Construct exactly the effects listed in ``scene.effects``, in that order."""
    return [EFFECT_TYPES[name].from_scene(scene, net, elastic) for name in scene.effects]


class RobotModel:
    def __init__(self, scene):
        self.scene = scene
        self.net = build_network(scene)
        self.elastic = ElasticModel(self.net)
        self.effects = build_effects(scene, self.net, self.elastic)
        self.ndof = self.net.ndof
        blocks = [(self.elastic.stretch_dofs, self.elastic.stretch_dofs),
                  (self.elastic.hinge_dofs, self.elastic.hinge_dofs)]
        ranges = []
        for eff in self.effects:
            b = eff.blocks()
            ranges.append((len(blocks), len(blocks) + len(b)))
            blocks.extend(b)
        self.pattern = shared_pattern(self.ndof, blocks)        # one per structure, shared: read it only
        self.elastic.set_slots(self.pattern.slots[0], self.pattern.slots[1])
        for eff, (b0, b1) in zip(self.effects, ranges):
            eff.bind(self.pattern.slots[b0:b1])
        drivers = [e for e in self.effects if isinstance(e, Driver)]
        if len(drivers) > 1:
            raise ValueError(f"a scene can have one driver, got {[d.name for d in drivers]}")
        #: the effect that takes the speed command (motor or clamp), or None
        self.driver: Driver | None = drivers[0] if drivers else None
        self.twist_hinge = self.driver.twist_hinge if self.driver is not None else -1
        self._prescribers = [e for e in self.effects if len(e.prescribed_dofs)]
        fixed = [e.prescribed_dofs for e in self._prescribers]
        #: DOFs prescribed by an effect (the clamp): held at its values, their residual rows are identity rows
        self.prescribed_dofs = np.unique(np.concatenate(fixed)) if fixed else np.zeros(0, np.int64)
        # residual scaling: torques on twist DOFs are divided by a length to compare with forces
        fl = scene.flagellum
        self.length_scale = fl.length / flagellum_edge_count(fl.length, fl.edge_length)
        self.force_scale = force_scale(scene)
        self.scale = np.ones(self.ndof)
        self.scale[3 * self.net.n_nodes:] = 1.0 / self.length_scale
        # A residual cannot be resolved below the round-off of the stiffest spring (RodNetwork.residual_roundoff).
        # Asking for less only burns iterations: the scene refuses a force_tol below this floor unless it is at
        # least the default (which then means "the default or the floor, whichever is coarser")
        #: N: the smallest Newton tolerance this robot can be solved to
        self.force_floor = NEWTON_ROUNDOFFS * self.net.residual_roundoff()[0]
        #: N: the residual norm (:meth:`residual_norm`) a Newton solve must reach, time-stepped or steady
        self.force_tol = max(scene.numerics.force_tol * self.force_scale, self.force_floor)

    def residual_norm(self, r: np.ndarray) -> float:
        """The largest scaled residual entry (N; torques on twist DOFs over the edge length)."""
        return float(np.max(np.abs(r * self.scale))) if len(r) else 0.0

    # ------------------------------------------------------------------ lookup
    def effect(self, name: str) -> Effect | None:
        for e in self.effects:
            if e.name == name:
                return e
        return None

    @property
    def effect_names(self) -> list[str]:
        return [e.name for e in self.effects]

    def spin_drag(self) -> tuple[float, float]:
        """(on the head, on the flagella): the effects' resisting torques about the axis per spin rate (N m s) of
        the straight robot turning rigidly (:meth:`Effect.spin_drag`)."""
        head = flagella = 0.0
        for e in self.effects:
            h, f = e.spin_drag(self.scene)
            head += h
            flagella += f
        return head, flagella

    # ------------------------------------------------------------------ state
    def initial_state(self) -> State:
        q = self.net.initial_q()
        return State(0.0, q, np.zeros_like(q), self.elastic.frames0.copy(), 0.0)

    def prescribe(self, q: np.ndarray, state: State, angle: float) -> None:
        """Set the prescribed DOFs of q to their values at drive angle ``angle`` (a step from ``state``)."""
        for e in self._prescribers:
            q[e.prescribed_dofs] = e.prescribed_values(state, angle)

    # ------------------------------------------------------------------ evaluation
    def context(self, q: np.ndarray, state: State, plan: StepPlan) -> StepContext:
        N = self.net.n_nodes
        v = plan.dv_dq * q + plan.v0
        return StepContext(q=q, x=q[: 3 * N].reshape(N, 3), v=v, a=plan.da_dq * q + plan.a0, dv_dq=plan.dv_dq,
                           da_dq=plan.da_dq, t=plan.t, h=plan.h, drive_angle=plan.drive_angle,
                           frames=self.elastic.trial_frames(q, state.frames))

    # ------------------------------------------------------------------ long runs
    def rebase_angles(self, states) -> float:
        """Take whole turns out of the angles that grow without bound as the robot spins, in place, in every
        State of ``states`` (the current one and the one before it: the same turns in each, so the step's
        velocities and the observer's increments do not see them); returns the turns (rad) taken out of the
        drive angle, which the caller adds back to the motor angle it reports.

        Each edge's twist angle theta_e loses 2 pi round(theta_e / 2 pi): its material frame is the same (cos
        and sin of the angle). Each hinge's reference twist gets back what those turns took out of its twist
        strain (sign_b theta_b - sign_a theta_a + rt), and the motor hinge's what the drive angle loses, so every
        twist strain less its natural twist is unchanged. Over hours of spinning these angles reach ~1e5 rad,
        whose round-off (~1e-11 rad) the stiff head and plate turn into residuals no Newton tolerance can reach
        (design 1, n = 3 after ~4 simulated hours at 60-250 rpm: steps cut, then a failed step at a command
        reversal). Not for prescribed DOFs (the clamp's angle is its own)."""
        states = [st for st in states if st is not None]
        if not states or len(self.prescribed_dofs):
            return 0.0
        n = 3 * self.net.n_nodes
        c = np.round(states[0].q[n:] / TWO_PI) * TWO_PI
        he, sg = self.net.hinge_edges, self.elastic.sign
        back = sg[:, 1] * c[he[:, 1]] - sg[:, 0] * c[he[:, 0]]
        turns = round(states[0].drive_angle / TWO_PI) * TWO_PI if self.twist_hinge >= 0 else 0.0
        if self.twist_hinge >= 0:
            back[self.twist_hinge] -= turns
        qs = {id(a): a for st in states for a in (st.q, st.q_prev, st.q_prev2) if a is not None}
        for a in qs.values():
            a[n:] -= c
        for rt in {id(st.frames.ref_twist): st.frames.ref_twist for st in states}.values():
            rt += back
        for st in states:
            st.drive_angle -= turns
        return float(turns)

    # ------------------------------------------------------------------ outputs
    def motor_torque(self, q: np.ndarray, frames: EdgeFrames, drive_angle: float) -> float:
        """Torque the motor applies to the shaft (N m; positive drives a positive omega_T): the motor hinge's
        twisting moment at configuration ``q`` (committed ``frames``), the motor turned by ``drive_angle``. At
        steady state it equals the head's Stokes torque C2 8 pi mu R_h^3 omega_h."""
        el = self.elastic
        h = self.net.motor_hinge
        if h < 0:
            return 0.0
        # the shaft's reaction to the motor hinge's twisting moment, as the springs compute it
        return float(-el.hinge_moments(q, el.trial_frames(q, frames), h, drive_angle)[h, 2])

    def medium_force(self, x: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Total force (N) and torque about the origin (N m) of the medium on the flagella at node positions ``x``
        (N, 3) and DOF velocities ``v``: RFT's, plus the spin drag's couple where the scene lists it; zero
        without either."""
        F, T = np.zeros(3), np.zeros(3)
        rft = self.effect("rft")
        if rft is not None:
            f = rft.node_forces(x, v)
            F, T = f.sum(axis=0), np.cross(x[rft.k], f).sum(axis=0)
        spin = self.effect("spin_drag")
        if spin is not None:
            T = T + spin.axial_torque(x, v)
        return F, T

    def residual(self, ctx: StepContext) -> np.ndarray:
        """The residual at the context's trial configuration; all NaN where a formula divides by an exact zero
        there (e.g. two edges folded exactly onto each other): the solvers reject non-finite trials."""
        r = np.zeros(self.ndof)
        try:
            for eff in self.effects:
                eff.add_force(ctx, r)
            self.elastic.accumulate(ctx.q, ctx.frames, r, None, self.twist_hinge, ctx.drive_angle)
        except ZeroDivisionError:
            r.fill(np.nan)
        return r

    def jacobian(self, ctx: StepContext, springs: bool = True) -> np.ndarray:
        """CSC data of the Jacobian (on ``self.pattern``) at the context's trial configuration; ``springs=False``:
        the effects' part alone (the springs depend on neither velocity nor acceleration)."""
        J = np.zeros(self.pattern.nnz)
        for eff in self.effects:
            eff.add_jacobian(ctx, J)
        if springs:
            self.elastic.accumulate(ctx.q, ctx.frames, np.zeros(self.ndof), J, self.twist_hinge, ctx.drive_angle)
        return J

    def residual_and_jacobian(self, ctx: StepContext, effects_jacobian: np.ndarray | None = None
                              ) -> tuple[np.ndarray, np.ndarray]:
        """The residual and the Jacobian's CSC data at the context. ``effects_jacobian``: the effects' part at this
        context, already evaluated (:meth:`jacobian` with ``springs=False``): the springs' part is added to a copy
        of it instead of evaluating the effects again (the same numbers: the effects add first either way)."""
        r = np.zeros(self.ndof)
        J = np.zeros(self.pattern.nnz) if effects_jacobian is None else effects_jacobian.copy()
        for eff in self.effects:
            eff.add_force(ctx, r)
            if effects_jacobian is None:
                eff.add_jacobian(ctx, J)
        self.elastic.accumulate(ctx.q, ctx.frames, r, J, self.twist_hinge, ctx.drive_angle)
        return r, J
