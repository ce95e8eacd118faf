"""Every result's estimated numerical error: a time part, a space part and their sum (docs/physics.md, "Error
estimates").

Outputs and measures: omega_h, omega_t and v of the free robot, Fx and Tx of the clamped flagellum, each relative
to its size; the clamped flagellum's tip as a distance over the flagellum length L.

* **Time** (a time-stepped run only): from the integrator's own local error estimate. Each step reports the
  relative error of the velocity it gives the medium (``StepStats.velocity_error``: Milne's estimate, fixed or
  error-controlled steps alike), averaged over the last steady window (``Simulation.velocity_error``). In steady
  rotation that error is BDF2's one systematic effect: every part turning at omega has its velocity (omega h)^2 / 3
  too fast and its centripetal acceleration twice that (the twist angles and the axial translation grow linearly
  and are exact). The time-stepped steady state is therefore, to first order, the exact one of a medium whose RFT
  coefficients are (1 + e) and whose masses are (1 + 2 e) times the scene's; the steady solver with that
  perturbation (``PERTURBATION``, one extra solve started at the solution) gives each output's sensitivity s_k,
  and the output's time error is s_k e, plus what the run had not yet settled (``Simulation.settling_error``).
  Implicit Euler's error is a lag of the velocity's direction by omega h / 2, which no coefficient scaling
  mimics: there s_k = 1 (and the tip's deflection over L), a bound rather than an estimate.
* **Space**: Richardson with the steady solver at the scene's edge length and at twice it, second order
  (observed: the error falls 4x per halving): (O_h - O_2h) / (r^2 - 1), r the ratio of the two edge lengths
  (edge counts are whole numbers).

``error_estimate`` is the sum of the parts (where one is missing, the other alone). Each is a dict by output.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:                 # the formatting helpers below need no simulator: the model is imported on use
    from .model import RobotModel

#: the relative change of the medium's velocity the time part's sensitivity is measured with (linear regime: the
#: outputs change by ~1e-3, far above the steady solver's tolerance)
PERTURBATION = 1.0e-3
#: Richardson's order: the DER's observed spatial convergence (docs/accuracy.md)
ORDER = 2
#: a result whose estimated error exceeds this says so in one line
WARN_ABOVE = 1.0e-2


def output_names(scene) -> tuple[str, ...]:
    return ("Fx", "Tx", "tip") if scene.clamped else ("omega_h", "omega_t", "v")


def relative_errors(a: dict, b: dict, scene) -> dict[str, float]:
    """Each output of summary ``a`` against ``b``: |a - b| / |b| (the tip: |a - b| / L)."""
    out = {}
    for k in output_names(scene):
        if k == "tip":
            out[k] = float(np.linalg.norm(np.asarray(a[k]) - np.asarray(b[k]))) / scene.flagellum.length
        else:
            out[k] = abs(a[k] - b[k]) / abs(b[k]) if b[k] != 0.0 else math.nan
    return out


def coarse_scene(scene):
    """The scene at twice its edge length, and the ratio r of the two actual edge lengths (about 2)."""
    from .network import flagellum_edge_count
    fl = scene.flagellum
    coarse = scene.with_overrides({"flagellum.edge_length": 2.0 * fl.edge_length})
    n_fine = flagellum_edge_count(fl.length, fl.edge_length)
    n_coarse = flagellum_edge_count(fl.length, coarse.flagellum.edge_length)
    return coarse, n_fine / n_coarse


class SpaceEstimator:
    """Richardson's second solve: the steady solver of the scene at twice its edge length, continued from speed
    to speed like the fine one (``estimate(fine_summary)`` for the scene's speed, or any other)."""

    def __init__(self, scene):
        from .model import RobotModel
        from .steady import SteadySolver
        self.scene = scene
        coarse, self.ratio = coarse_scene(scene)
        self.model = RobotModel(coarse)
        self.solver = SteadySolver(self.model)
        self._last = None

    def solve_fine(self, solver, omega_T: float):
        """The fine equilibrium at ``omega_T`` on ``solver``'s mesh, started from this estimator's coarse one,
        solved first (physics.steady.solve_with_coarse); estimate() continues from that coarse solution."""
        from .steady import solve_with_coarse
        sol, coarse = solve_with_coarse(solver, self.solver, omega_T)
        self.use(coarse)
        return sol

    def use(self, sol) -> None:
        """The coarse equilibrium at the next speed, already solved (physics.steady.solve_with_coarse): estimate()
        continues from it."""
        self._last = sol

    def estimate(self, fine: dict) -> dict[str, float] | None:
        """The space error of each output of the steady summary ``fine``; None if the coarse robot has no
        equilibrium there."""
        from .steady import SteadyFailed, summary
        try:
            sol = self.solver.solve(fine["omega_T"], start=self._last)
        except SteadyFailed:
            self._last = None
            return None
        self._last = sol
        coarse = summary(self.model, sol)
        factor = 1.0 / (self.ratio ** ORDER - 1.0)
        return {k: e * factor for k, e in relative_errors(fine, coarse, self.scene).items()}


def time_sensitivity(model: RobotModel, sol) -> dict[str, float] | None:
    """Each output's relative change per unit relative error of the velocity the medium sees (see the module
    docstring): the steady solution of the same robot with its RFT coefficients times (1 + PERTURBATION) and its
    masses times (1 + 2 PERTURBATION), against ``sol``, over PERTURBATION. None if that solve fails."""
    from .model import RobotModel
    from .steady import SteadyFailed, SteadySolver, summary
    d = PERTURBATION
    perturbed = RobotModel(model.scene)
    rft = perturbed.effect("rft")
    if rft is not None:
        rft.eta_t *= 1.0 + d
        rft.eta_p *= 1.0 + d
    inertia = perturbed.effect("inertia")
    if inertia is not None:
        inertia.mass = inertia.mass * (1.0 + 2.0 * d)
    try:
        psol = SteadySolver(perturbed).solve(sol.omega_T, start=sol)
    except SteadyFailed:
        return None
    base, pert = summary(model, sol), summary(perturbed, psol)
    return {k: e / d for k, e in relative_errors(pert, base, model.scene).items()}


def bound_sensitivity(model: RobotModel, sol=None) -> dict[str, float]:
    """s_k = 1 for every output (the tip: its deflection from the straight flagellum over L, 1 without a
    solution): where the sensitivity cannot be measured (implicit Euler, no equilibrium)."""
    sc = model.scene
    out = {k: 1.0 for k in output_names(sc)}
    if sc.clamped and sol is not None:
        tip = 3 * int(model.net.flagella_nodes[0][-1])
        straight = model.net.initial_q()[tip: tip + 3]
        out["tip"] = float(np.linalg.norm(sol.q[tip: tip + 3] - straight)) / sc.flagellum.length
    return out


def total(time: dict | None, space: dict | None) -> dict[str, float] | None:
    """The sum of the parts, output by output (a missing part counts as nothing)."""
    parts = [p for p in (time, space) if p is not None]
    if not parts:
        return None
    return {k: float(sum(p[k] for p in parts)) for k in parts[0]}


def fields(time: dict | None, space: dict | None) -> dict:
    """The JSON fields of a result: ``error_estimate`` and its two parts (None where a part does not exist: no
    time part for a steady solve)."""
    return {"error_estimate": total(time, space), "error_estimate_time": time, "error_estimate_space": space}


def for_steady(model: RobotModel, sol, row: dict, space: SpaceEstimator | None = None) -> dict:
    """The error fields of a steady solve (``row``: its summary): the space part alone (no time stepping)."""
    space = space or SpaceEstimator(model.scene)
    return fields(None, space.estimate(row))


def for_run(sim, out: dict) -> dict:
    """The error fields of a time-stepped run (``out``: its summary): time and space, each output's.

    Solves the scene's steady state (the space part's fine solve, and the point where the sensitivity is
    measured); where it has none (e.g. a whirling flagellum), the time part uses the bound s_k = 1 and the space
    part is None. A run that is not steady yet gets the bound s_k = 1 too (the sensitivity is the steady
    state's), and nothing for what it has still to settle (unknown: its summary says it is not steady)."""
    from .model import RobotModel
    from .steady import SteadyFailed, SteadySolver, summary
    scene = sim.scene
    model = RobotModel(scene)
    try:
        sol = SteadySolver(model).solve(scene.omega_T)
    except SteadyFailed:
        sol = None
    if sol is None:
        sens, space = bound_sensitivity(model), None
    else:
        fine = summary(model, sol)
        space = SpaceEstimator(scene).estimate(fine)
        sens = time_sensitivity(model, sol) if sim.stepper.integrator.order == 2 and sim.steady else None
        if sens is None:
            sens = bound_sensitivity(model, sol)
    e = sim.velocity_error()
    settle = sim.settling_error()
    time = {k: (abs(sens[k]) * e if math.isfinite(e) else 0.0)
            + (settle[k] if math.isfinite(settle.get(k, math.nan)) else 0.0) for k in output_names(scene)}
    return fields(time, space)


def worst(estimate: dict | None) -> tuple[str, float] | None:
    """(output, error) of the largest estimated error, or None."""
    if not estimate:
        return None
    finite = {k: v for k, v in estimate.items() if v is not None and math.isfinite(v)}
    if not finite:
        return None
    k = max(finite, key=finite.get)
    return k, finite[k]


def percent(x: float | None) -> str:
    """A relative error as a short percentage (two significant digits): 0.1%, 0.012%, 3.1%; '--' if unknown."""
    if x is None or not math.isfinite(x):
        return "--"
    p = 100.0 * x
    if p >= 10.0:
        return f"{p:.0f}%"
    return f"{p:.2g}%" if p >= 1e-3 else "<0.001%"


def plus_minus(out: dict, key: str) -> str:
    """' +/- 0.1%' for output ``key`` of a result with error fields, '' without them."""
    est = out.get("error_estimate")
    if not est or key not in est:
        return ""
    return f" +/- {percent(est[key])}"


def warning_line(out: dict) -> str | None:
    """The one line a steady result whose estimated error exceeds WARN_ABOVE prints, or None (also for a run that
    is not steady yet: its summary says so, and its error is first of all that)."""
    if out.get("steady") is False:
        return None
    w = worst(out.get("error_estimate"))
    if w is None or w[1] <= WARN_ABOVE:
        return None
    k, e = w
    t = (out.get("error_estimate_time") or {}).get(k)
    s = (out.get("error_estimate_space") or {}).get(k)
    cause = "the time step's" if (t or 0.0) >= (s or 0.0) else "the edge length's"
    return (f"estimated numerical error {percent(e)} in {k} exceeds {percent(WARN_ABOVE)} (mostly {cause}: time "
            f"{percent(t)}, space {percent(s)}); ask for accuracy with time.rtol or a finer "
            f"flagellum.edge_length")


# ----------------------------------------------------------------------------------------------- accuracy.rtol
#: the shares of accuracy.rtol given to the time and the space error. Error control keeps the steady outputs
#: within 0.71 time.rtol (BDF2, docs/accuracy.md): 0.5 of the request leaves ~0.36 of it for time; the edges are
#: chosen for 0.4 of it by Richardson's estimate
TIME_SHARE = 0.5
SPACE_SHARE = 0.4
#: the largest step accuracy.rtol allows (s): the 'accurate' preset's, so that a live run still advances smoothly
ACCURACY_DT = 0.1
#: where no equilibrium tells the space error: the worst measured at 4.11 mm (clamped flagellum up to 2000 rpm, vs
#: the rod BVP, docs/accuracy.md), which scales with the edge length squared
FALLBACK_SPACE_ERROR = (1.2e-2, 4.11e-3)


def _space_error_for_accuracy(scene) -> float | None:
    """The largest Richardson space error of the scene's steady outputs at its own edge length, the tip measured
    against its deflection (as the accuracy study measures it: stricter than over L); None without equilibrium."""
    from .model import RobotModel
    from .steady import SteadyFailed, SteadySolver, summary
    model = RobotModel(scene)
    try:
        sol = SteadySolver(model).solve(scene.omega_T)
    except SteadyFailed:
        return None
    fine = summary(model, sol)
    space = SpaceEstimator(scene).estimate(fine)
    if space is None:
        return None
    if scene.clamped:
        defl = bound_sensitivity(model, sol)["tip"]           # the tip's deflection over L
        space["tip"] = space["tip"] / max(defl, 1e-12)
    return max(space.values())


def resolve_accuracy(scene):
    """(scene, choice): the scene with ``accuracy.rtol``'s discretisation in place of its own, and what was
    chosen (None when accuracy.rtol is 0: the scene unchanged).

    Time: BDF2 with ``time.rtol`` = TIME_SHARE x the request, steps up to ACCURACY_DT. Space: the edge length whose
    Richardson space error (:func:`_space_error_for_accuracy`, second order) is SPACE_SHARE x the request, found
    from the scene's own edge length and checked once at the length chosen (a coarse start can be outside the
    asymptotic range); never longer than a quarter of the flagellum."""
    rtol = scene.accuracy.rtol
    if rtol <= 0.0:
        return scene, None
    fl = scene.flagellum
    longest = 0.25 * fl.length
    h = min(fl.edge_length, longest)
    target = SPACE_SHARE * rtol
    err = None
    for _ in range(2):
        trial = scene.with_overrides({"accuracy.rtol": 0.0, "flagellum.edge_length": h})
        err = _space_error_for_accuracy(trial)
        if err is None:
            e0, h0 = FALLBACK_SPACE_ERROR
            h = h0 * math.sqrt(target / e0)
            break
        h_new = min(h * math.sqrt(target / max(err, 1e-300)), longest)
        if h_new >= h and err <= target:
            break                # the length tried is fine enough (coarser would be cheaper: keep the checked one)
        h = 0.95 * h_new
    h = max(min(h, longest), fl.length / 20000.0)
    chosen = {"time.integrator": "bdf2", "time.rtol": TIME_SHARE * rtol, "time.dt": ACCURACY_DT,
              "flagellum.edge_length": h}
    resolved = scene.with_overrides({"accuracy.rtol": 0.0, **chosen})
    return resolved, {"rtol": rtol, **chosen, "space_error_estimate": err}
