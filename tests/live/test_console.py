"""The operator console (``shipstar live --http``): served read-only, and looked at in a
real browser (Debian's headless Chromium driven over the DevTools protocol pipe,
:mod:`shipstar.live._cdp`) while a simulated session is replayed into ``live``.

``SHIPSTAR_UPDATE_SCREENSHOT=1`` also writes the screenshot the browser test makes to
``docs/img/console.png`` (the README's picture).
"""

from __future__ import annotations

import http.client
import json
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from shipstar.live._cdp import chromium_path

from _live_process import Live  # noqa: E402  (tests/live on sys.path, pytest's rootdir-less import)

DOCS_SHOT = Path(__file__).resolve().parents[2] / "docs" / "img" / "console.png"


# -- helpers ------------------------------------------------------------------------------------

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _get(port, path, method="GET"):
    """``(status, headers, body)`` of one request sent with the path exactly as given."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.putrequest(method, path, skip_accept_encoding=True)
        conn.endheaders()
        r = conn.getresponse()
        body = r.read() if not r.getheader("Content-Type", "").startswith("text/event-stream") else r.read(200)
        return r.status, dict(r.getheaders()), body
    finally:
        conn.close()


class Receiver:
    """JSON lines arriving on a UDP socket bound to 127.0.0.1, in a thread."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.objects: list = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.is_set():
            try:
                data, _ = self.sock.recvfrom(65536)
            except socket.timeout:
                continue
            self.objects.append(json.loads(data))

    def joint(self, time_utc):
        return next((o for o in self.objects if o.get("method") == "joint" and o.get("time_utc") == time_utc), None)

    def close(self):
        self._stop.set()
        self._thread.join(2.0)
        self.sock.close()


def _install_chromium() -> str:
    """Debian's chromium with apt-get when running as root; '' on success, else why not."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0 or shutil.which("apt-get") is None:
        return "not root or no apt-get"
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    for cmd in (["apt-get", "update", "-qq"], ["apt-get", "install", "-y", "-qq", "chromium"]):
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=1800)
        if proc.returncode != 0:
            return f"{' '.join(cmd)} failed"
    return ""


@pytest.fixture(scope="module")
def chromium():
    path = chromium_path()
    if path is None:
        why = _install_chromium()
        path = chromium_path()
        if path is None:
            pytest.skip(f"headless Chromium is not installed ({why}): apt-get install chromium")
    return path


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A 6 s rendered two-sensor sea session and its true installations."""
    from shipstar.calibrate.installation import Installation, save_installation
    from shipstar.simulate._session import sea_session, write_session

    root = tmp_path_factory.mktemp("console")
    spec = sea_session(duration_s=6.0)
    write_session(spec, root / "sea")
    for s in spec.sensors:
        save_installation(Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor),
                          root / f"{s.name}.toml")
    return root


def _replay_thread(root: Path, to_dir: Path):
    from shipstar.live._replay import plan_replay, replay, session_sensor_dirs, session_tables

    plan = plan_replay(session_sensor_dirs(root / "sea"), session_tables(root / "sea"))
    out: dict = {}
    t = threading.Thread(target=lambda: out.setdefault("result", replay(plan, to_dir, speed=1.0, start_delay_s=0.3,
                                                                          handle_signals=False)), daemon=True)
    t.start()
    return t, out


def _live_args(incoming: Path, port: int, udp_port: int):
    return ["--sensor", f"A1={incoming / 'A1'}", "--sensor", f"A2={incoming / 'A2'}", "--install", "A1.toml",
            "A2.toml", "--track", str(incoming / "track.csv"), "--weather", str(incoming / "weather.csv"),
            "--udp", f"127.0.0.1:{udp_port}", "--format", "jsonl", "--http", f"127.0.0.1:{port}", "--stale-s", "1",
            "--quiet"]


