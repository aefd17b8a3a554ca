"""The centroid of an accelerating streak (docs/extraction.md, *Accelerating streaks*):
where the pipeline's extraction puts it, and the streak correction's model of it."""

from __future__ import annotations

import numpy as np
import pytest

from shipstar.camera import load_camera
from shipstar.extract import extract_stars
from shipstar.pipeline._exposure import StreakModel, exposure_mean_offset, streak_along_factor
from shipstar.simulate._motion import streak_sources
from shipstar.simulate._render import render_frame, star_signal_e


def test_along_factor_limits_and_continuity():
    """k = 1 for a point (the centroid), its series meets the closed form at L = 0.5 s2, and
    long streaks tend to the ends' midpoint (3 x the time average) less the PSF's pull."""
    s2 = np.sqrt(2 * (0.8 ** 2 + 1 / 12))
    assert streak_along_factor(0.0, 0.8) == 1.0
    eps = 1e-6
    lo, hi = streak_along_factor([0.5 * s2 - eps, 0.5 * s2 + eps], 0.8)
    assert abs(lo - hi) < 1e-5
    L = np.array([200.0, 400.0])
    np.testing.assert_allclose(streak_along_factor(L, 0.8), 3 - 6 * np.sqrt(2 * np.pi) * s2 / L, atol=2e-3)
    k = streak_along_factor(np.linspace(0.1, 40, 400), 0.8)
    assert np.all(np.isfinite(k)) and 0.6 < k.min() < 0.62 and k.max() < 3


@pytest.mark.parametrize("length_px", [6.0, 20.0])
def test_rendered_accelerating_streaks_are_fitted_where_the_model_says(length_px):
    """64 bright A1 streaks rendered along x(t) = x0 + v t + a t^2 / 2 (60 ms, a T^2 / 24 =
    0.1 px along, the simulator's piecewise renderer), extracted as the pipeline does: the
    fitted centre lies k(L) x 0.1 px beyond x0 along the streak (k = 0.95 / 2.18, not the
    time average's 1), and at the time average across it (curvature)."""
    cam = load_camera("A1").replace(exposure_s=0.06)
    T, n, d24 = 0.06, 16, 0.1
    tau = np.linspace(-T / 2, T / 2, 2 * n + 1)
    e = np.array([np.cos(0.35), np.sin(0.35)])
    p = np.array([-e[1], e[0]])
    g = np.arange(8) * 110 + 130.37
    xy0 = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    a = 24 * d24 / T ** 2

    def offsets(a_along, a_across, seed):
        s = length_px / T * tau + a_along * tau ** 2 / 2
        path = xy0[:, None, :] + s[None, :, None] * e + (a_across * tau ** 2 / 2)[None, :, None] * p
        xy, sig, sm = streak_sources(path, star_signal_e(cam, np.full(len(xy0), 5.0)))
        img = render_frame(cam, xy, sig, np.random.default_rng(seed), smear_px=sm, hot_pixel_fraction=0)
        ex = extract_stars(img, psf_sigma_px=cam.psf_sigma_px, gain_e_per_adu=cam.gain_e_per_adu)
        d = np.linalg.norm(ex.xy_px[:, None, :] - xy0[None], axis=2)
        dd = ex.xy_px[np.argmin(d, axis=0)] - xy0
        assert np.all(np.linalg.norm(dd, axis=1) < 1.0)
        return np.c_[dd @ e, dd @ p].mean(axis=0)

    k_model = float(streak_along_factor(length_px, cam.psf_sigma_px))
    k_along = (offsets(a, 0, 1)[0] - offsets(-a, 0, 2)[0]) / (2 * d24)
    k_across = (offsets(0, a, 3)[1] - offsets(0, -a, 4)[1]) / (2 * d24)
    assert abs(k_along - k_model) < 0.3, (k_along, k_model)
    assert abs(k_along - 1.0) > 0.5 * abs(k_model - 1.0) or abs(k_model - 1.0) < 0.1
    assert abs(k_across - 1.0) < 0.2, k_across


