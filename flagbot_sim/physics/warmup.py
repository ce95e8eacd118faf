"""Compile (first run) or load (every later run) the compiled kernels a simulation will call, before it starts.

numba compiles a kernel on its first call and caches the machine code on disk (next to the package, or in a
per-user cache directory when the install is read-only: numba's own fallback, ``NUMBA_CACHE_DIR`` overrides
both). Without this module the first steps of the first run would pay the compilation silently and count it as
simulation time. :func:`ensure_compiled` instead

* compiles only the kernel *groups* the caller will use (:func:`groups_for`: a scene without head torque or RFT
  compiles nothing for them, a steady solve no predictor and no time-stepping solver),
* when the cache is cold, says so once ("compiling kernels (first run only") and then reports each group as it
  finishes, with the seconds so far and an estimate of the time left on this machine,
* compiles in two processes at once: the groups are independent (each compiles on a tiny network of its own),
  so they are split by their measured cost (``Group.weight``) between this process and a helper process that
  imports only the physics; on a 2-core machine that halves the wait,
* then loads every group into this process, so that stepping starts with nothing left to compile or load.

Its time is reported as ``compile_seconds``, apart from the simulation's wall time and real-time factor. Each
group drives the package's own code paths (or its kernels with arguments of the types the model passes), so the
compiled signatures are the ones a run uses: a test checks that a run after the warm-up compiles nothing, for
each built-in scene and effect.
"""
from __future__ import annotations

import contextlib
import functools
import gc
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np

from .tiers import DEFERRED, compiled_calls, deferred  # noqa: F401  (deferred: part of this module's API)

#: groups loaded (compiled or read from the cache) in this process
_LOADED: set[str] = set()
#: held by ensure_compiled and swap_in: a node builds a simulation on one thread while its timer's steps call
#: swap_in on another, and a group swapped in between ensure_compiled's look at the deferred groups and its
#: update of them would be deferred again (a second background compile, with nothing left to compile)
_LOCK = threading.RLock()


def kernels_mode() -> str:
    """'compiled', or 'python' under numba's debugging switch NUMBA_DISABLE_JIT=1."""
    from numba.core import config
    return "python" if config.DISABLE_JIT else "compiled"


# ----------------------------------------------------------------------------------------------- the groups
@functools.lru_cache(maxsize=1)
def _tiny_network():
    """A 3-flagellum design-1 network with four edges per flagellum, and its straight configuration's frames
    computed with numpy (no compiled code, so that each group compiles only its own kernels). Shared by the
    groups, which read these arrays and never write them."""
    from ..scene import load_scene
    from .network import build_network
    net = build_network(load_scene("design1", ["robot.n_flagella=3", "flagellum.length=0.02",
                                               "flagellum.edge_length=0.005"]))
    q = net.initial_q()
    N = net.n_nodes
    x = q[: 3 * N].reshape(N, 3)
    e = x[net.edges[:, 1]] - x[net.edges[:, 0]]
    length = np.sqrt(np.einsum("ki,ki->k", e, e))
    t = e / length[:, None]
    d1 = np.cross(t, np.array([0.3, 0.5, 0.8]))
    d1 /= np.sqrt(np.einsum("ki,ki->k", d1, d1))[:, None]
    d2 = np.cross(t, d1)
    return net, q, x, t, length, d1, d2


def _warm_frames() -> None:
    """Reference frames: the trial frames of every iterate, transported from the committed ones."""
    from .frames import EdgeFrames, trial_frames
    net, q, x, t, length, d1, d2 = _tiny_network()
    committed = EdgeFrames(t, d1, d2, np.zeros(net.n_hinges))
    trial_frames(x + 1e-6, net.edges, net.hinge_edges, net.hinge_sign, committed)


def _warm_stretch() -> None:
    """The stretching springs' residual and Jacobian (the arguments ElasticModel.accumulate passes)."""
    from .elastic import _stretch, spring_dofs
    net, q, x, t, length, d1, d2 = _tiny_network()
    stretch, _ = spring_dofs(net)
    slots = np.zeros((net.n_edges, 36), np.int64)
    for J in (np.empty(0), np.zeros(1)):
        _stretch(t, length, net.edge_rest_length, net.EA, stretch, slots, np.zeros(net.ndof), J, len(J) > 0)


