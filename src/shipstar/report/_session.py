"""The HTML report of one processed session (a :class:`shipstar.pipeline.SessionResult`)."""

from __future__ import annotations

import math

import numpy as np

from shipstar.units import RAD2ASEC

__all__ = ["session_report"]

_OUT = ("heading", "pitch", "roll")


def _fmt(x, nd: int = 2) -> str:
    return f"{x:.{nd}f}" if x is not None and math.isfinite(float(x)) else "-"


def _methods(result) -> list:
    from shipstar.pipeline import method_series

    out = [(f"single {s}", method_series(result, "single", s)) for s in result.sensors]
    if len(result.sensors) > 1:
        out += [("seed rule", method_series(result, "seed-rule")), ("joint", method_series(result, "joint"))]
    return out


def _t_s(result, rows) -> np.ndarray:
    a, b = result.start_utc_jd
    return np.array([((j1 - a) + (j2 - b)) * 86400.0 for j1, j2, _ in rows])


def _minus_joint(result, methods) -> list:
    """Each method's (heading, pitch, roll) minus the joint solution at the nearest epoch, arcsec."""
    from shipstar.frames import wrap_pi

    joint = dict(methods)["joint"]
    tj = _t_s(result, joint)
    ref = np.array([[a.heading_rad, a.pitch_rad, a.roll_rad] if a.solved else [np.nan] * 3 for _, _, a in joint])
    out = []
    for name, rows in methods:
        if name == "joint":
            continue
        t = _t_s(result, rows)
        k = np.clip(np.searchsorted(tj, t), 0, len(tj) - 1)
        val = np.array([[a.heading_rad, a.pitch_rad, a.roll_rad] if a.solved else [np.nan] * 3 for _, _, a in rows])
        close = np.abs(tj[k] - t) < 0.06
        d = np.where(close[:, None], wrap_pi(val - ref[k]) * RAD2ASEC, np.nan)
        out.append((name, t, d))
    return out


def session_report(result, path, *, truth=None, ins=None, title: str = "shipstar session report"):
    """Write a self-contained HTML report of a processed session.

    Parameters
    ----------
    result : shipstar.pipeline.SessionResult
    path : str or Path
        The HTML file to write.
    truth : shipstar.pipeline.TruthTable, optional
        True ship attitude (simulated sessions): errors are plotted and tabulated.
    ins : shipstar.pipeline._ins.InsSolution, optional
        The INS calibrated against this session's stars (``estimate_ins``): a section
        "Inertial navigator (INS)" (report._ins_plot.ins_section; against ``truth`` when given).
    title : str

    Returns
    -------
    Path
    """
    from shipstar.pipeline import attitude_errors_arcsec, session_summary
    from shipstar.report._html import Report
    from shipstar.report._series_plot import plot_attitude_errors

    summary = session_summary(result, truth)
    rep = Report(title, subtitle=f"sensors {', '.join(result.sensors)}; refraction {result.options.refraction_model} "
                                 f"({result.options.refraction}); {summary['n_epochs']} epochs")
    rep.section("Frames")
    seeing = summary.get("seeing", {})
    rep.table(["sensor", "frames", "solved", "failed", "median stars used", "median residual RMS (\u2033)",
               "clouded", "Moon / Sun in field", "seeing: noise floor (\u2033)"],
              [[s, b["n_frames"], b["n_solved"], b["n_failed"], _fmt(b["median_stars_used"], 0),
                _fmt(b["median_residual_rms_arcsec"]), b.get("n_clouded", 0),
                b.get("n_moon_in_field", 0) + b.get("n_sun_in_field", 0),
                _fmt(seeing.get(s, {}).get("noise_floor_arcsec"))] for s, b in summary["sensors"].items()])
    fails = [f"{s} {f['frame']} ({f['time_utc']}): {f['reason']}" for s, b in summary["sensors"].items()
             for f in b["failures"]]
    if fails:
        rep.heading("Frames that did not solve")
        rep.bullets(fails)
    rep.section("Ship attitude")
    head = ["method", "solved"] + [f"median \u03c3 {o} (\u2033)" for o in _OUT]
    if truth is not None:
        head += [f"RMS {o} (\u2033)" for o in _OUT]
    rows = []
    for name, block in summary["methods"].items():
        row = [name, f"{block['n_solved']}/{block['n']}"] + [_fmt(v) for v in block["median_sigma_arcsec"]]
        if truth is not None:
            row += [_fmt(v) for v in block["rms_arcsec"]]
        rows.append(row)
    rep.table(head, rows)
    methods = _methods(result)
    if truth is not None:
        series = [(n, _t_s(result, r), attitude_errors_arcsec(r, truth)) for n, r in methods]
        rep.figure(plot_attitude_errors(series), "Ship heading, pitch and roll error against the truth.",
                   "attitude errors")
    elif len(result.sensors) > 1:
        rep.figure(plot_attitude_errors(_minus_joint(result, methods)),
                   "Each method minus the joint solution (no truth given).", "methods minus joint")
    from shipstar.report._conditions_plot import conditions_section, monitor_series

    conditions_section(rep, summary, monitor_series(result) if len(result.sensors) > 1 else None)
    if ins is not None:
        from shipstar.report._ins_plot import ins_section, true_attitude_at

        ins_section(rep, ins, true_attitude_rad=None if truth is None else true_attitude_at(ins, truth))
    return rep.write(path)
