"""Deep matching (shipstar.identify.deep_match) against truth.

Centroid-level scenes: the deep catalog's stars projected by camera A1 at a known
attitude (``shipstar.simulate.simulate_stars``), with Gaussian centroid noise of a
known sigma per star.  Image-level frames: ``simulate_frame`` -> ``extract_stars``.
References: the simulated truth (which star made each detection, the true attitude),
``shipstar.attitude.solve_attitude`` (the weighted solution deep matching must equal),
and a Monte Carlo of the chance model.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from shipstar.errors import ShipstarError
from shipstar.frames import C_icrs_from_sensor, ra_dec_from_unit, rotation_angle_rad
from shipstar.identify import DeepMatch, deep_catalog, deep_match, identify_lost_in_space
from shipstar.identify._result import failed_identification
from shipstar.simulate import simulate_stars
from shipstar.units import ASEC2RAD, DEG2RAD, RAD2ASEC

EPOCH = 2025.0


@pytest.fixture(scope="module")
def deep_cat(db_a1):
    return deep_catalog(db_a1)


def sigma_model_px(mag):
    """Centroid error of A1 stars (the extraction's Cramer-Rao sigmas of simulated frames,
    0.011 px at Hp 5.5 to 0.055 px at Hp 7.8) with a 0.02 px floor."""
    return np.hypot(0.011 * 10.0 ** (0.3 * (np.asarray(mag) - 5.5)), 0.02)


def scene(cam, catalog, C, rng, *, mag_max=9.0):
    """``(xy_px (N, 2) noisy, brightest first; sigma_px (N,); truth hip (N,))``."""
    stars = simulate_stars(cam, C, epoch_jyear=EPOCH, catalog=catalog, mag_limit=mag_max)
    sig = sigma_model_px(stars.mag)
    xy = stars.xy_px + rng.normal(0.0, 1.0, stars.xy_px.shape) * sig[:, None]
    return xy, sig, np.asarray(stars.hip)


def attitudes(n, seed):
    rng = np.random.default_rng(seed)
    return C_icrs_from_sensor(rng.uniform(0, 2 * np.pi, n), np.arcsin(rng.uniform(-0.9, 0.9, n)),
                              rng.uniform(0, 2 * np.pi, n))


def identify(xy, db, cam):
    idn = identify_lost_in_space(xy, db, camera=cam)
    assert idn.solved, idn.reason
    return idn


# ------------------------------------------------------------------------------------
# Star lists
# ------------------------------------------------------------------------------------

def test_adds_stars_without_changing_the_identification(cam_a1, db_a1, deep_cat):
    """A correct identification's stars keep their names; every added star is the truth's."""
    rng = np.random.default_rng(11)
    for C in attitudes(8, 3):
        xy, sig, hip_true = scene(cam_a1, deep_cat, C, rng)
        idn = identify(xy, db_a1, cam_a1)
        ident = idn.hip >= 0
        assert np.all(idn.hip[ident] == hip_true[ident])            # a correct identification
        dm = deep_match(xy, sig, idn, deep_cat, epoch_jyear=EPOCH, camera=cam_a1)
        assert isinstance(dm, DeepMatch) and dm.solved, dm.reason
        assert np.array_equal(dm.hip[ident], idn.hip[ident])
        assert not np.any(dm.added & ident)
        assert np.array_equal(dm.hip[dm.added], hip_true[dm.added])
        assert dm.n_identified == ident.sum() and dm.n_matched == dm.n_identified + dm.n_added
        # all but a few of the unidentified stars are named (a gate holds 4 sigma: 99.97 %)
        assert dm.n_added >= 0.95 * (len(xy) - ident.sum())
        assert dm.n_matched > 2 * dm.n_identified
        assert dm.nonrigid.tolist() == [[0.0, 0.0], [0.0, 0.0]]    # rigid "space" geometry
        assert dm.expected_chance <= 0.01


def _catalog_with(catalog, extra_hip, u_icrs, mag):
    """``catalog`` plus one star at the ICRS direction ``u_icrs`` (no motion)."""
    from shipstar.sky.catalog import StarCatalog

    ra, dec = ra_dec_from_unit(u_icrs)
    names = ("ra_rad", "dec_rad", "pm_ra_cosdec_mas_per_yr", "pm_dec_mas_per_yr", "parallax_mas", "mag",
             "b_v", "rv_km_s")
    extra = dict(ra_rad=ra, dec_rad=dec, pm_ra_cosdec_mas_per_yr=0.0, pm_dec_mas_per_yr=0.0,
                 parallax_mas=1e-3, mag=mag, b_v=0.5, rv_km_s=0.0)
    return StarCatalog(hip=np.append(catalog.hip, extra_hip),
                       **{k: np.append(getattr(catalog, k), extra[k]) for k in names})


def test_ambiguous_pairs_are_rejected(cam_a1, db_a1, deep_cat):
    """A false detection next to a faint star's own detection, and a detection with two
    catalog stars in its gate, are left unmatched; the other faint stars are matched."""
    rng = np.random.default_rng(5)
    C = C_icrs_from_sensor(1.2, 0.35, 0.4)
    xy, sig, hip_true = scene(cam_a1, deep_cat, C, rng)
    idn0 = identify(xy, db_a1, cam_a1)
    faint = np.flatnonzero((idn0.hip < 0) & (np.hypot(xy[:, 0] - 512, xy[:, 1] - 512) < 400))
    f, g = faint[-1], faint[-2]
    # (1) a false detection 0.7 sigma from star f's detection: two detections in f's gate
    xy1 = np.vstack([xy, xy[f] + [0.7 * sig[f], 0.0]])
    sig1 = np.append(sig, sig[f])
    idn = identify(xy1, db_a1, cam_a1)
    dm = deep_match(xy1, sig1, idn, deep_cat, epoch_jyear=EPOCH, camera=cam_a1)
    assert dm.hip[f] == -1 and dm.hip[-1] == -1
    assert dm.n_ambiguous >= 2
    others = np.setdiff1d(faint, [f])
    assert np.count_nonzero(dm.hip[others] == hip_true[others]) >= len(others) - 1
    # (2) a second catalog star 0.6 sigma from star g: two catalog stars in g's gate
    row = deep_cat.index_of_hip(hip_true[g])[0]
    u_g = deep_cat.subset([row]).unit_icrs(EPOCH)[0]
    u_new = u_g + 0.6 * sig[g] * cam_a1.pixel_mm / cam_a1.f_mm * C[:, 2]
    crowded = _catalog_with(deep_cat, 9_999_999, u_new / np.linalg.norm(u_new), deep_cat.mag[row] + 0.3)
    dm2 = deep_match(xy, sig, idn0, crowded, epoch_jyear=EPOCH, camera=cam_a1)
    assert dm2.hip[g] == -1 and 9_999_999 not in dm2.hip
    assert dm2.n_ambiguous >= 1
    assert dm2.hip[f] == hip_true[f]                      # alone again: matched


def test_poorly_measured_detections_are_not_paired(cam_a1, db_a1, deep_cat):
    """A detection with sigma above ``max_sigma_px`` (a failed fit, a blend) stays unmatched."""
    rng = np.random.default_rng(12)
    xy, sig, hip_true = scene(cam_a1, deep_cat, attitudes(1, 12)[0], rng)
    idn = identify(xy, db_a1, cam_a1)
    k = np.flatnonzero(idn.hip < 0)[:3]
    sig = sig.copy()
    sig[k] = 0.31
    dm = deep_match(xy, sig, idn, deep_cat, epoch_jyear=EPOCH, camera=cam_a1)
    assert np.all(dm.hip[k] == -1)
    dm = deep_match(xy, sig, idn, deep_cat, epoch_jyear=EPOCH, camera=cam_a1, max_sigma_px=0.5)
    assert np.array_equal(dm.hip[k], hip_true[k])


def test_chance_pairs_follow_the_model(cam_a1, db_a1, deep_cat):
    """Monte Carlo of the chance model: false detections uniform over the image pair with
    undetected catalog stars at the rate ``rho pi g^2`` (rho counted independently: the
    catalog stars projected into the image, per unit tangent-plane area; g the gate,
    4 sigma, or the reported cap)."""
    rng = np.random.default_rng(8)
    scale = cam_a1.pixel_mm / cam_a1.f_mm
    n_false, sig_false_px = 300, 0.7
    observed, expected, reported = 0, 0.0, 0.0
    for C in attitudes(40, 21):
        stars = simulate_stars(cam_a1, C, epoch_jyear=EPOCH, catalog=deep_cat, mag_limit=9.0)
        seen = stars.mag <= 7.5                                 # the sensor detects these only
        xy_true = stars.xy_px[seen]
        sig_true = sigma_model_px(stars.mag[seen])
        xy_false = rng.uniform(0.0, [cam_a1.width_px - 1, cam_a1.height_px - 1], (n_false, 2))
        xy = np.vstack([xy_true + rng.normal(0.0, 1.0, xy_true.shape) * sig_true[:, None], xy_false])
        sig = np.append(sig_true, np.full(n_false, sig_false_px))
        idn = identify(xy, db_a1, cam_a1)
        dm = deep_match(xy, sig, idn, deep_cat, epoch_jyear=EPOCH, camera=cam_a1, max_chance=1.0,
                        max_sigma_px=1.0)
        observed += int(np.count_nonzero(dm.added[-n_false:]))
        rho = np.count_nonzero(~seen) / (cam_a1.width_px * cam_a1.height_px * scale * scale)
        gate = min(4.0 * sig_false_px * dm.sigma_scale * scale, dm.gate_max_arcsec * ASEC2RAD)
        expected += n_false * rho * math.pi * gate * gate
        reported += dm.expected_chance
    # Poisson(expected ~ 30) within 4 sigma; the reported figure is an upper bound
    assert abs(observed - expected) <= 4.0 * math.sqrt(expected)
    assert expected > 15.0 and reported >= expected


# ------------------------------------------------------------------------------------
# Attitude
# ------------------------------------------------------------------------------------

def test_attitude_is_solve_attitude_over_the_matched_stars(cam_a1, db_a1, deep_cat):
    """The attitude is solve_attitude's (sigma_rad per star, outlier rejection)."""
    from shipstar.attitude import solve_attitude

    rng = np.random.default_rng(2)
    scale = cam_a1.pixel_mm / cam_a1.f_mm
    u_cat = deep_cat.unit_icrs(EPOCH)
    for C in attitudes(4, 9):
        xy, sig, _ = scene(cam_a1, deep_cat, C, rng)
        xy[5] += 0.5                                             # a bright star's centroid spoilt
        idn = identify(xy, db_a1, cam_a1)
        dm = deep_match(xy, sig, idn, deep_cat, epoch_jyear=EPOCH, camera=cam_a1)
        m = np.flatnonzero(dm.hip >= 0)
        ref = solve_attitude(dm.u_sensor[m], u_cat[dm.catalog_index[m]],
                             sigma_rad=sig[m] * scale * dm.sigma_scale)
        assert ref.solved
        assert rotation_angle_rad(ref.C_ref_from_body.T @ dm.C_icrs_from_sensor) * RAD2ASEC < 1e-6
        assert np.array_equal(ref.inliers, dm.inliers[m])
        assert dm.nonrigid.tolist() == [[0.0, 0.0], [0.0, 0.0]]
        np.testing.assert_allclose(dm.covariance_rad2, ref.covariance_rad2, rtol=1e-7,
                                   atol=1e-9 * np.abs(ref.covariance_rad2).max())
        assert dm.rms_arcsec == pytest.approx(ref.rms_arcsec, rel=1e-9)
        if idn.hip[5] >= 0:                                      # identified: kept, not used
            assert dm.hip[5] == idn.hip[5] and not dm.inliers[5]


