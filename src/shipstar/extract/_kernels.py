"""The compiled kernels of the extraction (``_ckernels.c``): dtype, order and size checks.

Each wrapper hands its C kernel C-contiguous arrays of the dtypes it reads and writes
(the C code trusts them) and returns NumPy arrays:

- :func:`streak_equations` / :func:`streak_fit`: the smeared-PSF model's weighted normal
  equations and its Levenberg-Marquardt fit, star by star, with a common PSF sigma
  (pixel fractions from :func:`shipstar.extract._streak._fraction_table`); the
  arithmetic of ``_streak._jacobian`` / ``fit_streaks`` in another summation order;
- :func:`gauss_fit` / :func:`gauss_normal`: the point stars' pixel-integrated Gaussian,
  its Gauss-Newton fit (``_fit.fit_gaussian``) star by star, and its normal equations;
- :func:`block_stats`, :func:`median3`, :func:`mesh_at`, :func:`grid_box_sums`,
  :func:`value_step`: the background mesh (block medians, MADs and clipped RMS; its 3 x 3
  median filter; bilinear values; the 3 x 3 sums of its box-noise factor; the samples'
  quantisation step);
- :func:`candidates`, :func:`local_max`, :func:`neighbours`: detection on the pixels
  above a block-wise level (any integer or float pixel type);
- :func:`tap_sum`: the line filter's sum of shifted partial-sum images;
- :func:`line_filter`: the whole line filter from the frame, row by row;
- :func:`box3`: the 3 x 3 mean of a float32 window (trails);
- :func:`label_runs`: 8- (or 4-) connected components of sorted candidate pixels, numbered in
  the order of their first pixel (as ``scipy.sparse.csgraph.connected_components`` on
  the runs' graph numbered them);
- :func:`suppress`: greedy suppression of the peaks within a stronger peak's footprint;
- :func:`streak_peaks`: the line filter's peaks from its candidates (the threshold, the 3 x 3
  maxima, the suppression, their components and extents: ``_matched._streak_peaks_python``);
- :func:`erf`: the error function of an array (libm);
- :func:`persistent_pairs`, :func:`persistent_merge`: the persistent-pixel test's look-up
  and its table's update (``_artifacts.PersistentPixels``).
"""

from __future__ import annotations

import numpy as np

from shipstar.extract import _ckernels
from shipstar.extract._scratch import scratch

__all__ = ["streak_equations", "streak_fit", "gauss_fit", "gauss_normal", "block_stats", "grid_box_sums",
           "value_step", "median3", "mesh_at",
           "candidates", "local_max", "neighbours", "tap_sum", "line_filter", "box3", "label_runs", "region_shape",
           "suppress", "streak_peaks", "point_objects", "erf", "persistent_pairs", "persistent_merge"]

_TABLE_STEPS = 1024


