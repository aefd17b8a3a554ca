"""The attitude CSV of a session (docs/file-formats.md): one row per frame and method.

Rows come in the engine's order (:mod:`shipstar.pipeline._engine`), an epoch's rows
together: the single-sensor rows of the frames that go with it (each at its own time),
then, with two or more sensors, the seed's rule and the joint solution at the epoch time.
Times are written to the microsecond (``time_utc`` ISO 8601 with 6 decimals, ``t_s``
with 6): at sea the deck turns by up to 4 deg/s, 14'' per millisecond.  Comment lines
(``# ...``) come before the header row (what is known at the start: Earth orientation
quality, warnings) and where a warning arises; shipstar's CSV reader skips them, astropy
(``Table.read(path, format="ascii.csv", comment="#")``) and pandas (``comment="#"``) do
when told.

:class:`AttitudeCsvWriter` writes a session as it runs: to ``OUT.partial``, flushed an
epoch at a time, renamed to ``OUT`` only when the session is complete.
"""

from __future__ import annotations

import csv
import io
import math
import os
from pathlib import Path

from shipstar.units import DAY_S, RAD2ASEC, RAD2DEG

__all__ = ["ATTITUDE_COLUMNS", "attitude_csv_text", "write_attitude_csv", "emission_rows", "AttitudeCsvWriter",
           "PARTIAL_SUFFIX", "comment_lines"]

ATTITUDE_COLUMNS = ("time_utc", "t_s", "method", "sensor", "frame", "solved", "heading_deg", "pitch_deg", "roll_deg",
                    "sigma_heading_arcsec", "sigma_pitch_arcsec", "sigma_roll_arcsec", "n_stars", "rms_arcsec",
                    "reason", "time_source", "integrity", "integrity_chi2", "suspect_sensor")
#: Appended to a single row's ``time_source`` when its sensor's estimated clock offset was
#: applied to its time (the row is then at the true exposure time, not the header's).
CLOCK_OFFSET_SUFFIX = "+clock-offset"
#: A session's CSV is ``OUT + PARTIAL_SUFFIX`` until it is complete.
PARTIAL_SUFFIX = ".partial"


_FORMATS = {d: f"{{:.{d}f}}".format for d in (2, 3, 6, 9)}


def _fmt(x, digits: int) -> str:
    x = float(x)
    return _FORMATS[digits](x) if math.isfinite(x) else ""


def _sigmas_arcsec(att) -> tuple:
    """``att.sigma_rad`` in arcsec in plain floats (a row's three; NaN where not positive)."""
    c = att.covariance_rad2
    return tuple(math.sqrt(v) * RAD2ASEC if v >= 0.0 else math.nan
                 for v in (float(c[0, 0]), float(c[1, 1]), float(c[2, 2])))


def _iso(jd1: float, jd2: float) -> str:
    from shipstar.sky.time import iso_from_utc_jd

    return iso_from_utc_jd(jd1, jd2, 6)


def _row(time_utc, t_s, method, sensor, frame, att, rms_arcsec=math.nan, time_source="", integrity=None) -> list:
    sig = _sigmas_arcsec(att)
    checks = ["", "", ""] if integrity is None or not integrity.checked else \
        [integrity.label, _fmt(integrity.chi2, 2), integrity.suspect]
    return [time_utc, _fmt(t_s, 6), method, sensor, frame, "1" if att.solved else "0",
            _fmt(att.heading_rad * RAD2DEG, 9), _fmt(att.pitch_rad * RAD2DEG, 9), _fmt(att.roll_rad * RAD2DEG, 9),
            _fmt(sig[0], 3), _fmt(sig[1], 3), _fmt(sig[2], 3), str(int(att.n_stars)), _fmt(rms_arcsec, 3),
            att.reason, time_source, *checks]


def emission_rows(emission, sensors, start_utc_jd) -> list:
    """The CSV rows (lists of str) of one :class:`~shipstar.pipeline._engine.Emission`.

    Parameters
    ----------
    emission : Emission
    sensors : sequence of str
        The session's sensors, in their order (fused rows only with two or more).
    start_utc_jd : (float, float)
        Time origin of ``t_s``.
    """
    j1, j2 = start_utc_jd
    rows = []
    shifts = emission.frame_shifts_s or (0.0,) * len(emission.frames)
    for fr, shift_s in zip(emission.frames, shifts):
        # a sensor whose clock offset is applied: its row at the true exposure time (the
        # header's plus the offset), which its attitude is of; time_source says so
        jd2 = fr.utc_jd2 + shift_s / DAY_S if shift_s else fr.utc_jd2
        t = ((fr.utc_jd1 - j1) + (jd2 - j2)) * 86400.0
        source = f"{fr.time_source}{CLOCK_OFFSET_SUFFIX}" if shift_s else fr.time_source
        rows.append(_row(_iso(fr.utc_jd1, jd2), t, "single", fr.sensor, fr.label, fr.ship, fr.rms_arcsec, source))
    e = emission.epoch
    if e is not None and len(sensors) > 1:
        both = "+".join(sensors)
        time_utc = _iso(e.utc_jd1, e.utc_jd2)
        rows.append(_row(time_utc, e.t_s, "seed-rule", both, e.label, e.seed_rule, time_source=e.time_source,
                         integrity=e.integrity))
        rows.append(_row(time_utc, e.t_s, "joint", both, e.label, e.joint, time_source=e.time_source,
                         integrity=e.integrity))
    return rows


