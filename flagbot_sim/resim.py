"""Re-simulation of a recorded run: feed the recorded commands to a fresh simulator and compare the motion.

The recording holds the resolved scene (metadata ``flagbot_sim``: scene file + overrides + n_flagella) and the
``joint_states`` stream, whose ``motor`` joint carries the command in force (velocity) and its integral (position)
at every published simulation time. Between two samples with different commands the integral pins the step at
which the new command took effect exactly:

    t_switch = t_k + (phi_{k+1} - phi_k - w_{k+1} (t_{k+1} - t_k)) / (w_k - w_{k+1}),  rounded to a step of dt,

so the re-simulation applies every command at the same step as the original run and should reproduce it to
round-off. Pose (``head_pose``), omega_h and omega_t (``joint_states``) are compared at every recorded stamp.

Verdict: the run is reproduced when the largest differences stay within :data:`POSITION_TOLERANCE` and
:data:`RATE_TOLERANCE`. With the version that recorded it the difference is exactly 0; a later solver (another
predictor, linear solver or build) stops its Newton iterations elsewhere inside the force tolerance
(``numerics.force_tol``, 1e-7 of EI/L^2), which moves the head by ~1e-11 m and the per-step spin rates (a
displacement difference divided by dt) by ~1e-7 rad/s, measured on the sample recordings in bags/. The
tolerances leave a factor of ~50-500 over that; a different command stream, scene or physics shows up orders of
magnitude above them (1 % more medium viscosity: 6e-3 rad/s in omega_h within 3 s, tests/test_replay_cli.py).
"""
from __future__ import annotations

import math
import sys
import tomllib
from dataclasses import dataclass, field

import numpy as np

from .bag import BagError, BagReader, find_topic, header_seconds
from .physics import Simulation
from .topics import HEAD_POSE, JOINT_STATES
from .scene import SceneError, node_overrides, scene_from_dict

#: largest head position difference (m) still counted as the same motion: Newton's tolerance, see above
POSITION_TOLERANCE = 1e-8
#: largest omega_h / omega_t difference (rad/s) still counted as the same motion
RATE_TOLERANCE = 1e-5


class ResimulationError(ValueError):
    pass


@dataclass
class Resimulation:
    samples: int
    duration: float
    commands: list                      # [(t_switch, omega_T)]
    max_position_error: float           # m
    max_omega_h_error: float            # rad/s
    max_omega_t_error: float            # rad/s
    notes: list = field(default_factory=list)

    @property
    def reproduced(self) -> bool:
        """True when the motion matches the recording within the solver tolerance (and anything was compared)."""
        return (self.samples > 0 and self.max_position_error <= POSITION_TOLERANCE
                and max(self.max_omega_h_error, self.max_omega_t_error) <= RATE_TOLERANCE)

    def verdict(self) -> str:
        """One line: reproduced or not, and by how much against the tolerance."""
        tol = f"tolerance {POSITION_TOLERANCE:.0e} m in head position, {RATE_TOLERANCE:.0e} rad/s in omega_h/omega_t"
        if self.samples == 0:
            return f"verdict: NOT CHECKED: no recorded sample could be compared ({tol})"
        if self.reproduced:
            return f"verdict: REPRODUCED: the re-simulated motion matches the recording within the {tol}"
        over = []
        if self.max_position_error > POSITION_TOLERANCE:
            over.append(f"head position by {self.max_position_error:.3e} m")
        for name, err in (("omega_h", self.max_omega_h_error), ("omega_t", self.max_omega_t_error)):
            if err > RATE_TOLERANCE:
                over.append(f"{name} by {err:.3e} rad/s")
        return f"verdict: DIFFERS: {', '.join(over)}, beyond the {tol}"

    def to_dict(self) -> dict:
        return dict(self.__dict__, reproduced=self.reproduced, verdict=self.verdict(),
                    tolerance={"position_m": POSITION_TOLERANCE, "rate_rad_s": RATE_TOLERANCE})


def motor_samples(js: list) -> tuple[list, np.ndarray, np.ndarray, np.ndarray] | None:
    """Decoded ``joint_states`` messages -> one sample per stamp, in time order: (messages, t, motor angle, motor
    rate); None when there is no ``motor`` joint."""
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


def command_schedule(t: np.ndarray, angle: np.ndarray, rate: np.ndarray, dt: float | None
                     ) -> tuple[list, list]:
    """[(t_switch, omega)] from the motor joint samples (the first entry starts at t[0]); switch times rounded to
    steps of dt (None: not rounded). Also notes about anything that could not be pinned."""
    notes = []
    schedule = [(float(t[0]), float(rate[0]))]
    for k in range(len(t) - 1):
        wa, wb = rate[k], rate[k + 1]
        if wa == wb:
            continue
        ts = t[k] + (angle[k + 1] - angle[k] - wb * (t[k + 1] - t[k])) / (wa - wb)
        off_step = False
        if dt is not None:
            n = round(ts / dt)
            off_step = abs(ts / dt - n) > 1e-3
            ts = n * dt
        # (stamps are whole nanoseconds: a switch at a sample's own step is found within a few ns of it)
        if off_step or not (t[k] - STAMP_SLACK <= ts <= t[k + 1] + STAMP_SLACK):
            notes.append(f"between t = {t[k]:.4f} s and {t[k + 1]:.4f} s the command changed more than once "
                         f"(or off a step); its switch time is taken as {ts:.4f} s")
        schedule.append((float(ts), float(wb)))
    return schedule, notes


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


