"""Rigid-segment fibres (kinematic chains, Sobottka 2008 ch. 8): the friction law (§8.3, eq. 8.51), obstacles,
the model (segments, joints, springs from EI₁, EI₂, GJ, §8.5.3) and state, their construction from polylines, and
the energies and joint gaps the step reports (SI units). The time stepping is :mod:`headsim.solvers.chains`."""

from __future__ import annotations

from dataclasses import dataclass, fields
from functools import cached_property

import numpy as np

from headsim._selection import index_selection
from headsim.errors import DivergenceError, ParameterError
from headsim.solvers._arrays import frozen_array
from headsim.solvers._kernels import chains_frames as FK

STANDARD_GRAVITY = 9.80665

# ------------------------------------------------------------------------------------------------
# friction law
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FrictionLaw:
    """Anisotropic Coulomb friction of a keratin fibre (Sobottka §8.3, Fig. 8.6).

    mu_with : coefficient for a friction *force* along +t₁, i.e. the fibre sliding towards its root
        relative to the partner (the partner moves root → tip: with the scales, low μ).
    mu_against : force along −t₁ (fibre sliding towards its tip: against the scales, high μ).
    mu_across : force along ±t₂ (across the fibre axis).
    n_directions : number m of generators d_β (multiple of 4, ≥ 4); the generators are m evenly spaced
        directions with μ_β on the limit curve made of four quarter-ellipses through the three
        principal values (the secant polygon under-estimates friction between generators by at most
        1 − cos(π/m)). m = 0: frictionless.
    """

    mu_with: float = 0.0
    mu_against: float = 0.0
    mu_across: float = 0.0
    n_directions: int = 16

    def __post_init__(self):
        if self.n_directions != 0 and (self.n_directions < 4 or self.n_directions % 4):
            raise ParameterError(f"n_directions must be 0 or a multiple of 4 (≥ 4), got {self.n_directions}")
        mus = (self.mu_with, self.mu_against, self.mu_across)
        if not all(np.isfinite(m) and m >= 0 for m in mus):
            raise ParameterError(f"friction coefficients must be finite and ≥ 0, got {mus}")
        if self.n_directions and min(mus) <= 0:
            raise ParameterError("friction coefficients must be > 0 (use FrictionLaw.none() for no friction)")

    @classmethod
    def none(cls) -> "FrictionLaw":
        return cls(0.0, 0.0, 0.0, 0)

    @classmethod
    def isotropic(cls, mu: float = 0.47, n_directions: int = 16) -> "FrictionLaw":
        """μ = 0.47 is the isotropic value of Sobottka §8.6.5.2."""
        return cls(mu, mu, mu, n_directions)

    @property
    def frictionless(self) -> bool:
        return self.n_directions == 0

    def generators(self) -> tuple[np.ndarray, np.ndarray]:
        """(m,), (m,) float64: μ_β cos φ_β, μ_β sin φ_β of the generators (CCW in (t₁, t₂))."""
        m = self.n_directions
        if m == 0:
            return np.zeros(0), np.zeros(0)
        phi = 2 * np.pi * np.arange(m) / m
        c, s = np.cos(phi), np.sin(phi)
        a = np.where(c >= 0, self.mu_with, self.mu_against)
        b = self.mu_across
        rho = 1.0 / np.sqrt((c / a) ** 2 + (s / b) ** 2)
        return np.ascontiguousarray(rho * c), np.ascontiguousarray(rho * s)

    def coefficient(self, direction_angle: float) -> float:
        """μ of the limit curve for a force at angle φ from t₁ (rad)."""
        c, s = np.cos(direction_angle), np.sin(direction_angle)
        a = self.mu_with if c >= 0 else self.mu_against
        return float(1.0 / np.sqrt((c / a) ** 2 + (s / self.mu_across) ** 2))


