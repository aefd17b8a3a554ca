"""Shared core of the Wahba solvers: input preparation, the attitude profile matrix,
Davenport's characteristic polynomial and its Newton iteration.

Wahba's problem here is posed for ``C_ref_from_body``: maximise
``sum_i a_i v_i . (C w_i) = tr(C^T B)`` with the attitude profile matrix
``B = sum_i a_i v_i w_i^T`` (Shuster & Oh 1981 with their "body" vectors = our reference
vectors ``v`` and their "reference" vectors = our body vectors ``w``, so their attitude
matrix ``A`` *is* ``C_ref_from_body``).  Weights are normalised to sum 1, so the largest
eigenvalue of Davenport's K matrix is ``lambda_max <= 1`` and ``lambda_0 = 1`` is a start
above it.

The algebra below works on the nine components of B, which are either Python floats
(one solve: fast, no NumPy call overhead) or NumPy arrays of any shape (a batch of
solves).  Both paths run the same formulas.
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.errors import ShipstarError

#: Column signs of the half-turn ``R_i`` about body axis i (i = x, y, z); index 0 is the
#: identity.  ``B' = B @ R_i`` negates two columns, and ``C = C' @ R_i`` undoes it.
FRAME_SIGNS = np.array([[1.0, 1.0, 1.0],
                        [1.0, -1.0, -1.0],
                        [-1.0, 1.0, -1.0],
                        [-1.0, -1.0, 1.0]])

_NEWTON_MAX_ITER = 60
_NEWTON_RTOL = 1e-15


def prepare(w_body, v_ref, weights=None):
    """Validate shapes, normalise vectors and weights.

    Parameters
    ----------
    w_body, v_ref : array_like, shape (..., N, 3)
        Matched directions in the body and reference frames (need not be unit).
    weights : array_like, shape (..., N) or (N,), optional
        Non-negative relative weights; equal weights if omitted.

    Returns
    -------
    w, v : ndarray, shape (..., N, 3)
        Unit vectors (rows of zero length become NaN).
    a : ndarray, shape (..., N)
        Weights normalised to sum 1 along the last axis.
    """
    w = np.asarray(w_body, dtype=float)
    v = np.asarray(v_ref, dtype=float)
    if w.ndim < 2 or w.shape[-1] != 3 or w.shape != v.shape:
        raise ShipstarError(
            f"w_body and v_ref must both have shape (..., N, 3); got {w.shape} and {v.shape}")
    n = w.shape[-2]
    if weights is None:
        a = np.full(w.shape[:-1], 1.0 / max(n, 1))
    else:
        a = np.asarray(weights, dtype=float)
        if a.shape != w.shape[:-1] and a.shape != (n,):
            raise ShipstarError(f"weights must have shape {w.shape[:-1]}; got {a.shape}")
        if not np.all(np.isfinite(a)) or np.any(a < 0):
            raise ShipstarError("weights must be finite and non-negative")
        a = np.broadcast_to(a, w.shape[:-1])
        total = a.sum(axis=-1, keepdims=True)
        if np.any(total <= 0):
            raise ShipstarError("weights sum to zero")
        a = a / total
    with np.errstate(invalid="ignore", divide="ignore"):
        w = w / np.sqrt(np.einsum("...i,...i->...", w, w))[..., None]
        v = v / np.sqrt(np.einsum("...i,...i->...", v, v))[..., None]
    return w, v, a


def profile_matrix(w, v, a):
    """Attitude profile matrix ``B = sum_i a_i v_i w_i^T``, shape (..., 3, 3)."""
    return np.swapaxes(v * a[..., None], -1, -2) @ w


def components(B):
    """The nine components ``(b00, b01, ..., b22)``: floats for one (3, 3) matrix,
    arrays of shape S for a stack S + (3, 3)."""
    if B.ndim == 2:
        return tuple(B.ravel().tolist())
    return tuple(B[..., i, j] for i in range(3) for j in range(3))


def flip(b, frame):
    """Components of ``B @ R_frame`` (two columns negated).

    ``frame`` is an int in 0..3, or (batch path) an integer array of shape S.
    """
    if isinstance(frame, (int, np.integer)):
        if frame == 0:
            return b
        sx, sy, sz = FRAME_SIGNS[frame].tolist()
    else:
        signs = FRAME_SIGNS[frame]
        sx, sy, sz = signs[..., 0], signs[..., 1], signs[..., 2]
    b00, b01, b02, b10, b11, b12, b20, b21, b22 = b
    return (sx * b00, sy * b01, sz * b02, sx * b10, sy * b11, sz * b12,
            sx * b20, sy * b21, sz * b22)


def k_parts(b):
    """Pieces of Davenport's K matrix: ``S = B + B^T`` (6 independent components),
    ``sigma = tr B`` and ``z = [B12 - B21, B20 - B02, B01 - B10]`` (zero-based)."""
    b00, b01, b02, b10, b11, b12, b20, b21, b22 = b
    s = (2.0 * b00, b01 + b10, b02 + b20, 2.0 * b11, b12 + b21, 2.0 * b22)
    sigma = b00 + b11 + b22
    z = (b12 - b21, b20 - b02, b01 - b10)
    return s, sigma, z


def sym_mul(s, x):
    """Product of the symmetric matrix with components ``s`` and the 3-vector ``x``."""
    s00, s01, s02, s11, s12, s22 = s
    x0, x1, x2 = x
    return (s00 * x0 + s01 * x1 + s02 * x2,
            s01 * x0 + s11 * x1 + s12 * x2,
            s02 * x0 + s12 * x1 + s22 * x2)


def kappa_delta(s):
    """``kappa = tr(adj S)`` and ``delta = det S``."""
    s00, s01, s02, s11, s12, s22 = s
    m00 = s11 * s22 - s12 * s12
    kappa = m00 + s00 * s22 - s02 * s02 + s00 * s11 - s01 * s01
    delta = s00 * m00 - s01 * (s01 * s22 - s12 * s02) + s02 * (s01 * s12 - s11 * s02)
    return kappa, delta


def rayleigh(b, qv, q4):
    """Rayleigh quotient ``q^T K q / q^T q`` of Davenport's K for ``q = [qv, q4]``.

    Its error is second order in the error of ``q``, so one evaluation at an approximate
    optimal quaternion gives ``lambda_max`` to rounding level, whereas the root of the
    characteristic polynomial is only good to ``eps / prod_k(lambda_max - lambda_k)``.
    """
    s, sigma, z = k_parts(b)
    sq = sym_mul(s, qv)
    qq = qv[0] * qv[0] + qv[1] * qv[1] + qv[2] * qv[2]
    num = (qv[0] * sq[0] + qv[1] * sq[1] + qv[2] * sq[2] - sigma * qq
           + 2.0 * q4 * (z[0] * qv[0] + z[1] * qv[1] + z[2] * qv[2]) + sigma * q4 * q4)
    return num / (qq + q4 * q4)


def _divide(num, den):
    if isinstance(num, float):
        return num / den if den != 0.0 else 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den != 0.0, num / np.where(den != 0.0, den, 1.0), 0.0)


def _max_abs(x):
    return abs(x) if isinstance(x, float) else float(np.max(np.abs(x), initial=0.0))


def lambda_max(b):
    """Largest eigenvalue of Davenport's K by Newton's method on its characteristic
    polynomial (Shuster & Oh 1981; the "Quest-Newton" of seed 000 sec. 3).

    ``lambda^4 - (a + b) lambda^2 - c lambda + (a b + c sigma - d) = 0`` with
    ``a = sigma^2 - kappa``, ``b = sigma^2 + z.z``, ``c = delta + z.S z``,
    ``d = z.S^2 z``.  The start ``lambda_0 = sum a_i = 1`` lies above every eigenvalue,
    and a polynomial with only real roots is convex to the right of its largest root,
    so the iteration decreases monotonically to ``lambda_max``.  The polynomial is
    invariant under a change of body frame, so one root serves all four frames of the
    sequential-rotation method.

    Returns ``(lambda_max, dp)`` where ``dp = prod_k (lambda_max - lambda_k)`` (the
    polynomial's derivative there) scales the adjugate ``adj(lambda_max I - K) =
    dp q q^T``: QUEST's ``gamma = dp q4^2``.
    """
    s, sigma, z = k_parts(b)
    kappa, delta = kappa_delta(s)
    sz = sym_mul(s, z)
    zz = z[0] * z[0] + z[1] * z[1] + z[2] * z[2]
    zsz = z[0] * sz[0] + z[1] * sz[1] + z[2] * sz[2]
    zs2z = sz[0] * sz[0] + sz[1] * sz[1] + sz[2] * sz[2]
    ca = sigma * sigma - kappa
    cb = sigma * sigma + zz
    cc = delta + zsz
    p2 = -(ca + cb)
    p1 = -cc
    p0 = ca * cb + cc * sigma - zs2z
    lam = 1.0 if isinstance(sigma, float) else np.ones_like(sigma)
    for _ in range(_NEWTON_MAX_ITER):
        lam2 = lam * lam
        f = (lam2 + p2) * lam2 + p1 * lam + p0
        fp = (4.0 * lam2 + 2.0 * p2) * lam + p1
        step = _divide(f, fp)
        lam = lam - step
        if _max_abs(step) <= _NEWTON_RTOL:
            break
    fp = (4.0 * lam * lam + 2.0 * p2) * lam + p1
    return lam, fp


def unit_q(q0, q1, q2, q4):
    """Normalise ``(q0, q1, q2, q4)``; a zero quaternion (no information) becomes NaN."""
    n = (q0 * q0 + q1 * q1 + q2 * q2 + q4 * q4) ** 0.5
    if isinstance(n, float):
        n = n if n > 0.0 else math.nan
    else:
        n = np.where(n > 0.0, n, np.nan)
    return q0 / n, q1 / n, q2 / n, q4 / n


def matrix_from_shuster_q(q0, q1, q2, q4):
    """``A(q) = (q4^2 - |q|^2) I + 2 q q^T - 2 q4 [q x]`` (Shuster's convention, vector
    part first), as a (..., 3, 3) array.  In Hamilton ``q_wxyz`` terms this rotation is
    ``(q4, -q0, -q1, -q2)``.
    """
    d = q4 * q4 - (q0 * q0 + q1 * q1 + q2 * q2)
    rows = ((d + 2 * q0 * q0, 2 * q0 * q1 + 2 * q4 * q2, 2 * q0 * q2 - 2 * q4 * q1),
            (2 * q1 * q0 - 2 * q4 * q2, d + 2 * q1 * q1, 2 * q1 * q2 + 2 * q4 * q0),
            (2 * q2 * q0 + 2 * q4 * q1, 2 * q2 * q1 - 2 * q4 * q0, d + 2 * q2 * q2))
    if isinstance(q0, float):
        return np.array(rows)
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)
