"""Error budgets (per-source contributions and their root-sum-square) and the Monte Carlo
check of the linear model through the full nonlinear chain."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shipstar import frames
from shipstar.errors import ShipstarError
from shipstar.units import ASEC2RAD, RAD2ASEC

from ._jacobian import OUTPUTS, PARAMS, ship_angles_rad, ship_jacobian, ship_matrix

__all__ = ["ErrorBudget", "error_budget", "MonteCarloCheck", "monte_carlo_check", "validate_errors_arcsec"]


def validate_errors_arcsec(errors_arcsec) -> np.ndarray:
    """Six finite, non-negative 1-sigma errors (arcsec) in :data:`PARAMS` order."""
    e = np.asarray(errors_arcsec, dtype=float)
    if e.shape != (6,):
        raise ShipstarError(f"need 6 errors (As, Es, gs, A0, E0, g0) in arcsec, got shape {e.shape}")
    if not np.all(np.isfinite(e)) or np.any(e < 0):
        raise ShipstarError(f"errors must be finite and >= 0 arcsec, got {e.tolist()}")
    return e


@dataclass(frozen=True)
class ErrorBudget:
    """Ship attitude error from independent error sources, by the linear model.

    Attributes
    ----------
    sources : tuple of str
        :data:`PARAMS`.
    errors_arcsec : ndarray, shape (6,)
        Error of each source (a 1-sigma value, or seed 001's deterministic error).
    jacobian : ndarray, shape S + (3, 6)
        ``d(K, psi, theta) / d(source)``, arcsec per arcsec.
    contributions_arcsec : ndarray, shape S + (3, 6)
        Signed contribution ``J[i, j] * errors[j]`` of each source to heading, pitch, roll.
    rss_arcsec : ndarray, shape S + (3,)
        Root-sum-square over the sources (independent errors): the 1-sigma ship error.
    signed_sum_arcsec : ndarray, shape S + (3,)
        Seed 001 eq. 5-7 taken literally: all errors added with their signs (a worst case
        only when all contributions share a sign).
    gimbal_locked : ndarray of bool, shape S
        Ship pitch within ``lock_margin_deg`` of +-90 deg: heading and roll are separately
        undefined there; all numbers at those points are NaN.
    ship_angles_rad : ndarray, shape S + (3,)
        The ship attitude (K, psi, theta) at each point.
    """

    sources: tuple
    errors_arcsec: np.ndarray
    jacobian: np.ndarray
    contributions_arcsec: np.ndarray
    rss_arcsec: np.ndarray
    signed_sum_arcsec: np.ndarray
    gimbal_locked: np.ndarray
    ship_angles_rad: np.ndarray

    def as_dict(self) -> dict:
        """JSON-ready dict for a single point (S = ()); NaN becomes None."""
        if self.rss_arcsec.ndim != 1:
            raise ShipstarError("as_dict() is for a single point; index the budget first")

        def f(x):
            return None if not np.isfinite(x) else float(x)

        return {
            "gimbal_locked": bool(self.gimbal_locked),
            "ship_angles_deg": {k: f(np.degrees(v)) for k, v in zip(OUTPUTS, self.ship_angles_rad)},
            "errors_arcsec": {p: float(e) for p, e in zip(self.sources, self.errors_arcsec)},
            "contributions_arcsec": {
                out: {p: f(self.contributions_arcsec[i, j]) for j, p in enumerate(self.sources)}
                for i, out in enumerate(OUTPUTS)
            },
            "rss_arcsec": {out: f(self.rss_arcsec[i]) for i, out in enumerate(OUTPUTS)},
            "signed_sum_arcsec": {out: f(self.signed_sum_arcsec[i]) for i, out in enumerate(OUTPUTS)},
        }


def error_budget(sensor_angles_rad, install_angles_rad, errors_arcsec, *, convention="shipstar",
                 lock_margin_deg: float = 1.0) -> ErrorBudget:
    """Per-source contributions, RSS and signed sum of the ship attitude error.

    Parameters
    ----------
    sensor_angles_rad, install_angles_rad : array_like, shape S + (3,)
        (As, Es, gs) and (A0, E0, g0).
    errors_arcsec : array_like, shape (6,)
        Errors of (As, Es, gs, A0, E0, g0).
    convention : {"shipstar", "seed001-factors"}
    lock_margin_deg : float
        Points whose ship pitch is within this of +-90 deg are flagged ``gimbal_locked``.
    """
    e = validate_errors_arcsec(errors_arcsec)
    if not (np.isfinite(lock_margin_deg) and 0.0 <= lock_margin_deg < 90.0):
        raise ShipstarError(f"lock_margin_deg must be in [0, 90), got {lock_margin_deg}")
    C_hd, _, _ = ship_matrix(sensor_angles_rad, install_angles_rad, convention)
    locked = frames.gimbal_lock_mask(C_hd, cos_tol=max(np.sin(np.radians(lock_margin_deg)), 1e-12))
    J = ship_jacobian(sensor_angles_rad, install_angles_rad, convention)
    J = np.where(locked[..., None, None], np.nan, J)
    contrib = J * e
    angles = np.stack(frames.ship_angles_from_C_hor_from_deck(C_hd), axis=-1)
    return ErrorBudget(
        sources=PARAMS, errors_arcsec=e, jacobian=J, contributions_arcsec=contrib,
        rss_arcsec=np.sqrt(np.sum(contrib**2, axis=-1)), signed_sum_arcsec=np.sum(contrib, axis=-1),
        gimbal_locked=np.asarray(locked), ship_angles_rad=angles,
    )


@dataclass(frozen=True)
class MonteCarloCheck:
    """Linear model against the full nonlinear chain, for independent Gaussian errors.

    Attributes
    ----------
    n_samples : int
    sigmas_arcsec : ndarray, shape (6,)
    rms_nonlinear_arcsec : ndarray, shape (3,)
        RMS of the ship (heading, pitch, roll) error through the nonlinear chain.
    rms_linear_arcsec : ndarray, shape (3,)
        ``sqrt(diag(J Sigma J^T))``, the linear model's prediction.
    rms_linear_samples_arcsec : ndarray, shape (3,)
        The linear model applied to the same samples (isolates the nonlinearity from the
        sampling noise, which is ``~ 1 / sqrt(2 n_samples)`` relative).
    rel_diff : ndarray, shape (3,)
        ``rms_nonlinear / rms_linear - 1``; NaN where the linear RMS is zero (< 1 micro-arcsec).
    rel_diff_same_samples : ndarray, shape (3,)
        ``rms_nonlinear / rms_linear_samples - 1``; NaN where that is zero.
    """

    n_samples: int
    sigmas_arcsec: np.ndarray
    rms_nonlinear_arcsec: np.ndarray
    rms_linear_arcsec: np.ndarray
    rms_linear_samples_arcsec: np.ndarray
    rel_diff: np.ndarray
    rel_diff_same_samples: np.ndarray

    def as_dict(self) -> dict:
        def f(x):
            return None if not np.isfinite(x) else float(x)

        keys = ("rms_nonlinear_arcsec", "rms_linear_arcsec", "rms_linear_samples_arcsec",
                "rel_diff", "rel_diff_same_samples")
        out = {"n_samples": self.n_samples,
               "sigmas_arcsec": {p: float(s) for p, s in zip(PARAMS, self.sigmas_arcsec)}}
        for k in keys:
            out[k] = {o: f(v) for o, v in zip(OUTPUTS, getattr(self, k))}
        return out


def _ratio_minus_one(a, b):
    # below a micro-arcsecond the linear RMS is zero up to rounding: no ratio
    out = np.full(a.shape, np.nan)
    np.divide(a, b, out=out, where=b > 1e-6)
    return out - 1.0


def monte_carlo_check(sensor_angles_rad, install_angles_rad, sigmas_arcsec, *, n_samples: int = 20000,
                      rng=None, convention: str = "shipstar") -> MonteCarloCheck:
    """Draw independent Gaussian errors of the six angles, push them through the full
    nonlinear chain (:func:`ship_angles_rad`) and compare the RMS ship error with the
    linear model.

    Parameters
    ----------
    sensor_angles_rad, install_angles_rad : array_like, shape (3,)
        The nominal point (not at gimbal lock).
    sigmas_arcsec : array_like, shape (6,)
        1-sigma errors of (As, Es, gs, A0, E0, g0).
    n_samples : int
    rng : numpy.random.Generator or int or None
    convention : {"shipstar", "seed001-factors"}
    """
    sig = validate_errors_arcsec(sigmas_arcsec)
    if int(n_samples) < 100:
        raise ShipstarError(f"n_samples must be >= 100, got {n_samples}")
    s0 = np.asarray(sensor_angles_rad, float).reshape(3)
    i0 = np.asarray(install_angles_rad, float).reshape(3)
    C_hd, _, _ = ship_matrix(s0, i0, convention)
    if frames.gimbal_lock_mask(C_hd, cos_tol=1e-6):
        raise ShipstarError("the nominal point is at gimbal lock (ship pitch +-90 deg): heading and roll are undefined")
    rng = np.random.default_rng(rng)
    d = rng.standard_normal((int(n_samples), 6)) * (sig * ASEC2RAD)
    nominal = ship_angles_rad(s0, i0, convention)
    perturbed = ship_angles_rad(s0 + d[:, :3], i0 + d[:, 3:], convention)
    err = frames.wrap_pi(perturbed - nominal)
    J = ship_jacobian(s0, i0, convention)
    lin = d @ J.T
    rms_nl = np.sqrt(np.mean(err**2, axis=0)) * RAD2ASEC
    rms_ls = np.sqrt(np.mean(lin**2, axis=0)) * RAD2ASEC
    rms_lin = np.sqrt(np.diag(J @ np.diag(sig**2) @ J.T))
    return MonteCarloCheck(
        n_samples=int(n_samples), sigmas_arcsec=sig, rms_nonlinear_arcsec=rms_nl,
        rms_linear_arcsec=rms_lin, rms_linear_samples_arcsec=rms_ls,
        rel_diff=_ratio_minus_one(rms_nl, rms_lin), rel_diff_same_samples=_ratio_minus_one(rms_nl, rms_ls),
    )
