"""Write a reconstructed hairstyle: fibres as NPZ (the layout ``headsim hair render`` reads: ``nodes`` (n, 3) m,
``fibre_offsets`` (F+1,) int64, ``radius``) and VTK polylines, the inputs as OBJ (metres), a JSON summary
and pictures (matplotlib views, the parametrisation with its stretch, the occupancy histogram of Fig. 5.6,
optionally a path-traced frame)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from headsim.hair.reconstruct.density import occupancy_counts
from headsim.hair.reconstruct.inputs import StyleInputs
from headsim.hair.reconstruct.pipeline import OCCUPANCY_CELL, Hairstyle

__all__ = ["write_hairstyle", "save_fibres_npz", "plot_views", "plot_parametrisation", "plot_occupancy"]


def save_fibres_npz(path: Path, hs: Hairstyle) -> None:
    np.savez_compressed(path, nodes=hs.nodes, fibre_offsets=hs.fibre_offsets,
                        radius=np.full(len(hs.nodes), hs.radius), strand=hs.strand, is_guide=hs.is_guide,
                        guides=hs.guides, guide_kept=hs.guide_kept, preguides=hs.preguides)


def _save_vtu(path: Path, hs: Hairstyle) -> None:
    import meshio

    off = hs.fibre_offsets
    n = len(hs.nodes)
    last = np.zeros(n, bool)
    last[off[1:] - 1] = True
    i = np.flatnonzero(~last)
    fibre = np.repeat(np.arange(len(off) - 1), np.diff(off) - 1)
    meshio.write(path, meshio.Mesh(hs.nodes, [("line", np.column_stack([i, i + 1]))],
                                   cell_data={"strand": [hs.strand[fibre].astype(np.int32)],
                                              "guide": [hs.is_guide[fibre].astype(np.int32)]}), binary=True)


def _fibre_list(hs: Hairstyle, every: int):
    off = hs.fibre_offsets
    return [hs.nodes[off[f]:off[f + 1]] for f in range(0, len(off) - 1, every)]


def plot_views(path: Path, hs: Hairstyle, inputs: StyleInputs, title: str, max_fibres: int = 4000) -> None:
    """Front (x, y), side (z, y) and top (x, z) views of the fibres over the head's silhouette."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    every = max(1, hs.n_fibres // max_fibres)
    fib = _fibre_list(hs, every)
    head = inputs.head.vertices
    fig, axes = plt.subplots(1, 3, figsize=(15, 5.6), dpi=110)
    for ax, (i, j, name) in zip(axes, [(0, 1, "front (x, y)"), (2, 1, "side (z, y)"), (0, 2, "top (x, z)")]):
        ax.scatter(head[::3, i], head[::3, j], s=0.2, c="0.8", rasterized=True)
        col = plt.cm.copper(np.linspace(0.2, 0.9, len(fib)))
        ax.add_collection(LineCollection([p[:, [i, j]] for p in fib], colors=col, linewidths=0.35, alpha=0.8))
        ax.set_aspect("equal")
        ax.autoscale()
        ax.set_title(name)
        ax.set_xlabel("m")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_parametrisation(path: Path, hs: Hairstyle) -> None:
    """The scalp on the unit disk coloured by the per-triangle stretch, with the guide roots."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from headsim.mesh.disk_parametrisation import triangle_stretch

    sm = hs.scalp_map
    uv, t = sm.param.uv, sm.scalp.triangles
    st = triangle_stretch(sm.scalp.vertices, t, uv)
    st = st / np.sqrt((sm.areas * st**2).sum() / sm.areas.sum())
    fig, ax = plt.subplots(figsize=(6.5, 6), dpi=110)
    from matplotlib.colors import LogNorm

    tp = ax.tripcolor(uv[:, 0], uv[:, 1], t, facecolors=st, cmap="viridis", edgecolors="none",
                      norm=LogNorm(vmin=max(np.percentile(st, 1), 1e-3), vmax=np.percentile(st, 99)))
    ax.triplot(uv[:, 0], uv[:, 1], t, color="w", lw=0.1, alpha=0.4)
    fig.colorbar(tp, ax=ax, label="L2 stretch / mean")
    hist = ", ".join(f"{s:.3f}" for s in sm.param.stretch_history)
    ax.set_title(f"Floater mean-value map + stretch relaxation\ntotal stretch {hist}", fontsize=9)
    ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_occupancy(path: Path, results: dict[str, Hairstyle]) -> None:
    """Histogram of segments per occupied cell (Fig. 5.6), one curve per run (e.g. density models)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4), dpi=110)
    for name, hs in results.items():
        c = occupancy_counts(hs.nodes, hs.fibre_offsets, OCCUPANCY_CELL)
        bins = np.arange(1, max(51, int(np.percentile(c, 99)) + 2))
        ax.hist(c, bins=bins, histtype="step", label=f"{name}: CV {c.std() / c.mean():.3f}")
    ax.set_xlabel(f"segments per cell ({OCCUPANCY_CELL * 1e3:g} mm)")
    ax.set_ylabel("cells")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def write_hairstyle(folder: Path, hs: Hairstyle, inputs: StyleInputs, summary: dict, *, images: bool = True,
                    render: bool = False, preset: str = "brown") -> list[Path]:
    """Write everything into ``folder`` (which exists). Returns the written files."""
    from headsim.mesh.io import save_surface

    folder = Path(folder)
    files = [folder / "fibres.npz", folder / "fibres.vtu", folder / "scalp.obj", folder / "volume.obj",
             folder / "style.json"]
    save_fibres_npz(files[0], hs)
    _save_vtu(files[1], hs)
    save_surface(inputs.scalp, files[2])
    save_surface(inputs.volume, files[3])
    files[4].write_text(json.dumps(summary, indent=2, default=float))
    if images:
        files.append(folder / "views.png")
        plot_views(files[-1], hs, inputs, f"{inputs.description}: {hs.n_fibres} fibres, {len(hs.guides)} guides")
        files.append(folder / "parametrisation.png")
        plot_parametrisation(files[-1], hs)
        files.append(folder / "occupancy.png")
        plot_occupancy(files[-1], {summary.get("density_model", "result"): hs})
    if render:
        from headsim.hair.render.bvh import CapsuleBVH, FibreAssembly
        from headsim.hair.render.renderer import Light, RenderOptions, camera_looking_at, render as trace, save_png
        from headsim.hair.render.scattering import MarschnerParams

        span = float(np.ptp(hs.nodes, axis=0).max())
        fibres = FibreAssembly(hs.nodes, hs.fibre_offsets, max(hs.radius, 0.5 * span / 384))
        cam = camera_looking_at(fibres, azimuth_deg=35.0, elevation_deg=15.0)
        res = trace(CapsuleBVH.from_fibres(fibres), MarschnerParams.preset(preset), cam,
                    [Light("directional", (1.0, 0.8, 0.6), (3.0, 3.0, 3.0))],
                    RenderOptions(width=384, height=384, spp=8, env=(0.05,) * 3, background=(0.05,) * 3))
        files.append(folder / "rendered.png")
        save_png(files[-1], res.image, 2.0)
    return files
