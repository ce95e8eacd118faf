"""Rod-network geometry of the flagellated robot: nodes, edges, bend-twist hinges and their stiffnesses.

Layout (robot axis = lab x; the flagella point to +x, the head leads towards -x, so *forward is -x*)::

    x0 ---- x1 ---- x2 ====== r_i ---- p_i ~~~~~~~~~~~~~~~~~~~ tip_i      (i = 0 .. n-1)
    head    head    joint     plate    plate   elastic flagellum, length L
    front   centre  (plate    rim      socket
                    centre)

* ``x0 -> x1`` is the head body (the motor's stator), ``x1 -> x2`` the motor shaft (rotor), both of length R_h.
* ``x2 -> r_i`` is a radial plate arm of length R_d = L_p/2 at azimuth 2*pi*i/n.
* ``r_i -> p_i`` is a short rigid axial socket (the plate thickness) in which flagellum i is clamped. It makes the
  hinge at the flagellum base a *straight* hinge, so the clamp condition w'(0) = 0 is discretised exactly like an
  interior node (a 90-degree hinge there would be stiffer by sec^2(45 deg)^2 = 4 and bias the deflection by ~6%).
* ``p_i -> ... -> tip_i`` are the elastic flagellum edges.

The joint x2 carries n + 1 edges and one bend-twist hinge for every pair of them (paper Fig. simSchematic(c)).
Rest curvature is that of the undeformed geometry, so the 90-degree turns at x2 and r_i are natural.

The clamped-flagellum scene uses the same plate + flagellum with n = 1 and no head: its first nodes (x2, r, p)
and the plate's twist are driven by the clamp.

Every hinge has node triple (a, b, c) and edges (ea, eb) traversed a->b->c; ``hinge_sign`` says whether each edge's
own direction agrees with the traversal (+1) or not (-1), so any pair of edges at a node can form a hinge.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: the Newton tolerance is never below this many round-offs of the residual (:meth:`RodNetwork.residual_roundoff`):
#: a converged residual sums many terms of that size, and asking for less only burns iterations
NEWTON_ROUNDOFFS = 64.0


@dataclass
class RodNetwork:
    nodes: np.ndarray                 # (N, 3) undeformed node positions (m)
    edges: np.ndarray                 # (Ne, 2) node indices, edge k runs edges[k,0] -> edges[k,1]
    edge_rest_length: np.ndarray      # (Ne,)
    EA: np.ndarray                    # (Ne,) stretching stiffness (N)
    hinge_nodes: np.ndarray           # (H, 3)
    hinge_edges: np.ndarray           # (H, 2)
    hinge_sign: np.ndarray            # (H, 2) +1/-1
    EI: np.ndarray                    # (H,) bending stiffness (N m^2)
    GJ: np.ndarray                    # (H,) twisting stiffness (N m^2)
    voronoi: np.ndarray               # (H,) Voronoi length of the hinge (m)
    node_mass: np.ndarray             # (N,) lumped mass (kg)
    edge_inertia: np.ndarray          # (Ne,) rotational inertia about the edge tangent (kg m^2)
    edge_elastic: np.ndarray          # (Ne,) bool: True for flagellum edges, False for rigid parts
    # labels
    head_nodes: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # x0, x1, x2 (empty w/o head)
    joint_node: int = -1
    head_edge: int = -1               # x0 -> x1 (stator)
    shaft_edge: int = -1              # x1 -> x2 (rotor)
    motor_hinge: int = -1             # hinge at x1 (the motor)
    plate_edges: np.ndarray = field(default_factory=lambda: np.zeros(0, int))   # x2 -> r_i
    socket_edges: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # r_i -> p_i
    flagella_nodes: list = field(default_factory=list)   # per flagellum: node indices p_i .. tip_i
    flagella_edges: list = field(default_factory=list)   # per flagellum: edge indices
    flagellum_voronoi: list = field(default_factory=list)  # per flagellum: node Voronoi lengths (m)

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    def residual_roundoff(self) -> tuple[float, int]:
        """(N, edge): the round-off of the residual's largest term and the edge it comes from. A relative error of
        machine epsilon in a node coordinate (at most the largest one, |x|max) changes an edge's strain by
        eps |x|max / L_rest and its stretching force by EA times that: the stiffest spring's is the largest, and
        no residual can be resolved below it."""
        scale = self.EA * np.abs(self.nodes).max() / self.edge_rest_length
        k = int(np.argmax(scale))
        return float(np.finfo(float).eps * scale[k]), k

    @property
    def n_edges(self) -> int:
        return len(self.edges)

    @property
    def n_hinges(self) -> int:
        return len(self.hinge_nodes)

    @property
    def ndof(self) -> int:
        return 3 * self.n_nodes + self.n_edges

    def node_dofs(self, nodes) -> np.ndarray:
        """DOF indices (..., 3) of node positions."""
        nodes = np.asarray(nodes)
        return 3 * nodes[..., None] + np.arange(3)

    def edge_dof(self, edges) -> np.ndarray:
        return 3 * self.n_nodes + np.asarray(edges)

    def initial_q(self) -> np.ndarray:
        q = np.zeros(self.ndof)
        q[: 3 * self.n_nodes] = self.nodes.ravel()
        return q


class _Builder:
    def __init__(self):
        self.nodes: list = []
        self.edges: list = []
        self.edge_props: list = []   # (EA, elastic, density*area or mass per length, inertia per length)
        self.hinges: list = []       # (a, b, c, ea, eb, sa, sb, EI, GJ, voronoi)

    def node(self, x) -> int:
        self.nodes.append(np.asarray(x, float))
        return len(self.nodes) - 1

    def edge(self, a: int, b: int, EA: float, elastic: bool, mass_per_length: float,
             inertia_per_length: float) -> int:
        self.edges.append((a, b))
        self.edge_props.append((EA, elastic, mass_per_length, inertia_per_length))
        return len(self.edges) - 1

    def hinge(self, ea: int, eb: int, EI: float, GJ: float, voronoi: float) -> int:
        """Hinge between two edges sharing a node; traversal goes through the shared node."""
        a0, a1 = self.edges[ea]
        b0, b1 = self.edges[eb]
        shared = set((a0, a1)) & set((b0, b1))
        if len(shared) != 1:
            raise ValueError(f"edges {ea} and {eb} do not share exactly one node")
        m = shared.pop()
        sa = 1 if a1 == m else -1       # edge a must arrive at m
        sb = 1 if b0 == m else -1       # edge b must leave m
        a = a0 if sa == 1 else a1
        c = b1 if sb == 1 else b0
        self.hinges.append((a, m, c, ea, eb, sa, sb, EI, GJ, voronoi))
        return len(self.hinges) - 1


def flagellum_edge_count(length: float, edge_length: float) -> int:
    """Edges of a flagellum of ``length`` whose target edge length is ``edge_length``: the nearest whole number,
    at least one (the edges are then L / count long)."""
    return max(1, int(round(length / edge_length)))


def helix_angle(radius: float, pitch: float) -> float:
    """Pitch angle theta (rad) between the tangent and the axis of a helix of ``radius`` advancing |``pitch``|
    per turn: tan(theta) = 2 pi R / |P| (0 for a straight flagellum, pitch = 0)."""
    return 0.0 if pitch == 0.0 else math.atan2(2.0 * math.pi * radius, abs(pitch))


def flagellum_centreline(s: np.ndarray, phi: float, radius: float, pitch: float) -> tuple[np.ndarray, np.ndarray]:
    """The rest centreline of a flagellum attached at azimuth ``phi`` and distance ``radius`` from the robot axis
    (x), at arc lengths ``s`` (m) from its base, and its unit tangent at the base: (len(s), 3), (3,).

    ``pitch`` = 0: straight along +x. Otherwise a helix coaxial with the robot through the attachment point,
    advancing |pitch| along +x per turn; pitch > 0 is right-handed (the azimuth grows with x), pitch < 0
    left-handed: x = s cos(theta), azimuth phi + sign(P) s sin(theta) / R, theta = :func:`helix_angle`. The
    nodes lie exactly on it, so the rod's rest curvature and twist (computed from the nodes and frames by
    :class:`~.elastic.ElasticModel`) are the discrete helix's."""
    s = np.asarray(s, float)
    if pitch == 0.0:
        out = np.zeros((len(s), 3))
        out[:, 0] = s
        out[:, 1] = radius * math.cos(phi)
        out[:, 2] = radius * math.sin(phi)
        return out, np.array([1.0, 0.0, 0.0])
    th = helix_angle(radius, pitch)
    chi = math.copysign(1.0, pitch)
    psi = phi + chi * s * math.sin(th) / radius
    out = np.stack([s * math.cos(th), radius * np.cos(psi), radius * np.sin(psi)], axis=1)
    t0 = np.array([math.cos(th), -chi * math.sin(th) * math.sin(phi), chi * math.sin(th) * math.cos(phi)])
    return out, t0


