"""Opaque diffuse surfaces in the hair path tracer (the obstacle under a drape): Lambert's law against the
analytic radiance, the environment term, shadows of fibres on the surface and of the surface on fibres, and the
drape scenes' surfaces lying on their obstacles."""

import math

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.hair.drape import build_drape_scene, render_surfaces
from headsim.hair.render import MarschnerParams
from headsim.hair.render.bvh import FibreAssembly
from headsim.hair.render.renderer import Camera, Light, MeshSurface, RenderOptions, Surface, render

FAR_AWAY = FibreAssembly(np.array([[100.0, 100, 100], [100.1, 100, 100]]), [0, 2], 1e-3)  # out of view
PARAMS = MarschnerParams.preset("brown")


def _pixel(cam: Camera, point, width, height):
    """The (row, column) of the pixel that sees ``point``."""
    c = cam.packed(width, height)
    pos, fwd, rt, ut = c[:3], c[3:6], c[6:9], c[9:12]
    d = np.asarray(point, float) - pos
    s = d @ fwd
    px = (d @ rt) / (s * (rt @ rt))
    py = (d @ ut) / (s * (ut @ ut))
    return int((1 - py) / 2 * height), int((px + 1) / 2 * width)


def test_lit_sphere_has_lambert_radiance():
    """A pixel seeing a unit sphere's point x under a directional light of irradiance E from w and a uniform
    environment L: radiance ρ/π E max(n·w, 0) + ρ L (exact: nothing else in view)."""
    albedo = (0.2, 0.5, 0.8)
    sphere = Surface("sphere", (0.0, 0.0, 0.0), 1.0, albedo=albedo)
    w = np.array([0.3, 0.5, 0.8])
    w /= np.linalg.norm(w)
    cam = Camera(position=(0, 0, 6.0), look_at=(0, 0, 0), fov_deg=30.0)
    opts = RenderOptions(width=64, height=64, spp=4, env=(0.1, 0.2, 0.3))
    res = render(FAR_AWAY, PARAMS, cam, [Light(vector=tuple(w), rgb=(2.0, 2.0, 2.0))], opts, surfaces=[sphere])
    for x in ([0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, -0.6, 0.8], [-0.6, 0.0, 0.8]):
        i, j = _pixel(cam, x, 64, 64)
        expect = np.array(albedo) * (2.0 / math.pi * max(float(np.dot(x, w)), 0.0) + np.array([0.1, 0.2, 0.3]))
        # the pixel's samples spread over ≈ 0.03 of the sphere: the normal varies by that much
        np.testing.assert_allclose(res.image[i, j], expect, rtol=0.05, atol=1e-3)
    assert res.image[0, 0].max() == 0.0  # corner: background
    # the dark side (n·w < 0) shows the environment term alone
    dark = np.array([-0.6, -0.7, math.sqrt(1 - 0.36 - 0.49)])  # seen from the camera, n·w = −0.22
    assert dark @ w < 0
    i, j = _pixel(cam, dark, 64, 64)
    assert res.image[i, j] == pytest.approx(np.array(albedo) * [0.1, 0.2, 0.3], rel=0.05, abs=2e-3)


QUAD = MeshSurface(np.array([[-1.0, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]]), np.array([[0, 2, 1], [0, 3, 2]]),
                   albedo=(0.5, 0.5, 0.5))  # the plane y = 0 as two triangles (wound downwards: either side shades)


@pytest.mark.parametrize("plane", [Surface("plane", (0.0, 0.0, 0.0), normal=(0.0, 1.0, 0.0), albedo=(0.5, 0.5, 0.5)),
                                   QUAD], ids=["analytic", "mesh"])
def test_fibre_shadows_the_plane_and_the_plane_shadows_fibres(plane):
    """A fibre between a directional light and a plane leaves its shadow there (only ρ L remains); a fibre below
    the plane's lit side, seen through nothing, is dark because the plane blocks its light. The same, exactly,
    for the plane as a two-triangle mesh."""
    w = np.array([0.0, 1.0, 1.0]) / math.sqrt(2.0)  # light from above and in front
    x = np.linspace(-0.05, 0.05, 6)
    blocker = np.column_stack([x, np.full(6, 0.02), np.full(6, 0.02)])  # over the plane point (·, 0, 0) along w
    fib = FibreAssembly(blocker, [0, 6], 2e-3)
    cam = Camera(position=(0.0, 0.3, -0.05), look_at=(0.0, 0.0, 0.0), fov_deg=20.0)
    opts = RenderOptions(width=64, height=64, spp=4, env=(0.05, 0.05, 0.05), max_scatter=1)
    light = [Light(vector=tuple(w), rgb=(1.0, 1.0, 1.0))]
    res = render(fib, PARAMS, cam, light, opts, surfaces=[plane])
    i, j = _pixel(cam, (0.0, 0.0, 0.0), 64, 64)
    assert res.image[i, j] == pytest.approx([0.025] * 3, rel=1e-6)  # in the shadow: ρ L
    i2, j2 = _pixel(cam, (0.0, 0.0, -0.04), 64, 64)
    lit = 0.5 * (1.0 / math.pi * w[1] + 0.05)
    assert res.image[i2, j2] == pytest.approx([lit] * 3, rel=1e-6)
    # the same fibre under the plane (light from above): no direct light reaches it
    below = FibreAssembly(blocker * [1, -1, 1], [0, 6], 2e-3)
    cam_below = Camera(position=(0.0, -0.3, 0.0), look_at=(0.0, -0.02, 0.02), up=(0, 0, 1), fov_deg=20.0)
    dark = render(below, PARAMS, cam_below, light, RenderOptions(width=32, height=32, spp=2, max_scatter=1),
                  surfaces=[plane])
    free = render(below, PARAMS, cam_below, light, RenderOptions(width=32, height=32, spp=2, max_scatter=1))
    assert free.image.max() > 0 and dark.image.max() == 0.0


