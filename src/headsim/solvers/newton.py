"""Newton's method with a backtracking line search on a sparse, positive semi-definite Hessian.

Used by the implicit Euler and quasi-static solvers. The linear solve is either sparse direct
(SciPy SuperLU, symmetric mode) or conjugate gradients preconditioned by smoothed-aggregation algebraic multigrid
(pyamg) with the rigid-body modes as near-null space; ``"auto"`` picks AMG-CG above
``amg_threshold`` unknowns (``benchmarks/bench_solver.py`` measures the two).

What makes it fast (profiled on the two-20k-tet-body benchmark; CPU s per phase in
``NewtonResult.timings``):

- the direct solve factorises in SuperLU's symmetric mode (diagonal pivots on the minimum-degree
  ordering of A + A^T, :func:`factorize_spd`), checked by its residual: on the mask-fit Hessians
  (10.3k unknowns) 3.8x faster than SuperLU's default partial pivoting, with half the fill
  (``benchmarks/bench_mask.py``);
- BLAS is held to one thread inside the solve (threadpoolctl): the level-1 BLAS calls of CG and of
  pyamg's set-up are too short to gain from threads, and OpenBLAS's spinning threads made them 4x
  slower on a loaded 2-core machine;
- the AMG hierarchy is built once and reused for the later Newton iterations (and, through
  ``amg_cache``, across the outer contact loop), rebuilt only when CG with it needs more than
  ``amg_rebuild_iterations``; the V-cycle is applied directly, without pyamg's per-call residuals;
- inexact Newton: the CG tolerance follows Eisenstat & Walker (1996), choice 2;
- the free-dof block of the Hessian is cut with an index map kept while the sparsity pattern stays
  the same, and the regularisation is added on its diagonal in place;
- (in :mod:`headsim.solvers.fem`) element Hessians are projected through the analytic eigensystem
  of the stable neo-Hookean energy and scattered into a fixed CSR pattern by a Numba kernel.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field
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
    amg_threshold : unknowns above which "auto" uses AMG-CG (measured crossover: at 6.9k unknowns
        AMG-CG is 2.5x faster than SuperLU on the FEM Hessian, at 43k 16x; bench_solver.py)
    amg_threshold_exact : the same when ``try_exact_hessian`` is set (the exact, possibly indefinite
        Hessian needs a factorisation, and the mask fit measured 18 Newton iterations with it against
        73 with the projected Hessian and AMG-CG, so "auto" keeps the direct solver longer there)
    cg_rtol : largest relative residual of the inner CG solve (the Eisenstat-Walker forcing term,
        choice 2, tightens it as the Newton residual falls)
    amg_rebuild_iterations : CG iterations with a reused AMG hierarchy above which it is rebuilt
    blas_threads : BLAS threads inside the solve (threadpoolctl); None leaves the process setting
    regularization : added to the Hessian diagonal, times its mean diagonal (keeps floating bodies solvable)
    try_exact_hessian : first try the unprojected Hessian (quadratic convergence where the energy is
        locally convex, e.g. compressed springs balanced by inertia); fall back to the projected one
        when that does not give a descent direction (direct solver only)
    max_step : largest change of any unknown per iteration (m), None for no limit; keeps a body that
        is not yet in contact (zero stiffness in a direction) from being thrown far away
    exact_after_full_step : with ``try_exact_hessian`` and a ``step_limit`` (barrier contact), use
        the projected Hessian while the step limit cuts the Newton step (the contact set is still
        forming and the exact Hessian's negative curvature only sends the step into the next
        collision), and try the exact Hessian only from the first iteration whose full step was
        admissible (local quadratic convergence where the projection would make it linear).
        Measured on the mask fit's barrier contact (demo configuration, cold fits at 10 / 15 / 20 N):
        61 / 98 / 138 Newton iterations against 83 / 126 / 159 with the exact Hessian tried at every
        iteration and 186 at 15 N with the projected one only (its local convergence is linear)
    exact_only_after_full_steps : with ``exact_after_full_step``: try the exact Hessian only on the
        iterations that follow a full (uncut) step, going back to the projected one (and to
        ``lagged_factorization``) whenever the step limit cuts a step again. On the mask fit the contact
        set keeps changing after the first full step (30 N from a 10 N start: 110 of 168 iterations
        after it, a third of them cut by CCD, 40 with an exact Hessian that was no descent direction)
    lagged_factorization : direct solver only, with a ``step_limit``: while the step limit cuts the steps
        (the last step's admissible fraction < 1), solve the Newton system by CG preconditioned with the
        sparse factorisation of an earlier (projected, SPD) Hessian, to ``lagged_rtol``, and factorise
        anew only where that CG needs more than ``lagged_max_iterations`` iterations, breaks down, or
        its last solve needed more than ``refactor_iterations``; once a full step is admissible every
        system is factorised (the exact solve for local quadratic convergence). A step that CCD cuts to
        a few per cent gains nothing from an exact direction, and a forward/back substitution costs far
        less than a factorisation (mask fit, 10.3k unknowns: 2 ms against 0.11 s). The CG direction
        from a zero start is a descent direction of an SPD system at every iteration.
    lagged_rtol, lagged_max_iterations, refactor_iterations : see ``lagged_factorization``
    lagged_exact_cg : with ``lagged_factorization`` and ``try_exact_hessian``: the exact (possibly
        indefinite) Hessian's system is solved by truncated CG (Steihaug 1983) preconditioned with the
        kept factorisation of an earlier projected Hessian, to ``exact_cg_rtol``: CG stops where it meets
        negative curvature and returns its last iterate, a descent direction, so neither the exact
        Hessian nor (where it is indefinite) the projected one is factorised. It falls back to the
        factorisations where CG gives no descent direction (negative curvature at its first iteration).
        Measured on the mask fit (demo problem, cold 15 N): 121 -> 94 Newton iterations, 99 -> 30
        factorisations, 23.3 -> 12.9 s; the exact Hessian was indefinite on 17 of the 18 tail solves
    exact_cg_rtol, exact_cg_max_iterations : see ``lagged_exact_cg``
    stall_tolerance : N or None. Where the line search finds no decrease at all -- the energy and its
        gradient jump at the iterate, so that even a vanishing step raises the energy (a contact set
        whose pairs switch type: ipctk's improved-max approximation, :mod:`headsim.mask.fit`
        "Barrier contact") -- the solve ends there if |g|_inf <= this, reported as not converged
        (``NewtonResult.converged`` False, ``gradient_norm`` the residual); None: it fails
        (ConvergenceError), as where |g|_inf is larger
    """

    force_tolerance: float | None = None
    relative_tolerance: float = 1e-8
    max_iterations: int = 100
    linear_solver: str = "auto"
    amg_threshold: int = 5_000
    amg_threshold_exact: int = 20_000
    cg_rtol: float = 1e-2
    regularization: float = 1e-10
    max_line_search: int = 40
    max_step: float | None = None
    try_exact_hessian: bool = False
    exact_after_full_step: bool = False
    amg_rebuild_iterations: int = 40
    blas_threads: int | None = 1
    stall_tolerance: float | None = None
    exact_only_after_full_steps: bool = False
    lagged_factorization: bool = False
    lagged_rtol: float = 0.2
    lagged_max_iterations: int = 20
    refactor_iterations: int = 6
    lagged_exact_cg: bool = False
    exact_cg_rtol: float = 1e-3
    exact_cg_max_iterations: int = 30

    def __post_init__(self):
        if self.linear_solver not in ("auto", "direct", "amg-cg"):
            raise ParameterError(f"linear_solver must be auto, direct or amg-cg, got {self.linear_solver!r}")
        if self.max_iterations < 1 or self.relative_tolerance < 0:
            raise ParameterError("max_iterations must be >= 1 and relative_tolerance >= 0")
        if not 0.0 < self.lagged_rtol < 1.0 or self.lagged_max_iterations < 1 or self.refactor_iterations < 0:
            raise ParameterError("lagged_rtol must lie in (0, 1), lagged_max_iterations >= 1 and "
                                 "refactor_iterations >= 0")
        if not 0.0 < self.exact_cg_rtol < 1.0 or self.exact_cg_max_iterations < 1:
            raise ParameterError("exact_cg_rtol must lie in (0, 1) and exact_cg_max_iterations >= 1")


