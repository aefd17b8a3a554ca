"""Time tables of the session: the ship's track (:class:`Track`), the weather
(:class:`WeatherTable`) and, for simulated sessions, the true attitude (:class:`TruthTable`);
and the quality of the Earth orientation over a session's frame times (:func:`eop_quality`).

All are CSV files with a header row and a ``time_utc`` column (ISO 8601 UTC), see
docs/file-formats.md.  Track and weather are interpolated linearly in time; a frame
outside a table's time range is refused (never extrapolated).  Every value is checked
against the physical ranges of :mod:`shipstar.limits`, and a table read as a table covers
a frame only when (docs/conventions.md, "Physical ranges"):

- the frame lies between two rows at most ``MAX_TRACK_GAP_S`` (track) or
  ``MAX_WEATHER_GAP_S`` (weather) apart, or within ``TABLE_EDGE_S`` (1 s) of the first or
  last row (the end row's values are held there);
- so a table of one row covers only frames within 1 s of it: a ship at a fixed place, or
  constant weather, is said explicitly (:meth:`Track.fixed`, :meth:`WeatherTable.constant`,
  the command line's ``--lat-deg``/``--lon-deg`` and ``--pressure-hpa``/``--temperature-c``).

A track whose consecutive rows imply a ship faster than 40 kn, or accelerating more than
0.5 g, is refused, naming the rows (:func:`check_ship_motion`).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.limits import (MAX_SHIP_ACCELERATION_M_PER_S2, MAX_SHIP_SPEED_M_PER_S, MAX_TRACK_GAP_S,
                             MAX_WEATHER_GAP_S, POSITION_NOISE_M, TABLE_EDGE_S, KNOT_M_PER_S, check_range)
from shipstar.units import DAY_S, DEG2RAD

__all__ = ["Track", "WeatherTable", "TruthTable", "read_csv_table", "EopQuality", "eop_quality",
           "check_ship_motion"]

#: Frames may lie this far outside a table's time range (s): 1 s (shipstar.limits.TABLE_EDGE_S).
_EDGE_S = TABLE_EDGE_S
#: Rows this much further apart than a table's largest gap still pass (s): clock rounding.
_GAP_ROUNDING_S = 1e-3
#: Earth's mean radius (m), for the distances between track rows.
_EARTH_RADIUS_M = 6371008.8


def read_csv_table(path, required: tuple, optional: tuple = (), what: str = "table"
                   ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Read a CSV time table: ``(jd1 (M,), jd2 (M,), {column: (M,) float})``.

    ``what`` names the table in messages (``"track file X has no rows"``).

    Raises
    ------
    ShipstarError
        Missing file, no rows, missing column (named), a bad number or time (row named),
        times not strictly increasing.
    """
    from shipstar.sky.time import utc_jd_from_iso

    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.DictReader(line for line in fh if not line.lstrip().startswith("#")))
    except FileNotFoundError:
        raise ShipstarError(f"no such file: {path}") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise ShipstarError(f"cannot read {path}: {exc}") from None
    if not rows:
        raise ShipstarError(f"{what} file {path} has no rows (need a header line time_utc, "
                            f"{', '.join(required)} and at least one row)")
    header = set(rows[0].keys())
    for col in ("time_utc",) + required:
        if col not in header:
            raise ShipstarError(f"{path}: missing column {col!r} (need time_utc, {', '.join(required)})")
    jd1, jd2, cols = [], [], {c: [] for c in required + tuple(c for c in optional if c in header)}
    for i, row in enumerate(rows, start=2):
        try:
            a, b = utc_jd_from_iso((row["time_utc"] or "").strip())
        except ShipstarError as exc:
            raise ShipstarError(f"{path} line {i}: {exc}") from None
        jd1.append(a)
        jd2.append(b)
        for c in cols:
            cols[c].append(_number(row.get(c), path, i, c))
    jd1, jd2 = np.array(jd1), np.array(jd2)
    dt = np.diff((jd1 - jd1[0]) + (jd2 - jd2[0])) if len(jd1) else np.array([])
    if np.any(dt <= 0):
        raise ShipstarError(f"{path}: times must increase strictly (line {int(np.argmax(dt <= 0)) + 3})")
    return jd1, jd2, {c: np.array(v) for c, v in cols.items()}


def _number(text, path, line: int, col: str) -> float:
    try:
        value = float((text or "").strip())
    except ValueError:
        raise ShipstarError(f"{path} line {line}: {col} is not a number: {text!r}") from None
    if not math.isfinite(value):
        raise ShipstarError(f"{path} line {line}: {col} must be finite, got {text!r}")
    return value


