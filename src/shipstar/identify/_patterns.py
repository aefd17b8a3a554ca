"""Four-star pattern geometry shared by the database builder and the solvers.

A *pattern* is four stars.  Its six pairwise angular separations (edges), sorted
ascending, divided by the largest, give five *edge ratios* in (0, 1]: invariant to
rotation and (to first order) to the focal length.  The ratios are quantised into
``bins`` cells each and combined into one integer *key* (exact, no hash collisions
beyond the quantisation itself), ``key = sum_k q_k * bins**k``.

Every array here is vectorised over patterns: ``(P, 4)`` star indices, ``(P, 6)``
edges, ``(P, 5)`` ratios.  The canonical pair order of the six edges is
``(0,1), (0,2), (0,3), (1,2), (1,3), (2,3)``.
"""

from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np

__all__ = [
    "PAIR_A", "PAIR_B", "PERMUTATION_EDGES", "PERMUTATIONS",
    "ordered_combinations", "pattern_edges_rad", "edge_ratios", "pattern_keys",
    "probe_keys",
]

#: first and second star of each of the six edges, canonical order
PAIR_A = np.array([0, 0, 0, 1, 1, 2])
PAIR_B = np.array([1, 2, 3, 2, 3, 3])
_PAIR_INDEX = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(PAIR_A, PAIR_B))}

#: the 24 permutations of four stars, (24, 4)
PERMUTATIONS = np.array(list(itertools.permutations(range(4))))


def _perm_edges():
    out = np.empty((24, 6), dtype=np.intp)
    for p, perm in enumerate(PERMUTATIONS):
        for k, (a, b) in enumerate(zip(PAIR_A, PAIR_B)):
            i, j = sorted((int(perm[a]), int(perm[b])))
            out[p, k] = _PAIR_INDEX[(i, j)]
    return out


#: ``edges[:, PERMUTATION_EDGES[p]]`` are the edges of the pattern whose star ``a`` is
#: the original pattern's star ``PERMUTATIONS[p, a]``; shape (24, 6)
PERMUTATION_EDGES = _perm_edges()


@lru_cache(maxsize=40)
def combination_edges(n_stars: int) -> np.ndarray:
    """Flat indices ``a * n_stars + b`` of the six edges of every pattern of
    :func:`ordered_combinations` into an ``(n_stars, n_stars)`` matrix; shape (C, 6)."""
    c = ordered_combinations(n_stars)
    out = c[:, PAIR_A] * n_stars + c[:, PAIR_B]
    out.setflags(write=False)
    return out


@lru_cache(maxsize=40)
def ordered_combinations(n_stars: int) -> np.ndarray:
    """All 4-subsets of ``range(n_stars)``, brightest patterns first; shape (C, 4), int.

    Breadth-first order: every pattern of the brightest ``m`` stars comes before any
    pattern that uses star ``m`` (so adding stars to the search never reorders the
    earlier patterns); within one ``m``, patterns with the smaller sum of brightness
    ranks come first.  Each row is sorted ascending.
    """
    if n_stars < 4:
        return np.empty((0, 4), dtype=np.intp)
    count = n_stars * (n_stars - 1) * (n_stars - 2) * (n_stars - 3) // 24
    combos = np.fromiter(itertools.chain.from_iterable(itertools.combinations(range(n_stars), 4)),
                         dtype=np.intp, count=4 * count).reshape(count, 4)       # 3x faster than np.array(list)
    order = np.lexsort((combos[:, 2], combos[:, 1], combos[:, 0], combos.sum(axis=1),
                        combos[:, 3]))
    out = combos[order]
    out.setflags(write=False)
    return out


def pattern_edges_rad(u):
    """Six edge angles (rad) of patterns given by their star vectors.

    Parameters
    ----------
    u : ndarray, shape (P, 4, 3)
        Unit vectors of the four stars of each pattern.

    Returns
    -------
    ndarray, shape (P, 6)
        Angles in canonical pair order (computed in float64 whatever ``u``'s type:
        float32 dot products would cost 6e-6 rad on a 0.01 rad edge).
    """
    u = np.asarray(u, dtype=np.float64)
    dots = np.einsum("pkj,pkj->pk", u[:, PAIR_A], u[:, PAIR_B])
    return np.arccos(np.clip(dots, -1.0, 1.0))


def edge_ratios(edges_rad):
    """Sorted edge ratios of patterns.

    Parameters
    ----------
    edges_rad : ndarray, shape (P, 6)

    Returns
    -------
    ratios : ndarray, shape (P, 5)
        The five smallest edges, ascending, divided by the largest.
    largest_rad : ndarray, shape (P,)
        The largest edge.
    """
    srt = np.sort(edges_rad, axis=1)
    largest = srt[:, 5]
    return srt[:, :5] / largest[:, None], largest


def _weights(bins: int) -> np.ndarray:
    return np.asarray(bins, dtype=np.int64) ** np.arange(5, dtype=np.int64)


def pattern_keys(ratios, bins: int) -> np.ndarray:
    """Integer keys of patterns from their sorted edge ratios; shape (P,), int64."""
    q = np.clip((np.asarray(ratios) * bins).astype(np.int64), 0, bins - 1)
    return q @ _weights(bins)


@lru_cache(maxsize=4)
def _offset_grid(max_span: int) -> np.ndarray:
    grid = np.array(list(itertools.product(range(max_span), repeat=5)), dtype=np.int64)
    grid.setflags(write=False)
    return grid


def probe_keys(ratios, tolerance, bins: int, max_span: int = 3):
    """Every key a pattern with these ratios (+- tolerance) can have in the database.

    Parameters
    ----------
    ratios, tolerance : ndarray, shape (P, 5)
        Measured sorted edge ratios and their error bound.
    bins : int
        Quantisation of the database.
    max_span : int
        Most cells probed per ratio: a looser interval is narrowed to the ``max_span``
        cells centred on the measured ratio (the lookup then covers at least
        ``(max_span - 1) / 2`` cells either side).

    Returns
    -------
    keys : ndarray, shape (K,), int64
    owner : ndarray, shape (K,), int
        Index of the pattern (row of ``ratios``) each key belongs to.
    """
    lo = np.clip(((ratios - tolerance) * bins).astype(np.int64), 0, bins - 1)
    span = np.clip(((ratios + tolerance) * bins).astype(np.int64), 0, bins - 1) - lo + 1
    need = int(span.max())
    if need > max_span:
        wide = span > max_span
        centre = np.clip((ratios * bins).astype(np.int64) - (max_span - 1) // 2, 0,
                         bins - max_span)
        lo = np.where(wide, centre, lo)
        span = np.where(wide, max_span, span)
        need = max_span
    owner = np.arange(ratios.shape[0])
    w = _weights(bins)
    if need == 1:
        return lo @ w, owner
    grid = _offset_grid(need)                                   # (G, 5)
    ok = np.all(grid[None, :, :] < span[:, None, :], axis=2)    # (P, G)
    p_idx, g_idx = np.nonzero(ok)
    keys = (lo @ w)[p_idx] + grid[g_idx] @ w
    return keys, owner[p_idx]
