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

import math

import numpy as np

from shipstar.units import RAD2ASEC

__all__ = ["MIN_CORRECTION_ARCSEC", "STREAK_MODEL_FRACTION", "exposure_mean_offset", "mid_exposure_vectors",
           "rotation_vector_rad", "streak_corrected", "streak_along_factor", "streak_model_covariance",
           "StreakModel"]

#: A frame is solved again only when the correction turns a star by more than this.
MIN_CORRECTION_ARCSEC = 0.01
#: Uncertainty of the streak correction of extracted frames, as a fraction of the attitude
#: change it makes (1 sigma, fully correlated over the frame's stars):
#: :func:`streak_model_covariance`.  Measured against the truth with ``benchmarks/bench_streaks.py
#: --fit-model-fraction`` (60 ms, 24 s: 0.095 and 0.090 with seeds 0 and 1; below 0.045 at
#: 30 ms), docs/pipeline.md, *Honest sigmas*.
STREAK_MODEL_FRACTION = 0.09


def streak_along_factor(length_px, psf_sigma_px: float) -> np.ndarray:
    """Where the extractor's fit puts an accelerating streak, along it, in units of the
    time average's offset: ``k`` such that the fitted centre is ``x0 + k a T^2 / 24``.

    A star moving as ``x(t) = x0 + v t + a t^2 / 2`` over ``[-T/2, T/2]`` draws a streak
    of chord ``L = v T`` centred on ``x0 + a T^2 / 8`` whose light is denser at its slow
    end; its intensity centroid (the time average) is ``x0 + a T^2 / 24``.  The least-squares
    fit of a *uniform* streak of length ``L`` (``extract._streak``) is decided by the two
    ends, where the model's slope is: linearised in ``a`` (docs/extraction.md,
    *Accelerating streaks*), with ``s2 = sqrt(2) sigma_e``, ``sigma_e^2 = sigma^2 + 1/12``
    (the pixel-integrated PSF) and ``x = L / s2``::

        k = 3 + 24 / x^2 - 12 (Phi(x) - 1/2) / (x (phi(0) - phi(x)))

    ``k -> 1`` for ``L << sigma`` (``1 - x^2 / 10 + x^4 / 210``: a point-source fit of a
    short streak is its centroid), dips to 0.61 at ``L ~ 2.7 s2`` and tends to
    ``3 - 6 sqrt(2 pi) s2 / L`` (the ends' midpoint, ``a T^2 / 8``, less a PSF-sized
    pull toward the brighter end) for long streaks.  Measured on rendered A1 streaks
    (0.8 px PSF, 60 ms): 0.76, 1.18, 1.67, 2.03, 2.26, 2.48, 2.52 for L = 3, 6, 10, 15, 20,
    30, 40 px (Hp 5, +-0.02-0.1; Hp 7: 0.62, 1.04, 1.61, 1.82, 2.16), against 0.63, 0.95,
    1.54, 1.95, 2.18, 2.44, 2.57 here.

    Parameters
    ----------
    length_px : array
        Streak lengths (chords, px).
    psf_sigma_px : float
        The camera's Gaussian PSF sigma (px).

    Returns
    -------
    array of ``k`` (1 at ``L = 0``).
    """
    from scipy.special import ndtr

    s2 = np.sqrt(2.0 * (float(psf_sigma_px) ** 2 + 1.0 / 12.0))
    x = np.abs(np.asarray(length_px, float)) / s2
    small = x < 0.5
    xs = np.where(small, 1.0, x)
    phi0 = 1.0 / np.sqrt(2.0 * np.pi)
    k = 3.0 + 24.0 / xs ** 2 - 12.0 * (ndtr(xs) - 0.5) / (xs * phi0 * -np.expm1(-0.5 * xs ** 2))
    return np.where(small, 1.0 - x ** 2 / 10.0 + x ** 4 / 210.0, k)


