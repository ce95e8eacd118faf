"""External effects: each a small class with the same interface, built only when a scene asks for it.

An effect contributes a force F(q) (generalised: forces on node DOFs, torques on twist DOFs) to the equations of
motion, r(q) = grad E(q) - sum F(q) = 0, and its Jacobian dF/dq as a batch of dense blocks on a fixed stencil.
Two entry points, as in dismech-rods' base_force: :meth:`Effect.force` (cheap; used by the line search) and
:meth:`Effect.force_and_jacobian`. Effects that drive the robot (motor, clamp) also take part in the step
protocol: :meth:`begin_step` computes their targets for a trial step from the committed state, and
:meth:`commit` stores them once the step is accepted, so a rejected step (dt halved) leaves nothing behind.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import kernels
from .frames import normalize, parallel_transport, rowdot, signed_angle, unwrap_to
from .network import RodNetwork

_EYE = np.eye(3)


@dataclass
class StepContext:
    """What an effect sees of one trial configuration."""
    q: np.ndarray          # trial DOFs (end of step)
    q_old: np.ndarray      # DOFs at the start of the step
    v_old: np.ndarray      # DOF velocities at the start of the step
    dt: float
    t_new: float
    x: np.ndarray          # (N, 3) trial positions
    x_old: np.ndarray      # (N, 3)
    frames: object         # TrialFrames of the trial configuration


class Effect:
    name = "effect"
    #: True for effects on the head, so that tests can assert a scene without them builds none
    on_head = False

    def blocks(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Jacobian stencils: list of (rows (K, a), cols (K, b)) DOF index arrays."""
        return []

    def force(self, ctx: StepContext) -> tuple[np.ndarray, np.ndarray] | None:
        """(dof indices, values) of the generalised force, or None."""
        return None

    def force_and_jacobian(self, ctx: StepContext):
        """(dof indices, force values, [dF/dq values per block])."""
        f = self.force(ctx)
        if f is None:
            return None, None, []
        return f[0], f[1], []

    # ---- step protocol (driving effects only)
    def begin_step(self, state, dt: float) -> None:
        pass

    def commit(self, state) -> None:
        pass

    def initial_state(self) -> dict:
        return {}


# ----------------------------------------------------------------------------------------------- inertia
class Inertia(Effect):
    """Lumped mass: F = -M (q - q_old - dt v_old) / dt^2 (paper Eq. DER3D_EOM)."""
    name = "inertia"

    def __init__(self, net: RodNetwork):
        self.mass = np.concatenate([np.repeat(net.node_mass, 3), net.edge_inertia])
        self.dofs = np.arange(net.ndof)

    def blocks(self):
        return [(self.dofs[:, None], self.dofs[:, None])]

    def force(self, ctx):
        return self.dofs, -self.mass * (ctx.q - ctx.q_old - ctx.dt * ctx.v_old) / ctx.dt ** 2

    def force_and_jacobian(self, ctx):
        idx, f = self.force(ctx)
        return idx, f, [(-self.mass / ctx.dt ** 2)[:, None, None]]


# ----------------------------------------------------------------------------------------------- gravity
class Gravity(Effect):
    name = "gravity"

    def __init__(self, net: RodNetwork, g):
        self.dofs = np.arange(3 * net.n_nodes)
        self.f = (net.node_mass[:, None] * np.asarray(g, float)[None, :]).ravel()

    def force(self, ctx):
        return self.dofs, self.f


