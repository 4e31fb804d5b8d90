"""Marschner far/near-field hair scattering (Sobottka 2008 §6.3–6.4): energy, reciprocity, the seed's
goniophotometric observations, the reference implementation and parameter validation."""

import math

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.hair.render import MarschnerParams, far_field_lobes, goniometric_curve, near_field_lobes, white_furnace
from headsim.hair.render._reference import far_field_reference

WHITE = dict(sigma_a=(0.0, 0.0, 0.0))


def _fresnel_h(eta, h):
    g = np.arcsin(h)
    ct = np.sqrt(1 - (h / eta) ** 2)
    ci = np.cos(g)
    rs = (ci - eta * ct) / (ci + eta * ct)
    rp = (eta * ci - ct) / (eta * ci + ct)
    return 0.5 * (rs**2 + rp**2)


@pytest.mark.parametrize("theta_i_deg", [-60.0, -30.0, 0.0, 30.0, 60.0])
def test_white_furnace_never_exceeds_one(theta_i_deg):
    """σ_a = 0: E_p = ∫ S_p cos θ_r dω_r ≤ 1 per lobe and in total, within 3 MC standard errors."""
    p = MarschnerParams(**WHITE)
    r = white_furnace(p, math.radians(theta_i_deg), n_samples=60_000, seed=1)
    assert np.all(r.stderr[3] < 0.01)  # the bound below is meaningful
    assert np.all(r.energy <= 1.0 + 3 * r.stderr)
    # a non-absorbing fibre loses only the orders p ≥ 3: total ≥ 1 − max F²(1−F) − lobe leakage
    assert np.all(r.energy[3] > 0.9)


def test_white_furnace_lobe_energies_match_attenuation_integrals():
    """At normal incidence the lobe energies equal ½∫A_p dh (A_R = F, A_TT = (1−F)², A_TRT = (1−F)²F)
    of the corrected attenuation (6.7–6.8), up to the spread of θ_d over the lobe (bounded below)."""
    p = MarschnerParams(**WHITE)
    r = white_furnace(p, 0.0, n_samples=60_000, seed=2)
    h = (np.arange(20000) + 0.5) / 20000 * 2 - 1
    f = _fresnel_h(1.55, h)
    expect = [0.5 * np.mean(f) * 2, 0.5 * np.mean((1 - f) ** 2) * 2, 0.5 * np.mean((1 - f) ** 2 * f) * 2]
    for lobe in range(3):
        # θ_d spreads by ~β_p around 0; n'(θ_d) changes F by < 1 % there
        assert abs(r.energy[lobe, 0] - expect[lobe]) < 4 * r.stderr[lobe, 0] + 0.01 * expect[lobe]


def test_absorption_colours_and_reduces_energy():
    r_blond = white_furnace(MarschnerParams.preset("blond"), 0.0, n_samples=20_000, seed=3)
    r_black = white_furnace(MarschnerParams.preset("black"), 0.0, n_samples=20_000, seed=3)
    # R is uncoloured, TT/TRT are red-dominant for melanin (σ_a,R < σ_a,G < σ_a,B)
    assert np.allclose(r_blond.energy[0], r_blond.energy[0, 0])
    assert r_blond.energy[1, 0] > r_blond.energy[1, 1] > r_blond.energy[1, 2]
    # black: the transmitted lobes carry < 5 % of what the surface reflection R carries
    assert np.all(r_black.energy[1:3].sum(axis=0) < 0.05 * r_black.energy[0])
    assert np.all(r_black.energy[3] < r_blond.energy[3])


def test_reciprocity_of_the_plain_marschner_lobes():
    """Without the per-θ_i energy normalisation every lobe (R, TT, TRT, elliptic TRT included) is
    symmetric under ω_i ↔ ω_r: θ_h, |θ_d|, φ_h and |Δφ| are unchanged. The normalised M is not
    reciprocal (Z_p depends on θ_i), which is the price of its energy bound."""
    rng = np.random.default_rng(4)
    ti, tr = rng.uniform(-1.4, 1.4, (2, 500))
    pi_, pr = rng.uniform(-np.pi, np.pi, (2, 500))
    for ecc in (1.0, 0.85):
        p = MarschnerParams(normalise_longitudinal=False, eccentricity=ecc)
        a = far_field_lobes(p, ti, pi_, tr, pr)
        b = far_field_lobes(p, tr, pr, ti, pi_)
        assert np.allclose(a, b, rtol=1e-9, atol=1e-12)
    p = MarschnerParams()
    a = far_field_lobes(p, ti, pi_, tr, pr)
    b = far_field_lobes(p, tr, pr, ti, pi_)
    assert not np.allclose(a, b, rtol=1e-3)


