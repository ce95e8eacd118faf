"""Re-simulation of a recorded run: feed the recorded commands to a fresh simulator and compare the motion.

The recording holds the resolved scene (metadata ``flagbot_sim``: scene file + overrides + n_flagella) and the
``joint_states`` stream, whose ``motor`` joint carries the command in force (velocity) and its integral (position)
at every published simulation time. Between two samples with different commands the integral pins the step at
which the new command took effect exactly:

    t_switch = t_k + (phi_{k+1} - phi_k - w_{k+1} (t_{k+1} - t_k)) / (w_k - w_{k+1}),  rounded to a step of dt,

so the re-simulation applies every command at the same step as the original run and should reproduce it to
round-off. Pose (``head_pose``), omega_h and omega_t (``joint_states``) are compared at every recorded stamp.

Restarts. sim_node publishes on ``resets`` (latched) every time its simulated state starts again from the
robot's initial state: a ``~/reset`` call or a rebuild (new scene, n_flagella or overrides), with the stamp, the
command kept and the resolved scene. The recording is cut into segments there, and each segment is re-simulated
from that initial state, as the node did. A command reversal is a command like any other. A recording without
the topic (made before it existed, or by a recorder told to leave it out) can still show a restart as a
discontinuity that no command can cause: the motor angle moving further between two samples than the largest
command of the run turns it. The comparison stops there, since the recording does not say what the state became.

Verdict: the run is reproduced when the whole recording was compared (every sample after the initial state of a
segment) and the largest differences stay within :data:`POSITION_TOLERANCE` and :data:`RATE_TOLERANCE`. Anything
less than the whole recording is PARTIAL, with the compared duration, its fraction and the reason. With the
version that recorded it the difference is exactly 0; a later solver (another predictor, linear solver or build)
stops its Newton iterations elsewhere inside the force tolerance (``numerics.force_tol``, 1e-7 of EI/L^2), which
moves the head by ~1e-11 m and the per-step spin rates (a displacement difference divided by dt) by ~1e-7 rad/s,
measured on the sample recordings in bags/. The tolerances leave a factor of ~50-500 over that; a different
command stream, scene or physics shows up orders of magnitude above them (1 % more medium viscosity: 6e-3 rad/s
in omega_h within 3 s, tests/test_replay_cli.py).
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np

from ..bag import BagReader, find_topic, header_seconds
from ..physics import Simulation, StepFailed
from ..topics import HEAD_POSE, JOINT_STATES, RESETS, node_overrides
from ..scene import Scene, SceneError, scene_from_dict

#: largest head position difference (m) still counted as the same motion: Newton's tolerance, see above
POSITION_TOLERANCE = 1e-8
#: largest omega_h / omega_t difference (rad/s) still counted as the same motion
RATE_TOLERANCE = 1e-5
#: largest |cmd_omega| sim_node accepts when the recording does not say (the range of its max_omega parameter)
MAX_COMMAND = 1e4


class ResimulationError(ValueError):
    pass


@dataclass
class Resimulation:
    samples: int                        # recorded joint_states samples (one per stamp)
    compared_samples: int               # of which compared with the re-simulation
    recorded_duration: float            # s of simulated time from the first sample to the last
    compared_duration: float            # s of it whose motion was compared (each sample checks the time before it)
    complete: bool                      # every sample after a segment's initial state was compared
    commands: list                      # [(t_switch, omega_T)] in recording time
    restarts: list                      # [{"t", "cause", "omega_T"}]: the recorded resets and rebuilds
    parts: int                          # segments simulated, each from an initial state (1 + restarts recorded)
    max_position_error: float           # m
    max_omega_h_error: float            # rad/s
    max_omega_t_error: float            # rad/s
    notes: list = field(default_factory=list)
    #: why part of the recording was not compared (empty when complete)
    uncompared: list = field(default_factory=list)

    @property
    def fraction(self) -> float:
        """Compared share of the recorded duration (1.0 for a whole recording)."""
        if self.complete and self.compared_samples:
            return 1.0
        return self.compared_duration / self.recorded_duration if self.recorded_duration > 0 else 0.0

    @property
    def matches(self) -> bool:
        """The compared part is within the solver tolerance."""
        return (self.max_position_error <= POSITION_TOLERANCE
                and max(self.max_omega_h_error, self.max_omega_t_error) <= RATE_TOLERANCE)

    @property
    def status(self) -> str:
        """NOT CHECKED (nothing compared), DIFFERS, PARTIAL (what was compared matches, but not all of it) or
        REPRODUCED (all of it, within tolerance)."""
        if self.compared_samples == 0:
            return "NOT CHECKED"
        if not self.matches:
            return "DIFFERS"
        return "REPRODUCED" if self.complete else "PARTIAL"

    @property
    def reproduced(self) -> bool:
        """True only when the whole recording was compared and matches within the solver tolerance."""
        return self.status == "REPRODUCED"

    def coverage(self) -> str:
        """'2.670 s of the 2.670 s recorded (100 %)', with the recorded restarts."""
        parts = f", in {self.parts} parts split at recorded restarts" if self.parts > 1 else ""
        return (f"{self.compared_duration:.3f} s of the {self.recorded_duration:.3f} s recorded "
                f"({100 * self.fraction:.1f} %{parts})")

    def verdict(self) -> str:
        """One line: reproduced or not, by how much against the tolerance, and over how much of the recording."""
        tol = f"tolerance {POSITION_TOLERANCE:.0e} m in head position, {RATE_TOLERANCE:.0e} rad/s in omega_h/omega_t"
        why = "; ".join(self.uncompared)
        status = self.status
        if status == "NOT CHECKED":
            return (f"verdict: NOT CHECKED: no recorded sample could be compared ({why or 'nothing to compare'}; "
                    f"{tol})")
        if status == "REPRODUCED":
            return f"verdict: REPRODUCED: compared {self.coverage()}: matches the recording within the {tol}"
        if status == "PARTIAL":
            return (f"verdict: PARTIAL: compared only {self.coverage()}: {why}; the part compared matches within "
                    f"the {tol}")
        over = []
        if self.max_position_error > POSITION_TOLERANCE:
            over.append(f"head position by {self.max_position_error:.3e} m")
        for name, err in (("omega_h", self.max_omega_h_error), ("omega_t", self.max_omega_t_error)):
            if err > RATE_TOLERANCE:
                over.append(f"{name} by {err:.3e} rad/s")
        return f"verdict: DIFFERS: {', '.join(over)}, beyond the {tol} (compared {self.coverage()})"

    def to_dict(self) -> dict:
        return dict(self.__dict__, fraction=self.fraction, status=self.status, reproduced=self.reproduced,
                    verdict=self.verdict(), tolerance={"position_m": POSITION_TOLERANCE, "rate_rad_s": RATE_TOLERANCE})


def motor_samples(js: list) -> tuple[list, np.ndarray, np.ndarray, np.ndarray] | None:
    """Decoded ``joint_states`` messages -> one sample per stamp, in time order: (messages, t, motor angle, motor
    rate); None when there is no ``motor`` joint. Of several messages with one stamp the first recorded is kept: a
    paused node repeats its state, and at a restart the state before it comes first (the one after it is the
    initial state, which the re-simulation knows)."""
    if not js or "motor" not in js[0].name:
        return None
    seen, samples = set(), []
    for m in sorted(js, key=header_seconds):
        ts = round(header_seconds(m), 9)
        if ts not in seen:
            seen.add(ts)
            samples.append(m)
    k = samples[0].name.index("motor")
    return (samples, np.array([header_seconds(m) for m in samples]), np.array([m.position[k] for m in samples]),
            np.array([m.velocity[k] for m in samples]))


#: how far (s) an inferred switch time may fall outside the samples around it: the stamps' nanosecond rounding
STAMP_SLACK = 1e-8


def angle_tolerance(w: float, angle: float) -> float:
    """How far (rad) a recorded motor angle may be from the integral of the commands: round-off of the angle's
    sum, and a command times the stamps' nanosecond rounding."""
    return 1e-6 + 2e-9 * abs(w) + 1e-12 * abs(angle)


