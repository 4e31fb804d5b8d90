"""Shape quality of tetrahedra: dihedral angles, radius ratio, volumes (vectorised).

The radius ratio is ``rho = 3 r_in / R_circ`` (1 for the regular tetrahedron, 0 for a flat one);
the dihedral angles of the regular tetrahedron are all arccos(1/3) = 70.53 deg. Finite-element
practice: minimum dihedral angles below ~5 deg or radius ratios below ~0.05 degrade conditioning
(Shewchuk, "What is a good linear finite element?", 2002).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.mesh.tet import TetMesh

#: the four faces of a tet (opposite vertex 0..3), each ordered with an outward normal for a
#: positively oriented tet
_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
#: the six edges, and the two faces meeting at each (faces are numbered by their opposite vertex)
_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])
_EDGE_FACES = np.array([[2, 3], [1, 3], [1, 2], [0, 3], [0, 2], [0, 1]])


def tet_dihedral_angles(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(m, 6) float64 interior dihedral angles, radians, at edges 01, 02, 03, 12, 13, 23."""
    p = vertices[tets]                                      # (m, 4, 3)
    f = p[:, _FACES]                                        # (m, 4, 3, 3)
    normals = np.cross(f[:, :, 1] - f[:, :, 0], f[:, :, 2] - f[:, :, 0])
    norm = np.linalg.norm(normals, axis=2, keepdims=True)
    normals = np.divide(normals, norm, out=np.zeros_like(normals), where=norm > 0)
    n1 = normals[:, _EDGE_FACES[:, 0]]
    n2 = normals[:, _EDGE_FACES[:, 1]]
    cos = np.clip(np.einsum("mek,mek->me", n1, n2), -1.0, 1.0)
    return np.pi - np.arccos(cos)


def tet_radius_ratio(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(m,) float64 ``3 r_in / R_circ``; negative for inverted tets (signed volume)."""
    p = vertices[tets]
    a, b, c = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]
    vol6 = np.einsum("ij,ij->i", np.cross(a, b), c)        # 6 V
    f = p[:, _FACES]
    areas = 0.5 * np.linalg.norm(np.cross(f[:, :, 1] - f[:, :, 0], f[:, :, 2] - f[:, :, 0]), axis=2).sum(axis=1)
    r_in = (vol6 / 2.0) / areas                              # 3V / S
    num = (np.einsum("ij,ij->i", a, a)[:, None] * np.cross(b, c)
           + np.einsum("ij,ij->i", b, b)[:, None] * np.cross(c, a)
           + np.einsum("ij,ij->i", c, c)[:, None] * np.cross(a, b))
    with np.errstate(divide="ignore", invalid="ignore"):
        r_circ = np.linalg.norm(num, axis=1) / (2.0 * np.abs(vol6))
        rho = np.where(np.abs(vol6) > 0, 3.0 * r_in / r_circ, 0.0)
    return rho


@dataclass(frozen=True)
class TetQuality:
    """Per-tet quality arrays and their summary.

    min_dihedral : (m,) float64, rad
    max_dihedral : (m,) float64, rad
    radius_ratio : (m,) float64, 3 r_in / R_circ in (0, 1]
    volume : (m,) float64, m^3
    """

    min_dihedral: np.ndarray
    max_dihedral: np.ndarray
    radius_ratio: np.ndarray
    volume: np.ndarray

    @property
    def min_dihedral_deg(self) -> float:
        return float(np.degrees(self.min_dihedral.min()))

    @property
    def max_dihedral_deg(self) -> float:
        return float(np.degrees(self.max_dihedral.max()))

    def summary(self) -> dict[str, float]:
        """Scalars for reports: angles in degrees, volumes in m^3."""
        rr = self.radius_ratio
        return {
            "n_tets": int(len(rr)),
            "min_dihedral_deg": self.min_dihedral_deg,
            "max_dihedral_deg": self.max_dihedral_deg,
            "dihedral_p1_deg": float(np.degrees(np.percentile(self.min_dihedral, 1))),
            "radius_ratio_min": float(rr.min()),
            "radius_ratio_p1": float(np.percentile(rr, 1)),
            "radius_ratio_median": float(np.median(rr)),
            "radius_ratio_mean": float(rr.mean()),
            "volume_total": float(self.volume.sum()),
            "volume_min": float(self.volume.min()),
            "volume_max": float(self.volume.max()),
            "volume_mean": float(self.volume.mean()),
        }


def tet_quality(mesh: TetMesh) -> TetQuality:
    """Quality of every tet of ``mesh`` (see :class:`TetQuality`)."""
    ang = tet_dihedral_angles(mesh.vertices, mesh.tets)
    return TetQuality(
        min_dihedral=ang.min(axis=1),
        max_dihedral=ang.max(axis=1),
        radius_ratio=tet_radius_ratio(mesh.vertices, mesh.tets),
        volume=mesh.rest_volumes.copy(),
    )
