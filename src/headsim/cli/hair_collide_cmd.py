"""``headsim hair collide``: fibre–fibre and fibre–head collision detection on a synthetic scene.

The ``hair`` command group lives in ``hair_cmd.py``; it calls :func:`register` to add this command.
Heavy imports happen inside the command.
"""

from __future__ import annotations

from pathlib import Path

import typer

SCENES = ("strand", "head", "soup")


def _picture(fibres, contacts, obstacle, path: Path, title: str) -> None:
    """PNG: fibres (thin grey, subsampled) and contact points (red: fibre–fibre, blue: head), 2 views."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.collections import LineCollection

    fig, axes = plt.subplots(1, 2, figsize=(12, 6.5), dpi=110)
    step = max(1, fibres.n_fibres // 1500)
    for ax, (i, j, name) in zip(axes, [(0, 1, "front (x, y)"), (2, 1, "side (z, y)")]):
        lines = []
        for f in range(0, fibres.n_fibres, step):
            x = fibres.nodes[fibres.fibre_offsets[f]:fibres.fibre_offsets[f + 1]]
            lines.append(x[:, [i, j]])
        ax.add_collection(LineCollection(lines, colors="0.6", linewidths=0.3, alpha=0.6))
        pts = contacts.point_a
        if len(pts):
            sel = np.random.default_rng(0).choice(len(pts), min(len(pts), 20000), replace=False)
            ax.scatter(pts[sel, i], pts[sel, j], s=1.5, c="crimson", lw=0, label=f"fibre–fibre ({len(pts):,})")
        if len(obstacle):
            ax.scatter(obstacle.point_a[:, i], obstacle.point_a[:, j], s=2, c="royalblue", lw=0,
                       label=f"fibre–head ({len(obstacle):,})")
        ax.autoscale()
        x0, x1 = ax.get_xlim()
        y0, y1 = ax.get_ylim()
        if max(x1 - x0, y1 - y0) < 5 * min(x1 - x0, y1 - y0):  # keep thin strands readable
            ax.set_aspect("equal")
        ax.set_title(name)
        ax.set_xlabel("m")
        if len(pts) or len(obstacle):
            ax.legend(loc="lower right", fontsize=8, markerscale=5)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def collide_cmd(
    scene: str = typer.Option("strand", help="synthetic scene: strand | head | soup"),
    fibres: int = typer.Option(0, min=0, help="number of fibres (0: 200 strand, 4900 head, 1000 soup)"),
    segments: int = typer.Option(0, min=0, help="segments per fibre (0: 100 strand/soup, 49 head)"),
    variant: str = typer.Option("AP", help="hierarchy: AP (packed AABB tree, fast) or Sobottka's Table 7.1 "
                                            "AS AL DS DL OS OW OL SS SW SL"),
    k: int = typer.Option(18, help="k of the k-DOP variants (DS, DL)"),
    radius_um: float = typer.Option(35.0, min=0.0, help="fibre radius, µm"),
    seed: int = typer.Option(0, help="random seed of the scene"),
    out: Path = typer.Option(..., help="output folder (contacts.npz, contacts.png)"),
) -> None:
    """Find all fibre–fibre (and, for the head, fibre–head) contacts; print counts and timings."""
    import time

    import numpy as np
    from rich.console import Console
    from rich.table import Table

    from headsim.cli._common import atomic_output_dir
    from headsim.collide.fibre_bvh import FAST_VARIANTS, VARIANTS, FibreBVH
    from headsim.collide.fibre_scenes import head_field_band, head_scene, soup_scene, strand_scene
    from headsim.errors import ParameterError

    if scene not in SCENES:
        raise ParameterError(f"unknown scene {scene!r}; choose strand, head or soup")
    if variant.upper() not in VARIANTS and variant.upper() not in FAST_VARIANTS:
        raise ParameterError(f"unknown variant {variant!r}; choose one of {', '.join([*FAST_VARIANTS, *VARIANTS])}")
    if not radius_um > 0:
        raise ParameterError("radius must be > 0 µm")
    r = radius_um * 1e-6
    console = Console()
    obstacle = None
    with console.status(f"building the {scene} scene …"):
        t0 = time.perf_counter()
        if scene == "strand":
            f = strand_scene(fibres or 200, segments or 100, radius=r, seed=seed)
        elif scene == "soup":
            f = soup_scene(fibres or 1000, segments or 100, radius=r, seed=seed)
        else:
            import trimesh

            from headsim.collide.distance_field import GridDistanceField
            from headsim.data import head_path

            m = trimesh.load(head_path(), process=False)
            field = GridDistanceField.from_mesh(np.asarray(m.vertices), np.asarray(m.faces), 0.003,
                                               band=head_field_band(radius=r))
            f = head_scene(fibres or 4900, segments or 49, radius=r, field=field, seed=seed)
        t_scene = time.perf_counter() - t0
    with console.status(f"building the {variant.upper()} hierarchy over {f.n_segments:,} segments …"):
        bvh = FibreBVH.from_variant(f, variant, k=k)
    with console.status("detecting contacts …"):
        contacts = bvh.self_contacts()
        t_update = bvh.update()
    stats = bvh.stats
    from headsim.collide.fibres import FibreContacts

    obstacle = FibreContacts.empty()
    t_obst = 0.0
    if scene == "head":
        from headsim.collide.distance_field import obstacle_contacts

        t0 = time.perf_counter()
        obstacle = obstacle_contacts(f, field, level=0.0)
        t_obst = time.perf_counter() - t0

    table = Table(title=f"headsim hair collide — {scene}, {variant.upper()}")
    table.add_column("quantity")
    table.add_column("value", justify="right")
    for name, value in [
        ("fibres", f"{f.n_fibres:,}"), ("segments", f"{f.n_segments:,}"),
        ("fibre–fibre contacts", f"{len(contacts):,}"), ("fibre–head contacts", f"{len(obstacle):,}"),
        ("BV tests", f"{stats.bv_tests:,}"), ("overlapping BV pairs", f"{stats.bv_overlaps:,}"),
        ("primitive tests", f"{stats.primitive_tests:,}"),
        ("scene (s)", f"{t_scene:.3f}"), ("build (s)", f"{bvh.timings['build']:.3f}"),
        ("detection (s)", f"{stats.seconds:.3f}"), ("update (s)", f"{t_update:.4f}"),
        ("head SDF query (s)", f"{t_obst:.4f}"),
    ]:
        table.add_row(name, value)
    console.print(table)
    with atomic_output_dir(out) as tmp:
        both = FibreContacts.concatenate([contacts, obstacle])
        np.savez_compressed(tmp / "contacts.npz", **{k_: getattr(both, k_) for k_ in both.__dataclass_fields__})
        _picture(f, contacts, obstacle, tmp / "contacts.png",
                 f"{scene}: {f.n_fibres:,} fibres, {f.n_segments:,} segments, {len(contacts):,} contacts "
                 f"({variant.upper()}, {stats.seconds:.2f} s)")
    console.print(f"wrote {out / 'contacts.png'} and {out / 'contacts.npz'}")


def register(hair_app: typer.Typer) -> None:
    """Add the ``collide`` command to the ``hair`` typer app."""
    hair_app.command("collide")(collide_cmd)
