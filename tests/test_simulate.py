"""Tests of the scene simulator (shipstar.simulate) against independent references.

References: the gnomonic (tangent-plane) projection written out from spherical
trigonometry; astropy's WCS (FITS TAN) and AltAz (test-only references); the refraction
module's ``refraction_rad``; the sky model at two times (for the diurnal smear);
closed-form rotation geometry; and the star extractor run on the rendered images.
"""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest

from shipstar.camera import camera_preset
from shipstar.errors import ShipstarError
from shipstar.frames import (
    C_deck_from_sensor,
    C_hor_from_deck,
    C_icrs_from_sensor,
    az_el_from_unit,
    matrix_from_q_wxyz,
    ra_dec_from_unit,
    unit_from_az_el,
)
from shipstar.simulate import (
    EARTH_RATE_RAD_PER_S,
    TRUTH_SCHEMA,
    FalseObjects,
    ShipPose,
    SimulatedStars,
    image_sha256,
    random_false_objects,
    read_truth,
    render,
    simulate_frame,
    simulate_stars,
    simulate_stars_horizontal,
    smear_px_from_rate,
    truth_path_for,
    write_frame,
)
from shipstar.sky.apparent import Site, frame_context
from shipstar.sky.catalog import navigation_catalog
from shipstar.sky.refraction import Weather, refraction_rad
from shipstar.sky.time import utc_jd_from_iso
from shipstar.units import ASEC2RAD, DEG2RAD, RAD2ASEC

# Seed 000's dock: Jiangyin, 2013-03-15 20:16 local, heading 46 deg 28' 28.51'', level.
DOCK_UTC = "2013-03-15T12:16:00"
DOCK_SITE = Site.from_deg(31.9, 120.3, 5.0)
DOCK_WEATHER = Weather(pressure_hpa=1021.7, temperature_c=11.1)
DOCK_HEADING_DEG = 46.0 + 28.0 / 60.0 + 28.51 / 3600.0
A1_POSE = ShipPose.from_deg(DOCK_HEADING_DEG, 0.0, 0.0, 185.1093, 39.3734, -0.2262)


@pytest.fixture(scope="module")
def a1():
    return camera_preset("A1")


@pytest.fixture(scope="module")
def nav():
    return navigation_catalog(8.0, 0.0)


@pytest.fixture(scope="module")
def dock_context():
    return frame_context(*utc_jd_from_iso(DOCK_UTC), DOCK_SITE)


