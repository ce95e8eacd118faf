"""Weighted least squares of simulated steady states against measured ones (the paper's "fitting parameters").

The model of a row is the relative equilibrium of the scene with the row's inputs and the trial parameters,
solved by the steady solver (:mod:`flagbot_sim.fit.evaluate`); residuals are (simulated - measured) / sigma for
every measured output (v, omega_h) of every row, sigma the row's ``*_std`` or, without one, the RMS of that
output's data. The search (scipy's trust-region-reflective ``least_squares``) runs in fit coordinates: the
logarithm of a parameter whose declared range is positive (C1, C2, mu, a yield force: scale-free, and a factor
is the natural step), the value itself otherwise; bounds are the scene's declared range, for log parameters
narrowed to six decades either side of the start, or ``--bounds``.

Jacobian: forward finite differences of the whole model, one step of ``FD_STEP`` in fit coordinates per
parameter (a relative change of 1e-4 for a log parameter). Why: any numeric scene key can be fitted, and for most
(mu enters the RFT drag, the head drag and torque; a modulus the springs) there is no cheap analytic derivative
of the equilibrium; the p perturbed models of one Jacobian are independent, so they run in parallel on the
engine. The steady solver converges quadratically, so its answers are smooth to ~1e-8 relative (measured: a
continued and a fresh solve of one point agree to 2e-8), far below the step; measured on the tests' design 2
fit, these slopes agree with central differences to 4e-5 (1e-3 step: 4e-4), negligible next to any experimental
scatter. Central differences would double the cost for no interval that changes.

At the optimum the covariance of the fit coordinates is (J^T W J)^-1 s^2, s^2 = chi^2 / (m - p) (or 1 with
``absolute_sigma``: the stds are the true measurement errors), from the SVD of the weighted Jacobian; 95%
intervals use Student's t with m - p degrees of freedom, and map back through exp for log parameters (so they
stay positive). A parameter the data do not determine is reported as such: when the smallest singular value is
below ``RCOND`` of the largest (J^T W J singular to the precision of the finite differences) every parameter in
that direction gets an infinite interval; when its interval spans more than a factor of ``WIDE`` (log) or ten
times its value (linear), it is flagged too. Its number is then only where the search stopped.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..scene import SECTIONS, Scene, SceneError, _split_key, inert_keys
from .data import ALIASES, Dataset, engine_rows
from .evaluate import evaluate

#: finite-difference step in fit coordinates (log parameters: a relative change of 1e-4)
FD_STEP = 1e-4
#: singular values below this fraction of the largest are zero (the finite differences' precision)
RCOND = 1e-7
#: a log parameter whose 95% interval spans more than this factor either way is not identified
WIDE = 10.0
#: log parameters search at most this factor either side of the start (unless --bounds says otherwise)
LOG_SPAN = 1e6


class FitError(SceneError):
    """A fit that cannot run or continue: the message says which parameter, row or evaluation."""


@dataclass
class Parameter:
    key: str
    start: float
    lower: float
    upper: float
    log: bool

    def to_x(self, value: float) -> float:
        return math.log(value) if self.log else value

    def from_x(self, x: float) -> float:
        if not self.log:
            return x
        return math.exp(x) if x < 709.0 else math.inf        # an interval's end beyond the float range

    @property
    def x_bounds(self) -> tuple[float, float]:
        return self.to_x(self.lower), self.to_x(self.upper)

    @property
    def scale(self) -> float:
        """Typical size of a step in fit coordinates."""
        return 1.0 if self.log else max(abs(self.start), 1e-3 * (self.upper - self.lower), 1e-12)


def canonical_key(key: str) -> str:
    key = key.strip()
    return ALIASES.get(key, key)


def parse_parameters(text: str, base: Scene, bounds: dict[str, tuple[float, float]] | None = None
                     ) -> list[Parameter]:
    """``head.C1,head.C2,medium.mu`` -> Parameters, with start values from the scene and bounds from the
    declared range (or ``bounds``)."""
    bounds = {canonical_key(k): v for k, v in (bounds or {}).items()}
    keys = [canonical_key(k) for k in text.split(",") if k.strip()]
    if not keys:
        raise FitError("--fit needs at least one scene key, e.g. --fit head.C1,head.C2,medium.mu")
    if len(set(keys)) != len(keys):
        raise FitError(f"--fit lists a key twice: {text}")
    unknown = sorted(set(bounds) - set(keys))
    if unknown:
        raise FitError(f"--bounds {unknown[0]}: not a fitted parameter (--fit {','.join(keys)})")
    out = []
    inert = inert_keys(base)
    for key in keys:
        section, name = _split_key(key)
        f = next(f for f in dataclasses.fields(SECTIONS[section]) if f.name == name)
        if key in inert:
            raise FitError(f"--fit {inert[key]}")
        if isinstance(f.default, bool) or not isinstance(f.default, float):
            kind = "an integer" if isinstance(f.default, int) else "not a number"
            raise FitError(f"--fit {key}: {kind} ({type(f.default).__name__}); only real-valued scene keys can be "
                           "fitted (give integer inputs such as n as data columns)")
        start = float(getattr(getattr(base, section), name))
        meta = f.metadata
        lo = meta["ge"] if meta["ge"] is not None else meta["gt"]
        hi = meta["le"] if meta["le"] is not None else meta["lt"]
        lo = -math.inf if lo is None else float(lo)
        hi = math.inf if hi is None else float(hi)
        if lo >= 0.0 and start == 0.0:
            raise FitError(f"--fit {key}: the start value is 0; a positive key is fitted in log space, so give a "
                           f"positive start with --set {key}=...")
        if key == "flagellum.helix_pitch" and start == 0.0:
            # 0 (straight) is apart from every helix (|P| > 2 r0): the first finite-difference step was refused
            raise FitError(f"--fit {key}: the start value is 0, straight flagella, which no helix is near (a helix "
                           f"needs |P| > 2 r0); give a helical start with --set {key}=... (its sign the handedness)")
        log = lo >= 0.0
        if key in bounds:
            blo, bhi = bounds[key]
            if not (blo < bhi):
                raise FitError(f"--bounds {key}={blo:g}:{bhi:g}: the lower bound must be below the upper one")
            if blo < lo or bhi > hi:
                raise FitError(f"--bounds {key}={blo:g}:{bhi:g} leaves the key's allowed range "
                               f"[{lo:g}, {hi:g}]")
            lo, hi = blo, bhi
            log = log and lo > 0.0
        elif log:
            lo, hi = max(lo, start / LOG_SPAN), min(hi, start * LOG_SPAN)
        if meta["gt"] is not None and lo <= meta["gt"] and not log:
            lo = meta["gt"] + 1e-12 * max(1.0, abs(meta["gt"]))
        if log and lo <= 0.0:
            lo = start / LOG_SPAN
        if not (lo <= start <= hi):
            raise FitError(f"the start value {key} = {start:g} (from the scene, or --set) is outside the bounds "
                           f"[{lo:g}, {hi:g}]")
        out.append(Parameter(key, start, lo, hi, log))
    return out


def parse_bounds(items: list[str]) -> dict[str, tuple[float, float]]:
    out = {}
    for item in items:
        if "=" not in item or ":" not in item.split("=", 1)[1]:
            raise FitError(f"--bounds {item!r} must look like KEY=LOW:HIGH, e.g. head.C1=0.1:100")
        key, rng = item.split("=", 1)
        try:
            lo, hi = (float(x) for x in rng.split(":"))
        except ValueError:
            raise FitError(f"--bounds {item!r}: LOW and HIGH must be numbers") from None
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise FitError(f"--bounds {item!r}: LOW and HIGH must be finite")
        out[canonical_key(key)] = (lo, hi)
    return out


# ---------------------------------------------------------------- the problem
class FitProblem:
    """Residuals and their Jacobian in fit coordinates, every model evaluation a batch on the engine."""

    def __init__(self, base: Scene, params: list[Parameter], data: Dataset, engine, progress=None):
        self.base, self.params, self.data, self.engine = base, params, data, engine
        self.rows = engine_rows(data)
        self.weights = data.weights()
        self.m = sum(len(w) for w in self.weights)
        self._cache: dict[bytes, tuple[np.ndarray, list[dict]]] = {}
        self.evaluations = 0          # model evaluations (each: every row once)
        self.progress = progress
        self.last_failure = ""

    def values(self, x: np.ndarray) -> dict:
        return {p.key: p.from_x(float(xi)) for p, xi in zip(self.params, x)}

    def _residuals(self, sims: list[dict]) -> np.ndarray | None:
        r = []
        for sim, ws in zip(sims, self.weights):
            if sim["error"]:
                return None
            for output, y, sigma in ws:
                r.append((sim[output] - y) / sigma)
        r = np.asarray(r, float)
        return r if np.all(np.isfinite(r)) else None

    def _failure(self, x: np.ndarray, sims: list[dict]) -> str:
        bad = next((s for s in sims if s["error"]), None)
        where = ", ".join(f"{k} = {v:.6g}" for k, v in self.values(x).items())
        if bad is None:
            return f"non-finite outputs at {where}"
        row = self.data.rows[bad["index"]]
        return f"no steady state for line {row.line} ({row.label()}) at {where}: {bad['error']}"

    def batch(self, xs: list[np.ndarray]) -> list[tuple[np.ndarray | None, list[dict]]]:
        """Residuals (None where a row failed) and row results at each x, cached; the new ones in one batch."""
        todo = [x for x in xs if x.tobytes() not in self._cache]
        uniq = list({x.tobytes(): x for x in todo}.values())
        if uniq:
            results = evaluate(self.engine, self.base, [self.values(x) for x in uniq], self.rows)
            self.evaluations += len(uniq)
            for x, sims in zip(uniq, results):
                self._cache[x.tobytes()] = (self._residuals(sims), sims)
        return [self._cache[x.tobytes()] for x in xs]

    def fun(self, x: np.ndarray) -> np.ndarray:
        r, sims = self.batch([np.asarray(x, float)])[0]
        if r is None:
            # a trial point without a steady state: a huge residual makes the trust region step back
            self.last_failure = self._failure(x, sims)
            return np.full(self.m, 1e6)
        if self.progress:
            self.progress(self, x, r)
        return r

    def steps(self, x: np.ndarray) -> np.ndarray:
        h = np.array([FD_STEP * p.scale for p in self.params])
        hi = np.array([p.x_bounds[1] for p in self.params])
        return np.where(x + h > hi, -h, h)              # backward at an upper bound

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, float)
        h = self.steps(x)
        shifted = []
        for j in range(len(x)):
            xj = x.copy()
            xj[j] += h[j]
            shifted.append(xj)
        res = self.batch([x, *shifted])
        r0 = res[0][0]
        if r0 is None:
            raise FitError(self._failure(x, res[0][1]))
        J = np.empty((len(r0), len(x)))
        for j, (rj, sims) in enumerate(res[1:]):
            if rj is None:
                # the other side, once
                xj = x.copy()
                xj[j] -= h[j]
                rj, sims = self.batch([xj])[0]
                if rj is None:
                    raise FitError(f"the finite difference in {self.params[j].key} failed: "
                                   f"{self._failure(xj, sims)}")
                J[:, j] = (r0 - rj) / h[j]
            else:
                J[:, j] = (rj - r0) / h[j]
        return J


# ---------------------------------------------------------------- the result
@dataclass
class Estimate:
    key: str
    start: float
    value: float
    log: bool
    lower: float
    upper: float
    std_error: float | None           # in the parameter's own units (delta method for log parameters)
    ci95: tuple | None                # (low, high); None: not identified (infinite interval)
    identifiable: bool
    at_bound: bool
    note: str = ""

    def to_dict(self) -> dict:
        return {"key": self.key, "start": self.start, "estimate": self.value, "log_space": self.log,
                "bounds": [self.lower, self.upper], "std_error": self.std_error,
                "ci95": list(self.ci95) if self.ci95 is not None else None, "identifiable": self.identifiable,
                "at_bound": self.at_bound, "note": self.note}


@dataclass
class FitResult:
    scene: Scene
    data: Dataset
    estimates: list[Estimate]
    correlation: np.ndarray
    chi2: float
    dof: int
    s2: float
    absolute_sigma: bool
    singular_values: np.ndarray
    condition: float
    rows: list[dict]                  # per data row: inputs, measured, simulated, residuals
    evaluations: int
    nfev: int
    status: str
    success: bool
    wall_seconds: float
    warnings: list[str] = field(default_factory=list)

    @property
    def identified(self) -> bool:
        return all(e.identifiable for e in self.estimates)

    def fitted_values(self) -> dict:
        return {e.key: e.value for e in self.estimates}

    def fitted_scene(self) -> Scene:
        return self.scene.with_overrides(self.fitted_values())

    def to_dict(self) -> dict:
        return {"scene": self.scene.scene.name, "data": self.data.path, "rows_used": len(self.data.rows),
                "rows_left_out": self.data.dropped, "outputs": self.data.outputs,
                "parameters": [e.to_dict() for e in self.estimates],
                "correlation": self.correlation.tolist(), "chi2": self.chi2, "dof": self.dof, "s2": self.s2,
                "absolute_sigma": self.absolute_sigma, "singular_values": self.singular_values.tolist(),
                "condition_number": self.condition, "identified": self.identified, "rows": self.rows,
                "model_evaluations": self.evaluations, "least_squares_nfev": self.nfev,
                "status": self.status, "converged": self.success, "wall_seconds": self.wall_seconds,
                "warnings": self.warnings}


def row_table(data: Dataset, sims: list[dict]) -> list[dict]:
    """Per row: its inputs, and for each measured output the measured and simulated value, the difference,
    its standard deviation used and the normalised residual."""
    out = []
    for row, sim, ws in zip(data.rows, sims, data.weights()):
        entry = {"line": row.line, "inputs": dict(row.overrides), "error": sim["error"]}
        for output, y, sigma in ws:
            s = sim[output]
            entry[output] = {"measured": y, "simulated": s, "difference": s - y,
                             "relative": (s - y) / abs(y) if y != 0 else None, "std": sigma,
                             "std_given": row.std.get(output) is not None, "residual": (s - y) / sigma}
            est = sim.get("error_estimate")
            if est is not None:          # predictions: the simulated value's estimated numerical error
                entry[output]["error_estimate"] = est.get(output)
        entry["stable"] = sim.get("stable")
        out.append(entry)
    return out


def confidence(params: list[Parameter], x: np.ndarray, J: np.ndarray, r: np.ndarray, absolute_sigma: bool):
    """Estimates with 95% intervals, the correlation matrix, s^2, the singular values and the warnings."""
    from scipy.stats import t as student_t
    m, p = J.shape
    dof = m - p
    chi2 = float(r @ r)
    warnings = []
    if dof <= 0 and not absolute_sigma:
        s2 = math.nan
        warnings.append(f"{m} residuals for {p} parameters: no degrees of freedom left to estimate the scatter, "
                        "so no confidence intervals (add rows, or give *_std columns and --absolute-sigma)")
    else:
        s2 = 1.0 if absolute_sigma else chi2 / dof
    U, S, Vt = np.linalg.svd(J, full_matrices=False)
    smax = S[0] if len(S) else 0.0
    null = S <= RCOND * smax if smax > 0 else np.ones(len(S), bool)
    cond = float(smax / S[-1]) if len(S) and S[-1] > 0 else math.inf
    inv = np.where(null, 0.0, 1.0 / np.where(S > 0, S, 1.0) ** 2)
    cov = (Vt.T * inv) @ Vt * s2
    # the parameters along a null direction (loadings above 0.1 of its unit vector) are not determined
    undetermined = np.zeros(p, bool)
    for k in np.where(null)[0]:
        undetermined |= np.abs(Vt[k]) > 0.1
    tq = float(student_t.ppf(0.975, dof)) if dof > 0 else (1.959963984540054 if absolute_sigma else math.nan)
    estimates = []
    for j, par in enumerate(params):
        value = par.from_x(float(x[j]))
        lo_x, hi_x = par.x_bounds
        at_bound = bool(np.isclose(x[j], lo_x, rtol=0, atol=1e-6 * par.scale)
                        or np.isclose(x[j], hi_x, rtol=0, atol=1e-6 * par.scale))
        sd = math.sqrt(cov[j, j]) if cov[j, j] >= 0 and math.isfinite(cov[j, j]) else math.nan
        note = ""
        ci = None
        std_error = None
        identifiable = True
        if undetermined[j]:
            identifiable = False
            note = (f"not identifiable from these data: J^T W J is singular in its direction (singular values "
                    f"{S[-1] / smax:.1e} of the largest; condition number {cond:.1e}); the estimate is only where "
                    "the search stopped")
        elif not math.isfinite(tq):
            # as many residuals as parameters: determined (J has full rank) but no scatter to size an interval
            note = "no confidence interval (no degrees of freedom)"
        elif not math.isfinite(sd):
            identifiable = False
            note = "not identifiable from these data: its variance is not finite"
        else:
            half = tq * sd
            ci = (par.from_x(x[j] - half), par.from_x(x[j] + half))
            std_error = value * sd if par.log else sd
            wide = half > math.log(WIDE) if par.log else half > WIDE * max(abs(value), par.scale)
            if wide:
                identifiable = False
                span = (f"a factor of {math.exp(min(half, 700.0)):.3g}" if par.log else f"+-{half:.3g}")
                note = (f"not identifiable from these data: its 95% interval spans {span} either way (the "
                        "measured outputs hardly depend on it)")
        if at_bound:
            note = (note + "; " if note else "") + "at a bound of the search: the interval assumes it is not"
        estimates.append(Estimate(par.key, par.start, value, par.log, par.lower, par.upper, std_error, ci,
                                  identifiable, at_bound, note))
    d = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(d, d)
    corr[~np.isfinite(corr)] = math.nan
    np.fill_diagonal(corr, 1.0)
    return estimates, corr, chi2, dof, s2, S, cond, warnings


def run_fit(base: Scene, params: list[Parameter], data: Dataset, engine, absolute_sigma: bool = False,
            max_evaluations: int = 60, progress=None) -> FitResult:
    from scipy.optimize import least_squares
    t0 = time.perf_counter()
    prob = FitProblem(base, params, data, engine, progress)
    if prob.m < 1:
        raise FitError("no measured values to fit")
    x0 = np.array([p.to_x(p.start) for p in params])
    r0, sims0 = prob.batch([x0])[0]
    if r0 is None:
        raise FitError(f"the start point fails: {prob._failure(x0, sims0)}")
    lo = np.array([p.x_bounds[0] for p in params])
    hi = np.array([p.x_bounds[1] for p in params])
    res = least_squares(prob.fun, x0, jac=prob.jacobian, bounds=(lo, hi), method="trf",
                        x_scale=np.array([p.scale for p in params]), ftol=1e-8, xtol=1e-6, gtol=1e-8,
                        max_nfev=max_evaluations)
    x = res.x
    r, sims = prob.batch([x])[0]
    if r is None:
        raise FitError(f"the final point fails: {prob._failure(x, sims)}")
    J = prob.jacobian(x)
    estimates, corr, chi2, dof, s2, S, cond, warnings = confidence(params, x, J, r, absolute_sigma)
    if not res.success or res.status == 0:
        warnings.append(f"the search stopped after {res.nfev} evaluations without meeting its tolerances "
                        f"({res.message}); raise --max-evaluations")
    if prob.last_failure:
        warnings.append(f"some trial points had no steady state (the search stepped back): {prob.last_failure}")
    for e in estimates:
        if not e.identifiable:
            warnings.append(f"{e.key}: {e.note}")
    # the equilibria at the optimum, with their stability (the same tasks: the same numbers)
    sims = evaluate(engine, base, [prob.values(x)], prob.rows, stability=True)[0]
    unstable = [data.rows[i].line for i, s in enumerate(sims) if s["stable"] is False]
    if unstable:
        warnings.append(f"the fitted model's equilibria of line(s) {', '.join(map(str, unstable))} are linearly "
                        "unstable: a robot (or a time-stepped run) does not stay in them")
    rows = row_table(data, sims)
    return FitResult(base, data, estimates, corr, chi2, dof, s2, absolute_sigma, S, cond, rows,
                     prob.evaluations, int(res.nfev), res.message, bool(res.success), time.perf_counter() - t0,
                     warnings)


def predict(scene: Scene, data: Dataset, engine) -> dict:
    """The scene (e.g. the fitted one) on held-out rows: per-row errors and their RMS per output, and each
    simulated value's estimated numerical error (``error_estimate``, relative; the summary's largest)."""
    sims = evaluate(engine, scene, [{}], engine_rows(data), stability=True, error_estimates=True)[0]
    rows = row_table(data, sims)
    summary = {}
    for o in data.outputs:
        rel = [r[o]["relative"] for r in rows if o in r and r[o]["relative"] is not None
               and math.isfinite(r[o]["relative"])]
        z = [r[o]["residual"] for r in rows if o in r and r[o]["std_given"] and math.isfinite(r[o]["residual"])]
        num = [r[o]["error_estimate"] for r in rows if o in r and r[o].get("error_estimate") is not None
               and math.isfinite(r[o]["error_estimate"])]
        summary[o] = {"rms_relative_error": math.sqrt(sum(e * e for e in rel) / len(rel)) if rel else None,
                      "max_relative_error": max((abs(e) for e in rel), default=None),
                      "max_error_estimate": max(num, default=None),
                      "rms_z": math.sqrt(sum(e * e for e in z) / len(z)) if z else None}
    failed = [r["line"] for r in rows if r["error"]]
    return {"data": data.path, "rows": rows, "summary": summary, "failed_lines": failed}
