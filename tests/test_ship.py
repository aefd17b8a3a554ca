"""Ship attitude from calibrated sensors and the two fusions (seed 003)."""

from __future__ import annotations

import numpy as np
import pytest

from shipstar import frames as F
from shipstar.errors import ShipstarError
from shipstar.ship import (
    SensorStars,
    ShipAttitude,
    fuse_joint,
    fuse_seed_rule,
    ship_angles_jacobian,
    ship_attitude_from_sensor,
)
from shipstar.units import ASEC2RAD, DEG2RAD, RAD2ASEC

A1 = (185.1093 * DEG2RAD, 39.3734 * DEG2RAD, -0.2262 * DEG2RAD)
A2 = (274.9246 * DEG2RAD, 35.1031 * DEG2RAD, 0.0789 * DEG2RAD)
SHIP = (46.47458611 * DEG2RAD, 1.5 * DEG2RAD, -3.0 * DEG2RAD)


def small_rotation(phi):
    """Exact rotation matrix exp([phi x]) (independent of shipstar.frames)."""
    phi = np.asarray(phi, float)
    a = np.linalg.norm(phi)
    if a == 0:
        return np.eye(3)
    k = phi / a
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def test_ship_attitude_from_sensor_inverts_the_chain():
    C_hd = F.C_hor_from_deck(*SHIP)
    C_ds = F.C_deck_from_sensor(*A1)
    att = ship_attitude_from_sensor(C_hd @ C_ds, C_ds)
    assert att.solved and att.method == "single"
    np.testing.assert_allclose([att.heading_rad, att.pitch_rad, att.roll_rad], SHIP, atol=1e-12)
    assert np.all(np.isnan(att.covariance_rad2))


def test_bad_matrices_are_refused():
    with pytest.raises(ShipstarError):
        ship_attitude_from_sensor(np.full((3, 3), np.nan), np.eye(3))
    with pytest.raises(ShipstarError):
        ship_attitude_from_sensor(np.eye(2), np.eye(3))


@pytest.mark.parametrize("ship", [SHIP, (0.1, 0.3, 1.2), (5.0, -1.2, -2.5)])
def test_angles_jacobian_matches_finite_differences(ship):
    C = F.C_hor_from_deck(*ship)
    J = ship_angles_jacobian(C)
    h = 1e-7
    for k in range(3):
        phi = np.zeros(3)
        phi[k] = h
        up = np.array(F.ship_angles_from_C_hor_from_deck(C @ small_rotation(phi)))
        dn = np.array(F.ship_angles_from_C_hor_from_deck(C @ small_rotation(-phi)))
        num = F.wrap_pi(up - dn) / (2 * h)
        np.testing.assert_allclose(J[:, k], num, rtol=1e-6, atol=1e-8)


def test_sensor_covariance_propagates_to_the_weak_axis():
    """A1 looks aft: its roll-about-boresight error shows up in heading and roll,
    hardly in pitch (seed 000's observation: pitch 5.98'', heading/roll 45/67'')."""
    C_ds = F.C_deck_from_sensor(*A1)
    C_hs = F.C_hor_from_deck(*SHIP) @ C_ds
    P_sensor = np.diag([(60 * ASEC2RAD) ** 2, (2 * ASEC2RAD) ** 2, (2 * ASEC2RAD) ** 2])  # about X = boresight
    att = ship_attitude_from_sensor(C_hs, C_ds, P_sensor)
    sig = att.sigma_rad * RAD2ASEC
    assert sig[1] < 8.0   # 60" about a boresight 5 deg off the ship axis leaks ~4" into pitch
    assert sig[0] > 30.0 and sig[2] > 30.0
    # Monte Carlo of the same propagation (errors are small rotations about sensor axes)
    rng = np.random.default_rng(3)
    errs = []
    for _ in range(3000):
        phi = rng.multivariate_normal(np.zeros(3), P_sensor)
        C_noisy = C_hs @ small_rotation(phi)
        a = ship_attitude_from_sensor(C_noisy, C_ds)
        errs.append(F.wrap_pi(np.array([a.heading_rad, a.pitch_rad, a.roll_rad]) - np.array(SHIP)))
    mc = np.std(np.array(errs), axis=0) * RAD2ASEC
    np.testing.assert_allclose(mc, sig, rtol=0.06)


