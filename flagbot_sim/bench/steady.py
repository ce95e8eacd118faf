"""``flagbot bench steady``: the steady solver against time stepping, and the paper's sweeps as whole commands.

(a) Per case (design 1 and 2, n = 2 and 3, 100 rpm by default): what ``flagbot steady`` computes for one speed
(the equilibrium, its space-error estimate and its stability; the solve alone too), in this process with the
kernels loaded, against BDF2 time stepping from rest to the steady-state rule at ``observe.steady_rtol`` = 1e-4
with a fixed step. Its outputs (omega_h, omega_t, v) are compared with the equilibrium, and the ratio is taken
against the fastest run whose outputs are within ``--accuracy`` (1e-4) of it: time stepping to the same
accuracy, as cheaply as it gets there. The steps tried (:func:`largest_step`) start at the scene's own step (what
``flagbot run`` uses), double while the outputs stay within the accuracy and halve while they do not, then bisect
the bracket twice (the step found is within 1.19x of the largest accurate one), so a coarser step that is
accurate enough is never missed (until 2026-12-08 the default tried only 2e-3 and 1e-3 s,
and so credited the steady solver with up to 5x too much for design 1, whose 1e-2 s steps are within 1e-5).

(b) ``--against DIR``: the paper's four full sweeps (README "Reproduce the paper", docs/make_figures.sh) as
whole commands (``python -m flagbot_sim sweep ...``, every framework, the figures) with this checkout's package and
with the one in DIR (e.g. ``git worktree add --detach ../old 7558dfb``, its kernel cache warmed by one run
first), in alternating pairs after one untimed run of each, each run in a fresh output directory and a
working directory outside both checkouts. Wall seconds only: the new sweep's workers fork from a fork server
whose CPU time the command's rusage does not include.
"""
from __future__ import annotations

import math
import os
import statistics
import time

from .stepsearch import fastest, largest_step, run_to_steady, turn_limit

#: the cases of (a): scene, extra overrides
CASES = (("design1", ["robot.n_flagella=2"]), ("design1", ["robot.n_flagella=3"]),
         ("design2", ["robot.n_flagella=2"]), ("design2", ["robot.n_flagella=3"]))
#: the paper's four full sweeps (384 points): label, argv after ``sweep``
SWEEPS = (("design1 n x rpm (48)", ["design1", "--grid", "n=2,3", "--grid", "rpm=20:250:10"]),
          ("design2 n x rpm (48)", ["design2", "--grid", "n=2,3", "--grid", "rpm=20:250:10"]),
          ("design1 L x n x rpm (144)", ["design1", "--grid", "L=0.09,0.111,0.13", "--grid", "n=2,3", "--grid",
                                         "rpm=20:250:10"]),
          ("design2 L x n x rpm (144)", ["design2", "--grid", "L=0.07,0.089,0.11", "--grid", "n=2,3", "--grid",
                                         "rpm=20:250:10"]))
OUTPUTS = ("omega_h", "omega_t", "v")


def arguments(ap) -> None:
    ap.add_argument("--rpm", type=float, default=100.0, help="motor speed of the cases (default 100)")
    ap.add_argument("--repeat", type=int, default=5, help="repeats of each steady solve (median reported)")
    ap.add_argument("--dts", default="auto", metavar="LIST",
                    help="BDF2 step sizes tried, s; the fastest run within --accuracy is compared (default auto: from "
                         "the scene's step, doubling while within --accuracy, halving while not)")
    ap.add_argument("--accuracy", type=float, default=1e-4,
                    help="relative accuracy the time-stepped steady state must reach (default 1e-4)")
    ap.add_argument("--t-max", type=float, default=120.0, help="cap on simulated seconds per time-stepped run")
    ap.add_argument("--no-cases", action="store_true", help="skip (a), the steady solver against time stepping")
    ap.add_argument("--against", default=None, metavar="DIR",
                    help="(b): the four sweeps as whole commands, this checkout against the flagbot_sim in DIR")
    ap.add_argument("--pairs", type=int, default=3, help="--against: pairs of runs per sweep (median reported)")
    ap.add_argument("--sweeps", default="1,2,3,4", metavar="LIST", help="--against: which of the four (1-4)")


