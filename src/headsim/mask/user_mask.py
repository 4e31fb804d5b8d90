"""User masks from mesh files: a closed body, or an open cushion membrane with a wall thickness.

- A **closed** surface (STL/OBJ/… of the whole mask body) is filled with tetrahedra by the
  foundation's mesher (:func:`headsim.mesh.tetra.tetrahedralize_surface`).
- An **open** surface (the usual CAD export of a silicone membrane) needs its wall ``thickness``;
  it is turned into a solid layer by :func:`extrude_shell` (written here: the mesh package's tissue
  extrusion is specialised to faces over bone — trimming, bone depth — and exposes no generic
  extrusion): every vertex is offset along its smoothed normal in ``layers`` steps, the layered
  prisms are split into three tets each (Dompierre et al. 1999, conforming).

The **rigid region** (the shell / end piece the strap pulls; Heinze 2023 §2.4.1) is given either
as a set of surface vertex ids (``rigid=np.array([...])``), or as a plane cut
``rigid=(point, normal)``: vertices *behind* the plane, ``(x - point) . normal < 0``, are rigid,
so ``normal`` points from the shell towards the face. For a closed body the mesher remeshes the
surface, so a vertex set is carried over by proximity: a tet vertex is rigid when its nearest
surface vertex is in the set and at most 1.5 mean surface edge lengths away.

Mask frame defaults (for ``placement="auto"`` pass them explicitly): ``airway_axis`` = the plane
normal, or the direction from the rigid vertices' centroid to the cushion vertices' centroid;
``airway_center`` = the centroid of the skin-side (contact) vertices; ``up`` = ``+y`` made
orthogonal to the axis (``+z`` if ``+y`` is parallel to it).
"""

from __future__ import annotations

import os

import numpy as np

from headsim.errors import MeshError, ParameterError, RegionError
from headsim.mask.geometry import split_prisms
from headsim.mask.masks import CUSHION_SILICONE, CushionMaterial, MaskModel
from headsim.mesh import REGION_CUSHION, REGION_SHELL, SurfaceMesh, TetMesh, check_head_scale, parse_units
from headsim.mesh.geometry import tet_signed_volumes, vertex_normals

#: Plausible largest extent of a mask, m.
MASK_EXTENT_RANGE_M = (0.02, 0.3)


def extrude_shell(surface: SurfaceMesh, thickness: float, layers: int = 2, direction: str = "inward",
                  smoothing: int = 3) -> TetMesh:
    """Solid layer of tets from an open (or closed) surface and a wall thickness.

    Parameters
    ----------
    surface : SurfaceMesh, m, consistently oriented
    thickness : wall thickness, m, > 0
    layers : tet layers through the wall, ≥ 1
    direction : "inward" (against the triangle normals) or "outward" (along them)
    smoothing : Laplacian smoothing passes of the offset directions

    Returns
    -------
    TetMesh
        Vertex ``j * n + i`` is surface vertex ``i`` offset by ``j / layers * thickness``;
        3 × layers × m positively oriented tets; no regions (set by the caller).

    Raises
    ------
    MeshError
        The offset folds (thickness too large for the surface's curvature) or vertices have no normal.
    """
    if not (np.isfinite(thickness) and thickness > 0):
        raise ParameterError(f"thickness must be > 0 m, got {thickness}")
    if int(layers) != layers or layers < 1:
        raise ParameterError(f"layers must be an integer ≥ 1, got {layers}")
    if direction not in ("inward", "outward"):
        raise ParameterError(f"direction must be 'inward' or 'outward', got {direction!r}")
    layers = int(layers)
    v, tri = surface.vertices, surface.triangles
    d = vertex_normals(v, tri) * (-1.0 if direction == "inward" else 1.0)
    if np.any(np.linalg.norm(d, axis=1) < 0.5):
        raise MeshError(f"{surface.name}: vertices without a normal (unused or in degenerate triangles only)")
    adj = surface.adjacency
    deg = np.maximum(np.asarray(adj.sum(axis=1)).ravel(), 1.0)
    for _ in range(int(smoothing)):
        d = 0.5 * d + 0.5 * (adj @ d) / deg[:, None]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
    n = len(v)
    offsets = np.arange(layers + 1) / layers * thickness
    vertices = (v[None, :, :] + offsets[:, None, None] * d[None, :, :]).reshape(-1, 3)
    prisms = np.concatenate([np.concatenate([tri + j * n, tri + (j + 1) * n], axis=1) for j in range(layers)])
    raw = split_prisms(prisms, vertices, orient=False)
    # the three tets of an unfolded prism share the prism's orientation; a folded offset shows up
    # as tets of the opposite sign (or flat ones)
    vol = tet_signed_volumes(vertices, raw)
    sign = np.sign(np.median(vol))
    bad = vol * sign <= 1e-15 * float(np.ptp(vertices, axis=0).max()) ** 3
    if sign == 0 or bad.any():
        raise MeshError(
            f"{surface.name}: the {thickness * 1e3:g} mm wall folds over itself at {int(bad.sum())} tets "
            "(thickness too large for the surface's curvature)"
        )
    tets = raw if sign > 0 else raw[:, [0, 2, 1, 3]]
    return TetMesh(vertices, tets, name=f"{surface.name}[shell {thickness * 1e3:g} mm]")


