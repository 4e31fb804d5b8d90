"""Mass-spring-damper model (Heinze eqs. 2.1-2.8) and spring constants from material data."""

from dataclasses import replace

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.mesh.tet import TetMesh
from headsim.solvers._kernels.massspring import spring_damper_forces
from headsim.solvers._reference import finite_difference_gradient, spring_damper_forces_reference
from headsim.solvers.grids import block_tetmesh
from headsim.solvers.massspring import STANDARD_GRAVITY, MassSpringModel, combine_mass_spring, mass_spring_from_tetmesh
from headsim.solvers.materials import Material, spring_stiffness_from_young


def test_kernel_matches_reference_and_newtons_third_law():
    rng = np.random.default_rng(0)
    mesh = block_tetmesh((0.02, 0.01, 0.01), (3, 2, 2))
    edges = mesh.edges
    x = mesh.vertices + 1e-3 * rng.standard_normal(mesh.vertices.shape)
    v = rng.standard_normal(x.shape)
    rest = np.linalg.norm(mesh.vertices[edges[:, 1]] - mesh.vertices[edges[:, 0]], axis=1)
    k = rng.uniform(1, 5, len(edges))
    c = rng.uniform(0, 0.1, len(edges))
    out = np.zeros_like(x)
    spring_damper_forces(x, v, edges, rest, k, c, out)
    want = spring_damper_forces_reference(x, v, edges, rest, k, c)
    assert np.allclose(out, want, rtol=1e-12, atol=1e-15)
    assert np.abs(out.sum(axis=0)).max() < 1e-12 * np.abs(out).max()  # eqs. 2.6, 2.8


def test_single_spring_force_is_hooke():
    m = MassSpringModel([[0, 0, 0], [0.12, 0, 0]], [1.0, 1.0], [[0, 1]], [0.1], [5.0], [0.0], [False, False],
                        np.zeros((2, 3)), [0, 0])
    f = m.forces(m.rest_positions, np.zeros((2, 3)))
    assert f[0] == pytest.approx([5.0 * 0.02, 0, 0])  # pulled towards vertex 1
    assert f[1] == pytest.approx([-5.0 * 0.02, 0, 0])


def test_damper_acts_on_relative_velocity_along_the_spring():
    m = MassSpringModel([[0, 0, 0], [1.0, 0, 0]], [1.0, 1.0], [[0, 1]], [1.0], [0.0], [2.0], [False, False],
                        np.zeros((2, 3)), [0, 0])
    v = np.array([[0.0, 0, 0], [0.5, 3.0, 0]])  # separating at 0.5 m/s; the 3 m/s sideways is ignored
    f = m.forces(m.rest_positions, v)
    assert f[0] == pytest.approx([1.0, 0, 0])
    assert f[1] == pytest.approx([-1.0, 0, 0])


