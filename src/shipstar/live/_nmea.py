"""NMEA 0183 sentences: shipstar's attitude and status out, the ship's navigation and
weather in.

Every sentence is ``$<address>,<field>,...,<field>*hh`` followed by CR LF, where ``hh``
is the XOR of all characters between ``$`` and ``*`` as two upper-case hexadecimal
digits (:func:`checksum`, :func:`sentence`).  Times are UTC; a time of day is
``hhmmss.ss...`` and a date ``ddmmyy``.  Empty fields mean "no value".

Sentences out (attitude, from shipstar)
---------------------------------------

``$PSSTA`` (proprietary, shipstar attitude at full precision)::

    $PSSTA,hhmmss.ssssss,ddmmyy,heading_deg,pitch_deg,roll_deg,
           sigma_heading_arcsec,sigma_pitch_arcsec,sigma_roll_arcsec,method,n_stars,A*hh

    1  UTC time of the epoch, to the microsecond
    2  UTC date of the epoch
    3  heading, deg, [0, 360), 6 decimals (0.0036'')     north toward east
    4  pitch, deg, 6 decimals, positive bow up
    5  roll, deg, 6 decimals, positive starboard side down
    6-8  1-sigma of heading, pitch, roll, arcsec, 2 decimals (empty: unknown)
    9  method: single, seed-rule, joint, ... (the attitude CSV's method column)
    10 number of stars used
    11 A = valid, V = not valid; with V fields 3-8 are empty

  With sensor-level precision it is longer than NMEA 0183's 82 characters (typically
  85-95): it is meant for shipstar-aware receivers over UDP, where a datagram carries it
  whole.  Receivers limited to 82 characters take ``$HEHDT`` and ``$PASHR``.

``$HEHDT`` (true heading, standard)::

    $HEHDT,HHH.HH,T*hh        heading in [0, 360), 2 decimals, zero-padded; T = true

``$PASHR`` (attitude in the layout of GNSS-INS attitude sensors, e.g. Hemisphere,
Applanix, Trimble; what pynmea2 reads as ``ASHRATT``)::

    $PASHR,hhmmss.sss,HHH.HH,T,+RRR.RR,+PPP.PP,,r.rrr,p.ppp,h.hhh,Q,S*hh

    1  UTC time of the epoch, to the millisecond
    2  true heading, deg, [0, 360), 2 decimals, zero-padded; 3  T (true)
    4  roll, deg, explicit sign, 2 decimals: positive starboard side down (port up)
    5  pitch, deg, explicit sign, 2 decimals: positive bow up
    6  heave: empty (shipstar does not measure it)
    7-9  1-sigma of roll, pitch, heading, deg, 3 decimals; a sigma below 0.0005 deg
       (1.8'', shipstar's usual) is written 0.001, never 0.000, since receivers read a
       zero accuracy as "unknown" or "perfect"; the full value is in $PSSTA
    10 Q, solution quality (pynmea2's ``aiding_status``):
         0 = no solution (fields 2, 4, 5, 7-9 empty),
         1 = one star sensor,
         2 = two or more sensors (the seeds' fusion rule or the joint solution)
    11 S, status of what the solution rests on (pynmea2's ``imu_status``):
         0 = no solution,
         1 = degraded: the solution carries an accuracy warning (e.g. Earth orientation
             extrapolated past the IERS tables, position extrapolated beyond a fix),
         2 = nominal

``$PSSTS`` (proprietary, shipstar health, once a second)::

    $PSSTS,hhmmss.ss,ddmmyy,N,name_1,in_1,out_1,lag_1_s,unsolved_1,...,
           name_N,in_N,out_N,lag_N_s,unsolved_N,eop,dut1_error_ms*hh

    1  UTC time of the report; 2  UTC date
    3  N, number of sensors; then 5 fields per sensor:
       name, frames received and frames processed (attitude out) since the previous
       $PSSTS, lag (s, 3 decimals: UTC now minus the time of the newest processed frame;
       empty if none yet), frames that did not solve since the previous $PSSTS
    4+5N  Earth orientation quality: M = measured, P = predicted, X = extrapolated
          (past the IERS tables: degraded), empty = unknown
    5+5N  estimated UT1-UTC error, ms, 3 decimals (1 ms turns azimuths by 0.015'');
          empty = unknown

  Sensor names are 1-16 characters of ``A-Z a-z 0-9 _ . -``.  Like $PSSTA it may pass
  82 characters.

Sentences in (navigation and weather, from the ship; formatters for replay and tests)
--------------------------------------------------------------------------------------

``GGA`` (fix)::

    $GPGGA,hhmmss.ss,ddmm.mmmmmm,N,dddmm.mmmmmm,E,q,nn,h.h,alt,M,sep,M,,*hh

  q fix quality (0 or empty: no fix, refused; 1-8 accepted), nn satellites, h.h HDOP,
  alt antenna altitude above mean sea level (m), sep geoidal separation (m, ellipsoid
  minus geoid).  Height above WGS84 = alt + sep (empty sep: 0; empty alt: 0 m, the
  height matters little for attitude).  No date: the receiver takes it from ZDA or RMC.
  :func:`gga` writes the ellipsoidal height as the altitude with separation 0.

``RMC`` (recommended minimum)::

    $GPRMC,hhmmss.ss,A,ddmm.mmmmmm,N,dddmm.mmmmmm,E,sog_kn,cog_deg,ddmmyy,,,A*hh

  status A = valid, V = void (refused); the mode indicator (field 12, NMEA 2.3) N = not
  valid is refused too.  Two-digit years 80-99 are 1980-1999, 00-79 are 2000-2079.

``ZDA`` (time and date)::

    $GPZDA,hhmmss.ss,dd,mm,yyyy,zh,zm*hh          zh, zm: local zone (ignored)

``MDA`` (meteorological composite)::

    $WIMDA,pp.pppp,I,p.ppppp,B,tt.tt,C,,,rh,,,,,,,,,,*hh

  barometric pressure in inches of mercury (field 1) and bar (field 3; preferred when
  both are given), air temperature C (field 5), relative humidity % (field 9).  The
  pressure is taken as the pressure at the sensors (docs/file-formats.md).

``XDR`` (transducer measurements, quadruplets ``type,value,unit,id``)::

    $WIXDR,P,1.02170,B,BARO,C,11.11,C,AIRT[,H,45.0,P,RHUM]*hh

  type P pressure (unit B bar or P pascal), C temperature (unit C, or K), H humidity
  (unit P, percent); other transducers are ignored, the first of each type is used.

MDA and XDR carry no time: the receiver stamps them (:mod:`shipstar.live._nav`).

Decoders check what makes no sense: latitude beyond 90 deg, longitude beyond 180,
minutes or seconds of arc or time out of range, dates that do not exist, fix quality 0,
RMC void, pressure outside 500-1200 hPa, temperature outside -80..+60 C, humidity
outside 0-100 %, and raise :class:`NmeaError` naming the sentence and the field.
"""

