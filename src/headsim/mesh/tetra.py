"""Tetrahedralisation of closed surfaces (mask bodies, test spheres and boxes).

Two real meshers:

``"tetwild"`` (default): fTetWild through ``pytetwild`` (MPL-2.0, a required dependency). Robust to
    imperfect input and gives the best-shaped tets; its boundary lies within an envelope of
    ``epsilon x`` the bounding-box diagonal of the input (the surface is remeshed, its vertices are
    not kept). Slow: seconds for a 1k-triangle sphere, tens of seconds of CPU for 10k triangles.
``"gmsh"``: Gmsh's Delaunay mesher plus Netgen optimisation on the input triangles as a discrete
    boundary: keeps the surface exactly (its vertices are the first vertices of the result) and is
    several times faster. Gmsh is GPL-2+, so it is only an optional extra
    (``pip install 'headsim[gmsh]'``); it needs the system GL/X libraries.

Measured on the 2-core development machine (heavily shared; CPU seconds): 1,280-triangle sphere,
gmsh 0.4 s / min dihedral 24°, tetwild 1.2 s / 27°; 768-triangle box, gmsh 0.2 s / 16°, tetwild
6 s / 10–23° (fTetWild is not deterministic across runs); 10k-triangle non-convex closed surface,
gmsh 7 s / 13°, tetwild 23 s / 13°. Volume error against the input surface: gmsh 1e-15,
tetwild <= 1e-3 (its envelope). tetwild is the default because the default install must stay
permissively licensed; gmsh is the better choice where its licence is acceptable.

fTetWild writes a temporary file into the working directory, so it runs in a temporary one (under
a lock: the working directory is process-wide). Both return positively oriented tets
(:class:`~headsim.mesh.TetMesh` refuses anything else).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import threading

import numpy as np

from headsim.errors import HeadsimError, MeshError, ParameterError
from headsim.mesh.surface import SurfaceMesh
from headsim.mesh.tet import REGION_TISSUE, TetMesh
from headsim.mesh.validate import check_surface

METHODS = ("tetwild", "gmsh")
_LOCK = threading.Lock()  # both meshers use process-global state (working directory, gmsh session)


@contextlib.contextmanager
def _in_temp_dir():
    """Run inside a fresh temporary working directory (fTetWild writes files into the cwd)."""
    old = os.getcwd()
    with tempfile.TemporaryDirectory(prefix="headsim-tetra-") as tmp:
        os.chdir(tmp)
        try:
            yield tmp
        finally:
            os.chdir(old)


def _default_edge(surface: SurfaceMesh) -> float:
    """Mean surface edge length, m: tets about as large as the surface triangles."""
    e = surface.edges
    return float(np.linalg.norm(surface.vertices[e[:, 1]] - surface.vertices[e[:, 0]], axis=1).mean())


def _finish(vertices: np.ndarray, tets: np.ndarray, name: str) -> TetMesh:
    """Drop unused vertices, orient every tet positively, build the TetMesh."""
    tets = np.asarray(tets, dtype=np.int64)
    used = np.unique(tets)
    remap = -np.ones(len(vertices), dtype=np.int64)
    remap[used] = np.arange(len(used))
    v = np.asarray(vertices, dtype=np.float64)[used]
    t = remap[tets]
    a = v[t[:, 0]]
    vol = np.einsum("ij,ij->i", np.cross(v[t[:, 1]] - a, v[t[:, 2]] - a), v[t[:, 3]] - a)
    t[vol < 0] = t[vol < 0][:, [1, 0, 2, 3]]
    return TetMesh(v, t, tet_region=np.full(len(t), REGION_TISSUE, dtype=np.int32), name=name)


def _tetwild(surface: SurfaceMesh, edge: float | None, epsilon: float, stop_energy: float,
             optimize_iterations: int) -> tuple[np.ndarray, np.ndarray]:
    try:
        import pytetwild
    except ImportError as e:  # pragma: no cover - declared dependency
        raise HeadsimError("tetrahedralisation with fTetWild needs pytetwild and pyvista: "
                           "pip install pytetwild pyvista") from e
    with _LOCK, _in_temp_dir():
        v, t = pytetwild.tetrahedralize(
            np.array(surface.vertices, dtype=np.float64), np.array(surface.triangles, dtype=np.int32), edge_length_abs=edge,
            edge_length_fac=0.05, epsilon=epsilon,
            vtk_ordering=True, quiet=True, num_threads=0, optimize=optimize_iterations > 0,
            stop_energy=stop_energy, num_opt_iter=max(int(optimize_iterations), 1),
        )
    return np.asarray(v), np.asarray(t)


def _gmsh(surface: SurfaceMesh, edge: float) -> tuple[np.ndarray, np.ndarray]:
    try:
        import gmsh
    except (ImportError, OSError) as e:
        raise HeadsimError(
            "method='gmsh' needs the optional gmsh package (GPL-2+) and the system GL/X libraries: "
            f"pip install 'headsim[gmsh]' ({type(e).__name__}: {e})"
        ) from e
    with _LOCK, _in_temp_dir():
        gmsh.initialize(["-noenv"], readConfigFiles=False)
        try:
            gmsh.option.setNumber("General.Terminal", 0)
            gmsh.model.add("surface")
            tag = gmsh.model.addDiscreteEntity(2)
            n = surface.n_vertices
            gmsh.model.mesh.addNodes(2, tag, np.arange(1, n + 1), surface.vertices.ravel())
            gmsh.model.mesh.addElementsByType(tag, 2, [], (surface.triangles + 1).ravel())
            loop = gmsh.model.geo.addSurfaceLoop([tag])
            gmsh.model.geo.addVolume([loop])
            gmsh.model.geo.synchronize()
            gmsh.option.setNumber("Mesh.MeshSizeMax", edge)
            gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
            gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 1)
            gmsh.option.setNumber("Mesh.Optimize", 1)
            gmsh.option.setNumber("Mesh.OptimizeNetgen", 1)
            gmsh.model.mesh.generate(3)
            node_tags, coords, _ = gmsh.model.mesh.getNodes()
            _, elem_nodes = gmsh.model.mesh.getElementsByType(4)
        except Exception as e:
            raise MeshError(f"{surface.name}: gmsh could not tetrahedralise the surface: {e}") from None
        finally:
            gmsh.finalize()
    coords = np.asarray(coords).reshape(-1, 3)
    node_tags = np.asarray(node_tags, dtype=np.int64)
    index = np.zeros(node_tags.max() + 1, dtype=np.int64)
    index[node_tags] = np.arange(len(node_tags))
    # order vertices by gmsh tag, so the surface vertices (tags 1..n) come first with their ids
    order = np.argsort(node_tags)
    inv = np.empty_like(order)
    inv[order] = np.arange(len(order))
    v = coords[order]
    t = inv[index[np.asarray(elem_nodes, dtype=np.int64).reshape(-1, 4)]]
    return v, t


def tetrahedralize_surface(
    surface: SurfaceMesh,
    target_edge: float | None = None,
    *,
    method: str = "tetwild",
    epsilon: float = 1e-3,
    stop_energy: float = 10.0,
    optimize_iterations: int = 80,
) -> TetMesh:
    """Fill a closed surface with tetrahedra.

    Parameters
    ----------
    surface : closed, consistently oriented surface (validated here; outward normals).
    target_edge : m, wanted tet edge length. Default: tetwild, 1/20 of the bounding-box diagonal
        (fTetWild's default; the boundary still follows the input within the envelope, only the
        triangulation is coarser); gmsh, the mean surface edge length (its boundary keeps the input
        triangles).
    method : ``"tetwild"`` (default, fTetWild via pytetwild) or ``"gmsh"`` (optional GPL extra).
    epsilon : tetwild only: envelope half-width relative to the bounding-box diagonal; the result's
        boundary stays within it of the input surface.
    stop_energy, optimize_iterations : tetwild only: its quality optimisation stops when the AMIPS
        energy of every tet is below ``stop_energy`` or after this many passes (fTetWild defaults
        10 and 80; larger energy / fewer passes is faster, with worse tets).

    Returns
    -------
    TetMesh
        Positively oriented tets, ``tet_region`` REGION_TISSUE. For ``"gmsh"`` the first
        ``surface.n_vertices`` vertices are the surface's, in order.
    """
    if method not in METHODS:
        raise ParameterError(f"unknown tetrahedralisation method {method!r}; use one of {', '.join(METHODS)}")
    check_surface(surface)
    if not surface.is_closed:
        raise MeshError(
            f"{surface.name}: tetrahedralisation needs a closed surface "
            f"({len(surface.boundary_loops)} boundary loops); use build_tissue_layer for open faces"
        )
    if surface.signed_volume() <= 0:
        raise MeshError(f"{surface.name}: the surface's normals point inwards (negative volume); repair it")
    if target_edge is not None and (not np.isfinite(target_edge) or target_edge <= 0):
        raise ParameterError(f"target_edge must be a positive length in m, got {target_edge}")
    edge = None if target_edge is None else float(target_edge)
    if method == "tetwild":
        if not 0 < epsilon < 1:
            raise ParameterError(f"epsilon must be in (0, 1), got {epsilon}")
        v, t = _tetwild(surface, edge, epsilon, stop_energy, optimize_iterations)
    else:
        v, t = _gmsh(surface, _default_edge(surface) if edge is None else edge)
    if len(t) == 0:
        raise MeshError(f"{surface.name}: the mesher ({method}) produced no tetrahedra")
    return _finish(v, t, name=f"{surface.name}[{method}]")
