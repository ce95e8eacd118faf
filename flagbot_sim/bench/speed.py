"""Throughput: steps/s, real-time factor and where the time goes; cost per step vs number of DOF.

The per-phase breakdown wraps the model's methods with timers for the duration of the benchmark only (the
normal hot path carries no instrumentation): frames (trial context: edge frames, reference twist, trial
velocity and acceleration), elastic (stretch and bend-twist forces/Jacobian), effects (RFT, head, inertia, ...),
assembly (allocating and zeroing the residual and CSC data around them), linear solve (factorisation and
solves), stepper (Newton bookkeeping, predictor, line search, commit) and observe (spin angles, speed, history).
Where the steps run compiled (physics/newton.py: the solve, and the whole steps in batches) the phases inside
them are not apart: "stepper" is the compiled steps' whole time, the observer's per-step work included.
"""
from __future__ import annotations

import math
import statistics
import time
from collections import defaultdict

import numpy as np

from ..physics import Simulation
from ..scene import load_scene

CASES = [("design1", 2), ("design1", 3), ("design1", 5), ("design2", 2), ("design2", 3), ("design2", 5)]
PHASES = ("frames", "elastic", "effects", "assembly", "linear solve", "stepper", "observe")


class PhaseTimer:
    def __init__(self):
        self.t = defaultdict(float)

    def wrap(self, obj, name: str, phase: str) -> None:
        f = getattr(obj, name)
        t = self.t

        def timed(*a, **k):
            t0 = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                t[phase] += time.perf_counter() - t0
        setattr(obj, name, timed)


def instrument(sim: Simulation) -> PhaseTimer:
    pt = PhaseTimer()
    m, st = sim.model, sim.stepper
    pt.wrap(m, "context", "frames")
    pt.wrap(m.elastic, "accumulate", "elastic")
    for e in m.effects:
        pt.wrap(e, "add_force", "effects")
        pt.wrap(e, "add_jacobian", "effects")
    pt.wrap(m, "residual", "_residual_total")
    pt.wrap(m, "jacobian", "_jacobian_total")
    pt.wrap(st.solver, "factor", "linear solve")
    pt.wrap(st.solver, "solve", "linear solve")
    pt.wrap(st, "step", "_step_total")
    pt.wrap(st, "advance", "_step_total")      # the compiled steps (the observer's per-step work included)
    pt.wrap(sim.observer, "record", "observe")
    return pt


def breakdown(pt: PhaseTimer, steps: int) -> dict:
    """Microseconds per step in each phase."""
    t = pt.t
    evals = t["_residual_total"] + t["_jacobian_total"]
    # residual / jacobian include elastic and effects (context is separate); what is left is assembly
    assembly = evals - t["elastic"] - t["effects"]
    stepper = t["_step_total"] - evals - t["frames"] - t["linear solve"]
    out = {"frames": t["frames"], "elastic": t["elastic"], "effects": t["effects"], "assembly": assembly,
           "linear solve": t["linear solve"], "stepper": stepper, "observe": t["observe"]}
    return {k: 1e6 * v / steps for k, v in out.items()}


def measure(scene: str, n: int, warmup: float = 3.0, span: float = 5.0, extra=()) -> dict:
    sim = Simulation(load_scene(scene, [f"robot.n_flagella={n}", *extra]))
    sim.run(warmup)
    steps0, it0 = sim.steps, sim.newton_iterations
    t0 = time.perf_counter()
    sim.run(span)
    wall = time.perf_counter() - t0
    steps = sim.steps - steps0
    newton = (sim.newton_iterations - it0) / steps if steps else math.nan
    # the same span again, instrumented, for the breakdown (timers cost a little; the figures above do not pay it)
    pt = instrument(sim)
    s1 = sim.steps
    sim.run(span)
    return {"steps_per_s": steps / wall, "rtf": span / wall, "newton_per_step": newton, "ndof": sim.model.ndof,
            "us_per_step": 1e6 * wall / steps, "phases": breakdown(pt, sim.steps - s1),
            "solver": sim.stepper.solver.name}


