"""Position Based Dynamics soft bodies (Müller et al. 2006) with an XPBD option (Macklin et al. 2016).

The loop is the one of Monkin 2016 (seed 001) §3–4:

.. code-block:: text

    v_i += dt w_i f_ext(x_i)                       gravity + hydrostatic pressure (§4.3, §4.4)
    p_i  = x_i + dt v_i                            prediction
    generate collision constraints                 planes / box walls / particle–particle voxel grid
    repeat solver iterations: project constraints  edges (distance), closed-body volume, collisions
    v_i  = (1 - damping) (p_i - x_i) / dt; x_i = p_i   damping coefficient in [0, 1] (§4.4)

with particle masses from the triangle areas (§4.2), an initial stabilisation that projects the
constraints without updating velocities (§4.4, after Macklin et al. 2014) and the stop rule "change of
the sum of absolute coordinates below a threshold" (§4.4).

Distance constraints are solved either by graph-coloured Gauss–Seidel (edges of one colour share no
vertex, so each colour is projected in parallel) or by Jacobi with averaging and over-relaxation
(Macklin et al. 2014). With ``xpbd=True`` each constraint has a compliance (inverse stiffness, SI) and a
multiplier kept over the iterations of one step, so stiffness does not depend on the iteration count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from headsim.errors import DivergenceError, MeshError, ParameterError
from headsim.mesh import geometry
from headsim.solvers._kernels import pbd as _k

__all__ = [
    "PBDModel",
    "PBDOptions",
    "PBDState",
    "PBDSolver",
    "SolveInfo",
    "particle_masses",
    "hydrostatic_forces",
    "colour_edges",
]

STANDARD_GRAVITY = 9.81  # m/s², Monkin 2016 §4.3


def _ro(a, dtype, shape_tail, what):
    arr = np.array(a, dtype=dtype, order="C")
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        raise ParameterError(f"{what} must have shape (k, {', '.join(map(str, shape_tail))}), got {arr.shape}")
    arr.flags.writeable = False
    return arr


def particle_masses(vertices: np.ndarray, triangles: np.ndarray, total_mass: float) -> np.ndarray:
    """Mass of every particle, kg (Monkin 2016 §4.2).

    m_i = M × (area of the triangles containing i) / (total area). Note that every triangle is counted at
    its three vertices, so the masses sum to 3 M; we normalise by 3 × total area so that they sum to M
    (the seed's ratio with the sum over the triangles at i replaced by its barycentric third).

    vertices (n, 3) m; triangles (m, 3) int64; total_mass kg > 0. Returns (n,) float64 kg; vertices in no
    triangle get mass 0 (they are then treated as fixed).
    """
    if not total_mass > 0 or not math.isfinite(total_mass):
        raise ParameterError(f"object mass must be positive and finite, got {total_mass}")
    areas = geometry.vertex_areas(np.asarray(vertices, float), np.asarray(triangles, np.int64))
    total = areas.sum()
    if not total > 0:
        raise MeshError("cannot distribute mass over a mesh of zero area")
    return total_mass * areas / total


def colour_edges(edges: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Greedy edge colouring for parallel Gauss–Seidel.

    Returns (order (s,) int64 permutation that sorts the edges by colour, offsets (c+1,) int64).
    """
    edges = np.ascontiguousarray(edges, dtype=np.int64)
    colour = np.zeros(len(edges), dtype=np.int64)
    nc = _k.greedy_edge_colouring(edges, int(n_vertices), colour) if len(edges) else 0
    if nc < 0:
        raise MeshError("a vertex has more than 31 edges; cannot colour the distance constraints")
    order = np.argsort(colour, kind="stable")
    offsets = np.zeros(nc + 1, dtype=np.int64)
    np.cumsum(np.bincount(colour, minlength=nc), out=offsets[1:])
    return order, offsets


@dataclass(frozen=True, eq=False)
class PBDModel:
    """What a PBD solve never changes.

    Attributes
    ----------
    mass : (n,) float64, kg (Monkin 2016 §4.2, see :func:`particle_masses`)
    fixed : (n,) bool, particles that never move (inverse mass 0)
    edges : (s, 2) int64, distance constraints
    rest_length : (s,) float64, m
    volume_triangles : (t, 3) int64, outward-oriented triangles of the closed bodies (may be empty)
    volume_body : (t,) int64, body of each volume triangle (0 … k-1)
    volume_target : (k,) float64, m³, target volume of every body (raise it to inject, Monkin §4.3)
    fluid_density : kg/m³, hydrostatic pressure F = rho g h A (Monkin §4.3); 0 switches it off
    plane_points, plane_normals : (q, 3) float64, collision half-spaces (n points into the free side)
    collision_radius : m, particles keep this distance from the planes and (if particle_contacts) from
        each other
    particle_contacts : particle–particle non-penetration on a voxel grid (Monkin §4.1, §4.5)
    """

    mass: np.ndarray
    fixed: np.ndarray
    edges: np.ndarray
    rest_length: np.ndarray
    volume_triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    volume_body: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    volume_target: np.ndarray = field(default_factory=lambda: np.zeros(0))
    fluid_density: float = 0.0
    plane_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    plane_normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    collision_radius: float = 0.0
    particle_contacts: bool = False

    def __post_init__(self):
        mass = np.array(self.mass, dtype=np.float64)
        n = len(mass)
        if mass.ndim != 1 or n == 0 or not np.isfinite(mass).all() or (mass < 0).any():
            raise ParameterError("mass must be a non-empty (n,) array of finite non-negative values (kg)")
        fixed = np.array(self.fixed, dtype=bool)
        if fixed.shape != (n,):
            raise ParameterError(f"fixed must have shape ({n},), got {fixed.shape}")
        fixed = fixed | (mass == 0)
        edges = _ro(self.edges, np.int64, (2,), "edges") if len(self.edges) else np.zeros((0, 2), np.int64)
        rest = np.array(self.rest_length, dtype=np.float64).reshape(-1)
        if len(rest) != len(edges) or not np.isfinite(rest).all() or (rest < 0).any():
            raise ParameterError("rest_length must be (s,) finite non-negative, one per edge (m)")
        if len(edges) and (edges.min() < 0 or edges.max() >= n or (edges[:, 0] == edges[:, 1]).any()):
            raise ParameterError(f"edges must join two different particles among {n}")
        vt = np.array(self.volume_triangles, dtype=np.int64).reshape(-1, 3)
        vb = np.array(self.volume_body, dtype=np.int64).reshape(-1)
        target = np.array(self.volume_target, dtype=np.float64).reshape(-1)
        if len(vt) != len(vb):
            raise ParameterError("volume_body must give one body per volume triangle")
        if len(vt) and (vt.min() < 0 or vt.max() >= n or vb.min() < 0 or vb.max() >= len(target)):
            raise ParameterError("volume triangles/bodies out of range")
        if not np.isfinite(target).all():
            raise ParameterError("volume_target must be finite (m³)")
        if len(vt):
            owner = np.full(n, -1)
            for k in range(3):
                clash = (owner[vt[:, k]] >= 0) & (owner[vt[:, k]] != vb)
                if clash.any():
                    raise ParameterError("a particle belongs to two closed bodies; give each body its own particles")
                owner[vt[:, k]] = vb
        if not (self.fluid_density >= 0 and math.isfinite(self.fluid_density)):
            raise ParameterError(f"fluid_density must be >= 0 kg/m³, got {self.fluid_density}")
        pp = np.array(self.plane_points, dtype=np.float64).reshape(-1, 3)
        pn = np.array(self.plane_normals, dtype=np.float64).reshape(-1, 3)
        if pp.shape != pn.shape:
            raise ParameterError("plane_points and plane_normals must have the same shape")
        if len(pn):
            norm = np.linalg.norm(pn, axis=1, keepdims=True)
            if (norm == 0).any():
                raise ParameterError("plane normals must be non-zero")
            pn = pn / norm
        if not (self.collision_radius >= 0 and math.isfinite(self.collision_radius)):
            raise ParameterError("collision_radius must be >= 0 m")
        if self.particle_contacts and not self.collision_radius > 0:
            raise ParameterError("particle contacts need collision_radius > 0")
        for name, arr in (("mass", mass), ("fixed", fixed), ("edges", edges), ("rest_length", rest),
                          ("volume_triangles", vt), ("volume_body", vb), ("volume_target", target),
                          ("plane_points", pp), ("plane_normals", pn)):
            arr = np.ascontiguousarray(arr)
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)

    @property
    def n_particles(self) -> int:
        return len(self.mass)

    @property
    def n_bodies(self) -> int:
        return len(self.volume_target)

    @property
    def inverse_mass(self) -> np.ndarray:
        """(n,) float64, 1/kg; 0 for fixed particles."""
        w = np.zeros(self.n_particles)
        free = ~self.fixed
        w[free] = 1.0 / self.mass[free]
        return w

    def with_volume_target(self, target) -> "PBDModel":
        """Same model with new target volumes (m³), e.g. raised by an injected volume (Monkin §4.3)."""
        return replace(self, volume_target=np.array(target, dtype=np.float64).reshape(-1))

    def body_volumes(self, positions: np.ndarray) -> np.ndarray:
        """(k,) float64, m³: current signed volume of every closed body."""
        out = np.zeros(self.n_bodies)
        if self.n_bodies:
            _k.body_volumes(np.ascontiguousarray(positions, dtype=np.float64), self.volume_triangles,
                            self.volume_body, self.n_bodies, out)
        return out

    @classmethod
    def from_surface(cls, vertices, triangles, *, total_mass: float, fixed=None, closed_bodies: bool = False,
                     **kwargs) -> "PBDModel":
        """Particles = vertices, distance constraints on the edges at their current lengths, masses by
        area (Monkin §4.2). With ``closed_bodies`` every connected component becomes a volume body whose
        target is its current volume."""
        v = np.asarray(vertices, dtype=np.float64)
        tri = np.asarray(triangles, dtype=np.int64)
        edges, _ = geometry.unique_edges(tri)
        rest = np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1)
        mass = particle_masses(v, tri, total_mass)
        fixed = np.zeros(len(v), bool) if fixed is None else fixed
        if closed_bodies:
            import scipy.sparse.csgraph as csg

            n_comp, label = csg.connected_components(geometry.vertex_adjacency(len(v), edges), directed=False)
            body = label[tri[:, 0]]
            target = np.zeros(n_comp)
            kwargs.setdefault("volume_triangles", tri)
            kwargs.setdefault("volume_body", body)
            probe = cls(mass=mass, fixed=fixed, edges=edges, rest_length=rest, volume_triangles=tri,
                        volume_body=body, volume_target=target)
            kwargs.setdefault("volume_target", probe.body_volumes(v))
        return cls(mass=mass, fixed=fixed, edges=edges, rest_length=rest, **kwargs)


