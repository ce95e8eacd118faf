"""sim_node: the simulated flagellated robot as a ROS 2 device.

Subscribes to the motor command (``cmd_omega``), steps the DER model in a wall-clock timer at the requested
real-time factor, and publishes the head pose, odometry, head/flagellar spin, the flagella as markers, the URDF
of head and plate, /clock and diagnostics, and /tf + /tf_static where tf2_msgs is installed (recordings derive
them where it is not: ros/tf_derive.py). The interface is documented in msg_docs/sim_node.md (a test checks it
against the live node).

Parameter sets are transactions: everything a set implies (the scene load and simulation build, the new
recording's file, the values' checks) is prepared before anything changes, so a refused set leaves parameters,
simulation, timer and recording as they were. The simulator owns the clock: its timer runs on the steady wall
clock whatever ``use_sim_time`` says, and every stamp is the simulated time it publishes on /clock.
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
from ..pacer import Pacer
from ..physics import Simulation, StepFailed
from ..scene import SceneError
from ..tf_tree import TfTree, stamp_ns_of
from ..urdf import robot_urdf
from . import convert, tf_derive
from .. import topics as names
from .dds import configure_dds
from .params import (SCENE_PARAMS, ParamSpec, TimeLimited, command_refusal, declare, frame_refusal, help_text,
                     lifecycle_requested, node_scene, record_refusal, text_refusal)
from .runtime import Polled, interruptible, one_line, run_node, take_all, wants_help

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
    ParamSpec("foxglove_port", 0, "serve the live 3-D view to the Foxglove app on this WebSocket port (needs the "
              "[view] extra); 0 = off", range=(0, 65535)),
    ParamSpec("lifecycle", False, "run as a managed (lifecycle) node: start unconfigured and follow "
              "~/change_state (configure, activate, deactivate, cleanup, shutdown); command line only "
              "(-p lifecycle:=true)", read_only=True),
    ParamSpec("foxglove_host", "127.0.0.1", "address the live view listens on (loopback unless you say "
              "otherwise)"),
]

#: every parameter the node has: its own and rclpy's
KNOWN_PARAMS = [s.name for s in PARAMS] + ["use_sim_time", "start_type_description_service"]

STEP_BUDGET = 0.8       # fraction of a timer period spent stepping; the rest serves commands and services
DIAG_PERIOD = 1.0       # s of wall time between diagnostics
BUILD_LIMIT = 5.0       # s: longest a scene load + simulation build may hold a set-parameters call
# flagellum edges in total: a step of 5300 edges took 0.14 s here, so beyond this one step outlasts many ticks
# and the node could not serve commands between them (the scene itself allows 12 x 20000)
MAX_NODE_EDGES = 5000


class Refused(Exception):
    """A parameter value (or combination) the node refuses; the message is the reason sent back."""


def build_simulation(scene: str, n_flagella: int, scene_overrides) -> Simulation:
    """The simulation a node runs for these parameter values; SceneError (one line) if it cannot be built."""
    sc = node_scene(scene, n_flagella, scene_overrides)
    edges = sc.robot.n_flagella * max(1, round(sc.flagellum.length / sc.flagellum.edge_length))
    if edges > MAX_NODE_EDGES:
        raise SceneError(f"{sc.robot.n_flagella} flagella of {edges // sc.robot.n_flagella} edges: sim_node runs "
                         f"at most {MAX_NODE_EDGES} flagellum edges (a step would take longer than many ticks)")
    try:
        with interruptible():            # Ctrl-C during the first compile stops the node now, not after it
            return Simulation(sc)
    except SceneError:
        raise
    except Exception as exc:  # noqa: BLE001 - an unbuildable scene is refused, never a crash of the node
        raise SceneError(one_line(f"cannot build the simulation of scene {sc.scene.name}: "
                                  f"{type(exc).__name__}: {exc}")) from None


def same_frames(p: dict) -> None:
    """Refuse frame_id == child_frame_id: the odometry and the head transform would relate a frame to itself."""
    if p["frame_id"] == p["child_frame_id"]:
        raise Refused(f"frame_id and child_frame_id are both {p['frame_id']!r}: the head's frame must differ "
                      "from the fixed frame")


def recording_error(recorder) -> str:
    """The recording's write error: '' while healthy (and without a recording); set once, kept until closed."""
    return (recorder.error or "") if recorder is not None else ""


