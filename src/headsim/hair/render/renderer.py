"""Path-traced images of fibre assemblies with the Marschner far-field BSDF (Sobottka 2008 §6.3–6.4.1).

Orders of fibre-to-fibre scattering: ``max_scatter`` = 1 renders single scattering (direct light only),
4 the seed's "up to order 4" (Fig. 6.9–6.10). Radiance units: lights give irradiance (directional,
W/m²) or intensity (point, W/sr); the image holds linear radiance (W/(m² sr)) per RGB channel.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from headsim.errors import ParameterError
from headsim.hair.render import _kernels_trace as _k
from headsim.hair.render.bvh import CapsuleBVH, FibreAssembly
from headsim.hair.render.scattering import MarschnerParams

__all__ = ["Camera", "Light", "MeshSurface", "RenderOptions", "RenderResult", "Surface", "render",
           "camera_looking_at", "to_srgb8", "save_png"]


def _unit(v, name):
    v = np.asarray(v, dtype=np.float64).reshape(3)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n == 0:
        raise ParameterError(f"{name} must be a finite non-zero 3-vector")
    return v / n


@dataclass(frozen=True, eq=False)
class Camera:
    """Pinhole camera: position (3,) m, look_at (3,) m, up (3,), vertical field of view in degrees."""

    position: tuple = (0.0, 0.0, 0.5)
    look_at: tuple = (0.0, 0.0, 0.0)
    up: tuple = (0.0, 1.0, 0.0)
    fov_deg: float = 40.0

    def __post_init__(self):
        if not (0.1 < self.fov_deg < 170):
            raise ParameterError(f"camera fov_deg must be in (0.1, 170), got {self.fov_deg}")
        if np.linalg.norm(np.subtract(self.look_at, self.position)) == 0:
            raise ParameterError("camera position and look_at coincide")

    def packed(self, width: int, height: int) -> np.ndarray:
        pos = np.asarray(self.position, dtype=np.float64)
        fwd = _unit(np.subtract(self.look_at, pos), "view direction")
        right = np.cross(fwd, _unit(self.up, "up"))
        if np.linalg.norm(right) < 1e-9:
            raise ParameterError("camera up is parallel to the view direction")
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        ty = math.tan(math.radians(self.fov_deg) / 2)
        tx = ty * width / height
        return np.concatenate([pos, fwd, right * tx, up * ty])


def camera_looking_at(fibres: FibreAssembly, azimuth_deg: float = 0.0, elevation_deg: float = 10.0,
                      fov_deg: float = 35.0, margin: float = 1.15) -> Camera:
    """Camera on a sphere around the assembly's bounding box (azimuth about +y, 0 = from +z)."""
    lo, hi = fibres.nodes.min(axis=0), fibres.nodes.max(axis=0)
    c = 0.5 * (lo + hi)
    rad = 0.5 * np.linalg.norm(hi - lo) * margin
    dist = rad / math.sin(math.radians(fov_deg) / 2)
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    d = np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
    return Camera(position=tuple(c + dist * d), look_at=tuple(c), fov_deg=fov_deg)


@dataclass(frozen=True)
class Light:
    """``kind`` "directional" (``vector`` toward the light, ``rgb`` irradiance W/m²) or "point"
    (``vector`` position m, ``rgb`` intensity W/sr)."""

    kind: str = "directional"
    vector: tuple = (0.3, 0.8, 0.6)
    rgb: tuple = (3.0, 3.0, 3.0)

    def __post_init__(self):
        if self.kind not in ("directional", "point"):
            raise ParameterError(f"light kind must be 'directional' or 'point', got {self.kind!r}")
        v = np.asarray(self.vector, dtype=np.float64)
        c = np.asarray(self.rgb, dtype=np.float64)
        if v.shape != (3,) or c.shape != (3,) or not np.isfinite(v).all() or not np.isfinite(c).all() or np.any(c < 0):
            raise ParameterError("light vector and rgb must be finite 3-vectors, rgb ≥ 0")
        if self.kind == "directional" and np.linalg.norm(v) == 0:
            raise ParameterError("directional light needs a non-zero direction")

    def row(self) -> np.ndarray:
        v = np.asarray(self.vector, dtype=np.float64)
        if self.kind == "directional":
            v = v / np.linalg.norm(v)
        return np.concatenate([[0.0 if self.kind == "directional" else 1.0], v, self.rgb])