@dataclass(frozen=True)
class NewtonResult:
    z: np.ndarray          # solution (N,)
    iterations: int
    gradient_norm: float   # |g_free|_inf at the solution
    energy: float
    linear_solver: str
    timings: dict = field(default_factory=dict)  # CPU s per phase (energy, gradient, hessian, free_block,
    #                                               linear_solve, line_search; amg_setup and cg within it)
    cg_iterations: int = 0
    amg_setups: int = 0                 # AMG hierarchies built, or with lagged_factorization: factorisations
    tolerance: float = 0.0  # the |g|_inf the solve aimed at (N); above it only where the energy
    #                         stagnated at round-off (accepted for |g| <= 1e-6 |g0|) or the step vanished

    @property
    def converged(self) -> bool:
        """|g|_inf reached the tolerance (False: stopped at round-off above it)."""
        return self.gradient_norm <= self.tolerance


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


def pcg(a, b: np.ndarray, apply: Callable[[np.ndarray], np.ndarray], rtol: float, maxiter: int,
        x0: np.ndarray | None = None) -> tuple[np.ndarray, int, bool]:
    """Preconditioned CG with the SPD preconditioner ``apply(r) ~ A^-1 r``; returns (x, iterations,
    converged). Stops at |r| <= rtol |b| (2-norms), or unconverged where p^T A p or r^T z is not positive
    (A or the preconditioner is not positive definite) with the last iterate: from a zero start every
    iterate is a descent direction of the quadratic model, also for an indefinite A (truncated CG,
    Steihaug 1983)."""
    bnorm = float(np.linalg.norm(b))
    x = np.zeros_like(b) if x0 is None else x0.copy()
    if bnorm == 0.0:
        return x, 0, True
    r = b - a @ x if x0 is not None else b.copy()
    z = apply(r)
    p = z.copy()
    rz = float(r @ z)
    target = rtol * bnorm
    if not rz > 0.0:
        return x, 0, False
    for it in range(1, maxiter + 1):
        ap = a @ p
        pap = float(p @ ap)
        if not pap > 0.0:  # lost positive definiteness (or breakdown)
            return x, it, False
        alpha = rz / pap
        x += alpha * p
        r -= alpha * ap
        if float(np.linalg.norm(r)) <= target:
            return x, it, True
        z = apply(r)
        rz_new = float(r @ z)
        if not rz_new > 0.0:
            return x, it, False
        p *= rz_new / rz
        p += z
        rz = rz_new
    return x, maxiter, False


