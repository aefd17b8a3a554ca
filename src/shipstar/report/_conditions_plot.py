"""The sky and the mounts in the session report (issue 14 item 4): availability by reason,
the seeing estimate, the clock offsets and the flexure / drift monitor.

:func:`plot_availability` and :func:`plot_mount_monitor` make the PNGs;
:func:`conditions_section` adds the section to a :class:`~shipstar.report._html.Report`
from a session's summary (``session_summary``) and its epochs' monitor snapshots
(``Epoch.mounts``, pipeline._mounts) or a ``measure --monitor`` CSV's rows.
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.report._figure import color_for, new_figure, png_bytes

__all__ = ["plot_availability", "plot_mount_monitor", "monitor_series", "monitor_series_from_csv",
           "conditions_section", "AVAILABILITY_ALT", "MONITOR_ALT"]

#: The figures' alt texts (what a test or a screen reader finds).
AVAILABILITY_ALT = "availability by reason"
MONITOR_ALT = "clock offset and flexure monitor"
_AXES = ("bow", "up", "starboard")
_REASON_COLORS = {"solved": "#2ca02c", "clouded": "#7f7f7f", "moon in field": "#bcbd22", "sun in field": "#ff7f0e"}


def plot_availability(availability: dict) -> bytes:
    """PNG: per sensor, a horizontal bar of its frames split into solved and each reason
    they were lost (``summary["availability"]``)."""
    if not availability:
        raise ShipstarError("no sensors to plot")
    names = list(availability)
    reasons = []
    for b in availability.values():
        for r in b.get("unsolved_by_reason", {}):
            if r not in reasons:
                reasons.append(r)
    fig, axes = new_figure(10.5, 0.9 + 0.55 * len(names))
    ax = axes[0, 0]
    left = np.zeros(len(names))
    cycle = ("#d62728", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#1f77b4")
    for k, r in enumerate(["solved"] + reasons):
        n = np.array([availability[s]["n_solved"] if r == "solved" else availability[s]["unsolved_by_reason"].get(r, 0)
                      for s in names], float)
        tot = np.array([max(1, availability[s]["n_frames"]) for s in names], float)
        frac = 100.0 * n / tot
        ax.barh(names, frac, left=left, color=_REASON_COLORS.get(r, cycle[k % len(cycle)]),
                label=f"{r} ({int(n.sum())})")
        left += frac
    ax.set_xlim(0, 100)
    ax.set_xlabel("share of the sensor's frames (%)")
    ax.invert_yaxis()
    ax.legend(fontsize=7, ncol=min(4, 1 + len(reasons)), loc="lower left", bbox_to_anchor=(0, 1.0), frameon=False)
    return png_bytes(fig, dpi=100)


def monitor_series(result) -> dict:
    """``{sensor: (t_s (M,), rot_arcsec (M, 3), sigma_arcsec (M, 3), offset_ms (M,), offset_sigma_ms (M,))}``
    from a :class:`~shipstar.pipeline.SessionResult`'s epochs (their ``mounts`` snapshots)."""
    a, b = result.start_utc_jd
    acc: dict = {}
    for e in result.epochs:
        m = getattr(e, "mounts", None)
        if m is None:
            continue
        t = ((e.utc_jd1 - a) + (e.utc_jd2 - b)) * 86400.0
        for name, rot, sig in m.monitor:
            off = (m.time_offsets_s or {}).get(name, {})
            o, s = off.get("offset_s"), off.get("sigma_s")
            acc.setdefault(name, []).append((t, *rot, *sig, math.nan if o is None else o * 1e3,
                                             math.nan if s is None else s * 1e3))
    out = {}
    for name, rows in acc.items():
        x = np.array(rows, float).reshape(-1, 9)
        out[name] = (x[:, 0], x[:, 1:4], x[:, 4:7], x[:, 7], x[:, 8])
    return out


