"""``headsim graft``, ``headsim compare`` and ``headsim graft-scene``: the fat-grafting planner (Monkin 2016)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer


def _pick_region(markers_path: Path | None, region: str | None):
    from headsim.errors import RegionError
    from headsim.graft import bundled_markers_path, load_markers

    path = markers_path or bundled_markers_path()
    markers = load_markers(path)
    if region is None:
        name = next(iter(markers))
    elif region not in markers:
        raise RegionError(f"{path}: no region {region!r}; it has {', '.join(markers)}")
    else:
        name = region
    return markers[name], path


def graft(
    face: Optional[Path] = typer.Option(None, help="face surface (.obj/.stl/.ply…); default: the bundled neutral face"),
    units: str = typer.Option("m", help="unit of FACE: m, dm, cm or mm (the bundled face is in m)"),
    markers: Optional[Path] = typer.Option(None, help="markers JSON; default: the bundled cheek markers"),
    region: Optional[str] = typer.Option(None, help="region name in the markers file (default: the first)"),
    volume: float = typer.Option(..., help="volume to inject, cm³"),
    out: Path = typer.Option(..., help="output folder (after.<ext>, graft.json, report.html, PNGs)"),
    closure: str = typer.Option("centroid", help="closed model of the region: centroid or mirror (seed §5.3)"),
    method: str = typer.Option("gauss_seidel", help="distance-constraint solver: gauss_seidel or jacobi"),
    acceleration: str = typer.Option("anderson", help="rest state by Anderson acceleration (anderson) or by the "
                                     "seed's damped time stepping (none)"),
    max_steps: int = typer.Option(20000, help="PBD step budget"),
    pictures: bool = typer.Option(True, help="write PNG pictures"),
) -> None:
    """Inject VOLUME cm³ into a marked region of FACE by PBD and write the result and a report."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from headsim.cli._common import atomic_output_dir
    from headsim.data import face_path
    from headsim.errors import ParameterError
    from headsim.graft import GraftOptions, inject_volume, prepare_graft, region_from_markers
    from headsim.mesh.io import load_surface, save_surface
    from headsim.mesh.units import parse_units
    from headsim.report.graft import write_graft_pictures, write_graft_report

    unit = parse_units(units)
    if not volume > 0:
        raise ParameterError(f"--volume must be > 0 cm³, got {volume}")
    face_file = face or face_path("neutral")
    if face is None and unit.value != "m":
        raise ParameterError("the bundled face is in metres; give --units m or --face FILE")
    mesh = load_surface(face_file, units=unit)
    marker_set, markers_file = _pick_region(markers, region)
    reg = region_from_markers(mesh, marker_set)
    options = GraftOptions(closure=closure, method=method, max_steps=max_steps, acceleration=acceleration)
    setup = prepare_graft(reg, closure)
    typer.echo(f"{reg}; closed model {setup.volume_before * 1e6:.3f} cm³ ({closure})")
    with Progress(TextColumn("PBD"), BarColumn(), TextColumn("step {task.completed}"),
                  TextColumn("Δ|x| {task.fields[change]}"), TimeElapsedColumn(), transient=True) as bar:
        task = bar.add_task("solve", total=max_steps, change="-")

        def progress(state, change):
            if state.steps % 10 == 0:
                bar.update(task, completed=state.steps, change=f"{change:.2e} m")

        result = inject_volume(setup, volume * 1e-6, options, callback=progress)
    suffix = Path(face_file).suffix.lower() if face is not None else ".obj"
    with atomic_output_dir(out) as tmp:
        save_surface(result.face_after, tmp / f"after{suffix}", units=unit)
        summary = result.summary()
        summary.update({"face": str(face_file), "face_units": unit.value, "markers_file": str(markers_file),
                        "output_units": unit.value})
        (tmp / "graft.json").write_text(json.dumps(summary, indent=1))
        write_graft_report(result, tmp / "report.html")
        if pictures:
            write_graft_pictures(result, tmp)
    typer.echo(f"injected {volume:g} cm³: measured change {summary['volume_change_cm3']:.3f} cm³, largest "
               f"displacement {summary['max_displacement_mm']:.2f} mm, {result.info.steps} steps → {out}")


