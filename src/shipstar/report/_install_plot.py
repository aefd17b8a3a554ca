"""Histograms of the per-frame installation angles of a dock calibration."""

from __future__ import annotations

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.report._figure import color_for, new_figure, png_bytes

__all__ = ["plot_installation_histograms"]

_NAMES = ("azimuth A", "elevation E", "roll \u03b3")


def plot_installation_histograms(errors_arcsec: dict, *, seed_std_arcsec: dict | None = None) -> bytes:
    """PNG: one row per sensor, one panel per angle (A, E, gamma).

    Parameters
    ----------
    errors_arcsec : dict of name -> (M, 3)
        Each frame's installation angles minus the truth, arcsec.
    seed_std_arcsec : dict of name -> (3,), optional
        The seed's published per-frame std, quoted in each panel.
    """
    if not errors_arcsec:
        raise ShipstarError("no sensors to plot")
    seed_std_arcsec = seed_std_arcsec or {}
    n = len(errors_arcsec)
    fig, axes = new_figure(10.5, 2.7 * n, n, 3)
    for i, (name, err) in enumerate(errors_arcsec.items()):
        e = np.asarray(err, float).reshape(-1, 3)
        seed = seed_std_arcsec.get(name)
        for k in range(3):
            ax = axes[i, k]
            col = e[:, k][np.isfinite(e[:, k])]
            if len(col):
                ax.hist(col, bins=max(8, min(40, len(col) // 4)), color=color_for(name, i), alpha=0.8)
                mean, std = float(np.mean(col)), float(np.std(col, ddof=1)) if len(col) > 1 else float("nan")
                ax.axvline(mean, color="k", lw=1.2, label=f"mean {mean:+.2f}\u2033")
            else:
                mean, std = float("nan"), float("nan")
            ax.axvline(0.0, color="#d62728", lw=1.2, ls="--", label="truth")
            text = f"std {std:.2f}\u2033" + (f"\nseed 000: {seed[k]:.2f}\u2033" if seed is not None else "")
            ax.text(0.02, 0.96, text, transform=ax.transAxes, va="top", fontsize=8,
                    bbox=dict(fc="white", ec="none", alpha=0.8))
            ax.set_title(f"{name}: {_NAMES[k]}", fontsize=9)
            ax.set_xlabel("frame minus truth (arcsec)", fontsize=8)
            ax.legend(fontsize=7, loc="upper right")
            ax.grid(alpha=0.3)
        axes[i, 0].set_ylabel("frames")
    return png_bytes(fig, dpi=100)
