"""``headsim scene``: run the solver's validation scenes and write pictures (PNG) and VTU files."""

from __future__ import annotations

from pathlib import Path

import typer

app = typer.Typer(help="Run the solver's validation scenes (Hertz sphere-on-block, seed ch. 4).",
                  no_args_is_help=True)

SCENES = {
    "sphere-on-block": "rigid sphere pressed with a force onto a soft FEM block (quasi-static), vs Hertz theory",
    "seed-sphere-on-cuboid": "the seed's ch. 4: mass-spring sphere (917 g) falls onto a cuboid (100 g)",
}


@app.command("list")
def list_cmd() -> None:
    """List the available scenes."""
    from rich.console import Console
    from rich.table import Table

    table = Table(show_header=True, header_style="bold")
    table.add_column("scene")
    table.add_column("what it shows")
    for k, v in SCENES.items():
        table.add_row(k, v)
    Console().print(table)


@app.command("run")
def run_cmd(
    name: str = typer.Argument(..., help="scene name (see `headsim scene list`)"),
    out: Path = typer.Option(..., "--out", help="output folder (written atomically)"),
    young_kpa: float = typer.Option(10.0, help="sphere-on-block: Young's modulus of the block, kPa"),
    poisson: float = typer.Option(0.3, help="sphere-on-block: Poisson ratio of the block"),
    radius_mm: float = typer.Option(10.0, help="sphere-on-block: sphere radius, mm"),
    contact_radius_mm: float = typer.Option(1.0, help="sphere-on-block: Hertz contact radius to load for, mm"),
    scenario: str = typer.Option("rigid-on-soft", help="seed scene: both-rigid, rigid-on-soft or both-soft"),
    steps: int = typer.Option(10, min=1, help="seed scene: number of 0.2 s steps"),
    scene_radius: float = typer.Option(0.5, help="seed scene: sphere radius R, m (the thesis gives none; the "
                                                 "k = 5 N/m sphere is rigid only at several metres, e.g. 5)"),
    sphere_divisions: int = typer.Option(2, min=1, help="seed scene: ball mesh divisions (2d + 1 points across)"),
) -> None:
    """Run scene NAME and write PNG pictures and a VTU deformation file into OUT."""
    from rich.console import Console
    from rich.progress import Progress

    from headsim.cli._common import atomic_output_dir
    from headsim.errors import ParameterError

    if name not in SCENES:
        raise ParameterError(f"unknown scene {name!r}; available: {', '.join(SCENES)}")
    con = Console(highlight=False)
    with atomic_output_dir(out) as tmp:
        if name == "sphere-on-block":
            from headsim.solvers.hertz import hertz_indentation
            from headsim.solvers.materials import Material
            from headsim.solvers.scene_output import plot_hertz, write_vtu

            with Progress(transient=True) as prog:
                task = prog.add_task("quasi-static Newton solve", total=None)
                res = hertz_indentation(Material.from_kpa(young_kpa, poisson), radius=radius_mm * 1e-3,
                                        contact_radius=contact_radius_mm * 1e-3)
                prog.update(task, completed=1, total=1)
            write_vtu(tmp / "sphere_on_block.vtu", res.model.rest_positions, res.positions, res.model.tets,
                      {"contact_pressure": res.contact_pressure})
            plot_hertz(res, tmp / "sphere_on_block.png")
            (tmp / "summary.txt").write_text(
                f"force {res.force:.6g} N\ncontact radius {res.contact_radius:.6g} m (Hertz {res.contact_radius_hertz:.6g}, "
                f"error {100 * res.contact_radius_error:+.2f} %)\nindentation {res.indentation:.6g} m "
                f"(Hertz {res.indentation_hertz:.6g}, error {100 * res.indentation_error:+.2f} %)\n"
                f"contact force {res.contact_force:.6g} N, support reaction {res.support_reaction:.6g} N\n"
                f"mesh: quarter block, {res.n_vertices} vertices, {res.n_tets} tets; Newton iterations "
                f"{res.newton_iterations}\n")
            con.print(f"contact radius {res.contact_radius * 1e3:.4g} mm (Hertz {res.contact_radius_hertz * 1e3:.4f} mm), "
                      f"indentation {res.indentation * 1e6:.4g} µm (Hertz {res.indentation_hertz * 1e6:.2f} µm)")
        else:
            import numpy as np

            from headsim.solvers.scene_output import plot_scene_frames, write_vtu
            from headsim.solvers.scenes import seed_sphere_on_cuboid

            with Progress(transient=True) as prog:
                task = prog.add_task(f"seed scene {scenario}", total=steps)
                res = seed_sphere_on_cuboid(scenario, steps=steps, radius=scene_radius, sphere_divisions=sphere_divisions,
                                            progress=lambda i: prog.update(task, completed=i))
            tets = np.vstack(res.tets)
            for k in sorted({0, steps // 2, steps}):
                write_vtu(tmp / f"sphere_on_cuboid_step{k:03d}.vtu", res.model.rest_positions, res.states[k].positions,
                          tets, {"body": res.model.body})
            plot_scene_frames(res, tmp / "sphere_on_cuboid.png", sorted({0, steps // 2, steps}))
            con.print(f"{res.name}: shape change sphere {res.shape_change[-1][0]:.3f}, cuboid {res.shape_change[-1][1]:.3f}")
    con.print(f"wrote {out}")