def check_ship_motion(t_s, lat_rad, lon_rad, *, name: str = "track", jd0=(0.0, 0.0)) -> None:
    """Refuse a track whose rows are not a ship's motion (:mod:`shipstar.limits`).

    Between consecutive rows (times ``t_s`` (M,) in s, latitude and unwrapped longitude in
    rad) the distance may exceed ``MAX_SHIP_SPEED_M_PER_S * dt`` (40 kn) by at most
    ``POSITION_NOISE_M`` (10 m, GNSS noise); between consecutive pairs of rows the velocity
    may change by at most ``MAX_SHIP_ACCELERATION_M_PER_S2`` (0.5 g) times the time between
    them plus the noise over each interval.  Distances on a sphere of the Earth's mean radius.

    Raises
    ------
    ShipstarError
        One line naming the rows (1-based data rows), their times and the implied speed or
        acceleration.
    """
    t = np.asarray(t_s, float)
    lat, lon = np.asarray(lat_rad, float), np.asarray(lon_rad, float)
    if len(t) < 2:
        return

    def when(k: int) -> str:
        from shipstar.sky.time import iso_from_utc_jd

        return iso_from_utc_jd(jd0[0], jd0[1] + t[k] / DAY_S, 6)

    dt = np.diff(t)
    a1, a2 = lat[:-1], lat[1:]
    hav = np.sin(0.5 * (a2 - a1)) ** 2 + np.cos(a1) * np.cos(a2) * np.sin(0.5 * np.diff(lon)) ** 2
    dist = 2.0 * _EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(hav, 0.0, 1.0)))
    fast = dist > MAX_SHIP_SPEED_M_PER_S * dt + POSITION_NOISE_M
    if np.any(fast):
        k = int(np.argmax(fast))
        v = dist[k] / dt[k]
        raise ShipstarError(f"{name}: data rows {k + 1} and {k + 2} ({when(k)} and {when(k + 1)}) are {dist[k]:.6g} m "
                            f"apart in {dt[k]:.6g} s: {v:.6g} m/s ({v / KNOT_M_PER_S:.4g} kn), faster than a ship "
                            f"(at most {MAX_SHIP_SPEED_M_PER_S:.3g} m/s = 40 kn, plus {POSITION_NOISE_M:g} m of "
                            f"position noise)")
    if len(t) < 3:
        return
    mid = 0.5 * (lat[:-1] + lat[1:])
    v_north = _EARTH_RADIUS_M * np.diff(lat) / dt
    v_east = _EARTH_RADIUS_M * np.cos(mid) * np.diff(lon) / dt
    dv = np.hypot(np.diff(v_north), np.diff(v_east))
    span = 0.5 * (dt[:-1] + dt[1:])
    allowed = MAX_SHIP_ACCELERATION_M_PER_S2 * span + POSITION_NOISE_M * (1.0 / dt[:-1] + 1.0 / dt[1:])
    jerky = dv > allowed
    if np.any(jerky):
        k = int(np.argmax(jerky))
        raise ShipstarError(f"{name}: data rows {k + 1} to {k + 3} ({when(k)} to {when(k + 2)}) change the ship's "
                            f"velocity by {dv[k]:.6g} m/s in {span[k]:.6g} s: {dv[k] / span[k]:.6g} m/s^2, more than a "
                            f"ship's {MAX_SHIP_ACCELERATION_M_PER_S2:g} m/s^2 (0.5 g) plus {POSITION_NOISE_M:g} m of "
                            f"position noise")