class StreakModel:
    """How a frame's centroids relate to the stars' paths during the exposure.

    ``StreakModel()`` (no PSF): the centroids are the time averages (``Frame.from_centroids``:
    given centroids are documented as such).  ``StreakModel(psf_sigma_px, pixel_rad)``:
    the pipeline's own extraction, whose fitted centre lies ``k(L)`` times the time
    average's offset along each streak (:func:`streak_along_factor`, ``L`` from the
    sensor's rate) and at the time average across it.

    Parameters
    ----------
    psf_sigma_px : float, optional
    pixel_rad : float, optional
        Angle of one pixel at the boresight (``pixel_mm / f_mm``).
    """

    def __init__(self, psf_sigma_px: float | None = None, pixel_rad: float | None = None):
        self.psf_sigma_px = None if psf_sigma_px is None else float(psf_sigma_px)
        self.pixel_rad = None if pixel_rad is None else float(pixel_rad)

    @property
    def fitted(self) -> bool:
        return self.psf_sigma_px is not None and self.pixel_rad is not None and self.pixel_rad > 0.0


def exposure_mean_offset(w_sensor, omega_rad_per_s, alpha_rad_per_s2, exposure_s: float,
                         model: StreakModel | None = None) -> np.ndarray:
    """Time average over the exposure minus the mid-exposure direction, ``(N, 3)``.

    Parameters
    ----------
    w_sensor : (N, 3) array
        Unit directions in the sensor frame.
    omega_rad_per_s, alpha_rad_per_s2 : (3,) arrays
        The sensor's angular velocity and acceleration (sensor axes, relative to the
        frame the stars are fixed in) at mid-exposure.
    exposure_s : float

    model : StreakModel, optional
        With a fitted model (the pipeline's own extraction) the component along each
        star's motion ``-omega x w`` is scaled by :func:`streak_along_factor` of its
        streak length ``|omega x w| T / pixel_rad``: the offset of the *fitted* centre.

    Returns
    -------
    (N, 3) array
        ``(-alpha x w + omega x (omega x w)) T^2 / 24`` (its along-streak part times ``k``).
    """
    w = np.asarray(w_sensor, float).reshape(-1, 3)
    om = np.asarray(omega_rad_per_s, float).reshape(3)
    al = np.asarray(alpha_rad_per_s2, float).reshape(3)
    x, y, z = w[:, 0], w[:, 1], w[:, 2]
    w_cross_alpha = np.stack([y * al[2] - z * al[1], z * al[0] - x * al[2], x * al[1] - y * al[0]], axis=1)
    curvature = np.outer(w @ om, om) - (om @ om) * w                     # omega x (omega x w)
    acc = w_cross_alpha + curvature
    if model is not None and model.fitted:
        vel = np.stack([y * om[2] - z * om[1], z * om[0] - x * om[2], x * om[1] - y * om[0]], axis=1)  # w x omega
        speed = np.sqrt(np.einsum("ij,ij->i", vel, vel))
        k = streak_along_factor(speed * float(exposure_s) / model.pixel_rad, model.psf_sigma_px)
        e = np.divide(vel, speed[:, None], out=np.zeros_like(vel), where=speed[:, None] > 0.0)
        acc = acc + ((k - 1.0) * np.einsum("ij,ij->i", acc, e))[:, None] * e
    return acc * (float(exposure_s) ** 2 / 24.0)


def mid_exposure_vectors(w_mean, omega_rad_per_s, alpha_rad_per_s2, exposure_s: float,
                         model: StreakModel | None = None):
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
    from shipstar.attitude import _ckernels

    w = np.ascontiguousarray(w_mean, dtype=np.float64).reshape(-1, 3)
    om = np.ascontiguousarray(omega_rad_per_s, dtype=np.float64).reshape(3)
    al = np.ascontiguousarray(alpha_rad_per_s2, dtype=np.float64).reshape(3)
    fitted = model is not None and model.fitted
    mid, turn = np.empty_like(w), np.empty(len(w))
    # compiled, star by star (~5 us against ~89 us for 40 stars); _mid_exposure_vectors_python
    # is its reference (the same arithmetic, to rounding)
    _ckernels.mid_exposure(w, om, al, float(exposure_s), model.psf_sigma_px if fitted else math.nan,
                           model.pixel_rad if fitted else math.nan, mid, turn)
    return mid, turn