def comment_lines(comments) -> list:
    """``# text`` lines (white space, newlines included, collapsed)."""
    if isinstance(comments, str):
        comments = [comments]
    return ["# " + " ".join(str(c).split()) + "\n" for c in comments]


def _csv_text(rows) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    return buf.getvalue()


def attitude_csv_text(result, comments=()) -> str:
    """The CSV text of a :class:`~shipstar.pipeline.SessionResult`: comment lines, header,
    then each emission's rows, each warning that arose as a ``# warning:`` line before the
    rows it came with (as ``shipstar measure`` writes it).

    Parameters
    ----------
    result : SessionResult
    comments : iterable of str
        Lines written first, each as ``# text``.
    """
    names = result.sensors
    parts = comment_lines(comments) + [_csv_text([ATTITUDE_COLUMNS])]
    for emission in result.emissions:
        parts += comment_lines([f"warning: {w}" for w in emission.warnings])
        parts.append(_csv_text(emission_rows(emission, names, result.start_utc_jd)))
    return "".join(parts)


def write_attitude_csv(result, path, comments=()) -> None:
    """Write the attitude CSV (:func:`attitude_csv_text`) atomically (temporary file +
    rename): a crash never leaves a partial file under the final name."""
    from shipstar._atomic import atomic_write_text

    atomic_write_text(path, attitude_csv_text(result, comments), newline="")


class AttitudeCsvWriter:
    """The attitude CSV written as a session runs.

    Rows go to ``path + ".partial"`` and are flushed to the operating system after each
    :meth:`write`; :meth:`complete` renames the file to ``path``.  A run stopped by a
    signal or a crash leaves ``path.partial`` holding every row written (the last epoch's
    rows whole: each :meth:`write` is one ``write`` call of complete lines).

    Parameters
    ----------
    path : str or Path
        The final name.
    sensors : sequence of str
        The session's sensors, in their order.
    start_utc_jd : (float, float)
    comments : iterable of str
        The ``#`` lines written before the header.
    append_at : int, optional
        Continue an existing ``path.partial``: truncate it to this many bytes (the end of
        the last complete group, recorded by the driver) and append.
    """

    def __init__(self, path, sensors, start_utc_jd, comments=(), *, append_at: int | None = None):
        self.path = Path(path)
        self.partial = self.path.with_name(self.path.name + PARTIAL_SUFFIX)
        self.sensors = tuple(sensors)
        self.start_utc_jd = start_utc_jd
        if append_at is None:
            self.partial.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.partial, "w", encoding="utf-8", newline="")
            self._fh.write("".join(comment_lines(comments)) + _csv_text([ATTITUDE_COLUMNS]))
            self._fh.flush()
        else:
            self._fh = open(self.partial, "r+", encoding="utf-8", newline="")
            self._fh.seek(append_at)
            self._fh.truncate()

    def write(self, emission) -> None:
        """Append one emission's rows (its warnings first, as ``# warning:`` lines) and flush."""
        text = "".join(comment_lines([f"warning: {w}" for w in emission.warnings]))
        text += _csv_text(emission_rows(emission, self.sensors, self.start_utc_jd))
        if text:
            self._fh.write(text)
            self._fh.flush()

    def comment(self, text: str) -> None:
        """Append one ``#`` line and flush."""
        self._fh.write("".join(comment_lines([text])))
        self._fh.flush()

    def tell(self) -> int:
        """Bytes written so far (a resume point)."""
        return self._fh.tell()

    def sync(self) -> None:
        """Flush and fsync (a checkpoint)."""
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        """Close, leaving ``path.partial`` (stopped before the end)."""
        if not self._fh.closed:
            self._fh.flush()
            self._fh.close()

    def complete(self) -> Path:
        """Close and rename ``path.partial`` to ``path``; returns ``path``."""
        if not self._fh.closed:
            self.sync()
            self._fh.close()
        os.replace(self.partial, self.path)
        return self.path
