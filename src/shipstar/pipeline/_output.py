"""The attitude CSV of a session (docs/file-formats.md): one row per frame and method.

Times are written to the microsecond (``time_utc`` ISO 8601 with 6 decimals, ``t_s``
with 6): at sea the deck turns by up to 4 deg/s, 14'' per millisecond.  Optional comment
lines (``# ...``, e.g. the Earth orientation quality and accuracy warnings) come before
the header row; shipstar's CSV reader skips them, astropy (``Table.read(path,
format="ascii.csv", comment="#")``) and pandas (``comment="#"``) do when told.
"""

from __future__ import annotations

import csv
import io
import math

from shipstar.units import RAD2ASEC, RAD2DEG

__all__ = ["ATTITUDE_COLUMNS", "attitude_csv_text", "write_attitude_csv"]

ATTITUDE_COLUMNS = ("time_utc", "t_s", "method", "sensor", "frame", "solved", "heading_deg", "pitch_deg", "roll_deg",
                    "sigma_heading_arcsec", "sigma_pitch_arcsec", "sigma_roll_arcsec", "n_stars", "rms_arcsec",
                    "reason", "time_source")


def _fmt(x, digits: int) -> str:
    x = float(x)
    return f"{x:.{digits}f}" if math.isfinite(x) else ""


def _iso(jd1: float, jd2: float) -> str:
    from shipstar.sky.time import iso_from_utc_jd

    return iso_from_utc_jd(jd1, jd2, 6)


def _row(time_utc, t_s, method, sensor, frame, att, rms_arcsec=math.nan, time_source="") -> list:
    sig = att.sigma_rad * RAD2ASEC
    return [time_utc, _fmt(t_s, 6), method, sensor, frame, "1" if att.solved else "0",
            _fmt(att.heading_rad * RAD2DEG, 9), _fmt(att.pitch_rad * RAD2DEG, 9), _fmt(att.roll_rad * RAD2DEG, 9),
            _fmt(sig[0], 3), _fmt(sig[1], 3), _fmt(sig[2], 3), str(int(att.n_stars)), _fmt(rms_arcsec, 3),
            att.reason, time_source]


def _sources(result, frames) -> dict:
    """``{(sensor, label): time_source}`` from the input frames (empty without them)."""
    if frames is None:
        return {}
    out = {}
    for name, frs in zip(result.sensors, frames):
        for f in frs:
            out[(name, f.label)] = getattr(f, "time_source", "")
    return out


def _rows(result, frames=None) -> list:
    source = _sources(result, frames)
    rows = []
    for frs in result.frames:
        for fr in frs:
            t = result.t_s(fr)
            rows.append((t, 0, _row(_iso(fr.utc_jd1, fr.utc_jd2), t, "single", fr.sensor, fr.label, fr.ship,
                                    fr.rms_arcsec, source.get((fr.sensor, fr.label), ""))))
    if len(result.sensors) > 1:
        both = "+".join(result.sensors)
        ref = result.frames_of(result.reference_sensor)
        for e in result.epochs:
            label = ref[e.index].label
            src = source.get((result.reference_sensor, label), "")
            rows.append((e.t_s, 1, _row(_iso(e.utc_jd1, e.utc_jd2), e.t_s, "seed-rule", both, label, e.seed_rule,
                                        time_source=src)))
            rows.append((e.t_s, 2, _row(_iso(e.utc_jd1, e.utc_jd2), e.t_s, "joint", both, label, e.joint,
                                        time_source=src)))
    rows.sort(key=lambda r: (r[0], r[1]))
    return [r[2] for r in rows]


def _comment_lines(comments) -> list:
    if isinstance(comments, str):
        comments = [comments]
    return ["# " + " ".join(str(c).split()) + "\n" for c in comments]


def attitude_csv_text(result, frames=None, comments=()) -> str:
    """The CSV text: comment lines, header, then rows sorted by time (single rows first at
    equal times).

    Parameters
    ----------
    result : SessionResult
    frames : sequence (per sensor, in ``result.sensors`` order) of sequences of Frame, optional
        The frames the session was processed from; their ``time_source`` (how each
        frame's mid-exposure time was found in its file, e.g. ``DATE-OBS+EXPTIME/2``)
        fills the ``time_source`` column (fused rows: the reference sensor's frame).
        Without them the column is empty.
    comments : iterable of str
        Lines written first, each as ``# text`` (white space, newlines included, collapsed).
    """
    buf = io.StringIO()
    buf.writelines(_comment_lines(comments))
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(ATTITUDE_COLUMNS)
    w.writerows(_rows(result, frames))
    return buf.getvalue()


def write_attitude_csv(result, path, frames=None, comments=()) -> None:
    """Write the attitude CSV (:func:`attitude_csv_text`) atomically (temporary file +
    rename): a crash never leaves a partial file under the final name."""
    from shipstar._atomic import atomic_write_text

    atomic_write_text(path, attitude_csv_text(result, frames, comments), newline="")
