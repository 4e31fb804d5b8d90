"""The packed fibre hierarchy (variant AP): same contacts as brute force, refit = rebuild, float32 safety."""

from __future__ import annotations

import numpy as np
import pytest

from headsim.collide._reference_fibres import capsule_contacts_bruteforce
from headsim.collide.fibre_bvh import DEFAULT_VARIANT, FibreBVH, PackedFibreBVH, RebuildPolicy, fibre_self_contacts
from headsim.collide.fibre_scenes import loop_frames, strand_scene
from headsim.collide.fibres import FibreSet
from headsim.errors import ParameterError


def random_scene(seed=1, n_fibres=20, n_nodes=51, radius=0.01):
    """Random walks (20 fibres × 50 segments) in a 0.3 m box, radius varying along the fibres
    (the scene of test_fibre_bvh)."""
    rng = np.random.default_rng(seed)
    steps = rng.normal(size=(n_fibres, n_nodes, 3)) * 0.02
    nodes = (rng.uniform(size=(n_fibres, 1, 3)) * 0.3 + np.cumsum(steps, 1)).reshape(-1, 3)
    r = rng.uniform(0.5, 1.5, n_fibres * (n_nodes - 1)) * radius
    return FibreSet(nodes, np.arange(n_fibres + 1) * n_nodes, r)


SCENES = {"random": random_scene,
          "strand": lambda: strand_scene(20, 50, length=0.05, radius=60e-6, noise=0.3, seed=3)}


@pytest.fixture(scope="module")
def references():
    out = {}
    for name, make in SCENES.items():
        f = make()
        out[name] = (f, *capsule_contacts_bruteforce(f))
    return out


@pytest.mark.parametrize("scene", list(SCENES))
@pytest.mark.parametrize("leaf_size", [1, 3, 8, 64])
@pytest.mark.parametrize("split", ["sah", "mid"])
def test_packed_tree_finds_the_brute_force_contact_set(references, scene, leaf_size, split):
    f, pairs, params = references[scene]
    for threads in (1, 2):
        bvh = PackedFibreBVH(f, leaf_size, split=split, threads=threads)
        got, got_params = bvh.self_contact_pairs()
        np.testing.assert_array_equal(got, pairs)
        np.testing.assert_array_equal(got_params, params)  # the same float64 test as brute force
        s = bvh.stats
        assert s.contacts == len(pairs)
        assert s.contacts <= s.primitive_tests <= s.leaf_bv_tests <= s.bv_tests
        assert (bvh.count[bvh.child < 0] <= leaf_size).all()


def test_every_slot_is_in_exactly_one_leaf_and_parents_contain_children(references):
    f, _, _ = references["random"]
    bvh = PackedFibreBVH(f, 5)
    assert np.array_equal(np.sort(bvh.perm), np.arange(f.n_segments))
    leaves = np.nonzero((bvh.child < 0) & (bvh.count > 0))[0]
    covered = np.concatenate([np.arange(bvh.first[u], bvh.first[u] + bvh.count[u]) for u in leaves])
    assert np.array_equal(np.sort(covered), np.arange(f.n_segments))
    inner = np.nonzero(bvh.child >= 0)[0]
    for c in (bvh.child[inner], bvh.child[inner] + 1):
        assert (bvh.nbox[inner, :3] <= bvh.nbox[c, :3]).all() and (bvh.nbox[inner, 3:6] >= bvh.nbox[c, 3:6]).all()
        assert (bvh.count[inner] == bvh.count[bvh.child[inner]] + bvh.count[bvh.child[inner] + 1]).all()
    # float32 segment boxes enclose the float64 capsule boxes (rounded outwards)
    p, q = f.segment_endpoints()
    lo = np.minimum(p, q)[bvh.perm] - f.radius[bvh.perm, None]
    hi = np.maximum(p, q)[bvh.perm] + f.radius[bvh.perm, None]
    assert (bvh.sbox[:, :3].astype(np.float64) <= lo).all() and (bvh.sbox[:, 3:6].astype(np.float64) >= hi).all()


def test_far_from_the_origin_float32_boxes_lose_no_contact():
    """1 km away float32 steps are 61 µm, larger than the gaps: the exact test stays float64."""
    f0 = random_scene(seed=4, radius=2e-4)
    f = f0.with_nodes(f0.nodes * 0.01 + np.array([1000.0, -1000.0, 1000.0]))
    want = capsule_contacts_bruteforce(f)[0]
    assert len(want) > 20
    np.testing.assert_array_equal(PackedFibreBVH(f).self_contact_pairs()[0], want)


def test_refit_after_deformation_equals_rebuild():
    f = random_scene(seed=9)
    bvh = PackedFibreBVH(f)
    moved = f.nodes + np.random.default_rng(10).normal(scale=0.03, size=f.nodes.shape)
    bvh.update(moved)
    refit = bvh.self_contact_pairs()[0]
    np.testing.assert_array_equal(refit, capsule_contacts_bruteforce(f, moved)[0])
    fresh = PackedFibreBVH(f.with_nodes(moved))
    bvh.rebuild()
    np.testing.assert_array_equal(bvh.child, fresh.child)
    np.testing.assert_array_equal(bvh.nbox, fresh.nbox)
    np.testing.assert_array_equal(bvh.self_contact_pairs()[0], refit)


