"""Hairstyle reconstruction from coarse surface data (Sobottka 2008 ch. 5).

scalp + hair-volume surface -> unit-disk parametrisation -> roots from density/direction/length maps ->
pre-guides (rising tip force, depth schedule) -> main guides (6-D tip wrench, L-BFGS-B over F1..F4 with the
binary or continuous density model) -> cut at the first exit -> strands -> fibres (NPZ + VTK).
"""

from headsim.hair.reconstruct.density import DENSITY_MODELS, DensityGrid, coefficient_of_variation, occupancy_counts
from headsim.hair.reconstruct.growth import GuideOptions, PreGuides, grow_preguides, optimise_guide
from headsim.hair.reconstruct.inputs import (
    STYLES,
    StyleInputs,
    boundary_fields,
    bundled_inputs,
    bundled_scalp,
    hair_volume,
    load_inputs,
)
from headsim.hair.reconstruct.maps import Roots, ScalpMap, TextureMap, default_maps, farthest_point_order
from headsim.hair.reconstruct.pipeline import Hairstyle, StyleOptions, reconstruct

__all__ = [
    "DENSITY_MODELS", "DensityGrid", "coefficient_of_variation", "occupancy_counts",
    "GuideOptions", "PreGuides", "grow_preguides", "optimise_guide",
    "STYLES", "StyleInputs", "boundary_fields", "bundled_inputs", "bundled_scalp", "hair_volume", "load_inputs",
    "Roots", "ScalpMap", "TextureMap", "default_maps", "farthest_point_order",
    "Hairstyle", "StyleOptions", "reconstruct",
]
