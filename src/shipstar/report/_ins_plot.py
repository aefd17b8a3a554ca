"""The inertial navigator (INS) in a report (issue 15 item 6): its estimated error with the
sigma band, and the corrected attitude against the truth through a star outage.

:func:`plot_ins_errors` and :func:`plot_ins_outage` make the PNGs; :func:`ins_statistics`
the numbers; :func:`ins_section` adds the section (tables and figures) to a
:class:`~shipstar.report._html.Report`, :func:`ins_report` writes it as a page of its own
(``shipstar measure --ins ... --ins-report HTML``).  Everything takes a
:class:`shipstar.pipeline._ins.InsSolution` (or its arrays); the truth, when known
(simulated sessions), is the true ship attitude at the solution's record times
(:func:`true_attitude_at`, from a ``--truth`` table).
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.report._figure import png_bytes

__all__ = ["plot_ins_errors", "plot_ins_outage", "outage_intervals", "true_attitude_at", "ins_statistics",
           "ins_section", "ins_page", "ins_report", "figure_pngs", "INS_ERRORS_ALT", "INS_OUTAGE_ALT"]

#: The figures' alt texts (what a test or a screen reader finds).
INS_ERRORS_ALT = "INS error estimate"
INS_OUTAGE_ALT = "corrected attitude through an outage"
_NAMES = ("heading", "pitch", "roll")
_COLORS = ("#1f77b4", "#2ca02c", "#d62728")
_OUTAGE = "#ececec"                 # shaded INS-bridged stretches
_MAX_POINTS = 6000


def _figure(width_in: float, height_in: float, height_ratios):
    """``(figure, axes (n,))`` on an Agg canvas, one column, shared time axis."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(height_ratios), 1, sharex=True, squeeze=False,
                        gridspec_kw={"height_ratios": list(height_ratios)})[:, 0]
    return fig, axes


