"""Coulomb forces among point charges: exact direct sum, fmm3dpy FMM, and the treecode.

SI throughout (Sobottka eq. 4.2 with c0 -> K = 1/(4 pi eps0)):
    F_i = K q_i sum_{j != i} q_j (x_i - x_j) / |x_i - x_j|^3      [N],   E = F / q  [V/m].
No distance cut-off is applied by any method (Sobottka §4.2 after Darden 1993: cut-offs give
unphysical artefacts). Coincident charges are skipped (the seed requires well-separated particles).

``fmm3dpy.lfmm3d`` (Flatiron FMM3D) evaluates u(x_i) = sum_j q_j / (4 pi |x_i - x_j|) and its
gradient, i.e. it already contains 1/(4 pi); hence E = -grad u / eps0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.errors import ParameterError
from headsim.hair.electrostatics import _kernels as _k
from headsim.hair.electrostatics.treecode import Treecode, TreecodeOptions
from headsim.hair.electrostatics.units import EPSILON_0, K_COULOMB

__all__ = ["CoulombOptions", "direct_field", "direct_forces", "fmm_field", "fmm_forces", "coulomb_forces",
           "field_at"]


@dataclass(frozen=True)
class CoulombOptions:
    """method: 'direct' (exact, O(n^2)), 'fmm3d' (fmm3dpy, precision ``eps``) or 'treecode'
    (``theta``, ``order``, ``leaf_size``, ``local``; see :mod:`.treecode`)."""

    method: str = "treecode"
    eps: float = 1e-3
    theta: float = 0.3
    order: int = 2
    leaf_size: int = 32
    local: bool = True

    def __post_init__(self):
        if self.method not in ("direct", "fmm3d", "treecode"):
            raise ParameterError(f"unknown Coulomb method {self.method!r}: direct, fmm3d or treecode")
        if not (0.0 < self.eps < 1.0):
            raise ParameterError(f"FMM precision eps must lie in (0, 1), got {self.eps}")
        TreecodeOptions(self.theta, self.order, self.leaf_size, self.local)

    @property
    def treecode_options(self) -> TreecodeOptions:
        return TreecodeOptions(self.theta, self.order, self.leaf_size, self.local)


def _check(points, charges):
    x = np.ascontiguousarray(np.asarray(points, dtype=np.float64))
    q = np.ascontiguousarray(np.asarray(charges, dtype=np.float64))
    if x.ndim != 2 or x.shape[1] != 3 or q.shape != (x.shape[0],):
        raise ParameterError(f"need points (n, 3) and charges (n,), got {x.shape} and {q.shape}")
    if not (np.isfinite(x).all() and np.isfinite(q).all()):
        raise ParameterError("charge positions and charges must be finite")
    return x, q


def direct_field(points, charges, targets=None) -> np.ndarray:
    """(m, 3) V/m: exact field of the charges at ``targets`` (default: at the charges, self excluded).

    points (n, 3) m, charges (n,) C. Numba, thread-parallel over targets; the reference.
    """
    x, q = _check(points, charges)
    t = x if targets is None else np.ascontiguousarray(np.asarray(targets, dtype=np.float64).reshape(-1, 3))
    out = np.empty((t.shape[0], 3))
    _k.coulomb_field_direct(t, x, q, out)
    return out * K_COULOMB


def direct_forces(points, charges) -> np.ndarray:
    """(n, 3) N: exact Coulomb forces (Sobottka eq. 4.2 in SI)."""
    x, q = _check(points, charges)
    return q[:, None] * direct_field(x, q)


def fmm_field(points, charges, eps: float = 1e-3, targets=None) -> np.ndarray:
    """(m, 3) V/m by fmm3dpy's Laplace FMM at relative precision ``eps`` (at the charges, self excluded,
    or at ``targets``)."""
    import fmm3dpy

    x, q = _check(points, charges)
    if not (0.0 < eps < 1.0):
        raise ParameterError(f"eps must lie in (0, 1), got {eps}")
    src = np.asfortranarray(x.T)
    if targets is None:
        out = fmm3dpy.lfmm3d(eps=float(eps), sources=src, charges=q, pg=2)
        grad = out.grad
    else:
        t = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
        out = fmm3dpy.lfmm3d(eps=float(eps), sources=src, charges=q, targets=np.asfortranarray(t.T), pgt=2)
        grad = out.gradtarg
    return -np.ascontiguousarray(np.asarray(grad).T) / EPSILON_0


def fmm_forces(points, charges, eps: float = 1e-3) -> np.ndarray:
    """(n, 3) N by fmm3dpy (see :func:`fmm_field`)."""
    x, q = _check(points, charges)
    return q[:, None] * fmm_field(x, q, eps)


def coulomb_forces(points, charges, options: CoulombOptions = CoulombOptions(), tree: Treecode | None = None):
    """(n, 3) N with the chosen method. For 'treecode', a ``tree`` built on the same charges is refitted
    to the new positions/charges instead of rebuilt (time coherence across charging steps)."""
    x, q = _check(points, charges)
    if options.method == "direct":
        return direct_forces(x, q)
    if options.method == "fmm3d":
        return fmm_forces(x, q, options.eps)
    if tree is None or tree.n_charges != x.shape[0]:
        tree = Treecode(x, q, options.treecode_options)
    else:
        tree.refit(x, q)
    return q[:, None] * tree.field(options.theta, options.order)


def field_at(probes, points, charges, options: CoulombOptions = CoulombOptions()) -> np.ndarray:
    """(m, 3) V/m at probe points (m, 3) m: the field strength E = F/q a test charge would feel."""
    x, q = _check(points, charges)
    p = np.asarray(probes, dtype=np.float64).reshape(-1, 3)
    if options.method == "direct":
        return direct_field(x, q, p)
    if options.method == "fmm3d":
        return fmm_field(x, q, options.eps, targets=p)
    return Treecode(x, q, options.treecode_options).field_at(p, options.theta, options.order)
