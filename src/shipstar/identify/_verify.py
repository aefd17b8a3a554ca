"""Verification of an attitude hypothesis: predict where catalog stars must fall, count
the measured stars that are there, and bound the probability that this is chance.

Chance model (as tetra3's "mismatch probability", made explicit): under a wrong
attitude, each measured star that was not used to make the hypothesis lands within
the gate of one of the ``M`` catalog stars predicted in the image with probability
``p1 = M * pi * gate^2 / area`` (tangent-plane area of the image).  The number of such
chance matches among ``n`` stars is binomial; ``P(X >= k)`` is the chance probability
of the observed ``k`` matches.
"""

from __future__ import annotations

import weakref

import numpy as np

from shipstar.identify import _skygrid
from shipstar.units import RAD2ASEC as _RAD2ASEC

#: fine match radius in units of the per-axis centroid error bound delta (a measured
#: star is within sqrt(2) delta of its true place; the rest is attitude-fit error)
FINE_GATE = 1.5

__all__ = ["FINE_GATE", "GATE_FRACTIONS", "image_box", "gate_counts", "chance_tail", "min_chance",
           "Prediction", "predict", "reproject", "associate", "match_stars", "refine",
           "chance_probability", "rms_arcsec", "rms_of", "unit_f64", "cell_stars", "wahba"]


# ------------------------------------------------------------------------------------
# Per-database caches (weak: they go with the database)
# ------------------------------------------------------------------------------------

_U64: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_CELLS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
#: sky-grid cells whose stars are kept per database (a tracked sensor stays in one cell
#: for many frames; lost-in-space visits random cells and only needs the last few)
_MAX_CELLS = 16
#: ``[database, u64, cells]`` of the database used last (a weak reference would cost
#: more than it saves; the entry is replaced when another database comes)
_LAST: list = [None, None, None]


def _caches(db):
    """``(u64, cells)`` of a database: its float64 unit vectors and its cell cache (the
    last database used is kept at hand: a session uses one or two)."""
    last = _LAST
    if last[0] is db:
        return last[1], last[2]
    u = _U64.get(db)
    if u is None:
        u = db.u_icrs.astype(np.float64)
        u /= np.sqrt(np.einsum("ij,ij->i", u, u))[:, None]
        u.setflags(write=False)
        _U64[db] = u
    cells = _CELLS.get(db)
    if cells is None:
        cells = _CELLS[db] = {}
    _LAST[:] = [db, u, cells]
    return u, cells


def unit_f64(db) -> np.ndarray:
    """The database's star vectors ``(S, 3)`` as float64 unit vectors (made once per
    database: the stored float32 rows are normalised to float32 precision only)."""
    return _caches(db)[0]


def cell_stars(db, direction):
    """``(rows (M,), u (M, 3) float64)``: the stars of the sky-grid cell holding the unit
    vector ``direction`` (all stars within ``db.query_radius_rad`` of it, brightest first),
    the same rows as ``db.near(direction)``; cached per database and cell (read only)."""
    u64, cells = _caches(db)
    c = _skygrid.cell_of_one(direction, db.grid_n)
    hit = cells.get(c)
    if hit is None:
        rows = db.cell_index[db.cell_start[c]:db.cell_start[c + 1]].astype(np.intp)
        hit = (rows, u64[rows])
        if len(cells) >= _MAX_CELLS:
            del cells[next(iter(cells))]
        cells[c] = hit
    return hit


def wahba(w_body, v_ref, C_near=None) -> np.ndarray:
    """``C_ref_from_body`` (3, 3) for matched *unit* vectors ``(k, 3)``, equal weights.

    :func:`shipstar.attitude.quest_single` (QUEST-Newton without :func:`~shipstar.
    attitude.quest`'s input preparation: the identification's vectors are unit vectors
    already, and this runs several times per frame).  With ``C_near`` (3, 3), a rotation
    close to the answer (a tracking prior, or the previous fit: rotations by
    construction), the problem is solved for the small rotation ``C_near^T C``: QUEST
    then never needs its sequential rotations (which it takes when the attitude is more
    than ~145 deg from the identity) and is ~2x faster.
    """
    from shipstar.attitude import quest_single      # not at import: `shipstar solve` runs the C kernels

    if C_near is None:
        return quest_single(w_body, v_ref)
    return C_near @ quest_single(w_body, v_ref @ C_near)


class Prediction:
    """Catalog stars predicted near the image for one attitude (tangent-plane coords)."""

    __slots__ = ("rows", "u", "t", "n_in")

    def __init__(self, rows, u, t, n_in):
        self.rows, self.u, self.t, self.n_in = rows, u, t, n_in


