"""Straightforward reference of the guide optimisation (tests and the benchmark's baseline).

The same objective as :func:`headsim.hair.reconstruct._kernels.guide_objective`, written plainly with NumPy:
the shape from :func:`headsim.solvers.rods_statics.pai_static` on a fresh :class:`RodModel`, field values by
NumPy trilinear interpolation of the same grids, the density gradient by central differences; optimised per guide by scipy
L-BFGS-B with scipy's own forward-difference gradient.
"""

from __future__ import annotations

import numpy as np
from scipy import optimize

from headsim.hair.reconstruct import _kernels as _k
from headsim.hair.reconstruct.growth import GuideOptions, objective_parameters

__all__ = ["reference_objective", "reference_optimise_guide"]


def _trilinear(values, origin, h, p, outside):
    """Plain NumPy trilinear interpolation (the same rule as the collide kernels), ``outside`` off the grid."""
    f = (np.asarray(p, float) - origin) / h
    n = np.array(values.shape)
    ok = np.all(np.isfinite(f) & (f >= 0) & (f <= n - 1), axis=1)
    f = np.where(ok[:, None], f, 0.0)
    i = np.minimum(np.floor(f).astype(np.int64), n - 2)
    t = f - i
    out = np.zeros(len(p))
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                w = (t[:, 0] if dx else 1 - t[:, 0]) * (t[:, 1] if dy else 1 - t[:, 1]) * (t[:, 2] if dz else 1 - t[:, 2])
                out += w * values[np.minimum(i[:, 0] + dx, n[0] - 1), np.minimum(i[:, 1] + dy, n[1] - 1),
                                  np.minimum(i[:, 2] + dz, n[2] - 1)]
    return np.where(ok, out, outside)


class _Grid:
    """A grid read like a distance field with :func:`_trilinear`."""

    def __init__(self, values, origin, spacing, far=0.0):
        self.values, self.origin, self.spacing, self.far = values, origin, spacing, far

    def distance(self, p):
        return _trilinear(self.values, self.origin, self.spacing, p, self.far)


def _boundary(d, margin, cd, eps):
    u = np.maximum(1.0 + d / margin, 0.0)
    s = d / eps
    step = np.where(s > 30, 1.0, np.where(s < -30, 0.0, 1.0 / (1.0 + np.exp(-np.clip(s, -30.0, 30.0)))))
    return u * u + cd * step


def reference_objective(eta, R0, r0, K, length, n_segments, pre_d3, pre_kl, pre_w, head_field, hair_field,
                        density, options: GuideOptions) -> float:
    """f(eta) (eq. 5.7) of one guide, plain NumPy."""
    from headsim.hair.fibres import fibre_model
    from headsim.solvers.rods_statics import pai_static

    par = objective_parameters(options, density.mode, K, length, n_segments, density.scale, head_field.far,
                               hair_field.far)
    N = n_segments
    # the default keratin fibre: its stiffness is growth.rod_stiffness() (pass that K), its root frame
    # straight_frame(d3, d2) = R0 for frames from growth.root_frames
    model = fibre_model(length, N, root_position=r0, root_direction=R0[:, 2], root_normal=R0[:, 1])
    kappa, _, r, R = pai_static(model, 0, np.asarray(eta[:3]) * par[_k.P_FSCALE],
                                np.asarray(eta[3:]) * par[_k.P_LSCALE])
    wq = np.ones(N + 1)
    wq[[0, -1]] = 0.5
    d3 = R[:, :, 2]
    F1 = sum(pre_w[c] * (wq * (1 - (d3 * pre_d3[c]).sum(1))).sum() / N for c in range(len(pre_w)))
    F2 = sum(pre_w[c] * np.sqrt((wq * ((kappa * length - pre_kl[c]) ** 2).sum(1)).sum() / N) for c in range(len(pre_w)))
    x = r[1:]
    hair_field = _Grid(hair_field.values, hair_field.origin, hair_field.spacing, hair_field.far)
    head_field = _Grid(head_field.values, head_field.origin, head_field.spacing, head_field.far)
    F3 = (_boundary(hair_field.distance(x), options.margin, options.exit_penalty, options.eps)
          + _boundary(-head_field.distance(x), options.margin, options.exit_penalty, options.eps)).sum() / N
    grid = _Grid(density.values, density.origin, density.spacing)
    F4 = 0.0
    if density.mode == 1:
        F4 = grid.distance(0.5 * (r[1:] + r[:-1])).sum() / N
    elif density.mode == 2:
        h = density.spacing
        g = np.stack([0.5 * (grid.distance(x + h * e) - grid.distance(x - h * e)) for e in np.eye(3)], axis=1)
        sc = density.scale
        p = (g * d3[1:]).sum(1) * sc
        over = grid.distance(x) * sc - options.rho_tolerance
        F4 = (p * p + options.rho_penalty * np.maximum(over, 0.0)).sum() / N
    w = par[_k.P_W1:_k.P_W4 + 1]
    f = float(w[0] * F1 + w[1] * F2 + w[2] * F3 + w[3] * F4)
    return f if np.isfinite(f) else 1e12


def reference_optimise_guide(R0, r0, K, length, n_segments, pre_d3, pre_kl, pre_w, head_field, hair_field,
                             density, options: GuideOptions, eta0=None):
    """The baseline per-guide optimisation: scipy L-BFGS-B, forward-difference gradient by scipy."""
    bounds = [(-options.force_bound, options.force_bound)] * 3 + [(-options.torque_bound, options.torque_bound)] * 3
    x0 = np.zeros(6) if eta0 is None else np.clip(eta0, [b[0] for b in bounds], [b[1] for b in bounds])
    res = optimize.minimize(reference_objective, x0, args=(R0, r0, K, length, n_segments, pre_d3, pre_kl, pre_w,
                                                           head_field, hair_field, density, options),
                            method="L-BFGS-B", bounds=bounds,
                            options={"maxiter": options.max_iterations, "gtol": 1e-6, "ftol": 1e-9,
                                     "eps": options.fd_step})
    return res.x, float(res.fun), int(res.nfev)
