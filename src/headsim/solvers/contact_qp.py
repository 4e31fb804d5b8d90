"""Frictionless contact of condensed linear bodies under force control: an LCP with rigid unknowns.

Unknowns: ``m`` normal contact forces ``lam`` (N, >= 0) at paired candidate points and ``r`` rigid
coordinates ``q`` of a force-driven body (m, e.g. a translation and rotations as arc lengths).
With the condensed compliance ``W`` (m/N, :mod:`headsim.solvers.condensation`, both bodies' added),
the initial gaps ``g0`` (m) and the rigid Jacobian ``J`` (m, r) (how much gap i closes per unit of
q_k), the gaps are

    g = g0 - J q + W lam,

and the contact conditions with the generalised load ``f`` (r,) on the driven body are

    lam >= 0,   g >= 0,   lam_i g_i = 0   (Signorini, complementarity),
    J^T lam = f                           (equilibrium of the driven body).

These are the KKT conditions of the convex QP  min 1/2 lam^T W lam + lam^T g0  s.t. lam >= 0,
J^T lam = f  (the dual of the potential-energy minimisation; q is the multiplier of the equality,
Kwon et al. 2022 solve mask fits this way with Lagrange multipliers). Solved by the primal-dual
active-set method (Hintermueller, Ito & Kunisch, SIAM J. Optim. 13 (2002) 865-888; a semi-smooth
Newton method): on the active set A the gaps vanish, giving the linear KKT system

    [ W_AA  -J_A ] [lam_A]   [-g0_A]
    [ J_A^T   0  ] [  q  ] = [  f  ],

(solved through a Cholesky factorisation of W_AA and the r x r Schur complement),

and the next set is ``{i : lam_i - c g_i > 0}``; it stops when the set repeats (then all
conditions hold to round-off) and reports cycling as a ConvergenceError.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from headsim.errors import ConvergenceError, ParameterError


@dataclass(frozen=True, eq=False)
class ContactLCPResult:
    """forces : (m,) N >= 0; rigid : (r,) q; gaps : (m,) m >= 0 (to round-off); iterations;
    active : (m,) bool; complementarity : max |lam_i g_i| (N m)."""

    forces: np.ndarray
    rigid: np.ndarray
    gaps: np.ndarray
    iterations: int
    active: np.ndarray
    complementarity: float


_CONTROLLER = []


def _blas_controller():
    """A cached threadpoolctl controller (building one scans the loaded libraries: milliseconds)."""
    if not _CONTROLLER:
        from threadpoolctl import ThreadpoolController

        _CONTROLLER.append(ThreadpoolController())
    return _CONTROLLER[0]


def _solve_kkt(w_aa: np.ndarray, j_a: np.ndarray, g_a: np.ndarray, f: np.ndarray):
    """lam_A, q of the active-set KKT system (module doc) by Cholesky of W_AA and the r x r Schur
    complement ``S = J_A^T W_AA^-1 J_A``: ``S q = f + J_A^T W_AA^-1 g_A``, ``lam_A = W_AA^-1 (J_A q - g_A)``.
    Falls back to a least-squares solve of the full KKT matrix when W_AA or S is singular."""
    k, r = j_a.shape
    try:
        cf = sla.cho_factor(w_aa, check_finite=False)
        wj = sla.cho_solve(cf, j_a, check_finite=False)
        wg = sla.cho_solve(cf, g_a, check_finite=False)
        q = np.linalg.solve(j_a.T @ wj, f + j_a.T @ wg)
        return wj @ q - wg, q
    except (sla.LinAlgError, np.linalg.LinAlgError, ValueError):
        kkt = np.zeros((k + r, k + r))
        kkt[:k, :k] = w_aa
        kkt[:k, k:] = -j_a
        kkt[k:, :k] = j_a.T
        sol = np.linalg.lstsq(kkt, np.concatenate([-g_a, f]), rcond=None)[0]
        return sol[:k], sol[k:]


def solve_contact_lcp(compliance: np.ndarray, gaps0: np.ndarray, rigid_jacobian: np.ndarray,
                      load: np.ndarray, *, max_iterations: int = 100,
                      initial_active: np.ndarray | None = None) -> ContactLCPResult:
    """Solve the force-controlled frictionless contact LCP of the module doc.

    compliance : (m, m) W, m/N, symmetric positive definite; gaps0 : (m,) m;
    rigid_jacobian : (m, r) J; load : (r,) f (N for a translation, N for a moment / radius)
    initial_active : (m,) bool warm start of the active set (e.g. the previous solution's)
    """
    w = np.asarray(compliance, dtype=np.float64)
    g0 = np.asarray(gaps0, dtype=np.float64)
    jac = np.asarray(rigid_jacobian, dtype=np.float64)
    f = np.asarray(load, dtype=np.float64).reshape(-1)
    m = len(g0)
    if jac.ndim == 1:
        jac = jac[:, None]
    r = jac.shape[1]
    if w.shape != (m, m) or jac.shape[0] != m or f.shape != (r,):
        raise ParameterError(f"contact LCP: shapes W {w.shape}, g0 {g0.shape}, J {jac.shape}, f {f.shape} disagree")
    if not (np.isfinite(w).all() and np.isfinite(g0).all() and np.isfinite(jac).all() and np.isfinite(f).all()):
        raise ParameterError("contact LCP: non-finite input")
    c = 1.0 / float(np.median(np.diag(w)))     # N/m: balances forces against gaps in the set update
    if initial_active is not None and np.any(initial_active):
        active = np.asarray(initial_active, dtype=bool).copy()
    else:
        # the points that a rigid approach would touch first: the smallest gaps, enough for J
        order = np.argsort(g0)
        active = np.zeros(m, dtype=bool)
        active[order[: max(4 * r, 8)]] = True
    # the dense systems have a few hundred unknowns: one BLAS thread is faster than several
    # (4 ms vs 20-120 ms per LCP with two threads on the loaded 2-core machine, coarse test problem)
    with _blas_controller().limit(limits=1, user_api="blas"):
        return _pdas(w, g0, jac, f, c, active, max_iterations)


def _pdas(w, g0, jac, f, c, active, max_iterations) -> ContactLCPResult:
    m = len(g0)
    seen = set()
    for it in range(1, max_iterations + 1):
        ia = np.flatnonzero(active)
        lam_a, q = _solve_kkt(w[np.ix_(ia, ia)], jac[ia], g0[ia], f)
        lam = np.zeros(m)
        lam[ia] = lam_a
        gap = g0 - jac @ q + w[:, ia] @ lam_a
        new = lam - c * gap > 0.0
        if np.array_equal(new, active):
            lam_c = np.maximum(lam, 0.0)
            comp = float(np.max(np.abs(lam_c * gap))) if m else 0.0
            return ContactLCPResult(lam_c, q, gap, it, active, comp)
        key = new.tobytes()
        if key in seen:
            raise ConvergenceError(f"contact LCP: the active set cycles after {it} iterations "
                                   f"({int(new.sum())} of {m} points active)")
        seen.add(key)
        if not new.any():
            raise ConvergenceError("contact LCP: no point in contact (the load pulls the bodies apart?)")
        active = new
    raise ConvergenceError(f"contact LCP: active set not settled after {max_iterations} iterations")