from __future__ import annotations

import datetime
import math
import re
from dataclasses import dataclass
from functools import reduce

from shipstar.errors import ShipstarError
from shipstar.limits import bounds

__all__ = [
    "NmeaError", "NmeaSentence", "SensorHealth", "GgaFix", "RmcFix", "ZdaTime", "WeatherReading",
    "checksum", "sentence", "parse",
    "pssta", "hehdt", "pashr", "pssts", "gga", "rmc", "zda", "mda", "xdr",
    "decode_gga", "decode_rmc", "decode_zda", "decode_mda", "decode_xdr",
    "utc_jd_from_date", "quote",
    "PASHR_Q_NONE", "PASHR_Q_SINGLE", "PASHR_Q_FUSED",
    "PASHR_S_NONE", "PASHR_S_DEGRADED", "PASHR_S_NOMINAL",
    "MAX_SENTENCE_CHARS", "PRESSURE_RANGE_HPA", "TEMPERATURE_RANGE_C",
]

#: NMEA 0183's longest sentence, ``$`` to CR LF included.
MAX_SENTENCE_CHARS = 82
#: Pressures and temperatures the decoders accept.
PRESSURE_RANGE_HPA = bounds("pressure_hpa")          # shipstar.limits: one set of ranges for every entry point
TEMPERATURE_RANGE_C = bounds("temperature_c")

#: $PASHR field Q: no solution, one sensor, two or more sensors.
PASHR_Q_NONE, PASHR_Q_SINGLE, PASHR_Q_FUSED = 0, 1, 2
#: $PASHR field S: no solution, degraded (accuracy warning), nominal.
PASHR_S_NONE, PASHR_S_DEGRADED, PASHR_S_NOMINAL = 0, 1, 2

_HPA_PER_INHG = 33.8638866667
_EOP_CODES = {"measured": "M", "predicted": "P", "extrapolated": "X"}
_NAME_RE = re.compile(r"^[A-Za-z0-9_.+\-]{1,16}$")       # '+': method stars+ins (INS, issue 15)
_TALKER_RE = re.compile(r"^[A-Z][A-Z0-9]$")
_ADDRESS_RE = re.compile(r"^(?:P(?P<ptype>[A-Z0-9]{3,})|(?P<talker>[A-Z][A-Z0-9])(?P<type>[A-Z]{3}))$")
_TIME_RE = re.compile(r"^(\d{2})(\d{2})(\d{2}(?:\.\d+)?)$")
_NUMBER_RE = re.compile(r"^[+-]?(?:\d+\.?\d*|\.\d+)$")


class NmeaError(ShipstarError):
    """A sentence that cannot be used; the message is one line.

    Attributes
    ----------
    kind : str
        What went wrong, for counting: ``empty``, ``non-ascii``, ``too-long``,
        ``no-start``, ``no-checksum``, ``checksum``, ``address``, ``type`` (a decoder given
        another sentence), ``value`` (a field that makes no sense), ``output`` (a value a
        formatter cannot write).
    """

    def __init__(self, message: str, kind: str = "value"):
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class NmeaSentence:
    """A checked sentence.

    Attributes
    ----------
    talker : str
        Two characters (``GP``, ``GN``, ``II``, ``WI``, ...), or ``P`` for a proprietary
        sentence.
    type : str
        ``GGA``, ``RMC``, ...; for a proprietary sentence the rest of the address
        (``SSTA`` for ``$PSSTA``, ``ASHR`` for ``$PASHR``).
    fields : tuple of str
        The fields after the address, in order (field 1 first).
    """

    talker: str
    type: str
    fields: tuple

    @property
    def address(self) -> str:
        return self.talker + self.type

    def field(self, number: int) -> str:
        """Field ``number`` (1-based, NMEA's numbering); ``""`` when the sentence is shorter."""
        return self.fields[number - 1] if 0 < number <= len(self.fields) else ""


@dataclass(frozen=True)
class SensorHealth:
    """One sensor's line of ``$PSSTS`` (counts since the previous status sentence).

    Attributes
    ----------
    name : str
        Sensor name, 1-16 characters of ``A-Z a-z 0-9 _ . -``.
    frames_in, frames_out, unsolved : int
        Frames received, frames processed (attitude out), frames that did not solve.
    lag_s : float or None
        UTC now minus the time of the newest processed frame; None (or NaN) if none yet.
    """

    name: str
    frames_in: int
    frames_out: int
    lag_s: float | None
    unsolved: int


