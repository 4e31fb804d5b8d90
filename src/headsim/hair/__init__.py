"""Hair fibres: properties, rods, collisions, electrostatics, reconstruction, rendering (app layer).

Implemented here: the keratin property database of Sobottka (2008) ch. 2 (:mod:`.properties`),
fibres and guide-fibre strands built from it (:mod:`.fibres`), the seed's rod scenes
(:mod:`.scenes`) and their output (:mod:`.output`). The rod numerics live in
:mod:`headsim.solvers.rods`.
"""

from headsim.hair import properties
from headsim.hair.fibres import (
    Strand,
    fibre_model,
    helix_axis,
    helix_curvature,
    interpolate_strand,
    make_strand,
    sinusoidal_curvature,
    to_polylines,
)
from headsim.hair.scenes import SCENES, Scene, Trajectory, build_scene, run_scene

__all__ = [
    "properties",
    "Strand",
    "fibre_model",
    "helix_axis",
    "helix_curvature",
    "interpolate_strand",
    "make_strand",
    "sinusoidal_curvature",
    "to_polylines",
    "SCENES",
    "Scene",
    "Trajectory",
    "build_scene",
    "run_scene",
]
