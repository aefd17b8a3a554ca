"""Least squares machinery: Levenberg-Marquardt with an optional Huber loss, per-frame
attitudes eliminated frame by frame, and the covariance of the estimate.

Covariance
----------
The residuals of the interstar equations are *not* independent: a star enters every pair
it belongs to.  The estimate is linear in the centroid errors ``e`` (independent,
``sigma_px`` per axis) through ``r = G e``, so for the weighted least-squares step
``dphi = -K A^T W r`` with ``K = (A^T W A)^-1``::

    cov = sigma^2 K (sum_f B_f B_f^T) K,     B_f = A_f^T W_f G_f

(a sandwich; for independent per-star residuals it reduces to ``sigma^2 K``).  The
centroid noise is estimated from the fitted residuals with their exact expectation
``E[r^T W r] = sigma^2 (sum_f tr(G_f^T W_f G_f) - tr(K sum_f B_f B_f^T))``.

Per-frame attitudes (the ``"star"`` equations) are eliminated with the projector
``P_f = I - A_att (A_att^T W A_att)^-1 A_att^T W``; the intrinsic parameters then see
``P_f A_f`` and ``P_f G_f``, which gives the same step and covariance as the full problem
(Schur complement).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shipstar.calibrate._intrinsics_pairs import StarSet, evaluate, tangent_basis

__all__ = ["Fit", "Linearization", "levenberg_marquardt", "linearize", "covariance",
           "rotation_from_vector"]

#: Huber threshold in units of the robust (MAD) residual scale
HUBER_K = 3.0
_MAD_TO_SIGMA = 1.4826


def rotation_from_vector(phi) -> np.ndarray:
    """``exp([phi x])`` by Rodrigues' formula: ``(..., 3)`` -> ``(..., 3, 3)``."""
    phi = np.asarray(phi, float)
    angle = np.linalg.norm(phi, axis=-1)[..., None, None]
    K = np.zeros(phi.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -phi[..., 2], phi[..., 1]
    K[..., 1, 0], K[..., 1, 2] = phi[..., 2], -phi[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -phi[..., 1], phi[..., 0]
    small = angle < 1e-8
    safe = np.where(small, 1.0, angle)
    a = np.where(small, 1.0, np.sin(safe) / safe)
    b = np.where(small, 0.5, (1.0 - np.cos(safe)) / (safe * safe))
    return np.eye(3) + a * K + b * (K @ K)


@dataclass
class Linearization:
    """An evaluation with its weights and (for ``"star"``) the attitudes eliminated."""

    ev: object                    # _intrinsics_pairs.Evaluation
    weights: np.ndarray           # (R,) Huber weights (ones without robust loss)
    r: np.ndarray                 # (R,) residuals, attitude directions projected out
    A: np.ndarray                 # (R, P) likewise
    Naa: np.ndarray | None = None         # (F, 3, 3) attitude normal matrices
    coef_r: np.ndarray | None = None      # (F, 3) N_aa^-1 A_att^T W r per frame
    coef_A: np.ndarray | None = None      # (F, 3, P)

    def attitude_step(self, step_theta) -> np.ndarray:
        """Best attitude change (F, 3) that goes with an intrinsic step (linearised)."""
        return -(self.coef_r + self.coef_A @ step_theta)

    def frame_G(self, f: int) -> np.ndarray:
        """``P_f G_f``: the frame's residuals by its centroids, attitude projected out."""
        G = self.ev.frame_G(f)
        if self.Naa is None:
            return G
        rows = self.ev.frame_rows(f)
        Aa = self.ev.A_att[rows]
        WG = G * self.weights[rows][:, None]
        return G - Aa @ np.linalg.solve(self.Naa[f], Aa.T @ WG)


@dataclass(frozen=True)
class Fit:
    """Result of :func:`levenberg_marquardt`."""

    theta: np.ndarray              # natural units, free parameters
    attitudes: np.ndarray | None   # (F, 3, 3) C_ref_from_sensor ("star" kind)
    lin: Linearization             # at the solution
    iterations: int
    converged: bool
    cost: float
    huber_threshold: float         # residual size where the loss turns linear (inf: none)


def _huber_threshold(r, robust: bool) -> float:
    if not robust or r.size == 0:
        return np.inf
    scale = _MAD_TO_SIGMA * float(np.median(np.abs(r)))
    return HUBER_K * scale if scale > 0.0 else np.inf


def _weights(r, k: float) -> np.ndarray:
    if not np.isfinite(k):
        return np.ones_like(r)
    return np.minimum(1.0, k / np.maximum(np.abs(r), 1e-300))


def _cost(r, k: float) -> float:
    """Huber cost: ``r^2`` inside ``|r| <= k``, ``2 k |r| - k^2`` outside."""
    a = np.abs(r)
    if np.isfinite(k):
        return float(np.sum(np.where(a <= k, a * a, 2.0 * k * a - k * k)))
    return float(a @ a)


def _linearize(ev, weights) -> Linearization:
    if ev.kind != "star":
        return Linearization(ev, weights, ev.r, ev.A)
    Aa, w, starts = ev.A_att, weights, ev.row_starts
    row_frame = np.repeat(np.arange(len(starts)), ev.row_counts)
    WAa = Aa * w[:, None]
    Naa = np.add.reduceat(WAa[:, :, None] * Aa[:, None, :], starts, axis=0)      # (F, 3, 3)
    b_r = np.add.reduceat(WAa * ev.r[:, None], starts, axis=0)                   # (F, 3)
    b_A = np.add.reduceat(WAa[:, :, None] * ev.A[:, None, :], starts, axis=0)    # (F, 3, P)
    coef_r = np.linalg.solve(Naa, b_r[..., None])[..., 0]
    coef_A = np.linalg.solve(Naa, b_A)
    r = ev.r - np.einsum("rk,rk->r", Aa, coef_r[row_frame])
    A = ev.A - np.einsum("rk,rkp->rp", Aa, coef_A[row_frame])
    return Linearization(ev, weights, r, A, Naa, coef_r, coef_A)


class _Problem:
    """Evaluates one kind of equations for a parameter space over a star set."""

    def __init__(self, stars: StarSet, space, kind: str):
        self.stars, self.space, self.kind = stars, space, kind
        self.bases = tangent_basis(stars.v_ref) if kind == "star" else None

    def evaluate(self, theta, attitudes):
        full = self.space.full(theta)
        return evaluate(self.stars, full, self.space.base.pixel_mm, self.space.free, self.kind,
                        attitudes, self.bases)

    def trial(self, theta, attitudes, lin, step_theta):
        """Parameters and evaluation after a step, or None where the model breaks down."""
        new_theta = theta + step_theta
        new_att = None
        if self.kind == "star":
            new_att = attitudes @ rotation_from_vector(lin.attitude_step(step_theta))
        try:
            ev = self.evaluate(new_theta, new_att)
        except ValueError:        # ShipstarError: e.g. a distortion the camera cannot invert
            return None
        if not (np.isfinite(ev.r).all() and np.isfinite(ev.A).all()):
            return None
        return new_theta, new_att, ev


def levenberg_marquardt(stars: StarSet, space, theta0, kind: str, *, attitudes0=None,
                        robust: bool = False, max_iter: int = 50, tol_px: float = 1e-6) -> Fit:
    """Minimise the (Huber) cost of the ``kind`` equations over the free parameters.

    Steps are taken in scaled parameters (``space.scales``; ``tol_px``: stop when no
    parameter moves an edge star by more than this).  For ``kind == "star"`` the
    per-frame attitudes start at ``attitudes0`` (F, 3, 3) and move with the intrinsics.
    With ``robust`` the Huber threshold is ``HUBER_K`` times the residuals' MAD scale,
    re-estimated every iteration.
    """
    prob = _Problem(stars, space, kind)
    scales = space.scales
    theta = np.asarray(theta0, float).copy()
    att = np.array(attitudes0, float) if kind == "star" else None
    ev = prob.evaluate(theta, att)
    if not (np.isfinite(ev.r).all() and np.isfinite(ev.A).all()):
        raise FloatingPointError("the starting camera cannot map every centroid")
    lam = 1e-4
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        k = _huber_threshold(ev.r, robust)
        lin = _linearize(ev, _weights(ev.r, k))
        cost = _cost(ev.r, k)
        As = lin.A * scales
        WAs = As * lin.weights[:, None]
        N = As.T @ WAs
        g = WAs.T @ lin.r
        diag = np.diag(N).copy()
        diag[~(diag > 0)] = 1.0
        accepted = False
        step = np.zeros_like(theta)
        for _ in range(30):
            try:
                step = -np.linalg.solve(N + lam * np.diag(diag), g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            trial = prob.trial(theta, att, lin, step * scales)
            if trial is not None and _cost(trial[2].r, k) <= cost:
                theta, att, ev = trial
                lam = max(lam * 0.1, 1e-12)
                accepted = True
                break
            lam *= 10.0
        small = float(np.max(np.abs(step), initial=0.0)) < tol_px
        if not accepted or small:
            converged = small
            break
    k = _huber_threshold(ev.r, robust)
    lin = _linearize(ev, _weights(ev.r, k))
    return Fit(theta, att, lin, it, converged, _cost(ev.r, k), k)


def linearize(stars: StarSet, space, theta, kind: str, *, attitudes=None,
              robust: bool = False) -> Linearization:
    """The linearisation at ``theta`` (no step taken)."""
    prob = _Problem(stars, space, kind)
    ev = prob.evaluate(np.asarray(theta, float), attitudes)
    return _linearize(ev, _weights(ev.r, _huber_threshold(ev.r, robust)))


def covariance(lin: Linearization, scales):
    """Covariance of the free parameters (natural units) and the centroid noise.

    Returns
    -------
    cov : ndarray (P, P)
    sigma_px : float
        Estimated centroid noise per axis.
    normal : ndarray (P, P)
        ``A^T W A`` in scaled parameters (for the degeneracy check).
    """
    P = len(scales)
    As = lin.A * scales
    w = lin.weights
    N = As.T @ (As * w[:, None])
    M = np.zeros((P, P))
    trace_g = 0.0
    for f in range(len(lin.ev.row_starts)):
        rows = lin.ev.frame_rows(f)
        G = lin.frame_G(f)
        WG = G * w[rows][:, None]
        B = As[rows].T @ WG
        M += B @ B.T
        trace_g += float(np.sum(G * WG))
    rwr = float(np.sum(w * lin.r * lin.r))
    K = np.linalg.inv(N)
    dof = trace_g - float(np.trace(K @ M))
    sigma2 = rwr / dof if dof > 0 else float("nan")
    cov = sigma2 * (K @ M @ K) * np.outer(scales, scales)
    return cov, float(np.sqrt(sigma2)), N
