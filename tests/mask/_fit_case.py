"""A small mask-fit problem shared by the fit / search / report tests (built once per session).

Coarse on purpose (tests must be fast): nasal-M meshed at 5 mm, one tissue layer, skin cropped 6 mm
around the cushion footprint. The physics checks (force balance, monotonicity) do not depend on
the resolution.
"""

from __future__ import annotations

from functools import lru_cache

from headsim.data import face_path
from headsim.mask import find_landmarks, make_mask
from headsim.mask.fit import FitOptions, prepare_fit, problem_fit
from headsim.mesh.io import load_surface

COARSE = FitOptions(tissue_layers=1, crop_margin=0.006)


@lru_cache(maxsize=1)
def neutral():
    face = load_surface(face_path("neutral"))
    return face, find_landmarks(face)


@lru_cache(maxsize=1)
def coarse_problem():
    face, lm = neutral()
    return prepare_fit(face, make_mask("nasal-M", edge_length=5e-3), COARSE, landmarks=lm)


@lru_cache(maxsize=4)
def coarse_fit(force: float):
    return problem_fit(coarse_problem(), force)
