"""``flagbot fit SCENE DATA.csv --fit KEYS`` and ``flagbot optimize SCENE --vary KEY=LOW:HIGH,...``."""
from __future__ import annotations

import math
import signal
import sys
from pathlib import Path

from ..cliutil import add_scene_arguments, json_output, make_out_dir
from ..scene import load_scene
from ..units import RPM
from ..sweep.engines import ENGINES, default_workers
from ..fit.data import _short_key
from ..fit.evaluate import RPM_KEY
from ..fit.pool import Engine


def _engine_arguments(p) -> None:
    p.add_argument("--engine", choices=ENGINES, default="local",
                   help="where the steady states are solved: local (process pool, default), dask (a Dask "
                        "cluster), serial (this process)")
    p.add_argument("--workers", type=int, default=None, metavar="K",
                   help=f"worker processes for local / a Dask LocalCluster (default: cores, here {default_workers()})")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler, e.g. tcp://10.0.0.5:8786 (default: a LocalCluster on 127.0.0.1)")
    p.add_argument("--out", default=None, metavar="DIR", help="directory for the output files (created)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the tables")
    p.add_argument("--no-plot", action="store_true", help="do not draw the figure")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def register(sub) -> None:
    p = sub.add_parser(
        "fit", help="fit scene constants (e.g. head.C1, head.C2, medium.mu) to measured steady states by "
                    "weighted least squares, with confidence intervals",
        description="Weighted least squares of the simulated relative equilibria against DATA.csv (one row per "
                    "experiment: inputs as scene keys or n, L, omega_T_rpm; outputs v (m/s) and/or omega_h "
                    "(rad/s), optional v_std / omega_h_std; a sweep's results.csv works). Writes DIR/fitted.toml "
                    "(the fitted scene), DIR/fit.png (data vs fit) and DIR/fit.json. Exit status 1 when a "
                    "parameter is not identifiable from the data or the search did not converge.")
    add_scene_arguments(p)
    p.add_argument("data", metavar="DATA.csv", help="measured steady states, one row per experiment")
    p.add_argument("--fit", required=True, metavar="KEYS",
                   help="comma-separated real-valued scene keys to fit, e.g. head.C1,head.C2,medium.mu; start "
                        "values from the scene (and --set)")
    p.add_argument("--bounds", action="append", default=[], metavar="KEY=LOW:HIGH",
                   help="search bounds of a fitted key (default: its declared range; positive keys are fitted "
                        "in log space within six decades of the start)")
    p.add_argument("--predict", default=None, metavar="OTHER.csv",
                   help="held-out rows (same format): evaluated with the fitted scene, per-row errors reported")
    p.add_argument("--absolute-sigma", action="store_true",
                   help="the *_std columns are the true measurement errors: intervals from (J^T W J)^-1 alone, "
                        "not scaled by chi^2 / dof")
    p.add_argument("--max-evaluations", type=int, default=60, metavar="N",
                   help="most least-squares function evaluations (default 60)")
    _engine_arguments(p)
    p.set_defaults(func=cmd_fit)

    q = sub.add_parser(
        "optimize", help="search a design space (integer n, continuous L, omega_rpm, any numeric key) for the "
                         "fastest or most efficient robot, optionally under a power budget",
        description="A coarse grid over every --vary variable, then a local refinement of the continuous ones "
                    "for each value of the integer ones; every design's steady state from the steady solver, "
                    "unstable equilibria excluded. Prints the optimum and the runner-up designs; writes "
                    "DIR/optimize.png and DIR/optimize.json.")
    add_scene_arguments(q)
    q.add_argument("--vary", action="append", default=[], required=True, metavar="KEY=LOW:HIGH,...",
                   help="design variables and their ranges, e.g. n=2:5,L=0.07:0.15,omega_rpm=20:250 (integer "
                        "keys take every value; shorthands n, L, omega_rpm / rpm)")
    q.add_argument("--maximize", choices=("v", "efficiency"), default="v",
                   help="v: forward speed; efficiency: m g v / P, i.e. the inverse cost of transport (default v)")
    q.add_argument("--max-power", type=float, default=None, metavar="W",
                   help="power budget: designs whose motor power (torque x omega_T) exceeds it are infeasible")
    q.add_argument("--grid-points", type=int, default=5, metavar="K",
                   help="coarse-grid values per continuous variable (default 5)")
    q.add_argument("--allow-unstable", action="store_true",
                   help="count linearly unstable equilibria as designs (default: excluded, marked in the table)")
    q.add_argument("--max-evaluations", type=int, default=80, metavar="N",
                   help="most evaluations of each local refinement (default 80)")
    q.add_argument("--top", type=int, default=5, metavar="K", help="runner-up grid designs listed (default 5)")
    _engine_arguments(q)
    q.set_defaults(func=cmd_optimize)


