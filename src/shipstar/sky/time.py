"""UTC times: ISO 8601 text to ERFA's two-part Julian dates, and the UTC -> TT/UT1 steps.

Inside shipstar a time is a two-part UTC Julian date ``(utc_jd1, utc_jd2)`` as ERFA
takes it (``erfa.dtf2d``'s "quasi-JD", which handles leap-second days).  TAI - UTC comes
from ERFA's built-in leap-second table (``erfa.dat``): it holds every leap second to
date (the last is 2017-01-01, TAI - UTC = 37 s) and agrees with the ``Leap_Second.dat``
that ``astropy-iers-data`` ships, which states how long it is valid
(:func:`leap_second_table_expiry_mjd`).  Past that date a new leap second is not yet
known; :mod:`shipstar.sky.eop` says so in its accuracy warning.

ERFA flags every year more than 5 years after its own release (2029 on, for ERFA
2.0.1) as a "dubious year"; shipstar mutes exactly that notice inside its ERFA calls
(:func:`quiet_dubious_year`) and reports the real accuracy through the Earth
orientation quality instead.
"""

from __future__ import annotations

import bisect
import contextlib
import functools
import math
import re
import warnings

import numpy as np

from shipstar.errors import ShipstarError

__all__ = [
    "utc_jd_from_iso",
    "iso_from_utc_jd",
    "mjd_from_jd",
    "tt_jd_from_utc_jd",
    "ut1_jd_from_utc_jd",
    "tai_minus_utc_s",
    "leap_second_table_expiry_mjd",
    "quiet_dubious_year",
    "MJD_ZERO_JD",
]

#: Julian date of MJD 0.
MJD_ZERO_JD = 2400000.5

_ISO_RE = re.compile(
    r"^(?P<y>\d{4})-(?P<mo>\d{2})-(?P<d>\d{2})"
    r"[T ](?P<h>\d{2}):(?P<mi>\d{2}):(?P<s>\d{2}(?:\.\d+)?)"
    r"(?P<z>Z|\+00:00)?$"
)


@contextlib.contextmanager
def quiet_dubious_year():
    """Mute ERFA's "dubious year" notice (and only that one) inside the block."""
    import erfa

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*dubious year", category=erfa.ErfaWarning)
        yield


