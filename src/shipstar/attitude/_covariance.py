"""Attitude error covariance (QUEST measurement model) and angular residuals."""

from __future__ import annotations

import numpy as np

from shipstar.errors import ShipstarError


def _unit(x):
    x = np.asarray(x, dtype=float)
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def projector_sum(w, c):
    """``sum_i c_i (I - w_i w_i^T)`` for unit ``w`` (..., N, 3) and ``c`` (..., N)."""
    wwt = np.einsum("...n,...ni,...nj->...ij", c, w, w)
    return c.sum(axis=-1)[..., None, None] * np.eye(3) - wwt


def sym3_inverse(F):
    """Inverse of symmetric positive semi-definite (..., 3, 3) matrices by the adjugate;
    ShipstarError when one is (numerically) singular, ``det F <= 1e-14 tr(F)^3`` (for
    two directions an angle t apart, ``det/tr^3 = sin^2(t) / 32``)."""
    a, b, c = F[..., 0, 0], F[..., 0, 1], F[..., 0, 2]
    d, e, f = F[..., 1, 1], F[..., 1, 2], F[..., 2, 2]
    adj = np.empty(F.shape)
    adj[..., 0, 0] = d * f - e * e
    adj[..., 0, 1] = adj[..., 1, 0] = c * e - b * f
    adj[..., 0, 2] = adj[..., 2, 0] = b * e - c * d
    adj[..., 1, 1] = a * f - c * c
    adj[..., 1, 2] = adj[..., 2, 1] = b * c - a * e
    adj[..., 2, 2] = a * d - b * b
    det = a * adj[..., 0, 0] + b * adj[..., 0, 1] + c * adj[..., 0, 2]
    tr = a + d + f
    if not np.all(np.isfinite(det)) or np.any(det <= 1e-14 * tr ** 3):
        raise ShipstarError("attitude covariance undefined: the directions are all parallel")
    return adj / det[..., None, None]


def attitude_covariance(w_body, sigma_rad, weights=None):
    """Small-angle attitude error covariance about the body axes (QUEST model).

    Shuster's measurement model: each measured body direction ``w_i`` is the true one
    plus noise perpendicular to it with standard deviation ``sigma_i`` (rad) on each of
    the two perpendicular axes.  For the optimal weights ``a_i ~ sigma_i^-2``

        P = ( sum_i sigma_i^-2 (I - w_i w_i^T) )^-1,

    the inverse Fisher information, i.e. the Cramer-Rao bound.  With other weights the
    covariance of the weighted solution is the sandwich
    ``F^-1 (sum_i a_i^2 sigma_i^2 (I - w_i w_i^T)) F^-1`` with
    ``F = sum_i a_i (I - w_i w_i^T)``, which reduces to P when ``a_i ~ sigma_i^-2``.

    The error ``e`` it describes is the rotation vector of ``C_true^T C_est``: the
    estimated body axes are the true ones turned by ``e`` (components along the body
    axes).  For a star sensor the axis along the boresight (roll) is the weak one.

    Parameters
    ----------
    w_body : array_like, shape (..., N, 3)
        Body-frame directions (normalised here).
    sigma_rad : float or array_like, shape (..., N)
        Per-axis angular noise of each direction, rad, > 0.
    weights : array_like, shape (..., N), optional
        Weights actually used by the estimator; ``sigma^-2`` if omitted.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Covariance in rad^2.

    Raises
    ------
    ShipstarError
        Bad shapes, non-positive sigma, or directions all parallel (the rotation about
        their common direction is then unobservable).
    """
    w = _unit(w_body)
    if w.ndim < 2 or w.shape[-1] != 3:
        raise ShipstarError(f"w_body must have shape (..., N, 3); got {w.shape}")
    sigma = np.broadcast_to(np.asarray(sigma_rad, dtype=float), w.shape[:-1])
    if not np.all(np.isfinite(sigma)) or np.any(sigma <= 0):
        raise ShipstarError("sigma_rad must be finite and > 0")
    if weights is None:
        F = projector_sum(w, sigma ** -2)
        G = None
    else:
        a = np.broadcast_to(np.asarray(weights, dtype=float), w.shape[:-1])
        if not np.all(np.isfinite(a)) or np.any(a < 0):
            raise ShipstarError("weights must be finite and non-negative")
        F = projector_sum(w, a)
        G = projector_sum(w, a * a * sigma * sigma)
    F_inv = sym3_inverse(F)
    if G is None:
        return 0.5 * (F_inv + np.swapaxes(F_inv, -1, -2))
    P = F_inv @ G @ F_inv
    return 0.5 * (P + np.swapaxes(P, -1, -2))


def angle_between_rad(a, b):
    """Angle (rad) between unit vectors ``(..., 3)``: ``2 atan2(|a - b|, |a + b|)``,
    accurate for tiny angles and up to 180 degrees."""
    d = a - b
    s = a + b
    return 2.0 * np.arctan2(np.sqrt(np.einsum("...i,...i->...", d, d)),
                            np.sqrt(np.einsum("...i,...i->...", s, s)))


def residuals_rad(C_ref_from_body, w_body, v_ref):
    """Angle (rad) between each ``v_ref`` and ``C_ref_from_body @ w_body``; shape (..., N)."""
    p = _unit(w_body) @ np.swapaxes(np.asarray(C_ref_from_body, dtype=float), -1, -2)
    return angle_between_rad(p, _unit(v_ref))
