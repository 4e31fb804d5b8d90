"""Volumetric soft-tissue layer under an open face surface (Heinze §2.3, §2.3.1).

Heinze fills the hollow face scan with a regular tetrahedral grid and makes the mass points deeper
than the tissue thickness (1 cm, from CT measurements around the nose) below the skin rigid
("bone"). Here the same model — a tissue layer of given thickness whose deep side is fixed bone —
is built directly and conformingly from the skin triangles: every skin triangle is extruded inwards
into ``layers`` prisms along smoothed inward vertex normals, and every prism is split into three
positively oriented tetrahedra by the global-vertex-index rule (Dompierre et al. 1999), so that
neighbouring prisms split their shared quad faces along the same diagonal.

Vertex numbering: vertex ``j * n + i`` is skin vertex ``i`` (``n`` skin vertices) at depth
``j / layers * thickness[i]``; layer 0 is the skin, layer ``layers`` is the bone surface
(``fixed=True``, ``vertex_region == REGION_BONE``). The skin is the face mesh itself, vertex for
vertex, unless triangles had to be trimmed (below); ``TissueLayer.face_vertex_ids`` maps skin ids to
face ids in every case (increasing, so the order is kept; for the bundled neutral face about 340 of
9,409 vertices, at the eyelid and lip margins, are left out).

Where the requested thickness does not fit, it is reduced locally and the reduction reported
(:class:`TissueLayer`):

* the skin faces another part of itself (eyelids, lips, nostrils): at most half the distance along
  the inward direction to the next skin sheet (embree ray casts), and the bone point must stay at
  least half its thickness away from every skin point (libigl AABB distance);
* the surface curves so sharply that the inward offset folds (nose ridge and tip, eye corners): the
  thickness at the vertices of any prism with a flat or inverted tet shrinks by a factor until every
  tet keeps ``min_volume_ratio`` of its straight-prism volume;
* the thickness field is then limited to a bounded slope along the skin (a multi-source Dijkstra),
  so the bone surface stays smooth.

Triangles where no direction field can be extruded at all (the skin folds back on itself by nearly
180°, as at the inner lips of the mouth corners), or where the thickness would have to fall below
``min_thickness_fraction`` of the request (eyelid and lip margins), are trimmed from the skin and
reported; with ``TissueOptions(trim_folds=False)`` a :class:`~headsim.errors.MeshError` names the
place instead. Every tet is positive (``TetMesh`` refuses anything else).

Limitations: self-intersection of the bone surface is prevented only through the two clearance
tests above (rays along the inward directions, nearest skin distance of the bone points), not by an
exact intersection test between distant tets.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from headsim.errors import MeshError, ParameterError
from headsim.mesh.geometry import vertex_normals
from headsim.mesh.surface import SurfaceMesh
from headsim.mesh.tet import REGION_BONE, REGION_TISSUE, TetMesh


@dataclass(frozen=True)
class TissueOptions:
    """Options of :func:`extrude_tissue_layer`.

    normal_smoothing : Laplacian smoothing passes over the inward directions (each pass averages a
        vertex's direction with the mean of its neighbours').
    min_direction_cosine : every skin triangle must see the inward directions of its three vertices
        within arccos(this) of its own inward normal; triangles that do not (where the skin folds back
        on itself by nearly 180 deg, e.g. the inner lip at the mouth corners) are trimmed when
        ``trim_folds`` is set, otherwise refused.
    trim_folds : drop such fold triangles, and those where the tissue would be thinner than
        ``min_thickness_fraction`` of the request (reported), instead of raising MeshError.
    clearance_fraction : the thickness at a vertex is at most this fraction of the distance along
        its inward direction to the next skin sheet (0.5: two facing sheets share the gap).
    max_thickness_slope : bound on |dh/ds| of the thickness field along the skin (m per m).
    min_depth_ratio : the bone point of a vertex must lie at least this fraction of its thickness
        away from every skin point (catches offsets that cross another sheet of skin).
    min_volume_ratio : a tet is accepted when its volume is at least this fraction of
        (top-triangle area x layer depth / 3), the volume it would have in a straight prism.
    reduction_factor : thickness multiplier per repair round at the vertices of rejected prisms.
    min_thickness_fraction : where the thickness would fall below this fraction of the request, the
        skin triangles there are trimmed (or MeshError when ``trim_folds`` is False).
    max_rounds : thickness-reduction rounds before giving up (MeshError).
    """

    normal_smoothing: int = 10
    min_direction_cosine: float = 0.2
    trim_folds: bool = True
    clearance_fraction: float = 0.5
    max_thickness_slope: float = 0.5
    min_depth_ratio: float = 0.5
    min_volume_ratio: float = 0.1
    reduction_factor: float = 0.8
    min_thickness_fraction: float = 0.1
    max_rounds: int = 60

    def __post_init__(self):
        if self.normal_smoothing < 0:
            raise ParameterError(f"normal_smoothing must be >= 0, got {self.normal_smoothing}")
        for name in ("clearance_fraction", "reduction_factor", "min_thickness_fraction", "min_direction_cosine",
                     "min_depth_ratio"):
            val = getattr(self, name)
            if not 0.0 < val <= 1.0:
                raise ParameterError(f"{name} must be in (0, 1], got {val}")
        if not self.max_thickness_slope > 0:
            raise ParameterError(f"max_thickness_slope must be > 0, got {self.max_thickness_slope}")
        if not 0.0 < self.min_volume_ratio < self.min_direction_cosine:
            raise ParameterError(
                f"min_volume_ratio must be in (0, min_direction_cosine = {self.min_direction_cosine}), "
                f"got {self.min_volume_ratio}")


@dataclass(frozen=True, eq=False)
class TissueLayer:
    """A tissue layer built by :func:`extrude_tissue_layer`.

    mesh : TetMesh; tet_region REGION_TISSUE, vertex_region REGION_BONE on the bone layer, fixed there
    n_skin : n, vertices of the face (= skin vertices 0..n-1 of ``mesh``)
    layers : k
    thickness : (n,) float64, m, thickness used at each face vertex
    requested_thickness : (n,) float64, m
    inward : (n, 3) float64, unit inward direction at each face vertex
    reduced_by_clearance : (n,) bool, thinner because the skin faces itself nearby
    reduced_by_shape : (n,) bool, thinner because the prisms would fold (curvature)
    skin_triangles : (m, 3) int64, the skin triangles (skin ids): the face's, less trimmed folds
    face_vertex_ids : (n,) int64, face vertex id of each skin vertex (arange(n) when nothing was trimmed
        away completely)
    trimmed_triangles : (t,) int64, ids of face triangles left out at folds (see TissueOptions)
    rounds : repair rounds used
    """

    mesh: TetMesh
    n_skin: int
    layers: int
    thickness: np.ndarray
    requested_thickness: np.ndarray
    inward: np.ndarray
    reduced_by_clearance: np.ndarray
    reduced_by_shape: np.ndarray
    skin_triangles: np.ndarray
    face_vertex_ids: np.ndarray
    trimmed_triangles: np.ndarray
    rounds: int

    @property
    def skin_vertex_ids(self) -> np.ndarray:
        """(n,) int64 tet-mesh ids of the skin vertices; equal to the face vertex ids."""
        return np.arange(self.n_skin, dtype=np.int64)

    @property
    def bone_vertex_ids(self) -> np.ndarray:
        """(n,) int64 tet-mesh ids of the bone vertices (bone vertex of face vertex i)."""
        return self.layers * self.n_skin + np.arange(self.n_skin, dtype=np.int64)

    @property
    def reduced(self) -> np.ndarray:
        """(n,) bool, vertices where the thickness is below the request."""
        return self.thickness < self.requested_thickness * (1.0 - 1e-12)

    def skin_id_of_face_vertex(self, n_face_vertices: int) -> np.ndarray:
        """(n_face,) int64: the tet-mesh (skin) id of each face vertex, -1 where it was trimmed away."""
        out = -np.ones(int(n_face_vertices), dtype=np.int64)
        out[self.face_vertex_ids] = np.arange(self.n_skin)
        return out

    def skin_surface(self) -> SurfaceMesh:
        return SurfaceMesh(self.mesh.vertices[: self.n_skin], self.skin_triangles, name=f"{self.mesh.name}[skin]")

    def bone_surface(self) -> SurfaceMesh:
        """The bone surface, oriented like the skin (normals towards the skin)."""
        return SurfaceMesh(self.mesh.vertices[self.bone_vertex_ids], self.skin_triangles, name=f"{self.mesh.name}[bone]")

    def summary(self) -> dict[str, float]:
        """Scalars for reports (SI units)."""
        red = self.reduced
        return {
            "n_vertices": self.mesh.n_vertices,
            "n_tets": self.mesh.n_tets,
            "n_fixed": int(self.mesh.fixed.sum()),
            "layers": self.layers,
            "volume": self.mesh.volume,
            "thickness_requested_max": float(self.requested_thickness.max()),
            "thickness_min": float(self.thickness.min()),
            "thickness_mean": float(self.thickness.mean()),
            "n_reduced": int(red.sum()),
            "n_reduced_clearance": int(self.reduced_by_clearance.sum()),
            "n_reduced_shape": int(self.reduced_by_shape.sum()),
            "n_trimmed_triangles": int(len(self.trimmed_triangles)),
            "rounds": self.rounds,
        }


# ----------------------------------------------------------------------------------------------
def prism_tets(triangles: np.ndarray, n_vertices: int, layers: int) -> np.ndarray:
    """Conforming split of the layered prisms into tets, positively oriented for an inward extrusion.

    triangles : (m, 3) skin triangles, counter-clockwise seen from outside (normal out of the body)
    Returns (3 * m * layers, 4) int64; vertex ``j * n + i`` is face vertex ``i`` in layer ``j``.

    Per prism with top vertex ids sorted p < q < r and bottom p', q', r', the quad faces are split
    along the diagonal from their smallest id (p-q', q-r', p-r'), which neighbours agree on, giving
    the tets (p, q, r, r'), (p, q', q, r'), (p, p', q', r').
    """
    t = np.asarray(triangles, dtype=np.int64)
    order = np.argsort(t, axis=1, kind="stable")
    s = np.take_along_axis(t, order, axis=1)
    # parity of the sorting permutation: even permutations keep the triangle's orientation
    inv = (order[:, 0] > order[:, 1]).astype(int) + (order[:, 0] > order[:, 2]) + (order[:, 1] > order[:, 2])
    even = inv % 2 == 0
    out = []
    for j in range(layers):
        p, q, r = (s[:, k] + j * n_vertices for k in range(3))
        p2, q2, r2 = p + n_vertices, q + n_vertices, r + n_vertices
        tets = np.stack([
            np.stack([p, q, r, r2], axis=1),
            np.stack([p, q2, q, r2], axis=1),
            np.stack([p, p2, q2, r2], axis=1),
        ], axis=1)                                             # (m, 3, 4)
        # for an even (counter-clockwise from outside) order these are negative: swap two vertices
        tets[even] = tets[even][:, :, [1, 0, 2, 3]]
        out.append(tets.reshape(-1, 4))
    return np.concatenate(out)


def smoothed_inward_directions(face: SurfaceMesh, passes: int) -> np.ndarray:
    """(n, 3) unit inward directions: minus the area-weighted vertex normals, Laplacian-smoothed."""
    d = -vertex_normals(face.vertices, face.triangles)
    adj = face.adjacency
    deg = np.maximum(np.asarray(adj.sum(axis=1)).ravel(), 1.0)
    for _ in range(passes):
        d = 0.5 * (d + (adj @ d) / deg[:, None])
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    return d


def trim_folds(face: SurfaceMesh, options: "TissueOptions") -> tuple[SurfaceMesh, np.ndarray, np.ndarray, np.ndarray]:
    """Drop triangles that no smoothed inward direction field can extrude (skin folded back).

    Repeats: smooth the inward directions, drop every triangle whose inward normal is more than
    arccos(``options.min_direction_cosine``) away from one of its vertices' directions.

    Returns
    -------
    skin : the kept surface
    face_vertex_ids : (n_skin,) int64, face id of each skin vertex
    trimmed : (t,) int64, face ids of the dropped triangles
    inward : (n_skin, 3) unit inward directions on ``skin``
    """
    tri_ids = np.arange(face.n_triangles)
    vert_ids = np.arange(face.n_vertices)
    skin = face
    for _ in range(100):
        inward = smoothed_inward_directions(skin, options.normal_smoothing)
        fn = -skin.face_normals
        cos = np.min([np.einsum("ij,ij->i", inward[skin.triangles[:, k]], fn) for k in range(3)], axis=0)
        bad = cos < options.min_direction_cosine
        if not bad.any():
            break
        if not options.trim_folds:
            i = int(skin.triangles[np.argmax(bad), 0])
            raise MeshError(
                f"{face.name}: the skin folds back on itself at {int(bad.sum())} triangles (first near "
                f"{np.array2string(skin.vertices[i] * 1e3, precision=1)} mm); no inward extrusion exists there"
            )
        tri = skin.triangles[~bad]
        if len(tri) == 0:
            raise MeshError(f"{face.name}: no triangle can be extruded inwards")
        used = np.unique(tri)
        remap = -np.ones(skin.n_vertices, dtype=np.int64)
        remap[used] = np.arange(len(used))
        skin = SurfaceMesh(skin.vertices[used], remap[tri], name=face.name)
        tri_ids = tri_ids[~bad]
        vert_ids = vert_ids[used]
    trimmed = np.setdiff1d(np.arange(face.n_triangles), tri_ids)
    return skin, vert_ids, trimmed, inward


def skin_clearance(face: SurfaceMesh, inward: np.ndarray) -> np.ndarray:
    """(n,) float64, m: distance along ``inward`` from each vertex to the next skin triangle not
    touching that vertex (inf where the ray leaves the face). Embree ray casts (trimesh/embreex)."""
    import trimesh

    tm = trimesh.Trimesh(face.vertices, face.triangles, process=False, validate=False)
    eps = 1e-9 * float(np.linalg.norm(face.extent))
    origins = face.vertices - eps * inward
    loc, ray_id, tri_id = tm.ray.intersects_location(origins, inward, multiple_hits=True)
    out = np.full(face.n_vertices, np.inf)
    if len(ray_id):
        dist = np.einsum("ij,ij->i", loc - face.vertices[ray_id], inward[ray_id])
        own = (face.triangles[tri_id] == ray_id[:, None]).any(axis=1)
        dist[own | (dist <= 0)] = np.inf
        np.minimum.at(out, ray_id, dist)
    return out


def limit_slope(h: np.ndarray, edges: np.ndarray, lengths: np.ndarray, slope: float) -> np.ndarray:
    """Largest field <= h with |h_i - h_j| <= slope * (path length from i to j along edges).

    h_i' = min_j (h_j + slope * d(i, j)): a multi-source shortest-path problem, solved by one
    Dijkstra run from a virtual source joined to every vertex j by an edge of weight h_j.
    """
    from scipy.sparse.csgraph import dijkstra

    n = len(h)
    src = np.full(n, n)
    rows = np.concatenate([edges[:, 0], edges[:, 1], src])
    cols = np.concatenate([edges[:, 1], edges[:, 0], np.arange(n)])
    w = np.concatenate([slope * lengths, slope * lengths, h])
    w = np.maximum(w, 1e-300)  # csgraph treats explicit zeros as missing edges
    g = sp.csr_matrix((w, (rows, cols)), shape=(n + 1, n + 1))
    return np.minimum(dijkstra(g, directed=True, indices=n)[:n], h)


def _layer_positions(x: np.ndarray, inward: np.ndarray, h: np.ndarray, layers: int) -> np.ndarray:
    depth = np.arange(layers + 1)[:, None, None] / layers * h[None, :, None]
    return (x[None] + depth * inward[None]).reshape(-1, 3)


def _sorted_corner_thickness(triangles: np.ndarray, h: np.ndarray) -> np.ndarray:
    """(m, 3) thickness at the vertices r, q, p (largest to smallest id) of each triangle: the
    vertex whose edge each of the three prism tets of :func:`prism_tets` stands on."""
    s = np.sort(triangles, axis=1)
    return h[s[:, ::-1]]


def _rejected_faces(pos, tets, triangles, area, h, layers, min_ratio, faces):
    """Bool mask over ``faces`` (ids): prisms with a tet below ``min_ratio`` of its straight-prism
    volume A h_v / (3 layers) (h_v the thickness at the vertex the tet stands on).

    pos : ((layers + 1) n, 3) layered positions; tets : all tets from :func:`prism_tets`."""
    m = len(triangles)
    rows = (np.arange(layers)[:, None, None] * 3 * m + 3 * faces[None, :, None] + np.arange(3)[None, None, :])
    t = tets[rows.ravel()]
    a = pos[t[:, 0]]
    vol = np.einsum("ij,ij->i", np.cross(pos[t[:, 1]] - a, pos[t[:, 2]] - a), pos[t[:, 3]] - a) / 6.0
    ref = area[faces, None] * _sorted_corner_thickness(triangles[faces], h) / (3.0 * layers)
    ratio = vol.reshape(layers, len(faces), 3) / ref[None]
    return (ratio < min_ratio).any(axis=(0, 2))


_CACHE: OrderedDict = OrderedDict()
_CACHE_SIZE = 8


def _key(face: SurfaceMesh, h: np.ndarray, layers: int, options: TissueOptions) -> str:
    d = hashlib.blake2b(digest_size=20)
    for a in (face.vertices, face.triangles, h):
        d.update(np.ascontiguousarray(a).tobytes())
    d.update(repr((layers, options, face.name)).encode())
    return d.hexdigest()


def _extrude(face: SurfaceMesh, h_face: np.ndarray, layers: int, options: TissueOptions):
    """Build the layer in one pass (see the module docstring).

    The inward directions are fixed once the fold triangles are trimmed; after that, trimming a
    triangle changes no other prism, so the prisms kept at the end passed every test as they are.
    The ray clearance is cast with the fuller skin, which can only make it smaller (conservative),
    and removing skin can only move it away from the bone points.

    Returns (skin, face_vertex_ids, inward, h, positions, tets, by_clearance, by_shape, rounds, trimmed)
    with ``trimmed`` the (m_face,) bool mask of face triangles left out.
    """
    skin, face_ids, fold_tris, inward = trim_folds(face, options)
    trimmed = np.zeros(face.n_triangles, dtype=bool)
    trimmed[fold_tris] = True
    skin_tri_ids = np.flatnonzero(~trimmed)               # face id of each skin triangle
    h_req = h_face[face_ids]
    floor = options.min_thickness_fraction * h_req
    n, m = skin.n_vertices, skin.n_triangles
    x = skin.vertices

    clearance = skin_clearance(skin, inward)
    by_clearance = options.clearance_fraction * clearance < h_req
    h = np.minimum(h_req, options.clearance_fraction * clearance)
    drop = h < floor                      # vertices whose triangles must be trimmed
    h = np.maximum(h, floor)
    edges = skin.edges
    lengths = np.linalg.norm(x[edges[:, 1]] - x[edges[:, 0]], axis=1)
    h = np.maximum(limit_slope(h, edges, lengths, options.max_thickness_slope), floor)

    tets = prism_tets(skin.triangles, n, layers)
    area = skin.triangle_areas
    by_shape = np.zeros(n, dtype=bool)
    rounds = 0
    check = np.arange(m)                  # faces to (re)check: all, then those whose thickness changed
    bad_faces = np.zeros(m, dtype=bool)
    shallow = np.zeros(n, dtype=bool)
    distance = _SkinDistance(skin)
    while True:
        pos = _layer_positions(x, inward, h, layers)
        bad_faces[check] = _rejected_faces(pos, tets, skin.triangles, area, h, layers,
                                           options.min_volume_ratio, check)
        bad_faces &= ~drop[skin.triangles].any(axis=1)
        check_v = np.unique(skin.triangles[check])
        shallow[check_v] = distance.depth_ratio(x[check_v] + h[check_v, None] * inward[check_v],
                                                h[check_v]) < options.min_depth_ratio
        shallow &= ~drop
        if not bad_faces.any() and not shallow.any():
            break
        rounds += 1
        if rounds > options.max_rounds:
            raise MeshError(f"{face.name}: the tissue thickness did not settle in {options.max_rounds} rounds")
        bad_vertices = np.union1d(np.unique(skin.triangles[bad_faces]), np.flatnonzero(shallow))
        stuck = h[bad_vertices] <= floor[bad_vertices] * (1 + 1e-12)
        drop[bad_vertices[stuck]] = True
        shrink = bad_vertices[~stuck]
        by_shape[np.intersect1d(shrink, np.unique(skin.triangles[bad_faces]))] = True
        by_clearance[shrink[shallow[shrink]]] = True
        h_old = h.copy()
        h[shrink] = np.maximum(h[shrink] * options.reduction_factor, floor[shrink])
        h = np.maximum(limit_slope(h, edges, lengths, options.max_thickness_slope), floor)
        check = np.flatnonzero((h != h_old)[skin.triangles].any(axis=1))

    if drop.any():
        thin = drop[skin.triangles].any(axis=1)
        if not options.trim_folds:
            i = int(skin.triangles[np.argmax(thin), 0])
            raise MeshError(
                f"{face.name}: the tissue layer would be thinner than {options.min_thickness_fraction:g} x the "
                f"requested thickness at {int(thin.sum())} triangles (first near "
                f"{np.array2string(x[i] * 1e3, precision=1)} mm): the skin faces itself or curves too sharply "
                "there; allow trimming (trim_folds=True) or smooth the surface"
            )
        if thin.all():
            raise MeshError(f"{face.name}: no part of the surface can carry the tissue layer")
        trimmed[skin_tri_ids[thin]] = True
        tri = skin.triangles[~thin]
        used = np.unique(tri)
        remap = -np.ones(n, dtype=np.int64)
        remap[used] = np.arange(len(used))
        skin = SurfaceMesh(x[used], remap[tri], name=face.name)
        face_ids, inward, h = face_ids[used], inward[used], h[used]
        by_clearance, by_shape = by_clearance[used], by_shape[used]
        tets = prism_tets(skin.triangles, skin.n_vertices, layers)
    pos = _layer_positions(skin.vertices, inward, h, layers)
    return skin, face_ids, inward, h, pos, tets, by_clearance, by_shape, rounds, trimmed


class _SkinDistance:
    """Distance from points to the skin surface (libigl AABB tree, built once)."""

    def __init__(self, skin: SurfaceMesh):
        import igl

        self.v = np.ascontiguousarray(skin.vertices)
        self.f = np.ascontiguousarray(skin.triangles)
        self.tree = igl.AABB()
        self.tree.init(self.v, self.f)

    def depth_ratio(self, bone: np.ndarray, h: np.ndarray) -> np.ndarray:
        """(k,) distance from bone points (k, 3) to the nearest skin point, over their thickness (k,).

        About 1 where the bone lies under its own skin; small where it comes close to another part
        of the skin (the offset crossed a nearby sheet: nostril wall, lip, eyelid)."""
        if len(bone) == 0:
            return np.ones(0)
        d2, _, _ = self.tree.squared_distance(self.v, self.f, np.ascontiguousarray(bone))
        return np.sqrt(d2) / h


def extrude_tissue_layer(
    face: SurfaceMesh,
    thickness: float | np.ndarray = 0.01,
    layers: int = 3,
    options: TissueOptions = TissueOptions(),
    *,
    use_cache: bool = True,
) -> TissueLayer:
    """Build the soft-tissue tet layer under ``face`` (Heinze §2.3, bone rule §2.3.1).

    Parameters
    ----------
    face : open skin surface, normals pointing out of the body (the bundled faces: +z).
    thickness : m, scalar or (n,) per face vertex; the tissue depth to the bone (Heinze: 0.01).
    layers : number of tet layers through the thickness (>= 1).
    options : :class:`TissueOptions`.
    use_cache : reuse the result of an identical earlier call (the result is immutable).

    Returns
    -------
    TissueLayer
        ``.mesh`` has (layers + 1) * n vertices and 3 * layers * m positively oriented tets.

    Raises
    ------
    ParameterError : non-positive or non-finite thickness, layers < 1.
    MeshError : nothing left after trimming, no convergence, or (``trim_folds=False``) a place where
        the layer cannot be built without trimming.
    """
    n_face = face.n_vertices
    h_req = np.array(np.broadcast_to(np.asarray(thickness, dtype=np.float64), (n_face,))) \
        if np.ndim(thickness) == 0 else np.array(thickness, dtype=np.float64)
    if h_req.shape != (n_face,):
        raise ParameterError(f"thickness must be a scalar or shape ({n_face},), got {h_req.shape}")
    if not np.isfinite(h_req).all() or (h_req <= 0).any():
        raise ParameterError("thickness must be finite and > 0 everywhere")
    if int(layers) != layers or layers < 1:
        raise ParameterError(f"layers must be an integer >= 1, got {layers}")
    layers = int(layers)
    key = _key(face, h_req, layers, options) if use_cache else None
    if key is not None and key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]

    skin, face_ids, inward, h, pos, tets, by_clearance, by_shape, rounds, trimmed_mask = _extrude(
        face, h_req, layers, options)
    h_req = h_req[face_ids]
    n = skin.n_vertices
    trimmed = np.flatnonzero(trimmed_mask)
    vertex_region = np.full((layers + 1) * n, REGION_TISSUE, dtype=np.int32)
    vertex_region[layers * n:] = REGION_BONE
    mesh = TetMesh(pos, tets, tet_region=np.full(len(tets), REGION_TISSUE, dtype=np.int32),
                   vertex_region=vertex_region, fixed=vertex_region == REGION_BONE,
                   name=f"{face.name}[tissue]")
    thinner = h < h_req
    by_clearance = by_clearance & thinner
    by_shape = by_shape & thinner
    for a in (h, h_req, inward, face_ids, trimmed, by_clearance, by_shape):
        a.flags.writeable = False  # the result is cached and shared: immutable
    result = TissueLayer(mesh=mesh, n_skin=n, layers=layers, thickness=h, requested_thickness=h_req,
                         inward=inward, reduced_by_clearance=by_clearance, reduced_by_shape=by_shape,
                         skin_triangles=skin.triangles, face_vertex_ids=face_ids, trimmed_triangles=trimmed,
                         rounds=rounds)
    if key is not None:
        _CACHE[key] = result
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
    return result


def build_tissue_layer(
    face: SurfaceMesh,
    thickness: float | np.ndarray = 0.01,
    layers: int = 3,
    options: TissueOptions = TissueOptions(),
) -> TetMesh:
    """The tet mesh of :func:`extrude_tissue_layer` (skin = vertices 0..n-1, bone vertices fixed).

    Use :func:`extrude_tissue_layer` for the skin-to-face vertex map and the thickness report."""
    return extrude_tissue_layer(face, thickness, layers, options).mesh