@dataclass(frozen=True, eq=False)
class _TimeTable:
    """Rows at times ``t_s`` (seconds since ``(jd1_0, jd2_0)``) with linear interpolation."""

    name: str
    jd1_0: float
    jd2_0: float
    t_s: np.ndarray

    #: Largest time between two rows a frame may fall in (s); class attribute, not a field.
    _max_gap_s = math.inf
    #: How to say a fixed value instead (messages about one-row tables).
    _fixed_hint = ""

    def _seconds(self, utc_jd1: float, utc_jd2: float) -> float:
        return ((utc_jd1 - self.jd1_0) + (utc_jd2 - self.jd2_0)) * DAY_S

    def _iso_at(self, t_s: float) -> str:
        from shipstar.sky.time import iso_from_utc_jd

        return iso_from_utc_jd(self.jd1_0, self.jd2_0 + t_s / DAY_S, 6)

    def _weights(self, utc_jd1: float, utc_jd2: float):
        """``(i, f)``: the value is ``(1 - f) row[i] + f row[i + 1]``.

        A fixed table (``covers_all``: :meth:`Track.fixed`, :meth:`WeatherTable.constant`) covers
        every time; a table read from rows covers the times between two rows at most
        ``_max_gap_s`` apart and within ``_EDGE_S`` of its first and last row."""
        if getattr(self, "covers_all", False):
            return 0, 0.0
        t = self._seconds(utc_jd1, utc_jd2)
        lo, hi = self.t_s[0], self.t_s[-1]
        if not lo - _EDGE_S <= t <= hi + _EDGE_S:
            from shipstar.sky.time import iso_from_utc_jd

            when = iso_from_utc_jd(utc_jd1, utc_jd2, 6)
            if len(self.t_s) == 1:
                raise ShipstarError(f"frame time {when} is outside the {self.name}: it has one row, at "
                                    f"{self._iso_at(lo)}, which covers only frames within {_EDGE_S:g} s of it"
                                    f"{self._fixed_hint}")
            raise ShipstarError(f"frame time {when} is outside the {self.name} ({self._iso_at(lo)} to "
                                f"{self._iso_at(hi)}; frames may lie at most {_EDGE_S:g} s before the first "
                                f"row or after the last)")
        if len(self.t_s) == 1:
            return 0, 0.0
        i = min(max(int(np.searchsorted(self.t_s, t)) - 1, 0), len(self.t_s) - 2)     # plain ints: 2 us, not 8
        gap = self.t_s[i + 1] - self.t_s[i]
        if gap > self._max_gap_s + _GAP_ROUNDING_S and self.t_s[i] < t < self.t_s[i + 1]:
            from shipstar.sky.time import iso_from_utc_jd

            raise ShipstarError(f"frame time {iso_from_utc_jd(utc_jd1, utc_jd2, 6)} falls in a gap of {gap:.6g} s "
                                f"of the {self.name} (rows at {self._iso_at(self.t_s[i])} and "
                                f"{self._iso_at(self.t_s[i + 1])}; at most {self._max_gap_s:g} s between rows)")
        f = min(max(float((t - self.t_s[i]) / gap), 0.0), 1.0)
        return i, f

    def check_covers(self, utc_jd1: float, utc_jd2: float) -> None:
        """ShipstarError when a time is not covered (see :meth:`_weights`)."""
        self._weights(utc_jd1, utc_jd2)

    def _located(self, utc_jd1, utc_jd2):
        """``(t_s, i, f, covered)`` of many times (arrays ``(N,)``): seconds since the table's
        first row, the row before each time and the fraction to the next, clamped as
        :meth:`_weights` clamps them (0 and 0.0 for a one-row or fixed table), and whether
        :meth:`_weights` would take the time (False for NaN)."""
        jd1, jd2 = np.atleast_1d(np.asarray(utc_jd1, float)), np.atleast_1d(np.asarray(utc_jd2, float))
        t = ((jd1 - self.jd1_0) + (jd2 - self.jd2_0)) * DAY_S
        i, f = np.zeros(t.shape, np.int64), np.zeros(t.shape)
        if getattr(self, "covers_all", False):
            return t, i, f, np.ones(t.shape, bool)
        covered = (t >= self.t_s[0] - _EDGE_S) & (t <= self.t_s[-1] + _EDGE_S)
        if len(self.t_s) == 1:
            return t, i, f, covered
        i = np.clip(np.searchsorted(self.t_s, t) - 1, 0, len(self.t_s) - 2)
        gap = self.t_s[i + 1] - self.t_s[i]
        covered &= ~((gap > self._max_gap_s + _GAP_ROUNDING_S) & (t > self.t_s[i]) & (t < self.t_s[i + 1]))
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.clip((t - self.t_s[i]) / gap, 0.0, 1.0)
        return t, i, f, covered

    def interpolate_many(self, values, utc_jd1, utc_jd2):
        """``(v (N,), covered (N,) bool)``: the column ``values`` at many times (arrays
        ``(N,)``), interpolated as :meth:`_weights` and :func:`_interp` do one time, with
        ``covered`` False where :meth:`_weights` would refuse the time (outside the table; a
        gap longer than it allows): ``v`` there is meaningless."""
        _, i, f, covered = self._located(utc_jd1, utc_jd2)
        values = np.asarray(values, float)
        if len(values) == 1:
            return np.full(i.shape, float(values[0])), covered
        return (1.0 - f) * values[i] + f * values[i + 1], covered

    def check_covers_all(self, utc_jd1, utc_jd2) -> None:
        """ShipstarError naming the first of many times (arrays ``(N,)``) that is not covered:
        outside the table, or in a gap longer than the table allows (NaN times are not
        judged here)."""
        jd1, jd2 = np.atleast_1d(np.asarray(utc_jd1, float)), np.atleast_1d(np.asarray(utc_jd2, float))
        if getattr(self, "covers_all", False) or jd1.size == 0:
            return
        t, _, _, covered = self._located(jd1, jd2)
        bad = ~covered & ~np.isnan(t)
        if bad.any():
            k = int(np.argmax(bad))
            self._weights(float(jd1[k]), float(jd2[k]))


