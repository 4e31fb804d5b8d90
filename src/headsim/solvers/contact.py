"""Contact as an energy, and the quasi-static contact solve the mask app builds on.

The implicit and quasi-static solvers need contact as a potential with gradient and Hessian. Every
contact here is a penalty ``E = sum_i kappa a_i max(0, d_i)^2 / 2`` on a per-vertex penetration depth
d_i (m), with ``kappa`` a pressure per metre of penetration (Pa/m) and ``a_i`` the vertex's share of
the surface area (m^2), so the contact pressure at vertex i is ``kappa d_i`` (Pa) and the force
``kappa a_i d_i`` (N), independent of the mesh resolution. Choose kappa ~ 100-1000 x E / h (E the
softer modulus, h the contact length scale) so that penetration stays well below the indentation.

Terms (all share the signature of :class:`ContactTerm`):

- :class:`SphereObstacle` -- an analytic rigid sphere (e.g. the Hertz indenter), optionally moved
  by a force-controlled rigid driver.
- :class:`PlaneContact` -- lagged "contact planes": each active vertex a of one body keeps an exit
  point q on a triangle of the other surface (barycentric weights fixed) and a direction r; the gap
  g = (x_a - q) . r is linear in the positions, so E, its gradient and its (exact, PSD) Hessian are
  cheap. q may lie on a deformable body (forces on both, equal and opposite) or on a rigid driven
  surface. The active set and the directions are refreshed between Newton solves by
  :meth:`PlaneContact.update`, using either the seed's consistent directions (Heinze eqs.
  3.9-3.13, :mod:`headsim.solvers.contact_consistent`) or the naive shortest way out.

Rigid drivers: a :class:`RigidDriver` is one extra unknown u (m), the translation of a rigid part
along ``axis``; its conjugate force is ``force`` (N), i.e. the energy gets ``-force u``. This is the
strap force on a rigid mask shell: at equilibrium the contact forces on the shell balance the strap
force exactly. A driver with ``displacement`` set instead is held at that translation and its
reaction force is reported.

:func:`solve_quasi_static` minimises elastic + external + contact energy over the free vertex
positions and the driver unknowns by Newton with line search, refreshing the lagged contact data in
an outer loop until the active set no longer changes. It accepts a warm start (positions and driver
displacements of a previous solution) and returns per-vertex contact forces and pressures
(contact force / vertex area, Pa) and the reaction forces at fixed vertices.

Mask use (next issue): face tissue = FEM model with fixed bone vertices; cushion = deformable FEM
body in the same model (several bodies share one model, ``body`` ids); shell = rigid surface on one
driver along the strap axis with the strap force; ``PlaneContact`` between skin and cushion
(``margin`` > 0 so that contacts about to close are seen before the first Newton step), and the
cushion glued to the shell with :class:`DriverAttachment` (or a ``PlaneContact`` with the shell as
rigid master). Warm-start a sweep over strap forces with the previous ``positions`` and
``driver_displacement``; the contact planes live in the ``PlaneContact`` objects, so reuse them too.

Limitations: frictionless unless ``PlaneContact(friction=mu, friction_slip=eps)`` (lagged Coulomb);
contact planes are lagged (kept from first detection unless
``refresh_planes``), which suits small sliding; slaves must be deformable vertices (a rigid part
touches the deformable body through ``PlaneContact`` with the rigid surface as master); a body that
is not constrained and not yet in contact makes Newton's system singular -- start in contact or
within ``margin``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from headsim.errors import ConvergenceError, ParameterError
from headsim.mesh import geometry
from headsim.solvers.newton import NewtonOptions, minimize_newton, rigid_body_modes


@dataclass(frozen=True)
class RigidDriver:
    """A rigid part's translation u (m) along ``axis``, driven by ``force`` (N) or held at ``displacement``."""

    axis: tuple[float, float, float] | np.ndarray
    force: float | None = None
    displacement: float | None = None

    def __post_init__(self):
        a = np.asarray(self.axis, dtype=np.float64)
        if a.shape != (3,) or not np.isfinite(a).all() or np.linalg.norm(a) == 0:
            raise ParameterError(f"driver axis must be a non-zero 3-vector, got {self.axis}")
        object.__setattr__(self, "axis", a / np.linalg.norm(a))
        if (self.force is None) == (self.displacement is None):
            raise ParameterError("a rigid driver needs exactly one of force (N) and displacement (m)")

    @property
    def is_free(self) -> bool:
        return self.force is not None


