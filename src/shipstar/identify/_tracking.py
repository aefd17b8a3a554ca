"""Tracking: identification by prediction from a prior attitude (the last frame's).

The catalog stars near the prior boresight are projected with the prior attitude;
each of the 20 brightest measured stars takes the nearest prediction within
``g_prior = prior_error + 2 delta``; QUEST on those pairs, then every star is re-matched
within the fine gate ``g = 1.5 delta``.  If every wide pair survives, a last QUEST on
all the fine pairs; if one was dropped (a false star or a neighbour paired in the wide
gate biases the first fit), refit and re-pair until the pairs settle (at most 3 times).

Chance model: after the refit (two stars' worth of freedom used) each other star lands
within ``g`` of one of the ``M`` predicted stars with ``p1 = M pi g^2 / area``; the prior
allows about ``(g_prior / g)^3`` distinguishable attitudes, so
``p_false = (g_prior / g)^3 P(Binomial(n - 2, p1) >= k - 2)``, evaluated for ``g`` the
fine gate and 1/2, 1/4, 1/8 of it (the smallest, times 4).
"""

from __future__ import annotations

import time

import numpy as np

from shipstar.identify._result import Identification, failed_identification
from shipstar.identify._verify import (FINE_GATE, GATE_FRACTIONS, associate, gate_counts,
                                      min_chance, predict, refine, reproject, rms_of)

__all__ = ["tracking"]

#: stars paired in the prior's wide gate (all stars are paired in the fine gate)
_WIDE_STARS = 60


def _fail(n, reason, t0):
    return failed_identification(n, "tracking", reason, n_candidates=1,
                                 time_s=time.perf_counter() - t0)


def tracking(field, db, C_prior, *, prior_error_rad: float, focal_scale: float = 1.0,
             p_false_max: float = 1e-6, min_matches: int = 3,
             max_verify_stars: int = 60) -> Identification:
    """Identify the stars of ``field`` near the prior attitude ``C_prior`` (3, 3)."""
    t0 = time.perf_counter()
    n = field.n
    if field.bad_rows.size:
        usable = np.setdiff1d(np.arange(n), field.bad_rows, assume_unique=True)[:max_verify_stars]
    else:
        usable = np.arange(min(n, max_verify_stars))
    if usable.size < min_matches:
        return _fail(n, f"only {usable.size} usable stars: tracking needs at least {min_matches}", t0)
    s = float(focal_scale)
    t_use = field.t[usable] if s == 1.0 else field.t[usable] * s
    box = field.box(s)
    gate = FINE_GATE * field.error_rad
    gate_prior = float(prior_error_rad) + 2.0 * field.error_rad
    pred = predict(db, C_prior, box, gate_prior)
    # pair only the brightest stars in the wide gate: fewer chances of a wrong pair
    img, cat, _ = associate(t_use[:_WIDE_STARS], pred, gate_prior)
    if img.size < min_matches:
        return _fail(n, f"only {img.size} stars within {gate_prior * 206264.8:.0f} arcsec of a "
                     "predicted catalog star", t0)
    C, _, _ = refine(field, db, usable[img], cat, s, False)
    pred = reproject(pred, C, box)
    img2, cat2, d2 = associate(t_use, pred, gate)
    if img2.size < min_matches:
        return _fail(n, f"only {img2.size} stars matched after the attitude update", t0)
    paired = np.full(usable.size, -1, dtype=np.intp)
    paired[img2] = cat2
    if np.all(paired[img] == cat):
        # every wide pair survived the fine gate: the fit was sound, the new pairs are
        # predicted by it; one more fit with all of them
        if img2.size > img.size:
            C, _, _ = refine(field, db, usable[img2], cat2, s, False)
        img, cat = img2, cat2
    else:
        # a wide pair was wrong (a false star, a near neighbour) and biased the fit:
        # refit on the fine pairs and re-pair until they settle
        for _ in range(3):
            img, cat = img2, cat2
            C, _, _ = refine(field, db, usable[img], cat, s, False)
            pred = reproject(pred, C, box)
            img2, cat2, d2 = associate(t_use, pred, gate)
            if img2.size < min_matches:
                return _fail(n, f"only {img2.size} stars matched after the attitude update", t0)
            if img2.size == img.size and np.array_equal(img2, img) and np.array_equal(cat2, cat):
                break
        else:
            return _fail(n, "the star pairs did not settle after three attitude updates", t0)
    g = gate * GATE_FRACTIONS
    p1 = pred.n_in * np.pi * g * g / (field.area_tan2 * s * s)
    look = np.maximum(1.0, (gate_prior / g) ** 3)
    n_gates = GATE_FRACTIONS.size
    p_false = min(1.0, n_gates * min_chance(
        look, np.full(n_gates, usable.size - 2), gate_counts(d2, gate) - 2, p1,
        stop_below=1e-3 * p_false_max / n_gates))
    if p_false > p_false_max:
        return _fail(n, f"{img.size} matches could be chance (p_false {p_false:.1e} > "
                     f"{p_false_max:g})", t0)
    rows = usable[img]
    star_index = np.full(n, -1, dtype=np.int64)
    star_index[rows] = cat
    hip = np.full(n, -1, dtype=np.int64)
    hip[rows] = db.hip[cat]
    u_sensor = field.unit(s)
    return Identification(
        solved=True, reason="", mode="tracking", C_icrs_from_sensor=C, star_index=star_index,
        hip=hip, u_sensor=u_sensor, n_matched=int(rows.size), p_false=float(p_false),
        rms_arcsec=rms_of(u_sensor[rows], db.u_icrs[cat], C), focal_scale=s, radial_k1=0.0,
        n_patterns=0, n_candidates=1, time_s=time.perf_counter() - t0,
    )