def outage_intervals(t_s, bridged) -> list:
    """The INS-bridged stretches ``[(t0_s, t1_s), ...]``: runs of bridged records, each
    widened by half a record interval on both sides."""
    t = np.asarray(t_s, float).reshape(-1)
    b = np.asarray(bridged, bool).reshape(-1)
    if len(t) != len(b):
        raise ShipstarError(f"bridged has {len(b)} entries, t_s {len(t)}")
    if not b.any():
        return []
    half = 0.5 * float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    d = np.diff(np.concatenate([[0], b.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1
    return [(float(t[i]) - half, float(t[j]) + half) for i, j in zip(starts, ends)]


def _longest_outage(t_s, bridged):
    """The longest bridged stretch away from the log's ends (else the longest), or None."""
    spans = outage_intervals(t_s, bridged)
    if not spans:
        return None
    t = np.asarray(t_s, float)
    inner = [s for s in spans if s[0] > t[0] and s[1] < t[-1]]
    return max(inner or spans, key=lambda s: s[1] - s[0])


def _stride(n: int, max_points: int = _MAX_POINTS) -> int:
    return max(1, -(-n // max_points))


def _shade(ax, spans, label: str | None) -> None:
    for k, (a, b) in enumerate(spans):
        ax.axvspan(a, b, color=_OUTAGE, lw=0, zorder=0, label=label if k == 0 else None)


def _bins(t, width_s: float):
    """Index of each record's time bin, and the number of bins."""
    k = np.floor((t - t[0]) / width_s).astype(np.int64)
    return k, int(k[-1]) + 1 if len(k) else 0


def _bin_mean(k, n, x):
    """Per bin mean of ``x`` (M,) or (M, c) (NaN-aware); empty bins NaN."""
    x = np.asarray(x, float)
    x2 = x.reshape(len(x), -1)
    out = np.empty((n, x2.shape[1]))
    for c in range(x2.shape[1]):
        ok = np.isfinite(x2[:, c])
        s = np.bincount(k[ok], x2[ok, c], minlength=n)
        m = np.bincount(k[ok], minlength=n).astype(float)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[:, c] = s / m
    return out.reshape((n,) + x.shape[1:]), np.bincount(k, minlength=n)


def _legend(fig, entries) -> None:
    """One legend above the panels, in neutral colours (each angle's colour is its own):
    ``entries`` of ``(kind, label)``, kind ``"outage"``, ``"band1"``, ``"band3"``, ``"line"``,
    ``"dashed"``, ``"thin"``, ``"dots"``."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    grey = "#555555"
    proxies = {"outage": Patch(color=_OUTAGE), "band1": Patch(color=grey, alpha=0.35, lw=0),
               "band3": Patch(color=grey, alpha=0.15, lw=0), "line": Line2D([], [], color=grey, lw=1.4),
               "dashed": Line2D([], [], color="k", lw=0.9, ls=(0, (3, 2))), "thin": Line2D([], [], color="k", lw=0.8),
               "dots": Line2D([], [], color="#222", marker=".", ls="", ms=4),
               "line3": Line2D([], [], color=grey, lw=1.0, alpha=0.6),
               "dashed_c": Line2D([], [], color=grey, lw=1.2, ls=(0, (3, 2)))}
    fig.legend([proxies[k] for k, _ in entries], [label for _, label in entries], loc="outside upper center",
               ncol=len(entries), fontsize=8, frameon=False)


def plot_ins_errors(t_s, error_arcsec, error_sigma_arcsec, bridged, *, true_error_arcsec=None,
                    true_error_noise_arcsec=0.0, title: str = "") -> bytes:
    """PNG: per angle (heading, pitch, roll), the estimated INS error (reading minus truth,
    arcsec) against time with its 1-sigma and 3-sigma bands and, beneath it, the estimate
    minus the true error (or, without a truth, the bands alone: the estimate's
    uncertainty); the INS-bridged stretches shaded.

    Parameters
    ----------
    t_s : (N,)
        Record times (frame clock), s since the session start.
    error_arcsec, error_sigma_arcsec : (N, 3)
        The estimated INS error and its sigma (``InsSolution.error_arcsec``,
        ``error_sigma_arcsec``).
    bridged : (N,) bool
    true_error_arcsec : (N, 3), optional
        The true INS error at the records (simulated sessions; NaN where unknown); drawn
        as 1 s means (of bins at least half covered).
    true_error_noise_arcsec : float or (N, 3)
        The white noise in ``true_error_arcsec`` (a reading minus the truth carries the
        INS's noise; the simulator's slow error none): it widens the bands of the
        difference by its 1 s mean's sigma.
    title : str
    """
    t = np.asarray(t_s, float).reshape(-1)
    e = np.asarray(error_arcsec, float).reshape(-1, 3)
    s = np.asarray(error_sigma_arcsec, float).reshape(-1, 3)
    if len(t) < 2 or len(e) != len(t) or len(s) != len(t):
        raise ShipstarError(f"INS error plot: need N >= 2 records with (N, 3) errors and sigmas, got t_s {len(t)}, "
                            f"errors {len(e)}, sigmas {len(s)}")
    spans = outage_intervals(t, bridged)
    fig, axes = _figure(10.5, 9.8, (2.2, 1.2) * 3)
    st = _stride(len(t))
    have_truth = true_error_arcsec is not None
    if have_truth:
        k_bin, n_bin = _bins(t, max(1.0, (t[-1] - t[0]) / 3000.0))
        tr = np.asarray(true_error_arcsec, float).reshape(-1, 3)
        noise2 = np.broadcast_to(np.square(np.asarray(true_error_noise_arcsec, float)), tr.shape)
        n_ok = _bin_mean(k_bin, n_bin, np.isfinite(tr[:, 0]).astype(float))[0] * np.bincount(k_bin, minlength=n_bin)
        keep = n_ok >= 0.5 * max(1.0, float(np.max(n_ok)))
        tb = _bin_mean(k_bin, n_bin, t)[0][keep]
        tr_b = _bin_mean(k_bin, n_bin, tr)[0][keep]
        d_b = _bin_mean(k_bin, n_bin, e - tr)[0][keep]
        var_b = _bin_mean(k_bin, n_bin, s * s)[0][keep] + _bin_mean(k_bin, n_bin, noise2)[0][keep] / n_ok[keep, None]
        sd_b = np.sqrt(var_b)
    for k in range(3):
        ax, axd = axes[2 * k], axes[2 * k + 1]
        c = _COLORS[k]
        _shade(ax, spans, None)
        _shade(axd, spans, None)
        tt, ee, ss = t[::st], e[::st, k], s[::st, k]
        ax.fill_between(tt, ee - 3 * ss, ee + 3 * ss, color=c, alpha=0.15, lw=0)
        ax.fill_between(tt, ee - ss, ee + ss, color=c, alpha=0.35, lw=0)
        ax.plot(tt, ee, color=c, lw=1.2)
        if have_truth:
            ax.plot(tb, tr_b[:, k], color="k", lw=0.9, ls=(0, (3, 2)))
        ax.set_ylabel(f"{_NAMES[k]} error (\u2033)")
        ax.grid(alpha=0.3)
        axd.axhline(0.0, color="k", lw=0.5)
        if have_truth:
            sd = sd_b[:, k]
            axd.fill_between(tb, -3 * sd, 3 * sd, color=c, alpha=0.15, lw=0)
            axd.fill_between(tb, -sd, sd, color=c, alpha=0.35, lw=0)
            axd.plot(tb, d_b[:, k], color="k", lw=0.8)
            vals = np.concatenate([np.abs(d_b[:, k]), 3 * sd])
            lim = 1.15 * float(np.nanmax(vals)) if np.isfinite(vals).any() else 1.0
            axd.set_ylabel(f"{_NAMES[k]}: est. \u2212 true (\u2033)", fontsize=8)
        else:
            axd.fill_between(tt, -3 * ss, 3 * ss, color=c, alpha=0.15, lw=0)
            axd.fill_between(tt, -ss, ss, color=c, alpha=0.35, lw=0)
            lim = 1.15 * 3 * float(np.nanmax(ss)) if np.isfinite(ss).any() else 1.0
            axd.set_ylabel(f"{_NAMES[k]}: \u00b1\u03c3 (\u2033)", fontsize=8)
        axd.set_ylim(-lim, lim)
        axd.grid(alpha=0.3)
    entries = [("line", "estimated INS error"), ("band1", "\u00b11\u03c3"), ("band3", "\u00b13\u03c3")]
    if have_truth:
        entries += [("dashed", "true INS error (1 s means)"), ("thin", "estimated minus true (1 s means)")]
    if spans:
        entries.append(("outage", "INS-bridged (no stars)"))
    _legend(fig, entries)
    axes[-1].set_xlabel("time since the start of the session (s)")
    axes[-1].set_xlim(t[0], t[-1])
    if title:
        fig.suptitle(title, fontsize=10)
    return png_bytes(fig, dpi=100)


def _window(t, span, margin_s=None):
    a, b = span
    m = max(10.0, 0.3 * (b - a)) if margin_s is None else float(margin_s)
    return max(a - m, float(t[0])), min(b + m, float(t[-1]))


def plot_ins_outage(t_s, sigma_arcsec, bridged, *, error_arcsec=None, error_sigma_arcsec=None, span_s=None,
                    title: str = "") -> bytes:
    """PNG: per angle, the corrected attitude minus the truth (arcsec; each INS record a
    dot, and their 1 s means) through an outage with its 1-sigma and 3-sigma bands, or,
    without a truth, its sigma (1 and 3 sigma, and the INS error estimate's sigma,
    ``error_sigma_arcsec``, the part beyond the INS's white noise); the outage shaded.

    Parameters
    ----------
    t_s : (N,)
    sigma_arcsec : (N, 3)
        The corrected attitude's sigma (``InsSolution.sigma_arcsec``).
    bridged : (N,) bool
    error_arcsec : (N, 3), optional
        Corrected attitude minus the truth (heading wrapped), arcsec; NaN where unknown.
    error_sigma_arcsec : (N, 3), optional
        Without a truth: the INS error estimate's sigma, drawn dashed.
    span_s : (t0, t1), optional
        The time span to show (default: the longest INS-bridged stretch with a margin of
        30 % of its length, at least 10 s, on each side; the whole log if nothing was
        bridged).
    title : str
    """
    t = np.asarray(t_s, float).reshape(-1)
    s = np.asarray(sigma_arcsec, float).reshape(-1, 3)
    b = np.asarray(bridged, bool).reshape(-1)
    if len(t) < 2 or len(s) != len(t) or len(b) != len(t):
        raise ShipstarError(f"INS outage plot: need N >= 2 records with (N, 3) sigmas and N flags, got t_s {len(t)}, "
                            f"sigmas {len(s)}, flags {len(b)}")
    if span_s is None:
        out = _longest_outage(t, b)
        span_s = (float(t[0]), float(t[-1])) if out is None else _window(t, out)
    sel = (t >= span_s[0]) & (t <= span_s[1])
    if sel.sum() < 2:
        raise ShipstarError(f"INS outage plot: fewer than 2 records in {span_s[0]:.1f}-{span_s[1]:.1f} s")
    idx = np.flatnonzero(sel)[::_stride(int(sel.sum()), 8000)]
    tt, ss = t[idx], s[idx]
    spans = [(max(x, span_s[0]), min(y, span_s[1])) for x, y in outage_intervals(t, b)
             if y > span_s[0] and x < span_s[1]]
    fig, axes = _figure(10.5, 7.4, (1, 1, 1))
    ee = None if error_arcsec is None else np.asarray(error_arcsec, float).reshape(-1, 3)
    if ee is not None:
        ts = t[sel]
        k_bin, n_bin = _bins(ts, 1.0)
        tb, cnt = _bin_mean(k_bin, n_bin, ts)
        mb = _bin_mean(k_bin, n_bin, ee[sel])[0][cnt > 0]
        tb = tb[cnt > 0]
    es = None if error_sigma_arcsec is None else np.asarray(error_sigma_arcsec, float).reshape(-1, 3)[idx]
    for k, ax in enumerate(axes):
        c = _COLORS[k]
        _shade(ax, spans, None)
        if ee is not None:
            ax.fill_between(tt, -3 * ss[:, k], 3 * ss[:, k], color=c, alpha=0.15, lw=0)
            ax.fill_between(tt, -ss[:, k], ss[:, k], color=c, alpha=0.35, lw=0)
            ax.axhline(0.0, color="k", lw=0.5)
            x = ee[idx, k]
            ax.plot(tt, x, ".", ms=1.6, color="#222", alpha=0.4, mew=0)
            ax.plot(tb, mb[:, k], color="k", lw=1.0)
            text = []
            for name, m in (("outside", ~b & sel), ("inside", b & sel)):
                ok = m & np.isfinite(ee[:, k])
                if ok.any():
                    z = ee[ok, k] / s[ok, k]
                    text.append(f"{name} the outage: RMS {math.sqrt(float(np.mean(ee[ok, k] ** 2))):.2f}\u2033, "
                                f"RMS(err/\u03c3) {math.sqrt(float(np.mean(z * z))):.2f}, "
                                f"max |err/\u03c3| {float(np.max(np.abs(z))):.1f}")
            if text:
                ax.text(0.995, 0.03, "\n".join(text), transform=ax.transAxes, ha="right", va="bottom", fontsize=7,
                        bbox=dict(fc="white", ec="none", alpha=0.85))
            finite = np.isfinite(x)
            lim = 1.1 * max(float(np.max(np.abs(x[finite]))) if finite.any() else 0.0, 3.0 * float(np.max(ss[:, k])))
            ax.set_ylim(-lim, lim)
            ax.set_ylabel(f"{_NAMES[k]}: corrected \u2212 true (\u2033)", fontsize=9)
        else:
            ax.plot(tt, 3 * ss[:, k], color=c, lw=1.0, alpha=0.6)
            ax.plot(tt, ss[:, k], color=c, lw=1.4)
            if es is not None:
                ax.plot(tt, es[:, k], color=c, lw=1.2, ls=(0, (3, 2)))
            ax.set_ylim(0.0, 1.1 * 3.0 * float(np.max(ss[:, k])))
            ax.set_ylabel(f"{_NAMES[k]}: \u03c3 (\u2033)", fontsize=9)
        ax.grid(alpha=0.3)
    if ee is not None:
        entries = [("dots", "corrected minus true (each INS record)"), ("thin", "their 1 s means"),
                   ("band1", "\u00b11\u03c3"), ("band3", "\u00b13\u03c3")]
    else:
        entries = [("line", "1\u03c3 of the corrected attitude"), ("line3", "3\u03c3"),
                   ("dashed_c", "1\u03c3 of the INS error estimate (white noise excluded)")]
    if spans:
        entries.append(("outage", "INS-bridged (no stars)"))
    _legend(fig, entries)
    axes[-1].set_xlabel("time since the start of the session (s)")
    axes[-1].set_xlim(*span_s)
    if title:
        fig.suptitle(title, fontsize=10)
    return png_bytes(fig, dpi=100)


def true_attitude_at(solution, truth, max_gap_s: float = 0.5) -> np.ndarray:
    """The true ship attitude (heading, pitch, roll, rad) at the solution's record times,
    shape (N, 3), from a :class:`shipstar.pipeline.TruthTable` (cubic through 4 rows;
    NaN outside it or where its rows are more than ``max_gap_s`` apart)."""
    from shipstar.pipeline._ins import interpolate_cubic

    tt = np.asarray(truth.t_s, float)
    if len(tt) < 4:
        raise ShipstarError(f"{truth.name}: fewer than 4 rows, cannot interpolate the truth")
    j1, j2 = solution.start_utc_jd
    shift_s = ((j1 - truth.jd1_0) + (j2 - truth.jd2_0)) * 86400.0
    y = np.stack([np.unwrap(truth.heading_rad), truth.pitch_rad, truth.roll_rad], -1)
    out, _, span, _ = interpolate_cubic(tt, y, np.asarray(solution.t_s, float) + shift_s)
    out[:, 0] = np.mod(out[:, 0], 2.0 * math.pi)
    out[~(span <= max_gap_s)] = np.nan
    return out


def _wrap_arcsec(d_rad):
    from shipstar.frames import wrap_pi
    from shipstar.units import RAD2ASEC

    d = np.array(d_rad, float)
    d[:, 0] = wrap_pi(d[:, 0])
    return d * RAD2ASEC


def ins_statistics(solution, true_attitude_rad=None) -> dict:
    """The corrected attitude inside (``ins-bridged``) and outside (``stars+ins``) the
    outages: ``{"outside": {...}, "inside": {...}}`` each with ``n_records``,
    ``median_sigma_arcsec`` (3,) and, with ``true_attitude_rad`` (N, 3), ``rms_arcsec``,
    ``rms_error_over_sigma``, ``max_abs_error_over_sigma`` (3,) and ``n_beyond_3_sigma``
    (records and angles, of ``n_compared``)."""
    b = np.asarray(solution.bridged, bool)
    err = None if true_attitude_rad is None else _wrap_arcsec(np.asarray(solution.angles_rad) - true_attitude_rad)
    out = {}
    for name, m in (("outside", ~b), ("inside", b)):
        block = {"n_records": int(m.sum()),
                 "median_sigma_arcsec": [float(np.median(solution.sigma_arcsec[m, k])) if m.any() else math.nan
                                         for k in range(3)]}
        if err is not None:
            ok = m & np.all(np.isfinite(err), 1)
            e, s = err[ok], solution.sigma_arcsec[ok]
            z = e / s if ok.any() else np.full((0, 3), math.nan)
            nan3 = [math.nan] * 3
            block.update(n_compared=int(ok.sum()),
                         rms_arcsec=np.sqrt(np.mean(e * e, 0)).tolist() if ok.any() else nan3,
                         rms_error_over_sigma=np.sqrt(np.mean(z * z, 0)).tolist() if ok.any() else nan3,
                         max_abs_error_over_sigma=np.max(np.abs(z), 0).tolist() if ok.any() else nan3,
                         n_beyond_3_sigma=int(np.sum(np.abs(z) > 3.0)))
        out[name] = block
    return out


def figure_pngs(rep) -> list:
    """The PNGs embedded in a report (bytes), in order."""
    import base64
    import re

    return [base64.b64decode(d) for d in re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', rep.to_html())]


def _f(x, nd: int = 2) -> str:
    if x is None or not math.isfinite(float(x)):
        return "-"
    x = float(x)
    return f"{0.0 if abs(x) < 0.5 * 10 ** -nd else x:.{nd}f}"


_TERMS = (  # label, estimate key, sigma key, scale to the shown unit, decimals
    ("heading bias at the first record (\u2033)", "heading_bias_arcsec", "heading_bias_sigma_arcsec", 1.0, 2),
    ("heading drift (\u2033/h)", "heading_drift_arcsec_per_h", "heading_drift_sigma_arcsec_per_h", 1.0, 2),
    ("pitch bias (\u2033)", "pitch_bias_arcsec", "pitch_bias_sigma_arcsec", 1.0, 2),
    ("roll bias (\u2033)", "roll_bias_arcsec", "roll_bias_sigma_arcsec", 1.0, 2),
    ("clock offset, INS minus frames (ms)", "time_offset_s", "time_offset_sigma_s", 1e3, 4),
)


def _true_term(true_terms, key: str, misalignment_estimated: bool):
    """The true value of a summary term: the misalignment about the bow is in the roll
    bias; without the misalignment estimated, the up / starboard parts are in the heading /
    pitch biases (no single true value then, unless they are 0)."""
    tv = true_terms.get(key)
    if tv is None:
        return None
    m = [float(x) for x in (true_terms.get("misalignment_arcsec") or (0.0, 0.0, 0.0))]
    if key == "roll_bias_arcsec":
        return float(tv) + m[0]
    if key in ("heading_bias_arcsec", "pitch_bias_arcsec") and not misalignment_estimated and any(m[1:]):
        return None
    return float(tv)


def _term_rows(solution, true_terms):
    rows = []
    for label, key, skey, scale, nd in _TERMS:
        est, sig = solution.summary[key] * scale, solution.summary[skey] * scale
        row = [label, _f(est, nd), _f(sig, nd)]
        if true_terms is not None:
            tv = _true_term(true_terms, key, bool(solution.details.get("misalignment_estimated")))
            tv = None if tv is None else tv * scale
            row += [_f(tv, nd), "-" if tv is None or not sig > 0 else _f((est - tv) / sig)]
        rows.append(row)
    d = solution.details
    if d.get("misalignment_estimated"):
        for axis in ("up", "starboard"):
            row = [f"INS-to-deck misalignment about {axis} (\u2033)", _f(d["misalignment_arcsec"][axis]),
                   _f(d["misalignment_sigma_arcsec"][axis])]
            if true_terms is not None:
                m = true_terms.get("misalignment_arcsec")
                tv = None if m is None else float(m[1 if axis == "up" else 2])
                sig = d["misalignment_sigma_arcsec"][axis]
                row += [_f(tv), "-" if tv is None or not sig > 0 else _f((d["misalignment_arcsec"][axis] - tv) / sig)]
            rows.append(row)
    return rows


def ins_section(rep, solution, *, true_attitude_rad=None, true_error_arcsec=None, true_error_noise_arcsec=None,
                true_terms=None) -> dict:
    """Add "Inertial navigator (INS)" to a report: the estimated error terms with their
    sigmas (and the true values), the corrected attitude's statistics inside and outside
    the outages, and the two figures.

    Parameters
    ----------
    rep : Report
    solution : shipstar.pipeline._ins.InsSolution
    true_attitude_rad : (N, 3), optional
        The true ship attitude at ``solution.t_s`` (:func:`true_attitude_at`).
    true_error_arcsec : (N, 3), optional
        The true INS error at the records; default, with ``true_attitude_rad``: the
        reading minus the truth (``error_arcsec`` + corrected minus true), which carries
        the INS's white noise (``true_error_noise_arcsec``, default the solution's).
    true_error_noise_arcsec : float or (N, 3), optional
    true_terms : dict, optional
        The true error terms under the summary's keys (``ins_truth.json``): a "true"
        column and (estimate - true) / sigma.

    Returns
    -------
    dict
        :func:`ins_statistics`.
    """
    sol = solution
    if true_attitude_rad is not None and not np.isfinite(true_attitude_rad).any():
        true_attitude_rad = None                          # the truth does not cover the log
    rep.section("Inertial navigator (INS)")
    d = sol.details
    n_bridged = d.get("n_records_bridged", int(sol.bridged.sum()))
    rep.paragraph(f"{d.get('n_records', len(sol.t_s))} INS records ({n_bridged} "
                  f"bridged: no star epoch within 1 s), {d.get('n_star_epochs_used', '-')} of "
                  f"{d.get('n_star_epochs', '-')} star epochs used ({d.get('n_star_epochs_gated', 0)} left out by the "
                  f"chi-square gate), {d.get('n_records_skipped', 0)} records skipped on reading. "
                  "INS error = INS reading minus truth; the biases are those at the first record; the INS-to-deck "
                  "misalignment about the bow is part of the roll bias"
                  + ("." if d.get("misalignment_estimated") else ", about up and starboard of the heading and pitch "
                     "biases (not estimated)."))
    head = ["INS error term", "estimated", "1\u03c3"] + (["true", "(est \u2212 true)/\u03c3"] if true_terms else [])
    rep.table(head, _term_rows(sol, true_terms or None))
    err = None
    if true_attitude_rad is not None:
        err = _wrap_arcsec(np.asarray(sol.angles_rad) - true_attitude_rad)
        if true_error_arcsec is None:
            true_error_arcsec = sol.error_arcsec + err
            if true_error_noise_arcsec is None:
                true_error_noise_arcsec = np.sqrt(np.maximum(sol.sigma_arcsec ** 2 - sol.error_sigma_arcsec ** 2, 0.0))
    stats = ins_statistics(sol, true_attitude_rad)
    head = ["corrected attitude", "records"] + [f"median \u03c3 {n} (\u2033)" for n in _NAMES]
    if err is not None:
        head += [f"RMS {n} error (\u2033)" for n in _NAMES] + [f"RMS(error/\u03c3) {n}" for n in _NAMES] + \
            ["beyond 3\u03c3"]
    rows = []
    for key, label in (("outside", "stars+ins (outside outages)"), ("inside", "ins-bridged (inside outages)")):
        b = stats[key]
        row = [label, b["n_records"]] + [_f(v) for v in b["median_sigma_arcsec"]]
        if err is not None:
            row += [_f(v) for v in b["rms_arcsec"]] + [_f(v) for v in b["rms_error_over_sigma"]] + \
                [f"{b['n_beyond_3_sigma']} of {3 * b['n_compared']}"]
        rows.append(row)
    rep.table(head, rows)
    truth_note = ("; the true error (dashed, 1 s means) and, beneath each angle, the estimate minus the truth"
                  if true_error_arcsec is not None else "; beneath each angle the bands alone (no truth given)")
    noise = 0.0 if true_error_noise_arcsec is None else true_error_noise_arcsec
    rep.figure(plot_ins_errors(sol.t_s, sol.error_arcsec, sol.error_sigma_arcsec, sol.bridged,
                               true_error_arcsec=true_error_arcsec, true_error_noise_arcsec=noise),
               "The INS's estimated error (reading minus truth) with its 1\u03c3 and 3\u03c3 bands (Kalman filter "
               "and Rauch-Tung-Striebel smoother over the star epochs), the INS-bridged stretches shaded"
               + truth_note + ".", INS_ERRORS_ALT)
    out = _longest_outage(sol.t_s, sol.bridged)
    what = ("the corrected attitude minus the truth at each INS record" if err is not None
            else "the corrected attitude's 1\u03c3 and 3\u03c3 and the INS error estimate's 1\u03c3 (no truth given)")
    where = ("through the longest outage" if out is not None else "over the whole log (no outage)")
    rep.figure(plot_ins_outage(sol.t_s, sol.sigma_arcsec, sol.bridged, error_arcsec=err,
                               error_sigma_arcsec=sol.error_sigma_arcsec),
               f"The corrected attitude {where}: {what}; its sigma grows while the INS carries on alone and shrinks "
               "when the stars return.", INS_OUTAGE_ALT)
    return stats


def ins_page(solution, *, true_attitude_rad=None, true_terms=None, title: str = "shipstar INS report"):
    """A :class:`~shipstar.report._html.Report` holding the INS section (:func:`ins_section`)."""
    from shipstar.report._html import Report

    d = solution.details
    sub = (f"INS log {d.get('source', '') or '-'} ({d.get('convention', '') or 'shipstar signs'}); "
           f"{d.get('n_records', len(solution.t_s))} records over {solution.t_s[-1] - solution.t_s[0]:.0f} s")
    rep = Report(title, subtitle=sub)
    ins_section(rep, solution, true_attitude_rad=true_attitude_rad, true_terms=true_terms)
    return rep


def ins_report(solution, path, *, truth=None, true_terms=None, title: str = "shipstar INS report"):
    """Write the INS section (:func:`ins_section`) as a self-contained HTML page.

    ``truth``: a :class:`shipstar.pipeline.TruthTable` (simulated sessions); ``true_terms``
    as :func:`ins_section`'s.  Returns the path.
    """
    return ins_page(solution, true_attitude_rad=None if truth is None else true_attitude_at(solution, truth),
                    true_terms=true_terms, title=title).write(path)
