"""Installation layout: where to point one or two sensors for the best ship attitude.

For a sensor installed at (A, E, g) with attitude covariance ``P_att`` about its own axes
(:func:`sensor_accuracy`) and installation calibration errors ``(sA0, sE0, sg0)``, the ship
attitude covariance is ``G (P_att + P_inst) G^T`` with ``G = M(K, psi)^-1 C_hor_from_sensor``
(:func:`ship_jacobian_sensor_axes`) and ``P_inst = T diag(s^2) T^T``,
``T = C_deck_from_sensor^T M(A, E)`` (the installation angle errors as rotations about
the sensor axes).  Two sensors are fused by weighting the two ship-attitude estimates
with their inverse covariances: ``P = (P_1^-1 + P_2^-1)^-1``.  The heading does not
enter (``M(K, psi)^-1 C_hor_from_deck`` is independent of K); the ship's pitch and roll
do, so a set of ship attitudes can be given and the covariance is averaged over them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shipstar import frames
from shipstar.errors import ShipstarError
from shipstar.units import ASEC2RAD, DEG2RAD, RAD2ASEC

from ._jacobian import OUTPUTS, angle_rate_matrix, ship_jacobian_sensor_axes
from ._sensor import SensorAccuracy

__all__ = ["OBJECTIVES", "ship_covariance", "layout_objective", "LayoutResult", "optimise_layout"]

#: "max": the largest of the heading/pitch/roll 1-sigma; "rss": root-sum-square of the
#: three; or one of them.
OBJECTIVES = ("max", "rss", "heading", "pitch", "roll")
#: ship attitudes are refused this close to pitch +-90 deg
_MAX_SHIP_PITCH_DEG = 80.0


def _ship_attitudes(ship_attitudes_deg):
    a = np.asarray(ship_attitudes_deg, float).reshape(-1, 2)
    if a.size == 0 or not np.all(np.isfinite(a)):
        raise ShipstarError("ship attitudes must be finite (pitch_deg, roll_deg) pairs")
    if np.any(np.abs(a[:, 0]) > _MAX_SHIP_PITCH_DEG) or np.any(np.abs(a[:, 1]) > 90.0):
        raise ShipstarError(f"ship pitch must be within +-{_MAX_SHIP_PITCH_DEG:g} deg and roll within +-90 deg, "
                            f"got {a.tolist()}")
    return a


def _install_sigmas(install_errors_arcsec):
    s = np.asarray(install_errors_arcsec, float)
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s < 0):
        raise ShipstarError(f"installation errors must be 3 finite values >= 0 arcsec (A0, E0, g0), got {s.tolist()}")
    return s * ASEC2RAD


def ship_covariance(sensor: SensorAccuracy, az_rad, el_rad, *, roll_rad=0.0, install_errors_arcsec=(0.0, 0.0, 0.0),
                    ship_pitch_rad=0.0, ship_roll_rad=0.0) -> np.ndarray:
    """Ship (heading, pitch, roll) error covariance (rad^2) from one sensor.

    Parameters
    ----------
    sensor : SensorAccuracy
    az_rad, el_rad, roll_rad : array_like, broadcast to shape S
        Installation azimuth (from the bow toward starboard), elevation above the deck,
        roll about the boresight.
    install_errors_arcsec : (3,)
        1-sigma calibration errors of (A0, E0, g0).
    ship_pitch_rad, ship_roll_rad : array_like, broadcast with the above
        Ship attitude (the heading does not matter).

    Returns
    -------
    ndarray, shape S + (3, 3)
    """
    sig0 = _install_sigmas(install_errors_arcsec)
    A, E, g, p, r = np.broadcast_arrays(*(np.asarray(x, float) for x in
                                          (az_rad, el_rad, roll_rad, ship_pitch_rad, ship_roll_rad)))
    C_ds = frames.C_deck_from_sensor(A, E, g)
    C_hs = frames.C_hor_from_deck(np.zeros_like(p), p, r) @ C_ds
    G, _ = ship_jacobian_sensor_axes(C_hs, C_ds)
    T = np.swapaxes(C_ds, -1, -2) @ angle_rate_matrix(A, E)
    P_body = sensor.covariance_rad2 + (T * sig0**2) @ np.swapaxes(T, -1, -2)
    return G @ P_body @ np.swapaxes(G, -1, -2)


def layout_objective(sigma_arcsec, objective: str) -> np.ndarray:
    """Scalar figure of merit (arcsec) from heading/pitch/roll 1-sigma ``(..., 3)``."""
    s = np.asarray(sigma_arcsec, float)
    if objective == "max":
        return np.max(s, axis=-1)
    if objective == "rss":
        return np.sqrt(np.sum(s**2, axis=-1))
    if objective in OUTPUTS:
        return s[..., OUTPUTS.index(objective)]
    raise ShipstarError(f"unknown objective {objective!r}; expected one of {', '.join(OBJECTIVES)}")


@dataclass(frozen=True)
class LayoutResult:
    """The best installation layout found for ``n_sensors`` sensors.

    Attributes
    ----------
    n_sensors : int
    objective : str
    az_deg, el_deg : tuple of float
        Installation azimuth (from the bow toward starboard) and elevation of each sensor.
    sigma_arcsec : ndarray, shape (3,)
        Predicted heading, pitch, roll 1-sigma (RMS over the ship attitudes), fused.
    objective_arcsec : float
    per_sensor_sigma_arcsec : ndarray, shape (n_sensors, 3)
        Each sensor alone at its place.
    ship_attitudes_deg : ndarray, shape (k, 2)
        (pitch, roll) of the ship the covariance is averaged over.
    az_range_deg, el_range_deg : tuple of float
    grid_az_deg, grid_el_deg : ndarray, shapes (na,), (ne,)
    grid_objective_arcsec : ndarray, shape (ne, na)
        One sensor's objective over the search grid (for maps).
    """

    n_sensors: int
    objective: str
    az_deg: tuple
    el_deg: tuple
    sigma_arcsec: np.ndarray
    objective_arcsec: float
    per_sensor_sigma_arcsec: np.ndarray
    ship_attitudes_deg: np.ndarray
    az_range_deg: tuple
    el_range_deg: tuple
    grid_az_deg: np.ndarray
    grid_el_deg: np.ndarray
    grid_objective_arcsec: np.ndarray

    def as_dict(self) -> dict:
        return {
            "n_sensors": self.n_sensors, "objective": self.objective,
            "az_deg": [float(a) for a in self.az_deg], "el_deg": [float(e) for e in self.el_deg],
            "sigma_arcsec": {o: float(v) for o, v in zip(OUTPUTS, self.sigma_arcsec)},
            "objective_arcsec": float(self.objective_arcsec),
            "per_sensor_sigma_arcsec": [{o: float(v) for o, v in zip(OUTPUTS, row)}
                                        for row in self.per_sensor_sigma_arcsec],
            "ship_attitudes_deg": [{"pitch_deg": float(p), "roll_deg": float(r)} for p, r in self.ship_attitudes_deg],
            "az_range_deg": list(self.az_range_deg), "el_range_deg": list(self.el_range_deg),
        }


class _Problem:
    """Covariances of one sensor at given places, per ship attitude, and their fusion."""

    def __init__(self, sensor, install_errors_arcsec, attitudes_deg, objective, roll_rad):
        self.sensor = sensor
        self.install = install_errors_arcsec
        self.att = attitudes_deg * DEG2RAD
        self.objective = objective
        self.roll = roll_rad

    def cov(self, az_deg, el_deg):
        """(..., k, 3, 3) for places of shape (...)."""
        a = np.asarray(az_deg, float)[..., None] * DEG2RAD
        e = np.asarray(el_deg, float)[..., None] * DEG2RAD
        return ship_covariance(self.sensor, a, e, roll_rad=self.roll, install_errors_arcsec=self.install,
                               ship_pitch_rad=self.att[:, 0], ship_roll_rad=self.att[:, 1])

    @staticmethod
    def sigma(P):
        """RMS over ship attitudes of each angle's 1-sigma (arcsec), (..., 3)."""
        return np.sqrt(np.mean(np.diagonal(P, axis1=-2, axis2=-1), axis=-2)) * RAD2ASEC

    def score(self, P):
        return layout_objective(self.sigma(P), self.objective)

    @staticmethod
    def fuse(P1, P2):
        return np.linalg.inv(np.linalg.inv(P1) + np.linalg.inv(P2))


