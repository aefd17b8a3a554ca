"""``shipstar live``: the streaming engine on frames as they arrive (docs/live.md).

One loop in the main process, fed by a queue:

- file events from the sensors' directories (:class:`~shipstar.live._watch.FrameWatcher`):
  a complete FITS frame is read (header only), checked (time order, the sensor its
  header names), given the ship's position and weather at its time, and sent to its
  sensor's worker process (:class:`~shipstar.live._workers.SensorWorkers`); a frame still
  being written waits for its next event, and is reported after
  :attr:`LiveSettings.incomplete_timeout_s`;
- frame results from the workers, handed to the :class:`~shipstar.pipeline.SessionEngine`
  in each sensor's frame order; its emissions go out at once to the CSV, UDP and the
  statistics;
- once a second: a status (stderr line, UDP status message), sensors whose frames stopped
  coming are left out of the pairing, growing CSV tables are read.

A sensor falls behind when frames arrive faster than its worker solves them: the loop
keeps at most :attr:`LiveSettings.max_waiting` frames waiting per sensor and skips the
older ones, each written as an unsolved row with reason ``skipped (behind)``: never an
unbounded queue, never a silent gap.  Every frame that appears is counted: solved,
unsolved with its reason, or (no time in its header) listed as unreadable.
"""

from __future__ import annotations

import collections
import math
import queue
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from shipstar.errors import ShipstarError

__all__ = ["LiveSettings", "LiveOutcome", "run_live"]

SKIPPED_BEHIND = "skipped (behind)"


@dataclass(frozen=True, eq=False)
class LiveSettings:
    """How ``shipstar live`` runs.

    Attributes
    ----------
    configs : tuple of SensorConfig
    dirs : tuple of Path
        Each sensor's frame directory (``configs`` order).
    options : PipelineOptions
    reference : int
    date_obs_is : str
    track, weather
        The ship's position and weather: fixed tables, or growing ones
        (:class:`~shipstar.live._nav.LiveTrack`, :class:`~shipstar.live._nav.LiveWeather`).
    tails : tuple of CsvTail
        Growing CSV files to read every :attr:`tail_period_s`.
    nav : NavReceiver or None
    out_csv : Path or None
    udp : tuple of (host, port)
    fmt : str
    method : str
    stop_after_s : float or None
    stale_s : float
        A sensor without frames for this long is left out of the pairing.
    max_waiting : int
        Frames waiting per sensor before the older ones are skipped.
    incomplete_timeout_s : float
        A frame file still incomplete this long after its last event is reported.
    status_period_s : float
    header_checks : tuple of HeaderCheck
        Each sensor's header cross-checks (``configs`` order; empty: only the SENSOR name
        is checked): a frame that contradicts the flags is an unsolved row with the
        reason; with ``--trust-flags`` it is processed and the override recorded.
    json_status : bool
        Status lines on stderr as text (False: none).
    """

    configs: tuple
    dirs: tuple
    options: object
    reference: int = 0
    date_obs_is: str = "start"
    track: object = None
    weather: object = None
    tails: tuple = ()
    nav: object = None
    out_csv: Path | None = None
    udp: tuple = ()
    fmt: str = "jsonl"
    method: str = "joint"
    stop_after_s: float | None = None
    stale_s: float = 2.0
    max_waiting: int = 2
    incomplete_timeout_s: float = 2.0
    status_period_s: float = 1.0
    status_stream: object = None
    tail_period_s: float = 0.2
    eop: dict | None = None
    header_checks: tuple = ()
    http: tuple | None = None       # (host, port) of the operator console (shipstar.live._http), or None
    ins: object = None              # shipstar.live._ins_live.LiveIns (--ins-udp), or None


@dataclass(frozen=True, eq=False)
class LiveOutcome:
    """What a live run gave: the summary (``measure``'s, plus the live counts)."""

    summary: dict
    stopped: str
    out_csv: Path | None


