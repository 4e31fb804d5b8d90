"""Write rod trajectories: NPZ, VTK polylines (meshio), plots and an image sequence (matplotlib)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["write_trajectory"]


def _polylines(positions: np.ndarray):
    """(F, N+1, 3) -> meshio points and line cells."""
    F, nn, _ = positions.shape
    pts = positions.reshape(-1, 3)
    seg = np.stack([np.arange(nn - 1), np.arange(1, nn)], axis=1)
    cells = np.concatenate([seg + f * nn for f in range(F)])
    return pts, cells


def write_trajectory(scene, traj, folder: Path, images: bool = True) -> list[Path]:
    """Write ``trajectory.npz``, ``vtk/frame_XXXX.vtu`` (guide and interpolated fibres as polylines),
    ``tip_position.png``, ``kinetic_energy.png`` and ``images/frame_XXXX.png``. Returns the files."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import meshio

    folder = Path(folder)
    files = []
    npz = folder / "trajectory.npz"
    np.savez_compressed(npz, times=traj.times, positions=traj.positions, curvature=traj.curvature,
                        kinetic=traj.kinetic, iterations=traj.iterations, step_times=traj.step_times,
                        step_tip=traj.step_tip, step_kinetic=traj.step_kinetic,
                        **({"interpolated": traj.interpolated} if traj.interpolated is not None else {}))
    files.append(npz)
    (folder / "vtk").mkdir()
    for k in range(len(traj.times)):
        pos = traj.positions[k]
        if traj.interpolated is not None:
            pos = np.concatenate([pos[:1], traj.interpolated[k]], axis=0)
        pts, cells = _polylines(pos)
        p = folder / "vtk" / f"frame_{k:04d}.vtu"
        meshio.write(p, meshio.Mesh(pts, [("line", cells)]), binary=True)
        files.append(p)
    ts = traj.step_times if traj.step_times is not None else traj.times
    tip = traj.step_tip[:, 0] if traj.step_tip is not None else traj.positions[:, 0, -1, :]
    kin = traj.step_kinetic if traj.step_kinetic is not None else traj.kinetic
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for c, name in enumerate("xyz"):
        ax.plot(ts, tip[:, c] * 100, label=name)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("tip position [cm]")
    ax.set_title(scene.description, fontsize=8)
    ax.legend()
    fig.tight_layout()
    p = folder / "tip_position.png"
    fig.savefig(p, dpi=120)
    plt.close(fig)
    files.append(p)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.semilogy(ts, np.maximum(kin.sum(axis=1), 1e-300))
    ax.set_xlabel("t [s]")
    ax.set_ylabel("kinetic energy [J]")
    fig.tight_layout()
    p = folder / "kinetic_energy.png"
    fig.savefig(p, dpi=120)
    plt.close(fig)
    files.append(p)
    if images:
        (folder / "images").mkdir()
        allp = traj.positions.reshape(-1, 3)
        lo, hi = allp.min(0), allp.max(0)
        span = float((hi - lo).max()) * 0.55 + 1e-6
        mid = 0.5 * (lo + hi)
        for k in range(len(traj.times)):
            fig = plt.figure(figsize=(4, 4))
            ax = fig.add_subplot(projection="3d")
            if traj.interpolated is not None:
                for q in traj.interpolated[k][:: max(1, len(traj.interpolated[k]) // 60)]:
                    ax.plot(q[:, 0], q[:, 1], q[:, 2], color="0.6", lw=0.4)
            for f in range(traj.positions.shape[1]):
                q = traj.positions[k, f]
                ax.plot(q[:, 0], q[:, 1], q[:, 2], color="tab:brown", lw=1.2)
            ax.set_xlim(mid[0] - span, mid[0] + span)
            ax.set_ylim(mid[1] - span, mid[1] + span)
            ax.set_zlim(mid[2] - span, mid[2] + span)
            ax.set_title(f"{scene.name}  t = {traj.times[k]:.3f} s", fontsize=8)
            p = folder / "images" / f"frame_{k:04d}.png"
            fig.savefig(p, dpi=80)
            plt.close(fig)
            files.append(p)
    return files