@dataclass(frozen=True)
class GgaFix:
    """A decoded GGA: a position at a time of day (GGA has no date).

    Attributes
    ----------
    utc_time_of_day_s : float
        Seconds since 00:00 UTC (86400 and above inside a leap second).
    lat_deg, lon_deg : float
        Geodetic latitude (north positive) and longitude (east positive), deg.
    height_m : float
        Height above the WGS84 ellipsoid (altitude + geoidal separation).
    quality : int
        Fix quality, 1-8 (1 GPS, 2 DGPS, 4 RTK fixed, 5 RTK float, 6 estimated, ...).
    n_satellites : int or None
    hdop : float or None
    """

    utc_time_of_day_s: float
    lat_deg: float
    lon_deg: float
    height_m: float
    quality: int
    n_satellites: int | None
    hdop: float | None


@dataclass(frozen=True)
class RmcFix:
    """A decoded, valid RMC: a dated position.

    Attributes
    ----------
    utc_jd1, utc_jd2 : float
        Two-part UTC Julian date of the fix.
    utc_date : datetime.date
    utc_time_of_day_s : float
    lat_deg, lon_deg : float
    speed_kn, course_deg : float or None
        Speed and true course over ground.
    """

    utc_jd1: float
    utc_jd2: float
    utc_date: datetime.date
    utc_time_of_day_s: float
    lat_deg: float
    lon_deg: float
    speed_kn: float | None
    course_deg: float | None


@dataclass(frozen=True)
class ZdaTime:
    """A decoded ZDA.

    Attributes
    ----------
    utc_jd1, utc_jd2 : float
        Two-part UTC Julian date.
    utc_date : datetime.date
    utc_time_of_day_s : float
    zone_offset_min : int or None
        Local zone (hours * 60 + minutes), for information only.
    """

    utc_jd1: float
    utc_jd2: float
    utc_date: datetime.date
    utc_time_of_day_s: float
    zone_offset_min: int | None


@dataclass(frozen=True)
class WeatherReading:
    """What an MDA or XDR gave; None for what it did not give.

    Attributes
    ----------
    pressure_hpa : float or None
    temperature_c : float or None
    relative_humidity : float or None
        Fraction 0..1 (as :class:`shipstar.sky.refraction.Weather` takes it).
    """

    pressure_hpa: float | None
    temperature_c: float | None
    relative_humidity: float | None


# -- checksums and framing ---------------------------------------------------------------

def checksum(body: str) -> str:
    """XOR of the characters of ``body`` (what lies between ``$`` and ``*``), as two
    upper-case hexadecimal digits.

    Examples
    --------
    >>> checksum("HEHDT,046.47,T")
    '1E'
    """
    return f"{reduce(lambda acc, ch: acc ^ ord(ch), body, 0):02X}"


def sentence(body: str) -> str:
    """``"$" + body + "*" + checksum(body) + "\\r\\n"``.

    Raises
    ------
    NmeaError
        ``body`` has a character that may not appear inside a sentence (non-ASCII,
        control, ``$``, ``*``, ``!``).
    """
    for ch in body:
        if not 32 <= ord(ch) <= 126 or ch in "$*!":
            raise NmeaError(f"cannot write {ch!r} inside an NMEA sentence: {quote(body)}", "output")
    return "$" + body + "*" + checksum(body) + "\r\n"


def quote(text: str, max_chars: int = 60) -> str:
    """``text`` for a one-line message: quoted, escaped to ASCII, cut after ``max_chars``."""
    text = str(text)
    cut = text if len(text) <= max_chars else text[:max_chars] + "..."
    return "'" + repr(cut)[1:-1].encode("ascii", "backslashreplace").decode("ascii") + "'"


def parse(line: str, max_chars: int | None = MAX_SENTENCE_CHARS) -> NmeaSentence:
    """Check one sentence and split it into its fields.

    Parameters
    ----------
    line : str
        ``$...*hh``, with or without the CR LF (surrounding white space is ignored).
        ``bytes`` are taken as Latin-1 (so non-ASCII bytes are reported, not decoded).
    max_chars : int or None
        Longest sentence accepted, ``$`` to CR LF included; NMEA 0183 says 82.  None: no
        limit (shipstar's own proprietary sentences may be longer).

    Returns
    -------
    NmeaSentence

    Raises
    ------
    NmeaError
        One line naming the problem and quoting the sentence: empty, non-ASCII or control
        characters, too long, no ``$`` at the start, missing checksum (with the expected
        one), bad checksum (expected vs got), bad address.
    """
    if isinstance(line, (bytes, bytearray)):
        line = bytes(line).decode("latin-1")
    if not isinstance(line, str):
        raise NmeaError(f"an NMEA sentence must be text, got {type(line).__name__}", "empty")
    text = line.strip(" \t\r\n")
    if not text:
        raise NmeaError("empty sentence", "empty")
    for pos, ch in enumerate(text):
        if not 32 <= ord(ch) <= 126:
            raise NmeaError(f"non-ASCII or control character {ch!r} at position {pos + 1} in {quote(text)}",
                            "non-ascii")
    if max_chars is not None and len(text) + 2 > max_chars:
        raise NmeaError(f"sentence too long: {len(text) + 2} characters with CR LF, NMEA 0183 allows "
                        f"{max_chars}, in {quote(text)}", "too-long")
    if not text.startswith("$"):
        raise NmeaError(f"no '$' at the start of {quote(text)}", "no-start")
    star = text.rfind("*")
    if star < 0:
        raise NmeaError(f"missing checksum in {quote(text)} (expected *{checksum(text[1:])} at the end)",
                        "no-checksum")
    body, got = text[1:star], text[star + 1:]
    expected = checksum(body)
    if not re.fullmatch(r"[0-9A-Fa-f]{2}", got):
        raise NmeaError(f"bad checksum field '*{got}' in {quote(text)} (expected {expected})", "no-checksum")
    if got.upper() != expected:
        raise NmeaError(f"bad checksum in {quote(text)} (expected {expected}, got {got})", "checksum")
    if "$" in body or "*" in body or "!" in body:
        raise NmeaError(f"stray '$', '*' or '!' inside {quote(text)}", "address")
    parts = body.split(",")
    m = _ADDRESS_RE.match(parts[0])
    if m is None:
        raise NmeaError(f"bad address {parts[0]!r} in {quote(text)} (expected e.g. GPGGA, or P + maker + type)",
                        "address")
    if m["ptype"] is not None:
        return NmeaSentence("P", m["ptype"], tuple(parts[1:]))
    return NmeaSentence(m["talker"], m["type"], tuple(parts[1:]))


