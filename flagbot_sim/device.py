"""The simulated robot as a device, without ROS: its settings, the simulation they build, and the transaction that
changes them (sim_node, flagbot_sim/ros/sim_node.py, is the ROS adapter around it; this module imports no rclpy).

A set of new values is a transaction (:meth:`Device.prepare`, then :meth:`Device.apply`): every changed value is
checked (its name, its range, its text), then the new simulation is built if the scene changed, then the device's
outputs that follow the changed values (a recording, a live view: :class:`Output`) are opened, in that order. The
first refusal raises :class:`Refused` (or SceneError) naming the value and why, discards whatever was opened, and
changes nothing. Applying a prepared set cannot fail.

Configured, it also runs: :meth:`Device.advance` steps towards the real-time schedule (:class:`Pacer`) within a
budget of wall time, a failed step keeps the last good state and is counted, :meth:`Device.observe` withholds a
non-finite state, and :meth:`Device.problems` says what the diagnostics report (ERROR, WARN) with the numbers.

Across a rebuild the device keeps its simulated time running (``time_offset``: the device's clock, ``sim_time``,
never goes back) and the operator's motor command; the robot itself starts again from the new scene's initial
state (pose, drive angle, the simulation's step counts), as after a reset; the device's own counts (rejected commands,
step failures) run on.
"""
from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass, field
from typing import Callable, ContextManager, Protocol, Sequence

from .pacer import Pacer
from .physics import Simulation, Snapshot, StepFailed
from .physics.network import flagellum_edge_count
from .scene import SceneError
from .values import (SCENE_PARAMS, ParamSpec, TimeLimited, command_refusal, frame_refusal, node_scene, one_line,
                     record_refusal, text_refusal)

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
SPECS = {s.name: s for s in PARAMS}

#: every parameter the node has: its own and rclpy's
KNOWN_PARAMS = [s.name for s in PARAMS] + ["use_sim_time", "start_type_description_service"]

BUILD_LIMIT = 5.0       # s: longest a scene load + simulation build may hold a set of new values
# flagellum edges in total: a step of 5300 edges took 0.14 s here, so beyond this one step outlasts many ticks
# and the node could not serve commands between them (the scene itself allows 12 x 20000)
MAX_NODE_EDGES = 5000


class Refused(Exception):
    """A parameter value (or combination) the device refuses; the message is the reason sent back."""


def build_simulation(scene: str, n_flagella: int, scene_overrides,
                     guard: Callable[[], ContextManager] = contextlib.nullcontext) -> Simulation:
    """The simulation a device runs for these parameter values; SceneError (one line) if it cannot be built.
    ``guard()`` is entered around the build (the first compile of the kernels): sim_node makes it interruptible."""
    sc = node_scene(scene, n_flagella, scene_overrides)
    edges = sc.robot.n_flagella * flagellum_edge_count(sc.flagellum.length, sc.flagellum.edge_length)
    if edges > MAX_NODE_EDGES:
        raise SceneError(f"{sc.robot.n_flagella} flagella of {edges // sc.robot.n_flagella} edges: sim_node runs "
                         f"at most {MAX_NODE_EDGES} flagellum edges (a step would take longer than many ticks)")
    try:
        with guard():
            return Simulation(sc)
    except SceneError:
        raise
    except Exception as exc:  # noqa: BLE001 - an unbuildable scene is refused, never a crash of the device
        raise SceneError(one_line(f"cannot build the simulation of scene {sc.scene.name}: "
                                  f"{type(exc).__name__}: {exc}")) from None


def check_values(new: dict) -> None:
    """Refuse a value no later step would catch: a name the device does not have (rclpy 7 lets an undeclared
    parameter named '' through), a value outside its spec (a range, NaN: rclpy checks these before a node sees
    them), a frame id, an overlong string or one with control characters, a non-bool use_sim_time."""
    unknown = [n for n in new if n not in KNOWN_PARAMS]
    if unknown:
        raise Refused(one_line(f"unknown parameter {unknown[0]!r}; sim_node has: {', '.join(KNOWN_PARAMS)}"))
    for name, value in new.items():
        reason = SPECS[name].refusal(value) if name in SPECS else None
        if reason:
            raise Refused(reason)
    for name in ("frame_id", "child_frame_id"):
        if name in new:
            reason = frame_refusal(name, new[name])
            if reason:
                raise Refused(reason)
    for name in ("scene", "record", "foxglove_host"):
        if name in new:
            reason = record_refusal(new[name]) if name == "record" else text_refusal(name, new[name])
            if reason:
                raise Refused(reason)
    # rclpy's time source checks use_sim_time only after the node's callback has accepted the set
    if "use_sim_time" in new and not isinstance(new["use_sim_time"], bool):
        raise Refused("use_sim_time must be true or false")


