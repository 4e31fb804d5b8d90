"""Steady viscous flow in a thin gap between two surfaces, on a triangle surface mesh.

**Equation** (Reynolds lubrication equation without sliding, incompressible, steady): with ``h``
the local aperture (m) and ``mu`` the dynamic viscosity (Pa s), the flux per unit width is
``q = -h^3 / (12 mu) grad p`` (plane Poiseuille flow) and mass conservation gives

    div( h^3 / (12 mu) grad p ) = 0      on the surface,

``p = p_in`` on a source vertex set, ``p = 0`` on a sink vertex set, no flux through the other
boundaries (natural boundary condition).

**Discretisation**: two-point-flux finite volumes on the mesh edges (the cotangent Laplacian with
an aperture-dependent conductance). The flux from vertex i to vertex j is

    Q_ij = w_ij * h_ij^3 / (12 mu) * (p_i - p_j)                                   (m^3/s)

- ``w_ij = (cot alpha + cot beta) / 2`` is the cotangent weight (alpha, beta the angles opposite
  the edge; one term on a boundary edge), the ratio of the circumcentric dual edge length to the
  edge length. It is **clamped at** ``W_FLOOR`` = 1e-6 from below: negative weights (an edge
  opposite obtuse angles) are the usual cause of a non-M-matrix and of non-physical flux against
  the pressure drop, and the clamp gives an M-matrix; the floor is positive rather than zero so
  that every mesh edge whose two ends are open conducts (a right-angled structured mesh has
  w = 0 on its diagonals), i.e. the graph of the scheme *is* the mesh graph.
- ``h_ij^3 = 2 h_i^2 h_j^2 / (h_i + h_j)`` (0 when both vanish) is the exact resistance mean of a
  gap that varies linearly along the edge (``int_0^L dx / h^3 = L (h_i + h_j) / (2 h_i^2 h_j^2)``).
  It vanishes when either end is closed, so a vertex with h = 0 blocks every edge at it: the flow
  is zero exactly when the vertices with h > 0 do not connect source to sink through mesh edges,
  the vertex-graph rule of :func:`headsim.mask.analyse_seal` (tested).

Vertices in a conducting component that touches neither the source nor the sink carry no flow
and have an undetermined pressure (NaN). The remaining system is a symmetric positive-definite
sparse matrix (a graph Laplacian with Dirichlet rows removed), solved by SuperLU in symmetric mode
(:func:`headsim.solvers.newton.factorize_spd`; the full bundled face, 9.0k unknowns: 0.04 s, against
1.5 s with SuperLU's threshold pivoting on the same minimum-degree ordering). Total flow Q is the sum of the source reactions and is
checked against the sink reactions (mass conservation).

**Validity, inertia**: lubrication theory needs a small reduced Reynolds number. Per edge the gap
Reynolds number ``Re = rho q / mu`` (q = |Q_ij| / (w_ij l_ij), the flux per unit width, equal to
``h_ij^3 |p_i - p_j| / (12 mu l_ij)``) and the reduced one ``Re h_ij / l_ij`` (l_ij the edge
length, the scale along the flow) are returned; where the reduced number exceeds ~1 the viscous
estimate is too large. Through such a break the flow is orifice-limited (Bernoulli):
``Q <= C_d A sqrt(2 dp / rho)``, :func:`orifice_flow`. :func:`constrictions` finds the narrowest
cross-section between source and sink -- the minimum cut of the edge graph with capacity
``h_ij w_ij l_ij`` (aperture x dual width: the flow area across the edge), by max-flow/min-cut
(:func:`scipy.sparse.csgraph.maximum_flow`) -- and splits it into connected channels, each with
its flow area, its viscous flow (the fluxes across the cut sum to Q exactly) and its largest
Reynolds number, so a caller can take min(viscous, orifice) per channel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, connected_components, maximum_flow

from headsim.errors import ParameterError
from headsim.solvers.newton import factorize_spd

#: lower clamp of the cotangent weight (module doc)
W_FLOOR = 1e-6
#: dynamic viscosity of air at 20 deg C, Pa s
AIR_VISCOSITY = 1.81e-5
#: density of air at 20 deg C, 1 atm, kg/m^3
AIR_DENSITY = 1.2
#: discharge coefficient of a sharp-edged orifice
ORIFICE_DISCHARGE = 0.6


@dataclass(frozen=True, eq=False)
class ThinFilmFlow:
    """Solution of :func:`solve_thin_film`.

    pressure : (n,) Pa (NaN where undetermined: no conducting path to source or sink)
    flow : m^3/s, total flow out of the source (sum of the source reactions)
    sink_flow : m^3/s, total flow into the sink (equals ``flow`` to round-off: mass conservation)
    edges : (e, 2) int64 mesh edges; edge_flux : (e,) m^3/s from edges[:, 0] to edges[:, 1]
    edge_aperture : (e,) m, h_ij; edge_weight : (e,) cotangent weight (clamped); edge_length : (e,) m
    throughflow : (n,) m^3/s, flow through each vertex (half the sum of |Q_ij| at it; at a source or
        sink vertex its reaction)
    reynolds : (e,) gap Reynolds number rho q / mu; reduced_reynolds : (e,) Re h_ij / l_ij
    inlet_pressure : Pa; viscosity : Pa s; density : kg/m^3
    """

    pressure: np.ndarray
    flow: float
    sink_flow: float
    edges: np.ndarray
    edge_flux: np.ndarray
    edge_aperture: np.ndarray
    edge_weight: np.ndarray
    edge_length: np.ndarray
    throughflow: np.ndarray
    reynolds: np.ndarray
    reduced_reynolds: np.ndarray
    inlet_pressure: float
    viscosity: float
    density: float


@dataclass(frozen=True, eq=False)
class Constriction:
    """One channel of the narrowest cross-section between source and sink (:func:`constrictions`).

    edges : (k,) int64 ids into ``ThinFilmFlow.edges`` of the cut edges of this channel
    vertices : (v,) int64 mesh vertices at those edges
    area : m^2, flow area (sum of aperture x dual width); flow : m^3/s viscous flow across it
    max_reynolds, max_reduced_reynolds : largest over its edges
    """

    edges: np.ndarray
    vertices: np.ndarray
    area: float
    flow: float
    max_reynolds: float
    max_reduced_reynolds: float


def cotangent_weights(vertices: np.ndarray, triangles: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(e,) ``(cot alpha + cot beta) / 2`` per edge (one term on boundary edges), clamped at
    :data:`W_FLOOR` from below (module doc). Degenerate triangles contribute nothing."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    n = len(v)
    key = edges[:, 0] * n + edges[:, 1]
    w = np.zeros(len(edges))
    for k in range(3):
        a, b, c = t[:, k], t[:, (k + 1) % 3], t[:, (k + 2) % 3]
        u, s = v[b] - v[a], v[c] - v[a]
        cross = np.linalg.norm(np.cross(u, s), axis=1)
        dot = np.einsum("ij,ij->i", u, s)
        cot = np.divide(dot, cross, out=np.zeros_like(dot), where=cross > 0)
        lo, hi = np.minimum(b, c), np.maximum(b, c)
        idx = np.searchsorted(key, lo * n + hi)
        np.add.at(w, idx, 0.5 * cot)
    return np.maximum(w, W_FLOOR)


def edge_aperture(h: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(e,) m: h_ij with h_ij^3 = 2 h_i^2 h_j^2 / (h_i + h_j), the exact mean of a linear gap."""
    hi, hj = h[edges[:, 0]], h[edges[:, 1]]
    s = hi + hj
    h3 = np.divide(2.0 * hi**2 * hj**2, s, out=np.zeros_like(s), where=s > 0)
    return np.cbrt(h3)


