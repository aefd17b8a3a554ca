"""What the real sky does to one sensor's frames, detected (issue 14 item 2).

One :class:`ConditionMonitor` per :class:`~shipstar.pipeline._sensor.SensorProcessor`:

- **the Moon and the Sun** (:mod:`shipstar.pipeline._skylight`): placed in the field with
  the tracking prior and masked before extraction; detections in the mask are dropped;
- **trails and persistent pixels** (:mod:`shipstar.extract._artifacts`) are dropped before
  identification (single-pixel hot pixels and cosmic rays are rejected by the extraction
  itself, as sharper than the PSF);
- **cloud**: a frame that does not solve and whose detections (after the above) are
  fewer than :data:`CLOUDED_FRACTION` of the catalog stars the database predicts in the
  field (:func:`expected_stars`, at the prior's pointing) is unsolved with reason
  :data:`CLOUDED_REASON`, not a solver failure; a frame lost with a body's mask in the
  image gets :data:`MOON_REASON` (or :data:`SUN_REASON`).  Partly clouded frames are
  solved with the stars they have;
- **seeing** (:class:`NoiseFloor`): the per-star noise floor added in quadrature to the
  extraction's Cramer-Rao sigma is estimated from the attitude residuals of the last
  :data:`FLOOR_FRAMES` solved frames (a median, robust to outliers and to a few
  misidentified stars), never below ``PipelineOptions.centroid_floor_px``;
- **the shape of the centroid errors** (:class:`NoiseShape`): a 2 x 2 factor, in image
  axes, between the errors the residuals show and the extraction's covariances (with the
  floor), from the same frames.  A star smeared by less than a streak (about 3 px: the
  extraction fits it as a point) is less certain along its smear than its point
  covariance says and more certain across; so are streaks whose model is imperfect.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

__all__ = ["ConditionMonitor", "NoiseFloor", "NoiseShape", "expected_stars", "CLOUDED_REASON", "MOON_REASON", "SUN_REASON",
           "CLOUDED_FRACTION", "ENVIRONMENT_REASONS"]

#: Reason of a frame lost to cloud (too few stars for the pointing).
CLOUDED_REASON = "clouded"
#: Reason of a frame lost with the Moon's (the Sun's) mask in the image.
MOON_REASON = "moon in field"
SUN_REASON = "sun in field"
#: Reasons that are the sky's, not the solver's (counted apart in the summary).
ENVIRONMENT_REASONS = (CLOUDED_REASON, MOON_REASON, SUN_REASON)
#: A lost frame with fewer detections than this fraction of the expected stars is clouded.
CLOUDED_FRACTION = 0.3
#: Solved frames whose residuals estimate the noise floor.
FLOOR_FRAMES = 20
#: Fewest residuals (stars, pooled over those frames) for an estimate.
FLOOR_MIN_STARS = 30
_LN2x2 = 2.0 * math.log(2.0)          # median of chi-square with 2 degrees of freedom
#: Whitened residuals (in units of their predicted sigma) beyond this are not used by
#: :class:`NoiseShape` (chi-square with 2 dof exceeds 4.5^2 with probability 4e-5).
SHAPE_CLIP = 4.5
#: Seconds of solved frames whose residuals give the noise shape (20 frames at 10 frames/s).
SHAPE_WINDOW_S = 2.0


def expected_stars(database, camera, C_icrs_from_sensor=None) -> float:
    """Catalog stars of ``database`` (its magnitude limit) in ``camera``'s image at the
    pointing ``C_icrs_from_sensor``; without a pointing, the sky's average for the field."""
    if C_icrs_from_sensor is None or not np.all(np.isfinite(C_icrs_from_sensor)):
        fx, fy = database.params.fov_x_rad, database.params.fov_y_rad
        return float(database.n_stars * fx * fy / (4.0 * math.pi))
    v = np.asarray(database.u_icrs, float) @ np.asarray(C_icrs_from_sensor, float)
    v = v[v[:, 0] > 0.0]
    return float(np.count_nonzero(camera.in_image(camera.project(v))))


