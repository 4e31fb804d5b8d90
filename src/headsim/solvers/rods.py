"""Implicit Kirchhoff rods: generalised-alpha in time and arc length, batched over fibres.

Sobottka (2008), *Faserbasierte Simulation von Humanhaar*, ch. 3 (seed 002): every fibre is a
special Cosserat rod in the Kirchhoff case (inextensible, unshearable). Per node the state
``x = (v, omega, kappa, n)`` (12 values, local material components) obeys the first-order PDE
system eqs. 3.61-3.64 with the linear-elastic law ``m = K (kappa - kappa0(s))``,
``K = diag(EI1, EI2, GJ)`` (eqs. 3.55-3.57). Orientations ``R_j`` (columns d1, d2, d3) and the
centreline ``r_j`` are stored apart from x and updated by exponential maps (§3.4.5-3.4.6).

Discretisation (§3.4.3): generalised-alpha with six coefficients, ``(alpha, beta, gamma)`` in time
and in arc length; derivatives by the generalised trapezoid rules eqs. 3.154/3.155. Every cell
equation 3.153 is solved together with the trapezoid links in s for all nodes of a fibre
simultaneously: Newton with the analytic Jacobian (block-banded, bandwidth 17), a banded Gaussian
elimination with partial pivoting (factorised once per step and re-used while the residual falls by
a factor 4 per iteration, i.e. a modified Newton; re-factorised otherwise), Armijo backtracking
(iota = 1e-4, mu halved from 1) and a warm start (Algorithm 1). Batches of at least
``PARALLEL_MIN_FIBRES`` fibres are stepped by a thread-parallel Numba kernel (one banded solve per
fibre in ``prange``).

Implementation notes
--------------------
* The unknowns of the Newton system are the nodal x_j; the s-derivatives xs_j are eliminated with
  the cell equations (they are linear in xs), and the trapezoid links eq. 3.155 are the residual.
  For ``alpha_s == beta_s`` (e.g. the box scheme in s) this Jacobian is exact; otherwise the
  coupling to the previous node's mixed mass/stiffness term is lagged inside an iteration, as the
  seed lags ``d_s x_{j-1}`` (it then converges linearly).
* Loads are given in the global frame, held constant over a step and rotated into the local frames
  of the iterate (``R = R_old exp(dt (omega + omega_old) / 2)``); their rotation enters the Jacobian.
* Geometric tip BC (tip modes "guided-position" / "clamped-position"): the tip position at the end
  of the step is a residual row computed inside Newton by integrating the iterate's curvature from
  the iterate's root frame and root point (the seed's "recompute positions inside the loop" for
  point-to-point BCs, §3.4.7). Its three rows depend on every node's curvature; they are added to the
  banded factorisation by the Sherman-Morrison-Woodbury identity (three extra banded solves per
  factorisation), so the tip follows a prescribed path exactly instead of drifting by the O(ds^2)
  mismatch between velocity and curvature kinematics that a velocity BC accumulates.
* Start-up (§3.4.7): the first step of a fresh state is a backward-Euler step (alpha_t = beta_t = 0,
  gamma_t = 1), which needs neither d_t x nor d_s x of the start and returns a state in which the PDE
  holds at the nodes, so that d_t x = M^-1 (P d_s x + g) as in the seed's start-up rule (with a
  consistent contact force n, which a non-equilibrium start does not know).
* After convergence the frames are re-integrated in s from the time-updated root frame and the
  centreline follows by constant-curvature arcs; the root point moves by eq. 3.165. With the box
  scheme in s the arcs turn by the Cayley angle 2 atan(|kappa| ds / 2) instead of |kappa| ds
  (``RodSolverOptions.frame_map``): that is how the discrete equations transport vectors along
  the rod, so velocity and position kinematics agree (no drift of the tip of a twisted rod away
  from its prescribed velocity).

References: Sobottka 2008 (seed 002) ch. 3; Chung & Hulbert 1993; Jansen, Whiting & Hulbert 2000;
Gobat & Grosenbaugh 2001; Simo & Vu-Quoc 1988.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from headsim.errors import ConvergenceError, DivergenceError, ParameterError
from headsim.solvers._kernels import rods as _k

__all__ = [
    "GeneralizedAlpha",
    "RodModel",
    "RodState",
    "RodLoads",
    "RodBoundary",
    "RodSolverOptions",
    "StepReport",
    "ImplicitRodSolver",
    "initial_state",
    "seed_startup_derivatives",
    "straight_frame",
    "kinetic_energy",
    "amplification_eigenvalues",
    "FRAME_MAPS",
]


# --------------------------------------------------------------------------------------------
# coefficients
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GeneralizedAlpha:
    """The six coefficients of the space-time generalised-alpha scheme (Sobottka eq. 3.153).

    alpha weights the mass term, beta the stiffness term and Lambda, gamma is the trapezoid
    parameter (eqs. 3.154/3.155). ``alpha = beta = gamma = 1/2`` is the box (trapezoid) scheme.
    """

    alpha_t: float = 0.5
    beta_t: float = 0.5
    gamma_t: float = 0.5
    alpha_s: float = 0.5
    beta_s: float = 0.5
    gamma_s: float = 0.5

    def __post_init__(self):
        for name in ("alpha_t", "beta_t", "gamma_t", "alpha_s", "beta_s", "gamma_s"):
            v = getattr(self, name)
            if not np.isfinite(v):
                raise ParameterError(f"{name} must be finite, got {v}")
        if not (0.0 < self.gamma_t <= 1.0 and 0.0 < self.gamma_s <= 1.0):
            raise ParameterError("gamma_t and gamma_s must lie in (0, 1]")
        if not (self.beta_t < 1.0 and self.beta_s < 1.0 and self.alpha_t < 1.0 and self.alpha_s < 1.0):
            raise ParameterError("alpha and beta must be below 1")

    @classmethod
    def from_rho_inf(cls, rho_inf_t: float, rho_inf_s: float = 1.0) -> "GeneralizedAlpha":
        """Coefficients from the spectral radius at infinite frequency (eq. 3.148, corrected in
        terms of rho_inf = -lambda_inf): alpha = (3 rho - 1) / (2 (1 + rho)), beta = rho / (1 + rho),
        gamma = 1 / (1 + rho). Second-order accurate for every rho_inf in [0, 1]."""
        for r in (rho_inf_t, rho_inf_s):
            if not 0.0 <= r <= 1.0:
                raise ParameterError(f"rho_inf must be in [0, 1], got {r}")

        def abc(r):
            return (3 * r - 1) / (2 * (1 + r)), r / (1 + r), 1 / (1 + r)

        at, bt, gt = abc(rho_inf_t)
        as_, bs, gs = abc(rho_inf_s)
        return cls(at, bt, gt, as_, bs, gs)

    @classmethod
    def seed_default(cls) -> "GeneralizedAlpha":
        """The seed's setting for all examples: alpha = 0.3, beta = 0, gamma = 0.7 (first order)."""
        return cls(0.3, 0.0, 0.7, 0.3, 0.0, 0.7)

    @classmethod
    def seed_high_damping(cls) -> "GeneralizedAlpha":
        """The seed's 'high internal damping' setting (fig. 3.16): alpha = 0.4, beta = 0, gamma = 1."""
        return cls(0.4, 0.0, 1.0, 0.4, 0.0, 1.0)

    @classmethod
    def backward_euler(cls, gamma_s: float = 0.5) -> "GeneralizedAlpha":
        """Backward Euler in time (alpha_t = beta_t = 0, gamma_t = 1), trapezoid in s: L-stable."""
        return cls(0.0, 0.0, 1.0, 0.5, 0.5, gamma_s)

    @property
    def exact_jacobian(self) -> bool:
        """True when the Newton Jacobian is exact (alpha_s == beta_s)."""
        return abs(self.alpha_s - self.beta_s) < 1e-15

    def as_array(self) -> np.ndarray:
        return np.array([self.alpha_t, self.beta_t, self.gamma_t, self.alpha_s, self.beta_s, self.gamma_s])


