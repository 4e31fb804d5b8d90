"""``headsim hair charge`` on a tiny bundle: files, numbers, atomic output on bad input."""

import json

import pytest
import typer
from typer.testing import CliRunner

from headsim.cli.hair_charge_cmd import register
from headsim.errors import ParameterError


@pytest.fixture(scope="module")
def app():
    a = typer.Typer()
    register(a)

    @a.command("noop")
    def _noop():  # a second command keeps 'charge' a sub-command
        pass

    return a


def test_charge_bundle_writes_pictures_and_numbers(app, tmp_path):
    out = tmp_path / "run"
    r = CliRunner().invoke(app, ["charge", "--scene", "bundle", "--scale", "0.02", "--segments", "10",
                                 "--length-cm", "10", "--density", "20", "--steps", "2", "--charge", "-7.7e-3",
                                 "--method", "direct", "--render", "--out", str(out)])
    assert r.exit_code == 0, r.output
    for name in ("before.png", "after.png", "field_map.png", "charging.json", "charging.npz",
                 "rendered/frame_0000.png", "rendered/frame_0001.png"):
        assert (out / name).stat().st_size > 0
    d = json.loads((out / "charging.json").read_text())
    assert d["particles"] == 6 * 200
    assert d["scene_info"]["fibres"] == 6
    assert len(d["history"]) == 2
    assert d["field_at_probe_v_per_m"] > 0
    assert d["tip_spread_m"]["after"] > d["tip_spread_m"]["before"]  # like charges push the fibres apart


def test_charge_refuses_bad_humidity_without_output(app, tmp_path):
    out = tmp_path / "bad"
    r = CliRunner().invoke(app, ["charge", "--rh", "165", "--out", str(out)])
    assert isinstance(r.exception, ParameterError)
    assert not out.exists()
