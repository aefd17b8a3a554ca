"""Lost-in-space identification: 4-star pattern hashing with error-bounded gates.

1. The brightest ``max_pattern_stars`` usable stars form 4-star patterns, brightest
   patterns first (:func:`._patterns.ordered_combinations`), looked up in batches.
2. Each pattern's six edges carry seed 004's error bound (sec. 4.3.1): a centroid
   error of at most ``delta`` per axis moves a direction by at most ``sqrt(2) delta``,
   so an edge by at most ``e = 2 sqrt(2) delta`` and the sorted ratio ``r_k`` by at
   most ``e (1 + r_k) / largest``.  Every database cell the error box touches is probed.
3. Candidates are re-checked against the catalog pattern's exact ratios and size (the
   size only to the focal-length tolerance), paired star by star (the permutation
   whose edges agree best), rotated by QUEST and verified (:mod:`._verify`): a match
   is accepted only when ``n_candidates * P(chance) <= p_false_max``.
"""

from __future__ import annotations

import time
from functools import lru_cache

import numpy as np

from shipstar.attitude import quest_single
from shipstar.identify import _patterns as pat
from shipstar.identify._result import Identification, failed_identification
from shipstar.identify._verify import (FINE_GATE, GATE_FRACTIONS, associate, gate_counts,
                                      min_chance, predict, refine, reproject, rms_arcsec,
                                      unit_f64)

__all__ = ["lost_in_space", "LisOptions"]

#: patterns are looked up in batches: all patterns of the brightest m stars, for these m
_BATCH_STARS = (5, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 28, 32)
_SQRT2 = np.sqrt(2.0)


@lru_cache(maxsize=64)
def _batch_ends(k: int) -> tuple:
    """End rows of the pattern batches of :func:`ordered_combinations(k)`."""
    last = pat.ordered_combinations(k)[:, 3]
    return tuple(sorted({int(np.searchsorted(last, m)) for m in _BATCH_STARS if m <= k}
                        | {last.shape[0]}))


class LisOptions:
    """Tuning of the lost-in-space search (plain holder; validated by the public API)."""

    __slots__ = ("p_false_max", "max_pattern_stars", "max_verify_stars", "max_time_s",
                 "max_candidates", "min_matches")

    def __init__(self, p_false_max=1e-6, max_pattern_stars=20, max_verify_stars=60,
                 max_time_s=1.0, max_candidates=2000, min_matches=5):
        self.p_false_max = float(p_false_max)
        self.max_pattern_stars = int(max_pattern_stars)
        self.max_verify_stars = int(max_verify_stars)
        self.max_time_s = float(max_time_s)
        self.max_candidates = int(max_candidates)
        self.min_matches = int(min_matches)