@dataclass(frozen=True)
class Surface:
    """An opaque diffuse (Lambertian) surface drawn with the fibres: ``kind`` "sphere" (``point`` its centre, m,
    ``size`` its radius, m) or "plane" (``point`` on it, ``normal``); ``albedo`` RGB in [0, 1]. It ends the paths
    that reach it with its own radiance (the lights through shadow rays, plus albedo × the environment) and casts
    shadows on the fibres; light it reflects onto the fibres is counted only where a scattered path ends on it."""

    kind: str
    point: tuple
    size: float = 0.0
    normal: tuple = (0.0, 1.0, 0.0)
    albedo: tuple = (0.5, 0.5, 0.5)

    def __post_init__(self):
        if self.kind not in ("sphere", "plane"):
            raise ParameterError(f"surface kind must be 'sphere' or 'plane', got {self.kind!r}")
        p = np.asarray(self.point, dtype=np.float64)
        n = np.asarray(self.normal, dtype=np.float64)
        al = np.asarray(self.albedo, dtype=np.float64)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ParameterError("surface point must be a finite 3-vector")
        if al.shape != (3,) or not (np.all(al >= 0) and np.all(al <= 1)):
            raise ParameterError(f"surface albedo must be 3 values in [0, 1], got {self.albedo}")
        if self.kind == "sphere" and not (np.isfinite(self.size) and self.size > 0):
            raise ParameterError(f"sphere radius must be > 0, got {self.size}")
        if self.kind == "plane" and (n.shape != (3,) or not np.isfinite(n).all() or np.linalg.norm(n) == 0):
            raise ParameterError("plane normal must be a finite non-zero 3-vector")

    def row(self) -> np.ndarray:
        """The kernel's row (:func:`headsim.hair.render._kernels_trace.surface_hit`)."""
        if self.kind == "sphere":
            shape = [0.0, *map(float, self.point), float(self.size), 0.0, 0.0]
        else:
            n = np.asarray(self.normal, dtype=np.float64)
            shape = [1.0, *map(float, self.point), *(n / np.linalg.norm(n))]
        return np.array(shape + list(map(float, self.albedo)))


@dataclass(frozen=True, eq=False)
class MeshSurface:
    """An opaque diffuse (Lambertian) triangle mesh drawn with the fibres (e.g. a head or a terrain): ``vertices``
    (n, 3) m, ``triangles`` (m, 3) vertex indices, ``albedo`` RGB in [0, 1]. Shaded with its vertex normals
    (trimesh's, interpolated across each triangle; either winding), otherwise as :class:`Surface`."""

    vertices: np.ndarray
    triangles: np.ndarray
    albedo: tuple = (0.5, 0.5, 0.5)

    def __post_init__(self):
        v = np.asarray(self.vertices, dtype=np.float64)
        t = np.asarray(self.triangles)
        al = np.asarray(self.albedo, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0 or not np.isfinite(v).all():
            raise ParameterError(f"mesh surface vertices must be a non-empty finite (n, 3) array, got shape {v.shape}")
        if (t.ndim != 2 or t.shape[1] != 3 or len(t) == 0 or not np.issubdtype(t.dtype, np.integer)
                or t.min() < 0 or t.max() >= len(v)):
            raise ParameterError(f"mesh surface triangles must be a non-empty (m, 3) array of vertex indices in "
                                 f"[0, {len(v) - 1}]")
        if al.shape != (3,) or not (np.all(al >= 0) and np.all(al <= 1)):
            raise ParameterError(f"surface albedo must be 3 values in [0, 1], got {self.albedo}")


def _kernel_mesh(meshes: Sequence[MeshSurface]) -> tuple:
    """The tracer's ``mesh`` tuple (:mod:`headsim.hair.render._kernels_trace`) of all ``meshes`` in one tree
    (empty arrays: none)."""
    if not meshes:
        return (np.zeros((0, 3, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64),
                np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)),
                np.zeros((0, 3)), np.ones(1, np.int64))
    import trimesh

    from headsim.collide.bvh import TriangleBVH

    vs, ts, albedo, corner, geo = [], [], [], [], []
    n0 = 0
    for m in meshes:
        v = np.asarray(m.vertices, dtype=np.float64)
        t = np.asarray(m.triangles, dtype=np.int64)
        tm = trimesh.Trimesh(v, t, process=False)  # face normals, and vertex normals weighted by the corner angles
        corner.append(np.asarray(tm.vertex_normals)[t])
        geo.append(np.asarray(tm.face_normals))
        albedo.append(np.broadcast_to(np.asarray(m.albedo, dtype=np.float64), (len(t), 3)))
        vs.append(v)
        ts.append(t + n0)
        n0 += len(v)
    bvh = TriangleBVH(np.concatenate(vs), np.concatenate(ts))
    *arrays, stack = bvh.ray_arrays
    return (*arrays, np.ascontiguousarray(np.concatenate(corner)),
            np.ascontiguousarray(np.concatenate(geo)), np.ascontiguousarray(np.concatenate(albedo)),
            np.array([stack], np.int64))


