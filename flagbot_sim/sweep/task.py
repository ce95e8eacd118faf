"""One grid point, computed by every framework: the unit of work the engines distribute.

``run_point(task)`` takes and returns plain picklable data (dicts of str/float/int), builds its scene from the
base scene's file data plus the point's overrides (so a remote Dask worker needs no scene file), and depends
on nothing but the task: the same task gives bit-identical numbers in any process, in any order.

DER steady state is *detected* by the one rule of :class:`flagbot_sim.physics.observe.SteadyDetector` (the
same as ``flagbot run`` and the ROS node use): every half window the mean omega_h and v over the last window are
compared with those one window earlier, and the run is steady when both changed by less than ``rtol``
(relative), and their geometric extrapolation puts them within ``rtol`` of their final values, at three
consecutive checks. A run that reaches ``t_max`` first reports its last-window rates with ``hit_cap = True``.
"""
from __future__ import annotations

import math
import os
import socket
import time
import traceback
from dataclasses import asdict, dataclass

from ..physics.medium import head_torque_coefficient, normalise_omega, normalise_speed
from ..scene import Scene, scene_from_dict

#: "der" then beam.balance.REGIMES in its order (tests/test_sweep.py checks it). Written out rather than imported:
#: importing anything from flagbot_sim.beam loads the beam solver (scipy), and plotting a sweep must not
FRAMEWORKS = ("der", "lb", "nlb-nohead", "nlb")
#: human names, as in the paper
FRAMEWORK_LABELS = {"der": "DER", "lb": "LB", "nlb-nohead": "NLB w/o head", "nlb": "NLB"}

#: consecutive passing checks (half a window apart) before a DER run counts as steady (SteadyDetector's default)
CONFIRM_CHECKS = 3


#: how the DER steady state of a point is found: solved directly (the relative equilibrium), or time-stepped
METHODS = ("steady", "time")


