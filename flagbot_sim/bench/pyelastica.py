#!/usr/bin/env python3
"""Wall time to the steady state within 1% of the rod BVP: our implicit DER against PyElastica (explicit Cosserat).

Both codes simulate the clamped-flagellum scene (design 1's flagellum: L = 0.111 m, r0 = 3.2 mm, E = 1.2 MPa,
G = E/3, density 1000 kg/m^3, clamped at R_d = 2 cm in a plate turning about x at omega), from rest, with the same
resistive-force-theory drag f = -eta_p v - (eta_t - eta_p)(v.t) t per unit length lumped on the nodes with their
Voronoi lengths. The reference is the steady solution of the geometrically exact rod
(flagbot_sim.reference.rod_bvp, with the centrifugal load of the rod's mass, as both codes have inertia).

For each run the tip deflection |z| (co-rotating frame) and the medium torque Tx are sampled every --sample
seconds of simulated time; the run stops once both have stayed within --tol of the reference for --confirm
seconds (or at --max-time). "to steady" is the first sample of that final within-tolerance stretch, "wall" the
stepping wall time up to it (JIT compilation, set-up, the stability probe and the sampling itself excluded).

PyElastica (PyPI ``pyelastica``) is driven by a custom forcing class (the RFT drag, a numba kernel like its own
forces) and a custom boundary condition that prescribes the first node's position and the first element's
directors (and their rates) turning at omega: the clamp. Its integrator is the explicit symplectic
PositionVerlet; its largest stable time step is found by a short probe (the shear/rotation mode of the cross
section, ~2 sqrt(G/rho)/r0 ~ 1.2e4 rad/s, limits it to ~1e-4 s whatever the element count). No extra damping:
the RFT drag damps the motion. Where the clamp sits matters: a Cosserat rod's directors live at element centres,
so PyElastica's usual clamp (node 0 and element 0 fixed) keeps the first element straight and shortens the
elastic flagellum by about half an element, a first-order error (5.5% on |z| at 27 elements, 2.6% at 54). The
"centre" clamp puts element 0's centre on the clamp (the rod starts half an element behind it, that ghost half
gets no drag), which is second order and is PyElastica's best setting here; the "node" clamp is run for the
record. Our DER: BDF2 (the default) and implicit Euler (the paper's) + Newton, dt 1e-2 / 2e-2 s, edges 4.11 /
8.22 mm.

    python benchmarks/pyelastica_compare.py            # full comparison (~30 s on this machine)
    python benchmarks/pyelastica_compare.py --quick    # one setting per code (~7 s)
    flagbot bench speed                                # also runs it, after the throughput figures

PyElastica is a benchmark-only dependency: pip install 'flagbot_sim[bench]' (or -r requirements-bench.txt).
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..cliutil import json_output
from ..optional import MissingExtra, available, require
from ..physics.medium import normalise_omega, rft_coefficients
from ..reference import from_scene
from ..scene import load_scene


# ------------------------------------------------------------------------------------------------ common
@dataclass
class Reference:
    z: float          # co-rotating tip z (m)
    Tx: float         # N m
    Fx: float         # N
    tip: list
    seconds: float    # BVP solve wall time


@dataclass
class RunResult:
    code: str
    settings: str
    dt: float
    elements: int
    reached: bool = False
    t_steady: float = float("nan")      # simulated time when the final within-tol stretch began (s)
    wall_steady: float = float("nan")   # stepping wall time up to t_steady (s)
    t_run: float = 0.0                  # simulated time run
    wall_run: float = 0.0               # stepping wall time of the whole run (s)
    steps: int = 0
    err_z: float = float("nan")         # relative errors at the end of the run
    err_Tx: float = float("nan")
    err_Fx: float = float("nan")
    note: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def us_per_step(self) -> float:
        return 1e6 * self.wall_run / max(self.steps, 1)


class Tracker:
    """Samples (t, wall, z, Tx, Fx); decides when the run is within tol and has stayed there for `confirm` s."""

    def __init__(self, ref: Reference, tol: float, confirm: float):
        self.ref, self.tol, self.confirm = ref, tol, confirm
        self.t_in = None      # start of the current within-tol stretch
        self.w_in = None
        self.last = None

    def add(self, t: float, wall: float, z: float, Tx: float, Fx: float) -> bool:
        """Record a sample; True when the run can stop (within tol for `confirm` seconds)."""
        ez = abs(abs(z) / abs(self.ref.z) - 1.0)
        eT = abs(Tx / self.ref.Tx - 1.0)
        eF = abs(Fx / self.ref.Fx - 1.0)
        self.last = (ez, eT, eF)
        if not (math.isfinite(z) and math.isfinite(Tx)):
            raise FloatingPointError(f"non-finite state at t = {t:g} s")
        if ez < self.tol and eT < self.tol:
            if self.t_in is None:
                self.t_in, self.w_in = t, wall
            return t - self.t_in >= self.confirm - 1e-9
        self.t_in = self.w_in = None
        return False

    def finish(self, res: RunResult) -> RunResult:
        res.reached = self.t_in is not None and res.t_run - self.t_in >= self.confirm - 1e-9
        if self.t_in is not None:
            res.t_steady, res.wall_steady = self.t_in, self.w_in
        if self.last is not None:
            res.err_z, res.err_Tx, res.err_Fx = self.last
        if not res.reached:
            res.note = res.note or (f"not within {100 * self.tol:g}% for {self.confirm:g} s by t = "
                                    f"{res.t_run:g} s")
        return res


INTEGRATOR_NAMES = {"bdf2": "BDF2", "implicit_euler": "implicit Euler"}


def scene_for(rpm: float, edge: float = 4.11e-3, dt: float = 1e-2, integrator: str = "bdf2"):
    return load_scene("clamped_flagellum", [f"motor.omega_rpm={rpm}", f"flagellum.edge_length={edge}",
                                            f"time.dt={dt}", f"time.integrator='{integrator}'"])


def reference(rpm: float) -> Reference:
    sc = scene_for(rpm)
    w0 = time.perf_counter()
    sol = from_scene(sc)                   # includes the centrifugal load: both codes have the rod's mass
    return Reference(z=float(sol.tip[2]), Tx=sol.Tx, Fx=sol.Fx, tip=[float(v) for v in sol.tip],
                     seconds=time.perf_counter() - w0)


# ------------------------------------------------------------------------------------------------ our DER
def run_der(rpm: float, edge: float, dt: float, ref: Reference, tol: float, confirm: float, max_time: float,
            sample: float, integrator: str = "bdf2") -> RunResult:
    from ..physics import Simulation

    sc = scene_for(rpm, edge, dt, integrator)
    sim = Simulation(sc)
    n_el = len(sim.model.net.flagella_edges[0])
    res = RunResult("DER (flagbot_sim)", f"edge {edge * 1e3:.3g} mm, dt {dt:g} s, {INTEGRATOR_NAMES[integrator]}",
                    dt, n_el)
    tr = Tracker(ref, tol, confirm)
    per = max(1, int(round(sample / dt)))
    try:
        while sim.time < max_time - 1e-9:
            for _ in range(per):
                sim.step()
            F, T = sim.medium_force_on_flagella()
            tip = sim.clamp_frame_tip()
            if tr.add(sim.time, sim.wall_seconds, float(tip[2]), float(T[0]), float(F[0])):
                break
    except Exception as exc:                                       # StepFailed, non-finite
        res.note = f"failed: {exc}"
    res.t_run, res.wall_run, res.steps = sim.time, sim.wall_seconds, sim.steps
    res.extra["newton_iterations"] = sim.newton_iterations
    return tr.finish(res)


def run_steady(rpm: float, edge: float, ref: Reference, tol: float) -> RunResult:
    """The same clamped flagellum's steady state solved directly (flagbot_sim.physics.steady): no time stepping,
    so "time to steady" is the solve's wall time."""
    from ..physics.model import RobotModel
    from ..physics.steady import SteadySolver, summary

    sc = scene_for(rpm, edge)
    w0 = time.perf_counter()
    model = RobotModel(sc)
    sol = SteadySolver(model).solve(sc.omega_T)
    wall = time.perf_counter() - w0
    out = summary(model, sol)
    res = RunResult("DER steady solver (flagbot_sim)", f"edge {edge * 1e3:.3g} mm, relative equilibrium", 0.0,
                    len(model.net.flagella_edges[0]))
    res.err_z = abs(out["tip"][2] / ref.z - 1.0)
    res.err_Tx = abs(out["Tx"] / ref.Tx - 1.0)
    res.err_Fx = abs(out["Fx"] / ref.Fx - 1.0)
    res.reached = res.err_z < tol and res.err_Tx < tol
    res.t_steady, res.wall_steady, res.wall_run, res.steps = float("nan"), wall, wall, sol.iterations
    if not res.reached:
        res.note = f"the discretisation's own error exceeds {100 * tol:g}%"
    return res


