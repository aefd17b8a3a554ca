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
        self.n_windowed = state.get("n_windowed", 0)
        self.max_streak = state.get("max_streak", 0.0)
        self.failures = list(state.get("failures", []))
        self.n_failures = state.get("n_failures", 0)
        # frames lost to the sky (clouded, the Moon or the Sun in the field): not solver failures
        self.n_sky = dict(state.get("n_sky", {}))
        self.first_sky = state.get("first_sky")
        # the solver's failures by reason (availability), and the seeing estimate (noise floor)
        self.n_by_reason = dict(state.get("n_by_reason", {}))
        self.floor = _Median(counts=state.get("floor"))
        self.last_floor = state.get("last_floor")

    def add(self, fr) -> None:
        from shipstar.pipeline._conditions import ENVIRONMENT_REASONS

        self.n_frames += 1
        if fr.solved:
            self.n_solved += 1
            self.stars.add(fr.n_used)
            self.residual.add(fr.rms_arcsec)
            f = float(getattr(fr, "noise_floor_arcsec", math.nan))
            if math.isfinite(f) and f > 0.0:
                self.floor.add(f)
                self.last_floor = f
        elif fr.reason in ENVIRONMENT_REASONS:
            self.n_sky[fr.reason] = self.n_sky.get(fr.reason, 0) + 1
            if self.first_sky is None:
                self.first_sky = {"frame": fr.label, "time_utc": fr.utc_iso, "reason": fr.reason}
        else:
            self.n_failures += 1
            key = _reason_key(fr.reason, self.n_by_reason)
            self.n_by_reason[key] = self.n_by_reason.get(key, 0) + 1
            if len(self.failures) < _MAX_LISTED_FAILURES:
                self.failures.append({"frame": fr.label, "time_utc": fr.utc_iso, "reason": fr.reason})
        self.n_windowed += bool(getattr(fr, "windowed", False))
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
                "n_windowed": self.n_windowed, "failures": self.failures, "n_failures": self.n_failures,
                "n_sky": self.n_sky, "first_sky": self.first_sky, "n_by_reason": self.n_by_reason, "floor": self.floor.counts,
                "last_floor": self.last_floor}

    def availability(self) -> dict:
        """Solved share and the unsolved frames by reason (the sky's and the solver's)."""
        reasons = {**self.n_sky, **{k: v for k, v in self.n_by_reason.items() if k not in self.n_sky}}
        return {"n_frames": self.n_frames, "n_solved": self.n_solved,
                "solved_fraction": _num(self.n_solved / self.n_frames) if self.n_frames else None,
                "unsolved_by_reason": dict(sorted(reasons.items(), key=lambda kv: -kv[1]))}

    def seeing(self) -> dict:
        """The per-star noise floor (seeing) estimated from the residuals: median over the
        solved frames and the last value, arcsec (None before an estimate)."""
        return {"noise_floor_arcsec": self.floor.value(), "noise_floor_last_arcsec": _num(self.last_floor)
                if self.last_floor is not None else None}

    def block(self) -> dict:
        from shipstar.pipeline._conditions import CLOUDED_REASON, MOON_REASON, SUN_REASON

        return {
            "n_frames": self.n_frames, "n_solved": self.n_solved, "n_failed": self.n_failures,
            "n_clouded": self.n_sky.get(CLOUDED_REASON, 0), "n_moon_in_field": self.n_sky.get(MOON_REASON, 0),
            "n_sun_in_field": self.n_sky.get(SUN_REASON, 0),
            "median_stars_used": self.stars.value(), "median_residual_rms_arcsec": self.residual.value(),
            "n_streak_corrected": self.n_streak_corrected, "n_streak_not_corrected": self.n_streak_not_corrected,
            "max_streak_correction_arcsec": self.max_streak, "n_windowed": self.n_windowed,
            "failures": list(self.failures), "failures_not_listed": self.n_failures - len(self.failures),
        }


#: Distinct failure reasons counted apart in ``availability`` (the rest: ``other``).
_MAX_REASONS = 20


def _reason_key(reason: str, counted: dict) -> str:
    """A failure reason as an availability key: numbers replaced by ``N`` (so "3 stars" and
    "4 stars" count together), at most :data:`_MAX_REASONS` distinct keys."""
    import re

    key = re.sub(r"[-+]?\d+(\.\d+)?(e[-+]?\d+)?", "N", str(reason or "unknown"))[:100]
    return key if key in counted or len(counted) < _MAX_REASONS else "other"


