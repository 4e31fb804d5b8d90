"""Hair rendering benchmark: headsim's Numba path tracer (Marschner far field) vs Mitsuba 3 (scalar_rgb,
``linearcurve`` + built-in ``hair`` BSDF of Chiang 2016) on the same synthetic hairstyle, equal samples
per pixel and path depth. Prints wall and CPU time side by side (the machine may be shared), the image
difference and writes a side-by-side PNG.

    python benchmarks/bench_render.py            # 90 k fibres × 25 segments, 1024², 16 spp, depth 8
    python benchmarks/bench_render.py --quick    # 9 k fibres × 25 segments, 256², 16 spp, depth 8
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from headsim.hair.render import PRESETS, MarschnerParams
from headsim.hair.render.bvh import CapsuleBVH
from headsim.hair.render.mitsuba_peer import mitsuba_available, render_mitsuba
from headsim.hair.render.renderer import Light, RenderOptions, camera_looking_at, render, save_png
from headsim.hair.render.synthetic import synthetic_hairstyle


def image_difference(a: np.ndarray, b: np.ndarray, block: int = 4) -> dict:
    """Relative L1 difference Σ|a−b|/Σ|b| per pixel and after block×block averaging (less MC noise),
    and the ratio of mean radiances per channel."""
    h, w = (a.shape[0] // block) * block, (a.shape[1] // block) * block
    def down(x):
        return x[:h, :w].reshape(h // block, block, w // block, block, 3).mean(axis=(1, 3))
    return {
        "rel_L1_pixel": float(np.abs(a - b).sum() / max(np.abs(b).sum(), 1e-300)),
        f"rel_L1_{block}x{block}": float(np.abs(down(a) - down(b)).sum() / max(np.abs(down(b)).sum(), 1e-300)),
        "mean_ratio_rgb": (a.mean(axis=(0, 1)) / np.maximum(b.mean(axis=(0, 1)), 1e-300)).round(3).tolist(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--preset", default="blond", choices=sorted(PRESETS))
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--depth", type=int, default=8, help="Mitsuba max_depth (headsim max_scatter = depth − 1)")
    ap.add_argument("--out", type=Path, default=Path("bench_render.png"))
    ap.add_argument("--no-mitsuba", action="store_true")
    args = ap.parse_args()
    n_fibres, size = (9_000, 256) if args.quick else (90_000, 1024)
    t0 = time.perf_counter()
    fibres = synthetic_hairstyle(n_fibres, 25, fibre_radius=40e-6 if not args.quick else 120e-6, seed=0)
    print(f"scene: {n_fibres} fibres × 25 segments ({len(fibres.nodes) - n_fibres} capsules), "
          f"{size}², {args.spp} spp, depth {args.depth}, preset {args.preset}; built in {time.perf_counter() - t0:.1f} s")
    params = MarschnerParams.preset(args.preset)
    cam = camera_looking_at(fibres, azimuth_deg=35.0, elevation_deg=10.0, margin=1.0)
    lights = [Light(vector=(1.0, 0.8, 0.6), rgb=(3.0, 3.0, 3.0))]
    opts = RenderOptions(width=size, height=size, spp=args.spp, max_scatter=args.depth - 1,
                         env=(0.08, 0.08, 0.08), background=(0.08, 0.08, 0.08))
    # compile once on a tiny image so the timing below is the render, not Numba's JIT
    bvh_t0 = time.perf_counter()
    bvh = CapsuleBVH.from_fibres(fibres)
    bvh_s = time.perf_counter() - bvh_t0
    render(bvh, params, cam, lights, RenderOptions(width=8, height=8, spp=1, max_scatter=2))
    ours = render(bvh, params, cam, lights, opts)
    rows = [("headsim (Numba, Marschner)", bvh_s, ours.wall, ours.cpu)]
    images = [ours.image]
    if not args.no_mitsuba and mitsuba_available():
        ref = render_mitsuba(fibres, params, cam, lights, opts, *PRESETS[args.preset])
        rows.append(("Mitsuba 3 scalar_rgb (hair BSDF)", ref.build, ref.wall, ref.cpu))
        images.append(ref.image)
    print(f"{'renderer':36s} {'load/BVH s':>10s} {'wall s':>8s} {'CPU s':>8s}")
    for name, b, w, c in rows:
        print(f"{name:36s} {b:10.2f} {w:8.2f} {c:8.2f}")
    if len(rows) == 2:
        print(f"wall ratio headsim / Mitsuba = {rows[0][2] / rows[1][2]:.2f}, "
              f"CPU ratio = {rows[0][3] / max(rows[1][3], 1e-9):.2f}")
        print("image difference (Marschner vs Chiang BSDF, same scene):", image_difference(images[0], images[1]))
    save_png(args.out, np.concatenate(images, axis=1), exposure=2.0)
    print(f"side-by-side picture (left: headsim, right: Mitsuba): {args.out}")


if __name__ == "__main__":
    main()