# what the page shows of its newest epoch, read in one go
_SHOWN = """(() => {
  const row = document.getElementById('now-joint');
  if (!row || !window.shipstarConsole.snap) return null;
  const cells = ['h', 'p', 'r'].map(c => row.querySelector('td.' + c));
  return {time: document.getElementById('now-time').textContent, rowTime: row.dataset.time,
          values: cells.map(c => c.dataset.value === undefined ? null : Number(c.dataset.value)),
          texts: cells.map(c => c.textContent), sigma: row.querySelector('td.sig').textContent,
          framesIn: Number(document.getElementById('frames-in-A1').dataset.value),
          run: window.shipstarConsole.run, messages: window.shipstarConsole.messages,
          conn: document.getElementById('conn').textContent};
})()"""


# -- the server alone -----------------------------------------------------------------------------

def test_console_serves_only_its_page_stream_and_thumbnails(tmp_path):
    """GET of the page, its static files, the event stream and a sensor's thumbnail; any
    other path 404 (path traversal included, however spelled); any other method 405;
    every answer forbids loading anything from elsewhere."""
    from types import SimpleNamespace

    from shipstar.camera import camera_preset
    from shipstar.live._http import Console

    (tmp_path / "A1").mkdir()
    (tmp_path / "secret.txt").write_text("not to be served")
    configs = [SimpleNamespace(name="A1", camera=camera_preset("A1"))]
    console = Console(("127.0.0.1", 0), configs, [tmp_path / "A1"])
    console.start()
    try:
        port = console.address[1]
        status, headers, body = _get(port, "/")
        assert status == 200 and b"/static/console.js" in body
        assert "default-src 'none'" in headers["Content-Security-Policy"]
        for name in ("console.js", "console.css", "icon.svg"):
            status, headers, body = _get(port, f"/static/{name}")
            assert status == 200 and body, name
            text = body.replace(b'xmlns="http://www.w3.org/2000/svg"', b"")     # a namespace name, not a fetch
            assert b"http://" not in text and b"https://" not in text and b"//" + b"cdn" not in text
        for path in ("/../../etc/passwd", "/static/../../etc/passwd", "/static/%2e%2e/%2e%2e/etc/passwd",
                     "/static/..%2f..%2fsecret.txt", "/static//etc/passwd", "/%2e%2e/secret.txt", "/secret.txt",
                     "/thumb/../secret.txt", "/thumb/..%2fsecret.png", "/thumb/A9.png", "/A1/", "/static/",
                     "/events/../etc/passwd", "//etc/passwd"):
            status, _, body = _get(port, path)
            assert status == 404, path
            assert b"not to be served" not in body and b"root:" not in body
        status, _, _ = _get(port, "/thumb/A1.png")
        assert status == 404                                  # no solved frame yet
        for method in ("POST", "PUT", "DELETE", "PATCH"):
            status, headers, _ = _get(port, "/", method)
            assert status == 405 and headers["Allow"] == "GET, HEAD", method
        status, headers, body = _get(port, "/events")
        assert status == 200 and headers["Content-Type"].startswith("text/event-stream")
        assert body.startswith(b"retry: 1000\nevent: hello\n")
    finally:
        console.close()


