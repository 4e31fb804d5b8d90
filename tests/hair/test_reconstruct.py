"""Hairstyle reconstruction, stage by stage (Sobottka 2008 §5.3): parametrisation, maps and roots, rod shapes,
the objective, density models, the cut."""

import numpy as np
import pytest
from scipy.spatial import Delaunay

from headsim.errors import MeshError
from headsim.mesh.disk_parametrisation import disk_parametrisation, mean_value_weights, signed_areas_2d


@pytest.fixture(scope="module")
def head():
    import trimesh

    from headsim.data import head_path
    from headsim.mesh.surface import SurfaceMesh

    m = trimesh.load(head_path(), process=False)
    return SurfaceMesh(np.asarray(m.vertices, float), np.asarray(m.faces, np.int64))


@pytest.fixture(scope="module")
def scalp(head):
    from headsim.hair.reconstruct.inputs import bundled_scalp

    return bundled_scalp(head)


@pytest.fixture(scope="module")
def scalp_map(scalp):
    from headsim.hair.reconstruct.maps import ScalpMap

    return ScalpMap(scalp)


# --- parametrisation ------------------------------------------------------------------------------------------

def test_mean_value_map_reproduces_a_planar_disk():
    """Mean-value coordinates reproduce linear functions: a flat mesh whose boundary is a regular polygon on
    the unit circle maps onto itself (and its stretch is uniform, so relaxation keeps it)."""
    rng = np.random.default_rng(3)
    n_b = 40
    ang = 2 * np.pi * np.arange(n_b) / n_b
    bnd = np.column_stack([np.cos(ang), np.sin(ang)])
    r = 0.9 * np.sqrt(rng.random(300))
    phi = 2 * np.pi * rng.random(300)
    inner = np.column_stack([r * np.cos(phi), r * np.sin(phi)])
    pts = np.concatenate([bnd, inner])
    tri = Delaunay(pts).simplices
    tri = np.where((signed_areas_2d(pts, tri) < 0)[:, None], tri[:, ::-1], tri)
    v3 = np.column_stack([pts, np.zeros(len(pts))])
    p = disk_parametrisation(v3, tri)
    np.testing.assert_allclose(p.uv, pts, atol=1e-10)
    assert abs(p.stretch_history[0] - 1.0) < 1e-9


def test_mean_value_weights_are_positive(scalp):
    W = mean_value_weights(scalp.vertices, scalp.triangles)
    assert W.nnz > 0 and W.data.min() > 0


def test_scalp_parametrisation_is_a_bijection_and_relaxation_lowers_stretch(scalp_map):
    p = scalp_map.param
    t = scalp_map.scalp.triangles
    assert np.all(signed_areas_2d(p.uv, t) > 0)  # no flipped or degenerate parameter triangle
    np.testing.assert_allclose(np.linalg.norm(p.uv[p.boundary], axis=1), 1.0, atol=1e-12)
    interior = np.setdiff1d(np.arange(len(p.uv)), p.boundary)
    assert np.linalg.norm(p.uv[interior], axis=1).max() < 1.0
    # the parameter triangles tile the disk exactly once (area of the boundary polygon)
    b = p.uv[p.boundary]
    poly = 0.5 * np.sum(b[:, 0] * np.roll(b[:, 1], -1) - np.roll(b[:, 0], -1) * b[:, 1])
    assert signed_areas_2d(p.uv, t).sum() == pytest.approx(poly, rel=1e-12)
    h = p.stretch_history
    assert p.relaxation_passes >= 1 and h[-1] < h[0]
    assert all(b_ < a_ for a_, b_ in zip(h, h[1:]))


def test_parametrisation_rejects_non_disk_topology():
    from headsim.mesh.primitives import icosphere

    s = icosphere(2)
    with pytest.raises(MeshError, match="boundary loop"):
        disk_parametrisation(s.vertices, s.triangles)


# --- maps and roots -------------------------------------------------------------------------------------------

def _area_right_half(scalp_map) -> float:
    """Surface area of the scalp whose parameter point has u > 0 (triangles clipped by the line u = 0; the
    map is affine per triangle, so the surface area scales with the parameter area)."""
    uv = scalp_map.param.uv
    total = 0.0
    for k, tri in enumerate(scalp_map.scalp.triangles):
        poly = uv[tri]
        out = []
        for i in range(3):
            a, b = poly[i], poly[(i + 1) % 3]
            if a[0] > 0:
                out.append(a)
            if (a[0] > 0) != (b[0] > 0):
                t = a[0] / (a[0] - b[0])
                out.append(a + t * (b - a))
        if len(out) >= 3:
            q = np.array(out)
            a2 = 0.5 * abs(np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1]))
            full = 0.5 * abs(np.linalg.det(np.column_stack([poly[1] - poly[0], poly[2] - poly[0]])))
            total += scalp_map.areas[k] * a2 / full
    return total


