"""Hair drape scenes: rigid-segment fibres falling onto obstacles (Sobottka 2008, §8.6).

Scenes (digest §2; sizes the seed does not state — sphere radius, heights, helix geometry — are ours
and listed in every scene's ``description``):

* ``sphere-horizontal`` (§8.6.1): a flat, one-side-fixed ribbon of horizontal fibres (seed: 500 × 40
  segments, 30 cm; ours 2.2 r apart, 2 mm above a sphere of :data:`RIBBON_SPHERE_RADIUS` = 6 cm,
  ``sphere_radius``) falling onto a sphere centred under its midline. At full size with μ = 0.47 the fibres that
  start more than ≈ 14 mm from the midline drift past the friction angle while they slide lengthwise on landing
  and slide off the 6 cm sphere, where the seed's stay (on an 8 cm sphere they stay):
  ``benchmarks/bench_drape_ribbon.py``.
* ``sphere-helical`` (§8.6.2, the reference scene): a vertical, initially helical strand (seed:
  355 × 100 segments, 30 cm, Δt = 1 ms) falling onto a sphere below, with the root height, sphere
  radius and helix derived from the seed's Table 8.1 box (:class:`HelicalSphereGeometry`: a 4.24 cm
  coil hanging from roots 6.8 cm above a 16.6 cm sphere); rest shape straight by default,
  so the helix unwinds (``rest_shape="initial"``: a curl that gravity stretches). The seed's "crossing,
  where the unwinding strand rests on the settled one as a distinct bundle" makes the strand one
  bundle: a ringlet whose centreline is the helix, the fibres on a hexagonal lattice across it
  (:data:`RINGLET_SPACING`), so no two fibres start closer than a diameter (the former 355 helices of
  one radius around a 4 mm disc with random phases started with 13,422 overlapping segment pairs).
* ``plane`` (§8.6.4): a horizontal helical strand (seed: 250 × 100) onto a 22.5° inclined plane.
* ``terrain`` (§8.6.3): the vertical helical strand onto a bumpy terrain, a 30 × 30 cm slab with rounded edges
  (grid distance field of the smooth surface; fibres can slide off its edge, as the seed's do in Fig. 8.17).
* ``head``: fibres rooted on the scalp of the bundled head (325 roots/cm², none two closer than 0.28 mm),
  draping under gravity against the head's skin (exact distances near it, a 3 mm narrow-band grid beyond).

Friction (``friction``): ``aniso`` — with / against the scales and across from the keratin table
(wool/wool static dry, Schwartz & Knowles via Sobottka Tab. 2.11: 0.13 / 0.61 / 0.21; the only
complete set of the three directions in the database); ``iso`` — μ = 0.47 (§8.6.5.2); ``none``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from headsim.collide import GridDistanceField, MeshDistanceField, PlaneField, SphereField
from headsim.errors import DivergenceError, ParameterError
from headsim.hair.drape_pictures import plane_patch, sphere_surface, wrapped_title, write_frames
from headsim.hair.properties import MASS_DENSITY, MODULI_ROBBINS, friction
from headsim.solvers.chains import (
    ChainModel,
    ChainOptions,
    ChainSolver,
    ChainState,
    FrictionLaw,
    Obstacle,
    chain_model_from_polylines,
    polylines_from_state,
)

__all__ = ["SCENES", "FRICTION_MODES", "HelicalSphereGeometry", "SEED_TABLE_8_1", "SEED_TABLE_8_1_RATIO",
           "DrapeScene", "DrapeResult", "friction_law", "build_drape_scene", "run_drape", "bounding_box",
           "volume_stability", "write_drape"]

SCENES = ("sphere-horizontal", "sphere-helical", "plane", "terrain", "head")
FRICTION_MODES = ("aniso", "iso", "none")
FIBRE_DIAMETER = 70e-6  # m, Sobottka §8.6 ("durchgängig ein Querschnitt von 70 µm")
# m, lattice spacing of the helical strands: 1.5 d leaves 35 µm (one radius) between neighbouring fibres,
# 1.49 d at the chords of 3 mm segments (measured); the seed gives no packing
RINGLET_SPACING = 1.5 * FIBRE_DIAMETER
# m, radius of the sphere under the sphere-horizontal ribbon (§8.6.1; the seed does not state it)
RIBBON_SPHERE_RADIUS = 0.06


#: Sobottka 2008 Table 8.1 (§8.6.5.2): axis-aligned bounding box of the reference scene at t ≈ 0.7 s,
#: (Länge, Breite, Höhe) in cm per friction model, and the volume relative to the anisotropic run (the
#: header's "%" column is that fraction).
SEED_TABLE_8_1 = {"iso": (8.69, 14.09, 8.35), "aniso": (8.53, 14.09, 8.59), "none": (8.12, 13.98, 8.24)}
SEED_TABLE_8_1_RATIO = {"iso": 0.990, "aniso": 1.000, "none": 0.906}
SEED_ISOTROPIC_MU = 0.47  # §8.6.5.2


@dataclass(frozen=True)
class HelicalSphereGeometry:
    """Geometry of the ``sphere-helical`` reference scene (§8.6.2), m, derived from what the seed states.

    The seed states: 355 fibres × 100 segments, 30 cm, 70 µm, Δt = 1 ms, a vertical, initially helical
    strand falling onto "a sphere below", gravity, and (Table 8.1, isotropic μ = 0.47, t ≈ 0.7 s) an
    axis-aligned box of 8.69 × 14.09 × 8.35 cm (Länge × Breite × Höhe; Höhe read as the vertical). It
    does not state the root height, the sphere radius or the helix. They are derived here (:meth:`derive`;
    Table 8.1's isotropic row and μ = 0.47, the only friction value the seed gives):

    1. *Helix radius* ρ: the box's short horizontal side (8.69 cm) is one coil diameter, i.e. the strand
       lands as loops of the coil it started as and the unwinding spreads it along the other side
       (14.09 cm). ρ = (8.69 cm − t)/2 with t the strand thickness (the hexagonal lattice of
       :data:`RINGLET_SPACING` holding 355 fibres is a disc of t = 2.1 mm): ρ = 4.24 cm. A 30 cm fibre
       is then 1.1 turns.
    2. *Sphere radius* R: "friction prevents further sliding" — the pile's rim, half the long side
       a = 14.09/2 = 7.05 cm from the axis, must rest where the sphere is no steeper than the friction
       angle of μ = 0.47 (25.2°): R ≥ a / sin(arctan μ) = 16.6 cm. The smallest such sphere is taken.
    3. *Root height* h above the sphere's top: the roots are fixed and everything else falls, so the
       roots are the top of the box and the rim of the pile resting on the sphere is its bottom:
       h = 8.35 cm − (R − √(R² − a²)) = 8.35 − 1.57 = 6.8 cm.
    4. The sphere is centred under the helix axis (as §8.6.1 centres its sphere under the midline).
    5. *Pitch* (not derivable): 3.6 cm, so the 1.1-turn coil is 4.0 cm tall and its lowest point hangs
       2.8 cm above the sphere (no contact at the start; turns 3.6 cm apart, far more than t).

    Consequences: the strand falls 2.8 cm (lands at ≈ 0.74 m/s, ≈ 0.08 s) and has ≈ 0.6 s to settle
    before the seed's 0.7 s box. The former geometry (12 mm helix, roots 12 cm above a 5 cm sphere,
    :meth:`former`) could not give the seed's box: its straightened strand hangs ≈ 28 cm.

    Outcome (``benchmarks/bench_drape_volume.py``, reduced scenes): with the default straight rest
    shape the strand still slides over the rim and hangs down the sphere's side; the boxes at 0.7 s are
    2–5 times the seed's; none < iso, aniso holds, iso ≈ aniso does not; the isotropic run comes to rest
    (stable volume), the anisotropic one does not by 1.5 s (nor, at full size, by 2.6 s: its loops keep sliding).
    At full size (355 × 100) the boxes at 0.7 s are 5–6 times the seed's: none/aniso 0.83 holds, none/iso 0.96
    just misses the seed's group threshold 0.95, iso/aniso 0.86.
    """

    helix_radius: float
    pitch: float
    root_height: float
    sphere_radius: float
    sphere_offset: float = 0.0  # m, the sphere centre's x offset from the helix axis

    @classmethod
    def former(cls) -> "HelicalSphereGeometry":
        """The geometry before the derivation (12 mm helix, pitch 8 mm, roots 12 cm above a 5 cm sphere
        offset 1.5 cm): for comparing with benchmarks measured on it (e.g. ``bench_drape.py`` timings)."""
        return cls(0.012, 0.008, 0.12, 0.05, 0.015)

    @classmethod
    def derive(cls, n_fibres: int = 355, spacing: float = RINGLET_SPACING, mu: float = SEED_ISOTROPIC_MU,
               box_cm=SEED_TABLE_8_1["iso"], pitch: float = 0.036) -> "HelicalSphereGeometry":
        """Steps 1–3 of the class docstring from the seed's numbers (box in cm, results in m)."""
        short, long_, height = (0.01 * v for v in box_cm)
        thickness = 2.0 * np.sqrt(n_fibres * (np.sqrt(3) / 2) * spacing**2 / np.pi)
        rho = 0.5 * (short - thickness)
        a = 0.5 * long_
        R = a / np.sin(np.arctan(mu))
        h = height - (R - np.sqrt(R**2 - a**2))
        return cls(float(rho), float(pitch), float(h), float(R))