def _single(angles, cov_diag_arcsec):
    C = F.C_hor_from_deck(*angles)
    return ShipAttitude(True, "", *angles, C_hor_from_deck=C,
                        covariance_rad2=np.diag((np.asarray(cov_diag_arcsec) * ASEC2RAD) ** 2), method="single")


def test_seed_rule_takes_mean_heading_fore_aft_pitch_athwart_roll():
    fore = _single((359.99 * DEG2RAD, 0.010, 0.020), [40, 5, 60])
    athw = _single((0.03 * DEG2RAD, 0.011, 0.021), [50, 70, 4])
    fused = fuse_seed_rule(fore, athw)
    assert fused.solved and fused.method == "seed-rule"
    assert F.wrap_pi(fused.heading_rad - 0.01 * DEG2RAD) == pytest.approx(0.0, abs=1e-12)  # circular mean across 0
    assert fused.pitch_rad == 0.010 and fused.roll_rad == 0.021
    np.testing.assert_allclose(fused.sigma_rad * RAD2ASEC, [np.hypot(40, 50) / 2, 5, 4])


def test_seed_rule_reports_which_sensor_failed():
    fused = fuse_seed_rule(_single(SHIP, [1, 1, 1]), ShipAttitude.failed("no stars identified", "single"))
    assert not fused.solved and "athwartship" in fused.reason and "no stars" in fused.reason


def _stars_for(C_hd, install, n, sigma_rad, rng, fov_deg=8.0):
    """Random stars in a sensor's field, their exact horizontal directions, noisy sensor vectors."""
    C_ds = F.C_deck_from_sensor(*install)
    C_hs = C_hd @ C_ds
    half = 0.5 * fov_deg * DEG2RAD
    yz = rng.uniform(-np.tan(half), np.tan(half), (n, 2))
    w = np.column_stack([np.ones(n), yz])
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    v = w @ C_hs.T
    # noise: small rotation of each measured vector
    noise = rng.normal(0, sigma_rad, (n, 3))
    w_noisy = w + np.cross(noise, w)
    w_noisy /= np.linalg.norm(w_noisy, axis=1, keepdims=True)
    return SensorStars(w_noisy, v, C_ds, sigma_rad)


def test_joint_fusion_beats_the_seed_rule_and_its_covariance_matches_scatter():
    rng = np.random.default_rng(11)
    C_hd = F.C_hor_from_deck(*SHIP)
    sigma = 5 * ASEC2RAD
    joint_err, rule_err, joint_sig = [], [], []
    for _ in range(400):
        s1 = _stars_for(C_hd, A1, 25, sigma, rng)
        s2 = _stars_for(C_hd, A2, 25, sigma, rng)
        j = fuse_joint([s1, s2])
        from shipstar.attitude import solve_attitude

        singles = []
        for s in (s1, s2):
            sol = solve_attitude(s.w_sensor, s.v_hor, sigma_rad=sigma)
            singles.append(ship_attitude_from_sensor(sol.C_ref_from_body, s.C_deck_from_sensor, sol.covariance_rad2))
        r = fuse_seed_rule(*singles)
        joint_err.append(F.wrap_pi(np.array([j.heading_rad, j.pitch_rad, j.roll_rad]) - SHIP))
        rule_err.append(F.wrap_pi(np.array([r.heading_rad, r.pitch_rad, r.roll_rad]) - SHIP))
        joint_sig.append(j.sigma_rad)
    rms_joint = np.sqrt(np.mean(np.square(joint_err), axis=0)) * RAD2ASEC
    rms_rule = np.sqrt(np.mean(np.square(rule_err), axis=0)) * RAD2ASEC
    assert rms_joint[0] < rms_rule[0]                      # heading: strictly better
    assert np.all(rms_joint[1:] <= rms_rule[1:] * 1.05)    # pitch, roll: as good or better
    np.testing.assert_allclose(rms_joint, np.mean(joint_sig, axis=0) * RAD2ASEC, rtol=0.12)


def test_joint_needs_data():
    assert not fuse_joint([]).solved
    with pytest.raises(ShipstarError):
        fuse_joint([SensorStars(np.zeros((3, 3)), np.zeros((2, 3)), np.eye(3), 1e-5)])
