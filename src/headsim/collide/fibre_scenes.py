"""Synthetic fibre arrangements: stand-ins for the test models of Sobottka 2008, Fig. 7.7 / §7.4.

The thesis' models are not available; these generators reproduce their fibre and segment counts
(digest §11). All lengths in m; every generator is deterministic for a given ``seed``.

* :func:`strand_scene` — a Tress-type strand: roots in a disc at a given root density (325 /cm²),
  fibres hanging along −y, gently swaying, converging towards the tip (the strand is pinched), with
  a small random walk; optional curl (helical fibres, "Locke").
* :func:`soup_scene` — "Filament Soup": persistent random walks in the unit cube.
* :func:`loop_frames` — the B4 loop deformation: a straight bundle along z bent into a loop over
  ``n_steps`` steps, with a small random perturbation per fibre (a kinematic stand-in for the
  thesis' static Cosserat solves).
* :func:`head_scene` — a full head: roots sampled on the scalp of the bundled head (above a height
  cut and behind the hairline) at the root density, fibres grown as gravity-draped random walks and
  kept outside the head with its signed distance field.
"""

from __future__ import annotations

import numpy as np

from headsim.collide.fibres import FibreSet
from headsim.errors import ParameterError

__all__ = ["strand_scene", "soup_scene", "loop_frames", "head_scene", "head_field_band", "ROOT_DENSITY"]

#: roots per m² (325 roots/cm², Sobottka §7.4)
ROOT_DENSITY = 325.0e4


def _offsets(n_fibres, n_nodes):
    return np.arange(n_fibres + 1, dtype=np.int64) * n_nodes


def _disc(n, radius, rng):
    """n points in a disc of the given radius, sorted into rows so consecutive roots are neighbours."""
    r = radius * np.sqrt(rng.uniform(size=n))
    a = rng.uniform(0, 2 * np.pi, n)
    p = np.stack([r * np.cos(a), r * np.sin(a)], 1)
    rows = np.floor((p[:, 1] + radius) / (2 * radius) * max(1, int(np.sqrt(n)))).astype(int)
    order = np.lexsort((p[:, 0] * np.where(rows % 2 == 0, 1, -1), rows))
    return p[order]


def strand_scene(n_fibres: int, segments_per_fibre: int = 100, *, length: float = 0.2,
                 radius: float = 35e-6, density: float = ROOT_DENSITY, pinch: float = 0.5,
                 curl_radius: float = 0.0, curl_turns: float = 0.0, noise: float = 0.02,
                 seed: int = 0) -> FibreSet:
    """A hanging strand (Tress I/II, B1/B2 stand-in; with curl, "Locke").

    n_fibres roots in a disc of area ``n_fibres / density``; every fibre has ``segments_per_fibre``
    segments of length ``length / segments_per_fibre``. The cross-section shrinks linearly to
    ``pinch`` × its root size at the tip; ``noise`` is the random-walk step relative to the segment
    length; ``curl_radius``/``curl_turns`` make each fibre a helix around its own axis.
    """
    if n_fibres < 1 or segments_per_fibre < 1 or not length > 0 or not radius > 0 or not density > 0:
        raise ParameterError("strand needs ≥ 1 fibre, ≥ 1 segment, length, radius and density > 0")
    rng = np.random.default_rng(seed)
    n = segments_per_fibre + 1
    disc_r = np.sqrt(n_fibres / density / np.pi)
    roots = _disc(n_fibres, disc_r, rng)
    s = np.linspace(0.0, 1.0, n)
    scale = 1.0 - (1.0 - pinch) * s
    seg = length / segments_per_fibre
    x = roots[:, 0:1] * scale
    z = roots[:, 1:2] * scale
    y = -length * s[None, :].repeat(n_fibres, 0)
    sway = 0.03 * length * np.sin(np.pi * s)  # gentle common bend
    x = x + sway
    walk = np.cumsum(rng.normal(scale=noise * seg, size=(n_fibres, n, 3)), axis=1)
    walk -= walk[:, :1]
    pts = np.stack([x, y, z], -1) + walk
    if curl_radius > 0 and curl_turns > 0:
        phase = rng.uniform(0, 2 * np.pi, (n_fibres, 1))
        ang = 2 * np.pi * curl_turns * s[None, :] + phase
        ramp = np.minimum(1.0, 5 * s)[None, :]
        pts[..., 0] += curl_radius * ramp * np.cos(ang)
        pts[..., 2] += curl_radius * ramp * np.sin(ang)
    return FibreSet(pts.reshape(-1, 3), _offsets(n_fibres, n), radius)


