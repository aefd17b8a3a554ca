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
        hdu.header["DATE-OBS"] = f"2013-03-15T12:16:00.{k}00"
        hdu.writeto(path / f"n{k}.fits")


def test_frames_that_do_not_identify(command, dock, tmp_path):
    _noise_dir(tmp_path / "noise")
    out = tmp_path / "x.toml"
    proc = _run(command, ["--frames", str(tmp_path / "noise"), "--sensor", "A1", "--camera", "A1", *COMMON,
                          "--out", str(out)], dock)
    _assert_bad_input(proc, "sensor A1: 0 of 3 frames solved", "not identified")
    assert not out.exists()


def test_some_failed_frames_give_exit_1(command, dock, tmp_path):
    from astropy.io import fits

    shutil.copytree(dock / "dock" / "A1", tmp_path / "A1")
    hdu = fits.PrimaryHDU(np.full((1024, 1024), 100, np.uint16))
    hdu.header["DATE-OBS"] = "2013-03-15T12:16:00.150"
    hdu.writeto(tmp_path / "A1" / "A1_00001b.fits")
    proc = _run(command, ["--frames", str(tmp_path / "A1"), "--sensor", "A1", "--camera", "A1", *COMMON,
                          "--out", str(tmp_path / "a.toml"), "--json"], dock)
    assert proc.returncode == 1, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["n_failed"] == 1 and rep["failures"][0]["frame"] == "A1_00001b.fits"
    assert load_installation(tmp_path / "a.toml").n_failed == 1


@pytest.mark.parametrize("args, fragment", [
    (["--frames", "dock/A1", "--sensor", "A1", "--camera", "A1", "--lat-deg", "31.9", "--lon-deg", "120.3",
      "--pressure-hpa", "1021.7", "--temperature-c", "11.1"], "--heading-deg"),
    (["--frames", "dock/A1", "--sensor", "A1", "--camera", "A1", *COMMON[:-1], "nan"], "--temperature-c"),
    (["--frames", "dock/A1", "--sensor", "A1", "--camera", "A1", *COMMON[:-1], "99"], "temperature_c"),
    (["--frames", "dock/A1", "--sensor", "A2", "--camera", "A2", *COMMON], "from sensor 'A1'"),
    (["--frames", "dock/nowhere", "--sensor", "A1", "--camera", "A1", *COMMON], "nowhere"),
    (["--frames", "dock/A1", "--sensor", "A1", "--camera", "B7", *COMMON], "B7"),
    (["--frames", "dock", "--sensor", "A1", "--camera", "A1", *COMMON], "no FITS frames"),
])
def test_bad_input(command, dock, args, fragment):
    proc = _run(command, [*args, "--out", "never.toml"], dock)
    _assert_bad_input(proc, fragment)
    assert not (dock / "never.toml").exists()
