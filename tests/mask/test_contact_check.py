"""Geometric consistency of a fitted contact (headsim.mask.contact_check) on the coarse fit problem.

The check itself is tested on constructed states (a skin vertex moved inside / outside the cushion;
a loaded skin vertex far from the cushion in a barrier fit). The lagged planes' consistency is an
expected failure that documents their defect (issue 6; strict: it starts to fail as an unexpected
pass once that contact model is fixed, so the marker must then be removed); the barrier contact
(FitOptions.contact="barrier") must pass the same requirement.
"""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from _fit_case import coarse_barrier_fit, coarse_barrier_problem, coarse_fit, coarse_problem
from headsim.collide import TriangleBVH
from headsim.mask.contact_check import contact_consistency


def _moved(fit, offset_along_normal: float, pressure: float):
    """The fit with its first skin vertex moved to a cushion contact triangle's centroid + offset
    along its outward normal (m), carrying ``pressure`` (Pa) there."""
    p = coarse_problem()
    x = fit.state.positions.copy()
    tri = p.mask_contact[len(p.mask_contact) // 2]
    normal = TriangleBVH(x, tri[None]).triangle_normals(np.array([0]))[0]
    x[p.skin_vertices[0]] = x[tri].mean(axis=0) + offset_along_normal * normal
    pr = fit.pressure.copy()
    pr[p.crop_face_ids[0]] = pressure
    return replace(fit, state=replace(fit.state, positions=x), pressure=pr)


def test_check_counts_inside_and_phantom_vertices():
    p = coarse_problem()
    fit = coarse_fit(8.0)
    base = contact_consistency(p, fit)
    inside = contact_consistency(p, _moved(fit, -0.4e-3, 0.0))
    outside = contact_consistency(p, _moved(fit, 0.9e-3, 5e3))
    v0_inside = TriangleBVH(fit.state.positions, p.mask_surface).contains(fit.state.positions[p.skin_vertices[:1]])[0]
    v0_phantom = (not v0_inside) and fit.pressure[p.crop_face_ids[0]] > 0
    assert inside.n_inside == base.n_inside + (0 if v0_inside else 1)
    assert inside.max_inside_depth >= 0.4e-3 * (1 - 1e-9)
    assert outside.n_phantom == base.n_phantom + (0 if v0_phantom else 1)
    assert outside.max_phantom_gap >= 0.9e-3 * (1 - 1e-9)
    assert not outside.consistent and outside.warning(8.0) is not None


@pytest.mark.xfail(strict=True, reason="issue 6: lagged contact planes (contact='planes', the fast option) are kept "
                   "from first contact while skin slides along the cushion, so pressure sits on skin that no "
                   "longer touches and true interpenetration goes unresisted (mask/contact_check.py); "
                   "contact='barrier' meets it (test_barrier_fit_puts_pressure_where_skin_and_cushion_touch)")
def test_fitted_pressure_sits_where_skin_and_cushion_touch():
    """A consistent penalty contact puts a vertex with pressure p at depth p / kappa inside the
    cushion. Allowed beyond that: the polyhedral facet scale, 0.1 x the median skin edge (0.2 mm on
    this 2 mm skin; the seal is decided by gaps of 0.1-1 mm, module doc of headsim.mask.fit). No
    skin vertex with pressure lies outside the cushion by more than that, none lies deeper inside
    than p / kappa + that. Measured (lagged planes, 15 N): 69 vertices with pressure outside, up to
    1.8 mm, carrying 7.1 of the 15 N; inside up to 0.66 mm. The hysteresis refresh with second
    planes (commit 5f120f5, reverted for its cost and 30 N failures; module doc, "Contact
    consistency") passed it: 45 outside, up to 0.12 mm; inside at most 0.16 mm beyond p / kappa."""
    p = coarse_problem()
    check = contact_consistency(p, coarse_fit(15.0))
    assert check.tolerance == pytest.approx(0.1 * p.skin_edge)
    assert check.max_phantom_gap <= check.tolerance
    assert check.max_excess_depth <= check.tolerance
    assert check.consistent


def test_barrier_fit_puts_pressure_where_skin_and_cushion_touch():
    """The requirement of the strict xfail above, met by the barrier contact: at 15 N no skin vertex
    carries pressure unless a point, edge or triangle of it lies within the tolerance (0.1 x the
    median skin edge) of the cushion, and nothing lies inside the other body (the barrier's energy is
    infinite there). The same fit balances the strap force (FitResult.balance_error)."""
    p = coarse_barrier_problem()
    fit = coarse_barrier_fit(15.0)
    check = contact_consistency(p, fit)
    assert check.n_phantom == 0 and check.max_phantom_gap == 0.0
    assert check.n_inside == 0 and check.max_excess_depth == 0.0
    assert check.n_cushion_in_skin == 0
    assert check.consistent and check.warning(15.0) is None
    assert fit.balance_error < 1e-2
    assert (fit.pressure > 0).sum() > 20  # a real contact patch, not an empty one


def test_barrier_check_flags_load_on_skin_away_from_the_cushion():
    """The primitive-based check can fail: pressure put on the skin vertex farthest from the cushion
    (its whole one-ring is mm away) is a phantom contact."""
    p = coarse_barrier_problem()
    fit = coarse_barrier_fit(15.0)
    x = fit.state.positions
    dist = TriangleBVH(x, p.mask_surface).closest_points(x[p.skin_vertices]).distance
    far = int(np.argmax(dist))
    assert dist[far] > 5 * p.skin_edge
    pr = fit.pressure.copy()
    pr[p.crop_face_ids[far]] = 5e3
    check = contact_consistency(p, replace(fit, pressure=pr))
    assert check.n_phantom == 1 and check.max_phantom_gap == pytest.approx(dist[far])
    assert not check.consistent and check.warning(15.0) is not None


@pytest.mark.parametrize("args, message", [
    (["--contact", "barrier", "--mode", "condensed"], "nonlinear mode only"),
    (["--contact", "ipc"], "--contact must be 'barrier' or 'planes'"),
    (["--contact", "planes", "--mode", "condensed"], "nonlinear mode only"),
])
def test_cli_refuses_impossible_contact_options(tmp_path, capsys, args, message):
    from headsim.cli import main

    out = tmp_path / "fit"
    with pytest.raises(SystemExit) as e:
        main(["mask", "fit", *args, "--out", str(out)])
    assert e.value.code == 2 and message in capsys.readouterr().err
    assert not out.exists()


def test_cli_contact_option_reaches_the_fit_and_study_options():
    from headsim.cli import mask_cmd
    from headsim.mask.fit import FitOptions
    from headsim.mask.study import StudyOptions

    assert FitOptions().contact == StudyOptions().contact == "barrier"
    assert mask_cmd.CONTACT.default == "auto"
    assert mask_cmd._resolve_contact("nonlinear", "auto") == "barrier"
    assert mask_cmd._resolve_contact("nonlinear", "planes") == "planes"
    assert mask_cmd._options(1, 8.0, 980.0, 4.3, "auto", contact="planes").contact == "planes"
    assert mask_cmd.ROTATION.default == "free" and FitOptions().rotate and StudyOptions().rotate
    assert mask_cmd._options(1, 8.0, 980.0, 4.3, "auto", rotation="held").rotate is False


def test_barrier_report_names_the_contact_model_and_its_clean_check(tmp_path):
    import json

    from headsim.mask.report import write_fit_report

    p = coarse_barrier_problem()
    fit = coarse_barrier_fit(15.0)
    write_fit_report(tmp_path, p, fit)
    result = json.loads((tmp_path / "result.json").read_text())
    assert result["contact_check"]["consistent"] is True and result["contact_check"]["n_phantom"] == 0
    assert "IPC barrier" in (tmp_path / "report.html").read_text()


def test_barrier_with_friction_reaches_the_contact_term():
    """``--contact barrier --friction MU``: the barrier contact carries the lagged Coulomb friction
    (its physics is tested on a block in tests/solvers/test_barrier.py) with the fit's stick length and
    the outer loop's force tolerance."""
    from headsim.cli import mask_cmd
    from headsim.mask.fit import FRICTION_SLIP_FRACTION, UPDATE_TOL, _contact_terms

    assert mask_cmd._check_mode("nonlinear", 0.5, "barrier") == "nonlinear"
    p = coarse_barrier_problem()
    p = replace(p, options=replace(p.options, friction=0.5))
    contact, _ = _contact_terms(p, p.model.rest_positions[p.shell_vertices], UPDATE_TOL * 15.0)
    assert contact.mu == 0.5 and contact.eps == pytest.approx(FRICTION_SLIP_FRACTION * p.skin_edge)
    assert contact.tolerance == pytest.approx(UPDATE_TOL * 15.0)


def test_barrier_friction_converges_where_the_plain_lagged_iteration_cycles(monkeypatch, tmp_path):
    """Coarse problem, mu = 0.5, 10 N: the plain lagged friction iteration (take the lagged normal
    forces and tangent planes at the last solution) does not settle within the fit's 30 outer
    updates (with every inner Newton Hessian factorised, fit.LAGGED_NEWTON = False, and the
    tight-inclusion CCD, as when it was found); the relaxed one (BarrierContact
    friction_lag="adaptive", the default) converges, and its fit is an equilibrium: the contact force
    balances the strap force, and the friction forces on the skin stay inside Coulomb's cone of the
    barrier's normal forces in total."""
    from headsim.errors import ConvergenceError
    from headsim.mask.fit import problem_fit
    from headsim.mask.report import write_fit_report
    from headsim.solvers import barrier

    from headsim.mask import fit as fit_module

    made = []
    contact_terms = fit_module._contact_terms

    def recording(*args, **kwargs):
        made.append(contact_terms(*args, **kwargs))
        return made[-1]

    p = coarse_barrier_problem()
    p = replace(p, options=replace(p.options, friction=0.5))
    with monkeypatch.context() as m:
        m.setattr(fit_module, "_contact_terms", recording)
        fit = problem_fit(p, 10.0)
    assert fit.balance_error <= p.options.balance_tolerance
    x = fit.state.positions
    contact = made[-1][0]
    friction = contact.friction_forces(x)[p.skin_vertices]
    normal = contact.vertex_forces(x, np.zeros(0))[p.skin_vertices] - friction
    assert np.linalg.norm(friction.sum(axis=0)) > 0.01 * np.linalg.norm(normal.sum(axis=0))  # friction acts
    assert np.linalg.norm(friction.sum(axis=0)) <= 0.5 * np.linalg.norm(normal.sum(axis=0))
    write_fit_report(tmp_path, p, fit)  # the report names the friction it was computed with
    assert "Coulomb friction mu = 0.5" in (tmp_path / "report.html").read_text()

    plain_init = barrier.BarrierContact.__init__

    def plain(self, *args, **kwargs):
        kwargs["friction_lag"] = "plain"
        kwargs["ccd"] = "tight-inclusion"
        plain_init(self, *args, **kwargs)

    monkeypatch.setattr(barrier.BarrierContact, "__init__", plain)
    # the cycle was found with every Newton Hessian factorised and the inclusion CCD; with the lagged
    # factorisation (fit.LAGGED_NEWTON) or the additive CCD the inner solves take other paths and the
    # plain iteration settles here
    monkeypatch.setattr(fit_module, "LAGGED_NEWTON", False)
    with pytest.raises(ConvergenceError, match="30 updates"):
        problem_fit(p, 10.0)
