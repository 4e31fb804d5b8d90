"""Contact pressure helpers against hand-computed values."""

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.mask import (CAPILLARY_CLOSING_PA, THERAPY_PRESSURE_PA, contact_pressure, summarize_pressure,
                          vertex_contact_pressure)
from headsim.mesh import SurfaceMesh


def test_constants():
    assert CAPILLARY_CLOSING_PA == pytest.approx(4266.3, abs=0.1)     # 32 mmHg
    assert THERAPY_PRESSURE_PA == pytest.approx(980.665)               # 10 cmH2O


def test_pressure_is_the_compressive_normal_component_over_area():
    forces = np.array([[0.0, 0.0, -2.0],      # pushes into the skin (normal +z): 2 N on 1 cm^2
                       [3.0, 0.0, -1.0],      # tangential part ignored
                       [0.0, 0.0, 1.0],       # pulls outwards: no pressure
                       [0.0, 0.0, 0.0]])
    normals = np.array([[0, 0, 1.0]] * 4)
    areas = np.array([1e-4, 2e-4, 1e-4, 0.0])
    np.testing.assert_allclose(contact_pressure(forces, normals, areas), [2e4, 5e3, 0.0, 0.0])


def test_force_on_zero_area_is_refused():
    with pytest.raises(ParameterError, match="zero area"):
        contact_pressure(np.array([[0, 0, -1.0]]), np.array([[0, 0, 1.0]]), np.array([0.0]))


def test_summary_by_hand():
    p = np.array([0.0, 1e3, 5e3, 10e3])
    a = np.array([1e-4, 2e-4, 1e-4, 0.5e-4])          # m^2
    s = summarize_pressure(p, a)                        # threshold 4266 Pa
    assert s.contact_area == pytest.approx(3.5e-4)
    assert s.contact_area_cm2 == pytest.approx(3.5)
    assert s.area_above_threshold_cm2 == pytest.approx(1.5)
    assert s.peak_pressure == 10e3
    force = 1e3 * 2e-4 + 5e3 * 1e-4 + 10e3 * 0.5e-4     # 0.2 + 0.5 + 0.5 = 1.2 N
    assert s.normal_force == pytest.approx(force)
    assert s.mean_pressure == pytest.approx(force / 3.5e-4)
    assert summarize_pressure(p, a, threshold=7e3).area_above_threshold == pytest.approx(0.5e-4)
    d = s.as_dict()
    assert d["peak_pressure_kpa"] == pytest.approx(10.0)


def test_uniform_load_on_a_flat_plate_is_recovered():
    """A 1 N load spread by area on a flat plate gives p = F / A everywhere (barycentric lumping)."""
    n = 6
    x, y = np.meshgrid(np.linspace(0, 0.02, n), np.linspace(0, 0.02, n))
    v = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    tri = []
    for j in range(n - 1):
        for i in range(n - 1):
            a = j * n + i
            tri += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    plate = SurfaceMesh(v, np.array(tri))
    forces = np.zeros((n * n, 3))
    forces[:, 2] = -1.0 * plate.vertex_areas / plate.area
    p = vertex_contact_pressure(plate, forces)
    np.testing.assert_allclose(p, 1.0 / 4e-4)
    s = summarize_pressure(p, plate.vertex_areas)
    assert s.normal_force == pytest.approx(1.0)
    assert s.contact_area == pytest.approx(4e-4)


def test_bad_summary_input():
    with pytest.raises(ParameterError):
        summarize_pressure(np.array([-1.0]), np.array([1.0]))
    with pytest.raises(ParameterError):
        summarize_pressure(np.array([1.0, 2.0]), np.array([1.0]))
    with pytest.raises(ParameterError):
        summarize_pressure(np.array([1.0]), np.array([1.0]), threshold=0.0)
