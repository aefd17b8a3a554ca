"""The operator console of ``shipstar live --http HOST:PORT``: one read-only web page fed
by server-sent events (docs/live.md, *Operator console*).

Three parts, none of which can slow the measurement:

- **the engine publishes**: :meth:`Console.emission` and :meth:`Console.status` put a
  reference to what the engine already made (an :class:`~shipstar.pipeline.Emission`,
  the once-a-second status dict) into a bounded queue without waiting (a full queue
  drops the item and counts it); nothing else runs on the engine's thread;
- **the console thread** takes them off the queue and keeps the page's state: the
  newest epoch's rows (the very rows the CSV and UDP carry, from
  :func:`~shipstar.pipeline._output.emission_rows`), per-sensor counts over the last
  minute, the last 10 minutes as history points (one per 0.5 s of session time) and the
  alarms; 2.5 times a second, while a browser is connected, it encodes one snapshot
  (JSON) shared by every browser;
- **the HTTP server** (standard library ``ThreadingHTTPServer``, its own threads):
  ``GET /`` the page, ``GET /static/NAME`` its script, style and icon (read from the
  package into memory at the start: no request ever opens a file by a name it gave),
  ``GET /events`` the event stream (a snapshot and the new history points each time the
  snapshot changes; at most :data:`MAX_STREAMS` streams), ``GET /thumb/SENSOR.png`` the
  sensor's newest solved frame, shrunk, its identified stars circled (made at most once a
  second per sensor, only when asked for).  Anything else is 404; other methods 405.
  Every answer carries a Content-Security-Policy that allows nothing from elsewhere.
"""

from __future__ import annotations

import collections
import http.server
import io
import json
import math
import queue
import threading
import time
import urllib.parse
import uuid
from pathlib import Path

from shipstar.errors import ShipstarError

__all__ = ["Console", "MAX_STREAMS", "HISTORY_S", "parse_http_address"]

#: Event streams served at once (browsers); more are answered 503.
MAX_STREAMS = 8
#: The plots' span (s) and the history's step (s of session time).
HISTORY_S = 600.0
HISTORY_STEP_S = 0.5
#: Snapshots per second while a browser is connected.
SNAPSHOT_HZ = 2.5
#: Thumbnails: at most one per sensor per this many seconds; longest side (px).
THUMB_PERIOD_S = 1.0
THUMB_SIZE_PX = 256
#: A sensor whose rows of the last SKY_LOST_S seconds are all unsolved has lost the sky.
SKY_LOST_S = 2.0
#: An alarm whose condition has gone stays active this long (s) before it is cleared.
CLEAR_AFTER_S = 5.0
_STATIC = Path(__file__).with_name("console")
_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
          ".css": "text/css; charset=utf-8", ".svg": "image/svg+xml"}
_CSP = ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; connect-src 'self'; "
        "base-uri 'none'; form-action 'none'; frame-ancestors 'none'")


def parse_http_address(text: str) -> tuple[str, int]:
    """``HOST:PORT`` or ``PORT`` (host 127.0.0.1) -> ``(host, port)``; port 0: any free one."""
    host, sep, port = str(text).rpartition(":")
    if not sep:
        host, port = "127.0.0.1", text
    host = host.strip("[]") or "127.0.0.1"
    try:
        number = int(port)
    except ValueError:
        raise ShipstarError(f"--http: expected [HOST:]PORT, got {text!r}") from None
    if not 0 <= number <= 65535:
        raise ShipstarError(f"--http: port must be in 0-65535, got {number}")
    return host, number


def _utc_iso_now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def _num(x):
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _unix_s(jd1: float, jd2: float) -> float:
    return ((jd1 - 2440587.5) + jd2) * 86400.0


class _SensorState:
    def __init__(self, name: str):
        self.name = name
        self.recent = collections.deque()          # (monotonic s, solved) of the last minute's rows
        self.last_row: dict | None = None
        self.last_solved_mono: float | None = None
        self.last_row_mono: float | None = None
        self.thumb_frame = None                    # newest solved FrameResult
        self.thumb_seq = 0
        self.status: dict = {}


