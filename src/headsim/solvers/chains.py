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
   is dropped as in the thesis. That is ``ChainOptions.joint_levers="start"``; the **default** ``"mean"``
   applies each impulse at the lever averaged over its body's rotation of the step, J_l(Δt ω') r, and solves
   each fibre's twists and impulses together to the root (Newton,
   :mod:`headsim.solvers._kernels.chains_mean`): the impulses then do no work on the end velocities, where the
   start levers made the plain step gain energy on fibres turning ≈ 1 rad per step.
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
5. Checks (ours): a step that raised the total energy, or after which a segment turns by more than
   ``max_rotation_per_step`` per step, is taken again as two half steps (``step_halvings``), and the end
   state is post-stabilised, its deeper overlaps moved apart in position only (``post_stabilisation``,
   Cline & Pai 2003).

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

Modules: the friction law, model, state and energies are :mod:`headsim.solvers.chains_model`, the options and
step statistics :mod:`headsim.solvers.chains_options`, the exact final solve :mod:`headsim.solvers.chains_exact`,
the Numba kernels :mod:`headsim.solvers._kernels`; every public name of the first two is importable from here.

Limitations: the gyroscopic term −ω × (Iω) is neglected and the world inertia is frozen over a step;
contacts are points (no spin friction); per-body projection has no global consistency (see the
stack test for the sag it leaves).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from headsim.errors import DivergenceError, ParameterError
from headsim.solvers._kernels import chains as K
from headsim.solvers._kernels import chains_coupled as KC
from headsim.solvers._kernels import chains_frames as FK
from headsim.solvers._kernels import chains_mean as KM
from headsim.solvers._kernels import chains_pairs as KP
from headsim.solvers.chain_band import LocalMotionBound
from headsim.solvers.chains_exact import EXACT_MAX_DOF, _exact_final_solve, _penetrating_fibre_rows
from headsim.solvers.chains_model import (
    FRAME_PASS_PARALLEL,
    ChainModel,
    ChainState,
    FrictionLaw,
    Obstacle,
    _apply_scaled,
    _f64,
    _inv_inertia_world,
    chain_energies,
    chain_model_from_polylines,
    chain_state_from_polylines,
    joint_gaps,
    kinetic_energy,
    polylines_from_state,
    potential_energy,
    select_fibres,
    spring_energy,
)
from headsim.solvers.chains_options import ChainOptions, StepStats

MEAN_LEVER_ITERATIONS = 40  # Newton iterations of a fibre's joint solve with joint_levers="mean"

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
    "select_fibres",
]

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


def _trusted_correction(model, base, corrected, R, dt, asked):
    """The position correction ``corrected`` − ``base`` (twists (S, 6), applied over ``dt`` s) with every fibre's
    part scaled down where it moves a point of that fibre (|Δv| + h|Δω⊥|)Δt, Δω⊥ the part of Δω across the
    segment's axis (spin about it moves no point of the capsule) by more than :data:`CORRECTION_TRUST` × ``asked``
    (m, the largest correction the solve's targets ask for). A split push-out or post-stabilisation whose constraints
    cannot all hold (a fibre pinched between obstacles and neighbours, with its joints' gaps to close) has no
    bounded solution: its Gauss–Seidel impulses grow with every sweep, and unscaled its answer moved points by
    millimetres to centimetres for corrections of microns (measured on the frictionless helical strand 7 × 30,
    t = 0.365–0.37 s: 10 % of the push-outs moved a point by more than 180 × the largest correction asked for,
    up to 3,400 ×; the reference scene at rest ≤ 2.2 ×). Returns ``corrected`` itself where no fibre is over the
    bound."""
    d = np.ascontiguousarray(corrected - base)
    e = R[:, :, 2]
    dw = d[:, 3:] - np.einsum("ij,ij->i", d[:, 3:], e)[:, None] * e
    move = (np.sqrt(np.einsum("ij,ij->i", d[:, :3], d[:, :3])) + model.half_length
            * np.sqrt(np.einsum("ij,ij->i", dw, dw))) * dt
    worst = np.zeros(model.n_fibres)
    np.maximum.at(worst, model.segment_fibre, move)
    bound = CORRECTION_TRUST * asked
    over = worst > bound
    if not over.any():
        return corrected
    scale = np.where(over, bound / np.where(over, worst, 1.0), 1.0)[model.segment_fibre]
    return base + scale[:, None] * d


# the StepStats fields _record_energies writes
ENERGY_FIELDS = ("kinetic_energy", "potential_energy", "spring_energy", "max_joint_gap")


def _record_energies(st: StepStats, model: ChainModel, state: ChainState, gravity) -> StepStats:
    """Write the kinetic, gravity and spring energies (J) and the largest joint gap (m) of ``state`` into ``st``
    (:data:`ENERGY_FIELDS`); returns it."""
    kin, spring, gap = chain_energies(model, state)
    st.kinetic_energy = float(kin.sum())
    st.potential_energy = potential_energy(model, state, np.asarray(gravity, float))
    st.spring_energy = float(spring.sum())
    st.max_joint_gap = float(gap.max(initial=0.0))
    return st


