"""Pictures of the scattering model: the seed's in-plane goniophotometer curves (Sobottka 2008 §6.2)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from headsim.hair.render.scattering import MarschnerParams, goniometric_curve

__all__ = ["goniometric_figure"]


def goniometric_figure(path: Path, presets=("blond", "brown", "black"), theta_i_deg: float = -30.0) -> dict:
    """Plot S_R, S_TRT and the total in the incidence plane (Δφ = 0) over θ_r for each colour preset;
    write a PNG and return {preset: (R peak θ_r, TRT peak θ_r)} in degrees."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(presets), figsize=(4.2 * len(presets), 3.4), squeeze=False)
    peaks = {}
    for ax, name in zip(axes[0], presets):
        th, lobes = goniometric_curve(MarschnerParams.preset(name), theta_i_deg)
        total = lobes.sum(axis=1)
        for ch, col in enumerate(("tab:red", "tab:green", "tab:blue")):
            ax.plot(th, total[:, ch], color=col, lw=1.2, label=f"total {'RGB'[ch]}")
        ax.plot(th, lobes[:, 0, 0], "k--", lw=1, label="R")
        ax.plot(th, lobes[:, 2].mean(axis=1), "k:", lw=1, label="TRT (RGB mean)")
        r_peak = float(th[np.argmax(lobes[:, 0, 0])])
        trt_peak = float(th[np.argmax(lobes[:, 2].mean(axis=1))])
        peaks[name] = (r_peak, trt_peak)
        ax.axvline(-theta_i_deg, color="0.6", lw=0.8)
        ax.set_title(f"{name}: R peak {r_peak:.1f}°, TRT peak {trt_peak:.1f}°", fontsize=9)
        ax.set_xlabel("θ_r (deg)")
        ax.set_xlim(-10, 80)
    axes[0][0].set_ylabel(f"S (1/sr), θ_i = {theta_i_deg:g}°, Δφ = 0")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return peaks
