"""Observation model of seed 001 (eq. 1-4) and its exact, closed-form Jacobian.

Observation model, in shipstar's conventions (``docs/conventions.md``)::

    C_hor_from_sensor(As, Es, gs) = C_hor_from_deck(K, psi, theta) @ C_deck_from_sensor(A0, E0, g0)
    =>  C_hor_from_deck = C_hor_from_sensor @ C_deck_from_sensor.T

All three matrices have the Y-Z-X structure ``R_y(a) @ R_z(-b) @ R_x(-c)``.

Derivation of the Jacobian
--------------------------
The passive elementary rotations are ``R_y(a) = exp(-a [e_y x])``,
``R_z(-b) = exp(b [e_z x])`` and ``R_x(-c) = exp(c [e_x x])``.  Differentiating
``C = R_y(a) R_z(-b) R_x(-c)`` gives ``dC C^T = [dphi x]`` with the small-rotation
vector, in the frame C maps *to*::

    dphi = M(a, b) @ [da, db, dc],     M = [ -e_y,  R_y(a) e_z,  C e_x ]
         = columns [0, -1, 0],  [-sin a, 0, cos a],  [cos a cos b, sin b, sin a cos b]

With ``h = [cos a, 0, sin a]`` and ``n = [-sin a, 0, cos a]`` (``e_y, n, h`` is an
orthonormal basis and ``C e_x = cos b h + sin b e_y``) the inverse is, in closed form::

    M^-1 rows:  tan b * h - e_y,    n,    h / cos b

singular only at gimbal lock (cos b = 0).  A perturbation of the two factors,
``dC_hs = [phi_s x] C_hs`` (hor frame) and ``dC_ds = [phi_0 x] C_ds`` (deck frame), moves
``C_hd = C_hs C_ds^T`` by ``[(phi_s - C_hd phi_0) x] C_hd``, hence::

    d(K, psi, theta) = M(K, psi)^-1 @ [ M(As, Es),  -C_hd @ M(A0, E0) ] @ d(As, Es, gs, A0, E0, g0)

Seed 001's printed error factors (eq. 8-38; e.g. ``k_s2 = -C_hd[0, 0]``,
``k_s4 = C_hd[2, 0]``, ``f_b2 = C_hd[1, 0]``) are those of ``C_hd = C_hs @ Y(A0, E0, g0)``,
i.e. the Y-Z-X matrix of the installation angles used *untransposed* (as a
sensor-from-deck matrix), the transpose of the seed's own eq. 4.  That composition is
available as ``convention="seed001-factors"`` so that the seed's figures can be
reproduced; its Jacobian is ``M(K, psi)^-1 @ [M(As, Es), C_hs @ M(A0, E0)]``.
"""

from __future__ import annotations

import numpy as np

from shipstar import frames
from shipstar.errors import ShipstarError

__all__ = [
    "PARAMS", "OUTPUTS", "CONVENTIONS",
    "C_hor_from_sensor_angles", "ship_angles_rad", "ship_matrix",
    "angle_rate_matrix", "inverse_angle_rate_matrix",
    "ship_jacobian", "ship_jacobian_sensor_axes", "propagate_covariance",
]

#: Inputs of the error model, in Jacobian column order: the sensor's horizontal attitude
#: (azimuth, elevation, roll) and its installation angles (azimuth, elevation, roll).
PARAMS = ("As", "Es", "gs", "A0", "E0", "g0")
#: Outputs, in Jacobian row order: ship heading K, pitch psi, roll theta.
OUTPUTS = ("heading", "pitch", "roll")
#: ``"shipstar"``: ``C_hor_from_deck = C_hor_from_sensor @ C_deck_from_sensor(A0, E0, g0).T``
#: (seed 001 eq. 1-4 as printed).  ``"seed001-factors"``: ``C_hor_from_sensor @ Y(A0, E0, g0)``,
#: the composition behind the seed's error factors eq. 8-38 and its figures.
CONVENTIONS = ("shipstar", "seed001-factors")


def _check_convention(convention: str) -> None:
    if convention not in CONVENTIONS:
        raise ShipstarError(f"unknown convention {convention!r}; expected one of {', '.join(CONVENTIONS)}")


