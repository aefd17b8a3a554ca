"""Detection on sparse candidate pixels: threshold, local maxima, connected components.

Only the pixels above a low per-pixel threshold (the *candidates*, a few per cent of
the frame at most) are ever gathered; everything after the threshold works on their
flat indices, so the cost does not grow with the frame beyond one comparison pass.
"""

from __future__ import annotations

import numpy as np

__all__ = ["candidate_pixels", "local_maxima", "box_sums", "neighbour_values", "EDGE_NEIGHBOURS", "components"]

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
    level = (mesh.bg + level_sigma * mesh.noise).astype(np.float32)
    n_by, n_bx = height // block, width // block
    if (n_by, n_bx) == level.shape and n_by * block == height and n_bx * block == width:
        mask = (image.reshape(n_by, block, n_bx, block) > level[:, None, :, None]).reshape(height, width)
        return mask, np.flatnonzero(mask)
    mask = np.empty((height, width), dtype=bool)
    for r in range(level.shape[0]):
        r0, r1 = r * block, min((r + 1) * block, height)
        if r0 >= r1:
            break
        row_level = np.repeat(level[r], block)[:width]
        np.greater(image[r0:r1], row_level, out=mask[r0:r1])
    return mask, np.flatnonzero(mask)


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

    Returns
    -------
    labels : (K,) int array
        Component number of each candidate (same order as ``idx``).
    n : int
        Number of components.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    flat_mask = mask.reshape(-1)
    a_list, b_list = [], []
    grid = _Grid(idx, shape_hw)
    for dr, dc in ((0, 1), (1, -1), (1, 0), (1, 1)):
        nb, inside = grid.neighbour(dr, dc)
        linked = inside & flat_mask[nb]
        a_list.append(np.flatnonzero(linked))
        b_list.append(np.searchsorted(idx, nb[linked]))
    a = np.concatenate(a_list)
    b = np.concatenate(b_list)
    graph = coo_matrix((np.ones(a.size, dtype=np.int8), (a, b)), shape=(idx.size, idx.size))
    n, labels = connected_components(graph, directed=False)
    return labels, n
