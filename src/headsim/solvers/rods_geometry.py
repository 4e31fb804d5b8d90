"""Shape measures of a rod centreline: writhe, tangent turning, self-distance.

Used to assert the seed's qualitative examples with numbers (Sobottka 2008 fig. 3.20: an end-shortened,
twisted rod "collapses and snaps into a loop", the twist-to-writhe transition).

* :func:`writhe` is the Gauss double integral Wr = 1/(4 pi) int int (t1 x t2) . (r1 - r2) / |r1 - r2|^3,
  evaluated exactly for a polyline by the solid-angle formula of Klenin & Langowski (2000, Biopolymers
  54, 307, eq. 13-16). Writhe is not an integer for an open curve; closing it by long straight
  extensions along a given axis makes it the mean number of signed self-crossings of the projected
  curve over all directions. A planar loop whose tails run along the axis has |Wr| -> 1, a straight or
  gently (helically) buckled rod |Wr| << 1.
* :func:`min_self_distance` is the smallest distance between non-neighbouring segments (capsule test
  for self-contact), by exact segment-segment distances.
"""

from __future__ import annotations

import numpy as np

from headsim.errors import ParameterError

__all__ = ["writhe", "extend_along_axis", "min_self_distance", "segment_distances"]


def _check_polyline(points) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 2:
        raise ParameterError(f"a centreline must be (n >= 2, 3), got {p.shape}")
    if not np.isfinite(p).all():
        raise ParameterError("centreline must be finite")
    return p


def extend_along_axis(points, axis, length: float) -> np.ndarray:
    """The polyline with a straight segment of ``length`` (m) added before its first point (along
    -axis) and after its last point (along +axis)."""
    p = _check_polyline(points)
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    return np.vstack([p[0] - length * a, p, p[-1] + length * a])


def writhe(points, axis=None, extension: float | None = None) -> float:
    """Writhe of a polyline (n, 3) (Klenin & Langowski 2000); a closed curve repeats its first point
    at the end. If ``axis`` is given the curve is first extended at both ends by straight segments of
    ``extension`` (default 100x its span) along it."""
    p = _check_polyline(points)
    if axis is not None:
        span = float(np.linalg.norm(p.max(0) - p.min(0)))
        p = extend_along_axis(p, axis, 100.0 * span if extension is None else extension)
    a, b = p[:-1], p[1:]
    m = a.shape[0]
    i, j = np.triu_indices(m, k=2)  # neighbours share an end point and contribute nothing
    span = float(np.linalg.norm(p.max(0) - p.min(0)))
    if m > 2 and np.linalg.norm(p[0] - p[-1]) <= 1e-12 * span:  # closed: first and last segment are neighbours
        keep = ~((i == 0) & (j == m - 1))
        i, j = i[keep], j[keep]
    p1, p2, p3, p4 = a[i], b[i], a[j], b[j]
    r13, r14, r23, r24 = p3 - p1, p4 - p1, p3 - p2, p4 - p2

    def unit(v):
        n = np.linalg.norm(v, axis=1)
        out = np.zeros_like(v)
        ok = n > 0
        out[ok] = v[ok] / n[ok, None]
        return out

    n1 = unit(np.cross(r13, r14))
    n2 = unit(np.cross(r14, r24))
    n3 = unit(np.cross(r24, r23))
    n4 = unit(np.cross(r23, r13))

    def asin_dot(u, v):
        return np.arcsin(np.clip((u * v).sum(1), -1.0, 1.0))

    omega = asin_dot(n1, n2) + asin_dot(n2, n3) + asin_dot(n3, n4) + asin_dot(n4, n1)
    sgn = np.sign((np.cross(p4 - p3, p2 - p1) * r13).sum(1))
    return float(2.0 * (omega * sgn).sum() / (4.0 * np.pi))


def segment_distances(points, min_index_gap: int = 2):
    """Distances between all segment pairs (i, j) with j - i >= ``min_index_gap`` of a polyline (n, 3):
    returns (i, j, distance (m), closest point parameters s (on i) and t (on j) in [0, 1])."""
    p = _check_polyline(points)
    a, b = p[:-1], p[1:]
    m = a.shape[0]
    i, j = np.triu_indices(m, k=max(1, int(min_index_gap)))
    d1, d2, r = b[i] - a[i], b[j] - a[j], a[i] - a[j]
    A = (d1 * d1).sum(1)
    E = (d2 * d2).sum(1)
    Fv = (d2 * r).sum(1)
    c = (d1 * r).sum(1)
    bb = (d1 * d2).sum(1)
    den = A * E - bb * bb
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(den > 1e-30 * A * E, np.clip((bb * Fv - c * E) / den, 0.0, 1.0), 0.0)
        t = (bb * s + Fv) / E
    # clamp t and recompute s (Ericson, Real-Time Collision Detection, 5.1.9)
    lo, hi = t < 0.0, t > 1.0
    t = np.clip(t, 0.0, 1.0)
    s = np.where(lo, np.clip(-c / A, 0.0, 1.0), s)
    s = np.where(hi, np.clip((bb - c) / A, 0.0, 1.0), s)
    q = (a[i] + s[:, None] * d1) - (a[j] + t[:, None] * d2)
    return i, j, np.linalg.norm(q, axis=1), s, t


def min_self_distance(points, min_index_gap: int = 3) -> float:
    """Smallest distance (m) between segments at least ``min_index_gap`` apart along the polyline."""
    _, _, d, _, _ = segment_distances(points, min_index_gap)
    return float(d.min()) if d.size else np.inf
