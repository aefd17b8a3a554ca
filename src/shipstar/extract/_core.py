"""``extract_stars``: background mesh -> candidates -> peaks -> components -> centroids."""

from __future__ import annotations

import math

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.extract._background import estimate_mesh
from shipstar.extract._detect import (
    EDGE_NEIGHBOURS,
    box_sums,
    candidate_pixels,
    components,
    local_maxima,
    neighbour_values,
)
from shipstar.extract._fit import (
    covariance,
    estimate_psf_sigma,
    fit_gaussian,
    gather_windows,
    neighbour_ratios,
    start_values,
    window_half_px,
)
from shipstar.extract._smeared import STREAK_MIN_PX, calibrate, measure_streaks, sharp_pixels, smear_from_moments
from shipstar.extract._result import (
    FLAG_EDGE,
    FLAG_ELONGATED,
    FLAG_FIT_FAILED,
    FLAG_SATURATED,
    Extraction,
)

__all__ = ["extract_stars", "STREAK_MIN_PX"]

REFINE_METHODS = ("gaussian", "none")
#: Per-pixel level of the candidate (segmentation) pixels, in noise sigmas.
SEGMENT_SIGMA = 2.5
#: A peak whose 8 neighbours hold less than this fraction of the peak pixel's excess is a
#: single-pixel event (hot pixel, cosmic ray): even a sharp star (sigma 0.5 px, centred)
#: puts 1.1 times its peak pixel into the neighbours.
SINGLE_PIXEL_RATIO = 0.5
#: A peak whose neighbours hold significantly (this many sigma) less than the frame's PSF
#: allows is not a star (hot pixel, cosmic ray): see ``_too_sharp``.
SHARPNESS_SIGMA = 3.0
#: ... tested against a PSF this much narrower than the fitted one.
SHARPNESS_MARGIN = 0.8
#: PSF sigma assumed by that test when the frame's cannot be fitted (no star in it).
SHARPEST_PSF_SIGMA_PX = 0.5
#: Axis ratio of the second moments above which a star is flagged elongated.
ELONGATION_LIMIT = 2.0
#: A frame with at least this fraction of saturated pixels is refused.
OVEREXPOSED_FRACTION = 0.5
MIN_SIZE_PX = 16
#: Longest smear hint accepted, px.
MAX_SMEAR_PX = 200.0
#: Smallest moment-based smear guess worth refining by fits, px.
SMEAR_GUESS_MIN_PX = 2.0
#: Binning of the frame in which a smear is looked for when no object is bright enough in the frame.
BIN_PX = 4
#: Detection threshold in the binned frame.
DETECT_SIGMA = 5.0
#: Shortest estimated smear (no hint) for which the frame is treated as smeared, px.
AUTO_SMEAR_MIN_PX = 3.0


def _prepare(image):
    """Validate a 2-D real image; return it (native byte order, C order) and its quantum."""
    arr = np.asarray(image)
    if arr.dtype.kind not in "uif":
        raise ShipstarError(f"image must be an integer or float array, got dtype {arr.dtype}")
    if arr.ndim != 2:
        hint = " (colour? convert to luminance first, e.g. with read_image)" if arr.ndim == 3 else ""
        raise ShipstarError(f"image must be 2-D (height, width), got shape {arr.shape}{hint}")
    if min(arr.shape) < MIN_SIZE_PX:
        raise ShipstarError(f"image is {arr.shape[1]}x{arr.shape[0]} px; at least {MIN_SIZE_PX}x{MIN_SIZE_PX} is needed")
    if not arr.dtype.isnative:
        arr = arr.astype(arr.dtype.newbyteorder("="))
    arr = np.ascontiguousarray(arr)
    if arr.dtype.kind == "f":
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        if bad:
            raise ShipstarError(f"image has {bad} non-finite pixels (NaN or inf); replace or mask them first")
    return arr, (1.0 if arr.dtype.kind in "ui" else 0.0)


def _saturation_level(arr, saturation_adu):
    """Given level, or for integer data the top of the ADC range the data fit in (8..16 bits)."""
    if saturation_adu is not None:
        value = float(saturation_adu)
        if not math.isfinite(value):
            raise ShipstarError(f"saturation_adu must be finite, got {saturation_adu}")
        return value
    if arr.dtype.kind == "f":
        return math.inf
    top = int(arr.max())
    for bits in (8, 10, 12, 14, 16, 20, 24, 32):
        if top <= (1 << bits) - 1:
            return float((1 << bits) - 1)
    return float(top)


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


