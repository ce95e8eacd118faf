"""What accuracy costs in time: implicit Euler and BDF2 side by side, fixed steps and error-controlled ones.

Three parts (``--parts``, default all):

front        For each case (the clamped flagellum of both designs at 100 rpm, the free robot of both designs with
             n = 2 and 3 at 100 rpm) a grid of time steps x flagellum edge lengths for each integrator, and BDF2
             with error control (time.rtol) at each edge length. Every run starts from rest and stops at the
             steady-state rule (``Simulation.run_until_steady``, observe.steady_rtol = 1e-4); its wall time is
             the wall time of that run. Its steady outputs are compared with two references:
               time error   against the steady solver (physics/steady.py: the relative equilibrium of the same
                            discrete model, i.e. the dt -> 0 limit of the run) at the run's own edge length;
               total error  against the converged answer: the geometrically exact rod (reference/rod_bvp.py,
                            with the centripetal load the scene's inertia puts on the DER) for the clamped
                            flagellum; for the free robot the steady solver at 1.03 and 0.51 mm edges,
                            Richardson-extrapolated (second order in the edge length, observed).
             Outputs: one Pareto figure (error vs wall time; top row time error, bottom row total error).
calibration  Requested time.rtol vs achieved time error (BDF2; implicit Euler on a subset) from 0.5 to 2000 rpm
             for both designs' clamped flagellum and the free robot at 100 rpm, 4.11 mm edges, each run to a
             steady state within rtol / 20.
presets      Each accuracy preset (scene.PRESETS) over 0.5-100 rpm for both clamped flagella and on the free robot:
             total and time error, and wall time to the steady state (median of ``--repeat``).

Errors: the clamped flagellum's Fx and Tx relative to their size, its tip as |tip - tip_ref| over the tip's
deflection |tip_ref - tip_straight| (a 1% tip error is 1% of how far the tip bends, at any speed); the free
robot's omega_h and v relative to their size. A run's error is the largest of its outputs'.
"""
from __future__ import annotations

import csv
import json
import math
import statistics
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

from ..cliutil import dumps, json_output, make_out_dir
from ..physics import Simulation, StepFailed
from ..scene import PRESETS, SceneError, load_scene

#: design 2's flagellum, medium and plate on the clamped scene (its default is design 1's)
D2_CLAMPED = ["flagellum.length=0.089", "medium.mu=2.125", "plate.diameter=0.03"]
CASES = {
    "clamped1": ("clamped_flagellum", ["motor.omega_rpm=100"]),
    "clamped2": ("clamped_flagellum", [*D2_CLAMPED, "motor.omega_rpm=100"]),
    "design1_n2": ("design1", ["robot.n_flagella=2", "motor.omega_rpm=100"]),
    "design1_n3": ("design1", ["robot.n_flagella=3", "motor.omega_rpm=100"]),
    "design2_n2": ("design2", ["robot.n_flagella=2", "motor.omega_rpm=100"]),
    "design2_n3": ("design2", ["robot.n_flagella=3", "motor.omega_rpm=100"]),
}
#: what each case is, as a figure's panel says it
CASE_TITLES = {"clamped1": "design 1: clamped flagellum", "clamped2": "design 2: clamped flagellum",
               "design1_n2": "design 1: free robot, n = 2", "design1_n3": "design 1: free robot, n = 3",
               "design2_n2": "design 2: free robot, n = 2", "design2_n3": "design 2: free robot, n = 3"}
#: the integrators' names as a reader knows them
INTEGRATOR_TITLES = {"implicit_euler": "implicit Euler", "bdf2": "BDF2"}
CLAMPED = ("clamped1", "clamped2")
FREE = ("design1_n2", "design1_n3", "design2_n2", "design2_n3")
INTEGRATORS = ("implicit_euler", "bdf2")
# 0.04 s: at 100 rpm the motor's time.max_turn (0.5 rad) allows 0.048 s; a larger dt would be sub-stepped
DTS = (4e-2, 2e-2, 1e-2, 5e-3, 2.5e-3)
EDGES = (16.44e-3, 8.22e-3, 4.11e-3, 2.055e-3)
RTOLS = (1e-2, 1e-3, 1e-4)
QUICK_DTS = (2e-2, 1e-2, 5e-3)
QUICK_EDGES = (4.11e-3,)
QUICK_RTOLS = (1e-2, 1e-3)
#: the error-controlled runs' largest step (time.dt): the steady-state window (2 s) must hold a step
RTOL_DT_MAX = 1.0
FINE_EDGES = (1.0275e-3, 0.51375e-3)        # the free robot's converged reference (Richardson)
CALIBRATION_RPM = (0.5, 2.0, 10.0, 50.0, 100.0, 500.0, 2000.0)
QUICK_CALIBRATION_RPM = (0.5, 10.0, 100.0)
PRESET_RPM = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 2000.0)   # the targets: 0.5-100 rpm
QUICK_PRESET_RPM = (0.5, 10.0, 100.0)
#: the front's and the presets' steady-state rule: the outputs within 1e-4 of their final values. Tighter is not
#: measurable everywhere: the clamped flagellum's net thrust Fx is a small difference of large drag forces, and
#: Newton's force tolerance alone leaves it ~1e-4 noise at fine edges and small steps (design 2, low rpm)
STEADY_RTOL = 1e-4
T_MAX = 200.0


