"""Newton's method with a backtracking line search on a sparse, positive semi-definite Hessian.

Used by the implicit Euler and quasi-static solvers. The linear solve is either sparse direct
(SciPy SuperLU) or conjugate gradients preconditioned by smoothed-aggregation algebraic multigrid
(pyamg) with the rigid-body modes as near-null space; ``"auto"`` picks AMG-CG above
``amg_threshold`` unknowns (``benchmarks/bench_solver.py`` measures the two).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from headsim.errors import ConvergenceError, ParameterError


@dataclass(frozen=True)
class NewtonOptions:
    """Options of :func:`minimize_newton`.

    force_tolerance : N, converged when every free gradient entry is below it (None: relative only)
    relative_tolerance : converged when |g|_inf <= relative_tolerance * |g0|_inf
    max_iterations : Newton iterations before ConvergenceError
    linear_solver : "auto", "direct" (SuperLU) or "amg-cg" (pyamg smoothed aggregation + CG)
    amg_threshold : unknowns above which "auto" uses AMG-CG
    cg_rtol : largest relative residual of the inner CG solve; it tightens with the Newton residual
        (min(cg_rtol, |g| / |g0|), an Eisenstat-Walker-type forcing term)
    regularization : added to the Hessian diagonal, times its mean diagonal (keeps floating bodies solvable)
    try_exact_hessian : first try the unprojected Hessian (quadratic convergence where the energy is
        locally convex, e.g. compressed springs balanced by inertia); fall back to the projected one
        when that does not give a descent direction (direct solver only)
    max_step : largest change of any unknown per iteration (m), None for no limit; keeps a body that
        is not yet in contact (zero stiffness in a direction) from being thrown far away
    """

    force_tolerance: float | None = None
    relative_tolerance: float = 1e-8
    max_iterations: int = 100
    linear_solver: str = "auto"
    amg_threshold: int = 20_000
    cg_rtol: float = 1e-2
    regularization: float = 1e-10
    max_line_search: int = 40
    max_step: float | None = None
    try_exact_hessian: bool = False

    def __post_init__(self):
        if self.linear_solver not in ("auto", "direct", "amg-cg"):
            raise ParameterError(f"linear_solver must be auto, direct or amg-cg, got {self.linear_solver!r}")
        if self.max_iterations < 1 or self.relative_tolerance < 0:
            raise ParameterError("max_iterations must be >= 1 and relative_tolerance >= 0")


@dataclass(frozen=True)
class NewtonResult:
    z: np.ndarray          # solution (N,)
    iterations: int
    gradient_norm: float   # |g_free|_inf at the solution
    energy: float
    linear_solver: str


def rigid_body_modes(positions: np.ndarray) -> np.ndarray:
    """(3n, 6) translations and infinitesimal rotations of a point set (AMG near-null space)."""
    x = np.asarray(positions) - np.mean(positions, axis=0)
    n = len(x)
    b = np.zeros((n, 3, 6))
    for c in range(3):
        b[:, c, c] = 1.0
    b[:, 1, 3], b[:, 2, 3] = -x[:, 2], x[:, 1]
    b[:, 0, 4], b[:, 2, 4] = x[:, 2], -x[:, 0]
    b[:, 0, 5], b[:, 1, 5] = -x[:, 1], x[:, 0]
    return b.reshape(3 * n, 6)


def solve_spd(a: sp.csr_matrix, b: np.ndarray, method: str, near_null: np.ndarray | None = None,
              cg_rtol: float = 1e-2, cache: dict | None = None) -> np.ndarray:
    """Solve the SPD system a x = b by SuperLU ("direct") or pyamg SA-preconditioned CG ("amg-cg").

    With a ``cache`` dict, the AMG hierarchy of an earlier matrix of the same size is reused as the
    preconditioner (Newton's Hessians change little between iterations); it is rebuilt when CG needs
    more than 60 iterations.
    """
    if method == "direct":
        return spla.spsolve(a.tocsc(), b, permc_spec="MMD_AT_PLUS_A")
    import pyamg

    a = a.tocsr()
    ml = cache.get("amg") if cache is not None else None
    if ml is not None and ml.levels[0].A.shape == a.shape:
        count = [0]
        x, info = spla.cg(a, b, rtol=cg_rtol, maxiter=60, M=ml.aspreconditioner(cycle="V"),
                          callback=lambda _: count.__setitem__(0, count[0] + 1))
        if info == 0:
            return x
    ml = pyamg.smoothed_aggregation_solver(a, B=near_null, symmetry="symmetric", max_coarse=500, max_levels=20,
                                           coarse_solver="splu")
    if cache is not None:
        cache["amg"] = ml
    x = ml.solve(b, tol=cg_rtol, accel="cg", maxiter=500)
    return np.asarray(x)


def _call_hessian(hessian, z, project):
    try:
        return hessian(z, project=project)
    except TypeError:
        return hessian(z)


def minimize_newton(
    energy: Callable[[np.ndarray], float],
    gradient: Callable[[np.ndarray], np.ndarray],
    hessian: Callable[[np.ndarray], sp.spmatrix],
    z0: np.ndarray,
    free: np.ndarray,
    options: NewtonOptions = NewtonOptions(),
    near_null: Callable[[np.ndarray], np.ndarray] | None = None,
    what: str = "Newton solve",
) -> NewtonResult:
    """Minimise ``energy`` over the entries of ``z`` where ``free`` is True.

    energy(z) -> float (may return inf for an inadmissible z, e.g. inverted tets: the line search
    then backtracks); gradient(z) -> (N,); hessian(z, project=True) -> (N, N) sparse, PSD when projected. Raises ConvergenceError
    when the gradient does not fall below the tolerance within ``options.max_iterations``.
    """
    z = np.array(z0, dtype=np.float64)
    free = np.asarray(free, dtype=bool)
    idx = np.flatnonzero(free)
    method = options.linear_solver
    if method == "auto":
        method = "amg-cg" if len(idx) > options.amg_threshold else "direct"
    e = energy(z)
    if not np.isfinite(e):
        raise ConvergenceError(f"{what}: the starting point has non-finite energy")
    g = gradient(z)[idx]
    g0 = float(np.max(np.abs(g))) if len(g) else 0.0
    tol = options.relative_tolerance * g0
    if options.force_tolerance is not None:
        tol = max(tol, options.force_tolerance)
    gnorm = g0
    amg_cache: dict = {}
    for it in range(options.max_iterations):
        if gnorm <= tol:
            return NewtonResult(z, it, gnorm, e, method)
        nn = near_null(z)[idx] if (near_null is not None and method == "amg-cg") else None
        for project in ((False, True) if options.try_exact_hessian and method == "direct" else (True,)):
            h = _call_hessian(hessian, z, project).tocsr()[idx][:, idx]
            diag = h.diagonal()
            reg = options.regularization * (float(np.mean(np.abs(diag))) or 1.0)
            h = h + sp.identity(len(idx), format="csr") * reg
            with np.errstate(all="ignore"):
                # inexact Newton (Eisenstat-Walker-type forcing): loose CG far from the solution
                eta = min(options.cg_rtol, max(gnorm / g0, 1e-10)) if g0 > 0 else options.cg_rtol
                dz = solve_spd(h, -g, method, nn, eta, amg_cache)
            slope = float(g @ dz)
            if np.isfinite(dz).all() and slope < 0:
                break
        if not np.isfinite(dz).all() or slope >= 0:  # not a descent direction: fall back to gradient
            dz = -g / (np.abs(diag) + reg)
            slope = float(g @ dz)
        if float(np.max(np.abs(dz))) <= 4 * np.finfo(float).eps * max(1.0, float(np.max(np.abs(z[idx])))):
            # the Newton step is below the round-off of the unknowns: nothing more can be gained
            return NewtonResult(z, it, gnorm, e, method)
        step = 1.0
        if options.max_step is not None:
            big = float(np.max(np.abs(dz))) if len(dz) else 0.0
            if big > options.max_step:
                step = options.max_step / big
        gt = None
        for trial in range(options.max_line_search):
            zt = z.copy()
            zt[idx] += step * dz
            et = energy(zt)
            if np.isfinite(et) and et <= e + 1e-4 * step * slope:
                break
            if trial == 0 and step == 1.0 and np.isfinite(et):
                # near the solution the energy decrease can drown in round-off; a full Newton step
                # that halves the gradient is accepted (local quadratic convergence)
                gt = gradient(zt)[idx]
                if float(np.max(np.abs(gt))) < 0.5 * gnorm:
                    break
                gt = None
            step *= 0.5
        else:
            # energy stagnates at round-off: accept if the gradient is already small relative to the start
            if gnorm <= max(tol, 1e-6 * g0):
                return NewtonResult(z, it, gnorm, e, method)
            raise ConvergenceError(f"{what}: line search failed at iteration {it} (|g| = {gnorm:.3g} N)")
        z, e = zt, et
        g = gt if gt is not None else gradient(z)[idx]
        gnorm = float(np.max(np.abs(g)))
    if gnorm <= tol:
        return NewtonResult(z, options.max_iterations, gnorm, e, method)
    raise ConvergenceError(
        f"{what}: no convergence in {options.max_iterations} iterations (|g|_inf = {gnorm:.3g} N, "
        f"tolerance {tol:.3g} N)")
