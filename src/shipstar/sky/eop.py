"""Earth orientation (UT1 - UTC, polar motion) from the IERS tables shipped offline.

The source is ``finals2000A.all`` from the ``astropy-iers-data`` package (IERS Rapid
Service / Bulletin A, 1973-01-02 to about a year after the package was built), read
directly with NumPy and kept in memory; nothing is ever downloaded and astropy is not
imported.  Policy (see ``docs/sky-model.md``):

- Values: Bulletin B columns where present, else Bulletin A (as astropy's ``IERS_A``).
- Interpolation: linear in UTC MJD.  UT1 - UTC jumps by 1 s at a leap second, so it is
  interpolated as UT1 - TAI (continuous) and TAI - UTC is added back at the requested
  time.
- Quality: ``"measured"`` between two measured rows (flag I, or Bulletin B),
  ``"predicted"`` when a bracketing row is a Bulletin A prediction (flag P),
  ``"extrapolated"`` past the table's last row.
- Extrapolation: UT1 - TAI continues with its mean trend over the last 365 days of the
  table (a whole year, so the seasonal terms cancel); polar motion follows a
  least-squares fit of offset + drift + annual + Chandler (433 d) terms to the last six
  years of the table, shifted to be continuous at the end.  The estimated (rms) errors
  are the table's last stated errors plus a growth calibrated by back-testing this very
  extrapolation on 30 years of measured values: ``2.5e-4 s * d + 2e-7 s * d**2`` for
  UT1 - UTC and ``0.045'' * (d / 100)**0.25`` for polar motion, d = days past the
  table's end (UT1 is not predictable: 0.1 s after a year, 0.3 s after two).  Every
  extrapolated value comes with an :class:`~shipstar.errors.AccuracyWarning` giving those
  sizes; past the point where the UT1 - UTC error would exceed
  :data:`MAX_DUT1_ERROR_S` (0.5 s, i.e. 7.5'' of azimuth at the equator), or where
  UT1 - UTC would pass 0.9 s (an unknown leap second), :func:`earth_orientation`
  refuses with a :class:`ShipstarError`.
- Before the table's start (1973-01-02): :class:`ShipstarError`.
- Leap seconds: after the expiry of the shipped leap-second file no new leap second is
  known; times after it get an AccuracyWarning saying so.

The celestial pole offsets dX, dY (< 1 mas) are not used, as in ``erfa.apco13`` and
astropy's AltAz.
"""

from __future__ import annotations

import functools
import math
import os
import warnings
import weakref
from dataclasses import dataclass

import numpy as np

from shipstar.errors import AccuracyWarning, ShipstarError
from shipstar.sky.time import (
    MJD_ZERO_JD,
    iso_from_utc_jd,
    leap_second_table_expiry_mjd,
    tai_minus_utc_s,
)
from shipstar.units import ASEC2RAD, RAD2ASEC

__all__ = [
    "EarthOrientation",
    "EopTableInfo",
    "earth_orientation",
    "eop_table_info",
    "set_eop_file",
    "eop_source",
    "eop_identity",
    "EOP_FILE_ENV",
    "QUALITIES",
    "MAX_DUT1_ERROR_S",
    "UT1_TREND_WINDOW_DAYS",
    "POLAR_MOTION_FIT_WINDOW_DAYS",
    "CHANDLER_PERIOD_DAYS",
]

QUALITIES = ("measured", "predicted", "extrapolated")
#: Extrapolation is refused once the estimated UT1 - UTC error exceeds this (s): 7.5''
#: of azimuth at the equator.
MAX_DUT1_ERROR_S = 0.5
#: Window (days) over which the UT1 - TAI trend is taken for extrapolation.
UT1_TREND_WINDOW_DAYS = 365.0
#: Window (days) of the polar motion fit used for extrapolation.
POLAR_MOTION_FIT_WINDOW_DAYS = 6 * 365.0
#: Chandler wobble period (days) used in the polar motion fit.
CHANDLER_PERIOD_DAYS = 433.0
_ANNUAL_PERIOD_DAYS = 365.25
#: Growth of the extrapolation error (rms) with the days d past the table's end, from
#: back-tests on the measured series: UT1 - UTC ``2.5e-4 s * d + 2e-7 s * d**2``,
#: polar motion ``0.045'' * (d / 100)**0.25``.
UT1_ERROR_S_PER_DAY = 2.5e-4
UT1_ERROR_S_PER_DAY2 = 2.0e-7
PM_ERROR_ARCSEC_AT_100_DAYS = 0.045
_PM_ERROR_EXPONENT = 0.25
#: Azimuth error (arcsec) per second of UT1 error at the equator: 15''/s of time.
_ASEC_PER_S_OF_UT1 = 15.0 * 1.00273781191135448