def surface_vertex_areas(n_vertices: int, triangles: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """(n,) float64, m^2: a third of the area of the incident surface triangles (0 off the surface)."""
    area = geometry.triangle_areas(vertices, triangles)
    out = np.zeros(n_vertices)
    np.add.at(out, np.asarray(triangles).ravel(), np.repeat(area / 3.0, 3))
    return out


class ContactTerm:
    """Base class: a penalty contact energy on (x (n, 3), u (r,)).

    energy(x, u) -> J; gradient(x, u) -> ((n, 3) N, (r,) N); hessian(x, u) -> (3n + r, 3n + r) PSD;
    update(x, u) -> bool refreshes lagged data; vertex_forces(x, u) -> (n, 3) N contact force on each
    vertex; vertex_pressure(x, u) -> (n,) Pa.
    """

    def update(self, x: np.ndarray, u: np.ndarray) -> bool:
        return False

    def start(self, x: np.ndarray, u: np.ndarray) -> None:
        """Called once at the start of every :func:`solve_quasi_static` (before the first update)."""


@dataclass(eq=False)
class SphereObstacle(ContactTerm):
    """Rigid sphere (centre ``center`` + u_driver axis, radius ``radius``) pushing on ``vertices``.

    d_i = radius - |x_i - c| (penetration, m); E = sum kappa a_i max(0, d_i)^2 / 2. The Hessian is
    the Gauss-Newton part kappa a_i grad d grad d^T (PSD; the dropped curvature term is of relative
    size d / radius).

    center : (3,) m; radius : m; penalty : kappa, Pa/m; vertices : (k,) int64 candidate vertices;
    areas : (k,) m^2 their surface areas; driver : index of a RigidDriver moving the sphere, or None.
    """

    center: np.ndarray
    radius: float
    penalty: float
    vertices: np.ndarray
    areas: np.ndarray
    driver: int | None = None
    axis: np.ndarray | None = None  # filled by solve_quasi_static from the driver

    def _geometry(self, x, u):
        c = np.asarray(self.center, dtype=np.float64)
        if self.driver is not None:
            c = c + u[self.driver] * self.axis
        y = x[self.vertices] - c
        rho = np.linalg.norm(y, axis=1)
        n = y / np.maximum(rho, 1e-300)[:, None]
        d = np.maximum(self.radius - rho, 0.0)
        return n, d

    def energy(self, x, u):
        _, d = self._geometry(x, u)
        return 0.5 * self.penalty * float(np.sum(self.areas * d * d))

    def gradient(self, x, u):
        n, d = self._geometry(x, u)
        gx = np.zeros_like(x)
        s = self.penalty * self.areas * d
        np.add.at(gx, self.vertices, -s[:, None] * n)
        gu = np.zeros(len(u))
        if self.driver is not None:
            gu[self.driver] = float(np.sum(s * (n @ self.axis)))
        return gx, gu

    def hessian(self, x, u):
        n_dof = 3 * len(x) + len(u)
        nn, d = self._geometry(x, u)
        act = d > 0
        if not act.any():
            return sp.csr_matrix((n_dof, n_dof))
        vid, nv, w = self.vertices[act], nn[act], self.penalty * self.areas[act]
        # J = [-n (dofs of x_i), n . axis (driver dof)]
        cols = [3 * vid[:, None] + np.arange(3)[None, :]]
        vals = [-nv]
        if self.driver is not None:
            cols.append(np.full((len(vid), 1), 3 * len(x) + self.driver))
            vals.append((nv @ self.axis)[:, None])
        cols = np.concatenate(cols, axis=1)
        vals = np.concatenate(vals, axis=1)
        k = cols.shape[1]
        rows = np.repeat(cols, k, axis=1).ravel()
        cc = np.tile(cols, (1, k)).ravel()
        data = (w[:, None, None] * vals[:, :, None] * vals[:, None, :]).ravel()
        return sp.csr_matrix((data, (rows, cc)), shape=(n_dof, n_dof))

    def vertex_forces(self, x, u):
        n, d = self._geometry(x, u)
        f = np.zeros_like(x)
        np.add.at(f, self.vertices, (self.penalty * self.areas * d)[:, None] * n)
        return f

    def vertex_pressure(self, x, u):
        _, d = self._geometry(x, u)
        p = np.zeros(len(x))
        p[self.vertices] = self.penalty * d
        return p


@dataclass(eq=False)
class DriverAttachment(ContactTerm):
    """Vertices glued to a rigid driver: E = k/2 sum |x_i - (X_i + u axis)|^2 (stiff springs).

    Lets a deformable part (a mask cushion) follow a force-driven rigid part (the shell) it is glued
    to. vertices : (k,) int64; anchor : (k, 3) m, their positions at u = 0; driver : RigidDriver index;
    stiffness : N/m per vertex (choose >> the part's own stiffness, e.g. 1e3 E h).
    """

    vertices: np.ndarray
    anchor: np.ndarray
    driver: int
    stiffness: float
    axis: np.ndarray | None = None

    def _offset(self, x, u):
        return x[self.vertices] - (np.asarray(self.anchor) + u[self.driver] * self.axis)

    def energy(self, x, u):
        return 0.5 * self.stiffness * float(np.sum(self._offset(x, u) ** 2))

    def gradient(self, x, u):
        d = self.stiffness * self._offset(x, u)
        gx = np.zeros_like(x)
        np.add.at(gx, self.vertices, d)
        gu = np.zeros(len(u))
        gu[self.driver] = -float(np.sum(d @ self.axis))
        return gx, gu

    def hessian(self, x, u):
        n_dof = 3 * len(x) + len(u)
        k = self.stiffness
        dof = (3 * np.asarray(self.vertices)[:, None] + np.arange(3)).ravel()
        ud = 3 * len(x) + self.driver
        a = np.tile(self.axis, len(self.vertices))
        rows = np.concatenate([dof, dof, np.full(len(dof), ud), [ud]])
        cols = np.concatenate([dof, np.full(len(dof), ud), dof, [ud]])
        data = np.concatenate([np.full(len(dof), k), -k * a, -k * a, [k * len(self.vertices)]])
        return sp.csr_matrix((data, (rows, cols)), shape=(n_dof, n_dof))

    def vertex_forces(self, x, u):
        return np.zeros_like(x)  # a bond, not a contact

    def vertex_pressure(self, x, u):
        return np.zeros(len(x))


@dataclass(eq=False)
class PlaneContact(ContactTerm):
    """Penalty on lagged contact planes between vertices of one body and the surface of another.

    Each active contact c: vertex ``slave[c]`` (index into x), exit point q_c = sum_b w_cb y_cb where
    y are the three triangle vertices -- deformable ones (index into x) or rigid ones (rows of
    ``rigid_vertices`` translated by the driver), direction r_c (unit, pointing out of the other
    body). Gap g_c = (x_a - q_c) . r_c; E = sum kappa a_c max(0, -g_c)^2 / 2.

    Built and refreshed by :meth:`update` from the current positions:

    slave_vertices : (k,) int64, candidates (surface vertices of body A)
    slave_areas : (k,) m^2
    master_triangles : (t, 3) int64 triangles of the other surface (indices into x, or into
        ``rigid_vertices`` when that is given)
    rigid_vertices : (p, 3) m rest positions of a rigid master surface, or None (deformable master)
    driver : RigidDriver index moving the rigid master, or None (fixed rigid / deformable)
    penalty : kappa, Pa/m
    direction : "consistent" (Heinze eqs. 3.9-3.13) or "naive" (shortest way out)
    slave_edges : (e, 2) int64 springs / tet edges of body A (needed for "consistent")
    margin : m, an active contact stays active while its gap is below this
    refresh_planes : recompute the plane of every active contact at each update (default: a contact
        keeps the plane of its first detection, computed at the smallest penetration, where the
        consistent direction is best defined; new contacts get fresh planes). Refreshing suits large
        sliding; keeping makes the outer loop converge (it stops when the active set is stable).
    friction : Coulomb coefficient mu (0: frictionless, the default)
    friction_slip : m, the tangential slip eps below which a contact sticks elastically (needed when
        friction > 0; choose well below the displacements of interest, e.g. 1e-3 x the element size)
    friction_tolerance : relative change of the lagged normal forces that triggers another outer
        iteration of :func:`solve_quasi_static`

    Friction (lagged Coulomb, the quasi-static form of the lagged friction potential of Incremental
    Potential Contact, Li et al. 2020, sec. 5): each active contact c keeps the normal force
    lambda_c = kappa a_c max(0, -g_c) of the last update and an anchor, its relative position
    x_a - q_c at the start of the solve (or at its first detection). With the tangential slip
    s_c = (I - r_c r_c^T) ((x_a - q_c) - anchor_c) the energy gets
    sum mu lambda_c f0(|s_c|), f0(y) = y^2 / (2 eps) for y < eps and y - eps / 2 above: a stick
    spring of stiffness mu lambda_c / eps up to the Coulomb limit, then a constant force mu lambda_c
    opposing the slip. Its Hessian is PSD (mu lambda / eps P, or mu lambda / y (P - s s^T / y^2)).
    The outer loop of :func:`solve_quasi_static` refreshes lambda_c until it changes by less than
    ``friction_tolerance`` (a fixed point in the normal forces), so at equilibrium |f_T| <= mu lambda
    holds with the converged normal forces. Anchors are reset at the start of every solve: a
    sequence of warm-started solves is a sequence of load increments.
    """

    slave_vertices: np.ndarray
    slave_areas: np.ndarray
    master_triangles: np.ndarray
    penalty: float
    rigid_vertices: np.ndarray | None = None
    driver: int | None = None
    direction: str = "consistent"
    slave_edges: np.ndarray | None = None
    axis: np.ndarray | None = None
    margin: float = 0.0
    refresh_planes: bool = False
    friction: float = 0.0
    friction_slip: float | None = None
    friction_tolerance: float = 1e-3
    # lagged contact data
    active: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))      # (c,) index into slave_vertices
    tri_vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    weights: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    normal_force: np.ndarray = field(default_factory=lambda: np.zeros(0))      # (c,) N, lagged lambda_c
    anchor: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))       # (c, 3) m

    def __post_init__(self):
        if self.friction < 0 or not np.isfinite(self.friction):
            raise ParameterError(f"friction coefficient must be >= 0, got {self.friction}")
        if self.friction > 0 and (self.friction_slip is None or not self.friction_slip > 0):
            raise ParameterError("friction > 0 needs friction_slip > 0 (m): the slip below which contacts stick")
        if self.direction not in ("consistent", "naive"):
            raise ParameterError(f"direction must be 'consistent' or 'naive', got {self.direction!r}")
        if self.direction == "consistent" and self.slave_edges is None:
            raise ParameterError("consistent directions need slave_edges (the springs / tet edges of the body)")
        self.slave_vertices = np.asarray(self.slave_vertices, dtype=np.int64)
        self.slave_areas = np.asarray(self.slave_areas, dtype=np.float64)
        self.master_triangles = np.asarray(self.master_triangles, dtype=np.int64)

    # -- geometry of the master surface ---------------------------------------------------------------
    def _master_positions(self, x, u):
        if self.rigid_vertices is None:
            return x
        y = np.asarray(self.rigid_vertices, dtype=np.float64)
        if self.driver is not None:
            y = y + u[self.driver] * self.axis
        return y

    def _gaps(self, x, u):
        y = self._master_positions(x, u)
        q = np.einsum("cb,cbk->ck", self.weights, y[self.tri_vertices])
        xa = x[self.slave_vertices[self.active]]
        return np.einsum("ck,ck->c", xa - q, self.normals)

    def energy(self, x, u):
        if len(self.active) == 0:
            return 0.0
        d = np.maximum(-self._gaps(x, u), 0.0)
        e = 0.5 * self.penalty * float(np.sum(self.slave_areas[self.active] * d * d))
        if self._has_friction:
            y = np.linalg.norm(self._slip(x, u), axis=1)
            eps = self.friction_slip
            f0 = np.where(y < eps, 0.5 * y * y / eps, y - 0.5 * eps)
            e += self.friction * float(np.sum(self.normal_force * f0))
        return e

    # -- lagged Coulomb friction ----------------------------------------------------------------------
    @property
    def _has_friction(self) -> bool:
        return self.friction > 0 and len(self.active) > 0 and len(self.normal_force) == len(self.active)

    def _relative(self, x, u):
        """(c, 3) m: x_a - q_c."""
        y = self._master_positions(x, u)
        q = np.einsum("cb,cbk->ck", self.weights, y[self.tri_vertices])
        return x[self.slave_vertices[self.active]] - q

    def _slip(self, x, u):
        """(c, 3) m: tangential slip (I - r r^T) ((x_a - q_c) - anchor_c)."""
        s = self._relative(x, u) - self.anchor
        return s - np.einsum("ck,ck->c", s, self.normals)[:, None] * self.normals

    def _relative_jacobian(self, x, u):
        """Dof columns (c, K) and d(x_a - q_c)/dz as (c, 3, K)."""
        nc = len(self.active)
        eye = np.broadcast_to(np.eye(3), (nc, 3, 3))
        cols = [3 * self.slave_vertices[self.active][:, None] + np.arange(3)]
        jac = [eye]
        if self.rigid_vertices is None:
            for b in range(3):
                cols.append(3 * self.tri_vertices[:, b][:, None] + np.arange(3))
                jac.append(-self.weights[:, b][:, None, None] * eye)
        elif self.driver is not None:
            cols.append(np.full((nc, 1), 3 * len(x) + self.driver))
            jac.append(np.broadcast_to(-np.asarray(self.axis)[None, :, None], (nc, 3, 1)))
        return np.concatenate(cols, axis=1), np.concatenate(jac, axis=2)

    def _friction_derivatives(self, x, u):
        """dE_f/d(relative) (c, 3) and its PSD Hessian (c, 3, 3)."""
        s = self._slip(x, u)
        y = np.linalg.norm(s, axis=1)
        eps = self.friction_slip
        ml = self.friction * self.normal_force
        stick = y < eps
        r = self.normals
        proj = np.eye(3)[None] - r[:, :, None] * r[:, None, :]
        g = np.where(stick[:, None], (ml / eps)[:, None] * s, ml[:, None] * s / np.maximum(y, 1e-300)[:, None])
        shat = s / np.maximum(y, 1e-300)[:, None]
        h_slide = (ml / np.maximum(y, 1e-300))[:, None, None] * (proj - shat[:, :, None] * shat[:, None, :])
        h = np.where(stick[:, None, None], (ml / eps)[:, None, None] * proj, h_slide)
        return g, h

    def _friction_gradient(self, x, u, flat):
        g, _ = self._friction_derivatives(x, u)
        cols, jac = self._relative_jacobian(x, u)
        np.add.at(flat, cols.ravel(), np.einsum("cik,ci->ck", jac, g).ravel())

    def _friction_hessian(self, x, u, n_dof):
        _, h = self._friction_derivatives(x, u)
        cols, jac = self._relative_jacobian(x, u)
        k = cols.shape[1]
        data = np.einsum("cip,cij,cjq->cpq", jac, h, jac)
        rows = np.repeat(cols, k, axis=1).ravel()
        cc = np.tile(cols, (1, k)).ravel()
        return sp.csr_matrix((data.ravel(), (rows, cc)), shape=(n_dof, n_dof))

    def friction_forces(self, x, u) -> np.ndarray:
        """(n, 3) N: the friction part of :meth:`vertex_forces` on the slave vertices (tangential)."""
        out = np.zeros_like(x)
        if self._has_friction:
            g, _ = self._friction_derivatives(x, u)
            np.add.at(out, self.slave_vertices[self.active], -g)
        return out

    def start(self, x, u) -> None:
        """Anchor the friction of the current contacts at the current positions (a new load increment)."""
        if self.friction > 0 and len(self.active):
            self.anchor = self._relative(x, u)
            if len(self.normal_force) != len(self.active):
                self.normal_force = self.penalty * self.slave_areas[self.active] * np.maximum(-self._gaps(x, u), 0.0)

    def _jacobian(self, x, u):
        """Columns (c, k) and values (c, k) of dg_c/dz (z = [x.ravel(), u])."""
        nc = len(self.active)
        r = self.normals
        cols = [3 * self.slave_vertices[self.active][:, None] + np.arange(3)]
        vals = [r]
        if self.rigid_vertices is None:
            for b in range(3):
                cols.append(3 * self.tri_vertices[:, b][:, None] + np.arange(3))
                vals.append(-self.weights[:, b][:, None] * r)
        elif self.driver is not None:
            cols.append(np.full((nc, 1), 3 * len(x) + self.driver))
            vals.append(-(r @ self.axis)[:, None])
        return np.concatenate(cols, axis=1), np.concatenate(vals, axis=1)

    def gradient(self, x, u):
        gx = np.zeros_like(x)
        gu = np.zeros(len(u))
        if len(self.active) == 0:
            return gx, gu
        d = np.maximum(-self._gaps(x, u), 0.0)
        s = -self.penalty * self.slave_areas[self.active] * d  # dE/dg
        cols, vals = self._jacobian(x, u)
        flat = np.zeros(3 * len(x) + len(u))
        np.add.at(flat, cols.ravel(), (s[:, None] * vals).ravel())
        if self._has_friction:
            self._friction_gradient(x, u, flat)
        return flat[:3 * len(x)].reshape(-1, 3), flat[3 * len(x):]

    def hessian(self, x, u):
        n_dof = 3 * len(x) + len(u)
        if len(self.active) == 0:
            return sp.csr_matrix((n_dof, n_dof))
        d = -self._gaps(x, u)
        w = self.penalty * self.slave_areas[self.active] * (d > 0)
        cols, vals = self._jacobian(x, u)
        k = cols.shape[1]
        rows = np.repeat(cols, k, axis=1).ravel()
        cc = np.tile(cols, (1, k)).ravel()
        data = (w[:, None, None] * vals[:, :, None] * vals[:, None, :]).ravel()
        h = sp.csr_matrix((data, (rows, cc)), shape=(n_dof, n_dof))
        if self._has_friction:
            h = h + self._friction_hessian(x, u, n_dof)
        return h

    def vertex_forces(self, x, u):
        """(n, 3) N contact force on every deformable vertex (slaves and deformable masters), friction included."""
        gx, _ = self.gradient(x, u)
        return -gx

    def vertex_pressure(self, x, u):
        """(n,) Pa: kappa x penetration at the slave vertices."""
        p = np.zeros(len(x))
        if len(self.active):
            d = np.maximum(-self._gaps(x, u), 0.0)
            p[self.slave_vertices[self.active]] = self.penalty * d
        return p

    # -- active set and lagged directions ------------------------------------------------------------
    def update(self, x, u) -> bool:
        """Refresh the active contacts and their planes from the current positions.

        Active: slave vertices inside the master surface (plane from :func:`exit_points`, consistent or
        naive direction), vertices outside but closer than ``margin`` (plane through the closest
        surface point, normal towards the vertex: no force until they touch), and previously active
        vertices whose gap is still below ``margin`` (they keep their plane unless
        ``refresh_planes``). Returns True if the set of active vertices changed.
        """
        from headsim.solvers.contact_consistent import _bvh, exit_points

        y = self._master_positions(x, u)
        tree = _bvh(y, self.master_triangles)
        old_active = self.active
        old_pos = {a: i for i, a in enumerate(old_active.tolist())}
        res = exit_points(x, self.slave_vertices, y, self.master_triangles, method=self.direction,
                          edges=self.slave_edges, bvh=tree)
        k = len(self.slave_vertices)
        tri = np.zeros((k, 3), np.int64)
        wts = np.zeros((k, 3))
        nrm = np.zeros((k, 3))
        ok = np.zeros(k, dtype=bool)
        fresh = res.valid & (res.triangle >= 0)
        tri[fresh] = self.master_triangles[res.triangle[fresh]]
        wts[fresh] = res.barycentric[fresh]
        nrm[fresh] = res.direction[fresh]
        ok |= fresh
        if self.margin > 0:
            near = np.flatnonzero(~res.inside)
            if len(near):
                cp = tree.closest_points(x[self.slave_vertices[near]], max_distance=self.margin)
                hit = cp.triangle >= 0
                idx = near[hit]
                vec = x[self.slave_vertices[idx]] - cp.point[hit]
                dist = np.linalg.norm(vec, axis=1)
                n_tri = tree.triangle_normals(cp.triangle[hit])
                direction = np.where(dist[:, None] > 1e-12 * self.margin, vec / np.maximum(dist, 1e-300)[:, None], n_tri)
                tri[idx] = self.master_triangles[cp.triangle[hit]]
                wts[idx] = cp.barycentric[hit]
                nrm[idx] = direction
                ok[idx] = True
        if len(old_active):
            g_old = self._gaps(x, u)
            for i, a in enumerate(old_active.tolist()):
                if g_old[i] < self.margin or res.inside[a]:
                    if not self.refresh_planes or not ok[a]:
                        tri[a], wts[a], nrm[a] = self.tri_vertices[i], self.weights[i], self.normals[i]
                        ok[a] = True
        ok &= np.linalg.norm(nrm, axis=1) > 0
        new_active = np.flatnonzero(ok)
        changed = set(new_active.tolist()) != set(old_pos)
        old_force = dict(zip(old_active.tolist(), self.normal_force.tolist())) \
            if len(self.normal_force) == len(old_active) else {}
        old_anchor = dict(zip(old_active.tolist(), self.anchor)) if len(self.anchor) == len(old_active) else {}
        self.active, self.tri_vertices, self.weights, self.normals = new_active, tri[ok], wts[ok], nrm[ok]
        if self.friction > 0:
            rel = self._relative(x, u)
            self.anchor = np.array([old_anchor[a] if a in old_anchor else rel[i]
                                    for i, a in enumerate(new_active.tolist())]).reshape(-1, 3)
            lam = self.penalty * self.slave_areas[new_active] * np.maximum(-self._gaps(x, u), 0.0)
            before = np.array([old_force.get(a, 0.0) for a in new_active.tolist()])
            if len(lam) and np.max(np.abs(lam - before)) > self.friction_tolerance * max(float(lam.max()), 1e-300):
                changed = True
            if changed:
                self.normal_force = lam
            else:
                # converged fixed point: keep the lambda the last solve used, so that the returned
                # state is an exact equilibrium of the energy it reports
                self.normal_force = before
        return changed


