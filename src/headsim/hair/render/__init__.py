"""Physically based hair rendering (Sobottka 2008 ch. 6): Marschner far field with the seed's
corrections, near field, and a Numba path tracer for fibre assemblies with multiple scattering."""

from headsim.hair.render.scattering import (
    PRESETS,
    FurnaceResult,
    MarschnerParams,
    far_field_lobes,
    goniometric_curve,
    near_field_lobes,
    scattering,
    sigma_a_from_melanin,
    white_furnace,
)

__all__ = [
    "PRESETS",
    "FurnaceResult",
    "MarschnerParams",
    "far_field_lobes",
    "goniometric_curve",
    "near_field_lobes",
    "scattering",
    "sigma_a_from_melanin",
    "white_furnace",
]
