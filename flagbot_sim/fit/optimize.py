"""Design search: the robot (integer n, continuous L, omega_T, any numeric scene key) that swims best.

Objectives (each design's relative equilibrium from the steady solver):

* ``v``: the forward speed v (m/s);
* ``efficiency``: the transport efficiency m g v / P = 1 / (cost of transport), P = motor torque x omega_T the
  mechanical power and m the robot's mass: maximising it minimises the energy spent per unit weight and distance
  (designs that do not move forward have none);
* either one under a power budget ``max_power`` (W): designs needing more power are infeasible.

A design is feasible when its equilibrium is found, it is linearly stable (``SteadySolver.stability``: an unstable
equilibrium is not what the robot does; ``allow_unstable`` keeps them) and it meets the budget. The search is a
coarse grid over every variable (integer ones: every value; continuous ones: ``grid_points`` values, log-spaced
when the range spans a factor of 20 or more), then, for every combination of the integer variables, a local
refinement of the continuous ones from its best grid point, within one grid cell of it: a bounded Brent search
for one variable, Nelder-Mead for several, COBYQA (derivative-free, with the power budget as a constraint) under
a budget. Every evaluated design is kept; the answer is the best feasible one of them all (so an optimum on the
edge of the range, which a bounded search approaches only to its tolerance, is the grid point itself). The grid
runs as engine tasks (continued along the motor speed), the refinements one task per integer combination.
"""
from __future__ import annotations

import dataclasses
import itertools
import math
import time
from dataclasses import dataclass

import numpy as np

from ..scene import SECTIONS, Scene, SceneError, _split_key, inert_keys, scene_from_dict
from .evaluate import OUTPUTS, equilibrium_outputs, evaluate
from .fit import FitError

ALIASES = {"n": "robot.n_flagella", "L": "flagellum.length", "rpm": "motor.omega_rpm",
           "omega_rpm": "motor.omega_rpm"}
OBJECTIVES = {"v": {"label": "v (mm/s)", "display_scale": 1e3},
              "efficiency": {"label": "efficiency m g v / P (= 1 / cost of transport)", "display_scale": 1.0}}
#: integer variables may take at most this many values
MAX_INTEGER_VALUES = 50
#: grid designs at most
MAX_GRID = 20_000
#: value of an infeasible design for the local optimisers (feasible values are about -1: normalised by the best
#: grid point's objective)
PENALTY = 10.0


@dataclass
class Variable:
    key: str
    lo: float
    hi: float
    integer: bool
    log: bool
    unit: str

    def grid(self, k: int) -> list:
        if self.integer:
            return list(range(int(self.lo), int(self.hi) + 1))
        if k < 2:
            return [0.5 * (self.lo + self.hi)]
        return [self.from_u(u) for u in np.linspace(0.0, 1.0, k)]

    def to_u(self, x: float) -> float:
        if self.log:
            return math.log(x / self.lo) / math.log(self.hi / self.lo)
        return (x - self.lo) / (self.hi - self.lo)

    def from_u(self, u: float) -> float:
        u = min(1.0, max(0.0, float(u)))
        if self.log:
            return float(self.lo * (self.hi / self.lo) ** u)
        return float(self.lo + u * (self.hi - self.lo))

    def to_dict(self) -> dict:
        return {"key": self.key, "low": self.lo, "high": self.hi, "integer": self.integer, "log": self.log,
                "display_unit": self.unit, "display_scale": 1.0}