def warm_der() -> None:
    from ..physics import Simulation
    sim = Simulation(scene_for(10.0))
    for _ in range(3):
        sim.step()


# ------------------------------------------------------------------------------------------------ PyElastica
def _elastica_parts():
    """The PyElastica pieces (imported lazily: the script's --help works without pyelastica)."""
    ea = require("bench", "the PyElastica comparison")
    from numba import njit

    @njit(cache=True)
    def rft_forces(x, v, eta_t, eta_p, first, F):
        """RFT per unit length on the nodes: node tangent = unit chord of its neighbours (one-sided at the
        ends, as in our DER), Voronoi length = half the adjacent current edge lengths. Nodes before ``first``
        (the ghost half element of the centre clamp) are outside the flagellum and get no force."""
        n = x.shape[1]
        de = eta_t - eta_p
        for k in range(first):
            F[0, k] = F[1, k] = F[2, k] = 0.0
        for k in range(first, n):
            a = k - 1 if k > 0 else 0
            b = k + 1 if k < n - 1 else n - 1
            c0, c1, c2 = x[0, b] - x[0, a], x[1, b] - x[1, a], x[2, b] - x[2, a]
            cn = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
            t0, t1, t2 = c0 / cn, c1 / cn, c2 / cn
            l = 0.0
            if k > 0:
                d0, d1, d2 = x[0, k] - x[0, k - 1], x[1, k] - x[1, k - 1], x[2, k] - x[2, k - 1]
                l += 0.5 * math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            if k < n - 1:
                d0, d1, d2 = x[0, k + 1] - x[0, k], x[1, k + 1] - x[1, k], x[2, k + 1] - x[2, k]
                l += 0.5 * math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            vt = v[0, k] * t0 + v[1, k] * t1 + v[2, k] * t2
            F[0, k] = -l * (eta_p * v[0, k] + de * vt * t0)
            F[1, k] = -l * (eta_p * v[1, k] + de * vt * t1)
            F[2, k] = -l * (eta_p * v[2, k] + de * vt * t2)

    @njit(cache=True)
    def add_rft(x, v, eta_t, eta_p, first, F, ext):
        rft_forces(x, v, eta_t, eta_p, first, F)
        ext += F

    class RFTDrag(ea.NoForces):
        """Resistive-force theory on the nodes: f = -eta_p v - (eta_t - eta_p)(v.t) t per unit length."""

        def __init__(self, eta_t: float, eta_p: float, first: int = 0):
            super().__init__()
            self.eta_t, self.eta_p = float(eta_t), float(eta_p)
            self.first = int(first)
            self.F = None

        def apply_forces(self, system, time=0.0):
            if self.F is None:
                self.F = np.zeros_like(system.position_collection)
            add_rft(system.position_collection, system.velocity_collection, self.eta_t, self.eta_p, self.first,
                    self.F, system.external_forces)

    @njit(cache=True)
    def _clamp_values(pos, dirs, x0, Q0, phi):
        c, s = math.cos(phi), math.sin(phi)
        pos[0, 0] = x0[0]
        pos[1, 0] = c * x0[1] - s * x0[2]
        pos[2, 0] = s * x0[1] + c * x0[2]
        for i in range(3):          # rows of Q are the directors: Q(t) = Q0 R(phi)^T
            dirs[i, 0, 0] = Q0[i, 0]
            dirs[i, 1, 0] = c * Q0[i, 1] - s * Q0[i, 2]
            dirs[i, 2, 0] = s * Q0[i, 1] + c * Q0[i, 2]

    @njit(cache=True)
    def _clamp_rates(vel, omg, dirs, x0, omega, phi):
        c, s = math.cos(phi), math.sin(phi)
        y, z = c * x0[1] - s * x0[2], s * x0[1] + c * x0[2]
        vel[0, 0] = 0.0                 # omega x_hat x r
        vel[1, 0] = -omega * z
        vel[2, 0] = omega * y
        for i in range(3):              # angular velocity omega x_hat in the material frame: Q (omega x_hat)
            omg[i, 0] = omega * dirs[i, 0, 0]

    class RotatingClamp(ea.ConstraintBase):
        """Clamp driven about the x axis at omega: node 0 at R(omega t) x0 and element 0's directors R(omega t)
        applied to their rest values, with the matching velocity and angular velocity."""

        def __init__(self, x0, Q0, omega, **kwargs):
            super().__init__(**kwargs)
            self.x0 = np.array(x0, float)
            self.Q0 = np.array(Q0, float)
            self.omega = float(omega)

        def constrain_values(self, system, time):
            _clamp_values(system.position_collection, system.director_collection, self.x0, self.Q0,
                          self.omega * float(time))

        def constrain_rates(self, system, time):
            _clamp_rates(system.velocity_collection, system.omega_collection, system.director_collection,
                         self.x0, self.omega, self.omega * float(time))

    class Simulator(ea.BaseSystemCollection, ea.Constraints, ea.Forcing):
        pass

    return ea, rft_forces, RFTDrag, RotatingClamp, Simulator


