"""The fixed frame the ROS layer publishes in, as pure numpy (no ROS import: the re-simulator uses it too).

The fixed frame is the simulation frame turned by pi about z and centred on the head centre at rest, so that the
robot starts at the origin facing +x and swims along +x (REP 103). The head body frame has x forward.
"""
from __future__ import annotations

import numpy as np

#: simulation frame -> fixed frame (rotation by pi about z)
WORLD_FROM_SIM = np.diag([-1.0, -1.0, 1.0])
#: head body frame (x forward) from the head edge's material frame (t, m1, m2): (-t, -m1, m2)
BODY_FROM_MATERIAL = np.diag([-1.0, -1.0, 1.0])


def to_world(points: np.ndarray, origin=np.zeros(3)) -> np.ndarray:
    """Simulation-frame points in the fixed frame, whose origin is ``origin`` (the head centre at rest)."""
    return (np.asarray(points) - origin) @ WORLD_FROM_SIM.T


def head_rotation_world(material: np.ndarray) -> np.ndarray:
    """Rotation of the head body frame in the fixed frame, from the head edge's material frame columns."""
    return WORLD_FROM_SIM @ material @ BODY_FROM_MATERIAL


def quaternion_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """Rotation matrix of the unit quaternion (x, y, z, w) (ROS order)."""
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
