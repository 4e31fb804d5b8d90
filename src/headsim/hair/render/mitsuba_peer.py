"""The same scene rendered by Mitsuba 3 (optional extra ``render``): ``linearcurve`` fibres with the
built-in ``hair`` BSDF (Chiang et al. 2016), ``path`` integrator — the peer of :func:`render`.

Parameter mapping (so both renderers draw the same hair): melanin concentrations are passed unchanged
(both use the d'Eon 2011 absorption per radius); Chiang's longitudinal variance v = (0.726β_m + 0.812β_m²
+ 3.7β_m²⁰)² is matched to Marschner's R-lobe variance in θ_r, (2β_R)²; scale_tilt = −α_R; path
max_depth = max_scatter + 1 (Mitsuba counts the camera segment).
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np

from headsim.errors import HeadsimError
from headsim.hair.render.bvh import FibreAssembly
from headsim.hair.render.renderer import Camera, RenderOptions, RenderResult
from headsim.hair.render.scattering import MarschnerParams

__all__ = ["mitsuba_available", "chiang_longitudinal_roughness", "render_mitsuba", "write_curves"]


def mitsuba_available() -> bool:
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        return False
    return True


def chiang_longitudinal_roughness(beta_r_deg: float) -> float:
    """β_m whose Chiang variance equals Marschner's R variance in θ_r, (2β_R)² (bisection)."""
    target = 2 * math.radians(beta_r_deg)
    lo, hi = 1e-4, 1.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if 0.726 * mid + 0.812 * mid**2 + 3.7 * mid**20 < target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def write_curves(fibres: FibreAssembly, path: Path) -> None:
    """Mitsuba ``linearcurve`` text file: 'x y z radius' per node, a blank line between fibres."""
    rows = np.column_stack([fibres.nodes, fibres.radius])
    off = fibres.fibre_offsets
    with open(path, "w") as f:
        for k in range(len(off) - 1):
            blk = rows[off[k]:off[k + 1]]
            f.write("\n".join(" ".join(f"{v:.9g}" for v in r) for r in blk))
            f.write("\n\n")


def render_mitsuba(fibres: FibreAssembly, params: MarschnerParams, camera: Camera, lights, options: RenderOptions,
                   eumelanin: float, pheomelanin: float = 0.0, azimuthal_roughness: float = 0.2,
                   variant: str = "scalar_rgb") -> RenderResult:
    """Render with Mitsuba 3's ``hair`` BSDF; ``build`` holds the scene-loading time (incl. its BVH)."""
    try:
        import mitsuba as mi
    except ImportError as e:  # pragma: no cover - optional
        raise HeadsimError("Mitsuba 3 is not installed: pip install 'headsim[render]'") from e
    mi.set_variant(variant)
    h, w = options.height, options.width
    emitters = {}
    for k, light in enumerate(lights):
        rgb = {"type": "rgb", "value": list(map(float, light.rgb))}
        if light.kind == "directional":
            d = -np.asarray(light.vector, dtype=np.float64)
            emitters[f"light{k}"] = {"type": "directional", "direction": (d / np.linalg.norm(d)).tolist(),
                                     "irradiance": rgb}
        else:
            emitters[f"light{k}"] = {"type": "point", "position": list(map(float, light.vector)), "intensity": rgb}
    if any(options.env):
        emitters["env"] = {"type": "constant", "radiance": {"type": "rgb", "value": list(map(float, options.env))}}
    with tempfile.TemporaryDirectory() as tmp:
        curves = Path(tmp) / "fibres.txt"
        write_curves(fibres, curves)
        t0 = time.perf_counter()
        scene = mi.load_dict({
            "type": "scene",
            "integrator": {"type": "path", "max_depth": int(options.max_scatter) + 1},
            "sensor": {
                "type": "perspective", "fov": float(camera.fov_deg), "fov_axis": "y",
                "to_world": mi.ScalarTransform4f().look_at(origin=list(map(float, camera.position)),
                                                           target=list(map(float, camera.look_at)),
                                                           up=list(map(float, camera.up))),
                "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"}},
                "sampler": {"type": "independent", "sample_count": int(options.spp), "seed": int(options.seed)},
            },
            "hair": {"type": "linearcurve", "filename": str(curves),
                     "bsdf": {"type": "hair", "eumelanin": float(eumelanin), "pheomelanin": float(pheomelanin),
                              "longitudinal_roughness": chiang_longitudinal_roughness(params.beta_r_deg),
                              "azimuthal_roughness": float(azimuthal_roughness),
                              "scale_tilt": float(-params.alpha_r_deg)}},
            **emitters,
        })
        build = time.perf_counter() - t0
    t1, c1 = time.perf_counter(), time.process_time()
    img = np.array(mi.render(scene), dtype=np.float64)[:, :, :3]
    return RenderResult(image=img, wall=time.perf_counter() - t1, cpu=time.process_time() - c1, build=build)
