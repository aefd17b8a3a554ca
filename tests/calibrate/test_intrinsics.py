"""Intrinsic calibration from star frames (issue 6, seed 002).

Truth: the seed 002 camera preset (Tab. 1 "improved sine" parameters).  Frames: the
simulator's star positions (shipstar.simulate.simulate_stars_horizontal: apparent places
and refraction at a ground site), plus Gaussian centroid noise drawn here.  References
the calibration is checked against: the truth camera, the noise floor computed here with
the true camera and numpy only, astropy (apparent places), and the simulator.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from shipstar.calibrate.intrinsics import (
    DISTORTION_TERMS,
    PARAM_NAMES,
    CalibrationFrame,
    calibrate_intrinsics,
    calibration_frame,
    interstar_rms_rad,
    load_calibration_frames,
    plot_residuals,
    reference_directions,
)
from shipstar.camera import Distortion, camera_preset
from shipstar.errors import ShipstarError
from shipstar.frames import C_hor_from_deck
from shipstar.sky.apparent import Site, frame_context
from shipstar.sky.refraction import Weather
from shipstar.sky.time import iso_from_utc_jd, utc_jd_from_iso
from shipstar.units import ASEC2RAD, DEG2RAD

SITE = Site.from_deg(28.2, 112.9, 60.0)          # Changsha (seed 002's university)
WEATHER = Weather(pressure_hpa=1008.0, temperature_c=12.0)
NIGHT = "2024-03-15T13:00:00"                    # 21:00 local; measured EOP
NOISE_PX = 0.1


@pytest.fixture(scope="module")
def truth():
    return camera_preset("seed002")


def _sky(truth, *, n=20, seed=0, el_deg=(45.0, 85.0), mag_limit=9.0, min_stars=8):
    """True star positions of ``n`` ground frames (one every 10 min from NIGHT)."""
    from shipstar.simulate import simulate_stars_horizontal

    rng = np.random.default_rng(seed)
    jd1, jd2 = utc_jd_from_iso(NIGHT)
    out = []
    k = 0
    while len(out) < n:
        k += 1
        t2 = jd2 + k * 600.0 / 86400.0
        ctx = frame_context(jd1, t2, SITE)
        C = C_hor_from_deck(rng.uniform(0, 2 * np.pi), rng.uniform(*el_deg) * DEG2RAD,
                            rng.uniform(-np.pi, np.pi))
        st = simulate_stars_horizontal(truth, C, ctx, WEATHER, mag_limit=mag_limit)
        ok = truth.in_image(st.xy_px, margin_px=2.0)
        if ok.sum() >= min_stars:
            out.append(dict(xy=st.xy_px[ok], hip=st.hip[ok], jd=(jd1, t2), v_sim=st.v_ref[ok]))
    return out


def _frames(sky, *, noise_px=NOISE_PX, seed=1, refraction_model="erfa", camera_name="seed002"):
    rng = np.random.default_rng(seed)
    frames = []
    for k, s in enumerate(sky):
        if "v_ref" not in s or s.get("model") != refraction_model:
            s["v_ref"] = calibration_frame(s["xy"], s["hip"], s["jd"], site=SITE, weather=WEATHER,
                                           refraction_model=refraction_model).v_ref
            s["model"] = refraction_model
        xy = s["xy"] + rng.normal(0.0, noise_px, s["xy"].shape)
        frames.append(CalibrationFrame(xy, s["v_ref"], s["hip"], f"frame{k:02d}", camera_name,
                                       (1920, 2560)))
    return frames


@pytest.fixture(scope="module")
def sky(truth):
    return _sky(truth)


@pytest.fixture(scope="module")
def frames(sky):
    return _frames(sky)


def _start(truth, sign=1.0):
    """f 2 % off, principal point 30 px off, no distortion."""
    return truth.replace(f_mm=truth.f_mm * (1 + 0.02 * sign), x0_px=truth.x0_px + 30 * sign,
                         y0_px=truth.y0_px - 30 * sign, distortion=Distortion())


def _true_values(camera):
    d = camera.distortion.as_dict()
    return {"f_mm": camera.f_mm, "x0_px": camera.x0_px, "y0_px": camera.y0_px, **d}


def _z_scores(cal, truth):
    tv = _true_values(truth)
    return {n: (v - tv[n]) / cal.sigma[n] for n, v in cal.values.items()}


def _noise_floor_rad(frames, truth):
    """RMS interstar-angle error the TRUE camera leaves on the noisy centroids
    (numpy only: Camera.unproject and arccos/arctan2 of the pairs)."""
    errs = []
    for fr in frames:
        w = truth.unproject(fr.xy_px)
        i, j = np.triu_indices(len(w), 1)
        ang_w = np.arctan2(np.linalg.norm(np.cross(w[i], w[j]), axis=1), np.sum(w[i] * w[j], 1))
        v = fr.v_ref
        ang_v = np.arctan2(np.linalg.norm(np.cross(v[i], v[j]), axis=1), np.sum(v[i] * v[j], 1))
        errs.append(ang_w - ang_v)
    e = np.concatenate(errs)
    return float(np.sqrt(np.mean(e * e)))


# ---------------------------------------------------------------------------------------
# Reference directions
# ---------------------------------------------------------------------------------------

def test_reference_directions_equal_the_simulators_observed_directions(sky):
    for s in sky[:5]:
        v = reference_directions(s["hip"], *s["jd"], site=SITE, weather=WEATHER)
        ang = np.arctan2(np.linalg.norm(np.cross(v, s["v_sim"]), axis=1), np.sum(v * s["v_sim"], 1))
        assert ang.max() < 1e-3 * ASEC2RAD


def test_refraction_lifts_each_star_by_its_own_refraction(sky):
    from shipstar.frames import az_el_from_unit
    from shipstar.sky.refraction import refraction_rad

    s = sky[0]
    v_true = reference_directions(s["hip"], *s["jd"], site=SITE, refraction_model="none")
    v_obs = reference_directions(s["hip"], *s["jd"], site=SITE, weather=WEATHER)
    az0, el0 = az_el_from_unit(v_true)
    az1, el1 = az_el_from_unit(v_obs)
    np.testing.assert_allclose(el1 - el0, refraction_rad(el1, WEATHER), atol=1e-4 * ASEC2RAD)
    np.testing.assert_allclose(az1, az0, atol=1e-9)


def test_geocentric_apparent_interstar_angles_match_astropy():
    """No site: geocentric apparent places; their interstar angles against astropy's GCRS
    (proper motion applied with apply_space_motion), and clearly not the catalog's."""
    from astropy import units as u
    from astropy.coordinates import GCRS, SkyCoord
    from astropy.time import Time
    from astropy.utils import iers

    from shipstar.sky.catalog import navigation_catalog

    cat = navigation_catalog(4.0)
    idx = np.arange(0, len(cat), max(1, len(cat) // 40))[:40]
    sub = cat.subset(idx)
    iso = "2024-09-01T00:00:00"
    v = reference_directions(sub.hip, *utc_jd_from_iso(iso), catalog=cat)
    with iers.conf.set_temp("auto_download", False), iers.conf.set_temp("auto_max_age", None):
        c = SkyCoord(ra=sub.ra_rad * u.rad, dec=sub.dec_rad * u.rad,
                     pm_ra_cosdec=sub.pm_ra_cosdec_mas_per_yr * u.mas / u.yr,
                     pm_dec=sub.pm_dec_mas_per_yr * u.mas / u.yr,
                     distance=(1000.0 / np.maximum(sub.parallax_mas, 1e-3)) * u.pc,
                     radial_velocity=sub.rv_km_s * u.km / u.s, obstime=Time("J2000.0", scale="tdb"))
        t = Time(iso, scale="utc")
        g = c.apply_space_motion(new_obstime=t).transform_to(GCRS(obstime=t))
    ref = g.cartesian.xyz.value.T
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    i, j = np.triu_indices(len(v), 1)

    def angles(x):
        return np.arctan2(np.linalg.norm(np.cross(x[i], x[j]), axis=1), np.sum(x[i] * x[j], 1))

    assert np.abs(angles(v) - angles(ref)).max() < 1e-3 * ASEC2RAD          # < 1 mas
    cat_dirs = reference_directions(sub.hip, *utc_jd_from_iso(iso), catalog=cat, places="catalog")
    assert np.abs(angles(v) - angles(cat_dirs)).max() > 5.0 * ASEC2RAD       # aberration is real


def test_catalog_places_are_proper_motion_only():
    from shipstar.sky.catalog import navigation_catalog

    cat = navigation_catalog(3.0)
    hip = cat.hip[:10]
    jd = utc_jd_from_iso("2010-01-01T00:00:00")
    v = reference_directions(hip, *jd, catalog=cat, places="catalog")
    epoch = 2000.0 + (jd[0] - 2451545.0 + jd[1]) / 365.25
    np.testing.assert_allclose(v, cat.subset(np.arange(10)).unit_icrs(epoch), atol=1e-14)
    with pytest.raises(ShipstarError, match="places"):
        reference_directions(hip, *jd, catalog=cat, places="mean")
    with pytest.raises(ShipstarError, match="catalog places"):
        reference_directions(hip, *jd, catalog=cat, places="catalog", site=SITE)


# ---------------------------------------------------------------------------------------
# Observation equations
# ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["cosine", "sine", "angle", "star"])
def test_derivatives_match_finite_differences(frames, truth, kind):
    """``A = dr/dtheta`` and ``G = dr/dxy`` of every kind of equation, by central
    differences."""
    from shipstar.calibrate._intrinsics_model import ParamSpace
    from shipstar.calibrate._intrinsics_pairs import StarSet, evaluate, tangent_basis
    from shipstar.calibrate._intrinsics_solve import initial_attitudes

    space = ParamSpace.for_camera(truth, PARAM_NAMES)
    theta = space.values(truth)
    stars = StarSet.build([(fr.xy_px, fr.v_ref) for fr in frames[:3]])
    att = initial_attitudes(stars, truth) if kind == "star" else None

    def r_of(st, th, free=()):
        bases = tangent_basis(st.v_ref) if kind == "star" else None
        return evaluate(st, space.full(th), truth.pixel_mm, free, kind, att, bases)

    e0 = r_of(stars, theta, space.free)
    for k, h in enumerate(space.scales * 1e-2):
        step = np.zeros_like(theta)
        step[k] = h
        num = (r_of(stars, theta + step).r - r_of(stars, theta - step).r) / (2 * h)
        assert np.abs(num - e0.A[:, k]).max() <= 1e-4 * np.abs(e0.A[:, k]).max()
    G = e0.frame_G(1)
    rows = e0.frame_rows(1)
    xy0, v0 = stars.frame(1)
    for col in range(G.shape[1]):
        d = np.zeros_like(xy0)
        d.flat[col] = 1e-2

        def moved(sign):
            parts = [stars.frame(f) for f in range(3)]
            parts[1] = (xy0 + sign * d, v0)
            return r_of(StarSet.build(parts), theta).r[rows]

        num = (moved(1) - moved(-1)) / 2e-2
        assert np.abs(num - G[:, col]).max() <= 1e-4 * np.abs(G).max()


def test_interstar_rms_is_zero_for_exact_data_and_linear_in_a_scale_error(sky, truth):
    exact = _frames(sky, noise_px=0.0)
    assert interstar_rms_rad(exact, truth) < 1e-11
    r1 = interstar_rms_rad(exact, truth.replace(f_mm=truth.f_mm * (1 + 1e-4)))
    r2 = interstar_rms_rad(exact, truth.replace(f_mm=truth.f_mm * (1 + 2e-4)))
    assert r1 > 1e-7
    assert r2 / r1 == pytest.approx(2.0, rel=1e-3)


# ---------------------------------------------------------------------------------------
# Acceptance: seed 002 camera, 0.1 px, 20 frames, start 2 % / 30 px off
# ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def calibrations(frames, truth):
    start = _start(truth)
    return {m: calibrate_intrinsics(frames, start, method=m, terms="all", check_terms=(m == "joint"))
            for m in ("sine", "cosine", "joint")}


@pytest.mark.parametrize("method", ["sine", "cosine", "joint"])
def test_recovers_the_seed002_camera_within_3_sigma(calibrations, truth, method):
    cal = calibrations[method]
    assert cal.solved, cal.reason
    assert cal.fitted == PARAM_NAMES
    z = _z_scores(cal, truth)
    assert max(abs(v) for v in z.values()) < 3.0, z
    # the uncertainties are meaningful, not inflated: f to ~4e-5 relative, pp to ~10 px
    assert cal.sigma["f_mm"] < 2e-4 * truth.f_mm
    assert cal.sigma["x0_px"] < 20 and cal.sigma["y0_px"] < 20
    assert cal.centroid_sigma_px == pytest.approx(NOISE_PX, rel=0.1)


@pytest.mark.parametrize("method", ["sine", "cosine", "joint"])
def test_interstar_rms_after_calibration_is_at_the_noise_floor(calibrations, frames, truth, method):
    cal = calibrations[method]
    floor = _noise_floor_rad(frames, truth)
    assert abs(cal.rms_after_rad / floor - 1.0) < 0.10
    assert cal.rms_before_rad > 10 * floor                    # the start camera was far off
    assert cal.rms_after_arcsec == pytest.approx(cal.rms_after_rad / ASEC2RAD)
    assert (cal.n_frames, cal.n_stars) == (20, sum(len(f) for f in frames))


def test_correlations_are_a_valid_correlation_matrix(calibrations):
    for cal in calibrations.values():
        c = cal.correlation
        np.testing.assert_allclose(np.diag(c), 1.0, atol=1e-9)
        np.testing.assert_allclose(c, c.T, atol=1e-9)
        assert np.linalg.eigvalsh(c).min() > -1e-9
        assert np.abs(c).max() <= 1.0 + 1e-9


@pytest.mark.parametrize("method", ["sine", "joint"])
def test_converges_from_the_other_side(frames, truth, method):
    cal = calibrate_intrinsics(frames, _start(truth, -1.0), method=method, terms="all", check_terms=False)
    assert cal.solved, cal.reason
    assert max(abs(v) for v in _z_scores(cal, truth).values()) < 3.0


def test_joint_on_interstar_angles(frames, truth):
    """``attitudes=False``: the joint fit on the interstar angles (no attitudes)."""
    cal = calibrate_intrinsics(frames, _start(truth), method="joint", attitudes=False,
                               terms="all", check_terms=False)
    assert cal.solved, cal.reason
    assert max(abs(v) for v in _z_scores(cal, truth).values()) < 3.0
    assert cal.centroid_sigma_px == pytest.approx(NOISE_PX, rel=0.1)


def test_robust_joint_ignores_a_misidentified_star(frames, truth):
    """One star per frame for 5 frames swapped with another frame's: the Huber loss keeps
    the calibration within 3 sigma; plain least squares does not."""
    bad = list(frames)
    for k in range(5):
        fr = bad[k]
        v = fr.v_ref.copy()
        v[0] = frames[k + 10].v_ref[0]
        bad[k] = CalibrationFrame(fr.xy_px, v, None, fr.label)
    robust = calibrate_intrinsics(bad, _start(truth), method="joint", terms="all", check_terms=False)
    plain = calibrate_intrinsics(bad, _start(truth), method="joint", robust=False, terms="all",
                                 check_terms=False)
    assert robust.solved and max(abs(v) for v in _z_scores(robust, truth).values()) < 3.0
    assert not plain.solved or max(abs(v) for v in _z_scores(plain, truth).values()) > 10.0


def test_converges_from_the_image_centre(frames, truth):
    """A nominal principal point at the image centre is 210 px from the truth."""
    start = truth.replace(x0_px=1279.5, y0_px=959.5, distortion=Distortion())
    cal = calibrate_intrinsics(frames, start, method="joint", terms="all", check_terms=False)
    assert max(abs(v) for v in _z_scores(cal, truth).values()) < 3.0


def test_joint_uncertainties_match_the_scatter_of_repeated_calibrations(sky, truth):
    """Twelve noise realisations of the same sky: the z-scores of all ten parameters
    have unit variance (chi-square bounds for 120 samples, loosely)."""
    z2 = []
    for seed in range(12):
        cal = calibrate_intrinsics(_frames(sky, seed=100 + seed), _start(truth), method="joint",
                                   terms="all", check_terms=False)
        z2 += [v * v for v in _z_scores(cal, truth).values()]
    assert 0.6 < np.mean(z2) < 1.5


@pytest.mark.slow
def test_sine_uncertainties_match_the_scatter_of_repeated_calibrations(sky, truth):
    z2 = []
    for seed in range(5):
        cal = calibrate_intrinsics(_frames(sky, seed=200 + seed), _start(truth), method="sine",
                                   terms="all", check_terms=False)
        z2 += [v * v for v in _z_scores(cal, truth).values()]
    assert 0.4 < np.mean(z2) < 1.8


def test_seed_plain_methods_are_worse_than_the_improved_ones(frames, truth, calibrations):
    """Seed 002 Tab. 1's ordering: plain cosine/sine (f and principal point only) leave
    the distortion in the residuals; the improved (distortion) methods reach the floor."""
    floor = _noise_floor_rad(frames, truth)
    for method in ("sine", "cosine"):
        plain = calibrate_intrinsics(frames, _start(truth), method=method, terms="none",
                                     check_terms=False)
        assert plain.solved
        assert plain.fitted == ("f_mm", "x0_px", "y0_px")
        assert plain.camera.distortion.is_zero
        assert plain.rms_after_rad > 2.0 * floor
        assert calibrations[method].rms_after_rad < 0.5 * plain.rms_after_rad


# ---------------------------------------------------------------------------------------
# Which distortion terms do the data support?
# ---------------------------------------------------------------------------------------

def test_supported_terms_for_the_seed002_lens(calibrations):
    cal = calibrations["joint"]
    sup = set(cal.supported_distortion_terms)
    # k1 moves the corners by 2.3 px, p and s by ~1-3 px: all clearly supported;
    # k3 moves a corner by 0.04 px: not detectable with 0.1 px noise.
    assert {"k1", "p1", "p2", "s1", "s2"} <= sup
    assert "k3" not in sup
    assert cal.term_delta_chi2["k1"] > 100


def test_auto_terms_on_a_radial_only_lens(truth):
    lens = truth.replace(distortion=Distortion(k1_per_mm2=1.14e-5))
    sky = _sky(lens, n=12, seed=5)
    cal = calibrate_intrinsics(_frames(sky, seed=6), _start(lens), method="joint", terms="auto")
    assert cal.supported_distortion_terms == ("k1",)
    assert cal.fitted == ("f_mm", "x0_px", "y0_px", "k1_per_mm2")
    assert max(abs(v) for v in _z_scores(cal, lens).values()) < 3.0
    assert set(cal.term_delta_chi2) == set(DISTORTION_TERMS)


def test_explicit_terms_by_short_or_field_name(frames, truth):
    a = calibrate_intrinsics(frames, _start(truth), terms=["k1", "s1_per_mm"], check_terms=False)
    b = calibrate_intrinsics(frames, _start(truth), terms="s1,k1", check_terms=False)
    assert a.fitted == b.fitted == ("f_mm", "x0_px", "y0_px", "k1_per_mm2", "s1_per_mm")
    assert a.camera.distortion.p1_per_mm == 0.0
    np.testing.assert_allclose(a.camera.f_mm, b.camera.f_mm, rtol=1e-12)


# ---------------------------------------------------------------------------------------
# Refraction matters on the ground
# ---------------------------------------------------------------------------------------

def test_refraction_must_be_in_the_references_at_low_elevation(truth):
    """At 20-35 deg elevation differential refraction compresses the field vertically
    by ~1e-4: references without it bias the calibration far beyond its uncertainty."""
    sky = _sky(truth, n=14, seed=11, el_deg=(20.0, 35.0))
    good = calibrate_intrinsics(_frames(sky, seed=12), _start(truth), method="joint", terms="all",
                                check_terms=False)
    assert max(abs(v) for v in _z_scores(good, truth).values()) < 3.0
    bad = calibrate_intrinsics(_frames(sky, seed=12, refraction_model="none"), _start(truth),
                               method="joint", terms="all", check_terms=False)
    z = _z_scores(bad, truth)
    assert max(abs(v) for v in z.values()) > 5.0
    assert bad.rms_after_rad > good.rms_after_rad


def test_ground_frames_without_a_site_are_refused(sky, truth):
    """Review finding: frames without a site got unrefracted (geocentric) references
    silently.  calibration_frame records how its references were made; geocentric ones
    pass only with in_space=True, topocentric ones not with it."""
    geo = [calibration_frame(s["xy"], s["hip"], s["jd"], label=f"g{k}") for k, s in enumerate(sky[:12])]
    assert {fr.places for fr in geo} == {"geocentric"}
    with pytest.raises(ShipstarError, match="'g0' has no observing site.*in_space=True"):
        calibrate_intrinsics(geo, _start(truth), terms="none")
    # declared in space it runs (and misses refraction: far worse than the noise floor
    # of ground frames, which is why the declaration is required)
    cal = calibrate_intrinsics(geo, _start(truth), terms="none", in_space=True)
    assert cal.solved and cal.rms_after_arcsec > 1.0
    topo = [calibration_frame(s["xy"], s["hip"], s["jd"], site=SITE, weather=WEATHER, label=f"t{k}")
            for k, s in enumerate(sky[:2])]
    assert topo[0].places == "topocentric"
    with pytest.raises(ShipstarError, match="'t0' has an observing site"):
        calibrate_intrinsics(topo + geo, _start(truth), terms="none", in_space=True)
    cat = calibration_frame(sky[0]["xy"], sky[0]["hip"], sky[0]["jd"], places="catalog")
    assert cat.places == "catalog"
    with pytest.raises(ShipstarError, match="places must be one of"):
        CalibrationFrame(sky[0]["xy"], sky[0]["v_sim"], places="ground")


def test_default_terms_are_the_supported_ones(calibrations, frames, truth):
    """Review finding: terms="all" (the old default) fitted terms the check rejects.  The
    default now fits exactly the supported terms; "all" reports the unsupported fitted."""
    full = calibrations["joint"]
    assert full.terms_checked and full.unsupported_fitted_terms == ("k2", "k3")
    cal = calibrate_intrinsics(frames, _start(truth), method="joint")
    assert cal.terms_checked and cal.unsupported_fitted_terms == ()
    assert cal.fitted_distortion_terms == cal.supported_distortion_terms == full.supported_distortion_terms
    no_check = calibrate_intrinsics(frames, _start(truth), method="joint", terms="k1", check_terms=False)
    assert not no_check.terms_checked and no_check.unsupported_fitted_terms == ()


# ---------------------------------------------------------------------------------------
# Bad input: a clear error, not a number
# ---------------------------------------------------------------------------------------

def test_too_few_stars(frames, truth):
    few = [CalibrationFrame(fr.xy_px[:4], fr.v_ref[:4], fr.hip[:4], fr.label) for fr in frames[:2]]
    with pytest.raises(ShipstarError, match="too few stars"):
        calibrate_intrinsics(few, _start(truth))
    with pytest.raises(ShipstarError, match="no frames"):
        calibrate_intrinsics([], _start(truth))


def test_frames_with_fewer_than_three_stars_are_skipped_not_fatal(frames, truth):
    tiny = CalibrationFrame(frames[0].xy_px[:2], frames[0].v_ref[:2], frames[0].hip[:2], "tiny")
    cal = calibrate_intrinsics(list(frames[:12]) + [tiny], _start(truth), terms="all", check_terms=False)
    assert cal.n_frames == 12


def test_frames_from_different_cameras(frames, truth):
    other = CalibrationFrame(frames[1].xy_px, frames[1].v_ref, frames[1].hip, "x.json", "A1")
    with pytest.raises(ShipstarError, match="different cameras.*'seed002'.*'A1'"):
        calibrate_intrinsics([frames[0], other] + list(frames[2:]), _start(truth))


def test_frame_size_must_match_the_camera(frames, truth):
    wrong = CalibrationFrame(frames[0].xy_px, frames[0].v_ref, frames[0].hip, "a.fits", None, (1024, 1024))
    with pytest.raises(ShipstarError, match="1024x1024 px but camera 'seed002' is 2560x1920"):
        calibrate_intrinsics([wrong] + list(frames[1:]), _start(truth))
    outside = CalibrationFrame(frames[0].xy_px + [3000.0, 0.0], frames[0].v_ref, frames[0].hip, "b")
    with pytest.raises(ShipstarError, match="outside the 2560x1920 image"):
        calibrate_intrinsics([outside] + list(frames[1:]), _start(truth))


def test_degenerate_geometry_all_stars_near_the_centre(truth):
    """Stars only within 150 px of the centre cannot show a distortion growing as r^3..7."""
    rng = np.random.default_rng(3)
    near = []
    for k in range(20):
        xy = np.array([1279.5, 959.5]) + rng.uniform(-150, 150, (20, 2))
        near.append(CalibrationFrame(xy, truth.unproject(xy), None, f"centre{k}"))
    with pytest.raises(ShipstarError, match="degenerate star geometry"):
        calibrate_intrinsics(near, _start(truth))


def test_degenerate_geometry_stars_on_one_line(truth):
    """Every frame's stars on the same image row: nothing constrains the vertical."""
    rng = np.random.default_rng(4)
    frames = []
    for k in range(10):
        xy = np.stack([rng.uniform(50, 2500, 15), np.full(15, 800.0)], 1)
        frames.append(CalibrationFrame(xy, truth.unproject(xy), None, f"line{k}"))
    with pytest.raises(ShipstarError, match="degenerate star geometry"):
        calibrate_intrinsics(frames, _start(truth), terms="k1", check_terms=False)


def test_bad_arguments(frames, truth):
    with pytest.raises(ShipstarError, match="method must be one of"):
        calibrate_intrinsics(frames, truth, method="tangent")
    with pytest.raises(ShipstarError, match="unknown distortion term 'k4'"):
        calibrate_intrinsics(frames, truth, terms="k1,k4")
    with pytest.raises(ShipstarError, match="Camera"):
        calibrate_intrinsics(frames, "seed002")
    with pytest.raises(ShipstarError, match="CalibrationFrame"):
        calibrate_intrinsics([{"xy": 1}], truth)
    with pytest.raises(ShipstarError, match="centroids but"):
        CalibrationFrame(np.zeros((3, 2)), np.ones((4, 3)))
    with pytest.raises(ShipstarError, match="non-finite"):
        CalibrationFrame(np.full((3, 2), np.nan), np.ones((3, 3)))
    with pytest.raises(ShipstarError, match="HIP 7 is listed twice"):
        CalibrationFrame(np.zeros((3, 2)), np.eye(3), np.array([7, 8, 7]))
    with pytest.raises(ShipstarError, match="shape"):
        CalibrationFrame(np.zeros((3, 3)), np.eye(3))


# ---------------------------------------------------------------------------------------
# Files and plots
# ---------------------------------------------------------------------------------------

def _write_star_lists(tmp_path, sky, n=None, xy_keys=("x_px", "y_px"), **extra):
    """Star lists as ``shipstar solve --json`` writes them (``xy_keys=("x", "y")``: as it
    wrote them before), plus a ground site."""
    rng = np.random.default_rng(9)
    kx, ky = xy_keys
    tmp_path.mkdir(parents=True, exist_ok=True)
    for k, s in enumerate(sky[:n]):
        xy = s["xy"] + rng.normal(0, NOISE_PX, s["xy"].shape)
        obj = {"solved": True, "reason": "",
               "stars": [{kx: float(x), ky: float(y), "hip": int(h)} for (x, y), h in zip(xy, s["hip"])],
               "date_obs": iso_from_utc_jd(*s["jd"], 3), "camera": "seed002",
               "width_px": 2560, "height_px": 1920, "lat_deg": 28.2, "lon_deg": 112.9, "height_m": 60.0,
               "pressure_hpa": 1008.0, "temperature_c": 12.0}
        obj.update(extra)
        (tmp_path / f"frame{k:02d}.json").write_text(json.dumps(obj))
    return tmp_path


def test_load_json_star_lists(tmp_path, sky, truth):
    _write_star_lists(tmp_path, sky, 4)
    (tmp_path / "frame99.json").write_text(json.dumps({"solved": False, "reason": "too few stars",
                                                       "stars": []}))
    (tmp_path / "frame00.truth.json").write_text("{}")          # never read as a star list
    loaded = load_calibration_frames(tmp_path, truth)
    assert loaded.kind == "json"
    assert len(loaded.frames) == 4
    assert loaded.skipped == [("frame99.json", "not solved: too few stars")]
    fr = loaded.frames[0]
    assert fr.camera_name == "seed002" and fr.image_shape_hw == (1920, 2560)
    # the ground site in the file: references are the refracted apparent directions
    ang = 2 * np.arcsin(0.5 * np.linalg.norm(fr.v_ref - sky[0]["v_sim"], axis=1))  # exact at tiny angles
    assert ang.max() < 1e-3 * ASEC2RAD
    assert {f.places for f in loaded.frames} == {"topocentric"}


def test_load_json_star_lists_with_the_older_x_y_keys(tmp_path, sky, truth):
    new = load_calibration_frames(_write_star_lists(tmp_path / "new", sky, 2), truth).frames
    old = load_calibration_frames(_write_star_lists(tmp_path / "old", sky, 2, xy_keys=("x", "y")),
                                  truth).frames
    for a, b, s in zip(new, old, sky):
        np.testing.assert_array_equal(a.xy_px, b.xy_px)
        np.testing.assert_array_equal(a.hip, b.hip)
        np.testing.assert_array_equal(a.v_ref, b.v_ref)
        assert np.abs(a.xy_px - s["xy"]).max() < 10 * NOISE_PX     # the positions as written


def test_load_json_null_camera_and_size_are_not_given(tmp_path, sky, truth):
    # what `shipstar solve --fov-deg` writes: "camera": null
    _write_star_lists(tmp_path, sky, 2, camera=None, width_px=None, height_px=None)
    loaded = load_calibration_frames(tmp_path, truth)
    assert [(f.camera_name, f.image_shape_hw) for f in loaded.frames] == [(None, None)] * 2


@pytest.mark.parametrize("date_obs", [None, ""])
def test_load_json_needs_a_time(tmp_path, sky, truth, date_obs):
    _write_star_lists(tmp_path, sky, 2, date_obs=date_obs)
    with pytest.raises(ShipstarError, match="no observation time.*--date-obs"):
        load_calibration_frames(tmp_path, truth)
    loaded = load_calibration_frames(tmp_path, truth, utc=iso_from_utc_jd(*sky[0]["jd"], 3))
    assert len(loaded.frames) == 2


def test_load_json_refuses_date_obs_for_frames_with_their_own_time(tmp_path, sky, truth):
    """--date-obs is for frames that carry no time; it silently replaced a frame's own time
    (f_mm 94.9477 against 94.9388 mm on a bad-input sweep's ten frames)."""
    _write_star_lists(tmp_path, sky, 2)
    with pytest.raises(ShipstarError, match="carries its own time .*--date-obs is for frames that carry none"):
        load_calibration_frames(tmp_path, truth, utc=iso_from_utc_jd(*sky[0]["jd"], 3))
    assert len(load_calibration_frames(tmp_path, truth).frames) == 2


def test_load_errors(tmp_path, truth):
    with pytest.raises(ShipstarError, match="not a directory"):
        load_calibration_frames(tmp_path / "missing", truth)
    with pytest.raises(ShipstarError, match="no frames in"):
        load_calibration_frames(tmp_path, truth)
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ShipstarError, match="not valid JSON"):
        load_calibration_frames(tmp_path, truth)
    for star in ({"x": 1.0}, {"x_px": 1.0, "hip": 5}, {"x": 1.0, "y_px": 2.0}, [1.0, 2.0]):
        (tmp_path / "bad.json").write_text(json.dumps({"stars": [star]}))
        with pytest.raises(ShipstarError, match="star 0 is not an object with .x_px. and .y_px."):
            load_calibration_frames(tmp_path, truth)
    (tmp_path / "bad.json").write_text(json.dumps({"stars": [{"x_px": "1", "y_px": 2.0, "hip": 5}]}))
    with pytest.raises(ShipstarError, match="star 0 x_px must be a finite number"):
        load_calibration_frames(tmp_path, truth)


def test_residual_plot(tmp_path, calibrations):
    from PIL import Image

    path = plot_residuals(calibrations["joint"], tmp_path / "res.png")
    with Image.open(path) as im:
        assert im.size[0] > 1000 and im.size[1] > 400


def test_json_dict_is_plain_json(calibrations):
    d = calibrations["sine"].as_json_dict()
    text = json.dumps(d, allow_nan=False)
    back = json.loads(text)
    assert back["method"] == "sine" and back["solved"] is True
    assert set(back["sigma"]) == set(PARAM_NAMES)
    assert math.isclose(back["rms_after_arcsec"], back["rms_after_rad"] / ASEC2RAD)
    assert len(back["correlation"]) == len(PARAM_NAMES)
