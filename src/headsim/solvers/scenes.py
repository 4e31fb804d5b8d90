"""Validation scenes of the seed (Heinze 2023, ch. 4) and the sphere-on-block scene of the CLI.

Seed ch. 4: a sphere (917 g) falls under gravity (y) onto a cuboid (100 g); mass-spring-damper
bodies, springs k = 5 N/m ("rigid") or 0.2 N/m ("soft"), collision k_coll = 1 N/m, dt = 0.2 s,
10-20 steps. Outcomes reported by the thesis: both rigid -> both keep their shape, the sphere
still sinks somewhat into the cuboid; rigid sphere on soft cuboid -> the cuboid deforms, the sphere
keeps its shape; both soft -> both deform, the cuboid more.

Assumptions where the thesis is silent (stated, not hidden): the Gmsh meshes are replaced by a
structured cuboid (4R x 2R x 4R, 4 x 2 x 4 cells) and a ball of radius R = 0.5 m
(:func:`~headsim.solvers.grids.ball_tetmesh`, 125 points), metre-sized like Gmsh's default
geometry; the cuboid stands on a fixed floor (bottom vertices fixed); masses are total / N (eq. 2.1)
in kg; gravity 9.81 m/s^2 on both bodies; no dampers (the thesis gives no k_d); the collision force
is per mass point (F = k_coll d, eq. 3.8) with consistent directions (eqs. 3.9-3.13).

With SI masses (about 7 g per sphere point) the seed's explicit Euler at dt = 0.2 s is far
beyond its stability limit (about 0.01 s here) and diverges on the first contact -- the seed's own
remark that larger steps need smaller spring constants (§3.2). :func:`seed_sphere_on_cuboid`
therefore reports the state every dt = 0.2 s but integrates with symplectic Euler sub-steps below
the stability limit (``integrator="substepped"``, the seed's collision force at every sub-step);
``integrator="explicit"`` runs the seed-faithful loop (eqs. 3.1-3.13) at the seed's dt, which raises
DivergenceError.

What this reproduces and what it does not (10 steps = 2 s, R = 0.5 m): both rigid -- the cuboid keeps
its shape (shape change 0.5 %) and the sphere sinks into it (and bounces), but the k = 5 N/m sphere
does *not* keep its shape (about 35 % shape change); rigid sphere on soft cuboid -- the cuboid deforms
(about 40 %) and the sphere much less (5 %), as in the thesis, but the 0.2 N/m cuboid is flattened and
the sphere passes through it after about 3 steps; both soft -- both deform (about 35-40 %).

Why the seed's numbers cannot all hold in SI (three dimensionless groups; M = 0.917 kg, g = 9.81 m/s^2):

1. Stability, omega_max dt: the masses are M / N per point (eq. 2.1), so omega_max^2 ~ (springs per
   point) k N / M. At N = 200 points the explicit limit is 0.009 s (k = 5) and 0.017 s (k = 5 / 0.2):
   dt = 0.2 s is 10-20x beyond it for any body size (the limit does not depend on lengths). The
   seed's rule k < 1/dt (eqs. 3.3-3.6) is the first-order problem x' = -k x, i.e. unit point masses.
   Reading the masses in grams as kilograms would make dt = 0.2 s stable (limit 0.28 s / 0.54 s), but
   then the weight is 9,000 N on 5 N/m springs and the sphere falls through everything.
2. Rigidity, M g / (k_eff L): a spring network under its own weight strains by about M g / (c k n L)
   (n points across, L the size, c ~ 1-2). "Keeps its shape" (< 5 %) at k = 5 N/m needs n L of tens
   of metres: at R = 0.5 m the sphere strains about 35 %, at R = 5 m with 9 points across
   (``radius=5, sphere_divisions=4``) 1-3 % -- there scenario 4.2.1 reproduces completely (both keep
   their shape, the sphere sinks somewhat into the cuboid; asserted in the tests).
3. Contact, M g / (k_coll N_c R): the per-point penalty F = k_coll d (eq. 3.8) acts on the colliding
   points only, with no reaction on the other body, so the 9 N weight is held by about 9 / N_c metres
   of penetration of the sphere's points, while the cuboid is loaded only through its own points that
   lie inside the sphere. At the size where the k = 5 sphere is rigid (R = 5 m) the sphere therefore
   sinks about 0.1 R into the soft cuboid and the cuboid deforms only 2-4 % (coarse or 8 x 4 x 8
   cells alike): the "cuboid deforms" outcomes of 4.2.2 / 4.2.3 need the metre size, where the k = 5
   sphere is no longer rigid. No single size reproduces all three scenarios; the thesis gives no
   body sizes, mesh sizes or units beyond the numbers above, so the mismatch cannot be traced further.
   The per-point constant also makes the contact stiffness grow with the number of colliding points
   (a mesh dependence of the seed's model; headsim's FEM contact uses a pressure penalty in Pa/m).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from headsim.errors import ParameterError
from headsim.solvers.contact_consistent import SeedCollisionForce, exit_points
from headsim.solvers.grids import ball_tetmesh, block_tetmesh
from headsim.solvers.integrators import ExplicitEuler, SymplecticEuler, critical_time_step
from headsim.solvers.massspring import STANDARD_GRAVITY, MassSpringModel, combine_mass_spring, \
    mass_spring_from_tetmesh
from headsim.solvers.state import BodyState

#: the thesis's three scenarios: (sphere k, cuboid k), N/m
SEED_SCENARIOS = {"both-rigid": (5.0, 5.0), "rigid-on-soft": (5.0, 0.2), "both-soft": (0.2, 0.2)}


@dataclass(frozen=True, eq=False)
class SceneResult:
    """Trajectory of a two-body scene.

    model : the combined MassSpringModel (body 0 = sphere, body 1 = cuboid); offsets (3,) vertex
    ranges; tets : per body (m, 4) global ids; surfaces : per body (t, 3) global ids; states :
    BodyState per step (initial included); shape_change : per step (2,) RMS deviation from the best
    rigid motion of each body, divided by its size; penetration : per step, the largest depth of a
    sphere point inside the cuboid, m.
    """

    name: str
    model: MassSpringModel
    offsets: np.ndarray
    tets: list
    surfaces: list
    states: list
    shape_change: np.ndarray
    penetration: np.ndarray


def rigid_fit_deviation(rest: np.ndarray, current: np.ndarray) -> float:
    """RMS distance (m) between ``current`` and the best rigid motion of ``rest`` (Kabsch)."""
    a = rest - rest.mean(axis=0)
    b = current - current.mean(axis=0)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(u @ vt))
    rot = u @ np.diag([1.0, 1.0, d]) @ vt
    return float(np.sqrt(np.mean(np.sum((a @ rot - b) ** 2, axis=1))))


def _sphere_cuboid_bodies(k_sphere: float, k_cuboid: float, sphere_mass: float, cuboid_mass: float,
                          radius: float, sphere_divisions: int, damping_ratio: float, cuboid_divisions=(4, 2, 4)):
    """Cuboid 4R x 2R x 4R on a fixed floor (bottom vertices fixed), ball of radius R 2 % of R above it."""
    h = 2.0 * radius
    cub = block_tetmesh((4 * radius, h, 4 * radius), tuple(cuboid_divisions), origin=(-2 * radius, -h, -2 * radius),
                        name="cuboid")
    cub = replace(cub, fixed=cub.vertices[:, 1] <= -h + 1e-9 * radius)
    sph = ball_tetmesh(radius, sphere_divisions, center=(0.0, 1.02 * radius, 0.0), name="sphere")
    ms = mass_spring_from_tetmesh(sph, stiffness=k_sphere, total_mass=sphere_mass, gravity=STANDARD_GRAVITY,
                                  damping_ratio=damping_ratio)
    mc = mass_spring_from_tetmesh(cub, stiffness=k_cuboid, total_mass=cuboid_mass, gravity=STANDARD_GRAVITY,
                                  damping_ratio=damping_ratio)
    model, off = combine_mass_spring([ms, mc])
    tets = [sph.tets, cub.tets + off[1]]
    surfaces = [sph.boundary_triangles, cub.boundary_triangles + off[1]]
    return model, off, tets, surfaces


def seed_sphere_on_cuboid(scenario: str = "both-rigid", steps: int = 10, dt: float = 0.2, k_coll: float = 1.0,
                          integrator: str = "substepped", sphere_mass: float = 0.917, cuboid_mass: float = 0.1,
                          radius: float = 0.5, sphere_divisions: int = 2, damping_ratio: float = 0.0,
                          direction: str = "consistent", cuboid_divisions: tuple[int, int, int] = (4, 2, 4),
                          progress: Callable[[int], None] | None = None) -> SceneResult:
    """Run one of the thesis's sphere-on-cuboid scenarios (Heinze §4.2).

    scenario : "both-rigid", "rigid-on-soft" or "both-soft" (:data:`SEED_SCENARIOS`)
    steps, dt : number of steps and step, s; k_coll : collision constant per point, N/m
    integrator : "substepped" (symplectic Euler with sub-steps below the stability limit inside each
        seed step of ``dt``; the seed's collision force every sub-step) or "explicit" (the seed's
        loop, eqs. 3.1-3.13, one step per ``dt``; diverges at dt = 0.2 s with SI masses)
    direction : "consistent" (eqs. 3.9-3.13) or "naive"
    progress : called with the step number after every step
    """
    if scenario not in SEED_SCENARIOS:
        raise ParameterError(f"unknown scenario {scenario!r}; use one of {', '.join(SEED_SCENARIOS)}")
    if not (np.isfinite(radius) and radius > 0) or sphere_divisions < 1 or min(cuboid_divisions) < 1:
        raise ParameterError(f"need radius > 0 m and divisions >= 1, got radius {radius}, sphere divisions "
                             f"{sphere_divisions}, cuboid divisions {tuple(cuboid_divisions)}")
    if integrator not in ("substepped", "explicit"):
        raise ParameterError(f"integrator must be 'substepped' or 'explicit', got {integrator!r}")
    ks, kc = SEED_SCENARIOS[scenario]
    model, off, tets, surfaces = _sphere_cuboid_bodies(ks, kc, sphere_mass, cuboid_mass, radius, sphere_divisions,
                                                     damping_ratio, cuboid_divisions)
    state = BodyState.at_rest(model.rest_positions)
    states = [state]
    force = SeedCollisionForce(model.body, surfaces, model.edges, k_coll, 0.0, direction)
    if integrator == "explicit":
        solver, substeps = ExplicitEuler(), 1
    else:
        solver = SymplecticEuler()
        substeps = max(1, int(np.ceil(dt / (0.5 * critical_time_step(model)))))
    for i in range(steps):
        for _ in range(substeps):
            state = solver.step(model, state, dt / substeps, extra_forces=force)
        states.append(replace(state, step=i + 1))
        if progress:
            progress(i + 1)
    size = [2.0 * radius, 4.0 * radius]  # sphere diameter, cuboid width, m
    shape = np.array([[rigid_fit_deviation(model.rest_positions[off[b]:off[b + 1]], s.positions[off[b]:off[b + 1]])
                       / size[b] for b in (0, 1)] for s in states])
    pen = []
    for s in states:
        res = exit_points(s.positions, np.arange(off[0], off[1]), s.positions, surfaces[1], "naive")
        pen.append(float(res.depth[res.inside].max()) if res.inside.any() else 0.0)
    return SceneResult(f"sphere-on-cuboid/{scenario}/{integrator}", model, off, tets, surfaces, states, shape,
                       np.array(pen))
