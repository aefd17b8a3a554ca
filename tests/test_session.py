"""Simulated sessions (simulate._session) and the ``simulate-session`` command."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tomllib

from dataclasses import replace

import erfa
import numpy as np
import pytest

from shipstar import frames as F
from shipstar.errors import ShipstarError
from shipstar.simulate._session import (
    SEED_A1_INSTALL_DEG,
    SEED_A2_INSTALL_DEG,
    SEED_DOCK_HEADING_DEG,
    ShipMotion,
    dock_session,
    sea_session,
    simulate_centroids,
)
from shipstar.units import DEG2RAD, RAD2ASEC


def test_dock_session_is_the_seed_case():
    spec = dock_session()
    assert SEED_DOCK_HEADING_DEG == pytest.approx(46.47458611, abs=1e-8)
    assert spec.start_utc == "2013-03-15T12:16:00" and spec.frame_rate_hz == 10 and spec.duration_s == 16
    assert (spec.pressure_hpa, spec.temperature_c) == (1021.70, 11.10)
    a1, a2 = spec.sensor("A1"), spec.sensor("A2")
    np.testing.assert_allclose(np.array([a1.install_az_rad, a1.install_el_rad, a1.install_roll_rad]) / DEG2RAD,
                               SEED_A1_INSTALL_DEG)
    np.testing.assert_allclose(np.array([a2.install_az_rad, a2.install_el_rad, a2.install_roll_rad]) / DEG2RAD,
                               SEED_A2_INSTALL_DEG)
    t = spec.times_s(a1)
    assert len(t) == 160 and t[-1] == pytest.approx(15.9)
    K, psi, theta = spec.motion.angles_rad(t)
    assert np.all(K == K[0]) and np.all(psi == 0) and np.all(theta == 0)
    with pytest.raises(ShipstarError):
        spec.sensor("A3")


def test_sea_motion_is_the_stated_sinusoids():
    m = sea_session().motion
    t = np.linspace(0, 16, 161)
    K, psi, theta = m.angles_rad(t)
    assert np.max(np.abs(theta)) == pytest.approx(5 * DEG2RAD, rel=1e-3)
    assert np.max(np.abs(psi)) == pytest.approx(2 * DEG2RAD, rel=1e-3)
    np.testing.assert_allclose(theta, 5 * DEG2RAD * np.sin(2 * np.pi * t / 8), atol=1e-15)


def test_deck_rate_of_a_pure_roll_is_the_roll_rate():
    """C = R_x(-theta) (level, heading 0) turns about the bow axis at d theta / dt."""
    m = ShipMotion(0.0, 0.5, 2.0, roll_amplitude_rad=5 * DEG2RAD, roll_period_s=8.0)
    for t in (0.0, 1.3, 2.0):
        w = m.omega_deck_rad_per_s(t)
        expected = 5 * DEG2RAD * 2 * np.pi / 8 * np.cos(2 * np.pi * t / 8)
        np.testing.assert_allclose(w, [expected, 0, 0], atol=1e-8)


def test_track_follows_the_heading_at_the_speed():
    m = sea_session().motion
    lat, lon, _ = m.position(np.array([0.0, 16.0]))
    # independent: haversine distance and initial bearing on the same sphere
    dlat, dlon = lat[1] - lat[0], lon[1] - lon[0]
    a = math.sin(dlat / 2) ** 2 + math.cos(lat[0]) * math.cos(lat[1]) * math.sin(dlon / 2) ** 2
    dist = 2 * 6371008.8 * math.asin(math.sqrt(a))
    bearing = math.atan2(math.sin(dlon) * math.cos(lat[1]),
                         math.cos(lat[0]) * math.sin(lat[1]) - math.sin(lat[0]) * math.cos(lat[1]) * math.cos(dlon))
    assert dist == pytest.approx(8.0 * 16.0, rel=1e-3)
    assert bearing == pytest.approx(m.heading0_rad + 0.5 * m.heading_rate_rad_per_s * 16, abs=2e-3)


def test_centroids_match_erfa_observed_places():
    """Noise-free centroids = the camera's projection of ERFA atco13's observed places
    (apparent place + refraction, an independent route) through the true attitude."""
    spec = sea_session(duration_s=0.3, centroid_sigma_px=0.0)
    frames = simulate_centroids(spec)
    from shipstar.sky.catalog import load_hipparcos
    from shipstar.sky.eop import earth_orientation

    cat = load_hipparcos()
    for s in spec.sensors:
        for f in frames[s.name]:
            idx = cat.index_of_hip(f.hip)
            eop = earth_orientation(f.utc_jd1, f.utc_jd2)
            site, w = spec.site(f.t_s), spec.weather(f.t_s)
            rc, dc, pr, pd, px, rv = (np.asarray(a)[idx] for a in cat.erfa_args())
            aob, zob, *_ = erfa.atco13(rc, dc, pr, pd, np.maximum(px, 0), rv, f.utc_jd1, f.utc_jd2, eop.dut1_s,
                                       site.lon_rad, site.lat_rad, site.height_m, eop.xp_rad, eop.yp_rad,
                                       w.pressure_hpa, w.temperature_c, w.relative_humidity, 0.55)
            v = F.unit_from_az_el(aob, 0.5 * np.pi - zob)
            xy = s.camera.project(v @ f.C_hor_from_sensor)
            assert len(f.hip) > 20
            np.testing.assert_allclose(f.xy_px, xy, atol=2e-3)
            np.testing.assert_allclose(f.xy_true_px, f.xy_px, atol=0)


def test_centroid_noise_has_the_requested_sigma():
    spec = dock_session(duration_s=1.0)
    frames = simulate_centroids(spec)
    d = np.concatenate([f.xy_px - f.xy_true_px for f in frames["A1"]])
    assert d.std() == pytest.approx(0.1, rel=0.05)
    again = simulate_centroids(spec)
    np.testing.assert_array_equal(again["A1"][3].xy_px, frames["A1"][3].xy_px)


def test_truth_attitudes_chain():
    spec = sea_session(duration_s=0.5)
    for f in simulate_centroids(spec)["A2"]:
        C = spec.motion.C_hor_from_deck(f.t_s) @ spec.sensor("A2").C_deck_from_sensor
        assert F.rotation_angle_rad(C.T @ f.C_hor_from_sensor) * RAD2ASEC < 1e-9


def test_bad_specs_are_refused():
    with pytest.raises(ShipstarError):
        dock_session(duration_s=0.0)
    with pytest.raises(ShipstarError):
        dock_session(start_utc="yesterday")
    with pytest.raises(ShipstarError):
        dock_session(centroid_sigma_px=float("nan"))
    with pytest.raises(ShipstarError):
        dock_session(sensors=())
    with pytest.raises(ShipstarError, match="frame period 0.05 s .* shorter than sensor A1's exposure 0.08 s: "
                                            "at most 12.5 Hz"):
        dock_session(frame_rate_hz=20.0)
    with pytest.raises(ShipstarError, match="microseconds"):
        dock_session(start_utc="2013-03-15T12:16:00.1234567")
    late = replace(dock_session().sensors[1], time_offset_s=1e6)
    with pytest.raises(ShipstarError, match="sensor A2: time_offset_s = 1000000.0 s is not within"):
        dock_session(sensors=(dock_session().sensors[0], late))


def test_impossible_weather_names_the_time():
    """The weather drifts linearly: 0.005 hPa/s reaches 1200 hPa after ~10 h; the error says
    when, not just 'pressure 1221.7 hPa'."""
    with pytest.raises(ShipstarError,
                       match=r"weather or ship position at t = 39999 s .*pressure_hpa = 1221.7 is outside"):
        sea_session(duration_s=40000.0, frame_rate_hz=1.0)


def test_frame_times_are_whole_microseconds():
    spec = sea_session(duration_s=0.35, frame_rate_hz=3.0)
    spec = spec.replace(sensors=(spec.sensors[0], replace(spec.sensors[1], time_offset_s=0.0304)))
    t = spec.times_s(spec.sensors[1])
    np.testing.assert_array_equal(t * 1e6, np.round(t * 1e6))
    assert t[1] == round(1 / 3 + 0.0304, 6) == 0.363733
    assert spec.utc_iso(t[0]) == "2013-03-15T12:16:00.030400Z"
    assert spec.utc_iso(t[1]) == "2013-03-15T12:16:00.363733Z"


def _dense_time_average_px(spec, s, t, camera, v_ref, n=4000):
    """Reference: the star's image averaged over the exposure by the midpoint rule, straight
    from the ship's attitude at each instant (the Earth's rotation, linear in time, does not
    move the average)."""
    T = camera.exposure_s
    tau = (np.arange(n) + 0.5) / n * T - 0.5 * T
    C = spec.motion.C_hor_from_deck(t + tau) @ s.C_deck_from_sensor               # (n, 3, 3)
    u = np.einsum("kj,nji->kni", v_ref, C)                                         # v_ref @ C[n]
    return camera.project(u.reshape(-1, 3)).reshape(len(v_ref), n, 2).mean(axis=1)


def test_streaks_follow_the_true_curved_path():
    """At t = 2 s of the sea session the roll acceleration peaks (3.08 deg/s^2).  With A1's
    80 ms exposure the time-averaged image of a star -- what its streak's centroid is --
    lies 2'' (0.07 px) off its mid-exposure position, as the Taylor term
    (-alpha x u + omega x (omega x u)) T^2 / 24 says; the session renders the true path:
    its noise-free streaks centre on the time average to 1e-4 px, the truth stays the
    mid-exposure position, and the noisy frame's brightest streak agrees too."""
    from shipstar.simulate._motion import earth_rate_hor_rad_per_s, exposure_offsets_s, exposure_path_px, \
        streak_sources
    from shipstar.simulate._render import render_image_e
    from shipstar.simulate._session import _sensor_frame

    spec = sea_session(exposure_s=0.08)
    s, t = spec.sensor("A1"), 2.0
    frame = _sensor_frame(spec, s, 20, t)
    cam, stars = frame.camera, frame.stars
    dense = _dense_time_average_px(spec, s, t, cam, stars.v_ref)
    shift_px = np.hypot(*(dense - stars.xy_px).T)
    assert 0.05 < np.median(shift_px) and shift_px.max() < 0.08

    # the Taylor prediction of the shift, from the deck rate and its derivative
    h = 1e-3
    C_ds = s.C_deck_from_sensor
    w = C_ds.T @ spec.motion.omega_deck_rad_per_s(t)
    alpha = C_ds.T @ (spec.motion.omega_deck_rad_per_s(t + h) - spec.motion.omega_deck_rad_per_s(t - h)) / (2 * h)
    u = stars.u_sensor
    du = (-np.cross(alpha, u) + np.cross(w, np.cross(w, u))) * cam.exposure_s ** 2 / 24
    np.testing.assert_allclose(cam.project(u + du) - stars.xy_px, dense - stars.xy_px, atol=2e-3)

    # the renderer's sources: exact to 1e-4 px, noise-free image of single stars
    tau = exposure_offsets_s(cam.exposure_s)
    lat = spec.site(t).astronomical_lat_rad
    path = exposure_path_px(cam, stars.v_ref, spec.motion.C_hor_from_deck(t + tau) @ C_ds, tau,
                            earth_rate_hor_rad_per_s(lat))
    np.testing.assert_allclose(path[:, len(tau) // 2], stars.xy_px, atol=1e-9)       # truth = mid-exposure
    np.testing.assert_allclose(stars.smear_px, path[:, -1] - path[:, 0], atol=1e-12)
    yy, xx = np.mgrid[0:cam.height_px, 0:cam.width_px]
    for k in range(3):
        xy, sig, smear = streak_sources(path[k:k + 1], stars.signal_e[k:k + 1])
        img = render_image_e((cam.height_px, cam.width_px), xy, sig, cam.psf_sigma_px, smear_px=smear)
        centroid = np.array([(img * xx).sum(), (img * yy).sum()]) / img.sum()
        np.testing.assert_allclose(centroid, dense[k], atol=1e-4)

    # the written frame: the brightest streak (2e6 e, unsaturated) centres on the time average
    k, half = 0, 16
    x0, y0 = np.rint(stars.xy_px[k]).astype(int)
    win = frame.image[y0 - half:y0 + half + 1, x0 - half:x0 + half + 1].astype(float)
    assert win.max() < cam.adc_max_adu
    win -= np.median(frame.image)
    wy, wx = np.mgrid[y0 - half:y0 + half + 1, x0 - half:x0 + half + 1]
    centroid = np.array([(win * wx).sum(), (win * wy).sum()]) / win.sum()
    assert np.hypot(*(centroid - dense[k])) < 0.01 < 0.05 < np.hypot(*(centroid - stars.xy_px[k]))


# -- the command ---------------------------------------------------------------------------

def _run(args, cwd):
    return subprocess.run([sys.executable, "-m", "shipstar", "simulate-session", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=600)


def test_simulate_session_command_writes_a_session(tmp_path):
    """A2 30.4 ms late: every time tag keeps the 0.4 ms (6 decimals); FITS 4.0 time cards."""
    from astropy.io import fits

    from shipstar.pipeline import scan_frames
    from shipstar.simulate import read_truth

    proc = _run(["--kind", "sea", "--out", "s", "--duration-s", "0.2", "--offset-ms", "30.4", "--json"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["frames"] == {"A1": 2, "A2": 2} and rep["exposure_s"] == {"A1": 0.01, "A2": 0.01}
    out = tmp_path / "s"
    files = sorted(p.name for p in (out / "A2").iterdir())
    assert files == ["A2_00000.fits", "A2_00000.truth.json", "A2_00001.fits", "A2_00001.truth.json"]
    hdr = fits.getheader(out / "A2" / "A2_00001.fits")
    assert hdr["DATE-AVG"] == "2013-03-15T12:16:00.130400"                  # mid-exposure
    assert hdr["DATE-OBS"] == hdr["DATE-BEG"] == "2013-03-15T12:16:00.125400"  # start (FITS standard)
    assert hdr["DATE-END"] == "2013-03-15T12:16:00.135400"
    assert hdr["EXPTIME"] == pytest.approx(0.01)
    session = tomllib.loads((out / "session.toml").read_text())
    assert session["kind"] == "sea" and [s["name"] for s in session["sensor"]] == ["A1", "A2"]
    assert session["sensor"][1]["time_offset_s"] == pytest.approx(0.0304)
    assert session["exposure_s"] == 0.01 and [s["exposure_s"] for s in session["sensor"]] == [0.01, 0.01]
    truth = (out / "truth.csv").read_text().splitlines()
    assert truth[0] == "time_utc,t_s,heading_deg,pitch_deg,roll_deg" and len(truth) == 5
    assert truth[4].startswith("2013-03-15T12:16:00.130400Z,0.130400,")
    assert (out / "track.csv").exists() and (out / "weather.csv").exists()
    truth_json = read_truth(out / "A2" / "A2_00001.truth.json")
    assert truth_json["utc_mid_exposure"] == "2013-03-15T12:16:00.130400Z"
    assert truth_json["ship_roll_deg"] == pytest.approx(float(truth[4].split(",")[4]), abs=1e-12)
    frames = scan_frames(out / "A2")                                     # read back: the truth time exactly
    assert [f.utc_iso for f in frames] == ["2013-03-15T12:16:00.030400Z", "2013-03-15T12:16:00.130400Z"]
    assert {f.time_source for f in frames} == {"DATE-AVG"}


@pytest.mark.parametrize("args, fragment", [
    (["--kind", "dock", "--out", "x", "--sensors", "A1,A9"], "--sensors"),
    (["--kind", "dock", "--out", "x", "--duration-s", "nan"], "--duration-s"),
    (["--kind", "harbour", "--out", "x"], "--kind"),
    (["--kind", "dock", "--out", "full"], "not an empty directory"),
    (["--kind", "sea", "--out", "x", "--frame-rate-hz", "1e6", "--duration-s", "0.1"],
     "--frame-rate-hz: frame period 1e-06 s (1e+06 Hz) is shorter than sensor A1's exposure 0.01 s"),
    (["--kind", "sea", "--out", "x", "--offset-ms", "1e9"], "--offset-ms must be within +-1000 ms"),
    (["--kind", "sea", "--out", "x", "--duration-s", "3600", "--frame-rate-hz", "10"],
     "GB (2 x 36000 frames), over the cap of 20 GB"),
    (["--kind", "dock", "--out", "x", "--duration-s", "1", "--max-output-gb", "0.01"], "over the cap of 10 MB"),
    (["--kind", "sea", "--out", "x", "--duration-s", "40000", "--frame-rate-hz", "1"], "at t = 39999 s"),
])
def test_simulate_session_bad_input(tmp_path, args, fragment):
    """Refused in one line before anything is created."""
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("x")
    proc = _run(args, tmp_path)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr and fragment in lines[0], proc.stderr
    assert not (tmp_path / "x").exists()


def test_write_session_checks_before_creating_anything(tmp_path):
    from shipstar.simulate._session import estimate_output_bytes, write_session

    spec = dock_session(duration_s=0.5)
    need = estimate_output_bytes(spec)
    assert 2 * 5 * 2105280 < need < 2 * 5 * 2.5e6                # five 2.1 MB frames per sensor + truth files
    with pytest.raises(ShipstarError, match="over the cap"):
        write_session(spec, tmp_path / "a" / "b", max_output_bytes=need - 1)
    assert not (tmp_path / "a").exists()
