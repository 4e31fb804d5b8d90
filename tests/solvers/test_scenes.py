"""The seed's validation scenes (Heinze ch. 4): sphere (917 g) on cuboid (100 g), k = 5 / 0.2 N/m, k_coll = 1 N/m."""

import numpy as np
import pytest

from headsim.errors import DivergenceError, ParameterError
from headsim.solvers.scenes import SEED_SCENARIOS, rigid_fit_deviation, seed_sphere_on_cuboid


@pytest.fixture(scope="module")
def runs():
    return {name: seed_sphere_on_cuboid(name, steps=10, dt=0.2) for name in SEED_SCENARIOS}


def test_seed_explicit_loop_diverges_at_seed_time_step_with_si_masses():
    """eqs. 3.1-3.2 at dt = 0.2 s are far beyond the stability limit (eq. 3.6) -> detected, not written out."""
    with pytest.raises(DivergenceError, match="stability limit"):
        seed_sphere_on_cuboid("both-rigid", steps=10, dt=0.2, integrator="explicit")


@pytest.mark.slow
def test_rigid_sphere_on_soft_cuboid_deforms_the_cuboid_not_the_sphere(runs):
    """§4.2.2: the cuboid (k = 0.2) deforms, the sphere (k = 5) keeps its shape (nearly).

    Not in the thesis: with SI masses the sphere then passes through the flattened cuboid (see the
    scenes module docstring).
    """
    sphere, cuboid = runs["rigid-on-soft"].shape_change[-1]
    assert cuboid > 0.1
    assert sphere < cuboid / 5


@pytest.mark.slow
def test_both_soft_bodies_deform(runs):
    """§4.2.3: both deform (the soft sphere much more than the k = 5 sphere of §4.2.2)."""
    sphere, cuboid = runs["both-soft"].shape_change[-1]
    assert cuboid > 0.1 and sphere > 0.1
    assert sphere > 3 * runs["rigid-on-soft"].shape_change[-1][0]


@pytest.mark.slow
def test_both_rigid_cuboid_keeps_shape_and_sphere_sinks_in(runs):
    """§4.2.1: the k = 5 cuboid keeps its shape; the sphere still sinks somewhat into it.

    The thesis also reports that the k = 5 sphere keeps its shape; here it does not (about 35 %
    shape change), so that part is not asserted (documented in headsim.solvers.scenes).
    """
    r = runs["both-rigid"]
    assert r.shape_change[-1][1] < 0.05
    assert r.penetration.max() > 0.0
    assert r.shape_change[-1][1] < runs["rigid-on-soft"].shape_change[-1][1] / 5


def test_rigid_fit_deviation_ignores_rigid_motion():
    rng = np.random.default_rng(0)
    x = rng.standard_normal((20, 3))
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    q *= np.sign(np.linalg.det(q))
    assert rigid_fit_deviation(x, x @ q.T + 3.0) < 1e-12
    assert rigid_fit_deviation(x, x * 1.1) > 0.01


def test_unknown_scenario_is_refused():
    with pytest.raises(ParameterError):
        seed_sphere_on_cuboid("both-squishy")


def test_cli_scene_run_writes_png_and_vtu(tmp_path):
    import meshio
    from typer.testing import CliRunner

    from headsim.cli import app

    out = tmp_path / "seed"
    result = CliRunner().invoke(app, ["scene", "run", "seed-sphere-on-cuboid", "--out", str(out), "--steps", "2",
                                      "--scenario", "rigid-on-soft"])
    assert result.exit_code == 0, result.output
    assert (out / "sphere_on_cuboid.png").stat().st_size > 1000
    mesh = meshio.read(out / "sphere_on_cuboid_step002.vtu")
    assert mesh.point_data["displacement"].shape == (len(mesh.points), 3)
    assert np.isfinite(mesh.point_data["displacement"]).all()
    assert np.abs(mesh.point_data["displacement"]).max() > 0


def test_cli_unknown_scene_fails_cleanly_without_output(tmp_path):
    from headsim.cli import main

    out = tmp_path / "nothing"
    with pytest.raises(SystemExit) as e:
        main(["scene", "run", "no-such-scene", "--out", str(out)])
    assert e.value.code == 2
    assert not out.exists()
    with pytest.raises(SystemExit) as e:
        main(["scene", "run", "seed-sphere-on-cuboid", "--out", str(out), "--scenario", "squishy"])
    assert e.value.code == 2
    with pytest.raises(SystemExit) as e:
        main(["scene", "run", "seed-sphere-on-cuboid", "--out", str(out), "--scene-radius", "-1"])
    assert e.value.code == 2
    assert not out.exists() and not any(tmp_path.iterdir())


@pytest.mark.slow
def test_both_rigid_at_a_size_where_k5_is_rigid_reproduces_section_4_2_1_completely():
    """§4.2.1 in full: both bodies keep their shape and the sphere still sinks somewhat into the cuboid.

    At R = 5 m with 9 points across the sphere, the k = 5 N/m network under its 9 N weight strains by a
    few per cent (the rigidity group M g / (k n L) of the scenes module docstring), so here the
    thesis's "keeps its shape" holds for the sphere too.
    """
    r = seed_sphere_on_cuboid("both-rigid", steps=10, dt=0.2, radius=5.0, sphere_divisions=4)
    assert r.shape_change[:, 0].max() < 0.05  # sphere keeps its shape
    assert r.shape_change[:, 1].max() < 0.01  # cuboid keeps its shape
    depth = r.penetration.max() / 5.0
    assert 0.02 < depth < 0.5  # sinks somewhat, does not pass through
    sphere = r.states[-1].positions[r.offsets[0]:r.offsets[1]]
    assert sphere[:, 1].min() > -0.5 * 5.0  # still on top of the cuboid (its top face is y = 0)
