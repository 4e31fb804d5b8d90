"""Compaction barrier: a volume floor for homogenised (hollow or cellular) solids.

A hollow silicone cushion modelled as an effective solid (:mod:`headsim.mask.masks`, E = 50 kPa,
nu = 0.45) has no stiffening where the real cushion bottoms out (its walls pressed together), so under
strap forces of 40 N and more its stable neo-Hookean elements are crushed through J = 0 and invert
(measured: identity000 x nasal-S at 42 N, nine cushion tets, min det F = -0.20). This term adds, per
selected tet, the clamped logarithmic barrier of Incremental Potential Contact (Li et al., ACM TOG
39(4) 2020, eq. 6) on the volume ratio J = det F instead of a distance:

    E_t = kappa_t V_t b(s),   s = (J - J_floor) / (J_onset - J_floor),
    b(s) = -(s - 1)^2 ln s  (0 < s < 1),  0  (s >= 1),   E_t = inf  (J <= J_floor)

so it is zero (with its first two derivatives) above ``onset`` and infinite at ``floor``: Newton's line
search keeps every selected tet above the floor and the element cannot invert. Floor and onset may
differ per tet: the mask fit (:mod:`headsim.mask.fit`) also floors its one-layer soft tissue, whose
sliver tets were crushed through J = 0 under the nasal bridge at 40-45 N (identity001 x nasal-S), at
(0.02, 0.1), below every tissue J of its demo fits. kappa_t (Pa) is
``scale`` x the tet's shear modulus. Derivatives (dJ/dF = cof F; d2J/dF_ij dF_kl = e_ikm e_jln F_mn):

    grad = kappa V b'(s) / D  dJ/dx,     D = J_onset - J_floor
    Hess = kappa V [ b''(s) / D^2  dJ/dx dJ/dx^T  +  b'(s) / D  d2J/dx2 ]

b' < 0 and b'' > 0 on (0, 1); the projected (PSD) form keeps the first, PSD, term only. The floor and
onset are modelling limits of the homogenised solid, not measured properties of a cushion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.errors import ParameterError
from headsim.solvers._kernels import fem as _k

_EPS = np.zeros((3, 3, 3))
_EPS[0, 1, 2] = _EPS[1, 2, 0] = _EPS[2, 0, 1] = 1.0
_EPS[0, 2, 1] = _EPS[2, 1, 0] = _EPS[1, 0, 2] = -1.0


@dataclass(frozen=True, eq=False)
class CompactionBarrier:
    """Volume floor of the tets where ``tets`` is True (see the module doc).

    tets : (m,) bool, the tets it acts on; floor, onset : J_floor < J_onset < 1, one value for all or
    (m,) per tet (only the selected tets' entries are used); scale : kappa / mu
    """

    tets: np.ndarray
    floor: float | np.ndarray = 0.1
    onset: float | np.ndarray = 0.3
    scale: float = 1.0

    def __post_init__(self):
        t = np.asarray(self.tets, dtype=bool).copy()
        if t.ndim != 1:
            raise ParameterError(f"compaction barrier tets must be an (m,) bool array, got shape {t.shape}")
        ids = np.flatnonzero(t)
        try:
            floors = np.broadcast_to(np.asarray(self.floor, dtype=np.float64), t.shape)[ids]
            onsets = np.broadcast_to(np.asarray(self.onset, dtype=np.float64), t.shape)[ids]
        except ValueError:
            raise ParameterError(f"compaction barrier floor and onset must be scalars or ({len(t)},) arrays") from None
        bad = ~((floors >= 0.0) & (floors < onsets) & (onsets < 1.0))
        if bad.any():
            k = int(np.argmax(bad))
            raise ParameterError(f"compaction barrier needs 0 <= floor < onset < 1, got {floors[k]}, {onsets[k]} "
                                 f"(tet {ids[k]})")
        if not self.scale > 0:
            raise ParameterError(f"compaction barrier scale must be > 0, got {self.scale}")
        t.flags.writeable = False
        object.__setattr__(self, "tets", t)
        object.__setattr__(self, "_ids", ids)
        object.__setattr__(self, "_floors", floors)
        object.__setattr__(self, "_onsets", onsets)
        object.__setattr__(self, "_onset_max", float(onsets.max()) if len(ids) else 0.0)
        object.__setattr__(self, "_subset_cache", [])

    def _subset(self, tets, grads):
        """Contiguous copies of the selected tets and their shape gradients (per model, cached)."""
        cached = self._subset_cache
        if not cached or cached[0] is not tets or cached[1] is not grads:  # the arrays are held: no id reuse
            cached[:] = [tets, grads, np.ascontiguousarray(tets[self._ids]), np.ascontiguousarray(grads[self._ids])]
        return cached[2], cached[3]

    def _active(self, x, tets, grads):
        """(ids, F, s, D) of the selected tets below their onset: s = (J - J_floor) / D, D = J_onset - J_floor."""
        ids = self._ids
        sub_tets, sub_grads = self._subset(tets, grads)
        if not len(ids) or _k.snh_min_jacobian(x, sub_tets, sub_grads) >= self._onset_max:  # the usual case
            return ids[:0], None, np.zeros(0), np.ones(0)
        f = np.einsum("tai,taj->tij", x[sub_tets], sub_grads)
        j = np.linalg.det(f)
        below = j < self._onsets
        floor = self._floors[below]
        d = self._onsets[below] - floor
        return ids[below], f[below], (j[below] - floor) / d, d

    @staticmethod
    def _slopes(s):
        """b'(s) and b''(s) (s kept above 0 for the logarithm)."""
        s = np.maximum(s, np.finfo(float).tiny)
        db = -2.0 * (s - 1.0) * np.log(s) - (s - 1.0) ** 2 / s
        d2b = -2.0 * np.log(s) - 4.0 * (s - 1.0) / s + (s - 1.0) ** 2 / s**2
        return db, d2b

    def energy(self, x, tets, grads, volumes, mu) -> float:
        """Sum of kappa V b(s), J; inf where a selected tet reached the floor."""
        ids, _, s, _ = self._active(x, tets, grads)
        if not len(ids):
            return 0.0
        if not (s > 0).all():
            return np.inf
        return float(np.sum(self.scale * mu[ids] * volumes[ids] * (-(s - 1.0) ** 2 * np.log(s))))

    @staticmethod
    def _dj_dx(f, grads):
        """dJ/dx (k, 4, 3), m^-1 x m^2: cof(F) grad_a per vertex a."""
        cof = np.stack([np.cross(f[:, :, 1], f[:, :, 2]), np.cross(f[:, :, 2], f[:, :, 0]),
                        np.cross(f[:, :, 0], f[:, :, 1])], axis=2)  # (k, 3, 3): cof_ij = dJ/dF_ij
        return np.einsum("tij,taj->tai", cof, grads)

    def add_gradient(self, x, tets, grads, volumes, mu, out) -> None:
        """Add the barrier's gradient to ``out`` (n, 3), N (no-op where nothing is below the onset)."""
        ids, f, s, d = self._active(x, tets, grads)
        if not len(ids):
            return
        db, _ = self._slopes(s)
        w = self.scale * mu[ids] * volumes[ids] * db / d
        np.add.at(out, tets[ids], w[:, None, None] * self._dj_dx(f, grads[ids]))

    def add_element_hessians(self, x, tets, grads, volumes, mu, project: bool, out) -> None:
        """Add the barrier's element Hessians to ``out`` (m, 12, 12), N/m; PSD part only when ``project``."""
        ids, f, s, d = self._active(x, tets, grads)
        if not len(ids):
            return
        db, d2b = self._slopes(s)
        k = self.scale * mu[ids] * volumes[ids]
        g = grads[ids]
        dj = self._dj_dx(f, g).reshape(len(ids), 12)
        h = (k * d2b / d**2)[:, None, None] * dj[:, :, None] * dj[:, None, :]
        if not project:
            # d2J/dF_ij dF_kl = e_ikm e_jln F_mn, mapped to the vertices: H[a i, b k] = g_aj H_F[i j k l] g_bl
            hf = np.einsum("ikm,jln,tmn->tijkl", _EPS, _EPS, f)
            h2 = np.einsum("taj,tijkl,tbl->taibk", g, hf, g).reshape(len(ids), 12, 12)
            h += (k * db / d)[:, None, None] * h2
        out[ids] += h
