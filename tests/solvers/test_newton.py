"""Newton minimiser (headsim.solvers.newton.minimize_newton): when the exact Hessian is tried."""

import numpy as np
import pytest

from headsim.solvers.newton import NewtonOptions, minimize_newton

A = 0.5  # minimiser of E(z) = sum (z^2 - A^2)^2 / 4 from a positive start


def _problem(limits, calls):
    """E, grad, Hessian (exact: 3 z^2 - A^2, indefinite for |z| < A / sqrt 3; projected: clamped at a
    positive floor) and a step limit returning ``limits`` in turn, then 1."""
    it = iter(limits)

    def energy(z):
        return float(np.sum((z * z - A * A) ** 2) / 4)

    def gradient(z):
        return z * (z * z - A * A)

    def hessian(z, project=True):
        import scipy.sparse as sp

        calls.append(project)
        h = 3 * z * z - A * A
        return sp.diags(np.maximum(h, 0.1) if project else h, format="csr")

    return energy, gradient, hessian, lambda z, dz: next(it, 1.0)


@pytest.mark.parametrize("wait", [True, False])
def test_exact_hessian_waits_until_the_step_limit_lets_a_full_step_through(wait):
    calls = []
    energy, gradient, hessian, limit = _problem([0.3, 0.3, 0.5], calls)
    z0 = np.array([0.2, 0.9, 2.0])
    opts = NewtonOptions(force_tolerance=1e-12, try_exact_hessian=True, exact_after_full_step=wait,
                         linear_solver="direct")
    res = minimize_newton(energy, gradient, hessian, z0, np.ones(3, bool), opts, step_limit=limit)
    if wait:
        # three cut steps: projected Hessians only; the fourth step is the first full one, after it
        # the exact Hessian is tried first; the minimiser is reached
        assert calls[:4] == [True] * 4
        assert False in calls[4:]
        assert np.allclose(res.z, A, atol=1e-10)
    else:
        # exact first from the start: the summed slope is negative although the first unknown sits
        # where its curvature is negative, so that unknown is driven to the stationary point z = 0 (a
        # maximum along it) -- the hazard the waiting avoids
        assert calls[0] is False
        assert abs(res.z[0]) < 1e-10 and np.allclose(res.z[1:], A, atol=1e-10)


def _kinked_problem():
    """E(z) = (z - 1)^2 / 2, plus, for z > c = 0.999, a jump J = 1e-6 J and a slope s = 2e-3 N: the
    lowest energy is approached from the left at the jump itself, where |g| = 1 - c = 1e-3 N and every
    step to the right, however short, raises E (a contact set that switches at the iterate)."""
    import scipy.sparse as sp

    c, jump, s = 0.999, 1e-6, 2e-3

    def energy(z):
        return float(0.5 * (z[0] - 1.0) ** 2 + (jump + s * (z[0] - c) if z[0] > c else 0.0))

    def gradient(z):
        return np.array([z[0] - 1.0 + (s if z[0] > c else 0.0)])

    def hessian(z, project=True):
        return sp.identity(1, format="csr")

    return energy, gradient, hessian, c


@pytest.mark.parametrize("stall", [None, 5e-4, 2e-3])
def test_a_solve_that_stalls_at_a_jump_ends_only_below_the_stall_tolerance(stall):
    """Newton reaches the jump (z -> c from the left) and no step decreases E any more: with a stall
    tolerance above the residual there (1e-3 N) the solve returns that point, flagged not converged
    with its residual; with none, or one below it, it fails."""
    from headsim.errors import ConvergenceError

    energy, gradient, hessian, c = _kinked_problem()
    opts = NewtonOptions(force_tolerance=1e-9, relative_tolerance=0.0, stall_tolerance=stall)
    if stall is None or stall < 1e-3:
        with pytest.raises(ConvergenceError, match="line search failed"):
            minimize_newton(energy, gradient, hessian, np.zeros(1), np.ones(1, bool), opts)
        return
    res = minimize_newton(energy, gradient, hessian, np.zeros(1), np.ones(1, bool), opts)
    assert not res.converged
    assert res.z[0] <= c and res.z[0] == pytest.approx(c, abs=1e-9)
    assert res.gradient_norm == pytest.approx(1.0 - c, rel=1e-6)