def _vertex_set(ids, n: int, what: str) -> np.ndarray:
    a = np.unique(np.asarray(ids, dtype=np.int64).ravel())
    if len(a) == 0:
        raise ParameterError(f"the {what} vertex set is empty")
    if a[0] < 0 or a[-1] >= n:
        raise ParameterError(f"{what} vertices must be ids in [0, {n - 1}]")
    return a


def solve_thin_film(vertices: np.ndarray, triangles: np.ndarray, aperture: np.ndarray, source, sink,
                    inlet_pressure: float, viscosity: float = AIR_VISCOSITY,
                    density: float = AIR_DENSITY) -> ThinFilmFlow:
    """Steady thin-film flow from ``source`` (p = inlet_pressure) to ``sink`` (p = 0) (module doc).

    vertices : (n, 3) m; triangles : (m, 3) int; aperture : (n,) m, finite and >= 0
    source, sink : vertex ids (non-empty, disjoint); inlet_pressure : Pa (> 0)
    viscosity : Pa s (> 0, default air); density : kg/m^3 (> 0, for the Reynolds numbers)
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    n = len(v)
    if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3 or len(t) == 0:
        raise ParameterError("vertices must be (n, 3) and triangles non-empty (m, 3)")
    if t.min() < 0 or t.max() >= n:
        raise ParameterError(f"triangle indices must lie in [0, {n - 1}]")
    h = np.asarray(aperture, dtype=np.float64)
    if h.shape != (n,):
        raise ParameterError(f"aperture must have shape ({n},), got {h.shape}")
    if not np.isfinite(h).all() or (h < 0).any():
        raise ParameterError("aperture must be finite and >= 0 (cap open regions at a finite gap)")
    for name, val in (("viscosity", viscosity), ("density", density), ("inlet_pressure", inlet_pressure)):
        if not (np.isfinite(val) and val > 0):
            raise ParameterError(f"{name} must be > 0, got {val}")
    src, snk = _vertex_set(source, n, "source"), _vertex_set(sink, n, "sink")
    if np.intersect1d(src, snk).size:
        raise ParameterError("source and sink vertex sets overlap")

    from headsim.mesh.geometry import unique_edges

    edges = unique_edges(t)[0]
    length = np.linalg.norm(v[edges[:, 1]] - v[edges[:, 0]], axis=1)
    w = cotangent_weights(v, t, edges)
    he = edge_aperture(h, edges)
    cond = w * he**3 / (12.0 * viscosity)           # m^3 / (Pa s)
    on = cond > 0
    i, j = edges[on, 0], edges[on, 1]
    c = cond[on]
    lap = sp.csr_matrix((np.concatenate([-c, -c, c, c]),
                         (np.concatenate([i, j, i, j]), np.concatenate([j, i, i, j]))), shape=(n, n))

    # components of the conducting graph: a component reaching only the source sits at p_in, one
    # reaching only the sink at 0 (no flow, exactly); the pressure is solved for where both are
    # reached and is undetermined (NaN) where neither is
    _, comp = connected_components(lap, directed=False)
    n_comp = int(comp.max()) + 1
    has_src = np.zeros(n_comp, dtype=bool)
    has_src[comp[src]] = True
    has_snk = np.zeros(n_comp, dtype=bool)
    has_snk[comp[snk]] = True
    p = np.full(n, np.nan)
    p[has_src[comp] & ~has_snk[comp]] = inlet_pressure
    p[has_snk[comp] & ~has_src[comp]] = 0.0
    p[src] = inlet_pressure
    p[snk] = 0.0
    fixed = np.zeros(n, dtype=bool)
    fixed[src] = fixed[snk] = True
    free = np.flatnonzero((has_src & has_snk)[comp] & ~fixed)
    if len(free):
        a = lap[free][:, free].tocsc()
        rhs = -(lap[free][:, src] @ np.full(len(src), float(inlet_pressure)))
        p[free] = factorize_spd(a).solve(rhs)
    p0 = np.where(np.isfinite(p), p, 0.0)
    dp = p0[edges[:, 0]] - p0[edges[:, 1]]
    flux = cond * dp
    # reactions from the edge fluxes (exactly zero across a closed seal, where every dp or
    # conductance is zero; a matrix product would leave round-off)
    net = np.zeros(n)
    np.add.at(net, edges[:, 0], flux)
    np.add.at(net, edges[:, 1], -flux)
    flow = float(net[src].sum())
    sink_flow = float(-net[snk].sum())
    through = np.zeros(n)
    np.add.at(through, edges[:, 0], 0.5 * np.abs(flux))
    np.add.at(through, edges[:, 1], 0.5 * np.abs(flux))
    through[fixed] = np.abs(net[fixed])
    q = he**3 * np.abs(dp) / (12.0 * viscosity * length)   # flux per unit width, m^2/s
    re = density * q / viscosity
    return ThinFilmFlow(pressure=p, flow=flow, sink_flow=sink_flow, edges=edges, edge_flux=flux, edge_aperture=he,
                        edge_weight=w, edge_length=length, throughflow=through, reynolds=re,
                        reduced_reynolds=re * he / length, inlet_pressure=float(inlet_pressure),
                        viscosity=float(viscosity), density=float(density))


def orifice_flow(area, pressure_drop: float, density: float = AIR_DENSITY,
                 discharge: float = ORIFICE_DISCHARGE):
    """Bernoulli orifice flow ``C_d A sqrt(2 dp / rho)`` (m^3/s) through flow area ``area`` (m^2)."""
    return discharge * np.asarray(area, dtype=np.float64) * np.sqrt(2.0 * pressure_drop / density)


#: integer capacity of the widest edge in the max-flow problem (scipy needs int32 capacities)
_CAP_QUANTA = 1_000_000


def constrictions(result: ThinFilmFlow, source, sink) -> list[Constriction]:
    """Channels of the narrowest cross-section between ``source`` and ``sink`` (module doc).

    The minimum cut of the edge graph with capacity = flow area ``h_ij w_ij l_ij`` (m^2), quantised
    to integers relative to the widest edge (each open edge keeps at least one quantum, so the cut
    never passes through an open edge for free); cut edges that are open are grouped into channels
    by shared vertices. Empty when no open path joins source and sink.
    """
    n = len(result.pressure)
    edges = result.edges
    area = result.edge_aperture * result.edge_weight * result.edge_length
    open_e = area > 0
    if not open_e.any() or result.flow == 0.0:
        return []
    scale = _CAP_QUANTA / float(area.max())
    cap = np.where(open_e, np.maximum(np.ceil(area * scale), 1), 0).astype(np.int64)
    s, t = n, n + 1
    src, snk = np.asarray(source, np.int64), np.asarray(sink, np.int64)
    big = np.iinfo(np.int32).max // 4
    e = edges[open_e]
    ce = cap[open_e]
    rows = np.concatenate([e[:, 0], e[:, 1], np.full(len(src), s), snk])
    cols = np.concatenate([e[:, 1], e[:, 0], src, np.full(len(snk), t)])
    vals = np.concatenate([ce, ce, np.full(len(src), big), np.full(len(snk), big)]).astype(np.int32)
    graph = sp.csr_matrix((vals, (rows, cols)), shape=(n + 2, n + 2))
    graph.sum_duplicates()
    mf = maximum_flow(graph, s, t)
    residual = (graph - mf.flow).tocsr()
    residual.data = np.where(residual.data > 0, 1, 0).astype(np.int32)
    residual.eliminate_zeros()
    reach = np.zeros(n + 2, dtype=bool)
    reach[breadth_first_order(residual, s, directed=True, return_predecessors=False)] = True
    side = reach[:n]
    cut = np.flatnonzero(open_e & (side[edges[:, 0]] != side[edges[:, 1]]))
    if len(cut) == 0:
        return []
    # group the cut edges into channels: edges sharing a vertex belong together
    ce_nodes = edges[cut]
    m = len(cut)
    inc = sp.csr_matrix((np.ones(2 * m), (np.repeat(np.arange(m), 2), ce_nodes.ravel())), shape=(m, n))
    k, label = connected_components(inc @ inc.T, directed=False)
    # flux oriented from the source side to the sink side of the cut
    sign = np.where(side[ce_nodes[:, 0]], 1.0, -1.0)
    oriented = sign * result.edge_flux[cut]
    out = []
    for g in range(k):
        sel = label == g
        ids = cut[sel]
        out.append(Constriction(edges=ids, vertices=np.unique(edges[ids]), area=float(area[ids].sum()),
                                flow=float(oriented[sel].sum()), max_reynolds=float(result.reynolds[ids].max()),
                                max_reduced_reynolds=float(result.reduced_reynolds[ids].max())))
    out.sort(key=lambda c: -c.flow)
    return out