class AmgPreconditioner:
    """Smoothed-aggregation AMG (pyamg) V-cycle for CG, with the hierarchy kept across Newton iterations.

    Newton's Hessians change little from one iteration to the next, so the hierarchy of an earlier
    matrix stays a good preconditioner: :meth:`solve` runs CG on the new matrix with the old
    hierarchy and rebuilds it (``setups`` counts the builds) only when CG needs more than
    ``rebuild_iterations`` iterations or does not converge. The V-cycle (symmetric Gauss-Seidel pre-
    and post-smoothing, sparse LU on the coarsest level) is applied directly, without pyamg's
    per-call residual norms.
    """

    def __init__(self, near_null: np.ndarray | None = None, rebuild_iterations: int = 40, max_iterations: int = 500):
        self.near_null = near_null
        self.rebuild_iterations = rebuild_iterations
        self.max_iterations = max_iterations
        self.ml = None
        self.setups = 0
        self.iterations = 0        # CG iterations over all solves
        self.setup_seconds = 0.0   # CPU s spent building hierarchies
        self.solve_seconds = 0.0   # CPU s spent in CG

    def build(self, a: sp.csr_matrix, near_null: np.ndarray | None = None) -> None:
        import pyamg

        t = time.process_time()
        if near_null is not None:
            self.near_null = near_null
        self.ml = pyamg.smoothed_aggregation_solver(a, B=self.near_null, symmetry="symmetric", max_coarse=500,
                                                    max_levels=20, coarse_solver="splu")
        self.setups += 1
        self.setup_seconds += time.process_time() - t

    def _vcycle(self, lvl: int, b: np.ndarray) -> np.ndarray:
        levels = self.ml.levels
        level = levels[lvl]
        x = np.zeros_like(b)
        level.presmoother(level.A, x, b)
        coarse_b = level.R @ (b - level.A @ x)
        if lvl == len(levels) - 2:
            coarse_x = self.ml.coarse_solver(levels[-1].A, coarse_b)
        else:
            coarse_x = self._vcycle(lvl + 1, coarse_b)
        x += level.P @ coarse_x
        level.postsmoother(level.A, x, b)
        return x

    def apply(self, r: np.ndarray) -> np.ndarray:
        """One V-cycle from a zero guess: an SPD approximation of A^-1 r."""
        if len(self.ml.levels) == 1:
            return np.asarray(self.ml.coarse_solver(self.ml.levels[0].A, r))
        return self._vcycle(0, r)

    def _pcg(self, a, b, rtol, maxiter, x0=None):
        return pcg(a, b, self.apply, rtol, maxiter, x0)

    def solve(self, a: sp.csr_matrix, b: np.ndarray, rtol: float, near_null: np.ndarray | None = None) -> np.ndarray:
        t = time.process_time()
        x = None
        if self.ml is not None and self.ml.levels[0].A.shape == a.shape:
            self.ml.levels[0].A = a  # the finest level is the current matrix; coarse levels are kept
            x, its, ok = self._pcg(a, b, rtol, self.rebuild_iterations)
            self.iterations += its
            if ok:
                self.solve_seconds += time.process_time() - t
                return x
        self.solve_seconds += time.process_time() - t
        self.build(a, near_null)
        t = time.process_time()
        x, its, ok = self._pcg(a, b, rtol, self.max_iterations, x0=x)
        self.iterations += its
        self.solve_seconds += time.process_time() - t
        return x


