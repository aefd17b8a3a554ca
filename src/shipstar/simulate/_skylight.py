"""The Moon and the Sun for simulated conditions: true places, moonlight, twilight.

Places (:func:`moon_sun`, from :mod:`shipstar.sky.bodies`): ERFA's ephemerides, ``erfa.moon98`` (the geocentric Moon,
GCRS, ~10'' over 1900-2100) and ``erfa.epv00`` (the Earth around the Sun and the
barycentre), made topocentric with the observer's position that the frame's sky model
(``FrameContext.astrom["eb"]``) already holds, corrected for light time (the body's
barycentric motion during it), then through the same apparent-place transform as the
stars (``FrameContext.hor_from_icrs``: light deflection and annual + diurnal aberration)
into the horizontal frame.  No refraction here; the caller refracts the observed
direction (:func:`observed`).

Brightness, in mag/arcsec^2 (V), relative to the camera files' dark sky of
:data:`DARK_SKY_MAG_PER_ARCSEC2` (their ``sky_e_per_px_per_s``):

- scattered moonlight: Krisciunas & Schaefer (1991, PASP 103, 1033) eq. 15-21, with
  the Moon's magnitude from its phase angle (eq. 9) and extinction ``k = 0.172`` mag per
  airmass;
- the lit disc: the Moon's magnitude spread over its lit area (mean surface brightness);
- twilight: a piecewise-linear zenith brightness against the Sun's elevation
  (:data:`TWILIGHT_TABLE`, dark at -18 deg, ~8 mag/arcsec^2 at sunset), uniform over a
  field.
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.sky.bodies import MOON_RADIUS_KM, BodyPlaces, moon_sun  # noqa: F401  (the places: shipstar.sky)
from shipstar.units import DEG2RAD, RAD2DEG

__all__ = ["BodyPlaces", "moon_sun", "observed", "moon_scatter_mag", "moon_disc_mag", "twilight_mag",
           "flux_ratio", "DARK_SKY_MAG_PER_ARCSEC2", "MOON_RADIUS_KM", "TWILIGHT_TABLE"]

#: Surface brightness of the camera files' ``sky_e_per_px_per_s`` (mag/arcsec^2).
DARK_SKY_MAG_PER_ARCSEC2 = 21.0
#: V extinction coefficient (mag per airmass) of Krisciunas & Schaefer.
_EXTINCTION_MAG_PER_AIRMASS = 0.172
#: (Sun elevation deg, zenith sky V mag/arcsec^2): dark below -18 deg.
TWILIGHT_TABLE = ((-18.0, 21.0), (-15.0, 20.0), (-12.0, 18.2), (-9.0, 15.8), (-6.0, 13.2), (-3.0, 10.6),
                  (0.0, 8.0), (10.0, 6.0))


def observed(v_hor, weather, refraction_model) -> np.ndarray:
    """A body's observed (refracted) direction; unrefracted below the model's limit."""
    from shipstar.sky.refraction import min_true_el_rad, refract_hor

    v = np.asarray(v_hor, float)
    if refraction_model == "none" or math.asin(max(-1.0, min(1.0, v[1]))) < min_true_el_rad(weather, refraction_model):
        return v
    return refract_hor(v[None, :], weather, refraction_model)[0]


def _airmass(zenith_rad):
    """Krisciunas & Schaefer eq. 3: ``X = (1 - 0.96 sin^2 Z)^-1/2``."""
    return 1.0 / np.sqrt(1.0 - 0.96 * np.sin(zenith_rad) ** 2)


def moon_magnitude(phase_angle_rad: float) -> float:
    """V magnitude of the Moon at a phase angle (K&S eq. 9, mean distance)."""
    a = abs(phase_angle_rad) * RAD2DEG
    return -12.73 + 0.026 * a + 4e-9 * a ** 4


def moon_scatter_mag(places: BodyPlaces, v_hor) -> np.ndarray:
    """Sky surface brightness (V mag/arcsec^2) of scattered moonlight toward ``v_hor`` (..., 3).

    K&S 1991 eq. 15-21; directions below 0.5 deg elevation and a Moon below the horizon
    give no moonlight (+inf).  The scattering angle is clipped at 2 deg (the formula's
    range; the disc is drawn separately).
    """
    v = np.asarray(v_hor, float)
    if places.moon_el_rad <= 0.0:
        return np.full(v.shape[:-1], np.inf)
    rho_deg = np.maximum(np.degrees(np.arccos(np.clip(v @ places.moon_hor, -1.0, 1.0))), 2.0)
    f = 10.0 ** 5.36 * (1.06 + np.cos(rho_deg * DEG2RAD) ** 2) + 10.0 ** (6.15 - rho_deg / 40.0)
    i_star = 10.0 ** (-0.4 * (moon_magnitude(places.phase_angle_rad) + 16.57))
    k = _EXTINCTION_MAG_PER_AIRMASS
    z_moon = 0.5 * math.pi - places.moon_el_rad
    z = 0.5 * math.pi - np.arcsin(np.clip(v[..., 1], math.sin(0.5 * DEG2RAD), 1.0))
    b_nl = f * i_star * 10.0 ** (-0.4 * k * _airmass(z_moon)) * (1.0 - 10.0 ** (-0.4 * k * _airmass(z)))
    with np.errstate(divide="ignore"):
        return (20.7233 - np.log(b_nl / 34.08)) / 0.92104


def moon_disc_mag(places: BodyPlaces) -> float:
    """Mean surface brightness (V mag/arcsec^2) of the lit part of the Moon's disc."""
    area_arcsec2 = math.pi * (places.moon_radius_rad * RAD2DEG * 3600.0) ** 2
    lit = max(places.illuminated_fraction, 1e-3) * area_arcsec2
    return moon_magnitude(places.phase_angle_rad) + 2.5 * math.log10(lit)


def twilight_mag(sun_el_rad: float) -> float:
    """Zenith twilight sky brightness (V mag/arcsec^2) at a Sun elevation; +inf when dark."""
    h = sun_el_rad * RAD2DEG
    els, mags = zip(*TWILIGHT_TABLE)
    if h <= els[0]:
        return math.inf
    return float(np.interp(h, els, mags))


def flux_ratio(mag_per_arcsec2) -> np.ndarray:
    """Surface brightness relative to the dark sky (:data:`DARK_SKY_MAG_PER_ARCSEC2`): 0 for +inf."""
    m = np.asarray(mag_per_arcsec2, float)
    with np.errstate(over="ignore"):
        return np.where(np.isfinite(m), 10.0 ** (-0.4 * (np.where(np.isfinite(m), m, 0.0) - DARK_SKY_MAG_PER_ARCSEC2)),
                        0.0)
