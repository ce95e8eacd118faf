"""``flagbot run SCENE``: the DER simulation of a scene, its progress, and the steady-state summary (text or
``--json``); ``--view`` serves the run to the Foxglove live view (:mod:`flagbot_sim.view.cli`)."""
from __future__ import annotations

import time

from ..cliutil import add_scene_arguments, finite_text, json_output, process_age
from ..physics.medium import normalise_omega, normalise_speed
from ..scene import SceneError, TimeSection, load_scene
from ..units import RPM


def register(sub, view_options: bool = True) -> None:
    """``flagbot run``; ``view_options`` False (``flagbot --help``) leaves out the ``--view`` options, which would
    import their module."""
    p = sub.add_parser("run", help="run the DER simulation of a scene and report steady-state outputs")
    add_scene_arguments(p)
    p.add_argument("--duration", type=float, default=None, help="simulated seconds (default: the scene's)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a summary")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    if view_options:
        from ..view.args import add_view_arguments
        add_view_arguments(p)
    p.set_defaults(func=cmd_run)


#: wall seconds of stepping between two progress updates of ``flagbot run`` (a tenth of the bar's fastest redraw)
PROGRESS_BATCH = 0.02


def progress_batch(sim) -> int:
    """Steps to the next progress update: PROGRESS_BATCH of wall time at the stepping rate so far, at least 10."""
    rate = sim.steps / sim.wall_seconds if sim.wall_seconds > 0 else 0.0
    return max(10, int(PROGRESS_BATCH * rate))


def cmd_run(args) -> int:
    scene = load_scene(args.scene, args.overrides)          # before the simulator's imports: a refusal is quick
    from ..physics import Simulation, StepFailed
    from ..progress import ProgressBar

    duration = args.duration if args.duration is not None else scene.time.duration
    longest = TimeSection.__dataclass_fields__["duration"].metadata["le"]
    if not (0 < duration <= longest):
        raise SceneError(f"--duration must be a positive number of seconds up to {longest:g}, got {duration!r}")
    if scene.time.rtol == 0.0 and duration < 0.5 * scene.time.dt:
        raise SceneError(f"--duration {duration:g} s is shorter than half a time step (time.dt = "
                         f"{scene.time.dt:g} s): fixed-step runs take whole steps")
    sim = Simulation(scene)
    startup = process_age()
    bar = ProgressBar(duration, label=scene.scene.name, enabled=not args.json and not args.quiet)
    n_steps = max(1, int(round(duration / scene.time.dt)))     # as Simulation.run counts them
    from ..view.cli import RunView
    view = RunView.from_args(args)      # --view: the run served to the Foxglove app (view/cli.py), else None

    warnings: list[str] = []

    def progress(s) -> None:
        if view is not None:
            view.tick(s)
        if s.cutting and not warnings:        # once: what slows the run, with the numbers
            warnings.append(s.cutting_report())
            bar.note(f"warning: {warnings[0]}")
        k = s.steps - 1
        if view is None or k % 10 == 0 or k == n_steps - 1:     # (a live view calls back every step)
            ob = s.observer
            bar.update(s.time, lambda: f"newton {s.last_stats.newton_iterations}  "
                                       f"w_h {finite_text(ob.rate_h, '+.3f')}  w_t {finite_text(ob.rate_t, '+.3f')} "
                                       f"rad/s  v {finite_text(1e3 * ob.speed, '+.3f')} mm/s")

    error = None
    paced0 = None                        # when the live view's pacing starts (after it waited for a client)
    try:
        if view is not None:
            view.start(sim)
            paced0 = time.perf_counter()
        # the steps between two progress updates run in one compiled call: as many as take PROGRESS_BATCH of
        # wall time at the rate so far (the bar draws at most every 0.2 s), at least 10 (it used to update every
        # 10th step); a live view is served every step
        sim.run(duration, callback=progress, every=1 if view is not None else lambda: progress_batch(sim))
    except StepFailed as exc:
        error = str(exc)
    except KeyboardInterrupt:
        error = f"interrupted at t = {sim.time:.3f} s"
    finally:
        if view is not None:
            view.close(sim)
    bar.close()
    out = sim.summary()
    if not error and sim.steps:
        from ..physics import error_estimate
        out.update(error_estimate.for_run(sim, out))
        line = error_estimate.warning_line(out)
        if line:
            warnings.append(line)
    out.setdefault("startup_seconds", startup)
    if paced0 is not None:
        # the stepping's own wall time and real-time factor stay as they are; the view's pacing is apart
        paced = time.perf_counter() - paced0
        out["paced_wall_seconds"] = paced
        out["paced_real_time_factor"] = sim.time / paced if paced > 0 else None
    if warnings:
        out["warnings"] = warnings
    if error:
        out["error"] = error
    if args.json:
        print(json_output(out))
    else:
        print(format_summary(scene, out))
    return 1 if error else 0


