"""Write solver results for people: VTU deformation files (ParaView) and PNG pictures (matplotlib)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from headsim.errors import DivergenceError


def write_vtu(path: Path, rest_positions: np.ndarray, positions: np.ndarray, tets: np.ndarray,
              point_data: dict[str, np.ndarray] | None = None) -> Path:
    """Tet mesh at ``positions`` with point data "displacement" (m) and any extra arrays (SI units).

    Refuses non-finite values (a diverged result is never written out).
    """
    import meshio

    x = np.asarray(positions, dtype=np.float64)
    if not np.isfinite(x).all():
        raise DivergenceError(f"refusing to write non-finite positions to {path}")
    data = {"displacement": x - np.asarray(rest_positions)}
    for k, v in (point_data or {}).items():
        data[k] = np.asarray(v, dtype=np.float64)
    meshio.Mesh(x, [("tetra", np.asarray(tets, dtype=np.int64))], point_data=data).write(str(path), binary=True)
    return Path(path)


def plot_hertz(result, path: Path) -> Path:
    """Two panels: deformed cross-section (y = 0 plane) coloured by displacement; contact pressure vs Hertz."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = result.model
    x0 = m.rest_positions
    u = result.positions - x0
    a = result.contact_radius_hertz
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    sel = np.abs(x0[:, 1]) < 1e-12
    sc = ax1.scatter(result.positions[sel, 0] * 1e3, result.positions[sel, 2] * 1e3, c=np.linalg.norm(u[sel], axis=1) * 1e6,
                     s=6, cmap="viridis")
    th = np.linspace(-np.pi / 2, -np.pi / 2 + 0.6, 50)
    cz = result.radius - result.indentation
    ax1.plot(result.radius * np.cos(th) * 1e3, (cz + result.radius * np.sin(th)) * 1e3, "r-", label="sphere")
    ax1.set_xlim(0, 6 * a * 1e3)
    ax1.set_ylim(-6 * a * 1e3, 1.5 * a * 1e3)
    ax1.set_aspect("equal")
    ax1.set_xlabel("x (mm)")
    ax1.set_ylabel("z (mm)")
    ax1.set_title("deformed section y = 0")
    fig.colorbar(sc, ax=ax1, label="|displacement| (µm)")
    ax1.legend(loc="lower right")
    r = np.hypot(x0[:, 0], x0[:, 1])
    top = np.abs(x0[:, 2]) < 1e-12
    order = np.argsort(r[top])
    ax2.plot(r[top][order] * 1e3, result.contact_pressure[top][order], "o", ms=3, label="FEM (penalty)")
    rr = np.linspace(0, a, 100)
    p0 = 3 * result.force / (2 * np.pi * a**2)
    ax2.plot(rr * 1e3, p0 * np.sqrt(1 - (rr / a) ** 2), "k-", label="Hertz")
    ax2.set_xlim(0, 2 * a * 1e3)
    ax2.set_xlabel("r (mm)")
    ax2.set_ylabel("contact pressure (Pa)")
    ax2.set_title(f"F = {result.force * 1e3:.3g} mN: a = {result.contact_radius * 1e3:.3g} mm "
                  f"(Hertz {a * 1e3:.3f} mm), δ = {result.indentation * 1e6:.3g} µm "
                  f"(Hertz {result.indentation_hertz * 1e6:.1f} µm)", fontsize=8)
    ax2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)


def plot_scene_frames(result, path: Path, frames: list[int]) -> Path:
    """Side views (x-y) of the two bodies at the given steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(frames), figsize=(4 * len(frames), 4), squeeze=False)
    for ax, k in zip(axes[0], frames):
        x = result.states[k].positions
        for b, colour in ((0, "tab:red"), (1, "tab:blue")):
            tri = result.surfaces[b]
            seg = x[tri][:, [0, 1, 2, 0], :]
            for s in seg[:: max(1, len(seg) // 400)]:
                ax.plot(s[:, 0], s[:, 1], "-", color=colour, lw=0.4)
        ax.set_title(f"step {k} (t = {result.states[k].time:.2g} s)")
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    fig.suptitle(result.name + f"  shape change sphere {result.shape_change[-1][0]:.3f}, "
                 f"cuboid {result.shape_change[-1][1]:.3f}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
