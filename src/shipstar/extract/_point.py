"""Point sources: detection on candidate pixels, components, PSF and gain, Gaussian centroids.

The path of unsmeared frames (and of smears shorter than ``STREAK_MIN_PX``):

1. candidate pixels above ``background + 2.5 sigma`` (one comparison pass), their local
   maxima, and the detection test on each maximum's 3x3 sum (``threshold_sigma``);
2. 8-connected components of the candidates (one star per component: size, peak,
   saturation, border contact, elongation, second moments);
3. the PSF sigma (and, if not given, the gain) from the brightest stars; hot pixels and
   cosmic rays rejected as sharper than the frame's PSF;
4. centroids: a pixel-integrated Gaussian fitted by vectorised Gauss-Newton on a fixed
   window (``refine="gaussian"``) or the thresholded centre of gravity.
"""

from __future__ import annotations

import math

import numpy as np

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
from shipstar.extract._kernels import component_stats as kernel_component_stats
from shipstar.extract._kernels import point_objects as kernel_point_objects
from shipstar.extract._kernels import too_sharp as kernel_too_sharp
from shipstar.extract._result import FLAG_EDGE, FLAG_ELONGATED, FLAG_FIT_FAILED, FLAG_SATURATED

__all__ = ["SEGMENT_SIGMA", "SHARPEST_PSF_SIGMA_PX", "detect_objects", "component_stats", "bright_objects",
           "too_sharp", "measure_points"]

#: Per-pixel level of the candidate (segmentation) pixels, in noise sigmas.
SEGMENT_SIGMA = 2.5
#: A peak whose 8 neighbours hold less than this fraction of the peak pixel's excess is a
#: single-pixel event (hot pixel, cosmic ray): even a sharp star (sigma 0.5 px, centred)
#: puts 1.1 times its peak pixel into the neighbours.
SINGLE_PIXEL_RATIO = 0.5
#: A peak whose neighbours hold significantly (this many sigma) less than the frame's PSF
#: allows is not a star (hot pixel, cosmic ray): see ``too_sharp``.
SHARPNESS_SIGMA = 3.0
#: ... tested against a PSF this much narrower than the fitted one.
SHARPNESS_MARGIN = 0.8
#: PSF sigma assumed by that test when the frame's cannot be fitted (no star in it).
SHARPEST_PSF_SIGMA_PX = 0.5
#: Axis ratio of the second moments above which a star is flagged elongated.
ELONGATION_LIMIT = 2.0


def detect_objects(arr, mesh, threshold_sigma):
    """Star peaks (flat indices, one per component), their components, candidate indices and labels.

    The candidates in one pass over the frame, then the peaks among them in one compiled call
    (:func:`shipstar.extract._kernels.point_objects`: the steps of :func:`_detect_objects_python`
    bit for bit, ~0.15 ms of NumPy calls a frame).
    """
    idx = candidate_pixels(arr, mesh, min(SEGMENT_SIGMA, threshold_sigma))
    peaks, peak_label, labels = kernel_point_objects(arr, idx, mesh.bg, mesh.noise, mesh.block_px,
                                                     threshold_sigma * mesh.box_noise_factor, SINGLE_PIXEL_RATIO)
    return peaks, peak_label, idx, labels


def _detect_objects_python(arr, mesh, threshold_sigma):
    """:func:`detect_objects` in NumPy (the compiled kernel's reference)."""
    shape = arr.shape
    flat = arr.reshape(-1)
    idx = candidate_pixels(arr, mesh, min(SEGMENT_SIGMA, threshold_sigma))
    peaks = local_maxima(flat, idx, shape)
    box, count = box_sums(flat, peaks, shape)
    row, col = np.divmod(peaks, shape[1])
    bg, noise = mesh.at(col, row)
    box_excess = box - count * bg
    peak_excess = flat[peaks] - bg
    star = (box_excess >= threshold_sigma * mesh.box_noise_factor * np.sqrt(count) * noise) & \
           (box_excess - peak_excess >= SINGLE_PIXEL_RATIO * peak_excess)
    peaks, box_excess = peaks[star], box_excess[star]
    labels, _ = components(idx, shape)
    peak_label = labels[np.searchsorted(idx, peaks)]
    order = np.argsort(-box_excess, kind="stable")
    _, first = np.unique(peak_label[order], return_index=True)
    keep = np.sort(order[first])
    return peaks[keep], peak_label[keep], idx, labels


def component_stats(arr, mesh, idx, labels, star_labels, saturation):
    """Per star: npix, peak value, saturated/edge/elongated, thresholded centre of gravity
    (compiled: :func:`_component_stats_python`'s values, bit for bit)."""
    n, pix, who, row, col, bg = _star_pixels(arr, mesh, idx, labels, star_labels)
    return kernel_component_stats(arr, pix, who, bg, n, saturation, ELONGATION_LIMIT ** 2, FLAG_SATURATED, FLAG_EDGE,
                                  FLAG_ELONGATED)


def _star_pixels(arr, mesh, idx, labels, star_labels):
    """``(n, pix, who, row, col, bg)``: the candidate pixels ``idx`` of the components of the
    ``n`` stars ``star_labels``, each one's star (0 .. n - 1), position and mesh background."""
    n = len(star_labels)
    star_of_label = np.full(labels.max() + 1 if labels.size else 0, -1)
    star_of_label[star_labels] = np.arange(n)
    star = star_of_label[labels] if labels.size else np.zeros(0, dtype=int)
    sel = star >= 0
    pix, who = idx[sel], star[sel]
    row, col = np.divmod(pix, arr.shape[1])
    bg, _ = mesh.at(col, row)
    return n, pix, who, row, col, bg