class _Alarms:
    """Alarms by key: raised when their condition starts, cleared CLEAR_AFTER_S after it ends."""

    def __init__(self, keep: int = 50):
        self.items: collections.OrderedDict = collections.OrderedDict()   # key -> alarm dict (active)
        self.past: collections.deque = collections.deque(maxlen=keep)
        self._seen: dict = {}                      # key -> monotonic s the condition was last seen
        self.n = 0

    def set(self, key: str, kind: str, text: str, now: float) -> None:
        self._seen[key] = now
        alarm = self.items.get(key)
        if alarm is None:
            self.n += 1
            self.items[key] = {"id": self.n, "kind": kind, "text": text, "since_utc": _utc_iso_now(),
                               "until_utc": None}
        else:
            alarm["text"] = text

    def sweep(self, now: float, keys_to_clear=()) -> None:
        for key in list(self.items):
            if key in keys_to_clear or now - self._seen.get(key, now) > CLEAR_AFTER_S:
                alarm = self.items.pop(key)
                alarm["until_utc"] = _utc_iso_now()
                self.past.appendleft(alarm)
                self._seen.pop(key, None)

    def as_list(self) -> list:
        return [*reversed(self.items.values()), *self.past]


class Console:
    """The operator console: state kept in its own thread, served over HTTP in others.

    Parameters
    ----------
    address : (str, int)
        Where to listen (port 0: a free port, see :attr:`address` after :meth:`start`).
    configs : sequence of SensorConfig
    dirs : sequence of Path
        Each sensor's frame directory (the thumbnails' frames are read from there).
    method : str
        The method the NMEA output carries (shown as the method in use).
    reference : int
    queue_size : int
        The engine's queue to the console thread (full: items dropped and counted).
    """

    def __init__(self, address, configs, dirs, *, method: str = "joint", reference: int = 0,
                 queue_size: int = 2000):
        self.requested = (str(address[0]), int(address[1]))
        self.configs = tuple(configs)
        self.names = tuple(c.name for c in self.configs)
        self.dirs = {n: Path(d) for n, d in zip(self.names, dirs)}
        self.method = method
        self.reference = self.names[reference]
        self.run_id = uuid.uuid4().hex[:12]
        self.n_dropped = 0
        self._q: queue.Queue = queue.Queue(maxsize=queue_size)
        self._static = self._load_static()
        self._sensors = {n: _SensorState(n) for n in self.names}
        self._alarms = _Alarms()
        self._now: dict | None = None
        self._now_mono: float | None = None
        self._status: dict = {}
        self._ins = None                               # INS error estimate (--ins-udp), arcsec h/p/r
        self._skipped_seen: dict = {}
        self._behind_until: dict = {}
        self._history: collections.deque = collections.deque()    # (seq, session t_s, json text)
        self._hist_seq = 0
        self._hist_last_t = -math.inf
        self._start_jd = None
        self._cond = threading.Condition()
        self._snapshot = ""                      # JSON text of the newest snapshot
        self._snap_seq = 0
        self._streams = 0
        self._closing = threading.Event()
        self._thumbs: dict = {}                  # sensor -> (thumb_seq, made monotonic, png bytes)
        self._thumb_lock = threading.Lock()
        self._server = None
        self._threads: list = []

    # -- static files, read once ----------------------------------------------------------------
    @staticmethod
    def _load_static() -> dict:
        files = {}
        for p in sorted(_STATIC.iterdir()):
            if p.is_file() and p.suffix in _TYPES:
                files[p.name] = (p.read_bytes(), _TYPES[p.suffix])
        if "index.html" not in files:
            raise ShipstarError(f"the operator console's page is missing from {_STATIC}")
        return files

    # -- life -------------------------------------------------------------------------------------
    def start(self) -> None:
        """Listen (a port in use: ShipstarError) and start the console and server threads."""
        console = self

        class Handler(_Handler):
            pass

        Handler.console = console
        try:
            self._server = _Server(self.requested, Handler)
        except OSError as exc:
            raise ShipstarError(f"--http {self.requested[0]}:{self.requested[1]}: cannot listen: "
                                f"{exc.strerror or exc}") from None
        self._threads = [threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.2},
                                          name="shipstar-console-http", daemon=True),
                         threading.Thread(target=self._loop, name="shipstar-console", daemon=True)]
        for t in self._threads:
            t.start()

    @property
    def address(self) -> tuple[str, int]:
        if self._server is None:
            return self.requested
        host, port = self._server.server_address[:2]
        return host, port

    @property
    def url(self) -> str:
        host, port = self.address
        return f"http://{'[' + host + ']' if ':' in host else host}:{port}/"

    def close(self) -> None:
        """Stop serving: the event streams end (browsers reconnect to the next run)."""
        self._closing.set()
        with self._cond:
            self._cond.notify_all()
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
        for t in self._threads:
            t.join(2.0)

    # -- the engine's side: never waits -----------------------------------------------------------
    def emission(self, emission, start_utc_jd) -> None:
        self._put(("e", emission, start_utc_jd, time.monotonic()))

    def status(self, status: dict) -> None:
        self._put(("s", status, time.monotonic()))

    def _put(self, item) -> None:
        try:
            self._q.put_nowait(item)
        except queue.Full:
            self.n_dropped += 1

    # -- the console thread ------------------------------------------------------------------------
    def _loop(self) -> None:
        period = 1.0 / SNAPSHOT_HZ
        next_snap = time.monotonic()
        while not self._closing.is_set():
            try:
                item = self._q.get(timeout=max(0.0, next_snap - time.monotonic()))
            except queue.Empty:
                item = None
            try:
                if item is not None:
                    if item[0] == "e":
                        self._on_emission(*item[1:])
                    else:
                        self._on_status(*item[1:])
                now = time.monotonic()
                if now >= next_snap:
                    next_snap = now + period
                    self._check(now)
                    if self._streams:
                        self._publish(now)
            except Exception as exc:           # noqa: BLE001 - the console must never stop the run
                self._alarms.set("console", "console", f"console error: {type(exc).__name__}: {exc}",
                                 time.monotonic())

    def _on_emission(self, e, start_utc_jd, mono: float) -> None:
        from shipstar.live._outputs import row_objects
        from shipstar.pipeline._output import emission_rows

        self._start_jd = start_utc_jd
        rows = row_objects(emission_rows(e, self.names, start_utc_jd))
        frames = {(fr.sensor, fr.label): fr for fr in e.frames}
        singles = {}
        for r in rows:
            if r["method"] != "single":
                continue
            s = self._sensors.get(r["sensor"])
            if s is None:
                continue
            s.last_row, s.last_row_mono = r, mono
            s.recent.append((mono, bool(r["solved"])))
            singles[s.name] = r
            if r["solved"]:
                s.last_solved_mono = mono
                fr = frames.get((r["sensor"], r["frame"]))
                if fr is not None and fr.horizontal is not None:
                    s.thumb_frame = fr
                    s.thumb_seq += 1
        epoch = e.epoch
        if epoch is None:
            return
        fused = {r["method"]: r for r in rows if r["method"] != "single"}
        if not fused:                                  # one sensor: its single row is the attitude
            fused = {"single": singles.get(self.reference)} if self.reference in singles else {}
        self._now = {"time_utc": next(iter(fused.values()))["time_utc"] if fused else None,
                     "unix_s": _unix_s(epoch.utc_jd1, epoch.utc_jd2), "methods": fused,
                     "singles": {n: s.last_row for n, s in self._sensors.items() if s.last_row is not None},
                     "integrity": self._integrity(epoch)}
        self._now_mono = mono
        self._alarm_integrity(epoch, mono)
        self._alarm_clock(epoch, mono)
        if epoch.t_s >= self._hist_last_t + HISTORY_STEP_S - 1e-9:
            self._hist_last_t = epoch.t_s
            self._add_history(epoch, fused, singles)

    @staticmethod
    def _integrity(epoch) -> dict | None:
        i = epoch.integrity
        if i is None or not i.checked:
            return None
        return {"label": i.label, "chi2": _num(i.chi2), "limit": _num(i.limit), "suspect": i.suspect,
                "disagreement_arcsec": _num(i.disagreement_arcsec)}

    def _add_history(self, epoch, fused, singles) -> None:
        row = fused.get(self.method) or fused.get("joint") or next(iter(fused.values()), None)
        point = {"t": round(_unix_s(epoch.utc_jd1, epoch.utc_jd2), 3)}
        if row is not None and row["solved"]:
            point.update(h=row["heading_deg"], p=row["pitch_deg"], r=row["roll_deg"])
        point["rms"] = {n: r["rms_arcsec"] for n, r in singles.items()}
        i = epoch.integrity
        if i is not None and i.checked:
            point["dis"] = _num(i.disagreement_arcsec)
        if self._ins is not None:
            point["ins"] = [None if v is None else round(v, 3) for v in self._ins]
        m = getattr(epoch, "mounts", None)
        if m is not None:
            point["clk"] = {n: (None if v.get("offset_s") is None else round(v["offset_s"] * 1e3, 4))
                            for n, v in (m.time_offsets_s or {}).items()}
            flx = {}
            for entry in m.monitor:
                name, rot = entry[0], entry[1]
                vals = [_num(x) for x in rot]
                if any(v is not None for v in vals):
                    flx[name] = [None if v is None else round(v, 3) for v in vals]
            if flx:
                point["flx"] = flx
        text = json.dumps(point, allow_nan=False)
        with self._cond:
            self._hist_seq += 1
            self._history.append((self._hist_seq, point["t"], text))
            while self._history and point["t"] - self._history[0][1] > HISTORY_S:
                self._history.popleft()

    def _on_status(self, st: dict, mono: float) -> None:
        self._status = st
        ins = st.get("ins")
        if ins:                                        # the INS error now (INS reading minus truth)
            self._ins = [_num(ins.get(f"{k}_bias_arcsec")) for k in ("heading", "pitch", "roll")]
        for name, v in (st.get("sensors") or {}).items():
            s = self._sensors.get(name)
            if s is None:
                continue
            s.status = v
            if v.get("absent"):
                self._alarms.set(f"stopped:{name}", "frames stopped", f"{name}: its frames stopped arriving", mono)
            skipped = v.get("skipped_behind", 0)
            if skipped > self._skipped_seen.get(name, 0):
                self._alarms.set(f"behind:{name}", "falling behind",
                                 f"{name}: falling behind, {skipped} frames skipped", mono)
            self._skipped_seen[name] = skipped
        eop = (st.get("eop") or {}).get("quality")
        if eop == "extrapolated":
            self._alarms.set("eop", "EOP extrapolated", "Earth orientation extrapolated beyond the IERS tables", mono)

    def _alarm_integrity(self, epoch, mono: float) -> None:
        i = epoch.integrity
        if i is not None and i.checked and not i.consistent:
            self._alarms.set("disagree", "sensors disagree",
                             f"sensors disagree: chi2 {i.chi2:.1f} > {i.limit:.1f}, "
                             f"{i.disagreement_arcsec:.1f}''" + (f", suspect {i.suspect}" if i.suspect else ""), mono)

    def _alarm_clock(self, epoch, mono: float) -> None:
        m = getattr(epoch, "mounts", None)
        if m is None:
            return
        for name, v in (m.time_offsets_s or {}).items():
            off, sig = _num(v.get("offset_s")), _num(v.get("sigma_s"))
            if v.get("applied") and off is not None:
                text = f"{name}: clock offset {off * 1e3:+.2f}" + (f" ± {sig * 1e3:.2f}" if sig else "") + " ms"
                self._alarms.set(f"clock:{name}", "clock offset significant", text, mono)

    def _check(self, now: float) -> None:
        """Conditions judged on time: sky lost (no solved row for SKY_LOST_S while rows come)."""
        for s in self._sensors.values():
            while s.recent and now - s.recent[0][0] > 60.0:
                s.recent.popleft()
            fresh = s.last_row_mono is not None and now - s.last_row_mono < SKY_LOST_S
            since = s.last_solved_mono if s.last_solved_mono is not None else -math.inf
            if fresh and s.recent and now - since > SKY_LOST_S and \
                    sum(1 for t, _ in s.recent if now - t <= SKY_LOST_S) >= 3:
                reason = (s.last_row or {}).get("reason") or "unsolved"
                self._alarms.set(f"sky:{s.name}", "sky lost", f"{s.name}: sky lost ({reason})", now)
        self._alarms.sweep(now)

    def _publish(self, now: float) -> None:
        from shipstar.sky.time import utc_jd_now

        jd = utc_jd_now()
        now_unix = _unix_s(*jd)
        st = self._status
        sensors = {}
        for n, s in self._sensors.items():
            v = s.status
            solved = sum(1 for _, ok in s.recent if ok)
            row = s.last_row or {}
            sensors[n] = {"frames_in": v.get("frames_in", 0), "frames_out": v.get("frames_out", 0),
                          "unsolved": v.get("unsolved", 0), "skipped_behind": v.get("skipped_behind", 0),
                          "waiting": v.get("waiting", 0), "lag_s": _num(v.get("lag_s")),
                          "absent": bool(v.get("absent")), "reasons": v.get("unsolved_reasons") or {},
                          "n_minute": len(s.recent), "solved_minute": solved,
                          "solved_share": (solved / len(s.recent)) if s.recent else None,
                          "stars": row.get("n_stars"), "rms_arcsec": row.get("rms_arcsec"),
                          "last_frame": row.get("frame"), "last_reason": row.get("reason"),
                          "thumb": s.thumb_seq}
        now_block = None
        if self._now is not None:
            now_block = dict(self._now, age_s=now - self._now_mono,
                             epoch_age_s=now_unix - self._now["unix_s"])
        snap = {"run": self.run_id, "server_utc": _utc_iso_now(), "sensors_order": list(self.names),
                "reference": self.reference, "method": self.method, "now": now_block, "sensors": sensors,
                "epochs": st.get("epochs", 0), "inconsistent": st.get("inconsistent", 0),
                "latency": st.get("latency"), "eop": (st.get("eop") or {}).get("quality"),
                "run_s": st.get("run_s"), "alarms": self._alarms.as_list(), "dropped": self.n_dropped}
        text = json.dumps(snap, allow_nan=False, default=str)
        with self._cond:
            self._snapshot = text
            self._snap_seq += 1
            self._cond.notify_all()

    # -- served to the HTTP threads ----------------------------------------------------------------
    def _message(self, last_hist: int) -> tuple[str, int]:
        """One event's data: the snapshot and the history points after ``last_hist``."""
        with self._cond:
            points = [(k, p) for k, _, p in self._history if k > last_hist]
            snapshot = self._snapshot
        newest = points[-1][0] if points else last_hist
        return '{"s":' + (snapshot or "null") + ',"h":[' + ",".join(p for _, p in points) + "]}", newest

    def thumbnail(self, sensor: str) -> bytes | None:
        """The sensor's newest solved frame as a PNG (remade at most once a THUMB_PERIOD_S)."""
        s = self._sensors.get(sensor)
        if s is None or s.thumb_frame is None:
            return None
        with self._thumb_lock:
            cached = self._thumbs.get(sensor)
            now = time.monotonic()
            if cached is not None and (cached[0] == s.thumb_seq or now - cached[1] < THUMB_PERIOD_S):
                return cached[2]
            seq, fr = s.thumb_seq, s.thumb_frame
            try:
                png = _thumbnail_png(self.dirs[sensor] / fr.label, fr, self.configs[self.names.index(sensor)].camera)
            except (OSError, ShipstarError, ValueError):
                png = cached[2] if cached is not None else None
            if png is not None:
                self._thumbs[sensor] = (seq, now, png)
            return png


