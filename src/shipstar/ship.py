"""Ship heading, pitch and roll from calibrated star sensors, and fusion of two sensors.

Seed 003 eq. 14-17: ``C_hor_from_deck = C_hor_from_sensor @ C_deck_from_sensor.T`` and the
angles by :func:`shipstar.frames.ship_angles_from_C_hor_from_deck`.  Two fusions:

``fuse_seed_rule``
    seed 003 eq. 3-5: heading = mean of the two sensors' headings, pitch from the
    fore-aft sensor, roll from the athwartship sensor.
``fuse_joint``
    one weighted attitude problem for the deck frame from both sensors' star vectors at
    once (each mapped to the deck frame by its installation matrix).  It is the
    minimum-variance solution: each sensor's weak roll-about-boresight axis is fixed by
    the other's stars.

Covariances are 3x3 over (heading, pitch, roll) in rad^2, propagated from the attitude
covariance about the deck (body) axes with the analytic Jacobian of the angle extraction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.frames import gimbal_lock_mask, ship_angles_from_C_hor_from_deck, wrap_2pi, wrap_pi

__all__ = [
    "ShipAttitude",
    "SensorStars",
    "ship_attitude_from_sensor",
    "fuse_seed_rule",
    "fuse_joint",
    "ship_angles_jacobian",
]

_NAN33 = np.full((3, 3), np.nan)


@dataclass(frozen=True)
class ShipAttitude:
    """Ship attitude at one instant.

    Attributes
    ----------
    solved : bool
    reason : str
        Why not solved ('' when solved).
    heading_rad, pitch_rad, roll_rad : float
        Seed 001 eq. 2 angles (conventions.md); NaN when not solved.
    C_hor_from_deck : ndarray, shape (3, 3)
    covariance_rad2 : ndarray, shape (3, 3)
        Covariance of (heading, pitch, roll).
    method : str
        ``"single"``, ``"seed-rule"`` or ``"joint"``.
    gimbal_locked : bool
        Pitch within 1e-6 rad of +-90 deg: heading and roll are not separable.
    n_stars : int
        Stars used.
    """

    solved: bool
    reason: str
    heading_rad: float = float("nan")
    pitch_rad: float = float("nan")
    roll_rad: float = float("nan")
    C_hor_from_deck: np.ndarray = field(default_factory=lambda: _NAN33.copy())
    covariance_rad2: np.ndarray = field(default_factory=lambda: _NAN33.copy())
    method: str = ""
    gimbal_locked: bool = False
    n_stars: int = 0

    @property
    def sigma_rad(self) -> np.ndarray:
        """1-sigma of (heading, pitch, roll), shape (3,)."""
        return np.sqrt(np.diag(self.covariance_rad2))

    @classmethod
    def failed(cls, reason: str, method: str) -> "ShipAttitude":
        return cls(solved=False, reason=reason, method=method)


@dataclass(frozen=True)
class SensorStars:
    """One sensor's matched stars at one instant, for the joint solution.

    Attributes
    ----------
    w_sensor : ndarray, shape (N, 3)
        Measured unit vectors in the sensor frame.
    v_hor : ndarray, shape (N, 3)
        The same stars' observed (refracted) directions in the horizontal frame.
    C_deck_from_sensor : ndarray, shape (3, 3)
        The sensor's calibrated installation matrix.
    sigma_rad : float or ndarray, shape (N,)
        Per-star angular measurement error (1-sigma, per axis).
    info_per_rad2 : ndarray, shape (N, 3, 3), optional
        Per-star information matrices of ``w_sensor`` (sensor frame, rad^-2) when the errors
        differ between the two axes across a direction (streaks); the joint solution then
        weights each axis by its own error.  ``sigma_rad`` still sets the outlier threshold.
    model_covariance_rad2 : ndarray, shape (3, 3), optional
        An error common to all these stars (sensor axes, rad^2: the streak model's,
        ``pipeline._exposure.streak_model_covariance``), which no per-star weight can
        carry; the joint covariance gains it through the weight the sensor has in the
        solution.
    mount_covariance_rad2 : ndarray, shape (3, 3), optional
        The uncertainty of the installation these stars are carried with (deck axes, rad^2:
        a flexing mount's estimate, ``pipeline._mounts``), a rotation common to all of them;
        the joint solution weights the sensor accordingly (:func:`_with_mount_errors`).
    """

    w_sensor: np.ndarray
    v_hor: np.ndarray
    C_deck_from_sensor: np.ndarray
    sigma_rad: float | np.ndarray
    info_per_rad2: np.ndarray | None = None
    model_covariance_rad2: np.ndarray | None = None
    mount_covariance_rad2: np.ndarray | None = None


def ship_angles_jacobian(C_hor_from_deck) -> np.ndarray:
    """d(heading, pitch, roll) / d(phi), phi a small rotation about the deck axes.

    The perturbed attitude is ``C_hor_from_deck @ (I + [phi x])``.

    Parameters
    ----------
    C_hor_from_deck : array_like, shape (..., 3, 3)

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Rows (heading, pitch, roll), columns (phi_x, phi_y, phi_z).  Heading and roll
        rows are infinite at gimbal lock.
    """
    C = np.asarray(C_hor_from_deck, float)
    if C.shape == (3, 3):
        J = _angles_jacobian_one(C)
        if J is not None:
            return J
    # dC = C @ [phi x]:   dC[:, 0] = C[:,1] phi_z - C[:,2] phi_y
    #                     dC[:, 1] = C[:,2] phi_x - C[:,0] phi_z
    #                     dC[:, 2] = C[:,0] phi_y - C[:,1] phi_x
    # derivative of column j w.r.t. phi_k, for k = x, y, z:
    zero = np.zeros(C.shape[:-1])
    dcol0 = np.stack([zero, -C[..., :, 2], C[..., :, 1]], axis=-1)  # (..., 3 rows, 3 phis)
    dcol1 = np.stack([C[..., :, 2], zero, -C[..., :, 0]], axis=-1)
    dcol2 = np.stack([-C[..., :, 1], C[..., :, 0], zero], axis=-1)
    c00, c20 = C[..., 0, 0], C[..., 2, 0]
    c11, c12 = C[..., 1, 1], C[..., 1, 2]
    h2 = c00**2 + c20**2
    dK = (c00[..., None] * dcol0[..., 2, :] - c20[..., None] * dcol0[..., 0, :]) / h2[..., None]
    dpsi = dcol0[..., 1, :] / np.sqrt(h2)[..., None]
    r2 = c11**2 + c12**2
    dtheta = -(c11[..., None] * dcol2[..., 1, :] - c12[..., None] * dcol1[..., 1, :]) / r2[..., None]
    return np.stack([dK, dpsi, dtheta], axis=-2)


def _angles_jacobian_one(C) -> np.ndarray | None:
    """:func:`ship_angles_jacobian` of one (3, 3) matrix in plain floats: the array
    path's operations on its nonzero terms, in its order (the fusion makes several every
    epoch); None at exact gimbal lock, whose infinite and undefined rows are the array
    path's (Python's floats raise on a division by zero)."""
    (c00, c01, c02), (c10, c11, c12), (c20, c21, c22) = C.tolist()
    h2 = c00 * c00 + c20 * c20
    r2 = c11 * c11 + c12 * c12
    if h2 == 0.0 or r2 == 0.0:
        return None
    h = math.sqrt(h2)
    # dcol0 = [[0, -c02, c01], [0, -c12, c11], [0, -c22, c21]] (rows: C's rows; columns: phi)
    # dcol1 row 1 = [c12, 0, -c10]; dcol2 row 1 = [-c11, c10, 0]
    dK = [(c00 * 0.0 - c20 * 0.0) / h2, (c00 * -c22 - c20 * -c02) / h2, (c00 * c21 - c20 * c01) / h2]
    dpsi = [0.0 / h, -c12 / h, c11 / h]
    dtheta = [-(c11 * -c11 - c12 * c12) / r2, -(c11 * c10 - c12 * 0.0) / r2, -(c11 * 0.0 - c12 * -c10) / r2]
    return np.array([dK, dpsi, dtheta])


def _from_C(C_hor_from_deck, cov_body_rad2, method: str, n_stars: int) -> ShipAttitude:
    C = np.asarray(C_hor_from_deck, float)
    K, psi, theta = ship_angles_from_C_hor_from_deck(C)
    locked = bool(gimbal_lock_mask(C))
    if cov_body_rad2 is None or locked:
        cov = _NAN33.copy()
    else:
        J = ship_angles_jacobian(C)
        cov = J @ np.asarray(cov_body_rad2, float) @ J.T
    return ShipAttitude(
        solved=True, reason="", heading_rad=float(K), pitch_rad=float(psi), roll_rad=float(theta),
        C_hor_from_deck=C, covariance_rad2=cov, method=method, gimbal_locked=locked, n_stars=n_stars,
    )


def ship_attitude_from_sensor(C_hor_from_sensor, C_deck_from_sensor, covariance_sensor_rad2=None,
                              n_stars: int = 0) -> ShipAttitude:
    """Ship attitude from one calibrated sensor (seed 003 eq. 14-17).

    Parameters
    ----------
    C_hor_from_sensor : array_like, shape (3, 3)
        The sensor's attitude in the horizontal frame (from its refracted star vectors).
    C_deck_from_sensor : array_like, shape (3, 3)
        Its installation matrix.
    covariance_sensor_rad2 : array_like, shape (3, 3), optional
        Attitude error covariance about the sensor axes (as
        :class:`shipstar.attitude.AttitudeSolution` reports it).

    Returns
    -------
    ShipAttitude
    """
    C_hs = np.asarray(C_hor_from_sensor, float)
    C_ds = np.asarray(C_deck_from_sensor, float)
    if C_hs.shape != (3, 3) or C_ds.shape != (3, 3) or not (np.isfinite(C_hs).all() and np.isfinite(C_ds).all()):
        raise ShipstarError("sensor attitude and installation matrix must be finite 3x3 rotation matrices")
    C_hd = C_hs @ C_ds.T
    cov_deck = None
    if covariance_sensor_rad2 is not None:
        # a small rotation about sensor axes is C_ds @ phi about deck axes
        cov_deck = C_ds @ np.asarray(covariance_sensor_rad2, float) @ C_ds.T
    return _from_C(C_hd, cov_deck, "single", n_stars)


def _circular_mean(a_rad, b_rad):
    return float(wrap_2pi(a_rad + 0.5 * wrap_pi(b_rad - a_rad)))


def fuse_seed_rule(fore_aft: ShipAttitude, athwartship: ShipAttitude) -> ShipAttitude:
    """Seed 003's fusion: heading averaged, pitch from the fore-aft sensor, roll from the
    athwartship sensor.

    The two inputs' errors are taken as independent.  The resulting matrix is rebuilt from
    the fused angles.
    """
    from shipstar.frames import C_hor_from_deck

    if not (fore_aft.solved and athwartship.solved):
        which = "fore-aft" if not fore_aft.solved else "athwartship"
        reason = fore_aft.reason if not fore_aft.solved else athwartship.reason
        return ShipAttitude.failed(f"{which} sensor not solved: {reason}", "seed-rule")
    K = _circular_mean(fore_aft.heading_rad, athwartship.heading_rad)
    psi, theta = fore_aft.pitch_rad, athwartship.roll_rad
    P1, P2 = fore_aft.covariance_rad2, athwartship.covariance_rad2
    cov = np.array([
        [0.25 * (P1[0, 0] + P2[0, 0]), 0.5 * P1[0, 1], 0.5 * P2[0, 2]],
        [0.5 * P1[1, 0], P1[1, 1], 0.0],
        [0.5 * P2[2, 0], 0.0, P2[2, 2]],
    ])
    C = C_hor_from_deck(K, psi, theta)
    return ShipAttitude(
        solved=True, reason="", heading_rad=K, pitch_rad=float(psi), roll_rad=float(theta),
        C_hor_from_deck=C, covariance_rad2=cov, method="seed-rule",
        gimbal_locked=bool(gimbal_lock_mask(C)), n_stars=fore_aft.n_stars + athwartship.n_stars,
    )


def fuse_joint(sensors: Sequence[SensorStars], *, reject_outliers: bool = True) -> ShipAttitude:
    """Joint deck attitude from all sensors' stars at once.

    Solves ``v_hor_i = C_hor_from_deck @ (C_deck_from_sensor_s @ w_i)`` for every star i of
    every sensor s, weighted by ``1 / sigma_i^2``, with :func:`shipstar.attitude.solve_attitude`.

    Parameters
    ----------
    sensors : sequence of SensorStars
        One entry per sensor (frames paired in time by the caller).

    Returns
    -------
    ShipAttitude
        With method ``"joint"`` and the covariance of (heading, pitch, roll).
    """
    from shipstar.attitude import solve_attitude
    from shipstar.attitude._solve import per_vector

    if len(sensors) == 0:
        return ShipAttitude.failed("no sensor data", "joint")
    w_deck, v_hor, sigma, turned = [], [], [], []
    for s in sensors:
        w = np.atleast_2d(np.asarray(s.w_sensor, float))
        v = np.atleast_2d(np.asarray(s.v_hor, float))
        if w.shape != v.shape or w.shape[-1] != 3:
            raise ShipstarError(f"sensor star arrays must both be (N, 3), got {w.shape} and {v.shape}")
        C_ds = np.asarray(s.C_deck_from_sensor, float)
        wd_info = _turned_to_deck(w, s.info_per_rad2, C_ds)
        w_deck.append(w @ C_ds.T if wd_info is None else wd_info[0])
        turned.append(None if wd_info is None else wd_info[1])
        v_hor.append(v)
        sigma.append(per_vector(s.sigma_rad, w.shape[0]))
    w_all, v_all, sig_all = np.concatenate(w_deck), np.concatenate(v_hor), np.concatenate(sigma)
    anisotropic = any(s.info_per_rad2 is not None for s in sensors)
    # the stars' information matrices (deck axes): given by the solver when anisotropic,
    # needed besides only to eliminate mount errors (the common-mode term of isotropic
    # stars uses their sigmas)
    mounts = any(s.mount_covariance_rad2 is not None for s in sensors)
    info = _deck_information(sensors, w_deck, sigma, turned) if anisotropic or mounts else None
    sol = solve_attitude(w_all, v_all, sigma_rad=sig_all, reject_outliers=reject_outliers,
                         info_per_rad2=info if anisotropic else None)
    if not sol.solved:
        return ShipAttitude.failed(sol.reason, "joint")
    C_new, P_new = _with_mount_errors(sensors, sol, w_all, v_all, info)
    if C_new is not None:
        sol = replace(sol, C_ref_from_body=C_new, covariance_rad2=P_new)
    cov = sol.covariance_rad2 + _common_mode_covariance(sensors, sol, info, sig_all, w_all)
    return _from_C(sol.C_ref_from_body, cov, "joint", int(sol.n_used))


#: An empty buffer: "not given" for the compiled kernels' optional arrays.
_EMPTY = np.empty(0)


def _turned_to_deck(w, info, C_ds):
    """``(w C_ds^T, C_ds info C_ds^T)`` of a sensor whose stars have information matrices
    (``info`` (N, 3, 3)), in one compiled call (``attitude._ckernels.sensor_rows``, equal
    to NumPy's products to rounding); None without them, or when they are not (N, 3, 3)
    (the NumPy path then words the error).  ``C_ds``: ``C_deck_from_sensor``."""
    from shipstar.attitude import _ckernels

    if info is None or C_ds.shape != (3, 3):
        return None
    W = np.ascontiguousarray(info, dtype=float)
    n = w.shape[0]
    if W.shape != (n, 3, 3):
        return None
    wd, Wd = np.empty((n, 3)), np.empty((n, 3, 3))
    _ckernels.sensor_rows(np.ascontiguousarray(w), W, _EMPTY, np.arange(n, dtype=np.int64),
                          np.ascontiguousarray(C_ds), wd, Wd, _EMPTY)
    return wd, Wd


def _deck_information(sensors, w_deck, sigma, turned=None) -> np.ndarray:
    """(N, 3, 3) information matrices (rad^-2, deck axes) of every sensor's stars, stacked:
    ``sigma^-2 (I - w w^T)`` for isotropic stars, ``C_ds F C_ds^T`` for given ones
    (``turned``: per sensor, that product already made, or None)."""
    info = []
    for k, (s, wd_s, sig) in enumerate(zip(sensors, w_deck, sigma)):
        if turned is not None and turned[k] is not None:
            info.append(turned[k])
        elif s.info_per_rad2 is None:            # isotropic: sigma^-2 (I - w w^T)
            wd = wd_s / np.linalg.norm(wd_s, axis=1, keepdims=True)
            info.append(sig[:, None, None] ** -2 * (np.eye(3) - wd[:, :, None] * wd[:, None, :]))
        else:
            C_ds = np.asarray(s.C_deck_from_sensor, float)        # sensor axes -> deck axes
            info.append(C_ds @ np.asarray(s.info_per_rad2, float) @ C_ds.T)
    return np.concatenate(info)


def _inlier_rows(sensors, inliers):
    """``(sensor, rows)`` for each sensor: the indices of its inlier stars among all the
    sensors' stars stacked in order (``inliers`` (N,) bool, the joint solution's)."""
    start = 0
    inliers = np.asarray(inliers, bool)
    for s in sensors:
        n = np.atleast_2d(np.asarray(s.w_sensor, float)).shape[0]
        yield s, np.flatnonzero(inliers[start:start + n]) + start
        start += n


def _with_mount_errors(sensors, sol, w_deck, v_hor, info):
    """The joint solution with the sensors' mount uncertainties eliminated, or (None, None).

    A mount error ``m_s`` (covariance ``M_s``, ``SensorStars.mount_covariance_rad2``, deck
    axes) turns all of sensor ``s``'s stars together.  Taken as a nuisance rotation of that
    sensor and eliminated from the normal equations at the joint solution, the sensor's
    information ``F_s`` (of its inlier stars, about the deck axes) becomes
    ``F_s' = F_s (I + M_s F_s)^-1`` and its gradient ``h_s`` becomes ``(I + F_s M_s)^-1 h_s``
    (the same single-sensor step ``F_s^-1 h_s``, weighted by ``(F_s^-1 + M_s)^-1``).  One
    Gauss-Newton step from the joint solution gives the attitude, ``(sum F_s')^-1`` its
    covariance (scaled as the solver scaled its own).  With every ``M_s`` zero it is the
    joint solution; with ``M_s`` large the sensor no longer pulls the attitude.
    """
    from shipstar.attitude._solve import _rotation_from_vector, _skew

    if not any(s.mount_covariance_rad2 is not None for s in sensors) or sol.inliers is None:
        return None, None
    C = np.asarray(sol.C_ref_from_body, float)
    W_all = info if sol.info_per_rad2 is None else np.asarray(sol.info_per_rad2, float)
    F_tot, F_new, h_new = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros(3)
    for s, keep in _inlier_rows(sensors, sol.inliers):
        if len(keep) == 0:
            continue
        u = v_hor[keep] @ C                                   # predicted directions, deck axes
        e = u - w_deck[keep]
        W = W_all[keep]
        A = _skew(u)
        F_s = (np.swapaxes(A, 1, 2) @ W @ A).sum(axis=0)
        h_s = np.cross(u, np.einsum("nij,nj->ni", W, e)).sum(axis=0)
        F_tot += F_s
        M = s.mount_covariance_rad2
        if M is None:
            F_new += F_s
            h_new += h_s
            continue
        M = np.asarray(M, float)
        F_new += F_s @ np.linalg.inv(np.eye(3) + M @ F_s)
        h_new += np.linalg.solve(np.eye(3) + F_s @ M, h_s)
    try:
        P_info = np.linalg.inv(F_new)
    except np.linalg.LinAlgError:
        return None, None
    k = float(np.trace(np.asarray(sol.covariance_rad2, float) @ F_tot)) / 3.0   # the solver's scaling
    if not (math.isfinite(k) and k > 0):
        return None, None
    P = 0.5 * (P_info + P_info.T) * k
    return C @ _rotation_from_vector(P_info @ h_new), P


def _common_mode_covariance(sensors, sol, info, sigma, w_deck) -> np.ndarray:
    """``sum_s P F_s M_s F_s P`` (3, 3, deck axes): each sensor's common-mode error ``M_s``
    (``SensorStars.model_covariance_rad2`` in deck axes) through the joint solution, whose
    attitude moves by ``P F_s d`` when that sensor's stars all turn by ``d`` (``P`` the
    joint covariance, ``F_s`` the information of the sensor's inlier stars).

    Each sensor's term by the compiled kernel (``attitude._ckernels.common_mode``: the
    whole function ~10 us an epoch against ~35-65 us for
    :func:`_common_mode_covariance_python`, the reference, equal to rounding), the NumPy
    path where the kernel declines (a singular mount term).
    """
    from shipstar.attitude import _ckernels

    if not any(s.model_covariance_rad2 is not None for s in sensors):
        return np.zeros((3, 3))
    f64 = np.ascontiguousarray
    aniso = sol.info_per_rad2 is not None
    w = f64(w_deck, dtype=float)
    W = f64(sol.info_per_rad2, dtype=float) if aniso else _EMPTY
    sig = _EMPTY if aniso else f64(sigma, dtype=float)
    P = f64(sol.covariance_rad2, dtype=float)
    out = np.zeros((3, 3))
    for s, keep in _inlier_rows(sensors, sol.inliers):
        if s.model_covariance_rad2 is None:
            continue
        K = s.mount_covariance_rad2
        if not _ckernels.common_mode(w, W, sig, keep.astype(np.int64, copy=False), P,
                                     f64(s.C_deck_from_sensor, dtype=float), f64(s.model_covariance_rad2, dtype=float),
                                     _EMPTY if K is None else f64(K, dtype=float), out):
            return _common_mode_covariance_python(sensors, sol, info, sigma, w_deck)
    return 0.5 * (out + out.T)


def _common_mode_covariance_python(sensors, sol, info, sigma, w_deck) -> np.ndarray:
    """:func:`_common_mode_covariance` in NumPy (the reference of the compiled kernel)."""
    from shipstar.attitude._solve import _fisher_body

    out = np.zeros((3, 3))
    W = info if sol.info_per_rad2 is None else sol.info_per_rad2
    for s, keep in _inlier_rows(sensors, sol.inliers):
        if s.model_covariance_rad2 is None:
            continue
        if sol.info_per_rad2 is None:                         # scalar weights sigma^-2
            wd = w_deck[keep] / np.linalg.norm(w_deck[keep], axis=1, keepdims=True)
            F_s = np.einsum("n,nij->ij", sigma[keep] ** -2.0, np.eye(3) - wd[:, :, None] * wd[:, None, :])
        else:
            F_s = _fisher_body(w_deck[keep] / np.linalg.norm(w_deck[keep], axis=1, keepdims=True), W[keep])
        R = np.asarray(s.C_deck_from_sensor, float)
        if s.mount_covariance_rad2 is not None:     # the sensor's weight with its mount eliminated
            F_s = F_s @ np.linalg.inv(np.eye(3) + np.asarray(s.mount_covariance_rad2, float) @ F_s)
        G = sol.covariance_rad2 @ F_s
        out += G @ (R @ np.asarray(s.model_covariance_rad2, float) @ R.T) @ G.T
    return 0.5 * (out + out.T)
