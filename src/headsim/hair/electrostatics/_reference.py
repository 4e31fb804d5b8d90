"""Slow, obvious references for the tests: pairwise Coulomb forces in NumPy and charge sampling by
``np.interp`` along the polyline arc length."""

from __future__ import annotations

import numpy as np

from headsim.hair.electrostatics.units import K_COULOMB


def coulomb_forces_reference(points, charges) -> np.ndarray:
    """(n, 3) N: F_i = K q_i sum_{j != i} q_j (x_i - x_j)/|x_i - x_j|^3, dense O(n^2) memory."""
    x = np.asarray(points, float)
    q = np.asarray(charges, float)
    d = x[:, None, :] - x[None, :, :]
    r = np.linalg.norm(d, axis=2)
    np.fill_diagonal(r, np.inf)
    return K_COULOMB * q[:, None] * np.einsum("ij,ijk->ik", q[None, :] / r**3, d)


def sample_positions_reference(node_positions, arc_length_per_fibre) -> list[np.ndarray]:
    """Particle positions of every fibre by linear interpolation in the NODE arc length (the rods are
    inextensible, so node f, j sits at s = j L / N). node_positions (F, N+1, 3); arc lengths: a list of
    (n_f,) arrays. Returns a list of (n_f, 3) arrays."""
    out = []
    for r, s in zip(np.asarray(node_positions, float), arc_length_per_fibre):
        seg = np.linalg.norm(np.diff(r, axis=0), axis=1)
        sn = np.concatenate([[0.0], np.cumsum(seg)])
        out.append(np.column_stack([np.interp(s, sn, r[:, c]) for c in range(3)]))
    return out
