"""``hair render`` command (registered on a private typer app; the lead wires it into ``headsim hair``)."""

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from headsim.cli.hair_render_cmd import parse_light, register
from headsim.errors import ParameterError
from headsim.hair.render.synthetic import synthetic_hairstyle


@pytest.fixture()
def app():
    a = typer.Typer()
    register(a)

    @a.callback()
    def _root():  # keep "render" as a sub-command
        pass

    return a


@pytest.fixture()
def npz(tmp_path):
    f = synthetic_hairstyle(60, 6, fibre_radius=1e-3, seed=3)
    p = tmp_path / "hair.npz"
    np.savez(p, nodes=f.nodes, fibre_offsets=f.fibre_offsets, radius=f.radius)
    return p


def test_render_writes_png_and_turntable(app, npz, tmp_path):
    import matplotlib.pyplot as plt

    out = tmp_path / "img.png"
    r = CliRunner().invoke(app, ["render", str(npz), "--out", str(out), "--preset", "blond", "--spp", "1",
                                 "--width", "24", "--height", "16", "--light", "dir:0,1,1:2"])
    assert r.exit_code == 0, r.output
    img = plt.imread(out)
    assert img.shape[:2] == (16, 24) and img[..., :3].std() > 0  # hair against the background
    frames = tmp_path / "turn"
    r = CliRunner().invoke(app, ["render", str(npz), "--out", str(frames), "--spp", "1", "--width", "8",
                                 "--height", "8", "--turntable", "3", "--max-scatter", "1"])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in frames.iterdir()) == ["frame_000.png", "frame_001.png", "frame_002.png"]


def test_render_bad_input_leaves_no_file(app, tmp_path, npz):
    out = tmp_path / "img.png"
    r = CliRunner().invoke(app, ["render", str(npz), "--out", str(out), "--light", "spot:1,2"])
    assert isinstance(r.exception, ParameterError)
    bad = tmp_path / "bad.npz"
    np.savez(bad, nodes=np.zeros((3, 3)), fibre_offsets=np.array([0, 1, 3]))
    r = CliRunner().invoke(app, ["render", str(bad), "--out", str(out)])
    assert isinstance(r.exception, ParameterError)
    assert not out.exists()


def test_parse_light():
    l = parse_light("point:0,0.3,0.2:5,4,3")
    assert l.kind == "point" and l.rgb == (5.0, 4.0, 3.0)
    with pytest.raises(ParameterError):
        parse_light("dir:1,2")
