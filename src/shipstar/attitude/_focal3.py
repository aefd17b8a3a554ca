"""Focal length from three stars: seed 004 sec. 3.2 (2), the cubic in t = f^2.

Seed 004's image-plane coordinates ``(X, Y)`` (mm from the principal point, X along
the row to the right, Y up) are shipstar's ``X = (x - x0) * pixel_mm``,
``Y = -(y - y0) * pixel_mm``; the sensor direction of a star is ``[f, Y, X]`` normalised
(docs/conventions.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.units import RAD2ASEC

PAIRS = ((0, 1), (1, 2), (2, 0))


@dataclass(frozen=True)
class FocalLength:
    """Result of :func:`focal_length_from_three_stars` (arrays of shape S for a stack).

    Attributes
    ----------
    solved : bool or ndarray of bool
    reason : str
        Empty when everything solved; otherwise the first failure and how many failed.
    f_mm : float or ndarray
        Focal length (NaN where not solved).
    angle_residual_arcsec : float or ndarray
        Largest of the three ``|interstar angle in the image - in the catalog|`` at
        ``f_mm``.
    candidates_f_mm : ndarray, shape S + (3,)
        Every positive real stationary point of the loss (NaN padded): the roots the
        choice was made from.
    """

    solved: object
    reason: str
    f_mm: object
    angle_residual_arcsec: object
    candidates_f_mm: np.ndarray


def check_triples(xy_mm, u_icrs):
    """Shapes ``(..., 3, 2)`` and ``(..., 3, 3)``; returns float arrays and the unit
    catalog directions."""
    xy = np.asarray(xy_mm, dtype=float)
    u = np.asarray(u_icrs, dtype=float)
    if xy.ndim < 2 or xy.shape[-2:] != (3, 2) or u.shape != xy.shape[:-1] + (3,):
        raise ShipstarError(
            f"xy_mm must have shape (..., 3, 2) and u_icrs (..., 3, 3); got {xy.shape}, {u.shape}")
    with np.errstate(invalid="ignore", divide="ignore"):
        u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    return xy, u


def sensor_dirs(xy, f_mm):
    """Sensor-frame unit directions ``[f, Y, X] / norm``, shape (..., 3, 3)."""
    f = np.broadcast_to(np.asarray(f_mm, dtype=float)[..., None], xy.shape[:-1])
    s = np.stack([f, xy[..., 1], xy[..., 0]], axis=-1)
    return s / np.linalg.norm(s, axis=-1, keepdims=True)


def _pair_rows(xy, u):
    """Rows ``[-1, A, B]`` (coefficients of t^2, t, 1) of the three squared cosine-law
    equations, in units where the longest image baseline is 1; also returns that unit
    and the quantities for the sign check.

    ``cos b_ij = (t + s_ij) / sqrt((t + r_i^2)(t + r_j^2))`` (seed 004 sec. 3.2 (2),
    law of cosines with ``|OQ_i|^2 = t + r_i^2``) squared and divided by ``sin^2 b_ij``:
    ``-t^2 + (d_ij^2 / sin^2 b - r_i^2 - r_j^2) t + (c_ij^2 / sin^2 b - r_i^2 r_j^2) = 0``
    with ``d_ij = |Q_i - Q_j|``, ``c_ij = X_i Y_j - X_j Y_i`` and ``s_ij = Q_i . Q_j``.
    """
    i = [p[0] for p in PAIRS]
    j = [p[1] for p in PAIRS]
    qi, qj = xy[..., i, :], xy[..., j, :]
    d2 = np.sum((qi - qj) ** 2, axis=-1)
    scale2 = np.max(d2, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        qi = qi / np.sqrt(scale2)[..., None]
        qj = qj / np.sqrt(scale2)[..., None]
        d2 = d2 / scale2
        ri2 = np.sum(qi ** 2, axis=-1)
        rj2 = np.sum(qj ** 2, axis=-1)
        c = qi[..., 0] * qj[..., 1] - qj[..., 0] * qi[..., 1]
        sin2 = np.sum(np.cross(u[..., i, :], u[..., j, :]) ** 2, axis=-1)
        rows = np.stack([-np.ones_like(d2), d2 / sin2 - ri2 - rj2, c * c / sin2 - ri2 * rj2], -1)
    sdot = np.sum(qi * qj, axis=-1)
    cosb = np.sum(u[..., i, :] * u[..., j, :], axis=-1)
    return rows, scale2[..., 0], sdot, cosb


def _cubic_real_roots(c3, c2, c1, c0):
    """Real roots (NaN padded), shape S + (3,), of ``c3 t^3 + c2 t^2 + c1 t + c0``.

    Eigenvalues of the companion matrix (the device seed 004 sec. 2.3.2 uses for its
    sextic), then three Newton steps on the cubic itself to polish each real root.
    """
    comp = np.zeros(c3.shape + (3, 3))
    comp[..., 0, 0] = -c2 / c3
    comp[..., 0, 1] = -c1 / c3
    comp[..., 0, 2] = -c0 / c3
    comp[..., 1, 0] = 1.0
    comp[..., 2, 1] = 1.0
    ok = np.all(np.isfinite(comp), axis=(-2, -1))
    comp[~ok] = 0.0
    z = np.linalg.eigvals(comp)
    real = np.abs(z.imag) <= 1e-7 * np.maximum(1.0, np.abs(z.real))
    t = np.where(real & ok[..., None], z.real, np.nan)
    a3, a2, a1, a0 = (x[..., None] for x in (c3, c2, c1, c0))
    for _ in range(3):
        g = ((a3 * t + a2) * t + a1) * t + a0
        gp = (3.0 * a3 * t + 2.0 * a2) * t + a1
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.where(gp != 0.0, t - g / gp, t)
    return t


def interstar_residual_rad(xy, u, f_mm):
    """Largest |image interstar angle - catalog interstar angle| (rad) at ``f_mm``."""
    s = sensor_dirs(xy, f_mm)
    worst = np.zeros(xy.shape[:-2])
    for i, j in PAIRS:
        bi = np.arctan2(np.linalg.norm(np.cross(s[..., i, :], s[..., j, :]), axis=-1),
                        np.sum(s[..., i, :] * s[..., j, :], axis=-1))
        bc = np.arctan2(np.linalg.norm(np.cross(u[..., i, :], u[..., j, :]), axis=-1),
                        np.sum(u[..., i, :] * u[..., j, :], axis=-1))
        worst = np.maximum(worst, np.abs(bi - bc))
    return worst


def focal_length_core(xy, u):
    """Vectorised solver: ``(f_mm, candidates_f_mm, code)`` with code 0 = solved,
    1 = non-finite input, 4 = no positive root consistent with the cosine signs."""
    rows, scale2, sdot, cosb = _pair_rows(xy, u)
    finite = np.all(np.isfinite(rows), axis=(-2, -1)) & (scale2 > 0)
    rows = np.where(finite[..., None, None], rows, 0.0)
    G = np.swapaxes(rows, -1, -2) @ rows
    # d/dt |D [t^2, t, 1]|^2 / 2 = 2 G00 t^3 + 3 G01 t^2 + (G11 + 2 G02) t + G12
    g00 = np.where(finite, G[..., 0, 0], 1.0)
    roots = _cubic_real_roots(2.0 * g00, 3.0 * G[..., 0, 1],
                              G[..., 1, 1] + 2.0 * G[..., 0, 2], G[..., 1, 2])
    tau = np.stack([roots ** 2, roots, np.ones_like(roots)], axis=-1)    # S + (3 roots, 3)
    loss = np.sum((tau @ np.swapaxes(rows, -1, -2)) ** 2, axis=-1)      # S + (3 roots,)
    sign_ok = np.all((roots[..., :, None] + sdot[..., None, :]) * cosb[..., None, :] > 0, -1)
    valid = np.isfinite(roots) & (roots > 0) & sign_ok & finite[..., None]
    loss = np.where(valid, loss, np.inf)
    best = np.argmin(loss, axis=-1)
    t_best = np.take_along_axis(roots, best[..., None], axis=-1)[..., 0]
    any_valid = np.any(valid, axis=-1)
    with np.errstate(invalid="ignore"):
        f = np.where(any_valid, np.sqrt(t_best * scale2), np.nan)
        cand = np.where(valid, np.sqrt(np.where(valid, roots, 0.0) * scale2[..., None]), np.nan)
    code = np.where(~finite, 1, np.where(any_valid, 0, 4))
    return f, cand, code


_MESSAGES = {
    1: "non-finite or coincident input (NaN, or two stars at the same place)",
    4: "no positive root of the cubic in f^2 is consistent with the interstar angles",
    5: "interstar angles do not match at the best focal length (stars misidentified?)",
}


def summarise(code, extra=None):
    """``(solved, reason)`` from integer failure codes (0 = solved)."""
    code = np.asarray(code)
    solved = code == 0
    if np.all(solved):
        reason = ""
    else:
        first = int(code[~solved].flat[0])
        msg = (extra or {}).get(first, _MESSAGES.get(first, "failed"))
        reason = (msg if code.ndim == 0
                  else f"{int((~solved).sum())} of {code.size} failed; first: {msg}")
    return (bool(solved) if code.ndim == 0 else solved), reason


def scalarise(x):
    x = np.asarray(x)
    return float(x) if x.ndim == 0 else x


def focal_length_from_three_stars(xy_mm, u_icrs, *, max_angle_residual_arcsec=60.0):
    """Focal length from three identified stars (seed 004 sec. 3.2 (2)).

    The law of cosines in the triangle (lens centre O, image points Q_i, Q_j) gives
    ``cos b_ij = (t + s_ij) / sqrt((t + r_i^2)(t + r_j^2))`` with ``t = f^2``; squared,
    each star pair is a quadratic in t, ``[d_i1 d_i2 d_i3] . [t^2, t, 1] = e_i`` (seed
    004's D matrix).  Minimising ``|e|^2`` sets its derivative, a **cubic in t**, to
    zero; the cubic is solved in closed form (companion matrix).

    Root choice: of the cubic's real roots, keep those with ``t > 0`` whose
    ``t + s_ij`` has the sign of the catalog's ``cos b_ij`` for all three pairs (the
    squaring lost that sign), and take the one with the smallest ``|e|^2`` (seed 004:
    "when there are several positive roots, the one with the smallest loss").  With
    noise-free data that root makes ``e = 0`` and is the true ``f^2``.  No valid root,
    or interstar angle residuals above ``max_angle_residual_arcsec`` ("loss too large:
    the data do not match"), gives ``solved=False``.

    Parameters
    ----------
    xy_mm : array_like, shape (..., 3, 2)
        Image-plane positions from the principal point, ``X`` right, ``Y`` up (mm).
    u_icrs : array_like, shape (..., 3, 3)
        Catalog directions of the same stars.
    max_angle_residual_arcsec : float or None
        Consistency gate on the interstar angles at the solution; None disables it.

    Returns
    -------
    FocalLength
    """
    xy, u = check_triples(xy_mm, u_icrs)
    f, cand, code = focal_length_core(xy, u)
    with np.errstate(invalid="ignore"):
        resid = interstar_residual_rad(xy, u, np.where(code == 0, f, 1.0)) * RAD2ASEC
    resid = np.where(code == 0, resid, np.nan)
    if max_angle_residual_arcsec is not None:
        code = np.where((code == 0) & (resid > max_angle_residual_arcsec), 5, code)
    f = np.where(code == 0, f, np.nan)
    solved, reason = summarise(code)
    return FocalLength(solved, reason, scalarise(f), scalarise(resid), cand)
