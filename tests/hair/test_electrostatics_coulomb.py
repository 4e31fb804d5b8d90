"""Coulomb forces: direct sum against Coulomb's law and Newton's third law; fmm3dpy and the treecode
against the direct sum (Sobottka eq. 4.2, §4.5)."""

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.hair.electrostatics import (
    CoulombOptions,
    Treecode,
    TreecodeOptions,
    coulomb_forces,
    direct_field,
    direct_forces,
    field_at,
    fmm_forces,
    force_errors,
)
from headsim.hair.electrostatics._reference import coulomb_forces_reference
from headsim.hair.electrostatics.units import EPSILON_0, K_COULOMB, STATCOULOMB, statc_per_cm_to_c_per_m


def fibre_charges(n_fibres=40, per_fibre=250, seed=0):
    """Charges on wavy fibres hanging from a disc (like the seed's test 1, smaller)."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 0.08, per_fibre)
    roots = rng.uniform(-4e-3, 4e-3, size=(n_fibres, 3))
    roots[:, 1] = 0.0
    phase = rng.uniform(0, 2 * np.pi, n_fibres)
    x = np.empty((n_fibres, per_fibre, 3))
    x[..., 0] = roots[:, :1] + 3e-3 * np.sin(60 * s[None, :] + phase[:, None])
    x[..., 1] = -s[None, :]
    x[..., 2] = roots[:, 2:3] + 2e-3 * np.cos(40 * s[None, :] + phase[:, None])
    q = np.full(n_fibres * per_fibre, -1e-14) * rng.uniform(0.5, 1.5, n_fibres * per_fibre)
    return x.reshape(-1, 3), q


def test_units():
    assert STATCOULOMB == pytest.approx(3.33564e-10, rel=1e-5)
    assert K_COULOMB == pytest.approx(8.98755e9, rel=1e-5)
    assert K_COULOMB * 4 * np.pi * EPSILON_0 == pytest.approx(1.0, rel=1e-14)
    assert statc_per_cm_to_c_per_m(-7.7e-4) == pytest.approx(-2.5684e-11, rel=1e-4)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_two_point_charges_coulombs_law(sign):
    q1, q2, r = 2e-9, sign * 3e-9, 0.05
    x = np.array([[0.1, 0.2, 0.3], [0.1, 0.2, 0.3]]) + np.array([[0, 0, 0], [r * 0.6, 0, r * 0.8]])
    F = direct_forces(x, [q1, q2])
    mag = K_COULOMB * abs(q1 * q2) / r**2
    u = (x[1] - x[0]) / r
    np.testing.assert_allclose(F[1], sign * mag * u, rtol=1e-13)  # like charges repel
    np.testing.assert_allclose(F[0], -F[1], rtol=1e-13)
    E = direct_field([x[0]], [q1], targets=[x[1]])
    np.testing.assert_allclose(np.linalg.norm(E), K_COULOMB * q1 / r**2, rtol=1e-13)


def test_direct_sum_against_reference_and_newtons_third_law():
    x, q = fibre_charges(8, 60)
    F = direct_forces(x, q)
    np.testing.assert_allclose(F, coulomb_forces_reference(x, q), rtol=1e-10, atol=1e-12 * np.abs(F).max())
    # isolated system: the forces sum to zero (pairwise antisymmetry)
    assert np.linalg.norm(F.sum(axis=0)) < 1e-12 * np.abs(F).sum()


def test_bad_input():
    with pytest.raises(ParameterError):
        direct_forces(np.zeros((3, 2)), np.ones(3))
    with pytest.raises(ParameterError):
        direct_forces([[0, 0, np.nan]], [1.0])
    with pytest.raises(ParameterError):
        CoulombOptions(method="ewald")
    with pytest.raises(ParameterError):
        TreecodeOptions(theta=1.5)


@pytest.fixture(scope="module")
def fibres_10k():
    x, q = fibre_charges()
    return x, q, direct_forces(x, q)


@pytest.mark.parametrize("eps", [1e-3, 1e-6])
def test_fmm3d_against_direct_sum(fibres_10k, eps):
    x, q, ref = fibres_10k
    err = force_errors(fmm_forces(x, q, eps), ref)
    # fmm3dpy's eps is a relative l2 precision of the gradients
    assert err["rms_relative"] < eps
    assert err["mean_angle_rad"] < eps


@pytest.mark.parametrize("local", [False, True])
def test_treecode_against_direct_sum(fibres_10k, local):
    x, q, ref = fibres_10k
    tree = Treecode(x, q, TreecodeOptions(leaf_size=32, local=local))
    errs = {}
    for theta in (0.8, 0.5, 0.3):
        for order in (0, 2):
            errs[theta, order] = force_errors(q[:, None] * tree.field(theta, order), ref)
    for order in (0, 2):  # converges as the opening angle shrinks
        r = [errs[t, order]["rms_relative"] for t in (0.8, 0.5, 0.3)]
        assert r[0] > r[1] > r[2]
    for theta in (0.8, 0.5, 0.3):  # the quadrupole helps, and stays below the truncation scale theta^3
        assert errs[theta, 2]["rms_relative"] < errs[theta, 0]["rms_relative"]
        assert errs[theta, 2]["rms_relative"] < theta**3
        assert errs[theta, 2]["mean_angle_rad"] < theta**3
    assert errs[0.3, 2]["rms_relative"] < 1e-3  # three digits


def test_treecode_small_theta_is_exact_and_refit(fibres_10k):
    x, q, ref = fibres_10k
    n = 2000
    tree = Treecode(x[:n], q[:n], TreecodeOptions(theta=1e-6, leaf_size=16))  # opens every cell
    np.testing.assert_allclose(tree.forces(), direct_forces(x[:n], q[:n]), rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    tree = Treecode(x, q, TreecodeOptions(theta=0.4))
    f1 = tree.forces()
    tree.refit(charges=2 * q)  # same positions, doubled charges: forces x 4
    np.testing.assert_allclose(tree.forces(), 4 * f1, rtol=1e-12, atol=1e-20)
    moved = x + np.array([1e-3, 0, 0]) * np.sin(30 * x[:, 1:2])  # deform, keep the topology
    tree.refit(moved, q)
    err = force_errors(tree.forces(), direct_forces(moved, q))
    assert err["rms_relative"] < 0.4**3


def test_coulomb_forces_dispatch_and_probe_field(fibres_10k):
    x, q, ref = fibres_10k
    for method in ("direct", "fmm3d", "treecode"):
        f = coulomb_forces(x[:3000], q[:3000], CoulombOptions(method=method, eps=1e-6, theta=0.3))
        assert force_errors(f, direct_forces(x[:3000], q[:3000]))["rms_relative"] < 1e-3
    # probe far away: the field of the total charge (monopole) to leading order
    p = np.array([[0.0, -0.04, 2.0]])
    c = (x * q[:, None]).sum(0) / q.sum()
    exact = K_COULOMB * q.sum() / np.linalg.norm(p[0] - c) ** 2
    for method in ("direct", "fmm3d", "treecode"):
        E = field_at(p, x, q, CoulombOptions(method=method, eps=1e-6))
        assert np.linalg.norm(E) == pytest.approx(abs(exact), rel=1e-3)