def test_model_scales_only_the_along_streak_part():
    """In direction space: with the extraction's model the offset's component along each
    star's motion (-omega x w) is k(L) times the time average's; across it is unchanged."""
    cam = load_camera("A1")
    T, pixel_rad = 0.06, cam.pixel_mm / cam.f_mm
    w = np.array([[0.01, 0.02, 1.0], [-0.03, 0.01, 1.0], [0.0, 0.0, 1.0]])
    w /= np.linalg.norm(w, axis=1)[:, None]
    omega = np.radians([2.0, -1.0, 0.5])
    alpha = np.radians([-1.0, 3.0, 0.2])
    plain = exposure_mean_offset(w, omega, alpha, T)
    fitted = exposure_mean_offset(w, omega, alpha, T, StreakModel(cam.psf_sigma_px, pixel_rad))
    vel = np.cross(w, omega)
    speed = np.linalg.norm(vel, axis=1)
    e = vel / speed[:, None]
    k = streak_along_factor(speed * T / pixel_rad, cam.psf_sigma_px)
    np.testing.assert_allclose(np.einsum("ij,ij->i", fitted, e), k * np.einsum("ij,ij->i", plain, e), rtol=1e-12)
    np.testing.assert_allclose(fitted - np.einsum("ij,ij->i", fitted, e)[:, None] * e,
                               plain - np.einsum("ij,ij->i", plain, e)[:, None] * e, atol=1e-18)
    np.testing.assert_array_equal(exposure_mean_offset(w, omega, alpha, T, StreakModel()), plain)


def test_compiled_mid_exposure_directions_are_the_numpy_reference():
    """``mid_exposure_vectors`` (compiled, star by star) against its NumPy reference: the same
    mid-exposure directions to 1e-15 and turns to 1e-9 of themselves or 1e-16 rad (2e-11'':
    turns of 1e-9-1e-4 rad are the chords of two nearly equal unit vectors, which carry their
    components' rounding), against the 0.01'' below which no correction is made; with and without the streak model,
    unnormalised inputs, a star on the rotation axis (no streak), streaks short enough for
    the series of ``k`` and rates from 0.1 to 20 deg/s."""
    from shipstar.pipeline._exposure import _mid_exposure_vectors_python, mid_exposure_vectors

    rng = np.random.default_rng(29)
    cam = load_camera("A1")
    n_short = n_long = 0
    for trial in range(40):
        omega = rng.normal(0.0, 1.0, 3) * np.radians(10.0 ** rng.uniform(-1.0, 1.3))
        alpha = rng.normal(0.0, 1.0, 3) * np.radians(rng.uniform(0.0, 5.0))
        w = np.vstack([rng.normal([0.0, 0.0, 1.0], 0.08, (30, 3)) * rng.uniform(0.5, 3.0, (30, 1)),
                       omega / np.linalg.norm(omega)])                  # the last one on the axis
        T = float(rng.uniform(0.005, 0.1))
        model = None if trial % 3 == 0 else StreakModel(float(rng.uniform(0.5, 1.6)), cam.pixel_mm / cam.f_mm)
        mid, turn = mid_exposure_vectors(w, omega, alpha, T, model)
        mid_ref, turn_ref = _mid_exposure_vectors_python(w, omega, alpha, T, model)
        np.testing.assert_allclose(mid, mid_ref, rtol=0.0, atol=1e-15, err_msg=str(trial))
        np.testing.assert_allclose(turn, turn_ref, rtol=1e-9, atol=1e-16, err_msg=str(trial))
        if model is not None:
            length = np.linalg.norm(np.cross(w / np.linalg.norm(w, axis=1)[:, None], omega), axis=1) * T \
                / model.pixel_rad / np.sqrt(2.0 * (model.psf_sigma_px ** 2 + 1.0 / 12.0))
            n_short += int(np.count_nonzero(length < 0.5))
            n_long += int(np.count_nonzero(length >= 0.5))
    assert n_short > 20 and n_long > 200                 # both branches of k were met


def test_the_smear_hints_cross_product_is_numpys_bit_for_bit():
    """The smear prediction's and its check's ``omega x u0`` (``pipeline._sensor._cross3``,
    for two 3-vectors, 18 x faster than ``np.cross``) are NumPy's numbers to the bit, over
    magnitudes from 1e-8 to 1e3 and signs of every kind."""
    from shipstar.pipeline._sensor import _cross3

    rng = np.random.default_rng(83)
    a = rng.normal(size=(3000, 3)) * 10.0 ** rng.uniform(-8, 3, (3000, 3))
    b = rng.normal(size=(3000, 3)) * 10.0 ** rng.uniform(-8, 3, (3000, 3))
    got = np.array([_cross3(x, y) for x, y in zip(a, b)])
    np.testing.assert_array_equal(got, np.cross(a, b))


