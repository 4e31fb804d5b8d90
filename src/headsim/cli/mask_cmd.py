"""``headsim mask ...`` (fit, seal-force, list, study) and ``headsim demo``: mask fit on a face."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

app = typer.Typer(help="Mask fit: does a mask seal on a face, where does it leak, how much pressure, "
                       "and the least strap force that seals.", no_args_is_help=True)


#: = headsim.mask.fit.SKIN_SILICONE_FRICTION (kept here so that the CLI starts without importing the solver)
SKIN_SILICONE_FRICTION = 0.5
#: = headsim.mask.leak.LARGE_LEAK_LPM (ResMed's large-leak threshold, L/min; same reason)
LARGE_LEAK_LPM = 24.0

def _load_face(face: Optional[Path], units: str):
    from headsim.data import face_path
    from headsim.errors import ParameterError
    from headsim.mesh.io import load_surface
    from headsim.mesh.units import parse_units

    unit = parse_units(units)
    if face is None:
        if unit.value != "m":
            raise ParameterError("the bundled face is in metres; give --units m or --face FILE")
        return load_surface(face_path("neutral"))
    return load_surface(face, units=unit)


def _load_mask(spec: str, mask_units: str, rigid_plane: Optional[str], thickness_mm: Optional[float], kind: str,
               edge_mm: float):
    """A built-in mask name (nasal-M, ...) or a mask file."""
    from headsim.errors import ParameterError
    from headsim.mask import load_user_mask, make_mask, mask_catalogue

    if spec in mask_catalogue() or not Path(spec).suffix:
        return make_mask(spec, edge_length=edge_mm * 1e-3)
    path = Path(spec)
    if not path.exists():
        raise ParameterError(f"mask {spec!r} is neither a built-in mask ({', '.join(mask_catalogue())}) nor a file")
    if rigid_plane is None:
        raise ParameterError("a mask file needs --rigid-plane 'px,py,pz,nx,ny,nz' (file units): the rigid shell is "
                             "the side of that plane the normal points away from")
    try:
        vals = [float(v) for v in rigid_plane.split(",")]
    except ValueError:
        vals = []
    if len(vals) != 6:
        raise ParameterError(f"--rigid-plane needs 6 comma-separated numbers, got {rigid_plane!r}")
    from headsim.mesh.units import parse_units

    scale = parse_units(mask_units).to_metres
    point = tuple(v * scale for v in vals[:3])
    return load_user_mask(path, units=mask_units, rigid=(point, tuple(vals[3:])), kind=kind,
                          thickness=None if thickness_mm is None else thickness_mm * 1e-3)


def _options(layers: int, crop_mm: float, therapy_pa: float, threshold_kpa: float, placement: str,
             friction: float = 0.0, leak_threshold: float = LARGE_LEAK_LPM, contact: str = "barrier",
             rotation: str = "free"):
    from headsim.mask.fit import FitOptions

    return FitOptions(tissue_layers=layers, crop_margin=crop_mm * 1e-3, therapy_pressure=therapy_pa,
                      pressure_threshold=threshold_kpa * 1e3, placement=placement, friction=friction,
                      leak_threshold_lpm=leak_threshold, contact=contact, rotate=rotation == "free")


FACE = typer.Option(None, "--face", help="face surface (.obj/.stl/.ply…); default: the bundled neutral face")
UNITS = typer.Option("m", "--units", help="unit of FACE: m, cm or mm")
MASK = typer.Option("nasal-M", "--mask", help="built-in mask (see `headsim mask list`) or a mask file")
MASK_UNITS = typer.Option("mm", "--mask-units", help="unit of a mask file")
RIGID = typer.Option(None, "--rigid-plane", help="mask file: rigid shell plane 'px,py,pz,nx,ny,nz' (mask units)")
THICK = typer.Option(None, "--thickness", help="open mask surface: wall thickness, mm")
KIND = typer.Option("nasal", "--kind", help="mask file: nasal or oronasal")
PLACEMENT = typer.Option("auto", "--placement", help="auto (landmarks, 2 cm off, centred on the airway) or as-is")
LAYERS = typer.Option(1, "--layers", help="tissue tet layers through the 1 cm thickness")
CROP = typer.Option(8.0, "--crop", help="skin kept around the mask footprint, mm")
EDGE = typer.Option(4.0, "--mask-edge", help="built-in mask element size, mm")
THERAPY = typer.Option(980.665, "--therapy-pressure", help="air pressure the seal must hold, Pa (10 cmH2O)")
THRESH = typer.Option(4.266, "--threshold", help="pressure-injury threshold, kPa (32 mmHg)")
FRICTION = typer.Option(0.0, "--friction", help="Coulomb coefficient skin-cushion, nonlinear mode (default 0: "
                        f"frictionless; silicone on dry skin ~{SKIN_SILICONE_FRICTION:g}, Derler & Gerhardt 2012; its "
                        "outer loop may not converge, which is reported)")
LEAK = typer.Option(LARGE_LEAK_LPM, "--leak-threshold", help="largest unintentional leak judged clinically "
                    "acceptable, L/min (default: the large-leak flag of ResMed CPAP devices)")
MODE = typer.Option("nonlinear", "--mode", help="nonlinear (finite-strain FEM contact) or condensed (linear face "
                    "and cushion condensed onto their contact surfaces, Kwon et al. 2022: fast re-fits)")
CONTACT = typer.Option("auto", "--contact", help="nonlinear mode's contact: barrier (IPC barrier on the current "
                       "surfaces: consistent, never interpenetrates; the default, 'auto') or planes (lagged-plane "
                       "penalty, 5-10x faster, known to put pressure where the surfaces no longer touch: see the "
                       "contact check)")
ROTATION = typer.Option("free", "--rotation", help="the mask's orientation: free (it pitches and yaws on its strap "
                        "until the contact moments balance: a strap pulling at the airway centre) or held (headgear "
                        "with a forehead support keeps it: the mask only advances along the approach axis)")


def _check_mode(mode: str, friction: float = 0.0, contact: str = "auto", rotation: str = "free") -> str:
    from headsim.errors import ParameterError

    if rotation not in ("free", "held"):
        raise ParameterError(f"--rotation must be 'free' or 'held', got {rotation!r}")
    if mode not in ("nonlinear", "condensed"):
        raise ParameterError(f"--mode must be 'nonlinear' or 'condensed', got {mode!r}")
    if mode == "condensed" and friction > 0:
        raise ParameterError("--friction applies to the nonlinear mode only (the condensed mode has no friction model)")
    if contact not in ("auto", "planes", "barrier"):
        raise ParameterError(f"--contact must be 'barrier' or 'planes', got {contact!r}")
    if mode == "condensed" and contact != "auto":
        raise ParameterError("--contact applies to the nonlinear mode only (the condensed mode has its own "
                             "complementarity contact)")
    return mode


def _resolve_contact(mode: str, contact: str) -> str:
    """--contact auto: the barrier in the nonlinear mode; the condensed mode's problem is set up as
    for the planes (no barrier start offset: its complementarity contact starts from the placement)."""
    if contact != "auto":
        return contact
    return "barrier" if mode == "nonlinear" else "planes"


@app.command("list")
def list_masks() -> None:
    """List the built-in masks."""
    from headsim.mask import make_mask, mask_catalogue

    for name in mask_catalogue():
        m = make_mask(name)
        typer.echo(f"{name:12s} {m.kind:9s} size {m.size}  {m.tetmesh.n_vertices} vertices, {m.tetmesh.n_tets} tets, "
                   f"cushion E = {m.material.youngs_modulus / 1e3:g} kPa")


def _prepare(face, units, mask, mask_units, rigid_plane, thickness, kind, placement, layers, crop, edge, therapy,
             threshold, friction=0.0, leak_threshold=LARGE_LEAK_LPM, contact="barrier", rotation="free"):
    from headsim.mask.fit import prepare_fit

    mesh = _load_face(face, units)
    m = _load_mask(mask, mask_units, rigid_plane, thickness, kind, edge)
    typer.echo(f"face {mesh.name}: {mesh.n_vertices} vertices; mask {m.name}")
    problem = prepare_fit(mesh, m, _options(layers, crop, therapy, threshold, placement, friction, leak_threshold,
                                            contact, rotation))
    d = problem.describe()
    typer.echo(f"model: {d['model_vertices']} vertices, {d['model_tets']} tets "
               f"({d['cropped_skin_vertices']} skin vertices in the mask region)")
    return problem


@app.command("fit")
def fit(face: Optional[Path] = FACE, units: str = UNITS, mask: str = MASK, mask_units: str = MASK_UNITS,
        rigid_plane: Optional[str] = RIGID, thickness: Optional[float] = THICK, kind: str = KIND,
        placement: str = PLACEMENT,
        force: float = typer.Option(15.0, "--force", help="strap force, N"),
        out: Path = typer.Option(..., "--out", help="output folder (report.html, result.json, PNG, VTU/PLY)"),
        layers: int = LAYERS, crop: float = CROP, mask_edge: float = EDGE, therapy_pressure: float = THERAPY,
        threshold: float = THRESH, mode: str = MODE, friction: float = FRICTION,
        leak_threshold: float = LEAK, contact: str = CONTACT, rotation: str = ROTATION) -> None:
    """Press MASK onto FACE with strap force FORCE (N); write pressures, seal, leaks and the leak flow."""
    from headsim.cli._common import atomic_output_dir
    from headsim.mask.fit import check_force, problem_fit
    from headsim.mask.report import fit_contact_check, write_fit_report

    check_force(force)
    _check_mode(mode, friction, contact, rotation)
    contact = _resolve_contact(mode, contact)
    problem = _prepare(face, units, mask, mask_units, rigid_plane, thickness, kind, placement, layers, crop,
                       mask_edge, therapy_pressure, threshold, friction, leak_threshold, contact, rotation)
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    label = f"fit at {force:g} N ({mode}{', ' + contact + ' contact' if mode == 'nonlinear' else ''})"
    with Progress(SpinnerColumn(), TextColumn(label), TextColumn("{task.fields[msg]}"), TimeElapsedColumn(),
                  transient=True) as bar:
        task = bar.add_task("fit", total=None, msg="")
        if mode == "condensed":
            from headsim.mask.condensed import condense_fit, condensed_fit

            result = condensed_fit(condense_fit(problem), force)
        else:
            def progress(it, gnorm, tol):
                bar.update(task, msg=f"Newton iteration {it}: force residual {gnorm:.2e} N (tolerance {tol:.1e} N)")

            result = problem_fit(problem, force, progress=progress)
    check = fit_contact_check(problem, result)
    with atomic_output_dir(out) as tmp:
        write_fit_report(tmp, problem, result, contact_check=check)
    s = result.summary
    typer.echo(f"{'SEALED' if result.sealed else 'LEAKS'} at {force:g} N: contact force {result.contact_force:.3f} N, "
               f"area {s.contact_area_cm2:.2f} cm², peak {s.peak_pressure / 1e3:.1f} kPa, mean "
               f"{s.mean_pressure / 1e3:.1f} kPa; {_leak_text(result)} -> {out}/report.html")
    _echo_check(check, force)


def _echo_check(check, force: float) -> None:
    """Print the contact check's warning (stderr) when the fitted contact is inconsistent."""
    warning = None if check is None else check.warning(force)
    if warning:
        typer.echo("warning: " + warning, err=True)