def friction_law(mode: str) -> FrictionLaw:
    """The friction model of a CLI mode (see the module docstring)."""
    if mode == "aniso":
        w = friction("wool/wool", 1).static
        a = friction("wool/wool", 2).static
        c = friction("wool/wool", 3).static
        return FrictionLaw(w, a, c)
    if mode == "iso":
        return FrictionLaw.isotropic(0.47)
    if mode == "none":
        return FrictionLaw.none()
    raise ParameterError(f"friction must be one of {', '.join(FRICTION_MODES)}, got {mode!r}")


OBSTACLE_ALBEDO = (0.2, 0.22, 0.26)  # the obstacles' diffuse albedo in the path-traced frames (mid grey)


@dataclass
class DrapeScene:
    name: str
    description: str
    model: ChainModel
    state: ChainState
    obstacles: list
    dt: float
    n_steps: int
    options: ChainOptions
    obstacle_mesh: tuple | None = None  # (vertices, triangles) for pictures, m


@dataclass
class DrapeResult:
    times: np.ndarray  # (K,) s, recorded frames
    polylines: np.ndarray  # (K, F, n+1, 3) m
    step_time: np.ndarray  # (steps,) s
    kinetic: np.ndarray  # (steps,) J
    total_energy: np.ndarray  # (steps,) J
    contacts: np.ndarray  # (steps,) int
    fibre_contacts: np.ndarray
    obstacle_contacts: np.ndarray
    max_joint_gap: np.ndarray  # (steps,) m
    max_penetration: np.ndarray  # (steps,) m
    newton_iterations: np.ndarray
    qp_sweeps: np.ndarray
    qp_capped: np.ndarray  # (steps,) contact solves of the step that ended at the sweep cap (no tolerance met)
    seconds: dict = field(default_factory=dict)  # summed per-phase wall time, s
    step_seconds: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (steps,) wall time of each step, s
    # (steps,) solver steps each step took (ChainOptions.step_halvings / max_rotation_per_step: 2 or more where it
    # was halved)
    substeps: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    # (steps,) fibre pairs turned back after passing through each other in the step (ChainOptions.restore_crossings)
    crossings_restored: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    # (steps,) m, the largest overlap of a step's contact rows at its end, exact (StepStats.end_overlap; nan: none)
    end_overlap: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # (steps,) fibre joint solves of the step whose mean-lever Newton did not converge and that took the start
    # levers' answer instead (StepStats.joint_root_failures; ChainOptions.joint_levers="mean")
    joint_root_failures: np.ndarray = field(default_factory=lambda: np.zeros(0, int))