def _say(args, text: str) -> None:
    if not args.quiet:
        print(text, file=sys.stderr, flush=True)


def _g(x, spec=".4g", missing="--") -> str:
    if x is None or not isinstance(x, (int, float)) or not math.isfinite(x):
        return missing
    return format(x, spec)


# ---------------------------------------------------------------- fit
def _fit_curves(scene, data_sets, engine) -> dict:
    """The fitted model along the motor speed for every group of rows whose speed varies."""
    from ..fit.evaluate import _group_key, evaluate
    from ..fit.plots import _group_label
    groups: dict[str, dict] = {}
    for data in data_sets:
        for r in data.rows:
            rpm = r.overrides.get(RPM_KEY)
            if rpm is None:
                continue
            g = groups.setdefault(_group_key(r.overrides), {"label": _group_label(r.overrides),
                                                            "base": {k: v for k, v in r.overrides.items()
                                                                     if k != RPM_KEY}, "rpm": []})
            g["rpm"].append(float(rpm))
    rows, owners = [], []
    import numpy as np
    for g in groups.values():
        lo, hi = min(g["rpm"]), max(g["rpm"])
        if hi <= lo:
            continue
        for w in np.linspace(min(0.0, lo) if lo > 0 and lo < 0.2 * hi else lo, hi, 25):
            rows.append({"index": len(rows), "overrides": {**g["base"], RPM_KEY: float(w)}})
            owners.append(g["label"])
    if not rows:
        return {}
    sims = evaluate(engine, scene, [{}], rows)[0]
    out: dict[str, tuple] = {}
    for label in dict.fromkeys(owners):
        idx = [i for i, o in enumerate(owners) if o == label and not sims[i]["error"]]
        out[label] = ([rows[i]["overrides"][RPM_KEY] for i in idx],
                      {o: [sims[i][o] for i in idx] for o in ("v", "omega_h")})
    return out


