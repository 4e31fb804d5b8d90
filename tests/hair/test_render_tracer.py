"""Hair path tracer: capsule BVH, single scattering against the far-field formula, shadows, and the
seed's multiple-scattering observation (Sobottka 2008 §6.4.1)."""

import math

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.hair.render import MarschnerParams, far_field_lobes
from headsim.hair.render._kernels_bvh import ray_capsule
from headsim.hair.render.bvh import CapsuleBVH, FibreAssembly
from headsim.hair.render.renderer import Camera, Light, RenderOptions, render
from headsim.hair.render.synthetic import synthetic_hairstyle


def test_ray_capsule_analytic_distance():
    # capsule along x through the origin, radius 0.5; ray along −z at height y = 0.3 from z = 5
    t = ray_capsule(0.2, 0.3, 5.0, 0.0, 0.0, -1.0, -1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.5)
    assert t == pytest.approx(5.0 - math.sqrt(0.25 - 0.09), rel=1e-12)
    # end cap: ray along −z at x = 1.2 hits the sphere around b = (1, 0, 0)
    t = ray_capsule(1.2, 0.0, 5.0, 0.0, 0.0, -1.0, -1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.5)
    assert t == pytest.approx(5.0 - math.sqrt(0.25 - 0.04), rel=1e-12)
    assert ray_capsule(2.0, 0.0, 5.0, 0.0, 0.0, -1.0, -1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.5) < 0


def test_bvh_first_hits_match_brute_force():
    rng = np.random.default_rng(0)
    a = rng.uniform(-1, 1, (300, 3))
    b = a + rng.normal(scale=0.15, size=(300, 3))
    r = rng.uniform(0.005, 0.03, 300)
    bvh = CapsuleBVH(a, b, r, leaf_size=3)
    o = rng.uniform(-1.5, 1.5, (400, 3)) + np.array([0, 0, 3.0])
    d = rng.normal(size=(400, 3)) + np.array([0, 0, -3.0])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, idx = bvh.intersect_rays(o, d)
    n_hit = 0
    for k in range(len(o)):
        ts = np.array([ray_capsule(*o[k], *d[k], *a[i], *b[i], r[i]) for i in range(len(a))])
        ts[ts <= 0] = np.inf
        best = ts.min()
        if np.isinf(best):
            assert idx[k] == -1
        else:
            n_hit += 1
            assert t[k] == pytest.approx(best, rel=1e-12)
            assert bvh.segment[idx[k]] == np.argmin(ts)
    assert n_hit > 40  # the comparison covers many hits


def _straight_fibre(radius=1e-3, y=0.0, z=0.0):
    x = np.linspace(-0.05, 0.05, 6)
    nodes = np.column_stack([x, np.full_like(x, y), np.full_like(x, z)])
    return nodes


def test_single_scattering_pixels_equal_far_field_prediction():
    """max_scatter = 1: a fully covered pixel has radiance S(ω_i, ω_r) E cos θ_i (far field is constant
    across the width). Near-orthographic camera along −z, fibre along +x, light inclined to the axis."""
    fib = FibreAssembly(_straight_fibre(), [0, 6], 1e-3)
    cam = Camera(position=(0, 0, 0.3), look_at=(0, 0, 0), fov_deg=1.0)  # 5.2 mm tall view, fibre 2 mm
    light_dir = np.array([0.5, 0.4, 0.7])
    light_dir /= np.linalg.norm(light_dir)
    p = MarschnerParams.preset("brown")
    res = render(fib, p, cam, [Light(vector=tuple(light_dir), rgb=(2.0, 2.0, 2.0))],
                 RenderOptions(width=32, height=32, spp=4, max_scatter=1))
    centre = res.image[14:18, 4:28]  # rows well inside the 2 mm band (≈ 12 px wide)
    theta_i = math.asin(light_dir[0])
    phi_i = math.atan2(light_dir[2], light_dir[1])  # azimuths in the (y, z) plane ⊥ tangent
    phi_r = math.atan2(1.0, 0.0)
    s = far_field_lobes(p, theta_i, phi_i, 0.0, phi_r).sum(axis=0)
    expect = s * 2.0 * math.cos(theta_i)
    # the perspective camera tilts rays by ≤ 0.5°: S changes by < 1 % there
    assert np.allclose(centre.mean(axis=(0, 1)), expect, rtol=0.01)
    assert res.image[0].max() == 0.0  # rows outside the fibre see the black background


def test_shadow_ray_blocks_direct_light():
    front = _straight_fibre(y=0.0, z=0.0)
    blocker = _straight_fibre(y=0.0, z=0.01)  # between the fibre and a light straight above the camera axis
    fib = FibreAssembly(np.concatenate([front, blocker]), [0, 6, 12], 1e-3)
    cam = Camera(position=(0, -0.3, 0.0), look_at=(0, 0, 0), up=(0, 0, 1), fov_deg=1.0)
    p = MarschnerParams.preset("blond")
    opts = RenderOptions(width=32, height=32, spp=2, max_scatter=1)
    lit = render(FibreAssembly(front, [0, 6], 1e-3), p, cam, [Light(vector=(0, 0, 1), rgb=(1, 1, 1))], opts)
    shadowed = render(fib, p, cam, [Light(vector=(0, 0, 1), rgb=(1, 1, 1))], opts)
    band = slice(14, 18)
    assert lit.image[band].max() > 0
    # the lower fibre (the one seen in the central rows of ``lit``) is fully in the blocker's shadow
    assert shadowed.image[band].max() == 0.0


