"""The fast paths of the solver against their plain references.

- analytic eigensystem projection of the stable neo-Hookean Hessian (Smith et al. 2018/2019) vs
  clamping the eigenvalues of the full 9 x 9 d2Psi/dF2 numerically;
- the vertex-level CSR pattern with a Numba scatter vs SciPy's COO -> CSR sum;
- Newton with AMG-preconditioned CG (hierarchy reuse, Eisenstat-Walker forcing) vs the sparse direct
  solve on the same contact problem;
- the symmetric-mode (static pivot) sparse LU vs SuperLU with partial pivoting.
"""

from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp

from headsim.mesh.tet import TetMesh
from headsim.solvers._assembly import ElementAssembler
from headsim.solvers._kernels import fem as kernels
from headsim.solvers.contact import QuasiStaticOptions, SphereObstacle, RigidDriver, solve_quasi_static, \
    surface_vertex_areas
from headsim.solvers.fem import fem_from_tetmesh
from headsim.solvers.grids import block_tetmesh
from headsim.solvers.materials import Material
import scipy.sparse.linalg as spla

from headsim.solvers.newton import AmgPreconditioner, NewtonOptions, _forcing_term, factorize_spd, \
    rigid_body_modes, solve_direct

MAT = Material.from_kpa(10.0, 0.3, 1000.0)


def _deformation_gradients():
    rng = np.random.default_rng(3)
    rot, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    rot *= np.sign(np.linalg.det(rot))
    fs = [np.eye(3), rot, np.diag([1.3, 1.3, 0.7]), rot @ np.diag([2.0, 2.0, 2.0]),  # repeated singular values
          np.diag([1.0, 1.0, -0.2]),  # inverted
          np.diag([1.5, 1e-9, 1e-9]),  # nearly collapsed to a line
          rot @ np.diag([0.9, 1.1, 1.0]) @ rot.T]
    fs += [np.eye(3) + s * rng.standard_normal((3, 3)) for s in (0.05, 0.3, 0.8) for _ in range(5)]
    return fs


@pytest.mark.parametrize("f", _deformation_gradients())
def test_analytic_projection_equals_numerical_eigenvalue_clamping(f):
    rest = np.array([[0.0, 0, 0], [1e-2, 0, 0], [0, 1.2e-2, 0], [0, 0, 0.9e-2]])
    tets = np.array([[0, 1, 2, 3]])
    model = fem_from_tetmesh(TetMesh(rest, tets), MAT)
    x = rest @ np.asarray(f).T
    args = (x, model.tets, model.grads, model.volumes, model.shear_modulus, model._snh_lambda)
    want = np.empty((1, 12, 12))
    got = np.empty((1, 12, 12))
    kernels.snh_hessian_values(*args, True, want)
    kernels.snh_hessian_values_projected(*args, got)
    scale = np.abs(want).max()
    assert np.abs(got - want).max() < 1e-10 * scale
    assert np.linalg.eigvalsh(got[0]).min() > -1e-12 * scale


def test_rotation_variant_svd_reconstructs_f_with_proper_rotations():
    u, s, v = np.empty((3, 3)), np.empty(3), np.empty((3, 3))
    for f in _deformation_gradients():
        kernels._rotation_variant_svd(np.asarray(f, dtype=float), u, s, v, np.empty((3, 3)), np.empty(3))
        assert np.abs(u @ np.diag(s) @ v.T - f).max() < 1e-12 * max(1.0, np.abs(f).max())
        assert np.linalg.det(u) == pytest.approx(1.0, abs=1e-12) and np.linalg.det(v) == pytest.approx(1.0, abs=1e-12)
        assert np.sign(s[2]) == np.sign(np.linalg.det(f)) or abs(np.linalg.det(f)) < 1e-15


@pytest.mark.parametrize("k", [2, 4])
def test_assembler_matches_scipy_coo_sum_in_canonical_csr(k):
    rng = np.random.default_rng(k)
    n = 40
    elements = np.array([rng.choice(n, size=k, replace=False) for _ in range(120)])
    values = rng.standard_normal((len(elements), 3 * k, 3 * k))
    asm = ElementAssembler(elements, n)
    got = asm.assemble(values)
    dofs = (3 * elements[:, :, None] + np.arange(3)).reshape(len(elements), 3 * k)
    rows = np.repeat(dofs, 3 * k, axis=1).ravel()
    cols = np.tile(dofs, (1, 3 * k)).ravel()
    want = sp.coo_matrix((values.ravel(), (rows, cols)), shape=(3 * n, 3 * n)).tocsr()
    want.sum_duplicates()
    assert abs(got - want).max() < 1e-12
    ref = got.copy()
    ref.sort_indices()
    assert np.array_equal(ref.indices, got.indices) and got.nnz == asm.nnz
    unused = np.setdiff1d(np.arange(n + 5), elements)  # vertices in no element have empty rows
    assert ElementAssembler(elements, n + 5).assemble(values).getnnz(axis=1)[3 * unused].max() == 0


