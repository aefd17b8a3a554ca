"""``shipstar simulate`` run as a subprocess: files, JSON, reproducibility and bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from shipstar.camera import camera_preset, save_camera
from shipstar.frames import C_icrs_from_sensor, matrix_from_q_wxyz
from shipstar.units import DEG2RAD

DOCK = ["--time", "2013-03-15T12:16:00", "--lat-deg", "31.9", "--lon-deg", "120.3",
        "--pressure-hpa", "1021.7", "--temperature-c", "11.1"]


def _run(args, cwd):
    return subprocess.run([sys.executable, "-m", "shipstar", "simulate", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def _assert_bad_input(proc, *fragments):
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert lines[0].startswith("shipstar simulate: error:")
    for text in fragments:
        assert text in lines[0], lines[0]
    assert proc.stdout == ""


def test_icrs_form_writes_fits_and_truth(tmp_path):
    from astropy.io import fits

    proc = _run(["--camera", "A1", "--ra-deg", "83.8", "--dec-deg", "-5.4", "--roll-deg", "20",
                 "--seed", "4", "--out", "orion.fits", "--json"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)                      # exactly one JSON object
    assert out["n_stars"] > 30 and out["seed"] == 4 and out["frame"] == "icrs"
    assert out["ra_deg"] == pytest.approx(83.8) and out["roll_deg"] == pytest.approx(20.0)
    truth = json.loads((tmp_path / "orion.truth.json").read_text())
    assert truth["n_stars"] == out["n_stars"] == len(truth["stars"]["hip"])
    expected = C_icrs_from_sensor(83.8 * DEG2RAD, -5.4 * DEG2RAD, 20 * DEG2RAD)
    np.testing.assert_allclose(matrix_from_q_wxyz(truth["q_wxyz_icrs_from_sensor"]), expected, atol=1e-14)
    with fits.open(tmp_path / "orion.fits") as hdul:
        assert len(hdul) == 1 and hdul[0].data.dtype == np.uint16 and hdul[0].data.shape == (1024, 1024)
        assert hdul[0].header["INSTRUME"] == "A1" and hdul[0].header["EXPTIME"] == pytest.approx(0.08)
        # FITS: DATE-OBS is the start of the exposure, DATE-AVG its middle (the frame's time)
        assert hdul[0].header["DATE-AVG"] == "2000-01-01T11:58:55.816000"
        assert hdul[0].header["DATE-OBS"] == "2000-01-01T11:58:55.776000"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["orion.fits", "orion.truth.json"]


def test_ship_form_with_smear_and_false_objects(tmp_path):
    proc = _run(["--heading-deg", "46.4746", "--install-az-deg", "185", "--install-el-deg", "40", *DOCK,
                 "--deck-rate-deg-per-s", "0.5", "0", "0", "--trails", "1", "--cosmic-rays", "3",
                 "--seed", "9", "--out", "sub/dock.fits"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "wrote" in proc.stdout and "seed 9" in proc.stdout
    truth = json.loads((tmp_path / "sub" / "dock.truth.json").read_text())
    assert truth["frame"] == "hor" and truth["refraction_model"] == "erfa"
    assert truth["sensor_az_deg"] == pytest.approx(231.4746, abs=1e-9)
    assert truth["sensor_el_deg"] == pytest.approx(40.0, abs=1e-9)
    assert truth["weather"] == {"pressure_hpa": 1021.7, "temperature_c": 11.1, "relative_humidity": 0.0,
                                "wavelength_um": 0.55}
    assert len(truth["false_objects"]["trail_xy_px"]) == 1 and truth["false_objects"]["cosmic_ray_count"] == 3
    # a roll rate of 0.5 deg/s about the bow smears every star by several pixels
    smear = np.hypot(*np.array(truth["stars"]["smear_px"]).T)
    assert np.all(smear > 2.0)


def test_same_seed_same_file(tmp_path):
    from astropy.io import fits

    args = ["--ra-deg", "10", "--dec-deg", "41", "--seed", "123"]
    for name in ("a.fits", "b.fits"):
        assert _run([*args, "--out", name], tmp_path).returncode == 0
    assert np.array_equal(fits.getdata(tmp_path / "a.fits"), fits.getdata(tmp_path / "b.fits"))


def test_camera_file_with_a_missing_field(tmp_path):
    path = tmp_path / "cam.toml"
    save_camera(camera_preset("A1"), path)
    text = "\n".join(line for line in path.read_text().splitlines() if not line.startswith("f_mm"))
    path.write_text(text)
    proc = _run(["--camera", str(path), "--ra-deg", "10", "--dec-deg", "41", "--out", "x.fits"], tmp_path)
    _assert_bad_input(proc, "f_mm", "cam.toml")
    assert not (tmp_path / "x.fits").exists()


@pytest.mark.parametrize("args, fragments", [
    (["--ra-deg", "10", "--dec-deg", "41", "--lat-deg", "95", "--lon-deg", "0", "--time", "2020-01-01T00:00:00"],
     ["--lat-deg", "95"]),
    (["--ra-deg", "10", "--dec-deg", "91"], ["declination"]),
    (["--ra-deg", "nan", "--dec-deg", "0"], ["--ra-deg"]),
    (["--ra-deg", "10"], ["--dec-deg"]),
    (["--ra-deg", "10", "--dec-deg", "0", "--heading-deg", "3"], ["not both"]),
    (["--heading-deg", "3", "--install-az-deg", "185", "--install-el-deg", "40"], ["--time"]),
    (["--heading-deg", "3", "--install-az-deg", "185"], ["--install-el-deg"]),
    (["--ra-deg", "10", "--dec-deg", "0", "--pressure-hpa", "1000"], ["need a site"]),
    (["--ra-deg", "10", "--dec-deg", "0", "--time", "2013-02-30T00:00:00"], ["2013-02-30"]),
    (["--ra-deg", "10", "--dec-deg", "0", "--camera", "nosuchcam"], ["nosuchcam"]),
    (["--ra-deg", "10", "--dec-deg", "0", "--mag-limit", "30"], ["mag_limit"]),
    (["--ra-deg", "10", "--dec-deg", "0", "--planets", "-2"], ["--planets"]),
])
def test_bad_input_is_one_line_exit_2(tmp_path, args, fragments):
    proc = _run([*args, "--out", "x.fits"], tmp_path)
    _assert_bad_input(proc, *fragments)
    assert not (tmp_path / "x.fits").exists()


def test_out_must_be_a_fits_name(tmp_path):
    _assert_bad_input(_run(["--ra-deg", "1", "--dec-deg", "2", "--out", "x.png"], tmp_path), "--out")


def test_help_has_an_example():
    proc = subprocess.run([sys.executable, "-m", "shipstar", "simulate", "--help"], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0
    assert "shipstar simulate --camera A1 --ra-deg" in proc.stdout and "--heading-deg" in proc.stdout
