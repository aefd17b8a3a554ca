"""Tracking: identification by prediction from a prior attitude (the last frame's).

1. **Prediction.** The stars of the prior boresight's sky-grid cell (cached per database
   and cell: a tracked sensor stays in one cell for many frames) are projected with the
   prior attitude; those within ``g_prior = prior_error + 2 delta`` of the image
   rectangle are kept.
2. **Common shift.** A small rotation moves every star by nearly the same tangent-plane
   shift.  Each of the 20 brightest measured stars takes its nearest prediction within
   ``g_prior``; the component-wise median of these pairs' offsets is the shift (robust
   to false stars and to neighbours paired in the wide gate while most pairs are right).
3. **Shifted pairs.** Every star is re-paired with the shifted predictions within the
   much smaller ``g_shift`` (:func:`shift_gate`: what a rotation by ``prior_error`` moves
   a star beyond the common shift, plus the centroid errors).
4. **Fit and fine gate.** QUEST on those pairs; every pair must lie within the fine gate
   ``g = 1.5 delta`` of the fit.  A few that do not (at most 20 %: a blended or streaked
   centroid, a false star) are dropped and the attitude refitted; more mean a biased
   fit: every star is re-paired within shrinking gates and the attitude refitted until
   the pairs settle.  Two stars within the fine gate of one catalog star are
   ambiguous: neither is matched.
5. **Vote.** When the prior error is comparable to the distance between stars, nearest
   neighbours are mostly wrong and so is their median: if steps 3-4 fail, the shift is
   taken where the offsets of all (star, prediction) pairs within ``g_prior`` cluster
   most densely, and steps 3-4 are repeated once (``p_false`` doubled for the second try).

Chance model: after the fit (two stars' worth of freedom used) each other star lands
within ``g`` of one of the ``M`` predicted stars with ``p1 = M pi g^2 / area``; the prior
allows about ``(g_prior / g)^3`` distinguishable attitudes, so
``p_false = (g_prior / g)^3 P(Binomial(n - 2, p1) >= k - 2)``, evaluated for ``g`` the
fine gate and 1/2, 1/4, 1/8 of it (the smallest, times 4).

Speed: a frame is ~100 NumPy calls on arrays of tens of elements plus one to three
QUEST solves (:func:`shipstar.attitude.quest_single` through :func:`._verify.wahba`,
solved relative to the prior, ~12 us each): median ~0.20 ms on the shared 2-core
development machine, 1.09x tetra3rs given the same prior in the same run
(benchmarks/bench_identify.py --tracking-only; docs/identification.md).
"""

from __future__ import annotations

import math
import time

import numpy as np

from shipstar.identify._result import Identification, failed_identification
from shipstar.identify._verify import (FINE_GATE, GATE_FRACTIONS, cell_stars, chance_probability,
                                      gate_counts, min_chance, rms_of, wahba)

__all__ = ["tracking", "shift_gate"]

#: attitude fits before the pairs must have settled
_MAX_FITS = 6
#: pairs beyond the fine gate of a fit are dropped and the fit repeated (at most
#: ``_MAX_TRIMS`` times) when they are at most this fraction of the pairs; more mean a
#: biased fit, and every star is re-paired within shrinking gates instead
_TRIM_FRACTION = 0.2
_MAX_TRIMS = 2
#: the brightest stars paired in the prior's wide gate to find the common shift (the
#: fewer, the fewer chance neighbours; the median needs only a majority of true pairs)
_WIDE_STARS = 20
_SQRT2 = math.sqrt(2.0)


def shift_gate(prior_error_rad: float, half_diagonal_tan: float, error_rad: float) -> float:
    """Pairing radius after the common shift has been removed (tangent-plane units).

    A rotation by ``theta <= prior_error_rad`` moves a star at ``|t| <= h`` (``h`` the
    half-diagonal) by the boresight's shift plus at most
    ``e = theta h + 2 T h (h + T) / (1 - h T)`` (``T = tan theta``; the roll part and the
    tangent-plane non-uniformity of the two tilts).  The median of the offsets lies,
    per axis, between the smallest and largest true offset, so a true pair is within
    ``2 (e + delta)`` per axis of it: ``g_shift = 2 sqrt(2) (e + delta)``.
    """
    theta = float(prior_error_rad)
    h = float(half_diagonal_tan)
    big_t = math.tan(min(theta, 0.5))
    e = theta * h + 2.0 * big_t * h * (h + big_t) / max(1.0 - h * big_t, 0.1)
    return 2.0 * _SQRT2 * (e + float(error_rad))


