"""headsim: physics simulation of the soft parts of the human head.

Layers (imports only go downwards):

- core: :mod:`headsim.mesh` (I/O, validation, geometry, tetrahedra), :mod:`headsim.collide`
  (BVH, ray casts, distance fields, heightmaps), :mod:`headsim.solvers` (mass-spring, FEM, PBD, rods, contact)
- apps: :mod:`headsim.mask`, :mod:`headsim.graft`, :mod:`headsim.hair` (never import each other)
- front: :mod:`headsim.cli`, :mod:`headsim.report`

SI units inside (m, kg, s, N, Pa); conversion happens at the edges.
"""

from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version("headsim")
except PackageNotFoundError:  # running from a source tree without install
    __version__ = "0.0.0+unknown"

from headsim.errors import (  # noqa: E402
    ConvergenceError,
    DivergenceError,
    HeadsimError,
    MeshError,
    ParameterError,
    RegionError,
    UnitsError,
)

__all__ = [
    "__version__",
    "HeadsimError",
    "MeshError",
    "UnitsError",
    "ParameterError",
    "RegionError",
    "DivergenceError",
    "ConvergenceError",
]
