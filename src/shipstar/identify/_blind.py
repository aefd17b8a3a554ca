"""Field-of-view bands: one star database per band of fields, blind or hinted solving.

An uncalibrated image (a photo, ``shipstar solve IMAGE`` with no ``--camera``) is a
pinhole camera whose focal length is unknown, or known to +-10 % from a hint.  Rather
than a database per hint, a small fixed set of databases covers the fields of view in
*bands* of the image's **short side** (the database's pattern circles must fit inside
the image, whatever its aspect ratio):

====  ======================  =========================================
band  short side (deg)        Hp limit
====  ======================  =========================================
0     3.42 .. 7.56            8.5  (20 stars in the narrowest field)
1     7.13 .. 15.75           7.71 (35 stars in the narrowest field)
2     14.25 .. 31.5           6.40 (35 stars in the narrowest field)
====  ======================  =========================================

(each band is ``[0.95 a, 2.1 a]`` for ``a`` = 3.6, 7.5, 15 deg: neighbours overlap by
10 % so that a +-10 % hint lies inside one band).  A band's database is built for the
band's narrowest field (its pattern circles have that diameter) and verifies over the
widest field of an image of aspect ratio up to 2:1.

A *hypothesis* is a band and a focal-length range inside it.  Blind, every band is cut
into pieces of at most +-10 % (:data:`PIECE_TOLERANCE`); with a hint ``fov_deg +- tol``,
the band holding the hinted range, searched exactly as the hint says (or, for a range
across two bands, one hypothesis per band with its part).

:func:`solve_bands` runs lost-in-space over the hypotheses brightest pattern first:
pass ``k`` uses only the patterns of the ``K_k`` brightest stars (8, 14, then the
requested maximum) in every hypothesis before any hypothesis tries fainter stars, and
stops at the first solution.  Its false-match probability is the solving run's bound
times the number of runs planned (a Bonferroni bound over every search that could have
produced a match), and each run is asked for ``p_false_max / runs``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from shipstar.errors import ShipstarError
from shipstar.units import DEG2RAD, RAD2DEG

__all__ = ["BANDS", "Band", "Hypothesis", "hypotheses", "band_database", "solve_bands",
           "BLIND_SHORT_SIDE_DEG", "MAX_ASPECT"]


@dataclass(frozen=True)
class Band:
    """One field-of-view band (short side of the image, radians)."""

    index: int
    lo_rad: float                    # narrowest short side
    hi_rad: float                    # widest short side
    stars_per_field: float           # mean catalog stars in the narrowest square field
    mag_limit: float                 # Hp limit giving them (default_mag_limit, stored:
                                     # computing it loads the whole catalog)

    @property
    def tol(self) -> float:
        """Focal-length tolerance covering the band (``tan`` of the half field)."""
        t1, t2 = math.tan(0.5 * self.lo_rad), math.tan(0.5 * self.hi_rad)
        return (t2 - t1) / (t2 + t1)


def _band(index, a_deg, stars_per_field, mag_limit):
    return Band(index, 0.95 * a_deg * DEG2RAD, 2.1 * a_deg * DEG2RAD, stars_per_field, mag_limit)


#: the bands, narrowest first (tests check the magnitude limits against default_mag_limit)
BANDS = (_band(0, 3.6, 20.0, 8.5), _band(1, 7.5, 35.0, 7.71), _band(2, 15.0, 35.0, 6.4))
#: the short side covered blind (deg)
BLIND_SHORT_SIDE_DEG = (BANDS[0].lo_rad * RAD2DEG, BANDS[-1].hi_rad * RAD2DEG)
#: widest image aspect ratio a band database verifies over
MAX_ASPECT = 2.0
#: blind search order: the middle band (typical photo lenses) first, the deepest last
_BLIND_ORDER = (1, 2, 0)
#: largest focal tolerance of one blind hypothesis (a piece of a band)
PIECE_TOLERANCE = 0.1
#: stars whose patterns each pass uses (the last pass: the requested maximum)
_PASS_STARS = (8, 14)


@dataclass(frozen=True)
class Hypothesis:
    """A band and a range of the image's focal length inside it.

    ``fov_x_rad`` is the nominal horizontal field of the pinhole camera and
    ``focal_tolerance`` its relative uncertainty (as :func:`field_from_pinhole` takes
    them); ``fraction`` is how much of the hinted range the hypothesis covers.
    """

    band: Band
    fov_x_rad: float
    focal_tolerance: float
    fraction: float


def _short_tan(width_px: int, height_px: int, tan_half_x: float) -> float:
    """``tan(short side / 2)`` of a pinhole image with ``tan(fov_x / 2)``."""
    return tan_half_x * min(width_px, height_px) / width_px


def _piece(band, lo, hi, k, fraction):
    """Hypothesis for ``tan(short/2)`` within ``[lo, hi]`` (LIS accepts true tangents
    ``s * nominal`` with ``s`` in ``1 +- tol``: nominal the middle, tol the half width)."""
    return Hypothesis(band, 2.0 * math.atan(0.5 * (lo + hi) / k), (hi - lo) / (hi + lo), fraction)


def hypotheses(width_px: int, height_px: int, fov_deg=None, fov_tolerance: float = 0.1):
    """The hypotheses to search for an image of this size, blind or hinted.

    Blind, every band is split into pieces of focal tolerance at most
    :data:`PIECE_TOLERANCE` (a search with a +-38 % scale window verifies ~50x more chance
    candidates per pattern than one with +-10 %: the pieces together cost less, and each
    is the search a +-10 % hint would make).  Hinted, the band that holds the whole
    hinted range (bands overlap by 10 %), else the bands that share it, each with its part.

    Parameters
    ----------
    width_px, height_px : int
    fov_deg : float, optional
        Hinted horizontal field of view (None: blind).
    fov_tolerance : float
        Relative uncertainty of the hint (of the focal length).

    Returns
    -------
    list of Hypothesis
        In search order.  Empty when the hint lies outside every band.
    """
    w, h = int(width_px), int(height_px)
    if w < 1 or h < 1:
        raise ShipstarError(f"image size must be positive, got {w}x{h}")
    if max(w, h) > MAX_ASPECT * min(w, h) * 1.0001:
        raise ShipstarError(f"image aspect ratio {max(w, h) / min(w, h):.2f}:1: the field-of-view "
                            f"bands cover images up to {MAX_ASPECT:g}:1 (give a camera model)")
    k = min(w, h) / w                   # tan(short/2) = k tan(fov_x/2)
    if fov_deg is None:
        out = []
        step = (1.0 + PIECE_TOLERANCE) / (1.0 - PIECE_TOLERANCE)
        for i in _BLIND_ORDER:
            b = BANDS[i]
            t1, t2 = math.tan(0.5 * b.lo_rad), math.tan(0.5 * b.hi_rad)
            m = max(1, math.ceil(math.log(t2 / t1) / math.log(step) - 1e-9))
            edges = [t1 * (t2 / t1) ** (j / m) for j in range(m + 1)]
            out += [_piece(b, edges[j], edges[j + 1], k, 1.0 / m) for j in range(m)]
        return out
    fov = float(fov_deg)
    tol = float(fov_tolerance)
    tan_x = math.tan(0.5 * fov * DEG2RAD)
    s_lo, s_hi = k * tan_x * (1.0 - tol), k * tan_x * (1.0 + tol)
    spans = [(b, math.tan(0.5 * b.lo_rad), math.tan(0.5 * b.hi_rad)) for b in BANDS]
    holding = [b for b, t1, t2 in spans if t1 <= s_lo and s_hi <= t2]
    if holding:                                   # the usual case: exactly the hint
        mid = math.sqrt(s_lo * s_hi)
        best = min(holding, key=lambda b: abs(math.log(mid / math.tan(0.25 * (b.lo_rad + b.hi_rad)))))
        return [Hypothesis(best, fov * DEG2RAD, tol, 1.0)]
    out = []
    for b, t1, t2 in spans:
        lo, hi = max(s_lo, t1), min(s_hi, t2)
        if hi > lo:
            out.append(_piece(b, lo, hi, k, (hi - lo) / (s_hi - s_lo)))
    out.sort(key=lambda hyp: -hyp.fraction)
    return out


def band_database(band: Band, *, mag_limit=None, epoch_jyear: float = 2025.0, use_cache=True):
    """The star database of a band (built once, cached: one file per band)."""
    from shipstar.identify._database import cached_database, params_for_field

    tol = band.tol
    fov_y = band.lo_rad / (1.0 - tol)                    # pattern circles: the narrowest field
    fov_x = min(MAX_ASPECT * 1.05 * fov_y, 59.9 * DEG2RAD)
    if mag_limit is None:
        mag_limit = band.mag_limit
    params = params_for_field(fov_x, fov_y, mag_limit=mag_limit, fov_tolerance=tol,
                              epoch_jyear=epoch_jyear, pixel_scale_rad=fov_y / 1000.0,
                              camera_name=f"band{band.index}")
    return cached_database(params, use_cache=use_cache)


def solve_bands(xy_px, width_px: int, height_px: int, hyps, *, centroid_error_px: float,
                p_false_max: float, max_pattern_stars: int = 20, max_verify_stars: int = 60,
                max_time_s: float = 10.0, mag_limit=None, databases=None):
    """Lost-in-space over field-of-view hypotheses, brightest patterns first.

    Parameters
    ----------
    xy_px : ndarray (N, 2)
        Centroids, brightest first.
    hyps : list of Hypothesis
    max_time_s : float
        The search's time budget.  Loading a band's database (or building it, on a cold
        cache: seconds) does not count against it, so a cold cache or a loaded host
        cannot turn a solvable frame into a timed-out one.
    databases : dict, optional
        ``band index -> StarDatabase`` to use instead of the cached band databases.

    Returns
    -------
    (Identification, Hypothesis or None, StarDatabase or None, int)
        The identification (its ``p_false`` multiplied by the number of runs planned),
        the hypothesis and database that solved, and the number of runs planned.
    """
    import time
    from dataclasses import replace

    from shipstar.identify._field import field_from_pinhole
    from shipstar.identify._lost_in_space import LisOptions, lost_in_space
    from shipstar.identify._result import failed_identification

    n = len(xy_px)
    if not hyps:
        return (failed_identification(n, "lost_in_space", "the field of view is outside the "
                                      "bands searched"), None, None, 0)
    passes = [k for k in _PASS_STARS if k < max_pattern_stars] + [max_pattern_stars]
    if len(hyps) == 1:
        passes = [max_pattern_stars]          # one hinted band: a single ordinary search
    runs = len(passes) * len(hyps)
    t0 = time.perf_counter()
    dbs = {} if databases is None else dict(databases)
    fields = {}
    reasons = []
    n_patterns = n_candidates = 0
    t_db = 0.0          # loading the band databases (on a cold cache, building them): not
    timed_out = False   # search time, so not counted against max_time_s
    for k_stars in passes:
        for hyp in hyps:
            left = max_time_s - (time.perf_counter() - t0 - t_db)
            if left <= 0.0:
                timed_out = True
                break
            b = hyp.band.index
            if b not in dbs:
                t_load = time.perf_counter()
                dbs[b] = band_database(hyp.band, mag_limit=mag_limit)
                t_db += time.perf_counter() - t_load
            key = (b, hyp.fov_x_rad)
            if key not in fields:
                fields[key] = field_from_pinhole(xy_px, width_px=width_px, height_px=height_px,
                                                 fov_x_rad=hyp.fov_x_rad,
                                                 error_px=centroid_error_px,
                                                 focal_tolerance=hyp.focal_tolerance)
            opts = LisOptions(p_false_max=p_false_max / runs, max_pattern_stars=k_stars,
                              max_verify_stars=max_verify_stars,
                              max_time_s=min(left, max(0.25, max_time_s / len(hyps))))
            ident = lost_in_space(fields[key], dbs[b], opts)
            n_patterns += ident.n_patterns
            n_candidates += ident.n_candidates
            if ident.solved:
                ident = replace(ident, p_false=min(1.0, ident.p_false * runs),
                                time_s=time.perf_counter() - t0)
                return ident, hyp, dbs[b], runs
            reasons.append(ident.reason)
        if timed_out:
            break
    stop = (f"the {max_time_s:g} s search budget was spent after {len(reasons)} of {runs} searches"
            if timed_out else f"{len(reasons)} searches")
    reason = (f"no verified match in {len(hyps)} field-of-view hypothesis(es) "
              f"({stop}; last: {reasons[-1] if reasons else 'none run'})")
    return (failed_identification(n, "lost_in_space", reason, n_patterns=n_patterns,
                                  n_candidates=n_candidates, time_s=time.perf_counter() - t0),
            None, None, runs)
