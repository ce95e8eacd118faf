"""sim_node: the simulated flagellated robot as a ROS 2 device.

Subscribes to the motor command (``cmd_omega``), steps the DER model in a wall-clock timer at the requested
real-time factor, and publishes the head pose, odometry, head/flagellar spin, the flagella as markers, the URDF
of head and plate, /clock and diagnostics, and /tf + /tf_static where tf2_msgs is installed (recordings derive
them where it is not: ros/tf_derive.py). The interface is documented in msg_docs/sim_node.md (a test checks it
against the live node).

Parameter sets are transactions (flagbot_sim/device.py, ROS-free: the node only adapts it): everything a set
implies (the values' checks, the scene load and simulation build, the new recording's file, the live view's port)
is prepared before anything changes, so a refused set leaves parameters, simulation, timer and recording as they
were. The simulator owns the clock: its timer runs on the steady wall clock whatever ``use_sim_time`` says, and
every stamp is the simulated time it publishes on /clock.
"""
from __future__ import annotations

import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock as RclClock, ClockType
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, String
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

from .. import __version__, world
from ..device import PARAMS, Device, Plan, Refused
from ..scene import SceneError
from ..tf_tree import TfTree, stamp_ns_of
from ..urdf import robot_urdf
from . import convert, tf_derive
from .. import topics as names
from .dds import configure_dds
from ..values import one_line
from .params import declare, help_text, lifecycle_requested
from .runtime import Polled, interruptible, run_node, take_all, wants_help
from .sim_outputs import RecordingOutput, ViewOutput, recording_error

STEP_BUDGET = 0.8       # fraction of a timer period spent stepping; the rest serves commands and services
DIAG_PERIOD = 1.0       # s of wall time between diagnostics


