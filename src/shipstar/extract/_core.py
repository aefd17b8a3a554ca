"""``extract_stars``: background mesh, then the point-source or the smeared-frame path.

Point sources: :mod:`shipstar.extract._point`; smeared frames (the sensor turned during
the exposure): :mod:`shipstar.extract._smear` (the common smear) and
:mod:`shipstar.extract._smeared` (detection and fits of the streaks).
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.extract._background import estimate_mesh
from shipstar.extract._detect import at_or_above
from shipstar.extract._point import component_stats, detect_objects, measure_points
from shipstar.extract._result import Extraction
from shipstar.extract._smear import AUTO_SMEAR_MIN_PX, STREAK_MIN_PX, frame_smear

__all__ = ["extract_stars", "frame_extraction", "STREAK_MIN_PX"]

REFINE_METHODS = ("gaussian", "none")
#: A frame with at least this fraction of saturated pixels is refused.
OVEREXPOSED_FRACTION = 0.5
MIN_SIZE_PX = 16
#: Longest smear hint accepted, px.
MAX_SMEAR_PX = 200.0
#: Largest pixel value accepted (magnitude, ADU): the work arrays are float32 (largest 3.4e38).
MAX_ABS_ADU = 3e38
#: Largest fraction of bad (non-finite or out-of-range) pixels that are masked rather than refused.
MAX_BAD_FRACTION = 0.01
#: A smear hint whose stated error (``smear_sigma_px``) is at most this (px) is used as it is:
#: the common smear measured again from the frame's brightest streaks (free-smear fits of up
#: to 12 of them) is worse than that (0.1 px median error, 0.2 px at the 90th percentile,
#: against the simulator's truth in ``bench_throughput``'s session at sea).
TRUSTED_SMEAR_SIGMA_PX = 0.05


def _prepare(image):
    """Validate a 2-D real image; return it (native byte order, C order) and its quantum."""
    arr = np.asarray(image)
    if arr.dtype.kind not in "uif":
        raise ShipstarError(f"image must be an integer or float array, got dtype {arr.dtype}")
    if arr.ndim != 2:
        hint = " (colour? convert to luminance first, e.g. with read_image)" if arr.ndim == 3 else ""
        raise ShipstarError(f"image must be 2-D (height, width), got shape {arr.shape}{hint}")
    if min(arr.shape) < MIN_SIZE_PX:
        raise ShipstarError(f"image is {arr.shape[1]}x{arr.shape[0]} px; "
                            f"at least {MIN_SIZE_PX}x{MIN_SIZE_PX} is needed")
    if not arr.dtype.isnative:
        arr = arr.astype(arr.dtype.newbyteorder("="))
    arr = np.ascontiguousarray(arr)
    if arr.dtype.kind == "f" and not float(np.max(np.abs(arr))) <= MAX_ABS_ADU:      # NaN fails too
        arr = _mask_bad_pixels(arr)
    return arr, (1.0 if arr.dtype.kind in "ui" else 0.0)


def _mask_bad_pixels(arr):
    """Replace a few non-finite or out-of-range pixels (masked pixels stored as NaN, a corrupt
    value) by the median of the good ones, so one bad pixel does not cost the frame; refuse
    a frame where more than MAX_BAD_FRACTION of the pixels are bad."""
    bad = ~(np.abs(arr) <= MAX_ABS_ADU)
    n_bad = int(np.count_nonzero(bad))
    if n_bad > MAX_BAD_FRACTION * arr.size:
        raise ShipstarError(f"image has {n_bad} of {arr.size} pixels non-finite (NaN, inf) or beyond "
                            f"+-{MAX_ABS_ADU:g} ADU (more than {MAX_BAD_FRACTION:.0%}); replace or mask them first")
    out = arr.copy()
    out[bad] = np.median(arr[~bad])
    return out


def _saturation(arr, saturation_adu):
    """``(level, n)``: the saturation level -- the given one, or for integer data the top of
    the ADC range the data fit in (8..32 bits) -- and the number of pixels at or above it.

    One pass over the frame (its maximum) when nothing reaches the level, as in nearly
    every frame: the count needs a second only when the maximum does.
    """
    if saturation_adu is not None:
        level = float(saturation_adu)
        if not math.isfinite(level):
            raise ShipstarError(f"saturation_adu must be finite, got {saturation_adu}")
    elif arr.dtype.kind == "f":
        return math.inf, 0
    else:
        top = int(arr.max())
        level = next((float((1 << bits) - 1) for bits in (8, 10, 12, 14, 16, 20, 24, 32) if top <= (1 << bits) - 1),
                     float(top))
        return level, (int(np.count_nonzero(arr == arr.dtype.type(top))) if top == level else 0)
    if float(arr.max()) < level:            # (NaN and inf were replaced by _prepare)
        return level, 0
    return level, int(np.count_nonzero(at_or_above(arr, level)))


def _check_args(threshold_sigma, max_stars, refine, psf_sigma_px, gain_e_per_adu):
    if not (math.isfinite(threshold_sigma) and 1.0 <= threshold_sigma <= 1000.0):
        raise ShipstarError(f"threshold_sigma must be within [1, 1000], got {threshold_sigma}")
    if max_stars is not None and (int(max_stars) != max_stars or max_stars < 1):
        raise ShipstarError(f"max_stars must be a positive integer, got {max_stars}")
    if refine not in REFINE_METHODS:
        raise ShipstarError(f"refine must be one of {', '.join(REFINE_METHODS)}, got {refine!r}")
    if psf_sigma_px is not None and not (math.isfinite(psf_sigma_px) and 0.25 < psf_sigma_px < 20.0):
        raise ShipstarError(f"psf_sigma_px must be within (0.25, 20) px, got {psf_sigma_px}")
    if gain_e_per_adu is not None and not (math.isfinite(gain_e_per_adu) and gain_e_per_adu > 0):
        raise ShipstarError(f"gain_e_per_adu must be finite and > 0, got {gain_e_per_adu}")


def trusted_smear(smear_sigma_px) -> bool:
    """Whether a smear hint with the stated error ``smear_sigma_px`` (px, or None: unknown) is
    used as it is (at most :data:`TRUSTED_SMEAR_SIGMA_PX`); a bad value is a ShipstarError."""
    if smear_sigma_px is None:
        return False
    if not (math.isfinite(smear_sigma_px) and smear_sigma_px >= 0.0):
        raise ShipstarError(f"smear_sigma_px must be finite and >= 0, got {smear_sigma_px}")
    return smear_sigma_px <= TRUSTED_SMEAR_SIGMA_PX


def _check_smear(smear_px, smear_sigma_px=None):
    """The caller's smear hint as a (2,) array, or None; and whether it is trusted as it is
    (:func:`trusted_smear`)."""
    trusted = trusted_smear(smear_sigma_px)
    if smear_px is None:
        return None, False
    try:
        smear = np.array(smear_px, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ShipstarError(f"smear_px must be two numbers (dx, dy) in px, got {smear_px!r}") from None
    if smear.shape != (2,) or not np.all(np.isfinite(smear)):
        raise ShipstarError(f"smear_px must be two finite numbers (dx, dy) in px, got {smear_px!r}")
    if math.hypot(*smear) > MAX_SMEAR_PX:
        raise ShipstarError(f"smear_px is {math.hypot(*smear):.1f} px long; at most {MAX_SMEAR_PX:g} px is supported")
    return smear, trusted


def extract_stars(image, *, threshold_sigma=5.0, max_stars=None, refine="gaussian",
                  psf_sigma_px=None, gain_e_per_adu=None, saturation_adu=None, smear_px=None,
                  smear_sigma_px=None) -> Extraction:
    """Find the stars in a frame and measure their sub-pixel centroids.

    Parameters
    ----------
    image : (H, W) array
        Integer or float frame in ADU (see :func:`shipstar.extract.read_image`).
    threshold_sigma : float
        Detection threshold: a star's 3x3 sum above the local background must exceed
        ``threshold_sigma`` times its noise (``3 * noise_adu``); the 3x3 box is close to
        the matched filter of a PSF with sigma ~ 1 px. In a smeared frame, the sum along
        the line filter (the streak's pixels, see ``smear_px``) instead.
    max_stars : int, optional
        Keep only the brightest ``max_stars``.
    refine : {"gaussian", "none"}
        ``"gaussian"`` (default): fit a pixel-integrated Gaussian (x, y, flux,
        background) on a fixed window, smeared along the frame's smear in a smeared
        frame; reaches the Cramer-Rao bound. ``"none"``: the background-subtracted
        centre of gravity of the star's pixels above 2.5 sigma (1.2-1.9 times the bound
        for A1 and pulled toward pixel centres by up to 0.03 px; saturated stars always
        get it), of its footprint in a smeared frame.
    psf_sigma_px : float, optional
        PSF sigma; fitted on the brightest stars when not given.
    gain_e_per_adu : float, optional
        Camera gain: the fit weights pixels by their Poisson variance, which matters for
        bright stars. When not given it is estimated from the brightest stars' residuals.
    saturation_adu : float, optional
        Saturation level; by default the top of the ADC range the integer data fit in
        (255, 1023, 4095, 16383 or 65535), none for float data.
    smear_px : (dx, dy), optional
        Image motion of the stars during the exposure (end minus start, px; the sign
        does not matter), e.g. from the sensor's angular rate. Given and at least
        ``STREAK_MIN_PX`` (1.5 px) long, stars are detected with a line filter along it
        and fitted with the smeared PSF, the common smear measured again by free-smear
        fits of the brightest streaks found (used when 3 of them agree); their positions
        are the streaks' midpoints (mid-exposure for a constant rate). With
        ``psf_sigma_px`` and ``gain_e_per_adu`` too, the fastest way (no point-source
        pass over the frame). Not given, the smear is estimated from the
        brightest objects (second moments, then fits), and the same is done when it is
        3 px or longer and the fits agree on it (``smear_px`` of the result).
    smear_sigma_px : float, optional
        The error (1 sigma, px) of ``smear_px``, e.g. from the sensor's motion fitted to
        its last frames.  At most ``TRUSTED_SMEAR_SIGMA_PX`` (0.05 px), the hint is used as
        it is: the common smear is not measured again from the streaks (that measurement
        is worse, ~0.1 px).

    Returns
    -------
    Extraction
        Stars brightest first; zero stars is a valid result (an empty sky).

    Raises
    ------
    ShipstarError
        Bad options, or a frame that is not 2-D numbers, smaller than 16 x 16, overexposed,
        or has more than 1 % of its pixels non-finite or beyond +-3e38 ADU (the work arrays
        are float32); fewer such pixels are replaced by the median of the others.
    """
    return frame_extraction(image, threshold_sigma=threshold_sigma, max_stars=max_stars, refine=refine,
                            psf_sigma_px=psf_sigma_px, gain_e_per_adu=gain_e_per_adu,
                            saturation_adu=saturation_adu, smear_px=smear_px, smear_sigma_px=smear_sigma_px)[0]


def frame_extraction(image, *, threshold_sigma=5.0, max_stars=None, refine="gaussian", psf_sigma_px=None,
                     gain_e_per_adu=None, saturation_adu=None, smear_px=None, smear_sigma_px=None):
    """:func:`extract_stars`, and what it learnt of the frame: ``(Extraction, mesh,
    saturation_adu)`` -- the background and noise :class:`~shipstar.extract._background.Mesh`
    and the saturation level (given, or the top of the ADC range the data fit in; inf for
    float data), which the windowed extraction of the next frames
    (:mod:`shipstar.extract._windowed`) reuses."""
    _check_args(threshold_sigma, max_stars, refine, psf_sigma_px, gain_e_per_adu)
    hint, trusted = _check_smear(smear_px, smear_sigma_px)
    arr, quantum = _prepare(image)
    saturation, n_sat = _saturation(arr, saturation_adu)
    if n_sat >= OVEREXPOSED_FRACTION * arr.size:
        raise ShipstarError(f"frame is overexposed: {100.0 * n_sat / arr.size:.0f}% of its pixels are saturated")
    level = saturation
    if not n_sat:                           # no pixel reaches it: nothing to test against it below
        saturation = math.inf
    mesh = estimate_mesh(arr, quantum_adu=quantum)
    inv_gain = None if gain_e_per_adu is None else 1.0 / float(gain_e_per_adu)
    sigma_given = None if psf_sigma_px is None else float(psf_sigma_px)
    if hint is not None and math.hypot(*hint) >= (AUTO_SMEAR_MIN_PX if trusted else STREAK_MIN_PX) and sigma_given \
            and inv_gain:
        # everything known: straight to the streaks (no segmentation of the frame needed)
        from shipstar.extract._smeared import extract_smeared   # (not loaded for point sources)

        res, sigma = extract_smeared(arr, mesh, None, hint, sigma_given, inv_gain, saturation,
                                     float(threshold_sigma), refine, refine_smear=not trusted)
        return _result(res, mesh, sigma, arr.shape, max_stars, res["smear"]), mesh, level
    peaks, labels_of_peaks, idx, labels = detect_objects(arr, mesh, float(threshold_sigma))
    stats = component_stats(arr, mesh, idx, labels, labels_of_peaks, saturation)
    if hint is not None and trusted and STREAK_MIN_PX <= math.hypot(*hint) < AUTO_SMEAR_MIN_PX and sigma_given \
            and inv_gain:
        # a short smear known to 0.05 px: the stars found as points, measured as streaks
        from shipstar.extract._smeared import measure_short_streaks

        res = measure_short_streaks(arr, mesh, peaks, idx, stats, hint, sigma_given, inv_gain, saturation,
                                    float(threshold_sigma), refine)
        return _result(res, mesh, sigma_given, arr.shape, max_stars, res["smear"]), mesh, level
    sat_mask = at_or_above(arr, saturation) if (hint is None and n_sat) else None
    smear, sigma_s, gain_s = frame_smear(arr, mesh, stats, hint, sigma_given, inv_gain, sat_mask)
    if smear is not None:
        from shipstar.extract._smeared import extract_smeared

        res, sigma = extract_smeared(arr, mesh, stats, smear, sigma_s, gain_s, saturation, float(threshold_sigma),
                                     refine, refine_smear=hint is not None and not trusted)
        return _result(res, mesh, sigma, arr.shape, max_stars, res["smear"]), mesh, level
    res, sigma = measure_points(arr, mesh, peaks, stats, refine, psf_sigma_px, inv_gain)
    return _result(res, mesh, sigma, arr.shape, max_stars, np.zeros(2)), mesh, level


def _result(res, mesh, sigma, shape, max_stars, smear) -> Extraction:
    """The Extraction of per-star arrays ``res``, brightest first."""
    order = np.argsort(-res["flux"], kind="stable")[:max_stars]
    xy_cov = res["xy_cov"][order]
    return Extraction(
        xy_px=res["xy"][order], flux_adu=res["flux"][order], peak_adu=res["peak"][order],
        npix=res["npix"][order].astype(np.int64), flags=res["flags"][order].astype(np.int64),
        snr=res["snr"][order], xy_sigma_px=np.sqrt(0.5 * (xy_cov[:, 0, 0] + xy_cov[:, 1, 1])),
        xy_cov_px2=xy_cov, background_adu=mesh.background_adu, noise_adu=mesh.noise_adu,
        psf_sigma_px=float(sigma), shape_hw=tuple(shape), smear_px=np.array(smear, dtype=float),
    )