def command_schedule(t: np.ndarray, angle: np.ndarray, rate: np.ndarray, dt: float | None, t0: float = 0.0
                     ) -> tuple[list, list]:
    """[(t_switch, omega)] from the motor joint samples (the first entry starts at t[0]); switch times rounded to
    steps of dt (None: not rounded). Also notes about anything that could not be pinned, their times shifted by
    ``t0`` (a segment's start in the recording)."""
    notes = []
    schedule = [(float(t[0]), float(rate[0]))]
    for k in range(len(t) - 1):
        wa, wb = rate[k], rate[k + 1]
        if wa == wb:
            turned, expected = angle[k + 1] - angle[k], wa * (t[k + 1] - t[k])
            if abs(turned - expected) > angle_tolerance(wa, angle[k + 1]):
                notes.append(f"between t = {t0 + t[k]:.4f} s and {t0 + t[k + 1]:.4f} s the motor turned "
                             f"{turned:+.6g} rad, not the {expected:+.6g} rad of the command in force before and "
                             "after: the command changed and changed back in between")
            continue
        ts = t[k] + (angle[k + 1] - angle[k] - wb * (t[k + 1] - t[k])) / (wa - wb)
        off_step = False
        if dt is not None:
            n = round(ts / dt)
            off_step = abs(ts / dt - n) > 1e-3
            ts = n * dt
        # (stamps are whole nanoseconds: a switch at a sample's own step is found within a few ns of it)
        if off_step or not (t[k] - STAMP_SLACK <= ts <= t[k + 1] + STAMP_SLACK):
            notes.append(f"between t = {t0 + t[k]:.4f} s and {t0 + t[k + 1]:.4f} s the command changed more than "
                         f"once (or off a step); its switch time is taken as {t0 + ts:.4f} s")
        schedule.append((float(ts), float(wb)))
    return schedule, notes


