"""Which kernel groups this process runs without for now: a first run starts on the interpreted twins of the
background groups while a background process compiles them (warmup.py: ensure_compiled defers them, swap_in loads
them). The callers of those kernels ask here which one to call. A module of its own, with no imports from the
package, so that the solver, the stepper and the observer can ask without importing warmup (which imports them)."""
from __future__ import annotations

import contextlib
import threading

#: background groups this process runs without for now (their callers use the interpreted twins)
DEFERRED: set[str] = set()
#: per thread: whether the caller wants the compiled kernels whatever is deferred (a warm-up: compiled_calls)
_local = threading.local()


def deferred(group: str) -> bool:
    """Whether this thread runs without the group's compiled kernels for now: its callers then call the
    interpreted twins (same numbers, slower) until warmup.swap_in loads them."""
    return group in DEFERRED and not getattr(_local, "compiled", False)


def tiered(group: str, dispatcher):
    """``dispatcher``, or its interpreted twin (jit.interpreted) while ``group`` is deferred."""
    if deferred(group):
        from .jit import interpreted
        return interpreted(dispatcher)
    return dispatcher


@contextlib.contextmanager
def compiled_calls():
    """In this thread, the deferred groups' callers call the compiled kernels (a warm-up compiles or loads them:
    a background process forked from a first run inherits its deferred groups, and swap_in loads them while they
    are still deferred); other threads go on with the twins."""
    before = getattr(_local, "compiled", False)
    _local.compiled = True
    try:
        yield
    finally:
        _local.compiled = before