def case_overrides(case: str, rpm: float | None = None) -> tuple[str, list[str]]:
    scene, over = CASES[case]
    over = [o for o in over if not (rpm is not None and o.startswith("motor.omega_rpm="))]
    return scene, over + ([f"motor.omega_rpm={rpm:g}"] if rpm is not None else [])


def is_clamped(case: str) -> bool:
    return case.startswith("clamped")


def outputs_of(summary: dict) -> dict:
    """The steady outputs of a run or a steady solution (``Simulation.summary()`` / ``steady.summary``)."""
    if "Fx" in summary:
        return {"Fx": summary["Fx"], "Tx": summary["Tx"], "tip": [float(v) for v in summary["tip"]]}
    return {"omega_h": summary["omega_h"], "v": summary["v"], "omega_t": summary["omega_t"]}


def errors(out: dict, ref: dict) -> dict:
    """Relative errors of the outputs against a reference (see the module docstring for the tip's)."""
    if "Fx" in ref:
        tip, tr, t0 = (np.asarray(x, float) for x in (out["tip"], ref["tip"], ref["tip_straight"]))
        return {"Fx": abs(out["Fx"] / ref["Fx"] - 1.0), "Tx": abs(out["Tx"] / ref["Tx"] - 1.0),
                "tip": float(np.linalg.norm(tip - tr) / np.linalg.norm(tr - t0))}
    return {k: abs(out[k] / ref[k] - 1.0) for k in ("omega_h", "v")}


# ------------------------------------------------------------------------------------------------- references
class References:
    """Steady-solver and converged references, computed once per (case, rpm, edge) and kept in a JSON file."""

    def __init__(self, path: Path | None = None):
        self.path = path
        self.data = json.loads(path.read_text()) if path is not None and path.exists() else {}

    def _get(self, key: str, make):
        if key not in self.data:
            self.data[key] = make()
            if self.path is not None:
                self.path.write_text(dumps(self.data, indent=1))
        return self.data[key]

    def steady(self, case: str, rpm: float, edge: float) -> dict:
        """The steady solver's answer: the dt -> 0 limit of time stepping at this edge length."""
        def make():
            from ..physics.model import RobotModel
            from ..physics.steady import SteadySolver, summary
            scene, over = case_overrides(case, rpm)
            sc = load_scene(scene, over + [f"flagellum.edge_length={edge}"])
            m = RobotModel(sc)
            t0 = time.perf_counter()
            out = outputs_of(summary(m, SteadySolver(m).solve(sc.omega_T)))
            out["wall"] = time.perf_counter() - t0
            if sc.clamped:
                out["tip_straight"] = straight_tip(sc)
            return out
        return self._get(f"steady|{case}|{rpm:g}|{edge:g}", make)

    def converged(self, case: str, rpm: float) -> dict:
        """The converged answer: the rod BVP (clamped) or the Richardson limit of fine steady solutions."""
        def make():
            scene, over = case_overrides(case, rpm)
            sc = load_scene(scene, over)
            if sc.clamped:
                from ..reference.rod_bvp import from_scene
                sol = from_scene(sc)
                return {"Fx": sol.Fx, "Tx": sol.Tx, "tip": [float(v) for v in sol.tip],
                        "tip_straight": straight_tip(sc), "source": "rod_bvp",
                        "error_estimate": float(sol.error_estimate)}
            coarse, fine = (self.steady(case, rpm, e) for e in FINE_EDGES)
            out = {k: fine[k] + (fine[k] - coarse[k]) / 3.0 for k in ("omega_h", "v", "omega_t")}
            out["source"] = "steady solver, Richardson of 1.03 / 0.51 mm edges"
            out["richardson_correction"] = max(abs(fine[k] / out[k] - 1.0) for k in ("omega_h", "v"))
            return out
        return self._get(f"converged|{case}|{rpm:g}", make)


def straight_tip(sc) -> list[float]:
    """The unbent flagellum's tip in the frame turning with the clamp (clamp at (0, R_d, 0))."""
    return [float(sc.flagellum.length), float(sc.R_d), 0.0]