def _leak_text(result) -> str:
    leak = result.leak
    return (f"leak {leak.flow_lpm:.2f} L/min ({'acceptable' if leak.acceptable else 'too large'}, "
            f"threshold {leak.threshold_lpm:g} L/min; estimate)")


def search_workers(workers: str, contact: str, mode: str) -> int:
    """--workers: an integer >= 1, or "auto": two fits at a time with the barrier contact in the
    nonlinear mode on a machine with two or more cores (the demo search 95 -> 61 s then; module doc of
    :mod:`headsim.mask.search`, "Parallel search"), one otherwise (a planes fit depends on its warm start,
    so the rounds of a parallel search can change its answer, and its fits are too short to pay for the
    worker processes; condensed fits always run one at a time)."""
    import os

    from headsim.errors import ParameterError

    if workers == "auto":
        return 2 if contact == "barrier" and mode == "nonlinear" and (os.cpu_count() or 1) >= 2 else 1
    try:
        n = int(workers)
    except ValueError:
        n = 0
    if n < 1:
        raise ParameterError(f"--workers must be 'auto' or an integer >= 1, got {workers!r}")
    return n


def run_seal_force(problem, out: Path, start: float, maximum: float, tol: float, mode: str = "nonlinear",
                   workers: int = 1):
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from headsim.cli._common import atomic_output_dir
    from headsim.mask.report import fit_contact_check, write_fit_report
    from headsim.mask.search import SearchOptions, least_seal_force

    opts = SearchOptions(start=start, maximum=maximum, abs_tol=tol)
    with Progress(TextColumn("seal-force search"), BarColumn(), TextColumn("{task.completed}/{task.total} fits"),
                  TextColumn("{task.fields[msg]}"), TimeElapsedColumn(), transient=True) as bar:
        task = bar.add_task("search", total=opts.max_solves, msg="")

        def progress(done, total, msg):
            bar.update(task, completed=done, msg=msg)

        result = least_seal_force(problem, opts, progress=progress, mode=mode, workers=workers)
    check = fit_contact_check(problem, result.fit)
    with atomic_output_dir(out) as tmp:
        write_fit_report(tmp, problem, result.fit, result, contact_check=check)
    if result.seal_force is None:
        typer.echo(f"{problem.mask.name} does not seal up to {maximum:g} N ({result.n_solves} fits, "
                   f"{result.seconds:.1f} s; at {result.fit.force:g} N: {_leak_text(result.fit)})")
    else:
        s = result.fit.summary
        typer.echo(f"least sealing force of {problem.mask.name}: {result.seal_force:.2f} N "
                   f"(largest leaking: {result.lower_bound if result.lower_bound is None else round(result.lower_bound, 2)} N; "
                   f"{result.n_solves} fits, {result.seconds:.1f} s); at that force: area {s.contact_area_cm2:.2f} cm², "
                   f"peak {s.peak_pressure / 1e3:.1f} kPa, mean {s.mean_pressure / 1e3:.1f} kPa")
    thr = problem.options.leak_threshold_lpm
    if result.leak_force is None:
        typer.echo(f"least force with an acceptable leak (<= {thr:g} L/min): none up to {result.leak_lower_bound:g} N "
                   f"-> {out}/report.html")
    else:
        lo = "-" if result.leak_lower_bound is None else f"{result.leak_lower_bound:.2f} N"
        typer.echo(f"least force with an acceptable leak (<= {thr:g} L/min, estimate): {result.leak_force:.2f} N "
                   f"(largest with more leak: {lo}; leak at {result.leak_force:.2f} N: {result.leak_fit.leak_flow_lpm:.2f} L/min; "
                   f"{result.leak_solves} extra fits) -> {out}/report.html")
        if result.leak_upper_force is not None:
            typer.echo(f"  ... but only up to {result.leak_window_text()}")
    _echo_check(check, result.fit.force)
    return result


