"""``flagbot compile``: every kernel of the simulator into numba's on-disk cache, now, with the time it took (and
the package's Python bytecode, where nothing wrote it)."""
from __future__ import annotations

import os


def register(sub) -> None:
    p = sub.add_parser("compile", help="compile the simulator's kernels into numba's on-disk cache now (first run "
                                       "only; later runs load them), saying how long it took",
                       description="Compile every kernel the simulator uses (or load them, when numba's on-disk "
                                   "cache already holds them) and say how long it took. Every command compiles on "
                                   "first use anyway; this makes it a step of its own, e.g. after an install, so "
                                   "that the first run, the demo's nodes and timed tests start warm. The cache is "
                                   "numba's: next to the package, or NUMBA_CACHE_DIR.")
    p.set_defaults(func=cmd_compile)


def cmd_compile(args) -> int:
    from ..kernels import compile_bytecode, compile_kernels, describe
    cache = os.environ.get("NUMBA_CACHE_DIR", "").strip()
    print(f"flagbot compile: every kernel of the simulator, into numba's cache "
          f"({'NUMBA_CACHE_DIR=' + cache if cache else 'its default: beside the package, or a per-user directory when that is read-only'})",
          flush=True)
    seconds, compiled = compile_kernels()
    print(describe(seconds, compiled))
    written = compile_bytecode()
    if written:
        print(f"python bytecode of {written} modules written (as a pip install writes it: later starts skip "
              "compiling their source)")
    return 0