def _interp(values: np.ndarray, i: int, f: float) -> float:
    if len(values) == 1:
        return float(values[0])
    return float((1.0 - f) * values[i] + f * values[i + 1])


@dataclass(frozen=True, eq=False)
class Track(_TimeTable):
    """The ship's geodetic position over time (one row: a fixed site, e.g. in dock), with
    the deflection of the vertical there.

    Longitudes are unwrapped, so a track may cross 180 deg.  The deflection of the
    vertical (xi north-south, eta east-west; docs/conventions.md) tilts the horizontal
    frame the levels and a levelled ship follow: 5-30'' in most places, and every
    arcsecond of it goes into elevation and roll if it is left out.
    """

    lat_rad: np.ndarray = None
    lon_rad: np.ndarray = None
    height_m: np.ndarray = None
    xi_rad: np.ndarray = None
    eta_rad: np.ndarray = None
    #: A ship at a fixed place (:meth:`fixed`): covers every time.
    covers_all: bool = False

    _max_gap_s = MAX_TRACK_GAP_S
    _fixed_hint = ("; for a ship at a fixed place give its position as such (--lat-deg/--lon-deg, or the "
                   "session's site)")

    @classmethod
    def fixed(cls, lat_deg: float, lon_deg: float, height_m: float = 0.0, xi_arcsec: float = 0.0,
              eta_arcsec: float = 0.0) -> "Track":
        """A fixed site: geodetic latitude and longitude (deg; longitude within [-180, 360]),
        height above WGS84 (m), deflection of the vertical (arcsec)."""
        from shipstar.sky.apparent import Site

        site = Site.from_deg(lat_deg, lon_deg, height_m, xi_arcsec, eta_arcsec)        # validates
        return cls("fixed site", 0.0, 0.0, np.zeros(1), np.array([site.lat_rad]), np.array([site.lon_rad]),
                   np.array([site.height_m]), np.array([site.xi_rad]), np.array([site.eta_rad]), covers_all=True)

    @classmethod
    def from_arrays(cls, jd1, jd2, lat_deg, lon_deg, height_m=None, name: str = "track", *, xi_arcsec=None,
                    eta_arcsec=None) -> "Track":
        """A track from per-row arrays ``(M,)``; ``height_m``, ``xi_arcsec``, ``eta_arcsec``
        default to 0.  Each row is validated (:meth:`shipstar.sky.apparent.Site.from_deg`), and
        consecutive rows must be a ship's motion (:func:`check_ship_motion`)."""
        from shipstar.sky.apparent import Site

        jd1, jd2 = np.asarray(jd1, float), np.asarray(jd2, float)
        lat, lon = np.asarray(lat_deg, float), np.asarray(lon_deg, float)
        cols = [np.zeros(len(lat)) if c is None else np.asarray(c, float) for c in (height_m, xi_arcsec, eta_arcsec)]
        for c in (jd2, lat, lon, *cols):
            if c.shape != jd1.shape or c.ndim != 1 or len(c) == 0:
                raise ShipstarError(f"{name}: every column must have the same length (M,) with M >= 1, "
                                    f"got shapes {jd1.shape} and {c.shape}")
        sites = []
        for k, row in enumerate(zip(lat, lon, *cols)):
            try:
                sites.append(Site.from_deg(*row))
            except ShipstarError as exc:
                raise ShipstarError(f"{name}, data row {k + 1}: {exc}") from None
        t = ((jd1 - jd1[0]) + (jd2 - jd2[0])) * DAY_S
        lon_rad = np.unwrap(np.array([s.lon_rad for s in sites]))
        check_ship_motion(t, lat * DEG2RAD, lon_rad, name=name, jd0=(float(jd1[0]), float(jd2[0])))
        return cls(name, float(jd1[0]), float(jd2[0]), t, lat * DEG2RAD, lon_rad, cols[0],
                   np.array([s.xi_rad for s in sites]), np.array([s.eta_rad for s in sites]))

    @classmethod
    def read_csv(cls, path) -> "Track":
        """CSV columns ``time_utc, lat_deg, lon_deg[, height_m][, xi_arcsec, eta_arcsec]``."""
        jd1, jd2, c = read_csv_table(path, ("lat_deg", "lon_deg"), ("height_m", "xi_arcsec", "eta_arcsec"),
                                     what="track")
        return cls.from_arrays(jd1, jd2, c["lat_deg"], c["lon_deg"], c.get("height_m"), name=f"track {path}",
                               xi_arcsec=c.get("xi_arcsec"), eta_arcsec=c.get("eta_arcsec"))

    def site(self, utc_jd1: float, utc_jd2: float):
        """The ship's :class:`~shipstar.sky.apparent.Site` at a time (with the deflection of
        the vertical)."""
        from shipstar.sky.apparent import Site

        i, f = self._weights(utc_jd1, utc_jd2)
        xi = 0.0 if self.xi_rad is None else _interp(self.xi_rad, i, f)
        eta = 0.0 if self.eta_rad is None else _interp(self.eta_rad, i, f)
        lon = math.remainder(_interp(self.lon_rad, i, f), 2.0 * math.pi)
        return Site(_interp(self.lat_rad, i, f), lon, _interp(self.height_m, i, f), xi, eta)