def _thumbnail_png(path: Path, fr, camera) -> bytes:
    """The frame shrunk to THUMB_SIZE_PX (block means; black at the sky plus 2 sigma,
    square-root stretch), its identified stars circled (green: used, orange: rejected)."""
    import numpy as np
    from PIL import Image, ImageDraw

    from shipstar._fitsio import read_fits_image

    img = np.asarray(read_fits_image(path), dtype=np.float32)
    h, w = img.shape
    k = max(1, math.ceil(max(h, w) / THUMB_SIZE_PX))
    hh, ww = h // k, w // k
    small = img[:hh * k, :ww * k].reshape(hh, k, ww, k).mean(axis=(1, 3))
    med = float(np.median(small))
    noise = 1.4826 * float(np.median(np.abs(small - med))) or 1.0
    lo = med + 2.0 * noise                                  # the sky's noise black, stars bright
    hi = max(float(np.percentile(small, 99.95)), lo + 20.0 * noise)
    scaled = np.sqrt(np.clip((small - lo) / (hi - lo), 0.0, 1.0))
    im = Image.fromarray((scaled * 255.0).astype(np.uint8), "L").convert("RGB")
    hz = fr.horizontal
    if hz is not None and getattr(hz, "w_sensor", None) is not None and len(hz.w_sensor):
        xy = camera.project(np.asarray(hz.w_sensor, float)) / k
        inl = np.asarray(hz.inliers, bool) if getattr(hz, "inliers", None) is not None else np.ones(len(xy), bool)
        draw = ImageDraw.Draw(im)
        for (x, y), ok in zip(xy, inl):
            if np.isfinite(x) and np.isfinite(y):
                r = 5
                draw.ellipse((x - r, y - r, x + r, y + r), outline=(60, 220, 90) if ok else (255, 150, 40), width=1)
    buf = io.BytesIO()
    im.save(buf, format="PNG", optimize=False, compress_level=3)
    return buf.getvalue()