def _rot(e):
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(e).as_matrix()


def test_streak_model_covariance_is_the_fraction_of_the_correction_fully_correlated():
    """Analytic case: an attitude turned by the correction's rotation vector d (scipy's
    rotation) gives fraction^2 d d^T, rank 1, with the fraction of the module by default."""
    from shipstar.pipeline._exposure import STREAK_MODEL_FRACTION, rotation_vector_rad, streak_model_covariance

    C0 = _rot([0.3, -1.1, 0.7])
    d = np.radians(np.array([2.0, -0.5, 1.2]) / 3600)
    C1 = C0 @ _rot(d)
    np.testing.assert_allclose(rotation_vector_rad(C0.T @ C1), d, rtol=1e-9, atol=1e-18)
    np.testing.assert_allclose(rotation_vector_rad(_rot([0.2, -0.1, 0.05])), [0.2, -0.1, 0.05], rtol=1e-12)
    np.testing.assert_allclose(streak_model_covariance(C0, C1, 0.1), 0.01 * np.outer(d, d), rtol=1e-8, atol=1e-30)
    M = streak_model_covariance(C0, C1)
    np.testing.assert_allclose(M, STREAK_MODEL_FRACTION ** 2 * np.outer(d, d), rtol=1e-8, atol=1e-30)
    assert np.linalg.matrix_rank(M / np.max(M), tol=1e-9) == 1
    assert np.all(streak_model_covariance(C0, C0) == 0.0)


def test_joint_covariance_carries_each_sensors_common_mode_error_as_monte_carlo_shows():
    """Two sensors whose stars (noise free) are all turned together by a random rotation
    drawn from each sensor's model covariance: the joint solutions' scatter (500 draws, the
    solver itself) is the covariance fuse_joint adds for it, to its sampling error."""
    from shipstar.ship import SensorStars, fuse_joint, ship_angles_jacobian

    rng = np.random.default_rng(3)
    C_hd = _rot([0.02, 0.5, -0.03])
    sensors = []
    for az, n in ((np.radians(185.0), 25), (np.radians(275.0), 12)):
        C_ds = _rot([0.0, -az, 0.0]) @ _rot([0.0, 0.0, np.radians(38.0)])
        w = np.c_[np.ones(n), rng.uniform(-0.07, 0.07, (n, 2))]
        w /= np.linalg.norm(w, axis=1)[:, None]
        sensors.append((C_ds, w, (C_hd @ C_ds @ w.T).T))
    sigma = np.radians(1.0 / 3600)
    L_model = [np.radians(np.array([[1.5, 0, 0], [0.4, 0.3, 0], [0.0, -0.2, 0.6]]) / 3600),
               np.radians(np.array([[0.5, 0, 0], [0.0, 0.8, 0], [0.3, 0.0, 0.2]]) / 3600)]
    M = [L @ L.T for L in L_model]

    def stars(turns, model):
        return [SensorStars(w @ _rot(d).T, v, C_ds, sigma, model_covariance_rad2=m)
                for (C_ds, w, v), d, m in zip(sensors, turns, model)]

    base = fuse_joint(stars([np.zeros(3)] * 2, [None, None]))
    with_model = fuse_joint(stars([np.zeros(3)] * 2, M))
    added = with_model.covariance_rad2 - base.covariance_rad2
    J = ship_angles_jacobian(C_hd)
    errs = []
    for _ in range(500):
        sol = fuse_joint(stars([L @ rng.standard_normal(3) for L in L_model], [None, None]), reject_outliers=False)
        errs.append(J @ _rotvec_between(C_hd, sol.C_hor_from_deck))
    emp = np.cov(np.array(errs).T)
    sd = np.sqrt(np.diag(added))
    assert np.all(sd > 0.05 * np.sqrt(np.diag(base.covariance_rad2)))
    # 500 draws: a variance to ~6 %, a correlation to ~0.05
    np.testing.assert_allclose(np.sqrt(np.diag(emp)), sd, rtol=0.1)
    np.testing.assert_allclose(emp / np.outer(sd, sd), added / np.outer(sd, sd), atol=0.12)