def format_summary(scene, out: dict) -> str:
    """The human-readable run summary. Values that are missing (None: no step taken, no steady window yet) or
    not finite print as '--', never as 'nan'."""
    def g(key, spec, scale=1.0):
        v = out.get(key)
        return finite_text(None if v is None else scale * v, spec)

    from ..physics.error_estimate import plus_minus
    omega_T = out["omega_T"]
    lines = [f"scene {out['scene']}  n = {out['n_flagella']}  omega_T = {g('omega_T', '.4f')} rad/s "
             f"({g('omega_T', '.1f', 1 / RPM)} rpm)  t = {g('time', '.3f')} s"]
    if scene.clamped:
        tip = out.get("tip") or []
        lines += [f"  Fx  (axial force on the flagellum)  = {g('Fx', '+.6e')} N{plus_minus(out, 'Fx')}",
                  f"  Tx  (torque about the axis)        = {g('Tx', '+.6e')} N m{plus_minus(out, 'Tx')}",
                  "  tip (co-rotating frame)            = [" + ", ".join(finite_text(v, "+.6f") for v in tip) + "] m"
                  + (f"{plus_minus(out, 'tip')} of L" if plus_minus(out, "tip") else "")]
    else:
        omega_h, v = out.get("omega_h"), out.get("v")
        share = 100 * omega_h / omega_T if omega_h is not None and omega_T else None
        lines += [f"  omega_h = {g('omega_h', '+.5f')} rad/s{plus_minus(out, 'omega_h')} "
                  f"({g('omega_h', '+.2f', 1 / RPM)} rpm, {finite_text(share, '.1f')}% of omega_T)",
                  f"  omega_t = {g('omega_t', '+.5f')} rad/s{plus_minus(out, 'omega_t')} "
                  f"({g('omega_t', '+.2f', 1 / RPM)} rpm)",
                  f"  v       = {g('v', '+.4f', 1e3)} mm/s{plus_minus(out, 'v')} ({g('v', '+.6e')} m/s, positive = "
                  "head first)",
                  f"  normalised: omega_T_bar = {finite_text(normalise_omega(scene, omega_T), '.2f')}, "
                  f"v_bar = {finite_text(None if v is None else normalise_speed(scene, v), '.4f')}"]
    if out.get("rft_coefficients"):
        from ..physics.medium import describe
        lines.append("  " + describe(out["rft_coefficients"]))
    verdict = "yes" if out.get("steady") else "NO (run longer)"
    if not out.get("steady") and out.get("error_estimate"):
        # the +/- bars are the numerical error of this transient state, not its distance from the steady state
        verdict = ("NO (run longer): the +/- above are the numerical error alone; how far these values still are "
                   "from the steady state is not estimated")
    lines.append(f"  steady over the last {g('window', '.2f')} s: {verdict}")
    timing = f"{g('wall_seconds', '.2f')} s wall, real-time factor {g('real_time_factor', '.2f')}"
    if out.get("startup_seconds") is not None:
        timing += f", start-up {g('startup_seconds', '.2f')} s"
        if (out.get("compile_seconds") or 0.0) >= 0.05:
            timing += f" (compiling or loading kernels: {g('compile_seconds', '.2f')} s of it)"
    if out.get("paced_wall_seconds") is not None:
        timing += (f"; paced for the live view: {g('paced_wall_seconds', '.2f')} s wall, real-time factor "
                   f"{g('paced_real_time_factor', '.2f')}")
    lines.append(f"  {out['steps']} steps, {out['newton_iterations']} Newton iterations, "
                 f"{out['dt_reductions']} dt reductions, {timing}")
    for w in out.get("warnings", []):
        lines.append(f"  WARNING: {w}")
    if "error" in out:
        lines.append(f"  ERROR: {out['error']}")
    return "\n".join(lines)
