"""The seed's approximate collision detector: a body as a height field along one axis (Heinze §3.3.1).

Heinze turns each body into a heightmap along the collision axis (y): the height at a grid node is
the distance at which a ray cast parallel to the axis first hits the body (the hull mass points
supply some values, ray casts the rest). A point of the other body collides when its coordinate
along the axis lies below (or above, depending on the side) the height there. Here every grid node
is ray cast against the body's :class:`~headsim.collide.bvh.TriangleBVH` and heights between nodes
are interpolated bilinearly. This is kept for comparison with the exact BVH queries: it sees only
the outermost surface from one side, so overhangs (the nose seen from below, the eye sockets seen
obliquely) are lost.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.collide.bvh import TriangleBVH
from headsim.errors import ParameterError

__all__ = ["Heightmap"]


@dataclass(frozen=True, eq=False)
class Heightmap:
    """Height field of a body's surface seen along ``axis``.

    Attributes
    ----------
    axis : 0, 1 or 2, the collision axis (Heinze uses y = 1)
    facing : +1 when the surface is seen from the + side of the axis (rays cast towards -axis; the
        body lies at coordinates below the height), -1 when seen from the - side
    origin : (2,) float64, m, in-plane coordinates of grid node (0, 0); the in-plane axes are the
        two other axes in increasing order
    spacing : (2,) float64, m, grid step along the two in-plane axes
    heights : (nu, nv) float64, m, coordinate along ``axis`` of the first hit; NaN where the ray missed
    """

    axis: int
    facing: int
    origin: np.ndarray
    spacing: np.ndarray
    heights: np.ndarray

    def __post_init__(self):
        if self.axis not in (0, 1, 2):
            raise ParameterError(f"axis must be 0, 1 or 2, got {self.axis}")
        if self.facing not in (1, -1):
            raise ParameterError(f"facing must be +1 or -1, got {self.facing}")
        origin = np.array(self.origin, dtype=np.float64).reshape(2)
        spacing = np.array(self.spacing, dtype=np.float64).reshape(2)
        heights = np.array(self.heights, dtype=np.float64)
        if not (np.isfinite(spacing).all() and (spacing > 0).all()):
            raise ParameterError(f"spacing must be positive, got {spacing}")
        if heights.ndim != 2 or min(heights.shape) < 2:
            raise ParameterError(f"heights must be a 2-D grid of at least 2 × 2 nodes, got {heights.shape}")
        for name, a in (("origin", origin), ("spacing", spacing), ("heights", heights)):
            a.flags.writeable = False
            object.__setattr__(self, name, a)

    @property
    def plane_axes(self) -> tuple[int, int]:
        """The two in-plane axes (u, v), in increasing order."""
        u, v = (k for k in range(3) if k != self.axis)
        return u, v

    @classmethod
    def from_mesh(cls, vertices, triangles, axis: int = 1, facing: int = 1, spacing: float | None = None,
                  bvh: TriangleBVH | None = None) -> "Heightmap":
        """Ray cast a grid over the mesh's bounding box along ``axis`` (Heinze §3.3.1).

        vertices (n, 3) float64, m; triangles (m, 3) int. spacing : grid step, m (default: 256
        cells along the longer in-plane side). bvh : a tree of the same mesh to reuse.
        """
        v = np.asarray(vertices, dtype=np.float64)
        if axis not in (0, 1, 2) or facing not in (1, -1):
            raise ParameterError(f"axis must be 0, 1 or 2 and facing +1 or -1, got {axis}, {facing}")
        tree = bvh if bvh is not None else TriangleBVH(v, triangles)
        u_ax, v_ax = (k for k in range(3) if k != axis)
        lo = v.min(axis=0)
        hi = v.max(axis=0)
        if spacing is None:
            spacing = max(hi[u_ax] - lo[u_ax], hi[v_ax] - lo[v_ax]) / 256.0
        spacing = float(spacing)
        if not spacing > 0:
            raise ParameterError(f"spacing must be > 0 m, got {spacing}")
        nu = max(int(np.ceil((hi[u_ax] - lo[u_ax]) / spacing)) + 1, 2)
        nv = max(int(np.ceil((hi[v_ax] - lo[v_ax]) / spacing)) + 1, 2)
        gu = lo[u_ax] + spacing * np.arange(nu)
        gv = lo[v_ax] + spacing * np.arange(nv)
        uu, vv = np.meshgrid(gu, gv, indexing="ij")
        origins = np.zeros((nu * nv, 3))
        origins[:, u_ax] = uu.ravel()
        origins[:, v_ax] = vv.ravel()
        span = hi[axis] - lo[axis]
        margin = span + spacing
        origins[:, axis] = hi[axis] + margin if facing == 1 else lo[axis] - margin
        directions = np.zeros_like(origins)
        directions[:, axis] = -float(facing)
        hits = tree.intersect_rays(origins, directions)
        heights = np.where(hits.hit, hits.point[:, axis], np.nan).reshape(nu, nv)
        return cls(axis, facing, (lo[u_ax], lo[v_ax]), (spacing, spacing), heights)

    def node_coordinates(self) -> tuple[np.ndarray, np.ndarray]:
        """(nu,), (nv,) float64, m: in-plane coordinates of the grid lines."""
        nu, nv = self.heights.shape
        return (self.origin[0] + self.spacing[0] * np.arange(nu),
                self.origin[1] + self.spacing[1] * np.arange(nv))

    def height_at(self, points) -> np.ndarray:
        """(q,) float64, m: bilinearly interpolated height under each point; NaN outside the grid
        or where a neighbouring node has no height. points (q, 3) float64, m."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        u_ax, v_ax = self.plane_axes
        nu, nv = self.heights.shape
        fu = (p[:, u_ax] - self.origin[0]) / self.spacing[0]
        fv = (p[:, v_ax] - self.origin[1]) / self.spacing[1]
        inside = (fu >= 0) & (fu <= nu - 1) & (fv >= 0) & (fv <= nv - 1)
        iu = np.clip(np.floor(fu), 0, nu - 2).astype(np.int64)
        iv = np.clip(np.floor(fv), 0, nv - 2).astype(np.int64)
        su = np.clip(fu - iu, 0.0, 1.0)
        sv = np.clip(fv - iv, 0.0, 1.0)
        h = self.heights
        value = ((1 - su) * (1 - sv) * h[iu, iv] + su * (1 - sv) * h[iu + 1, iv]
                 + (1 - su) * sv * h[iu, iv + 1] + su * sv * h[iu + 1, iv + 1])
        return np.where(inside, value, np.nan)

    def depth(self, points) -> np.ndarray:
        """(q,) float64, m: penetration along the axis, positive when the point lies on the body's
        side of the surface (below it for facing +1, above for -1); NaN where there is no height.
        This is the seed's penetration depth d along the collision direction (Heinze eq. 3.8)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return self.facing * (self.height_at(p) - p[:, self.axis])

    def collides(self, points) -> np.ndarray:
        """(q,) bool: the point is behind the surface (depth > 0); False where there is no height."""
        d = self.depth(points)
        return np.nan_to_num(d, nan=-1.0) > 0
