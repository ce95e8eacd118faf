"""Derived quantities: head pose, spin angles and rates, speed, flagellum centrelines, steady-state estimates.

Conventions (see docs/physics.md):

* the robot axis is a = unit(x2 - x0), +x in the undeformed robot; *forward* is -a (the head leads);
* ``omega_h`` is the head's spin rate about -a and ``omega_t`` the flagella's (shaft/plate) spin rate about +a,
  both in the lab frame. With a positive motor command both are positive and omega_h + omega_t = omega_T at
  steady state: head and flagella turn in opposite directions;
* ``v`` is the head-centre velocity along the forward direction (positive = head first).

Spin angles are accumulated step by step from the twist DOF increment plus the (small) rotation of the
time-parallel-transported reference frame about the axis, so they never alias, even at large dt.
"""
from __future__ import annotations

import math

import numpy as np

from .frames import material_frames, normalize, signed_angle
from .model import RobotModel, State


def quaternion_from_matrix(R: np.ndarray) -> np.ndarray:
    """(x, y, z, w) unit quaternion of a rotation matrix (Shepperd's method)."""
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s]
    q = np.array(q)
    return q / np.linalg.norm(q)


class Observer:
    """Accumulates spin angles and positions step by step; answers instantaneous and windowed rates."""

    def __init__(self, model: RobotModel, state: State):
        self.model = model
        self.net = model.net
        self.has_head = len(self.net.head_nodes) > 0
        self.clamped = model.scene.clamped
        self.reset(state)

    def reset(self, state: State) -> None:
        self.phi_h = 0.0
        self.phi_t = 0.0
        self.t = [state.t]
        self.hist_phi_h = [0.0]
        self.hist_phi_t = [0.0]
        self.hist_pos = [self.position(state).copy()]
        self.hist_tip = [self.corotating_tip(state)] if self.clamped else []
        self.rate_h = 0.0      # instantaneous (last step) rates, rad/s
        self.rate_t = 0.0
        self.speed = 0.0
        self.axis_now = self.axis(state)

    # ---------------------------------------------------------------- geometry of one state
    def x(self, state: State) -> np.ndarray:
        N = self.net.n_nodes
        return state.q[: 3 * N].reshape(N, 3)

    def axis(self, state: State) -> np.ndarray:
        """Unit robot axis a (head front -> joint); +x for the clamped scene."""
        if not self.has_head:
            return np.array([1.0, 0.0, 0.0])
        x = self.x(state)
        a, _ = normalize(x[self.net.head_nodes[2]] - x[self.net.head_nodes[0]])
        return a

    def position(self, state: State) -> np.ndarray:
        x = self.x(state)
        return x[self.net.head_nodes[1]] if self.has_head else x[self.net.joint_node]

    def _spin_increment(self, edge: int, old: State, new: State, axis: np.ndarray) -> float:
        k = 3 * self.net.n_nodes + edge
        dtheta = new.q[k] - old.q[k]
        dref = signed_angle(old.frames.d1[edge][None], new.frames.d1[edge][None], axis[None])[0]
        return float(dtheta + dref)

    def corotating_tip(self, state: State) -> np.ndarray:
        """Tip of the (first) flagellum in the frame turning with the clamp: clamp at (0, R_d, 0)."""
        phi = state.extras.get("clamp_angle", 0.0)
        c, s = math.cos(phi), math.sin(phi)
        R_inv = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])
        return R_inv @ self.x(state)[self.net.flagella_nodes[0][-1]]

    def head_orientation(self, state: State) -> np.ndarray:
        """Rotation matrix of the head body: columns (tangent, m1, m2) of the head edge's material frame."""
        if not self.has_head:
            return np.eye(3)
        e = self.net.head_edge
        fr = state.frames
        theta = state.q[3 * self.net.n_nodes + e]
        m1, m2 = material_frames(fr.d1[e][None], fr.d2[e][None], np.array([theta]))
        return np.column_stack([fr.t[e], m1[0], m2[0]])

    # ---------------------------------------------------------------- per step
    def record(self, old: State, new: State) -> None:
        dt = new.t - old.t
        a = self.axis(new)
        if self.has_head:
            dh = -self._spin_increment(self.net.head_edge, old, new, a)
            dtt = self._spin_increment(self.net.shaft_edge, old, new, a)
        elif self.clamped:
            dh = 0.0
            dtt = new.extras["clamp_angle"] - old.extras["clamp_angle"]
        else:
            dh = dtt = 0.0
        self.phi_h += dh
        self.phi_t += dtt
        pos = self.position(new).copy()
        self.rate_h = dh / dt
        self.rate_t = dtt / dt
        self.speed = float(np.dot(pos - self.hist_pos[-1], -a)) / dt
        self.axis_now = a
        self.t.append(new.t)
        self.hist_phi_h.append(self.phi_h)
        self.hist_phi_t.append(self.phi_t)
        self.hist_pos.append(pos)
        if self.clamped:
            self.hist_tip.append(self.corotating_tip(new))

    # ---------------------------------------------------------------- windows
    def window_rates(self, window: float, end_time: float | None = None) -> dict | None:
        """Mean omega_h, omega_t, v over [end - window, end]; None if the history is shorter than the window."""
        t = np.asarray(self.t)
        t_end = t[-1] if end_time is None else end_time
        i1 = int(np.searchsorted(t, t_end, side="right") - 1)
        i0 = int(np.searchsorted(t, t[i1] - window * (1 - 1e-9), side="right") - 1)
        if i0 < 0 or t[i1] - t[max(i0, 0)] < 0.999 * window or i1 <= i0:
            return None
        span = t[i1] - t[i0]
        p0, p1 = self.hist_pos[i0], self.hist_pos[i1]
        fwd = -self.axis_now
        return {
            "omega_h": (self.hist_phi_h[i1] - self.hist_phi_h[i0]) / span,
            "omega_t": (self.hist_phi_t[i1] - self.hist_phi_t[i0]) / span,
            "v": float(np.dot(p1 - p0, fwd)) / span,
            "t0": float(t[i0]), "t1": float(t[i1]),
        }

    def steady_state(self, window: float, rtol: float) -> dict:
        """Rates over the last window, and whether they changed less than rtol since the window before."""
        last = self.window_rates(window)
        if last is None:
            span = self.t[-1] - self.t[0]
            last = self.window_rates(span) if span > 0 else None
            if last is None:
                return {"omega_h": 0.0, "omega_t": 0.0, "v": 0.0, "steady": False, "window": 0.0}
            last.update(steady=False, window=span)
            return last
        prev = self.window_rates(window, end_time=self.t[-1] - window)
        steady = False
        if self.clamped:
            # the rates are imposed by the clamp: steadiness is the shape in the co-rotating frame
            i0 = int(np.searchsorted(self.t, self.t[-1] - window * (1 - 1e-9), side="right") - 1)
            if i0 >= 0 and self.t[-1] - self.t[i0] >= 0.999 * window:
                drift = np.linalg.norm(self.hist_tip[-1] - self.hist_tip[i0])
                steady = bool(drift < rtol * self.model.scene.flagellum.length)
        elif prev is not None:
            scale = max(abs(last["omega_h"]) + abs(last["omega_t"]), 1e-12)
            dv = abs(last["v"] - prev["v"]) / max(abs(last["v"]), 1e-12)
            dw = (abs(last["omega_h"] - prev["omega_h"]) + abs(last["omega_t"] - prev["omega_t"])) / scale
            steady = bool(dw < rtol and (dv < rtol or abs(last["v"]) < 1e-9))
        last.update(steady=steady, window=window)
        return last