def test_unit_vectors_give_the_same_match(cam_a1, db_a1, deep_cat):
    rng = np.random.default_rng(4)
    xy, sig, _ = scene(cam_a1, deep_cat, attitudes(1, 5)[0], rng)
    idn = identify(xy, db_a1, cam_a1)
    a = deep_match(xy, sig, idn, deep_cat, epoch_jyear=EPOCH, camera=cam_a1)
    b = deep_match(idn.u_sensor, sig, idn, deep_cat, epoch_jyear=EPOCH,
                   pixel_scale_arcsec=cam_a1.pixel_scale_arcsec)
    assert np.array_equal(a.hip, b.hip)
    assert rotation_angle_rad(a.C_icrs_from_sensor.T @ b.C_icrs_from_sensor) * RAD2ASEC < 1e-6
    # an unusable row (NaN, or behind the sensor) is left unmatched, the rest as before
    u = idn.u_sensor.copy()
    k = np.flatnonzero(a.added)[:2]
    u[k[0]] = np.nan
    u[k[1]] = -u[k[1]]
    c = deep_match(u, sig, idn, deep_cat, epoch_jyear=EPOCH, pixel_scale_arcsec=cam_a1.pixel_scale_arcsec)
    assert c.hip[k].tolist() == [-1, -1]
    others = np.setdiff1d(np.arange(len(xy)), k)
    assert np.array_equal(c.hip[others], a.hip[others])


