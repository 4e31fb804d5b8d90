"""The drape run's pictures: the obstacle's picture mesh is the surface the fibres collide with, and the frames
show it."""

import numpy as np
import pytest
from PIL import Image

from headsim.hair.drape import build_drape_scene, terrain_level
from headsim.hair.drape_pictures import clip_to_box, plane_patch, write_frames


@pytest.mark.parametrize("name", ["sphere-horizontal", "sphere-helical", "plane", "terrain"])
def test_picture_mesh_lies_on_the_obstacle_surface(name):
    """The mesh drawn in the frames is the obstacle's iso-surface: its vertices' distance to it is zero for the
    analytic sphere and plane (round-off) and within the trilinear interpolation bound of the terrain's grid field
    (the bound that is also its iso-level offset), away from the terrain's four rounded corners, where the blend of
    the two roundings is not a distance (measured there: 124 µm against the 106 µm bound)."""
    scene = build_drape_scene(name, "iso", n_fibres=3, segments=30)
    assert scene.obstacle_mesh is not None
    v, t = scene.obstacle_mesh
    assert t.min() >= 0 and t.max() < len(v) and len(t) > 100
    ob = scene.obstacles[0]
    phi = ob.field.distance(v)
    if name == "terrain":
        corner = (np.abs(v[:, 0]) > 0.13) & (np.abs(v[:, 2]) > 0.13)  # within 20 mm of a corner in x and z
        assert np.abs(phi[~corner]).max() <= terrain_level(ob.field.spacing)
        assert corner.sum() < 0.02 * len(v)  # the four 2 × 2 cm corner squares of the 30 × 30 cm terrain: 1.8 %
    else:
        assert np.abs(phi).max() < 1e-12


def test_clip_to_box_cuts_the_surface_at_the_box():
    """A 4 × 4 square in y = 0 clipped to the box [−1, 1]³ is the 2 × 2 square (area 4, every vertex in the box,
    its edge on the box's faces, not the triangles wholly inside: here none); a unit sphere clipped to the box
    [0, 2]³ is its octant (area π/2 to the icosphere's resolution); a mesh outside the box leaves nothing."""
    import trimesh

    v = np.array([[-2.0, 0, -2], [2, 0, -2], [2, 0, 2], [-2, 0, 2]])
    t = np.array([[0, 2, 1], [0, 3, 2]])
    cv, ct = clip_to_box(v, t, (-1, -1, -1), (1, 1, 1))
    assert trimesh.Trimesh(cv, ct, process=False).area == pytest.approx(4.0, rel=1e-12)
    assert (np.abs(cv) <= 1 + 1e-12).all() and ct.max() == len(cv) - 1
    ico = trimesh.creation.icosphere(subdivisions=5)
    sv, st = clip_to_box(ico.vertices, ico.faces, (0, 0, 0), (2, 2, 2))
    assert trimesh.Trimesh(sv, st, process=False).area == pytest.approx(np.pi / 2, rel=2e-3)
    assert (sv >= -1e-12).all()
    ev, et = clip_to_box(v, t, (5, 5, 5), (6, 6, 6))
    assert ev.shape == (0, 3) and et.shape == (0, 3)


def _bluish_fraction(path):
    """Fraction of the picture's pixels tinted like the obstacle (blue clearly above red)."""
    rgb = np.asarray(Image.open(path).convert("RGB"), float)
    return float(((rgb[..., 2] - rgb[..., 0]) > 12).mean())


def test_frames_draw_the_obstacle_under_the_fibres(tmp_path):
    """A fibre lying on a plane: the frame with the obstacle mesh has the obstacle's tint over a sizeable part of
    the picture, the frame without it none (matplotlib's panes are grey)."""
    x = np.linspace(-0.05, 0.05, 11)
    fibre = np.stack([x, 0.001 + 0.01 * x, np.zeros_like(x)], 1)
    polylines = np.stack([fibre[None], fibre[None] + [0.0, 0.0, 0.02]], 0)  # 2 frames × 1 fibre
    mesh = plane_patch((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 0.0), 0.2)
    with_mesh = write_frames(tmp_path / "with", "plane", np.array([0.0, 0.1]), polylines, mesh)
    without = write_frames(tmp_path / "without", "plane", np.array([0.0, 0.1]), polylines, None)
    assert [p.name for p in with_mesh] == ["frame_0000.png", "frame_0001.png"]
    assert _bluish_fraction(without[1]) < 0.001
    assert _bluish_fraction(with_mesh[1]) > 0.02
