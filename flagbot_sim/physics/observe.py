"""What is observed of the robot: one :class:`Snapshot` per state, windowed rates, and one steady-state rule.

Conventions (see docs/physics.md):

* the robot axis is a = unit(x2 - x0), +x in the undeformed robot; *forward* is -a (the head leads);
* ``omega_h`` is the head's spin rate about -a and ``omega_t`` the flagella's (shaft/plate) spin rate about +a,
  both in the lab frame. With a positive motor command both are positive and omega_h + omega_t = omega_T at
  steady state: head and flagella turn in opposite directions;
* ``v`` is the head-centre velocity along the forward direction (positive = head first).

Spin angles are accumulated step by step from the twist DOF increment plus the (small) rotation of the
time-parallel-transported reference frame about the axis, so they never alias, even at large dt.

Memory is bounded: the history behind the windowed rates holds only the last few windows, at most one sample
per ``window / 2048`` of simulated time (every step at the paper's dt), so a run of hours costs what a run of
seconds does.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from .. import world
from .frames import angle3, material3
from .model import RobotModel, State
from .tiers import tiered

#: |v| below this (m/s) is "not moving": its relative change is not meaningful
V_FLOOR = 1.0e-9
#: history kept behind the windowed rates, in windows
KEEP_WINDOWS = 4
#: history samples per window at most
SAMPLES_PER_WINDOW = 2048


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


def rotation_vector(R: np.ndarray) -> np.ndarray:
    """Rotation vector (log map) of a rotation matrix, robust near zero angle."""
    c = min(1.0, max(-1.0, (np.trace(R) - 1.0) / 2.0))
    angle = math.acos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return (0.5 if angle < 1e-8 else angle / (2.0 * math.sin(angle))) * w


@dataclass(frozen=True)
class Snapshot:
    """The one observation of the robot at a state, in the fixed frame (``world``: REP 103, x forward, origin at
    the head centre at rest). Everything the ROS node publishes, a recording replays and a CSV writes."""
    t: float                      # simulated time (s)
    position: np.ndarray          # head centre (m), fixed frame
    orientation: np.ndarray       # head body orientation, quaternion (x, y, z, w), fixed frame
    velocity: np.ndarray          # head-centre velocity over the last step (m/s), fixed frame
    angular_velocity: np.ndarray  # head body angular velocity over the last step (rad/s), fixed frame
    phi_h: float                  # accumulated head spin angle (rad)
    phi_t: float                  # accumulated flagella spin angle (rad)
    omega_h: float                # head spin rate over the last step (rad/s)
    omega_t: float                # flagella spin rate over the last step (rad/s)
    v: float                      # forward speed over the last step (m/s, positive = head first)
    drive_angle: float            # integrated drive command (rad)
    omega_T: float                # drive command in force (rad/s)
    motor_torque: float           # torque of the motor on the shaft (N m); 0 without a motor

    def values(self) -> np.ndarray:
        """Every number of the snapshot as one vector (to check them all for finiteness at once)."""
        return np.concatenate([self.position, self.orientation, self.velocity, self.angular_velocity,
                               [self.t, self.phi_h, self.phi_t, self.omega_h, self.omega_t, self.v,
                                self.drive_angle, self.omega_T, self.motor_torque]])

    def is_finite(self) -> bool:
        return bool(np.all(np.isfinite(self.values())))

    def rotation(self) -> np.ndarray:
        """The head body's rotation matrix in the fixed frame (from ``orientation``)."""
        return world.quaternion_matrix(*self.orientation)


#: standard gravity (m/s^2): the weight in the cost of transport, whatever the scene's gravity effect
G_STANDARD = 9.80665


def efficiency(torque: float, omega_T: float, v: float, mass: float) -> dict:
    """Motor torque (N m), mechanical power torque x omega_T (W) and the cost of transport P / (m g |v|)
    (dimensionless, None when the robot does not move); m is the robot's mass (kg)."""
    power = torque * omega_T
    cot = power / (mass * G_STANDARD * abs(v)) if abs(v) > V_FLOOR and mass > 0 else None
    return {"motor_torque": torque, "power": power, "cost_of_transport": cot}