CLAMPS = {
    "node": "node 0 at the clamp, element 0's directors fixed (OneEndFixedBC-style): the first element stays "
            "straight, a first-order (O(edge)) error in the clamp position",
    "centre": "element 0 centred on the clamp (the rod starts half an element behind it; that ghost half gets "
              "no drag): the directors are fixed where the continuum clamp is, second order",
}


class ElasticaRun:
    """One PyElastica clamped flagellum, stepped by PositionVerlet.

    ``clamp`` (see CLAMPS): where the prescribed first element sits. A Cosserat rod's directors live at element
    centres, so fixing element 0's directors clamps the tangent at the centre of element 0; with ``"node"`` the
    flagellum's first element is rigid and the elastic length is short by ~ half an element.
    """

    def __init__(self, rpm: float, n_elements: int, clamp: str = "centre"):
        if clamp not in CLAMPS:
            raise ValueError(f"clamp must be one of {', '.join(CLAMPS)}, got {clamp!r}")
        ea, self._rft, RFTDrag, RotatingClamp, Simulator = _elastica_parts()
        sc = scene_for(rpm)
        fl = sc.flagellum
        self.omega = sc.omega_T
        self.eta_t, self.eta_p = rft_coefficients(sc)
        G = fl.youngs_modulus / (2.0 * (1.0 + fl.poisson_ratio))
        if clamp == "centre":           # n elements of length l with (n - 1/2) l = L: element 0 spans [-l/2, l/2]
            length = fl.length * n_elements / (n_elements - 0.5)
            start = np.array([-0.5 * length / n_elements, sc.R_d, 0.0])
            self.first = 1
        else:
            length = fl.length
            start = np.array([0.0, sc.R_d, 0.0])
            self.first = 0
        self.clamp = clamp
        self.sim = Simulator()
        self.rod = ea.CosseratRod.straight_rod(n_elements, start, np.array([1.0, 0.0, 0.0]),
                                               np.array([0.0, 1.0, 0.0]), length, fl.radius, fl.density,
                                               youngs_modulus=fl.youngs_modulus, shear_modulus=G)
        self.sim.append(self.rod)
        self.sim.constrain(self.rod).using(RotatingClamp, constrained_position_idx=(0,),
                                           constrained_director_idx=(0,), omega=self.omega)
        self.sim.add_forcing_to(self.rod).using(RFTDrag, self.eta_t, self.eta_p, self.first)
        self.sim.finalize()
        self.stepper = ea.PositionVerlet()
        self.t = np.float64(0.0)
        self.steps = 0
        self.wall = 0.0
        self._F = np.zeros((3, n_elements + 1))

    def advance(self, n: int, dt: float) -> None:
        step, sim, t = self.stepper.step, self.sim, self.t
        dt = np.float64(dt)
        w0 = time.perf_counter()
        for _ in range(n):
            t = step(sim, t, dt)
        self.wall += time.perf_counter() - w0
        self.t = t
        self.steps += n

    def observe(self):
        """(co-rotating tip, Fx, Tx) of the current state; the RFT force recomputed from it."""
        x, v = self.rod.position_collection, self.rod.velocity_collection
        if not np.all(np.isfinite(x)):
            return None
        self._rft(x, v, self.eta_t, self.eta_p, self.first, self._F)
        phi = self.omega * float(self.t)
        c, s = math.cos(phi), math.sin(phi)
        tip = x[:, -1]
        tip_c = np.array([tip[0], c * tip[1] + s * tip[2], -s * tip[1] + c * tip[2]])
        F = self._F
        Tx = float(np.sum(x[1] * F[2] - x[2] * F[1]))
        return tip_c, float(F[0].sum()), Tx

    def bounded(self, L: float) -> bool:
        x = self.rod.position_collection
        return bool(np.all(np.isfinite(x)) and np.abs(x).max() < 10 * L)