# -- formatting helpers ------------------------------------------------------------------

def _finite(value, what: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise NmeaError(f"{what} must be a number, got {value!r}", "output") from None
    if not math.isfinite(x):
        raise NmeaError(f"{what} must be finite, got {value!r}", "output")
    return x


def _missing(value) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value))


def _fixed(x: float, ndp: int, sign: bool = False, int_digits: int = 1) -> str:
    """``x`` to ``ndp`` decimals, zero-padded to ``int_digits`` digits before the point;
    a value that rounds to zero is written without a minus sign."""
    text = f"{x:.{ndp}f}"
    if float(text) == 0.0:
        x = 0.0
    width = int_digits + (ndp + 1 if ndp else 0) + (1 if sign or x < 0 else 0)
    return f"{x:{'+' if sign else ''}0{width}.{ndp}f}"


def _heading(heading_deg, ndp: int, int_digits: int = 1, what: str = "heading_deg") -> str:
    """Heading in [0, 360) to ``ndp`` decimals: 359.9999999 is written as 0, never 360."""
    h = _finite(heading_deg, what) % 360.0
    text = _fixed(h, ndp, int_digits=int_digits)
    if float(text) >= 360.0:
        text = _fixed(0.0, ndp, int_digits=int_digits)
    return text


def _utc_text(utc_jd1: float, utc_jd2: float, ndp: int):
    """``(hhmmss.s..., ddmmyy, (y, m, d))`` of a two-part UTC JD, rounded to ``ndp`` decimals
    of a second (ERFA carries the rounding into minutes, hours and days)."""
    import erfa

    from shipstar.sky.time import quiet_dubious_year

    jd1, jd2 = _finite(utc_jd1, "utc_jd1"), _finite(utc_jd2, "utc_jd2")
    try:
        with quiet_dubious_year():
            iy, im, iday, ihmsf = erfa.d2dtf("UTC", ndp, jd1, jd2)
    except erfa.ErfaError as exc:
        raise NmeaError(f"cannot write the time {jd1} + {jd2} (JD): {exc}", "output") from None
    h, mi, s, f = (int(v) for v in ihmsf)
    frac = f".{f:0{ndp}d}" if ndp else ""
    return (f"{h:02d}{mi:02d}{s:02d}{frac}", f"{int(iday):02d}{int(im):02d}{int(iy) % 100:02d}",
            (int(iy), int(im), int(iday)))


def _latlon(lat_deg, lon_deg, ndp: int = 6) -> str:
    """``ddmm.mmmmmm,N,dddmm.mmmmmm,E`` (minutes to ``ndp`` decimals, carried exactly)."""
    lat = _finite(lat_deg, "lat_deg")
    lon = _finite(lon_deg, "lon_deg")
    if abs(lat) > 90.0:
        raise NmeaError(f"latitude {lat:g} deg is beyond 90", "output")
    lon = math.remainder(lon, 360.0)
    if lon == -180.0:
        lon = 180.0
    out = []
    for value, deg_digits, hemis in ((lat, 2, "NS"), (lon, 3, "EW")):
        scale = 10 ** ndp
        total = round(abs(value) * 60.0 * scale)                  # in 10^-ndp minutes
        deg, rest = divmod(total, 60 * scale)
        minutes = f"{rest // scale:02d}.{rest % scale:0{ndp}d}"
        hemi = hemis[0] if value >= 0 or total == 0 else hemis[1]
        out.append(f"{deg:0{deg_digits}d}{minutes},{hemi}")
    return ",".join(out)


def _talker(talker: str) -> str:
    if not isinstance(talker, str) or not _TALKER_RE.match(talker):
        raise NmeaError(f"talker must be two upper-case characters, got {talker!r}", "output")
    return talker