@dataclass(frozen=True)
class QuasiStaticOptions:
    """Options of :func:`solve_quasi_static`.

    newton : inner Newton options
    max_contact_updates : outer refreshes of the lagged contact data
    force_tolerance : N; default 1e-6 x (largest applied force, driver force, or weight)
    inexact_updates : None (every Newton solve to ``force_tolerance``) or a fraction q: while the
        lagged contact data still changes, a Newton solve stops once its |g|_inf has fallen to q
        times its value at the start of that solve (the next update moves the equilibrium anyway);
        after an update that changes nothing, the solve is finished to ``force_tolerance`` and the
        contact data checked once more, so the answer meets the same tolerances
    """

    newton: NewtonOptions = NewtonOptions(relative_tolerance=1e-10)
    max_contact_updates: int = 20
    force_tolerance: float | None = None
    inexact_updates: float | None = None

    def __post_init__(self):
        if self.inexact_updates is not None and not 0.0 < self.inexact_updates < 1.0:
            raise ParameterError(f"inexact_updates must be None or in (0, 1), got {self.inexact_updates}")


@dataclass(frozen=True, eq=False)
class QuasiStaticResult:
    """Equilibrium of :func:`solve_quasi_static`.

    positions : (n, 3) m; driver_displacement : (r,) m; contact_forces : (n, 3) N on the deformable
    vertices; contact_pressure : (n,) Pa; reaction_forces : (n, 3) N that the fixed vertices exert
    on the body; driver_forces : (r,) N contact force on each driven part along its axis;
    newton_iterations : total; contact_updates : outer iterations; timings : CPU s per phase
    (contact_update = detection and lagged planes; the others as in NewtonResult.timings, summed);
    gradient_norm, tolerance : |g|_inf (N) of the last Newton solve and the tolerance it aimed at
    (``gradient_norm > tolerance`` only where Newton stopped at round-off, NewtonResult.converged).
    """

    positions: np.ndarray
    driver_displacement: np.ndarray
    contact_forces: np.ndarray
    contact_pressure: np.ndarray
    reaction_forces: np.ndarray
    driver_forces: np.ndarray
    newton_iterations: int
    contact_updates: int
    timings: dict = field(default_factory=dict)
    gradient_norm: float = 0.0
    tolerance: float = 0.0


