"""Mask models: the built-in parametric nasal and oronasal masks (sizes S, M, L).

A mask is a soft silicone **cushion** following the nose outline, attached to a rigid **shell** (the
end piece that the strap pulls; Heinze 2023 §2.4.1 makes the back of the mask rigid in the same way).

Mask frame (metres): origin at the centre of the airway opening, ``+x`` the wearer's left,
``+y`` up, ``+z`` away from the face. The mask approaches the face along ``-z``
(:attr:`MaskModel.airway_axis`).

Parametric design (all lengths for size M; S and L scale the whole mask by 0.9 and 1.1):

- **Outline** (the cushion's centre line seen from the front): a teardrop, narrow at the nasal
  bridge, ``x(t) ∝ cos t (1 - k (1 + sin t)/2)`` scaled to the largest width ``W``,
  ``y(t) = y0 + H/2 sin t``, resampled evenly by
  arc length. Nasal: W = 50 mm, H = 55 mm, y0 = 8.5 mm, k = 0.3 (the centre line crosses the nasal
  bridge 36 mm above and the upper lip 19 mm below the airway centre, which sits midway between nose
  tip and subnasale). Oronasal: W = 80 mm, H = 90 mm, y0 = 10 mm, k = 0.45 (bridge 55 mm above,
  below the lower lip 35 mm below the airway centre, midway between subnasale and stomion). The
  taper is limited so that the outline's radius of curvature stays ≥ 0.75 cushion widths (no
  folded inner wall).
- **Saddle**: the skin-side edge of the cushion lies at ``z_c(t) = -Z_cheek + Z_bridge s_top(t)^2
  + Z_lip s_bottom(t)^2`` with ``s_top = max(sin t, 0)``, ``s_bottom = max(-sin t, 0)``: deep at the
  cheeks, raised over the nasal bridge and the lip/chin, as the face is (nasal: 28, 9, 20 mm;
  oronasal: 24, 11, 17 mm). Like a manufacturer's cushion these are designed on the population's
  mean face (the bundled ICT neutral face): with size M placed automatically on it, the smallest
  skin gap per 30° sector of the outline varies by 3.0 mm (nasal) and 3.4 mm (oronasal) around the
  outline (measured with :func:`headsim.mask.placement.place_mask`; the first design, 21/13/13 mm
  and 21/18/14 mm, varied by 10.8 and 10.3 mm and could not seal on any bundled face). S and L are
  the same design scaled, so they fit smaller and larger faces, not the mean face. The shell's
  back plane is flat, ``h_bridge`` = 8 mm behind the highest point of the edge, so the cushion is
  8 mm tall over the bridge and up to 27 mm at the cheeks.
- **Cross-section**: ``w`` wide (nasal 10 mm, oronasal 12 mm) with its skin-side corners rounded
  (radius 3 mm), swept along the outline; the last 2.5 mm at the back are the rigid shell rim.
- **Tetrahedra** by a structured sweep (:mod:`headsim.mask.geometry`): cross-section grid
  triangles × outline samples → prisms → 3 tets each (Dompierre et al. 1999), conforming and
  positively oriented; deterministic.

Material: see :data:`CUSHION_SILICONE` and :func:`effective_cushion_modulus`. ``make_mask(...,
cushion="membrane")`` builds the hollow-membrane homogenisation instead (:data:`MEMBRANE_CUSHION`,
per-tet modulus :func:`membrane_cushion_modulus` from each section's own height: 2-49 kPa for
nasal-M). Measured on the bundled face it is far too soft to stand for a real membrane cushion: the
condensed linear model moves the cushion 18 mm at 5 N (more than its height) and the nonlinear fit
inverts cushion tets at 3 N -- a wall-bending homogenisation has no axial stiffness before the walls
buckle and no undercushion to bottom out on. A 3 mm, 1.11 MPa wall clamped at the shell buckles at
P_cr = pi^2 D / (4 H^2) = 20 N/m per wall for H = 20 mm (D = E t^3 / (12 (1 - nu^2))), i.e. about
7 N on the 17 cm nasal outline with two walls: a real membrane cushion works at a near-constant
force after buckling, which no single linear or neo-Hookean solid reproduces. The solid cushion
stays the default; the membrane option is kept for that comparison.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from headsim.errors import MeshError, ParameterError
from headsim.mask.geometry import grid_triangles, resample_closed_curve, split_prisms, sweep_ring
from headsim.mesh import REGION_CUSHION, REGION_SHELL, SurfaceMesh, TetMesh


# ------------------------------------------------------------------------------------------------
# materials
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CushionMaterial:
    """Linear-elastic (small-strain) parameters of a cushion, with their source.

    youngs_modulus : Pa, > 0
    poisson_ratio : in (-1, 0.5)
    density : kg/m^3, > 0
    """

    youngs_modulus: float
    poisson_ratio: float
    density: float = 1100.0
    name: str = "silicone"
    source: str = ""

    def __post_init__(self):
        if not (np.isfinite(self.youngs_modulus) and self.youngs_modulus > 0):
            raise ParameterError(f"youngs_modulus must be > 0 Pa, got {self.youngs_modulus}")
        if not -1.0 < self.poisson_ratio < 0.5:
            raise ParameterError(f"poisson_ratio must be in (-1, 0.5), got {self.poisson_ratio}")
        if not (np.isfinite(self.density) and self.density > 0):
            raise ParameterError(f"density must be > 0 kg/m^3, got {self.density}")

    @property
    def lame(self) -> tuple[float, float]:
        """(lambda, mu), Pa."""
        e, nu = self.youngs_modulus, self.poisson_ratio
        return e * nu / ((1 + nu) * (1 - 2 * nu)), e / (2 * (1 + nu))


#: Silicone membrane of a published custom-fit PAP cushion FE design, as quoted in issue 6:
#: 3 mm wall, E = 1.11 MPa, nu = 0.49.
SILICONE_MEMBRANE = CushionMaterial(
    youngs_modulus=1.11e6, poisson_ratio=0.49, density=1100.0, name="silicone membrane (t = 3 mm)",
    source="custom-fit PAP cushion FE design: 3 mm silicone membrane, E = 1.11 MPa, nu = 0.49 (issue 6)",
)


def effective_cushion_modulus(membrane_modulus: float, wall_thickness: float, cushion_width: float,
                              cushion_height: float) -> float:
    """Modulus (Pa) of a solid ring with the axial stiffness of a hollow membrane cushion.

    A hollow cushion of width ``w`` and height ``H`` with two walls of thickness ``t`` carries an
    axial load mainly by bending its walls. Per unit length of outline, two clamped-free plates of
    height ``H`` loaded at their tip give ``k_m = 2 * 3 E_m (t^3/12) / H^3 = E_m t^3 / (2 H^3)``; a
    solid block gives ``k_s = E_eff w / H``. Equal stiffness: ``E_eff = E_m t^3 / (2 w H^2)``.

    All lengths in m; returns Pa. For the issue's 3 mm, 1.11 MPa membrane in a 10 mm wide,
    8–21 mm tall cushion this is 3–26 kPa.
    """
    for name, val in (("membrane_modulus", membrane_modulus), ("wall_thickness", wall_thickness),
                      ("cushion_width", cushion_width), ("cushion_height", cushion_height)):
        if not (np.isfinite(val) and val > 0):
            raise ParameterError(f"{name} must be > 0, got {val}")
    return membrane_modulus * wall_thickness**3 / (2.0 * cushion_width * cushion_height**2)


#: Effective material of the built-in solid cushions. E = 50 kPa: the membrane-bending estimate of
#: :func:`effective_cushion_modulus` gives 3–26 kPa for the built-in cushions; the pressurised air
#: inside a real cushion (1 kPa at 10 cmH2O) and membrane stretching at contact stiffen it, and
#: soft silicone gel cushions lie at about 10–100 kPa, so 50 kPa is an order-of-magnitude value
#: (not fitted to any result). nu = 0.45: silicone is nearly incompressible, but a hollow cushion as
#: a structure is not; 0.45 also keeps linear tets free of volumetric locking. The fit adds a volume
#: floor to the cushion tets (:data:`headsim.mask.fit.CUSHION_COMPACTION`, :mod:`headsim.solvers.compaction`):
#: the effective solid has no bottoming-out stiffness of its own and was crushed through J = 0 above 40 N.
CUSHION_SILICONE = CushionMaterial(
    youngs_modulus=50e3, poisson_ratio=0.45, density=1100.0, name="silicone cushion (effective solid)",
    source="order-of-magnitude effective modulus: membrane bending estimate 3-26 kPa "
           "(effective_cushion_modulus with the 3 mm, 1.11 MPa membrane of issue 6), silicone gels 10-100 kPa",
)


@dataclass(frozen=True)
class MembraneWall:
    """The thin silicone wall of a hollow (membrane) cushion: thickness m, modulus Pa, its source."""

    thickness: float = 3e-3
    youngs_modulus: float = 1.11e6
    poisson_ratio: float = 0.49
    source: str = SILICONE_MEMBRANE.source

    def __post_init__(self):
        if not (np.isfinite(self.thickness) and 0 < self.thickness <= 0.02):
            raise ParameterError(f"membrane thickness must be in (0, 20] mm, got {self.thickness * 1e3:g} mm")
        if not (np.isfinite(self.youngs_modulus) and self.youngs_modulus > 0):
            raise ParameterError(f"membrane youngs_modulus must be > 0 Pa, got {self.youngs_modulus}")


#: The issue's membrane: 3 mm silicone, E = 1.11 MPa, nu = 0.49.
PAP_MEMBRANE = MembraneWall()


def membrane_cushion_modulus(wall: MembraneWall, cushion_width: float, free_height) -> np.ndarray:
    """Per-section modulus (Pa) of the solid that stands in for a hollow membrane cushion.

    :func:`effective_cushion_modulus` evaluated at every cushion section's own free height
    ``free_height`` (m, array): the two walls of a section bend like plates clamped at the rigid
    shell and loaded at the skin, so a tall section (at the cheeks) is far softer than a short one
    (over the nasal bridge), ``E_eff = E_m t^3 / (2 w H^2)``. Returns an array shaped like
    ``free_height``.
    """
    h = np.asarray(free_height, dtype=np.float64)
    if not (np.isfinite(h).all() and (h > 0).all()):
        raise ParameterError("free_height must be > 0 m everywhere")
    if not (np.isfinite(cushion_width) and cushion_width > 0):
        raise ParameterError(f"cushion_width must be > 0 m, got {cushion_width}")
    return wall.youngs_modulus * wall.thickness**3 / (2.0 * cushion_width * h**2)


#: Material of the homogenised membrane cushion (the built-in masks' default; the modulus varies
#: per tet, :func:`membrane_cushion_modulus`, the value here is its value for a 15 mm tall, 10 mm
#: wide section and is used only where one number is needed). nu = 0.3: the homogenised body is a
#: hollow structure, mostly air, that deforms by bending its walls and does not bulge sideways like
#: an incompressible solid; cellular solids have an effective Poisson ratio of about 0.3 (Gibson &
#: Ashby, Cellular Solids, 2nd ed., Cambridge University Press 1997, ch. 5).
MEMBRANE_CUSHION = CushionMaterial(
    youngs_modulus=effective_cushion_modulus(1.11e6, 3e-3, 10e-3, 15e-3), poisson_ratio=0.3, density=1100.0,
    name="silicone membrane cushion (homogenised, per-section modulus)",
    source="hollow cushion of a 3 mm silicone membrane, E = 1.11 MPa (custom-fit PAP cushion FE design, "
           "issue 6), homogenised by wall bending: E_eff = E_m t^3 / (2 w H^2) per section height H; "
           "effective nu = 0.3 (cellular solids, Gibson & Ashby 1997)",
)


# ------------------------------------------------------------------------------------------------
# the model
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class MaskModel:
    """A mask: soft cushion + rigid shell, as a tet mesh in the mask frame (or placed on a face).

    Attributes
    ----------
    name : "nasal-M", a file name, …
    kind : "nasal" or "oronasal": the airway the mask covers (user masks declare it)
    size : "S", "M", "L", or None for user masks
    tetmesh : TetMesh, m. ``tet_region`` / ``vertex_region`` are REGION_CUSHION or REGION_SHELL;
        ``fixed`` (n,) bool marks the rigid shell vertices (moved as one body by the strap).
    contact_triangles : (k, 3) int64 outward boundary triangles of ``tetmesh`` that may touch the skin
        (all cushion boundary faces with no shell vertex).
    airway_center : (3,) float64, m, centre of the airway opening.
    airway_axis : (3,) float64 unit vector, direction of approach (from the mask towards the face).
    up : (3,) float64 unit vector, the mask's up direction (towards the wearer's forehead),
        orthogonal to ``airway_axis``.
    material : CushionMaterial of the cushion (the shell is rigid).
    tet_modulus : (m,) float64 Pa or None: per-tet Young's modulus of a homogenised cushion whose
        stiffness varies along the outline (the built-in membrane cushions,
        :func:`membrane_cushion_modulus`); None: ``material.youngs_modulus`` everywhere.
    section_grid : (outline samples, rows, columns) of a swept parametric mask, whose vertex
        ``(sample * rows + row) * columns + column`` lies in row ``row`` (0 = the skin-side edge) of
        the cross-section at that outline sample; None for meshes from files.
    """

    name: str
    kind: str
    size: str | None
    tetmesh: TetMesh
    contact_triangles: np.ndarray
    airway_center: np.ndarray
    airway_axis: np.ndarray
    up: np.ndarray
    material: CushionMaterial = field(default_factory=lambda: CUSHION_SILICONE)
    tet_modulus: np.ndarray | None = None
    section_grid: tuple[int, int, int] | None = None

    def __post_init__(self):
        tm = self.tetmesh
        if self.tet_modulus is not None:
            em = np.array(self.tet_modulus, dtype=np.float64)
            if em.shape != (tm.n_tets,) or not (np.isfinite(em).all() and (em > 0).all()):
                raise ParameterError(f"{self.name}: tet_modulus must be ({tm.n_tets},) positive finite Pa values")
            em.flags.writeable = False
            object.__setattr__(self, "tet_modulus", em)
        if not isinstance(tm, TetMesh):
            raise MeshError(f"{self.name}: tetmesh must be a TetMesh")
        if tm.fixed is None or tm.vertex_region is None or tm.tet_region is None:
            raise MeshError(f"{self.name}: the mask's tet mesh needs tet_region, vertex_region and fixed")
        n_fixed = int(np.count_nonzero(tm.fixed))
        if n_fixed == 0:
            raise MeshError(f"{self.name}: the mask has no rigid (shell) vertices")
        if n_fixed == tm.n_vertices:
            raise MeshError(f"{self.name}: every vertex of the mask is rigid; no cushion is left")
        ct = np.array(self.contact_triangles, dtype=np.int64)
        if ct.ndim != 2 or ct.shape[1] != 3 or len(ct) == 0 or ct.min() < 0 or ct.max() >= tm.n_vertices:
            raise MeshError(f"{self.name}: contact_triangles must be a non-empty (k, 3) array of vertex ids")
        ct.flags.writeable = False
        object.__setattr__(self, "contact_triangles", ct)
        for name in ("airway_center", "airway_axis", "up"):
            arr = np.array(getattr(self, name), dtype=np.float64)
            if arr.shape != (3,) or not np.isfinite(arr).all():
                raise ParameterError(f"{self.name}: {name} must be a finite (3,) vector")
            if name != "airway_center":
                norm = np.linalg.norm(arr)
                if norm < 1e-12:
                    raise ParameterError(f"{self.name}: {name} must be non-zero")
                arr = arr / norm
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        if abs(float(self.up @ self.airway_axis)) > 1e-6:
            raise ParameterError(f"{self.name}: up must be orthogonal to airway_axis")

    @property
    def shell_vertices(self) -> np.ndarray:
        """(s,) int64 ids of the rigid vertices."""
        return np.flatnonzero(self.tetmesh.fixed)

    @property
    def contact_vertices(self) -> np.ndarray:
        """(c,) int64 ids of the vertices of :attr:`contact_triangles`."""
        return np.unique(self.contact_triangles)

    @property
    def contact_surface(self) -> SurfaceMesh:
        """The skin-side surface as a SurfaceMesh sharing the tet mesh's vertex ids."""
        return SurfaceMesh(self.tetmesh.vertices, self.contact_triangles, name=f"{self.name}[contact]")

    @property
    def frame(self) -> np.ndarray:
        """(3, 3) float64: columns lateral (up x -axis), up, -airway_axis (the mask frame's axes)."""
        back = -self.airway_axis
        return np.column_stack([np.cross(self.up, back), self.up, back])

    def describe(self) -> dict:
        """Plain numbers for listings and reports (lengths in mm, modulus in kPa)."""
        ext = np.ptp(self.tetmesh.vertices @ self.frame, axis=0) * 1e3
        return {
            "name": self.name, "kind": self.kind, "size": self.size,
            "width_mm": float(ext[0]), "height_mm": float(ext[1]), "depth_mm": float(ext[2]),
            "n_vertices": self.tetmesh.n_vertices, "n_tets": self.tetmesh.n_tets,
            "n_rigid_vertices": int(np.count_nonzero(self.tetmesh.fixed)),
            "n_contact_triangles": int(len(self.contact_triangles)),
            "cushion_modulus_kpa": self.material.youngs_modulus / 1e3,
            "cushion_poisson_ratio": self.material.poisson_ratio,
        }

    def with_vertices(self, vertices: np.ndarray) -> "MaskModel":
        """The same mask with its tet mesh at new positions (e.g. deformed by a fit); the airway
        frame is kept."""
        return replace(self, tetmesh=self.tetmesh.with_vertices(vertices))

    def transformed(self, rotation: np.ndarray, translation: np.ndarray, name: str | None = None) -> "MaskModel":
        """The mask moved rigidly by ``x -> rotation @ x + translation`` (rotation (3, 3), proper)."""
        r = np.asarray(rotation, dtype=np.float64)
        t = np.asarray(translation, dtype=np.float64).reshape(3)
        if r.shape != (3, 3) or not np.allclose(r @ r.T, np.eye(3), atol=1e-9) or np.linalg.det(r) < 0:
            raise ParameterError("rotation must be a proper 3x3 rotation matrix")
        tm = self.tetmesh.with_vertices(self.tetmesh.vertices @ r.T + t)
        return replace(self, tetmesh=tm, airway_center=r @ self.airway_center + t,
                       airway_axis=r @ self.airway_axis, up=r @ self.up, name=name or self.name)

    def __repr__(self) -> str:
        return (f"MaskModel({self.name!r}, {self.kind}, {self.tetmesh.n_vertices} vertices, "
                f"{self.tetmesh.n_tets} tets)")