def same_frames(values: dict) -> None:
    """Refuse frame_id == child_frame_id: the odometry and the head transform would relate a frame to itself."""
    if values["frame_id"] == values["child_frame_id"]:
        raise Refused(f"frame_id and child_frame_id are both {values['frame_id']!r}: the head's frame must differ "
                      "from the fixed frame")


class Output(Protocol):
    """Something the device serves that follows some of its values and may refuse them (a recording's file, a
    live view's port). The transaction opens a new one when one of ``keys`` changes; the caller swaps it in."""

    keys: tuple[str, ...]

    def open(self, values: dict, sim: Simulation) -> object:
        """The output for ``values`` (every value once the set applies) and ``sim`` (the simulation from then
        on), not yet in service; None when these values turn it off. Raises Refused with the reason."""

    def discard(self, opened: object) -> None:
        """Undo an :meth:`open` whose set was refused after it (close it, remove what it created)."""


@dataclass
class Plan:
    """A prepared set of values: checked, everything it implies built, nothing in force yet."""
    new: dict                                   # the values set
    values: dict                                # every value once it applies
    sim: Simulation | None = None               # the rebuilt simulation (None: the simulation stays)
    opened: dict = field(default_factory=dict)  # Output -> what it opened (None: off) for the outputs it changes

    def changed(self, *names: str) -> bool:
        return any(n in self.new for n in names)


