"""What accuracy costs in time: a grid of time steps x edge lengths, each run to steady state.

For every case (the clamped flagellum, and the free robot in both designs with n = 2 and 3) each grid point
runs to a detected steady state; its steady outputs are compared with a converged reference, and its wall time
and real-time factor are recorded. Outputs: a CSV (one row per run), a PNG of error vs wall time per case with
the Pareto front, observed convergence orders, and a markdown table (docs/accuracy.md).

Reference: Richardson extrapolation from the finest runs, assuming first order in dt (implicit Euler) and
second order in the edge length (the rod discretisation): q* = q(h, e) + [q(h, e) - q(2h, e)]
+ [q(h, e) - q(h, 2e)] / 3. The observed orders, fitted from the grid, are printed next to it as a check of that
assumption. For the clamped flagellum the geometrically exact rod equations, solved as a boundary-value
problem (flagbot_sim.reference.rod_bvp), give a second, independent reference.
"""
from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..physics import Simulation, StepFailed
from ..scene import load_scene

FREE_OUTPUTS = ("v", "omega_h", "omega_t")
CLAMP_OUTPUTS = ("Fx", "Tx", "tip_y", "tip_z")

CASES = {
    "clamped": ("clamped_flagellum", ["motor.omega_rpm=10"]),
    "design1_n2": ("design1", ["robot.n_flagella=2", "motor.omega_rpm=100"]),
    "design1_n3": ("design1", ["robot.n_flagella=3", "motor.omega_rpm=100"]),
    "design2_n2": ("design2", ["robot.n_flagella=2", "motor.omega_rpm=100"]),
    "design2_n3": ("design2", ["robot.n_flagella=3", "motor.omega_rpm=100"]),
}
DTS = (1e-1, 5e-2, 2e-2, 1e-2, 5e-3, 2e-3)
EDGES = (16.44e-3, 8.22e-3, 4.11e-3, 2.055e-3)
QUICK_DTS = (5e-2, 2e-2, 1e-2)
QUICK_EDGES = (8.22e-3, 4.11e-3)


@dataclass
class Run:
    case: str
    dt: float
    edge: float
    outputs: dict
    sim_time: float          # simulated time until steady (s)
    wall: float              # wall time (s)
    steps: int
    newton: int
    reductions: int
    steady: bool
    error: str = ""
    rel_err: dict = field(default_factory=dict)
    max_err: float = math.nan

    @property
    def rtf(self) -> float:
        return self.sim_time / self.wall if self.wall > 0 else math.inf


def outputs_of(sim: Simulation) -> dict:
    s = sim.summary()
    if sim.scene.clamped:
        return {"Fx": s["Fx"], "Tx": s["Tx"], "tip_y": s["tip"][1], "tip_z": s["tip"][2]}
    return {"v": s["v"], "omega_h": s["omega_h"], "omega_t": s["omega_t"]}


def run_point(case: str, dt: float, edge: float, rtol: float = 1e-4, window: float = 2.0,
              cap: float = 90.0) -> Run:
    """One grid point: run until the steady-state estimate changes by less than rtol between windows."""
    scene_name, overrides = CASES[case]
    sc = load_scene(scene_name, overrides + [f"time.dt={dt}", f"flagellum.edge_length={edge}",
                                             f"observe.steady_window={window}", f"observe.steady_rtol={rtol}"])
    sim = Simulation(sc)
    w0 = time.perf_counter()
    err = ""
    check_every = max(1, int(round(0.5 / dt)))
    try:
        while sim.time < cap - 1e-9:
            sim.step()
            if sim.steps % check_every == 0 and sim.time >= 2 * window and sim.steady_state()["steady"]:
                break
    except StepFailed as exc:
        err = str(exc)
    wall = time.perf_counter() - w0
    steady = sim.steady_state()["steady"] and not err
    return Run(case, dt, edge, outputs_of(sim), sim.time, wall, sim.steps, sim.newton_iterations, sim.reductions,
               steady, err)


def richardson(fine: Run, coarse_dt: Run, coarse_edge: Run) -> dict:
    """Reference values: first order in dt, second order in the edge length."""
    out = {}
    for k, q in fine.outputs.items():
        out[k] = q + (q - coarse_dt.outputs[k]) + (q - coarse_edge.outputs[k]) / 3.0
    return out


