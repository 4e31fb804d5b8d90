"""Algorithm 2 of Sobottka (2008, §4.5): charge a fibre assembly and find its static equilibrium.

    for h = 1..n:  x <- particles(C), q <- q + dq_h, F <- Coulomb(x, q) + scalp(x, q),
                   C <- static equilibrium of every fibre under gravity and the dead loads F

* ``schedule="incremental"``: n increments that decrease logarithmically,
  dq_h = Q [ln(1 + h) - ln h] / ln(1 + n) (they sum to Q exactly); within every increment the
  force evaluation and the equilibrium are repeated until the configuration is self-consistent
  (the max node motion of a pass is below ``tolerance`` times the max node displacement from the
  uncharged configuration, plus 1e-9 m; at most ``inner_iterations`` passes; the forces of the next
  pass are taken at the new configuration). The default 1e-3 matches three-digit forces: an
  approximate Coulomb method (treecode, FMM) makes the loads noisy at its error level.
* ``schedule="one-shot"``: the full charge at once, forces from the uncharged configuration and
  one equilibrium (the seed's n = 1; ``one_shot_iterations`` > 1 makes it self-consistent too).

The material (E_B, G, weight rho A, diameter) comes from the property database at (T, RH) through
:func:`headsim.hair.electrostatics.scenes` (Alg. 2 line 3). The rod energy minimisation is
:func:`headsim.hair.electrostatics.equilibrium.fibre_equilibrium` (eq. 3.135, dead loads in the
global frame).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from headsim.errors import DivergenceError, ParameterError
from headsim.hair.electrostatics.charges import ChargeSampling, sample_charges
from headsim.hair.electrostatics.coulomb import CoulombOptions, coulomb_forces
from headsim.hair.electrostatics.equilibrium import fibre_equilibrium
from headsim.hair.electrostatics.scalp import DEFAULT_CLAMP, scalp_forces
from headsim.hair.electrostatics.treecode import Treecode
from headsim.hair.electrostatics.units import SEED_LINE_CHARGE_STATC_PER_CM, SEED_PARTICLES_PER_CM, \
    per_cm_to_per_m, statc_per_cm_to_c_per_m
from headsim.solvers.rods import RodModel

__all__ = ["ChargingOptions", "ChargingResult", "charge_schedule", "equilibrate", "charge_fibres"]


def charge_schedule(steps: int) -> np.ndarray:
    """(n,) increments as fractions of Q, logarithmically decreasing: [ln(1+h) - ln h] / ln(1+n)."""
    n = int(steps)
    if n < 1:
        raise ParameterError(f"need at least one charging step, got {steps}")
    h = np.arange(1, n + 1, dtype=float)
    return (np.log1p(h) - np.log(h)) / np.log1p(n)


@dataclass(frozen=True)
class ChargingOptions:
    """line_charge C/m (default the seed's -7.7e-4 statC/cm); particle_density per m (330 /cm);
    steps n; schedule 'incremental' | 'one-shot'; scalp_charge C (Q_S) and scalp_clamp m;
    gravity m/s^2; inner_iterations and tolerance (relative) of the self-consistency per increment;
    one_shot_iterations (1 = the seed's literal one-shot); relaxation: the first under-relaxation
    factor w of the nodal loads between self-consistency passes, F <- F + w (F(x) - F), adapted by
    Aitken's rule afterwards (the first pass of an increment takes the new charge's forces in full);
    coulomb: the force method."""

    line_charge: float = statc_per_cm_to_c_per_m(SEED_LINE_CHARGE_STATC_PER_CM)
    particle_density: float = per_cm_to_per_m(SEED_PARTICLES_PER_CM)
    steps: int = 8
    schedule: str = "incremental"
    scalp_charge: float = 0.0
    scalp_clamp: float = DEFAULT_CLAMP
    gravity: tuple = (0.0, -9.81, 0.0)
    inner_iterations: int = 20
    tolerance: float = 1e-3
    one_shot_iterations: int = 1
    relaxation: float = 0.5
    coulomb: CoulombOptions = field(default_factory=CoulombOptions)

    def __post_init__(self):
        if self.schedule not in ("incremental", "one-shot"):
            raise ParameterError(f"schedule must be 'incremental' or 'one-shot', got {self.schedule!r}")
        if not np.isfinite(self.line_charge):
            raise ParameterError("line charge must be finite (C/m)")
        if abs(self.line_charge) > 1e-6:
            raise ParameterError(f"line charge {self.line_charge} C/m is implausible for hair "
                                 "(did you pass statC/cm or another unit? convert with units.statc_per_cm_to_c_per_m)")
        if not (self.particle_density > 0 and np.isfinite(self.particle_density)):
            raise ParameterError("particle density must be positive (per m)")
        if self.steps < 1 or self.inner_iterations < 1 or self.one_shot_iterations < 1:
            raise ParameterError("steps and iteration counts must be >= 1")
        if not (0.0 < self.relaxation <= 1.0):
            raise ParameterError(f"relaxation must lie in (0, 1], got {self.relaxation}")
        if not (self.tolerance > 0):
            raise ParameterError("tolerance must be > 0 (relative)")
        if len(self.gravity) != 3 or not np.isfinite(self.gravity).all():
            raise ParameterError("gravity must be a finite 3-vector, m/s^2")


@dataclass(frozen=True, eq=False)
class ChargingResult:
    """positions_before/after (F, N+1, 3) m (before: gravity equilibrium without charge);
    kappa (F, N, 3) 1/m; particles (n, 3) m and charges (n,) C at the end; coulomb_forces,
    scalp_forces (n, 3) N; node_forces (F, N+1, 3) N; history: one dict per increment."""

    positions_before: np.ndarray
    positions_after: np.ndarray
    kappa: np.ndarray
    sampling: ChargeSampling
    particles: np.ndarray
    charges: np.ndarray
    coulomb_forces: np.ndarray
    scalp_forces: np.ndarray
    node_forces: np.ndarray
    history: list
    converged: bool

    @property
    def field_at_particles(self) -> np.ndarray:
        """(n,) V/m: |F| / |q| of the Coulomb force (the seed's E = F/q)."""
        return np.linalg.norm(self.coulomb_forces, axis=1) / np.abs(self.charges)


def equilibrate(model: RodModel, gravity, node_forces=None, kappa=None):
    """Static equilibrium of all fibres: (kappa (F, N, 3), positions (F, N+1, 3), Newton iterations)."""
    F, N = model.n_fibres, model.n_segments
    kap = np.empty((F, N, 3))
    pos = np.empty((F, N + 1, 3))
    its = 0
    same = {}  # without nodal loads, fibres that differ only by their root position share the shape
    for f in range(F):
        if node_forces is None and kappa is None:
            key = b"".join(np.ascontiguousarray(a[f]).tobytes() for a in (
                model.length, model.rho_area, model.stiffness, model.natural_curvature, model.root_frame))
            if key in same:
                g = same[key]
                kap[f] = kap[g]
                pos[f] = pos[g] - model.root_position[g] + model.root_position[f]
                continue
            same[key] = f
        k, r, it = fibre_equilibrium(model, f, gravity, None if node_forces is None else node_forces[f],
                                     None if kappa is None else kappa[f])
        kap[f], pos[f] = k, r
        its += it
    if not np.isfinite(pos).all():
        raise DivergenceError("static equilibrium produced non-finite positions")
    return kap, pos, its


def _forces(sampling, pos, q, options, scalp, tree):
    x = sampling.positions(pos)
    fc = coulomb_forces(x, q, options.coulomb, tree=tree)
    fs = scalp_forces(x, q, scalp, options.scalp_charge, options.scalp_clamp)
    if not (np.isfinite(fc).all() and np.isfinite(fs).all()):
        raise DivergenceError("non-finite electrostatic forces (coincident charges?)")
    return x, fc, fs


def charge_fibres(model: RodModel, options: ChargingOptions = ChargingOptions(), scalp=None,
                  progress: Callable[[int, int, dict], None] | None = None, initial_kappa=None) -> ChargingResult:
    """Run Algorithm 2 on all fibres of ``model``; ``scalp`` is a distance field (or None)."""
    g = tuple(float(v) for v in options.gravity)
    kap, pos, _ = equilibrate(model, g, None, initial_kappa)
    before = pos.copy()
    sampling = sample_charges(model.length, model.n_segments, options.particle_density)
    q_full = sampling.charges(options.line_charge)
    if options.schedule == "incremental":
        increments = charge_schedule(options.steps)
        passes = options.inner_iterations
    else:
        increments = np.ones(1)
        passes = options.one_shot_iterations
    tree = None
    if options.coulomb.method == "treecode":
        tree = Treecode(sampling.positions(pos), q_full * increments[0], options.coulomb.treecode_options)
    frac = 0.0
    history = []
    converged = True
    total = len(increments)
    x = fc = fs = nodal = None
    for h, dq in enumerate(increments, start=1):
        frac += dq
        q = q_full * frac
        t0 = time.perf_counter()
        moved = np.inf
        n_pass = 0
        newton = 0
        while n_pass < passes:
            x, fc, fs = _forces(sampling, pos, q, options, scalp, tree)
            new_loads = sampling.node_forces(fc + fs)
            if n_pass == 0 or nodal is None:
                nodal = new_loads
                resid_old = None
                omega = options.relaxation
            else:
                resid = new_loads - nodal
                if resid_old is not None:  # Aitken's dynamic relaxation (Irons & Tuck 1969)
                    dr = resid - resid_old
                    dd = float(np.sum(dr * dr))
                    if dd > 0:
                        omega = float(np.clip(-omega * np.sum(resid_old * dr) / dd, 0.05, 1.0))
                nodal = nodal + omega * resid
                resid_old = resid
            kap, new, its = equilibrate(model, g, nodal, kap)
            newton += its
            moved = float(np.abs(new - pos).max())
            pos = new
            n_pass += 1
            limit = options.tolerance * float(np.abs(pos - before).max()) + 1e-9
            if moved < limit:
                break
        if passes > 1 and moved >= limit:
            converged = False
        info = {"step": h, "charge_fraction": float(frac), "increment": float(dq), "passes": n_pass,
                "last_motion_m": moved, "motion_limit_m": limit, "newton_iterations": newton,
                "seconds": time.perf_counter() - t0}
        history.append(info)
        if progress is not None:
            progress(h, total, info)
    x, fc, fs = _forces(sampling, pos, q_full, options, scalp, tree)
    return ChargingResult(before, pos, kap, sampling, x, q_full, fc, fs, sampling.node_forces(fc + fs), history,
                          converged)
