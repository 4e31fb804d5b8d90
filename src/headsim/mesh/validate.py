"""Validation and safe repair of triangle surface meshes.

:func:`validate_surface` inspects a :class:`~headsim.mesh.SurfaceMesh` and returns a
:class:`ValidationReport` listing every defect found (degenerate or duplicate triangles, duplicate
vertices, non-manifold edges and vertices, inconsistent winding, non-orientable components) with
counts and the first offending ids. :func:`check_surface` raises :class:`MeshDefectError` (a
:class:`~headsim.errors.MeshError`) naming the mesh's source and its defects. The basic defects
(empty mesh, NaN/inf coordinates, out-of-range indices) are refused earlier, when the
``SurfaceMesh`` is built.

:func:`repair_surface` applies only *safe* repairs — merge duplicate vertices within a tolerance,
drop degenerate and duplicate triangles and unused vertices, make the winding consistent per
connected component (outward for closed components) — and returns a :class:`RepairReport` saying
what changed. Non-manifold edges and vertices are not repaired (no safe automatic fix exists).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from headsim.errors import MeshError
from headsim.mesh import geometry
from headsim.mesh.surface import SurfaceMesh

#: Default tolerances, relative to the bounding-box diagonal of the mesh.
DUPLICATE_VERTEX_RTOL = 1e-9
DEGENERATE_AREA_RTOL = 1e-14  # area <= rtol * diagonal^2 counts as zero area

#: Defect kinds that :func:`repair_surface` can fix.
REPAIRABLE = frozenset(
    {"degenerate_triangles", "duplicate_triangles", "duplicate_vertices", "inconsistent_winding",
     "unreferenced_vertices", "inward_orientation"}
)


class MeshDefectError(MeshError):
    """A mesh failed validation; ``report`` holds the :class:`ValidationReport`."""

    def __init__(self, message: str, report: "ValidationReport"):
        super().__init__(message)
        self.report = report


@dataclass(frozen=True)
class Defect:
    """One class of defect found in a mesh.

    kind : machine-readable name (``"degenerate_triangles"``, ``"non_manifold_edges"``, ...)
    count : number of offending items (triangles, vertices or edges, as ``message`` says)
    message : one human-readable phrase, e.g. ``"3 degenerate (zero-area) triangles (first: 4, 9, 17)"``
    examples : the first few offending ids (triangle, vertex or edge-vertex ids)
    error : True for defects that make the mesh unusable; False for notes (unused vertices)
    """

    kind: str
    count: int
    message: str
    examples: tuple = ()
    error: bool = True

    @property
    def repairable(self) -> bool:
        return self.kind in REPAIRABLE


@dataclass(frozen=True)
class ValidationReport:
    """Result of :func:`validate_surface`.

    source : the mesh's name (file path)
    defects : every defect found, errors and notes
    n_components : connected components (by shared edges)
    n_boundary_loops : boundary loops (0 for a closed surface)
    is_closed : every edge has exactly two triangles
    """

    source: str
    n_vertices: int
    n_triangles: int
    defects: tuple[Defect, ...]
    n_components: int
    n_boundary_loops: int
    is_closed: bool

    @property
    def errors(self) -> tuple[Defect, ...]:
        return tuple(d for d in self.defects if d.error)

    @property
    def notes(self) -> tuple[Defect, ...]:
        return tuple(d for d in self.defects if not d.error)

    @property
    def ok(self) -> bool:
        """True when no defect is an error."""
        return not self.errors

    @property
    def kinds(self) -> set[str]:
        return {d.kind for d in self.defects}

    def summary(self) -> str:
        """One line: ``"ok"`` or the defects separated by ``"; "``."""
        if not self.defects:
            return "ok"
        return "; ".join(d.message for d in self.defects)

    def raise_if_invalid(self) -> None:
        """Raise :class:`MeshDefectError` naming the source and every error-level defect."""
        if self.ok:
            return
        errors = self.errors
        msg = f"{self.source}: invalid mesh: " + "; ".join(d.message for d in errors)
        if all(d.repairable for d in errors):
            msg += " (repairable: load with repair=True / --repair)"
        elif any(d.repairable for d in errors):
            msg += " (--repair fixes some of these; non-manifold geometry must be fixed in a mesh editor)"
        else:
            msg += " (fix it in a mesh editor; no safe automatic repair exists)"
        raise MeshDefectError(msg, self)


@dataclass(frozen=True)
class RepairReport:
    """What :func:`repair_surface` changed.

    vertex_map : (n_old,) int64, new id of each old vertex, -1 where the vertex was dropped
    triangle_map : (m_new,) int64, old id of each kept triangle
    """

    merged_vertices: int = 0
    dropped_degenerate_triangles: int = 0
    dropped_duplicate_triangles: int = 0
    dropped_unreferenced_vertices: int = 0
    flipped_triangles: int = 0
    reoriented_components: int = 0
    vertex_map: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64), repr=False)
    triangle_map: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64), repr=False)

    @property
    def changed(self) -> bool:
        return bool(
            self.merged_vertices or self.dropped_degenerate_triangles or self.dropped_duplicate_triangles
            or self.dropped_unreferenced_vertices or self.flipped_triangles
        )

    def summary(self) -> str:
        if not self.changed:
            return "no repair needed"
        parts = []
        for value, text in (
            (self.merged_vertices, "merged {} duplicate vertices"),
            (self.dropped_degenerate_triangles, "dropped {} degenerate triangles"),
            (self.dropped_duplicate_triangles, "dropped {} duplicate triangles"),
            (self.dropped_unreferenced_vertices, "dropped {} unreferenced vertices"),
            (self.flipped_triangles, "flipped {} triangles"),
        ):
            if value:
                parts.append(text.format(value))
        text = ", ".join(parts)
        if self.reoriented_components:
            k = self.reoriented_components
            text += f" ({k} component{'s' if k != 1 else ''} re-oriented)"
        return text


# ----------------------------------------------------------------------------------------------
# detection primitives (array functions)
# ----------------------------------------------------------------------------------------------
def _diagonal(vertices: np.ndarray) -> float:
    d = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    return d if d > 0 else 1.0


def degenerate_triangles(vertices: np.ndarray, triangles: np.ndarray, area_tol: float | None = None) -> np.ndarray:
    """(k,) int64 ids of triangles with a repeated vertex or an area <= ``area_tol`` (m^2).

    ``area_tol`` defaults to ``DEGENERATE_AREA_RTOL * diagonal**2``.
    """
    if area_tol is None:
        area_tol = DEGENERATE_AREA_RTOL * _diagonal(vertices) ** 2
    t = triangles
    repeated = (t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 0] == t[:, 2])
    small = geometry.triangle_areas(vertices, t) <= area_tol
    return np.flatnonzero(repeated | small)


def duplicate_triangles(triangles: np.ndarray) -> np.ndarray:
    """(k,) int64 ids of triangles whose vertex set repeats an earlier triangle's (either winding)."""
    key = np.sort(triangles, axis=1)
    _, first = np.unique(key, axis=0, return_index=True)
    dup = np.ones(len(triangles), dtype=bool)
    dup[first] = False
    return np.flatnonzero(dup)