def test_every_alarm_is_raised_with_its_time_and_cleared(tmp_path, monkeypatch):
    """Sky lost, sensors disagree, clock offset significant, EOP extrapolated, falling
    behind, frames stopped: raised from what the engine publishes, listed with their
    time, cleared once their condition has gone for CLEAR_AFTER_S."""
    from types import SimpleNamespace

    from shipstar.camera import camera_preset
    from shipstar.live import _http
    from shipstar.pipeline._integrity import Integrity

    configs = [SimpleNamespace(name=n, camera=camera_preset(n)) for n in ("A1", "A2")]
    c = _http.Console(("127.0.0.1", 0), configs, [tmp_path, tmp_path])
    t = 1000.0
    bad = SimpleNamespace(integrity=Integrity(True, 52.0, 30.66, 3, False, "A2", 41.5),
                          mounts=SimpleNamespace(time_offsets_s={"A2": {"offset_s": 0.0123, "sigma_s": 0.0004,
                                                                        "applied": True}}, monitor=()))
    c._alarm_integrity(bad, t)
    c._alarm_clock(bad, t)
    c._on_status({"sensors": {"A1": {"absent": True, "skipped_behind": 0},
                              "A2": {"absent": False, "skipped_behind": 3}},
                  "eop": {"quality": "extrapolated"}}, t)
    s = c._sensors["A2"]
    s.recent.extend((t - 1.5 + 0.1 * k, False) for k in range(10))       # unsolved rows, still coming
    s.last_row_mono, s.last_row = t - 0.6, {"reason": "clouded: 2 stars"}
    c._check(t)
    alarms = {a["kind"]: a for a in c._alarms.as_list()}
    assert set(alarms) == {"sensors disagree", "clock offset significant", "frames stopped", "falling behind",
                           "EOP extrapolated", "sky lost"}
    assert all(a["until_utc"] is None and a["since_utc"].endswith("Z") for a in alarms.values())
    assert "suspect A2" in alarms["sensors disagree"]["text"]
    assert "+12.30 ± 0.40 ms" in alarms["clock offset significant"]["text"]
    assert "A2: sky lost (clouded: 2 stars)" == alarms["sky lost"]["text"]
    c._streams = 1                                   # as if a page were connected
    c._publish(t)
    snap = json.loads(c._snapshot)
    assert {a["kind"] for a in snap["alarms"]} == set(alarms) and snap["run"] == c.run_id
    # with --ins-udp the status carries the INS error estimate: the next history point has it
    c._on_status({"sensors": {}, "ins": {"heading_bias_arcsec": 29.9, "pitch_bias_arcsec": 5.02,
                                         "roll_bias_arcsec": float("nan")}}, t)
    ok = SimpleNamespace(integrity=None, mounts=None, utc_jd1=2456366.5, utc_jd2=0.5, t_s=0.0)
    c._add_history(ok, {}, {})
    assert json.loads(c._history[-1][2])["ins"] == [29.9, 5.02, None]
    c._check(t + _http.CLEAR_AFTER_S + 1.0)          # nothing seen since: all cleared, still listed
    listed = c._alarms.as_list()
    assert len(listed) == 6 and all(a["until_utc"] for a in listed)


def test_the_default_host_is_loopback():
    from shipstar.live._http import parse_http_address

    assert parse_http_address("8080") == ("127.0.0.1", 8080)
    assert parse_http_address("0.0.0.0:8080") == ("0.0.0.0", 8080)
    assert parse_http_address(":8080") == ("127.0.0.1", 8080)


def test_http_port_in_use_is_one_line(session):
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    try:
        proc = subprocess.run([sys.executable, "-m", "shipstar", "live", "--sensor", "A1=sea/A1", "--install",
                               "A1.toml", "--lat-deg", "31.9", "--lon-deg", "120.3", "--pressure-hpa", "1013",
                               "--temperature-c", "10", "--http", f"127.0.0.1:{busy.getsockname()[1]}"],
                              cwd=session, capture_output=True, text=True, timeout=120)
    finally:
        busy.close()
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "--http" in proc.stderr and "cannot listen" in proc.stderr and "Traceback" not in proc.stderr


# -- the page in a browser, against live ------------------------------------------------------------

