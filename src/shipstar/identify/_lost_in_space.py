"""Lost-in-space identification: 4-star pattern hashing with error-bounded gates.

1. The brightest ``max_pattern_stars`` usable stars form 4-star patterns, brightest
   patterns first (:func:`._patterns.ordered_combinations`), looked up in batches.
2. Each pattern's six edges carry seed 004's error bound (sec. 4.3.1): a centroid
   error of at most ``delta`` per axis moves a direction by at most ``sqrt(2) delta``,
   so an edge by at most ``e = 2 sqrt(2) delta`` and the sorted ratio ``r_k`` by at
   most ``e (1 + r_k) / largest``.  Every database cell the error box touches is probed.
3. Candidates are re-checked against the catalog pattern's exact ratios and size (the
   size only to the focal-length tolerance), paired star by star (the permutation
   whose edges agree best), rotated by QUEST and verified (:mod:`._verify`'s rules;
   two stars within the fine gate of one catalog star match neither, a pair far
   outside the frame's own scatter is dropped, and so is a pair whose catalog star has
   a star beyond the ``max_verify_stars`` brightest nearer than its own, as in tracking):
   a match is accepted only when ``n_candidates * P(chance) <= p_false_max``.

Steps 1-3 run in compiled code (:mod:`._ckernels` through :mod:`._kernels`): the same
computation as the NumPy version they replace (same batches, candidate order, gates and
chance probabilities), without ~150 NumPy calls of a few microseconds each per frame.
"""

from __future__ import annotations

import math
import time
from functools import lru_cache

import numpy as np

from shipstar.identify import _kernels
from shipstar.identify import _patterns as pat
from shipstar.identify._result import Identification, failed_identification, make_identification
from shipstar.identify._verify import FINE_GATE

__all__ = ["lost_in_space", "lost_in_space_pinhole", "search_params", "LisOptions"]

#: patterns are looked up in batches: all patterns of the brightest m stars, for these m
_BATCH_STARS = (5, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 28, 32)
_SQRT2 = float(np.sqrt(2.0))
#: the compiled search keeps the pattern stars' angles in a 32 x 32 table
_MAX_PATTERN_STARS = 32


@lru_cache(maxsize=64)
def _batch_ends(k: int) -> tuple:
    """End rows of the pattern batches of :func:`ordered_combinations(k)`."""
    last = pat.ordered_combinations(k)[:, 3]
    return tuple(sorted({int(np.searchsorted(last, m)) for m in _BATCH_STARS if m <= k}
                        | {last.shape[0]}))


@lru_cache(maxsize=64)
def _batch_ends_array(k: int) -> np.ndarray:
    out = np.array(_batch_ends(k), dtype=np.int64)
    out.setflags(write=False)
    return out


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


def search_params(db, opts: LisOptions, *, error_rad: float, ftol: float, fit_radial: bool, bounds,
                  t0: float) -> tuple:
    """The gates and limits of the compiled search (:func:`._kernels.lis_solve`) for a
    field with centroid error ``error_rad``, focal tolerance ``ftol`` and image rectangle
    ``bounds = (y0, y1, z0, z1)`` (tangent plane), started at ``t0`` (perf_counter), in
    the order of :func:`._kernels.lis_params`."""
    p = db.params
    e_edge = 2.0 * _SQRT2 * error_rad
    y0, y1, z0, z1 = bounds
    half_diag = math.hypot(max(abs(y0), abs(y1)), max(abs(z0), abs(z1)))   # field.half_diagonal_tan
    return (opts.min_matches, opts.max_candidates, ftol > 0.0, fit_radial, e_edge,
            p.pattern_fov_rad * (1.0 + ftol) * 1.001 + e_edge,                     # max_edge
            p.min_pattern_frac * p.pattern_fov_rad * (1.0 - ftol) - e_edge,        # min_edge
            2.0 * ftol * half_diag ** 2, ftol, error_rad, half_diag,               # model_tol ..
            FINE_GATE * error_rad, (y1 - y0) * (z1 - z0), opts.p_false_max,        # gate_fine ..
            opts.max_time_s - (time.perf_counter() - t0), bounds)


