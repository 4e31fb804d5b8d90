"""The seed's collision response (Heinze §3.4): naive shortest way out vs. consistent directions (fig. 3.1)."""

from dataclasses import replace

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.solvers.contact_consistent import SeedCollisionForce, exit_points
from headsim.solvers.grids import block_tetmesh
from headsim.solvers.integrators import SymplecticEuler
from headsim.solvers.massspring import combine_mass_spring, mass_spring_from_tetmesh
from headsim.solvers.state import BodyState


def _slab_scene():
    """Body A (4 x 3 x 4 cm) pushed 8 mm into a fixed 1 cm thick slab B: fig. 3.1 in 3-D.

    A's vertex layers at y = 2 mm and 7 mm lie inside B; the first is nearer B's far (bottom) face,
    the second nearer the top face, so their shortest ways out point in opposite directions.
    """
    slab = block_tetmesh((0.1, 0.01, 0.1), (4, 1, 4), origin=(-0.05, 0.0, -0.05))
    slab = replace(slab, fixed=np.ones(slab.n_vertices, dtype=bool))
    a = block_tetmesh((0.04, 0.03, 0.04), (4, 6, 4), origin=(-0.02, 0.002, -0.02))
    ma = mass_spring_from_tetmesh(a, stiffness=5.0, total_mass=1.0, damping=0.05)
    mb = mass_spring_from_tetmesh(slab, stiffness=5.0, total_mass=0.1)
    model, off = combine_mass_spring([ma, mb])
    return model, off, [a.boundary_triangles, slab.boundary_triangles + off[1]]


def _opposite_neighbours(model, res, n_a):
    e = model.edges[(model.edges < n_a).all(axis=1)]
    local_dir = np.zeros((n_a, 3))
    local_dir[res.valid] = res.direction[res.valid]
    both = res.valid[e[:, 0]] & res.valid[e[:, 1]]
    dots = np.einsum("ij,ij->i", local_dir[e[both, 0]], local_dir[e[both, 1]])
    return dots


def test_naive_directions_tear_body_apart_consistent_ones_do_not():
    model, off, surfaces = _slab_scene()
    x = model.rest_positions
    v = np.zeros_like(x)
    naive = SeedCollisionForce(model.body, surfaces, model.edges, stiffness=1.0, method="naive", bodies=[0, 1])
    cons = SeedCollisionForce(model.body, surfaces, model.edges, stiffness=1.0, method="consistent", bodies=[0, 1])
    f_naive, f_cons = naive(x, v), cons(x, v)
    r_naive, r_cons = naive.last[(0, 1)], cons.last[(0, 1)]
    assert r_naive.inside.sum() == r_cons.inside.sum() == 50
    y = x[:off[1], 1]
    low, high = r_cons.inside & np.isclose(y, 0.002), r_cons.inside & np.isclose(y, 0.007)
    # naive: the lower layer is pushed down (through the slab), the upper layer up: opposite directions
    assert np.allclose(r_naive.direction[low], [0, -1, 0]) and np.allclose(r_naive.direction[high], [0, 1, 0])
    assert (_opposite_neighbours(model, r_naive, off[1]) < -0.99).sum() > 0
    assert np.all(f_naive[:off[1]][low, 1] < 0) and np.all(f_naive[:off[1]][high, 1] > 0)
    # consistent: border points (springs crossing the top face, eqs. 3.9-3.11) and the BFS (3.12-3.13)
    assert np.all(r_cons.border[high]) and not np.any(r_cons.border[low])
    assert np.allclose(r_cons.direction[low | high], [0, 1, 0], atol=1e-12)
    assert np.allclose(r_cons.depth[high], 0.003, rtol=1e-9)  # eq. 3.9: to the top face
    assert np.allclose(r_cons.depth[low], 0.008, rtol=1e-9)  # eq. 3.12: 5 mm deeper
    assert np.all(_opposite_neighbours(model, r_cons, off[1]) > 0.999)
    assert np.all(f_cons[:off[1]][low | high, 1] > 0)


