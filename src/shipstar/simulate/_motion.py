"""Image motion during an exposure: per-star smear vectors from the sensor's angular rate.

A sensor turning with angular velocity ``omega`` (rad/s, in sensor axes, relative to
the frame the stars are fixed in) sees a fixed direction ``u`` move as
``du/dt = -omega x u``; over the exposure ``T`` (centred on the truth time ``t = 0``)
the star goes from ``u(-T/2) = Exp(+[omega T/2]x) u`` to ``u(+T/2) = Exp(-[omega T/2]x) u``
(Rodrigues).  The smear vector handed to the renderer is the difference of the two
projected end points; the renderer moves the star uniformly along that chord, centred
on the truth (mid-exposure) position.  The chord differs from the true (slightly
curved, slightly non-uniform) path by second-order terms: for the A1 sensor turning at
1 deg/s about its boresight, < 0.01 px at the image corners.

For a sensor fixed in the horizontal frame, the stars turn about the celestial pole at
the Earth's rotation rate (:func:`earth_rate_hor_rad_per_s`): 15''/s, i.e. 0.04 px of
A1 during an 80 ms exposure at the celestial equator.
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.errors import ShipstarError

__all__ = ["EARTH_RATE_RAD_PER_S", "earth_rate_hor_rad_per_s", "rotate_rodrigues",
           "smear_px_from_rate", "as_rate_rad_per_s"]

#: Earth's rotation rate relative to the stars (IERS conventions, rad/s).
EARTH_RATE_RAD_PER_S = 7.292115e-5
#: Largest accepted angular rate (rad/s): 1 turn per second.
_MAX_RATE_RAD_PER_S = 2.0 * math.pi


def as_rate_rad_per_s(omega, name: str = "omega_sensor_rad_per_s") -> np.ndarray:
    """Validated angular-rate vector ``(3,)`` (zeros for None)."""
    if omega is None:
        return np.zeros(3)
    try:
        w = np.array(omega, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ShipstarError(f"{name} must be 3 numbers (rad/s), got {omega!r}") from None
    if w.shape != (3,) or not np.all(np.isfinite(w)):
        raise ShipstarError(f"{name} must be 3 finite numbers (rad/s), got {omega!r}")
    if float(np.linalg.norm(w)) > _MAX_RATE_RAD_PER_S:
        raise ShipstarError(f"{name} = {np.linalg.norm(w):.4g} rad/s is above "
                            f"{_MAX_RATE_RAD_PER_S:.4g} rad/s (one turn per second)")
    return w


def earth_rate_hor_rad_per_s(astronomical_lat_rad: float) -> np.ndarray:
    """Angular velocity ``(3,)`` of the horizontal frame relative to the stars, in hor axes.

    The Earth turns about its axis, which points north and up at the latitude:
    ``EARTH_RATE_RAD_PER_S * [cos lat, sin lat, 0]`` (X north, Y up, Z east).
    """
    lat = float(astronomical_lat_rad)
    return EARTH_RATE_RAD_PER_S * np.array([math.cos(lat), math.sin(lat), 0.0])


def rotate_rodrigues(v, rotvec) -> np.ndarray:
    """``Exp([a]x) v`` for vectors ``v`` (N, 3) and one rotation vector ``a`` (3,).

    Positive angle: right-handed (active) rotation of ``v`` about ``a``.
    """
    v = np.asarray(v, float)
    a = np.asarray(rotvec, float)
    theta = float(np.linalg.norm(a))
    if theta == 0.0:
        return v.copy()
    k = a / theta
    kxv = np.cross(k, v)
    kdv = v @ k
    return v * math.cos(theta) + kxv * math.sin(theta) + np.outer(kdv, k) * (1.0 - math.cos(theta))


def smear_px_from_rate(camera, u_sensor, omega_sensor_rad_per_s, exposure_s: float) -> np.ndarray:
    """Image motion ``(N, 2)`` (end minus start, px) of stars ``u_sensor`` (N, 3) during an exposure.

    Parameters
    ----------
    camera : shipstar.camera.Camera
    u_sensor : (N, 3) array
        Star directions in the sensor frame at mid-exposure.
    omega_sensor_rad_per_s : (3,) array
        Angular velocity of the sensor relative to the stars, in sensor axes.
    exposure_s : float

    Returns
    -------
    (N, 2) array; zeros when the rate is zero.  NaN for a star that leaves the
    hemisphere in front of the lens (not possible at rates below 1 turn/s and
    fields below 90 deg).
    """
    u = np.asarray(u_sensor, float).reshape(-1, 3)
    half = 0.5 * float(exposure_s) * as_rate_rad_per_s(omega_sensor_rad_per_s)
    if not np.any(half):
        return np.zeros((len(u), 2))
    start = camera.project(rotate_rodrigues(u, half))
    end = camera.project(rotate_rodrigues(u, -half))
    return end - start