def _detect(arr, mesh, threshold_sigma):
    """Star peaks (flat indices, one per component) and the component data."""
    shape = arr.shape
    flat = arr.reshape(-1)
    mask, idx = candidate_pixels(arr, mesh, min(SEGMENT_SIGMA, threshold_sigma))
    peaks = local_maxima(flat, idx, shape)
    box, count = box_sums(flat, peaks, shape)
    row, col = np.divmod(peaks, shape[1])
    bg, noise = mesh.at(col, row)
    box_excess = box - count * bg
    peak_excess = flat[peaks] - bg
    star = (box_excess >= threshold_sigma * mesh.box_noise_factor * np.sqrt(count) * noise) & \
           (box_excess - peak_excess >= SINGLE_PIXEL_RATIO * peak_excess)
    peaks, box_excess = peaks[star], box_excess[star]
    labels, _ = components(mask, idx, shape)
    peak_label = labels[np.searchsorted(idx, peaks)]
    order = np.argsort(-box_excess, kind="stable")
    _, first = np.unique(peak_label[order], return_index=True)
    keep = np.sort(order[first])
    return peaks[keep], peak_label[keep], idx, labels, mask


def _component_stats(arr, mesh, idx, labels, star_labels, saturation):
    """Per star: npix, peak value, saturated/edge/elongated, thresholded centre of gravity."""
    height, width = arr.shape
    n = len(star_labels)
    star_of_label = np.full(labels.max() + 1 if labels.size else 0, -1)
    star_of_label[star_labels] = np.arange(n)
    star = star_of_label[labels] if labels.size else np.zeros(0, dtype=int)
    sel = star >= 0
    pix, who = idx[sel], star[sel]
    row, col = np.divmod(pix, width)
    values = arr.reshape(-1)[pix].astype(float)
    bg, _ = mesh.at(col, row)
    w = np.maximum(values - bg, 1e-12)
    sums = [np.bincount(who, weights=q, minlength=n) for q in (w, w * col, w * row)]
    cx, cy = sums[1] / sums[0], sums[2] / sums[0]
    dx, dy = col - cx[who], row - cy[who]
    mxx, myy, mxy = (np.bincount(who, weights=w * q, minlength=n) / sums[0] for q in (dx * dx, dy * dy, dx * dy))
    root = np.sqrt(((mxx - myy) / 2) ** 2 + mxy ** 2)
    major, minor = (mxx + myy) / 2 + root, np.maximum((mxx + myy) / 2 - root, 1e-12)
    peak = np.full(n, -np.inf)
    np.maximum.at(peak, who, values)
    npix = np.bincount(who, minlength=n)
    border = (row == 0) | (row == height - 1) | (col == 0) | (col == width - 1)
    flags = np.where(np.bincount(who, weights=values >= saturation, minlength=n) > 0, FLAG_SATURATED, 0)
    flags |= np.where(np.bincount(who, weights=border, minlength=n) > 0, FLAG_EDGE, 0)
    flags |= np.where((npix >= 9) & (major > ELONGATION_LIMIT ** 2 * minor), FLAG_ELONGATED, 0)
    return dict(npix=npix, peak=peak, flags=flags, cog=np.stack([cx, cy], axis=1), cog_flux=sums[0],
                moments=np.stack([mxx, myy, mxy], axis=1))


def _psf_and_gain(arr, col, row, bg, noise, stats, psf_sigma_px, inv_gain):
    """PSF sigma and inverse gain: given, or fitted on the brightest clean stars."""
    usable = np.flatnonzero((stats["flags"] & (FLAG_SATURATED | FLAG_EDGE)) == 0)
    if (psf_sigma_px is not None and inv_gain is not None) or usable.size == 0:
        return (math.nan if psf_sigma_px is None else float(psf_sigma_px)), (inv_gain or 0.0)
    bright = usable[np.argsort(-stats["cog_flux"][usable], kind="stable")]
    sigma, inv_gain = estimate_psf_sigma(arr, col[bright], row[bright], bg[bright], noise[bright],
                                         inv_gain=inv_gain)
    return (sigma if psf_sigma_px is None else float(psf_sigma_px)), inv_gain


