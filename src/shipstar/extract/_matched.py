"""Detection of smeared stars: a line-shaped matched filter and oriented non-maximum suppression.

A star smeared by (dx, dy) spreads its light over ~L = hypot(dx, dy) pixels, so its peak
signal-to-noise ratio per pixel drops as 1/L; the sum of the pixels along the streak
keeps it. The filter image is

    S(p) = sum_k sum_a I(p + o_k + a e),

with ``o_k`` integer offsets every pixel along the dominant axis of the smear, symmetric
about 0 and spanning it (``2 round(|d|/2) + 1`` taps, the other coordinate rounded onto
the line), and ``a`` = -w .. w steps ``e`` along the other axis (the PSF's width). For a
streak at p, S is maximal at its midpoint and holds ~90 % of its light, against the
noise of ``(2 w + 1) x taps`` pixels: close to the matched filter. Each add is one
pass over the frame (float32), so the cost grows with L.

Peaks of S are 3x3 local maxima above ``threshold_sigma`` times S's noise; a peak
within the streak footprint (along <= L + 1.5 px, across <= 2.5 px + sigma) of a
stronger one is the same star (noise bumps on the ridge) and dropped. A connected
region of S above 2.5 sigma that is longer or wider than one streak (a satellite trail,
the edge of a roof) gives one object, its strongest peak.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from shipstar.extract._background import Mesh, estimate_mesh, median
from shipstar.extract._detect import candidate_pixels, components, local_maxima, sum_dtype
from shipstar.extract._kernels import line_filter as kernel_line_filter
from shipstar.extract._kernels import streak_peaks, suppress, tap_sum
from shipstar.extract._scratch import scratch

__all__ = ["LineFilter", "line_filter", "detect_streaks", "EXTENT_FACTOR"]

#: Block size of the filter image's background and noise mesh, px.
_S_BLOCK_PX = 64

#: A component of S's candidates whose RMS extent along or across the smear exceeds this
#: multiple of a single streak's largest is a trail or an edge, not a star.
EXTENT_FACTOR = 1.5


class LineFilter:
    """Taps of the line filter for a smear ``smear_px`` (2,) and an across half-width ``across_px``."""

    def __init__(self, smear_px, across_px: int = 1):
        d = np.asarray(smear_px, dtype=float)
        self.smear_px = d
        self.length_px = float(math.hypot(d[0], d[1]))
        self.major = 0 if abs(d[0]) >= abs(d[1]) else 1          # 0: mostly along x
        span = abs(d[self.major])
        half = int(round(span / 2.0))
        k = np.arange(-half, half + 1)
        minor = np.rint(k * (d[1 - self.major] / d[self.major])) if span > 0 else np.zeros_like(k)
        offsets = np.zeros((len(k), 2), dtype=np.int64)          # (x, y)
        offsets[:, self.major] = k
        offsets[:, 1 - self.major] = minor.astype(np.int64)
        self.offsets = offsets
        self.across_px = int(across_px)

    @property
    def taps(self) -> int:
        """Number of pixels summed."""
        return len(self.offsets) * (2 * self.across_px + 1)

    @property
    def reach_px(self) -> int:
        return int(np.abs(self.offsets).max()) + self.across_px


def line_filter(image, fill_value: float, lf: LineFilter, patch=None) -> np.ndarray:
    """S (H, W): the sum of the ``lf.taps`` pixels of the line filter around each pixel.

    float32 (float64 for values beyond 1e30, whose float32 sums could overflow).

    Off-image pixels count as ``fill_value`` (the background); ``patch`` (flat indices,
    values) replaces pixels first, in the kernel as it casts each row (no patched copy of the
    frame: that was a fresh 4 MB array, ~2.6 ms). One compiled call (:func:`._kernels.line_filter`):
    the sums of :func:`_line_filter_python`, the reference, bit for bit -- the same
    partial sums across the smear, the same pairs of taps, added in the same order -- made
    row by row from the frame, where that makes ~10 frame-sized NumPy passes (4-5 ms a
    streak frame at 1024 x 1024; ~1.5 ms compiled). S and the work array are reused from
    frame to frame (:mod:`shipstar.extract._scratch`): S is valid until the next call in
    the same thread.
    """
    height, width = image.shape
    pad = lf.reach_px + 1
    dtype = sum_dtype(image)
    out = scratch("line_filter.s", (height, width), dtype)
    terms, kinds = _terms(lf)
    kernel_line_filter(image, float(fill_value), lf.major == 0, lf.across_px, pad, terms, kinds, out, patch)
    return out


def _terms(lf: LineFilter):
    """The line filter's terms ``(T, 3)`` int64 ``[source, oy, ox]`` in
    :func:`_line_filter_python`'s order, and the kinds of pairs ``(K, 2)`` ``[dy, dx]``:
    the odd tap out first (source 0, the partial sums across), then with 4 or more pairs
    each kind of pair of consecutive taps in the order of its flat step (source 1 + its
    kind), or else the pairs' first taps and then their second ones (source 0)."""
    off = [(int(oy), int(ox)) for ox, oy in lf.offsets]
    pairs = [(off[k], (off[k + 1][0] - off[k][0], off[k + 1][1] - off[k][1])) for k in range(0, len(off) - 1, 2)]
    rows = [(0, *off[-1])] if len(off) % 2 else []
    kinds = []
    if len(pairs) >= 4:
        # the reference orders the kinds by their flat step dy * wp + dx (|dx| <= 1 < wp):
        # by dy, then dx
        kinds = sorted({d for _, d in pairs})
        for j, step in enumerate(kinds):
            rows += [(1 + j, *o) for o, d in pairs if d == step]
    else:
        rows += [(0, *o) for o, _ in pairs] + [(0, o[0] + d[0], o[1] + d[1]) for o, d in pairs]
    return np.array(rows, dtype=np.int64).reshape(-1, 3), np.array(kinds, dtype=np.int64).reshape(-1, 2)


