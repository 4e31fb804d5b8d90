"""Fibre BVHs (Sobottka Ch. 7 §7.3): every variant equals brute force; Lemma 7.3.1; refit = rebuild."""

from __future__ import annotations

import numpy as np
import pytest

from headsim.collide._reference_fibres import capsule_contacts_bruteforce, capsule_contacts_kdtree
from headsim.collide.bounding_volumes import KDOP, Sphere
from headsim.collide.fibre_bvh import VARIANTS, FibreBVH, RebuildPolicy
from headsim.collide.fibre_scenes import loop_frames, strand_scene
from headsim.collide.fibres import FibreSet
from headsim.errors import ParameterError


def random_scene(seed=1, n_fibres=20, n_nodes=51, radius=0.01):
    """Random walks (20 fibres × 50 segments) in a 0.3 m box: many crossings and self-contacts."""
    rng = np.random.default_rng(seed)
    steps = rng.normal(size=(n_fibres, n_nodes, 3)) * 0.02
    nodes = (rng.uniform(size=(n_fibres, 1, 3)) * 0.3 + np.cumsum(steps, 1)).reshape(-1, 3)
    r = rng.uniform(0.5, 1.5, n_fibres * (n_nodes - 1)) * radius  # radius varies along fibres
    return FibreSet(nodes, np.arange(n_fibres + 1) * n_nodes, r)


def strand_like():
    return strand_scene(20, 50, length=0.05, radius=60e-6, noise=0.3, seed=3)


SCENES = {"random": random_scene, "strand": strand_like}


@pytest.fixture(scope="module")
def references():
    out = {}
    for name, make in SCENES.items():
        f = make()
        out[name] = (f, *capsule_contacts_bruteforce(f))
    return out


def test_scenes_have_contacts(references):
    for f, pairs, _ in references.values():
        assert len(pairs) > 50


@pytest.mark.parametrize("scene", list(SCENES))
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_variant_finds_the_brute_force_contact_set(references, scene, variant):
    f, pairs, params = references[scene]
    bvh = FibreBVH.from_variant(f, variant, k=14)
    got, got_params = bvh.self_contact_pairs()
    np.testing.assert_array_equal(got, pairs)
    np.testing.assert_allclose(got_params, params, atol=1e-9)
    s = bvh.stats
    assert s.contacts == len(pairs)
    assert s.contacts <= s.primitive_tests <= s.bv_overlaps <= s.bv_tests
    assert s.leaf_bv_tests <= s.bv_tests


@pytest.mark.parametrize("variant", ["AS", "DL"])
def test_grassmannian_dop_and_volume_rule_and_threads(references, variant):
    f, pairs, _ = references["random"]
    for threads in (1, 2):
        bvh = FibreBVH.from_variant(f, variant, k=20, split_rule="volume", threads=threads)
        np.testing.assert_array_equal(bvh.self_contact_pairs()[0], pairs)


def test_kdtree_peer_agrees_with_brute_force(references):
    for f, pairs, _ in references.values():
        np.testing.assert_array_equal(capsule_contacts_kdtree(f)[0], pairs)


def test_first_contact_mode(references):
    f, pairs, _ = references["random"]
    bvh = FibreBVH.from_variant(f, "AS")
    first, _ = bvh.self_contact_pairs("first")
    assert len(first) == 1
    assert any((pairs == first[0]).all(1))
    assert bvh.stats.contacts == 1
    apart = FibreSet(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float), [0, 2, 4], 0.1)
    assert len(FibreBVH(apart).self_contact_pairs("first")[0]) == 0


def test_adjacency_excluded_but_virtual_links_and_fold_backs_tested():
    # fibre 0 folds back on itself: segments 0 and 2 touch, 0–1 and 1–2 are joints (excluded);
    # fibre 1 starts at fibre 0's tip (the total fibre's virtual link): must be reported.
    nodes = np.array(
        [[0, 0, 0], [1, 0, 0], [1, 0.05, 0], [0, 0.05, 0], [0, 0.05, 0.05], [0, 1, 0.05]], float
    )
    f = FibreSet(nodes, [0, 4, 6], 0.03)
    want = capsule_contacts_bruteforce(f)[0]
    assert [0, 2] in want.tolist() and [2, 3] in want.tolist()
    assert not any(abs(a - b) == 1 and f.segment_fibre[a] == f.segment_fibre[b] for a, b in want)
    for v in ("AS", "AL", "SW"):
        np.testing.assert_array_equal(FibreBVH.from_variant(f, v).self_contact_pairs()[0], want)


@pytest.mark.parametrize("bv", ["aabb", KDOP(18), KDOP(24)])
def test_lemma_7_3_1_wrapped_equals_layered_for_slab_volumes(bv):
    """Sobottka Lemma 7.3.1: MEV(s_i..j) = MEV(MEV(s_i..k), MEV(s_k+1..j)) for AABBs / k-DOPs, so the
    top-down wrapped tree (H_TD) and the bottom-up layered tree (H_TI) are the same, node by node."""
    f = random_scene(seed=5)
    layered = FibreBVH(f, bv, "topological", wrapped=False)
    wrapped = FibreBVH(f, bv, "topological", wrapped=True)
    np.testing.assert_array_equal(layered.left, wrapped.left)
    np.testing.assert_array_equal(layered.bvs, wrapped.bvs)  # exactly equal, not approximately