def scaling(edges_per_flagellum=(5, 10, 20, 40, 80, 160, 330), n: int = 3, steps: int = 40, warmup_steps: int = 20):
    """Cost per step and per Newton iteration vs DOF (design 1, n = 3, dt = 1e-2, more and more edges)."""
    rows = []
    for N in edges_per_flagellum:
        edge = 0.111 / N
        sim = Simulation(load_scene("design1", [f"robot.n_flagella={n}", f"flagellum.edge_length={edge}"]))
        for _ in range(warmup_steps):
            sim.step()
        it0 = sim.newton_iterations
        best = math.inf
        t0 = time.perf_counter()
        for _ in range(steps):
            s = time.perf_counter()
            sim.step()
            best = min(best, time.perf_counter() - s)
        wall = time.perf_counter() - t0
        its = sim.newton_iterations - it0
        rows.append({"edges_per_flagellum": N, "ndof": sim.model.ndof, "us_per_step": 1e6 * wall / steps,
                     "us_per_newton": 1e6 * wall / max(its, 1), "newton_per_step": its / steps,
                     "best_us_per_step": 1e6 * best})
    x = np.log([r["ndof"] for r in rows])
    fit_step = float(np.polyfit(x, np.log([r["us_per_step"] for r in rows]), 1)[0])
    fit_newton = float(np.polyfit(x, np.log([r["us_per_newton"] for r in rows]), 1)[0])
    return rows, fit_step, fit_newton


def preset_table(repeat: int = 3, warmup: float = 3.0, span: float = 5.0) -> str:
    """Real-time factor of each accuracy preset (median of ``repeat``), for docs/accuracy.md."""
    from ..scene import PRESETS
    from .accuracy import CASES as ACCURACY_CASES     # the cases the presets' accuracy was measured on
    lines = ["real-time factor by accuracy preset (omega_T = 100 rpm, the clamped flagella too; median of "
             f"{repeat}, the presets interleaved)", f"{'case':20s} " + " ".join(f"{p:>12s}" for p in PRESETS)]
    for case, (scene, extra) in ACCURACY_CASES.items():
        n = load_scene(scene, extra).robot.n_flagella
        rtf = {p: [] for p in PRESETS}
        for _ in range(repeat):           # interleaved, so that a change of the machine's load hits all alike
            for preset in PRESETS:
                m = measure(scene, n, warmup, span, extra=[*extra, f"scene.preset='{preset}'"])
                rtf[preset].append(m["rtf"])
        lines.append(f"{case:20s} " + " ".join(f"{statistics.median(rtf[p]):12.1f}" for p in PRESETS))
    return "\n".join(lines)


def format_throughput(results: list[tuple]) -> str:
    lines = ["dt = 1e-2 s, 4.11 mm edges, omega_T = 100 rpm (median of the repeats; min..max)",
             f"{'case':12s} {'DOF':>5s} {'steps/s':>20s} {'real-time x':>20s} {'Newton/step':>11s} "
             + " ".join(f"{p:>12s}" for p in PHASES) + "   (us per step)"]
    for (scene, n), rs in results:
        sps = sorted(r["steps_per_s"] for r in rs)
        rtf = sorted(r["rtf"] for r in rs)
        ph = {p: statistics.median(r["phases"][p] for r in rs) for p in PHASES}
        lines.append(f"{scene} n={n:<3d} {rs[0]['ndof']:5d} {statistics.median(sps):8.0f} ({sps[0]:5.0f}..{sps[-1]:5.0f})"
                     f" {statistics.median(rtf):8.2f} ({rtf[0]:5.1f}..{rtf[-1]:5.1f}) "
                     f"{statistics.median(r['newton_per_step'] for r in rs):11.2f} "
                     + " ".join(f"{ph[p]:12.0f}" for p in PHASES))
    return "\n".join(lines)


def format_scaling(rows, fit_step, fit_newton) -> str:
    lines = ["cost vs size (design 1, n = 3, dt = 1e-2 s; more edges per flagellum)",
             f"{'edges/flag':>10s} {'DOF':>6s} {'us/step':>10s} {'us/Newton it':>13s} {'Newton/step':>11s}"]
    for r in rows:
        lines.append(f"{r['edges_per_flagellum']:10d} {r['ndof']:6d} {r['us_per_step']:10.0f} {r['us_per_newton']:13.0f} "
                     f"{r['newton_per_step']:11.2f}")
    lines.append(f"fitted growth exponent over all sizes: cost per step ~ DOF^{fit_step:.2f}, cost per Newton "
                 f"iteration ~ DOF^{fit_newton:.2f} (flattened by the fixed cost of a step taken alone)")
    if len(rows) >= 2:
        a, b = rows[-2], rows[-1]
        local = math.log(b["us_per_step"] / a["us_per_step"]) / math.log(b["ndof"] / a["ndof"])
        lines.append(f"growth between the two largest sizes ({a['ndof']} -> {b['ndof']} DOF): cost per step ~ "
                     f"DOF^{local:.2f}: what a larger model costs more")
    return "\n".join(lines)


