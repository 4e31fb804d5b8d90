"""Error measures of approximate Coulomb forces against the direct sum (Sobottka §4.5, Fig. 4.10).

* mean angular error: mean over particles of the angle between F and F_ref (rad);
* max relative error: max_i |F_i - F_ref,i| / |F_ref,i|;
* rms relative error: ||F - F_ref||_2 / ||F_ref||_2 over all particles (the usual FMM norm).
"""

from __future__ import annotations

import time

import numpy as np

from headsim.hair.electrostatics.coulomb import direct_forces, fmm_forces
from headsim.hair.electrostatics.treecode import Treecode, TreecodeOptions

__all__ = ["force_errors", "accuracy_table", "format_table"]


def force_errors(forces, reference) -> dict:
    """dict(mean_angle_rad, max_relative, rms_relative) of forces (n, 3) against reference (n, 3)."""
    F = np.asarray(forces, float)
    R = np.asarray(reference, float)
    nr = np.linalg.norm(R, axis=1)
    ok = nr > 0
    # atan2(|a x b|, a . b) is accurate for tiny angles (arccos of the cosine is not)
    ang = np.arctan2(np.linalg.norm(np.cross(F[ok], R[ok]), axis=1), np.einsum("ij,ij->i", F[ok], R[ok]))
    rel = np.linalg.norm(F[ok] - R[ok], axis=1) / nr[ok]
    return {"mean_angle_rad": float(ang.mean()), "max_relative": float(rel.max()),
            "rms_relative": float(np.linalg.norm(F - R) / np.linalg.norm(R))}


def accuracy_table(points, charges, fmm_eps=(1e-2, 1e-3, 1e-6, 1e-9), thetas=(0.8, 0.5, 0.3), orders=(0, 2),
                   leaf_size: int = 32, reference=None, local=(False, True)) -> list[dict]:
    """Rows {method, setting, seconds, errors...} for fmm3dpy at every eps and the treecode at every
    (theta, order) with and without cell-to-leaf local expansions, all against the direct sum
    (computed here unless ``reference`` is given)."""
    x = np.asarray(points, float)
    q = np.asarray(charges, float)
    t0 = time.perf_counter()
    ref = direct_forces(x, q) if reference is None else np.asarray(reference, float)
    rows = [{"method": "direct", "setting": "exact", "seconds": time.perf_counter() - t0,
             **force_errors(ref, ref)}]
    for eps in fmm_eps:
        t0 = time.perf_counter()
        f = fmm_forces(x, q, eps)
        rows.append({"method": "fmm3dpy", "setting": f"eps={eps:g}", "seconds": time.perf_counter() - t0,
                     **force_errors(f, ref)})
    for loc in local:
        t0 = time.perf_counter()
        tree = Treecode(x, q, TreecodeOptions(leaf_size=leaf_size, local=loc))
        build = time.perf_counter() - t0
        for th in thetas:
            for od in orders:
                t0 = time.perf_counter()
                f = q[:, None] * tree.field(th, od)
                rows.append({"method": "treecode" + (" + local" if loc else ""), "setting": f"theta={th:g}, order={od}",
                             "seconds": time.perf_counter() - t0 + build, **force_errors(f, ref)})
    return rows


def format_table(rows) -> str:
    """Markdown table of :func:`accuracy_table` rows."""
    lines = ["| method | setting | mean angle (rad) | max rel. | rms rel. | s |", "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['setting']} | {r['mean_angle_rad']:.2e} | {r['max_relative']:.2e} | "
                     f"{r['rms_relative']:.2e} | {r['seconds']:.2f} |")
    return "\n".join(lines)