def _rotvec_between(C_true, C_est):
    from shipstar.pipeline._exposure import rotation_vector_rad

    return rotation_vector_rad(np.asarray(C_true).T @ np.asarray(C_est))


def _sea_session_with_hints(monkeypatch, duration_s, exposure_s):
    """An image-level sea session (``test_pipeline._image_sea_session``) processed with the
    pipeline's smear hints recorded: ``(spec, frames, track, weather, truth, configs, result,
    hints)``, ``hints`` a list of ``(sensor name, t_s, frame, hint or None, stated error px or
    None)``."""
    import sys
    from pathlib import Path

    from shipstar.pipeline import PipelineOptions, process_session
    from shipstar.pipeline import _sensor

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_pipeline import _image_sea_session

    spec, frames, track, weather, truth, configs = _image_sea_session(duration_s, exposure_s)
    hints = []
    predict = _sensor.SensorProcessor._smear_hint_px

    def recorded(self, frame, t_s):
        smear = predict(self, frame, t_s)
        hints.append((self.config.name, t_s, frame, smear, self._smear_sigma_px(t_s)))
        return smear

    monkeypatch.setattr(_sensor.SensorProcessor, "_smear_hint_px", recorded)
    result = process_session(configs, frames, track, weather, PipelineOptions())
    monkeypatch.undo()
    return spec, frames, track, weather, truth, configs, result, hints


def _true_centre_motion_px(spec, name, t_s, exposure_s):
    """(dx, dy) px: the simulator's image motion over the exposure of the star at the image
    centre at mid-exposure ``t_s``."""
    s = spec.sensor(name)
    cam = s.camera
    u0 = cam.unproject(np.array([[0.5 * (cam.width_px - 1), 0.5 * (cam.height_px - 1)]]))[0]
    T = exposure_s
    C = [spec.motion.C_hor_from_deck(t) @ s.C_deck_from_sensor for t in (t_s - T / 2, t_s, t_s + T / 2)]
    v_hor = C[1] @ u0
    return np.diff(cam.project(np.array([C[0].T @ v_hor, C[2].T @ v_hor])), axis=0)[0]


def test_smear_hint_is_the_true_image_motion_and_leaves_the_attitudes_as_good(monkeypatch):
    """The pipeline's smear hint (``SensorProcessor._smear_hint_px``, from the sensor's motion
    fitted to its own solved frames) against the simulator's true image motion of the image
    centre over the exposure; and the session's joint attitudes with the hint against
    those without it (the extraction then estimates the smear), both against the truth."""
    from shipstar.pipeline import PipelineOptions, attitude_errors_arcsec, method_series, process_session
    from shipstar.pipeline import _sensor

    T = 0.03
    spec, frames, track, weather, truth, configs, with_hint, hints = _sea_session_with_hints(monkeypatch, 2.5, T)
    given = [(name, t, s) for name, t, _, s, _ in hints if s is not None and np.any(s)]
    assert len(given) >= 0.5 * len(hints)                      # 30 ms at sea: most frames are streaks
    for name, t_s, smear in given:
        true = _true_centre_motion_px(spec, name, t_s, T)
        assert np.hypot(*(smear - true)) <= 0.05 * np.hypot(*true) + 0.1, (name, t_s, smear, true)
    monkeypatch.setattr(_sensor.SensorProcessor, "_smear_hint_px", lambda self, frame, t_s: None)
    without = process_session(configs, frames, track, weather, PipelineOptions())

    def rms(res):
        err = attitude_errors_arcsec(method_series(res, "joint"), truth)[10:]      # motion fitted from frame 5
        return np.sqrt(np.nanmean(err ** 2, axis=0))

    assert np.all(rms(with_hint) <= 1.05 * rms(without) + 0.02), (rms(with_hint), rms(without))