def _hex_lattice(n: int, spacing: float) -> np.ndarray:
    """(n, 2) points of a hexagonal lattice of ``spacing`` (m), the n closest to the origin (a disc)."""
    k = int(np.ceil(np.sqrt(n))) + 2
    ii, jj = np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1), indexing="ij")
    lat = np.stack([ii + 0.5 * jj, jj * np.sqrt(3) / 2], -1).reshape(-1, 2) * spacing
    return lat[np.argsort(np.hypot(lat[:, 0], lat[:, 1]), kind="stable")[:n]]


def _ringlet(n_fibres: int, n_segments: int, length: float, radius: float, pitch: float, top,
             spacing: float, vertical: bool = True) -> np.ndarray:
    """A helical strand (ringlet): (n_fibres, n_segments + 1, 3) node polylines, m.

    The strand's centreline c(s) is a helix of ``radius`` and ``pitch`` (rise per turn) around a
    vertical (−y) or horizontal (+x) axis through ``top``, arc length ``length``. The fibres sit on a
    hexagonal lattice of ``spacing`` in the centreline's normal plane, spanned by the principal
    normal (−e_r for a helix) and the binormal B (Frenet frame; it turns about the tangent with the
    helix torsion, which leaves the in-plane distances unchanged), so fibre j is c(s) + a_j e_r(s) +
    b_j B(s). All fibres are sampled at the same centreline arc lengths s_k: neighbouring fibres then
    stay one spacing apart along their whole length, chords included (the chord of a 3 mm segment on
    a 12 mm helix cuts the arc by ℓ²/(8ρ) ≈ 94 µm, more than a diameter, so fibres sampled at their
    own arc lengths would start interpenetrating). The price: a fibre's length differs from
    ``length`` by the radial offset, by the factor ≈ 1 + κ a_j (κ = ρ/(ρ² + c²) the curvature,
    c = pitch/2π), a few per cent at the strand's edge."""
    turn = np.hypot(2 * np.pi * radius, pitch)  # arc length of one turn
    kappa = radius / (radius**2 + (pitch / (2 * np.pi)) ** 2)
    # chords of neighbouring fibres (same centreline arc lengths) are cos(ℓκ/2) times closer than the nodes
    clear = spacing * np.cos(0.5 * min(length / n_segments * kappa, np.pi))
    if not clear > FIBRE_DIAMETER:
        raise ParameterError(f"fibre spacing {spacing * 1e6:.1f} µm leaves chords {clear * 1e6:.1f} µm apart at "
                             f"{n_segments} segments on a {radius * 1e3:g} mm helix, not more than the fibre "
                             f"diameter {FIBRE_DIAMETER * 1e6:g} µm: the fibres would start interpenetrating")
    lat = _hex_lattice(n_fibres, spacing)
    s = np.linspace(0.0, length, n_segments + 1)
    ang = 2 * np.pi * s / turn
    rise = pitch * s / turn
    # local coordinates with the helix axis along −z': centreline, radial e_r, tangent t, binormal t × e_r
    c = np.stack([radius * np.cos(ang), radius * np.sin(ang), -rise], 1)
    er = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], 1)
    t = np.stack([-2 * np.pi * radius * np.sin(ang), 2 * np.pi * radius * np.cos(ang), np.full_like(ang, -pitch)], 1)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(t, er)
    local = c[None] + lat[:, None, 0:1] * er[None] + lat[:, None, 1:2] * b[None]
    x0, y0, z0 = top
    if vertical:  # axis along −y: local (x', y', z') → world (x', z', y')
        return np.stack([x0 + local[..., 0], y0 + local[..., 2], z0 + local[..., 1]], -1)
    return np.stack([x0 - local[..., 2], y0 + local[..., 0], z0 + local[..., 1]], -1)


_TERRAIN_K = 2 * np.pi / 0.12  # rad/m, wave number of the bumps (period 12 cm)
_TERRAIN_AMPLITUDE = 0.025  # m
_TERRAIN_HALF_WIDTH = 0.15  # m: the terrain is the slab |x|, |z| ≤ this under the surface (fibres fall off its edge)
_TERRAIN_DEPTH = 0.05  # m: the slab's bottom lies this far below the surface's lowest point
_TERRAIN_EDGE_RADIUS = 0.015  # m: the slab's edges and corners are rounded (1/ρ = 67 m⁻¹ < the bumps' κ_max = 70 m⁻¹)


def _terrain_height(x, z):
    """Height y (m) of the bumpy terrain at (x, z) m: cosine bumps of 2.5 cm, period 12 cm, in a bowl."""
    k, a = _TERRAIN_K, _TERRAIN_AMPLITUDE
    return -0.10 + a * np.cos(k * x) * np.cos(k * z) - (x**2 + z**2)


