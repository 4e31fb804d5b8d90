"""Leak-flow estimate of fitted masks (headsim.mask.leak) on the shared coarse fit problem."""

from functools import lru_cache

import numpy as np
import pytest

from _fit_case import coarse_fit, coarse_problem
from headsim.errors import ParameterError
from headsim.mask.condensed import condense_fit, condensed_fit
from headsim.mask.fit import FitOptions
from headsim.mask.leak import M3S_TO_LPM, estimate_leak, leak_aperture
from headsim.mask.seal import analyse_seal


@lru_cache(maxsize=1)
def _condensed():
    return condense_fit(coarse_problem())


def test_leak_is_zero_exactly_when_the_strict_rule_seals():
    """Real fits of the coarse problem (condensed mode: leaks at 20 N, seals at 30 N; measured), each
    judged at three therapy pressures: the leak flow is 0.0 exactly when analyse_seal says sealed,
    and both outcomes occur (so the check can fail either way)."""
    p = coarse_problem()
    outcomes = set()
    for force in (20.0, 30.0):
        fit = condensed_fit(_condensed(), force)
        assert (fit.leak_flow_lpm == 0.0) == fit.sealed
        for tp in (300.0, 980.665, 5000.0):
            seal = analyse_seal(fit.deformed_face, fit.pressure, p.airway, therapy_pressure_pa=tp, max_paths=1)
            leak = estimate_leak(fit.deformed_face, fit.deformed_mask, fit.pressure, p.airway, tp)
            assert (leak.flow_lpm == 0.0) == seal.sealed, (force, tp)
            assert (leak.viscous_lpm == 0.0) == seal.sealed
            assert (len(leak.channels) == 0) == seal.sealed
            outcomes.add(seal.sealed)
    assert outcomes == {True, False}


def test_leak_of_a_nonlinear_fit_conserves_mass_and_respects_both_bounds():
    fit = coarse_fit(8.0)
    leak = fit.leak
    assert not fit.sealed and leak.flow_lpm > 0
    assert leak.mass_balance < 1e-9
    # the channels cut the flow: their viscous flows sum to the total viscous flow (conservation)
    assert sum(c.viscous_lpm for c in leak.channels) == pytest.approx(leak.viscous_lpm, rel=1e-9)
    for c in leak.channels:
        assert c.flow_lpm == min(c.viscous_lpm, c.orifice_lpm)
    assert leak.flow_lpm <= min(leak.viscous_lpm, leak.orifice_lpm) * (1 + 1e-12)
    # more strap force, less leak (15 N against 8 N on the same problem)
    assert coarse_fit(15.0).leak_flow_lpm < leak.flow_lpm
    d = fit.as_dict()
    assert d["leak_flow_lpm"] == leak.flow_lpm and d["leak_threshold_lpm"] == 24.0
    assert d["leak_acceptable"] == (leak.flow_lpm <= 24.0)


def test_aperture_rules():
    p = coarse_problem()
    fit = coarse_fit(8.0)
    tp = p.options.therapy_pressure
    h = leak_aperture(fit.deformed_face, fit.deformed_mask, fit.pressure, tp, skin_roughness=20e-6, gap_cap=2e-3)
    assert np.all(h[fit.pressure > tp] == 0.0)
    touching = (fit.pressure > 0) & (fit.pressure <= tp)
    assert touching.any() and np.all(h[touching] == 20e-6)
    free = fit.pressure == 0
    assert np.all((h[free] >= 20e-6) & (h[free] <= 2e-3))
    # far from the cushion (outside the crop) the cap applies
    far = np.setdiff1d(np.arange(len(h)), p.crop_face_ids)
    assert np.all(h[far] == 2e-3)
    with pytest.raises(ParameterError):
        leak_aperture(fit.deformed_face, fit.deformed_mask, fit.pressure, tp, skin_roughness=3e-3, gap_cap=2e-3)
    with pytest.raises(ParameterError):
        FitOptions(leak_threshold_lpm=0.0)


def test_skin_inside_the_cushion_is_no_open_film():
    """A skin vertex inside the cushion body without contact pressure (interpenetrated material)
    gets the touching aperture, not its depth; the same vertex as far outside keeps its distance.
    Construction: two crop vertices moved 0.5 mm either side of a cushion skin-side triangle's
    centroid along its outward normal, all pressures 0."""
    from headsim.collide import TriangleBVH

    p = coarse_problem()
    fit = coarse_fit(8.0)
    mask = fit.deformed_mask
    mv = mask.tetmesh.vertices
    tri = mask.contact_triangles[len(mask.contact_triangles) // 2]
    centre = mv[tri].mean(axis=0)
    normal = TriangleBVH(mv, tri[None]).triangle_normals(np.array([0]))[0]
    depth = 0.5e-3
    inner, outer = p.crop_face_ids[:2]
    fv = fit.deformed_face.vertices.copy()
    fv[inner] = centre - depth * normal
    fv[outer] = centre + depth * normal
    face = fit.deformed_face.with_vertices(fv)
    assert TriangleBVH(mv, mask.tetmesh.boundary_triangles).contains(fv[[inner, outer]]).tolist() == [True, False]
    h = leak_aperture(face, mask, np.zeros(face.n_vertices), p.options.therapy_pressure,
                      skin_roughness=20e-6, gap_cap=2e-3)
    assert h[inner] == 20e-6
    assert h[outer] == pytest.approx(depth, rel=1e-6)


def test_threshold_only_changes_the_judgement():
    p = coarse_problem()
    fit = coarse_fit(8.0)
    args = (fit.deformed_face, fit.deformed_mask, fit.pressure, p.airway, p.options.therapy_pressure)
    low, high = estimate_leak(*args, threshold_lpm=1e-3), estimate_leak(*args, threshold_lpm=1e4)
    assert low.flow_lpm == high.flow_lpm and not low.acceptable and high.acceptable
    assert M3S_TO_LPM == 60_000.0
