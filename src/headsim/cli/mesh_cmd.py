"""``headsim mesh``: inspect, validate and tetrahedralise meshes.

Thin wrappers over :mod:`headsim.mesh`; heavy modules are imported inside the commands. Every
``HeadsimError`` (bad file, defect, wrong unit) reaches :func:`headsim.cli.main`, which prints one
line and exits with code 2; output files are written atomically (never a partial file).
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import typer

app = typer.Typer(help="Inspect, validate, repair and tetrahedralise meshes.", no_args_is_help=True)

_FILE_HELP = "mesh file (.obj .stl .ply .msh .mesh .vtk .vtu .off); default: the bundled neutral face"
_UNITS_HELP = "length unit of the file: m, cm or mm"


def _console():
    from rich.console import Console

    return Console(highlight=False)


def _resolve(file: Path | None) -> Path:
    if file is not None:
        return file
    from headsim.data import face_path

    return face_path()


def _load(file: Path | None, units: str, repair: bool, validate: bool = True):
    """read_surface with UnitsWarnings printed as warnings (not errors)."""
    from headsim.mesh.io import read_surface
    from headsim.mesh.units import UnitsWarning

    path = _resolve(file)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UnitsWarning)
        loaded = read_surface(path, units, repair=repair, validate=validate)
    con = _console()
    for w in caught:
        if issubclass(w.category, UnitsWarning):
            con.print(f"[yellow]warning:[/yellow] {w.message}")
    return path, loaded


def _report_table(report, title: str):
    from rich.table import Table

    table = Table(title=title, show_header=True, header_style="bold")
    table.add_column("defect")
    table.add_column("count", justify="right")
    table.add_column("details")
    if not report.defects:
        table.add_row("[green]none[/green]", "0", "mesh is valid")
    for d in report.defects:
        kind = f"[red]{d.kind}[/red]" if d.error else f"[yellow]{d.kind}[/yellow]"
        table.add_row(kind, str(d.count), d.message)
    return table


def _surface_table(path: Path, mesh, units: str, valid: bool = True):
    from rich.table import Table

    b = mesh.bounds * 1e3
    table = Table(title=f"{path.name} (read as {units})", show_header=False)
    table.add_column("quantity", style="bold")
    table.add_column("value")
    table.add_row("vertices", f"{mesh.n_vertices:,}")
    table.add_row("triangles", f"{mesh.n_triangles:,}")
    table.add_row("edges", f"{len(mesh.edges):,}")
    table.add_row("bounds min, mm", "  ".join(f"{x:9.2f}" for x in b[0]))
    table.add_row("bounds max, mm", "  ".join(f"{x:9.2f}" for x in b[1]))
    table.add_row("extent, mm", "  ".join(f"{x:9.2f}" for x in b[1] - b[0]))
    table.add_row("area, cm²", f"{mesh.area * 1e4:.2f}")
    closed = mesh.is_closed
    table.add_row("closed", "yes" if closed else "no")
    if closed and valid:
        table.add_row("volume, cm³", f"{mesh.signed_volume() * 1e6:.3f}")
    elif closed:
        table.add_row("volume, cm³", "(not defined until the defects below are fixed)")
    else:
        loops = mesh.boundary_loops
        table.add_row("boundary loops", f"{len(loops)} (lengths {', '.join(str(len(lp)) for lp in loops[:8])})")
    return table


@app.command("info")
def info_cmd(
    file: Path = typer.Argument(None, help=_FILE_HELP, show_default=False),
    units: str = typer.Option("m", "--units", help=_UNITS_HELP),
    repair: bool = typer.Option(False, "--repair", help="apply safe repairs first and report them"),
) -> None:
    """Counts, bounds, area, closedness, boundary loops and the validation report of FILE.

    Exits with code 2 when the mesh has defects (after printing them).
    """
    path, loaded = _load(file, units, repair, validate=False)
    con = _console()
    con.print(_surface_table(path, loaded.mesh, units, valid=loaded.validation.ok))
    if loaded.repair is not None:
        con.print(f"repair: {loaded.repair.summary()}")
    con.print(_report_table(loaded.validation, "validation"))
    loaded.validation.raise_if_invalid()


@app.command("validate")
def validate_cmd(
    file: Path = typer.Argument(None, help=_FILE_HELP, show_default=False),
    units: str = typer.Option("m", "--units", help=_UNITS_HELP),
    repair: bool = typer.Option(False, "--repair", help="apply safe repairs and report them"),
    out: Path = typer.Option(None, "--out", help="write the (repaired) surface here, same units as read"),
) -> None:
    """Check FILE for defects (exit code 2 if any remain); with --repair --out, save the fixed mesh."""
    path, loaded = _load(file, units, repair, validate=False)
    con = _console()
    if loaded.repair is not None:
        con.print(_report_table(loaded.original_validation, f"{path.name}: before repair"))
        con.print(f"repair: {loaded.repair.summary()}")
    con.print(_report_table(loaded.validation, f"{path.name}: validation"))
    loaded.validation.raise_if_invalid()
    if out is not None:
        from headsim.cli._common import atomic_output_file
        from headsim.mesh.io import save_surface

        with atomic_output_file(out) as tmp:
            save_surface(loaded.mesh, tmp, units=units)
        con.print(f"wrote {out}")
    con.print("[green]valid[/green]")


@app.command("tetra")
def tetra_cmd(
    file: Path = typer.Argument(None, help=_FILE_HELP, show_default=False),
    units: str = typer.Option("m", "--units", help=_UNITS_HELP),
    thickness_mm: float = typer.Option(10.0, "--thickness-mm", min=0.0, help="open faces: tissue thickness to the bone, mm (Heinze: 10)"),
    layers: int = typer.Option(3, "--layers", min=1, help="open faces: tet layers through the thickness"),
    target_edge_mm: float = typer.Option(None, "--target-edge-mm", help="closed surfaces: tet edge length, mm (default: tetwild 1/20 of the box diagonal, gmsh the mean surface edge)"),
    method: str = typer.Option("tetwild", "--method", help="closed surfaces: tetwild (default) or gmsh (optional, GPL)"),
    repair: bool = typer.Option(False, "--repair", help="apply safe surface repairs first"),
    out: Path = typer.Option(None, "--out", help="write the tet mesh (.vtu, .msh, .mesh, .vtk), in metres"),
    png: Path = typer.Option(None, "--png", help="open faces: write a front-view picture of the tissue thickness"),
) -> None:
    """Tetrahedralise FILE and print the model's statistics.

    An open face becomes a tissue layer over fixed bone (Heinze §2.3); a closed surface is filled
    by a mesher.
    """
    import numpy as np
    from rich.table import Table

    from headsim.errors import ParameterError
    from headsim.mesh.quality import tet_quality

    if thickness_mm <= 0:
        raise ParameterError(f"--thickness-mm must be > 0, got {thickness_mm}")
    if out is not None:
        from headsim.mesh.io import TET_FORMATS, _format_for

        _format_for(out, TET_FORMATS, "tet mesh")  # refuse a bad suffix before the work
    if png is not None and png.suffix.lower() != ".png":
        raise ParameterError(f"{png}: --png needs a .png file name")
    path, loaded = _load(file, units, repair)
    surface = loaded.mesh
    con = _console()
    extra: list[tuple[str, str]] = []
    layer = None
    t0 = time.perf_counter()
    with con.status("tetrahedralising ..."):
        if surface.is_closed:
            from headsim.mesh.tetra import tetrahedralize_surface

            edge = None if target_edge_mm is None else target_edge_mm * 1e-3
            mesh = tetrahedralize_surface(surface, edge, method=method)
            kind = f"closed surface filled by {method}"
            extra.append(("surface volume, cm³", f"{surface.signed_volume() * 1e6:.3f}"))
        else:
            from headsim.mesh.tissue import extrude_tissue_layer

            layer = extrude_tissue_layer(surface, thickness_mm * 1e-3, layers)
            mesh = layer.mesh
            kind = f"tissue layer, {layers} layers over fixed bone"
            s = layer.summary()
            extra += [
                ("thickness requested, mm", f"{thickness_mm:g}"),
                ("thickness min / mean, mm", f"{s['thickness_min'] * 1e3:.2f} / {s['thickness_mean'] * 1e3:.2f}"),
                ("vertices with reduced thickness", f"{s['n_reduced']:,} (clearance {s['n_reduced_clearance']:,}, "
                                                    f"curvature {s['n_reduced_shape']:,})"),
                ("skin triangles trimmed (folds)", f"{s['n_trimmed_triangles']:,} of {surface.n_triangles:,}"),
                ("skin area, cm²", f"{layer.skin_surface().area * 1e4:.2f}"),
            ]
    elapsed = time.perf_counter() - t0
    q = tet_quality(mesh).summary()
    table = Table(title=f"{path.name}: {kind}", show_header=False)
    table.add_column("quantity", style="bold")
    table.add_column("value")
    table.add_row("vertices", f"{mesh.n_vertices:,}")
    table.add_row("tets", f"{mesh.n_tets:,}")
    n_fixed = int(np.sum(mesh.fixed)) if mesh.fixed is not None else 0
    table.add_row("fixed (bone) vertices", f"{n_fixed:,}")
    table.add_row("volume, cm³", f"{mesh.volume * 1e6:.3f}")
    for k, v in extra:
        table.add_row(k, v)
    table.add_row("min dihedral angle, °", f"{q['min_dihedral_deg']:.2f} (1st percentile of per-tet minima {q['dihedral_p1_deg']:.2f})")
    table.add_row("max dihedral angle, °", f"{q['max_dihedral_deg']:.2f}")
    table.add_row("radius ratio min / p1 / median", f"{q['radius_ratio_min']:.3f} / {q['radius_ratio_p1']:.3f} / {q['radius_ratio_median']:.3f}")
    table.add_row("time, s", f"{elapsed:.2f}")
    con.print(table)
    if out is not None:
        from headsim.cli._common import atomic_output_file
        from headsim.mesh.io import save_tetmesh

        with atomic_output_file(out) as tmp:
            save_tetmesh(mesh, tmp)
        con.print(f"wrote {out}")
    if png is not None and layer is not None:
        from headsim.cli._common import atomic_output_file

        with atomic_output_file(png) as tmp:
            _thickness_picture(layer, tmp, title=f"{path.name}: tissue thickness")
        con.print(f"wrote {png}")


def _thickness_picture(layer, path: Path, title: str) -> None:
    """Front view (x right, y up) of the skin coloured by tissue thickness, trimmed parts grey."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    skin = layer.skin_surface()
    v = skin.vertices * 1e3
    fig, ax = plt.subplots(figsize=(6, 7), dpi=120)
    front = skin.face_normals[:, 2] > -0.2
    tri = skin.triangles[front]
    art = ax.tripcolor(v[:, 0], v[:, 1], tri, layer.thickness * 1e3, shading="gouraud", cmap="viridis",
                       vmin=0.0, vmax=float(np.max(layer.requested_thickness)) * 1e3)
    fig.colorbar(art, ax=ax, label="tissue thickness to the bone, mm")
    ax.set_aspect("equal")
    ax.set_xlabel("x, mm")
    ax.set_ylabel("y, mm")
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
