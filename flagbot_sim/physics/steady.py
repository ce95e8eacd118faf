"""Steady swimming without time stepping: the robot's relative equilibrium, solved directly by Newton.

At steady state every part of the robot moves rigidly about the axis (lab x): the shaft, plate and flagella turn
at omega_t about +x, the head body at -omega_h (omega_h + omega_t = omega_T, the motor), and the whole robot
translates at U along x (forward speed v = -U: the head leads towards -x). The shape is fixed in the frame
turning with each part, so one configuration q, seen at the instant the motor's drive angle is zero, together
with (omega_t, U) is a static nonlinear problem:

    R(q, omega_t, U) = grad E(q) - F(q, v(q), a(q)) = 0,      with, for a node x of a part turning at Omega,
    v = Omega e_x x x + U e_x,   a = -Omega^2 (0, y, z),   and for an edge's twist angle d(theta)/dt = Omega e_x.t

(the twist rate of a rigidly turning material frame seen from a time-parallel transported reference frame,
which has no spin about its tangent). The residual is exactly the time stepper's, with these velocities instead
of the integrator's: the same springs, RFT, head drag and torque, inertia as centripetal load. The problem is
invariant under translation along x and rotation about x; the two gauge conditions (head centre's x, the first
plate rim's z) fix them, and the two equations they free are the axial force and torque balance, which
determine U and omega_t. The clamped flagellum has neither (the clamp holds the plate): its unknowns are the
shape alone.

Newton's Jacobian: the effects' own Jacobians, evaluated three times with the integrator coefficients set to
(dv/dq, da/dq) = (0, 0), (1, 0), (0, 1), separate the explicit position dependence from dF/dv and dF/da; the
chain rule through the rigid-motion velocity field then gives dR/dq exactly (tests check it by finite
differences), and dR/d(omega_t, U) are dF/dv and dF/da applied to dv/d(omega_t, U). Continuation in omega_T from
the straight robot makes it robust: when Newton fails, the step in omega_T is halved.
"""
from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .effects import StepContext
from .frames import EdgeFrames
from .linsolve import ArrowSolver, flagellum_chains
from .medium import coefficients_report
from .model import RobotModel, State
from .observe import summary_fields
from .warmup import kernels_mode


#: a mode is the symmetry's neutral one when mu = +-i omega_t to this relative tolerance (round-off splits the
#: double eigenvalue of the shift and tilt pair, a Jordan block, by ~1e-5 omega_t)
NEUTRAL_RTOL = 1e-4
#: the stability analysis examines at most this many modes (those of smallest |mu|)
MAX_MODES = 192
#: 1/s: below this omega_t the neutral modes at +-i omega_t come so close to mu = 0 that the steady Jacobian is
#: (at rest: exactly) singular; the modes are then sought about the shift mu = -SHIFT_FLOOR instead of 0
SHIFT_FLOOR = 1e-2
#: ARPACK's Krylov space (ncv) for the stability analysis' 12 modes: scipy's default, 2k + 1 = 25, restarts often;
#: 30 took 13% fewer operator applications over both designs (n = 2, 3, 20-250 rpm: design 2 -21%, design 1 +7%)
ARNOLDI_VECTORS = 30
#: a mode grows when its real part exceeds this fraction of its |mu|: an undamped oscillation (the flagella's
#: twist carries no drag, so at rest its modes are purely imaginary) is marginal, not a round-off instability
GROWTH_RTOL = 1e-8


class SteadyFailed(RuntimeError):
    """No relative equilibrium was found; the message says at which omega_T and why."""


#: a mode is a twist mode when the flagella's twist angles (in metres: times the edge length) carry more than this
#: share of its shape vector's squared norm
TWIST_SHARE = 0.5


@dataclass
class Stability:
    """Linear stability of an equilibrium in the overdamped limit (see :meth:`SteadySolver.stability`)."""
    stable: bool
    rate: float                  # 1/s: largest real part of the growth rates of the non-neutral modes (< 0: decay)
    rates: list                  # the slowest growth rates found (1/s), largest real part first
    neutral: int                 # modes with zero growth: sideways shift and tilt of the whole robot
    #: per mode of ``rates``: the share of its vector in the flagella's twist (TWIST_SHARE splits the kinds)
    twist_shares: list = field(default_factory=list)
    #: 1/s: largest real part of the non-neutral modes that move the shape (the flagella's twist carries under
    #: TWIST_SHARE of them): the settling of the centreline, what the outputs show; NaN if none was found
    shape_rate: float = math.nan
    #: the slowest non-neutral twist mode (the flagella's twist carries no drag unless 'spin_drag' is listed, so
    #: it is an almost undamped oscillation): growth rate (1/s) and angular frequency (rad/s); NaN if none
    twist_rate: float = math.nan
    twist_frequency: float = math.nan

    def to_dict(self) -> dict:
        tc = (lambda r: (-1.0 / r) if r < 0 else None)     # noqa: E731
        finite = (lambda x: x if math.isfinite(x) else None)   # noqa: E731
        return {"stable": self.stable, "slowest_rate": self.rate, "neutral_modes": self.neutral,
                "slowest_time_constant": tc(self.rate),
                "shape_rate": finite(self.shape_rate),
                "settling_time_constant": tc(self.shape_rate) if math.isfinite(self.shape_rate) else None,
                "twist_oscillation": None if not math.isfinite(self.twist_rate) else
                {"rate": self.twist_rate, "frequency": self.twist_frequency,
                 "time_constant": tc(self.twist_rate)}}


@dataclass
class SteadySolution:
    omega_T: float               # rad/s
    omega_t: float               # rad/s, flagella (shaft, plate) about +x
    omega_h: float               # rad/s, head about -x
    v: float                     # m/s, forward speed (positive = head first)
    q: np.ndarray                # the configuration at drive angle 0
    velocity: np.ndarray         # DOF velocities of the rigid motion
    frames: EdgeFrames           # reference frames of q
    residual: float              # final scaled residual (N)
    iterations: int              # Newton iterations over the whole continuation
    continuation: list = field(default_factory=list)   # omega_T values solved on the way
    wall_seconds: float = 0.0


