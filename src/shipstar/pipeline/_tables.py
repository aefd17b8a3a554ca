"""Time tables of the session: the ship's track (:class:`Track`), the weather
(:class:`WeatherTable`) and, for simulated sessions, the true attitude (:class:`TruthTable`);
and the quality of the Earth orientation over a session's frame times (:func:`eop_quality`).

All are CSV files with a header row and a ``time_utc`` column (ISO 8601 UTC), see
docs/file-formats.md.  Track and weather are interpolated linearly in time; a frame
outside a table's time range is refused (never extrapolated).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.units import DAY_S, DEG2RAD

__all__ = ["Track", "WeatherTable", "TruthTable", "read_csv_table", "EopQuality", "eop_quality"]

#: Frames may lie this far outside a table's time range (s): clock rounding.
_EDGE_S = 1e-3


def read_csv_table(path, required: tuple, optional: tuple = ()) -> tuple[np.ndarray, np.ndarray, dict]:
    """Read a CSV time table: ``(jd1 (M,), jd2 (M,), {column: (M,) float})``.

    Raises
    ------
    ShipstarError
        Missing file, missing column (named), a bad number or time (row named), fewer
        than one row, times not strictly increasing.
    """
    from shipstar.sky.time import utc_jd_from_iso

    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(line for line in fh if not line.lstrip().startswith("#")))
    except FileNotFoundError:
        raise ShipstarError(f"no such file: {path}") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise ShipstarError(f"cannot read {path}: {exc}") from None
    header = set(rows[0].keys()) if rows else set()
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


@dataclass(frozen=True, eq=False)
class _TimeTable:
    """Rows at times ``t_s`` (seconds since ``(jd1_0, jd2_0)``) with linear interpolation."""

    name: str
    jd1_0: float
    jd2_0: float
    t_s: np.ndarray

    def _seconds(self, utc_jd1: float, utc_jd2: float) -> float:
        return ((utc_jd1 - self.jd1_0) + (utc_jd2 - self.jd2_0)) * DAY_S

    def _weights(self, utc_jd1: float, utc_jd2: float):
        """``(i, f)``: the value is ``(1 - f) row[i] + f row[i + 1]``."""
        t = self._seconds(utc_jd1, utc_jd2)
        if len(self.t_s) == 1:
            return 0, 0.0
        lo, hi = self.t_s[0], self.t_s[-1]
        if not lo - _EDGE_S <= t <= hi + _EDGE_S:
            from shipstar.sky.time import iso_from_utc_jd

            raise ShipstarError(f"frame time {iso_from_utc_jd(utc_jd1, utc_jd2, 6)} is outside the {self.name} "
                                f"({iso_from_utc_jd(self.jd1_0, self.jd2_0 + lo / DAY_S, 6)} to "
                                f"{iso_from_utc_jd(self.jd1_0, self.jd2_0 + hi / DAY_S, 6)})")
        i = int(np.clip(np.searchsorted(self.t_s, t) - 1, 0, len(self.t_s) - 2))
        f = float(np.clip((t - self.t_s[i]) / (self.t_s[i + 1] - self.t_s[i]), 0.0, 1.0))
        return i, f

    def check_covers(self, utc_jd1: float, utc_jd2: float) -> None:
        """ShipstarError when a time is outside the table (tables of one row cover all)."""
        self._weights(utc_jd1, utc_jd2)


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

    @classmethod
    def fixed(cls, lat_deg: float, lon_deg: float, height_m: float = 0.0, xi_arcsec: float = 0.0,
              eta_arcsec: float = 0.0) -> "Track":
        """A fixed site: geodetic latitude and longitude (deg; longitude within [-180, 360]),
        height above WGS84 (m), deflection of the vertical (arcsec)."""
        from shipstar.sky.apparent import Site

        site = Site.from_deg(lat_deg, lon_deg, height_m, xi_arcsec, eta_arcsec)        # validates
        return cls("fixed site", 0.0, 0.0, np.zeros(1), np.array([site.lat_rad]), np.array([site.lon_rad]),
                   np.array([site.height_m]), np.array([site.xi_rad]), np.array([site.eta_rad]))

    @classmethod
    def from_arrays(cls, jd1, jd2, lat_deg, lon_deg, height_m=None, name: str = "track", *, xi_arcsec=None,
                    eta_arcsec=None) -> "Track":
        """A track from per-row arrays ``(M,)``; ``height_m``, ``xi_arcsec``, ``eta_arcsec``
        default to 0.  Each row is validated (:meth:`shipstar.sky.apparent.Site.from_deg`)."""
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
        return cls(name, float(jd1[0]), float(jd2[0]), t, lat * DEG2RAD, lon_rad, cols[0],
                   np.array([s.xi_rad for s in sites]), np.array([s.eta_rad for s in sites]))

    @classmethod
    def read_csv(cls, path) -> "Track":
        """CSV columns ``time_utc, lat_deg, lon_deg[, height_m][, xi_arcsec, eta_arcsec]``."""
        jd1, jd2, c = read_csv_table(path, ("lat_deg", "lon_deg"), ("height_m", "xi_arcsec", "eta_arcsec"))
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

    @classmethod
    def constant(cls, pressure_hpa: float, temperature_c: float, relative_humidity: float = 0.0) -> "WeatherTable":
        from shipstar.sky.refraction import Weather

        Weather(pressure_hpa, temperature_c, relative_humidity)            # validates
        return cls("weather", 0.0, 0.0, np.zeros(1), np.array([float(pressure_hpa)]),
                   np.array([float(temperature_c)]), np.array([float(relative_humidity)]))

    @classmethod
    def read_csv(cls, path) -> "WeatherTable":
        """CSV columns ``time_utc, pressure_hpa, temperature_c[, relative_humidity]``."""
        from shipstar.sky.refraction import Weather

        jd1, jd2, c = read_csv_table(path, ("pressure_hpa", "temperature_c"), ("relative_humidity",))
        rh = c.get("relative_humidity", np.zeros(len(jd1)))
        for k, (p, t, h) in enumerate(zip(c["pressure_hpa"], c["temperature_c"], rh)):
            try:
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
        jd1, jd2, c = read_csv_table(path, ("heading_deg", "pitch_deg", "roll_deg"))
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
