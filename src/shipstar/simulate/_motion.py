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

**Curved paths** (a ship's rate changes during the exposure).  The image of a streak is
the time integral of the star's image over the exposure, so its centroid is the star's
*time-averaged* position, not its mid-exposure position: with an angular acceleration
``alpha`` the two differ by ``(-alpha x u + omega x (omega x u)) T^2 / 24`` (Taylor
expansion of ``u(t)``; the second term is the curvature of a constant-rate path), 2.96''
for A1's 80 ms at the sea state's peak roll acceleration 3.08 deg/s^2.  Simulated sessions
render the exact path: :func:`exposure_path_px` projects the star at ``2 n + 1`` instants
of the exposure (:func:`exposure_offsets_s`) with the true attitude at each, and
:func:`streak_sources` turns the path into ``n`` short straight streaks, each carrying
``1/n`` of the light and centred on its sub-interval's time-averaged position (Simpson's
rule, exact for a quadratic path), so the rendered image is the time-integrated one and
the truth stays the mid-exposure position.
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.errors import ShipstarError

__all__ = ["EARTH_RATE_RAD_PER_S", "earth_rate_hor_rad_per_s", "rotate_rodrigues",
           "smear_px_from_rate", "as_rate_rad_per_s", "EXPOSURE_SUBSTEPS", "exposure_offsets_s",
           "exposure_path_px", "streak_sources", "fewest_pieces"]

#: Earth's rotation rate relative to the stars (IERS conventions, rad/s).
EARTH_RATE_RAD_PER_S = 7.292115e-5
#: Largest accepted angular rate (rad/s): 1 turn per second.
_MAX_RATE_RAD_PER_S = 2.0 * math.pi
#: Straight pieces a star's path is rendered in (:func:`streak_sources`).  Simpson's rule
#: makes each piece's centroid exact for a quadratic path; what is left (the third
#: derivative) is below 1e-4 px for the sea session at 80 ms.
EXPOSURE_SUBSTEPS = 8
#: A path that a uniform straight streak follows to within this (px) is rendered as one.
PATH_TOLERANCE_PX = 1e-3


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


def exposure_offsets_s(exposure_s: float, n_steps: int = EXPOSURE_SUBSTEPS) -> np.ndarray:
    """Instants ``(2 n + 1,)`` of an exposure, seconds from mid-exposure: ``-T/2 .. T/2``
    in ``2 n`` equal steps (ends and middles of the ``n`` pieces of :func:`streak_sources`)."""
    t = float(exposure_s)
    if not (math.isfinite(t) and t >= 0.0):
        raise ShipstarError(f"exposure_s must be finite and >= 0, got {exposure_s!r}")
    if isinstance(n_steps, bool) or int(n_steps) != n_steps or n_steps < 1:
        raise ShipstarError(f"n_steps must be an integer >= 1, got {n_steps!r}")
    return np.linspace(-0.5 * t, 0.5 * t, 2 * int(n_steps) + 1)


def exposure_path_px(camera, v_ref, C_ref_from_sensor, tau_s, ref_rate_rad_per_s=None) -> np.ndarray:
    """Image positions ``(N, K, 2)`` of ``N`` stars at ``K`` instants of an exposure.

    Parameters
    ----------
    camera : shipstar.camera.Camera
    v_ref : (N, 3) array
        Star directions in the reference frame at mid-exposure (``tau = 0``).
    C_ref_from_sensor : (K, 3, 3) array
        True sensor attitude at each instant.
    tau_s : (K,) array
        The instants, seconds from mid-exposure.
    ref_rate_rad_per_s : (3,) array, optional
        Angular velocity of the reference frame relative to the stars, its own axes
        (the horizontal frame: :func:`earth_rate_hor_rad_per_s`); the stars turn by
        ``-rate * tau`` in it.

    Returns
    -------
    (N, K, 2) array of ``xy_px`` (distortion included).
    """
    v = np.asarray(v_ref, float).reshape(-1, 3)
    C = np.asarray(C_ref_from_sensor, float).reshape(-1, 3, 3)
    tau = np.asarray(tau_s, float).reshape(-1)
    if len(C) != len(tau):
        raise ShipstarError(f"{len(C)} attitudes for {len(tau)} instants")
    rate = as_rate_rad_per_s(ref_rate_rad_per_s, "ref_rate_rad_per_s")
    u = np.stack([rotate_rodrigues(v, -rate * tk) @ Ck for tk, Ck in zip(tau, C)], axis=1)   # (N, K, 3)
    return camera.project(u.reshape(-1, 3)).reshape(len(v), len(tau), 2)


def streak_sources(path_px, signal_e) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Short straight streaks that render a sampled path exactly (to its third derivative).

    Parameters
    ----------
    path_px : (N, 2 n + 1, 2) array
        Each star's image at the instants of :func:`exposure_offsets_s`.
    signal_e : (N,) array
        Electrons of each star in the whole exposure.

    Returns
    -------
    xy_px : (N n, 2) array
        Centre of each piece: its time-averaged position ``(p0 + 4 pm + p1) / 6``.
    signal_e : (N n,) array
        ``signal_e / n`` each.
    smear_px : (N n, 2) array
        Each piece's chord ``p1 - p0`` (the renderer moves uniformly along it).
    """
    p = np.asarray(path_px, float)
    if p.ndim != 3 or p.shape[2] != 2 or p.shape[1] < 3 or p.shape[1] % 2 == 0:
        raise ShipstarError(f"path_px must have shape (N, 2 n + 1, 2) with n >= 1, got {p.shape}")
    n = (p.shape[1] - 1) // 2
    p0, pm, p1 = p[:, 0:-1:2], p[:, 1::2], p[:, 2::2]
    signal = np.repeat(np.asarray(signal_e, float).reshape(-1) / n, n)
    if len(signal) != len(p) * n:
        raise ShipstarError(f"signal_e must have one value per star ({len(p)})")
    return ((p0 + 4.0 * pm + p1) / 6.0).reshape(-1, 2), signal, (p1 - p0).reshape(-1, 2)


def fewest_pieces(path_px, tol_px: float = PATH_TOLERANCE_PX) -> np.ndarray:
    """The path ``(N, 2 n + 1, 2)`` resampled to the fewest pieces ``m`` (1, 2, 4, ... dividing
    ``n``) whose uniform straight streaks pass every sampled point within ``tol_px``:
    ``(N, 2 m + 1, 2)``.

    A star that moves uniformly along a straight line (a ship at rest: only the Earth's
    rotation) is then one streak, as cheap as a still star and with the same pixels.
    """
    p = np.asarray(path_px, float)
    k = p.shape[1]
    n = (k - 1) // 2
    idx = np.arange(k)
    m = 1
    while m < n and n % m == 0 and len(p):
        half = n // m                                     # samples per half piece
        piece = np.minimum(idx // (2 * half), m - 1)
        frac = (idx - piece * 2 * half) / (2.0 * half)
        ends = p[:, ::2 * half]                           # (N, m + 1, 2) piece boundaries
        line = ends[:, piece] + frac[None, :, None] * (ends[:, piece + 1] - ends[:, piece])
        if np.max(np.abs(line - p)) <= tol_px:
            return p[:, ::half]
        m *= 2
    return p if len(p) else p[:, ::n]
