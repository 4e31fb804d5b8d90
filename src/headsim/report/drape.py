"""Report of a fibre drape run (``headsim hair drape``; Sobottka 2008 ch. 8): an interactive offline HTML page
with the fibres over the obstacle in 3-D (a slider over the recorded frames), the per-step statistics and the
numbers a reader checks first (cm, µm, J in the page; SI inside)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from headsim.hair.drape import DrapeResult, DrapeScene, bounding_box
from headsim.hair.drape_pictures import clip_to_box, view_box
from headsim.report.html import write_html_report

__all__ = ["drape_numbers", "drape_figure", "statistics_figure", "write_drape_report"]

MAX_SLIDER_LABELS = 10  # a slider with more frames hides its step labels (the current time stays shown)
MAX_FIBRES_SHOWN = 60  # fibres drawn in the 3-D view (every k-th): the page stays a few MB for the full scene
CM = 100.0


def drape_numbers(scene: DrapeScene, result: DrapeResult) -> list[tuple[str, str]]:
    """(label, value) rows for people."""
    ext, vol = bounding_box(result.polylines[-1])
    steps = len(result.step_time)
    median = float(np.median(result.step_seconds)) if len(result.step_seconds) else float("nan")
    rows = [
        ("scene", scene.description),
        ("time steps", f"{steps} × {scene.dt * 1e3:g} ms = {steps * scene.dt:.3f} s"),
        ("wall time per step (median)", f"{median:.3g} s"),
        ("final bounding box (Table 8.1's measure)", f"{ext[0] * CM:.2f} × {ext[1] * CM:.2f} × {ext[2] * CM:.2f} cm "
                                                     f"= {vol * 1e6:.1f} cm³"),
        ("kinetic energy: peak → final", f"{result.kinetic.max():.3e} → {result.kinetic[-1]:.3e} J"),
        ("active contacts at the end (fibre–fibre / fibre–obstacle)",
         f"{int(result.fibre_contacts[-1])} / {int(result.obstacle_contacts[-1])}"),
        ("largest penetration (any step; first order at the mid-step state, and the obstacles at the end)",
         f"{result.max_penetration.max() * 1e6:.1f} µm (fibre radius {scene.model.radius[0] * 1e6:.0f} µm)"),
        ("largest joint gap (any step)", f"{result.max_joint_gap.max() * 1e6:.2f} µm"),
        ("contact solves that ended at their sweep cap", f"{int(result.qp_capped.sum())} "
                                                         f"of the run's (≤ {int(result.qp_capped.max())} per step)"),
    ]
    if len(result.substeps):
        rows.append(("steps taken in halves (energy rose or a segment turned > max_rotation_per_step)",
                     f"{int((result.substeps > 1).sum())} of {steps} (≤ {int(result.substeps.max())} solver steps in "
                     "one)"))
    if len(result.end_overlap) and np.isfinite(result.end_overlap).any():
        rows.append(("largest overlap of a contact at the end of a step (exact, after the post-stabilisation)",
                     f"{np.nanmax(result.end_overlap) * 1e6:.1f} µm"))
    if len(result.crossings_restored):
        rows.append(("fibre pairs turned back after passing through each other",
                     f"{int(result.crossings_restored.sum())} in the run"))
    if len(result.joint_root_failures):
        rows.append(("fibre joint solves on the start levers (the mean-lever Newton did not converge)",
                     f"{int(result.joint_root_failures.sum())} in the run"))
    return rows


def _fibre_lines(polylines: np.ndarray, stride: int) -> np.ndarray:
    """The fibres polylines[::stride] (m) as one (N, 3) float32 array in cm (0.1 nm rounding at 10 cm; half the
    page of float64) with a NaN row between fibres (one trace)."""
    p = (polylines[::stride] * CM).astype(np.float32)
    gap = np.full((p.shape[0], 1, 3), np.nan, np.float32)
    return np.concatenate([p, gap], axis=1).reshape(-1, 3)


def drape_figure(scene: DrapeScene, result: DrapeResult):
    """plotly figure: the obstacle (the part inside the fibres' box) and every recorded frame's fibres (at most
    :data:`MAX_FIBRES_SHOWN`), one frame shown at a time with a slider; y up, cm."""
    import plotly.graph_objects as go

    F = result.polylines.shape[1]
    stride = max(1, -(-F // MAX_FIBRES_SHOWN))
    lower, upper = view_box(result.polylines)
    traces = []
    if scene.obstacle_mesh is not None:
        v, tt = clip_to_box(*scene.obstacle_mesh, lower, upper)
        if len(tt):
            w = v * CM
            traces.append(go.Mesh3d(x=w[:, 0], y=w[:, 1], z=w[:, 2], i=tt[:, 0], j=tt[:, 1], k=tt[:, 2],
                                    color="#9fb0c8", opacity=0.6, name=scene.obstacles[0].name, showlegend=True,
                                    hoverinfo="skip"))
    fibre_trace = len(traces)

    def fibres(k):
        q = _fibre_lines(result.polylines[k], stride)
        return go.Scatter3d(x=q[:, 0], y=q[:, 1], z=q[:, 2], mode="lines", line=dict(color="saddlebrown", width=2),
                            name=f"fibres (every {stride}.)" if stride > 1 else "fibres", showlegend=True)

    last = len(result.times) - 1
    traces.append(fibres(last))
    fig = go.Figure(data=traces)
    fig.frames = [go.Frame(data=[fibres(k)], traces=[fibre_trace], name=str(k)) for k in range(len(result.times))]
    steps = [dict(method="animate", label=f"{result.times[k]:.3f}",
                  args=[[str(k)], dict(mode="immediate", frame=dict(duration=0, redraw=True),
                                       transition=dict(duration=0))]) for k in range(len(result.times))]
    box = [[lower[i] * CM, upper[i] * CM] for i in range(3)]
    fig.update_layout(
        height=650, margin=dict(l=0, r=0, t=30, b=0), legend=dict(x=0, y=1),
        sliders=[dict(active=last, steps=steps, currentvalue=dict(prefix="t = ", suffix=" s"), pad=dict(t=10),
                      # more than 10 frames: the step labels would run into each other; the current time is shown
                      **(dict(font=dict(color="rgba(0,0,0,0)")) if len(steps) > MAX_SLIDER_LABELS else {}))],
        scene=dict(xaxis=dict(title="x [cm]", range=box[0]), yaxis=dict(title="y [cm]", range=box[1]),
                   zaxis=dict(title="z [cm]", range=box[2]), aspectmode="cube",
                   camera=dict(up=dict(x=0, y=1, z=0), eye=dict(x=1.2, y=0.9, z=1.5))))
    return fig


def statistics_figure(result: DrapeResult):
    """plotly figure of the per-step statistics: kinetic energy, active contacts, penetration, joint gap."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    t = result.step_time
    fig = make_subplots(rows=3, cols=1, shared_xaxes=True, vertical_spacing=0.06)
    fig.add_trace(go.Scatter(x=t, y=np.maximum(result.kinetic, 1e-30), name="kinetic energy [J]"), row=1, col=1)
    fig.add_trace(go.Scatter(x=t, y=result.fibre_contacts, name="fibre–fibre contacts"), row=2, col=1)
    fig.add_trace(go.Scatter(x=t, y=result.obstacle_contacts, name="fibre–obstacle contacts"), row=2, col=1)
    fig.add_trace(go.Scatter(x=t, y=result.max_penetration * 1e6, name="largest penetration [µm]"), row=3, col=1)
    fig.add_trace(go.Scatter(x=t, y=result.max_joint_gap * 1e6, name="largest joint gap [µm]"), row=3, col=1)
    fig.update_yaxes(type="log", title_text="J", row=1, col=1)
    fig.update_yaxes(title_text="contacts", row=2, col=1)
    fig.update_yaxes(title_text="µm", row=3, col=1)
    fig.update_xaxes(title_text="t [s]", row=3, col=1)
    fig.update_layout(height=700, margin=dict(l=60, r=10, t=20, b=40))
    return fig


def write_drape_report(scene: DrapeScene, result: DrapeResult, path: str | Path,
                       *, title: str = "Fibre drape") -> Path:
    """Self-contained HTML (plotly.js embedded, works offline; written atomically): numbers, the 3-D view with
    a frame slider, the per-step statistics."""
    notes = ["Rigid-segment fibres (kinematic chains) with Moreau midpoint time stepping, per-step contact "
             "projection and friction (Sobottka 2008 ch. 8). The 3-D view draws at most "
             f"{MAX_FIBRES_SHOWN} fibres and the part of the obstacle inside the fibres' box; the slider steps "
             "through the recorded frames. The full trajectory is in trajectory.npz and vtk/."]
    figs = [("Fibres on the obstacle (cm; slider: recorded frames)", drape_figure(scene, result)),
            ("Per-step statistics", statistics_figure(result))]
    return write_html_report(path, title=f"{title}: {scene.name}", figures=figs,
                             numbers=drape_numbers(scene, result), notes=notes)