def _grid(lo, hi, step):
    n = max(int(math.ceil((hi - lo) / step - 1e-9)), 1)
    return np.linspace(lo, hi, n + 1)


def _pattern_search(f, x0, lo, hi, step0, step_min=0.01):
    """Deterministic pattern search within the box [lo, hi] that refines a grid optimum.

    ``f`` maps points ``(m, d)`` to scores ``(m,)``.
    It polls all ``3^d - 1`` neighbours (axes and diagonals), so it can follow the ridge
    of a min-max objective, and halves the step when no neighbour is better.
    """
    x = np.array(x0, float)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    dirs = np.array(np.meshgrid(*([(-1.0, 0.0, 1.0)] * x.size), indexing="ij")).reshape(x.size, -1).T
    dirs = dirs[np.any(dirs != 0, axis=1)]
    best = float(f(x[None])[0])
    step = step0
    while step >= step_min:
        cand = np.clip(x + step * dirs, lo, hi)
        vals = f(cand)
        k = int(np.argmin(vals))
        if vals[k] < best - 1e-12:
            x, best = cand[k], float(vals[k])
        else:
            step /= 2.0
    return x, best


def _check_ranges(az_range_deg, el_range_deg):
    az = tuple(float(v) for v in az_range_deg)
    el = tuple(float(v) for v in el_range_deg)
    if len(az) != 2 or not all(map(math.isfinite, az)) or not (az[0] < az[1] <= az[0] + 360.0):
        raise ShipstarError(f"azimuth range must be (min, max) with min < max <= min + 360 deg, got {az}")
    if len(el) != 2 or not all(map(math.isfinite, el)) or not (0.0 <= el[0] <= el[1] <= 90.0):
        raise ShipstarError(f"elevation range must be (min, max) with 0 <= min <= max <= 90 deg, got {el}")
    return az, el


