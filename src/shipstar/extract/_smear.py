"""The common smear of a frame: estimated from its brightest objects, and its field.

All stars of a frame move by nearly the same image vector during the exposure (up to
field rotation and perspective, a few per cent over a star-sensor field). Without the
caller's hint it is estimated:

1. from the brightest objects' second moments: each streak adds ``L^2 / 12`` of variance
   along its direction; the medians of ``mxx - myy`` and ``2 mxy`` over up to 15
   objects give ``L^2 / 12 (cos 2 theta, sin 2 theta)`` (a round star adds nothing, so
   unsmeared frames give ~0); when no object is bright enough (faint stars, long
   smears broken into pieces), in the frame binned 4 x 4;
2. refined, with the PSF sigma when it is not given, by fits of the smeared PSF with
   free smear (x, y, F, b, [sigma], dx, dy) on the brightest objects: the medians.

The frame is treated as smeared only when these fits agree (see :func:`frame_smear`).
Then :func:`smear_field` fits an affine smear field to free-smear fits of the stars
found, which the final fits use star by star.
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.extract._background import estimate_mesh, median
from shipstar.extract._detect import sum_dtype
from shipstar.extract._fit import _spd_inverse, inv_gain_from_residuals
from shipstar.extract._point import bright_objects, component_stats, detect_objects
from shipstar.extract._result import FLAG_EDGE

__all__ = ["STREAK_MIN_PX", "FIELD_MIN_PX", "smear_from_moments", "binned_guess", "calibrate", "frame_smear",
           "spread_over_field", "AffineField", "smear_field"]

#: Smears shorter than this (px) are left to the point-source path (a Gaussian fit of a
#: 1.5 px smear is unbiased and loses < 3 % of its precision).
STREAK_MIN_PX = 1.5
#: Smallest moment-based smear guess worth refining by fits, px.
SMEAR_GUESS_MIN_PX = 2.0
#: Shortest estimated smear (no hint) for which the frame is treated as smeared, px.
AUTO_SMEAR_MIN_PX = 3.0
#: Binning of the frame in which a smear is looked for when no object is bright enough in the frame.
BIN_PX = 4
#: Detection threshold in the binned frame.
_BINNED_SIGMA = 5.0
#: Objects used to estimate the smear, PSF and gain ...
_CALIBRATION_STARS = 12
#: ... taken over this many regions a side (:func:`spread_over_field`).
_SPREAD_CELLS = 3
#: Their fits stop at this fraction of the predicted errors (only medians over them are used),
#: or after this many iterations (the few that take longer are left out).
_CALIBRATION_CONVERGED = 0.2
_CALIBRATION_ITERATIONS = 8
#: Without a hint (:func:`frame_smear`), a fit whose flux is measured below this SNR (its own
#: covariance) is not used: an object at the noise's level (the binned frame's detections in
#: a faint frame) has a smear that its own errors leave undetermined (two such fits of a
#: 1.7 px frame, flux 2.7-3.2 sigma, agreed on an 8 px smear within their 2 px errors and
#: outvoted the one star, flux 110 sigma, that measured it within 0.06 px).  Not applied to
#: a hint's refinement (``_smeared._refined_smear``), which keeps the hint unless 3 fits
#: agree: there it cost the realistic session 0.02-0.04'' of joint RMS.
_CALIBRATION_MIN_SNR = 5.0
#: Smears at least this long (px) get a smear field fitted (shorter: its variation is negligible).
FIELD_MIN_PX = 6.0
#: Stars with at least this line-filter SNR give the smear field, the brightest ``_FIELD_STARS``.
_FIELD_SNR = 8.0
_FIELD_STARS = 60
#: Gauss-Newton steps of the free-smear fits that give the field (from converged common-smear fits).
_FIELD_STEPS = 2
#: Stars needed for an affine smear field (fewer: the 3-parameter field rotation).
_AFFINE_STARS = 25


def smear_from_moments(moments, flux, usable, npix):
    """Common smear (2,) from the second moments of the brightest objects, or None.

    Parameters
    ----------
    moments : (N, 3) array
        ``mxx, myy, mxy`` of each object's pixels (image axes, px^2).
    flux : (N,) array
        Brightness used to pick the objects.
    usable : (N,) bool
        Objects that may be used (not at the border).
    npix : (N,) int
        Pixels of each object; at least 9 are needed.
    """
    pick = np.flatnonzero(usable & (npix >= 9))
    pick = pick[np.argsort(-flux[pick], kind="stable")][:15]
    if len(pick) < 3:
        return None
    c = median(moments[pick, 0] - moments[pick, 1])
    s = median(2.0 * moments[pick, 2])
    length = math.sqrt(12.0 * math.hypot(c, s))
    theta = 0.5 * math.atan2(s, c)
    return np.array([length * math.cos(theta), length * math.sin(theta)])


def binned_guess(arr):
    """Smear guess and bright objects' centres from the frame binned ``BIN_PX`` x ``BIN_PX``, or (None, None).

    Binning adds a streak's light across its width and along it (``BIN_PX`` px), so a
    long streak too faint to be found pixel by pixel forms one object in the binned frame.
    """
    height, width = (s - s % BIN_PX for s in arr.shape)
    if min(height, width) < BIN_PX * 16:
        return None, None
    binned = np.zeros((height // BIN_PX, width // BIN_PX), dtype=sum_dtype(arr))
    for i in range(BIN_PX):                  # strided adds: 20 x faster than a reshaped sum over two axes
        for j in range(BIN_PX):
            binned += arr[i:height:BIN_PX, j:width:BIN_PX]
    mesh = estimate_mesh(binned, quantum_adu=1.0)
    peaks, labels_of_peaks, idx, labels = detect_objects(binned, mesh, _BINNED_SIGMA)
    stats = component_stats(binned, mesh, idx, labels, labels_of_peaks, math.inf)
    usable = (stats["flags"] & FLAG_EDGE) == 0
    guess = smear_from_moments(stats["moments"], stats["cog_flux"], usable, np.maximum(stats["npix"], 9))
    if guess is None:
        return None, None
    cog = stats["cog"][bright_objects(stats)] * BIN_PX + 0.5 * (BIN_PX - 1)
    return guess * BIN_PX, cog


def spread_over_field(col, row, shape_hw, n: int, cells: int = _SPREAD_CELLS) -> np.ndarray:
    """Indices of up to ``n`` of the streaks ``col``, ``row`` (brightest first) spread over
    the field: the brightest of each of ``cells`` x ``cells`` regions, then each region's
    second brightest, and so on (within a round, brightest first).

    The smear varies over the field (a turn about the boresight rotates it, by +-11 % on
    A1 at 80 ms): the median smear of the brightest streaks is that of wherever they are,
    and on a field of equally bright stars the first ones found are one corner's (4-8 %
    short on the tests' grid frames); spread over the field, it is the field's middle's
    (:func:`calibrate`'s objects, with a hint or without).
    """
    if len(col) <= n:
        return np.arange(len(col))
    height, width = shape_hw
    col, row = np.asarray(col, np.int64), np.asarray(row, np.int64)
    region = np.clip(row * cells // height, 0, cells - 1) * cells + np.clip(col * cells // width, 0, cells - 1)
    by_region = np.argsort(region, kind="stable")              # each region's, brightest first
    grouped = region[by_region]
    rank = np.empty(len(col), dtype=np.int64)                  # each one's place among its region's
    rank[by_region] = np.arange(len(col)) - np.searchsorted(grouped, grouped)
    return np.sort(np.lexsort((np.arange(len(col)), rank))[:n])


def calibrate(image, mesh, bad, col, row, smear, sigma, inv_gain, *, fit_smear, min_snr=0.0):
    """Smear, PSF sigma and inverse gain from the brightest objects (``col``, ``row``: brightest first).

    ``sigma`` / ``inv_gain`` None means unknown (fitted / estimated); ``fit_smear`` refines
    ``smear``; fits whose flux SNR is below ``min_snr`` are not used (0: every converged
    fit). Returns ``(smear (2,), sigma, inv_gain, (n, spread))``: the inputs when
    nothing converges; ``n`` objects whose fits gave the smear and the median distance of
    their smear vectors from the median one, px (``inf`` without ``fit_smear``).
    """
    # the streak fits are imported here: a frame of point sources never needs them
    from shipstar.extract._streak import (BG, DX, FLUX, SIGMA, fit_streaks, gather_streak_windows, path_points,
                                          start_parameters, streak_half_sizes, streak_normal_equations)

    fit_sigma = sigma is None
    sigma0 = 1.0 if fit_sigma else float(sigma)
    sigma_out, gain_out = sigma, inv_gain
    col, row = col[:_CALIBRATION_STARS], row[:_CALIBRATION_STARS]
    if len(col) == 0:
        return np.asarray(smear, dtype=float), sigma, inv_gain, (0, math.inf)
    bg, noise = mesh.at(col, row)
    smear = np.asarray(smear, dtype=float)
    spread, n_ok = math.inf, 0
    for _ in range(2 if fit_smear else 1):
        length = float(np.hypot(*smear))
        reach = 1.2 * np.abs(smear) + 2.0 if fit_smear else np.abs(smear)
        hx, hy = streak_half_sizes(reach, 1.5 if fit_sigma else sigma0, 3.0)
        win = gather_streak_windows(image, col, row, hx, hy, bg, noise, bad)
        nodes = path_points(1.3 * length + 2.0 if fit_smear else length, min(sigma0, 0.8))
        fit = fit_streaks(win, start_parameters(win, col, row, sigma0, smear), nodes, fit_sigma=fit_sigma,
                          fit_smear=fit_smear, inv_gain=inv_gain or 0.0, max_iterations=_CALIBRATION_ITERATIONS,
                          converged_fraction=_CALIBRATION_CONVERGED)
        p, ok = fit.p, (fit.ok & _measured(fit.p[:, FLUX], fit.normal, min_snr)) if min_snr > 0.0 else fit.ok
        if not np.any(ok):
            break
        if fit_smear:
            fitted = p[ok][:, DX:]
            fitted *= np.where(fitted @ smear < 0, -1.0, 1.0)[:, None]   # (dx, dy) and -(dx, dy): the same streak
            previous, smear = smear, np.median(fitted, axis=0)
            spread = median(np.hypot(*(fitted - smear).T))
            n_ok = int(np.count_nonzero(ok))
            again = np.hypot(*(smear - previous)) > 0.1 * np.hypot(*previous) + 0.5   # windows were too small
        if fit_sigma:
            sigma0 = sigma_out = median(p[ok, SIGMA])
        if inv_gain is None:
            sel = np.flatnonzero(ok)
            _, _, model, jac_t = streak_normal_equations(p[sel], win.take(sel), nodes, fit_sigma=fit_sigma,
                                                         fit_smear=fit_smear)
            n = len(sel)
            gain_out = inv_gain_from_residuals(win.values[sel].reshape(n, -1), win.valid[sel].reshape(n, -1),
                                               win.noise[sel], model, jac_t, p[sel, BG])
        if not (fit_smear and again):
            break
    return smear, sigma_out, gain_out, (n_ok, spread)


def _measured(flux, normal, min_snr):
    """``(N,)`` bool: fits whose flux is measured at ``min_snr`` or better (the flux's
    variance from the inverse of each fit's normal matrix ``normal`` (N, k, k), flux its
    third parameter)."""
    if len(normal) == 0:
        return np.zeros(0, dtype=bool)
    with np.errstate(invalid="ignore"):
        return flux >= min_snr * np.sqrt(_spd_inverse(normal)[:, 2, 2])


def frame_smear(arr, mesh, stats, hint, sigma, inv_gain, saturated):
    """(smear (2,) or None for the point-source path, sigma, inv_gain) of the frame.

    Without a hint the frame is treated as smeared only on firm evidence: a moment-based
    guess of at least ``AUTO_SMEAR_MIN_PX``, confirmed by at least 3 fits of the
    brightest objects whose smear vectors agree (median distance from their median
    <= 20 % of its length + 0.5 px). Elongated PSFs of real lenses and odd bright
    objects (a roof's edge) do not pass; smears shorter than that are well measured by
    the point-source path.
    """
    if hint is not None:
        return (hint if math.hypot(*hint) >= STREAK_MIN_PX else None), sigma, inv_gain
    usable = (stats["flags"] & FLAG_EDGE) == 0
    guess = smear_from_moments(stats["moments"], stats["cog_flux"], usable, stats["npix"])
    cog = stats["cog"][bright_objects(stats)]
    if guess is None:                      # no bright object: faint stars, or long smears broken up
        guess, cog = binned_guess(arr)
    if guess is None or math.hypot(*guess) < SMEAR_GUESS_MIN_PX:
        return None, sigma, inv_gain
    col, row = np.rint(cog).astype(np.int64).T
    pick = spread_over_field(col, row, arr.shape, _CALIBRATION_STARS)
    col, row = col[pick], row[pick]
    smear, sigma_f, gain_f, (n_ok, spread) = calibrate(arr, mesh, saturated, col, row, guess, sigma, inv_gain,
                                                       fit_smear=True, min_snr=_CALIBRATION_MIN_SNR)
    length = math.hypot(*smear)
    if length < AUTO_SMEAR_MIN_PX or n_ok < 3 or spread > 0.2 * length + 0.5:
        return None, sigma, inv_gain
    return smear, sigma_f, gain_f


class AffineField:
    """Smear vector as an affine function of the image position: ``s(p) = s0 + A (p - centre)``."""

    def __init__(self, s0, a, centre):
        self.s0, self.a, self.centre = np.asarray(s0), np.asarray(a), np.asarray(centre)

    def __call__(self, xy):
        return self.s0 + (np.asarray(xy) - self.centre) @ self.a.T


def smear_field(win, p, ok, snr, nodes, inv_gain, smear):
    """The frame's smear field from free-smear fits of its stars, or None.

    Field rotation (a turn about the boresight) and perspective make the smear vary
    linearly over the image: by +-2 px on a 25 px smear for sensor A1 rolling with a
    ship at 4 deg/s, which costs faint stars up to 40 % of their precision along the
    streak if ignored. Up to ``_FIELD_STARS`` stars (the brightest with a line-filter
    SNR >= ``_FIELD_SNR`` whose common-smear fit ``p`` (N, 7) converged, ``ok``) are
    fitted again with free (dx, dy), from there: a few iterations. A field
    (:func:`_fit_field`) is fitted to their smear vectors, weighted by their predicted
    errors. None if fewer than 4 stars converge or the smear is shorter than
    ``FIELD_MIN_PX``.
    """
    from shipstar.extract._streak import BG, DX, DY, FLUX, X, Y, streak_normal_equations

    if float(np.hypot(*smear)) < FIELD_MIN_PX:
        return None
    pick = np.flatnonzero(ok & (snr >= _FIELD_SNR))
    pick = pick[np.argsort(-snr[pick], kind="stable")][:_FIELD_STARS]
    if len(pick) < 4:
        return None
    sub, q = win.take(pick), p[pick].copy()
    length = float(np.hypot(*smear))
    for _ in range(_FIELD_STEPS):                     # Gauss-Newton steps in (x, y, F, b, dx, dy)
        a, g, _, _ = streak_normal_equations(q, sub, nodes, fit_smear=True, inv_gain=inv_gain)
        cov = _spd_inverse(a)
        step = (cov @ g[:, :, None])[:, :, 0]
        q[:, [X, Y, FLUX, BG, DX, DY]] += np.clip(step, -0.25 * length, 0.25 * length)
    fine = np.all(np.isfinite(q), axis=1) & (np.hypot(*(q[:, DX:] - p[pick, DX:]).T) <= 0.25 * length)
    if np.count_nonzero(fine) < 4:
        return None
    var = np.diagonal(cov[fine], axis1=1, axis2=2)[:, -2:]             # (M, 2) of dx, dy
    q = q[fine]
    vec = q[:, DX:] * np.where(q[:, DX:] @ smear < 0, -1.0, 1.0)[:, None]
    centre = q[:, :2].mean(axis=0)
    weight = 1.0 / np.maximum(var, 1e-12)
    return _fit_field(q[:, :2] - centre, vec, weight, centre)


def _field_design(d, affine):
    """Rows (2 M, k) of the field's linear model at offsets ``d`` (M, 2) from the centre: x rows, then y rows.

    Rotation model (k = 3): ``s = s0 + phi (-dy, dx)``; affine (k = 6): ``s = s0 + A d``.
    """
    m = len(d)
    one, zero = np.ones(m), np.zeros(m)
    if affine:
        x_rows = np.column_stack([one, zero, d[:, 0], d[:, 1], zero, zero])
        y_rows = np.column_stack([zero, one, zero, zero, d[:, 0], d[:, 1]])
    else:
        x_rows = np.column_stack([one, zero, -d[:, 1]])
        y_rows = np.column_stack([zero, one, d[:, 0]])
    return np.concatenate([x_rows, y_rows])


def _fit_field(d, vec, weight, centre):
    """Weighted least-squares smear field (3.5-sigma outliers rejected) of smear vectors ``vec`` at ``d``.

    A turn about the boresight rotates the smear field (3 parameters: the field rotation
    model, exact up to perspective, ~0.6 % of the smear over sensor A1's field); with
    ``_AFFINE_STARS`` stars or more, a general affine field (6) takes perspective too.
    """
    affine = len(d) >= _AFFINE_STARS
    design = _field_design(d, affine)
    target = np.concatenate([vec[:, 0], vec[:, 1]])
    w = np.sqrt(np.concatenate([weight[:, 0], weight[:, 1]]))
    use = np.ones(len(d), dtype=bool)
    for _ in range(3):
        rows = np.concatenate([use, use])
        coef = np.linalg.lstsq(design[rows] * w[rows, None], target[rows] * w[rows], rcond=None)[0]
        z = ((target - design @ coef) * w).reshape(2, -1)
        keep = np.all(np.abs(z) <= 3.5, axis=0)
        if np.count_nonzero(keep) < 4 or np.array_equal(keep, use):
            break
        use = keep
    if affine:
        a = np.array([[coef[2], coef[3]], [coef[4], coef[5]]])
    else:
        a = np.array([[0.0, -coef[2]], [coef[2], 0.0]])
    return AffineField(coef[:2], a, centre)
