"""Rigid-segment fibres (kinematic chains) with Moreau midpoint time stepping, per-body contact
projection and anisotropic friction (Sobottka 2008, ch. 8; Kaufman, Edmunds & Pai 2005).

One step (:meth:`ChainSolver.step`), "variant two" of §8.6.5.3 (joints first, then contacts):

1. **Joints (Method I, Alg. 7).** From the saved t_i state, a Newton-type iteration finds the joint
   impulses P_j = (p, L*) such that the trial integration over Δt (eqs. 8.78/8.80: x + Δt(v + Δt/(2m) f),
   R ← exp(Δt ω̃) R) closes every point-joint gap (eq. 8.76); the bending/torsion spring rows
   L* = Δt[R_k K (θ − θ°) + c ω_rel] (§8.5.3, K = (EI₁, EI₂, GJ)/ℓ, θ = log(R_kᵀR_l)) are part of the
   same system and therefore implicit (unconditionally stable at Δt = 1 ms, where an explicit spring
   of a 70 µm, 3 mm segment would need Δt < 0.1 ms). The Newton matrix is the first-order
   (linearised K-matrix) Jacobian, block-tridiagonal per fibre, factorised once per step (chord
   Newton); the residual is the exact nonlinear trial integration. The orientation term f° of (8.86)
   is dropped as in the thesis.
2. **Contacts (Alg. 6).** Half step q^{i+½} = q^i + ½Δt u^i (θ = 1 convention of the source, rotation
   by the exponential map), u⁻ = u^i + Δt M⁻¹F (eq. 8.43; ``external_impulse="half"`` copies Alg. 6
   literally: contacting bodies then get only half the external impulse), detection at q^{i+½}
   (fibre–fibre: :class:`headsim.collide.fibre_bvh.PackedFibreBVH`; obstacles: signed distance fields
   sampled at the segment end points, iso-level ``level`` plus a tolerance band), persistence filter
   n·(u⁻_A − u⁻_B) ≤ ‖g‖Δt (smooth contacts count as persistent, eq. 8.9; the tolerance keeps resting
   contacts whose pre-impact velocities differ by round-off), then per body the normal QP
   ``min ½‖u − u⁻‖²_M s.t. J u ≥ v_N`` in its dual by projected Gauss–Seidel on the Delassus matrix,
   with v_N from both partners' pre-impact contact velocities weighted by their effective masses
   (eqs. 8.67–8.69), the friction programme and the restitution law u = (1+ε)u⁺ − εu⁻ + u^f
   (``contact_coupling="per-body"``, the seed's scheme). Later contact sweeps (``contact_sweeps`` > 1)
   replace v_N by the partner's current normal velocity (a block-Jacobi pass over the bodies).
   **Default** ``contact_coupling="coupled"``: the same per-contact normal rows and friction polygons
   solved by one projected (nonlinear) Gauss–Seidel over all contacts with relative velocities and
   equal and opposite impulses (Moreau–Jean NSCD), with the joints of every touched fibre in the same
   sweeps: per joint the point-joint row (the two anchors move together, J u⁺ = 0; the joints' position
   drift is left to the next step's joint stage, ``joint_gap_fraction``) and the joint's implicit bending/torsion spring over the
   second half step (extra angular impulse Λ = (½Δt² K_w + Δt c)(ω_rel − ω_rel⁻), the same linearly
   implicit spring as the joint stage), all joints of one fibre solved together exactly in each sweep
   (block-tridiagonal, :mod:`headsim.solvers._kernels.chains_coupled`; fibres in parallel), then the
   contacts one by one; between full sweeps, partial sweeps visit only the contacts that carry an
   impulse or are near their bound (same fixed point), and the solve starts from the previous
   step's impulses of the same contacts (``warm_start``) and stops on a measured residual
   (``contact_tolerance``, capped at ``qp_iterations`` sweeps). Without the spring rows the contact stage sees a floppy
   ball-joint chain: an off-centre contact impulse bends it freely (≈ 10 rad/s per step on a stacked
   5-segment fibre), the next joint stage's stiff springs push back, and stacked multi-segment layers
   gained energy a hundredfold and sank through each other within 300 steps (measured; test
   ``test_resting_stack_of_chains_...``). A contact that sits on a joint is kept once (on the inner
   segment; :func:`_unique_joint_contacts`), not as two redundant rows. The seed's per-body projection cannot hold a stack: a body squeezed between a static obstacle
   and a falling partner gets contradictory constraints (obstacle: v_n ≥ 0, partner: v_n ≤ −gΔt), and
   crossed fibre layers sink through each other within a few hundred steps (measured, see the tests).
   Fibres anchored at their roots get extra sweeps over their first segments after every unconverged full
   sweep (``root_sweeps``): next to the anchored root the solved chain hardly yields, and those rows are the
   slowest of the whole solve to converge.
3. **Harmonisation.** ``harmonisation_iterations`` > 1 repeats joints → contacts with the contact
   stage's velocity change fed into the joint trial integration, so the joints close around the
   projected motion; the contact stage is always last (non-penetration wins; the remaining joint gap
   is corrected next step, "no cumulative error"). The last pass's first half step moves with the joint
   stage's twists projected onto the previous pass's contacts (no closing velocity into a penetration,
   ``ChainOptions.half_step_projection``): the joint springs' velocity of a strand held bent by its
   contacts no longer carries it into them before the detection (issue 10). ``StepStats.max_penetration``
   is taken from the gaps of that last mid-step state (first order from the detection state) and from the
   end-of-step obstacle distances.
4. Second half step q^{i+1} = q^{i+½} + ½Δt u^{i+1}.

Gap handling (our additions, both stated): the normal bound is v_N − g/Δt for a separated pair
with gap g > 0 inside the detection band (a speculative contact: it only acts if the pair would
close the gap within a full step, i.e. by the next mid-step, where the next detection happens, so
the unconstrained first half step cannot carry it into penetration; the band grows with each
segment's speed, so discrete detection does not tunnel), and v_N + β·(−g)/(½Δt) for a penetration
(β = ``penetration_recovery``), the latter as a split impulse: it moves the positions of the second
half step but is not kept in the velocity. Later harmonisation passes update the gaps to first order
with the contact points' motion.

Rows and candidates (coupled mode): the absolute-speed band finds every pair that *could* close its gap
within the step (any contact point moves at most |v| + h|ω|), but most of those pairs move together
(neighbouring fibres falling side by side: 753 k pairs on the 355 × 100 helical scene at t = 32 ms, of
which 23 k end with an impulse). Only the pairs whose gap is within the contact band (``contact_band`` ×
the radii, without the speculative margin ``speculative_speed``·Δt) plus their *relative* normal closing
speed at u⁻ × Δt are rows from the start (≈ 17 k of 2.2 M pairs on the ringlet start at t = 5 ms; 189 k when
the margin was part of the row band); the others are candidates. A relative margin alone is unsafe, because the velocities change during the solve (a strand
stopped at its bottom by the sphere while the strand above still falls onto it), so every full
Gauss–Seidel sweep re-tests the candidates at the current velocities and turns those whose speculative
bound is violated, i.e. that would now close their gap within the step, into rows (≈ 600 per step
there); the solve ends with a full sweep that found none (or after 2 × ``qp_iterations``). The contact
set the solution satisfies is therefore the one of the absolute band, as before: a candidate the solve
leaves out is one whose final velocities do not close its gap within the step.

Candidate reserve (``candidate_reserve``, default): most candidates are far from being promoted (2.3 M on
the ringlet start, of which ≈ 1,300 per step become rows), yet each cost its row, its gather and its
screened tests in every solve. A candidate whose slack at u⁻, σ = n·(u_A − u_B) + G/Δt (G its gap, or the
smaller gap the last pass may give it), exceeds the allowances δ̂_A + δ̂_B of its bodies (the velocity
change each is expected to get in the step's solves, as for ``candidate_band = "relative"``) is kept in
reserve instead: only its position and σ. After every solve the reserve is checked with the bound of the
kernel's own screened test — σ ≤ B_A + B_B with B = |Δv| + (h + r)|Δω| + c·|mid-state change|/Δt per body —
and the suspects by the exact promotion rule at the solve's twists; where a solve would close one, the
suspects become candidates: the last harmonisation pass is then solved again (after 3 such rounds in a step
every suspect is taken untested), an earlier pass hands them to the next one (it only predicts that pass's
mid state). So the contact set is still the band's; a wrong allowance costs a repeated solve, not a missed
contact. Ringlet start (355 × 100): 2.3 M → 0.22 M candidates, no reserve pair closed.

Relative band (``candidate_band = "relative"``, default): the pairs the BVH reports at all are those within
the band of each segment's speed *relative to its neighbours* (a bound through a smooth reference velocity
field, :mod:`headsim.solvers.chain_band`) plus its allowance δ̂, not of its absolute speed (a strand falling
at 0.6 m/s: 10.5 M → 0.55 M pairs); where a pass's velocity changes exceed δ̂ the band is widened to them and
the pairs it adds are checked (see the option).

Friction (§8.3): per contact a frame t₁ = own segment axis (root → tip) projected on the tangent plane,
t₂ = n × t₁; the admissible tangential impulses are the polygon λ_α·conv{μ_β d_β}
(V-representation, eq. 8.51) with generators on the elliptic limit curve of :class:`FrictionLaw`; the
recommended QP objective ``min ½‖u⁺ + u^f‖²_M`` (maximal dissipation without overshoot) is solved by
block Gauss–Seidel with exact 2-D solves; ``friction_objective="lp"`` is the seed's linear objective
``min (u^f)ᵀ M u⁺`` (eq. 8.62) over the same set, solved by HiGHS (scipy.optimize.linprog) per body.

Limitations: the gyroscopic term −ω × (Iω) is neglected and the world inertia is frozen over a step;
contacts are points (no spin friction); per-body projection has no global consistency (see the
stack test for the sag it leaves).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields, replace
from functools import cached_property

import numpy as np
import scipy.sparse
import scipy.linalg
import scipy.sparse.linalg

from headsim.errors import DivergenceError, ParameterError
from headsim.solvers._kernels import chains as K
from headsim.solvers._kernels import chains_coupled as KC
from headsim.solvers._kernels import chains_frames as FK
from headsim.solvers._kernels import chains_pairs as KP
from headsim.solvers.chain_band import LocalMotionBound

__all__ = [
    "FrictionLaw",
    "Obstacle",
    "ChainModel",
    "ChainState",
    "ChainOptions",
    "StepStats",
    "ChainSolver",
    "chain_model_from_polylines",
    "chain_state_from_polylines",
    "polylines_from_state",
    "chain_energies",
    "kinetic_energy",
    "potential_energy",
    "spring_energy",
    "joint_gaps",
]

STANDARD_GRAVITY = 9.80665
# A fibre pair is a contact row of the coupled solve from the start when its gap is within the contact band
# (contact_band × the radii; the speculative margin speculative_speed·Δt only widens the candidate band)
# plus this factor × its relative normal closing speed at u⁻ × Δt (ChainSolver._detect); the rest of the
# pairs the absolute-speed margin finds are candidates that the solve adds as rows when its velocities
# would close them within the step. 1 is the speculative condition itself at u⁻; on the 355 × 100 helical
# scene at t = 32 ms it keeps 14 % of the 753 k pairs, all but 0.1 % of the rows that end with an impulse.
CLOSING_MARGIN_FACTOR = 1.0
# candidate_band="relative": a band widened for at most this fraction of the segments is detected by sweeping
# those segments against the others (headsim.collide.fibre_bvh.subset_contact_pairs) instead of a whole tree
# query (ringlet start: 55–1,300 segments per widening, 50–140 ms with the fused pass instead of 0.3–0.5 s;
# the landing strand at t = 85 ms: 2,468 segments (7 %), 0.31 s instead of 1.69 s)
SUBSET_QUERY_FRACTION = 0.2
# the fibre-pair tree is refitted (ChainSolver._packed_tree) for up to this many steps after its build, while its
# inner boxes sum to at most TREE_REFIT_QUALITY × their sum at the build
TREE_REFIT_STEPS = 10
TREE_REFIT_QUALITY = 1.3


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
def _ro(a, dtype=np.float64, shape=None, name="array"):
    a = np.array(a, dtype=dtype, order="C")
    if shape is not None and a.shape != shape:
        raise ParameterError(f"{name} must have shape {shape}, got {a.shape}")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise ParameterError(f"{name} contains NaN or inf")
    a.flags.writeable = False
    return a


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
        object.__setattr__(self, "segment_offsets", _ro(off, np.int64))
        for name, shp in (("half_length", (S,)), ("radius", (S,)), ("mass", (S,)), ("inertia", (S, 3)),
                          ("root_point", (F, 3)), ("root_frame", (F, 3, 3)), ("joint_stiffness", (S, 3)),
                          ("rest_rotation", (S, 3)), ("joint_damping", (S,))):
            object.__setattr__(self, name, _ro(getattr(self, name), shape=shp, name=name))
        object.__setattr__(self, "anchored", _ro(self.anchored, np.bool_, (F,), "anchored"))
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
    I₃/I₁ ≈ 1e-4) the explicit rotation update transfers energy between axial spin and tumbling and the
    torsion spring is 10⁴ times stiffer relative to its inertia. The price: spin about the fibre's own
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
    rest = np.zeros((S, 3))
    if rest_shape == "initial":
        Rk = np.where(is_root[:, None, None], root_frame[np.repeat(np.arange(F), np.diff(seg_off))],
                      rot[np.maximum(prev, 0)])
        rest = _log_so3_many(np.einsum("sji,sjk->sik", Rk, rot))
    model = ChainModel(seg_off, half, r, mass, inertia, anch, root_point, root_frame, Kj, rest,
                       np.full(S, float(joint_damping)))
    state = ChainState(pos, rot, np.zeros((S, 3)), np.zeros((S, 3)), 0.0)
    return model, state


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


# ------------------------------------------------------------------------------------------------
# options, stats, solver
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ChainOptions:
    """Algorithm options of :class:`ChainSolver` (SI units).

    gravity : (3,) m/s². restitution : ε ∈ [0, 1] (default 0, as in all seed examples).
    friction : :class:`FrictionLaw` (default: isotropic μ = 0.47).
    friction_objective : ``"qp"`` (recommended, Kaufman-style maximal dissipation) or ``"lp"`` (seed's
        linear objective, eq. 8.62, solved by HiGHS).
    normal_impulse : ``"dual"`` (λ_α of QP #1) or ``"projected"`` (eq. 8.27) as the friction bound.
    external_impulse : ``"full"`` (eq. 8.43) or ``"half"`` (Alg. 6 literally).
    harmonisation_iterations : joints → contacts passes per step (1–3 in the seed).
    contact_sweeps : per-body projection passes (≥ 2: later passes use the partners' current velocity).
    joint_tolerance : m, Newton stop on the max joint gap of the trial state; max_newton : iterations.
    qp_iterations, qp_tolerance : PGS / friction sweep limit and velocity tolerance (m/s) of the per-body
        projection; ``qp_iterations`` is also the sweep cap of the coupled solve (see ``contact_tolerance``).
        Default 30 (60 before ``contact_acceleration``): with the Nesterov extrapolation 30 sweeps leave the
        reference scene's solves nearer their converged answer than 60 plain sweeps did (see
        ``contact_acceleration``).
    contact_tolerance : m/s, stopping rule of the coupled contact solve: it ends at the first full
        Gauss–Seidel sweep in which no contact row changed its velocities by more than this (the largest
        |Δλ| W_nn and friction change of any row, i.e. the fixed-point residual of the sweep as a velocity)
        and no joint had a larger gap-rate residual, and no candidate became a row; at most
        ``qp_iterations`` sweeps (the solves that end at that cap without meeting the tolerance are
        counted in :attr:`StepStats.qp_capped`, the largest final residual is :attr:`StepStats.qp_residual`).
        The residual of a sweep under-states the distance to the converged answer where the Gauss–Seidel
        converges slowly (measured with ``benchmarks/bench_contact_convergence.py``: the largest velocity
        error was 2.7 × the residual on the ringlet start and 14 × on the settled 40 × 30 strand), so the
        default is 1e-5 m/s (≤ ≈ 1.5e-4 m/s velocity error, 0.15 µm per step at Δt = 1 ms, 0.4 % of a
        70 µm fibre's radius). With 1e-4 m/s the 4-layer stack of the tests stopped after ≈ 100 sweeps
        and sank 1.4 % of the radius in 1,000 steps (its test allows 1 %; 150 sweeps: 0.16 %).
    contact_band : detection band beyond contact as a fraction of the radius (fibre–fibre and default
        obstacles); speculative_speed : extra detection margin speed·Δt, m/s (obstacle rows and the fibre
        pairs' candidate band; a fibre pair that only this margin reaches is a candidate, not a row from the
        start: on the reference scene's ringlet start that cut the rows from 189 k to 17 k per step, and the
        step from 4.3 to ≈ 2.6–3.4 s; 6.3–8.5 k active contacts and 38–46 µm max penetration over the
        three timed steps, against 6.2–9.3 k and 41–47 µm).
    penetration_recovery : β ∈ [0, 1], fraction of a penetration removed per half step; the push-out is
        applied to the positions only (split impulse: a second contact solve whose velocity is not kept),
        so it adds no kinetic energy (``split_recovery=False``: the push-out is kept as velocity).
    recovery_keeps_joints : coupled mode, split push-out: end the push-out solve with one exact joint solve
        of every touched chain, so the positions it moves satisfy every joint row J u = 0 even when the
        Gauss–Seidel stops at its sweep cap (the sweeps end with the contacts). Without it the capped
        push-out opened the joints (27.6 mm/s joint-rate residual, 17 µm joint gaps on the settled 40 × 30
        drape strand) and the next joint stage closed them again, pushing the segments back into their
        contacts; with it the joint gaps there are 2–4 µm (``benchmarks/bench_penetration.py``). The
        remaining penetration of that strand (≈ 60 µm) is not from this: see that benchmark.
    springs_in_first_half_step : default True: the first half step q^{i+½} = q^i + ½Δt u_J moves with the
        joint stage's twists *including* the joint springs' (and dampers') impulses of the step. This is
        the main cause of the drape strand's interpenetration (issue 10, ``benchmarks/bench_penetration.py``):
        a strand held bent by its contacts (draped over the sphere, fibres pressed together) moves into
        those contacts in the unconstrained first half step by ½Δt × the spring velocity (10–40 mm/s at the
        deepest contacts of the 40 × 30 strand; −0.3 mm/s with the springs set to zero), which only the
        split push-out undoes: 130 µm (3.7 r) into the sphere at t = 0.2 s, 55–60 µm at t = 1.5 s (all
        measured before ``half_step_projection``, which now removes that motion in the last pass).
        False (opt-in, **not yet validated**; it replaces the projection): the first half step moves with the twists of a second,
        spring-free joint solve (the joints still close) and the spring impulses enter u⁻ only, where the
        contact solve sees them, as Moreau's midpoint scheme applies forces (q^{i+½} = q^i + ½Δt u^i).
        Measured: from the settled 40 × 30 state, 100 steps: sphere penetration 55.7 → 1.3 µm, rows deeper
        than r 79 → 9 (the rest: root segments of converging fibres, ≈ 60 µm, unchanged); 7 × 30 strand,
        300 steps from the start: max 232 → 82 µm, steps 150–300 max 153 → 42 µm (mean 78 → 10 µm). It
        changes contact-free dynamics too: ``test_anchored_chain_keeps_its_root_and_loses_energy`` fails with
        it (a transient single-step energy gain of 1.1e-11 J, 7 % of the energy exchanged, 1 % allowed).
        Why it gains: the joint stage's implicit spring impulse Δt K(θ_trial − θ°) is evaluated at the trial
        end θ_trial = θ^i + Δt ω_J (the joint stage assumes the segments rotate with ω_J for the whole step),
        but with this option the step reaches θ^i + ½Δt ω_J0 + ½Δt ω^{i+1} (ω_J0 spring-free): the spring is
        evaluated at a configuration the step does not reach, and its discrete work differs from the change
        of its potential. 1-D linear spring (mass 1, stiffness k, no contact): v' = v − Δt k x_t,
        x_t = x + Δt v', x' = x + ½Δt(v + v') gives E' − E = −k (x' − x)(x_t − (x + x')/2)
        = −½ k Δt² (v + v')(¾ v' − ¼ v), positive when the spring brakes the motion hard (v' between −v
        and v/3), which is the anchored chain's transient. Evaluating the spring at the reached end instead
        (trial x + ½Δt v + ½Δt v') is dissipative (E' − E = −½ k (x' − x)²) but not L-stable: for
        Δt² k/m → ∞, x' → 0 and v' → −v − 2x/Δt, an undamped period-2 ringing of the stiff bending modes
        (Δt² K/I ≈ 1–10⁴ for 70 µm fibres at 1–10 mm segments), so that variant was not pursued; see
        ``half_step_projection`` for the scheme that is the default now.
    half_step_projection : default True (coupled mode, ``harmonisation_iterations`` ≥ 2; issue 10; with
        ``end_velocity_positions``, the default, it only predicts the geometry of the last pass, and the
        energy analysis below is that of ``end_velocity_positions=False``): the first
        half step of the last harmonisation pass moves with the joint stage's twists u_J projected, in the
        kinetic metric plus the implicit spring rows (C = ½Δt² K_w, as in the contact solve), onto the
        contacts of the previous pass: min ½‖u_h − u_J‖² s.t. J_α u_h ≥ −max(g_α^i, 0)/(½Δt) for every row
        that is a row from the start or carried an impulse there (g_α^i: its gap at t_i, first order; a
        penetration may not deepen, a gap may close to contact), every joint of the touched fibres keeping its
        relative anchor velocity J_j u_h = J_j u_J (the joint stage's gap closure), frictionless, ε = 0,
        solved by the coupled kernel to ``qp_tolerance`` (its velocity error enters the positions directly:
        at ``contact_tolerance`` = 1e-5 m/s, 5 nm per step, the resting stack of the tests gained up to
        1.7e-5 of its energy in single steps, 1e-6 allowed). Everything else is unchanged: u⁻ = u_J + Δt g
        (the contact solve sees the springs' velocity and resolves it by the contact impulse), the
        velocity and push-out solves, and contact-free steps (bitwise: no rows, no projection). The spring
        rows of that pass's contact solves take ω_ref = 2ω_J − ω_h + dc_ω as their reference relative
        rotation rate (dc: the previous pass's contact velocity change that the joint trial integration
        contains), so that the total spring impulse Δt K(θ_trial − θ°) + ½Δt² K(ω^{i+1} − ω_ref) is
        Δt K(θ^i + ½Δt ω_h + ½Δt ω^{i+1} − θ°), the spring at the rotation the step reaches (first order),
        as the former scheme's is. Energy: with M(u^{i+1} − u^i) = P_springs + P_gravity + P_contacts and the
        springs evaluated at the reached end, E' − E = −½(u^{i+1} − u^i)ᵀM(u_h − u^i) + ½Σ_α λ_α J_α u_h
        − ½ΔqᵀHΔq (H: the springs' Hessian, ε = 0, frictionless contacts λ_α J_α u^{i+1} = 0). The former
        scheme (u_h = u_J) is dissipative through ½Σλ_α J_α u_J < 0: its half step moves into the pressed
        contacts, and that is its penetration; the projection removes that motion. Measured (issue 10; with
        ``separating_candidates``, both defaults): 7 × 30 drape strand, 300 steps, steps 150–300:
        StepStats.max_penetration 153 → 25.3 µm (0.72 r; mean 78 → 2.4 µm; 16.9 µm without the candidates),
        end-of-step capsule overlaps (exact, every 10th step) 43 → 5.3 µm; 40 × 30 strand at t = 0.3 s
        (``benchmarks/bench_penetration.py --settle 300``): StepStats 165 → 31–48 µm, sphere rows deeper than
        r 160 → 0–1, end-of-step fibre overlaps deepest 49–53 → 25–39 µm (pairs deeper than r 30–32 → 0–3);
        clamped fibre
        bent onto a plane by its springs (``tests/solvers/test_chains.py``) 6.1 r → 0.11 r; resting 4-layer
        stack: largest single-step energy rise −3e-9 → +1.0e-7 of its energy (1e-6 allowed), sink 0.0016 →
        0.0008 r; ``test_anchored_chain_…`` and ``test_energy_never_increases_for_inelastic_impacts``
        unchanged; 11–14 ms per step on the 7 × 30 strand either way (2 shared cores). Was open, now resolved by
        ``end_velocity_positions`` (strict xfail, removed:
        ``test_fibre_held_bent_by_its_contact_never_gains_energy``; ledger: ``benchmarks/bench_energy_ledger.py``):
        the projected scheme is not monotone in energy on the clamped bent fibre (R_c = 0.2 m, ε = 0,
        E0 = 1.14e-9 J); the former scheme is (largest single-step rise 4.5e-22 J, round-off). Measured, per
        step and substep: (1) without push-out, +7.6e-10 J (0.67 E0) in the first step after the release,
        made by the last pass's velocity solve stopped at its 60-sweep cap (``qp_iterations``; joint gap-rate
        residual 23 mm/s, 8.9 µm joint gaps at the step's end against 1.2 µm converged, the tip joint bent
        0.016 rad away from rest; the identity above does not hold for a capped solve, which violates its
        premises J_j u^{i+1} = 0 and the springs at the reached end). Converged (600 sweeps, 477 used) the
        step loses 1.9e-10 J; the projection QP's own sweep cap does not matter (60 or 5000: the same). The
        former scheme's solve stops at the cap too (residual 16 mm/s) without a gain; a likely difference
        (not proven): the spring rows are not balanced at u⁻ (reference 2ω_J − ω_h + dc_ω; ω_h − ω_J 42 rad/s
        relative at the tip joint), and the Gauss–Seidel between the contacts and a chain with Δt²K/I ≈ 1e4
        (tip segment) converges slowly; starting it from the chains
        balanced for that reference changes nothing (its first sweep does exactly that); ending the velocity
        solve with an exact joint solve removes this gain but leaves rises of 4.7e-12 J. (2) With push-out
        (the default) the first step loses 2.2e-10 J, the largest rise is 1.2e-12 J (1.1e-3 E0, step 11),
        and the resting fibre runs a period-3 limit cycle of its tip joint (+7.0e-13, +2.4e-13, −9.5e-13 J;
        segments 18–19 at 2–3 rad/s, the tip end 3.8 µm into the plane at mid-step and pushed out every
        step), gone with converged solves. (3) With every solve converged (20,000 sweeps, 1e-9 m/s) rises of
        up to 8.7e-14 J (7.7e-5 E0) remain at steps 10–12 and they are the identity's first term:
        −½(u^{i+1} − u^i)ᵀM(u_h − u^i) = +8.0e-14 J at step 11 (−2.1e-13 J with u_J in place of u_h; the
        contact terms ≈ 1e-26 J): the projected twists u_h are not u^i plus a part of the step's velocity
        change, and the term the projection adds, −½(u^{i+1} − u^i)ᵀM(u_h − u_J), has no sign. Variants
        measured and dropped, none monotone: the projection kept as velocity (u⁻ = u_h + Δt g; first step
        fixed, 1.7e-12 J at step 8), the first half step with the previous pass's contact-solved twists
        (6.5e-10 J at the cap, 3.8e-14 J converged) and the projection in the kinetic metric alone (spring
        rows C = 0: 1.6e-9 J in the first step at the cap, 1.9e-12 J at step 6 converged).
    end_velocity_positions : coupled mode, default True (issue 10, "energy never increases with ε = 0"): in the last
        harmonisation pass (≥ 2 passes, after a pass with contact rows) every fibre that has a contact row moves
        with the velocity solve's twists for the whole step, q^{i+1} = q^i + Δt u' (both half steps; the
        first half step, projected or not, only predicts the geometry the rows and joint levers are evaluated
        at), its joint springs are implicit at the rotation the step reaches, θ^i + Δt ω' (spring rows
        C = Δt² K_w + Δt c E with reference rate ω_J + dθ_extra/Δt, where the midpoint scheme has ½Δt² K_w),
        and the rows' targets come from their gaps at t_i, g^i (first order): a speculative row closes at most
        min(½ g^i, g_mid) (so it arrives no faster than g^i/(2Δt) and the next step's mid-step state does not
        pass through its partner: with g^i the dropped fibre of the tests tunnelled), a penetration is held
        (target 0) and the split push-out acts on its depth at t_i beyond ``push_out_slop``. Fibres without
        contact rows keep the midpoint step. The velocity solve ends with an exact joint solve, and for small
        systems (``exact_final_solve``) with an exact solve on the Gauss–Seidel's active set.
        Energy (derivation; linearised geometry, frictional contacts, ε = 0): with g(u') = M(u' − u⁻) +
        Sᵀ C (S u' − ω₀) the sum of every constraint impulse (contacts λ, friction f, joints p, the spring rows'
        residual; u⁻ = u_J + Δt g, M(u_J − u^i) = −Δt ∇V_s(θ_trial) + Gᵀp_J), M(u' − u^i) = −Δt ∇V(q^{i+1}) + g
        (V: springs and gravity, convex), so E' − E = ½(u' + u^i)ᵀM(u' − u^i) + V(q^{i+1}) − V(q^i)
        ≤ B := u'ᵀg(u') − ½‖u' − u^i‖²_M (convexity: V(q^i) ≥ V(q^{i+1}) − Δt u'ᵀ∇V(q^{i+1})), and at the
        solution of the velocity solve u'ᵀg = Σ λ_α b_α + Σ f_αᵀT_α u' ≤ 0 (complementarity λ_α (J_α u' − b_α) = 0
        with targets b_α = −max(g, 0)/Δt·(…) ≤ 0, maximal dissipation of the friction polygon, G u' = 0 and the
        spring rows met exactly), hence E' ≤ E − ½‖u' − u^i‖²_M − ½ΔqᵀHΔq. The midpoint scheme
        q' = q + ½Δt(u_h + u') instead gives E' − E = ½(u' − u^i)ᵀM(u^i − u_h) + ½Σλ_α J_α u_h + ½Σλ_α J_α u'
        − ½ΔqᵀHΔq, whose first term has no sign for the projected u_h (the measured rises; see
        ``half_step_projection``). The premises fail for a Gauss–Seidel stopped early (the joint rows, the
        spring rows and the contact rows are each met only at the sweep that visits them): the exact joint
        solve at the end makes G u' = 0 and the spring rows exact; the contact complementarity then holds to
        the solve's accuracy only, which gave rises of up to 4e-16 J on the clamped bent fibre (1.1e-9 J) at
        ``contact_tolerance`` and 6e-16 J at 1e-6 m/s, tracked by B to 1 % (B is :attr:`StepStats` ``energy_bound``):
        ``exact_final_solve`` removes them. Measured (``benchmarks/bench_energy_ledger.py``, clamped bent fibre,
        E0 = 1.14e-9 J, 300 steps): largest single-step change +3.3e-23 J with and without push-out (no rising
        step; before: +1.2e-12 J and a period-3 limit cycle at rest with push-out, +7.6e-10 J without),
        penetration over steps 150–300 0.00 µm (before 3.8 µm). Split push-out (``penetration_recovery``): it
        moves the positions by Δt(u_pos − u') beyond the velocity solve, which the bound does not cover (its
        potential-energy change has no sign); ``push_out_slop`` keeps it off the nm-deep penetrations that the
        first-order t_i gaps of rotating segments report, and ``exact_final_solve`` keeps tolerance-sized
        sinking from accumulating into deeper ones (the resting stack: 38 nm accumulated at 1e-5 m/s, then a
        push-out step gained 4e-6 of its energy).
    end_velocity_predictor : the mid-step state at which the last pass's rows, joint levers and inertias are
        evaluated under ``end_velocity_positions``: ``"previous"`` (default) q^i + ½Δt u' of the previous pass's
        velocity solve for the touched fibres (u_J for the others), ``"projection"`` the ``half_step_projection``
        of u_J. The joint rows hold at that state, so the joints of a fibre that moves with u' from q^i open by
        ≈ Δt²|ω'||ω_pred − ω'| h: measured on the reference scene (``benchmarks/bench_drape.py --fibres 120
        --segments 50 --settle 5 --steps 2 --coupled-only --geometry former``, t = 7 ms): max joint gap 23 µm
        and max penetration 23.5 µm with ``"previous"``, 57 µm and 32 µm with ``"projection"``, 4.5 µm and
        18.5 µm with ``end_velocity_positions=False`` (the projected midpoint scheme; the first two measured
        with ``sweep_budget`` = 1,000,000). Re-measured at the default ``sweep_budget`` = 100,000: 23.4 µm and
        23.5 µm, 57.1 µm and 32.4 µm, 4.5 µm and 18.5 µm, the same states as with 1,000,000 (the budget
        cannot act there: ≈ 31 k rows per solve, so budget/R < ``qp_iterations``). ``"previous"`` also
        skips the projection QP.
    sweep_budget : row visits (default 100,000) of the last pass's velocity and push-out solves under
        ``end_velocity_positions``: a solve with R rows (contacts + joints) may run max(``qp_iterations``,
        budget/R) sweeps and then stops at ``small_system_tolerance`` (default 1e-6 m/s) instead of
        ``contact_tolerance``. Small systems therefore run to (near) convergence (clamped bent fibre: up to
        ≈ 15,000 sweeps in the first steps with a budget of 1,000,000, median 142; at the 60-sweep cap its
        solves ended 4.5 mm/s off, the fibre sank 22 µm and the push-out pumped energy; its energy tests pass
        at 100,000 too, the exact final solve finishing them); on the reference scene (≈ 2 M rows) the cap
        stays ``qp_iterations``. 1,000,000 made the tests' 7 × 30 helical drapes (Table 8.1, three friction
        models, 1.5 s) take 165 s against 31 s before ``end_velocity_positions`` and 39 s at 100,000 (same
        machine, warm caches). 0 switches it off.
    exact_final_solve : default True, under ``end_velocity_positions``, systems of at most 100 bodies: the
        velocity solve's answer is replaced by the exact solution of its problem on the Gauss–Seidel's active
        set (M + SᵀCS with the joint rows, the rows with λ > 0 as equalities, sticking friction as T u = 0,
        sliding friction along its direction on the polygon), with rows leaving (λ < 0) or joining (bound
        violated) the set and friction switching between sticking (outside the polygon: slides) and sliding
        (accelerating its contact: sticks) until every sign condition holds, at most 8 rounds. Each round
        solves the equalities through their Schur complement C M̃⁻¹ Dᵀ (M̃ by SuperLU, the complement by a
        least-norm least-squares solve): redundant rows (two segments' end rows at one joint; a sticking
        crossing's rows next to a joint) share their load, and rows whose least-squares velocity misses its
        targets by more than :data:`EXACT_VELOCITY_TOLERANCE` (1e-12 m/s) + :data:`EXACT_RELATIVE_TOLERANCE`
        (1e-9) × the largest velocity change they demand are inconsistent and leave the set.
        When no such set is found the Gauss–Seidel answer is kept (:data:`EXACT_FAILURES` counts the reasons).
        Before the least-norm solve (a δ-regularised KKT factor with proximal refinement, tolerance 1e-10 of
        the right-hand side) the solve failed on redundant rows: in every step of the tests' 4-layer stack
        (``qp_iterations`` = 150: 192 × 'inconsistent', 8 × 'active set' in 200 steps; the defaults: 297 × and
        3 × in 300) and in 10 of the clamped bent fibre's 300 steps. Now it succeeds in all of them (issue 10,
        twenty-second session), in 1 round, rarely 2 (the default stack 199 / 1 of 200, the clamped fibre 295 /
        5): the stack sinks 2.5e-11 m (150 sweeps) / 2.8e-11 m (defaults) in 200 / 300 steps against 1.9e-9 /
        2.1e-9 m (its elastic sag is 1.4e-10 m), 34–35 against 32–37 ms per step (150 sweeps), 35–40 against
        33–34 (defaults); the clamped fibre rests 1.5 instead of 2.5 nm deep, its energy rises in 28 instead of
        107 of the 300 steps (largest 3.4e-23 J against 4.1e-23 J), and its 300 steps take 2.7–2.9 s instead of
        2.1–2.2 s. With an absolute residual tolerance alone (1e-12 m/s) the default stack failed in every step
        (its first round missed by 2.2e-12 m/s of a 1e-2 m/s change: the truncation's round-off), and a failing
        solve costs up to ``rounds`` least-squares solves (79 against 40 ms per step there); an (active, sticking)
        set met twice fails at once as 'active set cycles'. On a model of at most :data:`EXACT_MAX_DOF` / 6 = 100
        bodies the last pass's velocity solve stops at ``qp_iterations`` and the exact solve is tried on its
        active set; only when that fails does the Gauss–Seidel go on, from its impulses, under ``sweep_budget``,
        and the exact solve is tried again.
        Measured: the default stack 32 → 21 ms per step with bitwise the same states (the exact solve finds the
        same set), the 1,000-step stack test (150 sweeps) 50 → 24 s; the clamped fibre: the same resting depth,
        1 of 300 first tries fails ('active set') and the retry succeeds, its energy rises in 43 instead of 28
        steps (largest 3.35e-23 J, before 3.36e-23 J).
    push_out_slop : fraction of the radius (default 1e-3, 35 nm at 70 µm) a penetration at t_i must exceed
        before the split push-out acts on it, under ``end_velocity_positions`` (the rows' t_i gaps are first
        order: the clamped bent fibre reported 0.2 pm–3 nm depths every step, and pushing them out raised
        its energy by up to 3e-16 J per step).
    separating_candidates : coupled mode, default True: a penetrating pair (g < 0) that the persistence filter
        (eq. 8.9) drops because it separates at u⁻ is kept as a candidate row, which the coupled solve turns
        into a row as soon as its current velocities close it (the active set of eq. 8.9 evaluated at the
        solve's iterate instead of u⁻ only). Without it such a pair has no row at all for the step: measured
        on the 7 × 30 drape strand, a fibre pair 33 µm deep without a row for 6 steps (separating at u⁻,
        closing after the contact solve changed the chain's velocities) reached 67 µm. With
        ``half_step_projection``, 40 × 30 strand at t = 0.3 s, end-of-step fibre overlaps: deepest 68–70 µm
        and 43–48 pairs deeper than r without it, 25–39 µm and 0–3 with it; 7 × 30 strand, steps 150–300:
        StepStats 16.9 µm without, 25.3 µm with (end-of-step overlaps 7.9 / 5.3 µm; one chaotic trajectory
        each). False: the former filter (transient contacts dropped).
    fibre_contacts : detect fibre–fibre contacts (False: obstacles only).
    contact_coupling : ``"per-body"`` — the seed's independent projection of every segment with moving
        constraints (Alg. 6); ``"coupled"`` — one nonlinear Gauss–Seidel over all contacts with relative
        velocities and equal and opposite impulses (Moreau–Jean NSCD; no sag-through in stacks).
    obstacle_midpoints : also test the closest point of every segment axis to each obstacle when it lies
        inside the segment (False: end points only, as in the seed, §8.6.5).
    warm_start, warm_start_fraction : start the coupled contact solve from ``warm_start_fraction`` (default 1,
        in [0, 1]) of the previous step's impulses of the same contacts; the Gauss–Seidel fixed point is
        unchanged, only the starting point. Where the solves end at their sweep cap (the reference scene, every
        solve of every step), the full warm start carries the iteration on from step to step; a fraction
        throws part of the previous answer away every step. Issue 10's twenty-fourth session, reference scene
        (355 × 100, aniso), fraction 1 against the former 0.5, same state, runs alternated (2 shared cores whose
        speed drifted by up to 50 % over the hour, so only the interleaved ratios count): at rest (t = 1.0 s,
        20 steps, two rounds) 2.33 / 2.07 against 3.38 / 3.07 s per step (−32 %); after the landing (t = 0.12 s,
        30 steps) 2.33 against 2.89 s (−19 %); through the landing (t = 0.08 s, 25 steps) 7.16 against 6.93 s
        (+3 %; +24 % and, with ``late_promotion_overlap`` too, +15 % in other pairs: the full warm start costs
        while the impulses change fast, 40 steps of the first second). The same physics to the printed digits
        (energy change over the run −1.3e-6 / −1.2e-5 / −1.4e-4 J, box volume change +1.4 % / +35 % / +17 %), no
        step raising the total energy, no positive energy bound B (``end_velocity_positions``). On a replayed
        resting solve (2,000-sweep reference Σλ = 2.5383e-5 N s) 60 sweeps (its 30, extended by late promotions
        as the rule was then) reach Σλ = 2.5388e-5 with the full warm start, 2.24e-5 (of 2.41e-5) with half. The former 0.5 came from the 4-layer stack test before the exact final solve and
        the sweep budget existed (fractions 1.0 and 0.9 then raised the total energy by up to 1.4e-5 / 1e-5 of it
        in single steps); that test and every other chain and drape test pass with 1. The former first half
        step (``half_step_projection=False``, ``end_velocity_positions=False``) still needs 0.5 to keep the
        clamped bent fibre's energy from rising at rest (1.2e-16 J per step, 1e-7 of it, with 1: a capped
        solve's leftover warm-start impulse, which the default scheme's exact final solve removes).
    parallel_threshold : segments from which the Numba-parallel kernels are used (serial below: the
        thread start-up costs more than it saves on small scenes).
    joint_gap_fraction : γ ∈ [0, 1], the Baumgarte-style fraction of the mid-step joint gap d_mid that the
        joint rows of the coupled contact solve close by the step's end: they demand
        (v_k + ω_k × r_k) − (v_l + ω_l × r_l) = −γ d_mid/(½Δt). Default 0: the contact solve only keeps
        every joint's two anchors moving together (Moreau's velocity-level bilateral constraint, J u⁺ = 0)
        and the position drift is corrected separately by the next step's joint stage (Method I closes
        every gap of the t_i state in its trial integration: "no cumulative error", §8.5.1), so the
        correction never competes with the contacts and adds no kinetic energy. With γ = 0 the velocity
        solve is always feasible (u = 0 meets every row: its contact bounds are −g/Δt ≤ 0 or 0). γ = 1
        is the former behaviour (the gap closed within the contact solve), which on a resting strand asks
        for closing speeds 2 d/Δt that the contact bounds (−g/Δt) forbid: the impulses then grow with
        the sweeps instead of converging (``benchmarks/bench_contact_convergence.py``).
    contact_domains : coupled mode, number of body domains (integer ≥ 1, default 2) whose contact rows one
        Gauss–Seidel sweep visits in parallel (Numba ``prange``, one domain per thread). The touched fibres
        are split by a recursive bisection of their contact graph (``_fibre_domains``, balanced by row
        count); a row whose two bodies lie in one domain belongs to that domain, the others (the cross rows:
        4.5 % of the rows on the reference scene with 2 domains) are visited serially after the domains (in
        the reverse sweep: before them). Within a domain the rows keep their former order. Every sweep is
        still one projected Gauss–Seidel sweep over all rows (rows of different domains share no body, so
        visiting them at the same time is visiting them one after the other), in a different row order:
        the same fixed point of the same problem (Alg. 6's per-contact normal rows with the moving-constraint
        targets and the anisotropic friction polygons λ·conv{μ_β d_β}, eq. 8.51), a different iterate at the
        sweep cap (measured on the reference scene: the same distance to the converged answer). The result
        does not depend on the number of threads (the serial kernel visits the domains one after the other).
        1: the former single sequence, bitwise the former results. Measured (issue 10, reference scene
        355 × 100 at t = 4 ms, the captured solves of one step rerun in one process, 2 cores, load 1.3 with
        this job): 2 domains 0.415–0.52 s per solve against 0.485–0.58 s (≈ 15 % less wall time), the same
        distance to a 6,000-sweep answer (relative kinetic-metric error 0.4417 / 0.5087 against 0.4412 /
        0.5066 at the 60-sweep cap); with a second job on the machine (load 2–3.5) no gain at all (the
        threads share one core). The default was 1 until issue 10's thirteenth session (small, machine-dependent
        gain; the different iterate changed the chaotic drape trajectories, and the strict-xfail Table 8.1
        iso/aniso test, then asserted at 0.7 s alone, passed by chance for 2 and 3 domains). It is 2 since the
        landing of the reference strand was measured: on one captured solve at t = 86 ms (≈ 310 k rows from the
        start, 169 k candidates promoted in the solve, 60 sweeps), 1 domain 2.24–2.72 s, 2 domains 1.59–1.65 s,
        4 domains 1.78 s; whole reference steps at the ringlet start 1.95–2.01 → 1.78–1.83 s (contacts 0.82 →
        0.65 s).
    contact_acceleration : coupled mode (the contact solves and the half-step projection): ``"nesterov"``
        (default) extrapolates the contact impulses after every sweep along their last change, with adaptive
        restart (``momentum`` of :func:`headsim.solvers._kernels.chains_coupled._coupled_iterate_impl`); the
        same fixed point, reached in fewer sweeps (``benchmarks/bench_contact_convergence.py``, 120 × 50
        ringlet: after 60 sweeps 0.052 off the converged answer in the kinetic metric against 0.452 plain,
        the 1e-5 m/s stopping rule met after 656 sweeps against ≈ 3,000; reference scene: 30 accelerated
        sweeps 0.308 off against 0.344 for the former 60 plain ones). ``"none"``: the plain Gauss–Seidel
        (with ``qp_iterations=60`` the former iterates, bitwise).
    candidate_band : coupled mode, how far apart a fibre pair may be and still be a candidate (the pairs the
        solve may turn into rows). ``"absolute"``: within 0.75 (s_a + s_b) Δt of the row band, s the segments'
        own speeds |v| + h|ω| (it grows with the fall speed although neighbouring fibres move together).
        ``"relative"`` (default since issue 10's thirteenth session): s_a = (A_a + 1.5 δ̂_a)/0.75 with A_a the
        local-motion bound of :class:`headsim.solvers.chain_band.LocalMotionBound` (|u_a(p) − u_b(q)| ≤ A_a + A_b
        for points within the absolute band's reach ρ = r(1 + ½ band) + ½ margin + (s + 1.5 δ̂)Δt of each other;
        pairs farther apart cannot close even at their own speeds) and δ̂_a an allowance for the
        velocity change the step's solves may give it (1.5 × the change measured in the previous step, at
        least |g|Δt; where it has an obstacle row, at least its speed at the end of the step). After each
        harmonisation pass's
        solves every segment's measured change δ (against the detection's u⁻) is checked against δ̂: where it
        is larger, the pairs of the band widened to 1.25 δ are detected again at the detection's state (only
        those the first band missed, and only around the widened segments when they are few:
        :func:`headsim.collide.fibre_bvh.subset_contact_pairs`), the ones
        the solves' twists close (or that close at u⁻) join the candidates and the pass is solved again
        (:meth:`ChainSolver._widened_band`; 3 widenings per step at most). Only after a 4th is the step redone
        with the absolute band. So every pair that the final velocities close within a relative-band step was a
        candidate (the bound, not a heuristic). The absolute band is used for a step whose relative band
        would be wider in sum (the first step of the ringlet start, ``--geometry former``).
        Before issue 10's fourteenth session the reference field's bound held for pairs whose centres lie
        within one grid cell, the cell had to cover the largest candidate distance at the fastest segment's
        speed (8.9 mm at the ringlet start) and the bound included h|ω| in full: the ringlet start kept the
        absolute band (4.3 M pairs at t = 6 ms; now 1.8 M, most of them around the ≈ 2,000 segments near the
        tips moving at ≈ 2 m/s), and the falling strand of the derived geometry at t = 60 ms had 1.2 M reserve
        pairs (now 0.35 M; detection 0.40 → 0.29 s per step, the same states).
        Measured (``benchmarks/bench_drape.py`` scene, 355 × 100, from a saved t = 60 ms state of the derived
        geometry, 30 steps to 90 ms, with the candidate reserve and 2 contact domains, machine otherwise idle):
        absolute 177 s, relative 156 s; 61–82 ms (falling, 0.6 m/s) 1.3–2.5 s per step against 2.8–4.6 s
        (detection 0.5 s against 2.2–3.5 s: 1.2–1.5 M against 9–9.7 M candidate and reserve pairs), 83–84 ms
        (the strand lands on the sphere and on itself) 8.6 / 30 s against 11.5 / 31 s, 85–90 ms 12–16 s
        against 9–14 s: there the relative band is the wider one (1.7–2.1 M candidates against 1.4–1.8 M; from
        one t = 85 ms state with the same allowances its first detection gave 2.39 M against 1.81 M), as its
        radii carry the allowance 2 δ̂ where the absolute band carries none, and the segments just stopped
        have allowances above their own speeds. The
        trajectories agree to the printed digits (contacts, penetration, kinetic energy) up to 83 ms and
        differ slightly after the landing. Before the widening (issue 10's twelfth session) a violated
        allowance redid the whole step with the absolute band: 13 of the 15 landing steps were redone, 393 s
        against 262 s.
    candidate_reserve : coupled mode, keep the candidates whose slack at u⁻ exceeds their bodies' allowances out
        of the solve and check them after every solve (module docstring, "Candidate reserve"; default True).
        The states differ from ``False`` only where a candidate is promoted during an iteration but not
        violated at its end (same fixed point). The allowance δ̂ is the one of ``candidate_band = "relative"``
        (its velocity-change tracking then runs in every step).
    root_sweeps, root_segments : coupled mode (the contact solves and the half-step projection): after every
        full sweep that has not met the stopping rule, ``root_sweeps`` (default 8) extra Gauss–Seidel sweeps
        over the first ``root_segments`` (default 8) segments of every fibre anchored at its root: the
        joints there solved exactly, the rows on those segments visited (``root_sweeps`` of
        :func:`headsim.solvers._kernels.chains_coupled._coupled_iterate_impl`). Same fixed point; 0: the
        former iterates, bitwise. Issue 10's twentieth session: on the reference scene the roots are anchored
        105 µm apart (1.5 diameters), and once the strand has slid over the sphere (t ≈ 0.47 s) the capped
        solves left the first segments of neighbouring fibres crossing each other (overlaps up to one
        diameter). A contact next to the anchored root is the slowest row to converge: a push there moves
        the solved chain by 1.5–6 % of what it moves a free segment. Measured with the saved full-size aniso
        states (pairs of capsules overlapping by more than a radius, all but a few on segments 0–7; time per
        step, the machine otherwise idle):

        - t = 0.4 → 0.5 s (100 steps): 132 pairs at 0.5 s with 0 root sweeps, 1.77 s per step; 62 with 8,
          1.82 s; 96 with 16, 2.04 s;
        - t = 0.45 → 0.475 s: 37 pairs with 0 (1.72 s per step), 7 with 8 (1.67 s), 11 with 16 (1.92 s);
          ``qp_iterations`` = 120 instead gave 6 pairs at 3.0 s per step (nineteenth session);
        - at rest, t = 1.475 → 1.5 s (155 crossing pairs at the start): 155 pairs with 0 (1.43 s per step),
          117 with 8 (1.56 s), 83 with 16 (1.81 s);
        - the settled 40 × 30 strand (t = 1.5 s): deepest overlap 50.9 µm, 4 pairs, with 0; 39.0 µm, 1 pair,
          with 8; 31.6 µm, none, with 16.

        The crossings are fewer, not gone: a pair whose centre lines already cross (overlap ≈ 70 µm) has no
        consistent normal, and the deepest overlap stays at 69–70 µm in the full-size runs.
    persistent_normals : coupled mode, opt-in (default False; issue 10, "no tunnelling"): a fibre pair that
        penetrates (gap < 0) in this step and did in the previous one keeps the side of its previous normal. The
        normal of two capsules is the direction between the closest points of their axes, and it reverses when
        the axes pass through each other: a pair pressed to an overlap of nearly 2r (its axes ≈ 1 µm apart)
        whose axes cross within a step then gets a normal that points through its partner, and its contact row
        holds it on the wrong side (tunnelled). With this option such a row keeps the former side: its normal is
        reversed, its gap becomes the depth along that side, −(d + r_a + r_b) (d the axes' distance, i.e.
        between −2r and −4r for equal radii), its contact points move to the other sides of the axes, and it is
        a row from the start, so the push-out moves the pair back the way it came where the solve can move it:
        two crossed free fibres driven through each other (the tests) are held and pushed back to contact on
        their side, and tunnel without it. Why not the default (measured on the 120 × 100 drape, derived
        geometry, aniso, from a saved t = 0.5 s state, 150 steps; issue 10, twenty-first session): without it
        0–6 fibre pairs per step reverse their normal at gaps of −52 to −70 µm, all but one on segments 1–3
        (the root region, see ``root_sweeps``). With it those rows are held (5 at the start, 40–64 from
        t = 0.56 s), but the capped solves do not stop the root segments: the held pairs keep moving through,
        their axes 20–30 µm past the partner after 30 steps and up to 2r (70 µm: touching on the far side)
        after 75, and the held rows then keep them overlapping where the former normals let them separate on
        the far side. Capsule pairs of different fibres overlapping by more than r at the end of a step, with /
        without: 22 / 24 after 5 steps, 19 / 52 after 30, 35 / 81 after 60, 48 / 96 after 105, 77 / 36 after
        150; ``StepStats.max_penetration`` (which counts a held row's depth) 62–173 µm against 76–159 µm;
        0.449 / 0.470 s per step. So it turns a tunnelling that the solve cannot prevent into a lasting overlap;
        the cause is the solve's convergence at the anchored roots (see ``root_sweeps``), not the normal.
    late_promotion_overlap : coupled mode, fraction of the smallest segment radius (default 0.1: 3.5 µm at
        70 µm; ≥ 0). A candidate pair that becomes a row in a full sweep at the sweep cap used to extend the solve
        (9 sweeps at a time, up to 2 × ``qp_iterations``) so that the new row is solved; now only when the bound
        it violates, n·(u_A − u_B) ≥ target, is violated by more than this fraction × r / Δt, i.e. when the pair
        would overlap by more than this fraction of a radius at the step's end if the solve stopped there
        (first order; an overlap of one radius is where tunnelling begins, see the drape's sinking test). A
        smaller violation is left to the next step's rows and push-out. 0: every late promotion extends the
        solve (the former rule, iterates bitwise). Issue 10's twenty-fourth session, reference scene: at rest
        400–980 candidates become rows during each solve (most next to the anchored roots, where the capped
        iterates still swing by mm/s) and about half of the solves ran to 48–60 sweeps for them; with 0.1 every
        resting solve ends at its 30 sweeps. Measured from the same states, runs alternated (20 steps each):
        at rest (t = 1.0 s) 2.10 / 1.64 against 2.50 / 2.06 s per step (−16 / −20 %), max penetration of the last
        step 116 against 142 µm (the first-order t_i gaps), the same energy change to two digits; after the landing
        (t = 0.12 s) 2.05 against 2.19 s (−6 %); through the landing (t = 0.08 s, deficits of m/s: the
        extensions stay) 7.27 against 7.43 s, max penetration at t = 95 ms 80 against 117 µm.
    predictor_sweeps : coupled mode, sweep cap (≥ 1; at most ``qp_iterations``) of the contact solves of the
        harmonisation passes before the last (default 10), in systems too large for the sweep budget (R rows and joints
        with ``sweep_budget``/R ≤ ``qp_iterations``, as on the reference scene); smaller systems run them to
        ``qp_iterations`` as before (capped at 10, the resting stack of the tests, whose velocity solves run to 150
        sweeps, rose in energy by 1.6e-6 of it in one step, beyond its test's 1e-6). Their twists only predict: the last
        pass's mid-step state (``end_velocity_predictor`` "previous": the touched fibres at q^i + ½Δt u'), its joint
        stage's extra displacement and the impulses of ``half_step_projection``; the step keeps the last pass's solves,
        which start from the previous step's impulses (``warm_start``), not from these. Late promotions extend the cap
        as in every solve (up to twice it; see ``predictor_extension``). None: ``qp_iterations`` (the former solves).
        How far the cap can go down is set by the joints: a fibre that moves with u' opens its joints by ≈
        Δt²|ω'||ω_pred − ω'| h (see ``end_velocity_predictor``). Issue 10's twenty-fifth session, reference scene, 15
        steps through the landing from t = 0.08 s: max joint gap 7.96 µm with 10, 49.6 µm with 2, 6.58 µm with None;
        mean max penetration 62.0 / 60.0 / 61.7 µm (2 also let the clamped bent fibre of the tests sink before the cap
        was limited to large systems). Time per step, runs from the same states alternated with None (20 steps): at rest
        (t = 1.0 s) 1.30 / 1.29 against 1.38 / 1.39 s (−6.5 %), the same energy change to three digits, no step raising
        it, max joint gap 7.69 against 7.70 µm; after the landing (t = 0.12 s) 1.74 / 1.68 against 1.86 / 1.92 s (−8 %);
        through the landing (t = 0.08 s, 15 steps) 6.75 against 7.10 s (−5 %). With 2 it was 1.23 / 1.14 / 1.20 against
        1.45 / 1.34 s at rest and 6.29 against 6.94 / 7.13 s through the landing, which the joint gaps rule out.
    predictor_extension : coupled mode, default True: late promotions (``late_promotion_overlap``) extend the capped
        predictor solves of ``predictor_sweeps`` as they extend every solve; False: that cap is final. On the reference
        scene the extension is what the predictor costs: capped at 10 it ran 20 sweeps at rest (290 ms of a 1.27 s step,
        the captured solve of t = 1.003 s replayed; the velocity solve, capped at 30, is not extended there). Issue 10's
        twenty-sixth session, runs from the same states alternated, False against True: at rest (t = 1.0 s, 12 steps)
        1.15 against 1.27 s per step (−10 %), mean max penetration 108 against 112 µm; after the landing (t = 0.12 s, 12
        steps) 1.76 against 1.83 s (−4 %), 39.5 against 35.6 µm; through the landing (t = 0.08 s, 12 steps) 5.37 against
        5.84 s (−8 %), 55.4 against 52.4 µm, max joint gap 9.85 against 5.45 µm; the same energy change to two digits,
        no step raising it. (Measured with float64 kernel arrays.) A predictor-only threshold of r (10 ×
        ``late_promotion_overlap``; tried, not kept): −8 % at rest, through the landing the default's time and
        penetrations, after it False's 39.5 µm; of 0.3 r: −3 % at rest, otherwise the default's. Not the default: it
        buys the resting speed with the moving strand's accuracy. Re-checked in the twenty-eighth session with the
        end state's fibre overlaps (``benchmarks/bench_drape.py``'s ``overlap_summary``; float32 kernel arrays),
        False against True, steps alternated from the same states: through the landing (t = 0.080 → 0.120 s, 40
        steps) 4.49 against 4.59 s per step, overlaps away from the roots the same (1,183 against 1,222 > 10 µm,
        99 % 18.5 against 18.7 µm), but max joint gap 43.8 against 7.62 µm; after it (t = 0.120 s, 15 steps) 1.77
        against 1.92 s, 560 against 593 overlaps > 10 µm, largest 36.0 against 24.3 µm, max joint gap 7.64 both; at
        rest (twenty-seventh session, 25 steps) 1.00 against 1.19 s, 259 against 293. The joint gaps through the landing
        keep the extension on (True).
    kernel_precision : coupled mode, floating-point type of the arrays the coupled kernel's set-up stores and its sweeps
        read (per contact row its Jacobian rows, their mobility images and the 3×3 Delassus block; per joint the bodies'
        world inverse inertias and the block-Thomas factors): ``"auto"`` (default) float32 in systems that run the
        parallel kernels (``parallel_threshold``) and are too large for the sweep budget (as ``predictor_sweeps``),
        float64 in all others; ``"float64"`` or ``"float32"`` everywhere. The twists, impulses, targets and all
        arithmetic stay float64. Why: every row visit of a sweep reads ≈ 650 bytes of those arrays in float64 (half in
        float32), and the solves of such systems end at their sweep cap, a few to tens of per cent from their converged
        answer, far above float32's relative rounding (6e-8). What it costs: the chain solves run with rounded factors,
        so the joint rows that ``joints_last`` solves exactly keep a residual of that rounding times the velocities
        (measured: 6e-9 / 9e-9 m/s after the last pass's velocity / push-out solve of the reference scene at t = 1.003
        s, captured and replayed, whose 30 sweeps otherwise end with the same promotions, largest bound violation and
        impulse sum to six digits as float64's; 1.3e-7 of the push-out speed on the sunk stack of the tests; float64
        1e-16 m/s / 5e-16). Issue 10's twenty-sixth session, reference scene, runs from the same states alternated (12
        steps; through the landing 10) against ``"float64"``: at rest (t = 1.0 s) 1.17 against 1.29 s per step (−9 %);
        after the landing (t = 0.12 s) 1.64 against 1.79 s (−8 %), both with the same penetrations, joint gaps and
        energy change to the printed digits (one step's positions differ by 8e-11 m); through the landing (t = 0.08 s)
        4.66 against 5.21 s (−10.5 %), mean max penetration 37.8 against 35.6 µm, max joint gap 4.6 against 5.5 µm (the
        landing's iterates differ), the same energy change to four digits. The resting 4-layer stack of the tests forced
        to float32 (300 steps, velocity solves to 150 sweeps): sinks 1.25e-4 r against 1.20e-4 r, the same largest
        energy rise, heights within 7.4e-10 m of float64's.
    push_out_sweeps : coupled mode, sweep cap (≥ 1; at most ``qp_iterations``) of the split push-out solve
        (``penetration_recovery``), in systems too large for the sweep budget as above; default None
        (``qp_iterations``). Its twists only move the positions, by the fraction β of the row gaps it recovers in the
        step; a push-out stopped earlier recovers less of the overlap in that step and the rest in the next ones. Not
        lowered by default. Issue 10's twenty-fifth session, reference scene, with the former push-out start
        (``push_out_warm_start=False``) and ``predictor_sweeps`` = 2: 5 sweeps ran 0.95 against 1.38 s per step at rest
        with the same penetrations, but through the landing (t = 0.08–0.095 s) the mean max penetration doubled, 125
        against 62 µm (4.88 against 6.94 s per step); started from this step's velocity solve's impulses instead
        (tried, not kept) 93 µm (4.72 s). With the push-out's own warm start (the default) and ``predictor_sweeps`` =
        10, 10 sweeps ran 1.24 against 1.36 s per step at rest, 1.72 against 1.77 s after the landing and 4.79 against
        6.75 s through it, with mean max penetrations of 116 / 46 / 67 µm against 114 / 34.5 / 59.9 µm uncapped.
    push_out_warm_start : coupled mode with ``warm_start``, default True: the split push-out solve starts from the
        previous step's push-out impulses of the same contacts (its own iteration carried on from step to step, as the
        velocity solve's is), instead of the previous step's velocity impulses (False, the former start, also used when
        the previous step had no push-out). Both solves find the same fixed point; the push-out's differs from the
        velocity solve's by the recovery of the overlaps (β gap / Δt), which persists from step to step while the
        overlaps do. Every solve ends at its cap on the reference scene, so only the starting point matters there.
        Issue 10's twenty-fifth session, runs from the same states against False (20 steps; 15 through the landing): at
        rest mean max penetration 114 against 119 µm (max 159 against 142 µm) at the same time per step (1.35 / 1.31
        against 1.36 / 1.30 s); after the landing (t = 0.12 s) 34.5 against 41.0 µm (max 47.9 against 52.4 µm; 1.75
        against 1.77 s); through the landing 59.9 against 62.0 µm (6.55 against 6.75 s); the same energy change to two
        digits, no step raising it. On the sunk 4-layer stack of the tests, with the push-out stopped after 2 sweeps,
        it lifts the layers back as the converged push-out does, where the former start lets them creep down
        (``test_push_out_warm_start_lets_a_capped_push_out_lift_a_sunk_stack_back``).
    """

    gravity: tuple = (0.0, -STANDARD_GRAVITY, 0.0)
    restitution: float = 0.0
    friction: FrictionLaw = field(default_factory=FrictionLaw.isotropic)
    friction_objective: str = "qp"
    normal_impulse: str = "dual"
    external_impulse: str = "full"
    harmonisation_iterations: int = 2
    contact_sweeps: int = 2
    joint_tolerance: float = 1e-9
    max_newton: int = 8
    qp_iterations: int = 30
    qp_tolerance: float = 1e-9
    contact_band: float = 0.5
    speculative_speed: float = 0.05
    penetration_recovery: float = 0.2
    fibre_contacts: bool = True
    contact_coupling: str = "coupled"
    split_recovery: bool = True
    warm_start: bool = True
    warm_start_fraction: float = 1.0
    parallel_threshold: int = 2000
    obstacle_midpoints: bool = True
    joint_gap_fraction: float = 0.0
    contact_tolerance: float = 1e-5
    recovery_keeps_joints: bool = True
    springs_in_first_half_step: bool = True
    half_step_projection: bool = True
    end_velocity_positions: bool = True
    end_velocity_predictor: str = "previous"
    sweep_budget: int = 100_000
    small_system_tolerance: float = 1e-6
    exact_final_solve: bool = True
    push_out_slop: float = 1e-3
    separating_candidates: bool = True
    contact_domains: int = 2
    contact_acceleration: str = "nesterov"
    candidate_band: str = "relative"
    candidate_reserve: bool = True
    root_sweeps: int = 8
    root_segments: int = 8
    persistent_normals: bool = False
    late_promotion_overlap: float = 0.1
    predictor_sweeps: int | None = 10
    predictor_extension: bool = True
    kernel_precision: str = "auto"
    push_out_sweeps: int | None = None
    push_out_warm_start: bool = True

    def __post_init__(self):
        if not 0.0 <= self.restitution <= 1.0:
            raise ParameterError(f"restitution must be in [0, 1], got {self.restitution}")
        if self.friction_objective not in ("qp", "lp"):
            raise ParameterError("friction_objective must be 'qp' or 'lp'")
        if self.normal_impulse not in ("dual", "projected"):
            raise ParameterError("normal_impulse must be 'dual' or 'projected'")
        if self.external_impulse not in ("full", "half"):
            raise ParameterError("external_impulse must be 'full' or 'half'")
        if self.harmonisation_iterations < 1 or self.contact_sweeps < 1 or self.max_newton < 1:
            raise ParameterError("harmonisation_iterations, contact_sweeps and max_newton must be ≥ 1")
        if not (self.contact_band >= 0 and self.speculative_speed >= 0 and 0 <= self.penetration_recovery <= 1):
            raise ParameterError("contact_band, speculative_speed ≥ 0 and penetration_recovery in [0, 1]")
        if self.contact_coupling not in ("per-body", "coupled"):
            raise ParameterError("contact_coupling must be 'per-body' (seed) or 'coupled' (Gauss–Seidel over contacts)")
        if not isinstance(self.friction, FrictionLaw):
            raise ParameterError("friction must be a FrictionLaw")
        if not self.contact_tolerance >= 0.0:
            raise ParameterError(f"contact_tolerance must be ≥ 0 m/s, got {self.contact_tolerance}")
        if not (isinstance(self.contact_domains, (int, np.integer)) and self.contact_domains >= 1):
            raise ParameterError(f"contact_domains must be an integer ≥ 1, got {self.contact_domains}")
        for name in ("root_sweeps", "root_segments"):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 0):
                raise ParameterError(f"{name} must be an integer ≥ 0, got {v!r}")
        if self.candidate_band not in ("absolute", "relative"):
            raise ParameterError(f"candidate_band must be 'absolute' or 'relative', got {self.candidate_band!r}")
        if self.contact_acceleration not in ("nesterov", "none"):
            raise ParameterError(f"contact_acceleration must be 'nesterov' or 'none', got {self.contact_acceleration!r}")
        if self.end_velocity_predictor not in ("previous", "projection"):
            raise ParameterError("end_velocity_predictor must be 'previous' or 'projection'")
        if not self.late_promotion_overlap >= 0.0:
            raise ParameterError(f"late_promotion_overlap must be ≥ 0, got {self.late_promotion_overlap}")
        if not 0.0 <= self.warm_start_fraction <= 1.0:
            raise ParameterError(f"warm_start_fraction must be in [0, 1], got {self.warm_start_fraction}")
        for name in ("predictor_sweeps", "push_out_sweeps"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1):
                raise ParameterError(f"{name} must be an integer ≥ 1 or None, got {v!r}")
        if self.kernel_precision not in ("auto", "float64", "float32"):
            raise ParameterError("kernel_precision must be 'auto', 'float64' or 'float32', "
                                 f"got {self.kernel_precision!r}")
        for name in ("push_out_warm_start", "predictor_extension"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ParameterError(f"{name} must be True or False, got {getattr(self, name)!r}")
        if not 0.0 <= self.joint_gap_fraction <= 1.0:
            raise ParameterError(f"joint_gap_fraction must be in [0, 1], got {self.joint_gap_fraction}")


@dataclass
class StepStats:
    """Per-step instrumentation (§4 feature 12 of the digest)."""

    time: float = 0.0
    kinetic_energy: float = 0.0
    potential_energy: float = 0.0
    spring_energy: float = 0.0
    max_joint_gap: float = 0.0
    max_penetration: float = 0.0  # m: −min of the last pass's row gaps (mid-step; end_velocity_positions: at t_i,
    # first order) and the end-of-step obstacle gaps
    contacts: int = 0
    fibre_contacts: int = 0
    obstacle_contacts: int = 0
    newton_iterations: int = 0
    qp_sweeps: int = 0
    qp_capped: int = 0  # coupled mode: contact solves of the step that hit the sweep cap (qp_iterations); a solve
    # whose answer the exact final solve replaced does not count (nor its residual in qp_residual)
    qp_residual: float = 0.0  # coupled mode: largest final sweep residual of the step's solves, m/s
    harmonisation_iterations: int = 0
    energy_bound: float = float("nan")  # J, end_velocity_positions: B of the step's velocity solve (nan: none)
    exact_solves: int = 0  # end_velocity_positions: velocity solves replaced by the exact final solve
    contact_rows: int = 0  # coupled mode: rows of the last contact solve, from the start + added during it
    candidate_rows: int = 0  # coupled mode: candidate pairs not rows from the start
    promoted_rows: int = 0  # of those, added during the solves of the step (sum)
    candidate_band: str = ""  # coupled mode: the band the step's candidates came from ("absolute"/"relative")
    candidate_redos: int = 0  # candidate_band="relative": steps redone because a velocity change exceeded δ̂
    reserve_pairs: int = 0  # candidate_reserve: candidate pairs kept out of the solve at detection
    reserve_promoted: int = 0  # candidate_reserve: of those, the ones a solve's twists closed (then solved again)
    reserve_resolves: int = 0  # candidate_reserve: passes solved again for them
    band_extensions: int = 0  # candidate_band="relative": detections with a band widened to the twist changes
    reversed_normals: int = 0  # persistent_normals: fibre rows of the last pass held on their previous side
    seconds: dict = field(default_factory=dict)

    @property
    def total_energy(self) -> float:
        return self.kinetic_energy + self.potential_energy + self.spring_energy


@dataclass
class _Rows:
    body: np.ndarray
    partner: np.ndarray
    normal: np.ndarray
    lever: np.ndarray
    partner_lever: np.ndarray
    gap: np.ndarray
    obstacle: np.ndarray
    primary: np.ndarray
    key: np.ndarray  # int64 identity of the contact across steps (warm start): a·S + b, or < 0 for obstacles
    tight: np.ndarray = None  # row from the start (False: a candidate, coupled mode; see ChainSolver._detect)

    def __post_init__(self):
        if self.tight is None:
            self.tight = np.ones(len(self.body), bool)


@dataclass
class _Reserve:
    """Candidate pairs kept out of the coupled solve (``ChainOptions.candidate_reserve``): positions ``idx`` in
    the detection's sorted pairs ``sp`` (P, 2) / ``spar`` (P, 2) and their slacks ``sigma`` (m/s) at the
    detection's u⁻; ``args`` the geometry inputs of :func:`~headsim.solvers._kernels.chains_pairs.reserve_rows`
    (the detection state), ``margin`` the rounding margin of the split (m/s)."""

    sp: np.ndarray
    spar: np.ndarray
    idx: np.ndarray
    sigma: np.ndarray
    args: tuple
    margin: float


def _kernel_rows(rows: _Rows) -> tuple[np.ndarray, int]:
    """Primary rows in the coupled kernel's order, rows from the start (``tight``) first, then the
    candidates; and the number of the former."""
    t = np.nonzero(rows.primary & rows.tight)[0]
    c = np.nonzero(rows.primary & ~rows.tight)[0]
    return np.concatenate([t, c]), len(t)



def _point_speed(u: np.ndarray, lever) -> np.ndarray:
    """(n,) m/s: |v| + ρ|ω| of twists u (n, 6), a bound of the speed of every point within ρ (m; scalar or (n,))
    of a body's centre (ρ = h: the segment's axis; h + r: its contact points)."""
    out = np.empty(len(u))
    lever = np.atleast_1d(_f64(lever))
    (FK.point_speed_parallel if len(u) >= FRAME_PASS_PARALLEL else FK.point_speed)(_f64(u), lever, out)
    return out


def _speed_change(u: np.ndarray, u_ref: np.ndarray, half_length: np.ndarray) -> np.ndarray:
    """(S,) m/s: |Δv| + h|Δω| of twists u against u_ref (S, 6), the largest speed change of a segment's points."""
    return _point_speed(u - u_ref, half_length)


def _gaps_at_start(rows: "_Rows", dq0: np.ndarray, row_vn) -> np.ndarray:
    """(n,) m: the rows' gaps at t_i to first order, their mid-step gaps less the first half step's approach
    (dq0 (S, 6): that half step's (Δx, Δθ); row_vn: a :func:`~headsim.solvers._kernels.chains_pairs.row_normal_velocity`
    kernel)."""
    approach = np.empty(len(rows.body))
    row_vn(rows.body, rows.partner, rows.normal, rows.lever, rows.partner_lever, dq0, approach)
    return rows.gap - approach


def _chain_offsets(jk: np.ndarray, jl: np.ndarray) -> np.ndarray:
    """(c + 1,) int64 start of every chain in the joint rows (k, l) of :meth:`ChainSolver._joint_rows` (a
    chain continues where a row's k is the previous row's l), and the row count."""
    start = np.ones(len(jk), bool)
    start[1:] = jk[1:] != jl[:-1]
    return np.append(np.nonzero(start)[0], len(jk)).astype(np.int64)


def _spin_carried(w: np.ndarray, R: np.ndarray, R_mid: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    """(S, 3) rad/s: the world angular velocity at the orientations R_mid that keeps the world angular
    momentum R I Rᵀ w of angular velocity w at the orientations R (torque-free rotation, body inertia
    ``inertia`` (S, 3) kg m²)."""
    return _apply_scaled(R_mid, 1.0 / inertia, _apply_scaled(R, inertia, w))


def _tangent_frames(axis: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k, 3) t₁, t₂ of the coupled kernel's friction frames, from the kernel's own
    ``_kernels.chains._frame`` (t₁ from the segment axis), so the exact solve's friction rows are the
    Gauss–Seidel's."""
    frames = [K._frame(np.ascontiguousarray(a), np.ascontiguousarray(b)) for a, b in zip(axis, n)]
    if not frames:
        return np.zeros((0, 3)), np.zeros((0, 3))
    t1, t2 = zip(*frames)
    return np.array(t1), np.array(t2)


# largest |C u − target| of an accepted exact solve round (consistent rows): this absolute part (m/s) plus this
# relative part of the largest velocity change the rows demand, |target − C u_free| (the least-squares truncation
# at 1e-11 of the scaled Schur complement leaves 1e-10 of it on consistent rows: the 4-layer stack's first step at
# the default 30 sweeps, 2.2e-12 m/s of 1e-2 m/s; truly inconsistent rows there miss by 1e-9-3e-9 m/s)
EXACT_VELOCITY_TOLERANCE = 1e-12
EXACT_RELATIVE_TOLERANCE = 1e-9
EXACT_MAX_DOF = 600  # degrees of freedom (6 per body) of the largest system the exact final solve takes
EXACT_FAILURES: dict = {}  # reason -> count of _exact_final_solve results that were not used (diagnostics)


def _fail(reason):
    EXACT_FAILURES[reason] = EXACT_FAILURES.get(reason, 0) + 1
    return None


def _polygon_radius(px: np.ndarray, py: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(k,) distance from the origin to the boundary of the convex friction polygon (vertices px, py, CCW, per unit
    λ) along the directions of the (k, 2) vectors f (0 for a frictionless law)."""
    if not len(px) or np.hypot(px, py).max() == 0.0:
        return np.zeros(len(f))
    qx, qy = np.roll(px, -1), np.roll(py, -1)
    nx, ny = qy - py, px - qx  # outward edge normals (CCW polygon)
    h = nx * px + ny * py
    d = f / np.maximum(np.linalg.norm(f, axis=1), 1e-300)[:, None]
    nd = d[:, 0:1] * nx[None, :] + d[:, 1:2] * ny[None, :]
    t = np.where(nd > 1e-300, h[None, :] / np.where(nd > 1e-300, nd, 1.0), np.inf)
    return t.min(1)


def _csr_entries(m):
    """Entries of a sparse matrix, row-major: ((rows, columns, values), CSR row pointer)."""
    m = scipy.sparse.csr_matrix(m)
    m.sum_duplicates()
    return (np.repeat(np.arange(m.shape[0]), np.diff(m.indptr)), m.indices, m.data), m.indptr


def _row_entries(coo, rows, scale=None):
    """Entries of the given rows of a matrix from :func:`_csr_entries`, as (local row i of ``rows[i]``, column,
    value), the values multiplied by ``scale[i]`` when given."""
    (r, c, v), ptr = coo
    counts = ptr[rows + 1] - ptr[rows]
    idx = np.repeat(ptr[rows] - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())
    local = np.repeat(np.arange(len(rows)), counts)
    return local, c[idx], v[idx] if scale is None else v[idx] * scale[local]


def _join_entries(*parts):
    """Entries of several row blocks stacked, each shifted down by the row counts of the blocks before it:
    parts are (entries, row count)."""
    out, off = [], 0
    for (lr, c, v), n_rows in parts:
        out.append((lr + off, c, v))
        off += n_rows
    return tuple(np.concatenate(x) for x in zip(*out))


def _active_set_rows(N, joints, J, A, stick, ratio):
    """One round of :func:`_exact_final_solve`: the constraint rows C and the directions D their multipliers act
    along, sparse (m, N), from the joint rows ``joints`` = (entries, row count) and the contact rows J (normal,
    t₁, t₂: :func:`_csr_entries` of (rows, N) each) of the active rows A with their sticking flags. C: the joints,
    the active rows' normal rows, the sticking rows' t₁ rows then their t₂ rows (T u = 0); D: the same, except
    that a sliding row's impulse acts along n + its friction ratio (``ratio[A]``) · (t₁, t₂)."""
    na, ns = len(A), int(stick.sum())
    At = A[stick]
    normal = _row_entries(J[0], A)
    effective = _join_entries((normal, 0), (_row_entries(J[1], A, np.where(stick, 0.0, ratio[A, 0])), 0),
                              (_row_entries(J[2], A, np.where(stick, 0.0, ratio[A, 1])), 0))
    tangent = ((_row_entries(J[1], At), ns), (_row_entries(J[2], At), ns))
    m = joints[1] + na + 2 * ns
    cr, cc, cv = _join_entries(joints, (normal, na), *tangent)
    ir, ic, iv = _join_entries(joints, (effective, na), *tangent)
    return (scipy.sparse.csr_matrix((cv, (cr, cc)), shape=(m, N)),
            scipy.sparse.csr_matrix((iv, (ir, ic)), shape=(m, N)))


def _min_norm_solve(mobility, u_free, C, D, target, cond=1e-11):
    """Solve M̃ u − Dᵀλ = M̃ u_free, C u = target (velocities m/s, multipliers N s) through the Schur complement
    S = C M̃⁻¹ Dᵀ (``mobility``: a factorisation of M̃ with ``solve``): λ is the least-squares solution of least
    norm of S λ = target − C u_free (S scaled symmetrically by |diag S|^-½; singular values below ``cond`` × the
    largest are dropped), so redundant rows (two segments' end rows at one joint, rows of one contact through a
    joint) share their load instead of taking arbitrary opposite ones. Returns (u, λ, largest |C u − target|,
    largest |target − C u_free|, the velocity change the rows demand): a residual above round-off of the latter
    means the rows are inconsistent."""
    if C.shape[0] == 0:
        return u_free, np.zeros(0), 0.0, 0.0
    X = mobility.solve(D.T.toarray())
    S = np.asarray(C @ X)
    g = target - C @ u_free
    d = np.abs(np.diag(S))
    sc = 1.0 / np.sqrt(np.maximum(d, 1e-30 * max(d.max(), 1e-300)))
    # gelsy (complete orthogonal factorisation) gives the least-norm solution as gelsd (SVD) does, ≈ 2× faster here
    y = scipy.linalg.lstsq(S * sc[:, None] * sc[None, :], g * sc, cond=cond, lapack_driver="gelsy")[0]
    lam = y * sc
    u = u_free + X @ lam
    return u, lam, float(np.abs(C @ u - target).max()), float(np.abs(g).max())


def _penetrating_fibre_rows(rows) -> np.ndarray:
    """Indices of the fibre–fibre rows with a negative gap (``ChainOptions.persistent_normals``: the rows whose
    normal side is kept from one step to the next)."""
    return np.flatnonzero((rows.gap < 0.0) & (rows.partner >= 0))


def _body_mass_matrix(mass, inertia_world):
    """Sparse (6n, 6n) block-diagonal mass matrix of n bodies: m I₃ (kg) then the world inertia (kg m²)."""
    n = len(mass)
    blocks = np.zeros((n, 6, 6))
    blocks[:, [0, 1, 2], [0, 1, 2]] = mass[:, None]
    blocks[:, 3:, 3:] = inertia_world
    return scipy.sparse.block_diag(list(blocks), format="csr") if n else scipy.sparse.csr_matrix((0, 0))


def _skew_entries(r):
    """(k, 3, 3) skew matrices r̃ (r̃ b = r × b) of the (k, 3) vectors r."""
    s = np.zeros((len(r), 3, 3))
    s[:, 0, 1], s[:, 0, 2], s[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
    s[:, 1, 0], s[:, 2, 0], s[:, 2, 1] = r[:, 2], -r[:, 1], r[:, 0]
    return s


def _blocks_to_csr(row_block, col_start, blocks, shape):
    """Sparse matrix of 3 × 3 blocks: block i at rows 3 row_block[i] … +3, columns col_start[i] … +3."""
    r = 3 * row_block[:, None, None] + np.arange(3)[None, :, None] + np.zeros((1, 1, 3), np.int64)
    c = col_start[:, None, None] + np.arange(3)[None, None, :] + np.zeros((1, 3, 1), np.int64)
    return scipy.sparse.csr_matrix((blocks.reshape(-1), (r.reshape(-1), c.reshape(-1))), shape=shape)


def _joint_matrices(l, k, rk, rl, N):
    """Joint rows of :func:`_exact_final_solve` over local bodies (body l, body k or −1 for the anchor, anchors
    rk, rl in world axes, m): S (3 nj, N) the spin difference ω_l − ω_k and G (3 nj, N) the anchor velocity
    difference (v_k + ω_k × r_k) − (v_l + ω_l × r_l) (eqs. 8.81–8.85)."""
    nj = len(l)
    j = np.arange(nj)
    has_k = k >= 0
    eye = np.broadcast_to(np.eye(3), (nj, 3, 3))
    jk, kk = j[has_k], 6 * k[has_k]
    S = _blocks_to_csr(np.concatenate([j, jk]), np.concatenate([6 * l + 3, kk + 3]),
                       np.concatenate([eye, -eye[has_k]]), (3 * nj, N))
    G = _blocks_to_csr(np.concatenate([j, j, jk, jk]), np.concatenate([6 * l, 6 * l + 3, kk, kk + 3]),
                       np.concatenate([-eye, _skew_entries(rl), eye[has_k], -_skew_entries(rk[has_k])]),
                       (3 * nj, N))
    return S, G


def _contact_matrix(a, b, lever_a, lever_b, d, N):
    """(rows, N) sparse contact rows along the unit directions d (rows, 3): body a's point velocity
    v_a + ω_a × r_a minus partner b's (b = −1: an obstacle), projected on d."""
    nr = len(a)
    i = np.arange(nr)
    hb = b >= 0
    rows = np.concatenate([np.repeat(i, 6), np.repeat(i[hb], 6)])
    cols = np.concatenate([(6 * a[:, None] + np.arange(6)).reshape(-1), (6 * b[hb, None] + np.arange(6)).reshape(-1)])
    vals = np.concatenate([np.concatenate([d, np.cross(lever_a, d)], 1).reshape(-1),
                           -np.concatenate([d[hb], np.cross(lever_b[hb], d[hb])], 1).reshape(-1)])
    return scipy.sparse.csr_matrix((vals, (rows, cols)), shape=(nr, N))


def _exact_bodies(rows, joints):
    """The bodies of the exact system, sorted: every body of the contact rows and the joints."""
    jk, jl = joints[0], joints[1]
    return np.unique(np.concatenate([rows.body, rows.partner[rows.partner >= 0], jk[jk >= 0], jl]))


def _exact_system(model, rows, u_minus, R_mid, joints, used):
    """The linear pieces of :func:`_exact_final_solve` over the bodies ``used`` (their local order): M̃ = M + SᵀCS
    (sparse (N, N), N = 6 len(used); M block diagonal m I₃, I_world at R_mid; S the joints' spin differences
    ω_l − ω_k, C their spring rows), the momentum M u⁻ + SᵀC ω_rel,0 (N,), the joints' gap-rate rows G (3 nj, N):
    (v_k + ω_k × r_k) − (v_l + ω_l × r_l), and the contact rows J = [normal, t₁, t₂] (each (rows, N), t₁ from
    the body's axis)."""
    jk, jl, jrk, jrl, _, jc, jw0, _ = joints
    n = len(used)
    N = 6 * n
    loc = np.full(model.n_segments, -1, np.int64)
    loc[used] = np.arange(n)
    M = _body_mass_matrix(model.mass[used], _scaled_frames(R_mid[used], model.inertia[used]))
    S, G = _joint_matrices(loc[jl], np.where(jk >= 0, loc[np.maximum(jk, 0)], -1), jrk, jrl, N)
    Cb = scipy.sparse.block_diag(list(jc), format="csr") if len(jl) else scipy.sparse.csr_matrix((0, 0))
    Mt = (M + S.T @ Cb @ S).tocsr()
    rhs = M @ u_minus[used].reshape(-1) + S.T @ (Cb @ jw0.reshape(-1))
    t1, t2 = _tangent_frames(R_mid[rows.body, :, 2], rows.normal)
    partner = rows.partner
    pb = np.where(partner >= 0, loc[np.maximum(partner, 0)], -1)
    J = [_contact_matrix(loc[rows.body], pb, rows.lever, rows.partner_lever, d, N) for d in (rows.normal, t1, t2)]
    return Mt, rhs, G, J


def _exact_final_solve(model, rows, lam, fr, targets, u_minus, R_mid, joints, polygon, max_dof=EXACT_MAX_DOF,
                       rounds=8):
    """The velocity solve's problem solved exactly (Schur complement, :func:`_min_norm_solve`) on the active set the
    Gauss–Seidel found (``ChainOptions.exact_final_solve``): rows with λ > 0 hold J u = target (targets (rows,)
    m/s), a sticking contact (friction strictly inside the polygon λ·conv{μ_β d_β} at the Gauss–Seidel answer)
    T u = 0, a sliding one keeps the direction and ratio to λ of its friction impulse; the joints J u = target
    and their spring rows (``joints``: :meth:`ChainSolver._joint_rows`) exactly, M at R_mid. Rows whose λ comes
    out negative leave the set, rows whose bound is violated by more than 1e-12 m/s join it, sticking friction
    outside the polygon slides (on the polygon along its direction), sliding friction that would accelerate its
    contact sticks, until nothing changes (at most ``rounds`` times; a set met twice ends it). Returns (u (S, 6),
    λ (rows,), friction (rows, 2)) or None (the reason counted in :data:`EXACT_FAILURES`) when the system has more
    than ``max_dof`` degrees of freedom or no such set was found."""
    jl, jt = joints[1], joints[4]
    body = rows.body
    if 6 * len(np.unique(jl)) > max_dof:  # a lower bound of the bodies below, without the rows' unique
        return _fail("too large")
    used = _exact_bodies(rows, joints)
    n = len(used)
    N = 6 * n
    if N > max_dof or not len(body):
        return _fail("too large")
    Mt, rhs, G, J = _exact_system(model, rows, u_minus, R_mid, joints, used)
    nj, nr = len(jl), len(body)
    active = lam > 0
    ratio = np.zeros((nr, 2))
    ratio[active] = fr[active] / lam[active, None]
    px, py = polygon
    frictional = len(px) > 0 and np.hypot(px, py).max() > 0.0
    stick = active & (np.linalg.norm(ratio, axis=1) < _polygon_radius(px, py, ratio) * (1.0 - 1e-6))
    # M̃ is sparse (block-tridiagonal chains): one SuperLU factor serves every round
    G_e = _csr_entries(G)
    Je = [_csr_entries(j) for j in J]
    try:
        mobility = scipy.sparse.linalg.splu(Mt.tocsc())
    except RuntimeError:  # SuperLU: "Factor is exactly singular"
        return _fail("singular")
    u_free = mobility.solve(rhs)
    seen = set()  # the (active, sticking) sets tried: a set met again is a cycle, which no further round leaves
    for _ in range(rounds):
        key = (active.tobytes(), stick.tobytes())
        if key in seen:
            return _fail("active set cycles")
        seen.add(key)
        A = np.nonzero(active)[0]
        st = stick[A]
        na, ns = len(A), int(st.sum())
        Ast, Asl = A[st], A[~st]
        Cm, Dm = _active_set_rows(N, (G_e[0], 3 * nj), Je, A, st, ratio)
        target = np.concatenate([jt.reshape(-1), targets[A], np.zeros(2 * ns)])
        u, sol, residual, demanded = _min_norm_solve(mobility, u_free, Cm, Dm, target)
        if not np.isfinite(u).all() or not np.isfinite(sol).all():
            return _fail("singular")
        if residual > EXACT_VELOCITY_TOLERANCE + EXACT_RELATIVE_TOLERANCE * demanded:
            # inconsistent equalities (rows of one constraint with different targets): the rows the least-squares
            # velocity over-satisfies would be slack; leave them out
            over = (J[0] @ u)[A] > targets[A] + 1e-12
            if not over.any():
                return _fail("inconsistent")
            active[A[over]] = False
            continue
        lam_a = sol[3 * nj:3 * nj + na]
        f_s = sol[3 * nj + na:].reshape(2, ns).T
        changed = False
        neg = lam_a < 0
        if neg.any():
            active[A[neg]] = False
            changed = True
        viol = (J[0] @ u < targets - 1e-12) & ~active
        if viol.any():
            active |= viol
            ratio[viol] = 0.0
            stick |= viol & frictional
            changed = True
        # friction: a sticking force outside the inner cone slides (its direction, on the cone), a sliding
        # force that would accelerate its contact sticks
        rho = _polygon_radius(px, py, f_s)
        out_cone = np.linalg.norm(f_s, axis=1) > rho * np.maximum(lam_a[st], 0.0)
        if out_cone.any():
            r = Ast[out_cone]
            f = f_s[out_cone]
            ratio[r] = rho[out_cone, None] * f / np.maximum(np.linalg.norm(f, axis=1), 1e-300)[:, None]
            stick[r] = False
            changed = True
        vt = np.stack([(J[1] @ u)[Asl], (J[2] @ u)[Asl]], 1)
        fv = (ratio[Asl] * vt).sum(1)
        acc = fv > 1e-9 * np.linalg.norm(ratio[Asl], axis=1) * np.linalg.norm(vt, axis=1)
        if acc.any() and frictional:
            stick[Asl[acc]] = True
            changed = True
        elif acc.any():
            return _fail("sliding friction accelerates")
        if not changed:
            break
    else:
        return _fail("active set")
    lam_new = np.zeros(nr)
    lam_new[A] = lam_a
    fr_new = np.zeros((nr, 2))
    fr_new[Asl] = ratio[Asl] * lam_new[Asl, None]
    fr_new[Ast] = f_s
    out = u_minus.copy()
    out[used] = u.reshape(n, 6)
    return out, lam_new, fr_new


def _stored_impulses(rows, impulses):
    """(sorted keys, λ, friction) of the rows of a solve's ``impulses`` = (λ, friction) that carry a normal
    impulse: the next step's warm start (:meth:`ChainSolver._warm_start_impulses`); None without a solve."""
    if impulses is None:
        return None
    pr = np.nonzero(impulses[0] > 0)[0]
    order = pr[np.argsort(rows.key[pr])]
    return rows.key[order], impulses[0][order], impulses[1][order]


def _fibre_domains(fa: np.ndarray, fb: np.ndarray, n_fibres: int, n_domains: int) -> np.ndarray:
    """(n_fibres,) int64 domain 0 … n_domains − 1 of every fibre, for the parallel contact sweep of the coupled
    solve (``ChainOptions.contact_domains``): recursive bisection of the fibre contact graph (fa, fb: the
    fibres of a row's two bodies, fb < 0 for obstacle rows) into parts with about equal numbers of row ends,
    each cut along a breadth-first order from a pseudo-peripheral fibre (the BFS level sets of a contact
    graph are spatial layers, so few rows join two parts: 4.5 % on the reference scene). Deterministic."""
    import scipy.sparse as sp

    part = np.zeros(n_fibres, np.int64)
    if n_domains <= 1 or n_fibres < 2:
        return part
    m = fb >= 0
    G = sp.coo_matrix((np.ones(int(m.sum())), (fa[m], fb[m])), shape=(n_fibres, n_fibres)).tocsr()
    G = (G + G.T).tocsr()
    weight = (np.bincount(fa, minlength=n_fibres) + np.bincount(fb[m], minlength=n_fibres)).astype(float)

    def split(fibres, k, first):
        if k <= 1 or len(fibres) < 2:
            part[fibres] = first
            return
        sub = G[fibres][:, fibres]
        w = weight[fibres]
        by_weight = np.argsort(-w, kind="stable")

        def bfs_order(start):
            starts = np.concatenate([[start], by_weight]).astype(np.int64)
            return KC.breadth_first_cover(sub.indptr.astype(np.int64), sub.indices.astype(np.int64), starts)

        o = bfs_order(int(np.argmax(w)))
        o = bfs_order(int(o[-1]))  # from the last fibre reached: a pseudo-peripheral start
        k0 = k // 2
        c = np.cumsum(w[o])
        cut = c > c[-1] * (k0 / k) if c[-1] > 0 else np.arange(len(o)) >= len(o) * k0 // k
        split(fibres[o[~cut]], k0, first)
        split(fibres[o[cut]], k - k0, first + k0)

    split(np.arange(n_fibres), int(n_domains), 0)
    return part


def _obstacle_key(obstacle_index, segments, kind, n_segments):
    """Negative int64 keys of obstacle rows: kind 0 / 1 = inner / outer end point, 2 = axis interior."""
    return -1 - ((obstacle_index * n_segments + np.asarray(segments, np.int64)) * 3 + kind)


def _unique_joint_contacts(pairs: np.ndarray, params: np.ndarray, model: ChainModel) -> np.ndarray:
    """(n,) bool: drop the duplicates of a contact that sits on a joint.

    A partner touching a chain exactly at a joint is reported twice (closest point at the outer end of
    segment s − 1 and at the inner end of segment s, the same material point), four times if it is a
    joint of both chains. The copies are the same constraint with slightly different normals and gaps
    (the joint gap): as separate rows they are redundant (a singular Delassus block, on which projected
    Gauss–Seidel drifts) and, with their different gaps, contradictory. Keep the copy on the inner
    segment of each joint (s − 1). "At the joint": both closest points within one fibre radius of it
    (segments bend at the joint and the joint gap opens slightly, so the parameters are not exactly 0, 1).
    The pairs are the ones :func:`~headsim.solvers._kernels.chains_pairs.drop_pairs_without_rows` kept (in the
    band, not separating), so a copy is dropped only where the copy it defers to is a row (before issue 10's
    sixteenth session the copy on s was dropped also where the one on s − 1 was itself dropped: a contact on a
    joint that only segment s saw within its band had no row)."""
    if not len(pairs):
        return np.zeros(0, bool)
    drop = np.empty(len(pairs), np.bool_)
    KP.joint_duplicate_contacts(np.ascontiguousarray(pairs, np.int64), np.ascontiguousarray(params, np.float64),
                                model.half_length, model.radius, model.segment_fibre, model.is_root, drop)
    return ~drop


class ChainSolver:
    """Moreau midpoint stepper for kinematic chains (see the module docstring for the algorithm).

    ``step(model, state, dt, obstacles)`` returns the new state; ``last_stats`` holds its
    :class:`StepStats`. ``fibre_loop=True`` runs the joint and contact kernels one fibre at a time
    from Python (the seed's serial order; same results) — the benchmark's baseline.
    """

    def __init__(self, options: ChainOptions = ChainOptions(), *, fibre_loop: bool = False):
        self.options = options
        self.fibre_loop = fibre_loop
        self.last_stats = StepStats()
        self._bvh = None  # refitted or rebuilt every step (_packed_tree): its capsule radii carry the margins
        self._speed = None
        self._mu = options.friction.generators()
        self._momentum = 1.0 if options.contact_acceleration == "nesterov" else 0.0  # coupled kernels' Nesterov β scale
        self._warm = None  # (sorted keys, λ, friction) of the last step's contact solution (warm start)
        self._warm_push = None  # the same of the last step's push-out solve
        self._normals = None  # (sorted keys, normals) of last step's penetrating fibre rows (persistent_normals)
        self._impulses = None
        self._promoted = 0  # candidate rows the last coupled solve added
        self._qp_capped = 0  # coupled solves of this step that hit the sweep cap
        self._qp_residual = 0.0  # largest final sweep residual of this step's coupled solves, m/s
        self._gathered = None  # (rows, kernel order, rows from the start, gathered geometry, screen) of this step
        self._screen_ref = None  # (rows, their n·(u_A − u_B) at the detection's u⁻, that u⁻) of this step
        self._pair_speed = None  # candidate_band="relative": this step's per-segment allowance speed, m/s
        self._dhat = None  # (S,) m/s: allowance for each segment's velocity change in the next step's solves
        self._allow = None  # candidate_reserve: this step's allowance (S,) m/s of the reserve's split
        self._reserve = []  # candidate_reserve: this step's reserve pairs (_Reserve chunks)
        self._det_buffers = None  # work arrays of the fused detection pass (see _detection_buffers)
        self._rows_buf = None  # its output rows (see _row_buffers)
        self._joint_factor_buf = None  # the joint stage's Newton factors (see _joints)
        self._unsprung_factor_buf = None  # … of the spring-free joint stage (springs_in_first_half_step=False)
        self._pass_setup = None  # (rows, pass, joint rows, mass, inertia, kernel set-up, body domains) of this pass
        self._unsprung = None  # (model, the model without joint springs and damping): first half step
        self._bound = None  # end_velocity_positions: the last step's energy bound B (J, see _energy_bound)
        self._budgeted = False  # the last coupled solve ran under the small-system sweep budget
        self._continued = 0  # end_velocity_positions: exact final solves of the last step
        self._reserve_moved = 0  # candidate_reserve: reserve pairs this step moved to the candidates
        self._band_extensions = 0  # candidate_band="relative": widened detections of the last step
        self._widen_seconds = 0.0  # candidate_band="relative": their time, s
        self._rel_grid = None  # candidate_band="relative": the LocalMotionBound of this step's detection state

    @staticmethod
    def _writable(a):
        """A writeable copy of a read-only model array: the coupled kernel compiled for read-only mass and
        inertia arrays ran 5x slower on the same data (measured, 120 x 50 helical scene)."""
        return a if a.flags.writeable else a.copy()

    # -- joints ----------------------------------------------------------------------------------
    def _joints(self, model, x, R, v, w, dt, dx_extra, dth_extra, factor=None, store=None):
        """The joint stage (Method I) of every fibre at the t_i state x, R, v, w: (v, w) corrected, the largest
        Newton iteration count and the largest predicted joint gap (m). ``factor``: None, or a list that holds
        the chains' factorised Newton matrices for the given ``model`` and R, filled by the first call that gets
        it empty (the harmonisation passes of one step share it: the matrix depends on R of t_i only).
        ``store``: the attribute whose arrays (kept across steps, :meth:`_kept_arrays`) the factors go to;
        None: fresh arrays."""
        o = self.options
        F = model.n_fibres
        v_out = np.empty_like(v)
        w_out = np.empty_like(w)
        its = np.zeros(F, np.int64)
        gaps = np.zeros(F)
        g = np.asarray(o.gravity, float)
        args = (model.segment_offsets, model.anchored, x, R, v, w, model.mass, model.inertia, model.half_length,
                model.root_point, model.root_frame, float(dt), g, dx_extra, dth_extra, model.joint_stiffness,
                model.rest_rotation, model.joint_damping, float(o.joint_tolerance), int(o.max_newton))
        ready = factor is not None and len(factor) > 0
        if not ready:
            S = model.n_segments
            def alloc(m):
                return tuple(np.empty((m, 6, 6)) for _ in range(3))
            arrays = alloc(S) if store is None else tuple(a[:S] for a in self._kept_arrays(store, S, alloc, False))
            if factor is not None:
                factor.extend(arrays)
        else:
            arrays = tuple(factor)
        fac = arrays + (ready,)
        if self.fibre_loop:
            for f in range(F):
                its[f], gaps[f] = K.correct_fibre_joints(f, *args, v_out, w_out, *fac)
        elif model.n_segments >= self.options.parallel_threshold:
            K.correct_joints_batch(np.arange(F, dtype=np.int64), *args, v_out, w_out, *fac, its, gaps)
        else:
            K.correct_joints_serial(np.arange(F, dtype=np.int64), *args, v_out, w_out, *fac, its, gaps)
        return v_out, w_out, int(its.max(initial=0)), float(gaps.max(initial=0.0))

    # -- detection ---------------------------------------------------------------------------------
    def _detect(self, model, x, R, dt, obstacles, u_minus=None, dq0=None, old_speed=None) -> _Rows:
        """Contact rows at the mid-step state x, R. Fibre pairs come from the BVH with per-segment radii grown by
        0.75 |u|Δt of each segment's own speed (|v| + h|ω|, so the relative speed of any pair is covered) and
        are kept within ``contact_band`` + ``speculative_speed``·Δt + 0.75 (|u_a| + |u_b|)Δt of contact. In
        coupled mode, with the pre-impact twists ``u_minus`` given, only the pairs whose gap is within
        ``contact_band`` (without the speculative margin) plus :data:`CLOSING_MARGIN_FACTOR` × their relative
        normal closing speed × Δt are rows from the start (``tight``); the others are candidates that the coupled solve turns into rows as soon as its
        current velocities would close their gap within the step (see
        :func:`headsim.solvers._kernels.chains_coupled._coupled_iterate_impl`): a pair whose partner is
        stopped during the solve (a falling strand whose bottom lands) gets its row then, so the margin
        from the absolute speeds still bounds which pairs can collide, while only the pairs that do take
        part in the iteration."""
        o = self.options
        d3 = R[:, :, 2]
        h = model.half_length
        r = model.radius
        margin = o.speculative_speed * dt
        # persistence filter (eq. 8.9) with u⁻ given: approaching or smooth contacts only; relative normal
        # velocities below one step of gravity count as smooth (persistent): bodies resting on each other
        # differ by round-off-sized amounts in their pre-impact velocities, which must not switch resting
        # contacts off
        smooth = float(np.linalg.norm(o.gravity)) * dt
        uu_all = np.ascontiguousarray(u_minus) if u_minus is not None else None
        parts = []
        # obstacles: segment end points (Sobottka §8.6.5: end points suffice at this segment length)
        if obstacles:
            ends = np.concatenate([x - h[:, None] * d3, x + h[:, None] * d3])
            seg = np.concatenate([np.arange(model.n_segments)] * 2)
            # speculative margin per end point from its own speed (obstacles are cheap to over-detect)
            vend = np.concatenate([self._speed, self._speed]) if self._speed is not None else 0.0
            for oi, ob in enumerate(obstacles):
                band = (o.contact_band * r[seg] if ob.band is None else ob.band) + margin + 1.5 * vend * dt
                phi = ob.field.distance(ends) - ob.level
                hit = np.nonzero(phi < r[seg] + band)[0]
                if len(hit):
                    n = ob.field.normal(ends[hit])
                    ok = np.linalg.norm(n, axis=1) > 0.5
                    hit, n = hit[ok], n[ok]
                    s = seg[hit]
                    lever = ends[hit] - r[s, None] * n - x[s]
                    parts.append(_Rows(s, np.full(len(s), -1), n, lever, np.zeros_like(n), phi[hit] - r[s],
                                       np.ones(len(s), bool), np.ones(len(s), bool),
                                       _obstacle_key(oi, s, (hit >= model.n_segments).astype(np.int64),
                                                     model.n_segments)))
                if o.obstacle_midpoints:
                    mid = self._obstacle_interior(ob, model, x, d3, margin, dt, oi)
                    if mid is not None:
                        parts.append(mid)
        if u_minus is not None:  # persistence filter of the obstacle rows (the fibre rows' is in the kernel)
            for i, p in enumerate(parts):
                if p.obstacle.all() and len(p.body):
                    vn = np.empty(len(p.body))
                    KP.row_normal_velocity(p.body, p.partner, p.normal, p.lever, p.partner_lever, uu_all, vn)
                    keep = vn <= smooth
                    if o.separating_candidates and o.contact_coupling == "coupled":
                        cand = ~keep & (p.gap < 0)  # separating penetrations: candidate rows
                        p.tight = p.tight & ~cand
                        keep |= cand
                    if not keep.all():
                        parts[i] = _Rows(*[getattr(p, k)[keep] for k in _Rows.__dataclass_fields__])
        fields = _Rows.__dataclass_fields__
        self._reserve = []
        if o.fibre_contacts and model.n_segments > 1:
            from headsim.collide import FibreBVH, FibreSet
            from headsim.collide.fibre_bvh import subset_contact_pairs

            F = model.n_fibres
            so = model.segment_offsets
            nodes = np.empty((model.n_segments + F, 3))
            node_of_outer = np.arange(model.n_segments) + model.segment_fibre + 1
            nodes[node_of_outer] = x + h[:, None] * d3
            nodes[so[:-1] + np.arange(F)] = x[so[:-1]] - h[so[:-1], None] * d3[so[:-1]]
            # per-segment detection radius: band plus a speculative margin from the segment's own speed
            spd = self._speed if self._speed is not None else np.zeros(model.n_segments)
            if self._pair_speed is not None:  # candidate_band="relative"
                spd = self._pair_speed
            rdet = self._detection_base(model, dt) + 0.75 * spd * dt
            fs = FibreSet(nodes, so + np.arange(F + 1), rdet)
            # the packed AABB tree (variant AP) returns exactly the contact set of the AS tree: 4.3x faster on
            # the 35,500-segment reference scene (0.28 s vs 1.21 s), but slower on small scenes (320
            # segments: 18.6 ms vs 7.7 ms per step, its refit and thread pool dominate), which keep the AS
            # tree, queried on one thread
            grown = None if old_speed is None else np.flatnonzero(spd > old_speed)
            # the pairs without rows (separating, outside the band) are dropped before the rows are built
            # (KP.drop_pairs_without_rows; in the packed query's workers): they are neither joined nor sorted, and
            # a joint copy is one of a kept pair
            uu = uu_all if uu_all is not None else np.zeros((0, 6))
            geo = (np.ascontiguousarray(x), np.ascontiguousarray(d3), h, r)
            band_args = (np.ascontiguousarray(spd, np.float64), float(o.contact_band), float(margin), float(dt), uu,
                         CLOSING_MARGIN_FACTOR, self._pair_mark(), smooth)
            keep = geo + band_args  # the arguments of _pair_geometry's keep rule
            packed = model.n_segments >= o.parallel_threshold
            if grown is not None and len(grown) <= SUBSET_QUERY_FRACTION * model.n_segments:
                # a band widened for a few segments: only the pairs that involve them can be new (the kernel drops
                # the others, as it does the pairs of the first band), without a tree
                pairs, params = subset_contact_pairs(fs, grown)
                packed = False
            elif packed:
                # unsorted pairs: one fused pass orders them by (a, b), drops the joint copies and writes the
                # rows (KP.detect_rows; the same rows in the same order as the sort → duplicate filter → rows
                # kernels)
                self._bvh = self._packed_tree(fs, refit=old_speed is None)
                pairs, params = self._bvh.self_contact_pairs(
                    sort=False, chunk_filter=lambda p, q: KP.drop_pairs_without_rows(p, q, *keep))
            else:
                self._bvh = FibreBVH(fs, "aabb", "spatial", threads=1)
                pairs, params = self._bvh.self_contact_pairs(sort=False)
            if not packed:
                pairs, params = np.ascontiguousarray(pairs, np.int64), np.ascontiguousarray(params, np.float64)
                n_kept = KP.drop_pairs_without_rows(pairs, params, *keep)
                pairs, params = pairs[:n_kept], params[:n_kept]
            if len(pairs):
                P = len(pairs)
                S = model.n_segments
                coupled = o.contact_coupling == "coupled"
                # coupled mode: the fibre rows are written behind the obstacle rows into the arrays of the whole
                # row set (one copy less of ≈ 2 M rows on the reference scene than a concatenation, 0.3–0.4 s)
                n0 = sum(len(p.body) for p in parts) if coupled else 0
                full = self._row_buffers(n0 + P, fresh=old_speed is not None)
                a, b, n, la, lb, gap, tight, key = (full.body[n0:], full.partner[n0:], full.normal[n0:],
                                                    full.lever[n0:], full.partner_lever[n0:], full.gap[n0:],
                                                    full.tight[n0:], full.key[n0:])
                pairs = np.ascontiguousarray(pairs, np.int64)
                params = np.ascontiguousarray(params, np.float64)
                rest = band_args + (a, b, n, la, lb, gap, tight)
                fused = KP.detect_rows_parallel if S >= o.parallel_threshold else KP.detect_rows
                # candidate_reserve: candidates whose slack exceeds their bodies' allowances stay in reserve
                allow = self._allow if (coupled and uu_all is not None and self._allow is not None) else np.zeros(0)
                warm_keys = self._warm[0] if (self._warm is not None and len(allow)) else np.zeros(0, np.int64)
                res_margin = 0.0
                if len(allow):
                    rho = h + r
                    res_margin = 1e-12 + 1e-9 * float(np.max(_point_speed(uu, rho)))
                sp, spar, tmp_p, tmp_r, res_idx, res_sigma = self._detection_buffers(P, fresh=old_speed is not None)
                if not len(allow):
                    res_idx, res_sigma = res_idx[:0], res_sigma[:0]
                res_count = np.zeros(1, np.int64)
                k = fused(pairs, params, *geo, model.segment_fibre, model.is_root, *rest, key,
                          np.ascontiguousarray(allow, np.float64),
                          np.zeros((0, 6)) if dq0 is None else np.ascontiguousarray(dq0), self._reserve_half_gap(),
                          res_margin,
                          np.ascontiguousarray(warm_keys, np.int64), sp, spar, tmp_p, tmp_r, res_idx, res_sigma,
                          res_count, np.zeros(0) if old_speed is None else np.ascontiguousarray(old_speed, np.float64))
                if k >= 0 and res_count[0]:
                    nr = int(res_count[0])
                    self._reserve.append(_Reserve(sp[:P], spar[:P], res_idx[:nr].copy(), res_sigma[:nr].copy(),
                                             (x.copy(), np.ascontiguousarray(d3).copy(), h, r) + rest[:4]
                                                  + (uu.copy(),) + rest[5:8],
                                                  res_margin))
                if k < 0:  # a pair with a ≥ b (not from these trees): sort, filter and build the rows in steps
                    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
                    pairs, params = pairs[order], params[order]
                    keep = _unique_joint_contacts(pairs, params, model)
                    pairs, params = np.ascontiguousarray(pairs[keep]), np.ascontiguousarray(params[keep])
                    k = KP.fibre_pair_rows(pairs, params, *geo, *rest)
                    np.multiply(a[:k], S, out=key[:k])
                    key[:k] += b[:k]
                a, b, n, la, lb, gap, tight = a[:k], b[:k], n[:k], la[:k], lb[:k], gap[:k], tight[:k]
                z = np.zeros(k, bool)
                if coupled:  # one row per pair (the coupled solve applies equal and opposite impulses)
                    i0 = 0
                    for p in parts:  # the obstacle rows first, as in the concatenation of the parts
                        for f in fields:
                            getattr(full, f)[i0:i0 + len(p.body)] = getattr(p, f)
                        i0 += len(p.body)
                    out = _Rows(*[getattr(full, f)[:n0 + k] for f in fields])
                    self._keep_normal_sides(out, model)
                    return out
                else:
                    parts.append(_Rows(a, b, n, la, lb, gap, z, ~z, a * S + b))
                    parts.append(_Rows(b, a, -n, lb, la, gap, z, z, b * S + a))
        if not parts:
            z = np.zeros((0, 3))
            return _Rows(np.zeros(0, np.int64), np.zeros(0, np.int64), z, z, z, np.zeros(0), np.zeros(0, bool),
                         np.zeros(0, bool), np.zeros(0, np.int64), np.zeros(0, bool))
        return _Rows(*[np.concatenate([getattr(p, k) for p in parts]) for k in _Rows.__dataclass_fields__])

    def _keep_normal_sides(self, rows, model):
        """``ChainOptions.persistent_normals``: in place, give every penetrating fibre row (gap < 0) whose pair
        penetrated in the previous step with a normal pointing the other way that previous side: normal
        reversed, contact points on the other sides of the axes (levers ± 2r n), gap −(d + r_a + r_b) =
        −gap − 2(r_a + r_b), a row from the start."""
        if self._normals is None or not self.options.persistent_normals:
            return
        keys, normals = self._normals
        sel = _penetrating_fibre_rows(rows)
        if not len(keys) or not len(sel):
            return
        j = np.minimum(np.searchsorted(keys, rows.key[sel]), len(keys) - 1)
        same = keys[j] == rows.key[sel]
        sel, j = sel[same], j[same]
        sel = sel[np.einsum("ij,ij->i", rows.normal[sel], normals[j]) < 0.0]
        if not len(sel):
            return
        n = rows.normal[sel]
        ra, rb = model.radius[rows.body[sel]], model.radius[rows.partner[sel]]
        rows.lever[sel] += 2.0 * ra[:, None] * n
        rows.partner_lever[sel] -= 2.0 * rb[:, None] * n
        rows.gap[sel] = -rows.gap[sel] - 2.0 * (ra + rb)
        rows.normal[sel] = -n
        rows.tight[sel] = True

    def _pair_mark(self) -> int:
        """The row kernels' ``mark_tight``: 0 per-body mode (every pair a row), 1 coupled (rows and candidates),
        2 coupled with ``separating_candidates`` (separating penetrations kept as candidates)."""
        o = self.options
        return (2 if o.separating_candidates else 1) if o.contact_coupling == "coupled" else 0

    def _packed_tree(self, fs, refit: bool):
        """The packed tree of the fibre-pair detection for the fibre set ``fs`` (capsules grown to the detection
        radii): the previous step's tree refitted (``refit`` and younger than :data:`TREE_REFIT_STEPS` steps,
        and its inner boxes summed no more than :data:`TREE_REFIT_QUALITY` × the ones at its build), else a new
        build. The pairs are the same either way (the query is exact); a rebuild costs 24 ms on the reference
        scene, a refit 1–2 ms."""
        from headsim.collide.fibre_bvh import PackedFibreBVH

        tree = self._bvh
        if (refit and isinstance(tree, PackedFibreBVH) and tree._steps_since_rebuild + 1 < TREE_REFIT_STEPS
                and np.array_equal(tree.fibres.fibre_offsets, fs.fibre_offsets)):
            tree.refit_fibres(fs)
            if tree._quality() <= TREE_REFIT_QUALITY * tree._quality_ref:
                return tree
        return PackedFibreBVH(fs)

    def _obstacle_interior(self, ob, model, x, d3, margin, dt, oi=0, samples: int = 9):
        """Contact rows at the closest point of each segment's axis to the distance field when it lies
        inside the segment (end points are handled separately): φ sampled at ``samples`` points along the
        axis, the smallest interior sample refined by a parabola through its neighbours, and kept when it
        is below both end values and inside the detection band. Only segments whose centre is within
        h + r + band of the iso-level are sampled (a distance field is 1-Lipschitz). With long segments on
        a curved obstacle (the sphere scenes at 24–40 segments per 30 cm) the middle of a segment would
        otherwise sink in while both ends rest on the surface."""
        o = self.options
        h, r = model.half_length, model.radius
        spd = self._speed if self._speed is not None else np.zeros(model.n_segments)
        band = (o.contact_band * r if ob.band is None else np.full_like(r, ob.band)) + margin + 1.5 * spd * dt
        phic = ob.field.distance(x) - ob.level
        cand = np.nonzero(phic < h + r + band)[0]
        if not len(cand):
            return None
        ts = np.linspace(-1.0, 1.0, samples)
        pts = x[cand, None, :] + (ts[None, :, None] * h[cand, None, None]) * d3[cand, None, :]
        phi = (ob.field.distance(pts.reshape(-1, 3)) - ob.level).reshape(len(cand), samples)
        i = np.argmin(phi, axis=1)
        inner = (i > 0) & (i < samples - 1)
        cand, i, phi = cand[inner], i[inner], phi[inner]
        if not len(cand):
            return None
        rows = np.arange(len(cand))
        f0, f1, f2 = phi[rows, i - 1], phi[rows, i], phi[rows, i + 1]
        dts = ts[1] - ts[0]
        den = f0 - 2 * f1 + f2
        shift = np.where(den > 1e-300, 0.5 * (f0 - f2) / np.where(den > 1e-300, den, 1.0), 0.0)
        t = (ts[i] + np.clip(shift, -1.0, 1.0) * dts) * h[cand]
        p = x[cand] + t[:, None] * d3[cand]
        ph = ob.field.distance(p) - ob.level
        keep = (ph < np.minimum(phi[:, 0], phi[:, -1])) & (ph < r[cand] + band[cand])
        cand, p, ph = cand[keep], p[keep], ph[keep]
        if not len(cand):
            return None
        n = ob.field.normal(p)
        ok = np.linalg.norm(n, axis=1) > 0.5
        cand, p, ph, n = cand[ok], p[ok], ph[ok], n[ok]
        lever = p - r[cand, None] * n - x[cand]
        return _Rows(cand, np.full(len(cand), -1), n, lever, np.zeros_like(n), ph - r[cand],
                     np.ones(len(cand), bool), np.ones(len(cand), bool),
                     _obstacle_key(oi, cand, np.full(len(cand), 2, np.int64), model.n_segments))

    # -- contacts ----------------------------------------------------------------------------------
    def _targets(self, rows, gaps, beta, u, u_pre, model, Iwi, dt, sweep):
        """Lower bounds v_N of J u per row (eqs. 8.67–8.69 plus the gap terms of the module notes)."""
        n = rows.normal
        b = rows.partner
        vn = np.zeros(len(n))
        fib = ~rows.obstacle
        if fib.any():
            bb = b[fib]
            src = u_pre if sweep == 0 else u
            ub = src[bb, :3] + np.cross(src[bb, 3:], rows.partner_lever[fib])
            if sweep == 0:
                aa = rows.body[fib]
                ua = u_pre[aa, :3] + np.cross(u_pre[aa, 3:], rows.lever[fib])
                rna = np.cross(rows.lever[fib], n[fib])
                rnb = np.cross(rows.partner_lever[fib], n[fib])
                ma = 1.0 / (1.0 / model.mass[aa] + np.einsum("ka,kab,kb->k", rna, Iwi[aa], rna))  # eq. 8.68
                mb = 1.0 / (1.0 / model.mass[bb] + np.einsum("ka,kab,kb->k", rnb, Iwi[bb], rnb))
                vn[fib] = ((ma[:, None] * ua + mb[:, None] * ub) / (ma + mb)[:, None] * n[fib]).sum(1)  # eq. 8.67
            else:
                vn[fib] = (ub * n[fib]).sum(1)
        corr = np.where(gaps > 0, -gaps / dt, -beta * gaps / (0.5 * dt))
        return vn + corr

    def _project(self, rows, order, row_off, bodies, u_minus, targets, model, R, lam):
        o = self.options
        mu_c, mu_s = self._mu
        u_out = u_minus.copy()
        sweeps = np.zeros(len(bodies), np.int64)
        nrm = rows.normal[order]
        lev = rows.lever[order]
        tg = np.ascontiguousarray(targets[order])
        lam_sorted = np.zeros(len(order))
        eps = float(o.restitution)
        mode = 0 if o.normal_impulse == "dual" else 1
        lp = o.friction_objective == "lp" and not o.friction.frictionless
        mc = np.zeros(0) if lp else mu_c
        ms = np.zeros(0) if lp else mu_s
        if self.fibre_loop:
            fib = model.segment_fibre[bodies]
            for f in np.unique(fib):
                sel = np.nonzero(fib == f)[0]
                for q in sel:
                    s = bodies[q]
                    a, b = row_off[q], row_off[q + 1]
                    Iwi = K.world_inverse_inertia(R[s], model.inertia[s])
                    uo = np.zeros(6)
                    lo = np.zeros(b - a)
                    sweeps[q] = K.project_body(u_minus[s], model.mass[s], Iwi, nrm[a:b], lev[a:b],
                                               np.ascontiguousarray(R[s, :, 2]), tg[a:b], mc, ms, eps, mode,
                                               o.qp_iterations, o.qp_tolerance, uo, lo)
                    u_out[s] = uo
                    lam_sorted[a:b] = lo
        else:
            kern = K.project_bodies_batch if model.n_segments >= o.parallel_threshold else K.project_bodies_serial
            kern(bodies, row_off, u_minus, model.mass, R, model.inertia, nrm, lev, tg, mc, ms,
                                   eps, mode, o.qp_iterations, o.qp_tolerance, u_out, lam_sorted, sweeps)
        if lp:
            from headsim.solvers.chains_lp import lp_friction

            u_out = lp_friction(bodies, row_off, u_minus, u_out, model, R, nrm, lev, tg, lam_sorted, mu_c, mu_s, o)
        lam[order] = lam_sorted
        return u_out, int(sweeps.max(initial=0))

    def _joint_rows(self, model, rows, x_mid, R_mid, dt, u_minus=None, spring_step=0.5):
        """Bilateral joint rows of every fibre with a contact: bodies k (−1: root anchor), l, levers, and the
        target relative anchor velocity −γ d_mid/(½Δt) (γ = ``joint_gap_fraction``; γ = 1 closes the
        mid-step gap d_mid by the step's end, γ = 0 keeps the anchors moving together)."""
        fib = model.segment_fibre
        touched = KP.touched_fibres(rows.body, rows.partner, fib, model.n_fibres)
        seg = np.nonzero(touched[fib])[0]
        is_root = model.is_root[seg]
        keep = ~is_root | model.anchored[fib[seg]]
        seg, is_root = seg[keep].astype(np.int64), np.ascontiguousarray(is_root[keep])
        n = len(seg)
        k, rk, rl, target = np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
        C, w0 = np.empty((n, 3, 3)), np.empty((n, 3))
        # implicit spring of every joint over the second half step (§8.5.3; the joint stage's L* grows by
        # Δt K_w Δθ_end + Δt c Δω_rel with Δθ_end = ½Δt Δω_rel): C = ½Δt² K_w + Δt c E
        (FK.joint_rows_parallel if model.n_segments >= self.options.parallel_threshold else FK.joint_rows)(
            seg, is_root, np.ascontiguousarray(fib[seg]), np.ascontiguousarray(x_mid), np.ascontiguousarray(R_mid),
            model.half_length, model.root_point, model.root_frame, model.joint_stiffness, model.joint_damping,
            np.zeros((0, 6)) if u_minus is None else np.ascontiguousarray(u_minus),
            -float(self.options.joint_gap_fraction) / (0.5 * dt), spring_step * dt * dt, dt, k, rk, rl, target, C, w0)
        return k, seg, rk, rl, target, C, w0

    def _half_step_projection(self, model, rows, lam, gaps0, x, R, x_mid, R_mid, vJ, wJ, dt):
        """(S, 6) twists of the last pass's first half step (``ChainOptions.half_step_projection``): the joint
        stage's twists u_J = (vJ, wJ) projected, in the kinetic metric plus the implicit joint springs' rows,
        onto {J_α u ≥ −max(g_α^i, 0)/(½Δt)} for the previous pass's rows α that are rows from the start or
        carry an impulse λ_α > 0 (gaps0: their gaps at t_i, m), frictionless, ε = 0, with every joint of the
        touched fibres keeping its relative anchor velocity J_j u = J_j u_J. Row geometry and joint levers
        are those of the previous pass's mid-step state x_mid, R_mid; dt in s."""
        o = self.options
        act = np.nonzero(rows.primary & ((lam > 0) | rows.tight))[0]
        u = np.ascontiguousarray(np.concatenate([vJ, wJ], axis=1))
        if not len(act):
            return u
        body, partner = np.ascontiguousarray(rows.body[act]), np.ascontiguousarray(rows.partner[act])
        normal, lever = np.ascontiguousarray(rows.normal[act]), np.ascontiguousarray(rows.lever[act])
        plever = np.ascontiguousarray(rows.partner_lever[act])
        sub = _Rows(body, partner, normal, lever, plever, rows.gap[act], rows.obstacle[act], rows.primary[act],
                    rows.key[act])
        jk, jl, jrk, jrl, _, jc, jw0 = self._joint_rows(model, sub, x_mid, R_mid, dt, u)
        kk = np.maximum(jk, 0)
        uk = np.where((jk >= 0)[:, None], u[kk, :3] + np.cross(u[kk, 3:], jrk), 0.0)
        jt = np.ascontiguousarray(uk - (u[jl, :3] + np.cross(u[jl, 3:], jrl)))
        chain_off = _chain_offsets(jk, jl)
        n = len(act)
        lam_out, fr_out = np.zeros(n), np.zeros((n, 2))
        par = model.n_segments >= o.parallel_threshold
        target = np.ascontiguousarray(-np.maximum(gaps0[act], 0.0) / (0.5 * dt))
        KC.project_coupled(body, partner, normal, lever, plever, target, u, self._writable(model.mass),
                           np.ascontiguousarray(R), self._writable(model.inertia), np.zeros(0), np.zeros(0), 0.0,
                           int(o.qp_iterations), float(o.qp_tolerance), lam_out, fr_out, jk, jl, jrk, jrl, jt,
                           jc, jw0, chain_off, -1, par, momentum=self._momentum,
                           root_sweeps=int(o.root_sweeps), root_segments=int(o.root_segments))
        return u

    def _contacts(self, rows, gaps, beta, order, row_off, bodies, u_minus, model, R_mid, Iwi, dt, lam, sweeps_box,
                  x_mid=None, warm=None, pass_key=0, joints_last=False, u_spring=None, spring_step=0.5, budget=False,
                  tol_scale=1.0, sweep_cap=None, extend_cap=True):
        """Contact stage for given row gaps (m) and penetration recovery β; returns u (S, 6). Coupled mode:
        ``sweep_cap``: the solve's sweep cap when below ``qp_iterations`` in a system too large for the sweep
        budget (``predictor_sweeps``, ``push_out_sweeps``; None: ``qp_iterations``); ``extend_cap`` False: late
        promotions do not extend that cap (see ``predictor_extension``).
        ``warm`` = (λ, friction) (primary rows) to start from; the solution is left in ``self._impulses``.
        Calls with the same ``rows`` and ``pass_key`` (the harmonisation pass: same mid-step state x_mid,
        R_mid, u⁻) share the joint rows and the kernel set-up (:func:`~headsim.solvers._kernels.chains_coupled.coupled_setup`)."""
        o = self.options
        self._impulses = None
        if not len(bodies):
            return u_minus
        if o.contact_coupling == "coupled":
            u = np.ascontiguousarray(u_minus.copy())
            if self._gathered is None or self._gathered[0] is not rows:  # once per detection
                pr, n_rows = _kernel_rows(rows)
                n = len(pr)
                geo = (np.empty(n, np.int64), np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3)),
                       np.empty((n, 3)))
                gather = KP.gather_rows_parallel if model.n_segments >= o.parallel_threshold else KP.gather_rows
                gather(pr, *(np.ascontiguousarray(a) for a in (rows.body, rows.partner, rows.normal, rows.lever,
                                                                rows.partner_lever)), *geo)
                # the candidates' normal relative velocities at the detection's u⁻ (screened first candidate test)
                # (the lever bounds h + r also set the partial sweeps' slack bands when there is no screened test)
                sr = self._screen_ref
                lever_bound = np.ascontiguousarray(model.half_length + model.radius)
                if sr is not None and sr[0] is rows and n_rows < n:
                    screen = (np.ascontiguousarray(sr[1][pr]), sr[2], lever_bound)
                else:
                    screen = (np.zeros(0), np.zeros((0, 6)), lever_bound)
                self._gathered = (rows, pr, n_rows, geo, screen)
            _, pr, n_rows, geo, screen = self._gathered
            tg, lam_p, fr_p = np.empty(len(pr)), np.empty(len(pr)), np.empty((len(pr), 2))
            wl, wf = (np.zeros(0), np.zeros((0, 2))) if warm is None else warm
            par = model.n_segments >= o.parallel_threshold
            (KP.kernel_row_inputs_parallel if par else KP.kernel_row_inputs)(pr, gaps, float(beta), float(dt), wl, wf,
                                                                             tg, lam_p, fr_p)
            mc, ms = self._mu
            ps = self._pass_setup
            if ps is None or ps[0] is not rows or ps[1] != pass_key:  # once per harmonisation pass
                jk, jl, jrk, jrl, jt, jc, jw0 = self._joint_rows(model, rows, x_mid, R_mid, dt,
                                                                 u_minus if u_spring is None else u_spring,
                                                                 spring_step)
                chain_off = _chain_offsets(jk, jl)
                joints = (jk, jl, jrk, jrl, jt, jc, jw0, chain_off)
                mass, inertia = self._writable(model.mass), self._writable(model.inertia)
                setup = (KC.coupled_setup_parallel if par else KC.coupled_setup)(
                    *geo, mass, R_mid, inertia, jk, jl, jrk, jrl, jc, chain_off, n_rows,
                    np.zeros(0, self._kernel_storage(model, len(pr) + len(jk))))
                # domains of the parallel contact sweep (ChainOptions.contact_domains), from the rows from the start
                body_part = np.zeros(0, np.int64)  # one domain
                if o.contact_domains > 1:
                    sf = model.segment_fibre
                    b0, p0 = geo[0][:n_rows], geo[1][:n_rows]
                    fpart = _fibre_domains(sf[b0], np.where(p0 >= 0, sf[np.maximum(p0, 0)], -1), model.n_fibres,
                                           int(o.contact_domains))
                    body_part = np.ascontiguousarray(fpart[sf])
                ps = self._pass_setup = (rows, pass_key, joints, mass, inertia, setup, body_part)
            _, _, joints, mass, inertia, setup, body_part = ps
            kern = KC.coupled_iterate_parallel if par else KC.coupled_iterate
            cap, tol = int(o.qp_iterations), float(o.contact_tolerance)
            n_budget = self._budget_sweeps(len(pr) + len(joints[0]))
            late = o.late_promotion_overlap * float(model.radius.min()) / dt
            if sweep_cap is not None and n_budget <= cap:  # a system too large for the sweep budget
                cap = min(cap, int(sweep_cap))
                if not extend_cap:  # no late promotion extends this cap
                    late = np.inf
            if budget:  # small systems: run to a tighter stopping rule (see ChainOptions.sweep_budget)
                self._budgeted = n_budget > cap
                if n_budget > cap:
                    cap, tol = n_budget, min(tol, float(o.small_system_tolerance)) * tol_scale
            sw, change, promoted = kern(*setup, *geo, tg, u, mass, R_mid, inertia, mc, ms,
                                        float(o.restitution), cap, tol, lam_p,
                                        fr_p, *joints, n_rows, bool(joints_last), body_part, self._momentum,
                                        *screen, int(o.root_sweeps), int(o.root_segments),
                                        late)
            if change > tol:  # stopped by the sweep cap, not by the stopping rule
                self._qp_capped += 1
            self._qp_residual = max(self._qp_residual, float(change))
            fr = np.empty((len(lam), 2))
            (KP.scatter_kernel_impulses_parallel if par else KP.scatter_kernel_impulses)(pr, lam_p, fr_p, lam, fr)
            sweeps_box[0] = max(sweeps_box[0], int(sw))
            self._promoted = int(promoted)
            self._impulses = (lam.copy(), fr)
            return u
        u = u_minus
        for sweep in range(o.contact_sweeps):
            targets = self._targets(rows, gaps, beta, u, u_minus, model, Iwi, dt, sweep)
            u, sw = self._project(rows, order, row_off, bodies, u_minus, targets, model, R_mid, lam)
            sweeps_box[0] = max(sweeps_box[0], sw)
        return u

    def _budget_sweeps(self, n_rows_and_joints):
        """The sweeps ``ChainOptions.sweep_budget`` grants a coupled solve of this many rows and joints; a system
        is too large for the budget when they are ≤ ``qp_iterations``."""
        return int(self.options.sweep_budget) // max(1, n_rows_and_joints)

    def _kernel_storage(self, model, n_rows_and_joints):
        """Floating-point type of the coupled kernel's row and chain arrays for a system of ``model`` with this
        many rows and joints (``ChainOptions.kernel_precision``)."""
        o = self.options
        if o.kernel_precision == "auto":
            large = (model.n_segments >= o.parallel_threshold
                     and self._budget_sweeps(n_rows_and_joints) <= int(o.qp_iterations))
            return np.float32 if large else np.float64
        return np.float32 if o.kernel_precision == "float32" else np.float64

    def _kept_arrays(self, attr, n, alloc, fresh):
        """``alloc(m)``'s arrays with room for n entries, kept across steps in ``self.<attr>`` (as (arrays, m),
        grown to 1.25 n when too small: fresh arrays for the reference scene's millions of pairs and rows cost
        their page faults every step), or new ones of length n where ``fresh`` (a second detection in the step,
        while the first one's arrays are in use)."""
        if fresh:
            return alloc(n)
        kept = getattr(self, attr)
        if kept is None or kept[1] < n:
            m = int(1.25 * n) + 16
            kept = (alloc(m), m)
            setattr(self, attr, kept)
        return kept[0]

    def _row_buffers(self, n, fresh=False) -> "_Rows":
        """Output arrays of the fused detection pass for n rows (obstacle rows and fibre pairs; ``obstacle``
        False and ``primary`` True, the others unset), kept across steps (:meth:`_kept_arrays`; a new set of
        the reference scene's 1.4–4 M rows cost 40–100 ms of page faults per step). The rows of a step are
        views of these arrays: nothing keeps a step's rows into the next step's detection (the warm start keeps
        copies)."""
        def alloc(m):
            return _Rows(np.empty(m, np.int64), np.empty(m, np.int64), np.empty((m, 3)), np.empty((m, 3)),
                         np.empty((m, 3)), np.empty(m), np.empty(m, bool), np.empty(m, bool), np.empty(m, np.int64),
                         np.empty(m, np.bool_))
        buf = self._kept_arrays("_rows_buf", n, alloc, fresh)
        out = _Rows(*[getattr(buf, f)[:n] for f in _Rows.__dataclass_fields__])
        out.obstacle[:] = False
        out.primary[:] = True
        return out

    def _detection_buffers(self, n, fresh=False):
        """Work arrays of the fused detection pass for n pairs (sorted pairs and parameters, their intermediate
        order, the reserve's positions and slacks), kept across steps (:meth:`_kept_arrays`; ``fresh``: a second
        detection in the step, whose reserve must not overwrite the first one's)."""
        def alloc(m):
            return (np.empty((m, 2), np.int64), np.empty((m, 2)), np.empty((m, 2), np.int64), np.empty((m, 2)),
                    np.empty(m, np.int64), np.empty(m))
        return tuple(b[:n] for b in self._kept_arrays("_det_buffers", n, alloc, fresh))

    def _reserve_half_gap(self) -> bool:
        """Whether a last pass with ``end_velocity_positions`` may let a speculative row close only ½ g^i (then the
        reserve's slacks use the smaller gap G of :func:`~headsim.solvers._kernels.chains_pairs._reserve_gap`)."""
        o = self.options
        return bool(o.end_velocity_positions and o.harmonisation_iterations > 1 and o.springs_in_first_half_step)

    def _pass_gaps(self, rows, gaps0, dq, endvel, model, row_vn):
        """The row gaps (m) of a harmonisation pass: (velocity solve's, push-out solve's, reported). gaps0: the
        rows' gaps at t_i (first order); dq (S, 6): the pass's mid-state change (Δx, Δθ) since the detection
        state (None: the detection's pass)."""
        if dq is None:
            gaps = rows.gap.copy()
        else:
            gaps = np.empty(len(rows.body))
            row_vn(rows.body, rows.partner, rows.normal, rows.lever, rows.partner_lever, dq, gaps)
            gaps += rows.gap
        gaps_pos = gaps_stat = gaps
        if endvel:
            gaps_stat = gaps0
            # end gap g^i + Δt J u' (first order; g^i: the rows' gaps at t_i): a speculative row may close the
            # smaller of ½ g^i and its mid-step gap (so it arrives no faster than g^i/(2Δt) with ½ g^i left, and
            # the next step's mid-step state does not pass through its partner), a penetration is held
            # (velocity solve) and pushed out by its depth at t_i (push-out solve)
            mid, gaps, gaps_pos = gaps, np.empty(len(gaps)), np.empty(len(gaps))
            (KP.end_velocity_gaps_parallel if model.n_segments >= self.options.parallel_threshold
             else KP.end_velocity_gaps)(mid, np.ascontiguousarray(gaps0), rows.body, model.radius,
                                        float(self.options.push_out_slop), gaps, gaps_pos)
        return gaps, gaps_pos, gaps_stat

    def _reserve_violations(self, model, rows, checks, dq0, dq, endvel, dt, row_vn, rounds, chunks=None,
                            append=True):
        """``ChainOptions.candidate_reserve``: the reserve pairs that a solve's twists would close, appended to
        ``rows`` as candidates: (the new _Rows, the appended rows, their gaps at t_i), or None when there are none.
        checks: (u (S, 6), β) of the pass's solves; chunks: the reserve chunks to check (None: all); ``append``
        False: return only the rows taken from the reserve (or None). A reserve pair
        is promoted by the kernel's rule (n·(u_A − u_B) < target, the target of its gap in this pass); it can only
        be where σ ≤ B_A + B_B + margin with B = |Δv| + ρ|Δω| + c P/Δt per body: Δ the twist change since the
        detection's u⁻, ρ = h + r the lever bound, P = |Δx| + ρ|Δθ| of the pass's mid state change since the
        detection (the pass's gaps, in both solves, are at least G − P_A − P_B, G the gap in σ), c = max(1, 2 ×
        penetration_recovery) (a push-out target −β g/(½Δt) of a gap g ≤ 0); those are tested exactly, and where
        one of a chunk's suspects is closed, all of them are appended. After 3 rounds in one step every suspect is
        appended without the test (the absolute band's candidates for that step's remaining solves)."""
        S = model.n_segments
        rho = model.half_length + model.radius
        u_ref = self._screen_ref[2]
        P = np.zeros(S) if dq is None else _point_speed(dq, rho)
        c = max(1.0, 2.0 * self.options.penetration_recovery)
        par = S >= self.options.parallel_threshold
        bounds = []
        for u, _ in checks:
            d = u - u_ref
            bounds.append(_point_speed(d, rho) + c * P / dt)
        taken = []
        for res in (self._reserve if chunks is None else chunks):
            suspects = np.zeros(len(res.idx), bool)
            out = np.empty(len(res.idx), bool)
            for bound in bounds:
                (KP.reserve_suspects_parallel if par else KP.reserve_suspects)(res.idx, res.sigma, res.sp, bound,
                                                                                 res.margin, out)
                suspects |= out
            js = np.nonzero(suspects)[0]
            if not len(js):
                continue
            cand = self._reserve_rows(res, res.idx[js])
            self._keep_normal_sides(cand, model)
            if rounds < 3:
                # the exact test of the suspects: the kernel's promotion rule at each solve's twists; where one
                # closes, every suspect of the chunk becomes a candidate (a candidate only costs the screened test
                # of the full sweeps, a round a whole solve: promoting the closed ones alone took 5 rounds at the
                # landing strand's t = 84 ms, 27.4 s, against 1 round and 12.6 s, 310 k and 308 k pairs moved)
                if not self._closed_by(cand, checks, dq0, dq, endvel, dt, model, row_vn).any():
                    continue
            keep = np.ones(len(res.idx), bool)
            keep[js] = False
            res.idx, res.sigma = res.idx[keep], res.sigma[keep]
            self._reserve_moved += len(js)
            taken.append(cand)
        if not taken:
            return None
        cand = _Rows(*[np.concatenate([getattr(t, f) for t in taken]) for f in _Rows.__dataclass_fields__])
        return self._append_rows(rows, cand, dq0, row_vn) if append else cand

    def _closed_by(self, cand, checks, dq0, dq, endvel, dt, model, row_vn):
        """(n,) bool: the rows ``cand`` that the kernel would promote at some solve's twists of ``checks`` (u, β):
        n·(u_A − u_B) < the target of their gap in this pass (see :meth:`_pass_gaps`)."""
        gv, gp, _ = self._pass_gaps(cand, _gaps_at_start(cand, dq0, row_vn), dq, endvel, model, row_vn)
        hit = np.zeros(len(cand.body), bool)
        vn = np.empty(len(cand.body))
        for (u, beta), g in zip(checks, (gv, gp)):
            target = np.where(g > 0, -g / dt, -beta * g / (0.5 * dt))
            row_vn(cand.body, cand.partner, cand.normal, cand.lever, cand.partner_lever, np.ascontiguousarray(u), vn)
            hit |= vn < target
        return hit

    def _append_rows(self, rows, cand, dq0, row_vn):
        """(rows + cand, cand, cand's gaps at t_i (m)): candidate rows appended within a step, with their reference
        normal velocities for the kernel's screened first candidate test."""
        new = _Rows(*[np.concatenate([getattr(rows, f), getattr(cand, f)]) for f in _Rows.__dataclass_fields__])
        sr = self._screen_ref
        vn = np.empty(len(cand.body))
        row_vn(cand.body, cand.partner, cand.normal, cand.lever, cand.partner_lever, sr[2], vn)
        self._screen_ref = (new, np.concatenate([sr[1], vn]), sr[2])
        return new, cand, _gaps_at_start(cand, dq0, row_vn)

    @staticmethod
    def _reserve_rows(res, sel):
        """_Rows of the reserve pairs at positions sel of the detection's sorted pairs (candidates, not tight)."""
        n = len(sel)
        out = (np.empty(n, np.int64), np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)),
               np.empty(n), np.empty(n, bool), np.empty(n, np.int64))
        KP.reserve_rows(np.ascontiguousarray(sel, np.int64), res.sp, res.spar, *res.args, *out)
        a, b, nrm, la, lb, gap, tight, key = out
        return _Rows(a, b, nrm, la, lb, gap, np.zeros(n, bool), np.ones(n, bool), key, tight)

    def _energy_bound(self, model, u, u_minus, u_start, R_mid):
        """The bound B = u'ᵀ g(u') − ½‖u' − u^i‖²_M (J) of the step's energy change for the last contact solve's
        result u' (S, 6; ``ChainOptions.end_velocity_positions``): g(u') = M(u' − u⁻) + Sᵀ C (S u' − ω₀) is the
        sum of every constraint impulse (contacts, friction, joints, and the spring rows' residual; M at R_mid,
        S: the relative rotation rates of the joints of the touched chains, C, ω₀ their spring rows), u_start
        the twists at t_i (angular part carried to R_mid)."""
        jk, jl, _, _, _, jc, jw0, _ = self._pass_setup[2]

        def mdot(a, b):
            Lw = _apply_scaled(R_mid, model.inertia, b[:, 3:])
            return float((model.mass * (a[:, :3] * b[:, :3]).sum(1)).sum() + (a[:, 3:] * Lw).sum())

        wk = np.where((jk >= 0)[:, None], u[np.maximum(jk, 0), 3:], 0.0)
        wrel = u[jl, 3:] - wk
        spring = np.matmul(jc, (wrel - jw0)[:, :, None])[:, :, 0]
        d = u - u_start
        return mdot(u, u - u_minus) + float((wrel * spring).sum()) - 0.5 * mdot(d, d)

    def _exact_solve(self, model, rows, gaps, dt, u_minus, R_mid):
        """:func:`_exact_final_solve` of the last velocity solve (its impulses, the pass's joint rows)."""
        from headsim.solvers.contact_qp import _blas_controller

        # one BLAS thread for the Schur complement's products and least squares (a 300 × 300 LU took 0.1 s instead
        # of 1 ms with the BLAS threads competing with the Numba ones on 2 loaded cores)
        with _blas_controller().limit(limits=1, user_api="blas"):
            return _exact_final_solve(model, rows, self._impulses[0], self._impulses[1],
                                      np.where(gaps > 0, -gaps / dt, 0.0), u_minus, R_mid, self._pass_setup[2],
                                      self._mu)

    def _warm_start_impulses(self, rows, stored=None):
        """(λ, friction) per row: ``warm_start_fraction`` of the previous step's solution of the same
        contacts (same key; 0 for new contacts and non-primary rows), or None without a previous solution
        (coupled mode only). ``stored``: that solution (:func:`_stored_impulses`; None: the velocity solve's)."""
        stored = self._warm if stored is None else stored
        if stored is None or self.options.contact_coupling != "coupled":
            return None
        keys, lam0, fr0 = stored
        k = rows.key
        if not len(keys) or not len(k):
            return None
        lam, fr = np.empty(len(k)), np.empty((len(k), 2))
        big = len(k) >= self.options.parallel_threshold
        (KP.warm_start_rows_parallel if big else KP.warm_start_rows)(k, rows.primary, keys, lam0,
                                                                     np.ascontiguousarray(fr0),
                                                                     float(self.options.warm_start_fraction), lam, fr)
        return lam, fr

    # -- step ----------------------------------------------------------------------------------------
    def step(self, model: ChainModel, state: ChainState, dt: float, obstacles=()) -> ChainState:
        """Advance by Δt (s); obstacles: sequence of :class:`Obstacle`. Raises DivergenceError on
        non-finite results."""
        if not dt > 0:
            raise ParameterError(f"dt must be > 0 s, got {dt}")
        return self._step(model, state, dt, obstacles, 0)

    def _relative_pair_speed(self, model, x_mid, R_mid, u_minus, dt, dhat):
        """(S,) m/s allowance speed of every segment for the fibre pairs' candidate band
        (``ChainOptions.candidate_band = "relative"``) with the allowance ``dhat`` (S,) m/s, or None where the
        absolute band is narrower."""
        self._rel_base = self._detection_base(model, dt)
        self._rel_grid = LocalMotionBound(x_mid, R_mid[:, :, 2], u_minus[:, :3], u_minus[:, 3:], model.half_length,
                                          model.mass, float(self._band_reach(dt, dhat).max()))
        a = self._relative_speeds(dt, dhat)
        return None if a.sum() >= self._speed.sum() else a

    def _detection_base(self, model, dt):
        """(S,) m: a segment's fibre-pair detection radius without its speed term: its radius, half the row band
        (``contact_band``) and half the speculative margin (``speculative_speed`` Δt); the BVH's radius adds
        0.75 s Δt for the band speed s (see :meth:`_detect`)."""
        o = self.options
        return model.radius * (1.0 + 0.5 * o.contact_band) + 0.5 * (o.speculative_speed * dt)

    def _band_reach(self, dt, dhat):
        """(S,) m: the absolute band's reach of every segment (its detection radius at its own speed, plus 1.5 δ̂ Δt
        for the allowance ``dhat`` (S,) m/s): pairs farther apart cannot close within the step (chain_band module
        docstring)."""
        return self._rel_base + dt * (self._speed + 1.5 * dhat)

    def _relative_speeds(self, dt, dhat):
        """(S,) m/s: a = (A + 1.5 δ̂)/0.75 of the relative band for the allowance ``dhat`` (S,) m/s, A the
        local-motion bound of this step's detection state (:class:`headsim.solvers.chain_band.LocalMotionBound`)
        at the reach of the absolute band (see ``ChainOptions.candidate_band``)."""
        return (self._rel_grid.allowance(self._band_reach(dt, dhat)) + 1.5 * dhat) / 0.75

    def _widened_band(self, model, rows, dhat, checks, x_det, R_det, u_det, dq0, dq, endvel, dt, row_vn):
        """candidate_band="relative": a pass's twists changed some segments by more than the allowance δ̂ the
        band was built with. Detects again, at the detection's state, with the band of the allowance ``dhat``
        (S,) m/s (≥ the changes), keeping only the fibre pairs the first band did not reach. Of those pairs,
        the ones within the row band or without positive slack are appended as rows and candidates; the others
        join the reserve, where the ones the pass's twists close are appended too. Returns
        (rows, appended rows, their gaps at t_i) when rows were appended, else the input ``rows``."""
        old_speed = self._pair_speed
        # kept at least the first band (so that the pairs found before are the ones it excludes)
        a = np.maximum(self._relative_speeds(dt, dhat), old_speed)
        saved = (self._reserve, self._pair_speed, self._allow, self._bvh)
        t0 = time.perf_counter()
        try:
            self._pair_speed, self._allow = a, np.zeros(model.n_segments)
            new = self._detect(model, x_det, R_det, dt, (), u_det, dq0, old_speed=old_speed)
            chunks = self._reserve
        finally:
            self._reserve, _, self._allow, self._bvh = saved
        self._widen_seconds += time.perf_counter() - t0
        self._pair_speed = a
        self._reserve = self._reserve + chunks
        self._band_extensions += 1
        taken = [new] if len(new.body) else []
        if chunks:
            out = self._reserve_violations(model, rows, checks, dq0, dq, endvel, dt, row_vn, 0, chunks=chunks,
                                           append=False)
            if out is not None:
                taken.append(out)
        if not taken:
            return rows
        cand = _Rows(*[np.concatenate([getattr(t, f) for t in taken]) for f in _Rows.__dataclass_fields__])
        return self._append_rows(rows, cand, dq0, row_vn)

    def _step(self, model, state, dt, obstacles, redo, force_absolute=False):
        """One step (:meth:`step`); ``redo``: attempts of this step so far (candidate_band="relative")."""
        model = model.kernel
        o = self.options
        t_all = time.perf_counter()
        secs = {"joints": 0.0, "detection": 0.0, "contacts": 0.0, "integration": 0.0}
        S = model.n_segments
        # per-row passes over the rows and candidates (millions on the reference scene): prange above the threshold
        row_vn = KP.row_normal_velocity_parallel if S >= o.parallel_threshold else KP.row_normal_velocity
        self._qp_capped = 0
        self._qp_residual = 0.0
        self._continued = 0
        self._reserve_moved = 0
        self._band_extensions = 0
        self._widen_seconds = 0.0  # the widened detections' time (reported as detection, not contacts)
        self._bound = None
        half_step = K.half_step if S >= o.parallel_threshold else K.half_step_serial
        x, R, v, w = state.position, state.rotation, state.velocity, state.angular_velocity
        g = np.asarray(o.gravity, float)
        dv_ext = (dt if o.external_impulse == "full" else 0.5 * dt) * g
        dx_extra = np.zeros((S, 3))
        dth_extra = np.zeros((S, 3))
        x_mid = np.empty_like(x)
        R_mid = np.empty_like(R)
        rows = None
        newton = 0
        sweeps_box = [0]
        u_end = None
        promoted = 0
        vel_impulses = None
        u_vel = gaps0 = None  # the first pass's velocity solve and row gaps at t_i, read by the later passes
        joint_factor, unsprung_factor = [], []  # the joint stage's Newton factorisations of this step (x, R fixed)
        for it in range(o.harmonisation_iterations):
            t0 = time.perf_counter()
            vJ, wJ, nit, _ = self._joints(model, x, R, v, w, dt, dx_extra, dth_extra, joint_factor,
                                          "_joint_factor_buf")
            newton = max(newton, nit)
            t1 = time.perf_counter()
            secs["joints"] += t1 - t0
            w_mid = np.empty_like(wJ)
            projected = False
            if not o.springs_in_first_half_step:
                # the first half step moves with the joint stage's twists without the spring (and damping)
                # impulses: they enter u⁻ only, where the contact solve sees them (see the option's notes)
                if self._unsprung is None or self._unsprung[0] is not model:
                    self._unsprung = (model, replace(model, joint_stiffness=0.0 * model.joint_stiffness,
                                                     joint_damping=0.0 * model.joint_damping).kernel)
                vJ0, wJ0, _, _ = self._joints(self._unsprung[1], x, R, v, w, dt, dx_extra, dth_extra, unsprung_factor,
                                              "_unsprung_factor_buf")
                half_step(x, R, vJ0, wJ0, model.inertia, 0.5 * dt, x_mid, R_mid, w_mid)
                w_hs = w_mid
                w_mid = _spin_carried(wJ, R, R_mid, model.inertia)
            elif (it > 0 and o.end_velocity_positions and it + 1 == o.harmonisation_iterations and vel_impulses is not None
                  and o.end_velocity_predictor == "previous"):
                # the touched fibres' predicted mid-step state: the previous pass's contact-solved twists (the step
                # moves them with u' for Δt, so q^i + ½Δt u'_previous is nearer its midpoint than the projection)
                tb = KP.touched_fibres(rows.body, rows.partner, model.segment_fibre, model.n_fibres)[model.segment_fibre]
                uh = np.concatenate([vJ, wJ], axis=1)
                uh[tb] = u_vel[tb]
                w_hs = np.empty_like(wJ)
                projected = True
                half_step(x, R, np.ascontiguousarray(uh[:, :3]), np.ascontiguousarray(uh[:, 3:]), model.inertia,
                          0.5 * dt, x_mid, R_mid, w_hs)
                w_mid = _spin_carried(wJ, R, R_mid, model.inertia)
            elif it > 0 and o.half_step_projection and vel_impulses is not None:
                # no closing velocity into the contacts of the previous pass (see the option's notes)
                uh = self._half_step_projection(model, rows, vel_impulses[0], gaps0, x, R, x_mid, R_mid, vJ, wJ,
                                                dt)
                w_hs = np.empty_like(wJ)
                projected = True
                half_step(x, R, np.ascontiguousarray(uh[:, :3]), np.ascontiguousarray(uh[:, 3:]), model.inertia,
                          0.5 * dt, x_mid, R_mid, w_hs)
                w_mid = _spin_carried(wJ, R, R_mid, model.inertia)
            else:
                half_step(x, R, vJ, wJ, model.inertia, 0.5 * dt, x_mid, R_mid, w_mid)
                w_hs = w_mid
            u_minus = np.concatenate([vJ + dv_ext, w_mid], axis=1)
            # the spring rows' reference twist: u⁻, or, where the first half step rotated with ω_h ≠ ω_J, the one
            # whose rows put the spring impulse at the rotation the step reaches (see _joint_rows)
            endvel = (o.end_velocity_positions and it > 0 and it + 1 == o.harmonisation_iterations
                      and vel_impulses is not None and o.springs_in_first_half_step)
            spring_step = 1.0 if endvel else 0.5
            if endvel:  # the touched fibres move with u' for the whole step: springs at θ^i + Δt ω'
                u_spring = np.concatenate([vJ, w_mid + dth_extra / dt], axis=1)
            else:
                u_spring = u_minus if not projected else np.concatenate(
                    [vJ, 2.0 * w_mid - w_hs + dth_extra / (0.5 * dt)], axis=1)
            t2 = time.perf_counter()
            secs["integration"] += t2 - t1
            if rows is None:
                self._speed = _point_speed(u_minus, model.half_length)
                # the allowance δ̂ (S,) m/s of this step's velocity changes (the previous step's prediction; the
                # segments' own speeds in the first step) for the relative band and the reserve's split
                dhat_used = np.ascontiguousarray(
                    self._dhat if self._dhat is not None and len(self._dhat) == S else self._speed)
                self._pair_speed = None
                if (o.candidate_band == "relative" and o.contact_coupling == "coupled" and S > 1
                        and not force_absolute):
                    self._pair_speed = self._relative_pair_speed(model, x_mid, R_mid, u_minus, dt, dhat_used)
                # candidate_reserve: the allowance of the split into candidates and reserve pairs (see _detect)
                reserve_on = o.candidate_reserve and o.contact_coupling == "coupled" and S > 1
                self._allow = dhat_used if reserve_on else None
                reserve_rounds = 0
                # the solves' velocity changes, measured against this u⁻, for the check against the allowance the
                # relative band was built with and for the next step's δ̂
                track = (o.candidate_band == "relative" or reserve_on) and o.contact_coupling == "coupled"
                u_det = np.array(u_minus) if track else None
                change = np.zeros(S)
                rows = self._detect(model, x_mid, R_mid, dt, obstacles, u_minus,
                                    np.concatenate([x_mid - x, 0.5 * dt * w_hs], axis=1))
                R_det = R_mid.copy() if self._pair_speed is not None else None
                band_rounds = 0
                if o.contact_coupling == "coupled":  # the rows' normal relative velocities at this u⁻: the
                    # coupled kernel screens its first candidate test against them (see _contacts)
                    ref_vn = np.empty(len(rows.body))
                    u_ref = np.ascontiguousarray(u_minus)
                    row_vn(rows.body, rows.partner, rows.normal, rows.lever, rows.partner_lever,
                                           u_ref, ref_vn)
                    self._screen_ref = (rows, ref_vn, u_ref.copy())
                secs["detection"] += time.perf_counter() - t2
                t2 = time.perf_counter()
                Iwi = _inv_inertia_world(model, R_mid) if o.contact_coupling == "per-body" else None
                # (persistence filter, eq. 8.9: in _detect)
                if o.contact_coupling == "coupled":  # one Gauss–Seidel over all rows: no per-body grouping
                    order = row_off = None
                    bodies = rows.body
                else:  # per body: fibre rows first, obstacle rows last (a static obstacle wins a conflict)
                    order = np.lexsort((rows.obstacle, rows.body))
                    bodies, starts = np.unique(rows.body[order], return_index=True)
                    row_off = np.append(starts, len(order)).astype(np.int64)
                    bodies = bodies.astype(np.int64)
                lam = np.zeros(len(rows.body))
            while True:  # candidate_reserve: again with the reserve pairs a solve's twists would close as rows
                if it == 0:
                    x_mid0, w_hs0 = x_mid.copy(), w_hs.copy()
                    # row gaps at t_i (first order): the mid-step gaps less the first half step's approach
                    dq0 = np.ascontiguousarray(np.concatenate([x_mid - x, 0.5 * dt * w_hs], axis=1))
                    dq = None
                    gaps0 = _gaps_at_start(rows, dq0, row_vn)
                    warm = self._warm_start_impulses(rows) if o.warm_start else None
                    if warm is not None:  # a contact that carried an impulse last step is a row from the start
                        rows.tight |= warm[0] > 0
                else:  # contact points move with the bodies: first-order gap change of the new mid state
                    dq = np.ascontiguousarray(np.concatenate([x_mid - x_mid0, 0.5 * dt * (w_hs - w_hs0)], axis=1))
                gaps, gaps_pos, gaps_stat = self._pass_gaps(rows, gaps0, dq, endvel, model, row_vn)
                # a model small enough for the exact final solve tries it after the capped Gauss–Seidel first and
                # runs the sweep budget only when it fails (ChainOptions.exact_final_solve)
                exact_first = endvel and o.exact_final_solve and 6 * model.n_segments <= EXACT_MAX_DOF
                capped, residual = self._qp_capped, self._qp_residual  # restored if the exact solve replaces this one
                u_vel = self._contacts(rows, gaps, 0.0, order, row_off, bodies, u_minus, model, R_mid, Iwi, dt, lam,
                                       sweeps_box, x_mid, warm, pass_key=it, u_spring=u_spring,
                                       spring_step=spring_step, joints_last=endvel, budget=endvel and not exact_first,
                                       sweep_cap=o.predictor_sweeps if it + 1 < o.harmonisation_iterations else None,
                                       extend_cap=o.predictor_extension)
                pass_promoted = self._promoted
                if endvel:
                    # the step's energy bound (ChainOptions.end_velocity_positions); a small system whose solve met
                    # its stopping rule with a positive bound is solved on, from its own impulses, to a 10× tighter
                    # rule
                    if o.exact_final_solve and self._impulses is not None:
                        exact = self._exact_solve(model, rows, gaps, dt, u_minus, R_mid)
                        if exact is None and exact_first:
                            u_vel = self._contacts(rows, gaps, 0.0, order, row_off, bodies, u_minus, model, R_mid,
                                                   Iwi, dt, lam, sweeps_box, x_mid, self._impulses, pass_key=it,
                                                   u_spring=u_spring, spring_step=spring_step, joints_last=endvel,
                                                   budget=True)
                            pass_promoted += self._promoted
                            exact = self._exact_solve(model, rows, gaps, dt, u_minus, R_mid)
                        if exact is not None:  # the Gauss–Seidel answers it replaces are not the step's solves
                            self._qp_capped, self._qp_residual = capped, residual
                            u_vel, lam[:] = exact[0], exact[1]
                            self._impulses = (exact[1].copy(), exact[2])
                            self._continued += 1
                    u_start = np.concatenate([v, _spin_carried(w, R, R_mid, model.inertia)], axis=1)
                    self._bound = self._energy_bound(model, u_vel, u_minus, u_start, R_mid)
                vel_impulses = self._impulses
                u_pos = u_vel
                last = it + 1 == o.harmonisation_iterations
                beta_pos = o.penetration_recovery * (0.5 if endvel else 1.0)
                push_impulses = None
                if last and o.penetration_recovery > 0 and (gaps_pos < 0).any():
                    # split impulse: the penetration push-out moves the positions but is not kept as velocity
                    # (only the last pass's is used: an earlier pass feeds the joints u_vel alone)
                    # its own previous impulses (kept only under push_out_warm_start), else the velocity solve's
                    warm_pos = warm if self._warm_push is None else self._warm_start_impulses(rows, self._warm_push)
                    u_pos = self._contacts(rows, gaps_pos, beta_pos, order, row_off, bodies, u_minus, model, R_mid,
                                           Iwi, dt, np.zeros_like(lam), sweeps_box, x_mid, warm_pos, pass_key=it,
                                           joints_last=o.split_recovery and o.recovery_keeps_joints,
                                           u_spring=u_spring, spring_step=spring_step, budget=endvel,
                                           sweep_cap=o.push_out_sweeps)
                    push_impulses = self._impulses
                    pass_promoted += self._promoted
                checks = [(u_vel, 0.0)] + ([(u_pos, beta_pos)] if u_pos is not u_vel else [])
                if track:  # this pass's velocity changes (against the detection's u⁻)
                    pass_change = _speed_change(u_vel, u_det, model.half_length)
                    if u_pos is not u_vel:
                        pass_change = np.maximum(pass_change, _speed_change(u_pos, u_det, model.half_length))
                extended = None
                if self._reserve:
                    extended = self._reserve_violations(model, rows, checks, dq0, dq, endvel, dt,
                                                        row_vn, rounds=reserve_rounds)
                if extended is None and self._pair_speed is not None and band_rounds < 3:
                    # candidate_band="relative": a twist change beyond the allowance δ̂ of the band: the pairs of
                    # the band widened to the changes, at once (instead of redoing the step with the absolute band)
                    # the changes of this pass's solves and of the earlier passes' (one of which may have handed
                    # reserve pairs on without this check)
                    pc = np.maximum(change, pass_change)
                    over = pc > dhat_used
                    if over.any():
                        band_rounds += 1
                        dhat_new = np.where(over, 1.25 * pc, dhat_used)
                        wid = self._widened_band(model, rows, dhat_new, checks, x_mid0, R_det, u_det, dq0, dq,
                                                 endvel, dt, row_vn)
                        dhat_used = dhat_new
                        if wid is not rows:
                            extended = wid
                if extended is not None:
                    rows, added, added_g0 = extended
                    bodies = rows.body
                    lam = np.zeros(len(rows.body))
                    gaps0 = np.concatenate([gaps0, added_g0])
                    nz = len(added.body)
                    if warm is not None:
                        warm = (np.concatenate([warm[0], np.zeros(nz)]), np.concatenate([warm[1], np.zeros((nz, 2))]))
                    if last:  # the pass whose twists the step keeps: solved again with the new candidates
                        reserve_rounds += 1
                        continue
                    # an earlier pass only predicts the mid state of the next one: its new candidates join the
                    # next pass's solves (whose check guards the result) without solving this one again
                    if vel_impulses is not None:
                        vel_impulses = (np.concatenate([vel_impulses[0], np.zeros(nz)]),
                                        np.concatenate([vel_impulses[1], np.zeros((nz, 2))]))
                break
            promoted += pass_promoted
            if track:
                change = np.maximum(change, pass_change)
            u_end = u_vel if o.split_recovery else u_pos
            secs["contacts"] += time.perf_counter() - t2
            if it + 1 < o.harmonisation_iterations:
                dc = u_vel - np.concatenate([vJ + dt * g, w_mid], axis=1)
                dx_extra = 0.5 * dt * dc[:, :3]
                dth_extra = 0.5 * dt * dc[:, 3:]
        self._pass_setup = None  # the kernel set-up is per pass (hundreds of MB on the reference scene)
        band_mode = "absolute" if self._pair_speed is None else "relative"
        if rows is not None and track:
            if self._pair_speed is not None and (change > dhat_used).any():
                # a velocity change beyond its allowance: a pair outside the candidate band may close in this step
                self._dhat = np.maximum(dhat_used, 1.25 * change)
                return self._step(model, state, dt, obstacles, redo + 1, force_absolute=True)
            # the next step's allowance: 1.5 × this step's change, at least one step of gravity, and a segment
            # with an obstacle row may be stopped by it: by its speed at the end of this step (its speed at this
            # step's u⁻ before issue 10's thirteenth session, which kept the allowance of segments the obstacle had
            # just stopped at their former speed: on the landing strand, t = 85–90 ms, 10–15 % more candidates)
            self._dhat = np.maximum(1.5 * change, float(np.linalg.norm(o.gravity)) * dt)
            ob = rows.body[rows.obstacle]
            self._dhat[ob] = np.maximum(self._dhat[ob], _point_speed(u_end[ob], model.half_length[ob]))
        sweeps_max = sweeps_box[0]
        self._normals = None
        if rows is not None and o.persistent_normals and o.contact_coupling == "coupled":
            pen = _penetrating_fibre_rows(rows)
            pen = pen[np.argsort(rows.key[pen])]
            self._normals = (rows.key[pen], rows.normal[pen])
        self._warm = _stored_impulses(rows, vel_impulses) if o.warm_start else None
        # the push-out's own warm start (ChainOptions.push_out_warm_start)
        self._warm_push = _stored_impulses(rows, push_impulses) if o.warm_start and o.push_out_warm_start else None
        t3 = time.perf_counter()
        x_new = np.empty_like(x)
        R_new = np.empty_like(R)
        w_pos = np.empty((S, 3))
        half_step(x_mid, R_mid, np.ascontiguousarray(u_pos[:, :3]), np.ascontiguousarray(u_pos[:, 3:]), model.inertia,
                  0.5 * dt, x_new, R_new, w_pos)
        if endvel and len(rows.body):
            # the touched fibres: q^{i+1} = q^i + Δt u' (both half steps with the velocity solve's twists)
            fib = model.segment_fibre
            touched = KP.touched_fibres(rows.body, rows.partner, fib, model.n_fibres)
            tb = np.nonzero(touched[fib])[0]
            up = np.ascontiguousarray(u_pos[tb])
            xa, Ra, wa = np.empty((len(tb), 3)), np.empty((len(tb), 3, 3)), np.empty((len(tb), 3))
            half_step(np.ascontiguousarray(x[tb]), np.ascontiguousarray(R[tb]), np.ascontiguousarray(up[:, :3]),
                      np.ascontiguousarray(up[:, 3:]), np.ascontiguousarray(model.inertia[tb]), 0.5 * dt, xa, Ra, wa)
            xb, Rb, wb = np.empty_like(xa), np.empty_like(Ra), np.empty_like(wa)
            half_step(xa, Ra, np.ascontiguousarray(up[:, :3]), wa, np.ascontiguousarray(model.inertia[tb]), 0.5 * dt,
                      xb, Rb, wb)
            x_new[tb], R_new[tb] = xb, Rb
            w_pos[tb] = _spin_carried(np.ascontiguousarray(u_pos[tb, 3:]), R_mid[tb], Rb, model.inertia[tb])
        v_new = np.ascontiguousarray(u_end[:, :3])
        if u_pos is u_end:
            w_new = w_pos
        else:  # ω of the kept velocity, mapped to the new frame by the same angular-momentum rule
            w_new = _apply_scaled(R_new, 1.0 / model.inertia, _apply_scaled(R_mid, model.inertia, u_end[:, 3:]))
        secs["integration"] += time.perf_counter() - t3
        if not (np.isfinite(x_new).all() and np.isfinite(v_new).all() and np.isfinite(w_new).all()):
            raise DivergenceError(f"non-finite chain state at t = {state.time + dt:.4g} s (dt = {dt:g} s); "
                                  "reduce dt")
        new = ChainState(x_new, R_new, v_new, w_new, state.time + dt)
        st = StepStats(time=new.time, seconds=secs, newton_iterations=newton, qp_sweeps=sweeps_max,
                       qp_capped=self._qp_capped, qp_residual=self._qp_residual,
                       harmonisation_iterations=o.harmonisation_iterations,
                       energy_bound=float("nan") if self._bound is None else self._bound, exact_solves=self._continued)
        kin, spring, gap = chain_energies(model, new)
        st.kinetic_energy = float(kin.sum())
        st.potential_energy = potential_energy(model, new, g)
        st.spring_energy = float(spring.sum())
        st.max_joint_gap = float(gap.max(initial=0.0))
        active = (lam > 0) & (rows.primary | (o.contact_coupling == "per-body")) if len(lam) else np.zeros(0, bool)
        st.contacts = int(active.sum())
        st.candidate_band = band_mode if o.contact_coupling == "coupled" else ""
        st.candidate_redos = redo
        st.band_extensions = self._band_extensions
        if rows is not None and reserve_on:
            st.reserve_pairs = int(sum(len(c.idx) for c in self._reserve) + self._reserve_moved)
            st.reserve_promoted = self._reserve_moved
            st.reserve_resolves = reserve_rounds
        if o.contact_coupling == "coupled" and len(lam):
            st.candidate_rows = int((rows.primary & ~rows.tight).sum())
            st.contact_rows = int((rows.primary & rows.tight).sum()) + self._promoted
            st.promoted_rows = promoted
        st.obstacle_contacts = int((active & rows.obstacle).sum())
        if o.persistent_normals and o.contact_coupling == "coupled":  # a reversed row's gap is below −(r_a + r_b)
            fr = rows.partner >= 0
            st.reversed_normals = int((rows.gap[fr] < -(model.radius[rows.body[fr]]
                                                        + model.radius[rows.partner[fr]])).sum())
        st.fibre_contacts = st.contacts - st.obstacle_contacts
        # the mid-step state the step integrates from: the last pass's (first order from the detection state)
        st.max_penetration = float(max(0.0, -gaps_stat.min(initial=0.0)))
        if obstacles:
            d3 = R_new[:, :, 2]
            ends = np.concatenate([x_new - model.half_length[:, None] * d3, x_new + model.half_length[:, None] * d3])
            rr = np.concatenate([model.radius, model.radius])
            ts = np.linspace(-1.0, 1.0, 9)[1:-1]
            for ob in obstacles:
                st.max_penetration = max(st.max_penetration,
                                         float(np.max(rr - (ob.field.distance(ends) - ob.level), initial=0.0)))
                # interior of the segments too (7 samples on the axis of segments near the obstacle)
                near = np.nonzero(ob.field.distance(x_new) - ob.level < model.half_length + model.radius)[0]
                if len(near):
                    pts = x_new[near, None, :] + (ts[None, :, None] * model.half_length[near, None, None]) * d3[near, None, :]
                    phi = (ob.field.distance(pts.reshape(-1, 3)) - ob.level).reshape(len(near), len(ts))
                    st.max_penetration = max(st.max_penetration,
                                             float(np.max(model.radius[near, None] - phi, initial=0.0)))
        secs["detection"] += self._widen_seconds
        secs["contacts"] -= self._widen_seconds
        secs["total"] = time.perf_counter() - t_all
        self.last_stats = st
        return new