@dataclass(frozen=True)
class EarthOrientation:
    """Earth orientation parameters at one time.

    Attributes
    ----------
    dut1_s : float
        UT1 - UTC (s).
    xp_rad, yp_rad : float
        Polar motion (rad).
    quality : str
        ``"measured"``, ``"predicted"`` or ``"extrapolated"`` (see module notes).
    dut1_error_s : float
        Estimated possible error of ``dut1_s`` (s).
    polar_motion_error_rad : float
        Estimated possible error of each polar motion component (rad).
    """

    dut1_s: float
    xp_rad: float
    yp_rad: float
    quality: str
    dut1_error_s: float
    polar_motion_error_rad: float = 0.0

    def __post_init__(self):
        for name in ("dut1_s", "xp_rad", "yp_rad", "dut1_error_s", "polar_motion_error_rad"):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise ShipstarError(f"EarthOrientation.{name} must be a number, got {value!r}") from None
            if not math.isfinite(value):
                raise ShipstarError(f"EarthOrientation.{name} must be finite, got {value}")
            object.__setattr__(self, name, value)
        if self.quality not in QUALITIES:
            raise ShipstarError(f"EarthOrientation.quality must be one of {QUALITIES}, "
                                f"got {self.quality!r}")
        if abs(self.dut1_s) > 1.0:
            raise ShipstarError(f"UT1-UTC = {self.dut1_s} s: leap seconds keep it within 0.9 s")
        for name in ("xp_rad", "yp_rad"):
            if abs(getattr(self, name)) > 2.0 * ASEC2RAD:
                raise ShipstarError(f"polar motion {name} = {getattr(self, name) * RAD2ASEC:.3f} "
                                    "arcsec is not physical (|x|, |y| < 1 arcsec)")
        if self.dut1_error_s < 0 or self.polar_motion_error_rad < 0:
            raise ShipstarError("EarthOrientation errors must be >= 0")

    @property
    def xp_arcsec(self) -> float:
        return self.xp_rad * RAD2ASEC

    @property
    def yp_arcsec(self) -> float:
        return self.yp_rad * RAD2ASEC


@dataclass(frozen=True)
class EopTableInfo:
    """What the shipped IERS table covers (UTC MJDs) and where it comes from."""

    source: str
    first_mjd: float
    last_measured_mjd: float
    last_mjd: float
    horizon_mjd: float                 # extrapolation refused after this
    leap_second_expiry_mjd: float


@dataclass(frozen=True, eq=False)
class _Table:
    source: str
    mjd: np.ndarray
    ut1_tai_s: np.ndarray
    xp_arcsec: np.ndarray
    yp_arcsec: np.ndarray
    ut1_error_s: np.ndarray
    pm_error_arcsec: np.ndarray
    measured: np.ndarray               # both UT1 and polar motion measured on that row


def _field_text(block: np.ndarray, first: int, last: int) -> np.ndarray:
    """Fixed-width columns ``first..last`` (1-based, inclusive) of each row, stripped."""
    width = last - first + 1
    return np.char.strip(np.ascontiguousarray(block[:, first - 1:last]).view(f"S{width}").ravel())


def _field(block: np.ndarray, first: int, last: int) -> np.ndarray:
    """Fixed-width columns ``first..last`` (1-based, inclusive) as floats, NaN where blank.

    Raises ``ValueError`` if an entry that is not blank is not a finite number."""
    text = _field_text(block, first, last)
    out = np.full(text.shape, np.nan)
    ok = text != b""
    out[ok] = text[ok].astype(float)
    if not np.isfinite(out[ok]).all():
        raise ValueError("not finite")
    return out


def _not_a_number(path: str, raw: bytes, block: np.ndarray, first: int, last: int) -> str:
    """The one-line refusal of table ``path`` (content ``raw``) naming the line and the text
    of the first entry of columns ``first..last`` of ``block`` that is not a finite number."""
    text = _field_text(block, first, last)
    for row in np.flatnonzero(text != b""):
        try:
            if np.isfinite(text[row:row + 1].astype(float)).all():
                continue
        except ValueError:
            pass
        line = [n for n, ln in enumerate(raw.split(b"\n"), 1) if ln.strip()][row]
        entry = text[row].decode("ascii", errors="replace")
        return (f"IERS table {path} is not a daily finals2000A table: line {line}, "
                f"columns {first}-{last}: {entry!r} is not a number")
    return f"IERS table {path} is not a daily finals2000A table"


