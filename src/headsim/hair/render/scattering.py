"""Marschner far-field hair scattering (corrected as in Sobottka 2008 §6.3) and its near-field variant.

S(ω_i, ω_r) = Σ_{p ∈ R, TT, TRT} M_p(θ_i, θ_r) N_p(n'(θ_d), Δφ) / cos²θ_d          (Sobottka eq. 6.14)

* M_p: Gaussian in θ_h shifted by the cuticle tilt, M_p = ½ g(β_p; θ_h − α_p) (6.13); the ½ makes the
  β → 0 limit equal to (6.3)'s δ(θ_r + θ_i). Optional per-θ_i normalisation Z_p so that the lobe
  conserves energy (``normalise_longitudinal``; Marschner's plain Gaussians are not energy-conserving
  at oblique incidence and exceed 1 by a few per cent, see the furnace tests).
* N_p: root sum (6.11) with the corrected attenuation A(p,h) (6.7–6.8), absorption T (6.9) with
  σ_a/cos θ_t, Bravais indices n', n'' and the generalised Fresnel factor, Marschner's cubic Δφ(p,γ)
  fit for TT/TRT, energy-preserving TRT caustic regularisation (total ray density clamped, the removed
  energy returned as glints at ±φ_c; continuous where the caustics merge at n' = 2) and the elliptic
  n*(φ_h) for TRT (6.12).
* Near field (6.20): the same lobes for a given exit offset h across the fibre width, Δφ(p,h) exact,
  the azimuthal δ a Gaussian; its average over h equals the far-field lobe.

Angles: θ is the inclination from the fibre's normal plane (positive toward the tip, i.e. along the
root→tip tangent d₃), φ the azimuth around the fibre. Radiometry: S is the curve BSDF, so a fibre lit
by a directional light of irradiance E has (width-averaged) radiance L_r = S E cos θ_i and the energy
scattered per unit incident power is ∫ S cos θ_r dω_r (the white-furnace integral).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from headsim.errors import ParameterError
from headsim.hair.render import _kernels_scattering as _k

__all__ = [
    "EUMELANIN_SIGMA_A",
    "PHEOMELANIN_SIGMA_A",
    "PRESETS",
    "MarschnerParams",
    "FurnaceResult",
    "sigma_a_from_melanin",
    "far_field_lobes",
    "near_field_lobes",
    "scattering",
    "white_furnace",
    "goniometric_curve",
]

# Absorption per unit melanin concentration, per fibre *radius* (d'Eon et al. 2011, Chiang et al. 2016;
# also pbrt-v3's SigmaAFromConcentration and Mitsuba 3's ``hair`` BSDF).
EUMELANIN_SIGMA_A = (0.419, 0.697, 1.37)
PHEOMELANIN_SIGMA_A = (0.187, 0.4, 1.05)

# (eumelanin, pheomelanin) concentrations of the colour presets; 0.3 / 1.3 / 8 are the values pbrt-v3 and
# Chiang et al. (2016) quote for blond / brown / black hair.
PRESETS: dict[str, tuple[float, float]] = {
    "blond": (0.3, 0.0),
    "brown": (1.3, 0.0),
    "black": (8.0, 0.0),
    "red": (0.3, 1.8),
}

_NZ = 181  # θ_i grid of the normalisation tables


def sigma_a_from_melanin(eumelanin: float, pheomelanin: float = 0.0) -> tuple[float, float, float]:
    """RGB absorption coefficient per fibre radius from melanin concentrations (dimensionless)."""
    if not (np.isfinite(eumelanin) and np.isfinite(pheomelanin)) or eumelanin < 0 or pheomelanin < 0:
        raise ParameterError(f"melanin concentrations must be finite and ≥ 0, got {eumelanin}, {pheomelanin}")
    return tuple(float(eumelanin * e + pheomelanin * p) for e, p in zip(EUMELANIN_SIGMA_A, PHEOMELANIN_SIGMA_A))


@dataclass(frozen=True, eq=False)
class MarschnerParams:
    """Parameters of the Marschner far-field model (angles in degrees; validated on construction).

    eta : refractive index of keratin, seed §6.2: 1.55.
    alpha_r_deg : R-lobe shift α_R (negative: toward the root). Seed: cuticle tilt ≈ 3° → −3°; Marschner
        2003 Tab. 1: −10° … −5°; Zinke: −7° … −3°. α_TT = −α_R/2, α_TRT = −3α_R/2 unless given.
    beta_r_deg : R-lobe width β_R, Marschner 5°–10°; β_TT = β_R/2, β_TRT = 2β_R unless given.
    sigma_a : RGB absorption per fibre radius (Marschner: 0.2 … ∞); see :func:`sigma_a_from_melanin`.
    eccentricity : axis ratio a of the elliptic cross-section for TRT (6.12), Marschner 0.85–1.
    glint_width_deg : w_c of the TRT caustic glint, Marschner 10°–25°.
    dh_max : Δh_M, Marschner 0.5; the total TRT ray density Σ|dΔφ/dh|⁻¹ is clamped at D_max = Δh_M / w_c
        and the removed energy returns as Gaussian glints of width w_c at ±φ_c (energy-preserving).
    caustic : regularise the TRT caustic (clamp + energy-preserving glint); False keeps the raw root sum.
    near_field_width_deg : width of the azimuthal Gaussian replacing δ in the near field (6.20).
    normalise_longitudinal : scale each M_p by 1/Z_p(θ_i) so that the lobe never creates energy.
    """

    eta: float = 1.55
    alpha_r_deg: float = -3.0
    beta_r_deg: float = 5.0
    sigma_a: tuple[float, float, float] = field(default=sigma_a_from_melanin(*PRESETS["brown"]))
    eccentricity: float = 1.0
    glint_width_deg: float = 15.0
    dh_max: float = 0.5
    caustic: bool = True
    near_field_width_deg: float = 5.0
    normalise_longitudinal: bool = True
    alpha_tt_deg: float | None = None
    alpha_trt_deg: float | None = None
    beta_tt_deg: float | None = None
    beta_trt_deg: float | None = None

    def __post_init__(self):
        sig = np.asarray(self.sigma_a, dtype=np.float64).reshape(-1)
        if sig.shape == (1,):
            sig = np.repeat(sig, 3)
        if sig.shape != (3,) or not np.all(np.isfinite(sig)) or np.any(sig < 0):
            raise ParameterError(f"sigma_a must be 3 finite values ≥ 0 (RGB, per radius), got {self.sigma_a}")
        object.__setattr__(self, "sigma_a", tuple(float(s) for s in sig))
        checks = [
            ("eta", self.eta, 1.2, 2.2),
            ("alpha_r_deg", self.alpha_r_deg, -15.0, 0.0),
            ("beta_r_deg", self.beta_r_deg, 1.0, 25.0),
            ("eccentricity", self.eccentricity, 0.5, 1.0),
            ("glint_width_deg", self.glint_width_deg, 2.0, 45.0),
            ("dh_max", self.dh_max, 1e-3, 1.0),
            ("near_field_width_deg", self.near_field_width_deg, 0.2, 45.0),
        ]
        for name, v, lo, hi in checks:
            if not (isinstance(v, (int, float)) and math.isfinite(v) and lo <= v <= hi):
                raise ParameterError(f"MarschnerParams.{name} must lie in [{lo}, {hi}], got {v!r}")
        for name in ("alpha_tt_deg", "alpha_trt_deg"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and abs(v) <= 25.0):
                raise ParameterError(f"MarschnerParams.{name} must be within ±25°, got {v!r}")
        for name in ("beta_tt_deg", "beta_trt_deg"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and 0.5 <= v <= 45.0):
                raise ParameterError(f"MarschnerParams.{name} must lie in [0.5, 45], got {v!r}")

    # -- constructors -----------------------------------------------------------------------------
    @classmethod
    def from_melanin(cls, eumelanin: float, pheomelanin: float = 0.0, **kw) -> "MarschnerParams":
        return cls(sigma_a=sigma_a_from_melanin(eumelanin, pheomelanin), **kw)

    @classmethod
    def preset(cls, name: str, **kw) -> "MarschnerParams":
        """``blond``, ``brown``, ``black`` or ``red`` (melanin concentrations in :data:`PRESETS`)."""
        if name not in PRESETS:
            raise ParameterError(f"unknown hair colour preset {name!r}; choose one of {sorted(PRESETS)}")
        return cls.from_melanin(*PRESETS[name], **kw)

    # -- derived ----------------------------------------------------------------------------------
    @property
    def alphas_deg(self) -> tuple[float, float, float]:
        a = self.alpha_r_deg
        tt = -a / 2 if self.alpha_tt_deg is None else self.alpha_tt_deg
        trt = -3 * a / 2 if self.alpha_trt_deg is None else self.alpha_trt_deg
        return (a, tt, trt)

    @property
    def betas_deg(self) -> tuple[float, float, float]:
        b = self.beta_r_deg
        tt = b / 2 if self.beta_tt_deg is None else self.beta_tt_deg
        trt = 2 * b if self.beta_trt_deg is None else self.beta_trt_deg
        return (b, tt, trt)

    @cached_property
    def packed(self) -> np.ndarray:
        """(15,) float64 parameter vector of the kernels (radians)."""
        r = np.deg2rad
        v = np.zeros(_k.N_PRM)
        v[0] = self.eta
        v[1:4] = r(self.alphas_deg)
        v[4:7] = r(self.betas_deg)
        v[7:10] = self.sigma_a
        v[10] = self.eccentricity
        v[11] = r(self.glint_width_deg)
        v[12] = self.dh_max
        v[13] = r(self.near_field_width_deg)
        v[14] = 1.0 if self.caustic else 0.0
        v.flags.writeable = False
        return v

    @cached_property
    def ztab(self) -> np.ndarray:
        """(3, 181) float64 lobe normalisation Z_p(θ_i) = ∫ ½g(β_p; θ_h−α_p) cos²θ_r / cos²θ_d dθ_r."""
        z = np.ones((3, _NZ))
        if self.normalise_longitudinal:
            th_i = np.linspace(-np.pi / 2, np.pi / 2, _NZ)[:, None]
            n_q = 6001
            th_r = (np.arange(n_q) + 0.5) * (np.pi / n_q) - np.pi / 2
            th_r = th_r[None, :]
            th_h = 0.5 * (th_i + th_r)
            th_d = 0.5 * (th_r - th_i)
            w = np.cos(th_r) ** 2 / np.maximum(np.cos(th_d) ** 2, 1e-12) * (np.pi / n_q)
            p = self.packed
            for lobe in range(3):
                beta, alpha = p[4 + lobe], p[1 + lobe]
                g = np.exp(-0.5 * ((th_h - alpha) / beta) ** 2) / (beta * np.sqrt(2 * np.pi))
                z[lobe] = (0.5 * g * w).sum(axis=1)
        z.flags.writeable = False
        return z

    @cached_property
    def gtab(self) -> np.ndarray:
        """(91, 1 or 17, 4) float64 TRT caustic table: energy removed by the clamp (RGB) and φ_c, over
        |θ_d| × cos(φ_i + φ_r) (the second axis only for elliptic fibres)."""
        nc = 1 if self.eccentricity == 1.0 else 17
        g = np.zeros((91, nc, 4))
        _k.glint_table(self.packed, 91, nc, 2000, g)
        g.flags.writeable = False
        return g

    @cached_property
    def lobe_weights(self) -> np.ndarray:
        """(3,) float64: each lobe's azimuthal energy ½∫A_p T_p dh at θ_d = 0, mean over RGB (for sampling)."""
        h = (np.arange(400) + 0.5) / 400 * 2 - 1
        n1 = self.eta
        g = np.arcsin(h)
        gt = np.arcsin(h / n1)
        ct, ci = np.cos(gt), np.cos(g)
        rs = (ci - n1 * ct) / (ci + n1 * ct)
        rp = (n1 * ci - ct) / (n1 * ci + ct)
        f = 0.5 * (rs**2 + rp**2)
        sig = np.asarray(self.sigma_a)[:, None]
        out = np.empty(3)
        out[0] = 0.5 * np.mean(f) * 2
        for p in (1, 2):
            a = (1 - f) ** 2 * f ** (p - 1)
            out[p] = np.mean(0.5 * a * np.exp(-p * sig * 2 * ct) * 2)
        return out


