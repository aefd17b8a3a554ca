"""Frame and rotation conventions (docs/conventions.md), checked against analytic cases."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shipstar import frames as F
from shipstar.units import ASEC2RAD, DEG2RAD, RAD2ASEC

angle = st.floats(-4 * np.pi, 4 * np.pi, allow_nan=False)
azimuth = st.floats(0.0, 2 * np.pi, allow_nan=False, exclude_max=True)
middle = st.floats(-np.pi / 2 + 1e-6, np.pi / 2 - 1e-6, allow_nan=False)
roll = st.floats(-np.pi + 1e-9, np.pi, allow_nan=False)


def rodrigues_active(axis, angle_rad):
    """Active rotation of a vector by angle about axis (independent of frames.rot_*)."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1 - np.cos(angle_rad)) * K @ K


def ang_diff(a, b):
    return np.abs(F.wrap_pi(np.asarray(a) - np.asarray(b)))


class TestElementaryRotations:
    def test_passive_matrices_as_printed_in_seed(self):
        a = 0.3
        c, s = np.cos(a), np.sin(a)
        np.testing.assert_allclose(F.rot_x(a), [[1, 0, 0], [0, c, s], [0, -s, c]])
        np.testing.assert_allclose(F.rot_y(a), [[c, 0, -s], [0, 1, 0], [s, 0, c]])
        np.testing.assert_allclose(F.rot_z(a), [[c, s, 0], [-s, c, 0], [0, 0, 1]])

    def test_passive_is_transpose_of_active(self):
        for rot, axis in ((F.rot_x, [1, 0, 0]), (F.rot_y, [0, 1, 0]), (F.rot_z, [0, 0, 1])):
            np.testing.assert_allclose(rot(0.7), rodrigues_active(axis, 0.7).T, atol=1e-15)

    def test_vectorised_shapes(self):
        a = np.linspace(0, 1, 6).reshape(2, 3)
        assert F.rot_z(a).shape == (2, 3, 3, 3)
        M = F.C_hor_from_deck(a, a / 2, -a)
        assert M.shape == (2, 3, 3, 3)
        np.testing.assert_allclose(M[1, 2], F.C_hor_from_deck(a[1, 2], a[1, 2] / 2, -a[1, 2]))


class TestSeed001Eq2:
    """C_hor_from_deck = R_y(K) R_z(-psi) R_x(-theta) written out (seed 001 eq. 2)."""

    def test_written_out_form(self):
        K, p, t = 0.4, 0.1, -0.2
        cK, sK, cp, sp, ct, st_ = np.cos(K), np.sin(K), np.cos(p), np.sin(p), np.cos(t), np.sin(t)
        expected = np.array([
            [cK * cp, -cK * sp * ct - sK * st_, cK * sp * st_ - sK * ct],
            [sp, cp * ct, -cp * st_],
            [sK * cp, -sK * sp * ct + cK * st_, sK * sp * st_ + cK * ct],
        ])
        np.testing.assert_allclose(F.C_hor_from_deck(K, p, t), expected, atol=1e-15)

    def test_bow_direction(self):
        K, p = 46.4746 * DEG2RAD, 3.0 * DEG2RAD
        bow = F.C_hor_from_deck(K, p, 0.7)[:, 0]
        np.testing.assert_allclose(bow, [np.cos(K) * np.cos(p), np.sin(p), np.sin(K) * np.cos(p)])

    def test_pitch_positive_is_bow_up_and_roll_positive_is_starboard_down(self):
        bow = F.C_hor_from_deck(0.0, 5 * DEG2RAD, 0.0) @ [1, 0, 0]
        assert bow[1] > 0
        starboard = F.C_hor_from_deck(0.0, 0.0, 5 * DEG2RAD) @ [0, 0, 1]
        assert starboard[1] < 0
        # heading: bow at north for K = 0, at east for K = 90 deg
        np.testing.assert_allclose(F.C_hor_from_deck(np.pi / 2, 0, 0) @ [1, 0, 0], [0, 0, 1], atol=1e-15)

    def test_frames_are_right_handed(self):
        # hor: X north, Y up, Z east.  North x Up = East.
        np.testing.assert_allclose(np.cross([1, 0, 0], [0, 1, 0]), [0, 0, 1])
        for M in (F.C_hor_from_deck(1, 0.2, 0.3), F.C_deck_from_sensor(3, 0.6, -0.1),
                  F.C_icrs_from_sensor(1.0, -0.4, 2.0)):
            assert np.linalg.det(M) == pytest.approx(1.0, abs=1e-14)
            np.testing.assert_allclose(M @ M.T, np.eye(3), atol=1e-15)