def test_roots_follow_the_density_map(scalp_map):
    """Two-pixel density map, 100 and 300 roots/cm² on the halves u < 0 and u > 0: the count on the right half
    is Binomial(n, p) with p = 300 A_R / (100 A_L + 300 A_R); the bound is 4 standard deviations."""
    from headsim.hair.reconstruct.maps import TextureMap, default_maps

    dens = TextureMap(np.array([[85.0, 255.0]]), 300e4)  # grey 85 = 100 /cm²
    _, az, el, ln = default_maps(0.1)
    n = 20000
    roots = scalp_map.sample_roots(dens, az, el, ln, n=n, seed=5)
    assert len(roots) == n
    a_r = _area_right_half(scalp_map)
    a_l = scalp_map.area - a_r
    p = 300 * a_r / (100 * a_l + 300 * a_r)
    count = int((roots.uv[:, 0] > 0).sum())
    assert abs(count - n * p) <= 4 * np.sqrt(n * p * (1 - p))
    # the Poisson process has mean integral(rho dA)
    roots = scalp_map.sample_roots(TextureMap(np.array([[85.0, 255.0]]), 30e4), az, el, ln, n=None, seed=6)
    lam = (10 * a_l + 30 * a_r) * 1e4
    assert abs(len(roots) - lam) <= 4 * np.sqrt(lam)


def test_roots_lie_on_the_scalp_and_grow_outward(scalp_map):
    from headsim.collide.bvh import TriangleBVH
    from headsim.hair.reconstruct.maps import default_maps

    roots = scalp_map.sample_roots(*default_maps(0.07), n=500, seed=1)
    cp = TriangleBVH(scalp_map.scalp.vertices, scalp_map.scalp.triangles).closest_points(roots.positions)
    assert np.abs(cp.distance).max() < 1e-12
    np.testing.assert_allclose(np.linalg.norm(roots.directions, axis=1), 1.0, atol=1e-12)
    elev = np.degrees(np.arcsin(np.clip((roots.directions * roots.normals).sum(1), -1, 1)))
    assert elev.min() > 14.0 and elev.max() < 66.0  # the elevation map: 65° at the crown to 15° at the rim


# --- rod shapes and the objective -----------------------------------------------------------------------------

def test_batched_shapes_equal_pai_static():
    from headsim.hair.fibres import fibre_model
    from headsim.hair.reconstruct.growth import rod_shapes, rod_stiffness
    from headsim.solvers.rods import straight_frame
    from headsim.solvers.rods_statics import pai_static

    rng = np.random.default_rng(0)
    K = rod_stiffness()
    N, L = 20, 0.12
    d = rng.normal(size=(5, 3))
    nrm = rng.normal(size=(5, 3))
    R0 = np.stack([straight_frame(a, b) for a, b in zip(d, nrm)])
    r0 = rng.normal(size=(5, 3)) * 0.1
    eta = rng.normal(size=(5, 6)) * 3
    r, R, kap = rod_shapes(R0, r0, K, np.full(5, L), N, eta)
    Km = K[:2].mean()
    for b in range(5):
        model = fibre_model(L, N, root_position=r0[b], root_direction=d[b], root_normal=nrm[b])
        k2, _, r2, R2 = pai_static(model, 0, eta[b, :3] * Km / L**2, eta[b, 3:] * Km / L)
        np.testing.assert_allclose(r[b], r2, atol=1e-14)
        np.testing.assert_allclose(kap[b], k2, atol=1e-9)


