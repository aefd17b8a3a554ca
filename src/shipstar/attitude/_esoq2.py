"""ESOQ2 (Mortari 1997): the rotation axis as the null vector of a 3x3 matrix.

With Davenport's ``K = [[S - sigma I, z], [z^T, sigma]]`` and ``q = [q_v, q4]``, the
eigen-equation ``K q = lambda q`` gives ``q4 = z.q_v / (lambda - sigma)`` and

    M q_v = 0,   M = (lambda - sigma) [(lambda + sigma) I - S] - z z^T,

so the rotation axis ``e`` spans the null space of the symmetric ``M``: it is the
largest of the cross products of M's rows (the columns of ``adj M``), and
``q ~ [(lambda - sigma) e, z.e]``.  M vanishes for the identity rotation, so, as for
QUEST, the problem is solved in each of the four frames (identity and half-turns about
body x, y, z) and the frame with the best-conditioned M (largest ``|adj M|``) is kept.
"""

from __future__ import annotations

import numpy as np

from shipstar.attitude import _wahba as wb


def _cross(p, q):
    return (p[1] * q[2] - p[2] * q[1], p[2] * q[0] - p[0] * q[2], p[0] * q[1] - p[1] * q[0])


def _norm2(x):
    return x[0] * x[0] + x[1] * x[1] + x[2] * x[2]


def _pick(cond, p, q):
    if isinstance(cond, (bool, np.bool_)):
        return p if cond else q
    return tuple(np.where(cond, pk, qk) for pk, qk in zip(p, q))


def _frame_solution(b, lam):
    """Unnormalised ``(q_v, q4)`` and the conditioning ``|adj M|^2`` in one frame."""
    s, sigma, z = wb.k_parts(b)
    s00, s01, s02, s11, s12, s22 = s
    lm = lam - sigma
    lp = lam + sigma
    r0 = (lm * (lp - s00) - z[0] * z[0], -lm * s01 - z[0] * z[1], -lm * s02 - z[0] * z[2])
    r1 = (r0[1], lm * (lp - s11) - z[1] * z[1], -lm * s12 - z[1] * z[2])
    r2 = (r0[2], r1[2], lm * (lp - s22) - z[2] * z[2])
    c0, c1, c2 = _cross(r1, r2), _cross(r2, r0), _cross(r0, r1)
    n0, n1, n2 = _norm2(c0), _norm2(c1), _norm2(c2)
    use0 = (n0 >= n1) & (n0 >= n2)
    best = _pick(use0, c0, _pick(n1 >= n2, c1, c2))
    nbest = _norm2(best)
    e = best
    qv = (lm * e[0], lm * e[1], lm * e[2])
    q4 = z[0] * e[0] + z[1] * e[1] + z[2] * e[2]
    return qv, q4, nbest


def _finish(qv, q4, frame_signs):
    C = wb.matrix_from_shuster_q(*wb.unit_q(qv[0], qv[1], qv[2], q4))
    return C * frame_signs[..., None, :]


def esoq2(w_body, v_ref, weights=None):
    """Optimal attitude by ESOQ2 (Mortari's second estimator of the optimal quaternion).

    Same problem, inputs and output as :func:`shipstar.attitude.quest`; ``lambda_max``
    is found by the same Newton iteration, then the rotation axis from the null space of
    a 3x3 matrix instead of QUEST's linear solve.

    Parameters
    ----------
    w_body, v_ref : array_like, shape (..., N, 3)
    weights : array_like, shape (..., N) or (N,), optional

    Returns
    -------
    C_ref_from_body : ndarray, shape (..., 3, 3)
    """
    w, v, a = wb.prepare(w_body, v_ref, weights)
    B = wb.profile_matrix(w, v, a)
    b = wb.components(B)
    lam, _ = wb.lambda_max(b)
    sols = [_frame_solution(wb.flip(b, i), lam) for i in range(4)]
    if B.ndim == 2:
        k = max(range(4), key=lambda i: sols[i][2])
        qv, q4, _ = sols[k]
    else:
        cond = np.stack([sol[2] for sol in sols], axis=-1)
        k = np.argmax(cond, axis=-1)
        qvs = np.stack([np.stack(sol[0], axis=-1) for sol in sols], axis=-2)
        q4s = np.stack([sol[1] for sol in sols], axis=-1)
        qv = np.take_along_axis(qvs, k[..., None, None], axis=-2)[..., 0, :]
        q4 = np.take_along_axis(q4s, k[..., None], axis=-1)[..., 0]
        qv = (qv[..., 0], qv[..., 1], qv[..., 2])
    # Rayleigh-quotient refinement of lambda_max (see _quest._refined), same frame.
    bk = wb.flip(b, k)
    qv, q4, _ = _frame_solution(bk, wb.rayleigh(bk, qv, q4))
    return _finish(qv, q4, wb.FRAME_SIGNS[k])
