"""Input arrays of the solvers' frozen models: copied, checked and made read-only once, at construction."""

from __future__ import annotations

import numpy as np

from headsim.errors import ParameterError


def frozen_array(a, dtype=np.float64, shape=None, name: str = "array") -> np.ndarray:
    """A read-only C-contiguous copy of ``a`` as ``dtype``; ParameterError naming ``name`` when ``shape`` is given
    and not met, or when a floating-point array holds NaN/inf."""
    arr = np.array(a, dtype=dtype, order="C")
    if shape is not None and arr.shape != shape:
        raise ParameterError(f"{name} must have shape {shape}, got {arr.shape}")
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise ParameterError(f"{name} contains NaN/inf")
    arr.flags.writeable = False
    return arr