def _flag(block: np.ndarray, col: int) -> np.ndarray:
    return block[:, col - 1].view("S1").ravel()


def _read_table_file(path: str) -> bytes:
    try:
        with open(path, "rb") as fh:
            return fh.read()
    except OSError as exc:
        raise ShipstarError(f"cannot read the IERS table {path}: {exc.strerror}") from None


def _parse_finals(path: str, raw: bytes | None = None) -> _Table:
    """Parse ``finals2000A.all`` (format: ``ReadMe.finals2000A``); ``raw``: its bytes, read already."""
    if raw is None:
        raw = _read_table_file(path)
    lines = [ln.ljust(187)[:187] for ln in raw.split(b"\n") if ln.strip()]
    block = np.frombuffer(b"".join(lines), dtype="S1").reshape(len(lines), 187)

    def field(first: int, last: int) -> np.ndarray:
        try:
            return _field(block, first, last)
        except ValueError:
            raise ShipstarError(_not_a_number(path, raw, block, first, last)) from None

    mjd = field(8, 15)
    pm_flag, ut1_flag = _flag(block, 17), _flag(block, 58)
    ut1_a, ut1_err = field(59, 68), field(69, 78)
    xp_a, xp_err = field(19, 27), field(28, 36)
    yp_a, yp_err = field(38, 46), field(47, 55)
    xp_b, yp_b, ut1_b = field(135, 144), field(145, 154), field(155, 165)
    keep = np.isfinite(ut1_a) & (pm_flag != b" ") & np.isfinite(xp_a) & np.isfinite(yp_a)
    if keep.sum() < 400 or np.any(np.diff(mjd[keep]) != 1.0):
        raise ShipstarError(f"IERS table {path} is not a daily finals2000A table")
    b_ut1 = np.isfinite(ut1_b)
    b_pm = np.isfinite(xp_b) & np.isfinite(yp_b)
    ut1_utc = np.where(b_ut1, ut1_b, ut1_a)[keep]
    mjd = mjd[keep]
    measured = ((b_ut1 | (ut1_flag == b"I")) & (b_pm | (pm_flag == b"I")))[keep]
    return _Table(
        source=str(path),
        mjd=mjd,
        ut1_tai_s=ut1_utc - tai_minus_utc_s(mjd),
        xp_arcsec=np.where(b_pm, xp_b, xp_a)[keep],
        yp_arcsec=np.where(b_pm, yp_b, yp_a)[keep],
        ut1_error_s=np.nan_to_num(ut1_err[keep]),
        pm_error_arcsec=np.nan_to_num(np.fmax(xp_err, yp_err)[keep]),
        measured=measured,
    )


#: :func:`eop_identity`'s digest of each parsed table (computed once).
_DIGESTS: "weakref.WeakKeyDictionary[_Table, str]" = weakref.WeakKeyDictionary()


#: The parsed columns of a table, kept in the cache directory (``eop_v1_<digest>.npz``) by
#: the file's content: parsing the 3.8 MB text took ~55 ms of every process that needs Earth
#: orientation (``measure``, ``live``, each ``measure-archive`` driver); reading the file,
#: hashing it and loading the stored columns ~10 ms.
_CACHE_FORMAT = 1
_CACHE_PREFIX = f"eop_v{_CACHE_FORMAT}_"
#: Parsed tables kept in the cache directory (the most recently written; a new
#: astropy-iers-data release, or ``--eop FILE``, writes another).
_CACHE_KEEP_FILES = 3
_COLUMNS = ("mjd", "ut1_tai_s", "xp_arcsec", "yp_arcsec", "ut1_error_s", "pm_error_arcsec", "measured")


def _cache_path(raw: bytes):
    """Where the parsed table of a file with content ``raw`` is kept (None: no usable
    cache directory)."""
    import hashlib

    from shipstar.sky.catalog import cache_dir

    try:
        return cache_dir() / f"{_CACHE_PREFIX}{hashlib.sha256(raw).hexdigest()[:24]}.npz"    # ~2 ms
    except ShipstarError:
        return None


