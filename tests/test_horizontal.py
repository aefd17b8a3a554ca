"""Sensor attitude in the horizontal frame (attitude._horizontal), against ERFA and analytic cases."""

from __future__ import annotations

import math

import erfa
import numpy as np
import pytest

from shipstar import frames as F
from shipstar.attitude._horizontal import (
    REFRACTION_MODES,
    boresight_refraction_rad,
    boresight_true_hor,
    reference_hor,
    sensor_attitude_hor,
    sensor_attitude_hor_from_catalog,
)
from shipstar.errors import ShipstarError
from shipstar.sky.refraction import Weather
from shipstar.units import ASEC2RAD, DEG2RAD, RAD2ASEC

DOCK_WEATHER = Weather(pressure_hpa=1021.7, temperature_c=11.1)
#: A1 in dock (seed 000): boresight az ~231.5 deg, el ~39.4 deg.
C_TRUE = F.C_hor_from_deck(46.4746 * DEG2RAD, 0.0, 0.0) @ F.C_deck_from_sensor(185.1093 * DEG2RAD, 39.3734 * DEG2RAD,
                                                                               -0.2262 * DEG2RAD)


def _erfa_observed_el(el_true, weather):
    """Independent refraction: ERFA's refco coefficients, ``rho = A tan z + B tan^3 z`` at the
    OBSERVED zenith distance, solved by fixed-point iteration."""
    a, b = erfa.refco(weather.pressure_hpa, weather.temperature_c, weather.relative_humidity, weather.wavelength_um)
    el = np.array(el_true, float)
    for _ in range(50):
        tz = np.tan(0.5 * np.pi - el)
        el = el_true + a * tz + b * tz ** 3
    return el


def _field(n=25, half_width_deg=3.8, seed=3):
    """Star directions (true, unrefracted) scattered over an 8 deg field around C_TRUE's boresight."""
    rng = np.random.default_rng(seed)
    t = rng.uniform(-1, 1, (n, 2)) * math.tan(half_width_deg * DEG2RAD)
    w = np.column_stack([np.ones(n), t])
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    v_obs = w @ C_TRUE.T                  # where the sensor sees them (observed)
    az, el_obs = F.az_el_from_unit(v_obs)
    # true elevation: invert the independent refraction by bisection-free fixed point
    el_true = el_obs.copy()
    for _ in range(50):
        el_true = el_true + (el_obs - _erfa_observed_el(el_true, DOCK_WEATHER))
    return w, F.unit_from_az_el(az, el_true), v_obs


def test_per_star_recovers_the_attitude_exactly():
    w, v_true, v_obs = _field()
    h = sensor_attitude_hor(w, v_true, DOCK_WEATHER, model="erfa")
    assert h.solved and h.reason == "" and h.n_used == len(w)
    err = F.rotation_angle_rad(h.C_hor_from_sensor.T @ C_TRUE) * RAD2ASEC
    assert err < 1e-3
    np.testing.assert_allclose(h.v_hor, v_obs, atol=1e-3 * ASEC2RAD)
    az, el, roll = h.angles_rad
    a0, e0, r0 = F.installation_angles_from_C_deck_from_sensor(C_TRUE)
    assert abs(az - a0) * RAD2ASEC < 1e-3 and abs(el - e0) * RAD2ASEC < 1e-3 and abs(roll - r0) * RAD2ASEC < 1e-3


def test_reference_vectors_are_lifted_by_refraction():
    """Sign (docs/conventions.md): the sensor's reference is the OBSERVED, higher direction."""
    _, v_true, _ = _field()
    v = reference_hor(v_true, DOCK_WEATHER, model="erfa")
    az0, el0 = F.az_el_from_unit(v_true)
    az1, el1 = F.az_el_from_unit(v)
    np.testing.assert_allclose(az1, az0, atol=1e-12)
    rho = (el1 - el0) * RAD2ASEC
    # ~58'' cot(el) * P/1013 * 283/(273 + t) at 35-44 deg elevation
    expected = (_erfa_observed_el(el0, DOCK_WEATHER) - el0) * RAD2ASEC
    np.testing.assert_allclose(rho, expected, atol=1e-3)
    assert np.all((rho > 55) & (rho < 90))