def _merged_stats(first: StepStats, second: StepStats) -> StepStats:
    """The statistics of a step taken as two halves (``ChainOptions.step_halvings``): the second half's state
    values, the larger of the extremes, the sums of the counts and phase times."""
    out = replace(second)
    out.seconds = {k: first.seconds.get(k, 0.0) + second.seconds.get(k, 0.0)
                   for k in set(first.seconds) | set(second.seconds)}
    for name in ("newton_iterations", "qp_sweeps", "qp_residual", "max_penetration"):
        setattr(out, name, max(getattr(first, name), getattr(second, name)))
    for name in ("qp_capped", "exact_solves", "candidate_redos", "band_extensions", "reserve_resolves",
                 "promoted_rows", "substeps", "joint_root_failures"):
        setattr(out, name, getattr(first, name) + getattr(second, name))
    out.energy_bound = first.energy_bound + second.energy_bound
    return out


def _obstacle_row_geometry(ob: Obstacle, c: np.ndarray, r: np.ndarray, centre: np.ndarray):
    """(unit normal (n, 3), lever (n, 3) m, gap (n,) m) of obstacle rows whose axis points c (n, 3) m, of segments
    of radius r (n,) m centred at ``centre`` (n, 3), lie against ``ob``: the field's normal at c, the contact point
    c − r n less the centre, and φ(c) − level − r."""
    normal = ob.field.normal(c)
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    return normal, c - r[:, None] * normal - centre, ob.field.distance(c) - ob.level - r


def _no_rows():
    """An empty row set (body, partner, normal, lever, partner lever, gap), as the end-state row helpers return."""
    return (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)),
            np.zeros(0))


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