def _terrain_slope(x, z):
    """(∂h/∂x, ∂h/∂z) of :func:`_terrain_height`."""
    k, a = _TERRAIN_K, _TERRAIN_AMPLITUDE
    return -a * k * np.sin(k * x) * np.cos(k * z) - 2 * x, -a * k * np.cos(k * x) * np.sin(k * z) - 2 * z


def _terrain_distance(points, iterations: int = 4, near: float = 6e-3):
    """Signed distance (m) of points (n, 3) to the terrain, positive outside: the slab under the smooth surface
    y = h(x, z) over the footprint |x|, |z| ≤ :data:`_TERRAIN_HALF_WIDTH`, its edge rounded with radius
    :data:`_TERRAIN_EDGE_RADIUS`, side walls down to a flat bottom (:func:`_terrain_bottom`).

    The surface's signed distance a (:func:`_surface_distance`) and the footprint's b (exact in 2-D, corners
    rounded by ρ) are
    combined by a rounded intersection (:func:`_round_intersection`; exact more than ρ away from the edge), and
    the bottom with that the same way. The rounding is less curved than the bumps (1/ρ < κ_max), so the grid
    field's interpolation bound (:func:`terrain_level`, 106 µm) holds over the edges too, except at the four
    corners, where the two roundings meet and the blend is not a distance (measured within 4 mm of the slab: 99.9 %
    of 4e5 random points within 79 µm, at most 144 µm; the picture mesh's corner vertices 124 µm; the sharp edges
    before: 516 µm). Without the walls and the bottom the
    field continued the hill to the grid's border, where its values jumped to the grid's far value: a
    frictionless strand that slid off the edge swung under the grid and back up into a solid that ended nowhere
    (measured: 30 × 100 fibres, 55 mm deep at t = 0.54 s); without the fillet the fibres that draped over the
    sharp edge sank into it between their contact samples."""
    p = np.asarray(points, float)
    L, rho = _TERRAIN_HALF_WIDTH, _TERRAIN_EDGE_RADIUS
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    # the surface's distance, beyond the footprint that of the point moved in onto its border (so the surface
    # does not go on outside: the wall meets the edge there)
    a = _surface_distance(np.stack([np.clip(x, -L, L), y, np.clip(z, -L, L)], 1), iterations, near)
    qx, qz = np.abs(x) - (L - rho), np.abs(z) - (L - rho)  # the footprint, its vertical corners rounded by ρ too
    b = np.hypot(np.maximum(qx, 0.0), np.maximum(qz, 0.0)) + np.minimum(np.maximum(qx, qz), 0.0) - rho
    return _round_intersection(_round_intersection(a, b, rho), _terrain_bottom() - y, rho)


def _round_intersection(a, b, rho):
    """Signed distance (m) of the intersection of two solids with signed distances a, b (m), its edge rounded with
    radius ρ: min(−ρ, max(a, b)) + ‖(max(a + ρ, 0), max(b + ρ, 0))‖ (exact where one of them is more than ρ
    inside the other; a quarter circle between two perpendicular planes)."""
    return np.minimum(-rho, np.maximum(a, b)) + np.hypot(np.maximum(a + rho, 0.0), np.maximum(b + rho, 0.0))


@functools.cache
def _terrain_bottom() -> float:
    """y (m) of the terrain slab's flat bottom: :data:`_TERRAIN_DEPTH` below the surface's lowest point (computed
    once: every distance query reads it)."""
    xs = np.linspace(-_TERRAIN_HALF_WIDTH, _TERRAIN_HALF_WIDTH, 301)
    X, Z = np.meshgrid(xs, xs, indexing="ij")
    return float(_terrain_height(X, Z).min()) - _TERRAIN_DEPTH


def _surface_distance(points, iterations: int = 4, near: float = 6e-3):
    """Signed distance (m) of points (n, 3) to the smooth terrain surface y = h(x, z), positive above.

    Within ``near`` of the surface (by the first-order estimate (y − h)/√(1 + |∇h|²)) the closest
    surface point (u, h(u, w), w) is found by Newton on the tangency conditions (p − s)·s_u =
    (p − s)·s_w = 0 from the vertical foot point (quadratic convergence: 1e-14 m after 3 iterations at
    4 mm; the projection is unique there, the bumps' radius of curvature being ≥ 1.4 cm). Farther away
    the first-order estimate is used, at least ``near`` in magnitude (sign exact, gradient out of the
    solid)."""
    p = np.asarray(points, float)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    sx, sz = _terrain_slope(x, z)
    first = (y - _terrain_height(x, z)) / np.sqrt(1 + sx**2 + sz**2)
    out = np.sign(first) * np.maximum(np.abs(first), near)
    i = np.nonzero(np.abs(first) < near)[0]
    px, py, pz = x[i], y[i], z[i]
    u, w = px.copy(), pz.copy()
    k, a = _TERRAIN_K, _TERRAIN_AMPLITUDE
    for _ in range(iterations):
        hu, hw = _terrain_slope(u, w)
        huu = -a * k * k * np.cos(k * u) * np.cos(k * w) - 2
        huw = a * k * k * np.sin(k * u) * np.sin(k * w)
        dx, dy, dz = px - u, py - _terrain_height(u, w), pz - w
        g1, g2 = dx + dy * hu, dz + dy * hw  # (p − s)·s_u, (p − s)·s_w with s_u = (1, h_u, 0), s_w = (0, h_w, 1)
        j11 = -1 - hu * hu + dy * huu
        j12 = -hu * hw + dy * huw
        j22 = -1 - hw * hw + dy * huu  # h_ww = h_uu for this terrain
        det = j11 * j22 - j12 * j12
        u = u - (j22 * g1 - j12 * g2) / det
        w = w - (j11 * g2 - j12 * g1) / det
    dist = np.sqrt((px - u) ** 2 + (py - _terrain_height(u, w)) ** 2 + (pz - w) ** 2)
    out[i] = np.where(first[i] >= 0, dist, -dist)
    return out


