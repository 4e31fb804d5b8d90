"""Fat-grafting planner: volume injection into a marked face region by PBD (app layer).

Monkin 2016 (seed 001): markers → closed loop → region (:mod:`~headsim.graft.region`), closed region
model and volume injection (:mod:`~headsim.graft.plan`), measurements between aligned models
(:mod:`~headsim.graft.measure`), the simulation state machine (:mod:`~headsim.graft.state_machine`) and
the seed's demo scenes (:mod:`~headsim.graft.scenes`).
"""

from headsim.graft.measure import SurfaceDistances, signed_distances, surface_distances, volume_between
from headsim.graft.plan import GraftOptions, GraftResult, GraftSetup, inject_volume, prepare_graft
from headsim.graft.region import (
    ClosedRegion,
    FaceRegion,
    Markers,
    close_region,
    load_markers,
    region_from_loop,
    region_from_markers,
    save_markers,
    transfer_region_to_midpoint_subdivision,
)
from headsim.graft.state_machine import GraftSession, SimulationState, StateError

__all__ = [
    "Markers",
    "FaceRegion",
    "ClosedRegion",
    "load_markers",
    "save_markers",
    "region_from_markers",
    "region_from_loop",
    "transfer_region_to_midpoint_subdivision",
    "close_region",
    "GraftOptions",
    "GraftSetup",
    "GraftResult",
    "prepare_graft",
    "inject_volume",
    "volume_between",
    "surface_distances",
    "SurfaceDistances",
    "signed_distances",
    "GraftSession",
    "SimulationState",
    "StateError",
    "bundled_markers_path",
]


def bundled_markers_path(name: str = "cheeks_neutral"):
    """Path of a bundled markers file (``cheeks_neutral``: left and right cheek on the neutral face)."""
    from pathlib import Path

    from headsim.data import data_dir

    path = Path(data_dir()) / "markers" / f"{name}.json"
    if not path.exists():
        from headsim.errors import RegionError

        raise RegionError(f"no bundled markers named {name!r}")
    return path
