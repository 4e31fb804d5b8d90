"""Keratin fibre property database: the tables of Sobottka (2008), ch. 2, with their sources.

Everything is stored in SI units (Pa, kg/m^3, m). The thesis quotes moduli in 10^5 N/cm^2
(= 1 GPa) and diameters in um; ``GPA = 1e9`` and ``UM = 1e-6`` convert at this edge.

Every value is a :class:`Sourced` record (value, unit, conditions, source) so that the provenance
of a simulation parameter is never lost. Lookup functions interpolate the humidity dependence and
build elliptic cross-sections (I1 = pi a b^3 / 4, I2 = pi a^3 b / 4 with a, b the semi-axes).

Limitations (stated, not hidden)
--------------------------------
* Humidity: the thesis gives moduli at 60-65 % RH and the ratios E(65 %)/E(100 %) (Robbins 2002,
  Tab. 2.9). Between 65 % and 100 % RH we interpolate the logarithm of the modulus linearly in RH.
  Below 65 % RH the only numbers are the sound-speed moduli of Goldsmith & Baden 1970 (Tab. 2.5,
  11.7 GPa at 6 % and 8.8 GPa at 53 % RH); we use their log-slope (relative change only) for all
  three moduli. This is a modelling assumption.
* Temperature: the thesis gives E(T) only as a figure (Sakai 2000, Fig. 2.14, kinks at 0 and 75 C);
  no tabulated values for fibres in air. We therefore keep the moduli constant between the two
  transitions, refuse temperatures outside (0, 75) C, and apply the thermal expansion
  5.18e-4 /K (Tao & Postle 1989b) to the geometry.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.errors import ParameterError

__all__ = [
    "Sourced",
    "GPA",
    "UM",
    "MASS_DENSITY",
    "POISSON_RATIO",
    "THERMAL_EXPANSION",
    "MODULI_ROBBINS",
    "WET_RATIO",
    "SOUND_SPEED_MODULI",
    "TORSION_BY_TREATMENT",
    "CROSS_SECTIONS",
    "FRICTION",
    "Moduli",
    "CrossSection",
    "FrictionCoefficients",
    "moduli",
    "cross_section",
    "elliptic_cross_section",
    "friction",
    "list_sources",
]

GPA = 1e9  # 10^5 N/cm^2
UM = 1e-6


@dataclass(frozen=True)
class Sourced:
    """A tabulated value with its unit (SI), measuring conditions and literature source."""

    value: float
    unit: str
    conditions: str
    source: str


MASS_DENSITY = Sourced(1300.0, "kg/m^3", "dry fibre", "Goldsmith & Baden 1970 (Sobottka 2008, §2.1)")
POISSON_RATIO = Sourced(0.49, "1", "'realistic' for hair; wool 0.35-0.5", "Curiskis / Feughelman 1959 (Sobottka §2.2)")
THERMAL_EXPANSION = Sourced(5.18e-4, "1/K", "keratin composite", "Tao & Postle 1989b (Sobottka §2.2)")

#: Robbins 2002, Tab. 2.9 (Sobottka Tab. 2.9): stretching, bending and torsion modulus at 60-65 % RH
MODULI_ROBBINS = {
    "stretch": Sourced(3.89 * GPA, "Pa", "60-65 % RH", "Robbins 2002, Tab. 2.9"),
    "bend": Sourced(3.79 * GPA, "Pa", "60-65 % RH, 75 F, 12 fibres", "Scott & Robbins / Robbins 2002, Tab. 2.8-2.9"),
    "torsion": Sourced(0.89 * GPA, "Pa", "60-65 % RH", "Robbins 2002, Tab. 2.9"),
}
#: ratio modulus(65 % RH) / modulus(100 % RH), Robbins 2002 Tab. 2.9
WET_RATIO = {
    "stretch": Sourced(2.62, "1", "65 % vs 100 % RH", "Robbins 2002, Tab. 2.9"),
    "bend": Sourced(2.40, "1", "65 % vs 100 % RH", "Robbins 2002, Tab. 2.9"),
    "torsion": Sourced(4.10, "1", "65 % vs 100 % RH", "Robbins 2002, Tab. 2.9"),
}
#: dynamic moduli from the sound speed, Goldsmith & Baden 1970, Tab. 2.5 (23 C)
SOUND_SPEED_MODULI = {
    0.06: Sourced(11.7 * GPA, "Pa", "6 % RH, 23 C, v_s = 3.0 km/s", "Goldsmith & Baden 1970, Tab. 2.5"),
    0.53: Sourced(8.8 * GPA, "Pa", "53 % RH, 23 C, v_s = 2.6 km/s", "Goldsmith & Baden 1970, Tab. 2.5"),
}
#: torsion modulus (Pa) at 65 % RH and log. decrement by cosmetic treatment, Sobottka Tab. 2.10
TORSION_BY_TREATMENT = {
    "untreated": (Sourced(1.02 * GPA, "Pa", "65 % RH", "Tab. 2.10"), 0.40),
    "bleached": (Sourced(1.05 * GPA, "Pa", "65 % RH", "Tab. 2.10"), 0.44),
    "dyed_blond": (Sourced(1.07 * GPA, "Pa", "65 % RH", "Tab. 2.10"), 0.42),
    "dyed_black": (Sourced(1.08 * GPA, "Pa", "65 % RH", "Tab. 2.10"), 0.45),
    "permed": (Sourced(1.01 * GPA, "Pa", "65 % RH", "Tab. 2.10"), 0.56),
    "relaxed": (Sourced(0.91 * GPA, "Pa", "65 % RH", "Tab. 2.10"), 0.65),
}
#: major / minor diameter (m) by population, Swift 1995 / Robbins 2002 (Sobottka Tab. 2.2)
CROSS_SECTIONS = {
    "west_european": (81.94 * UM, 56.74 * UM),
    "chinese": (94.28 * UM, 76.79 * UM),
    "indian": (92.94 * UM, 66.49 * UM),
    "african": (98.23 * UM, 58.52 * UM),
    "caucasian": (63.93 * UM, 47.28 * UM),
    "mongolian": (79.53 * UM, 61.96 * UM),
    "ethiopian": (90.62 * UM, 51.70 * UM),
}
CROSS_SECTION_SOURCE = "Swift 1995; Robbins 2002 (Sobottka Tab. 2.2)"

#: friction coefficients (mu_static_dry, mu_static_wet, mu_kinetic_dry, mu_kinetic_wet) by pair and
#: direction code: 1 with the scales, 2 against the scales, 3 parallel fibres. NaN = not given.
#: Sobottka Tab. 2.11 (column placement reconstructed; see the digest).
_nan = float("nan")
FRICTION = {
    ("hair/hair", 1): (_nan, _nan, 0.15, 0.34),
    ("hair/hard_rubber", 2): (_nan, _nan, 0.19, 0.38),
    ("hair/hair_shampoo", 1): (_nan, _nan, _nan, 0.425),
    ("hair/hair_shampoo", 2): (_nan, _nan, _nan, 0.546),
    ("hair/hair_conditioner", 1): (_nan, _nan, _nan, 0.293),
    ("hair/hair_conditioner", 2): (_nan, _nan, _nan, 0.475),
    ("hair/nylon", 1): (_nan, _nan, 0.14, 0.22),
    ("hair/aluminium", 1): (_nan, _nan, 0.12, 0.18),
    ("hair/polyethylene", 1): (_nan, _nan, 0.22, 0.29),
    ("hair/glass", 1): (_nan, _nan, _nan, 1.40),
    ("wool/wool", 1): (0.13, _nan, 0.11, _nan),
    ("wool/wool", 2): (0.61, _nan, 0.38, _nan),
    ("wool/wool", 3): (0.21, _nan, 0.15, _nan),
    ("wool/rayon", 1): (0.11, _nan, 0.09, _nan),
    ("wool/rayon", 2): (0.39, _nan, 0.35, _nan),
    ("wool/nylon", 1): (0.26, _nan, 0.21, _nan),
    ("wool/nylon", 2): (0.43, _nan, 0.35, _nan),
}
FRICTION_SOURCE = "Robbins 2002; Morton & Hearle 1997; Schwartz & Knowles 1963 (Sobottka Tab. 2.11)"

_T_LOW_C, _T_HIGH_C, _T_REF_C = 0.0, 75.0, 20.0


@dataclass(frozen=True)
class Moduli:
    """Elastic moduli of a keratin fibre, Pa, at the stated conditions."""

    stretch: float
    bend: float
    torsion: float
    relative_humidity: float
    temperature_c: float
    source: str


def _humidity_factor(kind: str, rh: float) -> float:
    """modulus(rh) / modulus(65 %): log-linear in RH (see the module notes)."""
    if rh >= 0.65:
        return float(np.exp(-np.log(WET_RATIO[kind].value) * (rh - 0.65) / 0.35))
    e_lo, e_hi = SOUND_SPEED_MODULI[0.06].value, SOUND_SPEED_MODULI[0.53].value
    slope = np.log(e_lo / e_hi) / (0.53 - 0.06)  # per unit RH, decreasing with RH
    return float(np.exp(slope * (0.65 - rh)))


def moduli(relative_humidity: float = 0.65, temperature_c: float = 20.0, treatment: str | None = None) -> Moduli:
    """Stretch (Young's), bending and torsion modulus (Pa) at a relative humidity in [0, 1].

    Base values: Robbins 2002 Tab. 2.9 (60-65 % RH); with ``treatment`` the torsion modulus comes
    from Tab. 2.10 instead. Humidity and temperature handling: see the module notes.
    """
    rh = float(relative_humidity)
    if not 0.0 <= rh <= 1.0:
        raise ParameterError(f"relative_humidity must be a fraction in [0, 1], got {rh} (did you pass percent?)")
    T = float(temperature_c)
    if not _T_LOW_C < T < _T_HIGH_C:
        raise ParameterError(f"temperature {T} C is outside the tabulated range ({_T_LOW_C}, {_T_HIGH_C}) C "
                             "(transition kinks of E(T), Sakai 2000)")
    base_t = MODULI_ROBBINS["torsion"].value
    src = "Robbins 2002 Tab. 2.9"
    if treatment is not None:
        if treatment not in TORSION_BY_TREATMENT:
            raise ParameterError(f"unknown treatment {treatment!r}; known: {sorted(TORSION_BY_TREATMENT)}")
        base_t = TORSION_BY_TREATMENT[treatment][0].value
        src += f"; torsion Tab. 2.10 ({treatment})"
    return Moduli(
        stretch=MODULI_ROBBINS["stretch"].value * _humidity_factor("stretch", rh),
        bend=MODULI_ROBBINS["bend"].value * _humidity_factor("bend", rh),
        torsion=base_t * _humidity_factor("torsion", rh),
        relative_humidity=rh,
        temperature_c=T,
        source=src,
    )


@dataclass(frozen=True)
class CrossSection:
    """Elliptic fibre cross-section. a, b semi-axes (m, a >= b); area m^2; I1 about the major axis
    (bending towards the minor axis) = pi a b^3 / 4, I2 = pi a^3 b / 4, polar J = I1 + I2 (m^4)."""

    a: float
    b: float

    def __post_init__(self):
        if not (self.a > 0 and self.b > 0 and np.isfinite(self.a) and np.isfinite(self.b)):
            raise ParameterError(f"semi-axes must be positive, got a={self.a}, b={self.b}")
        if self.a > 1e-3:
            raise ParameterError(f"semi-axis {self.a} m is not a hair (did you pass um?)")

    @property
    def area(self) -> float:
        return float(np.pi * self.a * self.b)

    @property
    def I1(self) -> float:
        return float(np.pi * self.a * self.b**3 / 4)

    @property
    def I2(self) -> float:
        return float(np.pi * self.a**3 * self.b / 4)

    @property
    def polar(self) -> float:
        return self.I1 + self.I2

    @property
    def ellipticity(self) -> float:
        return self.a / self.b


def elliptic_cross_section(major_diameter: float, minor_diameter: float | None = None) -> CrossSection:
    """Cross-section from its diameters (m); circular when ``minor_diameter`` is None."""
    minor = major_diameter if minor_diameter is None else minor_diameter
    if minor > major_diameter:
        raise ParameterError("minor diameter must not exceed the major diameter")
    return CrossSection(0.5 * major_diameter, 0.5 * minor)


def cross_section(population: str = "caucasian", relative_humidity: float = 0.65, temperature_c: float = 20.0) -> CrossSection:
    """Tabulated elliptic cross-section (Tab. 2.2) with humidity swelling (up to 16 % in diameter at
    100 % RH, Kassenbeck 1999; assumed linear from 65 % RH) and thermal expansion."""
    if population not in CROSS_SECTIONS:
        raise ParameterError(f"unknown population {population!r}; known: {sorted(CROSS_SECTIONS)}")
    if not 0.0 <= relative_humidity <= 1.0:
        raise ParameterError("relative_humidity must be a fraction in [0, 1]")
    dmax, dmin = CROSS_SECTIONS[population]
    swell = 1.0 + 0.16 * max(relative_humidity - 0.65, 0.0) / 0.35
    thermal = 1.0 + THERMAL_EXPANSION.value * (temperature_c - _T_REF_C)
    return CrossSection(0.5 * dmax * swell * thermal, 0.5 * dmin * swell * thermal)


@dataclass(frozen=True)
class FrictionCoefficients:
    """Coulomb coefficients (NaN = not tabulated) and source."""

    static: float
    kinetic: float
    source: str


def friction(pair: str = "hair/hair", direction: int = 1, wet: bool = False) -> FrictionCoefficients:
    """Friction coefficients of Tab. 2.11. direction: 1 with the scales, 2 against, 3 parallel."""
    key = (pair, int(direction))
    if key not in FRICTION:
        raise ParameterError(f"no friction data for {key}; known: {sorted(FRICTION)}")
    ms_d, ms_w, mk_d, mk_w = FRICTION[key]
    return FrictionCoefficients(ms_w if wet else ms_d, mk_w if wet else mk_d, FRICTION_SOURCE)


def list_sources() -> list[str]:
    """All distinct literature sources used by this database."""
    out = {MASS_DENSITY.source, POISSON_RATIO.source, THERMAL_EXPANSION.source, CROSS_SECTION_SOURCE, FRICTION_SOURCE}
    for d in (MODULI_ROBBINS, WET_RATIO, SOUND_SPEED_MODULI):
        out.update(v.source for v in d.values())
    return sorted(out)
