"""The coupled contact solve's exact final solve (``ChainOptions.exact_final_solve``): small systems' contact and
joint rows solved by an active-set method on the bodies' mass matrix (minimum-norm Schur-complement solves, the
friction polygons of :class:`headsim.solvers.chains_model.FrictionLaw`), replacing the capped Gauss–Seidel answer
when it is consistent (SI units)."""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from headsim.solvers._kernels import chains as K
from headsim.solvers.chains_model import _scaled_frames


def _tangent_frames(axis: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k, 3) t₁, t₂ of the coupled kernel's friction frames, from the kernel's own
    ``_kernels.chains._frame`` (t₁ from the segment axis), so the exact solve's friction rows are the
    Gauss–Seidel's."""
    frames = [K._frame(np.ascontiguousarray(a), np.ascontiguousarray(b)) for a, b in zip(axis, n)]
    if not frames:
        return np.zeros((0, 3)), np.zeros((0, 3))
    t1, t2 = zip(*frames)
    return np.array(t1), np.array(t2)


# largest |C u − target| of an accepted exact solve round (consistent rows): this absolute part (m/s) plus this
# relative part of the largest velocity change the rows demand, |target − C u_free| (the least-squares truncation
# at 1e-11 of the scaled Schur complement leaves 1e-10 of it on consistent rows: the 4-layer stack's first step at
# the default 30 sweeps, 2.2e-12 m/s of 1e-2 m/s; truly inconsistent rows there miss by 1e-9-3e-9 m/s)
EXACT_VELOCITY_TOLERANCE = 1e-12
EXACT_RELATIVE_TOLERANCE = 1e-9
EXACT_MAX_DOF = 600  # degrees of freedom (6 per body) of the largest system the exact final solve takes
EXACT_FAILURES: dict = {}  # reason -> count of _exact_final_solve results that were not used (diagnostics)


def _fail(reason):
    EXACT_FAILURES[reason] = EXACT_FAILURES.get(reason, 0) + 1
    return None