def summary_fields(scene, mass: float, rates: dict, run: dict, *, motor_torque: float | None = None,
            clamp: tuple | None = None) -> dict:
    """The one schema of ``flagbot run --json`` and ``flagbot steady --json``: the scene's name and n, ``rates``
    (omega_T, omega_h, omega_t, v, steady), ``run`` (how they were obtained), then for a clamped flagellum
    ``clamp`` = (F, T, tip), the medium's force and torque on it and its tip in the clamp's frame, whose torque is
    the clamp's (-T_x), otherwise the ``motor_torque``; and :func:`efficiency` of that torque (robot mass
    ``mass``)."""
    out = {"scene": scene.scene.name, "n_flagella": scene.robot.n_flagella, **rates, **run}
    if clamp is not None:
        F, T, tip = clamp
        out.update(Fx=float(F[0]), Tx=float(T[0]), tip=[float(v) for v in tip])
        motor_torque = -float(T[0])          # what the clamp applies against the medium's torque
    out.update(efficiency(motor_torque, rates["omega_T"], rates["v"], mass))
    return out


class History:
    """The observer's samples (t, phi_h, phi_t, position (3), clamp tip (3)), one row each, over the last ``keep``
    seconds (at least two rows), no two but the newest closer than ``spacing`` in time: a sample that close to
    the one before the newest replaces the newest. Rows in one array, added a batch at a time (the compiled steps
    hand over hundreds of steps in one call): a step costs a row copy, not a Python tuple and two arrays."""

    COLUMNS = 9

    def __init__(self, spacing: float, keep: float):
        self.spacing, self.keep = float(spacing), float(keep)
        self._rows = np.empty((64, self.COLUMNS))
        self._lo = self._n = 0

    def __len__(self) -> int:
        return self._n

    def rows(self) -> np.ndarray:
        """The samples held, oldest first (a view: not to be written)."""
        return self._rows[self._lo: self._lo + self._n]

    @property
    def t_now(self) -> float:
        return float(self._rows[self._lo + self._n - 1, 0])

    @property
    def t_first(self) -> float:
        return float(self._rows[self._lo, 0])

    def add(self, samples: np.ndarray) -> None:
        """Add rows of samples in time order (the rule above, one sample after the other), then drop the oldest
        rows while the second oldest is at least ``keep`` older than the newest."""
        n = self._n
        h = self._rows[self._lo: self._lo + n, 0]
        t2 = float(h[-2]) if n >= 2 else 0.0            # the time of the row before the newest
        t1 = float(h[-1]) if n >= 1 else 0.0            # and of the newest
        slots = []
        spacing = self.spacing
        for t in samples[:, 0].tolist():
            if n >= 2 and t - t2 < spacing:
                slots.append(n - 1)                       # replaces the newest
            else:
                slots.append(n)
                n += 1
                t2 = t1
            t1 = t
        slot = np.asarray(slots)
        last = np.ones(len(slots), bool)                  # of the samples for one slot, the last is kept
        last[:-1] = slot[1:] != slot[:-1]
        self._room(n)
        self._rows[self._lo + slot[last]] = samples[last]
        self._n = n
        T = self._rows[self._lo: self._lo + n, 0]
        drop = min(n - 2, int(np.searchsorted(T, T[-1] - self.keep, side="right")) - 1)
        if drop > 0:
            self._lo += drop
            self._n -= drop

    def _room(self, n: int) -> None:
        """Room for n rows from self._lo: the live rows moved to the front, or a larger array."""
        if self._lo + n <= len(self._rows):
            return
        live = self._rows[self._lo: self._lo + self._n]
        if n > len(self._rows) // 2:
            grown = np.empty((2 * max(n, len(self._rows)), self.COLUMNS))
            grown[: self._n] = live
            self._rows = grown
        else:
            self._rows[: self._n] = live.copy()
        self._lo = 0

    def at(self, t: float) -> np.ndarray | None:
        """The row at time t by linear interpolation between the two samples around it (the first or last
        sample at the ends); None outside the history (beyond 1e-12 s)."""
        h = self.rows()
        T = h[:, 0]
        if t < T[0] - 1e-12 or t > T[-1] + 1e-12:
            return None
        if len(T) == 1:
            return h[0].copy()
        lo = min(max(int(np.searchsorted(T, t, side="right")) - 1, 0), len(T) - 2)
        a, b = h[lo], h[lo + 1]
        if b[0] <= a[0] or t <= a[0]:
            return a.copy()
        if t >= b[0]:
            return b.copy()
        f = (t - a[0]) / (b[0] - a[0])
        return a + f * (b - a)