def format_fit(res: dict, pred: dict | None) -> str:
    lines = [f"fit of {res['scene']} to {res['data']}: {res['rows_used']} rows"
             + (f" ({res['rows_left_out']} left out)" if res["rows_left_out"] else "")
             + f", outputs {', '.join(res['outputs'])}; {res['model_evaluations']} model evaluations, "
               f"{res['wall_seconds']:.1f} s"]
    hdr = f"  {'parameter':<22} {'start':>11} {'estimate':>12}  {'95% interval':<27} {'std error':>10}"
    lines += ["", hdr]
    for p in res["parameters"]:
        ci = p["ci95"]
        ci_text = f"[{_g(ci[0], '.5g')}, {_g(ci[1], '.5g', 'inf')}]" if ci else "NOT IDENTIFIABLE"
        flag = "" if p["identifiable"] else "  <- not identifiable"
        lines.append(f"  {p['key']:<22} {_g(p['start'], '.5g'):>11} {_g(p['estimate'], '.6g'):>12}  "
                     f"{ci_text:<27} {_g(p['std_error'], '.3g'):>10}{flag}")
    keys = [p["key"] for p in res["parameters"]]
    if len(keys) > 1:
        lines += ["", "  correlation:", "  " + " " * 22 + "".join(f"{_short_key(k):>12}" for k in keys)]
        for k, row in zip(keys, res["correlation"]):
            lines.append(f"  {k:<22}" + "".join(f"{_g(c, '+.3f'):>12}" for c in row))
    s = math.sqrt(res["s2"]) if res["s2"] is not None and math.isfinite(res["s2"]) else None
    lines += ["", f"  chi^2 = {_g(res['chi2'], '.4g')} over {res['dof']} degrees of freedom (s = {_g(s, '.3g')}"
                  f"{', stds taken as exact' if res['absolute_sigma'] else ''}); condition number of the weighted "
                  f"Jacobian {_g(res['condition_number'], '.3g')}; {res['status']}"]
    all_std = all(r[o]["std_given"] for r in res["rows"] for o in res["outputs"] if o in r)
    r_text = ("r = difference / std" if all_std else
              "r = difference / std, or / the output's RMS where no *_std column is given: a weight, not a z-score")
    lines += ["", _row_lines(f"residuals (simulated - measured; {r_text})", res["rows"], res["outputs"])]
    if pred is not None:
        from ..physics.error_estimate import percent
        lines += ["", _row_lines(f"prediction of {pred['data']} with the fitted scene", pred["rows"],
                                 [o for o in ("v", "omega_h") if o in pred["summary"]], r_needs_std=True)]
        for o, sm in pred["summary"].items():
            pct = {k: None if sm[k] is None else 100 * sm[k] for k in ("rms_relative_error", "max_relative_error")}
            lines.append(f"  {o}: RMS relative error {_g(pct['rms_relative_error'], '.2f')}%, largest "
                         f"{_g(pct['max_relative_error'], '.2f')}%"
                         + (f", RMS z {_g(sm['rms_z'], '.3g')}" if sm["rms_z"] is not None else "")
                         + (f"; the simulation's own numerical error at most +/- {percent(sm['max_error_estimate'])}"
                            if sm.get("max_error_estimate") is not None else ""))
    for w in res["warnings"]:
        lines.append(f"WARNING: {w}")
    return "\n".join(lines)


def _row_lines(title: str, rows: list[dict], outputs: list[str], r_needs_std: bool = False) -> str:
    """A table of rows; ``r_needs_std``: the normalised residual only where the row gave its std."""
    unit = {"v": ("mm/s", 1e3), "omega_h": ("rad/s", 1.0)}
    head = f"  {'line':>4}  {'inputs':<30}"
    for o in outputs:
        u = unit[o][0]
        head += f" {o + ' meas':>13} {'sim (' + u + ')':>14} {'rel':>8} {'r':>7}"
    out = [f"  {title}:", head]
    for r in rows:
        text = ", ".join(f"{_short_key(k)}={_g(v, 'g')}" for k, v in r["inputs"].items())
        line = f"  {r['line']:>4}  {text[:30]:<30}"
        for o in outputs:
            if o in r:
                e, sc = r[o], unit[o][1]
                rel = e["relative"]
                line += (f" {_g(e['measured'] * sc, '.5g'):>13} {_g(e['simulated'] * sc, '.5g'):>14} "
                         f"{_g(100 * rel, '+.2f') + '%' if rel is not None else '--':>8} "
                         f"{_g(e['residual'] if e['std_given'] or not r_needs_std else None, '+.2f'):>7}")
            else:
                line += f" {'':>13} {'':>14} {'':>8} {'':>7}"
        if r["error"]:
            line += f"  ERROR: {r['error']}"
        elif r.get("stable") is False:
            line += "  (unstable equilibrium)"
        out.append(line)
    return "\n".join(out)


def _interruptible(command):
    """Ctrl-C or SIGTERM (a batch scheduler's stop, as for sweeps): the pool's workers are stopped (Engine's
    exit), one line instead of a traceback, status 128 + the signal."""
    from .sweep import Terminated, _on_sigterm

    def run(args) -> int:
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
        try:
            return command(args)
        except KeyboardInterrupt as exc:
            what, sig = ("terminated", signal.SIGTERM) if isinstance(exc, Terminated) else \
                ("interrupted", signal.SIGINT)
            print(f"flagbot {args.command}: {what}; its output files are not written", file=sys.stderr)
            return 128 + sig
        finally:
            signal.signal(signal.SIGTERM, previous)
    return run