@dataclass(frozen=True, eq=False)
class WeatherTable(_TimeTable):
    """Pressure, temperature and humidity at the sensors over time (one row: constant)."""

    pressure_hpa: np.ndarray = None
    temperature_c: np.ndarray = None
    relative_humidity: np.ndarray = None
    #: Constant weather (:meth:`constant`): covers every time.
    covers_all: bool = False

    _max_gap_s = MAX_WEATHER_GAP_S
    _fixed_hint = "; for constant weather give it as such (--pressure-hpa/--temperature-c)"

    @classmethod
    def constant(cls, pressure_hpa: float, temperature_c: float, relative_humidity: float = 0.0) -> "WeatherTable":
        """Constant weather, within the physical ranges of :mod:`shipstar.limits`."""
        from shipstar.sky.refraction import Weather

        for key, value in (("pressure_hpa", pressure_hpa), ("temperature_c", temperature_c),
                           ("relative_humidity", relative_humidity)):
            check_range(key, value)
        Weather(pressure_hpa, temperature_c, relative_humidity)            # validates
        return cls("weather", 0.0, 0.0, np.zeros(1), np.array([float(pressure_hpa)]),
                   np.array([float(temperature_c)]), np.array([float(relative_humidity)]), covers_all=True)

    @classmethod
    def read_csv(cls, path) -> "WeatherTable":
        """CSV columns ``time_utc, pressure_hpa, temperature_c[, relative_humidity]``."""
        from shipstar.sky.refraction import Weather

        jd1, jd2, c = read_csv_table(path, ("pressure_hpa", "temperature_c"), ("relative_humidity",), what="weather")
        rh = c.get("relative_humidity", np.zeros(len(jd1)))
        for k, (p, t, h) in enumerate(zip(c["pressure_hpa"], c["temperature_c"], rh)):
            try:
                for key, value in (("pressure_hpa", p), ("temperature_c", t), ("relative_humidity", h)):
                    check_range(key, value)
                Weather(float(p), float(t), float(h))
            except ShipstarError as exc:
                raise ShipstarError(f"{path} line {k + 2}: {exc}") from None
        t_s = ((jd1 - jd1[0]) + (jd2 - jd2[0])) * DAY_S
        return cls(f"weather table {path}", float(jd1[0]), float(jd2[0]), t_s, c["pressure_hpa"],
                   c["temperature_c"], rh)

    def weather(self, utc_jd1: float, utc_jd2: float):
        """The :class:`~shipstar.sky.refraction.Weather` at a time.

        Interpolated values are rounded to 0.01 hPa, 0.01 C and 0.001 in humidity, so that
        consecutive frames share one refraction table (building one costs ~0.4 ms); the
        rounding changes the refraction by < 0.0015'' at 45 deg, < 0.007'' at 10 deg.
        """
        from shipstar.sky.refraction import Weather

        i, f = self._weights(utc_jd1, utc_jd2)
        return Weather(round(_interp(self.pressure_hpa, i, f), 2), round(_interp(self.temperature_c, i, f), 2),
                       round(_interp(self.relative_humidity, i, f), 3))


