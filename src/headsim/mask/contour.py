"""Cushion contouring: shape a parametric mask's skin-side edge to a face.

A cushion seals only where it is pressed against the skin all the way round the airway. The analytic
saddle of :mod:`headsim.mask.masks` (three heights: cheeks, bridge, lip) leaves the edge 0–3.5 mm off
the mean face depending on the position along the outline, so a strap force first compresses the
bridge and the lip while the cheeks beside the alae stay open. Manufacturers therefore design the
sealing edge on a reference head form (the population's mean face), and custom-fit cushions are
designed on the patient's own scan (e.g. Kwon et al., PLOS ONE 2022, custom-fit PAP cushion).

:func:`contour_correction` does this for a parametric design:

1. build the mask with its current edge and place it on the reference face
   (:func:`headsim.mask.placement.place_mask`: centred on the airway, along the approach axis);
2. for every outline sample, the gap along the approach axis from the cushion's skin-side rows
   (the flat edge and its rounded corners) to the skin, and its smallest value over the section;
3. that gap, minus its smallest value around the outline, is how far the section must move towards
   the face so that the whole edge touches the skin at once; it is smoothed to the lowest Fourier
   harmonics of the outline angle (``harmonics``, default 16: a 10 mm wide cushion edge cannot be
   shaped finer than about its own width, 16 harmonics on the 17 cm nasal outline; measured on the
   mean face, 8 harmonics leave a 0.58 mm spread of the section gaps, 16 leave 0.19 mm).

The correction is a function of the outline angle ``phi`` (:func:`outline_angle`), in metres at size
M: S and L are the same design scaled (they are not contoured to a smaller or larger face).
The gaps are measured along the approach axis, which is the mask's z axis, so moving the edge along
z changes them exactly by the move: one pass gives the contoured edge up to the smoothing residual
(reported as :attr:`Contour.residual`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from headsim.errors import ParameterError
from headsim.mask.landmarks import Landmarks, find_landmarks
from headsim.mask.masks import MaskDesign, build_parametric_mask, design_of, outline_angle
from headsim.mask.placement import gaps_along, place_mask
from headsim.mesh import SurfaceMesh


@dataclass(frozen=True)
class Contour:
    """Result of :func:`contour_correction`.

    design : the contoured MaskDesign (``edge_correction`` set)
    phi : (n,) outline angle of every section sample, rad
    gap_before : (n,) smallest skin gap of every section before contouring, relative to its
        smallest value around the outline, m
    residual : (n,) the same after contouring (what the smoothing leaves), m
    """

    design: MaskDesign
    phi: np.ndarray
    gap_before: np.ndarray
    residual: np.ndarray

    @property
    def spread_before(self) -> float:
        """Range of the section gaps around the outline before contouring, m."""
        return float(np.ptp(self.gap_before))

    @property
    def spread_after(self) -> float:
        """Range of the section gaps around the outline after contouring, m."""
        return float(np.ptp(self.residual))


def _fourier_fit(phi: np.ndarray, values: np.ndarray, harmonics: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Least-squares coefficients (a_0..a_K, b_0..b_K) of ``sum a_k cos k phi + b_k sin k phi``."""
    k = np.arange(harmonics + 1)
    basis = np.concatenate([np.cos(np.outer(phi, k)), np.sin(np.outer(phi, k[1:]))], axis=1)
    coef, *_ = np.linalg.lstsq(basis, values, rcond=None)
    a = coef[: harmonics + 1]
    b = np.concatenate([[0.0], coef[harmonics + 1:]])
    return tuple(float(x) for x in a), tuple(float(x) for x in b)