def test_short_predicted_smear_is_a_point_hint_that_finds_the_same_stars(monkeypatch):
    """A smear predicted shorter than ``POINT_HINT_MAX_PX`` (``TRUSTED_POINT_HINT_MAX_PX`` with
    a trusted stated error) is given as ``(0, 0)``: the true image motion is then under the
    3 px from which the extraction's own estimate takes a frame as smeared, and the frame's
    stars are those the extraction finds without a hint (it would have estimated the smear
    and found the frame unsmeared)."""
    from shipstar.extract._core import TRUSTED_SMEAR_SIGMA_PX, frame_extraction
    from shipstar.extract._smear import AUTO_SMEAR_MIN_PX
    from shipstar.pipeline import PipelineOptions
    from shipstar.pipeline import _sensor

    T = 0.01
    spec, *_, hints = _sea_session_with_hints(monkeypatch, 6.0, T)
    zero = [h for h in hints if h[3] is not None and not np.any(h[3])]
    assert len(zero) >= 5, [h[3] for h in hints]
    trusted = [h for h in zero if h[4] is not None and h[4] <= TRUSTED_SMEAR_SIGMA_PX]
    assert len(trusted) >= 5, [h[4] for h in zero]
    for name, t_s, frame, _, sigma in zero:
        true = _true_centre_motion_px(spec, name, t_s, T)
        if sigma is not None and sigma <= TRUSTED_SMEAR_SIGMA_PX:
            assert np.hypot(*true) < _sensor.TRUSTED_POINT_HINT_MAX_PX + 3 * sigma + 0.01 < AUTO_SMEAR_MIN_PX, \
                (name, t_s, true, sigma)
        else:
            assert np.hypot(*true) < _sensor.POINT_HINT_MAX_PX + 0.2 < AUTO_SMEAR_MIN_PX, (name, t_s, true)
        cam = spec.sensor(name).camera
        kw = dict(threshold_sigma=PipelineOptions().threshold_sigma, psf_sigma_px=cam.psf_sigma_px,
                  gain_e_per_adu=cam.gain_e_per_adu)
        hinted = frame_extraction(frame.image, smear_px=np.zeros(2), **kw)[0]
        free = frame_extraction(frame.image, **kw)[0]
        assert np.array_equal(free.smear_px, np.zeros(2))
        np.testing.assert_array_equal(hinted.xy_px, free.xy_px)
        np.testing.assert_array_equal(hinted.xy_cov_px2, free.xy_cov_px2)


def test_the_smear_hint_states_its_error_and_the_truth_is_within_it(monkeypatch):
    """The pipeline measures its smear prediction's error on its last frames
    (``SensorProcessor._smear_sigma_px``: each prediction against the motion fitted with that
    frame's attitude) and states it to the extraction, which uses a hint known to 0.05 px as it
    is.  Against the simulator's true image motion: within 3 stated sigmas (+ 0.01 px), and at
    sea (30 ms exposures, smooth motion) every hint is trusted once the motion fit has settled."""
    from shipstar.extract._core import TRUSTED_SMEAR_SIGMA_PX
    from shipstar.pipeline import _sensor

    stated = []
    sigma_of = _sensor.SensorProcessor._smear_sigma_px

    def recorded(self, t_s):
        sigma = sigma_of(self, t_s)
        predicted = self._smear_predicted
        if sigma is not None and predicted is not None and predicted[0] == t_s:
            stated.append((self.config.name, t_s, predicted[3].copy(), sigma))
        return sigma

    monkeypatch.setattr(_sensor.SensorProcessor, "_smear_sigma_px", recorded)
    T = 0.03
    spec, *_, hints = _sea_session_with_hints(monkeypatch, 2.5, T)
    assert len(stated) >= 20, len(stated)
    within = [np.hypot(*(smear - _true_centre_motion_px(spec, name, t_s, T))) <= 3.0 * sigma + 0.01
              for name, t_s, smear, sigma in stated]
    assert np.mean(within) >= 0.95, stated
    # the first fits (fewer samples, lower degrees) predict to ~0.4 px, and a frame's stated error
    # is the largest of the last 5: from the fifth frame after the first statement, 0.01-0.04 px
    late = [sigma for _, t_s, _, sigma in stated if t_s >= stated[0][1] + 0.5]
    assert len(late) >= 10 and all(sigma <= TRUSTED_SMEAR_SIGMA_PX for sigma in late), late