# ------------------------------------------------------------------------------------------------- runs
@dataclass
class Run:
    part: str
    case: str
    rpm: float
    integrator: str
    dt: float                # fixed step, or the largest step with error control (s)
    rtol: float              # 0: fixed steps
    edge: float
    preset: str = ""
    outputs: dict = field(default_factory=dict)
    sim_time: float = 0.0    # simulated time until steady (s)
    wall: float = 0.0        # wall time of the run (s)
    steps: int = 0
    newton: int = 0
    steady: bool = False
    last_dt: float = 0.0     # the last accepted step (s): the steady step of an error-controlled run
    error: str = ""
    time_err: dict = field(default_factory=dict)
    total_err: dict = field(default_factory=dict)
    accuracy: float = 0.0    # the 'request' part: the accuracy.rtol asked for (integrator, dt, rtol, edge: chosen)

    @property
    def max_time_err(self) -> float:
        return max(self.time_err.values()) if self.steady and self.time_err else math.inf

    @property
    def max_total_err(self) -> float:
        return max(self.total_err.values()) if self.steady and self.total_err else math.inf

    @property
    def label(self) -> str:
        if self.accuracy:
            return f"accuracy.rtol {self.accuracy:g}"
        if self.preset:
            return f"preset {self.preset}"
        step = f"rtol {self.rtol:g}" if self.rtol > 0 else f"dt {self.dt:g}"
        return f"{self.integrator} {step}"


def run_point(part: str, case: str, rpm: float, integrator: str, dt: float, edge: float, rtol: float = 0.0,
              steady_rtol: float = STEADY_RTOL, preset: str = "", t_max: float = T_MAX, accuracy: float = 0.0) -> Run:
    """One run from rest to the steady-state rule (or t_max). With ``preset`` the preset's discretisation is
    used as a user gets it (integrator, dt, rtol and edge are then read back from the scene); with ``accuracy``
    the one accuracy.rtol chooses (read back from the simulation, whose choice's steady solves count in the
    wall time)."""
    scene, over = case_overrides(case, rpm)
    if preset:
        over = over + [f"scene.preset='{preset}'"]
    elif accuracy:
        over = over + [f"accuracy.rtol={accuracy}"]
    else:
        over = over + [f"time.integrator='{integrator}'", f"time.dt={dt}", f"time.rtol={rtol}",
                       f"flagellum.edge_length={edge}"]
    sc = load_scene(scene, over + ["observe.steady_window=2.0", f"observe.steady_rtol={steady_rtol}"])
    c0 = time.perf_counter()
    sim = Simulation(sc)
    chosen = sim.scene                 # accuracy.rtol: the discretisation it chose
    r = Run(part, case, rpm, chosen.time.integrator, chosen.time.dt, chosen.time.rtol,
            chosen.flagellum.edge_length, preset, accuracy=accuracy)
    # the choice's steady solves are part of what a request costs (the kernels' compile or load is not)
    w0 = c0 + sim.compile_seconds if accuracy else time.perf_counter()
    try:
        sim.run_until_steady(t_max)
    except StepFailed as exc:
        r.error = str(exc)
    r.wall = time.perf_counter() - w0
    s = sim.summary()
    r.outputs = outputs_of(s)
    r.sim_time, r.steps, r.newton = sim.time, sim.steps, sim.newton_iterations
    r.steady = bool(s["steady"]) and not r.error
    dts = sim.last_stats.substep_dts
    r.last_dt = float(dts[-1]) if dts else 0.0
    return r


def score(r: Run, refs: References) -> Run:
    r.time_err = errors(r.outputs, refs.steady(r.case, r.rpm, r.edge))
    r.total_err = errors(r.outputs, refs.converged(r.case, r.rpm))
    return r


def pareto(runs: list[Run], key: str) -> list[Run]:
    """Runs that no other run beats in both wall time and error (``key``: max_time_err or max_total_err)."""
    ok = sorted((r for r in runs if math.isfinite(getattr(r, key))), key=lambda r: (r.wall, getattr(r, key)))
    front, best = [], math.inf
    for r in ok:
        if getattr(r, key) < best:
            front.append(r)
            best = getattr(r, key)
    return front


def _progress(progress, r: Run, i: int, n: int) -> None:
    errs = "  ".join(f"{k} {100 * v:.3f}%" for k, v in r.total_err.items())
    progress(f"{r.part:11s} {r.case:11s} {r.rpm:6g} rpm [{i:3d}/{n}] {r.label:26s} edge {1e3 * r.edge:6.3f} mm  "
             f"{'steady' if r.steady else 'NOT steady'} at {r.sim_time:6.1f} s  wall {r.wall:7.2f} s  "
             f"time err {100 * r.max_time_err:.4f}%  total err {100 * r.max_total_err:.4f}% ({errs})"
             + (f"  ERROR {r.error}" if r.error else ""))


# ------------------------------------------------------------------------------------------------- parts
def front(cases, dts, edges, rtols, refs: References, progress=print) -> list[Run]:
    plan = []
    for case in cases:
        # the two integrators interleaved, so that a change of the machine's load does not favour one of them
        plan += [(case, integ, dt, e, 0.0) for e in edges for dt in dts for integ in INTEGRATORS]
        plan += [(case, "bdf2", RTOL_DT_MAX, e, rt) for e in edges for rt in rtols]
    runs = []
    for i, (case, integ, dt, e, rt) in enumerate(plan):
        r = score(run_point("front", case, 100.0, integ, dt, e, rt), refs)
        _progress(progress, r, i + 1, len(plan))
        runs.append(r)
    return runs