def test_refraction_leaves_a_nonrigid_part_that_is_removed(cam_a1, db_a1, deep_cat):
    """Seed 000's dock (A1 at 39.4 deg elevation): seen rigidly from ICRS, the refracted
    field is compressed toward the zenith (d(rho)/dE up the image, ~7e-4).  Deep matching
    measures that linear part - against a least-squares fit of the true image positions
    to the catalog directions seen with the true attitude, and, physically, against the
    refraction model's derivative (to 20 %: annual aberration adds up to ~1e-4) - removes
    it and names the stars."""
    from shipstar.simulate import ShipPose, simulate_stars_horizontal
    from shipstar.sky.apparent import Site, frame_context
    from shipstar.sky.refraction import Weather, refraction_rad
    from shipstar.sky.time import utc_jd_from_iso

    pose = ShipPose.from_deg(46.4746, 0.0, 0.0, 185.1093, 39.3734, -0.2262)
    weather = Weather(pressure_hpa=1021.7, temperature_c=11.1)
    ctx = frame_context(*utc_jd_from_iso("2013-03-15T12:16:00"), Site(31.9 * DEG2RAD, 120.3 * DEG2RAD))
    stars = simulate_stars_horizontal(cam_a1, pose.C_hor_from_sensor, ctx, weather, "erfa", mag_limit=9.0,
                                      catalog=deep_cat, earth_rotation=False)
    epoch = 2013.2
    # the reference: affine least squares of true positions on rigid predictions
    C_rigid = np.asarray(ctx.C_hor_from_icrs_approx).T @ pose.C_hor_from_sensor
    v = deep_cat.subset(deep_cat.index_of_hip(stars.hip)).unit_icrs(epoch) @ C_rigid
    t_pred = v[:, 1:] / v[:, :1]
    u_true = cam_a1.unproject(stars.xy_px)
    x = np.column_stack([np.ones(len(v)), t_pred])
    beta, *_ = np.linalg.lstsq(x, u_true[:, 1:] / u_true[:, :1] - t_pred, rcond=None)
    s_ref = 0.5 * (beta[1:].T + beta[1:])
    el = 39.3734 * DEG2RAD
    drho = float(refraction_rad(el + 1e-3, weather) - refraction_rad(el - 1e-3, weather)) / 2e-3
    assert s_ref[0, 0] == pytest.approx(drho, rel=0.2)
    # deep matching on noisy centroids
    rng = np.random.default_rng(6)
    sig = sigma_model_px(stars.mag)
    xy = stars.xy_px + rng.normal(0.0, 1.0, stars.xy_px.shape) * sig[:, None]
    idn = identify(xy, db_a1, cam_a1)
    dm = deep_match(xy, sig, idn, deep_cat, epoch_jyear=epoch, camera=cam_a1)
    assert dm.solved
    assert np.array_equal(dm.hip[dm.added], np.asarray(stars.hip)[dm.added])
    assert dm.n_matched >= 0.95 * len(xy)
    np.testing.assert_allclose(dm.nonrigid, s_ref, atol=3e-5)
    noise_arcsec = math.sqrt(2.0 * float(np.mean(sig[dm.inliers] ** 2))) * cam_a1.pixel_scale_arcsec
    assert dm.rms_arcsec < 1.3 * noise_arcsec


