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