# ------------------------------------------------------------------------------------
# Small vectorised pieces
# ------------------------------------------------------------------------------------

def _project(u, C):
    """Tangent-plane columns ``(ty, tz)`` of unit vectors ``u (M, 3)`` seen with ``C``."""
    w = u @ C
    t = w[:, 1:] / w[:, :1]
    return t[:, 0], t[:, 1]


def _residuals2(t, v, C):
    """Squared tangent-plane distances ``(k,)`` between measured stars ``t (k, 2)`` and
    their catalog stars ``v (k, 3)`` projected with ``C``."""
    w = v @ C
    d = t - w[:, 1:] / w[:, :1]
    d *= d
    return d[:, 0] + d[:, 1]


def _pair(my, mz, py, pz, gate: float):
    """Nearest prediction of each measured star within ``gate``, one to one.

    ``my, mz`` (N,) measured and ``py, pz`` (M,) predicted tangent-plane coordinates.
    Returns ``(img, j, d2, lost)``: measured rows that paired, their prediction rows,
    the squared distances, and ``(row, j)`` of the stars that lost a prediction to a
    closer star (two stars wanting one prediction: the closer one keeps it).
    """
    if py.size == 0:
        return np.empty(0, np.intp), np.empty(0, np.intp), np.empty(0), []
    dy = my[:, None] - py
    dz = mz[:, None] - pz
    dy *= dy
    dz *= dz
    dy += dz
    j = dy.argmin(axis=1)
    d2 = dy[np.arange(j.size), j]
    img = (d2 <= gate * gate).nonzero()[0]
    j = j[img]
    d2 = d2[img]
    lost = []
    if img.size > 1:
        jl = j.tolist()
        if len(set(jl)) < len(jl):
            dl = d2.tolist()
            best: dict = {}
            for k, jk in enumerate(jl):
                b = best.get(jk)
                if b is None or dl[k] < dl[b]:
                    best[jk] = k
            keep = sorted(best.values())
            lost = [(int(img[k]), jk) for k, jk in enumerate(jl) if best[jk] != k]
            img, j, d2 = img[keep], j[keep], d2[keep]
    return img, j, d2, lost


def _nearest(my, mz, py, pz, gate: float):
    """``(img, j)``: the measured stars with a prediction within ``gate`` and their
    nearest one (not one to one: for the common shift, where a few doubles do not
    matter)."""
    dy = my[:, None] - py
    dz = mz[:, None] - pz
    dy *= dy
    dz *= dz
    dy += dz
    j = dy.argmin(axis=1)
    img = (dy[np.arange(j.size), j] <= gate * gate).nonzero()[0]
    return img, j[img]


def _median(values: list) -> float:
    v = sorted(values)
    k = len(v) // 2
    return v[k] if len(v) % 2 else 0.5 * (v[k - 1] + v[k])


def _without(img, j, d2, bad: set):
    """The pairs whose prediction is not in ``bad``."""
    keep = [k for k, jk in enumerate(j.tolist()) if jk not in bad]
    return img[keep], j[keep], d2[keep]


def _vote_shift(my, mz, py, pz, gate_prior: float, radius: float):
    """The offset ``(dy, dz)`` shared by most (star, prediction) pairs within
    ``gate_prior``: the median of the offsets within ``radius`` of the offset with the
    most such neighbours; None when no pair is within the gate."""
    dy = my[:, None] - py
    dz = mz[:, None] - pz
    near = dy * dy + dz * dz <= gate_prior * gate_prior
    cy, cz = dy[near], dz[near]
    if cy.size == 0:
        return None
    ddy = cy[:, None] - cy
    ddz = cz[:, None] - cz
    close = ddy * ddy + ddz * ddz <= radius * radius
    best = int(np.argmax(np.count_nonzero(close, axis=1)))
    sel = close[best]
    return _median(cy[sel].tolist()), _median(cz[sel].tolist())


def _tail_bound(n: int, k: int, p: float) -> float:
    """``C(n, k) p^k >= P(Binomial(n, p) >= k)`` (a union over the k-subsets), in plain
    floats: enough when it is far below the acceptance bound."""
    if k <= 0:
        return 1.0
    if k > n or p <= 0.0:
        return 0.0
    log_c = math.lgamma(n + 1) - math.lgamma(k + 1) - math.lgamma(n - k + 1)
    return math.exp(min(0.0, log_c + k * math.log(min(p, 1.0))))


