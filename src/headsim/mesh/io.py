"""Reading and writing surface and tetrahedral meshes (through meshio).

Formats, chosen by the file suffix: Wavefront ``.obj``, ``.stl`` (binary written), ``.ply`` (binary
written), Gmsh ``.msh`` (binary 4.1 written: meshio writes ASCII ``.msh`` cell data incorrectly under
NumPy 2), Medit ``.mesh``, VTK ``.vtk`` and ``.vtu`` (also ``.off`` for surfaces).

The file's length unit is stated by the caller (``units="mm"`` ...); coordinates are converted to
metres on reading and from metres on writing. Loaders validate what they read and raise
:class:`~headsim.errors.MeshError` naming the file and the defect; a file that does not exist, has an
unknown suffix or holds no triangles (tetrahedra) is refused the same way.

Tet meshes keep their labels: ``tet_region`` (cell data), ``vertex_region`` and ``fixed`` (point
data) round-trip through ``.vtu``, ``.vtk`` and ``.msh``; Medit ``.mesh`` keeps ``tet_region`` and
``vertex_region`` (as its ``ref`` numbers) but has no place for ``fixed``.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from headsim._atomic import atomic_output_file
from headsim.errors import MeshError
from headsim.mesh.surface import SurfaceMesh
from headsim.mesh.tet import TetMesh
from headsim.mesh.units import Units, check_head_scale, parse_units
from headsim.mesh.validate import RepairReport, ValidationReport, repair_surface, validate_surface

log = logging.getLogger(__name__)

#: suffix -> meshio format name
SURFACE_FORMATS = {
    ".obj": "obj", ".stl": "stl", ".ply": "ply", ".msh": "gmsh", ".mesh": "medit",
    ".vtk": "vtk", ".vtu": "vtu", ".off": "off",
}
TET_FORMATS = {".msh": "gmsh", ".mesh": "medit", ".vtk": "vtk", ".vtu": "vtu"}


def _format_for(path: Path, table: dict[str, str], what: str) -> str:
    fmt = table.get(path.suffix.lower())
    if fmt is None:
        raise MeshError(
            f"{path}: unknown {what} format {path.suffix or '(no suffix)'!r}; "
            f"supported: {', '.join(sorted(table))}"
        )
    return fmt


def _read_meshio(path: Path, fmt: str):
    import meshio

    if not path.exists():
        raise MeshError(f"{path}: file not found")
    if path.is_dir():
        raise MeshError(f"{path}: is a folder, not a mesh file")
    chatter = io.StringIO()
    try:
        with warnings.catch_warnings(), contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
            warnings.simplefilter("ignore")
            return meshio.read(path, file_format=fmt)
    except SystemExit:  # meshio calls sys.exit() on some unreadable files
        detail = " ".join(chatter.getvalue().split())
        raise MeshError(f"{path}: cannot read as {fmt}: {detail or 'unreadable file'}") from None
    except Exception as e:  # meshio raises many types (ReadError, ValueError, IndexError, ...)
        raise MeshError(f"{path}: cannot read as {fmt}: {type(e).__name__}: {e}".rstrip(": ")) from None


def _triangles_of(mesh, path: Path) -> np.ndarray:
    """All triangle cells, with quads and polygons split into fans."""
    tris = []
    for block in mesh.cells:
        data = np.asarray(block.data)
        if block.type == "triangle":
            tris.append(data)
        elif block.type in ("quad",) or block.type.startswith("polygon"):
            if data.ndim != 2 or data.shape[1] < 3:
                continue
            k = data.shape[1]
            tris.extend(data[:, [0, j, j + 1]] for j in range(1, k - 1))
    if not tris:
        types = ", ".join(sorted({b.type for b in mesh.cells})) or "none"
        raise MeshError(f"{path}: no triangles in the file (cell types: {types})")
    return np.concatenate(tris).astype(np.int64)


@dataclass(frozen=True)
class LoadedSurface:
    """A surface with what loading found and changed.

    mesh : the surface, in metres
    validation : report on the mesh as returned (after repairs, if any)
    repair : what ``repair=True`` changed (None when repairs were not asked for)
    original_validation : report on the mesh as read, before repairs
    extent_m : largest bounding-box side, m
    """

    mesh: SurfaceMesh
    validation: ValidationReport
    repair: RepairReport | None
    original_validation: ValidationReport
    extent_m: float


def read_surface(
    path: str | os.PathLike,
    units: str | Units = "m",
    *,
    repair: bool = False,
    validate: bool = True,
    expect_head_sized: bool = True,
) -> LoadedSurface:
    """Read a triangle surface and report on it (see :func:`load_surface`)."""
    path = Path(path)
    unit = parse_units(units)
    fmt = _format_for(path, SURFACE_FORMATS, "surface mesh")
    raw = _read_meshio(path, fmt)
    tri = _triangles_of(raw, path)
    pts = np.asarray(raw.points, dtype=np.float64)
    if pts.ndim == 2 and pts.shape[1] == 2:
        pts = np.concatenate([pts, np.zeros((len(pts), 1))], axis=1)
    mesh = SurfaceMesh(pts * unit.to_metres, tri, name=str(path))
    extent = float(np.max(mesh.extent))
    if expect_head_sized:
        check_head_scale(mesh.vertices, source=str(path))
    original = validate_surface(mesh)
    report = original
    repair_report = None
    if repair:
        mesh, repair_report = repair_surface(mesh)
        report = validate_surface(mesh)
        if repair_report.changed:
            log.info("%s: %s", path, repair_report.summary())
    if validate:
        report.raise_if_invalid()
    return LoadedSurface(mesh, report, repair_report, original, extent)


def load_surface(
    path: str | os.PathLike,
    units: str | Units = "m",
    repair: bool = False,
    *,
    validate: bool = True,
    expect_head_sized: bool = True,
) -> SurfaceMesh:
    """Load a triangle surface mesh, convert it to metres and validate it.

    Parameters
    ----------
    path : .obj, .stl, .ply, .msh, .mesh, .vtk, .vtu or .off file. Quads and polygons are split into
        triangles; other cells (lines, points, tets) are ignored.
    units : length unit of the file, ``"m"``, ``"cm"`` or ``"mm"``.
    repair : apply the safe repairs of :func:`headsim.mesh.validate.repair_surface` (use
        :func:`read_surface` to see what they changed).
    validate : raise :class:`~headsim.mesh.validate.MeshDefectError` on defects (default).
    expect_head_sized : warn (:class:`~headsim.mesh.units.UnitsWarning`) when the model's extent in
        metres is implausible for a face or head, which usually means a wrong ``units``.

    Returns
    -------
    SurfaceMesh
        vertices (n, 3) float64, m; ``name`` is the path.
    """
    return read_surface(path, units, repair=repair, validate=validate, expect_head_sized=expect_head_sized).mesh


def load_tetmesh(
    path: str | os.PathLike,
    units: str | Units = "m",
    *,
    expect_head_sized: bool = False,
) -> TetMesh:
    """Load a tetrahedral mesh (.vtu, .vtk, .msh, .mesh), in metres, with its labels.

    ``tet_region`` comes from cell data ``tet_region`` (else Gmsh physical tags minus one, or Medit
    refs), ``vertex_region`` and ``fixed`` from point data of those names (Medit: point refs).
    Inverted or degenerate tets are refused (:class:`~headsim.errors.MeshError`).
    """
    path = Path(path)
    unit = parse_units(units)
    fmt = _format_for(path, TET_FORMATS, "tet mesh")
    raw = _read_meshio(path, fmt)
    blocks = [i for i, b in enumerate(raw.cells) if b.type == "tetra"]
    if not blocks:
        types = ", ".join(sorted({b.type for b in raw.cells})) or "none"
        raise MeshError(f"{path}: no tetrahedra in the file (cell types: {types})")
    tets = np.concatenate([np.asarray(raw.cells[i].data) for i in blocks]).astype(np.int64)

    def cell_values(name):
        if name not in raw.cell_data:
            return None
        return np.concatenate([np.asarray(raw.cell_data[name][i]) for i in blocks])

    tet_region = cell_values("tet_region")
    if tet_region is None and (phys := cell_values("gmsh:physical")) is not None:
        tet_region = phys - 1
    if tet_region is None:
        tet_region = cell_values("medit:ref")
    vertex_region = raw.point_data.get("vertex_region", raw.point_data.get("medit:ref"))
    fixed = raw.point_data.get("fixed")

    def as_int(a):
        if a is None:
            return None
        a = np.asarray(a).reshape(len(a), -1)[:, 0]
        if not np.all(np.isfinite(a)) or not np.all(a == np.round(a)):
            raise MeshError(f"{path}: region labels must be integers")
        return a.astype(np.int32)

    pts = np.asarray(raw.points, dtype=np.float64) * unit.to_metres
    fixed_arr = None if fixed is None else np.asarray(fixed).reshape(len(fixed), -1)[:, 0] != 0
    mesh = TetMesh(pts, tets, tet_region=as_int(tet_region), vertex_region=as_int(vertex_region),
                   fixed=fixed_arr, name=str(path))
    if expect_head_sized:
        check_head_scale(mesh.vertices, source=str(path))
    return mesh


def _write_meshio(mesh, path: Path, fmt: str) -> None:
    kwargs = {"binary": True} if fmt in ("gmsh", "stl", "ply") else {}
    with atomic_output_file(path) as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            mesh.write(tmp, file_format=fmt, **kwargs)
        except Exception as e:
            raise MeshError(f"{path}: cannot write as {fmt}: {type(e).__name__}: {e}") from None


def save_surface(mesh: SurfaceMesh, path: str | os.PathLike, units: str | Units = "m") -> Path:
    """Write ``mesh`` to ``path`` (format from the suffix), coordinates in ``units``.

    The file appears only when writing succeeded (temporary file, then rename).
    """
    import meshio

    path = Path(path)
    fmt = _format_for(path, SURFACE_FORMATS, "surface mesh")
    scale = 1.0 / parse_units(units).to_metres
    cell_data = {}
    if fmt == "gmsh":
        cell_data = {"gmsh:physical": [np.ones(mesh.n_triangles, dtype=np.int32)],
                     "gmsh:geometrical": [np.ones(mesh.n_triangles, dtype=np.int32)]}
    out = meshio.Mesh(mesh.vertices * scale, [("triangle", mesh.triangles.astype(np.int32))], cell_data=cell_data)
    _write_meshio(out, path, fmt)
    return path


def save_tetmesh(mesh: TetMesh, path: str | os.PathLike, units: str | Units = "m") -> Path:
    """Write a tet mesh with its labels to ``.vtu``, ``.vtk``, ``.msh`` (binary) or ``.mesh``.

    ``tet_region`` is written as cell data, ``vertex_region`` and ``fixed`` (as 0/1 int32) as point
    data; Medit ``.mesh`` keeps the regions as refs and drops ``fixed``.
    """
    import meshio

    path = Path(path)
    fmt = _format_for(path, TET_FORMATS, "tet mesh")
    scale = 1.0 / parse_units(units).to_metres
    m = mesh.n_tets
    region = mesh.tet_region if mesh.tet_region is not None else np.zeros(m, dtype=np.int32)
    cell_data: dict = {}
    point_data: dict = {}
    if fmt == "medit":
        cell_data["medit:ref"] = [region.astype(np.int64)]
        if mesh.vertex_region is not None:
            point_data["medit:ref"] = mesh.vertex_region.astype(np.int64)
    else:
        if mesh.tet_region is not None:
            cell_data["tet_region"] = [mesh.tet_region.astype(np.int32)]
        if mesh.vertex_region is not None:
            point_data["vertex_region"] = mesh.vertex_region.astype(np.int32)
        if mesh.fixed is not None:
            point_data["fixed"] = mesh.fixed.astype(np.int32)
        if fmt == "gmsh":
            cell_data["gmsh:physical"] = [(region + 1).astype(np.int32)]
            cell_data["gmsh:geometrical"] = [np.ones(m, dtype=np.int32)]
    out = meshio.Mesh(mesh.vertices * scale, [("tetra", mesh.tets)], cell_data=cell_data, point_data=point_data)
    _write_meshio(out, path, fmt)
    return path