def _mid_exposure_vectors_python(w_mean, omega_rad_per_s, alpha_rad_per_s2, exposure_s: float,
                                 model: StreakModel | None = None):
    """:func:`mid_exposure_vectors` in NumPy (the compiled kernel's reference)."""
    w = np.asarray(w_mean, float).reshape(-1, 3)
    w = w / np.sqrt(np.einsum("ij,ij->i", w, w))[:, None]
    mid = w - exposure_mean_offset(w, omega_rad_per_s, alpha_rad_per_s2, exposure_s, model)
    mid /= np.sqrt(np.einsum("ij,ij->i", mid, mid))[:, None]
    chord = np.sqrt(np.einsum("ij,ij->i", mid - w, mid - w))
    return mid, 2.0 * np.arcsin(np.minimum(0.5 * chord, 1.0))


def rotation_vector_rad(C) -> np.ndarray:
    """Rotation vector (3,) of a rotation matrix ``C`` (3, 3) within a few degrees of the
    identity: ``C = exp([e]x)``."""
    C = np.asarray(C, float)
    v = 0.5 * np.array([C[2, 1] - C[1, 2], C[0, 2] - C[2, 0], C[1, 0] - C[0, 1]])
    s = float(np.linalg.norm(v))
    if s == 0.0:
        return v
    return v * (np.arctan2(s, 0.5 * (np.trace(C) - 1.0)) / s)


def streak_model_covariance(C_before, C_after, fraction: float = None) -> np.ndarray:
    """Covariance (3, 3, rad^2, sensor axes) that the streak model's error adds to a
    corrected frame's attitude.

    The correction's error is common to the frame's stars (the same rate, acceleration
    and streak model turn them all), so it does not average down over them, and the
    residuals do not show it (a common turn of the field is absorbed by the attitude).
    It is taken as ``fraction`` (default :data:`STREAK_MODEL_FRACTION`, 1 sigma) of the
    correction itself, fully correlated: with ``d`` the rotation vector of
    ``C_before^T C_after`` (the attitude change the correction made, sensor axes),
    ``fraction^2 d d^T``.  The correction is linear in the stars' shifts, so ``d`` is
    the same linear map of them as the solver applies (docs/pipeline.md, *Streaks*).

    Parameters
    ----------
    C_before, C_after : (3, 3) arrays
        ``C_hor_from_sensor`` solved from the measured and from the corrected directions.
    fraction : float, optional
    """
    f = STREAK_MODEL_FRACTION if fraction is None else float(fraction)
    d = rotation_vector_rad(np.asarray(C_before, float).T @ np.asarray(C_after, float))
    return f * f * np.outer(d, d)


def streak_corrected(fr, omega_sensor_rad_per_s, alpha_sensor_rad_per_s2, installation, options,
                     model: StreakModel | None = None):
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
    model : StreakModel, optional
        The pipeline's own extraction (:class:`StreakModel` with the camera's PSF and pixel
        angle): the fitted streak centres' along-streak offset; default: time averages.
    """
    from shipstar.pipeline._sensor import resolve_frame

    w_mid, turn = mid_exposure_vectors(fr.horizontal.w_sensor, omega_sensor_rad_per_s, alpha_sensor_rad_per_s2,
                                       fr.exposure_s, model)
    largest_arcsec = float(np.max(turn)) * RAD2ASEC if len(turn) else 0.0
    if largest_arcsec <= MIN_CORRECTION_ARCSEC:
        return fr
    # the pipeline's own streak fits: their model's frame-level covariance joins the new solve's
    fitted = model is not None and model.fitted
    return resolve_frame(fr, w_mid, installation, options, largest_arcsec,
                         streak_model_covariance if fitted else None)