#: relative residual |b - A x| / |b| above which a symmetric-mode solve is refined once
_REFINE_RTOL = float(np.sqrt(np.finfo(float).eps))
#: relative residual above which a (refined) symmetric-mode solve is not trusted and redone with partial
#: pivoting: the accuracy the inexact (AMG-CG) Newton steps accept (``NewtonOptions.cg_rtol``'s default)
SYMMETRIC_MODE_RTOL = 1e-2


def factorize_spd(a: sp.spmatrix):
    """Sparse LU (SciPy SuperLU) of a symmetric matrix with symmetric pivoting: a ``SuperLU`` object.

    SuperLU's symmetric mode (``SymmetricMode=True``, ``diag_pivot_thresh=0``) takes the pivots from
    the diagonal in the order of a minimum-degree ordering of A + A^T, so the factor keeps the fill of
    that ordering; the default threshold partial pivoting trades rows away from it for stability,
    which an SPD matrix does not need. Measured on the mask-fit Hessians (10.3k unknowns, 0.30 M
    nonzeros): fill 2.5 M against 5.4 M entries, factorisation 0.19 s against 0.50 s CPU, relative
    residuals as small. Raises RuntimeError where a pivot is exactly zero.
    """
    return spla.splu(sp.csc_matrix(a), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                     options=dict(SymmetricMode=True))


