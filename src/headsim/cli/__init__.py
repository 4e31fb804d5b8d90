"""The ``headsim`` command line: a thin layer over the Python API.

Each command group lives in its own module (``mesh_cmd``, ...) and imports heavy modules lazily so
``headsim --help`` stays fast. :func:`main` turns every :class:`headsim.HeadsimError` into a one-line
message on stderr and exit code 2.
"""

from __future__ import annotations

import sys

import typer

from headsim import __version__
from headsim.errors import HeadsimError

app = typer.Typer(
    name="headsim",
    help="Physics simulation of the soft parts of the human head: mask fit, fat grafting, hair.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version_callback(value: bool) -> None:
    if value:
        typer.echo(f"headsim {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_version_callback, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """headsim: physics simulation of the soft parts of the human head."""


def _register() -> None:
    from headsim.cli import mesh_cmd

    app.add_typer(mesh_cmd.app, name="mesh")

    from headsim.cli import scene_cmd

    app.add_typer(scene_cmd.app, name="scene")

    from headsim.cli import graft_cmd

    app.command("graft")(graft_cmd.graft)
    app.command("compare")(graft_cmd.compare)
    app.command("graft-scene")(graft_cmd.graft_scene)

    from headsim.cli import hair_cmd

    app.add_typer(hair_cmd.app, name="hair")

    from headsim.cli import mask_cmd

    app.add_typer(mask_cmd.app, name="mask")
    app.command("demo")(mask_cmd.demo)


_register()


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the CLI, turning headsim errors into a message and exit code 2."""
    try:
        app(args=argv, prog_name="headsim")
    except HeadsimError as e:
        typer.secho(f"error: {e}", fg=typer.colors.RED, err=True)
        sys.exit(2)