def amplification_eigenvalues(omega_dt: complex | np.ndarray, alpha: float, beta: float, gamma: float):
    """Eigenvalues of the amplification matrix of the first-order generalised-alpha scheme for the
    test equation y' + w y = 0 (Sobottka eqs. 3.140-3.145), with Omega = w dt (complex allowed;
    an undamped oscillation of angular frequency f has Omega = i f dt).

    Returns (..., 2) complex: the physical root (closest to exp(-Omega)) first, then the spurious one.
    """
    Om = np.atleast_1d(np.asarray(omega_dt, dtype=complex))
    out = np.empty(Om.shape + (2,), dtype=complex)
    for idx, W in np.ndenumerate(Om):
        # [y, dt y']^i: y^i - gamma z^i = y^{i-1} + (1 - gamma) z^{i-1}  (eq. 3.142)
        #               Omega (1 - beta) y^i + (1 - alpha) z^i = -Omega beta y^{i-1} - alpha z^{i-1}  (eq. 3.141)
        Lm = np.array([[1.0, -gamma], [W * (1 - beta), 1 - alpha]], dtype=complex)
        Rm = np.array([[1.0, 1 - gamma], [-W * beta, -alpha]], dtype=complex)
        A = np.linalg.solve(Lm, Rm)
        lam = np.linalg.eigvals(A)
        order = np.argsort(np.abs(lam - np.exp(-W)))
        out[idx] = lam[order]
    return out


