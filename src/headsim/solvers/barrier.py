"""Barrier contact between surfaces of a deformable model (Incremental Potential Contact).

Contact as a smooth, distance-based energy on the *current* geometry, so that the contact force sits
exactly where two surfaces are close and no surface ever passes through another (Li et al., "Incremental
Potential Contact: intersection- and inversion-free, large-deformation dynamics", ACM TOG 39(4) 2020;
the area-weighted, "improved max" formulation of Li, Kaufman & Jiang, "Convergent Incremental
Potential Contact", 2023). It replaces lagged contact planes where surfaces slide (the mask fit,
:mod:`headsim.mask.fit`: a lagged plane kept from first contact goes stale on a curved cushion).
Every point-triangle and edge-edge pair of two different surface components closer than ``dhat``
(m) contributes

    E = kappa * w * dhat * f(d / dhat),   f(t) = -(t^2 - 1)^2 ln(t) / 2   (0 < t < 1, else 0)

(ipctk's normalised clamped-log barrier on squared distances, "physical" scaling; w the pair's
area weight, m^2: the vertex area of a point-triangle pair, the edge area of an edge-edge pair).
So ``kappa`` (Pa) is a pressure: the contact pressure at distance d is

    p(d) = kappa * g(d / dhat),   g(t) = -f'(t) = 2 t (t^2 - 1) ln t + (t^2 - 1)^2 / (2 t)

(g(0.9) = 0.056, g(0.5) = 1.08, g(0.1) = 5.4, g -> inf as t -> 0), i.e. the two surfaces are
separated by a compliant layer of thickness ``dhat`` whose pressure rises without bound as it is
squeezed. The energy is infinite for touching surfaces; :meth:`BarrierContact.step_fraction`
(continuous collision detection) keeps every Newton step collision-free, so the line search never
leaves the admissible set (Li et al. 2020 sec. 4.3). The Hessian is projected to PSD per contact pair
(``PSDProjectionMethod.CLAMP``).

**CCD** (``ccd``): "additive" (default) is the additive CCD of Li, Kaufman & Jiang (Codimensional
Incremental Potential Contact, ACM TOG 40(4) 2021, sec. 5): each pair advances by conservative steps
bounded by its current distance over its largest relative displacement, and stops where its distance
has fallen to 10 % of the initial one (ipctk's conservative rescaling 0.9). It is conservative in exact
arithmetic but not provably so in floating point (Wang et al., "A Large Scale Benchmark and an
Inclusion-Based Algorithm for Continuous Collision Detection", ACM TOG 40(5) 2021), so the stepped
surfaces are checked for crossings (``ipctk.has_intersections``, 7 ms on the mask fit's 2.8k contact
vertices) and, where they cross, the fraction is recomputed by "tight-inclusion" (Wang et al. 2021,
provably conservative; ipctk's default). Measured on the 94 steps of the mask fit's cold 15 N solve
(demo problem, recorded and replayed): 0.73 s against 3.37 s, and fractions 1.56x those of the
inclusion method on average (larger on 73 steps, equal on 19, 0.94x on 2; up to 4.1x), so the fit
takes fewer Newton iterations (the six-fit set of :mod:`headsim.mask.fit`: 388 -> 298). On a point
falling straight through a plane both stop short of it (tests/solvers/test_barrier.py).

Geometry kernels (broad phase, distances, their derivatives, CCD) come from the IPC Toolkit's Python
bindings (``ipctk``, MIT licence); this module maps them onto the model's degrees of freedom and
the :class:`headsim.solvers.contact.ContactTerm` interface of :func:`solve_quasi_static`.
Contact pairs are rebuilt from the current positions at every evaluation (no lagged data): the
energy is one function of the positions, so Newton's method converges on it directly.

**Friction** (``friction`` = mu > 0, ``friction_slip`` = eps, m): IPC's lagged smoothed Coulomb
friction (Li et al. 2020 sec. 5), in its quasi-static form: the dissipation potential

    D(x) = sum_k w_k mu lambda_k f0(|P_k Gamma_k (x - x_a)|),  f0'(s) = f1(s) = 2 s / eps - s^2 / eps^2
                                                                   (s < eps), 1 (s >= eps)

over the tangential collisions k built from the barrier's contact pairs at a lagged configuration
(their normal force lambda_k from the barrier, closest-point weights Gamma_k and tangent-plane
projection P_k frozen there; :class:`headsim.solvers.barrier_friction.LaggedFriction`), with x_a the
anchors: each surface vertex's position at the first accepted Newton iterate (recorded when its
Hessian is evaluated) at which it took part in a contact pair (within dhat) -- for the pairs already
within dhat, the start -- so the tangential displacement is the two surfaces' relative slip since
they touched (a vertex first seen touching at an update is anchored there). Its force is
mu lambda_k f1(s) along the slip (Li et al. 2020 eq. 15): the Coulomb force mu lambda_k where the slip
s exceeds eps (sliding), a stiff, smooth rise from 0 below it (sticking). The tangent planes are
normal to a smoothed contact normal (``friction_normals="smooth"``: the vertex normals of the first
contact surface -- the skin in the mask fit -- interpolated at each pair's closest point on it):
ipctk's own plane of an edge-edge pair is spanned by edge a and (e_a x e_b) x e_a, arbitrary for the
nearly parallel edges of a cushion lying on skin (tests/solvers/test_barrier_friction.py: up to
65 deg off between two sheets 1e-3 rad apart).

The lagged data are refreshed by :meth:`BarrierContact.update` (the outer loop of
:func:`headsim.solvers.solve_quasi_static`) until the friction forces at the solution move by less
than ``tolerance`` (N) when taken there. The plain lagged iteration (take them at the last solution)
can end in a 2-cycle: on the mask fit (demo, mu = 0.5, 8 N) cushion vertices over a skin crease
alternated by 270 um and their friction forces by 0.02 N for 30 updates, with ipctk's and with the
smoothed planes alike, i.e. the lagged map is continuous there but its slope is beyond -1. Relaxation
turns that into a contraction: ``friction_lag="adaptive"`` takes the data at
xbar_k = xbar_k-1 + omega (x_k - xbar_k-1), halves omega (from 1) whenever the fixed-point residual
did not fall and lets it grow back while it falls (:meth:`BarrierContact._relaxed_lag_configuration`). Anchoring every vertex at the
solve's start instead (one quasi-static load step) counts the approach of pairs that touch later as
slip, and the outer loop alternated at 2.5 and 15 N as well (:mod:`headsim.mask.fit`, "Barrier
contact").
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from headsim.errors import ParameterError
from headsim.mesh.geometry import vertex_components
from headsim.solvers.barrier_friction import LaggedFriction


def barrier_pressure(distance, dhat: float, stiffness: float) -> np.ndarray:
    """Contact pressure p(d) = kappa g(d / dhat) of :class:`BarrierContact` (Pa; 0 at d >= dhat,
    inf at d <= 0). distance : m; dhat : m; stiffness : kappa, Pa."""
    t = np.asarray(distance, dtype=np.float64) / dhat
    with np.errstate(divide="ignore", invalid="ignore"):
        g = 2.0 * t * (t * t - 1.0) * np.log(t) + (t * t - 1.0) ** 2 / (2.0 * t)
    return stiffness * np.where(t >= 1.0, 0.0, np.where(t <= 0.0, np.inf, g))


def barrier_distance(pressure: float, dhat: float, stiffness: float) -> float:
    """Distance (m) at which :func:`barrier_pressure` equals ``pressure`` (Pa, > 0): bisection on
    the monotone g."""
    if not pressure > 0:
        raise ParameterError(f"pressure must be > 0 Pa, got {pressure}")
    lo, hi = 0.0, dhat
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if barrier_pressure(mid, dhat, stiffness) > pressure:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


#: smallest relaxation factor of the lagged friction's outer iteration (BarrierContact._relaxed_lag_configuration)
FRICTION_OMEGA_MIN = 1.0 / 16
#: factor by which that relaxation factor grows (up to 1) after an update whose residual fell
FRICTION_OMEGA_GROWTH = 1.5


class BarrierContact:
    """IPC barrier contact among the surface components of one model (module doc).

    n_vertices : vertices of the model (the contact acts on ``triangles``' vertices only)
    rest_positions : (n, 3) m, the area weights are taken here
    triangles : (t, 3) int model vertex ids of the contact surfaces; pairs within one body never
        interact (no self-contact), pairs of different bodies do
    bodies : (n,) int body label per model vertex (e.g. 0 skin, 1 mask); None: every connected
        component of ``triangles`` is a body. A cropped skin can fall into several pieces that lie
        closer than dhat to each other: as separate bodies they would repel (the mask fit on
        identity000 of the bundled faces: two skin pieces 20 um apart, no admissible start)
    dhat : m, barrier activation distance (thickness of the contact layer)
    stiffness : kappa, Pa (the contact pressure scale, module doc)
    friction : Coulomb coefficient mu (0: frictionless); friction_slip : eps, m, the slip below which a
        contact sticks (the regularisation; needed when friction > 0)
    friction_normals : "smooth" (default: the first contact surface's smoothed normal for every pair) or
        "pair" (ipctk's tangent planes), module doc "Friction"
    friction_lag : "adaptive" (default: the outer iteration relaxed when it stops contracting) or
        "plain" (module doc)
    ccd : "additive" (default) or "tight-inclusion": the continuous collision detection of
        :meth:`step_fraction` (module doc, "CCD")
    threads : ipctk's thread count (a process-wide setting of the IPC Toolkit, set here). 1, the
        default, makes a solve reproducible: ipctk's parallel broad phase and CCD reduce in a
        scheduling-dependent order, and the mask fit's Newton path is sensitive to the last bits
        (measured: the same cold 10 N fit took 78 and 81 iterations in two runs with 2 threads, 83 in
        every run with 1; its time per iteration is within the run-to-run scatter). None leaves it.

    A :class:`headsim.solvers.contact.ContactTerm` for :func:`headsim.solvers.solve_quasi_static`:
    energy / gradient / hessian on (x, u) (the driver unknowns u carry nothing here),
    ``step_fraction`` for the line search, ``vertex_forces`` (N) and ``vertex_pressure`` (Pa, force
    magnitude over the vertex's area on its surface).
    """

    def __init__(self, rest_positions: np.ndarray, triangles: np.ndarray, dhat: float, stiffness: float,
                 threads: int | None = 1, friction: float = 0.0, friction_slip: float | None = None,
                 friction_normals: str = "smooth", friction_lag: str = "adaptive", bodies: np.ndarray | None = None,
                 ccd: str = "additive"):
        import ipctk

        if threads is not None:
            ipctk.set_num_threads(int(threads))

        x = np.asarray(rest_positions, dtype=np.float64)
        tri = np.asarray(triangles, dtype=np.int64)
        if tri.ndim != 2 or tri.shape[1] != 3 or len(tri) == 0:
            raise ParameterError("barrier contact needs a non-empty (t, 3) triangle array")
        if not (np.isfinite(dhat) and dhat > 0 and np.isfinite(stiffness) and stiffness > 0):
            raise ParameterError(f"barrier dhat and stiffness must be > 0, got {dhat} m, {stiffness} Pa")
        if not (np.isfinite(friction) and friction >= 0):
            raise ParameterError(f"friction coefficient must be >= 0, got {friction}")
        if ccd not in ("additive", "tight-inclusion"):
            raise ParameterError(f"ccd must be 'additive' or 'tight-inclusion', got {ccd!r}")
        self.ccd = ccd
        self._additive = ipctk.AdditiveCCD() if ccd == "additive" else None
        #: steps whose additive-CCD fraction was recomputed by tight inclusion (the stepped surfaces crossed)
        self.ccd_fallbacks = 0
        if friction > 0 and not (friction_slip is not None and np.isfinite(friction_slip) and friction_slip > 0):
            raise ParameterError("friction > 0 needs friction_slip > 0 (m), the stick/slip regularisation")
        self.mu = float(friction)
        self.eps = float(friction_slip) if friction > 0 else None
        #: N: the outer loop ends when an update moves no friction force by more than this
        self.tolerance = 1e-9
        self._tangential = None  # lagged friction (barrier_friction.LaggedFriction)
        if friction_normals not in ("smooth", "pair"):
            raise ParameterError(f"friction_normals must be 'smooth' or 'pair', got {friction_normals!r}")
        self.friction_normals = friction_normals
        if friction_lag not in ("adaptive", "plain"):
            raise ParameterError(f"friction_lag must be 'adaptive' or 'plain', got {friction_lag!r}")
        self.friction_lag = friction_lag
        self._anchor = None      # (k, 3) per surface vertex: the slip's origin (where it first touched)
        self._anchored = None
        self._first_touch = None
        self.n = len(x)
        self.dhat = float(dhat)
        self.stiffness = float(stiffness)
        self.ids, local = np.unique(tri, return_inverse=True)
        faces = np.asfortranarray(local.reshape(-1, 3).astype(np.int32))
        edges = np.asfortranarray(ipctk.edges(faces))
        self._ipc = ipctk
        self.mesh = ipctk.CollisionMesh(np.asfortranarray(x[self.ids]), edges, faces)
        self.body = self._body_labels(faces, bodies)  # per contact vertex
        filt = np.concatenate([faces, self._body_links()]).astype(np.int32)
        self.mesh.can_collide = ipctk.make_connected_components_filter(np.asfortranarray(filt))
        self.areas = np.asarray(self.mesh.vertex_areas, dtype=np.float64).copy()  # m^2 per contact vertex
        self.potential = ipctk.BarrierPotential(ipctk.NormalizedClampedLogBarrier(), self.dhat, self.stiffness, True)
        self._frictional = self.mu > 0
        dof = (3 * self.ids[:, None] + np.arange(3)).ravel()
        self._dof = dof
        self._key = None
        self._collisions = None
        self.n_drivers = 0

    def _body_labels(self, faces, bodies) -> np.ndarray:
        """(k,) int body of every contact vertex: ``bodies`` where given (per model vertex), else the
        connected component of the contact triangles."""
        if bodies is None:
            return vertex_components(len(self.ids), faces)
        bodies = np.asarray(bodies)
        if bodies.shape != (self.n,):
            raise ParameterError(f"bodies must give one label per model vertex ({self.n}), got {bodies.shape}")
        return np.unique(bodies[self.ids], return_inverse=True)[1].astype(np.int64)

    def _body_links(self) -> np.ndarray:
        """(m, 3) degenerate triangles (a, b, b) that chain the contact vertices of each body, so that
        ipctk's connected-components filter sees one component per body."""
        links = [np.zeros((0, 3), dtype=np.int64)]
        for b in np.unique(self.body):
            members = np.flatnonzero(self.body == b)
            links.append(np.stack([members[:-1], members[1:], members[1:]], axis=1))
        return np.concatenate(links)

    # -- contact pairs at a configuration (cached for the last positions) -----------------------
    def _surface(self, x: np.ndarray) -> np.ndarray:
        return np.asfortranarray(x[self.ids])

    def collisions(self, x: np.ndarray):
        """ipctk NormalCollisions of the positions x (n, 3) m (pairs closer than dhat)."""
        v = self._surface(x)
        key = v.tobytes()
        if key != self._key:
            c = self._ipc.NormalCollisions()
            c.use_area_weighting = True
            c.collision_set_type = self._ipc.NormalCollisions.IMPROVED_MAX_APPROX
            c.build(self.mesh, v, self.dhat)
            self._key, self._collisions = key, c
        return self._collisions, v

    def minimum_distance(self, x: np.ndarray, search: float | None = None) -> float:
        """Smallest distance (m) between two contact components at x, looked for up to ``search``
        (default dhat; inf when nothing is that close)."""
        c = self._ipc.NormalCollisions()
        v = self._surface(x)
        c.build(self.mesh, v, float(search if search is not None else self.dhat))
        # ipctk returns the smallest *squared* distance
        return float(np.sqrt(c.compute_minimum_distance(self.mesh, v))) if len(c) else np.inf

    def vertices_within(self, x: np.ndarray, distance: float) -> np.ndarray:
        """(n,) bool: model vertices of a contact primitive (point, edge or triangle) that lies closer
        than ``distance`` (m) to a primitive of another component at x -- the vertices a barrier with
        that activation distance puts contact force on."""
        c = self._ipc.NormalCollisions()
        c.use_area_weighting = True
        c.collision_set_type = self._ipc.NormalCollisions.IMPROVED_MAX_APPROX
        v = self._surface(x)
        c.build(self.mesh, v, float(distance))
        out = np.zeros(self.n, dtype=bool)
        out[self.ids[self._collision_vertices(c)]] = True
        return out

    def _collision_vertices(self, collisions) -> np.ndarray:
        """(m,) int64 sorted local surface-vertex ids of the points, edges and triangles of ipctk
        normal or tangential ``collisions``."""
        edges, faces = self.mesh.edges, self.mesh.faces
        return np.unique(np.asarray([i for k in range(len(collisions))
                                     for i in collisions[k].vertex_ids(edges, faces) if i >= 0], dtype=np.int64))

    def intersecting(self, x: np.ndarray) -> bool:
        """True when two contact components cross at x."""
        return bool(self._ipc.has_intersections(self.mesh, self._surface(x)))

    # -- ContactTerm interface -------------------------------------------------------------------
    def energy(self, x, u) -> float:
        c, v = self.collisions(x)
        e = self._friction_energy(x)
        if len(c) == 0:
            return e
        if c.compute_minimum_distance(self.mesh, v) <= 0.0:
            return np.inf
        e += float(self.potential(c, self.mesh, v))
        return e if np.isfinite(e) else np.inf

    def _normal_gradient(self, x) -> np.ndarray:
        c, v = self.collisions(x)
        g = np.zeros(3 * self.n)
        if len(c):
            g[self._dof] = self.potential.gradient(c, self.mesh, v)
        return g

    def _full_gradient(self, x) -> np.ndarray:
        g = self._normal_gradient(x)
        if self._has_friction():
            g[self._dof] += self._tangential.gradient(self._slip(x)).ravel()
        return g

    # -- lagged friction (module doc) --------------------------------------------------------------
    def _has_friction(self) -> bool:
        return self._frictional and self._tangential is not None and len(self._tangential) > 0

    def _slip(self, x) -> np.ndarray:
        """(k, 3) m: displacement of the contact surfaces since the anchor (ipctk's "velocities")."""
        return np.asfortranarray(self._surface(x) - self._anchor)

    def _friction_energy(self, x) -> float:
        if not self._has_friction():
            return 0.0
        return self._tangential.energy(self._slip(x))

    def _lag_friction(self, x, at=None) -> None:
        c, v = self.collisions(x if at is None else at)
        t = self._ipc.TangentialCollisions()
        if len(c):
            t.build(self.mesh, v, c, self.potential, self.mu)
        self._tangential = LaggedFriction(t, self.mesh, v, self.eps, self.friction_normals, body=self.body)
        # the slip of a vertex counts from where it first touched (module doc); vertices that touch now
        # without a recorded first touch are anchored here
        self._note_first_touch(x)
        fresh = ~self._anchored & ~np.isnan(self._first_touch[:, 0])
        self._anchor[fresh] = self._first_touch[fresh]
        self._anchored |= fresh

    def friction_forces(self, x, u=None) -> np.ndarray:
        """(n, 3) N, the friction force on every model vertex (zero without friction)."""
        f = np.zeros(3 * self.n)
        if self._has_friction():
            f[self._dof] = -self._tangential.gradient(self._slip(x)).ravel()
        return f.reshape(-1, 3)

    def gradient(self, x, u):
        return self._full_gradient(x).reshape(-1, 3), np.zeros(len(u))

    def _note_first_touch(self, x) -> None:
        """Record where each surface vertex first takes part in a contact pair (within dhat). Called from
        :meth:`hessian`, which the Newton solve evaluates at its accepted iterates only (the gradient is
        also evaluated at trial steps the line search may reject), so this is the first accepted iterate
        at which the vertex touches."""
        c, v = self.collisions(x)
        ids = self._collision_vertices(c)
        new = ids[np.isnan(self._first_touch[ids, 0])]
        self._first_touch[new] = v[new]

    #: :func:`solve_quasi_static` passes ``project`` (exact Hessian first, projected as the fallback)
    projects_hessian = True

    def hessian(self, x, u, project: bool = True):
        """Sparse (3n + r)^2 Hessian; per contact pair projected to PSD (eigenvalues clamped) when
        ``project``, else exact (quadratic convergence near the solution, possibly indefinite)."""
        if self._frictional and self._first_touch is not None:
            self._note_first_touch(x)
        c, v = self.collisions(x)
        n_dof = 3 * self.n + len(u)
        if len(c) == 0:
            return sp.csr_matrix((n_dof, n_dof))
        method = self._ipc.PSDProjectionMethod.CLAMP if project else self._ipc.PSDProjectionMethod.NONE
        h = self.potential.hessian(c, self.mesh, v, method)
        if self._has_friction():
            h = h + self._tangential.hessian(self._slip(x), project=project)
        h = h.tocoo()
        return sp.csr_matrix((h.data, (self._dof[h.row], self._dof[h.col])), shape=(n_dof, n_dof))

    def step_fraction(self, x0, u0, x1, u1) -> float:
        """Largest fraction of the straight step x0 -> x1 that stays collision-free (CCD, module doc)."""
        v0, v1 = self._surface(x0), self._surface(x1)
        if self._additive is not None:
            f = float(self._ipc.compute_collision_free_stepsize(self.mesh, v0, v1, narrow_phase_ccd=self._additive))
            if not self._ipc.has_intersections(self.mesh, np.asfortranarray(v0 + f * (v1 - v0))):
                return f
            self.ccd_fallbacks += 1
        return float(self._ipc.compute_collision_free_stepsize(self.mesh, v0, v1))

    def update(self, x, u) -> bool:
        """Frictionless: nothing lagged (module doc). With friction: one step of the outer fixed-point
        iteration on the lagged friction. Its residual is the largest change (N) of a friction force
        at x between the operator the last solve used and the one taken at x itself; at most
        ``tolerance`` ends the loop (False) with the former kept, so that x is an exact equilibrium of
        the energy it reports. Otherwise the next operator is taken at the relaxed configuration of
        :meth:`_relaxed_lag_configuration` (True)."""
        if not self._frictional:
            return False
        used = self._tangential
        before = self.friction_forces(x)
        self._lag_friction(x)
        residual = float(np.max(np.abs(self.friction_forces(x) - before), initial=0.0))
        if residual <= self.tolerance:
            self._tangential = used
            return False
        at = self._relaxed_lag_configuration(x, residual)
        if at is not x:
            self._lag_friction(x, at)
        return True

    def _relaxed_lag_configuration(self, x, residual: float):
        """Where the next lagged friction operator is taken: xbar_k = xbar_k-1 + omega (x_k - xbar_k-1),
        x_k the solve's result under the operator taken at xbar_k-1 (module doc, "Friction").
        ``friction_lag="adaptive"``: omega starts at 1 (the plain lagged iteration of Li et al. 2020),
        is halved, down to FRICTION_OMEGA_MIN, at every update whose fixed-point residual (N) is not
        smaller than the one before -- the damping of a fixed-point iteration that stopped contracting
        (a 2-cycle of the plain iteration: the map's slope beyond -1, which relaxation by omega < 1
        turns into a contraction) -- and grows by FRICTION_OMEGA_GROWTH, up to 1, at every update whose
        residual fell (a residual that rises once because new vertices touched would otherwise slow
        the rest of the loop for good: the coarse test problem at 20 N, mu = 0.5, still 0.021 N from
        the 0.004 N tolerance after 30 updates at omega = 1/16, converged in 8 updates with the
        growth); "plain": omega = 1 always."""
        if self.friction_lag == "adaptive" and self._lag_residual is not None:
            if residual >= self._lag_residual:
                self._omega = max(0.5 * self._omega, FRICTION_OMEGA_MIN)
            else:
                self._omega = min(1.0, FRICTION_OMEGA_GROWTH * self._omega)
        self._lag_residual = residual
        at = x if self._omega == 1.0 else self._lag_at + self._omega * (np.asarray(x, dtype=np.float64) - self._lag_at)
        if at is not x and self.intersecting(at):
            at = x  # the blend of two admissible configurations crosses: take the operator at x
        self._lag_at = np.array(at, dtype=np.float64)
        return at

    def start(self, x, u) -> None:
        if self.intersecting(x):
            raise ParameterError("barrier contact: the surfaces already intersect at the start")
        if self._frictional:
            self._anchor = np.asfortranarray(self._surface(x).copy())
            self._anchored = np.zeros(len(self.ids), dtype=bool)
            self._first_touch = np.full((len(self.ids), 3), np.nan)
            self._lag_friction(x)
            self._lag_at = np.array(x, dtype=np.float64)
            self._lag_residual = None
            self._omega = 1.0

    def vertex_forces(self, x, u) -> np.ndarray:
        """(n, 3) N, contact force on every model vertex (minus the energy gradient)."""
        return -self._full_gradient(x).reshape(-1, 3)

    def vertex_pressure(self, x, u) -> np.ndarray:
        """(n,) Pa, the barrier's (normal) contact force magnitude over the vertex area on its contact
        surface; friction is tangential and not part of it."""
        f = -self._normal_gradient(x).reshape(-1, 3)[self.ids]
        p = np.zeros(self.n)
        p[self.ids] = np.linalg.norm(f, axis=1) / np.maximum(self.areas, 1e-300)
        return p