def optimise_layout(sensor: SensorAccuracy, *, n_sensors: int = 1, az_range_deg=(0.0, 360.0),
                    el_range_deg=(30.0, 60.0), install_errors_arcsec=(0.0, 0.0, 0.0),
                    ship_attitudes_deg=((0.0, 0.0),), objective: str = "max", roll_deg: float = 0.0,
                    step_deg: float = 2.0) -> LayoutResult:
    """Installation azimuth/elevation of one or two sensors minimising the ship attitude error.

    A grid search (``step_deg``; 5 deg or coarser for pairs) within the limits, refined by
    a pattern search down to 0.01 deg.  On a level ship without installation errors the
    trace of the single-sensor covariance does not depend on the layout, so
    ``objective="rss"`` is flat there; ``"max"`` (the default) is not.

    Parameters
    ----------
    sensor : SensorAccuracy
    n_sensors : {1, 2}
    az_range_deg : (min, max)
        Allowed installation azimuth (from the bow toward starboard), max - min <= 360.
    el_range_deg : (min, max)
        Allowed elevation above the deck (e.g. 30-60 deg for occlusion).
    install_errors_arcsec : (3,)
        1-sigma calibration errors of (A0, E0, g0).
    ship_attitudes_deg : sequence of (pitch_deg, roll_deg)
        Ship attitudes the covariance is averaged over (|pitch| <= 80 deg).
    objective : one of :data:`OBJECTIVES`
    roll_deg : float
        Installation roll of the sensors about their boresight.
    step_deg : float
        Grid step.
    """
    if n_sensors not in (1, 2):
        raise ShipstarError(f"n_sensors must be 1 or 2, got {n_sensors}")
    if objective not in OBJECTIVES:
        raise ShipstarError(f"unknown objective {objective!r}; expected one of {', '.join(OBJECTIVES)}")
    if not (math.isfinite(step_deg) and 0.1 <= step_deg <= 30.0):
        raise ShipstarError(f"step_deg must be within [0.1, 30], got {step_deg}")
    if not math.isfinite(roll_deg):
        raise ShipstarError(f"roll_deg must be finite, got {roll_deg}")
    az_r, el_r = _check_ranges(az_range_deg, el_range_deg)
    att = _ship_attitudes(ship_attitudes_deg)
    prob = _Problem(sensor, install_errors_arcsec, att, objective, roll_deg * DEG2RAD)
    gaz, gel = _grid(*az_r, step_deg), _grid(*el_r, step_deg)
    AZ, EL = np.meshgrid(gaz, gel, indexing="xy")
    grid_obj = prob.score(prob.cov(AZ, EL))
    if n_sensors == 1:
        x0 = np.array([AZ.flat[np.argmin(grid_obj)], EL.flat[np.argmin(grid_obj)]])
        x, best = _pattern_search(lambda X: prob.score(prob.cov(X[:, 0], X[:, 1])), x0,
                                  (az_r[0], el_r[0]), (az_r[1], el_r[1]), step_deg / 2)
        P = prob.cov(x[0], x[1])
        per = prob.sigma(P)[None]
        az, el = (float(x[0]),), (float(x[1]),)
    else:
        x, best = _best_pair(prob, az_r, el_r, max(step_deg, 5.0))
        P1, P2 = prob.cov(x[0], x[1]), prob.cov(x[2], x[3])
        P = prob.fuse(P1, P2)
        per = np.stack([prob.sigma(P1), prob.sigma(P2)])
        az, el = (float(x[0]), float(x[2])), (float(x[1]), float(x[3]))
    sig = prob.sigma(P)
    return LayoutResult(n_sensors=n_sensors, objective=objective, az_deg=az, el_deg=el, sigma_arcsec=sig,
                        objective_arcsec=float(best), per_sensor_sigma_arcsec=per, ship_attitudes_deg=att,
                        az_range_deg=az_r, el_range_deg=el_r, grid_az_deg=gaz, grid_el_deg=gel,
                        grid_objective_arcsec=grid_obj)