def test_consistent_force_pushes_body_out_naive_force_leaves_it_stuck():
    model, off, surfaces = _slab_scene()
    out = {}
    for method in ("naive", "consistent"):
        col = SeedCollisionForce(model.body, surfaces, model.edges, stiffness=1.0, method=method, bodies=[0, 1])
        st = BodyState.at_rest(model.rest_positions)
        for _ in range(100):
            st = SymplecticEuler().step(model, st, 0.005, extra_forces=col)
        col(st.positions, st.velocities)
        out[method] = (col.last[(0, 1)].inside.sum(), st.positions[:off[1], 1].min())
    assert out["consistent"][0] == 0 and out["consistent"][1] > 0.01  # completely out of the slab
    assert out["naive"][0] > 0 and out["naive"][1] < 0.005  # lower layer still held inside


def test_points_without_border_fall_back_to_shortest_way_out():
    slab = block_tetmesh((0.1, 0.02, 0.1), (2, 1, 2), origin=(-0.05, 0.0, -0.05))
    inner = block_tetmesh((0.01, 0.004, 0.01), (1, 1, 1), origin=(-0.005, 0.012, -0.005))  # entirely inside
    res = exit_points(inner.vertices, np.arange(inner.n_vertices), slab.vertices, slab.boundary_triangles,
                      "consistent", inner.edges)
    assert res.inside.all() and res.valid.all() and not res.border.any()
    assert np.allclose(res.direction, [0, 1, 0])  # nearest face is the top one
    assert np.allclose(res.depth, 0.02 - inner.vertices[:, 1])
    with pytest.raises(ParameterError):
        exit_points(inner.vertices, np.arange(8), slab.vertices, slab.boundary_triangles, "consistent", None)
    with pytest.raises(ParameterError):
        exit_points(inner.vertices, np.arange(8), slab.vertices, slab.boundary_triangles, "other", inner.edges)


def test_relative_velocity_damping_term_eq_3_7_3_8():
    model, off, surfaces = _slab_scene()
    x = model.rest_positions
    v = np.zeros_like(x)
    v[:off[1], 1] = -0.1  # A moving down into the fixed slab
    col = SeedCollisionForce(model.body, surfaces, model.edges, stiffness=1.0, damping=2.0, method="consistent",
                             bodies=[0, 1])
    f = col(x, v)
    f0 = SeedCollisionForce(model.body, surfaces, model.edges, stiffness=1.0, damping=0.0, method="consistent",
                            bodies=[0, 1])(x, v)
    inside = col.last[(0, 1)].valid
    # v_rel = v_body - v_mass = 0 - (-0.1) along r = +y: extra force 2.0 * 0.1 N up on each colliding point
    assert np.allclose((f - f0)[:off[1]][inside, 1], 0.2)
    assert np.allclose((f - f0)[:off[1]][~inside], 0.0)


def test_bfs_kernel_matches_reference():
    import scipy.sparse as sp

    from headsim.solvers._kernels.contact import bfs_propagate
    from headsim.solvers._reference import bfs_propagate_reference

    rng = np.random.default_rng(5)
    mesh = block_tetmesh((0.03, 0.03, 0.03), (3, 3, 3))
    n = mesh.n_vertices
    x = mesh.vertices + 1e-3 * rng.standard_normal((n, 3))
    e = mesh.edges
    adj = sp.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n))
    colliding = x[:, 2] < 0.02
    assigned = colliding & (mesh.vertices[:, 2] > 0.015)  # seeds
    depth = np.where(assigned, rng.uniform(0, 1e-3, n), 0.0)
    direction = np.zeros((n, 3))
    d = rng.standard_normal((n, 3)) + [0, 0, 3]
    direction[assigned] = (d / np.linalg.norm(d, axis=1, keepdims=True))[assigned]
    ids = np.arange(n)
    want = bfs_propagate_reference(x, ids, colliding, assigned, depth, direction,
                                   [list(adj.indices[adj.indptr[i]:adj.indptr[i + 1]]) for i in range(n)])
    got_assigned, got_depth, got_dir = assigned.copy(), depth.copy(), direction.copy()
    bfs_propagate(x, ids, colliding, got_assigned, got_depth, got_dir, adj.indptr.astype(np.int64),
                  adj.indices.astype(np.int64))
    assert np.array_equal(got_assigned, want[0]) and got_assigned[colliding].all()
    assert np.allclose(got_depth, want[1], rtol=1e-12, atol=1e-15)
    assert np.allclose(got_dir, want[2], rtol=1e-12, atol=1e-15)