def _broadcast(*arrays):
    arrs = np.broadcast_arrays(*[np.asarray(a, dtype=np.float64) for a in arrays])
    shape = arrs[0].shape
    flat = [np.ascontiguousarray(a.reshape(-1)) for a in arrs]
    for a in flat:
        if not np.all(np.isfinite(a)):
            raise ParameterError("scattering angles must be finite")
    return shape, flat


def far_field_lobes(params: MarschnerParams, theta_i, phi_i, theta_r, phi_r) -> np.ndarray:
    """Far-field lobes S_p (Sobottka eq. 6.14 term by term).

    Angles (broadcastable arrays, rad); returns (..., 3 lobes R/TT/TRT, 3 RGB) float64, 1/sr.
    """
    shape, (ti, pi_, tr, pr) = _broadcast(theta_i, phi_i, theta_r, phi_r)
    out = np.empty((ti.size, 3, 3))
    _k.far_field_batch(params.packed, params.ztab, params.gtab, ti, pi_, tr, pr, out)
    return out.reshape(shape + (3, 3))


def near_field_lobes(params: MarschnerParams, h, theta_i, phi_i, theta_r, phi_r) -> np.ndarray:
    """Near-field lobes (Sobottka eq. 6.20) at exit offset ``h`` ∈ (−1, 1) across the fibre width.

    Returns (..., 3, 3) like :func:`far_field_lobes`; ½∫ over h of it is the far-field lobe."""
    shape, (hh, ti, pi_, tr, pr) = _broadcast(h, theta_i, phi_i, theta_r, phi_r)
    if np.any(np.abs(hh) > 1):
        raise ParameterError("near-field offset h must lie in [−1, 1]")
    out = np.empty((ti.size, 3, 3))
    _k.near_field_batch(params.packed, params.ztab, hh, ti, pi_, tr, pr, out)
    return out.reshape(shape + (3, 3))


