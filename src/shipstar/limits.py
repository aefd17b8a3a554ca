"""Physical ranges of every input, in one place, and the one parser of angles in degrees.

Every entry point (command-line flags, TOML files, CSV tables, NMEA sentences, FITS
header values used as inputs) checks a value against the same :data:`RANGES` with
:func:`check_range`, which refuses a value outside in one line naming the value, the
range and why the range is what it is::

    pressure_hpa must be within [500, 1100] hPa (station pressure at a ship or dock: ...), got 0

The ranges are those of a ship at sea or in dock; a value outside one is a typo, a unit
mistake (kelvin, per cent, radians) or a broken sensor, never a place shipstar can
measure from.  The table with its reasons is in docs/conventions.md ("Physical ranges").

:func:`parse_angle_deg` reads degrees as surveyors write them: ``46.474586``,
``46d28m28.51s``, ``46:28:28.51``, ``46°28'28.51"``, with a sign in front
(``-46d28m28.51s`` is -46.474586).

A foundation module (stage 0, ``tests/test_layering.py``): it imports only ``units`` and
``errors``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from shipstar.errors import ShipstarError

__all__ = ["Range", "RANGES", "check_range", "bounds", "parse_angle_deg",
           "MAX_SHIP_SPEED_M_PER_S", "MAX_SHIP_ACCELERATION_M_PER_S2", "POSITION_NOISE_M",
           "MAX_TRACK_GAP_S", "MAX_WEATHER_GAP_S", "TABLE_EDGE_S", "KNOT_M_PER_S"]

#: One knot (m/s).
KNOT_M_PER_S = 1852.0 / 3600.0


@dataclass(frozen=True)
class Range:
    """A closed range ``[lo, hi]`` of one quantity, its unit as written in messages and
    why it is what it is."""

    lo: float
    hi: float
    unit: str
    reason: str

    def text(self) -> str:
        """``[500, 1100] hPa``."""
        return f"[{self.lo:g}, {self.hi:g}]" + (f" {self.unit}" if self.unit else "")


#: The fastest ships (fast ferries, warships at flank speed) make about 40 knots.
MAX_SHIP_SPEED_M_PER_S = 40.0 * KNOT_M_PER_S
#: Horizontal acceleration of a ship's GNSS antenna: below ~0.5 g even in heavy seas.
MAX_SHIP_ACCELERATION_M_PER_S2 = 5.0
#: Position noise allowed per track row (GNSS, m) before a jump counts as speed.
POSITION_NOISE_M = 10.0
#: Largest time between two track rows a frame may fall in (s); see docs/conventions.md.
MAX_TRACK_GAP_S = 10.0
#: Largest time between two weather rows a frame may fall in (s).
MAX_WEATHER_GAP_S = 3600.0
#: How far before the first or after the last row of a table a frame may lie (s).
TABLE_EDGE_S = 1.0

RANGES: dict[str, Range] = {
    "pressure_hpa": Range(500.0, 1100.0, "hPa", "station pressure at a ship or dock: the sea-level records are "
                          "870 and 1084 hPa, 500 hPa is 5.5 km up; 0 would switch refraction off"),
    "temperature_c": Range(-60.0, 60.0, "C", "air at sea level, from the Antarctic coast in winter to the hottest "
                           "record (57 C); kelvin or Fahrenheit land outside"),
    "relative_humidity": Range(0.0, 1.0, "", "a fraction, not per cent"),
    "wavelength_um": Range(0.3, 1.1, "um", "the effective wavelength of a silicon star sensor's passband"),
    "lat_deg": Range(-90.0, 90.0, "deg", "geodetic, north positive"),
    "lon_deg": Range(-180.0, 360.0, "deg", "east positive, or 0-360"),
    "heading_deg": Range(0.0, 360.0, "deg", "a heading, from north through east"),
    "pitch_deg": Range(-30.0, 30.0, "deg", "a ship's pitch, bow up positive: a few degrees in dock or at sea, "
                       "30 deg is beyond any ship still afloat"),
    "roll_deg": Range(-45.0, 45.0, "deg", "a ship's roll, starboard down positive: 45 deg is beyond any ship "
                      "still afloat"),
    "install_az_deg": Range(-360.0, 360.0, "deg", "an installation azimuth from the bow toward starboard, one turn "
                            "either way"),
    "install_el_deg": Range(-90.0, 90.0, "deg", "an installation elevation above the deck"),
    "install_roll_deg": Range(-180.0, 180.0, "deg", "a sensor's roll about its boresight"),
    "speed_m_per_s": Range(0.0, MAX_SHIP_SPEED_M_PER_S, "m/s", "40 knots, the fastest ships"),
    "acceleration_m_per_s2": Range(0.0, MAX_SHIP_ACCELERATION_M_PER_S2, "m/s^2",
                                   "a ship's horizontal acceleration stays below ~0.5 g even in heavy seas"),
}


def bounds(name: str) -> tuple[float, float]:
    """``(lo, hi)`` of a range in :data:`RANGES`."""
    r = RANGES[name]
    return r.lo, r.hi


def check_range(name: str, value, *, label: str | None = None, where: str | None = None) -> float:
    """``value`` as a float when it is a finite number within ``RANGES[name]``.

    Parameters
    ----------
    name : str
        Key of :data:`RANGES` (``"pressure_hpa"``, ``"install_az_deg"``, ...).
    value
        The value (a number; a bool is refused).
    label : str, optional
        The name shown in the message (default ``name``): the key or flag the user wrote,
        e.g. ``"az_deg"`` for ``install_az_deg``.
    where : str, optional
        Prefix naming the file, table or row: ``"{where}: {label} must be ..."``.

    Raises
    ------
    ShipstarError
        One line: ``pressure_hpa must be within [500, 1100] hPa (reason), got 0``.
    """
    r = RANGES[name]
    shown = label or name
    prefix = f"{where}: " if where else ""
    if isinstance(value, bool):
        raise ShipstarError(f"{prefix}{shown} must be a number, got {value!r}")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ShipstarError(f"{prefix}{shown} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise ShipstarError(f"{prefix}{shown} must be finite, got {value!r}")
    if not r.lo <= x <= r.hi:
        raise ShipstarError(f"{prefix}{shown} must be within {r.text()} ({r.reason}), got {x:g}")
    return x


# -- angles as surveyors write them -------------------------------------------------------

_NUMBER = r"\d+(?:\.\d*)?|\.\d+"
_DMS_LETTERS = re.compile(rf"^(?P<d>{_NUMBER})\s*[d°]\s*(?:(?P<m>{_NUMBER})\s*[m'′]\s*)?"
                          rf"(?:(?P<s>{_NUMBER})\s*(?:s|\"|''|″))?$", re.IGNORECASE)
_DMS_COLONS = re.compile(rf"^(?P<d>\d+):(?P<m>\d+(?:\.\d*)?)(?::(?P<s>{_NUMBER}))?$")


def parse_angle_deg(text) -> float:
    """Degrees from ``"46.474586"``, ``"46d28m28.51s"``, ``"46:28:28.51"``, ``"46:28.475"``,
    ``"46°28'28.51\\""`` or ``"46d28m"``; a leading ``-`` (or ``+``) signs the whole angle.

    A number (int or float) is returned as a float.  Minutes and seconds must be below 60
    and are only allowed after whole degrees (whole minutes before seconds).

    Raises
    ------
    ShipstarError
        Text that is none of these, or not finite.
    """
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        x = float(text)
        if not math.isfinite(x):
            raise ShipstarError(f"angle must be finite, got {text!r}")
        return x
    if not isinstance(text, str):
        raise ShipstarError(f"not an angle in degrees: {text!r}")
    s = text.strip()
    try:
        x = float(s)
    except ValueError:
        pass
    else:
        if not math.isfinite(x):
            raise ShipstarError(f"angle must be finite, got {text!r}")
        return x
    sign = 1.0
    body = s
    if body[:1] in "+-" and body:
        sign, body = (-1.0 if body[0] == "-" else 1.0), body[1:].strip()
    m = _DMS_LETTERS.match(body) or _DMS_COLONS.match(body)
    if not m:
        raise ShipstarError(f"not an angle in degrees: {text!r} (write 46.474586, 46d28m28.51s or 46:28:28.51)")
    d, mins, secs = m.group("d"), m.group("m"), m.group("s")
    if (mins is not None or secs is not None) and "." in d:
        raise ShipstarError(f"not an angle in degrees: {text!r} (degrees must be whole when minutes follow)")
    if secs is not None and mins is not None and "." in mins:
        raise ShipstarError(f"not an angle in degrees: {text!r} (minutes must be whole when seconds follow)")
    mv, sv = float(mins or 0.0), float(secs or 0.0)
    if mv >= 60.0 or sv >= 60.0:
        raise ShipstarError(f"not an angle in degrees: {text!r} (minutes and seconds must be below 60)")
    return sign * (float(d) + mv / 60.0 + sv / 3600.0)