def observed_order(runs: list[Run], ref: dict, key: str, vary: str) -> float:
    """Slope of log(error) vs log(dt or edge) along the finest line of the other parameter."""
    if vary == "dt":
        other = min(r.edge for r in runs)
        line = sorted((r.dt, r) for r in runs if r.edge == other and r.steady)
    else:
        other = min(r.dt for r in runs)
        line = sorted((r.edge, r) for r in runs if r.dt == other and r.steady)
    xs, ys = [], []
    for x, r in line:
        e = abs(r.outputs[key] - ref[key]) / max(abs(ref[key]), 1e-300)
        if e > 0:
            xs.append(math.log(x))
            ys.append(math.log(e))
    if len(xs) < 2:
        return math.nan
    return float(np.polyfit(xs, ys, 1)[0])


def pareto(runs: list[Run]) -> list[Run]:
    """Runs that no other run beats in both wall time and error."""
    ok = sorted((r for r in runs if math.isfinite(r.max_err)), key=lambda r: (r.wall, r.max_err))
    front, best = [], math.inf
    for r in ok:
        if r.max_err < best:
            front.append(r)
            best = r.max_err
    return front


def study(cases: list[str], dts=DTS, edges=EDGES, out_dir: Path = Path("out/accuracy"), progress=print,
          bvp: bool = True) -> dict:
    out_dir.mkdir(parents=True, exist_ok=True)
    results = {}
    for case in cases:
        runs = []
        grid = [(dt, e) for e in edges for dt in dts]
        h, e = min(dts), min(edges)
        ref_runs = [(h / 2, e / 2), (h, e / 2), (h / 2, e)]    # Richardson: fine, coarser dt, coarser edge
        for i, (dt, edge) in enumerate(grid + ref_runs):
            r = run_point(case, dt, edge)
            progress(f"{case:11s} [{i + 1:2d}/{len(grid) + 3}] dt {dt:7.4f} s  edge {1e3 * edge:6.3f} mm  "
                     f"{'steady' if r.steady else 'NOT steady'} at {r.sim_time:5.1f} s  wall {r.wall:6.1f} s  "
                     + "  ".join(f"{k} {v:+.6e}" for k, v in r.outputs.items()) + (f"  ERROR {r.error}" if r.error
                                                                                   else ""))
            runs.append(r)
        fine, cdt, cedge = runs[-3], runs[-2], runs[-1]
        ref = richardson(fine, cdt, cedge)
        refs = {"richardson": ref}
        if bvp and case == "clamped":
            refs["rod_bvp"] = rod_bvp_reference(case)
        grid_runs = runs[:-3]                                  # without the Richardson reference runs
        for r in runs:
            r.rel_err = {k: abs(r.outputs[k] - ref[k]) / max(abs(ref[k]), 1e-300) for k in ref}
            r.max_err = max(r.rel_err.values()) if r.steady else math.inf
        orders = {k: {"dt": observed_order(grid_runs, ref, k, "dt"), "edge": observed_order(grid_runs, ref, k, "edge")}
                  for k in ref}
        results[case] = {"runs": runs, "grid": grid_runs, "refs": refs, "orders": orders,
                         "pareto": pareto(grid_runs)}
        write_csv(out_dir / f"{case}.csv", runs, refs)
    return results


def rod_bvp_reference(case: str) -> dict:
    from ..reference.rod_bvp import from_scene
    scene_name, overrides = CASES[case]
    sol = from_scene(load_scene(scene_name, overrides))
    return {"Fx": sol.Fx, "Tx": sol.Tx, "tip_y": float(sol.tip[1]), "tip_z": float(sol.tip[2])}


def write_csv(path: Path, runs: list[Run], refs: dict) -> None:
    keys = list(runs[0].outputs)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["case", "dt_s", "edge_m", "steady", "sim_time_s", "wall_s", "real_time_factor", "steps",
                    "newton_iterations", "dt_reductions", *keys, *[f"relerr_{k}" for k in keys], "max_relerr",
                    "error"])
        for r in runs:
            w.writerow([r.case, r.dt, r.edge, r.steady, f"{r.sim_time:.4f}", f"{r.wall:.4f}", f"{r.rtf:.3f}", r.steps,
                        r.newton, r.reductions, *[f"{r.outputs[k]:.10e}" for k in keys],
                        *[f"{r.rel_err.get(k, math.nan):.4e}" for k in keys], f"{r.max_err:.4e}", r.error])
        for name, ref in refs.items():
            w.writerow([f"reference:{name}", "", "", "", "", "", "", "", "", "", *[f"{ref[k]:.10e}" for k in keys],
                        *[""] * len(keys), "", ""])


