"""Shared numerical solvers: mass-spring-damper, FEM, PBD/XPBD, rods, contact."""

# deformable-body solver (issue 5): mass-spring-damper, FEM, integrators, contact
from headsim.solvers.contact import (  # noqa: E402
    DriverAttachment,
    PlaneContact,
    QuasiStaticOptions,
    QuasiStaticResult,
    RigidDriver,
    SphereObstacle,
    solve_quasi_static,
    surface_vertex_areas,
)
from headsim.solvers.contact_consistent import ExitPoints, SeedCollisionForce, exit_points  # noqa: E402
from headsim.solvers.fem import FemModel, fem_from_tetmesh  # noqa: E402
from headsim.solvers.integrators import (  # noqa: E402
    ExplicitEuler,
    ImplicitEuler,
    SymplecticEuler,
    critical_time_step,
    simulate,
)
from headsim.solvers.massspring import (  # noqa: E402
    STANDARD_GRAVITY,
    MassSpringModel,
    combine_mass_spring,
    mass_spring_from_tetmesh,
)
from headsim.solvers.materials import Material, spring_stiffness_from_young  # noqa: E402
from headsim.solvers.newton import NewtonOptions, minimize_newton  # noqa: E402
from headsim.solvers.state import BodyState  # noqa: E402
from headsim.solvers.thin_film import ThinFilmFlow, constrictions, orifice_flow, solve_thin_film  # noqa: E402

__all__ = [
    "BodyState", "DriverAttachment", "ExitPoints", "ExplicitEuler", "FemModel", "ImplicitEuler", "MassSpringModel", "Material",
    "NewtonOptions", "PlaneContact", "QuasiStaticOptions", "QuasiStaticResult", "RigidDriver", "STANDARD_GRAVITY",
    "SeedCollisionForce", "SphereObstacle", "SymplecticEuler", "combine_mass_spring", "critical_time_step",
    "exit_points", "fem_from_tetmesh", "mass_spring_from_tetmesh", "minimize_newton", "simulate",
    "solve_quasi_static", "spring_stiffness_from_young", "surface_vertex_areas",
    "ThinFilmFlow", "constrictions", "orifice_flow", "solve_thin_film",
]
