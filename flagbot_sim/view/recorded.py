"""A recording as a sequence of :class:`~.geometry.RobotGeometry` frames: for ``replay --view`` and ``render``.

The robot's shape comes from the recorded ``markers`` (sim_node's MarkerArray: every flagellum node, the head
centre and radius, the plate arms, at ``marker_rate``), the head's orientation from ``head_pose`` and the numbers
from ``joint_states`` (spin angles and rates, the command and its integral, the motor torque) and ``speed``, all
matched by their simulation-time stamps. A recording without markers is re-simulated instead: the recorded scene
and command stream (flagbot_sim/runs/resim.py) run again, which reproduces the recorded motion to solver tolerance.

No ROS import: the messages are decoded by flagbot_sim.bag (mcap_ros2).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..bag import BagReader, find_topic, header_seconds
from ..topics import HEAD_POSE, JOINT_STATES, MARKERS, SPEED
from .geometry import RobotGeometry


@dataclass
class RecordedRun:
    path: str
    frames: list                       # RobotGeometry, in time order, one per distinct stamp
    scene: object | None = None        # the recorded scene (None when the file has no flagbot_sim metadata)
    source: str = "markers"            # or "resimulated"
    notes: list = field(default_factory=list)

    @property
    def times(self) -> np.ndarray:
        return np.array([f.t for f in self.frames])

    def at(self, t: float) -> RobotGeometry:
        """The frame whose stamp is nearest ``t``."""
        times = self.times
        return self.frames[int(np.argmin(np.abs(times - t)))]


def load(path: str | Path, namespace: str | None = None, *, max_rate: float | None = None) -> RecordedRun:
    """The frames of a recording (re-simulated when it has no markers). ``max_rate``: for a re-simulation, keep at
    most this many frames per simulated second (default: every recorded joint_states stamp)."""
    from ..runs.resim import ResimulationError, recorded_scene
    with BagReader(path) as r:
        meta = r.run_metadata()
        try:
            scene = recorded_scene(meta, path)
        except ResimulationError:
            scene = None
        topics = r.topics
        mk_topic = find_topic(topics, MARKERS, namespace)
        if mk_topic is None or topics[mk_topic].count == 0:
            if scene is None:
                raise ResimulationError(f"{path}: no markers to show and no recorded scene to re-simulate")
            return _resimulated(path, namespace, max_rate)
        names = [t for t in (mk_topic, find_topic(topics, HEAD_POSE, namespace),
                             find_topic(topics, JOINT_STATES, namespace), find_topic(topics, SPEED, namespace))]
        rows = r.decoded_many([t for t in names if t is not None])
        notes = [] if r.report.ok else [f"the recording is damaged: {r.report.describe_loss()}"]
    mk_rows = rows[names[0]]
    poses = {round(header_seconds(m), 9): m.pose.orientation for _, _, m in rows.get(names[1], [])} if names[1] else {}
    js_rows = rows.get(names[2], []) if names[2] else []
    values = _joint_values(js_rows, rows.get(names[3], []) if names[3] else [])
    by_stamp = {}
    for _, _, m in mk_rows:                   # markers repeat while the node is paused: keep one per stamp
        if m.markers:
            by_stamp[round(header_seconds(m.markers[0]), 9)] = m
    frames = []
    for ts in sorted(by_stamp):
        q = poses.get(ts)
        frames.append(RobotGeometry.from_markers(by_stamp[ts], t=ts, values=values.get(ts),
                                                 orientation=None if q is None else (q.x, q.y, q.z, q.w)))
    if not frames:
        raise ResimulationError(f"{path}: the markers topic holds no marker")
    return RecordedRun(str(path), frames, scene, "markers", notes)


def _joint_values(js_rows, speed_rows) -> dict:
    """stamp -> the numbers of the State channel, from joint_states (head_spin, flagella_spin, motor) and the
    speed sample logged nearest to it."""
    sp_t = np.array([lt for lt, _, _ in speed_rows], float)
    sp_v = np.array([float(m.data) for _, _, m in speed_rows])
    out = {}
    for lt, _, m in js_rows:
        if "motor" not in m.name:
            continue
        ih, it, im = m.name.index("head_spin"), m.name.index("flagella_spin"), m.name.index("motor")
        ts = round(header_seconds(m), 9)
        v = {"t": ts, "omega_h": m.velocity[ih], "omega_t": m.velocity[it], "omega_T": m.velocity[im],
             "phi_h": m.position[ih], "phi_t": m.position[it], "drive_angle": m.position[im],
             "motor_torque": m.effort[im] if len(m.effort) > im else math.nan}
        if len(sp_t):
            v["v"] = float(sp_v[int(np.argmin(np.abs(sp_t - lt)))])
        out[ts] = {k: float(x) for k, x in v.items()}
    return out


def _resimulated(path, namespace, max_rate) -> RecordedRun:
    """Frames from re-running the recorded commands (runs/resim.py's plan: its schedule, across recorded restarts) at
    the recorded joint_states stamps."""
    import dataclasses

    from ..runs.resim import plan_recording, replay
    plan, _ = plan_recording(path, namespace, with_pose=False)      # ResimulationError: nothing to re-run
    scene = plan.segments[0].scene if plan.segments else None
    notes = plan.notes + plan.uncompared
    frames, last = [], -math.inf
    spacing = 1.0 / max_rate if max_rate else 0.0
    for k, sim, _ in replay(plan):
        if sim is not None and plan.t[k] - last >= spacing - 1e-9:
            frames.append(dataclasses.replace(RobotGeometry.from_simulation(sim), t=float(plan.t[k])))
            last = plan.t[k]
    return RecordedRun(str(path), frames, scene, "resimulated",
                       notes + ["no markers recorded: the shape is re-simulated from the recorded commands"])