def calibration(rpms, rtols, refs: References, progress=print, quick: bool = False) -> list[Run]:
    """BDF2 over rpms x rtols (clamped, both designs) and the free robot at 100 rpm; implicit Euler on a
    subset (its cost grows as 1/rtol: at 100 rpm and rtol 1e-3 it takes ~3e5 steps)."""
    plan = [(c, rpm, "bdf2", rt) for c in CLAMPED for rpm in rpms for rt in rtols]
    plan += [(c, 100.0, "bdf2", rt) for c in FREE for rt in rtols]
    ie_rpm = [w for w in rpms if w <= 100.0]
    plan += [(c, rpm, "implicit_euler", 1e-2) for c in CLAMPED for rpm in ie_rpm]
    if not quick:
        plan += [(c, rpm, "implicit_euler", 1e-3) for c in CLAMPED for rpm in ie_rpm if rpm <= 10.0]
    plan += [(c, 100.0, "implicit_euler", 1e-2) for c in FREE]
    runs = []
    for i, (case, rpm, integ, rt) in enumerate(plan):
        # steady to rtol / 20: a tighter rule is not met everywhere (design 2's Fx carries ~1e-5 noise from
        # Newton's force tolerance; at rtol 1e-4 and rtol / 100 two runs did not settle in 200 s)
        r = score(run_point("calibration", case, rpm, integ, RTOL_DT_MAX, 4.11e-3, rt, steady_rtol=rt / 20.0),
                  refs)
        _progress(progress, r, i + 1, len(plan))
        runs.append(r)
    return runs


#: the 'request' part: (case, rpm, accuracy.rtol), the targets of issue 23's item 2
REQUESTS = (("clamped1", 20.0, 1e-3), ("clamped1", 100.0, 1e-3), ("clamped1", 500.0, 1e-3), ("clamped2", 100.0, 1e-3),
            ("clamped1", 1000.0, 1e-2), ("clamped1", 2000.0, 1e-2), ("clamped2", 1000.0, 1e-2),
            ("clamped2", 2000.0, 1e-2))
QUICK_REQUESTS = (("clamped1", 20.0, 1e-3), ("clamped2", 100.0, 1e-3), ("clamped2", 1000.0, 1e-2))


def requests(plan, refs: References, progress=print) -> list[Run]:
    """accuracy.rtol requested vs achieved vs wall time: each run to the steady-state rule (as tight as its
    time.rtol makes it) with the discretisation the request chooses."""
    runs = []
    for i, (case, rpm, acc) in enumerate(plan):
        r = score(run_point("request", case, rpm, "", 0.0, 0.0, steady_rtol=acc / 20.0, accuracy=acc), refs)
        _progress(progress, r, i + 1, len(plan))
        runs.append(r)
    return runs


def presets(rpms, refs: References, repeat: int = 1, progress=print) -> list[Run]:
    """Every preset at every point, the presets interleaved within each repeat (the machine's load drifts)."""
    plan = [(c, rpm) for c in CLAMPED for rpm in rpms] + [(c, 100.0) for c in FREE]
    runs = []
    n = len(plan) * len(PRESETS)
    for case, rpm in plan:
        timed = {p: [] for p in PRESETS}
        for _ in range(repeat):
            for p in PRESETS:
                timed[p].append(run_point("presets", case, rpm, "", 0.0, 0.0, preset=p))
        for p, rs in timed.items():
            r = rs[0]
            r.wall = statistics.median(x.wall for x in rs)
            score(r, refs)
            _progress(progress, r, len(runs) + 1, n)
            runs.append(r)
    return runs


# ------------------------------------------------------------------------------------------------- outputs
CSV_OUTPUTS = ("Fx", "Tx", "tip_x", "tip_y", "tip_z", "omega_h", "omega_t", "v")
CSV_ERRORS = ("Fx", "Tx", "tip", "omega_h", "v")


def _flat(out: dict) -> dict:
    d = {k: v for k, v in out.items() if k != "tip"}
    if "tip" in out:
        d.update(tip_x=out["tip"][0], tip_y=out["tip"][1], tip_z=out["tip"][2])
    return d


def write_csv(path: Path, runs: list[Run], refs: References) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["part", "case", "rpm", "preset", "integrator", "dt_s", "rtol", "edge_m", "steady", "sim_time_s",
                    "wall_s", "steps", "newton_iterations", "last_dt_s", *CSV_OUTPUTS,
                    *[f"time_err_{k}" for k in CSV_ERRORS], *[f"total_err_{k}" for k in CSV_ERRORS],
                    "max_time_err", "max_total_err", "error", "accuracy_rtol"])
        for r in runs:
            o = _flat(r.outputs)
            w.writerow([r.part, r.case, f"{r.rpm:g}", r.preset, r.integrator, f"{r.dt:g}", f"{r.rtol:g}",
                        f"{r.edge:g}", r.steady, f"{r.sim_time:.3f}", f"{r.wall:.3f}", r.steps, r.newton,
                        f"{r.last_dt:.4g}", *[f"{o[k]:.10e}" if k in o else "" for k in CSV_OUTPUTS],
                        *[f"{r.time_err[k]:.4e}" if k in r.time_err else "" for k in CSV_ERRORS],
                        *[f"{r.total_err[k]:.4e}" if k in r.total_err else "" for k in CSV_ERRORS],
                        f"{r.max_time_err:.4e}", f"{r.max_total_err:.4e}", r.error, f"{r.accuracy:g}"])
        for key, ref in sorted(refs.data.items()):
            kind, case, rpm, *edge = key.split("|")
            o = _flat(ref)
            w.writerow([f"reference:{kind}", case, rpm, "", ref.get("source", "steady solver"), "", "",
                        edge[0] if edge else "", "", "", f"{ref.get('wall', 0.0):.3f}", "", "", "",
                        *[f"{o[k]:.10e}" if k in o else "" for k in CSV_OUTPUTS],
                        *[""] * (2 * len(CSV_ERRORS)), "", "", "", ""])


