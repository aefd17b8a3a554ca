"""Detection on sparse candidate pixels: threshold, local maxima, connected components.

Only the pixels above a low per-pixel threshold (the *candidates*, a few per cent of
the frame at most) are ever gathered; everything after the threshold works on their
flat indices, so the cost does not grow with the frame beyond one comparison pass.
"""

from __future__ import annotations

import numpy as np

__all__ = ["candidate_pixels", "local_maxima", "box_sums", "neighbour_values", "EDGE_NEIGHBOURS", "components",
           "sum_dtype"]

#: Float frames with values beyond this (magnitude) are summed in float64: float32 sums of
#: many such pixels (line filter, binning) would overflow (the entry check allows 3e38).
_FLOAT32_SUM_MAX_ADU = 1e30


def sum_dtype(image):
    """float32 for frame-sized sums of ``image``'s pixels, float64 when its values are too large."""
    if image.dtype.kind == "f" and image.size and float(np.max(np.abs(image))) > _FLOAT32_SUM_MAX_ADU:
        return np.float64
    return np.float32

_OFFSETS_RC = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def candidate_pixels(image, mesh, level_sigma):
    """Pixels above ``background + level_sigma * noise`` (block-wise levels).

    Returns
    -------
    mask : (H, W) bool array
    idx : (K,) int64 array
        Sorted flat indices of the ``True`` pixels.
    """
    height, width = image.shape
    block = mesh.block_px
    level = _level_as(image.dtype, mesh.bg + level_sigma * mesh.noise)
    n_by, n_bx = height // block, width // block
    if (n_by, n_bx) == level.shape and n_by * block == height and n_bx * block == width:
        mask = (image.reshape(n_by, block, n_bx, block) > level[:, None, :, None]).reshape(height, width)
        return mask, np.flatnonzero(mask)
    # the last block row and column also cover the pixels past the mesh's blocks (a frame
    # whose size is not a multiple of the block size)
    mask = np.empty((height, width), dtype=bool)
    col_block = np.minimum(np.arange(width) // block, level.shape[1] - 1)
    n_rows = level.shape[0]
    for r in range(n_rows):
        r0, r1 = r * block, (height if r == n_rows - 1 else min((r + 1) * block, height))
        if r0 >= r1:
            break
        np.greater(image[r0:r1], level[r][col_block], out=mask[r0:r1])
    return mask, np.flatnonzero(mask)


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


class _Grid:
    """Row and column of flat pixel indices, computed once, and their neighbours."""

    def __init__(self, idx, shape_hw):
        self.idx = idx
        self.height, self.width = shape_hw
        self.row, self.col = np.divmod(idx, self.width)

    def take(self, sel) -> "_Grid":
        out = _Grid.__new__(_Grid)
        out.idx, out.row, out.col = self.idx[sel], self.row[sel], self.col[sel]
        out.height, out.width = self.height, self.width
        return out

    def neighbour(self, dr, dc):
        """Flat index of the (dr, dc) neighbour (the pixel itself where that is outside) and inside."""
        inside = np.ones(self.idx.shape, dtype=bool)
        if dr:
            inside &= (self.row >= -dr) if dr < 0 else (self.row < self.height - dr)
        if dc:
            inside &= (self.col >= -dc) if dc < 0 else (self.col < self.width - dc)
        return np.where(inside, self.idx + (dr * self.width + dc), self.idx), inside


def local_maxima(flat, idx, shape_hw):
    """Candidates that are the maximum of their 3x3 neighbourhood.

    Ties go to the pixel with the smallest flat index, so a flat (saturated) top gives
    few maxima, and a component keeps one star anyway.

    Returns
    -------
    (M,) int64 flat indices (a subset of ``idx``).
    """
    keep = np.ones(idx.shape, dtype=bool)
    values = flat[idx]
    grid = _Grid(idx, shape_hw)
    order = sorted(_OFFSETS_RC, key=lambda o: (abs(o[0]) + abs(o[1]), o))  # direct neighbours first
    for dr, dc in order:
        sel = np.flatnonzero(keep)
        nb, inside = grid.take(sel).neighbour(dr, dc)
        nb_values = flat[nb]
        before = dr * shape_hw[1] + dc < 0
        ok = values[sel] > nb_values if before else values[sel] >= nb_values
        keep[sel[~(ok | ~inside)]] = False
    return idx[keep]


def neighbour_values(flat, peaks, shape_hw):
    """Values (N, 8) of the 8 neighbours of each peak, in ``_OFFSETS_RC`` order, and inside (N, 8).

    Neighbours off the image get the peak's own value and ``inside = False``.
    """
    grid = _Grid(peaks, shape_hw)
    values = np.empty((len(peaks), 8))
    inside = np.empty((len(peaks), 8), dtype=bool)
    for k, (dr, dc) in enumerate(_OFFSETS_RC):
        nb, inside[:, k] = grid.neighbour(dr, dc)
        values[:, k] = flat[nb]
    return values, inside


#: Columns of the 4 edge-sharing neighbours in ``neighbour_values``.
EDGE_NEIGHBOURS = [k for k, (dr, dc) in enumerate(_OFFSETS_RC) if abs(dr) + abs(dc) == 1]


def box_sums(flat, peaks, shape_hw):
    """Sum and count of the inside pixels of the 3x3 box around each peak."""
    values, inside = neighbour_values(flat, peaks, shape_hw)
    total = flat[peaks].astype(float) + np.sum(np.where(inside, values, 0.0), axis=1)
    return total, 1.0 + inside.sum(axis=1)


def components(mask, idx, shape_hw):
    """8-connected components of the candidate pixels.

    Built on runs (maximal horizontal segments of candidates, a few per star): the runs
    of adjacent rows that touch (8-connectivity) are the graph's edges, found by binary
    search, and ``scipy.sparse.csgraph`` labels that graph, several times smaller than
    the pixels' own.

    Returns
    -------
    labels : (K,) int array
        Component number of each candidate (same order as ``idx``).
    n : int
        Number of components.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    del mask                                  # the sorted indices say it all
    width = shape_hw[1]
    if idx.size == 0:
        return np.zeros(0, dtype=np.int64), 0
    row = idx // width
    new = np.ones(idx.size, dtype=bool)
    new[1:] = (idx[1:] != idx[:-1] + 1) | (row[1:] != row[:-1])
    run_of = np.cumsum(new) - 1
    first = np.flatnonzero(new)
    start = idx[first]                                            # flat index of each run's first pixel
    end = idx[np.append(first[1:], idx.size) - 1]                 # ... and of its last
    run_row = row[first]
    col0, col1 = start - run_row * width, end - run_row * width
    below = (run_row + 1) * width
    lo = np.searchsorted(end, below + np.maximum(col0 - 1, 0), side="left")          # runs of the next row
    hi = np.searchsorted(start, below + np.minimum(col1 + 1, width - 1), side="right")  # that touch this one
    count = np.maximum(hi - lo, 0)
    total = int(count.sum())
    a = np.repeat(np.arange(first.size), count)
    b = np.repeat(lo, count) + np.arange(total) - np.repeat(np.cumsum(count) - count, count)
    graph = coo_matrix((np.ones(total, dtype=np.int8), (a, b)), shape=(first.size, first.size))
    n, run_labels = connected_components(graph, directed=False)
    return run_labels[run_of], n
