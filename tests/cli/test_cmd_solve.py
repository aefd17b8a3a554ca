"""``shipstar solve`` run as a subprocess (what a user types).

References: the true attitude of a frame rendered by ``shipstar.simulate`` (written as
FITS), and for a real photo the solution of tetra3rs / cedar-solve stored in
``tests/identify/data/real_images_reference.json`` (made by
``benchmarks/bench_real_images.py --write-reference``).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from shipstar.camera import camera_preset
from shipstar.frames import C_icrs_from_sensor, unit_from_ra_dec

# shared/ stands beside the repository (CI: a fresh clone with shared/ beside it)
REAL = next((d for d in (Path(__file__).resolve().parents[3] / "shared" / "real-images",
                          Path("/work/shared/real-images")) if d.is_dir()),
            Path(__file__).resolve().parents[3] / "shared" / "real-images")
REFERENCE = Path(__file__).parent.parent / "identify" / "data" / "real_images_reference.json"


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    e = dict(os.environ)
    e.setdefault("SHIPSTAR_CACHE_DIR", str(tmp_path_factory.mktemp("shipstar_cache")))
    return e


def _run(env, *args):
    return subprocess.run([sys.executable, "-m", "shipstar", "solve", *args], env=env,
                          capture_output=True, text=True, timeout=300)


def _sep_arcsec(ra1, dec1, ra2, dec2):
    a = unit_from_ra_dec(math.radians(ra1), math.radians(dec1))
    b = unit_from_ra_dec(math.radians(ra2), math.radians(dec2))
    return math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), a @ b)) * 3600


JSON_KEYS = {"solved", "reason", "ra_deg", "dec_deg", "roll_deg", "fov_deg", "matched",
             "rms_arcsec", "time_ms", "date_obs", "camera", "width_px", "height_px", "stars"}


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """``(fits path, SimulatedFrame)``: a seed004 frame of Orion written as FITS."""
    from shipstar.simulate import simulate_frame, write_frame

    C = C_icrs_from_sensor(math.radians(83.8), math.radians(-5.4), math.radians(30.0))
    frame = simulate_frame(camera_preset("seed004"), C_icrs_from_sensor=C, seed=7)
    path = tmp_path_factory.mktemp("frames") / "orion.fits"
    write_frame(frame, path)
    return path, frame


@pytest.fixture(scope="module")
def fits_frame(simulated):
    return simulated[0]


@pytest.fixture(scope="module")
def solved_json(env, fits_frame):
    proc = _run(env, str(fits_frame), "--camera", "seed004", "--json")
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_json_solution_of_a_simulated_fits_frame(solved_json):
    out = solved_json
    assert set(out) == JSON_KEYS
    assert out["solved"] is True and out["reason"] == "" and out["matched"] >= 8
    assert _sep_arcsec(out["ra_deg"], out["dec_deg"], 83.8, -5.4) < 10.0
    assert abs((out["roll_deg"] - 30.0 + 180) % 360 - 180) * 3600 < 120.0
    assert out["fov_deg"] == pytest.approx(camera_preset("seed004").fov_deg, rel=1e-9)
    hips = [s["hip"] for s in out["stars"]]
    assert sum(h > 0 for h in hips) == out["matched"]
    assert all({"x_px", "y_px", "hip"} == set(s) for s in out["stars"])


def test_json_carries_time_camera_and_image_size(solved_json, simulated):
    from astropy.time import Time

    _, frame = simulated
    out = solved_json
    assert out["camera"] == "seed004" and (out["width_px"], out["height_px"]) == (512, 512)
    # the header's DATE-AVG (mid-exposure); reference: astropy's reading of the frame's JD
    truth = Time(frame.utc_jd1, frame.utc_jd2, format="jd", scale="utc")
    got = Time(out["date_obs"].rstrip("Z"), format="isot", scale="utc")
    assert abs((got - truth).to_value("s")) < 1e-6
    # the matched stars sit on the rendered stars (the simulator's truth)
    true_xy = np.asarray(frame.stars.xy_px)
    for star in out["stars"]:
        if star["hip"] > 0:
            d = np.hypot(*(true_xy - [star["x_px"], star["y_px"]]).T)
            assert frame.stars.hip[np.argmin(d)] == star["hip"] and d.min() < 0.5


def test_json_output_is_a_frame_for_intrinsic_calibration(solved_json, tmp_path):
    from shipstar.calibrate.intrinsics import load_calibration_frames

    (tmp_path / "orion.json").write_text(json.dumps(solved_json))
    loaded = load_calibration_frames(tmp_path, camera_preset("seed004"))
    (fr,) = loaded.frames
    matched = [s for s in solved_json["stars"] if s["hip"] >= 0]
    np.testing.assert_array_equal(fr.hip, [s["hip"] for s in matched])
    np.testing.assert_array_equal(fr.xy_px, [[s["x_px"], s["y_px"]] for s in matched])
    assert fr.camera_name == "seed004" and fr.image_shape_hw == (512, 512)


def test_human_summary(env, fits_frame):
    proc = _run(env, str(fits_frame), "--camera", "seed004")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("solved: RA ") and "matched" in proc.stdout


def test_real_photo_with_fov_only_matches_the_anchor(env):
    ref = json.loads(REFERENCE.read_text())["orion_belt"]
    proc = _run(env, str(REAL / "orion_belt.jpg"), "--fov-deg", "10", "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["solved"]
    assert _sep_arcsec(out["ra_deg"], out["dec_deg"], ref["ra_deg"], ref["dec_deg"]) < 60
    assert abs((out["roll_deg"] - ref["roll_deg"] + 180) % 360 - 180) < 0.1
    assert out["fov_deg"] == pytest.approx(ref["fov_deg"], rel=0.01)


def _assert_one_line_error(proc):
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "error" in lines[0]


@pytest.mark.parametrize("args", [
    ["/no/such/image.png", "--fov-deg", "10"],
    ["IMAGE", "--fov-deg", "-3"],
    ["IMAGE", "--fov-deg", "nan"],
    ["IMAGE"],                                        # neither --camera nor --fov-deg
    ["IMAGE", "--fov-deg", "10", "--camera", "A1"],   # both
    ["IMAGE", "--camera", "A1"],                      # 512 x 512 image, 1024 x 1024 camera
    ["IMAGE", "--camera", "no_such_camera.toml"],
    ["IMAGE", "--fov-deg", "10", "--max-stars", "2"],
    ["IMAGE", "--camera", "seed004", "--date-obs-is", "end"],
])
def test_bad_input_exits_2_with_one_line(env, fits_frame, args):
    args = [str(fits_frame) if a == "IMAGE" else a for a in args]
    _assert_one_line_error(_run(env, *args))


def test_not_an_image_exits_2(env, tmp_path):
    bad = tmp_path / "notes.png"
    bad.write_text("this is not a picture")
    _assert_one_line_error(_run(env, str(bad), "--fov-deg", "10"))


def test_image_without_stars_is_not_solved(env, tmp_path):
    rng = np.random.default_rng(1)
    path = tmp_path / "dark.npy"
    np.save(path, (100 + rng.normal(0, 3, size=(256, 256))).astype(np.uint16))
    proc = _run(env, str(path), "--fov-deg", "10", "--json")
    assert proc.returncode == 1, proc.stderr
    out = json.loads(proc.stdout)
    assert set(out) == JSON_KEYS                      # the same keys as when solved
    assert out["solved"] is False and out["reason"] and out["ra_deg"] is None
    assert out["date_obs"] is None and out["camera"] is None            # .npy, --fov-deg
    assert (out["width_px"], out["height_px"]) == (256, 256)
    proc = _run(env, str(path), "--fov-deg", "10")
    assert proc.returncode == 1 and proc.stdout.startswith("not solved: ")


def test_far_wrong_fov_is_not_solved(env, fits_frame):
    proc = _run(env, str(fits_frame), "--fov-deg", "17", "--json")
    assert proc.returncode == 1, proc.stderr
    assert json.loads(proc.stdout)["solved"] is False
