"""Simulation observations -> ROS messages. Pure functions: no node, no publishing.

Frames (REP 103, SI units): the fixed frame (parameter ``frame_id``, default ``world``) is the simulation frame
turned by pi about z and centred on the head centre at rest, so that the robot starts at the origin facing +x
and swims along +x. The head's body
frame (``child_frame_id``, default ``head``) has x pointing forward (towards the head's front), z along the
simulation's z at rest. Every stamp is simulation time, the same as /clock.
"""
from __future__ import annotations

import math

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion, Vector3
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import ColorRGBA, Float64, String
from visualization_msgs.msg import Marker, MarkerArray

from ..physics.observe import quaternion_from_matrix
from ..urdf import JOINT_NAMES as _URDF_JOINTS

#: joint_states names: the joints of the URDF on robot_description (flagbot_sim.urdf), in this order
JOINT_NAMES = list(_URDF_JOINTS)


def stamp(t: float) -> Time:
    sec = math.floor(t)
    nsec = int(round((t - sec) * 1e9))
    if nsec >= 1_000_000_000:
        sec, nsec = sec + 1, nsec - 1_000_000_000
    return Time(sec=int(sec), nanosec=nsec)


def _point(p) -> Point:
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _quat(q) -> Quaternion:
    return Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))


def clock_msg(t: float) -> Clock:
    return Clock(clock=stamp(t))


def float_msg(x: float) -> Float64:
    return Float64(data=float(x))


def pose_msg(t: float, frame: str, position_w, R_w) -> PoseStamped:
    m = PoseStamped()
    m.header.stamp = stamp(t)
    m.header.frame_id = frame
    m.pose.position = _point(position_w)
    m.pose.orientation = _quat(quaternion_from_matrix(R_w))
    return m


def odometry_msg(t: float, frame: str, child: str, pose: Pose, R_w, v_w, omega_w) -> Odometry:
    """Pose in the fixed frame; twist in the head body frame (linear.x = forward speed, angular.x = spin).

    ``pose`` is the head pose of the same instant, normally ``pose_msg(...).pose`` (used as is, not copied), and
    ``R_w`` its rotation matrix, which turns the world-frame velocities into the body frame.
    """
    m = Odometry()
    m.header.stamp = stamp(t)
    m.header.frame_id = frame
    m.child_frame_id = child
    m.pose.pose = pose
    vb = R_w.T @ np.asarray(v_w)
    wb = R_w.T @ np.asarray(omega_w)
    m.twist.twist.linear = Vector3(x=float(vb[0]), y=float(vb[1]), z=float(vb[2]))
    m.twist.twist.angular = Vector3(x=float(wb[0]), y=float(wb[1]), z=float(wb[2]))
    return m


def joint_state_msg(t: float, phi_h: float, phi_t: float, omega_h: float, omega_t: float, motor_angle: float,
                    omega_T: float, torque: float) -> JointState:
    """Head spin, flagella spin and the motor (rotor relative to stator): angle (rad), rate (rad/s), motor
    torque (N m). The motor joint's rate is the command in force, its angle the integrated command: a recording
    therefore pins every command change to a simulation step. Every array is filled."""
    m = JointState()
    m.header.stamp = stamp(t)
    m.name = list(JOINT_NAMES)
    m.position = [float(phi_h), float(phi_t), float(motor_angle)]
    m.velocity = [float(omega_h), float(omega_t), float(omega_T)]
    m.effort = [float(torque)] * 3
    return m


def _color(r, g, b, a=1.0) -> ColorRGBA:
    return ColorRGBA(r=float(r), g=float(g), b=float(b), a=float(a))


def markers_msg(t: float, frame: str, flagella_w: list, head_centre_w, head_radius: float, plate_w: list,
                rod_radius: float, delete_all_first: bool = False) -> MarkerArray:
    """One LINE_STRIP per flagellum, a SPHERE for the head, a LINE_LIST for the plate arms and sockets.

    ``delete_all_first``: begin with a DELETEALL marker (empty namespace: every marker of this array's
    publisher), for when the set of markers changed (fewer flagella, no head) and old ones would stay on screen.
    """
    arr = MarkerArray()
    st = stamp(t)
    if delete_all_first:
        arr.markers.append(delete_all_marker(t, frame))
    for i, line in enumerate(flagella_w):
        m = Marker(ns="flagella", id=i, type=Marker.LINE_STRIP, action=Marker.ADD)
        m.header.stamp = st
        m.header.frame_id = frame
        m.pose.orientation.w = 1.0
        m.scale.x = 2.0 * rod_radius
        m.color = _color(0.1, 0.55, 0.25)
        m.points = [_point(p) for p in line]
        arr.markers.append(m)
    if head_centre_w is not None:
        m = Marker(ns="head", id=0, type=Marker.SPHERE, action=Marker.ADD)
        m.header.stamp = st
        m.header.frame_id = frame
        m.pose.position = _point(head_centre_w)
        m.pose.orientation.w = 1.0
        m.scale.x = m.scale.y = m.scale.z = 2.0 * head_radius
        m.color = _color(0.95, 0.8, 0.1)
        arr.markers.append(m)
    m = Marker(ns="plate", id=0, type=Marker.LINE_LIST, action=Marker.ADD)
    m.header.stamp = st
    m.header.frame_id = frame
    m.pose.orientation.w = 1.0
    m.scale.x = 2.0 * rod_radius
    m.color = _color(0.3, 0.3, 0.3)
    for arm in plate_w:
        for a, b in zip(arm[:-1], arm[1:]):
            m.points += [_point(a), _point(b)]
    arr.markers.append(m)
    return arr


def delete_all_marker(t: float, frame: str) -> Marker:
    """DELETEALL with an empty namespace: removes every marker this publisher drew (RViz, Foxglove)."""
    m = Marker(ns="", id=0, action=Marker.DELETEALL)
    m.header.stamp = stamp(t)
    m.header.frame_id = frame
    m.pose.orientation.w = 1.0
    return m


def marker_ids(arr: MarkerArray) -> set[tuple[str, int]]:
    """The (namespace, id) of every marker an array adds."""
    return {(m.ns, m.id) for m in arr.markers if m.action == Marker.ADD}


def string_msg(text: str) -> String:
    return String(data=text)


LEVELS = {"OK": DiagnosticStatus.OK, "WARN": DiagnosticStatus.WARN, "ERROR": DiagnosticStatus.ERROR}


def diagnostics_msg(t: float, name: str, level: str, message: str, values: dict) -> DiagnosticArray:
    arr = DiagnosticArray()
    arr.header.stamp = stamp(t)
    s = DiagnosticStatus(level=LEVELS[level], name=name, message=message, hardware_id="flagbot_sim")
    s.values = [KeyValue(key=str(k), value=str(v)) for k, v in values.items()]
    arr.status = [s]
    return arr
