"""A small mask-fit problem shared by the fit / search / report tests (built once per session).

Coarse on purpose (tests must be fast): nasal-M meshed at 5 mm, one tissue layer, skin cropped 6 mm
around the cushion footprint. The physics checks (force balance, monotonicity) do not depend on
the resolution.

The cushion is the analytic saddle (``make_mask(..., contour=False)``), not the default contoured
one: the contoured edge follows the face to 0.2 mm, so at small loads it touches all round at once
along a line about one skin vertex wide, and its peak pressure is then set by the mesh resolution,
not by the model (condensed vs nonlinear at 1 N: peak 29.5 vs 24.4 kPa, 21 % apart against a strain
scale of 0.13; the seal answer's resolution dependence is measured in headsim.mask.fit's doc). The
saddle touches first in patches at the bridge and the lip, a well-posed comparison for the solver
checks that use this problem.
"""

from __future__ import annotations

from functools import lru_cache

from headsim.data import face_path
from headsim.mask import find_landmarks, make_mask
from headsim.mask.fit import FitOptions, prepare_fit, problem_fit
from headsim.mesh.io import load_surface

COARSE = FitOptions(tissue_layers=1, crop_margin=0.006, contact="planes")  # the planes model's tests


@lru_cache(maxsize=1)
def neutral():
    face = load_surface(face_path("neutral"))
    return face, find_landmarks(face)


@lru_cache(maxsize=1)
def coarse_problem():
    face, lm = neutral()
    return prepare_fit(face, make_mask("nasal-M", edge_length=5e-3, contour=False), COARSE, landmarks=lm)


@lru_cache(maxsize=4)
def coarse_fit(force: float):
    return problem_fit(coarse_problem(), force)


@lru_cache(maxsize=1)
def coarse_barrier_problem():
    """The coarse problem with the barrier contact (FitOptions.contact="barrier")."""
    from dataclasses import replace

    face, lm = neutral()
    return prepare_fit(face, make_mask("nasal-M", edge_length=5e-3, contour=False),
                       replace(COARSE, contact="barrier"), landmarks=lm)


@lru_cache(maxsize=2)
def coarse_barrier_fit(force: float):
    return problem_fit(coarse_barrier_problem(), force)
