"""Foxglove messages of the robot: the 3-D scene, the head's transform, the plotted numbers.

Built from a :class:`~flagbot_sim.view.geometry.RobotGeometry` (a running simulation's or a recording's), all in
the fixed frame ``world`` (REP 103, x forward, origin at the head centre at rest; SI units):

* :func:`scene_update`: a ``foxglove.SceneUpdate`` with one entity per part, each replacing its previous version
  (same id, no lifetime): ``head`` (a sphere of radius R_h posed with the head's body frame, and a small black
  marker on its surface so that the head's spin shows, as on the real robot), ``plate`` (a disc of radius R_d and
  the plate's thickness on the robot axis), ``flagellum/<i>`` (a line strip through the flagellum's nodes whose
  thickness is the flagellum's true diameter 2 r0; flagellum 0 carries a red tip marker, as in the experiments);
* :func:`tube_update`: the granular medium's container, the paper's acrylic tube (inner radius 53 mm, 1220 mm
  long, the robot starting near one end), drawn translucent for context: the simulated medium has no wall;
* :func:`frame_transforms`: ``foxglove.FrameTransforms`` world -> head (the head body frame: x forward);
* :func:`state_message`: the plotted numbers (omega_T, omega_h, omega_t, v, motor torque, ...) as strict JSON,
  with :data:`STATE_SCHEMA` as its JSON schema.

Needs the ``[view]`` extra (foxglove-sdk): :func:`flagbot_sim.optional.require` names it when missing.
"""
from __future__ import annotations

import math

import numpy as np

from ..cliutil import dumps
from ..optional import require
from .geometry import RobotGeometry

fg = require("view", "the Foxglove live view", "foxglove.messages")
from foxglove.messages import (Color, CylinderPrimitive, FrameTransform, FrameTransforms,  # noqa: E402
                               LinePrimitive, LinePrimitiveLineType, Point3, Pose, Quaternion, SceneEntity,
                               SceneUpdate, SpherePrimitive, Timestamp, Vector3)

from ..physics.observe import quaternion_from_matrix  # noqa: E402

HEAD_COLOUR = (0.95, 0.80, 0.10, 1.0)       # the yellow head of the paper's robot
MARKER_COLOUR = (0.05, 0.05, 0.05, 1.0)     # its black spin marker
FLAGELLUM_COLOUR = (0.08, 0.42, 0.20, 1.0)  # dark green silicone flagella
TIP_COLOUR = (0.85, 0.10, 0.10, 1.0)        # the red marker on one flagellum
PLATE_COLOUR = (0.55, 0.55, 0.58, 1.0)
TUBE_COLOUR = (0.55, 0.75, 1.0, 0.10)

#: the paper's container (section "Experiments"): inner radius 53 mm, axial length 1220 mm
TUBE_RADIUS = 0.053
TUBE_LENGTH = 1.22
#: where the tube begins behind the robot's start (m, along -x): the robot starts at one end of the tube
TUBE_START = -0.25

#: JSON schema of :func:`state_message` (every value SI; the unit is in each description)
STATE_SCHEMA = {
    "title": "flagbot_sim.State",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "simulated time (s)"},
        "omega_T": {"type": "number", "description": "motor command in force (rad/s)"},
        "omega_h": {"type": "number", "description": "head spin rate over the last step (rad/s)"},
        "omega_t": {"type": "number", "description": "flagella spin rate over the last step (rad/s)"},
        "v": {"type": "number", "description": "forward speed over the last step (m/s, positive = head first)"},
        "motor_torque": {"type": "number", "description": "motor torque on the shaft (N m)"},
        "phi_h": {"type": "number", "description": "accumulated head spin angle (rad)"},
        "phi_t": {"type": "number", "description": "accumulated flagella spin angle (rad)"},
        "drive_angle": {"type": "number", "description": "integrated motor command (rad)"},
        "x": {"type": "number", "description": "head centre position along the world x axis (m)"},
    },
}


def stamp(t: float) -> Timestamp:
    sec = math.floor(t)
    nsec = int(round((t - sec) * 1e9))
    if nsec >= 1_000_000_000:
        sec, nsec = sec + 1, nsec - 1_000_000_000
    return Timestamp(int(sec), nsec)


def _colour(c) -> Color:
    return Color(r=c[0], g=c[1], b=c[2], a=c[3])


def _vec(p) -> Vector3:
    return Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _quat(q) -> Quaternion:
    return Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))