def compare(
    a: Path = typer.Argument(..., help="reference face (e.g. before)"),
    b: Path = typer.Argument(..., help="face to compare (e.g. after), aligned with A"),
    markers: Optional[Path] = typer.Option(None, help="markers JSON of the region on A; default: bundled cheeks"),
    region: Optional[str] = typer.Option(None, help="region name(s), comma separated (default: all)"),
    units: str = typer.Option("m", help="unit of both files"),
    json_out: Optional[Path] = typer.Option(None, "--json", help="also write the numbers as JSON"),
) -> None:
    """Volume difference B − A inside marked regions, and Hausdorff / mean surface distance (seed ch. 6)."""
    from headsim.cli._common import atomic_output_file
    from headsim.errors import RegionError
    from headsim.graft import (bundled_markers_path, load_markers, region_from_markers, surface_distances,
                               volume_between)
    from headsim.mesh.io import load_surface

    mesh_a = load_surface(a, units=units)
    mesh_b = load_surface(b, units=units)
    path = markers or bundled_markers_path()
    sets = load_markers(path)
    names = list(sets) if region is None else [r.strip() for r in region.split(",")]
    rows = {}
    whole = surface_distances(mesh_a, mesh_b)
    for name in names:
        if name not in sets:
            raise RegionError(f"{path}: no region {name!r}; it has {', '.join(sets)}")
        reg = region_from_markers(mesh_a, sets[name])
        vol = volume_between(mesh_a, mesh_b, reg)
        dist = surface_distances(mesh_a, mesh_b, reg)
        rows[name] = {"volume_difference_cm3": vol * 1e6, "hausdorff_mm": dist.hausdorff * 1e3,
                      "mean_distance_mm": dist.mean * 1e3, "area_cm2": reg.area * 1e4}
        typer.echo(f"{name}: volume B − A {vol * 1e6:+.3f} cm³, Hausdorff {dist.hausdorff * 1e3:.3f} mm, "
                   f"mean distance {dist.mean * 1e3:.3f} mm (region {reg.area * 1e4:.2f} cm²)")
    typer.echo(f"whole surface: Hausdorff {whole.hausdorff * 1e3:.3f} mm, mean distance {whole.mean * 1e3:.3f} mm")
    if json_out is not None:
        data = {"a": str(a), "b": str(b), "units": units, "regions": rows,
                "whole": {"hausdorff_mm": whole.hausdorff * 1e3, "mean_distance_mm": whole.mean * 1e3}}
        with atomic_output_file(json_out) as tmp:
            tmp.write_text(json.dumps(data, indent=1))


def graft_scene(
    scene: str = typer.Argument(..., help="box (8,000 particles), ball (volume + pressure on a plane) or cloth"),
    out: Path = typer.Option(..., help="output folder (final state, numbers JSON, picture)"),
    steps: Optional[int] = typer.Option(None, help="number of steps (default: the scene's)"),
    particles: int = typer.Option(8000, help="box scene: number of particles"),
) -> None:
    """Run one of the seed's demo scenes (Monkin 2016 §4.5) and save the result."""
    from headsim.cli._common import atomic_output_dir
    from headsim.errors import ParameterError
    from headsim.graft import scenes

    runners = {"box": lambda: scenes.run_box_scene(n_particles=particles, steps=steps),
               "ball": lambda: scenes.run_ball_scene(steps=steps),
               "cloth": lambda: scenes.run_cloth_scene(steps=steps)}
    if scene not in runners:
        raise ParameterError(f"unknown scene {scene!r}; choose box, ball or cloth")
    typer.echo(f"running the {scene} scene …")
    result = runners[scene]()
    with atomic_output_dir(out) as tmp:
        scenes.save_scene_result(result, tmp)
    typer.echo(json.dumps(result.numbers, indent=1))
    typer.echo(f"→ {out}")
