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
   ambiguous: neither is matched.  With 8 pairs or more, a pair whose squared residual
   exceeds 20 times the pairs' upper-quartile one is not matched and the attitude is
   refitted (the scatter screen of ``_ckernels.c``: a false star inside the fine gate of
   an undetected star, far outside the frame's own centroid scatter).  The detections
   beyond the ``max_verify_stars`` brightest take no part in the fit, but a pair whose
   catalog star has one of them nearer than its own detection is not matched either
   (the star's detection ranked beyond the used ones and a false star among them fell
   in its gate) and the attitude is refitted.
5. **Vote.** When the prior error is comparable to the distance between stars, nearest
   neighbours are mostly wrong and so is their median: if steps 3-4 fail, the shift is
   taken where the offsets of all (star, prediction) pairs within ``g_prior`` cluster
   most densely, and steps 3-4 are repeated once (``p_false`` doubled for the second try).

Chance model: after the fit (two stars' worth of freedom used) each other star lands
within ``g`` of one of the ``M`` predicted stars with ``p1 = M pi g^2 / area``; the prior
allows about ``(g_prior / g)^3`` distinguishable attitudes, so
``p_false = (g_prior / g)^3 P(Binomial(n - 2, p1) >= k - 2)``, evaluated for ``g`` the
fine gate and 1/2, 1/4, 1/8 of it (the smallest, times 4).

Steps 1-5 run in compiled code (:mod:`._ckernels` through :mod:`._kernels`, the same
computation as the NumPy version it replaced: ~100 NumPy calls and one to three QUEST
solves per frame); what is left in Python is the input check and the result
(benchmarks/bench_identify.py --tracking-only; docs/identification.md).
"""

from __future__ import annotations

import math
import time

import numpy as np

from shipstar.identify import _kernels
from shipstar.identify._result import Identification, failed_identification, make_identification
from shipstar.identify._verify import FINE_GATE

__all__ = ["tracking", "tracking_pinhole", "track_params", "shift_gate"]

# The compiled search (``_ckernels.c``, "Tracking") fixes: 6 attitude fits before the
# pairs must have settled; pairs beyond the fine gate dropped and refitted (twice at
# most) while they are at most 20 % of the pairs; the 20 brightest stars find the shift.
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


def _reason(code: int, count: int, p: float, gate_prior: float, limit: float) -> str:
    """The reason for the compiled search's failure code (1-5), ``count`` / ``p`` filled in."""
    if code == 1:
        return "no catalog star is predicted in the image"
    if code == 2:
        return (f"only {count} stars within {gate_prior * 206264.8:.0f} arcsec of a "
                "predicted catalog star")
    if code == 3:
        return f"only {count} stars agree with the common shift of the predicted stars"
    if code == 4:
        return f"only {count} stars matched after the attitude update"
    return f"{count} matches could be chance (p_false {p:.1e} > {limit:g})"


def _fail(n, reason, t0):
    return failed_identification(n, "tracking", reason, n_candidates=1,
                                 time_s=time.perf_counter() - t0)


def tracking(field, db, C_prior, *, prior_error_rad: float, focal_scale: float = 1.0,
             p_false_max: float = 1e-6, min_matches: int = 3,
             max_verify_stars: int = 60, stats: dict | None = None) -> Identification:
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
        Brightest stars used (at most 64).
    stats : dict, optional
        Filled with ``voted``: whether step 5 (the offset vote) was tried.

    Returns
    -------
    Identification
        ``mode="tracking"``; ``solved=False`` with a reason when the stars do not fit.
    """
    t0 = time.perf_counter()
    n = field.n
    s = float(focal_scale)
    if field.bad_rows.size:
        good = np.setdiff1d(np.arange(n), field.bad_rows, assume_unique=True)
        usable, t_more = good[:min(max_verify_stars, 64)], field.t[good[min(max_verify_stars, 64):]]
        t_use, w_use = field.t[usable], field.unit(s, rows=usable)
    else:
        usable = None
        m = min(n, max_verify_stars, 64)
        t_use, w_use, t_more = field.t[:m], field.unit(s)[:m], field.t[m:]
    n_use = t_use.shape[0]
    if n_use < min_matches:
        return _fail(n, f"only {n_use} usable stars: tracking needs at least {min_matches}", t0)
    if s != 1.0:
        t_use, t_more = t_use * s, t_more * s
    params = track_params(field.bounds.tolist(), s, field.error_rad, prior_error_rad, n_use,
                          min_matches, p_false_max)
    code, count, p, voted, C, star_index, hip, n_matched, p_false, rms = _kernels.track_solve(
        t_use, w_use, C_prior, db, params, n_field=n, usable=usable, t_more=t_more)
    if stats is not None:
        stats["voted"] = voted
    if code:
        return _fail(n, _reason(code, count, p, params[4], p_false_max), t0)
    return Identification(
        solved=True, reason="", mode="tracking", C_icrs_from_sensor=C, star_index=star_index,
        hip=hip, u_sensor=field.unit(s), n_matched=int(n_matched), p_false=float(p_false),
        rms_arcsec=float(rms), focal_scale=s, radial_k1=0.0,
        n_patterns=0, n_candidates=1, time_s=time.perf_counter() - t0,
    )


def track_params(bounds, s: float, err: float, prior_error_rad: float, n_use: int, min_matches: int,
                 p_false_max: float) -> tuple:
    """The gates of the compiled tracking (:func:`._kernels.track_solve`) for the image
    rectangle ``bounds = (y0, y1, z0, z1)`` (tangent plane at scale 1), focal scale ``s``,
    centroid error ``err`` and prior error (rad), with ``n_use`` usable stars:
    ``(min_matches, n_trials, box (cy, cz, hy, hz), gate, gate_prior, gate_shift, area,
    limit)``."""
    y0, y1, z0, z1 = bounds
    box = (0.5 * s * (y0 + y1), 0.5 * s * (z0 + z1), 0.5 * s * (y1 - y0), 0.5 * s * (z1 - z0))
    half_diag = math.hypot(max(abs(y0), abs(y1)), max(abs(z0), abs(z1)))   # field.half_diagonal_tan
    gate_prior = float(prior_error_rad) + 2.0 * err
    return (min_matches, n_use - 2, box, FINE_GATE * err, gate_prior,
            min(gate_prior, shift_gate(prior_error_rad, half_diag * s, err)),
            (y1 - y0) * (z1 - z0) * s * s, p_false_max)


#: packed gates of the compiled tracking, keyed by everything they are made of (a tracker
#: asks for the same few over and over: one per star count at its fixed prior error)
_PACKED: dict = {}


def _packed_gates(bounds, error_rad: float, prior_error_rad: float, m: int, min_matches: int,
                  p_false_max: float, db):
    """``(params, iparams, dparams)`` of :func:`track_params` at focal scale 1, packed for
    the kernel; cached (a tracked frame spends more on packing them than on matching)."""
    key = (bounds, error_rad, prior_error_rad, m, min_matches, p_false_max, id(db))
    hit = _PACKED.get(key)
    if hit is not None and hit[0] is db:
        return hit[1]
    params = track_params(bounds, 1.0, error_rad, prior_error_rad, m, min_matches, p_false_max)
    packed = (params,) + _kernels.pack_track_params(db, m, params)
    if len(_PACKED) > 512:
        _PACKED.clear()
    _PACKED[key] = (db, packed)
    return packed


def tracking_pinhole(xy, cam, error_rad: float, bounds, db, C_prior, *, prior_error_rad: float,
                     p_false_max: float = 1e-6, min_matches: int = 3,
                     max_verify_stars: int = 60) -> Identification | None:
    """:func:`tracking` at focal scale 1 of pixel centroids ``xy (N, 2)`` (float64, C
    order) of a camera without distortion, ``cam = (x0_px, y0_px, pixel_mm, f_mm)`` (or
    those four packed as native float64 bytes), with the image rectangle ``bounds``
    (tangent plane, a tuple), in one compiled call: the same result as through a
    :class:`StarField`.  None when a centroid is not finite or there are fewer than
    ``min_matches`` stars (the caller builds the field)."""
    t0 = time.perf_counter()
    n = xy.shape[0]
    m = min(n, max_verify_stars, 64)
    if m < min_matches:
        return None
    params, ip, dp = _packed_gates(bounds, error_rad, prior_error_rad, m, min_matches, p_false_max, db)
    out = _kernels.track_pinhole(xy, cam, m, C_prior, db, ip, dp)
    if out is None:
        return None
    code, count, p, voted, C, star_index, hip, u, n_matched, p_false, rms = out
    if code:
        return _fail(n, _reason(code, count, p, params[4], p_false_max), t0)
    return make_identification(True, "", "tracking", C, star_index, hip, u, n_matched, p_false, rms,
                               1.0, 0.0, 0, 1, time.perf_counter() - t0)