def first_jump(t: np.ndarray, angle: np.ndarray, bound: float) -> int | None:
    """The first index k whose motor angle moved from sample k-1 by more than any command up to ``bound`` rad/s
    can turn it in the time between: a restart of the state (the angle is back at 0); None if there is none."""
    for k in range(1, len(t)):
        if abs(angle[k] - angle[k - 1]) > bound * (t[k] - t[k - 1]) + angle_tolerance(bound, angle[k - 1]):
            return k
    return None


# ---------------------------------------------------------------- restarts and segments

@dataclass(frozen=True)
class Restart:
    """One message of sim_node's ``resets`` topic: at recording time ``t`` the simulated state started again from
    the robot's initial state in the scene ``scene_toml``, with the command ``omega_T`` kept."""
    t: float
    cause: str                   # 'reset' (the ~/reset service) or 'rebuild' (new scene, n_flagella, overrides)
    omega_T: float
    scene_toml: str


def recorded_restarts(msgs: list, path) -> list[Restart]:
    """The restarts in decoded ``resets`` messages (diagnostic_msgs/DiagnosticArray), in time order."""
    out = set()
    for m in msgs:
        for status in m.status:
            values = {kv.key: kv.value for kv in status.values}
            try:
                out.add(Restart(round(header_seconds(m), 9), values["cause"], float(values["omega_T_rad_s"]),
                                values["scene_toml"]))
            except (KeyError, ValueError) as exc:
                raise ResimulationError(f"{path}: a {RESETS} message at t = {header_seconds(m):.3f} s lacks "
                                        f"{exc}: not written by sim_node") from None
    return sorted(out, key=lambda r: r.t)


@dataclass
class Segment:
    """Part of a recording simulated from one initial state: the run's start, or a restart."""
    start: float                 # recording time at which this segment's simulation time is 0
    cause: str                   # 'start', 'reset' or 'rebuild'
    scene: Scene
    index: list                  # indices of its samples (into ReplayPlan.t), in time order
    schedule: list               # [(t_switch, omega_T)] in the segment's own simulation time
    compare_until: int           # samples index[:compare_until] can be compared (the rest follow a jump)


@dataclass
class ReplayPlan:
    """How to re-run a recording: its samples (one per stamp), cut into segments at the recorded restarts."""
    samples: list
    t: np.ndarray
    segments: list
    restarts: list
    notes: list
    uncompared: list             # why samples are left out: an unrecorded restart, samples before the first one

    def commands(self) -> list:
        """[(t_switch, omega_T)] in recording time, over every segment."""
        return [(seg.start + ts, w) for seg in self.segments for ts, w in seg.schedule]