def _rigid_mask(tm_vertices: np.ndarray, rigid, surface: SurfaceMesh, source_vertex: np.ndarray | None) -> np.ndarray:
    """(n,) bool rigid tet vertices from a vertex set or a plane cut (module doc)."""
    if isinstance(rigid, tuple) and len(rigid) == 2:
        point = np.asarray(rigid[0], dtype=np.float64)
        normal = np.asarray(rigid[1], dtype=np.float64)
        if point.shape != (3,) or normal.shape != (3,) or not (np.isfinite(point).all() and np.isfinite(normal).all()):
            raise ParameterError("a rigid plane is (point (3,), normal (3,)), both finite")
        if np.linalg.norm(normal) < 1e-12:
            raise ParameterError("the rigid plane's normal must be non-zero")
        return (tm_vertices - point) @ normal < 0
    ids = np.asarray(rigid)
    if ids.dtype == bool:
        if ids.shape != (surface.n_vertices,):
            raise RegionError(f"a boolean rigid mask must have shape ({surface.n_vertices},), got {ids.shape}")
        ids = np.flatnonzero(ids)
    ids = ids.astype(np.int64).ravel()
    if len(ids) and (ids.min() < 0 or ids.max() >= surface.n_vertices):
        raise RegionError(f"rigid vertex ids must lie in [0, {surface.n_vertices - 1}]")
    in_set = np.zeros(surface.n_vertices, dtype=bool)
    in_set[ids] = True
    if source_vertex is not None:
        return in_set[source_vertex]
    from scipy.spatial import cKDTree

    dist, nearest = cKDTree(surface.vertices).query(tm_vertices)
    e = surface.edges
    reach = 1.5 * float(np.mean(np.linalg.norm(surface.vertices[e[:, 1]] - surface.vertices[e[:, 0]], axis=1)))
    return in_set[nearest] & (dist <= reach)


