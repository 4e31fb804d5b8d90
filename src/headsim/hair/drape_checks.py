"""The seed's statements about its horizontal ribbon (Sobottka 2008 §8.6.1, Fig. 8.8), measured on a recorded
``sphere-horizontal`` run (:func:`headsim.hair.drape.run_drape`). SI units: m, s.

The seed: "Die Berechnung der Reibung verhindert ein Abrutschen der Fasern von der Kugeloberfläche" (with
friction the fibres stay on the sphere); without friction the arrangement splits into two portions of
different size that fall down to the right and the left of the sphere (Fig. 8.8).

Every measure here is taken at each fibre's middle node (node n/2 of n segments: over the top of the sphere,
which is centred under the ribbon's midline z = 0) or, for the contact, on the axes of the two segments that meet
there. Used by ``tests/hair/test_drape.py`` (reduced ribbon) and ``benchmarks/bench_drape_ribbon.py`` (the seed's
500 × 40), so both judge by the same numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# axis samples per segment of the contact measure (a 7.5 mm chord of a 6 cm sphere lifts its ends by 117 µm off the
# surface, so the contact is measured between the nodes, not at them)
AXIS_SAMPLES = 41


@dataclass(frozen=True)
class RibbonMeasures:
    """Per recorded frame k and fibre f: ``times`` (K,) s; ``middle`` (K, F, 3) m, the middle nodes; ``start_side``
    (F,) ±1, the side of the midline (sign of z) each fibre starts on; ``sphere_centre`` (3,), ``sphere_radius`` and
    ``fibre_radius`` m; ``contact_gap`` (F,) m, at the last frame: the distance of the two middle segments' axes
    (closest of :data:`AXIS_SAMPLES` samples each) to the sphere surface, less the fibre radius (0: touching)."""

    times: np.ndarray
    middle: np.ndarray
    start_side: np.ndarray
    sphere_centre: np.ndarray
    sphere_radius: float
    fibre_radius: float
    contact_gap: np.ndarray

    def surface_gap(self) -> np.ndarray:
        """(K, F) m: each middle node's distance to the sphere's surface, less the fibre radius."""
        d = np.linalg.norm(self.middle - self.sphere_centre, axis=2)
        return d - self.sphere_radius - self.fibre_radius

    def sides_kept(self) -> bool:
        """Every middle node is on its start side of the midline in every frame in which it is on the sphere's
        upper half: above its centre and no farther from its surface than the ribbon started, plus a fibre
        radius (where the split happens; a fibre that slid off swings in the air and under the sphere and may
        cross), with fibres on both sides (two portions, left and right)."""
        side = np.sign(self.middle[:, :, 2])
        gap = self.surface_gap()
        on_top = (self.middle[:, :, 1] > self.sphere_centre[1]) & (gap <= gap[0].max() + self.fibre_radius)
        return bool(((side == self.start_side[None, :]) | ~on_top).all() and (self.start_side > 0).any()
                    and (self.start_side < 0).any())

    def excursion(self) -> np.ndarray:
        """(F,) m: the farthest each middle node got from the midline on its start side in any frame, less its
        start distance (a fibre that slides off sideways and then swings in under the sphere keeps its
        excursion)."""
        z = self.middle[:, :, 2] * self.start_side[None, :]
        return z.max(axis=0) - z[0]

    def slid_off(self) -> np.ndarray:
        """(F,) bool: the fibre's middle node went below the sphere's centre (past its equator) in some frame."""
        return (self.middle[:, :, 1] < self.sphere_centre[1]).any(axis=0)

    def sideways(self, window: float) -> np.ndarray:
        """(F,) m: how far each middle node moved across the midline direction (z) over the last ``window`` s of
        the recorded frames (between the last frame and the latest one at least ``window`` before it)."""
        k = int(np.searchsorted(self.times, self.times[-1] - window + 1e-12, side="right")) - 1
        if k < 0:
            raise ValueError(f"the recording spans {self.times[-1] - self.times[0]:g} s, less than the window "
                             f"{window:g} s")
        return np.abs(self.middle[-1, :, 2] - self.middle[k, :, 2])

    def outermost_distance(self) -> np.ndarray:
        """(K,) m: the mean distance from the midline of the middle nodes of the two fibres that start outermost."""
        i = np.argsort(self.middle[0, :, 2])
        return np.abs(self.middle[:, [i[0], i[-1]], 2]).mean(axis=1)

    def spread(self) -> tuple[float, float]:
        """(start width, last width) m of the middle nodes across the midline (max z − min z)."""
        z = self.middle[:, :, 2]
        return float(np.ptp(z[0])), float(np.ptp(z[-1]))


def ribbon_measures(scene, result) -> RibbonMeasures:
    """:class:`RibbonMeasures` of a ``sphere-horizontal`` scene and its recorded run."""
    if scene.name != "sphere-horizontal":
        raise ValueError(f"ribbon measures need the sphere-horizontal scene, got {scene.name!r}")
    poly = np.asarray(result.polylines, float)  # (K, F, n + 1, 3)
    n = poly.shape[2] - 1
    if n < 2 or poly.shape[0] < 2:
        raise ValueError("ribbon measures need at least two recorded frames of fibres with two or more segments")
    obstacle = scene.obstacles[0]
    field = obstacle.field
    r = float(scene.model.radius[0])
    k = n // 2
    t = np.linspace(0.0, 1.0, AXIS_SAMPLES)[:, None]
    last = poly[-1]
    axis = np.concatenate([last[:, j, None] * (1 - t)[None] + last[:, j + 1, None] * t[None] for j in (k - 1, k)],
                          axis=1)  # (F, 2 samples, 3)
    phi = (field.distance(axis.reshape(-1, 3)) - obstacle.level).reshape(axis.shape[:2]).min(axis=1)
    return RibbonMeasures(times=np.asarray(result.times, float), middle=poly[:, :, k].copy(),
                          start_side=np.sign(poly[0, :, k, 2]), sphere_centre=np.asarray(field.center, float),
                          sphere_radius=float(field.radius), fibre_radius=r, contact_gap=phi - r)
