"""Rod scenes of Sobottka (2008) §3.4.9, with keratin parameters from the property database.

Each builder returns a :class:`Scene` (model, initial state, solver options, time step, duration and
a load / boundary schedule); :func:`run_scene` integrates it and records a :class:`Trajectory`.
The seed gives no magnitudes for most examples; the values chosen here are stated in each docstring.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from headsim.errors import ConvergenceError, ParameterError
from headsim.hair import properties as props
from headsim.hair.fibres import (
    Strand,
    fibre_model,
    helix_axis,
    helix_curvature,
    interpolate_strand,
    make_strand,
    sinusoidal_curvature,
)
from headsim.solvers.rods import (
    GeneralizedAlpha,
    ImplicitRodSolver,
    RodBoundary,
    RodLoads,
    RodModel,
    RodSolverOptions,
    RodState,
    initial_state,
    kinetic_energy,
)
from headsim.solvers.rods_geometry import writhe

__all__ = ["Scene", "Trajectory", "SCENES", "build_scene", "run_scene"]

GRAVITY = np.array([0.0, 0.0, -9.81])
Schedule = Callable[[float, RodState], tuple[RodLoads, RodBoundary]]


@dataclass(frozen=True, eq=False)
class Scene:
    """A rod simulation set-up. ``schedule(t, state)`` gives the loads and boundary conditions held
    over the step that ends at time t (s), given the state at its start."""

    name: str
    model: RodModel
    state: RodState
    options: RodSolverOptions
    dt: float
    duration: float
    schedule: Schedule
    description: str
    strand: Strand | None = None
    info: dict = field(default_factory=dict)  # scene-specific extras (e.g. the prescribed support path)

    @property
    def n_steps(self) -> int:
        return int(round(self.duration / self.dt))


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Recorded output. times (T,) s; positions (T, F, N+1, 3) m; frames_tip (T, F, 3, 3);
    kinetic (T, F) J; iterations (n_steps,) mean Newton iterations of every step;
    curvature (T, F, N+1, 3) 1/m; final_state."""

    times: np.ndarray
    positions: np.ndarray
    curvature: np.ndarray
    kinetic: np.ndarray
    iterations: np.ndarray
    final_state: RodState
    interpolated: np.ndarray | None = field(default=None)  # (T, M, N+1, 3) strand fibres of guide 0
    step_times: np.ndarray | None = None  # (n_steps + 1,) s, every step
    step_tip: np.ndarray | None = None  # (n_steps + 1, F, 3) m, tip positions at every step
    step_kinetic: np.ndarray | None = None  # (n_steps + 1, F) J, kinetic energy at every step


def _hair(length, n_segments, diameter=70e-6, **kw) -> RodModel:
    sec = props.elliptic_cross_section(diameter)
    return fibre_model(length, n_segments, section=sec, **kw)


def _static(loads=None, boundary=None) -> Schedule:
    lo = loads or RodLoads()
    bo = boundary or RodBoundary()
    return lambda t, state: (lo, bo)


def cantilever(n_segments: int = 50, dt: float = 1e-3, duration: float = 0.5) -> Scene:
    """A 5 cm hair (70 um) clamped horizontally and released under gravity; rho_inf = 0.5 in time."""
    m = _hair(0.05, n_segments, root_direction=(1, 0, 0))
    opts = RodSolverOptions(coefficients=GeneralizedAlpha.from_rho_inf(0.5, 1.0))
    st = initial_state(m, frame_map=opts.resolved_frame_map)
    return Scene("cantilever", m, st, opts, dt, duration, _static(RodLoads(gravity=GRAVITY)),
                 "5 cm keratin fibre, clamped horizontally, released under gravity")


def precurved(n_segments: int = 50, dt: float = 2e-3, duration: float = 0.5, rho_inf: float = 0.5) -> Scene:
    """Seed fig. 3.15: a sinusoidally pre-curved 10 cm fibre clamped horizontally, released under
    gravity (curvature amplitude 60 /m, wavelength 2.5 cm, bending in the vertical plane)."""
    L = 0.1
    k0 = sinusoidal_curvature(n_segments, L, 60.0, 0.025, component=0)
    m = _hair(L, n_segments, natural_curvature=k0, root_direction=(1, 0, 0))
    opts = RodSolverOptions(coefficients=GeneralizedAlpha.from_rho_inf(rho_inf, 1.0))
    st = initial_state(m, frame_map=opts.resolved_frame_map)
    return Scene("precurved", m, st, opts, dt, duration, _static(RodLoads(gravity=GRAVITY)),
                 "sinusoidally pre-curved fibre released under gravity (seed fig. 3.15)")