def monitor_series_from_csv(path, start_utc_jd=None) -> dict:
    """The same from a ``measure --monitor`` CSV (no clock column there: offsets NaN)."""
    import csv

    from shipstar.sky.time import utc_jd_from_iso

    acc: dict = {}
    with open(path, newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            j1, j2 = utc_jd_from_iso(r["time_utc"])
            if start_utc_jd is None:
                start_utc_jd = (j1, j2)
            t = ((j1 - start_utc_jd[0]) + (j2 - start_utc_jd[1])) * 86400.0
            vals = [float(r[f"rot_{a}_arcsec"]) for a in _AXES] + [float(r[f"sigma_{a}_arcsec"]) for a in _AXES]
            acc.setdefault(r["sensor"], []).append((t, *vals, math.nan, math.nan))
    return {n: (x[:, 0], x[:, 1:4], x[:, 4:7], x[:, 7], x[:, 8])
            for n, x in ((n, np.array(rows, float).reshape(-1, 9)) for n, rows in acc.items())}


def plot_mount_monitor(series: dict, *, reference: str = "", truth: dict | None = None) -> bytes:
    """PNG: per non-reference sensor, its mount's rotation relative to the reference mount
    about bow / up / starboard (arcsec, the smoothed monitor with its 1-sigma band) and,
    below, its estimated clock offset (ms, with 1 sigma) against time.

    ``truth``: optional ``{sensor: (t_s, rot_arcsec (M, 3))}`` drawn dashed (simulations)."""
    if not series:
        raise ShipstarError("no monitor series to plot")
    fig, axes = new_figure(10.5, 6.4, 2, 1)
    ax, axc = axes[0, 0], axes[1, 0]
    styles = ("-", "--", ":")
    for j, (name, (t, rot, sig, off, off_sig)) in enumerate(series.items()):
        for k, axis in enumerate(_AXES):
            c = ("#1f77b4", "#2ca02c", "#d62728")[k]
            ax.plot(t, rot[:, k], lw=1.0, color=c, ls=styles[j % 3], label=f"{name} {axis}")
            ok = np.isfinite(rot[:, k]) & np.isfinite(sig[:, k])
            if ok.any():
                ax.fill_between(t[ok], (rot[:, k] - sig[:, k])[ok], (rot[:, k] + sig[:, k])[ok], color=c, alpha=0.15,
                                lw=0)
            if truth and name in truth:
                tt, tr = truth[name]
                ax.plot(tt, np.asarray(tr)[:, k], lw=0.8, color=c, ls=(0, (2, 2)), alpha=0.7,
                        label=f"{name} {axis} (true)")
        if np.isfinite(off).any():
            axc.plot(t, off, lw=1.0, color=color_for(name, j), label=f"{name} clock offset")
            ok = np.isfinite(off) & np.isfinite(off_sig)
            axc.fill_between(t[ok], (off - off_sig)[ok], (off + off_sig)[ok], color=color_for(name, j), alpha=0.2, lw=0)
    ref = f" relative to {reference}'s mount" if reference else ""
    ax.set_ylabel(f"mount rotation{ref} (\u2033)")
    ax.axhline(0.0, color="k", lw=0.5)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=3, loc="upper right", framealpha=0.85)
    axc.set_ylabel("clock offset (ms)\ntrue minus header time")
    axc.axhline(0.0, color="k", lw=0.5)
    axc.grid(alpha=0.3)
    if axc.get_legend_handles_labels()[0]:
        axc.legend(fontsize=7, loc="upper right", framealpha=0.85)
    else:
        axc.text(0.5, 0.5, "no clock estimate in this series", transform=axc.transAxes, ha="center", va="center")
    axc.set_xlabel("time since the start of the session (s)")
    ax.sharex(axc)
    ax.tick_params(labelbottom=False)
    return png_bytes(fig, dpi=100)


def _f(x, fmt: str) -> str:
    return "-" if x is None or not math.isfinite(float(x)) else format(float(x), fmt)


def conditions_section(rep, summary: dict, series: dict | None) -> None:
    """Add "Sky and mounts" to the report: availability by reason (figure; the counts and the
    seeing estimate are in the report's frames table), the clock offsets, the flexure and
    the monitor plot."""
    avail = summary.get("availability") or {}
    if not avail:
        return
    rep.section("Sky and mounts")
    rep.figure(plot_availability(avail), "Availability: each sensor's frames, solved or lost, by reason "
               "(clouded and the Moon / the Sun in the field are the sky's; the others the solver's).",
               AVAILABILITY_ALT)
    offs, flex = summary.get("time_offsets_s") or {}, summary.get("flexure") or {}
    if offs or flex:
        rows = []
        for s in sorted(set(offs) | set(flex)):
            o, f = offs.get(s) or {}, flex.get(s) or {}
            amp, amp_sig = f.get("wave_amplitude_arcsec") or {}, f.get("wave_amplitude_sigma_arcsec") or {}
            st, st_sig = f.get("static_arcsec") or {}, f.get("static_sigma_arcsec") or {}
            ms = [None if o.get(k) is None else o[k] * 1e3 for k in ("offset_s", "sigma_s")]
            rows.append([f"{s} vs {summary.get('reference_sensor', '')}",
                         f"{_f(ms[0], '.3f')} \u00b1 {_f(ms[1], '.3f')}",
                         "yes" if o.get("applied") else "no",
                         " / ".join(f"{_f(st.get(a), '.1f')}\u00b1{_f(st_sig.get(a), '.1f')}" for a in _AXES),
                         " / ".join(f"{_f(amp.get(a), '.1f')}\u00b1{_f(amp_sig.get(a), '.1f')}" for a in _AXES),
                         "yes" if f.get("applied") else "no", "yes" if f.get("installation_drift") else "no"])
        rep.table(["sensor vs reference", "clock offset (ms)", "applied",
                   "static rotation bow / up / starboard (\u2033)", "wave amplitude bow / up / starboard (\u2033)",
                   "flexure applied", "installation drift"], rows)
    if series:
        rep.figure(plot_mount_monitor(series, reference=summary.get("reference_sensor", "")),
                   "Clock offset and flexure monitor: each sensor's mount rotation relative to the reference "
                   "mount beyond the installation files (smoothed, causal, 1-sigma band; measure --monitor) "
                   "and its estimated clock offset.", MONITOR_ALT)
