"""sim_node: the simulated flagellated robot as a ROS 2 device.

Subscribes to the motor command (``cmd_omega``), steps the DER model in a wall-clock timer at the requested
real-time factor, and publishes the head pose, odometry, head/flagellar spin, the flagella as markers, /clock and
diagnostics. The interface is documented in msg_docs/sim_node.md (a test checks it against the live node).
"""
from __future__ import annotations

import math
import sys
import time
from collections import deque

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

from .. import __version__, world
from ..bag import BagError
from ..physics import Simulation, StepFailed
from ..scene import SceneError
from . import convert
from .. import topics as names
from .params import ParamSpec, command_refusal, declare, help_text, node_scene, scene_request
from .runtime import run_node, wants_help

PARAMS = [
    ParamSpec("scene", "design1", "built-in scene name (design1, design2, ...) or path to a .toml scene file; "
              "changing it rebuilds the simulation"),
    ParamSpec("n_flagella", 0, "number of flagella; 0 keeps the scene's value", range=(0, 12)),
    ParamSpec("scene_overrides", [], "scene values to override, each 'section.key=value' "
              "(e.g. flagellum.length=0.2); changing them rebuilds the simulation"),
    ParamSpec("initial_omega", 0.0, "motor speed before the first cmd_omega arrives", "rad/s", range=(-1e4, 1e4)),
    ParamSpec("publish_rate", 50.0, "rate of the state topics and /clock (wall clock)", "Hz", range=(1.0, 1000.0)),
    ParamSpec("marker_rate", 10.0, "rate of the marker array (wall clock); 0 = no markers", "Hz",
              range=(0.0, 100.0)),
    ParamSpec("real_time_factor", 1.0, "simulated seconds per wall second; 0 = as fast as possible", "",
              range=(0.0, 1000.0)),
    ParamSpec("max_omega", 50.0, "largest |cmd_omega| accepted; larger commands are rejected", "rad/s",
              range=(1e-3, 1e4)),
    ParamSpec("start_paused", False, "start paused (call the pause service with false to run); lets other "
              "processes connect before simulated time starts"),
    ParamSpec("record", "", "MCAP file to record this run to (every flagbot topic, cmd_omega and /clock, with the "
              "scene and all parameters); setting it starts a new recording, '' stops"),
    ParamSpec("frame_id", "world", "fixed frame of poses, odometry and markers"),
    ParamSpec("child_frame_id", "head", "head body frame (odometry child frame)"),
]

STEP_BUDGET = 0.8       # fraction of a timer period spent stepping; the rest serves commands and services
DIAG_PERIOD = 1.0       # s of wall time between diagnostics


