"""Compaction barrier (headsim.solvers.compaction): a volume floor J > J_floor for homogenised solids."""

from dataclasses import replace

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.solvers.compaction import CompactionBarrier
from headsim.solvers.fem import FemModel

REST = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]) * 1e-2
MU, LAM = 1e4, 5e4


def _model(compaction=True, fixed=None, load=None):
    m = FemModel(REST, np.array([[0, 1, 2, 3]]), 1e-3, MU, LAM,
                 np.zeros(4, bool) if fixed is None else fixed, 0.0 if load is None else load, 0)
    return replace(m, compaction=CompactionBarrier(np.ones(1, bool), 0.1, 0.3)) if compaction else m


def _b(s):
    return -(s - 1.0) ** 2 * np.log(s)


def test_uniform_compression_energy_is_the_barrier_of_the_volume_ratio():
    """x = c X: J = c^3. Below the onset the energy is the SNH energy plus mu V b(s) exactly; above it
    the barrier adds nothing (bitwise)."""
    plain, barrier = _model(False), _model(True)
    vol = 1e-6 / 6
    for c in (0.9, 0.7, 0.6):           # J = 0.73, 0.34, 0.216
        x = c * REST
        j = c**3
        extra = MU * vol * _b((j - 0.1) / 0.2) if j < 0.3 else 0.0
        assert barrier.elastic_energy(x) - plain.elastic_energy(x) == pytest.approx(extra, rel=1e-12, abs=0.0)
        if j >= 0.3:
            assert barrier.elastic_energy(x) == plain.elastic_energy(x)
    assert barrier.elastic_energy(0.45 * REST) == np.inf           # J = 0.091 < floor
    assert np.isfinite(plain.elastic_energy(0.45 * REST))


def _compressed_state(seed=0):
    rng = np.random.default_rng(seed)
    x = REST * np.array([1.0, 1.0, 0.22]) + 1e-4 * rng.standard_normal((4, 3))  # J ~ 0.2: active
    return x


def test_gradient_and_exact_hessian_match_finite_differences_and_the_projected_one_is_psd():
    m = _model(True)
    x = _compressed_state()
    f = np.einsum("tai,taj->tij", x[m.tets], m.grads)
    assert 0.1 < np.linalg.det(f)[0] < 0.3
    g = m.elastic_gradient(x).ravel()
    h = m.element_hessians(x, project=False)[0]
    hp = m.element_hessians(x, project=True)[0]
    eps = 1e-9
    fd_g = np.empty(12)
    fd_h = np.empty((12, 12))
    for k in range(12):
        d = np.zeros(12)
        d[k] = eps
        xp, xm = x + d.reshape(4, 3), x - d.reshape(4, 3)
        fd_g[k] = (m.elastic_energy(xp) - m.elastic_energy(xm)) / (2 * eps)
        fd_h[:, k] = (m.elastic_gradient(xp).ravel() - m.elastic_gradient(xm).ravel()) / (2 * eps)
    assert np.allclose(g, fd_g, rtol=1e-5, atol=1e-6 * np.abs(g).max())
    assert np.allclose(h, fd_h, rtol=1e-5, atol=1e-6 * np.abs(h).max())
    assert np.linalg.eigvalsh(0.5 * (hp + hp.T)).min() >= -1e-9 * np.abs(hp).max()
    # the barrier's part is active: it changes the gradient against the plain model
    assert not np.allclose(g, _model(False).elastic_gradient(x).ravel())


def test_a_tet_crushed_by_a_large_load_stops_above_the_floor_instead_of_inverting():
    """Base fixed, apex pushed through the base with 50 x mu x area: the stable neo-Hookean tet alone finds an
    inverted equilibrium (J < 0); with the barrier the equilibrium has J in (floor, onset) and balances the load."""
    from headsim.solvers.newton import NewtonOptions, minimize_newton

    fixed = np.array([True, True, True, False])
    load = np.zeros((4, 3))
    load[3, 2] = -50.0 * MU * 0.5e-4
    results = {}
    for on in (False, True):
        m = _model(on, fixed, load)
        free = np.repeat(~fixed, 3)
        res = minimize_newton(lambda z, m=m: m.energy(z.reshape(4, 3)), lambda z, m=m: m.gradient(z.reshape(4, 3)).ravel(),
                              lambda z, project=True, m=m: m.hessian(z.reshape(4, 3), project), REST.ravel().copy(),
                              free, NewtonOptions(force_tolerance=0.0, relative_tolerance=1e-10,
                                            max_iterations=200, linear_solver="direct"))
        x = res.z.reshape(4, 3)
        results[on] = (m.min_jacobian(x), float(np.abs(m.gradient(x)[3]).max()))
    assert results[False][0] < 0.0                      # inverted without the barrier
    j, residual = results[True]
    assert 0.1 < j < 0.3 and residual <= 1e-8 * abs(load[3, 2])


def test_compaction_parameters_are_checked():
    with pytest.raises(ParameterError):
        CompactionBarrier(np.ones(1, bool), 0.3, 0.3)
    with pytest.raises(ParameterError):
        CompactionBarrier(np.ones(1, bool), 0.1, 0.3, scale=0.0)
    with pytest.raises(ParameterError, match="selects"):
        replace(_model(False), compaction=CompactionBarrier(np.ones(2, bool)))


def test_per_tet_floor_and_onset_act_tet_by_tet():
    """Two congruent tets compressed alike (J = 0.216): the one with (0.1, 0.3) carries mu V b(s), the one
    with the lower onset 0.2 nothing; at J = 0.09 the first is inadmissible (floor 0.1), the second
    (floor 0.02, onset 0.2) carries its own barrier."""
    rest = np.vstack([REST, REST + [0.05, 0.0, 0.0]])
    tets = np.array([[0, 1, 2, 3], [4, 5, 6, 7]])

    def model(compaction):
        return FemModel(rest, tets, 1e-3, MU, LAM, np.zeros(8, bool), 0.0, 0, compaction=compaction)

    plain = model(None)
    both = model(CompactionBarrier(np.ones(2, bool), np.array([0.1, 0.02]), np.array([0.3, 0.2])))
    vol = 1e-6 / 6
    x = 0.6 * rest                                  # J = 0.216 in both
    assert both.elastic_energy(x) - plain.elastic_energy(x) == pytest.approx(MU * vol * _b((0.216 - 0.1) / 0.2),
                                                                             rel=1e-9)
    second = model(CompactionBarrier(np.array([False, True]), 0.02, 0.2))
    x = (0.09 ** (1 / 3)) * rest                    # J = 0.09
    assert both.elastic_energy(x) == np.inf
    assert second.elastic_energy(x) - plain.elastic_energy(x) == pytest.approx(MU * vol * _b((0.09 - 0.02) / 0.18),
                                                                               rel=1e-9)
    with pytest.raises(ParameterError, match="tet 1"):
        CompactionBarrier(np.ones(2, bool), np.array([0.1, 0.2]), 0.2)
