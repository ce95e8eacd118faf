"""A URDF's kinematic tree as transforms, the way robot_state_publisher turns it into TF. No ROS import.

:class:`TfTree` reads the joints of a URDF (``robot_description``): each joint is a transform from its parent link
to its child link, the joint's ``origin`` (xyz, then roll-pitch-yaw about the fixed x, y, z axes) followed by its
motion along or about ``axis`` (default 1 0 0). Fixed joints give :meth:`TfTree.static_transforms` (/tf_static,
sent once, latched); revolute, continuous and prismatic joints give :meth:`TfTree.joint_transforms` from the
positions of ``sensor_msgs/JointState`` (/tf, each time joint states arrive). Floating and planar joints have no
single position and, like robot_state_publisher, are left to whoever publishes them. The fixed frame's link to the
tree root (world -> head) comes from the head pose (:func:`pose_transform`).
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Iterable, Sequence

from .bag.tf import Transform

MOVING = ("revolute", "continuous", "prismatic")
_KNOWN = ("fixed", "floating", "planar") + MOVING


class UrdfError(ValueError):
    """The text is not a URDF tree this reader understands."""


def quat_multiply(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float, float]:
    """a * b for quaternions x, y, z, w (b applied first)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def quat_from_rpy(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """URDF's rpy: roll about x, then pitch about y, then yaw about z, all fixed axes (R = Rz Ry Rx)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy)


def quat_about(axis: Sequence[float], angle: float) -> tuple[float, float, float, float]:
    s = math.sin(angle / 2)
    return (axis[0] * s, axis[1] * s, axis[2] * s, math.cos(angle / 2))


def rotate(q: Sequence[float], v: Sequence[float]) -> tuple[float, float, float]:
    x, y, z, _ = quat_multiply(quat_multiply(q, (v[0], v[1], v[2], 0.0)), (-q[0], -q[1], -q[2], q[3]))
    return (x, y, z)


def _floats(text: str | None, n: int, default: tuple, what: str) -> tuple:
    if text is None:
        return default
    try:
        values = tuple(float(v) for v in text.split())
    except ValueError:
        values = ()
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise UrdfError(f"{what}: expected {n} finite numbers, got {text!r}")
    return values


@dataclass(frozen=True)
class Joint:
    name: str
    type: str
    parent: str
    child: str
    xyz: tuple[float, float, float]
    rotation: tuple[float, float, float, float]     # of the origin's rpy
    axis: tuple[float, float, float]                # unit vector

    def transform(self, stamp_ns: int, position: float = 0.0) -> Transform:
        """Parent -> child at joint ``position`` (rad or m)."""
        xyz, rot = self.xyz, self.rotation
        if self.type in ("revolute", "continuous"):
            rot = quat_multiply(rot, quat_about(self.axis, position))
        elif self.type == "prismatic":
            d = rotate(rot, self.axis)
            xyz = (xyz[0] + position * d[0], xyz[1] + position * d[1], xyz[2] + position * d[2])
        return Transform(stamp_ns, self.parent, self.child, xyz, rot)


class TfTree:
    """The joints of a URDF text. UrdfError if it is not XML with a ``robot`` root whose joints name their links."""

    def __init__(self, urdf: str):
        try:
            root = ET.fromstring(urdf)
        except ET.ParseError as exc:
            raise UrdfError(f"not XML: {exc}") from None
        if root.tag != "robot":
            raise UrdfError(f"the root element is <{root.tag}>, not <robot>")
        self.links = [link.get("name") for link in root.findall("link")]
        self.joints: list[Joint] = []
        for j in root.findall("joint"):
            name, kind = j.get("name"), j.get("type")
            parent, child = j.find("parent"), j.find("child")
            if not name or kind not in _KNOWN or parent is None or child is None:
                raise UrdfError(f"joint {name!r}: needs a name, a known type (not {kind!r}), a parent and a child")
            origin = j.find("origin")
            xyz = _floats(origin.get("xyz") if origin is not None else None, 3, (0.0, 0.0, 0.0), f"{name} origin xyz")
            rpy = _floats(origin.get("rpy") if origin is not None else None, 3, (0.0, 0.0, 0.0), f"{name} origin rpy")
            axis_el = j.find("axis")
            axis = _floats(axis_el.get("xyz") if axis_el is not None else None, 3, (1.0, 0.0, 0.0), f"{name} axis")
            norm = math.sqrt(sum(a * a for a in axis))
            if kind in MOVING and norm == 0.0:
                raise UrdfError(f"joint {name}: axis is zero")
            axis = tuple(a / norm for a in axis) if norm else axis
            self.joints.append(Joint(name, kind, parent.get("link"), child.get("link"), xyz, quat_from_rpy(*rpy),
                                     axis))
        children = [j.child for j in self.joints]
        roots = [link for link in self.links if link not in children]
        self.root = roots[0] if len(roots) == 1 else None
        self._moving = {j.name: j for j in self.joints if j.type in MOVING}

    @property
    def moving_joints(self) -> list[str]:
        return list(self._moving)

    def static_transforms(self, stamp_ns: int) -> list[Transform]:
        """Every fixed joint, parent -> child (robot_state_publisher's /tf_static)."""
        return [j.transform(stamp_ns) for j in self.joints if j.type == "fixed"]

    def joint_transforms(self, stamp_ns: int, names: Iterable[str], positions: Sequence[float]) -> list[Transform]:
        """The moving joints among ``names`` at ``positions`` (robot_state_publisher's /tf for one joint state);
        names the URDF does not have are ignored."""
        out = []
        for name, q in zip(names, positions):
            j = self._moving.get(name)
            if j is not None and math.isfinite(q):
                out.append(j.transform(stamp_ns, float(q)))
        return out


def pose_transform(stamp_ns: int, parent: str, child: str, position: Sequence[float],
                   orientation: Sequence[float]) -> Transform:
    """The transform of a pose (head_pose, odometry): ``child`` placed at ``position`` with ``orientation``
    (x, y, z, w) in ``parent``."""
    return Transform(stamp_ns, parent, child, tuple(float(v) for v in position),
                     tuple(float(v) for v in orientation))


def stamp_ns_of(stamp) -> int:
    """builtin_interfaces/Time -> ns."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
