"""Compile (first run) or load (every later run) the compiled kernels before a simulation starts.

numba compiles a kernel on its first call and caches the machine code on disk (next to the package, or in a
per-user cache directory when the install is read-only: numba's own fallback, ``NUMBA_CACHE_DIR`` overrides
both). Without this module the first steps of the first run would pay ~8 s of compilation, silently, and count
it as simulation time. :func:`ensure_compiled` instead

* says so in one line ("compiling kernels (first run only)") when the cache is empty,
* compiles in two processes at once, because the kernels fall into two independent groups: the model's springs
  (frames, strains, bend-twist, stretch) here, and the solver's, predictor's, RFT's and clamp's in a helper
  process that never builds an elastic model; on a 2-core machine that halves the wait,
* then loads every kernel into this process, so that stepping starts with nothing left to compile or load.

Its time is reported as ``compile_seconds``, apart from the simulation's wall time and real-time factor.
Both groups drive the package's own code paths on tiny models, so the compiled signatures are the ones a run
uses (a test checks that a run after the warm-up compiles nothing).
"""
from __future__ import annotations

import os
import subprocess
import sys
import time
from typing import Callable

import numpy as np

_DONE = False
SPRINGS, SOLVER = "springs", "solver"


def kernels_mode() -> str:
    """'compiled', or 'python' under numba's debugging switch NUMBA_DISABLE_JIT=1."""
    from numba.core import config
    return "python" if config.DISABLE_JIT else "compiled"


def _tiny_scene(overrides: list[str]):
    from ..scene import load_scene
    return load_scene("design1", ["flagellum.length=0.02", "flagellum.edge_length=0.005", *overrides])


def warm_springs() -> None:
    """Frames, rest strains, stretch and bend-twist springs: residual and Jacobian of a tiny robot (the energy
    alone, which only the tests evaluate, compiles where it is used)."""
    from .model import RobotModel
    from .stepper import ImplicitEuler
    # (the head torque's kernel is the solver group's: it balances the two groups' compile times)
    model = RobotModel(_tiny_scene(["scene.effects=['inertia','head_drag','motor']"]))
    st = model.initial_state()
    ctx = model.context(st.q + 1e-6, st, ImplicitEuler().plan(st, 1e-2, 0.1))
    model.residual(ctx)
    model.jacobian(ctx)


def warm_solver() -> None:
    """Arrow factor/solve, predictor, RFT and the clamp's twist angles, on a network alone (no elastic model)."""
    from .assembly import SparsePattern
    from .effects import RFTDrag, StepContext
    from .elastic import spring_dofs, tangent_torque
    from .frames import EdgeFrames, twist_for_director, unit_rows
    from .linsolve import ArrowSolver, flagellum_chains
    from .model import State
    from .network import build_network
    from .stepper import axis_nodes, predict
    net = build_network(_tiny_scene([]))
    stretch, hinge = spring_dofs(net)
    rft = RFTDrag(net, 1.0, 2.0)
    blocks = [(stretch, stretch), (hinge, hinge), *rft.blocks()]
    pattern = SparsePattern(net.ndof, blocks)
    rft.bind(pattern.slots[2:])
    data = np.zeros(pattern.nnz)
    data[pattern.diag_slots] = 1.0
    solver = ArrowSolver(pattern, flagellum_chains(net))
    solver.factor(data)
    solver.solve(np.ones(net.ndof))
    q = net.initial_q()
    N = net.n_nodes
    v = np.full(net.ndof, 1e-3)
    ctx = StepContext(q=q, x=q[: 3 * N].reshape(N, 3), v=v, a=v.copy(), dv_dq=1.0, da_dq=1.0, t=0.0, h=1.0,
                      drive_angle=0.0, frames=None)
    rft.add_force(ctx, np.zeros(net.ndof))
    rft.add_jacobian(ctx, np.zeros(pattern.nnz))
    rft.node_forces(ctx.x, v)
    t, _ = unit_rows(net.nodes[net.edges[:, 1]] - net.nodes[net.edges[:, 0]])
    fr = EdgeFrames.initial(t, net.n_hinges)
    st = State(0.0, q, v, fr, 0.0, 1e-2, 1e-2, q.copy(), v.copy(), q.copy())
    predict(st, 1e-2, axis_nodes(net), N)
    e = np.arange(2)
    twist_for_director(fr.d1[e], fr.t[e], t[e], fr.d1[e] @ np.eye(3).T, q[e])
    x_dofs = np.arange(6, dtype=np.int64)
    for want in (False, True):
        tangent_torque(fr.t, fr.t, np.ones(len(t)), 0, 1.0, 1.0, x_dofs, np.zeros(net.ndof), np.zeros(36 + 6),
                       np.arange(36, dtype=np.int64), np.arange(36, 42, dtype=np.int64), want)


GROUPS: dict[str, Callable[[], None]] = {SPRINGS: warm_springs, SOLVER: warm_solver}


def _dispatchers():
    """The kernels a run calls from Python (their callees are compiled into them)."""
    from . import effects, elastic, frames, linsolve, stepper
    return [frames.unit_rows, frames._trial_frames, frames.twist_for_director, elastic._stretch,
            elastic._bend_twist, elastic._hinge_strains, elastic.tangent_torque,
            effects.rft_kernel(), linsolve._arrow_factor, linsolve._arrow_solve, stepper._predict_cylindrical]


def cache_is_warm() -> bool:
    """Whether every kernel has an entry in numba's on-disk cache (a guess: a stale entry is recompiled)."""
    try:
        return all(os.path.exists(d._cache._cache_file._index_path) for d in _dispatchers())
    except AttributeError:         # numba internals changed: assume cold, which only costs the helper process
        return False


def ensure_compiled(notify: Callable[[str], None] | None = None) -> float:
    """Compile or load every kernel into this process once; returns the seconds it took (0 if already done).

    ``notify`` receives the one-line message shown when the cache is empty (default: stderr)."""
    global _DONE
    if _DONE:
        return 0.0
    t0 = time.perf_counter()
    from numba.core import config
    helper = None
    if not config.DISABLE_JIT and not cache_is_warm():
        (notify or _stderr)("flagbot_sim: compiling kernels (first run only, ~5-10 s; later runs load them from "
                            "the cache)")
        helper = _start_helper(SOLVER)
    warm_springs()
    if helper is not None:
        helper.wait()
    warm_solver()                  # loads what the helper compiled (or compiles it, if the helper failed)
    _DONE = True
    return time.perf_counter() - t0


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _start_helper(group: str) -> subprocess.Popen | None:
    try:
        return subprocess.Popen([sys.executable, "-m", "flagbot_sim.physics.warmup", group],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=dict(os.environ))
    except OSError:
        return None


if __name__ == "__main__":          # the helper process: compile one group into the cache
    GROUPS[sys.argv[1]]()
