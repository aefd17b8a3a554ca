"""Checked attitude solution with iterative outlier rejection: :func:`solve_attitude`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shipstar.attitude._covariance import (
    angle_between_rad, attitude_covariance, projector_sum, residuals_rad, sym3_inverse,
)
from shipstar.attitude._esoq2 import esoq2
from shipstar.attitude._quest import quest
from shipstar.attitude._svd import svd_attitude
from shipstar.errors import ShipstarError
from shipstar.frames import q_wxyz_from_matrix
from shipstar.units import ASEC2RAD, RAD2ASEC

METHODS = {"quest": quest, "svd": svd_attitude, "esoq2": esoq2}

#: Directions all within this angle (rad) of the first one's line are "all parallel":
#: the rotation about that line is then not determined.
PARALLEL_TOL_RAD = 1e-6
#: Floor of the robust noise estimate, so that noise-free data does not turn rounding
#: error into "outliers".
ROBUST_SIGMA_FLOOR_RAD = 1e-3 * ASEC2RAD
#: The robust (median) noise estimate needs at least this many vectors to judge one.
ROBUST_MIN_VECTORS = 4
#: median of a 2-D Rayleigh-distributed residual = sigma * sqrt(2 ln 2).
_RAYLEIGH_MEDIAN = math.sqrt(2.0 * math.log(2.0))


@dataclass(frozen=True)
class AttitudeSolution:
    """Result of :func:`solve_attitude`.

    Attributes
    ----------
    solved : bool
        False when no trustworthy attitude exists; then ``reason`` says why and every
        number is NaN.
    reason : str
        Empty when solved.
    C_ref_from_body : ndarray, shape (3, 3)
        ``v_ref = C_ref_from_body @ w_body``.
    q_wxyz : ndarray, shape (4,)
        The same rotation (Hamilton, scalar first, w >= 0).
    covariance_rad2 : ndarray, shape (3, 3)
        Small-angle error covariance about the BODY axes (rotation vector of
        ``C_true^T C_est``), from the given ``sigma_rad`` or, if none was given, from
        the residual scatter.
    rms_arcsec : float
        RMS angular residual of the inliers.
    residuals_arcsec : ndarray, shape (N,)
        Angle between each ``v_ref`` and ``C @ w_body`` (all rows, inliers or not).
    inliers : ndarray, shape (N,), bool
        Rows used in the final solution.
    n_used : int
        ``inliers.sum()``.
    sigma_rad : ndarray, shape (N,)
        Per-vector angular error (1-sigma per axis) that ``covariance_rad2`` assumes: the
        given ``sigma_rad``, or, without it, ``s / sqrt(a_rel)`` with ``s`` from the inliers'
        residual scatter (NaN when not solved).
    info_per_rad2 : ndarray, shape (N, 3, 3), or None
        With per-direction information matrices given (``solve_attitude(info_per_rad2=)``):
        those behind ``covariance_rad2``, i.e. the given ones, divided by the variance
        factor when they were relative (no ``sigma_rad``).  None otherwise.
    """

    solved: bool
    reason: str
    C_ref_from_body: np.ndarray
    q_wxyz: np.ndarray
    covariance_rad2: np.ndarray
    rms_arcsec: float
    residuals_arcsec: np.ndarray
    inliers: np.ndarray
    n_used: int
    sigma_rad: np.ndarray
    info_per_rad2: np.ndarray | None = None


def _failed(n, reason, residuals_arcsec=None):
    res = np.full(n, np.nan) if residuals_arcsec is None else residuals_arcsec
    return AttitudeSolution(False, reason, np.full((3, 3), np.nan), np.full(4, np.nan),
                            np.full((3, 3), np.nan), math.nan, res,
                            np.zeros(n, dtype=bool), 0, np.full(n, np.nan))


def _spread_rad(u):
    """Largest angle (rad) between the unit vectors ``u`` (M, 3) and the line of the
    first one: zero when they are all parallel or antiparallel."""
    ang = angle_between_rad(u, u[0])
    return float(np.max(np.minimum(ang, math.pi - ang)))


def _check_info(info, n):
    """The per-direction information matrices ``(N, 3, 3)`` (checked), or None."""
    if info is None:
        return None
    W = np.asarray(info, dtype=float)
    if W.shape != (n, 3, 3) or not np.isfinite(W).all():
        raise ShipstarError(f"info_per_rad2 must be {n} finite 3x3 matrices; got shape {W.shape}")
    return 0.5 * (W + np.swapaxes(W, 1, 2))


def _skew(u):
    """``[u]x`` (N, 3, 3) of vectors ``u`` (N, 3): ``[u]x @ b = u x b``."""
    S = np.zeros(u.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -u[..., 2], u[..., 1], -u[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = u[..., 2], -u[..., 1], u[..., 0]
    return S


def _rotation_from_vector(e):
    """Rotation matrix ``exp([e]x)`` of a rotation vector ``e`` (3,) (Rodrigues)."""
    t = float(np.linalg.norm(e))
    K = _skew(np.asarray(e, float))
    if t < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + math.sin(t) / t * K + (1.0 - math.cos(t)) / (t * t) * (K @ K)


def _fisher_body(w, W):
    """``sum_i [w_i]x^T W_i [w_i]x`` (3, 3): the attitude information about the body axes
    of directions ``w`` (M, 3) with information matrices ``W`` (M, 3, 3)."""
    A = _skew(w)
    return (np.swapaxes(A, 1, 2) @ W @ A).sum(axis=0)


def _refine_anisotropic(C, w, v, W, F):
    """One Gauss-Newton step from ``C`` on ``sum_i e_i^T W_i e_i``, ``e_i = C^T v_i - w_i``.

    A body-frame correction ``d`` (``C <- C exp([d]x)``) moves the predicted direction
    ``u_i = C^T v_i`` by ``[u_i]x d``; the normal equations give ``d``, with the normal
    matrix ``F`` (:func:`_fisher_body`) taken at the measured ``w_i`` (they differ from
    ``u_i`` by arcseconds: a relative change of 1e-5 in a step of arcseconds).  QUEST's
    scalar weights are optimal only for isotropic noise; a streak's centroid is less
    certain along the smear than across it, and this step weights each axis by its own
    error.  From QUEST's solution one step leaves an error of second order in its size
    (micro-arcseconds)."""
    u = v @ C
    # sum_i [u_i]x^T W_i e_i, and [u]x^T b = -u x b
    g = -np.cross(u, np.einsum("nij,nj->ni", W, u - w)).sum(axis=0)
    return C @ _rotation_from_vector(-np.linalg.solve(F, g))


def per_vector(x, n: int) -> np.ndarray:
    """``x`` (a scalar or (n,)) as a read-only (n,) float array: ``np.broadcast_to``'s
    result, without its cost (~10 us) when ``x`` is already an (n,) float array."""
    a = np.asarray(x, dtype=float)
    if a.shape != (n,):
        return np.broadcast_to(a, (n,))
    a = a.view()
    a.flags.writeable = False
    return a


def _check_args(w, v, weights, sigma_rad, method, k_sigma, max_residual_arcsec, min_vectors):
    if method not in METHODS:
        raise ShipstarError(f"unknown attitude method {method!r}; use one of {sorted(METHODS)}")
    if w.ndim != 2 or w.shape[-1] != 3 or w.shape != v.shape:
        raise ShipstarError(
            f"w_body and v_ref must both have shape (N, 3); got {w.shape} and {v.shape}")
    n = len(w)
    a = np.ones(n) if weights is None else np.asarray(weights, dtype=float)
    if a.shape != (n,) or not np.isfinite(a).all() or (a < 0).any():
        raise ShipstarError(f"weights must be {n} finite non-negative numbers")
    sigma = None
    if sigma_rad is not None:
        sigma = per_vector(sigma_rad, n)
        if not np.isfinite(sigma).all() or (sigma <= 0).any():
            raise ShipstarError("sigma_rad must be finite and > 0")
        if weights is None:
            a = sigma ** -2
    if not (math.isfinite(k_sigma) and k_sigma > 0):
        raise ShipstarError(f"k_sigma must be finite and > 0; got {k_sigma}")
    if max_residual_arcsec is not None and not (
            math.isfinite(max_residual_arcsec) and max_residual_arcsec > 0):
        raise ShipstarError(
            f"max_residual_arcsec must be finite and > 0; got {max_residual_arcsec}")
    if int(min_vectors) != min_vectors or min_vectors < 2:
        raise ShipstarError(f"min_vectors must be an integer >= 2; got {min_vectors}")
    return a, sigma


def _bad_rows(w, v):
    """Reason string for NaN / zero-length rows, or ''."""
    finite = np.all(np.isfinite(w), axis=1) & np.all(np.isfinite(v), axis=1)
    if not finite.all():
        return f"non-finite (NaN/inf) input vectors at rows {np.flatnonzero(~finite).tolist()}"
    zero = (np.linalg.norm(w, axis=1) == 0) | (np.linalg.norm(v, axis=1) == 0)
    if zero.any():
        return f"zero-length input vectors at rows {np.flatnonzero(zero).tolist()}"
    return ""


def _degenerate(w, v):
    for name, u in (("body", w), ("reference", v)):
        spread = _spread_rad(u)
        if spread < PARALLEL_TOL_RAD:
            return (f"degenerate geometry: the {name} vectors are all parallel "
                    f"(within {spread * RAD2ASEC:.2g} arcsec); rotation about them is undetermined")
    return ""


def _robust_sigma(r, a_rel, n):
    """Per-axis noise scale from the median residual (Rayleigh), fit-dof corrected."""
    s = np.median(r * np.sqrt(a_rel)) / _RAYLEIGH_MEDIAN * math.sqrt(2 * n / (2 * n - 3))
    return max(float(s), ROBUST_SIGMA_FLOOR_RAD)


def robust_k(k_sigma, n):
    """Threshold multiplier for a sigma estimated from the median of ``n`` residuals.

    With a known sigma a good 2-D residual exceeds ``k sigma`` with probability
    ``p = exp(-k^2 / 2)``.  With sigma estimated on ``nu`` degrees of freedom the ratio
    ``r^2 / (2 sigma_hat^2)`` is F(2, nu)-distributed, whose tail
    ``(1 + 2x / nu)^(-nu / 2) = p`` gives ``k' = sqrt(nu * expm1(k^2 / nu))`` for the
    same false-rejection probability.  The median of Rayleigh residuals has about 48 %
    of the efficiency of their RMS, so ``nu = 0.48 (2 n - 3)``.
    """
    nu = 0.48 * (2 * n - 3)
    return math.sqrt(nu * math.expm1(k_sigma * k_sigma / nu))


def _thresholds(r, active, a, sigma, k_sigma, max_residual_arcsec):
    """Rejection threshold (rad) per row, or None when no judgement is possible."""
    if max_residual_arcsec is not None:
        return np.full(len(r), max_residual_arcsec * ASEC2RAD)
    if sigma is not None:
        return k_sigma * sigma
    n = int(active.sum())
    if n < ROBUST_MIN_VECTORS:
        return None
    a_rel = a / a[active].mean()
    s = robust_k(k_sigma, n) * _robust_sigma(r[active], a_rel[active], n)
    thr = np.full(len(r), np.inf)
    thr[active] = s / np.sqrt(a_rel[active])
    return thr


def solve_attitude(w_body, v_ref, *, weights=None, sigma_rad=None, method="quest",
                   reject_outliers=True, max_residual_arcsec=None, k_sigma=5.0,
                   min_vectors=2, info_per_rad2=None):
    """Attitude from matched directions, with covariance and outlier rejection.

    Parameters
    ----------
    w_body : array_like, shape (N, 3)
        Measured directions in the body (sensor) frame.
    v_ref : array_like, shape (N, 3)
        Matched reference directions (ICRS, horizontal, ...).
    weights : array_like, shape (N,), optional
        Relative weights; default ``sigma_rad^-2`` if given, else equal.
    sigma_rad : float or array_like, shape (N,), optional
        Per-axis angular noise of each body direction (rad).  Sets the covariance and
        the rejection threshold; if omitted both come from the residual scatter.
    method : {"quest", "svd", "esoq2"}
        Wahba solver (:func:`quest`, :func:`svd_attitude`, :func:`esoq2`).
    reject_outliers : bool
        Iteratively drop the vector with the largest residual-to-threshold ratio and
        re-solve while that ratio exceeds 1.  Threshold: ``max_residual_arcsec`` if
        given; else ``k_sigma * sigma_i`` with the given sigma; else
        ``k' * sigma_hat_i`` from a median (Rayleigh) estimate, which needs at least
        :data:`ROBUST_MIN_VECTORS` vectors, with ``k'`` (:func:`robust_k`) raised for
        the estimate's uncertainty so that the false-rejection rate stays
        ``exp(-k_sigma^2 / 2)`` (k' = 7.4 for 20 vectors and k_sigma = 5).
    max_residual_arcsec : float, optional
        Absolute residual threshold (arcsec).
    k_sigma : float
        Threshold in units of the 2-D residual's sigma; a good residual exceeds 5 sigma
        with probability ``exp(-12.5) = 3.7e-6``.
    min_vectors : int
        Fewest vectors a solution may rest on (>= 2).
    info_per_rad2 : array_like, shape (N, 3, 3), optional
        Information matrix (pseudo-inverse covariance, rad^-2, in the body frame, zero
        along ``w_i``) of each measured direction, for noise that differs between the two
        axes across it (a streak's centroid: larger along the smear).  The outliers are
        found with the scalar weights as without it; then the inliers' solution is refined
        by Gauss-Newton steps weighted by these matrices and the covariance is their
        ``(sum_i [w_i]x^T W_i [w_i]x)^-1``: absolute with ``sigma_rad`` given, else scaled
        by the variance factor ``sum_i e_i^T W_i e_i / (2m - 3)`` of the residuals times
        :func:`t_factor` ``(m)``.

    Returns
    -------
    AttitudeSolution
        ``solved=False`` with a reason for: fewer than ``min_vectors`` vectors (given
        or after rejection), NaN/inf or zero-length vectors, all-parallel (degenerate)
        geometry, or two vectors that disagree beyond the threshold.

    Raises
    ------
    ShipstarError
        Bad shapes, weights, sigma, method or thresholds (caller errors).
    """
    w = np.asarray(w_body, dtype=float)
    v = np.asarray(v_ref, dtype=float)
    a, sigma = _check_args(w, v, weights, sigma_rad, method, k_sigma, max_residual_arcsec,
                           min_vectors)
    if method == "quest" and _COMPILED[0]:
        sol = _solve_compiled(w, v, a, sigma, info_per_rad2, weights is not None, reject_outliers,
                              max_residual_arcsec, k_sigma, min_vectors)
        if sol is not None:
            return sol
    return _solve_python(w, v, a, sigma, info_per_rad2, weights is not None, method, reject_outliers,
                         max_residual_arcsec, k_sigma, min_vectors)


#: ``[True]``: solve_attitude's QUEST path runs compiled (:mod:`._ckernels`); the tests set
#: it False to run the Python path, the reference the compiled one is checked against.
_COMPILED = [True]
_F64 = np.dtype(np.float64)
#: the kernel's "not given" for sigma and the information matrices
_NO_SIGMA = np.empty(0)
_NO_INFO = np.empty(0)


def _solve_compiled(w, v, a, sigma, info_per_rad2, weights_given, reject_outliers, max_residual_arcsec,
                    k_sigma, min_vectors):
    """:func:`solve_attitude` by the compiled kernel, or None where the Python path must
    decide (every failure, singular information): the same steps, results equal to
    rounding."""
    from shipstar.attitude import _ckernels

    n = len(w)
    W = None
    if info_per_rad2 is not None:
        W = np.ascontiguousarray(info_per_rad2, dtype=_F64)
        if W.shape != (n, 3, 3):
            return None                                  # the Python path words the error
    f64 = np.ascontiguousarray
    wu, vu, C, r, P, work = np.empty((n, 3)), np.empty((n, 3)), np.empty((3, 3)), np.empty(n), np.empty((3, 3)), \
        np.empty(n)
    active = np.empty(n, dtype=np.bool_)
    Ws, sig = (np.empty((n, 3, 3)), np.empty(n)) if W is not None else (_NO_INFO, _NO_SIGMA)
    max_res = 0.0 if max_residual_arcsec is None else float(max_residual_arcsec) * ASEC2RAD
    status, scale, rms_rad = _ckernels.solve(
        f64(w, dtype=_F64), f64(v, dtype=_F64), f64(a, dtype=_F64),
        _NO_SIGMA if sigma is None else f64(sigma, dtype=_F64), _NO_INFO if W is None else W,
        np.array([float(k_sigma), max_res]), np.array([int(min_vectors), int(bool(reject_outliers))], dtype=np.int64),
        wu, vu, C, r, active.view(np.uint8), P, Ws, sig, work)
    if status != 0:
        return None
    if W is None:
        return _solution(C, r, active, a, sigma, wu, weights_given)
    info_used = Ws / scale if scale > 0 else np.full_like(Ws, np.inf)
    return AttitudeSolution(True, "", C, q_wxyz_from_matrix(C), P, rms_rad * RAD2ASEC, r * RAD2ASEC, active,
                            int(np.count_nonzero(active)), sig, info_used)


def _solve_python(w, v, a, sigma, info_per_rad2, weights_given, method, reject_outliers, max_residual_arcsec,
                  k_sigma, min_vectors):
    """:func:`solve_attitude` in Python (every method; the failures' reasons)."""
    n = len(w)
    info = _check_info(info_per_rad2, n)
    bad = _bad_rows(w, v)
    if bad:
        return _failed(n, bad)
    w = w / np.linalg.norm(w, axis=1, keepdims=True)
    v = v / np.linalg.norm(v, axis=1, keepdims=True)
    active = a > 0
    if active.sum() < min_vectors:
        return _failed(n, f"{int(active.sum())} usable vectors; at least {min_vectors} needed")
    solver = METHODS[method]
    while True:
        reason = _degenerate(w[active], v[active])
        if reason:
            return _failed(n, reason)
        C = solver(w[active], v[active], a[active])
        r = residuals_rad(C, w, v)
        if not reject_outliers:
            break
        thr = _thresholds(r, active, a, sigma, k_sigma, max_residual_arcsec)
        if thr is None:
            break
        ratio = np.where(active, r / thr, -np.inf)
        worst = int(np.argmax(ratio))
        if ratio[worst] <= 1.0:
            break
        if active.sum() - 1 < min_vectors:
            return _failed(n, (
                f"inconsistent vectors: residual {r[worst] * RAD2ASEC:.3g} arcsec exceeds the "
                f"{thr[worst] * RAD2ASEC:.3g} arcsec threshold and rejecting it would leave "
                f"fewer than {min_vectors} vectors"), r * RAD2ASEC)
        active[worst] = False
    if info is not None:
        sol = _solution_anisotropic(C, w, v, active, a, sigma, info)
        if sol is not None:
            return sol
    return _solution(C, r, active, a, sigma, w, weights_given)


def t_factor(m: int) -> float:
    """``nu / (nu - 2)``, ``nu = 2m - 3``: the mean of ``F(1, nu)``.

    A covariance whose noise level is estimated from the solution's own ``m`` residuals
    (``2m`` coordinates, 3 parameters: ``nu`` degrees of freedom) is scaled by it, so that
    RMS(error / sigma) is 1 rather than Student's ``sqrt(nu / (nu - 2))``: 1.07 for 10
    stars, 1.15 for 5, 1.01 for 60 (3.0, the value at ``nu = 3``, for fewer stars)."""
    nu = 2 * int(m) - 3
    return nu / (nu - 2.0) if nu >= 3 else 3.0


def _covariance(w, r, a, sigma, weights_given):
    """Covariance of the inlier solution (arrays already restricted to the inliers).

    Without sigma: ``sigma_i^2 = s^2 / a_rel_i`` with ``s^2 = sum a_rel r^2 / (2m - 3)`` times :func:`t_factor`,
    so the weights are optimal and ``P = s^2 (sum a_rel (I - w w^T))^-1``.
    """
    if sigma is None:
        a_rel = a / a.mean()
        s2 = float(np.sum(a_rel * r * r)) / (2 * len(r) - 3) * t_factor(len(r))
        if s2 == 0.0:
            return np.zeros((3, 3))
        return s2 * sym3_inverse(projector_sum(w, a_rel))
    if not weights_given:                       # a = sigma^-2: Shuster's P directly
        return sym3_inverse(projector_sum(w, a))
    return attitude_covariance(w, sigma, weights=a)


def _solution(C, r, active, a, sigma, w, weights_given):
    m = int(active.sum())
    try:
        P = _covariance(w[active], r[active], a[active],
                        None if sigma is None else sigma[active], weights_given)
    except ShipstarError as exc:
        return _failed(len(w), f"degenerate geometry: {exc}", r * RAD2ASEC)
    rms = math.sqrt(float(np.mean(r[active] ** 2))) * RAD2ASEC
    return AttitudeSolution(True, "", C, q_wxyz_from_matrix(C), P, rms, r * RAD2ASEC,
                            active.copy(), m, _assumed_sigma(r, active, a, sigma))


def _solution_anisotropic(C, w, v, active, a, sigma, info):
    """The inliers' solution refined with per-direction information matrices, its
    covariance from them (see :func:`solve_attitude`); None when those matrices give no
    attitude information about some axis (the scalar solution is then returned)."""
    m = int(active.sum())
    W = info[active]
    try:
        F = _fisher_body(w[active], W)
        P = sym3_inverse(F)
        C = _refine_anisotropic(C, w[active], v[active], W, F)
    except (ShipstarError, np.linalg.LinAlgError):
        return None
    r = residuals_rad(C, w, v)
    scale = 1.0
    if sigma is None:
        e = v[active] @ C - w[active]
        chi2 = float(np.einsum("ni,nij,nj->", e, W, e))
        scale = chi2 / max(2 * m - 3, 1) * t_factor(m)
        P = P * scale
    rms = math.sqrt(float(np.mean(r[active] ** 2))) * RAD2ASEC
    info_used = info / scale if scale > 0 else np.full_like(info, np.inf)
    return AttitudeSolution(True, "", C, q_wxyz_from_matrix(C), P, rms, r * RAD2ASEC,
                            active.copy(), m, _assumed_sigma(r, active, a, sigma), info_used)


def _assumed_sigma(r, active, a, sigma):
    """Per-vector sigma behind the covariance: the given one, else the residual scale
    ``s^2 = sum a_rel r^2 / (2m - 3)`` (times :func:`t_factor`) over the inliers divided by
    ``sqrt(a_rel)``."""
    if sigma is not None:
        return np.broadcast_to(np.asarray(sigma, float), r.shape).copy()
    a_rel = a / a[active].mean()
    m = int(active.sum())
    s = math.sqrt(float(np.sum(a_rel[active] * r[active] ** 2)) / max(2 * m - 3, 1) * t_factor(m))
    with np.errstate(divide="ignore"):
        return np.where(a_rel > 0, s / np.sqrt(a_rel), np.inf)