def _weighted_median(r2, cr2, f2) -> float:
    """The median of ``r2 / (cr2 + f2)`` with each star weighted by its information
    ``1 / (cr2 + f2)``: the stars that carry the attitude decide the floor.  (An unweighted
    median is decided by the many faint stars, whose Cramer-Rao sigma dwarfs a seeing of
    0.05 px: measured, 0.77 and 1.28'' for a true 1.5'', 1.41 and 1.49'' weighted)."""
    v = np.maximum(cr2 + f2, 1e-12)
    ratio = r2 / v
    order = np.argsort(ratio)
    cw = np.cumsum(1.0 / v[order])
    return float(ratio[order[np.searchsorted(cw, 0.5 * cw[-1])]])


class NoiseFloor:
    """Per-star noise floor (px, 1 sigma per axis) from recent attitude residuals.

    Each solved frame adds its inlier stars' squared residuals ``r2`` (px^2, the 2-D
    residual, corrected for the fit's 3 degrees of freedom) and their Cramer-Rao
    variances ``cr2``.  The floor ``f`` solves ``median(r2 / (cr2 + f^2)) = 2 ln 2`` (the
    median of chi-square with 2 degrees of freedom; each star weighted by its information
    ``1 / (cr2 + f^2)``, :func:`_weighted_median`); 0 when the Cramer-Rao sigmas alone
    already explain the residuals.
    """

    def __init__(self, n_frames: int = FLOOR_FRAMES, min_stars: int = FLOOR_MIN_STARS):
        self._frames: deque = deque(maxlen=int(n_frames))
        self.min_stars = int(min_stars)
        self._cache = None

    def add(self, r2_px2, cr2_px2, leverage=None) -> None:
        """Add a frame's squared residuals and Cramer-Rao variances (px^2); ``leverage``
        (N,), optional: each star's share ``tr(H_ii)`` of the fit's 3 degrees of freedom
        (its residual's variance is ``(cr2 + f^2) (2 - tr H_ii)`` of the 2 axes), else the
        average share ``3 / n``."""
        r2 = np.asarray(r2_px2, float)
        cr2 = np.asarray(cr2_px2, float)
        n = r2.size
        ok = np.isfinite(r2) & np.isfinite(cr2) & (cr2 >= 0.0)
        if n < 3 or not np.any(ok):
            return
        if leverage is None:
            scale = np.full(n, 1.0 - 1.5 / n)
        else:
            scale = np.clip(1.0 - 0.5 * np.asarray(leverage, float), 0.05, 1.0)
        self._frames.append((r2[ok] / scale[ok], cr2[ok]))
        self._cache = None

    @property
    def n_stars(self) -> int:
        return int(sum(len(r) for r, _ in self._frames))

    def estimate_px(self) -> float:
        """The floor (px), NaN with fewer than ``min_stars`` residuals."""
        if self._cache is not None:
            return self._cache
        if self.n_stars < self.min_stars:
            return math.nan
        r2 = np.concatenate([r for r, _ in self._frames])
        cr2 = np.concatenate([c for _, c in self._frames])
        if _weighted_median(r2, cr2, 0.0) <= _LN2x2:
            self._cache = 0.0
            return 0.0
        lo, hi = 0.0, float(np.max(r2))
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            if _weighted_median(r2, cr2, mid) > _LN2x2:
                lo = mid
            else:
                hi = mid
        self._cache = math.sqrt(0.5 * (lo + hi))
        return self._cache


