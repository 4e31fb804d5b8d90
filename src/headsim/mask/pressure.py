"""Contact pressure on the skin from per-vertex contact forces, and its summary numbers.

Per-vertex pressure is the compressive normal component of the contact force over the vertex's
lumped area: ``p_i = max(0, -f_i . n_i) / A_i`` with ``n_i`` the skin's outward unit vertex normal
and ``A_i`` one third of the area of the triangles at vertex ``i`` (so ``sum_i p_i A_i`` is the
total normal contact force). A force pulling the skin outwards (adhesion) gives no pressure.

Thresholds:

- capillary closing pressure 32 mmHg = 4266 Pa (Landis 1930), the usual pressure-injury threshold;
- therapy pressure 10 cmH2O = 980.665 Pa (the default CPAP/NIV air pressure a seal must hold).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.errors import ParameterError
from headsim.mesh import SurfaceMesh

#: 1 mmHg in Pa.
MMHG = 133.322387415
#: 1 cmH2O in Pa.
CMH2O = 98.0665
#: Capillary closing pressure, 32 mmHg (Landis 1930), Pa.
CAPILLARY_CLOSING_PA = 32.0 * MMHG
#: Default therapy air pressure, 10 cmH2O, Pa.
THERAPY_PRESSURE_PA = 10.0 * CMH2O


def _vector_field(a, n: int, what: str) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.shape != (n, 3) or not np.isfinite(arr).all():
        raise ParameterError(f"{what} must be a finite ({n}, 3) array, got shape {arr.shape}")
    return arr


def _scalar_field(a, n: int, what: str) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.shape != (n,) or not np.isfinite(arr).all():
        raise ParameterError(f"{what} must be a finite ({n},) array, got shape {arr.shape}")
    return arr


def contact_pressure(forces: np.ndarray, normals: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """Per-vertex contact pressure, Pa.

    Parameters
    ----------
    forces : (n, 3) float64, N, contact force acting on each skin vertex
    normals : (n, 3) float64, outward unit skin normals
    areas : (n,) float64, m^2, lumped vertex areas (> 0 wherever a force acts)

    Returns
    -------
    (n,) float64, Pa: ``max(0, -f . n) / A`` (0 where the vertex area is 0 and no force acts).
    """
    f = np.asarray(forces, dtype=np.float64)
    n = len(f)
    f = _vector_field(f, n, "forces")
    nv = _vector_field(normals, n, "normals")
    a = _scalar_field(areas, n, "areas")
    push = np.maximum(-np.einsum("ij,ij->i", f, nv), 0.0)
    if np.any((a <= 0) & (push > 0)):
        raise ParameterError("a contact force acts on a vertex with zero area")
    return np.divide(push, a, out=np.zeros(n), where=a > 0)


def vertex_contact_pressure(face: SurfaceMesh, forces: np.ndarray) -> np.ndarray:
    """:func:`contact_pressure` with the face's own vertex normals and areas; (n,) Pa."""
    return contact_pressure(forces, face.vertex_normals, face.vertex_areas)


@dataclass(frozen=True)
class PressureSummary:
    """Summary of a contact-pressure field on the skin.

    contact_area : m^2, area of the vertices with pressure > 0
    area_above_threshold : m^2, area of the vertices with pressure > ``threshold``
    threshold : Pa
    peak_pressure : Pa, largest vertex pressure
    mean_pressure : Pa, area-weighted mean over the contact area (0 without contact)
    normal_force : N, sum of pressure × area
    """

    contact_area: float
    area_above_threshold: float
    threshold: float
    peak_pressure: float
    mean_pressure: float
    normal_force: float

    @property
    def contact_area_cm2(self) -> float:
        return self.contact_area * 1e4

    @property
    def area_above_threshold_cm2(self) -> float:
        return self.area_above_threshold * 1e4

    def as_dict(self) -> dict[str, float]:
        """Numbers in report units: cm^2, kPa, N."""
        return {
            "contact_area_cm2": self.contact_area_cm2,
            "area_above_threshold_cm2": self.area_above_threshold_cm2,
            "threshold_kpa": self.threshold / 1e3,
            "peak_pressure_kpa": self.peak_pressure / 1e3,
            "mean_pressure_kpa": self.mean_pressure / 1e3,
            "normal_force_n": self.normal_force,
        }


def summarize_pressure(pressure: np.ndarray, areas: np.ndarray,
                       threshold: float = CAPILLARY_CLOSING_PA) -> PressureSummary:
    """Contact area, area above ``threshold``, peak and mean pressure, total normal force.

    Parameters
    ----------
    pressure : (n,) float64, Pa, ≥ 0
    areas : (n,) float64, m^2, lumped vertex areas
    threshold : Pa, > 0 (default: capillary closing pressure, 32 mmHg)
    """
    p = np.asarray(pressure, dtype=np.float64)
    n = len(p)
    p = _scalar_field(p, n, "pressure")
    a = _scalar_field(areas, n, "areas")
    if np.any(p < 0):
        raise ParameterError("pressure must be ≥ 0 Pa")
    if np.any(a < 0):
        raise ParameterError("areas must be ≥ 0 m^2")
    if not (np.isfinite(threshold) and threshold > 0):
        raise ParameterError(f"threshold must be > 0 Pa, got {threshold}")
    contact = p > 0
    contact_area = float(a[contact].sum())
    force = float((p * a).sum())
    return PressureSummary(
        contact_area=contact_area,
        area_above_threshold=float(a[p > threshold].sum()),
        threshold=float(threshold),
        peak_pressure=float(p.max()) if n else 0.0,
        mean_pressure=force / contact_area if contact_area > 0 else 0.0,
        normal_force=force,
    )
