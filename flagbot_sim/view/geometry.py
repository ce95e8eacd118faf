"""The robot's drawable shape at one instant, in the fixed frame ``world``: what the live view and the renders draw.

One :class:`RobotGeometry` holds the node positions that matter for a picture (each flagellum's centreline, the
head centre and body frame, the plate arms) plus the true sizes (head radius, flagellum radius, plate radius and
thickness). It comes either from a running :class:`~flagbot_sim.physics.Simulation`
(:meth:`RobotGeometry.from_simulation`) or from a recorded ``markers`` MarkerArray plus ``head_pose``
(:meth:`RobotGeometry.from_markers`), so a live run, a recording and a figure draw exactly the same numbers.

Frame: ``world`` (flagbot_sim/world.py): REP 103, x forward (the robot swims along +x), origin at the head centre at
rest. Pure numpy: no ROS, no Foxglove, no matplotlib.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .. import world


@dataclass
class RobotGeometry:
    t: float                                  # simulated time (s)
    flagella: list                            # per flagellum: (m, 3) centreline nodes, base first (m)
    plate_arms: list                          # per flagellum: (3, 3) joint x2, rim r_i, socket p_i (m)
    flagellum_radius: float                   # r0 (m)
    head_radius: float = 0.0                  # R_h (m); 0 without a head (clamped flagellum)
    head_centre: np.ndarray | None = None     # x1 (m)
    head_rotation: np.ndarray | None = None   # head body frame (x forward) in world: columns x, y, z
    values: dict = field(default_factory=dict)   # the numbers of that instant (omega_T, omega_h, ... SI units)

    # ------------------------------------------------------------------------------------------ derived
    @property
    def n(self) -> int:
        return len(self.flagella)

    @property
    def joint(self) -> np.ndarray:
        """The plate centre x2 (where the shaft meets the plate)."""
        return np.asarray(self.plate_arms[0][0]) if self.plate_arms else np.asarray(self.flagella[0][0])

    @property
    def plate_radius(self) -> float:
        """R_d: the distance from the plate centre to the flagella's rim points."""
        return float(np.mean([np.linalg.norm(a[1] - a[0]) for a in self.plate_arms])) if self.plate_arms else 0.0

    @property
    def plate_thickness(self) -> float:
        return float(np.mean([np.linalg.norm(a[2] - a[1]) for a in self.plate_arms])) if self.plate_arms else 0.0

    @property
    def tail_axis(self) -> np.ndarray:
        """Unit robot axis pointing from the head towards the flagella (the sockets' direction; -x at rest)."""
        if self.plate_arms:
            d = np.mean([a[2] - a[1] for a in self.plate_arms], axis=0)
            if np.linalg.norm(d) > 0:
                return d / np.linalg.norm(d)
        if self.head_rotation is not None:
            return -self.head_rotation[:, 0]
        return np.array([-1.0, 0.0, 0.0])

    @property
    def plate_frame(self) -> np.ndarray:
        """Rotation (columns e1, e2, axis) of the plate: axis = :attr:`tail_axis`, e1 towards the first rim point."""
        a = self.tail_axis
        r = (self.plate_arms[0][1] - self.plate_arms[0][0]) if self.plate_arms else _any_normal(a)
        r = r - np.dot(r, a) * a
        r = r / np.linalg.norm(r) if np.linalg.norm(r) > 0 else _any_normal(a)
        return np.column_stack([r, np.cross(a, r), a])

    @property
    def tips(self) -> np.ndarray:
        """(n, 3) flagellum tips."""
        return np.array([f[-1] for f in self.flagella])

    def points(self) -> np.ndarray:
        """Every drawn point (for extents): nodes, head extremes, plate rims."""
        pts = [np.asarray(f) for f in self.flagella] + [np.asarray(a) for a in self.plate_arms]
        if self.head_centre is not None:
            pts.append(self.head_centre + self.head_radius * np.vstack([np.eye(3), -np.eye(3)]))
        return np.vstack(pts)

    # ------------------------------------------------------------------------------------------ sources
    @classmethod
    def from_simulation(cls, sim, snapshot=None) -> "RobotGeometry":
        """The shape of ``sim`` now (its node positions turned into the world frame, as sim_node's markers)."""
        o = sim.observer.origin
        rigid = sim.rigid_polylines()
        head = rigid.get("head")
        rot = None
        if head is not None:
            rot = world.head_rotation_world(sim.observer.head_orientation(sim.state))
        snap = snapshot if snapshot is not None else sim.snapshot()
        return cls(t=float(sim.time), flagella=[world.to_world(c, o) for c in sim.flagella_centrelines()],
                   plate_arms=[world.to_world(a, o) for a in rigid["plate"]],
                   flagellum_radius=float(sim.scene.flagellum.radius),
                   head_radius=float(sim.scene.head.radius) if head is not None else 0.0,
                   head_centre=world.to_world(head[1], o) if head is not None else None,
                   head_rotation=rot, values=snapshot_values(snap))

    @classmethod
    def from_markers(cls, markers, t: float | None = None, orientation=None, values: dict | None = None
                     ) -> "RobotGeometry":
        """From a recorded ``markers`` MarkerArray (flagellum LINE_STRIPs, head SPHERE, plate LINE_LIST of arm and
        socket segments; see ros/convert.py markers_msg) and optionally the ``head_pose`` orientation (x, y, z, w)
        of the same instant. ``t`` defaults to the markers' header stamp."""
        flagella, arm_points, head_centre, head_radius, radius = {}, [], None, 0.0, None
        stamp = None
        for m in markers.markers:
            stamp = m.header.stamp if stamp is None else stamp
            pts = np.array([[p.x, p.y, p.z] for p in m.points], float).reshape(-1, 3)
            if m.ns == "flagella":
                flagella[m.id] = pts
                radius = 0.5 * float(m.scale.x)
            elif m.ns == "head":
                head_centre = np.array([m.pose.position.x, m.pose.position.y, m.pose.position.z])
                head_radius = 0.5 * float(m.scale.x)
            elif m.ns == "plate":
                arm_points = pts
        if not flagella:
            raise ValueError("the MarkerArray holds no 'flagella' marker: not a flagbot_sim markers message")
        # the plate LINE_LIST is, per arm, the segments joint->rim and rim->socket
        arms = [np.array([arm_points[k], arm_points[k + 1], arm_points[k + 3]])
                for k in range(0, len(arm_points) - 3, 4)]
        rot = quaternion_to_matrix(orientation) if orientation is not None and head_centre is not None else None
        if t is None:
            t = stamp.sec + 1e-9 * stamp.nanosec if stamp is not None else 0.0
        return cls(t=float(t), flagella=[flagella[k] for k in sorted(flagella)], plate_arms=arms,
                   flagellum_radius=radius, head_radius=head_radius, head_centre=head_centre, head_rotation=rot,
                   values=dict(values or {}))


#: the numbers every view shows, in this order (SI units: rad/s, m/s, N m, s, rad)
VALUE_KEYS = ("t", "omega_T", "omega_h", "omega_t", "v", "motor_torque", "phi_h", "phi_t", "drive_angle")


def snapshot_values(snap) -> dict:
    """The plotted numbers of a :class:`~flagbot_sim.physics.observe.Snapshot` (plain floats)."""
    out = {k: float(getattr(snap, k)) for k in VALUE_KEYS}
    out["x"] = float(snap.position[0])
    return out


def quaternion_to_matrix(q) -> np.ndarray:
    """Rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = (float(c) for c in q)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    return world.quaternion_matrix(x / n, y / n, z / n, w / n)


def _any_normal(a: np.ndarray) -> np.ndarray:
    e = np.eye(3)[int(np.argmin(np.abs(a)))]
    v = e - np.dot(e, a) * a
    return v / np.linalg.norm(v)
