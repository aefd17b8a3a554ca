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
- **seeing and the shape of the centroid errors** (:class:`NoiseModel`): the centroid
  covariances used are ``L S L^T + f^2 I``, ``L L^T`` the extraction's (Cramer-Rao)
  covariance, ``S`` a 2 x 2 factor in image axes and ``f`` a floor (seeing), both estimated
  from the attitude residuals of the last :data:`SHAPE_WINDOW_S` seconds of solved frames
  against their exact expectations (:func:`residual_moments`); the floor never below
  ``PipelineOptions.centroid_floor_px``.  A star smeared by less than a streak (about 3 px:
  the extraction fits it as a point) is less certain along its smear than its point
  covariance says and more certain across; so are streaks whose model is imperfect (``S``);
  the brightest stars, which carry the attitude, are as uncertain as the seeing (``f``).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

__all__ = ["ConditionMonitor", "NoiseModel", "residual_moments", "expected_stars", "CLOUDED_REASON", "MOON_REASON", "SUN_REASON",
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
#: Fewest residuals (stars, pooled over frames) for an estimate of the noise model.
FLOOR_MIN_STARS = 30
#: Whitened residuals (in units of their predicted sigma) beyond this are not used by
#: :class:`NoiseModel` (chi-square with 2 dof exceeds 4.5^2 with probability 4e-5).
SHAPE_CLIP = 4.5
#: Seconds of solved frames whose residuals give the noise model (20 frames at 10 frames/s).
SHAPE_WINDOW_S = 2.0
#: Whitened residuals beyond this are left out when a frame is added (gross outliers only:
#: under the model the frame was processed with, a bright star may be many sigmas out).
_FIRST_CLIP = 30.0
#: The smallest eigenvalue of the shape factor ``S`` (the Cramer-Rao covariance 20x too large).
_MIN_SHAPE = 0.05
#: With fewer than ``FLOOR_MIN_STARS`` residuals in the window (after cloud), the noise model
#: takes older frames too, newest first, up to this age (s).
NOISE_MAX_AGE_S = 4.0


def expected_stars(database, camera, C_icrs_from_sensor=None) -> float:
    """Catalog stars of ``database`` (its magnitude limit) in ``camera``'s image at the
    pointing ``C_icrs_from_sensor``; without a pointing, the sky's average for the field."""
    if C_icrs_from_sensor is None or not np.all(np.isfinite(C_icrs_from_sensor)):
        fx, fy = database.params.fov_x_rad, database.params.fov_y_rad
        return float(database.n_stars * fx * fy / (4.0 * math.pi))
    v = np.asarray(database.u_icrs, float) @ np.asarray(C_icrs_from_sensor, float)
    v = v[v[:, 0] > 0.0]
    return float(np.count_nonzero(camera.in_image(camera.project(v))))


class NoiseModel:
    """The centroid errors' covariance ``L S L^T + f^2 I`` from recent attitude residuals:
    a 2 x 2 factor ``S`` (image axes) on the extraction's covariance ``L L^T`` and a floor
    ``f`` (px, seeing) added after it, estimated together.

    The two parts act on different stars: ``S`` on the faint ones, whose Cramer-Rao
    covariance dwarfs the floor (a streak's model too cautious, or not cautious enough,
    along its smear), ``f`` on the bright ones, which carry the attitude.  Each solved frame
    adds its inlier stars' residuals whitened by the extraction's covariance alone,
    ``z_i = L_i^-1 e_i``, with their expectation: for a fit with fixed weights the residual
    is linear in every star's error, so ``E[z_i z_i^T]`` is linear in ``(S, f^2)``
    (:func:`residual_moments`; exact to first order in the errors, whatever the fit's
    weights: a star that carries the fit shows little of its error, and none of it is lost
    to a leverage approximation).  Over the frames of the last :data:`SHAPE_WINDOW_S`
    seconds ``(S, f^2)`` is a least-squares fit of ``z z^T`` to those expectations, each
    star weighted by its expected scatter: first under the model its frame was processed
    with (each frame's normal equations, kept when it is added), then once more under
    that first fit's model; whitened residuals beyond :data:`SHAPE_CLIP` under it are left
    out (a misidentified or blended star).  A floor that comes out negative is 0 (the Cramer-Rao covariances explain the
    residuals).  When the window has fewer than ``min_stars`` residuals (after cloud) or
    does not show the floor at one sigma (its stars all faint), older frames up to
    :data:`NOISE_MAX_AGE_S` join it: a floor collapsing to 0 there would give the next
    bright star the weight of a seeing-free one.

    Measured on a moonlit, clouded 160 s session (``realistic.toml``, seeing 1.5'' per
    axis): the former estimates (a median floor, and ``S`` over the floor too, from an
    average leverage) gave 1.16'' and ``S`` 0.78, so the brightest stars were given 0.45x
    their error variance and A1's RMS(error/sigma) was 1.23 / 1.27 / 1.24; this model
    gives a floor of 1.50'' (median; the truth's errors fitted to the same model: 1.51'',
    ``S`` 0.77) and 1.07 / 1.09 / 1.07.
    """

    def __init__(self, window_s: float = None, min_stars: int = FLOOR_MIN_STARS, max_age_s: float = None):
        self.window_s = SHAPE_WINDOW_S if window_s is None else float(window_s)
        self.max_age_s = max(self.window_s, NOISE_MAX_AGE_S if max_age_s is None else float(max_age_s))
        self._frames: deque = deque()
        self.min_stars = int(min_stars)
        self._cache = None

    def _prune(self, t_s: float) -> None:
        while self._frames and self._frames[0][0] < t_s - self.max_age_s:
            self._frames.popleft()
            self._cache = None

    def _recent(self, t_s: float, age_s: float) -> list:
        """The frames of the last ``age_s`` seconds; with fewer than ``min_stars``
        residuals there, the newest older ones that reach ``min_stars``."""
        frames = [f for f in self._frames if f[0] >= t_s - age_s]
        n = sum(f[3] for f in frames)
        older = [f for f in self._frames if f[0] < t_s - age_s]
        while n < self.min_stars and older:
            f = older.pop()
            frames.insert(0, f)
            n += f[3]
        return frames

    def add(self, z, X, t_s: float, theta_used=None) -> None:
        """Add a frame's whitened residuals ``z`` (M, 2) and their expectations ``X``
        (M, 3, 4): ``E[(z_x^2, z_x z_y, z_y^2)] = X @ (S_xx, S_xy, S_yy, f^2)``; at ``t_s`` (s).

        ``theta_used`` (4,): the noise model the frame was processed with (None: no estimate
        yet, ``S = I``, no floor).  The frame keeps its normal equations with each star
        weighted by its expected scatter under that model, ``1 / (tr V / 2)^2``,
        ``V = X theta_used``, the gross outliers (beyond ``_FIRST_CLIP``) left out: the first
        pass of :meth:`estimate` sums them, the second re-weights the window's stars once
        with the first pass's model."""
        z = np.asarray(z, float).reshape(-1, 2)
        X = np.asarray(X, float).reshape(-1, 3, 4)
        ok = np.all(np.isfinite(z), axis=1) & np.all(np.isfinite(X), axis=(1, 2))
        z, X = z[ok], X[ok]
        theta = np.array([1.0, 0.0, 1.0, 0.0]) if theta_used is None else np.asarray(theta_used, float)
        zz = np.stack([z[:, 0] ** 2, z[:, 0] * z[:, 1], z[:, 1] ** 2], axis=1)
        use, w = _clip_and_weights(z, X, theta, _FIRST_CLIP)
        if np.count_nonzero(use) < 3:
            return
        z, zz, X, w = z[use], zz[use], X[use], w[use]
        A, b = _normal_equations(zz, X, w)
        self._prune(t_s)
        c64 = np.ascontiguousarray                      # as the compiled fit reads them
        self._frames.append((float(t_s), c64(A, dtype=np.float64), c64(b, dtype=np.float64), len(z),
                             c64(z, dtype=np.float64), c64(zz, dtype=np.float64), c64(X, dtype=np.float64)))
        self._cache = None

    def estimate(self, t_s: float):
        """``(S (2, 2), f2_px2)`` for a frame at ``t_s`` from the frames after
        ``t_s - window_s`` (and older ones, up to ``max_age_s``, when they have fewer than
        ``min_stars`` residuals or do not show the floor at one sigma), or None with fewer
        than ``min_stars`` residuals up to ``max_age_s``."""
        self._prune(t_s)
        if self._cache is not None and self._cache[0] == t_s:
            return self._cache[1]
        est = self._fit(self._recent(t_s, self.window_s))
        if (est is None or not est[1] > est[2]) and any(f[0] < t_s - self.window_s for f in self._frames):
            est = self._fit(self._recent(t_s, self.max_age_s))
        result = None if est is None else est[:2]
        self._cache = (t_s, result)
        return result

    def _fit(self, frames):
        """``(S, f2, sigma_f2)`` from ``frames``, or None: the frames' own normal equations
        summed, then the stars re-weighted once with that model (those beyond
        :data:`SHAPE_CLIP` under it left out).  Compiled (``attitude._ckernels.noise_fit``,
        the same steps); :meth:`_fit_python` is its reference."""
        from shipstar.attitude import _ckernels

        theta = np.empty(4)
        ok, sigma_f2 = _ckernels.noise_fit(frames, self.min_stars, SHAPE_CLIP, _MIN_SHAPE, theta)
        if not ok:
            return None
        return np.array([[theta[0], theta[1]], [theta[1], theta[2]]]), float(theta[3]), sigma_f2

    def _fit_python(self, frames):
        """:meth:`_fit` in NumPy (the compiled kernel's reference)."""
        if sum(f[3] for f in frames) < self.min_stars:
            return None
        fit = _fit_shape_floor(sum(f[1] for f in frames), sum(f[2] for f in frames))
        if fit is None:
            return None
        z = np.concatenate([f[4] for f in frames])
        zz = np.concatenate([f[5] for f in frames])
        X = np.concatenate([f[6] for f in frames])
        use, w = _clip_and_weights(z, X, fit[0], SHAPE_CLIP)
        if np.count_nonzero(use) < self.min_stars:
            return None
        fit = _fit_shape_floor(*_normal_equations(zz, X, np.where(use, w, 0.0)))
        if fit is None:
            return None
        theta, sigma_f2 = fit
        S = np.array([[theta[0], theta[1]], [theta[1], theta[2]]])
        return S, float(theta[3]), sigma_f2


def _clip_and_weights(z, X, theta, clip: float):
    """``(use (n,) bool, w (n,))``: the stars within ``clip`` sigma under the model
    ``theta`` and their weights ``1 / (tr V / 2)^2``, ``V = X theta``."""
    V = (X.reshape(-1, 4) @ theta).reshape(-1, 3)            # (n, 3): E[z z^T] under theta
    v0, v1, v2 = V[:, 0], V[:, 1], V[:, 2]
    z0, z1 = z[:, 0], z[:, 1]
    det = v0 * v2 - v1 * v1
    good = det > 0.0
    # one pass over all stars (no boolean-indexed copies: this runs twice a frame); a star
    # whose V is not positive definite gets chi2 = inf (not used) and weight 0
    chi2 = np.divide(z0 * z0 * v2 - 2.0 * z0 * z1 * v1 + z1 * z1 * v0, det,
                     out=np.full(len(z), np.inf), where=good)
    tr = v0 + v2
    w = np.divide(4.0, tr * tr, out=np.zeros(len(z)), where=good)
    return chi2 < clip * clip, w


def _normal_equations(zz, X, w):
    """``(A (4, 4), b (4,))`` of the weighted least squares ``zz (n, 3) = X (n, 3, 4) theta``,
    the off-diagonal row counted twice (a star of weight 0 adds nothing)."""
    Xr = X.reshape(-1, 4)
    XtW = Xr.T * (w[:, None] * _ROW_WEIGHTS[None, :]).reshape(-1)
    return XtW @ Xr, XtW @ zz.reshape(-1)


def _fit_shape_floor(A, b):
    """``theta = (S_xx, S_xy, S_yy, f^2)`` from the weighted normal equations ``A theta = b``
    of ``z z^T = X theta`` (the off-diagonal counted twice), with ``f^2 >= 0``.  ``(theta,
    sigma_f2)``: ``sigma_f2`` the unconstrained ``f^2``'s standard error (for Gaussian
    errors the weights ``1 / (tr V / 2)^2`` are twice the inverse variance of ``z z^T``'s
    diagonal, so the covariance is ``2 A^-1``); None when singular."""
    try:
        A_inv = np.linalg.inv(A)
        theta = A_inv @ b
        sigma_f2 = math.sqrt(max(2.0 * A_inv[3, 3], 0.0))
        if not theta[3] > 0.0:                   # the Cramer-Rao covariances explain it all
            theta = np.append(np.linalg.solve(A[:3, :3], b[:3]), 0.0)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(theta)):
        return None
    # an S that is not positive definite (few stars) has its eigenvalues raised to _MIN_SHAPE
    # (the smaller eigenvalue in closed form first: eigh only in that rare case)
    half_tr, half_diff = 0.5 * (theta[0] + theta[2]), 0.5 * (theta[0] - theta[2])
    if half_tr - math.sqrt(half_diff * half_diff + theta[1] * theta[1]) < _MIN_SHAPE * (1.0 + 1e-9):
        lam, vec = np.linalg.eigh(np.array([[theta[0], theta[1]], [theta[1], theta[2]]]))
        if lam[0] < _MIN_SHAPE:
            S = (vec * np.maximum(lam, _MIN_SHAPE)) @ vec.T
            theta = np.array([S[0, 0], S[0, 1], S[1, 1], theta[3]])
    return theta, sigma_f2


