"""``shipstar measure`` run as a subprocess on simulated image-level sessions, and its bad input."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from shipstar.calibrate.installation import Installation, save_installation


def _run(args, cwd):
    return subprocess.run([sys.executable, "-m", "shipstar", "measure", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=600)


def _assert_bad_input(proc, *fragments):
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for text in fragments:
        assert text in lines[0], lines[0]


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _noise_frame(path, date_obs):
    from astropy.io import fits

    rng = np.random.default_rng(abs(hash(str(path))) % 2**32)
    hdu = fits.PrimaryHDU(rng.poisson(110, (1024, 1024)).astype(np.uint16))
    hdu.header["DATE-OBS"] = date_obs
    hdu.writeto(path)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A 0.5 s sea session (A2 30 ms late) and a 0.3 s dock session, with true installation files."""
    from shipstar.simulate._session import dock_session, sea_session, write_session

    root = tmp_path_factory.mktemp("measure")
    sea = sea_session(duration_s=0.5)
    sea = sea.replace(sensors=(sea.sensors[0], sea.sensors[1].__class__(**{**sea.sensors[1].__dict__,
                                                                            "time_offset_s": 0.03})))
    write_session(sea, root / "sea")
    write_session(dock_session(duration_s=0.3), root / "dock")
    for s in sea.sensors:
        save_installation(Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor),
                          root / f"{s.name}.toml")
    return root


SEA = ["--sensor", "A1=sea/A1", "--sensor", "A2=sea/A2", "--install", "A1.toml", "A2.toml",
       "--track", "sea/track.csv", "--weather", "sea/weather.csv"]
DOCK_SITE = ["--lat-deg", "31.9", "--lon-deg", "120.3", "--pressure-hpa", "1021.7", "--temperature-c", "11.1"]


def test_sea_session_two_sensors(session):
    proc = _run(SEA + ["--out", "out/att.csv", "--truth", "sea/truth.csv", "--plots", "out/plots", "--json"], session)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["fore_aft_sensor"] == "A1" and summary["athwartship_sensor"] == "A2"
    for s in ("A1", "A2"):
        assert summary["sensors"][s]["n_solved"] == 5 and summary["sensors"][s]["failures"] == []
    joint, seed = summary["methods"]["joint"], summary["methods"]["seed-rule"]
    assert joint["n_solved"] == 5 and max(joint["rms_arcsec"]) < 3.0
    assert joint["rms_arcsec"][0] < seed["rms_arcsec"][0]
    rows = _rows(session / "out" / "att.csv")
    assert len(rows) == 20 and {r["method"] for r in rows} == {"single", "seed-rule", "joint"}
    assert all(r["solved"] == "1" for r in rows)
    assert {p.split("/")[-1] for p in summary["plots"]} == {"attitude.png", "residuals.png"}
    assert (session / "out" / "plots" / "attitude.png").stat().st_size > 10000


def test_dock_single_sensor_text_summary(session):
    proc = _run(["--sensor", "A1=dock/A1", "--install", "A1.toml", *DOCK_SITE, "--out", "dock.csv"], session)
    assert proc.returncode == 0, proc.stderr
    assert "sensor A1: 3 of 3 frames solved" in proc.stdout and "written: dock.csv" in proc.stdout
    rows = _rows(session / "dock.csv")
    assert [r["method"] for r in rows] == ["single"] * 3
    heading = np.array([float(r["heading_deg"]) for r in rows])
    assert np.all(np.abs(heading - 46.47458611) * 3600 < 5.0)


def test_a_failing_frame_is_reported_with_exit_1(session, tmp_path):
    shutil.copytree(session / "dock" / "A1", tmp_path / "A1")
    _noise_frame(tmp_path / "A1" / "A1_00001b.fits", "2013-03-15T12:16:00.150")
    proc = _run(["--sensor", f"A1={tmp_path / 'A1'}", "--install", "A1.toml", *DOCK_SITE,
                 "--out", str(tmp_path / "a.csv")], session)
    assert proc.returncode == 1, proc.stderr
    assert "1 frames failed" in proc.stderr and "A1_00001b.fits" in proc.stderr
    rows = _rows(tmp_path / "a.csv")
    bad = [r for r in rows if r["solved"] == "0"]
    assert len(rows) == 4 and len(bad) == 1 and bad[0]["frame"] == "A1_00001b.fits" and bad[0]["reason"]


