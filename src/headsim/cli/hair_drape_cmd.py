"""``headsim hair drape``: rigid-segment fibres with Moreau contact response (Sobottka 2008, ch. 8).

The ``hair`` command group lives in ``hair_cmd.py``; it calls :func:`register` to add this command.
Heavy imports happen inside the command.
"""

from __future__ import annotations

from pathlib import Path

import typer

SCENE_HELP = "sphere-horizontal | sphere-helical | plane | terrain | head"


def drape_cmd(
    scene: str = typer.Option(..., help=f"seed scene (Sobottka §8.6): {SCENE_HELP}"),
    friction: str = typer.Option("aniso", help="friction model: aniso (keratin scales) | iso (μ = 0.47) | none"),
    out: Path = typer.Option(..., help="output folder (replaced atomically on success)"),
    fibres: int = typer.Option(0, min=0, help="number of fibres (0: the seed's count)"),
    segments: int = typer.Option(0, min=0, help="segments per fibre (0: the seed's count)"),
    dt: float = typer.Option(1e-3, min=1e-6, help="time step, s (seed: 1 ms)"),
    duration: float = typer.Option(0.0, min=0.0, help="simulated time, s (0: the scene's default)"),
    frames: int = typer.Option(30, min=2, help="recorded frames"),
    contact_coupling: str = typer.Option("coupled", help="coupled (Gauss–Seidel over contacts) | per-body (seed)"),
    friction_objective: str = typer.Option("qp", help="qp (recommended) | lp (seed eq. 8.62, HiGHS)"),
    joint_levers: str = typer.Option("mean", help="mean (joint impulses at the levers averaged over the step's "
                                     "rotation: no energy gain on fast-turning bent fibres) | start (seed eq. 8.72; "
                                     "cheaper)"),
    sphere_radius: float = typer.Option(0.0, min=0.0, help="sphere-horizontal only: the sphere's radius, m (0: the "
                                        "scene's 6 cm; the seed does not state it)"),
    render: bool = typer.Option(False, help="also write path-traced frames to rendered/ (slow)"),
) -> None:
    """Drop fibres onto an obstacle; write the trajectory (NPZ + VTK polylines), plots, frames and report.html."""
    import numpy as np
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from headsim.cli._common import atomic_output_dir
    from headsim.errors import ParameterError
    from headsim.hair.drape import FRICTION_MODES, SCENES, bounding_box, build_drape_scene, run_drape, write_drape
    from headsim.report.drape import write_drape_report

    if scene not in SCENES:
        raise ParameterError(f"--scene must be one of {', '.join(SCENES)}, got {scene!r}")
    if friction not in FRICTION_MODES:
        raise ParameterError(f"--friction must be one of {', '.join(FRICTION_MODES)}, got {friction!r}")
    sc = build_drape_scene(scene, friction, n_fibres=fibres or None, segments=segments or None, dt=dt,
                           duration=duration or None, contact_coupling=contact_coupling,
                           friction_objective=friction_objective, joint_levers=joint_levers,
                           sphere_radius=sphere_radius or None)
    every = max(1, sc.n_steps // (frames - 1))
    with Progress(TextColumn(f"[bold]{sc.name}[/bold] ({friction})"), BarColumn(),
                  TextColumn("{task.completed}/{task.total} steps"), TimeRemainingColumn()) as progress:
        task = progress.add_task("steps", total=sc.n_steps)
        res = run_drape(sc, record_every=every, progress=lambda i, n: progress.update(task, completed=i))
    with atomic_output_dir(out) as tmp:
        if render:
            with Progress(TextColumn("[bold]rendering[/bold]"), BarColumn(),
                          TextColumn("{task.completed}/{task.total} frames")) as progress:
                task = progress.add_task("frames", total=len(res.times))
                files = write_drape(sc, res, tmp, render=True,
                                    progress=lambda i, n: progress.update(task, completed=i))
        else:
            files = write_drape(sc, res, tmp)
        files.append(write_drape_report(sc, res, tmp / "report.html"))
    ext, vol = bounding_box(res.polylines[-1])
    # the median: the first steps of a fresh installation include the kernels' compilation (a scene has ≥ 1 step)
    per_step = float(np.median(res.step_seconds))
    overlaps = res.end_overlap[np.isfinite(res.end_overlap)]  # nan: a step without rows
    end_overlap = float(overlaps.max()) if len(overlaps) else float("nan")
    typer.echo(f"{sc.description}: {sc.n_steps} steps of {dt:g} s, median {per_step:.3g} s/step (first step "
               f"{res.step_seconds[0]:.3g} s); final bounding box "
               f"{ext[0] * 100:.2f} × {ext[1] * 100:.2f} × {ext[2] * 100:.2f} cm = {vol * 1e6:.1f} cm³, "
               f"max penetration {res.max_penetration.max() * 1e6:.1f} µm (first order, mid-step), largest "
               f"overlap of a contact row at a step's end {end_overlap * 1e6:.1f} µm, max joint gap "
               f"{res.max_joint_gap.max() * 1e6:.2f} µm, {int((res.substeps > 1).sum())} steps taken in halves, "
               f"{int(res.crossings_restored.sum())} fibre pairs turned back, "
               f"{int(res.joint_root_failures.sum())} fibre joint solves on the start levers (mean-lever Newton not "
               f"converged); wrote {len(files)} files to {out}")


def register(app: typer.Typer) -> None:
    app.command("drape")(drape_cmd)
