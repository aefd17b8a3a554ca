"""The streaming session engine: each sensor's frame results in, epochs out, in order.

The per-frame work of a sensor (extraction, identification, sky, attitude, streak
correction: :class:`shipstar.pipeline._sensor.SensorProcessor`) depends only on that
sensor's frames up to the frame.  What needs both sensors is done here, as the frames
come, by :class:`SessionEngine`:

- **pairing**: an epoch is a frame of the reference sensor (time ``t``); each other
  sensor's frame nearest ``t`` within ``max_pair_offset_s`` is paired to it.  The pairing
  is decided as soon as each other sensor has delivered a frame at or after ``t`` (or has
  ended): later frames can only be further away.  That frame is the engine's only
  look-ahead: at most one frame period of the other sensor, none when the sensors expose
  together;
- **carry**: paired frames exposed at another time are turned to ``t`` with the deck's
  motion fitted (:mod:`shipstar.pipeline._motion`) to the solved single-sensor deck
  attitudes of every sensor up to the frames the decision used (the reference sensor's up
  to ``t``, each other sensor's up to its first frame at or after ``t``), so the numbers
  do not depend on how far other frames have arrived;
- **fusion**: the seed's rule and the joint solution (:func:`shipstar.pipeline._fusion.fuse_epoch`);
- **time checks**: frames in time order per sensor (a frame not later than the sensor's
  previous one is answered at once as a failed frame, never paired), the way each
  sensor's frame times were read staying the same, gaps in a sensor's frames.

What the engine holds is bounded: per sensor the frames not yet given out (one frame
period when the sensors run together), the last paired frame, and the deck attitudes of
the last :data:`~shipstar.pipeline._motion.MOTION_WINDOW_S` seconds.

Out come :class:`Emission` s in epoch order: an epoch with the single-sensor frames whose
rows go with it (the reference frame, the frames it paired that no earlier epoch had,
and frames no epoch can pair any more), and the warnings that arose.  Batch processing
(:func:`shipstar.pipeline.process_session`, ``shipstar measure``) and ``shipstar live``
are two drivers of this engine.

**Fixed-lag smoothing of the mounts** (``smooth_lag_s > 0``, ``shipstar measure``; live
has 0): the flexure estimate an epoch is fused with is, causally, the one of the epochs
before it (:mod:`shipstar.pipeline._mounts`), poor in the first seconds of a night and
under a sparse sky.  With a lag ``L`` the engine holds each epoch until the reference
sensor's epochs have reached ``t + L`` (or the session ends, or the caller flushes), and
then fuses it again with the estimate of every epoch up to then: the estimate of a
fixed-lag smoother (the estimator's own inputs, the sensors' disagreements, do not
depend on the fusion, so holding changes nothing else).  The monitor rows of a held epoch
are the smoothed estimate too.  An epoch fused with a rigid deck then and now is given
out unchanged, so a session without flexure has the rows of the causal engine.  Held:
the epochs of ``L`` seconds with their frames (about 0.2 MB a second for two sensors) and
the deck attitudes of ``L`` seconds more for the motion.  A frame paired before its
sensor's clock offset was applied is carried from its true time, with the deck's motion
fitted on both sides of the epoch.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace

from shipstar.errors import ShipstarError

__all__ = ["Emission", "SessionEngine", "GAP_WARNING_S"]

#: A sensor's frames further apart than this (s) are reported as a gap.
GAP_WARNING_S = 2.0
_EPS_S = 1e-9


def _replaced(obj, **changes):
    """``dataclasses.replace`` of one of the engine's frozen records (``Emission``,
    ``Epoch``, ``MountsSnapshot``: plain dataclasses, no ``__post_init__``, no slots) by
    copying its fields: ~1 us against replace's ~7 (four an epoch)."""
    new = object.__new__(type(obj))
    d = new.__dict__
    d.update(obj.__dict__)
    for k, v in changes.items():
        if k not in d:                                  # pragma: no cover - a typo here
            raise TypeError(f"{type(obj).__name__} has no field {k!r}")
        d[k] = v
    return new


@dataclass(frozen=True, eq=False)
class Emission:
    """What the engine gives out at once.

    Attributes
    ----------
    frames : tuple of FrameResult
        Frames whose single-sensor rows go out now, in time order.
    epoch : Epoch or None
        The epoch these rows belong to; None for frames left over when the reference
        sensor has ended, and for a frame refused for its time.
    warnings : tuple of str
        Warnings that arose with these frames (one line each).
    frame_shifts_s : tuple of float
        Per frame, the clock offset (s) applied to its time when it came (true exposure
        time minus header time; ``pipeline._mounts``); empty when none was applied to any.
        Its single-sensor row is stamped with the corrected time.
    """

    frames: tuple
    epoch: object
    warnings: tuple = ()
    frame_shifts_s: tuple = ()