@pytest.mark.parametrize("only_after_full", [True, False])
def test_exact_hessian_only_after_full_steps_returns_to_the_projected_one_after_a_cut_step(only_after_full):
    """Limits 0.3 (cut), 1 (full), 0.4 (cut), then 1: with ``exact_only_after_full_steps`` the
    iteration after the second cut step uses the projected Hessian only; without it (the former,
    sticky rule) the exact one is tried on every iteration after the first full step."""
    calls, marks = [], []
    energy, gradient, hessian, limit = _problem([0.3, 1.0, 0.4], calls)
    opts = NewtonOptions(force_tolerance=1e-12, try_exact_hessian=True, exact_after_full_step=True,
                         exact_only_after_full_steps=only_after_full, linear_solver="direct")
    res = minimize_newton(energy, gradient, hessian, np.array([0.2, 0.9, 2.0]), np.ones(3, bool), opts,
                          step_limit=limit, progress=lambda it, g, tol: marks.append(len(calls)))
    per_iteration = [calls[a:b] for a, b in zip(marks, marks[1:] + [len(calls)])]
    assert per_iteration[0] == [True] and per_iteration[1] == [True]   # no full step yet
    assert per_iteration[2][0] is False                                 # after the full step: exact first
    assert (per_iteration[3] == [True]) is only_after_full              # after the cut step
    assert np.allclose(res.z, A, atol=1e-10)


def test_pcg_meets_its_tolerance_and_reports_an_indefinite_matrix():
    import scipy.sparse as sp

    from headsim.solvers.newton import pcg

    rng = np.random.default_rng(0)
    n = 200
    lap = sp.diags([-np.ones(n - 1), 2.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1], format="csr")
    b = rng.standard_normal(n)
    x, its, ok = pcg(lap, b, lambda r: r, 1e-8, 500)
    assert ok and np.linalg.norm(lap @ x - b) <= 1e-8 * np.linalg.norm(b)
    # the exact inverse as preconditioner: one iteration
    inv = np.linalg.inv(lap.toarray())
    x, its, ok = pcg(lap, b, lambda r: inv @ r, 1e-10, 5)
    assert ok and its == 1
    # an indefinite matrix: reported as not converged, not as a solution
    indefinite = sp.diags(np.where(np.arange(n) % 2 == 0, 1.0, -1.0), format="csr")
    x, its, ok = pcg(indefinite, b, lambda r: r, 1e-8, 500)
    assert not ok


def _coupled_quartic(n=60, seed=1):
    """E(z) = 1/2 z^T K z + 1/4 sum c_i z_i^4 - f^T z: K an SPD chain stiffness (coupled unknowns), a
    stiffening quartic term (Hessian K + diag(3 c z^2), SPD, changing with z); a step limit that cuts the
    first 12 steps (0.1 ... 0.7), then lets them through."""
    import scipy.sparse as sp

    rng = np.random.default_rng(seed)
    K = sp.diags([-np.ones(n - 1), 2.05 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1], format="csr") * 10.0
    c = rng.uniform(50.0, 500.0, n)
    f = rng.uniform(-20.0, 20.0, n)

    def energy(z):
        return float(0.5 * z @ (K @ z) + 0.25 * np.sum(c * z**4) - f @ z)

    def gradient(z):
        return K @ z + c * z**3 - f

    def hessian(z, project=True):
        return (K + sp.diags(3.0 * c * z * z)).tocsr()

    cuts = iter(np.linspace(0.1, 0.7, 12))
    return energy, gradient, hessian, (lambda z, dz: next(cuts, 1.0))


def test_lagged_factorization_reaches_the_same_minimiser_with_fewer_factorisations():
    """While the step limit cuts the steps, CG on an earlier Hessian's factor replaces most
    factorisations (``NewtonResult.amg_setups`` counts them, ``cg_iterations`` the CG work); the solve
    converges to the same minimiser as the one that factorises every Hessian."""
    results = {}
    for lagged in (False, True):
        energy, gradient, hessian, limit = _coupled_quartic()
        opts = NewtonOptions(force_tolerance=1e-10, relative_tolerance=0.0, linear_solver="direct",
                             lagged_factorization=lagged)
        results[lagged] = minimize_newton(energy, gradient, hessian, np.zeros(60), np.ones(60, bool), opts,
                                          step_limit=limit)
    exact, lag = results[False], results[True]
    assert lag.converged and exact.converged
    assert np.allclose(lag.z, exact.z, rtol=0, atol=1e-10 / 10.0)
    assert lag.cg_iterations > 0
    assert lag.amg_setups < lag.iterations
    # 12 cut steps: at most every other of them factorised (a refactorisation follows a CG solve that
    # needed more than refactor_iterations, or failed), then every full step's system is factorised
    assert lag.amg_setups <= lag.iterations - 12 + 6