class _Search:
    """State of one lost-in-space search (kept small: arrays computed once)."""

    def __init__(self, field, db, opts, t_start):
        self.field, self.db, self.opts, self.t_start = field, db, opts, t_start
        if field.bad_rows.size:
            usable = np.setdiff1d(np.arange(field.n), field.bad_rows, assume_unique=True)
        else:
            usable = np.arange(field.n)
        self.usable = usable[:opts.max_verify_stars]
        self.t_use = field.t[self.usable]
        self.n_verified = 0
        self.n_patterns = 0
        p = db.params
        self.ftol = field.focal_tolerance
        self.e_edge = 2.0 * _SQRT2 * field.error_rad
        self.half_diag = field.half_diagonal_tan
        self.model_tol = 2.0 * self.ftol * self.half_diag ** 2
        self.max_edge = p.pattern_fov_rad * (1.0 + self.ftol) * 1.001 + self.e_edge
        self.min_edge = p.min_pattern_frac * p.pattern_fov_rad * (1.0 - self.ftol) - self.e_edge
        self.area0 = field.area_tan2
        self.gate_fine = FINE_GATE * field.error_rad

    # ------------------------------------------------------------------ candidates
    def candidates(self, ang_flat, edge_index):
        """Catalog patterns consistent with a batch of image patterns.

        Parameters
        ----------
        ang_flat : ndarray (K * K,)
            Angles between the pattern stars, flattened.
        edge_index : ndarray (B, 6)
            Flat indices of each image pattern's six edges (canonical pair order).

        Returns
        -------
        None, or ``(owner, cat (C, 4), scale)``: image pattern (row of the batch), catalog
        star rows paired with its four stars, catalog / image size; sorted by image
        pattern, then by edge misfit.
        """
        db = self.db
        edges = ang_flat[edge_index]
        ratios, largest = pat.edge_ratios(edges)
        ok = np.flatnonzero((largest <= self.max_edge) & (largest >= self.min_edge))
        self.n_patterns += ok.size
        if ok.size == 0:
            return None
        tol = self.e_edge * (1.0 + ratios[ok]) / largest[ok, None] + self.model_tol
        keys, owner = pat.probe_keys(ratios[ok], tol, db.params.bins)
        probe, prow = db.lookup(keys)
        if prow.size == 0:
            return None
        owner = owner[probe]                              # index into ok
        cat = db.pattern_stars[prow].astype(np.intp)
        cedges = pat.pattern_edges_rad(db.u_icrs[cat])
        cratios, clargest = pat.edge_ratios(cedges)
        img_largest = largest[ok][owner]
        scale = clargest / img_largest
        good = np.all(np.abs(cratios - ratios[ok][owner]) <= tol[owner], axis=1)
        good &= np.abs(scale - 1.0) <= self.ftol * 1.001 + 2.0 * self.e_edge / img_largest
        if not np.any(good):
            return None
        owner, cat, cedges, scale = owner[good], cat[good], cedges[good], scale[good]
        img_edges = edges[ok][owner] * scale[:, None]
        err = np.sum((cedges[:, pat.PERMUTATION_EDGES] - img_edges[:, None, :]) ** 2, axis=2)
        best = np.argmin(err, axis=1)
        cat = cat[np.arange(cat.shape[0])[:, None], pat.PERMUTATIONS[best]]
        if owner.size > 1:
            order = np.lexsort((err[np.arange(err.shape[0]), best], owner))
            owner, cat, scale = owner[order], cat[order], scale[order]
        return ok[owner], cat, scale

    # ------------------------------------------------------------------ verification
    def verify(self, img4, cat4, scale):
        """Verify one candidate; returns ``(C, scale, k1, rows, cat, p_false)`` or None."""
        field, db = self.field, self.db
        fit = self.ftol > 0.0
        s = float(scale) if fit else 1.0
        t4 = field.t[img4]
        w4 = field.unit(s, rows=img4)
        v4 = unit_f64(db)[cat4]
        C = quest_single(w4, v4)
        d = w4 @ C.T - v4
        if np.max(np.einsum("ij,ij->i", d, d)) > (2.0 * self.e_edge) ** 2:
            return None                                   # mirror image or wrong pairing
        dt = t4[:, None, :] - t4[None, :, :]
        largest = float(np.sqrt(np.max(np.einsum("ijk,ijk->ij", dt, dt))))
        gate = 2.0 * field.error_rad * (1.0 + 2.0 * self.half_diag / max(largest, 1e-12))
        if field.fit_radial:                    # uncalibrated lens: 1 % of the width, as tetra3
            gate = max(gate, 0.01 * (field.bounds[3] - field.bounds[2]))
        pred = predict(db, C, field.box(s), gate)
        img, cat, _ = associate(self.t_use * s, pred, gate)
        if img.size < 4:
            return None
        radial = fit and field.fit_radial
        C, s, k1 = refine(field, db, self.usable[img], cat, s, fit, 0.0, radial)
        for attempt in range(4):
            pred = reproject(pred, C, field.box(s))
            img2, cat2, d2 = associate(field.t_true(s, k1, rows=self.usable), pred, self.gate_fine)
            if img2.size < self.opts.min_matches:
                return None
            settled = (img2.size == img.size and np.array_equal(img2, img)
                       and np.array_equal(cat2, cat))
            img, cat = img2, cat2
            if settled or attempt == 3:      # borderline stars may flip: keep the last pairs,
                break                        # matched with the current fit
            C, s, k1 = refine(field, db, self.usable[img], cat, s, fit, k1, radial)
        rows = self.usable[img]
        p_false = self.p_false(rows, d2, img4, pred.n_in, s)
        if p_false > self.opts.p_false_max:
            return None
        return C, s, k1, rows, cat, p_false

    def p_false(self, rows, d2, img4, n_in: int, s: float) -> float:
        """Chance probability of the final match (two bounds, see docs/identification.md).

        (B) given that the search picked this catalog pattern: each of the other
        ``n - 4`` stars matches by chance with ``p1``; times the candidates verified.
        (A) unconditionally (tetra3's accounting): two pattern stars fix the attitude,
        the other ``n - 2`` stars match by chance with ``p1``; times the patterns looked
        up times the database patterns.  Both are evaluated within the fine gate and
        within 1/2, 1/4, 1/8 of it (factor 4); either bounds the false-match
        probability, so ``2 * 4 * min`` does.
        """
        in_pattern = np.zeros(self.field.n, dtype=bool)
        in_pattern[img4] = True
        pat_rows = in_pattern[rows]
        k_all = gate_counts(d2, self.gate_fine)
        k_other = gate_counts(d2[~pat_rows], self.gate_fine)
        n = self.usable.size
        n_gates = GATE_FRACTIONS.size
        g = self.gate_fine * GATE_FRACTIONS
        p1 = n_in * np.pi * g * g / (self.area0 * s * s)
        stop = 1e-3 * self.opts.p_false_max / (2 * n_gates)
        p_b = min_chance(np.full(n_gates, float(self.n_verified)), np.full(n_gates, n - 4),
                         k_other, p1, stop)
        if p_b <= stop:
            return 2.0 * n_gates * p_b
        p_a = min_chance(np.full(n_gates, float(max(self.n_patterns, 1) * self.db.n_patterns)),
                         np.full(n_gates, n - 2), k_all - 2, p1, stop)
        return min(1.0, 2.0 * n_gates * min(p_a, p_b))

    def timed_out(self) -> bool:
        return (time.perf_counter() - self.t_start > self.opts.max_time_s
                or self.n_verified >= self.opts.max_candidates)