def _bend_twist_arguments():
    """The bend-twist kernels' arguments on the tiny network (the types the model passes)."""
    from .elastic import spring_dofs
    net, q, x, t, length, d1, d2 = _tiny_network()
    _, hinge = spring_dofs(net)
    H = net.n_hinges
    return dict(net=net, x=x, theta=q[3 * net.n_nodes:], t=t, length=length, d1=d1, d2=d2, rt=np.zeros(H),
                beta=np.zeros(H), tau_bar=np.zeros(H), kappa_bar=np.zeros((H, 2)), k_bend=net.EI / net.voronoi,
                k_twist=net.GJ / net.voronoi, dofs=hinge, slots=np.zeros((H, 121), np.int64), S=np.empty((H, 6)),
                W=np.empty((H, 3)), grad=np.zeros((H, 11)), Hs=np.zeros((H, 121)))


def _warm_bend_twist() -> None:
    """The bend-twist springs in every hinge's local DOFs: strains, moments, gradient and Hessian (and so their
    strains: model set-up, motor torque)."""
    from .elastic import _bend_twist_local
    a = _bend_twist_arguments()
    net = a["net"]
    for want in (False, True):
        _bend_twist_local(a["x"], a["theta"], a["d1"], a["d2"], a["rt"], net.hinge_nodes, net.hinge_edges,
                          net.hinge_sign, a["beta"], a["kappa_bar"], a["tau_bar"], a["k_bend"], a["k_twist"],
                          int(net.motor_hinge), 0.0, a["S"], a["W"], a["grad"], a["Hs"], want)


def _warm_bend_twist_global() -> None:
    """The bend-twist springs' gradient and Hessian into the global DOFs, through the frames' transport."""
    from .elastic import _bend_twist_global
    a = _bend_twist_arguments()
    net = a["net"]
    for J in (np.empty(0), np.zeros(1)):
        _bend_twist_global(a["t"], a["t"], a["length"], net.hinge_edges, net.hinge_sign, a["dofs"], a["slots"],
                           a["grad"], a["Hs"], np.zeros(net.ndof), J, len(J) > 0)


def _warm_time_stepping() -> None:
    """What a time-stepped Simulation adds to the model: the predictor and the observer's spin angle."""
    from .frames import angle3
    from .model import State
    from .newton import error_sums, residual_norms, robot_pose
    from .stepper import axis_nodes, continuations
    net, q, x, t, length, d1, d2 = _tiny_network()
    v = np.zeros_like(q)
    st = State(0.0, q, v, None, 0.0, 1e-2, 1e-2, q.copy(), v.copy(), q.copy())
    continuations(st, 1e-2, axis_nodes(net), net.n_nodes)
    residual_norms(v, v)
    error_sums(v, v, v, v)
    i0, _, i2 = axis_nodes(net)
    robot_pose(q, i0, i2, int(net.edges[net.plate_edges[0], 1]), np.empty(9))
    u, w = d1[0], d2[0]
    angle3(u[0], u[1], u[2], w[0], w[1], w[2], t[0, 0], t[0, 1], t[0, 2])


def _warm_arrow() -> None:
    """The arrow solver's factorisation and solve (banded flagella + Schur complement of the core)."""
    from .assembly import SparsePattern
    from .elastic import spring_dofs
    from .linsolve import ArrowSolver, flagellum_chains
    net, *_ = _tiny_network()
    stretch, hinge = spring_dofs(net)
    pattern = SparsePattern(net.ndof, [(stretch, stretch), (hinge, hinge)])
    data = np.zeros(pattern.nnz)
    data[pattern.diag_slots] = 1.0
    solver = ArrowSolver(pattern, flagellum_chains(net))
    solver.factor(data)
    solver.solve(np.ones(net.ndof))


