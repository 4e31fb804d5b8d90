"""Static Kirchhoff rods: the seed's energy minimisation and Pai's integration (Sobottka 2008, §3.3.2).

* :func:`solve_static_energy` minimises the total potential energy over the discrete curvature
  vectors kappa_i (one per segment, exact constant-curvature arcs between nodes), with dead loads in
  the GLOBAL frame (gravity, point loads, tip force): eqs. 3.130-3.135. The seed uses conjugate
  directions with a forward-difference gradient; we use L-BFGS with the exact adjoint gradient
  (O(N) per evaluation) on variables scaled by sqrt(ds K), and keep the finite-difference gradient
  for the tests.
* :func:`pai_static` is Pai's (2002) two-phase explicit integration with loads in LOCAL frames,
  which turns every load into a follower load (Sobottka Fig. 3.9).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

from headsim.errors import ConvergenceError, ParameterError
from headsim.solvers._kernels import rods_statics as _ks
from headsim.solvers.rods import RodModel

__all__ = ["StaticSolution", "static_nodal_loads", "static_energy", "solve_static_energy", "pai_static"]


@dataclass(frozen=True, eq=False)
class StaticSolution:
    """kappa (N, 3) 1/m per segment; positions (N+1, 3) m; frames (N+1, 3, 3); energy J;
    iterations (optimiser); gradient_norm (scaled)."""

    kappa: np.ndarray
    positions: np.ndarray
    frames: np.ndarray
    energy: float
    iterations: int
    gradient_norm: float


def _segment_k0(model: RodModel, fibre: int) -> np.ndarray:
    k = model.natural_curvature[fibre]
    return 0.5 * (k[1:] + k[:-1])


def static_nodal_loads(model: RodModel, fibre: int = 0, gravity=(0.0, 0.0, 0.0), tip_force=None,
                       node_forces=None) -> np.ndarray:
    """(N+1, 3) N: gravity rho A g lumped by the trapezoid rule, plus point loads and the tip force."""
    N = model.n_segments
    ds = model.segment_length[fibre]
    w = np.full(N + 1, ds)
    w[0] = w[-1] = 0.5 * ds
    F = model.rho_area[fibre] * w[:, None] * np.asarray(gravity, float)[None, :]
    if node_forces is not None:
        F = F + np.asarray(node_forces, float)
    if tip_force is not None:
        F[-1] += np.asarray(tip_force, float)
    if not np.isfinite(F).all():
        raise ParameterError("loads must be finite")
    return F


def static_energy(model: RodModel, kappa: np.ndarray, loads: np.ndarray, fibre: int = 0):
    """(energy J, gradient (N, 3), positions (N+1, 3), frames (N+1, 3, 3)) for segment curvatures kappa (N, 3)."""
    N = model.n_segments
    grad = np.empty((N, 3))
    R = np.empty((N + 1, 3, 3))
    r = np.empty((N + 1, 3))
    e = _ks.static_energy_gradient(np.ascontiguousarray(kappa, dtype=float), _segment_k0(model, fibre),
                                   model.stiffness[fibre], model.segment_length[fibre], model.root_frame[fibre],
                                   model.root_position[fibre], np.ascontiguousarray(loads, dtype=float),
                                   _ks._GL_X, _ks._GL_W, grad, R, r)
    return e, grad, r, R


def solve_static_energy(model: RodModel, fibre: int = 0, gravity=(0.0, 0.0, 0.0), tip_force=None,
                        node_forces=None, kappa_start=None, gtol: float = 1e-11,
                        max_iterations: int = 20000, polish_iterations: int = 4) -> StaticSolution:
    """Static equilibrium by minimising the total energy over the segment curvatures (eq. 3.135).

    Loads are dead loads in the global frame. kappa_start (N, 3) defaults to the natural curvature.
    Raises ConvergenceError if the optimiser fails.
    """
    N = model.n_segments
    ds = model.segment_length[fibre]
    K = model.stiffness[fibre]
    sq = np.sqrt(ds * K)  # u = sq (kappa - k0)
    k0 = _segment_k0(model, fibre)
    loads = static_nodal_loads(model, fibre, gravity, tip_force, node_forces)
    scale = 0.5 * float((K / model.length[fibre]).min()) + 1e-300  # energy scale EI / L

    def fun(u):
        kap = k0 + u.reshape(N, 3) / sq
        e, g, _, _ = static_energy(model, kap, loads, fibre)
        return e / scale, (g / sq).ravel() / scale

    u0 = np.zeros(3 * N) if kappa_start is None else ((np.asarray(kappa_start) - k0) * sq).ravel()
    res = optimize.minimize(fun, u0, jac=True, method="L-BFGS-B",
                            options={"maxiter": max_iterations, "gtol": 1e-8, "ftol": 1e-15, "maxcor": 30})
    u = res.x
    iterations = int(res.nit)
    # Newton polish of the stationarity condition grad = 0 with a central-difference Hessian
    # (the energy itself cannot resolve the last digits: cancellation in -F.r)
    g = fun(u)[1]
    for _ in range(polish_iterations):
        if np.abs(g).max() <= gtol:
            break
        h = 1e-6 * max(1.0, float(np.abs(u).max()))
        H = np.empty((u.size, u.size))
        for i in range(u.size):
            up = u.copy()
            up[i] += h
            um = u.copy()
            um[i] -= h
            H[:, i] = (fun(up)[1] - fun(um)[1]) / (2 * h)
        H = 0.5 * (H + H.T)
        u = u - np.linalg.solve(H, g)
        g = fun(u)[1]
        iterations += 1
    gnorm = float(np.abs(g).max())
    if not np.isfinite(gnorm) or gnorm > max(gtol, 1e-7):
        raise ConvergenceError(f"static energy minimisation failed: {res.message} (|grad| = {gnorm:.2e})")
    res.x = u
    kap = k0 + res.x.reshape(N, 3) / sq
    e, _, r, R = static_energy(model, kap, loads, fibre)
    return StaticSolution(kap, r, R, float(e), int(res.nit), gnorm)


def pai_static(model: RodModel, fibre: int = 0, tip_force_local=(0.0, 0.0, 0.0), tip_torque_local=(0.0, 0.0, 0.0),
               force_local=None, couple_local=None):
    """Pai-style static integration with loads in local frames (follower loads). Returns
    (kappa (N+1, 3), n (N+1, 3), positions (N+1, 3), frames (N+1, 3, 3)). First order in ds."""
    nn = model.n_nodes
    f = np.zeros((nn, 3)) if force_local is None else np.asarray(force_local, float)
    lc = np.zeros((nn, 3)) if couple_local is None else np.asarray(couple_local, float)
    kappa = np.empty((nn, 3))
    n = np.empty((nn, 3))
    R = np.empty((nn, 3, 3))
    r = np.empty((nn, 3))
    _ks.pai_integrate(model.natural_curvature[fibre], model.stiffness[fibre], model.segment_length[fibre],
                      model.root_frame[fibre], model.root_position[fibre], f, lc,
                      np.asarray(tip_force_local, float), np.asarray(tip_torque_local, float), kappa, n, R, r)
    return kappa, n, r, R