def _too_sharp(arr, mesh, peaks, sigma, inv_gain, saturated):
    """Peaks significantly sharper than the frame's PSF allows: hot pixels, cosmic rays.

    Two one-sided tests (``SHARPNESS_SIGMA``) against :func:`neighbour_ratios` of a PSF
    ``SHARPNESS_MARGIN`` times narrower than the frame's (PSF changes over the field,
    error of the fitted sigma): the 8 neighbours' total, and the two faintest edge
    neighbours (a cosmic-ray line of 2-3 pixels leaves them empty).
    """
    flat = arr.reshape(-1)
    values, inside = neighbour_values(flat, peaks, arr.shape)
    row, col = np.divmod(peaks, arr.shape[1])
    bg, noise = mesh.at(col, row)
    noise = noise * mesh.box_noise_factor
    peak = flat[peaks] - bg
    excess = np.where(inside, values - bg[:, None], 0.0)
    edges = np.sort(np.where(inside[:, EDGE_NEIGHBOURS], excess[:, EDGE_NEIGHBOURS], np.inf), axis=1)[:, :2]
    edges = np.where(np.isfinite(edges), edges, 0.0)
    ratio_total, ratio_edges = neighbour_ratios(SHARPNESS_MARGIN * sigma)
    var_peak = noise ** 2 + np.maximum(peak, 0.0) * inv_gain
    too_sharp = np.zeros(len(peaks), dtype=bool)
    for ratio, part, n in ((ratio_total, excess.sum(axis=1), inside.sum(axis=1)),
                           (ratio_edges, edges.sum(axis=1), 2)):
        var = ratio ** 2 * var_peak + n * noise ** 2 + np.maximum(part, 0.0) * inv_gain
        too_sharp |= ratio * peak - part > SHARPNESS_SIGMA * np.sqrt(var)
    return too_sharp & ~saturated


def _centroids(arr, mesh, peaks, stats, refine, sigma, inv_gain):
    """Centroids, fluxes, SNR, predicted errors and updated flags of the detected stars."""
    row, col = np.divmod(peaks, arr.shape[1])
    bg, noise = mesh.at(col, row)
    have_sigma = math.isfinite(sigma)
    win = gather_windows(arr, col, row, window_half_px(sigma if have_sigma else 1.0), bg, noise)
    flags = stats["flags"] | np.where(np.all(win.valid, axis=(1, 2)), 0, FLAG_EDGE)
    saturated = (flags & FLAG_SATURATED) != 0
    p = start_values(win, sigma if have_sigma else 1.0)
    ok = np.zeros(len(peaks), dtype=bool)
    if refine == "gaussian":
        if have_sigma:
            p, ok = fit_gaussian(win, p, inv_gain=inv_gain)
        ok &= ~saturated & (p[:, 2] > 0)
        flags = flags | np.where(ok | saturated, 0, FLAG_FIT_FAILED)
    xy = np.where(ok[:, None], p[:, :2], stats["cog"])
    flux = np.where(ok, p[:, 2], start_values(win, 1.0)[:, 2])
    flux = np.where(saturated, np.maximum(flux, stats["cog_flux"]), flux)
    centre = np.column_stack([win.x0, win.y0]) + win.size // 2
    p_at = np.column_stack([np.clip(xy, centre - 1.0, centre + 1.0), flux, p[:, 3],
                            np.full(len(xy), sigma if have_sigma else 1.0)])
    cov = covariance(win, p_at, inv_gain=inv_gain) * mesh.box_noise_factor ** 2   # correlated (JPEG) noise
    snr = flux / np.sqrt(cov[:, 2, 2])
    unknown = saturated | ((flags & FLAG_FIT_FAILED) != 0) | (not have_sigma)
    xy_cov = np.where(unknown[:, None, None], np.nan, cov[:, :2, :2])
    return xy, flux, snr, xy_cov, flags, sigma


