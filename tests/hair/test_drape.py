"""Drape scenes (headsim.hair.drape) and ``headsim hair drape`` (Sobottka 2008 §8.6).

The seed's scenes are far too large for CI (500 × 40 and 355 × 100 fibres × segments at 1 ms); the
tests here scale them down, as each docstring states; ``benchmarks/bench_drape.py`` and the CLI run the
full sizes.
"""

import numpy as np
import pytest
from typer.testing import CliRunner

from headsim.cli import app, main
from headsim.errors import ParameterError
from headsim.hair.drape import bounding_box, build_drape_scene, friction_law, run_drape
from headsim.hair.drape_checks import ribbon_measures
from headsim.hair.properties import friction
from headsim.solvers.chains import ChainSolver


def test_friction_modes_come_from_the_property_database():
    law = friction_law("aniso")
    assert law.mu_with == friction("wool/wool", 1).static  # with the scales: low
    assert law.mu_against == friction("wool/wool", 2).static  # against the scales: high
    assert law.mu_with < law.mu_across < law.mu_against
    iso = friction_law("iso")
    assert iso.mu_with == iso.mu_against == iso.mu_across == 0.47
    assert friction_law("none").frictionless
    with pytest.raises(ParameterError):
        friction_law("sticky")
    with pytest.raises(ParameterError):
        build_drape_scene("moon")


def _ribbon(mode):
    """The reduced §8.6.1 ribbon after 0.32 s: 6 fibres × 40 segments × 30 cm (the seed's segment length
    7.5 mm and fibre length), recorded every 0.08 s, and its measures (headsim.hair.drape_checks)."""
    sc = build_drape_scene("sphere-horizontal", mode, n_fibres=6, segments=40, duration=0.32)
    res = run_drape(sc, record_every=80)
    assert np.isfinite(res.polylines).all()
    return sc, res, ribbon_measures(sc, res)


def test_horizontal_ribbon_splits_without_friction_and_stays_with_friction():
    """§8.6.1 reduced: 6 instead of 500 fibres (a 0.4 mm wide ribbon instead of 3.9 cm), same 30 cm
    fibres with 40 segments, Δt = 1 ms, 0.32 s of the seed's few seconds. The ribbon is fixed at one
    end, falls onto a 6 cm sphere centred under its midline and lands after ≈ 0.06 s.

    Seed: without friction the arrangement splits into two portions that slide off to the left and the
    right; with friction the fibres stay on the sphere. Asserted at the middle node of every fibre
    (which rests on the top of the sphere):
    * frictionless: every fibre moves away from the midline on its own side (two portions; the scene
      and the solver are mirror-symmetric, so here they are equal halves, the seed's were of different
      sizes), the outermost ones sliding faster and faster (sliding on the sphere accelerates away from
      its top) and ending more than 10 ribbon widths apart;
    * μ = 0.47: the middle nodes stay in contact with the top of the sphere (within 2 radii of the
      iso-level) and, after fanning out by ≈ 0.6 mm on landing, no longer move sideways: less than one
      fibre diameter over the last 0.08 s.
    The full-size ribbon (500 fibres) is ``benchmarks/bench_drape_ribbon.py``: there the outer fibres, 19 mm
    from the midline on this sphere, drift beyond the friction angle on landing and slide off."""
    r = 35e-6
    sc, res, m = _ribbon("none")
    assert m.sides_kept()
    out = m.outermost_distance()  # outermost fibres' distance from the midline per frame
    steps = np.diff(out[1:])
    assert (steps > 0).all() and (np.diff(steps) > 0).all()
    width, last = m.spread()
    assert last > 10 * width
    sc, res, m = _ribbon("iso")
    assert (np.abs(m.contact_gap) < 2 * r).all()
    assert m.sideways(0.08).max() < 2 * r
    assert res.obstacle_contacts[-1] > 0


def test_cli_drape_joint_levers_option(tmp_path):
    """``--joint-levers mean`` reaches the solver (ChainOptions.joint_levers; its physics is tested in
    tests/solvers/test_chains_stabilisation.py): the same small plane drape with either choice writes its trajectory,
    the two trajectories differ (the joint stage's equations differ), and an unknown choice exits with 2 and
    writes nothing."""
    runs = {}
    for levers in ("start", "mean"):
        out = tmp_path / levers
        r = CliRunner().invoke(app, ["hair", "drape", "--scene", "plane", "--friction", "iso", "--fibres", "2",
                                     "--segments", "30", "--duration", "0.005", "--frames", "2", "--joint-levers",
                                     levers, "--out", str(out)])
        assert r.exit_code == 0, r.output
        runs[levers] = np.load(out / "trajectory.npz")["polylines"]
    assert np.isfinite(runs["mean"]).all()
    assert np.abs(runs["mean"][-1] - runs["start"][-1]).max() > 0.0
    with pytest.raises(SystemExit) as e:
        main(["hair", "drape", "--scene", "plane", "--joint-levers", "end", "--out", str(tmp_path / "bad")])
    assert e.value.code == 2
    assert not (tmp_path / "bad").exists()