def section(flagellum) -> tuple[float, float, float]:
    """Area, second moment and polar moment A, I, J (m^2, m^4, m^4) of the flagellum's solid circular section
    (radius r0): the one home of these formulas, for the rod's springs and masses and for every scale measured
    against them (physics/medium.py's EI)."""
    r0 = flagellum.radius
    return math.pi * r0 ** 2, math.pi / 4.0 * r0 ** 4, math.pi / 2.0 * r0 ** 4


def build_network(scene) -> RodNetwork:
    """Build the robot (or, for a clamp scene, the driven plate + one flagellum) described by ``scene``."""
    fl = scene.flagellum
    E = fl.youngs_modulus
    G = E / (2.0 * (1.0 + fl.poisson_ratio))
    r0 = fl.radius
    A, I, J = section(fl)
    EA, EI, GJ = E * A, E * I, G * J
    rf = scene.numerics.rigid_factor
    rho = fl.density
    L = fl.length
    n_seg = flagellum_edge_count(L, fl.edge_length)
    ds = L / n_seg
    R_d = scene.R_d
    R_h = scene.head.radius
    s_len = scene.plate.thickness
    with_head = not scene.clamped
    n = scene.robot.n_flagella

    # rigid parts get the flagellum's stiffness times rigid_factor: stiff enough that their strain is
    # 1/rigid_factor of the flagellum's, mild enough that the Jacobian keeps a sane condition number.
    rEA, rEI, rGJ = rf * EA, rf * EI, rf * GJ
    rod_m, rod_j = rho * A, rho * J                     # mass and rotational inertia per length of flagellum
    head_m = rho * 4.0 / 3.0 * math.pi * R_h ** 3      # the head as a solid sphere
    head_j = 0.4 * head_m * R_h ** 2

    b = _Builder()
    net_labels: dict = {}
    x_plate = -s_len   # plate (joint and arms) sits one socket length behind the flagellum bases at x = 0
    if with_head:
        x0 = b.node((x_plate - 2.0 * R_h, 0.0, 0.0))
        x1 = b.node((x_plate - R_h, 0.0, 0.0))
        x2 = b.node((x_plate, 0.0, 0.0))
        # head edges carry the head's mass/inertia spread over their length (set per node below)
        e_head = b.edge(x0, x1, rEA, False, 0.0, head_j / (2.0 * R_h))
        e_shaft = b.edge(x1, x2, rEA, False, 0.0, head_j / (2.0 * R_h))
        h_motor = b.hinge(e_head, e_shaft, rEI, rGJ, R_h)
        net_labels.update(head_nodes=np.array([x0, x1, x2]), joint_node=x2, head_edge=e_head,
                          shaft_edge=e_shaft, motor_hinge=h_motor)
    else:
        x2 = b.node((x_plate, 0.0, 0.0))
        net_labels.update(joint_node=x2)

    plate_edges, socket_edges, fl_nodes, fl_edges, fl_vor = [], [], [], [], []
    pitch = fl.helix_pitch
    for i in range(n):
        phi = 2.0 * math.pi * i / n
        centre, t0 = flagellum_centreline(np.arange(n_seg + 1) * ds, phi, R_d, pitch)
        # the socket points along the flagellum's base tangent (+x when straight: the rim node r_i is then on the
        # plate, x = x_plate), so the base hinge stays a (nearly) straight one
        r = b.node(centre[0] - s_len * t0)
        p = b.node(centre[0])
        e_arm = b.edge(x2, r, rEA, False, rod_m, rod_j)
        e_sock = b.edge(r, p, rEA, False, rod_m, rod_j)
        plate_edges.append(e_arm)
        socket_edges.append(e_sock)
        b.hinge(e_arm, e_sock, rEI, rGJ, 0.5 * (R_d + s_len))
        nodes_i = [p]
        edges_i = []
        prev_edge = e_sock
        for k in range(1, n_seg + 1):
            nk = b.node(centre[k])
            ek = b.edge(nodes_i[-1], nk, EA, True, rod_m, rod_j)
            # Voronoi length counts elastic edges only: the base hinge represents the half cell [0, ds/2]
            vor = 0.5 * ds if k == 1 else ds
            b.hinge(prev_edge, ek, EI, GJ, vor)
            nodes_i.append(nk)
            edges_i.append(ek)
            prev_edge = ek
        fl_nodes.append(np.array(nodes_i))
        fl_edges.append(np.array(edges_i))
        vor_nodes = np.full(n_seg + 1, ds)
        vor_nodes[0] = vor_nodes[-1] = 0.5 * ds
        fl_vor.append(vor_nodes)

    # joint hinges: one for every pair of edges meeting at x2
    joint_edges = ([net_labels["shaft_edge"]] if with_head else []) + plate_edges
    for ia in range(len(joint_edges)):
        for ib in range(ia + 1, len(joint_edges)):
            ea, eb = joint_edges[ia], joint_edges[ib]
            la = 2 * R_h if (with_head and ia == 0) else R_d
            b.hinge(ea, eb, rEI, rGJ, 0.5 * (la + R_d))

    nodes = np.array(b.nodes)
    edges = np.array(b.edges, dtype=np.int64)
    rest = np.linalg.norm(nodes[edges[:, 1]] - nodes[edges[:, 0]], axis=1)
    props = b.edge_props
    node_mass = np.zeros(len(nodes))
    edge_inertia = np.zeros(len(edges))
    for k, (e_a, e_b) in enumerate(edges):
        _, _, m_per_l, j_per_l = props[k]
        node_mass[e_a] += 0.5 * m_per_l * rest[k]
        node_mass[e_b] += 0.5 * m_per_l * rest[k]
        edge_inertia[k] = j_per_l * rest[k]
    if with_head:
        node_mass[net_labels["head_nodes"]] += head_m / 3.0
    H = np.array(b.hinges, dtype=object)
    net = RodNetwork(
        nodes=nodes, edges=edges, edge_rest_length=rest,
        EA=np.array([p[0] for p in props], float),
        hinge_nodes=H[:, 0:3].astype(np.int64), hinge_edges=H[:, 3:5].astype(np.int64),
        hinge_sign=H[:, 5:7].astype(np.float64),
        EI=H[:, 7].astype(float), GJ=H[:, 8].astype(float), voronoi=H[:, 9].astype(float),
        node_mass=node_mass, edge_inertia=edge_inertia,
        edge_elastic=np.array([p[1] for p in props], bool),
        plate_edges=np.array(plate_edges), socket_edges=np.array(socket_edges),
        flagella_nodes=fl_nodes, flagella_edges=fl_edges, flagellum_voronoi=fl_vor,
        **net_labels,
    )
    return net
