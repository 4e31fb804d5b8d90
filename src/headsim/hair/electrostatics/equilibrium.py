"""Static equilibrium of every fibre under dead loads, fast enough for the charging loop.

The energy and its exact adjoint gradient are the committed rod statics
(:func:`headsim.solvers.rods_statics.static_energy`, Sobottka eqs. 3.130-3.135) in the same scaled
variables u = sqrt(ds K) (kappa - kappa0). Instead of L-BFGS + a dense finite-difference Hessian
polish (3N gradients per Newton step), we solve grad = 0 by an inexact Newton method whose Hessian
products are central differences of the exact gradient (2 gradients per CG iteration), with a
backtracking step on |grad|. If this fails (e.g. an indefinite Hessian after buckling) we fall back
to :func:`headsim.solvers.rods_statics.solve_static_energy`.
"""

from __future__ import annotations

import numpy as np
from scipy import optimize
from scipy.sparse.linalg import LinearOperator, cg

from headsim.errors import ConvergenceError
from headsim.solvers.rods import RodModel
from headsim.solvers.rods_statics import solve_static_energy, static_energy, static_nodal_loads

__all__ = ["fibre_equilibrium"]


def fibre_equilibrium(model: RodModel, fibre: int, gravity=(0.0, 0.0, 0.0), node_forces=None, kappa_start=None,
                      gtol: float = 1e-9, max_newton: int = 30):
    """(kappa (N, 3) 1/m, positions (N+1, 3) m, Newton iterations) of fibre ``fibre`` in static
    equilibrium under gravity (m/s^2) and dead nodal loads ``node_forces`` (N+1, 3) N (global frame).

    gtol: max |dE/du| in units of EI/L (as in solve_static_energy). Raises ConvergenceError.
    """
    N = model.n_segments
    ds = model.segment_length[fibre]
    K = model.stiffness[fibre]
    sq = np.sqrt(ds * K)
    kn = model.natural_curvature[fibre]
    k0 = 0.5 * (kn[1:] + kn[:-1])
    loads = static_nodal_loads(model, fibre, gravity, None, node_forces)
    scale = 0.5 * float((K / model.length[fibre]).min()) + 1e-300

    def grad(u):
        _, g, _, _ = static_energy(model, k0 + u.reshape(N, 3) / sq, loads, fibre)
        return (g / sq).ravel() / scale

    if kappa_start is None:
        # a cold start is far from the solution: L-BFGS on the energy first, Newton afterwards
        def fun(u):
            e, gk, _, _ = static_energy(model, k0 + u.reshape(N, 3) / sq, loads, fibre)
            return e / scale, (gk / sq).ravel() / scale

        u = optimize.minimize(fun, np.zeros(3 * N), jac=True, method="L-BFGS-B",
                              options={"maxiter": 5000, "gtol": 1e-6, "ftol": 1e-15, "maxcor": 30}).x
    else:
        u = ((np.asarray(kappa_start) - k0) * sq).ravel()
    g = grad(u)
    gn = float(np.abs(g).max())
    it = 0
    ok = np.isfinite(gn)
    while ok and gn > gtol and it < max_newton:
        h = 1e-7 * max(1.0, float(np.abs(u).max()))

        def hv(v, u=u, h=h):
            nv = float(np.linalg.norm(v))
            if nv == 0.0:
                return np.zeros_like(v)
            e = h / nv
            return (grad(u + e * v) - grad(u - e * v)) / (2 * e)

        H = LinearOperator((3 * N, 3 * N), matvec=hv, dtype=float)
        du, info = cg(H, -g, rtol=1e-4, maxiter=10 * N)
        if not np.all(np.isfinite(du)):
            ok = False
            break
        step = 1.0
        while step > 1e-4:
            un = u + step * du
            gnew = grad(un)
            gnn = float(np.abs(gnew).max())
            if np.isfinite(gnn) and gnn < gn:
                break
            step *= 0.5
        else:
            ok = False
            break
        u, g, gn = un, gnew, gnn
        it += 1
    if not ok or gn > max(gtol, 1e-7):
        try:
            sol = solve_static_energy(model, fibre, gravity=gravity, node_forces=node_forces,
                                      kappa_start=None if kappa_start is None else kappa_start)
        except ConvergenceError as e:
            raise ConvergenceError(f"fibre {fibre}: no static equilibrium ({e})") from e
        return sol.kappa, sol.positions, it + sol.iterations
    kap = k0 + u.reshape(N, 3) / sq
    _, _, r, _ = static_energy(model, kap, loads, fibre)
    return kap, r, it