#: The rows of ``z z^T`` (xx, xy, yy) in the least squares: the off-diagonal counts twice.
_ROW_WEIGHTS = np.array([1.0, 2.0, 1.0])
#: ``E_k`` of the shape's three components (xx, xy, yy) and the row order of ``z z^T``.
_BASIS = np.array([[[1.0, 0.0], [0.0, 0.0]], [[0.0, 1.0], [1.0, 0.0]], [[0.0, 0.0], [0.0, 1.0]]])


def residual_moments(w_sensor, weights, whiten_per_rad, floor_gram_per_px2):
    """The expectation of the whitened residuals' ``z z^T`` of a weighted fit, linear in the
    noise model ``(S, f^2)`` (:class:`NoiseModel`).

    A rotation fitted to ``w_sensor`` with scalar ``weights`` leaves the residuals
    ``r_i = sum_j M_ij n_j``, ``M_ij = delta_ij P_i - w_j [u_i]x F^-1 [u_j]x^T``,
    ``F = sum w_j P_j``, ``P = I - u u^T`` (first order in the errors ``n_j``).  With the
    error covariance ``D_j V_j D_j^T``, ``V_j = S + f^2 G_j`` (``D_j = J_j L_j``, the
    pseudo-inverse of the whitening ``W_j = L_j^-1 J_j+``), the whitened residual
    ``z_i = W_i r_i`` has ``E[z_i z_i^T] = sum_j A_ij V_j A_ij^T`` with
    ``A_ij = delta_ij I - R_i Q_j``, ``R_i = W_i [u_i]x F^-1``, ``Q_j = w_j [u_j]x^T D_j``:

    ``V_i - R_i Q_i V_i - V_i Q_i^T R_i^T + R_i (sum_j Q_j V_j Q_j^T) R_i^T``,

    whose sum is one 3 x 3 matrix for all ``i`` (O(N), not O(N^2)).

    Parameters
    ----------
    w_sensor : ndarray, shape (N, 3)
    weights : ndarray, shape (N,)
    whiten_per_rad : ndarray, shape (N, 2, 3)
    floor_gram_per_px2 : ndarray, shape (N, 2, 2)

    Returns
    -------
    X : ndarray, shape (N, 3, 4)
        Rows ``(z_x^2, z_x z_y, z_y^2)``, columns ``(S_xx, S_xy, S_yy, f^2)``; None when
        the fit is singular.

    Notes
    -----
    Computed by the compiled kernel (``attitude._ckernels.residual_moments``, the same
    steps); :func:`_residual_moments_python` is the reference it is tested against, and
    answers where the kernel finds a matrix singular.
    """
    from shipstar.attitude import _ckernels

    u = np.ascontiguousarray(w_sensor, dtype=np.float64)
    wts = np.ascontiguousarray(weights, dtype=np.float64)
    W = np.ascontiguousarray(whiten_per_rad, dtype=np.float64)
    G = np.ascontiguousarray(floor_gram_per_px2, dtype=np.float64)
    n = len(wts)
    if u.shape == (n, 3) and W.shape == (n, 2, 3) and G.shape == (n, 2, 2):
        X = np.empty((n, 3, 4))
        if _ckernels.residual_moments(u, wts, W, G, X, np.empty(16 * n)):
            return X
    return _residual_moments_python(u, wts, W, G)