def _read_cached(cache, source: str) -> _Table | None:
    """The table kept at ``cache``, or None (missing, unreadable or not whole)."""
    from shipstar._arraycache import read_arrays

    cols = read_arrays(cache, _COLUMNS)
    if cols is None:
        return None
    n = len(cols["mjd"])
    if n < 400 or any(c.shape != (n,) for c in cols.values()) or cols["measured"].dtype != bool:
        return None
    return _Table(source=source, **cols)


def _write_cached(cache, table: _Table) -> None:
    """Keep ``table`` at ``cache`` (atomically) and only the :data:`_CACHE_KEEP_FILES` most
    recent such files; a directory that cannot be written only means the next process
    parses the file again."""
    from shipstar._arraycache import write_arrays

    if not write_arrays(cache, {name: getattr(table, name) for name in _COLUMNS}):
        return
    try:
        kept = sorted(cache.parent.glob(f"{_CACHE_PREFIX}*.npz"), key=lambda p: p.stat().st_mtime, reverse=True)
        for old in kept[_CACHE_KEEP_FILES:]:
            if old != cache:
                old.unlink()
    except OSError:
        pass


@functools.lru_cache(maxsize=4)
def _table(path: str | None = None) -> _Table:
    if path is None:
        from astropy_iers_data import IERS_A_FILE

        path = str(IERS_A_FILE)
    raw = _read_table_file(path)
    cache = _cache_path(raw)
    table = None if cache is None else _read_cached(cache, str(path))
    if table is None:
        table = _parse_finals(path, raw)
        if cache is not None:
            _write_cached(cache, table)
    return table


#: Environment variable holding the IERS table in use (``--eop FILE``); an environment
#: variable so that worker processes (fork or spawn) use the same table.
EOP_FILE_ENV = "SHIPSTAR_EOP_FILE"


def _active_table() -> _Table:
    return _table(os.environ.get(EOP_FILE_ENV) or None)


def set_eop_file(path) -> str:
    """Use the IERS ``finals2000A`` table ``path`` (a newer one than the packaged
    ``astropy-iers-data`` file) for every Earth orientation from now on, in this process and
    the processes it starts; ``None`` goes back to the packaged table.  The file is read and
    checked at once (one-line :class:`ShipstarError` naming it).  Returns its absolute path
    (what :func:`eop_source` then reports)."""
    if path is None:
        os.environ.pop(EOP_FILE_ENV, None)
        return eop_source()
    full = os.path.abspath(os.fspath(path))
    if not os.path.isfile(full):
        raise ShipstarError(f"IERS table {path}: " + ("a directory, not a file" if os.path.isdir(full) else
                                                      "no such file"))
    _table(full)                                   # parse now: a bad file is refused before any work
    os.environ[EOP_FILE_ENV] = full
    return full


def eop_identity() -> tuple[str, str]:
    """``(source, digest)`` of the Earth orientation table in use: where it comes from
    (:func:`eop_source`) and a SHA-256 of its parsed columns, the same for the same table
    wherever it is installed.  A process that computes apparent places for another (a Dask
    worker of ``measure-archive``) checks with it that its table is the caller's."""
    table = _active_table()
    digest = _DIGESTS.get(table)
    if digest is None:
        import hashlib

        h = hashlib.sha256()
        for a in (table.mjd, table.ut1_tai_s, table.xp_arcsec, table.yp_arcsec, table.ut1_error_s,
                  table.pm_error_arcsec, table.measured):
            h.update(np.ascontiguousarray(a).tobytes())
        digest = _DIGESTS[table] = h.hexdigest()
    return table.source, digest


def eop_source() -> str:
    """Where Earth orientation comes from: the table's path (``--eop FILE``, or the packaged
    ``finals2000A.all`` of astropy-iers-data)."""
    return _active_table().source


# ---------------------------------------------------------------------------------------
# Extrapolation model
# ---------------------------------------------------------------------------------------

def _pm_design(dt_days: np.ndarray) -> np.ndarray:
    w_a = 2 * np.pi * dt_days / _ANNUAL_PERIOD_DAYS
    w_c = 2 * np.pi * dt_days / CHANDLER_PERIOD_DAYS
    return np.stack([np.ones_like(dt_days), dt_days / 365.25, np.cos(w_a), np.sin(w_a),
                     np.cos(w_c), np.sin(w_c)], axis=-1)