def cmd_fit(args) -> int:
    return _interruptible(_cmd_fit)(args)


def cmd_optimize(args) -> int:
    return _interruptible(_cmd_optimize)(args)


def _cmd_fit(args) -> int:
    from ..fit.data import read_data
    from ..fit.fit import parse_bounds, parse_parameters, predict, run_fit
    base = load_scene(args.scene, args.overrides)
    params = parse_parameters(args.fit, base, parse_bounds(args.bounds))
    data = read_data(args.data, base, exclude=tuple(p.key for p in params))
    held = read_data(args.predict, base, exclude=tuple(p.key for p in params)) if args.predict else None
    if args.max_evaluations < 1:
        from ..fit.fit import FitError
        raise FitError(f"--max-evaluations must be at least 1, got {args.max_evaluations}")
    out_dir = make_out_dir(args.out or f"fit-{base.scene.name}")
    with Engine(args.engine, args.workers, args.scheduler) as engine:
        _say(args, f"fit {', '.join(p.key for p in params)} of {base.scene.name} to {len(data.rows)} rows of "
                   f"{args.data} ({sum(len(w) for w in data.weights())} values) [{engine.where}]")

        def progress(prob, x, r):
            _say(args, f"  evaluation {prob.evaluations}: chi^2 = {float(r @ r):.6g}  " +
                 "  ".join(f"{_short_key(k)}={v:.6g}" for k, v in prob.values(x).items()))

        result = run_fit(base, params, data, engine, absolute_sigma=args.absolute_sigma,
                         max_evaluations=args.max_evaluations, progress=progress)
        res = result.to_dict()
        fitted = result.fitted_scene()
        pred = predict(fitted, held, engine) if held is not None else None
        files = {"scene": str(out_dir / "fitted.toml"), "json": str(out_dir / "fit.json")}
        header = ["# fitted by flagbot fit: " + ", ".join(
            f"{e.key} = {e.value:.6g}" + (f" (95% CI {e.ci95[0]:.4g} .. {e.ci95[1]:.4g})" if e.ci95 else
                                          " (NOT IDENTIFIABLE)") for e in result.estimates),
                  f"# data: {args.data} ({len(data.rows)} rows), chi^2 = {result.chi2:.4g}, dof = {result.dof}", ""]
        Path(files["scene"]).write_text("\n".join(header) + fitted.to_toml())
        if not args.no_plot:
            from ..fit.plots import figure_fit
            curves = _fit_curves(fitted, [data] + ([held] if held is not None else []), engine)
            title = "; ".join(f"{_short_key(e.key)} = {e.value:.4g}" + ("" if e.identifiable else " (n.i.)")
                              for e in result.estimates)
            fig = figure_fit(res, pred, curves, title=f"{base.scene.name}: {title}")
            files["plot"] = str(out_dir / "fit.png")
            fig.savefig(files["plot"], dpi=110)
    res["predict"] = pred
    res["files"] = files
    res["engine"] = {"engine": args.engine, "workers": engine.workers, "tasks": engine.tasks_run}
    Path(files["json"]).write_text(json_output(res, indent=1))
    if args.json:
        print(json_output(res))
    else:
        print(format_fit(res, pred))
        print("wrote " + ", ".join(files.values()))
    return 0 if result.identified and result.success else 1


# ---------------------------------------------------------------- optimize
def _design_text(design: dict) -> str:
    return ", ".join(f"{_short_key(k)}={_g(v, '.5g')}" for k, v in design.items())