def plot(results: dict, png: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    n = len(results)
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 4.0), squeeze=False)
    for ax, (case, res) in zip(axes[0], results.items()):
        runs = [r for r in res["grid"] if math.isfinite(r.max_err)]
        edges = sorted({r.edge for r in runs})
        for i, e in enumerate(edges):
            rs = sorted((r for r in runs if r.edge == e), key=lambda r: r.dt)
            ax.loglog([r.wall for r in rs], [r.max_err for r in rs], "o-", ms=4, lw=0.8, color=f"C{i}",
                      label=f"edge {1e3 * e:.2f} mm")
            for r in rs:
                ax.annotate(f"{r.dt:g}", (r.wall, r.max_err), fontsize=6, xytext=(3, 2), textcoords="offset points")
        front = res["pareto"]
        ax.loglog([r.wall for r in front], [r.max_err for r in front], "k--", lw=1.2, label="Pareto front")
        ax.set_title(case)
        ax.set_xlabel("wall time to steady state (s)")
        ax.grid(alpha=0.3, which="both")
    axes[0][0].set_ylabel("largest relative error of the steady outputs")
    axes[0][0].legend(fontsize=7)
    fig.suptitle("Accuracy vs time (labels: dt in s)")
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)


def markdown(results: dict) -> str:
    lines = []
    for case, res in results.items():
        keys = list(res["refs"]["richardson"])
        lines += [f"### {case}", "",
                  "Reference (Richardson): " + ", ".join(f"{k} = {v:.6e}" for k, v in res["refs"]["richardson"].items())]
        if "rod_bvp" in res["refs"]:
            b = res["refs"]["rod_bvp"]
            rr = res["refs"]["richardson"]
            lines.append("Rod BVP (geometrically exact, independent): " + ", ".join(
                f"{k} = {b[k]:.6e} ({100 * (rr[k] - b[k]) / abs(b[k]):+.3f}% DER)" for k in keys))
        lines.append("Observed orders (dt; edge): " + ", ".join(
            f"{k} {o['dt']:.2f}; {o['edge']:.2f}" for k, o in res["orders"].items()))
        lines += ["", "| dt (s) | edge (mm) | steady at (s) | wall (s) | real-time factor | Newton it/step | "
                  + " | ".join(f"err {k}" for k in keys) + " | max err |",
                  "|---|---|---|---|---|---|" + "---|" * len(keys) + "---|"]
        for r in sorted(res["grid"], key=lambda r: (r.edge, -r.dt)):
            errs = " | ".join(f"{100 * r.rel_err[k]:.3f}%" for k in keys)
            flag = "" if r.steady else " (not steady)"
            lines.append(f"| {r.dt:g} | {1e3 * r.edge:.3f} | {r.sim_time:.1f}{flag} | {r.wall:.1f} | {r.rtf:.1f} | "
                         f"{r.newton / max(r.steps, 1):.2f} | {errs} | {100 * r.max_err:.3f}% |")
        lines.append("")
    return "\n".join(lines)


def to_json(results: dict) -> dict:
    return {case: {"refs": res["refs"], "orders": res["orders"],
                   "runs": [dict(asdict(r), rtf=r.rtf) for r in res["runs"]]} for case, res in results.items()}


def main(argv=None) -> int:
    import argparse
    ap = argparse.ArgumentParser(prog="bench accuracy", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    from . import accuracy_arguments
    accuracy_arguments(ap)
    return run(ap.parse_args(argv))


def run(args) -> int:
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    bad = [c for c in cases if c not in CASES]
    if bad:
        raise SystemExit(f"error: unknown case(s) {bad}; choose from {', '.join(CASES)}")
    out = Path(args.out)
    dts, edges = (QUICK_DTS, QUICK_EDGES) if args.quick else (DTS, EDGES)
    results = study(cases, dts, edges, out, bvp=not args.no_bvp)
    plot(results, out / "accuracy_vs_time.png")
    md = markdown(results)
    (out / "accuracy.md").write_text(md)
    (out / "accuracy.json").write_text(json.dumps(to_json(results), default=float, indent=1))
    print(md)
    print(f"wrote {out}/: one CSV per case, accuracy_vs_time.png, accuracy.md, accuracy.json")
    return 0
