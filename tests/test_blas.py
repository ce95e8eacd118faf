"""The loaded OpenBLAS libraries: one thread for the steady solver, and their workers counted for the compile
helper's fork (physics/blas.py)."""
import os

import numpy as np
import pytest
import scipy.linalg

from flagbot_sim.physics import blas


def _counts():
    return {path: int(getter()) for path, _, _, getter in blas._libraries()}


def test_one_thread_sets_every_openblas_to_one_and_restores_it():
    scipy.linalg.lu_factor(np.eye(50) + 0.1)        # scipy's OpenBLAS loaded, as numpy's
    before = _counts()
    if not before:
        pytest.skip("no OpenBLAS found in this process")
    workers = blas.workers()
    with blas.one_thread():
        assert set(_counts().values()) == {1}
        # the pools keep their threads while idled: the fork check still counts them
        assert blas.workers() == workers
    assert _counts() == before


def test_the_workers_counted_are_the_threads_besides_this_one():
    a = np.random.default_rng(1).random((300, 300))
    scipy.linalg.lu_factor(a @ a)                   # both pools awake
    counts = _counts()
    if not counts:
        pytest.skip("no OpenBLAS found in this process")
    assert blas.workers() == sum(n - 1 for n in counts.values())
    # the test process has other threads too (pytest's, rclpy's from earlier tests): at least these
    assert len(os.listdir("/proc/self/task")) >= 1 + blas.workers()


PROGRAM = """
import json, os, sys
import numpy                                    # numpy's OpenBLAS loads before main runs, as in flagbot's
from flagbot_sim.physics import blas
changed = blas.single_threaded_process()
import scipy.linalg                             # scipy's loads after it
scipy.linalg.lu_factor(numpy.eye(40) + 0.1)
counts = sorted(int(g()) for _, _, _, g in blas._libraries())
scans, libraries = [], blas._libraries
blas._libraries = lambda: scans.append(1) or libraries()
with blas.one_thread():                         # (the steady solver's)
    inside = sorted(int(g()) for _, _, _, g in libraries())
print(json.dumps({"changed": changed, "counts": counts, "env": os.environ.get("OPENBLAS_NUM_THREADS"),
                  "scans": len(scans), "inside": inside}))
"""


def _program(env):
    import json
    import subprocess
    import sys
    out = subprocess.run([sys.executable, "-c", PROGRAM], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def test_the_programs_run_every_openblas_on_one_thread_unless_the_user_set_a_count():
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    got = _program(env)
    if not got["counts"]:
        pytest.skip("no OpenBLAS found")
    # both libraries, the one loaded before and the one loaded after, and the children through the variable
    assert got["changed"] and len(got["counts"]) == 2 and set(got["counts"]) == {1} and got["env"] == "1"
    # the steady solver's one_thread then has nothing to do, and does not read the process's maps again
    assert got["scans"] == 0 and set(got["inside"]) == {1}
    mine = _program({**env, "OPENBLAS_NUM_THREADS": "2"})
    assert not mine["changed"] and mine["env"] == "2"
    assert mine["scans"] == 1 and set(mine["inside"]) == {1}   # one_thread still sets the user's pools to one
    if len(os.sched_getaffinity(0)) >= 2:           # (OpenBLAS caps the count at the cores it may use)
        assert set(mine["counts"]) == {2}
