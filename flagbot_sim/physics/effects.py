"""External effects and drivers: one small class each, built only when a scene lists it (``EFFECT_TYPES``).

The equations of motion are r(q) = grad E(q) - sum_effects F(q) = 0 at the end of every step (paper Eq.
DER3D_EOM; inertia is an effect). An effect sees one trial configuration through a :class:`StepContext`: the
trial DOFs q, and the velocity v and acceleration a that the time integrator assigns to them, both affine in q
(v = dv_dq q + ..., a = da_dq q + ...), so an effect never needs to know which integrator runs.

The protocol (every hook has a default here; dismech-rods' base_force has the same two entry points):

* ``from_scene(scene, net, elastic)``: build the effect from its scene section(s) and the rod network.
* ``blocks()``: the Jacobian stencils it writes, as (rows (K, a), cols (K, b)) DOF index arrays. The model
  merges them into one sparse pattern at construction and hands each block's CSC slots back through ``bind``;
  an effect must fill exactly the blocks it declared (``bind`` checks the count).
* ``add_force(ctx, r)``: subtract its generalised force from the residual r (cheap: the line search calls
  only this).
* ``add_jacobian(ctx, J)``: subtract dF/dq from the CSC data array J, on its slots.
* ``prescribed_dofs`` and ``prescribed_values(state, angle)``: DOFs whose values the effect imposes (a clamp)
  and their values at the end of a trial step; empty for a force.
* ``spin_drag(scene)``: the torque about the axis per spin rate it puts on the head and on the flagella of the
  straight robot turning rigidly, (0, 0) for most; the steady solver's first guess balances their sums.

Effects keep no state that changes during a run: what changes lives in the :class:`~.model.State` (the drive
angle) or in the step context, so a rejected trial step leaves nothing to undo.

A :class:`Driver` (motor, clamp) is what the speed command ``omega`` (rad/s) drives: the command is an argument
of every step (``Stepper.step(state, dt, omega)``), integrated into ``State.drive_angle`` (paper Eq.
SpecifyTheta as an integral: a live command changes omega without a jump), never state of the effect. A
driver says how the drive angle enters the physics: as the natural-twist offset of one hinge
(``twist_hinge``, the motor) or as prescribed DOF values (``prescribed_values``, the clamp).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from .medium import head_drag_coefficient, head_torque_coefficient, rft_coefficients
from .network import RodNetwork, helix_angle

if TYPE_CHECKING:
    from .frames import TrialFrames

_NO_DOFS = np.zeros(0, np.int64)


@dataclass
class StepContext:
    """What an effect sees of one trial configuration (end of a step, or of a stage of one)."""
    q: np.ndarray          # trial DOFs
    x: np.ndarray          # (N, 3) view of the trial node positions
    v: np.ndarray          # trial DOF velocities (from the integrator)
    a: np.ndarray          # trial DOF accelerations (from the integrator)
    dv_dq: float           # d v / d q (the integrator's coefficient; a multiple of the identity)
    da_dq: float           # d a / d q
    t: float               # time of the trial configuration (s)
    h: float               # step size (s)
    drive_angle: float     # the driver's angle at time t (rad)
    frames: TrialFrames


class Effect:
    """Base class: documents and defaults every hook of the effect protocol (module docstring)."""
    #: the name a scene lists in ``scene.effects``
    name: ClassVar[str] = ""
    #: one line for ``flagbot scenes`` and the docs
    description: ClassVar[str] = ""
    #: True for effects that need the head (a clamped scene holds the head fixed and cannot list them)
    on_head: ClassVar[bool] = False
    #: DOFs the stepper holds at values the effect prescribes (their residual rows become identity rows)
    prescribed_dofs: np.ndarray = _NO_DOFS
    #: the compiled kernels it calls, as groups of physics.warmup.GROUPS (compiled only for scenes listing it)
    kernel_groups: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def from_scene(cls, scene, net: RodNetwork, elastic) -> "Effect":
        raise NotImplementedError(f"{cls.__name__}.from_scene")

    def blocks(self) -> list[tuple[np.ndarray, np.ndarray]]:
        return []

    def bind(self, slots: list[np.ndarray]) -> None:
        """Receive the CSC slots of the declared blocks, in the order of :meth:`blocks` (each flat, in the
        block's (K, a, b) order)."""
        if len(slots) != len(self.blocks()):
            raise ValueError(f"effect {self.name!r} declared {len(self.blocks())} Jacobian blocks, "
                             f"got {len(slots)} slot arrays")
        self.slots = [np.ascontiguousarray(s, dtype=np.int64) for s in slots]

    def add_force(self, ctx: StepContext, r: np.ndarray) -> None:
        pass

    def add_jacobian(self, ctx: StepContext, J: np.ndarray) -> None:
        pass

    def prescribed_values(self, state, angle: float) -> np.ndarray:
        """Values of ``prescribed_dofs`` for a step from the committed ``state`` to drive angle ``angle``."""
        return np.zeros(0)

    def spin_drag(self, scene) -> tuple[float, float]:
        """(on the head, on the flagella): the resisting torque about the axis per spin rate (N m s) of the straight
        robot turning rigidly (the head at its spin rate, the flagella at theirs)."""
        return 0.0, 0.0


class Driver(Effect):
    """An effect commanded by a speed omega (rad/s, the step's argument), whose integral is the State's
    ``drive_angle``."""
    #: hinge whose natural twist advances with the drive angle (-1: none)
    twist_hinge: int = -1


# ----------------------------------------------------------------------------------------------- inertia
class Inertia(Effect):
    """Lumped mass and rotational inertia: F = -M a (paper Eq. DER3D_EOM)."""
    name = "inertia"
    description = "lumped mass of every node and rotational inertia of every edge (density from the scene)"

    def __init__(self, net: RodNetwork):
        self.mass = np.concatenate([np.repeat(net.node_mass, 3), net.edge_inertia])
        self.dofs = np.arange(net.ndof)

    @classmethod
    def from_scene(cls, scene, net, elastic):
        return cls(net)

    def blocks(self):
        return [(self.dofs[:, None], self.dofs[:, None])]

    def add_force(self, ctx, r):
        r += self.mass * ctx.a

    def add_jacobian(self, ctx, J):
        J[self.slots[0]] += self.mass * ctx.da_dq


# ----------------------------------------------------------------------------------------------- gravity
class Gravity(Effect):
    name = "gravity"
    description = "weight of every node, m*g"

    def __init__(self, net: RodNetwork, g):
        self.f = (net.node_mass[:, None] * np.asarray(g, float)[None, :]).ravel()
        self.n = 3 * net.n_nodes

    @classmethod
    def from_scene(cls, scene, net, elastic):
        return cls(net, scene.gravity.g)

    def add_force(self, ctx, r):
        r[: self.n] -= self.f


# ----------------------------------------------------------------------------------------------- RFT drag
def _rft_py(x, v, dv_dx, k, a, b, vor, eta_t, eta_p, dofs, r, J, s_kk, s_ka, s_kb, want_jacobian):
    """F_k = -l_k [eta_t (v.t) t + eta_p (v - (v.t) t)] into r (residual: -F); -dF/dx into J."""
    de = eta_t - eta_p
    tv = np.empty(3)
    vv = np.empty(3)
    for n in range(k.shape[0]):
        kk, aa, bb = k[n], a[n], b[n]
        for i in range(3):
            vv[i] = v[3 * kk + i]
            tv[i] = x[bb, i] - x[aa, i]
        chord = math.sqrt(tv[0] * tv[0] + tv[1] * tv[1] + tv[2] * tv[2])
        tv /= chord
        vt = vv[0] * tv[0] + vv[1] * tv[1] + vv[2] * tv[2]
        l = vor[n]
        for i in range(3):
            r[dofs[n, i]] += l * (eta_p * vv[i] + de * vt * tv[i])
        if not want_jacobian:
            continue
        # through v_k: dF/dx_k = -l dv_dx (eta_p I + de t t^T); through the tangent:
        # dF/dt = -l de (vt I + t v^T), dt/dx_b = (I - t t^T) / chord = -dt/dx_a
        for i in range(3):
            for j in range(3):
                dij = 1.0 if i == j else 0.0
                J[s_kk[n, i, j]] += l * dv_dx * (eta_p * dij + de * tv[i] * tv[j])
                acc = 0.0
                for m in range(3):
                    dft = -l * de * (vt * (1.0 if i == m else 0.0) + tv[i] * vv[m])
                    acc += dft * ((1.0 if m == j else 0.0) - tv[m] * tv[j])
                J[s_kb[n, i, j]] -= acc / chord
                J[s_ka[n, i, j]] += acc / chord


_RFT = None


def rft_kernel():
    """The compiled :func:`_rft_py`, compiled (or loaded from the cache) on first use: this module is imported
    by the scene validator for the registry alone, which must not pull in numba."""
    global _RFT
    if _RFT is None:
        from .jit import kernel
        _RFT = kernel(_rft_py)
    return _RFT


class RFTDrag(Effect):
    """Resistive-force theory on the flagellum nodes (paper Eqs. externalForceTail, viscousForce).

    F_k = -l_k [eta_t (v.t) t + eta_p (v - (v.t) t)] with l_k the node's Voronoi length on the flagellum, v_k its
    velocity and t_k the node tangent, the unit chord between its neighbours (one-sided at the base and the tip).
    The Jacobian includes the tangent's dependence on the positions (the lab's codes freeze it; the full one
    keeps Newton quadratic when the flagella swing).
    """
    name = "rft"
    kernel_groups = ("rft",)
    description = ("resistive-force-theory drag of the medium on the flagella (eta_t, eta_p from medium.model, mu, "
                   "r0 and L or the helix)")

    def __init__(self, net: RodNetwork, eta_t: float, eta_p: float):
        self.eta_t, self.eta_p = float(eta_t), float(eta_p)
        k, a, b, l = [], [], [], []
        for nodes, vor in zip(net.flagella_nodes, net.flagellum_voronoi):
            k.append(nodes)
            a.append(np.concatenate([[nodes[0]], nodes[:-2], [nodes[-2]]]))
            b.append(np.concatenate([[nodes[1]], nodes[2:], [nodes[-1]]]))
            l.append(vor)
        self.k, self.a, self.b = (np.concatenate(z).astype(np.int64) for z in (k, a, b))
        self.l = np.concatenate(l)
        self.dof_k = net.node_dofs(self.k)
        self.dof_a = net.node_dofs(self.a)
        self.dof_b = net.node_dofs(self.b)

    @classmethod
    def from_scene(cls, scene, net, elastic):
        return cls(net, *rft_coefficients(scene))

    def spin_drag(self, scene):
        """n rigid flagella on a cylinder of radius R_d, moving at omega R_d along it: the component across their
        tangent (helix angle theta; 0 for straight ones) and along it give n L R_d^2 (eta_t sin^2 + eta_p cos^2)."""
        th = helix_angle(scene.R_d, scene.flagellum.helix_pitch)
        drag = self.eta_t * math.sin(th) ** 2 + self.eta_p * math.cos(th) ** 2
        return 0.0, scene.robot.n_flagella * drag * scene.flagellum.length * scene.R_d ** 2

    def blocks(self):
        return [(self.dof_k, self.dof_k), (self.dof_k, self.dof_a), (self.dof_k, self.dof_b)]

    def bind(self, slots):
        super().bind(slots)
        self._s = [s.reshape(-1, 3, 3) for s in self.slots]

    def _run(self, x, v, dv_dx, r, J, want):
        rft_kernel()(x, v, dv_dx, self.k, self.a, self.b, self.l, self.eta_t, self.eta_p, self.dof_k, r, J, *self._s, want)

    def add_force(self, ctx, r):
        self._run(ctx.x, ctx.v, ctx.dv_dq, r, np.empty(0), False)

    def add_jacobian(self, ctx, J):
        self._run(ctx.x, ctx.v, ctx.dv_dq, np.zeros(len(ctx.q)), J, True)

    def node_forces(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(n, 3) RFT forces on the flagellum nodes ``self.k`` for positions x (N, 3) and DOF velocities v."""
        r = np.zeros(len(v))
        rft_kernel()(x, v, 0.0, self.k, self.a, self.b, self.l, self.eta_t, self.eta_p, self.dof_k, r, np.empty(0),
             *([np.zeros((0, 3, 3), np.int64)] * 3), False)
        return -r[self.dof_k]


# ----------------------------------------------------------------------------------------------- head
class HeadDrag(Effect):
    """Stokes drag on the head, F = -C1 6 pi mu R_h v_h (paper Eq. stokes_drag_refined).

    Split equally over the head nodes x0, x1, x2, each with its own velocity: for a rigid translation this is
    exactly the paper's force on v_h = dx1/dt, and it also resists the head's tilting.
    """
    name = "head_drag"
    description = "Stokes drag on the head, -C1*6*pi*mu*R_h*v_h (C1 = 1 in the viscous medium)"
    on_head = True

    def __init__(self, net: RodNetwork, coefficient: float):
        self.c = float(coefficient)
        self.dofs = net.node_dofs(net.head_nodes).ravel()         # (9,)
        self.w = self.c / len(net.head_nodes)

    @classmethod
    def from_scene(cls, scene, net, elastic):
        return cls(net, head_drag_coefficient(scene))

    def blocks(self):
        return [(self.dofs[:, None], self.dofs[:, None])]

    def add_force(self, ctx, r):
        r[self.dofs] += self.w * ctx.v[self.dofs]

    def add_jacobian(self, ctx, J):
        J[self.slots[0]] += self.w * ctx.dv_dq


class HeadTorque(Effect):
    """Stokes torque on the head spin, T = -C2 8 pi mu R_h^3 omega_h (paper Eq. stokes_torque_refined).

    omega_h is the spin rate of the head body's material frame about its tangent, which for a time-parallel
    transported reference frame is exactly d(theta^0)/dt; the torque acts on that twist DOF. A torque about the
    tangent also does work when the tangent moves: the material frame then spins by d(theta) + dOmega/dx dx, with
    Omega the holonomy of the transport from the committed tangent (elastic._edge_holonomy), so the head's nodes
    receive T dOmega/dx. It vanishes while the head's tangent is its committed one (a time step along a fixed axis,
    every relative equilibrium), but its derivative does not: without it the linearisation about a steady state,
    whose frames stay those of the equilibrium, is not invariant under tilting the whole robot (a tilt looked
    like a slowly growing precession, and design 1 "unstable" above ~117 rpm).
    """
    name = "head_torque"
    kernel_groups = ("head_torque",)
    description = "Stokes torque on the head spin, -C2*8*pi*mu*R_h^3*omega_h (C2 = 1 in the viscous medium)"
    on_head = True

    def __init__(self, net: RodNetwork, coefficient: float):
        from .elastic import tangent_torque      # compiled; built with the model, which imports elastic anyway
        self._kernel = tangent_torque
        self.c = float(coefficient)
        self.edge = int(net.head_edge)
        self.dof = int(net.edge_dof(net.head_edge))
        a, b = net.edges[self.edge]
        self.x_dofs = net.node_dofs([a, b]).ravel().astype(np.int64)             # [x_tail, x_head]
        self._none = np.zeros(0, np.int64)

    @classmethod
    def from_scene(cls, scene, net, elastic):
        return cls(net, head_torque_coefficient(scene))

    def spin_drag(self, scene):
        return self.c, 0.0

    def blocks(self):
        th = np.array([[self.dof]])
        xs = self.x_dofs[None, :]
        return [(th, th), (xs, xs), (xs, th)]

    def add_force(self, ctx, r):
        tq = self.c * ctx.v[self.dof]                  # -T
        r[self.dof] += tq
        fr = ctx.frames
        self._kernel(fr.t, fr.t_committed, fr.length, self.edge, tq, 0.0, self.x_dofs, r, np.empty(0),
                     self._none, self._none, False)

    def add_jacobian(self, ctx, J):
        tq = self.c * ctx.v[self.dof]
        J[self.slots[0][0]] += self.c * ctx.dv_dq
        fr = ctx.frames
        self._kernel(fr.t, fr.t_committed, fr.length, self.edge, tq, self.c * ctx.dv_dq, self.x_dofs,
                     np.zeros(len(ctx.q)), J, self.slots[1], self.slots[2], True)


class SpinDrag(Effect):
    """Resistance of the medium to each flagellum spinning about its own axis: T_e = -c l_e omega_e about the
    tangent of every flagellum edge e (rest length l_e), omega_e the spin rate of its material frame.

    c (N s, torque per length per rad/s) from ``medium.spin_drag`` (medium.spin_drag_coefficient; by default the
    one of ``medium.model``): 'viscous', c = 4 pi mu r0^2, the torque per
    length on an infinite cylinder of radius r0 turning about its axis in Stokes flow (the flow u = Omega r0^2 / r
    around it, wall shear stress 2 mu Omega); 'granular', c = k eta_t r0^2 (k = ``medium.spin_traction``), an
    assumption: the grains resist the surface sliding round the axis at omega r0 with the traction that resists
    the same surface sliding along it, eta_t v / (2 pi r0) per area. The paper's model has no such term (RFT acts
    on the centreline only), so the effect is off unless a scene lists it.

    With time-parallel transported reference frames omega_e is the twist DOF's rate d(theta_e)/dt, and, like the
    head torque (:class:`HeadTorque`), a torque about a moving tangent also does work through the transport's
    holonomy: the edge's nodes receive T dOmega/dx (elastic.tangent_torques). Its velocity Jacobian c l_e is a
    damping of the flagella's twist, which otherwise carries only its inertia.
    """
    name = "spin_drag"
    kernel_groups = ("spin_drag",)
    description = ("drag on each flagellum spinning about its own axis, -c*l*omega per edge (c = 4*pi*mu*r0^2, or "
                   "the granular analogue: medium.spin_drag); not in the paper's model")

    def __init__(self, net: RodNetwork, coefficient: float):
        from .elastic import tangent_torques      # compiled; built with the model, which imports elastic anyway
        self._kernel = tangent_torques
        self.c = float(coefficient)
        self.edges = np.concatenate(net.flagella_edges).astype(np.int64)
        self.c_l = self.c * net.edge_rest_length[self.edges]              # N m s per edge
        self.dofs = net.edge_dof(self.edges).astype(np.int64)
        ends = net.edges[self.edges]                                      # (E, 2): tail, head
        self.x_dofs = np.ascontiguousarray(np.concatenate([net.node_dofs(ends[:, 0]), net.node_dofs(ends[:, 1])],
                                                          axis=1).astype(np.int64))      # (E, 6)
        E = len(self.edges)
        self._none = (np.zeros((E, 0), np.int64), np.zeros((E, 0), np.int64))

    @classmethod
    def from_scene(cls, scene, net, elastic):
        from .medium import spin_drag_coefficient
        return cls(net, spin_drag_coefficient(scene))

    def spin_drag(self, scene):
        """The straight (or helical, helix angle theta) flagella turning rigidly at omega spin about their tangents
        at omega cos(theta), whose torque about the axis is c L omega cos^2(theta) each."""
        th = helix_angle(scene.R_d, scene.flagellum.helix_pitch)
        return 0.0, float(self.c_l.sum()) * math.cos(th) ** 2

    def blocks(self):
        th = self.dofs[:, None]
        return [(th, th), (self.x_dofs, self.x_dofs), (self.x_dofs, th)]

    def bind(self, slots):
        super().bind(slots)
        E = len(self.edges)
        self._s_xx = self.slots[1].reshape(E, 36)
        self._s_xth = self.slots[2].reshape(E, 6)

    def add_force(self, ctx, r):
        tq = self.c_l * ctx.v[self.dofs]               # -T
        r[self.dofs] += tq
        fr = ctx.frames
        self._kernel(fr.t, fr.t_committed, fr.length, self.edges, tq, tq, self.x_dofs, r, np.empty(0),
                     *self._none, False)

    def add_jacobian(self, ctx, J):
        tq = self.c_l * ctx.v[self.dofs]
        dtq = self.c_l * ctx.dv_dq
        J[self.slots[0]] += dtq
        fr = ctx.frames
        self._kernel(fr.t, fr.t_committed, fr.length, self.edges, tq, dtq, self.x_dofs, np.zeros(len(ctx.q)), J,
                     self._s_xx, self._s_xth, True)

    def axial_torque(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The torque (N m, a 3-vector) the spin drag exerts on the flagella at positions x (N, 3), DOF velocities v."""
        e = x[self.x_dofs[:, 5] // 3] - x[self.x_dofs[:, 0] // 3]
        t = e / np.linalg.norm(e, axis=1)[:, None]
        return -(self.c_l * v[self.dofs]) @ t


# ----------------------------------------------------------------------------------------------- drivers
class Motor(Driver):
    """The motor at the head centre: the natural twist of the head/shaft hinge advances with the drive angle.

    Paper Eq. SpecifyTheta writes tau_bar = omega_T t; the drive angle integrates omega_T step by step instead,
    so omega_T can change at any step (a live ROS command) without a jump in the natural twist.
    """
    name = "motor"
    description = "motor at the head centre: natural twist of the head/shaft hinge advanced by omega_T*dt"
    on_head = True

    def __init__(self, net: RodNetwork):
        self.twist_hinge = int(net.motor_hinge)

    @classmethod
    def from_scene(cls, scene, net, elastic):
        return cls(net)


class Clamp(Driver):
    """Drives the plate (joint, plate arm, socket) of a single flagellum about the x axis at omega.

    The flagellum is clamped in the socket, so its base position and tangent follow the plate: the paper's
    'clamped flagellum fixed in space' (head held fixed). Positions and the twist angles of the plate edges are
    prescribed; the twist angles are chosen so that the material frames turn rigidly with the plate.
    """
    name = "clamp"
    kernel_groups = ("clamp",)
    description = ("flagellum base clamped to a plate driven about the axis at omega (no head; the paper's "
                   "'clamped flagellum fixed in space')")

    def __init__(self, net: RodNetwork, elastic):
        self.nodes = np.unique(np.concatenate([[net.joint_node], net.edges[net.plate_edges].ravel(),
                                               net.edges[net.socket_edges].ravel()]))
        self.edges = np.concatenate([net.plate_edges, net.socket_edges])
        self.x0 = net.nodes[self.nodes]
        self.m1_0 = elastic.frames0.d1[self.edges].copy()          # material director m1 at rest (theta = 0)
        self._edge_local = np.searchsorted(self.nodes, net.edges[self.edges])   # driven edges in self.nodes
        self._theta_dofs = net.edge_dof(self.edges)
        self.prescribed_dofs = np.concatenate([net.node_dofs(self.nodes).ravel(), self._theta_dofs])

    @classmethod
    def from_scene(cls, scene, net, elastic):
        return cls(net, elastic)

    @staticmethod
    def rotation(phi: float) -> np.ndarray:
        c, s = math.cos(phi), math.sin(phi)
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])

    def prescribed_values(self, state, angle):
        from .frames import twist_for_director, unit_rows
        R = self.rotation(angle)
        x = self.x0 @ R.T
        e = self._edge_local
        t, _ = unit_rows(x[e[:, 1]] - x[e[:, 0]])
        fr = state.frames
        theta = twist_for_director(fr.d1[self.edges], fr.t[self.edges], t, self.m1_0 @ R.T,
                                   state.q[self._theta_dofs])
        return np.concatenate([x.ravel(), theta])


