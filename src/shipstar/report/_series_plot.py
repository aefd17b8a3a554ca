"""Ship heading, pitch and roll error against time, one line per method."""

from __future__ import annotations

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.report._figure import color_for, new_figure, png_bytes

__all__ = ["plot_attitude_errors"]

_NAMES = ("heading", "pitch", "roll")


def _limit(series) -> float:
    vals = np.concatenate([np.abs(np.asarray(e, float)[np.isfinite(e)]) for _, _, e in series] or [np.zeros(1)])
    return 1.15 * float(np.max(vals)) if vals.size and np.any(vals > 0) else 1.0


def plot_attitude_errors(series, *, shade_s=None, shade_label: str = "", title: str = "",
                         linear_limit_arcsec: float | None = None) -> bytes:
    """PNG: three panels (heading, pitch, roll error, arcsec) against time.

    Parameters
    ----------
    series : sequence of (label, t_s (M,), errors_arcsec (M, 3))
        NaN rows (unsolved) leave gaps.
    shade_s : (t0, t1), optional
        A time span to shade (e.g. the image-level frames).
    shade_label : str
    title : str
    linear_limit_arcsec : float, optional
        Errors beyond +- this are drawn on a logarithmic scale (symlog), so that a
        session with errors of very different sizes (e.g. smeared and sharp frames) stays
        readable; default: linear throughout.
    """
    if not series:
        raise ShipstarError("no series to plot")
    fig, axes = new_figure(10.5, 7.2, 3, 1)
    lim = _limit(series)
    lin = linear_limit_arcsec
    if lin is not None and not (np.isfinite(lin) and lin > 0):
        raise ShipstarError(f"linear_limit_arcsec must be > 0, got {lin!r}")
    for k, ax in enumerate(axes[:, 0]):
        if shade_s is not None:
            ax.axvspan(*shade_s, color="#e8eef7", zorder=0, label=shade_label if k == 0 else None)
        for j, (label, t, e) in enumerate(series):
            e = np.asarray(e, float).reshape(-1, 3)
            rms = np.sqrt(np.nanmean(e[:, k] ** 2)) if np.isfinite(e[:, k]).any() else np.nan
            ax.plot(t, e[:, k], lw=0.9, color=color_for(label, j), label=f"{label} (RMS {rms:.2f}\u2033)")
        if lin is not None and lim > 2.0 * lin:
            ax.set_yscale("symlog", linthresh=lin, linscale=3.0)
        ax.set_ylim(-lim, lim)
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_ylabel(f"{_NAMES[k]} error (\u2033)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=3, loc="upper right", framealpha=0.85)
    log_note = "; beyond the dotted lines the scale is logarithmic" if axes[0, 0].get_yscale() == "symlog" else ""
    axes[-1, 0].set_xlabel(f"time since the start of the session (s){log_note}")
    for ax in axes[:, 0]:
        if ax.get_yscale() == "symlog":
            ax.axhline(lin, color="0.5", lw=0.6, ls=":")
            ax.axhline(-lin, color="0.5", lw=0.6, ls=":")
    for ax in axes[:-1, 0]:
        ax.sharex(axes[-1, 0])
        ax.tick_params(labelbottom=False)
    if title:
        fig.suptitle(title, fontsize=10)
    return png_bytes(fig, dpi=100)