def utc_jd_from_iso(text: str) -> tuple[float, float]:
    """Two-part UTC Julian date from an ISO 8601 UTC string.

    Accepted: ``YYYY-MM-DDTHH:MM:SS[.fff][Z]`` (a space may replace the ``T``; ``+00:00``
    may replace the ``Z``).  Seconds may be 60 only inside a leap second.

    Parameters
    ----------
    text : str
        e.g. ``"2013-03-15T12:16:00"``.

    Returns
    -------
    (float, float)
        ``(utc_jd1, utc_jd2)`` as ``erfa.dtf2d("UTC", ...)`` gives them.

    Raises
    ------
    ShipstarError
        Anything else: another format, a time zone other than UTC, an impossible date
        or time.
    """
    import erfa

    if not isinstance(text, str):
        raise ShipstarError(f"time must be an ISO 8601 UTC string, got {text!r}")
    m = _ISO_RE.match(text.strip())
    if m is None:
        raise ShipstarError(
            f"time {text!r} is not ISO 8601 UTC (expected e.g. 2013-03-15T12:16:00 or "
            "2013-03-15T12:16:00.25Z)"
        )
    parts = [int(m[k]) for k in ("y", "mo", "d", "h", "mi")]
    sec = float(m["s"])
    # ERFA's ufunc first (status 0: fine, 1: a dubious year, accepted): every frame's header
    # time comes through here; any other status goes through the wrapper for its message
    jd1, jd2, status = erfa.ufunc.dtf2d(b"UTC", *parts, sec)
    if status in (0, 1):
        return float(jd1), float(jd2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            jd1, jd2 = erfa.dtf2d("UTC", *parts, sec)
        except erfa.ErfaError as exc:
            raise ShipstarError(f"time {text!r} is not a valid UTC date and time "
                                f"({_erfa_reason(exc)})") from None
    for w in caught:
        if "dubious year" in str(w.message):
            continue
        raise ShipstarError(f"time {text!r} is not a valid UTC date and time "
                            f"({_erfa_reason(w.message)})")
    return float(jd1), float(jd2)


def _erfa_reason(message) -> str:
    """The reason inside an ERFA status message, e.g. ``bad day``."""
    quoted = re.findall(r'"([^"]*)"', str(message))
    reason = quoted[-1] if quoted else str(message)
    return re.sub(r"\s*\(Note \d+\)", "", reason)


def iso_from_utc_jd(utc_jd1: float, utc_jd2: float, ndp: int = 3) -> str:
    """ISO 8601 UTC text (``YYYY-MM-DDTHH:MM:SS.sssZ``) from a two-part UTC JD."""
    from erfa import ufunc

    # ERFA's ufunc itself (2 us a call; the wrapper's status checks and warnings cost 12 us
    # more, for every row of the attitude CSV): status 1 is a dubious year, ignored as the
    # wrapper's warning is here; an unacceptable date goes through the wrapper, which raises
    iy, im, iday, ihmsf, status = ufunc.d2dtf(b"UTC", ndp, utc_jd1, utc_jd2)
    if status < 0:
        import erfa

        with quiet_dubious_year():
            iy, im, iday, ihmsf = erfa.d2dtf("UTC", ndp, utc_jd1, utc_jd2)
    h, mi, s, f = (int(v) for v in ihmsf)
    frac = f".{f:0{ndp}d}" if ndp > 0 else ""
    return f"{int(iy):04d}-{int(im):02d}-{int(iday):02d}T{h:02d}:{mi:02d}:{s:02d}{frac}Z"


def mjd_from_jd(jd1, jd2):
    """Modified Julian date from a two-part Julian date (keeps the small part's precision)."""
    return (np.asarray(jd1, float) - MJD_ZERO_JD) + np.asarray(jd2, float)


#: UTC MJD of 1972-01-01, since when TAI - UTC is a whole number of seconds.
_MJD_1972 = 41317.0
#: TT - TAI (s).
_TT_MINUS_TAI_S = 32.184
_LEAP_CACHE: dict = {}


def _leap_steps() -> tuple[list, list]:
    """``(mjd_of_step, tai_minus_utc_s)`` since 1972 from ERFA's current leap-second table.

    Rebuilt whenever ERFA's table changes (astropy may extend it at run time), so the
    fast paths below always agree with ``erfa.dat``.
    """
    import erfa

    table = erfa.leap_seconds.get()
    last = table[-1]
    key = (len(table), int(last["year"]), int(last["month"]), float(last["tai_utc"]))
    steps = _LEAP_CACHE.get(key)
    if steps is None:
        rows = table[table["year"] >= 1972]
        jd1, jd2 = erfa.cal2jd(rows["year"], rows["month"], 1)
        steps = (((jd1 - MJD_ZERO_JD) + jd2).tolist(), [float(v) for v in rows["tai_utc"]])
        _LEAP_CACHE.clear()
        _LEAP_CACHE[key] = steps
    return steps


def _tai_minus_utc_scalar(mjd: float) -> float:
    """TAI - UTC (s) at a UTC MJD >= 1972-01-01 (bisection in ERFA's table)."""
    mjds, values = _leap_steps()
    return values[max(bisect.bisect_right(mjds, mjd) - 1, 0)]


def _is_simple_utc_day(utc_jd1: float, utc_jd2: float) -> tuple[bool, float]:
    """``(True, TAI-UTC)`` for a UTC day since 1972 without a leap second at its end."""
    mjd = (utc_jd1 - MJD_ZERO_JD) + utc_jd2
    if not mjd >= _MJD_1972:
        return False, 0.0
    day = math.floor(mjd)
    dat0 = _tai_minus_utc_scalar(day)
    return dat0 == _tai_minus_utc_scalar(day + 1.0), dat0


def tt_jd_from_utc_jd(utc_jd1: float, utc_jd2: float) -> tuple[float, float]:
    """Two-part TT Julian date; equals ``erfa.utctai`` then ``erfa.taitt``.

    On ordinary days since 1972, TT = UTC + (TAI - UTC) + 32.184 s added to the second
    part (ERFA's result to ~1e-16 d); on leap-second days and before 1972, ERFA itself.
    """
    simple, dat = _is_simple_utc_day(utc_jd1, utc_jd2)
    if simple:
        return float(utc_jd1), float(utc_jd2) + (dat + _TT_MINUS_TAI_S) / 86400.0
    import erfa

    with quiet_dubious_year():
        tai1, tai2 = erfa.utctai(utc_jd1, utc_jd2)
    tt1, tt2 = erfa.taitt(tai1, tai2)
    return float(tt1), float(tt2)


def ut1_jd_from_utc_jd(utc_jd1: float, utc_jd2: float, dut1_s: float) -> tuple[float, float]:
    """Two-part UT1 Julian date from UTC and UT1 - UTC; equals ``erfa.utcut1``."""
    simple, _ = _is_simple_utc_day(utc_jd1, utc_jd2)
    if simple:
        return float(utc_jd1), float(utc_jd2) + float(dut1_s) / 86400.0
    import erfa

    with quiet_dubious_year():
        ut1, ut2 = erfa.utcut1(utc_jd1, utc_jd2, dut1_s)
    return float(ut1), float(ut2)


def tai_minus_utc_s(mjd_utc):
    """TAI - UTC (s) at UTC MJDs (scalar or array) from ERFA's leap-second table.

    Valid from 1960 on; since 1972 a whole number of seconds (fast lookup), before 1972
    ERFA's drift formulas.
    """
    mjd = np.asarray(mjd_utc, float)
    if mjd.ndim == 0 and float(mjd) >= _MJD_1972:
        return _tai_minus_utc_scalar(float(mjd))
    mjds, values = _leap_steps()
    out = np.asarray(values)[np.clip(np.searchsorted(mjds, mjd, side="right") - 1, 0, None)]
    early = mjd < _MJD_1972
    if np.any(early):
        import erfa

        day = np.floor(mjd[early])
        with quiet_dubious_year():
            iy, im, iday, _ = erfa.jd2cal(MJD_ZERO_JD, day)
            out = np.array(out, float)
            out[early] = erfa.dat(iy, im, iday, mjd[early] - day)
    return out


@functools.lru_cache(maxsize=1)
def leap_second_table_expiry_mjd() -> float:
    """UTC MJD up to which TAI - UTC is known (the expiry of astropy-iers-data's file).

    ``Leap_Second.dat`` states "File expires on DD Month YYYY".  If its leap seconds
    disagree with ERFA's built-in table (a newer astropy-iers-data that knows a leap
    second this ERFA does not), the date of the first disagreement is returned instead,
    since ERFA's TAI - UTC is wrong after it.
    """
    import erfa
    from astropy_iers_data import IERS_LEAP_SECOND_FILE

    with open(IERS_LEAP_SECOND_FILE, encoding="ascii", errors="replace") as fh:
        text = fh.read()
    m = re.search(r"expires on\s+(\d{1,2})\s+([A-Za-z]+)\s+(\d{4})", text)
    if m is None:
        raise ShipstarError(f"cannot find the expiry date in {IERS_LEAP_SECOND_FILE}")
    months = ["january", "february", "march", "april", "may", "june", "july", "august",
              "september", "october", "november", "december"]
    month = months.index(m[2].lower()) + 1
    jd1, jd2 = erfa.cal2jd(int(m[3]), month, int(m[1]))
    expiry_mjd = float(jd1 - MJD_ZERO_JD + jd2)
    rows = [line.split() for line in text.splitlines() if line.strip() and not line.startswith("#")]
    file_mjd = np.array([float(r[0]) for r in rows])
    file_tai_utc = np.array([float(r[4]) for r in rows])
    erfa_tai_utc = tai_minus_utc_s(file_mjd)
    bad = np.flatnonzero(np.abs(erfa_tai_utc - file_tai_utc) > 0.5)
    if bad.size:
        return float(file_mjd[bad[0]])
    return expiry_mjd


def utc_jd_now() -> tuple[float, float]:
    """The system clock's UTC now as a two-part Julian date ``(2440587.5, days since
    1970-01-01)`` (POSIX time has no leap seconds: as UTC everywhere but inside one)."""
    import time

    return 2440587.5, time.time() / 86400.0
