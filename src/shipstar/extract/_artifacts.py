"""Objects of a frame that are not stars: trails and persistent (hot) pixels.

The extraction itself rejects single-pixel events (hot pixels, cosmic rays: sharper than
the PSF, ``_point.too_sharp`` / ``_matched``) and reports a trail that crosses a frame as
its strongest peak only, flagged ``elongated``.  What is left for the caller to reject
before identification:

- **trails** (:func:`trail_mask`): a detection flagged ``elongated`` or ``fit_failed``
  (a trail's pieces) whose connected region, in the frame smoothed with a 3 x 3 box and
  cut at 2.5 sigma of the smoothed noise, is much longer than one star's streak (the
  frame's common smear ``smear_px`` plus the PSF) and narrow: a satellite or aircraft
  line.  Stars on a trail go with it.
- **persistent pixels** (:class:`PersistentPixels`): detections at the same pixel frame
  after frame while the stars move across the detector (the sensor turns by more than
  ``min_motion_px`` per frame): a hot pixel or a defect, whatever its shape.
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.extract._kernels import box3, label_runs, persistent_merge, persistent_pairs, region_shape
from shipstar.extract._result import FLAG_ELONGATED, FLAG_FIT_FAILED

__all__ = ["trail_mask", "PersistentPixels", "TRAIL_MIN_LENGTH_PX", "TRAIL_MIN_AXIS_RATIO"]

#: A region at least this long (px, along its major axis) ...
TRAIL_MIN_LENGTH_PX = 25.0
#: ... and at least this many times longer than wide is a trail.
TRAIL_MIN_AXIS_RATIO = 3.0
#: Half-size of the window searched around a candidate (px); a region reaching its border
#: is at least this long.
_WINDOW_HALF_PX = 40
#: Cut of the 3 x 3 smoothed frame, in sigma of its noise.
_CUT_SIGMA = 2.5


def _region_shape(image, x: float, y: float, background: float, noise: float):
    """``(length_px, width_px)`` of the smoothed region around ``(x, y)`` (0, 0 if none).

    The window's pixels are cut from the frame here and the rest is one compiled call
    (:func:`._kernels.region_shape`, ~33 us against ~90 us a call); :func:`_region_shape_python`
    is its reference (the same regions; the axes' extents to rounding: the principal axes
    in closed form against LAPACK's)."""
    h, w = image.shape
    ix, iy = int(round(x)), int(round(y))
    x0, x1 = max(ix - _WINDOW_HALF_PX, 0), min(ix + _WINDOW_HALF_PX + 1, w)
    y0, y1 = max(iy - _WINDOW_HALF_PX, 0), min(iy + _WINDOW_HALF_PX + 1, h)
    if x1 <= x0 or y1 <= y0:
        return _region_shape_python(image, x, y, background, noise)
    cut = background + _CUT_SIGMA * noise / 3.0
    if np.result_type(np.float32, cut) == np.float32:      # NumPy compares a float32 frame with a
        cut = float(np.float32(cut))                       # Python float in float32
    cx, cy = min(max(ix - x0, 0), x1 - x0 - 1), min(max(iy - y0, 0), y1 - y0 - 1)
    return region_shape(image[y0:y1, x0:x1], cx, cy, cut)


def _region_shape_python(image, x: float, y: float, background: float, noise: float):
    """:func:`_region_shape` in NumPy (the compiled kernel's reference)."""
    h, w = image.shape
    ix, iy = int(round(x)), int(round(y))
    x0, x1 = max(ix - _WINDOW_HALF_PX, 0), min(ix + _WINDOW_HALF_PX + 1, w)
    y0, y1 = max(iy - _WINDOW_HALF_PX, 0), min(iy + _WINDOW_HALF_PX + 1, h)
    win = box3(image[y0:y1, x0:x1])               # scipy.ndimage.uniform_filter(..., 3, mode="nearest")
    above = win > background + _CUT_SIGMA * noise / 3.0
    idx = np.flatnonzero(above)
    if idx.size == 0:
        return 0.0, 0.0
    found, _ = label_runs(idx, above.shape[1], diagonal=False)   # scipy.ndimage.label's 4-connectivity
    labels = np.zeros(above.shape, dtype=np.int64)
    labels.reshape(-1)[idx] = found + 1
    cx, cy = min(max(ix - x0, 0), x1 - x0 - 1), min(max(iy - y0, 0), y1 - y0 - 1)
    near = labels[max(cy - 2, 0):cy + 3, max(cx - 2, 0):cx + 3]
    ids = near[near > 0]
    if ids.size == 0:
        return 0.0, 0.0
    yy, xx = np.nonzero(labels == np.bincount(ids).argmax())
    if xx.size < 3:
        return float(xx.size), 1.0
    pts = np.stack([xx, yy], axis=1).astype(float)
    pts -= pts.mean(axis=0)
    evals, evecs = np.linalg.eigh(pts.T @ pts / len(pts))
    major = pts @ evecs[:, 1]
    minor = pts @ evecs[:, 0]
    return float(major.max() - major.min() + 1.0), float(minor.max() - minor.min() + 1.0)


def trail_mask(image, extraction, *, smear_px=None) -> np.ndarray:
    """``(N,)`` bool: the extraction's detections that lie on a trail (see the module).

    Parameters
    ----------
    image : (H, W) array
        The frame the extraction was made from.
    extraction : Extraction
    smear_px : (2,), optional
        The frame's common smear (default: the extraction's).
    """
    ex = extraction
    out = np.zeros(len(ex), dtype=bool)
    cand = np.flatnonzero((ex.flags & (FLAG_ELONGATED | FLAG_FIT_FAILED)) != 0)
    if cand.size == 0:
        return out
    smear = ex.smear_px if smear_px is None else np.asarray(smear_px, float)
    psf = ex.psf_sigma_px if math.isfinite(ex.psf_sigma_px) else 1.0
    star_px = float(np.hypot(*smear)) + 6.0 * psf
    min_length = max(TRAIL_MIN_LENGTH_PX, 2.0 * star_px + 10.0)
    noise = ex.noise_adu if ex.noise_adu > 0 else 1.0
    for i in cand:
        length, width = _region_shape(image, ex.xy_px[i, 0], ex.xy_px[i, 1], ex.background_adu, noise)
        out[i] = length >= min_length and length >= TRAIL_MIN_AXIS_RATIO * width
    return out


#: Pixel keys: ``(ix + _KEY_OFFSET) * _KEY_STRIDE + (iy + _KEY_OFFSET)`` (int64); a detection's
#: 3 x 3 neighbours are its key plus :data:`_NEAR`.  Pixel numbers beyond +-``_KEY_CLIP`` (no
#: detector has them) are clipped so that the keys cannot overflow.
_KEY_OFFSET = 1 << 30
_KEY_STRIDE = 1 << 32
_KEY_CLIP = 1 << 29
_NEAR = np.array([di * _KEY_STRIDE + dj for di in (-1, 0, 1) for dj in (-1, 0, 1)], dtype=np.int64)


def _pixel_keys(xy) -> np.ndarray:
    """``(N,)`` int64 keys of the pixels (rounded) of ``xy`` (N, 2)."""
    ij = np.clip(np.rint(xy), -_KEY_CLIP, _KEY_CLIP).astype(np.int64) + _KEY_OFFSET
    return ij[:, 0] * _KEY_STRIDE + ij[:, 1]


class PersistentPixels:
    """Detections at the same pixel in earlier frames while the stars moved on.

    Each frame's detections are kept (their pixels) for the last ``n_frames`` frames with
    a token of the frame's pointing.  A detection is persistent when within 1 px of a
    detection of at least ``min_count`` of those frames for which ``displacement_px``
    says a star at its place would have moved by ``min_motion_px`` or more (so a field
    at rest, as in dock, flags nothing; a star that comes back to the same pixel as the
    ship rolls back is not flagged either: the displacement is the net one).

    The remembered detections are one table of ``(pixel key, frame number)`` sorted by key
    (:func:`_pixel_keys`), entries older than the last ``n_frames`` frames dropped as each
    frame is added: a frame's look-up is one compiled call (:func:`._kernels.persistent_pairs`:
    binary searches of each detection's 9 pixels, its frames marked in a window's array) and
    its update one linear merge (:func:`._kernels.persistent_merge`), whatever the number of
    detections (a Python loop over them and their 9 pixels each was 0.15-0.18 ms a frame at
    sea, ~3 % of the whole chain; the NumPy searches and sorts after it 2.6 ms a frame at rest,
    in dock, where each of ~120 detections pairs with 49 frames), and a pixel detected in
    every frame (a field at rest, a hot pixel) has at most ``n_frames`` entries, not one per
    frame of the night.

    Parameters
    ----------
    n_frames, min_count : int
    min_motion_px : float
    """

    def __init__(self, n_frames: int = 50, min_count: int = 2, min_motion_px: float = 3.0):
        self.n_frames = int(n_frames)
        self.min_count = int(min_count)
        self.min_motion_px = float(min_motion_px)
        self._frame = 0                 # frames remembered so far
        self._tokens: dict = {}         # frame number -> token
        #: the remembered detections: pixel keys (sorted) and the frame numbers, within the last n_frames
        self._keys = np.zeros(0, dtype=np.int64)
        self._frames = np.zeros(0, dtype=np.int64)

    def entries_per_pixel_max(self) -> int:
        """The most entries any pixel holds (0: none): at most ``n_frames``."""
        if not self._keys.size:
            return 0
        return int(np.max(np.unique(self._keys, return_counts=True)[1]))

    def n_pixels(self) -> int:
        """Distinct pixels remembered."""
        return int(np.unique(self._keys).size)

    def update(self, xy_px, token=None, displacement_px=None) -> np.ndarray:
        """``(N,)`` bool for the frame's detections ``xy_px`` (N, 2).

        ``token``: this frame's pointing (None: unknown, the frame is not remembered);
        ``displacement_px(tokens_then, index (M,), token_now, xy (N, 2), star (M,))`` ->
        ``(M,)``: how far the star now at ``xy[star[m]]`` was from there in the frame of
        ``tokens_then[index[m]]`` (all the pairs of the frame in one call, ``star``
        non-decreasing: at rest, in dock, every star has a detection at its pixel in each of
        the last frames, and one call per pair was 15 % of a dock session's time).
        """
        xy = np.asarray(xy_px, float).reshape(-1, 2)
        n = len(xy)
        keys = _pixel_keys(xy)
        out = np.zeros(n, dtype=bool)
        oldest = self._frame - self.n_frames
        if token is not None and displacement_px is not None and self._tokens and n and self._keys.size:
            stars, frames = persistent_pairs(self._keys, self._frames, keys, _NEAR, oldest, self.n_frames,
                                             self.min_count)
            if stars.size:
                # the distinct frames (sorted) and each pair's place among them, as np.unique's
                # inverse: the frames lie in the window (oldest, oldest + n_frames)
                seen = np.zeros(self.n_frames, dtype=bool)
                at = frames - (oldest + 1)
                seen[at] = True
                index = (np.cumsum(seen) - 1)[at]
                tokens = [self._tokens[f] for f in (np.flatnonzero(seen) + (oldest + 1)).tolist()]
                moved = displacement_px(tokens, index, token, xy, stars) >= self.min_motion_px
                out = np.bincount(stars[moved], minlength=n) >= self.min_count
        if token is None:
            return out
        self._tokens[self._frame] = token
        self._tokens.pop(oldest, None)
        self._keys, self._frames = persistent_merge(self._keys, self._frames, np.unique(keys), oldest, self._frame)
        self._frame += 1
        return out

    def _pairs_python(self, keys, oldest: int):
        """``(stars (P,), frames (P,))``: each detection with each remembered frame after
        ``oldest`` that had a detection in its 3 x 3 pixels, for the detections with at
        least ``min_count`` such frames (star-major, frames increasing).  The reference of
        the compiled look-up (:func:`._kernels.persistent_pairs`, which :meth:`update`
        uses: 1.1 -> ~0.05 ms a frame at rest, 121 detections each with 49 frames)."""
        n = keys.size
        query = (keys[:, None] + _NEAR).reshape(-1)                  # (9 N,)
        lo = np.searchsorted(self._keys, query, side="left")
        count = np.searchsorted(self._keys, query, side="right") - lo
        hit = np.flatnonzero(count)
        if not hit.size:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        lo, count = lo[hit], count[hit]
        first = np.cumsum(count) - count                             # each hit's first row in the expansion
        rows = np.arange(int(first[-1] + count[-1])) + np.repeat(lo - first, count)
        star = np.repeat(hit // 9, count)
        frame = self._frames[rows]
        live = frame > oldest
        span = self._frame + 1
        code = np.unique(star[live] * span + frame[live])            # distinct (star, frame) pairs
        star, frame = np.divmod(code, span)
        ok = np.bincount(star, minlength=n)[star] >= self.min_count
        return star[ok], frame[ok]
