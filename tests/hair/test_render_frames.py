"""Rendered frames for the hair commands (``headsim hair rod --render``)."""

import numpy as np
from typer.testing import CliRunner

from headsim.cli import app
from headsim.hair.render.frames import render_frames


def _png_pixels(path):
    import matplotlib.image as mpimg

    return mpimg.imread(path)[..., :3]


def test_render_frames_draws_the_fibre_where_it_is(tmp_path):
    """A straight horizontal fibre through the frame centre darkens/brightens pixels on the centre row
    only; the corners stay background."""
    x = np.linspace(-0.02, 0.02, 21)
    fibre = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])[None]
    (path,) = render_frames([fibre], tmp_path, width=64, height=64, spp=4, elevation_deg=0.0, azimuth_deg=0.0)
    img = _png_pixels(path)
    background = img[0, 0]
    changed = np.abs(img - background).sum(axis=2) > 0.02
    rows = np.nonzero(changed.any(axis=1))[0]
    assert changed.sum() >= 20, "the fibre left no visible pixels"
    assert abs(rows.mean() - 31.5) < 3 and np.ptp(rows) < 8
    assert not changed[:8].any() and not changed[-8:].any()


def test_hair_rod_render_option_writes_frames(tmp_path):
    out = tmp_path / "rod"
    result = CliRunner().invoke(app, ["hair", "rod", "--scene", "cantilever", "--frames", "2", "--duration", "0.02",
                                      "--render", "--out", str(out)])
    assert result.exit_code == 0, result.output
    frames = sorted((out / "rendered").glob("frame_*.png"))
    assert len(frames) >= 2
