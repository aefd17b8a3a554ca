"""Session statistics: errors against a truth table, RMS per method, a JSON-able summary.

:class:`SessionStats` accumulates the summary from the engine's emissions as they come,
in memory that does not grow with the session (counts, sums, and medians from
logarithmically binned counts), so a ten-hour ``shipstar measure`` and an in-memory
:func:`session_summary` give the same numbers.  Its state is JSON-able
(:meth:`SessionStats.state`), so an interrupted ``measure --resume`` continues it.
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.frames import wrap_pi
from shipstar.units import RAD2ASEC

__all__ = ["attitude_errors_arcsec", "rms_arcsec", "method_series", "session_summary", "SessionStats", "METHODS",
           "MEDIAN_BINS_PER_DECADE"]

METHODS = ("single", "seed-rule", "joint")
_MAX_LISTED_FAILURES = 20
#: Medians of real values are read from counts in bins of 1/1000 decade: within 0.12 %
#: (the summaries print them to 0.01'' on values of 0.2-10'': invisible), a few hundred
#: bins a series, so the summary and the checkpoint of a night stay small.
MEDIAN_BINS_PER_DECADE = 1000


def method_series(result, method: str, sensor: str | None = None) -> list:
    """``[(utc_jd1, utc_jd2, ShipAttitude), ...]`` of one method.

    ``"single"`` needs ``sensor`` and gives that sensor's frames at their own times;
    ``"seed-rule"`` and ``"joint"`` give the epochs.
    """
    if method == "single":
        return [(fr.utc_jd1, fr.utc_jd2, fr.ship) for fr in result.frames_of(sensor)]
    attr = {"seed-rule": "seed_rule", "joint": "joint"}[method]
    return [(e.utc_jd1, e.utc_jd2, getattr(e, attr)) for e in result.epochs]


def _error_arcsec(att, truth, utc_jd1: float, utc_jd2: float):
    """Estimated minus true (heading, pitch, roll) (3,) arcsec, or None."""
    if not att.solved:
        return None
    K, psi, theta = truth.angles_rad(utc_jd1, utc_jd2)
    if math.isnan(K):
        return None
    return wrap_pi(np.array([att.heading_rad - K, att.pitch_rad - psi, att.roll_rad - theta])) * RAD2ASEC


def attitude_errors_arcsec(series, truth) -> np.ndarray:
    """Estimated minus true (heading, pitch, roll) in arcsec, shape (M, 3).

    NaN rows where the attitude did not solve or the truth has no row at that time.
    """
    out = np.full((len(series), 3), np.nan)
    for k, (j1, j2, att) in enumerate(series):
        e = _error_arcsec(att, truth, j1, j2)
        if e is not None:
            out[k] = e
    return out


def rms_arcsec(errors_arcsec) -> np.ndarray:
    """RMS (3,) over the finite rows of an (M, 3) error array (NaN when none)."""
    e = np.asarray(errors_arcsec, float)
    e = e[np.all(np.isfinite(e), axis=1)]
    return np.sqrt(np.mean(e ** 2, axis=0)) if len(e) else np.full(3, np.nan)


def _num(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


class _Median:
    """Median of a stream of values >= 0: exact for integers (``integer=True``), else read
    from counts in bins of 1/:data:`MEDIAN_BINS_PER_DECADE` decade (within 0.12 %)."""

    def __init__(self, integer: bool = False, counts=None):
        self.integer = integer
        self.counts: dict = {} if counts is None else {int(k): int(v) for k, v in counts.items()}

    def _key(self, x: float) -> int:
        if self.integer:
            return int(round(x))
        return -(2 ** 62) if x <= 0.0 else int(math.floor(math.log10(x) * MEDIAN_BINS_PER_DECADE))

    def _value(self, key: int) -> float:
        if self.integer:
            return float(key)
        return 0.0 if key == -(2 ** 62) else 10.0 ** ((key + 0.5) / MEDIAN_BINS_PER_DECADE)

    def add(self, x: float) -> None:
        if math.isfinite(x):
            k = self._key(float(x))
            self.counts[k] = self.counts.get(k, 0) + 1

    def value(self) -> float | None:
        n = sum(self.counts.values())
        if n == 0:
            return None
        ranks = (n // 2, n // 2) if n % 2 else (n // 2 - 1, n // 2)
        found, seen = [], 0
        for key in sorted(self.counts):
            seen += self.counts[key]
            while len(found) < 2 and ranks[len(found)] < seen:
                found.append(self._value(key))
        return 0.5 * (found[0] + found[1])


class _MethodStats:
    """One method's counts, formal sigmas and (with a truth table) errors."""

    def __init__(self, state=None):
        state = state or {}
        self.n = state.get("n", 0)
        self.n_solved = state.get("n_solved", 0)
        self.sigma = [_Median(counts=c) for c in state.get("sigma", [None] * 3)]
        self.n_compared = state.get("n_compared", 0)
        self.sum = np.array(state.get("sum", [0.0] * 3))
        self.sum2 = np.array(state.get("sum2", [0.0] * 3))

    def add(self, att, truth, utc_jd1: float, utc_jd2: float) -> None:
        self.n += 1
        if not att.solved:
            return
        self.n_solved += 1
        for median, s in zip(self.sigma, np.asarray(att.sigma_rad) * RAD2ASEC):
            median.add(s)
        if truth is not None:
            e = _error_arcsec(att, truth, utc_jd1, utc_jd2)
            if e is not None:
                self.n_compared += 1
                self.sum += e
                self.sum2 += e * e

    def state(self) -> dict:
        return {"n": self.n, "n_solved": self.n_solved, "sigma": [m.counts for m in self.sigma],
                "n_compared": self.n_compared, "sum": self.sum.tolist(), "sum2": self.sum2.tolist()}

    def block(self, with_truth: bool) -> dict:
        out = {"n": self.n, "n_solved": self.n_solved, "median_sigma_arcsec": [m.value() for m in self.sigma]}
        if with_truth:
            k = self.n_compared
            mean = self.sum / k if k else np.full(3, np.nan)
            var = (self.sum2 - k * mean * mean) / (k - 1) if k > 1 else np.full(3, np.nan)
            out["n_compared"] = k
            out["rms_arcsec"] = [_num(v) for v in (np.sqrt(self.sum2 / k) if k else np.full(3, np.nan))]
            out["mean_arcsec"] = [_num(v) for v in mean]
            out["std_arcsec"] = [_num(v) for v in np.sqrt(np.maximum(var, 0.0))]
        return out


