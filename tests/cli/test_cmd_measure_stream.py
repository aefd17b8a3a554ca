"""``shipstar measure`` as a stream: chunks and workers give the same rows, a stopped or
killed run resumes to the rows of an uninterrupted one, and nothing half-written looks
complete."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from shipstar.calibrate.installation import Installation, save_installation
from shipstar.pipeline import ATTITUDE_COLUMNS


@pytest.fixture(scope="module")
def night(tmp_path_factory):
    """A 4 s rendered sea session (both sensors, 80 frames) with the true installations."""
    from shipstar.simulate._session import sea_session, write_session

    root = tmp_path_factory.mktemp("night")
    spec = sea_session(duration_s=4.0)
    write_session(spec, root / "sea")
    for s in spec.sensors:
        save_installation(Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor),
                          root / f"{s.name}.toml")
    return root


ARGS = ["--sensor", "A1=sea/A1", "--sensor", "A2=sea/A2", "--install", "A1.toml", "A2.toml",
        "--track", "sea/track.csv", "--weather", "sea/weather.csv"]


def _cmd(*extra):
    return [sys.executable, "-m", "shipstar", "measure", *ARGS, *extra]


def _run(cwd, *extra):
    return subprocess.run(_cmd(*extra), cwd=cwd, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def reference(night):
    """The uninterrupted run, in chunks of 0.4 s with one worker."""
    proc = _run(night, "--out", "ref/att.csv", "--chunk-s", "0.4", "--workers", "1")
    assert proc.returncode == 0, proc.stderr
    return (night / "ref" / "att.csv").read_text()


def _rows(text):
    return list(csv.reader(line for line in text.splitlines() if not line.startswith("#")))


def test_chunks_and_workers_give_the_same_rows_as_one_pass(night, reference):
    """Two workers, or one chunk for the whole session, or the in-memory Python API: the
    same rows, byte for byte (each chunk is processed after 6.6 s of warm-up frames)."""
    from shipstar.calibrate.installation import load_installation
    from shipstar.camera import load_camera
    from shipstar.pipeline import SensorConfig, Track, WeatherTable, attitude_csv_text, process_session, scan_frames

    for extra in (["--workers", "2"], ["--chunk-s", "100", "--workers", "1"]):
        out = f"other/{extra[1]}.csv"
        proc = _run(night, "--out", out, "--chunk-s", "0.4", *extra)
        assert proc.returncode == 0, proc.stderr
        assert (night / out).read_text() == reference
    configs = []
    for name in ("A1", "A2"):
        inst = load_installation(night / f"{name}.toml")
        configs.append(SensorConfig(name, load_camera(inst.camera), inst))
    result = process_session(configs, [scan_frames(night / "sea" / n) for n in ("A1", "A2")],
                             Track.read_csv(night / "sea" / "track.csv"),
                             WeatherTable.read_csv(night / "sea" / "weather.csv"))
    assert _rows(attitude_csv_text(result)) == _rows(reference)
    assert len(_rows(reference)) == 1 + 4 * 40


def _wait_for(path, proc, timeout_s=120.0):
    end = time.monotonic() + timeout_s
    while not path.exists():
        assert proc.poll() is None, "the run ended before its first checkpoint"
        assert time.monotonic() < end
        time.sleep(0.002)


def test_a_killed_run_resumes_to_the_rows_of_an_uninterrupted_one(night, reference):
    # epochs held for the mounts' smoothing (a lag of 0.5 s: a little over a chunk) are not
    # written when the run dies; the checkpoint sends the resume back to their chunk
    out = night / "killed" / "att.csv"
    lag = ("--smooth-lag-s", "0.5")
    proc = subprocess.Popen(_cmd("--out", str(out), "--chunk-s", "0.4", "--workers", "1", *lag), cwd=night,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _wait_for(out.with_name("att.csv.resume"), proc)
    end = time.monotonic() + 120.0
    while json.loads(out.with_name("att.csv.resume").read_text())["next_chunk"] < 1:   # past chunk 0
        assert proc.poll() is None and time.monotonic() < end
        time.sleep(0.002)
    proc.kill()                                                   # a crash: no handler runs
    proc.wait(30)
    partial = out.with_name("att.csv.partial")
    assert not out.exists() and partial.exists()
    assert len(_rows(partial.read_text())) < len(_rows(reference))
    # the same command without --resume refuses to start over the stopped run
    again = _run(night, "--out", str(out), "--chunk-s", "0.4", "--workers", "1", *lag)
    assert again.returncode == 2 and "--resume" in again.stderr and len(again.stderr.splitlines()) == 1
    other = _run(night, "--out", str(out), "--chunk-s", "0.4", "--workers", "2", "--resume")
    assert other.returncode == 2 and "smooth_lag_s" in other.stderr       # another lag: other input
    done = _run(night, "--out", str(out), "--chunk-s", "0.4", "--workers", "2", "--resume", "--json", *lag)
    assert done.returncode == 0, done.stderr
    assert out.read_text() == reference           # a rigid deck: the rows of any lag
    assert not partial.exists() and not out.with_name("att.csv.resume").exists()
    summary = json.loads(done.stdout)
    assert summary["complete"] is True and summary["resumed_at_s"] > 0
    assert summary["methods"]["joint"]["n"] == 40 and summary["sensors"]["A1"]["n_frames"] == 40


def test_sigint_stops_cleanly_and_the_run_resumes(night, reference):
    out = night / "stopped" / "att.csv"
    proc = subprocess.Popen(_cmd("--out", str(out), "--chunk-s", "0.4", "--workers", "1", "--json"), cwd=night,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for(out.with_name("att.csv.resume"), proc)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    lines = [ln for ln in stderr.splitlines() if "stopped by SIGINT" in ln]
    assert len(lines) == 1 and "--resume" in lines[0] and "Traceback" not in stderr
    summary = json.loads(stdout)
    assert summary["stopped"] == "SIGINT" and summary["complete"] is False
    assert summary["out"].endswith("att.csv.partial")
    partial = out.with_name("att.csv.partial")
    text = partial.read_text()
    assert not out.exists() and text.endswith("\n")
    rows = _rows(text)
    assert rows[0] == list(ATTITUDE_COLUMNS) and all(len(r) == len(ATTITUDE_COLUMNS) for r in rows)
    assert rows == _rows(reference)[:len(rows)]                  # every finished row, and nothing else
    done = _run(night, "--out", str(out), "--chunk-s", "0.4", "--workers", "1", "--resume")
    assert done.returncode == 0, done.stderr
    assert out.read_text() == reference


def test_resume_refuses_other_input(night, reference, tmp_path):
    out = tmp_path / "att.csv"
    proc = subprocess.Popen(_cmd("--out", str(out), "--chunk-s", "0.4", "--workers", "1"), cwd=night,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _wait_for(tmp_path / "att.csv.resume", proc)
    proc.kill()
    proc.wait(30)
    bad = _run(night, "--out", str(out), "--chunk-s", "0.5", "--workers", "1", "--resume")
    assert bad.returncode == 2 and len(bad.stderr.splitlines()) == 1 and "chunk_s" in bad.stderr
    # another Earth orientation table (here 0.1 ms of 1973's UT1 - UTC): the rows after the
    # resume would not be those of the rows before it
    from pathlib import Path

    from astropy_iers_data import IERS_A_FILE

    first, rest = Path(IERS_A_FILE).read_bytes().split(b"\n", 1)
    table = tmp_path / "finals.all"
    table.write_bytes(first[:154] + first[154:165].replace(b".8075000", b".8076000") + first[165:] + b"\n" + rest)
    eop = _run(night, "--out", str(out), "--chunk-s", "0.4", "--workers", "1", "--resume", "--eop", str(table))
    assert eop.returncode == 2 and len(eop.stderr.splitlines()) == 1 and "eop_digest" in eop.stderr, eop.stderr
    nothing = _run(night, "--out", str(tmp_path / "never.csv"), "--resume")
    assert nothing.returncode == 2 and "nothing was stopped" in nothing.stderr
    assert (tmp_path / "att.csv.partial").exists() and os.path.getsize(tmp_path / "att.csv.partial") > 0
