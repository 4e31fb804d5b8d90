"""Length units at the edges of headsim (SI metres inside).

Mesh files come in m, dm (the seed's planning system, Monkin 2016 §5.4), cm or mm; the caller states which. :func:`check_head_scale` flags a model
whose size is off by a factor of 10, 100 or 1000 for the size the caller expects (a face is about
0.15–0.25 m wide, a whole head about 0.2–0.35 m).
"""

from __future__ import annotations

import enum
import math
import warnings

import numpy as np

from headsim.errors import UnitsError


class Units(str, enum.Enum):
    """A length unit a mesh file may be written in."""

    m = "m"
    dm = "dm"
    cm = "cm"
    mm = "mm"

    @property
    def to_metres(self) -> float:
        """Factor that converts a length in this unit to metres."""
        return {"m": 1.0, "dm": 1e-1, "cm": 1e-2, "mm": 1e-3}[self.value]


def parse_units(units: str | Units) -> Units:
    """Return :class:`Units` for ``"m"``, ``"dm"``, ``"cm"`` or ``"mm"``; raise :class:`UnitsError` otherwise."""
    if isinstance(units, Units):
        return units
    try:
        return Units(str(units).strip().lower())
    except ValueError:
        raise UnitsError(f"unknown length unit {units!r}; use one of m, dm, cm, mm") from None


#: Plausible extents (largest bounding-box side, metres) of models headsim works with.
HEAD_SIZED_RANGE_M = (0.05, 0.5)


class UnitsWarning(UserWarning):
    """A model's size suggests that its stated unit is wrong."""


def check_head_scale(
    vertices_m: np.ndarray,
    *,
    source: str = "mesh",
    plausible_range_m: tuple[float, float] = HEAD_SIZED_RANGE_M,
    strict: bool = False,
) -> float:
    """Check that a head-sized model has a plausible size once converted to metres.

    Parameters
    ----------
    vertices_m : (n, 3) float64, m
    source : name of the file or object, used in the message.
    plausible_range_m : (lo, hi) largest bounding-box side, m.
    strict : raise :class:`UnitsError` instead of warning.

    Returns
    -------
    float
        The largest bounding-box side, m.
    """
    v = np.asarray(vertices_m, dtype=np.float64)
    if v.size == 0:
        return 0.0
    extent = float(np.max(v.max(axis=0) - v.min(axis=0)))
    lo, hi = plausible_range_m
    if lo <= extent <= hi:
        return extent
    hint = ""
    if extent > 0:
        for factor, name in ((10.0, "cm vs mm"), (100.0, "m vs cm"), (1000.0, "m vs mm")):
            for f in (factor, 1.0 / factor):
                if lo <= extent / f <= hi:
                    hint = (f" It would fit if it were scaled by {1 / f:g} — is the unit wrong ({name})?")
                    break
            if hint:
                break
    message = (
        f"{source}: largest extent {extent:.4g} m is outside the plausible range "
        f"{lo:g}–{hi:g} m for a head-sized model.{hint} State the file's unit with --units m|dm|cm|mm."
    )
    if strict or not math.isfinite(extent):
        raise UnitsError(message)
    warnings.warn(message, UnitsWarning, stacklevel=2)
    return extent
