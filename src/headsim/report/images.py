"""PNG pictures of meshes with matplotlib (headless, Agg backend).

:func:`render_mesh` draws a triangle mesh seen along a view axis as shaded, depth-sorted triangles
(painter's algorithm on a 2-D projection — fast for tens of thousands of triangles), either in a plain
colour with Lambert shading or coloured by a per-vertex scalar with a colour bar. Generic and reusable.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from headsim._atomic import atomic_output_file

__all__ = ["render_mesh", "render_panels"]

_VIEWS = {
    # view direction (camera looks along -axis), screen right, screen up
    "front": (np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])),
    "left": (np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0])),
    "right": (np.array([-1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])),
    "top": (np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0])),
}


def _draw(ax, vertices, triangles, scalar, view, cmap, vmin, vmax, color):
    import matplotlib.colors as mcolors
    from matplotlib.collections import PolyCollection

    toward, right, up = _VIEWS[view]
    v = np.asarray(vertices, float)
    t = np.asarray(triangles, np.int64)
    xy = np.column_stack([v @ right, v @ up])
    depth = (v @ toward)[t].mean(axis=1)
    n = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    nn = np.linalg.norm(n, axis=1)
    nn[nn == 0] = 1.0
    facing = (n @ toward) / nn
    keep = facing > 0  # back-face culling
    order = np.argsort(depth[keep])
    tk = t[keep][order]
    shade = 0.35 + 0.65 * np.clip(facing[keep][order], 0, 1)
    if scalar is not None:
        s = np.asarray(scalar, float)[tk].mean(axis=1)
        norm = mcolors.Normalize(vmin=vmin, vmax=vmax)
        rgba = cmap(norm(s))
        rgba[:, :3] *= (0.55 + 0.45 * shade)[:, None]
    else:
        base = np.array(mcolors.to_rgba(color))
        rgba = np.tile(base, (len(tk), 1))
        rgba[:, :3] *= shade[:, None]
    pc = PolyCollection(xy[tk], facecolors=rgba, edgecolors="none", antialiased=False)
    ax.add_collection(pc)
    ax.set_xlim(xy[:, 0].min(), xy[:, 0].max())
    ax.set_ylim(xy[:, 1].min(), xy[:, 1].max())
    ax.set_aspect("equal")
    ax.axis("off")


def render_panels(path: str | os.PathLike, panels: Sequence[dict], *, title: str = "", view: str = "front",
                  colorbar_label: str = "", cmap: str = "RdBu_r", symmetric: bool = True,
                  panel_size: float = 4.0, dpi: int = 120) -> Path:
    """Write a PNG with one panel per mesh, side by side.

    Each panel is a dict with ``vertices`` (n, 3), ``triangles`` (m, 3), optional ``scalar`` (n,) and
    ``title``. Scalar panels share one colour range (±max|scalar| when ``symmetric``). The file is
    written atomically.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib import cm
    import matplotlib.colors as mcolors

    if view not in _VIEWS:
        raise ValueError(f"view must be one of {sorted(_VIEWS)}")
    cmap_obj = plt.get_cmap(cmap)
    scalars = [np.asarray(p["scalar"], float) for p in panels if p.get("scalar") is not None]
    vmin = vmax = None
    if scalars:
        allv = np.concatenate(scalars)
        if symmetric:
            m = float(np.max(np.abs(allv))) or 1.0
            vmin, vmax = -m, m
        else:
            vmin, vmax = float(allv.min()), float(allv.max())
    fig, axes = plt.subplots(1, len(panels), figsize=(panel_size * len(panels), panel_size * 1.2), squeeze=False)
    for ax, p in zip(axes[0], panels):
        _draw(ax, p["vertices"], p["triangles"], p.get("scalar"), view, cmap_obj, vmin, vmax,
              p.get("color", "#d9b38c"))
        ax.set_title(p.get("title", ""))
    if scalars:
        sm = cm.ScalarMappable(norm=mcolors.Normalize(vmin=vmin, vmax=vmax), cmap=cmap_obj)
        fig.colorbar(sm, ax=list(axes[0]), shrink=0.7, label=colorbar_label)
    if title:
        fig.suptitle(title)
    path = Path(path)
    try:
        with atomic_output_file(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format="png")
    finally:
        plt.close(fig)
    return path


def render_mesh(path: str | os.PathLike, vertices: np.ndarray, triangles: np.ndarray,
                scalar: np.ndarray | None = None, **kwargs) -> Path:
    """Write a PNG of one mesh (see :func:`render_panels` for the keyword arguments)."""
    title = kwargs.pop("panel_title", "")
    return render_panels(path, [dict(vertices=vertices, triangles=triangles, scalar=scalar, title=title)], **kwargs)