def terrain_level(spacing: float) -> float:
    """Iso-level offset (m) of the terrain field of grid ``spacing`` (m): (3/8) Δs² κ_max, the bound of
    the trilinear interpolation error of a distance function whose Hessian is bounded by the largest
    principal curvature κ_max = A k² + 2 m⁻¹ of the terrain (h/8 per axis, three axes). Fibres rest on
    this iso-surface, so the interpolation error cannot put them into the true surface."""
    kappa = _TERRAIN_AMPLITUDE * _TERRAIN_K**2 + 2.0
    return 3.0 / 8.0 * spacing**2 * kappa


def _onto_zero_level(distance, points, iterations: int = 4, h: float = 1e-7):
    """points (n, 3) m moved onto the zero level of the signed distance function ``distance`` by Newton steps
    along its central-difference gradient (step h, m): p ← p − φ ∇φ / ‖∇φ‖²."""
    p = np.array(points, dtype=np.float64)
    eye = np.eye(3) * h
    for _ in range(iterations):
        phi = distance(p)
        g = np.stack([(distance(p + e) - distance(p - e)) / (2 * h) for e in eye], 1)
        p -= (phi / np.maximum((g * g).sum(1), 1e-12))[:, None] * g
    return p


def _terrain_field(spacing=2e-3):
    """Bumpy terrain y = h(x, z) as a triangle mesh (for pictures) and its distance field (m).

    The field samples the exact signed distance to the smooth surface (:func:`_terrain_distance`) on a
    grid of ``spacing`` over the terrain slab (surface, rounded edge, side walls, flat bottom 5 cm under the
    surface's lowest point; :func:`_terrain_distance`) and 8 Δs around it, 16 Δs above: outside the grid is outside
    the slab. The picture mesh is the surface's height field with its vertices moved onto the slab's zero level
    (onto the rounded edge at the border).
    It replaces a narrow-band field of a 5 mm height-field mesh with all-positive far values, which
    (a) differed from the mesh's exact distance by up to 258 µm (7.4 r) at the mesh creases, where the
    trilinear interpolation cannot follow the kink of the distance function, and the 5 mm mesh
    itself was up to 0.43 mm off the smooth bumps, and (b) was positive deeper than its 8 mm band, so
    a fibre end pushed in that far met a false zero crossing or a zero normal and fell through
    (measured: tips 8 cm under the surface after 0.5 s in the 19 × 30 scene). Trilinear
    interpolation of the smooth distance errs by at most ≈ (3/8) Δs² κ (κ ≤ 70 m⁻¹ the largest
    principal curvature of the bumps): 105 µm bound (measured: ≤ 92 µm within 4 mm of the surface),
    used as the obstacle's iso-level offset (:func:`terrain_level`)."""
    n = 121
    xs = np.linspace(-_TERRAIN_HALF_WIDTH, _TERRAIN_HALF_WIDTH, n)
    X, Z = np.meshgrid(xs, xs, indexing="ij")
    Y = _terrain_height(X, Z)
    v = _onto_zero_level(_terrain_distance, np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1))
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tri = np.concatenate([np.stack([a, d, b], 1), np.stack([b, d, c], 1)])  # +y facing
    pad = 8 * spacing
    L = _TERRAIN_HALF_WIDTH
    lower = np.array([-L - pad, _terrain_bottom() - pad, -L - pad])  # the whole slab and a margin round it
    upper = np.array([L + pad, Y.max() + 2 * pad, L + pad])
    fld = GridDistanceField.from_function(_terrain_distance, lower, upper, spacing)
    return fld, (v, tri)


# head scene: a hair leaves the scalp along its comb direction at arctan(1 / GROWTH_TANGENT) (27°) to the skin; the
# comb direction is down and back (y up, +z forward), projected onto the skin's tangent plane
COMB_DIRECTION = (0.0, -1.0, -0.7)
GROWTH_TANGENT = 2.0


def _growth_direction(normal) -> np.ndarray:
    """Unit start direction of a hair rooted where the skin's outward unit normal is ``normal``: n + 2 t, t the unit
    tangent of :data:`COMB_DIRECTION` (straight back where that is along the normal)."""
    n = np.asarray(normal, float)
    for comb in (COMB_DIRECTION, (0.0, 0.0, -1.0), (1.0, 0.0, 0.0)):
        t = np.asarray(comb, float)
        t = t - (t @ n) * n
        if np.linalg.norm(t) > 1e-3:
            break
    d = n + GROWTH_TANGENT * t / np.linalg.norm(t)
    return d / np.linalg.norm(d)


