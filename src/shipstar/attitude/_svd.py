"""Markley's SVD solution of Wahba's problem (Markley 1988)."""

from __future__ import annotations

import numpy as np

from shipstar.attitude import _wahba as wb


def svd_attitude(w_body, v_ref, weights=None):
    """Optimal attitude from the singular value decomposition of the profile matrix.

    ``B = sum_i a_i v_i w_i^T = U diag(s) V^T`` gives
    ``C_ref_from_body = U diag(1, 1, det U det V) V^T`` (Markley 1988), the rotation
    that maximises ``tr(C^T B)``; the determinant factor keeps it proper.

    Parameters
    ----------
    w_body, v_ref : array_like, shape (..., N, 3)
        Matched body and reference directions (normalised here).
    weights : array_like, shape (..., N) or (N,), optional
        Relative weights; equal if omitted.

    Returns
    -------
    C_ref_from_body : ndarray, shape (..., 3, 3)
        NaN where the input holds NaN.
    """
    w, v, a = wb.prepare(w_body, v_ref, weights)
    B = wb.profile_matrix(w, v, a)
    bad = ~np.all(np.isfinite(B), axis=(-2, -1))
    if np.any(bad):
        B = np.where(bad[..., None, None], 0.0, B)
    u, _, vt = np.linalg.svd(B)
    d = np.linalg.det(u) * np.linalg.det(vt)
    u[..., :, 2] *= d[..., None]
    C = u @ vt
    if np.any(bad):
        C = np.where(bad[..., None, None], np.nan, C)
    return C
