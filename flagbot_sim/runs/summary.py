"""Recordings as data: ``bag-summary``'s analysis of an MCAP file (no ROS, no argparse).

:func:`summarize` finds the omega_T steps in the ``cmd_omega`` stream (a new step whenever the commanded value
changes; the exact steps from the ``motor`` joint when the recording has it) and reports, for each, the steady
omega_h, omega_t and v: the mean of the ``omega_h``, ``omega_t`` and ``speed`` topics (std_msgs/Float64) over the
last ``tail`` fraction of the step. The time axis is the simulation time from the recorded /clock when there is
one (log/receive time otherwise), so steps are measured in simulated seconds even when the simulator ran faster
or slower than real time. :func:`format_summary` and :func:`summary_figure` are its text and its plot; the
``flagbot bag-summary`` command (:mod:`flagbot_sim.commands.bag`) prints them.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

from ..bag import BagError, BagReader, SimTimeMap, find_topic, namespace_of
from ..units import RPM
from ..topics import CLOCK, CMD_OMEGA, JOINT_STATES, OMEGA_H, OMEGA_T, SPEED  # plain names, no ROS import



@dataclass
class Step:
    index: int
    t_start: float      # s (time axis of the summary)
    t_end: float
    omega_T: float      # rad/s, commanded
    omega_h: float      # rad/s, steady value (mean over the tail window); NaN without samples
    omega_t: float
    v: float            # m/s
    samples: int        # omega_h samples in the tail window
    source: str = "cmd_omega"   # or 'initial': the speed before the first command (parameter or scene)


def _initial_omega(meta) -> float | None:
    """Motor speed before the first command: the sim_node's ``initial_omega`` parameter when recorded, else the
    scene's motor speed (a scene run from the CLI), else unknown."""
    if meta is None:
        return None
    w = meta.parameters.get("initial_omega")
    if isinstance(w, (int, float)) and not isinstance(w, bool):
        return float(w)
    if not meta.scene_toml:
        return None
    try:
        import tomllib

        from ..scene import scene_from_dict
        return float(scene_from_dict(tomllib.loads(meta.scene_toml)).omega_T)
    except Exception:
        return None


def _motor_joint_steps(js_rows) -> list:
    """Exact command steps from the sim_node's ``motor`` joint (command in force and its integral, stamped in
    simulation time) in the decoded ``joint_states`` rows; [] when the recording has no such joint."""
    from .resim import command_schedule, motor_samples
    motor = motor_samples([m for _, _, m in js_rows])
    if motor is None:
        return []
    _, t, angle, rate = motor
    schedule, _ = command_schedule(t, angle, rate, dt=None)
    return [(ts, w, "motor joint") for ts, w in schedule]