class _SensorStats:
    """One sensor's frame counts, stars used, residuals, streak corrections, failures."""

    def __init__(self, state=None):
        state = state or {}
        self.n_frames = state.get("n_frames", 0)
        self.n_solved = state.get("n_solved", 0)
        self.stars = _Median(integer=True, counts=state.get("stars"))
        self.residual = _Median(counts=state.get("residual"))
        self.n_streak_corrected = state.get("n_streak_corrected", 0)
        self.n_streak_not_corrected = state.get("n_streak_not_corrected", 0)
        self.max_streak = state.get("max_streak", 0.0)
        self.failures = list(state.get("failures", []))
        self.n_failures = state.get("n_failures", 0)

    def add(self, fr) -> None:
        self.n_frames += 1
        if fr.solved:
            self.n_solved += 1
            self.stars.add(fr.n_used)
            self.residual.add(fr.rms_arcsec)
        else:
            self.n_failures += 1
            if len(self.failures) < _MAX_LISTED_FAILURES:
                self.failures.append({"frame": fr.label, "time_utc": fr.utc_iso, "reason": fr.reason})
        c = fr.streak_correction_arcsec
        if math.isnan(c):
            self.n_streak_not_corrected += 1
        elif c > 0.0:
            self.n_streak_corrected += 1
            self.max_streak = max(self.max_streak, float(c))

    def state(self) -> dict:
        return {"n_frames": self.n_frames, "n_solved": self.n_solved, "stars": self.stars.counts,
                "residual": self.residual.counts, "n_streak_corrected": self.n_streak_corrected,
                "n_streak_not_corrected": self.n_streak_not_corrected, "max_streak": self.max_streak,
                "failures": self.failures, "n_failures": self.n_failures}

    def block(self) -> dict:
        return {
            "n_frames": self.n_frames, "n_solved": self.n_solved, "n_failed": self.n_frames - self.n_solved,
            "median_stars_used": self.stars.value(), "median_residual_rms_arcsec": self.residual.value(),
            "n_streak_corrected": self.n_streak_corrected, "n_streak_not_corrected": self.n_streak_not_corrected,
            "max_streak_correction_arcsec": self.max_streak,
            "failures": list(self.failures), "failures_not_listed": self.n_failures - len(self.failures),
        }


