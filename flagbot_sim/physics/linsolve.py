"""Linear solvers for the Newton system J dq = -r on the fixed sparsity pattern.

* :class:`ArrowSolver` exploits the robot's structure: each flagellum's Jacobian block is banded (a chain of
  nodes and edges, interleaved), and the flagella couple only through a small *core* (head, joint, plate arms,
  sockets). With the flagella ordered first and the core last the matrix is an "arrow":

      [A_1          B_1]
      [     A_2     B_2]      A_i banded   -> LAPACK dgbtrf (partial pivoting), O(N_i b^2)
      [         ... ...]      S = D - sum_i C_i A_i^-1 B_i   (small, dense) -> LAPACK getrf
      [C_1  C_2 ... D  ]

  so the cost grows linearly with the number of nodes.
* :class:`SparseLU` is scipy's SuperLU (COLAMD ordering): general, used when a network has no arrow structure.

Both take the CSC data array assembled on :class:`~flagbot_sim.physics.assembly.SparsePattern`; the arrow solver
maps every CSC slot once, at construction, to its place in the banded / dense blocks.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse.linalg as spla
from scipy.linalg import lapack

from . import kernels
from .assembly import SparsePattern


class SingularJacobian(RuntimeError):
    pass


class SparseLU:
    name = "splu"

    def __init__(self, pattern: SparsePattern):
        self.pattern = pattern
        self._lu = None

    def factor(self, data: np.ndarray) -> None:
        try:
            self._lu = spla.splu(self.pattern.matrix(data), permc_spec="COLAMD")
        except RuntimeError as exc:
            raise SingularJacobian(str(exc)) from None

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self._lu.solve(b)


class ArrowSolver:
    name = "arrow"

    def __init__(self, pattern: SparsePattern, chains: list[np.ndarray]):
        """``chains``: for each flagellum, its DOFs in chain order (interleaved twist angle / node position)."""
        n = pattern.ndof
        self.ndof = n
        owner = np.full(n, -1)                        # -1 = core, i = chain i
        pos = np.zeros(n, dtype=np.int64)             # position inside its chain (or inside the core)
        for i, c in enumerate(chains):
            owner[c] = i
            pos[c] = np.arange(len(c))
        core = np.nonzero(owner < 0)[0]
        pos[core] = np.arange(len(core))
        self.chains = [np.asarray(c) for c in chains]
        self.core = core
        rows, cols = pattern.row_of_slot, pattern.col_of_slot
        ro, co = owner[rows], owner[cols]
        if np.any((ro >= 0) & (co >= 0) & (ro != co)):
            raise ValueError("two flagella couple directly: not an arrow matrix")
        self.kl, self.ku, self.couple_cols, self.couple_rows = [], [], [], []
        for i in range(len(chains)):
            inside = (ro == i) & (co == i)
            d = pos[rows[inside]] - pos[cols[inside]]
            self.kl.append(int(max(d.max(), 0)))
            self.ku.append(int(max(-d.min(), 0)))
            # core DOFs that touch this chain: the columns of B_i and the rows of C_i
            self.couple_cols.append(np.unique(pos[cols[(ro == i) & (co < 0)]]))
            self.couple_rows.append(np.unique(pos[rows[(ro < 0) & (co == i)]]))
        # destination of every CSC slot in one flat buffer: [ab_0 | ab_1 | ... | B_0 | C_0 | ... | D]
        offset = 0
        self._ab_shape, self._ab_off = [], []
        for i, c in enumerate(chains):
            ldab = 2 * self.kl[i] + self.ku[i] + 1
            self._ab_shape.append((ldab, len(c)))
            self._ab_off.append(offset)
            offset += ldab * len(c)
        self._B_off, self._C_off = [], []
        for i, c in enumerate(chains):
            self._B_off.append(offset)
            offset += len(c) * len(self.couple_cols[i])
            self._C_off.append(offset)
            offset += len(self.couple_rows[i]) * len(c)
        nc = len(core)
        self._D_off = offset
        offset += nc * nc
        self.size = offset
        dest = np.empty(pattern.nnz, dtype=np.int64)
        r_pos, c_pos = pos[rows], pos[cols]
        for i in range(len(chains)):
            kl, ku = self.kl[i], self.ku[i]
            ldab = self._ab_shape[i][0]
            m = (ro == i) & (co == i)        # banded storage (Fortran order): A[r, c] -> ab[kl + ku + r - c, c]
            dest[m] = self._ab_off[i] + c_pos[m] * ldab + (kl + ku + r_pos[m] - c_pos[m])
            m = (ro == i) & (co < 0)         # B_i: (chain rows) x (coupled core columns), row-major
            k = np.searchsorted(self.couple_cols[i], c_pos[m])
            dest[m] = self._B_off[i] + r_pos[m] * len(self.couple_cols[i]) + k
            m = (ro < 0) & (co == i)         # C_i: (coupled core rows) x (chain columns)
            k = np.searchsorted(self.couple_rows[i], r_pos[m])
            dest[m] = self._C_off[i] + k * len(chains[i]) + c_pos[m]
        m = (ro < 0) & (co < 0)
        dest[m] = self._D_off + r_pos[m] * nc + c_pos[m]
        self.dest = dest
        self._factors = None
        # flat arrays for the compiled path
        self._k = dict(
            ab_off=np.array(self._ab_off, np.int64), ab_rows=np.array([s[0] for s in self._ab_shape], np.int64),
            ab_cols=np.array([s[1] for s in self._ab_shape], np.int64), kl=np.array(self.kl, np.int64),
            ku=np.array(self.ku, np.int64), B_off=np.array(self._B_off, np.int64),
            C_off=np.array(self._C_off, np.int64),
            cc_ptr=np.cumsum([0] + [len(c) for c in self.couple_cols]).astype(np.int64),
            cc=np.concatenate(self.couple_cols).astype(np.int64),
            cr_ptr=np.cumsum([0] + [len(c) for c in self.couple_rows]).astype(np.int64),
            cr=np.concatenate(self.couple_rows).astype(np.int64))
        # start of chain i in any per-chain-DOF concatenation: the chain DOFs and the band pivots alike
        self._chain_ptr = np.cumsum([0] + [len(c) for c in self.chains]).astype(np.int64)
        self._Y_off = np.cumsum([0] + [len(c) * len(cc) for c, cc in zip(chains, self.couple_cols)]).astype(np.int64)
        self._chain_dofs = np.concatenate(self.chains).astype(np.int64)
        self.compiled = kernels.AVAILABLE

    def factor(self, data: np.ndarray) -> None:
        if self.compiled:
            return self._factor_compiled(data)
        return self._factor_lapack(data)

    def _factor_compiled(self, data: np.ndarray) -> None:
        buf = np.zeros(self.size)
        buf[self.dest] = data
        ipiv = np.empty(self._chain_ptr[-1], np.int64)
        Y = np.empty(self._Y_off[-1])
        k = self._k
        bad = kernels.arrow_factor(buf, k["ab_off"], k["ab_rows"], k["ab_cols"], k["kl"], k["ku"], k["B_off"],
                                   k["C_off"], k["cc_ptr"], k["cc"], k["cr_ptr"], k["cr"], self._D_off,
                                   len(self.core), ipiv, self._chain_ptr, Y, self._Y_off)
        if bad:
            raise SingularJacobian(f"flagellum block {bad - 1} is singular")
        nc = len(self.core)
        core_piv = np.empty(nc, np.int64)
        if kernels.getrf(buf[self._D_off:self._D_off + nc * nc].reshape(nc, nc), core_piv):
            raise SingularJacobian("core Schur complement is singular")
        self._compiled_factors = (buf, ipiv, Y, core_piv)

    def _solve_compiled(self, b: np.ndarray) -> np.ndarray:
        buf, ipiv, Y, core_piv = self._compiled_factors
        k = self._k
        x = np.empty(self.ndof)
        kernels.arrow_solve(buf, k["ab_off"], k["ab_rows"], k["ab_cols"], k["kl"], k["ku"], k["C_off"], k["cc_ptr"],
                            k["cc"], k["cr_ptr"], k["cr"], self._D_off, len(self.core), ipiv, self._chain_ptr, Y,
                            self._Y_off, core_piv, self._chain_dofs, self._chain_ptr, self.core, b, x)
        return x

    def _factor_lapack(self, data: np.ndarray) -> None:
        buf = np.zeros(self.size)
        buf[self.dest] = data
        nc = len(self.core)
        S = buf[self._D_off:self._D_off + nc * nc].reshape(nc, nc)
        factors = []
        for i, c in enumerate(self.chains):
            ldab, m = self._ab_shape[i]
            ab = buf[self._ab_off[i]:self._ab_off[i] + ldab * m].reshape((ldab, m), order="F")
            lu, piv, info = lapack.dgbtrf(ab, self.kl[i], self.ku[i], overwrite_ab=1)
            if info != 0:
                raise SingularJacobian(f"flagellum block {i} is singular (dgbtrf info {info})")
            cc, cr = self.couple_cols[i], self.couple_rows[i]
            B = buf[self._B_off[i]:self._B_off[i] + m * len(cc)].reshape(m, len(cc))
            C = buf[self._C_off[i]:self._C_off[i] + len(cr) * m].reshape(len(cr), m)
            Y, info = lapack.dgbtrs(lu, self.kl[i], self.ku[i], B, piv)      # A_i^-1 B_i
            S[np.ix_(cr, cc)] -= C @ Y
            factors.append((lu, piv, C, Y))
        try:
            S_lu = sla.lu_factor(S, check_finite=False)
        except (ValueError, sla.LinAlgError) as exc:
            raise SingularJacobian(str(exc)) from None
        if np.any(np.diag(S_lu[0]) == 0.0):
            raise SingularJacobian("core Schur complement is singular")
        self._factors = (factors, S_lu)

    def solve(self, b: np.ndarray) -> np.ndarray:
        if self.compiled:
            return self._solve_compiled(b)
        factors, S_lu = self._factors
        x = np.empty(self.ndof)
        rhs_core = b[self.core].copy()
        zs = []
        for i, c in enumerate(self.chains):
            lu, piv, C, Y = factors[i]
            z, _ = lapack.dgbtrs(lu, self.kl[i], self.ku[i], b[c], piv)
            rhs_core[self.couple_rows[i]] -= C @ z
            zs.append(z)
        xc = sla.lu_solve(S_lu, rhs_core, check_finite=False)
        x[self.core] = xc
        for i, c in enumerate(self.chains):
            lu, piv, C, Y = factors[i]
            x[c] = zs[i] - Y @ xc[self.couple_cols[i]]
        return x


def flagellum_chains(net) -> list[np.ndarray]:
    """Each flagellum's DOFs beyond its socket, interleaved (theta of edge k, then node k) along the chain."""
    chains = []
    for nodes, edges in zip(net.flagella_nodes, net.flagella_edges):
        dofs = []
        for node, edge in zip(nodes[1:], edges):
            dofs.append(net.edge_dof(edge))
            dofs.extend(3 * node + np.arange(3))
        chains.append(np.array(dofs, dtype=np.int64))
    return chains


def make_solver(model, kind: str = "auto"):
    if kind == "splu":
        return SparseLU(model.pattern)
    try:
        return ArrowSolver(model.pattern, flagellum_chains(model.net))
    except ValueError:
        if kind == "arrow":
            raise
        return SparseLU(model.pattern)
