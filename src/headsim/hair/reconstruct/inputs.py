"""Inputs of the reconstruction (Sobottka 2008 §5.2, §5.3.1): the scalp S_S, the hair-volume surface S_H,
the head (obstacle) and their distance fields.

* :func:`load_inputs` — scalp and hair-volume meshes from files (any format :mod:`headsim.mesh.io` reads,
  units stated); the head obstacle is the scalp itself unless a head mesh is given.
* :func:`bundled_inputs` — the bundled ICT head: the scalp region is cut from the skin above a hairline,
  and the hair volume is generated from it (the seed's "offset surface" route): ``short`` = the set of
  points within ``thickness`` of the scalp; ``long`` = a straight bob, the same offset shell swept straight
  down (hair hanging under gravity) and cut by a horizontal plane at jaw height and a frontal plane in
  front of the cheeks. The surface is extracted by marching cubes (libigl).
* :func:`boundary_fields` — narrow-band signed distance grids (eq. 5.3) of the head and of S_H, negative
  inside, with the band wide enough to hold the immersion depths.

Metres, y up, +z out of the face.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.errors import MeshError, ParameterError
from headsim.mesh.surface import SurfaceMesh

__all__ = ["StyleInputs", "STYLES", "load_inputs", "bundled_scalp", "hair_volume", "bundled_inputs", "boundary_fields"]

STYLES = {
    # thickness of the hair layer over the scalp (m), hair length (m), bob cut height (m) or None
    "short": {"thickness": 0.022, "length": 0.07, "cut_y": None},
    "long": {"thickness": 0.030, "length": 0.26, "cut_y": -0.06},
}


@dataclass(frozen=True, eq=False)
class StyleInputs:
    """scalp: open disk-like growth region; volume: closed outer hair surface S_H (outward normals);
    head: the obstacle the fibres must stay out of (closed or open skin, outward normals); description."""

    scalp: SurfaceMesh
    volume: SurfaceMesh
    head: SurfaceMesh
    description: str


def _largest_component(triangles: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Boolean mask of the largest edge-connected component among the triangles selected by ``keep``."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    ids = np.flatnonzero(keep)
    t = triangles[ids]
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    e.sort(axis=1)
    owner = np.tile(np.arange(len(ids)), 3)
    order = np.lexsort((e[:, 1], e[:, 0]))
    e, owner = e[order], owner[order]
    same = np.all(e[1:] == e[:-1], axis=1)
    a, b = owner[:-1][same], owner[1:][same]
    g = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(len(ids), len(ids)))
    _, lab = connected_components(g, directed=False)
    big = np.bincount(lab).argmax()
    out = np.zeros(len(triangles), bool)
    out[ids[lab == big]] = True
    return out


def bundled_scalp(head: SurfaceMesh, *, back_y: float = -0.035, front_y: float = 0.085,
                  back_z: float = -0.09, front_z: float = 0.10) -> SurfaceMesh:
    """The scalp of the bundled head: outward-facing skin triangles above a hairline that rises linearly
    from ``back_y`` at z = ``back_z`` (nape) to ``front_y`` at z = ``front_z`` (forehead), m. The largest
    connected piece is kept and enclosed islands are filled, so the result is a topological disk."""
    v, t = head.vertices, head.triangles
    cen = v[t].mean(axis=1)
    nrm = head.face_normals
    mid = 0.5 * (v.min(0) + v.max(0))
    w = np.clip((cen[:, 2] - back_z) / (front_z - back_z), 0.0, 1.0)
    y_cut = back_y + w * (front_y - back_y)
    keep = (cen[:, 1] > y_cut) & (np.einsum("ij,ij->i", nrm, cen - mid) > 0)
    keep = _largest_component(t, keep)
    rest = _largest_component(t, ~keep)  # the rest of the head; anything else is an island inside the scalp
    keep = ~rest
    used = np.unique(t[keep])
    remap = -np.ones(len(v), np.int64)
    remap[used] = np.arange(len(used))
    scalp = SurfaceMesh(v[used], remap[t[keep]], name="bundled scalp")
    if len(scalp.boundary_loops) != 1:
        raise MeshError(f"the scalp cut has {len(scalp.boundary_loops)} boundary loops; expected one")
    return scalp


def _grid(lower, upper, spacing):
    dims = np.ceil((upper - lower) / spacing).astype(int) + 1
    axes = [lower[c] + spacing * np.arange(dims[c]) for c in range(3)]
    return axes, dims


def hair_volume(scalp: SurfaceMesh, style: str = "short", *, thickness: float | None = None,
                cut_y: float | None = None, front_z: float = 0.055, spacing: float = 0.005) -> SurfaceMesh:
    """Closed outer hair surface S_H generated from the scalp (offset surface; see the module docstring).

    thickness m (default from :data:`STYLES`); cut_y: bob cut height, m (``long`` only); front_z: the
    hanging part is kept behind this plane (m) so the face stays free; spacing: marching-cubes grid, m.
    """
    import igl

    if style not in STYLES:
        raise ParameterError(f"unknown style {style!r}; choose one of {', '.join(STYLES)}")
    th = STYLES[style]["thickness"] if thickness is None else float(thickness)
    cut = STYLES[style]["cut_y"] if cut_y is None else cut_y
    if not th > 0:
        raise ParameterError("hair-volume thickness must be > 0 m")
    v = scalp.vertices
    lower = v.min(0) - th - 2 * spacing
    upper = v.max(0) + th + 2 * spacing
    if style == "long":
        lower[1] = min(lower[1], cut - 2 * spacing)
    axes, dims = _grid(lower, upper, spacing)
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    pts = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    d2, _, _ = igl.point_mesh_squared_distance(pts, v, scalp.triangles.astype(np.int64))
    f = (np.sqrt(d2) - th).reshape(tuple(dims))
    if style == "long":
        # hanging curtain: the shell swept straight down (cumulative minimum from the top), cut below and in front
        sweep = np.minimum.accumulate(f[:, ::-1, :], axis=1)[:, ::-1, :]
        sweep = np.maximum(sweep, cut - Y)
        sweep = np.maximum(sweep, Z - front_z)
        f = np.minimum(f, sweep)
    f[[0, -1], :, :] = spacing  # close the surface at the grid border
    f[:, [0, -1], :] = spacing
    f[:, :, [0, -1]] = spacing
    # libigl's grid order is x fastest
    S = np.ascontiguousarray(f.transpose(2, 1, 0).ravel())
    GV = np.column_stack([X.transpose(2, 1, 0).ravel(), Y.transpose(2, 1, 0).ravel(), Z.transpose(2, 1, 0).ravel()])
    Vm, Fm, _ = igl.marching_cubes(S, GV, int(dims[0]), int(dims[1]), int(dims[2]), 0.0)
    Vm = np.asarray(Vm, float)
    Fm = np.asarray(Fm, np.int64)
    Vm, _, J, Fm = igl.remove_duplicate_vertices(Vm, Fm, 1e-9 * spacing)
    Fm = Fm[(Fm[:, 0] != Fm[:, 1]) & (Fm[:, 1] != Fm[:, 2]) & (Fm[:, 0] != Fm[:, 2])]
    used = np.unique(Fm)
    remap = -np.ones(len(Vm), np.int64)
    remap[used] = np.arange(len(used))
    mesh = SurfaceMesh(Vm[used], remap[Fm], name=f"{style} hair volume")
    if mesh.signed_volume() < 0:
        mesh = SurfaceMesh(mesh.vertices, mesh.triangles[:, ::-1], name=mesh.name)
    return mesh


def bundled_inputs(style: str = "short") -> StyleInputs:
    """Scalp, generated hair volume and head obstacle on the bundled ICT head."""
    import trimesh

    from headsim.data import head_path

    if style not in STYLES:
        raise ParameterError(f"unknown demo style {style!r}; choose one of {', '.join(STYLES)}")
    m = trimesh.load(head_path(), process=False)
    head = SurfaceMesh(np.asarray(m.vertices, float), np.asarray(m.faces, np.int64), name="bundled head")
    scalp = bundled_scalp(head)
    return StyleInputs(scalp, hair_volume(scalp, style), head,
                       f"bundled ICT head, {style} style (generated hair volume)")


def load_inputs(scalp_path, volume_path, units: str = "m", head_path=None) -> StyleInputs:
    """Scalp and hair-volume meshes from files (units ``m``, ``cm`` or ``mm``). The head obstacle is the
    optional ``head_path`` mesh, else the scalp itself (fibres must not cross it)."""
    from headsim.mesh.io import load_surface

    scalp = load_surface(scalp_path, units)
    volume = load_surface(volume_path, units)
    if not volume.is_closed:
        raise MeshError(f"{volume_path}: the hair volume must be a closed surface")
    if volume.signed_volume() < 0:
        volume = SurfaceMesh(volume.vertices, volume.triangles[:, ::-1], name=volume.name)
    head = load_surface(head_path, units) if head_path is not None else scalp
    return StyleInputs(scalp, volume, head, f"scalp {scalp_path}, volume {volume_path} ({units})")


def signed_field(mesh: SurfaceMesh, spacing: float, band: float):
    """Narrow-band signed distance grid of a mesh (:meth:`GridDistanceField.from_mesh`, exact inside the band),
    with the sign of the nodes outside the band taken from the generalised winding number evaluated on every
    third node and copied to its neighbours: a far node lies more than ``band`` >= 3 spacing from the surface,
    so its coarse neighbour (at most 1.5 sqrt(3) spacing away) is on the same side."""
    import igl

    from headsim.collide.distance_field import GridDistanceField

    if band < 3 * spacing:
        raise ParameterError("band must be at least 3 grid spacings")
    f = GridDistanceField.from_mesh(mesh.vertices, mesh.triangles, spacing, band=band, far_sign="positive")
    vals = f.values.copy()
    shape = np.array(vals.shape)
    coarse = [np.arange(0, n, 3) for n in shape]
    G = np.stack(np.meshgrid(*coarse, indexing="ij"), -1).reshape(-1, 3)
    wn = igl.fast_winding_number(np.ascontiguousarray(mesh.vertices), np.ascontiguousarray(mesh.triangles),
                                 f.origin + spacing * G.astype(float))
    inside_c = (wn > 0.5).reshape([len(c) for c in coarse])
    idx = [np.minimum(np.rint(np.arange(n) / 3).astype(int), len(c) - 1) for n, c in zip(shape, coarse)]
    inside = inside_c[np.ix_(*idx)]
    far = np.abs(vals) > band
    vals[far & inside] = -f.far
    return GridDistanceField(f.origin, spacing, vals, band, f.far)


def boundary_fields(inputs: StyleInputs, head_spacing: float = 0.003, hair_spacing: float = 0.004,
                    depth: float = 0.012):
    """(head field, hair-volume field): narrow-band signed distance grids (eq. 5.3) of half-width
    4 spacings around the head and ``depth`` + 2 spacings around S_H (m), negative inside."""
    head = signed_field(inputs.head, head_spacing, 4 * head_spacing)
    hair = signed_field(inputs.volume, hair_spacing, max(depth + 2 * hair_spacing, 3 * hair_spacing))
    return head, hair
