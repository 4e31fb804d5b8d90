"""The demo scenes of Monkin 2016 (seed 001) §4.5, figs. 2–5, on :mod:`headsim.solvers.pbd`.

- :func:`run_box_scene`: 8,000 particles (radius 0.4 m, mass 0.286 kg) under gravity in a closed box, with
  particle–particle collisions found on a voxel grid (fig. 2).
- :func:`run_ball_scene`: a ball (642 vertices, 1,280 triangles) with the volume constraint, gravity and
  hydrostatic pressure dropped on a plane (fig. 3). The seed's "radius 1" with volume 0.00415 fits a
  radius of 0.1 (in the seed's metres: an icosphere of radius 0.1 with 642 vertices encloses 0.004153 m³),
  so the ball here has radius 0.1 m.
- :func:`run_cloth_scene`: cloth patches of different mesh density (total mass 10 kg), pinned at their
  corners, with soft balls (volume constraint) falling on them (figs. 4–5). Ball–cloth contact is a
  sphere–particle constraint on the ball's current centre and rest radius, the correction shared by mass
  between the cloth particle and the whole ball (a simplification of the seed's particle–polygon test).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from headsim.mesh.primitives import icosphere
from headsim.solvers.pbd import PBDModel, PBDOptions, PBDSolver, PBDState

#: contact mass scaling of the box scene, k × particle diameter (Macklin et al. 2014), see run_box_scene.
#: Measured (8,000 particles, 10 Jacobi sweeps, 300 steps): deepest overlap 26.5 % of the diameter without,
#: 3.3 % with 0.5, 3.7 % with 1.0 (the pile still bouncing), unstable at 3
MASS_SCALING_PER_DIAMETER = 0.5

__all__ = ["SceneResult", "run_box_scene", "run_ball_scene", "run_cloth_scene", "save_scene_result"]


@dataclass(frozen=True, eq=False)
class SceneResult:
    """Final positions (n, 3) m, triangles of the meshes in the scene ((m, 3), may be empty), numbers."""

    name: str
    positions: np.ndarray
    triangles: np.ndarray
    numbers: dict = field(default_factory=dict)
    radius: float = 0.0


def run_box_scene(n_particles: int = 8000, steps: int | None = None, *, radius: float = 0.4,
                  mass: float = 0.286, box_size: float = 12.0, dt: float = 1.0 / 60.0,
                  iterations: int = 10, seed: int = 0, mass_scaling: float | None = None) -> SceneResult:
    """Particles dropped into a closed box (seed fig. 2). Returns positions and penetration numbers.

    Contacts are projected by averaged Jacobi sweeps; a pile of ~47 layers (8,000 particles) needs the mass
    scaling of Macklin et al. 2014 (``mass_scaling`` k in 1/m, default MASS_SCALING_PER_DIAMETER / diameter;
    0 = off) to be held up within 10 sweeps per step.
    """
    steps = 300 if steps is None else steps
    rng = np.random.default_rng(seed)
    spacing = 2.0 * radius * 1.05
    per_row = max(int((box_size - 2 * radius) / spacing), 1)
    idx = np.arange(n_particles)
    ix, iz, iy = idx % per_row, (idx // per_row) % per_row, idx // (per_row * per_row)
    start = np.column_stack([ix, iy, iz]) * spacing + radius * 1.05
    start[:, [0, 2]] -= box_size / 2
    start += rng.uniform(-0.02, 0.02, size=start.shape) * radius
    height = float(start[:, 1].max() + 2 * radius)
    half = box_size / 2
    planes_p = [[0, 0, 0], [0, height, 0], [-half, 0, 0], [half, 0, 0], [0, 0, -half], [0, 0, half]]
    planes_n = [[0, 1, 0], [0, -1, 0], [1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 0, -1]]
    model = PBDModel(mass=np.full(n_particles, mass), fixed=np.zeros(n_particles, bool), edges=np.zeros((0, 2)),
                     rest_length=np.zeros(0), plane_points=planes_p, plane_normals=planes_n,
                     collision_radius=radius, particle_contacts=True)
    k = (MASS_SCALING_PER_DIAMETER / (2 * radius)) if mass_scaling is None else mass_scaling
    solver = PBDSolver(model, PBDOptions(dt=dt, iterations=iterations, damping=0.01, contact_mass_scaling=k))
    state = PBDState.at_rest(start)
    for _ in range(steps):
        state = solver.step(state)
    p = state.positions
    from scipy.spatial import cKDTree

    pairs = cKDTree(p).query_pairs(2 * radius * 0.999, output_type="ndarray")
    gaps = np.linalg.norm(p[pairs[:, 0]] - p[pairs[:, 1]], axis=1) if len(pairs) else np.zeros(0)
    inside = np.all((p[:, [0, 2]] >= -half + radius * 0.999) & (p[:, [0, 2]] <= half - radius * 0.999), axis=1) \
        & (p[:, 1] >= radius * 0.999) & (p[:, 1] <= height - radius * 0.999)
    numbers = {
        "particles": n_particles, "radius_m": radius, "mass_kg": mass, "steps": steps, "dt_s": dt,
        "overlapping_pairs": int(len(pairs)),
        "deepest_overlap_fraction_of_diameter": float(1 - gaps.min() / (2 * radius)) if len(gaps) else 0.0,
        "particles_inside_box": int(inside.sum()),
        "kinetic_energy_J": float(0.5 * mass * np.sum(state.velocities ** 2)),
        "pile_height_m": float(p[:, 1].max() + radius),
        "start_height_m": float(start[:, 1].max() + radius),
    }
    return SceneResult("box", p, np.zeros((0, 3), np.int64), numbers, radius)


def run_ball_scene(steps: int | None = None, *, radius: float = 0.1, subdivisions: int = 3, drop_height: float = 0.3,
                   mass: float = 1.0, fluid_density: float = 800.0, edge_compliance: float = 1e-4,
                   dt: float = 1.0 / 120.0, iterations: int = 10, damping: float = 0.02) -> SceneResult:
    """A soft ball with the volume constraint, gravity and hydrostatic pressure dropped on the plane y = 0
    (seed fig. 3). ``steps`` None runs to the stop rule (max 3,000 steps)."""
    ball = icosphere(radius, subdivisions, center=(0.0, drop_height, 0.0))
    model = PBDModel.from_surface(ball.vertices, ball.triangles, total_mass=mass, closed_bodies=True,
                                  fluid_density=fluid_density, plane_points=[[0, 0, 0]], plane_normals=[[0, 1, 0]])
    options = PBDOptions(dt=dt, iterations=iterations, damping=damping, xpbd=True, edge_compliance=edge_compliance,
                         stop_tolerance=1e-8, max_steps=3000 if steps is None else steps,
                         min_steps=3 if steps is None else steps)
    solver = PBDSolver(model, options)
    state, info = solver.solve(PBDState.at_rest(ball.vertices))
    v0 = float(model.volume_target[0])
    v1 = float(model.body_volumes(state.positions)[0])
    p = state.positions
    numbers = {
        "vertices": ball.n_vertices, "triangles": ball.n_triangles, "radius_m": radius,
        "initial_volume_m3": v0, "final_volume_m3": v1, "relative_volume_change": (v1 - v0) / v0,
        "fluid_density_kg_m3": fluid_density, "steps": info.steps, "stopped_by_rule": info.converged,
        "lowest_point_m": float(p[:, 1].min()), "height_m": float(np.ptp(p[:, 1])),
        "width_m": float(np.ptp(p[:, 0])),
    }
    return SceneResult("ball", p, ball.triangles, numbers)


def _cloth_grid(n: int, size: float, center) -> tuple[np.ndarray, np.ndarray]:
    s = np.linspace(-size / 2, size / 2, n + 1)
    x, z = np.meshgrid(s, s, indexing="ij")
    v = np.column_stack([x.ravel(), np.zeros(x.size), z.ravel()]) + np.asarray(center, float)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tri = np.concatenate([np.column_stack([a, d, c]), np.column_stack([a, c, b])])  # normals +y
    return v, tri


class _BallClothContacts:
    """Sphere–particle contacts between balls (current centre, rest radius + thickness) and cloth particles.

    The penetration is shared by inverse mass between the cloth particle and the ball, whose share moves
    all its particles rigidly (linear momentum of the pair is conserved).
    """

    def __init__(self, ball_ids: list[np.ndarray], radii: list[float], cloth_ids: np.ndarray, thickness: float):
        self.ball_ids, self.radii, self.cloth_ids, self.thickness = ball_ids, radii, cloth_ids, thickness

    def __call__(self, p: np.ndarray, w: np.ndarray) -> None:
        cloth = self.cloth_ids
        for ids, r in zip(self.ball_ids, self.radii):
            centre = p[ids].mean(axis=0)
            d = p[cloth] - centre
            dist = np.linalg.norm(d, axis=1)
            reach = r + self.thickness
            hit = (dist < reach) & (dist > 0)
            if not hit.any():
                continue
            n = d[hit] / dist[hit, None]
            depth = reach - dist[hit]
            w_cloth = w[cloth[hit]]
            w_ball = 1.0 / np.sum(1.0 / w[ids])
            share_c = w_cloth / (w_cloth + w_ball)
            share_b = w_ball / (w_cloth + w_ball)
            p[cloth[hit]] += (share_c * depth)[:, None] * n
            p[ids] -= np.sum((share_b * depth)[:, None] * n, axis=0)


def run_cloth_scene(steps: int | None = None, *, resolutions=(8, 12, 16, 24), cloth_size: float = 1.0,
                    cloth_mass: float = 10.0, ball_radius: float = 0.2, ball_mass: float = 1.0,
                    dt: float = 1.0 / 120.0, iterations: int = 30) -> SceneResult:
    """Cloth patches of different density, pinned at the corners, with a soft ball falling on each
    (seed figs. 4–5). Cloth mass is spread over all cloth particles by area.

    The seed's balls were 8× heavier than their cloth; with hard PBD distance constraints and corner pins
    that stretches the cloth by ~150 % at 10 sweeps (PBD stiffness depends on the sweep count), so the
    default balls weigh 1 kg and 30 sweeps are used (max stretch ~25 %)."""
    steps = 240 if steps is None else steps
    verts, tris, fixed, masses = [], [], [], []
    offset = 0
    cloth_area_total = len(resolutions) * cloth_size ** 2
    centres = [(-0.6, 0.0, -0.6), (0.6, 0.0, -0.6), (-0.6, 0.0, 0.6), (0.6, 0.0, 0.6)]
    cloth_ids = []
    for n, c in zip(resolutions, centres):
        v, t = _cloth_grid(n, cloth_size, c)
        pin = np.zeros(len(v), bool)
        pin[[0, n, (n + 1) * n, (n + 1) ** 2 - 1]] = True
        from headsim.mesh import geometry

        m = cloth_mass * geometry.vertex_areas(v, t) / cloth_area_total
        verts.append(v)
        tris.append(t + offset)
        fixed.append(pin)
        masses.append(m)
        cloth_ids.append(np.arange(len(v)) + offset)
        offset += len(v)
    ball_ids, vol_tris, vol_body = [], [], []
    for b, c in enumerate(centres[:len(resolutions)]):
        ball = icosphere(ball_radius, 2, center=(c[0], 0.4, c[2]))
        verts.append(ball.vertices)
        tris.append(ball.triangles + offset)
        vol_tris.append(ball.triangles + offset)
        vol_body.append(np.full(ball.n_triangles, b))
        fixed.append(np.zeros(ball.n_vertices, bool))
        from headsim.solvers.pbd import particle_masses

        masses.append(particle_masses(ball.vertices, ball.triangles, ball_mass))
        ball_ids.append(np.arange(ball.n_vertices) + offset)
        offset += ball.n_vertices
    v = np.vstack(verts)
    t = np.vstack(tris)
    from headsim.mesh import geometry

    edges, _ = geometry.unique_edges(t)
    rest = np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1)
    vt = np.vstack(vol_tris)
    vb = np.concatenate(vol_body)
    probe = PBDModel(mass=np.concatenate(masses), fixed=np.concatenate(fixed), edges=edges, rest_length=rest,
                     volume_triangles=vt, volume_body=vb, volume_target=np.zeros(len(ball_ids)))
    model = PBDModel(mass=probe.mass, fixed=probe.fixed, edges=edges, rest_length=rest, volume_triangles=vt,
                     volume_body=vb, volume_target=probe.body_volumes(v))
    contacts = _BallClothContacts(ball_ids, [ball_radius] * len(ball_ids), np.concatenate(cloth_ids), 0.01)
    solver = PBDSolver(model, PBDOptions(dt=dt, iterations=iterations, damping=0.01), extra_constraints=(contacts,))
    state = PBDState.at_rest(v)
    for _ in range(steps):
        state = solver.step(state)
    p = state.positions
    vols = model.body_volumes(p)
    cloth_all = np.concatenate(cloth_ids)
    gaps = [float(np.min(np.linalg.norm(p[cloth_all] - p[ids].mean(axis=0), axis=1)) - ball_radius) for ids in ball_ids]
    cloth_edges = np.isin(edges[:, 0], cloth_all)
    stretch = np.linalg.norm(p[edges[cloth_edges, 0]] - p[edges[cloth_edges, 1]], axis=1) / rest[cloth_edges] - 1
    numbers = {
        "cloth_vertices": int(len(cloth_all)), "balls": len(ball_ids), "vertices": int(len(v)),
        "triangles": int(len(t)), "steps": steps,
        "ball_relative_volume_change": ((vols - model.volume_target) / model.volume_target).tolist(),
        "ball_to_cloth_clearance_m": gaps, "cloth_max_stretch": float(stretch.max()),
        "ball_centre_height_m": [float(p[ids, 1].mean()) for ids in ball_ids],
    }
    return SceneResult("cloth", p, t, numbers)


def save_scene_result(result: SceneResult, folder: str | Path) -> None:
    """Write ``numbers.json``, ``positions.npy`` and ``scene.png`` (matplotlib) into ``folder``."""
    folder = Path(folder)
    (folder / "numbers.json").write_text(json.dumps(result.numbers, indent=1))
    np.save(folder / "positions.npy", result.positions)
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    p = result.positions
    if len(result.triangles):
        ax.plot_trisurf(p[:, 0], p[:, 2], p[:, 1], triangles=result.triangles, color="#d9b38c", linewidth=0.1,
                        edgecolor="k", alpha=0.9)
    else:
        ax.scatter(p[:, 0], p[:, 2], p[:, 1], s=2, c=p[:, 1], cmap="viridis")
    ax.set_box_aspect(np.maximum(np.ptp(p[:, [0, 2, 1]], axis=0), 1e-9))  # equal scale on all axes
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_zlabel("y (m)")
    ax.set_title(f"{result.name} scene (Monkin 2016 §4.5)")
    fig.savefig(folder / "scene.png", dpi=100)
    plt.close(fig)