# ------------------------------------------------------------------------------------------------
# parametric design
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MaskDesign:
    """Parameters of a built-in mask at size M (lengths in m; see the module doc)."""

    kind: str
    width: float            # W, outline width
    height: float           # H, outline height
    y_offset: float         # y0, outline centre above the airway centre
    taper: float            # k, narrowing towards the bridge, in [0, 1)
    cheek_depth: float      # Z_cheek, how far the skin-side edge reaches towards the face at the cheeks
    bridge_rise: float      # Z_bridge
    lip_rise: float         # Z_lip (lip for nasal, chin for oronasal)
    cushion_width: float    # w
    bridge_height: float = 8e-3   # cushion height over the bridge
    shell_thickness: float = 2.5e-3
    corner_radius: float = 3e-3
    #: Fourier coefficients ((a_0..a_K), (b_0..b_K)), m at size M, of how far the edge is moved towards
    #: the face as a function of the outline angle (:func:`outline_angle`): the contour to a reference
    #: face (:mod:`headsim.mask.contour`). None: the analytic saddle alone.
    edge_correction: tuple[tuple[float, ...], tuple[float, ...]] | None = None

    def __post_init__(self):
        if self.edge_correction is not None:
            a, b = self.edge_correction
            if len(a) != len(b) or len(a) < 1 or not np.isfinite(np.r_[a, b]).all():
                raise ParameterError("mask design: edge_correction must be two equally long finite coefficient lists")
            if np.abs(np.r_[a, b]).sum() > 0.05:
                raise ParameterError("mask design: edge_correction moves the edge by more than 5 cm")
        for name in ("width", "height", "cheek_depth", "cushion_width", "bridge_height",
                     "shell_thickness", "corner_radius"):
            if not getattr(self, name) > 0:
                raise ParameterError(f"mask design: {name} must be > 0")
        if not 0 <= self.taper < 1:
            raise ParameterError("mask design: taper must be in [0, 1)")
        if 2 * self.corner_radius > self.cushion_width:
            raise ParameterError("mask design: corner_radius must be at most half the cushion width")


