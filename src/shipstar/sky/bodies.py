"""The Moon and the Sun: their topocentric places at a frame's time and site.

:func:`moon_sun` takes ERFA's ephemerides, ``erfa.moon98`` (the geocentric Moon, GCRS,
~10'' over 1900-2100) and ``erfa.epv00`` (the Earth around the Sun and the barycentre),
makes them topocentric with the observer's position that the frame's sky model
(``FrameContext.astrom["eb"]``) already holds, corrects for light time (the body's
barycentric motion during it), then puts them through the same apparent-place transform
as the stars (``FrameContext.hor_from_icrs``: light deflection and annual + diurnal
aberration) into the horizontal frame.  No refraction.

The simulator draws the Moon with it (``simulate._skylight``); the pipeline masks the
Moon's and the Sun's light before extraction (``pipeline._skylight``), placing them in a
sensor's field with the identification's J2000 attitude through their *astrometric*
directions (:attr:`BodyPlaces.moon_icrs`, the frame in which the catalog stars are
matched).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["BodyPlaces", "moon_sun", "MOON_RADIUS_KM", "SUN_RADIUS_KM"]

#: The Moon's mean radius (km).
MOON_RADIUS_KM = 1737.4
#: The Sun's radius (km, IAU nominal).
SUN_RADIUS_KM = 695700.0
_AU_KM = 149597870.7
_C_AU_PER_DAY = 173.1446326846693


@dataclass(frozen=True)
class BodyPlaces:
    """Apparent (unrefracted) topocentric places of the Moon and the Sun at one time.

    Attributes
    ----------
    moon_hor, sun_hor : (3,)
        Unit vectors in the horizontal frame (X north, Y up, Z east), no refraction.
    moon_distance_km : float
        Topocentric distance of the Moon.
    moon_radius_rad : float
        Topocentric angular radius of the Moon.
    phase_angle_rad : float
        Sun-Moon-observer angle (0 = full Moon).
    illuminated_fraction : float
        ``(1 + cos(phase angle)) / 2``.
    sun_from_moon_hor : (3,)
        Unit vector from the Moon toward the Sun, horizontal frame (lit side of the disc).
    moon_icrs, sun_icrs : (3,)
        Topocentric astrometric directions (ICRS axes, light time, no deflection or
        aberration): where a catalog star at the body's place would be.
    sun_radius_rad : float
        The Sun's angular radius.
    """

    moon_hor: np.ndarray
    sun_hor: np.ndarray
    moon_distance_km: float
    moon_radius_rad: float
    phase_angle_rad: float
    illuminated_fraction: float
    sun_from_moon_hor: np.ndarray
    moon_icrs: np.ndarray | None = None
    sun_icrs: np.ndarray | None = None
    sun_radius_rad: float = math.nan

    @property
    def moon_el_rad(self) -> float:
        return float(math.asin(max(-1.0, min(1.0, self.moon_hor[1]))))

    @property
    def sun_el_rad(self) -> float:
        return float(math.asin(max(-1.0, min(1.0, self.sun_hor[1]))))


def moon_sun(context) -> BodyPlaces:
    """The Moon's and the Sun's apparent topocentric places for a ``FrameContext``."""
    import erfa

    from shipstar.sky.time import tt_jd_from_utc_jd

    tt1, tt2 = tt_jd_from_utc_jd(context.utc_jd1, context.utc_jd2)
    pvh, pvb = erfa.epv00(tt1, tt2)
    moon = erfa.moon98(tt1, tt2)
    earth_b, earth_v = np.asarray(pvb["p"], float), np.asarray(pvb["v"], float)
    sun_b = earth_b - np.asarray(pvh["p"], float)              # the Sun, barycentric (AU)
    sun_v = earth_v - np.asarray(pvh["v"], float)
    obs_b = np.asarray(context.astrom["eb"], float)            # the observer, barycentric (AU)
    moon_topo = np.asarray(moon["p"], float) - (obs_b - earth_b)
    moon_vb = np.asarray(moon["v"], float) + earth_v
    moon_lt = moon_topo - moon_vb * (np.linalg.norm(moon_topo) / _C_AU_PER_DAY)
    sun_topo = sun_b - obs_b
    sun_lt = sun_topo - sun_v * (np.linalg.norm(sun_topo) / _C_AU_PER_DAY)
    moon_hor, sun_hor = context.hor_from_icrs(np.stack([moon_lt, sun_lt]))
    dist_km = float(np.linalg.norm(moon_topo)) * _AU_KM
    to_obs = -moon_topo / np.linalg.norm(moon_topo)
    to_sun = sun_topo - moon_topo
    to_sun /= np.linalg.norm(to_sun)
    alpha = float(math.acos(max(-1.0, min(1.0, float(to_obs @ to_sun)))))
    C = np.asarray(context.C_hor_from_icrs_approx)
    sun_from_moon = C @ to_sun
    sun_km = float(np.linalg.norm(sun_topo)) * _AU_KM
    return BodyPlaces(moon_hor, sun_hor, dist_km, math.asin(MOON_RADIUS_KM / dist_km), alpha,
                      0.5 * (1.0 + math.cos(alpha)), sun_from_moon / np.linalg.norm(sun_from_moon),
                      moon_lt / np.linalg.norm(moon_lt), sun_lt / np.linalg.norm(sun_lt),
                      math.asin(SUN_RADIUS_KM / sun_km))
