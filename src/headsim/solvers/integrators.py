"""Time integration and quasi-static equilibrium for the mass-spring and FEM models.

Model / State / Solver: a model (:class:`~headsim.solvers.massspring.MassSpringModel` or
:class:`~headsim.solvers.fem.FemModel`) is what a solve never changes; a
:class:`~headsim.solvers.state.BodyState` is what a step changes; the integrators below take
algorithm options only and return a new state (the input is untouched).

- :class:`ExplicitEuler` -- the seed's baseline, Heinze eqs. 3.1-3.2: all forces from the old state,
  v' = v + dt F/m and x' = x + dt v (old velocity), written into new buffers.
- :class:`SymplecticEuler` -- x' = x + dt v' (semi-implicit Euler).
- :class:`ImplicitEuler` -- backward Euler as the minimisation of the incremental potential
  |x - x_n - dt v_n|_M^2 / (2 dt^2) + E(x) + dampers + contact energy, by Newton's method with a line
  search (:mod:`headsim.solvers.newton`), v' = (x' - x_n) / dt.
- :func:`solve_quasi_static` (in :mod:`headsim.solvers.contact`) -- no inertia: minimise elastic +
  contact + external energy.

Stability (Heinze eqs. 3.3-3.6): on x' = -k x explicit Euler multiplies the error by (1 - k dt) per
step, so it oscillates for dt > 1/k and diverges for dt > 2/k; backward Euler divides by (1 + k dt)
and is stable for every dt. For a mass-spring network the limit is dt < 2 / omega_max
(:func:`critical_time_step`).

Divergence (non-finite values, a point jumping farther than the body's size in one step, inverted
tets) is detected after every step and raised as :class:`headsim.errors.DivergenceError` naming the
step, the time and the likely cause.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol, Sequence

import numpy as np
import scipy.sparse as sp

from headsim.errors import ConvergenceError, DivergenceError, ParameterError
from headsim.solvers.newton import NewtonOptions, minimize_newton, rigid_body_modes
from headsim.solvers.state import BodyState

ForceCallback = Callable[[np.ndarray, np.ndarray], np.ndarray]


class ElasticModel(Protocol):
    """What the integrators need from a model (both MassSpringModel and FemModel provide it)."""

    rest_positions: np.ndarray  # (n, 3) m
    mass: np.ndarray  # (n,) kg
    fixed: np.ndarray  # (n,) bool
    external_force: np.ndarray  # (n, 3) N

    def forces(self, positions: np.ndarray, velocities: np.ndarray) -> np.ndarray: ...
    def energy(self, positions: np.ndarray) -> float: ...
    def gradient(self, positions: np.ndarray) -> np.ndarray: ...
    def hessian(self, positions: np.ndarray, project: bool = True) -> sp.csr_matrix: ...
    def damping_matrix(self, positions: np.ndarray) -> sp.csr_matrix: ...
    def check_state(self, positions: np.ndarray) -> str | None: ...


def lowest_angular_frequency(model: ElasticModel) -> float:
    """Lowest angular frequency ω_min (rad/s) of the supported model at rest: the smallest eigenvalue
    of K v = ω² M v over the free degrees of freedom (shift-invert Lanczos). ln(1/tol) / ω_min is the
    settling time of an explicit loop's slowest, critically damped mode (used by the benchmarks to
    extrapolate the seed-faithful loop)."""
    import scipy.sparse.linalg as spla

    free = np.flatnonzero(np.repeat(~model.fixed, 3))
    k = model.hessian(model.rest_positions).tocsc()[free][:, free]
    m = np.repeat(model.mass, 3)[free]
    vals = spla.eigsh(k, k=1, M=sp.diags(m).tocsc(), sigma=0.0, which="LM", return_eigenvectors=False)
    return float(np.sqrt(max(vals[0], 1e-300)))


def critical_time_step(model: ElasticModel) -> float:
    """Upper bound-based estimate of the explicit stability limit (2 / omega_max without damping), s.

    omega_max^2 <= max_i sum_j |K_ij| / m_i (Gershgorin on M^-1 K over the free dofs, at rest), so the returned dt is a
    safe (slightly conservative) limit. For one spring on a unit mass this is the seed's dt < 2/k.
    """
    free = ~np.asarray(model.fixed)
    if not free.any():
        return np.inf
    dofs = np.flatnonzero(np.repeat(free, 3))
    k = model.hessian(model.rest_positions, project=True).tocsr()[dofs][:, dofs]
    rows = np.asarray(abs(k).sum(axis=1)).ravel().reshape(-1, 3).max(axis=1)
    omega2 = float(np.max(rows / model.mass[free]))
    c = model.damping_matrix(model.rest_positions).tocsr()[dofs][:, dofs]
    crow = np.asarray(abs(c).sum(axis=1)).ravel().reshape(-1, 3).max(axis=1)
    gamma = float(np.max(crow / model.mass[free])) if c.nnz else 0.0
    if omega2 <= 0:
        return 4.0 / (2.0 * gamma) if gamma > 0 else np.inf
    # damped oscillator x'' + 2 zeta omega x' + omega^2 x = 0 with gamma = c/m: stable for
    # omega^2 dt^2 + 2 gamma dt < 4 (both explicit schemes); gamma = 0 gives 2 / omega
    return float((-gamma + np.sqrt(gamma**2 + 4.0 * omega2)) / omega2)


def _body_size(model: ElasticModel) -> float:
    x = model.rest_positions
    return float(np.linalg.norm(x.max(axis=0) - x.min(axis=0))) or 1.0


def check_divergence(model: ElasticModel, old: BodyState, new_positions: np.ndarray, new_velocities: np.ndarray,
                     dt: float, max_jump: float = 0.5) -> None:
    """Raise DivergenceError if the new state is unusable.

    Non-finite values; a point moving, or about to move (|v| dt), more than ``max_jump`` x the body
    size in one step (the seed's "mass points jump away", eq. 3.6); inverted tets (FEM).
    """
    step = old.step + 1
    where = f"step {step} (t = {old.time + dt:.4g} s, dt = {dt:g} s)"

    def hint() -> str:  # only when raising: the estimate assembles the stiffness matrix
        try:
            dt_crit = critical_time_step(model)
        except Exception:  # noqa: BLE001 - the estimate only decorates the message
            dt_crit = float("nan")
        return (f"; the explicit stability limit of this model is about dt < {dt_crit:.3g} s: reduce dt, soften "
                "the springs, or use ImplicitEuler / solve_quasi_static")

    if not (np.isfinite(new_positions).all() and np.isfinite(new_velocities).all()):
        raise DivergenceError(f"non-finite positions or velocities at {where}{hint()}")
    jump = float(np.max(np.linalg.norm(new_positions - old.positions, axis=1)))
    size = _body_size(model)
    if jump > max_jump * size:
        raise DivergenceError(f"energy blow-up at {where}: a point moved {jump:.3g} m in one step "
                              f"(body size {size:.3g} m){hint()}")
    speed = float(np.max(np.linalg.norm(new_velocities, axis=1)))
    if speed * dt > max_jump * size:
        raise DivergenceError(f"energy blow-up at {where}: speed {speed:.3g} m/s would carry a point "
                              f"{speed * dt:.3g} m in one step (body size {size:.3g} m){hint()}")
    reason = model.check_state(new_positions)
    if reason is not None:
        raise DivergenceError(f"{reason} at {where}{hint()}")


@dataclass(frozen=True)
class ExplicitEuler:
    """Heinze eqs. 3.1-3.2 (forward Euler): forces from the old state, new values into new buffers.

    max_jump : divergence threshold, fraction of the body size a point may move in one step.
    """

    max_jump: float = 0.5

    def step(self, model: ElasticModel, state: BodyState, dt: float,
             extra_forces: ForceCallback | None = None) -> BodyState:
        """One step; ``extra_forces(x, v) -> (n, 3) N`` adds e.g. the collision force (eq. 2.2)."""
        if not dt > 0:
            raise ParameterError(f"dt must be > 0 s, got {dt}")
        f = model.forces(state.positions, state.velocities)
        if extra_forces is not None:
            f = f + extra_forces(state.positions, state.velocities)
        a = f / model.mass[:, None]
        v_new = state.velocities + dt * a  # eq. 3.1
        x_new = state.positions + dt * state.velocities  # eq. 3.2 (old velocity)
        v_new[model.fixed] = 0.0
        x_new[model.fixed] = state.positions[model.fixed]
        check_divergence(model, state, x_new, v_new, dt, self.max_jump)
        return BodyState(x_new, v_new, state.time + dt, state.step + 1)


@dataclass(frozen=True)
class SymplecticEuler:
    """Semi-implicit Euler: v' = v + dt F(x, v)/m, x' = x + dt v'."""

    max_jump: float = 0.5

    def step(self, model: ElasticModel, state: BodyState, dt: float,
             extra_forces: ForceCallback | None = None) -> BodyState:
        if not dt > 0:
            raise ParameterError(f"dt must be > 0 s, got {dt}")
        f = model.forces(state.positions, state.velocities)
        if extra_forces is not None:
            f = f + extra_forces(state.positions, state.velocities)
        v_new = state.velocities + dt * f / model.mass[:, None]
        v_new[model.fixed] = 0.0
        x_new = state.positions + dt * v_new
        check_divergence(model, state, x_new, v_new, dt, self.max_jump)
        return BodyState(x_new, v_new, state.time + dt, state.step + 1)


class EnergyTerm(Protocol):
    """An extra potential (contact, ...) for the Newton-based solvers, e.g. contact.PlaneContact.

    energy(x (n, 3), u (r,)) -> J; gradient(x, u) -> ((n, 3) N, (r,) N); hessian(x, u) -> (3n + r,
    3n + r) PSD sparse; update(x, u) refreshes lagged data (active set, directions) between Newton
    solves and returns True if anything changed. u are rigid-driver unknowns (empty in dynamics).
    """

    def energy(self, positions: np.ndarray, u: np.ndarray) -> float: ...
    def gradient(self, positions: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...
    def hessian(self, positions: np.ndarray, u: np.ndarray) -> sp.csr_matrix: ...
    def update(self, positions: np.ndarray, u: np.ndarray) -> bool: ...


@dataclass(frozen=True)
class ImplicitEuler:
    """Backward Euler by Newton on the incremental potential (any dt is stable).

    newton : options of the inner Newton solve (force tolerance defaults to 1e-9 x the weight scale)
    max_contact_updates : lagged contact data is refreshed and the step re-solved up to this often
    """

    newton: NewtonOptions = NewtonOptions(relative_tolerance=1e-9, try_exact_hessian=True)
    max_contact_updates: int = 5
    max_jump: float = 0.5

    def step(self, model: ElasticModel, state: BodyState, dt: float,
             terms: Sequence[EnergyTerm] = (), amg_cache: dict | None = None) -> BodyState:
        """One step; ``amg_cache``: a dict kept by the caller to reuse the AMG hierarchy across steps
        (it is always reused across the contact updates of one step). Contact terms with friction are
        anchored at the start of the step (the slip of a step is the tangential motion during it)."""
        if not dt > 0:
            raise ParameterError(f"dt must be > 0 s, got {dt}")
        x0 = state.positions
        n = len(x0)
        m3 = np.repeat(model.mass, 3)
        xt = (x0 + dt * state.velocities).ravel()
        dmat = model.damping_matrix(x0)
        free = np.repeat(~np.asarray(model.fixed), 3)
        no_u = np.zeros(0)  # contact terms take driver unknowns; dynamics has none
        for t in terms:
            if hasattr(t, "start"):
                t.start(x0, no_u)
            t.update(x0, no_u)
        cache = {} if amg_cache is None else amg_cache

        def energy(z):
            x = z.reshape(n, 3)
            dz = z - xt
            dx = z - x0.ravel()
            e = 0.5 * float(dz @ (m3 * dz)) / dt**2 + model.energy(x) + 0.5 * float(dx @ (dmat @ dx)) / dt
            return e + sum(t.energy(x, no_u) for t in terms)

        def gradient(z):
            x = z.reshape(n, 3)
            g = m3 * (z - xt) / dt**2 + model.gradient(x).ravel() + (dmat @ (z - x0.ravel())) / dt
            for t in terms:
                g = g + t.gradient(x, no_u)[0].ravel()
            return g

        def hessian(z, project=True):
            x = z.reshape(n, 3)
            h = model.hessian(x, project=project) + sp.diags(m3 / dt**2) + dmat / dt
            for t in terms:
                h = h + t.hessian(x, no_u)
            return h

        # force scale of this step: inertia, elastic + external forces at the start
        scale = max(float(np.max(np.abs(m3 * state.velocities.ravel() / dt))),
                    float(np.max(np.abs(model.gradient(x0)[~np.asarray(model.fixed)]))) if (~np.asarray(model.fixed)).any()
                    else 0.0, float(np.max(np.abs(model.external_force))))
        newton = self.newton
        if newton.force_tolerance is None and scale > 0:
            newton = NewtonOptions(**{**newton.__dict__, "force_tolerance": 1e-9 * scale})
        z = x0.ravel().copy()
        for _ in range(self.max_contact_updates):
            try:
                res = minimize_newton(energy, gradient, hessian, z, free, newton,
                                      near_null=lambda zz: rigid_body_modes(zz.reshape(n, 3)),
                                      what=f"implicit Euler step {state.step + 1}", amg_cache=cache)
            except ConvergenceError as e:
                raise DivergenceError(f"{e}; likely cause: dt = {dt:g} s too large for the contact "
                                      "stiffness or an inverted element") from e
            z = res.z
            if not any([t.update(z.reshape(n, 3), no_u) for t in terms]):
                break
        x_new = z.reshape(n, 3)
        v_new = (x_new - x0) / dt
        v_new[model.fixed] = 0.0
        check_divergence(model, state, x_new, v_new, dt, self.max_jump)
        return BodyState(x_new, v_new, state.time + dt, state.step + 1)


def simulate(integrator, model: ElasticModel, state: BodyState, dt: float, n_steps: int,
             progress: Callable[[int], None] | None = None, **step_kwargs) -> list[BodyState]:
    """Run ``n_steps`` steps; returns the list of states (initial included)."""
    states = [state]
    for i in range(n_steps):
        state = integrator.step(model, state, dt, **step_kwargs)
        states.append(state)
        if progress is not None:
            progress(i + 1)
    return states