def _line_filter_python(image, fill_value: float, lf: LineFilter, patch=None) -> np.ndarray:
    """S (H, W): the sum of the ``lf.taps`` pixels of the line filter around each pixel.

    float32 (float64 for values beyond 1e30, whose float32 sums could overflow).

    Off-image pixels count as ``fill_value`` (the background); ``patch`` (flat indices,
    values) replaces pixels first. The frame is padded by the filter's reach and
    flattened, so that every tap is one add of a contiguous 1-D slice (a shift of the flat
    index; the pad columns between rows take the garbage): ~0.1 ms a tap for a 1024 x 1024
    frame, 5 x less than adding 2-D slices row by row. The work arrays, S included, are
    reused from frame to frame (:mod:`shipstar.extract._scratch`): S is valid until the
    next call in the same thread.
    """
    height, width = image.shape
    pad = lf.reach_px + 1
    wp = width + 2 * pad
    dtype = sum_dtype(image)                                       # float32 unless the values are huge
    padded = scratch("line_filter.padded", (height + 2 * pad, wp), dtype)
    fill = dtype(fill_value)
    padded[:pad], padded[pad + height:], padded[pad:pad + height, :pad], padded[pad:pad + height, pad + width:] = (
        fill, fill, fill, fill)
    inner = padded[pad:pad + height, pad:pad + width]
    inner[...] = image
    if patch is not None and len(patch[0]):
        inner[np.divmod(patch[0], width)] = patch[1]
    flat = padded.reshape(-1)
    n = flat.size
    minor = 1 if lf.major == 1 else wp                             # flat step across the smear
    lo = lf.across_px * minor
    across = scratch("line_filter.across", (n - 2 * lo,), dtype)   # across[i - lo]: sum over i + j minor
    if lf.across_px:
        np.add(flat[lo - minor:n - lo - minor], flat[lo + minor:n - lo + minor], out=across)
        across += flat[lo:n - lo]
    else:
        np.copyto(across, flat)
    for j in range(2, lf.across_px + 1):
        across += flat[lo + j * minor:n - lo + j * minor]
        across += flat[lo - j * minor:n - lo - j * minor]
    start = pad * wp + pad - lo                                    # pixel (0, 0) in ``across``
    span = (height - 1) * wp + width
    shifts = [start + int(oy) * wp + int(ox) for ox, oy in lf.offsets]
    out = scratch("line_filter.out", (height * wp,), dtype)
    # consecutive taps in pairs: a pair's second tap is one of <= 2 shifts from its first
    # (one step along, 0 or 1 across), so one image per kind of pair (one pass each) halves
    # the passes over the frame for a long smear (exactly the same sum)
    pairs = [(shifts[k], shifts[k + 1] - shifts[k]) for k in range(0, len(shifts) - 1, 2)]
    single = [shifts[-1]] if len(shifts) % 2 else []
    terms = [(across, sh) for sh in single]
    if len(pairs) >= 4:
        m = across.size
        for n_kind, step in enumerate(sorted({d for _, d in pairs})):
            both = scratch(f"line_filter.pair{n_kind}", (m,), dtype)
            i0, i1 = max(0, -step), m - max(0, step)                # both[i] = across[i] + across[i + step]
            np.add(across[i0:i1], across[i0 + step:i1 + step], out=both[i0:i1])
            terms += [(both, sh) for sh, d in pairs if d == step]
    else:
        terms += [(across, sh) for sh, d in pairs] + [(across, sh + d) for sh, d in pairs]
    tap_sum(terms, out, span)                   # out[:span] = the terms' sum, in their order, tile by tile
    s_image = scratch("line_filter.s", (height, width), dtype)
    np.copyto(s_image, out.reshape(height, wp)[:, :width])
    return s_image