@dataclass(frozen=True)
class RenderOptions:
    """width, height : pixels; spp : samples per pixel; max_scatter : fibre scattering orders (1–16);
    env : constant environment radiance RGB seen by scattered rays; background : RGB of camera misses;
    seed : sampler seed; rows_per_block : progress granularity; rr_depth : path segment from which
    Russian roulette starts (Mitsuba's default 5; a large value disables it); near_field : shade with
    the near-field lobes at the hit's offset across the fibre width (close-ups, Sobottka §6.4)."""

    width: int = 256
    height: int = 256
    spp: int = 16
    max_scatter: int = 4
    env: tuple = (0.0, 0.0, 0.0)
    background: tuple = (0.0, 0.0, 0.0)
    seed: int = 0
    rows_per_block: int = 16
    rr_depth: int = 5
    near_field: bool = False

    def __post_init__(self):
        if not (1 <= self.width <= 16384 and 1 <= self.height <= 16384):
            raise ParameterError(f"image size must be 1 … 16384 pixels, got {self.width}×{self.height}")
        if not (1 <= self.spp <= 1 << 16):
            raise ParameterError(f"spp must be in [1, 65536], got {self.spp}")
        if self.rr_depth < 1:
            raise ParameterError(f"rr_depth must be ≥ 1, got {self.rr_depth}")
        if not (1 <= self.max_scatter <= 16):
            raise ParameterError(f"max_scatter must be in [1, 16], got {self.max_scatter}")
        for name in ("env", "background"):
            c = np.asarray(getattr(self, name), dtype=np.float64)
            if c.shape != (3,) or not np.isfinite(c).all() or np.any(c < 0):
                raise ParameterError(f"{name} must be 3 finite values ≥ 0")


@dataclass(frozen=True, eq=False)
class RenderResult:
    """image : (H, W, 3) float64 linear radiance; wall / cpu : seconds (trace only); build : BVH seconds."""

    image: np.ndarray
    wall: float
    cpu: float
    build: float


def _mixture(params: MarschnerParams) -> np.ndarray:
    w = np.maximum(params.lobe_weights, 0.02)
    w = 0.9 * w / w.sum()
    return np.concatenate([[0.1], w])


def render(fibres: FibreAssembly | CapsuleBVH, params: MarschnerParams, camera: Camera,
           lights: list[Light] | tuple[Light, ...], options: RenderOptions = RenderOptions(),
           progress: Callable[[int, int], None] | None = None,
           surfaces: Sequence[Surface | MeshSurface] = ()) -> RenderResult:
    """Path-trace the fibres (Marschner far field, NEE with shadow rays, lobe importance sampling), with
    ``surfaces`` (:class:`Surface`, :class:`MeshSurface`: e.g. the obstacle the fibres lie on) drawn as opaque
    diffuse surfaces.

    ``fibres`` may be a prebuilt :class:`CapsuleBVH` to render several frames of one assembly."""
    t0 = time.perf_counter()
    bvh = fibres if isinstance(fibres, CapsuleBVH) else CapsuleBVH.from_fibres(fibres)
    build = time.perf_counter() - t0
    if not lights and not any(options.env):
        raise ParameterError("the scene needs at least one light or a non-zero environment")
    light_rows = np.array([l.row() for l in lights], dtype=np.float64).reshape(-1, 7)
    h, w = options.height, options.width
    img = np.zeros((h, w, 3))
    cam = camera.packed(w, h)
    prm = np.array(params.packed)
    ztab = np.array(params.ztab)
    gtab = np.array(params.gtab)
    mixp = _mixture(params)
    env = np.asarray(options.env, dtype=np.float64)
    bg = np.asarray(options.background, dtype=np.float64)
    for sf in surfaces:
        if not isinstance(sf, (Surface, MeshSurface)):
            raise ParameterError(f"surfaces must be Surface or MeshSurface objects, got {type(sf).__name__}")
    surface_rows = np.array([sf.row() for sf in surfaces if isinstance(sf, Surface)],
                            dtype=np.float64).reshape(-1, 10)
    mesh = _kernel_mesh([sf for sf in surfaces if isinstance(sf, MeshSurface)])
    t1 = time.perf_counter()
    c1 = time.process_time()
    for r0 in range(0, h, options.rows_per_block):
        r1 = min(h, r0 + options.rows_per_block)
        _k.render_rows(r0, r1, h, w, options.spp, options.seed, cam, prm, ztab, gtab, mixp, light_rows, env, bg,
                       options.max_scatter, options.rr_depth, bool(options.near_field), *bvh.arrays, surface_rows, mesh,
                       img)
        if progress is not None:
            progress(r1, h)
    wall = time.perf_counter() - t1
    cpu = time.process_time() - c1
    if not np.isfinite(img).all():
        raise ParameterError("render produced non-finite radiance (check light and parameter values)")
    return RenderResult(image=img, wall=wall, cpu=cpu, build=build)


def to_srgb8(image: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear radiance (H, W, 3) → sRGB uint8 (clipped) after multiplying by ``exposure``."""
    x = np.clip(np.asarray(image, dtype=np.float64) * exposure, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (s * 255 + 0.5).astype(np.uint8)


def save_png(path, image: np.ndarray, exposure: float = 1.0) -> None:
    """Write the image as PNG (sRGB, 8 bit) via matplotlib."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    plt.imsave(str(path), to_srgb8(image, exposure))
