"""Which kernel groups this process runs without for now: a first run starts on the interpreted twins of the
background groups while a background process compiles them (warmup.py: ensure_compiled defers them, swap_in loads
them). The callers of those kernels ask here which one to call. A module of its own, with no imports from the
package, so that the solver, the stepper and the observer can ask without importing warmup (which imports them)."""
from __future__ import annotations

#: background groups this process runs without for now (their callers use the interpreted twins)
DEFERRED: set[str] = set()


def deferred(group: str) -> bool:
    """Whether this process runs without the group's compiled kernels for now: its callers then call the
    interpreted twins (same numbers, slower) until warmup.swap_in loads them."""
    return group in DEFERRED


def tiered(group: str, dispatcher):
    """``dispatcher``, or its interpreted twin (jit.interpreted) while ``group`` is deferred."""
    if group in DEFERRED:
        from .jit import interpreted
        return interpreted(dispatcher)
    return dispatcher