class _Server(http.server.ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 16

    def __init__(self, address, handler):
        import socket

        if ":" in address[0]:
            self.address_family = socket.AF_INET6
        super().__init__(address, handler)


class _Handler(http.server.BaseHTTPRequestHandler):
    console: Console = None
    server_version = "shipstar-console"
    sys_version = ""
    protocol_version = "HTTP/1.1"
    timeout = 30

    def log_message(self, format, *args) -> None:     # noqa: A002 - the base class's name
        return

    def _headers(self, code: int, ctype: str, length: int | None, extra=()) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        if length is not None:
            self.send_header("Content-Length", str(length))
        self.send_header("Content-Security-Policy", _CSP)
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Referrer-Policy", "no-referrer")
        self.send_header("Cache-Control", "no-store")
        for k, v in extra:
            self.send_header(k, v)
        self.end_headers()

    def _body(self, code: int, data: bytes, ctype: str) -> None:
        self._headers(code, ctype, len(data))
        if self.command != "HEAD":
            self.wfile.write(data)

    def _error(self, code: int, text: str) -> None:
        self._body(code, (text + "\n").encode(), "text/plain; charset=utf-8")

    def _refuse(self) -> None:
        self.send_response(405)
        self.send_header("Allow", "GET, HEAD")
        self.send_header("Content-Length", "0")
        self.end_headers()

    do_POST = do_PUT = do_DELETE = do_PATCH = do_OPTIONS = do_TRACE = do_CONNECT = _refuse

    def do_HEAD(self) -> None:
        self.do_GET()

    def do_GET(self) -> None:
        c = self.console
        path = urllib.parse.urlsplit(self.path).path
        if path in ("/", "/index.html"):
            data, ctype = c._static["index.html"]
            return self._body(200, data, ctype)
        if path.startswith("/static/"):
            entry = c._static.get(path[len("/static/"):])          # names read at the start only
            if entry is None:
                return self._error(404, "not found")
            return self._body(200, *entry)
        if path.startswith("/thumb/") and path.endswith(".png"):
            name = urllib.parse.unquote(path[len("/thumb/"):-len(".png")])
            if name not in c.names:
                return self._error(404, "not found")
            png = c.thumbnail(name)
            if png is None:
                return self._error(404, "no solved frame yet")
            return self._body(200, png, "image/png")
        if path == "/events":
            return self._events()
        return self._error(404, "not found")

    def _events(self) -> None:
        c = self.console
        with c._cond:
            if c._streams >= MAX_STREAMS or c._closing.is_set():
                busy = True
            else:
                busy = False
                c._streams += 1
        if busy:
            return self._error(503, "too many event streams")
        try:
            self.close_connection = True
            self._headers(200, "text/event-stream; charset=utf-8", None, (("Connection", "close"),))
            if self.command == "HEAD":
                return
            self.connection.settimeout(10.0)
            self.wfile.write(f"retry: 1000\nevent: hello\ndata: {json.dumps({'run': c.run_id})}\n\n".encode())
            self.wfile.flush()
            last_snap, last_hist = -1, -1
            while not c._closing.is_set():
                with c._cond:
                    c._cond.wait_for(lambda: c._snap_seq != last_snap or c._closing.is_set(), timeout=10.0)
                    if c._closing.is_set():
                        break
                    changed = c._snap_seq != last_snap
                    last_snap = c._snap_seq
                if changed and c._snapshot:
                    data, last_hist = c._message(last_hist)
                    self.wfile.write(b"data: " + data.encode() + b"\n\n")
                else:
                    self.wfile.write(b": keep-alive\n\n")
                self.wfile.flush()
        except (OSError, ValueError):
            pass                                            # the browser went away
        finally:
            with c._cond:
                c._streams -= 1