def soup_scene(n_fibres: int = 10_000, segments_per_fibre: int = 100, *, segment_length: float = 0.01,
               radius: float = 4.5e-4, persistence: float = 0.8, seed: int = 0) -> FibreSet:
    """Filament Soup: persistent random walks in the unit cube (reflected at the walls)."""
    if n_fibres < 1 or segments_per_fibre < 1:
        raise ParameterError("soup needs ≥ 1 fibre and ≥ 1 segment")
    rng = np.random.default_rng(seed)
    n = segments_per_fibre + 1
    pts = np.empty((n_fibres, n, 3))
    pts[:, 0] = rng.uniform(size=(n_fibres, 3))
    d = rng.normal(size=(n_fibres, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for j in range(1, n):
        d = persistence * d + (1 - persistence) * rng.normal(size=(n_fibres, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        p = pts[:, j - 1] + segment_length * d
        out = (p < 0) | (p > 1)
        d = np.where(out, -d, d)
        pts[:, j] = np.clip(np.where(out, pts[:, j - 1] + segment_length * d, p), 0, 1)
    order = np.lexsort(np.round(pts[:, 0] * 8).T[::-1])  # roots in coarse cells: neighbours adjacent
    return FibreSet(pts[order].reshape(-1, 3), _offsets(n_fibres, n), radius)


def loop_frames(n_fibres: int = 150, segments_per_fibre: int = 100, n_steps: int = 100, *,
                length: float = 0.2, radius: float = 35e-6, density: float = ROOT_DENSITY,
                perturbation: float = 0.03, seed: int = 0):
    """B4: straight bundle along +z bent into a loop; yields (step, FibreSet) for step = 0 … n_steps.

    Every fibre is a circular arc of curvature κ = θ/L in the x–z plane (θ grows linearly to
    2π(1 + δ_f), δ_f a per-fibre random perturbation), offset across the bundle in the arc's
    normal/binormal frame, with a small helical rise in y so that the loop closes past itself.
    """
    rng = np.random.default_rng(seed)
    n = segments_per_fibre + 1
    disc_r = np.sqrt(n_fibres / density / np.pi)
    off = _disc(n_fibres, disc_r, rng)
    delta = perturbation * rng.normal(size=(n_fibres, 1))
    s = np.linspace(0.0, length, n)[None, :]
    jitter = rng.normal(scale=0.05 * disc_r, size=(n_fibres, n, 3))
    jitter[:, 0] = 0
    offsets = _offsets(n_fibres, n)
    for step in range(n_steps + 1):
        theta = 2 * np.pi * (step / n_steps) * (1 + delta)
        kappa = np.maximum(theta / length, 1e-12)
        ks = kappa * s
        cx = (1 - np.cos(ks)) / kappa
        cz = np.sin(ks) / kappa
        nx, nz = np.cos(ks), -np.sin(ks)
        rise = 4 * disc_r * (theta / (2 * np.pi)) * s / length
        x = cx + off[:, :1] * nx
        z = cz + off[:, :1] * nz
        y = off[:, 1:2] + rise + 0 * s
        pts = np.stack([x, y, z], -1) + jitter * (step / n_steps)
        yield step, FibreSet(pts.reshape(-1, 3), offsets, radius)


def scalp_roots(vertices, triangles, n_roots: int | None = None, *, density: float = ROOT_DENSITY,
                hairline_z: float = 0.06, seed: int = 0, min_spacing: float = 0.0):
    """Sample hair roots on the scalp of a head mesh (y up, +z forward, metres).

    The scalp is the set of triangles whose centroid lies behind ``hairline_z`` and above a height
    cut chosen so that the scalp area holds ``n_roots`` roots at ``density`` (if ``n_roots`` is None:
    the cut is at the ears' height, 55 % of the way up from the lowest to the highest vertex).
    Returns roots (n, 3) m and their outward unit normals (n, 3); roots are sorted by azimuth and
    height so consecutive roots are neighbours.

    ``min_spacing`` (m, default 0: independent uniform samples, as before): no two roots closer than this
    (dart throwing: area-uniform candidates, each kept when no kept root lies within ``min_spacing``).
    Independent samples put some roots closer than a fibre diameter (300 roots at 325 /cm²: 14 µm
    apart, against 70 µm fibres): fibres anchored there start overlapping at their roots, where no
    motion can separate them. Raises ParameterError when the scalp cannot hold ``n_roots`` roots that
    far apart (random sequential packing saturates at ≈ 0.55 of the area covered by disks of diameter
    ``min_spacing``).
    """
    v = np.asarray(vertices, float)
    t = np.asarray(triangles, np.int64)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    cr = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cr, axis=1)
    nrm = cr / np.maximum(2 * area, 1e-300)[:, None]
    cen = (a + b + c) / 3
    behind = (cen[:, 2] < hairline_z) & (nrm[:, 1] > -0.3)
    if n_roots is None:
        y_cut = v[:, 1].min() + 0.55 * (v[:, 1].max() - v[:, 1].min())
    else:
        want = n_roots / density
        ys = np.sort(cen[behind, 1])[::-1]
        acc = np.cumsum(area[behind][np.argsort(cen[behind, 1])[::-1]])
        i = int(np.searchsorted(acc, want))
        if i >= len(ys):
            raise ParameterError(f"the scalp cannot hold {n_roots} roots at {density / 1e4:g} /cm²")
        y_cut = ys[i]
    scalp = behind & (cen[:, 1] >= y_cut)
    total = area[scalp].sum()
    n = int(round(total * density)) if n_roots is None else int(n_roots)
    if not (np.isfinite(min_spacing) and min_spacing >= 0):
        raise ParameterError(f"min_spacing must be a finite length ≥ 0 m, got {min_spacing!r}")
    rng = np.random.default_rng(seed)
    ids = np.nonzero(scalp)[0]

    def sample(k):
        tri = rng.choice(ids, k, p=area[ids] / total)
        u, w = rng.uniform(size=(2, k))
        flip = u + w > 1
        u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
        return a[tri] + u[:, None] * (b[tri] - a[tri]) + w[:, None] * (c[tri] - a[tri]), nrm[tri]

    if min_spacing > 0:
        roots, normals = _spaced_samples(sample, n, float(min_spacing), total)
    else:
        roots, normals = sample(n)
    az = np.arctan2(roots[:, 0], roots[:, 2])
    band = np.floor((roots[:, 1] - roots[:, 1].min()) / 0.01).astype(int)
    order = np.lexsort((az * np.where(band % 2 == 0, 1, -1), band))
    return roots[order], normals[order]


_NEIGHBOUR_CELLS = [(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)]


def _has_neighbour(grid, points, p, cell, s2: float) -> bool:
    """Whether a point of ``points`` listed in ``grid`` (cell → indices, cells of edge √s2) lies within √s2
    of p (in cell ``cell``)."""
    for dx, dy, dz in _NEIGHBOUR_CELLS:
        for j in grid.get((cell[0] + dx, cell[1] + dy, cell[2] + dz), ()):
            d = p - points[j]
            if d @ d < s2:
                return True
    return False


def _spaced_samples(sample, n: int, spacing: float, area: float, max_candidates_per_root: int = 40):
    """n of the points drawn by ``sample(k) -> (points (k, 3), normals (k, 3))``, none two closer than
    ``spacing`` (m): dart throwing, candidates tested in their drawn order against the kept ones in a hash
    grid of cell ``spacing``. ``area``: the sampled area, m² (for the error message)."""
    kept_p, kept_n = [], []
    grid: dict[tuple[int, int, int], list[int]] = {}
    drawn = 0
    s2 = spacing * spacing
    while len(kept_p) < n:
        if drawn >= max_candidates_per_root * n:
            raise ParameterError(
                f"the scalp ({area * 1e4:.3g} cm²) cannot hold {n} roots at least {spacing * 1e3:.3g} mm apart "
                f"(placed {len(kept_p)} after {drawn} candidates); lower min_spacing or the number of roots")
        k = max(64, 2 * (n - len(kept_p)))
        pts, nrs = sample(k)
        drawn += k
        for p, nr in zip(pts, nrs):
            cell = np.floor(p / spacing).astype(np.int64)
            if not _has_neighbour(grid, kept_p, p, cell, s2):
                grid.setdefault(tuple(cell), []).append(len(kept_p))
                kept_p.append(p)
                kept_n.append(nr)
                if len(kept_p) == n:
                    break
    return np.array(kept_p), np.array(kept_n)


def head_field_band(layer_thickness: float = 0.04, radius: float = 35e-6) -> float:
    """Band half-width (m) a head distance field needs for :func:`head_scene`: layer + 2 r + 5 mm.

    Outside its narrow band a grid field holds a constant far value, so a clearance beyond the band
    would be read wrongly (and push nodes far out)."""
    return float(layer_thickness + 2 * radius + 0.005)


def head_scene(n_fibres: int | None = 49_000, segments_per_fibre: int = 49, *, length: float = 0.12,
               radius: float = 35e-6, density: float = ROOT_DENSITY, gravity: float = 0.25,
               noise: float = 0.15, layer_thickness: float = 0.04, climb: float = 0.5,
               push_iterations: int = 10, field=None, seed: int = 0) -> FibreSet:
    """Full-head hair (Charming stand-in: 49 k fibres, 2.4 M segments at 325 roots/cm²).

    Roots from :func:`scalp_roots` on the bundled head; each fibre starts along the skin normal and
    bends towards −y (weight ``gravity``) with a random walk (``noise``); every node is pushed out of
    the head to Φ ≥ 2r + c_f with the head's distance field (built if ``field`` is None), where the
    clearance c_f grows linearly with the root's height rank up to ``layer_thickness``, so hair from
    the crown lies over hair from lower down, as combed hair does. Along a fibre the clearance rises
    by at most ``climb`` segment lengths per segment, and after every push-out the node is put back
    at the segment length from its predecessor: all segments have length ``length /
    segments_per_fibre`` (inextensible fibres), and the clearance is reached where the fibre can
    climb to it (up to ``push_iterations`` push-outs per node, so a node may stay a little below its
    target).
    """
    from headsim.data import head_path

    import trimesh

    from headsim.collide.distance_field import GridDistanceField

    mesh = trimesh.load(head_path(), process=False)
    v, t = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    need = head_field_band(layer_thickness, radius)
    if field is None:
        field = GridDistanceField.from_mesh(v, t, 0.003, band=need)
    elif getattr(field, "band", np.inf) < need:
        raise ParameterError(
            f"the head field's band ({field.band * 1e3:.1f} mm) must cover the hair layer: ≥ {need * 1e3:.1f} mm "
            "(beyond the band the field reads a constant far value; see head_field_band)")
    roots, normals = scalp_roots(v, t, n_fibres, density=density, seed=seed)
    rng = np.random.default_rng(seed + 1)
    nf = len(roots)
    n = segments_per_fibre + 1
    seg = length / segments_per_fibre
    pts = np.empty((nf, n, 3))
    pts[:, 0] = roots
    d = normals.copy()
    down = np.array([0.0, -1.0, 0.0])
    rank = np.argsort(np.argsort(roots[:, 1])) / max(nf - 1, 1)
    clearance = 2 * radius + layer_thickness * rank
    for j in range(1, n):
        d = d + gravity * down + noise * rng.normal(size=(nf, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        p = pts[:, j - 1] + seg * d
        # the clearance rises by at most climb × seg per segment, so the fibre can follow it
        target = np.minimum(clearance, 2 * radius + climb * seg * j)
        for _ in range(push_iterations):
            phi = field.distance(p)
            inside = phi < target
            if not inside.any():
                break
            g = field.normal(p[inside])
            p[inside] += (target[inside] - phi[inside])[:, None] * g
            # slide: keep the direction tangential to the skin
            dn = (d[inside] * g).sum(1, keepdims=True)
            d[inside] -= np.minimum(dn, 0) * g
            d[inside] /= np.linalg.norm(d[inside], axis=1, keepdims=True)
            # inextensible: back to the segment length along the pushed-out direction
            step = p[inside] - pts[inside, j - 1]
            p[inside] = pts[inside, j - 1] + seg * step / np.linalg.norm(step, axis=1, keepdims=True)
        pts[:, j] = p
    return FibreSet(pts.reshape(-1, 3), _offsets(nf, n), radius)