@dataclass
class _Sensor:
    """The main loop's state of one sensor (bounded)."""

    name: str
    seen: collections.OrderedDict = field(default_factory=collections.OrderedDict)   # name -> file signature
    incomplete: dict = field(default_factory=dict)        # path -> (first seen, last event) monotonic s
    waiting: collections.deque = field(default_factory=collections.deque)  # (index, Frame, arrival s)
    in_flight: int | None = None
    ready: dict = field(default_factory=dict)             # index -> FrameResult not yet handed to the engine
    arrival: dict = field(default_factory=dict)           # index -> arrival monotonic s
    next_index: int = 0
    next_feed: int = 0
    last_t_s: float = -math.inf
    last_frame_s: float | None = None                      # monotonic s of the last frame event
    absent: bool = False
    frames_in: int = 0
    frames_out: int = 0
    unsolved: int = 0
    skipped: int = 0
    unreadable: list = field(default_factory=list)
    n_unreadable: int = 0
    interval_in: int = 0
    interval_out: int = 0
    interval_unsolved: int = 0
    newest_done_jd: tuple | None = None
    reasons: collections.Counter = field(default_factory=collections.Counter)

    def take(self, name: str, signature) -> None:
        """Remember a file taken (the last 1000): ``signature`` = (inode, mtime, size), so
        that a camera reusing file names still has each new frame taken."""
        self.seen[name] = signature
        self.seen.move_to_end(name)
        if len(self.seen) > 1000:
            self.seen.popitem(last=False)

    def taken(self, name: str, signature) -> bool:
        return self.seen.get(name) == signature


class _Latency:
    """Row latencies (file event to row out), a bounded reservoir for median and p99."""

    def __init__(self, size: int = 100000):
        self.values = collections.deque(maxlen=size)

    def add(self, seconds: float) -> None:
        self.values.append(seconds)

    def quantiles_ms(self) -> dict:
        if not self.values:
            return {"n": 0, "median_ms": None, "p99_ms": None, "max_ms": None}
        import numpy as np

        v = np.array(self.values) * 1000.0
        return {"n": int(len(v)), "median_ms": float(np.median(v)), "p99_ms": float(np.percentile(v, 99)),
                "max_ms": float(v.max())}


