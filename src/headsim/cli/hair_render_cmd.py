"""``headsim hair render``: path-traced PNG images of a fibre assembly (Marschner far field, Sobottka 2008
ch. 6) with multiple fibre-to-fibre scattering; optional turntable."""

from __future__ import annotations

from enum import Enum
from pathlib import Path

import typer


class Preset(str, Enum):
    blond = "blond"
    brown = "brown"
    black = "black"
    red = "red"


def parse_light(spec: str):
    """``dir:x,y,z[:r,g,b]`` (direction toward the light, irradiance W/m²) or ``point:x,y,z[:r,g,b]``
    (position m, intensity W/sr). Raises ParameterError on bad syntax."""
    from headsim.errors import ParameterError
    from headsim.hair.render.renderer import Light

    parts = spec.split(":")
    kinds = {"dir": "directional", "directional": "directional", "point": "point"}
    try:
        if parts[0] not in kinds or len(parts) not in (2, 3):
            raise ValueError
        vec = tuple(float(x) for x in parts[1].split(","))
        rgb = tuple(float(x) for x in parts[2].split(",")) if len(parts) == 3 else (3.0, 3.0, 3.0)
        if len(rgb) == 1:
            rgb = rgb * 3
        if len(vec) != 3 or len(rgb) != 3:
            raise ValueError
    except ValueError:
        raise ParameterError(f"bad --light {spec!r}; use dir:x,y,z[:r,g,b] or point:x,y,z[:r,g,b]") from None
    return Light(kind=kinds[parts[0]], vector=vec, rgb=rgb)


def render_cmd(
    fibres_npz: Path = typer.Argument(..., exists=True, dir_okay=False,
                                      help="NPZ with nodes (N,3) m, fibre_offsets (F+1,) int64, optional radius"),
    out: Path = typer.Option(..., "--out", help="PNG file, or a folder of frames with --turntable"),
    preset: Preset = typer.Option(Preset.brown, help="hair colour (melanin preset)"),
    light: list[str] = typer.Option(["dir:1,0.8,0.6"], help="dir:x,y,z[:r,g,b] or point:x,y,z[:r,g,b]; repeatable"),
    spp: int = typer.Option(64, min=1, help="samples per pixel"),
    width: int = typer.Option(512, min=8, help="image width, pixels"),
    height: int = typer.Option(512, min=8, help="image height, pixels"),
    max_scatter: int = typer.Option(4, min=1, max=16, help="fibre scattering orders (1 = direct light only)"),
    env: float = typer.Option(0.05, min=0.0, help="grey environment radiance (also the background)"),
    azimuth: float = typer.Option(30.0, help="camera azimuth about +y, degrees"),
    elevation: float = typer.Option(10.0, help="camera elevation, degrees"),
    exposure: float = typer.Option(2.0, min=0.0, help="multiplier before sRGB encoding"),
    turntable: int = typer.Option(0, min=0, help="render N frames around +y into the --out folder"),
    near_field: bool = typer.Option(False, help="near-field lobes across the fibre width (close-ups)"),
) -> None:
    """Render a fibre assembly with the corrected Marschner model and path-traced multiple scattering."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from headsim.cli._common import atomic_output_dir, atomic_output_file
    from headsim.hair.render import MarschnerParams
    from headsim.hair.render.bvh import CapsuleBVH, FibreAssembly
    from headsim.hair.render.renderer import RenderOptions, camera_looking_at, render, save_png

    lights = [parse_light(s) for s in light]
    fibres = FibreAssembly.load_npz(fibres_npz)
    params = MarschnerParams.preset(preset.value)
    opts = RenderOptions(width=width, height=height, spp=spp, max_scatter=max_scatter, env=(env,) * 3,
                         background=(env,) * 3, near_field=near_field)
    bvh = CapsuleBVH.from_fibres(fibres)
    n_frames = max(1, turntable)
    azimuths = [azimuth + 360.0 * k / n_frames for k in range(n_frames)]
    with Progress(TextColumn("[bold]hair render[/bold] {task.description}"), BarColumn(),
                  TextColumn("{task.completed}/{task.total} rows"), TimeRemainingColumn()) as progress:
        task = progress.add_task("", total=height * n_frames)
        images = []
        for k, az in enumerate(azimuths):
            progress.update(task, description=f"frame {k + 1}/{n_frames}")
            cam = camera_looking_at(fibres, azimuth_deg=az, elevation_deg=elevation)
            res = render(bvh, params, cam, lights, opts,
                         progress=lambda r, h, k=k: progress.update(task, completed=k * height + r))
            images.append(res.image)
    if turntable:
        with atomic_output_dir(out) as tmp:
            for k, img in enumerate(images):
                save_png(tmp / f"frame_{k:03d}.png", img, exposure)
        typer.echo(f"{fibres.n_fibres} fibres, {n_frames} frames, {spp} spp → {out}/frame_*.png")
    else:
        with atomic_output_file(out) as tmp:
            save_png(tmp, images[0], exposure)
        typer.echo(f"{fibres.n_fibres} fibres, {width}×{height}, {spp} spp, preset {preset.value} → {out}")


def register(hair_app: typer.Typer) -> None:
    """Add the ``render`` command to the ``hair`` typer app."""
    hair_app.command("render")(render_cmd)