def build_drape_scene(name: str, friction_mode: str = "aniso", *, n_fibres: int | None = None,
                      segments: int | None = None, length: float = 0.30, dt: float = 1e-3,
                      duration: float | None = None, seed: int = 0, fibre_spacing: float | None = None,
                      rest_shape: str = "straight", geometry: HelicalSphereGeometry | None = None,
                      sphere_radius: float | None = None, **option_overrides) -> DrapeScene:
    """One of :data:`SCENES` at the seed's size (or ``n_fibres`` × ``segments`` when given).

    fibre_spacing : lattice spacing of the helical strands (sphere-helical, terrain, plane), m;
        default :data:`RINGLET_SPACING`. Must exceed the fibre diameter (no start in interpenetration).
    rest_shape : ``"straight"`` (the helices unwind) or ``"initial"`` (the start is the rest shape).
    seed : random seed of the head scene's scalp roots (the other scenes are deterministic).
    geometry : sphere-helical only; default :meth:`HelicalSphereGeometry.derive` (the derivation from
        the seed's Table 8.1 box is in :class:`HelicalSphereGeometry`).
    sphere_radius : sphere-horizontal only, m; default :data:`RIBBON_SPHERE_RADIUS` (the seed does not state its
        sphere; see ``benchmarks/bench_drape_ribbon.py`` for what the full-size ribbon does on which sphere).
    Other keywords go to :class:`~headsim.solvers.chains.ChainOptions`."""
    if name not in SCENES:
        raise ParameterError(f"unknown drape scene {name!r}; choose one of {', '.join(SCENES)}")
    if not (dt > 0 and length > 0):
        raise ParameterError("dt and length must be > 0")
    if sphere_radius is not None:
        if name != "sphere-horizontal":
            raise ParameterError(f"sphere_radius applies to the sphere-horizontal scene only, not {name!r}")
        if not (np.isfinite(sphere_radius) and sphere_radius > 0):
            raise ParameterError(f"sphere_radius must be a finite length > 0 m, got {sphere_radius}")
    spacing = RINGLET_SPACING if fibre_spacing is None else float(fibre_spacing)
    if not spacing > FIBRE_DIAMETER:
        raise ParameterError(f"fibre_spacing must exceed the fibre diameter {FIBRE_DIAMETER * 1e6:g} µm "
                             f"(fibres would start interpenetrating), got {spacing * 1e6:g} µm")
    r = 0.5 * FIBRE_DIAMETER
    law = friction_law(friction_mode)
    mesh = None
    anchored = True
    if name == "sphere-horizontal":
        F, n = n_fibres or 500, segments or 40
        R = RIBBON_SPHERE_RADIUS if sphere_radius is None else float(sphere_radius)
        spacing = 2.2 * r
        zs = (np.arange(F) - (F - 1) / 2) * spacing
        x = np.linspace(-0.5 * length, 0.5 * length, n + 1)
        polys = [np.stack([x, np.full(n + 1, 0.002 + r), np.full(n + 1, z)], 1) for z in zs]
        # fixed on one side: the roots at −x are anchored, the fibres extend along +x over the sphere
        obstacles = [Obstacle(SphereField((0.0, -R, 0.0), R), name="sphere")]
        mesh = sphere_surface((0.0, -R, 0.0), R)
        desc = (f"{F} horizontal fibres × {n} segments, {length * 100:g} cm, roots fixed at x = "
                f"{-50 * length:g} cm, over a sphere R = {R * 100:g} cm centred under the midline "
                f"(top 2 mm below the ribbon); friction {friction_mode}")
        dur = 0.6 if duration is None else duration
    elif name in ("sphere-helical", "terrain"):
        F, n = n_fibres or 355, segments or 100
        if name == "sphere-helical":
            g = HelicalSphereGeometry.derive() if geometry is None else geometry
            rho, pitch, top = g.helix_radius, g.pitch, g.root_height
        else:
            rho, pitch, top = 0.012, 0.008, 0.0
        polys = list(_ringlet(F, n, length, rho, pitch, (0.0, top, 0.0), spacing))
        strand = (f"a vertical helical strand (centreline helix radius {rho * 100:.3g} cm, pitch {pitch * 1e3:.3g} mm; "
                  f"fibres on a {spacing * 1e6:.0f} µm hexagonal lattice across it; rest shape {rest_shape})")
        if name == "sphere-helical":
            R = g.sphere_radius
            # centred under the helix axis (x = z = 0) unless offset, its top at y = 0
            obstacles = [Obstacle(SphereField((g.sphere_offset, -R, 0.0), R), name="sphere")]
            mesh = sphere_surface((g.sphere_offset, -R, 0.0), R)
            desc = (f"{F} fibres × {n} segments, {length * 100:g} cm, {strand}, roots at y = {top * 100:.3g} cm, "
                    f"sphere R = {R * 100:.3g} cm with its top at y = 0, centre {g.sphere_offset * 100:.3g} cm "
                    f"from the helix axis; friction {friction_mode}")
        else:
            fld, mesh = _terrain_field()
            # iso-level offset (§8.6.5) = the bound of the trilinear interpolation error, (3/8) Δs² κ_max
            level = terrain_level(fld.spacing)
            obstacles = [Obstacle(fld, level=level, name="terrain")]
            desc = (f"{F} fibres × {n} segments, {length * 100:g} cm, {strand}, roots at y = 0, onto a bumpy terrain (cosine "
                    f"bumps 2.5 cm, period 12 cm, top at y = −7.5 cm, a 30 × 30 cm slab with edges rounded by "
                    f"{_TERRAIN_EDGE_RADIUS * 1e3:g} mm, grid distance field {fld.spacing * 1e3:g} mm of the "
                    f"smooth surface, iso-level offset {level * 1e6:.0f} µm); friction {friction_mode}")
        dur = 0.7 if duration is None else duration
    elif name == "plane":
        F, n = n_fibres or 250, segments or 100
        alpha = np.deg2rad(22.5)
        polys = list(_ringlet(F, n, length, 0.012, 0.01, (-0.05, 0.05, 0.0), spacing, vertical=False))
        nrm = (np.sin(alpha), np.cos(alpha), 0.0)
        obstacles = [Obstacle(PlaneField((0.0, 0.0, 0.0), nrm), name="plane 22.5°")]
        mesh = plane_patch((0.0, 0.0, 0.0), nrm, polys[0][0], length)
        desc = (f"{F} fibres × {n} segments, {length * 100:g} cm, a horizontal helical strand (centreline helix "
                f"radius 1.2 cm, pitch 1 cm; fibres on a {spacing * 1e6:.0f} µm hexagonal lattice; rest shape "
                f"straight), roots fixed, above a 22.5° plane; "
                f"friction {friction_mode}")
        dur = 0.7 if duration is None else duration
    else:  # head
        import trimesh

        from headsim.collide.fibre_scenes import ROOT_DENSITY, scalp_roots
        from headsim.data import head_path

        F, n = n_fibres or 300, segments or 30
        length = min(length, 0.15)
        hm = trimesh.load(head_path(), process=False)
        v, t = np.asarray(hm.vertices, float), np.asarray(hm.faces, np.int64)
        # roots at the seed's density (325 /cm²) with no two closer than half its mean spacing (0.28 mm):
        # independent samples put anchored roots closer than a fibre diameter, an overlap no motion removes
        roots, normals = scalp_roots(v, t, F, seed=seed, min_spacing=0.5 / np.sqrt(ROOT_DENSITY))
        # exact distances to the skin within the band of a 3 mm grid (the grid alone reads up to 4 mm off)
        fld = MeshDistanceField(v, t, 0.003, band=0.012)
        polys = []
        for p0, nr in zip(roots, normals):
            d = _growth_direction(nr)
            polys.append(p0 + 3 * r * nr + np.linspace(0, length, n + 1)[:, None] * d)
        obstacles = [Obstacle(fld, name="head")]
        mesh = (v, t)
        desc = (f"{len(roots)} fibres × {n} segments, {length * 100:g} cm, rooted on the bundled head's scalp, "
                f"growing combed down and back at {np.degrees(np.arctan(1 / GROWTH_TANGENT)):.0f}° to the skin; skin "
                f"distances exact within 6.8 mm (3 mm grid, 12 mm band); friction {friction_mode}")
        dur = 0.5 if duration is None else duration
    nodes = np.concatenate(polys)
    offsets = np.arange(0, len(nodes) + 1, polys[0].shape[0])
    model, state = chain_model_from_polylines(nodes, offsets, radius=r, density=MASS_DENSITY.value,
                                              young=MODULI_ROBBINS["bend"].value,
                                              shear=MODULI_ROBBINS["torsion"].value, anchored=anchored,
                                              rest_shape=rest_shape, joint_damping=0.0)
    opts = dict(friction=law)
    opts.update(option_overrides)
    n_steps = max(1, int(round(dur / dt)))
    return DrapeScene(name, desc, model, state, obstacles, dt, n_steps, ChainOptions(**opts), mesh)


