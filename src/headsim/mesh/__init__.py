"""Meshes: surface and tetrahedral containers, geometry, units, I/O, validation and repair,
subdivision, primitives, the tissue layer of a face (Heinze §2.3) and closed-surface
tetrahedralisation."""

from headsim.mesh.io import LoadedSurface, load_surface, load_tetmesh, read_surface, save_surface, save_tetmesh
from headsim.mesh.primitives import box, icosphere
from headsim.mesh.quality import TetQuality, tet_quality
from headsim.mesh.subdivide import subdivide_loop, subdivide_midpoint
from headsim.mesh.surface import SurfaceMesh
from headsim.mesh.tet import REGION_BONE, REGION_CUSHION, REGION_SHELL, REGION_TISSUE, TetMesh
from headsim.mesh.tetra import tetrahedralize_surface
from headsim.mesh.tissue import TissueLayer, TissueOptions, build_tissue_layer, extrude_tissue_layer
from headsim.mesh.units import Units, UnitsWarning, check_head_scale, parse_units
from headsim.mesh.validate import (
    Defect,
    MeshDefectError,
    RepairReport,
    ValidationReport,
    check_surface,
    repair_surface,
    validate_surface,
)

__all__ = [
    "SurfaceMesh",
    "TetMesh",
    "Units",
    "UnitsWarning",
    "parse_units",
    "check_head_scale",
    "REGION_TISSUE",
    "REGION_BONE",
    "REGION_CUSHION",
    "REGION_SHELL",
    "load_surface",
    "read_surface",
    "LoadedSurface",
    "save_surface",
    "load_tetmesh",
    "save_tetmesh",
    "validate_surface",
    "check_surface",
    "repair_surface",
    "ValidationReport",
    "RepairReport",
    "Defect",
    "MeshDefectError",
    "subdivide_midpoint",
    "subdivide_loop",
    "icosphere",
    "box",
    "tet_quality",
    "TetQuality",
    "tetrahedralize_surface",
    "build_tissue_layer",
    "extrude_tissue_layer",
    "TissueLayer",
    "TissueOptions",
]
