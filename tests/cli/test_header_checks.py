"""Cross-checks of the frames' own FITS headers (issue 13, item 2; docs/file-formats.md,
"Header cross-checks"), through the real command line on small simulated frames.

A contradiction beyond its tolerance is refused in one line naming both values; with
``--trust-flags`` the command runs and records the override in its outputs.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import pytest

from shipstar.calibrate.installation import load_installation
from shipstar.simulate._session import SEED_DOCK_HEADING_DEG


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    e = dict(os.environ)
    e.setdefault("SHIPSTAR_CACHE_DIR", str(tmp_path_factory.mktemp("shipstar_cache")))
    return e


def _run(env, cwd, *args):
    return subprocess.run([sys.executable, "-m", "shipstar", *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


def _refused(proc, *fragments):
    assert proc.returncode not in (0, 1), (proc.returncode, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    for text in fragments:
        assert text in lines[0], lines[0]
    return lines[0]


# ------------------------------------------------------------------ calibrate install / measure (dock)

@pytest.fixture(scope="module")
def dock(tmp_path_factory):
    """Seed 000's dock night (SITELAT 31.9, SITELONG 120.3, 1021.7 hPa, 11.1 C), 4 frames."""
    from shipstar.simulate._session import dock_session, write_session

    root = tmp_path_factory.mktemp("header_checks")
    write_session(dock_session(duration_s=0.4), root / "dock")
    return root


def _install(lat="31.9", lon="120.3", pressure="1021.7", temperature="11.1", sensor="A1", camera="A1"):
    return ["calibrate", "install", "--frames", "dock/A1", "--sensor", sensor, "--camera", camera,
            "--lat-deg", lat, "--lon-deg", lon, "--heading-deg", repr(SEED_DOCK_HEADING_DEG),
            "--pressure-hpa", pressure, "--temperature-c", temperature]


def test_simulated_frames_pass_the_checks_without_flags(env, dock):
    proc = _run(env, dock, *_install(), "--out", "ok.install.toml", "--json")
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert "trust_flags" not in rep and "header_overrides" not in rep
    inst = load_installation(dock / "ok.install.toml")
    assert inst.trust_flags is False and inst.header_overrides == ()
    assert "trust_flags" not in (dock / "ok.install.toml").read_text()


def test_install_refuses_a_latitude_the_headers_contradict(env, dock):
    line = _refused(_run(env, dock, *_install(lat="41.9"), "--out", "bad.install.toml"),
                    "SITELAT = 31.9 deg", "--lat-deg 41.9", "tolerance 0.02 deg", "--trust-flags")
    assert "A1_" in line                                        # the frame is named
    assert not (dock / "bad.install.toml").exists()


@pytest.mark.parametrize("change, fragments", [
    ({"lon": "121.3"}, ("SITELONG = 120.3 deg", "--lon-deg 121.3")),
    ({"pressure": "1010"}, ("PRESSURE = 1021.7 hPa", "--pressure-hpa 1010", "tolerance 5 hPa")),
    ({"temperature": "20"}, ("TEMPERAT = 11.1 C", "--temperature-c 20", "tolerance 5 C")),
    ({"sensor": "A2", "camera": "A2"}, ("SENSOR = 'A1'", "--sensor A2 (camera A2)")),
    ({"camera": "seed004"}, ("1024 x 1024 px", "camera 'seed004' is 512 x 512 px")),
])
def test_install_refuses_each_contradiction(env, dock, change, fragments):
    _refused(_run(env, dock, *_install(**change), "--out", "bad.install.toml"), *fragments)


def test_install_within_the_tolerances_runs(env, dock):
    # 0.015 deg of latitude (1.7 km), 4 hPa, 4 C: within the documented tolerances
    proc = _run(env, dock, *_install(lat="31.915", pressure="1025.7", temperature="15.1"), "--out", "near.toml")
    assert proc.returncode == 0, proc.stderr