_DESIGNS = {
    "nasal": MaskDesign("nasal", width=50e-3, height=55e-3, y_offset=8.5e-3, taper=0.3,
                        cheek_depth=28e-3, bridge_rise=9e-3, lip_rise=20e-3, cushion_width=10e-3),
    "oronasal": MaskDesign("oronasal", width=80e-3, height=90e-3, y_offset=10e-3, taper=0.45,
                           cheek_depth=24e-3, bridge_rise=11e-3, lip_rise=17e-3, cushion_width=12e-3),
}
_SIZES = {"S": 0.9, "M": 1.0, "L": 1.1}

#: The contour of the built-in cushions to the bundled mean face (written by
#: ``python -m headsim.mask.contour --write``; :mod:`headsim.mask.contour`).
CONTOUR_FILE = Path(__file__).with_name("cushion_contours.json")


@lru_cache(maxsize=1)
def _stored_contours() -> dict:
    if not CONTOUR_FILE.exists():  # part of the package: a missing file must not silently uncontour
        raise FileNotFoundError(f"{CONTOUR_FILE} is missing from the installation; regenerate it with "
                                "`python -m headsim.mask.contour --write` or use contour=False")
    return json.loads(CONTOUR_FILE.read_text())


def design_of(kind: str, contour: bool = True) -> MaskDesign:
    """The built-in design of ``kind`` ("nasal" or "oronasal") at size M; ``contour``: with its edge
    contoured to the mean face (the stored :data:`CONTOUR_FILE`), else the analytic saddle alone."""
    if kind not in _DESIGNS:
        raise ParameterError(f"unknown mask kind {kind!r}; use one of {', '.join(_DESIGNS)}")
    design = _DESIGNS[kind]
    if contour:
        stored = _stored_contours()[kind]
        design = replace(design, edge_correction=(tuple(stored["a"]), tuple(stored["b"])))
    return design