def _effect_context(net, q, x, v):
    from .effects import StepContext
    return StepContext(q=q, x=x, v=v, a=v.copy(), dv_dq=1.0, da_dq=1.0, t=0.0, h=1.0, drive_angle=0.0,
                       frames=None)


def _warm_rft() -> None:
    """Resistive-force theory: its residual, Jacobian and the medium's force on the flagella."""
    from .assembly import SparsePattern
    from .effects import RFTDrag
    net, q, x, *_ = _tiny_network()
    rft = RFTDrag(net, 1.0, 2.0)
    pattern = SparsePattern(net.ndof, rft.blocks())
    rft.bind(pattern.slots)
    v = np.full(net.ndof, 1e-3)
    ctx = _effect_context(net, q, x, v)
    rft.add_force(ctx, np.zeros(net.ndof))
    rft.add_jacobian(ctx, np.zeros(pattern.nnz))
    rft.node_forces(x, v)


def _warm_head_torque() -> None:
    """The head's Stokes torque on its tilting tangent (residual and Jacobian: one signature)."""
    from .elastic import tangent_torque
    net, q, x, t, length, *_ = _tiny_network()
    x_dofs = np.arange(6, dtype=np.int64)
    tangent_torque(t, t, length, 0, 1.0, 1.0, x_dofs, np.zeros(net.ndof), np.zeros(42),
                   np.arange(36, dtype=np.int64), np.arange(36, 42, dtype=np.int64), True)


def _warm_spin_drag() -> None:
    """The flagella's spin drag: torques about every flagellum edge's tangent (residual and Jacobian)."""
    from .elastic import tangent_torques
    net, q, x, t, length, *_ = _tiny_network()
    edges = np.arange(2, dtype=np.int64)
    x_dofs = np.tile(np.arange(6, dtype=np.int64), (2, 1))
    tangent_torques(t, t, length, edges, np.ones(2), np.ones(2), x_dofs, np.zeros(net.ndof), np.zeros(84),
                    np.arange(72, dtype=np.int64).reshape(2, 36), np.arange(72, 84, dtype=np.int64).reshape(2, 6),
                    True)


def _warm_clamp() -> None:
    """The clamp's prescribed twist angles."""
    from .frames import twist_for_director
    net, q, x, t, length, d1, d2 = _tiny_network()
    e = np.arange(2)
    twist_for_director(d1[e], t[e], t[e], d1[e] @ np.eye(3).T, q[e])


def _warm_newton() -> None:
    """The compiled Newton solve of a time step (it calls the other groups' kernels by address, so it compiles
    without them)."""
    from .newton import compile_newton
    compile_newton()


@dataclass(frozen=True)
class Group:
    name: str
    warm: Callable[[], None]
    #: the dispatchers it compiles that Python calls ("module.name"; callees are compiled into them)
    kernels: tuple[str, ...]
    #: compile seconds on the reference machine (docs/startup.md; 2-core x86-64, one process, quiet): only
    #: the split between the two processes and the estimate of the time left use it, so it need not be exact
    weight: float
    doc: str
    #: kernels with a slower equivalent that gives the same numbers to the last bit (the compiled Newton step:
    #: the stepper's Python loop; the predictor, the observer's sums, the arrow solver: their interpreted twins):
    #: a scene's run never waits for their compile; when their cache is cold, a background process compiles
    #: them and the run switches to them once they are in the cache (see ensure_compiled, swap_in)
    background: bool = False


def _group(warm: Callable[[], None], kernels: tuple[str, ...], weight: float, background: bool = False) -> Group:
    return Group(warm.__name__.removeprefix("_warm_"), _compiled_calls(warm), kernels, weight,
                 (warm.__doc__ or "").strip(), background)


def _compiled_calls(warm: Callable[[], None]) -> Callable[[], None]:
    """``warm`` with the deferred groups' callers calling the compiled kernels while it runs (tiers.compiled_calls):
    a warm-up exists to compile or load them."""
    @functools.wraps(warm)
    def run() -> None:
        with compiled_calls():
            warm()
    return run