def image_box(bounds):
    """``(centre (2,), half_size (2,))`` of the rectangle ``y_min, y_max, z_min, z_max``."""
    y0, y1, z0, z1 = bounds
    return np.array([0.5 * (y0 + y1), 0.5 * (z0 + z1)]), np.array([0.5 * (y1 - y0), 0.5 * (z1 - z0)])


def predict(db, C_icrs_from_sensor, box, margin_tan: float) -> Prediction:
    """Catalog stars that fall within ``margin_tan`` of the image rectangle.

    ``box = (centre, half_size)`` is the image rectangle in the tangent plane at the
    hypothesis' focal scale (:func:`image_box`); ``n_in`` counts the stars inside it.
    """
    rows, u = cell_stars(db, C_icrs_from_sensor[:, 0])
    w = u @ C_icrs_from_sensor                     # in front: the query radius is < 81 deg
    t = w[:, 1:] / w[:, :1]
    centre, half = box
    off = np.abs(t - centre)
    sel = np.flatnonzero(np.all(off <= half + margin_tan, axis=1))
    n_in = int(np.count_nonzero(np.all(off[sel] <= half, axis=1)))
    return Prediction(rows[sel], u[sel], t[sel], n_in)


def reproject(pred: Prediction, C_icrs_from_sensor, box) -> Prediction:
    """The same catalog stars projected with an updated attitude."""
    w = pred.u @ C_icrs_from_sensor
    t = w[:, 1:] / w[:, :1]
    centre, half = box
    n_in = int(np.count_nonzero(np.all(np.abs(t - centre) <= half, axis=1)))
    return Prediction(pred.rows, pred.u, t, n_in)


def associate(t_true, pred: Prediction, gate_tan: float):
    """Nearest predicted star of each measured star within ``gate_tan``, one to one.

    Returns ``(img, cat, d2)``: rows of ``t_true`` that matched (NaN rows never do), the
    database rows they matched and the squared tangent-plane distances.
    """
    if pred.t.shape[0] == 0 or t_true.shape[0] == 0:
        return np.empty(0, np.intp), np.empty(0, np.intp), np.empty(0)
    dy = t_true[:, :1] - pred.t[:, 0]
    dz = t_true[:, 1:] - pred.t[:, 1]
    d2 = dy * dy + dz * dz
    j = np.argmin(d2, axis=1)
    dmin = d2[np.arange(d2.shape[0]), j]
    img = np.flatnonzero(dmin <= gate_tan * gate_tan)
    jj = j[img]
    if img.size > 1 and len(set(jj.tolist())) < jj.size:
        order = np.argsort(dmin[img], kind="stable")
        _, first = np.unique(jj[order], return_index=True)
        keep = np.sort(order[first])
        img, jj = img[keep], jj[keep]
    return img, pred.rows[jj].astype(np.intp), dmin[img]


def match_stars(t_true, db, C_icrs_from_sensor, bounds_true, gate_tan: float):
    """Match measured stars to the catalog stars predicted by an attitude, one to one.

    Parameters
    ----------
    t_true : ndarray (N, 2)
        Tangent-plane coordinates of the measured stars (at the hypothesis' focal
        scale); rows with NaN never match.
    db : StarDatabase
    C_icrs_from_sensor : ndarray (3, 3)
        Attitude hypothesis.
    bounds_true : ndarray (4,)
        Image rectangle ``y_min, y_max, z_min, z_max`` in the same tangent plane.
    gate_tan : float
        Match radius (tangent-plane units ~ rad).

    Returns
    -------
    img : ndarray (k,), int
        Rows of ``t_true`` that matched.
    cat : ndarray (k,), int
        Database star rows they matched.
    n_in : int
        Number of catalog stars predicted inside the image rectangle.
    """
    pred = predict(db, C_icrs_from_sensor, image_box(bounds_true), gate_tan)
    img, cat, _ = associate(t_true, pred, gate_tan)
    return img, cat, pred.n_in