def _best_pair(prob: _Problem, az_r, el_r, step):
    gaz, gel = _grid(*az_r, step), _grid(*el_r, step)
    AZ, EL = (m.ravel() for m in np.meshgrid(gaz, gel, indexing="xy"))
    P = prob.cov(AZ, EL)                          # (n, k, 3, 3)
    info = np.linalg.inv(P)
    i, j = np.triu_indices(AZ.size)
    best, best_ij = np.inf, (0, 0)
    chunk = 20000
    for s in range(0, i.size, chunk):
        ii, jj = i[s:s + chunk], j[s:s + chunk]
        score = prob.score(np.linalg.inv(info[ii] + info[jj]))
        k = int(np.argmin(score))
        if score[k] < best:
            best, best_ij = float(score[k]), (ii[k], jj[k])
    a, b = best_ij
    x0 = np.array([AZ[a], EL[a], AZ[b], EL[b]])

    def f(X):
        return prob.score(prob.fuse(prob.cov(X[:, 0], X[:, 1]), prob.cov(X[:, 2], X[:, 3])))

    lo = (az_r[0], el_r[0], az_r[0], el_r[0])
    hi = (az_r[1], el_r[1], az_r[1], el_r[1])
    return _pattern_search(f, x0, lo, hi, step / 2)