def solve_direct(a: sp.spmatrix, b: np.ndarray, rtol: float = SYMMETRIC_MODE_RTOL) -> np.ndarray:
    """x with A x = b for a symmetric (SPD or mildly indefinite) sparse A, by :func:`factorize_spd`.

    Static (symmetric) pivoting is not backward stable where A is indefinite, so, as SuperLU_DIST
    does with its static pivots (Li & Demmel, "Making sparse Gaussian elimination scalable by static
    pivoting", SC 1998), the residual is checked: one step of iterative refinement where it exceeds
    sqrt(eps) |b|, and where it still exceeds ``rtol`` |b| (or a pivot is zero) the solve is redone with
    SuperLU's threshold partial pivoting (non-finite entries then tell the caller that A is singular).
    """
    return _solve_direct_factor(a, b, rtol)[0]


def _solve_direct_factor(a: sp.spmatrix, b: np.ndarray, rtol: float = SYMMETRIC_MODE_RTOL):
    """:func:`solve_direct`, returning (x, the symmetric-mode factor, or None where it was not trusted)."""
    a = sp.csc_matrix(a)
    b = np.asarray(b, dtype=np.float64)
    bnorm = float(np.linalg.norm(b))
    try:
        with np.errstate(all="ignore"):
            lu = factorize_spd(a)
            x = lu.solve(b)
            r = b - a @ x
            if not float(np.linalg.norm(r)) <= _REFINE_RTOL * bnorm:
                x = x + lu.solve(r)
                r = b - a @ x
            ok = np.isfinite(x).all() and float(np.linalg.norm(r)) <= rtol * bnorm
    except RuntimeError:  # exactly zero pivot
        ok = False
    if ok:
        return x, lu
    return spla.spsolve(a, b, permc_spec="MMD_AT_PLUS_A"), None


class LaggedFactorization:
    """Direct Newton solves that reuse an earlier Hessian's factorisation as a CG preconditioner
    (:attr:`NewtonOptions.lagged_factorization`). ``factorizations`` and ``cg_iterations`` count the work."""

    def __init__(self, rtol: float, max_iterations: int, refactor_iterations: int,
                 exact_rtol: float | None = None, exact_max_iterations: int = 30):
        self.rtol = rtol
        self.max_iterations = max_iterations
        self.refactor_iterations = refactor_iterations
        self.exact_rtol = exact_rtol
        self.exact_max_iterations = exact_max_iterations
        self.lu = None
        self.last_iterations = 0
        self.factorizations = 0
        self.cg_iterations = 0

    def _usable(self, a) -> bool:
        """A factor is kept and fits ``a``'s size (a preconditioner for it)."""
        return self.lu is not None and self.lu.shape == a.shape

    def solve(self, a: sp.spmatrix, b: np.ndarray, lagged: bool, keep: bool) -> np.ndarray:
        """x with A x = b: by CG on the kept factor where ``lagged`` and it is usable, else factorised
        (kept for later solves where ``keep``: only factors of SPD, i.e. projected, Hessians). With
        ``exact_rtol`` a system that is not kept (the exact Hessian) is first tried by truncated CG on
        the kept factor (:attr:`NewtonOptions.lagged_exact_cg`)."""
        if lagged and self._usable(a) and self.last_iterations <= self.refactor_iterations:
            x, its, ok = pcg(a, b, self.lu.solve, self.rtol, self.max_iterations)
            self.cg_iterations += its
            if ok and np.isfinite(x).all():
                self.last_iterations = its
                return x
        if not keep and self.exact_rtol is not None and self._usable(a):
            x, its, _ = pcg(a, b, self.lu.solve, self.exact_rtol, self.exact_max_iterations)
            self.cg_iterations += its
            if np.isfinite(x).all() and float(b @ x) > 0.0:
                return x
        x, lu = _solve_direct_factor(a, b)
        self.factorizations += 1
        self.last_iterations = 0
        if keep:
            self.lu = lu
        return x


