"""PNG plots of the sweeps and the layout map (matplotlib, Agg backend, imported lazily)."""

from __future__ import annotations

import numpy as np

from ._jacobian import OUTPUTS
from ._layout import LayoutResult
from ._sweep import SweepResult

__all__ = ["plot_sweep", "plot_layout", "Y_CAP_FACTOR"]

#: The y axis stops at this multiple of the largest error source: near gimbal lock the
#: error grows as 1/cos(pitch), and the rest of the figure must stay readable.
Y_CAP_FACTOR = 10.0

_SYMBOL = {"As": "A_s", "Es": "E_s", "gs": r"\gamma_s", "A0": "A_0", "E0": "E_0", "g0": r"\gamma_0"}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _locked_spans(x, locked):
    """Contiguous x-intervals where ``locked`` (1-D bool) is true."""
    spans, start = [], None
    for k, flag in enumerate(locked):
        if flag and start is None:
            start = k
        if start is not None and (not flag or k == len(locked) - 1):
            end = k if flag else k - 1
            lo = x[max(start - 1, 0)] if start > 0 else x[0]
            hi = x[min(end + 1, len(x) - 1)]
            spans.append((lo, hi))
            start = None
    return spans


def plot_sweep(result: SweepResult, path, *, title: str = "", kind: str = "rss") -> None:
    """Heading, pitch and roll error against the swept angle, one curve per A0.

    Points flagged at gimbal lock are not drawn (grey band); values above
    ``Y_CAP_FACTOR`` times the largest error source run off the top of the axes.
    """
    plt = _pyplot()
    b = result.budget
    y_all = np.abs(getattr(b, f"{kind}_arcsec"))
    cap = Y_CAP_FACTOR * float(np.max(b.errors_arcsec))
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), sharex=True)
    locked_any = np.any(b.gimbal_locked, axis=0)
    for i, (ax, out) in enumerate(zip(axes, OUTPUTS)):
        for k, label in enumerate(result.curve_labels):
            ax.plot(result.values_deg, y_all[k, :, i], lw=1.4, label=label)
        for n, (lo, hi) in enumerate(_locked_spans(result.values_deg, locked_any)):
            ax.axvspan(lo, hi, color="0.8", label="gimbal lock (flagged)" if n == 0 else None)
        top = np.nanmax(y_all[..., i]) if np.any(np.isfinite(y_all[..., i])) else 1.0
        if top > cap:
            ax.set_ylim(0, cap * 1.05)
            ax.annotate("off scale: grows as 1/cos(pitch)\ntoward gimbal lock", xy=(0.02, 0.97),
                        xycoords="axes fraction", va="top", fontsize=7, color="0.3")
        else:
            ax.set_ylim(0, max(top * 1.08, 1e-3))
        ax.set_title(f"{out} error")
        ax.set_xlabel(f"${_SYMBOL[result.param]}$ (deg)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(("1-sigma (RSS)" if kind == "rss" else "|signed sum|") + ", arcsec")
    axes[-1].legend(fontsize=7, loc="best")
    fig.suptitle(f"{title}  [{result.convention}; errors (As, Es, gs, A0, E0, g0) = "
                 f"{', '.join(f'{e:g}' for e in b.errors_arcsec)}'']", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_layout(single: LayoutResult, path, *, dual: LayoutResult | None = None) -> None:
    """Map of one sensor's objective over installation azimuth/elevation, optima marked."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 3.8))
    mesh = ax.pcolormesh(single.grid_az_deg, single.grid_el_deg, single.grid_objective_arcsec,
                         shading="nearest", cmap="viridis")
    fig.colorbar(mesh, ax=ax, label=f"one sensor, {single.objective} 1-sigma ('')")
    ax.plot(single.az_deg, single.el_deg, "w*", ms=14, mec="k",
            label=f"best single: {single.objective_arcsec:.2f}''")
    if dual is not None:
        ax.plot(dual.az_deg, dual.el_deg, "rD", ms=8, mec="k",
                label=f"best pair (fused): {dual.objective_arcsec:.2f}''")
    ax.set_xlabel("installation azimuth from the bow toward starboard (deg)")
    ax.set_ylabel("installation elevation (deg)")
    att = ", ".join(f"({p:g}, {r:g})" for p, r in single.ship_attitudes_deg)
    ax.set_title(f"layout; ship (pitch, roll) deg: {att}", fontsize=9)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