def helix(n_segments: int = 100, dt: float = 2e-3, duration: float = 1.0, load: str = "torque") -> Scene:
    """Seed fig. 3.16: a 30 cm helical fibre (coil radius 1 cm, pitch 1 cm), root clamped with the
    helix axis vertical, no gravity; a tip torque (or force, ``load='force'``) parallel to the axis
    ramps up over the first 40 % of the run and is then held. High numerical damping (seed: alpha = 0.4,
    beta = 0, gamma = 1 -> we use rho_inf = 0 in time). Torque 0.5 EI kappa; force 2e-5 N."""
    L = 0.30
    kap = helix_curvature(0.01, 0.01)
    m = _hair(L, n_segments, natural_curvature=kap, root_direction=(1, 0, 0), root_normal=(0, 0, 1))
    axis = helix_axis(m.root_frame[0], kap)
    EI = m.stiffness[0, 0]
    T0 = 0.5 * EI * np.linalg.norm(kap)
    F0 = 2e-5

    def schedule(t, state):
        ramp = min(t / (0.4 * duration), 1.0)
        if load == "torque":
            return RodLoads(tip_torque=ramp * T0 * axis), RodBoundary()
        return RodLoads(tip_force=ramp * F0 * axis), RodBoundary()

    opts = RodSolverOptions(coefficients=GeneralizedAlpha.from_rho_inf(0.0, 1.0))
    return Scene("helix", m, initial_state(m, frame_map=opts.resolved_frame_map), opts, dt, duration, schedule,
                 f"30 cm helical fibre under an axial tip {load} (seed fig. 3.16)")


def spiral(n_segments: int = 80, dt: float = 2.5e-4, duration: float = 0.2, turns: float = 5.0,
           coil_radius: float = 2e-3, pitch: float = 1e-3, force: float = 2e-6, release: float = 0.05,
           rho_inf: float = 1.0) -> Scene:
    """Seed figs. 3.18/3.19: a pre-stressed spiral spring (helical keratin fibre, 70 um) excited by
    an axial tip force that is switched off after ``release`` s; no gravity, root clamped. The force
    acts on the spring axis (the wire tip gets the force plus the torque that transfers it there)."""
    kap = helix_curvature(coil_radius, pitch)
    L = turns * 2 * np.pi * np.sqrt(coil_radius**2 + (pitch / (2 * np.pi)) ** 2)
    m = _hair(L, n_segments, natural_curvature=kap, root_direction=(1, 0, 0), root_normal=(0, 0, 1))
    axis = helix_axis(m.root_frame[0], kap)
    st = initial_state(m, frame_map="cayley")  # the solver below uses the box scheme in s
    # apply the force on the spring axis: add the torque that moves it from the wire tip to the axis
    centre = st.positions[0, 0] - coil_radius * m.root_frame[0][:, 1]  # principal normal is -d2
    tip = st.positions[0, -1]
    offset = (tip - centre) - np.dot(tip - centre, axis) * axis
    on = RodLoads(tip_force=force * axis, tip_torque=-np.cross(offset, force * axis))
    off = RodLoads()

    def schedule(t, state):
        return (on if t <= release + 1e-12 else off), RodBoundary()

    opts = RodSolverOptions(coefficients=GeneralizedAlpha.from_rho_inf(rho_inf, 1.0))
    return Scene("spiral", m, st, opts, dt, duration, schedule,
                 f"helical spring, {turns:g} turns, axial tip force {force:g} N released at {release:g} s (seed fig. 3.18)")