@dataclass(frozen=True, eq=False)
class TruthTable(_TimeTable):
    """True ship attitude at given times (simulated sessions' ``truth.csv``); exact-time lookup."""

    heading_rad: np.ndarray = None
    pitch_rad: np.ndarray = None
    roll_rad: np.ndarray = None

    @classmethod
    def read_csv(cls, path) -> "TruthTable":
        """CSV columns ``time_utc, heading_deg, pitch_deg, roll_deg``."""
        jd1, jd2, c = read_csv_table(path, ("heading_deg", "pitch_deg", "roll_deg"), what="truth")
        return cls.from_arrays(jd1, jd2, c["heading_deg"], c["pitch_deg"], c["roll_deg"], name=f"truth {path}")

    @classmethod
    def from_arrays(cls, jd1, jd2, heading_deg, pitch_deg, roll_deg, name: str = "truth") -> "TruthTable":
        jd1, jd2 = np.asarray(jd1, float), np.asarray(jd2, float)
        t = ((jd1 - jd1[0]) + (jd2 - jd2[0])) * DAY_S
        return cls(name, float(jd1[0]), float(jd2[0]), t, np.asarray(heading_deg, float) * DEG2RAD,
                   np.asarray(pitch_deg, float) * DEG2RAD, np.asarray(roll_deg, float) * DEG2RAD)

    def angles_rad(self, utc_jd1: float, utc_jd2: float, tolerance_s: float = 5e-4):
        """(heading, pitch, roll) at a time listed in the table (within ``tolerance_s``),
        else ``(nan, nan, nan)``."""
        t = self._seconds(utc_jd1, utc_jd2)
        k = int(np.searchsorted(self.t_s, t))                   # O(log M): the rows are in time order
        i = min((j for j in (k - 1, k) if 0 <= j < len(self.t_s)), key=lambda j: abs(self.t_s[j] - t))
        if abs(self.t_s[i] - t) > tolerance_s:
            return math.nan, math.nan, math.nan
        return float(self.heading_rad[i]), float(self.pitch_rad[i]), float(self.roll_rad[i])


@dataclass(frozen=True)
class EopQuality:
    """Earth orientation over a session: the worst quality and largest estimated errors.

    Attributes
    ----------
    quality : str
        ``"measured"``, ``"predicted"`` or ``"extrapolated"`` (:mod:`shipstar.sky.eop`).
    dut1_error_s : float
        Largest estimated UT1 - UTC error (s); 1 s of UT1 turns azimuths by 15''.
    polar_motion_error_arcsec : float
        Largest estimated error of each polar motion component.
    """

    quality: str
    dut1_error_s: float
    polar_motion_error_arcsec: float

    def as_dict(self) -> dict:
        return {"quality": self.quality, "dut1_error_s": self.dut1_error_s,
                "polar_motion_error_arcsec": self.polar_motion_error_arcsec}


def eop_quality(utc_jd1, utc_jd2) -> EopQuality:
    """:class:`EopQuality` over frame times (two-part UTC Julian dates, arrays ``(M,)``).

    Evaluated at up to 200 times spread over the session, first and last included
    (quality and errors change on a scale of days).  Accuracy warnings are not repeated
    here (the processing of the frames issued them).

    Raises
    ------
    ShipstarError
        No times, or a time outside the Earth orientation tables.
    """
    import warnings

    from shipstar.errors import AccuracyWarning
    from shipstar.sky.eop import QUALITIES, earth_orientation
    from shipstar.units import RAD2ASEC

    jd1, jd2 = np.atleast_1d(np.asarray(utc_jd1, float)), np.atleast_1d(np.asarray(utc_jd2, float))
    if jd1.size == 0 or jd1.shape != jd2.shape:
        raise ShipstarError(f"eop_quality needs matching, non-empty time arrays, got {jd1.shape} and {jd2.shape}")
    order = np.argsort((jd1 - jd1[0]) + jd2)
    picks = order[np.unique(np.round(np.linspace(0, len(order) - 1, min(len(order), 200))).astype(int))]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        eops = [earth_orientation(jd1[k], jd2[k]) for k in picks]
    return EopQuality(quality=max((e.quality for e in eops), key=QUALITIES.index),
                      dut1_error_s=max(e.dut1_error_s for e in eops),
                      polar_motion_error_arcsec=max(e.polar_motion_error_rad for e in eops) * RAD2ASEC)