def bounding_box(polylines: np.ndarray) -> tuple[np.ndarray, float]:
    """Axis-aligned extent (3,) m and volume m³ of fibre polylines (Table 8.1's measure)."""
    p = np.asarray(polylines).reshape(-1, 3)
    ext = p.max(0) - p.min(0)
    return ext, float(np.prod(ext))


def volume_stability(result: DrapeResult, window: float) -> tuple[float, float]:
    """The seed's "stable volume" (§8.6.2) as two numbers: (max − min) / mean of the recorded frames'
    bounding-box volumes (Table 8.1's measure) over the last ``window`` seconds, and the last step's
    kinetic energy over its peak over the run (both dimensionless)."""
    vol = np.array([bounding_box(p)[1] for p in result.polylines])
    win = result.times >= result.times[-1] - window - 1e-12
    spread = float((vol[win].max() - vol[win].min()) / vol[win].mean())
    return spread, float(result.kinetic[-1] / max(result.kinetic.max(), 1e-300))


def render_surfaces(scene: DrapeScene) -> list:
    """The scene's obstacles as surfaces of the path-traced frames: the spheres and planes analytic, at their
    iso-level (:class:`headsim.hair.render.Surface`), the grid and mesh obstacles (terrain, head) as the scene's picture
    mesh (:class:`headsim.hair.render.MeshSurface`; the terrain's 0.1 mm iso-level offset is not drawn)."""
    from headsim.hair.render import MeshSurface, Surface

    out = []
    for ob in scene.obstacles:
        f = ob.field
        if isinstance(f, SphereField):
            out.append(Surface("sphere", tuple(map(float, f.center)), float(f.radius) + ob.level,
                               albedo=OBSTACLE_ALBEDO))
        elif isinstance(f, PlaneField):
            n = np.asarray(f.normal_vector, float) / np.linalg.norm(f.normal_vector)
            out.append(Surface("plane", tuple(np.asarray(f.point, float) + ob.level * n), normal=tuple(n),
                               albedo=OBSTACLE_ALBEDO))
        elif scene.obstacle_mesh is not None:
            v, t = scene.obstacle_mesh
            out.append(MeshSurface(np.asarray(v, float), np.asarray(t, np.int64), albedo=OBSTACLE_ALBEDO))
    return out