def _filter_mesh(s_image, mesh) -> Mesh:
    """Background and noise of the filter image itself, on blocks of ``_S_BLOCK_PX``.

    S's background must be known to a small fraction of S's noise, ``sqrt(taps)``
    times smaller than ``taps`` times the pixel noise: the frame's own mesh (the median of
    integer pixel values, quantised to 1/2 ADU) is too coarse for that, the median of S
    (sums of many pixels) is not. A block's noise estimate never goes below the median
    over the blocks (it comes from 64 correlated samples).
    """
    block = int(min(_S_BLOCK_PX, max(8, min(s_image.shape) // 4)))
    mesh_s = estimate_mesh(s_image, block_px=block, box_noise=False)
    noise = np.maximum(mesh_s.noise, median(mesh_s.noise))
    return replace(mesh_s, noise=noise, box_noise_factor=1.0)


def _suppress(xy, strength, u, along_px: float, across_px: float) -> np.ndarray:
    """Indices (strongest first) of peaks not within ``along_px`` along the unit smear ``u``
    (2,) and ``across_px`` across it of a stronger peak."""
    order = np.argsort(-strength, kind="stable")
    if len(order) < 2:
        return order
    # greedy, strongest first: a peak is dropped only by a stronger peak that was kept
    dropped = suppress(xy, order, u, along_px, across_px)
    return order[~dropped[order]]


def _peak_rule(mesh_s: Mesh, lf: LineFilter, threshold_sigma: float, psf_sigma_px: float) -> tuple:
    """What makes a peak of the line filter's image, for the compiled kernel and its NumPy
    reference alike: ``(level, u, along_px, across_px, max_extent_px)`` -- the lowest value
    the mesh lets reach ``threshold_sigma`` (a cheap first cut), the unit smear (2,), the
    suppression's reach along and across it (px), and the RMS extent (2,) along and across
    beyond which a component is a trail or an edge (px)."""
    level = np.min(mesh_s.bg + threshold_sigma * mesh_s.noise)
    u = lf.smear_px / max(lf.length_px, 1e-12)
    return level, u, lf.length_px + 1.5, 2.5 + psf_sigma_px, EXTENT_FACTOR * _single_extent_px(lf, psf_sigma_px)


def detect_streaks(image, mesh: Mesh, lf: LineFilter, threshold_sigma: float, segment_sigma: float,
                   psf_sigma_px: float, patch=None):
    """Smeared stars in ``image``, its pixels ``patch`` (flat indices, values: hot pixels and
    cosmic rays replaced by the background) patched.

    Returns
    -------
    dict with ``col``, ``row`` (M,) int peak pixels of S (the streaks' midpoints to
    ~1 px), ``snr`` (M,) S excess over its noise, ``label`` (M,) component of S's
    candidate pixels each peak is in, ``npix`` (M,) pixels in that component, and
    ``too_big`` (M,) bool: the component is longer or wider than one streak (a trail,
    an edge; only its strongest peak is kept).  The peaks are found among S's candidate
    pixels in one compiled call (:func:`shipstar.extract._kernels.streak_peaks`, the steps
    of :func:`_streak_peaks_python` bit for bit; ~0.2 ms of NumPy calls a streak frame).
    """
    s_image = line_filter(image, mesh.background_adu, lf, patch)
    mesh_s = _filter_mesh(s_image, mesh)
    idx = candidate_pixels(s_image, mesh_s, segment_sigma)
    level, u, along_px, across_px, max_extent_px = _peak_rule(mesh_s, lf, threshold_sigma, psf_sigma_px)
    col, row, snr, label, npix, too_big = streak_peaks(s_image, idx, mesh_s.bg, mesh_s.noise, mesh_s.block_px, level,
                                                       threshold_sigma, u, along_px, across_px, max_extent_px)
    return dict(col=col, row=row, snr=snr, label=label, npix=npix, too_big=too_big)


def _single_extent_px(lf: LineFilter, psf_sigma_px: float) -> np.ndarray:
    """(2,) RMS extent along and across the smear of a single streak's pixels, at most, px."""
    return np.array([lf.length_px + 4.0 * psf_sigma_px + 2.0, 2.0 * psf_sigma_px + 2.0]) / math.sqrt(3.0)


def _streak_peaks_python(s_image, idx, mesh_s: Mesh, lf: LineFilter, threshold_sigma: float, psf_sigma_px: float):
    """The peaks of :func:`detect_streaks` from the line filter's image ``s_image``, its mesh
    ``mesh_s`` and its candidate pixels ``idx``, in NumPy: the compiled kernel's reference
    (:func:`shipstar.extract._kernels.streak_peaks`)."""
    flat = s_image.reshape(-1)
    level, u, along_px, across_px, max_extent_px = _peak_rule(mesh_s, lf, threshold_sigma, psf_sigma_px)
    # the peaks that count are local maxima among the pixels >= threshold_sigma (bilinear mesh,
    # whose values are never below the lowest block's: a cheap first cut)
    high = idx[flat[idx] >= level]
    row, col = np.divmod(high, s_image.shape[1])
    bg, noise = mesh_s.at(col, row)
    snr = (flat[high] - bg) / noise
    strong = snr >= threshold_sigma
    peaks = local_maxima(flat, high[strong], s_image.shape)
    pick = np.searchsorted(high, peaks)
    row, col, snr = row[pick], col[pick], snr[pick]
    xy = np.stack([col, row], axis=1).astype(float)
    kept = _suppress(xy, snr, u, along_px, across_px)
    peaks, row, col, snr = peaks[kept], row[kept], col[kept], snr[kept]
    labels, n_labels = components(idx, s_image.shape)
    label = labels[np.searchsorted(idx, peaks)] if len(peaks) else np.zeros(0, dtype=np.int64)
    npix = np.bincount(labels, minlength=n_labels)
    # the extents of the components with a peak only (~40 of ~2,500: most are noise pixels);
    # first: each one's strongest peak (peaks are strongest first)
    with_peak, first = np.unique(label, return_index=True)
    compact = np.full(n_labels, -1, dtype=np.int64)
    compact[with_peak] = np.arange(len(with_peak))
    sel = compact[labels] >= 0
    extent = _component_extent(idx[sel], compact[labels[sel]], len(with_peak), s_image.shape[1], lf)[compact[label]]
    # a component longer or wider than one streak is a trail or an edge: its strongest peak only
    too_big = np.any(extent > max_extent_px, axis=1)
    keep = ~too_big
    keep[first] = True
    return dict(col=col[keep], row=row[keep], snr=snr[keep], label=label[keep], npix=npix[label][keep],
                too_big=too_big[keep])


def _component_extent(idx, labels, n_labels, width, lf: LineFilter) -> np.ndarray:
    """(n_labels, 2) RMS extent of each component's pixels along and across the smear, px."""
    if n_labels == 0:
        return np.zeros((0, 2))
    row, col = np.divmod(idx, width)
    u = lf.smear_px / max(lf.length_px, 1e-12)
    a = col * u[0] + row * u[1]
    c = col * u[1] - row * u[0]
    n = np.bincount(labels, minlength=n_labels)
    out = []
    for q in (a, c):
        mean = np.bincount(labels, weights=q, minlength=n_labels) / n
        var = np.bincount(labels, weights=(q - mean[labels]) ** 2, minlength=n_labels) / n
        out.append(np.sqrt(var))
    return np.stack(out, axis=1)