def summarize(path: str | Path, *, namespace: str | None = None, tail: float = 0.25,
              time_axis: str = "auto") -> dict:
    """Everything ``bag-summary`` prints, as a JSON-able dict (``series`` holds the plotted arrays)."""
    import numpy as np
    if not 0 < tail <= 1:
        raise BagError(f"--tail must be in (0, 1], got {tail}")
    with BagReader(path) as r:
        rep = r.report
        if rep.messages == 0:      # nothing to summarise: say so, never an empty table that looks like success
            raise BagError(f"nothing recoverable: {rep.describe_loss()}" if not rep.ok else
                           f"{r.path}: the recording holds no message: nothing to summarise")
        meta = r.run_metadata()
        topics = r.topics
        from ..bag.lost import LOST_METADATA_NAME, counts_from_record
        lost = counts_from_record(r.metadata_named(LOST_METADATA_NAME))   # None: not counted (an older recorder)
        cmd_topic = find_topic(topics, CMD_OMEGA, namespace)
        ns = namespace
        if ns is None:
            for name in (CMD_OMEGA, OMEGA_H, SPEED, OMEGA_T):
                t = find_topic(topics, name)
                if t is not None:
                    ns = namespace_of(t, name)
                    break
        series_topics = {"omega_h": find_topic(topics, OMEGA_H, ns), "omega_t": find_topic(topics, OMEGA_T, ns),
                         "speed": find_topic(topics, SPEED, ns)}
        js_topic = find_topic(topics, JOINT_STATES, ns) if time_axis != "log" else None
        rows = r.decoded_many([t for t in (*series_topics.values(), cmd_topic, js_topic, CLOCK) if t is not None])
        smap = SimTimeMap.from_rows(rows[CLOCK])
        use_sim = (time_axis == "sim") or (time_axis == "auto" and bool(smap))
        if use_sim and not smap:
            raise BagError("--time sim needs a recorded /clock")
        t0 = rep.start_ns or 0

        def axis(log_ns):
            log_ns = np.asarray(log_ns, dtype=float)
            return smap(log_ns) if use_sim else (log_ns - t0) * 1e-9

        series = {}
        for name, topic in series_topics.items():
            if topic is None:
                series[name] = (np.zeros(0), np.zeros(0))
                continue
            got = rows[topic]
            series[name] = (axis([lt for lt, _, _ in got]), np.array([float(m.data) for _, _, m in got]))
        cmds = []
        if cmd_topic is not None:
            cmds = list(zip(axis([lt for lt, _, _ in rows[cmd_topic]]).tolist(),
                            [float(m.data) for _, _, m in rows[cmd_topic]]))
        starts = [s[0][0] for s in series.values() if len(s[0])]
        ends = [s[0][-1] for s in series.values() if len(s[0])]
        t_first = min(starts) if starts else (cmds[0][0] if cmds else 0.0)
        t_last = max(ends) if ends else (cmds[-1][0] if cmds else 0.0)
        # steps: [time, omega_T, source]; the initial speed applies before the first command
        bounds = _motor_joint_steps(rows[js_topic]) if use_sim and js_topic is not None else []
        if not bounds:
            w0 = _initial_omega(meta)
            if w0 is not None and (not cmds or cmds[0][0] > t_first):
                bounds.append((t_first, w0, "initial"))
            for t, w in cmds:
                if not bounds or w != bounds[-1][1]:
                    bounds.append((t, w, "cmd_omega"))
        steps = []
        for i, (ts, w, src) in enumerate(bounds):
            te = bounds[i + 1][0] if i + 1 < len(bounds) else max(t_last, ts)
            lo = te - tail * (te - ts)
            vals, n = {}, 0
            for name, (tt, yy) in series.items():
                sel = (tt >= lo) & (tt <= te) if i + 1 == len(bounds) else (tt >= lo) & (tt < te)
                vals[name] = float(np.mean(yy[sel])) if sel.any() else float("nan")
                if name == "omega_h":
                    n = int(sel.sum())
            steps.append(Step(i, ts, te, w, vals["omega_h"], vals["omega_t"], vals["speed"], n, src))
        out = {
            "path": str(r.path), "size_bytes": rep.size, "messages": rep.messages, "duration": rep.duration,
            "closed": rep.closed, "ok": rep.ok, "loss": rep.describe_loss(), "time_axis": "sim" if use_sim else "log",
            "namespace": ns or "",
            # messages that never reached the recorder (gaps in the publishers' sequence numbers); None: not counted
            "lost_in_transport": sum(lost.values()) if lost is not None else None,
            "topics": [{"topic": t.topic, "type": t.type_name, "count": t.count,
                        "lost": lost.get(t.topic, 0) if lost is not None else None,
                        "rate_hz": (t.count - 1) / ((t.last_log_ns - t.first_log_ns) * 1e-9)
                        if t.count > 1 and t.last_log_ns > t.first_log_ns else None}
                       for t in sorted(topics.values(), key=lambda t: t.topic)],
            "metadata": ({"package_version": meta.package_version, "source_revision": meta.source_revision,
                          "created_utc": meta.created_utc, "parameters": len(meta.parameters),
                          "scene": bool(meta.scene_toml)} if meta else None),
            "steps": [asdict(s) for s in steps],
            "tail": tail,
            "series": {k: {"t": v[0], "y": v[1]} for k, v in series.items()},
            "cmd_omega": cmds,
        }
        return out


