"""Thin-film (Reynolds lubrication) flow on triangle meshes against analytic solutions.

Analytic references (plane Poiseuille flow, flux per unit width q = -h^3 / (12 mu) dp/dx):
parallel plates Q = W h^3 dp / (12 mu L); a gap varying along the channel
Q = W dp / (12 mu int_0^L dx / h^3); radial flow in an annulus Q = pi h^3 dp / (6 mu ln(r_o / r_i)).
"""

from __future__ import annotations

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.solvers.thin_film import (
    AIR_VISCOSITY,
    W_FLOOR,
    constrictions,
    orifice_flow,
    solve_thin_film,
)

MU = AIR_VISCOSITY
DP = 980.665  # Pa (10 cmH2O)


def strip(length: float, width: float, nx: int, ny: int):
    """Structured rectangle [0, L] x [0, W] in z = 0, each cell split along one diagonal."""
    x, y = np.meshgrid(np.linspace(0, length, nx + 1), np.linspace(0, width, ny + 1), indexing="ij")
    v = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    idx = np.arange(v.shape[0]).reshape(nx + 1, ny + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    t = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return v, t, idx[0], idx[-1]


def annulus(r_in: float, r_out: float, n_theta: int):
    """Polar annulus mesh with near-square cells (radii in geometric progression)."""
    n_r = max(2, int(round(np.log(r_out / r_in) * n_theta / (2 * np.pi))))
    r = r_in * (r_out / r_in) ** (np.arange(n_r + 1) / n_r)
    th = 2 * np.pi * np.arange(n_theta) / n_theta
    rr, tt = np.meshgrid(r, th, indexing="ij")
    # stagger alternate rings by half a step: no right angles, fewer obtuse triangles
    tt = tt + (np.arange(n_r + 1)[:, None] % 2) * np.pi / n_theta
    v = np.column_stack([(rr * np.cos(tt)).ravel(), (rr * np.sin(tt)).ravel(), np.zeros(rr.size)])
    idx = np.arange(v.shape[0]).reshape(n_r + 1, n_theta)
    nxt = np.roll(idx, -1, axis=1)
    tris = []
    for k in range(n_r):
        a, b, c, d = idx[k], nxt[k], nxt[k + 1], idx[k + 1]
        if k % 2 == 0:   # ring k not shifted, ring k+1 shifted forward
            tris += [np.column_stack([a, b, d]), np.column_stack([b, c, d])]
        else:
            tris += [np.column_stack([a, c, d]), np.column_stack([a, b, c])]
    return v, np.concatenate(tris), idx[0], idx[-1], idx


def test_parallel_plates_uniform_gap():
    length, width, h = 0.02, 0.005, 50e-6
    v, t, left, right = strip(length, width, 20, 6)
    res = solve_thin_film(v, t, np.full(len(v), h), left, right, DP)
    exact = width * h**3 * DP / (12 * MU * length)
    # the cotangent scheme reproduces a linear pressure exactly on this mesh
    assert res.flow == pytest.approx(exact, rel=1e-9)
    assert res.sink_flow == pytest.approx(res.flow, rel=1e-12)      # mass conservation
    assert np.allclose(res.pressure, DP * (1 - v[:, 0] / length), atol=1e-9 * DP)


def test_linearly_varying_gap_along_channel():
    length, width, h0, h1 = 0.01, 0.004, 20e-6, 120e-6
    v, t, left, right = strip(length, width, 15, 4)
    h = h0 + (h1 - h0) * v[:, 0] / length
    res = solve_thin_film(v, t, h, left, right, DP)
    integral = length * (h0 + h1) / (2 * h0**2 * h1**2)         # int_0^L dx / h^3, h linear
    exact = width * DP / (12 * MU * integral)
    # the edge mean is exact for a linear gap; what is left is the W_FLOOR conductance of the
    # zero-weight diagonals (relative perturbation of order W_FLOOR)
    assert res.flow == pytest.approx(exact, rel=10 * W_FLOOR)
    assert res.sink_flow == pytest.approx(res.flow, rel=1e-12)


def _annulus_error(n_theta: int) -> float:
    r_in, r_out, h = 2e-3, 10e-3, 80e-6
    v, t, inner, outer, _ = annulus(r_in, r_out, n_theta)
    res = solve_thin_film(v, t, np.full(len(v), h), inner, outer, DP)
    assert res.sink_flow == pytest.approx(res.flow, rel=1e-10)
    # the polygon rings have radius r_in, r_out at their vertices: compare with the analytic flow
    exact = np.pi * h**3 * DP / (6 * MU * np.log(r_out / r_in))
    return abs(res.flow - exact) / exact


def test_radial_annulus_converges():
    coarse, fine = _annulus_error(24), _annulus_error(48)
    # measured: 24 sectors 1.28e-2, 48 sectors 3.19e-3, 96 sectors 7.7e-4 (second order); assert it decreases at least at
    # first order in the mesh size (the bound a consistent FV scheme must meet), not a tuned value
    assert fine < coarse
    assert fine <= coarse / 2


def test_closed_ring_blocks_flow_exactly_and_one_open_vertex_leaks():
    v, t, inner, outer, idx = annulus(2e-3, 10e-3, 32)
    h = np.full(len(v), 50e-6)
    ring = idx[idx.shape[0] // 2]
    h[ring] = 0.0
    res = solve_thin_film(v, t, h, inner, outer, DP)
    assert res.flow == 0.0 and res.sink_flow == 0.0
    assert constrictions(res, inner, outer) == []
    h[ring[5]] = 50e-6
    res = solve_thin_film(v, t, h, inner, outer, DP)
    assert res.flow > 0
    assert res.sink_flow == pytest.approx(res.flow, rel=1e-10)
    ch = constrictions(res, inner, outer)
    # the cut fluxes sum to the total flow (conservation across any cut)
    assert sum(c.flow for c in ch) == pytest.approx(res.flow, rel=1e-9)
    assert ring[5] in np.concatenate([c.vertices for c in ch])


def test_constriction_of_a_uniform_strip_is_its_cross_section():
    length, width, h = 0.02, 0.005, 50e-6
    v, t, left, right = strip(length, width, 20, 6)
    res = solve_thin_film(v, t, np.full(len(v), h), left, right, DP)
    (c,) = constrictions(res, left, right)
    # dual widths of the edges across any column of a structured strip sum to the strip width
    assert c.area == pytest.approx(width * h, rel=1e-3)
    assert c.flow == pytest.approx(res.flow, rel=1e-9)
    assert orifice_flow(c.area, DP) == pytest.approx(0.6 * width * h * np.sqrt(2 * DP / 1.2), rel=1e-3)
    # Re = rho q / mu with q the flux per unit width of the analytic solution
    q = h**3 * DP / (12 * MU * length)
    # (the W_FLOOR diagonals perturb the linear pressure at the side walls by O(W_FLOOR))
    assert c.max_reynolds == pytest.approx(1.2 * q / MU, rel=10 * W_FLOOR)


def test_bad_input():
    v, t, left, right = strip(0.01, 0.002, 4, 2)
    h = np.full(len(v), 1e-5)
    bad = h.copy()
    bad[3] = np.nan
    with pytest.raises(ParameterError, match="finite"):
        solve_thin_film(v, t, bad, left, right, DP)
    bad[3] = -1e-6
    with pytest.raises(ParameterError, match=">= 0"):
        solve_thin_film(v, t, bad, left, right, DP)
    with pytest.raises(ParameterError, match="empty"):
        solve_thin_film(v, t, h, [], right, DP)
    with pytest.raises(ParameterError, match="overlap"):
        solve_thin_film(v, t, h, left, np.concatenate([right, left[:1]]), DP)
    with pytest.raises(ParameterError, match="viscosity"):
        solve_thin_film(v, t, h, left, right, DP, viscosity=0.0)