def mask_catalogue() -> list[str]:
    """Names of the built-in masks: ``nasal-S`` … ``oronasal-L``."""
    return [f"{kind}-{size}" for kind in _DESIGNS for size in _SIZES]


def outline_angle(design: MaskDesign, scale: float, xy: np.ndarray) -> np.ndarray:
    """(n,) rad: the angle of outline points ``xy`` (n, 2), m (mask frame), around the outline centre,
    with the axes scaled to the outline's half width and half height (0 at the wearer's left cheek,
    pi/2 over the bridge); the same for every size."""
    xy = np.asarray(xy, dtype=np.float64)
    return np.arctan2((xy[:, 1] - design.y_offset * scale) / (0.5 * design.height * scale),
                      xy[:, 0] / (0.5 * design.width * scale))


def edge_correction_at(design: MaskDesign, phi: np.ndarray) -> np.ndarray:
    """(n,) m at size M: the design's contour correction at outline angles ``phi`` (0 without one)."""
    phi = np.asarray(phi, dtype=np.float64)
    if design.edge_correction is None:
        return np.zeros_like(phi)
    a, b = (np.asarray(c) for c in design.edge_correction)
    k = np.arange(len(a))
    return np.cos(np.outer(phi, k)) @ a + np.sin(np.outer(phi, k)) @ b


