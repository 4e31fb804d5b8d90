"""``headsim hair``: keratin fibre simulations (implicit Kirchhoff rods, Sobottka 2008 ch. 3)."""

from __future__ import annotations

from enum import Enum
from pathlib import Path

import typer

app = typer.Typer(help="Hair fibres: Kirchhoff rods, fibre collision detection, contact response (drape), "
                       "electrostatics, hairstyle growth and rendering.",
                  no_args_is_help=True)


class SceneName(str, Enum):
    cantilever = "cantilever"
    precurved = "precurved"
    helix = "helix"
    spiral = "spiral"
    loop = "loop"
    buckling = "buckling"
    strand_stretch = "strand-stretch"
    moving_support = "moving-support"


@app.command("rod")
def rod_cmd(
    scene: SceneName = typer.Option(..., help="which seed example to run"),
    out: Path = typer.Option(..., help="output folder (replaced atomically on success)"),
    segments: int = typer.Option(0, min=0, help="segments per fibre (0: the scene's default)"),
    dt: float = typer.Option(0.0, min=0.0, help="time step, s (0: the scene's default)"),
    duration: float = typer.Option(0.0, min=0.0, help="simulated time, s (0: the scene's default)"),
    frames: int = typer.Option(24, min=2, help="number of recorded frames / images"),
    images: bool = typer.Option(True, help="write a PNG image sequence"),
    render: bool = typer.Option(False, help="also write path-traced frames (Marschner model) to rendered/"),
    preset: str = typer.Option("brown", help="hair colour preset for --render (blond, brown, black, red)"),
) -> None:
    """Run a rod scene; write the trajectory (NPZ and VTK polylines), plots and an image sequence."""
    import numpy as np
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from headsim.cli._common import atomic_output_dir
    from headsim.hair.output import write_trajectory
    from headsim.hair.scenes import build_scene, run_scene

    kw = {}
    if segments:
        kw["n_segments"] = segments
    if dt:
        kw["dt"] = dt
    if duration:
        kw["duration"] = duration
    sc = build_scene(scene.value, **kw)
    every = max(1, sc.n_steps // (frames - 1))
    with Progress(TextColumn(f"[bold]{sc.name}[/bold]"), BarColumn(), TextColumn("{task.completed}/{task.total} steps"),
                  TimeRemainingColumn()) as progress:
        task = progress.add_task("steps", total=sc.n_steps)
        traj = run_scene(sc, record_every=every, progress=lambda i, n: progress.update(task, completed=i))
    with atomic_output_dir(out) as tmp:
        files = write_trajectory(sc, traj, tmp, images=images)
        if render:
            from headsim.hair.render.frames import render_frames

            states = [traj.positions[k] if traj.interpolated is None else
                      np.concatenate([traj.positions[k][:1], traj.interpolated[k]], axis=0)
                      for k in range(len(traj.times))]
            with Progress(TextColumn("[bold]rendering[/bold]"), BarColumn(),
                          TextColumn("{task.completed}/{task.total} frames")) as progress:
                task = progress.add_task("frames", total=len(states))
                files += render_frames(states, tmp / "rendered", preset=preset,
                                       progress=lambda i, n: progress.update(task, completed=i))
    stopped = ""
    if traj.times[-1] < sc.duration - 0.5 * sc.dt:
        stopped = f" (stopped at t = {traj.times[-1]:.4g} s: {sc.info.get('stop_reason', 'stop criterion met')})"
    typer.echo(f"{sc.description}: {len(traj.iterations)} steps{stopped}, mean Newton iterations "
               f"{np.mean(traj.iterations):.2f}; wrote {len(files)} files to {out}")

from headsim.cli import hair_collide_cmd, hair_render_cmd  # noqa: E402

hair_collide_cmd.register(app)  # headsim hair collide
hair_render_cmd.register(app)  # headsim hair render
__import__("headsim.cli.hair_charge_cmd", fromlist=["register"]).register(app)  # headsim hair charge
__import__("headsim.cli.hair_style_cmd", fromlist=["register"]).register(app)  # headsim hair style
__import__("headsim.cli.hair_drape_cmd", fromlist=["register"]).register(app)  # headsim hair drape