@app.command("seal-force")
def seal_force(face: Optional[Path] = FACE, units: str = UNITS, mask: str = MASK, mask_units: str = MASK_UNITS,
               rigid_plane: Optional[str] = RIGID, thickness: Optional[float] = THICK, kind: str = KIND,
               placement: str = PLACEMENT,
               start: float = typer.Option(10.0, "--start", help="first force tried, N"),
               maximum: float = typer.Option(30.0, "--max-force", help="largest force tried, N (<= 200)"),
               tol: float = typer.Option(0.5, "--tol", help="force tolerance, N (or 5 %, the larger)"),
               out: Path = typer.Option(..., "--out", help="output folder"),
               layers: int = LAYERS, crop: float = CROP, mask_edge: float = EDGE,
               therapy_pressure: float = THERAPY, threshold: float = THRESH, mode: str = MODE,
               friction: float = FRICTION, leak_threshold: float = LEAK, contact: str = CONTACT,
               rotation: str = ROTATION,
               workers: str = typer.Option("auto", "--workers", help="fits solved at once, each in its own process "
                                           "(nonlinear mode; auto: 2 with the barrier contact on >= 2 cores, else 1)")) -> None:
    """Search the least strap force with which MASK seals on FACE (bracketing + bisection, warm-started)."""
    from headsim.mask.search import SearchOptions

    SearchOptions(start=start, maximum=maximum, abs_tol=tol)  # validate before the set-up work
    _check_mode(mode, friction, contact, rotation)
    contact = _resolve_contact(mode, contact)
    n_workers = search_workers(workers, contact, mode)
    problem = _prepare(face, units, mask, mask_units, rigid_plane, thickness, kind, placement, layers, crop,
                       mask_edge, therapy_pressure, threshold, friction, leak_threshold, contact, rotation)
    run_seal_force(problem, out, start, maximum, tol, mode, n_workers)