def _pose(position, R=None) -> Pose:
    q = quaternion_from_matrix(R) if R is not None else (0.0, 0.0, 0.0, 1.0)
    return Pose(position=_vec(position), orientation=_quat(q))


def _sphere(centre, diameter: float, colour, R=None) -> SpherePrimitive:
    return SpherePrimitive(pose=_pose(centre, R), size=Vector3(x=diameter, y=diameter, z=diameter),
                           color=_colour(colour))


def is_finite(geom: RobotGeometry) -> bool:
    """Whether every drawn number is finite (nothing non-finite is ever published)."""
    return bool(np.all(np.isfinite(geom.points())))


def scene_update(geom: RobotGeometry, frame: str = "world") -> SceneUpdate:
    """The robot at ``geom.t`` as one SceneUpdate (see the module docstring for the entities)."""
    ts = stamp(geom.t)
    entities = []
    if geom.head_centre is not None:
        R = geom.head_rotation if geom.head_rotation is not None else np.eye(3)
        d = 2.0 * geom.head_radius
        marker = geom.head_centre + geom.head_radius * R[:, 2]       # on the body z axis: turns with the head
        entities.append(SceneEntity(timestamp=ts, frame_id=frame, id="head", spheres=[
            _sphere(geom.head_centre, d, HEAD_COLOUR, R), _sphere(marker, 0.25 * d, MARKER_COLOUR)]))
    if geom.plate_arms:
        P = geom.plate_frame
        centre = geom.joint + 0.5 * geom.plate_thickness * P[:, 2]
        d = 2.0 * geom.plate_radius
        entities.append(SceneEntity(timestamp=ts, frame_id=frame, id="plate", cylinders=[
            CylinderPrimitive(pose=_pose(centre, P), size=Vector3(x=d, y=d, z=max(geom.plate_thickness, 1e-4)),
                              bottom_scale=1.0, top_scale=1.0, color=_colour(PLATE_COLOUR))]))
    width = 2.0 * geom.flagellum_radius
    for i, nodes in enumerate(geom.flagella):
        spheres = [_sphere(nodes[-1], 1.3 * width, TIP_COLOUR)] if i == 0 else []
        entities.append(SceneEntity(timestamp=ts, frame_id=frame, id=f"flagellum/{i}", spheres=spheres, lines=[
            LinePrimitive(type=LinePrimitiveLineType.LineStrip, pose=_pose((0.0, 0.0, 0.0)), thickness=width,
                          scale_invariant=False, points=[Point3(x=float(p[0]), y=float(p[1]), z=float(p[2]))
                                                         for p in nodes],
                          color=_colour(FLAGELLUM_COLOUR))]))
    return SceneUpdate(entities=entities)


def tube_update(t: float = 0.0, frame: str = "world", radius: float = TUBE_RADIUS,
                length: float = TUBE_LENGTH, start: float = TUBE_START) -> SceneUpdate:
    """The container tube along the world x axis, from x = ``start`` for ``length`` metres (context only)."""
    # the cylinder's own axis is z: turn it onto x (a quarter turn about y)
    q = (0.0, math.sin(math.pi / 4), 0.0, math.cos(math.pi / 4))
    d = 2.0 * radius
    return SceneUpdate(entities=[SceneEntity(timestamp=stamp(t), frame_id=frame, id="tube", cylinders=[
        CylinderPrimitive(pose=Pose(position=Vector3(x=start + 0.5 * length, y=0.0, z=0.0), orientation=_quat(q)),
                          size=Vector3(x=d, y=d, z=length), bottom_scale=1.0, top_scale=1.0,
                          color=_colour(TUBE_COLOUR))])])


def frame_transforms(geom: RobotGeometry, frame: str = "world", child: str = "head") -> FrameTransforms | None:
    """world -> head (translation = head centre, rotation = head body frame); None without a head."""
    if geom.head_centre is None or geom.head_rotation is None:
        return None
    return FrameTransforms(transforms=[FrameTransform(
        timestamp=stamp(geom.t), parent_frame_id=frame, child_frame_id=child, translation=_vec(geom.head_centre),
        rotation=_quat(quaternion_from_matrix(geom.head_rotation)))])


def state_message(values: dict) -> str:
    """The numbers of :data:`STATE_SCHEMA` that ``values`` has, as strict JSON (a non-finite value -> null)."""
    return dumps({k: values[k] for k in STATE_SCHEMA["properties"] if k in values})