def _component_stats_python(arr, mesh, idx, labels, star_labels, saturation):
    """:func:`component_stats` in NumPy (the compiled kernel's reference)."""
    height, width = arr.shape
    n, pix, who, row, col, bg = _star_pixels(arr, mesh, idx, labels, star_labels)
    values = arr.reshape(-1)[pix].astype(float)
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


def bright_objects(stats):
    """Indices of unsaturated objects off the border, brightest first."""
    usable = np.flatnonzero((stats["flags"] & (FLAG_SATURATED | FLAG_EDGE)) == 0)
    return usable[np.argsort(-stats["cog_flux"][usable], kind="stable")]


def _psf_and_gain(arr, col, row, bg, noise, stats, psf_sigma_px, inv_gain):
    """PSF sigma and inverse gain: given, or fitted on the brightest clean stars."""
    usable = np.flatnonzero((stats["flags"] & (FLAG_SATURATED | FLAG_EDGE)) == 0)
    if (psf_sigma_px is not None and inv_gain is not None) or usable.size == 0:
        return (math.nan if psf_sigma_px is None else float(psf_sigma_px)), (inv_gain or 0.0)
    bright = usable[np.argsort(-stats["cog_flux"][usable], kind="stable")]
    sigma, inv_gain = estimate_psf_sigma(arr, col[bright], row[bright], bg[bright], noise[bright],
                                         inv_gain=inv_gain)
    return (sigma if psf_sigma_px is None else float(psf_sigma_px)), inv_gain


def too_sharp(arr, mesh, peaks, sigma, inv_gain, saturated):
    """Peaks significantly sharper than the frame's PSF allows: hot pixels, cosmic rays.

    Two one-sided tests (``SHARPNESS_SIGMA``) against :func:`neighbour_ratios` of a PSF
    ``SHARPNESS_MARGIN`` times narrower than the frame's (PSF changes over the field,
    error of the fitted sigma): the 8 neighbours' total, and the two faintest edge
    neighbours (a cosmic-ray line of 2-3 pixels leaves them empty).  Compiled
    (``_kernels.too_sharp``): :func:`_too_sharp_python`'s answer.
    """
    row, col = np.divmod(np.asarray(peaks, dtype=np.int64), arr.shape[1])
    bg, noise = mesh.at(col, row)
    ratio_total, ratio_edges = neighbour_ratios(SHARPNESS_MARGIN * sigma)
    return kernel_too_sharp(arr, peaks, bg, noise * mesh.box_noise_factor, saturated, inv_gain, ratio_total,
                            ratio_edges, SHARPNESS_SIGMA)


def _too_sharp_python(arr, mesh, peaks, sigma, inv_gain, saturated):
    """:func:`too_sharp` in NumPy (the compiled kernel's reference)."""
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
    start_flux = p[:, 2]                    # (the start's flux does not depend on the sigma given)
    ok = np.zeros(len(peaks), dtype=bool)
    if refine == "gaussian":
        if have_sigma:
            p, ok = fit_gaussian(win, p, inv_gain=inv_gain)
        ok &= ~saturated & (p[:, 2] > 0)
        flags = flags | np.where(ok | saturated, 0, FLAG_FIT_FAILED)
    xy = np.where(ok[:, None], p[:, :2], stats["cog"])
    flux = np.where(ok, p[:, 2], start_flux)
    flux = np.where(saturated, np.maximum(flux, stats["cog_flux"]), flux)
    centre = np.column_stack([win.x0, win.y0]) + win.size // 2
    p_at = np.column_stack([np.clip(xy, centre - 1.0, centre + 1.0), flux, p[:, 3],
                            np.full(len(xy), sigma if have_sigma else 1.0)])
    cov = covariance(win, p_at, inv_gain=inv_gain) * mesh.box_noise_factor ** 2   # correlated (JPEG) noise
    snr = flux / np.sqrt(cov[:, 2, 2])
    unknown = saturated | ((flags & FLAG_FIT_FAILED) != 0) | (not have_sigma)
    xy_cov = np.where(unknown[:, None, None], np.nan, cov[:, :2, :2])
    return xy, flux, snr, xy_cov, flags, sigma


def measure_points(arr, mesh, peaks, stats, refine, psf_sigma_px, inv_gain):
    """Centroids of the point sources ``peaks`` (flat indices) with their component ``stats``.

    Returns the dict of per-star arrays (xy, flux, peak, npix, flags, snr, xy_cov) and the
    PSF sigma used (NaN if none could be fitted).
    """
    row, col = np.divmod(peaks, arr.shape[1])
    bg, noise = mesh.at(col, row)
    sigma, inv_gain = _psf_and_gain(arr, col, row, bg, noise, stats, psf_sigma_px, inv_gain)
    sharp_sigma = sigma if math.isfinite(sigma) else SHARPEST_PSF_SIGMA_PX
    keep = ~too_sharp(arr, mesh, peaks, sharp_sigma, inv_gain, (stats["flags"] & FLAG_SATURATED) != 0)
    peaks, stats = peaks[keep], {k: v[keep] for k, v in stats.items()}
    xy, flux, snr, xy_cov, flags, sigma = _centroids(arr, mesh, peaks, stats, refine, sigma, inv_gain)
    res = dict(xy=xy, flux=flux, peak=stats["peak"], npix=stats["npix"], flags=flags, snr=snr, xy_cov=xy_cov)
    return res, sigma