def _tress(n=400, seed=0, radius=50e-6, width=0.01, depth=0.002, nseg=8):
    rng = np.random.default_rng(seed)
    y0 = rng.uniform(-width / 2, width / 2, n)
    z0 = rng.uniform(-depth, 0, n)
    x = np.linspace(-width / 2, width / 2, nseg + 1)
    nodes = np.empty((n, nseg + 1, 3))
    nodes[:, :, 0] = x
    nodes[:, :, 1] = y0[:, None] + 3e-4 * np.sin(x[None] * 800 + rng.uniform(0, 6, (n, 1)))
    nodes[:, :, 2] = z0[:, None]
    return FibreAssembly(nodes.reshape(-1, 3), np.arange(n + 1) * (nseg + 1), radius)


def test_multiple_scattering_brightens_light_hair_strongly_and_dark_hair_barely():
    """Seed §6.4.1 / Fig. 6.10: fibre-to-fibre scattering (orders up to 4) brightens blond hair strongly and
    black hair barely. Measured as the mean-radiance ratio order ≤ 4 / order 1 on a 2 mm thick tress."""
    fib = _tress()
    bvh = CapsuleBVH.from_fibres(fib)
    cam = Camera(position=(0, 0, 0.1), look_at=(0, 0, 0), fov_deg=4.0)
    lights = [Light(vector=(0.3, 0.2, 1.0))]
    ratio = {}
    for preset in ("blond", "brown", "black"):
        p = MarschnerParams.preset(preset)
        m = [render(bvh, p, cam, lights, RenderOptions(width=40, height=40, spp=12, max_scatter=k)).image.mean()
             for k in (1, 4)]
        ratio[preset] = m[1] / m[0]
    assert ratio["blond"] > 1.35
    assert ratio["black"] < 1.12
    assert ratio["blond"] > ratio["brown"] > ratio["black"]


def test_render_rejects_bad_input():
    with pytest.raises(ParameterError):
        FibreAssembly(np.zeros((3, 3)), [0, 1, 3])  # a one-node fibre
    with pytest.raises(ParameterError):
        FibreAssembly(np.full((2, 3), np.nan), [0, 2])
    with pytest.raises(ParameterError):
        RenderOptions(spp=0)
    with pytest.raises(ParameterError):
        Light(kind="spot")
    fib = synthetic_hairstyle(20, 5, seed=1)
    with pytest.raises(ParameterError):
        render(fib, MarschnerParams(), Camera(), [], RenderOptions(width=8, height=8, spp=1))


def test_synthetic_hairstyle_hangs_outside_the_head():
    fib = synthetic_hairstyle(300, 20, head_radius=0.1, seed=2)
    r = np.linalg.norm(fib.nodes, axis=1)
    assert r.min() >= 0.1 * 0.999
    tips = fib.nodes[fib.fibre_offsets[1:] - 1]
    roots = fib.nodes[fib.fibre_offsets[:-1]]
    assert np.mean(tips[:, 1] < roots[:, 1]) > 0.9  # droop


def test_near_field_varies_across_the_width_and_averages_to_the_far_field():
    """Seed Fig. 6.7: the far field is constant across the fibre width, the near field is not; the mean
    over the width of the near-field radiance equals the far field (6.20 averaged over h → 6.11)."""
    fib = FibreAssembly(_straight_fibre(), [0, 6], 1e-3)
    cam = Camera(position=(0, 0, 0.3), look_at=(0, 0, 0), fov_deg=1.0)
    lights = [Light(vector=(0.3, 0.2, -0.9), rgb=(2.0, 2.0, 2.0))]  # back light: TT-dominated, smooth in Δφ
    p = MarschnerParams.preset("blond", near_field_width_deg=3.0)
    imgs = {}
    for near in (False, True):
        opts = RenderOptions(width=8, height=512, spp=2, max_scatter=1, near_field=near)
        imgs[near] = render(fib, p, cam, lights, opts).image[:, 2:6].mean(axis=1)  # (rows, 3)
    band = imgs[False][:, 0] > 0
    rows = np.flatnonzero(band)[3:-3]  # drop partially covered edge rows
    ff, nf = imgs[False][rows], imgs[True][rows]
    assert ff[:, 0].std() < 1e-2 * ff[:, 0].mean()  # constant up to the ≤ 0.5° perspective tilt
    assert nf[:, 0].std() > 0.2 * nf[:, 0].mean()
    # rows sample the width uniformly in projected offset h, so the sum over all rows (edge rows weighted by
    # their coverage, the same for both) is ∝ ½∫S^NF dh; the far field uses Marschner's cubic Δφ fit, the
    # near field the exact (6.4) → a few per cent apart
    assert np.allclose(imgs[True].sum(axis=0), imgs[False].sum(axis=0), rtol=0.06)
