"""Mask fit (quasi-static FEM contact): force balance, pressures, seal analysis, bad input."""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))  # the shared small problem (import mode is importlib)
from _fit_case import COARSE, coarse_fit, coarse_problem, neutral
from headsim.errors import ConvergenceError, HeadsimError, ParameterError
from headsim.mask import make_mask
from headsim.mask.fit import FitOptions, check_force, fit_mask, prepare_fit, problem_fit
from headsim.mesh.primitives import icosphere


def test_contact_force_balances_the_strap_force_within_one_percent():
    """Equilibrium (Newton's third law on the mask and on the face): the cushion's push on the skin
    along the strap, and the bone's support of the tissue, both equal the strap force."""
    r = coarse_fit(8.0)
    assert r.balance_error < 0.01
    assert r.contact_force == pytest.approx(8.0, rel=0.01)
    assert r.support_force == pytest.approx(8.0, rel=0.01)
    # the pressure field carries the load: sum p A >= the axial component (normals tilt off the axis)
    assert r.summary.normal_force >= 0.99 * r.contact_force


def test_pressure_field_is_consistent():
    p = coarse_problem()
    r = coarse_fit(8.0)
    assert r.pressure.shape == (p.face.n_vertices,)
    assert np.isfinite(r.pressure).all() and (r.pressure >= 0).all()
    outside = np.setdiff1d(np.arange(p.face.n_vertices), p.crop_face_ids)
    assert np.all(r.pressure[outside] == 0)
    s = r.summary
    assert s.contact_area > 0 and s.peak_pressure >= s.mean_pressure > 0
    assert s.area_above_threshold <= s.contact_area
    # contact area = sum of the areas of the vertices that carry pressure
    assert s.contact_area == pytest.approx(float(r.areas[r.pressure > 0].sum()))
    # the face is only pushed in: the deformed skin moved along the approach axis where loaded
    disp = (r.deformed_face.vertices - p.face.vertices) @ p.approach
    loaded = r.pressure > 1e3
    assert np.median(disp[loaded]) > 0
    d = r.as_dict()
    assert d["strap_force_n"] == 8.0 and "seal" in d and d["contact_area_cm2"] == pytest.approx(s.contact_area * 1e4)


def test_more_force_more_contact_and_warm_start():
    """Monotone response: a smaller strap force (warm-started from the larger one) gives less
    contact area, a smaller mask travel, and still balances."""
    p = coarse_problem()
    hi = coarse_fit(8.0)
    lo = problem_fit(p, 4.0, warm_start=hi.state)
    assert lo.balance_error < 0.01
    assert lo.summary.contact_area < hi.summary.contact_area
    assert lo.mask_displacement < hi.mask_displacement
    assert lo.summary.normal_force < hi.summary.normal_force


def test_seal_result_is_reported():
    r = coarse_fit(8.0)
    seal = r.seal
    assert seal.sealed == r.sealed
    if not r.sealed:
        assert seal.leak_paths, "a leaking fit must report where it leaks"
        lp = seal.leak_paths[0]
        assert lp.crossing_point.shape == (3,)
        assert lp.gap_width is not None


@pytest.mark.parametrize("force", [0.0, -3.0, float("nan"), 250.0])
def test_bad_force_is_refused(force):
    with pytest.raises(ParameterError):
        check_force(force)
    with pytest.raises(ParameterError):
        problem_fit(coarse_problem(), force)


def test_not_a_face_is_refused():
    ball = icosphere(0.5, 2)  # a 1 m ball: not a face
    with pytest.raises(HeadsimError):
        fit_mask(ball, make_mask("nasal-M", edge_length=5e-3), 10.0, COARSE)


def test_mask_that_cannot_be_placed_is_refused():
    face, lm = neutral()
    # keep only the nose and the skin right around it: an oronasal mask finds no skin under its rim
    keep = np.flatnonzero(np.linalg.norm(face.vertices - lm.nose_tip, axis=1) < 0.03)
    nose, _ = face.submesh(keep)
    with pytest.raises(ParameterError):
        prepare_fit(nose, make_mask("oronasal-L", edge_length=5e-3), COARSE, landmarks=lm)


def test_inexact_newton_solves_between_contact_updates_reach_the_same_equilibrium(monkeypatch):
    """INEXACT_UPDATES only changes where the Newton solves before the last contact update stop: the
    equilibrium meets the same tolerances, so the skin's contact forces agree to the outer loop's
    tolerance (refreshed planes move less than UPDATE_TOL x F)."""
    from headsim.mask import fit

    p = coarse_problem()
    inexact = coarse_fit(8.0)
    monkeypatch.setattr(fit, "INEXACT_UPDATES", None)
    exact = problem_fit(p, 8.0)
    assert fit.INEXACT_UPDATES is None and inexact.balance_error < 0.01
    moved = np.abs(inexact.pressure * inexact.areas - exact.pressure * exact.areas).sum()
    assert moved <= fit.UPDATE_TOL * 8.0
    assert inexact.mask_displacement == pytest.approx(exact.mask_displacement, rel=fit.UPDATE_TOL)


def test_solve_that_does_not_converge_raises():
    # one contact update only: the active set cannot settle from first contact
    p = replace(coarse_problem(), options=replace(COARSE, max_contact_updates=1))
    with pytest.raises(ConvergenceError, match="did not converge"):
        problem_fit(p, 8.0)


def test_options_are_validated():
    with pytest.raises(ParameterError):
        FitOptions(tissue_poisson=0.5)
    with pytest.raises(ParameterError):
        FitOptions(tissue_layers=0)
    with pytest.raises(ParameterError):
        FitOptions(crop_margin=-1.0)


def test_fit_reports_newton_progress_until_the_residual_meets_the_tolerance():
    calls = []
    fit = problem_fit(coarse_problem(), 8.0, progress=lambda it, g, tol: calls.append((it, g, tol)))
    its = [c[0] for c in calls]
    assert its == sorted(its) and len(calls) >= fit.newton_iterations
    last_it, last_g, last_tol = calls[-1]
    assert last_it == fit.newton_iterations and last_g <= last_tol  # the call that ended the solve


def test_barrier_start_backs_off_past_a_wall_parallel_to_the_approach():
    """A skin wall and a cushion wall, both containing the approach axis (z), 20 um apart and overlapping
    over 2 mm along it: backing the mask off along the approach does not widen their gap until the
    cushion wall has left the skin wall's extent, so the back-off must grow its steps (the fixed
    increments of 0.5 dhat - d stopped after 60 steps, 0.3 mm: face_pop07 x nasal-M at 3 mm edges)."""
    from headsim.mask.fit import barrier_start_offset

    dhat, gap = 5e-5, 2e-5
    skin = np.array([[0.0, -1e-3, 0.0], [0.0, 1e-3, 0.0], [0.0, 0.0, 2e-3]])
    cushion = np.array([[gap, -1e-3, 1e-3], [gap, 1e-3, 1e-3], [gap, 0.0, 3e-3]])
    vertices = np.vstack([skin, cushion])
    triangles = np.array([[0, 1, 2], [3, 4, 5]])
    approach = np.array([0.0, 0.0, -1.0])   # the mask moves towards -z onto the face; backing off is +z
    shift = barrier_start_offset(vertices, triangles, 3, approach, dhat)
    moved = vertices.copy()
    moved[3:] -= shift * approach
    # the cushion wall's lowest point now lies above the skin wall's top, at least dhat / 2 away
    assert moved[3:, 2].min() > skin[:, 2].max()
    lowest = moved[3:][np.argmin(moved[3:, 2])]
    assert np.linalg.norm(lowest - skin[2]) >= 0.5 * dhat
