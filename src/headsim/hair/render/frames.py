"""Rendered frames for every hair command: path-traced PNGs of a sequence of fibre states.

The rod, charge (and later drape and style) commands record fibre polylines over time; this module turns
them into images with the corrected Marschner model (:mod:`headsim.hair.render.renderer`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from headsim.hair.render.bvh import CapsuleBVH, FibreAssembly
from headsim.hair.render.renderer import Light, RenderOptions, Surface, camera_looking_at, render, save_png
from headsim.hair.render.scattering import MarschnerParams

__all__ = ["render_frames"]


def render_frames(frames: Sequence[np.ndarray], folder: str | Path, *, radius: float = 35e-6,
                  preset: str = "brown", width: int = 256, height: int = 256, spp: int = 8,
                  azimuth_deg: float = 30.0, elevation_deg: float = 10.0, min_pixels: float = 1.0,
                  progress: Callable[[int, int], None] | None = None,
                  surfaces: Sequence[Surface] = ()) -> list[Path]:
    """Render each frame to ``folder/frame_XXXX.png`` with one camera framing all frames' fibres; ``surfaces``
    (e.g. the obstacle of a drape) are drawn with them.

    Parameters
    ----------
    frames : sequence of (F, N, 3) float64 arrays, m — F fibres of N nodes each (a (N, 3) array is one fibre)
    radius : fibre radius, m. A single hair (35 µm) is far thinner than a pixel when a whole rod is in
        view, so the drawn radius is raised to ``min_pixels`` pixel footprints where needed (display
        thickening only; the scattering model is unchanged)
    preset : Marschner colour preset (blond, brown, black, red)

    Returns
    -------
    The written PNG paths.
    """
    frames = [np.asarray(f, dtype=np.float64).reshape(-1 if np.ndim(f) == 3 else 1, np.shape(f)[-2], 3)
              for f in frames]
    everything = np.concatenate([f.reshape(-1, 3) for f in frames])
    n_nodes = frames[0].shape[1]
    offsets = np.arange(0, len(everything) + 1, n_nodes, dtype=np.int64)
    camera = camera_looking_at(FibreAssembly(everything, offsets, radius), azimuth_deg=azimuth_deg,
                               elevation_deg=elevation_deg)
    span = float(np.linalg.norm(everything.max(axis=0) - everything.min(axis=0))) or 1e-3
    pixel = span / width
    drawn_radius = max(radius, 0.5 * min_pixels * pixel)
    params = MarschnerParams.preset(preset)
    options = RenderOptions(width=width, height=height, spp=spp, env=(0.05,) * 3, background=(0.05,) * 3)
    lights = [Light("directional", (1.0, 0.8, 0.6), (3.0, 3.0, 3.0))]
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, f in enumerate(frames):
        fibres = FibreAssembly(f.reshape(-1, 3), np.arange(0, f.size // 3 + 1, f.shape[1], dtype=np.int64),
                               drawn_radius)
        result = render(CapsuleBVH.from_fibres(fibres), params, camera, lights, options, surfaces=surfaces)
        path = folder / f"frame_{k:04d}.png"
        save_png(path, result.image, 2.0)
        paths.append(path)
        if progress is not None:
            progress(k + 1, len(frames))
    return paths
