"""Simulation: one robot, its stepper, its observer; the object the CLI, the ROS node and the sweeps drive."""
from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np

from ..scene import Scene
from . import kernels
from .model import RobotModel
from .observe import Observer, quaternion_from_matrix
from .stepper import Stepper, StepStats


class Simulation:
    def __init__(self, scene: Scene):
        self.scene = scene
        self.model = RobotModel(scene)
        self.stepper = Stepper(self.model)
        self.dt = scene.time.dt
        self.initial = self.model.initial_state()
        self.state = self.initial.copy()
        self.observer = Observer(self.model, self.state)
        self.last_stats = StepStats(dt_min=self.dt)
        self.steps = 0
        self.newton_iterations = 0
        self.reductions = 0
        self.wall_seconds = 0.0
        self._prev_state = self.state

    # ---------------------------------------------------------------- command
    @property
    def omega_T(self) -> float:
        d = self.model.driver
        return d.omega if d is not None else 0.0

    def set_omega(self, omega_T: float) -> None:
        """Set the motor (or clamp) speed in rad/s; takes effect at the next step."""
        if not math.isfinite(omega_T):
            raise ValueError(f"omega_T must be finite, got {omega_T!r}")
        d = self.model.driver
        if d is None:
            raise ValueError("this scene has no motor or clamp effect to command")
        d.omega = float(omega_T)

    # ---------------------------------------------------------------- stepping
    def step(self, dt: float | None = None) -> StepStats:
        """Advance by dt (default: the scene's). Raises StepFailed and keeps the state if Newton fails."""
        dt = self.dt if dt is None else dt
        w0 = time.perf_counter()
        new, stats = self.stepper.step(self.state, dt)
        self.wall_seconds += time.perf_counter() - w0
        self.observer.record(self.state, new)
        self._prev_state = self.state
        self.state = new
        self.last_stats = stats
        self.steps += 1
        self.newton_iterations += stats.newton_iterations
        self.reductions += stats.reductions
        return stats

    def run(self, duration: float, callback: Callable[["Simulation"], None] | None = None) -> None:
        n = max(1, int(round(duration / self.dt)))
        for _ in range(n):
            self.step()
            if callback is not None:
                callback(self)

    def reset(self) -> None:
        self.state = self.initial.copy()
        self._prev_state = self.state
        self.model.restore(self.state)
        for e in self.model.effects:
            if e.name in ("motor", "clamp"):
                e.omega = self.scene.omega_T
        self.observer.reset(self.state)
        self.steps = 0
        self.newton_iterations = 0
        self.reductions = 0
        self.wall_seconds = 0.0

    @property
    def time(self) -> float:
        return self.state.t

    @property
    def motor_angle(self) -> float:
        """Integrated drive command (rad): the motor's natural-twist angle, or the clamp's rotation angle."""
        return float(self.state.extras.get("motor_angle", self.state.extras.get("clamp_angle", 0.0)))

    # ---------------------------------------------------------------- observations
    def positions(self) -> np.ndarray:
        return self.observer.x(self.state)

    def head_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(position of the head centre x1 (m), orientation quaternion x, y, z, w)."""
        pos = self.observer.position(self.state)
        return pos.copy(), quaternion_from_matrix(self.observer.head_orientation(self.state))

    def head_velocity(self) -> np.ndarray:
        """Velocity of the head centre over the last step (m/s, simulation frame)."""
        net = self.model.net
        node = net.head_nodes[1] if len(net.head_nodes) else net.joint_node
        return self.state.v[3 * node: 3 * node + 3].copy()

    def head_angular_velocity(self) -> np.ndarray:
        """Angular velocity of the head body over the last step (rad/s, simulation frame)."""
        if self.steps == 0:
            return np.zeros(3)
        R0 = self.observer.head_orientation(self._prev_state)
        R1 = self.observer.head_orientation(self.state)
        dR = R1 @ R0.T
        # rotation vector of dR (log map), robust near zero angle
        c = np.clip((np.trace(dR) - 1.0) / 2.0, -1.0, 1.0)
        angle = math.acos(c)
        w = np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]])
        scale = 0.5 if angle < 1e-8 else angle / (2.0 * math.sin(angle))
        return scale * w / (self.state.t - self._prev_state.t)

    def motor_torque(self) -> float:
        """Torque the motor applies to the shaft (N m; positive drives a positive omega_T): the motor hinge's
        twisting moment. At steady state it equals the head's Stokes torque C2 8 pi mu R_h^3 omega_h."""
        net, el = self.model.net, self.model.elastic
        if net.motor_hinge < 0:
            return 0.0
        fr = el.trial_frames(self.state.q, self.state.frames)
        _, _, tau = el.hinge_strains(self.state.q, fr)
        h = net.motor_hinge
        return float(-el.k_twist[h] * (tau[h] - el.tau_bar[h]))

    def flagella_centrelines(self) -> list[np.ndarray]:
        x = self.positions()
        return [x[nodes] for nodes in self.model.net.flagella_nodes]

    def rigid_polylines(self) -> dict[str, np.ndarray]:
        """Head (x0-x1-x2) and plate arms + sockets, for drawing."""
        net, x = self.model.net, self.positions()
        out = {}
        if len(net.head_nodes):
            out["head"] = x[net.head_nodes]
        arms = []
        for pe, se in zip(net.plate_edges, net.socket_edges):
            a, b = net.edges[pe]
            _, c = net.edges[se]
            arms.append(x[[a, b, c]])
        out["plate"] = arms
        return out

    def medium_force_on_flagella(self) -> tuple[np.ndarray, np.ndarray]:
        """Total RFT force (N) and torque about the origin (N m) on the flagella over the last step."""
        rft = self.model.effect("rft")
        if rft is None or self.steps == 0:
            return np.zeros(3), np.zeros(3)
        ctx = self.model.context(self.state.q, self._prev_state, self.state.t - self._prev_state.t)
        F = rft.node_forces(ctx)
        r = ctx.x[rft.k]
        return F.sum(axis=0), np.cross(r, F).sum(axis=0)

    def clamp_frame_tip(self) -> np.ndarray:
        """Flagellum tip in the frame co-rotating with the clamp (clamp at (0, R_d, 0))."""
        return self.observer.corotating_tip(self.state)

    def steady_state(self) -> dict:
        ob = self.scene.observe
        return self.observer.steady_state(ob.steady_window, ob.steady_rtol)

    def summary(self) -> dict:
        """Steady-state outputs and run statistics (SI units)."""
        ss = self.steady_state()
        out = {
            "scene": self.scene.scene.name,
            "n_flagella": self.scene.robot.n_flagella,
            "omega_T": self.omega_T,
            "omega_h": ss["omega_h"],
            "omega_t": ss["omega_t"],
            "v": ss["v"],
            "steady": ss["steady"],
            "window": ss["window"],
            "time": self.state.t,
            "steps": self.steps,
            "newton_iterations": self.newton_iterations,
            "dt_reductions": self.reductions,
            "wall_seconds": self.wall_seconds,
            "real_time_factor": self.state.t / self.wall_seconds if self.wall_seconds > 0 else None,
            "kernels": "compiled" if kernels.AVAILABLE else "python",
        }
        if self.scene.clamped:
            F, T = self.medium_force_on_flagella()
            out.update(Fx=float(F[0]), Tx=float(T[0]), tip=[float(v) for v in self.clamp_frame_tip()])
        return out
