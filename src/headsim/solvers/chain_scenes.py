"""Small kinematic-chain scenes of the contact validation (Sobottka 2008 ch. 8, issue 10), shared by the tests and
the benchmarks."""

from __future__ import annotations

import numpy as np

from headsim.solvers.chains import ChainModel, ChainState, chain_model_from_polylines


def crossed_layer_stack(layers: int = 4, per_layer: int = 3, length: float = 3e-3, segments: int = 1,
                        radius: float = 35e-6) -> tuple[ChainModel, ChainState]:
    """Straight unanchored fibres (length m, ``segments`` rigid segments each, capsule radius m) in ``layers``
    layers of ``per_layer`` parallel fibres, the layers crossed at right angles (along x, then z, …) and stacked
    in contact on the plane y = 0 (axis heights r, 3r, 5r, …; fibres of a layer ``length``/``per_layer`` apart,
    centred on the origin). Returns the model and its resting state."""
    polys = []
    for lay in range(layers):
        y = radius + 2 * radius * lay
        for k in range(per_layer):
            off = (k - (per_layer - 1) / 2) * length / per_layer
            a = np.array([-length / 2, y, off]) if lay % 2 == 0 else np.array([off, y, -length / 2])
            b = np.array([length / 2, y, off]) if lay % 2 == 0 else np.array([off, y, length / 2])
            polys.append(np.linspace(a, b, segments + 1))
    nodes = np.concatenate(polys)
    return chain_model_from_polylines(nodes, np.arange(0, len(nodes) + 1, segments + 1), radius=radius,
                                      anchored=False)
