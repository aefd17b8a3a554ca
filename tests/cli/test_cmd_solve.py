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
             "rms_arcsec", "time_ms", "date_obs", "camera", "width_px", "height_px", "stars",
             "p_false", "q_icrs_from_sensor_wxyz", "fov_search"}


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
    [],                                               # no input
    ["--centroids", "IMAGE"],                         # without --image-size-px
    ["IMAGE", "--image-size-px", "512x512"],             # --image-size-px without --centroids
    ["--centroids", "IMAGE", "--image-size-px", "512by512"],
    ["--centroids", "IMAGE", "--image-size-px", "512x512", "--fov-deg", "12"],   # FITS is not text
    ["IMAGE", "IMAGE", "--wcs-header", "/tmp/x.hdr", "--camera", "seed004"],
    ["IMAGE", "--camera", "seed004", "--wcs-out", "IMAGE"],                   # overwrite input
    ["IMAGE", "--camera", "seed004", "--prior-error-deg", "40"],
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


def test_blind_solve_of_a_real_photo(env):
    ref = json.loads(REFERENCE.read_text())["orion_belt"]
    proc = _run(env, str(REAL / "orion_belt.jpg"), "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert set(out) == JSON_KEYS and out["fov_search"] == "blind"
    assert _sep_arcsec(out["ra_deg"], out["dec_deg"], ref["ra_deg"], ref["dec_deg"]) < 60
    assert out["fov_deg"] == pytest.approx(ref["fov_deg"], rel=0.01)
    assert out["p_false"] < 1e-6


def test_json_quaternion_is_the_true_attitude(solved_json, simulated):
    from shipstar.frames import matrix_from_q_wxyz, rotation_angle_rad

    _, frame = simulated
    q = np.asarray(solved_json["q_icrs_from_sensor_wxyz"])
    assert q[0] >= 0 and np.linalg.norm(q) == pytest.approx(1.0, abs=1e-12)
    err = rotation_angle_rad(matrix_from_q_wxyz(q).T @ frame.C_icrs_from_sensor)
    assert math.degrees(err) * 3600 < 120.0                       # roll dominates
    assert 0.0 < solved_json["p_false"] < 1e-6


def _matched_sky_errors_arcsec(header, stars):
    """astropy.wcs pixel -> sky of the matched stars against their Hipparcos places."""
    from astropy.wcs import WCS

    from shipstar.sky.catalog import load_hipparcos

    cat = load_hipparcos()
    row = {int(h): i for i, h in enumerate(np.asarray(cat.hip))}
    matched = [s for s in stars if s["hip"] > 0]
    radec = WCS(header).all_pix2world([[s["x_px"], s["y_px"]] for s in matched], 0)
    got = unit_from_ra_dec(np.radians(radec[:, 0]), np.radians(radec[:, 1]))
    idx = [row[s["hip"]] for s in matched]
    ref = unit_from_ra_dec(np.asarray(cat.ra_rad)[idx], np.asarray(cat.dec_rad)[idx])
    return np.degrees(np.arccos(np.clip(np.sum(got * ref, axis=1), -1, 1))) * 3600


def test_wcs_out_copy_and_header_sidecar(env, fits_frame, tmp_path):
    from astropy.io import fits

    out_fits, out_hdr = tmp_path / "wcs.fits", tmp_path / "frame.hdr"
    proc = _run(env, str(fits_frame), "--camera", "seed004", "--json", "--wcs-out", str(out_fits),
                "--wcs-header", str(out_hdr))
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout)
    assert res["wcs_file"] == str(out_fits) and res["wcs_header_file"] == str(out_hdr)
    with fits.open(out_fits) as hdul:
        header = hdul[0].header
        with fits.open(fits_frame) as orig:
            np.testing.assert_array_equal(hdul[0].data, orig[0].data)    # the same pixels
            assert header["DATE-AVG"] == orig[0].header["DATE-AVG"]       # and header cards
    # seed004 has no distortion: a plain TAN projection; the catalog (J2000 places) and the
    # frame (rendered at its epoch) differ by proper motion: a few arcsec at most
    assert header["CTYPE1"] == "RA---TAN"
    err = _matched_sky_errors_arcsec(header, res["stars"])
    assert len(err) == res["matched"] and np.median(err) < 3.0 and err.max() < 20.0
    side = fits.Header.fromtextfile(out_hdr)
    assert (side["IMAGEW"], side["IMAGEH"]) == (512, 512)
    assert side["CRVAL1"] == pytest.approx(header["CRVAL1"]) and side["CD1_2"] == header["CD1_2"]


def test_wcs_header_of_a_real_photo_has_sip(env, tmp_path):
    from astropy.io import fits

    out_hdr = tmp_path / "virgo.hdr"
    proc = _run(env, str(REAL / "orion_belt.jpg"), "--fov-deg", "10", "--json", "--wcs-header", str(out_hdr))
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout)
    header = fits.Header.fromtextfile(out_hdr)
    assert header["CTYPE1"] == "RA---TAN-SIP" and header["A_ORDER"] == 3
    err = _matched_sky_errors_arcsec(header, res["stars"])
    assert np.sqrt(np.mean(err ** 2)) < 2.0 * res["rms_arcsec"] + 5.0