class TestPhysical:
    def test_aft_sensor_on_heading_46(self):
        """A1 at azimuth 185 deg, elevation 40 deg, ship heading 46.4746 deg, level."""
        C = F.C_hor_from_deck(46.4746 * DEG2RAD, 0, 0) @ F.C_deck_from_sensor(185 * DEG2RAD, 40 * DEG2RAD, 0)
        az, el = F.az_el_from_unit(C[:, 0])
        assert az / DEG2RAD == pytest.approx(231.4746, abs=1e-10)
        assert el / DEG2RAD == pytest.approx(40.0, abs=1e-10)

    def test_pitch_and_roll_move_the_boresight_as_eq2_says(self):
        """Small ship pitch/roll tilt the boresight by the deck rotation of eq. 2:
        d(boresight) = (C(K, dpsi, dtheta) - C(K, 0, 0)) b_deck, to first order
        the rotation of the deck about its Z (pitch) and X (roll) axes."""
        K, A, E = 46.4746 * DEG2RAD, 185 * DEG2RAD, 40 * DEG2RAD
        b_deck = F.C_deck_from_sensor(A, E, 0)[:, 0]
        d = 10 * ASEC2RAD
        b0 = F.C_hor_from_deck(K, 0, 0) @ b_deck
        # pitch: active rotation of deck vectors by +psi about deck +Z (bow goes up)
        b_p = F.C_hor_from_deck(K, d, 0) @ b_deck
        expected_p = F.C_hor_from_deck(K, 0, 0) @ (rodrigues_active([0, 0, 1], d) @ b_deck)
        np.testing.assert_allclose(b_p, expected_p, atol=1e-15)
        # roll: starboard down is an active rotation of deck vectors about the bow (+X)
        b_r = F.C_hor_from_deck(K, 0, d) @ b_deck
        expected_r = F.C_hor_from_deck(K, 0, 0) @ (rodrigues_active([1, 0, 0], d) @ b_deck)
        np.testing.assert_allclose(b_r, expected_r, atol=1e-15)
        # An aft-looking sensor (A ~ 185 deg) sees bow-up pitch as its boresight going DOWN.
        assert F.az_el_from_unit(b_p)[1] < F.az_el_from_unit(b0)[1]
        # to first order the elevation changes by pitch * cos(A): -9.96" for A = 185 deg
        d_el_arcsec = (F.az_el_from_unit(b_p)[1] - F.az_el_from_unit(b0)[1]) * RAD2ASEC
        assert d_el_arcsec == pytest.approx(10 * np.cos(A), rel=2e-3)