def _too_few(n: int, n_use: int, need: int, t0: float) -> Identification:
    return failed_identification(
        n, "lost_in_space", f"only {n_use} usable stars: lost-in-space needs at "
        f"least {need}", time_s=time.perf_counter() - t0)


def lost_in_space(field, db, opts: LisOptions) -> Identification:
    """Identify the stars of ``field`` with no prior attitude (see module docstring)."""
    t0 = time.perf_counter()
    n = field.n
    if field.bad_rows.size:
        good = np.setdiff1d(np.arange(n), field.bad_rows, assume_unique=True)
        usable, t_more = good[:opts.max_verify_stars], field.t[good[opts.max_verify_stars:]]
        t_use, u_use = field.t[usable], field.u0[usable]
    else:
        usable = None
        m = min(n, opts.max_verify_stars)
        t_use, u_use, t_more = field.t[:m], field.u0[:m], field.t[m:]
    n_use = t_use.shape[0]
    need = max(4, opts.min_matches)
    if n_use < need:
        return _too_few(n, n_use, need, t0)
    k = min(n_use, opts.max_pattern_stars, _MAX_PATTERN_STARS)
    params = search_params(db, opts, error_rad=field.error_rad, ftol=field.focal_tolerance,
                           fit_radial=field.fit_radial, bounds=field.bounds.tolist(), t0=t0)
    status, C, star_index, hip, n_matched, n_verified, n_patterns, s, k1, p_false, rms = \
        _kernels.lis_solve(t_use, u_use, k, pat.ordered_combinations(k), _batch_ends_array(k), db,
                           params, n_field=n, usable=usable, t_more=t_more)
    u_sensor = None
    if status == 1:
        u_sensor = field.u0 if s == 1.0 and k1 == 0.0 else _kernels.unit_rows(field.t, s, k1)
    return _result(status, C, star_index, hip, u_sensor, n_matched, n_verified, n_patterns, s, k1,
                   p_false, rms, n=n, opts=opts, t0=t0)


def lost_in_space_pinhole(xy, cam, error_rad: float, ftol: float, bounds, db,
                          opts: LisOptions) -> Identification | None:
    """:func:`lost_in_space` of pixel centroids ``xy (N, 2)`` (float64, C order) of a
    camera without distortion, ``cam = (x0_px, y0_px, pixel_mm, f_mm)`` with the image
    rectangle ``bounds`` (tangent plane), in one compiled call: the same search and
    result as through a :class:`StarField`.  None when a centroid is not finite (the
    caller builds the field)."""
    t0 = time.perf_counter()
    n = xy.shape[0]
    m = min(n, opts.max_verify_stars)
    need = max(4, opts.min_matches)
    if m < need:
        return None
    k = min(m, opts.max_pattern_stars, _MAX_PATTERN_STARS)
    params = search_params(db, opts, error_rad=error_rad, ftol=ftol, fit_radial=False, bounds=bounds,
                           t0=t0)
    out = _kernels.lis_pinhole(xy, cam, m, k, pat.ordered_combinations(k), _batch_ends_array(k), db,
                               params)
    if out is None:
        return None
    return _result(*out, n=n, opts=opts, t0=t0)


def _result(status, C, star_index, hip, u_sensor, n_matched, n_verified, n_patterns, s, k1, p_false,
            rms, *, n: int, opts: LisOptions, t0: float) -> Identification:
    if status == 1:
        return make_identification(True, "", "lost_in_space", C, star_index, hip, u_sensor,
                                   int(n_matched), float(p_false), float(rms), float(s), float(k1),
                                   int(n_patterns), int(n_verified), time.perf_counter() - t0)
    if status == 2:
        reason = (f"search stopped after {n_verified} candidates / "
                  f"{time.perf_counter() - t0:.3f} s without a verified match")
    elif n_verified:
        reason = (f"{n_verified} candidate pattern(s) failed verification "
                  f"(p_false > {opts.p_false_max:g} or fewer than {opts.min_matches} stars matched)")
    else:
        reason = f"no catalog pattern matched {n_patterns} star patterns"
    return failed_identification(n, "lost_in_space", reason, n_patterns=n_patterns,
                                 n_candidates=n_verified, time_s=time.perf_counter() - t0)