def duplicate_vertex_groups(vertices: np.ndarray, tol: float) -> np.ndarray:
    """(n,) int64 representative (smallest id) of each vertex's cluster of points within ``tol`` (m).

    Clusters are the connected components of the "closer than ``tol``" graph.
    """
    n = len(vertices)
    if tol <= 0:
        _, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
        return first[inverse.ravel()].astype(np.int64)
    pairs = cKDTree(vertices).query_pairs(tol, output_type="ndarray")
    if len(pairs) == 0:
        return np.arange(n, dtype=np.int64)
    g = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(g, directed=False)
    rep = np.full(labels.max() + 1, n, dtype=np.int64)
    np.minimum.at(rep, labels, np.arange(n))
    return rep[labels]


def _half_edge_keys(triangles: np.ndarray):
    """Half-edges (3m, 2) in face order, their undirected edge id (3m,), edges (e, 2), counts (e,)."""
    t = triangles
    half = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])  # half-edge h belongs to face h % m
    key = np.sort(half, axis=1)
    base = int(t.max()) + 1
    codes, inverse, counts = np.unique(key[:, 0] * base + key[:, 1], return_inverse=True, return_counts=True)
    edges = np.stack([codes // base, codes % base], axis=1)
    return half, inverse.ravel(), edges, counts


def _face_pairs(triangles: np.ndarray):
    """Pairs of faces sharing a manifold edge (exactly 2 faces): f1, f2 (p,), same_direction (p,) bool,
    and the shared edge's vertices (p, 2)."""
    m = len(triangles)
    half, eid, edges, counts = _half_edge_keys(triangles)
    manifold = counts[eid] == 2
    h = np.flatnonzero(manifold)
    order = h[np.argsort(eid[h], kind="stable")]
    h1, h2 = order[0::2], order[1::2]
    same = half[h1, 0] == half[h2, 0]
    return h1 % m, h2 % m, same, half[h1]


def vertex_fan_counts(n_vertices: int, triangles: np.ndarray) -> np.ndarray:
    """(n,) int64 number of separate triangle fans around each vertex (1 for a manifold vertex,
    0 for an unused vertex, > 1 for a non-manifold "bow-tie" vertex).

    Corners (face, vertex) are joined when their faces share an edge through the vertex.
    """
    m = len(triangles)
    corner_vertex = triangles.T.ravel()  # corner c = k * m + f  ->  vertex triangles[f, k]
    f1, f2, _, ev = _face_pairs(triangles)
    # corner id of vertex v in face f
    def corner(f, v):
        k = np.argmax(triangles[f] == v[:, None], axis=1)
        return k * m + f

    rows, cols = [], []
    for j in range(2):
        v = ev[:, j]
        rows.append(corner(f1, v))
        cols.append(corner(f2, v))
    rows = np.concatenate(rows)
    cols = np.concatenate(cols)
    g = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(3 * m, 3 * m))
    _, labels = connected_components(g, directed=False)
    pairs = np.unique(np.stack([corner_vertex, labels], axis=1), axis=0)
    return np.bincount(pairs[:, 0], minlength=n_vertices).astype(np.int64)


def orientation_flips(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Make the winding consistent: which faces to flip, component labels, orientability.

    Faces are joined across manifold edges (exactly two faces). Within each component the first
    face keeps its winding and the others are flipped where needed.

    Returns
    -------
    flip : (m,) bool, faces to flip for a consistent winding
    component : (m,) int64 component label of each face
    orientable : (c,) bool per component (False for a Möbius-like component)
    """
    m = len(triangles)
    f1, f2, same, _ = _face_pairs(triangles)
    # doubled graph: node (f, s) = f + s * m; a same-direction pair needs opposite states
    r = np.concatenate([f1, f1 + m])
    c = np.concatenate([np.where(same, f2 + m, f2), np.where(same, f2, f2 + m)])
    g2 = sp.coo_matrix((np.ones(len(r)), (r, c)), shape=(2 * m, 2 * m))
    _, lab2 = connected_components(g2, directed=False)
    g1 = sp.coo_matrix((np.ones(len(f1)), (f1, f2)), shape=(m, m))
    n_comp, comp = connected_components(g1, directed=False)
    root = np.full(n_comp, m, dtype=np.int64)
    np.minimum.at(root, comp, np.arange(m))
    flip = lab2[:m] != lab2[root[comp]]
    bad = lab2[:m] == lab2[m:]
    orientable = np.ones(n_comp, dtype=bool)
    orientable[comp[bad]] = False
    flip[bad] = False
    return flip, comp.astype(np.int64), orientable


def _first(ids, k: int = 5) -> str:
    ids = list(ids[:k])
    return ", ".join(str(int(i)) if np.ndim(i) == 0 else "-".join(str(int(j)) for j in i) for i in ids)


# ----------------------------------------------------------------------------------------------
# validation
# ----------------------------------------------------------------------------------------------
def validate_surface(
    mesh: SurfaceMesh,
    *,
    duplicate_tolerance: float | None = None,
    area_tolerance: float | None = None,
) -> ValidationReport:
    """Inspect ``mesh`` for defects; never raises for a defect (see :func:`check_surface`).

    Parameters
    ----------
    duplicate_tolerance : m; vertices closer than this count as duplicates.
        Default ``1e-9 x`` the bounding-box diagonal.
    area_tolerance : m^2; triangles with at most this area count as degenerate.
        Default ``1e-14 x`` the squared diagonal.
    """
    v, t = mesh.vertices, mesh.triangles
    diag = _diagonal(v)
    if duplicate_tolerance is None:
        duplicate_tolerance = DUPLICATE_VERTEX_RTOL * diag
    defects: list[Defect] = []

    deg = degenerate_triangles(v, t, area_tolerance)
    if len(deg):
        defects.append(Defect("degenerate_triangles", len(deg),
                              f"{len(deg)} degenerate (zero-area) triangles (first: {_first(deg)})", tuple(deg[:5])))
    dup_t = duplicate_triangles(t)
    if len(dup_t):
        defects.append(Defect("duplicate_triangles", len(dup_t),
                              f"{len(dup_t)} duplicate triangles (first: {_first(dup_t)})", tuple(dup_t[:5])))
    used = np.zeros(len(v), dtype=bool)
    used[t.ravel()] = True
    rep = duplicate_vertex_groups(v, duplicate_tolerance)
    dup_v = np.flatnonzero(rep != np.arange(len(v)))
    if len(dup_v):
        defects.append(Defect("duplicate_vertices", len(dup_v),
                              f"{len(dup_v)} duplicate vertices within {duplicate_tolerance:.3g} m "
                              f"(first: {_first(dup_v)})", tuple(dup_v[:5])))
    unused = np.flatnonzero(~used)
    if len(unused):
        defects.append(Defect("unreferenced_vertices", len(unused),
                              f"{len(unused)} vertices used by no triangle (first: {_first(unused)})",
                              tuple(unused[:5]), error=False))

    # topology is judged on the proper triangles only, so one defect is not reported three times
    proper = np.ones(len(t), dtype=bool)
    proper[deg] = False
    proper[dup_t] = False
    t = t[proper]
    if len(t) == 0:
        return ValidationReport(source=mesh.name, n_vertices=mesh.n_vertices, n_triangles=mesh.n_triangles,
                                defects=tuple(defects), n_components=0, n_boundary_loops=0, is_closed=False)
    edges, counts = geometry.unique_edges(t)
    nm = np.flatnonzero(counts > 2)
    if len(nm):
        defects.append(Defect("non_manifold_edges", len(nm),
                              f"{len(nm)} non-manifold edges shared by more than 2 triangles "
                              f"(first: {_first(edges[nm])})", tuple(map(tuple, edges[nm[:5]].tolist()))))
    fans = vertex_fan_counts(len(v), t)
    nmv = np.flatnonzero(fans > 1)
    if len(nmv):
        defects.append(Defect("non_manifold_vertices", len(nmv),
                              f"{len(nmv)} non-manifold vertices joining separate triangle fans "
                              f"(first: {_first(nmv)})", tuple(nmv[:5])))

    f1, f2, same, ev = _face_pairs(t)
    flip, comp, orientable = orientation_flips(t)
    n_comp = len(orientable)
    if same.any():
        bad = ev[same]
        defects.append(Defect("inconsistent_winding", int(same.sum()),
                              f"inconsistent winding: {int(same.sum())} edges where neighbouring triangles run the "
                              f"same way ({int(min(flip.sum(), (~flip).sum()))} triangles would need flipping; "
                              f"first edges: {_first(bad)})", tuple(map(tuple, bad[:5].tolist()))))
    if not orientable.all():
        k = int((~orientable).sum())
        defects.append(Defect("non_orientable", k, f"{k} non-orientable (Möbius-like) components"))

    closed = bool(np.all(counts == 2))
    if closed and orientable.all() and not same.any():
        # closed, consistent components must face outwards
        vols = np.bincount(comp, weights=_face_volume_terms(v, t), minlength=n_comp)
        inward = np.flatnonzero(vols < 0)
        if len(inward):
            defects.append(Defect("inward_orientation", len(inward),
                                  f"{len(inward)} closed components have inward-pointing normals "
                                  f"(negative volume)", tuple(inward[:5])))
    loops = geometry.boundary_loops(t) if not len(nm) else []
    return ValidationReport(
        source=mesh.name, n_vertices=mesh.n_vertices, n_triangles=mesh.n_triangles, defects=tuple(defects),
        n_components=n_comp, n_boundary_loops=len(loops), is_closed=closed,
    )


def _face_volume_terms(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    return np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0


def check_surface(mesh: SurfaceMesh, **kwargs) -> ValidationReport:
    """Validate ``mesh`` and raise :class:`MeshDefectError` if it has error-level defects.

    Returns the report when the mesh is usable (notes such as unused vertices allowed).
    """
    report = validate_surface(mesh, **kwargs)
    report.raise_if_invalid()
    return report


# ----------------------------------------------------------------------------------------------
# repair
# ----------------------------------------------------------------------------------------------
def repair_surface(
    mesh: SurfaceMesh,
    *,
    duplicate_tolerance: float | None = None,
    area_tolerance: float | None = None,
) -> tuple[SurfaceMesh, RepairReport]:
    """Apply the safe repairs and say what changed.

    In order: merge vertices closer than ``duplicate_tolerance`` (m; default ``1e-9 x`` diagonal;
    the merged vertex keeps the smallest id's position), drop degenerate triangles, drop duplicate
    triangles (same vertex set), drop unused vertices, then flip triangles so the winding is
    consistent within each connected component; closed components are turned to face outwards
    (positive volume), open components keep the winding of the majority of their triangles.

    Returns
    -------
    SurfaceMesh, RepairReport
    """
    v, t = mesh.vertices, mesh.triangles
    n = len(v)
    diag = _diagonal(v)
    if duplicate_tolerance is None:
        duplicate_tolerance = DUPLICATE_VERTEX_RTOL * diag
    if area_tolerance is None:
        area_tolerance = DEGENERATE_AREA_RTOL * diag**2

    rep = duplicate_vertex_groups(v, duplicate_tolerance)
    merged = int((rep != np.arange(n)).sum())
    t = rep[t]
    tri_ids = np.arange(len(t))

    deg = degenerate_triangles(v, t, area_tolerance)
    keep = np.ones(len(t), dtype=bool)
    keep[deg] = False
    t, tri_ids = t[keep], tri_ids[keep]
    dup = duplicate_triangles(t) if len(t) else np.zeros(0, dtype=np.int64)
    keep = np.ones(len(t), dtype=bool)
    keep[dup] = False
    t, tri_ids = t[keep], tri_ids[keep]
    if len(t) == 0:
        raise MeshError(f"{mesh.name}: nothing left after dropping degenerate/duplicate triangles")

    used = np.unique(t)
    vertex_map = -np.ones(n, dtype=np.int64)
    vertex_map[used] = np.arange(len(used))
    dropped_unused = int(n - merged - len(used))
    # merged-away vertices map to their representative's new id
    vertex_map = vertex_map[rep]
    new_v = v[used]
    t = vertex_map[t]

    flip, comp, orientable = orientation_flips(t)
    n_comp = len(orientable)
    # orient each component: closed -> positive volume; open -> keep the majority winding
    t_cons = np.where(flip[:, None], t[:, ::-1], t)
    half, eid, edges, counts = _half_edge_keys(t_cons)
    m = len(t_cons)
    boundary_faces = np.unique(np.flatnonzero(counts[eid] != 2) % m)
    comp_open = np.zeros(n_comp, dtype=bool)
    comp_open[comp[boundary_faces]] = True
    vols = np.bincount(comp, weights=_face_volume_terms(new_v, t_cons), minlength=n_comp)
    flips_per_comp = np.bincount(comp, weights=flip.astype(float), minlength=n_comp)
    faces_per_comp = np.bincount(comp, minlength=n_comp)
    invert = np.where(comp_open, flips_per_comp > faces_per_comp / 2.0, vols < 0)
    invert &= orientable
    final_flip = flip ^ invert[comp]
    t = np.where(final_flip[:, None], t[:, ::-1], t)
    reoriented = int(np.unique(comp[final_flip]).size)

    out = SurfaceMesh(new_v, t, name=mesh.name)
    report = RepairReport(
        merged_vertices=merged,
        dropped_degenerate_triangles=len(deg),
        dropped_duplicate_triangles=len(dup),
        dropped_unreferenced_vertices=dropped_unused,
        flipped_triangles=int(final_flip.sum()),
        reoriented_components=reoriented,
        vertex_map=vertex_map,
        triangle_map=tri_ids,
    )
    return out, report
