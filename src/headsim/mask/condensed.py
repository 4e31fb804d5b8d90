"""Interactive re-fit mode: linear-elastic face and cushion condensed onto their contact surfaces.

The approach of Kwon et al. (PLOS ONE 2022, cited in issue 6) for evaluating many mask designs on
one face: the face is linear elastic, condensed once onto its contact-candidate skin nodes
(:func:`headsim.solvers.condensation.condense`, the Schur complement of the tissue stiffness), and
every fit is then a small contact problem with Lagrange multipliers
(:func:`headsim.solvers.contact_qp.solve_contact_lcp`). Here the cushion is condensed too (onto
its skin-side vertices, shell fixed), so a re-fit at another force or pose costs one dense LCP.

Model (same meshes, materials and placement as :mod:`headsim.mask.fit`, but linearised):

- **Pairs**: every cropped skin vertex whose line along the approach axis meets the cushion's
  skin-side surface at rest (the seed's heightmap view, Heinze §3.3.1; the same rays as the
  nonlinear fit's :class:`~headsim.mask.fit.AxialContact`) is paired with that cushion point;
  the pairing is fixed (small sliding).
- **Gaps**: ``g = g0 - J q + (W_face + B W_cushion B^T) lam`` along the approach axis, with
  ``lam`` (N) the contact force of each pair, ``B`` the barycentric weights of the cushion point,
  ``q`` the mask's rigid motion (translation along the axis; pitch and yaw about the airway centre as
  arc lengths at 3 cm, as the nonlinear fit's :func:`~headsim.mask.fit.shell_modes`), ``J`` how much
  each gap closes per unit ``q``; ``J^T lam = (F, 0, 0)``: the strap force and no moment.
- **Linear elasticity** about the rest state: the FEM stiffness at rest (tangent of the same
  neo-Hookean materials). Valid while strains stay small; the comparison with the nonlinear fit
  (``tests/mask/test_condensed.py``, ``benchmarks/bench_mask.py``) states where it holds.

Outputs are a :class:`~headsim.mask.fit.FitResult` like the nonlinear fit's: pressure at a skin
vertex = its pair force / its vertex area; contact force = sum of pair forces (= F to round-off).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from headsim.errors import ConvergenceError, ParameterError
from headsim.mask.fit import _ROT_RADIUS, FitProblem, FitResult, FitState, check_force, fit_leak
from headsim.mask.pressure import summarize_pressure
from headsim.mask.seal import analyse_seal


@dataclass(frozen=True, eq=False)
class CondensedFit:
    """A fit problem condensed for fast re-fits (module doc), built once by :func:`condense_fit`.

    pairs : (m,) int64 indices into ``problem.skin_vertices`` of the paired skin vertices;
    cushion_tri : (m, 3) model ids, cushion_weights : (m, 3) barycentric weights of the cushion points;
    gaps0 : (m,) m; jacobian : (m, r); compliance : (m, m) m/N (face + cushion);
    tissue, cushion : the CondensedBody of each; seconds : condensation time
    """

    problem: FitProblem
    pairs: np.ndarray
    cushion_tri: np.ndarray
    cushion_weights: np.ndarray
    cushion_nodes: np.ndarray
    weights_matrix: np.ndarray
    gaps0: np.ndarray
    jacobian: np.ndarray
    compliance: np.ndarray
    tissue: object
    cushion: object
    seconds: float
    cache: dict = field(default_factory=dict)   # the last active set (warm start of the next LCP)

    @property
    def n_pairs(self) -> int:
        return len(self.pairs)


def condense_fit(problem: FitProblem) -> CondensedFit:
    """Pair skin and cushion along the approach axis and condense both bodies (module doc)."""
    from headsim.collide import TriangleBVH
    from headsim.solvers.condensation import condense

    if problem.options.friction > 0:
        raise ParameterError(f"the condensed mode is frictionless; got friction {problem.options.friction:g} "
                             "(use the nonlinear mode for skin-cushion friction)")
    t0 = time.perf_counter()
    p = problem
    x = p.model.rest_positions
    a = p.approach
    nt = p.n_tissue
    tree = TriangleBVH(x, p.mask_contact)
    xs = x[p.skin_vertices]
    behind = 0.05
    hits = tree.intersect_rays(xs + behind * a, np.broadcast_to(-a, xs.shape).copy())
    ok = hits.hit & (np.einsum("ij,j->i", hits.normal, a) > 0.2)
    pairs = np.flatnonzero(ok)
    if len(pairs) < 8:
        raise ConvergenceError(f"condensed fit: only {len(pairs)} skin vertices face the cushion")
    tri = p.mask_contact[hits.triangle[pairs]]
    wts = hits.barycentric[pairs]
    g0 = hits.distance[pairs] - behind
    # face: skin vertices pushed along +a (into the face)
    k = p.model.rest_hessian
    n3t = 3 * nt
    fixed = np.repeat(np.asarray(p.model.fixed), 3)
    face_body = condense(k[:n3t, :n3t], fixed[:n3t], p.skin_vertices[pairs], np.tile(a, (len(pairs), 1)))
    # cushion: its skin-side vertices pushed along -a (out of the face), the rigid shell fixed
    nodes, inv = np.unique(tri.ravel(), return_inverse=True)
    mask_fixed = fixed[n3t:].copy()
    mask_fixed[(3 * (p.shell_vertices - nt)[:, None] + np.arange(3)).ravel()] = True
    cushion_body = condense(k[n3t:, n3t:], mask_fixed, nodes - nt, np.tile(-a, (len(nodes), 1)))
    bmat = np.zeros((len(pairs), len(nodes)))
    np.add.at(bmat, (np.repeat(np.arange(len(pairs)), 3), inv), wts.ravel())
    w = face_body.compliance + bmat @ cushion_body.compliance @ bmat.T
    # rigid motion of the cushion points: translation along a, pitch and yaw about the airway centre
    pts = np.einsum("mk,mkd->md", wts, x[tri])
    cols = [np.ones(len(pairs))]
    if p.options.rotate:
        rel = pts - p.mask.airway_center
        lateral = np.cross(p.mask.up, -a)
        for e in (lateral / np.linalg.norm(lateral), p.mask.up):
            cols.append(np.cross(e, rel) @ a / _ROT_RADIUS)
    jac = np.column_stack(cols)
    return CondensedFit(p, pairs, tri, wts, nodes, bmat, g0, jac, w, face_body, cushion_body,
                        time.perf_counter() - t0)


def condensed_fit(cf: CondensedFit, force: float, *, warm_active: np.ndarray | None = None) -> FitResult:
    """One force-controlled fit on a condensed problem: strap force ``force`` (N). Same outputs as
    :func:`headsim.mask.fit.problem_fit` (``newton_iterations`` counts active-set iterations)."""
    from headsim.solvers.contact_qp import solve_contact_lcp

    force = check_force(force)
    t0 = time.perf_counter()
    p = cf.problem
    r = cf.jacobian.shape[1]
    load = np.zeros(r)
    load[0] = force
    # the QP is strictly convex (W positive definite): its solution does not depend on the start,
    # so the last active set is a safe warm start
    start = warm_active if warm_active is not None else cf.cache.get("active")
    res = solve_contact_lcp(cf.compliance, cf.gaps0, cf.jacobian, load, initial_active=start)
    cf.cache["active"] = res.active
    lam = res.forces
    a = p.approach
    x0 = p.model.rest_positions
    nt = p.n_tissue
    # deformed bodies: elastic displacements + the mask's rigid motion
    ut = cf.tissue.displacements(lam)
    uc = cf.cushion.displacements(cf.weights_matrix.T @ lam)
    xm = x0[nt:]
    rigid = np.outer(np.full(len(xm), res.rigid[0]), a)
    if r > 1:
        lateral = np.cross(p.mask.up, -a)
        rel = xm - p.mask.airway_center
        for qk, e in zip(res.rigid[1:], (lateral / np.linalg.norm(lateral), p.mask.up)):
            rigid += qk * np.cross(e, rel) / _ROT_RADIUS
    x = np.vstack([x0[:nt] + ut, xm + uc + rigid])
    n_face = p.face.n_vertices
    skin_face = p.crop_face_ids[cf.pairs]
    pressure = np.zeros(n_face)
    pressure[skin_face] = lam / p.skin_areas[cf.pairs]
    areas = np.zeros(n_face)
    areas[p.crop_face_ids] = p.skin_areas
    gap = np.full(n_face, np.inf)
    gap[skin_face] = res.gaps
    contact_force = float(lam.sum())
    # bone reaction: the stiffness times the displacement at the fixed tissue dofs
    n3t = 3 * nt
    fixed = np.repeat(np.asarray(p.model.fixed[:nt]), 3)
    reaction = (p.model.rest_hessian[:n3t, :n3t] @ ut.ravel())[fixed].reshape(-1, 3)
    support = -float((reaction @ a).sum())
    balance = abs(contact_force - force) / force
    summary = summarize_pressure(pressure, areas, p.options.pressure_threshold)
    fv = p.face.vertices.copy()
    fv[p.crop_face_ids] = x[p.skin_vertices]
    deformed_face = p.face.with_vertices(fv)
    from headsim.errors import MeshError

    try:
        deformed_mask = p.mask.with_vertices(x[nt:])
    except MeshError as e:
        raise ConvergenceError(f"condensed fit at {force:g} N: the linear cushion displacement inverts "
                               f"elements ({e}); the load is beyond the linear model, use the nonlinear fit") from None
    seal = analyse_seal(deformed_face, pressure, p.airway, therapy_pressure_pa=p.options.therapy_pressure, gap=gap)
    u = res.rigid
    return FitResult(
        force=force, contact_force=contact_force, support_force=support, balance_error=balance,
        pressure=pressure, areas=areas, summary=summary, seal=seal, gap=gap, deformed_face=deformed_face,
        deformed_mask=deformed_mask, mask_displacement=float(u[0]),
        mask_rotation_deg=tuple(np.degrees(u[1:] / _ROT_RADIUS).tolist()),
        state=FitState(x, tuple(u.tolist()), force), newton_iterations=res.iterations, contact_updates=0,
        seconds=time.perf_counter() - t0, mode="condensed", leak=fit_leak(p, deformed_face, deformed_mask, pressure))
