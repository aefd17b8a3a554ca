"""Session plots (PNG): ship attitude (or its error against a truth) vs time, per-sensor residuals."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from shipstar.units import RAD2DEG

__all__ = ["plot_session", "plot_attitude_csv"]

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


def _data_from_result(result, truth):
    """``(methods, sensors)``: ``[(label, t_s (M,), y (M, 3))]`` (degrees, or errors in
    arcsec with a truth table) and ``[(sensor, t_s (M,), rms_arcsec (M,), n_used (M,))]``."""
    from shipstar.pipeline._stats import attitude_errors_arcsec

    methods = []
    for label, series in _series(result):
        t = np.array([_t(result, j1, j2) for j1, j2, _ in series])
        if truth is not None:
            y = attitude_errors_arcsec(series, truth)
        else:
            y = np.array([[a.heading_rad, a.pitch_rad, a.roll_rad] if a.solved else [np.nan] * 3
                          for _, _, a in series]).reshape(-1, 3) * RAD2DEG
        methods.append((label, t, y))
    sensors = [(frames[0].sensor if frames else "", np.array([result.t_s(fr) for fr in frames]),
                np.array([fr.rms_arcsec for fr in frames]), np.array([fr.n_used for fr in frames]))
               for frames in result.frames]
    return methods, sensors


def _data_from_csv(path, truth, max_points: int):
    """As :func:`_data_from_result`, from an attitude CSV, every k-th row of each series
    kept so that at most ``max_points`` remain (a night's CSV is read line by line)."""
    import csv

    from shipstar.frames import wrap_pi
    from shipstar.sky.time import utc_jd_from_iso
    from shipstar.units import DEG2RAD, RAD2ASEC

    with open(path, newline="", encoding="utf-8") as fh:
        n_rows = sum(1 for line in fh if not line.startswith("#"))
    stride = max(1, -(-n_rows // max_points))
    acc: dict = {}
    with open(path, newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(line for line in fh if not line.startswith("#")):
            key = ("single " + row["sensor"]) if row["method"] == "single" else row["method"].replace("-", " ")
            rows, seen = acc.setdefault(key, ([], [0]))
            seen[0] += 1
            if (seen[0] - 1) % stride:
                continue
            ok = row["solved"] == "1"
            angles = [float(row[c]) if ok else np.nan for c in ("heading_deg", "pitch_deg", "roll_deg")]
            if truth is not None and ok:
                true = np.array(truth.angles_rad(*utc_jd_from_iso(row["time_utc"])))
                angles = list(wrap_pi(np.array(angles) * DEG2RAD - true) * RAD2ASEC)
            rms = float(row["rms_arcsec"]) if row["rms_arcsec"] else np.nan
            rows.append((float(row["t_s"]), angles, rms, int(row["n_stars"]) if ok else 0))
    methods, sensors = [], []
    for key, (rows, _) in acc.items():
        t = np.array([r[0] for r in rows])
        methods.append((key, t, np.array([r[1] for r in rows]).reshape(-1, 3)))
        if key.startswith("single "):
            sensors.append((key[7:], t, np.array([r[2] for r in rows]), np.array([r[3] for r in rows])))
    return methods, sensors


def _attitude_plot(methods, path: Path, with_truth: bool) -> None:
    fig, axes = _figure(3)
    for label, t, y in methods:
        for k, ax in enumerate(axes):
            ax.plot(t, y[:, k], ".-", ms=3, lw=0.8, label=label)
    unit = "error (arcsec)" if with_truth else "(deg)"
    for k, ax in enumerate(axes):
        ax.set_ylabel(f"{_NAMES[k]} {unit}")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize="small", ncol=4)
    axes[-1].set_xlabel("time since session start (s)")
    _save(fig, path)


def _residual_plot(sensors, path: Path) -> None:
    fig, axes = _figure(2)
    for name, t, rms, n_used in sensors:
        axes[0].plot(t, rms, ".-", ms=3, lw=0.8, label=name)
        axes[1].plot(t, n_used, ".-", ms=3, lw=0.8)
    axes[0].set_ylabel("star residual RMS (arcsec)")
    axes[1].set_ylabel("stars used")
    axes[0].legend(fontsize="small")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time since session start (s)")
    _save(fig, path)


def _plot(methods, sensors, out_dir, with_truth: bool) -> list:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "attitude.png", out / "residuals.png"]
    _attitude_plot(methods, paths[0], with_truth)
    _residual_plot(sensors, paths[1])
    return paths


def plot_session(result, out_dir, truth=None) -> list:
    """Write ``attitude.png`` (heading/pitch/roll, or their errors when ``truth`` is given,
    for every method) and ``residuals.png`` (per-sensor star residual RMS and stars used)
    into ``out_dir``; returns the paths."""
    return _plot(*_data_from_result(result, truth), out_dir, truth is not None)


def plot_attitude_csv(csv_path, out_dir, truth=None, *, max_points: int = 20000) -> list:
    """The plots of :func:`plot_session` from an attitude CSV (``shipstar measure``'s
    output), at most ``max_points`` points per series (a night is thinned evenly)."""
    return _plot(*_data_from_csv(csv_path, truth, max_points), out_dir, truth is not None)
