"""Simulator conditions (issue 14 item 1): each condition's effect against an analytic expectation."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from shipstar.errors import ShipstarError
from shipstar.simulate._conditions import (
    CONDITION_NAMES,
    CONDITIONS_CSV_COLUMNS,
    Conditions,
    Seeing,
    _State,
    _rotation,
    _seeing_px,
    apply_conditions,
    condition_frame,
    flexure_rotvec_rad,
    load_conditions,
    parse_conditions,
)
from shipstar.simulate._session import dock_session, sea_session, write_session
from shipstar.units import RAD2ASEC

HEAD = 'format = "shipstar-conditions"\nformat_version = 1\n'


def _spec(text, base=None, **changes):
    base = base or sea_session(duration_s=0.05)
    return apply_conditions(base.replace(**changes), parse_conditions(HEAD + text, "test.toml"))


def _frame(spec, name="A1", k=0):
    s = spec.sensor(name)
    return condition_frame(spec, _State(spec), s, k, float(spec.times_s(s)[k]))


def test_every_shipped_file_parses():
    for name in CONDITION_NAMES:
        cond = load_conditions(name)
        apply_conditions(sea_session(), cond)
    real = load_conditions("realistic")
    assert real.seeing.sigma_arcsec == 1.5 and real.clock["A2"].offset_s == 0.003
    assert real.flexure["A2"].wave_arcsec == (20.0, 0.0, 0.0) and real.cloud is not None and real.moon is not None


def test_moon_place_matches_astropy():
    from astropy.coordinates import AltAz, EarthLocation, get_body
    from astropy.time import Time
    import astropy.units as u

    from shipstar.simulate._skylight import moon_sun
    from shipstar.sky.apparent import Site, frame_context
    from shipstar.sky.time import utc_jd_from_iso

    site = Site.from_deg(31.9, 120.3, 0.0)
    loc = EarthLocation.from_geodetic(120.3 * u.deg, 31.9 * u.deg, 0.0 * u.m)
    for iso in ("2013-03-26T19:00:00", "2013-05-20T14:20:00"):
        p = moon_sun(frame_context(*utc_jd_from_iso(iso), site))
        t = Time(iso, scale="utc")
        for body, v in (("moon", p.moon_hor), ("sun", p.sun_hor)):
            aa = get_body(body, t, loc).transform_to(AltAz(obstime=t, location=loc, pressure=0.0 * u.hPa))
            w = np.array([math.cos(aa.alt.rad) * math.cos(aa.az.rad), math.sin(aa.alt.rad),
                          math.cos(aa.alt.rad) * math.sin(aa.az.rad)])
            assert math.acos(min(1.0, float(w @ v))) * RAD2ASEC < 10.0          # well inside 1 arcmin


def test_realistic_moon_is_15_deg_from_a1_and_scatters_light():
    spec = apply_conditions(sea_session(duration_s=0.05), load_conditions("realistic"))
    frame, b = _frame(spec, "A1")
    assert abs(b["moon"]["sep_deg"] - 15.0) < 0.5 and not b["moon_in_field"]
    assert b["moon"]["illuminated_fraction"] > 0.95 and b["sun"]["el_deg"] < -18.0
    cam = frame.camera
    sky = b["sky_e_per_px_per_s"]
    assert sky > 10 * cam.sky_e_per_px_per_s                                # moonlit sky
    bg = np.median(frame.image) - cam.bias_adu
    expect = (sky + cam.dark_e_per_s) * cam.exposure_s / cam.gain_e_per_adu
    assert abs(bg - expect) < 0.1 * expect + 0.6


def test_moon_disc_in_field():
    spec = apply_conditions(sea_session(duration_s=0.05), load_conditions("moon"))
    frame, b = _frame(spec, "A1")
    assert b["moon_in_field"] and b["moon"]["sep_deg"] < 3.0
    x, y = b["moon_xy_px"]
    r = b["moon_radius_px"]
    assert 25 < r < 40 and b["moon_lit_pixels"] > 0.5 * math.pi * r * r     # gibbous: > half the disc lit
    yy, xx = np.mgrid[0:frame.image.shape[0], 0:frame.image.shape[1]]
    lit = np.hypot(xx - x, yy - y) < 0.5 * r
    assert np.mean(frame.image[lit] >= frame.camera.adc_max_adu) > 0.5     # the lit disc saturates
    far = np.hypot(xx - x, yy - y) > 3 * r
    assert np.median(frame.image[far]) < 0.5 * frame.camera.adc_max_adu


def test_twilight_brightens_the_sky():
    from shipstar.simulate._skylight import flux_ratio, twilight_mag

    spec = apply_conditions(dock_session(duration_s=0.05), load_conditions("twilight"))
    frame, b = _frame(spec, "A1")
    assert -10.0 < b["sun"]["el_deg"] < -8.0
    ratio = float(flux_ratio(twilight_mag(math.radians(b["sun"]["el_deg"]))))
    cam = frame.camera
    assert b["sky_e_per_px_per_s"] == pytest.approx(cam.sky_e_per_px_per_s * ratio, rel=1e-9)
    bg = np.median(frame.image) - cam.bias_adu
    expect = (b["sky_e_per_px_per_s"] + cam.dark_e_per_s) * cam.exposure_s / cam.gain_e_per_adu
    assert abs(bg - expect) < 0.05 * expect


def test_seeing_rms_and_correlation():
    spec = _spec("[seeing]\nsigma_arcsec = 1.5\ncorrelation_time_s = 0.1\n")
    cam = spec.sensors[0].camera
    state = _State(spec)
    hip = np.arange(1, 401)
    d = np.stack([_seeing_px(spec, state, "A1", k, hip, cam) for k in range(6)]) * cam.pixel_scale_arcsec
    rms = float(np.sqrt(np.mean(d ** 2)))
    assert abs(rms / 1.5 - 1.0) < 0.05
    rho = math.exp(-1.0 / (spec.frame_rate_hz * 0.1))
    lag1 = float(np.mean(d[1:] * d[:-1]) / np.mean(d ** 2))
    assert abs(lag1 - rho) < 0.06
    # the truth of a rendered frame: its per-star displacements and their RMS
    frame, b = _frame(spec, "A1")
    off = np.array(b["stars"]["seeing_offset_arcsec"])
    assert b["seeing_rms_arcsec"] == pytest.approx(float(np.sqrt(np.mean(off ** 2))))
    assert 0.8 * 1.5 < b["seeing_rms_arcsec"] < 1.2 * 1.5


def test_clock_offset_hidden_from_headers(tmp_path):
    from astropy.io import fits

    from shipstar.sky.time import utc_jd_from_iso

    spec = _spec("[clock.A2]\noffset_s = 0.003\n", sensors=sea_session().sensors, duration_s=0.15)
    files = write_session(spec, tmp_path / "s")
    for k, path in enumerate(files["frames"]["A2"]):
        truth = json.loads(path.with_name(path.stem + ".truth.json").read_text())
        c = truth["conditions"]
        header = fits.getheader(path)["DATE-AVG"]
        assert header + "Z" == c["header_utc_mid_exposure"] == truth["utc_mid_exposure"]
        h1, h2 = utc_jd_from_iso(header)
        t1, t2 = utc_jd_from_iso(c["true_utc_mid_exposure"])
        assert round(((t1 - h1) + (t2 - h2)) * 86400e6) == 3000              # exactly 3 ms, to the microsecond
        assert c["clock_offset_s"] == pytest.approx(0.003, abs=1e-12)
        # the sky was rendered at the true time: the ship's attitude then
        C = spec.motion.C_hor_from_deck(c["true_t_s"])
        assert np.allclose(truth["C_hor_from_deck"], C, atol=1e-12)
        assert not np.allclose(truth["C_hor_from_deck"], spec.motion.C_hor_from_deck(c["t_s"]), atol=1e-7)
    a1 = json.loads(files["frames"]["A1"][0].with_name("A1_00000.truth.json").read_text())
    assert a1["conditions"]["clock_offset_s"] == 0.0
    lines = files["conditions"].read_text().splitlines()
    assert lines[0].split(",") == list(CONDITIONS_CSV_COLUMNS) and len(lines) == 1 + 2 * spec.n_frames()
    assert (tmp_path / "s" / "session.toml").exists() and (tmp_path / "s" / "conditions.toml").exists()


def test_flexure_truth_matches_the_configuration():
    spec = _spec("[flexure]\nreference = \"A1\"\n[flexure.A2]\nstatic_arcsec = [3.0, -2.0, 4.0]\n"
                 "wave_arcsec = [20.0, 0.0, 0.0]\n", sensors=sea_session().sensors)
    t = np.linspace(0.0, spec.motion.roll_period_s, 2001)
    phi = flexure_rotvec_rad(spec, "A2", t) * RAD2ASEC
    assert np.max(phi[:, 0]) - 3.0 == pytest.approx(20.0, abs=1e-3)
    assert np.min(phi[:, 0]) - 3.0 == pytest.approx(-20.0, abs=1e-3)
    assert np.allclose(phi[:, 1:], [-2.0, 4.0])
    assert np.all(flexure_rotvec_rad(spec, "A1", t) == 0.0)
    frame, b = _frame(spec, "A2", 0)
    s = spec.sensor("A2")
    rot = np.radians(np.array([b["rot_bow_arcsec"], b["rot_up_arcsec"], b["rot_starboard_arcsec"]]) / 3600.0)
    expect = flexure_rotvec_rad(spec, "A2", b["true_t_s"])
    assert np.allclose(rot, expect, atol=1e-15)
    C = spec.motion.C_hor_from_deck(b["true_t_s"]) @ _rotation(expect) @ s.C_deck_from_sensor
    assert np.allclose(frame.C_hor_from_sensor, C, atol=1e-12)
    # the boresight moved by the flexure angle, relative to the rigid mount
    rigid = spec.motion.C_hor_from_deck(b["true_t_s"]) @ s.C_deck_from_sensor
    angle = math.acos(min(1.0, float(rigid[:, 0] @ C[:, 0]))) * RAD2ASEC
    assert angle <= np.linalg.norm(expect) * RAD2ASEC + 1e-6


def _aperture_flux(image, xy, bias_adu, gain, r=4, sky_r=(7, 10)):
    x, y = (int(round(v)) for v in xy)
    win = image[y - sky_r[1]:y + sky_r[1] + 1, x - sky_r[1]:x + sky_r[1] + 1].astype(float)
    yy, xx = np.mgrid[-sky_r[1]:sky_r[1] + 1, -sky_r[1]:sky_r[1] + 1]
    d = np.hypot(xx + x - xy[0], yy + y - xy[1])
    sky = np.median(win[(d >= sky_r[0]) & (d <= sky_r[1])])
    return float(np.sum(win[d <= r] - sky)) * gain


def test_cloud_reduces_star_fluxes_by_the_truth_factor():
    base = dock_session(duration_s=0.05)
    cloud = "[cloud]\nhaze_mag = 0.3\nbank_mag = 1.0\ncover_fraction = 0.5\nscale_km = 0.5\n"
    frame_c, b = _frame(_spec(cloud, base), "A1")
    frame_0, b0 = _frame(_spec("", base), "A1")
    T = np.array(b["stars"]["transmission"])
    assert np.all(T < 10 ** (-0.4 * 0.3) + 1e-12) and np.ptp(T) > 0.05        # haze + banks: varies over the field
    assert b0["stars"]["transmission"] == [1.0] * len(T)
    cam = frame_c.camera
    xy = frame_c.stars.xy_px
    inner = np.all((xy > 20) & (xy < np.array([cam.width_px, cam.height_px]) - 20), axis=1)
    bright = np.flatnonzero(inner & (frame_0.stars.signal_e > 20000) & (frame_0.stars.signal_e < 150000))[:12]
    assert len(bright) >= 5
    ratios = [_aperture_flux(frame_c.image, xy[i], cam.bias_adu, cam.gain_e_per_adu)
              / _aperture_flux(frame_0.image, xy[i], cam.bias_adu, cam.gain_e_per_adu) for i in bright]
    assert np.allclose(ratios, T[bright], rtol=0.05)
    assert np.allclose(frame_c.stars.signal_e, np.array(b["stars"]["signal_clear_e"]) * T)


def test_overcast_spell_and_sky_factor():
    text = "[cloud]\nbank_mag = 0.0\novercast_s = [[-1.0, 1.0]]\novercast_mag = 5.0\novercast_ramp_s = 0.01\n" \
           "sky_factor = 0.5\n"
    frame, b = _frame(_spec(text, dock_session(duration_s=0.05)), "A1")
    assert max(b["stars"]["transmission"]) < 10 ** (-0.4 * 5.0) * 1.0001 and b["transmission"] < 0.011
    assert b["sky_e_per_px_per_s"] == pytest.approx(frame.camera.sky_e_per_px_per_s * (b["transmission"] * 0.5 + 0.5))


def test_hot_pixels_cosmic_rays_and_trails():
    text = ("[hot_pixels]\nfraction = 1e-4\ne_per_s = 20000.0\n[cosmic_rays]\nper_frame = 20.0\n"
            "[trails]\nsatellites_per_frame = 3.0\naircraft_per_frame = 1.0\n")
    spec = _spec(text, dock_session(duration_s=0.25))
    state = _State(spec)
    s = spec.sensor("A1")
    cam = s.camera
    seen = []
    for k in range(2):
        frame, b = condition_frame(spec, state, s, k, float(spec.times_s(s)[k]))
        idx, rate = state.hot["A1"]
        assert len(idx) == round(1e-4 * cam.width_px * cam.height_px) == b["hot_pixels"]["count"]
        img = frame.image.ravel().astype(float)
        level = np.median(img)
        hot = rate * cam.exposure_s / cam.gain_e_per_adu > 20              # the hot ones clearly above the noise
        assert np.mean(img[idx[hot]] > level + 10) > 0.95
        seen.append(set(idx.tolist()))
        assert b["cosmic_rays"]["count"] == frame.false_objects.cosmic_ray_count
        for ray in b["cosmic_rays"]["xy_px"]:
            assert frame.image[int(ray[1]), int(ray[0])] > level + 10
        for tr in b["trails"]:
            (x0, y0), (x1, y1) = tr["xy_px"]
            f = np.linspace(0.3, 0.7, 50)
            px = np.round(np.stack([x0 + f * (x1 - x0), y0 + f * (y1 - y0)], axis=1)).astype(int)
            on = (px[:, 0] >= 0) & (px[:, 0] < cam.width_px) & (px[:, 1] >= 0) & (px[:, 1] < cam.height_px)
            if on.sum() > 10 and tr["signal_e"] / math.hypot(x1 - x0, y1 - y0) > 200:
                assert np.median(frame.image[px[on, 1], px[on, 0]]) > level + 3
    assert seen[0] == seen[1]                                                   # fixed per sensor
    assert len(b["trails"]) == len(frame.false_objects.trail_xy_px)


def test_distortion_moves_the_stars():
    text = "[distortion.A1]\nk1_per_mm2 = 2.0e-5\n"
    frame, b = _frame(_spec(text, dock_session(duration_s=0.05)), "A1")
    cam = frame.camera
    assert cam.distortion.k1_per_mm2 == 2.0e-5 and b["distortion"]["k1_per_mm2"] == 2.0e-5
    assert np.allclose(cam.project(frame.stars.u_sensor), frame.stars.xy_px, atol=1e-9)
    pinhole = cam.replace(distortion=type(cam.distortion)()).project(frame.stars.u_sensor)
    shift = np.hypot(*(frame.stars.xy_px - pinhole).T)
    r_mm = np.hypot(*((pinhole - [cam.x0_px, cam.y0_px]) * cam.pixel_mm).T)
    assert np.allclose(shift, 2.0e-5 * r_mm ** 3 / cam.pixel_mm, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("text, words", [
    ("[cloud]\nhaze_mag = -1\n", "haze_mag must be within"),
    ("[seeing]\nsigma = 1.5\n", "unknown key 'sigma'"),
    ("[fog]\n", "unknown key 'fog'"),
    ("[clock.A3]\noffset_s = 0.003\n", "names no sensor"),
    ("[clock.A2]\noffset_s = 2.0\n", "offset_s must be within"),
    ("[flexure.A2]\nwave_arcsec = [1, 2]\n", "list of 3 finite numbers"),
    ("[flexure]\nreference = \"A2\"\n[flexure.A2]\nstatic_arcsec = [1, 2, 3]\n", "reference"),
    ("[cloud]\novercast_s = [[3.0, 1.0]]\n", "overcast_s"),
    ("[trails]\nsatellite_mag = [6.0, 3.0]\n", "min <= max"),
    ("[session]\nstart_utc = \"2013-02-30T00:00:00\"\n", "start_utc"),
    ("[moon]\ndisc = 1\n", "true or false"),
    ("seeing = 3\n", "must be a table"),
])
def test_bad_files_give_one_line_errors(text, words):
    with pytest.raises(ShipstarError) as exc:
        apply_conditions(sea_session(), parse_conditions(HEAD + text, "bad.toml"))
    assert words in str(exc.value) and "\n" not in str(exc.value)


def test_bad_header_and_missing_file():
    for text in ('format = "shipstar-camera"\nformat_version = 1\n', HEAD.replace("1", "7"), "x = [\n"):
        with pytest.raises(ShipstarError) as exc:
            parse_conditions(text, "bad.toml")
        assert "\n" not in str(exc.value)
    with pytest.raises(ShipstarError, match="does not exist"):
        load_conditions("/nonexistent/realistic.toml")


def test_cli_conditions(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(HEAD + "[seeing]\nsigma_arcsec = -2\n")
    run = subprocess.run([sys.executable, "-m", "shipstar", "simulate-session", "--kind", "sea", "--out",
                          str(tmp_path / "o"), "--duration-s", "0.05", "--conditions", str(bad)],
                         capture_output=True, text=True)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1 and "sigma_arcsec" in run.stderr
    assert not (tmp_path / "o").exists()
    run = subprocess.run([sys.executable, "-m", "shipstar", "simulate-session", "--kind", "sea", "--out",
                          str(tmp_path / "ok"), "--duration-s", "0.05", "--sensors", "A1", "--conditions", "seeing",
                          "--json"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    assert report["conditions"].endswith("conditions.csv") and report["frames"] == {"A1": 1}
    summary = json.loads((tmp_path / "ok" / "conditions.json").read_text())
    assert summary["parameters"]["seeing"] == {"sigma_arcsec": 1.5, "correlation_time_s": 0.1}
    truth = json.loads((tmp_path / "ok" / "A1" / "A1_00000.truth.json").read_text())
    assert 0.5 < truth["conditions"]["seeing_rms_arcsec"] < 3.0


def test_no_condition_is_the_clean_session():
    spec = sea_session()
    assert spec.conditions is None
    nothing = Conditions()
    empty = apply_conditions(spec, nothing)
    assert empty.conditions is nothing and replace(empty, conditions=None) == spec
    hash(empty)                                                             # a spec with conditions stays hashable
    # seeing of zero size adds no displacement
    zero = _spec("[seeing]\nsigma_arcsec = 0.0\n")
    assert zero.conditions.seeing == Seeing(0.0, 0.1)


def test_cloud_field_drifts_with_the_wind():
    from shipstar.simulate._conditions import _CloudField

    spec = _spec("[cloud]\nbank_mag = 2.0\nheight_km = 2.0\nwind_m_per_s = 20.0\nwind_from_deg = 270.0\n")
    cloud = _CloudField(spec, spec.conditions)
    el, az = np.radians(40.0), np.radians(np.linspace(0.0, 360.0, 50, endpoint=False))
    v = np.stack([np.cos(el) * np.cos(az), np.full_like(az, np.sin(el)), np.cos(el) * np.sin(az)], axis=1)
    # the layer point under v at t = 0 is under w at t = 10 s: 200 m further east
    r = 2.0 * np.stack([v[:, 0], v[:, 2]], axis=1) / v[:, 1:2] + [0.0, 0.2]
    w = np.stack([r[:, 0], np.full(len(r), 2.0), r[:, 1]], axis=1)
    sin_w = w[:, 1] / np.linalg.norm(w, axis=1)
    # the same vertical extinction, seen through a slant path 1 / sin(el)
    assert np.allclose(cloud.extinction_mag(v, 0.0) * v[:, 1], cloud.extinction_mag(w, 10.0) * sin_w, rtol=1e-9)
    assert np.ptp(cloud.transmission(v, 0.0)) > 0.1


def test_centroid_level_conditions():
    from shipstar.simulate._session import simulate_centroids

    text = ("[clock.A2]\noffset_s = 0.003\n[flexure.A2]\nwave_arcsec = [20.0, 0.0, 0.0]\n"
            "[seeing]\nsigma_arcsec = 1.5\n[cloud]\nbank_mag = 0.0\novercast_s = [[0.25, 10.0]]\novercast_mag = 12.0\n"
            "overcast_ramp_s = 0.01\n")
    spec = _spec(text, sensors=sea_session().sensors, duration_s=0.4, centroid_sigma_px=0.0)
    frames = simulate_centroids(spec)
    for f in frames["A2"]:
        c = f.conditions
        assert c["clock_offset_s"] == pytest.approx(0.003, abs=1e-12) and f.t_s == c["t_s"]
        assert np.allclose(f.C_hor_from_deck, spec.motion.C_hor_from_deck(c["true_t_s"]), atol=1e-12)
        phi = flexure_rotvec_rad(spec, "A2", c["true_t_s"])
        assert c["rot_bow_arcsec"] == pytest.approx(phi[0] * RAD2ASEC)
    clear, clouded = frames["A1"][:2], frames["A1"][3:]
    assert all(len(f.hip) > 20 for f in clear) and all(len(f.hip) == 0 for f in clouded)
    d = np.concatenate([(f.xy_px - f.xy_true_px) for f in clear]) * spec.sensors[0].camera.pixel_scale_arcsec
    assert np.allclose(d, np.concatenate([f.conditions["stars"]["seeing_offset_arcsec"] for f in clear]))
    assert 0.7 * 1.5 < float(np.sqrt(np.mean(d ** 2))) < 1.3 * 1.5


def test_empty_conditions_frame_has_the_clean_geometry():
    from shipstar.simulate._session import _sensor_frame

    spec = sea_session(duration_s=0.05)
    clean = _sensor_frame(spec, spec.sensor("A2"), 0, 0.0)
    frame, b = _frame(apply_conditions(spec, Conditions()), "A2")
    for name in ("hip", "xy_px", "smear_px", "signal_e", "v_ref"):
        assert np.array_equal(getattr(frame.stars, name), getattr(clean.stars, name)), name
    assert np.array_equal(frame.C_hor_from_sensor, clean.C_hor_from_sensor) and frame.utc_iso == clean.utc_iso
    assert frame.weather == clean.weather
    # and the same light: the mean image agrees to the noise
    assert abs(float(np.mean(frame.image)) - float(np.mean(clean.image))) < 0.05