def _applied(shifts) -> tuple:
    """``Emission.frame_shifts_s`` of per-frame clock offsets (s): empty when none was applied."""
    shifts = tuple(shifts)
    return shifts if any(abs(x) > _EPS_S for x in shifts) else ()


def _shifts(engine, rows) -> tuple:
    """The clock offsets applied to ``rows`` ``(t_s as corrected, sensor, frame)``."""
    return _applied(t - engine.t_s(fr) for t, _, fr in rows)


class SessionEngine:
    """Pairs, carries and fuses the sensors' frames as they come.

    Parameters
    ----------
    configs : sequence of SensorConfig
    options : PipelineOptions, optional
    start_utc_jd : (float, float)
        Time origin of every ``t_s``.
    reference : int
        Index of the sensor whose frame times are the epochs.

    Notes
    -----
    Feed each sensor's :class:`~shipstar.pipeline._sensor.FrameResult` s in time order with
    :meth:`add`; :meth:`close` a sensor when its frames have ended (or, live, stopped
    coming: it is then left out of the pairing until it delivers again).  Each call
    returns the :class:`Emission` s that became final.
    """

    def __init__(self, configs, options=None, *, start_utc_jd, reference: int = 0, smooth_lag_s: float = 0.0):
        from shipstar.pipeline._fusion import sensor_roles
        from shipstar.pipeline._motion import MotionWindow
        from shipstar.pipeline._options import PipelineOptions

        self.configs = tuple(configs)
        self.names = tuple(c.name for c in self.configs)
        if not self.configs:
            raise ShipstarError("no sensors given")
        if not 0 <= reference < len(self.configs):
            raise ShipstarError(f"reference sensor index {reference} out of range")
        self.options = PipelineOptions() if options is None else options
        self.start_utc_jd = (float(start_utc_jd[0]), float(start_utc_jd[1]))
        self.reference = int(reference)
        self.roles = sensor_roles(self.configs)
        n = len(self.configs)
        self._queue = [deque() for _ in range(n)]       # (t_s, FrameResult) not yet given out
        self._kept = [None] * n                         # (t_s, FrameResult) last paired frame (may pair again)
        self._closed = [False] * n
        self._last_t = [-math.inf] * n
        self._source = [None] * n                       # time_source of the sensor's first frame
        self._motion = MotionWindow(n)                  # solved single-sensor deck attitudes
        from shipstar.pipeline._mounts import MountEstimator

        self._mounts = MountEstimator(self.configs, self.reference) if n > 1 else None   # clocks, flexure
        if n > 1:
            # the chi-square quantile of the integrity check, computed once here (cached)
            from shipstar.pipeline._integrity import chi2_limit

            chi2_limit(3 * (n - 1))
        self._warnings: list = []
        self.n_epochs = 0
        lag = float(smooth_lag_s)
        if not (math.isfinite(lag) and lag >= 0.0):
            raise ShipstarError(f"smooth lag must be a number of seconds >= 0, got {smooth_lag_s!r}")
        #: the fixed lag (s) of the mounts' smoothing (module docstring; 0: causal)
        self.smooth_lag_s = lag if self._mounts is not None else 0.0
        self._held = deque()     # (t_s, Emission, fusion inputs or None) not yet given out
        self._windows: dict = {}     # key -> (t_lo_s, t_hi_s): record the mounts' estimator there
        self._records: dict = {}     # key -> {"states": [[t_s, state]], "shifts": [[sensor, t_s, shift_s]]}
        self._replay = None          # (deque of (t_s, state), {(sensor, t_s): shift_s}) being replayed

    # -- resuming (shipstar measure --resume) ------------------------------------------------
    def record_mounts(self, windows: dict) -> None:
        """Keep what a resume that replays from each window needs (``{key: (t_lo_s, t_hi_s)}``,
        seconds from the start): the mounts' estimator state before every epoch at ``t_lo
        <= t <= t_hi`` and the clock shift applied to every frame added at ``t_lo <= t <
        t_hi + 1 s`` (header time).  A resume (:meth:`replay_mounts`) replays the frames
        from ``t_lo`` with the estimator as it was: its own updates from the replayed
        epochs alone would start afresh.  Bounded: drop what is no longer needed
        (:meth:`drop_records`)."""
        if self._mounts is not None:
            self._windows.update({k: (float(a), float(b)) for k, (a, b) in windows.items()})
            self._sort_windows()

    def _sort_windows(self) -> None:
        self._win = sorted((lo, hi, k) for k, (lo, hi) in self._windows.items())
        self._win_lo = [w[0] for w in self._win]
        self._win_span = max((hi - lo for lo, hi, _ in self._win), default=0.0)

    def _windows_at(self, t_s: float, after_s: float = 0.0) -> list:
        """Keys of the windows with ``lo <= t_s <= hi + after_s`` (bisection: a night has
        hundreds of chunks)."""
        import bisect

        out = []
        k = bisect.bisect_right(self._win_lo, t_s + _EPS_S) - 1
        while k >= 0 and self._win[k][0] >= t_s - self._win_span - after_s - 1.0:
            lo, hi, key = self._win[k]
            if lo - _EPS_S <= t_s <= hi + after_s + _EPS_S:
                out.append(key)
            k -= 1
        return out

    def mounts_record(self, key):
        """What was kept for window ``key`` (JSON-able), or None."""
        return self._records.get(key)

    def drop_records(self, keep) -> None:
        """Forget the windows and records whose key is not in ``keep``."""
        self._windows = {k: v for k, v in self._windows.items() if k in keep}
        self._records = {k: v for k, v in self._records.items() if k in keep}
        self._sort_windows()

    def replay_mounts(self, record) -> None:
        """Replay with a record kept by :meth:`record_mounts` (a resume): the estimator
        starts from the state before the window's first epoch, is set to the kept state
        before each of its epochs, and the kept shifts are applied to the window's frames;
        past the window the engine goes on as the uninterrupted run did."""
        if self._mounts is None or not record or not record.get("states"):
            return
        states = deque((float(t), st) for t, st in record["states"])
        shifts = {(int(k), round(float(t), 6)): float(x) for k, t, x in record.get("shifts", ())}
        self._mounts.restore(states[0][1])
        self._replay = (states, shifts)

    def _shift_s(self, s: int, t_header_s: float) -> float:
        """The clock shift (s) applied to sensor ``s``'s frame at header time ``t_header_s``."""
        if self._mounts is None:
            return 0.0
        if self._replay is not None:
            kept = self._replay[1].get((s, round(t_header_s, 6)))
            if kept is not None:
                return kept
        x = self._mounts.shift_s(s)
        if self._windows:
            for key in self._windows_at(t_header_s, 1.0):
                self._records.setdefault(key, {"states": [], "shifts": []})["shifts"].append([s, t_header_s, x])
        return x

    def _mounts_before_epoch(self, t_k: float) -> None:
        """Replay: the kept state before epoch ``t_k``; recording: keep it."""
        if self._replay is not None:
            states = self._replay[0]
            while states and states[0][0] < t_k - 1e-6:
                states.popleft()
            if states and abs(states[0][0] - t_k) <= 1e-6:
                self._mounts.restore(states.popleft()[1])
            if not states:
                self._replay = None
        if self._windows:
            keys = self._windows_at(t_k)
            state = self._mounts.state() if keys else None
            for key in keys:
                self._records.setdefault(key, {"states": [], "shifts": []})["states"].append([t_k, state])

    # -- input -----------------------------------------------------------------------------
    def t_s(self, fr) -> float:
        """Seconds from the session start to a frame."""
        return ((fr.utc_jd1 - self.start_utc_jd[0]) + (fr.utc_jd2 - self.start_utc_jd[1])) * 86400.0

    def _index(self, sensor: str) -> int:
        try:
            return self.names.index(sensor)
        except ValueError:
            raise ShipstarError(f"no sensor {sensor!r} in this session (have {', '.join(self.names)})") from None

    def add(self, fr) -> list:
        """Add one frame result of one sensor; returns the emissions that became final."""
        s = self._index(fr.sensor)
        t_header = self.t_s(fr)
        t = t_header + self._shift_s(s, t_header)       # clock offset
        if t <= self._last_t[s] + _EPS_S:
            reason = (f"frame time {fr.utc_iso} is not later than the sensor's previous frame "
                      f"({self._last_t[s] - t:.6f} s earlier or the same): refused")
            from shipstar.ship import ShipAttitude

            bad = replace(fr, solved=False, reason=reason, ship=ShipAttitude.failed(reason, "single"))
            refused = Emission((bad,), None, (f"sensor {fr.sensor}: frame {fr.label}: {reason}",),
                               _shifts(self, [(t, s, fr)]))
            if self._held:                               # after the held epochs: rows in time order
                self._held.append((self._held[-1][0], refused, None))
                return []
            return [refused]
        self._check_time(s, fr, t)
        self._last_t[s] = t
        self._closed[s] = False
        self._queue[s].append((t, fr))
        inst = self.configs[s].installation
        if fr.ship.solved and inst is not None:
            C_ds = inst.C_deck_from_sensor
            self._motion.add(s, t, fr.ship.C_hor_from_deck, C_ds @ fr.horizontal.covariance_rad2 @ C_ds.T)
        return self._advance()

    def close(self, sensor: str) -> list:
        """No more frames from ``sensor`` (for now); returns the emissions that became final."""
        self._closed[self._index(sensor)] = True
        return self._advance()

    def finish(self) -> list:
        """Close every sensor; returns the remaining emissions."""
        for k in range(len(self.names)):
            self._closed[k] = True
        return self._advance()

    def flush(self) -> list:
        """Give out the held epochs now, fused with the estimate as it stands (a run that
        stops early; nothing else changes)."""
        return self._release(math.inf)

    def next_epoch_t_s(self) -> float | None:
        """Time of the next epoch not yet given out (held, or its reference frame held), or None."""
        for t, e, _ in self._held:
            if e.epoch is not None:
                return t
        q = self._queue[self.reference]
        return q[0][0] if q else None

    @property
    def n_pending(self) -> int:
        """Frames held (not yet given out)."""
        return sum(len(q) for q in self._queue) + sum(len(e.frames) for _, e, _ in self._held)

    def _check_time(self, s: int, fr, t: float) -> None:
        name = self.names[s]
        src = getattr(fr, "time_source", "")
        if self._source[s] is None:
            self._source[s] = src
        elif src != self._source[s]:
            self._warnings.append(f"sensor {name}: frame {fr.label}'s time comes from {src or 'the caller'}, "
                                  f"the frames' before it from {self._source[s] or 'the caller'}")
            self._source[s] = src
        gap = t - self._last_t[s]
        if math.isfinite(gap) and gap > GAP_WARNING_S:
            self._warnings.append(f"sensor {name}: {gap:.1f} s without frames before {fr.label} ({fr.utc_iso})")

    # -- output ----------------------------------------------------------------------------
    def _advance(self) -> list:
        out = []
        ref = self.reference
        others = [s for s in range(len(self.names)) if s != ref]
        while True:
            R = self._queue[ref]
            if not R:
                if self._closed[ref]:
                    rest = sorted(((t, s, fr) for s in others for t, fr in self._queue[s]), key=lambda x: x[:2])
                    for s in others:
                        self._queue[s].clear()
                    out.extend(self._release(math.inf))
                    if rest or self._warnings:
                        out.append(Emission(tuple(fr for _, _, fr in rest), None, self._take_warnings(),
                                            _shifts(self, rest)))
                break
            t_k = R[0][0]
            if not all(self._closed[s] or (self._queue[s] and self._queue[s][-1][0] >= t_k - _EPS_S)
                       for s in others):
                break
            out.extend(self._epoch(R.popleft(), others))
        return out

    def _take_warnings(self) -> tuple:
        w, self._warnings = tuple(self._warnings), []
        return w

    def _release(self, t_now: float) -> list:
        """The held emissions of epochs at or before ``t_now - smooth_lag_s``, re-fused."""
        out = []
        while self._held and self._held[0][0] <= t_now - self.smooth_lag_s + _EPS_S:
            _, emission, inputs = self._held.popleft()
            out.append(emission if inputs is None else self._smoothed(emission, inputs))
        return out

    def _smoothed(self, emission, inputs) -> Emission:
        """A held epoch fused with the mounts' estimate of now (module docstring)."""
        from shipstar.pipeline._fusion import fuse_epoch
        from shipstar.pipeline._mounts import is_flexed

        t_k, paired, offsets, motion, fit, shifts, configs_then, vf = inputs
        epoch = emission.epoch
        fr_ref = paired[self.reference]
        offsets = list(offsets)
        changes = [0.0 if p is None or s == self.reference or not self.options.compensate_motion
                   else self._mounts.shift_s(s) - shifts[s] for s, p in enumerate(paired)]
        retimed = any(abs(c) > 1e-9 for c in changes)
        if retimed:
            # the clock offsets as estimated now: a frame paired before its sensor's offset
            # was applied is carried from its true time (the pairing stays), with the deck's
            # motion fitted to the attitudes on both sides of the epoch
            fit = self._motion.fit(t_k + 0.5 * self._motion.window_s) or fit
            retimed = fit is not None
            if retimed:
                offsets = [o + c for o, c in zip(offsets, changes)]
                # and the single rows of the held frames at their true times, as the fusion
                emission = replace(emission, frame_shifts_s=_applied(
                    0.0 if self._index(fr.sensor) == self.reference else self._mounts.shift_s(self._index(fr.sensor))
                    for fr in emission.frames))
        configs = self._mounts.configs_for(fr_ref, None if fit is None else fit.omega_at(t_k))
        if retimed or any(is_flexed(c) for c in (*configs, *configs_then)):
            epoch = fuse_epoch(epoch.index, t_k, self.start_utc_jd, configs, paired, offsets,
                               fit if retimed else motion, self.options, self.roles, reference=self.reference,
                               variance_factor=vf)
        mounts = emission.epoch.mounts
        if mounts is not None:
            mounts = _replaced(mounts, monitor=self._mounts.monitor(fr_ref))
        return _replaced(emission, epoch=_replaced(epoch, mounts=mounts))

    def _epoch(self, ref_item, others) -> list:
        from shipstar.pipeline._fusion import fuse_epoch

        t_k, fr_ref = ref_item
        n = len(self.names)
        paired, offsets, limits = [None] * n, [math.nan] * n, [t_k] * n
        paired[self.reference], offsets[self.reference] = fr_ref, 0.0
        rows = [(t_k, self.reference, fr_ref)]
        window = self.options.max_pair_offset_s
        for s in others:
            q = self._queue[s]
            first = next((j for j, (t, _) in enumerate(q) if t >= t_k - _EPS_S), len(q))
            cands = ([self._kept[s]] if self._kept[s] is not None else []) + list(q)[:first + 1]
            best = min(cands, key=lambda c: (abs(c[0] - t_k), c[0])) if cands else None
            if best is not None and abs(best[0] - t_k) > window + _EPS_S:
                best = None
            if first < len(q):
                limits[s] = q[first][0]
            elif cands:
                limits[s] = cands[-1][0]
            while q and q[0][0] < t_k - _EPS_S:          # no later epoch can pair these
                rows.append((q[0][0], s, q.popleft()[1]))
            if best is not None and q and q[0][1] is best[1]:
                rows.append((q[0][0], s, q.popleft()[1]))
            if best is not None:
                paired[s], offsets[s] = best[1], best[0] - t_k
            self._kept[s] = best
        motion = None
        if self.options.compensate_motion and any(abs(o) > 1e-6 for o in offsets if math.isfinite(o)):
            motion = self._motion.fit(limits)
        shifts, fit, configs, vf = None, None, self.configs, 1.0
        if self._mounts is not None:                    # clock offsets and flexure (pipeline._mounts)
            self._mounts_before_epoch(t_k)
            fit = motion if motion is not None else self._motion.fit(limits)
            configs = self._mounts.configs_for(fr_ref, None if fit is None else fit.omega_at(t_k))
            vf = self._mounts.variance_factor()
        epoch = fuse_epoch(self.n_epochs, t_k, self.start_utc_jd, configs, paired, offsets, motion,
                           self.options, self.roles, reference=self.reference, variance_factor=vf)
        if self._mounts is not None:
            shifts = [0.0 if p is None else t_k + o - self.t_s(p) for p, o in zip(paired, offsets)]
            # a held epoch's monitor is that of its release (_smoothed)
            epoch = _replaced(epoch, mounts=self._mounts.update(t_k, epoch, paired, shifts, configs, fit,
                                                                with_monitor=self.smooth_lag_s <= 0.0))
        self.n_epochs += 1
        self._motion.prune(t_k - self.smooth_lag_s)     # the held epochs' deck motion stays
        rows.sort(key=lambda r: (r[0], r[1]))
        emission = Emission(tuple(fr for _, _, fr in rows), epoch, self._take_warnings(), _shifts(self, rows))
        if self.smooth_lag_s <= 0.0:
            return [emission]
        self._held.append((t_k, emission, (t_k, paired, offsets, motion, fit, shifts, configs, vf)))
        return self._release(t_k)