def _polygon_radius(px: np.ndarray, py: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(k,) distance from the origin to the boundary of the convex friction polygon (vertices px, py, CCW, per unit
    λ) along the directions of the (k, 2) vectors f (0 for a frictionless law)."""
    if not len(px) or np.hypot(px, py).max() == 0.0:
        return np.zeros(len(f))
    qx, qy = np.roll(px, -1), np.roll(py, -1)
    nx, ny = qy - py, px - qx  # outward edge normals (CCW polygon)
    h = nx * px + ny * py
    d = f / np.maximum(np.linalg.norm(f, axis=1), 1e-300)[:, None]
    nd = d[:, 0:1] * nx[None, :] + d[:, 1:2] * ny[None, :]
    t = np.where(nd > 1e-300, h[None, :] / np.where(nd > 1e-300, nd, 1.0), np.inf)
    return t.min(1)


def _csr_entries(m):
    """Entries of a sparse matrix, row-major: ((rows, columns, values), CSR row pointer)."""
    m = scipy.sparse.csr_matrix(m)
    m.sum_duplicates()
    return (np.repeat(np.arange(m.shape[0]), np.diff(m.indptr)), m.indices, m.data), m.indptr


def _row_entries(coo, rows, scale=None):
    """Entries of the given rows of a matrix from :func:`_csr_entries`, as (local row i of ``rows[i]``, column,
    value), the values multiplied by ``scale[i]`` when given."""
    (r, c, v), ptr = coo
    counts = ptr[rows + 1] - ptr[rows]
    idx = np.repeat(ptr[rows] - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())
    local = np.repeat(np.arange(len(rows)), counts)
    return local, c[idx], v[idx] if scale is None else v[idx] * scale[local]


def _join_entries(*parts):
    """Entries of several row blocks stacked, each shifted down by the row counts of the blocks before it:
    parts are (entries, row count)."""
    out, off = [], 0
    for (lr, c, v), n_rows in parts:
        out.append((lr + off, c, v))
        off += n_rows
    return tuple(np.concatenate(x) for x in zip(*out))


def _active_set_rows(N, joints, J, A, stick, ratio):
    """One round of :func:`_exact_final_solve`: the constraint rows C and the directions D their multipliers act
    along, sparse (m, N), from the joint rows ``joints`` = (entries, row count) and the contact rows J (normal,
    t₁, t₂: :func:`_csr_entries` of (rows, N) each) of the active rows A with their sticking flags. C: the joints,
    the active rows' normal rows, the sticking rows' t₁ rows then their t₂ rows (T u = 0); D: the same, except
    that a sliding row's impulse acts along n + its friction ratio (``ratio[A]``) · (t₁, t₂)."""
    na, ns = len(A), int(stick.sum())
    At = A[stick]
    normal = _row_entries(J[0], A)
    effective = _join_entries((normal, 0), (_row_entries(J[1], A, np.where(stick, 0.0, ratio[A, 0])), 0),
                              (_row_entries(J[2], A, np.where(stick, 0.0, ratio[A, 1])), 0))
    tangent = ((_row_entries(J[1], At), ns), (_row_entries(J[2], At), ns))
    m = joints[1] + na + 2 * ns
    cr, cc, cv = _join_entries(joints, (normal, na), *tangent)
    ir, ic, iv = _join_entries(joints, (effective, na), *tangent)
    return (scipy.sparse.csr_matrix((cv, (cr, cc)), shape=(m, N)),
            scipy.sparse.csr_matrix((iv, (ir, ic)), shape=(m, N)))


def _min_norm_solve(mobility, u_free, C, D, target, cond=1e-11):
    """Solve M̃ u − Dᵀλ = M̃ u_free, C u = target (velocities m/s, multipliers N s) through the Schur complement
    S = C M̃⁻¹ Dᵀ (``mobility``: a factorisation of M̃ with ``solve``): λ is the least-squares solution of least
    norm of S λ = target − C u_free (S scaled symmetrically by |diag S|^-½; singular values below ``cond`` × the
    largest are dropped), so redundant rows (two segments' end rows at one joint, rows of one contact through a
    joint) share their load instead of taking arbitrary opposite ones. Returns (u, λ, largest |C u − target|,
    largest |target − C u_free|, the velocity change the rows demand): a residual above round-off of the latter
    means the rows are inconsistent."""
    if C.shape[0] == 0:
        return u_free, np.zeros(0), 0.0, 0.0
    X = mobility.solve(D.T.toarray())
    S = np.asarray(C @ X)
    g = target - C @ u_free
    d = np.abs(np.diag(S))
    sc = 1.0 / np.sqrt(np.maximum(d, 1e-30 * max(d.max(), 1e-300)))
    # gelsy (complete orthogonal factorisation) gives the least-norm solution as gelsd (SVD) does, ≈ 2× faster here
    y = scipy.linalg.lstsq(S * sc[:, None] * sc[None, :], g * sc, cond=cond, lapack_driver="gelsy")[0]
    lam = y * sc
    u = u_free + X @ lam
    return u, lam, float(np.abs(C @ u - target).max()), float(np.abs(g).max())


def _penetrating_fibre_rows(rows) -> np.ndarray:
    """Indices of the fibre–fibre rows with a negative gap (``ChainOptions.persistent_normals``: the rows whose
    normal side is kept from one step to the next)."""
    return np.flatnonzero((rows.gap < 0.0) & (rows.partner >= 0))


def _body_mass_matrix(mass, inertia_world):
    """Sparse (6n, 6n) block-diagonal mass matrix of n bodies: m I₃ (kg) then the world inertia (kg m²)."""
    n = len(mass)
    blocks = np.zeros((n, 6, 6))
    blocks[:, [0, 1, 2], [0, 1, 2]] = mass[:, None]
    blocks[:, 3:, 3:] = inertia_world
    return scipy.sparse.block_diag(list(blocks), format="csr") if n else scipy.sparse.csr_matrix((0, 0))


def _skew_entries(r):
    """(k, 3, 3) skew matrices r̃ (r̃ b = r × b) of the (k, 3) vectors r."""
    s = np.zeros((len(r), 3, 3))
    s[:, 0, 1], s[:, 0, 2], s[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
    s[:, 1, 0], s[:, 2, 0], s[:, 2, 1] = r[:, 2], -r[:, 1], r[:, 0]
    return s


def _blocks_to_csr(row_block, col_start, blocks, shape):
    """Sparse matrix of 3 × 3 blocks: block i at rows 3 row_block[i] … +3, columns col_start[i] … +3."""
    r = 3 * row_block[:, None, None] + np.arange(3)[None, :, None] + np.zeros((1, 1, 3), np.int64)
    c = col_start[:, None, None] + np.arange(3)[None, None, :] + np.zeros((1, 3, 1), np.int64)
    return scipy.sparse.csr_matrix((blocks.reshape(-1), (r.reshape(-1), c.reshape(-1))), shape=shape)


def _joint_matrices(l, k, rk, rl, N):
    """Joint rows of :func:`_exact_final_solve` over local bodies (body l, body k or −1 for the anchor, anchors
    rk, rl in world axes, m): S (3 nj, N) the spin difference ω_l − ω_k and G (3 nj, N) the anchor velocity
    difference (v_k + ω_k × r_k) − (v_l + ω_l × r_l) (eqs. 8.81–8.85)."""
    nj = len(l)
    j = np.arange(nj)
    has_k = k >= 0
    eye = np.broadcast_to(np.eye(3), (nj, 3, 3))
    jk, kk = j[has_k], 6 * k[has_k]
    S = _blocks_to_csr(np.concatenate([j, jk]), np.concatenate([6 * l + 3, kk + 3]),
                       np.concatenate([eye, -eye[has_k]]), (3 * nj, N))
    G = _blocks_to_csr(np.concatenate([j, j, jk, jk]), np.concatenate([6 * l, 6 * l + 3, kk, kk + 3]),
                       np.concatenate([-eye, _skew_entries(rl), eye[has_k], -_skew_entries(rk[has_k])]),
                       (3 * nj, N))
    return S, G


def _contact_matrix(a, b, lever_a, lever_b, d, N):
    """(rows, N) sparse contact rows along the unit directions d (rows, 3): body a's point velocity
    v_a + ω_a × r_a minus partner b's (b = −1: an obstacle), projected on d."""
    nr = len(a)
    i = np.arange(nr)
    hb = b >= 0
    rows = np.concatenate([np.repeat(i, 6), np.repeat(i[hb], 6)])
    cols = np.concatenate([(6 * a[:, None] + np.arange(6)).reshape(-1), (6 * b[hb, None] + np.arange(6)).reshape(-1)])
    vals = np.concatenate([np.concatenate([d, np.cross(lever_a, d)], 1).reshape(-1),
                           -np.concatenate([d[hb], np.cross(lever_b[hb], d[hb])], 1).reshape(-1)])
    return scipy.sparse.csr_matrix((vals, (rows, cols)), shape=(nr, N))


def _exact_bodies(rows, joints):
    """The bodies of the exact system, sorted: every body of the contact rows and the joints."""
    jk, jl = joints[0], joints[1]
    return np.unique(np.concatenate([rows.body, rows.partner[rows.partner >= 0], jk[jk >= 0], jl]))


def _exact_system(model, rows, u_minus, R_mid, joints, used):
    """The linear pieces of :func:`_exact_final_solve` over the bodies ``used`` (their local order): M̃ = M + SᵀCS
    (sparse (N, N), N = 6 len(used); M block diagonal m I₃, I_world at R_mid; S the joints' spin differences
    ω_l − ω_k, C their spring rows), the momentum M u⁻ + SᵀC ω_rel,0 (N,), the joints' gap-rate rows G (3 nj, N):
    (v_k + ω_k × r_k) − (v_l + ω_l × r_l), and the contact rows J = [normal, t₁, t₂] (each (rows, N), t₁ from
    the body's axis)."""
    jk, jl, jrk, jrl, _, jc, jw0, _ = joints
    n = len(used)
    N = 6 * n
    loc = np.full(model.n_segments, -1, np.int64)
    loc[used] = np.arange(n)
    M = _body_mass_matrix(model.mass[used], _scaled_frames(R_mid[used], model.inertia[used]))
    S, G = _joint_matrices(loc[jl], np.where(jk >= 0, loc[np.maximum(jk, 0)], -1), jrk, jrl, N)
    Cb = scipy.sparse.block_diag(list(jc), format="csr") if len(jl) else scipy.sparse.csr_matrix((0, 0))
    Mt = (M + S.T @ Cb @ S).tocsr()
    rhs = M @ u_minus[used].reshape(-1) + S.T @ (Cb @ jw0.reshape(-1))
    t1, t2 = _tangent_frames(R_mid[rows.body, :, 2], rows.normal)
    partner = rows.partner
    pb = np.where(partner >= 0, loc[np.maximum(partner, 0)], -1)
    J = [_contact_matrix(loc[rows.body], pb, rows.lever, rows.partner_lever, d, N) for d in (rows.normal, t1, t2)]
    return Mt, rhs, G, J


def _exact_final_solve(model, rows, lam, fr, targets, u_minus, R_mid, joints, polygon, max_dof=EXACT_MAX_DOF,
                       rounds=8):
    """The velocity solve's problem solved exactly (Schur complement, :func:`_min_norm_solve`) on the active set the
    Gauss–Seidel found (``ChainOptions.exact_final_solve``): rows with λ > 0 hold J u = target (targets (rows,)
    m/s), a sticking contact (friction strictly inside the polygon λ·conv{μ_β d_β} at the Gauss–Seidel answer)
    T u = 0, a sliding one keeps the direction and ratio to λ of its friction impulse; the joints J u = target
    and their spring rows (``joints``: :meth:`ChainSolver._joint_rows`) exactly, M at R_mid. Rows whose λ comes
    out negative leave the set, rows whose bound is violated by more than 1e-12 m/s join it, sticking friction
    outside the polygon slides (on the polygon along its direction), sliding friction that would accelerate its
    contact sticks, until nothing changes (at most ``rounds`` times; a set met twice ends it). Returns (u (S, 6),
    λ (rows,), friction (rows, 2)) or None (the reason counted in :data:`EXACT_FAILURES`) when the system has more
    than ``max_dof`` degrees of freedom or no such set was found."""
    jl, jt = joints[1], joints[4]
    body = rows.body
    if 6 * len(np.unique(jl)) > max_dof:  # a lower bound of the bodies below, without the rows' unique
        return _fail("too large")
    used = _exact_bodies(rows, joints)
    n = len(used)
    N = 6 * n
    if N > max_dof or not len(body):
        return _fail("too large")
    Mt, rhs, G, J = _exact_system(model, rows, u_minus, R_mid, joints, used)
    nj, nr = len(jl), len(body)
    active = lam > 0
    ratio = np.zeros((nr, 2))
    ratio[active] = fr[active] / lam[active, None]
    px, py = polygon
    frictional = len(px) > 0 and np.hypot(px, py).max() > 0.0
    stick = active & (np.linalg.norm(ratio, axis=1) < _polygon_radius(px, py, ratio) * (1.0 - 1e-6))
    # M̃ is sparse (block-tridiagonal chains): one SuperLU factor serves every round
    G_e = _csr_entries(G)
    Je = [_csr_entries(j) for j in J]
    try:
        mobility = scipy.sparse.linalg.splu(Mt.tocsc())
    except RuntimeError:  # SuperLU: "Factor is exactly singular"
        return _fail("singular")
    u_free = mobility.solve(rhs)
    seen = set()  # the (active, sticking) sets tried: a set met again is a cycle, which no further round leaves
    for _ in range(rounds):
        key = (active.tobytes(), stick.tobytes())
        if key in seen:
            return _fail("active set cycles")
        seen.add(key)
        A = np.nonzero(active)[0]
        st = stick[A]
        na, ns = len(A), int(st.sum())
        Ast, Asl = A[st], A[~st]
        Cm, Dm = _active_set_rows(N, (G_e[0], 3 * nj), Je, A, st, ratio)
        target = np.concatenate([jt.reshape(-1), targets[A], np.zeros(2 * ns)])
        u, sol, residual, demanded = _min_norm_solve(mobility, u_free, Cm, Dm, target)
        if not np.isfinite(u).all() or not np.isfinite(sol).all():
            return _fail("singular")
        if residual > EXACT_VELOCITY_TOLERANCE + EXACT_RELATIVE_TOLERANCE * demanded:
            # inconsistent equalities (rows of one constraint with different targets): the rows the least-squares
            # velocity over-satisfies would be slack; leave them out
            over = (J[0] @ u)[A] > targets[A] + 1e-12
            if not over.any():
                return _fail("inconsistent")
            active[A[over]] = False
            continue
        lam_a = sol[3 * nj:3 * nj + na]
        f_s = sol[3 * nj + na:].reshape(2, ns).T
        changed = False
        neg = lam_a < 0
        if neg.any():
            active[A[neg]] = False
            changed = True
        viol = (J[0] @ u < targets - 1e-12) & ~active
        if viol.any():
            active |= viol
            ratio[viol] = 0.0
            stick |= viol & frictional
            changed = True
        # friction: a sticking force outside the inner cone slides (its direction, on the cone), a sliding
        # force that would accelerate its contact sticks
        rho = _polygon_radius(px, py, f_s)
        out_cone = np.linalg.norm(f_s, axis=1) > rho * np.maximum(lam_a[st], 0.0)
        if out_cone.any():
            r = Ast[out_cone]
            f = f_s[out_cone]
            ratio[r] = rho[out_cone, None] * f / np.maximum(np.linalg.norm(f, axis=1), 1e-300)[:, None]
            stick[r] = False
            changed = True
        vt = np.stack([(J[1] @ u)[Asl], (J[2] @ u)[Asl]], 1)
        fv = (ratio[Asl] * vt).sum(1)
        acc = fv > 1e-9 * np.linalg.norm(ratio[Asl], axis=1) * np.linalg.norm(vt, axis=1)
        if acc.any() and frictional:
            stick[Asl[acc]] = True
            changed = True
        elif acc.any():
            return _fail("sliding friction accelerates")
        if not changed:
            break
    else:
        return _fail("active set")
    lam_new = np.zeros(nr)
    lam_new[A] = lam_a
    fr_new = np.zeros((nr, 2))
    fr_new[Asl] = ratio[Asl] * lam_new[Asl, None]
    fr_new[Ast] = f_s
    out = u_minus.copy()
    out[used] = u.reshape(n, 6)
    return out, lam_new, fr_new