def elastica_stable_dt(rpm: float, n_elements: int, candidates, probe_time: float, L: float,
                       clamp: str = "centre"):
    """Largest candidate dt (descending) for which a fresh run stays finite and bounded over probe_time; the
    probes' wall time is returned separately (tuning cost, not counted in the comparison)."""
    w0 = time.perf_counter()
    log = []
    for dt in sorted(candidates, reverse=True):
        run = ElasticaRun(rpm, n_elements, clamp)
        n = int(round(probe_time / dt))
        ok = True
        for _ in range(10):
            run.advance(n // 10, dt)
            if not run.bounded(L):
                ok = False
                break
        log.append((dt, ok))
        if ok:
            return dt, time.perf_counter() - w0, log
    return None, time.perf_counter() - w0, log


def run_elastica(rpm: float, n_elements: int, dt: float, ref: Reference, tol: float, confirm: float,
                 max_time: float, sample: float, L: float, clamp: str = "centre") -> RunResult:
    run = ElasticaRun(rpm, n_elements, clamp)
    edge = run.rod.rest_lengths[0]
    res = RunResult("PyElastica", f"{n_elements} elements (edge {edge * 1e3:.3g} mm), {clamp} clamp, "
                                  f"dt {dt:.3g} s, PositionVerlet", dt, n_elements)
    tr = Tracker(ref, tol, confirm)
    per = max(1, int(round(sample / dt)))
    try:
        while float(run.t) < max_time - 1e-9:
            run.advance(per, dt)
            obs = run.observe()
            if obs is None:
                raise FloatingPointError(f"non-finite state at t = {float(run.t):g} s")
            tip, Fx, Tx = obs
            if tr.add(float(run.t), run.wall, float(tip[2]), Tx, Fx):
                break
    except FloatingPointError as exc:
        res.note = f"unstable: {exc}"
    res.t_run, res.wall_run, res.steps = float(run.t), run.wall, run.steps
    return tr.finish(res)


# ------------------------------------------------------------------------------------------------ report
def table(rows: list[RunResult]) -> str:
    head = ("| code | settings | simulated time to steady (s) | wall time to steady (s) | steps run | us/step | "
            "err |z| | err Tx | err Fx |")
    lines = [head, "|" + "---|" * 9]
    for r in rows:
        direct = r.reached and math.isnan(r.t_steady)          # the steady solver: no time stepped at all
        ts = "none (solved directly)" if direct else f"{r.t_steady:.2f}" if r.reached else "not reached"
        ws = f"{r.wall_steady:.3f}" if r.reached else f"> {r.wall_run:.2f}"
        steps = f"{r.steps} Newton iterations" if direct else str(r.steps)
        per = "-" if direct else f"{r.us_per_step:.1f}"
        lines.append(f"| {r.code} | {r.settings} | {ts} | {ws} | {steps} | {per} | "
                     f"{100 * r.err_z:.2f}% | {100 * r.err_Tx:.2f}% | {100 * r.err_Fx:.2f}% |")
    return "\n".join(lines)


def best(rows: list[RunResult], code: str) -> RunResult | None:
    ok = [r for r in rows if r.code == code and r.reached]
    return min(ok, key=lambda r: r.wall_steady) if ok else None


def compare(rpm=10.0, tol=0.01, confirm=5.0, max_time=40.0, sample=0.1, der_settings=None,
            elastica_settings=None, elastica_dts=None, probe_time=0.3, run_elastica_part=True, log=print) -> dict:
    """Run the comparison; returns dict(reference, rows, ratio, ...). Also usable from other benchmarks.

    None for der_settings, elastica_settings or elastica_dts means the full comparison's settings."""
    der_settings = der_settings or [(4.11e-3, 1e-2), (4.11e-3, 2e-2), (8.22e-3, 1e-2), (8.22e-3, 2e-2)]
    elastica_settings = elastica_settings or [(27, "centre"), (14, "centre"), (27, "node")]
    elastica_dts = elastica_dts or [2e-4, 1.5e-4, 1.25e-4, 1.1e-4, 1.0e-4, 9e-5, 8e-5, 7e-5, 6e-5, 5e-5, 4e-5,
                                    3e-5, 2e-5, 1e-5]
    ref = reference(rpm)
    sc = scene_for(rpm)
    L = sc.flagellum.length
    log(f"reference (rod BVP, {ref.seconds * 1e3:.0f} ms): omega = {rpm:g} rpm (omega_bar = "
        f"{normalise_omega(sc, sc.omega_T):.3g}), tip z = {ref.z * 1e3:.4f} mm, Tx = {ref.Tx:.5e} N m, "
        f"Fx = {ref.Fx:.5e} N")
    if abs(ref.z) < 0.05 * L * abs(sc.R_d / L):
        log("warning: the reference tip z is small at this omega; the relative |z| criterion is severe")
    rows: list[RunResult] = []
    w0 = time.perf_counter()
    warm_der()
    log(f"DER warm-up (JIT): {time.perf_counter() - w0:.2f} s")
    for integrator, (edge, dt) in ((i, s) for i in INTEGRATOR_NAMES for s in der_settings):
        r = run_der(rpm, edge, dt, ref, tol, confirm, max_time, sample, integrator)
        rows.append(r)
        log(f"  DER {r.settings}: " + (f"within {100 * tol:g}% from t = {r.t_steady:.2f} s, wall "
                                       f"{r.wall_steady:.3f} s" if r.reached else r.note))
    r = run_steady(rpm, 4.11e-3, ref, tol)
    rows.append(r)
    log(f"  DER steady solver {r.settings}: {1e3 * r.wall_steady:.1f} ms, errors |z| {100 * r.err_z:.2f}%, "
        f"Tx {100 * r.err_Tx:.2f}%")
    probes = {}
    if run_elastica_part and not available("bench"):
        log(f"{MissingExtra('bench', 'the PyElastica comparison')}; its half is skipped")
        run_elastica_part = False
    if run_elastica_part:
        w0 = time.perf_counter()
        warm = ElasticaRun(rpm, elastica_settings[0][0], elastica_settings[0][1])
        warm.advance(5, 1e-5)
        warm.observe()
        log(f"PyElastica set-up + JIT warm-up: {time.perf_counter() - w0:.2f} s")
        for n_el, clamp in elastica_settings:
            dt, secs, plog = elastica_stable_dt(rpm, n_el, elastica_dts, probe_time, L, clamp)
            probes[f"{n_el}:{clamp}"] = {"dt": dt, "probe_seconds": secs, "tried": plog}
            if dt is None:
                log(f"  PyElastica {n_el} elements, {clamp} clamp: no stable dt among {elastica_dts}")
                continue
            log(f"  PyElastica {n_el} elements, {clamp} clamp: largest stable dt {dt:g} s (probe {secs:.1f} s: "
                + ", ".join(f"{d:g} {'ok' if ok else 'unstable'}" for d, ok in plog) + ")")
            r = run_elastica(rpm, n_el, dt, ref, tol, confirm, max_time, sample, L, clamp)
            if r.note.startswith("unstable"):          # stable in the probe, not later: back off once
                dt2 = 0.8 * dt
                log(f"    unstable later ({r.note}); retrying at dt {dt2:g} s")
                r = run_elastica(rpm, n_el, dt2, ref, tol, confirm, max_time, sample, L, clamp)
            r.extra["probe_seconds"] = secs
            rows.append(r)
            log(f"  PyElastica {r.settings}: " + (f"within {100 * tol:g}% from t = {r.t_steady:.2f} s, wall "
                                                  f"{r.wall_steady:.3f} s" if r.reached else r.note))
    b_der, b_el = best(rows, "DER (flagbot_sim)"), best(rows, "PyElastica")
    b_st = best(rows, "DER steady solver (flagbot_sim)")
    ratio = b_el.wall_steady / b_der.wall_steady if (b_der and b_el) else float("nan")
    ratio_st = b_el.wall_steady / b_st.wall_steady if (b_st and b_el) else float("nan")
    return {"rpm": rpm, "tol": tol, "confirm": confirm, "reference": asdict(ref), "rows": rows,
            "best_der": b_der, "best_elastica": b_el, "best_steady": b_st, "speed_ratio": ratio,
            "speed_ratio_steady": ratio_st, "probes": probes}


def run_comparison(quick: bool = False) -> int:
    """The comparison as `flagbot bench speed` runs it."""
    return main(["--quick"] if quick else [])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description="Wall time for our DER and for PyElastica to reach the clamped flagellum's steady state "
                    "within a tolerance of the rod-BVP reference (tip |z| and Tx), side by side in one run.")
    ap.add_argument("--quick", action="store_true",
                    help="one setting per code (DER edge 4.11 mm dt 1e-2; PyElastica 27 elements, centre clamp), shorter "
                         "confirmation: ~15 s")
    ap.add_argument("--rpm", type=float, default=10.0, help="clamp speed (rpm), default 10 (omega_bar ~ 29)")
    ap.add_argument("--tol", type=float, default=0.01, help="relative tolerance on |z| and Tx (default 0.01)")
    ap.add_argument("--confirm", type=float, default=None,
                    help="seconds (simulated) the errors must stay within tol (default 5, --quick 3)")
    ap.add_argument("--max-time", type=float, default=40.0, help="simulated time limit per run (s)")
    ap.add_argument("--sample", type=float, default=0.1, help="sampling interval (simulated s)")
    ap.add_argument("--elastica", default=None, metavar="N:CLAMP,...",
                    help="PyElastica runs as elements:clamp, comma-separated; clamp 'centre' (element 0 centred "
                         "on the clamp) or 'node' (node 0 and element 0 fixed, PyElastica's usual clamp) "
                         "(default 27:centre,14:centre,27:node; --quick 27:centre)")
    ap.add_argument("--der", default=None,
                    help="DER settings edge:dt, comma-separated, e.g. 4.11e-3:1e-2,8.22e-3:2e-2 (default: "
                         "4.11/8.22 mm x 1e-2/2e-2 s; --quick 4.11e-3:1e-2)")
    ap.add_argument("--no-elastica", action="store_true", help="skip the PyElastica half")
    ap.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    a = ap.parse_args(argv)
    if a.json:
        from ..cliutil import check_out_file
        from ..scene import SceneError
        try:
            check_out_file(a.json, "--json")       # before minutes of benchmarking
        except SceneError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    confirm = a.confirm if a.confirm is not None else (3.0 if a.quick else 5.0)
    if a.der:
        der = [tuple(float(v) for v in item.split(":")) for item in a.der.split(",")]
    else:
        der = [(4.11e-3, 1e-2)] if a.quick else None
    if a.elastica:
        elastica = []
        for item in a.elastica.split(","):
            n, _, clamp = item.partition(":")
            if (clamp or "centre") not in CLAMPS:
                ap.error(f"--elastica {item!r}: clamp must be one of {', '.join(CLAMPS)}")
            elastica.append((int(n), clamp or "centre"))
    else:
        elastica = [(27, "centre")] if a.quick else None
    w0 = time.perf_counter()
    out = compare(rpm=a.rpm, tol=a.tol, confirm=confirm, max_time=a.max_time, sample=a.sample, der_settings=der,
                  elastica_settings=elastica, run_elastica_part=not a.no_elastica)
    print()
    print(f"Clamped flagellum at {a.rpm:g} rpm: wall time to stay within {100 * a.tol:g}% of the rod BVP "
          f"(tip |z| and Tx) for {confirm:g} s; errors at the end of each run.")
    print()
    print(table(out["rows"]))
    print()
    bd, be = out["best_der"], out["best_elastica"]
    if bd:
        print(f"best DER:        {bd.settings}: {bd.wall_steady:.3f} s wall")
    if be:
        print(f"best PyElastica: {be.settings}: {be.wall_steady:.3f} s wall")
    if bd and be:
        print(f"speed ratio (PyElastica wall / DER wall at {100 * a.tol:g}%): {out['speed_ratio']:.1f}x")
    bs = out["best_steady"]
    if bs:
        print(f"DER steady solver: {1e3 * bs.wall_steady:.1f} ms" + (
            f" ({out['speed_ratio_steady']:.0f}x faster than PyElastica's time stepping)" if be else ""))
    print(f"(script total {time.perf_counter() - w0:.1f} s)")
    if a.json:
        payload = {k: v for k, v in out.items() if k not in ("rows", "best_der", "best_elastica", "best_steady")}
        payload["rows"] = [dict(asdict(r), us_per_step=r.us_per_step) for r in out["rows"]]
        Path(a.json).write_text(json_output(payload, indent=2))     # strict: a NaN is null
    return 0


if __name__ == "__main__":
    sys.exit(main())