# --------------------------------------------------------------------------------------------- (a) per case
def _steady_once(scene) -> tuple[float, float, dict]:
    """(wall of flagbot steady's work for one speed, wall of the solve alone, its summary row). The work is
    commands/steady.py's solve_scene for one speed, step by step (a bench does not import the commands): the
    model, the coarse and fine solves, the summary, the space-error estimate, the stability, on one BLAS
    thread."""
    from ..physics import error_estimate, warmup
    from ..physics.model import RobotModel
    from ..physics.blas import one_thread
    from ..physics.steady import SteadySolver, summary
    with one_thread():
        t0 = time.perf_counter()
        sc, _ = error_estimate.resolve_accuracy(scene)
        warmup.ensure_compiled(groups=warmup.groups_for(sc, time_stepping=False))
        model = RobotModel(sc)
        solver = SteadySolver(model)
        space = error_estimate.SpaceEstimator(sc)
        sol = space.solve_fine(solver, sc.omega_T)
        row = summary(model, sol)
        row.update(error_estimate.for_steady(model, sol, row, space))
        row["stability"] = solver.stability(sol).to_dict()
        whole = time.perf_counter() - t0
        t0 = time.perf_counter()
        model = RobotModel(sc)
        space = error_estimate.SpaceEstimator(sc)
        space.solve_fine(SteadySolver(model), sc.omega_T)
        return whole, time.perf_counter() - t0, row


def compare_case(scene_name: str, extra: list[str], rpm: float, repeat: int, dts: list[float] | None,
                 accuracy: float, t_max: float) -> dict:
    """One case of (a). ``dts`` None: :func:`largest_step` from the scene's own step; else those steps."""
    from ..scene import load_scene
    over = [*extra, f"motor.omega_rpm={rpm:g}", "observe.steady_rtol=1e-4"]
    scene = load_scene(scene_name, over)
    _steady_once(scene)                                 # loads what the first solve loads
    runs = [_steady_once(scene) for _ in range(repeat)]
    ref = runs[-1][2]
    out = {"case": f"{scene_name} {' '.join(extra)} {rpm:g} rpm", "steady_s": statistics.median(r[0] for r in runs),
           "solve_s": statistics.median(r[1] for r in runs)}

    def trial(dt: float) -> dict:
        r = run_to_steady(load_scene(scene_name, [*over, "time.integrator='bdf2'", f"time.dt={dt!r}"]), ref, OUTPUTS,
                          t_max)
        if "failed" in r:
            print(f"  {out['case']}: BDF2 dt {dt:g} s: failed ({r['failed']})", flush=True)
        else:
            print(f"  {out['case']}: BDF2 dt {dt:g} s: {r['wall']:.2f} s, error {r['error']:.2e}"
                  + ("" if r["steady"] else " (not steady at the cap)"), flush=True)
        return r

    out["stepping"] = (largest_step(trial, scene.time.dt, accuracy, dt_max=turn_limit(scene))
                       if dts is None else [trial(dt) for dt in dts])
    out["matched"] = fastest(out["stepping"], accuracy)
    return out


def format_cases(rows: list[dict], accuracy: float) -> str:
    lines = [f"steady state solved directly (flagbot steady's work for one speed: equilibrium, space-error estimate, "
             f"stability; and the solve alone) vs BDF2 from rest to the steady-state rule (rtol 1e-4) at the "
             f"fastest step whose omega_h, omega_t, v are within {accuracy:g} of the equilibrium",
             f"{'case':28s} {'steady ms':>10s} {'solve ms':>9s} {'BDF2 dt':>8s} {'wall s':>8s} {'error':>9s} "
             f"{'ratio (steady)':>15s} {'ratio (solve)':>14s}"]
    for r in rows:
        m = r["matched"]
        if m is None:
            lines.append(f"{r['case']:28s} {1e3 * r['steady_s']:10.1f} {1e3 * r['solve_s']:9.1f}   no step tried "
                         f"reached {accuracy:g}")
            continue
        lines.append(f"{r['case']:28s} {1e3 * r['steady_s']:10.1f} {1e3 * r['solve_s']:9.1f} {m['dt']:8.2g} "
                     f"{m['wall']:8.2f} {m['error']:9.1e} {m['wall'] / r['steady_s']:14.0f}x "
                     f"{m['wall'] / r['solve_s']:13.0f}x")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------- (b) the sweeps
