"""``shipstar live`` end to end: a simulated session replayed into watched directories,
the outputs received on UDP sockets bound to 127.0.0.1, NMEA checked with pynmea2, the
rows compared with ``shipstar measure`` on the same frames, and the bad inputs."""

from __future__ import annotations

import csv
import json
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pynmea2
import pytest

from shipstar.calibrate.installation import Installation, save_installation
from shipstar.pipeline import ATTITUDE_COLUMNS

from _live_process import Live  # noqa: E402  (tests/live on sys.path, pytest's rootdir-less import)

@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A 1 s rendered sea session (A2 30 ms late: pairing and carry), true installations,
    and measure's CSV of it."""
    from shipstar.simulate._session import sea_session, write_session

    root = tmp_path_factory.mktemp("live")
    spec = sea_session(duration_s=1.0)
    spec = spec.replace(sensors=(spec.sensors[0], spec.sensors[1].__class__(**{**spec.sensors[1].__dict__,
                                                                                "time_offset_s": 0.03})))
    write_session(spec, root / "sea")
    for s in spec.sensors:
        save_installation(Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor),
                          root / f"{s.name}.toml")
    proc = subprocess.run([sys.executable, "-m", "shipstar", "measure", "--sensor", "A1=sea/A1", "--sensor",
                           "A2=sea/A2", "--install", "A1.toml", "A2.toml", "--track", "sea/track.csv", "--weather",
                           "sea/weather.csv", "--out", "measure.csv"], cwd=root, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr
    return root


class Receiver:
    """Datagrams arriving on a UDP socket bound to 127.0.0.1 (a free port), in a thread."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.datagrams: list = []             # (monotonic s, text)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.is_set():
            try:
                data, _ = self.sock.recvfrom(65536)
            except socket.timeout:
                continue
            self.datagrams.append((time.monotonic(), data.decode("ascii")))

    def wait_for(self, predicate, timeout_s=60.0):
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if predicate([d for _, d in self.datagrams]):
                return True
            time.sleep(0.05)
        return False

    def close(self):
        self._stop.set()
        self._thread.join(2.0)
        self.sock.close()


def _replay(session_root, to_dir, speed=1.0):
    from shipstar.live._replay import plan_replay, replay, session_sensor_dirs, session_tables

    plan = plan_replay(session_sensor_dirs(session_root / "sea"), session_tables(session_root / "sea"))
    return replay(plan, to_dir, speed=speed, start_delay_s=0.3, handle_signals=False)


def _csv_rows(path):
    with open(path, newline="") as fh:
        return list(csv.reader(line for line in fh if not line.startswith("#")))


def _attitude_rows(datagrams):
    return [json.loads(d) for d in datagrams if '"kind"' not in d]


def test_live_sends_the_rows_measure_writes(session, tmp_path):
    """Replayed at its real pace, the session gives in live exactly measure's rows, in the
    CSV and as JSON lines; a status message every second; SIGTERM closes the CSV complete."""
    rx = Receiver()
    incoming = tmp_path / "in"
    incoming.mkdir()
    live = Live(session, ["--sensor", f"A1={incoming / 'A1'}", "--sensor", f"A2={incoming / 'A2'}", "--install",
                          "A1.toml", "A2.toml", "--track", str(incoming / "track.csv"), "--weather",
                          str(incoming / "weather.csv"), "--out", str(tmp_path / "live.csv"), "--udp",
                          f"127.0.0.1:{rx.port}", "--format", "jsonl", "--json",
                          "--max-waiting", "100"])       # never skip, even on a loaded machine: every row compared
    try:
        live.wait_line("watching")
        result = _replay(session, incoming)
        assert result.frames_written == 20
        n_rows = len(_csv_rows(session / "measure.csv")) - 1
        assert rx.wait_for(lambda ds: len(_attitude_rows(ds)) >= n_rows), live.lines
        assert (tmp_path / "live.csv.partial").exists() and not (tmp_path / "live.csv").exists()
        code, out = live.stop(signal.SIGTERM)
    finally:
        rx.close()
        if live.proc.poll() is None:
            live.proc.kill()
    assert code == 0, live.lines
    assert not (tmp_path / "live.csv.partial").exists()
    rows = _csv_rows(tmp_path / "live.csv")
    assert rows == _csv_rows(session / "measure.csv")                      # the same engine, the same numbers
    # what made each file, in both: the same software line
    from shipstar._codeid import software_line

    software = [[ln for ln in p.read_text().splitlines() if ln.startswith("# software = ")]
                for p in (tmp_path / "live.csv", session / "measure.csv")]
    assert software == [[f"# {software_line()}"]] * 2
    objects = _attitude_rows([d for _, d in rx.datagrams])
    assert len(objects) == n_rows
    for obj, row in zip(objects, rows[1:]):
        assert list(obj) == list(ATTITUDE_COLUMNS)
        for col, text in zip(ATTITUDE_COLUMNS, row):
            if text == "":
                assert obj[col] is None
            elif col in ("solved", "n_stars"):
                assert obj[col] == int(text)
            elif col in ("t_s", "heading_deg", "pitch_deg", "roll_deg", "integrity_chi2") or \
                    col.startswith(("sigma", "rms")):
                assert obj[col] == float(text)
            else:
                assert obj[col] == text
    status = [json.loads(d) for _, d in rx.datagrams if '"kind"' in d]
    assert len(status) >= 2 and all(s["kind"] == "status" for s in status)
    counts = [st["sensors"]["A1"]["frames_in"] for st in status]
    assert counts == sorted(counts) and counts[-1] > 0
    summary = json.loads(out)
    assert summary["stopped"] == "SIGTERM" and summary["out"] == str(tmp_path / "live.csv")
    assert summary["sensors"]["A1"]["n_frames"] == summary["sensors"]["A1"]["frames_in"] == 10
    assert summary["sensors"]["A2"]["skipped_behind"] == 0
    assert summary["latency"]["n"] == 20 and summary["latency"]["median_ms"] < 1000


def _nmea_datagrams(rx):
    return [d for _, d in rx.datagrams if d.startswith("$PSSTA")]


def _nav_sentences(session):
    """GGA + ZDA + MDA of the session's track and weather rows, one datagram per row."""
    from shipstar.live import _nmea
    from shipstar.sky.time import utc_jd_from_iso

    out = []
    with open(session / "sea" / "track.csv") as fh:
        track = [r for r in csv.DictReader(line for line in fh if not line.startswith("#"))]
    with open(session / "sea" / "weather.csv") as fh:
        weather = [r for r in csv.DictReader(line for line in fh if not line.startswith("#"))]
    for t, w in zip(track, weather):
        jd = utc_jd_from_iso(t["time_utc"])
        out.append(_nmea.zda(*jd) + _nmea.gga(*jd, float(t["lat_deg"]), float(t["lon_deg"]),
                                              float(t.get("height_m") or 0.0))
                   + _nmea.mda(float(w["pressure_hpa"]), float(w["temperature_c"])))
    return out


def test_nmea_out_with_the_position_from_nmea_in(session, tmp_path):
    """--format nmea: one datagram per epoch, $PSSTA (A or V), $HEHDT when valid, $PASHR, in
    that order, each with a checksum pynmea2 accepts, equal to the joint rows; $PSSTS every
    second.  The position and weather come as NMEA over UDP; a sentence with a bad checksum
    and one with a latitude of 91 deg are each reported in one line and change nothing."""
    rx = Receiver()
    nav = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    nav.bind(("127.0.0.1", 0))
    nav_port = nav.getsockname()[1]
    nav.close()
    incoming = tmp_path / "in"
    incoming.mkdir()
    live = Live(session, ["--sensor", f"A1={incoming / 'A1'}", "--sensor", f"A2={incoming / 'A2'}", "--install",
                          "A1.toml", "A2.toml", "--nav-udp", f"127.0.0.1:{nav_port}", "--udp",
                          f"127.0.0.1:{rx.port}", "--format", "nmea", "--quiet", "--max-waiting", "100"])
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        live.wait_line("watching")
        for text in _nav_sentences(session):
            sender.sendto(text.encode("ascii"), ("127.0.0.1", nav_port))
        sender.sendto(b"$GPGGA,121600.00,3154.000000,N,12018.000000,E,1,12,0.9,0.0,M,0.0,M,,*00\r\n",
                      ("127.0.0.1", nav_port))
        sender.sendto(pynmea2_gga_with_latitude_91().encode("ascii"), ("127.0.0.1", nav_port))
        live.wait_line("bad checksum")
        live.wait_line("91")
        _replay(session, incoming)
        assert rx.wait_for(lambda ds: sum(d.startswith("$PSSTA") for d in ds) >= 10), live.lines
        code, _ = live.stop(signal.SIGINT)
    finally:
        sender.close()
        rx.close()
        if live.proc.poll() is None:
            live.proc.kill()
    assert code == 0, live.lines
    epochs = _nmea_datagrams(rx)
    assert len(epochs) == 10
    joint = [r for r in _csv_rows(session / "measure.csv")[1:] if r[2] == "joint"]
    for datagram, row in zip(epochs, joint):
        assert datagram.endswith("\r\n") and datagram.count("\r\n") in (2, 3)
        lines = datagram.split("\r\n")[:-1]
        parsed = [pynmea2.parse(line, check=True) for line in lines]
        pssta = lines[0].split("*")[0].split(",")
        valid = row[5] == "1"
        assert pssta[11] == ("A" if valid else "V") and pssta[9] == "joint"
        if valid:
            assert [type(p).__name__ for p in parsed[1:]] == ["HDT", "ASHRATT"]
            assert float(pssta[3]) == pytest.approx(float(row[6]), abs=1.5e-6)
            assert float(pssta[4]) == pytest.approx(float(row[7]), abs=1.5e-6)
            assert float(pssta[5]) == pytest.approx(float(row[8]), abs=1.5e-6)
            assert float(parsed[1].heading) == pytest.approx(float(row[6]), abs=0.006)
            assert float(parsed[2].roll) == pytest.approx(float(row[8]), abs=0.006)
            assert float(parsed[2].pitch) == pytest.approx(float(row[7]), abs=0.006)
        else:
            assert pssta[3:9] == [""] * 6 and len(parsed) == 2
    status = [d for _, d in rx.datagrams if d.startswith("$PSSTS")]
    assert status and all(pynmea2.parse(s.strip(), check=True) for s in status)
    bad = [line for line in live.lines if "nav UDP" in line]
    assert len(bad) == 2, live.lines


def pynmea2_gga_with_latitude_91() -> str:
    """A GGA with a correct checksum and a latitude of 91 deg (nonsense)."""
    from shipstar.live._nmea import sentence

    return sentence("GPGGA,121600.00,9100.000000,N,12018.000000,E,1,12,0.9,0.0,M,0.0,M,,")


def test_bad_frames_are_reported_and_counted(session, tmp_path):
    """A frame that stays half-written, a corrupt one, one older than the sensor's last,
    and a sensor directory that disappears: one line each, the run goes on, every frame
    counted in the summary (and a row for each that has a time)."""
    frames = {s: sorted((session / "sea" / s).glob("*.fits")) for s in ("A1", "A2")}
    incoming = tmp_path / "in"
    for s in ("A1", "A2"):
        (incoming / s).mkdir(parents=True)
    live = Live(session, ["--sensor", f"A1={incoming / 'A1'}", "--sensor", f"A2={incoming / 'A2'}", "--install",
                          "A1.toml", "A2.toml", "--track", "sea/track.csv", "--weather", "sea/weather.csv",
                          "--out", str(tmp_path / "live.csv"), "--json", "--quiet", "--max-waiting", "100"])

    def put(sensor, src, name=None):
        tmp = incoming / sensor / f".{src.name}.part"
        shutil.copyfile(src, tmp)
        tmp.rename(incoming / sensor / (name or src.name))

    try:
        live.wait_line("watching")
        for k in range(4):
            put("A1", frames["A1"][k])
            put("A2", frames["A2"][k])
            time.sleep(0.1)
        data = frames["A1"][4].read_bytes()
        (incoming / "A1" / "half.fits").write_bytes(data[:len(data) // 2])          # never finished
        (incoming / "A1" / "junk.fits").write_bytes(b"this is not a FITS file" * 200)
        put("A1", frames["A1"][1], "older.fits")                                    # an old frame, new name
        live.wait_line("stayed incomplete")
        live.wait_line("junk.fits: unreadable")
        live.wait_line("older.fits")
        shutil.rmtree(incoming / "A2")
        live.wait_line("is gone")
        code, out = live.stop(signal.SIGINT)
    finally:
        if live.proc.poll() is None:
            live.proc.kill()
    assert code == 0, live.lines
    assert "Traceback" not in "\n".join(live.lines)
    summary = json.loads(out)
    a1 = summary["sensors"]["A1"]
    assert a1["frames_in"] == 7 and a1["n_frames"] == 7 and a1["n_unreadable"] == 1
    reasons = {f["frame"]: f["reason"] for f in a1["failures"]}
    assert "not later than" in reasons["older.fits"] and "stayed incomplete" in reasons["half.fits"]
    assert a1["unreadable"][0]["frame"] == "junk.fits"
    rows = _csv_rows(tmp_path / "live.csv")
    assert {r[4] for r in rows if r[3] == "A1"} >= {"older.fits", "half.fits"}


def test_nav_udp_port_in_use_is_one_line(session):
    busy = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    busy.bind(("127.0.0.1", 0))
    try:
        proc = subprocess.run([sys.executable, "-m", "shipstar", "live", "--sensor", "A1=sea/A1", "--install",
                               "A1.toml", "--nav-udp", f"127.0.0.1:{busy.getsockname()[1]}", "--out", "x.csv"],
                              cwd=session, capture_output=True, text=True, timeout=120)
    finally:
        busy.close()
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "in use" in proc.stderr and "Traceback" not in proc.stderr
    assert not (Path(session) / "x.csv.partial").exists()


def test_a_stop_before_any_frame_says_nothing_was_written(session):
    """No frame before the stop: no file, and a line that says so (the summary's "out":
    null alone, with exit 0, looked like a run that wrote; found by a bad-input sweep)."""
    (Path(session) / "empty").mkdir(exist_ok=True)
    live = Live(session, ["--sensor", "A1=empty", "--install", "A1.toml", "--track", "sea/track.csv",
                          "--weather", "sea/weather.csv", "--out", "none.csv", "--json"])
    live.wait_line("watching A1=empty")
    code, out = live.stop(signal.SIGINT)
    assert code == 0 and json.loads(out)["out"] is None
    assert "shipstar live: no frame arrived before the stop (SIGINT): nothing written to none.csv" in live.lines
    assert not list(Path(session).glob("none.csv*"))