class SessionStats:
    """The session summary, accumulated from the engine's emissions in bounded memory.

    Parameters
    ----------
    sensors : sequence of str
    truth : TruthTable, optional
        With it, each method's error RMS / mean / std against the truth.
    state : dict, optional
        A :meth:`state` to continue from (``measure --resume``).
    """

    def __init__(self, sensors, truth=None, state=None):
        self.sensors = tuple(sensors)
        self.truth = truth
        state = state or {}
        self.n_epochs = state.get("n_epochs", 0)
        self._sensors = {s: _SensorStats(state.get("sensors", {}).get(s)) for s in self.sensors}
        names = [f"single:{s}" for s in self.sensors] + (["seed-rule", "joint"] if len(self.sensors) > 1 else [])
        self._methods = {m: _MethodStats(state.get("methods", {}).get(m)) for m in names}

    def add(self, emission) -> None:
        """Count one :class:`~shipstar.pipeline._engine.Emission`."""
        for fr in emission.frames:
            self._sensors[fr.sensor].add(fr)
            self._methods[f"single:{fr.sensor}"].add(fr.ship, self.truth, fr.utc_jd1, fr.utc_jd2)
        e = emission.epoch
        if e is None:
            return
        self.n_epochs += 1
        if len(self.sensors) > 1:
            self._methods["seed-rule"].add(e.seed_rule, self.truth, e.utc_jd1, e.utc_jd2)
            self._methods["joint"].add(e.joint, self.truth, e.utc_jd1, e.utc_jd2)

    @property
    def n_failed(self) -> int:
        return sum(s.n_frames - s.n_solved for s in self._sensors.values())

    def unsolved_sensors(self) -> list:
        """``[(sensor, n_frames, first reason), ...]`` of the sensors with frames none of
        which solved."""
        return [(name, s.n_frames, s.failures[0]["reason"] if s.failures else "")
                for name, s in self._sensors.items() if s.n_frames and not s.n_solved]

    def first_failure(self):
        """``(sensor, frame, reason)`` of the first frame that did not solve, or None."""
        for name, s in self._sensors.items():
            if s.failures:
                return name, s.failures[0]["frame"], s.failures[0]["reason"]
        return None

    def state(self) -> dict:
        """JSON-able state (to continue with ``SessionStats(..., state=...)``)."""
        return {"n_epochs": self.n_epochs, "sensors": {k: v.state() for k, v in self._sensors.items()},
                "methods": {k: v.state() for k, v in self._methods.items()}}

    def summary(self, *, reference_sensor: str, fore_aft_sensor: str, athwartship_sensor: str, options) -> dict:
        """The JSON-able summary (the structure of :func:`session_summary`)."""
        return {
            "sensors": {name: s.block() for name, s in self._sensors.items()},
            "reference_sensor": reference_sensor,
            "fore_aft_sensor": fore_aft_sensor, "athwartship_sensor": athwartship_sensor,
            "n_epochs": self.n_epochs,
            "refraction_model": options.refraction_model, "refraction": options.refraction,
            "streak_correction": options.streak_correction,
            "methods": {m: b.block(self.truth is not None) for m, b in self._methods.items()},
        }


def session_summary(result, truth=None) -> dict:
    """A JSON-able summary of a :class:`~shipstar.pipeline.SessionResult`: per-sensor frame
    counts, failures (with reasons and microsecond times) and streak corrections, and per
    method the solved counts, median formal sigma and, with a truth table, the error RMS /
    mean / std of (heading, pitch, roll) in arcsec.  The same numbers as ``shipstar
    measure`` accumulates (:class:`SessionStats`)."""
    stats = SessionStats(result.sensors, truth)
    for emission in result.emissions:
        stats.add(emission)
    return stats.summary(reference_sensor=result.reference_sensor, fore_aft_sensor=result.fore_aft_sensor,
                         athwartship_sensor=result.athwartship_sensor, options=result.options)
