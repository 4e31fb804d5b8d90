"""``headsim mesh``: inspect, validate and tetrahedralise meshes."""

from __future__ import annotations

import typer

app = typer.Typer(help="Inspect, validate, repair and tetrahedralise meshes.", no_args_is_help=True)
