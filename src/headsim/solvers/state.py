"""What a time step changes: positions, velocities, time."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.errors import ParameterError


@dataclass(frozen=True, eq=False)
class BodyState:
    """State of one or several bodies (concatenated vertices).

    Attributes
    ----------
    positions : (n, 3) float64, m
    velocities : (n, 3) float64, m/s
    time : float, s
    step : int, number of steps taken
    """

    positions: np.ndarray
    velocities: np.ndarray
    time: float = 0.0
    step: int = 0

    def __post_init__(self):
        x = np.array(self.positions, dtype=np.float64, order="C")
        v = np.array(self.velocities, dtype=np.float64, order="C")
        if x.ndim != 2 or x.shape[1] != 3 or v.shape != x.shape:
            raise ParameterError(f"positions and velocities must both be (n, 3), got {x.shape}, {v.shape}")
        x.flags.writeable = False
        v.flags.writeable = False
        object.__setattr__(self, "positions", x)
        object.__setattr__(self, "velocities", v)

    @classmethod
    def at_rest(cls, positions: np.ndarray) -> "BodyState":
        x = np.asarray(positions, dtype=np.float64)
        return cls(x, np.zeros_like(x))