class _Live:
    def __init__(self, settings: LiveSettings, stop: threading.Event):
        from shipstar._codeid import software_line
        from shipstar.live._outputs import UdpOutput
        from shipstar.live._watch import FrameWatcher
        from shipstar.live._workers import SensorWorkers

        self.s = settings
        self.software = software_line()           # the CSV's provenance, made before any frame (~10 ms)
        self.stop = stop
        self.names = tuple(c.name for c in settings.configs)
        self.sensors = {n: _Sensor(n) for n in self.names}
        self.events: queue.Queue = queue.Queue()
        self.messages: list = []                  # one-line reports (also on stderr)
        self.warnings: list = []
        self.engine = None
        self.writer = None
        self.stats = None
        self.latency = _Latency()
        self.eop = settings.eop
        self._eop_checked = -math.inf
        self.t0 = time.monotonic()
        self.udp = (UdpOutput(settings.udp, settings.fmt, settings.method, self.names, self.names[settings.reference])
                    if settings.udp else None)
        self.console = None
        if settings.http is not None:              # a port in use: an error before the workers start
            from shipstar.live._http import Console

            self.console = Console(settings.http, settings.configs, settings.dirs, method=settings.method,
                                   reference=settings.reference)
            self.console.start()
            self.report(f"operator console at {self.console.url}")
        self.workers = SensorWorkers(settings.configs, settings.options)
        self._reader = threading.Thread(target=self._read_results, name="shipstar-live-results", daemon=True)
        self._reader.start()
        self.watcher = FrameWatcher(dict(zip(self.names, settings.dirs)), self.events)
        self.n_ready = 0

    # -- reports ---------------------------------------------------------------------------
    def report(self, text: str) -> None:
        line = " ".join(str(text).split())
        self.messages.append(line)
        if len(self.messages) > 1000:
            del self.messages[:500]
        print(f"shipstar live: {line}", file=sys.stderr, flush=True)

    def warn(self, text: str) -> None:
        if text not in self.warnings:
            self.warnings.append(text)
            self.report(f"warning: {text}")
            if self.writer is not None:
                self.writer.comment(f"warning: {text}")

    # -- threads -----------------------------------------------------------------------------
    def _read_results(self) -> None:
        while True:
            try:
                msg = self.workers.results.get()
            except (EOFError, OSError, ValueError):
                return
            self.events.put(msg)
            if msg == ("bye",):
                return

    # -- frames in ---------------------------------------------------------------------------
    def on_file(self, name: str, path: str, when: float) -> None:
        from shipstar._fitsio import file_is_complete

        sensor = self.sensors[name]
        p = Path(path)
        signature = _signature(p)
        if signature is None or sensor.taken(p.name, signature):
            return
        complete, detail = file_is_complete(p)
        if not complete:
            first = sensor.incomplete.get(path, (when, when))[0]
            sensor.incomplete[path] = (first, when)
            return
        sensor.incomplete.pop(path, None)
        sensor.take(p.name, _signature(p))
        self.accept(sensor, p, when)

    def accept(self, sensor: _Sensor, path: Path, when: float) -> None:
        """A complete frame file: read its header, check it, queue it for its worker."""
        from shipstar._fitsio import read_fits_header
        from shipstar.pipeline import Frame
        from shipstar.pipeline._sensor import FrameResult

        sensor.frames_in += 1
        sensor.interval_in += 1
        sensor.last_frame_s = when
        if sensor.absent:
            sensor.absent = False
            self.report(f"sensor {sensor.name}: frames again ({path.name})")
        try:
            info = read_fits_header(path, date_obs_is=self.s.date_obs_is)
            jd1, jd2 = info.mid_utc_jd()
        except ShipstarError as exc:
            self.unreadable(sensor, path.name, str(exc))
            return
        frame = Frame(jd1, jd2, path.name, path=path, sensor=info.sensor_name, time_source=info.time_source,
                      exposure_s=info.exposure_s)
        if self.engine is None:
            self.start_engine(frame)
        t_s = self.engine.t_s(frame)
        index = sensor.next_index
        sensor.next_index += 1
        sensor.arrival[index] = when
        config = self.s.configs[self.names.index(sensor.name)]
        reason = self._header_reason(sensor, config, info, frame)
        if not reason and t_s <= sensor.last_t_s:
            reason = (f"frame time {frame.utc_iso} is not later than the sensor's previous frame "
                      f"({sensor.last_t_s - t_s:.6f} s earlier or the same): refused")
        if reason:
            self.report(f"sensor {sensor.name}: {path.name}: {reason}")
            self.done(sensor, index, FrameResult.failed(sensor.name, index, frame, reason))
            return
        sensor.last_t_s = t_s
        try:
            site = self.s.track.site(jd1, jd2)
            weather = self.s.weather.weather(jd1, jd2)
        except ShipstarError as exc:
            self.done(sensor, index, FrameResult.failed(sensor.name, index, frame, str(exc)))
            return
        sensor.waiting.append((index, frame, t_s, site, weather))
        self.dispatch(sensor)

    def _header_reason(self, sensor: _Sensor, config, info, frame) -> str:
        """Why the frame's header refuses it ('' when it does not): the header cross-checks
        (a contradiction overridden by --trust-flags is written as a comment where it first
        arises)."""
        if not self.s.header_checks:
            if frame.sensor and frame.sensor not in (sensor.name, config.camera.name):
                return f"the frame's header names sensor {frame.sensor!r}, not {sensor.name!r}"
            return ""
        check = self.s.header_checks[self.names.index(sensor.name)]
        try:
            found = check(info)
        except ShipstarError as exc:
            return f"refused: {exc}"
        counts = {o["key"]: o["n_frames"] for o in check.overrides()}
        for c in found:
            if counts.get(c.key) == 1:
                self.report(f"sensor {sensor.name}: --trust-flags: {c.text}")
                if self.writer is not None:
                    self.writer.comment(f"header override: sensor {sensor.name}: {c.text}")
        return ""

    def unreadable(self, sensor: _Sensor, name: str, reason: str) -> None:
        sensor.n_unreadable += 1
        if len(sensor.unreadable) < 20:
            sensor.unreadable.append({"frame": name, "reason": reason})
        self.report(f"sensor {sensor.name}: {name}: unreadable, not processed: {reason}")

    def start_engine(self, frame) -> None:
        from shipstar.pipeline import SessionEngine
        from shipstar.pipeline._output import AttitudeCsvWriter
        from shipstar.pipeline._stats import SessionStats

        start = (frame.utc_jd1, frame.utc_jd2)
        self.engine = SessionEngine(self.s.configs, self.s.options, start_utc_jd=start, reference=self.s.reference)
        self.stats = SessionStats(self.names)
        self.eop = self.s.eop or _eop_at(frame)
        self._eop_checked = time.monotonic()
        if self.s.out_csv is not None:
            eop = self.eop
            comments = ["shipstar live: ship attitude (docs/file-formats.md)", self.software,
                        f"eop_quality = {eop['quality']}, dut1_error_s = {eop['dut1_error_s']:.3g}, "
                        f"polar_motion_error_arcsec = {eop['polar_motion_error_arcsec']:.3g}"]
            comments += [f"warning: {w}" for w in self.warnings] or [
                "warnings at the start: none (a warning that arises later is written where it arises)"]
            if any(c.trust_flags for c in self.s.header_checks):
                comments.append("trust_flags = true: the flags are used where the frames' FITS headers contradict "
                                "them (each contradiction is a '# header override:' line where it first arises)")
            self.writer = AttitudeCsvWriter(self.s.out_csv, self.names, start, comments)

    def dispatch(self, sensor: _Sensor) -> None:
        """Send the sensor's next frame to its worker, skipping to the newest when behind."""
        from shipstar.pipeline._sensor import FrameResult

        while len(sensor.waiting) > self.s.max_waiting:
            index, frame, *_ = sensor.waiting.popleft()
            sensor.skipped += 1
            if sensor.skipped == 1 or sensor.skipped % 100 == 0:
                self.report(f"sensor {sensor.name}: falling behind, skipping to the newest frames "
                            f"({sensor.skipped} skipped so far)")
            self.done(sensor, index, FrameResult.failed(sensor.name, index, frame, SKIPPED_BEHIND))
        if sensor.in_flight is None and sensor.waiting and self.n_ready == len(self.names):
            index, frame, t_s, site, weather = sensor.waiting.popleft()
            sensor.in_flight = index
            self.workers.send(sensor.name, index, frame, t_s, site, weather)

    # -- results -----------------------------------------------------------------------------
    def on_result(self, name: str, index: int, fr, warnings: list) -> None:
        sensor = self.sensors[name]
        for w in warnings:
            self.warn(w)
        if sensor.in_flight == index:
            sensor.in_flight = None
        self.done(sensor, index, fr)
        self.dispatch(sensor)

    def done(self, sensor: _Sensor, index: int, fr) -> None:
        """A frame's result; handed to the engine in the sensor's frame order."""
        sensor.ready[index] = fr
        while sensor.next_feed in sensor.ready:
            result = sensor.ready.pop(sensor.next_feed)
            sensor.next_feed += 1
            sensor.frames_out += 1
            sensor.interval_out += 1
            if not result.solved:
                sensor.unsolved += 1
                sensor.interval_unsolved += 1
                sensor.reasons[_reason_kind(result.reason)] += 1
            sensor.newest_done_jd = (result.utc_jd1, result.utc_jd2)
            self.out(self.engine.add(result))

    def out(self, emissions) -> None:
        now = time.monotonic()
        for e in emissions:
            degraded = bool(self.warnings)
            if self.writer is not None:
                self.writer.write(e)
            if self.udp is not None:
                self.udp.emission(e, self.engine.start_utc_jd, degraded=degraded)
            self.stats.add(e)
            if self.console is not None:
                self.console.emission(e, self.engine.start_utc_jd)
            if self.s.ins is not None:                # --ins-udp: the INS corrected by this epoch
                self.s.ins.star(e)
            for fr in e.frames:
                arrival = self.sensors[fr.sensor].arrival.pop(fr.index, None)
                if arrival is not None:
                    self.latency.add(now - arrival)
            for w in e.warnings:
                self.warn(w)

    # -- once a second -----------------------------------------------------------------------
    def housekeeping(self, now: float) -> None:
        from shipstar.pipeline._sensor import FrameResult

        for sensor in self.sensors.values():
            for path, (first, last) in list(sensor.incomplete.items()):
                if now - last > self.s.incomplete_timeout_s:
                    del sensor.incomplete[path]
                    sensor.take(Path(path).name, _signature(Path(path)))
                    _, detail = _complete(path)
                    self.report(f"sensor {sensor.name}: {Path(path).name} stayed incomplete for "
                                f"{now - first:.1f} s ({detail}): not processed")
                    self._incomplete_frame(sensor, Path(path), detail, now, FrameResult)
            quiet = sensor.last_frame_s is None or now - sensor.last_frame_s > self.s.stale_s
            if (quiet and not sensor.absent and sensor.in_flight is None and not sensor.waiting
                    and self.engine is not None):
                sensor.absent = True
                since = "no frame yet" if sensor.last_frame_s is None else \
                    f"none for {now - sensor.last_frame_s:.1f} s"
                self.report(f"sensor {sensor.name}: {since}; fusing without it until it delivers again")
                self.out(self.engine.close(sensor.name))

    def _incomplete_frame(self, sensor, path: Path, detail: str, now: float, FrameResult) -> None:
        """A frame that stayed half-written: an unsolved row if its header gives a time."""
        from shipstar._fitsio import read_fits_header
        from shipstar.pipeline import Frame

        sensor.frames_in += 1
        sensor.interval_in += 1
        try:
            info = read_fits_header(path, date_obs_is=self.s.date_obs_is)
            jd1, jd2 = info.mid_utc_jd()
        except ShipstarError as exc:
            self.unreadable(sensor, path.name, f"incomplete ({detail}); {exc}")
            return
        frame = Frame(jd1, jd2, path.name, path=path, time_source=info.time_source, exposure_s=info.exposure_s)
        if self.engine is None:
            self.start_engine(frame)
        t_s = self.engine.t_s(frame)
        index = sensor.next_index
        sensor.next_index += 1
        reason = f"file stayed incomplete ({detail})"
        if t_s > sensor.last_t_s:
            sensor.last_t_s = t_s
        self.done(sensor, index, FrameResult.failed(sensor.name, index, frame, reason))

    def _refresh_eop(self) -> None:
        """Earth orientation quality at the newest frame's time, every 10 minutes."""
        newest = [s.newest_done_jd for s in self.sensors.values() if s.newest_done_jd is not None]
        if newest and time.monotonic() - self._eop_checked > 600.0:
            self._eop_checked = time.monotonic()
            self.eop = _eop_at(_Time(*newest[0]))

    def status(self) -> dict:
        from shipstar.sky.time import utc_jd_now

        self._refresh_eop()
        now_jd = utc_jd_now()
        sensors = {}
        for s in self.sensors.values():
            lag = None if s.newest_done_jd is None else \
                ((now_jd[0] - s.newest_done_jd[0]) + (now_jd[1] - s.newest_done_jd[1])) * 86400.0
            sensors[s.name] = {"frames_in": s.frames_in, "frames_out": s.frames_out, "unsolved": s.unsolved,
                               "skipped_behind": s.skipped, "unreadable": s.n_unreadable,
                               "waiting": len(s.waiting) + (s.in_flight is not None),
                               "lag_s": lag, "absent": s.absent, "unsolved_reasons": dict(s.reasons.most_common(5))}
        nav = self.s.nav.stats() if self.s.nav is not None else None
        return {"time_utc": _iso(now_jd), "run_s": round(time.monotonic() - self.t0, 3), "sensors": sensors,
                "epochs": self.stats.n_epochs if self.stats else 0,
                "inconsistent": self.stats.n_inconsistent if self.stats else 0, "latency": self.latency.quantiles_ms(),
                "eop": self.eop, "nav": nav, "warnings": len(self.warnings)}

    def send_status(self) -> None:
        from shipstar.live._nmea import SensorHealth
        from shipstar.sky.time import utc_jd_now

        st = self.status()
        if self.udp is not None:
            health = [SensorHealth(name, s.interval_in, s.interval_out,
                                   st["sensors"][name]["lag_s"], s.interval_unsolved)
                      for name, s in self.sensors.items()]
            self.udp.status(st, health, utc_jd_now(), self.eop)
        if self.console is not None:               # with --ins-udp: the INS error estimate too
            self.console.status({**st, "ins": self.s.ins.summary()} if self.s.ins is not None else st)
        for s in self.sensors.values():
            s.interval_in = s.interval_out = s.interval_unsolved = 0
        stream = self.s.status_stream
        if stream is not None:
            parts = [f"{n} in {v['frames_in']} out {v['frames_out']} unsolved {v['unsolved']}"
                     + (f" skipped {v['skipped_behind']}" if v["skipped_behind"] else "")
                     + (" ABSENT" if v["absent"] else "")
                     for n, v in st["sensors"].items()]
            lat = st["latency"]
            med = "-" if lat["median_ms"] is None else f"{lat['median_ms']:.0f}"
            eop = (st["eop"] or {}).get("quality", "-")
            bad = f" ({st['inconsistent']} inconsistent)" if st["inconsistent"] else ""
            stream.write(f"shipstar live: {st['run_s']:.0f} s, {st['epochs']} epochs{bad}; " + "; ".join(parts)
                         + f"; latency median {med} ms; Earth orientation {eop}\n")
            stream.flush()

    # -- the loop ------------------------------------------------------------------------------
    def run(self) -> str:
        next_status = next_tail = time.monotonic()
        deadline = None if self.s.stop_after_s is None else self.t0 + self.s.stop_after_s
        failed = ""
        while self.n_ready < len(self.names) and not self.stop.is_set():
            failed = self._pump(0.1) or failed
            if failed:
                raise ShipstarError(failed)
            if deadline is not None and time.monotonic() > deadline:
                break
        self.watcher.start()
        self.report("watching " + ", ".join(f"{n}={d}" for n, d in zip(self.names, self.s.dirs)))
        while not self.stop.is_set():
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            failed = self._pump(0.02)
            if failed:
                raise ShipstarError(failed)
            if self.s.ins is not None:                # --ins-udp: each INS record corrected and sent (every 20 ms)
                self.s.ins.poll(self.udp)
            now = time.monotonic()
            if now >= next_tail:
                for tail in self.s.tails:
                    tail.poll()
                next_tail = now + self.s.tail_period_s
            if now >= next_status:
                self.housekeeping(now)
                self.send_status()
                next_status = now + self.s.status_period_s
        return getattr(self.stop, "reason", "") if self.stop.is_set() else ("stop-after" if deadline else "")

    def _pump(self, timeout_s: float) -> str:
        """Handle the queued events (waiting at most ``timeout_s`` for the first); returns a
        fatal message, or ''."""
        try:
            item = self.events.get(timeout=timeout_s)
        except queue.Empty:
            return ""
        while True:
            kind = item[0]
            if kind == "file":
                self.on_file(item[1], item[2], item[3])
            elif kind == "result":
                self.on_result(item[1], item[2], item[3], item[4])
            elif kind == "ready":
                self.n_ready += 1
                for sensor in self.sensors.values():
                    self.dispatch(sensor)
            elif kind == "failed":
                return f"sensor {item[1]}'s worker could not start: {item[2]}"
            elif kind == "dir-gone":
                self.report(f"sensor {item[1]}: its directory {item[2]} is gone; waiting for it to come back")
            elif kind == "dir-wait":
                self.report(f"sensor {item[1]}: waiting for its directory {item[2]} to appear")
            elif kind == "dir-back":
                self.report(f"sensor {item[1]}: its directory {item[2]} is back")
            try:
                item = self.events.get_nowait()
            except queue.Empty:
                return ""

    def drain(self, timeout_s: float = 5.0) -> None:
        """After the stop: the frames sent and waiting are solved (for at most
        ``timeout_s``), the rest written as unsolved, then the engine finishes."""
        from shipstar.pipeline._sensor import FrameResult

        end = time.monotonic() + timeout_s
        while time.monotonic() < end and any(s.in_flight is not None or s.waiting for s in self.sensors.values()):
            self._pump(0.05)
        for sensor in self.sensors.values():
            if sensor.in_flight is not None:
                self.report(f"sensor {sensor.name}: a frame was still being solved {timeout_s:g} s after the stop")
            while sensor.waiting:
                index, frame, *_ = sensor.waiting.popleft()
                self.done(sensor, index, FrameResult.failed(sensor.name, index, frame, "not solved before the stop"))
        if self.engine is not None:
            self.out(self.engine.finish())

    def close(self, complete: bool) -> Path | None:
        self.watcher.stop()
        if self.console is not None:
            self.console.close()
        self.workers.results.put(("bye",))
        self._reader.join(2.0)
        self.workers.stop()
        if self.udp is not None:
            self.udp.close()
        if self.writer is None:
            return None
        if complete:
            return self.writer.complete()
        self.writer.close()
        return self.writer.partial

    def summary(self, stopped: str, out: Path | None) -> dict:
        from shipstar.pipeline._fusion import sensor_roles

        names = self.names
        fore, athw = sensor_roles(self.s.configs)
        if self.stats is not None:
            summary = self.stats.summary(reference_sensor=names[self.s.reference],
                                         fore_aft_sensor=names[fore] if fore >= 0 else "",
                                         athwartship_sensor=names[athw] if athw >= 0 else "", options=self.s.options)
        else:
            summary = {"sensors": {}, "methods": {}, "n_epochs": 0}
        for name, s in self.sensors.items():
            block = summary["sensors"].setdefault(name, {"n_frames": 0, "n_solved": 0, "n_failed": 0})
            block["n_frames"] += s.n_unreadable
            block["n_failed"] += s.n_unreadable
            block.update({"frames_in": s.frames_in, "skipped_behind": s.skipped, "n_unreadable": s.n_unreadable,
                          "unreadable": s.unreadable})
        summary.update({"out": None if out is None else str(out), "stopped": stopped,
                        "run_s": round(time.monotonic() - self.t0, 3), "latency": self.latency.quantiles_ms(),
                        "warnings": list(self.warnings), "eop": self.eop,
                        "nav": self.s.nav.stats() if self.s.nav is not None else None,
                        "udp": {"sent": self.udp.n_sent, "errors": self.udp.n_errors} if self.udp else None})
        if self.s.ins is not None:
            self.s.ins.poll(self.udp)
            summary["ins"] = self.s.ins.summary()
        if any(c.trust_flags for c in self.s.header_checks):
            summary.update(trust_flags=True, header_overrides=[o for c in self.s.header_checks for o in c.overrides()])
        return summary