class NoiseShape:
    """2 x 2 factor ``S`` (image axes) between the centroid errors and their predicted
    covariances, from recent attitude residuals.

    Each solved frame adds its inlier stars' residuals whitened by the covariance they were
    predicted with, ``z_i = L_i^-1 e_i`` (``L_i L_i^T`` = the extraction's covariance with
    the floor, ``e_i`` the residual in px), scaled by ``1 / sqrt(1 - 1.5 / m)`` for the
    fit's 3 degrees of freedom among ``2 m``.  ``S = mean(z z^T)`` over the frames of the
    last :data:`SHAPE_WINDOW_S` seconds; the next frame's covariances are ``L_i S L_i^T``.
    Whitened residuals beyond :data:`SHAPE_CLIP` (a misidentified or blended star) are left
    out.  The window is in seconds, not frames, so that a chunk's warm-up
    (``pipeline._measure.WARMUP_S``) covers it at any frame rate.
    """

    def __init__(self, window_s: float = None, min_stars: int = FLOOR_MIN_STARS):
        self.window_s = SHAPE_WINDOW_S if window_s is None else float(window_s)
        self._frames: deque = deque()
        self.min_stars = int(min_stars)
        self._cache = None

    def _prune(self, t_s: float) -> None:
        while self._frames and self._frames[0][0] < t_s - self.window_s:
            self._frames.popleft()
            self._cache = None

    def add(self, z, t_s: float) -> None:
        """Add the whitened residuals ``z`` (M, 2) of the frame at ``t_s`` (s)."""
        z = np.asarray(z, float).reshape(-1, 2)
        m = len(z)
        if m < 3:
            return
        z = z[np.all(np.isfinite(z), axis=1)]
        z = z[np.hypot(z[:, 0], z[:, 1]) < SHAPE_CLIP] / math.sqrt(1.0 - 1.5 / m)
        self._prune(t_s)
        self._frames.append((float(t_s), np.einsum("ni,nj->ij", z, z), len(z)))
        self._cache = None

    def matrix(self, t_s: float):
        """``S`` (2, 2) for a frame at ``t_s`` (from the frames after ``t_s - window_s``),
        or None with fewer than ``min_stars`` residuals there."""
        self._prune(t_s)
        if self._cache is not None:
            return self._cache
        n = sum(k for _, _, k in self._frames)
        if n < self.min_stars:
            return None
        self._cache = sum(zz for _, zz, _ in self._frames) / n
        return self._cache