def _p_false(d2, gate, gate_prior, n_trials, n_in, area, p_false_max) -> float:
    """Chance probability of ``d2.size`` fine pairs among ``n_trials + 2`` stars (module
    docstring).  When an upper bound from the fine gate alone is far below the limit,
    that bound is the answer (the minimum over the gates can only be smaller, and only
    its size matters then): first the union bound, then the exact binomial tail."""
    n_gates = GATE_FRACTIONS.size
    stop = 1e-3 * p_false_max / n_gates
    look = max(1.0, (gate_prior / gate) ** 3)
    p1 = n_in * math.pi * gate * gate / area
    first = look * _tail_bound(n_trials, d2.size - 2, p1)
    if first > stop:
        first = look * chance_probability(n_trials, d2.size - 2, p1)
    if first <= stop:
        return min(1.0, n_gates * first)
    g = gate * GATE_FRACTIONS
    p1s = n_in * np.pi * g * g / area
    looks = np.maximum(1.0, (gate_prior / g) ** 3)
    return min(1.0, n_gates * min_chance(looks, np.full(n_gates, n_trials), gate_counts(d2, gate) - 2,
                                         p1s, stop_below=stop))


# ------------------------------------------------------------------------------------
# One frame
# ------------------------------------------------------------------------------------

class _Scene:
    """The measured stars and the predicted catalog stars of one frame."""

    def __init__(self, t_use, w_use, rows, u, py, pz, gate, gate_prior, gate_shift, min_matches):
        self.t, self.w_use = t_use, w_use
        self.my, self.mz = t_use[:, 0], t_use[:, 1]
        self.rows, self.u, self.py, self.pz = rows, u, py, pz
        self.gate, self.gate_prior, self.gate_shift = gate, gate_prior, gate_shift
        self.min_matches = min_matches

    def median_shift(self):
        """``(dy, dz)`` from the brightest stars' nearest predictions, or a reason."""
        my, mz = self.my[:_WIDE_STARS], self.mz[:_WIDE_STARS]
        if self.py.size == 0:
            return "no catalog star is predicted in the image"
        img, j = _nearest(my, mz, self.py, self.pz, self.gate_prior)
        if img.size < self.min_matches:
            return (f"only {img.size} stars within {self.gate_prior * 206264.8:.0f} arcsec of a "
                    "predicted catalog star")
        return _median((my[img] - self.py[j]).tolist()), _median((mz[img] - self.pz[j]).tolist())

    def vote_shift(self):
        """``(dy, dz)`` where the brightest stars' offsets cluster (None: no pair)."""
        return _vote_shift(self.my[:_WIDE_STARS], self.mz[:_WIDE_STARS], self.py, self.pz,
                           self.gate_prior, 0.5 * self.gate_shift)

    def match(self, C_prior, shift, box):
        """``(C, img, j, d2, n_in)`` for a common shift, or the reason it fails.

        ``n_in`` counts the catalog stars predicted inside the image rectangle ``box``
        (``cy, cz, hy, hz``), at their shifted prior places (within ``g_shift`` of the
        fitted ones: a star more or less at the edge of a ~35-star field changes the
        chance probability by a few per cent).
        """
        py, pz = self.py + shift[0], self.pz + shift[1]
        img, j, _, lost = _pair(self.my, self.mz, py, pz, self.gate_shift)
        if img.size < self.min_matches:
            return f"only {img.size} stars agree with the common shift of the predicted stars"
        C, img, j, d2 = self.settle(img, j, lost, C_prior)
        if img.size < self.min_matches:
            return f"only {img.size} stars matched after the attitude update"
        cy, cz, hy, hz = box
        n_in = int(np.count_nonzero((np.abs(py - cy) <= hy) & (np.abs(pz - cz) <= hz)))
        return C, img, j, d2, n_in

    def settle(self, img, j, lost, C_near):
        """Fit the attitude to the pairs and keep the pairs that fit within the fine gate.

        Common case: one QUEST on the shifted pairs, every pair within the fine gate of
        the fit; when a few are not (at most ``_TRIM_FRACTION``: a blended or streaked
        centroid, a false star), they are dropped and the attitude refitted.  Otherwise
        (a biased fit) every star is re-paired with the fit's predictions within a
        quarter of the previous gate (never below the fine gate) and the attitude
        refitted, until the pairs within the fine gate settle (at most ``_MAX_FITS``
        fits; a borderline star may flip: the last pairs, matched with the current fit,
        are kept).  Two stars within the fine gate of one catalog star: neither is
        matched.  ``img`` may end up shorter than ``min_matches``.
        """
        my, mz, u, gate = self.my, self.mz, self.u, self.gate
        g2 = gate * gate
        v = u[j]
        C = wahba(self.w_use[img], v, C_near)
        d2 = _residuals2(self.t[img], v, C)
        g = self.gate_shift
        if d2.max() > g2:
            img, j, C, d2 = self._trim(img, j, C, d2)
            if img.size < self.min_matches:
                return C, img, j, d2
        if d2.max() <= g2:
            bad = self._ambiguous(lost, j, C) if lost else set()
            if not bad:
                return C, img, j, d2
            img, j, d2 = _without(img, j, d2, bad)
            if img.size < self.min_matches:
                return C, img, j, d2
            C = wahba(self.w_use[img], u[j], C)
            g = gate
        for _ in range(_MAX_FITS):
            g = max(gate, 0.25 * g)
            py, pz = _project(u, C)
            img2, j2, d2, lost = _pair(my, mz, py, pz, g)
            if g == gate and lost:
                img2, j2, d2 = _without(img2, j2, d2, {jp for _, jp in lost})
            settled = g == gate and img2.tolist() == img.tolist() and j2.tolist() == j.tolist()
            img, j = img2, j2
            if settled or img.size < self.min_matches:
                break
            C = wahba(self.w_use[img], u[j], C)
        return C, img, j, d2

    def _trim(self, img, j, C, d2):
        """Drop the pairs beyond the fine gate and refit while they are few (at most
        ``_TRIM_FRACTION`` of the pairs: a blended or streaked centroid, a false star;
        the fit was sound); ``(img, j, C, d2)``."""
        g2 = self.gate * self.gate
        for _ in range(_MAX_TRIMS):
            keep = (d2 <= g2).nonzero()[0]
            if keep.size == img.size or img.size - keep.size > _TRIM_FRACTION * img.size:
                break
            img, j = img[keep], j[keep]
            if img.size < self.min_matches:
                return img, j, C, d2[keep]
            v = self.u[j]
            C = wahba(self.w_use[img], v, C)
            d2 = _residuals2(self.t[img], v, C)
        return img, j, C, d2

    def _ambiguous(self, lost, j, C) -> set:
        """Predictions that a star which lost them in a conflict is also within the fine
        gate of under ``C``."""
        taken = set(j.tolist())
        cand = [(r, jp) for r, jp in lost if jp in taken]
        if not cand:
            return set()
        r = np.array([c[0] for c in cand], dtype=np.intp)
        jp = np.array([c[1] for c in cand], dtype=np.intp)
        d2 = _residuals2(self.t[r], self.u[jp], C)
        return {jk for jk, d in zip(jp.tolist(), d2.tolist()) if d <= self.gate * self.gate}


