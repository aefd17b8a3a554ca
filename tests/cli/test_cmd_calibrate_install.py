"""``shipstar calibrate install`` run as a subprocess on a simulated dock session, and its bad input.

The ``calibrate`` group lives in ``cli/_cmd_calibrate.py``; until it adds ``install``, the
command is run through a wrapper with the same error handling as ``shipstar.cli.main``.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from shipstar.calibrate.installation import load_installation
from shipstar.simulate._session import SEED_A1_INSTALL_DEG, SEED_DOCK_HEADING_DEG

_WRAPPER = """
import argparse, sys
from shipstar.cli._calibrate_install import add_install_parser
from shipstar.errors import ShipstarError
parser = argparse.ArgumentParser(prog="shipstar calibrate")
add_install_parser(parser.add_subparsers(dest="sub"))
args = parser.parse_args(sys.argv[1:])
try:
    sys.exit(args.run(args))
except ShipstarError as exc:
    print(f"shipstar calibrate: error: {exc}", file=sys.stderr)
    sys.exit(2)
"""


def _wired() -> bool:
    proc = subprocess.run([sys.executable, "-m", "shipstar", "calibrate", "install", "--help"],
                          capture_output=True, text=True, timeout=120)
    return proc.returncode == 0 and "--heading-deg" in proc.stdout


@pytest.fixture(scope="module")
def command():
    if _wired():
        return [sys.executable, "-m", "shipstar", "calibrate", "install"]
    return [sys.executable, "-c", _WRAPPER, "install"]


def _run(command, args, cwd):
    return subprocess.run([*command, *args], cwd=cwd, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def dock(tmp_path_factory):
    from shipstar.simulate._session import dock_session, write_session

    root = tmp_path_factory.mktemp("install")
    write_session(dock_session(duration_s=0.4), root / "dock")
    return root


COMMON = ["--lat-deg", "31.9", "--lon-deg", "120.3", "--heading-deg", repr(SEED_DOCK_HEADING_DEG),
          "--pressure-hpa", "1021.7", "--temperature-c", "11.1"]


def _assert_bad_input(proc, *fragments):
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for text in fragments:
        assert text in lines[0], lines[0]


def test_calibrates_a1_from_dock_frames(command, dock):
    proc = _run(command, ["--frames", "dock/A1", "--sensor", "A1", "--camera", "A1", *COMMON,
                          "--out", "A1.install.toml", "--json"], dock)
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["n_frames"] == 4 and rep["n_used"] == 4 and rep["failures"] == []
    inst = load_installation(dock / "A1.install.toml")
    assert inst.sensor == "A1" and inst.camera == "A1" and inst.date_utc.startswith("2013-03-15T12:16:00")
    got = np.degrees([inst.az_rad, inst.el_rad, inst.roll_rad])
    err_arcsec = (got - SEED_A1_INSTALL_DEG) * 3600
    assert abs(err_arcsec[0]) < 1.0 and abs(err_arcsec[1]) < 1.0 and abs(err_arcsec[2]) < 5.0
    assert rep["az_deg"] == pytest.approx(got[0], abs=1e-12)
    assert inst.dock is not None and inst.dock.heading_rad == pytest.approx(np.radians(SEED_DOCK_HEADING_DEG))
    assert inst.dock.refraction_model == "erfa" and inst.dock.refraction_mode == "per-star"
    assert inst.dock.eop_quality == "measured" and inst.dock.dut1_error_s < 1e-3 and inst.warnings == ()
    assert (inst.dock.xi_rad, inst.dock.eta_rad) == (0.0, 0.0)
    assert rep["eop"]["quality"] == "measured" and rep["warnings"] == []


def test_text_output_and_almanac_model(command, dock):
    proc = _run(command, ["--frames", "dock/A2", "--sensor", "A2", "--camera", "A2", *COMMON, "--refraction",
                          "almanac", "--out", "A2.toml"], dock)
    assert proc.returncode == 0, proc.stderr
    assert "sensor A2 (camera A2): 4 of 4 frames used" in proc.stdout and "written: A2.toml" in proc.stdout
    assert load_installation(dock / "A2.toml").dock.refraction_model == "almanac"


def _noise_dir(path, n=3):
    from astropy.io import fits

    path.mkdir()
    rng = np.random.default_rng(1)
    for k in range(n):
        hdu = fits.PrimaryHDU(rng.poisson(110, (1024, 1024)).astype(np.uint16))
        hdu.header["DATE-AVG"] = f"2013-03-15T12:16:00.{k}00"           # mid-exposure
        hdu.writeto(path / f"n{k}.fits")


def test_frames_that_do_not_identify(command, dock, tmp_path):
    _noise_dir(tmp_path / "noise")
    out = tmp_path / "x.toml"
    proc = _run(command, ["--frames", str(tmp_path / "noise"), "--sensor", "A1", "--camera", "A1", *COMMON,
                          "--out", str(out)], dock)
    _assert_bad_input(proc, "sensor A1: 0 of 3 frames solved", "clouded")    # noise only: no stars where ~50 are expected
    assert not out.exists()


def test_some_failed_frames_give_exit_1(command, dock, tmp_path):
    from astropy.io import fits

    shutil.copytree(dock / "dock" / "A1", tmp_path / "A1")
    hdu = fits.PrimaryHDU(np.full((1024, 1024), 100, np.uint16))
    hdu.header["DATE-AVG"] = "2013-03-15T12:16:00.150"
    hdu.writeto(tmp_path / "A1" / "A1_00001b.fits")
    proc = _run(command, ["--frames", str(tmp_path / "A1"), "--sensor", "A1", "--camera", "A1", *COMMON,
                          "--out", str(tmp_path / "a.toml"), "--json"], dock)
    assert proc.returncode == 1, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["n_failed"] == 1 and rep["failures"][0]["frame"] == "A1_00001b.fits"
    assert load_installation(tmp_path / "a.toml").n_failed == 1


def test_deflection_of_the_vertical_is_used_and_recorded(command, dock):
    """Review finding: the dock's deflection of the vertical was dropped.  xi = 10'' turns
    the installation by 10'' (about the deck's east-west axis) and is written to [dock]."""
    from shipstar.frames import rotation_angle_rad

    proc = _run(command, ["--frames", "dock/A1", "--sensor", "A1", "--camera", "A1", *COMMON, "--xi-arcsec", "10",
                          "--eta-arcsec", "-4.5", "--out", "A1.xi.toml", "--json"], dock)
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert (rep["xi_arcsec"], rep["eta_arcsec"]) == (pytest.approx(10.0), pytest.approx(-4.5))
    text = (dock / "A1.xi.toml").read_text()
    assert "xi_arcsec = 10.0" in text and "eta_arcsec = -4.5" in text
    assert _run(command, ["--frames", "dock/A1", "--sensor", "A1", "--camera", "A1", *COMMON, "--xi-arcsec", "10",
                          "--out", "A1.xi_only.toml"], dock).returncode == 0
    assert _run(command, ["--frames", "dock/A1", "--sensor", "A1", "--camera", "A1", *COMMON,
                          "--out", "A1.plain.toml"], dock).returncode == 0
    with_xi, plain = (load_installation(dock / f"A1.{k}.toml") for k in ("xi_only", "plain"))
    angle = rotation_angle_rad(with_xi.C_deck_from_sensor @ plain.C_deck_from_sensor.T) * 206264.806
    assert angle == pytest.approx(10.0, abs=0.05)


def test_extrapolated_earth_orientation_is_recorded_and_warned_once(command, tmp_path):
    """Review finding: accuracy warnings were multi-line Python warnings, repeated, and
    absent from the installation file.  A dock night past the IERS table's end: each
    warning once, one line, and the EOP quality and the warnings in the TOML and JSON."""
    import warnings

    from shipstar.errors import AccuracyWarning
    from shipstar.simulate._session import dock_session, write_session
    from shipstar.sky.eop import eop_table_info
    from shipstar.sky.time import iso_from_utc_jd

    night = iso_from_utc_jd(2400000.5, eop_table_info().last_mjd + 60.5, 0)[:10] + "T12:16:00"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        write_session(dock_session(duration_s=0.3, start_utc=night), tmp_path / "dock")
    proc = _run(command, ["--frames", "dock/A1", "--sensor", "A1", "--camera", "A1", *COMMON,
                          "--out", "A1.toml", "--json"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()          # EOP extrapolated (+ leap-second table expired)
    assert 1 <= len(lines) <= 2 and len(set(lines)) == len(lines), proc.stderr
    assert all(line.startswith("shipstar calibrate install: warning: ") for line in lines)
    assert any("is extrapolated" in line for line in lines)
    rep = json.loads(proc.stdout)
    inst = load_installation(tmp_path / "A1.toml")
    assert rep["eop"]["quality"] == inst.dock.eop_quality == "extrapolated"
    assert 1e-3 < inst.dock.dut1_error_s < 0.5
    assert sorted(inst.warnings) == sorted(rep["warnings"]) == sorted(x.split("warning: ", 1)[1] for x in lines)


@pytest.mark.parametrize("args, fragment", [
    (["--frames", "dock/A1", "--sensor", "A1", "--camera", "A1", *COMMON, "--xi-arcsec", "inf"], "--xi-arcsec"),
    (["--frames", "dock/A1", "--sensor", "A1", "--camera", "A1", *COMMON[:2], "--lon-deg", "400", *COMMON[4:]],
     "longitude must be within [-180, 360]"),
    (["--frames", "dock/A1", "--sensor", "A1", "--camera", "A1", "--lat-deg", "31.9", "--lon-deg", "120.3",
      "--pressure-hpa", "1021.7", "--temperature-c", "11.1"], "--heading-deg"),
    (["--frames", "dock/A1", "--sensor", "A1", "--camera", "A1", *COMMON[:-1], "nan"], "--temperature-c"),
    (["--frames", "dock/A1", "--sensor", "A1", "--camera", "A1", *COMMON[:-1], "99"], "temperature_c"),
    (["--frames", "dock/A1", "--sensor", "A2", "--camera", "A2", *COMMON], "SENSOR = 'A1'"),
    (["--frames", "dock/nowhere", "--sensor", "A1", "--camera", "A1", *COMMON], "nowhere"),
    (["--frames", "dock/A1", "--sensor", "A1", "--camera", "B7", *COMMON], "B7"),
    (["--frames", "dock", "--sensor", "A1", "--camera", "A1", *COMMON], "no FITS frames"),
])
def test_bad_input(command, dock, args, fragment):
    proc = _run(command, [*args, "--out", "never.toml"], dock)
    _assert_bad_input(proc, fragment)
    assert not (dock / "never.toml").exists()


@pytest.mark.parametrize("out, fragment", [("dock", "--out dock is a directory"),
                                           ("dock/A1/A1_00000.fits/x.toml", "is a file, not a directory")])
def test_bad_output_path_is_refused_before_processing(command, dock, out, fragment):
    proc = _run(command, ["--frames", "dock/A1", "--sensor", "A1", "--camera", "A1", *COMMON, "--out", out], dock)
    _assert_bad_input(proc, fragment)


def test_date_obs_is_mid(command, dock, tmp_path):
    """DATE-OBS alone, written at mid-exposure: refused by default, used with --date-obs-is mid."""
    from astropy.io import fits

    shutil.copytree(dock / "dock" / "A1", tmp_path / "A1")
    for path in sorted((tmp_path / "A1").glob("*.fits")):
        with fits.open(path) as hdul:
            header, data = hdul[0].header.copy(), hdul[0].data.copy()
        header["DATE-OBS"] = header["DATE-AVG"]
        for key in ("DATE-AVG", "DATE-BEG", "DATE-END", "EXPTIME", "EXPOSURE"):
            header.remove(key, ignore_missing=True)
        fits.PrimaryHDU(data, header).writeto(path, overwrite=True)
    args = ["--frames", str(tmp_path / "A1"), "--sensor", "A1", "--camera", "A1", *COMMON]
    _assert_bad_input(_run(command, [*args, "--out", str(tmp_path / "x.toml")], dock), "no EXPTIME")
    proc = _run(command, [*args, "--date-obs-is", "mid", "--out", str(tmp_path / "mid.toml"), "--json"], dock)
    assert proc.returncode == 0, proc.stderr
    assert load_installation(tmp_path / "mid.toml").date_utc.startswith("2013-03-15T12:16:00.000")