def parse_vary(specs: list[str], base: Scene) -> list[Variable]:
    """``["n=2:5,L=0.07:0.15", "omega_rpm=20:250"]`` -> Variables, checked against the scene's ranges."""
    items = [it.strip() for spec in specs for it in spec.split(",") if it.strip()]
    if not items:
        raise FitError("--vary needs at least one KEY=LOW:HIGH, e.g. --vary n=2:5,L=0.07:0.15,omega_rpm=20:250")
    out, seen = [], set()
    for item in items:
        if "=" not in item or ":" not in item.split("=", 1)[1]:
            raise FitError(f"--vary {item!r} must look like KEY=LOW:HIGH, e.g. L=0.07:0.15")
        raw, rng = item.split("=", 1)
        key = ALIASES.get(raw.strip(), raw.strip())
        try:
            section, name = _split_key(key)
        except SceneError as exc:
            raise FitError(f"--vary {raw.strip()}: {exc}") from None
        if key in seen:
            raise FitError(f"--vary {key} is given twice")
        seen.add(key)
        if key in inert_keys(base):
            raise FitError(f"--vary {inert_keys(base)[key]}")
        f = next(f for f in dataclasses.fields(SECTIONS[section]) if f.name == name)
        if isinstance(f.default, bool) or not isinstance(f.default, (int, float)):
            raise FitError(f"--vary {key}: not a number; only numeric scene keys can be design variables")
        integer = isinstance(f.default, int)
        try:
            lo, hi = (float(x) for x in rng.split(":"))
        except ValueError:
            raise FitError(f"--vary {item!r}: LOW and HIGH must be two numbers") from None
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise FitError(f"--vary {item!r}: LOW and HIGH must be finite")
        if integer and not (lo.is_integer() and hi.is_integer()):
            raise FitError(f"--vary {key}: an integer key needs integer bounds, got {rng}")
        if hi < lo or (hi == lo and not integer):
            raise FitError(f"--vary {item!r}: needs LOW < HIGH (a fixed value is a --set)")
        if integer and hi - lo + 1 > MAX_INTEGER_VALUES:
            raise FitError(f"--vary {key}: {int(hi - lo + 1)} integer values (limit {MAX_INTEGER_VALUES})")
        for v in (lo, hi):
            try:
                base.with_overrides({key: int(v) if integer else v})
            except SceneError as exc:
                raise FitError(f"--vary {key}: {exc}") from None
        log = not integer and lo > 0 and hi / lo >= 20.0
        out.append(Variable(key, lo, hi, integer, log, f.metadata["unit"]))
    if base.clamped:
        raise FitError(f"scene {base.scene.name!r} is a clamped flagellum; a design search needs a free robot")
    return out


def score(res: dict, objective: str, max_power: float | None, allow_unstable: bool) -> tuple[float, bool, str]:
    """(objective value, feasible, why not) of one evaluated design."""
    if res["error"] and not res["error"].startswith("stability not determined"):
        return math.nan, False, "no equilibrium"
    v, P = res["v"], res["power"]
    if objective == "v":
        value = v
    else:
        cot = res["cost_of_transport"]
        value = 1.0 / cot if (math.isfinite(cot) and cot > 0 and v > 0) else math.nan
    if not math.isfinite(value):
        return math.nan, False, "does not move forward" if objective == "efficiency" else "not finite"
    if res["stable"] is False and not allow_unstable:
        return value, False, "unstable"
    if res["stable"] is None and not allow_unstable:
        return value, False, "stability unknown"
    if max_power is not None and not (P <= max_power):
        return value, False, "over the power budget"
    return value, True, ""


def _record(design: dict, res: dict, objective, max_power, allow_unstable) -> dict:
    value, ok, why = score(res, objective, max_power, allow_unstable)
    return {"design": design, "objective": value, "feasible": ok, "reason": why,
            **{k: res[k] for k in (*OUTPUTS, "stable", "growth_rate")}, "error": res["error"]}


#: restarts of COBYQA from its own answer (each with a tenth of the trust radius), while they still gain
COBYQA_RESTARTS = 2