def _scene_toml(text: str, path, what: str) -> Scene:
    try:
        return scene_from_dict(tomllib.loads(text))
    except (SceneError, tomllib.TOMLDecodeError) as exc:
        raise ResimulationError(f"{path}: {what} does not load: {exc}") from None


def replay_plan(motor: tuple, restarts: list[Restart], scene: Scene, parameters: dict, path,
                records_resets: bool = True) -> ReplayPlan:
    """Cut the motor samples into segments at the restarts and read each segment's command schedule.
    ``records_resets``: the recording has the ``resets`` topic (for the message about an unrecorded restart)."""
    samples, t, angle, rate = motor
    notes, uncompared = [], []
    bounds = [(0.0, "start", scene, float(parameters.get("initial_omega", rate[0])))]
    bounds += [(r.t, r.cause, _scene_toml(r.scene_toml, path, f"the scene of the {r.cause} at t = {r.t:.3f} s"),
                r.omega_T) for r in restarts]
    if len(bounds) > 1 and bounds[1][0] <= t[0] + 0.5e-9:
        # the recording began after a restart (it has the latched message): it starts from the last such one
        while len(bounds) > 1 and bounds[1][0] <= t[0] + 0.5e-9:
            bounds = bounds[1:]
        before = int(np.count_nonzero(t <= bounds[0][0] + 0.5e-9))
        if before:
            notes.append(f"{before} sample(s) at the instant of the {bounds[0][1]} at t = {bounds[0][0]:.3f} s, "
                         "the state before it: the recording began there, so they are not compared")
    bound = max(float(parameters.get("max_omega", MAX_COMMAND)), float(np.max(np.abs(rate))))
    segments = []
    for j, (start, cause, sc, omega0) in enumerate(bounds):
        end = bounds[j + 1][0] if j + 1 < len(bounds) else math.inf
        # a sample stamped at a restart is the state before it (motor_samples keeps the first of a stamp)
        lo = start - 0.5e-9 if cause == "start" else start + 0.5e-9
        index = [k for k in range(len(t)) if lo < t[k] <= end + 0.5e-9]
        if not index:
            continue
        lt, la, lw = t[index] - start, angle[index], rate[index]
        # the segment begins in its initial state (motor angle 0, command omega0): at its first sample, or before
        shift = int(cause != "start" or lt[0] > 0.5 * sc.time.dt)
        if shift:
            lt, la, lw = np.r_[0.0, lt], np.r_[0.0, la], np.r_[omega0, lw]
        jump = first_jump(lt, la, bound)
        compare_until = len(index)
        if jump is not None:
            compare_until = jump - shift                  # samples index[compare_until:] follow the jump
            lt, la, lw = lt[:jump], la[:jump], lw[:jump]
            at = t[index[compare_until]]
            if compare_until == 0:
                uncompared.append(f"the motor angle at the first sample (t = {at:.3f} s) is further from 0 than any "
                                  f"command up to {bound:g} rad/s turns it since t = {start:.3f} s: the run was "
                                  "restarted before the recording began, and the recording does not say when")
            else:
                before = t[index[compare_until - 1]]
                why = "it has no resets topic" if not records_resets else f"none on its {RESETS} topic"
                uncompared.append(f"between t = {before:.3f} s and {at:.3f} s the motor angle jumps by "
                                  f"{angle[index[compare_until]] - angle[index[compare_until - 1]]:+.4g} rad, more "
                                  f"than any command up to {bound:g} rad/s turns it in {at - before:.3g} s: a "
                                  f"restart that the recording does not record ({why}), so the "
                                  f"{t[index[-1]] - before:.3f} s from there on are not compared")
        schedule, more = command_schedule(lt, la, lw, None if sc.time.rtol > 0 else sc.time.dt, t0=start)
        notes += more
        segments.append(Segment(start, cause, sc, index, schedule, compare_until))
    return ReplayPlan(samples, t, segments, restarts, notes, uncompared)


