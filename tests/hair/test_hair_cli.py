"""headsim hair rod: files written atomically, errors as exit code 2."""

import pytest

from headsim.cli import main


def test_rod_cli_writes_trajectory_plots_and_images(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as e:
        main(["hair", "rod", "--scene", "cantilever", "--out", str(out), "--segments", "10",
              "--duration", "0.01", "--frames", "3"])
    assert e.value.code == 0
    assert (out / "trajectory.npz").is_file()
    assert (out / "tip_position.png").is_file() and (out / "kinetic_energy.png").is_file()
    assert len(list((out / "vtk").glob("*.vtu"))) >= 3
    assert len(list((out / "images").glob("*.png"))) >= 3


def test_rod_cli_failure_leaves_no_output(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as e:
        main(["hair", "rod", "--scene", "helix", "--out", str(out), "--segments", "1"])
    assert e.value.code == 2
    assert not out.exists()
