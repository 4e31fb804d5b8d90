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
