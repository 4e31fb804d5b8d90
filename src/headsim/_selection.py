"""Index selections given by the user: integer indices or a boolean mask over n items."""

from __future__ import annotations

import numpy as np

from headsim.errors import ParameterError


def index_selection(values, n: int, name: str) -> np.ndarray:
    """The sorted distinct int64 indices in 0 … n − 1 that ``values`` selects: integer indices (any order, repeats
    allowed; empty: none) or an (n,) bool mask. ParameterError naming ``name`` (e.g. "fibre") for a mask of another
    shape, non-integer or non-1-D indices, or an index outside 0 … n − 1."""
    a = np.asarray(values)
    if a.dtype == np.bool_:
        if a.shape != (n,):
            raise ParameterError(f"a {name} mask must have shape ({n},), got {a.shape}")
        return np.flatnonzero(a).astype(np.int64)
    if a.size == 0:
        return np.zeros(0, np.int64)
    if a.ndim != 1 or not np.issubdtype(a.dtype, np.integer):
        raise ParameterError(f"{name} indices must be a 1-D array of integers or an ({n},) bool mask, got a "
                             f"{a.dtype} array of shape {a.shape}")
    if a.min() < 0 or a.max() >= n:
        raise ParameterError(f"{name} indices must be within 0 … {n - 1}, got {a.min()} … {a.max()}")
    return np.unique(a.astype(np.int64))
