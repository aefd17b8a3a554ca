"""Windowed extraction: a tracked frame's stars measured only around their predicted places.

Flight star trackers track in windows: once the attitude is known, each catalog star's
place in the next frame is predicted to a pixel or two, and only the pixels around it
are read.  Here the frame-wide passes of :func:`~shipstar.extract.extract_stars` (the
background mesh, the saturation count, the hot-pixel candidates, the line filter or the
segmentation) are replaced by the same steps inside one window per predicted star,
with the background mesh and the saturation level of a recent full frame
(:func:`~shipstar.extract._core.frame_extraction`):

1. a window around each prediction: the streak's extent, the fit's margin and the
   prediction's own error (``search_px``);
2. the background's drift since the full frame, from the windows' border rings (the
   clipped mean of their pixels less the mesh): beyond
   :data:`MAX_BACKGROUND_SHIFT_SIGMA` of the noise, or enough to change the noise's
   Poisson part by :data:`MAX_NOISE_VARIANCE_CHANGE`, the frame is refused (the caller
   extracts it whole: cloud, the Moon, twilight);
3. hot pixels and cosmic rays among the windows' pixels (the frame-wide test of
   :func:`~shipstar.extract._smeared.sharp_pixels`), and saturated pixels, left out;
4. the predictions' common error (the predicted attitude's: the sensor's motion
   extrapolated over a frame period is off by pixels when the ship's rate changes), from
   the peaks of the brightest :data:`ACQUIRE_STARS` windows searched as far as the
   windows reach (at most :data:`ACQUIRE_PX`; beyond that the windows are gathered again
   at the moved places); then each star's peak: the maximum of the line filter (the
   streak's pixels summed along the smear, 3 across; a 3 x 3 box for a point) within
   ``search_px`` of its moved prediction, and the detection test on it
   (:data:`PEAK_SNR_FRACTION` of ``threshold_sigma`` times its white-noise sigma, the
   background each window's ring's); peaks of two predictions within one streak's
   footprint are one star, flagged as a blend, and a star whose window holds many bright
   pixels outside its footprint (a trail, another object) is flagged too (``elongated``,
   as a full frame flags them: the caller's trail test then looks at its whole region);
5. the fits, exactly as in a full frame (:func:`~shipstar.extract._smeared.measure_streaks`):
   the common smear measured again from the brightest streaks (from :data:`REFINE_MIN_PX`
   long, where a full frame is given the smear too; shorter, the prediction), the smear
   field, the pixel-integrated Gaussian moved along each star's smear (a point when the smear is
   zero); fitted flux SNR below 0.8 ``threshold_sigma`` dropped.

Only predicted stars are found: a star missing from the prediction (not in the catalog,
outside the windows) is not, and neither are trails crossing the frame elsewhere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from shipstar.extract._background import median
from shipstar.extract._core import _prepare, _result, trusted_smear
from shipstar.extract._kernels import crowded_count, ring_levels, suppress, window_peaks
from shipstar.extract._matched import LineFilter
from shipstar.extract._point import SEGMENT_SIGMA, too_sharp
from shipstar.extract._result import Extraction
from shipstar.extract._smear import STREAK_MIN_PX
from shipstar.extract._smeared import _FIELD_FRACTION, _MARGIN_PX, measure_streaks, sharp_pixels
from shipstar.extract._streak import gather_streak_windows, streak_half_sizes

__all__ = ["WindowResult", "extract_windows", "MAX_BACKGROUND_SHIFT_SIGMA", "MAX_NOISE_VARIANCE_CHANGE"]

#: The windows' background may differ from the full frame's mesh by this many noise sigmas ...
MAX_BACKGROUND_SHIFT_SIGMA = 0.5
#: ... and change the noise's variance (its Poisson part, through the gain) by this fraction.
MAX_NOISE_VARIANCE_CHANGE = 0.1
#: The common smear is measured again from the brightest streaks (as in a full frame) from
#: this length, px; a shorter one is modelled as predicted (its error moves no midpoint).
REFINE_MIN_PX = 3.0
#: Bright pixels (3 sigma) outside a star's footprint that mark its window as crossed by
#: something else (white noise puts ~0.1 % of the pixels there).
_CROWDED_PX = 8
#: A window's line-filter peak is tested at this fraction of ``threshold_sigma``: a frame's
#: threshold keeps false peaks rare among its ~10^6 places, a window's search among its
#: ~25-50 (at 3.5 sigma ~1 % of the windows without a star get a noise peak, which the
#: fit's SNR test then drops); the fits keep, as in a full frame, SNR >= 0.8 threshold.
PEAK_SNR_FRACTION = 0.7
#: The predictions' common error (the predicted attitude's) is measured on this many of the
#: first (brightest) predictions ...
ACQUIRE_STARS = 8
#: ... searched this far (px).
ACQUIRE_PX = 8
#: Width of each window's border ring that measures the background, px.
_RING_PX = 2


@dataclass(frozen=True)
class WindowResult:
    """A windowed extraction: ``extraction`` (None when refused) and why it was refused.

    Attributes
    ----------
    extraction : Extraction or None
        The stars found, brightest first (``background_adu``: the mesh's plus the
        measured drift; ``noise_adu``: the mesh's).
    reason : str
        Why the windows were refused ("" when not): the caller then extracts the frame whole.
    n_predicted : int
        Predictions inside the frame (windows).
    background_shift_adu : float
        Median background of the windows' border rings less the mesh's (NaN if refused before).
    """

    extraction: Extraction | None
    reason: str
    n_predicted: int = 0
    background_shift_adu: float = math.nan

    @property
    def ok(self) -> bool:
        return self.extraction is not None


def _ring_shift(win):
    """The windows' border-ring pixels less the mesh's background, ADU: their level over all
    the windows (NaN: none), and each window's own (N,) (0 where it has none).

    Levels are means of the pixels within 3 noise sigma of the pooled median (a star or a
    hot pixel in a ring left out): with integer data and ~1 ADU of noise a median moves in
    steps of 1/2 ADU, which the line filter's sum of ~15-100 pixels would turn into
    several of its sigmas.  Compiled (``_kernels.ring_levels``): :func:`_ring_shift_python`'s
    values to the bit."""
    level, own = ring_levels(win.values, win.valid, win.bg, win.noise, _RING_PX)
    return float(level), own


def _ring_shift_python(win):
    """:func:`_ring_shift` in NumPy (the compiled kernel's reference)."""
    r = _RING_PX
    n = len(win.values)
    parts = []
    for sl in ((slice(None), slice(None, r), slice(None)), (slice(None), slice(-r, None), slice(None)),
               (slice(None), slice(r, -r), slice(None, r)), (slice(None), slice(r, -r), slice(-r, None))):
        parts.append(((win.values[sl] - win.bg[:, None, None]).reshape(n, -1), win.valid[sl].reshape(n, -1)))
    values = np.concatenate([v for v, _ in parts], axis=1)
    ok = np.concatenate([k for _, k in parts], axis=1)
    if not ok.any():
        return math.nan, np.zeros(n)
    centre = median(values[ok])
    ok &= np.abs(values - centre) <= 3.0 * win.noise[:, None]
    count = ok.sum(axis=1)
    total = np.where(ok, values, 0.0).sum(axis=1)
    own = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    return (float(total.sum() / count.sum()) if count.sum() else math.nan), own


def _taps(smear, sigma):
    """The line filter's pixel offsets [(ox, oy), ...] (a 3 x 3 box for points) and their
    reach (rx, ry), px."""
    if float(math.hypot(*smear)) >= STREAK_MIN_PX:
        lf = LineFilter(smear, across_px=max(1, int(round(1.2 * sigma))))
        minor = (0, 1) if lf.major == 0 else (1, 0)
        taps = [(int(ox) + a * minor[0], int(oy) + a * minor[1]) for ox, oy in lf.offsets
                for a in range(-lf.across_px, lf.across_px + 1)]
    else:
        taps = [(ox, oy) for oy in (-1, 0, 1) for ox in (-1, 0, 1)]
    return taps, (max(abs(t[0]) for t in taps), max(abs(t[1]) for t in taps))


def _peaks(win, taps, search: int, box_noise_factor: float, local_adu, centre=(0, 0)):
    """Per window: the line filter's maximum within ``search`` px of the window's centre
    moved by ``centre`` (dx, dy): ``(dx, dy)`` (N,) int offsets from the window's centre and
    its SNR (N,) against white noise; the background is the mesh's plus each window's ring
    level ``local_adu`` (N,).  Compiled (``_kernels.window_peaks``): :func:`_peaks_python`'s
    values to the bit."""
    n, wy, wx = win.values.shape
    cy, cx = (wy - 1) // 2 + int(centre[1]), (wx - 1) // 2 + int(centre[0])
    side = 2 * search + 1
    for ox, oy in taps:
        y0, x0 = cy + oy - search, cx + ox - search
        if y0 < 0 or x0 < 0 or y0 + side > wy or x0 + side > wx:
            raise ValueError("window too small for the line filter's reach")   # (the callers size them)
    best, s = window_peaks(win.values, win.valid, win.bg + local_adu, taps, search, cx, cy)
    dy, dx = np.divmod(best, side)
    noise = win.noise * box_noise_factor * math.sqrt(len(taps))
    return dx - search + int(centre[0]), dy - search + int(centre[1]), s / noise


def _peaks_python(win, taps, search: int, box_noise_factor: float, local_adu, centre=(0, 0)):
    """:func:`_peaks` in NumPy (the compiled kernel's reference)."""
    excess = np.where(win.valid, win.values - (win.bg + local_adu)[:, None, None], 0.0)
    n, wy, wx = excess.shape
    cy, cx = (wy - 1) // 2 + int(centre[1]), (wx - 1) // 2 + int(centre[0])
    side = 2 * search + 1
    s = np.zeros((n, side, side))
    for ox, oy in taps:
        y0, x0 = cy + oy - search, cx + ox - search
        if y0 < 0 or x0 < 0 or y0 + side > wy or x0 + side > wx:
            raise ValueError("window too small for the line filter's reach")   # (the callers size them)
        s += excess[:, y0:y0 + side, x0:x0 + side]
    best = np.argmax(s.reshape(n, -1), axis=1)
    dy, dx = np.divmod(best, side)
    noise = win.noise * box_noise_factor * math.sqrt(len(taps))
    snr = s.reshape(n, -1)[np.arange(n), best] / noise
    return dx - search + int(centre[0]), dy - search + int(centre[1]), snr


def _common_offset(win, taps, reach, box_noise_factor: float, local_adu, threshold_sigma: float):
    """(dx, dy) int px: the predictions' common error (the predicted attitude's), from the
    first (brightest) :data:`ACQUIRE_STARS` windows searched as far as they reach (at most
    :data:`ACQUIRE_PX`): the median of their peaks' offsets when at least 3 are found, else
    (0, 0)."""
    wy, wx = win.shape
    far = min(ACQUIRE_PX, (wx - 1) // 2 - reach[0], (wy - 1) // 2 - reach[1])
    first = win.take(slice(0, ACQUIRE_STARS))
    dx, dy, snr = _peaks(first, taps, far, box_noise_factor, local_adu[:ACQUIRE_STARS])
    found = snr >= threshold_sigma
    if np.count_nonzero(found) < 3:
        return 0, 0
    return int(np.rint(np.median(dx[found]))), int(np.rint(np.median(dy[found])))


def _crowded(win, dx, dy, smear, sigma: float, box_noise_factor: float) -> np.ndarray:
    """(N,) bool: windows with more bright pixels (3 sigma) outside their star's footprint
    (centred ``dx, dy`` (N,) px from the window's centre) than noise gives
    (:data:`_CROWDED_PX`, or half the window's width): a trail or another object crosses it.
    Such a star is flagged as a full frame flags a trail's or a blend's (``elongated``), and
    the caller's trail test (``extract._artifacts.trail_mask``) looks at its whole region.
    Compiled (``_kernels.crowded_count``): :func:`_crowded_python`'s answer."""
    n, wy, wx = win.values.shape
    if n == 0:
        return np.zeros(0, dtype=bool)
    length = float(math.hypot(*smear))
    u = smear / length if length > 1e-9 else np.array([1.0, 0.0])
    reach = 3.0 * sigma + 1.0
    counts = crowded_count(win.values, win.valid, win.bg, win.noise, dx, dy, u, 0.5 * length + reach, reach,
                           3.0 * box_noise_factor)
    return counts >= max(_CROWDED_PX, 0.5 * wx)


def _crowded_python(win, dx, dy, smear, sigma: float, box_noise_factor: float) -> np.ndarray:
    """:func:`_crowded` in NumPy (the compiled kernel's reference)."""
    n, wy, wx = win.values.shape
    if n == 0:
        return np.zeros(0, dtype=bool)
    length = float(math.hypot(*smear))
    u = smear / length if length > 1e-9 else np.array([1.0, 0.0])
    m = int(max(np.max(np.abs(dx)), np.max(np.abs(dy))))
    # the footprint about the centre of a table m px wider each way, cut at each star's offset
    gy = np.arange(wy + 2 * m) - ((wy - 1) // 2 + m)
    gx = np.arange(wx + 2 * m) - ((wx - 1) // 2 + m)
    along = gx[None, :] * u[0] + gy[:, None] * u[1]
    across = gx[None, :] * u[1] - gy[:, None] * u[0]
    reach = 3.0 * sigma + 1.0
    table = (np.abs(along) <= 0.5 * length + reach) & (np.abs(across) <= reach)
    rows = (m - dy)[:, None] + np.arange(wy)
    cols = (m - dx)[:, None] + np.arange(wx)
    inside = table[rows[:, :, None], cols[:, None, :]]
    level = (win.bg + 3.0 * box_noise_factor * win.noise)[:, None, None]
    bright = win.valid & (win.values > level) & ~inside
    return bright.sum(axis=(1, 2)) >= max(_CROWDED_PX, 0.5 * wx)


def extract_windows(image, xy_pred_px, *, mesh, saturation_adu: float, smear_px, psf_sigma_px: float,
                    gain_e_per_adu: float, threshold_sigma: float = 5.0, search_px: float = 3.0,
                    smear_sigma_px: float | None = None) -> WindowResult:
    """The stars of a frame measured in windows around their predicted places.

    Parameters
    ----------
    image : (H, W) array
        The frame, ADU, the same shape as the full frame the mesh is of.
    xy_pred_px : (M, 2) array
        Predicted centroids (x right, y down), brightest first, e.g. the catalog stars
        projected with the predicted attitude; those off the frame are ignored.  Their
        common error (the predicted attitude's) is measured first on the brightest
        :data:`ACQUIRE_STARS` (searched :data:`ACQUIRE_PX` far) and removed.
    mesh : Mesh
        The background mesh of a recent full frame (:func:`frame_extraction`).
    saturation_adu : float
        Its saturation level (inf: none).
    smear_px : (2,) array
        The stars' motion during the exposure (end minus start, px), e.g. from the sensor's
        rate; (0, 0) for points.  At least ``STREAK_MIN_PX`` long it is measured again from
        the brightest streaks, as in a full frame.
    psf_sigma_px, gain_e_per_adu : float
        The camera's PSF sigma and gain (both needed: nothing in the windows fits them).
    threshold_sigma : float
        Detection threshold, as for :func:`extract_stars`.
    search_px : float
        Largest error of the predictions, px (the peak is looked for this far).
    smear_sigma_px : float, optional
        The error of ``smear_px`` (1 sigma, px): at most ``TRUSTED_SMEAR_SIGMA_PX`` (0.05 px)
        the smear is used as it is, not measured again (as for :func:`extract_stars`).

    Returns
    -------
    WindowResult
    """
    trusted = trusted_smear(smear_sigma_px)
    return _windows(image, xy_pred_px, mesh, saturation_adu, smear_px, psf_sigma_px, gain_e_per_adu,
                    threshold_sigma, search_px, moved=False, trusted=trusted)


def _windows(image, xy_pred_px, mesh, saturation_adu, smear_px, psf_sigma_px, gain_e_per_adu, threshold_sigma,
             search_px, *, moved: bool, trusted: bool = False) -> WindowResult:
    """:func:`extract_windows`; ``moved``: the predictions were moved by their common error
    already (it is not measured again); ``trusted``: the smear is used as given."""
    arr, _ = _prepare(image)
    if arr.shape != tuple(mesh.shape_hw):
        return WindowResult(None, f"frame is {arr.shape[1]}x{arr.shape[0]}, the full frame's mesh "
                                  f"{mesh.shape_hw[1]}x{mesh.shape_hw[0]}")
    sigma, inv_gain = float(psf_sigma_px), 1.0 / float(gain_e_per_adu)
    smear = np.asarray(smear_px, dtype=float).reshape(2)
    height, width = arr.shape
    xy = np.asarray(xy_pred_px, dtype=float).reshape(-1, 2)
    on = np.all(np.isfinite(xy), axis=1) & (xy[:, 0] >= -0.5) & (xy[:, 0] <= width - 0.5) \
        & (xy[:, 1] >= -0.5) & (xy[:, 1] <= height - 0.5)
    xy = xy[on]
    if not len(xy):
        return WindowResult(None, "no predicted star in the frame")
    search = int(math.ceil(search_px))
    length = float(math.hypot(*smear))
    col, row = np.rint(xy).astype(np.int64).T
    hx, hy = streak_half_sizes(smear, sigma, _MARGIN_PX + _FIELD_FRACTION * length + search + 1.0)
    bg, noise = mesh.at(col, row)
    win = gather_streak_windows(arr, col, row, hx, hy, bg, noise)
    n_pred = len(col)
    shift, local = _ring_shift(win)
    noise_adu = mesh.noise_adu
    if not math.isfinite(shift):
        return WindowResult(None, "no background pixel in the windows", n_pred)
    if abs(shift) > MAX_BACKGROUND_SHIFT_SIGMA * noise_adu or \
            abs(shift) * inv_gain > MAX_NOISE_VARIANCE_CHANGE * noise_adu ** 2:
        return WindowResult(None, f"background moved by {shift:+.2f} ADU since the full frame "
                                  f"(noise {noise_adu:.2f} ADU)", n_pred, shift)
    # the windows' pixels: flat indices, saturated ones and hot-pixel candidates
    rows = row[:, None] + np.arange(-hy, hy + 1)
    cols = col[:, None] + np.arange(-hx, hx + 1)
    flat_idx = np.clip(rows, 0, height - 1)[:, :, None] * width + np.clip(cols, 0, width - 1)[:, None, :]
    # (H, W) masks for the fits' windows, written only where the windows are (np.zeros maps
    # its pages lazily: a copy of a full-frame mask would cost ~0.7 ms here); no saturated
    # pixel in the windows: None (the fits then look nothing up in it)
    saturated = None
    bad = np.zeros(arr.shape, dtype=bool)
    if math.isfinite(saturation_adu):
        at_top = flat_idx[win.valid & (win.values >= saturation_adu)]
        if at_top.size:
            saturated = np.zeros(arr.shape, dtype=bool)
            saturated.reshape(-1)[at_top] = True
            bad.reshape(-1)[at_top] = True
    level = (bg + 3.5 * mesh.box_noise_factor * noise)[:, None, None]
    cand = np.unique(flat_idx[win.valid & (win.values > level)])
    flat = arr.reshape(-1)

    def test(peaks):
        return too_sharp(arr, mesh, peaks, sigma, inv_gain, flat[peaks] >= saturation_adu)

    segment_sigma = min(SEGMENT_SIGMA, float(threshold_sigma))
    masked = sharp_pixels(arr, mesh, test, segment_sigma, idx=cand)
    bad.reshape(-1)[masked] = True
    win = replace(win, valid=win.valid & ~bad.reshape(-1)[flat_idx])
    # the predictions' common error, then the peak of each window, the detection test, one
    # star per streak footprint
    taps, reach = _taps(smear, sigma)
    centre = (0, 0) if moved else _common_offset(win, taps, reach, mesh.box_noise_factor, local,
                                                  float(threshold_sigma))
    if abs(centre[0]) + reach[0] + search > hx or abs(centre[1]) + reach[1] + search > hy:
        # beyond the windows: the frame again with the predictions moved (rare)
        return _windows(image, xy + np.array(centre, dtype=float), mesh, saturation_adu, smear, psf_sigma_px,
                        gain_e_per_adu, threshold_sigma, search_px, moved=True, trusted=trusted)
    dx, dy, snr = _peaks(win, taps, search, mesh.box_noise_factor, local, centre)
    found = np.flatnonzero(snr >= PEAK_SNR_FRACTION * threshold_sigma)
    crowded = _crowded(win.take(found), dx[found], dy[found], smear, sigma, mesh.box_noise_factor)
    col, row, snr = col[found] + dx[found], row[found] + dy[found], snr[found]
    order = np.argsort(-snr, kind="stable")
    u = smear / length if length >= STREAK_MIN_PX else np.array([1.0, 0.0])
    peak_xy = np.stack([col, row], axis=1).astype(float)
    dropped = suppress(peak_xy, order, u, length + 1.5, 2.5 + sigma) if len(order) > 1 \
        else np.zeros(len(order), dtype=bool)
    kept = np.flatnonzero(~dropped)
    blend = np.zeros(len(kept), dtype=bool)
    if dropped.any():                       # a dropped peak's star was merged into the nearest kept one
        d = np.hypot(*(peak_xy[dropped][:, None, :] - peak_xy[kept][None, :, :]).transpose(2, 0, 1))
        blend[np.unique(np.argmin(d, axis=1))] = True
    det = dict(col=col[kept], row=row[kept], snr=snr[kept], label=np.arange(len(kept)), npix=None,
               too_big=blend | crowded[kept])
    res = measure_streaks(arr, mesh, smear, threshold_sigma=float(threshold_sigma), segment_sigma=segment_sigma,
                          sigma=sigma, inv_gain=inv_gain, bad=bad, saturated=saturated, fit=True,
                          refine_smear=length >= REFINE_MIN_PX and not trusted, det=det)   # (no star: empty arrays)
    ex = replace(_result(res, mesh, sigma, arr.shape, None, res["smear"]), background_adu=mesh.background_adu + shift)
    return WindowResult(ex, "", n_pred, shift)
