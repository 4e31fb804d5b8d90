"""Lagged friction over the barrier's pairs (headsim.solvers.barrier_friction): the same potential as the
IPC Toolkit's FrictionPotential with its own tangent planes, and smoothed tangent planes that are the
surfaces' where ipctk's edge-edge planes are arbitrary (nearly parallel edges)."""

import numpy as np
import pytest

ipctk = pytest.importorskip("ipctk")

from headsim.mesh.geometry import vertex_normals  # noqa: E402
from headsim.solvers.barrier_friction import LaggedFriction  # noqa: E402

DHAT = 0.05
CREASE = 0.2  # z = CREASE |x|: a 22.6 deg fold along x = 0


def _grid(n, half):
    xs = np.linspace(-half, half, n)
    x, y = np.meshgrid(xs, xs)
    v = np.c_[x.ravel(), y.ravel(), np.zeros(n * n)]
    f = [[i * n + j, i * n + j + 1, (i + 1) * n + j + 1] for i in range(n - 1) for j in range(n - 1)]
    f += [[i * n + j, (i + 1) * n + j + 1, (i + 1) * n + j] for i in range(n - 1) for j in range(n - 1)]
    return v, np.array(f)


def _mesh(v, f):
    f = np.asfortranarray(f, dtype=np.int32)
    mesh = ipctk.CollisionMesh(np.asfortranarray(v), np.asfortranarray(ipctk.edges(f)), f)
    mesh.can_collide = ipctk.make_connected_components_filter(f)
    return mesh


def _tangential(mesh, v, mu=0.4):
    c = ipctk.NormalCollisions()
    c.use_area_weighting = True
    c.collision_set_type = ipctk.NormalCollisions.IMPROVED_MAX_APPROX
    c.build(mesh, np.asfortranarray(v), DHAT)
    t = ipctk.TangentialCollisions()
    t.build(mesh, np.asfortranarray(v), c, ipctk.BarrierPotential(ipctk.NormalizedClampedLogBarrier(), DHAT, 1e3, True), mu)
    return t


def _two_creased_sheets():
    """A creased sheet and a smaller, slightly tilted and shifted copy 0.02 above it: point-triangle,
    edge-vertex and edge-edge pairs (checked below)."""
    v1, f1 = _grid(6, 1.0)
    v1[:, 2] = CREASE * np.abs(v1[:, 0])
    v2, f2 = _grid(5, 0.6)
    v2[:, 2] = CREASE * np.abs(v2[:, 0]) + 0.02 + 0.01 * v2[:, 1]
    v2[:, :2] += [0.05, 0.03]
    return np.vstack([v1, v2]), np.vstack([f1, f2[:, ::-1] + len(v1)])


@pytest.mark.parametrize("scale", [3e-4, 5e-3])  # slips below (sticking) and above (sliding) eps
def test_with_the_pairs_own_planes_it_is_ipctks_friction_potential(scale):
    v, f = _two_creased_sheets()
    mesh = _mesh(v, f)
    t = _tangential(mesh, v)
    assert min(len(t.fv_collisions), len(t.ev_collisions), len(t.ee_collisions)) > 0
    eps = 1e-3
    u = np.asfortranarray(np.random.default_rng(1).normal(size=v.shape) * scale)
    ours = LaggedFriction(t, mesh, v, eps, normals="pair")
    ref = ipctk.FrictionPotential(eps)
    assert ours.energy(u) == pytest.approx(ref(t, mesh, u), rel=1e-12)
    g_ref = ref.gradient(t, mesh, u)
    assert np.abs(ours.gradient(u).ravel() - g_ref).max() <= 1e-12 * np.abs(g_ref).max()
    h_ref = ref.hessian(t, mesh, u, ipctk.PSDProjectionMethod.NONE)
    assert abs(ours.hessian(u) - h_ref).max() <= 1e-12 * abs(h_ref).max()


def test_smoothed_potential_gradient_and_hessian_are_its_derivatives():
    v, f = _two_creased_sheets()
    mesh = _mesh(v, f)
    rng = np.random.default_rng(2)
    fr = LaggedFriction(_tangential(mesh, v), mesh, v, 1e-3)
    for scale in (3e-4, 5e-3):
        u = rng.normal(size=v.shape) * scale
        d = rng.normal(size=v.shape) * 1e-7
        assert (fr.energy(u + d) - fr.energy(u - d)) / 2 == pytest.approx(np.sum(fr.gradient(u) * d), rel=1e-6)
        hd = fr.hessian(u) @ d.ravel()
        fd = (fr.gradient(u + d) - fr.gradient(u - d)).ravel() / 2
        assert np.abs(fd - hd).max() <= 1e-5 * np.abs(hd).max()
        # projected: positive semi-definite; exact: not (pairs of negative weight, module doc)
        h = fr.hessian(u, project=True).toarray()
        assert np.linalg.eigvalsh(h).min() >= -1e-9 * np.abs(h).max()
    assert fr.coeff.min() < 0


