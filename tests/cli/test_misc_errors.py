"""Issue 13 item 10: bounded memory, errors in shipstar's words, one set of frame
extensions, one-frame-fails everywhere, demo --out over an earlier demo, no ~/.astropy,
progress bars."""

from __future__ import annotations

import gzip
import json
import os
import shutil
import subprocess
import sys
from dataclasses import replace

import pytest

from shipstar.calibrate.installation import Installation, save_installation


def _shipstar(args, cwd, env=None):
    return subprocess.run([sys.executable, "-m", "shipstar", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600, env=env)


def _one_line(proc, code):
    assert proc.returncode == code, (proc.returncode, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    return lines[0]


@pytest.fixture(scope="module")
def sea(tmp_path_factory):
    """A rendered 0.5 s sea session with true installations."""
    from shipstar.simulate._session import sea_session, write_session

    root = tmp_path_factory.mktemp("misc")
    spec = sea_session(duration_s=0.5)
    spec = spec.replace(sensors=(spec.sensors[0], replace(spec.sensors[1], time_offset_s=0.03)))
    write_session(spec, root / "sea")
    for s in spec.sensors:
        save_installation(Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor),
                          root / f"{s.name}.toml")
    return root


@pytest.mark.parametrize("flag, value, limit", [("--points", "100000000", "10000"),
                                                ("--mc-samples", "1000000000", "1000000")])
def test_error_model_sizes_above_the_limit_are_refused(tmp_path, flag, value, limit):
    line = _one_line(_shipstar(["error-model", flag, value, "--out", "em"], tmp_path), 2)
    assert f"{flag} {value} is above the limit of {limit}" in line and "GB" in line, line
    assert not (tmp_path / "em").exists()


def test_os_errors_name_what_and_the_users_path(tmp_path):
    line = _one_line(_shipstar(["error-model", "--out", "/proc/shipstar-em"], tmp_path), 2)
    assert line.startswith("shipstar error-model: error: cannot write --out /proc/shipstar-em"), line
    assert "Errno" not in line and "Error:" not in line, line


def test_measure_reads_gzipped_frames(sea, tmp_path):
    """One set of extensions for every command: .fits.gz frames measure as .fits do."""
    (tmp_path / "A1").mkdir()
    for p in sorted((sea / "sea" / "A1").glob("*.fits")):
        with open(p, "rb") as src, gzip.open(tmp_path / "A1" / (p.name + ".gz"), "wb", compresslevel=1) as dst:
            shutil.copyfileobj(src, dst)
    proc = _shipstar(["measure", "--sensor", f"A1={tmp_path / 'A1'}", "--install", str(sea / "A1.toml"),
                      "--track", str(sea / "sea" / "track.csv"), "--weather", str(sea / "sea" / "weather.csv"),
                      "--workers", "1", "--out", "att.csv", "--json"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)["sensors"]["A1"]
    assert s["n_frames"] == s["n_solved"] == 5


def test_measure_shows_the_index_then_the_frames(sea, tmp_path):
    """--progress: each sensor's indexing has its bar before the frames' (a night's index
    takes tens of seconds)."""
    proc = _shipstar(["measure", "--sensor", f"A1={sea / 'sea' / 'A1'}", "--install", str(sea / "A1.toml"),
                      "--track", str(sea / "sea" / "track.csv"), "--weather", str(sea / "sea" / "weather.csv"),
                      "--workers", "1", "--out", "att.csv", "--progress"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    err = proc.stderr
    assert "index A1 [" in err and "] 5/5" in err, err
    assert "frames [" in err and err.index("index A1 [") < err.index("frames ["), err


def test_calibrate_intrinsics_skips_a_truncated_frame_and_counts_it(sea, tmp_path):
    frames = tmp_path / "frames"
    shutil.copytree(sea / "sea" / "A1", frames)
    data = (frames / "A1_00002.fits").read_bytes()
    (frames / "A1_00002x.fits").write_bytes(data[:100000])                  # truncated
    proc = _shipstar(["calibrate", "intrinsics", "--frames", "frames", "--camera", "A1", "--out", "A1.cal.toml",
                      "--no-plot", "--progress"], tmp_path)
    assert proc.returncode == 1, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("shipstar calibrate intrinsics:")]
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "1 of 6 frames skipped (first: A1_00002x.fits: unreadable: truncated" in lines[0], lines[0]
    assert (tmp_path / "A1.cal.toml").exists()
    assert "frames [" in proc.stderr and "6/6" in proc.stderr                # the progress bar


def test_error_model_has_a_progress_bar(tmp_path):
    proc = _shipstar(["error-model", "--out", "em", "--progress"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "error model [" in proc.stderr and "1/1" in proc.stderr, proc.stderr


def test_solve_needs_nothing_of_home(sea, tmp_path):
    """An unwritable home (here a path under a file: unwritable even for root)."""
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")
    env = {**os.environ, "HOME": str(blocker / "home")}
    env.pop("XDG_CONFIG_HOME", None)
    env.pop("XDG_CACHE_HOME", None)
    proc = _shipstar(["solve", str(sea / "sea" / "A1" / "A1_00000.fits"), "--camera", "A1", "--json"], tmp_path,
                     env=env)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["solved"] is True
    assert not proc.stderr.strip(), proc.stderr


def test_demo_out_over_an_earlier_demo_cleans_its_outputs(tmp_path):
    out = tmp_path / "demo"
    (out / "config-used").mkdir(parents=True)
    (out / "config-used" / "old.toml").write_text("old = 1\n")
    (out / "report.html").write_text("<html>old</html>")
    (out / "results.json").write_text("{}")
    (out / "notes.txt").write_text("mine")                                    # not the demo's: kept
    assert _shipstar(["demo", "--write-config", "cfg"], tmp_path).returncode == 0
    proc = _shipstar(["demo", "--quick", "--config", "cfg", "--out", "demo", "--json"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert not (out / "config-used").exists()
    assert (out / "notes.txt").read_text() == "mine"
    assert "old" not in (out / "report.html").read_text()[:1000]