def _split3(angles_rad, what: str):
    a = np.asarray(angles_rad, dtype=float)
    if a.shape[-1:] != (3,):
        raise ShipstarError(f"{what} must have a last axis of length 3 (azimuth, elevation, roll), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ShipstarError(f"{what} must be finite")
    return a[..., 0], a[..., 1], a[..., 2]


def C_hor_from_sensor_angles(az_rad, el_rad, roll_rad) -> np.ndarray:
    """Sensor attitude in the horizontal frame from its horizontal azimuth, elevation, roll.

    Same Y-Z-X structure as the ship attitude (``R_y(As) R_z(-Es) R_x(-gs)``, seed 001
    eq. 3); its first column is the boresight ``[cos Es cos As, sin Es, cos Es sin As]``.
    Shape ``S + (3, 3)``.
    """
    return frames.C_hor_from_deck(az_rad, el_rad, roll_rad)


def ship_matrix(sensor_angles_rad, install_angles_rad, convention: str = "shipstar"):
    """``(C_hor_from_deck, C_hor_from_sensor, C_install)`` of the observation model.

    Parameters
    ----------
    sensor_angles_rad : array_like, shape S + (3,)
        Sensor horizontal attitude (As, Es, gs).
    install_angles_rad : array_like, shape S + (3,)
        Installation angles (A0, E0, g0).
    convention : {"shipstar", "seed001-factors"}

    Returns
    -------
    tuple of ndarray, each shape S + (3, 3)
        ``C_install`` is ``C_deck_from_sensor(A0, E0, g0)`` for ``"shipstar"`` and the
        seed's untransposed ``Y(A0, E0, g0)`` (acting as sensor-from-deck) otherwise.
    """
    _check_convention(convention)
    As, Es, gs = _split3(sensor_angles_rad, "sensor angles")
    A0, E0, g0 = _split3(install_angles_rad, "installation angles")
    C_hs = C_hor_from_sensor_angles(As, Es, gs)
    C_inst = frames.C_deck_from_sensor(A0, E0, g0)
    if convention == "shipstar":
        C_hd = C_hs @ np.swapaxes(C_inst, -1, -2)
    else:
        C_hd = C_hs @ C_inst
    return C_hd, C_hs, C_inst


def ship_angles_rad(sensor_angles_rad, install_angles_rad, convention: str = "shipstar") -> np.ndarray:
    """Ship (heading, pitch, roll) through the full nonlinear chain; shape S + (3,).

    Heading in [0, 2 pi); see :func:`shipstar.frames.ship_angles_from_C_hor_from_deck`.
    """
    C_hd, _, _ = ship_matrix(sensor_angles_rad, install_angles_rad, convention)
    return np.stack(frames.ship_angles_from_C_hor_from_deck(C_hd), axis=-1)


def angle_rate_matrix(az_rad, el_rad) -> np.ndarray:
    """``M`` with ``dphi = M @ d(a, b, c)`` for ``C = R_y(a) R_z(-b) R_x(-c)``; shape S + (3, 3).

    ``dphi`` is the small-rotation vector of ``dC C^T = [dphi x]``, in the frame that C
    maps to.  It does not depend on the third angle.
    """
    a = np.asarray(az_rad, float)
    b = np.asarray(el_rad, float)
    a, b = np.broadcast_arrays(a, b)
    ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
    M = np.zeros(a.shape + (3, 3))
    M[..., 1, 0] = -1.0
    M[..., 0, 1] = -sa
    M[..., 2, 1] = ca
    M[..., 0, 2] = ca * cb
    M[..., 1, 2] = sb
    M[..., 2, 2] = sa * cb
    return M


def inverse_angle_rate_matrix(az_rad, el_rad) -> np.ndarray:
    """Closed-form ``M^-1`` of :func:`angle_rate_matrix`: ``d(a, b, c) = M^-1 @ dphi``.

    Rows ``tan b h - e_y``, ``n``, ``h / cos b`` with ``h = [cos a, 0, sin a]``,
    ``n = [-sin a, 0, cos a]``.  Infinite at gimbal lock (cos b = 0): callers flag those
    points with :func:`shipstar.frames.gimbal_lock_mask`.  Shape S + (3, 3).
    """
    a = np.asarray(az_rad, float)
    b = np.asarray(el_rad, float)
    a, b = np.broadcast_arrays(a, b)
    ca, sa, cb = np.cos(a), np.sin(a), np.cos(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        sec = 1.0 / cb
        tb = np.sin(b) * sec
    N = np.zeros(a.shape + (3, 3))
    N[..., 0, 0] = tb * ca
    N[..., 0, 1] = -1.0
    N[..., 0, 2] = tb * sa
    N[..., 1, 0] = -sa
    N[..., 1, 2] = ca
    N[..., 2, 0] = ca * sec
    N[..., 2, 2] = sa * sec
    return N


def _ship_inverse_rate(C_hd):
    # (K, psi) of the ship from the matrix itself; sin/cos of psi directly from C so the
    # result stays exact when the angle extraction is near its singularity.
    K, psi, _ = frames.ship_angles_from_C_hor_from_deck(C_hd)
    return inverse_angle_rate_matrix(K, psi)


def ship_jacobian(sensor_angles_rad, install_angles_rad, convention: str = "shipstar") -> np.ndarray:
    """Exact Jacobian ``d(K, psi, theta) / d(As, Es, gs, A0, E0, g0)``; shape S + (3, 6).

    Rows follow :data:`OUTPUTS`, columns :data:`PARAMS`; rad per rad (so arcsec per
    arcsec).  Closed form (see the module docstring); NaN/inf where the ship is at gimbal
    lock (pitch +-90 deg), which :func:`shipstar.frames.gimbal_lock_mask` flags.
    """
    C_hd, C_hs, C_inst = ship_matrix(sensor_angles_rad, install_angles_rad, convention)
    As, Es, _ = _split3(sensor_angles_rad, "sensor angles")
    A0, E0, _ = _split3(install_angles_rad, "installation angles")
    N = _ship_inverse_rate(C_hd)
    M_s = angle_rate_matrix(As, Es)
    M_0 = angle_rate_matrix(A0, E0)
    if convention == "shipstar":
        phi_0 = -(C_hd @ M_0)
    else:
        phi_0 = C_hs @ M_0
    with np.errstate(invalid="ignore"):
        return N @ np.concatenate([M_s, phi_0], axis=-1)


def ship_jacobian_sensor_axes(C_hor_from_sensor_, C_deck_from_sensor_):
    """Jacobians of (K, psi, theta) w.r.t. small rotations about the SENSOR axes.

    ``G_att``: for an attitude error ``C_hor_from_sensor_meas = C_hor_from_sensor (I + [d x])``
    (``d`` about sensor axes, as :class:`shipstar.attitude.AttitudeSolution` reports its
    covariance).  ``G_inst``: for an installation calibration error
    ``C_deck_from_sensor_cal = C_deck_from_sensor (I + [e x])``.  Since
    ``C_hor_from_deck = C_hor_from_sensor @ C_deck_from_sensor.T``,
    ``d(ship) = M(K, psi)^-1 C_hor_from_sensor (d - e)``: ``G_inst = -G_att``.

    Parameters
    ----------
    C_hor_from_sensor_, C_deck_from_sensor_ : array_like, shape S + (3, 3)

    Returns
    -------
    (G_att, G_inst) : ndarray, each shape S + (3, 3)
    """
    C_hs = np.asarray(C_hor_from_sensor_, float)
    C_ds = np.asarray(C_deck_from_sensor_, float)
    C_hd = C_hs @ np.swapaxes(C_ds, -1, -2)
    with np.errstate(invalid="ignore"):
        G = _ship_inverse_rate(C_hd) @ C_hs
    return G, -G


def propagate_covariance(jacobian, covariance) -> np.ndarray:
    """``J @ P @ J^T`` for stacked Jacobians ``S + (m, n)`` and covariances ``(n, n)`` or ``S + (n, n)``."""
    J = np.asarray(jacobian, float)
    P = np.asarray(covariance, float)
    if P.shape[-2:] != (J.shape[-1], J.shape[-1]):
        raise ShipstarError(f"covariance shape {P.shape} does not match Jacobian shape {J.shape}")
    return J @ P @ np.swapaxes(J, -1, -2)
