"""Linear solvers for the Newton system J dq = -r on the fixed sparsity pattern.

* :class:`ArrowSolver` exploits the robot's structure: each flagellum's Jacobian block is banded (a chain of
  nodes and edges, interleaved), and the flagella couple only through a small *core* (head, joint, plate arms,
  sockets). With the flagella ordered first and the core last the matrix is an "arrow":

      [A_1          B_1]
      [     A_2     B_2]      A_i banded   -> LAPACK dgbtrf (partial pivoting), O(N_i b^2)
      [         ... ...]      S = D - sum_i C_i A_i^-1 B_i   (small, dense) -> LAPACK dgetrf
      [C_1  C_2 ... D  ]

  so the cost grows linearly with the number of nodes. The factorisation and the solves run as one compiled
  call each, calling LAPACK (scipy's own, through ``scipy.linalg.cython_lapack``) for every LU: the only LU
  implementation in the package is LAPACK's.
* :class:`SparseLU` is scipy's SuperLU (COLAMD ordering): general, used when a network has no arrow structure.

Both take the CSC data array assembled on :class:`~flagbot_sim.physics.assembly.SparsePattern` (the arrow solver
also the steady solver's bordered Jacobian, steady.py, whose two border columns and rows join the core); the arrow
solver maps every CSC slot once, at construction, to its place in the banded / dense blocks.
"""
from __future__ import annotations

import llvmlite.binding as llvm
import numpy as np
from numba import types
from numba.extending import get_cython_function_address

from .assembly import SparsePattern
from .jit import external, interpreted, kernel, stage
from .tiers import deferred


class SingularJacobian(RuntimeError):
    pass


def _lapack(name: str, nargs: int):
    """A LAPACK routine of scipy's, callable from compiled code, every argument passed by reference (Fortran ABI).

    Bound by symbol name (registered with LLVM in every process), not by address, so the compiled callers can
    be cached on disk like every other kernel. Each reference is passed as an address in an int64, which the
    64-bit calling conventions pass exactly as a pointer: the callers form it as an array's base address plus a
    byte offset, where an array slice and its ``.ctypes`` compile to ~100 lines of code each (docs/startup.md).
    Every array whose address is passed must stay referenced until the call returns: the work arrays are the
    callers' arguments.
    """
    symbol = f"flagbot_{name}"
    llvm.add_symbol(symbol, get_cython_function_address("scipy.linalg.cython_lapack", name))
    return types.ExternalFunction(symbol, types.void(*([types.int64] * nargs)))


_dgbtrf = _lapack("dgbtrf", 8)     # m n kl ku ab ldab ipiv info
_dgbtrs = _lapack("dgbtrs", 11)    # trans n kl ku nrhs ab ldab ipiv b ldb info
_dgetrf = _lapack("dgetrf", 6)     # m n a lda ipiv info
_dgetrs = _lapack("dgetrs", 9)     # trans n nrhs a lda ipiv b ldb info

#: LAPACK's integer arguments live in a work array of int32 (``iw``, 8 entries, 4 bytes apart): byte offsets
I0, I1, I2, I3, I4, INFO, I6, TRANS = 0, 4, 8, 12, 16, 20, 24, 28


@stage
def _address(a):
    """The address of an array's first element, as an int64."""
    return np.int64(a.ctypes.data)


@stage
def _band_factor(buf, off, ldab, m, kl, ku, ipiv, piv_off, iw):
    """dgbtrf on the Fortran-ordered band matrix buf[off: off + ldab m], pivots into ipiv[piv_off:]; returns
    LAPACK's info."""
    iw[0], iw[1], iw[2], iw[3], iw[4] = m, m, kl, ku, ldab
    w = _address(iw)
    _dgbtrf(w + I0, w + I1, w + I2, w + I3, _address(buf) + 8 * off, w + I4, _address(ipiv) + 4 * piv_off,
            w + INFO)
    return iw[5]


