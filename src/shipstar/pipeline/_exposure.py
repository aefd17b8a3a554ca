"""Streak centroids -> mid-exposure directions (the exposure-motion correction).

An image is the time integral of the star's image over the exposure, so a measured
centroid is the star's *time-averaged* direction, while the frame is tagged with its
mid-exposure time.  For a direction ``u(t)`` in the sensor frame, ``du/dt = -omega x u``
(``omega``: the sensor's angular velocity relative to the horizontal frame, sensor axes),
Taylor expansion about mid-exposure gives (docs/simulation.md, *Curved paths*)::

    mean of u over [-T/2, T/2]  =  u(0) + u''(0) T^2 / 24,    u'' = -alpha x u + omega x (omega x u)

The first term turns the whole field by ``-alpha T^2 / 24``, so it biases the attitude by
``+alpha T^2 / 24`` (up to 3.6'' at the seeds' sea state with 80 ms exposures, 0.06''
with 10 ms); the second, the curvature of a constant-rate path, is smaller (0.14'' at
80 ms).  The Earth's rotation adds < 0.001'' (its rate is 15''/s).

The sensor's ``omega(t)`` and ``alpha(t)`` come from its own solved attitudes of the last
0.8 s up to the frame (:mod:`shipstar.pipeline._motion`, causal).  Each solved frame's
measured vectors are turned back to the mid-exposure directions,
``w_mid = normalise(w - u''(w) T^2 / 24)`` with ``T`` the frame's ``exposure_s``, and the
frame is solved again when the largest turn exceeds :data:`MIN_CORRECTION_ARCSEC`.  The
motion is fitted to the uncorrected attitudes: the correction changes the rates by its
own derivative, ``jerk T^2 / 24`` (< 3''/s at 80 ms), far below their noise.  The
sensor's own attitudes are enough: the fit is weak only about the sensor's boresight,
and an error of ``alpha`` about the boresight turns the frame about its boresight, the
axis its attitude is weak about anyway (with both sensors' attitudes in the fit the joint
RMS of the 80 ms test session is the same to 0.001'').
"""

from __future__ import annotations

import numpy as np

from shipstar.units import RAD2ASEC

__all__ = ["MIN_CORRECTION_ARCSEC", "exposure_mean_offset", "mid_exposure_vectors", "streak_corrected"]

#: A frame is solved again only when the correction turns a star by more than this.
MIN_CORRECTION_ARCSEC = 0.01


def exposure_mean_offset(w_sensor, omega_rad_per_s, alpha_rad_per_s2, exposure_s: float) -> np.ndarray:
    """Time average over the exposure minus the mid-exposure direction, ``(N, 3)``.

    Parameters
    ----------
    w_sensor : (N, 3) array
        Unit directions in the sensor frame.
    omega_rad_per_s, alpha_rad_per_s2 : (3,) arrays
        The sensor's angular velocity and acceleration (sensor axes, relative to the
        frame the stars are fixed in) at mid-exposure.
    exposure_s : float

    Returns
    -------
    (N, 3) array
        ``(-alpha x w + omega x (omega x w)) T^2 / 24``.
    """
    w = np.asarray(w_sensor, float).reshape(-1, 3)
    om = np.asarray(omega_rad_per_s, float).reshape(3)
    al = np.asarray(alpha_rad_per_s2, float).reshape(3)
    x, y, z = w[:, 0], w[:, 1], w[:, 2]
    w_cross_alpha = np.stack([y * al[2] - z * al[1], z * al[0] - x * al[2], x * al[1] - y * al[0]], axis=1)
    curvature = np.outer(w @ om, om) - (om @ om) * w                     # omega x (omega x w)
    return (w_cross_alpha + curvature) * (float(exposure_s) ** 2 / 24.0)


def mid_exposure_vectors(w_mean, omega_rad_per_s, alpha_rad_per_s2, exposure_s: float):
    """Mid-exposure directions from measured (time-averaged) ones.

    Parameters
    ----------
    w_mean : (N, 3) array
        Measured unit directions (streak centroids), sensor frame.
    omega_rad_per_s, alpha_rad_per_s2 : (3,) arrays
        As for :func:`exposure_mean_offset`.
    exposure_s : float

    Returns
    -------
    w_mid : (N, 3) array
        Unit vectors.
    turn_rad : (N,) array
        Angle between each measured and corrected direction.
    """
    w = np.asarray(w_mean, float).reshape(-1, 3)
    w = w / np.sqrt(np.einsum("ij,ij->i", w, w))[:, None]
    mid = w - exposure_mean_offset(w, omega_rad_per_s, alpha_rad_per_s2, exposure_s)
    mid /= np.sqrt(np.einsum("ij,ij->i", mid, mid))[:, None]
    chord = np.sqrt(np.einsum("ij,ij->i", mid - w, mid - w))
    return mid, 2.0 * np.arcsin(np.minimum(0.5 * chord, 1.0))


def streak_corrected(fr, omega_sensor_rad_per_s, alpha_sensor_rad_per_s2, installation, options):
    """A solved frame turned to its mid-exposure directions and solved again (or ``fr``
    unchanged when the largest turn is below :data:`MIN_CORRECTION_ARCSEC`).

    Parameters
    ----------
    fr : FrameResult
        Solved, with ``solve_inputs`` and a finite ``exposure_s``.
    omega_sensor_rad_per_s, alpha_sensor_rad_per_s2 : (3,) arrays
        The sensor's angular velocity and acceleration at the frame's time, sensor axes.
    installation : Installation or None
    options : PipelineOptions
    """
    from shipstar.pipeline._sensor import resolve_frame

    w_mid, turn = mid_exposure_vectors(fr.horizontal.w_sensor, omega_sensor_rad_per_s, alpha_sensor_rad_per_s2,
                                       fr.exposure_s)
    largest_arcsec = float(np.max(turn)) * RAD2ASEC if len(turn) else 0.0
    if largest_arcsec <= MIN_CORRECTION_ARCSEC:
        return fr
    return resolve_frame(fr, w_mid, installation, options, largest_arcsec)