class Observer:
    """Accumulates spin angles step by step; answers instantaneous and windowed rates over a bounded history."""

    def __init__(self, model: RobotModel, state: State, window: float):
        self.model = model
        self.net = model.net
        self.has_head = len(self.net.head_nodes) > 0
        self.clamped = model.scene.clamped
        self.window = float(window)
        self.origin = self.position(state).copy()
        self.reset(state)

    def reset(self, state: State) -> None:
        self.phi_h = 0.0
        self.phi_t = 0.0
        self.rate_h = 0.0      # instantaneous (last step) rates, rad/s
        self.rate_t = 0.0
        self.speed = 0.0
        self.axis_now = self.axis(state)
        self._pos = self.position(state).copy()
        self.history = History(self.window / SAMPLES_PER_WINDOW, KEEP_WINDOWS * self.window)
        self._append(state.t)

    # ---------------------------------------------------------------- geometry of one state
    def x(self, state: State) -> np.ndarray:
        N = self.net.n_nodes
        return state.q[: 3 * N].reshape(N, 3)

    def axis(self, state: State) -> np.ndarray:
        """Unit robot axis a (head front -> joint); +x for the clamped scene."""
        if not self.has_head:
            return np.array([1.0, 0.0, 0.0])
        q, i, j = state.q, 3 * self.net.head_nodes[0], 3 * self.net.head_nodes[2]
        a0, a1, a2 = q[j] - q[i], q[j + 1] - q[i + 1], q[j + 2] - q[i + 2]
        n = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)         # (scalars: a step's observation is ~1/3 of its cost)
        return np.array([a0 / n, a1 / n, a2 / n])

    def position(self, state: State) -> np.ndarray:
        x = self.x(state)
        return x[self.net.head_nodes[1]] if self.has_head else x[self.net.joint_node]

    def _spin_increment(self, edge: int, old: State, new: State, axis: np.ndarray) -> float:
        k = 3 * self.net.n_nodes + edge
        u, w = old.frames.d1[edge], new.frames.d1[edge]
        turn = tiered("time_stepping", angle3)(u[0], u[1], u[2], w[0], w[1], w[2], axis[0], axis[1], axis[2])
        return float(new.q[k] - old.q[k] + turn)

    def corotating_tip(self, state: State) -> np.ndarray:
        """Tip of the (first) flagellum in the frame turning with the clamp: clamp at (0, R_d, 0)."""
        c, s = math.cos(state.drive_angle), math.sin(state.drive_angle)
        R_inv = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])
        return R_inv @ self.x(state)[self.net.flagella_nodes[0][-1]]

    def head_orientation(self, state: State) -> np.ndarray:
        """Rotation matrix of the head body: columns (tangent, m1, m2) of the head edge's material frame."""
        if not self.has_head:
            return np.eye(3)
        e = self.net.head_edge
        fr = state.frames
        d1, d2 = fr.d1[e], fr.d2[e]
        m = material3(d1[0], d1[1], d1[2], d2[0], d2[1], d2[2], state.q[3 * self.net.n_nodes + e])
        return np.column_stack([fr.t[e], m[:3], m[3:]])

    # ---------------------------------------------------------------- per step
    def record(self, old: State, new: State) -> None:
        dt = new.t - old.t
        a = self.axis(new)
        if self.has_head:
            dh = -self._spin_increment(self.net.head_edge, old, new, a)
            dtt = self._spin_increment(self.net.shaft_edge, old, new, a)
        elif self.clamped:
            dh = 0.0
            dtt = new.drive_angle - old.drive_angle
        else:
            dh = dtt = 0.0
        self.phi_h += dh
        self.phi_t += dtt
        pos = self.position(new).copy()
        self.rate_h = dh / dt
        self.rate_t = dtt / dt
        d, p0 = pos - self._pos, a
        self.speed = -(d[0] * p0[0] + d[1] * p0[1] + d[2] * p0[2]) / dt
        self._pos = pos
        self.axis_now = a
        self._append(new.t, new)

    def recorded(self, rows: np.ndarray) -> None:
        """What :meth:`record` leaves behind, for steps the compiled steps took (stepper.Stepper.advance: one row
        per step, t, -, -, phi_h, phi_t, position, ...; the instantaneous rates already set). Not clamped."""
        samples = np.zeros((rows.shape[0], History.COLUMNS))
        samples[:, 0] = rows[:, 0]
        samples[:, 1:6] = rows[:, 3:8]
        self.history.add(samples)

    def _append(self, t: float, state: State | None = None) -> None:
        sample = np.zeros((1, History.COLUMNS))
        sample[0, :6] = t, self.phi_h, self.phi_t, *self._pos
        if self.clamped and state is not None:
            sample[0, 6:] = self.corotating_tip(state)
        self.history.add(sample)

    @property
    def t_now(self) -> float:
        return self.history.t_now

    @property
    def t_first(self) -> float:
        return self.history.t_first

    def _at(self, t: float):
        """(phi_h, phi_t, position, tip) at time t by linear interpolation in the history (None if outside)."""
        row = self.history.at(t)
        return None if row is None else (float(row[1]), float(row[2]), row[3:6], row[6:9])

    # ---------------------------------------------------------------- windows
    def window_rates(self, window: float, end_time: float | None = None) -> dict | None:
        """Mean omega_h, omega_t, v over [end - window, end]; None if the history does not cover the window."""
        t1 = self.t_now if end_time is None else end_time
        t0 = t1 - window
        p1, p0 = self._at(t1), self._at(t0 + 1e-9 * window)
        if p1 is None or p0 is None or window <= 0:
            return None
        p0 = self._at(t0) or p0
        fwd = -self.axis_now
        return {"omega_h": (p1[0] - p0[0]) / window, "omega_t": (p1[1] - p0[1]) / window,
                "v": float(np.dot(p1[2] - p0[2], fwd)) / window, "t0": float(t0), "t1": float(t1)}

    def tip_at(self, t: float) -> np.ndarray | None:
        p = self._at(t)
        return None if p is None else p[3]

    def snapshot(self, state: State, prev: State | None, omega_T: float, motor_torque: float) -> Snapshot:
        """The :class:`Snapshot` of ``state``; ``prev`` is the state one step before (None: none yet)."""
        R = self.head_orientation(state)
        v_sim = np.zeros(3)
        w_sim = np.zeros(3)
        if prev is not None and state.t > prev.t:
            node = self.net.head_nodes[1] if self.has_head else self.net.joint_node
            v_sim = state.v[3 * node: 3 * node + 3]
            w_sim = rotation_vector(R @ self.head_orientation(prev).T) / (state.t - prev.t)
        R_w = world.head_rotation_world(R)
        return Snapshot(t=state.t, position=world.to_world(self.position(state), self.origin),
                        orientation=quaternion_from_matrix(R_w), velocity=world.to_world(v_sim),
                        angular_velocity=world.WORLD_FROM_SIM @ w_sim, phi_h=self.phi_h, phi_t=self.phi_t,
                        omega_h=self.rate_h, omega_t=self.rate_t, v=self.speed, drive_angle=state.drive_angle,
                        omega_T=omega_T, motor_torque=motor_torque)


