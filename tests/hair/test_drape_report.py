"""The drape run's interactive report (headsim.report.drape): what the 3-D view holds, the numbers, and that the
page renders offline in headless Chromium."""

import sys
from pathlib import Path

import numpy as np
import pytest

from headsim.hair.drape import bounding_box, build_drape_scene, run_drape
from headsim.report.drape import MAX_FIBRES_SHOWN, drape_figure, write_drape_report

sys.path.insert(0, str(Path(__file__).parents[1]))
from headless_chromium import render_page  # noqa: E402


@pytest.fixture(scope="module")
def run():
    scene = build_drape_scene("sphere-horizontal", "iso", n_fibres=3, segments=30, duration=0.01)
    return scene, run_drape(scene, record_every=5)


def test_figure_holds_every_recorded_frame_and_the_obstacle_in_view(run):
    scene, res = run
    fig = drape_figure(scene, res)
    assert [t.type for t in fig.data] == ["mesh3d", "scatter3d"]
    assert len(fig.frames) == len(res.times) == 3
    assert len(fig.layout.sliders[0].steps) == 3
    assert fig.layout.sliders[0].font.color is None  # few frames: the step labels are shown
    # 31 frames (the CLI's default 30 + the start): the labels are hidden, the current time is not
    from dataclasses import replace

    many = replace(res, times=np.linspace(0, res.times[-1], 31), polylines=np.repeat(res.polylines[-1:], 31, axis=0))
    sl = drape_figure(scene, many).layout.sliders[0]
    assert len(sl.steps) == 31 and sl.font.color == "rgba(0,0,0,0)" and sl.currentvalue.prefix == "t = "
    for k, frame in enumerate(fig.frames):  # each frame's fibres, in cm, NaN between fibres
        q = np.column_stack([frame.data[0].x, frame.data[0].y, frame.data[0].z]).astype(float)
        pts = q[~np.isnan(q).any(1)]
        np.testing.assert_allclose(pts, res.polylines[k].reshape(-1, 3) * 100, rtol=1e-6, atol=1e-6)
        assert np.isnan(q).any(1).sum() == res.polylines.shape[1]
    mesh = fig.data[0]
    v = np.column_stack([mesh.x, mesh.y, mesh.z]) / 100
    box = [np.array(r) / 100 for r in (fig.layout.scene.xaxis.range, fig.layout.scene.yaxis.range,
                                       fig.layout.scene.zaxis.range)]
    for i in range(3):
        assert box[i][0] - 1e-12 <= v[:, i].min() and v[:, i].max() <= box[i][1] + 1e-12
    # the obstacle drawn is the one the fibres collide with: its vertices lie on the sphere
    np.testing.assert_allclose(scene.obstacles[0].field.distance(v), 0.0, atol=1e-12)


def test_many_fibres_are_thinned_to_the_shown_maximum(run):
    scene, res = run
    many = type(res)(**{**res.__dict__, "polylines": np.repeat(res.polylines, 50, axis=1)})  # 150 fibres
    fig = drape_figure(scene, many)
    q = np.asarray(fig.data[-1].x, float)
    assert np.isnan(q).sum() == 50 <= MAX_FIBRES_SHOWN  # every 3rd of 150


def test_report_numbers_and_offline_rendering(run, tmp_path):
    """report.html holds the bounding box of the last frame and opens offline in headless Chromium at the last
    frame with the 3-D scene drawn (WebGL through SwiftShader, not its 'not supported' message) and the statistics
    plotted."""
    scene, res = run
    page = write_drape_report(scene, res, tmp_path / "report.html")
    html = page.read_text()
    ext, vol = bounding_box(res.polylines[-1])
    assert f"= {vol * 1e6:.1f} cm³" in html and scene.description in html
    assert "steps taken in halves" in html and "at the end of a step (exact" in html and "fibre pairs turned back after passing through each other" in html
    assert f"the mean-lever Newton did not converge)</th><td>{int(res.joint_root_failures.sum())} in the run" in html
    rendered, img = render_page(page, tmp_path)
    assert "WebGL is not supported" not in rendered
    assert "gl-container" in rendered and rendered.count("main-svg") >= 2
    # the page opens at the last recorded frame (the slider's active step), not wherever an autoplay stopped
    assert f"t = {res.times[-1]:.3f} s" in rendered and f"t = {res.times[0]:.3f} s" not in rendered
    lower = img[img.shape[0] // 2:]
    assert lower.std() > 0.02, "the 3-D area is uniform: plotly/WebGL did not draw"
