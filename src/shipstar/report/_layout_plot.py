"""Error-model sweep of an installed layout: predicted 1-sigma against a ship angle, measured beside it."""

from __future__ import annotations

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.report._figure import color_for, new_figure, png_bytes

__all__ = ["plot_layout_sweep"]

_NAMES = ("heading", "pitch", "roll")


def _tick_label(value, _pos) -> str:
    """Log-axis labels as plain numbers on 1, 2, 3, 5 x 10^k ('' elsewhere)."""
    if value <= 0:
        return ""
    mantissa = value / 10 ** np.floor(np.log10(value) + 1e-9)
    return f"{value:g}" if any(abs(mantissa - m) < 1e-6 for m in (1.0, 2.0, 3.0, 5.0)) else ""


def _plain_log_labels(ax) -> None:
    from matplotlib.ticker import FuncFormatter

    ax.yaxis.set_major_formatter(FuncFormatter(_tick_label))
    ax.yaxis.set_minor_formatter(FuncFormatter(_tick_label))


def plot_layout_sweep(x_deg, predicted, *, measured=(), xlabel: str = "ship roll (deg)", title: str = "") -> bytes:
    """PNG: three panels (heading, pitch, roll 1-sigma, arcsec) against ``x_deg``.

    Parameters
    ----------
    x_deg : (n,)
    predicted : sequence of (label, sigma_arcsec (n, 3))
        Lines (the error model).
    measured : sequence of (label, x_deg (m,), rms_arcsec (m, 3))
        Markers (e.g. RMS errors of a session binned by the same angle).
    """
    x = np.asarray(x_deg, float).reshape(-1)
    if not predicted:
        raise ShipstarError("nothing to plot")
    fig, axes = new_figure(11.0, 4.4, 1, 3)
    for k, ax in enumerate(axes[0]):
        for j, (label, sig) in enumerate(predicted):
            sig = np.asarray(sig, float).reshape(-1, 3)
            ls = "--" if label.startswith("single") else "-"
            ax.plot(x, sig[:, k], ls, color=color_for(label, j), lw=1.6, label=f"{label} (model)")
        for j, (label, xm, rms) in enumerate(measured):
            rms = np.asarray(rms, float).reshape(-1, 3)
            ax.plot(xm, rms[:, k], "o", color=color_for(label, j), ms=4.5, mec="k", mew=0.4,
                    label=f"{label} (measured RMS)")
        ax.set_yscale("log")
        _plain_log_labels(ax)
        ax.set_title(f"{_NAMES[k]}", fontsize=10)
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3, which="both")
    axes[0, 0].set_ylabel("1-sigma error (\u2033)")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=4, fontsize=7.5)
    if title:
        fig.suptitle(title, fontsize=10)
    return png_bytes(fig, dpi=100)
