"""A synthetic test hairstyle for the renderer: fibres grown from a spherical scalp cap, drooping
under a gravity-like bending rule and kept outside the head sphere (no mechanics; a stand-in until the
reconstruction of Sobottka ch. 5 is available)."""

from __future__ import annotations

import numpy as np

from headsim.errors import ParameterError
from headsim.hair.render.bvh import FibreAssembly

__all__ = ["synthetic_hairstyle"]


def synthetic_hairstyle(n_fibres: int = 2000, n_segments: int = 25, head_radius: float = 0.1,
                        length: float = 0.22, fibre_radius: float = 40e-6, droop: float = 0.35,
                        cap_angle_deg: float = 105.0, seed: int = 0) -> FibreAssembly:
    """Fibres (nodes in m, y up, face toward +z) rooted on the cap θ < ``cap_angle_deg`` from +y (minus
    a forehead/face window), grown in ``n_segments`` steps of length/n_segments; each step turns the
    direction toward −y by ``droop`` (fraction per step) and projects it out of the head sphere."""
    if n_fibres < 1 or n_segments < 1 or head_radius <= 0 or length <= 0 or fibre_radius <= 0:
        raise ParameterError("synthetic_hairstyle needs positive counts and sizes")
    rng = np.random.default_rng(seed)
    # roots: rejection-sample the cap uniformly by area, leave the face (front, below the hairline) bare
    roots = np.empty((0, 3))
    cmin = np.cos(np.radians(cap_angle_deg))
    while len(roots) < n_fibres:
        m = 2 * n_fibres
        y = rng.uniform(cmin, 1.0, m)
        ph = rng.uniform(0, 2 * np.pi, m)
        s = np.sqrt(1 - y**2)
        p = np.stack([s * np.sin(ph), y, s * np.cos(ph)], axis=1)
        face = (p[:, 2] > 0.35) & (p[:, 1] < 0.55)
        roots = np.concatenate([roots, p[~face]])[:n_fibres]
    normal = roots.copy()
    x = roots * head_radius
    d = normal + np.array([0.0, 0.0, -0.3]) + 0.15 * rng.normal(size=normal.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ds = length / n_segments * rng.uniform(0.85, 1.15, (n_fibres, 1))
    nodes = np.empty((n_fibres, n_segments + 1, 3))
    nodes[:, 0] = x
    g = np.array([0.0, -1.0, 0.0])
    clearance = head_radius * 1.02
    for k in range(n_segments):
        d = d + droop * g + 0.03 * rng.normal(size=d.shape)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        x = x + ds * d
        r = np.linalg.norm(x, axis=1, keepdims=True)
        inside = r[:, 0] < clearance
        if inside.any():
            x[inside] *= clearance / r[inside]
            nrm = x[inside] / np.linalg.norm(x[inside], axis=1, keepdims=True)
            d[inside] -= (d[inside] * nrm).sum(axis=1, keepdims=True) * nrm
            d[inside] /= np.maximum(np.linalg.norm(d[inside], axis=1, keepdims=True), 1e-12)
        nodes[:, k + 1] = x
    offsets = np.arange(n_fibres + 1, dtype=np.int64) * (n_segments + 1)
    return FibreAssembly(nodes.reshape(-1, 3), offsets, fibre_radius)
