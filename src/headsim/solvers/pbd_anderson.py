"""Anderson acceleration of Position Based Dynamics towards its rest state (quasi-static solves).

A PBD solve that is run until it stops moving (the fat-grafting planner, Monkin 2016 §4.4–5.3) ends at a
fixed point of the *rest map*

    Φ(x) = positions after one PBD step started at rest at x
         = the constraint projections of :class:`~headsim.solvers.pbd.PBDSolver` applied to
           x + dt² a_ext(x)  (same constraints, order, iterations, compliances)

because at rest the velocity is zero and the step must give x back. The plain loop reaches it by time
stepping with damping, which is a heavy-ball iteration on Φ; this module reaches it by Anderson
acceleration (type II, Walker & Ni 2011; for geometry/physics solvers Peng et al. 2018): with the last m
residuals f_k = Φ(x_k) - x_k and values g_k = Φ(x_k),

    γ = argmin |f_k - ΔF γ|,   x_(k+1) = g_k - ΔG γ

(ΔF, ΔG: differences of consecutive residuals and values). The fixed points are exactly those of the
plain loop, so the physics is unchanged; only the path to them is. A step whose residual grows tenfold is
rejected and replaced by the plain step Φ(g_k) (history cleared).

Stop rule: the seed's rule measures the change of Σ|x| over a step (Monkin §4.4), which can cancel; at
rest the step is x → Φ(x), so the rule here is Σ|Φ(x) - x| < stop_tolerance × n (the uncancelled form,
stricter). No patience is needed.

Caveat measured in ``benchmarks/bench_graft.py``: when the equilibrium is not unique (spring nets with
compressed springs, e.g. large face regions), the accelerated path may select another fixed point than the
damped time stepping from the same start.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Callable

import numpy as np

from headsim.solvers._kernels import pbd as _k

if TYPE_CHECKING:  # pragma: no cover
    from headsim.solvers.pbd import PBDSolver, PBDState, SolveInfo

__all__ = ["solve_anderson"]

_REJECT_GROWTH = 10.0


def solve_anderson(solver: "PBDSolver", state: "PBDState", *, history: int,
                   callback: Callable[["PBDState", float], None] | None = None,
                   cancel: Callable[[], bool] | None = None) -> tuple["PBDState", "SolveInfo"]:
    """Iterate x ← Anderson(Φ) from ``state.positions`` until Σ|Φ(x) - x| < stop_tolerance × n.

    solver : its options give the step map, stop_tolerance (m per particle), min_steps and max_steps
        (counted in evaluations of Φ, i.e. PBD steps)
    history : m, number of previous residuals used (m = 0 is the plain rest-map iteration)
    callback(state, residual) after every evaluation (residual = Σ|Φ(x) - x|, m); cancel() polled before it

    Returns (state at rest with the last Φ value as positions, SolveInfo). Velocities of the result are
    zero; ``time`` is left unchanged (the iterations are not time steps).
    """
    from headsim.solvers.pbd import PBDState, SolveInfo

    o = solver.options
    m = max(int(history), 0)
    shape = state.positions.shape
    n_values = state.positions.size
    threshold = o.stop_tolerance * solver.model.n_particles
    dF = np.zeros((n_values, max(m, 1)))  # (N, m): one streaming pass per iteration
    dG = np.zeros((n_values, max(m, 1)))
    gram = np.zeros((max(m, 1), max(m, 1)))
    rhs = np.zeros(max(m, 1))
    row = np.zeros(max(m, 1))
    x = state.positions.reshape(-1).copy()

    def phi(v):
        return solver.rest_step(v.reshape(shape)).reshape(-1)

    g = phi(x)
    f = g - x
    res = _k.sum_abs_difference(g, x)
    evaluations = 1
    count = 0
    slot = 0
    xn = np.empty_like(x)

    def report(positions, r):
        if callback is not None:
            callback(PBDState(positions.reshape(shape), np.zeros(shape), state.time, state.steps + evaluations), r)

    report(g, res)
    while True:
        if evaluations >= o.min_steps and res < threshold:
            return (PBDState(g.reshape(shape), np.zeros(shape), state.time, state.steps + evaluations),
                    SolveInfo(evaluations, True, False, res))
        if evaluations >= o.max_steps:
            return (PBDState(g.reshape(shape), np.zeros(shape), state.time, state.steps + evaluations),
                    SolveInfo(evaluations, False, False, res))
        if cancel is not None and cancel():
            return state, SolveInfo(evaluations, False, True, res)
        if count:
            k = count  # rhs[:k] = dF[:, :k] . f from the last record
            a = gram[:k, :k] + (1e-12 * np.trace(gram[:k, :k]) / k + 1e-300) * np.eye(k)
            try:
                gamma = np.linalg.solve(a, rhs[:k])
            except np.linalg.LinAlgError:
                gamma = np.zeros(k)
            _k.anderson_combine(g, dG, k, gamma, xn)
        else:
            xn[:] = g
        gn = phi(xn)
        evaluations += 1
        if count:
            res_n = _k.sum_abs_difference(gn, xn)
            if not (res_n <= _REJECT_GROWTH * res and math.isfinite(res_n)):
                # rejected: plain step from the last value, history cleared
                count = 0
                slot = 0
                xn[:] = g
                gn = phi(xn)
                evaluations += 1
        used = min(count + 1, m) if m else 0
        res_n = _k.anderson_record(g, gn, xn, f, dF, dG, slot, used, row, rhs)
        if used:
            gram[slot, :used] = row[:used]
            gram[:used, slot] = row[:used]
            slot = (slot + 1) % m
            count = used
        x, xn = xn, x
        g, res = gn, res_n
        report(g, res)