def lost_in_space(field, db, opts: LisOptions) -> Identification:
    """Identify the stars of ``field`` with no prior attitude (see module docstring)."""
    t0 = time.perf_counter()
    n = field.n
    search = _Search(field, db, opts, t0)
    usable = search.usable
    need = max(4, opts.min_matches)
    if usable.size < need:
        return failed_identification(
            n, "lost_in_space", f"only {usable.size} usable stars: lost-in-space needs at "
            f"least {need}", time_s=time.perf_counter() - t0)
    k = min(usable.size, opts.max_pattern_stars)
    pattern_rows = usable[:k]
    u = field.unit(1.0, rows=pattern_rows)
    ang_flat = np.arccos(np.clip(u @ u.T, -1.0, 1.0)).ravel()
    combos = pat.ordered_combinations(k)
    edge_index = pat.combination_edges(k)
    ends = _batch_ends(k)
    start = 0
    stopped = False
    for end in ends:
        if end <= start:
            continue
        found = search.candidates(ang_flat, edge_index[start:end])
        if found is not None:
            owner, cat, scale = found
            for i in range(owner.shape[0]):
                search.n_verified += 1
                img4 = pattern_rows[combos[start + owner[i]]]
                accepted = search.verify(img4, cat[i], scale[i])
                if accepted is not None:
                    return _solved(field, db, search, accepted, t0)
                if search.timed_out():
                    break
        if search.timed_out():
            stopped = True
            break
        start = end
    if stopped:
        reason = (f"search stopped after {search.n_verified} candidates / "
                  f"{time.perf_counter() - t0:.3f} s without a verified match")
    elif search.n_verified:
        reason = (f"{search.n_verified} candidate pattern(s) failed verification "
                  f"(p_false > {opts.p_false_max:g} or fewer than {opts.min_matches} stars matched)")
    else:
        reason = f"no catalog pattern matched {search.n_patterns} star patterns"
    return failed_identification(n, "lost_in_space", reason, n_patterns=search.n_patterns,
                                 n_candidates=search.n_verified, time_s=time.perf_counter() - t0)


def _solved(field, db, search, accepted, t0) -> Identification:
    C, s, k1, rows, cat, p_false = accepted
    n = field.n
    star_index = np.full(n, -1, dtype=np.int64)
    star_index[rows] = cat
    hip = np.full(n, -1, dtype=np.int64)
    hip[rows] = db.hip[cat]
    return Identification(
        solved=True, reason="", mode="lost_in_space", C_icrs_from_sensor=C,
        star_index=star_index, hip=hip, u_sensor=field.unit(s, k1=k1), n_matched=int(rows.size),
        p_false=float(p_false), rms_arcsec=rms_arcsec(field, db, rows, cat, C, s, k1),
        focal_scale=float(s), radial_k1=float(k1), n_patterns=search.n_patterns,
        n_candidates=search.n_verified,
        time_s=time.perf_counter() - t0,
    )
