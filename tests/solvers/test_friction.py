"""Lagged Coulomb friction in the quasi-static contact (PlaneContact(friction=mu, friction_slip=eps)).

A block rests on a fixed rigid slab under a normal pressure p_n, then gets a tangential traction p_t
on its top. Below the Coulomb limit (p_t < mu p_n) it holds: the friction forces balance the
tangential load exactly, none leaves the Coulomb cone, each contact follows the regularised law
(stick spring mu lambda_c / eps, or mu lambda_c when sliding), and the edges of the bonded block slide
while its centre sticks (partial slip, as in Cattaneo-Mindlin). Above the limit there is no static
equilibrium and the solve reports that instead of returning one.
"""

from dataclasses import replace

import numpy as np
import pytest

from headsim.errors import ConvergenceError, ParameterError
from headsim.mesh.primitives import box
from headsim.solvers.contact import PlaneContact, QuasiStaticOptions, solve_quasi_static, surface_vertex_areas
from headsim.solvers.fem import fem_from_tetmesh
from headsim.solvers.grids import block_tetmesh
from headsim.solvers.materials import Material

MAT = Material.from_kpa(10.0, 0.3, 1000.0)
H = 0.01
MU = 0.5
EPS = 1e-7  # m


def _face(mesh, z):
    tri = mesh.boundary_triangles
    return tri[np.all(np.isclose(mesh.vertices[tri][:, :, 2], z), axis=1)]


def _setup():
    mesh = block_tetmesh((H, H, H), (3, 3, 3))
    x = mesh.vertices
    model = fem_from_tetmesh(mesh, MAT)
    bottom_areas = surface_vertex_areas(len(x), _face(mesh, 0.0), x)
    top_areas = surface_vertex_areas(len(x), _face(mesh, H), x)
    slaves = np.flatnonzero(bottom_areas > 0)
    slab = box((3 * H, 3 * H, 0.5 * H), center=(0.5 * H, 0.5 * H, -0.25 * H))
    contact = PlaneContact(slaves, bottom_areas[slaves], slab.triangles, 1e3 * MAT.young_modulus / H,
                           rigid_vertices=slab.vertices, direction="naive", margin=1e-3 * H, friction=MU,
                           friction_slip=EPS)
    return model, contact, top_areas, slaves


def _solve(model, contact, top_areas, p_n, p_t, x0=None):
    ext = np.zeros((model.n_vertices, 3))
    ext[:, 2] = -p_n * top_areas
    ext[:, 0] = p_t * top_areas
    opts = QuasiStaticOptions(force_tolerance=1e-9 * p_n * H * H)
    return solve_quasi_static(replace(model, external_force=ext), [contact], initial_positions=x0, options=opts)


def test_block_below_the_coulomb_limit_sticks_and_friction_balances_the_load():
    model, contact, top_areas, slaves = _setup()
    p_n = 1e-2 * MAT.young_modulus
    first = _solve(model, contact, top_areas, p_n, 0.0)
    p_t = 0.5 * MU * p_n
    res = _solve(model, contact, top_areas, p_n, p_t, x0=first.positions)
    n_total, t_total = p_n * H * H, p_t * H * H
    friction = contact.friction_forces(res.positions, res.driver_displacement)
    assert friction[:, 0].sum() == pytest.approx(-t_total, rel=1e-6)
    assert res.contact_forces[:, 2].sum() == pytest.approx(n_total, rel=1e-6)
    lam = contact.normal_force
    f_t = np.linalg.norm(friction[slaves[contact.active]], axis=1)
    assert (f_t <= MU * lam * (1 + 1e-9)).all()  # inside the Coulomb cone
    slip = np.linalg.norm(contact._slip(res.positions, res.driver_displacement), axis=1)
    stick = slip < EPS
    # the regularised Coulomb law per contact: a spring mu lambda / eps while sticking, mu lambda when sliding
    assert f_t[stick] == pytest.approx(MU * lam[stick] * slip[stick] / EPS, rel=1e-9)
    assert f_t[~stick] == pytest.approx(MU * lam[~stick], rel=1e-9)
    # the bonded block concentrates shear at its edges: the corners slide (partial slip), the centre sticks
    xy = res.positions[slaves[contact.active], :2] - 0.5 * H
    centre = np.argmin(np.hypot(xy[:, 0], xy[:, 1]))
    corner = np.argmax(np.abs(xy[:, 0]) + np.abs(xy[:, 1]))
    assert stick[centre] and not stick[corner]
    assert lam.sum() == pytest.approx(n_total, rel=1e-6)


def test_block_above_the_coulomb_limit_has_no_static_equilibrium():
    model, contact, top_areas, _ = _setup()
    p_n = 1e-2 * MAT.young_modulus
    first = _solve(model, contact, top_areas, p_n, 0.0)
    with pytest.raises(ConvergenceError):
        _solve(model, contact, top_areas, p_n, 1.5 * MU * p_n, x0=first.positions)


def test_friction_needs_a_slip_length():
    with pytest.raises(ParameterError, match="friction_slip"):
        PlaneContact(np.arange(3), np.ones(3), np.zeros((1, 3), int), 1.0, direction="naive", friction=0.3)