def _f8(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def _window_args(win, nodes, table, half):
    n_star = len(win.values)
    wy, wx = win.values.shape[1:]
    values = _f8(win.values)
    valid = np.ascontiguousarray(win.valid, dtype=np.bool_).view(np.uint8)
    if values.shape != (n_star, wy, wx) or valid.shape != values.shape:
        raise ValueError("window arrays of unequal shapes")
    t, w = _f8(nodes[0]), _f8(nodes[1])
    if t.shape != w.shape or t.ndim != 1:
        raise ValueError("nodes and weights of unequal shapes")
    table = _f8(table)
    if table.shape != (4, _TABLE_STEPS + 1, 2 * half + 1):
        raise ValueError(f"fraction table of shape {table.shape}")
    per_star = [_f8(a) for a in (win.x0, win.y0, win.noise)]
    if any(a.shape != (n_star,) for a in per_star):
        raise ValueError("per-star window arrays of the wrong length")
    return (values, valid, *per_star, t, w, table), (n_star, wy, wx, len(t), int(half), _TABLE_STEPS)


def streak_equations(p, win, nodes, table, half, *, fit_smear, inv_gain, want_jacobian=True):
    """Normal matrix (N, k, k), gradient (N, k), model (N, P), variances (N, P) and
    Jacobian (N, k, P) (None unless ``want_jacobian``) at parameters ``p`` (N, 7); k = 4, or 6
    with the smear; P = Wy * Wx."""
    arrays, dims = _window_args(win, nodes, table, half)
    n_star, wy, wx = dims[:3]
    p = _f8(p)
    if p.shape != (n_star, 7):
        raise ValueError(f"parameters of shape {p.shape}, expected ({n_star}, 7)")
    k = 6 if fit_smear else 4
    size = wy * wx
    a = np.empty((n_star, k, k))
    g = np.empty((n_star, k))
    model = np.empty((n_star, size))
    var = np.empty((n_star, size))
    jac = np.empty((n_star, k, size) if want_jacobian else (0,))
    _ckernels.streak_equations(p, *arrays, a, g, model, var, jac, *dims, int(bool(fit_smear)), float(inv_gain))
    return a, g, model, var, (jac if want_jacobian else None)


def streak_fit(p0, win, nodes, table, half, *, fit_smear, inv_gain, max_iterations, tol_px, converged_fraction,
               converged_chi2):
    """Levenberg-Marquardt fits from ``p0`` (N, 7): parameters (N, 7), converged (N,) bool,
    the normal matrix (N, k, k) and model (N, P) of each star's last accepted parameters."""
    arrays, dims = _window_args(win, nodes, table, half)
    n_star, wy, wx = dims[:3]
    p0 = _f8(p0)
    if p0.shape != (n_star, 7):
        raise ValueError(f"start parameters of shape {p0.shape}, expected ({n_star}, 7)")
    k = 6 if fit_smear else 4
    p = np.empty_like(p0)
    a = np.empty((n_star, k, k))
    model = np.empty((n_star, wy * wx))
    converged = np.zeros(n_star, dtype=np.uint8)
    _ckernels.streak_fit(p0, *arrays, p, a, model, converged, *dims, int(bool(fit_smear)), int(max_iterations),
                         float(inv_gain), float(tol_px), float(converged_fraction), float(converged_chi2))
    return p, converged.astype(bool), a, model


def _point_args(win, p):
    n_star, size = len(win.values), win.values.shape[-1]
    values = _f8(win.values)
    valid = np.ascontiguousarray(win.valid, dtype=np.bool_).view(np.uint8)
    per_star = [_f8(a) for a in (win.x0, win.y0, win.noise)]
    p = _f8(p)
    if values.shape != (n_star, size, size) or valid.shape != values.shape or p.shape != (n_star, 5) \
            or any(a.shape != (n_star,) for a in per_star):
        raise ValueError("point-star windows or parameters of inconsistent shapes")
    return p, (values, valid, *per_star), n_star, size


def gauss_fit(win, p0, *, fit_sigma, inv_gain, tol_px, tol_chi2, max_iterations):
    """Gauss-Newton fits from ``p0`` (N, 5) (x, y, F, b, sigma): parameters (N, 5) and the
    length of each star's last (x, y) step (N,)."""
    p0, arrays, n_star, size = _point_args(win, p0)
    p = np.empty_like(p0)
    step_norm = np.empty(n_star)
    _ckernels.gauss_fit(p0, *arrays, p, step_norm, n_star, size, int(bool(fit_sigma)), float(inv_gain),
                        float(tol_px), float(tol_chi2), int(max_iterations))
    return p, step_norm


def gauss_normal(win, p, *, fit_sigma, inv_gain):
    """Weighted normal matrix (N, k, k) and gradient (N, k) at ``p`` (N, 5); k = 4, or 5 with sigma."""
    p, arrays, n_star, size = _point_args(win, p)
    k = 5 if fit_sigma else 4
    a = np.empty((n_star, k, k))
    g = np.empty((n_star, k))
    _ckernels.gauss_normal(p, *arrays, a, g, n_star, size, int(bool(fit_sigma)), float(inv_gain))
    return a, g


def block_stats(samples, quantum_adu: float):
    """Per block of ``samples`` (..., k), sorted along the last axis: median, median absolute
    deviation, and the RMS of the deviations from the median within
    ``3 max(1.4826 MAD, quantum_adu)``; each (...)."""
    samples = _f8(samples)
    shape, k = samples.shape[:-1], samples.shape[-1]
    if k < 1:
        raise ValueError("block_stats needs at least one sample a block")
    med, mad, rms = (np.empty(shape) for _ in range(3))
    _ckernels.block_stats(samples, med, mad, rms, med.size, k, float(quantum_adu))
    return med, mad, rms


def grid_box_sums(image, step: int, n_rows: int, n_cols: int):
    """(n_rows, n_cols) float64: the 3 x 3 sums of ``image`` (H, W) around the pixels
    ``(1 + step i, 1 + step j)``, added from 0 row by row, each row left to right."""
    image, code = _pixels(image)
    out = np.empty((int(n_rows), int(n_cols)))
    _ckernels.grid_box_sums(image, out, *image.shape, int(step), int(n_rows), int(n_cols), code)
    return out


def value_step(sorted_samples) -> float:
    """Smallest positive difference between consecutive values of ``sorted_samples`` (..., k),
    sorted along the last axis (0.0 when there is none)."""
    s = _f8(sorted_samples)
    k = s.shape[-1]
    return _ckernels.value_step(s, s.size // k if k else 0, k)


def median3(grid):
    """3 x 3 median of a 2-D grid, edges extended."""
    grid = _f8(grid)
    if grid.ndim != 2 or min(grid.shape) < 1:
        raise ValueError(f"grid of shape {grid.shape}")
    out = np.empty_like(grid)
    _ckernels.median3(grid, out, *grid.shape)
    return out


def mesh_at(bg, noise, block_px: int, x_px, y_px):
    """Bilinear ``bg`` and ``noise`` (n_by, n_bx) at pixel positions (arrays of equal shape)."""
    bg, noise = _f8(bg), _f8(noise)
    x, y = _f8(x_px), _f8(y_px)
    if bg.shape != noise.shape or bg.ndim != 2 or x.shape != y.shape:
        raise ValueError("mesh grids or positions of unequal shapes")
    out_bg, out_noise = np.empty(x.shape), np.empty(x.shape)
    _ckernels.mesh_at(bg, noise, x, y, out_bg, out_noise, *bg.shape, x.size, float(block_px))
    return out_bg, out_noise


def _pixels(image):
    """A C-contiguous, native-order image of a type the kernels read, and its type code.

    float16 is widened to float32 and longer floats narrowed to float64 (no kernel for them).
    """
    image = np.asarray(image)
    if image.dtype.kind == "f" and image.dtype.itemsize < 4:
        image = image.astype(np.float32)
    elif image.dtype.kind == "f" and image.dtype.itemsize > 8:
        image = image.astype(np.float64)
    image = np.ascontiguousarray(image, dtype=image.dtype.newbyteorder("="))
    if image.ndim != 2:
        raise ValueError(f"image of shape {image.shape}")
    return image, f"{image.dtype.kind}{image.dtype.itemsize}"


def _flat_indices(idx, size: int) -> np.ndarray:
    """``idx`` as a contiguous 1-D int64 array, every index within an image of ``size`` pixels."""
    idx = np.ascontiguousarray(idx, dtype=np.int64).reshape(-1)
    if idx.size and (int(idx.min()) < 0 or int(idx.max()) >= size):
        raise ValueError("pixel indices outside the image")
    return idx


def candidates(image, level, block_px: int):
    """Sorted flat indices (K,) int64 of the pixels of ``image`` (H, W) above the ``level`` of
    their block (n_by, n_bx), in the image's own type; pixels past the last block row and
    column belong to it."""
    image, code = _pixels(image)
    level = np.ascontiguousarray(level, dtype=image.dtype)
    if level.ndim != 2 or min(level.shape) < 1 or int(block_px) < 1:
        raise ValueError(f"levels of shape {level.shape}, blocks of {block_px} px")
    out = scratch("kernels.candidates", (image.size,), np.int64)
    n = _ckernels.candidates(image, level, out, *image.shape, int(block_px), *level.shape, code)
    return out[:n].copy()


def local_max(image, idx):
    """(K,) bool: pixels ``idx`` (flat) that are the maximum of their 3 x 3 neighbourhood,
    ties going to the smaller flat index."""
    image, code = _pixels(image)
    idx = _flat_indices(idx, image.size)
    keep = np.empty(idx.shape, dtype=np.uint8)
    _ckernels.local_max(image, idx, keep, idx.size, *image.shape, code)
    return keep.view(bool)


def neighbours(image, peaks):
    """Values (N, 8) float64 of the 8 neighbours of pixels ``peaks`` (flat), in the order
    (-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1) (row, column),
    and inside (N, 8) bool; a neighbour off the image has the pixel's own value."""
    image, code = _pixels(image)
    peaks = _flat_indices(peaks, image.size)
    values = np.empty((peaks.size, 8))
    inside = np.empty((peaks.size, 8), dtype=np.uint8)
    _ckernels.neighbours(image, peaks, values, inside, peaks.size, *image.shape, code)
    return values, inside.view(bool)


def tap_sum(terms, out, span: int):
    """``out[i] = sum(src[shift + i] for src, shift in terms)``, i < ``span``, summed in the
    order of ``terms`` (a list of (1-D array, shift); at most 3 distinct arrays, all of
    ``out``'s dtype, float32 or float64, C-contiguous)."""
    sources = []
    for src, _ in terms:
        if not any(src is x for x in sources):
            sources.append(src)
    if len(sources) > 3 or not terms:
        raise ValueError("tap_sum takes 1 to 3 source arrays")
    dtype = out.dtype
    if dtype not in (np.float32, np.float64) or not out.flags.c_contiguous or out.size < span:
        raise ValueError("tap_sum's output must be a contiguous float32 or float64 array of span values")
    for src in sources:
        if src.dtype != dtype or not src.flags.c_contiguous or src.ndim != 1:
            raise ValueError("tap_sum's sources must be contiguous 1-D arrays of the output's dtype")
    table = np.array([(next(k for k, x in enumerate(sources) if x is src), int(shift)) for src, shift in terms],
                     dtype=np.int64)
    if np.any(table[:, 1] < 0) or any(int(shift) + span > src.size for src, shift in terms):
        raise ValueError("tap_sum's shifts reach past a source")
    padded = sources + [sources[0]] * (3 - len(sources))
    _ckernels.tap_sum(*padded, table, out, int(span), len(terms), dtype == np.float64)


def line_filter(image, fill_value: float, minor_is_row: bool, across_px: int, pad: int, terms, kinds, out,
                patch=None):
    """The line filter of ``image`` (H, W) into ``out`` (H, W), float32 or float64 (its
    dtype is the sum's), the pixels ``patch`` ``(flat indices (P,), values (P,) or one)``
    replaced first, as ``image.astype(out.dtype).reshape(-1)[idx] = values`` would (the
    frame itself is not changed): ``terms (T, 3)`` int64 ``[source, oy, ox]`` (source 0: the
    partial sums across the smear, ``1 + j``: pairs of them of kind ``j``), ``kinds (K, 2)``
    int64 ``[dy, dx]`` (the steps from a pair's first tap to its second), every
    term within ``pad`` of the pixel (see ``_matched._terms``); ``minor_is_row``: one step
    across the smear is one row."""
    image, code = _pixels(image)
    dtype = out.dtype
    terms = np.ascontiguousarray(terms, dtype=np.int64)
    kinds = np.ascontiguousarray(kinds, dtype=np.int64).reshape(-1, 2)
    if (dtype not in (np.float32, np.float64) or out.shape != image.shape or not out.flags.c_contiguous
            or terms.ndim != 2 or terms.shape[1] != 3 or not len(terms)):
        raise ValueError("line_filter: bad arrays")
    p_idx, p_val, n_patch = np.zeros(1, np.int64), np.zeros(1, dtype), 0      # no patch (placeholders)
    if patch is not None and np.size(patch[0]):  # sorted (the kernel checks them: sorted, on the image)
        idx = np.asarray(patch[0], dtype=np.int64).reshape(-1)
        values = np.broadcast_to(np.asarray(patch[1]).astype(dtype, casting="same_kind"), idx.shape)
        order = np.argsort(idx, kind="stable")        # a repeated index: the last value, as numpy assigns
        p_idx, p_val, n_patch = np.ascontiguousarray(idx[order]), np.ascontiguousarray(values[order]), idx.size
    across = scratch("kernels.line_filter.across", (2 * pad + 1, image.shape[1] + 2 * pad), dtype)   # a ring of rows
    _ckernels.line_filter(image, code, *image.shape, float(fill_value), bool(minor_is_row), int(across_px),
                          int(pad), terms, len(terms), kinds if len(kinds) else np.zeros((1, 2), np.int64),
                          len(kinds), p_idx, p_val, n_patch, across, out, dtype == np.float64)


def label_runs(idx, width: int, *, diagonal: bool = True):
    """``(labels (K,) int64, n)``: 8-connected (``diagonal=False``: 4-connected) components
    of the sorted flat indices ``idx`` (K,), numbered in the order of their first pixel."""
    idx = np.ascontiguousarray(idx, dtype=np.int64).reshape(-1)
    if idx.size > 1 and not np.all(idx[1:] > idx[:-1]):
        raise ValueError("label_runs needs sorted, distinct flat indices")
    labels = np.empty(idx.shape, dtype=np.int64)
    n = _ckernels.label_runs(idx, labels, idx.size, int(width), bool(diagonal))
    return labels, int(n)


def box3(image) -> np.ndarray:
    """3 x 3 mean (H, W) float32 of a 2-D image, edges extended: the values of
    ``scipy.ndimage.uniform_filter(image.astype(np.float32), 3, mode="nearest")``."""
    image = np.ascontiguousarray(image, dtype=np.float32)
    if image.ndim != 2 or min(image.shape) < 1:
        raise ValueError(f"image of shape {image.shape}")
    out = np.empty_like(image)
    _ckernels.box3(image, out, *image.shape)
    return out


def region_shape(window, cx: int, cy: int, cut: float) -> tuple[float, float]:
    """``(length_px, width_px)`` of the trail test's region (``_artifacts._region_shape``)
    in ``window`` (h, w) float32, cut from the frame around the detection at pixel
    ``(cx, cy)`` of it: the 3 x 3 mean of the window (:func:`box3`'s values), its pixels
    above ``cut`` (compared in float64), the 4-connected region with the most pixels in the
    5 x 5 around ``(cx, cy)``, and its extent along and across its principal axes; (0, 0)
    when no region reaches the 5 x 5."""
    window = np.ascontiguousarray(window, dtype=np.float32)
    if window.ndim != 2 or min(window.shape) < 1:
        raise ValueError(f"image of shape {window.shape}")
    out = np.empty(2)
    _ckernels.region_shape(window, out, *window.shape, int(cx), int(cy), float(cut))
    return float(out[0]), float(out[1])


def suppress(xy, order, u, along_px: float, across_px: float) -> np.ndarray:
    """(M,) bool: peaks ``xy`` (M, 2) dropped, visiting them in ``order`` (strongest first):
    a peak not dropped drops every weaker one within ``along_px`` along the unit vector
    ``u`` and ``across_px`` across it."""
    xy = _f8(xy)
    order = np.ascontiguousarray(order, dtype=np.int64)
    if xy.shape != (len(order), 2):
        raise ValueError("peaks and order of unequal lengths")
    dropped = np.zeros(len(order), dtype=np.uint8)
    _ckernels.suppress(xy, order, dropped, len(order), float(u[0]), float(u[1]), float(along_px), float(across_px))
    return dropped.astype(bool)


def _candidates_and_mesh(name: str, idx, size: int, bg, noise):
    """``(idx, bg, noise)`` as the candidate kernels read them: sorted, distinct flat indices
    (K,) int64 on an image of ``size`` pixels, and the mesh's two (n_by, n_bx) float64 grids."""
    idx = np.ascontiguousarray(idx, dtype=np.int64).reshape(-1)
    bg, noise = _f8(bg), _f8(noise)
    if bg.shape != noise.shape or bg.ndim != 2:
        raise ValueError(f"{name}: mesh grids of unequal shapes")
    if idx.size and (idx[0] < 0 or idx[-1] >= size or (idx.size > 1 and not np.all(idx[1:] > idx[:-1]))):
        raise ValueError(f"{name} needs sorted, distinct flat indices on the image")
    return idx, bg, noise


def streak_peaks(s_image, idx, bg, noise, block_px: int, level: float, threshold: float, u, along_px: float,
                 across_px: float, max_extent_px):
    """The line filter's peaks from its candidate pixels, as ``_matched._streak_peaks_python``
    finds them (the same arithmetic in the same order): ``(col, row, snr, label, npix, too_big)``
    (M,) of the candidates ``idx`` (K,) sorted flat indices of ``s_image`` (H, W) float32 or
    float64 at or above ``level`` whose excess over the filter's bilinear background ``bg``
    (``noise``, (n_by, n_bx) blocks of ``block_px``) is at least ``threshold`` noises and that
    are the maximum of their 3 x 3 neighbourhood, strongest first; those within ``along_px``
    along the unit smear ``u`` (2,) and ``across_px`` across it of a stronger kept one
    dropped; each one's 8-connected component of the candidates, its pixel count, and
    whether its RMS extent along or across the smear exceeds ``max_extent_px`` (2,) (then
    only the component's strongest peak is kept)."""
    s_image = np.asarray(s_image)
    if s_image.dtype not in (np.float32, np.float64) or s_image.ndim != 2 or not s_image.flags.c_contiguous:
        raise ValueError("streak_peaks: the filter image must be a C-contiguous 2-D float32 or float64 array")
    idx, bg, noise = _candidates_and_mesh("streak_peaks", idx, s_image.size, bg, noise)
    k = idx.size
    col, row, label, npix = (np.empty(k, dtype=np.int64) for _ in range(4))
    snr, too_big = np.empty(k), np.empty(k, dtype=np.uint8)
    n = _ckernels.streak_peaks(s_image, idx, bg, noise, col, row, snr, label, npix, too_big, k, *s_image.shape,
                               *bg.shape, float(block_px), float(level), float(threshold), float(u[0]), float(u[1]),
                               float(along_px), float(across_px), float(max_extent_px[0]), float(max_extent_px[1]),
                               s_image.dtype == np.float64)
    return col[:n], row[:n], snr[:n], label[:n], npix[:n], too_big[:n].astype(bool)


def point_objects(image, idx, bg, noise, block_px: int, level: float, ratio: float):
    """Point sources from the candidate pixels ``idx`` (K,) (sorted flat indices) of ``image``
    (H, W), as ``_point._detect_objects_python`` finds them (the same arithmetic in the same
    order): ``(peaks (M,), peak_label (M,), labels (K,))`` int64 -- the candidates that are the
    maximum of their 3 x 3 neighbourhood, whose 3 x 3 box excess over the bilinear background
    ``bg`` (``noise``; (n_by, n_bx) blocks of ``block_px``) is at least ``level`` (the
    threshold times the box-noise factor) times ``sqrt(box pixels) noise`` and whose 8
    neighbours hold at least ``ratio`` of the peak pixel's excess, one a component (the
    largest box excess; ties the first) in flat-index order, each one's component, and every
    candidate's 8-connected component (numbered as :func:`label_runs`)."""
    image, code = _pixels(image)
    idx, bg, noise = _candidates_and_mesh("point_objects", idx, image.size, bg, noise)
    k = idx.size
    peaks, peak_label, labels = (np.empty(k, dtype=np.int64) for _ in range(3))
    n = _ckernels.point_objects(image, idx, bg, noise, peaks, peak_label, labels, k, *image.shape, *bg.shape,
                                float(block_px), float(level), float(ratio), code)
    return peaks[:n], peak_label[:n], labels


def erf(x) -> np.ndarray:
    """The error function of an array (any shape), float64."""
    x = _f8(x)
    out = np.empty_like(x)
    _ckernels.erf_array(x, out, x.size)
    return out


def cho_solve(low, b):
    """Solve ``(L L^T) x = b`` for stacks ``low`` (N, k, k) lower triangular and ``b``
    (N, k, m): the substitutions of ``_fit._cho_solve_python``, matrix by matrix, the same
    values to the bit."""
    low = _f8(low)
    y = np.array(b, dtype=np.float64, order="C")                    # a copy, solved in place
    n, k = low.shape[:2]
    if low.shape != (n, k, k) or y.ndim != 3 or y.shape[:2] != (n, k):
        raise ValueError(f"cho_solve of shapes {low.shape} and {y.shape}")
    _ckernels.cho_solve(low, y, n, k, y.shape[2])
    return y


def grid_box_z(total, bg, noise, block_px: float, step: int):
    """``(total - 9 bg) / (3 noise)`` (n_rows, n_cols) at the grid pixels ``(1 + step i,
    1 + step j)`` of :func:`grid_box_sums`'s ``total``, ``bg`` and ``noise`` (n_by, n_bx)
    bilinear between block centres (``_background.Mesh.on_grid``'s weights)."""
    total, bg, noise = _f8(total), _f8(bg), _f8(noise)
    if total.ndim != 2 or bg.ndim != 2 or noise.shape != bg.shape or min(bg.shape) < 1:
        raise ValueError("grid_box_z: bad shapes")
    out = np.empty_like(total)
    _ckernels.grid_box_z(total, bg, noise, out, *total.shape, *bg.shape, float(block_px), int(step))
    return out


def streak_start(win, col, row, sigma, d, reach: float, along_max: float, across_max: float):
    """The streak fits' start parameters (N, 7) of ``_streak.start_parameters`` (whose NumPy
    code, ``_streak._start_parameters_python``, is the reference, bit for bit): windows
    ``win`` (values, valid, bg, noise, x0, y0), peaks ``col``, ``row`` (N,), PSF sigma (N,),
    smears ``d`` (N, 2)."""
    values = _f8(win.values)
    n_star = len(values)
    wy, wx = values.shape[1:] if values.ndim == 3 else (0, 0)
    valid = np.ascontiguousarray(win.valid, dtype=np.bool_).view(np.uint8)
    per_star = [_f8(a).reshape(-1) for a in (win.bg, win.noise, win.x0, win.y0, col, row, sigma)]
    d = _f8(d).reshape(-1, 2)
    if values.shape != (n_star, wy, wx) or valid.shape != values.shape or d.shape != (n_star, 2) \
            or any(a.shape != (n_star,) for a in per_star):
        raise ValueError("streak_start: arrays of inconsistent shapes")
    p0 = np.empty((n_star, 7))
    _ckernels.streak_start(values, valid, *per_star, d, p0, n_star, wy, wx, float(reach), float(along_max),
                           float(across_max))
    return p0


def streak_footprint(model, bg, values, valid, col, row, shape_hw, fraction: float, saturated=None):
    """The streak fits' footprints (``_smeared._footprint_python``'s numbers, the reference):
    ``(foot (N, wy, wx) bool, peak (N,), npix (N,) int64, saturated (N,) bool, off_image
    (N,) bool)`` of the fitted models ``model`` (N, wy * wx) over their backgrounds ``bg``
    (N,), the windows' ``values`` and ``valid`` (N, wy, wx) centred on ``col``, ``row`` (N,)
    of an image of shape ``shape_hw`` whose saturated pixels are ``saturated`` ((H, W) bool;
    None: none is)."""
    values = _f8(values)
    n, wy, wx = values.shape
    valid_u8 = np.ascontiguousarray(valid, dtype=np.bool_).view(np.uint8)
    model, bg = _f8(model).reshape(n, wy * wx), _f8(bg).reshape(-1)
    col = np.ascontiguousarray(col, dtype=np.int64).reshape(-1)
    row = np.ascontiguousarray(row, dtype=np.int64).reshape(-1)
    h, w = (int(v) for v in shape_hw)
    sat = np.zeros(1, np.uint8) if saturated is None else np.ascontiguousarray(saturated, dtype=np.bool_).view(np.uint8)
    if valid_u8.shape != values.shape or bg.shape != (n,) or col.shape != (n,) or row.shape != (n,) \
            or (saturated is not None and sat.shape != (h, w)):
        raise ValueError("streak_footprint: arrays of inconsistent shapes")
    foot = np.empty(values.shape, dtype=np.bool_)
    peak, npix, flags = np.empty(n), np.empty(n, dtype=np.int64), np.empty((n, 2), dtype=np.bool_)
    _ckernels.streak_footprint(model, bg, values, valid_u8, sat, col, row, foot.view(np.uint8), peak, npix,
                               flags.view(np.uint8), n, wy, wx, h, w, saturated is not None, float(fraction))
    return foot, peak, npix, flags[:, 0], flags[:, 1]


def window_peaks(values, valid, level, taps, search: int, cx: int, cy: int):
    """Per window (N, wy, wx): the flat index (N,) int64 among the (2 search + 1)^2 places
    around pixel (cx, cy) of the first largest line-filter sum, and that sum (N,): the sums
    over ``taps`` (T, 2) ``(ox, oy)``, in their order, of ``valid ? values - level : 0``
    (``_windowed._peaks_python``'s values, bit for bit)."""
    values = _f8(values)
    n, wy, wx = values.shape
    valid = np.ascontiguousarray(valid, dtype=np.bool_).view(np.uint8)
    level = _f8(level).reshape(-1)
    taps = np.ascontiguousarray(taps, dtype=np.int64).reshape(-1, 2)
    if valid.shape != values.shape or level.shape != (n,):
        raise ValueError("window_peaks: arrays of inconsistent shapes")
    best, s = np.empty(n, dtype=np.int64), np.empty(n)
    _ckernels.window_peaks(values, valid, level, taps, best, s, n, wy, wx, len(taps), int(search), int(cx), int(cy))
    return best, s


def ring_levels(values, valid, bg, noise, ring_px: int):
    """``(level, own (N,))``: the border rings (``ring_px`` wide) of the windows ``values``
    (N, wy, wx) less their background ``bg`` (N,), their valid pixels within 3 ``noise`` (N,)
    of the median of all of them: pooled mean (NaN: none) and each window's mean (0: none)
    (``_windowed._ring_shift_python``'s values, bit for bit)."""
    values = _f8(values)
    n, wy, wx = values.shape
    valid = np.ascontiguousarray(valid, dtype=np.bool_).view(np.uint8)
    bg, noise = _f8(bg).reshape(-1), _f8(noise).reshape(-1)
    if valid.shape != values.shape or bg.shape != (n,) or noise.shape != (n,):
        raise ValueError("ring_levels: arrays of inconsistent shapes")
    own = np.empty(n)
    level = _ckernels.ring_levels(values, valid, bg, noise, own, n, wy, wx, int(ring_px))
    return level, own


def gather(image, col, row, hx: int, hy: int, bad=None):
    """``(values (N, 2 hy + 1, 2 hx + 1) float64, valid (same) bool)``: the windows of ``image``
    (H, W) centred on the integer pixels ``col``, ``row`` (N,), off-image pixels the nearest
    pixel's value and invalid, pixels of ``bad`` ((H, W) bool, optional) invalid."""
    image, code = _pixels(image)
    h, w = image.shape
    col = np.ascontiguousarray(col, dtype=np.int64).reshape(-1)
    row = np.ascontiguousarray(row, dtype=np.int64).reshape(-1)
    n = col.size
    if row.size != n:
        raise ValueError("gather: col and row of different lengths")
    if bad is None:
        bad_u8, has_bad = np.zeros(1, np.uint8), False
    else:
        bad_u8 = np.ascontiguousarray(bad, dtype=np.bool_).view(np.uint8)
        if bad_u8.shape != (h, w):
            raise ValueError("gather: bad mask of another shape than the image")
        has_bad = True
    values = np.empty((n, 2 * hy + 1, 2 * hx + 1))
    valid = np.empty(values.shape, dtype=np.bool_)
    _ckernels.gather(image, values, valid.view(np.uint8), col, row, bad_u8, h, w, n, int(hx), int(hy), has_bad, code)
    return values, valid


def crowded_count(values, valid, bg, noise, dx, dy, u, along_max: float, across_max: float, k: float):
    """``(N,)`` int64: per window (N, wy, wx), its valid pixels above ``bg + k noise`` outside
    the footprint (``|along| <= along_max``, ``|across| <= across_max`` along the unit vector
    ``u``) centred ``dx, dy`` (N,) px from the window's centre (``_windowed._crowded_python``'s
    pixels)."""
    values = _f8(values)
    n, wy, wx = values.shape
    valid = np.ascontiguousarray(valid, dtype=np.bool_).view(np.uint8)
    per_star = [_f8(bg).reshape(-1), _f8(noise).reshape(-1)]
    offsets = [np.ascontiguousarray(a, dtype=np.int64).reshape(-1) for a in (dx, dy)]
    if valid.shape != values.shape or any(a.shape != (n,) for a in per_star + offsets):
        raise ValueError("crowded_count: arrays of inconsistent shapes")
    counts = np.empty(n, dtype=np.int64)
    _ckernels.crowded_count(values, valid, *per_star, *offsets, counts, n, wy, wx, float(u[0]), float(u[1]),
                            float(along_max), float(across_max), float(k))
    return counts


def box_sums(image, peaks):
    """``(total (N,), count (N,))`` float64: each pixel ``peaks`` (flat) plus its 8 neighbours on
    the image (``_detect._box_sums_python``'s sums, bit for bit), and 1 + how many those are."""
    image, code = _pixels(image)
    peaks = _flat_indices(peaks, image.size)
    total, count = np.empty(peaks.size), np.empty(peaks.size)
    _ckernels.box_sums(image, peaks, total, count, peaks.size, *image.shape, code)
    return total, count


def point_start(win, sigma_px: float):
    """The point fits' start values (N, 5) ``(x, y, F, b, sigma)`` of windows ``win`` (values,
    valid (N, S, S), bg, x0, y0) (``_fit._start_values_python``'s values, bit for bit)."""
    values = _f8(win.values)
    n = len(values)
    size = values.shape[-1] if values.ndim == 3 else 0
    valid = np.ascontiguousarray(win.valid, dtype=np.bool_).view(np.uint8)
    per_star = [_f8(a).reshape(-1) for a in (win.bg, win.x0, win.y0)]
    if values.shape != (n, size, size) or valid.shape != values.shape or any(a.shape != (n,) for a in per_star):
        raise ValueError("point_start: windows of inconsistent shapes")
    p = np.empty((n, 5))
    _ckernels.point_start(values, valid, *per_star, p, n, size, float(sigma_px))
    return p


def too_sharp(image, peaks, bg, noise, saturated, inv_gain: float, ratio_total: float, ratio_edges: float,
              n_sigma: float):
    """``(N,)`` bool: the peaks (flat) sharper than a PSF whose neighbour ratios are
    ``ratio_total`` / ``ratio_edges`` allows, by ``n_sigma`` (``noise`` (N,) the per-pixel noise
    times the box-noise factor; ``_point._too_sharp_python``'s answer)."""
    image, code = _pixels(image)
    peaks = _flat_indices(peaks, image.size)
    k = peaks.size
    bg, noise = _f8(bg).reshape(-1), _f8(noise).reshape(-1)
    sat = np.ascontiguousarray(saturated, dtype=np.bool_).reshape(-1).view(np.uint8)
    if bg.shape != (k,) or noise.shape != (k,) or sat.shape != (k,):
        raise ValueError("too_sharp: arrays of inconsistent lengths")
    out = np.empty(k, dtype=np.bool_)
    _ckernels.too_sharp(image, peaks, bg, noise, sat, out.view(np.uint8), k, *image.shape, float(inv_gain),
                        float(ratio_total), float(ratio_total) ** 2, float(ratio_edges), float(ratio_edges) ** 2,
                        float(n_sigma), code)
    return out


def component_stats(image, pix, who, bg, n: int, saturation: float, elongation2: float, flag_saturated: int,
                    flag_edge: int, flag_elongated: int) -> dict:
    """Per star ``0 .. n - 1`` of the pixels ``pix`` (flat) that belong to star ``who`` (both (M,)),
    background ``bg`` (M,): its pixel count, peak, flags and thresholded centre of gravity and
    second moments (``_point._component_stats_python``'s dict, the same values)."""
    image, code = _pixels(image)
    pix = _flat_indices(pix, image.size)
    who = np.ascontiguousarray(who, dtype=np.int64).reshape(-1)
    bg = _f8(bg).reshape(-1)
    m = pix.size
    if who.shape != (m,) or bg.shape != (m,):
        raise ValueError("component_stats: arrays of inconsistent lengths")
    npix, flags = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
    peak, flux, cx, cy, mxx, myy, mxy = (np.empty(n) for _ in range(7))
    _ckernels.component_stats(image, pix, who, bg, npix, peak, flux, cx, cy, mxx, myy, mxy, flags, m, int(n),
                              *image.shape, float(saturation), float(elongation2), int(flag_saturated),
                              int(flag_edge), int(flag_elongated), code)
    return dict(npix=npix, peak=peak, flags=flags, cog=np.stack([cx, cy], axis=1), cog_flux=flux,
                moments=np.stack([mxx, myy, mxy], axis=1))


def median_abs_deviation(x) -> float:
    """The median of ``|x - median(x)|`` of a non-empty array, exactly as
    ``_background.median`` takes both medians (NaN-free values)."""
    x = _f8(x).reshape(-1)
    if x.size == 0:
        raise ValueError("median_abs_deviation of no values")
    return _ckernels.median_abs_deviation(x, x.size)


def _i8(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.int64).reshape(-1)


def persistent_pairs(table_keys, table_frames, keys, near, oldest: int, window: int, min_count: int) -> tuple:
    """``(stars (P,), frames (P,))`` int64: each of the detections' pixel ``keys`` (N,) with
    each remembered frame after ``oldest`` (up to ``oldest + window``) whose entry in the
    sorted table ``table_keys`` / ``table_frames`` (T,) lies at one of ``keys[n] + near``
    (9,), for the detections with at least ``min_count`` such frames; star-major, frames
    increasing (``_artifacts.PersistentPixels._pairs_python``'s arrays)."""
    tk, tf, keys, near = _i8(table_keys), _i8(table_frames), _i8(keys), _i8(near)
    window = int(window)
    if tf.size != tk.size or near.size != 9 or window < 1:
        raise ValueError("persistent_pairs: arrays of inconsistent lengths")
    stamp = np.empty(window, dtype=np.int64)
    stars, frames = np.empty(keys.size * window, dtype=np.int64), np.empty(keys.size * window, dtype=np.int64)
    n = _ckernels.persistent_pairs(tk, tf, tk.size, keys, keys.size, near, int(oldest), window, int(min_count),
                                   stamp, stars, frames)
    if n < 0:
        raise ValueError("persistent_pairs: a remembered frame after the window")
    return stars[:n], frames[:n]


def persistent_merge(table_keys, table_frames, new_keys, oldest: int, frame: int) -> tuple:
    """``(keys, frames)``: the table's entries after ``oldest`` and the sorted distinct
    ``new_keys`` (each with ``frame``) merged in key order, old entries first among equal
    keys (a stable sort of the two concatenated)."""
    tk, tf, nk = _i8(table_keys), _i8(table_frames), _i8(new_keys)
    if tf.size != tk.size:
        raise ValueError("persistent_merge: arrays of inconsistent lengths")
    if nk.size > 1 and not np.all(nk[1:] > nk[:-1]):
        raise ValueError("persistent_merge needs sorted, distinct new keys")
    keys, frames = np.empty(tk.size + nk.size, dtype=np.int64), np.empty(tk.size + nk.size, dtype=np.int64)
    n = _ckernels.persistent_merge(tk, tf, tk.size, nk, nk.size, int(oldest), int(frame), keys, frames)
    return keys[:n], frames[:n]