def _centroid_file(path, frame, n=40, flux=False):
    """The frame's rendered stars (truth), brightest first, as a centroid list."""
    order = np.argsort(np.asarray(frame.stars.mag))[:n]
    xy = np.asarray(frame.stars.xy_px)[order]
    lines = ["# x_px,y_px" + (",flux" if flux else ""), "x_px,y_px" + (",flux" if flux else "")]
    for k, (x, y) in enumerate(xy):
        lines.append(f"{x:.3f},{y:.3f}" + (f",{1000.0 / (k + 1):.3f}" if flux else ""))
    if flux:                                     # order in the file does not matter
        lines = lines[:2] + lines[2:][::-1]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("flux", [False, True])
def test_centroid_list(env, simulated, tmp_path, flux):
    _, frame = simulated
    path = _centroid_file(tmp_path / "stars.csv", frame, flux=flux)
    proc = _run(env, "--centroids", str(path), "--image-size-px", "512x512", "--fov-deg", "12", "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["solved"] and out["fov_search"] == "hint" and out["matched"] >= 20
    assert _sep_arcsec(out["ra_deg"], out["dec_deg"], 83.8, -5.4) < 10.0
    assert (out["width_px"], out["height_px"]) == (512, 512)


def test_centroid_columns_follow_the_header_and_stay_inside_the_image(tmp_path):
    """A header's names choose the columns (read by position, ``y_px,x_px`` swapped the
    axes and ``flux,x_px,y_px`` took the fluxes for x, without a word); a name that is not
    a column, centroids outside the image, a UTF-8 byte-order mark: as below."""
    from shipstar.cli._cmd_solve import _check_inside, read_centroids
    from shipstar.errors import ShipstarError

    rows = [(10.5, 20.25, 300.0), (40.0, 5.0, 100.0)]
    for header, order in [("x_px,y_px,flux", (0, 1, 2)), ("y_px,x_px,flux", (1, 0, 2)),
                          ("flux;X_PX;y_px", (2, 0, 1)), ("x y", (0, 1)), ("\ufeffy,x", (1, 0))]:
        path = tmp_path / "c.csv"
        path.write_text(header + "\n" + "".join(",".join(f"{r[k]:g}" for k in order) + "\n" for r in rows),
                        encoding="utf-8")
        xy, flux = read_centroids(path)
        np.testing.assert_array_equal(xy, [[10.5, 20.25], [40.0, 5.0]])
        assert (flux is None) == (len(order) == 2) and (flux is None or list(flux) == [300.0, 100.0])
    for header in ("x_px,y_px,mag", "x_px,x_px", "ra,dec"):
        path.write_text(header + "\n1,2" + ",3" * (header.count(",") - 1) + "\n")
        with pytest.raises(ShipstarError, match="line 1: the header names .*expected x_px, y_px and optionally flux"):
            read_centroids(path)
    path.write_text("x_px,y_px\n1,2,3\n")
    with pytest.raises(ShipstarError, match="line 2: expected 2 columns"):
        read_centroids(path)
    _check_inside(path, np.array([[-0.5, -0.5], [511.5, 255.5]]), (256, 512))      # the corners: inside
    for xy in ([[512.0, 10.0]], [[10.0, 256.0]], [[-0.6, 3.0]]):
        with pytest.raises(ShipstarError, match="1 centroid.* outside the 512x256 image"):
            _check_inside(path, np.array(xy), (256, 512))


def test_centroid_list_bad_line_is_one_line_error(env, tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("10,20\n30,forty\n")
    proc = _run(env, "--centroids", str(path), "--image-size-px", "512x512")
    _assert_one_line_error(proc)
    assert "line 2" in proc.stderr


def test_track_a_sequence(env, tmp_path):
    """Three frames of a slowly turning camera: the first lost-in-space, then tracking."""
    from shipstar.simulate import simulate_frame, write_frame

    cam = camera_preset("seed004")
    paths, truth = [], []
    for k in range(3):
        C = C_icrs_from_sensor(math.radians(60.0 + 0.2 * k), math.radians(30.0), math.radians(5.0 * k / 10))
        frame = simulate_frame(cam, C_icrs_from_sensor=C, seed=20 + k)
        paths.append(tmp_path / f"f{k}.fits")
        write_frame(frame, paths[-1])
        truth.append(C)
    proc = _run(env, "--track", *map(str, paths), "--camera", "seed004", "--json")
    assert proc.returncode == 0, proc.stderr
    rows = [json.loads(line) for line in proc.stdout.splitlines()]
    assert [r["input"] for r in rows] == [str(p) for p in paths]
    assert [r["fov_search"] for r in rows] == ["camera", "tracking", "tracking"]
    for r, C in zip(rows, truth):
        assert r["solved"] and _sep_arcsec(r["ra_deg"], r["dec_deg"], *np.degrees(
            [math.atan2(C[1, 0], C[0, 0]) % (2 * math.pi), math.asin(C[2, 0])])) < 10.0