class TestAngleRoundTrips:
    @settings(max_examples=300, deadline=None)
    @given(azimuth, middle, roll)
    def test_ship_angles(self, K, p, t):
        K2, p2, t2 = F.ship_angles_from_C_hor_from_deck(F.C_hor_from_deck(K, p, t))
        assert ang_diff(K2, K) < 1e-9 and abs(p2 - p) < 1e-9 and ang_diff(t2, t) < 1e-9
        assert 0 <= K2 < 2 * np.pi

    @settings(max_examples=300, deadline=None)
    @given(azimuth, middle, roll)
    def test_installation_angles(self, A, E, g):
        A2, E2, g2 = F.installation_angles_from_C_deck_from_sensor(F.C_deck_from_sensor(A, E, g))
        assert ang_diff(A2, A) < 1e-9 and abs(E2 - E) < 1e-9 and ang_diff(g2, g) < 1e-9

    @settings(max_examples=300, deadline=None)
    @given(angle, angle, angle)
    def test_any_matrix_reproduced(self, a, b, c):
        """Any rotation: extraction then reconstruction gives the same matrix."""
        C = F.C_hor_from_deck(a, b, c)
        np.testing.assert_allclose(F.C_hor_from_deck(*F.ship_angles_from_C_hor_from_deck(C)), C, atol=1e-9)

    @settings(max_examples=300, deadline=None)
    @given(azimuth, st.floats(-np.pi / 2, np.pi / 2), azimuth)
    def test_icrs_attitude(self, ra, dec, r):
        C = F.C_icrs_from_sensor(ra, dec, r)
        np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(F.C_icrs_from_sensor(*F.ra_dec_roll_from_C_icrs_from_sensor(C)), C, atol=1e-9)

    @settings(max_examples=300, deadline=None)
    @given(angle, angle, angle)
    def test_quaternion(self, a, b, c):
        C = F.C_hor_from_deck(a, b, c)
        q = F.q_wxyz_from_matrix(C)
        assert q[0] >= 0 and np.linalg.norm(q) == pytest.approx(1.0)
        np.testing.assert_allclose(F.matrix_from_q_wxyz(q), C, atol=1e-12)

    @settings(max_examples=100, deadline=None)
    @given(angle, angle, angle, angle, angle, angle)
    def test_quaternion_product_matches_matrix_product(self, a, b, c, d, e, f):
        C1, C2 = F.C_hor_from_deck(a, b, c), F.C_deck_from_sensor(d, e, f)
        q = F.q_wxyz_multiply(F.q_wxyz_from_matrix(C1), F.q_wxyz_from_matrix(C2))
        np.testing.assert_allclose(F.matrix_from_q_wxyz(q), C1 @ C2, atol=1e-12)

    def test_quaternion_is_the_active_rotation(self):
        # 90 deg about +Z takes X to Y (active), q = [cos 45, 0, 0, sin 45]
        q = np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
        np.testing.assert_allclose(F.matrix_from_q_wxyz(q) @ [1, 0, 0], [0, 1, 0], atol=1e-15)

    def test_quaternion_180_degrees(self):
        for axis in np.eye(3):
            C = rodrigues_active(axis, np.pi)
            np.testing.assert_allclose(F.matrix_from_q_wxyz(F.q_wxyz_from_matrix(C)), C, atol=1e-14)


class TestEdgeCases:
    @pytest.mark.parametrize("pitch_deg", [90.0, -90.0])
    def test_gimbal_lock_keeps_the_matrix(self, pitch_deg):
        C = F.C_hor_from_deck(0.3, pitch_deg * DEG2RAD, 0.5)
        K, p, t = F.ship_angles_from_C_hor_from_deck(C)
        assert t == 0.0
        assert p / DEG2RAD == pytest.approx(pitch_deg, abs=1e-6)
        np.testing.assert_allclose(F.C_hor_from_deck(K, p, t), C, atol=1e-12)
        assert F.gimbal_lock_mask(C)

    def test_near_gimbal_lock_pitch_is_accurate(self):
        # asin would lose half the digits at 89.9999 deg; atan2 keeps them
        p = (90 - 1e-4) * DEG2RAD
        C = F.C_hor_from_deck(1.0, p, 0.2)
        assert F.ship_angles_from_C_hor_from_deck(C)[1] == pytest.approx(p, abs=1e-12)
        assert not F.gimbal_lock_mask(C)

    def test_heading_wraps_into_0_360(self):
        for K_deg in (-0.0001, 359.99999, 360.0, 720.5, -45.0):
            K2 = F.ship_angles_from_C_hor_from_deck(F.C_hor_from_deck(K_deg * DEG2RAD, 0, 0))[0]
            assert 0.0 <= K2 < 2 * np.pi
            assert ang_diff(K2, K_deg * DEG2RAD) < 1e-12

    def test_wrap(self):
        np.testing.assert_allclose(F.wrap_2pi([-0.1, 2 * np.pi, 7.0]), [2 * np.pi - 0.1, 0.0, 7.0 - 2 * np.pi])
        np.testing.assert_allclose(F.wrap_pi([np.pi, -np.pi, 3 * np.pi / 2]), [np.pi, np.pi, -np.pi / 2])

    def test_icrs_attitude_at_the_pole(self):
        C = F.C_icrs_from_sensor(0.7, np.pi / 2, 0.3)
        np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-15)
        np.testing.assert_allclose(C[:, 0], [0, 0, 1], atol=1e-15)

    def test_roll_zero_has_north_up_and_east_left(self):
        C = F.C_icrs_from_sensor(0.0, 0.0, 0.0)
        np.testing.assert_allclose(C[:, 1], [0, 0, 1], atol=1e-15)  # image up = north
        np.testing.assert_allclose(C[:, 2], [0, -1, 0], atol=1e-15)  # image right = west
        C90 = F.C_icrs_from_sensor(0.0, 0.0, np.pi / 2)
        np.testing.assert_allclose(C90[:, 1], [0, 1, 0], atol=1e-15)  # roll 90: image up = east

    def test_rotation_angle_small_and_large(self):
        assert F.rotation_angle_rad(F.rot_y(1e-10)) == pytest.approx(1e-10, rel=1e-6)
        assert F.rotation_angle_rad(F.rot_y(np.pi)) == pytest.approx(np.pi)
        assert F.rotation_angle_rad(F.rot_x(-0.5)) == pytest.approx(0.5)

    def test_orthonormalize(self):
        C = F.C_hor_from_deck(1, 0.5, 0.2)
        noisy = C + 1e-6 * np.random.default_rng(1).standard_normal((3, 3))
        R = F.orthonormalize(noisy)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(R, C, atol=3e-6)

    def test_az_el_and_ra_dec_round_trips(self):
        az = np.array([0.0, 1.0, 4.0, 6.2])
        el = np.array([-0.5, 0.0, 0.7, 1.5])
        np.testing.assert_allclose(F.az_el_from_unit(F.unit_from_az_el(az, el)), (az, el), atol=1e-14)
        np.testing.assert_allclose(F.ra_dec_from_unit(F.unit_from_ra_dec(az, el)), (az, el), atol=1e-14)
        # north, east, zenith
        np.testing.assert_allclose(F.unit_from_az_el(0, 0), [1, 0, 0], atol=1e-15)
        np.testing.assert_allclose(F.unit_from_az_el(np.pi / 2, 0), [0, 0, 1], atol=1e-15)
        np.testing.assert_allclose(F.unit_from_az_el(0, np.pi / 2), [0, 1, 0], atol=1e-15)