@functools.lru_cache(maxsize=4)
def _extrapolation_model(table: _Table):
    """``(ut1_tai_slope_s_per_day, pm_coefficients (6, 2), last_measured_mjd)``."""
    mjd = table.mjd
    k = int(np.searchsorted(mjd, mjd[-1] - UT1_TREND_WINDOW_DAYS))
    slope = (table.ut1_tai_s[-1] - table.ut1_tai_s[k]) / (mjd[-1] - mjd[k])
    fit = mjd >= mjd[-1] - POLAR_MOTION_FIT_WINDOW_DAYS
    a = _pm_design(mjd[fit] - mjd[-1])
    coef, *_ = np.linalg.lstsq(a, np.stack([table.xp_arcsec[fit], table.yp_arcsec[fit]], -1),
                               rcond=None)
    last_measured = float(mjd[np.flatnonzero(table.measured)[-1]])
    return float(slope), coef, last_measured


def _extrapolation_errors(table: _Table, mjd):
    """Estimated (rms) errors ``(dut1_s, polar_motion_arcsec)`` of extrapolated values.

    The table's own error at its last row plus the growth of shipstar's extrapolation
    error with the days d past that row, calibrated by back-testing the extrapolation
    on the measured IERS series 1995-2026 (``tests/sky/test_eop.py``):
    ``UT1: 2.5e-4 s * d + 2e-7 s * d**2``, ``polar motion: 0.045'' * (d / 100)**0.25``
    (the UT1 formula is the rms of the back-test; the polar motion one bounds it).
    """
    days = np.maximum(np.asarray(mjd, float) - table.mjd[-1], 0.0)
    dut1 = table.ut1_error_s[-1] + UT1_ERROR_S_PER_DAY * days + UT1_ERROR_S_PER_DAY2 * days**2
    pm = table.pm_error_arcsec[-1] + PM_ERROR_ARCSEC_AT_100_DAYS * (days / 100.0) ** _PM_ERROR_EXPONENT
    return dut1, pm


def _extrapolated_values(table: _Table, mjd):
    """``(ut1_tai_s, xp_arcsec, yp_arcsec, dut1_error_s, pm_error_arcsec)`` past the end."""
    slope, coef, _ = _extrapolation_model(table)
    past = np.asarray(mjd, float) - table.mjd[-1]
    ut1_tai = table.ut1_tai_s[-1] + slope * past
    pm = (_pm_design(past) - _pm_design(np.zeros_like(past))) @ coef
    dut1_err, pm_err = _extrapolation_errors(table, mjd)
    return (ut1_tai, pm[..., 0] + table.xp_arcsec[-1], pm[..., 1] + table.yp_arcsec[-1],
            dut1_err, pm_err)


def _horizon(table: _Table) -> tuple[float, str]:
    """Last UTC MJD that is extrapolated, and why extrapolation stops there.

    The earlier of: the estimated UT1 - UTC error reaching :data:`MAX_DUT1_ERROR_S`, and
    the extrapolated UT1 - UTC reaching +-0.9 s (by then IERS will have scheduled a leap
    second that shipstar cannot know).
    """
    slope, _, _ = _extrapolation_model(table)
    room = max(MAX_DUT1_ERROR_S - table.ut1_error_s[-1], 0.0)
    a, b = UT1_ERROR_S_PER_DAY2, UT1_ERROR_S_PER_DAY
    by_error = float(table.mjd[-1] + (-b + math.sqrt(b * b + 4 * a * room)) / (2 * a))
    dut1_end = table.ut1_tai_s[-1] + float(tai_minus_utc_s(table.mjd[-1]))
    if slope != 0.0:
        by_leap = float(table.mjd[-1] + (math.copysign(0.9, slope) - dut1_end) / slope)
        if by_leap < by_error:
            return max(by_leap, float(table.mjd[-1])), (
                "UT1-UTC would pass 0.9 s there, so a leap second unknown to shipstar "
                "will have been inserted")
    return by_error, f"UT1-UTC would be uncertain by more than {MAX_DUT1_ERROR_S} s"


def _extrapolate(table: _Table, mjd: float, tai_utc: float) -> EarthOrientation:
    ut1_tai, xp, yp, dut1_err, pm_err = _extrapolated_values(table, mjd)
    return EarthOrientation(
        dut1_s=float(ut1_tai + tai_utc), xp_rad=float(xp * ASEC2RAD), yp_rad=float(yp * ASEC2RAD),
        quality="extrapolated", dut1_error_s=float(dut1_err),
        polar_motion_error_rad=float(pm_err * ASEC2RAD),
    )


