"""solve_image: extraction + identification + attitude on images.

References: the true attitude of frames rendered by ``shipstar.simulate``, and for the
real photos of /work/shared/real-images the solutions of tetra3rs / cedar-solve stored
in ``data/real_images_reference.json`` by ``benchmarks/bench_real_images.py``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from shipstar.errors import ShipstarError
from shipstar.frames import rotation_angle_rad, unit_from_ra_dec
from shipstar.identify import solve_image
from shipstar.identify._sim import random_attitudes

# shared/ stands beside the repository (CI: a fresh clone with shared/ beside it)
REAL = next((d for d in (Path(__file__).resolve().parents[3] / "shared" / "real-images",
                          Path("/work/shared/real-images")) if d.is_dir()),
            Path(__file__).resolve().parents[3] / "shared" / "real-images")
REFERENCE = json.loads((Path(__file__).parent / "data" / "real_images_reference.json").read_text())


@pytest.mark.parametrize("camera_name", ["seed004", "A1"])
def test_rendered_frames_give_the_true_attitude(camera_name):
    from shipstar.camera import camera_preset
    from shipstar.simulate import simulate_frame

    cam = camera_preset(camera_name)
    rng = np.random.default_rng(41)
    for k, C in enumerate(random_attitudes(4, rng)):
        frame = simulate_frame(cam, C_icrs_from_sensor=C, seed=k)
        res = solve_image(frame.image, camera=cam)
        assert res.solved, res.reason
        bore = math.acos(min(1.0, res.C_icrs_from_sensor[:, 0] @ C[:, 0]))
        assert bore < 0.3 * cam.pixel_mm / cam.f_mm                 # well under a pixel
        assert rotation_angle_rad(res.C_icrs_from_sensor.T @ C) < 3 * cam.pixel_mm / cam.f_mm
        truth = dict(zip(map(tuple, np.round(frame.stars.xy_px, 0)), frame.stars.hip))
        for xy, hip in zip(res.xy_px, res.hip):
            if hip > 0 and tuple(np.round(xy, 0)) in truth:
                assert truth[tuple(np.round(xy, 0))] == hip
        assert res.fov_deg == pytest.approx(cam.fov_deg)


def test_fov_only_recovers_the_field_of_view():
    from shipstar.camera import camera_preset
    from shipstar.simulate import simulate_frame

    cam = camera_preset("seed004")
    rng = np.random.default_rng(42)
    (C,) = random_attitudes(1, rng)
    frame = simulate_frame(cam, C_icrs_from_sensor=C, seed=3)
    res = solve_image(frame.image, fov_deg=cam.fov_deg * 1.07)
    assert res.solved, res.reason
    assert res.fov_deg == pytest.approx(cam.fov_deg, rel=2e-3)
    assert math.acos(min(1.0, res.C_icrs_from_sensor[:, 0] @ C[:, 0])) < cam.pixel_mm / cam.f_mm


def _sep_deg(a_ra, a_dec, b_ra, b_dec):
    a = unit_from_ra_dec(math.radians(a_ra), math.radians(a_dec))
    b = unit_from_ra_dec(math.radians(b_ra), math.radians(b_dec))
    return math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), a @ b))


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(REFERENCE))
def test_real_photos_agree_with_the_anchors(name):
    ref = REFERENCE[name]
    res = solve_image(REAL / f"{name}.jpg", fov_deg=ref["fov_deg_nominal"])
    assert res.solved, res.reason
    assert _sep_deg(res.ra_deg, res.dec_deg, ref["ra_deg"], ref["dec_deg"]) * 3600 < 60
    assert abs((res.roll_deg - ref["roll_deg"] + 180) % 360 - 180) < 0.15
    assert res.fov_deg == pytest.approx(ref["fov_deg"], rel=0.02)
    assert res.matched >= 10 and res.identification.p_false < 1e-6


def test_flat_image_is_not_solved():
    rng = np.random.default_rng(43)
    img = (200 + rng.normal(0, 4, size=(300, 400))).astype(np.uint16)
    res = solve_image(img, fov_deg=10.0)
    assert not res.solved and res.reason
    assert np.all(np.isnan(res.C_icrs_from_sensor)) and math.isnan(res.ra_deg)
    d = res.as_json_dict()
    assert d["solved"] is False and d["ra_deg"] is None and d["reason"] == res.reason


@pytest.mark.parametrize("kw, words", [
    ({}, "exactly one"),
    ({"fov_deg": 10.0, "camera": "A1"}, "exactly one"),
    ({"fov_deg": 0.1}, "fov_deg"),
    ({"camera": "A1"}, "camera"),
])
def test_bad_arguments_raise(kw, words):
    with pytest.raises(ShipstarError, match=words):
        solve_image(np.zeros((50, 60), np.uint16), **kw)


def test_image_must_be_2d():
    with pytest.raises(ShipstarError, match="2-D"):
        solve_image(np.zeros((5, 5, 3)), fov_deg=10.0)


# -- the frame time of FITS images (what `shipstar solve --json` passes on to calibration) --

EXPTIME_S = 2.0


@pytest.fixture(scope="module")
def rendered(cam12):
    """A seed004 frame and its mid-exposure UTC as an astropy Time (the reference)."""
    from astropy.time import Time

    from shipstar.simulate import simulate_frame

    (C,) = random_attitudes(1, np.random.default_rng(44))
    frame = simulate_frame(cam12, C_icrs_from_sensor=C, seed=5)
    return frame, Time(frame.utc_jd1, frame.utc_jd2, format="jd", scale="utc")


def _fits_with(path, image, **cards):
    """A FITS file with only the given header cards (written by astropy, not shipstar)."""
    from astropy.io import fits

    hdu = fits.PrimaryHDU(np.asarray(image, dtype=np.uint16))
    for key, value in cards.items():
        hdu.header[key.replace("_", "-")] = value
    hdu.writeto(path)
    return path


def _utc_seconds_between(iso_a, time_b):
    from astropy.time import Time

    return (Time(iso_a.rstrip("Z"), format="isot", scale="utc") - time_b).to_value("s")


def test_fits_date_obs_is_mid_exposure(rendered, db12, cam12, tmp_path):
    from astropy.time import TimeDelta

    frame, mid = rendered
    start = (mid - TimeDelta(EXPTIME_S / 2, format="sec")).isot
    path = _fits_with(tmp_path / "start.fits", frame.image, DATE_OBS=start, EXPTIME=EXPTIME_S)
    res = solve_image(path, camera=cam12, database=db12)
    assert res.solved and res.camera_name == "seed004" and res.time_problem == ""
    assert abs(_utc_seconds_between(res.date_obs, mid)) < 1e-6      # DATE-OBS + EXPTIME / 2
    # a camera that writes mid-exposure into DATE-OBS
    res = solve_image(path, camera=cam12, database=db12, date_obs_is="mid")
    assert abs(_utc_seconds_between(res.date_obs, mid) + EXPTIME_S / 2) < 1e-6
    assert res.as_json_dict()["date_obs"] == res.date_obs


@pytest.mark.parametrize("cards, words", [
    ({"DATE_OBS": "2024-03-15T20:16:00"}, "EXPTIME"),             # a start, no exposure
    ({"DATE_OBS": "yesterday", "EXPTIME": 1.0}, "DATE-OBS"),       # malformed
    ({}, "DATE-OBS"),                                              # no time at all
])
def test_fits_without_a_usable_time_still_solves(rendered, db12, cam12, tmp_path, cards, words):
    frame, _ = rendered
    res = solve_image(_fits_with(tmp_path / "f.fits", frame.image, **cards), camera=cam12,
                      database=db12)
    assert res.solved and res.date_obs == "" and words in res.time_problem
    d = res.as_json_dict()
    assert d["date_obs"] is None and d["camera"] == "seed004"


def test_arrays_and_other_formats_have_no_time(rendered, db12, cam12, tmp_path):
    frame, _ = rendered
    np.save(tmp_path / "f.npy", np.asarray(frame.image, np.uint16))
    for image in (frame.image, tmp_path / "f.npy"):
        res = solve_image(image, camera=cam12, database=db12)
        assert res.solved and res.date_obs == "" and res.time_problem == ""
    with pytest.raises(ShipstarError, match="date_obs_is"):
        solve_image(frame.image, camera=cam12, database=db12, date_obs_is="end")