def test_cli_drape_writes_outputs_and_rejects_bad_input(tmp_path, capsys):
    runner = CliRunner()
    out = tmp_path / "drape"
    r = runner.invoke(app, ["hair", "drape", "--scene", "plane", "--friction", "iso", "--fibres", "3",
                            "--segments", "30", "--duration", "0.01", "--frames", "3", "--out", str(out)])
    assert r.exit_code == 0, r.output
    for name in ("trajectory.npz", "energy_contacts.png", "vtk/frame_0000.vtu", "frames/frame_0000.png", "report.html"):
        assert (out / name).exists()
    data = np.load(out / "trajectory.npz")
    assert data["polylines"].shape[1:] == (3, 31, 3)
    assert np.isfinite(data["polylines"]).all()
    # per step: the solver steps it took (≥ 1) and the pairs turned back (≥ 0), one entry per 1 ms step
    assert data["substeps"].shape == data["crossings_restored"].shape == data["step_time"].shape == (10,)
    assert data["end_overlap"].shape == data["joint_root_failures"].shape == (10,)
    assert (data["substeps"] >= 1).all() and (data["crossings_restored"] >= 0).all()
    assert (data["joint_root_failures"] >= 0).all()
    assert "steps taken in halves" in r.output and "fibre pairs turned back" in r.output
    assert f"{int(data['joint_root_failures'].sum())} fibre joint solves on the start levers" in r.output
    assert "overlap of a contact row at a step's end" in r.output
    with pytest.raises(SystemExit) as e:
        main(["hair", "drape", "--scene", "moon", "--out", str(tmp_path / "bad")])
    assert e.value.code == 2
    assert not (tmp_path / "bad").exists()
    # Δt = 1 s: the chains tear apart (a joint gap of 8 cm, more than half a 15 mm segment, even in the solver's
    # smallest sub-steps of 125 ms): reported as a failed simulation, exit 2, no output folder. (At Δt = 0.5 s the
    # sub-steps of max_rotation_per_step kept the chain together with the former default start levers: 1.1 mm gaps.)
    with pytest.raises(SystemExit) as e:
        main(["hair", "drape", "--scene", "sphere-helical", "--fibres", "20", "--segments", "10", "--dt", "1",
              "--duration", "2", "--out", str(tmp_path / "torn")])
    assert e.value.code == 2
    assert "tore apart" in capsys.readouterr().err
    assert not (tmp_path / "torn").exists()