def refine(task: dict) -> dict:
    """Local search of the continuous variables for one combination of the integer ones (an engine task):
    {"evaluations": [record, ...], "method": ..., "message": ...}."""
    from scipy.optimize import Bounds, NonlinearConstraint, minimize, minimize_scalar

    from ..physics import warmup
    from ..physics.model import RobotModel
    from ..physics.steady import SteadyFailed, SteadySolver
    warmup.ensure_compiled()
    variables = [Variable(**v) for v in task["variables"]]
    objective, max_power, allow = task["objective"], task["max_power"], task["allow_unstable"]
    scale = abs(task["best_value"]) or 1.0
    method = task["method"]
    records, cache = [], {}

    def evaluate_u(u) -> dict:
        u = np.clip(np.asarray(u, float), 0.0, 1.0)
        key = u.tobytes()
        if key in cache:
            return cache[key]
        design = {**task["fixed"], **{v.key: v.from_u(ui) for v, ui in zip(variables, u)}}
        try:
            scene = scene_from_dict(task["scene_data"], source=task["source"],
                                    overrides={**task["overrides"], **design})
            model = RobotModel(scene)
            solver = SteadySolver(model)
            res = equilibrium_outputs(model, solver, solver.solve(scene.omega_T), stability=True)
        except (SteadyFailed, SceneError) as exc:
            res = {**{k: math.nan for k in OUTPUTS}, "stable": None, "growth_rate": math.nan,
                   "error": f"{type(exc).__name__}: {exc}"}
        rec = _record(design, res, objective, max_power, allow)
        records.append(rec)
        cache[key] = rec
        return rec

    def f(u) -> float:
        rec = evaluate_u(u)
        if rec["feasible"] or (method == "cobyqa" and rec["reason"] == "over the power budget"):
            return -rec["objective"] / scale           # over the budget: COBYQA's constraint says so
        return PENALTY

    box = np.array(task["box"], float)
    u0 = np.array(task["u0"], float)
    if method == "bounded":
        res = minimize_scalar(lambda t: f([t]), bounds=tuple(box[0]), method="bounded",
                              options={"xatol": task["xatol"], "maxiter": task["max_evaluations"]})
        message = str(res.message)
    elif method == "nelder-mead":
        d = len(u0)
        simplex = [u0.copy()]
        for j in range(d):
            e = u0.copy()
            half = 0.5 * (box[j, 1] - box[j, 0])
            e[j] = u0[j] + half if u0[j] + half <= box[j, 1] else u0[j] - half
            simplex.append(e)
        res = minimize(f, u0, method="Nelder-Mead", bounds=Bounds(box[:, 0], box[:, 1]),
                       options={"initial_simplex": np.array(simplex), "xatol": task["xatol"], "fatol": 1e-6,
                                "maxfev": task["max_evaluations"]})
        message = str(res.message)
    else:
        def power_margin(u) -> float:
            rec = evaluate_u(u)
            P = rec["power"]
            return (P - max_power) / max_power if math.isfinite(P) else 1e3

        # COBYQA's linear models of v and P can shrink its trust region before the budget binds (design 1, n = 2:
        # stopped at 97% of it); a restart from its answer with a smaller radius builds fresh models there, and
        # is repeated while it still gains
        radius = 0.25 * float(np.min(box[:, 1] - box[:, 0]))
        start, best_f = u0, math.inf
        for attempt in range(1 + COBYQA_RESTARTS):
            left = task["max_evaluations"] - len(records)
            if attempt and left < 2 * len(u0) + 2:     # a restart needs room for its initial models
                break
            res = minimize(f, start, method="COBYQA", bounds=Bounds(box[:, 0], box[:, 1]),
                           constraints=[NonlinearConstraint(power_margin, -np.inf, 0.0)],
                           options={"initial_tr_radius": radius, "final_tr_radius": task["xatol"],
                                    "maxfev": left})
            message = str(res.message)
            gain = best_f - float(res.fun)
            if not (res.maxcv <= 0.0 and math.isfinite(res.fun)) or (math.isfinite(best_f) and gain <= 1e-6):
                break
            start, best_f = np.clip(res.x, box[:, 0], box[:, 1]), float(res.fun)
            radius = max(0.1 * radius, 10.0 * task["xatol"])
    return {"evaluations": records, "method": method, "message": message, "fixed": task["fixed"]}