def run_drape(scene: DrapeScene, *, n_steps: int | None = None, record_every: int | None = None,
              progress: Callable[[int, int], None] | None = None, fibre_loop: bool = False,
              max_speed: float = 20.0) -> DrapeResult:
    """Step the scene; record polylines every ``record_every`` steps and the per-step statistics.

    Raises DivergenceError (never returns NaN) when a state is non-finite, a segment moves faster
    than ``max_speed`` m/s (free fall from the scenes' heights stays below 2 m/s) or a joint gap opens wider than
    the shortest segment's half length (the chains tore apart: the seed's "Kettenabriss", §8.6.5.1)."""
    steps = scene.n_steps if n_steps is None else int(n_steps)
    every = record_every or max(1, steps // 30)
    solver = ChainSolver(scene.options, fibre_loop=fibre_loop)
    state = scene.state
    tear = float(scene.model.half_length.min())
    times, frames = [0.0], [polylines_from_state(scene.model, state)]
    cols = {k: [] for k in ("step_time", "kinetic", "total_energy", "contacts", "fibre_contacts", "obstacle_contacts",
                            "max_joint_gap", "max_penetration", "newton_iterations", "qp_sweeps", "qp_capped",
                            "step_seconds", "substeps", "crossings_restored", "end_overlap", "joint_root_failures")}
    secs: dict[str, float] = {}
    for i in range(steps):
        state = solver.step(scene.model, state, scene.dt, scene.obstacles)
        st = solver.last_stats
        vmax = float(np.sqrt((state.velocity**2).sum(1).max()))
        if not vmax <= max_speed:
            raise DivergenceError(f"{scene.name}: a segment moves at {vmax:.3g} m/s at t = {state.time:.4g} s "
                                  f"(dt = {scene.dt:g} s); the simulation diverged — reduce dt or raise "
                                  "qp_iterations / harmonisation_iterations")
        if not st.max_joint_gap <= tear:
            raise DivergenceError(f"{scene.name}: a joint gap opened to {st.max_joint_gap * 1e3:.3g} mm at t = "
                                  f"{state.time:.4g} s, more than half a segment ({tear * 1e3:.3g} mm): the fibres "
                                  f"tore apart (dt = {scene.dt:g} s; the seed's 1 ms is safe for 70 µm fibres)")
        cols["step_time"].append(st.time)
        cols["kinetic"].append(st.kinetic_energy)
        cols["total_energy"].append(st.total_energy)
        cols["step_seconds"].append(st.seconds.get("total", 0.0))
        for k in ("contacts", "fibre_contacts", "obstacle_contacts", "max_joint_gap", "max_penetration",
                  "newton_iterations", "qp_sweeps", "qp_capped", "substeps", "crossings_restored", "end_overlap",
                  "joint_root_failures"):
            cols[k].append(getattr(st, k))
        for k, v in st.seconds.items():
            secs[k] = secs.get(k, 0.0) + v
        if (i + 1) % every == 0 or i + 1 == steps:
            times.append(state.time)
            frames.append(polylines_from_state(scene.model, state))
        if progress is not None:
            progress(i + 1, steps)
    return DrapeResult(np.array(times), np.array(frames), **{k: np.array(v) for k, v in cols.items()}, seconds=secs)


def write_drape(scene: DrapeScene, result: DrapeResult, folder: Path, *, render: bool = False,
                progress: Callable[[int, int], None] | None = None) -> list[Path]:
    """Write ``trajectory.npz``, ``vtk/frame_XXXX.vtu`` (polylines), ``energy_contacts.png``,
    ``frames/frame_XXXX.png`` (matplotlib) and, with ``render``, path-traced ``rendered/`` frames."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import meshio

    folder = Path(folder)
    files = []
    npz = folder / "trajectory.npz"
    np.savez_compressed(npz, times=result.times, polylines=result.polylines, step_time=result.step_time,
                        kinetic=result.kinetic, total_energy=result.total_energy, contacts=result.contacts,
                        fibre_contacts=result.fibre_contacts, obstacle_contacts=result.obstacle_contacts,
                        max_joint_gap=result.max_joint_gap, max_penetration=result.max_penetration,
                        newton_iterations=result.newton_iterations, qp_sweeps=result.qp_sweeps,
                        qp_capped=result.qp_capped, step_seconds=result.step_seconds, substeps=result.substeps,
                        crossings_restored=result.crossings_restored, end_overlap=result.end_overlap,
                        joint_root_failures=result.joint_root_failures, radius=scene.model.radius[0], dt=scene.dt)
    files.append(npz)
    (folder / "vtk").mkdir()
    F, nn = result.polylines.shape[1:3]
    seg = np.stack([np.arange(nn - 1), np.arange(1, nn)], 1)
    cells = np.concatenate([seg + f * nn for f in range(F)])
    for k in range(len(result.times)):
        p = folder / "vtk" / f"frame_{k:04d}.vtu"
        meshio.write(p, meshio.Mesh(result.polylines[k].reshape(-1, 3), [("line", cells)]), binary=True)
        files.append(p)
    fig, ax = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    ax[0].semilogy(result.step_time, np.maximum(result.kinetic, 1e-30), label="kinetic")
    ax[0].set_ylabel("kinetic energy [J]")
    ax[0].set_title(wrapped_title(scene.description), fontsize=7)
    ax[1].plot(result.step_time, result.fibre_contacts, label="fibre–fibre")
    ax[1].plot(result.step_time, result.obstacle_contacts, label="fibre–obstacle")
    ax[1].set_ylabel("active contacts")
    ax[1].set_xlabel("t [s]")
    ax[1].legend(fontsize=8)
    fig.tight_layout()
    p = folder / "energy_contacts.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files.append(p)
    files += write_frames(folder / "frames", scene.name, result.times, result.polylines, scene.obstacle_mesh)
    if render:
        from headsim.hair.render.frames import render_frames

        files += render_frames(list(result.polylines), folder / "rendered", radius=float(scene.model.radius[0]),
                               progress=progress, surfaces=render_surfaces(scene))
    return files