class SimAdapter:
    """The ROS side of the simulated robot (:class:`flagbot_sim.device.Device` is the rest): its topics,
    services, timer and parameter callback, for the plain node (:class:`SimNode`, which configures and activates
    itself at start) and the managed one (:class:`ManagedSimNode`, whose lifecycle transitions call the same
    steps). The steps:

    * :meth:`_declare` (construction): the parameters, and the ROS-free :class:`flagbot_sim.device.Device` that
      holds and checks their values and changes them as transactions; nothing else exists yet.
    * :meth:`_configure`: read and validate the scene, build the simulation, create the topics and services,
      open the recording and the live view. Raises with the reason and leaves nothing behind when it cannot.
    * :meth:`_activate` / :meth:`_deactivate`: start / stop the timer that steps and publishes ("hold").
    * :meth:`_cleanup`: close the recording and the view, destroy the topics and services, drop the simulation.
    """

    def _declare(self, managed: bool) -> None:
        declare(self, PARAMS)
        if self.get_parameter("lifecycle").value != managed:
            raise ValueError("lifecycle is chosen on the command line (sim_node --ros-args -p lifecycle:=true); "
                             "a parameters file cannot switch it")
        try:
            self.device = Device({s.name: self.get_parameter(s.name).value for s in PARAMS}, guard=interruptible)
        except Refused as exc:
            raise ValueError(str(exc)) from None
        self.recording = RecordingOutput(self, self.get_logger().info)
        self.views = ViewOutput(self.get_logger().info, self.get_logger().warning)
        self.timer = None
        self._entities: list = []               # the publishers, subscriptions and services of a configuration
        self._said_sim_time = False
        self._said_no_tf = False
        self._tree = None                        # the kinematic tree of the robot_description last published
        self.add_on_set_parameters_callback(self._on_set_parameters)

    # the device's state and values, as the node uses them
    sim = property(lambda self: self.device.sim)
    configured = property(lambda self: self.device.configured)
    sim_time = property(lambda self: self.device.sim_time)
    publish_rate = property(lambda self: self.device.values["publish_rate"])
    marker_rate = property(lambda self: self.device.values["marker_rate"])
    rtf = property(lambda self: self.device.values["real_time_factor"])
    frame_id = property(lambda self: self.device.values["frame_id"])
    child_frame_id = property(lambda self: self.device.values["child_frame_id"])

    def _configure(self) -> None:
        """Build the device from the parameters; on any failure raise (Refused, SceneError, ValueError) with
        everything built so far torn down again."""
        sim = self.device.configure()
        try:
            self._create_entities()
            self._last_marker = -math.inf
            self._last_diag = -math.inf
            self._marker_ids: set | None = None     # (ns, id) of the markers last published
            self._description = ""
            if self.device.time_offset > 0.0:   # a managed node configured again: the run starts afresh from here
                self._publish_reset("configure")
            for out in (self.recording, self.views):
                out.swap(out.open(self.device.values, sim))
        except BaseException:
            self._cleanup()
            raise

    def _create_entities(self) -> None:
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)

        def pub(kind, topic, q=qos):
            p = self.create_publisher(kind, topic, q)
            self._entities.append(p)
            return p
        self.pub_clock = pub(Clock, names.CLOCK)
        self.pub_pose = pub(PoseStamped, names.HEAD_POSE)
        self.pub_odom = pub(Odometry, names.ODOM)
        self.pub_joints = pub(JointState, names.JOINT_STATES)
        self.pub_omega_h = pub(Float64, names.OMEGA_H)
        self.pub_omega_t = pub(Float64, names.OMEGA_T)
        self.pub_speed = pub(Float64, names.SPEED)
        self.pub_markers = pub(MarkerArray, names.MARKERS, QoSProfile(depth=2))
        self.pub_diag = pub(DiagnosticArray, names.DIAGNOSTICS)
        self.pub_description = pub(String, names.ROBOT_DESCRIPTION, latched)
        self.pub_resets = pub(DiagnosticArray, names.RESETS, latched)
        self.pub_tf = self.pub_tf_static = None
        tf_cls = tf_derive.tf_message_class()
        if tf_cls is not None:     # tf2's broadcasters' QoS: /tf keep last 100, /tf_static latched
            self.pub_tf = pub(tf_cls, names.TF, QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
            self.pub_tf_static = pub(tf_cls, names.TF_STATIC, latched)
        elif not self._said_no_tf:
            self._said_no_tf = True
            self.get_logger().info(f"not publishing {names.TF} and {names.TF_STATIC}: {tf_derive.NO_TF2}; "
                                   "recordings derive them from odom, joint_states and robot_description")
        # commands are taken in the timer, never by the executor (see _take_commands)
        self._cmd_sub = self.create_subscription(Float64, names.CMD_OMEGA, self._on_cmd, qos,
                                                 callback_group=Polled())
        self._entities += [self._cmd_sub,
                           self.create_service(Trigger, names.RESET, self._on_reset),
                           self.create_service(SetBool, names.PAUSE, self._on_pause)]

    def _activate(self) -> None:
        self._publish_description()
        self.device.anchor()
        self.timer = self._make_timer()
        self.get_logger().info(
            f"flagbot_sim {__version__}: scene {self.sim.scene.scene.name}, n = {self.sim.scene.robot.n_flagella}, "
            f"dt = {self.sim.dt} s, real_time_factor {self.rtf or 'max'}; {configure_dds()}; "
            f"waiting for {names.CMD_OMEGA}")
        if self.get_parameter("use_sim_time").value:
            self._say_sim_time()

    def _deactivate(self) -> None:
        if self.timer is not None:
            self.timer.cancel()
            self.destroy_timer(self.timer)
            self.timer = None

    def _cleanup(self) -> None:
        """Back to nothing but the parameters: the recording closed (its summary logged), the view closed, every
        topic and service destroyed, the simulation dropped; simulated time carries on from where it was."""
        self._deactivate()
        self.views.close()
        summary = self.recording.close()
        if summary:
            self.get_logger().info(summary)
        destroy = {"Publisher": self.destroy_publisher, "Subscription": self.destroy_subscription,
                   "Service": self.destroy_service}
        for entity in reversed(self._entities):
            destroy[type(entity).__name__](entity)
        self._entities.clear()
        self.device.release()

    # ------------------------------------------------------------------ time
    def _make_timer(self):
        # the simulator owns /clock: a timer on the node clock would, with use_sim_time, wait for the /clock this
        # node publishes itself (and never fire). The steady wall clock drives stepping and publishing either way
        return self.create_timer(1.0 / self.publish_rate, self._on_timer,
                                 clock=RclClock(clock_type=ClockType.STEADY_TIME))

    def _say_sim_time(self) -> None:
        if not self._said_sim_time:
            self._said_sim_time = True
            self.get_logger().info(
                "use_sim_time is true: sim_node owns /clock, so it keeps stepping on the wall clock (at "
                "real_time_factor) and publishing /clock; every stamp is the simulated time it publishes")

    def close(self) -> int:
        """Close any recording. Exit code: 1 if a recording failed to write during the run, else 0."""
        # called after the context is gone (SIGINT/SIGTERM): plain print, rosout can no longer be published to
        self.views.close()
        summary = self.recording.close()
        if summary:
            print(summary, flush=True)
        if self.recording.failed:
            print("error: a recording failed to write during this run (exit code 1)", file=sys.stderr, flush=True)
            return 1
        return 0

    # ------------------------------------------------------------------ callbacks
    def _on_cmd(self, msg: Float64) -> None:
        w = msg.data
        reason = self.device.command(w)
        if reason is None:
            return
        self.get_logger().warn(f"rejected {names.CMD_OMEGA} = {w!r} rad/s: {reason}; keeping "
                               f"omega_T = {self.sim.omega_T:g} rad/s", throttle_duration_sec=2.0)

    def _on_reset(self, request, response):
        self.device.reset()                  # the robot restored, the operator's command and the clock kept
        self._publish_reset("reset")
        if self.timer is not None:          # an inactive managed node holds: it publishes the state once active
            self._publish_state(force_markers=True)
        response.success = True
        response.message = f"robot back at its initial state at simulation time {self.sim_time:.3f} s"
        return response

    def _on_pause(self, request, response):
        self.device.pause(request.data)
        response.success = True
        response.message = "paused" if self.device.paused else "running"
        return response

    def _on_set_parameters(self, params) -> SetParametersResult:
        new = {p.name: p.value for p in params}
        try:
            plan = self.device.prepare(new, (self.recording, self.views))
        except (Refused, SceneError, ValueError) as exc:
            return SetParametersResult(successful=False, reason=one_line(str(exc)))
        except Exception as exc:  # noqa: BLE001 - no value may kill the node: refuse what was not foreseen
            return SetParametersResult(successful=False, reason=one_line(f"{type(exc).__name__}: {exc}"))
        self._apply(plan)
        return SetParametersResult(successful=True)

    def _apply(self, plan: Plan) -> None:
        """Put a prepared set in force: the device's values and simulation, then what the node makes of them.
        Nothing here can refuse."""
        configured = self.configured
        old = self.device.apply(plan)
        if not configured:       # a managed node not yet configured: configure builds from the values
            return
        sim = self.sim if old is not None else None
        if sim is not None:
            self._publish_reset("rebuild")
            self.get_logger().info(f"rebuilt the simulation: scene {sim.scene.scene.name}, "
                                   f"n = {sim.scene.robot.n_flagella}")
        if plan.changed("publish_rate") and self.timer is not None:
            # (an inactive managed node starts its timer at this rate)
            self._deactivate()
            self.timer = self._make_timer()
        if sim is not None or plan.changed("child_frame_id"):
            self._publish_description()
        for out, opened in plan.opened.items():
            out.swap(opened)
        if plan.new.get("use_sim_time") is True:
            self._say_sim_time()

    # ------------------------------------------------------------------ stepping
    def _take_commands(self) -> None:
        """Apply the commands that arrived since the last tick, in order: the newest wins.

        At most the queue depth of them wait (older ones are dropped unseen under a faster stream), so a tick
        costs a bounded number of takes whatever the message rate; a flood of commands handled by the executor
        one callback at a time cost the stepping its time (see runtime.Polled)."""
        for msg in take_all(self._cmd_sub, self._cmd_sub.qos_profile.depth):
            self._on_cmd(msg)

    def _on_timer(self) -> None:
        self._take_commands()
        self.device.advance(STEP_BUDGET / self.publish_rate, 1.0 / self.publish_rate, self._step_failed)
        self._publish_state()
        now = time.monotonic()
        if now - self._last_diag >= DIAG_PERIOD:
            self._last_diag = now
            self._publish_diagnostics()

    def _step_failed(self, why: str) -> None:
        self.get_logger().error(f"step failed, keeping the last good state: {why}", throttle_duration_sec=5.0)

    # ------------------------------------------------------------------ publishing
    def _publish_state(self, force_markers: bool = False) -> None:
        sim = self.sim
        t = self.sim_time
        snap = self.device.observe()
        if snap is None:               # not finite: withheld (and counted)
            return
        R_w = snap.rotation()
        self.pub_clock.publish(convert.clock_msg(t))
        pose = convert.pose_msg(t, self.frame_id, snap.position, R_w)
        self.pub_pose.publish(pose)
        # odometry carries the same pose: the orientation quaternion is computed once per tick
        self.pub_odom.publish(convert.odometry_msg(t, self.frame_id, self.child_frame_id, pose.pose, R_w,
                                                   snap.velocity, snap.angular_velocity))
        joints = convert.joint_state_msg(t, snap.phi_h, snap.phi_t, snap.omega_h, snap.omega_t, snap.drive_angle,
                                         snap.omega_T, snap.motor_torque)
        self.pub_joints.publish(joints)
        if self.pub_tf is not None:     # what robot_state_publisher and an odometry broadcaster would send
            st = stamp_ns_of(pose.header.stamp)
            self.pub_tf.publish(tf_derive.ros_tf_message(
                [tf_derive.head_transform(st, self.frame_id, self.child_frame_id, pose.pose)] +
                (self._tree.joint_transforms(st, joints.name, joints.position) if self._tree else [])))
        self.pub_omega_h.publish(convert.float_msg(snap.omega_h))
        self.pub_omega_t.publish(convert.float_msg(snap.omega_t))
        self.pub_speed.publish(convert.float_msg(snap.v))
        now = time.monotonic()
        if self.marker_rate > 0 and (force_markers or now - self._last_marker >= 1.0 / self.marker_rate):
            self._last_marker = now
            self.pub_markers.publish(self._markers(t))
        self.views.update(sim, snap)

    def _markers(self, t: float) -> MarkerArray:
        sim = self.sim
        o = sim.observer.position(sim.initial)
        rigid = sim.rigid_polylines()
        head = world.to_world(rigid["head"][1], o) if "head" in rigid else None
        arr = convert.markers_msg(
            t, self.frame_id, [world.to_world(c, o) for c in sim.flagella_centrelines()], head,
            sim.scene.head.radius, [world.to_world(a, o) for a in rigid["plate"]], sim.scene.flagellum.radius)
        ids = convert.marker_ids(arr)
        if self._marker_ids is not None and ids != self._marker_ids:
            # the set of markers changed (n_flagella, a scene without a head): clear the old ones first, or a
            # removed flagellum would stay on screen
            arr.markers.insert(0, convert.delete_all_marker(t, self.frame_id))
        self._marker_ids = ids
        return arr

    def _publish_reset(self, cause: str) -> None:
        """Record a restart of the simulated state on ``resets`` (latched, so a later recorder still learns of the
        last one): from this stamp on the robot starts again from its initial state in this scene with this
        command. ``replay --resimulate`` follows a recording across it (msg_docs/sim_node.md)."""
        what = ("~/reset: the robot is back at its initial state" if cause == "reset" else
                "rebuilt: a new scene, n_flagella or scene_overrides, from its initial state")
        self.pub_resets.publish(convert.diagnostics_msg(
            self.sim_time, "flagbot_sim: reset", "OK", what,
            {"cause": cause, "omega_T_rad_s": repr(float(self.sim.omega_T)), "scene_toml": self.sim.scene.to_toml()}))

    def _publish_description(self) -> None:
        """robot_description (latched): the URDF of head and plate, whenever it changes."""
        text = robot_urdf(self.sim.scene, self.child_frame_id)
        if text != self._description:
            self._description = text
            self.pub_description.publish(convert.string_msg(text))
            if self.pub_tf_static is not None:    # the tree serves only what sim_node publishes on /tf itself
                self._tree = TfTree(text)
                self.pub_tf_static.publish(tf_derive.ros_tf_message(
                    self._tree.static_transforms(int(round(self.sim_time * 1e9)))))

    def _problems(self, achieved: float) -> tuple[list[str], list[str]]:
        """(errors, warnings) for the diagnostics: the device's (Device.problems), and an ERROR while the
        recording has failed."""
        errors, warnings = self.device.problems(achieved)
        rec_err = self.recording.check()          # a failed recording stays an ERROR until it is stopped
        if rec_err:
            errors.append(f"recording to {self.recording.path} failed: {rec_err}; nothing more is written (set "
                          f"record to '' or to a new file)")
        return errors, warnings

    def _publish_diagnostics(self) -> None:
        dev, pacer, d = self.device, self.device.pacer, self.sim.diagnostics()
        achieved = pacer.achieved()
        achieved = float("nan") if achieved is None else achieved
        errors, warnings = self._problems(achieved)
        level, message = "OK", "paused" if dev.paused else "running"
        if errors:
            level, message = "ERROR", "; ".join(errors + warnings)
        elif warnings:
            level, message = "WARN", "; ".join(warnings)
        values = {
            "sim_time_s": f"{self.sim_time:.4f}", "omega_T_rad_s": f"{d['omega_T']:.6g}",
            "newton_iterations_last_step": d["newton_iterations_last_step"], "residual_N": f"{d['residual']:.3e}",
            "newton_tolerance_N": f"{d['newton_tolerance']:.3e}",
            "dt_s": d["dt"], "dt_min_last_step_s": f"{d['dt_min_last_step']:.3g}",
            "dt_reductions_total": d["dt_reductions_total"], "dt_reductions_recent": d["dt_reductions_recent"],
            "real_time_factor_achieved": f"{achieved:.3f}", "real_time_factor_requested": self.rtf,
            "behind_schedule_s": f"{pacer.lag:.3g}", "sim_time_given_up_s": f"{pacer.given_up:.3g}",
            "rejected_commands": dev.rejected, "step_failures": dev.step_failures,
            "withheld_non_finite": dev.withheld, "steps": d["steps"], "scene": d["scene"],
            "n_flagella": d["n_flagella"], "recording": self.recording.path,
            "recording_error": recording_error(self.recording.current),
            # the steady-state rule of flagbot run and the sweeps (SteadyDetector), on this run
            "steady": d["steady"], "steady_change": f"{d['steady_change']:.3g}",
            "integrator": d["integrator"], "error_control_rtol": d["error_control_rtol"],
            "live_view": self.views.url,
        }
        self.pub_diag.publish(convert.diagnostics_msg(self.sim_time, "flagbot_sim: simulator", level, message,
                                                      values))


class SimNode(SimAdapter, Node):
    """sim_node as a plain node: configured and active from the start (a bad scene or value ends the process)."""

    def __init__(self):
        Node.__init__(self, "sim_node")
        self._declare(managed=False)
        self._configure()
        self._activate()


class ManagedSimNode(SimAdapter, LifecycleNode):
    """sim_node as a managed (lifecycle) node, ``-p lifecycle:=true``: it starts unconfigured, and an operator or a
    launch system brings it up (configure, activate), holds it (deactivate) and tears it down (cleanup,
    shutdown) through ``~/change_state``. A configure that fails (a bad scene, a file it cannot record to) is
    refused with the reason in the log, and the node stays unconfigured."""

    def __init__(self):
        LifecycleNode.__init__(self, "sim_node")
        self._declare(managed=True)
        self.get_logger().info(f"flagbot_sim {__version__}: managed node, unconfigured; bring it up with "
                               f"{self.get_fully_qualified_name()}/change_state (configure, activate)")

    def on_configure(self, state) -> TransitionCallbackReturn:
        try:
            self._configure()
        except (Refused, SceneError, ValueError) as exc:
            self.get_logger().error(f"configure refused: {one_line(str(exc))}")
            return TransitionCallbackReturn.FAILURE
        self.get_logger().info(f"configured: scene {self.sim.scene.scene.name}, n = "
                               f"{self.sim.scene.robot.n_flagella}, dt = {self.sim.dt} s")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        self._activate()
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self._deactivate()
        self.get_logger().info(f"inactive: holding at simulation time {self.sim_time:.3f} s")
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        self._cleanup()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        self._cleanup()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state) -> TransitionCallbackReturn:
        self._cleanup()
        return TransitionCallbackReturn.SUCCESS


def main(argv: list[str] | None = None) -> int:
    process_exit = argv is None             # the console script / python -m: the process ends with this
    argv = sys.argv if argv is None else argv
    if wants_help(argv):
        print(help_text("sim_node", __doc__.strip().splitlines()[0], PARAMS,
                        "topics: sub cmd_omega; pub /clock, head_pose, odom, joint_states, omega_h, omega_t, speed, "
                        "markers, robot_description, /diagnostics, resets, /tf and /tf_static (where tf2_msgs is "
                        "installed); services: ~/reset, ~/pause"))
        return 0
    try:
        managed = lifecycle_requested(argv)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return run_node(ManagedSimNode if managed else SimNode, argv, process_exit=process_exit)


if __name__ == "__main__":
    sys.exit(main())