def test_one_matrix_angle_paths_agree_with_the_array_paths():
    """The plain-float paths for one (3, 3) matrix (ship and installation angles, the
    gimbal-lock test, the angles' Jacobian) give the array paths' values: the Jacobian
    exactly (the same operations), the angles within 1 ulp of 2 pi (NumPy's vectorised
    arctan2 may round differently from the C library's)."""
    from shipstar.identify._sim import random_attitudes
    from shipstar.ship import ship_angles_jacobian

    Cs = list(random_attitudes(300, np.random.default_rng(4)))
    Cs += [F.C_hor_from_deck(1.0, 0.5 * np.pi, 0.3), F.C_hor_from_deck(0.0, -0.5 * np.pi + 1e-8, 0.0),
           F.C_hor_from_deck(2 * np.pi - 1e-17, 0.0, 0.0), np.eye(3)]
    for C in Cs:
        one = F.ship_angles_from_C_hor_from_deck(C)
        batch = F.ship_angles_from_C_hor_from_deck(C[None])
        assert all(isinstance(x, np.floating) for x in one)
        np.testing.assert_allclose([float(x) for x in one], [float(x[0]) for x in batch], rtol=0, atol=1e-15)
        assert 0.0 <= one[0] < 2 * np.pi
        assert bool(F.gimbal_lock_mask(C)) == bool(F.gimbal_lock_mask(C[None])[0])
        if not F.gimbal_lock_mask(C):
            assert np.array_equal(ship_angles_jacobian(C), ship_angles_jacobian(C[None])[0])


def test_one_matrix_jacobian_at_exact_gimbal_lock_is_the_array_paths():
    """At exact gimbal lock (cos(pitch) exactly 0) the heading and roll rows divide by
    zero: one matrix gives what the array path gives (inf and NaN, NumPy's warnings),
    not the plain-float path's ZeroDivisionError."""
    from shipstar.ship import ship_angles_jacobian

    C = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])      # pitch +90 deg, exactly
    with np.errstate(divide="ignore", invalid="ignore"):
        one, batch = ship_angles_jacobian(C), ship_angles_jacobian(C[None])[0]
    np.testing.assert_array_equal(one, batch)
    assert not np.all(np.isfinite(one))


def test_installation_matrix_is_made_once_and_read_only():
    from shipstar.calibrate.installation import Installation

    inst = Installation("A1", "A1", az_rad=0.3, el_rad=0.6, roll_rad=-0.2)
    C = inst.C_deck_from_sensor
    assert C is inst.C_deck_from_sensor
    assert np.array_equal(C, F.C_deck_from_sensor(0.3, 0.6, -0.2))
    with pytest.raises(ValueError):
        C[0, 0] = 1.0
    assert inst == Installation("A1", "A1", az_rad=0.3, el_rad=0.6, roll_rad=-0.2)