def read_csv(path: Path) -> list[Run]:
    """The runs of an ``accuracy.csv`` (:func:`write_csv`'s rows; the reference rows are left out), with what the
    figures need: ``flagbot bench accuracy --plot-from CSV`` redraws them without running anything."""
    def num(text: str) -> float:
        return float(text) if text else math.nan
    runs = []
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            if row["part"].startswith("reference:"):
                continue
            r = Run(row["part"], row["case"], float(row["rpm"]), row["integrator"], float(row["dt_s"]),
                    float(row["rtol"]), float(row["edge_m"]), row["preset"], sim_time=num(row["sim_time_s"]),
                    wall=float(row["wall_s"]), steps=int(row["steps"]), newton=int(row["newton_iterations"]),
                    steady=row["steady"] == "True", last_dt=num(row["last_dt_s"]), error=row["error"],
                    accuracy=float(row.get("accuracy_rtol") or 0.0))
            out = {k: float(row[k]) for k in CSV_OUTPUTS if row[k]}
            if "tip_x" in out:
                out["tip"] = [out.pop("tip_x"), out.pop("tip_y"), out.pop("tip_z")]
            r.outputs = out
            r.time_err = {k: float(row[f"time_err_{k}"]) for k in CSV_ERRORS if row[f"time_err_{k}"]}
            r.total_err = {k: float(row[f"total_err_{k}"]) for k in CSV_ERRORS if row[f"total_err_{k}"]}
            runs.append(r)
    return runs


COLORS = {"implicit_euler": "C0", "bdf2": "C1"}
MARKERS = {16.44e-3: "v", 8.22e-3: "s", 4.11e-3: "o", 2.055e-3: "D"}


def front_figure(runs: list[Run]):
    """The front: error vs wall time, a column per case (titled by what it is), time error above, total error
    below; the presets' names at their runs, each placed where it covers no other (plotlabels)."""
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    from ..plotlabels import marker_box, place_labels
    cases = list(dict.fromkeys(r.case for r in runs))
    fig = Figure(figsize=(3.6 * len(cases), 7.6))
    axes = fig.subplots(2, len(cases), squeeze=False)
    tags = {}                                  # axes -> [(preset, (wall, error))]
    for j, case in enumerate(cases):
        rc = [r for r in runs if r.case == case]
        for i, key in enumerate(("max_time_err", "max_total_err")):
            ax = axes[i][j]
            for integ in INTEGRATORS:
                for e in sorted({r.edge for r in rc}):
                    rs = sorted((r for r in rc if r.integrator == integ and r.rtol == 0 and r.edge == e
                                 and math.isfinite(getattr(r, key))), key=lambda r: r.dt)
                    if rs:
                        ax.loglog([r.wall for r in rs], [getattr(r, key) for r in rs], "-", lw=0.6,
                                  color=COLORS[integ], alpha=0.6, marker=MARKERS.get(e, "o"), ms=3.5, mfc="none")
                    ra = sorted((r for r in rc if integ == "bdf2" and r.rtol > 0 and r.edge == e
                                 and math.isfinite(getattr(r, key))), key=lambda r: -r.rtol)
                    if ra:
                        ax.loglog([r.wall for r in ra], [getattr(r, key) for r in ra], ":", lw=0.8, color="C3",
                                  marker=MARKERS.get(e, "o"), ms=4)
            for integ, style in (("implicit_euler", "--"), ("bdf2", "-")):
                f = pareto([r for r in rc if r.integrator == integ], key)
                ax.loglog([r.wall for r in f], [getattr(r, key) for r in f], style, color=COLORS[integ], lw=1.6,
                          label=f"{'implicit Euler' if integ == 'implicit_euler' else 'BDF2 (fixed + rtol)'} front")
            tags[ax] = [(tag, (r.wall, getattr(r, key))) for r in rc
                        if (tag := _preset_tag(r)) and math.isfinite(getattr(r, key))]
            ax.grid(alpha=0.3, which="both")
            if i == 0:
                ax.set_title(CASE_TITLES.get(case, case), fontsize=10)
            else:
                ax.set_xlabel("wall time from rest to steady state (s)")
            ax.axhline(1e-2, color="0.5", lw=0.5)
    axes[0][0].set_ylabel("time error (vs the steady solver,\nsame edges): largest relative")
    axes[1][0].set_ylabel("total error (vs rod BVP / converged\nsteady solution): largest relative")
    handles = [Line2D([], [], color="C0", marker="o", mfc="none", lw=0.6, label="implicit Euler, fixed dt"),
               Line2D([], [], color="C1", marker="o", mfc="none", lw=0.6, label="BDF2, fixed dt"),
               Line2D([], [], color="C3", marker="o", ls=":", label="BDF2, rtol 1e-2 / 1e-3 / 1e-4"),
               Line2D([], [], color="C0", ls="--", lw=1.6, label="implicit Euler front"),
               Line2D([], [], color="C1", lw=1.6, label="BDF2 front (fixed and rtol)")]
    handles += [Line2D([], [], color="0.3", marker=m, ls="none", mfc="none", label=f"edge {1e3 * e:.3g} mm")
                for e, m in MARKERS.items() if any(r.edge == e for r in runs)]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=7, frameon=False)
    fig.suptitle("Accuracy vs wall time, 100 rpm: implicit Euler (the paper's) and BDF2; a name marks the run "
                 "with a preset's discretisation (scene.preset)")
    fig.tight_layout(rect=(0, 0.04, 1, 0.97))
    for ax, items in tags.items():              # the layout is final: the names are measured where they will be
        place_labels(ax, items, avoid=[marker_box(ax, x, y, 6.0) for _, (x, y) in items], fontsize=7,
                     distances=(12.0, 22.0, 34.0))
    return fig