def refine(field, db, img, cat, scale: float, fit_scale: bool, k1: float = 0.0,
           fit_k1: bool = False):
    """Attitude (QUEST) and, if asked, focal scale and radial term from matched stars.

    Returns ``(C_icrs_from_sensor, scale, k1)``.  The catalog stars are projected with
    the current attitude and ``t_cat ~ s t (1 + k1 |t|^2)`` is solved by least squares
    (``k1`` only with ``fit_k1`` and at least 6 stars, and kept only if it bends the
    image corner by less than 5 %); two rounds converge far below the centroid noise.
    """
    v = unit_f64(db)[cat]
    C = wahba(field.unit(scale, rows=img, k1=k1), v)
    if not fit_scale or img.size < 3:
        return C, scale, k1
    t = field.t[img]
    r2 = np.einsum("ij,ij->i", t, t)
    h2 = field.half_diagonal_tan ** 2
    for _ in range(2):
        w = v @ C
        tc = (w[:, 1:] / w[:, :1]).ravel()
        if fit_k1 and img.size >= 6:
            a = np.stack([t.ravel(), (t * r2[:, None]).ravel()], axis=1)
            (s_new, b), *_ = np.linalg.lstsq(a, tc, rcond=None)
            k_new = b / s_new
            if abs(k_new) * h2 < 0.05:
                scale, k1 = float(s_new), float(k_new)
            else:
                g = t.ravel() * np.repeat(1.0 + k1 * r2, 2)
                scale = float(tc @ g / (g @ g))
        else:
            g = t.ravel() * np.repeat(1.0 + k1 * r2, 2)
            scale = float(tc @ g / (g @ g))
        C = wahba(field.unit(scale, rows=img, k1=k1), v)
    return C, scale, k1


#: the chance probability is evaluated within the fine gate and within these fractions
#: of it (a Bonferroni factor ``len(GATE_FRACTIONS)`` pays for the choice): true stars,
#: matched far inside the gate, then count for more than the gate alone would let them
GATE_FRACTIONS = np.array([1.0, 0.5, 0.25, 0.125])


def gate_counts(d2, gate: float) -> np.ndarray:
    """Number of the squared distances ``d2`` within each ``gate * GATE_FRACTIONS``."""
    g2 = (gate * GATE_FRACTIONS) ** 2
    return np.count_nonzero(np.asarray(d2)[:, None] <= g2[None, :], axis=0)


def chance_tail(n_trials, k_matches, p1) -> np.ndarray:
    """Vectorised ``P(X >= k)`` for ``X ~ Binomial(n, p1)`` (1 where ``k <= 0``, 0 where
    ``k > n``); arguments broadcast."""
    from scipy.special import bdtrc

    n = np.asarray(n_trials, dtype=np.int64)
    k = np.asarray(k_matches, dtype=np.int64)
    p = np.clip(np.asarray(p1, dtype=float), 0.0, 1.0)
    inner = bdtrc(np.clip(k - 1, 0, None), np.maximum(n, 0), p)
    return np.where(k <= 0, 1.0, np.where(k > n, 0.0, inner))


def min_chance(factors, n_trials, k_matches, p1, stop_below: float) -> float:
    """``min_j factors_j P(Bin(n_j, p1_j) >= k_j)`` over the gates (arrays, gate 0 = the
    fine gate), evaluated lazily: when the fine gate alone already gives a value below
    ``stop_below`` the others are not computed (the result is then an upper bound on the
    minimum, which is all a chance probability needs to be)."""
    first = float(factors[0]) * chance_probability(int(n_trials[0]), int(k_matches[0]),
                                                   float(p1[0]))
    if first <= stop_below:
        return first
    return float(np.min(np.asarray(factors) * chance_tail(n_trials, k_matches, p1)))


def chance_probability(n_trials: int, k_matches: int, p1: float) -> float:
    """``P(X >= k)`` for ``X ~ Binomial(n_trials, p1)``; 1 when ``k <= 0``."""
    if k_matches <= 0:
        return 1.0
    if k_matches > n_trials:
        return 0.0
    from scipy.special import bdtrc

    return float(bdtrc(k_matches - 1, n_trials, min(max(p1, 0.0), 1.0)))


def rms_of(w_sensor, v_ref, C) -> float:
    """RMS angle (arcsec) between ``C @ w`` and ``v`` for matched rows ``(k, 3)``.

    The chord stands for the angle: they differ by ``angle^3 / 24`` (1e-15 rad at 1').
    """
    d = w_sensor @ C.T - v_ref
    return float(np.sqrt(np.einsum("ij,ij->", d, d) / d.shape[0]) * _RAD2ASEC)


def rms_arcsec(field, db, img, cat, C, scale, k1=0.0) -> float:
    """RMS angle (arcsec) between fitted measured directions and their catalog stars."""
    return rms_of(field.unit(scale, rows=img, k1=k1), unit_f64(db)[cat], C)