def scattering(params: MarschnerParams, theta_i, phi_i, theta_r, phi_r) -> np.ndarray:
    """Total far-field S (sum of the lobes), (..., 3) RGB, 1/sr."""
    return far_field_lobes(params, theta_i, phi_i, theta_r, phi_r).sum(axis=-2)


@dataclass(frozen=True)
class FurnaceResult:
    """White-furnace integral E_p = ∫ S_p cos θ_r dω_r per lobe and total, with Monte-Carlo standard errors.

    energy, stderr : (4, 3) float64 — rows R, TT, TRT, total; columns RGB."""

    theta_i: float
    n_samples: int
    energy: np.ndarray
    stderr: np.ndarray


def white_furnace(params: MarschnerParams, theta_i: float, n_samples: int = 200_000, seed: int = 0,
                  phi_i: float = 0.0) -> FurnaceResult:
    """Monte-Carlo estimate of ∫_{S²} S(ω_i, ω_r) cos θ_r dω_r (energy leaving per unit incident power).

    Importance sampling: θ_r from a defensive mixture (10 % uniform on (−π/2, π/2), 25/45/20 % truncated
    Gaussians of the R/TT/TRT lobes centred at 2α_p − θ_i with width 2β_p), φ_r uniform; with dω = cos θ dθ dφ the
    estimator is S cos²θ_r · 2π / p(θ_r). Returns means and standard errors (σ/√n)."""
    if n_samples < 1000:
        raise ParameterError("white_furnace needs at least 1000 samples")
    rng = np.random.default_rng(seed)
    p = params.packed
    centres = 2 * p[1:4] - theta_i
    widths = 2 * p[4:7]
    n = int(n_samples)
    mix = np.array([0.1, 0.25, 0.45, 0.2])  # uniform, R, TT, TRT
    comp = rng.choice(4, size=n, p=mix)
    th = np.empty(n)
    uni = comp == 0
    th[uni] = rng.uniform(-np.pi / 2, np.pi / 2, uni.sum())
    for lobe in range(3):
        sel = comp == lobe + 1
        k = int(sel.sum())
        x = np.empty(0)
        while len(x) < k:  # truncated normal by rejection
            y = rng.normal(centres[lobe], widths[lobe], size=2 * k + 64)
            x = np.concatenate([x, y[np.abs(y) < np.pi / 2]])
        th[sel] = x[:k]
    from scipy.special import ndtr

    pdf = np.full(n, mix[0] / np.pi)
    for lobe in range(3):
        c, w = centres[lobe], widths[lobe]
        mass = ndtr((np.pi / 2 - c) / w) - ndtr((-np.pi / 2 - c) / w)
        pdf += mix[lobe + 1] * np.exp(-0.5 * ((th - c) / w) ** 2) / (w * np.sqrt(2 * np.pi)) / mass
    ph = rng.uniform(-np.pi, np.pi, n)
    s = far_field_lobes(params, np.full(n, theta_i), np.full(n, phi_i), th, ph)
    f = s * (np.cos(th) ** 2 * 2 * np.pi / pdf)[:, None, None]
    f = np.concatenate([f, f.sum(axis=1, keepdims=True)], axis=1)
    return FurnaceResult(theta_i=float(theta_i), n_samples=n, energy=f.mean(axis=0),
                         stderr=f.std(axis=0, ddof=1) / np.sqrt(n))


def goniometric_curve(params: MarschnerParams, theta_i_deg: float = -30.0, theta_r_deg=None,
                      dphi: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """In-plane goniophotometer curve (seed §6.2): S_p(θ_r) at fixed θ_i and Δφ (0: incidence plane).

    Returns (θ_r in degrees (m,), lobes (m, 3, 3))."""
    if theta_r_deg is None:
        theta_r_deg = np.linspace(-89.5, 89.5, 3581)
    tr = np.deg2rad(np.asarray(theta_r_deg, dtype=np.float64))
    lobes = far_field_lobes(params, np.deg2rad(theta_i_deg), 0.0, tr, dphi)
    return np.asarray(theta_r_deg, dtype=np.float64), lobes