def test_lagged_factorization_options_are_checked():
    from headsim.errors import ParameterError

    for bad in (dict(lagged_rtol=0.0), dict(lagged_rtol=1.0), dict(lagged_max_iterations=0),
                dict(refactor_iterations=-1)):
        with pytest.raises(ParameterError):
            NewtonOptions(**bad)


def _double_well_chain(n=60, seed=1, a=0.3, n_cuts=4):
    """E(z) = 1/2 z^T K z + 1/4 sum c_i (z_i^2 - a^2)^2 - f^T z: a chain stiffness K over double wells,
    whose exact Hessian K + diag(c (3 z^2 - a^2)) is indefinite near z = 0 (the projected one clamps the
    wells' curvature at 0); a step limit cuts the first ``n_cuts`` steps. ``exact_min_eigenvalues``
    collects the smallest eigenvalue of every exact Hessian evaluated."""
    import scipy.sparse as sp

    rng = np.random.default_rng(seed)
    K = sp.diags([-np.ones(n - 1), 2.05 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1], format="csr") * 10.0
    c = rng.uniform(50.0, 500.0, n)
    f = rng.uniform(-20.0, 20.0, n)
    exact_min_eigenvalues = []

    def energy(z):
        return float(0.5 * z @ (K @ z) + 0.25 * np.sum(c * (z * z - a * a) ** 2) - f @ z)

    def gradient(z):
        return K @ z + c * z * (z * z - a * a) - f

    def hessian(z, project=True):
        d = c * (3.0 * z * z - a * a)
        h = (K + sp.diags(np.maximum(d, 0.0) if project else d)).tocsr()
        if not project:
            exact_min_eigenvalues.append(float(np.linalg.eigvalsh(h.toarray()).min()))
        return h

    cuts = iter(np.linspace(0.1, 0.7, n_cuts))
    return energy, gradient, hessian, (lambda z, dz: next(cuts, 1.0)), exact_min_eigenvalues


def test_truncated_cg_on_the_exact_hessian_reaches_the_same_minimiser_with_fewer_factorisations():
    """``lagged_exact_cg``: after full steps the exact Hessian's system is solved by CG on the kept
    projected factor, truncated at negative curvature (the exact Hessian is indefinite at some of those
    iterates here), instead of factorising the exact and then the projected Hessian. Both reach the same
    minimiser (its exact Hessian positive definite)."""
    results, eigs = {}, {}
    for truncated in (False, True):
        energy, gradient, hessian, limit, eigs[truncated] = _double_well_chain()
        opts = NewtonOptions(force_tolerance=1e-10, relative_tolerance=0.0, linear_solver="direct",
                             try_exact_hessian=True, exact_after_full_step=True, exact_only_after_full_steps=True,
                             lagged_factorization=True, lagged_exact_cg=truncated)
        results[truncated] = minimize_newton(energy, gradient, hessian, np.full(60, 0.01), np.ones(60, bool), opts,
                                             step_limit=limit)
        assert results[truncated].converged
    plain, cg = results[False], results[True]
    assert min(eigs[True]) < 0.0            # CG met an indefinite exact Hessian
    hessian(cg.z, project=False)
    assert eigs[True][-1] > 0.0             # ... and ends at a minimiser
    assert np.allclose(cg.z, plain.z, rtol=0.0, atol=1e-8)
    assert cg.amg_setups <= plain.amg_setups // 4   # factorisations (measured 17 -> 2)


def test_exact_cg_options_are_checked():
    from headsim.errors import ParameterError

    for bad in (dict(exact_cg_rtol=0.0), dict(exact_cg_rtol=1.0), dict(exact_cg_max_iterations=0)):
        with pytest.raises(ParameterError):
            NewtonOptions(**bad)
