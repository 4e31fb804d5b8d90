"""Meshes: surface and tetrahedral containers, geometry, units (I/O, validation and
tetrahedralisation live in sibling modules)."""

from headsim.mesh.surface import SurfaceMesh
from headsim.mesh.tet import REGION_BONE, REGION_CUSHION, REGION_SHELL, REGION_TISSUE, TetMesh
from headsim.mesh.units import Units, check_head_scale, parse_units

__all__ = [
    "SurfaceMesh",
    "TetMesh",
    "Units",
    "parse_units",
    "check_head_scale",
    "REGION_TISSUE",
    "REGION_BONE",
    "REGION_CUSHION",
    "REGION_SHELL",
]
