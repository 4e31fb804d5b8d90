"""``headsim mesh``: info / validate / tetra on good and broken files (exit code 2, no output file)."""

from __future__ import annotations

import numpy as np
import pytest

from headsim.cli import main
from headsim.mesh import SurfaceMesh
from headsim.mesh.io import load_tetmesh, save_surface
from headsim.mesh.primitives import box


def run(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    out = capsys.readouterr()
    return info.value.code or 0, out.out, out.err


def test_info_on_bundled_face(capsys):
    code, out, _ = run(["mesh", "info"], capsys)
    assert code == 0
    assert "9,409" in out and "18,460" in out and "836.83" in out and "mesh is valid" in out
    assert "4 (lengths 204, 74, 42, 42)" in out


def test_info_warns_on_wrong_unit(tmp_path, capsys):
    path = save_surface(box((0.2, 0.25, 0.15)), tmp_path / "head_mm.stl", units="mm")
    code, out, _ = run(["mesh", "info", str(path), "--units", "m"], capsys)
    assert code == 0 and "warning" in out and "m vs mm" in " ".join(out.split())


@pytest.fixture
def nonmanifold_obj(tmp_path):
    p = tmp_path / "fin.obj"
    p.write_text("v 0 0 0\nv 0.1 0 0\nv 0.1 0.1 0\nv 0 0.1 0\nv 0.05 0.05 0.1\n"
                 "f 1 2 3\nf 1 3 4\nf 3 1 5\n")
    return p


@pytest.mark.parametrize("command", ["info", "validate", "tetra"])
def test_broken_file_exit_2_and_no_output(command, nonmanifold_obj, tmp_path, capsys):
    out_file = tmp_path / "out.vtu"
    argv = ["mesh", command, str(nonmanifold_obj)] + (["--out", str(out_file)] if command == "tetra" else [])
    code, _, err = run(argv, capsys)
    assert code == 2
    assert "fin.obj" in err and "non-manifold edges" in err
    assert not out_file.exists()
    assert list(tmp_path.iterdir()) == [nonmanifold_obj]  # no temporary files left behind


def test_missing_file_and_bad_unit(tmp_path, capsys):
    code, _, err = run(["mesh", "tetra", str(tmp_path / "nope.stl")], capsys)
    assert code == 2 and "nope.stl: file not found" in err
    code, _, err = run(["mesh", "info", "--units", "furlong"], capsys)
    assert code == 2 and "unknown length unit 'furlong'" in err


def test_validate_repair_writes_fixed_mesh(tmp_path, capsys):
    s = box((0.1, 0.1, 0.1), 2)
    tri = s.triangles.copy()
    tri[:3] = tri[:3, ::-1]
    src = save_surface(SurfaceMesh(s.vertices, tri), tmp_path / "flipped.ply", units="mm")
    code, _, err = run(["mesh", "validate", str(src), "--units", "mm"], capsys)
    assert code == 2 and "inconsistent winding" in err and "--repair" in err
    out = tmp_path / "fixed.obj"
    code, text, _ = run(["mesh", "validate", str(src), "--units", "mm", "--repair", "--out", str(out)], capsys)
    assert code == 0 and "flipped 3 triangles" in text
    from headsim.mesh.io import load_surface

    fixed = load_surface(out, units="mm")
    assert fixed.signed_volume() == pytest.approx(1e-3, rel=1e-6)


def test_tetra_open_surface_writes_tissue_model(tmp_path, capsys, make_grid):
    src = save_surface(make_grid(6, 6, spacing=0.01), tmp_path / "patch.obj", units="mm")
    out = tmp_path / "model.msh"
    png = tmp_path / "thickness.png"
    code, text, _ = run(["mesh", "tetra", str(src), "--units", "mm", "--thickness-mm", "4", "--layers", "2",
                         "--out", str(out), "--png", str(png)], capsys)
    assert code == 0, text
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    mesh = load_tetmesh(out)
    assert mesh.n_tets == 3 * 2 * 72 and mesh.fixed.sum() == 49
    assert mesh.volume == pytest.approx(0.06 * 0.06 * 0.004, rel=1e-9)
    assert "fixed (bone) vertices" in text and "14.400" in text  # volume in cm^3


def test_tetra_closed_surface_and_bad_out_suffix(tmp_path, capsys):
    from headsim.mesh.primitives import icosphere

    sphere = icosphere(0.03, 1)
    src = save_surface(sphere, tmp_path / "ball.stl")
    bad = tmp_path / "model.xyz"
    code, _, err = run(["mesh", "tetra", str(src), "--out", str(bad)], capsys)
    assert code == 2 and "unknown tet mesh format" in err and not bad.exists()
    out = tmp_path / "ball.vtu"
    code, text, _ = run(["mesh", "tetra", str(src), "--target-edge-mm", "20", "--out", str(out)], capsys)
    assert code == 0, text
    mesh = load_tetmesh(out)
    assert np.all(mesh.rest_volumes > 0)
    # within fTetWild's envelope (1e-3 x diagonal) of the STL surface (float32 coordinates)
    envelope = 1e-3 * np.linalg.norm(sphere.extent)
    assert abs(mesh.volume - sphere.signed_volume()) <= sphere.area * envelope
    assert "filled by tetwild" in text
