"""Fibres and strands built from the property database."""

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.hair import properties as P
from headsim.hair.fibres import (
    fibre_model,
    helix_axis,
    helix_curvature,
    interpolate_strand,
    make_strand,
    sinusoidal_curvature,
    to_polylines,
)
from headsim.solvers.rods import initial_state


def test_fibre_stiffness_from_database():
    sec = P.cross_section("african")
    mod = P.moduli(0.8)
    m = fibre_model(0.2, 20, section=sec, moduli=mod, n_fibres=3)
    np.testing.assert_allclose(m.stiffness[0], [mod.bend * sec.I1, mod.bend * sec.I2, mod.torsion * sec.polar])
    assert m.rho_area[2] == pytest.approx(1300 * sec.area)
    assert m.n_fibres == 3
    with pytest.raises(ParameterError):
        fibre_model(25.0, 20)  # cm passed as m


def test_helix_curvature_generates_the_helix():
    R, pitch = 0.01, 0.02
    kap = helix_curvature(R, pitch)
    L = 2 * np.pi * np.hypot(R, pitch / (2 * np.pi))  # one turn
    m = fibre_model(L, 200, natural_curvature=kap)
    st = initial_state(m)
    axis = helix_axis(m.root_frame[0], kap)
    rise = (st.positions[0, -1] - st.positions[0, 0]) @ axis
    assert abs(rise) == pytest.approx(pitch, rel=1e-6)
    # every point is at distance R from the axis through the helix centre
    c = st.positions[0, 0] - R * m.root_frame[0][:, 1]
    d = st.positions[0] - c
    radial = d - np.outer(d @ axis, axis)
    np.testing.assert_allclose(np.linalg.norm(radial, axis=1), R, rtol=1e-6)


def test_strand_fibres_ride_on_the_guide_frame():
    m = fibre_model(0.1, 30, natural_curvature=sinusoidal_curvature(30, 0.1, 50.0, 0.04))
    st = initial_state(m)
    strand = make_strand(50, 1e-3, m.n_nodes, winding=10.0)
    pos = interpolate_strand(strand, st.positions[0], st.frames[0], m.arc_length[0])
    assert pos.shape == (50, 31, 3)
    off = pos - st.positions[0][None]
    # offsets stay in the guide's normal plane and within the strand radius
    assert np.abs(np.einsum("mnc,nc->mn", off, st.frames[0][:, :, 2])).max() < 1e-12
    assert np.linalg.norm(off, axis=2).max() <= 1e-3 + 1e-12
    pts, offs = to_polylines(st.positions)
    assert pts.shape == (31, 3) and list(offs) == [0, 31]