def test_ribbon_sphere_radius_is_the_users_and_checked(tmp_path, capsys):
    """``sphere_radius`` (sphere-horizontal only; the seed does not state its sphere): the obstacle is a sphere of
    that radius whose top stays 2 mm + r under the ribbon; impossible values and other scenes are refused, by
    build_drape_scene and by ``headsim hair drape --sphere-radius`` (exit 2, no output folder)."""
    from headsim.hair.drape import RIBBON_SPHERE_RADIUS

    for radius, expected in ((None, RIBBON_SPHERE_RADIUS), (0.08, 0.08)):
        sc = build_drape_scene("sphere-horizontal", "iso", n_fibres=2, segments=4, sphere_radius=radius)
        field = sc.obstacles[0].field
        assert field.radius == expected and tuple(field.center) == (0.0, -expected, 0.0)
        assert abs(float(field.distance(np.zeros((1, 3)))[0])) < 1e-15  # the sphere's top at the origin
        np.testing.assert_allclose(sc.state.position[:, 1], 0.002 + 35e-6)  # the flat ribbon 2 mm + r above it
    for bad in (0.0, -0.05, float("nan"), float("inf")):
        with pytest.raises(ParameterError, match="sphere_radius"):
            build_drape_scene("sphere-horizontal", "iso", n_fibres=2, segments=4, sphere_radius=bad)
    with pytest.raises(ParameterError, match="sphere-horizontal scene only"):
        build_drape_scene("plane", "iso", n_fibres=1, segments=30, sphere_radius=0.08)
    with pytest.raises(SystemExit) as e:
        main(["hair", "drape", "--scene", "plane", "--sphere-radius", "0.08", "--out", str(tmp_path / "bad")])
    assert e.value.code == 2
    assert "sphere-horizontal scene only" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_head_scene_hairs_start_combed_down_and_back_at_a_shallow_angle():
    """The head scene's start direction (_growth_direction): a unit vector at arctan(1/2) ≈ 26.6° to the skin's
    tangent plane (d·n = 1/√5), its tangential part along the comb direction (down and back) projected onto that
    plane; on the crown, where down is along the normal, straight back."""
    from headsim.hair.drape import COMB_DIRECTION, _growth_direction

    rng = np.random.default_rng(1)
    normals = rng.normal(size=(50, 3))
    normals[:, 1] = np.abs(normals[:, 1])  # scalp normals point up or sideways
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    comb = np.asarray(COMB_DIRECTION) / np.linalg.norm(COMB_DIRECTION)
    for n in normals:
        d = _growth_direction(n)
        assert np.linalg.norm(d) == pytest.approx(1.0)
        assert d @ n == pytest.approx(1 / np.sqrt(5))
        t = comb - (comb @ n) * n
        tangential = d - (d @ n) * n
        assert tangential @ t / (np.linalg.norm(tangential) * np.linalg.norm(t)) == pytest.approx(1.0)
    crown = _growth_direction(np.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(crown, np.array([0.0, 1.0, -2.0]) / np.sqrt(5), atol=1e-12)


def test_head_scene_roots_are_spaced_and_the_fibres_land_on_the_head():
    """The head scene (20 × 15 segments, 15 cm, combed down and back) through the fibres' landing on the head
    (first contact at t ≈ 0.12 s, tips at up to 4.0 m/s): no two anchored roots closer than 0.28 mm (with
    independent samples the
    40-fibre scene had two 42 µm apart, and that run diverged at t = 0.41 s), the fibres reach the head, and
    every joint gap opened in the landing is closed again by t = 0.45 s (``close_joint_gaps``; without it this run
    keeps 28 µm, the 40 × 30 one 22.5 µm), and no fibre axis (nodes and segment midpoints, every step) enters the
    skin, measured against the mesh by libigl (the criterion of ``test_draped_strand_sinks_less_than_a_fibre_radius``:
    an overlap of a radius or more puts the axis on the surface). Measured: closest 19 µm (0.53 r) with the scene's
    exact mesh distances, final joint gap 35 nm (issue 10's thirty-fourth session). Before the hairs started combed
    back (they started between the skin normal and straight down, so those on the crown stood up and landed at
    t ≈ 0.38 s): closest 22 µm; with the 3 mm grid field alone the axes went 32 µm into the skin in 39 of the 451
    steps (40 before the band grid was capped per segment)."""
    import igl
    from scipy.spatial import cKDTree

    from headsim.collide.fibre_scenes import ROOT_DENSITY

    sc = build_drape_scene("head", n_fibres=20, segments=15, duration=0.45)
    roots = sc.model.root_point
    assert cKDTree(roots).query(roots, k=2)[0][:, 1].min() >= 0.5 / np.sqrt(ROOT_DENSITY) * (1 - 1e-9)
    res = run_drape(sc, record_every=1)
    assert res.obstacle_contacts.max() > 0
    assert np.isfinite(res.polylines).all()
    v, t = sc.obstacle_mesh
    p = res.polylines
    axis = np.concatenate([p[:, :, 1:], 0.5 * (p[:, :, 1:] + p[:, :, :-1])], axis=2).reshape(-1, 3)
    skin, *_ = igl.signed_distance(axis, np.asarray(v, float), np.asarray(t, np.int64),
                                   sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)
    assert skin.min() > 0.0
    # closed to what one step's second-order rotation opens (tens of nm here), not kept (28 µm without it)
    assert res.max_joint_gap[-1] < 1e-6


def test_bounding_box_volume():
    p = np.zeros((2, 3, 3))
    p[1, 2] = [0.01, 0.02, 0.03]
    ext, vol = bounding_box(p)
    np.testing.assert_allclose(ext, [0.01, 0.02, 0.03])
    assert vol == pytest.approx(6e-6)



@pytest.mark.parametrize("name", ["sphere-helical", "plane", "terrain"])
def test_helical_strands_start_without_interpenetration(name):
    """§8.6.2–8.6.4 at the seed's full size (355 or 250 fibres × 100 segments, 30 cm): the initially
    helical strand starts with no pair of segments (other than joint neighbours) closer than one fibre
    diameter, by the project's fibre–fibre detection (a contact there is a centre-line distance below
    2r). The former start (independent 12 mm helices with random phases around a 4 mm disc) had 13,422
    such pairs. Too close a lattice is refused: its chords would overlap."""
    from headsim.collide import fibre_self_contacts, fibres_from_arrays
    from headsim.hair.drape import FIBRE_DIAMETER
    from headsim.solvers.chains import polylines_from_state

    sc = build_drape_scene(name)
    assert sc.model.n_fibres == (250 if name == "plane" else 355) and sc.model.n_segments == 100 * sc.model.n_fibres
    p = polylines_from_state(sc.model, sc.state)
    F, nn, _ = p.shape
    off = np.arange(F + 1) * nn
    overlaps = fibre_self_contacts(fibres_from_arrays(p.reshape(-1, 3), off, 0.5 * FIBRE_DIAMETER))
    assert len(overlaps) == 0
    # the strand is a bundle: every fibre has lattice neighbours within 1.6 diameters (not loose helices)
    near = fibre_self_contacts(fibres_from_arrays(p.reshape(-1, 3), off, 0.8 * FIBRE_DIAMETER))
    assert len(np.unique(np.concatenate([near.body_a, near.body_b]))) == F
    with pytest.raises(ParameterError):
        build_drape_scene(name, n_fibres=7, segments=10, fibre_spacing=1.002 * FIBRE_DIAMETER)


def test_terrain_field_is_solid_and_within_its_interpolation_bound():
    """§8.6.3 (no penetration even in strongly curved cavities, thanks to the distance field and its
    iso-level offset): the terrain field is a solid under the height field, negative deeper than any
    band (a fibre end pushed in must be pushed back out, not meet a false zero crossing and fall
    through, as with the former all-positive far values), with normals out of it; the exact distance
    returns the offset of points placed along the surface normal; the grid field is within the
    trilinear interpolation bound (3/8) Δs² κ_max of it near the surface, and that bound is the iso-level
    the fibres rest on (so the interpolation cannot put them into the true surface)."""
    from headsim.hair.drape import (
        _terrain_bottom,
        _terrain_distance,
        _terrain_field,
        _terrain_height,
        _terrain_slope,
        terrain_level,
    )

    fld, _ = _terrain_field()
    rng = np.random.default_rng(1)
    xz = rng.uniform(-0.13, 0.13, (2000, 2))  # more than the edge's rounding radius (15 mm) inside the walls
    h = _terrain_height(xz[:, 0], xz[:, 1])
    sx, sz = _terrain_slope(xz[:, 0], xz[:, 1])
    nrm = np.stack([-sx, np.ones_like(sx), -sz], 1)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    surf = np.stack([xz[:, 0], h, xz[:, 1]], 1)
    bound = terrain_level(fld.spacing)
    for d in (-4e-3, -1e-3, -35e-6, 0.0, 35e-6, 1e-3, 4e-3):
        p = surf + d * nrm
        np.testing.assert_allclose(_terrain_distance(p), d, atol=1e-9)
        assert np.abs(fld.distance(p) - d).max() < bound
    for depth in (4e-3, 12e-3, 28e-3):
        assert (fld.distance(surf - [0.0, depth, 0.0]) < 0).all()
        assert (fld.distance(surf + [0.0, depth, 0.0]) > 0).all()
        # nearer the top than the side walls (the bottom lies 5 cm under the lowest point)
        away = np.abs(xz).max(1) < 0.15 - depth - 2 * fld.spacing
        assert (fld.normal(surf[away] - [0.0, depth, 0.0])[:, 1] > 0).all()
    sc = build_drape_scene("terrain", n_fibres=3, segments=30)
    assert sc.obstacles[0].level == bound
    # the side walls: the slab ends at |x|, |z| = 15 cm; beside it, below its rounded edge, the distance is horizontal
    edge_z = rng.uniform(-0.12, 0.12, 200)
    he = _terrain_height(0.15, edge_z)
    # more than the 15 mm rounding below the edge (along the steepest slope there) and above the bottom
    for dx, dy in ((2e-3, -32e-3), (8e-3, -35e-3), (-2e-3, -33e-3)):
        q = np.stack([np.full(200, 0.15 + dx), he + dy, edge_z], 1)
        np.testing.assert_allclose(_terrain_distance(q), dx, atol=1e-12)
        assert np.abs(fld.distance(q) - dx).max() < bound
        if dx > 0:
            n = fld.normal(q)
            assert (n[:, 0] > 0.99).all()  # out of the wall, not up through the hill
    # under the flat bottom: outside, by the height below it; the grid holds the slab with a margin
    b = _terrain_bottom()
    under = np.stack([xz[:, 0], np.full(2000, b - 5e-3), xz[:, 1]], 1)
    np.testing.assert_allclose(_terrain_distance(under), 5e-3, atol=1e-12)
    assert (fld.distance(under) > 0).all() and (fld.normal(under)[:, 1] < -0.99).all()


def test_sphere_helical_geometry_is_derived_from_the_seeds_table_8_1_box():
    """§8.6.2 / Table 8.1: the seed states neither the root height nor the sphere nor the helix; the
    default scene derives them from its isotropic box 8.69 × 14.09 × 8.35 cm and μ = 0.47
    (:class:`HelicalSphereGeometry`). Checked: each derivation step's relation; the full-size start
    (355 × 100, 30 cm) is a coil one short box side wide (8.69 cm, within one segment chord, 3 mm),
    hangs from the roots (the highest nodes) clear of the sphere, and the pile's rim on the sphere
    (half the long side from the axis) lies on the friction angle and 8.35 cm below the roots."""
    from headsim.hair.drape import (
        FIBRE_DIAMETER,
        SEED_ISOTROPIC_MU,
        SEED_TABLE_8_1,
        HelicalSphereGeometry,
    )
    from headsim.solvers.chains import polylines_from_state

    g = HelicalSphereGeometry.derive()
    short, long_, height = (0.01 * v for v in SEED_TABLE_8_1["iso"])
    a = 0.5 * long_
    assert a / g.sphere_radius == pytest.approx(np.sin(np.arctan(SEED_ISOTROPIC_MU)), rel=1e-12)
    rim_depth = g.sphere_radius - np.sqrt(g.sphere_radius**2 - a**2)
    assert g.root_height + rim_depth == pytest.approx(height, rel=1e-12)
    assert 0.04 < g.helix_radius < 0.5 * short
    sc = build_drape_scene("sphere-helical")
    p = polylines_from_state(sc.model, sc.state)
    assert p.shape == (355, 101, 3)
    ext, _ = bounding_box(p)
    assert abs(ext[0] - short) < 3e-3 and abs(ext[2] - short) < 3e-3  # the coil's diameter
    assert np.allclose(p[:, 0, 1], p[..., 1].max(), atol=2e-3)  # roots on top (lattice offsets ≤ 1 mm)
    phi = sc.obstacles[0].field.distance(p.reshape(-1, 3))
    assert phi.min() > 0.02  # hangs ≥ 2 cm above the sphere at the start
    assert p[..., 1].max() - p[..., 1].min() < height  # the coil fits in the seed's box height
    assert sc.model.radius[0] == pytest.approx(0.5 * FIBRE_DIAMETER)


# Table 8.1's thresholds, from the seed's own figures (volumes relative to the anisotropic run: iso 0.99,
# aniso 1.00, none 0.906): 0.95 is half-way between its two groups, 0.05 half the gap between them.
GROUP_THRESHOLD = 0.95
SAME_BAND = 0.05
# "stable volume": the volume range over the last 0.2 s below half the seed's 9 % friction / no-friction
# difference (a change Table 8.1 could not resolve), the kinetic energy below 1/100 of its peak
STABLE_FRACTION = 0.05
KE_FRACTION = 1e-2


HELICAL_MODES = (("aniso", 5.0), ("iso", 1.5), ("none", 0.7))


def _helical_run(mode, duration):
    """One run of :func:`helical_runs`: (result, volumes (frames,) m³)."""
    sc = build_drape_scene("sphere-helical", mode, n_fibres=7, segments=30, duration=duration)
    res = run_drape(sc, record_every=10)
    assert np.isfinite(res.polylines).all()
    return res, np.array([bounding_box(p)[1] for p in res.polylines])


def _shared_runs(directory, jobs, wait_s=1800.0):
    """{name: job()} for jobs = {name: callable}, computed once per test session across pytest-xdist workers:
    a worker claims a job by creating ``<name>.claim`` in ``directory`` (atomic, O_EXCL), runs it and writes
    ``<name>.pkl``; the other workers run the jobs they claim and load the rest when written. (Without
    sharing, the module-scoped fixture ran in both workers whenever its tests were split between them: two
    × 200–280 s on 2 cores. pytest-xdist's ``--dist loadgroup`` does not keep them together under pytest 9.2:
    it tags the groups through ``item._nodeid``, which pytest 9 no longer reads.) A claim whose result does
    not appear within ``wait_s`` (its worker died) is run here; a job that raised in its worker (``<name>.failed``)
    fails the waiting workers at once."""
    import os
    import pickle
    import time

    out = {}
    for name, job in jobs.items():
        try:
            os.close(os.open(directory / f"{name}.claim", os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            continue
        try:
            out[name] = job()
        except BaseException as e:  # the workers waiting for this job fail at once instead of after wait_s
            (directory / f"{name}.failed").write_text(f"{type(e).__name__}: {e}")
            raise
        tmp = directory / f"{name}.{os.getpid()}.tmp"
        with tmp.open("wb") as f:
            pickle.dump(out[name], f)
        os.replace(tmp, directory / f"{name}.pkl")
    deadline = time.monotonic() + wait_s
    for name, job in jobs.items():
        if name in out:
            continue
        path = directory / f"{name}.pkl"
        failed = directory / f"{name}.failed"
        while not path.exists() and time.monotonic() < deadline:
            if failed.exists():
                raise RuntimeError(f"the shared run {name!r} failed in another worker: {failed.read_text()}")
            time.sleep(0.5)
        if path.exists():
            with path.open("rb") as f:
                out[name] = pickle.load(f)
        else:
            out[name] = job()
    return out


def test_a_shared_run_that_fails_fails_the_waiting_worker_at_once(tmp_path):
    """_shared_runs: the worker that claimed a job re-raises its error and marks it; a second worker (here the
    same process with the claim present) fails at once instead of waiting for a result that never comes."""
    def boom():
        raise ValueError("diverged")

    with pytest.raises(ValueError, match="diverged"):
        _shared_runs(tmp_path, {"none": boom})
    with pytest.raises(RuntimeError, match="failed in another worker: ValueError: diverged"):
        _shared_runs(tmp_path, {"none": boom}, wait_s=60.0)


@pytest.fixture(scope="module")
def helical_runs(tmp_path_factory):
    """The reference scene (§8.6.2, the derived default geometry, rest shape straight) reduced to 7 fibres
    × 30 segments (1 cm; the seed: 355 × 100), Δt = 1 ms, 30 cm fibres, recorded every 10 ms: none to the
    seed's 0.7 s, iso to 1.5 s and aniso to 5 s (for the stable volume; their frames at 0.65–0.75 s, the seed's
    "ca. 0,7 Sekunden" ± 0.05 s, for Table 8.1). Returns {mode: (result, volumes (frames,) m³)}. Each run
    is made once per test session (:func:`_shared_runs`, in the directory this session's xdist workers share;
    a run without xdist keeps them in its own temporary directory)."""
    import os

    base = tmp_path_factory.getbasetemp()
    shared = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "helical_runs"
    shared.mkdir(exist_ok=True)
    return _shared_runs(shared, {mode: (lambda m=mode, d=duration: _helical_run(m, d))
                                 for mode, duration in HELICAL_MODES})


def _volume_at(run, t):
    res, vol = run
    return vol[int(np.argmin(np.abs(res.times - t)))]


def test_table_8_1_no_friction_gives_the_smallest_box(helical_runs):
    """Table 8.1 (§8.6.5.2), t = 0.7 s: without friction the bounding box is the smallest — volume below
    0.95 × the isotropic and the anisotropic ones (seed: 0.915 and 0.906).

    Reduced scene (see ``helical_runs``); the ordering was checked on larger scenes once
    (``benchmarks/bench_drape_volume.py``, derived geometry, straight rest shape): none/aniso, none/iso =
    0.58, 0.68 at 19 × 30 and 0.53, 0.72 at 61 × 50 (before the contact solve's joint rows became J u = 0,
    ``joint_gap_fraction`` = 0; not re-measured since); here 0.59, 0.53 with the Nesterov-accelerated 30-sweep
    contact solve (0.49, 0.49 with the former plain 60 sweeps; measured at 0.7 s in issue 10's twelfth session),
    0.64, 0.60 with issue 10's ``half_step_projection`` and ``separating_candidates`` (0.62, 0.56 before them,
    0.57, 0.53 after that change, 0.49, 0.56 before it; 0.46, 0.47 with the mean joint levers, the default since
    issue 10's thirty-eighth session). At full size (355 × 100, twenty-eighth session) none/aniso
    is 0.83 but none/iso 0.96: the second assertion would fail there (see ``bench_drape_volume.py``). Where it
    holds, the agreement is in the ordering only, not in the mechanism or the size: our boxes are 2–5 times the
    seed's; the frictionless strand
    slides over the sphere's rim and hangs down its side (box ≈ 12 × 24 × 7 cm, 24 cm tall against the
    seed's 8.24 cm), narrower than the frictional strands spread over the cap."""
    n, i, a = (_volume_at(helical_runs[m], 0.7) for m in ("none", "iso", "aniso"))
    assert n / a < GROUP_THRESHOLD
    assert n / i < GROUP_THRESHOLD


def test_reduced_reference_scene_never_gains_energy(helical_runs):
    """Issue 10: "energy never increases with ε = 0", on the three runs of ``helical_runs`` (none to 0.7 s, iso
    to 1.5 s, aniso to 5 s; landing, sliding and settling on the sphere): no step raises the total energy
    (kinetic + springs + gravity) by more than round-off (1e-9 of the peak kinetic energy, the solver's
    ``ENERGY_ROUNDOFF``). Before the position corrections were bounded (``_trusted_correction``) the frictionless
    run gained up to 5e-7 J (≈ 20 % of its kinetic energy) in 4 steps at t = 0.365–0.368 s, each taken in 5–8
    halved steps, from split push-outs that moved points by millimetres to correct microns."""
    for mode, (res, _) in helical_runs.items():
        rise = float(np.diff(res.total_energy).max())
        assert rise <= 1e-9 * float(res.kinetic.max()), (mode, rise)


@pytest.mark.xfail(strict=True, reason="Table 8.1's iso ≈ aniso is not reproduced at this scale: around 0.7 s the "
                   "ratio is a transient crossing 1 (see the docstring)")
def test_table_8_1_isotropic_and_anisotropic_boxes_agree(helical_runs):
    """Table 8.1: the isotropic (μ = 0.47) and anisotropic (wool/wool 0.13 / 0.61 / 0.21) boxes agree
    within 5 % (seed: 0.99) "after about 0.7 s" (ca. 0,7 Sekunden): asserted at 0.65, 0.70 and 0.75 s, so that a
    transient crossing 1 near 0.7 s does not count as agreement. Not reproduced on this reduced scene (strict
    xfail): neither frictional strand has come to rest, and the ratio sweeps through 1. Measured (issue 10,
    7 × 30, iso/aniso every 0.1 s from 0.4 to 1.0 s): plain Gauss–Seidel at 60 sweeps (the former defaults)
    0.50, 0.61, 0.77, 1.00 (0.7 s), 1.64, 3.22, 5.16; Nesterov-accelerated at 60 sweeps 0.47, 0.53, 0.65,
    0.88, 1.40, 2.36, 2.28; Nesterov at 30 sweeps 0.47, 0.59, 0.75, 1.115 (0.7 s), 1.79, 2.18, 2.29; with the
    candidate reserve 0.48, 0.64, 0.81, 0.981 (0.7 s), 1.26, 1.88, 2.66, and 0.868 / 0.981 / 1.072 at 0.65 /
    0.70 / 0.75 s; with it, 2 contact domains and the relative candidate band (the defaults since issue 10's
    thirteenth session) 0.455, 0.520, 0.699, 0.940 (0.7 s), 1.148, 1.535, 1.803, and 0.770 / 0.940 / 0.974 at
    0.65 / 0.70 / 0.75 s. At 0.7 s alone the check passed by chance with the former defaults (0.998) and with
    the candidate reserve (0.981); other solver variants gave 0.88–1.11
    there (1.070 with a sweep budget of 1,000,000, 0.981 / 0.948 / 1.074 with 2 / 3 / 4 contact_domains,
    0.85 at 19 × 30 and 0.74 at 61 × 50). With the mean joint levers (the default since issue 10's thirty-eighth
    session) 0.503, 0.640, 0.809, 0.972 (0.7 s), 1.374, 2.306, 3.127, and 0.887 / 0.972 / 1.079 at 0.65 / 0.70 /
    0.75 s; at 19 × 30 0.952 / 1.110 / 1.425 at 0.65 / 0.70 / 0.75 s (none/aniso 0.46, none/iso 0.41 at 0.7 s).
    Strict: a change that makes it pass is to be measured (is the
    agreement then robust over time and scale?), not taken as a reproduction."""
    for t in (0.65, 0.70, 0.75):
        i, a = (_volume_at(helical_runs[m], t) for m in ("iso", "aniso"))
        assert abs(i / a - 1) < SAME_BAND, (t, i / a)


def test_reference_scene_settles_to_a_stable_volume_with_isotropic_friction(helical_runs):
    """§8.6.2: the strand settles ("friction prevents further sliding") and forms a stable volume. With
    μ = 0.47 (the reduced scene of ``helical_runs``, 1.5 s): over the last 0.2 s the bounding-box volume
    varies by less than 5 % of its mean and the kinetic energy is below 1/100 of its peak (measured:
    0.98 % and 1.1e-3 with the mean joint levers, issue 10's thirty-eighth session; 0.27 % and 4.4e-4 with
    issue 10's ``half_step_projection`` and ``separating_candidates``; before them 0.2 % and 3.1e-4, 3.9e-4
    before ``joint_gap_fraction`` = 0; 19 × 30: 0.2 %, 2.8e-4; 61 × 50: 0.2 %, 3.2e-5, both before; the full 355 × 100 scene, run once by ``benchmarks/bench_drape_volume.py --modes iso``:
    0.3 %, 2.8e-5). The strand rests partly over the
    sphere's rim (box ≈ 13 × 16 cm wide, 20 cm tall, against the seed's 8.7 × 14.1 cm, 8.4 cm tall). The
    anisotropic strand takes longer: see the next test."""
    from headsim.hair.drape import volume_stability

    res, _ = helical_runs["iso"]
    assert res.times[-1] == pytest.approx(1.5)
    spread, ke = volume_stability(res, 0.2)
    assert spread < STABLE_FRACTION
    assert ke < KE_FRACTION


def test_reference_scene_settles_to_a_stable_volume_with_anisotropic_friction(helical_runs):
    """§8.6.2: the strand comes to rest "nach wenigen Sekunden Simulationszeit" (after a few seconds of simulated
    time). With the anisotropic law (wool/wool 0.13 / 0.61 / 0.21: across the fibres it slides at less than half the
    isotropic μ = 0.47) it is still moving at 1.5 s, but by 5 s the same criteria as the isotropic strand's hold
    (last 0.2 s). When it comes to rest depends on the trajectory, which any change of the solver reshuffles (a
    fibre that swings off the sphere's side takes a second or more to come back); measured (issue 10, thirty-first
    session; volume range over the preceding 0.2 s / kinetic energy over its peak):

    * 7 × 30 (this test's scene): 25 % / 4.3e-3 at 1.5 s, 0.5 % / 7.3e-5 at 2.5 s, 0.1 % / 2.2e-5 at 4 s; with the
      relative band's grid capped at 100 nodes per segment (``chain_band.NODES_PER_SEGMENT``, the same session) a
      fibre swings off (49 % at 2.5 s): 3.2 % / 1.3e-4 at 3.5 s, 3.2 % / 6.2e-5 at 4 s, 2.4 % / 1.1e-5 at 5 s;
    * 19 × 30: 8.4 % at 3.5 s, then 1.6–4.3 % from 3.75 to 7 s (2.4 % / 5.7e-5 at 4 s), creeping by ≈ 1 % of its
      volume per second from 5.5 s;
    * 61 × 50 and full size: 15 % and 18 % at 1.5 s (``benchmarks/bench_drape_volume.py``), not run longer;
    * 7 × 30 with the post-stabilisation and step halving (``ChainOptions``, thirty-second session): a fibre swings
      off (93 % at 2.75 s), then 5.0 % at 3.5 s, 5.3 % at 4 s, 4.1 % at 4.25 s and falling, 2.8 % / 1.2e-5 at 5 s,
      1.9 % at 6 s: the check moved from 4 s to 5 s;
    * 7 × 30 with the mean joint levers (the default since the thirty-eighth session): 0.02 % / 2.7e-6 at 5 s."""
    from headsim.hair.drape import volume_stability

    res, _ = helical_runs["aniso"]
    assert res.times[-1] == pytest.approx(5.0)
    spread, ke = volume_stability(res, 0.2)
    assert spread < STABLE_FRACTION
    assert ke < KE_FRACTION


def test_draped_strand_sinks_less_than_a_fibre_radius():
    """7 fibres × 30 segments of the sphere-helical drape, 300 steps of 1 ms (the strand lands on the sphere
    and on itself): over the second half of the run no capsule may overlap another or the sphere by a
    fibre radius or more (StepStats.max_penetration: mid-step gaps of the contact rows with r_a + r_b,
    adjacent segments of one fibre excluded, plus the end-of-step sphere distance of the segment axes).
    An overlap of one radius puts a fibre's axis on the other's surface: past it the contact normal
    points through the partner (tunnelling). Issue 10: with the former first half step (the joint stage's
    twists, springs included) the strand was carried into the contacts that hold it bent every step and
    sat up to 153 µm deep (mean 78 µm over these steps); with ``ChainOptions.half_step_projection``
    and ``separating_candidates`` (defaults) 25.3 µm (0.72 r; mean 2.4 µm), and the exact end-of-step
    capsule overlaps (every 10th step) 5.3 µm against 43 µm (measured). With ``end_velocity_positions`` (default;
    the rows' gaps in StepStats are then first-order gaps at t_i, not mid-step gaps) 8.8 µm (0.25 r; mean
    2.4 µm; max joint gap 7.7 µm against 3.4 µm, measured with a sweep budget of 1,000,000); at the
    default ``sweep_budget`` = 100,000 4.6 µm (0.13 r; mean 2.0 µm; max joint gap 7.9 µm; measured, and
    8.8 µm reproduced with ``sweep_budget=1_000_000`` on the same tree; one chaotic trajectory each)."""
    scene = build_drape_scene("sphere-helical", "aniso", n_fibres=7, segments=30)
    solver = ChainSolver(scene.options)
    state = scene.state
    pen = []
    for _ in range(300):
        state = solver.step(scene.model, state, scene.dt, scene.obstacles)
        pen.append(solver.last_stats.max_penetration)
    assert max(pen[150:]) < scene.model.radius[0]


def test_parallel_kernels_reproduce_the_serial_ones_bitwise():
    """The chain solver's Numba-parallel kernels (``ChainOptions.parallel_threshold`` = 1: the packed BVH, the
    fused detection pass, the contact iteration over 2 body domains with its parallel candidate test and
    extrapolation) against the serial ones (the default on this size) on the ringlet start reduced to 7 × 30
    (in contact with itself from the first step), 40 steps of 1 ms: positions, rotations and velocities the
    same to the bit (every row is visited in the same order whatever the number of threads; the domains'
    rows share no body), with candidates promoted during the solves so that those paths run. Both store the
    kernel's arrays in float64 (``kernel_precision``'s "auto" ties float32 to the parallel kernels' size)."""
    from headsim.hair.drape import HelicalSphereGeometry

    runs = []
    for threshold in (10**9, 1):
        sc = build_drape_scene("sphere-helical", "aniso", n_fibres=7, segments=30,
                               geometry=HelicalSphereGeometry.former(), parallel_threshold=threshold,
                               kernel_precision="float64")
        solver = ChainSolver(sc.options)
        state, promoted = sc.state, 0
        for _ in range(40):
            state = solver.step(sc.model, state, sc.dt, sc.obstacles)
            promoted += solver.last_stats.promoted_rows
        runs.append((state, promoted))
    (a, pa), (b, pb) = runs
    assert pa == pb and pa > 0
    for name in ("position", "rotation", "velocity", "angular_velocity"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_predictor_extension_false_keeps_the_predictor_at_its_cap(monkeypatch):
    """``ChainOptions.predictor_extension``: 7 × 30 fibres of the sphere-helical drape falling onto the sphere
    and onto themselves (150 steps of 1 ms), the predictor solves capped at one sweep (``predictor_sweeps`` = 1;
    no sweep budget, under which so small a system would run them to ``qp_iterations``). Candidates that become
    rows in that sweep extend it (measured: 31 of the 150 predictor solves ran 2 sweeps) unless the extension is
    off: then every one of them stops after its sweep. The kernel's calls are recorded by their sweep cap
    (argument 23)."""
    from headsim.solvers import _kernels

    kernel = _kernels.chains_coupled.coupled_iterate
    predictor_sweeps = {}
    for extension in (True, False):
        sc = build_drape_scene("sphere-helical", "aniso", n_fibres=7, segments=30, predictor_sweeps=1,
                               sweep_budget=0, predictor_extension=extension)
        solver = ChainSolver(sc.options)
        sweeps = predictor_sweeps[extension] = []

        def spy(*args, sweeps=sweeps):
            out = kernel(*args)
            if args[23] == 1:
                sweeps.append(int(out[0]))
            return out

        monkeypatch.setattr(_kernels.chains_coupled, "coupled_iterate", spy)
        state = sc.state
        for _ in range(150):
            state = solver.step(sc.model, state, sc.dt, sc.obstacles)
    assert len(predictor_sweeps[True]) == len(predictor_sweeps[False]) == 150
    assert max(predictor_sweeps[True]) == 2  # the extension ran here (up to twice the cap)
    assert max(predictor_sweeps[False]) == 1
