"""Interactive, self-contained (offline) HTML reports with plotly.

:func:`mesh_figure` draws triangle meshes in 3-D, optionally coloured by a per-vertex scalar;
:func:`write_html_report` writes a page with a title, a table of numbers and any number of figures,
with plotly.js embedded (``include_plotlyjs=True``: works without network) and written atomically
(temporary file, then rename). Generic: used by the graft planner and reusable by the other apps.
"""

from __future__ import annotations

import html
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from headsim._atomic import atomic_output_file


__all__ = ["MeshLayer", "mesh_figure", "write_html_report", "numbers_table"]


@dataclass(frozen=True, eq=False)
class MeshLayer:
    """One mesh to draw.

    vertices : (n, 3) float64 (any length unit; the caller converts, e.g. to mm for display)
    triangles : (m, 3) int64
    scalar : (n,) float64 per-vertex values for the colour map, or None for a plain colour
    name : legend name; color : plain colour; opacity in (0, 1]
    """

    vertices: np.ndarray
    triangles: np.ndarray
    scalar: np.ndarray | None = None
    name: str = "mesh"
    color: str = "#d9b38c"
    opacity: float = 1.0
    offset: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0))


def mesh_figure(layers: Sequence[MeshLayer] | MeshLayer, *, title: str = "", colorbar_title: str = "",
                colorscale: str = "RdBu_r", symmetric: bool = True, cmin: float | None = None,
                cmax: float | None = None, height: int = 600):
    """A plotly figure of one or more meshes (``go.Mesh3d``), coloured by their scalars if given.

    With ``symmetric`` the colour range is ±max|scalar| (signed differences). Axes keep equal scale.
    """
    import plotly.graph_objects as go

    if isinstance(layers, MeshLayer):
        layers = [layers]
    scalars = [np.asarray(l.scalar, float) for l in layers if l.scalar is not None]
    if scalars and (cmin is None or cmax is None):
        allv = np.concatenate(scalars)
        if symmetric:
            m = float(np.max(np.abs(allv))) or 1.0
            cmin, cmax = -m, m
        else:
            cmin, cmax = float(allv.min()), float(allv.max())
    fig = go.Figure()
    shown_bar = False
    for layer in layers:
        v = np.asarray(layer.vertices, float) + np.asarray(layer.offset, float)
        t = np.asarray(layer.triangles, np.int64)
        kw = dict(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=t[:, 0], j=t[:, 1], k=t[:, 2], name=layer.name,
                  opacity=layer.opacity, showlegend=True, flatshading=False,
                  lighting=dict(ambient=0.45, diffuse=0.8, specular=0.1, roughness=0.8),
                  lightposition=dict(x=0, y=0, z=1e5))
        if layer.scalar is not None:
            kw.update(intensity=np.asarray(layer.scalar, float), intensitymode="vertex", colorscale=colorscale,
                      cmin=cmin, cmax=cmax, showscale=not shown_bar,
                      colorbar=dict(title=colorbar_title))
            shown_bar = True
        else:
            kw.update(color=layer.color)
        fig.add_trace(go.Mesh3d(**kw))
    fig.update_layout(
        title=title, height=height, margin=dict(l=0, r=0, t=40 if title else 10, b=0),
        scene=dict(aspectmode="data", camera=dict(up=dict(x=0, y=1, z=0), eye=dict(x=0, y=0, z=2.0))),
        legend=dict(x=0, y=1),
    )
    return fig


def numbers_table(rows: Sequence[tuple[str, str]]) -> str:
    """An HTML table of (label, value) rows, escaped."""
    body = "".join(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(str(v))}</td></tr>" for k, v in rows)
    return f'<table class="numbers">{body}</table>'


_STYLE = """
body { font-family: system-ui, sans-serif; margin: 1.5em; color: #222; }
h1 { font-size: 1.4em; } h2 { font-size: 1.1em; margin-top: 1.5em; }
table.numbers { border-collapse: collapse; } table.numbers th, table.numbers td { border: 1px solid #ccc;
 padding: 0.25em 0.6em; text-align: left; } table.numbers th { background: #f3f3f3; font-weight: 600; }
.note { color: #555; font-size: 0.9em; max-width: 60em; }
"""


def write_html_report(path: str | os.PathLike, *, title: str, figures: Sequence[tuple[str, object]] = (),
                      numbers: Sequence[tuple[str, str]] = (), notes: Sequence[str] = ()) -> Path:
    """Write a self-contained HTML page: title, numbers table, notes and (heading, plotly figure) sections.

    plotly.js is embedded once (the page works offline). The file appears only when complete.
    """
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
             f"<style>{_STYLE}</style></head><body><h1>{html.escape(title)}</h1>"]
    if numbers:
        parts.append(numbers_table(numbers))
    for note in notes:
        parts.append(f"<p class='note'>{html.escape(note)}</p>")
    first = True
    for heading, fig in figures:
        parts.append(f"<h2>{html.escape(heading)}</h2>")
        # auto_play False: a figure with frames (a slider over time) opens at its slider's active step instead of
        # playing through every frame on load (plotly's default) and stopping wherever that left it
        parts.append(fig.to_html(full_html=False, include_plotlyjs=True if first else False, auto_play=False))
        first = False
    parts.append("</body></html>")
    path = Path(path)
    with atomic_output_file(path) as tmp:
        tmp.write_text("".join(parts), encoding="utf-8")
    return path
