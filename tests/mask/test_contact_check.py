"""Geometric consistency of a fitted contact (headsim.mask.contact_check) on the coarse fit problem.

The check itself is tested on constructed states (a skin vertex moved inside / outside the cushion);
the fit's consistency is an expected failure that documents the lagged-plane defect of issue 6
(strict: it starts to fail as an unexpected pass once the contact model is fixed, so the marker
must then be removed).
"""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from _fit_case import coarse_fit, coarse_problem
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


@pytest.mark.xfail(strict=True, reason="issue 6: lagged contact planes are kept from first contact while "
                   "skin slides along the cushion, so pressure sits on skin that no longer touches and "
                   "true interpenetration goes unresisted (mask/contact_check.py)")
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