@dataclass(frozen=True)
class PBDOptions:
    """Algorithm options of :class:`PBDSolver`.

    dt : s, constant step (Monkin §4.4)
    iterations : solver iterations per step
    gravity : (3,) m/s²
    damping : coefficient in [0, 1] applied at the last velocity update, v <- (1 - damping) v (Monkin §4.4)
    method : "gauss_seidel" (graph-coloured, parallel within a colour) or "jacobi" (averaged, over-relaxed)
    jacobi_omega : over-relaxation of the Jacobi average, in (0, 2)
    xpbd : use compliances (below) instead of the iteration-dependent PBD stiffness
    stiffness : PBD distance stiffness factor in (0, 1] (ignored with xpbd)
    edge_compliance : XPBD compliance of the distance constraints, m/N (inverse spring stiffness)
    volume_compliance : XPBD compliance of the volume constraints, m³/Pa; 0 is incompressible
    stabilisation_iterations : projections without velocity update before the first step (Monkin §4.4)
    stop_tolerance : m per particle; stop when |Δ Σ|x|| < stop_tolerance × n (Monkin §4.4)
    min_steps, max_steps : bounds of :meth:`PBDSolver.solve`
    parallel : use the Numba-parallel kernels (a gain only with several free cores and large meshes)
    stop_patience : the stop rule must hold on this many consecutive steps (1 = the seed's rule; the
        change of Σ|x| also passes through zero whenever the motion turns, so > 1 makes the rule robust)
    acceleration : "none" (the seed's time stepping to rest) or "anderson": find the rest state, i.e. a
        fixed point of the step-from-rest map, by Anderson acceleration (:mod:`headsim.solvers.pbd_anderson`;
        same constraints and fixed points, stop rule Σ|Φ(x) - x| < stop_tolerance × n, no patience);
        only for quasi-static solves, the dynamics in between is not simulated
    anderson_history : number of previous residuals Anderson acceleration combines (m)
    contact_mass_scaling : k, 1/m; particle–particle contacts share their corrections by the scaled masses
        m_i exp(-k h_i), h_i the height along -gravity (mass scaling of Macklin et al. 2014 for stiff stacks:
        lower particles act heavier, so a tall pile is held up within a few iterations); 0 = off
    """

    dt: float = 1.0 / 60.0
    iterations: int = 10
    gravity: tuple[float, float, float] = (0.0, -STANDARD_GRAVITY, 0.0)
    damping: float = 0.0
    method: str = "gauss_seidel"
    jacobi_omega: float = 1.5
    xpbd: bool = False
    stiffness: float = 1.0
    edge_compliance: float = 0.0
    volume_compliance: float = 0.0
    stabilisation_iterations: int = 0
    stop_tolerance: float = 1e-7
    min_steps: int = 2
    max_steps: int = 10_000
    parallel: bool = False
    stop_patience: int = 1
    acceleration: str = "none"
    anderson_history: int = 5
    contact_mass_scaling: float = 0.0

    def __post_init__(self):
        if not (self.dt > 0 and math.isfinite(self.dt)):
            raise ParameterError(f"dt must be positive, got {self.dt}")
        if int(self.iterations) < 1:
            raise ParameterError(f"iterations must be >= 1, got {self.iterations}")
        g = tuple(float(x) for x in self.gravity)
        if len(g) != 3 or not all(map(math.isfinite, g)):
            raise ParameterError(f"gravity must be 3 finite numbers (m/s²), got {self.gravity}")
        object.__setattr__(self, "gravity", g)
        if not 0.0 <= self.damping <= 1.0:
            raise ParameterError(f"damping must be in [0, 1], got {self.damping}")
        if self.method not in ("gauss_seidel", "jacobi"):
            raise ParameterError(f"method must be 'gauss_seidel' or 'jacobi', got {self.method!r}")
        if not 0.0 < self.jacobi_omega < 2.0:
            raise ParameterError(f"jacobi_omega must be in (0, 2), got {self.jacobi_omega}")
        if not 0.0 < self.stiffness <= 1.0:
            raise ParameterError(f"stiffness must be in (0, 1], got {self.stiffness}")
        if self.edge_compliance < 0 or self.volume_compliance < 0:
            raise ParameterError("compliances must be >= 0")
        if self.stabilisation_iterations < 0 or self.min_steps < 0 or self.max_steps < 1:
            raise ParameterError("stabilisation_iterations, min_steps must be >= 0 and max_steps >= 1")
        if int(self.stop_patience) < 1:
            raise ParameterError(f"stop_patience must be >= 1, got {self.stop_patience}")
        if self.acceleration not in ("none", "anderson"):
            raise ParameterError(f"acceleration must be 'none' or 'anderson', got {self.acceleration!r}")
        if not 1 <= int(self.anderson_history) <= 50:
            raise ParameterError(f"anderson_history must be in [1, 50], got {self.anderson_history}")
        if not (self.contact_mass_scaling >= 0 and math.isfinite(self.contact_mass_scaling)):
            raise ParameterError(f"contact_mass_scaling must be >= 0 (1/m), got {self.contact_mass_scaling}")
        if not self.stop_tolerance > 0:
            raise ParameterError(f"stop_tolerance must be > 0 m, got {self.stop_tolerance}")


