"""``python -m flagbot_sim beam SCENE --omega-rpm 50,100,150 [--regime lb|nlb|nlb-nohead] [--json]``.

Reads the same scene files as the DER simulator, so both frameworks use the same parameters. rpm appear only
here, at the edge; everything below is rad/s.
"""
from __future__ import annotations

import math

from ..scene import SceneError, load_scene
from ..units import RPM
from ..beam.balance import REGIMES, solve_balance_curve
from ..beam.params import BeamParams


def parse_rpm_list(text: str) -> list[float]:
    values = []
    for item in text.split(","):
        item = item.strip()
        try:
            value = float(item)
        except ValueError:
            raise SceneError(f"--omega-rpm: {item!r} is not a number; give a comma-separated list such as "
                             "50,100,150") from None
        if not math.isfinite(value):
            raise SceneError(f"--omega-rpm: {item!r} is not a finite number")
        values.append(value)
    return values


def register(subparsers) -> None:
    from ..cliutil import add_scene_arguments
    p = subparsers.add_parser("beam", help="beam-theory estimate (LB / NLB w/o head / NLB) of omega_h, omega_t "
                                           "and speed for motor speeds omega_T")
    add_scene_arguments(p)
    p.add_argument("--omega-rpm", default=None, metavar="W1,W2,...",
                   help="comma-separated motor speeds omega_T in rpm (default: the scene's motor.omega_rpm)")
    p.add_argument("--regime", choices=REGIMES, default="nlb",
                   help="lb: linear beam (closed form); nlb-nohead: nonlinear beam without the head speed in the "
                        "flagellum load (the paper's beam curves); nlb: nonlinear beam with it (default)")
    p.add_argument("--json", action="store_true", help="print one JSON list, an object per omega_T")
    p.set_defaults(func=cmd_beam)


def cmd_beam(args) -> int:
    from ..cliutil import json_output
    scene = load_scene(args.scene, args.overrides)
    params = BeamParams.for_free_robot(scene)
    rpms = parse_rpm_list(args.omega_rpm) if args.omega_rpm is not None else [scene.motor.omega_rpm]
    results = solve_balance_curve(params, [w * RPM for w in rpms], args.regime, raise_on_failure=False)
    if args.json:
        print(json_output([r.to_dict() for r in results]))            # strict JSON: a non-finite value is null
    else:
        print(format_table(scene.scene.name, params, args.regime, results))
    return 0 if all(r.converged for r in results) else 1


def format_table(name: str, params: BeamParams, regime: str, results) -> str:
    lines = [f"beam theory, regime {regime}: scene {name}  n = {params.n}  L = {params.L:g} m  "
             f"eta_p L^4/EI = {params.relaxation_time:.4g} s",
             f"{'omega_T':>16s} {'omega_T_bar':>11s} {'omega_h':>21s} {'omega_t':>21s} {'v_h':>11s} "
             f"{'F_p':>11s} {'F_x':>11s} {'w(L)/L':>8s}",
             f"{'rad/s (rpm)':>16s} {'':>11s} {'rad/s (rpm)':>21s} {'rad/s (rpm)':>21s} {'m/s':>11s} "
             f"{'N':>11s} {'N':>11s} {'':>8s}"]
    for r in results:
        head = f"{r.omega_T:8.4f} ({r.omega_T / RPM:5.1f}) {r.omega_T_bar:11.3f}"
        if not r.converged:
            lines.append(f"{head}  FAILED: {r.message}")
            continue
        lines.append(f"{head} {r.omega_h:10.5f} ({r.omega_h / RPM:8.3f}) {r.omega_t:10.5f} ({r.omega_t / RPM:8.3f}) "
                     f"{r.v_h:11.4e} {r.F_p:11.4e} {r.F_x:11.4e} {r.w_tip_over_L:8.4f}")
    return "\n".join(lines)