def _timed_sweep(root: str, argv: list[str]) -> float:
    """Wall seconds of ``python -m flagbot_sim sweep ARGV`` with the package from ``root``, as a whole process,
    into a fresh directory (working directory outside every checkout: ``python -m`` puts it first on the path)."""
    import subprocess
    import sys
    import tempfile
    with tempfile.TemporaryDirectory(prefix="flagbot-bench-steady-") as tmp:
        env = dict(os.environ, PYTHONPATH=root)
        cmd = [sys.executable, "-m", "flagbot_sim", "sweep", *argv, "--out", os.path.join(tmp, "out"), "--quiet"]
        t0 = time.perf_counter()
        p = subprocess.run(cmd, env=env, cwd=tmp, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        wall = time.perf_counter() - t0
    if p.returncode not in (0, 1):           # 1: the sweep ran but some point reports an error (its summary)
        raise RuntimeError(f"sweep {' '.join(argv)} with PYTHONPATH={root} exited with {p.returncode}: "
                           f"{p.stderr[-500:]}")
    return wall


def sweeps_side_by_side(against: str, pairs: int, which: list[int]) -> str:
    from pathlib import Path

    from .speed import alternating_pairs, load_line
    here = str(Path(__file__).resolve().parents[2])
    against = str(Path(against).resolve())
    load0 = os.getloadavg()
    lines = [f"the paper's sweeps as whole commands: new = {here}, old = {against}; {pairs} pairs each, alternating, "
             "after one untimed run of each; wall seconds, median (min..max of the pairs' old/new)",
             f"{'sweep':28s} {'old s':>8s} {'new s':>8s} {'old/new':>20s}"]
    tot_old, tot_new = [], []
    for i in which:
        label, argv = SWEEPS[i - 1]
        rows = alternating_pairs(_timed_sweep, here, against, argv, pairs)
        ratio = sorted(o / n for o, n in rows)
        old = statistics.median(o for o, _ in rows)
        new = statistics.median(n for _, n in rows)
        tot_old.append(old)
        tot_new.append(new)
        lines.append(f"{label:28s} {old:8.2f} {new:8.2f} {statistics.median(ratio):7.2f} "
                     f"({ratio[0]:.2f}..{ratio[-1]:.2f})")
        print(lines[-1], flush=True)
    lines.append(f"{'all of them (sum of medians)':28s} {sum(tot_old):8.2f} {sum(tot_new):8.2f} "
                 f"{sum(tot_old) / sum(tot_new):7.2f}   (target: >= 2, at most half the old time)")
    lines.append(load_line(load0))
    return "\n".join(lines)


def run(args) -> int:
    if not args.no_cases:
        dts = None
        if args.dts.strip() != "auto":
            try:
                dts = sorted({float(x) for x in args.dts.split(",") if x.strip()}, reverse=True)
            except ValueError:
                dts = []
            if not dts or not all(math.isfinite(d) and d > 0 for d in dts):
                raise SystemExit(f"error: --dts needs 'auto' or positive step sizes, got {args.dts!r}")
        rows = [compare_case(name, extra, args.rpm, max(1, args.repeat), dts, args.accuracy, args.t_max)
                for name, extra in CASES]
        print(format_cases(rows, args.accuracy), flush=True)
    if args.against:
        which = [int(x) for x in args.sweeps.split(",") if x.strip()]
        if not which or any(i not in (1, 2, 3, 4) for i in which):
            raise SystemExit(f"error: --sweeps lists numbers 1-4, got {args.sweeps!r}")
        print(sweeps_side_by_side(args.against, max(1, args.pairs), which), flush=True)
    return 0
