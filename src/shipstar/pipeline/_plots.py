"""Session plots (PNG): ship attitude (or its error against a truth) vs time, per-sensor residuals."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from shipstar.units import RAD2DEG

__all__ = ["plot_session"]

_NAMES = ("heading", "pitch", "roll")


def _save(fig, path: Path) -> None:
    """Save to a temporary file beside ``path`` and rename (never a partial PNG)."""
    from shipstar._atomic import atomic_path

    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=100, format="png")


def _figure(n_rows: int):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9.0, 2.4 * n_rows), layout="constrained")
    FigureCanvasAgg(fig)
    return fig, fig.subplots(n_rows, 1, sharex=True, squeeze=False)[:, 0]


def _series(result):
    from shipstar.pipeline._stats import method_series

    out = [(f"single {s}", method_series(result, "single", s)) for s in result.sensors]
    if len(result.sensors) > 1:
        out += [("seed rule", method_series(result, "seed-rule")), ("joint", method_series(result, "joint"))]
    return out


def _t(result, j1, j2) -> float:
    a, b = result.start_utc_jd
    return ((j1 - a) + (j2 - b)) * 86400.0


def _attitude_plot(result, path: Path, truth) -> None:
    from shipstar.pipeline._stats import attitude_errors_arcsec

    fig, axes = _figure(3)
    for label, series in _series(result):
        t = np.array([_t(result, j1, j2) for j1, j2, _ in series])
        if truth is not None:
            y = attitude_errors_arcsec(series, truth)
        else:
            y = np.array([[a.heading_rad, a.pitch_rad, a.roll_rad] if a.solved else [np.nan] * 3
                          for _, _, a in series]).reshape(-1, 3) * RAD2DEG
        for k, ax in enumerate(axes):
            ax.plot(t, y[:, k], ".-", ms=3, lw=0.8, label=label)
    unit = "error (arcsec)" if truth is not None else "(deg)"
    for k, ax in enumerate(axes):
        ax.set_ylabel(f"{_NAMES[k]} {unit}")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize="small", ncol=4)
    axes[-1].set_xlabel("time since session start (s)")
    _save(fig, path)


def _residual_plot(result, path: Path) -> None:
    fig, axes = _figure(2)
    for frames in result.frames:
        t = np.array([result.t_s(fr) for fr in frames])
        axes[0].plot(t, [fr.rms_arcsec for fr in frames], ".-", ms=3, lw=0.8, label=frames[0].sensor if frames else "")
        axes[1].plot(t, [fr.n_used for fr in frames], ".-", ms=3, lw=0.8)
    axes[0].set_ylabel("star residual RMS (arcsec)")
    axes[1].set_ylabel("stars used")
    axes[0].legend(fontsize="small")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time since session start (s)")
    _save(fig, path)


def plot_session(result, out_dir, truth=None) -> list:
    """Write ``attitude.png`` (heading/pitch/roll, or their errors when ``truth`` is given,
    for every method) and ``residuals.png`` (per-sensor star residual RMS and stars used)
    into ``out_dir``; returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "attitude.png", out / "residuals.png"]
    _attitude_plot(result, paths[0], truth)
    _residual_plot(result, paths[1])
    return paths
