"""Imported once by the local engine's fork server (:func:`flagbot_sim.sweep.engines.run_local`) before it forks
the workers: numpy, scipy, numba, the physics modules, the beam solver and the kernels of a steady solve are loaded
there, so each worker starts with them instead of importing and loading them afresh (~1.1 s of CPU per worker,
most of a 48-point sweep's worker).

The fork server ends when the sweep's process does (or stops it): then, without the interpreter's teardown of
numba and scipy (~0.3 s), which only kept the output pipes it shares with the sweep open after the sweep ended."""
from __future__ import annotations

import atexit
import os

from ..beam import balance, nonlinear  # noqa: F401  (the beam regimes' solver: numpy; scipy's BVP only on fallback)
from ..physics import error_estimate, model, steady, warmup  # noqa: F401
from . import task  # noqa: F401
from ..workers import FORK_SERVER_PARENT_ENV

try:
    warmup.ensure_compiled(groups=warmup.solve_groups())    # what every point's run_der_steady asks for
except Exception:                     # noqa: BLE001 -- the fork server must start; each worker then loads its own
    pass

if os.environ.get(FORK_SERVER_PARENT_ENV) == str(os.getppid()):
    # the fork server itself (its workers end with os._exit and never run this): holds no file and no state
    # worth a teardown when its sweep is over
    atexit.register(os._exit, 0)