def test_dead_tip_force_is_carried_exactly():
    """With only a terminal load the internal force is constant, so the found local force rotated by the tip
    frame equals the dead load; the shape equals the energy-minimisation statics (solve_static_energy)."""
    from headsim.hair.fibres import fibre_model
    from headsim.hair.reconstruct.growth import dead_tip_force, rod_shapes, rod_stiffness
    from headsim.solvers.rods import straight_frame
    from headsim.solvers.rods_statics import solve_static_energy

    K = rod_stiffness()
    L, N = 0.1, 40
    R0 = straight_frame((0, 1, 0), (0, 0, 1))[None]
    f = np.array([[0.0, 0.0, -2.0]])  # F L^2 / K = 2, normal to the axis
    eta, res = dead_tip_force(R0, np.zeros((1, 3)), K, np.array([L]), N, f, iterations=60)
    assert res[0] < 1e-8
    r, _, _ = rod_shapes(R0, np.zeros((1, 3)), K, np.array([L]), N, eta)
    model = fibre_model(L, N, root_direction=(0, 1, 0), root_normal=(0, 0, 1))
    sol = solve_static_energy(model, tip_force=f[0] * K[:2].mean() / L**2)
    # Pai's explicit integration is first order in ds: compare at the tip to a few ds^1 of L
    assert np.linalg.norm(r[0, -1] - sol.positions[-1]) < 3 * (L / N) * 0.1


@pytest.fixture(scope="module")
def fields_short():
    from headsim.hair.reconstruct.inputs import boundary_fields, bundled_inputs

    inp = bundled_inputs("short")
    return inp, boundary_fields(inp)


@pytest.mark.parametrize("model", ["none", "binary", "continuous"])
def test_kernel_objective_equals_numpy_reference(fields_short, model):
    from headsim.hair.reconstruct import _kernels as _k
    from headsim.hair.reconstruct._reference import reference_objective
    from headsim.hair.reconstruct.density import DensityGrid
    from headsim.hair.reconstruct.growth import GuideOptions, objective_parameters, rod_shapes, rod_stiffness, root_frames
    from headsim.hair.reconstruct.maps import ScalpMap, default_maps

    inp, (head_f, hair_f) = fields_short
    sm = ScalpMap(inp.scalp)
    roots = sm.sample_roots(*default_maps(0.07), n=4, seed=2)
    K = rod_stiffness()
    N = 16
    R0 = root_frames(roots)
    rng = np.random.default_rng(1)
    pre_eta = rng.normal(size=(3, 6))
    pr, pR, pk = rod_shapes(R0[1:], roots.positions[1:], K, roots.lengths[1:], N, pre_eta)
    pre_d3 = np.ascontiguousarray(pR[:, :, :, 2])
    pre_kl = np.ascontiguousarray(pk * roots.lengths[1:, None, None])
    w = np.array([0.5, 0.3, 0.2])
    lo, hi = inp.volume.bounds
    dens = DensityGrid(model, lo, hi, 0.003)
    dens.calibrate(head_f, hair_f, 100 * 0.07)
    dens.add_strand(pr[0], np.full(N + 1, 0.004), pr[:2])  # some occupied cells next to the guide
    go = GuideOptions()
    par = objective_parameters(go, dens.mode, K, float(roots.lengths[0]), N, dens.scale, head_f.far, hair_f.far)
    nn = N + 1
    out = [np.empty((nn, 3)), np.empty((nn, 3)), np.empty((nn, 3, 3)), np.empty((nn, 3))]
    shift = np.array([0.0, 0.0, 0.0])
    for k, eta in enumerate(rng.normal(size=(5, 6))):
        if k == 4:
            shift = np.array([0.5, 0.0, 0.0])  # a rod off every grid reads the fields' far values
        f = _k.guide_objective(eta, par, R0[0], roots.positions[0] + shift, K, pre_d3, pre_kl, w, head_f.values,
                               head_f.origin, head_f.spacing, hair_f.values, hair_f.origin, hair_f.spacing,
                               dens.values, dens.origin, dens.spacing, *out)
        g = reference_objective(eta, R0[0], roots.positions[0] + shift, K, float(roots.lengths[0]), N, pre_d3,
                                pre_kl, w, head_f, hair_f, dens, go)
        assert f == pytest.approx(g, rel=1e-9, abs=1e-12)


# --- density models -------------------------------------------------------------------------------------------

def test_kdm_traversal_conserves_segment_length():
    """Each voxel gains (length inside it) / diagonal, so the total gain times the diagonal is the length."""
    from headsim.hair.reconstruct import _kernels as _k

    rng = np.random.default_rng(4)
    h = 0.002
    grid = np.zeros((40, 40, 40))
    pts = 0.01 + 0.06 * rng.random((1, 30, 3))
    _k.kdm_add_polylines(grid, np.zeros(3), h, pts, 1.0)
    length = np.linalg.norm(np.diff(pts[0], axis=0), axis=1).sum()
    assert grid.sum() * h * np.sqrt(3) == pytest.approx(length, rel=1e-12)
    # an axis-aligned segment along node centres fills exactly the voxels it crosses
    g2 = np.zeros((10, 10, 10))
    _k.kdm_add_segment(g2, np.zeros(3), 1.0, np.array([2.0, 3.0, 3.0]), np.array([6.0, 3.0, 3.0]), 1.0)
    np.testing.assert_allclose(g2[2:7, 3, 3], np.array([0.5, 1, 1, 1, 0.5]) / np.sqrt(3))


