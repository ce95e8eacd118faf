"""Wall time of beam-theory solves: ``python -m flagbot_sim.bench.beam_timing [--repeat 20]``.

A measurement script, not a test (timings depend on the machine); docs/beam.md quotes its output.
Each full balance solve starts cold (no warm start), as a ROS beam_node answering one new omega_T would.
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np
import scipy

from ..scene import load_scene
from ..units import RPM
from ..beam.balance import REGIMES, solve_balance, solve_balance_curve
from ..beam.nonlinear import solve_nlb
from ..beam.params import BeamParams


def _times(fn, repeat: int) -> list[float]:
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--rpm", type=float, default=100.0)
    args = ap.parse_args(argv)
    print(f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
          f"{platform.machine()}, {os.cpu_count()} CPUs; {args.repeat} repeats, cold starts")
    print(f"{'scene':8s} {'n':>2s} {'regime':10s} {'median ms':>9s} {'max ms':>8s} {'BVP solves':>10s}")
    for name in ("design1", "design2"):
        for n in (2, 3):
            params = BeamParams.from_scene(load_scene(name, [f"robot.n_flagella={n}"]))
            for regime in REGIMES:
                res = solve_balance(params, args.rpm * RPM, regime)
                t = _times(lambda: solve_balance(params, args.rpm * RPM, regime), args.repeat)
                print(f"{name:8s} {n:2d} {regime:10s} {1e3 * statistics.median(t):9.2f} {1e3 * max(t):8.2f} "
                      f"{res.bvp_solves:10d}")
    params = BeamParams.from_scene(load_scene("design1"))
    omega_t = solve_balance(params, args.rpm * RPM, "nlb").omega_t
    t = _times(lambda: solve_nlb(params, omega_t, 0.0), args.repeat)
    print(f"one NLB flagellum solve (design1, omega_t = {omega_t:.4f} rad/s): median "
          f"{1e3 * statistics.median(t):.2f} ms")
    rpms = np.linspace(10.0, 250.0, 25)
    t = _times(lambda: solve_balance_curve(params, rpms * RPM, "nlb"), max(1, args.repeat // 5))
    print(f"NLB curve of {rpms.size} omega_T (design1, 10..250 rpm, warm-started): median "
          f"{1e3 * statistics.median(t):.1f} ms, {1e3 * statistics.median(t) / rpms.size:.2f} ms per point")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