def replay(plan: ReplayPlan, progress: Callable[[float], None] | None = None
           ) -> Iterator[tuple[int, Simulation | None, str]]:
    """Run the recorded commands through the simulator, segment by segment, as sim_node did (a reset resets the
    simulation, a rebuild or the start builds one); yield ``(sample index, simulation, '')`` at every sample the
    re-simulation reaches on a step, ``(index, None, why)`` for a sample it cannot compare. A step that fails ends
    the segment (its remaining samples are yielded with the reason)."""
    sim = None
    t_end = plan.t[-1] if len(plan.t) else 0.0
    for seg in plan.segments:
        if seg.cause == "reset" and sim is not None and sim.scene.to_dict() == seg.scene.to_dict():
            sim.reset()
        else:
            sim = Simulation(seg.scene)
        if sim.model.driver is not None:
            sim.set_omega(seg.schedule[0][1])
        slack = 1e-7 if sim.adaptive else 0.5 * sim.dt
        nxt, failed = 1, ""
        for j, k in enumerate(seg.index):
            if failed or j >= seg.compare_until:
                yield k, None, failed or "after an unrecorded restart"
                continue
            target = plan.t[k] - seg.start
            try:
                while sim.time < target - slack:
                    if nxt < len(seg.schedule) and sim.time >= seg.schedule[nxt][0] - slack:
                        sim.set_omega(seg.schedule[nxt][1])
                        nxt += 1
                    sim.step()
            except StepFailed as exc:
                failed = f"the re-simulation's step at t = {seg.start + sim.time:.4f} s failed ({exc})"
                yield k, None, failed
                continue
            if abs(sim.time - target) > 1e-6:
                yield k, None, f"recorded stamp {plan.t[k]:.6f} s is not on a step of the re-simulation"
                continue
            yield k, sim, ""
            if progress is not None and t_end > 0:
                progress(plan.t[k] / t_end)


def recorded_scene(meta, path):
    """The scene a recording ran (its ``flagbot_sim`` metadata: scene file + the node's overrides)."""
    if meta is None or not meta.scene_toml:
        raise ResimulationError(f"{path}: no flagbot_sim metadata with the scene: not recorded by sim_node's "
                                "`record` parameter or `record --params-from /sim_node`")
    try:
        data = tomllib.loads(meta.scene_toml)
        # a resolved scene (sim_node's recorder writes every section) without time.integrator was recorded before
        # that key existed, when implicit Euler was the only integrator (the default is BDF2 since)
        resolved = {"scene", "robot", "motor", "time", "flagellum", "medium", "head", "plate", "numerics", "observe"}
        if resolved <= set(data) and isinstance(data["time"], dict) and "integrator" not in data["time"]:
            data["time"]["integrator"] = "implicit_euler"
        scene = scene_from_dict(data)
        # a standalone recorder stores the scene file as written: apply the node's overrides (idempotent on the
        # resolved scene that sim_node's own recorder stores)
        extra = node_overrides(meta.parameters.get("n_flagella", 0), meta.parameters.get("scene_overrides", []))
        if extra:
            scene = scene.with_overrides(extra)
    except (SceneError, tomllib.TOMLDecodeError) as exc:
        raise ResimulationError(f"{path}: the recorded scene does not load: {exc}") from None
    return scene


def read_recording(path, namespace: str | None = None, with_pose: bool = True):
    """(metadata, joint_states messages, {stamp: head position} or None, restarts (None: no resets topic),
    notes) of a recording."""
    with BagReader(path) as r:
        meta = r.run_metadata()
        if meta is None or not meta.scene_toml:
            raise ResimulationError(f"{path}: no flagbot_sim metadata with the scene: not recorded by sim_node's "
                                    "`record` parameter or `record --params-from /sim_node`")
        js_topic = find_topic(r.topics, JOINT_STATES, namespace)
        pose_topic = find_topic(r.topics, HEAD_POSE, namespace) if with_pose else None
        if js_topic is None or (with_pose and pose_topic is None):
            raise ResimulationError(f"{path}: needs the joint_states" + (" and head_pose topics" if with_pose else
                                                                         " topic"))
        resets_topic = find_topic(r.topics, RESETS, namespace)
        rows = r.decoded_many([x for x in (js_topic, pose_topic, resets_topic) if x is not None])
        js = [m for _, _, m in rows[js_topic]]
        poses = None
        if pose_topic is not None:
            poses = {}
            for _, _, m in sorted(rows[pose_topic], key=lambda row: header_seconds(row[2])):
                poses.setdefault(round(header_seconds(m), 9), m.pose.position)    # the first of a stamp, as above
        restarts = recorded_restarts([m for _, _, m in rows[resets_topic]], path) if resets_topic else None
        notes = [] if r.report.ok else [f"the recording is damaged: {r.report.describe_loss()}"]
    return meta, js, poses, restarts, notes


