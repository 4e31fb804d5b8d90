"""Bundled meshes (ICT-FaceKit, MIT licence; see ``LICENSE-ICT-FaceKit-MIT.txt`` and ``README.md`` here).

All bundled meshes are in metres, y up, +z out of the face, +x the subject's left.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from headsim.errors import HeadsimError

_FACES = ("neutral", "identity000", "identity001")


def data_dir() -> Path:
    """Folder of the bundled data inside the installed package."""
    return Path(str(resources.files("headsim") / "data"))


def face_path(name: str = "neutral") -> Path:
    """Path of a bundled face: ``neutral``, ``identity000``, ``identity001`` or ``pop01`` … ``pop12``."""
    d = data_dir() / "faces"
    if name in _FACES:
        return d / f"face_{name}.obj"
    if name.startswith("pop") and (d / "population" / f"face_{name}.obj").exists():
        return d / "population" / f"face_{name}.obj"
    raise HeadsimError(
        f"unknown bundled face {name!r}; choose one of {', '.join(_FACES)}, pop01 … pop12"
    )


def population_paths() -> list[Path]:
    """The 12 bundled population faces (face_pop01.obj … face_pop12.obj), sorted."""
    return sorted((data_dir() / "faces" / "population").glob("face_pop*.obj"))


def head_path() -> Path:
    """The bundled whole-head skin (face + scalp + neck), for hair work."""
    return data_dir() / "heads" / "head_neutral.obj"
