"""``shipstar extract`` run as a subprocess: JSON, the table, exit codes and bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from shipstar.camera import camera_preset
from shipstar.simulate._render import render_frame, star_signal_e

A1 = camera_preset("A1")
TRUTH = np.array([[200.3, 300.7], [640.5, 120.2], [812.9, 901.4], [455.0, 610.6], [90.1, 760.8]])
MAGS = np.array([4.0, 5.0, 5.5, 6.0, 6.5])


def _run(args, cwd):
    return subprocess.run([sys.executable, "-m", "shipstar", "extract", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def _assert_bad_input(proc, *fragments):
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert lines[0].startswith("shipstar extract: error:")
    for text in fragments:
        assert text in lines[0], lines[0]
    assert proc.stdout == ""


@pytest.fixture(scope="module")
def frame_fits(tmp_path_factory):
    from astropy.io import fits

    image = render_frame(A1, TRUTH, star_signal_e(A1, MAGS), np.random.default_rng(21), hot_pixel_fraction=0.0)
    path = tmp_path_factory.mktemp("extract") / "frame.fits"
    fits.PrimaryHDU(image).writeto(path)
    return path


def test_json_lists_the_stars_brightest_first(frame_fits):
    proc = _run([str(frame_fits), "--json"], frame_fits.parent)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)                               # exactly one JSON object
    assert out["image"] == {"path": str(frame_fits), "width_px": 1024, "height_px": 1024}
    assert out["background_adu"] == pytest.approx(A1.bias_adu + 1.0, abs=1.0)
    assert out["noise_adu"] > 0 and out["psf_sigma_px"] == pytest.approx(A1.psf_sigma_px, rel=0.1)
    stars = out["stars"]
    assert len(stars) == len(TRUTH)
    assert set(stars[0]) == {"x_px", "y_px", "flux_adu", "peak_adu", "snr", "npix", "xy_sigma_px", "flags"}
    xy = np.array([[s["x_px"], s["y_px"]] for s in stars])
    np.testing.assert_allclose(xy, TRUTH[np.argsort(MAGS)], atol=0.1)   # brightest = smallest magnitude first
    assert all(s["flags"] == [] for s in stars)
    assert [s["flux_adu"] for s in stars] == sorted((s["flux_adu"] for s in stars), reverse=True)


def test_table_options_and_camera(frame_fits):
    proc = _run([str(frame_fits), "--max-stars", "2", "--camera", "A1", "--refine", "none",
                 "--threshold-sigma", "6"], frame_fits.parent)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert "2 stars" in lines[0] and "PSF sigma 0.80 px" in lines[0]
    assert lines[1].split()[:3] == ["#", "x_px", "y_px"]
    first = lines[2].split()
    assert float(first[1]) == pytest.approx(TRUTH[0, 0], abs=0.3)
    assert float(first[2]) == pytest.approx(TRUTH[0, 1], abs=0.3)
    assert len(lines) == 4


def test_saturated_star_flag_in_json(tmp_path):
    image = render_frame(A1, [[500.0, 500.0]], [5e7], np.random.default_rng(2), hot_pixel_fraction=0.0)
    np.save(tmp_path / "sat.npy", image)
    proc = _run(["sat.npy", "--json"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    star = json.loads(proc.stdout)["stars"][0]
    assert star["flags"] == ["saturated"] and star["xy_sigma_px"] is None
    assert star["peak_adu"] == 4095.0


def test_empty_frame_exits_1_with_a_message(tmp_path):
    image = render_frame(A1, np.zeros((0, 2)), [], np.random.default_rng(3), hot_pixel_fraction=0.0)
    np.save(tmp_path / "empty.npy", image)
    proc = _run(["empty.npy", "--json"], tmp_path)
    assert proc.returncode == 1
    assert json.loads(proc.stdout)["stars"] == []
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()] and "no stars found" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_bad_input_exits_2_with_one_line(tmp_path):
    (tmp_path / "notes.txt").write_text("hello\n")
    (tmp_path / "bad.fits").write_bytes(b"SIMPLE  =                    T" + b" " * 50 + b"garbage")
    np.save(tmp_path / "saturated.npy", np.full((64, 64), 4095, dtype=np.uint16))
    _assert_bad_input(_run(["notes.txt"], tmp_path), "not an image file")
    _assert_bad_input(_run(["bad.fits", "--json"], tmp_path), "FITS")
    _assert_bad_input(_run(["missing.png"], tmp_path), "no such file")
    _assert_bad_input(_run(["saturated.npy"], tmp_path), "overexposed")
    _assert_bad_input(_run(["notes.txt", "--camera", "no-such-camera"], tmp_path))
    proc = _run(["saturated.npy", "--threshold-sigma", "nan"], tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and "finite" in proc.stderr
    proc = _run(["saturated.npy", "--max-stars", "0"], tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    _assert_bad_input(_run(["saturated.npy", "--threshold-sigma", "0.5"], tmp_path), "threshold_sigma")


def test_an_image_over_pillows_size_limit_exits_2_with_one_line(tmp_path):
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", 20000, 20000, 8, 0, 0, 0, 0)                  # 8-bit grey, no pixels
    (tmp_path / "big.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b""))
    _assert_bad_input(_run(["big.png"], tmp_path),
                      "big.png is too large: 400000000 pixels, over the limit of 178956970")


def test_smeared_frame_with_a_smear_hint(tmp_path):
    """Streaks (the ship turning during the exposure) are centred at mid-exposure."""
    from astropy.io import fits

    smear = np.tile([16.0, -5.0], (len(TRUTH), 1))
    image = render_frame(A1, TRUTH, star_signal_e(A1, MAGS), np.random.default_rng(5),
                         smear_px=smear, hot_pixel_fraction=0.0)
    path = tmp_path / "streaks.fits"
    fits.PrimaryHDU(image).writeto(path)
    proc = _run([str(path), "--json", "--camera", "A1", "--smear-px", "16", "-5"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert np.allclose(np.abs(out["smear_px"]), [16.0, 5.0], atol=0.5)
    stars = out["stars"][:len(TRUTH)]        # brightest first; faint noise detections may follow
    xy = np.array([[s["x_px"], s["y_px"]] for s in stars])
    sigma = np.array([s["xy_sigma_px"] for s in stars])
    nearest = np.linalg.norm(xy[:, None, :] - TRUTH[None, :, :], axis=2)
    d = nearest.min(axis=1)
    assert len(set(nearest.argmin(axis=1))) == len(TRUTH)      # one extracted star per true star
    assert np.all(d < 5.0 * sigma) and np.all(sigma < 0.2), (d, sigma)


def test_bad_smear_hint_is_one_line(tmp_path, frame_fits):
    _assert_bad_input(_run([str(frame_fits), "--smear-px", "1", "nan"], tmp_path), "--smear-px")