def _section_gaps(design: MaskDesign, face: SurfaceMesh, landmarks: Landmarks | None, edge_length: float,
                  face_bvh) -> tuple[np.ndarray, np.ndarray]:
    """(phi, smallest gap per outline sample) of the size-M mask of ``design`` placed on ``face``."""
    mask = build_parametric_mask(design, 1.0, edge_length=edge_length)
    placement = place_mask(mask, face, landmarks, face_bvh=face_bvh)
    n_samples, n_rows, n_cols = mask.section_grid
    verts = placement.mask.tetmesh.vertices.reshape(n_samples, n_rows, n_cols, 3)
    skin_side = verts[:, :3].reshape(-1, 3)            # the flat edge row and the two rounded rows
    gaps = gaps_along(skin_side, face_bvh, placement.approach).reshape(n_samples, -1)
    if np.isnan(gaps).all(axis=1).any():
        raise ParameterError(f"cannot contour {design.kind}: a part of its edge has no skin in front of it")
    rest = mask.tetmesh.vertices.reshape(n_samples, n_rows, n_cols, 3)[:, 0, :, :2].mean(axis=1)  # outline points
    phi = outline_angle(design, 1.0, rest)
    return phi, np.nanmin(gaps, axis=1)


def contour_correction(design: MaskDesign | str, face: SurfaceMesh, landmarks: Landmarks | None = None,
                       harmonics: int = 16, edge_length: float = 2e-3) -> Contour:
    """Contour ``design`` (a MaskDesign or a built-in kind, "nasal" / "oronasal") to ``face``.

    Returns a :class:`Contour` whose ``design`` has the smoothed edge correction (module doc); any
    correction already in ``design`` is replaced. ``harmonics`` 1–32; ``edge_length`` (m) is the
    sampling of the outline used for the measurement.
    """
    if not 1 <= int(harmonics) <= 32:
        raise ParameterError(f"harmonics must be 1–32, got {harmonics}")
    base = design_of(design, contour=False) if isinstance(design, str) else replace(design, edge_correction=None)
    from headsim.collide import TriangleBVH

    bvh = TriangleBVH(face.vertices, face.triangles)
    landmarks = landmarks if landmarks is not None else find_landmarks(face)  # once for both placements
    phi, gap = _section_gaps(base, face, landmarks, edge_length, bvh)
    rel = gap - gap.min()
    a, b = _fourier_fit(phi, rel, int(harmonics))
    contoured = replace(base, edge_correction=(a, b))
    # the outline (and so every section's phi) does not move: only the edge heights change
    _, gap2 = _section_gaps(contoured, face, landmarks, edge_length, bvh)
    return Contour(design=contoured, phi=phi, gap_before=rel, residual=gap2 - gap2.min())


def bundled_contours(harmonics: int = 16) -> dict:
    """Contours of the built-in designs to the bundled mean face (ICT-FaceKit neutral), as stored in
    :data:`headsim.mask.masks.CONTOUR_FILE`: {kind: {"a", "b", "harmonics", "face",
    "spread_before_mm", "spread_after_mm"}}."""
    from headsim.data import face_path
    from headsim.mesh.io import load_surface

    face = load_surface(face_path("neutral"))
    landmarks = find_landmarks(face)
    out = {}
    for kind in ("nasal", "oronasal"):
        c = contour_correction(design_of(kind, contour=False), face, landmarks, harmonics=harmonics)
        a, b = c.design.edge_correction
        out[kind] = {"a": list(a), "b": list(b), "harmonics": harmonics, "face": "face_neutral.obj (ICT-FaceKit)",
                     "spread_before_mm": round(c.spread_before * 1e3, 3),
                     "spread_after_mm": round(c.spread_after * 1e3, 3)}
    return out


if __name__ == "__main__":  # python -m headsim.mask.contour [--write]
    import json
    import sys

    from headsim.mask.masks import CONTOUR_FILE

    data = bundled_contours()
    for kind, d in data.items():
        print(f"{kind}: section gap spread {d['spread_before_mm']:.2f} mm -> {d['spread_after_mm']:.2f} mm "
              f"({d['harmonics']} harmonics)")
    if "--write" in sys.argv[1:]:
        CONTOUR_FILE.write_text(json.dumps(data, indent=1) + "\n")
        print(f"wrote {CONTOUR_FILE}")
