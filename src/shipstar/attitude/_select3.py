"""Seed 004 sec. 2.3 / 3.3: choose the three stars with the smallest error bound."""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from shipstar.attitude._boresight3 import three_star_error_bound
from shipstar.errors import ShipstarError


@dataclass(frozen=True)
class BestThree:
    """Result of :func:`best_three_stars`.

    Attributes
    ----------
    solved : bool
        False when no triple is usable (all collinear or non-finite).
    reason : str
    indices : ndarray of int, shape (3,)
        Rows of the input forming the chosen triple (-1 when not solved).
    error_bound_rad_per_mm : float
        Its bound ``||M||_F`` (see :func:`three_star_error_bound`).
    triples : ndarray of int, shape (T, 3)
        Every triple examined.
    bounds_rad_per_mm : ndarray, shape (T,)
        Their bounds (``inf`` for collinear triples).
    """

    solved: bool
    reason: str
    indices: np.ndarray
    error_bound_rad_per_mm: float
    triples: np.ndarray
    bounds_rad_per_mm: np.ndarray


def all_triples(n):
    """Every combination of 3 of ``n`` indices, shape (C(n, 3), 3), lexicographic."""
    return np.array(list(combinations(range(n), 3)), dtype=int).reshape(-1, 3)


def best_three_stars(xy_mm, f_mm, u_icrs, *, max_stars=None):
    """The triple of identified stars with the smallest seed-004 error bound.

    Seed 004 sec. 2.3.1 / 3.3.1: the boresight error of a 3-star solution is at most
    ``||M|| ||dXY||``; traversing all triples and keeping the smallest ``||M||`` gives
    the combination whose error is "certainly controlled" (not necessarily the best).

    Parameters
    ----------
    xy_mm : array_like, shape (N, 2)
        Image-plane positions from the principal point, X right, Y up (mm).
    f_mm : float
        Focal length (mm).
    u_icrs : array_like, shape (N, 3)
        Catalog directions of the same stars.
    max_stars : int, optional
        Only consider the first ``max_stars`` rows (e.g. the brightest), to bound the
        ``C(N, 3)`` work.

    Returns
    -------
    BestThree
    """
    xy = np.asarray(xy_mm, dtype=float)
    u = np.asarray(u_icrs, dtype=float)
    if xy.ndim != 2 or xy.shape[1] != 2 or u.shape != (len(xy), 3):
        raise ShipstarError(f"xy_mm must be (N, 2) and u_icrs (N, 3); got {xy.shape}, {u.shape}")
    n = len(xy) if max_stars is None else min(len(xy), int(max_stars))
    triples = all_triples(n)
    if len(triples) == 0:
        return BestThree(False, f"{n} stars; at least 3 needed", np.full(3, -1), np.nan,
                         triples, np.zeros(0))
    bounds = np.asarray(three_star_error_bound(xy[triples], f_mm, u[triples]), dtype=float)
    usable = np.isfinite(bounds)
    if not np.any(usable):
        return BestThree(False, "no usable triple: every triple is collinear or non-finite",
                         np.full(3, -1), np.nan, triples, bounds)
    k = int(np.argmin(np.where(usable, bounds, np.inf)))
    return BestThree(True, "", triples[k], float(bounds[k]), triples, bounds)