def solve_spd(a: sp.csr_matrix, b: np.ndarray, method: str, near_null: np.ndarray | None = None,
              cg_rtol: float = 1e-2, cache: dict | None = None) -> np.ndarray:
    """Solve the SPD system a x = b by SuperLU ("direct") or pyamg SA-preconditioned CG ("amg-cg").

    With a ``cache`` dict, the AMG hierarchy of an earlier matrix of the same size is reused as the
    preconditioner (see :class:`AmgPreconditioner`).
    """
    if method == "direct":
        return solve_direct(a, b)
    a = a.tocsr()
    pre = cache.get("amg") if cache is not None else None
    if pre is None:
        pre = AmgPreconditioner(near_null)
        if cache is not None:
            cache["amg"] = pre
    return pre.solve(a, b, cg_rtol, near_null)


def _call_hessian(hessian, z, project):
    try:
        return hessian(z, project=project)
    except TypeError:
        return hessian(z)


class _FreeBlock:
    """Extracts the free-dof block A[idx][:, idx] of CSR matrices, reusing the index map while the
    sparsity pattern stays the same (it does within a Newton solve unless contacts open or close)."""

    def __init__(self, free: np.ndarray):
        self.free = free
        self.remap = np.full(len(free), -1, dtype=np.int64)
        self.remap[free] = np.arange(int(free.sum()))
        self.key = None

    def __call__(self, h: sp.csr_matrix) -> sp.csr_matrix:
        h = h.tocsr()
        if not h.has_sorted_indices:
            h.sort_indices()
        n = int(self.free.sum())
        if self.key is not None and self.key[0].shape == h.indptr.shape and self.key[1].shape == h.indices.shape \
                and np.array_equal(self.key[0], h.indptr) and np.array_equal(self.key[1], h.indices):
            keep, indices, indptr, diag = self.keep, self.indices, self.indptr, self.diag
        else:
            rows = np.repeat(np.arange(h.shape[0]), np.diff(h.indptr))
            keep = self.free[rows] & self.free[h.indices]
            indices = self.remap[h.indices[keep]].astype(h.indices.dtype)
            counts = np.bincount(self.remap[rows[keep]], minlength=n)
            indptr = np.concatenate([[0], np.cumsum(counts)]).astype(h.indptr.dtype)
            new_rows = np.repeat(np.arange(n), counts)
            diag = np.flatnonzero(new_rows == indices)
            if len(diag) != n:
                diag = None
            self.key = (h.indptr.copy(), h.indices.copy())
            self.keep, self.indices, self.indptr, self.diag = keep, indices, indptr, diag
        out = sp.csr_matrix((h.data[keep], indices, indptr), shape=(n, n))
        return out

    def add_to_diagonal(self, a: sp.csr_matrix, value: float) -> sp.csr_matrix:
        if self.diag is not None:
            a.data[self.diag] += value
            return a
        return a + sp.identity(a.shape[0], format="csr") * value


@contextmanager
def blas_threads(n: int | None):
    """Limit BLAS threads inside the block (None: leave as is). The vectors of a Newton solve are too
    short to gain from threaded level-1 BLAS, and OpenBLAS threads spin-wait on a loaded machine."""
    if n is None:
        yield
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=n, user_api="blas"):
        yield


class _PhaseTimer:
    """CPU seconds (time.process_time) per phase."""

    def __init__(self):
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, phase: str):
        t = time.process_time()
        try:
            yield
        finally:
            self.seconds[phase] = self.seconds.get(phase, 0.0) + time.process_time() - t