def test_gradient_and_hessian_match_finite_differences():
    rng = np.random.default_rng(3)
    mesh = block_tetmesh((0.02, 0.02, 0.02), (1, 1, 2))
    m = mass_spring_from_tetmesh(mesh, stiffness=3.0, total_mass=0.1, gravity=STANDARD_GRAVITY)
    x = m.rest_positions + 2e-3 * rng.standard_normal(m.rest_positions.shape)
    assert np.allclose(m.gradient(x), finite_difference_gradient(m.energy, x, 1e-7), atol=1e-7)
    h = m.hessian(x, project=False).toarray()
    hf = np.column_stack([finite_difference_gradient(lambda y: m.gradient(y)[i // 3, i % 3], x, 1e-7).ravel()
                          for i in range(3 * len(x))])
    assert np.abs(h - hf).max() < 1e-6 * np.abs(h).max()
    assert np.linalg.eigvalsh(m.hessian(x).toarray()).min() > -1e-10


def test_masses_uniform_as_in_seed_or_lumped_from_density():
    mesh = block_tetmesh((0.1, 0.1, 0.1), (2, 2, 2))
    m = mass_spring_from_tetmesh(mesh, stiffness=5.0, total_mass=0.917)
    assert np.allclose(m.mass, 0.917 / mesh.n_vertices)  # eq. 2.1
    mat = Material.from_kpa(10.0, 0.25, 1000.0)
    m2 = mass_spring_from_tetmesh(mesh, material=mat, gravity=STANDARD_GRAVITY)
    assert m2.mass.sum() == pytest.approx(1000.0 * 1e-3)
    assert m2.external_force.sum(axis=0) == pytest.approx(m2.mass.sum() * STANDARD_GRAVITY)


def test_fixed_bone_vertices_and_per_region_constants():
    mesh = block_tetmesh((0.02, 0.02, 0.02), (2, 2, 2))
    region = (mesh.vertices[mesh.tets].mean(axis=1)[:, 1] > 0.01).astype(np.int32)
    fixed = mesh.vertices[:, 1] == 0.0
    mesh = replace(mesh, tet_region=region, fixed=fixed)
    m = mass_spring_from_tetmesh(mesh, stiffness={0: 5.0, 1: 0.2}, total_mass=0.1, gravity=STANDARD_GRAVITY)
    low = np.all(mesh.vertices[m.edges][:, :, 1] < 0.005, axis=1)
    high = np.all(mesh.vertices[m.edges][:, :, 1] > 0.015, axis=1)
    assert np.allclose(m.stiffness[low], 5.0) and np.allclose(m.stiffness[high], 0.2)
    assert np.all(m.external_force[fixed] == 0)
    with pytest.raises(ParameterError):
        mass_spring_from_tetmesh(mesh, stiffness={0: 5.0}, total_mass=0.1)
    with pytest.raises(ParameterError):
        mass_spring_from_tetmesh(mesh, stiffness=5.0, material=Material(1e4), total_mass=0.1)


def test_spring_constants_reproduce_young_modulus_on_average():
    """Van Gelder-type rule k = E sum V / l^2: orientation-averaged energy = linear elasticity, E, nu = 1/4."""
    rng = np.random.default_rng(7)
    x0 = np.array([[0, 0, 0], [1, 0.1, 0], [0.2, 0.9, 0], [0.3, 0.2, 1.1]]) * 0.01
    tets = np.array([[0, 1, 2, 3]])
    mesh = TetMesh(x0, tets)
    young = 12e3
    k = spring_stiffness_from_young(x0, tets, mesh.edges, young)
    vol = mesh.volume
    eps = np.array([[1.0, 0.3, 0.0], [0.3, -0.5, 0.2], [0.0, 0.2, 0.4]]) * 1e-4
    mu = lam = 0.4 * young  # E = 12e3, nu = 1/4
    w_lin = vol * (mu * np.sum(eps * eps) + 0.5 * lam * np.trace(eps) ** 2)
    energies = []
    for _ in range(4000):
        q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
        xr = x0 @ q.T
        d0 = xr[mesh.edges[:, 1]] - xr[mesh.edges[:, 0]]
        d1 = d0 + d0 @ eps.T
        energies.append(0.5 * np.sum(k * (np.linalg.norm(d1, axis=1) - np.linalg.norm(d0, axis=1)) ** 2))
    mean = np.mean(energies)
    sem = np.std(energies) / np.sqrt(len(energies))
    assert abs(mean - w_lin) < 4 * sem + 1e-3 * w_lin


def test_zero_length_springs_and_bad_masses_are_refused():
    with pytest.raises(ParameterError):
        MassSpringModel([[0, 0, 0], [0, 0, 0]], [1.0, 1.0], [[0, 1]], [0.0], [5.0], [0.0], [False, False],
                        np.zeros((2, 3)), [0, 0])
    with pytest.raises(ParameterError):
        MassSpringModel([[0, 0, 0], [1, 0, 0]], [1.0, -1.0], [[0, 1]], [1.0], [5.0], [0.0], [False, False],
                        np.zeros((2, 3)), [0, 0])


def test_combining_bodies_keeps_them_separate():
    a = mass_spring_from_tetmesh(block_tetmesh((0.1, 0.1, 0.1)), stiffness=5.0, total_mass=0.1)
    b = mass_spring_from_tetmesh(block_tetmesh((0.1, 0.1, 0.1), origin=(0, 0.2, 0)), stiffness=0.2, total_mass=0.9)
    m, offsets = combine_mass_spring([a, b])
    assert m.n_vertices == a.n_vertices + b.n_vertices
    assert set(np.unique(m.body)) == {0, 1}
    assert m.mass.sum() == pytest.approx(1.0)
    assert np.all((m.edges < offsets[1]).all(axis=1) | (m.edges >= offsets[1]).all(axis=1))
