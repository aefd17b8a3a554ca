"""Boresight from three identified stars: seed 004 ch. 2-3 (sec. 2.1, 3.1, 3.2).

Seed 004 works in a camera frame with the boresight along Z and image-plane
coordinates ``(X, Y)`` in mm; shipstar maps it (docs/conventions.md): ``X = (x - x0) *
pixel_mm`` to the right, ``Y = -(y - y0) * pixel_mm`` up, and a star's sensor direction
is ``[f, Y, X] / norm`` with the boresight along sensor +X.  The seed's frame is that one
with two axes swapped (a mirror), which is why ``C_icrs_from_sensor`` here is built in
shipstar's proper frame; the boresight is the same.

Collinear image stars are coplanar catalog directions (the gnomonic projection maps
great circles to lines), so seed 004's matrix ``P`` of catalog directions is singular:
sec. 2.1.2 case (2) then has two mirror-image boresights.  These functions report that
as ``solved=False`` instead of picking one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shipstar.attitude._focal3 import (
    check_triples, focal_length_core, interstar_residual_rad, scalarise, sensor_dirs, summarise,
)
from shipstar.errors import ShipstarError
from shipstar.frames import orthonormalize, ra_dec_from_unit
from shipstar.units import RAD2ASEC

#: Default collinearity gate: a triple whose third star lies within this angle (rad) of
#: the great circle through the other two (in the catalog or in the image) is collinear.
COLLINEAR_TOL_RAD = 1e-6

_MESSAGES = {
    1: "non-finite or coincident input (NaN, or two stars at the same place)",
    2: "stars collinear (catalog directions coplanar): seed 004 sec. 2.1.2 case (2), "
       "two mirror-image boresights, no unique answer",
    3: "stars collinear in the image (sensor directions coplanar) but not in the catalog",
    4: "no positive root of the cubic in f^2 is consistent with the interstar angles",
    5: "interstar angles do not match the catalog (stars misidentified?)",
}


@dataclass(frozen=True)
class ThreeStarSolution:
    """Boresight from one triple of stars, or from a stack S of triples.

    Attributes
    ----------
    solved : bool or ndarray of bool, shape S
    reason : str
        Empty when everything solved; otherwise the first failure (and the count).
    boresight_icrs : ndarray, shape S + (3,)
        Unit boresight (sensor +X) in ICRS: seed 004's point D, ``^0w``.
    ra_rad, dec_rad : float or ndarray, shape S
        Boresight right ascension in [0, 2 pi) and declination.
    f_mm : float or ndarray, shape S
        Focal length used (given, or recovered from the cubic).
    C_icrs_from_sensor : ndarray, shape S + (3, 3)
        Full sensor attitude (NaN for the radius-only method, which has no roll).
    error_bound_rad_per_mm : float or ndarray, shape S
        Seed 004's first-order error bound ``||(I - w w^T) P^-1 N_3||_F`` (rad of
        boresight error per mm of centroid error); see :func:`three_star_error_bound`.
    """

    solved: object
    reason: str
    boresight_icrs: np.ndarray
    ra_rad: object
    dec_rad: object
    f_mm: object
    C_icrs_from_sensor: np.ndarray
    error_bound_rad_per_mm: object


def _out_of_plane_rad(d):
    """Angle of the third direction from the great circle of the most separated pair,
    ``|det| / max |d_i x d_j|``; shape S for directions S + (3, 3)."""
    det = np.abs(np.linalg.det(d))
    cross = np.stack([np.linalg.norm(np.cross(d[..., i, :], d[..., j, :]), axis=-1)
                      for i, j in ((0, 1), (1, 2), (2, 0))], axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return det / np.max(cross, axis=-1)


def _check_f(f_mm, shape):
    f = np.broadcast_to(np.asarray(f_mm, dtype=float), shape)
    if not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise ShipstarError("f_mm must be finite and > 0")
    return f


def _geometry_codes(u, s, tol):
    finite = np.all(np.isfinite(u), axis=(-2, -1)) & np.all(np.isfinite(s), axis=(-2, -1))
    with np.errstate(invalid="ignore"):
        cat = _out_of_plane_rad(np.where(finite[..., None, None], u, 1.0))
        img = _out_of_plane_rad(np.where(finite[..., None, None], s, 1.0))
        code = np.where(~finite | ~np.isfinite(cat), 1,
                        np.where(cat < tol, 2, np.where(img < tol, 3, 0)))
    return code, finite


def _safe_inv(P, good):
    return np.linalg.inv(np.where(good[..., None, None], P, np.eye(3)))


def _bound(P_inv, w, xy, f):
    """``||(I - w w^T) P^-1 N_3||_F`` with ``N_3`` the derivatives of
    ``b_i = f / sqrt(f^2 + X_i^2 + Y_i^2)`` by ``(X_i, Y_i)`` (seed 004 sec. 3.3.1).

    ``||N_3 row i||^2 = f^2 r_i^2 / (f^2 + r_i^2)^3``; the derivative of the normalised
    ``P^-1 b`` adds the projector and the ``1 / |P^-1 b|`` factor.
    """
    r2 = np.sum(xy ** 2, axis=-1)
    f2 = (f ** 2)[..., None]
    dn2 = f2 * r2 / (f2 + r2) ** 3                                        # S + (3,)
    cols = P_inv - w[..., :, None] * np.sum(w[..., :, None] * P_inv, axis=-2, keepdims=True)
    return np.sqrt(np.sum(np.sum(cols ** 2, axis=-2) * dn2, axis=-1))


def _radial_cos(r2, f):
    return f[..., None] / np.sqrt(f[..., None] ** 2 + r2)


def _finish(code, w, C, f, bound, messages):
    ok = code == 0
    w = np.where(ok[..., None], w, np.nan)
    C = np.where(ok[..., None, None], C, np.nan)
    ra, dec = ra_dec_from_unit(w)
    solved, reason = summarise(code, messages)
    return ThreeStarSolution(solved, reason, w, scalarise(ra), scalarise(dec),
                             scalarise(np.where(ok, f, np.nan)), C,
                             scalarise(np.where(ok, bound, np.nan)))


def boresight_from_three_radii(radius_mm, f_mm, u_icrs, *, collinear_tol_rad=COLLINEAR_TOL_RAD):
    """Boresight from three stars' radial distances (seed 004 sec. 2.1, scalar ``a_i``).

    Each star's angle from the boresight is known from its image radius ``a_i``:
    ``p_i . w = cos g_i = f / sqrt(f^2 + a_i^2)`` (eq. 2-1), i.e. ``P w = b``
    (eq. 2-2, rows of P the catalog directions); the solution is the normalised
    ``P^-1 b`` (eq. 2-3, "normalisation" variant I).  Roll is not determined.

    Parameters
    ----------
    radius_mm : array_like, shape (..., 3)
        Distances of the star images from the principal point (mm).
    f_mm : float or array_like, shape (...)
        Focal length (mm).
    u_icrs : array_like, shape (..., 3, 3)
        Catalog directions (rows).
    collinear_tol_rad : float
        Collinearity gate (see module docstring).

    Returns
    -------
    ThreeStarSolution
        ``C_icrs_from_sensor`` is NaN (no roll from radii alone).
    """
    a = np.asarray(radius_mm, dtype=float)
    xy = np.stack([a, np.zeros_like(a)], axis=-1)
    xy, u = check_triples(xy, u_icrs)
    f = _check_f(f_mm, xy.shape[:-2])
    code, finite = _geometry_codes(u, u, collinear_tol_rad)
    code = np.where(finite & np.all(np.isfinite(a), -1) & np.all(a >= 0, -1), code, 1)
    good = code == 0
    P_inv = _safe_inv(u, good)
    raw = np.einsum("...ij,...j->...i", P_inv, _radial_cos(a ** 2, f))
    norm = np.linalg.norm(raw, axis=-1, keepdims=True)
    w = raw / norm
    bound = _bound(P_inv / norm[..., None], w, xy, f)
    return _finish(code, w, np.full(w.shape + (3,), np.nan), f, bound, _MESSAGES)


def boresight_from_three_stars(xy_mm, f_mm, u_icrs, *, collinear_tol_rad=COLLINEAR_TOL_RAD,
                               max_angle_residual_arcsec=60.0):
    """Sensor attitude and boresight from three stars (seed 004 sec. 3.1 and 3.2).

    Known focal length (sec. 3.1, vector ``a_i``): the sensor directions
    ``s_i = [f, Y_i, X_i] / norm`` and catalog directions ``u_i`` satisfy
    ``u_i = C s_i``, so ``C = P^-1 S`` (rows of P: ``u_i``, rows of S: ``s_i``; the
    seed's eq. 3-1 ``R = c P^-1`` for the inverse rotation), made orthogonal by SVD
    (``U V^T``, "normalisation" variant I); the boresight is its first column.

    Unknown focal length (``f_mm=None``, sec. 3.2 (2)): f first from the cubic in
    ``f^2`` (:func:`focal_length_from_three_stars`), then as above.

    Parameters
    ----------
    xy_mm : array_like, shape (..., 3, 2)
        Image-plane positions from the principal point, X right, Y up (mm).
    f_mm : float, array_like of shape (...), or None
        Focal length (mm); None to recover it from the three interstar angles.
    u_icrs : array_like, shape (..., 3, 3)
        Catalog directions (rows) of the same three stars.
    collinear_tol_rad : float
        Collinearity gate (see module docstring).
    max_angle_residual_arcsec : float or None
        The image's three interstar angles (at the given or recovered f) must match the
        catalog's within this, else the stars are taken as misidentified
        (``solved=False``); None disables the check.

    Returns
    -------
    ThreeStarSolution
        ``solved=False`` for collinear stars, non-finite input, mismatched interstar
        angles, or (unknown f) no admissible root of the cubic.
    """
    xy, u = check_triples(xy_mm, u_icrs)
    if f_mm is None:
        f, _, fcode = focal_length_core(xy, u)
        f = np.where(fcode == 0, f, 1.0)
    else:
        f = _check_f(f_mm, xy.shape[:-2])
        fcode = np.zeros(xy.shape[:-2], dtype=int)
    s = sensor_dirs(xy, f)
    code, _ = _geometry_codes(u, s, collinear_tol_rad)
    code = np.where(fcode != 0, fcode, code)
    if max_angle_residual_arcsec is not None:
        with np.errstate(invalid="ignore"):
            resid = interstar_residual_rad(xy, u, f) * RAD2ASEC
        code = np.where((code == 0) & ~(resid <= max_angle_residual_arcsec), 5, code)
    good = code == 0
    P_inv = _safe_inv(u, good)
    C = orthonormalize(P_inv @ np.where(good[..., None, None], s, np.eye(3)))
    raw = np.einsum("...ij,...j->...i", P_inv, s[..., :, 0])
    norm = np.linalg.norm(raw, axis=-1, keepdims=True)
    bound = _bound(P_inv / norm[..., None], raw / norm, xy, f)
    return _finish(code, C[..., :, 0], C, f, bound, _MESSAGES)


def three_star_error_bound(xy_mm, f_mm, u_icrs, *, collinear_tol_rad=COLLINEAR_TOL_RAD):
    """Seed 004's error bound for a triple (sec. 2.3.1 / 3.3.1), rad per mm.

    To first order the boresight ``w = P^-1 b / |P^-1 b|`` moves by ``M dXY`` with
    ``M = (I - w w^T) P^-1 N_3 / |P^-1 b|`` and ``N_3`` the 3x6 block-diagonal
    derivatives of ``b_i = f / sqrt(f^2 + X_i^2 + Y_i^2)`` by the centroid
    coordinates.  ``|M dXY| <= ||M|| |dXY|``; this returns ``||M||_F`` (which is also
    the RMS boresight error per mm for isotropic centroid noise).  The seed writes
    ``(P^-1)^T N_3`` in 3.3.1; with P's rows the catalog directions the propagation is
    through ``P^-1``, and the projector (from its sec. 2.3.1) removes the harmless
    component along ``w``.

    Parameters
    ----------
    xy_mm : array_like, shape (..., 3, 2)
    f_mm : float or array_like, shape (...)
    u_icrs : array_like, shape (..., 3, 3)
    collinear_tol_rad : float
        Triples collinear within this angle get ``inf`` (as the solvers refuse them).

    Returns
    -------
    float or ndarray, shape (...)
        ``inf`` for collinear triples, NaN for non-finite input.
    """
    xy, u = check_triples(xy_mm, u_icrs)
    f = _check_f(f_mm, xy.shape[:-2])
    s = sensor_dirs(xy, f)
    code, _ = _geometry_codes(u, s, collinear_tol_rad)
    good = code == 0
    P_inv = _safe_inv(u, good)
    raw = np.einsum("...ij,...j->...i", P_inv, s[..., :, 0])
    norm = np.linalg.norm(raw, axis=-1, keepdims=True)
    bound = _bound(P_inv / norm[..., None], raw / norm, xy, f)
    finite = np.all(np.isfinite(xy), axis=(-2, -1)) & np.all(np.isfinite(u), axis=(-2, -1))
    return scalarise(np.where(finite, np.where(good, bound, np.inf), np.nan))