def minimize_newton(
    energy: Callable[[np.ndarray], float],
    gradient: Callable[[np.ndarray], np.ndarray],
    hessian: Callable[[np.ndarray], sp.spmatrix],
    z0: np.ndarray,
    free: np.ndarray,
    options: NewtonOptions = NewtonOptions(),
    near_null: Callable[[np.ndarray], np.ndarray] | None = None,
    what: str = "Newton solve",
    amg_cache: dict | None = None,
    step_limit: Callable[[np.ndarray, np.ndarray], float] | None = None,
    progress: Callable[[int, float, float], None] | None = None,
) -> NewtonResult:
    """Minimise ``energy`` over the entries of ``z`` where ``free`` is True.

    energy(z) -> float (may return inf for an inadmissible z, e.g. inverted tets: the line search
    then backtracks); gradient(z) -> (N,); hessian(z, project=True) -> (N, N) sparse, PSD when projected. Raises ConvergenceError
    when the gradient does not fall below the tolerance within ``options.max_iterations``.
    ``amg_cache``: a dict kept by the caller to reuse the AMG hierarchy across solves (e.g. the
    outer contact loop). ``step_limit(z, dz)`` -> largest admissible fraction of the step ``dz`` (in
    (0, 1]; e.g. the collision-free step of a barrier contact's continuous collision detection, Li et
    al. 2020 sec. 4.3): the line search starts there. The result carries CPU seconds per phase
    (``timings``). ``progress(iteration, |g|_inf, tolerance)`` (N) is called before every iteration
    (a progress display for long solves).
    """
    with blas_threads(options.blas_threads):
        return _minimize_newton(energy, gradient, hessian, z0, free, options, near_null, what,
                                {} if amg_cache is None else amg_cache, step_limit, progress)


def _forcing_term(options: NewtonOptions, g2: float, g2_prev: float | None, eta_prev: float | None,
                  tol2: float) -> float:
    """Eisenstat & Walker (1996) choice 2: eta = gamma (|g_k| / |g_k-1|)^2 with their safeguard, capped
    at ``cg_rtol`` and kept above 0.5 tol / |g| so that the last iterations do not over-solve."""
    if g2_prev is None or eta_prev is None:
        eta = options.cg_rtol
    else:
        eta = 0.9 * (g2 / g2_prev) ** 2
        if 0.9 * eta_prev**2 > 0.1:
            eta = max(eta, 0.9 * eta_prev**2)
    eta = min(eta, options.cg_rtol)
    if g2 > 0:
        eta = max(eta, 0.5 * tol2 / g2)
    return float(min(max(eta, 1e-12), options.cg_rtol))


