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

from shipstar.extract._detect import _OFFSETS_RC, _Grid, local_maxima
from shipstar.extract._fit import _spd_inverse
from shipstar.extract._matched import LineFilter, detect_streaks
from shipstar.extract._point import SEGMENT_SIGMA, SHARPEST_PSF_SIGMA_PX, bright_objects, too_sharp
from shipstar.extract._result import FLAG_EDGE, FLAG_ELONGATED, FLAG_FIT_FAILED, FLAG_SATURATED
from shipstar.extract._smear import binned_guess, calibrate, smear_field
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

__all__ = ["sharp_pixels", "measure_streaks", "extract_smeared"]

#: A hot pixel's or cosmic ray's whole connected component is masked when it has at most this many pixels.
_SHARP_COMPONENT_PX = 9
#: Extra window margin and path length for per-star smears that differ from the common one, px.
_FIELD_MARGIN_PX = 2.0
#: A line-filter peak whose fitted flux SNR is below this fraction of the detection threshold is
#: noise (the fit is the matched filter itself, the line filter ~90 % of it).
_FIT_SNR_FRACTION = 0.8
#: Fraction of a star's largest model pixel that delimits its footprint (flags, peak value).
_FOOTPRINT_FRACTION = 0.02


def sharp_pixels(image, mesh, idx, labels, too_sharp):
    """Flat indices of hot pixels and cosmic rays: significant candidate peaks that ``too_sharp``
    rejects, with the rest of their (small) connected component, or their 3 x 3 neighbours
    in a large one (a cosmic ray on a star).

    ``idx``/``labels``: candidate pixels (sorted flat indices) and their components;
    ``too_sharp(peaks) -> (M,) bool``.
    """
    flat = image.reshape(-1)
    peaks = local_maxima(flat, idx, image.shape)
    row, col = np.divmod(peaks, image.shape[1])
    bg, noise = mesh.at(col, row)
    peaks = peaks[flat[peaks] - bg >= 5.0 * noise * mesh.box_noise_factor]
    peaks = peaks[too_sharp(peaks)] if len(peaks) else peaks
    if not len(peaks):
        return peaks
    size = np.bincount(labels)
    label = labels[np.searchsorted(idx, peaks)]
    small = size[label] <= _SHARP_COMPONENT_PX
    out = [idx[np.isin(labels, label[small])]]
    grid = _Grid(peaks[~small], image.shape)
    out.append(peaks[~small])
    for dr, dc in _OFFSETS_RC:
        nb, inside = grid.neighbour(dr, dc)
        out.append(nb[inside])
    return np.unique(np.concatenate(out))


def measure_streaks(image, mesh, smear, *, threshold_sigma, segment_sigma, sigma, inv_gain, bad, saturated, fit=True):
    """Detect and fit the smeared stars of a frame.

    Parameters
    ----------
    image : (H, W) array
        The frame with hot pixels and cosmic rays replaced by the background.
    mesh : Mesh
    smear : (2,) array
        Common smear (dx, dy), px.
    threshold_sigma, segment_sigma : float
        Detection threshold of the line filter's peaks, and of its segmentation, in its noise.
    sigma, inv_gain : float
        PSF sigma and inverse gain (0: uniform weights).
    bad, saturated : (H, W) bool
        Pixels left out of the fits (masked or saturated), and the saturated ones.
    fit : bool
        Fit the smeared PSF (else: the centre of light of each streak's footprint).

    Returns
    -------
    dict of per-star arrays: xy (M, 2), flux, peak, npix, flags, snr, xy_cov (M, 2, 2). Peaks
    whose fit converged with a flux SNR below 0.8 ``threshold_sigma`` are dropped (noise).
    """
    lf = LineFilter(smear, across_px=max(1, int(round(1.2 * sigma))))
    det = detect_streaks(image, mesh, lf, threshold_sigma, segment_sigma, sigma)
    if len(det["col"]) == 0:
        return dict(xy=np.zeros((0, 2)), flux=np.zeros(0), peak=np.zeros(0), npix=np.zeros(0, dtype=np.int64),
                    flags=np.zeros(0, dtype=np.int64), snr=np.zeros(0), xy_cov=np.zeros((0, 2, 2)))
    col, row = det["col"], det["row"]
    length = float(np.hypot(*smear))
    hx, hy = streak_half_sizes(smear, sigma, max(3.0, 0.1 * length) + _FIELD_MARGIN_PX)
    bg, noise = mesh.at(col, row)
    win = gather_streak_windows(image, col, row, hx, hy, bg, noise, bad)
    nodes = path_points(length + 2.0 * _FIELD_MARGIN_PX, sigma)
    p0 = start_parameters(win, col, row, sigma, smear)
    if fit:
        field = smear_field(win, p0, det["snr"], nodes, inv_gain, smear)
        if field is not None:
            p0[:, DX:] = field(p0[:, :2])
        p, ok = fit_streaks(win, p0, nodes, inv_gain=inv_gain)
        height, width = image.shape
        ok &= np.all((p[:, :2] >= -0.5) & (p[:, :2] <= np.array([width, height]) - 0.5), axis=1)
        p = np.where(ok[:, None], p, p0)
    else:
        p, ok = p0, np.zeros(len(p0), dtype=bool)
    a, _, model, _ = streak_normal_equations(p, win, nodes, inv_gain=inv_gain)
    cov = _spd_inverse(a) * mesh.box_noise_factor ** 2
    excess = (model - p[:, BG, None]).reshape(win.values.shape)
    foot = excess >= _FOOTPRINT_FRACTION * excess.max(axis=(1, 2), keepdims=True)
    flags = _flags(win, foot, saturated, ok | (not fit), det, col, row)
    xy = np.where(ok[:, None], p[:, :2], _centre_of_light(win, foot))
    flux = p[:, FLUX]
    peak = np.where(foot, win.values, -np.inf).max(axis=(1, 2))
    xy_cov = np.where(ok[:, None, None], cov[:, :2, :2], np.nan)
    snr = flux / np.sqrt(cov[:, FLUX, FLUX])
    keep = ~ok | (snr >= _FIT_SNR_FRACTION * threshold_sigma) if fit else np.ones(len(snr), dtype=bool)
    xy, flux, peak, flags, snr, xy_cov = xy[keep], flux[keep], peak[keep], flags[keep], snr[keep], xy_cov[keep]
    return dict(xy=xy, flux=flux, peak=peak, npix=det["npix"][keep], flags=flags, snr=snr, xy_cov=xy_cov)


