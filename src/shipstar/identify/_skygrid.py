"""Cube-face grid over the sky for O(1) "which catalog stars are near this direction".

The sphere is cut into the six faces of an equiangular cube, each face into ``n x n``
cells.  For every cell the grid stores (CSR layout) the indices of all stars within
``radius_rad`` of *any* point of the cell, ascending (= brightest first, since the
database's stars are sorted by magnitude).  A look-up is then one slice.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["cell_of", "cell_of_one", "cell_centres", "build_cell_lists", "grid_size_for_radius"]

_QUARTER_PI = np.pi / 4


def grid_size_for_radius(radius_rad: float) -> int:
    """Cells per face edge so that a cell is about 1.2 x the query radius wide."""
    n = int(np.ceil((np.pi / 2) / (1.2 * radius_rad)))
    return int(np.clip(n, 1, 256))


def _face_uv(v):
    """Face index (0..5) and equiangular coordinates in [-1, 1] of unit vectors (..., 3)."""
    v = np.asarray(v, float)
    a = np.abs(v)
    major = np.argmax(a, axis=-1)
    sign = np.take_along_axis(v, major[..., None], axis=-1)[..., 0] >= 0
    face = 2 * major + (~sign)
    # the two other axes, in a fixed order per major axis
    other1 = np.where(major == 0, 1, 0)
    other2 = np.where(major == 2, 1, 2)
    m = np.take_along_axis(a, major[..., None], axis=-1)[..., 0]
    s = np.take_along_axis(v, other1[..., None], axis=-1)[..., 0] / m
    t = np.take_along_axis(v, other2[..., None], axis=-1)[..., 0] / m
    return face, np.arctan(s) / _QUARTER_PI, np.arctan(t) / _QUARTER_PI


def cell_of_one(v, n: int) -> int:
    """Cell index of one unit vector (plain floats: this is on every solve's hot path)."""
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    ax, ay, az = abs(x), abs(y), abs(z)
    if ax >= ay and ax >= az:
        major, m, a, b, positive = 0, ax, y, z, x >= 0
    elif ay >= az:
        major, m, a, b, positive = 1, ay, x, z, y >= 0
    else:
        major, m, a, b, positive = 2, az, x, y, z >= 0
    face = 2 * major + (0 if positive else 1)
    i = min(max(int((math.atan(a / m) / _QUARTER_PI + 1.0) * 0.5 * n), 0), n - 1)
    j = min(max(int((math.atan(b / m) / _QUARTER_PI + 1.0) * 0.5 * n), 0), n - 1)
    return (face * n + i) * n + j


def cell_of(v, n: int):
    """Cell index of unit vectors ``v`` (..., 3) on an ``n x n``-per-face grid."""
    face, s, t = _face_uv(v)
    i = np.clip(((s + 1.0) * 0.5 * n).astype(np.int64), 0, n - 1)
    j = np.clip(((t + 1.0) * 0.5 * n).astype(np.int64), 0, n - 1)
    return (face * n + i) * n + j


def _unit_from_face(face, s, t):
    """Inverse of :func:`_face_uv` for arrays of face / equiangular coordinates."""
    face = np.asarray(face)
    major = face // 2
    sign = np.where(face % 2 == 0, 1.0, -1.0)
    ts = np.tan(np.asarray(s) * _QUARTER_PI)
    tt = np.tan(np.asarray(t) * _QUARTER_PI)
    v = np.zeros(np.broadcast(face, ts, tt).shape + (3,))
    other1 = np.where(major == 0, 1, 0)
    other2 = np.where(major == 2, 1, 2)
    np.put_along_axis(v, major[..., None], sign[..., None], axis=-1)
    np.put_along_axis(v, other1[..., None], ts[..., None], axis=-1)
    np.put_along_axis(v, other2[..., None], tt[..., None], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def cell_centres(n: int):
    """Centre directions (6 n^2, 3) and angular circumradius (6 n^2,) of every cell."""
    face, i, j = np.meshgrid(np.arange(6), np.arange(n), np.arange(n), indexing="ij")
    face, i, j = face.ravel(), i.ravel(), j.ravel()
    s0, t0 = 2.0 * i / n - 1.0, 2.0 * j / n - 1.0
    h = 2.0 / n
    centre = _unit_from_face(face, s0 + 0.5 * h, t0 + 0.5 * h)
    radius = np.zeros(face.shape)
    for ds, dt in ((0, 0), (h, 0), (0, h), (h, h)):
        corner = _unit_from_face(face, s0 + ds, t0 + dt)
        cosang = np.clip(np.sum(corner * centre, axis=-1), -1.0, 1.0)
        radius = np.maximum(radius, np.arccos(cosang))
    return centre, radius


def build_cell_lists(u_stars, radius_rad: float, n: int):
    """CSR lists of the stars within ``radius_rad`` of each cell.

    Parameters
    ----------
    u_stars : ndarray, shape (S, 3)
        Star unit vectors, brightest first.
    radius_rad : float
        Query radius the lists must serve (from any direction inside the cell).
    n : int
        Cells per face edge.

    Returns
    -------
    start : ndarray, shape (6 n^2 + 1,), int32
    index : ndarray, shape (M,), uint16 or uint32
        Stars of cell ``c`` are ``index[start[c]:start[c + 1]]``, ascending.
    """
    from scipy.spatial import cKDTree

    centre, cell_radius = cell_centres(n)
    tree = cKDTree(u_stars)
    reach = np.minimum(radius_rad + cell_radius + 1e-9, np.pi)
    chord = 2.0 * np.sin(0.5 * reach)
    lists = tree.query_ball_point(centre, chord, return_sorted=True)
    counts = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
    start = np.zeros(len(lists) + 1, dtype=np.int64)
    np.cumsum(counts, out=start[1:])
    dtype = np.uint16 if len(u_stars) <= np.iinfo(np.uint16).max else np.uint32
    index = np.fromiter((k for x in lists for k in x), dtype=dtype, count=int(start[-1]))
    if start[-1] > np.iinfo(np.int32).max:  # pragma: no cover - absurd sizes
        raise OverflowError("sky grid too large")
    return start.astype(np.int32), index