def loop(n_segments: int = 60, dt: float = 0.05, duration: float = 30.0, length: float = 0.45) -> Scene:
    """Seed fig. 3.17: a straight horizontal rod with a tip torque about d1 (ramped to 2 pi EI / L over
    the first third of the run, then held); no gravity. The static answer is a closed circle."""
    m = _hair(length, n_segments, root_direction=(1, 0, 0), root_normal=(0, 0, 1))
    EI = m.stiffness[0, 0]
    d1 = m.root_frame[0][:, 0]
    T0 = 2 * np.pi * EI / length

    def schedule(t, state):
        ramp = min(t / (duration / 3), 1.0)
        return RodLoads(tip_torque=ramp * T0 * d1), RodBoundary()

    opts = RodSolverOptions(coefficients=GeneralizedAlpha.from_rho_inf(0.0, 1.0))
    return Scene("loop", m, initial_state(m, frame_map=opts.resolved_frame_map), opts, dt, duration, schedule,
                 "straight rod, tip torque 2 pi EI / L: forms a loop (seed fig. 3.17)")


def buckling(n_segments: int = 40, dt: float = 4e-3, duration: float = 1.0, length: float = 0.10,
             shortening: float = 0.5, loop_writhe: float | None = 0.8) -> Scene:
    """Seed fig. 3.20: the tip moves towards the root along the rod axis (end-shortening
    ``shortening`` L over 75 % of the run, after a smooth start) while an axial torque (ramped to
    4 pi EI / L over the first 20 %) is applied; a small mid-span transverse force over the first
    10 % triggers the instability. Root clamped; the tip is guided: its position is prescribed (the
    seed's geometric boundary condition, solved inside Newton: tip mode "guided-position"), its
    tangent kept along the axis, its spin free under the prescribed axial moment.

    The rod first buckles into a spatial (helical) shape whose writhe grows smoothly with the
    shortening; at about 35 % the twisted rod snaps (the motion accelerates, seed: "the rod
    collapses and snaps into a loop") and its writhe jumps towards 1: a loop. With ``loop_writhe``
    set the run stops once the writhe (Klenin-Langowski, tails closed along the axis) reaches it,
    i.e. when the loop has formed (N = 40: at 36.8 % end-shortening, N = 80: 35.3 %). Beyond that
    the loop closes on itself: N = 40 measured, the strands cross 1.6 ms later at about 3 m/s, and
    the snap goes on to 10-80 m/s (the released twist energy on a 70 um fibre's tiny inertia, with no
    air drag). The model has no rod self-contact, so the rod would pass through itself (its link
    number jumps by 2)."""
    m = _hair(length, n_segments, root_direction=(1, 0, 0), root_normal=(0, 0, 1))
    EI = m.stiffness[0, 0]
    torque = 4 * np.pi * EI / length  # ~1.4x the clamped-clamped Greenhill moment 8.99 EI / L
    speed = shortening * length / (0.75 * duration)
    nn = m.n_nodes
    kick = np.zeros((1, nn, 3))
    kick[0, nn // 2, 2] = 1e-2 * EI / length**2 / m.segment_length[0]

    kap = np.zeros((m.n_nodes, 3))
    kap[:, 1] = 1.0 / length * np.sin(2 * np.pi * m.arc_length[0] / length)
    start = initial_state(m, kappa=kap, frame_map="cayley")  # box scheme in s (options below)
    tip_start = start.positions[0, -1].copy()
    x_start = float(tip_start[0])

    def target(t):
        a = 0.2 * duration
        b = 0.1 * duration  # velocity ramp
        if t <= a:
            return x_start
        if t <= a + b:
            return x_start - 0.5 * speed * (t - a) ** 2 / b
        return x_start - speed * (0.5 * b + t - a - b)

    def schedule(t, state):
        ramp = min(t / (0.2 * duration), 1.0)
        loads = RodLoads(tip_torque=np.array([ramp * torque, 0.0, 0.0]),
                         distributed_force=kick if t <= 0.1 * duration else None)
        goal = np.array([target(t), tip_start[1], tip_start[2]])
        return loads, RodBoundary(tip="guided-position", tip_position=goal)

    info = {"tip_path": lambda t: np.array([target(t), tip_start[1], tip_start[2]]), "torque": torque,
            "max_step_rotation": 0.1}
    if loop_writhe is not None:
        info["stop"] = lambda st: abs(writhe(st.positions[0], axis=(1.0, 0.0, 0.0))) >= loop_writhe
        info["stop_reason"] = f"the loop has formed (writhe >= {loop_writhe:g}); no rod self-contact beyond"
    opts = RodSolverOptions(coefficients=GeneralizedAlpha.from_rho_inf(0.0, 1.0))
    # an inextensible straight rod with both ends guided carries an indeterminate axial force
    # (singular Jacobian): start from a slightly bent (imperfect) rod (kap above)
    return Scene("buckling", m, start, opts, dt, duration, schedule,
                 "end-shortening plus axial torque: twist-to-writhe buckling into a loop (seed fig. 3.20)",
                 info=info)


def strand_stretch(n_segments: int = 100, dt: float = 2e-3, duration: float = 2.0, n_interpolated: int = 180,
                   stretch: float = 0.3, pull_time: float = 1.0, gravity: bool = True,
                   coefficients: GeneralizedAlpha | None = None) -> Scene:
    """Seed fig. 3.21: a 25 cm curly strand (guide fibre with kappa0 = 170 cos(2 pi s / 5 cm) /m, i.e.
    tangent swinging +-77 degrees about the hanging direction, plus ``n_interpolated`` fibres) hangs from its root; the guide's tip is pulled along -z at
    constant speed until the end-to-end distance has grown by ``stretch`` of the initial distance,
    then released (tip BC back to free). Default coefficients: the seed's alpha = 0.3, beta = 0,
    gamma = 0.7 in time (first order, numerically dissipative, so the strand settles), box in s."""
    L = 0.25
    k0 = sinusoidal_curvature(n_segments, L, 170.0, 0.05, component=0, phase=np.pi / 2)
    m = _hair(L, n_segments, natural_curvature=k0, root_direction=(0, 0, -1), root_normal=(1, 0, 0))
    coefficients = coefficients or GeneralizedAlpha(0.3, 0.0, 0.7, 0.5, 0.5, 0.5)
    opts = RodSolverOptions(coefficients=coefficients)
    st = initial_state(m, frame_map=opts.resolved_frame_map)
    d0 = float(np.linalg.norm(st.positions[0, -1] - st.positions[0, 0]))
    ramp = 0.2 * pull_time  # smooth start: an inextensible rod cannot take a velocity jump
    speed = stretch * d0 / (pull_time - 0.5 * ramp)
    g = GRAVITY if gravity else np.zeros(3)

    def schedule(t, state):
        if t <= pull_time + 1e-12:
            v = speed * min((t - 0.5 * dt) / ramp, 1.0)
            return RodLoads(gravity=g), RodBoundary(tip="velocity", tip_velocity=np.array([0.0, 0.0, -v]))
        return RodLoads(gravity=g), RodBoundary()

    strand = make_strand(n_interpolated, 1.5e-3, m.n_nodes, tip_radius=0.5e-3, winding=20.0)
    return Scene("strand-stretch", m, st, opts, dt, duration, schedule,
                 f"curly 25 cm strand stretched by {stretch:.0%} and released (seed fig. 3.21)", strand)


def moving_support(n_segments: int = 100, dt: float = 2e-3, duration: float = 2.0, n_interpolated: int = 180,
                   arc_radius: float = 0.30, arc_angle: float = np.pi / 4, period: float = 1.0) -> Scene:
    """Seed fig. 3.24: the strand hangs under gravity from a support that moves at constant speed up
    and down along a 45 degree arc of radius 30 cm (a rigid arm rotating about the y axis through the
    arc centre); velocity BC at the root (v = W x (r - c), omega = W)."""
    L = 0.25
    k0 = sinusoidal_curvature(n_segments, L, 170.0, 0.05, component=0, phase=np.pi / 2)
    center = np.array([0.0, 0.0, 0.0])
    root0 = center + arc_radius * np.array([1.0, 0.0, 0.0])
    m = _hair(L, n_segments, natural_curvature=k0, root_position=root0, root_direction=(0, 0, -1), root_normal=(1, 0, 0))
    rate = 2 * arc_angle / period  # rad/s, up for half a period, down for the other half
    axis = np.array([0.0, -1.0, 0.0])  # positive rate lifts the support (x -> z)

    def angle(t):
        ph = (t % period) / period
        return rate * period * (ph if ph < 0.5 else 1.0 - ph)

    def schedule(t, state):
        # angular velocity of the arm over the step ending at t (constant speed, reversing at the ends)
        ph = ((t - 1e-12) % period) / period
        W = (rate if ph < 0.5 else -rate) * axis
        a = angle(t - 0.5 * dt)
        r = center + arc_radius * np.array([np.cos(a), 0.0, np.sin(a)])
        return RodLoads(gravity=GRAVITY), RodBoundary(root_velocity=np.cross(W, r - center), root_angular_velocity=W)

    opts = RodSolverOptions(coefficients=GeneralizedAlpha.from_rho_inf(0.5, 1.0))
    strand = make_strand(n_interpolated, 1.5e-3, m.n_nodes, tip_radius=0.5e-3, winding=20.0)
    return Scene("moving-support", m, initial_state(m, frame_map=opts.resolved_frame_map), opts, dt, duration, schedule,
                 "strand under gravity on a support moving along a 45 degree arc of radius 30 cm (seed fig. 3.24)",
                 strand, info={"support_angle": angle, "arc_centre": center, "arc_radius": arc_radius})


SCENES = {
    "cantilever": cantilever,
    "precurved": precurved,
    "helix": helix,
    "spiral": spiral,
    "loop": loop,
    "buckling": buckling,
    "strand-stretch": strand_stretch,
    "moving-support": moving_support,
}


def build_scene(name: str, **kw) -> Scene:
    """Scene by name (see ``SCENES``); keyword arguments go to its builder."""
    if name not in SCENES:
        raise ParameterError(f"unknown scene {name!r}; known: {sorted(SCENES)}")
    return SCENES[name](**kw)


def _advance(solver, scene, st, dt, halvings_left):
    """One step of ``dt``; if Newton fails, or the step turns some cross-section by more than
    ``scene.info["max_step_rotation"]`` rad (max |omega| dt; an accuracy limit for snap-throughs),
    two half steps instead (recursively, at most ``halvings_left`` times). A (sub)step after which
    ``scene.info["stop"](state)`` holds ends the step there.
    Returns (state, mean Newton iterations per (sub)step, stopped)."""
    loads, boundary = scene.schedule(st.time + dt, st)
    limit = scene.info.get("max_step_rotation")
    stop = scene.info.get("stop")
    try:
        new, rep = solver.step(scene.model, st, dt, loads, boundary)
        if limit is None or halvings_left <= 0 or np.abs(new.x[:, :, 3:6]).max() * dt <= limit:
            return new, float(rep.iterations.mean()), stop is not None and bool(stop(new))
    except ConvergenceError:
        if halvings_left <= 0:
            raise
    mid, a, stopped = _advance(solver, scene, st, 0.5 * dt, halvings_left - 1)
    if stopped:
        return mid, a, True
    end, b, stopped = _advance(solver, scene, mid, 0.5 * dt, halvings_left - 1)
    return end, 0.5 * (a + b), stopped


def run_scene(scene: Scene, record_every: int = 1, progress: Callable[[int, int], None] | None = None,
              interpolate: bool = True, max_halvings: int = 6) -> Trajectory:
    """Integrate a scene; record every ``record_every`` steps (and the last). A step whose Newton
    solve fails is retried as two half steps (at most ``max_halvings`` levels), for fast snap-throughs.
    If ``scene.info["stop"](state)`` is true after a (sub)step, the run ends there (recorded)."""
    solver = ImplicitRodSolver(scene.options)
    st = scene.state
    n = scene.n_steps
    times, pos, curv, kin, its, interp = [st.time], [st.positions], [st.x[:, :, 6:9]], [kinetic_energy(scene.model, st)], [], []
    arc = scene.model.arc_length[0]

    def _interp(state):
        if scene.strand is not None and interpolate:
            interp.append(interpolate_strand(scene.strand, state.positions[0], state.frames[0], arc))

    _interp(st)
    s_t, s_tip, s_kin = [st.time], [st.tip_position], [kin[0]]
    for i in range(1, n + 1):
        st, it, done = _advance(solver, scene, st, scene.dt, max_halvings)
        its.append(it)
        s_t.append(st.time)
        s_tip.append(st.tip_position)
        s_kin.append(kinetic_energy(scene.model, st))
        if i % record_every == 0 or i == n or done:
            times.append(st.time)
            pos.append(st.positions)
            curv.append(st.x[:, :, 6:9])
            kin.append(kinetic_energy(scene.model, st))
            _interp(st)
        if progress is not None:
            progress(n if done else i, n)
        if done:
            break
    return Trajectory(np.array(times), np.array(pos), np.array(curv), np.array(kin), np.array(its), st,
                      np.array(interp) if interp else None, np.array(s_t), np.array(s_tip), np.array(s_kin))
