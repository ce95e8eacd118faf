"""The OpenBLAS libraries this process has loaded (numpy's and scipy's wheels each bring one): their worker
threads and their thread count.

Two things in the package care. The compile helper may be forked from a process whose only other threads are
OpenBLAS's workers (warmup.py): OpenBLAS stops its pool before a fork (its pthread_atfork handler,
``openblas_fork_handler``) and starts it again at its next call, in parent and child alike. And the steady solver
runs with one BLAS thread (:func:`one_thread`): its matrices are small, and waking a pool costs more than it
computes. Where no OpenBLAS can be found (not Linux, another BLAS) :func:`workers` is 0 and :func:`one_thread`
changes nothing.
"""
from __future__ import annotations

import contextlib
import ctypes
import os

#: thread-count functions by the names OpenBLAS builds export them under (set, get): scipy's wheels' prefix with
#: the 64-bit interface, the prefix alone, the plain names with and without the 64-bit suffix
_THREAD_FUNCTIONS = (("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
                     ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
                     ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
                     ("openblas_set_num_threads", "openblas_get_num_threads"))

#: the largest thread count each library has had while this module watched it (a smaller count set later keeps
#: the pool's threads: OpenBLAS only idles them)
_PEAK: dict[str, int] = {}


def _libraries():
    """(path, handle, set, get) of every OpenBLAS loaded here that exports its thread-count functions."""
    try:
        with open("/proc/self/maps") as f:
            paths = {line.split(maxsplit=5)[5].strip() for line in f
                     if "openblas" in line.lower() and len(line.split(maxsplit=5)) == 6}
    except OSError:
        return
    for path in sorted(p for p in paths if "openblas" in os.path.basename(p).lower()):
        try:
            lib = ctypes.CDLL(path, mode=os.RTLD_NOLOAD | os.RTLD_LAZY)      # (loaded already: no new load)
        except OSError:
            continue
        for set_name, get_name in _THREAD_FUNCTIONS:
            setter, getter = getattr(lib, set_name, None), getattr(lib, get_name, None)
            if setter is not None and getter is not None:
                getter.restype = ctypes.c_int
                yield path, lib, setter, getter
                break


def _count(path: str, getter) -> int:
    n = _PEAK[path] = max(_PEAK.get(path, 1), int(getter()))
    return n


def workers() -> int:
    """The worker threads of the loaded OpenBLAS libraries that stop themselves before a fork (a library
    without the fork handler counts 0: its threads are then foreign to :func:`warmup._can_fork`)."""
    total = 0
    for path, lib, _, getter in _libraries():
        if getattr(lib, "openblas_fork_handler", None) is not None:
            total += _count(path, getter) - 1
    return total


@contextlib.contextmanager
def one_thread():
    """Every loaded OpenBLAS on one thread for the duration, then as it was.

    The steady solver's matrices are small (hundreds of unknowns): SuperLU's and ARPACK's BLAS calls cost more in
    waking and joining threads than they compute, so with the default thread pool a solve with its stability took
    ~2x the CPU, and ARPACK's part ~10x, of one thread's (a sweep's workers run with one thread for the same
    reason). In a process :func:`single_threaded_process` set up it changes nothing, and does not look again."""
    if _single_threaded:
        yield
        return
    restore = []
    for path, _, setter, getter in _libraries():
        before = int(getter())
        _count(path, getter)
        if before != 1:
            setter(1)
            restore.append((setter, before))
    try:
        yield
    finally:
        for setter, before in restore:
            setter(before)


#: the variable OpenBLAS reads its thread count from when it loads
THREADS_VARIABLE = "OPENBLAS_NUM_THREADS"
#: whether single_threaded_process put every OpenBLAS of this process on one thread (then one_thread need not
#: read /proc/self/maps at every steady solve: ~2 ms of a 36 ms `flagbot steady` of design 2, n = 3)
_single_threaded = False


def single_threaded_process() -> bool:
    """One BLAS thread for the rest of this process and the processes it starts, unless the environment sets
    ``OPENBLAS_NUM_THREADS`` already (the user's choice stands); returns whether it changed anything.

    For the package's own programs, called first thing in their ``main``. Every matrix they factorise is small
    (the time step's banded LU and Schur complement, SuperLU, ARPACK, the fits): with the default pool the
    workers spin after every call that woke them, and beside a time-stepped run they took ~9% of the process's
    CPU samples for no work done (design 1, n = 3, 150 rpm, 300 s: 3.35 s of CPU on one thread against 3.6 s,
    same numbers to the last bit). The libraries loaded already (numpy's, when a program's first import brought
    it in) are set at run time; those loaded later (scipy's) and every child process read the variable."""
    global _single_threaded
    if THREADS_VARIABLE in os.environ:
        return False
    os.environ[THREADS_VARIABLE] = "1"
    for path, _, setter, getter in _libraries():
        _count(path, getter)
        setter(1)
    _single_threaded = True
    return True