def test_bbm_sat_marks_exactly_the_overlapped_voxels():
    """Voxels whose centre lies inside the segment's cylinder (radius r, no caps) must be set, and no voxel
    farther than r sqrt 2 (the OBB's edge) + half a voxel diagonal from the segment may be."""
    from headsim.hair.reconstruct import _kernels as _k

    h, r = 0.001, 0.0025
    grid = np.zeros((30, 30, 30))
    a, b = np.array([0.006, 0.007, 0.008]), np.array([0.022, 0.018, 0.02])
    _k.bbm_add_polyline(grid, np.zeros(3), h, np.stack([a, b]), np.array([r, r]))
    ijk = np.stack(np.meshgrid(*[np.arange(30)] * 3, indexing="ij"), -1).reshape(-1, 3)
    c = ijk * h
    t = ((c - a) @ (b - a)) / ((b - a) @ (b - a))
    in_cyl = (t >= 0) & (t <= 1) & (np.linalg.norm(c - (a + t[:, None] * (b - a)), axis=1) <= r)
    t = np.clip(t, 0, 1)
    d = np.linalg.norm(c - (a + t[:, None] * (b - a)), axis=1)
    marked = grid.reshape(-1) > 0
    assert in_cyl.sum() > 100 and marked[in_cyl].all()
    assert not marked[d > r * np.sqrt(2) + h * np.sqrt(3) / 2 + 1e-12].any()  # OBB corner: r sqrt 2


def test_first_exit_tolerates_short_excursions_only():
    from headsim.hair.reconstruct import _kernels as _k

    inside = -np.ones(10)
    head = np.ones(10)
    seg = np.full(9, 0.002)
    hair = inside.copy()
    hair[4] = 0.003  # one node out: 2 x 2 mm of arc outside <= 4 mm tolerated
    assert _k.first_exit(hair, head, seg, 0.001, 0.004) == 9
    hair[4:7] = 0.003  # three nodes out: 8 mm, cut before the exit
    assert _k.first_exit(hair, head, seg, 0.001, 0.004) == 3
    hd = head.copy()
    hd[2:] = -0.002  # into the head and never back
    assert _k.first_exit(inside, hd, seg, 0.001, 0.004) == 1


def test_strand_fibres_start_at_their_roots_and_keep_the_tapered_radius():
    """Interpolated fibres ride in a generalised cylinder: fibre i starts at its own root, and its distance
    from the guide's node is |o_i| T(s) with the taper T(s) = 1 - (1 - tip_ratio) s / L, with or without
    winding (a rotation about the guide's tangent)."""
    from headsim.hair.reconstruct.growth import rod_shapes, rod_stiffness
    from headsim.hair.reconstruct.strands import interpolate_strand
    from headsim.solvers.rods import straight_frame

    K = rod_stiffness()
    N, L = 20, 0.1
    R0 = straight_frame((0, 1, 0.3), (0, 0, 1))[None]
    r, R, _ = rod_shapes(R0, np.zeros((1, 3)), K, np.array([L]), N, np.array([[0.5, -2.0, 0.0, 0.3, 0.0, 0.0]]))
    rng = np.random.default_rng(0)
    off = rng.normal(size=(6, 3)) * 0.002
    off -= (off @ R0[0][:, 2])[:, None] * R0[0][:, 2]  # offsets in the root's cross-section plane
    roots = off
    for winding in (0.0, 40.0):
        fib = interpolate_strand(r[0], R[0], N, roots, np.full(6, L), L, N, tip_ratio=0.5, winding=winding)
        np.testing.assert_allclose(fib[:, 0], roots, atol=1e-15)
        taper = 1 - 0.5 * np.arange(N + 1) / N
        dist = np.linalg.norm(fib - r[0][None], axis=2)
        np.testing.assert_allclose(dist, np.linalg.norm(off, axis=1)[:, None] * taper[None], rtol=1e-12)
