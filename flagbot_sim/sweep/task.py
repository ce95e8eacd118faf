"""One grid point, computed by every framework: the unit of work the engines distribute.

``run_point(task)`` takes and returns plain picklable data (dicts of str/float/int), builds its scene from the
base scene's file data plus the point's overrides (so a remote Dask worker needs no scene file), and depends
on nothing but the task: the same task gives bit-identical numbers in any process, in any order.

DER steady state is *detected*: every half window the mean rates over the last window [t - w, t] are compared
with those over [t - 2w, t - w]; the run is steady when omega_h and v both changed by less than ``rtol``
(relative) at three consecutive checks, i.e. over a whole window of checks. A single check is not enough: while
v passes through the maximum of its start-up overshoot (design 1 at high omega_T), two adjacent windows
straddling the peak can have equal means. A run that reaches ``t_max`` first reports its last-window rates with
``hit_cap = True``.
"""
from __future__ import annotations

import math
import os
import socket
import time
import traceback
from dataclasses import asdict, dataclass

from ..scene import Scene, scene_from_dict

#: "der" then beam.balance.REGIMES in its order (tests/test_sweep.py checks it). Written out rather than imported:
#: importing anything from flagbot_sim.beam loads the beam solver (scipy), and plotting a sweep must not
FRAMEWORKS = ("der", "lb", "nlb-nohead", "nlb")
#: human names, as in the paper
FRAMEWORK_LABELS = {"der": "DER", "lb": "LB", "nlb-nohead": "NLB w/o head", "nlb": "NLB"}

#: consecutive passing checks (half a window apart) before a DER run counts as steady
CONFIRM_CHECKS = 3
#: |v| below this (m/s) is "not moving": its relative change is not meaningful
V_FLOOR = 1.0e-9


@dataclass(frozen=True)
class SteadySettings:
    t_max: float          # s of simulated time: the cap
    window: float         # s: rates are averaged over this
    rtol: float           # relative change between consecutive windows counted as steady

    def check(self) -> None:
        from .grid import SweepError
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


def _steady_change(ob, window: float) -> tuple[float, float] | None:
    """Relative changes of omega_h and v between the last two windows; None while the history is short."""
    # Deliberately not Observer.steady_state's rule, which is one check of (|d omega_h| + |d omega_t|) /
    # (|omega_h| + |omega_t|) and of v, with |v| < 1e-9 m/s passing outright. A sweep point is reported, so:
    # one check can pass at a start-up overshoot peak (module docstring), hence CONFIRM_CHECKS passes in a row;
    # v is measured against max(|v|, V_FLOOR) and a small v must be steady too, not waved through; and
    # omega_h alone, relative to itself, is the rate the sweep reports (omega_t ~ omega_T - omega_h carries
    # nothing new). With omega_h + omega_t ~ omega_T the observer's measure is ~ 2 |d omega_h| / omega_T, so this
    # one is tighter on omega when omega_h < omega_T / 2 (design 2) and up to 2x looser when the head takes
    # most of omega_T (design 1), where v settles far more slowly and decides anyway. The committed sweep
    # results were made with this rule: do not change it to match the observer.
    last = ob.window_rates(window)
    prev = ob.window_rates(window, end_time=ob.t[-1] - window)
    if last is None or prev is None:
        return None
    dw = abs(last["omega_h"] - prev["omega_h"]) / max(abs(last["omega_h"]), 1e-12)
    dv = abs(last["v"] - prev["v"]) / max(abs(last["v"]), V_FLOOR)
    return dw, dv