class _BorderedPattern:
    """The steady Jacobian's sparsity, built once, and its numerical assembly as one weighted bincount.

    The Jacobian is J00 + Kv Dv + Ka Da on the DOFs (Kv = dR/dv, Ka = dR/da on the model's CSC pattern; Dv, Da the
    rigid-motion field's derivatives, whose structure is fixed), bordered by the columns Kv dv/domega_t +
    Ka da/domega_t and Kv dv/dU and the two gauge rows (free robot), with identity rows for prescribed DOFs. Every
    contribution's target slot is precomputed, so each assembly is products of arrays and one ``np.bincount``:
    no sparse products, no format conversions. Factorised by the arrow solver (:meth:`arrow`: the flagella banded,
    the border columns and rows with the core), or by SuperLU in a fill-reducing column order found once, when
    first asked for (:meth:`factor`: a scene that asks for ``numerics.linear_solver = 'splu'``, a network
    without the arrow structure)."""

    def __init__(self, pattern, N: int, n_edges: int, head: np.ndarray, tail: np.ndarray, fixed: np.ndarray,
                 gauge: np.ndarray, bordered: bool):
        ndof = pattern.ndof
        n = ndof + (2 if bordered else 0)
        self.n = n
        k = np.arange(N)
        e = 3 * N + np.arange(n_edges)
        # Dv's entries, in the order of the values dv_values() returns
        self.dv_rows = np.concatenate([3 * k + 1, 3 * k + 2] + [e] * 6)
        self.dv_cols = np.concatenate([3 * k + 2, 3 * k + 1] + [3 * head + i for i in range(3)]
                                      + [3 * tail + i for i in range(3)])
        self.da_rows = self.da_cols = np.concatenate([3 * k + 1, 3 * k + 2])
        indptr = pattern.indptr.astype(np.int64)
        srow, scol = pattern.row_of_slot, pattern.col_of_slot

        def product(d_rows, d_cols):
            """(slots of K, entries of D, target rows, target cols) of every term of K @ D."""
            counts = indptr[d_rows + 1] - indptr[d_rows]
            m = np.repeat(np.arange(len(d_rows)), counts)
            starts = np.repeat(indptr[d_rows] - np.cumsum(counts) + counts, counts)
            slots = starts + np.arange(counts.sum())
            return slots, m, srow[slots], d_cols[m]

        self.kv_slots, self.kv_m, r_v, c_v = product(self.dv_rows, self.dv_cols)
        self.ka_slots, self.ka_m, r_a, c_a = product(self.da_rows, self.da_cols)
        groups_r = [srow, r_v, r_a]
        groups_c = [scol, c_v, c_a]
        if bordered:
            groups_r += [srow, srow, ndof + np.arange(len(gauge))]
            groups_c += [np.full(pattern.nnz, ndof), np.full(pattern.nnz, ndof + 1), gauge]
        groups_r.append(fixed)
        groups_c.append(fixed)
        sizes = [len(g) for g in groups_r]
        rows = np.concatenate(groups_r).astype(np.int64)
        cols = np.concatenate(groups_c).astype(np.int64)
        is_fixed = np.zeros(n, bool)
        is_fixed[fixed] = True
        keep = ~is_fixed[rows]
        if len(fixed):
            keep[-len(fixed):] = True                  # the identity rows themselves
        key = cols * n + rows
        uniq, inverse = np.unique(key[keep], return_inverse=True)
        self.nnz = len(uniq)
        target = np.full(len(rows), self.nnz)       # contributions to prescribed rows go to a discarded bin
        target[keep] = inverse
        self.target = target
        self.indices = (uniq % n).astype(np.int32)
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(uniq // n, minlength=n))]).astype(np.int32)
        # the structure as linsolve.ArrowSolver reads it
        self.ndof = n
        self.row_of_slot = self.indices.astype(np.int64)
        self.col_of_slot = uniq // n
        self.sizes = sizes
        self.scol = scol
        self.bordered = bordered
        self._ones = np.ones(sizes[-1] + (sizes[-2] if bordered else 0))
        self._arrow = None                     # the arrow solver of this structure (:meth:`arrow`), once built

    def arrow(self, net) -> ArrowSolver:
        """An arrow solver of this structure (``net``: the network, whose flagella are its chains) with buffers
        of its own; the slot mapping is built once per structure (~0.3-0.6 ms) and shared. Raises ValueError if
        the structure is not an arrow."""
        if self._arrow is None:
            self._arrow = ArrowSolver(self, flagellum_chains(net))
        return self._arrow.copy()

    @functools.cached_property
    def _ordering(self) -> tuple:
        """SuperLU's minimum degree ordering of A + A^T depends on the structure alone: found once, when first
        needed, on values drawn from a fixed seed, and every SuperLU factorisation (:meth:`factor`) takes the
        columns in that order. (order, its CSC slots, indices, indptr, the assembly's targets in that order)."""
        n = self.n
        probe = sp.csc_matrix((np.random.default_rng(0).standard_normal(self.nnz), self.indices.copy(),
                               self.indptr.copy()), shape=(n, n))
        perm_c = spla.splu(probe, permc_spec="MMD_AT_PLUS_A").perm_c
        order = np.empty(n, np.int64)
        order[perm_c] = np.arange(n)
        counts = np.diff(self.indptr.astype(np.int64))[order]
        starts = self.indptr[order].astype(np.int64)
        slots = np.repeat(starts - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())
        indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
        in_order = np.full(self.nnz + 1, self.nnz)          # (the discarded bin stays where it is)
        in_order[slots] = np.arange(self.nnz)
        return order, slots, self.indices[slots], indptr, in_order[self.target]

    @property
    def order(self) -> np.ndarray:
        """The columns of the Jacobian in SuperLU's factorisation order."""
        return self._ordering[0]

    @property
    def order_slots(self) -> np.ndarray:
        """The CSC slots of the matrix with its columns in :attr:`order`."""
        return self._ordering[1]

    def factor(self, A: sp.csc_matrix) -> "_OrderedLU":
        """SuperLU's factors of ``A`` (on this pattern), its columns in the fill-reducing order found once per
        structure (no ordering per factorisation; one-column panels and no relaxed supernodes, which for
        matrices this small cost less than they save). Raises RuntimeError if ``A`` is singular."""
        return self.factor_values(A.data[self.order_slots])

    def factor_values(self, data: np.ndarray) -> "_OrderedLU":
        """:meth:`factor` of the matrix whose CSC data in the factorisation's column order is ``data`` (what
        :meth:`values` gives with ``ordered=True``)."""
        _, _, indices, indptr, _ = self._ordering
        P = sp.csc_matrix((data, indices, indptr), shape=(self.n, self.n))
        return _OrderedLU(spla.splu(P, permc_spec="NATURAL", panel_size=1, relax=1), self.order)

    @staticmethod
    def dv_values(Om_n: np.ndarray, g: np.ndarray) -> np.ndarray:
        """Dv's values: dv/dx = Omega [e_x]x on the nodes; the twist rates' d(Omega_e e_x.t_e)/dx = +-g."""
        return np.concatenate([-Om_n, Om_n, g[:, 0], g[:, 1], g[:, 2], -g[:, 0], -g[:, 1], -g[:, 2]])

    def assemble(self, *args, **kwargs) -> sp.csc_matrix:
        """The Jacobian as a CSC matrix (arguments: :meth:`values`')."""
        return sp.csc_matrix((self.values(*args, **kwargs), self.indices, self.indptr), shape=(self.n, self.n))

    def values(self, J00, Kv, Ka, dv_vals, da_vals, dv_dw=None, da_dw=None, dv_dU=None, identity: bool = True,
               ordered: bool = False) -> np.ndarray:
        """The Jacobian's CSC data (``Ka``/``da_*`` None: without the inertia terms); ``ordered``: the data of the
        matrix with its columns in the factorisation's order (:meth:`factor_values`), each entry the same sum.
        ``identity=False``: without the gauge rows' and the prescribed DOFs' ones (the linearisation's damping,
        whose bordered form is J00 + Kv Dv with the same border columns, is assembled here too)."""
        parts = [J00, Kv[self.kv_slots] * dv_vals[self.kv_m]]
        parts.append(Ka[self.ka_slots] * da_vals[self.ka_m] if Ka is not None else np.zeros(self.sizes[2]))
        if self.bordered:
            w = Kv * dv_dw[self.scol]
            if Ka is not None:
                w = w + Ka * da_dw[self.scol]
            parts += [w, Kv * dv_dU[self.scol]]
        parts.append(self._ones if identity else np.zeros(len(self._ones)))
        target = self._ordering[4] if ordered else self.target
        return np.bincount(target, np.concatenate(parts), minlength=self.nnz + 1)[: self.nnz]

    def embed(self, K: np.ndarray) -> np.ndarray:
        """The CSC data on this pattern of a matrix on the model's pattern (CSC data ``K``), its prescribed rows
        dropped."""
        return np.bincount(self.target[: self.sizes[0]], K, minlength=self.nnz + 1)[: self.nnz]



class _OrderedLU:
    """Factors of a Jacobian whose columns were taken in the order ``order`` (:meth:`_BorderedPattern.factor`):
    ``solve(b)`` is A^-1 b in the Jacobian's own unknowns."""
    __slots__ = ("lu", "order")

    def __init__(self, lu, order: np.ndarray):
        self.lu, self.order = lu, order

    def solve(self, b: np.ndarray) -> np.ndarray:
        x = np.empty(len(self.order))
        x[self.order] = self.lu.solve(b)
        return x


#: _BorderedPattern of each structure built in this process (a sweep's points share a few): key -> pattern
_PATTERNS: dict = {}
#: patterns kept at most (a sweep has a handful of (n, L) structures)
_PATTERN_CACHE_SIZE = 16


def bordered_pattern(pattern, N: int, n_edges: int, head, tail, fixed, gauge, bordered: bool) -> _BorderedPattern:
    """The :class:`_BorderedPattern` of this structure, built once per process: it depends on the structure alone
    (the model's CSC pattern, the edges, the prescribed DOFs and the gauge), and is only read after it is built
    (but for what it builds once, when first asked: the SuperLU column order, the arrow solver's slot mapping)."""
    arrays = (pattern.indptr, pattern.indices, head, tail, fixed, gauge)
    key = (N, n_edges, pattern.ndof, bool(bordered)) + tuple(
        (np.asarray(a).dtype.str, np.asarray(a).shape, np.ascontiguousarray(a).tobytes()) for a in arrays)
    got = _PATTERNS.get(key)
    if got is None:
        got = _BorderedPattern(pattern, N, n_edges, head, tail, fixed, gauge, bordered)
        if len(_PATTERNS) >= _PATTERN_CACHE_SIZE:
            _PATTERNS.pop(next(iter(_PATTERNS)))
        _PATTERNS[key] = got
    return got


def conjugate_pairs(mu: np.ndarray, rtol: float = 1e-6) -> np.ndarray:
    """``mu`` without a complex mode whose conjugate is missing. The pencil is real, so its modes come in
    conjugate pairs; ARPACK's k modes of largest |nu| can end on half a pair, and the modes examined must be every
    mode up to the largest |mu| reported (the slowest-mode verdict relies on that)."""
    return mu[_paired(mu, rtol)] if len(mu) else mu


def _paired(mu: np.ndarray, rtol: float = 1e-6) -> np.ndarray:
    """The mask of :func:`conjugate_pairs`."""
    return np.array([abs(m.imag) <= rtol * abs(m) or np.min(np.abs(mu - np.conj(m))) <= rtol * max(1.0, abs(m))
                     for m in mu], bool)

class FreeRobot:
    """The swimming robot's problem: unknowns (q, omega_t, U). The two gauge conditions (the head centre's x, the
    first plate rim node's z) fix translation along and rotation about the axis; the two equations they free, the
    axial force and torque balance, determine U and omega_t."""
    #: modes of the symmetry at mu = +-i omega_t: a sideways shift and a tilt of the whole robot, as pairs
    neutral_modes = 4

    def __init__(self, model: RobotModel):
        self.model = model
        net = model.net
        rim = net.edges[net.plate_edges[0], 1]
        self.gauge = np.array([3 * net.head_nodes[1], 3 * rim + 2])

    def pack(self, omega_t: float, U: float) -> np.ndarray:
        """The unknowns beyond q."""
        return np.array([omega_t, U])

    def rates(self, p: np.ndarray, omega_T: float) -> tuple[float, float]:
        """(omega_t, U) of the unknowns ``p`` beyond q."""
        return p[0], p[1]

    def first_guess(self, omega_T: float) -> tuple[float, float]:
        """(omega_t, U) of the undeformed robot turning as a rigid body, from the torque balance of the effects'
        spin drag: omega_h c_h = c_t omega_t (c_t = n L R_d^2 (eta_t sin^2 theta + eta_p cos^2 theta) of rigid
        flagella, theta the helix angle), omega_h + omega_t = omega_T."""
        c_h, c_t = self.model.spin_drag()
        return (omega_T * c_h / (c_h + c_t) if c_h + c_t > 0 else 0.5 * omega_T), 0.0

    def continued(self, p: np.ndarray, omega_T: float, from_omega_T: float, ratio: float) -> np.ndarray:
        """The guess at ``omega_T`` from the solution ``p`` at ``from_omega_T`` (or, from none, omega_t = ratio
        omega_T): omega_t in proportion, U as it was."""
        omega_t = p[0] * omega_T / from_omega_T if from_omega_T else ratio * omega_T
        return np.array([omega_t, p[1]])

    def prepare(self, q: np.ndarray, committed: EdgeFrames) -> None:
        """Nothing is prescribed."""

    def shift(self, omega_t: float) -> float:
        """Where the modes are sought (mu = shift + 1/nu): 0, unless the neutral modes at +-i omega_t are so near 0
        (a robot nearly or wholly at rest) that the steady Jacobian itself is singular."""
        return 0.0 if abs(omega_t) >= SHIFT_FLOOR else -SHIFT_FLOOR

    def neutral(self, mu: np.ndarray, omega_t: float, sigma: float) -> np.ndarray:
        """Which modes are the symmetry's: mu = +-i omega_t to NEUTRAL_RTOL."""
        scale = max(abs(omega_t), SHIFT_FLOOR if sigma else 1e-12)
        return (np.abs(mu.real) <= NEUTRAL_RTOL * scale) & (np.abs(np.abs(mu.imag) - abs(omega_t))
                                                            <= NEUTRAL_RTOL * scale)

    def observations(self, sol: "SteadySolution") -> dict:
        """What the summary reports of the equilibrium beyond its rates: the motor's torque (its twist is in the
        frames at drive angle 0)."""
        return {"motor_torque": self.model.motor_torque(sol.q, sol.frames, 0.0)}


class ClampedFlagellum:
    """The clamped flagellum's problem: the clamp holds the plate, turning at omega_T, so the unknowns are the
    shape q alone (no gauge, no rates)."""
    neutral_modes = 0
    gauge = np.zeros(0, np.int64)

    def __init__(self, model: RobotModel):
        self.model = model

    def pack(self, omega_t: float, U: float) -> np.ndarray:
        return np.zeros(0)

    def rates(self, p: np.ndarray, omega_T: float) -> tuple[float, float]:
        """The flagellum turns with the clamp and does not translate."""
        return omega_T, 0.0

    def first_guess(self, omega_T: float) -> tuple[float, float]:
        return omega_T, 0.0

    def continued(self, p: np.ndarray, omega_T: float, from_omega_T: float, ratio: float) -> np.ndarray:
        return p

    def prepare(self, q: np.ndarray, committed: EdgeFrames) -> None:
        """Put the clamped DOFs at the clamp's configuration at drive angle 0."""
        state = State(0.0, q, np.zeros_like(q), committed, 0.0)
        self.model.prescribe(q, state, 0.0)

    def shift(self, omega_t: float) -> float:
        return 0.0

    def neutral(self, mu: np.ndarray, omega_t: float, sigma: float) -> np.ndarray:
        return np.zeros(len(mu), bool)

    def observations(self, sol: "SteadySolution") -> dict:
        """The medium's force and torque on the flagellum (the clamp's torque is -T_x) and its tip, at drive angle
        0 (where the clamp's frame is the lab's)."""
        model = self.model
        N = model.net.n_nodes
        x = sol.q[: 3 * N].reshape(N, 3)
        F, T = model.medium_force(x, sol.velocity)
        return {"clamp": (F, T, x[model.net.flagella_nodes[0][-1]])}


def steady_problem(model: RobotModel) -> FreeRobot | ClampedFlagellum:
    """The steady problem of a model's scene: the clamped flagellum when a clamp holds it, else the free robot."""
    return ClampedFlagellum(model) if model.scene.clamped else FreeRobot(model)


@dataclass
class _Linear:
    """What the steady Jacobian is assembled from at one (q, omega_t, U)."""
    r: np.ndarray                # residual
    frames: EdgeFrames           # trial frames of q
    fields: tuple                # (v, a, dv/domega_t, da/domega_t, dv/dU) of the rigid motion
    J00: np.ndarray              # dR/dq at fixed v, a (springs and effects), CSC data on the model's pattern
    Kv: np.ndarray               # dR/dv, the effects' Jacobian with dv/dq = 1 less the one at dv/dq = 0
    Ka: np.ndarray               # dR/da, likewise with da/dq = 1
    dv_vals: np.ndarray          # values of dv/dq and da/dq of the rigid-motion field
    da_vals: np.ndarray


class SteadySolver:
    """Relative equilibria of one scene (its RobotModel): ``solve(omega_T)``.

    One damped Newton driver and continuation in omega_T; what differs between the free robot and the clamped
    flagellum (unknowns, gauge, first guess, neutral modes, what is reported) is its problem, :class:`FreeRobot`
    or :class:`ClampedFlagellum` (``self.problem``)."""

    def __init__(self, model: RobotModel, tol: float | None = None, max_iterations: int = 30):
        self.model = model
        net = model.net
        self.net = net
        self.problem = steady_problem(model)
        N = net.n_nodes
        self.N = N
        self.tol = tol if tol is not None else model.force_tol
        self._norm = model.residual_norm
        self.max_iterations = max_iterations
        # which part each node and edge turns with: the head body (x0 -> x1) at -omega_h, all else at omega_t
        self.head_node = np.zeros(N, bool)
        self.head_edge = np.zeros(net.n_edges, bool)
        if len(net.head_nodes):
            self.head_node[net.head_nodes[:2]] = True
            self.head_edge[net.head_edge] = True
        self.fixed = model.prescribed_dofs
        self.gauge = self.problem.gauge
        e = net.edges
        self._tail, self._head = e[:, 0], e[:, 1]
        self._is_fixed = np.zeros(model.ndof, bool)
        self._is_fixed[self.fixed] = True
        self._pattern = bordered_pattern(model.pattern, N, net.n_edges, self._head, self._tail, self.fixed,
                                         self.gauge, bordered=len(self.gauge) > 0)
        #: the arrow solver that factorises the Jacobian (linsolve.ArrowSolver, buffers of this solver's own), or
        #: None: SuperLU (_BorderedPattern.factor), where the scene asks for it or the network is not an arrow
        self._arrow = None
        if model.scene.numerics.linear_solver != "splu":
            try:
                self._arrow = self._pattern.arrow(net)
            except ValueError:
                if model.scene.numerics.linear_solver == "arrow":
                    raise
        self._ex = np.eye(3)[0]
        self._dv_dU = np.zeros(model.ndof)
        self._dv_dU[0: 3 * N: 3] = 1.0

    # ---------------------------------------------------------------- the rigid-motion velocity field
    def _rates(self, omega_T: float, omega_t: float):
        """Turning rate about +x of the frame each node is seen in, and of every edge's material frame.

        Every node is described in the frame turning with the flagella (omega_t), the head's too: the head is
        axisymmetric (isotropic drag, a torque about its own axis), so its spin shows only in its twist rate,
        omega_t - omega_T. At the equilibrium the head nodes are on the axis, where the two descriptions agree;
        off it (perturbations) one common frame keeps the linearised dynamics autonomous, so a rigid sideways
        shift or tilt of the whole robot is the neutral mode it physically is."""
        Om_n = np.full(self.N, omega_t)
        Om_e = np.where(self.head_edge, omega_t - omega_T, omega_t)
        return Om_n, Om_e

    def fields(self, q, frames_t, omega_T, omega_t, U):
        """(v, a, dv/domega_t, da/domega_t, dv/dU) as DOF vectors (dv/dU is shared: read it, do not write it)."""
        N, ndof = self.N, self.model.ndof
        x = q[: 3 * N].reshape(N, 3)
        _, Om_e = self._rates(omega_T, omega_t)          # every node turns at omega_t (see _rates)
        v, a, dv_dw, da_dw = (np.zeros(ndof) for _ in range(4))
        vn, an, wn, dan = (z[: 3 * N].reshape(N, 3) for z in (v, a, dv_dw, da_dw))
        wn[:, 1] = -x[:, 2]                              # e_x x x
        wn[:, 2] = x[:, 1]
        vn[:] = omega_t * wn
        vn[:, 0] = U
        an[:, 1:] = -(omega_t * omega_t) * x[:, 1:]      # -Omega^2 (0, y, z)
        dan[:, 1:] = -2.0 * omega_t * x[:, 1:]
        tx = frames_t[:, 0]                              # e_x . t of every edge
        v[3 * N:] = Om_e * tx
        dv_dw[3 * N:] = tx
        return v, a, dv_dw, da_dw, self._dv_dU

    def _velocity_derivatives(self, fr, omega_T, omega_t):
        """Values of Dv = dv/dq and Da = da/dq of the rigid-motion field, on their fixed structure: on the nodes
        dv/dx = Omega [e_x]x (v_y = -Omega z, v_z = Omega y) and da/dx = -Omega^2 diag(0, 1, 1); the twist rates
        Omega_e e_x.t_e have d(e_x.t)/dx_head = (e_x - (t.e_x) t) / l, the opposite for the tail."""
        Om_n, Om_e = self._rates(omega_T, omega_t)
        t, le = fr.t, fr.length
        g = (self._ex[None, :] - t[:, 0:1] * t) * (Om_e / le)[:, None]
        sq = -(Om_n ** 2)
        return self._pattern.dv_values(Om_n, g), np.concatenate([sq, sq])

    # ---------------------------------------------------------------- residual and Jacobian
    def _context(self, q, fr, v, a, dv, da) -> StepContext:
        N = self.N
        return StepContext(q=q, x=q[: 3 * N].reshape(N, 3), v=v, a=a, dv_dq=dv, da_dq=da, t=0.0, h=1.0,
                           drive_angle=0.0, frames=fr)

    def residual(self, q, committed: EdgeFrames, omega_T, omega_t, U):
        fr = self.model.elastic.trial_frames(q, committed)
        v, a, *_ = self.fields(q, fr.t, omega_T, omega_t, U)
        r = self.model.residual(self._context(q, fr, v, a, 0.0, 0.0))
        r[self.fixed] = 0.0
        return r, fr, v

    def _linear(self, q, committed: EdgeFrames, omega_T, omega_t, U) -> _Linear:
        """The residual and the parts of its Jacobian at (q, omega_t, U). The effects' Jacobians evaluated with
        the integrator coefficients (dv/dq, da/dq) = (0, 0), (1, 0), (0, 1) separate the explicit position
        dependence from dR/dv and dR/da (the springs depend on neither)."""
        model = self.model
        fr = model.elastic.trial_frames(q, committed)
        fields = self.fields(q, fr.t, omega_T, omega_t, U)
        ctx = self._context(q, fr, fields[0], fields[1], 0.0, 0.0)
        E00 = model.jacobian(ctx, springs=False)                     # the effects' part of J00
        r, J00 = model.residual_and_jacobian(ctx, effects_jacobian=E00)
        ctx.dv_dq, ctx.da_dq = 1.0, 0.0
        Kv = model.jacobian(ctx, springs=False) - E00                # dR/dv
        ctx.dv_dq, ctx.da_dq = 0.0, 1.0
        Ka = model.jacobian(ctx, springs=False) - E00                # dR/da
        dv_vals, da_vals = self._velocity_derivatives(fr, omega_T, omega_t)
        r[self.fixed] = 0.0
        return _Linear(r, fr, fields, J00, Kv, Ka, dv_vals, da_vals)

    def _assemble(self, lin: _Linear) -> sp.csc_matrix:
        _, _, dv_dw, da_dw, dv_dU = lin.fields
        return self._pattern.assemble(lin.J00, lin.Kv, lin.Ka, lin.dv_vals, lin.da_vals, dv_dw, da_dw, dv_dU)

    def _factor(self, lin: _Linear):
        """The Jacobian's factors, something with ``solve(b)``: the arrow solver's (valid until this solver's next
        factorisation), or SuperLU's (:meth:`_BorderedPattern.factor_values`, the Jacobian assembled straight into
        its column order). Raises RuntimeError if the Jacobian is singular."""
        _, _, dv_dw, da_dw, dv_dU = lin.fields
        if self._arrow is not None:
            return self._factor_data(self._pattern.values(lin.J00, lin.Kv, lin.Ka, lin.dv_vals, lin.da_vals,
                                                          dv_dw, da_dw, dv_dU))
        return self._pattern.factor_values(self._pattern.values(lin.J00, lin.Kv, lin.Ka, lin.dv_vals, lin.da_vals,
                                                                dv_dw, da_dw, dv_dU, ordered=True))

    def _factor_data(self, data: np.ndarray):
        """The factors of the matrix whose CSC data on the bordered pattern is ``data``: the arrow solver's (its
        compiled kernels: warmup.groups_for names them for a steady solve; its interpreted twins, the same numbers
        to the last bit, only where a time-stepped run in this process deferred them), or SuperLU's."""
        if self._arrow is None:
            return self._pattern.factor_values(data[self._pattern.order_slots])
        self._arrow.factor(data)
        return self._arrow

    def system(self, q, committed: EdgeFrames, omega_T, omega_t, U):
        """Residual and Jacobian of the bordered system in the problem's unknowns: (q, omega_t, U) (free robot) or
        q (clamped flagellum)."""
        lin = self._linear(q, committed, omega_T, omega_t, U)
        return lin.r, self._assemble(lin), lin.frames

    # ---------------------------------------------------------------- Newton
    def _step_norm(self, dz: np.ndarray, omega_T: float) -> float:
        """Size of a Newton correction: positions over the edge length, angles in radians, omega_t against
        omega_T, U against the speed of a point turning at omega_T one edge length from the axis."""
        ndof, ell = self.model.ndof, self.model.length_scale
        w = np.empty(len(dz))
        w[: 3 * self.N] = 1.0 / ell
        w[3 * self.N: ndof] = 1.0
        if len(dz) > ndof:
            ref = max(abs(omega_T), 1e-12)
            w[ndof] = 1.0 / ref
            w[ndof + 1] = 1.0 / (ref * ell)
        return float(np.sqrt(np.mean((dz * w) ** 2)))

    def newton(self, q, committed, omega_T, omega_t, U, q_gauge):
        """Damped Newton (Deuflhard's natural monotonicity test); returns (q, omega_t, U, residual, iterations,
        frames) or raises SteadyFailed.

        The test compares the simplified correction J^-1 r(trial), with the Jacobian already factorised, to the
        Newton correction itself: unlike the residual's norm it is not dominated by the stiff stretching terms,
        which a full step along a turning flagellum raises by orders of magnitude for one iteration although the
        next removes them (pure Newton then converges quadratically)."""
        ndof = self.model.ndof
        problem = self.problem
        p = problem.pack(omega_t, U)                   # the unknowns beyond q
        r, fr, _ = self.residual(q, committed, omega_T, omega_t, U)
        rn = self._norm(r)
        lam = 1.0
        lu, dz_next = None, None      # a factorisation whose last simplified correction contracted fast
        for it in range(self.max_iterations + 1):
            g = q[self.gauge] - q_gauge
            rn = self._norm(r)
            if not math.isfinite(rn):
                raise SteadyFailed(f"non-finite residual at omega_T = {omega_T:.6g} rad/s")
            if rn <= self.tol and np.all(np.abs(g) < 1e-12):
                return q, omega_t, U, rn, it, fr
            if it == self.max_iterations:
                break
            if dz_next is not None:
                # the simplified correction the monotonicity test just computed, with the same factorisation: it
                # contracted at least 50x, so a fresh Jacobian would buy little (simplified Newton)
                dz, dz_next = dz_next, None
            else:
                lin = self._linear(q, committed, omega_T, omega_t, U)
                try:
                    lu = self._factor(lin)
                except RuntimeError as exc:
                    raise SteadyFailed(f"singular Jacobian at omega_T = {omega_T:.6g} rad/s: {exc}") from None
                dz = -lu.solve(np.concatenate([r, g]))
            if not np.all(np.isfinite(dz)):
                raise SteadyFailed(f"non-finite Newton step at omega_T = {omega_T:.6g} rad/s")
            dn = self._step_norm(dz, omega_T)
            lam = min(1.0, 2.0 * lam)
            while True:
                q_try = q + lam * dz[:ndof]
                p_try = p + lam * dz[ndof:]
                w_try, U_try = problem.rates(p_try, omega_T)
                r_try, fr_try, _ = self.residual(q_try, committed, omega_T, w_try, U_try)
                ok = np.all(np.isfinite(r_try))
                if ok:
                    bar = lu.solve(np.concatenate([r_try, q_try[self.gauge] - q_gauge]))
                    dn_try = self._step_norm(bar, omega_T)
                    if dn_try <= (1.0 - 0.5 * lam) * dn or dn <= 1e-14:
                        if lam == 1.0 and dn_try <= 0.02 * dn:
                            dz_next = -bar
                        break
                lam *= 0.5
                if lam < 1.0 / 1024.0:
                    raise SteadyFailed(f"the damped Newton iteration stalled at omega_T = {omega_T:.6g} rad/s "
                                       f"(residual {rn:.3g} N, tolerance {self.tol:.3g} N)")
            q, p, omega_t, U, r, fr = q_try, p_try, w_try, U_try, r_try, fr_try
        raise SteadyFailed(f"Newton did not converge in {self.max_iterations} iterations at omega_T = "
                           f"{omega_T:.6g} rad/s (residual {self._norm(r):.3g} N, tolerance {self.tol:.3g} N)")

    def initial_guess(self, omega_T: float):
        """(q, omega_t, U): the straight robot turning as a rigid body at the problem's first guess of its rates
        (:meth:`FreeRobot.first_guess`)."""
        return (self.net.initial_q(), *self.problem.first_guess(omega_T))

    def guess_from(self, other: "SteadySolver", sol: SteadySolution):
        """(q, omega_t, U) on this solver's mesh from ``sol``, an equilibrium of the same robot on ``other``'s (the
        same scene at another flagellum edge length, e.g. Richardson's coarse one), or None if the two robots
        differ beyond their flagella's edge counts.

        The rigid parts (head, shaft, plate, sockets) are the same nodes and edges in both: copied. Along each
        flagellum the node positions are a cubic (Hermite) interpolation of the other's in arc length and the twist angles a linear
        interpolation of the other's at the edge midpoints. Both are measured from the reference frames carried
        from the straight robot's, which is where a solve from the straight robot measures them, so the guess is
        that solve's answer up to the discretisation's difference; Newton removes the rest."""
        a, b = other.net, self.net
        if (len(a.flagella_nodes) != len(b.flagella_nodes) or a.n_nodes - sum(map(len, a.flagella_nodes))
                != b.n_nodes - sum(map(len, b.flagella_nodes)) or type(other.problem) is not type(self.problem)):
            return None
        def rigid(n_total, parts):
            mask = np.ones(n_total, bool)
            for p in parts:
                mask[p] = False
            return np.nonzero(mask)[0]

        # a flagellum's first node p_i is the socket's end: it stays with the rigid parts
        ra = rigid(a.n_nodes, [f[1:] for f in a.flagella_nodes])
        rb = rigid(b.n_nodes, [f[1:] for f in b.flagella_nodes])
        ea = rigid(a.n_edges, a.flagella_edges)
        eb = rigid(b.n_edges, b.flagella_edges)
        if len(ra) != len(rb) or len(ea) != len(eb):
            return None
        Na, Nb = a.n_nodes, b.n_nodes
        xa = sol.q[: 3 * Na].reshape(Na, 3)
        q = b.initial_q()
        xb = q[: 3 * Nb].reshape(Nb, 3)
        xb[rb] = xa[ra]
        q[3 * Nb + eb] = sol.q[3 * Na + ea]
        for na, nb, fa, fb in zip(a.flagella_nodes, b.flagella_nodes, a.flagella_edges, b.flagella_edges):
            sa = np.linspace(0.0, 1.0, len(na))
            sb = np.linspace(0.0, 1.0, len(nb))
            xb[nb] = _hermite(sa, xa[na], sb)
            ma = 0.5 * (sa[1:] + sa[:-1])
            mb = 0.5 * (sb[1:] + sb[:-1])
            q[3 * Nb + fb] = np.interp(mb, ma, sol.q[3 * Na + fa])
        return q, sol.omega_t, -sol.v

    def solve(self, omega_T: float, start: SteadySolution | None = None, min_fraction: float = 1e-3,
              guess: tuple | None = None) -> SteadySolution:
        """The relative equilibrium at omega_T (rad/s), continued from ``start`` (default: the straight robot at
        rest). Newton first tries the whole way; where it fails, the step in omega_T is halved (continuation),
        and steps grow again by doubling. Raises SteadyFailed with the reason when no equilibrium is found.

        ``guess``: (q, omega_t, U) at omega_T itself, measured from the straight robot's reference frames (see
        :meth:`guess_from`), where Newton starts instead; no continuation then (SteadyFailed if it fails)."""
        t0 = time.perf_counter()
        problem = self.problem
        target = float(omega_T)
        scene = self.model.scene
        if "gravity" in scene.scene.effects and (scene.gravity.g[1] != 0.0 or scene.gravity.g[2] != 0.0):
            raise SteadyFailed(f"gravity.g = {list(scene.gravity.g)} has a part across the robot's axis (x): in the "
                               "frame turning with the robot it turns, so no relative equilibrium exists (only "
                               "gravity along x keeps the axial symmetry); a time-stepped run (flagbot run) shows "
                               "the motion")
        if guess is not None:
            q, omega_t, U = guess[0].copy(), float(guess[1]), float(guess[2])
            ratio = omega_t / target if target else 0.0
            committed = self.model.elastic.frames0.copy()
            w_done = target                  # no continuation: a failure at the target raises
            q_gauge = self.net.initial_q()[self.gauge]
        elif start is None:
            q, omega_t, U = self.initial_guess(target)
            ratio = omega_t / target if target else 0.0          # omega_t / omega_T of the guess
            committed = self.model.elastic.frames0.copy()
            w_done = 0.0
            q_gauge = self.net.initial_q()[self.gauge]
        else:
            q, omega_t, U, committed, w_done = start.q.copy(), start.omega_t, -start.v, start.frames.copy(), \
                start.omega_T
            ratio = omega_t / w_done if w_done else 0.5
            q_gauge = start.q[self.gauge]
        problem.prepare(q, committed)
        path, iterations, rn = [], 0, 0.0
        w = target
        while True:
            guess_w, guess_U = problem.rates(problem.continued(problem.pack(omega_t, U), w, w_done, ratio), w)
            try:
                q1, omega_t1, U1, rn, its, fr = self.newton(q.copy(), committed, w, guess_w, guess_U, q_gauge)
            except SteadyFailed as exc:
                step = w - w_done
                if abs(step) <= min_fraction * max(abs(target), 1e-12):
                    raise SteadyFailed(f"no relative equilibrium found beyond omega_T = {w_done:.6g} rad/s "
                                       f"(target {target:.6g} rad/s): {exc}") from None
                w = w_done + 0.5 * step
                continue
            iterations += its
            step = w - w_done
            path.append(w)
            # carry the shape forward, and its frames with it (small transports for the next solve)
            q, omega_t, U, committed, w_done = q1, omega_t1, U1, EdgeFrames.of(fr), w
            if w == target:
                break
            w = w_done + 2.0 * step
            if (w - target) * step > 0:
                w = target
        v_dofs = self.fields(q, committed.t, target, omega_t, U)[0]
        return SteadySolution(omega_T=target, omega_t=omega_t, omega_h=target - omega_t, v=-U, q=q, velocity=v_dofs,
                              frames=committed, residual=rn, iterations=iterations, continuation=path,
                              wall_seconds=time.perf_counter() - t0)

    def linearization(self, sol: SteadySolution):
        """(A, D, Mm, omega_t) of the linearised dynamics A dz + D dz' + Mm dz'' = 0 about ``sol``, in the frame
        that follows its rigid motion; z the problem's unknowns, (q, omega_t, U) for the free robot, q for the
        clamped flagellum.

        With v = V(q) + z' and a = A_r(q) + C z' + z'' (the rigid-motion field V, its centripetal acceleration
        A_r, and C the Coriolis term 2 Omega e_x x on the nodes and the twist rates' d(Omega_e e_x.t)/dx x' on
        the edges): A is the steady Jacobian, D = dR/dv + dR/da C on the DOFs (with the border columns' rates:
        a turning rate or speed that changes accelerates every node), and Mm = dR/da, the masses."""
        A, D, Mm, omega_t = self._linearization_data(sol)
        pat = self._pattern
        return sp.csc_matrix((A, pat.indices, pat.indptr), shape=(pat.n, pat.n)), self._sparse(D), \
            self._sparse(Mm), omega_t

    def _sparse(self, data: np.ndarray) -> sp.csc_matrix:
        """The matrix of CSC data ``data`` on the bordered pattern without the pattern's unused slots (no inertia
        effect: Mm = 0). ``data`` is compacted in place (eliminate_zeros): not to be read afterwards."""
        pat = self._pattern
        M = sp.csc_matrix((data, pat.indices.copy(), pat.indptr.copy()), shape=(pat.n, pat.n))
        M.eliminate_zeros()            # (on copies of the pattern's index arrays)
        return M

    def _linearization_data(self, sol: SteadySolution):
        """:meth:`linearization`'s A, D and Mm as CSC data on the bordered pattern (none dropped), and omega_t."""
        omega_t = sol.omega_t
        lin = self._linear(sol.q, sol.frames, sol.omega_T, omega_t, -sol.v)
        _, _, dv_dw, da_dw, dv_dU = lin.fields
        pat = self._pattern
        A = pat.values(lin.J00, lin.Kv, lin.Ka, lin.dv_vals, lin.da_vals, dv_dw, da_dw, dv_dU)
        coriolis = lin.dv_vals.copy()
        coriolis[: 2 * self.N] *= 2.0                 # the node entries: 2 Omega e_x x; the edges' as they are
        # D = Kv + Ka C, bordered by Ka dv/domega_t and Ka dv/dU: the steady Jacobian's assembly with (Kv, Ka, C)
        # in place of (J00, Kv, Dv), without its inertia terms and ones; Mm = Ka on the same pattern
        D = pat.values(lin.Kv, lin.Ka, None, coriolis, None, dv_dw, None, dv_dU, identity=False)
        Mm = pat.embed(lin.Ka)
        return A, D, Mm, omega_t

    def stability(self, sol: SteadySolution, k: int = 12, vectors: bool = True) -> Stability:
        """Growth rates mu of small perturbations of the equilibrium, in the frame that follows its rigid motion.

        The linearised dynamics A dz + D dz' + Mm dz'' = 0 (:meth:`linearization`: the bordered steady Jacobian,
        the medium's damping with the Coriolis terms, the masses; the gauge fixes translation along and rotation
        about the axis, and omega_t and U follow the force and torque balance) have solutions z e^(mu t). As a
        first-order pencil in y = (z, mu z), the modes nearest mu = 0 are the largest eigenvalues nu = 1/mu of
        y -> (A^-1 (-D z - Mm w), z), found by ARPACK with A factorised once (by the arrow solver, as Newton's
        Jacobian), as many as it takes to reach the neutral modes' |mu| = omega_t (so every mode slower than the
        turning itself is examined; the tests compare with the whole spectrum of dense solves). Stable when every
        mu found has a negative real part, apart from the neutral modes of the symmetry: a sideways shift and a
        tilt of the whole robot (it swims the same along any axis, from any point) appear in the turning frame as
        oscillations at exactly +-i omega_t. Inertia is included: the centripetal load reaches the drag at
        ~1800 rpm for design 2's flagellum, where the overdamped picture calls a folding equilibrium stable.

        ``vectors=False``: the eigenvalues alone (ARPACK's Ritz vectors are not formed), so the verdict, ``rate``
        and ``rates`` are the same but the modes are not classified: ``twist_shares`` is empty and
        ``shape_rate``, ``twist_rate`` and ``twist_frequency`` are NaN (what a sweep, which records only
        ``stable``, does not need)."""
        problem = self.problem
        a, d, m, omega_t = self._linearization_data(sol)
        n = self._pattern.n
        # shift-invert about sigma (mu = sigma + 1/theta)
        sigma = problem.shift(omega_t)
        lu = self._factor_data(a if sigma == 0.0 else a + sigma * d + sigma ** 2 * m)
        D, Mm = self._sparse(d), self._sparse(m)
        if Mm.nnz:
            # D z + Mm (w + sigma z) as one product with [D + sigma Mm, Mm]
            B = sp.hstack([D + sigma * Mm, Mm], format="csr")

            def matvec(y):
                x = lu.solve(B @ y)
                return np.concatenate([-x, y[:n] - sigma * x])
            op = spla.LinearOperator((2 * n, 2 * n), matvec=matvec, dtype=float)
        else:
            B = D.tocsr()
            op = spla.LinearOperator((n, n), matvec=lambda z: -lu.solve(B @ z), dtype=float)
        k = min(k, op.shape[0] - 2)
        # ARPACK's own start vector is random: the same state gave eigenvalues differing by up to 6e-5 relative
        # from run to run; a fixed one makes every report reproducible to the last digit
        v0 = np.random.default_rng(0).standard_normal(op.shape[0])
        while True:
            try:
                got = spla.eigs(op, k=k, which="LM", return_eigenvectors=vectors, tol=1e-10, maxiter=5000, v0=v0,
                                ncv=min(op.shape[0], max(2 * k + 1, ARNOLDI_VECTORS)))
                nu, vec = got if vectors else (got, None)
            except spla.ArpackNoConvergence as exc:      # the converged ones are still eigenvalues
                nu, vec = exc.eigenvalues, (exc.eigenvectors if vectors else None)
            keep = np.abs(nu) > 1e-300
            mu = sigma + 1.0 / nu[keep]
            paired = _paired(mu)
            mu = mu[paired]
            order = np.argsort(-mu.real)
            mu = mu[order]
            if vectors:
                vec = vec[:, keep][:, paired][:, order]
            neutral = problem.neutral(mu, omega_t, sigma)
            # every mode with |mu| below the neutral ones' omega_t is examined: more modes until they are found
            if neutral.sum() >= problem.neutral_modes or k >= min(MAX_MODES, op.shape[0] - 2):
                break
            k = min(2 * k, MAX_MODES, op.shape[0] - 2)
        rest = mu[~neutral]
        rate = float(rest[0].real) if len(rest) else 0.0
        growing = rest.real > GROWTH_RTOL * np.abs(rest)
        if not growing.any() and np.any(rest.real >= -GROWTH_RTOL * np.abs(rest)):
            rate = 0.0            # the slowest mode neither grows nor decays (to round-off): marginal
        if not vectors:
            return Stability(stable=not growing.any(), rate=rate, rates=[complex(m) for m in mu],
                             neutral=int(neutral.sum()))
        shares = self._twist_shares(vec[:n])
        twist = ~neutral & (shares > TWIST_SHARE)
        shape = ~neutral & ~twist
        shape_rate = float(mu[shape][0].real) if shape.any() else math.nan
        if shape.any() and abs(shape_rate) <= GROWTH_RTOL * abs(mu[shape][0]):
            shape_rate = 0.0
        tw = mu[twist][0] if twist.any() else complex(math.nan, math.nan)
        return Stability(stable=not growing.any(), rate=rate, rates=[complex(m) for m in mu],
                         neutral=int(neutral.sum()), twist_shares=[float(x) for x in shares],
                         shape_rate=shape_rate, twist_rate=float(tw.real), twist_frequency=float(abs(tw.imag)))

    def _twist_shares(self, z: np.ndarray) -> np.ndarray:
        """Per mode (column of z, the modes' DOF vectors, bordered or not): the share of its squared norm in the
        flagella's twist angles, the angles counted in metres (times the edge length) like the node positions."""
        net = self.net
        N, ndof = self.N, self.model.ndof
        ell2 = self.model.length_scale ** 2
        tw = 3 * N + np.concatenate(net.flagella_edges).astype(np.int64)
        w = np.ones(ndof)
        w[3 * N:] = ell2
        w[self._is_fixed] = 0.0
        a = np.abs(z[:ndof]) ** 2
        total = w @ a
        return np.where(total > 0, (w[tw] @ a[tw]) / np.where(total > 0, total, 1.0), 0.0)


def _hermite(s: np.ndarray, y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The cubic Hermite interpolation of the rows ``y`` at increasing ``s`` (slopes by central differences,
    one-sided at the ends) at ``t``, each row a point: the curve through the points with a continuous tangent
    (scipy.interpolate would cost a sweep worker ~0.3 s of importing)."""
    m = np.gradient(y, s, axis=0)
    k = np.clip(np.searchsorted(s, t, side="right") - 1, 0, len(s) - 2)
    h = s[k + 1] - s[k]
    u = ((t - s[k]) / h)[:, None]
    u2, u3 = u * u, u * u * u
    return ((2 * u3 - 3 * u2 + 1) * y[k] + (u3 - 2 * u2 + u) * h[:, None] * m[k]
            + (-2 * u3 + 3 * u2) * y[k + 1] + (u3 - u2) * h[:, None] * m[k + 1])


def solve_with_coarse(solver: SteadySolver, coarse: SteadySolver, omega_T: float
                      ) -> tuple[SteadySolution, SteadySolution | None]:
    """(fine, coarse): the equilibrium at omega_T on ``coarse``'s mesh (the same scene at twice the edge length:
    Richardson's second solve), solved first from the straight robot, then on ``solver``'s mesh started from it
    (:meth:`SteadySolver.guess_from`): a few Newton iterations instead of a solve from the straight robot. Where
    the coarse robot has no equilibrium, or Newton from its guess fails, the fine one is solved from the straight
    robot as before (coarse None in the first case). Raises SteadyFailed if the fine robot has none."""
    try:
        csol = coarse.solve(omega_T)
    except SteadyFailed:
        return solver.solve(omega_T), None
    guess = solver.guess_from(coarse, csol)
    if guess is not None:
        try:
            sol = solver.solve(omega_T, guess=guess)
            sol.wall_seconds += csol.wall_seconds
            return sol, csol
        except SteadyFailed:
            pass
    return solver.solve(omega_T), csol


def summary(model: RobotModel, sol: SteadySolution) -> dict:
    """The fields of ``flagbot run --json`` for the equilibrium (one schema: :func:`.observe.summary_fields`),
    plus its residual and Newton iterations."""
    problem = steady_problem(model)
    rates = {"omega_T": sol.omega_T, "omega_h": sol.omega_h, "omega_t": sol.omega_t, "v": sol.v, "steady": True}
    run = {"method": "steady", "residual": sol.residual, "newton_iterations": sol.iterations,
           "continuation": list(sol.continuation), "wall_seconds": sol.wall_seconds,
           # run --json's time-stepping fields, for one schema: no steps, no simulated time, no window
           "steady_change": None, "steady_rtol": None, "window": None, "time": None, "steps": 0,
           "dt_reductions": 0, "real_time_factor": None, "kernels": kernels_mode(),
           "rft_coefficients": coefficients_report(model.scene)}
    return summary_fields(model.scene, float(model.net.node_mass.sum()), rates, run, **problem.observations(sol))
