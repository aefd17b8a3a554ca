"""The attitude CSV of a session (docs/file-formats.md): one row per frame and method."""

from __future__ import annotations

import csv
import io
import math

from shipstar.units import RAD2ASEC, RAD2DEG

__all__ = ["ATTITUDE_COLUMNS", "attitude_csv_text", "write_attitude_csv"]

ATTITUDE_COLUMNS = ("time_utc", "t_s", "method", "sensor", "frame", "solved", "heading_deg", "pitch_deg", "roll_deg",
                    "sigma_heading_arcsec", "sigma_pitch_arcsec", "sigma_roll_arcsec", "n_stars", "rms_arcsec",
                    "reason")


def _fmt(x, digits: int) -> str:
    x = float(x)
    return f"{x:.{digits}f}" if math.isfinite(x) else ""


def _row(time_utc, t_s, method, sensor, frame, att, rms_arcsec=math.nan) -> list:
    sig = att.sigma_rad * RAD2ASEC
    return [time_utc, _fmt(t_s, 4), method, sensor, frame, "1" if att.solved else "0",
            _fmt(att.heading_rad * RAD2DEG, 9), _fmt(att.pitch_rad * RAD2DEG, 9), _fmt(att.roll_rad * RAD2DEG, 9),
            _fmt(sig[0], 3), _fmt(sig[1], 3), _fmt(sig[2], 3), str(int(att.n_stars)), _fmt(rms_arcsec, 3),
            att.reason]


def _rows(result) -> list:
    rows = []
    for frames in result.frames:
        for fr in frames:
            rows.append((result.t_s(fr), 0, _row(fr.utc_iso, result.t_s(fr), "single", fr.sensor, fr.label, fr.ship,
                                                fr.rms_arcsec)))
    if len(result.sensors) > 1:
        both = "+".join(result.sensors)
        ref = result.frames_of(result.reference_sensor)
        for e in result.epochs:
            label = ref[e.index].label
            rows.append((e.t_s, 1, _row(e.utc_iso, e.t_s, "seed-rule", both, label, e.seed_rule)))
            rows.append((e.t_s, 2, _row(e.utc_iso, e.t_s, "joint", both, label, e.joint)))
    rows.sort(key=lambda r: (r[0], r[1]))
    return [r[2] for r in rows]


def attitude_csv_text(result) -> str:
    """The CSV text: header, then rows sorted by time (single rows first at equal times)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(ATTITUDE_COLUMNS)
    w.writerows(_rows(result))
    return buf.getvalue()


def write_attitude_csv(result, path) -> None:
    """Write the attitude CSV atomically (temporary file + rename): a crash never leaves a
    partial file under the final name."""
    from shipstar._atomic import atomic_write_text

    atomic_write_text(path, attitude_csv_text(result), newline="")