def _check_smear(smear_px):
    """The caller's smear hint as a (2,) array, or None."""
    if smear_px is None:
        return None
    try:
        smear = np.array(smear_px, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ShipstarError(f"smear_px must be two numbers (dx, dy) in px, got {smear_px!r}") from None
    if smear.shape != (2,) or not np.all(np.isfinite(smear)):
        raise ShipstarError(f"smear_px must be two finite numbers (dx, dy) in px, got {smear_px!r}")
    if math.hypot(*smear) > MAX_SMEAR_PX:
        raise ShipstarError(f"smear_px is {math.hypot(*smear):.1f} px long; at most {MAX_SMEAR_PX:g} px is supported")
    return smear


def _bright_objects(stats):
    """Indices of unsaturated objects off the border, brightest first."""
    usable = np.flatnonzero((stats["flags"] & (FLAG_SATURATED | FLAG_EDGE)) == 0)
    return usable[np.argsort(-stats["cog_flux"][usable], kind="stable")]


def _frame_smear(arr, mesh, stats, hint, sigma, inv_gain, saturated):
    """(smear (2,) or None for the point-source path, sigma, inv_gain) of the frame.

    Without a hint the frame is treated as smeared only on firm evidence: a moment-based
    guess of at least ``AUTO_SMEAR_MIN_PX``, confirmed by at least 3 fits of the
    brightest objects whose smear vectors agree (median distance from their median
    <= 20 % of its length + 0.5 px). Elongated PSFs of real lenses, roof edges and
    other odd objects do not pass; smears shorter than that are well measured by the
    point-source path.
    """
    if hint is not None:
        return (hint if math.hypot(*hint) >= STREAK_MIN_PX else None), sigma, inv_gain
    usable = (stats["flags"] & FLAG_EDGE) == 0
    guess = smear_from_moments(stats["moments"], stats["cog_flux"], usable, stats["npix"])
    cog = stats["cog"][_bright_objects(stats)]
    if guess is None:                      # no bright object: faint stars, or long smears broken up
        guess, cog = _binned_guess(arr)
    if guess is None or math.hypot(*guess) < SMEAR_GUESS_MIN_PX:
        return None, sigma, inv_gain
    col, row = np.rint(cog).astype(np.int64).T
    smear, sigma_f, gain_f, (n_ok, spread) = calibrate(arr, mesh, saturated, col, row, guess, sigma, inv_gain,
                                                       fit_smear=True)
    length = math.hypot(*smear)
    if length < AUTO_SMEAR_MIN_PX or n_ok < 3 or spread > 0.2 * length + 0.5:
        return None, sigma, inv_gain
    return smear, sigma_f, gain_f


def _binned_guess(arr):
    """Smear guess and bright objects' centres from the frame binned ``BIN_PX`` x ``BIN_PX``, or (None, None).

    Binning adds a streak's light across its width and along it (``BIN_PX`` px), so a
    long streak too faint to be found pixel by pixel forms one object in the binned frame.
    """
    height, width = (s - s % BIN_PX for s in arr.shape)
    if min(height, width) < BIN_PX * MIN_SIZE_PX:
        return None, None
    binned = arr[:height, :width].astype(np.float32).reshape(height // BIN_PX, BIN_PX, width // BIN_PX, BIN_PX)
    binned = binned.sum(axis=(1, 3))
    mesh = estimate_mesh(binned, quantum_adu=1.0)
    peaks, labels_of_peaks, idx, labels, _ = _detect(binned, mesh, DETECT_SIGMA)
    stats = _component_stats(binned, mesh, idx, labels, labels_of_peaks, math.inf)
    usable = (stats["flags"] & FLAG_EDGE) == 0
    guess = smear_from_moments(stats["moments"], stats["cog_flux"], usable, np.maximum(stats["npix"], 9))
    if guess is None:
        return None, None
    cog = stats["cog"][_bright_objects(stats)] * BIN_PX + 0.5 * (BIN_PX - 1)
    return guess * BIN_PX, cog


def _extract_smeared(arr, mesh, idx, labels, stats, smear, sigma, inv_gain, saturation, threshold_sigma, refine):
    """Centroids of a smeared frame: the dict of :func:`measure_streaks`, and sigma."""
    saturated = arr >= saturation if math.isfinite(saturation) else np.zeros(arr.shape, dtype=bool)

    def too_sharp(peaks, psf_sigma, gain):
        row, col = np.divmod(peaks, arr.shape[1])
        return _too_sharp(arr, mesh, peaks, psf_sigma, gain or 0.0, saturated[row, col])

    if sigma is None or inv_gain is None:
        bad = saturated.copy()
        bad.reshape(-1)[sharp_pixels(arr, mesh, idx, labels, lambda pk: too_sharp(
            pk, SHARPEST_PSF_SIGMA_PX if sigma is None else sigma, inv_gain))] = True
        bright = _bright_objects(stats)
        col, row = np.rint(stats["cog"][bright]).astype(np.int64).T
        _, sigma, inv_gain, _ = calibrate(arr, mesh, bad, col, row, smear, sigma, inv_gain, fit_smear=False)
    sigma = 1.0 if sigma is None else sigma
    sharp = sharp_pixels(arr, mesh, idx, labels, lambda pk: too_sharp(pk, sigma, inv_gain))
    work = arr.astype(np.float32)
    row, col = np.divmod(sharp, arr.shape[1])
    work.reshape(-1)[sharp] = mesh.at(col, row)[0]
    bad = saturated.copy()
    bad.reshape(-1)[sharp] = True
    result = measure_streaks(work, mesh, smear, threshold_sigma=threshold_sigma,
                             segment_sigma=min(SEGMENT_SIGMA, threshold_sigma), sigma=sigma,
                             inv_gain=inv_gain or 0.0, bad=bad, saturated=saturated, fit=refine == "gaussian")
    return result, sigma


def extract_stars(image, *, threshold_sigma=5.0, max_stars=None, refine="gaussian",
                  psf_sigma_px=None, gain_e_per_adu=None, saturation_adu=None, smear_px=None) -> Extraction:
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
        and fitted with the smeared PSF; their positions are the streaks' midpoints
        (mid-exposure for a constant rate). Not given, the smear is estimated from the
        brightest objects (second moments, then fits), and the same is done when it is
        3 px or longer and the fits agree on it (``smear_px`` of the result).

    Returns
    -------
    Extraction
        Stars brightest first; zero stars is a valid result (an empty sky).
    """
    _check_args(threshold_sigma, max_stars, refine, psf_sigma_px, gain_e_per_adu)
    hint = _check_smear(smear_px)
    arr, quantum = _prepare(image)
    saturation = _saturation_level(arr, saturation_adu)
    n_sat = int(np.count_nonzero(arr >= saturation)) if math.isfinite(saturation) else 0
    if n_sat >= OVEREXPOSED_FRACTION * arr.size:
        raise ShipstarError(f"frame is overexposed: {100.0 * n_sat / arr.size:.0f}% of its pixels are saturated")
    mesh = estimate_mesh(arr, quantum_adu=quantum)
    peaks, labels_of_peaks, idx, labels, mask = _detect(arr, mesh, float(threshold_sigma))
    stats = _component_stats(arr, mesh, idx, labels, labels_of_peaks, saturation)
    inv_gain = None if gain_e_per_adu is None else 1.0 / float(gain_e_per_adu)
    sigma_given = None if psf_sigma_px is None else float(psf_sigma_px)
    sat_mask = (arr >= saturation) if (hint is None and n_sat and math.isfinite(saturation)) else None
    smear, sigma_s, gain_s = _frame_smear(arr, mesh, stats, hint, sigma_given, inv_gain, sat_mask)
    if smear is not None:
        res, sigma = _extract_smeared(arr, mesh, idx, labels, stats, smear, sigma_s, gain_s, saturation,
                                      float(threshold_sigma), refine)
        return _result(res, mesh, sigma, arr.shape, max_stars, smear)
    row, col = np.divmod(peaks, arr.shape[1])
    bg, noise = mesh.at(col, row)
    sigma, inv_gain = _psf_and_gain(arr, col, row, bg, noise, stats, psf_sigma_px, inv_gain)
    sharp_sigma = sigma if math.isfinite(sigma) else SHARPEST_PSF_SIGMA_PX
    keep = ~_too_sharp(arr, mesh, peaks, sharp_sigma, inv_gain, (stats["flags"] & FLAG_SATURATED) != 0)
    peaks, stats = peaks[keep], {k: v[keep] for k, v in stats.items()}
    xy, flux, snr, xy_cov, flags, sigma = _centroids(arr, mesh, peaks, stats, refine, sigma, inv_gain)
    res = dict(xy=xy, flux=flux, peak=stats["peak"], npix=stats["npix"], flags=flags, snr=snr, xy_cov=xy_cov)
    return _result(res, mesh, sigma, arr.shape, max_stars, np.zeros(2))


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