def format_summary(s: dict) -> str:
    lines = [f"{s['path']}: {s['messages']} messages, {len(s['topics'])} topics, {s['duration']:.3f} s, "
             f"{s['size_bytes'] / 1024:.1f} KiB, {'closed properly' if s['closed'] else 'NOT closed properly'}"]
    if s["loss"]:
        lines.append("  LOST: " + s["loss"])
    lost = s.get("lost_in_transport")
    if lost is None:
        lines.append("  messages lost before reaching the recorder: not counted (recorded without that count)")
    elif lost:
        lines.append(f"  LOST before reaching the recorder: {lost} messages (gaps in the publishers' sequence "
                     f"numbers; per topic below)")
    else:
        lines.append("  no message lost before reaching the recorder")
    m = s["metadata"]
    if m:
        lines.append(f"  recorded by flagbot_sim {m['package_version']} {m['source_revision']} at {m['created_utc']}; "
                     f"scene {'stored' if m['scene'] else 'not stored'}, {m['parameters']} parameters")
    lines.append(f"  {'topic':34s} {'type':38s} {'count':>8s} {'rate Hz':>9s} {'lost':>6s}")
    for t in s["topics"]:
        rate = f"{t['rate_hz']:9.2f}" if t["rate_hz"] is not None else " " * 9
        lines.append(f"  {t['topic']:34s} {t['type']:38s} {t['count']:8d} {rate} "
                     f"{t['lost'] if t['lost'] is not None else '-':>6}")
    if s["steps"]:
        lines.append(f"omega_T steps (steady = mean over the last {100 * s['tail']:.0f} % of each step; "
                     f"time = {s['time_axis']} time, s):")
        lines.append(f"  {'#':>2s} {'t_start':>9s} {'t_end':>9s} {'omega_T rad/s':>14s} {'(rpm)':>8s} "
                     f"{'omega_h rad/s':>14s} {'omega_t rad/s':>14s} {'v mm/s':>10s} {'n':>5s}")
        for st in s["steps"]:
            lines.append(f"  {st['index']:2d} {st['t_start']:9.3f} {st['t_end']:9.3f} {st['omega_T']:14.4f} "
                         f"{st['omega_T'] / RPM:8.1f} {st['omega_h']:14.4f} {st['omega_t']:14.4f} "
                         f"{1e3 * st['v']:10.4f} {st['samples']:5d}"
                         + ("  (initial)" if st["source"] == "initial" else ""))
    else:
        lines.append("no cmd_omega in this recording: no omega_T steps")
    return "\n".join(lines)


def summary_figure(s: dict):
    """v, omega_h, omega_t over time, with the step boundaries and the steady windows, and a legend saying what
    the shaded windows and the lines in them are (a matplotlib Figure; the caller closes it)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(9, 8.0))
    panels = [("speed", 1e3, "v (mm/s)"), ("omega_h", 1.0, "omega_h (rad/s)"), ("omega_t", 1.0, "omega_t (rad/s)")]
    keys = {"speed": "v", "omega_h": "omega_h", "omega_t": "omega_t"}
    for ax, (name, scale, label) in zip(axes, panels):
        ser = s["series"][name]
        ax.plot(ser["t"], scale * ser["y"], lw=1.0)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        for st in s["steps"]:
            ax.axvline(st["t_start"], color="0.6", ls=":", lw=0.8)
            lo = st["t_end"] - s["tail"] * (st["t_end"] - st["t_start"])
            ax.axvspan(lo, st["t_end"], color="C1", alpha=0.12, lw=0)
            val = st[keys[name]]
            if math.isfinite(val):
                ax.hlines(scale * val, lo, st["t_end"], color="C1", lw=2)
    span = max((st["t_end"] for st in s["steps"]), default=0.0) - min((st["t_start"] for st in s["steps"]),
                                                                     default=0.0)
    for st in s["steps"]:
        if st["t_end"] - st["t_start"] >= 0.03 * span:     # a label per step that is wide enough to carry one
            axes[0].annotate(f"{st['omega_T'] / RPM:.0f} rpm", (st["t_start"], 1.0),
                             xycoords=("data", "axes fraction"), fontsize=8, va="bottom")
    axes[-1].set_xlabel(f"{s['time_axis']} time (s)")
    fig.suptitle(Path(s["path"]).name, y=0.995)
    handles = [Line2D([], [], color="C0", lw=1.0),
               Patch(facecolor="C1", alpha=0.12),
               Line2D([], [], color="C1", lw=2),
               Line2D([], [], color="0.6", ls=":", lw=0.8)]
    labels = ["recorded value",
              f"steady window: the last {100 * s['tail']:.0f} % of each omega_T step",
              "steady value: mean over the window",
              "omega_T step (new command)"]
    fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    return fig


def plot_summary(s: dict, out: str | Path) -> None:
    """PNG of :func:`summary_figure`."""
    import matplotlib.pyplot as plt
    fig = summary_figure(s)
    fig.savefig(out, dpi=110)
    plt.close(fig)
