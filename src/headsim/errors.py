"""Error types. Every error headsim raises on purpose derives from :class:`HeadsimError`.

The CLI turns a ``HeadsimError`` into a one-line message and exit code 2; anything else is a bug.
"""


class HeadsimError(Exception):
    """Every error headsim raises on purpose."""


class MeshError(HeadsimError, ValueError):
    """A mesh is empty, malformed, non-manifold, inverted, or otherwise unusable."""


class UnitsError(HeadsimError, ValueError):
    """A unit is unknown, or a model's size is implausible for the stated unit."""


class ParameterError(HeadsimError, ValueError):
    """A parameter is out of its physical or numerical range."""


class RegionError(HeadsimError, ValueError):
    """A named or marked region does not exist, is empty, or is not closed."""


class DivergenceError(HeadsimError, RuntimeError):
    """A simulation produced non-finite values, an energy blow-up, or inverted elements."""


class ConvergenceError(HeadsimError, RuntimeError):
    """An iterative solve did not reach its tolerance within its iteration budget."""