class SimDevice:
    """The simulated robot as a device: everything sim_node does, for the plain node (:class:`SimNode`, which
    configures and activates itself at start) and the managed one (:class:`ManagedSimNode`, whose lifecycle
    transitions call the same steps). The steps:

    * :meth:`_declare` (construction): the parameters and their validation; nothing else exists yet.
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
        p = self._params()
        try:
            self._check_values(p)
            same_frames(p)
        except Refused as exc:
            raise ValueError(str(exc)) from None
        self.sim = None
        self.recorder = None
        self.view = None
        self.timer = None
        self._entities: list = []               # the publishers, subscriptions and services of a configuration
        self.time_offset = 0.0                   # keeps /clock monotonic across resets and configurations
        self.recording_failed = False            # a recording failed to write during this run: exit code 1
        self._said_sim_time = False
        self._said_no_tf = False
        self._tree = None                        # the kinematic tree of the robot_description last published
        self._builder = TimeLimited(BUILD_LIMIT, "the scene load and simulation build")
        self.add_on_set_parameters_callback(self._on_set_parameters)

    @property
    def configured(self) -> bool:
        return self.sim is not None

    def _configure(self) -> None:
        """Build the device from the parameters; on any failure raise (Refused, SceneError, ValueError) with
        everything built so far torn down again."""
        p = self._params()
        sim = build_simulation(p["scene"], p["n_flagella"], p["scene_overrides"])
        try:
            self._create_entities()
            self.sim = sim
            self.publish_rate = p["publish_rate"]
            self.marker_rate = p["marker_rate"]
            self.rtf = p["real_time_factor"]
            self.max_omega = p["max_omega"]
            self.frame_id = p["frame_id"]
            self.child_frame_id = p["child_frame_id"]
            if sim.model.driver is not None:
                sim.set_omega(p["initial_omega"])
            self.paused = bool(p["start_paused"])
            self.rejected = 0
            self.step_failures = 0
            self._failures_reported = 0              # step_failures when the last diagnostics went out
            self._last_failure = ""                  # the last step failure's reason
            self.last_error = ""
            self.withheld = 0
            self.pacer = Pacer(self.rtf, sim.time)
            self._last_marker = -math.inf
            self._last_diag = -math.inf
            self._marker_ids: set | None = None     # (ns, id) of the markers last published
            self._description = ""
            if self.time_offset > 0.0:   # a managed node configured again: the run starts afresh from here
                self._publish_reset("configure")
            if p["record"]:
                self.recorder = self._open_recorder(p, sim)
                self.get_logger().info(f"recording to {self.recorder.path}")
            if p["foxglove_port"]:
                self.view = self._open_view(p)
                self.get_logger().info(f"live view for the Foxglove app at {self.view.url}")
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
        self._anchor()
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
        if self.view is not None:
            self.view.close()
            self.view = None
        if self.recorder is not None:
            rec, self.recorder = self.recorder, None
            self.get_logger().info(self._close_recording(rec))
        destroy = {"Publisher": self.destroy_publisher, "Subscription": self.destroy_subscription,
                   "Service": self.destroy_service}
        for entity in reversed(self._entities):
            destroy[type(entity).__name__](entity)
        self._entities.clear()
        if self.sim is not None:
            self.time_offset += self.sim.time
            self.sim = None

    # ------------------------------------------------------------------ time
    @property
    def sim_time(self) -> float:
        return self.time_offset + self.sim.time

    def _anchor(self) -> None:
        """Restart the real-time schedule at the present (after a reset, a pause, a rebuild)."""
        self.pacer.anchor(self.sim.time)
        self.pacer.restart_window()

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

    def _params(self, new: dict | None = None) -> dict:
        """Every parameter's value once ``new`` applies.

        A set-parameter callback runs before rclpy stores the new values, so get_parameter alone would still
        return the old ones there.
        """
        p = {s.name: self.get_parameter(s.name).value for s in PARAMS}
        p.update({k: v for k, v in (new or {}).items() if k in p})
        return p

    # ------------------------------------------------------------------ recording
    def _open_recorder(self, params: dict, sim: Simulation):
        """A recorder on ``params["record"]`` with ``params`` (every parameter's value once the set applies) and
        ``sim``'s resolved scene (file + overrides + n_flagella) in the metadata, so the recording alone
        reproduces the run. Raises Refused with the reason if the file cannot be created or written."""
        from ..bag import BagWriteError, RunMetadata
        from .recorder import Recorder
        path = params["record"]
        params = dict(params, scene_overrides=list(params["scene_overrides"]))
        meta = RunMetadata(scene_toml=sim.scene.to_toml(), parameters=params)
        try:
            rec = Recorder(self, path, None, meta)
        except BagWriteError as exc:          # its message names the file and why
            raise Refused(str(exc)) from None
        except Exception as exc:  # noqa: BLE001 - a BagError or anything else: refused, with the reason
            raise Refused(f"cannot record to {path!r}: {exc}") from None
        err = recording_error(rec)
        if err:         # opened, but writing its header already failed (a full disk): a file it cannot write
            try:
                rec.close()
            except Exception:  # noqa: BLE001
                pass
            raise Refused(f"cannot record to {path!r}: {err}")
        return rec

    def _open_view(self, params: dict):
        """A live view on ``params["foxglove_port"]``; Refused with the reason if it cannot serve there."""
        from ..optional import MissingExtra
        try:
            from ..view.live import LiveView, ViewError
            return LiveView(host=params["foxglove_host"], port=int(params["foxglove_port"]), frame=params["frame_id"],
                            child_frame=params["child_frame_id"], log=self.get_logger().warning)
        except (MissingExtra, ViewError, ValueError, OSError) as exc:
            raise Refused(one_line(str(exc))) from None

    def _close_recording(self, rec) -> str:
        """Close ``rec``; the summary line to report."""
        try:
            s = rec.close()
        except Exception as exc:  # noqa: BLE001 - a close that fails is reported, it must not kill the node
            self.recording_failed = True
            return f"recording {getattr(rec, 'path', '?')} could not be closed: {type(exc).__name__}: {exc}"
        if s.error:
            self.recording_failed = True
        return (f"recording closed: {s.path}, {s.messages} messages on {len(s.topics)} topics, "
                f"{s.duration:.1f} s, {s.size_bytes / 1024:.0f} KiB"
                + (f", {sum(s.lost.values())} messages lost before reaching it" if any(s.lost.values()) else "")
                + (f", ERROR {s.error}" if s.error else ""))

    def _check_recording(self) -> str:
        """The current recording's write error ('' if none). The recorder logs it itself, once."""
        err = recording_error(self.recorder)
        if err:
            self.recording_failed = True
        return err

    def close(self) -> int:
        """Close any recording. Exit code: 1 if a recording failed to write during the run, else 0."""
        # called after the context is gone (SIGINT/SIGTERM): plain print, rosout can no longer be published to
        if self.view is not None:
            self.view.close()
            self.view = None
        if self.recorder is not None:
            rec, self.recorder = self.recorder, None
            print(self._close_recording(rec), flush=True)
        if self.recording_failed:
            print("error: a recording failed to write during this run (exit code 1)", file=sys.stderr, flush=True)
            return 1
        return 0

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
        self._publish_reset("reset")
        if self.timer is not None:          # an inactive managed node holds: it publishes the state once active
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

    def _check_values(self, p: dict) -> None:
        """Refuse values that no later step would catch: frame ids, overlong strings, a non-bool use_sim_time,
        and names this node does not have (rclpy 7 lets an undeclared parameter named '' through)."""
        unknown = [n for n in p if n not in KNOWN_PARAMS]
        if unknown:
            raise Refused(one_line(f"unknown parameter {unknown[0]!r}; sim_node has: {', '.join(KNOWN_PARAMS)}"))
        for name in ("frame_id", "child_frame_id"):
            if name in p:
                reason = frame_refusal(name, p[name])
                if reason:
                    raise Refused(reason)
        for name in ("scene", "record", "foxglove_host"):
            if name in p:
                reason = record_refusal(p[name]) if name == "record" else text_refusal(name, p[name])
                if reason:
                    raise Refused(reason)
        # rclpy's time source checks use_sim_time only after this node's callback has accepted the set
        if "use_sim_time" in p and not isinstance(p["use_sim_time"], bool):
            raise Refused("use_sim_time must be true or false")

    def _on_set_parameters(self, params) -> SetParametersResult:
        new = {p.name: p.value for p in params}
        try:
            plan = self._prepare(new)
        except (Refused, SceneError, ValueError) as exc:
            return SetParametersResult(successful=False, reason=one_line(str(exc)))
        except Exception as exc:  # noqa: BLE001 - no value may kill the node: refuse what was not foreseen
            return SetParametersResult(successful=False, reason=one_line(f"{type(exc).__name__}: {exc}"))
        self._apply(new, plan)
        return SetParametersResult(successful=True)

    def _prepare(self, new: dict) -> dict:
        """Everything ``new`` implies, built but not yet in force; raises Refused or SceneError with the reason.

        Order: plain checks, then the new simulation (loaded and built off the executor thread, at most
        BUILD_LIMIT seconds), then the new recording's file last (the only step with an effect outside this
        node: its recorder raises and leaves no file when it cannot create or write the file).
        """
        self._check_values(new)
        after = self._params(new)
        same_frames(after)
        if not self.configured:      # a managed node not yet configured: the values are checked, the scene and
            return {}                # the files are at configure (which refuses what cannot be built)
        sim = None
        if set(SCENE_PARAMS) & set(new):
            sim = self._builder.run(lambda: build_simulation(after["scene"], after["n_flagella"],
                                                             after["scene_overrides"]))
        rec = self._open_recorder(after, sim or self.sim) if new.get("record") else None
        view = None
        if ({"foxglove_port", "foxglove_host"} & set(new)) and after["foxglove_port"]:
            try:
                view = self._open_view(after)
            except Refused:
                if rec is not None:            # refused as a whole: the new recording's file goes too
                    self._discard(rec)
                raise
        return {"sim": sim, "recorder": rec, "view": view}

    def _discard(self, rec) -> None:
        import os
        path = getattr(rec, "path", None)
        try:
            rec.close()
        except Exception:  # noqa: BLE001
            pass
        if path:
            try:
                os.remove(path)
            except OSError:
                pass

    def _apply(self, new: dict, plan: dict) -> None:
        """Put a prepared set in force. Nothing here can refuse."""
        if not self.configured:
            return
        sim = plan["sim"]
        if sim is not None:
            if self.sim.model.driver is not None and sim.model.driver is not None:
                sim.set_omega(self.sim.omega_T)
            self.time_offset += self.sim.time
            self.sim = sim
            self._anchor()
            self._publish_reset("rebuild")
            self.get_logger().info(f"rebuilt the simulation: scene {sim.scene.scene.name}, "
                                   f"n = {sim.scene.robot.n_flagella}")
        if "publish_rate" in new:
            self.publish_rate = float(new["publish_rate"])
            if self.timer is not None:       # (an inactive managed node starts its timer at this rate)
                self._deactivate()
                self.timer = self._make_timer()
        if "real_time_factor" in new:
            self.rtf = float(new["real_time_factor"])
            self.pacer.set_rtf(self.rtf, self.sim.time)
        for name in ("marker_rate", "max_omega", "frame_id", "child_frame_id"):
            if name in new:
                setattr(self, name, new[name])
        if sim is not None or "child_frame_id" in new:
            self._publish_description()
        if "record" in new:
            old, self.recorder = self.recorder, plan["recorder"]
            if old is not None:
                self.get_logger().info(self._close_recording(old))
            if self.recorder is not None:
                self.get_logger().info(f"recording to {self.recorder.path}")
        if {"foxglove_port", "foxglove_host"} & set(new):
            old, self.view = self.view, plan["view"]
            if old is not None:
                old.close(linger=0.0)
            if self.view is not None:
                self.get_logger().info(f"live view for the Foxglove app at {self.view.url}")
        if new.get("use_sim_time") is True:
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
        wall_start = time.monotonic()
        if not self.paused:
            self._advance(wall_start)
        self._publish_state()
        now = time.monotonic()
        if now - self._last_diag >= DIAG_PERIOD:
            self._last_diag = now
            self._publish_diagnostics()

    def _advance(self, wall_start: float) -> None:
        # fixed steps, or (time.rtol > 0) the error-controlled steps the simulation picks: never truncated to a
        # tick, so a recording's re-simulation takes exactly the same steps
        self.pacer.advance(lambda: self.sim.time, self._step, STEP_BUDGET / self.publish_rate,
                           None if self.sim.adaptive else self.sim.dt, 1.0 / self.publish_rate,
                           log_time=lambda: self.sim_time)

    def _step(self) -> bool:
        try:
            self.sim.step()
        except StepFailed as exc:
            self.step_failures += 1
            self.last_error = self._last_failure = str(exc)
            self.get_logger().error(f"step failed, keeping the last good state: {exc}", throttle_duration_sec=5.0)
            return False
        self.last_error = ""
        return True

    # ------------------------------------------------------------------ publishing
    def _publish_state(self, force_markers: bool = False) -> None:
        sim = self.sim
        t = self.sim_time
        snap = sim.snapshot()          # the one observation: the same function makes re-simulation's
        if not snap.is_finite():       # the physics never returns NaN; refuse to pass one on anyway
            self.withheld += 1
            self.last_error = "non-finite state withheld from publication"
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
        if self.view is not None:
            self.view.update(sim, snapshot=snap)

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
        """(errors, warnings) for the diagnostics, each a sentence with its numbers.

        ERROR: a step failed since the last report (even if a later one succeeded), the state is withheld, or the
        recording failed. WARN: simulated time falls behind the requested real-time factor, or steps are being
        cut repeatedly (Newton failing at the step size asked for: the run crawls)."""
        errors, warnings = [], []
        new_failures = self.step_failures - self._failures_reported
        self._failures_reported = self.step_failures
        if new_failures:
            errors.append(f"{new_failures} step failure{'s' if new_failures > 1 else ''} since the last report "
                          f"({self.step_failures} in total), keeping the last good state: {self._last_failure}")
        elif self.last_error:
            errors.append(self.last_error)
        rec_err = self._check_recording()          # a failed recording stays an ERROR until it is stopped
        if rec_err:
            errors.append(f"recording to {self.recorder.path} failed: {rec_err}; nothing more is written (set "
                          f"record to '' or to a new file)")
        p = self.pacer
        if p.behind and not self.paused:
            rate = (f"real-time factor {achieved:.3g} achieved over the last {p.window:g} s, "
                    if math.isfinite(achieved) else "real-time factor ")
            text = (f"cannot keep up: {rate}{self.rtf:g} requested; {p.lag:.3g} s of simulated time behind "
                    "schedule")
            if p.given_up > 0:
                text += f", {p.given_up:.3g} s given up since the start to stay live"
            warnings.append(text)
        if self.sim.cutting:
            warnings.append(self.sim.cutting_report())
        return errors, warnings

    def _publish_diagnostics(self) -> None:
        sim, st = self.sim, self.sim.last_stats
        achieved = self.pacer.achieved()
        achieved = float("nan") if achieved is None else achieved
        errors, warnings = self._problems(achieved)
        level, message = "OK", "paused" if self.paused else "running"
        if errors:
            level, message = "ERROR", "; ".join(errors + warnings)
        elif warnings:
            level, message = "WARN", "; ".join(warnings)
        values = {
            "sim_time_s": f"{self.sim_time:.4f}", "omega_T_rad_s": f"{sim.omega_T:.6g}",
            "newton_iterations_last_step": st.newton_iterations, "residual_N": f"{st.residual:.3e}",
            "newton_tolerance_N": f"{sim.model.force_tol:.3e}",
            "dt_s": sim.dt, "dt_min_last_step_s": f"{st.dt_min:.3g}", "dt_reductions_total": sim.reductions,
            "dt_reductions_recent": sim.recent_reductions,
            "real_time_factor_achieved": f"{achieved:.3f}", "real_time_factor_requested": self.rtf,
            "behind_schedule_s": f"{self.pacer.lag:.3g}", "sim_time_given_up_s": f"{self.pacer.given_up:.3g}",
            "rejected_commands": self.rejected, "step_failures": self.step_failures,
            "withheld_non_finite": self.withheld, "steps": sim.steps, "scene": sim.scene.scene.name,
            "n_flagella": sim.scene.robot.n_flagella,
            "recording": self.recorder.path if self.recorder is not None else "",
            "recording_error": recording_error(self.recorder),
            # the steady-state rule of flagbot run and the sweeps (SteadyDetector), on this run
            "steady": sim.steady, "steady_change": f"{sim.steady_detector.change:.3g}",
            "integrator": sim.stepper.integrator.name, "error_control_rtol": sim.stepper.rtol,
            "live_view": self.view.url if self.view is not None else "",
        }
        self.pub_diag.publish(convert.diagnostics_msg(self.sim_time, "flagbot_sim: simulator", level, message,
                                                      values))


class SimNode(SimDevice, Node):
    """sim_node as a plain node: configured and active from the start (a bad scene or value ends the process)."""

    def __init__(self):
        Node.__init__(self, "sim_node")
        self._declare(managed=False)
        self._configure()
        self._activate()


class ManagedSimNode(SimDevice, LifecycleNode):
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