def _count(value, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise NmeaError(f"{what} must be a whole number >= 0, got {value!r}", "output")
    return value


def _name(value, what: str) -> str:
    if not isinstance(value, str) or not _NAME_RE.match(value):
        raise NmeaError(f"{what} must be 1-16 characters of A-Z a-z 0-9 _ . + -, got {value!r}", "output")
    return value


# -- sentences out -----------------------------------------------------------------------

def pssta(utc_jd1: float, utc_jd2: float, heading_deg: float, pitch_deg: float, roll_deg: float,
          sigma_heading_arcsec: float, sigma_pitch_arcsec: float, sigma_roll_arcsec: float,
          method: str, n_stars: int, valid: bool) -> str:
    """``$PSSTA``: shipstar's attitude at full precision (layout in the module docstring).

    Parameters
    ----------
    utc_jd1, utc_jd2 : float
        The epoch, two-part UTC Julian date (written to the microsecond).
    heading_deg, pitch_deg, roll_deg : float
        Ship attitude (docs/conventions.md); ignored when ``valid`` is False.
    sigma_heading_arcsec, sigma_pitch_arcsec, sigma_roll_arcsec : float or None
        1-sigma; None or NaN writes an empty field.
    method : str
        ``single``, ``seed-rule``, ``joint``, ...
    n_stars : int
        Stars used.
    valid : bool
        A: the attitude is valid; V: not (angle and sigma fields empty).

    Returns
    -------
    str
        The sentence with CR LF.
    """
    hms, dmy, _ = _utc_text(utc_jd1, utc_jd2, 6)
    method = _name(method, "method")
    n_stars = _count(n_stars, "n_stars")
    if valid:
        pitch = _finite(pitch_deg, "pitch_deg")
        if abs(pitch) > 90.0:
            raise NmeaError(f"pitch {pitch:g} deg is beyond 90", "output")
        angles = [_heading(heading_deg, 6), _fixed(pitch, 6), _fixed(math.remainder(_finite(roll_deg, "roll_deg"),
                                                                                    360.0), 6)]
        sigmas = ["" if _missing(s) else _fixed(abs(_finite(s, name)), 2)
                  for s, name in ((sigma_heading_arcsec, "sigma_heading_arcsec"),
                                  (sigma_pitch_arcsec, "sigma_pitch_arcsec"),
                                  (sigma_roll_arcsec, "sigma_roll_arcsec"))]
    else:
        angles, sigmas = ["", "", ""], ["", "", ""]
    return sentence(",".join(["PSSTA", hms, dmy, *angles, *sigmas, method, str(n_stars), "A" if valid else "V"]))


def hehdt(heading_deg: float) -> str:
    """``$HEHDT,HHH.HH,T``: true heading, 2 decimals, wrapped into [0, 360).

    Examples
    --------
    >>> hehdt(359.999999)
    '$HEHDT,000.00,T*1F\\r\\n'
    """
    return sentence(f"HEHDT,{_heading(heading_deg, 2, 3)},T")


def _sigma_deg(value, what: str) -> str:
    if _missing(value):
        return ""
    s = abs(_finite(value, what))
    return "0.001" if 0.0 < s < 0.0005 else _fixed(s, 3)


def pashr(utc_jd1: float, utc_jd2: float, heading_deg: float, roll_deg: float, pitch_deg: float,
          sigma_roll_deg: float, sigma_pitch_deg: float, sigma_heading_deg: float,
          quality: int, ins_status: int) -> str:
    """``$PASHR``: attitude in the layout of GNSS-INS attitude sensors (module docstring).

    Parameters
    ----------
    utc_jd1, utc_jd2 : float
        The epoch (written to the millisecond).
    heading_deg, roll_deg, pitch_deg : float or None
        Ship attitude (roll positive starboard down, pitch positive bow up); ignored, and
        written empty, when ``quality`` is 0.
    sigma_roll_deg, sigma_pitch_deg, sigma_heading_deg : float or None
        1-sigma in degrees (None or NaN: empty).
    quality : int
        Q: 0 no solution, 1 one sensor, 2 two or more sensors (``PASHR_Q_*``).
    ins_status : int
        S: 0 no solution, 1 degraded (accuracy warning), 2 nominal (``PASHR_S_*``).

    Returns
    -------
    str
        The sentence with CR LF.
    """
    if quality not in (PASHR_Q_NONE, PASHR_Q_SINGLE, PASHR_Q_FUSED) or isinstance(quality, bool):
        raise NmeaError(f"PASHR quality must be 0, 1 or 2, got {quality!r}", "output")
    if ins_status not in (PASHR_S_NONE, PASHR_S_DEGRADED, PASHR_S_NOMINAL) or isinstance(ins_status, bool):
        raise NmeaError(f"PASHR status must be 0, 1 or 2, got {ins_status!r}", "output")
    hms, _, _ = _utc_text(utc_jd1, utc_jd2, 3)
    if quality == PASHR_Q_NONE:
        heading = roll = pitch = s_r = s_p = s_h = ""
    else:
        heading = _heading(heading_deg, 2, 3)
        r = math.remainder(_finite(roll_deg, "roll_deg"), 360.0)
        p = _finite(pitch_deg, "pitch_deg")
        if abs(p) > 90.0:
            raise NmeaError(f"pitch {p:g} deg is beyond 90", "output")
        roll, pitch = _fixed(r, 2, sign=True, int_digits=3), _fixed(p, 2, sign=True, int_digits=3)
        s_r, s_p, s_h = (_sigma_deg(sigma_roll_deg, "sigma_roll_deg"), _sigma_deg(sigma_pitch_deg, "sigma_pitch_deg"),
                         _sigma_deg(sigma_heading_deg, "sigma_heading_deg"))
    return sentence(f"PASHR,{hms},{heading},T,{roll},{pitch},,{s_r},{s_p},{s_h},{quality},{ins_status}")


def pssts(utc_jd1: float, utc_jd2: float, sensors, eop_quality: str | None = None,
          dut1_error_s: float | None = None) -> str:
    """``$PSSTS``: shipstar's once-a-second health (layout in the module docstring).

    Parameters
    ----------
    utc_jd1, utc_jd2 : float
        Time of the report (written to 0.01 s).
    sensors : sequence of SensorHealth (or of ``(name, frames_in, frames_out, lag_s,
        unsolved)`` tuples)
        One entry per sensor, at least one.
    eop_quality : str or None
        ``measured``, ``predicted``, ``extrapolated`` (:mod:`shipstar.sky.eop`), or None.
    dut1_error_s : float or None
        Estimated UT1 - UTC error (s), written in ms.

    Returns
    -------
    str
        The sentence with CR LF.
    """
    hms, dmy, _ = _utc_text(utc_jd1, utc_jd2, 2)
    sensors = [s if isinstance(s, SensorHealth) else SensorHealth(*s) for s in sensors]
    if not sensors:
        raise NmeaError("PSSTS needs at least one sensor", "output")
    fields = ["PSSTS", hms, dmy, str(len(sensors))]
    for s in sensors:
        lag = "" if _missing(s.lag_s) else _fixed(_finite(s.lag_s, f"lag_s of {s.name}"), 3)
        fields += [_name(s.name, "sensor name"), str(_count(s.frames_in, "frames_in")),
                   str(_count(s.frames_out, "frames_out")), lag, str(_count(s.unsolved, "unsolved"))]
    if eop_quality is None or eop_quality == "":
        code = ""
    elif eop_quality in _EOP_CODES:
        code = _EOP_CODES[eop_quality]
    else:
        raise NmeaError(f"eop_quality must be one of {', '.join(_EOP_CODES)} or None, got {eop_quality!r}", "output")
    dut1 = "" if _missing(dut1_error_s) else _fixed(abs(_finite(dut1_error_s, "dut1_error_s")) * 1e3, 3)
    return sentence(",".join(fields + [code, dut1]))


def gga(utc_jd1: float, utc_jd2: float, lat_deg: float, lon_deg: float, height_m: float = 0.0, *,
        quality: int = 1, n_satellites: int = 12, hdop: float = 0.9, talker: str = "GP") -> str:
    """``$GPGGA`` fix at a time (time of day to 0.01 s, minutes of arc to 1e-6).

    The ellipsoidal ``height_m`` is written as the altitude with a geoidal separation of
    0, so :func:`decode_gga` gives it back.
    """
    hms, _, _ = _utc_text(utc_jd1, utc_jd2, 2)
    if quality not in range(0, 9) or isinstance(quality, bool):
        raise NmeaError(f"GGA quality must be 0-8, got {quality!r}", "output")
    height = _finite(height_m, "height_m")
    return sentence(f"{_talker(talker)}GGA,{hms},{_latlon(lat_deg, lon_deg)},{quality},"
                    f"{_count(n_satellites, 'n_satellites'):02d},{_fixed(_finite(hdop, 'hdop'), 1)},"
                    f"{_fixed(height, 3)},M,0.000,M,,")


def rmc(utc_jd1: float, utc_jd2: float, lat_deg: float, lon_deg: float, speed_kn: float = 0.0,
        course_deg: float = 0.0, *, valid: bool = True, talker: str = "GP") -> str:
    """``$GPRMC``: dated fix (status A, or V when ``valid`` is False), mode indicator A."""
    hms, dmy, _ = _utc_text(utc_jd1, utc_jd2, 2)
    speed = _fixed(abs(_finite(speed_kn, "speed_kn")), 2)
    course = _heading(course_deg, 2, what="course_deg")
    return sentence(f"{_talker(talker)}RMC,{hms},{'A' if valid else 'V'},{_latlon(lat_deg, lon_deg)},"
                    f"{speed},{course},{dmy},,,{'A' if valid else 'N'}")


def zda(utc_jd1: float, utc_jd2: float, *, talker: str = "GP") -> str:
    """``$GPZDA,hhmmss.ss,dd,mm,yyyy,00,00``: UTC time and date."""
    hms, _, (y, m, d) = _utc_text(utc_jd1, utc_jd2, 2)
    return sentence(f"{_talker(talker)}ZDA,{hms},{d:02d},{m:02d},{y:04d},00,00")


def mda(pressure_hpa: float, temperature_c: float, relative_humidity: float | None = None, *,
        talker: str = "WI") -> str:
    """``$WIMDA``: pressure (inHg to 1e-4, bar to 1e-5 = 0.01 hPa), air temperature (0.01 C),
    relative humidity (fraction 0..1, written in %; None: empty).  MDA has no time."""
    p = _finite(pressure_hpa, "pressure_hpa")
    t = _finite(temperature_c, "temperature_c")
    rh = "" if _missing(relative_humidity) else _fixed(100.0 * _finite(relative_humidity, "relative_humidity"), 1)
    return sentence(f"{_talker(talker)}MDA,{_fixed(p / _HPA_PER_INHG, 4)},I,{_fixed(p / 1000.0, 5)},B,"
                    f"{_fixed(t, 2)},C,,,{rh},,,,,,,,,,,")


def xdr(pressure_hpa: float, temperature_c: float, relative_humidity: float | None = None, *,
        talker: str = "WI") -> str:
    """``$WIXDR,P,<bar>,B,BARO,C,<C>,C,AIRT[,H,<%>,P,RHUM]``: pressure in bar (1e-5 =
    0.01 hPa), air temperature in C (0.01), optional relative humidity (fraction 0..1,
    written in %).  XDR has no time."""
    p = _finite(pressure_hpa, "pressure_hpa")
    t = _finite(temperature_c, "temperature_c")
    body = f"{_talker(talker)}XDR,P,{_fixed(p / 1000.0, 5)},B,BARO,C,{_fixed(t, 2)},C,AIRT"
    if not _missing(relative_humidity):
        body += f",H,{_fixed(100.0 * _finite(relative_humidity, 'relative_humidity'), 1)},P,RHUM"
    return sentence(body)


# -- decoding ----------------------------------------------------------------------------

def _as_sentence(s, stype: str) -> NmeaSentence:
    if not isinstance(s, NmeaSentence):
        s = parse(s)
    if s.type != stype:
        raise NmeaError(f"expected a {stype} sentence, got {s.address}", "type")
    return s


def _bad(stype: str, number: int, what: str, problem: str) -> NmeaError:
    return NmeaError(f"{stype} field {number} ({what}): {problem}", "value")


def _num(s: NmeaSentence, number: int, what: str, required: bool = True) -> float | None:
    text = s.field(number).strip()
    if text == "":
        if required:
            raise _bad(s.type, number, what, "empty")
        return None
    if not _NUMBER_RE.match(text):
        raise _bad(s.type, number, what, f"{text!r} is not a number")
    return float(text)


def _time_of_day(s: NmeaSentence, number: int) -> float:
    text = s.field(number).strip()
    m = _TIME_RE.match(text)
    if m is None:
        raise _bad(s.type, number, "UTC time", f"{text!r} is not hhmmss[.ss]" if text else "empty")
    h, mi, sec = int(m[1]), int(m[2]), float(m[3])
    if h > 23:
        raise _bad(s.type, number, "UTC time", f"hour {h} is not below 24")
    if mi > 59:
        raise _bad(s.type, number, "UTC time", f"minute {mi} is not below 60")
    if sec >= 61.0 or (sec >= 60.0 and (h, mi) != (23, 59)):
        raise _bad(s.type, number, "UTC time", f"second {m[3]} is out of range")
    return h * 3600.0 + mi * 60.0 + sec


def _angle(s: NmeaSentence, number: int, is_lat: bool) -> float:
    what = "latitude" if is_lat else "longitude"
    text = s.field(number).strip()
    hemi = s.field(number + 1).strip()
    if text == "":
        raise _bad(s.type, number, what, "empty (no fix)")
    if not re.fullmatch(r"\d+(?:\.\d*)?", text):
        raise _bad(s.type, number, what, f"{text!r} is not {'dd' if is_lat else 'ddd'}mm.mmmm")
    dot = text.find(".")
    split = (dot if dot >= 0 else len(text)) - 2
    if split < 1:
        raise _bad(s.type, number, what, f"{text!r} is not {'dd' if is_lat else 'ddd'}mm.mmmm")
    deg, minutes = int(text[:split]), float(text[split:])
    limit = 90 if is_lat else 180
    if minutes >= 60.0:
        raise _bad(s.type, number, what, f"{minutes:g} minutes is not below 60")
    value = deg + minutes / 60.0
    if value > limit:
        raise _bad(s.type, number, what, f"{value:.6g} deg is beyond {limit}")
    good = "NS" if is_lat else "EW"
    if hemi not in good:
        raise _bad(s.type, number + 1, f"{what} direction", f"{hemi!r} is not {good[0]} or {good[1]}")
    return -value if hemi == good[1] else value


def _date(stype: str, number: str, y: int, m: int, d: int) -> datetime.date:
    try:
        return datetime.date(y, m, d)
    except ValueError:
        raise NmeaError(f"{stype} field {number} (UTC date): {y:04d}-{m:02d}-{d:02d} does not exist",
                        "value") from None


def utc_jd_from_date(utc_date: datetime.date, utc_time_of_day_s: float) -> tuple[float, float]:
    """Two-part UTC Julian date of a date and a time of day (s since 00:00 UTC; 86400 and
    above only inside a leap second).

    Raises
    ------
    NmeaError
        A time that does not exist (e.g. a second 60 on a day without a leap second).
    """
    from shipstar.sky.time import utc_jd_from_iso

    us = round(float(utc_time_of_day_s) * 1e6)
    if us >= 86_400_000_000:                                   # inside a leap second
        h, mi, sec_us = 23, 59, us - 86_340_000_000
    else:
        h, rest = divmod(us, 3_600_000_000)
        mi, sec_us = divmod(rest, 60_000_000)
    text = (f"{utc_date.year:04d}-{utc_date.month:02d}-{utc_date.day:02d}T{h:02d}:{mi:02d}:"
            f"{sec_us // 1_000_000:02d}.{sec_us % 1_000_000:06d}")
    try:
        return utc_jd_from_iso(text)
    except ShipstarError as exc:
        raise NmeaError(str(exc), "value") from None


def decode_gga(s: NmeaSentence | str) -> GgaFix:
    """A GGA's fix (layout in the module docstring).

    Raises
    ------
    NmeaError
        Not a GGA; fix quality empty or 0 (no fix) or not 0-8; a bad time, latitude,
        longitude (naming the field), altitude, or altitude unit other than M.
    """
    s = _as_sentence(s, "GGA")
    q_text = s.field(6).strip()
    if q_text in ("", "0"):
        raise _bad("GGA", 6, "fix quality", f"{q_text or 'empty'}, no fix")
    if not q_text.isdigit() or not 1 <= int(q_text) <= 8:
        raise _bad("GGA", 6, "fix quality", f"{q_text!r} is not 0-8")
    tod = _time_of_day(s, 1)
    lat, lon = _angle(s, 2, True), _angle(s, 4, False)
    n_sat = s.field(7).strip()
    if n_sat and not n_sat.isdigit():
        raise _bad("GGA", 7, "satellites", f"{n_sat!r} is not a count")
    hdop = _num(s, 8, "HDOP", required=False)
    alt = _num(s, 9, "altitude", required=False)
    if alt is not None and s.field(10).strip() not in ("M", ""):
        raise _bad("GGA", 10, "altitude unit", f"{s.field(10)!r} is not M")
    sep = _num(s, 11, "geoidal separation", required=False)
    height = (alt or 0.0) + (sep or 0.0)
    if not -1000.0 <= height <= 10000.0:
        raise _bad("GGA", 9, "altitude", f"height {height:g} m is outside -1000..10000 m")
    return GgaFix(tod, lat, lon, height, int(q_text), int(n_sat) if n_sat else None, hdop)


def decode_rmc(s: NmeaSentence | str) -> RmcFix:
    """A valid RMC's dated fix (layout in the module docstring).

    Raises
    ------
    NmeaError
        Not an RMC; status V (void) or other than A; mode indicator N; a bad time,
        position, speed, course or date (one that does not exist).
    """
    s = _as_sentence(s, "RMC")
    status = s.field(2).strip()
    if status == "V":
        raise _bad("RMC", 2, "status", "V, void (no valid fix)")
    if status != "A":
        raise _bad("RMC", 2, "status", f"{status or 'empty'!r} is not A or V")
    if s.field(12).strip() == "N":
        raise _bad("RMC", 12, "mode", "N, data not valid")
    tod = _time_of_day(s, 1)
    lat, lon = _angle(s, 3, True), _angle(s, 5, False)
    speed = _num(s, 7, "speed over ground", required=False)
    course = _num(s, 8, "course over ground", required=False)
    if course is not None and not 0.0 <= course <= 360.0:
        raise _bad("RMC", 8, "course over ground", f"{course:g} deg is outside 0-360")
    dtext = s.field(9).strip()
    if not re.fullmatch(r"\d{6}", dtext):
        raise _bad("RMC", 9, "UTC date", f"{dtext!r} is not ddmmyy" if dtext else "empty")
    yy = int(dtext[4:6])
    date = _date("RMC", "9", yy + (1900 if yy >= 80 else 2000), int(dtext[2:4]), int(dtext[0:2]))
    jd1, jd2 = utc_jd_from_date(date, tod)
    return RmcFix(jd1, jd2, date, tod, lat, lon, speed, course)


def decode_zda(s: NmeaSentence | str) -> ZdaTime:
    """A ZDA's UTC date and time.

    Raises
    ------
    NmeaError
        Not a ZDA; a bad time; a day, month or year missing or a date that does not exist.
    """
    s = _as_sentence(s, "ZDA")
    tod = _time_of_day(s, 1)
    parts = []
    for number, what, pattern in ((2, "day", r"\d{1,2}"), (3, "month", r"\d{1,2}"), (4, "year", r"\d{4}")):
        text = s.field(number).strip()
        if not re.fullmatch(pattern, text):
            raise _bad("ZDA", number, what, f"{text!r} is not a {what}" if text else "empty")
        parts.append(int(text))
    d, m, y = parts
    date = _date("ZDA", "2-4", y, m, d)
    zone = None
    zh, zm = _num(s, 5, "local zone hours", required=False), _num(s, 6, "local zone minutes", required=False)
    if zh is not None:
        zone = int(zh) * 60 + (-1 if zh < 0 else 1) * int(abs(zm or 0.0))
    jd1, jd2 = utc_jd_from_date(date, tod)
    return ZdaTime(jd1, jd2, date, tod, zone)


def _check_weather(stype: str, pressure_hpa, temperature_c, humidity_pct, field_numbers) -> WeatherReading:
    """Range checks; ``field_numbers``: where pressure, temperature, humidity were."""
    p_field, t_field, h_field = field_numbers
    if pressure_hpa is not None:
        lo, hi = PRESSURE_RANGE_HPA
        if not lo <= pressure_hpa <= hi:
            raise _bad(stype, p_field, "pressure", f"{pressure_hpa:g} hPa is outside {lo:g}-{hi:g} hPa")
    if temperature_c is not None:
        lo, hi = TEMPERATURE_RANGE_C
        if not lo <= temperature_c <= hi:
            raise _bad(stype, t_field, "air temperature", f"{temperature_c:g} C is outside {lo:+g}..{hi:+g} C")
    if humidity_pct is not None and not 0.0 <= humidity_pct <= 100.0:
        raise _bad(stype, h_field, "relative humidity", f"{humidity_pct:g} % is outside 0-100 %")
    if pressure_hpa is None and temperature_c is None and humidity_pct is None:
        raise NmeaError(f"{stype}: no pressure, air temperature or humidity in it", "value")
    return WeatherReading(pressure_hpa, temperature_c, None if humidity_pct is None else humidity_pct / 100.0)


def decode_mda(s: NmeaSentence | str) -> WeatherReading:
    """An MDA's pressure (bar field preferred to inHg), air temperature and humidity.

    Raises
    ------
    NmeaError
        Not an MDA; a unit letter other than I, B, C; pressure outside 500-1200 hPa
        (negative or 0 included), temperature outside -80..+60 C, humidity outside
        0-100 %; none of the three given.
    """
    s = _as_sentence(s, "MDA")
    p_field = 3
    p_bar = _num(s, 3, "pressure, bar", required=False)
    if p_bar is not None:
        if s.field(4).strip() != "B":
            raise _bad("MDA", 4, "pressure unit", f"{s.field(4)!r} is not B")
        pressure = p_bar * 1000.0
    else:
        p_inhg = _num(s, 1, "pressure, inHg", required=False)
        p_field = 1
        if p_inhg is not None and s.field(2).strip() != "I":
            raise _bad("MDA", 2, "pressure unit", f"{s.field(2)!r} is not I")
        pressure = None if p_inhg is None else p_inhg * _HPA_PER_INHG
    temp = _num(s, 5, "air temperature", required=False)
    if temp is not None and s.field(6).strip() != "C":
        raise _bad("MDA", 6, "air temperature unit", f"{s.field(6)!r} is not C")
    rh = _num(s, 9, "relative humidity", required=False)
    return _check_weather("MDA", pressure, temp, rh, (p_field, 5, 9))


def decode_xdr(s: NmeaSentence | str) -> WeatherReading:
    """An XDR's first pressure (P: B bar or P pascal), temperature (C: C or K) and humidity
    (H: P percent) transducers; other transducer types are ignored.

    Raises
    ------
    NmeaError
        Not an XDR; fields not in groups of four; a unit that does not fit its type; values
        out of range (as :func:`decode_mda`); none of the three present.
    """
    s = _as_sentence(s, "XDR")
    if len(s.fields) % 4:
        raise NmeaError(f"XDR: {len(s.fields)} fields, not groups of four (type, value, unit, id)", "value")
    pressure = temp = rh = None
    where = [0, 0, 0]
    for k in range(0, len(s.fields), 4):
        ttype, unit = s.fields[k].strip(), s.fields[k + 2].strip()
        number = k + 2
        if ttype not in ("P", "C", "H") or s.fields[k + 1].strip() == "":
            continue
        value = _num(s, number, f"transducer {ttype} value")
        if ttype == "P" and pressure is None:
            scale = {"B": 1000.0, "P": 0.01}.get(unit)
            if scale is None:
                raise _bad("XDR", number + 1, "pressure unit", f"{unit!r} is not B (bar) or P (pascal)")
            pressure, where[0] = value * scale, number
        elif ttype == "C" and temp is None:
            offset = {"C": 0.0, "K": -273.15}.get(unit)
            if offset is None:
                raise _bad("XDR", number + 1, "temperature unit", f"{unit!r} is not C or K")
            temp, where[1] = value + offset, number
        elif ttype == "H" and rh is None:
            if unit != "P":
                raise _bad("XDR", number + 1, "humidity unit", f"{unit!r} is not P (percent)")
            rh, where[2] = value, number
    return _check_weather("XDR", pressure, temp, rh, tuple(where))