def run_search(base: Scene, variables: list[Variable], objective: str, engine, max_power: float | None = None,
               grid_points: int = 5, allow_unstable: bool = False, max_evaluations: int = 80,
               xatol: float = 1e-4, progress=None) -> dict:
    if objective not in OBJECTIVES:
        raise FitError(f"--maximize {objective!r}: choose one of {', '.join(OBJECTIVES)}")
    if max_power is not None and not (math.isfinite(max_power) and max_power > 0):
        raise FitError(f"--max-power must be a positive number of watts, got {max_power!r}")
    if grid_points < 2:
        raise FitError(f"--grid-points must be at least 2, got {grid_points}")
    t0 = time.perf_counter()
    cont = [v for v in variables if not v.integer]
    ints = [v for v in variables if v.integer]
    axes = [v.grid(grid_points) for v in variables]
    combos = list(itertools.product(*axes))
    if len(combos) > MAX_GRID:
        raise FitError(f"the coarse grid has {len(combos)} designs (limit {MAX_GRID}); use fewer --grid-points")
    designs = [{v.key: (int(x) if v.integer else float(x)) for v, x in zip(variables, c)} for c in combos]
    for d in designs:
        try:
            base.with_overrides(d)
        except SceneError as exc:
            raise FitError(f"design {d}: {exc}") from None
    rows = [{"index": i, "overrides": d} for i, d in enumerate(designs)]
    if progress:
        progress(f"coarse grid: {len(designs)} designs")
    sims = evaluate(engine, base, [{}], rows, stability=True)[0]
    grid = [_record(d, s, objective, max_power, allow_unstable) for d, s in zip(designs, sims)]
    # refinement: per combination of the integer variables, from its best feasible grid point
    tasks = []
    skipped = []
    for ic in itertools.product(*(v.grid(grid_points) for v in ints)):
        fixed = {v.key: int(x) for v, x in zip(ints, ic)}
        members = [g for g in grid if all(g["design"][k] == x for k, x in fixed.items())]
        feasible = [g for g in members if g["feasible"]]
        if not feasible:
            skipped.append({"design": fixed, "reason": "no feasible grid point"})
            continue
        best = max(feasible, key=lambda g: g["objective"])
        if not cont:
            continue
        u0 = [v.to_u(best["design"][v.key]) for v in cont]
        du = 1.0 / (grid_points - 1)
        box = [[max(0.0, u - du), min(1.0, u + du)] for u in u0]
        method = "cobyqa" if max_power is not None else ("bounded" if len(cont) == 1 else "nelder-mead")
        tasks.append({"scene_data": base.file_data, "source": base.source, "overrides": dict(base.overrides),
                      "fixed": fixed, "variables": [dataclasses.asdict(v) for v in cont], "u0": u0, "box": box,
                      "best_value": best["objective"], "objective": objective, "max_power": max_power,
                      "allow_unstable": allow_unstable, "method": method, "xatol": xatol,
                      "max_evaluations": max_evaluations})
    if progress and tasks:
        progress(f"refining {len(tasks)} combination(s) of the integer variables")
    refined_raw = engine.map(refine, tasks)
    evaluated = list(grid)
    refined = []
    for out in refined_raw:
        evaluated += out["evaluations"]
        ok = [e for e in out["evaluations"] if e["feasible"]]
        members = [g for g in grid if all(g["design"][k] == x for k, x in out["fixed"].items()) and g["feasible"]]
        cand = ok + members
        best = max(cand, key=lambda e: e["objective"])
        refined.append({**best, "method": out["method"], "message": out["message"],
                        "refinement_evaluations": len(out["evaluations"])})
    if not cont:                          # integer variables only: the grid is the whole space
        for ic in itertools.product(*(v.grid(grid_points) for v in ints)):
            fixed = {v.key: int(x) for v, x in zip(ints, ic)}
            ok = [g for g in grid if g["feasible"] and all(g["design"][k] == x for k, x in fixed.items())]
            if ok:
                refined.append({**max(ok, key=lambda e: e["objective"]), "method": "grid", "message": "",
                                "refinement_evaluations": 0})
    refined.sort(key=lambda e: -e["objective"])
    feasible_all = [e for e in evaluated if e["feasible"]]
    optimum = max(feasible_all, key=lambda e: e["objective"]) if feasible_all else None
    top_grid = sorted((g for g in grid if g["feasible"]), key=lambda g: -g["objective"])
    obj = dict(OBJECTIVES[objective], name=objective)
    var_dicts = [v.to_dict() for v in variables]
    for vd in var_dicts:
        if vd["key"] == "motor.omega_rpm":
            vd["display_unit"] = "rpm"
    return {"scene": base.scene.name, "objective": obj, "max_power": max_power,
            "allow_unstable": allow_unstable, "variables": var_dicts, "grid_points": grid_points,
            "optimum": optimum, "refined": refined, "top_grid": top_grid[:10], "grid": grid, "skipped": skipped,
            "evaluations": len(evaluated), "grid_evaluations": len(grid),
            "infeasible_grid_points": {r: sum(1 for g in grid if g["reason"] == r)
                                       for r in sorted({g["reason"] for g in grid if not g["feasible"]})},
            "wall_seconds": time.perf_counter() - t0}
