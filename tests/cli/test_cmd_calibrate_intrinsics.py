"""``shipstar calibrate intrinsics`` run as a subprocess (JSON star lists and FITS images)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from shipstar.camera import Distortion, camera_preset, load_camera, save_camera
from shipstar.frames import C_hor_from_deck, C_icrs_from_sensor
from shipstar.sky.apparent import Site, frame_context
from shipstar.sky.refraction import Weather
from shipstar.sky.time import iso_from_utc_jd, utc_jd_from_iso
from shipstar.units import ASEC2RAD, DEG2RAD

LAT_DEG, LON_DEG, HEIGHT_M = 28.2, 112.9, 60.0


def run(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "shipstar", "calibrate", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout)


def assert_one_line_error(res, pattern):
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert "Traceback" not in res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert pattern in lines[0], lines[0]


def camera_error_arcsec(camera, truth) -> float:
    """Largest angle between the two cameras' lines of sight over a 17x13 grid of the
    image, after the best common rotation (Kabsch; numpy only): what an intrinsic
    calibration can be held to (its attitude is free)."""
    g = np.stack(np.meshgrid(np.linspace(0, truth.width_px - 1, 17), np.linspace(0, truth.height_px - 1, 13)),
                 -1).reshape(-1, 2)
    a, b = camera.unproject(g), truth.unproject(g)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return float(np.degrees(np.arccos(np.clip(np.sum((a @ rot.T) * b, axis=1), -1.0, 1.0))).max() * 3600.0)


def write_star_lists(directory, truth, *, n=20, noise_px=0.1, seed=0, camera_name="seed002",
                     with_time=True, with_site=True):
    """JSON star lists (``shipstar solve --json`` form plus time and site) of ground frames."""
    from shipstar.simulate import simulate_stars_horizontal

    site, weather = Site.from_deg(LAT_DEG, LON_DEG, HEIGHT_M), Weather(1008.0, 12.0)
    rng = np.random.default_rng(seed)
    jd1, jd2 = utc_jd_from_iso("2024-03-15T13:00:00")
    directory.mkdir(parents=True, exist_ok=True)
    k = written = 0
    while written < n:
        k += 1
        t2 = jd2 + k * 600.0 / 86400.0
        C = C_hor_from_deck(rng.uniform(0, 2 * np.pi), rng.uniform(45, 85) * DEG2RAD, rng.uniform(-np.pi, np.pi))
        st = simulate_stars_horizontal(truth, C, frame_context(jd1, t2, site), weather, mag_limit=9.0)
        ok = truth.in_image(st.xy_px, margin_px=2.0)
        if ok.sum() < 8:
            continue
        xy = st.xy_px[ok] + rng.normal(0.0, noise_px, (ok.sum(), 2))
        obj = {"solved": True, "reason": "", "stars": [{"x_px": float(x), "y_px": float(y), "hip": int(h)}
                                                       for (x, y), h in zip(xy, st.hip[ok])],
               "camera": camera_name, "lat_deg": LAT_DEG, "lon_deg": LON_DEG, "height_m": HEIGHT_M,
               "pressure_hpa": 1008.0, "temperature_c": 12.0}
        if with_time:
            obj["date_obs"] = iso_from_utc_jd(jd1, t2, 3)
        if not with_site:
            for key in ("lat_deg", "lon_deg", "height_m", "pressure_hpa", "temperature_c"):
                del obj[key]
        (directory / f"frame{written:02d}.json").write_text(json.dumps(obj))
        written += 1
    return directory


@pytest.fixture(scope="module")
def truth():
    return camera_preset("seed002")


@pytest.fixture(scope="module")
def star_lists(tmp_path_factory, truth):
    return write_star_lists(tmp_path_factory.mktemp("lists"), truth)


@pytest.fixture(scope="module")
def nominal(tmp_path_factory, truth):
    """The nominal camera: focal length 2 % off, principal point 30 px off, no distortion."""
    cam = truth.replace(f_mm=truth.f_mm * 1.02, x0_px=truth.x0_px + 30, y0_px=truth.y0_px - 30,
                        distortion=Distortion())
    path = tmp_path_factory.mktemp("cam") / "nominal.toml"
    save_camera(cam, path)
    return path


def test_joint_from_json_star_lists(star_lists, nominal, truth, tmp_path):
    out = tmp_path / "cal.toml"
    res = run("intrinsics", "--frames", star_lists, "--camera", nominal, "--out", out, "--json")
    assert res.returncode == 0, res.stderr
    obj = json.loads(res.stdout)                      # exactly one JSON object
    assert res.stdout.count("\n") == 1
    assert obj["solved"] is True and obj["method"] == "joint" and obj["source"] == "json"
    assert obj["n_frames"] == 20 and obj["n_stars"] > 200 and obj["n_pairs"] > obj["n_stars"]
    assert obj["rms_before_rad"] > 10 * obj["rms_after_rad"]
    assert obj["rms_after_arcsec"] == pytest.approx(obj["rms_after_rad"] / ASEC2RAD)
    assert obj["rms_after_arcsec"] < 1.0                # 0.1 px of 5.6" pixels, two stars
    # default --terms auto: the terms the data support, and only those, are fitted
    assert obj["terms_checked"] is True and obj["unsupported_fitted_terms"] == [] and obj["warnings"] == []
    assert {"k1", "p1", "p2", "s1", "s2"} <= set(obj["supported_distortion_terms"])
    assert [n.split("_")[0] for n in obj["fitted"][3:]] == obj["supported_distortion_terms"]
    for name, true_value in (("f_mm", truth.f_mm), ("x0_px", truth.x0_px), ("y0_px", truth.y0_px)):
        assert abs(obj["parameters"][name] - true_value) < 3 * obj["sigma"][name], name
    cam = load_camera(out)
    # k1 absorbs the undetectable k2 (0.16 px at the corner), so the camera as a whole is
    # the check: within 2x the 0.56'' centroid noise of the truth over the whole image
    assert camera_error_arcsec(cam, truth) < 1.2
    assert cam.f_mm == obj["parameters"]["f_mm"]
    assert cam.distortion.k1_per_mm2 == obj["parameters"]["k1_per_mm2"]
    assert "calibrated by shipstar calibrate intrinsics" in cam.notes
    assert obj["plot"].endswith("cal.residuals.png")
    assert (tmp_path / "cal.residuals.png").stat().st_size > 10_000


def test_sine_text_output(star_lists, nominal, tmp_path):
    out = tmp_path / "sine.toml"
    res = run("intrinsics", "--frames", star_lists, "--camera", nominal, "--method", "sine", "--terms", "all",
              "--no-term-check", "--out", out, "--plot", tmp_path / "p.png")
    assert res.returncode == 0, res.stderr
    assert "method sine" in res.stdout and "interstar rms" in res.stdout
    assert "distortion terms: not checked (--no-term-check)" in res.stdout
    assert f"wrote {out}" in res.stdout
    assert (tmp_path / "p.png").exists() and out.exists()


def test_fits_images_are_extracted_and_identified(tmp_path):
    """FITS frames written by the simulator (sensor A1 with an unknown focal length,
    principal point and radial distortion); the nominal A1 preset as the start."""
    from shipstar.simulate import simulate_frame, write_frame

    truth = camera_preset("A1").replace(f_mm=94.938 * 1.003, x0_px=520.0, y0_px=490.0,
                                        distortion=Distortion(k1_per_mm2=2e-5))
    rng = np.random.default_rng(0)
    frames = tmp_path / "fits"
    for k in range(6):
        C = C_icrs_from_sensor(rng.uniform(0, 2 * np.pi), np.arcsin(rng.uniform(-0.9, 0.9)),
                               rng.uniform(0, 2 * np.pi))
        write_frame(simulate_frame(truth, C_icrs_from_sensor=C, utc_iso="2024-03-15T13:00:00", seed=k),
                    frames / f"f{k:02d}.fits")
    res = run("intrinsics", "--frames", frames, "--camera", "A1", "--terms", "k1", "--no-plot",
              "--out", tmp_path / "a1.toml", "--json")
    assert res.returncode == 0, res.stderr
    obj = json.loads(res.stdout)
    assert obj["source"] == "fits" and obj["n_frames"] == 6 and obj["plot"] is None
    p = obj["parameters"]
    assert p["f_mm"] == pytest.approx(truth.f_mm, rel=5e-5)
    assert p["x0_px"] == pytest.approx(520.0, abs=3.0) and p["y0_px"] == pytest.approx(490.0, abs=3.0)
    assert p["k1_per_mm2"] == pytest.approx(2e-5, rel=0.05)
    assert obj["rms_after_arcsec"] < 0.05 * obj["rms_before_arcsec"]

    # a camera that writes mid-exposure into DATE-OBS (and nothing else): --date-obs-is mid
    from astropy.io import fits

    for path in sorted(frames.glob("*.fits")):
        with fits.open(path) as hdul:
            header, data = hdul[0].header.copy(), hdul[0].data.copy()
        header["DATE-OBS"] = header["DATE-AVG"]
        for key in ("DATE-AVG", "DATE-BEG", "DATE-END", "EXPTIME", "EXPOSURE"):
            header.remove(key, ignore_missing=True)
        fits.PrimaryHDU(data, header).writeto(path, overwrite=True)
    args = ["intrinsics", "--frames", frames, "--camera", "A1", "--terms", "k1", "--no-plot",
            "--out", tmp_path / "mid.toml"]
    assert_one_line_error(run(*args), "no EXPTIME")
    res = run(*args, "--date-obs-is", "mid", "--json")
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["parameters"] == p


def test_star_lists_without_time_need_date_obs(tmp_path, truth, nominal):
    lists = write_star_lists(tmp_path / "notime", truth, n=12, with_time=False)
    res = run("intrinsics", "--frames", lists, "--camera", nominal, "--out", tmp_path / "x.toml")
    assert_one_line_error(res, "--date-obs")
    res = run("intrinsics", "--frames", lists, "--camera", nominal, "--out", tmp_path / "x.toml",
              "--date-obs", "2024-03-15T14:00:00", "--terms", "all", "--no-term-check", "--no-plot", "--json")
    assert res.returncode == 0, res.stderr     # one time for all: runs (with a worse fit)
    assert json.loads(res.stdout)["solved"] is True


def test_bad_input_missing_directory(tmp_path, nominal):
    res = run("intrinsics", "--frames", tmp_path / "nowhere", "--camera", nominal, "--out", tmp_path / "x.toml")
    assert_one_line_error(res, "does not exist")


def test_bad_input_latitude(star_lists, nominal, tmp_path):
    res = run("intrinsics", "--frames", star_lists, "--camera", nominal, "--out", tmp_path / "x.toml",
              "--lat-deg", "95", "--lon-deg", "112.9")
    assert_one_line_error(res, "latitude must be within")
    res = run("intrinsics", "--frames", star_lists, "--camera", nominal, "--out", tmp_path / "x.toml",
              "--lat-deg", "28")
    assert_one_line_error(res, "give both --lat-deg and --lon-deg")


def test_bad_input_frames_from_two_cameras(tmp_path, truth, nominal):
    lists = write_star_lists(tmp_path / "mixed", truth, n=6)
    obj = json.loads((lists / "frame03.json").read_text())
    obj["camera"] = "A2"
    (lists / "frame03.json").write_text(json.dumps(obj))
    res = run("intrinsics", "--frames", lists, "--camera", nominal, "--out", tmp_path / "x.toml")
    assert_one_line_error(res, "frames come from different cameras")
    assert not (tmp_path / "x.toml").exists()


def test_bad_input_too_few_stars(tmp_path, truth, nominal):
    lists = write_star_lists(tmp_path / "few", truth, n=2)
    for path in lists.glob("*.json"):
        obj = json.loads(path.read_text())
        obj["stars"] = obj["stars"][:4]
        path.write_text(json.dumps(obj))
    res = run("intrinsics", "--frames", lists, "--camera", nominal, "--out", tmp_path / "x.toml")
    assert_one_line_error(res, "too few stars")


def test_bad_input_camera_file(star_lists, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nwidth_px = 10\n')
    res = run("intrinsics", "--frames", star_lists, "--camera", bad, "--out", tmp_path / "x.toml")
    assert_one_line_error(res, "missing field")


def test_bad_input_unknown_term(star_lists, nominal, tmp_path):
    res = run("intrinsics", "--frames", star_lists, "--camera", nominal, "--out", tmp_path / "x.toml",
              "--terms", "k1,q7")
    assert_one_line_error(res, "unknown distortion term 'q7'")


def test_group_without_command_prints_help():
    res = run()
    assert res.returncode == 2
    assert "intrinsics" in res.stderr and "install" in res.stderr
    assert "Traceback" not in res.stderr


def test_help_has_an_example():
    res = run("intrinsics", "--help")
    assert res.returncode == 0
    assert "example" in res.stdout and "shipstar calibrate intrinsics --frames" in res.stdout


def test_default_terms_fit_no_noise_on_a_distortion_free_camera(tmp_path):
    """Review finding: --terms all (the old default) fitted all seven Weng terms to noise on
    a distortion-free A1 and moved the principal point by ~30 px (sigma 12 px).  The
    default (auto) fits f and the principal point only, says so, and lands within 3 px;
    an explicit --terms all is warned about on one stderr line and in the JSON."""
    truth = camera_preset("A1").replace(distortion=Distortion())
    lists = write_star_lists(tmp_path / "a1", truth, camera_name="A1")
    res = run("intrinsics", "--frames", lists, "--camera", "A1", "--out", tmp_path / "a1.toml", "--no-plot")
    assert res.returncode == 0, res.stderr
    assert "distortion terms the data support: none supported by the data" in res.stdout
    assert res.stderr == ""
    cam = load_camera(tmp_path / "a1.toml")
    assert cam.distortion.is_zero
    assert abs(cam.x0_px - truth.x0_px) < 3.0 and abs(cam.y0_px - truth.y0_px) < 3.0
    assert camera_error_arcsec(cam, truth) < 1.0                     # 0.1 px = 3'' per star

    res = run("intrinsics", "--frames", lists, "--camera", "A1", "--out", tmp_path / "all.toml", "--no-plot",
              "--terms", "all", "--json")
    assert res.returncode == 0, res.stderr
    obj = json.loads(res.stdout)
    assert obj["supported_distortion_terms"] == [] and len(obj["fitted"]) == 10
    assert obj["unsupported_fitted_terms"] == ["k1", "k2", "k3", "p1", "p2", "s1", "s2"]
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("shipstar calibrate intrinsics: warning: fitted distortion "
                                                   "terms the data do not support: k1, k2, k3, p1, p2, s1, s2")
    assert obj["warnings"] == [lines[0].split("warning: ", 1)[1]]


def test_ground_frames_need_a_site_or_in_space(tmp_path, truth, nominal):
    """Review finding: star lists without a site were calibrated without refraction,
    silently.  Now refused unless --in-space says they were taken above the atmosphere."""
    lists = write_star_lists(tmp_path / "nosite", truth, n=12, with_site=False)
    out = tmp_path / "x.toml"
    res = run("intrinsics", "--frames", lists, "--camera", nominal, "--out", out)
    assert_one_line_error(res, "has no observing site")
    assert "--in-space" in res.stderr and not out.exists()
    res = run("intrinsics", "--frames", lists, "--camera", nominal, "--out", out, "--in-space", "--no-plot",
              "--json")
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["in_space"] is True and out.exists()
    res = run("intrinsics", "--frames", lists, "--camera", nominal, "--out", out, "--in-space",
              "--lat-deg", "28.2", "--lon-deg", "112.9")
    assert_one_line_error(res, "--in-space frames have no site")
    with_site = write_star_lists(tmp_path / "site", truth, n=12)
    res = run("intrinsics", "--frames", with_site, "--camera", nominal, "--out", out, "--in-space")
    assert_one_line_error(res, "has an observing site")


@pytest.mark.parametrize("flag, make, fragment", [
    ("--out", "dir", "is a directory"),
    ("--out", "under-file", "is a file, not a directory"),
    ("--plot", "dir", "is a directory"),
    # was matplotlib's traceback after the camera file had been written
    ("--plot", "plot.xyz", "the plot's format is its extension, one of "),
    ("--plot", "plot", "got none"),
])
def test_bad_output_paths_are_refused_before_any_work(star_lists, nominal, tmp_path, flag, make, fragment):
    target = tmp_path / "target"
    if make == "dir":
        target.mkdir()
    elif make.startswith("plot"):
        target = tmp_path / make
    else:
        (tmp_path / "file").write_text("x")
        target = tmp_path / "file" / "cal.toml"
    paths = {"--out": tmp_path / "ok.toml", "--plot": tmp_path / "ok.png", flag: target}
    res = run("intrinsics", "--frames", star_lists, "--camera", nominal, "--out", paths["--out"],
              "--plot", paths["--plot"], timeout=60)
    assert_one_line_error(res, f"{flag} ")
    assert fragment in res.stderr
    assert not (tmp_path / "ok.toml").exists()


def test_longitude_out_of_range(star_lists, nominal, tmp_path):
    res = run("intrinsics", "--frames", star_lists, "--camera", nominal, "--out", tmp_path / "x.toml",
              "--lat-deg", "28.2", "--lon-deg", "1e308")
    assert_one_line_error(res, "longitude must be within [-180, 360]")