class Device:
    """The device's values (every parameter in :data:`PARAMS`), the simulation they build, the command and the
    device's clock. Unconfigured (``sim`` None) it only keeps and checks values; :meth:`configure` builds the
    simulation, :meth:`release` drops it (simulated time carries on from where it was)."""

    def __init__(self, values: dict, guard: Callable[[], ContextManager] = contextlib.nullcontext,
                 build_limit: float = BUILD_LIMIT, clock: Callable[[], float] = time.monotonic):
        """``values``: every parameter's start value (Refused if one is bad); ``guard``: see build_simulation;
        ``clock``: the wall clock the real-time schedule follows."""
        missing = [s.name for s in PARAMS if s.name not in values]
        if missing:
            raise Refused(f"no value for {', '.join(missing)}")
        check_values(values)
        same_frames(values)
        self.values = {s.name: values[s.name] for s in PARAMS}
        self.guard = guard
        self.sim: Simulation | None = None
        self.time_offset = 0.0                   # keeps sim_time monotonic across resets, rebuilds, configurations
        self.clock = clock
        self.pacer: Pacer | None = None
        self._builder = TimeLimited(build_limit, "the scene load and simulation build")

    @property
    def configured(self) -> bool:
        return self.sim is not None

    @property
    def sim_time(self) -> float:
        """The device's clock: simulated time since it first started, across resets and rebuilds."""
        return self.time_offset + self.sim.time

    def _build(self, values: dict) -> Simulation:
        return build_simulation(values["scene"], values["n_flagella"], values["scene_overrides"], self.guard)

    def configure(self) -> Simulation:
        """Build the simulation of the current values, with the motor at ``initial_omega``; the run starts afresh
        (paused if ``start_paused``, every count at zero)."""
        sim = self._build(self.values)
        if sim.has_drive:
            sim.set_omega(self.values["initial_omega"])
        self.sim = sim
        self.paused = bool(self.values["start_paused"])
        self.rejected = 0                        # commands refused
        self.step_failures = 0
        self.withheld = 0                        # non-finite states not published
        self.last_error = ""                     # the current error ('' once a step succeeds again)
        self._last_failure = ""                  # the last step failure's reason
        self._failures_reported = 0              # step_failures when problems() last reported
        self.pacer = Pacer(self.values["real_time_factor"], sim.time, clock=self.clock)
        return sim

    def release(self) -> None:
        """Drop the simulation; the clock keeps the time it reached."""
        if self.sim is not None:
            self.time_offset += self.sim.time
            self.sim = None

    # ---------------------------------------------------------------- the robot
    def command(self, omega: float) -> str | None:
        """Set the motor speed (rad/s) from the next step on; the reason if refused (NaN, |omega| > max_omega),
        and then nothing changes. A scene without a motor or clamp accepts and ignores it."""
        reason = command_refusal(omega, self.values["max_omega"])
        if reason is not None:
            self.rejected += 1
        elif self.sim.has_drive:
            self.sim.set_omega(omega)
        return reason

    def reset(self) -> None:
        """The robot back at its initial state, the current error cleared; the command and the clock carry on."""
        self.time_offset += self.sim.time
        omega = self.sim.omega_T
        self.sim.reset()
        if self.sim.has_drive:
            self.sim.set_omega(omega)        # reset restores the robot, not the operator's command
        self.last_error = ""
        self.anchor()

    def pause(self, paused: bool) -> None:
        self.paused = bool(paused)
        self.anchor()

    def anchor(self) -> None:
        """Restart the real-time schedule at the present (after a reset, a pause, a rebuild, an activation)."""
        self.pacer.anchor(self.sim.time)
        self.pacer.restart_window()

    # ---------------------------------------------------------------- the run
    def advance(self, budget: float, tick_period: float, on_failure: Callable[[str], None] = lambda why: None):
        """One tick (nothing while paused): step towards the schedule for at most ``budget`` s of wall time.
        Fixed steps, or (time.rtol > 0) the error-controlled steps the simulation picks: never truncated to a
        tick, so a recording's re-simulation takes exactly the same steps. A failed step keeps the last good
        state, is counted, and its reason goes to ``on_failure``."""
        if self.paused:
            return
        sim = self.sim

        def steps(n: int, t_stop: float) -> int | None:
            # up to n steps in one compiled call (Simulation.advance: the same steps as one at a time)
            try:
                taken = sim.advance(n, t_stop=t_stop)
            except StepFailed as exc:
                self.step_failures += 1
                self.last_error = self._last_failure = str(exc)
                on_failure(str(exc))
                return None
            self.last_error = ""
            return taken
        self.pacer.advance(lambda: sim.time, steps, budget, None if sim.adaptive else sim.dt, tick_period,
                           log_time=lambda: self.sim_time)

    def observe(self) -> Snapshot | None:
        """The robot's state now (the one observation: the same function makes re-simulation's), or None if it
        is not finite: the physics never returns NaN; a device refuses to pass one on anyway."""
        snap = self.sim.snapshot()
        if not snap.is_finite():
            self.withheld += 1
            self.last_error = "non-finite state withheld from publication"
            return None
        return snap

    def problems(self, achieved: float) -> tuple[list[str], list[str]]:
        """(errors, warnings) since the last call, each a sentence with its numbers; ``achieved`` is the
        real-time factor achieved (NaN: not known yet).

        ERROR: a step failed since the last report (even if a later one succeeded), or the state is withheld.
        WARN: simulated time falls behind the requested real-time factor, or steps are being cut repeatedly
        (Newton failing at the step size asked for: the run crawls)."""
        errors, warnings = [], []
        new_failures = self.step_failures - self._failures_reported
        self._failures_reported = self.step_failures
        if new_failures:
            errors.append(f"{new_failures} step failure{'s' if new_failures > 1 else ''} since the last report "
                          f"({self.step_failures} in total), keeping the last good state: {self._last_failure}")
        elif self.last_error:
            errors.append(self.last_error)
        p = self.pacer
        if p.behind and not self.paused:
            rate = (f"real-time factor {achieved:.3g} achieved over the last {p.window:g} s, "
                    if math.isfinite(achieved) else "real-time factor ")
            text = (f"cannot keep up: {rate}{p.rtf:g} requested; {p.lag:.3g} s of simulated time behind "
                    "schedule")
            if p.given_up > 0:
                text += f", {p.given_up:.3g} s given up since the start to stay live"
            warnings.append(text)
        if self.sim.cutting:
            warnings.append(self.sim.cutting_report())
        return errors, warnings

    # ---------------------------------------------------------------- transactions
    def prepare(self, new: dict, outputs: Sequence[Output] = ()) -> Plan:
        """Everything ``new`` implies, built but not in force; raises Refused or SceneError with the reason and
        leaves nothing behind.

        Order: the plain checks, then (configured only) the new simulation (loaded and built on a worker thread,
        at most ``build_limit`` seconds), then each output whose keys changed, in the order given (put the one
        with an effect outside the device, a recording's file, first: it is discarded if a later one refuses).
        Unconfigured, the values are only checked: the scene and the outputs are built at configure, which refuses
        what cannot be.
        """
        check_values(new)
        after = dict(self.values)
        after.update({k: v for k, v in new.items() if k in after})
        same_frames(after)
        plan = Plan(new=dict(new), values=after)
        if not self.configured:
            return plan
        if set(SCENE_PARAMS) & set(new):
            plan.sim = self._builder.run(lambda: self._build(after))
        try:
            for out in outputs:
                if plan.changed(*out.keys):
                    plan.opened[out] = out.open(after, plan.sim or self.sim)
        except BaseException:
            self.discard(plan)
            raise
        return plan

    def discard(self, plan: Plan) -> None:
        """Undo a prepared set that will not be applied."""
        for out, opened in plan.opened.items():
            if opened is not None:
                out.discard(opened)
        plan.opened.clear()

    def apply(self, plan: Plan) -> Simulation | None:
        """Put a prepared set's values and simulation in force (the caller swaps the outputs in: ``plan.opened``).
        Returns the simulation it replaced, if it rebuilt. Nothing here can refuse."""
        self.values = plan.values
        if self.sim is None:
            return None
        old = None
        if plan.sim is not None:
            old, new = self.sim, plan.sim
            if old.has_drive and new.has_drive:
                new.set_omega(old.omega_T)
            self.time_offset += old.time
            self.sim = new
            self.anchor()
        if plan.changed("real_time_factor"):
            self.pacer.set_rtf(self.values["real_time_factor"], self.sim.time)
        return old