#: whole processes as users run them (issue 24's targets): the 300 s design 1, n = 3 run at 150 rpm, and the
#: two designs from rest with their defaults
SIDE_BY_SIDE = (("design1 n=3 150 rpm 300 s", ["run", "design1", "--set", "robot.n_flagella=3", "--set",
                                              "motor.omega_rpm=150", "--duration", "300"]),
                ("run design1", ["run", "design1"]),
                ("run design2 n=3", ["run", "design2", "--set", "robot.n_flagella=3"]))


def _timed(root: str, argv: list[str]) -> tuple[float, float]:
    """(wall, CPU) seconds of ``python -m flagbot_sim ARGV`` with the package from ``root``, as a whole process."""
    import os
    import subprocess
    import sys
    env = dict(os.environ, PYTHONPATH=root)
    t0 = time.perf_counter()
    # cwd = root: ``python -m`` puts the working directory ahead of PYTHONPATH, so from inside a checkout both
    # runs would import that checkout's package
    p = subprocess.Popen([sys.executable, "-m", "flagbot_sim", *argv], env=env, cwd=root, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} with PYTHONPATH={root} exited with {p.returncode}")
    return wall, usage.ru_utime + usage.ru_stime


def alternating_pairs(timed, here: str, against: str, argv: list[str], pairs: int) -> list[tuple]:
    """[(old, new), ...] of ``timed(root, argv)`` with the package in ``against`` (old) and in ``here`` (new):
    one untimed run of each first (both kernel caches warm), then ``pairs`` pairs, alternating which goes first.
    Both packages are byte-compiled first: a checkout made under PYTHONDONTWRITEBYTECODE has no bytecode, and
    compiling its sources in every timed process (~0.04 s) would handicap that side."""
    import compileall
    import os
    for root in (here, against):
        compileall.compile_dir(os.path.join(root, "flagbot_sim"), quiet=1)
    timed(here, argv)
    timed(against, argv)
    rows = []
    for i in range(pairs):
        order = (against, here) if i % 2 == 0 else (here, against)
        got = {root: timed(root, argv) for root in order}
        rows.append((got[against], got[here]))
    return rows


def load_line(load0: tuple[float, float, float]) -> str:
    """The load average before (``load0``, os.getloadavg() then) and now, and the CPU count."""
    import os
    load1 = os.getloadavg()
    return (f"load average (1, 5, 15 min) before {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}, after "
            f"{load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}; {os.cpu_count()} CPUs")


def side_by_side(against: str, pairs: int = 3, commands=SIDE_BY_SIDE) -> str:
    """Each command as a whole process with this checkout's package and with the one in ``against``, in
    alternating pairs (after one untimed run of each, so both kernel caches are warm): medians of wall and CPU
    seconds and of the pair-by-pair ratio old / new, and the load average before and after."""
    import os
    from pathlib import Path
    here = str(Path(__file__).resolve().parents[2])
    load0 = os.getloadavg()
    lines = [f"side by side, whole processes: new = {here}, old = {against}; {pairs} pairs per command, "
             f"alternating; median (min..max)",
             f"{'command':28s} {'old wall s':>10s} {'new wall s':>10s} {'old/new wall':>20s} {'old/new CPU':>20s}"]
    for label, argv in commands:
        rows = alternating_pairs(_timed, here, against, argv, pairs)
        wall = sorted(o[0] / n[0] for o, n in rows)
        cpu = sorted(o[1] / n[1] for o, n in rows)
        lines.append(f"{label:28s} {statistics.median(o[0] for o, _ in rows):10.2f} "
                     f"{statistics.median(n[0] for _, n in rows):10.2f} "
                     f"{statistics.median(wall):7.2f} ({wall[0]:.2f}..{wall[-1]:.2f}) "
                     f"{statistics.median(cpu):7.2f} ({cpu[0]:.2f}..{cpu[-1]:.2f})")
        print(lines[-1], flush=True)
    lines.append(load_line(load0))
    return "\n".join(lines)


#: the device (sim_node's stepping, without ROS: device.Device, ticks of the node's default 50 Hz with its
#: stepping budget) as fast as it can go, design 1, n = 3 at 150 rpm: its simulated seconds per wall second after
#: 2 s of warm-up, printed by a child process of either checkout
DEVICE_CODE = r"""
import sys, time
from flagbot_sim.device import Device, PARAMS
try:
    from flagbot_sim.physics.blas import single_threaded_process
    single_threaded_process()                  # as sim_node's console script does
except ImportError:
    pass
values = {s.name: s.default for s in PARAMS}
values.update(scene="design1", n_flagella=3, real_time_factor=0.0, initial_omega=150 * 0.10471975511965977)
device = Device(values)
device.configure()
tick = 1.0 / 50.0
while device.sim.time < 2.0:
    device.advance(0.8 * tick, tick)
t0, w0 = device.sim.time, time.perf_counter()
while time.perf_counter() - w0 < float(sys.argv[1]):
    device.advance(0.8 * tick, tick)
print((device.sim.time - t0) / (time.perf_counter() - w0))
"""


