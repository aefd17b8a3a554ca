"""Unit constants.  Degrees at the edges, radians inside: convert once at the entry point.

Names follow skyfield: ``ASEC2RAD`` multiplies arcseconds to give radians, and so on.
"""

from __future__ import annotations

import math

__all__ = [
    "DEG2RAD", "RAD2DEG", "ASEC2RAD", "RAD2ASEC", "MAS2RAD", "RAD2MAS",
    "AMIN2RAD", "DAY_S", "JULIAN_YEAR_DAYS", "J2000_JD", "C_M_PER_S",
]

DEG2RAD = math.pi / 180.0
RAD2DEG = 180.0 / math.pi
ASEC2RAD = DEG2RAD / 3600.0
RAD2ASEC = 1.0 / ASEC2RAD
MAS2RAD = ASEC2RAD / 1000.0
RAD2MAS = 1.0 / MAS2RAD
AMIN2RAD = DEG2RAD / 60.0
DAY_S = 86400.0
JULIAN_YEAR_DAYS = 365.25
J2000_JD = 2451545.0
C_M_PER_S = 299792458.0