# --------------------------------------------------------------------------------------------
# model, state, loads
# --------------------------------------------------------------------------------------------
def straight_frame(tangent, normal_hint=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Right-handed frame (3, 3), columns d1, d2, d3 with d3 = tangent (unit) and d2 as close as
    possible to ``normal_hint``."""
    t = np.asarray(tangent, dtype=float)
    t = t / np.linalg.norm(t)
    h = np.asarray(normal_hint, dtype=float)
    h = h - h.dot(t) * t
    if np.linalg.norm(h) < 1e-8:
        h = np.array([1.0, 0.0, 0.0]) - t[0] * t
        if np.linalg.norm(h) < 1e-8:
            h = np.array([0.0, 1.0, 0.0]) - t[1] * t
    d2 = h / np.linalg.norm(h)
    d1 = np.cross(d2, t)
    return np.column_stack([d1, d2, t])


def _as_fibre_array(a, n_fibres, tail, name):
    a = np.asarray(a, dtype=np.float64)
    if a.shape == tail:
        a = np.broadcast_to(a, (n_fibres,) + tail)
    if a.shape != (n_fibres,) + tail:
        raise ParameterError(f"{name} must have shape {tail} or {(n_fibres,) + tail}, got {a.shape}")
    if not np.isfinite(a).all():
        raise ParameterError(f"{name} must be finite")
    out = np.array(a, dtype=np.float64, order="C")
    out.flags.writeable = False
    return out


@dataclass(frozen=True, eq=False)
class RodModel:
    """A batch of F Kirchhoff rods with the same number of segments N (what a step never changes).

    length : (F,) m
    rho_area : (F,) kg/m, rho A
    rho_inertia : (F, 3) kg m, rho (I1, I2, I1 + I2) (rotary inertia per length)
    stiffness : (F, 3) N m^2, K = (E I1, E I2, G J) (eq. 3.57)
    natural_curvature : (F, N+1, 3) 1/m, kappa0(s) at the nodes (local components)
    natural_curvature_ds : (F, N+1, 3) 1/m^2, d kappa0 / ds (eq. 3.65); central differences if None
    root_position : (F, 3) m; root_frame : (F, 3, 3), columns d1, d2, d3 at s = 0
    """

    n_segments: int
    length: np.ndarray
    rho_area: np.ndarray
    rho_inertia: np.ndarray
    stiffness: np.ndarray
    natural_curvature: np.ndarray
    root_position: np.ndarray
    root_frame: np.ndarray
    natural_curvature_ds: np.ndarray | None = None

    def __post_init__(self):
        N = int(self.n_segments)
        if N < 2:
            raise ParameterError(f"a rod needs at least 2 segments, got {N}")
        length = np.atleast_1d(np.asarray(self.length, dtype=np.float64))
        F = length.shape[0]
        if length.ndim != 1 or not (np.isfinite(length).all() and (length > 0).all()):
            raise ParameterError("length must be positive and finite, (F,) m")
        object.__setattr__(self, "n_segments", N)
        object.__setattr__(self, "length", _as_fibre_array(length, F, (), "length"))
        rA = _as_fibre_array(self.rho_area, F, (), "rho_area")
        rI = _as_fibre_array(self.rho_inertia, F, (3,), "rho_inertia")
        K = _as_fibre_array(self.stiffness, F, (3,), "stiffness")
        if (rA <= 0).any() or (rI <= 0).any() or (K <= 0).any():
            raise ParameterError("rho_area, rho_inertia and stiffness must be positive")
        object.__setattr__(self, "rho_area", rA)
        object.__setattr__(self, "rho_inertia", rI)
        object.__setattr__(self, "stiffness", K)
        k0 = _as_fibre_array(self.natural_curvature, F, (N + 1, 3), "natural_curvature")
        object.__setattr__(self, "natural_curvature", k0)
        if self.natural_curvature_ds is None:
            ds = (length / N)[:, None, None]
            dk = np.gradient(k0, axis=1) / ds
        else:
            dk = self.natural_curvature_ds
        object.__setattr__(self, "natural_curvature_ds", _as_fibre_array(dk, F, (N + 1, 3), "natural_curvature_ds"))
        object.__setattr__(self, "root_position", _as_fibre_array(self.root_position, F, (3,), "root_position"))
        R0 = _as_fibre_array(self.root_frame, F, (3, 3), "root_frame")
        err = np.abs(np.einsum("fji,fjk->fik", R0, R0) - np.eye(3)).max()
        if err > 1e-8 or (np.linalg.det(R0) < 0).any():
            raise ParameterError(f"root_frame must be a rotation matrix (orthonormality error {err:.2e})")
        object.__setattr__(self, "root_frame", R0)

    @property
    def n_fibres(self) -> int:
        return int(self.length.shape[0])

    @property
    def n_nodes(self) -> int:
        return self.n_segments + 1

    @property
    def segment_length(self) -> np.ndarray:
        """(F,) m."""
        return self.length / self.n_segments

    @property
    def arc_length(self) -> np.ndarray:
        """(F, N+1) m, s of every node."""
        return self.segment_length[:, None] * np.arange(self.n_nodes)[None, :]

    def with_natural_curvature(self, kappa0) -> "RodModel":
        return replace(self, natural_curvature=kappa0, natural_curvature_ds=None)


@dataclass(frozen=True, eq=False)
class RodState:
    """Everything a step changes and a restart needs (F fibres, N+1 nodes).

    x : (F, N+1, 12) (v m/s, omega 1/s, kappa 1/m, n N), local components
    x_t, x_s : (F, N+1, 12) time and arc-length derivatives kept by the generalised trapezoid rules
    g : (F, N+1, 12) non-derivative terms at this level (needed by beta-weighting)
    frames : (F, N+1, 3, 3) columns d1, d2, d3; positions : (F, N+1, 3) m
    time : s; derivatives_valid : False for a fresh state (the next step is a start-up step)
    """

    x: np.ndarray
    x_t: np.ndarray
    x_s: np.ndarray
    g: np.ndarray
    frames: np.ndarray
    positions: np.ndarray
    time: float = 0.0
    derivatives_valid: bool = False

    def __post_init__(self):
        for name in ("x", "x_t", "x_s", "g", "frames", "positions"):
            a = np.array(getattr(self, name), dtype=np.float64, order="C")
            a.flags.writeable = False
            object.__setattr__(self, name, a)
        if self.x.ndim != 3 or self.x.shape[2] != 12:
            raise ParameterError(f"x must be (F, N+1, 12), got {self.x.shape}")

    @property
    def velocity(self) -> np.ndarray:
        """(F, N+1, 3) m/s, centreline velocity in global components."""
        return np.einsum("fnij,fnj->fni", self.frames, self.x[:, :, 0:3])

    @property
    def curvature(self) -> np.ndarray:
        """(F, N+1, 3) 1/m, local components."""
        return self.x[:, :, 6:9]

    @property
    def tip_position(self) -> np.ndarray:
        """(F, 3) m."""
        return self.positions[:, -1, :]


FRAME_MAPS = ("auto", "cayley", "exp")


def initial_state(model: RodModel, kappa=None, x=None, time: float = 0.0, frame_map: str = "exp") -> RodState:
    """A rest state: v = omega = 0, kappa = kappa0 (or ``kappa`` (F, N+1, 3)), n = 0; or a full ``x``.

    Frames and positions follow from the root frame by integration in s with constant-curvature
    arcs: ``frame_map="exp"`` (default: exact arcs, eq. 3.162; e.g. an exact helix for constant
    kappa) or ``"cayley"`` (the map the solver uses with its default box scheme in s, see
    :attr:`RodSolverOptions.frame_map`; shapes differ by O((|kappa| ds)^2)). A state that a solver
    will step should use that solver's map (:meth:`ImplicitRodSolver.initial_state`), otherwise its
    first step re-integrates the shape with the solver's map.
    """
    if frame_map not in ("cayley", "exp"):
        raise ParameterError(f"frame_map must be 'cayley' or 'exp', got {frame_map!r}")
    F, nn = model.n_fibres, model.n_nodes
    if x is None:
        x = np.zeros((F, nn, 12))
        x[:, :, 6:9] = model.natural_curvature if kappa is None else np.broadcast_to(kappa, (F, nn, 3))
    else:
        x = np.array(np.broadcast_to(x, (F, nn, 12)), dtype=np.float64)
    if not np.isfinite(x).all():
        raise ParameterError("initial state must be finite")
    frames = np.empty((F, nn, 3, 3))
    pos = np.empty((F, nn, 3))
    _k.integrate_frames_serial(np.ascontiguousarray(model.root_frame), np.ascontiguousarray(x[:, :, 6:9]),
                              np.ascontiguousarray(model.segment_length), frames,
                              np.ascontiguousarray(model.root_position), pos, frame_map == "cayley")
    z = np.zeros((F, nn, 12))
    return RodState(x, z, z, z, frames, pos, time, False)


@dataclass(frozen=True, eq=False)
class RodLoads:
    """External loads in the GLOBAL frame, held constant over a step (re-expressed locally per iteration).

    gravity : (3,) m/s^2 (adds rho A g per length); distributed_force : (F, N+1, 3) N/m or None;
    tip_force : (F, 3) N; tip_torque : (F, 3) N m.
    """

    gravity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    distributed_force: np.ndarray | None = None
    tip_force: np.ndarray | None = None
    tip_torque: np.ndarray | None = None

    def __post_init__(self):
        g = np.asarray(self.gravity, dtype=np.float64)
        if g.shape != (3,) or not np.isfinite(g).all():
            raise ParameterError("gravity must be a finite (3,) vector, m/s^2")
        object.__setattr__(self, "gravity", g)


_TIP_MODES = {"force": 0, "velocity": 1, "velocity-torque": 2, "guided-torque": 3, "guided-position": 4,
              "clamped-position": 5}


@dataclass(frozen=True, eq=False)
class RodBoundary:
    """Boundary conditions (eq. 3.4.4), global components, re-expressed in the end frames per iteration.

    root_velocity : (F, 3) m/s and root_angular_velocity (F, 3) 1/s (zero: clamped root; else a
    moving support); tip : "force" (free tip or tip force / torque from RodLoads), "velocity"
    (tip velocity and angular velocity prescribed), "velocity-torque" (tip velocity prescribed,
    tip torque from RodLoads) or "guided-torque" (tip velocity and the transverse components of
    the tip angular velocity prescribed, the axial component of the tip torque from RodLoads) or
    "guided-position" (as "guided-torque", but the tip POSITION at the end of the step is prescribed
    instead of its velocity: the seed's geometric boundary condition, positions recomputed inside the
    Newton loop, §3.4.7; no drift between the prescribed and the actual tip path) or
    "clamped-position" (tip position and tip angular velocity prescribed);
    tip_velocity, tip_angular_velocity : (F, 3); tip_position : (F, 3) m (for the "-position" modes).
    """

    root_velocity: np.ndarray | None = None
    root_angular_velocity: np.ndarray | None = None
    tip: str = "force"
    tip_velocity: np.ndarray | None = None
    tip_angular_velocity: np.ndarray | None = None
    tip_position: np.ndarray | None = None

    def __post_init__(self):
        if self.tip not in _TIP_MODES:
            raise ParameterError(f"tip must be one of {sorted(_TIP_MODES)}, got {self.tip!r}")
        if self.tip.endswith("-position") and self.tip_position is None:
            raise ParameterError(f"tip={self.tip!r} needs tip_position (m, global)")


CLAMPED_FREE = RodBoundary()

#: batches with at least this many fibres are stepped by the thread-parallel kernel
PARALLEL_MIN_FIBRES = 8


@dataclass(frozen=True)
class RodSolverOptions:
    """Options of :class:`ImplicitRodSolver`.

    coefficients : GeneralizedAlpha (default: box scheme in s, rho_inf = 0.5 in time)
    tolerance : max-norm of the residual, each component scaled by its characteristic size
    max_iterations : Newton iterations per step; armijo : iota of eq. 3.172; max_halvings : of mu
    raise_on_failure : raise ConvergenceError when a fibre does not converge
    frame_map : how frames and centreline are integrated in s after a step: "cayley" (turning angle
      2 atan(|kappa| ds / 2) per segment: the map by which the box scheme in s transports vectors,
      so a rigid translation of a twisted rod is an exact discrete solution and the tip velocity
      agrees with the motion of the tip position), "exp" (exponential map, eq. 3.162; the two
      kinematics then differ at O((|kappa| ds)^2), i.e. position drift of strongly twisted rods) or
      "auto" (default: "cayley" for the box scheme in s, alpha_s = beta_s = gamma_s = 1/2, else "exp")
    startup : first step of a fresh state: "backward_euler" (default; needs no derivatives and finds
      a consistent contact force n) or "seed" (Sobottka Algorithm 1, i = 0: d_s x from the nodal
      values (central differences), d_t x = M^-1 (P d_s x + g) for v, omega, kappa and d_t n = 0,
      then the chosen coefficients; needs a consistent n in the start state)
    """

    coefficients: GeneralizedAlpha = field(default_factory=lambda: GeneralizedAlpha.from_rho_inf(0.5, 1.0))
    tolerance: float = 1e-9
    max_iterations: int = 40
    armijo: float = 1e-4
    max_halvings: int = 12
    raise_on_failure: bool = True
    startup: str = "backward_euler"
    frame_map: str = "auto"

    def __post_init__(self):
        if self.frame_map not in FRAME_MAPS:
            raise ParameterError(f"frame_map must be one of {FRAME_MAPS}, got {self.frame_map!r}")
        if not (self.tolerance > 0 and self.max_iterations >= 1 and 0 < self.armijo < 0.5):
            raise ParameterError("tolerance > 0, max_iterations >= 1 and 0 < armijo < 0.5 required")
        if self.startup not in ("backward_euler", "seed"):
            raise ParameterError(f"startup must be 'backward_euler' or 'seed', got {self.startup!r}")

    @property
    def resolved_frame_map(self) -> str:
        """"cayley" or "exp": the frame map ``frame_map`` stands for with these coefficients."""
        if self.frame_map != "auto":
            return self.frame_map
        c = self.coefficients
        box = all(abs(a - 0.5) < 1e-15 for a in (c.alpha_s, c.beta_s, c.gamma_s))
        return "cayley" if box else "exp"


@dataclass(frozen=True)
class StepReport:
    """Per-fibre Newton statistics of one step: iterations (F,), residual (F,), status (F,),
    residual evaluations (F,), Jacobian factorisations (F,)."""

    iterations: np.ndarray
    residual: np.ndarray
    status: np.ndarray
    evaluations: np.ndarray
    factorizations: np.ndarray


def _scales(model: RodModel) -> np.ndarray:
    """(F, 12) characteristic size of v, omega, kappa, n for residual scaling."""
    L = model.length
    EI = model.stiffness[:, :2].min(axis=1)
    tau = L**2 * np.sqrt(model.rho_area / EI)
    s = np.empty((model.n_fibres, 12))
    s[:, 0:3] = (L / tau)[:, None]
    s[:, 3:6] = (1.0 / tau)[:, None]
    s[:, 6:9] = (1.0 / L)[:, None]
    s[:, 9:12] = (EI / L**2)[:, None]
    return s


def _fibre_vec(a, F, name):
    if a is None:
        return np.zeros((F, 3))
    a = np.asarray(a, dtype=np.float64)
    a = np.broadcast_to(a, (F, 3)) if a.shape == (3,) else a
    if a.shape != (F, 3) or not np.isfinite(a).all():
        raise ParameterError(f"{name} must be finite (3,) or ({F}, 3)")
    return a


class ImplicitRodSolver:
    """Generalised-alpha space-time integrator of Kirchhoff rods (Sobottka 2008, Algorithm 1)."""

    def __init__(self, options: RodSolverOptions = RodSolverOptions()):
        self.options = options

    def initial_state(self, model: RodModel, kappa=None, x=None, time: float = 0.0) -> RodState:
        """:func:`initial_state` with this solver's frame map (``options.resolved_frame_map``)."""
        return initial_state(model, kappa=kappa, x=x, time=time, frame_map=self.options.resolved_frame_map)

    def _pack(self, model: RodModel, dt: float, startup: bool, tip_mode: int) -> np.ndarray:
        o = self.options
        c = o.coefficients.as_array()
        if startup:
            c[0:3] = (0.0, 0.0, 1.0)  # backward Euler start-up step
        par = np.empty((model.n_fibres, _k.NPAR))
        par[:, 0] = model.segment_length
        par[:, 1] = dt
        par[:, 2] = model.rho_area
        par[:, 3:6] = model.rho_inertia
        par[:, 6:9] = model.stiffness
        par[:, 9:15] = c
        par[:, 15] = o.tolerance
        par[:, 16] = o.max_iterations
        par[:, 17] = o.armijo
        par[:, 18] = tip_mode
        par[:, 19] = o.max_halvings
        par[:, 20] = 1.0 if o.resolved_frame_map == "cayley" else 0.0
        return par

    def step(self, model: RodModel, state: RodState, dt: float, loads: RodLoads = RodLoads(),
             boundary: RodBoundary = CLAMPED_FREE) -> tuple[RodState, StepReport]:
        """Advance all fibres by ``dt`` (s). Returns the new state and the Newton statistics.

        Raises DivergenceError on non-finite results and ConvergenceError when Newton fails
        (unless ``raise_on_failure`` is False).
        """
        if not (np.isfinite(dt) and dt > 0):
            raise ParameterError(f"dt must be positive, got {dt}")
        F, nn = model.n_fibres, model.n_nodes
        if state.x.shape != (F, nn, 12):
            raise ParameterError(f"state has shape {state.x.shape}, model needs {(F, nn, 12)}")
        startup = not state.derivatives_valid
        if startup and self.options.startup == "seed":
            state = seed_startup_derivatives(model, state, loads)
            startup = False
        tip_mode = _TIP_MODES[boundary.tip]
        par = self._pack(model, dt, startup, tip_mode)
        fdist = np.broadcast_to(model.rho_area[:, None, None] * loads.gravity[None, None, :], (F, nn, 3)).copy()
        if loads.distributed_force is not None:
            fd = np.asarray(loads.distributed_force, dtype=np.float64)
            if fd.shape != (F, nn, 3) or not np.isfinite(fd).all():
                raise ParameterError(f"distributed_force must be finite ({F}, {nn}, 3) N/m")
            fdist += fd
        bc = np.zeros((F, _k.NBC))
        bc[:, 0:3] = _fibre_vec(boundary.root_velocity, F, "root_velocity")
        bc[:, 3:6] = _fibre_vec(boundary.root_angular_velocity, F, "root_angular_velocity")
        bc[:, 6:9] = _fibre_vec(loads.tip_force, F, "tip_force")
        bc[:, 9:12] = _fibre_vec(loads.tip_torque, F, "tip_torque")
        if boundary.tip.endswith("-position"):
            bc[:, 12:15] = _fibre_vec(boundary.tip_position, F, "tip_position")
        else:
            bc[:, 12:15] = _fibre_vec(boundary.tip_velocity, F, "tip_velocity")
        bc[:, 15:18] = _fibre_vec(boundary.tip_angular_velocity, F, "tip_angular_velocity")
        bc[:, 18:21] = state.positions[:, 0]
        x = np.array(state.x)  # warm start
        xt = np.empty_like(x)
        xs = np.empty_like(x)
        g = np.empty_like(x)
        R = np.empty((F, nn, 3, 3))
        info = np.zeros((F, 5))
        kernel = _k.newton_step_batch if F >= PARALLEL_MIN_FIBRES else _k.newton_step_serial
        kernel(state.x, state.x_t, state.x_s, state.g, state.frames,
                             model.natural_curvature, model.natural_curvature_ds, fdist, bc, par,
                             _scales(model), x, xt, xs, g, R, info)
        report = StepReport(info[:, 0].astype(int), info[:, 1], info[:, 2].astype(int), info[:, 3].astype(int),
                            info[:, 4].astype(int))
        if not np.isfinite(x).all():
            raise DivergenceError(f"non-finite rod state at t = {state.time + dt:.4g} s (dt = {dt:g} s)")
        bad = report.status != 0
        if bad.any() and self.options.raise_on_failure:
            i = int(np.argmax(bad))
            raise ConvergenceError(
                f"{int(bad.sum())} of {F} fibres did not converge at t = {state.time + dt:.4g} s "
                f"(first: fibre {i}, residual {report.residual[i]:.3g}, status {report.status[i]}); reduce dt")
        # frames: root from the time update, the rest by integration in s; root point by eq. 3.165
        frames = np.empty_like(R)
        pos = np.empty((F, nn, 3))
        v_new = np.einsum("fij,fj->fi", R[:, 0], x[:, 0, 0:3])
        v_old = np.einsum("fij,fj->fi", state.frames[:, 0], state.x[:, 0, 0:3])
        r0 = state.positions[:, 0] + 0.5 * dt * (v_new + v_old)
        integ = _k.integrate_frames_batch if F >= PARALLEL_MIN_FIBRES else _k.integrate_frames_serial
        integ(np.ascontiguousarray(R[:, 0]), np.ascontiguousarray(x[:, :, 6:9]),
                                  np.ascontiguousarray(model.segment_length), frames, r0, pos,
                                  self.options.resolved_frame_map == "cayley")
        return RodState(x, xt, xs, g, frames, pos, state.time + dt, True), report


def seed_startup_derivatives(model: RodModel, state: RodState, loads: RodLoads = RodLoads()) -> RodState:
    """The seed's start-up rule (Algorithm 1, i = 0; eq. 3.171): d_s x by second-order differences
    of the nodal values, d_t x = M^-1 (P d_s x + g(x)) for the v, omega and kappa rows and d_t n = 0.
    Loads of the first step stand in for the (unknown) loads before it."""
    F, nn = model.n_fibres, model.n_nodes
    xs = np.gradient(state.x, axis=1) / model.segment_length[:, None, None]
    g = np.empty_like(state.x)
    xt = np.zeros_like(state.x)
    fglob = model.rho_area[:, None, None] * loads.gravity[None, None, :] + (
        0.0 if loads.distributed_force is None else np.asarray(loads.distributed_force, float))
    fglob = np.broadcast_to(fglob, (F, nn, 3))
    zero = np.zeros(3)
    for f in range(F):
        rhoI, K = model.rho_inertia[f], model.stiffness[f]
        for j in range(nn):
            floc = state.frames[f, j].T @ fglob[f, j]
            _k.node_g(state.x[f, j], floc, zero, model.natural_curvature[f, j], model.natural_curvature_ds[f, j],
                      model.rho_area[f], rhoI, K, g[f, j])
            # P xs + g  (rows: lin <- n', ang <- K kappa', compat <- omega', constraint <- v')
            q = g[f, j].copy()
            q[0:3] += xs[f, j, 9:12]
            q[3:6] += K * xs[f, j, 6:9]
            q[6:9] += xs[f, j, 3:6]
            xt[f, j, 0:3] = q[0:3] / model.rho_area[f]
            xt[f, j, 3:6] = q[3:6] / rhoI
            xt[f, j, 6:9] = q[6:9]
    return RodState(state.x, xt, xs, g, state.frames, state.positions, state.time, True)


def kinetic_energy(model: RodModel, state: RodState) -> np.ndarray:
    """(F,) J: 1/2 integral of rho A |v|^2 + omega . rho I omega ds (trapezoid rule)."""
    v = state.x[:, :, 0:3]
    w = state.x[:, :, 3:6]
    e = 0.5 * (model.rho_area[:, None] * (v**2).sum(-1) + (model.rho_inertia[:, None, :] * w**2).sum(-1))
    wts = np.ones(model.n_nodes)
    wts[0] = wts[-1] = 0.5
    return (e * wts[None, :]).sum(-1) * model.segment_length
