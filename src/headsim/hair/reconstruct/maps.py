"""Scalp parametrisation, grey-value texture maps and hair roots (Sobottka 2008 §5.3.2).

The scalp is mapped onto the unit disk (:func:`headsim.mesh.disk_parametrisation.disk_parametrisation`:
Floater mean-value weights, Yoshizawa stretch relaxation). Grey-value textures (0-255) over the disk's
square [-1, 1]^2 encode the root density (roots/cm^2 at 255), the growth direction (the azimuth in the
parameter plane relative to "away from the crown", and the elevation above the scalp) and the hair length.
A map pixel is read back on the surface through the piecewise-linear map: those points are the pores.

Roots are a Poisson process of intensity rho(uv) per surface area (rejection sampling: uniform points on
the surface, accepted with rho / rho_max), or exactly n roots drawn from that density.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from headsim.errors import ParameterError
from headsim.mesh.disk_parametrisation import DiskParametrisation, disk_parametrisation
from headsim.mesh.surface import SurfaceMesh

__all__ = ["TextureMap", "ScalpMap", "Roots", "default_maps", "farthest_point_order"]


@dataclass(frozen=True, eq=False)
class TextureMap:
    """Grey values (H, W) in 0..255 over [-1, 1]^2 (row 0 at v = +1, as an image), read by nearest pixel;
    a value is ``scale * grey / 255`` (scale: the unit quantity at grey 255)."""

    grey: np.ndarray
    scale: float

    def __post_init__(self):
        g = np.asarray(self.grey, dtype=np.float64)
        if g.ndim != 2 or min(g.shape) < 1 or not np.isfinite(g).all() or g.min() < 0 or g.max() > 255:
            raise ParameterError("a texture map must be a 2-D array of grey values in 0..255")
        if not np.isfinite(self.scale):
            raise ParameterError("texture scale must be finite")
        object.__setattr__(self, "grey", g)

    @classmethod
    def from_function(cls, fn, scale: float, size: int = 256) -> "TextureMap":
        """Sample ``fn(u, v) -> [0, 1]`` at the pixel centres."""
        c = (np.arange(size) + 0.5) / size * 2 - 1
        u, v = np.meshgrid(c, -c)
        return cls(np.clip(255.0 * np.asarray(fn(u, v), float), 0, 255), scale)

    @classmethod
    def from_image(cls, path, scale: float) -> "TextureMap":
        """A grey (or RGB: mean of the channels) PNG image."""
        import matplotlib.image as mpimg

        img = np.asarray(mpimg.imread(path), float)
        if img.ndim == 3:
            img = img[..., :3].mean(axis=2)
        if img.max() <= 1.0:
            img = img * 255.0
        return cls(img, scale)

    def __call__(self, uv) -> np.ndarray:
        uv = np.asarray(uv, float).reshape(-1, 2)
        H, W = self.grey.shape
        col = np.clip(((uv[:, 0] + 1) * 0.5 * W).astype(np.int64), 0, W - 1)
        row = np.clip(((1 - uv[:, 1]) * 0.5 * H).astype(np.int64), 0, H - 1)
        return self.scale * self.grey[row, col] / 255.0


def default_maps(length: float, density_per_cm2: float = 250.0):
    """(density, azimuth, elevation, length) maps: uniform density (roots/cm^2), hair growing straight away
    from the crown (azimuth 0 rad), elevation falling from 65 deg at the crown to 15 deg at the hairline (temporal
    and occipital hair grows more tangentially, §5.3.2), constant length (m)."""
    one = lambda u, v: np.ones_like(u)  # noqa: E731
    return (TextureMap.from_function(one, density_per_cm2 * 1e4, 4),
            TextureMap.from_function(lambda u, v: np.full_like(u, 0.5), 2 * np.pi, 4),  # grey 127.5 = 0 rad
            TextureMap.from_function(lambda u, v: (65.0 - 50.0 * np.minimum(u * u + v * v, 1.0)) / 90.0,
                                     np.pi / 2, 256),
            TextureMap.from_function(one, length, 4))


@dataclass(frozen=True, eq=False)
class Roots:
    """positions (n, 3) m on the scalp; normals (n, 3); directions (n, 3) unit growth directions;
    lengths (n,) m; uv (n, 2); triangle (n,) scalp triangle ids."""

    positions: np.ndarray
    normals: np.ndarray
    directions: np.ndarray
    lengths: np.ndarray
    uv: np.ndarray
    triangle: np.ndarray

    def subset(self, ids) -> "Roots":
        return Roots(*(a[ids] for a in (self.positions, self.normals, self.directions, self.lengths, self.uv,
                                         self.triangle)))

    def __len__(self) -> int:
        return len(self.positions)


class ScalpMap:
    """A scalp mesh with its unit-disk parametrisation, per-triangle Jacobians and areas."""

    def __init__(self, scalp: SurfaceMesh, parametrisation: DiskParametrisation | None = None):
        self.scalp = scalp
        self.param = parametrisation or disk_parametrisation(scalp.vertices, scalp.triangles)
        v, t, uv = scalp.vertices, scalp.triangles, self.param.uv
        q1, q2, q3 = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
        s1, s2, s3 = (uv[t[:, k], 0] for k in range(3))
        t1, t2, t3 = (uv[t[:, k], 1] for k in range(3))
        A = 0.5 * ((s2 - s1) * (t3 - t1) - (s3 - s1) * (t2 - t1))
        self.jac_u = (q1 * (t2 - t3)[:, None] + q2 * (t3 - t1)[:, None] + q3 * (t1 - t2)[:, None]) / (2 * A)[:, None]
        self.jac_v = (q1 * (s3 - s2)[:, None] + q2 * (s1 - s3)[:, None] + q3 * (s2 - s1)[:, None]) / (2 * A)[:, None]
        self.areas = scalp.triangle_areas
        self.normals = scalp.face_normals

    @property
    def area(self) -> float:
        """Scalp area, m^2."""
        return float(self.areas.sum())

    def _uniform(self, n: int, rng):
        t = self.scalp.triangles
        tri = rng.choice(len(t), size=n, p=self.areas / self.areas.sum())
        a, b = rng.random((2, n))
        flip = a + b > 1
        a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
        bary = np.column_stack([1 - a - b, a, b])
        return tri, bary

    def _at(self, tri, bary, field):
        return np.einsum("nk,nkc->nc", bary, field[self.scalp.triangles[tri]])

    def sample_roots(self, density: TextureMap, azimuth: TextureMap, elevation: TextureMap, length: TextureMap,
                     n: int | None = None, seed: int = 0) -> Roots:
        """Roots from the maps: a Poisson process of intensity density(uv) (roots/m^2), or exactly ``n``
        roots with that distribution. Raises ParameterError for an empty density map."""
        rng = np.random.default_rng(seed)
        rho_max = float(density.scale * density.grey.max() / 255.0)
        if not rho_max > 0:
            raise ParameterError("the density map is zero everywhere")
        if n is None:  # Poisson process: candidates ~ Poisson(rho_max A) uniform points, thinned by rho / rho_max
            tri, bary = self._uniform(int(rng.poisson(rho_max * self.area)), rng)
            keep = rng.random(len(tri)) * rho_max < density(self._at(tri, bary, self.param.uv))
            return self.roots_at(tri[keep], bary[keep], azimuth, elevation, length)
        if n <= 0:
            raise ParameterError(f"number of roots must be > 0, got {n}")
        rate = max(self._mean_density(density) / rho_max, 1e-3)  # expected acceptance
        tris, barys, got = [], [], 0
        while got < n:
            tri, bary = self._uniform(int(1.2 * (n - got) / rate) + 64, rng)
            keep = rng.random(len(tri)) * rho_max < density(self._at(tri, bary, self.param.uv))
            tris.append(tri[keep])
            barys.append(bary[keep])
            got += int(keep.sum())
        return self.roots_at(np.concatenate(tris)[:n], np.concatenate(barys)[:n], azimuth, elevation, length)

    def _mean_density(self, density: TextureMap) -> float:
        cen = self.param.uv[self.scalp.triangles].mean(axis=1)
        return float((density(cen) * self.areas).sum() / self.areas.sum())

    def roots_at(self, tri, bary, azimuth: TextureMap, elevation: TextureMap, length: TextureMap) -> Roots:
        """Roots at barycentric points of scalp triangles, with directions and lengths from the maps."""
        pos = self._at(tri, bary, self.scalp.vertices)
        uv = self._at(tri, bary, self.param.uv)
        nrm = self.normals[tri]
        r = np.linalg.norm(uv, axis=1, keepdims=True)
        radial = np.where(r > 1e-9, uv / np.maximum(r, 1e-300), np.array([[0.0, -1.0]]))
        phi = azimuth(uv) - np.pi  # grey 127.5 -> 0 rad: straight away from the crown
        c, s = np.cos(phi), np.sin(phi)
        duv = np.column_stack([c * radial[:, 0] - s * radial[:, 1], s * radial[:, 0] + c * radial[:, 1]])
        tan = self.jac_u[tri] * duv[:, :1] + self.jac_v[tri] * duv[:, 1:]
        tan -= (tan * nrm).sum(1, keepdims=True) * nrm
        tan /= np.maximum(np.linalg.norm(tan, axis=1, keepdims=True), 1e-300)
        el = elevation(uv)[:, None]
        d = np.cos(el) * tan + np.sin(el) * nrm
        L = length(uv)
        if np.any(L <= 0):
            raise ParameterError("the length map must be > 0 at every root")
        return Roots(pos, nrm, d / np.linalg.norm(d, axis=1, keepdims=True), L, uv, np.asarray(tri))


@njit(cache=True)
def _fps(points, k, start):
    n = points.shape[0]
    d = np.full(n, np.inf)
    order = np.empty(k, np.int64)
    cur = start
    for i in range(k):
        order[i] = cur
        best = -1.0
        arg = 0
        for j in range(n):
            dx = points[j, 0] - points[cur, 0]
            dy = points[j, 1] - points[cur, 1]
            dz = points[j, 2] - points[cur, 2]
            e = dx * dx + dy * dy + dz * dz
            if e < d[j]:
                d[j] = e
            if d[j] > best:
                best = d[j]
                arg = j
        cur = arg
    return order


def farthest_point_order(points: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
    """k indices by farthest-point sampling (evenly spread subsets: pre-guide and guide roots)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    if not 0 < k <= len(points):
        raise ParameterError(f"cannot pick {k} of {len(points)} roots")
    return _fps(points, int(k), int(np.random.default_rng(seed).integers(len(points))))
