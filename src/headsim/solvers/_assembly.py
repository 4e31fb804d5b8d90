"""Sparse assembly of element matrices into a fixed CSR pattern with a precomputed scatter map."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit


@njit(cache=True)
def _scatter(slot, values, out):
    """out[slot[e]] += values[e] over the flattened element entries (Numba, no temporary arrays)."""
    out[:] = 0.0
    for e in range(slot.shape[0]):
        out[slot[e]] += values[e]


class ElementAssembler:
    """Scatter element matrices (m, 3k, 3k) of elements (m, k) vertex ids into a (3n, 3n) CSR matrix.

    The pattern is built once at the vertex level (unique vertex pairs, m k^2 keys instead of
    9 m k^2) and expanded to 3 x 3 blocks: row 3a + i holds the columns 3b + j of a's neighbours b in
    increasing order, so the CSR arrays are sorted and canonical. The map from every element entry
    to its CSR slot is kept; each assembly is one Numba scatter into the fixed pattern. Local dof
    order is (vertex a, component i) -> 3 a + i.
    """

    def __init__(self, elements: np.ndarray, n_vertices: int):
        el = np.asarray(elements, dtype=np.int64)
        m, k = el.shape
        nv = int(n_vertices)
        va = np.repeat(el, k, axis=1).ravel()   # (m k k,) row vertex of local block (alpha, beta)
        vb = np.tile(el, (1, k)).ravel()        # column vertex
        key = va * nv + vb
        uniq, block_of = np.unique(key, return_inverse=True)
        block_of = block_of.ravel()
        ba, bb = uniq // nv, uniq % nv          # block rows / columns, sorted by (row, column)
        deg = np.bincount(ba, minlength=nv)     # blocks per block row
        start = np.concatenate([[0], np.cumsum(deg)])
        # scalar CSR: row 3a + i has 3 deg(a) entries, starting at 9 start(a) + 3 i deg(a)
        n = 3 * nv
        idx_dtype = np.int32 if 9 * len(uniq) < 2**31 else np.int64
        row_len = np.repeat(3 * deg, 3)
        self._indptr = np.concatenate([[0], np.cumsum(row_len)]).astype(idx_dtype)
        # indices: for block row a and component i, the columns 3 b + j of its blocks in order
        pos_in_row = np.arange(len(uniq)) - start[ba]                      # block's rank within its row
        blk_base = 9 * start[ba]                                           # first slot of block row a
        i3 = np.arange(3)
        # slot(block, i, j) = 9 start(a) + 3 i deg(a) + 3 rank + j
        slot_block = (blk_base[:, None, None] + 3 * i3[None, :, None] * deg[ba][:, None, None]
                      + 3 * pos_in_row[:, None, None] + i3[None, None, :])  # (blocks, 3, 3)
        indices = np.empty(9 * len(uniq), dtype=idx_dtype)
        indices[slot_block.ravel()] = np.broadcast_to(3 * bb[:, None, None] + i3[None, None, :],
                                                      slot_block.shape).ravel()
        self._indices = indices
        # element entry (t, 3 alpha + i, 3 beta + j) -> slot of block (t, alpha, beta), component (i, j)
        sb = slot_block[block_of].reshape(m, k, k, 3, 3)
        self._slot = np.ascontiguousarray(sb.transpose(0, 1, 3, 2, 4).reshape(-1)).astype(np.int64)
        self.shape = (n, n)
        self.nnz = len(indices)

    def assemble(self, values: np.ndarray) -> sp.csr_matrix:
        data = np.empty(self.nnz)
        _scatter(self._slot, np.ascontiguousarray(values, dtype=np.float64).ravel(), data)
        out = sp.csr_matrix((data, self._indices.copy(), self._indptr.copy()), shape=self.shape)
        out.has_sorted_indices = True
        return out
