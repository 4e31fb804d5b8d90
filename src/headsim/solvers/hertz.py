"""Hertz validation: a rigid sphere pressed with a force onto a thick FEM block (quasi-static).

Hertz (1882) for a rigid sphere of radius R on an elastic half-space (E, nu) under force F:
contact radius a = (3 F R / (4 E*))^(1/3), indentation delta = a^2 / R, E* = E / (1 - nu^2), pressure
p(r) = p0 sqrt(1 - r^2/a^2), p0 = 3 F / (2 pi a^2). The block is a quarter (symmetry planes x = 0
and y = 0), graded towards the contact point, bottom fixed, so its size is many contact radii.

The contact radius is measured from the contact-force distribution through its second moment:
for the Hertz pressure sum f_i r_i^2 / sum f_i = 2 a^2 / 5, so a = sqrt(5/2 <r^2>_f), which uses every
loaded node instead of the (mesh-size-quantised) outermost one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from headsim.solvers.contact import QuasiStaticOptions, RigidDriver, SphereObstacle, solve_quasi_static, \
    surface_vertex_areas
from headsim.solvers.fem import FemModel, fem_from_tetmesh
from headsim.solvers.grids import graded_coordinates, structured_tet_grid
from headsim.solvers.materials import Material


@dataclass(frozen=True)
class HertzResult:
    """Measured vs. Hertz: forces N, lengths m."""

    force: float
    radius: float
    contact_radius: float
    contact_radius_hertz: float
    indentation: float
    indentation_hertz: float
    contact_force: float
    support_reaction: float
    n_vertices: int
    n_tets: int
    newton_iterations: int
    model: FemModel
    positions: np.ndarray
    contact_pressure: np.ndarray
    timings: dict = field(default_factory=dict)  # CPU s per phase of the quasi-static solve

    @property
    def contact_radius_error(self) -> float:
        return self.contact_radius / self.contact_radius_hertz - 1.0

    @property
    def indentation_error(self) -> float:
        return self.indentation / self.indentation_hertz - 1.0


def hertz_contact_radius(force: float, radius: float, material: Material) -> float:
    """a = (3 F R / (4 E*))^(1/3), m."""
    return (3.0 * force * radius / (4.0 * material.plane_strain_modulus)) ** (1.0 / 3.0)


def hertz_indentation(material: Material = Material.from_kpa(10.0, 0.3), radius: float = 0.01,
                      contact_radius: float = 0.001, first_cell: float | None = None, growth: float = 1.25,
                      extent: float = 15.0, penalty_factor: float = 300.0, linear_solver: str = "auto") -> HertzResult:
    """Press a rigid sphere onto a quarter block with the force that gives ``contact_radius`` in theory.

    material : block material (E in Pa); radius : sphere radius R, m; contact_radius : target Hertz a, m
    first_cell : element size under the contact, m (default a / 6); growth : cell growth ratio
    extent : block width and depth in contact radii; penalty_factor : kappa = factor x E* / a (Pa/m)
    """
    a = contact_radius
    h0 = first_cell if first_cell is not None else a / 6.0
    estar = material.plane_strain_modulus
    force = 4.0 * estar * a**3 / (3.0 * radius)
    xs = graded_coordinates(extent * a, h0, growth)
    zs = -graded_coordinates(extent * a, h0, growth)[::-1]
    mesh = structured_tet_grid(xs, xs, zs, name="hertz block")
    fixed = mesh.vertices[:, 2] <= zs[0] + 1e-12
    from dataclasses import replace

    mesh = replace(mesh, fixed=fixed)
    model = fem_from_tetmesh(mesh, material)
    x = mesh.vertices
    sym = np.zeros((len(x), 3), dtype=bool)
    sym[:, 0] = np.abs(x[:, 0]) < 1e-12
    sym[:, 1] = np.abs(x[:, 1]) < 1e-12
    btri = mesh.boundary_triangles
    top = btri[np.all(np.abs(x[btri][:, :, 2]) < 1e-12, axis=1)]
    areas = surface_vertex_areas(len(x), top, x)
    cand = np.flatnonzero((areas > 0) & (np.hypot(x[:, 0], x[:, 1]) < 4 * a))
    sphere = SphereObstacle(center=np.array([0.0, 0.0, radius]), radius=radius, penalty=penalty_factor * estar / a,
                            vertices=cand, areas=areas[cand], driver=0)
    driver = RigidDriver(axis=(0.0, 0.0, -1.0), force=force / 4.0)  # quarter model
    from headsim.solvers.newton import NewtonOptions

    opts = QuasiStaticOptions(newton=NewtonOptions(relative_tolerance=1e-10, linear_solver=linear_solver),
                              force_tolerance=1e-7 * force)
    res = solve_quasi_static(model, [sphere], [driver], fixed_dofs=sym, options=opts)
    fz = res.contact_forces[:, 2]  # downward on the block
    rr = np.hypot(x[:, 0], x[:, 1])
    load = -fz
    a_meas = np.sqrt(2.5 * np.sum(load * rr**2) / np.sum(load))
    return HertzResult(
        force=force, radius=radius, contact_radius=float(a_meas),
        contact_radius_hertz=hertz_contact_radius(force, radius, material),
        indentation=float(res.driver_displacement[0]), indentation_hertz=a**2 / radius,
        contact_force=float(4.0 * np.sum(load)), support_reaction=float(4.0 * np.sum(res.reaction_forces[fixed, 2])),
        n_vertices=len(x), n_tets=mesh.n_tets, newton_iterations=res.newton_iterations, model=model,
        positions=res.positions, contact_pressure=res.contact_pressure, timings=res.timings,
    )
