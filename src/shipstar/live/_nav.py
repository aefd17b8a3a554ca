"""The ship's position, time and weather while live: tables that grow as samples arrive
(:class:`LiveTrack`, :class:`LiveWeather`), fed by NMEA 0183 over UDP
(:class:`NavReceiver`) or by CSV files that keep growing (:class:`CsvTail`).

The tables read like :class:`shipstar.pipeline.Track` and
:class:`shipstar.pipeline.WeatherTable` (``site``, ``weather``, ``check_covers``), so the
streaming engine takes either.  What differs is what happens past the newest sample:

- between two samples, both interpolate linearly in time (longitude unwrapped, so the
  ship may cross 180 deg);
- after the newest position, :class:`LiveTrack` extrapolates latitude and longitude
  linearly from the last two samples (the ship's velocity) for at most
  ``max_extrapolation_s`` (default 5 s; height and deflection of the vertical are held).
  At 10 m/s, 5 s of a steady course is 50 m, and a turn of 5 deg/s over 5 s misses by
  about 10 m (0.3'' of latitude);
- after the newest weather sample, :class:`LiveWeather` holds it for at most
  ``max_weather_age_s`` (default 600 s: pressure and temperature change slowly);
- otherwise, and before the first kept sample, a :class:`~shipstar.errors.ShipstarError`
  with a one-line message, e.g. ``no position within 5 s of 2013-03-15T12:16:03.100000Z
  (last fix 7.2 s earlier)``.

The tables keep at most ``max_samples`` samples (default 3600: an hour of 1 Hz fixes),
dropping the oldest.  Samples must come in time order: an older or equal-time sample is
refused (:class:`SampleOrderError`, counted in ``n_refused``, not applied).  All methods
are thread-safe.
"""

from __future__ import annotations

import bisect
import collections
import csv
import datetime
import errno
import math
import os
import select
import socket
import threading
import time
from pathlib import Path

from shipstar.errors import ShipstarError
from shipstar.live._nmea import (NmeaError, decode_gga, decode_mda, decode_rmc, decode_xdr, decode_zda, parse,
                                 quote, utc_jd_from_date)
from shipstar.units import DAY_S

__all__ = ["LiveTrack", "LiveWeather", "NavReceiver", "CsvTail", "SampleOrderError"]

#: A time may lie this far before the first sample (s): clock rounding, as in Track.
_EDGE_S = 1e-3


class SampleOrderError(ShipstarError):
    """A sample at or before the newest one already in a live table."""


def _iso(utc_jd1: float, utc_jd2: float) -> str:
    from shipstar.sky.time import iso_from_utc_jd

    return iso_from_utc_jd(utc_jd1, utc_jd2, 6)


