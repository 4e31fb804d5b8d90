"""Sparse assembly of element matrices with a precomputed CSR pattern."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


class ElementAssembler:
    """Scatter element matrices (m, 3k, 3k) of elements (m, k) vertex ids into a (3n, 3n) CSR matrix.

    The pattern (and the map from element entries to CSR slots) is computed once; each assembly is
    one ``np.bincount``. Local dof order is (vertex a, component i) -> 3 a + i.
    """

    def __init__(self, elements: np.ndarray, n_vertices: int):
        el = np.asarray(elements, dtype=np.int64)
        m, k = el.shape
        dofs = (3 * el[:, :, None] + np.arange(3)[None, None, :]).reshape(m, 3 * k)
        rows = np.repeat(dofs, 3 * k, axis=1).ravel()
        cols = np.tile(dofs, (1, 3 * k)).ravel()
        n = 3 * n_vertices
        key = rows * n + cols
        uniq, self._slot = np.unique(key, return_inverse=True)
        self._slot = self._slot.ravel()
        r = uniq // n
        self._indices = (uniq % n).astype(np.int32 if n < 2**31 else np.int64)
        self._indptr = np.zeros(n + 1, dtype=self._indices.dtype)
        np.add.at(self._indptr, r + 1, 1)
        self._indptr = np.cumsum(self._indptr).astype(self._indices.dtype)
        self.shape = (n, n)
        self.nnz = len(uniq)

    def assemble(self, values: np.ndarray) -> sp.csr_matrix:
        data = np.bincount(self._slot, weights=np.asarray(values).ravel(), minlength=self.nnz)
        return sp.csr_matrix((data, self._indices.copy(), self._indptr.copy()), shape=self.shape)
