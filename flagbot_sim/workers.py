"""The start of the local sweep engine's worker processes, standard library only: ``flagbot sweep`` starts it
first thing, before the command line imports numpy and the scene machinery (~0.2 s that the workers' own ~1.3 s
start then overlaps), and :mod:`flagbot_sim.sweep.engines` makes its pool from the same context.

The workers fork from a fork server that has loaded numpy, scipy, numba, the physics, the beam solver and the
kernels once (:mod:`flagbot_sim.sweep.preload`), where the platform has one; else they are spawned (Windows). The
fork server is a fresh interpreter of its own, not this process: no inherited locks, threads or open files, like
spawn, without each worker's ~1.1 s of imports and kernel loading.
"""
from __future__ import annotations

import os

#: names the sweep process whose fork server is starting (:mod:`flagbot_sim.sweep.preload` checks that it runs in
#: that process's child)
FORK_SERVER_PARENT_ENV = "FLAGBOT_SWEEP_FORK_SERVER_PARENT"
#: one thread per worker process: the workers already use every core, and threaded BLAS would oversubscribe
SINGLE_THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
#: the module the fork server imports before it forks a worker
PRELOAD = "flagbot_sim.sweep.preload"


def single_thread_env() -> None:
    """One thread per library in the processes started after this (they read the variables at their start)."""
    for k in SINGLE_THREAD_ENV:
        os.environ.setdefault(k, "1")


def context():
    """The multiprocessing context the workers start from: the fork server (preloaded) or spawn."""
    import multiprocessing
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    os.environ[FORK_SERVER_PARENT_ENV] = str(os.getpid())
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload([PRELOAD])
    return ctx


def start() -> None:
    """Start the fork server now, with the workers' environment, so that it loads while this process goes on (it
    is started once: the pool made later forks its workers from it). Nothing where the workers are spawned."""
    single_thread_env()
    ctx = context()
    if ctx.get_start_method() == "forkserver":
        from multiprocessing import forkserver
        forkserver.ensure_running()


def wants_local_engine(argv: list[str]) -> bool:
    """Whether the ``flagbot sweep`` command line ``argv`` (after ``sweep``) runs its points on the local engine,
    the default: no ``--engine`` other than ``local``, and no ``-h``/``--help`` (read as argparse will; a wrong
    command line only costs a fork server that ends with this process)."""
    engine = "local"
    for i, item in enumerate(argv):
        if item == "--":
            break
        if item in ("-h", "--help"):
            return False
        if item == "--engine" and i + 1 < len(argv):
            engine = argv[i + 1]
        elif item.startswith("--engine="):
            engine = item.split("=", 1)[1]
    return engine == "local"