def test_layered_spheres_are_not_wrapped_spheres():
    """For spheres the lemma fails: layered spheres contain the wrapped ones and are larger."""
    f = random_scene(seed=5)
    layered = FibreBVH(f, "sphere", "topological")
    wrapped = FibreBVH(f, "sphere", "topological", wrapped=True)
    inner = layered.left >= 0
    assert Sphere().contains(layered.bvs[inner][:1], layered.bvs[inner][:1]).all()
    assert (layered.bvs[inner, 3] > wrapped.bvs[inner, 3] * 1.01).mean() > 0.3
    # every wrapped sphere encloses all capsules below it: check the root against the endpoints
    c, r = wrapped.bvs[0, :3], wrapped.bvs[0, 3]
    for end in f.segment_endpoints():
        assert (np.linalg.norm(end - c, axis=1) + f.radius <= r * (1 + 1e-12)).all()


@pytest.mark.parametrize("variant", ["AL", "DL", "SL", "OL", "SW", "OW"])
def test_update_after_random_deformation_equals_rebuild_for_topological_trees(variant):
    f = random_scene(seed=7)
    bvh = FibreBVH.from_variant(f, variant, k=14)
    moved = f.nodes + np.random.default_rng(8).normal(scale=0.02, size=f.nodes.shape)
    bvh.update(moved)
    fresh = FibreBVH.from_variant(f.with_nodes(moved), variant, k=14)
    np.testing.assert_allclose(bvh.bvs, fresh.bvs, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(bvh.self_contact_pairs()[0], capsule_contacts_bruteforce(f, moved)[0])


@pytest.mark.parametrize("variant", ["AS", "DS", "SS", "OS"])
def test_refit_spatial_tree_after_deformation_finds_the_rebuild_contacts(variant):
    f = random_scene(seed=9)
    bvh = FibreBVH.from_variant(f, variant, k=14)
    moved = f.nodes + np.random.default_rng(10).normal(scale=0.03, size=f.nodes.shape)
    bvh.update(moved)
    refit_pairs = bvh.self_contact_pairs()[0]
    # the refit tree encloses its subtrees: a parent BV contains both children's
    inner = np.nonzero(bvh.left >= 0)[0]
    if bvh.kind == 0:
        assert bvh.bv.contains(bvh.bvs[inner], bvh.bvs[bvh.left[inner]]).all()
    bvh.rebuild()
    np.testing.assert_array_equal(bvh.self_contact_pairs()[0], refit_pairs)
    np.testing.assert_array_equal(refit_pairs, capsule_contacts_bruteforce(f, moved)[0])


def test_rebuild_policies():
    frames = list(loop_frames(12, 20, 6, length=0.05, radius=80e-6))
    _, f0 = frames[0]
    every = FibreBVH(f0, "aabb", "spatial")
    done = [every.maintain(f.nodes, RebuildPolicy("every", every=3)) for _, f in frames[1:]]
    assert done == ["refit", "refit", "rebuild", "refit", "refit", "rebuild"]
    always = FibreBVH(f0, "aabb", "spatial")
    assert {always.maintain(f.nodes, RebuildPolicy("rebuild")) for _, f in frames[1:]} == {"rebuild"}
    topo = FibreBVH(f0, "aabb", "topological")
    assert {topo.maintain(f.nodes, RebuildPolicy("rebuild")) for _, f in frames[1:]} == {"refit"}
    _, last = frames[-1]
    np.testing.assert_array_equal(every.self_contact_pairs()[0], capsule_contacts_bruteforce(last)[0])
    with pytest.raises(ParameterError):
        RebuildPolicy("sometimes")


def test_contact_records_are_consistent(references):
    f, pairs, _ = references["random"]
    c = FibreBVH(f).self_contacts()
    assert len(c) == len(pairs)
    np.testing.assert_allclose(np.linalg.norm(c.normal, axis=1), 1.0)
    assert (c.depth > 0).all()
    # point_a − point_b = −depth · normal (surface points overlap by the depth)
    np.testing.assert_allclose(c.point_a - c.point_b, -c.depth[:, None] * c.normal, atol=1e-12)
    np.testing.assert_array_equal(c.body_a, f.segment_fibre[c.segment_a])


def test_bad_arguments():
    f = random_scene()
    with pytest.raises(ParameterError):
        FibreBVH.from_variant(f, "XX")
    with pytest.raises(ParameterError):
        FibreBVH(f, "cone")
    with pytest.raises(ParameterError):
        FibreBVH(f, "aabb", "octree")
    bvh = FibreBVH(f)
    with pytest.raises(ParameterError):
        bvh.update(np.full_like(f.nodes, np.nan))
    with pytest.raises(ParameterError):
        bvh.self_contact_pairs("some")


def test_level_volumes_of_layered_tree_are_no_smaller_than_wrapped_spheres():
    f = random_scene(seed=11)
    lv = FibreBVH(f, "sphere", "topological").level_volumes()
    wv = FibreBVH(f, "sphere", "topological", wrapped=True).level_volumes()
    assert len(lv) == len(wv)
    assert (lv >= wv * (1 - 1e-9)).all()