def device_rate(root: str | None = None, seconds: float = 4.0) -> float:
    """The device's real-time factor at rtf 0 (:data:`DEVICE_CODE`) in a child process with the package from
    ``root`` (default this checkout)."""
    import os
    import subprocess
    import sys
    env = dict(os.environ)
    if root is not None:
        env["PYTHONPATH"] = root
    out = subprocess.run([sys.executable, "-c", DEVICE_CODE, str(seconds)], env=env, cwd=root or os.getcwd(),
                         capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"the device benchmark failed (PYTHONPATH={root}): {out.stderr.strip()[-300:]}")
    return float(out.stdout.strip().splitlines()[-1])


def device_side_by_side(against: str, pairs: int) -> str:
    """The device's real-time factor at rtf 0 with this checkout and with ``against``: alternating pairs after one
    untimed run of each, as the whole processes above."""
    from pathlib import Path
    if not (Path(against) / "flagbot_sim" / "device.py").exists():
        return f"{'device, rtf 0 (sim s / wall s)':28s} skipped: {against} has no flagbot_sim/device.py"
    here = str(Path(__file__).resolve().parents[2])
    rows = alternating_pairs(lambda root, _: device_rate(root), here, against, [], pairs)
    ratio = sorted(n / o for o, n in rows)
    return (f"{'device, rtf 0 (sim s / wall s)':28s} {statistics.median(o for o, _ in rows):10.1f} "
            f"{statistics.median(n for _, n in rows):10.1f}    new/old rate {statistics.median(ratio):.2f} "
            f"({ratio[0]:.2f}..{ratio[-1]:.2f})")


def run(args) -> int:
    if args.against:
        print(side_by_side(args.against, args.pairs))
        print(device_side_by_side(args.against, args.pairs), flush=True)
        return 0
    cases = CASES[:2] + CASES[3:5] if args.quick else CASES
    repeat = 1 if args.quick else args.repeat
    results = []
    for scene, n in cases:
        results.append(((scene, n), [measure(scene, n, args.warmup, args.measure) for _ in range(repeat)]))
        print(f"  measured {scene} n={n}", flush=True)
    print(format_throughput(results), flush=True)
    print(f"the device (sim_node's stepping without ROS, 50 Hz ticks), design 1, n = 3, 150 rpm, as fast as it "
          f"can: real-time factor {device_rate():.1f}", flush=True)
    if not args.no_scaling:
        rows, fs, fn = scaling(edges_per_flagellum=(5, 20, 80, 330) if args.quick else
                               (5, 10, 20, 40, 80, 160, 330))
        print(format_scaling(rows, fs, fn), flush=True)
    if not args.no_steady:
        rows = steady_vs_time(1 if args.quick else repeat,
                              cases=STEADY_CASES[:3] if args.quick else STEADY_CASES)
        print(format_steady(rows), flush=True)
    if not args.no_presets:
        print(preset_table(1 if args.quick else repeat, args.warmup, args.measure), flush=True)
    if not args.no_pyelastica:
        from . import pyelastica
        pyelastica.run_comparison(quick=args.quick)
    return 0


