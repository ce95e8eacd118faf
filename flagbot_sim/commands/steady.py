"""``flagbot steady SCENE``: the steady state of a scene solved directly (relative equilibrium), no time stepping.

Prints the same fields as ``flagbot run --json`` (omega_T, omega_h, omega_t, v; Fx, Tx and tip for the clamped
flagellum) plus the Newton residual, the continuation path and the equilibrium's stability.
"""
from __future__ import annotations

import math
import sys

from ..cliutil import add_scene_arguments, json_output, process_age
from ..scene import SceneError, load_scene
from ..units import RPM


def register(sub) -> None:
    p = sub.add_parser("steady", help="solve the steady state (relative equilibrium) directly, without time "
                                      "stepping; with its stability")
    add_scene_arguments(p)
    p.add_argument("--omega-rpm", default=None, metavar="LIST",
                   help="motor speeds in rpm, comma-separated (default: the scene's motor.omega_rpm); each is "
                        "continued from the one before")
    p.add_argument("--no-stability", action="store_true", help="skip the stability analysis")
    p.add_argument("--json", action="store_true", help="one JSON object per motor speed (a list if several)")
    p.set_defaults(func=cmd_steady)


def parse_rpm_list(text: str) -> list[float]:
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise SceneError(f"--omega-rpm must be comma-separated numbers, got {text!r}") from None
    if not values or not all(math.isfinite(v) and abs(v) <= 1e4 for v in values):
        raise SceneError(f"--omega-rpm needs finite values within +-10000 rpm, got {text!r}")
    return values


def solve_scene(scene, omega_rpm: list[float] | None = None, stability: bool = True) -> list[dict]:
    """The steady state of ``scene`` at each motor speed (rpm; default the scene's), as summary dicts. A failure
    at one speed is that entry's ``error``; the next speed starts again from the straight robot."""
    from ..physics.blas import one_thread
    with one_thread():          # small sparse problems: BLAS threads cost more than they compute
        return _solve_scene(scene, omega_rpm, stability)


def _solve_scene(scene, omega_rpm: list[float] | None, stability: bool) -> list[dict]:
    from ..physics import error_estimate, warmup
    from ..physics.medium import coefficients_report
    from ..physics.model import RobotModel
    from ..physics.steady import SteadyFailed, SteadySolver, summary
    scene, accuracy = error_estimate.resolve_accuracy(scene)     # accuracy.rtol: the edge length it chooses
    compile_seconds = warmup.ensure_compiled(groups=warmup.groups_for(scene, time_stepping=False))
    model = RobotModel(scene)
    solver = SteadySolver(model)
    space = error_estimate.SpaceEstimator(scene)      # Richardson's coarse solve, continued like the fine one
    startup = process_age()            # process start to solver ready, as run --json's startup_seconds
    out, prev = [], None
    for rpm in (omega_rpm if omega_rpm is not None else [scene.motor.omega_rpm]):
        w = rpm * RPM
        try:
            if prev is None:            # the space estimate's coarse solve first, the fine one started from it
                sol = space.solve_fine(solver, w)
            else:
                sol = solver.solve(w, start=prev)
        except SteadyFailed as exc:
            out.append({"scene": scene.scene.name, "n_flagella": scene.robot.n_flagella, "omega_T": w,
                        "steady": False, "method": "steady", "error": str(exc),
                        "rft_coefficients": coefficients_report(scene)})
            prev = None
            continue
        row = summary(model, sol)
        row.update(error_estimate.for_steady(model, sol, row, space))
        if accuracy is not None:
            row["accuracy"] = accuracy
        line = error_estimate.warning_line(row)
        row["warnings"] = [line] if line else []       # run --json's field (its warnings), for one schema
        if stability:
            st = solver.stability(sol)
            row["stability"] = st.to_dict()
        row["compile_seconds"] = compile_seconds
        row["startup_seconds"] = startup
        compile_seconds = 0.0
        out.append(row)
        prev = sol
    return out


def format_row(scene, row: dict) -> str:
    w = row["omega_T"]
    head = f"scene {row['scene']}  n = {row['n_flagella']}  omega_T = {w:.4f} rad/s ({w / RPM:.1f} rpm)"
    if "error" in row:
        return head + f"\n  NO EQUILIBRIUM: {row['error']}"
    from ..physics.error_estimate import plus_minus
    lines = [head]
    if scene.clamped:
        lines += [f"  Fx  (axial force on the flagellum)  = {row['Fx']:+.6e} N{plus_minus(row, 'Fx')}",
                  f"  Tx  (torque about the axis)        = {row['Tx']:+.6e} N m{plus_minus(row, 'Tx')}",
                  "  tip (co-rotating frame)            = [" + ", ".join(f"{v:+.6f}" for v in row["tip"]) + "] m"
                  + (f"{plus_minus(row, 'tip')} of L" if plus_minus(row, "tip") else "")]
    else:
        share = f", {100 * row['omega_h'] / w:.1f}% of omega_T" if w else ""
        lines += [f"  omega_h = {row['omega_h']:+.5f} rad/s{plus_minus(row, 'omega_h')} ({row['omega_h'] / RPM:+.2f} "
                  f"rpm{share})",
                  f"  omega_t = {row['omega_t']:+.5f} rad/s{plus_minus(row, 'omega_t')} ({row['omega_t'] / RPM:+.2f} "
                  "rpm)",
                  f"  v       = {1e3 * row['v']:+.4f} mm/s{plus_minus(row, 'v')} ({row['v']:+.6e} m/s, positive = head "
                  "first)",
                  f"  motor torque = {row['motor_torque']:+.6e} N m"]
    if row.get("rft_coefficients"):
        from ..physics.medium import describe
        lines.append("  " + describe(row["rft_coefficients"]))
    st = row.get("stability")
    if st is not None:
        settle = st.get("settling_time_constant")
        lines.append(("  stable: perturbations decay" + (f" (the shape settles with time constant {settle:.3g} s)"
                                                         if settle else "")
                      if st["slowest_rate"] < 0 else
                      "  stable (marginally): the slowest mode neither grows nor decays (an undamped oscillation)")
                     if st["stable"] else
                     f"  UNSTABLE: a perturbation grows at {st['slowest_rate']:.3g} 1/s (a real robot does not "
                     "stay in this state)")
        tw = st.get("twist_oscillation")
        if tw is not None and st["stable"]:
            tc = tw["time_constant"]
            lines.append(f"  the flagella's twist oscillates at {tw['frequency']:.4g} rad/s, "
                         + (f"decaying with time constant {tc:.3g} s" if tc else "undamped")
                         + " (no drag acts on it unless spin_drag is listed; the centreline barely shows it)")
    for line in row.get("warnings", []):
        lines.append(f"  WARNING: {line}")
    lines.append(f"  residual {row['residual']:.2e} N after {row['newton_iterations']} Newton iterations "
                 f"({len(row['continuation'])} continuation step(s)), {1e3 * row['wall_seconds']:.1f} ms")
    return "\n".join(lines)


def cmd_steady(args) -> int:
    scene = load_scene(args.scene, args.overrides)
    rpms = parse_rpm_list(args.omega_rpm) if args.omega_rpm is not None else None
    rows = solve_scene(scene, rpms, stability=not args.no_stability)
    if args.json:
        print(json_output(rows if len(rows) > 1 else rows[0]))
    else:
        print("\n".join(format_row(scene, r) for r in rows))
    failed = any("error" in r for r in rows)
    if failed:
        print("error: no relative equilibrium at some motor speed (see above); a time-stepped run (flagbot run) "
              "shows what the robot does there", file=sys.stderr)
    return 1 if failed else 0