def solve_quasi_static(model, contacts: Sequence[ContactTerm] = (), drivers: Sequence[RigidDriver] = (), *,
                       initial_positions: np.ndarray | None = None, initial_drivers: np.ndarray | None = None,
                       fixed_dofs: np.ndarray | None = None,
                       options: QuasiStaticOptions = QuasiStaticOptions(),
                       progress: Callable[[int, float, float], None] | None = None) -> QuasiStaticResult:
    """Static equilibrium: minimise E_model(x) + sum contact(x, u) - sum F_k u_k.

    model : MassSpringModel or FemModel (its ``fixed`` vertices stay at ``initial_positions``)
    contacts : contact terms (their lagged data is refreshed here)
    drivers : rigid drivers; contact terms refer to them by index
    initial_positions : (n, 3) m warm start (default: rest positions); fixed vertices keep these
    initial_drivers : (r,) m warm start of the driver translations
    fixed_dofs : (n, 3) bool, optional per-component constraints (symmetry planes) added to ``fixed``
    progress : called as ``progress(newton_iterations_so_far, |g|_inf, tolerance)`` (N) before every
        Newton iteration (:func:`headsim.solvers.newton.minimize_newton`)
    """
    x0 = np.array(model.rest_positions if initial_positions is None else initial_positions, dtype=np.float64)
    n = len(x0)
    r = len(drivers)
    u0 = np.zeros(r) if initial_drivers is None else np.array(initial_drivers, dtype=np.float64)
    for k, d in enumerate(drivers):
        if not d.is_free:
            u0[k] = d.displacement
    for c in contacts:
        if getattr(c, "driver", None) is not None:
            if not 0 <= c.driver < r:
                raise ParameterError(f"contact refers to driver {c.driver}, but {r} drivers were given")
            c.axis = drivers[c.driver].axis
    fixed = np.repeat(np.asarray(model.fixed, dtype=bool), 3).reshape(n, 3)
    if fixed_dofs is not None:
        fixed = fixed | np.asarray(fixed_dofs, dtype=bool).reshape(n, 3)
    free = np.concatenate([~fixed.ravel(), [d.is_free for d in drivers]]).astype(bool)
    forces_u = np.array([d.force if d.is_free else 0.0 for d in drivers])

    def split(z):
        return z[:3 * n].reshape(n, 3), z[3 * n:]

    def energy(z):
        x, u = split(z)
        e = model.energy(x) - float(forces_u @ u)
        return e + sum(c.energy(x, u) for c in contacts)

    def gradient(z):
        x, u = split(z)
        gx = model.gradient(x)
        gu = -forces_u.copy()
        for c in contacts:
            a, b = c.gradient(x, u)
            gx = gx + a
            gu = gu + b
        return np.concatenate([gx.ravel(), gu])

    def hessian(z, project=True):
        x, u = split(z)
        h = sp.block_diag([model.hessian(x, project=project), sp.csr_matrix((r, r))], format="csr") if r else \
            model.hessian(x, project=project)
        for c in contacts:
            # terms with an indefinite exact Hessian (barrier contact) take the projection flag
            h = h + (c.hessian(x, u, project=project) if getattr(c, "projects_hessian", False) else c.hessian(x, u))
        return h

    def near_null(z):
        modes = rigid_body_modes(z[:3 * n].reshape(n, 3))
        return np.vstack([modes, np.zeros((r, 6))])

    limited = [c for c in contacts if hasattr(c, "step_fraction")]

    def step_limit(z, dz):
        # barrier contacts (headsim.solvers.barrier) admit only collision-free steps
        x, u = split(z)
        x1, u1 = split(z + dz)
        return min([1.0] + [c.step_fraction(x, u, x1, u1) for c in limited])

    scale = max([abs(f) for f in forces_u] + [float(np.max(np.abs(model.external_force))) if n else 0.0] + [0.0])
    tol = options.force_tolerance if options.force_tolerance is not None else 1e-6 * scale if scale > 0 else None
    size = float(np.linalg.norm(np.ptp(x0, axis=0))) or 1.0
    max_step = options.newton.max_step if options.newton.max_step is not None else 0.05 * size
    newton = NewtonOptions(**{**options.newton.__dict__, "force_tolerance": tol, "max_step": max_step})
    z = np.concatenate([x0.ravel(), u0])
    total_it = 0
    timings: dict[str, float] = {}
    amg_cache: dict = {}  # the AMG hierarchy is reused across the outer contact loop

    def update_contacts():
        t = time.process_time()
        changed = [c.update(*split(z)) for c in contacts]
        timings["contact_update"] = timings.get("contact_update", 0.0) + time.process_time() - t
        return changed

    for c in contacts:
        if hasattr(c, "start"):  # duck-typed terms (e.g. the mask's shell attachment) may lack it
            c.start(*split(z))
    update_contacts()
    finishing = options.inexact_updates is None  # solve to the final tolerance
    changes = outer = 0
    while True:
        outer += 1
        # between contact updates: converged at inexact_updates x the solve's starting |g| (or the tolerance)
        inner = newton if finishing else replace(
            newton, relative_tolerance=max(newton.relative_tolerance, options.inexact_updates))
        done_before = total_it
        res = minimize_newton(energy, gradient, hessian, z, free, inner, near_null=near_null,
                              what="quasi-static contact solve", amg_cache=amg_cache,
                              step_limit=step_limit if limited else None,
                              progress=None if progress is None else
                              (lambda it, g, t: progress(done_before + it, g, t)))
        z = res.z
        total_it += res.iterations
        for k, v in res.timings.items():
            if k in ("amg_setup", "cg"):
                timings[k] = v  # cumulative over the shared preconditioner
            else:
                timings[k] = timings.get(k, 0.0) + v
        if not any(update_contacts()):
            if finishing or (tol is not None and res.gradient_norm <= tol):
                break
            finishing = True  # the lagged data is settled: finish this fixed point to the tolerance
            continue          # (an extra solve, not an update that changed anything)
        changes += 1
        finishing = options.inexact_updates is None
        if changes >= options.max_contact_updates:
            raise ConvergenceError(f"contact active set still changing after {options.max_contact_updates} updates")
    x, u = split(z)
    cf = np.zeros_like(x)
    pressure = np.zeros(n)
    gu_contact = np.zeros(r)
    for c in contacts:
        cf += c.vertex_forces(x, u)
        pressure = np.maximum(pressure, c.vertex_pressure(x, u))
        gu_contact += c.gradient(x, u)[1]
    # reaction at constrained dofs: the support must supply R = dPi/dx there (free dofs have dPi/dx = 0)
    g = gradient(z)[:3 * n].reshape(n, 3)
    reaction = np.where(fixed, g, 0.0)
    return QuasiStaticResult(x, u, cf, pressure, reaction, -gu_contact, total_it, outer, timings,
                             res.gradient_norm, res.tolerance)