# ------------------------------------------------------------------------------------
# Accuracy at image level, against truth
# ------------------------------------------------------------------------------------

@pytest.mark.slow
def test_accuracy_gain_at_the_dock(cam_a1, db_a1, deep_cat):
    """50 image-level frames at seed 000's dock: the pipeline's horizontal attitude
    (per-star refraction, weights sigma^-2) from the deep-matched stars against the same
    from the identified stars only.  Centroids carry a 0.03 px error floor (independent
    per star: pixel response, PSF and calibration residuals; the renderer has none) and
    the weights its sigma, as the pipeline's ``centroid_floor_px``.  The RMS error about
    the boresight (roll) and across it must both drop by at least 1.15x; no added star
    may be a wrong one."""
    from shipstar.attitude import sensor_attitude_hor_from_catalog
    from shipstar.extract import extract_stars
    from shipstar.simulate import ShipPose, simulate_frame
    from shipstar.sky.apparent import Site
    from shipstar.sky.refraction import Weather
    from shipstar.sky.time import iso_from_utc_jd, utc_jd_from_iso

    pose = ShipPose.from_deg(46.4746, 0.0, 0.0, 185.1093, 39.3734, -0.2262)
    site, weather = Site(31.9 * DEG2RAD, 120.3 * DEG2RAD), Weather(pressure_hpa=1021.7, temperature_c=11.1)
    jd1, jd2 = utc_jd_from_iso("2013-03-15T12:16:00")
    rng = np.random.default_rng(50)
    errors = {"before": [], "after": []}
    for k in range(50):
        sim = simulate_frame(cam_a1, ship=pose, utc_iso=iso_from_utc_jd(jd1, jd2 + 0.1 * k / 86400.0, 6),
                             site=site, weather=weather, mag_limit=9.0, seed=500 + k)
        ex = extract_stars(sim.image, psf_sigma_px=cam_a1.psf_sigma_px, gain_e_per_adu=cam_a1.gain_e_per_adu)
        sig = np.hypot(np.where(np.isfinite(ex.xy_sigma_px), ex.xy_sigma_px, 1.0), 0.03)
        xy = ex.xy_px + rng.normal(0.0, 0.03, ex.xy_px.shape)
        idn = identify(xy, db_a1, cam_a1)
        dm = deep_match(xy, sig, idn, deep_cat, epoch_jyear=sim.epoch_jyear, camera=cam_a1)
        d = np.linalg.norm(sim.stars.xy_px[:, None, :] - xy[None, dm.added, :], axis=2)
        assert np.array_equal(sim.stars.hip[np.argmin(d, axis=0)], dm.hip[dm.added])
        for key, rows in (("before", idn.hip >= 0), ("after", dm.hip >= 0)):
            h = sensor_attitude_hor_from_catalog(dm.u_sensor[rows], dm.hip[rows], deep_cat, sim.context, weather,
                                                 weights=sig[rows] ** -2.0)
            e = sim.C_hor_from_sensor.T @ h.C_hor_from_sensor
            errors[key].append(0.5 * np.array([e[2, 1] - e[1, 2], e[0, 2] - e[2, 0], e[1, 0] - e[0, 1]]))
    before, after = (np.sqrt(np.mean(np.square(errors[k]), axis=0)) for k in ("before", "after"))
    assert before[0] / after[0] >= 1.15                                       # roll
    assert math.hypot(before[1], before[2]) / math.hypot(after[1], after[2]) >= 1.15
    assert after[0] * RAD2ASEC < 4.0 and math.hypot(after[1], after[2]) * RAD2ASEC < 0.5


