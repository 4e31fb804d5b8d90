"""Physically based hair rendering (Sobottka 2008 ch. 6): the Marschner far field with the seed's
corrections, the near field across the fibre width, and a Numba path tracer for fibre assemblies with
multiple fibre-to-fibre scattering (Mitsuba 3 as the optional peer, :mod:`.mitsuba_peer`)."""

from headsim.hair.render.bvh import CapsuleBVH, FibreAssembly
from headsim.hair.render.renderer import (
    Camera,
    Light,
    MeshSurface,
    RenderOptions,
    RenderResult,
    Surface,
    camera_looking_at,
    render,
    save_png,
    to_srgb8,
)
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
from headsim.hair.render.synthetic import synthetic_hairstyle

__all__ = [
    "PRESETS",
    "Camera",
    "CapsuleBVH",
    "FibreAssembly",
    "FurnaceResult",
    "Light",
    "MarschnerParams",
    "MeshSurface",
    "RenderOptions",
    "RenderResult",
    "Surface",
    "camera_looking_at",
    "far_field_lobes",
    "goniometric_curve",
    "near_field_lobes",
    "render",
    "save_png",
    "scattering",
    "sigma_a_from_melanin",
    "synthetic_hairstyle",
    "to_srgb8",
    "white_furnace",
]
