"""Pictures of a drape run (``headsim hair drape``): the obstacle's surface as a triangle mesh and the
matplotlib frames that show the fibres on it (SI units inside, centimetres on the axes)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

# the obstacle's picture mesh: how finely a sphere and a plane patch are triangulated
SPHERE_SUBDIVISIONS = 4  # icosphere: 5,120 triangles, edge ≈ 0.06 R
PLANE_CELLS = 24  # cells per side of the square plane patch


def sphere_surface(centre, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh (vertices (V, 3) m, triangles (T, 3)) of a sphere: an icosphere whose vertices lie on it."""
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIVISIONS, radius=float(radius))
    return np.asarray(s.vertices, float) + np.asarray(centre, float), np.asarray(s.faces, np.int64)


def plane_patch(point, normal, centre, half_size: float) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh of the square of side 2 ``half_size`` (m) in the plane through ``point`` with ``normal``,
    centred at the projection of ``centre`` onto it (a grid of :data:`PLANE_CELLS`², so that the frames'
    depth sorting has small faces to work with)."""
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    p0 = np.asarray(point, float)
    c = np.asarray(centre, float)
    c = c - np.dot(c - p0, n) * n
    helper = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    s = np.linspace(-half_size, half_size, PLANE_CELLS + 1)
    A, B = np.meshgrid(s, s, indexing="ij")
    v = c + A.reshape(-1, 1) * t1 + B.reshape(-1, 1) * t2
    k = PLANE_CELLS + 1
    idx = np.arange(k * k).reshape(k, k)
    a, b, cc, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return v, np.concatenate([np.stack([a, b, cc], 1), np.stack([a, cc, d], 1)]).astype(np.int64)


def _cm(axis):
    """Tick labels of a matplotlib axis in centimetres (the data are in metres)."""
    from matplotlib.ticker import FuncFormatter

    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{100.0 * v:.0f}"))


def view_box(polylines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) corners, m, of the cube that holds every recorded frame's fibres with a 10 % margin: the view
    of the frames and of the report's 3-D figure."""
    allp = np.asarray(polylines).reshape(-1, 3)
    lo, hi = allp.min(0), allp.max(0)
    mid, span = 0.5 * (lo + hi), 0.55 * float((hi - lo).max()) + 1e-6
    return mid - span, mid + span


def clip_to_box(vertices: np.ndarray, triangles: np.ndarray, lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """The part of a triangle mesh (vertices (n, 3) m, triangles (m, 3)) inside the box [lower, upper]: every
    triangle cut by the box's six planes (trimesh's ``slice_faces_plane``), so the surface ends on the box instead of
    at the last triangle wholly inside. Returns (vertices (n', 3), triangles (m', 3)), only the vertices used."""
    from trimesh.intersections import slice_faces_plane

    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    lower, upper = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    for axis in range(3):
        for sign, bound in ((1.0, lower), (-1.0, upper)):
            if not len(t):
                return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
            normal = np.zeros(3)
            normal[axis] = sign
            origin = np.zeros(3)
            origin[axis] = bound[axis]
            v, t = slice_faces_plane(v, t, normal, origin)[:2]
    used, inverse = np.unique(t, return_inverse=True)
    return v[used], inverse.reshape(-1, 3).astype(np.int64)


def write_frames(folder: Path, name: str, times: np.ndarray, polylines: np.ndarray,
                 obstacle_mesh: tuple | None = None) -> list[Path]:
    """``folder/frame_XXXX.png`` for every recorded frame: the fibres (at most 150 drawn) over the part of the
    obstacle's surface inside one view box that holds every frame's fibres, y up, axes in cm. Returns the paths.

    The obstacle is drawn half transparent under the fibres (matplotlib sorts whole artists by depth, not
    pixels, so the fibres are always drawn last: a fibre behind the obstacle shows through it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    folder = Path(folder)
    folder.mkdir()
    F = polylines.shape[1]
    lower, upper = view_box(polylines)
    tris = None
    if obstacle_mesh is not None:
        v, t = clip_to_box(*obstacle_mesh, lower, upper)
        if len(t):
            tris = v[t][:, :, [0, 2, 1]]  # plotted as (x, z, y): y is the picture's vertical
    sub = max(1, F // 150)
    files = []
    for k in range(len(times)):
        fig = plt.figure(figsize=(4.5, 4.5))
        a3 = fig.add_subplot(projection="3d", computed_zorder=False)
        if tris is not None:
            a3.add_collection3d(Poly3DCollection(tris, facecolor=(0.62, 0.68, 0.78, 0.35), edgecolor="none",
                                                 zorder=1))
        for q in polylines[k][::sub]:
            a3.plot(q[:, 0], q[:, 2], q[:, 1], color="saddlebrown", lw=0.5, zorder=2)
        a3.set_xlim(lower[0], upper[0])
        a3.set_ylim(lower[2], upper[2])
        a3.set_zlim(lower[1], upper[1])
        a3.set_box_aspect((1, 1, 1))
        for axis, label in ((a3.xaxis, "x [cm]"), (a3.yaxis, "z [cm]"), (a3.zaxis, "y [cm]")):
            _cm(axis)
            axis.set_label_text(label, fontsize=7)
        a3.tick_params(labelsize=6)
        a3.set_title(f"{name}  t = {times[k]:.3f} s", fontsize=8)
        p = folder / f"frame_{k:04d}.png"
        fig.savefig(p, dpi=80)
        plt.close(fig)
        files.append(p)
    return files


def wrapped_title(text: str, width: int = 110) -> str:
    """A scene description broken into lines that fit a figure's width."""
    return textwrap.fill(text, width)