@dataclass(frozen=True, eq=False)
class Obstacle:
    """A static obstacle given by a signed distance field (Φ < 0 inside; ``headsim.collide``).

    level : iso-level the fibres rest on, m (the seed's level-set offset, §8.6.5).
    band : tolerance band beyond the fibre radius within which end points are reported, m
        (None: the solver's ``contact_band`` × radius).
    """

    field: object
    level: float = 0.0
    band: float | None = None
    name: str = "obstacle"


# ------------------------------------------------------------------------------------------------
# model and state
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ChainModel:
    """What a step never changes. S segments in F fibres (CSR ``segment_offsets``).

    segment_offsets : (F + 1,) int64.
    half_length : (S,) m; radius : (S,) m; mass : (S,) kg; inertia : (S, 3) kg m², body-frame
        principal moments (d₁, d₂, d₃ = axis).
    anchored : (F,) bool — root fixed to ``root_point`` (F, 3) m with frame ``root_frame`` (F, 3, 3).
    joint_stiffness : (S, 3) N m/rad — (EI₁, EI₂, GJ)/ℓ of the inner joint of every segment.
    rest_rotation : (S, 3) rad — rest relative rotation vector θ° of every inner joint (k frame).
    joint_damping : (S,) N m s — viscous joint damping (0: none).
    """

    segment_offsets: np.ndarray
    half_length: np.ndarray
    radius: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray
    anchored: np.ndarray
    root_point: np.ndarray
    root_frame: np.ndarray
    joint_stiffness: np.ndarray
    rest_rotation: np.ndarray
    joint_damping: np.ndarray

    def __post_init__(self):
        off = np.array(self.segment_offsets, np.int64)
        if off.ndim != 1 or off.size < 2 or off[0] != 0 or (np.diff(off) < 1).any():
            raise ParameterError("segment_offsets must start at 0 and give every fibre ≥ 1 segment")
        S, F = int(off[-1]), off.size - 1
        object.__setattr__(self, "segment_offsets", frozen_array(off, np.int64))
        for name, shp in (("half_length", (S,)), ("radius", (S,)), ("mass", (S,)), ("inertia", (S, 3)),
                          ("root_point", (F, 3)), ("root_frame", (F, 3, 3)), ("joint_stiffness", (S, 3)),
                          ("rest_rotation", (S, 3)), ("joint_damping", (S,))):
            object.__setattr__(self, name, frozen_array(getattr(self, name), shape=shp, name=name))
        object.__setattr__(self, "anchored", frozen_array(self.anchored, np.bool_, (F,), "anchored"))
        for name in ("half_length", "radius", "mass"):
            if not (getattr(self, name) > 0).all():
                raise ParameterError(f"{name} must be > 0")
        if not (self.inertia > 0).all():
            raise ParameterError("inertia must be > 0")
        if (self.joint_stiffness < 0).any() or (self.joint_damping < 0).any():
            raise ParameterError("joint stiffness and damping must be ≥ 0")

    @cached_property
    def kernel(self) -> "ChainModel":
        """This model with writable copies of its arrays, for the Numba kernels (cached; the solver steps with
        it). The model's own arrays are read-only, and Numba compiles a separate, slower version of a kernel
        for read-only arguments: the fused detection pass took 1.0–1.2 s per step on the reference scene with
        the read-only half lengths and radii against 0.36 s with writable copies (measured, same inputs)."""
        m = object.__new__(ChainModel)
        for f in fields(self):
            object.__setattr__(m, f.name, np.array(getattr(self, f.name)))
        m.__dict__["kernel"] = m
        return m

    @property
    def n_fibres(self) -> int:
        return self.segment_offsets.size - 1

    @property
    def n_segments(self) -> int:
        return int(self.segment_offsets[-1])

    @property
    def segment_fibre(self) -> np.ndarray:
        return np.repeat(np.arange(self.n_fibres), np.diff(self.segment_offsets))

    @property
    def is_root(self) -> np.ndarray:
        r = np.zeros(self.n_segments, bool)
        r[self.segment_offsets[:-1]] = True
        return r