# ----------------------------------------------------------------------------------------------- RFT drag
class RFTDrag(Effect):
    """Resistive-force theory on the flagellum nodes (paper Eqs. externalForceTail, viscousForce).

    F_k = -l_k [eta_t (v.t) t + eta_p (v - (v.t) t)] with l_k the node's Voronoi length on the flagellum,
    v_k = (x_k - x_k_old) / dt from the implicit step and t_k the node tangent, the unit chord between its
    neighbours (one-sided at the base and the tip). The Jacobian includes the tangent's dependence on the
    positions (the lab's codes freeze it; the full one keeps Newton quadratic when the flagella swing).
    """
    name = "rft"

    def __init__(self, net: RodNetwork, eta_t: float, eta_p: float):
        self.eta_t, self.eta_p = eta_t, eta_p
        k_list, a_list, b_list, l_list = [], [], [], []
        for nodes, vor in zip(net.flagella_nodes, net.flagellum_voronoi):
            m = len(nodes)
            a = np.concatenate([[nodes[0]], nodes[:-2], [nodes[-2]]])
            b = np.concatenate([[nodes[1]], nodes[2:], [nodes[-1]]])
            k_list.append(nodes)
            a_list.append(a)
            b_list.append(b)
            l_list.append(vor)
            assert len(a) == m
        self.k = np.concatenate(k_list)
        self.a = np.concatenate(a_list)
        self.b = np.concatenate(b_list)
        self.l = np.concatenate(l_list)
        self.dof_k = net.node_dofs(self.k)
        self._no_jacobian = np.empty((1, 3, 3))
        self.dof_a = net.node_dofs(self.a)
        self.dof_b = net.node_dofs(self.b)

    def blocks(self):
        return [(self.dof_k, self.dof_k), (self.dof_k, self.dof_a), (self.dof_k, self.dof_b)]

    def _kinematics(self, ctx):
        v = (ctx.x[self.k] - ctx.x_old[self.k]) / ctx.dt
        t, chord = normalize(ctx.x[self.b] - ctx.x[self.a])
        vt = rowdot(v, t)
        return v, t, chord, vt

    def node_forces(self, ctx) -> np.ndarray:
        v, t, _, vt = self._kinematics(ctx)
        return -self.l[:, None] * (self.eta_p * v + ((self.eta_t - self.eta_p) * vt)[:, None] * t)

    #: compiled kernel when numba is available (set False on an instance for the numpy reference)
    use_kernels = kernels.AVAILABLE

    def force(self, ctx):
        if self.use_kernels:
            F = np.empty((len(self.k), 3))
            kernels.rft(ctx.x, ctx.x_old, ctx.dt, self.k, self.a, self.b, self.l, self.eta_t, self.eta_p, F,
                        self._no_jacobian, self._no_jacobian, False)
            return self.dof_k, F
        return self.dof_k, self.node_forces(ctx)

    def force_and_jacobian(self, ctx):
        if self.use_kernels:
            n = len(self.k)
            F, J_k, J_b = np.empty((n, 3)), np.empty((n, 3, 3)), np.empty((n, 3, 3))
            kernels.rft(ctx.x, ctx.x_old, ctx.dt, self.k, self.a, self.b, self.l, self.eta_t, self.eta_p, F, J_k,
                        J_b, True)
            return self.dof_k, F, [J_k, -J_b, J_b]
        v, t, chord, vt = self._kinematics(ctx)
        l, de = self.l[:, None, None], self.eta_t - self.eta_p
        F = -self.l[:, None] * (self.eta_p * v + (de * vt)[:, None] * t)
        tt = t[:, :, None] * t[:, None, :]
        dF_dx = -(l / ctx.dt) * (self.eta_p * _EYE + de * tt)                     # through v_k
        dF_dt = -l * de * (vt[:, None, None] * _EYE + t[:, :, None] * v[:, None, :])  # through t_k
        dt_db = (_EYE - tt) / chord[:, None, None]
        J_b = dF_dt @ dt_db
        return self.dof_k, F, [dF_dx, -J_b, J_b]


# ----------------------------------------------------------------------------------------------- head
class HeadDrag(Effect):
    """Stokes drag on the head, F = -C1 6 pi mu R_h v_h (paper Eq. stokes_drag_refined).

    Split equally over the head nodes x0, x1, x2, each with its own velocity: for a rigid translation this is
    exactly the paper's force on v_h = dx1/dt, and it also resists the head's tilting.
    """
    name = "head_drag"
    on_head = True

    def __init__(self, net: RodNetwork, coefficient: float):
        self.c = coefficient
        self.dofs = net.node_dofs(net.head_nodes)          # (3, 3)
        self.w = coefficient / len(net.head_nodes)

    def blocks(self):
        return [(self.dofs, self.dofs)]

    def force(self, ctx):
        return self.dofs, -self.w * (ctx.q[self.dofs] - ctx.q_old[self.dofs]) / ctx.dt

    def force_and_jacobian(self, ctx):
        idx, f = self.force(ctx)
        return idx, f, [np.broadcast_to(-self.w / ctx.dt * _EYE, (len(self.dofs), 3, 3))]


class HeadTorque(Effect):
    """Stokes torque on the head spin, T = -C2 8 pi mu R_h^3 omega_h (paper Eq. stokes_torque_refined).

    omega_h is the spin rate of the head body's material frame about its tangent, which for a time-parallel
    transported reference frame is exactly d(theta^0)/dt; the torque acts on that twist DOF.
    """
    name = "head_torque"
    on_head = True

    def __init__(self, net: RodNetwork, coefficient: float):
        self.c = coefficient
        self.dof = np.array([net.edge_dof(net.head_edge)])

    def blocks(self):
        return [(self.dof[:, None], self.dof[:, None])]

    def force(self, ctx):
        return self.dof, -self.c * (ctx.q[self.dof] - ctx.q_old[self.dof]) / ctx.dt

    def force_and_jacobian(self, ctx):
        idx, f = self.force(ctx)
        return idx, f, [np.full((1, 1, 1), -self.c / ctx.dt)]