def plot_front(runs: list[Run], png: Path) -> None:
    front_figure(runs).savefig(png, dpi=110)


def _preset_tag(r: Run) -> str:
    """The preset whose discretisation this front run is, or ''. (The error-controlled presets' largest step,
    0.1 s, is above every step the front's error-controlled runs take at 100 rpm: the same runs.)"""
    for name, p in PRESETS.items():
        integ = p.get("time.integrator", "bdf2")
        dt, edge, rtol = p.get("time.dt", 1e-2), p.get("flagellum.edge_length", 4.11e-3), p.get("time.rtol", 0.0)
        if r.integrator == integ and r.rtol == rtol and math.isclose(r.edge, edge) and (rtol > 0 or
                                                                                       math.isclose(r.dt, dt)):
            return name
    return ""


def calibration_figure(runs: list[Run]):
    """Achieved time error / requested rtol vs speed, a panel per integrator."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(15, 4.4), layout="constrained")       # room for each panel's legend beside it
    axes = fig.subplots(1, 2)
    for ax, integ in zip(axes, INTEGRATORS[::-1]):
        for k, rt in enumerate(sorted({r.rtol for r in runs if r.integrator == integ}, reverse=True)):
            for case, mk in zip(CLAMPED, ("o", "s")):
                rs = sorted((r for r in runs if r.integrator == integ and r.rtol == rt and r.case == case),
                            key=lambda r: r.rpm)
                if rs:
                    ax.semilogx([r.rpm for r in rs], [r.max_time_err / rt for r in rs], "-", marker=mk,
                                color=f"C{k}", ms=4, label=f"rtol {rt:g}, {CASE_TITLES[case]}")
            rf = [r for r in runs if r.integrator == integ and r.rtol == rt and not is_clamped(r.case)]
            if rf:
                # the four free-robot cases all run at 100 rpm: spread about it so that they do not hide each other
                ax.semilogx([r.rpm * (0.8 + 0.1 * i) for i, r in enumerate(rf)], [r.max_time_err / rt for r in rf],
                            "^", color=f"C{k}", ms=5, ls="none",
                            label=f"rtol {rt:g}, free robot (4 cases at 100 rpm, spread)")
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_ylim(0, 1.2)
        ax.set_xlabel("clamp / motor speed (rpm)")
        ax.set_title(f"{INTEGRATOR_TITLES[integ]}: achieved time error / requested rtol")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=6.5, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    axes[0].set_ylabel("largest relative error of the steady outputs / rtol")
    return fig


def plot_calibration(runs: list[Run], png: Path) -> None:
    calibration_figure(runs).savefig(png, dpi=110)


def _pct(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{100 * x:.3f}%"


def markdown(runs: list[Run], refs: References) -> str:
    lines = []
    fr = [r for r in runs if r.part == "front"]
    if fr:
        lines += ["## Front (100 rpm): best wall time for a given error", ""]
        lines += ["Cheapest run, per case and integrator, whose largest total error (vs rod BVP / converged steady "
                  "solution) is below each level; wall time from rest to the steady state (s), the run in brackets.",
                  "", "| case | integrator | < 2% | < 1% | < 0.5% | < 0.2% |", "|---|---|---|---|---|---|"]
        for case in dict.fromkeys(r.case for r in fr):
            for integ, name in (("implicit_euler", "implicit Euler"), ("bdf2", "BDF2 (fixed or rtol)")):
                cells = []
                for lvl in (2e-2, 1e-2, 5e-3, 2e-3):
                    ok = [r for r in fr if r.case == case and r.integrator == integ and r.max_total_err < lvl]
                    if ok:
                        b = min(ok, key=lambda r: r.wall)
                        cells.append(f"{b.wall:.2f} ({b.label.split(' ', 1)[1]}, {1e3 * b.edge:.3g} mm)")
                    else:
                        cells.append("not reached")
                lines.append(f"| {case} | {name} | " + " | ".join(cells) + " |")
        lines += ["", "All runs of the front:", "",
                  "| case | run | edge (mm) | steady at (s) | steps | wall (s) | time error | total error |",
                  "|---|---|---|---|---|---|---|---|"]
        for r in sorted(fr, key=lambda r: (r.case, r.integrator, r.rtol > 0, -r.edge, -r.dt, -r.rtol)):
            lines.append(f"| {r.case} | {r.label} | {1e3 * r.edge:.3f} | {r.sim_time:.1f}"
                         f"{'' if r.steady else ' (not steady)'} | {r.steps} | {r.wall:.2f} | "
                         f"{_pct(r.max_time_err)} | {_pct(r.max_total_err)} |")
        lines.append("")
    cal = [r for r in runs if r.part == "calibration"]
    if cal:
        lines += ["## Requested rtol vs achieved error vs wall time", "",
                  "Time error (vs the steady solver at the same 4.11 mm edges), as a multiple of the requested "
                  "rtol, and the wall time from rest to the steady state; time.dt (the largest step) = "
                  f"{RTOL_DT_MAX:g} s.", ""]
        for integ in INTEGRATORS[::-1]:
            rc = [r for r in cal if r.integrator == integ]
            if not rc:
                continue
            rts = sorted({r.rtol for r in rc}, reverse=True)
            lines += [f"**{integ}**", "", "| case | rpm | " + " | ".join(f"rtol {rt:g}: achieved / wall"
                                                                          for rt in rts) + " |",
                      "|---|---|" + "---|" * len(rts)]
            for case, rpm in dict.fromkeys((r.case, r.rpm) for r in rc):
                cells = []
                for rt in rts:
                    m = [r for r in rc if r.case == case and r.rpm == rpm and r.rtol == rt]
                    cells.append(f"{m[0].max_time_err / rt:.2f} rtol / {m[0].wall:.2f} s" if m else "")
                lines.append(f"| {case} | {rpm:g} | " + " | ".join(cells) + " |")
            worst = {rt: max(r.max_time_err / rt for r in rc if r.rtol == rt) for rt in rts}
            wall = {rt: sum(r.wall for r in rc if r.rtol == rt) for rt in rts}
            lines += [f"| **worst / total wall** | | " + " | ".join(f"**{worst[rt]:.2f} rtol** / {wall[rt]:.1f} s"
                                                                    for rt in rts) + " |", ""]
    pr = [r for r in runs if r.part == "presets"]
    if pr:
        lines += ["## Presets", "", "Total error (vs rod BVP for the clamped flagellum, vs the converged steady "
                  "solution for the free robot; in brackets the time error alone) and wall time from rest to the "
                  "steady state (median of the repeats).", ""]
        names = list(dict.fromkeys(r.preset for r in pr))
        lines += ["| case | rpm | " + " | ".join(f"`{p}`" for p in names) + " |", "|---|---|" + "---|" * len(names)]
        for case, rpm in dict.fromkeys((r.case, r.rpm) for r in pr):
            cells = []
            for p in names:
                m = [r for r in pr if r.case == case and r.rpm == rpm and r.preset == p]
                cells.append(f"{_pct(m[0].max_total_err)} ({_pct(m[0].max_time_err)}), {m[0].wall:.2f} s"
                             if m else "")
            lines.append(f"| {case} | {rpm:g} | " + " | ".join(cells) + " |")
        lines += ["", "| preset | worst clamped, 0.5-100 rpm | worst free robot, 100 rpm | wall, these (s) | "
                  "worst clamped, 200-2000 rpm | wall, these (s) |", "|---|---|---|---|---|---|"]
        for p in names:
            rp = [r for r in pr if r.preset == p]
            low = [r for r in rp if is_clamped(r.case) and r.rpm <= 100.0]
            free = [r for r in rp if not is_clamped(r.case)]
            high = [r for r in rp if is_clamped(r.case) and r.rpm > 100.0]
            worst = lambda rs: max((r.max_total_err for r in rs), default=math.nan)   # noqa: E731
            wall = lambda rs: f"{sum(r.wall for r in rs):.1f}" if rs else "-"                # noqa: E731
            lines.append(f"| `{p}` | {_pct(worst(low))} | {_pct(worst(free))} | {wall(low + free)} | "
                         f"{_pct(worst(high))} | {wall(high)} |")
        lines.append("")
    rq = [r for r in runs if r.part == "request"]
    if rq:
        lines += ["## Accuracy you ask for: accuracy.rtol", "",
                  "The discretisation each request chose, its total error (vs the rod BVP: Fx, Tx, the tip over its "
                  "deflection) and the wall time from rest to the steady state, the choice's steady solves "
                  "included.", "",
                  "| case | rpm | accuracy.rtol | chosen: time.rtol, edge | achieved | achieved / requested | "
                  "wall (s) |", "|---|---|---|---|---|---|---|"]
        for r in rq:
            lines.append(f"| {r.case} | {r.rpm:g} | {r.accuracy:g} | {r.rtol:g}, {1e3 * r.edge:.2f} mm | "
                         f"{_pct(r.max_total_err)} | {r.max_total_err / r.accuracy:.2f} | {r.wall:.2f} |")
        lines.append("")
    conv = {k: v for k, v in refs.data.items() if k.startswith("converged|")}
    if conv:
        lines += ["## References", ""]
        for k, v in sorted(conv.items()):
            vals = ", ".join(f"{n} = {v[n]:.6e}" for n in ("Fx", "Tx", "omega_h", "v") if n in v)
            extra = f", tip = ({', '.join(f'{x:.5e}' for x in v['tip'])})" if "tip" in v else ""
            lines.append(f"- {k.split('|', 1)[1]}: {v['source']}: {vals}{extra}")
        lines.append("")
    return "\n".join(lines)


def to_json(runs: list[Run], refs: References) -> dict:
    return {"runs": [dict(asdict(r), max_time_err=r.max_time_err, max_total_err=r.max_total_err) for r in runs],
            "references": refs.data}


def main(argv=None) -> int:
    import argparse
    ap = argparse.ArgumentParser(prog="bench accuracy", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    from . import accuracy_arguments
    accuracy_arguments(ap)
    return run(ap.parse_args(argv))


PARTS = ("front", "calibration", "presets", "request")


def replot(csv_path: Path, out: Path) -> list[Path]:
    """``--plot-from``: the figures of the runs in ``csv_path``, written into ``out``; the files written."""
    from ..cliutil import make_out_dir
    if not csv_path.is_file():
        raise SceneError(f"--plot-from {csv_path}: no such file")
    runs = read_csv(csv_path)
    out = make_out_dir(out)
    written = []
    for part, plot, name in (("front", plot_front, "accuracy_vs_time.png"),
                             ("calibration", plot_calibration, "accuracy_calibration.png")):
        sel = [r for r in runs if r.part == part]
        if sel:
            plot(sel, out / name)
            written.append(out / name)
    return written


def run(args) -> int:
    if args.plot_from:
        written = replot(Path(args.plot_from), Path(args.out))
        print("wrote " + (", ".join(map(str, written)) or "nothing (no front or calibration runs in the CSV)"))
        return 0
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    bad = [c for c in cases if c not in CASES]
    if bad:
        raise SystemExit(f"error: unknown case(s) {bad}; choose from {', '.join(CASES)}")
    parts = [p.strip() for p in args.parts.split(",") if p.strip()]
    bad = [p for p in parts if p not in PARTS]
    if bad:
        raise SystemExit(f"error: unknown part(s) {bad}; choose from {', '.join(PARTS)}")
    out = make_out_dir(args.out)
    refs = References(out / "references.json")
    q = args.quick
    runs: list[Run] = []
    previous = out / "accuracy.json"
    if previous.exists():          # the parts not run now are kept from the last run into this directory
        names = {f.name for f in fields(Run)}
        runs = [Run(**{k: v for k, v in r.items() if k in names})
                for r in json.loads(previous.read_text())["runs"] if r["part"] not in parts]
    t0 = time.perf_counter()
    if "front" in parts:
        runs += front(cases, QUICK_DTS if q else DTS, QUICK_EDGES if q else EDGES, QUICK_RTOLS if q else RTOLS, refs)
    if "calibration" in parts:
        runs += calibration(QUICK_CALIBRATION_RPM if q else CALIBRATION_RPM, QUICK_RTOLS if q else RTOLS, refs,
                            quick=q)
    if "presets" in parts:
        runs += presets(QUICK_PRESET_RPM if q else PRESET_RPM, refs, repeat=1 if q else args.repeat)
    if "request" in parts:
        runs += requests(QUICK_REQUESTS if q else REQUESTS, refs)
    runs.sort(key=lambda r: PARTS.index(r.part))
    if any(r.part == "front" for r in runs):
        plot_front([r for r in runs if r.part == "front"], out / "accuracy_vs_time.png")
    if any(r.part == "calibration" for r in runs):
        plot_calibration([r for r in runs if r.part == "calibration"], out / "accuracy_calibration.png")
    write_csv(out / "accuracy.csv", runs, refs)
    md = markdown(runs, refs)
    (out / "accuracy.md").write_text(md)
    (out / "accuracy.json").write_text(json_output(to_json(runs, refs), indent=1))
    print(md)
    print(f"wrote {out}/: accuracy.csv, accuracy.md, accuracy.json, references.json, the figures "
          f"({time.perf_counter() - t0:.0f} s; parts run now: {', '.join(parts)}; kept from before: "
          f"{', '.join(sorted({r.part for r in runs} - set(parts))) or 'none'})")
    return 0
