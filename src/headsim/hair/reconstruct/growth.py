"""Guide hair generation (Sobottka 2008 §5.3.3) and the final cut (§5.3.5).

Every guide is a static Kirchhoff rod (keratin stiffness from :mod:`headsim.hair.properties`) clamped at its
root in the growth direction and loaded by a tip wrench eta_L = {f_L, l_L} given in the tip's material frame;
Pai's integration turns it into the shape (exact for terminal loads, O(N)). The wrench is made dimensionless:
f = eta_f K / L^2, l = eta_l K / L (K the mean bending stiffness, L the hair length).

* :func:`grow_preguides` — (a): a dead tip force normal to the straight rod's axis, in the plane of the root
  normal and the growth direction, pointing to the scalp, raised geometrically until every node lies below the
  hair surface at the root's immersion depth (Phi_H <= -depth); all pre-guides advance together (vectorised).
  The dead load is carried into Pai's local-frame integration by :func:`dead_tip_force`.
* :func:`depth_schedule` — the immersion depth: smallest for frontal roots, growing as the root's height falls
  (lower layers lie deeper, upper layers reach toward the surface), capped at a fraction of the local
  scalp-to-surface thickness (the superposition of both distance fields).
* :func:`optimise_guide` — (b): minimise f(eta) = sum w_i F_i (eq. 5.7: direction F1 eq. 5.8 and similarity F2
  eq. 5.9 against the 3 nearest pre-guides, boundary F3 eq. 5.10 as corrected, density F4 eqs. 5.11/5.12)
  with **scipy L-BFGS-B** (box bounds on eta; the gradient by central differences computed in the same
  Numba call as f). The outer optimiser is not named by the seed.
* :func:`cut_index` — first exit through S_H or into the head, short excursions tolerated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

from headsim.errors import ParameterError
from headsim.hair.reconstruct import _kernels as _k
from headsim.hair.reconstruct.maps import Roots
from headsim.solvers.rods import straight_frame

__all__ = ["GuideOptions", "PreGuides", "rod_stiffness", "root_frames", "rod_shapes", "depth_schedule",
           "grow_preguides", "dead_tip_force", "objective_parameters", "optimise_guide", "cut_index"]


@dataclass(frozen=True)
class GuideOptions:
    """Weights (w1 direction, w2 similarity, w3 boundary, w4 density; normalised to sum 1, eq. 5.7);
    margin delta m and exit penalty c_d of F3; eps m: width of the smoothed exit step; KDM predicted-density
    tolerance (in units of the mean density of evenly spread strands) and penalty; eta bounds (dimensionless force
    F L^2/K, torque l L/K: Pai's explicit integration stays accurate for ds kappa < 1/2, i.e. |eta| <~ N/2; also
    the largest pre-guide force level); L-BFGS-B iterations
    and finite-difference step; depth schedule d_min m and the cap (fraction of the local thickness);
    cut tolerances: distance m and tolerated excursion length m; start: "pre-guide" (L-BFGS-B starts from the
    root-distance-weighted wrench of the 3 nearest pre-guides) or "straight" (eta = 0, the seed's start)."""

    weights: tuple[float, float, float, float] = (0.17, 0.10, 0.32, 0.41)
    margin: float = 0.003
    exit_penalty: float = 2.0
    eps: float = 0.0005
    rho_tolerance: float = 1.5
    rho_penalty: float = 1.0
    force_bound: float = 12.0
    torque_bound: float = 8.0
    max_iterations: int = 20
    fd_step: float = 1e-5
    depth_min: float = 0.002
    depth_cap: float = 0.6
    cut_distance: float = 0.001
    cut_length: float = 0.004
    start: str = "pre-guide"

    def normalised_weights(self) -> np.ndarray:
        w = np.asarray(self.weights, float)
        if w.shape != (4,) or np.any(w < 0) or w.sum() <= 0:
            raise ParameterError("the four objective weights must be >= 0 and not all zero")
        return w / w.sum()


def rod_stiffness() -> np.ndarray:
    """(3,) N m^2: K = (E_B I1, E_B I2, G J) of the default keratin fibre (Caucasian ellipse, 65 % RH)."""
    from headsim.hair.fibres import fibre_model

    return np.asarray(fibre_model(0.1, 2).stiffness[0], float)


def root_frames(roots: Roots) -> np.ndarray:
    """(n, 3, 3) clamped root frames: d3 = growth direction, d2 as close as possible to the scalp normal."""
    return np.stack([straight_frame(d, n) for d, n in zip(roots.directions, roots.normals)])


def rod_shapes(R0, r0, K, lengths, n_segments: int, eta: np.ndarray):
    """Batched shapes (positions (B, N+1, 3), frames (B, N+1, 3, 3), kappa (B, N+1, 3)) for dimensionless
    local tip wrenches eta (B, 6)."""
    B = len(r0)
    N = int(n_segments)
    Km = float(np.mean(K[:2]))
    L = np.asarray(lengths, float)
    tf = np.ascontiguousarray(eta[:, :3] * (Km / L**2)[:, None])
    tl = np.ascontiguousarray(eta[:, 3:] * (Km / L)[:, None])
    kappa = np.empty((B, N + 1, 3))
    R = np.empty((B, N + 1, 3, 3))
    r = np.empty((B, N + 1, 3))
    _k.rod_shapes_batch(np.ascontiguousarray(R0), np.ascontiguousarray(r0), np.ascontiguousarray(np.broadcast_to(K, (B, 3))),
                        np.ascontiguousarray(L / N), tf, tl, kappa, R, r)
    return r, R, kappa


def depth_schedule(roots: Roots, hair_field, options: GuideOptions) -> np.ndarray:
    """(n,) immersion depth per root, m (see the module docstring)."""
    p = roots.positions
    thick = np.clip(-_k.field_distance(hair_field, p), 0.0, getattr(hair_field, "band", np.inf))  # band: exact
    y = p[:, 1]
    h = (y - y.min()) / max(np.ptp(y), 1e-12)
    z = p[:, 2]
    zmid = np.median(z)
    front = np.clip((z - zmid) / max(z.max() - zmid, 1e-12), 0.0, 1.0)
    cap = np.maximum(options.depth_cap * thick, options.depth_min)
    return options.depth_min + (cap - options.depth_min) * (1.0 - h) * (1.0 - front)


@dataclass(frozen=True, eq=False)
class PreGuides:
    """roots; positions (P, N+1, 3) m; frames (P, N+1, 3, 3); kappa (P, N+1, 3) 1/m; eta (P, 6) the final
    dimensionless tip wrench; depth (P,) m; fitted (P,) bool: the depth condition was met."""

    roots: Roots
    positions: np.ndarray
    frames: np.ndarray
    kappa: np.ndarray
    eta: np.ndarray
    depth: np.ndarray
    fitted: np.ndarray


def dead_tip_force(R0, r0, K, lengths, n_segments: int, f_global: np.ndarray, start: np.ndarray | None = None,
                   iterations: int = 12, relax: float = 0.7):
    """Local tip wrenches eta (B, 6) whose Pai shapes carry the DEAD dimensionless tip force f_global (B, 3):
    with only a terminal load the internal force is constant, so the local force must equal R(L)^T f_global;
    found by damped fixed-point iteration from ``start`` (continuation over rising loads). Returns (eta,
    residual (B,)) with the residual |R(L) f_local - f_global| / (|f_global| + 1e-12)."""
    B = len(r0)
    eta = np.zeros((B, 6)) if start is None else start.copy()
    for _ in range(iterations):
        _, R, _ = rod_shapes(R0, r0, K, lengths, n_segments, eta)
        target = np.einsum("bji,bj->bi", R[:, -1], f_global)
        eta[:, :3] = (1 - relax) * eta[:, :3] + relax * target
    _, R, _ = rod_shapes(R0, r0, K, lengths, n_segments, eta)
    res = np.linalg.norm(np.einsum("bij,bj->bi", R[:, -1], eta[:, :3]) - f_global, axis=1)
    return eta, res / (np.linalg.norm(f_global, axis=1) + 1e-12)


def grow_preguides(roots: Roots, hair_field, K, n_segments: int, options: GuideOptions,
                   force_levels: np.ndarray | None = None) -> PreGuides:
    """Pre-guides by a rising tip force (§5.3.3 a): a dead load normal to the straight rod's axis, in the plane
    of the root normal and the growth direction, pointing to the scalp (-d2 of the root frame), of
    dimensionless size F L^2 / K raised over ``force_levels``. Each pre-guide keeps the first level that meets
    the depth condition, else the level with the smallest violation (``fitted`` False)."""
    P = len(roots)
    levels = np.concatenate([[0.0], np.geomspace(0.05, options.force_bound, 40)]) if force_levels is None \
        else np.asarray(force_levels, float)
    R0 = root_frames(roots)
    depth = depth_schedule(roots, hair_field, options)
    best_v = np.full(P, np.inf)
    best_eta = np.zeros((P, 6))
    eta_cur = np.zeros((P, 6))
    done = np.zeros(P, bool)
    for F in levels:
        todo = np.flatnonzero(~done)
        if todo.size == 0:
            break
        fg = -F * R0[todo, :, 1]
        eta, _ = dead_tip_force(R0[todo], roots.positions[todo], K, roots.lengths[todo], n_segments, fg,
                                eta_cur[todo])
        eta_cur[todo] = eta
        r, _, _ = rod_shapes(R0[todo], roots.positions[todo], K, roots.lengths[todo], n_segments, eta)
        phi = _k.field_distance(hair_field, r[:, 1:])
        viol = (phi + depth[todo, None]).max(axis=1)
        better = viol < best_v[todo] - 1e-6
        best_v[todo[better]] = viol[better]
        best_eta[todo[better]] = eta[better]
        done[todo[viol <= 0]] = True
    r, R, kap = rod_shapes(R0, roots.positions, K, roots.lengths, n_segments, best_eta)
    return PreGuides(roots, r, R, kap, best_eta, depth, best_v <= 0)


def objective_parameters(options: GuideOptions, density_mode: int, K, length: float, n_segments: int,
                         density_scale: float = 1.0, head_far: float = 1.0, hair_far: float = 1.0) -> np.ndarray:
    """The ``par`` vector of :func:`headsim.hair.reconstruct._kernels.guide_objective`."""
    par = np.zeros(_k.N_PAR)
    par[_k.P_W1:_k.P_W4 + 1] = options.normalised_weights()
    if density_mode == 0:
        par[_k.P_W4] = 0.0
    par[_k.P_MARGIN] = options.margin
    par[_k.P_CD] = options.exit_penalty
    par[_k.P_EPS] = options.eps
    par[_k.P_MODE] = density_mode
    par[_k.P_RHO_TOL] = options.rho_tolerance
    par[_k.P_RHO_PEN] = options.rho_penalty
    Km = float(np.mean(np.asarray(K)[:2]))
    par[_k.P_FSCALE] = Km / length**2
    par[_k.P_LSCALE] = Km / length
    par[_k.P_DS] = length / n_segments
    par[_k.P_RHO_SCALE] = density_scale
    par[_k.P_HEAD_FAR] = head_far
    par[_k.P_HAIR_FAR] = hair_far
    return par


def _grid(field_):
    return np.ascontiguousarray(field_.values), np.ascontiguousarray(field_.origin), float(field_.spacing)


def optimise_guide(R0, r0, K, length: float, n_segments: int, pre_d3, pre_kl, pre_w, head_field, hair_field,
                   density, options: GuideOptions, eta0=None):
    """One main guide (§5.3.3 b). Returns (eta (6,), f, positions (N+1, 3), frames (N+1, 3, 3), evaluations)."""
    par = objective_parameters(options, density.mode, K, length, n_segments, density.scale, head_field.far,
                               hair_field.far)
    hv, ho, hh = _grid(head_field)
    sv, so, sh = _grid(hair_field)
    dv, do, dh = density.values, density.origin, density.spacing
    K = np.ascontiguousarray(K, dtype=float)
    grad = np.empty(6)
    count = [0]

    def fun(eta):
        count[0] += 1
        f = _k.objective_and_gradient(np.ascontiguousarray(eta), options.fd_step, par, R0, r0, K, pre_d3, pre_kl,
                                      pre_w, hv, ho, hh, sv, so, sh, dv, do, dh, grad)
        return f, grad.copy()

    bounds = [(-options.force_bound, options.force_bound)] * 3 + [(-options.torque_bound, options.torque_bound)] * 3
    x0 = np.zeros(6) if eta0 is None else np.clip(eta0, [b[0] for b in bounds], [b[1] for b in bounds])
    res = optimize.minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=bounds,
                            options={"maxiter": options.max_iterations, "gtol": 1e-6, "ftol": 1e-9})
    nn = n_segments + 1
    kappa = np.empty((nn, 3))
    n = np.empty((nn, 3))
    R = np.empty((nn, 3, 3))
    r = np.empty((nn, 3))
    f = _k.guide_objective(res.x, par, R0, r0, K, pre_d3, pre_kl, pre_w, hv, ho, hh, sv, so, sh, dv, do, dh,
                           kappa, n, R, r)
    if not np.isfinite(f) or not np.isfinite(r).all():
        from headsim.errors import ConvergenceError

        raise ConvergenceError(f"guide optimisation produced a non-finite shape (f = {f})")
    return res.x, float(f), r, R, count[0] * 7


def cut_index(points: np.ndarray, head_field, hair_field, options: GuideOptions) -> int:
    """Index of the last node kept by the final cut of one polyline (points (n, 3) m)."""
    p = np.ascontiguousarray(points, dtype=float)
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    hd = _k.field_distance(hair_field, p)
    sd = _k.field_distance(head_field, p)
    return max(1, int(_k.first_exit(hd, sd, seg, options.cut_distance, options.cut_length)))