def test_frame_without_date_obs(session, tmp_path):
    from astropy.io import fits

    shutil.copytree(session / "dock" / "A1", tmp_path / "A1")
    fits.PrimaryHDU(np.zeros((8, 8), np.uint16)).writeto(tmp_path / "A1" / "A1_00009.fits")
    out = tmp_path / "x.csv"
    proc = _run(["--sensor", f"A1={tmp_path / 'A1'}", "--install", "A1.toml", *DOCK_SITE, "--out", str(out)], session)
    _assert_bad_input(proc, "A1_00009.fits has no DATE-OBS")
    assert not out.exists()


def test_frames_out_of_time_order(session, tmp_path):
    (tmp_path / "A1").mkdir()
    shutil.copy(session / "dock" / "A1" / "A1_00000.fits", tmp_path / "A1" / "b.fits")
    shutil.copy(session / "dock" / "A1" / "A1_00001.fits", tmp_path / "A1" / "a.fits")
    proc = _run(["--sensor", f"A1={tmp_path / 'A1'}", "--install", "A1.toml", *DOCK_SITE,
                 "--out", str(tmp_path / "x.csv")], session)
    _assert_bad_input(proc, "out of time order", "b.fits")


def test_sensor_whose_frames_do_not_identify(session, tmp_path):
    (tmp_path / "A1").mkdir()
    for k in range(3):
        _noise_frame(tmp_path / "A1" / f"n{k}.fits", f"2013-03-15T12:16:00.{k}00")
    out = tmp_path / "x.csv"
    proc = _run(["--sensor", f"A1={tmp_path / 'A1'}", "--install", "A1.toml", *DOCK_SITE, "--out", str(out)], session)
    _assert_bad_input(proc, "sensor A1: none of its 3 frames solved")
    assert not out.exists()


@pytest.mark.parametrize("args, fragment", [
    (["--sensor", "A1=dock/A1", "--install", "A2.toml", *DOCK_SITE], "is for sensor 'A2'"),
    (["--sensor", "A1=dock/A1", "--sensor", "A2=dock/A2", "--install", "A1.toml", *DOCK_SITE],
     "no installation file for sensor 'A2'"),
    (["--sensor", "A1=dock/A1", "--install", "A1.toml", "--camera", "A1=A2", *DOCK_SITE],
     "calibrated with camera 'A1'"),
    (["--sensor", "A1=dock/A1", "--install", "A1.toml", "--lat-deg", "31.9", "--lon-deg", "120.3",
      "--pressure-hpa", "nan", "--temperature-c", "11.1"], "--pressure-hpa"),
    (["--sensor", "A1=dock/A1", "--install", "A1.toml", "--lat-deg", "31.9", "--lon-deg", "120.3"],
     "give the weather"),
    (["--sensor", "A1=dock/A1", "--install", "A1.toml", "--pressure-hpa", "1000", "--temperature-c", "5"],
     "ship's position"),
    (["--sensor", "A1=dock/A1", "--install", "A1.toml", *DOCK_SITE, "--track", "sea/track.csv"], "not both"),
    (["--sensor", "A1=sea/A1", "--install", "A1.toml", "--track", "sea/track.csv", "--weather", "bad.csv"],
     "must be finite"),
    (["--sensor", "A1=dock/A1", "--install", "A1.toml", "--track", "late.csv", *DOCK_SITE[4:]],
     "outside the track"),
    (["--sensor", "A1=dock/A2", "--install", "A1.toml", *DOCK_SITE], "from sensor 'A2'"),
    (["--sensor", "A1", "--install", "A1.toml", *DOCK_SITE], "NAME=VALUE"),
    (["--sensor", "A1=nowhere", "--install", "A1.toml", *DOCK_SITE], "nowhere"),
])
def test_bad_input(session, args, fragment):
    (session / "bad.csv").write_text("time_utc,pressure_hpa,temperature_c\n2013-03-15T12:15:00,1021,nan\n")
    (session / "late.csv").write_text("time_utc,lat_deg,lon_deg\n2013-03-15T13:00:00,31.9,120.3\n"
                                      "2013-03-15T13:10:00,31.9,120.3\n")
    proc = _run([*args, "--out", "never.csv"], session)
    _assert_bad_input(proc, fragment)
    assert not (session / "never.csv").exists()
