"""Volume injection into a marked face region by PBD (Monkin 2016, seed 001, §4.3, §5.2–5.3).

:func:`prepare_graft` builds what the seed's module keeps between runs (closed region model, fixed
vertices, initial area and volume); :func:`inject_volume` raises the volume constraint's target by the
injected volume and relaxes the closed model with PBD to the stop rule; the result is a copy of the whole
face with the region's vertices replaced.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Callable

import numpy as np

from headsim.errors import ConvergenceError, ParameterError
from headsim.graft.region import ClosedRegion, FaceRegion, close_region
from headsim.mesh.surface import SurfaceMesh
from headsim.solvers.pbd import STANDARD_GRAVITY, PBDModel, PBDOptions, PBDSolver, PBDState, SolveInfo

__all__ = ["GraftOptions", "GraftSetup", "GraftResult", "prepare_graft", "inject_volume", "graft_pbd_options",
           "graft_problem", "warm_start_positions"]


@dataclass(frozen=True)
class GraftOptions:
    """Parameters of one injection (seed step 3) and of its PBD solve.

    areal_density : kg/m², mass of the region per area (region mass = areal_density × area, spread over
        the particles by area, Monkin §4.2); it only matters with gravity or hydrostatic pressure
    gravity : apply gravity (−y, the bundled faces' "down"; the seed notes it shifts the result slightly)
    fluid_density : kg/m³, hydrostatic pressure of the injected fat (Monkin §4.3: 600–1000); 0 = off
    closure : "centroid" or "mirror" (Monkin §5.3)
    method : distance-constraint solver, "gauss_seidel" (coloured) or "jacobi"
    xpbd : XPBD compliance (iteration-count independent stiffness) instead of PBD stiffness 1
    edge_compliance : m/N, XPBD compliance of the edge springs; None = ``spring_softness`` × dt² / mean
        particle mass. The equilibrium shape does not depend on it (linear springs at their initial
        lengths plus a volume constraint: scaling all stiffnesses scales only the pressure); it sets how
        fast and how exactly the solve gets there: stiff springs (softness ≪ 1) make XPBD behave like PBD,
        whose fixed point then depends on the iteration scheme
    spring_softness : dimensionless compliance / dt² × mass, used when edge_compliance is None
    dt : s; iterations : per step; damping : in [0, 1] (Monkin §4.4). Defaults chosen by measurement
        (benchmarks/bench_graft.py): 2 sweeps per step and damping 0.05 reach 0.1 mm of the equilibrium
        with half the sweeps of 4 sweeps and damping 0.1; damping 0 does not settle
    loaded_iterations : sweeps per step used instead of ``iterations`` when gravity or hydrostatic pressure
        is on. The rest state of XPBD is the force balance only when the sweeps of a step converge; with
        external forces every step first moves the region by a·dt² and 2 sweeps do not undo it, so the steps
        cycle or settle on a dt- and sweep-dependent shape. Measured on the bundled cheek (5 cm³, 900 kg/m³,
        edge_compliance 0.1 m/N): 200 and 800 sweeps give the same surface (5.59 mm sag); with stiff springs
        (1e-3 m/N) 50 → 200 sweeps still change it (0.72 → 0.29 mm), i.e. stiff nets need more sweeps
    stop_tolerance : Monkin §4.4 stop rule, as a fraction of the region's mean edge length: stop when the
        change of Σ|x| over a step is below stop_tolerance × mean edge length × number of particles
        (scaling with the edge length keeps the rule equally strict on refined meshes)
    stop_patience : consecutive steps the stop rule must hold (the change of Σ|x| crosses zero whenever
        the motion turns; with 1, the seed's rule, it stopped 0.35–1 mm short of the equilibrium)
    max_steps : step budget
    stabilisation_iterations : projections without velocity update first (Monkin §4.4)
    require_convergence : raise ConvergenceError when max_steps is reached before the stop rule holds
    parallel : Numba-parallel kernels (a gain only with free cores)
    acceleration : "anderson" (default) finds the PBD rest state by Anderson acceleration of the step-from-
        rest map (:mod:`headsim.solvers.pbd_anderson`: same constraints, same fixed points, stop rule
        Σ|Φ(x) - x| < anderson_tolerance × mean edge × n); "none" is the seed's damped time stepping with the
        Σ|x| rule. Measured (benchmarks/bench_graft.py): Anderson needs 2–3× fewer steps; on the 9,400-vertex
        region it may end on another of the nearby equilibria (0.15 mm Hausdorff from the time-stepped one)
    anderson_history : residuals combined by Anderson acceleration
    anderson_tolerance : stop rule of the Anderson solve as a fraction of the mean edge length: stop when
        Σ|Φ(x) - x| < anderson_tolerance × mean edge × n. Measured (benchmarks/bench_graft.py): 1e-5 ends
        within 0.03 mm of the tightly converged fixed point (2,400 and 9,400 vertices), as close as the seed's
        rule with ``stop_tolerance`` 3e-6 gets to its own (0.05 mm on 9,400 vertices)
    warm_start : start PBD from a bulge of the right volume (:func:`warm_start_positions`) instead of the
        flat region (the seed's start). Off by default: measured (benchmarks/bench_graft.py) it does not
        save steps on the 2,400-vertex region, and on the 9,400-vertex one it did not come within 0.1 mm
        of the flat-start equilibrium in 20,000 steps (the spring net + volume problem is not convex, so
        the start may select the equilibrium)
    """

    areal_density: float = 10.0
    gravity: bool = False
    fluid_density: float = 0.0
    closure: str = "centroid"
    method: str = "gauss_seidel"
    xpbd: bool = True
    edge_compliance: float | None = None
    spring_softness: float = 1.5
    dt: float = 1e-2
    iterations: int = 2
    loaded_iterations: int = 200
    damping: float = 0.05
    stop_tolerance: float = 3e-6
    stop_patience: int = 20
    max_steps: int = 20_000
    stabilisation_iterations: int = 0
    require_convergence: bool = True
    parallel: bool = False
    acceleration: str = "anderson"
    anderson_history: int = 8
    anderson_tolerance: float = 1e-5
    warm_start: bool = False

    def __post_init__(self):
        if not (self.areal_density > 0 and math.isfinite(self.areal_density)):
            raise ParameterError(f"areal_density must be > 0 kg/m², got {self.areal_density}")
        if not self.spring_softness > 0:
            raise ParameterError(f"spring_softness must be > 0, got {self.spring_softness}")
        if self.edge_compliance is not None and not self.edge_compliance > 0:
            raise ParameterError(f"edge_compliance must be > 0 m/N or None, got {self.edge_compliance}")
        if (self.gravity or self.fluid_density > 0) and self.edge_compliance is None:
            raise ParameterError(
                "gravity and hydrostatic pressure need a physical spring compliance: give edge_compliance (m/N); "
                "the default softness only shapes the volume-driven equilibrium")
        if int(self.loaded_iterations) < 1:
            raise ParameterError(f"loaded_iterations must be >= 1, got {self.loaded_iterations}")
        if not self.anderson_tolerance > 0:
            raise ParameterError(f"anderson_tolerance must be > 0, got {self.anderson_tolerance}")
        if self.closure not in ("centroid", "mirror"):
            raise ParameterError(f"closure must be 'centroid' or 'mirror', got {self.closure!r}")
        if not 0 <= self.fluid_density < 1e5:
            raise ParameterError(f"fluid_density must be in [0, 1e5) kg/m³, got {self.fluid_density}")
        graft_pbd_options(self)  # validates the rest

    def to_json(self) -> dict:
        return asdict(self)


def graft_pbd_options(options: GraftOptions) -> PBDOptions:
    """The :class:`PBDOptions` of a graft solve."""
    loaded = options.gravity or options.fluid_density > 0
    return PBDOptions(
        dt=options.dt, iterations=options.loaded_iterations if loaded else options.iterations,
        gravity=(0.0, -STANDARD_GRAVITY if options.gravity else 0.0, 0.0),
        damping=options.damping, method=options.method, xpbd=options.xpbd,
        edge_compliance=options.edge_compliance or 0.0, volume_compliance=0.0,
        stabilisation_iterations=options.stabilisation_iterations, stop_tolerance=options.stop_tolerance,
        min_steps=3, max_steps=options.max_steps, parallel=options.parallel, stop_patience=options.stop_patience,
        acceleration=options.acceleration, anderson_history=options.anderson_history,
    )


@dataclass(frozen=True, eq=False)
class GraftSetup:
    """Prepared data of the seed's module (§5.2): the region, its closed model, initial area and volume.

    A setup is reused for any number of injections with different parameters.
    """

    region: FaceRegion
    closed: ClosedRegion
    area_before: float  # m²
    volume_before: float  # m³, closed model

    @property
    def face(self) -> SurfaceMesh:
        return self.region.mesh


def prepare_graft(region: FaceRegion, closure: str = "centroid") -> GraftSetup:
    """Close ``region`` (Monkin §5.3) and record its initial area and volume (seed step 2 → 3)."""
    closed = close_region(region, closure)
    return GraftSetup(region, closed, region.area, closed.volume)


@dataclass(frozen=True, eq=False)
class GraftResult:
    """Result of one injection (seed step 4).

    face_after : the whole face with the region replaced
    volume_injected : m³, requested
    volume_before, volume_after : m³, closed model before and after
    area_before, area_after : m², region surface
    info : how the PBD solve ended
    options : the parameters used
    """

    setup: GraftSetup
    face_after: SurfaceMesh
    volume_injected: float
    volume_before: float
    volume_after: float
    area_before: float
    area_after: float
    info: SolveInfo
    options: GraftOptions
    closed_after: np.ndarray = field(repr=False, default=None)  # (k, 3) m, closed model positions

    @property
    def displacement(self) -> np.ndarray:
        """(n,) float64, m: signed displacement of every face vertex along its original normal."""
        before = self.setup.face
        d = self.face_after.vertices - before.vertices
        return np.einsum("ij,ij->i", d, before.vertex_normals)

    def summary(self) -> dict:
        """JSON-ready numbers (SI units and cm³/cm² copies for people)."""
        r = self.setup.region
        return {
            "region": r.markers.name if r.markers is not None else "region",
            "markers": r.markers.to_json() if r.markers is not None else None,
            "marker_vertices": r.marker_vertices.tolist(),
            "region_vertices": int(len(r.vertex_ids)),
            "region_triangles": int(len(r.triangle_ids)),
            "closure": self.setup.closed.method,
            "volume_injected_m3": self.volume_injected,
            "volume_before_m3": self.volume_before,
            "volume_after_m3": self.volume_after,
            "volume_change_cm3": (self.volume_after - self.volume_before) * 1e6,
            "area_before_m2": self.area_before,
            "area_after_m2": self.area_after,
            "max_displacement_mm": float(np.max(np.abs(self.displacement)) * 1e3),
            "steps": self.info.steps,
            "converged": self.info.converged,
            "params": self.options.to_json(),
        }


def _pbd_model(setup: GraftSetup, options: GraftOptions, target: float) -> PBDModel:
    c = setup.closed
    surf = c.triangles[c.surface_triangles]
    mass_total = options.areal_density * setup.area_before
    base = PBDModel.from_surface(c.vertices, surf, total_mass=mass_total, fixed=c.fixed)
    return PBDModel(mass=base.mass, fixed=c.fixed, edges=base.edges, rest_length=base.rest_length,
                    volume_triangles=c.triangles, volume_body=np.zeros(len(c.triangles), np.int64),
                    volume_target=[target], fluid_density=options.fluid_density)


def graft_problem(setup: GraftSetup, volume: float, options: GraftOptions = GraftOptions()
                  ) -> tuple[PBDModel, PBDOptions]:
    """The PBD model (closed region, target raised by ``volume`` m³) and options of one injection."""
    model = _pbd_model(setup, options, setup.volume_before + volume)
    pbd_options = graft_pbd_options(options)
    mean_edge = float(np.mean(model.rest_length[~(model.fixed[model.edges[:, 0]] & model.fixed[model.edges[:, 1]])]))
    fraction = options.anderson_tolerance if options.acceleration == "anderson" else options.stop_tolerance
    pbd_options = replace(pbd_options, stop_tolerance=fraction * mean_edge)
    if options.edge_compliance is None:
        mean_mass = float(model.mass[~model.fixed].mean())
        pbd_options = replace(pbd_options, edge_compliance=options.spring_softness * options.dt**2 / mean_mass)
    return model, pbd_options


def warm_start_positions(setup: GraftSetup, volume: float) -> np.ndarray:
    """(k, 3) float64, m: closed-model positions with the region pushed out along its vertex normals by a
    membrane-like bulge u (cotangent Laplacian: -L u = M 1 inside, u = 0 on the loop), scaled so that
    the closed model gains ``volume`` m³ (secant iterations on the exact closed volume).

    Only an initial guess for PBD (the seed starts from the flat region); experimental, see
    :class:`GraftOptions` ``warm_start``.
    """
    import igl
    import scipy.sparse.linalg as spla

    closed = setup.closed
    surf = closed.triangles[closed.surface_triangles]
    v = closed.vertices
    used = np.unique(surf)
    free = used[~closed.fixed[used]]
    lap = igl.cotmatrix(v, surf).tocsr()  # rows up to the largest index used by ``surf``
    mass = np.zeros(len(v))
    diag = igl.massmatrix(v, surf, igl.MASSMATRIX_TYPE_VORONOI).diagonal()
    mass[:len(diag)] = diag
    u = np.zeros(len(v))
    u[free] = spla.spsolve((-lap[free][:, free]).tocsc(), mass[free])
    from headsim.mesh import geometry

    normals = geometry.vertex_normals(v, surf)
    direction = u[:, None] * normals
    target = setup.volume_before + volume

    def excess(scale):
        return closed.volume_on(v + scale * direction) - target

    # secant on the (cubic) volume, from the linear estimate
    linear = float(np.sum(mass * u * np.einsum("ij,ij->i", normals, normals)))
    s0, s1 = 0.0, volume / max(linear, 1e-30)
    f0, f1 = excess(s0), excess(s1)
    for _ in range(30):
        if abs(f1) <= 1e-12 * max(volume, 1e-30) or f1 == f0:
            break
        s0, s1, f0 = s1, s1 - f1 * (s1 - s0) / (f1 - f0), f1
        f1 = excess(s1)
    return v + s1 * direction


def inject_volume(setup: GraftSetup, volume: float, options: GraftOptions = GraftOptions(), *,
                  callback: Callable[[PBDState, float], None] | None = None,
                  cancel: Callable[[], bool] | None = None) -> GraftResult | None:
    """Raise the closed model's target volume by ``volume`` and relax it with PBD (Monkin §4.3, §5.3).

    Parameters
    ----------
    volume : m³ to inject (> 0; 1 cm³ = 1e-6 m³)
    callback : called after every PBD step with (state, change of Σ|x|) for progress display
    cancel : polled every step; when it returns True the solve stops and None is returned

    Returns
    -------
    GraftResult, or None when cancelled. ``setup`` and its face are never modified.

    Notes
    -----
    The region's loop and the closure are fixed, so the closed model's volume change equals the volume
    between the face surfaces before and after inside the region.
    """
    if not (volume > 0 and math.isfinite(volume)):
        raise ParameterError(f"volume to inject must be > 0 m³, got {volume}")
    limit = 50.0 * setup.area_before ** 1.5
    if volume > limit:
        raise ParameterError(
            f"{volume * 1e6:.3g} cm³ is implausibly large for a region of {setup.area_before * 1e4:.3g} cm² "
            f"(limit {limit * 1e6:.3g} cm³); check the volume's unit (cm³) and the mesh's unit")
    model, pbd_options = graft_problem(setup, volume, options)
    solver = PBDSolver(model, pbd_options)
    start = warm_start_positions(setup, volume) if options.warm_start else setup.closed.vertices
    state, info = solver.solve(PBDState.at_rest(start), callback=callback, cancel=cancel)
    if info.cancelled:
        return None
    if not info.converged and options.require_convergence:
        why = ""
        if options.gravity or options.fluid_density > 0:
            # measured on the bundled cheek (5 cm³, 900 kg/m³, compliance 1e-3 m/N): with dt = 1e-2 s and 2
            # sweeps the steps settle into a period-8 cycle (no flips of the loaded particles: the step map
            # has no attracting fixed point); 10 sweeps or dt = 1e-3 s settle, but on shapes 3.9 mm and
            # 0.6 mm from each other, so such a result would depend on dt and the sweep count
            why = (" With gravity or hydrostatic pressure each step first moves the region by a·dt² (1 mm at "
                   "dt = 1e-2 s); unless the sweeps of a step converge (loaded_iterations; stiff springs need "
                   "more) the step map may have no rest state.")
        raise ConvergenceError(
            f"the graft solve did not meet the stop rule in {info.steps} steps (last change "
            f"{info.last_change:.3g} m); raise max_steps or damping.{why}")
    closed = setup.closed
    moved = closed.face_ids >= 0
    after = setup.face.vertices.copy()
    after[closed.face_ids[moved]] = state.positions[moved]
    face_after = setup.face.with_vertices(after)
    return GraftResult(
        setup=setup, face_after=face_after, volume_injected=volume, volume_before=setup.volume_before,
        volume_after=closed.volume_on(state.positions), area_before=setup.area_before,
        area_after=setup.region.area_on(after), info=info, options=options, closed_after=state.positions,
    )
