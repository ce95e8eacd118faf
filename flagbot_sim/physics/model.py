"""RobotModel: the rod network, its elastic springs and exactly the effects the scene lists.

The model turns a trial configuration into the residual of the implicit-Euler equations of motion,

    r(q) = grad E(q) - sum_effects F(q, q_old, v_old, dt)        (paper Eq. DER3D_EOM; inertia is an effect)

and its Jacobian J = Hess E - sum dF/dq on a sparse pattern fixed at construction. It knows nothing about time
stepping; the :class:`~flagbot_sim.physics.stepper.Stepper` knows nothing about which effects exist.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from ..scene import Scene
from .assembly import SparsePattern
from .effects import (Clamp, Effect, Gravity, HeadDrag, HeadTorque, Inertia, Motor, RFTDrag, StepContext)
from .elastic import ElasticModel
from .frames import EdgeFrames
from .network import RodNetwork, build_network


@dataclass
class State:
    """Everything needed to continue a simulation: DOFs, velocities, committed frames, driver angles."""
    t: float
    q: np.ndarray
    v: np.ndarray
    frames: EdgeFrames
    extras: dict = field(default_factory=dict)
    # for the Newton predictor only: the sizes of the last two steps and the velocity of the one before
    h: float = 0.0
    h_prev: float = 0.0
    v_prev: np.ndarray | None = None

    def copy(self) -> "State":
        return State(self.t, self.q.copy(), self.v.copy(), self.frames.copy(), copy.deepcopy(self.extras), self.h,
                     self.h_prev, None if self.v_prev is None else self.v_prev.copy())


def build_effects(scene: Scene, net: RodNetwork, elastic: ElasticModel) -> list[Effect]:
    """Construct exactly the effects listed in ``scene.effects``, in that order."""
    makers = {
        "inertia": lambda: Inertia(net),
        "gravity": lambda: Gravity(net, scene.gravity.g),
        "rft": lambda: RFTDrag(net, scene.eta_t, scene.eta_p),
        "head_drag": lambda: HeadDrag(net, scene.head_drag_coefficient),
        "head_torque": lambda: HeadTorque(net, scene.head_torque_coefficient),
        "motor": lambda: Motor(net, elastic, scene.omega_T),
        "clamp": lambda: Clamp(net, elastic, scene.omega_T),
    }
    return [makers[name]() for name in scene.effects]


class RobotModel:
    def __init__(self, scene: Scene):
        self.scene = scene
        self.net = build_network(scene)
        self.elastic = ElasticModel(self.net)
        self.effects = build_effects(scene, self.net, self.elastic)
        self.ndof = self.net.ndof
        blocks = [(self.elastic.stretch_dofs, self.elastic.stretch_dofs),
                  (self.elastic.hinge_dofs, self.elastic.hinge_dofs)]
        self._effect_block_range = []
        for eff in self.effects:
            b = eff.blocks()
            self._effect_block_range.append((len(blocks), len(blocks) + len(b)))
            blocks.extend(b)
        self.pattern = SparsePattern(self.ndof, blocks)
        self.elastic.set_slots(self.pattern.slots[0], self.pattern.slots[1])
        self.drivers = [e for e in self.effects if type(e).begin_step is not Effect.begin_step]
        # residual scaling: torques on twist DOFs are divided by a length to compare with forces
        fl = scene.flagellum
        self.length_scale = fl.length / max(1, round(fl.length / fl.edge_length))
        self.force_scale = scene.EI / fl.length ** 2
        self.scale = np.ones(self.ndof)
        self.scale[3 * self.net.n_nodes:] = 1.0 / self.length_scale

    # ------------------------------------------------------------------ lookup
    def effect(self, name: str) -> Effect | None:
        for e in self.effects:
            if e.name == name:
                return e
        return None

    @property
    def effect_names(self) -> list[str]:
        return [e.name for e in self.effects]

    @property
    def driver(self) -> Effect | None:
        """The effect that takes the speed command (motor, or clamp), if any."""
        return self.effect("motor") or self.effect("clamp")

    # ------------------------------------------------------------------ state
    def initial_state(self) -> State:
        q = self.net.initial_q()
        extras = {}
        for e in self.effects:
            extras.update(e.initial_state())
        st = State(0.0, q, np.zeros_like(q), self.elastic.frames0.copy(), extras)
        self.restore(st)
        return st

    def restore(self, state: State) -> None:
        """Bring effect-held quantities (motor natural twist) in line with a committed state."""
        for e in self.effects:
            if hasattr(e, "restore"):
                e.restore(state)

    # ------------------------------------------------------------------ evaluation
    def context(self, q: np.ndarray, state: State, dt: float) -> StepContext:
        N = self.net.n_nodes
        return StepContext(q=q, q_old=state.q, v_old=state.v, dt=dt, t_new=state.t + dt,
                           x=q[: 3 * N].reshape(N, 3), x_old=state.q[: 3 * N].reshape(N, 3),
                           frames=self.elastic.trial_frames(q, state.frames))

    def residual(self, q: np.ndarray, state: State, dt: float, ctx: StepContext | None = None) -> np.ndarray:
        ctx = ctx or self.context(q, state, dt)
        idx, val = [], []
        for eff in self.effects:
            f = eff.force(ctx)
            if f is not None:
                idx.append(np.ravel(f[0]))
                val.append(-np.ravel(f[1]))
        r = (np.bincount(np.concatenate(idx), weights=np.concatenate(val), minlength=self.ndof) if idx
             else np.zeros(self.ndof))
        self.elastic.accumulate(q, ctx.frames, r, None)
        return r

    def residual_and_jacobian(self, q: np.ndarray, state: State, dt: float, ctx: StepContext | None = None):
        """Residual vector and CSC data of the Jacobian (on ``self.pattern``) at the trial q.

        ``ctx`` is the context of this q (from :meth:`context`) if the caller already has it."""
        if ctx is None:
            ctx = self.context(q, state, dt)
        idx, val = [], []
        jac_values: list = [None, None]          # elastic blocks are added by the elastic model below
        for eff, (b0, b1) in zip(self.effects, self._effect_block_range):
            fi, fv, jv = eff.force_and_jacobian(ctx)
            if fi is not None:
                idx.append(np.ravel(fi))
                val.append(-np.ravel(fv))
            for j in jv:
                jac_values.append(-np.asarray(j))
            jac_values.extend([None] * (b1 - b0 - len(jv)))
        r = (np.bincount(np.concatenate(idx), weights=np.concatenate(val), minlength=self.ndof) if idx
             else np.zeros(self.ndof))
        data = self.pattern.assemble(jac_values)
        self.elastic.accumulate(q, ctx.frames, r, data)
        return r, data, ctx