def _signature(path: Path):
    """``(inode, mtime_ns, size)`` of a file, None when it is gone."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


def _reason_kind(reason: str) -> str:
    """A reason shortened to its kind (for the status's counts)."""
    return reason.split(":")[0].split("(")[0].strip()[:60] or "?"


def _complete(path):
    from shipstar._fitsio import file_is_complete

    return file_is_complete(path)


def _iso(jd) -> str:
    from shipstar.sky.time import iso_from_utc_jd

    return iso_from_utc_jd(jd[0], jd[1], 3)


@dataclass(frozen=True)
class _Time:
    utc_jd1: float
    utc_jd2: float


def _eop_at(frame) -> dict:
    """Earth orientation quality at a frame's time (its warnings are the frames' own)."""
    from shipstar.pipeline import eop_quality

    return eop_quality([frame.utc_jd1], [frame.utc_jd2]).as_dict()


def run_live(settings: LiveSettings, stop: threading.Event) -> LiveOutcome:
    """Run until ``stop`` is set (a signal) or ``settings.stop_after_s`` has passed; then
    finish the frames under way, close the outputs complete and return the summary.
    ``settings.nav`` (a started :class:`~shipstar.live._nav.NavReceiver`) is the caller's
    to start and stop.

    Raises
    ------
    ShipstarError
        A worker that cannot start (e.g. a camera whose star database cannot be built).
    """
    live = _Live(settings, stop)
    complete = False
    try:
        stopped = live.run()
        live.drain()
        complete = True
    finally:
        out = live.close(complete)
    return LiveOutcome(live.summary(stopped, out), stopped, out)