def _minimize_newton(energy, gradient, hessian, z0, free, options, near_null, what, amg_cache,
                     step_limit=None, progress=None) -> NewtonResult:
    timer = _PhaseTimer()
    z = np.array(z0, dtype=np.float64)
    free = np.asarray(free, dtype=bool)
    idx = np.flatnonzero(free)
    method = options.linear_solver
    if method == "auto":
        limit = options.amg_threshold_exact if options.try_exact_hessian else options.amg_threshold
        method = "amg-cg" if len(idx) > limit else "direct"
    with timer("energy"):
        e = energy(z)
    if not np.isfinite(e):
        raise ConvergenceError(f"{what}: the starting point has non-finite energy")
    with timer("gradient"):
        g = gradient(z)[idx]
    g0 = float(np.max(np.abs(g))) if len(g) else 0.0
    tol = options.relative_tolerance * g0
    if options.force_tolerance is not None:
        tol = max(tol, options.force_tolerance)
    gnorm = g0
    block = _FreeBlock(free)
    pre = amg_cache.get("amg")
    if method == "amg-cg" and pre is None:
        pre = amg_cache["amg"] = AmgPreconditioner(rebuild_iterations=options.amg_rebuild_iterations)
    cg0 = pre.iterations if pre is not None else 0
    setups0 = pre.setups if pre is not None else 0
    g2_prev = eta = None
    # exact Hessians are tried from the start unless they wait for the step limit to let a full step through
    exact_now = not (options.exact_after_full_step and step_limit is not None)
    lagged = (LaggedFactorization(options.lagged_rtol, options.lagged_max_iterations, options.refactor_iterations,
                                  options.exact_cg_rtol if options.lagged_exact_cg else None,
                                  options.exact_cg_max_iterations)
              if options.lagged_factorization and method == "direct" and step_limit is not None else None)
    step_cut = False  # the last step was cut by the step limit (lagged_factorization)

    def result(it):
        t = dict(timer.seconds)
        if pre is not None:
            t["amg_setup"] = pre.setup_seconds
            t["cg"] = pre.solve_seconds
        if lagged is not None:
            cg, setups = lagged.cg_iterations, lagged.factorizations
        else:
            cg, setups = ((pre.iterations - cg0), (pre.setups - setups0)) if pre is not None else (0, 0)
        return NewtonResult(z, it, gnorm, e, method, t, cg, setups, tol)

    for it in range(options.max_iterations):
        if progress is not None:
            progress(it, gnorm, tol)
        if gnorm <= tol:
            return result(it)
        g2 = float(np.linalg.norm(g))
        exact = options.try_exact_hessian and method == "direct" and exact_now
        for project in ((False, True) if exact else (True,)):
            with timer("hessian"):
                hfull = _call_hessian(hessian, z, project)
            with timer("free_block"):
                h = block(hfull)
                diag = h.diagonal()
                reg = options.regularization * (float(np.mean(np.abs(diag))) or 1.0)
                h = block.add_to_diagonal(h, reg)
            with np.errstate(all="ignore"):
                if method == "direct":
                    with timer("linear_solve"):
                        if lagged is not None:
                            dz = lagged.solve(h, -g, step_cut and project, project)
                        else:
                            dz = solve_direct(h, -g)
                else:
                    # inexact Newton: Eisenstat-Walker forcing term for the CG tolerance
                    eta = _forcing_term(options, g2, g2_prev, eta, tol * np.sqrt(max(len(idx), 1)))
                    nn = near_null(z)[idx] if near_null is not None else None
                    with timer("linear_solve"):
                        dz = pre.solve(h, -g, eta, nn)
            slope = float(g @ dz)
            if np.isfinite(dz).all() and slope < 0:
                break
        g2_prev = g2
        if not np.isfinite(dz).all() or slope >= 0:  # not a descent direction: fall back to gradient
            dz = -g / (np.abs(diag) + reg)
            slope = float(g @ dz)
        if float(np.max(np.abs(dz))) <= 4 * np.finfo(float).eps * max(1.0, float(np.max(np.abs(z[idx])))):
            # the Newton step is below the round-off of the unknowns: nothing more can be gained
            return result(it)
        step = 1.0
        if options.max_step is not None:
            big = float(np.max(np.abs(dz))) if len(dz) else 0.0
            if big > options.max_step:
                step = options.max_step / big
        if step_limit is not None:
            with timer("step_limit"):
                full = np.zeros_like(z)
                full[idx] = step * dz
                fraction = float(step_limit(z, full))
                step *= fraction
                step_cut = fraction < 1.0
                if options.exact_only_after_full_steps:
                    exact_now = fraction >= 1.0
                else:
                    exact_now = exact_now or fraction >= 1.0
            if step <= 0.0:
                raise ConvergenceError(f"{what}: no admissible step at iteration {it} (|g| = {gnorm:.3g} N)")
        gt = None
        with timer("line_search"):
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
                    return result(it)
                if options.stall_tolerance is not None and gnorm <= options.stall_tolerance:
                    return result(it)   # stalled at a jump of the energy (stall_tolerance)
                raise ConvergenceError(f"{what}: line search failed at iteration {it} (|g| = {gnorm:.3g} N)")
        z, e = zt, et
        with timer("gradient"):
            g = gt if gt is not None else gradient(z)[idx]
        gnorm = float(np.max(np.abs(g)))
    if gnorm <= tol:
        return result(options.max_iterations)
    raise ConvergenceError(
        f"{what}: no convergence in {options.max_iterations} iterations (|g|_inf = {gnorm:.3g} N, "
        f"tolerance {tol:.3g} N)")