def test_install_with_trust_flags_runs_and_records_the_override(env, dock):
    proc = _run(env, dock, *_install(lat="41.9"), "--trust-flags", "--out", "trusted.install.toml", "--json")
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["trust_flags"] is True
    (o,) = rep["header_overrides"]
    assert o["key"] == "SITELAT" and o["n_frames"] == 4 and "--lat-deg 41.9" in o["first"]
    assert "--trust-flags" in proc.stderr and "SITELAT" in proc.stderr
    inst = load_installation(dock / "trusted.install.toml")
    assert inst.trust_flags is True
    assert len(inst.header_overrides) == 1 and "SITELAT = 31.9 deg" in inst.header_overrides[0]
    assert inst.dock.lat_rad == pytest.approx(math.radians(41.9))           # the flag was used
    # the wrong latitude moved the installation by degrees: what the check protects against
    ok = load_installation(dock / "ok.install.toml") if (dock / "ok.install.toml").exists() else None
    if ok is not None:
        assert abs(math.degrees(inst.el_rad - ok.el_rad)) > 1.0 or abs(math.degrees(inst.az_rad - ok.az_rad)) > 1.0


def test_install_trust_flags_does_not_override_the_image_size(env, dock):
    _refused(_run(env, dock, *_install(camera="seed004"), "--trust-flags", "--out", "x.toml"),
             "camera 'seed004' is 512 x 512 px")


def test_measure_refuses_a_latitude_the_headers_contradict_and_trust_flags_records_it(env, dock):
    proc = _run(env, dock, *_install(), "--out", "A1.install.toml")
    assert proc.returncode == 0, proc.stderr
    common = ["measure", "--sensor", "A1=dock/A1", "--install", "A1.install.toml", "--lon-deg", "120.3",
              "--pressure-hpa", "1021.7", "--temperature-c", "11.1", "--workers", "1"]
    _refused(_run(env, dock, *common, "--lat-deg", "41.9", "--out", "bad.csv"),
             "SITELAT = 31.9 deg", "--lat-deg 41.9", "--trust-flags")
    assert not (dock / "bad.csv").exists()
    proc = _run(env, dock, *common, "--lat-deg", "41.9", "--trust-flags", "--out", "trusted.csv", "--json")
    assert proc.returncode in (0, 1), proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["trust_flags"] is True
    (o,) = summary["header_overrides"]
    assert (o["sensor"], o["key"], o["n_frames"]) == ("A1", "SITELAT", 4)
    comments = [ln for ln in (dock / "trusted.csv").read_text().splitlines() if ln.startswith("#")]
    assert any(ln.startswith("# trust_flags = true") for ln in comments), comments
    assert any("header override: sensor A1: SITELAT" in ln and "--lat-deg 41.9" in ln for ln in comments), comments


def test_measure_refuses_frames_whose_sensor_header_names_another_sensor(env, dock):
    # A2's frames given as A1's (their SENSOR header says A2): refused, both names in the line
    proc = _run(env, dock, *_install(), "--out", "A1b.install.toml")
    assert proc.returncode == 0, proc.stderr
    _refused(_run(env, dock, "measure", "--sensor", "A1=dock/A2", "--install", "A1b.install.toml",
                  "--lat-deg", "31.9", "--lon-deg", "120.3", "--pressure-hpa", "1021.7", "--temperature-c", "11.1",
                  "--workers", "1", "--out", "swapped.csv"),
             "SENSOR = 'A2'", "--sensor A1=dock/A2")


def test_install_refuses_frames_of_another_camera_whose_sensor_card_matches(env, dock):
    """`--sensor A1 --camera A2` on A1's frames (SENSOR = INSTRUME = 'A1'): the SENSOR card
    matched the sensor's name, INSTRUME was never compared with the camera, and the
    installation came out 0.31 deg off in elevation (39.686 against 39.373 deg) with exit 0."""
    line = _refused(_run(env, dock, *_install(camera="A2"), "--out", "cam.install.toml"),
                    "A1_00000.fits", "header INSTRUME = 'A1'", "the camera is 'A2'", "--sensor A1 (camera A2)",
                    "--trust-flags")
    assert "header SENSOR" not in line                      # SENSOR = 'A1' is the sensor given
    assert not (dock / "cam.install.toml").exists()
    proc = _run(env, dock, *_install(camera="A2"), "--trust-flags", "--out", "cam.install.toml", "--json")
    assert proc.returncode == 0, proc.stderr
    (o,) = json.loads(proc.stdout)["header_overrides"]
    assert o["key"] == "INSTRUME" and o["n_frames"] == 4 and "the camera is 'A2'" in o["first"]
    # what the check protects against: A2's model on A1's frames moves the elevation by 0.3 deg
    el_deg = math.degrees(load_installation(dock / "cam.install.toml").el_rad)
    assert abs(el_deg - 39.3734) > 0.2


