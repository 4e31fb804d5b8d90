"""Package-level checks: entry point, version, bundled data, error handling of the CLI root."""

import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

import headsim
from headsim import data
from headsim.cli import app, main
from headsim.errors import HeadsimError, MeshError, UnitsError
from headsim.mesh import SurfaceMesh, TetMesh, check_head_scale, parse_units
from headsim.mesh.units import UnitsWarning


def test_version_flag():
    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0
    assert headsim.__version__ in result.output


def test_console_script_help_runs_in_subprocess():
    out = subprocess.run([sys.executable, "-m", "headsim", "--help"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "mesh" in out.stdout


def test_bundled_faces_and_licence_are_installed():
    assert (data.data_dir() / "LICENSE-ICT-FaceKit-MIT.txt").read_text().startswith("MIT License")
    assert data.face_path("neutral").is_file()
    assert data.head_path().is_file()
    assert len(data.population_paths()) == 12
    with pytest.raises(HeadsimError, match="unknown bundled face"):
        data.face_path("nobody")


def test_headsim_error_becomes_exit_code_2(capsys):
    import typer

    extra = typer.Typer()

    @extra.command("boom")
    def boom():
        raise MeshError("broken.obj: 3 non-manifold edges")

    app.add_typer(extra, name="_test-boom")
    try:
        with pytest.raises(SystemExit) as exc:
            main(["_test-boom", "boom"])
        assert exc.value.code == 2
        assert "broken.obj: 3 non-manifold edges" in capsys.readouterr().err
    finally:
        app.registered_groups = [g for g in app.registered_groups if g.name != "_test-boom"]


def test_units_parse_and_scale_check():
    assert parse_units("MM").to_metres == pytest.approx(1e-3)
    with pytest.raises(UnitsError, match="unknown length unit"):
        parse_units("inch")
    face_m = np.array([[0.0, 0.0, 0.0], [0.18, 0.22, 0.12]])
    assert check_head_scale(face_m) == pytest.approx(0.22)
    with pytest.warns(UnitsWarning, match="scaled by 0.001"):
        check_head_scale(face_m * 1000.0, source="face.obj")  # millimetre numbers read as metres
    with pytest.raises(UnitsError):
        check_head_scale(face_m * 100.0, strict=True)


def test_surface_and_tet_containers_refuse_bad_input():
    with pytest.raises(MeshError, match="empty"):
        SurfaceMesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    with pytest.raises(MeshError, match="NaN"):
        SurfaceMesh([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], [[0, 1, 2]])
    with pytest.raises(MeshError, match="indices"):
        SurfaceMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]])
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    assert TetMesh(v, [[0, 1, 2, 3]]).volume == pytest.approx(1 / 6)
    with pytest.raises(MeshError, match="inverted"):
        TetMesh(v, [[0, 2, 1, 3]])


def test_tet_boundary_faces_point_outwards():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    tm = TetMesh(v, [[0, 1, 2, 3]])
    surf = SurfaceMesh(tm.vertices, tm.boundary_triangles)
    assert surf.signed_volume() == pytest.approx(1 / 6)