#: every kernel group, by name. Effects name theirs in ``Effect.kernel_groups``.
GROUPS: dict[str, Group] = {g.name: g for g in (
    _group(_warm_frames, ("frames._trial_frames",), 0.45),
    _group(_warm_stretch, ("elastic._stretch",), 0.25),
    _group(_warm_bend_twist, ("elastic._bend_twist_local",), 2.3),
    _group(_warm_bend_twist_global, ("elastic._bend_twist_global",), 1.2),
    _group(_warm_time_stepping, ("stepper._predict_cylindrical", "frames.angle3", "newton.residual_norms",
                                    "newton.robot_pose", "newton.error_sums"), 0.65, background=True),
    _group(_warm_arrow, ("linsolve._arrow_factor", "linsolve._arrow_solve"), 1.15, background=True),
    _group(_warm_rft, ("effects.rft",), 0.35),
    _group(_warm_head_torque, ("elastic.tangent_torque",), 0.45),
    _group(_warm_clamp, ("frames.twist_for_director",), 0.3),
    _group(_warm_spin_drag, ("elastic.tangent_torques",), 0.5),
    _group(_warm_newton, ("newton._newton", "newton._advance"), 5.5, background=True),
)}

#: what every model needs: its frames and its springs
MODEL_GROUPS = ("frames", "stretch", "bend_twist", "bend_twist_global")

#: the helper process's start in the units of ``Group.weight``, forked or as a fresh interpreter (which imports
#: numpy, scipy and numba and sets numba's compiler up again, ~1 s). The fork itself is ~0.05 s; with 0.15 a cold
#: design 1 splits as measured best (2026-12-07, the bend-twist springs in two groups: the helper's four groups
#: then took 1.6 s of the 3.5 s compile to the first, the main process's bend_twist 3.05 s, so rft goes to the
#: helper and stretch stays here; with 0.4 the main process finished ~0.4 s after the helper)
HELPER_START = {"fork": 0.15, "spawn": 1.1}


def groups_for(scene, time_stepping: bool = True) -> list[str]:
    """The kernel groups a model of ``scene`` uses: its frames and springs, its effects' kernels, unless the scene
    asks for scipy's sparse LU the arrow solver, and for a time-stepped simulation (``time_stepping``) the
    predictor, the observer and (unless sparse LU) the compiled Newton solve of a step (newton.py). A steady solve
    (``time_stepping=False``) factorises its Jacobian with the arrow solver too (steady.py); on a cold cache
    ensure_compiled compiles it in the foreground for a steady solve (measured +0.2-0.7 s on a 2-core machine;
    its twin would run the whole solve) and in the background for a time-stepped run."""
    return _groups(scene.effects, time_stepping, arrow=scene.numerics.linear_solver != "splu")


def solve_groups() -> list[str]:
    """Every group a steady solve of any scene may use (:func:`groups_for` with ``time_stepping=False``, over
    every effect): the frames, the springs, each effect's kernels and the arrow solver, none of the time-stepping
    ones. What the sweeps' fork server loads once for all its workers, whatever scene their points have."""
    from .effects import EFFECT_TYPES
    return _groups(EFFECT_TYPES, time_stepping=False, arrow=True)


def _groups(effects, time_stepping: bool, arrow: bool) -> list[str]:
    """The groups of a model with ``effects`` (names): :func:`groups_for`'s list."""
    from .effects import EFFECT_TYPES
    names = list(MODEL_GROUPS)
    for effect in effects:
        names.extend(EFFECT_TYPES[effect].kernel_groups)
    if time_stepping:
        names.append("time_stepping")
    if arrow:
        names.append("arrow")
        if time_stepping:
            names.append("newton")
    return list(dict.fromkeys(names))


# ----------------------------------------------------------------------------------------------- the cache
def _dispatcher(name: str):
    import importlib
    module, func = name.split(".")
    if name == "effects.rft":
        from .effects import rft_kernel
        return rft_kernel()
    return getattr(importlib.import_module(f"{__package__}.{module}"), func)


def _dispatchers(groups: Iterable[str] | None = None):
    """The kernels the groups (default: all) compile that a run calls from Python."""
    return [_dispatcher(k) for g in (GROUPS if groups is None else groups) for k in GROUPS[g].kernels]