def test_install_refuses_frames_of_another_sensor_whose_camera_card_matches(env, dock):
    """`--sensor A2 --camera A1` on A1's frames wrote an A2 installation from A1's frames (exit 0)."""
    _refused(_run(env, dock, *_install(sensor="A2"), "--out", "a2.install.toml"),
             "header SENSOR = 'A1'", "the sensor is 'A2'", "--sensor A2 (camera A1)", "--trust-flags")
    assert not (dock / "a2.install.toml").exists()


def test_measure_refuses_an_installation_of_another_camera_than_the_frames(env, dock):
    """An installation file naming camera A2 for sensor A1's frames: measure used A2's model
    on them (at sea: pitch 0.979 against a true 1.288 deg) with exit 0; refused, and with
    --trust-flags run and recorded."""
    proc = _run(env, dock, *_install(), "--out", "A1c.install.toml")
    assert proc.returncode == 0, proc.stderr
    path = dock / "A1c.install.toml"
    text = path.read_text()
    assert 'camera = "A1"' in text
    path.write_text(text.replace('camera = "A1"', 'camera = "A2"'))
    common = ["measure", "--sensor", "A1=dock/A1", "--install", "A1c.install.toml", "--lat-deg", "31.9",
              "--lon-deg", "120.3", "--pressure-hpa", "1021.7", "--temperature-c", "11.1", "--workers", "1"]
    _refused(_run(env, dock, *common, "--out", "cam.csv"),
             "header INSTRUME = 'A1'", "the camera is 'A2'", "--sensor A1=dock/A1 (camera A2)", "--trust-flags")
    assert not (dock / "cam.csv").exists()
    proc = _run(env, dock, *common, "--trust-flags", "--out", "cam_trusted.csv", "--json")
    assert proc.returncode in (0, 1), proc.stderr
    (o,) = json.loads(proc.stdout)["header_overrides"]
    assert (o["sensor"], o["key"], o["n_frames"]) == ("A1", "INSTRUME", 4)


# ------------------------------------------------------------------ solve

@pytest.fixture(scope="module")
def a1_frame(env, tmp_path_factory):
    """A frame of camera A1 (FITS SENSOR = INSTRUME = 'A1'), in space (Orion)."""
    root = tmp_path_factory.mktemp("solve")
    proc = _run(env, root, "simulate", "--camera", "A1", "--ra-deg", "83.8", "--dec-deg", "-5.4", "--seed", "3",
                "--out", "a1.fits")
    assert proc.returncode == 0, proc.stderr
    return root / "a1.fits"


def test_solve_with_the_camera_the_header_names_runs(env, a1_frame):
    proc = _run(env, a1_frame.parent, "solve", a1_frame, "--camera", "A1", "--json")
    assert proc.returncode == 0, proc.stderr
    assert "trust_flags" not in json.loads(proc.stdout)


def test_solve_refuses_another_camera_than_the_header_names(env, a1_frame):
    _refused(_run(env, a1_frame.parent, "solve", a1_frame, "--camera", "A2", "--json"),
             "a1.fits", "SENSOR = 'A1'", "--camera A2", "--trust-flags")


def test_solve_with_trust_flags_runs_and_records_the_override(env, a1_frame):
    proc = _run(env, a1_frame.parent, "solve", a1_frame, "--camera", "A2", "--trust-flags", "--json")
    assert proc.returncode in (0, 1), proc.stderr
    out = json.loads(proc.stdout)
    assert out["trust_flags"] is True and out["camera"] == "A2"
    (o,) = out["header_overrides"]
    assert o["key"] == "SENSOR" and "SENSOR = 'A1'" in o["first"] and "--camera A2" in o["first"]
    assert "--trust-flags" in proc.stderr

