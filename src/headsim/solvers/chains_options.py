"""Algorithm options (:class:`ChainOptions`) and per-step statistics (:class:`StepStats`) of
:class:`headsim.solvers.chains.ChainSolver` (SI units). The options' notes record what each choice was measured to
cost and buy on the seed's scenes (Sobottka 2008 ch. 8)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from headsim.errors import ParameterError
from headsim.solvers.chains_model import STANDARD_GRAVITY, FrictionLaw


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
    joint_levers : ``"mean"`` (default since issue 10's thirty-eighth session) or ``"start"`` (eq. 8.72, the seed's
        Method I: the joint stage applies each joint impulse at the levers ±h R e₃ of the start of the step, its
        spring rows linearly implicit). ``"mean"``: each impulse at the lever averaged over its body's rotation φ of
        the step, J_l(φ) r (J_l the left Jacobian of SO(3)), so that the end-of-step gap is exactly Δt times the
        joint's relative velocity at it and the impulses do no work on the end velocities; the twists and impulses of
        every fibre are then solved together to the root of the stage's equations
        (:mod:`headsim.solvers._kernels.chains_mean`: Newton with a coloured forward-difference Jacobian whose block
        factors are kept across iterations, harmonisation passes and steps while chord steps on them more than halve
        the residual; up to 40 iterations from the start-of-step twists; a fibre whose Newton does not converge gets
        the start levers' answer, counted in :attr:`StepStats.joint_root_failures`). Issue 10's thirty-seventh session
        (``benchmarks/bench_joint_stage_root.py``): the start levers' impulses did the work that made the plain step
        gain energy on strongly bent, stiff fibres turning ≈ 1 rad per step (the released coil, 8.7 × its energy in 20
        ms); with ``"mean"`` the same plain steps lose energy in every step (0.344 × after 20 ms, joint gaps ≤ 0.4 nm;
        the 3 mm coil at 0.5 ms: 0.107 ×, where the start levers give 3.8 ×). Where no root is found (the 3 mm coil at
        1 ms: 1 rad of bending per joint) the step control (``step_halvings``) still acts. The terrain drape reduced
        to 7 × 100 (frictionless, 110 steps) never gains energy with ``"mean"`` even without the step control (the
        start levers: up to 3.6e-4 J in a step, then a torsional runaway;
        ``tests/solvers/test_chains_stabilisation.py``). At rest the two agree (the 4-layer stack of free 5-segment
        chains: the same total energy to 12 digits after 20 steps, spin ≤ 5e-5 rad/s). They differ where the first
        pass's contact solve is stopped after one sweep (``predictor_sweeps`` = 1): its crude friction correction
        spins the light chains about their axes by up to 9 rad/s, the second pass's joint stage starts from that
        rotation Δθ_extra, and the mean levers follow it (the start levers do not): ≈ 0.1–0.2 rad/s of spin left
        against ≈ 0.01 rad/s, nanometre overlaps that the split push-out corrects in every step, 7 of 300 steps halved
        by the energy check (its bound at rest is ≈ 1e-25 J); with one harmonisation pass both give the same 0.4 rad/s
        (``tests/solvers/test_chains.py``). Cost (thirty-eighth session, after the factors were kept across calls and
        the double work of the start kernel for every fibre was removed): the 7 × 30 helical drape (aniso, 400 steps)
        18.2–18.4 ms per step against 19.9 ms with ``"start"`` (joint stage 2.3 against 0.9 ms per step; before these
        changes 8.6 ms), the reference scene at rest (``benchmarks/bench_drape.py --state
        benchmarks/data/drape_355x100_aniso_t1.0.npz --settle 3 --steps 5 --coupled-only``, alternated runs) 1.91 /
        1.72 s per step against 1.85 / 1.74 s with ``"start"`` (joint stage 0.15–0.16 against 0.06–0.07 s; contacts,
        joint gaps, penetrations and energies the same to 2–3 digits). Figures in the notes and tests measured before
        the thirty-eighth session are the start levers' unless they say otherwise. Thirty-seventh session, with
        ``"mean"`` opt-in: on the terrain subset (fibres 300–330 from t = 69 ms, no ``max_rotation_per_step``) fibre
        328's spin-up of the start levers (464 → 4,070 rad/s in 12 steps) does not occur (≤ 392 rad/s), but fibre 314
        turns ever faster, 441 → 883 rad/s over t = 75–83 ms (with the limit: to 731 rad/s, 21 solver steps for 14
        steps; the start levers with the limit: ≤ 597 rad/s, 19). It is a real motion resolved too coarsely, not a
        runaway: with smaller steps (mean levers, no limit) fibre 314 reaches 884 / 675 / 570 rad/s at t = 83 ms with
        Δt = 1 / 0.5 / 0.25 ms (the start levers at 0.25 ms: 613 rad/s), the total energy 8.83 / 8.90 / 8.98e-5 J
        (start levers at 0.25 ms: 9.00e-5 J). The limit stays on with either lever choice (it is the accuracy
        control).
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
        so it adds no kinetic energy (``split_recovery=False``: the push-out is kept as velocity). Its
        constraints need not have a common solution (a segment pinched between an obstacle and neighbours while
        its joint gaps are closed): then its Gauss–Seidel impulses grow with every sweep, and a fibre whose
        correction would move a point by more than :data:`~headsim.solvers.chains.CORRECTION_TRUST` × the
        largest correction asked for (2β × the deepest penetration, or the largest joint gap closed) is moved
        only that far (``chains._trusted_correction``; likewise the post-stabilisation). Measured (issue 10's
        thirty-fourth session): the frictionless helical strand 7 × 30 had push-outs moving points by up to
        2.3 cm for corrections of 7 µm, and 4 steps at t = 0.365–0.368 s gained up to 5e-7 J (≈ 20 % of its
        kinetic energy) though halved to Δt/8; bounded, no step of its runs (none 0.7 s, iso 1.5 s, aniso 5 s)
        gains energy and none is halved. The reference scene at rest (≤ 2.2 × the correction asked for) and the
        plane 7 × 100, terrain 7 × 100 and sphere landings are unchanged; plane 20 × 50 changes (its
        overlaps > 10 µm 472 → 363 pair-steps, flips 48 → 47; its 3 rising steps, ≤ 6.4e-8 J, remain: their
        kinetic energy gain exceeds the springs' release in the velocity stage, not in a correction).
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
    separating_allowance : coupled mode with ``candidate_reserve``, default True: a fibre pair that separates at u⁻
        faster than the persistence filter's ‖g‖Δt (eq. 8.9) but slower than ‖g‖Δt + δ̂_a + δ̂_b (the two segments'
        allowances of this step's velocity changes, as the relative band and the reserve use them) is kept as a
        candidate row instead of being dropped: the solve's velocities may turn it round and close it, and without a
        row it then passes through. False: the former filter (only separating penetrations kept). Issue 10's
        thirtieth session (against False, same runs otherwise): plane scene 30 × 100 through its landing (steps
        90–150), fibre pairs more than 50 µm into each other at a step's end 16.4 per step (largest 54) against 18.9
        (85; the pairs without a row had been between 37 µm into each other and 58 µm apart at the step's start,
        0.01–0.38 m/s); reference scene at rest (t = 1.0 s, 8 steps after 3): overlaps away from the roots > 10 µm
        4 against 251, 99th percentile 4.1 against 16.6 µm, largest 14.3 against 69.0 µm, next to the roots > 10 µm
        469 against 1,114; 128 k candidates against 108 k; 0.96 / 0.83 against 0.98 / 0.93 s per step (noise).
    pass_through_normals : default True: a fibre pair detected at the mid-step state whose closest points' separation
        points the other way at t_i (first order, from the first half step's motion; closest points inside both
        segments) has passed through its partner in that half step: it gets the t_i side's normal and the gap
        −(distance + r_a + r_b) instead of reading as a pair on the far side, separating. The mid-step detection
        (the seed's maximum compression) otherwise lets pairs approaching faster than (2r + gap)/(½Δt), ≈ 0.2 m/s
        for 70 µm fibres 40 µm apart, through each other. False: the former detection. Issue 10's thirtieth
        session, against False: two crossed segments falling onto each other at 0.3–2 m/s stop (before: through
        at 0.3 m/s and above); plane scene 30 × 100 through its landing (steps 90–150), fibre pairs more than 50 µm
        into each other at a step's end 1.1 per step (largest 4) against 16.4 (54); reference scene at rest (8 steps
        after 3) overlaps > 10 µm next to the roots 420 against 469, reported max penetration 87 against 133 µm;
        step time within the machine's noise (0.94 / 1.04 / 1.16 / 1.21 against 0.75 / 0.87 / 1.65 / 1.71 s).
    post_stabilisation : coupled mode, default True: post-stabilisation (Cline & Pai 2003) of the end state. The
        step's contact rows are evaluated again at the positions it reached (fibre pairs: the closest points of
        their axes there; obstacle rows: the field at the row's axis point), and where a row overlaps by more than
        twice the slop s = :data:`~headsim.solvers.chains.POST_SLOP_FRACTION` × r (7 µm for 70 µm fibres), the
        fibres of those rows are moved apart: min ½‖Δu‖²_M plus the joint springs' rows s.t. Δt J Δu ≥ −(g + s) for
        every row of theirs within a radius of contact, the joints' anchors moving together (ending with an exact
        joint solve), q ← q + Δt Δu; the velocities are left as the step made them. The velocity solve and the split
        push-out hold and correct the rows' first-order gaps at their mid-step normals and points; where the
        contact points slide or the segments turn fast, the true end-of-step overlap grows by up to tens of µm per
        step and was left to accumulate. Measured (issue 10's thirty-second session; pair-steps = end-of-step fibre
        pairs summed over the steps, exact capsule distances; with / without): plane 7 × 100 (0.3 s) overlaps
        > 10 µm 61 / 790 pair-steps, > 50 µm 11 / 44, max joint gap 32.8 / 56.4 µm; terrain 7 × 100 (0.4 s)
        104 / 1,321 and 21 / 54, deepest axis point into the terrain 46 / 268 µm; sphere-helical 7 × 100 (0.5 s)
        0 / 37 above 10 µm; 19 × 30 0 / 203; plane 20 × 50 (6 mm segments) 478 / 11,090 and 57 / 994, max joint
        gap 92 / 232 µm; reference scene at rest (t = 1.0 s, 8 steps after 3): overlaps > 10 µm next to the
        roots 244 / 420 (largest 44 / 67 µm), elsewhere 1 / 4, 0.95 against 0.76 s per step. It does not stop
        fibres passing through each other within one step (the sign of the crossing flips): plane 7 × 100 16 / 27
        such events, plane 20 × 50 149 / 337. The correction moves positions only, against gravity and the
        joint springs: where it would make the step gain energy it is applied in part (½, ¼, ⅛) or not at all,
        unless it turns a pair back (``ChainSolver._energy_limited_correction``; thirty-fourth session). False:
        the former end state.
    restore_crossings : with ``post_stabilisation``, default True: a fibre pair of the step's rows that passed
        through its partner during the step (the sign of (e_a × e_b)·(c_a − c_b) changed between the step's start
        and end, closest points inside both segments, axes not parallel) is turned back: the post-stabilisation
        sees it on its start side with the overlap −(distance + r_a + r_b), not as a pair on the far side, and
        moves it back (``ChainSolver._restore_crossings``); after such a round the post-stabilisation runs again
        (up to :data:`~headsim.solvers.chains.POST_ROUNDS` rounds), as a pair moved back by its whole overlap may
        carry a neighbour through a third fibre, and the obstacles near the fibres moved are rows of it too.
        ``StepStats.crossings_restored`` counts the pairs. Measured (issue 10's thirty-third session, with
        ``max_rotation_per_step`` = 0.5; with / without; crossing flips = pairs whose crossing sign at the end of
        a step differs from the step before, closest points inside): plane 7 × 100 (0.3 s) flips 8 / 14,
        overlaps > 10 µm 39 / 48 pair-steps; terrain 7 × 100 (0.4 s) flips 2 / 15, overlaps > 10 µm 122 / 56,
        > 50 µm 11 / 6; plane 20 × 50 (0.3 s) flips 61 / 137, overlaps > 10 µm 400 / 480, > 50 µm 43 / 53,
        deepest axis point into the plane 84 / 58 µm (from the steps themselves, not the corrections); the sphere
        scenes turned no pair (bitwise unchanged); 89 against 87 ms per step on plane 20 × 50; reference scene at
        rest: no pair turned, 7 ms per step for the two crossing evaluations of its 173 k rows and candidates.
        The pairs next to a row across a joint are checked too (``ChainSolver._neighbour_crossings``): the
        detection keeps one row of a contact at a joint, and the contact may slide past it during the step
        (on plane 20 × 50, 17 of the 19 flips of pairs without a row had such a row). Measured with them (issue
        10's thirty-fourth session; with / without): plane 20 × 50 flips 48 / 61, overlaps > 10 µm 472 / 400,
        > 50 µm 34 / 43; plane 7 × 100 flips 9 / 8, terrain 7 × 100 3 / 2 (single runs of chaotic landings;
        their overlaps within the run-to-run spread); sphere 19 × 30 unchanged; reference scene at rest
        15 ms per evaluation (2–3 per step). The flips left (plane 20 × 50, traced): 34 of the step's rows whose
        closest point lies within 5 % of a segment end at the step's start or end (before the correction), where
        the crossing sign is not taken as a side (the criterion at 2 % was tried in the thirty-third session:
        fewer flips, three times the overlaps).
    step_halvings : default 3: a step that ends with more total energy (kinetic + joint springs + gravity) than it
        started with, beyond 1e-9 of the kinetic and spring energies (round-off), is taken again as two steps of
        Δt/2, each checked the same way, down to Δt/2^step_halvings (the warm-start impulses scaled with the step);
        ``StepStats.substeps`` counts the steps taken. With ε ≤ 1, static obstacles and gravity in the energy no
        step may raise it ("energy never increases with ε = 0"), and none did in the plane, sphere-helical, head
        and sphere-horizontal scenes measured (300–500 steps each); the terrain scene's frictionless 7 × 100 strand,
        coiled on itself, gained energy in every step from t = 0.081 s on and ran away into a torsional spin
        (10⁴ rad/s, joint gaps of centimetres by 0.125 s; also with friction, without push-out, with 3
        harmonisation passes, and with 60 more sweeps): with the halving, 17 of its first 150 steps are halved and
        no step raises the energy (at Δt = 0.5 ms the strand is stable too). 0: the former fixed step (and no
        ``max_rotation_per_step`` either).
    max_rotation_per_step : rad, default 0.5 (None: off): a step after which a segment turns faster than this per
        step (|ω| Δt at its end angular velocity) is halved like one that raised the energy (``step_halvings``
        levels). The springs' moments and the joint and contact levers are taken in one frame per step, which
        holds only for small rotations per step; a local torsional spin-up inside a scene whose total energy
        falls is invisible to the energy check. Measured (issue 10's thirty-third session): the full-size terrain
        drape (355 × 100, ``benchmarks/bench_terrain_spin.py`` from t = 69 ms) spun fibre 316's segments up
        from 443 to 3,375 rad/s in 7 steps with joint gaps of 149 µm; with 0.5 rad the segments stayed at
        410–620 rad/s over 14 steps (1–2 solver steps per step), joint gaps ≤ 24 µm. 5 small scenes (one core
        each; default / 0.5 / 0.3 rad): terrain 7 × 100 (0.4 s) extra solver steps 15 / 150 / 307, crossing
        flips 23 / 15 / 6, overlaps > 10 µm 104 / 56 / 56 pair-steps, max joint gap 61 / 25 / 21 µm, 36 / 52 /
        81 ms per step; plane 20 × 50 (0.3 s) 29 / 94 / 354 extra steps, flips 149 / 137 / 28, overlaps 478 /
        480 / 275, 60 / 79 / 145 ms per step; plane 7 × 100 overlaps 61 / 48 / 95, flips 16 / 14 / 27; the
        sphere scenes never reached the limit (≤ 144 rad/s), bitwise unchanged. The spin-up's source (thirty-fifth
        session, ``bench_terrain_spin.py``): it is the same without friction, warm starts, split push-out, second
        harmonisation pass, end-velocity positions or post-stabilisation, and absent with
        ``springs_in_first_half_step=False`` (≤ 206 rad/s) on the terrain scene. Thirty-sixth session: it is the
        plain step's energy gain on a strongly bent, stiff chain at ≈ 1 rad per step, without contacts: a single
        fibre cut out of the terrain state (``bench_terrain_spin.py --fibres 328:329``, no obstacles) gains energy
        even from rest, and a released 5 mm coil of 3 mm segments gains 8.7 × its energy in 20 plain steps (9.5 ×
        in 10 with ``springs_in_first_half_step=False``, so that option does not remove the cause); with this
        limit and the energy check it loses 41 % (``tests/solvers/test_chains_stabilisation.py``, whose strict
        xfail lists what did not change it). Thirty-seventh session (``benchmarks/bench_joint_stage_root.py``): not
        the spring rows' linearisation either (the joint stage solved to its root gains energy too, and more often)
        but the work of the joint impulses at the start-of-step levers; at the levers averaged over each body's
        rotation, J_l(Δt ω') r, the exact root dissipated in every step: ``joint_levers="mean"`` (the default
        since the thirty-eighth session; with it this limit stays on). Refinement on the 30 fibres
        300–330 of the terrain state (``--fibres 300:330``, 30 steps from t = 69 ms; limit 0.5 / 0.25 / 0.1 rad):
        largest transverse spin per step 142–510 / 117–290 / 139–438 rad/s (off: up to 1,544, and 4,070 rad/s in all
        at the 12th step), joint gaps ≤ 25.9 / 6.5 / 1.1 µm, total energy after the 30 steps 8.49 / 8.59 / 8.67e-5
        J, 51 / 89 / 204 solver steps (6.7 / 12.3 / 33.8 s): the landing converges as the limit is refined; 0.5 rad
        is the cheapest of the three and stays the default.
    close_joint_gaps : coupled mode with ``end_velocity_positions`` and ``split_recovery``, default True: the split
        push-out of the last pass also closes the joint gaps d^i (t_i) of the fibres with contact rows, its joint
        rows asking for −d^i/Δt where ‖d^i‖ exceeds ``push_out_slop`` × the radius (and the push-out runs for them
        when no row penetrates). Those fibres move q^{i+1} = q^i + Δt u, and the velocity solve's joint rows
        (J u' = 0, ``joint_gap_fraction`` = 0) keep every gap as it was, so the joint stage's closing of the gaps
        (Method I) never reached their positions: a gap opened in one step stayed while the fibre had a row
        (measured, head scene 40 × 30 after the landing at t = 0.40 s: 22.5 µm at one joint for the 200 steps to
        t = 0.6 s). Positions only, as the penetrations' push-out: the velocity kept is the velocity solve's.
        False: the former steps. Issue 10's thirtieth session: after the landing the head scene's gaps are
        0.03–0.05 µm; reference scene at rest (t = 1.0 s, 8 steps after 3, alternated runs against False): max
        joint gap 0.10 against 7.7 µm, max penetration 122 against 127 µm, fibre overlaps > 1 µm away from the
        roots 2,058 against 2,506 (largest 69 against 51 µm), mean active contacts 16.5 k against 15.8 k; time per step
        within the machine's noise: 0.97 / 0.98 / 0.84 / 0.89 / 0.88 against 0.90 / 0.85 / 0.80 / 0.95 / 1.07 s.
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
        The root rows are visited by domain (``contact_domains``: each domain's in parallel, then the rows that
        cross domains), as the full sweeps visit theirs (issue 10, twenty-ninth session; before: all of them on one
        thread). On the reference scene at rest (t = 1.003 s) 8.1 k of the 75.6 k rows touch the root region (4.0 k
        / 2.2 k in the two domains, 2.0 k crossing), and one root sweep's visits took ≈ 1.9 ms of its ≈ 2.1 ms on one
        thread (the root chains' solves 0.2 ms), ≈ 40 root sweeps per solve. The step's three captured solves
        replayed, best of 5 and of 8 interleaved runs: 211 / 300 / 352 → 203 / 275 / 308 ms and 148 / 186 / 186 →
        135 / 178 / 174 ms (−6.5 % of the kernel in both), the same sweeps, promotions to ±3 % and final residuals
        to ±10 %; one domain: the former iterates, bitwise. At the step level the gain (≈ 3–5 %) is below the
        machine's noise (8 steps from t = 1.0 s, alternated: 1.03 / 1.35 s before, 1.16 / 1.19 s after), with the
        same end-state overlaps (``bench_drape.py``: 281 against 260 > 10 µm away from the roots).
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
        energy rise, heights within 7.4e-10 m of float64's. The post-stabilisation's projection follows the same rule
        (since issue 10's thirty-ninth session; before, float64 always): on the reference scene at rest its 30 sweeps
        over ≈ 43 k rows and the joints of 352 fibres took 0.20 → 0.16 s per step, the overlaps at the end the same.
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
    joint_levers: str = "mean"
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
    close_joint_gaps: bool = True
    separating_allowance: bool = True
    pass_through_normals: bool = True
    post_stabilisation: bool = True
    restore_crossings: bool = True
    step_halvings: int = 3
    max_rotation_per_step: float | None = 0.5

    def __post_init__(self):
        if not 0.0 <= self.restitution <= 1.0:
            raise ParameterError(f"restitution must be in [0, 1], got {self.restitution}")
        if self.friction_objective not in ("qp", "lp"):
            raise ParameterError("friction_objective must be 'qp' or 'lp'")
        if self.joint_levers not in ("mean", "start"):
            raise ParameterError(f"joint_levers must be 'mean' or 'start', got {self.joint_levers!r}")
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
        if not (isinstance(self.step_halvings, (int, np.integer)) and not isinstance(self.step_halvings, bool)
                and 0 <= self.step_halvings <= 10):
            raise ParameterError(f"step_halvings must be an integer in 0 … 10, got {self.step_halvings!r}")
        if self.max_rotation_per_step is not None and not (
                isinstance(self.max_rotation_per_step, (int, float, np.integer, np.floating))
                and not isinstance(self.max_rotation_per_step, bool)
                and self.max_rotation_per_step > 0 and np.isfinite(self.max_rotation_per_step)):
            raise ParameterError(f"max_rotation_per_step must be a positive number of radians or None, "
                                 f"got {self.max_rotation_per_step!r}")
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
        for name in ("push_out_warm_start", "predictor_extension", "close_joint_gaps", "separating_allowance",
                     "pass_through_normals", "post_stabilisation", "restore_crossings"):
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
    joint_root_failures: int = 0  # joint_levers="mean": fibre joint solves of the step whose Newton did not converge
    qp_sweeps: int = 0
    qp_capped: int = 0  # coupled mode: contact solves of the step that hit the sweep cap (qp_iterations); a solve
    # whose answer the exact final solve replaced does not count (nor its residual in qp_residual)
    qp_residual: float = 0.0  # coupled mode: largest final sweep residual of the step's solves, m/s
    harmonisation_iterations: int = 0
    energy_bound: float = float("nan")  # J, end_velocity_positions: B of the step's velocity solve (nan: none)
    exact_solves: int = 0  # end_velocity_positions: velocity solves replaced by the exact final solve
    substeps: int = 1  # steps of the solver this step took (step_halvings: 2 or more where its energy rose or a
    # segment turned by more than max_rotation_per_step)
    contact_rows: int = 0  # coupled mode: rows of the last contact solve, from the start + added during it
    candidate_rows: int = 0  # coupled mode: candidate pairs not rows from the start
    promoted_rows: int = 0  # of those, added during the solves of the step (sum)
    candidate_band: str = ""  # coupled mode: the band the step's candidates came from ("absolute"/"relative")
    candidate_redos: int = 0  # candidate_band="relative": steps redone because a velocity change exceeded δ̂
    reserve_pairs: int = 0  # candidate_reserve: candidate pairs kept out of the solve at detection
    reserve_promoted: int = 0  # candidate_reserve: of those, the ones a solve's twists closed (then solved again)
    reserve_resolves: int = 0  # candidate_reserve: passes solved again for them
    band_extensions: int = 0  # candidate_band="relative": detections with a band widened to the twist changes
    end_overlap: float = float("nan")  # m, post_stabilisation: the largest overlap of the step's rows at the state
    # the step returns (fibre pairs: exact closest points of the axes, pairs that passed through each other counted
    # through (restore_crossings); obstacle rows: the field at the row's axis point); nan without it
    crossings_restored: int = 0  # restore_crossings: fibre pairs found passed through each other and turned back
    reversed_normals: int = 0  # persistent_normals: fibre rows of the last pass held on their previous side
    seconds: dict = field(default_factory=dict)

    @property
    def total_energy(self) -> float:
        return self.kinetic_energy + self.potential_energy + self.spring_energy
