"""Imported once by the local engine's fork server (:func:`flagbot_sim.sweep.engines.run_local`) before it forks
the workers: numpy, scipy, numba, the physics modules and the kernels are loaded there, so each worker starts with
them instead of importing and loading them afresh (~1.1 s of CPU per worker, most of a 48-point sweep's worker)."""
from __future__ import annotations

from ..physics import error_estimate, model, steady, warmup  # noqa: F401  (loaded for the workers)
from . import task  # noqa: F401

try:
    warmup.ensure_compiled()          # what every point's run_der_steady asks for
except Exception:                     # noqa: BLE001 -- the fork server must start; each worker then loads its own
    pass
