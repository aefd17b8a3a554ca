"""Session statistics: errors against a truth table, RMS per method, a JSON-able summary."""

from __future__ import annotations

import math

import numpy as np

from shipstar.frames import wrap_pi
from shipstar.units import RAD2ASEC

__all__ = ["attitude_errors_arcsec", "rms_arcsec", "method_series", "session_summary", "METHODS"]

METHODS = ("single", "seed-rule", "joint")
_MAX_LISTED_FAILURES = 20


def method_series(result, method: str, sensor: str | None = None) -> list:
    """``[(utc_jd1, utc_jd2, ShipAttitude), ...]`` of one method.

    ``"single"`` needs ``sensor`` and gives that sensor's frames at their own times;
    ``"seed-rule"`` and ``"joint"`` give the epochs.
    """
    if method == "single":
        return [(fr.utc_jd1, fr.utc_jd2, fr.ship) for fr in result.frames_of(sensor)]
    attr = {"seed-rule": "seed_rule", "joint": "joint"}[method]
    return [(e.utc_jd1, e.utc_jd2, getattr(e, attr)) for e in result.epochs]


def attitude_errors_arcsec(series, truth) -> np.ndarray:
    """Estimated minus true (heading, pitch, roll) in arcsec, shape (M, 3).

    NaN rows where the attitude did not solve or the truth has no row at that time.
    """
    out = np.full((len(series), 3), np.nan)
    for k, (j1, j2, att) in enumerate(series):
        if not att.solved:
            continue
        K, psi, theta = truth.angles_rad(j1, j2)
        if math.isnan(K):
            continue
        out[k] = wrap_pi(np.array([att.heading_rad - K, att.pitch_rad - psi, att.roll_rad - theta])) * RAD2ASEC
    return out


def rms_arcsec(errors_arcsec) -> np.ndarray:
    """RMS (3,) over the finite rows of an (M, 3) error array (NaN when none)."""
    e = np.asarray(errors_arcsec, float)
    e = e[np.all(np.isfinite(e), axis=1)]
    return np.sqrt(np.mean(e ** 2, axis=0)) if len(e) else np.full(3, np.nan)


def _num(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _median_finite(x) -> float | None:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(np.median(x)) if len(x) else None


def _triple(values) -> list:
    return [_num(v) for v in values]


def _method_block(series, truth) -> dict:
    atts = [a for _, _, a in series]
    ok = [a for a in atts if a.solved]
    sig = np.array([a.sigma_rad for a in ok]).reshape(-1, 3) * RAD2ASEC
    block = {"n": len(atts), "n_solved": len(ok), "median_sigma_arcsec": [_median_finite(sig[:, k]) for k in range(3)]}
    if truth is not None:
        err = attitude_errors_arcsec(series, truth)
        good = np.all(np.isfinite(err), axis=1)
        block["n_compared"] = int(good.sum())
        block["rms_arcsec"] = _triple(rms_arcsec(err))
        block["mean_arcsec"] = _triple(err[good].mean(axis=0) if good.any() else np.full(3, np.nan))
        block["std_arcsec"] = _triple(err[good].std(axis=0, ddof=1) if good.sum() > 1 else np.full(3, np.nan))
    return block


def _sensor_block(frames) -> dict:
    ok = [fr for fr in frames if fr.solved]
    failures = [{"frame": fr.label, "time_utc": fr.utc_iso, "reason": fr.reason} for fr in frames if not fr.solved]
    corrections = [fr.streak_correction_arcsec for fr in frames if fr.streak_correction_arcsec > 0.0]
    return {
        "n_frames": len(frames), "n_solved": len(ok), "n_failed": len(frames) - len(ok),
        "median_stars_used": _num(np.median([fr.n_used for fr in ok])) if ok else None,
        "median_residual_rms_arcsec": _num(np.median([fr.rms_arcsec for fr in ok])) if ok else None,
        "n_streak_corrected": len(corrections),
        "max_streak_correction_arcsec": _num(max(corrections)) if corrections else 0.0,
        "failures": failures[:_MAX_LISTED_FAILURES], "failures_not_listed": max(0, len(failures) - _MAX_LISTED_FAILURES),
    }


def session_summary(result, truth=None) -> dict:
    """A JSON-able summary: per-sensor frame counts, failures (with reasons and
    microsecond times) and streak corrections, and per method the solved counts, median
    formal sigma and, with a truth table, the error RMS / mean / std of (heading, pitch,
    roll) in arcsec."""
    methods = {f"single:{s}": _method_block(method_series(result, "single", s), truth) for s in result.sensors}
    if len(result.sensors) > 1:
        for m in ("seed-rule", "joint"):
            methods[m] = _method_block(method_series(result, m), truth)
    return {
        "sensors": {s: _sensor_block(result.frames_of(s)) for s in result.sensors},
        "reference_sensor": result.reference_sensor,
        "fore_aft_sensor": result.fore_aft_sensor, "athwartship_sensor": result.athwartship_sensor,
        "n_epochs": len(result.epochs),
        "refraction_model": result.options.refraction_model, "refraction": result.options.refraction,
        "streak_correction": result.options.streak_correction,
        "methods": methods,
    }