def _interpolate(table: _Table, mjd: float, tai_utc: float) -> EarthOrientation:
    # Rows are consecutive days (checked on parsing): the row index is the day number.
    j = min(max(int(math.floor(mjd - table.mjd[0])), 0), len(table.mjd) - 2)
    f = mjd - float(table.mjd[j])

    def lin(arr):
        a = float(arr[j])
        return a + f * (float(arr[j + 1]) - a)

    both = bool(table.measured[j]) and (bool(table.measured[j + 1]) or f == 0.0)
    return EarthOrientation(
        dut1_s=lin(table.ut1_tai_s) + tai_utc, xp_rad=lin(table.xp_arcsec) * ASEC2RAD,
        yp_rad=lin(table.yp_arcsec) * ASEC2RAD, quality="measured" if both else "predicted",
        dut1_error_s=lin(table.ut1_error_s), polar_motion_error_rad=lin(table.pm_error_arcsec) * ASEC2RAD,
    )


# ---------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------

def eop_table_info() -> EopTableInfo:
    """Coverage of the shipped IERS table: first, last measured, last row, horizon."""
    table = _active_table()
    _, _, last_measured = _extrapolation_model(table)
    return EopTableInfo(
        source=table.source, first_mjd=float(table.mjd[0]), last_measured_mjd=last_measured,
        last_mjd=float(table.mjd[-1]), horizon_mjd=_horizon(table)[0],
        leap_second_expiry_mjd=leap_second_table_expiry_mjd(),
    )


def _date(mjd: float) -> str:
    return iso_from_utc_jd(2400000.5, mjd, 0)[:10]


def earth_orientation(utc_jd1, utc_jd2=0.0) -> EarthOrientation:
    """UT1 - UTC and polar motion at a UTC time, with their quality and possible error.

    Parameters
    ----------
    utc_jd1, utc_jd2 : float
        Two-part UTC Julian date (as from :func:`shipstar.sky.time.utc_jd_from_iso`).

    Returns
    -------
    EarthOrientation

    Warns
    -----
    AccuracyWarning
        Past the table's end (extrapolated values, with their estimated errors), or past
        the expiry of the leap-second table.

    Raises
    ------
    ShipstarError
        Non-finite time, a time before 1973-01-02, or past the extrapolation horizon.
    """
    try:
        jd1, jd2 = float(utc_jd1), float(utc_jd2)
    except (TypeError, ValueError):
        raise ShipstarError(f"time must be a two-part Julian date, got {utc_jd1!r}, {utc_jd2!r}") from None
    if not (math.isfinite(jd1) and math.isfinite(jd2)):
        raise ShipstarError(f"time must be finite, got JD {utc_jd1!r} + {utc_jd2!r}")
    table = _active_table()
    mjd = (jd1 - MJD_ZERO_JD) + jd2
    if mjd < table.mjd[0]:
        raise ShipstarError(
            f"time {_date(mjd)} is before the start of the IERS Earth orientation table "
            f"({_date(table.mjd[0])}): UT1-UTC and polar motion are unknown")
    tai_utc = float(tai_minus_utc_s(mjd))
    if mjd <= table.mjd[-1]:
        eop = _interpolate(table, mjd, tai_utc)
    else:
        horizon, why = _horizon(table)
        if mjd > horizon:
            raise ShipstarError(
                f"time {_date(mjd)} is too far past the end of the IERS table "
                f"({_date(table.mjd[-1])}): shipstar extrapolates Earth orientation only up to "
                f"{_date(horizon)} ({why}); update astropy-iers-data or give a newer table with --eop FILE")
        eop = _extrapolate(table, mjd, tai_utc)
        warnings.warn(
            f"Earth orientation at {_date(mjd)} is extrapolated {mjd - table.mjd[-1]:.0f} days "
            f"past the IERS table (ends {_date(table.mjd[-1])}): UT1-UTC estimated error "
            f"{eop.dut1_error_s:.3f} s ({eop.dut1_error_s * _ASEC_PER_S_OF_UT1:.2f} arcsec of "
            f"azimuth at the equator), polar motion {eop.polar_motion_error_rad * RAD2ASEC:.3f} "
            "arcsec; update astropy-iers-data for better values",
            AccuracyWarning, stacklevel=2)
    expiry = leap_second_table_expiry_mjd()
    if mjd > expiry:
        warnings.warn(
            f"no leap second is known after {_date(expiry)} (expiry of the shipped leap-second "
            f"table): TAI-UTC = {tai_utc:.0f} s assumed at {_date(mjd)}; a new leap second "
            "would change UT1-UTC by 1 s", AccuracyWarning, stacklevel=2)
    return eop