def test_boresight_mode_lifts_every_star_by_the_boresight_refraction():
    w, v_true, _ = _field()
    bore = boresight_true_hor(w, v_true)
    el_b = math.asin(bore[1])
    rho_b = boresight_refraction_rad(bore, DOCK_WEATHER, "erfa")
    assert rho_b == pytest.approx(float(_erfa_observed_el(el_b, DOCK_WEATHER)) - el_b, abs=1e-4 * ASEC2RAD)
    v = reference_hor(v_true, DOCK_WEATHER, model="erfa", refraction="boresight", boresight_hor=bore)
    d_el = F.az_el_from_unit(v)[1] - F.az_el_from_unit(v_true)[1]
    np.testing.assert_allclose(d_el, rho_b, atol=1e-9 * ASEC2RAD)


def test_boresight_mode_is_wrong_by_the_differential_refraction():
    """Seed 000 Tab. 4: one rho for the whole 8 deg field leaves the differential refraction
    (+-11'' at the field edges at 40 deg) in the residuals and the attitude."""
    w, v_true, _ = _field(n=40)
    per_star = sensor_attitude_hor(w, v_true, DOCK_WEATHER, model="erfa", reject_outliers=False)
    bore = sensor_attitude_hor(w, v_true, DOCK_WEATHER, model="erfa", refraction="boresight",
                               reject_outliers=False)
    assert per_star.rms_arcsec < 1e-3
    assert 2.0 < bore.rms_arcsec < 15.0
    assert math.isfinite(bore.boresight_refraction_arcsec) and math.isnan(per_star.boresight_refraction_arcsec)
    err = F.rotation_angle_rad(bore.C_hor_from_sensor.T @ C_TRUE) * RAD2ASEC
    assert err > 0.1


def test_none_mode_uses_unrefracted_places():
    w, v_true, _ = _field()
    w_true = v_true @ C_TRUE             # a sensor in vacuum
    h = sensor_attitude_hor(w_true, v_true, DOCK_WEATHER, refraction="none")
    assert F.rotation_angle_rad(h.C_hor_from_sensor.T @ C_TRUE) * RAD2ASEC < 1e-4


def test_catalog_stars_against_erfa_atco13():
    """Whole chain for real stars: shipstar's apparent places + refraction vs ERFA's atco13
    (observed az/zenith distance with its own refraction) for the same time and site."""
    from shipstar.sky.apparent import Site, frame_context
    from shipstar.sky.catalog import navigation_catalog
    from shipstar.sky.time import utc_jd_from_iso

    cat = navigation_catalog(6.5)
    site = Site.from_deg(31.9, 120.3)
    jd1, jd2 = utc_jd_from_iso("2013-03-15T12:16:00")
    ctx = frame_context(jd1, jd2, site)
    eop = ctx.eop
    b = C_TRUE[:, 0]
    v_all = ctx.hor_from_catalog(cat)
    near = np.flatnonzero(v_all @ b > math.cos(4.0 * DEG2RAD))
    assert len(near) >= 10
    rc, dc, pr, pd, px, rv = (np.asarray(a)[near] for a in cat.erfa_args())
    aob, zob, *_ = erfa.atco13(rc, dc, pr, pd, px, rv, jd1, jd2, eop.dut1_s, site.lon_rad, site.lat_rad,
                               site.height_m, eop.xp_rad, eop.yp_rad, DOCK_WEATHER.pressure_hpa,
                               DOCK_WEATHER.temperature_c, 0.0, 0.55)
    v_obs_erfa = F.unit_from_az_el(aob, 0.5 * np.pi - zob)
    w = v_obs_erfa @ C_TRUE               # what a sensor at C_TRUE measures
    h = sensor_attitude_hor_from_catalog(w, cat.hip[near], cat, ctx, DOCK_WEATHER, model="erfa")
    assert h.solved
    assert F.rotation_angle_rad(h.C_hor_from_sensor.T @ C_TRUE) * RAD2ASEC < 1e-3     # measured 3e-5''
    assert h.rms_arcsec < 1e-3


