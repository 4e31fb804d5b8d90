"""``headsim hair charge``: electrostatic charging of a fibre assembly (Sobottka 2008 ch. 4, Alg. 2).

The ``hair`` command group lives in ``hair_cmd.py``; it calls :func:`register` to add this command.
Inputs in the seed's units at this edge: line charge density in statC/cm, particle density per cm,
scalp charge in statC, relative humidity in percent; everything inside is SI.
"""

from __future__ import annotations

from pathlib import Path

import typer

SCENES = ("bundle", "head")


def _views(before, after, path: Path, title: str) -> None:
    """PNG: fibres before (grey) and after (blue) charging, front (x, y) and side (z, y) views."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    fig, axes = plt.subplots(1, 2, figsize=(12, 6.5), dpi=110)
    step = max(1, before.shape[0] // 1500)
    for ax, (i, j, name) in zip(axes, [(0, 1, "front (x, y)"), (2, 1, "side (z, y)")]):
        for P, colour, label in ((before, "0.6", "before"), (after, "tab:blue", "after")):
            if P is None:
                continue
            ax.add_collection(LineCollection([p[:, [i, j]] for p in P[::step]], colors=colour, linewidths=0.4,
                                             alpha=0.7, label=label))
        ax.autoscale()
        x0, x1 = ax.get_xlim()
        y0, y1 = ax.get_ylim()
        if max(x1 - x0, y1 - y0) < 5 * min(x1 - x0, y1 - y0):  # keep thin bundles readable
            ax.set_aspect("equal")
        ax.set_title(name)
        ax.set_xlabel("m")
        ax.legend(loc="lower right", fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _field_picture(gu, gv, E, probe_uv, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.colors import LogNorm

    fig, ax = plt.subplots(figsize=(7, 6.5), dpi=110)
    Ep = np.maximum(E / 1e3, 1e-6)
    im = ax.pcolormesh(gu, gv, Ep, norm=LogNorm(vmin=max(Ep.min(), Ep.max() * 1e-4), vmax=Ep.max()), shading="auto",
                       cmap="magma")
    fig.colorbar(im, ax=ax, label="|E|, kV/m")
    ax.plot([probe_uv[0]], [probe_uv[1]], "c+", ms=12, label="probe (12 cm from the surface)")
    ax.set_xlabel("lateral, m")
    ax.set_ylabel("along the axis, m")
    ax.set_aspect("equal")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def charge_cmd(
    scene: str = typer.Option("bundle", help="bundle (the seed's test 1) | head (half-head hairstyle)"),
    charge: float = typer.Option(-7.7e-4, help="line charge density on every fibre, statC/cm (seed: -7.7e-4)"),
    steps: int = typer.Option(8, min=1, help="charging increments (logarithmically decreasing)"),
    schedule: str = typer.Option("incremental", help="incremental | one-shot"),
    rh: float = typer.Option(65.0, help="relative humidity, percent"),
    temperature: float = typer.Option(25.0, help="temperature, C"),
    scale: float = typer.Option(1.0, min=1e-4, help="fraction of the scene's fibres (bundle: 300, head: 400)"),
    segments: int = typer.Option(0, min=0, help="segments per fibre (0: 100 bundle, 30 head)"),
    length_cm: float = typer.Option(0.0, min=0.0, help="fibre length, cm (0: 30 bundle, 12 head)"),
    density: float = typer.Option(330.0, min=1e-3, help="charge particles per cm of fibre (seed: 330)"),
    scalp_charge: float = typer.Option(None, help="scalp charge Q_S, statC (default: 0 bundle; head: the "
                                                    "total hair charge)"),
    method: str = typer.Option("treecode", help="Coulomb method: treecode | fmm3d | direct"),
    theta: float = typer.Option(0.3, help="treecode opening angle (0.3: ~3 digits)"),
    eps: float = typer.Option(1e-3, help="fmm3d precision"),
    gravity: bool = typer.Option(True, help="gravity along -y"),
    out: Path = typer.Option(..., help="output folder (replaced atomically on success)"),
    render: bool = typer.Option(False, help="also write path-traced before/after frames (Marschner model) "
                                            "to rendered/"),
    preset: str = typer.Option("brown", help="hair colour preset for --render (blond, brown, black, red)"),
) -> None:
    """Charge the fibres (Algorithm 2), write before/after pictures, a field-strength map and numbers."""
    import json
    import time

    import numpy as np
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from headsim.cli._common import atomic_output_dir
    from headsim.errors import ParameterError
    from headsim.hair.electrostatics import (
        ChargingOptions,
        CoulombOptions,
        bundle_scene,
        charge_fibres,
        field_map,
        field_strength,
        head_scene,
        probe_beside,
    )
    from headsim.hair.electrostatics.units import STATCOULOMB, per_cm_to_per_m, statc_per_cm_to_c_per_m

    if scene not in SCENES:
        raise ParameterError(f"unknown scene {scene!r}; choose bundle or head")
    if not 0.0 <= rh <= 100.0:
        raise ParameterError(f"relative humidity must be a percentage in [0, 100], got {rh}")
    kw = {"relative_humidity": rh / 100.0, "temperature_c": temperature}
    if segments:
        kw["n_segments"] = segments
    if length_cm:
        kw["length"] = length_cm / 100.0
    if scene == "bundle":
        sc = bundle_scene(n_fibres=max(1, int(round(300 * scale))), **kw)
    else:
        sc = head_scene(n_fibres=max(1, int(round(400 * scale))), **kw)
    lam = statc_per_cm_to_c_per_m(charge)
    total_hair = lam * float(sc.model.length.sum())
    if scalp_charge is None:
        qs = total_hair if scene == "head" else 0.0
    else:
        qs = scalp_charge * STATCOULOMB
    coulomb = CoulombOptions(method=method, eps=eps, theta=theta)
    opts = ChargingOptions(line_charge=lam, particle_density=per_cm_to_per_m(density), steps=steps,
                           schedule=schedule, scalp_charge=qs,
                           gravity=(0.0, -9.81, 0.0) if gravity else (0.0, 0.0, 0.0),
                           coulomb=coulomb)
    t0 = time.perf_counter()
    n_incr = steps if schedule == "incremental" else 1
    with Progress(TextColumn(f"[bold]charging {sc.name}[/bold]"), BarColumn(),
                  TextColumn("{task.completed}/{task.total} increments"), TextColumn("{task.description}"),
                  TimeElapsedColumn()) as progress:
        task = progress.add_task("", total=n_incr)

        def report(h, n, info):
            progress.update(task, completed=h, description=f"q = {info['charge_fraction']:.2f} Q, "
                                                           f"{info['passes']} passes")

        res = charge_fibres(sc.model, opts, scalp=sc.scalp, progress=report)
    seconds = time.perf_counter() - t0
    probe = probe_beside(res.particles, sc.axis_point, sc.axis, 0.12)
    field_opts = CoulombOptions(method="treecode" if method != "fmm3d" else "fmm3d", eps=1e-6, theta=0.3)
    e_probe = float(field_strength(probe[None, :], res.particles, res.charges, field_opts)[0])
    extent = 0.2 if scene == "bundle" else 0.25
    gu, gv, E, origin, eu, ev = field_map(res.particles, res.charges, sc.axis_point, sc.axis, extent, 40, field_opts)
    lateral = lambda P: (P - sc.axis_point) - np.outer((P - sc.axis_point) @ sc.axis, sc.axis)  # noqa: E731
    spread_before = float(np.linalg.norm(lateral(res.positions_before[:, -1]), axis=1).mean())
    spread_after = float(np.linalg.norm(lateral(res.positions_after[:, -1]), axis=1).mean())
    e_part = res.field_at_particles
    numbers = {
        "scene": sc.name, "scene_info": sc.info, "schedule": schedule, "steps": n_incr,
        "line_charge_statc_per_cm": charge, "line_charge_c_per_m": lam,
        "particles": int(res.sampling.n_particles), "charge_per_particle_c": float(res.charges[0]),
        "charge_per_particle_statc": float(res.charges[0] / STATCOULOMB), "scalp_charge_c": qs,
        "coulomb": {"method": method, "theta": theta, "eps": eps},
        "field_at_probe_v_per_m": e_probe, "probe_position_m": probe.tolist(),
        "seed_reference": "Sobottka: ~13 kV/m; Patel 1988: 20-120 kV/m at 12 cm from combed tresses",
        "field_at_particles_v_per_m": {"mean": float(e_part.mean()), "max": float(e_part.max())},
        "tip_spread_m": {"before": spread_before, "after": spread_after},
        "max_node_displacement_m": float(np.abs(res.positions_after - res.positions_before).max()),
        "converged": res.converged, "history": res.history, "seconds": seconds,
    }
    pu = float((probe - origin) @ eu)
    pv = float((probe - origin) @ ev)
    with atomic_output_dir(out) as tmp:
        _views(res.positions_before, None, tmp / "before.png", f"{sc.name}: before charging (gravity equilibrium)")
        _views(res.positions_before, res.positions_after, tmp / "after.png",
               f"{sc.name}: after charging, {charge:g} statC/cm, RH {rh:g} %, {schedule} ({n_incr} steps)")
        _field_picture(gu, gv, E, (pu, pv), tmp / "field_map.png",
                       f"|E| after charging; probe: {e_probe / 1e3:.2f} kV/m")
        np.savez_compressed(tmp / "charging.npz", positions_before=res.positions_before,
                            positions_after=res.positions_after, particles=res.particles, charges=res.charges,
                            coulomb_forces=res.coulomb_forces, scalp_forces=res.scalp_forces, field_map=E,
                            field_u=gu, field_v=gv)
        (tmp / "charging.json").write_text(json.dumps(numbers, indent=2))
        if render:
            from headsim.hair.render.frames import render_frames

            render_frames([res.positions_before, res.positions_after], tmp / "rendered", preset=preset)
    typer.echo(f"{sc.name}: {res.sampling.n_particles:,} charges, {n_incr} increments in {seconds:.1f} s; "
               f"|E| at 12 cm = {e_probe / 1e3:.2f} kV/m; tip spread {spread_before * 1e3:.2f} -> "
               f"{spread_after * 1e3:.2f} mm; wrote {out}")


def register(hair_app: typer.Typer) -> None:
    """Add the ``charge`` command to the ``hair`` typer app."""
    hair_app.command("charge")(charge_cmd)