def test_between_two_nearly_parallel_sheets_the_smoothed_planes_are_the_sheets():
    """Two flat sheets 0.02 apart, the upper one turned and tilted by 1e-3 rad (a cushion lying on skin):
    ipctk's plane of an edge-edge pair is spanned by edge a and (e_a x e_b) x e_a, and for two nearly
    parallel edges e_a x e_b points anywhere in the plane normal to e_a (here it mixes the 1e-3 turn
    and the 1e-3 tilt: up to 65 deg from the sheets' normal), so sliding the upper sheet across the
    edges is partly taken as normal motion. The smoothed normals are the sheets' to the tilt (1e-3 rad
    = 0.057 deg), and the friction on the sliding sheet lies in its plane to that angle."""
    v1, f1 = _grid(6, 1.0)
    v2, f2 = _grid(5, 0.6)
    a = 1e-3
    turn = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    tilt = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    v2 = v2 @ (tilt @ turn).T + [0.07, 0.11, 0.02]
    v, f = np.vstack([v1, v2]), np.vstack([f1, f2[:, ::-1] + len(v1)])
    mesh = _mesh(v, f)
    t = _tangential(mesh, v)
    assert len(t.ee_collisions) > 0
    u = np.zeros_like(v)
    u[len(v1):] = [0, 1e-2, 0]  # the upper sheet slides across the edges (sliding: 1e-2 >> eps)
    tilt_deg = {}
    for normals in ("pair", "smooth"):
        fr = LaggedFriction(t, mesh, v, 1e-3, normals=normals)
        tilt_deg[normals] = np.degrees(np.arccos(np.clip(np.abs(fr.normals[:, 2]), 0, 1)))
        if normals == "smooth":
            force = -fr.gradient(u)[len(v1):].sum(axis=0)
            assert abs(force[2]) <= np.sin(2 * a) * np.linalg.norm(force)
    assert tilt_deg["pair"].max() > 30.0
    assert tilt_deg["smooth"].max() <= np.degrees(2 * a)


def test_on_a_flat_face_the_smoothed_normal_is_the_face_normal():
    """A triangle parallel to one face of a creased sheet, over its interior away from the fold (all
    three vertex normals are that face's normal): every pair's smoothed normal is the face normal, the
    point-triangle pairs' as ipctk's (its edge-edge pairs between the parallel edges are arbitrary,
    the test above)."""
    v, f = _grid(7, 1.0)
    v[:, 2] = CREASE * np.abs(v[:, 0])
    face_normal = np.array([-CREASE, 0.0, 1.0]) / np.hypot(CREASE, 1.0)
    e1 = np.array([1.0, 0.0, CREASE]) / np.hypot(CREASE, 1.0)
    p = np.array([0.55, 0.05, CREASE * 0.55]) + 0.3 * DHAT * face_normal
    tri = p + np.array([[0, 0, 0], 0.1 * e1, [0, 0.1, 0]])  # parallel to the face, facing it
    v, f = np.vstack([v, tri]), np.vstack([f, np.array([[0, 2, 1]]) + len(v)])
    mesh = _mesh(v, f)
    t = _tangential(mesh, v)
    assert len(t.fv_collisions) > 0
    pair, smooth = (LaggedFriction(t, mesh, v, 1e-3, normals=m).normals for m in ("pair", "smooth"))
    assert np.abs(np.abs(smooth @ face_normal) - 1.0).max() <= 1e-12
    n_ev_ee = len(t.vv_collisions) + len(t.ev_collisions) + len(t.ee_collisions)
    fv = slice(n_ev_ee, None)  # LaggedFriction orders the pairs vv, ev, ee, fv
    assert np.abs(np.abs(pair[fv] @ face_normal) - 1.0).max() <= 1e-12


def test_vertex_normals_of_a_fold_lie_between_its_faces():
    v, f = _grid(5, 1.0)
    v[:, 2] = CREASE * np.abs(v[:, 0])
    n = vertex_normals(v, f)
    n *= np.sign(n[:, 2])[:, None]
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    half_fold = np.arctan(CREASE)
    off = ~np.isclose(v[:, 0], 0.0)
    # off the fold: the face normal (-+CREASE, 0, 1) / |..|; on it: within the two faces' normals
    assert np.allclose(n[off, 0], -np.sign(v[off, 0]) * np.sin(half_fold), atol=1e-12)
    assert np.all(np.abs(n[~off, 0]) < np.sin(half_fold)) and np.allclose(n[:, 1], 0, atol=1e-12)


def test_the_pairs_at_one_point_share_the_smoothed_normal():
    """A tent's ridge edge passes 0.3 dhat over a vertex of the creased sheet (the first surface): the
    vertex has several pairs (with the ridge and with the tent's faces through it; improved-max pairs
    that share a point must agree for their friction to add up as the barrier's forces do). ipctk's
    planes differ between them by 11 deg; the smoothed normals (the sheet's, interpolated at each
    pair's closest point on it, all next to the vertex) by less than 0.05 deg."""
    v, f = _grid(7, 1.0)
    v[:, 2] = CREASE * np.abs(v[:, 0])
    vertex = int(np.argmin(np.linalg.norm(v[:, :2] - [1 / 3, 0], axis=1)))
    normal = np.array([-CREASE, 0.0, 1.0]) / np.hypot(CREASE, 1.0)
    c = v[vertex] + 0.3 * DHAT * normal
    tent = np.vstack([np.array([[0.02, -0.2, 0.0], [-0.02, 0.2, 0.0]]) + c, c + [0.15, 0, 0.1], c + [-0.15, 0, 0.1]])
    v, f = np.vstack([v, tent]), np.vstack([f, np.array([[0, 1, 2], [1, 0, 3]]) + len(v)])
    mesh = _mesh(v, f)
    t = _tangential(mesh, v)
    spread = {}
    for normals in ("pair", "smooth"):
        fr = LaggedFriction(t, mesh, v, 1e-3, normals=normals)
        at_vertex = np.any((fr.ids == vertex) & (np.abs(fr.gamma) > 0.5), axis=1)
        n = fr.normals[at_vertex] * np.sign(fr.normals[at_vertex][:, 2:3])
        assert len(n) >= 3
        spread[normals] = np.degrees(np.arccos(np.clip((n @ n.T).min(), -1.0, 1.0)))
    assert spread["pair"] > 5.0
    assert spread["smooth"] < 0.05