def _residual_moments_python(w_sensor, weights, whiten_per_rad, floor_gram_per_px2):
    """:func:`residual_moments` in NumPy (the compiled kernel's reference)."""
    from shipstar.attitude._solve import _skew

    u = np.asarray(w_sensor, float)
    wts = np.asarray(weights, float)
    W = np.asarray(whiten_per_rad, float)
    G = np.asarray(floor_gram_per_px2, float)
    n = len(u)
    P = np.eye(3)[None] - u[:, :, None] * u[:, None, :]
    try:
        F_inv = np.linalg.inv(np.einsum("n,nij->ij", wts, P))
    except np.linalg.LinAlgError:
        return None
    ux = _skew(u)                                               # [u_i]x           (n, 3, 3)
    Wt = np.swapaxes(W, 1, 2)
    Dm = Wt @ np.linalg.inv(W @ Wt)                              # pinv(W_j)          (n, 3, 2)
    R = W @ ux @ F_inv                                          # (n, 2, 3)
    Q = wts[:, None, None] * (np.swapaxes(ux, 1, 2) @ Dm)       # (n, 3, 2)
    RQ = R @ Q                                                  # (n, 2, 2)
    Rt = np.swapaxes(R, 1, 2)
    Qt = np.swapaxes(Q, 1, 2)
    X = np.empty((n, 3, 4))
    for k, V in enumerate((*_BASIS, None)):
        V = G if V is None else np.broadcast_to(V, (n, 2, 2))
        M = np.sum(Q @ V @ Qt, axis=0)                          # sum_j Q_j V_j Q_j^T  (3, 3)
        RQV = RQ @ V
        E = V - RQV - np.swapaxes(RQV, 1, 2) + R @ M @ Rt
        X[:, :, k] = E[:, [0, 0, 1], [0, 1, 1]]
    return X


