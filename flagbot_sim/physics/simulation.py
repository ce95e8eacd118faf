"""Simulation: one robot, its stepper, its observer; the facade the CLI, the ROS node and the sweeps drive."""
from __future__ import annotations

import dataclasses
import math
import time
from collections import deque
from typing import Callable

import numpy as np

from . import warmup
from .error_estimate import output_names
from .medium import coefficients_report
from .model import RobotModel
from .observe import V_FLOOR, Observer, Snapshot, SteadyDetector, summary_fields
from .newton import ADVANCED, BELOW_MIN_DT, FIXED_FAILED
from .stepper import Stepper, StepStats

#: rad: a twist angle or the drive angle beyond this has its whole turns taken out at the next sample of the
#: steady-state rule (RobotModel.rebase_angles): its round-off stays ~1e-13 rad however long the run
REBASE_ANGLE = 1024.0


#: with error control the steady-state rule's tolerance is at most this fraction of time.rtol
STEADY_PER_RTOL = 0.1
#: steps are "being cut repeatedly" when at most the last CUT_WINDOW steps took CUT_WINDOW dt reductions or more
#: (one per step on average, or a single step cut that often): Newton keeps failing at the step size asked for,
#: and the run crawls through sub-steps
CUT_WINDOW = 20


class Simulation:
    def __init__(self, scene, steady_window: float | None = None, steady_rtol: float | None = None):
        """``steady_window`` / ``steady_rtol``: the steady-state rule's window (s) and tolerance (default: the
        scene's ``observe`` section; with error control, ``time.rtol`` > 0, at most time.rtol / 10, so that a run
        called steady has settled well inside the accuracy it asked for). A scene with ``accuracy.rtol`` > 0 runs
        with the discretisation that request chooses (``error_estimate.resolve_accuracy``; ``self.scene`` is the
        resolved scene, ``self.accuracy`` what was chosen)."""
        from .error_estimate import resolve_accuracy
        scene, self.accuracy = resolve_accuracy(scene)
        #: time spent compiling (first run) or loading the kernels this scene uses: not simulation time
        self.compile_seconds = warmup.ensure_compiled(groups=warmup.groups_for(scene))
        self.scene = scene
        self.model = RobotModel(scene)
        self.stepper = Stepper(self.model, compiled=warmup.loaded("newton"))
        #: built while groups were deferred (a first run: warmup.ensure_compiled): switch once they are loaded
        self._awaiting_compiled = bool(warmup.DEFERRED)
        self.dt = scene.time.dt
        #: the drive command in force (rad/s): an argument of every step, not state of the driver effect
        self._omega = float(scene.omega_T) if self.model.driver is not None else 0.0
        self.initial = self.model.initial_state()
        self.state = self.initial.copy()
        ob = scene.observe
        self.observer = Observer(self.model, self.state, steady_window or ob.steady_window)
        if steady_rtol is None:
            steady_rtol = ob.steady_rtol
            if scene.time.rtol > 0.0:
                steady_rtol = min(steady_rtol, STEADY_PER_RTOL * scene.time.rtol)
        self.steady_detector = SteadyDetector(steady_window or ob.steady_window, steady_rtol)
        self.last_stats = StepStats(dt_min=self.dt)
        self._prev_state = None
        self._buffers = None           # the compiled steps' arrays (advance), made at the first batch
        #: rad: the whole turns taken out of the state's drive angle (_sample), part of the motor angle
        self.drive_offset = 0.0
        self._zero_counters()

    def _switch_when_compiled(self) -> None:
        """Once the background compile of a first run has delivered the deferred kernels (warmup.swap_in loads
        them, in whichever simulation of the process asks first), step with the compiled Newton solve; the load
        counts as compile time."""
        t0 = time.perf_counter()
        swapped = warmup.swap_in()
        if not warmup.DEFERRED:
            self._awaiting_compiled = False
            self.stepper.use_compiled()
        if swapped:
            self.compile_seconds += time.perf_counter() - t0

    def _zero_counters(self) -> None:
        self.steps = 0
        self.newton_iterations = 0
        self.reductions = 0
        self.wall_seconds = 0.0
        self._recent = deque(maxlen=CUT_WINDOW)     # (dt reductions, smallest sub-step) of the last steps
        self._recent_cuts = 0                       # their dt reductions in total
        self._velocity_errors = deque()             # (t, the step's velocity error estimate) over the last window

    # ---------------------------------------------------------------- command
    @property
    def omega_T(self) -> float:
        return self._omega

    @property
    def has_drive(self) -> bool:
        """The scene has a motor or clamp effect to command: without one omega_T is 0 and set_omega refuses."""
        return self.model.driver is not None

    def set_omega(self, omega_T: float) -> None:
        """Set the motor (or clamp) speed in rad/s; takes effect at the next step."""
        if not math.isfinite(omega_T):
            raise ValueError(f"omega_T must be finite, got {omega_T!r}")
        if self.model.driver is None:
            raise ValueError("this scene has no motor or clamp effect to command")
        self._omega = float(omega_T)

    # ---------------------------------------------------------------- stepping
    @property
    def adaptive(self) -> bool:
        """Error-controlled steps (time.rtol > 0): each step picks its own size."""
        return self.stepper.adaptive

    def step(self, dt: float | None = None, t_end: float = math.inf, *, _resume: StepStats | None = None,
             _python_first: bool = False) -> StepStats:
        """Advance by dt (default: the scene's time.dt; with error control, one step of the size it picks, never
        past t_end). Raises StepFailed and keeps the state if Newton fails. (``_resume`` / ``_python_first``:
        a step the compiled steps of :meth:`advance` began, Stepper.step's.)"""
        if self._awaiting_compiled:
            self._switch_when_compiled()
        w0 = time.perf_counter()
        if dt is None and self.stepper.adaptive:
            new, stats = self.stepper.step_adaptive(self.state, t_end, self._omega, python_first=_python_first)
        else:
            new, stats = self.stepper.step(self.state, self.dt if dt is None else dt, self._omega, resume=_resume,
                                           python_first=_python_first)
        self.observer.record(self.state, new)
        self._prev_state = self.state
        self.state = new
        self.last_stats = stats
        self.steps += 1
        self.newton_iterations += stats.newton_iterations
        self.reductions += stats.reductions
        if len(self._recent) == CUT_WINDOW:
            self._recent_cuts -= self._recent[0][0]
        self._recent.append((stats.reductions, stats.dt_min))
        self._recent_cuts += stats.reductions
        ve = self._velocity_errors
        ve.append((new.t, stats.velocity_error))
        while ve and ve[0][0] < new.t - self.steady_detector.window:
            ve.popleft()
        if self.steady_detector.due(new.t):
            self._sample()
        # the step's whole cost, its observation included (a caller's callback is the caller's)
        self.wall_seconds += time.perf_counter() - w0
        return stats

    def advance(self, max_steps: int, t_end: float = math.inf, t_stop: float = math.inf) -> int:
        """Up to ``max_steps`` steps as :meth:`step` takes them (error control: towards ``t_end``), none from a
        time >= ``t_stop``, with everything :meth:`step` does after each (the observer, the counters, the
        steady-state rule), the same numbers to the last bit: in one compiled call (Stepper.advance) where it
        applies (its kernel loaded: a first run compiles it in the background), else step by step. It also
        stops after a step at which the steady-state rule samples. Returns the steps taken (0: t_stop reached).
        Raises StepFailed and keeps the state of the steps before the failed one."""
        if self._awaiting_compiled:
            self._switch_when_compiled()
        st = self.stepper
        if max_steps <= 0 or not self.time < t_stop:
            return 0
        if max_steps == 1 or not st.can_advance(self.dt, self._omega):
            self.step(t_end=t_end)      # (one step: as fast in the Python code, which passes fewer arrays)
            return 1
        w0 = time.perf_counter()
        b = self._buffers
        if b is None:
            from .stepper import StepBuffers
            b = self._buffers = StepBuffers(st, self.observer)
        b.load(self.state, self._prev_state, self.observer)     # (a caller may have changed them in place)
        det = self.steady_detector
        status = -1
        try:
            status = st.advance(b, self.dt, self._omega, min(max_steps, b.capacity), t_end, t_stop,
                                det.next_check - 1e-9 * det.window)
        except ZeroDivisionError:
            # a folded iterate: that step again, its first attempt in the Python loop (as step's), from the
            # predictor's order it began with (an earlier attempt of it may have changed it)
            st._kept[2] = b.last[12]
        k = int(b.icfg[8])
        if k:
            self._took(b, k)
            if det.due(self.state.t):
                self._sample()
        self.wall_seconds += time.perf_counter() - w0
        if status == ADVANCED:
            return k
        if status == FIXED_FAILED:
            self.step(_resume=st.last_stats(b, failed=True))
        elif status == BELOW_MIN_DT:
            stats = st.last_stats(b)
            raise st._failed(self.state, stats.substep_dts[0], stats)
        else:
            self.step(t_end=t_end, _python_first=True)
        return k + 1

    def _sample(self) -> None:
        """After the step at which the steady-state rule samples (step by step and in batches alike: batches end
        there): its sample, and the whole turns taken out of angles grown beyond REBASE_ANGLE
        (RobotModel.rebase_angles; the same steps either way, so the same numbers)."""
        st = self.state
        self.steady_detector.update(st.t, *self._steady_sample())
        n = 3 * self.model.net.n_nodes
        if abs(st.drive_angle) > REBASE_ANGLE or (len(st.q) > n and np.abs(st.q[n:]).max() > REBASE_ANGLE):
            self.drive_offset += self.model.rebase_angles([st, self._prev_state])

    def _took(self, b, k: int) -> None:
        """Simulation.step's work after each of the k steps the compiled steps took into ``b``."""
        rows = b.out[:k]
        self.state, self._prev_state = b.states()
        ob, o = self.observer, b.ob
        ob.phi_h, ob.phi_t, ob.rate_h, ob.rate_t, ob.speed = (float(x) for x in o[:5])
        ob.axis_now = o[5:8].copy()
        ob._pos = o[8:11].copy()
        ob.recorded(rows)
        self.last_stats = self.stepper.last_stats(b)
        self.steps += k
        self.newton_iterations += int(rows[:, 2].sum())
        self.reductions += int(rows[:, 8].sum())
        self._recent.extend(zip(rows[-CUT_WINDOW:, 8].astype(int).tolist(), rows[-CUT_WINDOW:, 9].tolist()))
        self._recent_cuts = sum(r for r, _ in self._recent)
        ve = self._velocity_errors
        ve.extend(zip(rows[:, 0].tolist(), rows[:, 1].tolist()))
        while ve and ve[0][0] < self.state.t - self.steady_detector.window:
            ve.popleft()

    def run(self, duration: float, callback: Callable[["Simulation"], None] | None = None,
            every: int | Callable[[], int] = 1) -> None:
        """Advance by ``duration`` of simulated time: whole steps of time.dt (rounded to a whole number of them),
        or error-controlled steps ending exactly at the end. ``callback`` is called after the first step, then
        after every ``every``-th (1: each; a function: asked after each call for the steps to the next), and after
        the last; between its calls the steps run in batches (:meth:`advance`)."""
        done = 0
        next_call = 1                      # the step count at which the callback is called next

        def called() -> None:
            nonlocal next_call
            callback(self)
            next_call = done + max(1, int(every() if callable(every) else every))

        def batch() -> int:               # steps to the next call of the callback
            return 1 << 30 if callback is None else max(1, next_call - done)
        if self.stepper.adaptive:
            t_end = self.time + duration
            t_stop = t_end - 1e-12 * max(1.0, abs(t_end))
            while self.time < t_stop:
                done += self.advance(batch(), t_end=t_end, t_stop=t_stop)
                if callback is not None and (done >= next_call or not self.time < t_stop):
                    called()
            return
        n = max(1, int(round(duration / self.dt)))
        while done < n:
            done += self.advance(min(batch(), n - done))
            if callback is not None and (done >= next_call or done == n):
                called()

    def run_until_steady(self, t_max: float, callback: Callable[["Simulation"], None] | None = None) -> bool:
        """Step until the steady-state rule holds or the simulated time reaches t_max; True if steady (in batches
        of steps between the rule's samples without a ``callback``, called after each step)."""
        t_stop = t_max - 1e-9 * self.dt
        while not self.steady_detector.steady and self.time < t_stop:
            if callback is None:
                self.advance(1 << 30, t_stop=t_stop)
            else:
                self.step()
                callback(self)
        return self.steady_detector.steady

    def reset(self) -> None:
        """Back to the initial state with the scene's command; counters and steady-state rule start over."""
        self.state = self.initial.copy()
        self._prev_state = None
        self.stepper.reset()
        if self.model.driver is not None:
            self._omega = float(self.scene.omega_T)
        self.observer.reset(self.state)
        self.steady_detector.reset()
        self.drive_offset = 0.0
        self._zero_counters()

    @property
    def time(self) -> float:
        return self.state.t

    @property
    def motor_angle(self) -> float:
        """Integrated drive command (rad): the motor's natural-twist angle, or the clamp's rotation angle (with
        the whole turns a long run took out of the state's: _sample)."""
        return float(self.state.drive_angle + self.drive_offset)

    @property
    def steady(self) -> bool:
        return self.steady_detector.steady

    @property
    def cutting(self) -> bool:
        """Steps are being cut repeatedly: the last CUT_WINDOW steps (or fewer) took CUT_WINDOW dt reductions or
        more."""
        return self._recent_cuts >= CUT_WINDOW

    @property
    def recent_reductions(self) -> int:
        """dt reductions of the last CUT_WINDOW steps."""
        return self._recent_cuts

    def cutting_report(self) -> str:
        """What the cut steps look like, with the numbers (for a warning while :attr:`cutting`)."""
        num = self.scene.numerics
        return (f"steps are being cut repeatedly: {self._recent_cuts} dt reductions in the last "
                f"{len(self._recent)} steps ({self.reductions} in {self.steps} steps so far), sub-steps down to "
                f"{min(h for _, h in self._recent):.3g} s of time.dt = {self.dt:g} s: Newton does not converge "
                f"within numerics.max_iterations = {num.max_iterations} at the step asked for (tolerance "
                f"{self.model.force_tol:.3g} N), so the run is slow")

    def diagnostics(self) -> dict:
        """The numbers a live device reports about its run, raw and in SI (sim_node formats them for
        /diagnostics): the command, the last step's Newton iterations, residual and smallest sub-step, the force
        tolerance in force, dt, the dt reductions (in total and of the last CUT_WINDOW steps), the steps taken, the
        scene and its flagella, the steady-state rule's verdict and change, the integrator and time.rtol."""
        st = self.last_stats
        return {"omega_T": self.omega_T, "newton_iterations_last_step": st.newton_iterations,
                "residual": st.residual, "newton_tolerance": self.model.force_tol, "dt": self.dt,
                "dt_min_last_step": st.dt_min, "dt_reductions_total": self.reductions,
                "dt_reductions_recent": self.recent_reductions, "steps": self.steps, "scene": self.scene.scene.name,
                "n_flagella": self.scene.robot.n_flagella, "steady": self.steady,
                "steady_change": self.steady_detector.change, "integrator": self.stepper.integrator.name,
                "error_control_rtol": self.stepper.rtol}

    # ---------------------------------------------------------------- error estimates
    def velocity_error(self) -> float:
        """The mean over the steps of the last steady window of each step's estimated relative error of the
        velocity the medium sees (``StepStats.velocity_error``: the integrator's own local error estimate); NaN
        before any step had one. physics/error_estimate.py turns it into each output's time error."""
        vals = [e for _, e in self._velocity_errors if not math.isnan(e)]
        return float(np.mean(vals)) if vals else math.nan

    def settling_error(self) -> dict[str, float]:
        """Each output's estimated relative distance to its final value that the run has not covered (the
        steady-state rule's extrapolated tail of each quantity, or its change over the last window where the
        approach is not clearly geometric; NaN before the rule has compared three samples). Clamped: Fx, Tx and
        the tip over L; free robot: omega_h, omega_t, v."""
        tails = self.steady_detector.tails
        if len(tails) == 0:
            return {k: math.nan for k in output_names(self.scene)}
        if self.scene.clamped:
            return {"Fx": float(tails[3]), "Tx": float(tails[4]), "tip": float(np.linalg.norm(tails[:3]))}
        ss = self.steady_state()
        w_h, w_t = abs(ss["omega_h"]), abs(ss["omega_t"])
        # omega_t = omega_T - omega_h: its error is omega_h's, relative to omega_t
        wt = float(tails[0]) * w_h / w_t if w_t > 0 else math.nan
        return {"omega_h": float(tails[0]), "omega_t": wt, "v": float(tails[1])}

    # ---------------------------------------------------------------- observations
    def snapshot(self) -> Snapshot:
        snap = self.observer.snapshot(self.state, self._prev_state, self.omega_T, self.motor_torque())
        if self.drive_offset:                          # the motor angle published: the whole integral
            snap = dataclasses.replace(snap, drive_angle=snap.drive_angle + self.drive_offset)
        return snap

    def positions(self) -> np.ndarray:
        return self.observer.x(self.state)

    def motor_torque(self) -> float:
        """Torque the motor applies to the shaft (N m; positive drives a positive omega_T): the motor hinge's
        twisting moment. At steady state it equals the head's Stokes torque C2 8 pi mu R_h^3 omega_h."""
        return self.model.motor_torque(self.state.q, self.state.frames, self.state.drive_angle)

    def flagella_centrelines(self) -> list[np.ndarray]:
        x = self.positions()
        return [x[nodes] for nodes in self.model.net.flagella_nodes]

    def rigid_polylines(self) -> dict[str, np.ndarray]:
        """Head (x0-x1-x2) and plate arms + sockets, for drawing."""
        net, x = self.model.net, self.positions()
        out = {}
        if len(net.head_nodes):
            out["head"] = x[net.head_nodes]
        arms = []
        for pe, se in zip(net.plate_edges, net.socket_edges):
            a, b = net.edges[pe]
            _, c = net.edges[se]
            arms.append(x[[a, b, c]])
        out["plate"] = arms
        return out

    def medium_force_on_flagella(self) -> tuple[np.ndarray, np.ndarray]:
        """Total RFT force (N) and torque about the origin (N m) on the flagella at the current state."""
        if self._prev_state is None:
            return np.zeros(3), np.zeros(3)
        return self.model.medium_force(self.positions(), self.state.v)

    def clamp_frame_tip(self) -> np.ndarray:
        """Flagellum tip in the frame co-rotating with the clamp (clamp at (0, R_d, 0))."""
        return self.observer.corotating_tip(self.state)

    def _steady_sample(self) -> tuple[np.ndarray, np.ndarray]:
        """The quantities the steady-state rule watches, and their scales (see SteadyDetector)."""
        if self.scene.clamped:
            F, T = self.medium_force_on_flagella()
            tip = self.clamp_frame_tip()
            L = self.scene.flagellum.length
            return (np.array([*tip, F[0], T[0]]),
                    np.array([L, L, L, max(abs(F[0]), 1e-30), max(abs(T[0]), 1e-30)]))
        r = self.observer.window_rates(self.steady_detector.window)
        if r is None:
            return np.array([math.nan, math.nan]), np.ones(2)
        w_floor = max(1e-3 * abs(self.omega_T), 1e-12)
        return (np.array([r["omega_h"], r["v"]]),
                np.array([max(abs(r["omega_h"]), w_floor), max(abs(r["v"]), V_FLOOR)]))

    def steady_state(self) -> dict:
        """Rates over the last steady window (or over the whole run if shorter) and the steady-state verdict."""
        window = self.steady_detector.window
        last = self.observer.window_rates(window)
        span = window
        if last is None:
            span = self.observer.t_now - self.observer.t_first
            last = self.observer.window_rates(span) if span > 0 else None
            if last is None:
                return {"omega_h": 0.0, "omega_t": 0.0, "v": 0.0, "steady": False, "window": 0.0}
        last.update(steady=self.steady, window=span)
        return last

    def summary(self) -> dict:
        """Steady-state outputs and run statistics (SI units)."""
        ss = self.steady_state()
        det = self.steady_detector
        rates = {"omega_T": self.omega_T, "omega_h": ss["omega_h"], "omega_t": ss["omega_t"], "v": ss["v"],
                 "steady": ss["steady"]}
        run = {
            "steady_change": det.change,
            "steady_rtol": det.rtol,
            "window": ss["window"],
            "time": self.state.t,
            "steps": self.steps,
            "newton_iterations": self.newton_iterations,
            "dt_reductions": self.reductions,
            "wall_seconds": self.wall_seconds,
            "real_time_factor": self.state.t / self.wall_seconds if self.wall_seconds > 0 else None,
            "compile_seconds": self.compile_seconds,
            "kernels": warmup.kernels_mode(),
            "rft_coefficients": coefficients_report(self.scene),
        }
        if self.accuracy is not None:
            run["accuracy"] = self.accuracy
        mass = float(self.model.net.node_mass.sum())
        if self.scene.clamped:
            return summary_fields(self.scene, mass, rates, run, clamp=(*self.medium_force_on_flagella(),
                                                                self.clamp_frame_tip()))
        return summary_fields(self.scene, mass, rates, run, motor_torque=self.motor_torque())