def _cached(dispatcher) -> bool:
    """Whether numba's on-disk cache holds a valid entry for the kernel: an index for this source file's
    version with at least one signature (a stale entry, after an edit or an upgrade, is recompiled)."""
    return bool(dispatcher._cache._cache_file._load_index())


def cache_is_warm(groups: Iterable[str] | None = None) -> bool:
    """Whether numba's on-disk cache holds every kernel of the groups (default: all groups)."""
    try:
        return all(_cached(d) for d in _dispatchers(groups))
    except (AttributeError, OSError):   # numba internals changed: assume cold, which only costs the helper process
        return False


# ----------------------------------------------------------------------------------------------- compiling
def loaded(group: str) -> bool:
    """Whether the group's kernels are loaded in this process (a background group may not be: see
    ensure_compiled)."""
    return group in _LOADED


def ensure_compiled(notify: Callable[[str], None] | None = None, groups: Iterable[str] | None = None) -> float:
    """Compile or load the kernel groups (default: every group) into this process; returns the seconds it took
    (0 if they were all loaded already).

    ``notify`` receives the lines shown while the cache is cold (default: stderr): one that says the kernels
    are being compiled, then one per finished group with the seconds so far and an estimate of the time left.

    Background groups (``Group.background``: the time-stepping kernels that have a twin, the same numbers
    slower) among the ``groups`` a caller names are loaded if their cache is warm. If any is cold and the caller
    is a time-stepped run (its groups include "time_stepping"), this process goes on without them
    (:func:`deferred` is true for each: their callers use the interpreted twins) and a background process
    compiles the cold ones into the cache (after this process's own compile); the simulation swaps each group's
    compiled kernels in as soon as they are there (:func:`swap_in`), and the next run loads them. A steady solve (no
    "time_stepping": it has no step at which to swap them in, and its arrow solver's twin would run the whole
    solve) compiles them here with the others. With ``groups=None`` (``flagbot compile``, dev.py) every group is
    compiled here. A group a time-stepped run deferred already (an earlier call in this process) stays deferred
    until swap_in loads it (its background compile is under way), unless a steady solve asks for it: then it is
    loaded (or compiled) here."""
    with _LOCK:
        return _ensure_compiled(notify, groups)


def _ensure_compiled(notify, groups) -> float:
    from numba.core import config
    wanted_all = list(GROUPS if groups is None else dict.fromkeys(groups))
    wanted = [g for g in wanted_all if g not in _LOADED]
    if not wanted:
        return 0.0
    t0 = time.perf_counter()
    if config.DISABLE_JIT:                        # plain Python: nothing to compile
        _LOADED.update(wanted)
        return time.perf_counter() - t0
    cold = [g for g in wanted if not cache_is_warm([g])]
    stepping = groups is not None and "time_stepping" in wanted_all
    later = [g for g in wanted if stepping and GROUPS[g].background and (g in cold or g in DEFERRED)]
    if later:                                     # the compiled step calls the others: all of them, or none
        later = [g for g in wanted if GROUPS[g].background]
    cold = [g for g in cold if g not in later]
    if cold:
        _Compile(cold, notify or _stderr, t0).run()
    for g in wanted:                              # loads what is cached (or compiles what the helper failed to)
        if g not in _LOADED and g not in later:
            GROUPS[g].warm()
            _LOADED.add(g)
            DEFERRED.discard(g)
    later = [g for g in later if g not in DEFERRED]
    if later:
        DEFERRED.update(later)
        compile_later = [g for g in later if not cache_is_warm([g])] or later     # (warm since: swap_in loads)
        (notify or _stderr)(f"flagbot_sim:   {', '.join(compile_later)}: compiling in the background (low "
                            "priority, one core) while this run starts with the same steps interpreted, the same "
                            "numbers; the run switches to them when they are ready, and later runs load them")
        _compile_in_background(compile_later)
    return time.perf_counter() - t0


#: when swap_in next looks at the cache (perf_counter seconds)
_next_look = 0.0
#: how often swap_in looks (seconds): each look reads a few index files of the cache (~1 ms)
LOOK_EVERY = 0.5