@dataclass(frozen=True)
class SteadySettings:
    t_max: float          # s of simulated time: the cap (time-stepping)
    window: float         # s: rates are averaged over this (time-stepping)
    rtol: float           # relative change between consecutive windows counted as steady (time-stepping)
    method: str = "steady"   # "steady": the relative equilibrium, time-stepping where none is found; "time"

    def check(self) -> None:
        from .grid import SweepError
        if self.method not in METHODS:
            raise SweepError(f"--method {self.method!r}: choose one of {', '.join(METHODS)}")
        for name in ("t_max", "window", "rtol"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise SweepError(f"--{name.replace('_', '-')} must be a positive number, got {v!r}")
        earliest = 2 * self.window + (CONFIRM_CHECKS - 1) * 0.5 * self.window
        if self.t_max < earliest:
            raise SweepError(f"--t-max = {self.t_max:g} s is too short to ever detect a steady state: two windows "
                             f"plus {CONFIRM_CHECKS - 1} checks half a window apart need {earliest:g} s "
                             f"(--window = {self.window:g} s)")

    def to_dict(self) -> dict:
        return asdict(self)


def make_task(base: Scene, point_key: str, overrides: dict, settings: SteadySettings,
              frameworks: tuple[str, ...]) -> dict:
    return {"point": point_key, "scene_data": base.file_data, "source": base.source,
            "overrides": {**base.overrides, **overrides}, "settings": settings.to_dict(),
            "frameworks": list(frameworks)}


def task_scene(task: dict) -> Scene:
    return scene_from_dict(task["scene_data"], source=task["source"], overrides=task["overrides"])


def run_der(scene: Scene, settings: SteadySettings) -> dict:
    """The DER steady state of one point: solved directly, or (method "time", or where no equilibrium is found)
    time-stepped to the steady-state rule."""
    if settings.method == "steady":
        from ..physics.steady import SteadyFailed
        try:
            return run_der_steady(scene)
        except SteadyFailed:
            out = run_der_time(scene, settings)
            out["method"] = "time (no equilibrium)"      # the solver's reason is not a failure of the point
            return out
    return run_der_time(scene, settings)


def run_der_steady(scene: Scene) -> dict:
    from ..physics import error_estimate, warmup
    from ..physics.model import RobotModel
    from ..physics.steady import SteadySolver, summary

    # the kernels a steady solve calls (a fork server's workers have them already); a point that falls back to
    # time stepping loads the others in its Simulation
    warmup.ensure_compiled(groups=warmup.groups_for(scene, time_stepping=False))
    w0 = time.perf_counter()
    scene, _ = error_estimate.resolve_accuracy(scene)      # accuracy.rtol: the edge length it chooses
    model = RobotModel(scene)
    solver = SteadySolver(model)
    # the space estimate's coarse solve first, the fine one started from it (a few Newton iterations)
    space = error_estimate.SpaceEstimator(scene)
    sol = space.solve_fine(solver, scene.omega_T)
    s = summary(model, sol)
    s.update(error_estimate.for_steady(model, sol, s, space))
    stable = solver.stability(sol, vectors=False).stable     # the sweep records the verdict alone
    omega_T = scene.omega_T
    return {"framework": "der", "error": "", "hit_cap": False, "converged": True, "method": "steady",
            "stable": stable, "residual": sol.residual, "omega_h": s["omega_h"], "omega_t": s["omega_t"],
            "v": s["v"], "omega_T_bar": normalise_omega(scene, omega_T),
            "omega_h_bar": normalise_omega(scene, s["omega_h"]), "v_bar": normalise_speed(scene, s["v"]),
            "w_tip_over_L": math.nan, "motor_torque": s["motor_torque"], "power": s["power"],
            "cost_of_transport": _nan(s["cost_of_transport"]), "steps": sol.iterations, "sim_time": math.nan,
            "change_omega_h": math.nan, "change_v": math.nan, **error_columns(s),
            "wall_seconds": time.perf_counter() - w0}


def _nan(x):
    return math.nan if x is None else x


def error_columns(result: dict) -> dict:
    """A result's error fields (physics/error_estimate.py) as the sweep's flat ERROR_COLUMNS."""
    total = result.get("error_estimate") or {}
    out = {f"error_estimate_{k}": _nan(total.get(k)) for k in ("omega_h", "omega_t", "v")}
    for part in ("time", "space"):
        est = result.get(f"error_estimate_{part}")
        out[f"error_estimate_{part}"] = max(est.values()) if est else math.nan
    return out


def run_der_time(scene: Scene, settings: SteadySettings) -> dict:
    from ..physics import Simulation, StepFailed

    w0 = time.perf_counter()
    out = {"framework": "der", "error": "", "hit_cap": False, "converged": False, "method": "time", "stable": "",
           "residual": math.nan}
    sim = Simulation(scene, steady_window=settings.window, steady_rtol=settings.rtol)
    dt = scene.time.dt
    try:
        out["converged"] = sim.run_until_steady(settings.t_max)
        out["hit_cap"] = not out["converged"]
    except StepFailed as exc:
        out["error"] = f"step failed at t = {sim.time:.4f} s: {exc}"
    rates = sim.observer.window_rates(settings.window) or sim.observer.window_rates(max(sim.time, dt))
    changes = sim.steady_detector.changes          # omega_h, v: relative changes over the last window
    omega_T = scene.omega_T
    if rates is None:
        omega_h = omega_t = v = math.nan
    else:
        omega_h, omega_t, v = rates["omega_h"], rates["omega_t"], rates["v"]
    eff = sim.summary()
    if not out["error"] and sim.steps:
        from ..physics import error_estimate
        out.update(error_columns(error_estimate.for_run(sim, eff)))
    out.update(omega_h=omega_h, omega_t=omega_t, v=v, omega_T_bar=normalise_omega(scene, omega_T),
               omega_h_bar=normalise_omega(scene, omega_h), v_bar=normalise_speed(scene, v),
               w_tip_over_L=math.nan, motor_torque=eff["motor_torque"], power=eff["power"],
               cost_of_transport=_nan(eff["cost_of_transport"]), steps=sim.steps, sim_time=sim.time,
               change_omega_h=float(changes[0]) if len(changes) else math.nan,
               change_v=float(changes[1]) if len(changes) else math.nan,
               wall_seconds=time.perf_counter() - w0)
    return out


def run_beam(scene: Scene, regime: str, mass: float) -> dict:
    """One beam regime's balance at the scene's motor speed as a row; ``mass``: the robot's (robot_mass), which
    the regimes of one point share."""
    from ..beam import BeamParams, solve_balance

    w0 = time.perf_counter()
    # no warm start from a neighbouring point: each point must not depend on which others ran before it
    res = solve_balance(BeamParams.from_scene(scene), scene.omega_T, regime=regime, raise_on_failure=False)
    # the motor's torque is the head's Stokes torque at the balance
    eff = _beam_efficiency(scene, res.omega_h, res.v_h, mass)
    return {"framework": regime, "omega_h": res.omega_h, "omega_t": res.omega_t, "v": res.v_h,
            "method": "beam", "stable": "", "residual": math.nan, **eff,
            "omega_T_bar": res.omega_T_bar, "omega_h_bar": res.omega_h_bar, "v_bar": res.v_bar,
            "w_tip_over_L": res.w_tip_over_L, "steps": res.bvp_solves, "sim_time": math.nan,
            "change_omega_h": math.nan, "change_v": math.nan, "converged": bool(res.converged),
            "hit_cap": False, "error": "" if res.converged else res.message,
            "wall_seconds": time.perf_counter() - w0}


def robot_mass(scene: Scene) -> float:
    """The robot's mass (kg): its rod network's node masses."""
    from ..physics.network import build_network
    return float(build_network(scene).node_mass.sum())


def _beam_efficiency(scene: Scene, omega_h: float, v: float, mass: float) -> dict:
    from ..physics.observe import efficiency
    torque = head_torque_coefficient(scene) * omega_h
    if not math.isfinite(torque):
        return {"motor_torque": math.nan, "power": math.nan, "cost_of_transport": math.nan}
    eff = efficiency(torque, scene.omega_T, v, mass)
    eff["cost_of_transport"] = _nan(eff["cost_of_transport"])
    return eff


def run_point(task: dict) -> dict:
    """Compute one grid point in every requested framework: {"point": key, "rows": [...]}.

    A failure inside one framework becomes that row's ``error`` text; it never aborts the sweep.
    """
    scene = task_scene(task)
    settings = SteadySettings(**task["settings"])
    common = {"point": task["point"], "n": scene.robot.n_flagella, "L": scene.flagellum.length,
              "omega_T": scene.omega_T, "omega_T_rpm": scene.motor.omega_rpm}
    rows = []
    mass = None                 # the robot's, built once for the beam rows (~1 ms a regime)
    for fw in task["frameworks"]:
        try:
            if fw == "der":
                row = run_der(scene, settings)
            else:
                mass = robot_mass(scene) if mass is None else mass
                row = run_beam(scene, fw, mass)
        except Exception as exc:   # noqa: BLE001 -- recorded in the CSV, the rest of the sweep goes on
            nan = math.nan
            row = {"framework": fw, "omega_h": nan, "omega_t": nan, "v": nan, "motor_torque": nan, "power": nan,
                   "cost_of_transport": nan, "method": "", "stable": "", "residual": nan,
                   "omega_T_bar": normalise_omega(scene, scene.omega_T), "omega_h_bar": nan, "v_bar": nan,
                   "w_tip_over_L": nan, "steps": 0, "sim_time": nan, "change_omega_h": nan, "change_v": nan,
                   "converged": False, "hit_cap": False, "wall_seconds": nan,
                   "error": f"{type(exc).__name__}: {exc} "
                            f"[{traceback.extract_tb(exc.__traceback__)[-1].name}]".replace("\n", " ")}
        row.update(common)
        row["worker"] = f"{socket.gethostname()}:{os.getpid()}"
        row["finished_at"] = time.time()
        rows.append(row)
    return {"point": task["point"], "rows": rows}