def test_console_in_headless_chromium(chromium, session, tmp_path):
    """Replay into ``live --http``: the page shows the numbers live sends on UDP for the
    same epoch, advances as frames arrive, raises an alarm when the frames stop, logs no
    error, and reconnects to a new live run on the same port."""
    from PIL import Image

    from shipstar.live._cdp import Browser

    port = _free_port()
    rx = Receiver()
    incoming = tmp_path / "in1"
    incoming.mkdir()
    live = Live(session, _live_args(incoming, port, rx.port))
    browser = live2 = None
    try:
        live.wait_line("operator console at http://127.0.0.1:")
        live.wait_line("watching")
        browser = Browser(f"http://127.0.0.1:{port}/", width=1280, height=900, binary=chromium)
        browser.wait_for("document.getElementById('conn').textContent === 'live'")
        replay, _ = _replay_thread(session, incoming)

        # the page advances as frames arrive
        first = browser.wait_for(_SHOWN.replace("return {", "if (!row.dataset.time) return null; return {"),
                                 timeout_s=60)
        later = browser.wait_for(f"(() => {{ const s = {_SHOWN}; return s && s.time > {json.dumps(first['time'])} "
                                 f"&& s.framesIn > {first['framesIn']} && s; }})()", timeout_s=30)
        assert later["messages"] > first["messages"]

        # the numbers shown are the UDP row's of the same epoch
        shown = browser.wait_for(f"(() => {{ const s = {_SHOWN}; return s && s.values[0] !== null && s; }})()",
                                 timeout_s=30)                  # a solved epoch (not one skipped behind)
        assert shown["time"] == shown["rowTime"]
        end = time.monotonic() + 10
        while rx.joint(shown["time"]) is None and time.monotonic() < end:
            time.sleep(0.05)
        row = rx.joint(shown["time"])
        assert row is not None, shown
        assert row["solved"] == 1
        assert shown["values"] == [row["heading_deg"], row["pitch_deg"], row["roll_deg"]]
        assert shown["texts"] == [f"{row[c]:.6f}" for c in ("heading_deg", "pitch_deg", "roll_deg")]
        # to 2 decimals: JavaScript's toFixed rounds a tie (0.125) up, Python's format to even
        sigmas = [float(x) for x in shown["sigma"].split(" / ")]
        assert sigmas == pytest.approx([row[c] for c in ("sigma_heading_arcsec", "sigma_pitch_arcsec",
                                                         "sigma_roll_arcsec")], abs=0.005 + 1e-9)

        # the thumbnails: PNGs of the frames with the identified stars circled
        browser.wait_for("['A1', 'A2'].every(n => { const i = document.getElementById('thumb-' + n); "
                         "return i && i.complete && i.naturalWidth > 0; })", timeout_s=20)
        status, headers, png = _get(port, "/thumb/A1.png")
        assert status == 200 and headers["Content-Type"] == "image/png" and png.startswith(b"\x89PNG")

        # a screenshot near the end of the replay: plots drawn
        replay.join(60)
        time.sleep(0.6)
        shot = tmp_path / "console.png"
        browser.screenshot(shot)
        with Image.open(shot) as im:
            rgb = np.asarray(im.convert("RGB"), float)
        assert rgb.shape[1] == 1280 and rgb.shape[0] >= 900
        assert rgb.std() > 20.0
        if os.environ.get("SHIPSTAR_UPDATE_SCREENSHOT"):
            DOCS_SHOT.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(shot, DOCS_SHOT)

        # the frames stop: an alarm with its time
        alarm = browser.wait_for("(() => { const a = [...document.querySelectorAll('#alarms li.active')]"
                                 ".find(li => li.dataset.kind === 'frames stopped'); return a && a.textContent; })()",
                                 timeout_s=20)
        assert "frames stopped arriving" in alarm and alarm[2] == ":" and alarm[5] == ":"
        assert browser.errors == [], browser.errors
        run1 = browser.evaluate("window.shipstarConsole.run")

        # live stops: the page says so; a new live run on the same port: it reconnects
        assert live.interrupt() == 0, live.lines
        browser.wait_for("document.getElementById('conn').textContent === 'reconnecting'", timeout_s=20)
        incoming2 = tmp_path / "in2"
        incoming2.mkdir()
        live2 = Live(session, _live_args(incoming2, port, rx.port))
        live2.wait_line("watching")
        browser.wait_for(f"window.shipstarConsole.run && window.shipstarConsole.run !== {json.dumps(run1)} && "
                         "document.getElementById('conn').textContent === 'live'", timeout_s=30)
        replay2, _ = _replay_thread(session, incoming2)
        again = browser.wait_for(f"(() => {{ const s = {_SHOWN}; return s && s.rowTime && s.framesIn > 0 && s; }})()",
                                 timeout_s=60)
        assert again["run"] != run1
        replay2.join(60)
        # while live was down the browser could not connect: only those refusals are logged
        assert all("ERR_CONNECTION_REFUSED" in e and "/events" in e for e in browser.errors), browser.errors
    finally:
        if browser is not None:
            browser.close()
        for lv in (live, live2):
            if lv is not None and lv.proc.poll() is None:
                lv.interrupt()
        rx.close()