def main(argv=None) -> int:
    import argparse
    ap = argparse.ArgumentParser(prog="bench speed", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    from . import speed_arguments
    speed_arguments(ap)
    return run(ap.parse_args(argv))


# ---------------------------------------------------------------------------------------------- steady vs stepping
STEADY_CASES = [("clamped_flagellum", ["motor.omega_rpm=10"]), ("clamped_flagellum", ["motor.omega_rpm=100"]),
                ("design1", []), ("design1", ["robot.n_flagella=3"]), ("design2", []),
                ("design2", ["robot.n_flagella=3"])]


def _output_keys(scene) -> tuple[str, ...]:
    return ("Fx", "Tx") if scene.clamped else ("omega_h", "omega_t", "v")


#: the time-stepped runs beside each direct solve: the default (BDF2 at the scene's dt = 1e-2 s) and the paper's
#: numerics (implicit Euler, dt = 1e-2 s), each with the time error it leaves; then time stepping to the same
#: accuracy as cheaply as it gets there: BDF2 at the fastest step within FASTEST_ACCURACY of the equilibrium
#: (bench/stepsearch.py's search from the scene's own step: a fixed fine step would overstate the steady solver's
#: gain, since design 1's default steps are within 1e-5 already)
STEADY_COLUMNS = (("default", ["time.integrator='bdf2'"]), ("paper", ["time.integrator='implicit_euler'"]))
STEADY_LABELS = {"default": "default: BDF2 dt=1e-2", "paper": "paper: impl. Euler dt=1e-2",
                 "fastest": "BDF2, fastest step within 1e-4"}
FASTEST_ACCURACY = 1e-4


def _stepped(scene_name: str, extra: list[str], over: list[str], ref: dict, t_max: float) -> dict:
    """Time stepping from rest to the steady-state rule (stepsearch.run_to_steady), its outputs (omega_h, omega_t,
    v; or Fx, Tx) against the equilibrium's summary ``ref``."""
    from .stepsearch import run_to_steady
    scene = load_scene(scene_name, ["observe.steady_rtol=1e-4", *extra, *over])
    return run_to_steady(scene, ref, _output_keys(scene), t_max)


def steady_vs_time(repeat: int = 3, t_max: float = 120.0, cases=STEADY_CASES) -> list[dict]:
    """For each case: the direct steady solve (median wall of ``repeat``), and time-stepping to the steady-state
    rule from rest (:data:`STEADY_COLUMNS`, and the fastest step within :data:`FASTEST_ACCURACY`), each with its
    largest relative difference from the equilibrium in its outputs (omega_h, omega_t, v; or Fx, Tx)."""
    from ..physics.model import RobotModel
    from ..physics.steady import SteadySolver, summary
    from .stepsearch import fastest, largest_step, turn_limit
    rows = []
    for scene_name, extra in cases:
        sc = load_scene(scene_name, ["observe.steady_rtol=1e-4", *extra])
        SteadySolver(RobotModel(sc)).solve(sc.omega_T)      # untimed: loads the kernels a first solve loads
        walls = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            m = RobotModel(sc)
            sol = SteadySolver(m).solve(sc.omega_T)
            walls.append(time.perf_counter() - t0)
        ref = summary(m, sol)
        row = {"case": f"{scene_name} {' '.join(extra)}".strip(), "steady_s": statistics.median(walls),
               "iterations": sol.iterations}
        for tag, over in STEADY_COLUMNS:
            r = _stepped(scene_name, extra, over, ref, t_max)
            for k in ("wall", "steady", "error", "sim_time"):
                row[f"{tag}_{k}"] = r[k]
        tried = largest_step(lambda dt: _stepped(scene_name, extra, ["time.integrator='bdf2'", f"time.dt={dt!r}"],
                                                 ref, t_max), sc.time.dt, FASTEST_ACCURACY,
                             dt_max=turn_limit(sc))
        best = fastest(tried, FASTEST_ACCURACY)
        for k in ("wall", "steady", "error", "sim_time", "dt"):
            row[f"fastest_{k}"] = best[k] if best else (math.inf if k == "error" else math.nan)
        rows.append(row)
        print(f"  steady vs time-stepping: {row['case']}", flush=True)
    return rows


def format_steady(rows: list[dict]) -> str:
    tags = [tag for tag, _ in STEADY_COLUMNS] + ["fastest"]
    lines = ["steady state: solved directly vs time-stepped from rest to the steady-state rule (rtol 1e-4); "
             "error = largest relative difference from the equilibrium (omega_h, omega_t, v; clamped: Fx, Tx); the last "
             "column at the fastest BDF2 step within 1e-4 (its dt in s), time stepping to the same accuracy",
             f"{'case':38s} {'steady solve':>12s}" + "".join(f" {STEADY_LABELS[t]:>34s}" for t in tags),
             f"{'':38s} {'ms':>12s}" + "".join(f" {'s wall (error)  ratio':>34s}" for _ in tags)]
    for r in rows:
        cells = []
        for tag in tags:
            if not math.isfinite(r[f"{tag}_wall"]):
                cells.append("no step within 1e-4" if tag == "fastest" else "failed")
                continue
            flag = "" if r[f"{tag}_steady"] else " CAP"
            at = f" @{r['fastest_dt']:.2g}" if tag == "fastest" else ""
            cells.append(f"{r[f'{tag}_wall']:8.2f} ({100 * r[f'{tag}_error']:6.3f}%) "
                         f"{r[f'{tag}_wall'] / r['steady_s']:6.0f}x{flag}{at}")
        lines.append(f"{r['case']:38s} {1e3 * r['steady_s']:12.1f}" + "".join(f" {c:>34s}" for c in cells))
    return "\n".join(lines)