def test_covariance_matches_the_cramer_rao_bound_and_monte_carlo():
    w, v_true, v_obs = _field(n=20)
    sigma = 3.0 * ASEC2RAD
    F_info = sum(sigma ** -2 * (np.eye(3) - np.outer(x, x)) for x in w)
    crb = np.linalg.inv(F_info)
    rng = np.random.default_rng(11)
    errs = []
    for _ in range(300):
        noise = rng.normal(0.0, sigma, w.shape)
        wn = w + noise - (np.sum(noise * w, axis=1))[:, None] * w
        h = sensor_attitude_hor(wn, v_true, DOCK_WEATHER, model="erfa", sigma_rad=sigma, reject_outliers=False)
        E = C_TRUE.T @ h.C_hor_from_sensor
        errs.append([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
    np.testing.assert_allclose(h.covariance_rad2, crb, rtol=2e-3)     # evaluated at the noisy w
    std = np.std(np.array(errs) * 0.5, axis=0)
    np.testing.assert_allclose(std, np.sqrt(np.diag(crb)), rtol=0.15)
    assert std[0] > 5 * std[1]           # the roll about the boresight is the weak axis


def test_estimated_sigma_tracks_the_noise():
    w, v_true, _ = _field(n=60)
    rng = np.random.default_rng(5)
    sigma = 3.0 * ASEC2RAD
    noise = rng.normal(0.0, sigma, w.shape)
    wn = w + noise - (np.sum(noise * w, axis=1))[:, None] * w
    h = sensor_attitude_hor(wn, v_true, DOCK_WEATHER, model="erfa")
    assert h.solved
    assert np.nanmedian(h.sigma_rad) == pytest.approx(sigma, rel=0.2)


def test_stars_below_the_model_limit_are_left_out():
    w, v_true, _ = _field(n=5)
    low = F.unit_from_az_el(np.array([1.0, 2.0]), np.array([3.0, 4.0]) * DEG2RAD)
    h = sensor_attitude_hor(np.vstack([w, w[:2]]), np.vstack([v_true, low]), DOCK_WEATHER, model="erfa")
    assert h.solved and h.n_used == 5
    assert np.all(np.isnan(h.v_hor[-2:])) and not h.inliers[-2:].any()
    h2 = sensor_attitude_hor(w[:2], low, DOCK_WEATHER, model="erfa")
    assert not h2.solved and "above the refraction model's elevation limit" in h2.reason
    assert np.all(np.isnan(h2.C_hor_from_sensor))


def test_bad_input_raises_shipstar_error():
    w, v_true, _ = _field(n=5)
    with pytest.raises(ShipstarError, match="same shape"):
        sensor_attitude_hor(w, v_true[:4], DOCK_WEATHER)
    with pytest.raises(ShipstarError, match="NaN"):
        sensor_attitude_hor(np.full((5, 3), np.nan), v_true, DOCK_WEATHER)
    with pytest.raises(ShipstarError, match="refraction mode"):
        sensor_attitude_hor(w, v_true, DOCK_WEATHER, refraction="zenith")
    with pytest.raises(ShipstarError, match="refraction model"):
        sensor_attitude_hor(w, v_true, DOCK_WEATHER, model="saastamoinen")
    with pytest.raises(ShipstarError, match="boresight"):
        reference_hor(v_true, DOCK_WEATHER, refraction="boresight")
    with pytest.raises(ShipstarError, match="weather"):
        sensor_attitude_hor(w, v_true, None)
    assert REFRACTION_MODES == ("per-star", "boresight", "none")


def test_a_second_solve_with_the_first_ones_references_is_the_same_solve():
    """The streak correction solves a frame again from turned vectors: per-star refraction
    of the same stars does not depend on them, so the first solve's refracted references
    (``v_ref_hor``, NaN rows below the limit) give the solve that computing them again gives,
    bit for bit; boresight refraction depends on the measured vectors and ignores them."""
    import dataclasses

    w, v_true, _ = _field(n=12)
    low = F.unit_from_az_el(np.array([1.0, 2.0]), np.array([3.0, 4.0]) * DEG2RAD)
    w, v_true = np.vstack([w, w[:2]]), np.vstack([v_true, low])
    first = sensor_attitude_hor(w, v_true, DOCK_WEATHER, model="erfa", sigma_rad=2e-5)
    rng = np.random.default_rng(7)
    turned = w + rng.normal(0.0, 1e-6, w.shape)
    turned /= np.linalg.norm(turned, axis=1, keepdims=True)
    for refraction in ("per-star", "boresight"):
        again = sensor_attitude_hor(turned, v_true, DOCK_WEATHER, model="erfa", sigma_rad=2e-5,
                                    refraction=refraction)
        reused = sensor_attitude_hor(turned, v_true, DOCK_WEATHER, model="erfa", sigma_rad=2e-5,
                                     refraction=refraction, v_ref_hor=first.v_hor)
        assert again.solved and again.n_used == 12
        for f in dataclasses.fields(again):
            a, b = getattr(again, f.name), getattr(reused, f.name)
            if isinstance(a, np.ndarray):
                np.testing.assert_array_equal(a, b, err_msg=f"{refraction} {f.name}")
            else:
                assert a == b or (isinstance(a, float) and math.isnan(a) and math.isnan(b)), (refraction, f.name)
    with pytest.raises(ShipstarError, match="v_ref_hor must have shape"):
        sensor_attitude_hor(turned, v_true, DOCK_WEATHER, v_ref_hor=first.v_hor[:3])