def _predicted(db, C_prior, box, margin: float):
    """``(rows, u, ty, tz)`` of the catalog stars projected within ``margin`` of the image
    rectangle ``box = (cy, cz, hy, hz)`` (centre, half sizes) by ``C_prior``."""
    rows, u = cell_stars(db, C_prior[:, 0])
    ty, tz = _project(u, C_prior)
    cy, cz, hy, hz = box
    sel = ((np.abs(ty - cy) <= hy + margin) & (np.abs(tz - cz) <= hz + margin)).nonzero()[0]
    return rows[sel], u[sel], ty[sel], tz[sel]


def _fail(n, reason, t0):
    return failed_identification(n, "tracking", reason, n_candidates=1,
                                 time_s=time.perf_counter() - t0)


def _match_with_fallback(scene, C_prior, box, p_value):
    """Steps 2-5: ``(C, img, j, d2, p_false)`` or a reason; ``p_value(d2, n_in)`` is the
    chance probability of a match, ``p_value.limit`` the largest accepted."""
    shift = scene.median_shift()
    out = scene.match(C_prior, shift, box) if not isinstance(shift, str) else shift
    if not isinstance(out, str):
        p = p_value(out[3], out[4])
        if p <= p_value.limit:
            return (*out[:4], p)
        out = f"{out[1].size} matches could be chance (p_false {p:.1e} > {p_value.limit:g})"
    vote = scene.vote_shift()
    if vote is None or (not isinstance(shift, str) and math.hypot(vote[0] - shift[0], vote[1] - shift[1])
                        <= 0.5 * scene.gate_shift):
        return out
    out2 = scene.match(C_prior, vote, box)
    if isinstance(out2, str):
        return out
    p = 2.0 * p_value(out2[3], out2[4])          # two shifts tried
    if p > p_value.limit:
        return f"{out2[1].size} matches could be chance (p_false {p:.1e} > {p_value.limit:g})"
    return (*out2[:4], p)


