#!/usr/bin/env python3
"""Regenerate the example data of `flagbot fit` (data/*.csv; what they are: docs/data.md).

    .venv/bin/python data/make_fit_data.py

The paper does not list its measured points (its figures are not in the source), so these rows are synthetic:
the DER steady state of each design, solved by the steady solver that `flagbot fit` itself uses, at the paper's
fitted constants (the scene files' C1, C2, mu), with Gaussian scatter of NOISE of each value added from a fixed
seed, and that standard deviation written beside it. Fitting them recovers the constants they were made with: they
show how the command is used and what it reports, not how well the model matches the real robot.
"""
from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
NOISE = 0.03                      # relative standard deviation of the scatter (and of the *_std columns)
RPMS = [25, 50, 75, 100, 125, 150, 175, 200]   # motor speeds, omega_T in rpm (the paper's range: up to ~200)
#: file -> (scene, number of flagella, seed of its scatter)
FILES = {"design1_n2.csv": ("design1", 2, 2), "design1_n3.csv": ("design1", 3, 3),
         "design2_n2.csv": ("design2", 2, 22), "design2_n3.csv": ("design2", 3, 23)}
HEADER = ["n", "omega_T_rpm", "v", "v_std", "omega_h", "omega_h_std", "comment"]


def model_values(scene: str, n: int, rpms=RPMS) -> list[dict]:
    """The steady v (m/s) and omega_h (rad/s) of ``scene`` with ``n`` flagella at each motor speed: the fit's own
    model evaluation (steady solver, continued along omega_T)."""
    from flagbot_sim.fit.evaluate import evaluate
    from flagbot_sim.fit.pool import Engine
    from flagbot_sim.scene import load_scene
    base = load_scene(scene, [f"robot.n_flagella={n}"])
    rows = [{"index": i, "overrides": {"motor.omega_rpm": float(r)}} for i, r in enumerate(rpms)]
    return [{"v": r["v"], "omega_h": r["omega_h"]} for r in evaluate(Engine("serial"), base, [{}], rows)[0]]


def synthetic_rows(scene: str, n: int, seed: int, rpms=RPMS, noise: float = NOISE) -> list[list]:
    """CSV rows: the model's values with scatter of ``noise`` (relative, Gaussian, from ``seed``), 4 digits (std: 3)."""
    rng = np.random.default_rng(seed)
    out = []
    for rpm, m in zip(rpms, model_values(scene, n, rpms)):
        sv, sw = noise * abs(m["v"]), noise * abs(m["omega_h"])
        v, w = m["v"] + sv * rng.standard_normal(), m["omega_h"] + sw * rng.standard_normal()
        out.append([n, rpm, f"{v:.4g}", f"{sv:.3g}", f"{w:.4g}", f"{sw:.3g}",
                    f"synthetic: {scene} DER steady state + {100 * noise:g}% scatter (seed {seed})"])
    return out


def main() -> int:
    for name, (scene, n, seed) in FILES.items():
        with open(HERE / name, "w", newline="") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(HEADER)
            w.writerows(synthetic_rows(scene, n, seed))
        print(f"wrote {HERE / name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