#: the deferred group whose kernels call every other's (the compiled Newton step): loaded only with or after them
STEP_GROUP = "newton"


def swap_in() -> bool:
    """Load the deferred groups the background compile has put in the cache so far (a few hundredths of a second
    each) and return True if any was: their callers call the compiled kernels from then on (the Python loop's
    predictor, sums and arrow solver, each as soon as its group is there: the background compiles them first,
    and the cheapest), and once none is left deferred the caller switches to the compiled step. The compiled
    step's own group (STEP_GROUP) is loaded only when the others are. Looks at the cache at most every
    LOOK_EVERY seconds; cheap to call at every step."""
    global _next_look
    if not DEFERRED:
        return False
    now = time.perf_counter()
    if now < _next_look:
        return False
    if not _LOCK.acquire(blocking=False):         # ensure_compiled is at work on another thread: look next time
        return False
    try:
        _next_look = now + LOOK_EVERY
        return _swap_ready()
    finally:
        _LOCK.release()


def _swap_ready() -> bool:
    groups = [g for g in GROUPS if g in DEFERRED]
    ready = [g for g in groups if cache_is_warm([g])]
    if STEP_GROUP in ready and len(ready) < len(groups):
        ready.remove(STEP_GROUP)
    for g in ready:
        GROUPS[g].warm()
        _LOADED.add(g)
        DEFERRED.discard(g)
    return bool(ready)


#: the background compile's lock file, in the kernel cache's own directory: held while it compiles
BACKGROUND_LOCK = "flagbot_background.lock"


def _compile_in_background(groups: list[str]) -> None:
    """Compile the groups into the cache in a detached, low-priority process that outlives this one if need be
    (its output discarded; one at a time: a second waits for the first's lock, then compiles what is still cold)."""
    try:
        if _can_fork():
            pid = os.fork()
            if pid == 0:                          # the child: its own session, no terminal, no inherited output
                code = 1
                try:
                    os.setsid()
                    devnull = os.open(os.devnull, os.O_RDWR)
                    for fd in (0, 1, 2):
                        os.dup2(devnull, fd)
                    _background(groups)
                    code = 0
                finally:
                    os._exit(code)
            threading.Thread(target=_reap, args=(pid,), daemon=True).start()
        else:
            subprocess.Popen([sys.executable, "-m", "flagbot_sim.physics.warmup", "--background", *groups],
                             stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                             start_new_session=True, env=dict(os.environ))
    except OSError:
        pass                                      # no process to spare: a later run tries again


def _reap(pid: int) -> None:
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass


def _background(groups: list[str]) -> None:
    """In the background process: after any other background compile into the same cache, the groups still
    cold."""
    import fcntl
    os.nice(10)
    # inside the kernel cache directory itself (numba's __pycache__ beside the source, or the per-user cache): the
    # lock file never lands among the package's sources, where a `git add -A` picked it up
    lock_dir = _dispatchers(groups)[0]._cache._cache_path
    os.makedirs(lock_dir, exist_ok=True)
    with open(os.path.join(lock_dir, BACKGROUND_LOCK), "w") as lock:
        # another process's background compile (other groups, perhaps): wait for it, then compile what it left
        # cold; a run that deferred these groups swaps each in as it lands in the cache (swap_in)
        fcntl.flock(lock, fcntl.LOCK_EX)
        with _fewer_collections():
            for g in groups:
                if not cache_is_warm([g]):
                    GROUPS[g].warm()


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def split(groups: list[str], processes: int, helper_start: float) -> tuple[list[str], list[str]]:
    """(this process's groups, the helper's): the largest first, each to the process that would finish it
    first, the helper starting ``helper_start`` late; everything here when one process would finish nearly as
    soon (one core, or too little to compile to pay for the helper's start)."""
    if processes < 2 or sum(GROUPS[g].weight for g in groups) < 2 * helper_start:
        return list(groups), []
    mine, theirs = [], []
    load_mine, load_theirs = 0.0, helper_start
    for g in sorted(groups, key=lambda g: -GROUPS[g].weight):
        if load_mine <= load_theirs:
            mine.append(g)
            load_mine += GROUPS[g].weight
        else:
            theirs.append(g)
            load_theirs += GROUPS[g].weight
    return mine, theirs