def select_fibres(model: ChainModel, state: "ChainState", fibres) -> tuple[ChainModel, "ChainState"]:
    """The model and state of the fibres ``fibres`` (indices or a boolean mask over the F fibres, kept in
    increasing order) alone: their segments, roots and springs, the same time. For diagnostics on a part of a
    large scene (e.g. the fibres around a local event of a saved state); the dropped fibres' contacts go with
    them. ParameterError for an empty selection or an invalid one (:func:`headsim._selection.index_selection`)."""
    sel = index_selection(fibres, model.n_fibres, "fibre")
    if not sel.size:
        raise ParameterError("select at least one fibre")
    counts = np.diff(model.segment_offsets)[sel]
    seg = np.flatnonzero(np.isin(model.segment_fibre, sel))
    per_fibre = {"anchored", "root_point", "root_frame"}
    kw = {f.name: np.asarray(getattr(model, f.name))[sel if f.name in per_fibre else seg]
          for f in fields(model) if f.name != "segment_offsets"}
    sub = ChainModel(segment_offsets=np.concatenate([[0], np.cumsum(counts)]), **kw)
    return sub, ChainState(state.position[seg], state.rotation[seg], state.velocity[seg],
                           state.angular_velocity[seg], state.time)


@dataclass(frozen=True, eq=False)
class ChainState:
    """position (S, 3) m (centres of mass); rotation (S, 3, 3) (columns d₁, d₂, d₃); velocity (S, 3) m/s;
    angular_velocity (S, 3) rad/s (world frame); time s."""

    position: np.ndarray
    rotation: np.ndarray
    velocity: np.ndarray
    angular_velocity: np.ndarray
    time: float = 0.0

    def __post_init__(self):
        S = len(np.asarray(self.position))
        for name, shp in (("position", (S, 3)), ("rotation", (S, 3, 3)), ("velocity", (S, 3)),
                          ("angular_velocity", (S, 3))):
            a = np.ascontiguousarray(np.asarray(getattr(self, name), np.float64))
            if a.shape != shp:
                raise ParameterError(f"{name} must have shape {shp}, got {a.shape}")
            if not np.isfinite(a).all():
                raise DivergenceError(f"non-finite {name} at t = {self.time:.4g} s")
            object.__setattr__(self, name, a)