def run_der(scene: Scene, settings: SteadySettings) -> dict:
    from ..physics import Simulation, StepFailed

    w0 = time.perf_counter()
    out = {"framework": "der", "error": "", "hit_cap": False, "converged": False}
    sim = Simulation(scene)
    dt = scene.time.dt
    n_max = max(1, int(math.ceil(settings.t_max / dt - 1e-9)))
    check_every = max(1, int(round(0.5 * settings.window / dt)))
    passed = 0
    try:
        for k in range(1, n_max + 1):
            sim.step()
            if k % check_every == 0:
                change = _steady_change(sim.observer, settings.window)
                if change is not None and max(change) < settings.rtol:
                    passed += 1
                    if passed >= CONFIRM_CHECKS:
                        out["converged"] = True
                        break
                else:
                    passed = 0
        else:
            out["hit_cap"] = True
    except StepFailed as exc:
        out["error"] = f"step failed at t = {sim.time:.4f} s: {exc}"
    rates = sim.observer.window_rates(settings.window) or sim.observer.window_rates(max(sim.time, dt))
    change = _steady_change(sim.observer, settings.window)
    omega_T = scene.omega_T
    if rates is None:
        omega_h = omega_t = v = math.nan
    else:
        omega_h, omega_t, v = rates["omega_h"], rates["omega_t"], rates["v"]
    out.update(omega_h=omega_h, omega_t=omega_t, v=v, omega_T_bar=scene.normalise_omega(omega_T),
               omega_h_bar=scene.normalise_omega(omega_h), v_bar=scene.normalise_speed(v),
               w_tip_over_L=math.nan, steps=sim.steps, sim_time=sim.time,
               change_omega_h=change[0] if change else math.nan, change_v=change[1] if change else math.nan,
               wall_seconds=time.perf_counter() - w0)
    return out


def run_beam(scene: Scene, regime: str) -> dict:
    from ..beam import BeamParams, solve_balance

    w0 = time.perf_counter()
    # no warm start from a neighbouring point: each point must not depend on which others ran before it
    res = solve_balance(BeamParams.from_scene(scene), scene.omega_T, regime=regime, raise_on_failure=False)
    return {"framework": regime, "omega_h": res.omega_h, "omega_t": res.omega_t, "v": res.v_h,
            "omega_T_bar": res.omega_T_bar, "omega_h_bar": res.omega_h_bar, "v_bar": res.v_bar,
            "w_tip_over_L": res.w_tip_over_L, "steps": res.bvp_solves, "sim_time": math.nan,
            "change_omega_h": math.nan, "change_v": math.nan, "converged": bool(res.converged),
            "hit_cap": False, "error": "" if res.converged else res.message,
            "wall_seconds": time.perf_counter() - w0}


def run_point(task: dict) -> dict:
    """Compute one grid point in every requested framework: {"point": key, "rows": [...]}.

    A failure inside one framework becomes that row's ``error`` text; it never aborts the sweep.
    """
    scene = task_scene(task)
    settings = SteadySettings(**task["settings"])
    common = {"point": task["point"], "n": scene.robot.n_flagella, "L": scene.flagellum.length,
              "omega_T": scene.omega_T, "omega_T_rpm": scene.motor.omega_rpm}
    rows = []
    for fw in task["frameworks"]:
        try:
            row = run_der(scene, settings) if fw == "der" else run_beam(scene, fw)
        except Exception as exc:   # noqa: BLE001 -- recorded in the CSV, the rest of the sweep goes on
            nan = math.nan
            row = {"framework": fw, "omega_h": nan, "omega_t": nan, "v": nan,
                   "omega_T_bar": scene.normalise_omega(scene.omega_T), "omega_h_bar": nan, "v_bar": nan,
                   "w_tip_over_L": nan, "steps": 0, "sim_time": nan, "change_omega_h": nan, "change_v": nan,
                   "converged": False, "hit_cap": False, "wall_seconds": nan,
                   "error": f"{type(exc).__name__}: {exc} "
                            f"[{traceback.extract_tb(exc.__traceback__)[-1].name}]".replace("\n", " ")}
        row.update(common)
        row["worker"] = f"{socket.gethostname()}:{os.getpid()}"
        row["finished_at"] = time.time()
        rows.append(row)
    return {"point": task["point"], "rows": rows}
