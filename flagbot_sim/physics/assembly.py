"""Sparse Jacobian assembly on a pattern built once.

Every contribution to the Jacobian is a batch of dense blocks: rows (K, a) x cols (K, b) DOF indices with values
(K, a, b). At construction all (row, col) pairs of all batches, plus the diagonal, are merged into one CSC
structure; each block entry gets the position of its slot in the CSC data array. The springs and effects then add
their values straight into that array through their slots: no index sorting, no COO conversion, no per-step
allocation of the pattern.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

#: SparsePattern of each block structure built in this process (:func:`shared_pattern`): key -> pattern
_PATTERNS: dict = {}
#: patterns kept at most (a sweep has a handful of structures, each with its coarse twin)
PATTERN_CACHE_SIZE = 16


def shared_pattern(ndof: int, blocks: list[tuple[np.ndarray, np.ndarray]]) -> "SparsePattern":
    """The :class:`SparsePattern` of ``blocks``, built once per process: it depends on the blocks' index arrays
    alone (the key holds them whole), and is only read after it is built, so every model of one structure (a
    sweep's points, the Richardson coarse robot of each) shares it. Building one costs ~0.8 ms of sorting."""
    arrays = [(np.asarray(r, np.int64), np.asarray(c, np.int64)) for r, c in blocks]
    key = (ndof,) + tuple((r.shape, c.shape, r.tobytes(), c.tobytes()) for r, c in arrays)
    got = _PATTERNS.get(key)
    if got is None:
        got = SparsePattern(ndof, arrays)
        if len(_PATTERNS) >= PATTERN_CACHE_SIZE:
            _PATTERNS.pop(next(iter(_PATTERNS)))
        _PATTERNS[key] = got
    return got


class SparsePattern:
    def __init__(self, ndof: int, blocks: list[tuple[np.ndarray, np.ndarray]]):
        self.ndof = ndof
        rows, cols, sizes = [], [], []
        for r, c in blocks:
            r = np.asarray(r, np.int64)
            c = np.asarray(c, np.int64)
            R = np.broadcast_to(r[:, :, None], (r.shape[0], r.shape[1], c.shape[1]))
            C = np.broadcast_to(c[:, None, :], (r.shape[0], r.shape[1], c.shape[1]))
            rows.append(R.ravel())
            cols.append(C.ravel())
            sizes.append(R.size)
        diag = np.arange(ndof, dtype=np.int64)
        rows.append(diag)
        cols.append(diag)
        all_r = np.concatenate(rows)
        all_c = np.concatenate(cols)
        key = all_c * ndof + all_r                      # CSC order: column-major, rows sorted
        uniq, inverse = np.unique(key, return_inverse=True)
        self.nnz = len(uniq)
        self.indices = (uniq % ndof).astype(np.int32)
        col_of = uniq // ndof
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(col_of, minlength=ndof))]).astype(np.int32)
        offsets = np.concatenate([[0], np.cumsum(sizes)])
        self.slots = [inverse[offsets[i]:offsets[i + 1]] for i in range(len(blocks))]
        self.diag_slots = inverse[offsets[-1]:]
        self.row_of_slot = self.indices.astype(np.int64)
        self.col_of_slot = col_of

    def matrix(self, data: np.ndarray) -> sp.csc_matrix:
        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.ndof, self.ndof))

    def fix_rows_mask(self, fixed_dofs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Slots in rows of ``fixed_dofs`` (to zero) and their diagonal slots (to set to one)."""
        is_fixed = np.zeros(self.ndof, bool)
        is_fixed[fixed_dofs] = True
        return np.nonzero(is_fixed[self.row_of_slot])[0], self.diag_slots[fixed_dofs]