def test_seed_goniophotometry_peak_shifts_at_30_degrees():
    """Seed §6.2 (Stamm 1977 et al.): light at 30° from root to tip; the specular peak is shifted toward
    the root by ≈ 2× the 3° cuticle tilt (to ≈ 24°), the coloured secondary (TRT) peak lies further out.
    θ_i = −30° (light toward the root side), mirror direction θ_r = +30°, Δφ = 0 (incidence plane)."""
    p = MarschnerParams.preset("blond")  # α_R = −3° (seed tilt), β_R = 5°
    th, lobes = goniometric_curve(p, -30.0)
    r_peak = th[np.argmax(lobes[:, 0, 0])]
    trt_peak = th[np.argmax(lobes[:, 2, 0])]
    # seed: peak at ≈ 24° (2|α_R| = 6° toward the root); the model's 1/cos²θ_d and Fresnel(θ_d) factors
    # push the broad Gaussian back by ≈ 1° (25.1° measured) — tolerance ±2° around the published value
    assert 22.0 <= r_peak <= 26.0, r_peak
    # seed: reversing the direction (tip → root) puts the peak at ≈ 36°
    th2, lobes2 = goniometric_curve(p, 30.0)
    assert 34.0 <= -th2[np.argmax(lobes2[:, 0, 0])] <= 38.0
    assert r_peak + 10.0 < trt_peak < r_peak + 25.0  # seed: ≈ 16° further (measured here: 18°)
    # coloured: the red TRT peak clearly exceeds the blue one for blond hair
    trt_max = lobes[:, 2].max(axis=0)
    assert trt_max[0] > 2 * trt_max[2]


def test_black_hair_has_no_secondary_peak():
    """Seed §6.2: the secondary peak is absent for black hair (eumelanin 8): TRT ≤ 10⁻³ of the R peak,
    and the in-plane total has a single maximum."""
    p = MarschnerParams.preset("black")
    th, lobes = goniometric_curve(p, -30.0)
    total = lobes.sum(axis=1).mean(axis=1)
    assert lobes[:, 2].max() < 1e-3 * lobes[:, 0, 0].max()
    interior = (total[1:-1] > total[:-2]) & (total[1:-1] > total[2:])
    assert interior.sum() == 1
    brown = goniometric_curve(MarschnerParams.preset("brown"), -30.0)[1]
    blond = goniometric_curve(MarschnerParams.preset("blond"), -30.0)[1]
    assert blond[:, 2, 0].max() > brown[:, 2, 0].max() > 100 * lobes[:, 2, 0].max()


@pytest.mark.parametrize("kw", [dict(), dict(eccentricity=0.85), dict(caustic=False, normalise_longitudinal=False)])
def test_kernels_match_reference(kw):
    p = MarschnerParams(sigma_a=(0.2, 0.5, 1.1), **kw)
    rng = np.random.default_rng(5)
    for _ in range(8):
        ti, tr = rng.uniform(-1.3, 1.3, 2)
        pi_, pr = rng.uniform(-np.pi, np.pi, 2)
        fast = far_field_lobes(p, ti, pi_, tr, pr)
        ref = far_field_reference(p, ti, pi_, tr, pr)
        assert np.allclose(fast[:2], ref[:2], rtol=2e-3, atol=1e-9)
        assert np.allclose(fast[2], ref[2], rtol=2e-2, atol=1e-6 * max(1.0, ref[2].max()))


