"""Steady states of many scene variants, as engine tasks: the model evaluations of fits and design searches.

A task is plain picklable data: the base scene's file data, the overrides every row shares (the parameters being
fitted or the fixed ``--set`` values) and a list of rows, each with its own overrides. ``run_rows(task)`` solves
every row's relative equilibrium with the steady solver (:mod:`flagbot_sim.physics.steady`) in the listed order;
a row that differs from the one before only in ``motor.omega_rpm`` is continued from that row's solution (a few
Newton iterations instead of a solve from the straight robot). :func:`make_tasks` orders rows for that (grouped
by everything but the motor speed, ascending speed within a group) and cuts groups into chunks of a fixed size,
so that the tasks, hence the numbers, depend only on the rows, never on the engine or the number of workers.
"""
from __future__ import annotations

import math
import time

from ..scene import Scene, SceneError, scene_from_dict

RPM_KEY = "motor.omega_rpm"
#: rows per task at most: long rpm series are split so that a single fit evaluation can use several workers
CHUNK = 8

NAN = math.nan
#: what every row result holds (the sweep rows' names)
OUTPUTS = ("v", "omega_h", "omega_t", "motor_torque", "power", "cost_of_transport")


def _group_key(overrides: dict) -> str:
    return repr(sorted((k, repr(v)) for k, v in overrides.items() if k != RPM_KEY))


def make_tasks(base: Scene, shared: dict, rows: list[dict], stability: bool = False, chunk: int = CHUNK,
               error_estimates: bool = False) -> list[dict]:
    """Tasks for ``rows`` ({"index": ..., "overrides": {...}} each) of ``base`` with ``shared`` overrides on top.

    Rows are grouped by their overrides other than the motor speed (in order of first appearance), sorted by
    speed within a group, and each group cut into chunks of at most ``chunk`` rows: one task per chunk."""
    groups: dict[str, list[dict]] = {}
    for row in rows:
        groups.setdefault(_group_key(row["overrides"]), []).append(row)
    default_rpm = base.with_overrides(shared).motor.omega_rpm if shared else base.motor.omega_rpm
    tasks = []
    for members in groups.values():
        members = sorted(members, key=lambda r: (float(r["overrides"].get(RPM_KEY, default_rpm)), r["index"]))
        for i in range(0, len(members), chunk):
            tasks.append({"scene_data": base.file_data, "source": base.source,
                          "overrides": {**base.overrides, **shared},
                          "rows": [{"index": r["index"], "overrides": dict(r["overrides"])}
                                   for r in members[i:i + chunk]],
                          "stability": bool(stability), "error_estimates": bool(error_estimates)})
    return tasks


def equilibrium_outputs(model, solver, sol, stability: bool) -> dict:
    """OUTPUTS of a solved equilibrium (NaN for a missing one), with its stability when asked: ``stable`` and
    ``growth_rate`` (None / NaN without), and ``error`` saying so where ARPACK could not determine it."""
    from ..physics.steady import summary
    s = summary(model, sol)
    res = {**{k: (NAN if s[k] is None else float(s[k])) for k in OUTPUTS}, "stable": None, "growth_rate": NAN,
           "error": ""}
    if stability:
        try:
            st = solver.stability(sol)
            res["stable"], res["growth_rate"] = bool(st.stable), float(st.rate)
        except Exception as exc:   # noqa: BLE001 -- ARPACK not converging: unknown, not a failed evaluation
            res["error"] = f"stability not determined: {type(exc).__name__}: {exc}"
    return res


def _failed(index: int, error: str) -> dict:
    return {"index": index, **{k: NAN for k in OUTPUTS}, "stable": None, "growth_rate": NAN, "residual": NAN,
            "iterations": 0, "error": error}


def run_rows(task: dict) -> dict:
    """Solve every row of the task: {"rows": [result, ...], "wall_seconds": ...} (results in the task's order).

    A row whose equilibrium is not found (also not from the straight robot, when it was continued) gets its
    ``error`` text and NaN values; the other rows go on."""
    from ..physics import error_estimate, warmup
    from ..physics.model import RobotModel
    from ..physics.steady import SteadyFailed, SteadySolver, summary
    warmup.ensure_compiled()
    w0 = time.perf_counter()
    out = []
    prev, prev_key, space = None, None, None
    for row in task["rows"]:
        key = _group_key(row["overrides"])
        if key != prev_key:
            prev, space = None, None
        prev_key = key
        try:
            scene = scene_from_dict(task["scene_data"], source=task["source"],
                                    overrides={**task["overrides"], **row["overrides"]})
            scene, _ = error_estimate.resolve_accuracy(scene)    # accuracy.rtol: the edge length it chooses
            model = RobotModel(scene)
            solver = SteadySolver(model)
            try:
                sol = solver.solve(scene.omega_T, start=prev)
            except SteadyFailed:
                if prev is None:
                    raise
                sol = solver.solve(scene.omega_T)        # continuation failed: from the straight robot
        except (SteadyFailed, SceneError) as exc:
            out.append(_failed(row["index"], f"{type(exc).__name__}: {exc}"))
            prev = None
            continue
        res = equilibrium_outputs(model, solver, sol, bool(task.get("stability")))
        if task.get("error_estimates"):
            # the space part (a steady solve has no time part), Richardson's coarse solve continued in the group
            space = space or error_estimate.SpaceEstimator(scene)
            res["error_estimate"] = error_estimate.for_steady(model, sol, summary(model, sol), space)["error_estimate"]
        error = res.pop("error")
        out.append({"index": row["index"], **res, "residual": float(sol.residual),
                    "iterations": int(sol.iterations), "error": error})
        prev = sol
    return {"rows": out, "wall_seconds": time.perf_counter() - w0}


def evaluate(engine, base: Scene, shared_list: list[dict], rows: list[dict], stability: bool = False,
             error_estimates: bool = False) -> list[list[dict]]:
    """The rows' results for each overrides dict of ``shared_list`` (one batch on the engine): a list, per
    shared dict, of row results ordered like ``rows``; ``error_estimates``: each with its ``error_estimate``
    (physics/error_estimate.py: the relative numerical error of each output, the space part)."""
    tasks, owner = [], []
    for j, shared in enumerate(shared_list):
        ts = make_tasks(base, shared, rows, stability, error_estimates=error_estimates)
        tasks += ts
        owner += [j] * len(ts)
    results = engine.map(run_rows, tasks)
    position = {r["index"]: i for i, r in enumerate(rows)}
    out = [[None] * len(rows) for _ in shared_list]
    for j, res in zip(owner, results):
        for r in res["rows"]:
            out[j][position[r["index"]]] = r
    return out