def _block_hessian():
    """(model, free dof ids, rest Hessian on the free dofs as CSR) of a block clamped at its base."""
    mesh = block_tetmesh((0.02, 0.02, 0.01), (8, 8, 4))
    mesh = replace(mesh, fixed=np.isclose(mesh.vertices[:, 2], 0.0))
    m = fem_from_tetmesh(mesh, MAT)
    free = np.flatnonzero(np.repeat(~m.fixed, 3))
    return m, free, m.hessian(m.rest_positions).tocsr()[free][:, free]


def test_amg_preconditioned_cg_reuses_its_hierarchy_and_solves_to_tolerance():
    m, free, a = _block_hessian()
    rng = np.random.default_rng(0)
    pre = AmgPreconditioner(rigid_body_modes(m.rest_positions)[free])
    for i in range(3):
        b = rng.standard_normal(len(free))
        a_i = a * (1.0 + 0.05 * i)  # slowly changing matrices, as in Newton
        x = pre.solve(a_i, b, 1e-8)
        assert np.linalg.norm(a_i @ x - b) <= 1e-8 * np.linalg.norm(b)
    assert pre.setups == 1  # built once, reused for the two later matrices


def test_eisenstat_walker_forcing_term_is_bounded_and_tightens():
    o = NewtonOptions(cg_rtol=1e-2)
    assert _forcing_term(o, 1.0, None, None, 0.0) == 1e-2
    eta = _forcing_term(o, 1e-3, 1.0, 1e-2, 0.0)  # fast decrease -> 0.9 (1e-3)^2
    assert eta == pytest.approx(0.9e-6)
    assert _forcing_term(o, 0.9, 1.0, 1e-2, 0.0) == 1e-2  # slow decrease: capped at cg_rtol
    # never tighter than half the final tolerance relative to |g|: 0.5 * 1e-7 / 1e-3 = 5e-5
    assert _forcing_term(o, 1e-3, 1.0, 1e-2, 1e-7) == pytest.approx(5e-5)


def test_amg_newton_matches_direct_newton_on_a_contact_problem():
    mesh = block_tetmesh((0.02, 0.02, 0.01), (8, 8, 4), origin=(-0.01, -0.01, -0.01))
    x = mesh.vertices
    mesh = replace(mesh, fixed=np.isclose(x[:, 2], -0.01))
    model = fem_from_tetmesh(mesh, MAT)
    btri = mesh.boundary_triangles
    top = btri[np.all(np.isclose(x[btri][:, :, 2], 0.0), axis=1)]
    areas = surface_vertex_areas(len(x), top, x)
    cand = np.flatnonzero(areas > 0)
    out = {}
    for solver in ("direct", "amg-cg"):
        sphere = SphereObstacle(np.array([0.0, 0.0, 0.01]), 0.01, 300 * MAT.young_modulus / 1e-3, cand, areas[cand],
                                driver=0)
        opts = QuasiStaticOptions(newton=NewtonOptions(relative_tolerance=1e-10, linear_solver=solver),
                                  force_tolerance=1e-9)
        out[solver] = solve_quasi_static(model, [sphere], [RigidDriver((0, 0, -1.0), force=2e-3)], options=opts)
    d, a = out["direct"], out["amg-cg"]
    assert a.driver_displacement[0] == pytest.approx(d.driver_displacement[0], rel=1e-6)
    assert np.abs(a.positions - d.positions).max() < 1e-6 * abs(d.driver_displacement[0])
    assert a.timings["linear_solve"] > 0 and "amg_setup" in a.timings


def test_symmetric_mode_lu_matches_partial_pivoting_on_an_fem_hessian():
    _, free, a = _block_hessian()
    a = a.tocsc()
    b = np.random.default_rng(1).standard_normal(len(free))
    ref = spla.spsolve(a, b, permc_spec="MMD_AT_PLUS_A")
    x = solve_direct(a, b)
    assert np.linalg.norm(x - ref) <= 1e-10 * np.linalg.norm(ref)


def test_direct_solve_refines_or_falls_back_where_static_pivots_are_tiny():
    # symmetric indefinite: a 1e-14 pivot first, so static pivoting loses ~10 digits before refinement
    e = 1e-14
    a = sp.csc_matrix(np.array([[e, 1.0, 0.0], [1.0, e, 0.0], [0.0, 0.0, 2.0]]))
    b = np.array([1.0, 2.0, 3.0])
    x0 = factorize_spd(a).solve(b)
    assert np.linalg.norm(a @ x0 - b) > 1e-6 * np.linalg.norm(b)  # the unrefined static-pivot solve is off
    x = solve_direct(a, b)
    assert np.linalg.norm(a @ x - b) <= 1e-12 * np.linalg.norm(b)
