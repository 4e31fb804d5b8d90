"""Writhe and self-distance of rod centrelines (headsim.solvers.rods_geometry)."""

import numpy as np

from headsim.solvers.rods_geometry import min_self_distance, segment_distances, writhe


def _gauss_writhe_quadrature(p):
    """Brute-force Gauss double integral by the midpoint rule (independent of the solid-angle formula)."""
    mid = 0.5 * (p[1:] + p[:-1])
    t = np.diff(p, axis=0)
    r = mid[:, None, :] - mid[None, :, :]
    d = np.linalg.norm(r, axis=2)
    np.fill_diagonal(d, np.inf)
    cr = np.cross(t[:, None, :], t[None, :, :])
    return float((cr * r).sum(2).__truediv__(d**3).sum() / (4 * np.pi))


def _trefoil(n):
    u = np.linspace(0, 2 * np.pi, n + 1)
    return np.c_[np.sin(u) + 2 * np.sin(2 * u), np.cos(u) - 2 * np.cos(2 * u), -np.sin(3 * u)]


def test_writhe_matches_the_gauss_integral_and_its_symmetries():
    p = _trefoil(400)
    w = writhe(p)
    w_ref = _gauss_writhe_quadrature(_trefoil(1500))
    print("trefoil writhe (Klenin-Langowski, 400 segments):", w, "midpoint quadrature (1500):", w_ref)
    assert abs(w - w_ref) < 1e-3 * abs(w_ref)
    mirrored = p * np.array([1.0, 1.0, -1.0])
    assert writhe(mirrored) == -w  # chirality
    Q = np.linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))[0]
    Q *= np.sign(np.linalg.det(Q))
    assert abs(writhe(2.5 * p @ Q.T + 1.0) - w) < 1e-10  # rigid motion and scale
    line = np.c_[np.linspace(0, 1, 20), np.zeros(20), np.zeros(20)]
    assert writhe(line, axis=(1, 0, 0)) == 0.0


def test_a_loop_between_axial_tails_has_writhe_one():
    """A loop of a rod whose tails lie on the axis (closed at infinity): |Wr| -> 1 (one crossing seen
    from every direction); a gentle bend has |Wr| << 1."""
    u = np.linspace(0, 2 * np.pi, 300)
    loop = np.c_[np.sin(u) + 0.5 * u, 0.2 * np.sin(u / 2) * (1 - np.cos(u)), 1 - np.cos(u)]
    assert abs(abs(writhe(loop, axis=(1, 0, 0))) - 1.0) < 0.02
    bend = np.c_[u, 0.1 * np.sin(u), 0.3 * (1 - np.cos(u))]
    assert abs(writhe(bend, axis=(1, 0, 0))) < 0.1


def test_segment_distances_match_dense_sampling():
    rng = np.random.default_rng(3)
    p = np.cumsum(rng.normal(size=(30, 3)), axis=0)
    i, j, d, _, _ = segment_distances(p, 2)
    t = np.linspace(0, 1, 401)
    for k in rng.choice(len(i), 25, replace=False):
        a = p[i[k]] + t[:, None] * (p[i[k] + 1] - p[i[k]])
        b = p[j[k]] + t[:, None] * (p[j[k] + 1] - p[j[k]])
        brute = np.linalg.norm(a[:, None] - b[None], axis=2).min()
        assert d[k] <= brute + 1e-12 and brute - d[k] < 1e-2 * np.linalg.norm(p[i[k] + 1] - p[i[k]])
    assert min_self_distance(p, 2) == d.min()
