"""The fastest time stepping to a given accuracy: a search for the largest fixed step whose steady outputs are within
it, shared by ``flagbot bench steady`` and ``flagbot bench speed``'s steady table. Comparing a steady solve with
time stepping at a fixed fine step overstates the solve's gain (design 1's default 1e-2 s steps are within 1e-5
of the equilibrium already); the search starts at the scene's own step and goes both ways."""
from __future__ import annotations

import math
import time

#: --dts auto: at most this many doublings above, and halvings below, the scene's own step
MAX_DOUBLINGS = 4
MAX_HALVINGS = 6
#: --dts auto: geometric bisections of the bracket [accurate, not] once doubling or halving has found one, so the
#: step found is within 2^(1/2^REFINEMENTS) = 1.19x of the largest accurate one
REFINEMENTS = 2


def within(r: dict, accuracy: float) -> bool:
    """A time-stepped run reached the steady-state rule with outputs within ``accuracy`` of the equilibrium."""
    return bool(r["steady"]) and r["error"] <= accuracy


def turn_limit(scene) -> float:
    """The largest step (s) the stepper takes whole at the scene's motor speed: above it, each step is cut into
    equal sub-steps turning the drive at most ``time.max_turn`` (physics/stepper.py), so a larger step asked for
    is not the step that runs. inf without a motor speed."""
    w = abs(scene.omega_T)
    return scene.time.max_turn / w if w > 0.0 else math.inf


def largest_step(trial, dt0: float, accuracy: float, doublings: int = MAX_DOUBLINGS,
                 halvings: int = MAX_HALVINGS, refinements: int = REFINEMENTS, dt_max: float = math.inf) -> list[dict]:
    """The runs ``trial(dt)`` (a dict with ``error`` and ``steady``) tried to find the largest step within
    ``accuracy``: ``dt0`` first; if within, doubling until a step is not (or ``doublings`` more were tried); if not,
    halving until one is (or ``halvings`` were tried); then, if an accurate and an inaccurate step bracket the
    largest accurate one, ``refinements`` geometric bisections of the bracket. No step above ``dt_max`` is tried
    (:func:`turn_limit`: above it the step asked for is not the one that runs); ``dt0`` is lowered to it. In the
    order tried; the caller picks among them."""
    dt0 = min(dt0, dt_max)
    tried = [trial(dt0)]
    up = within(tried[0], accuracy)
    dt = dt0
    for _ in range(doublings if up else halvings):
        if up and dt >= dt_max:
            break
        dt = min(dt * 2.0, dt_max) if up else dt / 2.0
        tried.append(trial(dt))
        if within(tried[-1], accuracy) != up:
            break
    good = [r["dt"] for r in tried if within(r, accuracy)]
    bad = [r["dt"] for r in tried if not within(r, accuracy) and good and r["dt"] > max(good)]
    if bad:                                       # (bad is empty without an accurate step)
        lo, hi = max(good), min(bad)
        for _ in range(refinements):
            mid = math.sqrt(lo * hi)
            tried.append(trial(mid))
            if within(tried[-1], accuracy):
                lo = mid
            else:
                hi = mid
    return tried


def fastest(tried: list[dict], accuracy: float) -> dict | None:
    """The run of ``tried`` within ``accuracy`` with the least wall time: time stepping to that accuracy as cheaply
    as it got there; None if no run was."""
    ok = [r for r in tried if within(r, accuracy)]
    return min(ok, key=lambda r: r["wall"]) if ok else None


def run_to_steady(scene, ref: dict, keys, t_max: float) -> dict:
    """Time stepping of ``scene`` from rest to its steady-state rule (at most ``t_max`` simulated seconds): its
    step ``dt``, ``wall`` seconds, whether it got ``steady``, and its ``error``, the largest relative difference
    of the summary's ``keys`` from ``ref``'s; a step that fails gives error inf, wall NaN and ``failed``, the
    reason."""
    from ..physics import Simulation, StepFailed
    sim = Simulation(scene)
    t0 = time.perf_counter()
    try:
        steady = sim.run_until_steady(t_max)
    except StepFailed as e:
        return {"dt": scene.time.dt, "wall": math.nan, "steady": False, "error": math.inf, "sim_time": sim.time,
                "failed": str(e)}
    wall = time.perf_counter() - t0
    s = sim.summary()
    return {"dt": scene.time.dt, "wall": wall, "steady": steady, "error": max(abs(s[k] / ref[k] - 1.0) for k in keys),
            "sim_time": sim.time}