@dataclass(frozen=True, eq=False)
class PBDState:
    """positions (n, 3) float64 m; velocities (n, 3) float64 m/s; time s; steps taken."""

    positions: np.ndarray
    velocities: np.ndarray
    time: float = 0.0
    steps: int = 0

    def __post_init__(self):
        p = np.array(self.positions, dtype=np.float64, order="C")
        v = np.array(self.velocities, dtype=np.float64, order="C")
        if p.ndim != 2 or p.shape[1] != 3 or v.shape != p.shape:
            raise ParameterError(f"positions and velocities must be equal (n, 3) arrays, got {p.shape}, {v.shape}")
        p.flags.writeable = False
        v.flags.writeable = False
        object.__setattr__(self, "positions", p)
        object.__setattr__(self, "velocities", v)

    @classmethod
    def at_rest(cls, positions) -> "PBDState":
        p = np.asarray(positions, dtype=np.float64)
        return cls(p, np.zeros_like(p))


@dataclass(frozen=True)
class SolveInfo:
    """How :meth:`PBDSolver.solve` ended: steps taken, converged (stop rule met), cancelled, and the last
    change of the sum of absolute coordinates (m)."""

    steps: int
    converged: bool
    cancelled: bool
    last_change: float


def hydrostatic_forces(positions: np.ndarray, triangles: np.ndarray, density: float, gravity, *,
                       parallel: bool = False) -> np.ndarray:
    """Hydrostatic pressure force on every particle, N (Monkin 2016 §4.3).

    F_i = rho |g| h_i A_i along gravity, with A_i = (area of the triangles at i) / 3 and h_i the distance
    from i, opposite to gravity, to the nearest point of the surface (0 if none). The seed's shortcut for
    dense meshes (nearest vertex of the hit triangle) is replaced by the exact ray hit at the same cost.

    positions (n, 3) m; triangles (m, 3) int64 (the closed model); density kg/m³; gravity (3,) m/s².
    """
    p = np.ascontiguousarray(positions, dtype=np.float64)
    g = np.asarray(gravity, dtype=np.float64)
    gnorm = float(np.linalg.norm(g))
    out = np.zeros_like(p)
    if density == 0 or gnorm == 0 or len(triangles) == 0:
        return out
    up = -g / gnorm
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(up, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    tri = np.ascontiguousarray(triangles, dtype=np.int64)
    lengths = np.linalg.norm(p[tri[:, 0]] - p[tri[:, 1]], axis=1)
    cell = max(float(np.mean(lengths)) * 2.0, 1e-9)
    h = np.zeros(len(p))
    (_k.column_heights_parallel if parallel else _k.column_heights)(p, tri, up, e1, e2, cell, h)
    area = geometry.vertex_areas(p, tri)
    out[:] = (density * gnorm * h * area)[:, None] * (g / gnorm)[None, :]
    return out


class PBDSolver:
    """Steps a :class:`PBDModel` (see the module docstring for the loop).

    The constructor precomputes the edge colouring (Gauss–Seidel) or the vertex→edge lists (Jacobi) and
    scratch buffers; :meth:`step`, :meth:`stabilise` and :meth:`solve` return new states and never modify
    their input.
    """

    def __init__(self, model: PBDModel, options: PBDOptions = PBDOptions(),
                 extra_constraints: tuple[Callable[[np.ndarray, np.ndarray], None], ...] = ()):
        """``extra_constraints``: callables ``project(p, w)`` that project further constraints in place
        (p (n, 3) m, w (n,) 1/kg), called in every solver iteration after the built-in ones but before
        the volume constraints (e.g. the ball–cloth contacts of the demo scenes)."""
        self.model = model
        self._extra = tuple(extra_constraints)
        self.options = options
        self._w = model.inverse_mass
        edges = model.edges
        if options.method == "gauss_seidel":
            order, self._offsets = colour_edges(edges, model.n_particles)
            self._edges = np.ascontiguousarray(edges[order])
            self._rest = np.ascontiguousarray(model.rest_length[order])
        else:
            self._edges = np.ascontiguousarray(edges)
            self._rest = np.ascontiguousarray(model.rest_length)
            inc = np.concatenate([edges[:, 0], edges[:, 1]]) if len(edges) else np.zeros(0, np.int64)
            eid = np.concatenate([np.arange(len(edges))] * 2)
            order = np.argsort(inc, kind="stable")
            self._vertex_edges = np.ascontiguousarray(eid[order], dtype=np.int64)
            self._vertex_edge_offsets = np.zeros(model.n_particles + 1, dtype=np.int64)
            np.cumsum(np.bincount(inc, minlength=model.n_particles), out=self._vertex_edge_offsets[1:])
            self._dlam = np.zeros(len(edges))
            self._dir = np.zeros((len(edges), 3))
        self._lam_e = np.zeros(len(edges))
        self._lam_v = np.zeros(model.n_bodies)
        self._grad = np.zeros((model.n_particles, 3))
        self._vertex_body = np.full(model.n_particles, -1, dtype=np.int64)
        for k in range(3):
            self._vertex_body[model.volume_triangles[:, k]] = model.volume_body
        self._vol = np.zeros(model.n_bodies)
        self._den = np.zeros(model.n_bodies)
        self._gravity = np.asarray(options.gravity)
        self._has_external_force = bool(np.any(self._gravity != 0.0))
        if model.particle_contacts:
            self._contact = np.zeros((model.n_particles, 3))
            self._cells = np.zeros(model.n_particles, dtype=np.int64)

    # --- constraint projection ---------------------------------------------------------------------
    def _project(self, p: np.ndarray, dt: float) -> None:
        o, m = self.options, self.model
        if o.xpbd:
            at_e, at_v, k = o.edge_compliance / dt**2, o.volume_compliance / dt**2, 1.0
        else:
            at_e, at_v, k = 0.0, 0.0, o.stiffness
        if len(self._edges):
            if o.method == "gauss_seidel":
                kern = _k.project_distance_coloured_parallel if o.parallel else _k.project_distance_coloured
                kern(self._edges, self._rest, self._offsets, self._w, at_e, k,
                                             self._lam_e, p)
            else:
                kern = _k.project_distance_jacobi_parallel if o.parallel else _k.project_distance_jacobi
                kern(self._edges, self._rest, self._vertex_edge_offsets, self._vertex_edges,
                                           self._w, at_e, k, o.jacobi_omega, self._lam_e, self._dlam, self._dir, p)
        if m.particle_contacts:
            self._project_contacts(p)
        for project in self._extra:
            project(p, self._w)
        w_volume = self._w
        if len(m.plane_points) and m.n_bodies:
            # particles resting on a plane are held by it: the volume projection moves the others only,
            # so that the plane projection after it does not undo the volume (ball on a plane, seed fig. 3)
            _k.project_planes(m.plane_points, m.plane_normals, m.collision_radius, self._w, p)
            gap = np.einsum("ikj,kj->ik", p[:, None, :] - m.plane_points[None], m.plane_normals) - m.collision_radius
            touching = (gap <= 1e-12 * (1.0 + np.abs(p).max())).any(axis=1)
            if touching.any():
                w_volume = self._w.copy()
                w_volume[touching] = 0.0
        if m.n_bodies:
            _k.project_volume(m.volume_triangles, m.volume_body, self._vertex_body, m.volume_target, w_volume,
                              at_v, 1.0, self._lam_v, self._grad, self._vol, self._den, p)
        if len(m.plane_points):
            _k.project_planes(m.plane_points, m.plane_normals, m.collision_radius, self._w, p)

    def _project_iterations(self, p: np.ndarray, dt: float) -> None:
        """All solver iterations of one step (one fused kernel call for models with only distance and volume
        constraints projected by serial Gauss–Seidel, the fat-grafting case; same operations and order)."""
        o, m = self.options, self.model
        if (o.method == "gauss_seidel" and not o.parallel and not m.particle_contacts and not self._extra
                and not len(m.plane_points) and len(self._edges)):
            if o.xpbd:
                at_e, at_v, k = o.edge_compliance / dt**2, o.volume_compliance / dt**2, 1.0
            else:
                at_e, at_v, k = 0.0, 0.0, o.stiffness
            _k.project_gs_volume_iterations(int(o.iterations), self._edges, self._rest, self._offsets, self._w, at_e, k,
                                            self._lam_e, m.volume_triangles, m.volume_body, self._vertex_body,
                                            m.volume_target, at_v, self._lam_v, self._grad, self._vol, self._den, p)
            return
        for _ in range(o.iterations):
            self._project(p, dt)

    def _project_contacts(self, p: np.ndarray) -> None:
        r = self.model.collision_radius
        cell = 2.0 * r
        lo = p.min(axis=0) - cell
        dims = np.maximum(((p.max(axis=0) + cell - lo) / cell).astype(np.int64) + 1, 1)
        if int(np.prod(dims)) > 8 * self.model.n_particles + 1000:  # sparse cloud: coarser grid
            cell = float(np.max(p.max(axis=0) - lo)) / max(round(self.model.n_particles ** (1 / 3)), 1)
            cell = max(cell, 2.0 * r)
            dims = np.maximum(((p.max(axis=0) + cell - lo) / cell).astype(np.int64) + 1, 1)
        start = np.zeros(int(np.prod(dims)) + 1, dtype=np.int64)
        _k.build_voxel_grid(p, lo, cell, dims, start, self._cells)
        w = self._w
        k = self.options.contact_mass_scaling
        if k > 0 and self._has_external_force:
            up = -self._gravity / np.linalg.norm(self._gravity)
            h = p @ up
            w = self._w * np.exp(k * (h - h.max()))  # ratios only: the top particle keeps its w
        kern = _k.project_particle_contacts_parallel if self.options.parallel else _k.project_particle_contacts
        kern(p, w, r, lo, cell, dims, start, self._cells, self._contact)
        p += self._contact

    # --- public ------------------------------------------------------------------------------------
    def external_acceleration(self, positions: np.ndarray) -> np.ndarray:
        """(n, 3) m/s²: gravity plus hydrostatic force × inverse mass, zero on fixed particles."""
        m = self.model
        acc = np.broadcast_to(self._gravity, positions.shape).copy()
        if m.fluid_density > 0 and m.n_bodies:
            f = hydrostatic_forces(positions, m.volume_triangles, m.fluid_density, self._gravity,
                                   parallel=self.options.parallel)
            acc += f * self._w[:, None]
        acc[m.fixed] = 0.0
        return acc

    def stabilise(self, state: PBDState, iterations: int | None = None) -> PBDState:
        """Project the constraints ``iterations`` times without updating velocities (Monkin §4.4)."""
        n_it = self.options.stabilisation_iterations if iterations is None else iterations
        p = state.positions.copy()
        for _ in range(n_it):
            self._lam_e[:] = 0.0
            self._lam_v[:] = 0.0
            self._project(p, self.options.dt)
        self._check(p, state)
        return replace(state, positions=p)

    def step(self, state: PBDState) -> PBDState:
        """One PBD step (Müller et al. 2006, Monkin §3–4.4); ``state`` is unchanged."""
        o = self.options
        dt = o.dt
        x = state.positions
        with np.errstate(over="ignore", invalid="ignore"):  # non-finite values are caught by _check
            if self._has_external_force:
                v = state.velocities + dt * self.external_acceleration(x)
            else:
                v = state.velocities.copy()
            v[self.model.fixed] = 0.0
            p = x + dt * v
            self._lam_e[:] = 0.0
            self._lam_v[:] = 0.0
            if np.isfinite(p).all():
                self._project_iterations(p, dt)
        self._check(p, state)
        v = (1.0 - o.damping) * (p - x) / dt
        return PBDState(p, v, state.time + dt, state.steps + 1)

    def rest_step(self, positions: np.ndarray) -> np.ndarray:
        """(n, 3) m: positions after one step started at rest at ``positions`` (same as
        ``step(PBDState.at_rest(positions)).positions``, without building states). Its fixed points are
        the rest states of the solve (:mod:`headsim.solvers.pbd_anderson`)."""
        o = self.options
        dt = o.dt
        x = np.ascontiguousarray(positions, dtype=np.float64)
        with np.errstate(over="ignore", invalid="ignore"):
            if self._has_external_force:
                p = x + (dt * dt) * self.external_acceleration(x)  # zero on fixed particles
            else:
                p = x.copy()
            self._lam_e[:] = 0.0
            self._lam_v[:] = 0.0
            if np.isfinite(p).all():
                self._project_iterations(p, dt)
        if not np.isfinite(p).all():
            raise DivergenceError(
                f"PBD produced non-finite positions in a step from rest (dt = {dt:g} s); reduce dt or check the "
                "constraints")
        return p

    def _check(self, p: np.ndarray, state: PBDState) -> None:
        if not np.isfinite(p).all():
            raise DivergenceError(
                f"PBD produced non-finite positions at t = {state.time:.4g} s (step {state.steps}, "
                f"dt = {self.options.dt:g} s); reduce dt or raise damping"
            )

    def solve(self, state: PBDState, *, callback: Callable[[PBDState, float], None] | None = None,
              cancel: Callable[[], bool] | None = None) -> tuple[PBDState, SolveInfo]:
        """Stabilise, then step until the stop rule of Monkin §4.4 holds (with ``acceleration="anderson"``:
        iterate to the rest state, see :mod:`headsim.solvers.pbd_anderson`).

        Stops when |Σ|x_k| - Σ|x_(k-1)|| < stop_tolerance × n on ``stop_patience`` consecutive steps (after at
        least ``min_steps`` steps), or after
        ``max_steps`` steps (``converged=False``), or when ``cancel()`` returns True (checked every step).
        ``callback(state, change)`` is called after every step (progress display).
        """
        o = self.options
        if o.stabilisation_iterations:
            state = self.stabilise(state)
        if o.acceleration == "anderson":
            from headsim.solvers.pbd_anderson import solve_anderson

            return solve_anderson(self, state, history=o.anderson_history, callback=callback, cancel=cancel)
        threshold = o.stop_tolerance * self.model.n_particles
        previous = _k.sum_abs(state.positions)
        change = math.inf
        quiet = 0
        for k in range(o.max_steps):
            if cancel is not None and cancel():
                return state, SolveInfo(k, False, True, change)
            state = self.step(state)
            current = _k.sum_abs(state.positions)
            change = abs(current - previous)
            previous = current
            if callback is not None:
                callback(state, change)
            quiet = quiet + 1 if change < threshold else 0
            if k + 1 >= o.min_steps and quiet >= o.stop_patience:
                return state, SolveInfo(k + 1, True, False, change)
        return state, SolveInfo(o.max_steps, False, False, change)
