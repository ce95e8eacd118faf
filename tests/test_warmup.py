"""Kernels are compiled (first run) or loaded before a simulation starts, never during it, and the first run
says so once."""
import json
import os
import subprocess
import sys

from flagbot_sim.physics import Simulation, warmup
from flagbot_sim.scene import load_scene

from cli_helpers import ROOT


def test_a_run_after_the_warm_up_compiles_nothing():
    warmup.ensure_compiled()
    before = {d: len(d.signatures) for d in warmup._dispatchers()}
    for scene, extra in (("design1", ["robot.n_flagella=3"]), ("clamped_flagellum", []), ("design2", [])):
        sim = Simulation(load_scene(scene, extra))
        assert sim.compile_seconds == 0.0              # already done in this process
        sim.run(0.2)
        sim.summary()
    after = {d: len(d.signatures) for d in warmup._dispatchers()}
    assert after == before, {d.py_func.__name__: (before[d], after[d]) for d in after if after[d] != before[d]}


def test_first_run_announces_the_compilation_once_and_reports_it_apart(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    runs = []
    for _ in range(2):
        p = subprocess.run([sys.executable, "-m", "flagbot_sim", "run", "design1", "--duration", "0.2", "--json"],
                           cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
        assert p.returncode == 0, p.stderr
        runs.append((json.loads(p.stdout), p.stderr))
    (cold, cold_err), (warm, warm_err) = runs
    assert cold_err.count("compiling kernels (first run only") == 1
    assert "compiling" not in warm_err
    # the compile time is reported on its own and is not in the simulation's wall time
    assert cold["compile_seconds"] > 1.0 > cold["wall_seconds"]
    assert warm["compile_seconds"] < cold["compile_seconds"]
    assert cold["omega_h"] == warm["omega_h"] and cold["v"] == warm["v"]
