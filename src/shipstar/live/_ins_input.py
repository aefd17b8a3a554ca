"""An inertial navigator's (INS) attitude log: CSV or NMEA 0183, mapped to shipstar's signs.

CSV: ``time_utc, heading_deg, pitch_deg, roll_deg[, heading_rate_deg_per_s,
pitch_rate_deg_per_s, roll_rate_deg_per_s]`` (``#`` lines are comments), ``time_utc`` on the
INS's clock.

NMEA 0183 (a recorded file, one sentence a line): ``$--ZDA`` gives the time and date;
``$PASHR`` (time of day, heading, roll, pitch; pynmea2's ``ASHRATT``) gives the time of
day (its date from the last ZDA, else the day that puts it nearest the session);
``$--HDT`` (heading) and Seapath's ``$PSXN,23`` (roll, pitch, heading, heave) carry no time
and belong to the record of the last time given.  A record is complete when it has a
heading, a pitch and a roll; the sentences of one time make one record.  Other sentences
are ignored.

Signs: one convention per source (:class:`shipstar.frames.AttitudeConvention`,
``--ins-convention``, docs/conventions.md) applies to every sentence or column of it.

A record that cannot be read (bad checksum, a field not a number, an angle out of range,
incomplete) or whose time is not later than the previous record's is skipped and counted,
with one line saying why (:attr:`InsLog.problems`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.units import DAY_S, DEG2RAD

__all__ = ["InsLog", "read_ins_log", "MAX_PROBLEMS_LISTED", "NmeaRecords"]

#: Problems listed one by one (the rest only counted).
MAX_PROBLEMS_LISTED = 20
_ISO_RE = re.compile(r"^(\d{4}-\d{2}-\d{2})[T ](\d{2}):(\d{2}):(\d{2}(?:\.\d+)?)Z?$")
_TOD_RE = re.compile(r"^\d{6}(?:\.\d+)?$")
_RATE_COLUMNS = ("heading_rate_deg_per_s", "pitch_rate_deg_per_s", "roll_rate_deg_per_s")


@dataclass(frozen=True, eq=False)
class InsLog:
    """An INS attitude log, in shipstar's signs.

    Attributes
    ----------
    t_s : (N,)
        Record times on the INS's clock, s since ``start_utc_jd``; strictly increasing.
    angles_rad : (N, 3)
        Heading in [0, 2 pi), pitch (bow up), roll (starboard down).
    rates_rad_per_s : (N, 3) or None
        Their rates when the log gives them.
    start_utc_jd : (float, float)
    source : str
    convention : str
    n_skipped : int
        Records skipped (unreadable or out of order).
    problems : tuple of str
        One line per skipped record (the first :data:`MAX_PROBLEMS_LISTED`).
    """

    t_s: np.ndarray
    angles_rad: np.ndarray
    rates_rad_per_s: np.ndarray | None
    start_utc_jd: tuple
    source: str
    convention: str
    n_skipped: int = 0
    problems: tuple = ()

    @property
    def rate_hz(self) -> float:
        return float((len(self.t_s) - 1) / (self.t_s[-1] - self.t_s[0])) if len(self.t_s) > 1 else math.nan


class _Collector:
    def __init__(self, source: str, start_utc_jd, sink=None, convention=None):
        self.source, self.start = source, (float(start_utc_jd[0]), float(start_utc_jd[1]))
        self.sink, self.convention = sink, convention       # live: each record to sink(t_s, angles_rad)
        self.t, self.a, self.r = [], [], []
        self.n_skipped, self.problems = 0, []
        self._date_cache: dict = {}

    def skip(self, where: str, why: str) -> None:
        self.n_skipped += 1
        if len(self.problems) < MAX_PROBLEMS_LISTED:
            self.problems.append(f"INS {self.source} {where}: {why}: record skipped")

    def day_s(self, date: str) -> float:
        """Seconds from the start to 00:00 UTC of ``date`` (YYYY-MM-DD)."""
        v = self._date_cache.get(date)
        if v is None:
            from shipstar.sky.time import utc_jd_from_iso

            j1, j2 = utc_jd_from_iso(date + "T00:00:00")
            v = self._date_cache[date] = ((j1 - self.start[0]) + (j2 - self.start[1])) * DAY_S
        return v

    def add(self, where: str, t: float, heading_deg, pitch_deg, roll_deg, rates=None) -> None:
        from shipstar.limits import bounds

        vals = (heading_deg, pitch_deg, roll_deg)
        if not all(math.isfinite(v) for v in vals) or not math.isfinite(t):
            self.skip(where, "a value is not a finite number")
            return
        for name, key, v in (("heading_deg", "heading_deg", heading_deg), ("pitch_deg", "pitch_deg", pitch_deg),
                             ("roll_deg", "roll_deg", roll_deg)):
            lo, hi = bounds(key)
            if not lo <= v <= hi:
                self.skip(where, f"{name} {v:g} is outside [{lo:g}, {hi:g}]")
                return
        if self.t and t <= self.t[-1]:
            self.skip(where, f"time {t:.6f} s is not later than the previous record's ({self.t[-1]:.6f} s): out of order")
            return
        if self.sink is not None:
            K, p, r = self.convention.to_shipstar(heading_deg, pitch_deg, roll_deg)
            self.t[:] = [t]
            self.sink(t, np.array([math.radians(K) % (2 * math.pi), math.radians(float(p)), math.radians(float(r))]))
            return
        self.t.append(t)
        self.a.append(vals)
        self.r.append(rates)

    def log(self, convention) -> InsLog:
        if len(self.t) < 4:
            raise ShipstarError(f"INS log {self.source}: {len(self.t)} readable records, at least 4 needed"
                                + (f" ({self.problems[0]})" if self.problems else ""))
        a = np.asarray(self.a, float)
        K, p, r = convention.to_shipstar(a[:, 0], a[:, 1], a[:, 2])
        angles = np.stack([np.mod(np.asarray(K) * DEG2RAD, 2 * math.pi), np.asarray(p) * DEG2RAD,
                           np.asarray(r) * DEG2RAD], -1)
        rates = None
        if all(x is not None for x in self.r):
            ra = np.asarray(self.r, float)
            rK, rp, rr = convention.to_shipstar(ra[:, 0], ra[:, 1], ra[:, 2])
            rates = np.stack([np.asarray(rK), np.asarray(rp), np.asarray(rr)], -1) * DEG2RAD
        return InsLog(np.asarray(self.t, float), angles, rates, self.start, self.source, convention.text,
                      self.n_skipped, tuple(self.problems))


def _read_csv(lines, col: _Collector) -> None:
    header = None
    for n, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        cells = [c.strip() for c in line.split(",")]
        if header is None:
            header = cells
            need = ("time_utc", "heading_deg", "pitch_deg", "roll_deg")
            missing = [c for c in need if c not in header]
            if missing:
                raise ShipstarError(f"INS log {col.source}: its header has no {', '.join(missing)} column "
                                    f"(want time_utc, heading_deg, pitch_deg, roll_deg[, rates])")
            idx = [header.index(c) for c in need]
            ridx = [header.index(c) for c in _RATE_COLUMNS] if all(c in header for c in _RATE_COLUMNS) else None
            continue
        where = f"line {n}"
        if len(cells) != len(header):
            col.skip(where, f"{len(cells)} fields, the header has {len(header)}")
            continue
        m = _ISO_RE.match(cells[idx[0]])
        if m is None:
            col.skip(where, f"time_utc {cells[idx[0]]!r} is not YYYY-MM-DDThh:mm:ss[.ffffff]")
            continue
        try:
            vals = [float(cells[i]) for i in idx[1:]]
            rates = [float(cells[i]) for i in ridx] if ridx is not None else None
        except ValueError:
            col.skip(where, "a value is not a number")
            continue
        h, mi, s = int(m[2]), int(m[3]), float(m[4])
        if h > 23 or mi > 59 or s >= 61.0:
            col.skip(where, f"time_utc {cells[idx[0]]!r} does not exist")
            continue
        try:
            t = col.day_s(m[1]) + h * 3600.0 + mi * 60.0 + s
        except ShipstarError as exc:
            col.skip(where, str(exc))
            continue
        col.add(where, t, *vals, rates)


class NmeaRecords:
    """NMEA sentences in, INS records out (to ``col.add``): the sentences of one time make
    one record, given out when the next time arrives (or at :meth:`flush`)."""

    def __init__(self, col: "_Collector"):
        self.col = col
        self.cur_t, self.cur_where, self.vals, self.date = None, "", {}, None

    def flush(self) -> None:
        vals, col = self.vals, self.col
        if self.cur_t is None or not vals:
            return
        self.vals = {}
        if not all(k in vals for k in ("heading", "pitch", "roll")):
            col.skip(self.cur_where, "incomplete (" + ", ".join(k for k in ("heading", "pitch", "roll")
                                                               if k not in vals) + " missing)")
            return
        col.add(self.cur_where, self.cur_t, vals["heading"], vals["pitch"], vals["roll"])

    def feed(self, line: str, where: str) -> None:
        from shipstar.live._nmea import NmeaError, _time_of_day, decode_zda, parse

        col = self.col
        line = line.strip()
        if not line:
            return
        try:
            s = parse(line, max_chars=None)
            t = None
            is_att = s.type == "ASHR" and _TOD_RE.match(s.field(1).strip()) is not None   # $PASHR,hhmmss.sss,...
            if s.type == "ZDA":
                z = decode_zda(s)
                self.date = z.utc_date.isoformat()
                t = col.day_s(self.date) + z.utc_time_of_day_s
            elif is_att:
                tod = _time_of_day(s, 1)
                if self.date is not None:
                    day = col.day_s(self.date)
                else:                                   # no ZDA yet: the day that puts it nearest the start
                    day = col.day_s(_start_date(col.start))
                    day = min((day - DAY_S, day, day + DAY_S), key=lambda d: abs(d + tod))
                t = day + tod
            tol = 5e-4 if s.type == "ASHR" else 1e-7          # PASHR's time: to the ms; ZDA's may be finer
            if t is not None and (self.cur_t is None or abs(t - self.cur_t) > tol):
                self.flush()
                self.cur_t, self.cur_where, self.vals = t, where, {}
            if is_att:
                if s.field(3).strip() not in ("T", ""):
                    raise NmeaError(f"PASHR field 3: heading {s.field(3)!r} is not true (T)")
                self.vals.update(heading=_f(s, 2, "heading"), roll=_f(s, 4, "roll"), pitch=_f(s, 5, "pitch"))
            elif s.type == "HDT":
                if s.field(2).strip() not in ("T", ""):
                    raise NmeaError(f"HDT field 2: {s.field(2)!r} is not T (true)")
                self.vals["heading"] = _f(s, 1, "heading")
            elif s.type == "SXN" and s.field(1).strip() == "23":              # $PSXN,23,roll,pitch,head,heave
                self.vals.update(roll=_f(s, 2, "roll"), pitch=_f(s, 3, "pitch"), heading=_f(s, 4, "heading"))
        except (NmeaError, ShipstarError) as exc:
            col.skip(where, str(exc))


def _read_nmea(lines, col: "_Collector") -> None:
    rec = NmeaRecords(col)
    for n, raw in enumerate(lines, start=1):
        rec.feed(raw, f"line {n}")
    rec.flush()


def _start_date(start_utc_jd) -> str:
    from shipstar.sky.time import iso_from_utc_jd

    return iso_from_utc_jd(start_utc_jd[0], start_utc_jd[1], 0)[:10]


def _f(s, number: int, what: str) -> float:
    from shipstar.live._nmea import NmeaError

    text = s.field(number).strip()
    try:
        v = float(text)
    except ValueError:
        raise NmeaError(f"{s.type} field {number} ({what}): {text!r} is not a number") from None
    if not math.isfinite(v):
        raise NmeaError(f"{s.type} field {number} ({what}): {text!r} is not finite")
    return v


def read_ins_log(path, start_utc_jd, convention: str = "") -> InsLog:
    """Read an INS log (CSV, or NMEA when its first non-blank line starts with ``$``).

    Parameters
    ----------
    path : str or Path
    start_utc_jd : (float, float)
        The session's start: record times are counted from it (and a ``$PASHR``'s date,
        before any ZDA, is the day that puts it nearest).
    convention : str
        The source's signs (:class:`shipstar.frames.AttitudeConvention`).
    """
    from shipstar.frames import AttitudeConvention

    conv = AttitudeConvention(convention)
    p = Path(path)
    try:
        text = p.read_text(encoding="latin-1")
    except OSError as exc:
        raise ShipstarError(f"cannot read INS log {p}: {exc.strerror or exc}") from None
    lines = text.splitlines()
    first = next((ln.strip() for ln in lines if ln.strip() and not ln.strip().startswith("#")), "")
    col = _Collector(str(p), start_utc_jd)
    (_read_nmea if first.startswith("$") else _read_csv)(lines, col)
    return col.log(conv)