@stage
def _band_solve(buf, off, ldab, m, kl, ku, ipiv, piv_off, rhs, rhs_off, nrhs, iw):
    """dgbtrs: overwrite the Fortran-ordered (m, nrhs) block rhs[rhs_off:] with A^-1 rhs."""
    iw[0], iw[1], iw[2], iw[3], iw[4], iw[6] = m, kl, ku, nrhs, ldab, m
    iw[7] = 78                    # "N" (the first byte of the int32)
    w = _address(iw)
    _dgbtrs(w + TRANS, w + I0, w + I1, w + I2, w + I3, _address(buf) + 8 * off, w + I4,
            _address(ipiv) + 4 * piv_off, _address(rhs) + 8 * rhs_off, w + I6, w + INFO)


@kernel
def _arrow_factor(data, dest, buf, ab_off, ab_rows, ab_cols, kl, ku, B_off, C_off, cc_ptr, cc, cr_ptr, cr, D_off,
                  nc, ipiv, piv_ptr, Y, Y_off, core_piv, iw):
    """Factor every chain block, form Y_i = A_i^-1 B_i, the Schur complement S = D - sum C_i Y_i and its LU
    (``iw``: LAPACK's int32 work array, 8 entries).

    Returns 0, i + 1 if chain block i is singular, or -1 if the Schur complement is."""
    for s in range(buf.shape[0]):
        buf[s] = 0.0
    for s in range(data.shape[0]):
        buf[dest[s]] = data[s]
    for i in range(ab_off.shape[0]):
        m = ab_cols[i]
        p0 = piv_ptr[i]
        if _band_factor(buf, ab_off[i], ab_rows[i], m, kl[i], ku[i], ipiv, p0, iw) != 0:
            return i + 1
        ncc = cc_ptr[i + 1] - cc_ptr[i]
        ncr = cr_ptr[i + 1] - cr_ptr[i]
        y0 = Y_off[i]
        for s in range(m * ncc):                                            # B_i, Fortran (m, ncc)
            Y[y0 + s] = buf[B_off[i] + s]
        if ncc:
            _band_solve(buf, ab_off[i], ab_rows[i], m, kl[i], ku[i], ipiv, p0, Y, y0, ncc, iw)
        c0 = C_off[i]
        for a in range(ncr):
            row = cr[cr_ptr[i] + a]
            for k in range(ncc):
                col = cc[cc_ptr[i] + k]
                acc = 0.0
                for rr in range(m):
                    acc += buf[c0 + a * m + rr] * Y[y0 + k * m + rr]
                buf[D_off + row * nc + col] -= acc
    # S is stored row-major, which LAPACK reads as S^T: factor S^T, solve with 'T'
    iw[0], iw[1], iw[2] = nc, nc, nc
    w = _address(iw)
    _dgetrf(w + I0, w + I1, _address(buf) + 8 * D_off, w + I2, _address(core_piv), w + INFO)
    if iw[5] != 0:
        return -1
    return 0


@kernel
def _arrow_solve(buf, ab_off, ab_rows, ab_cols, kl, ku, C_off, cc_ptr, cc, cr_ptr, cr, D_off, nc, ipiv, piv_ptr,
                 Y, Y_off, core_piv, chain_dofs, core_dofs, b, x, rhs, z, iw):
    """Solve J x = b with the factors of :func:`_arrow_factor` (``rhs`` (nc), ``z`` (chain DOFs), ``iw`` (8
    int32): work arrays)."""
    one = np.int64(1)             # one right-hand side (a literal 1 would compile _band_solve a second time)
    for k in range(nc):
        rhs[k] = b[core_dofs[k]]
    for i in range(ab_off.shape[0]):
        m = ab_cols[i]
        z0 = piv_ptr[i]
        for k in range(m):
            z[z0 + k] = b[chain_dofs[z0 + k]]
        _band_solve(buf, ab_off[i], ab_rows[i], m, kl[i], ku[i], ipiv, z0, z, z0, one, iw)
        c0 = C_off[i]
        for a in range(cr_ptr[i + 1] - cr_ptr[i]):
            acc = 0.0
            for rr in range(m):
                acc += buf[c0 + a * m + rr] * z[z0 + rr]
            rhs[cr[cr_ptr[i] + a]] -= acc
    iw[0], iw[1], iw[2], iw[3] = nc, 1, nc, nc
    iw[7] = 84                    # "T"
    w = _address(iw)
    _dgetrs(w + TRANS, w + I0, w + I1, _address(buf) + 8 * D_off, w + I2, _address(core_piv), _address(rhs),
            w + I3, w + INFO)
    for k in range(nc):
        x[core_dofs[k]] = rhs[k]
    for i in range(ab_off.shape[0]):
        m = ab_cols[i]
        z0 = piv_ptr[i]
        y0 = Y_off[i]
        ncc = cc_ptr[i + 1] - cc_ptr[i]
        for rr in range(m):
            acc = z[z0 + rr]
            for k in range(ncc):
                acc -= Y[y0 + k * m + rr] * rhs[cc[cc_ptr[i] + k]]
            x[chain_dofs[z0 + rr]] = acc