class ConditionMonitor:
    """One sensor's detection of cloud, the Moon and the Sun, trails and seeing."""

    def __init__(self, camera, options):
        from shipstar.extract._artifacts import PersistentPixels
        from shipstar.pipeline._skylight import BodyPredictor

        self.camera = camera
        self.options = options
        self.bodies = BodyPredictor(camera)
        self.persistent = PersistentPixels()
        self.noise_model = NoiseModel()
        self._floor_px = math.nan
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

    def noise_at(self, t_s: float):
        """``(S (2, 2) or None, floor_px)`` for a frame at ``t_s``: the noise model's
        estimate (:class:`NoiseModel`), its floor at least the options' floor; before an
        estimate, no shape and the options' floor."""
        base = self.options.centroid_floor_px
        est = self.noise_model.estimate(t_s) if math.isfinite(t_s) else None
        if est is None:
            self._floor_px = base
            return None, base
        S, f2 = est
        self._floor_px = max(base, math.sqrt(f2))
        return S, self._floor_px

    def floor_px(self) -> float:
        """The floor (px) of the last :meth:`noise_at` (the options' floor before one)."""
        return self.options.centroid_floor_px if not math.isfinite(self._floor_px) else self._floor_px

    # -- after the frame -----------------------------------------------------------------
    def reason(self, reason: str, n_detected: int, database, prior) -> str:
        """The reason of a lost frame: the Moon's or the Sun's, clouded, or ``reason``."""
        if self.discs:
            return MOON_REASON if any(d.name == "moon" for d in self.discs) else SUN_REASON
        if n_detected < CLOUDED_FRACTION * expected_stars(database, self.camera, prior):
            return CLOUDED_REASON
        return reason

    def add_solved(self, fr, floor_used_px: float, first=None, t_s: float = math.nan, shape=None) -> None:
        """Feed a solved frame's inlier residuals to the noise model (:class:`NoiseModel`).

        ``first`` (:class:`~shipstar.attitude.HorizontalAttitude`): the frame's first solve,
        before the streak correction.  The residuals are those of the QUEST solution of its
        inliers with the scalar weights: a solution that the model's shape did not weight, so
        that the model depends on the last :data:`SHAPE_WINDOW_S` seconds (a chunk's warm-up
        rebuilds it, ``pipeline._measure.WARMUP_S``) rather than on every earlier one through
        the weights it gave them.  ``shape``: the noise model's ``S`` the frame was processed
        with (None before an estimate)."""
        inputs = fr.solve_inputs
        if inputs is None or inputs.weights is None or not fr.solved or inputs.whiten_per_rad is None \
                or first is None or not first.solved:
            return
        from shipstar.attitude import _ckernels

        k1 = np.asarray(first.inliers)
        wts = np.ascontiguousarray(np.asarray(inputs.weights, float)[k1])
        good = 1.0 / wts - floor_used_px ** 2 < 0.98          # unknown Cramer-Rao sigma (1 px): not used
        w = np.ascontiguousarray(first.w_sensor[k1], dtype=np.float64)
        v = np.ascontiguousarray(first.v_hor[k1], dtype=np.float64)
        C0 = np.empty((3, 3))
        _ckernels.quest(w, v, wts, C0)                       # attitude.quest, compiled
        e = v @ C0 - w                                       # C^T v - w, sensor frame
        W = inputs.whiten_per_rad[k1]
        X = residual_moments(w, wts, W, inputs.floor_gram_per_px2[k1])
        if X is None:
            return
        z = np.einsum("nij,nj->ni", W, e)
        theta = None if shape is None else np.array([shape[0][0], shape[0][1], shape[1][1], floor_used_px ** 2])
        self.noise_model.add(z[good], X[good], t_s, theta)

    def _displacement_px(self, C_then, index, C_now, xy_px, star) -> np.ndarray:
        """``(M,)``: how far (px) the star now at ``xy_px[star[m]]`` (``xy_px`` (N, 2),
        ``star`` (M,) non-decreasing) was from there with the attitude ``C_then[index[m]]``
        (a list of (3, 3) J2000 attitudes), the attitude now ``C_now``: one batched
        projection for every pair of the frame.  Each star's direction is found once (at
        rest a star pairs with ~49 frames), from the stars the pairs hold: the same
        distinct positions as the pairs' rows, so the Newton inverse of the distortion takes
        the same steps and gives the same directions."""
        cam = self.camera
        star = np.asarray(star, np.int64)
        first = np.ones(star.size, dtype=bool)
        first[1:] = star[1:] != star[:-1]
        w = cam.unproject(xy_px[star[first]])[np.cumsum(first) - 1]       # (M, 3) sensor
        C_now_from_then = np.asarray(C_now).T @ np.asarray(C_then, float)   # (U, 3, 3)
        then = cam.project(np.einsum("mi,mij->mj", w, C_now_from_then[index]))
        return np.hypot(*(then - xy_px[star]).T)
