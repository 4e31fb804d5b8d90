"""Facial landmarks found from geometry alone (any face scan, not only the ICT topology).

The face's frame and seven soft-tissue landmarks are found from the surface, with no template:

1. **forward** (approach axis, out of the face): the area-weighted mean triangle normal
   ``sum_k A_k n_k / |sum_k A_k n_k|`` (a face is an open, outward-facing surface; a closed or
   saddle-like surface has a near-zero mean normal and is refused).
2. **lateral** (left–right): the normal of the face's mirror-symmetry plane. Candidate planes contain
   ``forward`` and pass through the most anterior vertex; their direction is scanned in the plane
   normal to ``forward`` (6° steps from the principal axis of the projected vertices, then 1°) and
   the plane whose mirror image of the vertices lies closest to the vertices (median nearest-neighbour
   distance) wins; normal and offset are then refined by three mirror-ICP steps (the chords between
   mirror partners are parallel to the plane normal). ``forward`` is then projected into
   the symmetry plane.
3. **up**: the symmetry-plane direction normal to ``forward``; its sign follows the rule that the
   nose is longer above the tip than below it: the first concavity of the midline profile above the
   tip (nasion; 30–39 mm above the tip on the bundled faces) is farther from the tip than the first
   one below it (subnasale; 11–20 mm below).
   An ``up`` (or ``forward``) given by the caller replaces the estimate (the other axis is
   orthogonalised against it); pass both for scans that are not roughly frontal.

Landmarks come from the **midline profile** — the section of the surface by the symmetry plane,
reduced to its anterior envelope ``a(u)`` (the most anterior surface point per 0.5 mm band of height
``u``, Gaussian-smoothed with σ = 1 mm; points more than 90 mm behind the most anterior one — the back
of a whole-head scan — are ignored, and bands without a point, e.g. across an open mouth, are
interpolated):

- nose tip (pronasale): the most anterior point of the nose — of the peaks of ``a(u)`` (prominence
  ≥ 1 mm, within 25 mm of the most anterior one), the one with the steepest lateral walls 4 mm above
  or below it (the alae: the section normal to ``up`` falls back ≥ 8 mm over 4 mm, 8–30 mm from the
  midline, on both sides; lips and chin have no such walls). On some bundled population faces the
  upper lip is more anterior than the nose, so "most anterior point" alone is not enough;
- nasion and subnasale: the first concavity (pocket below the upper convex hull of the profile,
  ≥ 3 mm deep, at its deepest) walking up from the tip, and walking down from the tip;
- stomion (mouth): the deepest point of ``a(u)`` between the upper and the lower lip, the first two
  peaks (prominence ≥ 0.2 mm) 3–45 mm below the subnasale (found on every bundled face); failing
  that, the point deepest below the profile's convex hull 8–30 mm below the subnasale;
- chin (pogonion): the most anterior profile point 8–70 mm below the lower lip and at most 40 mm
  behind the subnasale, measured along ``forward``
  tilted 20° downwards (so that a receding chin still yields its most prominent point and the
  under-chin is never chosen);
- alae (alare, left/right): sections normal to ``up`` at 20 %, 30 % and 40 % of the way from
  subnasale to tip (nostril level); on each side the lateral nose wall is where the section's anterior
  envelope falls back fastest (largest 4 mm drop) 8–30 mm from the midline; the alare is the most
  lateral section point on that wall, and the widest of the three levels is kept.

All positions are points on the surface (section points), in metres.

References
----------
Farkas, L. G. (1994). *Anthropometry of the Head and Face*, 2nd ed. — landmark definitions
(prn, n, sn, sto, pg, al); adult alar width al–al ≈ 31–40 mm, nose height n–sn ≈ 45–60 mm.

Notes
-----
Limitations: the face must be roughly frontal-facing (its mean normal is taken as the approach axis;
on the bundled ICT faces it tilts 2–14° downwards from +z because the forehead slopes back) and the
nose tip must lie within 25 mm of the most anterior point of the midline profile; strongly rotated
or partial scans need explicit ``forward``/``up``. The scan must reach ≥ 40 mm below the subnasale
(mouth and chin) and above the nasion concavity. The nose's mirror symmetry is assumed (a strongly deviated nose shifts the
midline). Landmarks are surface points, not vertex ids; :attr:`Landmarks.nearest_vertices` maps
them to the closest vertices.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from headsim.errors import MeshError, ParameterError
from headsim.mesh import SurfaceMesh, check_head_scale

#: Plausible largest extent of a face (or face-and-head) scan, m.
FACE_EXTENT_RANGE_M = (0.08, 0.45)

_BIN = 0.5e-3  # profile band width, m
_SMOOTH = 1.0e-3  # profile smoothing sigma, m
_PROFILE_DEPTH = 0.09  # section points more than this behind the most anterior one are ignored, m

LANDMARK_NAMES = ("nose_tip", "nasion", "subnasale", "stomion", "chin", "ala_left", "ala_right")


@dataclass(frozen=True, eq=False)
class Landmarks:
    """Soft-tissue landmarks and the face frame, all in the face mesh's coordinates.

    Attributes
    ----------
    nose_tip, nasion, subnasale, stomion, chin, ala_left, ala_right : (3,) float64, m
        Surface points (Farkas: prn, n, sn, sto, pg, al). ``ala_left`` lies on the subject's left
        (``+lateral`` side).
    forward : (3,) float64 unit vector, out of the face (the mask's approach is along ``-forward``).
    up : (3,) float64 unit vector, towards the forehead, orthogonal to ``forward``.
    lateral : (3,) float64 unit vector, ``up x forward`` (the subject's left for a right-handed frame).
    """

    nose_tip: np.ndarray
    nasion: np.ndarray
    subnasale: np.ndarray
    stomion: np.ndarray
    chin: np.ndarray
    ala_left: np.ndarray
    ala_right: np.ndarray
    forward: np.ndarray
    up: np.ndarray

    def __post_init__(self):
        for name in LANDMARK_NAMES + ("forward", "up"):
            arr = np.array(getattr(self, name), dtype=np.float64)
            if arr.shape != (3,) or not np.isfinite(arr).all():
                raise ParameterError(f"landmark {name} must be a finite (3,) vector, got {arr!r}")
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        for name in ("forward", "up"):
            if abs(np.linalg.norm(getattr(self, name)) - 1.0) > 1e-6:
                raise ParameterError(f"{name} must be a unit vector")
        if abs(float(self.forward @ self.up)) > 1e-6:
            raise ParameterError("forward and up must be orthogonal")

    @property
    def lateral(self) -> np.ndarray:
        return np.cross(self.up, self.forward)

    @property
    def alar_width(self) -> float:
        """al–al distance, m."""
        return float(np.linalg.norm(self.ala_left - self.ala_right))

    @property
    def nose_height(self) -> float:
        """n–sn distance, m."""
        return float(np.linalg.norm(self.nasion - self.subnasale))

    @property
    def frame(self) -> np.ndarray:
        """(3, 3) float64 rotation whose columns are lateral, up, forward (face frame → mesh frame)."""
        return np.column_stack([self.lateral, self.up, self.forward])

    def as_dict(self) -> dict[str, list[float]]:
        """Landmarks and axes as plain lists (m), for JSON."""
        return {name: getattr(self, name).tolist() for name in LANDMARK_NAMES + ("forward", "up")}

    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> "Landmarks":
        """Landmarks of the face moved by ``x -> rotation @ x + translation``."""
        r = np.asarray(rotation, dtype=np.float64)
        t = np.asarray(translation, dtype=np.float64)
        kw = {name: r @ getattr(self, name) + t for name in LANDMARK_NAMES}
        return Landmarks(**kw, forward=r @ self.forward, up=r @ self.up)

    def nearest_vertices(self, face: SurfaceMesh) -> dict[str, int]:
        """Closest vertex id of ``face`` to every landmark."""
        tree = cKDTree(face.vertices)
        return {name: int(tree.query(getattr(self, name))[1]) for name in LANDMARK_NAMES}


# ------------------------------------------------------------------------------------------------
# geometry helpers
# ------------------------------------------------------------------------------------------------
def plane_section_segments(vertices: np.ndarray, triangles: np.ndarray, point: np.ndarray,
                           normal: np.ndarray) -> np.ndarray:
    """Section of a triangle mesh by a plane, as line segments.

    Parameters
    ----------
    vertices : (n, 3) float64, m; triangles : (m, 3) int64
    point : (3,) a point of the plane, m; normal : (3,) its normal (any length > 0)

    Returns
    -------
    (k, 2, 3) float64, m: one segment per triangle that the plane crosses (a vertex on the plane
    counts as lying on the positive side, so every crossing triangle has exactly two crossing edges).
    """
    v = np.asarray(vertices, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int64)
    d = (v - point) @ np.asarray(normal, dtype=np.float64)
    pos = d[tri] >= 0
    crossing = pos.any(axis=1) & ~pos.all(axis=1)
    tri, dt, pos = tri[crossing], d[tri[crossing]], pos[crossing]
    ends = []
    for a, b in ((0, 1), (1, 2), (2, 0)):
        cut = pos[:, a] != pos[:, b]
        da, db = dt[:, a], dt[:, b]
        w = np.divide(da, da - db, out=np.zeros_like(da), where=cut)[:, None]
        ends.append((cut, v[tri[:, a]] + w * (v[tri[:, b]] - v[tri[:, a]])))
    cut = np.stack([e[0] for e in ends], axis=1)  # (k, 3), two True per row
    pts = np.stack([e[1] for e in ends], axis=1)  # (k, 3, 3)
    order = np.argsort(~cut, axis=1, kind="stable")[:, :2]
    return np.take_along_axis(pts, order[:, :, None], axis=1)


def plane_section_points(vertices: np.ndarray, triangles: np.ndarray, point: np.ndarray,
                         normal: np.ndarray, spacing: float = 0.25e-3) -> np.ndarray:
    """Points along the section of a mesh by a plane, at most ``spacing`` (m) apart.

    Returns
    -------
    (p, 3) float64, m: the section segments of :func:`plane_section_segments`, sampled densely
    (both end points and evenly spaced interior points).
    """
    seg = plane_section_segments(vertices, triangles, point, normal)
    if len(seg) == 0:
        return np.zeros((0, 3))
    length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)
    n = np.maximum(1, np.ceil(length / spacing).astype(np.int64))
    owner = np.repeat(np.arange(len(seg)), n + 1)
    start = np.repeat(np.cumsum(n + 1) - (n + 1), n + 1)
    t = (np.arange(len(owner)) - start) / n[owner]
    return seg[owner, 0] + t[:, None] * (seg[owner, 1] - seg[owner, 0])


def _smooth(values: np.ndarray, sigma_bins: float) -> np.ndarray:
    """Gaussian smoothing (scipy.ndimage, imported lazily: it is slow to import)."""
    from scipy.ndimage import gaussian_filter1d

    return gaussian_filter1d(values, sigma_bins, mode="nearest")


def _unit(v: np.ndarray, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    if v.shape != (3,) or not np.isfinite(v).all():
        raise ParameterError(f"{what} must be a finite 3-vector, got {v!r}")
    n = np.linalg.norm(v)
    if n < 1e-12:
        raise ParameterError(f"{what} must be non-zero")
    return v / n


def _mean_normal(face: SurfaceMesh) -> np.ndarray:
    s = (face.triangle_areas[:, None] * face.face_normals).sum(axis=0)
    ratio = np.linalg.norm(s) / max(face.area, 1e-300)
    if ratio < 0.2:
        raise MeshError(
            f"{face.name}: does not look like a face scan — its triangles face no common direction "
            f"(|area-weighted mean normal| = {ratio:.2f} of the area; a frontal face scan gives 0.3–0.7). "
            "A closed surface (e.g. a sphere) is not a face; for a whole-head scan pass forward= "
            "(out of the face) explicitly."
        )
    return s / np.linalg.norm(s)


def _symmetry_lateral(points: np.ndarray, targets: np.ndarray, forward: np.ndarray,
                      origin: np.ndarray) -> tuple[np.ndarray, float]:
    """Normal of the best mirror-symmetry plane containing ``forward``, and its offset.

    ``points`` (mirrored, a subsample) are matched to their nearest ``targets`` (all vertices).
    Returns (lateral unit vector, offset c such that the plane is {x : lateral . x = c}).
    """
    tree = cKDTree(targets)
    p = points - origin
    proj = p - np.outer(p @ forward, forward)
    # start the angular scan at the principal axis of the projected points (frame-independent)
    w, vecs = np.linalg.eigh(proj.T @ proj)
    e1 = vecs[:, 2]
    e2 = np.cross(forward, e1)

    def cost(theta: float, n_icp: int = 2) -> tuple[float, np.ndarray, float]:
        lat = np.cos(theta) * e1 + np.sin(theta) * e2
        c = float(lat @ origin)
        for _ in range(n_icp):  # mirror ICP on the offset
            mirrored = points - 2.0 * np.outer(points @ lat - c, lat)
            dist, idx = tree.query(mirrored)
            c = float(np.median(0.5 * (points @ lat + targets[idx] @ lat)))
        mirrored = points - 2.0 * np.outer(points @ lat - c, lat)
        dist, _ = tree.query(mirrored)
        return float(np.median(dist)), lat, c

    coarse = np.deg2rad(np.arange(0.0, 180.0, 6.0))
    best = min(coarse, key=lambda t: cost(t, 1)[0])
    fine = best + np.deg2rad(np.arange(-5.0, 5.01, 1.0))
    best = min(fine, key=lambda t: cost(t, 1)[0])
    _, lat, c = cost(best, 2)
    # mirror ICP: the chords between mirror partners are parallel to the plane normal
    for _ in range(3):
        mirrored = points - 2.0 * np.outer(points @ lat - c, lat)
        _, idx = tree.query(mirrored)
        chord = points - targets[idx]
        far = np.abs(points @ lat - c) > 5e-3
        if far.sum() < 10:
            break
        ch = chord[far]
        ch = ch - np.outer(ch @ forward, forward)
        w, vecs = np.linalg.eigh(ch.T @ ch)
        new = vecs[:, 2] * np.sign(vecs[:, 2] @ lat)
        lat = new / np.linalg.norm(new)
        c = float(np.median(0.5 * (points @ lat + targets[idx] @ lat)))
    return lat, c


class _Profile:
    """Anterior envelope a(u) of a set of section points: u along ``axis``, a along ``forward``."""

    def __init__(self, points: np.ndarray, axis: np.ndarray, forward: np.ndarray, origin: np.ndarray):
        a_all = (points - origin) @ forward
        points = points[a_all >= a_all.max() - _PROFILE_DEPTH]   # the face, not the back of a head
        u = (points - origin) @ axis
        a = (points - origin) @ forward
        lo, hi = np.floor(u.min() / _BIN), np.ceil(u.max() / _BIN)
        self.u = np.arange(lo, hi + 1) * _BIN
        k = np.round(u / _BIN - lo).astype(np.int64)
        env = np.full(len(self.u), -np.inf)
        np.maximum.at(env, k, a)
        arg = np.full(len(self.u), -1, dtype=np.int64)
        order = np.argsort(a)  # later (larger a) overwrite earlier: arg = point of the max
        arg[k[order]] = order
        filled = np.isfinite(env)
        self.raw = np.interp(self.u, self.u[filled], env[filled])
        self.a = _smooth(self.raw, _SMOOTH / _BIN)
        # nearest filled band for every band, for point lookup
        idx_filled = np.flatnonzero(filled)
        pos = np.searchsorted(idx_filled, np.arange(len(self.u))).clip(0, len(idx_filled) - 1)
        left = idx_filled[(pos - 1).clip(0)]
        right = idx_filled[pos]
        self._nearest = np.where(np.abs(np.arange(len(self.u)) - left) < np.abs(right - np.arange(len(self.u))),
                                 left, right)
        self._arg = arg
        self._points = points

    def index(self, u: float) -> int:
        return int(np.clip(np.round((u - self.u[0]) / _BIN), 0, len(self.u) - 1))

    def point(self, i: int) -> np.ndarray:
        """Surface point of band ``i`` (the most anterior section point of the nearest non-empty band)."""
        return self._points[self._arg[self._nearest[i]]].copy()


def _hull_depth(u: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Depth of every profile sample below the upper convex hull of (u, a) (≥ 0, same unit)."""
    hull: list[int] = []
    for i in range(len(u)):  # monotone chain, upper hull, u increasing
        while len(hull) >= 2:
            i0, i1 = hull[-2], hull[-1]
            cross = (u[i1] - u[i0]) * (a[i] - a[i0]) - (a[i1] - a[i0]) * (u[i] - u[i0])
            if cross >= 0:
                hull.pop()
            else:
                break
        hull.append(i)
    return np.interp(u, u[hull], a[hull]) - a


def _no_face(face: SurfaceMesh, why: str) -> MeshError:
    return MeshError(f"{face.name}: no face found — {why}. Is this a frontal face scan in the stated unit? "
                     "Pass forward=/up= if the scan is not roughly frontal.")


def _estimate_frame(face: SurfaceMesh, forward, up) -> tuple[np.ndarray, np.ndarray, np.ndarray, float | None, bool]:
    """(forward, up, lateral, symmetry-plane offset or None, up_sign_known); up's sign is decided later."""
    v = face.vertices
    if up is not None:
        upv = _unit(up, "up")
        if forward is not None:
            f = _unit(forward, "forward")
        else:
            f = _mean_normal(face)
        f = f - (f @ upv) * upv
        if np.linalg.norm(f) < 1e-6:
            raise ParameterError("forward and up must not be parallel")
        f /= np.linalg.norm(f)
        return f, upv, np.cross(upv, f), None, True
    f = _unit(forward, "forward") if forward is not None else _mean_normal(face)
    step = max(1, len(v) // 1500)
    lat, c = _symmetry_lateral(v[::step], v, f, v[np.argmax(v @ f)])
    if forward is None:  # the approach axis lies in the symmetry plane
        f = f - (f @ lat) * lat
        f /= np.linalg.norm(f)
    return f, np.cross(f, lat), lat, c, False


def _first_pocket(u: np.ndarray, a: np.ndarray, i_tip: int, direction: int,
                  min_depth: float = 3e-3) -> int | None:
    """Index of the first concavity of the profile walking from the tip along ``direction`` (±1).

    The walk's depth below the upper convex hull of the walked profile is followed from the tip
    until it first exceeds ``min_depth`` and then to its local maximum (the bottom of the pocket).
    """
    idx = np.arange(i_tip, len(u)) if direction > 0 else np.arange(i_tip, -1, -1)
    if len(idx) < 3:
        return None
    s = np.abs(u[idx] - u[i_tip])
    depth = _hull_depth(s, a[idx])
    over = np.flatnonzero(depth >= min_depth)
    if len(over) == 0:
        return None
    k = int(over[0])
    while k + 1 < len(depth) and depth[k + 1] >= depth[k]:
        k += 1
    return int(idx[k])


def find_landmarks(face: SurfaceMesh, forward=None, up=None) -> Landmarks:
    """Find nose tip, nasion, subnasale, stomion, chin, alae and the face frame (see module doc).

    Parameters
    ----------
    face : SurfaceMesh, m. An open face surface (a scan of the front of a head).
    forward : (3,) approach axis out of the face, optional (estimated when None).
    up : (3,) direction towards the forehead, optional (estimated when None).

    Returns
    -------
    Landmarks

    Raises
    ------
    UnitsError
        The mesh's extent is not face-sized (0.08–0.45 m).
    MeshError
        The surface is not face-like (closed, no nose protruding from a midline profile, …).
    """
    v = face.vertices
    check_head_scale(v, source=face.name, plausible_range_m=FACE_EXTENT_RANGE_M, strict=True)
    f, upv, lat, c, up_known = _estimate_frame(face, forward, up)
    anterior = v[np.argmax(v @ f)]
    if c is None:  # axes given: the midline plane passes through the most anterior point
        c = float(lat @ anterior)
    origin = lat * c + f * float(f @ anterior) + upv * float(upv @ anterior)

    mid_pts = plane_section_points(v, face.triangles, origin, lat)
    if len(mid_pts) < 20:
        raise _no_face(face, "its symmetry plane crosses too little of the surface")
    prof = _Profile(mid_pts, upv, f, origin)

    # --- nose tip: the profile peak with the steepest lateral walls 4 mm above or below it -------
    from scipy.signal import find_peaks  # scipy.signal takes ~1 s to import; only needed here

    peaks, _ = find_peaks(np.concatenate([[-np.inf], prof.a, [-np.inf]]), prominence=1e-3)
    peaks = peaks - 1
    peaks = peaks[prof.a[peaks] >= prof.a.max() - 25e-3]
    scores = []
    for i in peaks:
        walls = [_nose_walls(face, origin, upv, lat, f, prof.u[i] + du) for du in (-4e-3, 4e-3)]
        scores.append(max((w[0] for w in walls if w is not None), default=-np.inf))
    if len(scores) == 0 or max(scores) < _NOSE_WALL_MIN:
        raise _no_face(face, "no nose: no peak of the midline profile has steep lateral walls beside it "
                             f"(a fall of ≥ {1e3 * _NOSE_WALL_MIN:.0f} mm over 4 mm, 8–30 mm from the midline, "
                             "4 mm above or below the peak)")
    i_tip = int(peaks[int(np.argmax(scores))])

    # --- up's sign: the nasion concavity lies farther from the tip than the subnasale -----------
    pocket_plus = _first_pocket(prof.u, prof.a, i_tip, +1)
    pocket_minus = _first_pocket(prof.u, prof.a, i_tip, -1)
    if not up_known:
        d_plus = abs(prof.u[pocket_plus] - prof.u[i_tip]) if pocket_plus is not None else 0.0
        d_minus = abs(prof.u[pocket_minus] - prof.u[i_tip]) if pocket_minus is not None else 0.0
        if d_minus > d_plus:
            upv, lat = -upv, -lat
            old_u = prof.u
            prof = _Profile(mid_pts, upv, f, origin)
            i_tip = prof.index(-old_u[i_tip])
            pocket_plus, pocket_minus = (
                prof.index(-old_u[pocket_minus]) if pocket_minus is not None else None,
                prof.index(-old_u[pocket_plus]) if pocket_plus is not None else None,
            )
    u, a = prof.u, prof.a
    if pocket_plus is None or pocket_minus is None:
        raise _no_face(face, "no nasal bridge or subnasale concavity next to the nose tip in the midline profile")
    i_n, i_sn = pocket_plus, pocket_minus
    tip_u = u[i_tip]
    if not 15e-3 <= u[i_n] - tip_u <= 90e-3:
        raise _no_face(face, f"nasion {1e3 * (u[i_n] - tip_u):.1f} mm above the nose tip (expected 15–90 mm)")
    if not 4e-3 <= tip_u - u[i_sn] <= 40e-3:
        raise _no_face(face, f"subnasale {1e3 * (tip_u - u[i_sn]):.1f} mm below the nose tip (expected 4–40 mm)")

    # --- mouth and chin ---------------------------------------------------------------------------
    lip = np.flatnonzero((u >= u[i_sn] - 45e-3) & (u <= u[i_sn] - 3e-3))[::-1]   # walking down
    if len(lip) < 20:
        raise _no_face(face, "the surface ends less than 45 mm below the subnasale (no mouth)")
    lip_peaks, _ = find_peaks(a[lip], prominence=0.2e-3)
    if len(lip_peaks) >= 2:  # upper and lower lip: the mouth is the deepest point between them
        i_ls, i_li = int(lip[lip_peaks[0]]), int(lip[lip_peaks[1]])
        between = np.arange(i_li, i_ls + 1)
        i_sto = int(between[np.argmin(a[between])])
    else:  # lips not separated in the profile: the deepest point below its hull, 8-30 mm down
        window = np.flatnonzero((u >= u[i_sn] - 30e-3) & (u <= u[i_sn] - 8e-3))
        i_sto = int(window[np.argmax(_hull_depth(u[window], a[window]))])
        lower_lip = np.flatnonzero((u >= u[i_sto] - 18e-3) & (u <= u[i_sto] - 2e-3))
        i_li = int(lower_lip[np.argmax(a[lower_lip])])
    beta = np.deg2rad(_CHIN_TILT_DEG)
    low = (u <= u[i_li] - 8e-3) & (u >= u[i_li] - 70e-3) & (a >= a[i_sn] - 40e-3)
    if low.sum() < 10:
        raise _no_face(face, "no chin below the mouth in the midline profile")
    low_idx = np.flatnonzero(low)
    score = a[low_idx] * np.cos(beta) - u[low_idx] * np.sin(beta)
    i_chin = int(low_idx[np.argmax(score)])

    # --- alae: sections normal to up at nostril level ---------------------------------------------
    best = None
    for frac in (0.2, 0.3, 0.4):
        level = u[i_sn] + frac * (tip_u - u[i_sn])
        found = _alae_at(face, origin, upv, lat, f, level)
        if found is not None and (best is None or found[0] > best[0]):
            best = found
    if best is None:
        raise _no_face(face, "no alae: no nose wall found beside the midline at nostril level")
    _, ala_left, ala_right = best

    return Landmarks(
        nose_tip=prof.point(i_tip), nasion=prof.point(i_n), subnasale=prof.point(i_sn),
        stomion=prof.point(i_sto), chin=prof.point(i_chin), ala_left=ala_left, ala_right=ala_right,
        forward=f, up=upv,
    )


#: Least fall (m over 4 mm laterally) of the nose's side walls next to the tip (bundled faces: 11–18 mm
#: at the nose, ≤ 7 mm at lips and chin).
_NOSE_WALL_MIN = 8e-3

#: The chin is the most anterior point below the mouth along ``forward`` tilted this far downwards.
_CHIN_TILT_DEG = 20.0


def _nose_walls(face: SurfaceMesh, origin, upv, lat, f, level: float):
    """Steep lateral nose walls in the section normal to ``up`` at ``level``.

    On each side of the midline, the section's anterior envelope (0.5 mm bands, smoothed σ = 0.5 mm)
    is searched 8–30 mm from the midline for its largest fall over 4 mm (the alar wall).

    Returns
    -------
    (min fall over both sides (m), left wall point, right wall point), or None when the section
    is empty; a wall point is the most lateral section point on the upper half of the fall.
    """
    pts = plane_section_points(face.vertices, face.triangles, origin + level * upv, upv)
    if len(pts) < 10:
        return None
    x = (pts - origin) @ lat
    pa = (pts - origin) @ f
    sides, falls = [], []
    xs = np.arange(0.0, 35e-3 + 1e-9, _BIN)
    h = int(round(2e-3 / _BIN))
    for sign in (+1, -1):
        side = sign * x
        kb = np.round(side / _BIN).astype(np.int64)
        keep = (kb >= 0) & (kb < len(xs))
        env = np.full(len(xs), -np.inf)
        np.maximum.at(env, kb[keep], pa[keep])
        filled = np.isfinite(env)
        if filled.sum() < 10:
            return None
        env = _smooth(np.interp(xs, xs[filled], env[filled]), 0.5e-3 / _BIN)
        fall = np.full(len(xs), -np.inf)
        fall[h:-h] = env[:-2 * h] - env[2 * h:]
        fall[(xs < 8e-3) | (xs > 30e-3)] = -np.inf
        j = int(np.argmax(fall))
        top, bottom = env[j - h], env[j + h]
        on_wall = (side >= xs[j] - 3e-3) & (side <= xs[j] + 1.5e-3) & (pa >= 0.5 * (top + bottom))
        if not on_wall.any():
            return None
        cand = np.flatnonzero(on_wall)
        sides.append(pts[cand[np.argmax(side[cand])]])
        falls.append(float(fall[j]))
    return min(falls), sides[0], sides[1]


def _alae_at(face: SurfaceMesh, origin, upv, lat, f, level: float):
    """(alar width, left point, right point) from the section normal to ``up`` at ``level``, or None."""
    walls = _nose_walls(face, origin, upv, lat, f, level)
    if walls is None or walls[0] < 3e-3:  # a nose wall falls back ≥ 3 mm over 4 mm
        return None
    return float(np.linalg.norm(walls[1] - walls[2])), walls[1], walls[2]