class SimNode(Node):
    def __init__(self):
        super().__init__("sim_node")
        declare(self, PARAMS)
        p = self._params()
        self.sim = Simulation(node_scene(p["scene"], p["n_flagella"], p["scene_overrides"]))
        self.publish_rate = p["publish_rate"]
        self.marker_rate = p["marker_rate"]
        self.rtf = p["real_time_factor"]
        self.max_omega = p["max_omega"]
        self.frame_id = p["frame_id"]
        self.child_frame_id = p["child_frame_id"]
        if self.sim.model.driver is not None:
            self.sim.set_omega(p["initial_omega"])
        self.add_on_set_parameters_callback(self._on_set_parameters)

        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pub_clock = self.create_publisher(Clock, names.CLOCK, qos)
        self.pub_pose = self.create_publisher(PoseStamped, names.HEAD_POSE, qos)
        self.pub_odom = self.create_publisher(Odometry, names.ODOM, qos)
        self.pub_joints = self.create_publisher(JointState, names.JOINT_STATES, qos)
        self.pub_omega_h = self.create_publisher(Float64, names.OMEGA_H, qos)
        self.pub_omega_t = self.create_publisher(Float64, names.OMEGA_T, qos)
        self.pub_speed = self.create_publisher(Float64, names.SPEED, qos)
        self.pub_markers = self.create_publisher(MarkerArray, names.MARKERS, QoSProfile(depth=2))
        self.pub_diag = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS, qos)
        self.create_subscription(Float64, names.CMD_OMEGA, self._on_cmd, qos)
        self.create_service(Trigger, names.RESET, self._on_reset)
        self.create_service(SetBool, names.PAUSE, self._on_pause)

        self.paused = bool(p["start_paused"])
        self.rejected = 0
        self.step_failures = 0
        self.last_error = ""
        self.withheld = 0
        self.time_offset = 0.0           # keeps /clock monotonic across resets
        self._anchor()
        self._last_marker = -math.inf
        self._last_diag = -math.inf
        self._rtf_window: deque[tuple[float, float]] = deque()    # (wall, sim time) over the last 2 s of wall time
        self._behind = False
        self.recorder = None
        if p["record"]:
            self._start_recording(p)
        self.timer = self.create_timer(1.0 / self.publish_rate, self._on_timer)
        self.get_logger().info(
            f"flagbot_sim {__version__}: scene {self.sim.scene.scene.name}, n = {self.sim.scene.robot.n_flagella}, "
            f"dt = {self.sim.dt} s, real_time_factor {self.rtf or 'max'}; waiting for {names.CMD_OMEGA}")

    # ------------------------------------------------------------------ time
    @property
    def sim_time(self) -> float:
        return self.time_offset + self.sim.time

    def _anchor(self) -> None:
        self._wall0 = time.monotonic()
        self._sim0 = self.sim.time

    def _params(self, new: dict | None = None) -> dict:
        """Every parameter's value once ``new`` applies.

        A set-parameter callback runs before rclpy stores the new values, so get_parameter alone would still
        return the old ones there.
        """
        p = {s.name: self.get_parameter(s.name).value for s in PARAMS}
        p.update({k: v for k, v in (new or {}).items() if k in p})
        return p

    # ------------------------------------------------------------------ recording
    def _start_recording(self, params: dict) -> None:
        """Record to ``params["record"]``; ``params`` (every parameter's value) goes into the metadata."""
        from ..bag import RunMetadata
        from .recorder import Recorder
        path = params["record"]
        params = dict(params, scene_overrides=list(params["scene_overrides"]))
        # the resolved scene (file + overrides + n_flagella), so the recording alone reproduces the run
        meta = RunMetadata(scene_toml=self.sim.scene.to_toml(), parameters=params)
        self.recorder = Recorder(self, path, None, meta)
        self.get_logger().info(f"recording to {path}")

    def _stop_recording(self) -> str:
        if self.recorder is None:
            return ""
        s = self.recorder.close()
        self.recorder = None
        return (f"recording closed: {s.path}, {s.messages} messages on {len(s.topics)} topics, "
                f"{s.duration:.1f} s, {s.size_bytes / 1024:.0f} KiB" + (f", ERROR {s.error}" if s.error else ""))

    def close(self) -> None:
        # called after the context is gone (SIGINT/SIGTERM): plain print, rosout can no longer be published to
        msg = self._stop_recording()
        if msg:
            print(msg, flush=True)

    # ------------------------------------------------------------------ callbacks
    def _on_cmd(self, msg: Float64) -> None:
        w = msg.data
        reason = command_refusal(w, self.max_omega)
        if reason is None:
            if self.sim.model.driver is not None:
                self.sim.set_omega(w)
            return
        self.rejected += 1
        self.get_logger().warn(f"rejected {names.CMD_OMEGA} = {w!r} rad/s: {reason}; keeping "
                               f"omega_T = {self.sim.omega_T:g} rad/s", throttle_duration_sec=2.0)

    def _on_reset(self, request, response):
        self.time_offset += self.sim.time
        omega = self.sim.omega_T
        self.sim.reset()
        if self.sim.model.driver is not None:
            self.sim.set_omega(omega)        # reset restores the robot, not the operator's command
        self.last_error = ""
        self._anchor()
        self._publish_state(force_markers=True)
        response.success = True
        response.message = f"robot back at its initial state at simulation time {self.sim_time:.3f} s"
        return response

    def _on_pause(self, request, response):
        self.paused = bool(request.data)
        self._anchor()
        response.success = True
        response.message = "paused" if self.paused else "running"
        return response

    def _on_set_parameters(self, params) -> SetParametersResult:
        new = {p.name: p.value for p in params}
        for name in ("frame_id", "child_frame_id"):
            if name in new and not str(new[name]).strip():
                return SetParametersResult(successful=False, reason=f"{name} must not be empty")
        try:
            scene = scene_request(self, new)
        except (SceneError, ValueError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        if scene is not None:
            sim = Simulation(scene)
            if self.sim.model.driver is not None and sim.model.driver is not None:
                sim.set_omega(self.sim.omega_T)
            self.time_offset += self.sim.time
            self.sim = sim
            self._anchor()
            self.get_logger().info(f"rebuilt the simulation: scene {sim.scene.scene.name}, "
                                   f"n = {sim.scene.robot.n_flagella}")
        if "publish_rate" in new:
            self.publish_rate = float(new["publish_rate"])
            self.timer.cancel()
            self.destroy_timer(self.timer)
            self.timer = self.create_timer(1.0 / self.publish_rate, self._on_timer)
        if "real_time_factor" in new:
            self.rtf = float(new["real_time_factor"])
            self._anchor()
        for name in ("marker_rate", "max_omega", "frame_id", "child_frame_id"):
            if name in new:
                setattr(self, name, new[name])
        if "record" in new:
            msg = self._stop_recording()
            if msg:
                self.get_logger().info(msg)
            if new["record"]:
                try:
                    self._start_recording(self._params(new))
                except (OSError, ValueError, BagError) as exc:
                    return SetParametersResult(successful=False, reason=f"cannot record to {new['record']!r}: {exc}")
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ stepping
    def _on_timer(self) -> None:
        wall_start = time.monotonic()
        if not self.paused:
            self._advance(wall_start)
        self._publish_state()
        now = time.monotonic()
        if now - self._last_diag >= DIAG_PERIOD:
            self._last_diag = now
            self._publish_diagnostics()

    def _advance(self, wall_start: float) -> None:
        budget = STEP_BUDGET / self.publish_rate
        dt = self.sim.dt
        if self.rtf > 0:
            target = self._sim0 + self.rtf * (wall_start - self._wall0)
            while self.sim.time + 0.5 * dt <= target and time.monotonic() - wall_start < budget:
                if not self._step():
                    return
            lag = target - self.sim.time
            self._behind = lag > max(2.0 * dt, self.rtf * 2.0 / self.publish_rate)
            if lag > self.rtf * 1.0:       # more than a second of wall time behind: stop accumulating debt
                self._anchor()
        else:
            self._behind = False
            while True:
                if not self._step():
                    return
                if time.monotonic() - wall_start >= budget:
                    break
        now = time.monotonic()
        self._rtf_window.append((now, self.sim_time))
        while self._rtf_window[0][0] <= now - 2.0:     # entries are in wall-time order: the old ones are first
            self._rtf_window.popleft()

    def _step(self) -> bool:
        try:
            self.sim.step()
        except StepFailed as exc:
            self.step_failures += 1
            self.last_error = str(exc)
            self.get_logger().error(f"step failed, keeping the last good state: {exc}", throttle_duration_sec=5.0)
            return False
        self.last_error = ""
        return True

    # ------------------------------------------------------------------ publishing
    def _publish_state(self, force_markers: bool = False) -> None:
        sim, ob = self.sim, self.sim.observer
        t = self.sim_time
        snap = sim.snapshot()
        pos_w = snap.position
        R_w = world.head_rotation_world(ob.head_orientation(sim.state))
        v_w, w_w, torque = snap.velocity, snap.angular_velocity, snap.motor_torque
        values = np.concatenate([pos_w, R_w.ravel(), v_w, w_w, [ob.phi_h, ob.phi_t, ob.rate_h, ob.rate_t,
                                                               ob.speed, torque]])
        if not np.all(np.isfinite(values)):     # the physics never returns NaN; refuse to pass one on anyway
            self.withheld += 1
            self.last_error = "non-finite state withheld from publication"
            return
        self.pub_clock.publish(convert.clock_msg(t))
        pose = convert.pose_msg(t, self.frame_id, pos_w, R_w)
        self.pub_pose.publish(pose)
        # odometry carries the same pose: the orientation quaternion is computed once per tick
        self.pub_odom.publish(convert.odometry_msg(t, self.frame_id, self.child_frame_id, pose.pose, R_w, v_w, w_w))
        self.pub_joints.publish(convert.joint_state_msg(t, ob.phi_h, ob.phi_t, ob.rate_h, ob.rate_t,
                                                        sim.motor_angle, sim.omega_T, torque))
        self.pub_omega_h.publish(convert.float_msg(ob.rate_h))
        self.pub_omega_t.publish(convert.float_msg(ob.rate_t))
        self.pub_speed.publish(convert.float_msg(ob.speed))
        now = time.monotonic()
        if self.marker_rate > 0 and (force_markers or now - self._last_marker >= 1.0 / self.marker_rate):
            self._last_marker = now
            self.pub_markers.publish(self._markers(t))

    def _markers(self, t: float) -> MarkerArray:
        sim = self.sim
        o = sim.observer.position(sim.initial)
        rigid = sim.rigid_polylines()
        head = world.to_world(rigid["head"][1], o) if "head" in rigid else None
        return convert.markers_msg(
            t, self.frame_id, [world.to_world(c, o) for c in sim.flagella_centrelines()], head,
            sim.scene.head.radius, [world.to_world(a, o) for a in rigid["plate"]], sim.scene.flagellum.radius)

    def _publish_diagnostics(self) -> None:
        sim, st = self.sim, self.sim.last_stats
        achieved = float("nan")
        if len(self._rtf_window) >= 2 and self._rtf_window[-1][0] > self._rtf_window[0][0]:
            (w0, s0), (w1, s1) = self._rtf_window[0], self._rtf_window[-1]
            achieved = (s1 - s0) / (w1 - w0)
        level, message = "OK", "running"
        if self.paused:
            message = "paused"
        if self._behind:
            level, message = "WARN", (f"cannot keep up: real-time factor {achieved:.2f} achieved, "
                                      f"{self.rtf:g} requested")
        if self.last_error:
            level, message = "ERROR", self.last_error
        values = {
            "sim_time_s": f"{self.sim_time:.4f}", "omega_T_rad_s": f"{sim.omega_T:.6g}",
            "newton_iterations_last_step": st.newton_iterations, "residual_N": f"{st.residual:.3e}",
            "dt_s": sim.dt, "dt_min_last_step_s": f"{st.dt_min:.3g}", "dt_reductions_total": sim.reductions,
            "real_time_factor_achieved": f"{achieved:.3f}", "real_time_factor_requested": self.rtf,
            "rejected_commands": self.rejected, "step_failures": self.step_failures,
            "withheld_non_finite": self.withheld, "steps": sim.steps, "scene": sim.scene.scene.name,
            "n_flagella": sim.scene.robot.n_flagella,
        }
        self.pub_diag.publish(convert.diagnostics_msg(self.sim_time, "flagbot_sim: simulator", level, message,
                                                      values))


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv if argv is None else argv
    if wants_help(argv):
        print(help_text("sim_node", __doc__.strip().splitlines()[0], PARAMS,
                        "topics: sub cmd_omega; pub /clock, head_pose, odom, joint_states, omega_h, omega_t, speed, "
                        "markers, /diagnostics; services: reset, pause"))
        return 0
    return run_node(SimNode, argv)


if __name__ == "__main__":
    sys.exit(main())