class ConditionMonitor:
    """One sensor's detection of cloud, the Moon and the Sun, trails and seeing."""

    def __init__(self, camera, options):
        from shipstar.extract._artifacts import PersistentPixels
        from shipstar.pipeline._skylight import BodyPredictor

        self.camera = camera
        self.options = options
        self.bodies = BodyPredictor(camera)
        self.persistent = PersistentPixels()
        self.noise_floor = NoiseFloor()
        self.noise_shape = NoiseShape()
        self.discs: tuple = ()
        #: The last frame: detections dropped per cause, and the positions kept.
        self.last: dict = {}

    # -- before and after extraction ----------------------------------------------------
    def mask(self, image, frame, site, prior, extrapolated: bool = True):
        """``image`` with the Moon's and the Sun's discs masked (``self.discs``); a prior
        that is not ``extrapolated`` (one solved frame only) widens the masks by the
        tracking gate (``PipelineOptions.prior_error_deg``), else by 3 px."""
        from shipstar.pipeline._skylight import body_discs_or_none, mask_bodies
        from shipstar.units import DEG2RAD

        cam = self.camera
        extra = 3.0 if extrapolated else self.options.prior_error_deg * DEG2RAD / (cam.pixel_mm / cam.f_mm)
        self.discs = body_discs_or_none(self.bodies, frame, site, prior, extra)
        return mask_bodies(image, self.discs)

    def keep(self, image, extraction, prior=None) -> np.ndarray:
        """``(N,)`` bool: the extraction's detections that go to identification; ``prior``:
        the frame's predicted J2000 attitude (persistent pixels are only found with it)."""
        from shipstar.extract._artifacts import trail_mask
        from shipstar.pipeline._skylight import in_discs

        ex = extraction
        body = in_discs(ex.xy_px, self.discs)
        trail = trail_mask(image, ex) & ~body
        persistent = self.persistent.update(ex.xy_px, prior, self._displacement_px) & ~body & ~trail
        keep = ~(body | trail | persistent)
        self.last = {"n_extracted": len(ex), "n_in_body_mask": int(np.count_nonzero(body)),
                     "n_trail": int(np.count_nonzero(trail)), "n_persistent": int(np.count_nonzero(persistent)),
                     "bodies": [d.name for d in self.discs], "xy_kept_px": ex.xy_px[keep],
                     "xy_rejected_px": ex.xy_px[~keep]}
        return keep

    def floor_px(self) -> float:
        """Noise floor for the next frame (px): the estimate, at least the options' floor."""
        f = self.noise_floor.estimate_px()
        base = self.options.centroid_floor_px
        return base if not math.isfinite(f) else max(base, f)

    # -- after the frame -----------------------------------------------------------------
    def reason(self, reason: str, n_detected: int, database, prior) -> str:
        """The reason of a lost frame: the Moon's or the Sun's, clouded, or ``reason``."""
        if self.discs:
            return MOON_REASON if any(d.name == "moon" for d in self.discs) else SUN_REASON
        if n_detected < CLOUDED_FRACTION * expected_stars(database, self.camera, prior):
            return CLOUDED_REASON
        return reason

    def add_solved(self, fr, floor_used_px: float, first=None, t_s: float = math.nan) -> None:
        """Feed a solved frame's inlier residuals to the noise-floor and noise-shape estimates.

        ``first`` (:class:`~shipstar.attitude.HorizontalAttitude`): the frame's first solve,
        before the streak correction.  The shape's residuals are those of the QUEST solution
        of its inliers with the scalar weights: a solution that the shape itself did not
        weight, so that the shape depends on the last :data:`SHAPE_WINDOW_S` seconds only (a
        chunk's warm-up rebuilds it, ``pipeline._measure.WARMUP_S``), not on every earlier one
        through the weights it gave them."""
        h, inputs = fr.horizontal, fr.solve_inputs
        if inputs is None or inputs.weights is None or not fr.solved:
            return
        cam = self.camera
        keep = np.asarray(h.inliers)
        u = h.w_sensor[keep] @ np.asarray(h.C_hor_from_sensor).T
        r_px = np.linalg.norm(np.cross(u, h.v_hor[keep]), axis=1) / (cam.pixel_mm / cam.f_mm)
        wts = np.asarray(inputs.weights, float)[keep]
        cr2 = 1.0 / wts - floor_used_px ** 2
        good = cr2 < 0.98                                  # unknown Cramer-Rao sigma (1 px): not used
        # each star's leverage in the weighted fit, w_i tr(F^-1 (I - u_i u_i^T)),
        # F = sum w (I - u u^T): with a low floor the brightest stars carry most of the
        # fit and their residuals are shrunk far more than the average 3 / n, which would
        # bias the floor low (and the lower floor weights them still more)
        proj = np.eye(3)[None, :, :] - u[:, :, None] * u[:, None, :]
        try:
            F_inv = np.linalg.inv(np.einsum("n,nij->ij", wts, proj))
            lev = wts * np.einsum("ij,nji->n", F_inv, proj)
        except np.linalg.LinAlgError:
            lev = None
        self.noise_floor.add(r_px[good] ** 2, np.maximum(cr2[good], 0.0),
                             None if lev is None else lev[good])
        if inputs.whiten_per_rad is not None and first is not None and first.solved:
            from shipstar.attitude import quest

            k1 = np.asarray(first.inliers)
            w, v = first.w_sensor[k1], first.v_hor[k1]
            C0 = quest(w, v, np.asarray(inputs.weights, float)[k1])
            e = v @ C0 - w                                   # C^T v - w, sensor frame
            good1 = 1.0 / np.asarray(inputs.weights, float)[k1] - floor_used_px ** 2 < 0.98
            self.noise_shape.add(np.einsum("nij,nj->ni", inputs.whiten_per_rad[k1][good1], e[good1]), t_s)


    def _displacement_px(self, C_then, C_now, xy_px) -> np.ndarray:
        """How far (px) a star now at ``xy_px`` was from there with the attitude ``C_then``."""
        cam = self.camera
        w = cam.unproject(xy_px)
        then = cam.project(w @ (np.asarray(C_now).T @ np.asarray(C_then)))
        return np.hypot(*(then - xy_px).T)
