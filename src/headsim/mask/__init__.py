"""Mask fit: seal, leak paths, contact pressure and least sealing strap force (app layer).

Geometry half (this package): face landmarks from geometry, built-in parametric masks and user
mask files, automatic placement on a face, seal / leak-path analysis of a contact-pressure field,
and contact-pressure summaries. The fit itself (quasi-static FEM contact under a strap force) lives
in :mod:`headsim.solvers`.
"""

from headsim.mask.landmarks import LANDMARK_NAMES, Landmarks, find_landmarks, plane_section_points
from headsim.mask.masks import (
    CUSHION_SILICONE,
    SILICONE_MEMBRANE,
    CushionMaterial,
    MaskDesign,
    MaskModel,
    build_parametric_mask,
    effective_cushion_modulus,
    make_mask,
    mask_catalogue,
)
from headsim.mask.placement import Placement, airway_point, gaps_along, place_mask, skin_cushion_gap
from headsim.mask.pressure import (
    CAPILLARY_CLOSING_PA,
    CMH2O,
    MMHG,
    THERAPY_PRESSURE_PA,
    PressureSummary,
    contact_pressure,
    summarize_pressure,
    vertex_contact_pressure,
)
from headsim.mask.seal import LeakPath, SealResult, airway_vertices, analyse_seal, outer_boundary
from headsim.mask.user_mask import extrude_shell, load_user_mask, mask_from_tetmesh

__all__ = [
    "Landmarks", "find_landmarks", "LANDMARK_NAMES", "plane_section_points",
    "MaskModel", "MaskDesign", "CushionMaterial", "CUSHION_SILICONE", "SILICONE_MEMBRANE",
    "effective_cushion_modulus", "build_parametric_mask", "make_mask", "mask_catalogue",
    "load_user_mask", "extrude_shell", "mask_from_tetmesh",
    "Placement", "place_mask", "airway_point", "gaps_along", "skin_cushion_gap",
    "SealResult", "LeakPath", "analyse_seal", "airway_vertices", "outer_boundary",
    "PressureSummary", "contact_pressure", "vertex_contact_pressure", "summarize_pressure",
    "CAPILLARY_CLOSING_PA", "THERAPY_PRESSURE_PA", "MMHG", "CMH2O",
]
