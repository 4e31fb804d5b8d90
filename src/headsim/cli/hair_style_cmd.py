"""``headsim hair style``: reconstruct a fibre hairstyle from a scalp and a hair-volume surface (Sobottka 2008
ch. 5), or on the bundled head with a generated volume (``--demo short|long``).

The ``hair`` command group lives in ``hair_cmd.py``; it calls :func:`register` to add this command.
"""

from __future__ import annotations

from pathlib import Path

import typer


def style_cmd(
    out: Path = typer.Option(..., "--out", help="output folder (replaced atomically on success)"),
    scalp: Path = typer.Option(None, "--scalp", exists=True, dir_okay=False, help="scalp (growth region) mesh"),
    volume: Path = typer.Option(None, "--volume", exists=True, dir_okay=False, help="closed hair-volume surface"),
    head: Path = typer.Option(None, "--head", exists=True, dir_okay=False,
                              help="head mesh the fibres must stay out of (default: the scalp)"),
    units: str = typer.Option("m", "--units", help="length unit of the mesh files: m, cm or mm"),
    demo: str = typer.Option(None, "--demo", help="bundled head with a generated volume: short | long"),
    fibres: int = typer.Option(90_000, "--fibres", min=0,
                               help="number of fibres (roots); 0: a Poisson process at --max-density"),
    guides: int = typer.Option(3000, "--guides", min=1, help="number of main guide hairs"),
    segments: int = typer.Option(24, "--segments", min=2, help="segments per fibre"),
    length_cm: float = typer.Option(0.0, "--length-cm", min=0.0, help="hair length, cm (0: the style's default)"),
    density_model: str = typer.Option("continuous", "--density-model", help="none | binary | continuous"),
    density_map: Path = typer.Option(None, "--density-map", exists=True, dir_okay=False,
                                     help="grey PNG over the unit disk's square: relative root density"),
    max_density: float = typer.Option(250.0, "--max-density", min=1.0,
                                      help="roots/cm² at grey 255 of the density map (sets the count with --fibres 0)"),
    tip_ratio: float = typer.Option(0.6, "--tip-ratio", min=0.0, max=1.0,
                                    help="strand radius at the tip / at the root (generalised cylinder)"),
    winding: float = typer.Option(0.0, "--winding", help="strand fibres wind about the guide, degrees per cm"),
    seed: int = typer.Option(0, "--seed", help="random seed"),
    images: bool = typer.Option(True, help="write the matplotlib pictures"),
    render: bool = typer.Option(False, "--render", help="also write a path-traced frame (rendered.png)"),
    preset: str = typer.Option("brown", help="hair colour preset for --render"),
) -> None:
    """Grow a fibre hairstyle into a hair volume; write fibres.npz/.vtu, pictures and style.json."""
    from dataclasses import asdict

    import numpy as np
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from headsim.cli._common import atomic_output_dir
    from headsim.errors import ParameterError
    from headsim.hair.reconstruct import (
        DENSITY_MODELS,
        STYLES,
        StyleOptions,
        TextureMap,
        bundled_inputs,
        default_maps,
        load_inputs,
        reconstruct,
    )
    from headsim.hair.reconstruct.output import write_hairstyle

    if density_model not in DENSITY_MODELS:
        raise ParameterError(f"--density-model must be one of {', '.join(DENSITY_MODELS)}")
    if demo is not None:
        if scalp is not None or volume is not None:
            raise ParameterError("give either --demo or --scalp/--volume, not both")
        if demo not in STYLES:
            raise ParameterError(f"--demo must be one of {', '.join(STYLES)}")
    elif scalp is None or volume is None:
        raise ParameterError("give --scalp and --volume (with --units), or --demo short|long")
    length = length_cm / 100.0 if length_cm > 0 else (STYLES[demo]["length"] if demo else 0.1)
    maps = None
    if density_map is not None:
        d, az, el, ln = default_maps(length, max_density)
        maps = (TextureMap.from_image(density_map, max_density * 1e4), az, el, ln)
    with Progress(TextColumn("[bold]hair style[/bold] {task.description}"), BarColumn(),
                  TextColumn("{task.completed}/{task.total}"), TimeElapsedColumn()) as progress:
        task = progress.add_task("inputs", total=1)
        inputs = bundled_inputs(demo) if demo else load_inputs(scalp, volume, units, head)

        def report(stage, done, total):
            progress.update(task, description=stage, completed=done, total=total)

        options = StyleOptions(n_fibres=fibres or None, n_guides=guides, n_segments=segments, length=length,
                               style=demo, density_model=density_model, maps=maps,
                               density_per_cm2=max_density, tip_ratio=tip_ratio,
                               winding=float(np.radians(winding) * 100.0), seed=seed)
        hs = reconstruct(inputs, options, report)
    summary = {"inputs": inputs.description, "density_model": density_model, "timings_s": hs.timings,
               "timings_cpu_s": hs.timings_cpu, "stats": hs.stats, "guide_options": asdict(options.guide),
               "fibres_requested": fibres, "guides_requested": guides, "segments": segments, "length_m": length}
    with atomic_output_dir(out) as tmp:
        files = write_hairstyle(tmp, hs, inputs, summary, images=images, render=render, preset=preset)
    t = hs.timings
    typer.echo(f"{hs.n_fibres} fibres ({hs.stats['fibres_dropped']} dropped), {len(hs.guides)} guides in "
               f"{t['total']:.1f} s (guides {t['guides']:.1f} s); occupancy CV {hs.stats['occupancy_cv']:.3f}; "
               f"wrote {len(files)} files to {out}")


def register(hair_app: typer.Typer) -> None:
    """Add the ``style`` command to the ``hair`` typer app."""
    hair_app.command("style")(style_cmd)