def test_lit_triangulated_sphere_has_lambert_radiance():
    """A unit icosphere (5,120 triangles, smooth-shaded) under the light and environment of the analytic sphere's
    test: the same Lambert radiance at the same points (its flat faces lie ≤ 1.2e-3 inside the sphere, its
    interpolated normals within 0.4° of the sphere's), and the same picture as the analytic sphere away from
    the outline (silhouette pixels aside: ≤ 2 % of the radiance range)."""
    import trimesh

    ico = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    albedo = (0.2, 0.5, 0.8)
    mesh = MeshSurface(np.asarray(ico.vertices), np.asarray(ico.faces), albedo=albedo)
    w = np.array([0.3, 0.5, 0.8])
    w /= np.linalg.norm(w)
    cam = Camera(position=(0, 0, 6.0), look_at=(0, 0, 0), fov_deg=30.0)
    opts = RenderOptions(width=64, height=64, spp=4, env=(0.1, 0.2, 0.3))
    light = [Light(vector=tuple(w), rgb=(2.0, 2.0, 2.0))]
    res = render(FAR_AWAY, PARAMS, cam, light, opts, surfaces=[mesh])
    for x in ([0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, -0.6, 0.8], [-0.6, 0.0, 0.8]):
        i, j = _pixel(cam, x, 64, 64)
        expect = np.array(albedo) * (2.0 / math.pi * max(float(np.dot(x, w)), 0.0) + np.array([0.1, 0.2, 0.3]))
        np.testing.assert_allclose(res.image[i, j], expect, rtol=0.05, atol=1e-3)
    ref = render(FAR_AWAY, PARAMS, cam, light, opts, surfaces=[Surface("sphere", (0.0, 0.0, 0.0), 1.0, albedo=albedo)])
    inside = (ref.image.max(axis=2) > 0) & (res.image.max(axis=2) > 0)
    both = inside.copy()  # pixels whose 3 × 3 neighbourhood lies on the sphere in both pictures
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            both &= np.roll(np.roll(inside, di, 0), dj, 1)
    assert both.sum() > 1000
    assert np.abs(res.image - ref.image)[both].max() < 0.02 * ref.image.max()
    # out of view (behind the camera), a mesh changes nothing
    behind = MeshSurface(np.asarray(ico.vertices) * 0.1 + [0, 0, 9.0], np.asarray(ico.faces))
    sphere = Surface("sphere", (0.0, 0.0, 0.0), 1.0, albedo=albedo)
    np.testing.assert_array_equal(render(FAR_AWAY, PARAMS, cam, light, opts, surfaces=[sphere, behind]).image,
                                  ref.image)


def test_drape_scenes_render_their_obstacles():
    for name, kind in (("sphere-helical", "sphere"), ("plane", "plane")):
        scene = build_drape_scene(name, "iso", n_fibres=3, segments=30)
        (s,) = render_surfaces(scene)
        assert s.kind == kind
        row = s.row()
        probe = np.array(row[1:4]) + (row[4] * np.array([0.0, 1.0, 0.0]) if kind == "sphere" else 0.0)
        assert abs(scene.obstacles[0].field.distance(probe[None])[0] - scene.obstacles[0].level) < 1e-12
    for name in ("terrain", "head"):  # grid-field obstacles: their picture mesh, which lies on the field's zero
        scene = build_drape_scene(name, "iso", n_fibres=3, segments=30)
        (s,) = render_surfaces(scene)
        assert isinstance(s, MeshSurface)
        v, t = scene.obstacle_mesh
        np.testing.assert_array_equal(s.vertices, v)
        np.testing.assert_array_equal(s.triangles, t)


@pytest.mark.parametrize("bad", [dict(kind="cube", point=(0, 0, 0)), dict(kind="sphere", point=(0, 0, 0), size=0.0),
                                 dict(kind="plane", point=(0, 0, 0), normal=(0, 0, 0)),
                                 dict(kind="sphere", point=(0, 0, 0), size=1.0, albedo=(1.5, 0, 0))])
def test_bad_surfaces_are_refused(bad):
    with pytest.raises(ParameterError):
        Surface(**bad)


@pytest.mark.parametrize("bad", [dict(vertices=np.zeros((0, 3)), triangles=np.zeros((0, 3), int)),
                                 dict(vertices=np.full((3, 3), np.nan), triangles=[[0, 1, 2]]),
                                 dict(vertices=np.eye(3), triangles=[[0, 1, 3]]),
                                 dict(vertices=np.eye(3), triangles=[[0.0, 1.0, 2.0]]),
                                 dict(vertices=np.eye(3), triangles=[[0, 1, 2]], albedo=(0, 0, 2))])
def test_bad_mesh_surfaces_are_refused(bad):
    with pytest.raises(ParameterError):
        MeshSurface(**bad)
    with pytest.raises(ParameterError, match="Surface or MeshSurface"):
        render(FAR_AWAY, PARAMS, Camera(position=(0, 0, 1.0), look_at=(0, 0, 0)), [Light(vector=(0, 1, 0))],
               RenderOptions(width=4, height=4, spp=1), surfaces=[(0, 0, 0)])
