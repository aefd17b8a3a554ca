"""Sensor attitude in the horizontal frame from identified stars (seed 000 eq. 6-16, seed 003 steps 1-3).

The chain for one frame::

    identified stars (HIP)  --FrameContext.hor_from_catalog-->  v_true_hor   (apparent, no air)
    v_true_hor  --refraction (per star, or the seed's boresight-only)-->  v_obs_hor
    (w_sensor, v_obs_hor)  --solve_attitude (QUEST-Newton)-->  C_hor_from_sensor

The reference vectors are the OBSERVED (refracted, higher) directions: a sensor looking
through the air sees a star at ``el_true + rho``.  Seed 000 eq. 8 writes ``E' = E - rho``,
the opposite sign (docs/conventions.md, *Refraction sign*).

Refraction modes (``refraction=``):

``"per-star"``
    Each star lifted by the refraction at its own elevation (seed 000's method).
``"boresight"``
    Seed 000's reference [9]: every star lifted by the same ``rho(E_boresight)``, the
    refraction at the boresight's elevation (``el_i + rho(E_b)``).  Wrong by the
    differential refraction across the field (+-11'' at the edges of an 8 deg field at
    35-40 deg elevation); kept to reproduce seed 000 Table 4.
``"none"``
    No refraction (the unrefracted apparent places): for tests and space geometry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.frames import az_el_from_unit, installation_angles_from_C_deck_from_sensor, unit_from_az_el
from shipstar.units import RAD2ASEC

__all__ = [
    "HorizontalAttitude",
    "REFRACTION_MODES",
    "reference_hor",
    "boresight_true_hor",
    "boresight_refraction_rad",
    "sensor_attitude_hor",
    "sensor_attitude_hor_from_catalog",
]

REFRACTION_MODES = ("per-star", "boresight", "none")

_NAN33 = np.full((3, 3), np.nan)


@dataclass(frozen=True, eq=False)
class HorizontalAttitude:
    """A sensor's attitude in the horizontal frame (X north, Y up, Z east) at one instant.

    Attributes
    ----------
    solved : bool
    reason : str
        Why not solved ('' when solved).
    C_hor_from_sensor : ndarray, shape (3, 3)
        ``v_hor = C_hor_from_sensor @ w_sensor``; NaN when not solved.
    covariance_rad2 : ndarray, shape (3, 3)
        Small-angle error covariance about the SENSOR axes (X boresight: the weak roll axis).
    rms_arcsec : float
        RMS residual of the stars used.
    residuals_arcsec : ndarray, shape (N,)
        Angle between each reference vector and the solved ``C @ w`` (NaN rows for stars
        below the refraction model's limit).
    inliers : ndarray, shape (N,), bool
        Stars used in the final solution.
    n_used : int
    w_sensor : ndarray, shape (N, 3)
        Measured unit vectors in the sensor frame.
    v_hor : ndarray, shape (N, 3)
        Reference directions in the horizontal frame, refracted per ``refraction``
        (NaN rows for stars below the model's limit).
    sigma_rad : ndarray, shape (N,)
        Per-star angular noise (1-sigma per axis): the one given, or estimated from the
        residual scatter (NaN when not solved).
    refraction : str
        ``"per-star"``, ``"boresight"`` or ``"none"``.
    model : str
        Refraction model (``shipstar.sky.refraction.MODELS``).
    boresight_refraction_arcsec : float
        The single ``rho(E_boresight)`` applied in ``"boresight"`` mode (NaN otherwise).
    info_per_rad2 : ndarray, shape (N, 3, 3), or None
        Per-star information matrices (sensor frame) behind ``covariance_rad2`` when the
        solve had them (anisotropic centroid errors, ``sensor_attitude_hor(info_per_rad2=)``);
        NaN rows for stars not used.  None otherwise.
    """

    solved: bool
    reason: str
    C_hor_from_sensor: np.ndarray
    covariance_rad2: np.ndarray
    rms_arcsec: float
    residuals_arcsec: np.ndarray
    inliers: np.ndarray
    n_used: int
    w_sensor: np.ndarray
    v_hor: np.ndarray
    sigma_rad: np.ndarray
    refraction: str
    model: str
    boresight_refraction_arcsec: float = math.nan
    info_per_rad2: np.ndarray | None = None

    @property
    def angles_rad(self) -> tuple[float, float, float]:
        """Sensor horizontal azimuth As, elevation Es and roll gamma_s (rad), docs/conventions.md."""
        if not self.solved:
            return (math.nan,) * 3
        a, e, g = installation_angles_from_C_deck_from_sensor(self.C_hor_from_sensor)
        return float(a), float(e), float(g)

    @property
    def sigma_axes_rad(self) -> np.ndarray:
        """1-sigma attitude error about the sensor axes (boresight, up, right), shape (3,)."""
        return np.sqrt(np.diag(self.covariance_rad2))


def _as_vectors(v, name: str) -> np.ndarray:
    try:
        arr = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise ShipstarError(f"{name} must be a numeric (N, 3) array") from None
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ShipstarError(f"{name} must have shape (N, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ShipstarError(f"{name} contains NaN or infinite values")
    norm = np.linalg.norm(arr, axis=1)
    if np.any(norm == 0.0):
        raise ShipstarError(f"{name} contains zero vectors")
    return arr / norm[:, None]


def _check_mode(refraction: str) -> None:
    if refraction not in REFRACTION_MODES:
        raise ShipstarError(f"unknown refraction mode {refraction!r}; choose one of {', '.join(REFRACTION_MODES)}")


def boresight_true_hor(w_sensor, v_true_hor) -> np.ndarray:
    """The boresight's unrefracted horizontal direction, from a rigid fit of the stars.

    This is seed 000 ref. [9]'s "J2000 attitude transformed to the horizontal frame":
    the attitude that maps the measured vectors onto the unrefracted apparent places.

    Parameters
    ----------
    w_sensor, v_true_hor : array_like, shape (N, 3), N >= 2

    Returns
    -------
    ndarray, shape (3,)
    """
    from shipstar.attitude._quest import quest

    w = _as_vectors(w_sensor, "w_sensor")
    v = _as_vectors(v_true_hor, "v_true_hor")
    if w.shape != v.shape or len(w) < 2:
        raise ShipstarError(f"w_sensor and v_true_hor must both be (N, 3) with N >= 2, got {w.shape} and {v.shape}")
    return quest(w, v)[:, 0]


def reference_hor(v_true_hor, weather, *, model: str = "erfa", refraction: str = "per-star",
                  boresight_hor=None) -> np.ndarray:
    """Observed reference directions from unrefracted apparent places.

    Parameters
    ----------
    v_true_hor : array_like, shape (N, 3)
        Topocentric apparent directions without refraction (``FrameContext.hor_from_catalog``).
    weather : shipstar.sky.refraction.Weather
    model : {"erfa", "almanac", "none"}
        Refraction model.  ``"erfa"`` is the default for measurement (0.03'' from ray
        tracing above 15 deg); ``"almanac"`` reproduces the seeds.
    refraction : {"per-star", "boresight", "none"}
    boresight_hor : array_like, shape (3,), optional
        Unrefracted boresight direction, needed for ``"boresight"``
        (see :func:`boresight_true_hor`).

    Returns
    -------
    ndarray, shape (N, 3)
        Unit vectors, azimuths unchanged, elevations raised.

    Raises
    ------
    ShipstarError
        A star or the boresight below the model's elevation limit, bad arguments.
    """
    from shipstar.sky.refraction import refract_hor

    _check_mode(refraction)
    v = _as_vectors(v_true_hor, "v_true_hor")
    if refraction == "none":
        return v
    if refraction == "per-star":
        return refract_hor(v, weather, model)
    if boresight_hor is None:
        raise ShipstarError("boresight-only refraction needs the boresight direction (boresight_hor)")
    az, el = az_el_from_unit(v)
    return unit_from_az_el(az, el + boresight_refraction_rad(boresight_hor, weather, model))


def boresight_refraction_rad(boresight_hor, weather, model: str = "erfa") -> float:
    """``rho(E_b)``: the refraction at the boresight's elevation (seed 000 ref. [9]).

    Parameters
    ----------
    boresight_hor : array_like, shape (3,)
        Unrefracted (true) boresight direction in the horizontal frame.
    """
    from shipstar.sky.refraction import observed_el_from_true

    try:
        b = np.reshape(np.asarray(boresight_hor, float), (1, 3))
    except (TypeError, ValueError):
        raise ShipstarError("boresight_hor must be a 3-vector") from None
    b = _as_vectors(b, "boresight_hor")[0]
    el_b = math.asin(max(-1.0, min(1.0, float(b[1]))))
    return float(observed_el_from_true(el_b, weather, model)) - el_b


def _above_limit(v_true, weather, model: str, refraction: str) -> np.ndarray:
    """Stars whose true elevation the model can refract (all, for mode "none")."""
    from shipstar.sky.refraction import min_true_el_rad

    if refraction == "none":
        return np.ones(len(v_true), dtype=bool)
    lo = min_true_el_rad(weather, model)
    return np.arcsin(np.clip(v_true[:, 1], -1.0, 1.0)) >= lo


def _failed(n: int, reason: str, w, v, refraction: str, model: str) -> HorizontalAttitude:
    return HorizontalAttitude(False, reason, _NAN33.copy(), _NAN33.copy(), math.nan, np.full(n, np.nan),
                              np.zeros(n, dtype=bool), 0, w, v, np.full(n, np.nan), refraction, model)


def sensor_attitude_hor(w_sensor, v_true_hor, weather, *, model: str = "erfa", refraction: str = "per-star",
                        sigma_rad=None, weights=None, reject_outliers: bool = True,
                        max_residual_arcsec=None, method: str = "quest",
                        info_per_rad2=None, v_ref_hor=None) -> HorizontalAttitude:
    """Attitude of a sensor in the horizontal frame from its matched stars.

    Parameters
    ----------
    w_sensor : array_like, shape (N, 3)
        Measured directions in the sensor frame (``camera.unproject(xy_px)``).
    v_true_hor : array_like, shape (N, 3)
        The same stars' unrefracted apparent directions at the frame's time and the
        ship's position (``FrameContext.hor_from_catalog``).
    weather : shipstar.sky.refraction.Weather
        At the frame's time (temperature and pressure at the sensor).
    model : {"erfa", "almanac", "none"}
    refraction : {"per-star", "boresight", "none"}
    sigma_rad : float or array_like, shape (N,), optional
        Per-axis angular noise of each measured star.  Default: estimated from the
        residual scatter (relative weights ``weights``).
    weights : array_like, shape (N,), optional
        Relative weights (default ``sigma_rad**-2`` or equal).
    reject_outliers, max_residual_arcsec, method
        Passed to :func:`shipstar.attitude.solve_attitude`.
    info_per_rad2 : array_like, shape (N, 3, 3), optional
        Per-star information matrices of the measured directions (sensor frame, rad^-2;
        relative unless ``sigma_rad`` is given), passed to ``solve_attitude``.
    v_ref_hor : array_like, shape (N, 3), optional
        The refracted reference directions an earlier call with the same ``v_true_hor``,
        weather and model computed (its ``HorizontalAttitude.v_hor``: NaN rows below the
        model's limit): with per-star refraction they do not depend on the measured
        vectors, and are used instead of being computed again (a frame solved again from
        its streak-corrected vectors).  Ignored with ``refraction="boresight"``.

    Returns
    -------
    HorizontalAttitude
        ``solved=False`` with the reason when fewer than 2 usable stars remain, the
        geometry is degenerate or the stars are inconsistent.  Stars below the model's
        elevation limit are left out (NaN rows) and named in the reason if that leaves
        too few.

    Raises
    ------
    ShipstarError
        Bad shapes, NaN vectors, bad weather/model/mode (caller errors).
    """
    from shipstar.attitude._solve import solve_attitude

    _check_mode(refraction)
    w = _as_vectors(w_sensor, "w_sensor")
    v_true = _as_vectors(v_true_hor, "v_true_hor")
    if w.shape != v_true.shape:
        raise ShipstarError(f"w_sensor and v_true_hor must have the same shape, got {w.shape} and {v_true.shape}")
    n = len(w)
    reuse = v_ref_hor is not None and refraction != "boresight"
    if reuse:
        v_ref = np.array(v_ref_hor, dtype=float)
        if v_ref.shape != (n, 3):
            raise ShipstarError(f"v_ref_hor must have shape ({n}, 3), got {v_ref.shape}")
        ok = np.isfinite(v_ref).all(axis=1)
    else:
        ok = _above_limit(v_true, weather, model, refraction)
        v_ref = np.full((n, 3), np.nan)
    if ok.sum() < 2:
        return _failed(n, f"{int(ok.sum())} of {n} stars above the refraction model's elevation limit; "
                          "at least 2 needed", w, v_ref, refraction, model)
    bore = boresight_true_hor(w[ok], v_true[ok]) if refraction == "boresight" else None
    if not reuse:
        v_ref[ok] = reference_hor(v_true[ok], weather, model=model, refraction=refraction, boresight_hor=bore)
    sig = None if sigma_rad is None else np.broadcast_to(np.asarray(sigma_rad, float), (n,))
    wts = None if weights is None else np.asarray(weights, float)
    if wts is not None and wts.shape != (n,):
        raise ShipstarError(f"weights must have shape ({n},), got {wts.shape}")
    info = None if info_per_rad2 is None else np.asarray(info_per_rad2, float)
    if info is not None and info.shape != (n, 3, 3):
        raise ShipstarError(f"info_per_rad2 must have shape ({n}, 3, 3), got {info.shape}")
    sol = solve_attitude(w[ok], v_ref[ok], weights=None if wts is None else wts[ok],
                         sigma_rad=None if sig is None else sig[ok], method=method,
                         reject_outliers=reject_outliers, max_residual_arcsec=max_residual_arcsec,
                         info_per_rad2=None if info is None else info[ok])
    rho_b = math.nan if bore is None else boresight_refraction_rad(bore, weather, model) * RAD2ASEC
    if not sol.solved:
        return _failed(n, sol.reason, w, v_ref, refraction, model)
    res = np.full(n, np.nan)
    res[ok] = sol.residuals_arcsec
    inl = np.zeros(n, dtype=bool)
    inl[ok] = sol.inliers
    sigma_out = np.full(n, np.nan)
    sigma_out[ok] = sol.sigma_rad
    info_out = None
    if sol.info_per_rad2 is not None:
        info_out = np.full((n, 3, 3), np.nan)
        info_out[ok] = sol.info_per_rad2
    return HorizontalAttitude(True, "", sol.C_ref_from_body, sol.covariance_rad2, float(sol.rms_arcsec), res, inl,
                              int(sol.n_used), w, v_ref, sigma_out, refraction, model, rho_b, info_out)


def sensor_attitude_hor_from_catalog(w_sensor, hip, catalog, context, weather, **options) -> HorizontalAttitude:
    """:func:`sensor_attitude_hor` for stars named by HIP number.

    Parameters
    ----------
    w_sensor : array_like, shape (N, 3)
    hip : array_like of int, shape (N,)
        Hipparcos numbers of the measured stars (from the identification).
    catalog : shipstar.sky.catalog.StarCatalog
        Catalog holding those stars (``load_hipparcos()`` or a navigation catalog).
    context : shipstar.sky.apparent.FrameContext
        Frame time (mid-exposure) and the ship's position.
    weather : shipstar.sky.refraction.Weather
    **options
        As for :func:`sensor_attitude_hor`.
    """
    idx = catalog.index_of_hip(hip)
    v_true = context.hor_from_catalog(catalog, idx)
    return sensor_attitude_hor(w_sensor, v_true, weather, **options)