@app.command("study")
def study(faces: Path = typer.Option(..., "--faces", help="folder of face meshes (*.obj, *.stl, *.ply)"),
          units: str = UNITS,
          masks: str = typer.Option("nasal-S,nasal-M,nasal-L", "--masks", help="comma-separated built-in masks"),
          out: Path = typer.Option(..., "--out", help="output folder (cases.sqlite, ranking.csv, ranking.html)"),
          scheduler: Optional[str] = typer.Option(None, "--scheduler", help="Dask scheduler address (default: a "
                                                  "LocalCluster)"),
          workers: int = typer.Option(2, "--workers", help="LocalCluster workers"),
          start: float = typer.Option(10.0, "--start", help="first force tried, N"),
          maximum: float = typer.Option(60.0, "--max-force", help="largest force tried, N"),
          tol: float = typer.Option(1.0, "--tol", help="force tolerance, N"),
          layers: int = LAYERS, crop: float = CROP, mask_edge: float = EDGE, mode: str = MODE,
          friction: float = FRICTION, contact: str = CONTACT, rotation: str = ROTATION) -> None:
    """Least seal force of every face x mask on Dask; resumable (finished cases kept in OUT/cases.sqlite)."""
    from headsim.mask.study import StudyOptions, run_study

    opts = StudyOptions(units=units, start=start, maximum=maximum, abs_tol=tol, tissue_layers=layers,
                        crop_margin=crop * 1e-3, mask_edge=mask_edge * 1e-3, mode=_check_mode(mode, friction, contact, rotation), friction=friction,
                        contact=_resolve_contact(mode, contact), rotate=rotation == "free")
    summary = run_study(faces, [m.strip() for m in masks.split(",") if m.strip()], out, options=opts,
                        scheduler=scheduler, n_workers=workers, progress=True)
    typer.echo(f"{summary['n_cases']} cases ({summary['n_computed']} computed now, {summary['n_reused']} from the "
               f"store, {summary['n_failed']} failed) -> {out}/ranking.csv, {out}/ranking.html")


def demo(out: Path = typer.Option(Path("headsim-demo"), "--out", help="output folder")) -> None:
    """Least sealing force of the default mask (nasal-M) on the bundled face, with the report."""
    problem = _prepare(None, "m", "nasal-M", "mm", None, None, "nasal", "auto", 1, 8.0, 4.0, 980.665, 4.266)
    run_seal_force(problem, out, 10.0, 30.0, 1.0, workers=search_workers("auto", problem.options.contact, "nonlinear"))