def _centre_of_light(win, foot):
    """Background-subtracted first moment of the footprint pixels (failed fits)."""
    w = np.where(foot & win.valid, np.maximum(win.values - win.bg[:, None, None], 0.0), 0.0)
    total = np.maximum(w.sum(axis=(1, 2)), 1e-12)
    wy, wx = win.shape
    cx = (w.sum(axis=1) * np.arange(wx)).sum(axis=1) / total
    cy = (w.sum(axis=2) * np.arange(wy)).sum(axis=1) / total
    return np.stack([win.x0 + cx, win.y0 + cy], axis=1)


def _flags(win, foot, saturated, ok, det, col, row):
    """Per-star flag bits of the streak path."""
    height, width = saturated.shape
    wy, wx = win.shape
    rows = row[:, None] + np.arange(wy) - (wy - 1) // 2
    cols = col[:, None] + np.arange(wx) - (wx - 1) // 2
    inside = ((rows >= 0) & (rows < height))[:, :, None] & ((cols >= 0) & (cols < width))[:, None, :]
    sat = saturated[np.clip(rows, 0, height - 1)[:, :, None], np.clip(cols, 0, width - 1)[:, None, :]]
    flags = np.where(np.any(foot & sat & inside, axis=(1, 2)), FLAG_SATURATED, 0)
    flags |= np.where(np.any(foot & ~inside, axis=(1, 2)), FLAG_EDGE, 0)
    flags |= np.where(ok, 0, FLAG_FIT_FAILED)
    label = det["label"]
    shared = np.bincount(label)[label] > 1 if len(label) else np.zeros(0, dtype=bool)
    flags |= np.where(det["too_big"] | shared, FLAG_ELONGATED, 0)
    return flags.astype(np.int64)


def extract_smeared(arr, mesh, idx, labels, stats, smear, sigma, inv_gain, saturation, threshold_sigma, refine):
    """Centroids of a smeared frame: the dict of :func:`measure_streaks`, and the PSF sigma used.

    ``idx``/``labels``: the frame's candidate pixels and components, ``stats`` their
    statistics (:func:`shipstar.extract._point.component_stats`); ``sigma`` / ``inv_gain``
    None: estimated on the brightest objects (sigma 1 px when none can be fitted).
    """
    saturated = arr >= saturation if math.isfinite(saturation) else np.zeros(arr.shape, dtype=bool)

    def sharp(psf_sigma, gain):
        def test(peaks):
            row, col = np.divmod(peaks, arr.shape[1])
            return too_sharp(arr, mesh, peaks, psf_sigma, gain or 0.0, saturated[row, col])
        return sharp_pixels(arr, mesh, idx, labels, test)

    if sigma is None or inv_gain is None:
        bad = saturated.copy()
        bad.reshape(-1)[sharp(SHARPEST_PSF_SIGMA_PX if sigma is None else sigma, inv_gain)] = True
        cog = stats["cog"][bright_objects(stats)]
        if len(cog) == 0:
            _, cog = binned_guess(arr)
        if cog is not None and len(cog):
            col, row = np.rint(cog).astype(np.int64).T
            _, sigma, inv_gain, _ = calibrate(arr, mesh, bad, col, row, smear, sigma, inv_gain, fit_smear=False)
    sigma = 1.0 if sigma is None else sigma
    masked = sharp(sigma, inv_gain)
    work = arr.astype(np.float32)
    row, col = np.divmod(masked, arr.shape[1])
    work.reshape(-1)[masked] = mesh.at(col, row)[0]
    bad = saturated.copy()
    bad.reshape(-1)[masked] = True
    result = measure_streaks(work, mesh, smear, threshold_sigma=threshold_sigma,
                             segment_sigma=min(SEGMENT_SIGMA, threshold_sigma), sigma=sigma,
                             inv_gain=inv_gain or 0.0, bad=bad, saturated=saturated, fit=refine == "gaussian")
    return result, sigma