# ChainOptions.step_halvings: a step whose total energy rises by more than this fraction of the kinetic and spring
# energies is halved (round-off of the energy sums is ≈ 1e-15 of them)
ENERGY_ROUNDOFF = 1e-9
# ChainOptions.post_stabilisation: the overlap (fraction of the radius) a correction leaves; it runs where a pair
# overlaps by twice that
POST_SLOP_FRACTION = 0.1
# a (sub)step whose fibres spread over, or in which a segment's point would move, this many times the fibres' total
# length is a diverged state (raised as such before the candidate band's grid is sized from it)
DIVERGED_REACH = 1000.0
# a position correction (the split push-out, the post-stabilisation) moves no point of a fibre by more than this
# many times the largest correction its targets ask for (row depth, joint gap); a larger one is scaled down to it
# (_trusted_correction)
CORRECTION_TRUST = 10.0
# ChainOptions.restore_crossings: a pair's crossing sign counts where both closest points are farther than this
# fraction of the segment's length from its ends and the axes cross at sin > CROSSING_MIN_SIN (3°)
CROSSING_END_FRACTION = 0.05
CROSSING_MIN_SIN = 0.05
# ... and the post-stabilisation is repeated (at most this many rounds in all) after a round that turned pairs back:
# a correction that moves a pair by its whole overlap may carry one of its neighbours through a third fibre
POST_ROUNDS = 3


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
        self._mean_lever_failures = 0  # joint_levers="mean": this step's fibre joint solves that did not converge
        self._mean_factors = {}  # joint_levers="mean": Newton's Jacobian factors per joint stage (_mean_lever_factors)
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
        self._post_input = None  # post_stabilisation: (rows, mid-step rotations) of the last step
        self._last_energy = None  # (the state step() returned last, the statistics holding its energies)

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
        None: fresh arrays. With ``joint_levers="mean"`` ``factor`` is not used and ``store`` names the mean-lever
        Newton's kept factors (:meth:`_mean_lever_factors`); the start levers' kernel runs only for the fibres whose
        Newton fails."""
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
        if o.joint_levers == "mean":
            # the mean levers' Newton (chord steps on the factors of an earlier call, kept across calls and steps);
            # the start levers' answer for the fibres where it does not converge
            v_out[:] = v
            w_out[:] = w
            ok = np.zeros(F, np.bool_)
            inv, G, Up, kept = self._mean_lever_factors(model, store)
            # args[:-1]: the joint tolerance kept, the start levers' iteration cap replaced
            margs = args[:-1] + (MEAN_LEVER_ITERATIONS, v_out, w_out, its, ok, inv, G, Up, kept)
            large = model.n_segments >= o.parallel_threshold and not self.fibre_loop
            if self.fibre_loop:
                for f in range(F):
                    KM.solve_mean_levers_serial(np.array([f], np.int64), *margs)
            else:
                (KM.solve_mean_levers_batch if large else KM.solve_mean_levers_serial)(np.arange(F, dtype=np.int64),
                                                                                        *margs)
            failed = np.flatnonzero(~ok)
            self._mean_lever_failures += failed.size
            if failed.size:
                fac = tuple(np.empty((model.n_segments, 6, 6)) for _ in range(3)) + (False,)
                (K.correct_joints_batch if large else K.correct_joints_serial)(failed.astype(np.int64), *args, v_out,
                                                                               w_out, *fac, its, gaps)
            return v_out, w_out, int(its.max(initial=0)), float(gaps.max(initial=0.0))
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

    def _mean_lever_factors(self, model, store):
        """(inv, G, Up (S, 12, 12), kept (F,) bool): the mean-lever Newton's Jacobian factors of ``model``'s fibres,
        kept across calls and steps under the name ``store`` (one set per joint stage: with and without springs);
        new ones (none kept) for another model."""
        kept = self._mean_factors.get(store)
        if kept is None or kept[0] is not model:
            S, F = model.n_segments, model.n_fibres
            kept = (model, *(np.zeros((S, KM.BLOCK, KM.BLOCK)) for _ in range(3)), np.zeros(F, np.bool_))
            self._mean_factors[store] = kept
        return kept[1:]

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
            # separating pairs within this step's allowance δ̂ of velocity changes (candidate_reserve) stay candidates:
            # the solve may turn them round (ChainOptions.separating_allowance)
            sep_allow = (np.ascontiguousarray(self._allow, np.float64)
                         if o.separating_allowance and self._allow is not None else np.zeros(0))
            # pairs that passed through each other in the first half step: the t_i side (ChainOptions.pass_through_normals)
            dq_half = (np.ascontiguousarray(dq0, np.float64) if (dq0 is not None and o.pass_through_normals)
                       else np.zeros((0, 6)))
            band_args = (np.ascontiguousarray(spd, np.float64), float(o.contact_band), float(margin), float(dt), uu,
                         CLOSING_MARGIN_FACTOR, self._pair_mark(), smooth, sep_allow, dq_half)
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
                                                  + (uu.copy(),) + rest[5:10],
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

    def _joint_rows(self, model, rows, x_mid, R_mid, dt, u_minus=None, spring_step=0.5, target_scale=None):
        """Bilateral joint rows of every fibre with a contact: bodies k (−1: root anchor), l, levers, and the
        target relative anchor velocity −γ d_mid/(½Δt) (γ = ``joint_gap_fraction``; γ = 1 closes the
        mid-step gap d_mid by the step's end, γ = 0 keeps the anchors moving together); ``target_scale`` (1/s):
        target_scale × d instead (d the gap of the given state x_mid, R_mid)."""
        fib = model.segment_fibre
        touched = KP.touched_fibres(rows.body, rows.partner, fib, model.n_fibres)
        seg = np.nonzero(touched[fib])[0]
        is_root = model.is_root[seg]
        keep = ~is_root | model.anchored[fib[seg]]
        seg, is_root = seg[keep].astype(np.int64), np.ascontiguousarray(is_root[keep])
        if target_scale is None:
            target_scale = -float(self.options.joint_gap_fraction) / (0.5 * dt)
        n = len(seg)
        k, rk, rl, target = np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
        C, w0 = np.empty((n, 3, 3)), np.empty((n, 3))
        # implicit spring of every joint over the second half step (§8.5.3; the joint stage's L* grows by
        # Δt K_w Δθ_end + Δt c Δω_rel with Δθ_end = ½Δt Δω_rel): C = ½Δt² K_w + Δt c E
        (FK.joint_rows_parallel if model.n_segments >= self.options.parallel_threshold else FK.joint_rows)(
            seg, is_root, np.ascontiguousarray(fib[seg]), np.ascontiguousarray(x_mid), np.ascontiguousarray(R_mid),
            model.half_length, model.root_point, model.root_frame, model.joint_stiffness, model.joint_damping,
            np.zeros((0, 6)) if u_minus is None else np.ascontiguousarray(u_minus),
            float(target_scale), spring_step * dt * dt, dt, k, rk, rl, target, C, w0)
        return k, seg, rk, rl, target, C, w0

    def _joint_gap_push(self, model, rows, x, R, dt):
        """(n, 3) m/s or None: joint targets of the split push-out that close the t_i joint gaps d^i of the
        touched fibres (``ChainOptions.close_joint_gaps``) within the step, −d^i/Δt where ‖d^i‖ exceeds
        ``push_out_slop`` × the radius, 0 elsewhere (rows in :meth:`_joint_rows` order); None when no gap does.
        Under ``end_velocity_positions`` those fibres move q^{i+1} = q^i + Δt u, and the velocity solve's joint
        rows (J u' = 0) keep their gaps as they were, so without this a gap that opened in one step stayed."""
        _, seg, _, _, target, _, _ = self._joint_rows(model, rows, x, R, dt, target_scale=-1.0 / dt)
        if not len(seg):
            return None
        slop = float(self.options.push_out_slop) * model.radius[seg] / dt  # as a closing speed
        small = np.sqrt((target * target).sum(1)) <= slop
        if small.all():
            return None
        target[small] = 0.0
        return target

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

    def _end_fibre_rows(self, model, rows, x, R):
        """The step's fibre rows (primary) at the state x, R: (body, partner, normal, lever, partner lever, gap) of
        the closest points of the axes (:func:`~headsim.solvers._kernels.chains_pairs.end_state_pairs`)."""
        sel = np.nonzero(rows.primary & (rows.partner >= 0))[0]
        body, partner = np.ascontiguousarray(rows.body[sel]), np.ascontiguousarray(rows.partner[sel])
        return (body, partner) + self._pair_geometry(model, body, partner, x, R)

    def _pair_geometry(self, model, body, partner, x, R):
        """(normal, lever, partner lever, gap) of the fibre pairs body, partner at the state x, R
        (:func:`~headsim.solvers._kernels.chains_pairs.end_state_pairs`)."""
        n = len(body)
        normal, lever, plever, gap = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
        if n:
            (KP.end_state_pairs_parallel if model.n_segments >= self.options.parallel_threshold
             else KP.end_state_pairs)(body, partner, np.ascontiguousarray(x), np.ascontiguousarray(R[:, :, 2]),
                                      model.half_length, model.radius, normal, lever, plever, gap)
        return normal, lever, plever, gap

    def _crossing_flips(self, model, start, body, partner, x_end, d3):
        """Indices of the fibre pairs (segments body, partner) that passed through each other between the state
        ``start`` and the end state x_end, d3 (S, 3): the sign of (e_a × e_b)·(c_a − c_b) (axes e, closest axis
        points c; :func:`~headsim.solvers._kernels.chains_pairs.crossing_sides`) changed while both closest points
        lie inside both segments (not within :data:`CROSSING_END_FRACTION` of an end), the axes cross at sin >
        :data:`CROSSING_MIN_SIN` and their cross product keeps its direction (within 60°); with the start sides
        and the end unit cross products of all pairs: (k, side at start (n,), e_a × e_b / ‖·‖ at the end (n, 3))."""
        sides = (KP.crossing_sides_parallel if model.n_segments >= self.options.parallel_threshold
                 else KP.crossing_sides)
        n = len(body)
        cn0, sg0, cn1, sg1 = np.empty((n, 3)), np.empty(n), np.empty((n, 3)), np.empty(n)
        sides(body, partner, np.ascontiguousarray(start.position), np.ascontiguousarray(start.rotation[:, :, 2]),
              model.half_length, CROSSING_END_FRACTION, CROSSING_MIN_SIN, cn0, sg0)
        sides(body, partner, np.ascontiguousarray(x_end), np.ascontiguousarray(d3), model.half_length,
              CROSSING_END_FRACTION, CROSSING_MIN_SIN, cn1, sg1)
        k = np.nonzero(sg0 * sg1 < 0)[0]
        return k[np.einsum("ij,ij->i", cn0[k], cn1[k]) > 0.5], sg0, cn1

    def _restore_crossings(self, model, start, body, partner, normal, lever, plever, gap, x_end, d3):
        """Fibre pairs that passed through each other during the step (``ChainOptions.restore_crossings``;
        :meth:`_crossing_flips` between ``start`` and the end state x_end, d3). Such a pair reads at the end as
        separating on the far side; its row (normal, levers, gap, modified in place) is turned back to the start
        side: normal ±(e_a × e_b)/‖·‖, gap −(distance + r_a + r_b), levers to the same axis points. Returns the
        number of pairs turned."""
        if not len(body):
            return 0
        k, sg0, cn1 = self._crossing_flips(model, start, body, partner, x_end, d3)
        self._turn_back(model, k, sg0[k], cn1[k], body, partner, normal, lever, plever, gap, d3)
        return len(k)

    @staticmethod
    def _turn_back(model, k, side0, cross1, body, partner, normal, lever, plever, gap, d3):
        """Turn the rows k (of body, partner, normal, lever, plever, gap; modified in place) of pairs that passed
        through each other back to their start side ``side0`` (k,): normal side0 × ``cross1`` (k, 3) (the unit
        e_a × e_b at the end state, axes d3), gap −(distance + r_a + r_b), levers to the same axis points."""
        if len(k):
            a, b = body[k], partner[k]
            ra, rb = model.radius[a], model.radius[b]
            ta = np.einsum("ij,ij->i", lever[k] + ra[:, None] * normal[k], d3[a])
            tb = np.einsum("ij,ij->i", plever[k] - rb[:, None] * normal[k], d3[b])
            sep = (gap[k] + ra + rb)[:, None] * normal[k]  # c_a − c_b at the end
            nk = side0[:, None] * cross1
            normal[k] = nk
            gap[k] = np.einsum("ij,ij->i", nk, sep) - ra - rb
            lever[k] = ta[:, None] * d3[a] - ra[:, None] * nk
            plever[k] = tb[:, None] * d3[b] + rb[:, None] * nk

    def _neighbour_crossings(self, model, start, body, partner, normal, lever, plever, x, R):
        """Pairs next to the step's fibre rows across a joint that passed through each other
        (``ChainOptions.restore_crossings``), as rows turned back to their start side (:meth:`_restore_crossings`):
        (body, partner, normal, lever, partner lever, gap), and their number. The detection keeps one row of a
        contact at a joint (:func:`_unique_joint_contacts`: the pairs with either segment of the joint are copies),
        and during the step the contact may slide past the joint onto the other segment, whose pair has no row: for
        every row (a, b) (end-state geometry ``normal``, ``lever``, ``plever``) whose closest axis point on a (on b)
        lies within 2 :data:`CROSSING_END_FRACTION` of the segment's length from its end at a joint, the pairs
        (a', b) (and (a, b'), (a', b')) are checked, a' (b') the neighbour across that joint (measured on the
        plane 20 × 50 landing: 17 of the 19 pass-throughs of pairs without a row had such a row)."""
        S = model.n_segments
        d3 = R[:, :, 2]
        ca, cb = np.empty(3 * len(body), np.int64), np.empty(3 * len(body), np.int64)
        m = KP.joint_neighbour_pairs(body, partner, np.ascontiguousarray(normal), np.ascontiguousarray(lever),
                                     np.ascontiguousarray(plever), np.ascontiguousarray(d3), model.half_length,
                                     model.radius, model.segment_fibre, 1.0 - 2.0 * CROSSING_END_FRACTION, ca, cb)
        if not m:
            return _no_rows(), 0
        key = np.sort(ca[:m] * S + cb[:m])  # (np.unique hashes: 7 × slower on the reference scene's 10⁵ keys)
        key = key[np.concatenate(([True], key[1:] != key[:-1]))]
        cb_, cp_ = np.ascontiguousarray(key // S), np.ascontiguousarray(key % S)
        k, sg0, cn1 = self._crossing_flips(model, start, cb_, cp_, x, d3)
        # a flipped pair that is a row itself was turned back with the rows
        k = np.asarray(k, np.int64)
        if len(k):  # (np.isin hashes all the rows' keys even for no k: 20 ms on the reference scene)
            k = k[~np.isin(key[k], np.minimum(body, partner) * S + np.maximum(body, partner))]
        if not len(k):
            return _no_rows(), 0
        fb, fp = np.ascontiguousarray(cb_[k]), np.ascontiguousarray(cp_[k])
        geo = self._pair_geometry(model, fb, fp, x, R)
        self._turn_back(model, np.arange(len(k)), sg0[k], cn1[k], fb, fp, *geo, d3)
        return (fb, fp) + geo, len(k)

    def _end_obstacle_rows(self, model, rows, x, R, R_mid, obstacles):
        """The step's obstacle rows at the state x, R: the row's axis point (its contact point + r n at the mid
        state R_mid, carried with the segment) against its obstacle's field: (body, −1, normal, lever, 0, gap)."""
        sel = np.nonzero(rows.primary & (rows.partner < 0))[0]
        sb = np.ascontiguousarray(rows.body[sel])
        r = model.radius[sb]
        local = np.einsum("kji,kj->ki", R_mid[sb], rows.lever[sel] + r[:, None] * rows.normal[sel])
        c = x[sb] + np.einsum("kij,kj->ki", R[sb], local)
        which = ((-1 - rows.key[sel]) // 3) // model.n_segments  # _obstacle_key
        gap, normal, lever = np.empty(len(sel)), np.empty((len(sel), 3)), np.empty((len(sel), 3))
        for i, ob in enumerate(obstacles):
            m = which == i
            if m.any():
                normal[m], lever[m], gap[m] = _obstacle_row_geometry(ob, c[m], r[m], x[sb[m]])
        return sb, np.full(len(sb), -1, np.int64), normal, lever, np.zeros((len(sb), 3)), gap

    def _end_rows(self, model, rows, x, R, R_mid, obstacles, start):
        """The step's rows evaluated at the state x, R (fibre pairs: :meth:`_end_fibre_rows`, turned back where
        they passed through each other since ``start`` (``restore_crossings``), with the pairs next to them across a
        joint that did (:meth:`_neighbour_crossings`); obstacle rows:
        :meth:`_end_obstacle_rows`): ((body, partner, normal, lever, partner lever, gap), the number of pairs
        turned back)."""
        parts = [self._end_fibre_rows(model, rows, x, R)]
        turned = 0
        if self.options.restore_crossings and start is not None:
            body, partner, normal, lever, plever, _ = parts[0]
            turned = self._restore_crossings(model, start, *parts[0], x, R[:, :, 2])
            if len(body):
                extra, n_extra = self._neighbour_crossings(model, start, body, partner, normal, lever, plever, x, R)
                if n_extra:
                    parts.append(extra)
                    turned += n_extra
        if obstacles and (rows.partner < 0).any():
            parts.append(self._end_obstacle_rows(model, rows, x, R, R_mid, obstacles))
        return tuple(np.concatenate(z) for z in zip(*parts)), turned

    @staticmethod
    def _hot_obstacle_rows(model, x, R, seg, obstacles, reach):
        """Obstacle rows (body, −1, normal, lever, 0, gap) of the segments ``seg`` at the state x, R: per segment
        and obstacle the deepest of its axis end points and midpoint, where its gap φ − level − r is below
        ``reach`` (m)."""
        out = []
        if not len(seg):
            return _no_rows()
        d3 = R[seg, :, 2]
        h = model.half_length[seg, None]
        pts = np.stack([x[seg] - h * d3, x[seg], x[seg] + h * d3], axis=1)  # (n, 3 samples, 3)
        r = model.radius[seg]
        for ob in obstacles:
            phi = (ob.field.distance(pts.reshape(-1, 3)) - ob.level).reshape(len(seg), 3)
            j = np.argmin(phi, axis=1)
            g = phi[np.arange(len(seg)), j] - r
            m = np.nonzero(g < reach)[0]
            if not len(m):
                continue
            nrm, lever, gap = _obstacle_row_geometry(ob, pts[m, j[m]], r[m], x[seg[m]])
            out.append((seg[m], np.full(len(m), -1, np.int64), nrm, lever, np.zeros((len(m), 3)), gap))
        return tuple(np.concatenate(z) for z in zip(*out)) if out else _no_rows()

    def _post_stabilise(self, model, rows, x, R, R_mid, dt, obstacles, start=None):
        """Post-stabilisation (Cline & Pai 2003; ``ChainOptions.post_stabilisation``). The step's contact rows are
        evaluated again at its end state x, R (fibre pairs: the closest points of their axes now; obstacle rows: the
        field at the row's axis point), and where one overlaps by more than 2 s (s = :data:`POST_SLOP_FRACTION` × its
        radius), the fibres of those rows get a position-only correction: min ½‖Δu‖²_M (with the joint springs'
        rows) s.t. Δt J_α Δu ≥ −(g_α + s) for every row of theirs within a radius of contact, their joints' anchors
        moving together; q ← q + Δt Δu (exponential map), velocities unchanged. Returns the corrected (x, R) (the
        given arrays where nothing overlapped that deep), the pairs turned back (``restore_crossings``) and the
        largest overlap (m) of the rows at x, R."""
        o = self.options
        fib = model.segment_fibre
        (body, partner, normal, lever, plever, gap), turned = self._end_rows(model, rows, x, R, R_mid, obstacles,
                                                                            start)
        overlap = float(max(0.0, -gap.min(initial=0.0)))
        r = model.radius[body]
        deep = gap < -2.0 * POST_SLOP_FRACTION * r
        if not deep.any():
            return x, R, turned, overlap
        hot = np.zeros(model.n_fibres + 1, bool)  # the last entry, read for an obstacle partner (−1), stays False
        hot[fib[body[deep]]] = True
        pf = np.where(partner >= 0, fib[np.maximum(partner, 0)], -1)
        hot[pf[deep & (partner >= 0)]] = True
        near = np.nonzero((gap < r) & (hot[fib[body]] | hot[pf]))[0]
        body, partner, normal, lever, plever, gap, r = (np.ascontiguousarray(a[near]) for a in
                                                        (body, partner, normal, lever, plever, gap, r))
        if obstacles and turned:
            # a pair turned back moves by up to its whole overlap: the obstacles near its fibres hold too, also
            # where the step had no row (its segments were not near them at the mid state)
            reach = float(max(0.0, -gap.min(initial=0.0))) + float(model.radius.max())
            extra = self._hot_obstacle_rows(model, x, R, np.nonzero(hot[fib])[0], obstacles, reach)
            body, partner, normal, lever, plever, gap = (np.ascontiguousarray(np.concatenate([a, b])) for a, b in
                                                         zip((body, partner, normal, lever, plever, gap), extra))
            r = model.radius[body]
        k = len(body)
        sub = _Rows(body, partner, normal, lever, plever, gap, partner < 0, np.ones(k, bool), np.zeros(k, np.int64))
        S = model.n_segments
        du = np.zeros((S, 6))
        jk, jl, jrk, jrl, jt, jc, jw0 = self._joint_rows(model, sub, x, R, dt, du)
        target = np.ascontiguousarray(-(gap + POST_SLOP_FRACTION * r) / dt)
        par = S >= o.parallel_threshold
        KC.project_coupled(body, partner, normal, lever, plever, target, du, self._writable(model.mass),
                           np.ascontiguousarray(R), self._writable(model.inertia), np.zeros(0), np.zeros(0), 0.0,
                           int(o.qp_iterations), float(o.contact_tolerance), np.zeros(k), np.zeros((k, 2)), jk, jl,
                           jrk, jrl, np.ascontiguousarray(jt), jc, jw0, _chain_offsets(jk, jl), -1, par,
                           momentum=self._momentum, root_sweeps=int(o.root_sweeps), root_segments=int(o.root_segments),
                           joints_last=True, storage=self._kernel_storage(model, k + len(jk)))
        # (an unbounded correction scaled down: _trusted_correction)
        du = np.ascontiguousarray(_trusted_correction(model, np.zeros_like(du), du, R, dt,
                                                      float(np.max(-(gap + POST_SLOP_FRACTION * r)))))
        x_out, R_out = np.empty_like(x), np.empty_like(R)
        (K.exp_step if par else K.exp_step_serial)(x, R, np.ascontiguousarray(du[:, :3]),
                                                   np.ascontiguousarray(du[:, 3:]), dt, x_out, R_out)
        return x_out, R_out, turned, overlap

    def _contacts(self, rows, gaps, beta, order, row_off, bodies, u_minus, model, R_mid, Iwi, dt, lam, sweeps_box,
                  x_mid=None, warm=None, pass_key=0, joints_last=False, u_spring=None, spring_step=0.5, budget=False,
                  tol_scale=1.0, sweep_cap=None, extend_cap=True, joint_target=None):
        """Contact stage for given row gaps (m) and penetration recovery β; returns u (S, 6). Coupled mode:
        ``sweep_cap``: the solve's sweep cap when below ``qp_iterations`` in a system too large for the sweep
        budget (``predictor_sweeps``, ``push_out_sweeps``; None: ``qp_iterations``); ``extend_cap`` False: late
        promotions do not extend that cap (see ``predictor_extension``). ``joint_target`` (n_j, 3) m/s: the joint
        rows' targets instead of the pass's (:meth:`_joint_gap_push`).
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
            if joint_target is not None:  # the set-up does not depend on the joint targets
                joints = joints[:4] + (np.ascontiguousarray(joint_target),) + joints[5:]
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
        non-finite results. A step that would raise the total energy is taken as two halves instead
        (``ChainOptions.step_halvings``); the end state is post-stabilised (``ChainOptions.post_stabilisation``)."""
        if not dt > 0:
            raise ParameterError(f"dt must be > 0 s, got {dt}")
        new = self._energy_checked_step(model, state, dt, obstacles, int(self.options.step_halvings))
        if self._post_input is not None:
            new = self._post_stabilised(model, state, new, dt, obstacles)
        self._last_energy = (new, self.last_stats)
        return new

    def _post_stabilised(self, model, start, new, dt, obstacles):
        """The state ``new`` after :meth:`_post_stabilise` with the last step's rows (``start``: the step's start
        state); the step's statistics updated (its energies and joint gap; the correction's time counted as
        contacts)."""
        t0 = time.perf_counter()
        rows, R_mid = self._post_input
        x, R = new.position, new.rotation
        st = self.last_stats
        st.crossings_restored = 0
        overlap = None  # the largest overlap of the rows at the returned state (StepStats.end_overlap)
        for _ in range(POST_ROUNDS):
            x_c, R_c, turned, before = self._post_stabilise(model, rows, x, R, R_mid, dt, obstacles, start)
            st.crossings_restored += turned
            if x_c is x:
                overlap = before
                break
            x, R = x_c, R_c
            if not turned:  # a round that turned no pair back moved nothing far
                break
        if x is not new.position:
            if not (np.isfinite(x).all() and np.isfinite(R).all()):
                raise DivergenceError(f"non-finite post-stabilised positions at t = {new.time:.4g} s "
                                      f"(dt = {dt:g} s); reduce dt")
            energies = None  # the returned state's energies, where the energy limit computed them
            if not st.crossings_restored:  # (a pair turned back is moved back whatever the energy)
                x_l, R_l, energies = self._energy_limited_correction(model, start, new, x, R)
                if x_l is not x:  # a part of the correction or none: the overlap it leaves is measured again
                    x, R, overlap = x_l, R_l, None
            if x is not new.position:
                new = ChainState(x, R, new.velocity, new.angular_velocity, new.time)
                if energies is None:
                    _record_energies(st, model, new, self.options.gravity)
                else:
                    for name in ENERGY_FIELDS:
                        setattr(st, name, getattr(energies, name))
        if overlap is None:  # the overlap the correction left
            gap = self._end_rows(model, rows, x, R, R_mid, obstacles, start)[0][5]
            overlap = float(max(0.0, -gap.min(initial=0.0)))
        st.end_overlap = overlap
        st.seconds["contacts"] = st.seconds.get("contacts", 0.0) + time.perf_counter() - t0
        st.seconds["total"] = st.seconds.get("total", 0.0) + time.perf_counter() - t0
        return new

    def _energy_limited_correction(self, model, start, new, x, R):
        """The post-stabilised positions x, R of the step ``start`` → ``new``, or a part of their correction: the
        correction moves positions only, against gravity and the joint springs, and is not to make the step gain
        energy (with ε = 0 none may): where the corrected state's total energy exceeds the larger of the step's
        start energy and the uncorrected end's (+ round-off, as in :meth:`_energy_checked_step`), the largest of
        ½, ¼, ⅛ of the correction (positions linearly, rotations along their geodesic) that does not is applied,
        else none. Not applied to a correction that turned a pair back (``restore_crossings``): a pass-through left
        in place would be lasting, an energy gain of a correction is of the order of the overlap's spring and
        gravity work. Measured (issue 10, thirty-fourth session): the frictionless terrain 7 × 100 strand's only
        rising step (t = 0.092 s, +7e-12 J) was a correction that added 1.29e-10 J to a step that had lost
        1.22e-10 J. Returns (x, R, their energies as :class:`StepStats`, or None for the uncorrected end state,
        whose energies the step's statistics hold)."""
        begin = self._state_energies(model, start)
        before = self.last_stats
        scale = before.kinetic_energy + before.spring_energy + begin.kinetic_energy
        limit = max(begin.total_energy, before.total_energy) + ENERGY_ROUNDOFF * scale
        g = self.options.gravity

        def energies(xx, RR):
            return _record_energies(StepStats(), model, ChainState(xx, RR, new.velocity, new.angular_velocity,
                                                                   new.time), g)

        full = energies(x, R)
        if full.total_energy <= limit:
            return x, R, full
        x0, R0 = new.position, new.rotation
        phi = Rotation.from_matrix(np.einsum("sij,skj->sik", R, R0)).as_rotvec()  # R = exp(φ̃) R0
        for part in (0.5, 0.25, 0.125):
            xp = x0 + part * (x - x0)
            Rp = np.ascontiguousarray(np.einsum("sij,sjk->sik", Rotation.from_rotvec(part * phi).as_matrix(), R0))
            e = energies(xp, Rp)
            if e.total_energy <= limit:
                return xp, Rp, e
        return x0, R0, None

    def _state_energies(self, model, state) -> StepStats:
        """Statistics holding the energies (J) of ``state``: the last step's when it is that step's result."""
        if self._last_energy is not None and self._last_energy[0] is state:
            return self._last_energy[1]
        return _record_energies(StepStats(), model, state, self.options.gravity)

    def _scale_warm(self, factor):
        """Scale the stored warm-start impulses (normal and friction, N s) by ``factor``: impulses of resting
        contacts are proportional to the step (a halved step starts from half of them)."""
        for name in ("_warm", "_warm_push"):
            w = getattr(self, name)
            if w is not None:
                setattr(self, name, (w[0], w[1] * factor, w[2] * factor))

    def _energy_checked_step(self, model, state, dt, obstacles, halvings):
        """One step; with ``halvings`` > 0, a step that ends with more total energy than it started with (beyond
        round-off: with ε ≤ 1, static obstacles and gravity in the energy, none may) or with a segment turning by
        more than ``max_rotation_per_step`` per step (:meth:`_over_rotated`) is taken again as two steps of
        Δt/2, each checked the same way with one halving less. The statistics of the halves are merged
        (:func:`_merged_stats`)."""
        if halvings <= 0:
            return self._step(model, state, dt, obstacles, 0)
        start = self._state_energies(model, state)
        saved = (self._warm, self._warm_push, self._normals, self._dhat)
        new = self._step(model, state, dt, obstacles, 0)
        st = self.last_stats
        scale = st.kinetic_energy + st.spring_energy + start.kinetic_energy
        if not (st.total_energy > start.total_energy + ENERGY_ROUNDOFF * scale
                or self._over_rotated(new, dt)):
            return new
        self._warm, self._warm_push, self._normals, self._dhat = saved
        self._scale_warm(0.5)
        half = self._energy_checked_step(model, state, 0.5 * dt, obstacles, halvings - 1)
        first = self.last_stats
        self._last_energy = (half, first)
        new = self._energy_checked_step(model, half, 0.5 * dt, obstacles, halvings - 1)
        self._scale_warm(2.0)
        self.last_stats = _merged_stats(first, self.last_stats)
        return new

    def _over_rotated(self, state, dt) -> bool:
        """Whether a segment of ``state`` turns by more than ``ChainOptions.max_rotation_per_step`` (rad) in a
        step of ``dt`` (s) at its end angular velocity."""
        limit = self.options.max_rotation_per_step
        if limit is None:
            return False
        w2 = np.einsum("ij,ij->i", state.angular_velocity, state.angular_velocity)
        return bool(w2.max(initial=0.0) * dt * dt > limit * limit)

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
        self._mean_lever_failures = 0
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
                size = 2.0 * float(model.half_length.sum())  # all fibres end to end
                reach = max(dt * float(self._speed.max(initial=0.0) + 1.5 * dhat_used.max(initial=0.0)),
                            float(np.ptp(x, axis=0).max()))
                if not reach <= DIVERGED_REACH * size:
                    raise DivergenceError(f"the fibres spread over {reach:.3g} m, or a segment's speed or its expected "
                                          f"velocity change would move it that far in one step, at t = "
                                          f"{state.time:.4g} s: {DIVERGED_REACH:g} × their total length "
                                          f"({size:.3g} m) or more; the simulation diverged (dt = {dt:g} s); "
                                          "reduce dt")
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
                joint_push = None  # the touched fibres' t_i joint gaps, closed by the push-out (close_joint_gaps)
                if (last and endvel and o.close_joint_gaps and o.split_recovery and o.penetration_recovery > 0
                        and o.contact_coupling == "coupled"):
                    joint_push = self._joint_gap_push(model, rows, x, R, dt)
                if last and o.penetration_recovery > 0 and ((gaps_pos < 0).any() or joint_push is not None):
                    # split impulse: the penetration push-out moves the positions but is not kept as velocity
                    # (only the last pass's is used: an earlier pass feeds the joints u_vel alone)
                    # its own previous impulses (kept only under push_out_warm_start), else the velocity solve's
                    warm_pos = warm if self._warm_push is None else self._warm_start_impulses(rows, self._warm_push)
                    u_pos = self._contacts(rows, gaps_pos, beta_pos, order, row_off, bodies, u_minus, model, R_mid,
                                           Iwi, dt, np.zeros_like(lam), sweeps_box, x_mid, warm_pos, pass_key=it,
                                           joints_last=o.split_recovery and o.recovery_keeps_joints,
                                           u_spring=u_spring, spring_step=spring_step, budget=endvel,
                                           sweep_cap=o.push_out_sweeps, joint_target=joint_push)
                    push_impulses = self._impulses
                    pass_promoted += self._promoted
                    if o.split_recovery:  # a push-out without a bounded solution is scaled down (see the helper)
                        asked = 2.0 * beta_pos * max(0.0, -float(gaps_pos.min(initial=0.0)))
                        if joint_push is not None:
                            asked = max(asked, dt * float(np.sqrt((joint_push * joint_push).sum(1)).max()))
                        u_pos = _trusted_correction(model, u_vel, u_pos, R_mid, dt, asked)
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
        # post-stabilisation acts on the state step() returns (after any halved steps): its rows and mid state
        self._post_input = ((rows, R_mid) if o.post_stabilisation and rows is not None
                            and o.contact_coupling == "coupled" and len(rows.body) else None)
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
                       joint_root_failures=self._mean_lever_failures,
                       harmonisation_iterations=o.harmonisation_iterations,
                       energy_bound=float("nan") if self._bound is None else self._bound, exact_solves=self._continued)
        _record_energies(st, model, new, g)
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