def format_search(res: dict, top: int) -> str:
    obj = res["objective"]
    sc = obj["display_scale"]
    lines = [f"design search of {res['scene']}: maximise {obj['label']}"
             + (f" at P <= {res['max_power']:g} W" if res["max_power"] is not None else "")
             + f"; {res['evaluations']} steady states ({res['grid_evaluations']} on the grid), "
               f"{res['wall_seconds']:.1f} s"]
    bad = res["infeasible_grid_points"]
    if bad:
        lines.append("  grid points left out: " + ", ".join(f"{n} {r}" for r, n in bad.items()))
    best = res["optimum"]
    if best is None:
        lines.append("NO FEASIBLE DESIGN in the search space")
        return "\n".join(lines)
    lines += ["", f"  optimum: {_design_text(best['design'])}",
              f"    {obj['label']} = {_g(best['objective'] * sc, '.6g')}; v = {_g(best['v'] * 1e3, '.5g')} mm/s, "
              f"omega_h = {_g(best['omega_h'], '.4g')} rad/s, motor torque = {_g(best['motor_torque'], '.4g')} N m, "
              f"power = {_g(best['power'], '.4g')} W, cost of transport = {_g(best['cost_of_transport'], '.4g')}"]

    def table(title, items):
        out = ["", f"  {title}:", f"  {'#':>3}  {'design':<52} {'objective':>11} {'v (mm/s)':>10} {'P (W)':>10} "
                                   f"{'CoT':>9}  note"]
        for i, e in enumerate(items, 1):
            note = "" if e["feasible"] else e["reason"].upper()
            if e.get("method"):
                note = (note + " " if note else "") + f"refined ({e['method']}, {e['refinement_evaluations']} evals)"
            out.append(f"  {i:>3}  {_design_text(e['design'])[:52]:<52} {_g(e['objective'] * sc, '.5g'):>11} "
                       f"{_g(e['v'] * 1e3, '.4g'):>10} {_g(e['power'], '.4g'):>10} "
                       f"{_g(e['cost_of_transport'], '.4g'):>9}  {note}")
        return out

    lines += table("best design of each integer combination (ranked)", res["refined"])
    lines += table(f"runner-up grid designs (top {top})", res["top_grid"][:top])
    unstable = [g for g in res["grid"] if g["reason"] == "unstable"]
    if unstable:
        u = max(unstable, key=lambda g: g["objective"])
        lines.append(f"  (best UNSTABLE grid design, left out: {_design_text(u['design'])}, objective "
                     f"{_g(u['objective'] * sc, '.5g')}; --allow-unstable counts such designs)")
    for s in res["skipped"]:
        lines.append(f"  {_design_text(s['design'])}: {s['reason']}")
    return "\n".join(lines)


def _cmd_optimize(args) -> int:
    from ..fit.fit import FitError
    from ..fit.optimize import parse_vary, run_search
    base = load_scene(args.scene, args.overrides)
    variables = parse_vary(args.vary, base)
    if args.top < 1 or args.max_evaluations < 1:
        raise FitError("--top and --max-evaluations must be at least 1")
    out_dir = make_out_dir(args.out or f"optimize-{base.scene.name}")
    with Engine(args.engine, args.workers, args.scheduler) as engine:
        _say(args, f"optimize {base.scene.name}: {', '.join(v.key for v in variables)} [{engine.where}]")
        res = run_search(base, variables, args.maximize, engine, max_power=args.max_power,
                         grid_points=args.grid_points, allow_unstable=args.allow_unstable,
                         max_evaluations=args.max_evaluations, progress=lambda t: _say(args, "  " + t))
    files = {"json": str(out_dir / "optimize.json")}
    if not args.no_plot:
        from ..fit.plots import figure_design
        files["plot"] = str(out_dir / "optimize.png")
        figure_design(res).savefig(files["plot"], dpi=110)
    res["files"] = files
    res["engine"] = {"engine": args.engine, "workers": engine.workers, "tasks": engine.tasks_run}
    res["rpm_per_rad_s"] = 1.0 / RPM
    Path(files["json"]).write_text(json_output(res, indent=1))
    if args.json:
        print(json_output(res))
    else:
        print(format_search(res, args.top))
        print("wrote " + ", ".join(files.values()))
    return 0 if res["optimum"] is not None else 1
