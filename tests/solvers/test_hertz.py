"""Hertz contact: rigid sphere on a thick stable-neo-Hookean block, quasi-static Newton (issue 5)."""

import pytest

from headsim.solvers.hertz import hertz_contact_radius, hertz_indentation
from headsim.solvers.materials import Material


@pytest.fixture(scope="module")
def hertz():
    # E = 10 kPa, nu = 0.3, R = 1 cm, force chosen for a = 1 mm (a/R = 0.1: small indentation)
    return hertz_indentation(Material.from_kpa(10.0, 0.3), radius=0.01, contact_radius=0.001)


@pytest.mark.slow
def test_contact_radius_and_indentation_match_hertz(hertz):
    assert hertz.contact_radius_hertz == pytest.approx(0.001, rel=1e-12)
    assert abs(hertz.contact_radius_error) < 0.10
    assert abs(hertz.indentation_error) < 0.10


@pytest.mark.slow
def test_contact_force_balances_applied_force(hertz):
    assert hertz.contact_force == pytest.approx(hertz.force, rel=0.01)
    assert hertz.support_reaction == pytest.approx(hertz.force, rel=0.01)


def test_hertz_formula_units():
    # a = (3 F R / 4 E*)^(1/3) with E in Pa: 1 N on R = 1 m, E* = 0.75 Pa gives a = 1 m
    mat = Material(0.75 * (1 - 0.3**2), 0.3)
    assert hertz_contact_radius(1.0, 1.0, mat) == pytest.approx(1.0)