# ------------------------------------------------------------------------------------
# Failures and bad input
# ------------------------------------------------------------------------------------

def test_unsolved_identification_gives_unsolved_result(cam_a1, deep_cat):
    xy = np.array([[10.0, 10.0], [500.0, 500.0]])
    idn = failed_identification(2, "lost_in_space", "only 2 usable stars")
    dm = deep_match(xy, [0.1, 0.1], idn, deep_cat, epoch_jyear=EPOCH, camera=cam_a1)
    assert not dm.solved and "only 2 usable stars" in dm.reason
    assert dm.hip.tolist() == [-1, -1] and np.all(np.isnan(dm.C_icrs_from_sensor))
    assert math.isnan(dm.ra_dec_roll_deg[0])


def test_bad_input_raises(cam_a1, db_a1, deep_cat):
    rng = np.random.default_rng(1)
    xy, sig, _ = scene(cam_a1, deep_cat, attitudes(1, 1)[0], rng)
    idn = identify(xy, db_a1, cam_a1)
    ok = dict(epoch_jyear=EPOCH, camera=cam_a1)
    cases = [
        ((xy[:-1], sig, idn, deep_cat), ok, "shape"),
        ((xy, sig[:-1], idn, deep_cat), ok, "sigma_px must have shape"),
        ((xy, np.where(np.arange(len(sig)) == 3, np.nan, sig), idn, deep_cat), ok, "finite and > 0"),
        ((xy, sig, idn, deep_cat), dict(epoch_jyear=EPOCH), "need the camera"),
        ((idn.u_sensor, sig, idn, deep_cat), dict(epoch_jyear=EPOCH), "pixel_scale_arcsec"),
        ((xy, sig, "idn", deep_cat), ok, "must be an Identification"),
        ((xy, sig, idn, db_a1), ok, "must be a StarCatalog"),
        ((xy, sig, idn, deep_cat), dict(ok, epoch_jyear=2460000.5), "Julian year"),
        ((xy, sig, idn, deep_cat), dict(ok, gate_sigma=0.1), "gate_sigma"),
        ((xy, sig, idn, deep_cat), dict(ok, max_chance=0.0), "max_chance"),
        ((xy, sig, idn, deep_cat), dict(ok, max_sigma_px=-1.0), "max_sigma_px"),
        ((xy, sig, idn, deep_cat.subset(deep_cat.mag > 7.0)), ok, "lacks identified stars"),
    ]
    for args, kwargs, message in cases:
        with pytest.raises(ShipstarError, match=message):
            deep_match(*args, **kwargs)
    with pytest.raises(ShipstarError, match="StarDatabase"):
        deep_catalog(deep_cat)