class _PValue:
    """``p_false`` of ``d2.size`` fine pairs with ``n_in`` catalog stars in the image."""

    def __init__(self, scene, n_use, area, limit):
        self.scene, self.n_use, self.area, self.limit = scene, n_use, area, limit

    def __call__(self, d2, n_in) -> float:
        sc = self.scene
        return _p_false(d2, sc.gate, sc.gate_prior, self.n_use - 2, n_in, self.area, self.limit)


def tracking(field, db, C_prior, *, prior_error_rad: float, focal_scale: float = 1.0,
             p_false_max: float = 1e-6, min_matches: int = 3,
             max_verify_stars: int = 60) -> Identification:
    """Identify the stars of ``field`` near the prior attitude ``C_prior`` (3, 3).

    Parameters
    ----------
    field : StarField
    db : StarDatabase
    C_prior : ndarray (3, 3)
        Prior ``C_icrs_from_sensor`` (a rotation; checked by the caller).
    prior_error_rad : float
        Bound on the prior's error.
    focal_scale : float
        ``f_nominal / f_true`` of a previous solution (1 for a calibrated camera).
    p_false_max : float
        Largest accepted chance probability.
    min_matches : int
        Fewest matched stars accepted.
    max_verify_stars : int
        Brightest stars used.

    Returns
    -------
    Identification
        ``mode="tracking"``; ``solved=False`` with a reason when the stars do not fit.
    """
    t0 = time.perf_counter()
    n = field.n
    s = float(focal_scale)
    if field.bad_rows.size:
        usable = np.setdiff1d(np.arange(n), field.bad_rows, assume_unique=True)[:max_verify_stars]
        t_use, w_use = field.t[usable], field.unit(s, rows=usable)
    else:
        usable = None
        m = min(n, max_verify_stars)
        t_use, w_use = field.t[:m], field.unit(s)[:m]
    n_use = t_use.shape[0]
    if n_use < min_matches:
        return _fail(n, f"only {n_use} usable stars: tracking needs at least {min_matches}", t0)
    if s != 1.0:
        t_use = t_use * s
    y0, y1, z0, z1 = field.bounds.tolist()
    box = (0.5 * s * (y0 + y1), 0.5 * s * (z0 + z1), 0.5 * s * (y1 - y0), 0.5 * s * (z1 - z0))
    err = field.error_rad
    gate_prior = float(prior_error_rad) + 2.0 * err
    gate_shift = min(gate_prior, shift_gate(prior_error_rad, field.half_diagonal_tan * s, err))
    rows, u, py, pz = _predicted(db, C_prior, box, gate_prior)
    scene = _Scene(t_use, w_use, rows, u, py, pz, FINE_GATE * err, gate_prior, gate_shift,
                   min_matches)
    out = _match_with_fallback(scene, C_prior, box, _PValue(scene, n_use, field.area_tan2 * s * s,
                                                            p_false_max))
    if isinstance(out, str):
        return _fail(n, out, t0)
    C, img, j, _, p_false = out
    matched = img if usable is None else usable[img]
    cat = rows[j]
    star_index = np.full(n, -1, dtype=np.int64)
    star_index[matched] = cat
    hip = np.full(n, -1, dtype=np.int64)
    hip[matched] = db.hip[cat]
    return Identification(
        solved=True, reason="", mode="tracking", C_icrs_from_sensor=C, star_index=star_index,
        hip=hip, u_sensor=field.unit(s), n_matched=int(matched.size), p_false=float(p_false),
        rms_arcsec=rms_of(w_use[img], u[j], C), focal_scale=s, radial_k1=0.0,
        n_patterns=0, n_candidates=1, time_s=time.perf_counter() - t0,
    )
