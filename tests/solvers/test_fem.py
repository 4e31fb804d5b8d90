"""FEM (stable neo-Hookean tets): derivatives, patch test, uniaxial stress against Hooke's law."""

from dataclasses import replace

import numpy as np
import pytest

from headsim.errors import MeshError, ParameterError
from headsim.solvers._reference import finite_difference_gradient, snh_energy_reference
from headsim.solvers.contact import solve_quasi_static
from headsim.solvers.fem import FemModel, fem_from_tetmesh
from headsim.solvers.grids import block_tetmesh
from headsim.solvers.materials import Material

MAT = Material.from_kpa(10.0, 0.3, 1000.0)


def _model(divisions=(2, 2, 2), size=(0.02, 0.02, 0.02), material=MAT):
    return fem_from_tetmesh(block_tetmesh(size, divisions), material)


def test_energy_matches_reference_and_vanishes_at_rest():
    m = _model()
    rng = np.random.default_rng(1)
    x = m.rest_positions + 2e-3 * rng.standard_normal(m.rest_positions.shape)
    want = snh_energy_reference(x, m.rest_positions, m.tets, MAT.shear_modulus, MAT.lame_lambda)
    assert m.elastic_energy(x) == pytest.approx(want, rel=1e-12)
    scale = MAT.young_modulus * m.volumes.sum()  # J per unit strain^2
    assert abs(m.elastic_energy(m.rest_positions)) < 1e-12 * scale
    assert np.abs(m.elastic_gradient(m.rest_positions)).max() < 1e-12 * MAT.young_modulus * 0.02**2


def test_gradient_and_hessian_match_finite_differences():
    m = _model((1, 1, 1))
    rng = np.random.default_rng(2)
    x = m.rest_positions + 3e-3 * rng.standard_normal(m.rest_positions.shape)
    g = m.elastic_gradient(x)
    gf = finite_difference_gradient(m.elastic_energy, x, h=1e-8)
    assert np.abs(g - gf).max() < 1e-6 * np.abs(g).max()
    h = m.hessian(x, project=False).toarray()
    hf = np.column_stack([finite_difference_gradient(lambda y: m.elastic_gradient(y)[i // 3, i % 3], x, h=1e-8).ravel()
                          for i in range(3 * len(x))])
    assert np.abs(h - hf).max() < 1e-5 * np.abs(h).max()
    hp = m.hessian(x, project=True).toarray()
    assert np.linalg.eigvalsh(hp).min() > -1e-9 * np.abs(hp).max()
    assert np.allclose(hp, hp.T)


def test_patch_test_homogeneous_deformation_is_exact():
    """Boundary nodes follow an affine map; the free interior nodes must follow it too."""
    mesh = block_tetmesh((0.02, 0.02, 0.02), (3, 3, 3))
    x0 = mesh.vertices
    boundary = np.zeros(len(x0), dtype=bool)
    boundary[np.unique(mesh.boundary_triangles)] = True
    f = np.eye(3) + np.array([[0.04, 0.01, -0.02], [0.0, -0.03, 0.015], [0.02, 0.0, 0.05]])
    target = x0 @ f.T + np.array([1e-3, -2e-3, 0.5e-3])
    model = fem_from_tetmesh(replace(mesh, fixed=boundary), MAT)
    start = np.where(boundary[:, None], target, x0)
    res = solve_quasi_static(model, initial_positions=start)
    assert np.abs(res.positions - target).max() < 1e-10
    assert (~boundary).sum() == 8


@pytest.mark.parametrize("nu", [0.25, 0.3, 0.45])
def test_uniaxial_stress_gives_young_modulus_and_poisson_ratio(nu):
    """A traction sigma on x = L, rollers on x = y = z = 0 planes: eps_x = sigma / E, eps_y = -nu eps_x."""
    mat = Material.from_kpa(10.0, nu, 1000.0)
    size = np.array([0.03, 0.02, 0.02])
    mesh = block_tetmesh(tuple(size), (3, 2, 2))
    x = mesh.vertices
    sigma = 1e-4 * mat.young_modulus  # small strain: 1e-4
    right = np.isclose(x[:, 0], size[0])
    tri = mesh.boundary_triangles
    face = tri[np.all(right[tri], axis=1)]
    area = np.zeros(len(x))
    from headsim.mesh.geometry import triangle_areas

    np.add.at(area, face.ravel(), np.repeat(triangle_areas(x, face) / 3.0, 3))
    ext = np.zeros((len(x), 3))
    ext[:, 0] = sigma * area
    model = replace(fem_from_tetmesh(mesh, mat), external_force=ext)
    rollers = np.column_stack([np.isclose(x[:, c], 0.0) for c in range(3)])
    res = solve_quasi_static(model, fixed_dofs=rollers)
    strain = (res.positions - x)[right, 0].mean() / size[0]
    top = np.isclose(x[:, 1], size[1])
    lateral = (res.positions - x)[top, 1].mean() / size[1]
    assert sigma / strain == pytest.approx(mat.young_modulus, rel=2e-3)
    assert -lateral / strain == pytest.approx(nu, rel=5e-3)
    # the Cauchy stress in every tet is the applied traction
    s = model.cauchy_stress(res.positions)
    assert np.allclose(s[:, 0, 0], sigma, rtol=2e-3)
    assert np.abs(res.reaction_forces.sum(axis=0) + ext.sum(axis=0)).max() < 1e-9 * ext.sum()


def test_bad_input_is_refused():
    with pytest.raises(ParameterError):
        Material.from_kpa(-1.0)
    with pytest.raises(ParameterError):
        Material.from_kpa(10.0, 0.5)
    mesh = block_tetmesh()
    with pytest.raises(ParameterError):
        fem_from_tetmesh(replace(mesh, tet_region=np.full(mesh.n_tets, 2)), {0: MAT})
    bad = mesh.tets.copy()
    bad[0] = bad[0][[1, 0, 2, 3]]
    with pytest.raises(MeshError):
        FemModel(mesh.vertices, bad, 1.0, 1.0, 1.0, False, 0.0, 0)