def plan_recording(path, namespace: str | None = None, with_pose: bool = True):
    """(ReplayPlan, head positions by stamp or None) of a recording; ResimulationError when it cannot be re-run."""
    meta, js, poses, restarts, notes = read_recording(path, namespace, with_pose)
    motor = motor_samples(js)
    if motor is None:
        raise ResimulationError(f"{path}: joint_states has no 'motor' joint (recorded by an older version?)")
    plan = replay_plan(motor, restarts or [], recorded_scene(meta, path), meta.parameters, path,
                       records_resets=restarts is not None)
    plan.notes[:0] = notes
    return plan, poses


def resimulate(path, namespace: str | None = None, progress=None) -> Resimulation:
    """Re-simulate a recording; ``progress(fraction)`` is called as it goes."""
    plan, poses = plan_recording(path, namespace)
    t = plan.t
    err_x = err_h = err_t = 0.0
    compared, covered = 0, 0.0
    first = {seg.index[0] for seg in plan.segments if seg.cause == "start"}
    skipped: dict[str, int] = {}
    for k, sim, why in replay(plan, progress):
        if sim is None:
            skipped[why] = skipped.get(why, 0) + 1
            continue
        if sim.steps == 0:
            continue                                   # the initial state: before the first step there is no rate
        m = plan.samples[k]
        snap = sim.snapshot()            # the observation sim_node published, made by the same function
        err_h = max(err_h, abs(snap.omega_h - m.velocity[0]))
        err_t = max(err_t, abs(snap.omega_t - m.velocity[1]))
        p = poses.get(round(t[k], 9))
        if p is not None:
            err_x = max(err_x, float(np.linalg.norm(snap.position - np.array([p.x, p.y, p.z]))))
        compared += 1
        if k > 0 and k not in first:
            covered += t[k] - t[k - 1]       # this sample checks the motion since the one before
    uncompared = list(plan.uncompared)
    for why, n in skipped.items():
        if why != "after an unrecorded restart":
            uncompared.append(f"{n} sample(s) not compared: {why}")
    recorded = float(t[-1] - t[0]) if len(t) else 0.0
    complete = not uncompared and compared > 0
    return Resimulation(samples=len(t), compared_samples=compared, recorded_duration=recorded,
                        compared_duration=recorded if complete else covered, complete=complete,
                        commands=plan.commands(),
                        restarts=[{"t": r.t, "cause": r.cause, "omega_T": r.omega_T} for r in plan.restarts],
                        parts=len(plan.segments),
                        max_position_error=err_x, max_omega_h_error=err_h, max_omega_t_error=err_t,
                        notes=plan.notes, uncompared=uncompared)


RESTART_TEXT = {"reset": "reset (~/reset): the robot back at its initial state, the command kept",
                "rebuild": "rebuild (a new scene, n_flagella or scene_overrides): the robot from its initial state, "
                           "the command kept"}


def format_report(res: Resimulation, path) -> str:
    lines = [f"re-simulation of {path}: {res.samples} samples over {res.recorded_duration:.3f} s of simulated "
             f"time, {len(res.commands)} command(s), {len(res.restarts)} recorded restart(s)"]
    events = [(ts, 1, f"omega_T = {w:+.6f} rad/s ({w * 60 / (2 * math.pi):+.2f} rpm)") for ts, w in res.commands]
    events += [(r["t"], 0, RESTART_TEXT.get(r["cause"], r["cause"])) for r in res.restarts]
    for ts, _, what in sorted(events):
        lines.append(f"  from t = {ts:8.3f} s: {what}")
    lines += [f"  compared {res.compared_samples} samples: {res.coverage()}",
              f"  largest difference from the recording: head position {res.max_position_error:.3e} m, "
              f"omega_h {res.max_omega_h_error:.3e} rad/s, omega_t {res.max_omega_t_error:.3e} rad/s"]
    lines += [f"  not compared: {n}" for n in res.uncompared]
    lines += [f"  note: {n}" for n in res.notes]
    lines.append(res.verdict())
    return "\n".join(lines)