#: The reason of the fused rows of a session's first epochs, before the deck's motion is
#: known (not counted as unsolved by :attr:`SessionStats.n_fused_unsolved`).
WARM_UP_REASON = "the deck's motion is not known yet"


class _IntegrityStats:
    """Epochs checked by the integrity monitor, inconsistent ones and their suspects."""

    def __init__(self, state=None):
        state = state or {}
        self.n_checked = state.get("n_checked", 0)
        self.n_inconsistent = state.get("n_inconsistent", 0)
        self.suspects = dict(state.get("suspects", {}))
        self.listed = list(state.get("listed", []))
        self.max_chi2 = state.get("max_chi2", None)
        self.limit = state.get("limit", None)
        self.n_fused_unsolved = state.get("n_fused_unsolved", 0)
        self.n_warm_up = state.get("n_warm_up", 0)

    def add(self, e) -> None:
        if not e.joint.solved:
            if e.joint.reason.startswith(WARM_UP_REASON):
                self.n_warm_up += 1
            else:
                self.n_fused_unsolved += 1
        i = e.integrity
        if i is None or not i.checked:
            return
        self.n_checked += 1
        self.limit = i.limit
        self.max_chi2 = i.chi2 if self.max_chi2 is None else max(self.max_chi2, i.chi2)
        if not i.consistent:
            self.n_inconsistent += 1
            self.suspects[i.suspect] = self.suspects.get(i.suspect, 0) + 1
            if len(self.listed) < _MAX_LISTED_FAILURES:
                self.listed.append({"frame": e.label, "time_utc": e.utc_iso, "chi2": round(i.chi2, 2),
                                    "disagreement_arcsec": round(i.disagreement_arcsec, 2), "suspect": i.suspect})

    def state(self) -> dict:
        return {"n_checked": self.n_checked, "n_inconsistent": self.n_inconsistent, "suspects": self.suspects,
                "listed": self.listed, "max_chi2": self.max_chi2, "limit": self.limit,
                "n_fused_unsolved": self.n_fused_unsolved, "n_warm_up": self.n_warm_up}

    def block(self) -> dict:
        from shipstar.pipeline._integrity import FALSE_ALARM_PROBABILITY

        return {"n_checked": self.n_checked, "n_inconsistent": self.n_inconsistent,
                "suspects": dict(self.suspects), "chi2_limit": self.limit, "max_chi2": self.max_chi2,
                "false_alarm_probability": FALSE_ALARM_PROBABILITY, "inconsistent": list(self.listed),
                "inconsistent_not_listed": self.n_inconsistent - len(self.listed),
                "n_fused_unsolved": self.n_fused_unsolved, "n_warm_up": self.n_warm_up}


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
        self._integrity = _IntegrityStats(state.get("integrity"))
        self._mounts = state.get("mounts")              # the last epoch's clock offsets and flexure

    def add(self, emission) -> None:
        """Count one :class:`~shipstar.pipeline._engine.Emission`."""
        for fr in emission.frames:
            self._sensors[fr.sensor].add(fr)
            self._methods[f"single:{fr.sensor}"].add(fr.ship, self.truth, fr.utc_jd1, fr.utc_jd2)
        e = emission.epoch
        if e is None:
            return
        self.n_epochs += 1
        if getattr(e, "mounts", None) is not None:
            self._mounts = e.mounts            # MountsSnapshot: its flexure is built when read
        if len(self.sensors) > 1:
            self._integrity.add(e)
            self._methods["seed-rule"].add(e.seed_rule, self.truth, e.utc_jd1, e.utc_jd2)
            self._methods["joint"].add(e.joint, self.truth, e.utc_jd1, e.utc_jd2)

    @property
    def n_failed(self) -> int:
        """Frames the solver lost (frames lost to the sky -- clouded, the Moon or the Sun in the
        field -- are counted apart, :attr:`n_sky`)."""
        return sum(s.n_failures for s in self._sensors.values())

    @property
    def n_sky(self) -> int:
        """Frames lost to the sky: clouded, the Moon or the Sun in the field."""
        return sum(sum(s.n_sky.values()) for s in self._sensors.values())

    @property
    def n_inconsistent(self) -> int:
        """Epochs whose sensors disagree beyond their combined uncertainty."""
        return self._integrity.n_inconsistent

    @property
    def n_fused_unsolved(self) -> int:
        """Epochs without a fused attitude, the warm-up's first epochs not counted."""
        return self._integrity.n_fused_unsolved

    def problems_line(self) -> str:
        """``''`` when every frame solved and every epoch is fused and consistent, else the
        counts in one line (``measure`` and ``live`` print it)."""
        parts = []
        n_frames = sum(s.n_frames for s in self._sensors.values())
        if self.n_failed or self.n_sky:
            # every unsolved frame counts (exit 1), those lost to the sky named apart
            sky = {}
            for st in self._sensors.values():
                for reason, n in st.n_sky.items():
                    sky[reason] = sky.get(reason, 0) + n
            kinds = ([f"{self.n_failed} not solved"] if self.n_failed and sky else []) + \
                [f"{n} {reason}" for reason, n in sorted(sky.items())]
            first = self.first_failure() or next((name, st.first_sky["frame"], st.first_sky["reason"])
                                                 for name, st in self._sensors.items() if st.first_sky)
            sensor, label, reason = first
            parts.append(f"{self.n_failed + self.n_sky} of {n_frames} frames unsolved ("
                         + "".join(f"{k}; " for k in kinds) + f"first: {sensor} {label}: {reason})")
        if self.n_fused_unsolved:
            parts.append(f"{self.n_fused_unsolved} of {self.n_epochs} epochs without a fused attitude")
        if self.n_inconsistent:
            i = self._integrity
            who = ", ".join(f"{k} in {v}" for k, v in sorted(i.suspects.items(), key=lambda kv: -kv[1]))
            first = i.listed[0] if i.listed else None
            parts.append(f"{i.n_inconsistent} of {i.n_checked} epochs inconsistent (the sensor that does not fit: "
                         f"{who}" + (f"; first: {first['frame']}, {first['disagreement_arcsec']:.1f}'', chi2 "
                                     f"{first['chi2']:.1f} > {i.limit:.1f}" if first else "") + ")")
        return "; ".join(parts)

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
                "methods": {k: v.state() for k, v in self._methods.items()}, "integrity": self._integrity.state(),
                "mounts": self._mounts_dict()}

    def _mounts_dict(self):
        """The last epoch's clock offsets and flexure (dicts), or None."""
        m = self._mounts
        if m is None or isinstance(m, dict):
            return m
        return {"time_offsets_s": m.time_offsets_s, "flexure": m.flexure}

    def summary(self, *, reference_sensor: str, fore_aft_sensor: str, athwartship_sensor: str, options) -> dict:
        """The JSON-able summary (the structure of :func:`session_summary`)."""
        return {
            "sensors": {name: s.block() for name, s in self._sensors.items()},
            "reference_sensor": reference_sensor,
            "fore_aft_sensor": fore_aft_sensor, "athwartship_sensor": athwartship_sensor,
            "n_epochs": self.n_epochs,
            "refraction_model": options.refraction_model, "refraction": options.refraction,
            "streak_correction": options.streak_correction,
            "windowed_full_frame_every": getattr(options, "windowed_full_frame_every", 0),
            "methods": {m: b.block(self.truth is not None) for m, b in self._methods.items()},
            "availability": {name: s.availability() for name, s in self._sensors.items()},
            "seeing": {name: s.seeing() for name, s in self._sensors.items()},
            **({"integrity": self._integrity.block()} if len(self.sensors) > 1 else {}),
            **(self._mounts_block(reference_sensor) if len(self.sensors) > 1 else {}),
        }

    def _mounts_block(self, reference_sensor: str) -> dict:
        """``time_offsets_s`` and ``flexure`` (pipeline._mounts): one entry per non-reference sensor."""
        m = self._mounts_dict() or {}
        others = [s for s in self.sensors if s != reference_sensor]
        none = {"offset_s": None, "sigma_s": None, "applied": False}
        return {"time_offsets_s": {s: m.get("time_offsets_s", {}).get(s, none) for s in others},
                "flexure": {s: m.get("flexure", {}).get(s, {"n_epochs": 0, "applied": False}) for s in others},
                "attitude_refers_to": f"the mount of the reference sensor {reference_sensor} (the other mounts' "
                                      f"estimated flexure applied where significant)"}


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