def _outline(design: MaskDesign, scale: float, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, 2) outline points, (n, 2) outward normals, (n,) skin-side edge z, m (mask frame)."""
    t = np.linspace(0.0, 2.0 * np.pi, 4096, endpoint=False)
    w, h = design.width * scale, design.height * scale
    x = np.cos(t) * (1.0 - design.taper * (1.0 + np.sin(t)) / 2.0)
    x *= 0.5 * w / np.abs(x).max()                     # W is the outline's largest width
    y = design.y_offset * scale + 0.5 * h * np.sin(t)
    pts, tangent = resample_closed_curve(np.column_stack([x, y]), n)
    # counter-clockwise curve: the outward normal is the tangent turned clockwise
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    # the edge height follows the angle around the outline centre
    rel = pts - np.array([0.0, design.y_offset * scale])
    sin_t = rel[:, 1] / (0.5 * h)
    sin_t = np.clip(sin_t, -1.0, 1.0)
    z_edge = scale * (-design.cheek_depth + design.bridge_rise * np.maximum(sin_t, 0.0) ** 2
                      + design.lip_rise * np.maximum(-sin_t, 0.0) ** 2
                      - edge_correction_at(design, outline_angle(design, scale, pts)))
    return pts, normal, z_edge


def _min_curvature_radius(points: np.ndarray) -> float:
    """Smallest radius of curvature (m) of a closed planar polyline (circumscribed circles of
    consecutive point triples)."""
    a, b, c = np.roll(points, 1, axis=0), points, np.roll(points, -1, axis=0)
    ab, bc, ca = (np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1), np.linalg.norm(a - c, axis=1))
    cross = np.abs((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    with np.errstate(divide="ignore"):
        radius = ab * bc * ca / (2.0 * cross)
    return float(np.min(radius))


def build_parametric_mask(design: MaskDesign, scale: float = 1.0, edge_length: float = 3e-3,
                          name: str | None = None, size: str | None = None,
                          material: CushionMaterial = CUSHION_SILICONE,
                          membrane: "MembraneWall | None" = None, section_edge: float | None = None,
                          corner_segments: int | None = None) -> MaskModel:
    """Build the tet mesh of a parametric mask (see the module doc).

    Parameters
    ----------
    design : MaskDesign
    scale : uniform size factor (S 0.9, M 1.0, L 1.1)
    edge_length : target element size along the outline and across the cushion, m (1–5 mm)
    material : the cushion's material (its Poisson ratio and density are used with ``membrane``)
    membrane : a MembraneWall: the solid cushion is the homogenised hollow membrane cushion, with a
        per-tet modulus from the local cushion height (:func:`membrane_cushion_modulus`); None: the
        uniform ``material``
    section_edge : element size across the cross-section (columns and the rows above the rounded
        corner), m, 0.5–5 mm; None: ``edge_length`` (which always sets the spacing along the outline)
    corner_segments : rows of the rounded skin-side corner (radius ``corner_radius``): n >= 2 segments
        at equal angles, so the vertices lie on the arc and each chord stays within
        ``r (1 - cos(pi / (4 n)))`` of it (r = 3 mm: 0.23 mm for 2, 0.06 mm for 4); None: the
        original rows at heights 0, r/2 and r (chords of 60 and 30 degrees, up to 0.40 mm inside the
        arc). Many segments make the lowest rows slivers (height r (1 - cos(pi / (2 n))): 0.10 mm for
        6, 0.06 mm for 8): with 8 and 12 the linear condensed model inverted cushion tets at 10 N.
    """
    if not 0.5e-3 <= edge_length <= 5e-3:
        raise ParameterError(f"edge_length must be 0.5–5 mm, got {edge_length * 1e3:g} mm")
    if not 0.5 <= scale <= 2.0:
        raise ParameterError(f"scale must be 0.5–2, got {scale}")
    w = design.cushion_width * scale
    rc = design.corner_radius * scale
    shell_t = design.shell_thickness * scale
    # outline samples
    perimeter_guess = np.pi * (design.width + design.height) * scale / 2.0
    n_samples = max(24, int(np.ceil(perimeter_guess / edge_length)))
    pts, normal, z_edge = _outline(design, scale, n_samples)
    radius = _min_curvature_radius(_outline(design, scale, 2048)[0])
    if radius < 0.75 * w:
        raise ParameterError(
            f"mask design: the outline bends with radius {radius * 1e3:.1f} mm, too tight for a "
            f"{w * 1e3:.1f} mm wide cushion (needs ≥ {0.75 * w * 1e3:.1f} mm); lower the taper"
        )
    z_back = float(z_edge.max()) + design.bridge_height * scale   # flat back plane of the shell

    # cross-section grid: columns across the width, rows up from the skin-side edge
    se = edge_length if section_edge is None else section_edge
    if not 0.5e-3 <= se <= 5e-3:
        raise ParameterError(f"section_edge must be 0.5–5 mm, got {se * 1e3:g} mm")
    if corner_segments is not None and (int(corner_segments) != corner_segments or not 2 <= corner_segments <= 6):
        raise ParameterError(f"corner_segments must be an integer 2–6 or None, got {corner_segments}")
    n_cols = max(3, int(np.ceil(w / se))) + 1
    if corner_segments is None:
        h_round = np.array([0.0, 0.5, 1.0]) * rc            # the rounded skin-side rows
    else:
        theta = np.linspace(0.0, 0.5 * np.pi, int(corner_segments) + 1)
        h_round = rc * (1.0 - np.cos(theta))
    min_height = z_back - float(z_edge.max()) - shell_t           # cushion height at the bridge
    n_mid = max(2, int(np.ceil((z_back - float(z_edge.min()) - shell_t - rc) / se)))
    if min_height <= rc:
        raise ParameterError("mask design: the cushion is shorter than its rounded edge")
    n_rows = len(h_round) + n_mid + 1                             # … + mid rows + shell top row
    section_tri = grid_triangles(n_rows, n_cols)
    n_nodes = n_rows * n_cols

    height = z_back - z_edge                                      # (n_samples,) cushion + shell height
    rows = np.empty((n_samples, n_rows))
    rows[:, : len(h_round)] = h_round
    frac = np.arange(1, n_mid + 1) / n_mid
    rows[:, len(h_round): len(h_round) + n_mid] = rc + frac[None, :] * (height - shell_t - rc)[:, None]
    rows[:, -1] = height
    half = np.where(rows < rc, 0.5 * w - rc + np.sqrt(np.clip(rc**2 - (rc - rows) ** 2, 0.0, None)), 0.5 * w)
    r = half[:, :, None] * np.linspace(-1.0, 1.0, n_cols)[None, None, :]      # (samples, rows, cols)
    xy = pts[:, None, None, :] + r[..., None] * normal[:, None, None, :]
    z = (z_edge[:, None] + rows)[:, :, None] * np.ones((1, 1, n_cols))
    vertices = np.concatenate([xy, z[..., None]], axis=3).reshape(-1, 3)

    prisms = sweep_ring(section_tri, n_nodes, n_samples)
    tets = split_prisms(prisms, vertices)
    row_of_vertex = np.tile(np.repeat(np.arange(n_rows), n_cols), n_samples)
    shell_row = n_rows - 2                                        # shell tets span rows n-2 .. n-1
    vertex_region = np.where(row_of_vertex >= shell_row, REGION_SHELL, REGION_CUSHION).astype(np.int32)
    tet_region = np.where((row_of_vertex[tets] >= shell_row).all(axis=1), REGION_SHELL,
                          REGION_CUSHION).astype(np.int32)
    fixed = vertex_region == REGION_SHELL
    label = name or f"{design.kind}-custom"
    tm = TetMesh(vertices, tets, tet_region=tet_region, vertex_region=vertex_region, fixed=fixed, name=label)
    boundary = tm.boundary_triangles
    contact = boundary[(~fixed[boundary]).all(axis=1)]
    tet_modulus = None
    if membrane is not None:
        # free (soft) height of the cushion at each outline sample, averaged over a tet's vertices
        sample_of_vertex = np.repeat(np.arange(n_samples), n_nodes)
        free_height = (height - shell_t)[sample_of_vertex[tets]].mean(axis=1)
        tet_modulus = membrane_cushion_modulus(membrane, w, free_height)
    return MaskModel(name=label, kind=design.kind, size=size, tetmesh=tm, contact_triangles=contact,
                     airway_center=np.zeros(3), airway_axis=np.array([0.0, 0.0, -1.0]),
                     up=np.array([0.0, 1.0, 0.0]), material=material, tet_modulus=tet_modulus,
                     section_grid=(n_samples, n_rows, n_cols))


def make_mask(name: str, edge_length: float = 3e-3, material: CushionMaterial | None = None,
              cushion: str = "solid", contour: bool = True, section_edge: float | None = None,
              corner_segments: int | None = None) -> MaskModel:
    """A built-in mask by name (``nasal-M``, ``oronasal-L``, … see :func:`mask_catalogue`).

    cushion : "solid" (default: a uniform solid cushion, material :data:`CUSHION_SILICONE`) or
        "membrane" (the hollow 3 mm silicone membrane cushion homogenised per section,
        :func:`membrane_cushion_modulus`, material :data:`MEMBRANE_CUSHION`; too soft, module doc)
    material : overrides the cushion's material (its modulus is used only with ``cushion="solid"``)
    contour : True (default): the skin-side edge contoured to the bundled mean face, as a
        manufacturer designs a cushion on a reference head form (:mod:`headsim.mask.contour`);
        False: the analytic three-height saddle alone
    section_edge, corner_segments : the cross-section's resolution (:func:`build_parametric_mask`)
    """
    if cushion not in ("membrane", "solid"):
        raise ParameterError(f"cushion must be 'membrane' or 'solid', got {cushion!r}")
    membrane = PAP_MEMBRANE if cushion == "membrane" else None
    if material is None:
        material = MEMBRANE_CUSHION if cushion == "membrane" else CUSHION_SILICONE
    kind, _, size = str(name).strip().partition("-")
    if kind not in _DESIGNS or size.upper() not in _SIZES:
        raise ParameterError(f"unknown mask {name!r}; built-in masks: {', '.join(mask_catalogue())}")
    size = size.upper()
    return build_parametric_mask(design_of(kind, contour), scale=_SIZES[size], edge_length=edge_length,
                                 name=f"{kind}-{size}", size=size, material=material, membrane=membrane,
                                 section_edge=section_edge, corner_segments=corner_segments)