def test_caustic_regularisation_preserves_trt_energy():
    """∫ N_TRT dφ equals ½∫A_TRT dh (Bravais n', n'' at θ_d) both for the raw, integrably singular root sum
    and for the clamped + glint form; the regularised lobe has no infinite spike."""
    dphi = np.linspace(-np.pi, np.pi, 40001)[:-1]
    td = 0.3
    ti, tr = np.full_like(dphi, -td), np.full_like(dphi, td)
    eta = 1.55
    n1 = math.sqrt(eta**2 - math.sin(td) ** 2) / math.cos(td)
    n2 = eta**2 * math.cos(td) / math.sqrt(eta**2 - math.sin(td) ** 2)
    h = (np.arange(200000) + 0.5) / 200000 * 2 - 1
    g = np.arcsin(h)
    ct = np.sqrt(1 - (h / n1) ** 2)
    rs = (np.cos(g) - n1 * ct) / (np.cos(g) + n1 * ct)
    rp = (n2 * np.cos(g) - ct) / (n2 * np.cos(g) + ct)
    f = 0.5 * (rs**2 + rp**2)
    energy_n = np.mean((1 - f) ** 2 * f)  # ½∫ dh over (−1, 1)
    peaks = {}
    for caustic, tol in ((True, 0.005), (False, 0.03)):  # raw: grid sum of a 1/√ singularity
        p = MarschnerParams(caustic=caustic, normalise_longitudinal=False, **WHITE)
        m = 0.5 / (math.radians(10.0) * math.sqrt(2 * math.pi)) * math.exp(-0.5 * (math.radians(4.5) / math.radians(10.0)) ** 2)
        s = far_field_lobes(p, ti, 0.0, tr, dphi)[:, 2, 0] * math.cos(td) ** 2 / m
        assert abs(s.mean() * 2 * np.pi - energy_n) < tol * energy_n
        peaks[caustic] = s.max()
    assert peaks[True] < 0.5 * peaks[False]


def test_near_field_averages_to_far_field():
    """½∫ S^NF(h) dh over the fibre width equals the far-field lobe (6.20 → 6.11): lobe energies agree
    exactly, pointwise values agree where N_p is smooth (away from the TRT caustics)."""
    p = MarschnerParams(near_field_width_deg=1.0, caustic=False, **WHITE)
    h = (np.arange(4000) + 0.5) / 4000 * 2 - 1
    ti, tr = -0.2, 0.2
    for lobe, dphis in ((0, (-2.0, -1.0, 0.5, 1.5)), (1, (2.2, 2.8, 3.3, 3.9))):
        for dphi in dphis:
            nf = near_field_lobes(p, h, ti, 0.0, tr, dphi)[:, lobe, 0].mean()
            ff = far_field_lobes(p, ti, 0.0, tr, dphi)[lobe, 0]
            # near field: exact Δφ(p,h); far field: Marschner's cubic fit (TT) → a few per cent
            assert abs(nf - ff) < (0.002 if lobe == 0 else 0.06) * ff + 1e-6


@pytest.mark.parametrize("bad", [dict(eta=0.9), dict(alpha_r_deg=5.0), dict(beta_r_deg=0.0),
                                 dict(sigma_a=(1.0, -1.0, 0.0)), dict(sigma_a=(np.nan, 0, 0)),
                                 dict(eccentricity=1.2), dict(glint_width_deg=90.0)])
def test_invalid_parameters_raise(bad):
    with pytest.raises(ParameterError):
        MarschnerParams(**bad)


def test_presets_and_unknown_preset():
    for name in ("blond", "brown", "black", "red"):
        p = MarschnerParams.preset(name)
        assert all(s >= 0 for s in p.sigma_a)
    assert MarschnerParams.preset("black").sigma_a[0] > MarschnerParams.preset("blond").sigma_a[0]
    with pytest.raises(ParameterError):
        MarschnerParams.preset("green")


def test_goniometric_figure_writes_png(tmp_path):
    from headsim.hair.render.figures import goniometric_figure

    peaks = goniometric_figure(tmp_path / "gonio.png", presets=("blond", "black"))
    assert (tmp_path / "gonio.png").stat().st_size > 1000
    assert peaks["blond"][1] > peaks["blond"][0]  # TRT beyond R