def test_deep_catalog_holds_every_database_star(db_a1, deep_cat):
    assert deep_cat.mag.max() <= 9.0 and len(deep_cat) > 70_000
    deep_cat.index_of_hip(db_a1.hip)                     # raises if one is missing
    assert not np.isin(9_999_999, deep_cat.hip)


def test_arcsec_units(cam_a1, db_a1, deep_cat):
    """Reported figures are in the units their names say."""
    rng = np.random.default_rng(3)
    xy, sig, _ = scene(cam_a1, deep_cat, attitudes(1, 2)[0], rng)
    dm = deep_match(xy, sig, identify(xy, db_a1, cam_a1), deep_cat, epoch_jyear=EPOCH, camera=cam_a1)
    # the solution's RMS residual matches the centroid noise (2-D: sqrt(2) sigma), in arcsec
    noise_arcsec = math.sqrt(2.0 * float(np.mean(sig[dm.inliers] ** 2))) * cam_a1.pixel_scale_arcsec
    assert 0.7 * noise_arcsec < dm.rms_arcsec < 1.3 * noise_arcsec
    assert math.isinf(dm.gate_max_arcsec) or dm.gate_max_arcsec > 0.1 * cam_a1.pixel_scale_arcsec
    assert np.sqrt(np.diag(dm.covariance_rad2))[1] * RAD2ASEC < 1.0