def mask_from_tetmesh(tm: TetMesh, rigid_vertices: np.ndarray, name: str, kind: str = "nasal",
                      airway_center=None, airway_axis=None, up=None,
                      material: CushionMaterial = CUSHION_SILICONE, plane_normal=None) -> MaskModel:
    """Label a tet mesh as cushion + rigid shell and wrap it as a MaskModel (defaults: module doc)."""
    rigid = np.asarray(rigid_vertices, dtype=bool)
    if not rigid.any():
        raise RegionError(f"{name}: the rigid region is empty (no vertex is rigid); the strap needs a shell to pull")
    if rigid.all():
        raise RegionError(f"{name}: the rigid region is the whole mask; no soft cushion is left")
    vertex_region = np.where(rigid, REGION_SHELL, REGION_CUSHION).astype(np.int32)
    tet_region = np.where(rigid[tm.tets].all(axis=1), REGION_SHELL, REGION_CUSHION).astype(np.int32)
    tm = TetMesh(tm.vertices, tm.tets, tet_region=tet_region, vertex_region=vertex_region, fixed=rigid, name=name)
    boundary = tm.boundary_triangles
    contact = boundary[(~rigid[boundary]).all(axis=1)]
    if len(contact) == 0:
        raise RegionError(f"{name}: every boundary triangle touches the rigid region; no skin-side surface is left")
    v = tm.vertices
    if airway_axis is None:
        axis = np.asarray(plane_normal, dtype=np.float64) if plane_normal is not None else \
            v[~rigid].mean(axis=0) - v[rigid].mean(axis=0)
        if np.linalg.norm(axis) < 1e-9:
            raise RegionError(f"{name}: cannot tell the approach axis (rigid and soft parts share a centroid); "
                              "pass airway_axis")
    else:
        axis = np.asarray(airway_axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    if up is None:
        up_v = np.array([0.0, 1.0, 0.0])
        if abs(up_v @ axis) > 0.95:
            up_v = np.array([0.0, 0.0, 1.0])
    else:
        up_v = np.asarray(up, dtype=np.float64)
    up_v = up_v - (up_v @ axis) * axis
    if np.linalg.norm(up_v) < 1e-9:
        raise ParameterError(f"{name}: up is parallel to the airway axis")
    up_v /= np.linalg.norm(up_v)
    center = v[np.unique(contact)].mean(axis=0) if airway_center is None else np.asarray(airway_center, float)
    return MaskModel(name=name, kind=kind, size=None, tetmesh=tm, contact_triangles=contact,
                     airway_center=center, airway_axis=axis, up=up_v, material=material)


def load_user_mask(path: str | os.PathLike | SurfaceMesh, units: str = "mm", rigid=None, *,
                   thickness: float | None = None, layers: int = 2, direction: str = "inward",
                   kind: str = "nasal", target_edge: float | None = None, airway_center=None,
                   airway_axis=None, up=None, material: CushionMaterial = CUSHION_SILICONE) -> MaskModel:
    """Load a mask surface and build its MaskModel (module doc).

    Parameters
    ----------
    path : mesh file (any format :func:`headsim.mesh.io.load_surface` reads) or a SurfaceMesh in m
    units : the file's length unit ("m", "cm", "mm"); ignored for a SurfaceMesh
    rigid : (k,) int vertex ids / (n,) bool of the surface, or a plane ``(point, normal)`` in the
        file's frame converted to m (vertices with ``(x - point) . normal < 0`` are rigid). Required.
    thickness : wall thickness, m, for an open surface (required there, refused for a closed one)
    layers, direction : extrusion of an open surface (:func:`extrude_shell`)
    kind : "nasal" or "oronasal" — which airway the mask is centred on by automatic placement
    target_edge : tet edge length for a closed body, m (mesher default when None)
    airway_center, airway_axis, up : mask frame (defaults in the module doc)
    material : CushionMaterial of the soft part

    Raises
    ------
    MeshError, RegionError, ParameterError, UnitsError
    """
    if kind not in ("nasal", "oronasal"):
        raise ParameterError(f"kind must be 'nasal' or 'oronasal', got {kind!r}")
    if rigid is None:
        raise RegionError("a user mask needs a rigid region: rigid=vertex ids or rigid=(point, normal)")
    if isinstance(path, SurfaceMesh):
        surface = path
    else:
        from headsim.mesh.io import load_surface

        surface = load_surface(path, units=parse_units(units), expect_head_sized=False)
    check_head_scale(surface.vertices, source=surface.name, plausible_range_m=MASK_EXTENT_RANGE_M, strict=True)
    name = os.path.basename(str(surface.name)) or "user-mask"
    plane_normal = None
    if isinstance(rigid, tuple) and len(rigid) == 2:
        plane_normal = rigid[1]
    if surface.is_closed:
        if thickness is not None:
            raise ParameterError(f"{surface.name}: a closed mask body needs no wall thickness (got {thickness} m); "
                                 "thickness is for open membrane surfaces")
        from headsim.mesh.tetra import tetrahedralize_surface

        tm = tetrahedralize_surface(surface, target_edge)
        rigid_mask = _rigid_mask(tm.vertices, rigid, surface, None)
    else:
        if thickness is None:
            raise MeshError(f"{surface.name}: the mask surface is open ({len(surface.boundary_loops)} boundary "
                            "loops); give its wall thickness to turn it into a solid layer, or close it")
        tm = extrude_shell(surface, thickness, layers=layers, direction=direction)
        source = np.tile(np.arange(surface.n_vertices), layers + 1)
        rigid_mask = _rigid_mask(tm.vertices, rigid, surface, source)
    return mask_from_tetmesh(tm, rigid_mask, name=name, kind=kind, airway_center=airway_center,
                             airway_axis=airway_axis, up=up, material=material, plane_normal=plane_normal)