# ----------------------------------------------------------------------------------------------- drivers
class Motor(Effect):
    """The motor at the head centre: the natural twist of the head/shaft hinge advances by omega_T * dt.

    Paper Eq. SpecifyTheta writes tau_bar = omega_T t; integrating omega_T step by step instead lets omega_T
    change at any step (a live ROS command) without a jump in the natural twist.
    """
    name = "motor"
    on_head = True

    def __init__(self, net: RodNetwork, elastic, omega_T: float):
        self.elastic = elastic
        self.hinge = net.motor_hinge
        self.omega = float(omega_T)
        self.base_twist = float(elastic.tau_bar0[self.hinge])
        self._trial_angle = 0.0

    def initial_state(self):
        return {"motor_angle": 0.0}

    def begin_step(self, state, dt):
        self._trial_angle = state.extras["motor_angle"] + self.omega * dt
        self.elastic.tau_bar[self.hinge] = self.base_twist + self._trial_angle

    def commit(self, state):
        state.extras["motor_angle"] = self._trial_angle

    def restore(self, state):
        """Make the elastic model's natural twist match a committed state (after reset / rollback)."""
        self.elastic.tau_bar[self.hinge] = self.base_twist + state.extras["motor_angle"]


class Clamp(Effect):
    """Drives the plate (joint, plate arm, socket) of a single flagellum about the x axis at omega.

    The flagellum is clamped in the socket, so its base position and tangent follow the plate: the paper's
    'clamped flagellum fixed in space' (head held fixed). Positions and the twist angles of the plate edges are
    prescribed; the twist angles are chosen so that the material frames turn rigidly with the plate.
    """
    name = "clamp"

    def __init__(self, net: RodNetwork, elastic, omega: float):
        self.net = net
        self.elastic = elastic
        self.omega = float(omega)
        self.nodes = np.unique(np.concatenate([[net.joint_node], net.edges[net.plate_edges].ravel(),
                                               net.edges[net.socket_edges].ravel()]))
        self.edges = np.concatenate([net.plate_edges, net.socket_edges])
        self.x0 = net.nodes[self.nodes]
        # material director m1 of the driven edges at rest (theta = 0)
        self.m1_0 = elastic.frames0.d1[self.edges].copy()
        self._edge_local = np.searchsorted(self.nodes, net.edges[self.edges])   # driven edges in self.nodes
        self._theta_dofs = net.edge_dof(self.edges)
        #: DOFs the stepper holds at the clamp's values (their residual rows become identity rows)
        self.prescribed_dofs = np.concatenate([net.node_dofs(self.nodes).ravel(), net.edge_dof(self.edges)])
        self._trial = None

    #: compiled kernel when numba is available (set False on an instance for the numpy reference). The numpy
    #: path costs ~55 us more per sub-step (numpy call overhead on two edges), ~15-20% of a clamped step.
    use_kernels = kernels.AVAILABLE

    def initial_state(self):
        return {"clamp_angle": 0.0}

    @staticmethod
    def rotation(phi: float) -> np.ndarray:
        c, s = math.cos(phi), math.sin(phi)
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])

    def begin_step(self, state, dt):
        phi = state.extras["clamp_angle"] + self.omega * dt
        R = self.rotation(phi)
        x = self.x0 @ R.T
        # twist angles that make the material frame the rotated rest frame, given the transported reference frame
        e = self._edge_local
        t, _ = normalize(x[e[:, 1]] - x[e[:, 0]])
        fr = state.frames
        theta_old = state.q[self._theta_dofs]
        if self.use_kernels:
            theta = np.empty(len(self.edges))
            kernels.clamp_twist(fr.d1[self.edges], fr.t[self.edges], t, self.m1_0 @ R.T, theta_old, theta)
        else:
            d1_new = parallel_transport(fr.d1[self.edges], fr.t[self.edges], t)
            theta = unwrap_to(signed_angle(d1_new, self.m1_0 @ R.T, t), theta_old)
        self._trial = (phi, np.concatenate([x.ravel(), theta]))

    def prescribed(self):
        return self.prescribed_dofs, self._trial[1]

    def commit(self, state):
        state.extras["clamp_angle"] = self._trial[0]