# ----------------------------------------------------------------------------------------------- granular yield
class GranularYield(Effect):
    """Yield of the granular medium against the head's translation: a regularised Coulomb law,

        F_k = -(F_y / 3) v_k / sqrt(|v_k|^2 + v_eps^2)       on each head node k (x0, x1, x2)

    (F_y = ``medium.yield_force``, v_eps = ``medium.yield_speed``). Granular media resist the onset of motion
    with a finite force, whatever the speed: a robot whose flagella push with less than F_y stays put (it creeps
    at |v| ~ v_eps T / F_y), above it the excess thrust drives it against the viscous (Stokes, RFT) drag: the
    paper's threshold motor speed omega_T^s, below which its robots did not move. The law is isotropic, on every
    head node's own velocity (split like the head drag): frame-invariant, with no axis to pick (so no position
    dependence and no extra Jacobian terms), and at steady swimming, where the head nodes move along the axis,
    it is exactly the axial law F = -F_y v/sqrt(v^2+v_eps^2). It is smooth (C-infinity) for v_eps > 0; its
    velocity Jacobian F_y/3 (I - v v^T/s^2)/s, s = sqrt(|v|^2 + v_eps^2), is symmetric positive definite (a
    damping, so it never destabilises an implicit step), largest, F_y/(3 v_eps), at rest.
    """
    name = "granular_yield"
    description = ("yield of the granular medium on the head: regularised Coulomb resistance "
                   "-F_y*v/sqrt(|v|^2+v_eps^2) (stays put below a threshold motor speed)")
    on_head = True

    def __init__(self, net: RodNetwork, yield_force: float, yield_speed: float):
        self.f = float(yield_force) / len(net.head_nodes)
        self.eps2 = float(yield_speed) ** 2
        self.dofs = net.node_dofs(net.head_nodes)                 # (3 nodes, 3)

    @classmethod
    def from_scene(cls, scene, net, elastic):
        return cls(net, scene.medium.yield_force, scene.medium.yield_speed)

    def blocks(self):
        return [(self.dofs, self.dofs)]

    def _velocities(self, ctx):
        v = ctx.v[self.dofs]                                       # (3, 3)
        # the sum in the order the compiled step forms it (physics/newton.py)
        return v, np.sqrt(v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1] + v[:, 2] * v[:, 2] + self.eps2)

    def add_force(self, ctx, r):
        v, s = self._velocities(ctx)
        r[self.dofs] += (self.f / s)[:, None] * v

    def add_jacobian(self, ctx, J):
        # F depends on q only through v = dv_dq q + v0
        v, s = self._velocities(ctx)
        d = (self.f / s)[:, None, None] * (np.eye(3)[None] - v[:, :, None] * v[:, None, :] / (s * s)[:, None, None])
        J[self.slots[0]] += (d * ctx.dv_dq).ravel()


#: every effect a scene may list, by name, in the order ``flagbot scenes`` shows them (scipy's METHODS shape:
#: adding an effect is one class here plus, if it has constants, its keys in a scene section)
EFFECT_TYPES: dict[str, type[Effect]] = {cls.name: cls for cls in
                                         (Inertia, RFTDrag, HeadDrag, HeadTorque, Motor, Clamp, Gravity,
                                          GranularYield, SpinDrag)}