def test_policies_first_mode_and_records():
    frames = list(loop_frames(12, 20, 4, length=0.05, radius=80e-6))
    bvh = FibreBVH.from_variant(frames[0][1], "AP")
    assert isinstance(bvh, PackedFibreBVH) and DEFAULT_VARIANT == "AP"
    done = [bvh.maintain(f.nodes, RebuildPolicy("every", every=2)) for _, f in frames[1:]]
    assert done == ["refit", "rebuild", "refit", "rebuild"]
    last = frames[-1][1]
    want = capsule_contacts_bruteforce(last)[0]
    assert len(want) > 0
    first, _ = bvh.self_contact_pairs("first")
    assert len(first) == 1 and any((want == first[0]).all(1))
    c = fibre_self_contacts(last)
    ref = FibreBVH.from_variant(last, "AS").self_contacts()
    for name in ref.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(c, name), getattr(ref, name))
    apart = FibreSet(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float), [0, 2, 4], 0.1)
    assert len(PackedFibreBVH(apart).self_contact_pairs("first")[0]) == 0
    assert len(PackedFibreBVH(apart).self_contact_pairs()[0]) == 0


def test_bad_arguments():
    f = random_scene()
    with pytest.raises(ParameterError):
        PackedFibreBVH(f, 0)
    with pytest.raises(ParameterError):
        PackedFibreBVH(f, 65)
    with pytest.raises(ParameterError):
        PackedFibreBVH(f, split="median")
    with pytest.raises(ParameterError):
        PackedFibreBVH(f.nodes)
    bvh = PackedFibreBVH(f)
    with pytest.raises(ParameterError):
        bvh.update(np.full_like(f.nodes, np.inf))
    with pytest.raises(ParameterError):
        bvh.self_contact_pairs("any")


@pytest.mark.parametrize("scene", list(SCENES))
@pytest.mark.parametrize("n_query", [1, 7, 120])
def test_subset_contact_pairs_are_the_brute_force_pairs_of_the_query_segments(references, scene, n_query):
    """subset_contact_pairs (the sweep the chain solver's widened band uses): exactly the brute-force pairs
    with a query segment in them (a < b, each once also when both are queried), with its closest-point
    parameters (the same float64 test up to the order of the segments' arguments)."""
    from headsim.collide.fibre_bvh import subset_contact_pairs

    f, pairs, params = references[scene]
    rng = np.random.default_rng(n_query)
    # the segments of the first contacts among the queries, so that every size has pairs to find
    query = np.unique(np.concatenate([pairs[: max(1, n_query // 2), 0],
                                      rng.choice(f.n_segments, n_query, replace=False)]))[:n_query]
    got, got_params = subset_contact_pairs(f, query)
    assert (got[:, 0] < got[:, 1]).all()
    order = np.lexsort((got[:, 1], got[:, 0]))
    got, got_params = got[order], got_params[order]
    mine = np.isin(pairs[:, 0], query) | np.isin(pairs[:, 1], query)
    assert mine.sum() >= 1
    np.testing.assert_array_equal(got, pairs[mine])
    np.testing.assert_allclose(got_params, params[mine], atol=1e-9)
    empty, _ = subset_contact_pairs(f, np.zeros(0, np.int64))
    assert empty.shape == (0, 2)
    mask = np.zeros(f.n_segments, bool)
    mask[query] = True
    np.testing.assert_array_equal(np.sort(subset_contact_pairs(f, mask)[0], axis=0), np.sort(got, axis=0))
    for bad in (np.array([f.n_segments]), np.array([-1]), np.array([0.5]), np.ones(3, bool)):
        with pytest.raises(ParameterError, match="query"):
            subset_contact_pairs(f, bad)


def test_refit_to_moved_fibres_with_new_radii_finds_the_brute_force_contact_set(references):
    """refit_fibres (the chain solver keeps its tree across steps): after the nodes moved and the radii changed
    (grown for some segments, shrunk for others), the refitted tree reports exactly the brute-force contacts of
    the new fibre set."""
    f, _, _ = references["random"]
    bvh = PackedFibreBVH(f, 8)
    rng = np.random.default_rng(7)
    for _ in range(3):
        nodes = f.nodes + rng.normal(scale=0.01, size=f.nodes.shape)
        radius = f.radius * rng.uniform(0.5, 2.0, f.n_segments)
        moved = FibreSet(nodes, f.fibre_offsets, radius)
        bvh.refit_fibres(moved)
        pairs, params = capsule_contacts_bruteforce(moved)
        got, got_params = bvh.self_contact_pairs()
        np.testing.assert_array_equal(got, pairs)
        np.testing.assert_array_equal(got_params, params)
    other = FibreSet(f.nodes[: -f.fibre_offsets[1]], f.fibre_offsets[:-1], f.radius[: -(f.fibre_offsets[1] - 1)])
    with pytest.raises(ParameterError, match="same fibre offsets"):
        bvh.refit_fibres(other)
    with pytest.raises(ParameterError, match="FibreSet"):
        bvh.refit_fibres(f.nodes)


def test_chunk_filter_keeps_exactly_the_pairs_it_moves_to_the_front(references):
    """self_contact_pairs(chunk_filter=…) applies the filter to every worker's pairs: the result is the
    unfiltered contact set restricted to the pairs the filter kept (here: those whose first segment is even)."""
    f, pairs, params = references["random"]

    def even_first(p, q):
        keep = p[:, 0] % 2 == 0
        n = int(keep.sum())
        p[:n], q[:n] = p[keep].copy(), q[keep].copy()
        return n

    for threads in (1, 2):
        bvh = PackedFibreBVH(f, 4, threads=threads)
        got, got_params = bvh.self_contact_pairs(chunk_filter=even_first)
        mine = pairs[:, 0] % 2 == 0
        assert 0 < mine.sum() < len(pairs)
        np.testing.assert_array_equal(got, pairs[mine])
        np.testing.assert_array_equal(got_params, params[mine])