class _Compile:
    """One cold compile: this process's groups here, the others in a helper process, progress as they finish."""

    def __init__(self, groups: list[str], notify: Callable[[str], None], t0: float):
        self.groups, self.notify, self.t0 = groups, notify, t0
        self.done: list[str] = []
        self.t_compile = t0
        self.lock = threading.Lock()
        self.helper_done = threading.Event()

    def run(self) -> None:
        with _fewer_collections():
            _numba_set_up()                   # before the fork: the helper inherits numba's compiler set up
            mine, theirs = split(self.groups, _cores(),
                                 HELPER_START["fork" if _can_fork() else "spawn"])
            self.share = [mine, theirs]
            self.t_compile = time.perf_counter()
            how = "in 2 processes" if theirs else "in 1 process"
            self.notify(f"flagbot_sim: compiling kernels (first run only; later runs load them from the cache): "
                        f"{len(self.groups)} groups ({', '.join(self.groups)}) {how}")
            helper = _start_helper(theirs) if theirs else None
            if helper is not None:
                threading.Thread(target=self._read, args=(helper,), daemon=True).start()
            try:
                for g in mine:
                    GROUPS[g].warm()
                    _LOADED.add(g)
                    self._finished(g)
            except BaseException:
                if helper is not None:
                    helper.kill()
                raise
            if helper is not None:
                if not self.helper_done.is_set():
                    gc.collect()              # this process's compiling garbage, while the helper still works
                self.helper_done.wait()
        # a group the helper did not finish is compiled by ensure_compiled, which warms every group afterwards
        self.notify(f"flagbot_sim: kernels compiled in {time.perf_counter() - self.t0:.1f} s")

    def _read(self, helper: _Helper) -> None:
        """Report the helper's groups as they finish; once all have (or it ended), let this process go on at
        once and reap the helper here: a process that compiled takes ~0.5 s to end (its memory is released)."""
        expected = set(self.share[1])
        try:
            for line in helper.lines:
                parts = line.split()
                if len(parts) == 2 and parts[0] == "done" and parts[1] in expected:
                    self._finished(parts[1])
                    expected.discard(parts[1])
                    if not expected:
                        self.helper_done.set()
        finally:
            self.helper_done.set()
            helper.wait()
            helper.lines.close()

    def time_left(self, elapsed: float) -> float | None:
        """Seconds until the later of the two processes finishes, if each goes on at the rate it has shown in
        the ``elapsed`` seconds since compiling began (a process with nothing finished yet is taken to go at
        the other's rate since then); None before any group has finished."""
        rates = []
        for share in self.share:
            done = sum(GROUPS[g].weight for g in share if g in self.done)
            rates.append(done / elapsed if done > 0 else None)
        known = [r for r in rates if r]
        if not known:
            return None
        finish = [sum(GROUPS[g].weight for g in share) / (rate or min(known))
                  for share, rate in zip(self.share, rates) if any(g not in self.done for g in share)]
        return max(0.0, max(finish) - elapsed) if finish else 0.0

    def _finished(self, group: str) -> None:
        with self.lock:
            self.done.append(group)
            now = time.perf_counter()
            elapsed = now - self.t0
            left = self.time_left(now - self.t_compile)        # (the rates from when compiling began)
            tail = f", about {left:.0f} s to go" if left is not None and len(self.done) < len(self.groups) else ""
            self.notify(f"flagbot_sim:   {group} compiled ({len(self.done)}/{len(self.groups)}), "
                        f"{elapsed:.1f} s so far{tail}")