def _angle_rad(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _match(truth_xy, found_xy, radius_px=1.5):
    """Index of the nearest extracted star for each true star (-1: none) and the distance."""
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(found_xy).query(truth_xy, distance_upper_bound=radius_px)
    return np.where(np.isfinite(dist), idx, -1), dist


# --------------------------------------------------------------------------- geometry

@pytest.mark.parametrize("preset", ["A1", "seed002"])
def test_star_on_boresight_lands_on_principal_point(preset, nav):
    cam = camera_preset(preset)
    vega = nav.index_of_hip(91262)
    u = nav.subset(vega).unit_icrs(2013.2)
    ra, dec = ra_dec_from_unit(u[0])
    stars = simulate_stars(cam, C_icrs_from_sensor(ra, dec, 0.7), epoch_jyear=2013.2, catalog=nav)
    k = np.flatnonzero(stars.hip == 91262)
    assert k.size == 1
    np.testing.assert_allclose(stars.xy_px[k[0]], [cam.x0_px, cam.y0_px], atol=1e-7)
    np.testing.assert_allclose(stars.u_sensor[k[0]], [1.0, 0.0, 0.0], atol=1e-12)


@pytest.mark.parametrize("ra_deg, dec_deg, roll_deg", [(83.8, -5.4, 0.0), (279.2, 38.8, 123.0),
                                                       (10.0, 88.5, 250.0), (200.0, -60.0, 300.0)])
def test_positions_match_gnomonic_projection(a1, nav, ra_deg, dec_deg, roll_deg):
    """Tangent-plane coordinates from spherical trigonometry, turned by the roll."""
    a0, d0, r = ra_deg * DEG2RAD, dec_deg * DEG2RAD, roll_deg * DEG2RAD
    stars = simulate_stars(a1, C_icrs_from_sensor(a0, d0, r), epoch_jyear=2000.0, catalog=nav)
    assert len(stars) > 20
    idx = nav.index_of_hip(stars.hip)
    a, d = nav.ra_rad[idx], nav.dec_rad[idx]
    cos_c = np.sin(d0) * np.sin(d) + np.cos(d0) * np.cos(d) * np.cos(a - a0)
    xi = np.cos(d) * np.sin(a - a0) / cos_c                                     # toward east
    eta = (np.cos(d0) * np.sin(d) - np.sin(d0) * np.cos(d) * np.cos(a - a0)) / cos_c   # toward north
    up = np.array([np.sin(r), np.cos(r)])          # position angle r from north through east
    right = np.array([-np.cos(r), np.sin(r)])      # east is left when north is up
    scale = a1.f_mm / a1.pixel_mm
    x = a1.x0_px + scale * (xi * right[0] + eta * right[1])
    y = a1.y0_px - scale * (xi * up[0] + eta * up[1])
    np.testing.assert_allclose(stars.xy_px, np.column_stack([x, y]), atol=1e-6)
    assert np.all(np.diff(stars.mag) >= 0)                              # brightest first
    assert np.all(a1.in_image(stars.xy_px))


def test_no_star_of_the_catalog_is_missed(a1, nav):
    """Every catalog star that projects onto the detector is in the result (brute force)."""
    C = C_icrs_from_sensor(1.2, -0.4, 2.0)
    stars = simulate_stars(a1, C, epoch_jyear=2026.0, catalog=nav)
    u = nav.unit_icrs(2026.0)
    xy = a1.project(u @ C)
    expected = np.sort(nav.hip[a1.in_image(xy)])
    np.testing.assert_array_equal(np.sort(stars.hip), expected)


def test_horizontal_geometry_matches_astropy_altaz(a1, nav, dock_context):
    from astropy import units as u
    from astropy.coordinates import AltAz, Distance, EarthLocation, SkyCoord
    from astropy.time import Time
    from astropy.utils import iers

    stars = simulate_stars_horizontal(a1, A1_POSE.C_hor_from_sensor, dock_context, DOCK_WEATHER, "none",
                                      catalog=nav, earth_rotation=False)
    assert len(stars) > 30
    cat = nav.subset(nav.index_of_hip(stars.hip[:12]))
    jd1, jd2 = utc_jd_from_iso(DOCK_UTC)
    t = Time(jd1, jd2, format="jd", scale="utc")
    with iers.conf.set_temp("auto_download", False), iers.conf.set_temp("auto_max_age", None):
        sc = SkyCoord(ra=cat.ra_rad * u.rad, dec=cat.dec_rad * u.rad,
                      pm_ra_cosdec=cat.pm_ra_cosdec_mas_per_yr * u.mas / u.yr,
                      pm_dec=cat.pm_dec_mas_per_yr * u.mas / u.yr,
                      distance=Distance(parallax=np.maximum(cat.parallax_mas, 1e-3) * u.mas),
                      radial_velocity=cat.rv_km_s * u.km / u.s, obstime=Time("J2000"), frame="icrs")
        loc = EarthLocation.from_geodetic(120.3 * u.deg, 31.9 * u.deg, 5.0 * u.m)
        aa = sc.apply_space_motion(new_obstime=t).transform_to(AltAz(obstime=t, location=loc, pressure=0 * u.hPa))
    v_ref = unit_from_az_el(aa.az.rad, aa.alt.rad)
    assert np.max(_angle_rad(v_ref, stars.v_ref[:12])) * RAD2ASEC < 0.005
    # independent pinhole projection of the reference directions through C_hor_from_sensor
    C = A1_POSE.C_hor_from_sensor
    w = v_ref @ C
    scale = a1.f_mm / a1.pixel_mm
    xy = np.column_stack([a1.x0_px + scale * w[:, 2] / w[:, 0], a1.y0_px - scale * w[:, 1] / w[:, 0]])
    np.testing.assert_allclose(stars.xy_px[:12], xy, atol=2e-4)


def test_refraction_lifts_each_star_by_its_own_amount(a1, nav, dock_context):
    C = A1_POSE.C_hor_from_sensor
    kw = dict(catalog=nav, earth_rotation=False)
    obs = simulate_stars_horizontal(a1, C, dock_context, DOCK_WEATHER, "almanac", **kw)
    true = simulate_stars_horizontal(a1, C, dock_context, DOCK_WEATHER, "none", **kw)
    common, i, j = np.intersect1d(obs.hip, true.hip, return_indices=True)
    assert len(common) > 30
    az_o, el_o = az_el_from_unit(obs.v_ref[i])
    az_t, el_t = az_el_from_unit(true.v_ref[j])
    assert np.max(np.abs(az_o - az_t)) < 1e-12                       # azimuth unchanged
    rho = refraction_rad(el_o, DOCK_WEATHER, "almanac")
    np.testing.assert_allclose((el_o - el_t) * RAD2ASEC, rho * RAD2ASEC, atol=1e-3)
    np.testing.assert_allclose(obs.refraction_rad[i], rho, atol=1e-3 * ASEC2RAD)
    assert np.ptp(rho) * RAD2ASEC > 15.0                             # per star, not one value
    assert np.all(true.refraction_rad == 0.0)
    # image "up" is nearly vertical for this installation: every star moves up (y decreases)
    dy = obs.xy_px[i, 1] - true.xy_px[j, 1]
    assert np.all(dy < 0)
    np.testing.assert_allclose(-dy, rho * RAD2ASEC / a1.pixel_scale_arcsec, rtol=0.05)


def test_stars_below_five_degrees_are_dropped(a1, nav, dock_context):
    C = C_hor_from_deck(200 * DEG2RAD, 4.0 * DEG2RAD, 0.0)          # boresight 4 deg above the horizon
    stars = simulate_stars_horizontal(a1, C, dock_context, DOCK_WEATHER, "almanac", catalog=nav)
    _, el = az_el_from_unit(stars.v_ref)
    assert len(stars) > 5
    assert el.min() >= 5.0 * DEG2RAD - 1e-12
    assert el.min() < 5.5 * DEG2RAD                                   # the cut, not an empty half
    # stars with centres between the horizon and 5 deg exist in the catalog but not here
    lower = simulate_stars(a1, dock_context.C_hor_from_icrs_approx.T @ C, catalog=nav, epoch_jyear=2013.2)
    assert len(lower) > len(stars)


def test_sensor_pointing_into_the_ground_sees_no_star(a1, nav, dock_context):
    C = C_hor_from_deck(0.0, -30 * DEG2RAD, 0.0)
    stars = simulate_stars_horizontal(a1, C, dock_context, DOCK_WEATHER, catalog=nav)
    assert len(stars) == 0 and stars.xy_px.shape == (0, 2)
    image = render(a1, stars, np.random.default_rng(0))
    assert image.shape == (1024, 1024) and image.dtype == np.uint16


# --------------------------------------------------------------------------- motion smear

def test_smear_of_a_rotation_about_image_up_is_analytic(a1):
    rate = 0.5 * DEG2RAD
    smear = smear_px_from_rate(a1, np.array([[1.0, 0.0, 0.0]]), [0.0, rate, 0.0], a1.exposure_s)
    theta = 0.5 * rate * a1.exposure_s
    np.testing.assert_allclose(smear[0], [2 * a1.f_mm / a1.pixel_mm * math.tan(theta), 0.0], atol=1e-9)
    # about the boresight a star at the principal point does not move; one off-axis circles
    u = a1.unproject(np.array([[a1.x0_px, a1.y0_px], [a1.x0_px + 400.0, a1.y0_px]]))
    spin = smear_px_from_rate(a1, u, [1.0 * DEG2RAD, 0.0, 0.0], 0.1)
    assert np.abs(spin[0]).max() < 1e-9
    assert abs(spin[1, 0]) < 1e-6 and abs(abs(spin[1, 1]) - 400.0 * 1.0 * DEG2RAD * 0.1) < 1e-3


def test_diurnal_smear_matches_the_sky_model_at_two_times(a1, nav):
    jd1, jd2 = utc_jd_from_iso(DOCK_UTC)
    C = A1_POSE.C_hor_from_sensor
    dt_s = 20.0
    sims = {}
    for k, shift_s in ((-1, -dt_s), (0, 0.0), (1, dt_s)):
        ctx = frame_context(jd1, jd2 + shift_s / 86400.0, DOCK_SITE)
        sims[k] = simulate_stars_horizontal(a1, C, ctx, DOCK_WEATHER, "none", catalog=nav)
    common = np.intersect1d(np.intersect1d(sims[-1].hip, sims[1].hip), sims[0].hip)   # a few leave the edge
    assert len(common) > 100
    pick = {k: np.array([np.flatnonzero(s.hip == h)[0] for h in common]) for k, s in sims.items()}
    rate_px = (sims[1].xy_px[pick[1]] - sims[-1].xy_px[pick[-1]]) / (2 * dt_s)
    smear = sims[0].smear_px[pick[0]]
    np.testing.assert_allclose(smear, rate_px * a1.exposure_s, atol=2e-5)
    # size: 15''/s * cos(dec) over 80 ms, in pixels (gnomonic stretch off axis: up to 1.2 %)
    dec = ra_dec_from_unit(frame_context(jd1, jd2, DOCK_SITE).icrs_from_hor(sims[0].v_ref[pick[0]]))[1]
    expect = EARTH_RATE_RAD_PER_S * RAD2ASEC * np.cos(dec) * a1.exposure_s / a1.pixel_scale_arcsec
    np.testing.assert_allclose(np.hypot(*smear.T), expect, rtol=0.015)


# --------------------------------------------------------------------------- rendered truth

@pytest.fixture(scope="module")
def orion_frame(a1):
    return simulate_frame(a1, C_icrs_from_sensor=C_icrs_from_sensor(83.8 * DEG2RAD, -5.4 * DEG2RAD, 0.3),
                          utc_iso="2024-05-01T00:00:00", seed=11)


def test_extracted_centroids_match_truth(orion_frame, a1):
    from shipstar.extract import extract_stars

    ext = extract_stars(orion_frame.image, gain_e_per_adu=a1.gain_e_per_adu)
    stars = orion_frame.stars
    bright = (stars.signal_e > 2e4) & (stars.signal_e < 2e5)        # high SNR, unsaturated
    assert bright.sum() >= 10
    which, dist = _match(stars.xy_px[bright], ext.xy_px)
    assert np.mean(which >= 0) >= 0.9                                 # a few may be blended pairs
    err = dist[which >= 0]
    assert np.median(err) < 0.1
    # A1 detects stars to Hp ~ 8.4: nearly all simulated stars are found (a few blend in pairs)
    found, _ = _match(stars.xy_px, ext.xy_px)
    assert np.mean(found >= 0) > 0.9


def test_smeared_frame_keeps_mid_exposure_truth(a1):
    from shipstar.extract import extract_stars

    C = C_icrs_from_sensor(1.46, -0.09, 0.0)
    # a moderate rate (2.4 px of smear along y): extracted centroids sit at the truth, the
    # mid-exposure position, not at either end of the path (1.2 px away)
    frame = simulate_frame(a1, C_icrs_from_sensor=C, seed=3, omega_sensor_rad_per_s=[0.0, 0.0, 0.25 * DEG2RAD])
    stars = frame.stars
    assert np.all(np.abs(stars.smear_px[:, 1] - 2.37) < 0.05) and np.all(np.abs(stars.smear_px[:, 0]) < 0.1)
    ext = extract_stars(frame.image, gain_e_per_adu=a1.gain_e_per_adu)
    bright = (stars.signal_e > 2e4) & (stars.signal_e < 1e6)
    which, dist = _match(stars.xy_px[bright], ext.xy_px, radius_px=1.0)
    assert np.mean(which >= 0) >= 0.9
    assert np.median(dist[which >= 0]) < 0.1


def test_long_smear_is_a_uniform_streak_centred_on_truth(a1):
    """Moments of a 19 px streak: centre = truth, variance along it = sigma^2 + L^2 / 12."""
    frame = simulate_frame(a1, C_icrs_from_sensor=C_icrs_from_sensor(1.46, -0.09, 0.0), seed=3,
                           omega_sensor_rad_per_s=[0.0, 0.0, 2.0 * DEG2RAD], hot_pixel_fraction=0.0)
    x, y = frame.stars.xy_px[0]
    length = float(np.hypot(*frame.stars.smear_px[0]))
    assert 18.0 < length < 20.0
    half = 16
    x0, y0 = int(round(x)), int(round(y))
    cut = frame.image[y0 - half:y0 + half + 1, x0 - half:x0 + half + 1].astype(float)
    cut -= np.median(frame.image)
    yy, xx = np.mgrid[y0 - half:y0 + half + 1, x0 - half:x0 + half + 1]
    total = cut.sum()
    cx, cy = (cut * xx).sum() / total, (cut * yy).sum() / total
    assert abs(cx - x) < 0.05 and abs(cy - y) < 0.05
    var_y = (cut * (yy - cy) ** 2).sum() / total
    assert var_y == pytest.approx(a1.psf_sigma_px ** 2 + length ** 2 / 12.0, rel=0.03)
    assert total * a1.gain_e_per_adu == pytest.approx(frame.stars.signal_e[0], rel=0.02)


def test_seed_reproduces_the_frame(a1):
    C = C_icrs_from_sensor(3.0, 0.5, 1.0)
    f1 = simulate_frame(a1, C_icrs_from_sensor=C, seed=5)
    f2 = simulate_frame(a1, C_icrs_from_sensor=C, seed=5)
    f3 = simulate_frame(a1, C_icrs_from_sensor=C, seed=6)
    assert np.array_equal(f1.image, f2.image)
    assert not np.array_equal(f1.image, f3.image)
    f4 = simulate_frame(a1, C_icrs_from_sensor=C)                     # random seed, recorded
    assert isinstance(f4.seed, int)
    assert np.array_equal(simulate_frame(a1, C_icrs_from_sensor=C, seed=f4.seed).image, f4.image)


def test_false_objects_appear_where_placed(a1):
    from shipstar.extract import extract_stars

    objects = random_false_objects(a1, np.random.default_rng(2), planets=3, trails=1, cosmic_rays=5)
    assert objects.planet_xy_px.shape == (3, 2) and objects.trail_xy_px.shape == (1, 2, 2)
    frame = simulate_frame(a1, C_icrs_from_sensor=C_icrs_from_sensor(0.3, 1.2, 0.0), seed=1,
                           false_objects=objects)
    ext = extract_stars(frame.image, gain_e_per_adu=a1.gain_e_per_adu)
    inside = a1.in_image(objects.planet_xy_px, margin_px=5)
    which, dist = _match(objects.planet_xy_px[inside], ext.xy_px, radius_px=1.0)
    assert np.all(which >= 0)
    with pytest.raises(ShipstarError, match="planets"):
        random_false_objects(a1, np.random.default_rng(0), planets=-1)


# --------------------------------------------------------------------------- files

def test_fits_file_header_and_data(tmp_path, orion_frame):
    from astropy.io import fits

    from shipstar.extract import read_image

    fits_path, truth_path = write_frame(orion_frame, tmp_path / "orion.fits")
    assert truth_path == tmp_path / "orion.truth.json" == truth_path_for(fits_path)
    with fits.open(fits_path) as hdul:
        assert len(hdul) == 1
        hdr, data = hdul[0].header, hdul[0].data
        assert data.dtype == np.uint16 and np.array_equal(data, orion_frame.image)
        # FITS 4.0: DATE-OBS is the start of the exposure; DATE-AVG the (truth) mid-exposure
        assert hdr["DATE-AVG"] == "2024-05-01T00:00:00.000000" and hdr["TIMESYS"] == "UTC"
        assert hdr["DATE-OBS"] == hdr["DATE-BEG"] == "2024-04-30T23:59:59.960000"
        assert hdr["DATE-END"] == "2024-05-01T00:00:00.040000"
        assert hdr["MJD-AVG"] - hdr["MJD-OBS"] == pytest.approx(0.04 / 86400, abs=1e-11)
        assert hdr["EXPTIME"] == pytest.approx(0.08) and hdr["ROWORDER"] == "TOP-DOWN"
        assert hdr["INSTRUME"] == "A1" and hdr["SENSOR"] == "A1"
        assert hdr["SIMSEED"] == 11 and hdr["NSTARS"] == len(orion_frame.stars)
        q = [hdr[k] for k in ("QICRS_W", "QICRS_X", "QICRS_Y", "QICRS_Z")]
        np.testing.assert_allclose(matrix_from_q_wxyz(q), orion_frame.C_icrs_from_sensor, atol=1e-14)
        assert hdul[0].verify_checksum() == 1
    assert np.array_equal(read_image(fits_path), orion_frame.image)
    assert not list(tmp_path.glob("*.tmp")) and not list(tmp_path.glob(".*"))


def test_fits_wcs_agrees_with_the_star_positions(tmp_path, orion_frame):
    from astropy.io import fits
    from astropy.wcs import WCS

    fits_path, _ = write_frame(orion_frame, tmp_path / "w.fits")
    wcs = WCS(fits.getheader(fits_path))
    ra, dec = ra_dec_from_unit(orion_frame.stars.v_ref)
    x, y = wcs.all_world2pix(np.degrees(ra), np.degrees(dec), 0)
    np.testing.assert_allclose(np.column_stack([x, y]), orion_frame.stars.xy_px, atol=1e-6)


def test_truth_json_schema_space(tmp_path, orion_frame):
    _, truth_path = write_frame(orion_frame, tmp_path / "orion.fits")
    truth = read_truth(truth_path)
    assert truth == json.loads(truth_path.read_text())
    assert truth["schema"] == TRUTH_SCHEMA and truth["frame"] == "icrs"
    assert truth["fits_file"] == "orion.fits" and truth["camera_name"] == "A1"
    assert truth["image_sha256"] == image_sha256(orion_frame.image)
    assert truth["utc_mid_exposure"] == "2024-05-01T00:00:00.000000Z"
    assert truth["exposure_s"] == 0.08 and truth["seed"] == 11 and truth["mag_limit"] == 8.0
    assert truth["ra_deg"] == pytest.approx(83.8) and truth["dec_deg"] == pytest.approx(-5.4)
    assert truth["roll_deg"] == pytest.approx(0.3 / DEG2RAD)
    np.testing.assert_allclose(matrix_from_q_wxyz(truth["q_wxyz_icrs_from_sensor"]),
                               truth["C_icrs_from_sensor"], atol=1e-14)
    s = truth["stars"]
    n = truth["n_stars"]
    assert n == len(orion_frame.stars) > 30
    for key in ("hip", "xy_px", "mag", "signal_e", "smear_px", "u_sensor", "v_ref", "ra_deg", "dec_deg"):
        assert len(s[key]) == n, key
    assert np.array_equal(np.array(s["xy_px"]), orion_frame.stars.xy_px)    # exact round trip
    assert s["hip"] == orion_frame.stars.hip.tolist()
    assert "C_hor_from_sensor" not in truth and "heading_deg" not in truth


def test_truth_json_schema_ship(tmp_path, a1):
    frame = simulate_frame(a1, ship=ShipPose.from_deg(46.4746, 0.0, 0.0, 185.0, 40.0, 0.0), utc_iso=DOCK_UTC,
                           site=DOCK_SITE, weather=DOCK_WEATHER, seed=2)
    _, truth_path = write_frame(frame, tmp_path / "dock.fits")
    t = read_truth(tmp_path / "dock.fits")
    assert t["frame"] == "hor" and t["refraction_model"] == "erfa"
    # physical check (conventions.md): the boresight looks at azimuth 231.4746 deg, elevation 40 deg
    assert t["sensor_az_deg"] == pytest.approx(231.4746, abs=1e-9)
    assert t["sensor_el_deg"] == pytest.approx(40.0, abs=1e-9)
    assert t["heading_deg"] == pytest.approx(46.4746) and t["install_az_deg"] == pytest.approx(185.0)
    assert t["pitch_deg"] == 0.0 and t["ship_roll_deg"] == 0.0
    np.testing.assert_allclose(np.array(t["C_hor_from_deck"]) @ np.array(t["C_deck_from_sensor"]),
                               t["C_hor_from_sensor"], atol=1e-15)
    np.testing.assert_allclose(t["C_deck_from_sensor"], C_deck_from_sensor(185 * DEG2RAD, 40 * DEG2RAD, 0.0))
    assert t["site"]["lat_deg"] == pytest.approx(31.9) and t["weather"]["pressure_hpa"] == 1021.7
    assert t["eop"]["quality"] == "measured"
    s = t["stars"]
    assert s["ref_frame"] == "hor" and len(s["el_deg"]) == t["n_stars"] > 30
    assert min(s["refraction_arcsec"]) > 50.0                          # ~ 60-80'' at 32-48 deg
    np.testing.assert_allclose(unit_from_az_el(np.radians(s["az_deg"]), np.radians(s["el_deg"])), s["v_ref"],
                               atol=1e-12)


def test_truth_of_another_image_is_detected(tmp_path, a1, orion_frame):
    write_frame(orion_frame, tmp_path / "x.fits")
    other = simulate_frame(a1, C_icrs_from_sensor=np.eye(3), seed=1)
    from astropy.io import fits

    fits.PrimaryHDU(other.image).writeto(tmp_path / "x.fits", overwrite=True)
    with pytest.raises(ShipstarError, match="does not describe"):
        read_truth(tmp_path / "x.truth.json")
    (tmp_path / "y.truth.json").write_text('{"schema": "other"}')
    with pytest.raises(ShipstarError, match="not a shipstar truth file"):
        read_truth(tmp_path / "y.truth.json")


def test_icrs_attitude_seen_from_a_site(a1):
    C = C_icrs_from_sensor(83.8 * DEG2RAD, -5.4 * DEG2RAD, 0.0)
    frame = simulate_frame(a1, C_icrs_from_sensor=C, utc_iso=DOCK_UTC, site=DOCK_SITE, seed=4)
    assert frame.frame == "hor" and frame.refraction_model == "erfa"
    np.testing.assert_allclose(frame.C_hor_from_sensor, frame.context.C_hor_from_icrs_approx @ C, atol=1e-15)
    space = simulate_stars(a1, C, epoch_jyear=frame.epoch_jyear)
    common, i, j = np.intersect1d(frame.stars.hip, space.hip, return_indices=True)
    shift = np.hypot(*(frame.stars.xy_px[i] - space.xy_px[j]).T) * a1.pixel_scale_arcsec
    # aberration residual (< 21'') plus refraction at ~ 40-50 deg (~ 50-70'')
    assert 30.0 < np.median(shift) < 120.0


# --------------------------------------------------------------------------- bad input

@pytest.mark.parametrize("kwargs, message", [
    (dict(C_icrs_from_sensor=np.diag([1.0, 1.0, -1.0])), "not a rotation"),
    (dict(C_icrs_from_sensor=np.eye(3) * 1.01), "not a rotation"),
    (dict(C_icrs_from_sensor=np.eye(2)), "3x3"),
    (dict(C_icrs_from_sensor=np.eye(3), C_hor_from_sensor=np.eye(3)), "exactly one"),
    (dict(), "exactly one"),
    (dict(C_hor_from_sensor=np.eye(3), utc_iso=DOCK_UTC), "needs a site"),
    (dict(C_hor_from_sensor=np.eye(3), site=DOCK_SITE), "time"),
    (dict(C_icrs_from_sensor=np.eye(3), weather=DOCK_WEATHER), "weather needs a site"),
    (dict(C_icrs_from_sensor=np.eye(3), mag_limit=float("nan")), "mag_limit"),
    (dict(C_icrs_from_sensor=np.eye(3), seed=-1), "seed"),
    (dict(C_icrs_from_sensor=np.eye(3), utc_iso="2013-13-01T00:00:00"), "2013-13-01"),
    (dict(C_icrs_from_sensor=np.eye(3), omega_sensor_rad_per_s=[1.0, 2.0]), "omega"),
    (dict(C_icrs_from_sensor=np.eye(3), omega_sensor_rad_per_s=[np.nan, 0, 0]), "omega"),
    (dict(ship=A1_POSE, utc_iso=DOCK_UTC, site=DOCK_SITE, refraction_model="magic"), "refraction model"),
])
def test_bad_input_is_refused(a1, kwargs, message):
    with pytest.raises(ShipstarError, match=message):
        simulate_frame(a1, **kwargs)


def test_bad_objects_are_refused(a1, dock_context):
    with pytest.raises(ShipstarError, match="Camera"):
        simulate_stars("A1", np.eye(3))
    with pytest.raises(ShipstarError, match="FrameContext"):
        simulate_stars_horizontal(a1, np.eye(3), object())
    with pytest.raises(ShipstarError, match="pitch"):
        ShipPose.from_deg(0.0, 95.0, 0.0, 0.0, 0.0)
    with pytest.raises(ShipstarError, match="finite"):
        ShipPose.from_deg(float("inf"), 0.0, 0.0, 0.0, 0.0)
    with pytest.raises(ShipstarError, match="SimulatedStars"):
        render(a1, np.zeros((3, 2)), np.random.default_rng(0))
    with pytest.raises(ShipstarError, match="SimulatedFrame"):
        write_frame("frame", "x.fits")
    with pytest.raises(ShipstarError, match="no truth file"):
        read_truth("/nonexistent/dir/x.truth.json")


def test_subset_and_types(orion_frame):
    stars = orion_frame.stars
    assert isinstance(stars, SimulatedStars) and isinstance(orion_frame.false_objects, FalseObjects)
    top = stars.subset(stars.mag < 5)
    assert len(top) == int(np.sum(stars.mag < 5)) and top.ref_frame == "icrs"
    assert stars.hip.dtype == np.int64 and stars.xy_px.shape == (len(stars), 2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_allclose(np.linalg.norm(stars.u_sensor, axis=1), 1.0, atol=1e-14)
