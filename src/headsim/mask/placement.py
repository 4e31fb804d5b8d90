"""Putting a mask in front of a face: centred on the airway, along the approach axis, 2 cm off.

Automatic placement (``placement="auto"``) is a rigid motion of the mask:

1. **Rotation**: the mask's ``airway_axis`` is turned onto the approach direction ``-forward``
   (into the face) and its ``up`` onto the face's ``up`` (the roll), i.e. ``R = F_face F_mask^T``
   with the frames' columns (lateral, up, out of the face).
2. **Centring**: the airway centre goes to the face's airway point: for a nasal mask the midpoint of
   nose tip and subnasale (in front of the nostrils), for an oronasal mask the midpoint of subnasale
   and stomion.
3. **Stand-off**: the mask is slid along ``forward`` until the smallest gap between its skin-side
   (contact) vertices and the skin, measured along the approach axis, equals ``standoff``
   (2 cm by default: the mask starts 2 cm from the face in Heinze 2023 ch. 5). Gaps are measured
   by casting, for every contact vertex, a ray along ``-forward`` from far in front of the face and
   taking its first hit on the skin (the front-most skin on that line).

``placement="as-is"`` keeps the designer's pose (a mask file already aligned on the face); an
initial overlap is allowed and left to the solver.

A mask that cannot be placed raises :class:`~headsim.errors.ParameterError`: more than
``max_miss_fraction`` of its contact vertices have no skin in front of them (the mask is larger than
the face scan), or, as-is, it is nowhere near the face.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from headsim.errors import ParameterError
from headsim.mask.landmarks import Landmarks, find_landmarks
from headsim.mask.masks import MaskModel
from headsim.mesh import SurfaceMesh

if TYPE_CHECKING:  # the BVH (Numba kernels) is imported when a placement needs it
    from headsim.collide import TriangleBVH

#: How far in front of the skin the gap rays start, m.
_RAY_START = 0.5


@dataclass(frozen=True, eq=False)
class Placement:
    """A mask placed on a face.

    mask : MaskModel moved onto the face (face coordinates, m)
    rotation : (3, 3) float64, translation : (3,) float64, m — ``x_face = rotation @ x_mask + translation``
    approach : (3,) float64 unit vector, the direction the mask moves to close the gap (``-forward``)
    target : (3,) float64, m, the face's airway point the airway centre was centred on (as-is: the
        mask's airway centre)
    gaps : (c,) float64, m, gap along ``approach`` from every contact vertex of ``mask`` to the skin
        (``mask.contact_vertices`` order; NaN where no skin lies on that line; negative = overlap)
    mode : "auto" or "as-is"
    """

    mask: MaskModel
    rotation: np.ndarray
    translation: np.ndarray
    approach: np.ndarray
    target: np.ndarray
    gaps: np.ndarray
    mode: str

    @property
    def min_gap(self) -> float:
        """Smallest gap along the approach axis, m (negative where the mask overlaps the skin)."""
        return float(np.nanmin(self.gaps))


def airway_point(landmarks: Landmarks, kind: str) -> np.ndarray:
    """(3,) m: where a mask of ``kind`` centres its airway opening (module doc, step 2)."""
    if kind == "nasal":
        return 0.5 * (landmarks.nose_tip + landmarks.subnasale)
    if kind == "oronasal":
        return 0.5 * (landmarks.subnasale + landmarks.stomion)
    raise ParameterError(f"unknown mask kind {kind!r}; use 'nasal' or 'oronasal'")


def gaps_along(points: np.ndarray, face_bvh: TriangleBVH, approach: np.ndarray) -> np.ndarray:
    """(n,) m: signed gap from each point to the front-most skin on its line along ``approach``.

    ``gap = (p - s) . (-approach)`` where ``s`` is the first hit of a ray that starts
    0.5 m in front of ``p`` (against ``approach``) and travels along ``approach``; NaN on a miss.
    """
    d = np.asarray(approach, dtype=np.float64)
    origins = points - _RAY_START * d
    hits = face_bvh.intersect_rays(origins, np.broadcast_to(d, points.shape).copy())
    gap = np.where(hits.hit, hits.distance - _RAY_START, np.nan)
    return gap


def place_mask(mask: MaskModel, face: SurfaceMesh, landmarks: Landmarks | None = None,
               standoff: float = 0.02, placement: str = "auto", max_miss_fraction: float = 0.05,
               face_bvh: TriangleBVH | None = None) -> Placement:
    """Place ``mask`` on ``face`` (see the module doc).

    Parameters
    ----------
    mask : MaskModel in its own frame (auto) or already on the face (as-is)
    face : SurfaceMesh, m
    landmarks : from :func:`~headsim.mask.find_landmarks` (computed when None; not needed as-is)
    standoff : smallest gap along the approach axis after placement, m, in [0, 0.1]
    placement : "auto" or "as-is"
    max_miss_fraction : largest share of contact vertices allowed to have no skin in front of them
    face_bvh : a TriangleBVH of ``face`` to reuse (built when None)

    Returns
    -------
    Placement
    """
    if placement not in ("auto", "as-is"):
        raise ParameterError(f"placement must be 'auto' or 'as-is', got {placement!r}")
    if not (np.isfinite(standoff) and 0.0 <= standoff <= 0.1):
        raise ParameterError(f"standoff must be 0–0.1 m, got {standoff}")
    if face_bvh is None:
        from headsim.collide import TriangleBVH

        face_bvh = TriangleBVH(face.vertices, face.triangles)
    bvh = face_bvh
    contact_ids = mask.contact_vertices

    if placement == "as-is":
        pts = mask.tetmesh.vertices[contact_ids]
        gaps = gaps_along(pts, bvh, mask.airway_axis)
        nearest = bvh.closest_points(mask.tetmesh.vertices[mask.shell_vertices[:1]])
        if np.all(np.isnan(gaps)) or nearest.distance[0] > 0.1:
            raise ParameterError(
                f"{mask.name}: as placed, the mask is not in front of {face.name} (no skin along its "
                f"airway axis, shell {nearest.distance[0] * 1e3:.0f} mm from the skin); use placement='auto'"
            )
        return Placement(mask=mask, rotation=np.eye(3), translation=np.zeros(3), approach=mask.airway_axis.copy(),
                         target=mask.airway_center.copy(), gaps=gaps, mode="as-is")

    lm = landmarks if landmarks is not None else find_landmarks(face)
    target = airway_point(lm, mask.kind)
    rotation = lm.frame @ mask.frame.T
    approach = -lm.forward
    translation = target - rotation @ mask.airway_center
    pts = mask.tetmesh.vertices[contact_ids] @ rotation.T + translation
    gaps = gaps_along(pts, bvh, approach)
    miss = np.isnan(gaps)
    if miss.mean() > max_miss_fraction:
        raise ParameterError(
            f"cannot place {mask.name} on {face.name}: {100 * miss.mean():.0f}% of its skin-side vertices "
            f"have no skin in front of them (allowed {100 * max_miss_fraction:.0f}%): the mask reaches beyond "
            "the edge of the scan or over its holes (eyes, mouth), i.e. it is too large for this face, "
            "or the landmarks are wrong"
        )
    shift = standoff - float(np.nanmin(gaps))          # positive: move away from the face
    translation = translation + shift * lm.forward
    placed = mask.transformed(rotation, translation)
    return Placement(mask=placed, rotation=rotation, translation=translation, approach=approach,
                     target=target, gaps=gaps + shift, mode="auto")


def skin_cushion_gap(face: SurfaceMesh, mask: MaskModel, approach: np.ndarray | None = None,
                     behind: float = 0.05) -> np.ndarray:
    """(n,) float64, m: gap from every face vertex to the mask's skin-side surface, along the approach.

    For face vertex ``x`` a ray starts ``behind`` (m) inside the face at ``x + behind * approach`` and
    runs against ``approach`` (out of the face); its first hit ``c`` on the contact surface gives
    ``gap = (c - x) . (-approach)`` (negative where the cushion overlaps the skin). ``inf`` where no
    cushion lies on that line. ``approach`` defaults to ``mask.airway_axis``. This is the ``gap``
    field :func:`headsim.mask.analyse_seal` takes.
    """
    d = np.asarray(mask.airway_axis if approach is None else approach, dtype=np.float64)
    d = d / np.linalg.norm(d)
    from headsim.collide import TriangleBVH

    bvh = TriangleBVH(mask.tetmesh.vertices, mask.contact_triangles)
    origins = face.vertices + behind * d
    hits = bvh.intersect_rays(origins, np.broadcast_to(-d, origins.shape).copy())
    return np.where(hits.hit, hits.distance - behind, np.inf)
