"""`headsim graft`, `headsim compare`, `headsim graft-scene` and the report writers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from headsim.cli import main
from headsim.mesh.io import load_surface


def _run(argv, capsys):
    try:
        main(argv)
        code = 0
    except SystemExit as e:
        code = e.code or 0
    return code, capsys.readouterr()


def test_graft_command_writes_result_sidecar_report_and_pictures(tmp_path, capsys, face):
    out = tmp_path / "plan"
    code, io = _run(["graft", "--volume", "3", "--out", str(out), "--region", "right_cheek"], capsys)
    assert code == 0, io.err
    names = {p.name for p in out.iterdir()}
    assert {"after.obj", "graft.json", "report.html", "before_after.png", "difference.png"} <= names
    side = json.loads((out / "graft.json").read_text())
    assert side["region"] == "right_cheek"
    assert side["volume_change_cm3"] == pytest.approx(3.0, rel=0.01)
    assert side["area_after_m2"] > side["area_before_m2"] > 0
    assert side["params"]["closure"] == "centroid" and len(side["markers"]["points"]) >= 3
    after = load_surface(out / "after.obj")
    assert after.n_vertices == face.n_vertices
    html = (out / "report.html").read_text()
    # offline: plotly.js embedded (megabytes), no script loaded from the network
    assert len(html) > 1_000_000 and "Plotly.newPlot" in html
    assert 'src="http' not in html and "src='http" not in html
    assert (out / "before_after.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # compare before with after: the volume difference in the region is the injected volume
    code, io = _run(["compare", str(face.name), str(out / "after.obj"), "--region", "right_cheek",
                     "--json", str(tmp_path / "cmp.json")], capsys)
    assert code == 0, io.err
    cmp = json.loads((tmp_path / "cmp.json").read_text())["regions"]["right_cheek"]
    assert cmp["volume_difference_cm3"] == pytest.approx(3.0, rel=0.01)
    assert cmp["hausdorff_mm"] > 1.0


@pytest.mark.parametrize("unit,factor", [("mm", 1e3), ("dm", 10.0)])
def test_graft_command_in_other_units(tmp_path, capsys, face, cheek_markers, unit, factor):
    """Face and markers in mm, or in dm as in the seed's planning system (Monkin 2016 §5.4)."""
    from headsim.mesh.io import save_surface

    path = tmp_path / f"face_{unit}.obj"
    save_surface(face, path, units=unit)
    markers = tmp_path / f"markers_{unit}.json"
    markers.write_text(json.dumps({"units": unit, "regions": {
        "left_cheek": {"points": (cheek_markers["left_cheek"].points * factor).tolist()}}}))
    out = tmp_path / unit
    code, io = _run(["graft", "--face", str(path), "--units", unit, "--markers", str(markers), "--volume", "2",
                     "--out", str(out)], capsys)
    assert code == 0, io.err
    after = load_surface(out / "after.obj", units=unit)
    assert np.max(np.abs(after.vertices)) == pytest.approx(np.max(np.abs(face.vertices)), rel=0.05)
    assert json.loads((out / "graft.json").read_text())["volume_change_cm3"] == pytest.approx(2.0, rel=0.01)
    raw = np.loadtxt([ln[2:] for ln in (out / "after.obj").read_text().splitlines() if ln.startswith("v ")])
    np.testing.assert_allclose(raw, after.vertices * factor, rtol=1e-6, atol=1e-9)  # written back in the unit


def test_graft_command_errors_leave_no_output(tmp_path, capsys):
    out = tmp_path / "bad"
    code, io = _run(["graft", "--volume", "3", "--out", str(out), "--region", "nose"], capsys)
    assert code == 2 and "nose" in io.err and not out.exists()
    code, io = _run(["graft", "--volume", "3", "--out", str(out), "--units", "furlong"], capsys)
    assert code == 2 and not out.exists()
    code, io = _run(["graft", "--volume", "-1", "--out", str(out)], capsys)
    assert code == 2 and not out.exists()
    code, io = _run(["graft", "--volume", "3", "--out", str(out), "--acceleration", "warp"], capsys)
    assert code == 2 and "acceleration" in io.err and not out.exists()
    code, io = _run(["graft", "--volume", "3", "--out", str(out), "--markers", str(tmp_path / "none.json")], capsys)
    assert code == 2 and "not found" in io.err and not out.exists()
    assert not any(tmp_path.iterdir()) or all(p.name == "none.json" for p in tmp_path.iterdir())


def test_graft_scene_command(tmp_path, capsys):
    out = tmp_path / "box"
    code, io = _run(["graft-scene", "box", "--particles", "300", "--steps", "60", "--out", str(out)], capsys)
    assert code == 0, io.err
    numbers = json.loads((out / "numbers.json").read_text())
    assert numbers["particles"] == 300 and numbers["particles_inside_box"] == 300
    assert (out / "scene.png").exists()
    code, io = _run(["graft-scene", "jelly", "--out", str(tmp_path / "x")], capsys)
    assert code == 2


def test_report_writers_are_generic(tmp_path):
    from headsim.mesh.primitives import icosphere
    from headsim.report.html import MeshLayer, mesh_figure, write_html_report
    from headsim.report.images import render_mesh

    s = icosphere(0.1, 2)
    fig = mesh_figure(MeshLayer(s.vertices, s.triangles, scalar=s.vertices[:, 1]), colorbar_title="m")
    path = write_html_report(tmp_path / "r.html", title="t <&>", figures=[("sphere", fig)], numbers=[("a", "1 < 2")])
    text = path.read_text()
    assert "t &lt;&amp;&gt;" in text and "1 &lt; 2" in text and text.count("<script") >= 1
    png = render_mesh(tmp_path / "s.png", s.vertices, s.triangles, s.vertices[:, 1], panel_title="y")
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.html", "s.png"]  # no temporary files left