def _frames_along(nodes: np.ndarray) -> np.ndarray:
    """(n−1, 3, 3) rotation matrices of the segments of one polyline, d₃ = tangent, d₁ parallel-transported."""
    t = np.diff(nodes, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    n = len(t)
    R = np.empty((n, 3, 3))
    helper = np.array([0.0, 0.0, 1.0]) if abs(t[0, 2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    d1 = helper - (helper @ t[0]) * t[0]
    d1 /= np.linalg.norm(d1)
    for k in range(n):
        if k:
            d1 = d1 - (d1 @ t[k]) * t[k]
            d1 /= np.linalg.norm(d1)
        R[k, :, 0] = d1
        R[k, :, 1] = np.cross(t[k], d1)
        R[k, :, 2] = t[k]
    return R


def _log_so3_many(R: np.ndarray) -> np.ndarray:
    """(n, 3) rotation vectors of (n, 3, 3) rotations (vectorised eq. 8.83; exact away from θ = π)."""
    c = np.clip(0.5 * (np.trace(R, axis1=1, axis2=2) - 1.0), -1.0, 1.0)
    th = np.arccos(c)
    v = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    s = np.sin(th)
    f = np.where(th < 1e-6, 0.5, 0.5 * th / np.where(s > 1e-12, s, 1.0))
    return v * f[:, None]


def chain_model_from_polylines(nodes, fibre_offsets, *, radius: float = 35e-6, density: float = 1300.0,
                               young: float = 3.89e9, shear: float | None = None, anchored=True,
                               rest_shape: str = "straight", stiffness_scale: float = 1.0,
                               joint_damping: float = 0.0, spherical_inertia: bool = True
                               ) -> tuple[ChainModel, ChainState]:
    """Kinematic chains from fibre polylines (nodes (N, 3) m, CSR ``fibre_offsets``), at rest.

    Segments are cylinders of the given radius (m) and density (kg/m³): m = ρπr²ℓ,
    I = (m(3r² + ℓ²)/12, same, m r²/2); with ``spherical_inertia`` (default) the axial moment is raised
    to the transverse one. Then ω × Iω ≡ 0, so neglecting the gyroscopic term is exact and the
    exponential-map rotation conserves the rotational energy; with the true axial moment (ℓ/r ≈ 100,
    I₃/I₁ ≈ 1e-4) the torsion spring is 10⁴ times stiffer relative to its inertia (the half steps' rotation is
    then the exact torque-free motion of the axisymmetric segment, :func:`headsim.solvers._kernels.chains.half_step`;
    before issue 10's thirty-fifth session its exponential map moved energy from tumbling into axial spin). The price: spin about the fibre's own
    axis (rolling) is slowed by ≈ ℓ²/(6r²). Joint springs (EI₁, EI₂, GJ)/ℓ_j with EI = Eπr⁴/4,
    GJ = Gπr⁴/2 (G = E/(2(1 + 0.49)) when not given) and ℓ_j the centre distance, times
    ``stiffness_scale`` (the seed leaves the stiffness as a user parameter). ``rest_shape``:
    ``"straight"`` (θ° = 0: a helix unwinds under gravity, as in the seed's reference scene) or
    ``"initial"`` (the polylines are the rest shape). ``anchored``: bool or (F,) bool — root fixed at
    the first node with the first segment's initial frame (a clamped, elastic root joint).
    Returns the model and the state at rest (zero velocities).
    """
    x = np.asarray(nodes, np.float64)
    off = np.asarray(fibre_offsets, np.int64)
    F = off.size - 1
    if x.ndim != 2 or x.shape[1] != 3 or off[0] != 0 or off[-1] != len(x) or (np.diff(off) < 2).any():
        raise ParameterError("nodes must be (N, 3) with CSR fibre_offsets and ≥ 2 nodes per fibre")
    if rest_shape not in ("straight", "initial"):
        raise ParameterError(f"rest_shape must be 'straight' or 'initial', got {rest_shape!r}")
    if not (radius > 0 and density > 0 and young > 0 and stiffness_scale >= 0 and joint_damping >= 0):
        raise ParameterError("radius, density, young must be > 0; stiffness_scale, joint_damping ≥ 0")
    G = young / (2 * 1.49) if shear is None else float(shear)
    seg_off = off - np.arange(F + 1)
    S = int(seg_off[-1])
    pos = np.empty((S, 3))
    rot = np.empty((S, 3, 3))
    half = np.empty(S)
    for f in range(F):
        p = x[off[f]:off[f + 1]]
        L = np.linalg.norm(np.diff(p, axis=0), axis=1)
        if not (L > 0).all():
            raise ParameterError(f"fibre {f} has a zero-length segment")
        a, b = seg_off[f], seg_off[f + 1]
        pos[a:b] = 0.5 * (p[1:] + p[:-1])
        rot[a:b] = _frames_along(p)
        half[a:b] = 0.5 * L
    r = np.full(S, float(radius))
    length = 2 * half
    mass = density * np.pi * r**2 * length
    i_perp = mass * (3 * r**2 + length**2) / 12
    i_axis = i_perp if spherical_inertia else 0.5 * mass * r**2
    inertia = np.stack([i_perp, i_perp, i_axis], 1)
    anch = np.broadcast_to(np.asarray(anchored, bool), (F,)).copy()
    is_root = np.zeros(S, bool)
    is_root[seg_off[:-1]] = True
    prev = np.arange(S) - 1
    lj = np.where(is_root, 2 * half, half + half[np.maximum(prev, 0)])
    EI = young * np.pi * radius**4 / 4
    GJ = G * np.pi * radius**4 / 2
    Kj = stiffness_scale * np.stack([EI / lj, EI / lj, GJ / lj], axis=1)
    root_frame = rot[seg_off[:-1]].copy()
    root_point = pos[seg_off[:-1]] - half[seg_off[:-1], None] * rot[seg_off[:-1], :, 2]
    _check_anchored_roots_apart(root_point[anch], float(radius), np.nonzero(anch)[0])
    rest = np.zeros((S, 3))
    if rest_shape == "initial":
        Rk = np.where(is_root[:, None, None], root_frame[np.repeat(np.arange(F), np.diff(seg_off))],
                      rot[np.maximum(prev, 0)])
        rest = _log_so3_many(np.einsum("sji,sjk->sik", Rk, rot))
    model = ChainModel(seg_off, half, r, mass, inertia, anch, root_point, root_frame, Kj, rest,
                       np.full(S, float(joint_damping)))
    state = ChainState(pos, rot, np.zeros((S, 3)), np.zeros((S, 3)), 0.0)
    return model, state


def _check_anchored_roots_apart(roots: np.ndarray, radius: float, fibre_ids: np.ndarray) -> None:
    """ParameterError when two anchored roots (m) lie closer than a fibre diameter 2 ``radius``: their root
    segments would start overlapping where no motion of the chains can separate them (the anchors hold both
    ends), and the contact solves would push against the anchors for ever (measured: a 42 µm pair of the former
    head-scene roots spun its root segments up until the run diverged at t = 0.41 s)."""
    if len(roots) < 2:
        return
    from scipy.spatial import cKDTree

    pairs = cKDTree(roots).query_pairs(2.0 * radius, output_type="ndarray")
    d = np.linalg.norm(roots[pairs[:, 0]] - roots[pairs[:, 1]], axis=1) if len(pairs) else np.zeros(0)
    pairs, d = pairs[d < 2.0 * radius], d[d < 2.0 * radius]  # touching roots (exactly a diameter apart) are fine
    if len(pairs):
        i = int(np.argmin(d))
        a, b = fibre_ids[pairs[i, 0]], fibre_ids[pairs[i, 1]]
        raise ParameterError(f"{len(pairs)} pair(s) of anchored fibre roots lie closer than the fibre diameter "
                             f"{2e6 * radius:.4g} µm (closest: fibres {a} and {b}, {d[i] * 1e6:.3g} µm apart): their root "
                             "segments would overlap where the anchors hold them; space the roots at least a diameter apart")


def chain_state_from_polylines(model: ChainModel, nodes) -> ChainState:
    """State at rest whose segments run along the polylines (same CSR layout as the model)."""
    x = np.asarray(nodes, np.float64)
    F = model.n_fibres
    off = model.segment_offsets + np.arange(F + 1)
    pos = np.empty((model.n_segments, 3))
    rot = np.empty((model.n_segments, 3, 3))
    for f in range(F):
        p = x[off[f]:off[f + 1]]
        a, b = model.segment_offsets[f], model.segment_offsets[f + 1]
        pos[a:b] = 0.5 * (p[1:] + p[:-1])
        rot[a:b] = _frames_along(p)
    return ChainState(pos, rot, np.zeros_like(pos), np.zeros_like(pos))


def polylines_from_state(model: ChainModel, state: ChainState) -> np.ndarray:
    """(F, n+1, 3) node polylines for fibres of equal segment count n (root node, then every segment's
    outer end), m. Raises for fibres of different lengths."""
    n = np.diff(model.segment_offsets)
    if (n != n[0]).any():
        raise ParameterError("polylines_from_state needs fibres of equal segment counts")
    d3 = state.rotation[:, :, 2]
    tips = state.position + model.half_length[:, None] * d3
    roots = state.position[model.segment_offsets[:-1]] - (model.half_length[:, None] * d3)[model.segment_offsets[:-1]]
    out = np.empty((model.n_fibres, n[0] + 1, 3))
    out[:, 0] = roots
    out[:, 1:] = tips.reshape(model.n_fibres, n[0], 3)
    return out


# ------------------------------------------------------------------------------------------------
# energies and joint gaps
# ------------------------------------------------------------------------------------------------
def _inv_inertia_world(model: ChainModel, R: np.ndarray) -> np.ndarray:
    return _scaled_frames(R, 1.0 / model.inertia)


# per-segment passes (no reductions across segments, so both builds give the same numbers): prange from this size
FRAME_PASS_PARALLEL = 4096


def _f64(a):
    return np.ascontiguousarray(a, np.float64)


def _scaled_frames(R: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(S, 3, 3) R diag(d) Rᵀ per segment (a world inertia tensor or its inverse; R (S, 3, 3), d (S, 3))."""
    out = np.empty((len(R), 3, 3))
    (FK.scaled_frames_parallel if len(R) >= FRAME_PASS_PARALLEL else FK.scaled_frames)(_f64(R), _f64(d), out)
    return out


def _apply_scaled(R: np.ndarray, d: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(S, 3) R diag(d) Rᵀ w per segment, without forming the matrices (one Numba pass: 0.1 ms on 35,500
    segments against 2 ms for NumPy's two batched products)."""
    out = np.empty((len(R), 3))
    (FK.apply_scaled_parallel if len(R) >= FRAME_PASS_PARALLEL else FK.apply_scaled)(_f64(R), _f64(d), _f64(w), out)
    return out


def _joint_frames(model: ChainModel, state: ChainState):
    """(R_k (S, 3, 3) the frame each segment's inner joint is measured from — the previous segment's, the root
    frame at a root —, active (S,) bool, prev, is_root, fibre) (NumPy; the energy ledger benchmark's joint
    angles)."""
    S = model.n_segments
    is_root = model.is_root
    prev = np.maximum(np.arange(S) - 1, 0)
    fib = model.segment_fibre
    Rk = np.where(is_root[:, None, None], model.root_frame[fib], state.rotation[prev])
    active = ~is_root | model.anchored[fib]
    return Rk, active, prev, is_root, fib


def chain_energies(model: ChainModel, state: ChainState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(S,) each, per segment, in one Numba pass: kinetic energy ½ (m v² + ωᵀ I_w ω) (J), the spring energy
    ½ Σ_c K_c (θ_c − θ°_c)² of its inner joint (θ = log(R_kᵀ R_l), eq. 8.83; J) and that joint's gap norm ‖d‖
    (eq. 8.76; m); the last two 0 at free roots."""
    S = model.n_segments
    fib = model.segment_fibre
    active = np.ascontiguousarray(~model.is_root | model.anchored[fib])
    kin, spring, gap = np.empty(S), np.empty(S), np.empty(S)
    (FK.chain_stats_parallel if S >= FRAME_PASS_PARALLEL else FK.chain_stats)(
        _f64(state.position), _f64(state.rotation), _f64(state.velocity), _f64(state.angular_velocity), _f64(model.mass),
        _f64(model.inertia), _f64(model.half_length), np.ascontiguousarray(model.is_root), active,
        np.ascontiguousarray(fib, np.int64), _f64(model.root_point), _f64(model.root_frame),
        _f64(model.joint_stiffness), _f64(model.rest_rotation), np.empty((S, 3, 3)), kin, spring, gap)
    return kin, spring, gap


def kinetic_energy(model: ChainModel, state: ChainState) -> float:
    """½ Σ (m v² + ωᵀ I_w ω), J."""
    return float(chain_energies(model, state)[0].sum())


def potential_energy(model: ChainModel, state: ChainState, gravity=(0.0, -STANDARD_GRAVITY, 0.0)) -> float:
    """−Σ m gᵀx, J."""
    return float(-(model.mass * (state.position @ np.asarray(gravity, float))).sum())


def spring_energy(model: ChainModel, state: ChainState) -> float:
    """½ Σ_j Σ_c K_c (θ_c − θ°_c)², J (θ = log(R_kᵀ R_l) of every active joint)."""
    return float(chain_energies(model, state)[1].sum())


def joint_gaps(model: ChainModel, state: ChainState) -> np.ndarray:
    """(S,) m: gap norm ‖d‖ of every segment's inner joint (eq. 8.76; 0 for free roots)."""
    return chain_energies(model, state)[2]