class SteadyDetector:
    """The one steady-state rule, used by ``flagbot run``, the sweeps and the ROS node's diagnostics.

    Every half window the observed quantities are sampled: for the free robot the mean omega_h and v over the
    last window, for the clamped flagellum its tip in the co-rotating frame and the medium's axial force and
    torque (Fx, Tx). Each quantity's change d_k over one window, relative to its size (v against
    max(|v|, V_FLOOR); the tip against the flagellum length), must be below ``rtol``; and so must the distance
    to the final value that the geometric extrapolation of successive window-to-window changes predicts,
    |d_k| rho / (1 - rho) with rho = |d_k / d_{k-1}| (the tail of an exponential approach), wherever the
    approach is clearly geometric (d_{k-1} > rtol / 10 and rho < 1). That second test makes "steady" mean
    "within rtol of the final value" for slow relaxations, where consecutive windows agree to rtol long before
    the value has arrived. Both must hold at ``confirm`` consecutive checks: one check can pass at the peak of a
    start-up overshoot, where two windows straddling it have equal means.
    """

    #: largest rho / (1 - rho) the extrapolation uses (rho above 0.99: the approach is not yet geometric)
    MAX_TAIL = 99.0

    def __init__(self, window: float, rtol: float, confirm: int = 3):
        self.window = float(window)
        self.rtol = float(rtol)
        self.confirm = int(confirm)
        self.reset()

    def reset(self, t0: float = 0.0) -> None:
        """Start over at time t0 (checks at t0 + k window / 2)."""
        self.samples: deque = deque(maxlen=5)     # (t, values, scales)
        self.passed = 0
        self.steady = False
        self.changes = np.zeros(0)        # each quantity's relative change over the last window (last check)
        self.change = math.nan            # the largest of them
        self.tail = math.nan              # largest extrapolated relative distance to the final value
        self.tails = np.zeros(0)          # each quantity's (the extrapolation where geometric, else its change)
        self.next_check = t0 + 0.5 * self.window

    def due(self, t: float) -> bool:
        return t >= self.next_check - 1e-9 * self.window

    def update(self, t: float, values: np.ndarray, scales: np.ndarray) -> bool:
        """Add the sample at check time t; return whether the run is steady now."""
        self.next_check += 0.5 * self.window
        self.samples.append((t, np.asarray(values, float), np.asarray(scales, float)))
        s = self.samples
        if len(s) < 3:
            self.passed = 0
            self.steady = False
            return False
        _, x2, scale = s[-1]
        d = np.abs(x2 - s[-3][1]) / scale                 # change over one window, relative
        self.changes = d
        self.change = float(np.max(d))
        factor = np.ones_like(d)
        if len(s) >= 5:
            d_prev = np.abs(s[-3][1] - s[-5][1]) / scale      # the window before
            # only a clear, monotone approach is extrapolated: changes below rtol/10 are noise or the ripple
            # of an oscillating approach, and a ratio >= 1 is no geometric tail at all
            clear = d_prev > 0.1 * self.rtol
            rho = np.where(clear, d / np.where(clear, d_prev, 1.0), 1.0)
            factor = np.where(clear & (rho < 1.0), np.minimum(rho / np.maximum(1.0 - rho, 1e-12), self.MAX_TAIL),
                              1.0)
        self.tails = factor * d
        self.tail = float(np.max(self.tails))
        ok = self.change < self.rtol and self.tail < self.rtol
        self.passed = self.passed + 1 if ok else 0
        self.steady = self.passed >= self.confirm
        return self.steady