@contextlib.contextmanager
def _fewer_collections():
    """Keep the garbage collector out of the compile's way (docs/startup.md).

    Compiling allocates millions of short-lived objects and leaves ~10^6 long-lived ones behind (numba keeps each
    kernel's typed IR). With the objects alive at the start frozen out of the collector's sweeps and a larger
    first-generation threshold, a compile spends ~0.2 s collecting instead of ~0.55 s; at the end everything
    alive is frozen too (the caller collects first when it has time to wait), or the next full collection walks
    it all again (~0.3 s, just when the simulation starts) and every later one too. Freezing keeps nothing
    alive: reference counting frees frozen objects as ever, only a cycle among them waits. The thresholds are
    handed back."""
    old = gc.get_threshold()
    gc.freeze()
    gc.set_threshold(50_000, 20, 20)
    try:
        yield
    finally:
        gc.set_threshold(*old)
        gc.freeze()


def _numba_set_up() -> None:
    """numba loads its typing and lowering registries at its first compile in a process (~0.3 s)."""
    from .jit import kernel
    kernel(_one)(1.0)


def _one(x):
    return x + 1.0


class _Helper:
    """The helper process: the groups it compiles, its 'done GROUP' lines as they come (``lines``), ``wait``.

    Forked from this process where that is safe (Linux, and no thread besides this one but OpenBLAS's workers:
    :func:`_can_fork`): the child starts with the interpreter, numpy, numba and its
    compiler already set up, where a fresh interpreter takes about a second to get there. Otherwise (a ROS node
    has its middleware's threads, other systems) a fresh interpreter runs this module."""

    def __init__(self, groups: list[str]):
        self.pid = self.proc = None
        self._reaping, self._reaped = threading.Lock(), False
        if _can_fork():
            r, w = os.pipe()
            pid = os.fork()
            if pid == 0:                          # the child: compile, report, and leave without any clean-up
                code = 1
                try:
                    os.close(r)
                    out = os.fdopen(w, "w")
                    for g in groups:                  # (the collector as the parent set it for compiling)
                        GROUPS[g].warm()
                        print("done", g, file=out, flush=True)
                    code = 0
                finally:
                    os._exit(code)
            os.close(w)
            self.pid, self.lines = pid, os.fdopen(r)
        else:
            self.proc = subprocess.Popen([sys.executable, "-m", "flagbot_sim.physics.warmup", *groups], text=True,
                                         stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=dict(os.environ))
            self.lines = self.proc.stdout

    def wait(self) -> None:
        """Reap the helper (once, from whichever thread comes first)."""
        with self._reaping:
            if self._reaped:
                return
            self._reaped = True
            try:
                self.proc.wait() if self.proc is not None else os.waitpid(self.pid, 0)
            except ChildProcessError:
                pass

    def kill(self) -> None:
        try:
            os.kill(self.proc.pid if self.proc is not None else self.pid, signal.SIGKILL)
        except OSError:
            pass
        self.wait()


def _can_fork() -> bool:
    """Whether a helper can be forked from this process (Linux): only if no other thread of it could hold a lock
    the child needs. Threads besides this one are allowed only as OpenBLAS's workers: numpy and scipy each load
    an OpenBLAS that starts a pool of (its thread count - 1) workers at import, so without them no numpy program
    (`flagbot run`, `flagbot steady`) would ever count as single-threaded; OpenBLAS stops its pool before a fork
    (its pthread_atfork handler, ``openblas_fork_handler``) and starts it again at its next call, in parent and
    child alike. A ROS node has its middleware's threads: it is not forked."""
    if not sys.platform.startswith("linux") or not hasattr(os, "fork"):
        return False
    try:
        threads = len(os.listdir("/proc/self/task"))
    except OSError:
        return False
    if threads == 1:
        return True
    from .blas import workers
    return threads <= 1 + workers()


def _start_helper(groups: list[str]) -> _Helper | None:
    try:
        return _Helper(groups)
    except OSError:
        return None


def _compile_groups(groups: list[str], out) -> None:
    """In the helper process: compile the groups into the cache, writing 'done GROUP' after each."""
    with _fewer_collections():
        for g in groups:
            GROUPS[g].warm()
            print("done", g, file=out, flush=True)


if __name__ == "__main__":               # the helper process when it is not forked
    if sys.argv[1:2] == ["--background"]:
        _background(sys.argv[2:])
    else:
        _compile_groups(sys.argv[1:], sys.stdout)
