"""``headsim hair collide`` (registered on a hair typer app by ``hair_collide_cmd.register``)."""

from __future__ import annotations

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from headsim.cli.hair_collide_cmd import register
from headsim.collide._reference_fibres import capsule_contacts_bruteforce
from headsim.collide.fibre_scenes import strand_scene
from headsim.errors import ParameterError


def hair_app():
    app = typer.Typer()

    @app.callback()
    def _hair() -> None:
        """hair"""

    register(app)
    return app


def test_collide_strand_writes_picture_and_contacts(tmp_path):
    out = tmp_path / "run"
    res = CliRunner().invoke(hair_app(), ["collide", "--scene", "strand", "--fibres", "12", "--segments", "40",
                                          "--radius-um", "60", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "fibre–fibre contacts" in res.output
    assert (out / "contacts.png").stat().st_size > 10_000
    data = np.load(out / "contacts.npz")
    want, _ = capsule_contacts_bruteforce(strand_scene(12, 40, radius=60e-6, seed=0))
    np.testing.assert_array_equal(np.stack([data["segment_a"], data["segment_b"]], 1), want)


def test_unknown_scene_is_an_error_and_leaves_no_output(tmp_path):
    out = tmp_path / "bad"
    res = CliRunner().invoke(hair_app(), ["collide", "--scene", "octopus", "--out", str(out)])
    assert isinstance(res.exception, ParameterError)
    assert not out.exists()


@pytest.mark.parametrize("scene", ["soup"])  # the head scene needs the head SDF: see test_distance_field
def test_other_scenes_run(tmp_path, scene):
    res = CliRunner().invoke(hair_app(), ["collide", "--scene", scene, "--fibres", "60", "--segments", "10",
                                          "--out", str(tmp_path / scene)])
    assert res.exit_code == 0, res.output
    assert (tmp_path / scene / "contacts.png").exists()
