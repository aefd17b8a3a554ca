"""Smeared frames: hot pixels and cosmic rays masked, line-filter detection, streak fits, flags.

Hot pixels and cosmic rays (peaks much sharper than the PSF) are replaced by the
background and left out of the fits; stars are detected with the line filter
(:mod:`shipstar.extract._matched`) and each is fitted with the smeared PSF
(x, y, F, b; :mod:`shipstar.extract._streak`) of its smear (the frame's smear field,
:func:`shipstar.extract._smear.smear_field`), saturated pixels left out.
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.extract._detect import at_or_above, box_sums, candidate_pixels, local_maxima
from shipstar.extract._fit import _spd_inverse
from shipstar.extract._kernels import streak_footprint
from shipstar.extract._matched import LineFilter, detect_streaks
from shipstar.extract._point import SEGMENT_SIGMA, SHARPEST_PSF_SIGMA_PX, bright_objects, too_sharp
from shipstar.extract._result import FLAG_EDGE, FLAG_ELONGATED, FLAG_FIT_FAILED, FLAG_SATURATED
from shipstar.extract._smear import (_CALIBRATION_STARS, FIELD_MIN_PX, STREAK_MIN_PX, binned_guess, calibrate,
                                     smear_field, spread_over_field)
from shipstar.extract._streak import (
    BG,
    DX,
    FLUX,
    fit_streaks,
    gather_streak_windows,
    path_points,
    start_parameters,
    streak_half_sizes,
    streak_normal_equations,
)

__all__ = ["sharp_pixels", "measure_streaks", "extract_smeared", "measure_short_streaks"]

#: A hot pixel's or cosmic ray's whole connected component is masked when it has at most this many pixels.
_SHARP_COMPONENT_PX = 9
#: Window margin beyond the streak +- 3 sigma, px: the start's error along the streak.
_MARGIN_PX = 2.0
#: Per-star smears may differ from the common one by this fraction (field rotation, perspective):
#: windows and the model's path allow for it.
_FIELD_FRACTION = 0.1
#: The fits again with the smear field start at the solutions for the common smear: a step below
#: this fraction of a star's predicted error (Gauss-Newton from next to the optimum) ends it.
_REFIT_CONVERGED = 0.2
#: A line-filter peak whose fitted flux SNR is below this fraction of the detection threshold is
#: noise (the fit is the matched filter itself, the line filter ~90 % of it).
_FIT_SNR_FRACTION = 0.8
#: Fraction of a star's largest model pixel that delimits its footprint (flags, peak value).
_FOOTPRINT_FRACTION = 0.02


def sharp_pixels(image, mesh, too_sharp, segment_sigma=SEGMENT_SIGMA, idx=None):
    """Flat indices of hot pixels and cosmic rays: the local maxima >= 5 sigma that ``too_sharp``
    rejects, with the rest of their small connected component, or their 3 x 3 neighbours
    when they sit on something larger (a cosmic ray on a star).

    Only pixels a little below 5 sigma are gathered (``image > bg + 3.5 noise``: stars'
    cores, hot pixels, cosmic rays), so no full segmentation of the frame is needed. A
    peak's component is judged in the 7 x 7 box around it: pixels above ``segment_sigma``
    on the box's border mean a large component; else the <= ``_SHARP_COMPONENT_PX`` such
    pixels of the inner 5 x 5 are the component (a cosmic ray of 1-3 pixels in a line).
    ``too_sharp(peaks) -> (M,) bool``. ``idx``: the pixels above that level, sorted flat
    indices, when the caller has them (windows around predicted stars); else one pass
    over the frame finds them.
    """
    flat = image.reshape(-1)
    height, width = image.shape
    if idx is None:
        idx = candidate_pixels(image, mesh, 3.5 * mesh.box_noise_factor)
    peaks = local_maxima(flat, idx, image.shape)
    row, col = np.divmod(peaks, width)
    bg, noise = mesh.at(col, row)
    keep = flat[peaks] - bg >= 5.0 * noise * mesh.box_noise_factor
    peaks, row, col, bg, noise = peaks[keep], row[keep], col[keep], bg[keep], noise[keep]
    sharp = too_sharp(peaks) if len(peaks) else np.zeros(0, dtype=bool)
    peaks, row, col, bg, noise = peaks[sharp], row[sharp], col[sharp], bg[sharp], noise[sharp]
    if not len(peaks):
        return peaks
    d = np.arange(-3, 4)
    rows, cols = row[:, None, None] + d[:, None], col[:, None, None] + d[None, :]
    inside = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
    values = flat[np.clip(rows, 0, height - 1) * width + np.clip(cols, 0, width - 1)]
    above = inside & (values > (bg + segment_sigma * noise)[:, None, None])
    ring = np.ones((7, 7), dtype=bool)
    ring[1:-1, 1:-1] = False
    core = np.zeros((7, 7), dtype=bool)
    core[2:5, 2:5] = True
    small = ~np.any(above & ring, axis=(1, 2)) & (np.sum(above, axis=(1, 2)) <= _SHARP_COMPONENT_PX)
    take = np.where(small[:, None, None], above & ~ring, core & inside)
    take[:, 3, 3] = True
    return np.unique((rows * width + cols)[take])


def measure_streaks(image, mesh, smear, *, threshold_sigma, segment_sigma, sigma, inv_gain, bad, saturated, patch=None,
                    fit=True, refine_smear=False, det=None):
    """Detect and fit the smeared stars of a frame.

    Parameters
    ----------
    image : (H, W) array
        The frame.
    mesh : Mesh
    smear : (2,) array
        Common smear (dx, dy), px.
    threshold_sigma, segment_sigma : float
        Detection threshold of the line filter's peaks, and of its segmentation, in its noise.
    sigma, inv_gain : float
        PSF sigma and inverse gain (0: uniform weights).
    bad, saturated : (H, W) bool
        Pixels left out of the fits (masked or saturated), and the saturated ones (None:
        none is).
    patch : (flat indices (K,), values (K,)), optional
        Pixels replaced by these values (the background) for the detection: hot pixels
        and cosmic rays (also in ``bad``).
    fit : bool
        Fit the smeared PSF (else: the centre of light of each streak's footprint).
    refine_smear : bool
        ``smear`` is a prediction (the caller's hint): the detection uses it, then the
        common smear is measured by free-smear fits of the brightest streaks found
        (:func:`_refined_smear`) and the fits use that.
    det : dict, optional
        The detections, as :func:`shipstar.extract._matched.detect_streaks` returns them
        (``npix`` may be None: then the fitted footprint's pixels), when the caller found
        them (windows around predicted stars); else the line filter finds them in the frame.

    Returns
    -------
    dict of per-star arrays: xy (M, 2), flux, peak, npix, flags, snr, xy_cov (M, 2, 2); and
    ``smear`` (2,), the common smear the fits used (measured again with ``refine_smear``, else
    as given). Peaks whose fit converged with a flux SNR below 0.8 ``threshold_sigma`` are
    dropped (noise).
    """
    if det is None:
        lf = LineFilter(smear, across_px=max(1, int(round(1.2 * sigma))))
        det = detect_streaks(image, mesh, lf, threshold_sigma, segment_sigma, sigma, patch=patch)
    if len(det["col"]) == 0:
        return dict(xy=np.zeros((0, 2)), flux=np.zeros(0), peak=np.zeros(0), npix=np.zeros(0, dtype=np.int64),
                    flags=np.zeros(0, dtype=np.int64), snr=np.zeros(0), xy_cov=np.zeros((0, 2, 2)),
                    smear=np.array(smear, dtype=float))
    col, row = det["col"], det["row"]
    if refine_smear and fit:
        smear = _refined_smear(image, mesh, det, smear, sigma, inv_gain, bad, saturated)
    length = float(np.hypot(*smear))
    hx, hy = streak_half_sizes(smear, sigma, _MARGIN_PX + _FIELD_FRACTION * length)
    bg, noise = mesh.at(col, row)
    win = gather_streak_windows(image, col, row, hx, hy, bg, noise, bad)
    nodes = path_points((1.0 + 2.0 * _FIELD_FRACTION) * length + 1.0, sigma)
    p0 = start_parameters(win, col, row, sigma, smear)
    if fit:
        result = _fit_with_field(win, p0, nodes, det["snr"], inv_gain, smear)
        p, ok, a, model = result.p, result.ok, result.normal, result.model
        height, width = image.shape
        ok &= np.all((p[:, :2] >= -0.5) & (p[:, :2] <= np.array([width, height]) - 0.5), axis=1)
    else:
        p, ok = p0, np.zeros(len(p0), dtype=bool)
        a, _, model, _ = streak_normal_equations(p, win, nodes, inv_gain=inv_gain)
    failed = np.flatnonzero(~ok)
    if fit and len(failed):                # failed fits: the start values, and the equations there
        p = np.where(ok[:, None], p, p0)
        a, model = a.copy(), model.copy()
        a[failed], _, model[failed], _ = streak_normal_equations(p[failed], win.take(failed), nodes, inv_gain=inv_gain)
    cov = _spd_inverse(a) * mesh.box_noise_factor ** 2
    # compiled: the footprints, their pixel counts and peaks (masked pixels not), and whether
    # they reach a saturated pixel or off the image (_footprint_python's numbers)
    foot, peak, n_foot, any_sat, any_off = streak_footprint(model, p[:, BG], win.values, win.valid, col, row,
                                                            image.shape, _FOOTPRINT_FRACTION, saturated)
    flags = _flags(any_sat, any_off, ok | (not fit), det)
    xy = p[:, :2].copy()
    if len(failed):                        # (a failed fit's: the centre of light of its footprint)
        xy[failed] = _centre_of_light(win.take(failed), foot[failed])
    flux = p[:, FLUX]
    xy_cov = np.where(ok[:, None, None], cov[:, :2, :2], np.nan)
    snr = flux / np.sqrt(cov[:, FLUX, FLUX])
    keep = ~ok | (snr >= _FIT_SNR_FRACTION * threshold_sigma) if fit else np.ones(len(snr), dtype=bool)
    xy, flux, peak, flags, snr, xy_cov = xy[keep], flux[keep], peak[keep], flags[keep], snr[keep], xy_cov[keep]
    npix = n_foot if det["npix"] is None else det["npix"]
    return dict(xy=xy, flux=flux, peak=peak, npix=npix[keep], flags=flags, snr=snr, xy_cov=xy_cov,
                smear=np.array(smear, dtype=float))


def _refined_smear(image, mesh, det, smear, sigma, inv_gain, bad, saturated):
    """The common smear measured from a predicted one: free-smear fits of the brightest
    unsaturated streaks detected with it, taken over the whole field
    (:func:`~shipstar.extract._smear.spread_over_field`,
    :func:`~shipstar.extract._smear.calibrate`), accepted on the evidence
    :func:`shipstar.extract._smear.frame_smear` asks of an estimate (at least 3 fits whose
    smear vectors agree); else the prediction."""
    order = np.argsort(-det["snr"], kind="stable")
    col, row = det["col"][order], det["row"][order]
    clean = np.ones(len(col), dtype=bool) if saturated is None else ~saturated[row, col]
    col, row = col[clean], row[clean]
    pick = spread_over_field(col, row, image.shape, _CALIBRATION_STARS)
    refined, _, _, (n_ok, spread) = calibrate(image, mesh, bad, col[pick], row[pick], smear, sigma, inv_gain,
                                              fit_smear=True)
    length = float(np.hypot(*refined))
    if n_ok < 3 or not spread <= 0.2 * length + 0.5 or length < STREAK_MIN_PX:
        return np.asarray(smear, dtype=float)
    return refined


def _fit_with_field(win, p0, nodes, snr, inv_gain, smear):
    """The streak fits (a :class:`StreakFit`): with the common smear, and for smears of
    ``FIELD_MIN_PX`` or more once more with each star's own (the smear field of
    :func:`smear_field`, fitted to the first fits), from where the first fits got.

    ``p0``'s smear columns are set to the field too (the start values a failed fit keeps).
    """
    if float(np.hypot(*smear)) < FIELD_MIN_PX:
        return fit_streaks(win, p0, nodes, inv_gain=inv_gain)
    # the first fits are the field's start and the second fits': the slowest stars go on there
    result = fit_streaks(win, p0, nodes, inv_gain=inv_gain, max_iterations=8, converged_fraction=_REFIT_CONVERGED)
    field = smear_field(win, result.p, result.ok, snr, nodes, inv_gain, smear)
    sane = np.all(np.isfinite(result.p), axis=1) & np.all(
        np.abs(result.p[:, :2] - win.centre) <= np.array(win.shape[::-1]) / 4.0, axis=1)
    start = np.where(sane[:, None], result.p, p0)
    if field is not None:
        p0[:, DX:] = start[:, DX:] = field(start[:, :2])
    return fit_streaks(win, start, nodes, inv_gain=inv_gain, converged_fraction=_REFIT_CONVERGED)


def _centre_of_light(win, foot):
    """Background-subtracted first moment of the footprint pixels (failed fits)."""
    w = np.where(foot & win.valid, np.maximum(win.values - win.bg[:, None, None], 0.0), 0.0)
    total = np.maximum(w.sum(axis=(1, 2)), 1e-12)
    wy, wx = win.shape
    cx = (w.sum(axis=1) * np.arange(wx)).sum(axis=1) / total
    cy = (w.sum(axis=2) * np.arange(wy)).sum(axis=1) / total
    return np.stack([win.x0 + cx, win.y0 + cy], axis=1)


def _window_mask(mask, window_hw, col, row, shape_hw):
    """``mask`` (H, W) bool (None: all False) at the pixels (N, Wy, Wx) of the windows of
    shape ``window_hw`` centred on ``col``, ``row`` (False off the image), and which are on it."""
    height, width = shape_hw
    wy, wx = window_hw
    rows = row[:, None] + np.arange(wy) - (wy - 1) // 2
    cols = col[:, None] + np.arange(wx) - (wx - 1) // 2
    inside = ((rows >= 0) & (rows < height))[:, :, None] & ((cols >= 0) & (cols < width))[:, None, :]
    if mask is None:
        return np.zeros_like(inside), inside
    return inside & mask[np.clip(rows, 0, height - 1)[:, :, None], np.clip(cols, 0, width - 1)[:, None, :]], inside


def _at(mask, flat_idx):
    """``mask`` (H, W) bool (None: all False) at the flat indices ``flat_idx``."""
    return np.zeros(len(flat_idx), dtype=bool) if mask is None else mask.reshape(-1)[flat_idx]


def _bad(shape_hw, saturated, masked):
    """(H, W) bool: the saturated pixels (None: none) and the flat indices ``masked`` (a fresh
    array: the zeros' pages are mapped as they are written)."""
    bad = np.zeros(shape_hw, dtype=bool) if saturated is None else saturated.copy()
    bad.reshape(-1)[masked] = True
    return bad


def _footprint_python(model, bg, values, valid, col, row, shape_hw, fraction, saturated=None):
    """The compiled :func:`~shipstar.extract._kernels.streak_footprint` in NumPy (its
    reference): ``(foot, peak, npix, saturated, off_image)`` of each star's window."""
    excess = (model - bg[:, None]).reshape(values.shape)
    foot = excess >= fraction * excess.max(axis=(1, 2), keepdims=True)
    sat, inside = _window_mask(saturated, values.shape[1:], col, row, shape_hw)
    peak = np.where(foot & (valid | sat), values, -np.inf).max(axis=(1, 2))
    return foot, peak, foot.sum(axis=(1, 2)), np.any(foot & sat, axis=(1, 2)), np.any(foot & ~inside, axis=(1, 2))


def _flags(any_sat, any_off, ok, det):
    """Per-star flag bits of the streak path (``any_sat``, ``any_off``: the footprint reaches a
    saturated pixel, off the image)."""
    flags = np.where(any_sat, FLAG_SATURATED, 0)
    flags |= np.where(any_off, FLAG_EDGE, 0)
    flags |= np.where(ok, 0, FLAG_FIT_FAILED)
    label = det["label"]
    shared = np.bincount(label)[label] > 1 if len(label) else np.zeros(0, dtype=bool)
    flags |= np.where(det["too_big"] | shared, FLAG_ELONGATED, 0)
    return flags.astype(np.int64)


def extract_smeared(arr, mesh, stats, smear, sigma, inv_gain, saturation, threshold_sigma, refine, refine_smear=False):
    """Centroids of a smeared frame: the dict of :func:`measure_streaks`, and the PSF sigma used.

    ``refine_smear``: ``smear`` is the caller's hint, measured again from the streaks found
    (:func:`measure_streaks`); else it was estimated from the frame already.

    ``sigma`` / ``inv_gain`` None: estimated on the brightest objects, from ``stats``
    (:func:`shipstar.extract._point.component_stats` of the frame's objects; sigma 1 px
    when none can be fitted); ``stats`` is not used when both are given.
    """
    saturated = at_or_above(arr, saturation) if math.isfinite(saturation) else None
    segment_sigma = min(SEGMENT_SIGMA, threshold_sigma)

    def sharp(psf_sigma, gain):
        def test(peaks):
            return too_sharp(arr, mesh, peaks, psf_sigma, gain or 0.0, _at(saturated, peaks))
        return sharp_pixels(arr, mesh, test, segment_sigma)

    if sigma is None or inv_gain is None:
        bad = _bad(arr.shape, saturated, sharp(SHARPEST_PSF_SIGMA_PX if sigma is None else sigma, inv_gain))
        cog = stats["cog"][bright_objects(stats)]
        if len(cog) == 0:
            _, cog = binned_guess(arr)
        if cog is not None and len(cog):
            col, row = np.rint(cog).astype(np.int64).T
            _, sigma, inv_gain, _ = calibrate(arr, mesh, bad, col, row, smear, sigma, inv_gain, fit_smear=False)
    sigma = 1.0 if sigma is None else sigma
    masked = sharp(sigma, inv_gain)
    row, col = np.divmod(masked, arr.shape[1])
    bad = _bad(arr.shape, saturated, masked)
    result = measure_streaks(arr, mesh, smear, threshold_sigma=threshold_sigma, segment_sigma=segment_sigma,
                             sigma=sigma, inv_gain=inv_gain or 0.0, bad=bad, saturated=saturated,
                             patch=(masked, mesh.at(col, row)[0]), fit=refine == "gaussian",
                             refine_smear=refine_smear)
    return result, sigma


def measure_short_streaks(arr, mesh, peaks, idx, stats, smear, sigma, inv_gain, saturation, threshold_sigma, refine):
    """Centroids of a frame whose smear is short (``STREAK_MIN_PX`` to 3 px) and known: the
    stars found as points (``peaks``: one per component of the candidate pixels ``idx``,
    :func:`shipstar.extract._point.detect_objects`; ``stats``: their
    :func:`~shipstar.extract._point.component_stats`), measured as streaks of ``smear``
    (:func:`measure_streaks` with these detections; the smear as given).

    A streak this short is as compact as a point -- the 3 x 3 box detects it as well as the
    line filter -- but its light is not a point's: the streak model (the PSF moved along the
    smear) measures it better than the Gaussian of the point path (docs/extraction.md,
    *Short smears*).  Hot pixels and cosmic rays (:func:`sharp_pixels`, from the candidates
    already found) are left out of the fits and are not stars; saturated pixels are left out
    of the fits.  Returns the dict of :func:`measure_streaks`.
    """
    saturated = at_or_above(arr, saturation) if math.isfinite(saturation) else None
    segment_sigma = min(SEGMENT_SIGMA, threshold_sigma)
    width = arr.shape[1]

    def test(candidates):
        return too_sharp(arr, mesh, candidates, sigma, inv_gain, _at(saturated, candidates))

    masked = sharp_pixels(arr, mesh, test, segment_sigma, idx=idx)      # (idx: a superset of its 3.5 sigma pixels)
    bad = _bad(arr.shape, saturated, masked)
    star = ~np.isin(peaks, masked, assume_unique=True)
    peaks = peaks[star]
    row, col = np.divmod(peaks, width)
    box, count = box_sums(arr.reshape(-1), peaks, arr.shape)
    bg, noise = mesh.at(col, row)
    det = dict(col=col, row=row, snr=(box - count * bg) / (np.sqrt(count) * noise * mesh.box_noise_factor),
               label=np.arange(len(peaks)), npix=stats["npix"][star],
               too_big=(stats["flags"][star] & FLAG_ELONGATED) != 0)
    return measure_streaks(arr, mesh, np.asarray(smear, dtype=float), threshold_sigma=threshold_sigma,
                           segment_sigma=segment_sigma, sigma=sigma, inv_gain=inv_gain, bad=bad, saturated=saturated,
                           fit=refine == "gaussian", refine_smear=False, det=det)