def _positive(value, what: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ShipstarError(f"{what} must be a number, got {value!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise ShipstarError(f"{what} must be finite and > 0, got {value!r}")
    return x


class _LiveTable:
    """Rows at strictly increasing times (s since the first sample ever), bounded."""

    _noun = "sample"

    def __init__(self, name: str, max_samples: int):
        if isinstance(max_samples, bool) or not isinstance(max_samples, int) or max_samples < 2:
            raise ShipstarError(f"max_samples must be a whole number >= 2, got {max_samples!r}")
        self.name = name
        self.max_samples = max_samples
        self._lock = threading.Lock()
        self._jd0: tuple[float, float] | None = None
        self._t: list[float] = []
        self._rows: list[tuple] = []
        self._last_jd: tuple[float, float] | None = None
        self.n_added = 0
        self.n_refused = 0

    def __len__(self) -> int:
        with self._lock:
            return len(self._t)

    def _seconds(self, utc_jd1: float, utc_jd2: float) -> float:
        return ((utc_jd1 - self._jd0[0]) + (utc_jd2 - self._jd0[1])) * DAY_S

    def last_utc_jd(self) -> tuple[float, float] | None:
        """Time of the newest sample (two-part UTC JD), None when empty."""
        with self._lock:
            return self._last_jd

    def _refused(self, exc: ShipstarError) -> ShipstarError:
        """Count a refused sample; returns ``exc`` to raise."""
        with self._lock:
            self.n_refused += 1
        return exc

    def _append(self, utc_jd1: float, utc_jd2: float, make_row) -> None:
        """Append ``make_row(previous_row_or_None)`` at a time after the newest sample."""
        utc_jd1, utc_jd2 = float(utc_jd1), float(utc_jd2)
        if not (math.isfinite(utc_jd1) and math.isfinite(utc_jd2)):
            raise self._refused(ShipstarError(f"{self.name}: time must be finite, got {utc_jd1} + {utc_jd2}"))
        with self._lock:
            if self._jd0 is None:
                self._jd0 = (utc_jd1, utc_jd2)
            t = self._seconds(utc_jd1, utc_jd2)
            if self._t and t <= self._t[-1]:
                self.n_refused += 1
                raise SampleOrderError(
                    f"{self.name}: {self._noun} at {_iso(utc_jd1, utc_jd2)} is not after the newest one "
                    f"({_iso(*self._last_jd)}); refused")
            row = make_row(self._rows[-1] if self._rows else None)
            self._t.append(t)
            self._rows.append(row)
            self._last_jd = (utc_jd1, utc_jd2)
            if len(self._t) > self.max_samples:
                del self._t[0]
                del self._rows[0]
            self.n_added += 1

    def _locate(self, utc_jd1: float, utc_jd2: float, what: str, limit_s: float, newest: str):
        """Under the lock: ``("in", i, f)`` to interpolate between rows i and i + 1 (f in
        [0, 1]; i = 0, f = 0 with one row), or ``("after", dt)``, dt in (0, limit_s].

        Raises the one-line ShipstarError otherwise."""
        if not self._t:
            raise ShipstarError(f"no {what} for {_iso(utc_jd1, utc_jd2)} (none received yet)")
        t = self._seconds(utc_jd1, utc_jd2)
        first, last = self._t[0], self._t[-1]
        if t < first - _EDGE_S:
            raise ShipstarError(f"no {what} within {limit_s:g} s of {_iso(utc_jd1, utc_jd2)} "
                                f"(first kept {newest} {first - t:.1f} s later)")
        if t <= last + _EDGE_S:
            if len(self._t) == 1:
                return "in", 0, 0.0
            i = min(max(bisect.bisect_right(self._t, t) - 1, 0), len(self._t) - 2)
            f = min(max((t - self._t[i]) / (self._t[i + 1] - self._t[i]), 0.0), 1.0)
            return "in", i, f
        dt = t - last
        if dt > limit_s:
            raise ShipstarError(f"no {what} within {limit_s:g} s of {_iso(utc_jd1, utc_jd2)} "
                                f"(last {newest} {dt:.1f} s earlier)")
        return "after", dt

    def _mix(self, i: int, f: float) -> tuple:
        if len(self._rows) == 1 or f == 0.0:
            return self._rows[i]
        a, b = self._rows[i], self._rows[i + 1]
        return tuple((1.0 - f) * x + f * y for x, y in zip(a, b))


class LiveTrack(_LiveTable):
    """The ship's position, growing while live; reads like :class:`shipstar.pipeline.Track`.

    Parameters
    ----------
    max_samples : int
        Samples kept (the oldest are dropped), default 3600.
    max_extrapolation_s : float
        How long after the newest fix a position is extrapolated from the ship's velocity
        (the last two fixes), default 5 s.
    name : str
        For messages.
    """

    _noun = "fix"

    def __init__(self, max_samples: int = 3600, max_extrapolation_s: float = 5.0, name: str = "live track"):
        super().__init__(name, max_samples)
        self.max_extrapolation_s = _positive(max_extrapolation_s, "max_extrapolation_s")

    def add(self, utc_jd1: float, utc_jd2: float, lat_deg: float, lon_deg: float, height_m: float = 0.0,
            xi_arcsec: float = 0.0, eta_arcsec: float = 0.0) -> None:
        """Append a fix (validated as :meth:`shipstar.sky.apparent.Site.from_deg` does).

        Raises
        ------
        SampleOrderError
            The time is not after the newest fix (refused, counted in ``n_refused``).
        ShipstarError
            A value :class:`~shipstar.sky.apparent.Site` refuses (refused and counted too).
        """
        from shipstar.sky.apparent import Site

        try:
            site = Site.from_deg(lat_deg, lon_deg, height_m, xi_arcsec, eta_arcsec)
        except ShipstarError as exc:
            raise self._refused(ShipstarError(f"{self.name}: {exc}")) from None

        def row(prev):
            lon = site.lon_rad
            if prev is not None:                       # unwrap: the ship may cross 180 deg
                lon = prev[1] + math.remainder(lon - prev[1], 2.0 * math.pi)
            return (site.lat_rad, lon, site.height_m, site.xi_rad, site.eta_rad)

        self._append(utc_jd1, utc_jd2, row)

    def site(self, utc_jd1: float, utc_jd2: float):
        """The ship's :class:`~shipstar.sky.apparent.Site` at a time.

        Raises
        ------
        ShipstarError
            Before the first kept fix, or more than ``max_extrapolation_s`` after the
            newest (or after the only fix: no velocity yet).
        """
        from shipstar.sky.apparent import Site

        with self._lock:
            where = self._locate(utc_jd1, utc_jd2, "position", self.max_extrapolation_s, "fix")
            if where[0] == "in":
                lat, lon, height, xi, eta = self._mix(where[1], where[2])
            else:
                dt = where[1]
                if len(self._t) < 2:
                    raise ShipstarError(f"no position for {_iso(utc_jd1, utc_jd2)}: one fix only "
                                        f"({dt:.1f} s earlier), no velocity to extrapolate with yet")
                (t0, t1), (r0, r1) = self._t[-2:], self._rows[-2:]
                k = dt / (t1 - t0)
                lat, lon = r1[0] + k * (r1[0] - r0[0]), r1[1] + k * (r1[1] - r0[1])
                height, xi, eta = r1[2:]
        if abs(lat) > 0.5 * math.pi:
            raise ShipstarError(f"no position for {_iso(utc_jd1, utc_jd2)}: extrapolated beyond a pole")
        return Site(lat, math.remainder(lon, 2.0 * math.pi), height, xi, eta)

    def check_covers(self, utc_jd1: float, utc_jd2: float) -> None:
        """ShipstarError when :meth:`site` has no position for a time."""
        self.site(utc_jd1, utc_jd2)

    def latest(self) -> dict | None:
        """The newest fix: ``{"utc_jd1", "utc_jd2", "lat_deg", "lon_deg", "height_m"}``,
        longitude in (-180, 180]; None when empty."""
        from shipstar.units import RAD2DEG

        with self._lock:
            if not self._rows:
                return None
            lat, lon, height = self._rows[-1][:3]
            jd = self._last_jd
        lon_deg = math.remainder(lon, 2.0 * math.pi) * RAD2DEG
        return {"utc_jd1": jd[0], "utc_jd2": jd[1], "lat_deg": lat * RAD2DEG,
                "lon_deg": 180.0 if lon_deg == -180.0 else lon_deg, "height_m": height}


class LiveWeather(_LiveTable):
    """Pressure, temperature and humidity, growing while live; reads like
    :class:`shipstar.pipeline.WeatherTable`.

    Parameters
    ----------
    max_samples : int
        Samples kept (the oldest are dropped), default 3600.
    max_weather_age_s : float
        How long the newest sample is held, default 600 s.
    name : str
        For messages.
    """

    _noun = "reading"

    def __init__(self, max_samples: int = 3600, max_weather_age_s: float = 600.0, name: str = "live weather"):
        super().__init__(name, max_samples)
        self.max_weather_age_s = _positive(max_weather_age_s, "max_weather_age_s")

    def add(self, utc_jd1: float, utc_jd2: float, pressure_hpa: float, temperature_c: float,
            relative_humidity: float = 0.0) -> None:
        """Append a reading (validated as :class:`~shipstar.sky.refraction.Weather` does).

        Raises
        ------
        SampleOrderError
            The time is not after the newest reading (refused, counted in ``n_refused``).
        ShipstarError
            A value :class:`~shipstar.sky.refraction.Weather` refuses (refused, counted).
        """
        from shipstar.limits import check_range
        from shipstar.sky.refraction import Weather

        try:
            for key, value in (("pressure_hpa", pressure_hpa), ("temperature_c", temperature_c),
                               ("relative_humidity", relative_humidity)):
                check_range(key, value)                  # shipstar.limits: the ranges of every entry point
            w = Weather(pressure_hpa, temperature_c, relative_humidity)
        except ShipstarError as exc:
            raise self._refused(ShipstarError(f"{self.name}: {exc}")) from None
        self._append(utc_jd1, utc_jd2, lambda prev: (w.pressure_hpa, w.temperature_c, w.relative_humidity))

    def weather(self, utc_jd1: float, utc_jd2: float):
        """The :class:`~shipstar.sky.refraction.Weather` at a time, rounded as
        :meth:`shipstar.pipeline.WeatherTable.weather` rounds (0.01 hPa, 0.01 C, 0.001).

        Raises
        ------
        ShipstarError
            Before the first kept reading, or more than ``max_weather_age_s`` after the
            newest.
        """
        from shipstar.sky.refraction import Weather

        with self._lock:
            where = self._locate(utc_jd1, utc_jd2, "weather", self.max_weather_age_s, "reading")
            p, t, h = self._mix(where[1], where[2]) if where[0] == "in" else self._rows[-1]
        return Weather(round(p, 2), round(t, 2), round(h, 3))

    def check_covers(self, utc_jd1: float, utc_jd2: float) -> None:
        """ShipstarError when :meth:`weather` has no weather for a time."""
        self.weather(utc_jd1, utc_jd2)


class NavReceiver:
    """NMEA 0183 over UDP from the ship's navigation network into live tables.

    A background thread receives datagrams (one or more sentences each, CR LF or LF
    separated) and applies:

    - ``GGA``: a position at a time of day; its date is the one that puts it nearest
      (within 12 h) to the latest ZDA or RMC, so midnight is crossed correctly.  GGAs
      that arrive before any date are held (at most ``max_pending``, the oldest dropped)
      and applied when a ZDA or RMC arrives;
    - ``RMC``: a dated position (and the date for GGA); ``ZDA``: the date and time;
    - ``MDA``, ``XDR``: pressure, temperature, humidity.  The latest of each is kept; a
      weather sample is added when pressure and temperature are both known and were
      received within ``weather.max_weather_age_s`` of each other (humidity 0 until one
      arrives).  MDA and XDR carry no time: the sample is stamped with the navigation
      clock, the time of the latest dated sentence (ZDA, RMC, GGA) plus the time elapsed
      since it arrived, made strictly later than the previous sample (by 1 us if need
      be).  Readings that arrive before any dated sentence wait for one.

    Two sentences giving the same epoch (GGA and RMC of one fix) add one position; the
    first wins.  Other sentence types are counted and ignored.  Each bad sentence is
    counted by kind (:class:`~shipstar.live._nmea.NmeaError` kinds, ``order`` for a sample
    older than the table's newest, ``refused`` for a value the table refuses,
    ``no-date`` for GGAs dropped while waiting for a date, ``internal`` for anything
    unexpected) and reported through ``on_error`` as one line, e.g. ``nav UDP: bad
    checksum in '$GPGGA,...' (expected 4F, got 00)``; nothing is raised out of the thread.

    Parameters
    ----------
    track : LiveTrack
    weather : LiveWeather or None
        None: weather sentences are counted and ignored.
    host : str
        Address to listen on (e.g. ``"0.0.0.0"`` on the ship's network, ``"127.0.0.1"``).
    port : int
        UDP port; 0 picks a free one (see :attr:`port` after :meth:`start`).
    on_error : callable(str) or None
        Called from the receiver thread with each one-line error message.
    max_pending : int
        GGAs held while no date is known.
    name : str
        Prefix of the messages.
    """

    def __init__(self, track: LiveTrack, weather: LiveWeather | None = None, *, host: str, port: int,
                 on_error=None, max_pending: int = 100, name: str = "nav UDP"):
        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise ShipstarError(f"UDP port must be 0-65535, got {port!r}")
        self.track, self.weather = track, weather
        self.host, self._port = str(host), port
        self.on_error = on_error
        self.name = name
        self._sock: socket.socket | None = None
        self._wake: tuple[socket.socket, socket.socket] | None = None
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._feed_lock = threading.Lock()                 # one datagram at a time
        self._stats_cond = threading.Condition()
        self._n_datagrams = 0
        self._counts: collections.Counter = collections.Counter()
        self._errors: collections.Counter = collections.Counter()
        self.recent_errors: collections.deque = collections.deque(maxlen=20)
        self._pending: collections.deque = collections.deque(maxlen=max(1, int(max_pending)))
        self._date_ref: tuple[datetime.date, float] | None = None      # latest ZDA/RMC: date, time of day
        self._clock: tuple[float, float, float] | None = None          # (jd1, jd2, monotonic at arrival)
        self._last_pos_jd: tuple[float, float] | None = None
        self._last_wx_jd: tuple[float, float] | None = None
        self._wx: dict = {}                                            # "p"/"t"/"h": (value, monotonic)
        self._wx_waiting = False

    # -- lifecycle ------------------------------------------------------------------------

    @property
    def port(self) -> int:
        """The UDP port listened on (the one picked when started with port 0)."""
        return self._sock.getsockname()[1] if self._sock is not None else self._port

    def start(self) -> "NavReceiver":
        """Bind the socket and start the thread.

        Raises
        ------
        ShipstarError
            Already started; the port is in use (``UDP port 10110 on 127.0.0.1 is in
            use``); the address cannot be listened on.
        """
        if self._thread is not None:
            raise ShipstarError(f"{self.name}: already started")
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            sock.bind((self.host, self._port))
        except OSError as exc:
            sock.close()
            if exc.errno == errno.EADDRINUSE:
                raise ShipstarError(f"UDP port {self._port} on {self.host} is in use") from None
            raise ShipstarError(f"cannot listen on UDP port {self._port} on {self.host}: "
                                f"{exc.strerror or exc}") from None
        except (TypeError, ValueError) as exc:            # e.g. an unresolvable host text
            sock.close()
            raise ShipstarError(f"cannot listen on UDP port {self._port} on {self.host!r}: {exc}") from None
        sock.setblocking(False)
        self._sock = sock
        self._wake = socket.socketpair()
        self._stopping.clear()
        self._thread = threading.Thread(target=self._run, name=f"shipstar {self.name} {self.port}", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the thread (at once: it is woken) and close the sockets.  Idempotent."""
        if self._thread is None:
            return
        self._stopping.set()
        try:
            self._wake[1].send(b"x")
        except OSError:
            pass
        self._thread.join(timeout_s)
        self._thread = None
        for s in (self._sock, *self._wake):
            s.close()
        self._wake = None
        self._sock = None

    def __enter__(self) -> "NavReceiver":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _run(self) -> None:
        sock, wake = self._sock, self._wake[0]
        while not self._stopping.is_set():
            try:
                ready, _, _ = select.select([sock, wake], [], [])
            except OSError as exc:                         # a closed socket: stop quietly
                if not self._stopping.is_set():
                    self._report("internal", f"{self.name}: receive failed: {exc}")
                return
            if wake in ready or self._stopping.is_set():
                return
            while True:                                    # drain what is waiting
                try:
                    data = sock.recv(65535)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError as exc:
                    self._report("internal", f"{self.name}: receive failed: {exc}")
                    break
                self.feed_datagram(data)

    # -- statistics -----------------------------------------------------------------------

    @property
    def n_datagrams(self) -> int:
        """Datagrams processed so far."""
        with self._stats_cond:
            return self._n_datagrams

    def wait_datagrams(self, n: int, timeout_s: float) -> bool:
        """Wait until at least ``n`` datagrams have been processed; False on time-out."""
        with self._stats_cond:
            return self._stats_cond.wait_for(lambda: self._n_datagrams >= n, timeout_s)

    def stats(self) -> dict:
        """``{"datagrams": int, "sentences": {type: count}, "errors": {kind: count},
        "pending_gga": int}`` (proprietary types as ``P`` + type, e.g. ``PASHR``)."""
        with self._stats_cond:
            return {"datagrams": self._n_datagrams, "sentences": dict(self._counts),
                    "errors": dict(self._errors), "pending_gga": len(self._pending)}

    def _report(self, kind: str, message: str, notify: bool = True) -> None:
        """Count an error of ``kind``; pass ``message`` to ``on_error`` when ``notify``."""
        with self._stats_cond:
            self._errors[kind] += 1
            if notify:
                self.recent_errors.append(message)
        if notify and self.on_error is not None:
            try:
                self.on_error(message)
            except Exception:                              # noqa: BLE001 - never out of the thread
                pass

    # -- processing -----------------------------------------------------------------------

    def feed_datagram(self, data: bytes | str, arrival_monotonic_s: float | None = None) -> None:
        """Apply one datagram's sentences (what the thread does with each datagram)."""
        now = time.monotonic() if arrival_monotonic_s is None else float(arrival_monotonic_s)
        text = data.decode("latin-1") if isinstance(data, (bytes, bytearray)) else str(data)
        with self._feed_lock:
            for line in text.replace("\r\n", "\n").replace("\r", "\n").split("\n"):
                if line.strip():
                    try:
                        self._sentence(line, now)
                    except Exception as exc:               # noqa: BLE001 - never out of the thread
                        self._report("internal", f"{self.name}: internal error on {quote(line.strip())}: "
                                                 f"{type(exc).__name__}: {exc}")
        with self._stats_cond:
            self._n_datagrams += 1
            self._stats_cond.notify_all()

    def _sentence(self, line: str, now: float) -> None:
        try:
            s = parse(line)
        except NmeaError as exc:
            self._report(exc.kind, f"{self.name}: {exc}")
            return
        with self._stats_cond:
            self._counts[("P" if s.talker == "P" else "") + s.type] += 1
        where = f" in {quote(line.strip())}"
        try:
            if s.type == "GGA":
                self._on_gga(decode_gga(s), now, where)
            elif s.type == "RMC":
                fix = decode_rmc(s)
                self._set_date(fix.utc_date, fix.utc_time_of_day_s, fix.utc_jd1, fix.utc_jd2, now)
                self._flush_pending()
                self._add_position(fix.utc_jd1, fix.utc_jd2, fix.lat_deg, fix.lon_deg, 0.0, where)
            elif s.type == "ZDA":
                z = decode_zda(s)
                self._set_date(z.utc_date, z.utc_time_of_day_s, z.utc_jd1, z.utc_jd2, now)
                self._flush_pending()
            elif s.type in ("MDA", "XDR") and self.weather is not None:
                r = decode_mda(s) if s.type == "MDA" else decode_xdr(s)
                for key, value in (("p", r.pressure_hpa), ("t", r.temperature_c), ("h", r.relative_humidity)):
                    if value is not None:
                        self._wx[key] = (value, now)
                self._wx_waiting = True
                self._add_weather(now, where)
        except NmeaError as exc:
            self._report(exc.kind, f"{self.name}: {exc}{where}")

    def _set_date(self, date: datetime.date, tod_s: float, jd1: float, jd2: float, now: float) -> None:
        self._date_ref = (date, tod_s)
        self._clock = (jd1, jd2, now)
        if self._wx_waiting:
            self._add_weather(now, "")

    def _dated(self, tod_s: float) -> tuple[float, float]:
        date, ref_s = self._date_ref
        shift = min((-1, 0, 1), key=lambda k: abs(k * 86400.0 + tod_s - ref_s))
        return utc_jd_from_date(date + datetime.timedelta(days=shift), tod_s)

    def _on_gga(self, fix, now: float, where: str) -> None:
        if self._date_ref is None:
            if len(self._pending) == self._pending.maxlen:   # report the first drop only; count all
                with self._stats_cond:
                    first = self._errors["no-date"] == 0
                self._report("no-date", f"{self.name}: GGA at {self._pending[0].utc_time_of_day_s:.2f} s of day "
                                        f"dropped: no date yet (needs ZDA or RMC), {len(self._pending)} held",
                             notify=first)
            self._pending.append(fix)
            return
        jd1, jd2 = self._dated(fix.utc_time_of_day_s)
        self._clock = (jd1, jd2, now)
        self._add_position(jd1, jd2, fix.lat_deg, fix.lon_deg, fix.height_m, where)

    def _flush_pending(self) -> None:
        while self._pending:
            fix = self._pending.popleft()
            try:
                jd1, jd2 = self._dated(fix.utc_time_of_day_s)
            except NmeaError as exc:
                self._report(exc.kind, f"{self.name}: held GGA: {exc}")
                continue
            self._add_position(jd1, jd2, fix.lat_deg, fix.lon_deg, fix.height_m, " (held GGA)")

    def _add_position(self, jd1, jd2, lat_deg, lon_deg, height_m, where: str) -> None:
        if self._last_pos_jd == (jd1, jd2):                # same epoch from another sentence
            return
        try:
            self.track.add(jd1, jd2, lat_deg, lon_deg, height_m)
        except SampleOrderError as exc:
            self._report("order", f"{self.name}: {exc}{where}")
            return
        except ShipstarError as exc:
            self._report("refused", f"{self.name}: {exc}{where}")
            return
        self._last_pos_jd = (jd1, jd2)

    def _add_weather(self, now: float, where: str) -> None:
        p, t = self._wx.get("p"), self._wx.get("t")
        if p is None or t is None or self._clock is None:
            return
        if abs(p[1] - t[1]) > self.weather.max_weather_age_s:
            return                                         # one of them is stale: wait for a fresh one
        jd1, jd2, at = self._clock
        jd2 += (now - at) / DAY_S
        if self._last_wx_jd is not None:
            last1, last2 = self._last_wx_jd
            if ((jd1 - last1) + (jd2 - last2)) * DAY_S < 1e-6:
                jd1, jd2 = last1, last2 + 1e-6 / DAY_S
        h = self._wx.get("h", (0.0, now))[0]
        self._wx_waiting = False
        try:
            self.weather.add(jd1, jd2, p[0], t[0], h)
        except SampleOrderError as exc:
            self._report("order", f"{self.name}: {exc}{where}")
            return
        except ShipstarError as exc:
            self._report("refused", f"{self.name}: {exc}{where}")
            return
        self._last_wx_jd = (jd1, jd2)


class CsvTail:
    """Follow a CSV file that keeps growing and feed a live table.

    The file has the track (``time_utc, lat_deg, lon_deg[, height_m][, xi_arcsec,
    eta_arcsec]``) or weather (``time_utc, pressure_hpa, temperature_c[,
    relative_humidity]``) columns of docs/file-formats.md, by the kind of ``table``; lines
    starting with ``#`` are comments.  :meth:`poll` reads what was appended since the last
    call: complete lines only, a partial last line waits for the next call.  A file that
    is replaced or shrinks is read again from its start.  A bad row is reported through
    ``on_error`` as one line (``track.csv line 7: ...``), skipped and counted in
    ``n_errors``; a row the table refuses (out of time order, out of range) likewise.

    Parameters
    ----------
    path : str or Path
        The file (it may not exist yet).
    table : LiveTrack or LiveWeather
    on_error : callable(str) or None
    """

    _COLUMNS = {LiveTrack: (("lat_deg", "lon_deg"), ("height_m", "xi_arcsec", "eta_arcsec")),
                LiveWeather: (("pressure_hpa", "temperature_c"), ("relative_humidity",))}

    def __init__(self, path, table, *, on_error=None):
        kind = next((k for k in self._COLUMNS if isinstance(table, k)), None)
        if kind is None:
            raise ShipstarError(f"CsvTail feeds a LiveTrack or a LiveWeather, got {type(table).__name__}")
        self.path = Path(path)
        self.table = table
        self.on_error = on_error
        self._required, self._optional = self._COLUMNS[kind]
        self.n_rows = 0
        self.n_errors = 0
        self._reset()

    def _reset(self) -> None:
        self._offset = 0
        self._inode = None
        self._partial = b""
        self._line_no = 0
        self._header: list[str] | None = None
        self._bad_header: str | None = None

    def _error(self, message: str) -> None:
        self.n_errors += 1
        if self.on_error is not None:
            self.on_error(message)

    def poll(self) -> int:
        """Read and apply the complete lines appended since the last call.

        Returns
        -------
        int
            Rows applied by this call.

        Raises
        ------
        ShipstarError
            The header misses a required column (raised again on every call until the
            file is replaced), or the file cannot be read.
        """
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            return 0
        except OSError as exc:
            raise ShipstarError(f"cannot read {self.path}: {exc.strerror or exc}") from None
        if self._inode is not None and (st.st_ino != self._inode or st.st_size < self._offset):
            self._error(f"{self.path}: file replaced or truncated; reading it again from the start")
            self._reset()
        self._inode = st.st_ino
        if self._bad_header is not None:
            raise ShipstarError(self._bad_header)
        if st.st_size == self._offset:
            return 0
        try:
            with open(self.path, "rb") as fh:
                fh.seek(self._offset)
                data = fh.read()
        except OSError as exc:
            raise ShipstarError(f"cannot read {self.path}: {exc.strerror or exc}") from None
        self._offset += len(data)
        lines = (self._partial + data).split(b"\n")
        self._partial = lines.pop()
        applied = 0
        for raw in lines:
            self._line_no += 1
            applied += self._line(raw)
        return applied

    def _line(self, raw: bytes) -> int:
        where = f"{self.path} line {self._line_no}"
        try:
            text = raw.decode("utf-8").rstrip("\r")
        except UnicodeDecodeError:
            if self._header is None:                # not a CSV table: one error, not one a line
                self._bad_header = (f"{where}: not UTF-8 text, so not a CSV table (need a header line time_utc, "
                                    f"{', '.join(self._required)})")
                raise ShipstarError(self._bad_header) from None
            self._error(f"{where}: not UTF-8 text")
            return 0
        if self._header is None:
            text = text.lstrip("\ufeff")                # a spreadsheet's byte-order mark
        if not text.strip() or text.lstrip().startswith("#"):
            return 0
        try:
            values = [v.strip() for v in next(csv.reader([text]))]
        except csv.Error as exc:
            self._error(f"{where}: {exc}")
            return 0
        if self._header is None:
            missing = [c for c in ("time_utc",) + self._required if c not in values]
            if missing:
                self._bad_header = (f"{self.path}: missing column {missing[0]!r} (need time_utc, "
                                    f"{', '.join(self._required)})")
                raise ShipstarError(self._bad_header)
            self._header = values
            return 0
        if len(values) != len(self._header):
            self._error(f"{where}: {len(values)} fields, the header has {len(self._header)}")
            return 0
        row = dict(zip(self._header, values))
        try:
            from shipstar.sky.time import utc_jd_from_iso

            jd1, jd2 = utc_jd_from_iso(row["time_utc"])
            numbers = [self._number(row[c], c) for c in self._required]
            numbers += [self._number(row[c], c) if c in row and row[c] != "" else 0.0 for c in self._optional]
            self.table.add(jd1, jd2, *numbers)
        except ShipstarError as exc:
            self._error(f"{where}: {exc}")
            return 0
        self.n_rows += 1
        return 1

    @staticmethod
    def _number(text: str, column: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise ShipstarError(f"{column} is not a number: {text!r}") from None
        if not math.isfinite(value):
            raise ShipstarError(f"{column} must be finite, got {text!r}")
        return value
