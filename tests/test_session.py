"""Simulated sessions (simulate._session) and the ``simulate-session`` command."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tomllib

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


# -- the command ---------------------------------------------------------------------------

def _run(args, cwd):
    return subprocess.run([sys.executable, "-m", "shipstar", "simulate-session", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=600)


def test_simulate_session_command_writes_a_session(tmp_path):
    from astropy.io import fits

    proc = _run(["--kind", "sea", "--out", "s", "--duration-s", "0.2", "--offset-ms", "30", "--json"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["frames"] == {"A1": 2, "A2": 2}
    out = tmp_path / "s"
    files = sorted(p.name for p in (out / "A2").iterdir())
    assert files == ["A2_00000.fits", "A2_00000.truth.json", "A2_00001.fits", "A2_00001.truth.json"]
    hdr = fits.getheader(out / "A2" / "A2_00001.fits")
    assert hdr["DATE-OBS"] == "2013-03-15T12:16:00.130"
    assert hdr["EXPTIME"] == pytest.approx(0.01)
    session = tomllib.loads((out / "session.toml").read_text())
    assert session["kind"] == "sea" and [s["name"] for s in session["sensor"]] == ["A1", "A2"]
    assert session["sensor"][1]["time_offset_s"] == pytest.approx(0.03)
    truth = (out / "truth.csv").read_text().splitlines()
    assert truth[0] == "time_utc,t_s,heading_deg,pitch_deg,roll_deg" and len(truth) == 5
    assert (out / "track.csv").exists() and (out / "weather.csv").exists()
    truth_json = json.loads((out / "A2" / "A2_00001.truth.json").read_text())
    assert truth_json["ship_roll_deg"] == pytest.approx(float(truth[4].split(",")[4]), abs=1e-9)


@pytest.mark.parametrize("args, fragment", [
    (["--kind", "dock", "--out", "x", "--sensors", "A1,A9"], "--sensors"),
    (["--kind", "dock", "--out", "x", "--duration-s", "nan"], "--duration-s"),
    (["--kind", "harbour", "--out", "x"], "--kind"),
    (["--kind", "dock", "--out", "full"], "not an empty directory"),
])
def test_simulate_session_bad_input(tmp_path, args, fragment):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("x")
    proc = _run(args, tmp_path)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr and fragment in lines[0], proc.stderr
    assert not (tmp_path / "x").exists()