# ----------------------------------------------------------------------------------------------- interpreted twins
# The two kernels above, run by the interpreter: the band stages' own twins (jit.interpreted) and the same LAPACK
# functions (jit.external: the very functions the compiled code calls) on the same buffers, and numpy for the
# loops, summing in the same order (np.add.accumulate adds left to right, from a leading 0.0 as the loops'
# accumulators start): the same numbers to the last bit, and the same factors in the same places, so a
# factorisation made here serves the compiled solve and back. What a first run steps with while a background
# process compiles the kernels (warmup.py, group "arrow").
def _dots(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(len(rows), len(cols)) sums of products of their rows, each summed left to right from 0.0 (as a loop
    ``acc += a[i] * b[i]`` does)."""
    prods = rows[:, None, :] * cols[None, :, :]
    acc = np.zeros(prods.shape[:2] + (prods.shape[2] + 1,))
    acc[:, :, 1:] = prods
    return np.add.accumulate(acc, axis=2)[:, :, -1]


def _arrow_factor_py(data, dest, buf, ab_off, ab_rows, ab_cols, kl, ku, B_off, C_off, cc_ptr, cc, cr_ptr, cr,
                     D_off, nc, ipiv, piv_ptr, Y, Y_off, core_piv, iw):
    """:func:`_arrow_factor`, interpreted."""
    buf[:] = 0.0
    buf[dest] = data
    for i in range(ab_off.shape[0]):
        m = int(ab_cols[i])
        p0 = int(piv_ptr[i])
        if interpreted(_band_factor)(buf, ab_off[i], ab_rows[i], m, kl[i], ku[i], ipiv, p0, iw) != 0:
            return i + 1
        ncc = int(cc_ptr[i + 1] - cc_ptr[i])
        ncr = int(cr_ptr[i + 1] - cr_ptr[i])
        y0 = int(Y_off[i])
        Y[y0: y0 + m * ncc] = buf[B_off[i]: B_off[i] + m * ncc]
        if ncc:
            interpreted(_band_solve)(buf, ab_off[i], ab_rows[i], m, kl[i], ku[i], ipiv, p0, Y, y0, ncc, iw)
        if ncr and ncc:
            c0 = int(C_off[i])
            acc = _dots(buf[c0: c0 + ncr * m].reshape(ncr, m), Y[y0: y0 + ncc * m].reshape(ncc, m))
            rows, cols = cr[cr_ptr[i]: cr_ptr[i + 1]], cc[cc_ptr[i]: cc_ptr[i + 1]]
            buf[D_off + rows[:, None] * nc + cols[None, :]] -= acc
    iw[0], iw[1], iw[2] = nc, nc, nc
    w = iw.ctypes.data
    external(_dgetrf)(w + I0, w + I1, buf.ctypes.data + 8 * D_off, w + I2, core_piv.ctypes.data, w + INFO)
    return -1 if iw[5] != 0 else 0


def _arrow_solve_py(buf, ab_off, ab_rows, ab_cols, kl, ku, C_off, cc_ptr, cc, cr_ptr, cr, D_off, nc, ipiv, piv_ptr,
                    Y, Y_off, core_piv, chain_dofs, core_dofs, b, x, rhs, z, iw):
    """:func:`_arrow_solve`, interpreted."""
    rhs[:] = b[core_dofs]
    for i in range(ab_off.shape[0]):
        m = int(ab_cols[i])
        z0 = int(piv_ptr[i])
        z[z0: z0 + m] = b[chain_dofs[z0: z0 + m]]
        interpreted(_band_solve)(buf, ab_off[i], ab_rows[i], m, kl[i], ku[i], ipiv, z0, z, z0, 1, iw)
        ncr = int(cr_ptr[i + 1] - cr_ptr[i])
        if ncr:
            c0 = int(C_off[i])
            rhs[cr[cr_ptr[i]: cr_ptr[i + 1]]] -= _dots(buf[c0: c0 + ncr * m].reshape(ncr, m),
                                                       z[None, z0: z0 + m])[:, 0]
    iw[0], iw[1], iw[2], iw[3] = nc, 1, nc, nc
    iw[7] = 84
    w = iw.ctypes.data
    external(_dgetrs)(w + TRANS, w + I0, w + I1, buf.ctypes.data + 8 * D_off, w + I2, core_piv.ctypes.data,
                            rhs.ctypes.data, w + I3, w + INFO)
    x[core_dofs] = rhs
    for i in range(ab_off.shape[0]):
        m = int(ab_cols[i])
        z0 = int(piv_ptr[i])
        y0 = int(Y_off[i])
        acc = z[z0: z0 + m].copy()
        for k in range(int(cc_ptr[i + 1] - cc_ptr[i])):
            acc -= Y[y0 + k * m: y0 + (k + 1) * m] * rhs[cc[cc_ptr[i] + k]]
        x[chain_dofs[z0: z0 + m]] = acc


class SparseLU:
    name = "splu"

    def __init__(self, pattern: SparsePattern):
        self.pattern = pattern
        self._lu = None

    def factor(self, data: np.ndarray) -> None:
        try:
            import scipy.sparse.linalg as spla    # (here: a device that never uses it does not import it)
            self._lu = spla.splu(self.pattern.matrix(data), permc_spec="COLAMD")
        except RuntimeError as exc:
            raise SingularJacobian(str(exc)) from None

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self._lu.solve(b)


class ArrowSolver:
    name = "arrow"

    def __init__(self, pattern: SparsePattern, chains: list[np.ndarray]):
        """``chains``: for each flagellum, its DOFs in chain order (interleaved twist angle / node position).
        ``pattern``: any CSC structure with ``ndof``, ``nnz``, ``row_of_slot`` and ``col_of_slot`` (the model's
        SparsePattern, or the steady solver's bordered one, whose extra unknowns and rows join the core). Raises
        ValueError if two chains couple directly."""
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
        ab_shape, ab_off = [], []
        for i, c in enumerate(chains):
            ldab = 2 * self.kl[i] + self.ku[i] + 1        # LAPACK band storage with kl rows of fill-in space
            ab_shape.append((ldab, len(c)))
            ab_off.append(offset)
            offset += ldab * len(c)
        B_off, C_off = [], []
        for i, c in enumerate(chains):
            B_off.append(offset)
            offset += len(c) * len(self.couple_cols[i])
            C_off.append(offset)
            offset += len(self.couple_rows[i]) * len(c)
        nc = len(core)
        D_off = offset
        offset += nc * nc
        dest = np.empty(pattern.nnz, dtype=np.int64)
        r_pos, c_pos = pos[rows], pos[cols]
        for i in range(len(chains)):
            kl, ku = self.kl[i], self.ku[i]
            ldab, m = ab_shape[i]
            sel = (ro == i) & (co == i)      # band storage (Fortran order): A[r, c] -> ab[kl + ku + r - c, c]
            dest[sel] = ab_off[i] + c_pos[sel] * ldab + (kl + ku + r_pos[sel] - c_pos[sel])
            sel = (ro == i) & (co < 0)       # B_i: (chain rows) x (coupled core columns), Fortran order
            k = np.searchsorted(self.couple_cols[i], c_pos[sel])
            dest[sel] = B_off[i] + k * m + r_pos[sel]
            sel = (ro < 0) & (co == i)       # C_i: (coupled core rows) x (chain columns), row-major
            k = np.searchsorted(self.couple_rows[i], r_pos[sel])
            dest[sel] = C_off[i] + k * m + c_pos[sel]
        sel = (ro < 0) & (co < 0)
        dest[sel] = D_off + r_pos[sel] * nc + c_pos[sel]
        self.dest = dest
        i64 = lambda v: np.array(v, np.int64)   # noqa: E731
        self._piv_ptr = np.cumsum([0] + [len(c) for c in self.chains]).astype(np.int64)
        self._Y_off = np.cumsum([0] + [len(c) * len(cc) for c, cc in zip(chains, self.couple_cols)]).astype(np.int64)
        self._k = dict(
            ab_off=i64(ab_off), ab_rows=i64([s[0] for s in ab_shape]), ab_cols=i64([s[1] for s in ab_shape]),
            kl=i64(self.kl), ku=i64(self.ku), C_off=i64(C_off),
            cc_ptr=np.cumsum([0] + [len(c) for c in self.couple_cols]).astype(np.int64),
            cc=np.concatenate(self.couple_cols).astype(np.int64),
            cr_ptr=np.cumsum([0] + [len(c) for c in self.couple_rows]).astype(np.int64),
            cr=np.concatenate(self.couple_rows).astype(np.int64), D_off=D_off, nc=nc)
        self._B_off = i64(B_off)
        self._chain_dofs = np.concatenate(self.chains).astype(np.int64)
        self._core = core.astype(np.int64)
        self._buf = np.zeros(offset)
        self._ipiv = np.zeros(self._piv_ptr[-1], np.int32)
        self._Y = np.zeros(self._Y_off[-1])
        self._core_piv = np.zeros(nc, np.int32)
        self._iw = np.zeros(8, np.int32)            # LAPACK's integer arguments
        self._rhs = np.empty(nc)                    # solve's work arrays
        self._z = np.empty(len(self._chain_dofs))

    def copy(self) -> "ArrowSolver":
        """A solver of the same structure with work buffers of its own (the slot mapping, read only, shared): its
        factorisation is independent of this one's, and it costs no construction (~0.3-0.6 ms)."""
        new = object.__new__(ArrowSolver)
        new.__dict__.update(self.__dict__)
        for name in ("_buf", "_ipiv", "_Y", "_core_piv", "_iw", "_rhs", "_z"):
            setattr(new, name, np.zeros_like(getattr(self, name)))
        return new

    def factor(self, data: np.ndarray) -> None:
        k = self._k
        factor = _arrow_factor_py if deferred("arrow") else _arrow_factor
        bad = factor(data, self.dest, self._buf, k["ab_off"], k["ab_rows"], k["ab_cols"], k["kl"], k["ku"],
                     self._B_off, k["C_off"], k["cc_ptr"], k["cc"], k["cr_ptr"], k["cr"], k["D_off"], k["nc"],
                     self._ipiv, self._piv_ptr, self._Y, self._Y_off, self._core_piv, self._iw)
        if bad > 0:
            raise SingularJacobian(f"flagellum block {bad - 1} is singular")
        if bad < 0:
            raise SingularJacobian("core Schur complement is singular")

    def solve(self, b: np.ndarray) -> np.ndarray:
        k = self._k
        x = np.empty(self.ndof)
        solve = _arrow_solve_py if deferred("arrow") else _arrow_solve
        solve(self._buf, k["ab_off"], k["ab_rows"], k["ab_cols"], k["kl"], k["ku"], k["C_off"], k["cc_ptr"],
              k["cc"], k["cr_ptr"], k["cr"], k["D_off"], k["nc"], self._ipiv, self._piv_ptr, self._Y,
              self._Y_off, self._core_piv, self._chain_dofs, self._core, np.ascontiguousarray(b), x,
              self._rhs, self._z, self._iw)
        return x


def flagellum_chains(net) -> list[np.ndarray]:
    """Each flagellum's DOFs beyond its socket, interleaved (theta of edge k, then node k) along the chain."""
    chains = []
    for nodes, edges in zip(net.flagella_nodes, net.flagella_edges):
        nodes = np.asarray(nodes, np.int64)[1:]
        edges = np.asarray(edges, np.int64)[: len(nodes)]
        dofs = np.column_stack([net.edge_dof(edges), 3 * nodes, 3 * nodes + 1, 3 * nodes + 2])
        chains.append(dofs.ravel().astype(np.int64))
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