def resimulate(path, namespace: str | None = None, progress=None) -> Resimulation:
    """Re-simulate a recording; ``progress(fraction)`` is called as it goes."""
    with BagReader(path) as r:
        meta = r.run_metadata()
        if meta is None or not meta.scene_toml:
            raise ResimulationError(f"{path}: no flagbot_sim metadata with the scene: not recorded by sim_node's "
                                    "`record` parameter or `record --params-from /sim_node`")
        js_topic = find_topic(r.topics, JOINT_STATES, namespace)
        pose_topic = find_topic(r.topics, HEAD_POSE, namespace)
        if js_topic is None or pose_topic is None:
            raise ResimulationError(f"{path}: needs the joint_states and head_pose topics")
        rows = r.decoded_many([js_topic, pose_topic])
        js = [m for _, _, m in rows[js_topic]]
        poses = {round(header_seconds(m), 9): m.pose.position for _, _, m in rows[pose_topic]}
        notes = [] if r.report.ok else [f"the recording is damaged: {r.report.describe_loss()}"]
    motor = motor_samples(js)
    if motor is None:
        raise ResimulationError(f"{path}: joint_states has no 'motor' joint (recorded by an older version?)")
    scene = recorded_scene(meta, path)
    # a reset (motor angle back to zero) ends what can be compared
    samples, t, angle, rate = motor
    drop = np.nonzero(np.diff(angle) * np.sign(rate[:-1] + 1e-300) < -1e-9)[0]
    if len(drop):
        cut = drop[0] + 1
        notes.append(f"the run was reset at t = {t[cut]:.3f} s: compared up to there")
        samples, t, angle, rate = samples[:cut], t[:cut], angle[:cut], rate[:cut]
    if t[0] > 0.5 * scene.time.dt:
        # the first sample is after the start: the command before it was the node's initial_omega (motor at 0)
        w0 = float(meta.parameters.get("initial_omega", rate[0]))
        t, angle, rate = np.r_[0.0, t], np.r_[0.0, angle], np.r_[w0, rate]
        samples = [None] + samples
    sim = Simulation(scene)
    dt = scene.time.dt
    # error-controlled steps (time.rtol > 0) fall where the controller put them, not on multiples of dt: the
    # switch times are taken as computed, and reached by taking the same steps again
    schedule, more = command_schedule(t, angle, rate, None if sim.adaptive else dt)
    notes += more
    slack = 1e-7 if sim.adaptive else 0.5 * dt
    sim.set_omega(schedule[0][1])
    next_cmd = 1
    err_x = err_h = err_t = 0.0
    for k, m in enumerate(samples):
        if m is None:
            continue
        target = t[k]
        while sim.time < target - slack:
            if next_cmd < len(schedule) and sim.time >= schedule[next_cmd][0] - slack:
                sim.set_omega(schedule[next_cmd][1])
                next_cmd += 1
            sim.step()
        if abs(sim.time - target) > 1e-6:
            notes.append(f"recorded stamp {target:.6f} s is not on a step of the re-simulation")
            continue
        if sim.steps == 0:
            continue                                   # before the first step there is no rate to compare
        snap = sim.snapshot()            # the observation sim_node published, made by the same function
        err_h = max(err_h, abs(snap.omega_h - m.velocity[0]))
        err_t = max(err_t, abs(snap.omega_t - m.velocity[1]))
        p = poses.get(round(target, 9))
        if p is not None:
            err_x = max(err_x, float(np.linalg.norm(snap.position - np.array([p.x, p.y, p.z]))))
        if progress is not None:
            progress(target / t[-1])
    return Resimulation(samples=sum(m is not None for m in samples), duration=float(t[-1]), commands=schedule, max_position_error=err_x,
                        max_omega_h_error=err_h, max_omega_t_error=err_t, notes=notes)


def format_report(res: Resimulation, path) -> str:
    lines = [f"re-simulation of {path}: {res.samples} samples over {res.duration:.3f} s of simulated time, "
             f"{len(res.commands)} command(s)"]
    for ts, w in res.commands:
        lines.append(f"  from t = {ts:8.3f} s: omega_T = {w:+.6f} rad/s ({w * 60 / (2 * math.pi):+.2f} rpm)")
    lines += [f"  largest difference from the recording: head position {res.max_position_error:.3e} m, "
              f"omega_h {res.max_omega_h_error:.3e} rad/s, omega_t {res.max_omega_t_error:.3e} rad/s"]
    lines += [f"  note: {n}" for n in res.notes]
    lines.append(res.verdict())
    return "\n".join(lines)


def cmd_resimulate(args) -> int:
    """``flagbot replay --resimulate BAG [--json] [--namespace NS]``: the report and its verdict; exit 0 when the
    recording is reproduced, 1 when it is not, 2 when it cannot be re-simulated."""
    from .cliutil import json_output
    from .progress import ProgressBar
    try:
        bar = ProgressBar(100.0, label="re-simulating", unit="%", enabled=not args.json)
        res = resimulate(args.bag, args.namespace or None, progress=lambda f: bar.update(100.0 * f))
        bar.close()
    except (BagError, ResimulationError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json_output({"bag": str(args.bag), **res.to_dict()}))
    else:
        print(format_report(res, args.bag))
    return 0 if res.reproduced else 1
