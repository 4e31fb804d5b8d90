"""Skin-cushion Coulomb friction of the mask fit (FitOptions.friction; fit.py module doc, "Friction").

A cushion block is pressed by a rigid shell (the mask's ShellAttachment, strap force F along the
approach axis) onto an FEM tissue slab whose deep side is fixed bone (a flat face patch), through
the mask's own AxialContact, then sheared along the skin by the shell. Coulomb's law is checked:
below the limit (shear T = mu F / 2, force-controlled) the block sticks and the friction on the skin
balances T, with no contact outside the cone |f_T| <= mu lambda; driven far past the stick length
(displacement-controlled) every contact slides and carries exactly mu lambda, so the skin's total
tangential load is mu F. Without friction there is no tangential equilibrium at all (the first check
cannot hold). The full mask fit with friction still balances the strap force within 1 %.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from headsim.errors import ConvergenceError, ParameterError
from headsim.mask.fit import (FRICTION_SLIP_FRACTION, SKIN_SILICONE_FRICTION, AxialContact, FitOptions,
                              ShellAttachment, _solve)
from headsim.mesh import TetMesh
from headsim.mesh.tet import REGION_CUSHION, REGION_TISSUE
from headsim.solvers.contact import QuasiStaticOptions, RigidDriver, solve_quasi_static, surface_vertex_areas
from headsim.solvers.fem import fem_from_tetmesh
from headsim.solvers.grids import block_tetmesh
from headsim.solvers.materials import Material

sys.path.insert(0, str(Path(__file__).parent))
from _fit_case import coarse_problem  # noqa: E402

MU = SKIN_SILICONE_FRICTION
L = 0.02     # m, face patch side
T_TISSUE = 0.01  # m, tissue thickness (Heinze §2.3.1)
HB = 0.004   # m, cushion block height
F = 2.0      # N strap force
APPROACH = np.array([0.0, 0.0, -1.0])  # the mask moves onto the skin along -z
PATCH = Material.from_kpa(1000.0, 0.45, 1050.0)
BLOCK = Material.from_kpa(1000.0, 0.45, 1050.0)


def _faces(mesh, z, offset=0):
    tri = mesh.boundary_triangles
    return tri[np.all(np.isclose(mesh.vertices[tri][:, :, 2], z), axis=1)] + offset


def _scene():
    slab = block_tetmesh((L, L, T_TISSUE), (4, 4, 2), origin=(0.0, 0.0, -T_TISSUE))
    block = block_tetmesh((L / 2, L / 2, HB), (2, 2, 1), origin=(L / 4, L / 4, 0.0))
    ns = slab.n_vertices
    verts = np.vstack([slab.vertices, block.vertices])
    fixed = np.concatenate([np.isclose(slab.vertices[:, 2], -T_TISSUE), np.zeros(block.n_vertices, bool)])
    region = np.concatenate([np.full(slab.n_tets, REGION_TISSUE), np.full(block.n_tets, REGION_CUSHION)])
    mesh = TetMesh(verts, np.vstack([slab.tets, block.tets + ns]), tet_region=region.astype(np.int32), fixed=fixed,
                   name="patch+block")
    model = fem_from_tetmesh(mesh, {REGION_TISSUE: PATCH, REGION_CUSHION: BLOCK})
    skin_tri = _faces(slab, 0.0)
    areas = surface_vertex_areas(ns, skin_tri, slab.vertices)
    skin = np.flatnonzero(areas > 0)
    shell = ns + np.flatnonzero(np.isclose(block.vertices[:, 2], HB))
    h = L / 4
    return model, skin, areas[skin], _faces(block, 0.0, ns), shell, h


def _solve_patch(model, skin, areas, cushion_tri, shell, h, drivers, x0=None, u0=None, mu=MU):
    penalty = 200.0 * PATCH.young_modulus / h
    contact = AxialContact(skin, areas, cushion_tri, penalty, friction=mu,
                           friction_slip=FRICTION_SLIP_FRACTION * h if mu > 0 else None)
    contact.axis_of_approach = APPROACH
    contact._tree = None
    contact.tolerance = 2e-4 * F
    rest = model.rest_positions[shell]
    modes = np.stack([np.broadcast_to(APPROACH, rest.shape), np.broadcast_to([1.0, 0.0, 0.0], rest.shape)])
    attach = ShellAttachment(shell, rest, 1e4 * PATCH.young_modulus * 3e-3, modes)
    opts = QuasiStaticOptions(force_tolerance=1e-7 * F, max_contact_updates=30)
    res = solve_quasi_static(model, [contact, attach], drivers, initial_positions=x0, initial_drivers=u0,
                             options=opts)
    return res, contact


def _pressed():
    scene = _scene()
    drivers = [RigidDriver(APPROACH, force=F), RigidDriver(APPROACH, displacement=0.0)]
    first, _ = _solve_patch(*scene, drivers)
    return scene, first


def _shear(drivers):
    scene, first = _pressed()
    res, contact = _solve_patch(*scene, drivers, x0=first.positions, u0=first.driver_displacement)
    x, u = res.positions, res.driver_displacement
    on = contact.normal_force > 0
    slave = contact.slave_vertices[contact.active]
    total = contact.vertex_forces(x, u)[scene[1]].sum(axis=0)
    friction = contact.friction_forces(x, u)[slave]
    slip = np.linalg.norm(contact._slip(x, u), axis=1)
    return res, contact, total, friction, slip, on


def test_block_below_the_coulomb_limit_sticks_inside_the_cone():
    shear = 0.5 * MU * F
    res, contact, total, friction, slip, on = _shear([RigidDriver(APPROACH, force=F),
                                                      RigidDriver(APPROACH, force=shear)])
    # the skin takes the whole strap and shear load (momentum balance of the shell + cushion; the
    # shell's other motions are held by its tie)
    assert total[[0, 2]] == pytest.approx([shear, -F], abs=1e-6 * F)
    lam = contact.normal_force
    f_t = np.linalg.norm(friction, axis=1)
    assert on.sum() >= 4
    assert (f_t <= MU * lam * (1 + 1e-9) + 1e-15).all()  # no contact outside the Coulomb cone
    stick = slip < contact.friction_slip
    assert stick[on].all()  # below the limit the block sticks
    # the regularised law: a stick spring mu lambda / eps
    assert f_t[on] == pytest.approx(MU * lam[on] * slip[on] / contact.friction_slip, rel=1e-9)
    # the friction, not the normal forces, holds the shear (planes tilt only by the small strain)
    assert friction[:, 0].sum() == pytest.approx(shear, rel=2e-2)


def test_the_same_shear_without_friction_has_no_equilibrium():
    scene, first = _pressed()
    drivers = [RigidDriver(APPROACH, force=F), RigidDriver(APPROACH, force=0.5 * MU * F)]
    with pytest.raises(ConvergenceError):
        _solve_patch(*scene, drivers, x0=first.positions, u0=first.driver_displacement, mu=0.0)


def test_block_driven_past_the_stick_length_slides_at_mu_times_the_normal_force():
    h = L / 4
    res, contact, total, friction, slip, on = _shear([RigidDriver(APPROACH, force=F),
                                                      RigidDriver(APPROACH, displacement=0.5 * h)])
    assert total @ APPROACH == pytest.approx(F, rel=1e-6)
    assert (slip[on] > contact.friction_slip).all()  # every contact slides
    lam = contact.normal_force[on]
    # sliding contacts carry exactly mu lambda, opposing their slip
    assert np.linalg.norm(friction[on], axis=1) == pytest.approx(MU * lam, rel=1e-9)
    assert friction[on][:, 0].sum() == pytest.approx(MU * lam.sum(), rel=2e-2)


def test_mask_fit_with_friction_balances_the_strap_force_and_stays_in_the_cone():
    p = coarse_problem()
    p = replace(p, options=replace(p.options, friction=MU))
    force = 15.0
    from headsim.solvers.contact import RigidDriver as RD

    drivers = [RD(p.approach, force=force)] + [RD(p.approach, force=0.0)] * 2
    res, contact = _solve(p, drivers, None, np.zeros(3), force)
    x, u = res.positions, res.driver_displacement
    cf = contact.vertex_forces(x, u)[p.skin_vertices]
    assert float((cf @ p.approach).sum()) == pytest.approx(force, rel=1e-2)
    friction = contact.friction_forces(x, u)[p.skin_vertices]
    lam = np.zeros(len(p.skin_vertices))
    lam[contact.active] = contact.normal_force
    assert np.abs(friction).sum() > 0  # friction acts
    assert (np.linalg.norm(friction, axis=1) <= MU * lam * (1 + 1e-9) + 1e-12).all()


def test_friction_coefficient_is_validated():
    with pytest.raises(ParameterError, match="friction"):
        FitOptions(friction=-0.1)
    with pytest.raises(ParameterError, match="friction"):
        FitOptions(friction=float("nan"))


def test_cli_study_and_fit_share_the_friction_defaults():
    import typer.testing  # noqa: F401  (the CLI module needs typer)
    from headsim.cli import mask_cmd
    from headsim.mask.study import StudyOptions

    assert mask_cmd.SKIN_SILICONE_FRICTION == SKIN_SILICONE_FRICTION
    assert mask_cmd.FRICTION.default == FitOptions().friction == StudyOptions().friction
    assert mask_cmd._options(1, 8.0, 980.0, 4.3, "auto", 0.7).friction == 0.7


def test_cli_refuses_friction_in_the_condensed_mode(tmp_path, capsys):
    from headsim.cli import main

    out = tmp_path / "fit"
    with pytest.raises(SystemExit) as e:
        main(["mask", "fit", "--mode", "condensed", "--friction", "0.5", "--out", str(out)])
    assert e.value.code == 2 and "nonlinear mode only" in capsys.readouterr().err
    assert not out.exists()
