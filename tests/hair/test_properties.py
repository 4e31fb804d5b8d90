"""Keratin property database (Sobottka ch. 2): values, units, humidity dependence, sections, friction."""

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.hair import properties as P


def test_tabulated_moduli_in_si_with_sources():
    m = P.moduli(0.65)
    assert m.stretch == pytest.approx(3.89e9)
    assert m.bend == pytest.approx(3.79e9)
    assert m.torsion == pytest.approx(0.89e9)
    assert "Robbins" in m.source
    assert P.MASS_DENSITY.value == 1300.0 and "Goldsmith" in P.MASS_DENSITY.source
    assert all(isinstance(s, str) and s for s in P.list_sources())


def test_wet_ratios_of_table_2_9_are_reproduced():
    dry, wet = P.moduli(0.65), P.moduli(1.0)
    assert dry.stretch / wet.stretch == pytest.approx(2.62)
    assert dry.bend / wet.bend == pytest.approx(2.40)
    assert dry.torsion / wet.torsion == pytest.approx(4.10)
    # monotone: drier is stiffer
    rh = np.linspace(0, 1, 21)
    e = [P.moduli(r).stretch for r in rh]
    assert np.all(np.diff(e) < 0)
    # below 65 % RH the Goldsmith & Baden log-slope: E(6 %) / E(53 %) = 11.7 / 8.8
    assert P.moduli(0.06).stretch / P.moduli(0.53).stretch == pytest.approx(11.7 / 8.8)


def test_treatment_torsion_and_bad_input():
    assert P.moduli(treatment="bleached").torsion == pytest.approx(1.05e9)
    with pytest.raises(ParameterError):
        P.moduli(65.0)  # percent instead of a fraction
    with pytest.raises(ParameterError):
        P.moduli(temperature_c=90.0)
    with pytest.raises(ParameterError):
        P.moduli(treatment="dreadlocks")


def test_elliptic_cross_section_moments_match_table_2_7():
    """Tab. 2.7 (Swift 1995): I2/I1 = (d_max/d_min)^2: W. European 2.09, African 2.82."""
    we = P.cross_section("west_european")
    af = P.cross_section("african")
    assert we.I2 / we.I1 == pytest.approx(2.09, abs=0.01)
    assert af.I2 / af.I1 == pytest.approx(2.82, abs=0.01)
    assert we.polar == pytest.approx(we.I1 + we.I2)
    assert we.area == pytest.approx(np.pi * 81.94e-6 * 56.74e-6 / 4)
    c = P.elliptic_cross_section(70e-6)
    assert c.I1 == pytest.approx(np.pi * (35e-6) ** 4 / 4)
    assert P.cross_section("caucasian", relative_humidity=1.0).a == pytest.approx(1.16 * P.cross_section("caucasian").a)
    with pytest.raises(ParameterError):
        P.elliptic_cross_section(70.0)  # micrometres passed as metres


def test_friction_directional():
    w = P.friction("wool/wool", 1)
    a = P.friction("wool/wool", 2)
    assert a.static > w.static and a.kinetic > w.kinetic  # against the scales is larger
    assert P.friction("hair/hair", 1, wet=True).kinetic == pytest.approx(0.34)
    with pytest.raises(ParameterError):
        P.friction("hair/velvet", 1)
