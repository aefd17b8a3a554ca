"""Detection on sparse candidate pixels: threshold, local maxima, connected components.

Only the pixels above a low per-pixel threshold (the *candidates*, a few per cent of
the frame at most) are ever gathered; everything after the threshold works on their
flat indices, so the cost does not grow with the frame beyond one comparison pass.
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.extract._kernels import box_sums as kernel_box_sums
from shipstar.extract._kernels import candidates, label_runs, local_max, neighbours

__all__ = ["candidate_pixels", "local_maxima", "box_sums", "neighbour_values", "EDGE_NEIGHBOURS", "components",
           "sum_dtype", "at_or_above"]

#: Float frames with values beyond this (magnitude) are summed in float64: float32 sums of
#: many such pixels (line filter, binning) would overflow (the entry check allows 3e38).
_FLOAT32_SUM_MAX_ADU = 1e30


def at_or_above(image, level: float) -> np.ndarray:
    """``image >= level`` (bool, the image's shape) for a finite ``level``, compared in an
    integer image's own type against ``ceil(level)`` (the same answer for every integer
    pixel): ``image >= level`` with a Python float casts a whole 16-bit frame to float64
    first (~1 ms a 1024 x 1024 frame, 10 x the comparison).  Integers of 8 bytes keep the
    float comparison, whose float64 cast rounds their large values (the answer NumPy gives)."""
    if image.dtype.kind in "ui" and image.dtype.itemsize <= 4:   # every value exact in float64
        info = np.iinfo(image.dtype)
        top = math.ceil(level)
        if top <= info.min:
            return np.ones(image.shape, dtype=bool)
        if top > info.max:
            return np.zeros(image.shape, dtype=bool)
        return image >= image.dtype.type(top)
    return image >= level


def sum_dtype(image):
    """float32 for frame-sized sums of ``image``'s pixels, float64 when its values are too large."""
    if image.dtype.kind == "f" and image.size and float(np.max(np.abs(image))) > _FLOAT32_SUM_MAX_ADU:
        return np.float64
    return np.float32

_OFFSETS_RC = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def candidate_pixels(image, mesh, level_sigma):
    """Sorted flat indices (K,) int64 of the pixels above ``background + level_sigma * noise``
    (block-wise levels; the last block row and column also cover the pixels past the
    mesh's blocks, in a frame whose size is not a multiple of the block size): one pass of
    the compiled kernel, in the image's own type."""
    level = _level_as(image.dtype, mesh.bg + level_sigma * mesh.noise)
    if level.dtype != image.dtype:              # integers against a level beyond their range: exact in float64
        image, level = image.astype(np.float64), level.astype(np.float64)
    return candidates(image, level, mesh.block_px)


def _level_as(dtype, level):
    """Block levels in the image's own type: for integers ``v > level <=> v > floor(level)``, and a
    comparison without conversion is 5 x faster; float64 for float64 frames, float32 otherwise."""
    if dtype.kind in "ui":
        info = np.iinfo(dtype)
        floor = np.floor(level)
        if np.all(np.isfinite(floor)) and floor.min() >= info.min:
            return np.minimum(floor, info.max).astype(dtype)
    if dtype == np.float64:
        return level
    top = float(np.finfo(np.float32).max)                   # nothing in the frame is above it anyway
    return np.clip(level, -top, top).astype(np.float32)


def local_maxima(flat, idx, shape_hw):
    """Candidates that are the maximum of their 3x3 neighbourhood (compiled).

    Ties go to the pixel with the smallest flat index, so a flat (saturated) top gives
    few maxima, and a component keeps one star anyway.

    Returns
    -------
    (M,) int64 flat indices (a subset of ``idx``).
    """
    return idx[local_max(flat.reshape(shape_hw), idx)]


def neighbour_values(flat, peaks, shape_hw):
    """Values (N, 8) of the 8 neighbours of each peak, in ``_OFFSETS_RC`` order, and inside (N, 8).

    Neighbours off the image get the peak's own value and ``inside = False``.
    """
    return neighbours(flat.reshape(shape_hw), peaks)


#: Columns of the 4 edge-sharing neighbours in ``neighbour_values``.
EDGE_NEIGHBOURS = [k for k, (dr, dc) in enumerate(_OFFSETS_RC) if abs(dr) + abs(dc) == 1]


def box_sums(flat, peaks, shape_hw):
    """Sum and count of the inside pixels of the 3x3 box around each peak (compiled:
    :func:`_box_sums_python`'s values to the bit)."""
    return kernel_box_sums(flat.reshape(shape_hw), peaks)


def _box_sums_python(flat, peaks, shape_hw):
    """:func:`box_sums` in NumPy (the compiled kernel's reference)."""
    values, inside = neighbour_values(flat, peaks, shape_hw)
    total = flat[peaks].astype(float) + np.sum(np.where(inside, values, 0.0), axis=1)
    return total, 1.0 + inside.sum(axis=1)


def components(idx, shape_hw):
    """8-connected components of the candidate pixels.

    Built on runs (maximal horizontal segments of candidates, a few per star): the runs of
    adjacent rows that touch (8-connectivity) are joined by union-find in the compiled
    kernel (:func:`shipstar.extract._kernels.label_runs`); components are numbered in the
    order of their first pixel.

    Returns
    -------
    labels : (K,) int array
        Component number of each candidate (same order as ``idx``).
    n : int
        Number of components.
    """
    if idx.size == 0:
        return np.zeros(0, dtype=np.int64), 0
    return label_runs(idx, shape_hw[1])
