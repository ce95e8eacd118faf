"""How the package compiles a function with numba: the two decorators every kernel uses.

Both cache the machine code on disk (see warmup.py). What they leave out is what the package never calls, and
each costs compile time on a first run (docs/startup.md has the measurements):

* ``kernel``: a function called from Python. numba would also build a C-callable (cfunc) wrapper for it,
  which nothing here uses.
* ``stage``: a function called only from other compiled functions (a stage of a kernel, a scalar formula).
  Its code is linked into each caller, so it needs no Python wrapper either: boxing and unboxing every
  argument is a large share of a small function's code.

Neither changes the arithmetic: the same machine code runs, to the last bit.
"""
from numba import njit

kernel = njit(cache=True, no_cfunc_wrapper=True)
stage = njit(cache=True, no_cfunc_wrapper=True, no_cpython_wrapper=True)
