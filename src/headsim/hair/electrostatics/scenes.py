"""Scenes of Sobottka (2008) §4.5 with the material looked up at (T, RH) (Alg. 2 line 3).

* :func:`bundle_scene` — test 1: pre-curved fibres (default 300 x 30 cm x 100 segments) whose roots
  are spread uniformly (Vogel spiral) over an ellipse at 200 fibres/cm^2, hanging along -y.
  Smaller versions for tests: fewer fibres, shorter, fewer segments.
* :func:`symmetric_bundle` — straight fibres on a hexagonal pattern with C6 symmetry about the y
  axis (root frames rotate with the pattern), for the symmetry test of the charging schedule.
* :func:`head_scene` — a hairstyle on the upper half of the bundled head (roots on scalp vertices,
  growing along the normal, pre-curved backwards) with the head as the charged surface.

The material: bending modulus E_B and torsion modulus G from ``properties.moduli(rh, T)``, the
elliptic section (with humidity swelling, so the weight rho A grows with RH) from
``properties.cross_section(rh=, T=)``, density 1300 kg/m^3.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.errors import ParameterError
from headsim.hair import properties as props
from headsim.solvers.rods import RodModel, straight_frame

__all__ = ["ChargingScene", "material_model", "bundle_scene", "symmetric_bundle", "head_scene"]

GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


@dataclass(frozen=True, eq=False)
class ChargingScene:
    """model: the fibres; scalp: a distance field or None; axis_point/axis (3,): the bundle axis used
    for the spread measure; info: numbers for the report."""

    name: str
    model: RodModel
    scalp: object
    axis_point: np.ndarray
    axis: np.ndarray
    info: dict


def material_model(roots, directions, normals, length: float, n_segments: int, natural_curvature=(0.0, 0.0, 0.0),
                   relative_humidity: float = 0.65, temperature_c: float = 25.0, circular: bool = False) -> RodModel:
    """RodModel of F fibres with per-fibre roots (F, 3) m, root directions and normal hints (F, 3),
    material from the property database at (rh in [0, 1], T in C)."""
    roots = np.asarray(roots, float).reshape(-1, 3)
    F = roots.shape[0]
    sec = props.cross_section("caucasian", relative_humidity, temperature_c)
    if circular:
        r = float(np.sqrt(sec.a * sec.b))
        sec = props.CrossSection(r, r)
    mod = props.moduli(relative_humidity, temperature_c)
    rho = props.MASS_DENSITY.value
    K = np.array([mod.bend * sec.I1, mod.bend * sec.I2, mod.torsion * sec.polar])
    rhoI = rho * np.array([sec.I1, sec.I2, sec.polar])
    frames = np.stack([straight_frame(d, n) for d, n in zip(np.asarray(directions, float).reshape(-1, 3),
                                                          np.asarray(normals, float).reshape(-1, 3))])
    k0 = np.broadcast_to(np.asarray(natural_curvature, float), (F, n_segments + 1, 3))
    return RodModel(int(n_segments), np.full(F, float(length)), np.full(F, rho * sec.area),
                    np.broadcast_to(rhoI, (F, 3)), np.broadcast_to(K, (F, 3)), k0, roots, frames)


def bundle_scene(n_fibres: int = 300, length: float = 0.30, n_segments: int = 100, root_density_cm2: float = 200.0,
                 curvature: float = 10.0, ellipse_ratio: float = 2.0, relative_humidity: float = 0.65,
                 temperature_c: float = 25.0) -> ChargingScene:
    """Test 1 of Sobottka §4.5 (defaults); curvature 1/m about d1 (all fibres curl towards +x)."""
    if n_fibres < 1 or root_density_cm2 <= 0 or ellipse_ratio < 1:
        raise ParameterError("need n_fibres >= 1, a positive root density and ellipse_ratio >= 1")
    area = n_fibres / root_density_cm2 * 1e-4  # m^2
    b = np.sqrt(area / (np.pi * ellipse_ratio))
    a = ellipse_ratio * b
    k = np.arange(n_fibres)
    r = np.sqrt((k + 0.5) / n_fibres)
    phi = k * GOLDEN_ANGLE
    roots = np.column_stack([a * r * np.cos(phi), np.zeros(n_fibres), b * r * np.sin(phi)])
    dirs = np.tile([0.0, -1.0, 0.0], (n_fibres, 1))
    normals = np.tile([1.0, 0.0, 0.0], (n_fibres, 1))
    model = material_model(roots, dirs, normals, length, n_segments, (curvature, 0.0, 0.0), relative_humidity,
                           temperature_c)
    info = {"fibres": n_fibres, "length_m": length, "segments": n_segments, "ellipse_semi_axes_m": [a, b],
            "root_density_per_cm2": root_density_cm2, "curvature_per_m": curvature, "rh": relative_humidity,
            "temperature_c": temperature_c}
    return ChargingScene("bundle", model, None, np.zeros(3), np.array([0.0, -1.0, 0.0]), info)


def symmetric_bundle(rings: int = 1, spacing: float = 1e-3, length: float = 0.1, n_segments: int = 20,
                     relative_humidity: float = 0.65, temperature_c: float = 25.0, circular: bool = True):
    """Hexagonal bundle (1 + 6 + 12 ... fibres) hanging along -y; returns (scene, permutation (F,) of
    the fibres under a rotation by 60 degrees about the y axis)."""
    pts = [np.zeros(3)]
    for ring in range(1, rings + 1):
        for m in range(6 * ring):
            ang = 2 * np.pi * m / (6 * ring)
            pts.append(ring * spacing * np.array([np.cos(ang), 0.0, np.sin(ang)]))
    roots = np.array(pts)
    F = len(roots)
    radial = roots.copy()
    radial[0] = [1.0, 0.0, 0.0]
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    dirs = np.tile([0.0, -1.0, 0.0], (F, 1))
    model = material_model(roots, dirs, radial, length, n_segments, (0.0, 0.0, 0.0), relative_humidity,
                           temperature_c, circular=circular)
    c, s = np.cos(np.pi / 3), np.sin(np.pi / 3)
    R = np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]])  # (x, z) rotated by +60 degrees
    img = roots @ R.T
    perm = np.array([int(np.argmin(np.linalg.norm(roots - p, axis=1))) for p in img])
    scene = ChargingScene("symmetric-bundle", model, None, np.zeros(3), np.array([0.0, -1.0, 0.0]),
                          {"fibres": F, "rings": rings, "spacing_m": spacing, "length_m": length,
                           "segments": n_segments, "rh": relative_humidity, "temperature_c": temperature_c,
                           "rotation": R.tolist()})
    return scene, perm


def head_scene(n_fibres: int = 400, length: float = 0.12, n_segments: int = 30, curvature: float = 8.0,
               relative_humidity: float = 0.65, temperature_c: float = 25.0, seed: int = 0) -> ChargingScene:
    """Half-head hairstyle on the bundled head (y up, +z out of the face): roots on vertices of the upper
    back half (y above the 60 % height, z below the 70 % depth), growing along the vertex normal and
    curling backwards; the head is the charged surface (exact mesh distance)."""
    import trimesh

    from headsim.data import head_path
    from headsim.hair.electrostatics.scalp import MeshDistance

    mesh = trimesh.load(head_path(), process=False)
    V = np.asarray(mesh.vertices, float)
    T = np.asarray(mesh.faces, np.int64)
    N = np.asarray(mesh.vertex_normals, float)
    lo, hi = V.min(0), V.max(0)
    centre = 0.5 * (lo + hi)
    sel = (V[:, 1] > lo[1] + 0.6 * (hi[1] - lo[1])) & (V[:, 2] < lo[2] + 0.7 * (hi[2] - lo[2]))
    sel &= np.einsum("ij,ij->i", N, V - centre) > 0  # outward-facing
    ids = np.flatnonzero(sel)
    if ids.size == 0:
        raise ParameterError("no scalp vertices found on the bundled head")
    rng = np.random.default_rng(seed)
    pick = rng.choice(ids, size=min(n_fibres, ids.size), replace=False)
    roots = V[pick] + 1e-4 * N[pick]
    back = np.array([0.0, 0.0, -1.0])
    hints = np.cross(N[pick], back)
    hints[np.linalg.norm(hints, axis=1) < 1e-6] = [1.0, 0.0, 0.0]
    model = material_model(roots, N[pick], hints, length, n_segments, (curvature, 0.0, 0.0), relative_humidity,
                           temperature_c)
    top = np.array([centre[0], hi[1], centre[2]])
    return ChargingScene("head", model, MeshDistance(V, T), top, np.array([0.0, 1.0, 0.0]),
                         {"fibres": len(pick), "length_m": length, "segments": n_segments, "rh": relative_humidity,
                          "temperature_c": temperature_c, "mesh": str(head_path())})
