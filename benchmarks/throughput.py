#!/usr/bin/env python3
"""Throughput of the DER simulator: steps per second and real-time factor at the paper's discretisation.

    python benchmarks/throughput.py [--warmup 3] [--measure 5] [--repeat 3]

Each case is first run through its start-up transient (--warmup seconds of simulated time), then timed over
--measure seconds of simulated time, --repeat times; the median is reported with min and max.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from flagbot_sim.physics import Simulation  # noqa: E402
from flagbot_sim.scene import load_scene  # noqa: E402

CASES = [("design1", 2), ("design1", 3), ("design2", 2), ("design2", 3)]


def measure(scene: str, n: int, warmup: float, span: float) -> dict:
    sim = Simulation(load_scene(scene, [f"robot.n_flagella={n}"]))
    sim.run(warmup)
    steps0, it0 = sim.steps, sim.newton_iterations
    t0 = time.perf_counter()
    sim.run(span)
    wall = time.perf_counter() - t0
    steps = sim.steps - steps0
    return {"steps_per_s": steps / wall, "rtf": span / wall, "newton_per_step": (sim.newton_iterations - it0) / steps,
            "ndof": sim.model.ndof}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--warmup", type=float, default=3.0)
    ap.add_argument("--measure", type=float, default=5.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print(f"dt = 1e-2 s, 4.11 mm edges, omega_T = 100 rpm; median (min..max) of {args.repeat} runs")
    print(f"{'scene':8s} {'n':>2s} {'DOF':>5s} {'steps/s':>22s} {'real-time factor':>22s} {'Newton it/step':>15s}")
    for scene, n in CASES:
        rs = [measure(scene, n, args.warmup, args.measure) for _ in range(args.repeat)]
        sps = sorted(r["steps_per_s"] for r in rs)
        rtf = sorted(r["rtf"] for r in rs)
        print(f"{scene:8s} {n:2d} {rs[0]['ndof']:5d} {statistics.median(sps):8.1f} ({sps[0]:5.1f}..{sps[-1]:5.1f}) "
              f"{statistics.median(rtf):8.2f} ({rtf[0]:5.2f}..{rtf[-1]:5.2f}) "
              f"{statistics.median(r['newton_per_step'] for r in rs):15.2f}", flush=True)


if __name__ == "__main__":
    main()
