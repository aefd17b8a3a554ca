"""Anisotropic centroid errors in the pipeline: the directions' information matrices
(``pipeline._sensor.direction_info``) and the noise model -- a shape on the extraction's
covariance and a floor (seeing) -- from residuals (``pipeline._conditions.NoiseModel``,
``residual_moments``).

References: the pinhole camera's analytic derivative at the principal point; Monte Carlo
fits of stars with errors drawn from a known covariance.
"""

from __future__ import annotations

import numpy as np
import pytest

from shipstar.camera import camera_preset
from shipstar.attitude import quest
from shipstar.pipeline._conditions import NoiseModel, residual_moments
from shipstar.pipeline._sensor import direction_info


def test_direction_info_at_the_principal_point_is_the_pinhole_derivative():
    cam = camera_preset("A1")
    s = cam.pixel_mm / cam.f_mm                  # rad per px at the centre
    cov = np.array([[[0.09, 0.03], [0.03, 0.04]]])
    info, whiten, _ = direction_info(cam, np.array([[cam.x0_px, cam.y0_px]]), cov)
    Si = np.linalg.inv(cov[0])
    # x (image right) turns the direction towards +Z, y (image down) towards -Y
    ref = np.zeros((3, 3))
    ref[2, 2] = Si[0, 0] / s ** 2
    ref[1, 1] = Si[1, 1] / s ** 2
    ref[1, 2] = ref[2, 1] = -Si[0, 1] / s ** 2
    assert np.allclose(info[0], ref, rtol=1e-6, atol=1e-9 * ref.max())
    # whitening: a residual of one pixel along x is cov^(-1/2) of (1, 0) in the centroid's units
    e = np.array([0.0, 0.0, s])
    z = whiten[0] @ e
    assert np.isclose(z @ z, Si[0, 0], rtol=1e-6)


def test_direction_info_with_a_shape_and_a_floor_is_that_covariance():
    cam = camera_preset("A2")
    xy = np.array([[100.0, 700.0], [900.0, 50.0]])
    cov = np.array([np.diag([0.04, 0.01]), [[0.02, -0.005], [-0.005, 0.03]]])
    S = np.array([[1.7, 0.2], [0.2, 0.8]])
    info_s, whiten, G = direction_info(cam, xy, cov, S, floor_px=0.07)
    L = np.linalg.cholesky(cov)
    info_ref, _, _ = direction_info(cam, xy, L @ S @ np.swapaxes(L, 1, 2) + 0.07 ** 2 * np.eye(2))
    assert np.allclose(info_s, info_ref, rtol=1e-9)
    assert np.allclose(G, np.linalg.inv(np.swapaxes(L, 1, 2) @ L), rtol=1e-12)


def test_compiled_direction_info_is_the_numpy_reference():
    """``direction_info`` in closed form (compiled) against its LAPACK reference
    (``_direction_info_python``): the same information, whitening and Gram matrices to 1e-12,
    with and without a shape and a floor, over the whole image of both cameras; a covariance
    that is not positive definite is refused as LAPACK refuses it."""
    from shipstar.pipeline._sensor import _direction_info_python

    rng = np.random.default_rng(54)
    for name in ("A1", "A2"):
        cam = camera_preset(name)
        xy, cov = _field(rng, 200, cam)
        for S, floor in ((None, 0.0), (np.array([[1.7, 0.2], [0.2, 0.8]]), 0.07)):
            got, want = direction_info(cam, xy, cov, S, floor_px=floor), _direction_info_python(cam, xy, cov, S,
                                                                                                floor_px=floor)
            for g, r in zip(got, want):
                scale = np.max(np.abs(r), axis=tuple(range(1, r.ndim)), keepdims=True)
                np.testing.assert_allclose(g / scale, r / scale, rtol=0, atol=1e-12)
    bad = cov.copy()
    bad[3] = [[0.01, 0.02], [0.02, 0.01]]                             # not positive definite
    with pytest.raises(np.linalg.LinAlgError):
        direction_info(cam, xy, bad)


def _field(rng, n, cam):
    """``n`` stars over the image; Cramer-Rao sigmas from 0.01 px (bright) to 0.5 px."""
    xy = rng.uniform(40.0, 980.0, (n, 2))
    sig = np.exp(rng.uniform(np.log(0.01), np.log(0.5), (n, 2)))
    rho = rng.uniform(-0.5, 0.5, n)
    cov = np.stack([np.stack([sig[:, 0] ** 2, rho * sig[:, 0] * sig[:, 1]], 1),
                    np.stack([rho * sig[:, 0] * sig[:, 1], sig[:, 1] ** 2], 1)], 1)
    return xy, cov


def _draw(rng, cam, xy, cov, S, f_px, floor_used_px):
    """One fitted frame: whitened residuals of the QUEST fit with scalar weights, and their
    expectations (``residual_moments``)."""
    w = cam.unproject(xy)
    _, W, G = direction_info(cam, xy, cov, None, w)
    L = np.linalg.cholesky(cov)
    true_cov = L @ S @ np.swapaxes(L, 1, 2) + f_px ** 2 * np.eye(2)
    dxy = np.einsum("nij,nj->ni", np.linalg.cholesky(true_cov), rng.standard_normal((len(xy), 2)))
    wm = cam.unproject(xy + dxy)
    wts = 1.0 / (0.5 * np.trace(cov, axis1=1, axis2=2) + floor_used_px ** 2)
    C0 = quest(wm, w, wts)                       # the true directions: identity attitude
    z = np.einsum("nij,nj->ni", W, w @ C0 - wm)
    return z, residual_moments(wm, wts, W, G)


def _feed(model, z, X, t_s):
    """Add a frame as the pipeline does: weighted by the model it was processed with."""
    est = model.estimate(t_s)
    model.add(z, X, t_s, None if est is None else [est[0][0, 0], est[0][0, 1], est[0][1, 1], est[1]])


def test_residual_moments_are_the_fitted_residuals_second_moments():
    """A field with one star far brighter than the rest (it carries the fit and shows little
    of its error): Monte Carlo ``z z^T`` against the expectation, star by star."""
    rng = np.random.default_rng(11)
    cam = camera_preset("A1")
    xy, cov = _field(rng, 7, cam)
    cov[0] = np.diag([1e-4, 2e-4])
    S, f = np.array([[0.8, 0.1], [0.1, 0.6]]), 0.05
    theta = np.array([S[0, 0], S[0, 1], S[1, 1], f * f])
    acc, trials = np.zeros((7, 3)), 3000
    for _ in range(trials):
        z, X = _draw(rng, cam, xy, cov, S, f, 0.0)
        acc += np.stack([z[:, 0] ** 2, z[:, 0] * z[:, 1], z[:, 1] ** 2], 1)
    pred = X @ theta
    mc = acc / trials
    # the bright star shows about half its error (the leverage): the prediction sees it
    assert pred[0, 0] < 0.9 * (S[0, 0] + f * f * np.linalg.inv(np.linalg.cholesky(cov[0]).T
                                                                 @ np.linalg.cholesky(cov[0]))[0, 0])
    se = np.sqrt(2.0 / trials) * np.sqrt(pred[:, [0, 0, 2]] * pred[:, [0, 2, 2]])   # ~ std of each mean
    assert np.all(np.abs(mc - pred) < 4.5 * se + 1e-3)


def test_noise_model_recovers_shape_and_floor():
    rng = np.random.default_rng(5)
    cam = camera_preset("A1")
    S_true, f_true = np.array([[1.3, 0.15], [0.15, 0.8]]), 0.05          # 0.05 px: 1.5'' on A1
    model = NoiseModel(window_s=4.0, min_stars=30)
    assert model.estimate(0.0) is None
    for k in range(40):
        xy, cov = _field(rng, 30, cam)
        z, X = _draw(rng, cam, xy, cov, S_true, f_true, 0.005)
        _feed(model, z, X, 0.1 * k)
    S, f2 = model.estimate(3.95)
    # 1200 stars: S's elements to ~0.1 (one standard error; f^2 carries the bright ones)
    assert np.allclose(S, S_true, atol=0.3)
    assert np.sqrt(f2) == pytest.approx(f_true, rel=0.1)
    # a misidentified star far out is left out
    z, X = _draw(rng, cam, *_field(rng, 30, cam), S_true, f_true, 0.005)
    z[0] = [60.0, -40.0]
    _feed(model, z, X, 4.0)
    S2, f2b = model.estimate(4.0)
    assert np.allclose(S2, S_true, atol=0.3) and np.sqrt(f2b) == pytest.approx(f_true, rel=0.1)
    # the window is in seconds: frames older than the model's reach are forgotten
    assert model.estimate(100.0) is None


def test_noise_model_without_a_floor_and_after_cloud():
    rng = np.random.default_rng(8)
    cam = camera_preset("A1")
    clean = NoiseModel()
    for k in range(20):
        _feed(clean, *_draw(rng, cam, *_field(rng, 15, cam), np.eye(2), 0.0, 0.005), 0.1 * k)
    S, f2 = clean.estimate(1.95)
    assert np.allclose(S, np.eye(2), atol=0.2) and np.sqrt(f2) < 0.01
    # seeing, then 2 s of cloud, then 3 frames of 4 stars: the 2 s window alone has 12
    # stars (< 30); the model takes the newest frames before the cloud too, so the floor
    # does not fall back to none
    seeing = NoiseModel()
    for k in range(20):
        _feed(seeing, *_draw(rng, cam, *_field(rng, 15, cam), np.eye(2), 0.05, 0.005), 0.1 * k)
    for k in range(3):
        _feed(seeing, *_draw(rng, cam, *_field(rng, 4, cam), np.eye(2), 0.05, 0.05), 4.0 + 0.1 * k)
    assert [f[0] for f in seeing._recent(4.25, seeing.window_s)] == pytest.approx([1.8, 1.9, 4.0, 4.1, 4.2])
    S, f2 = seeing.estimate(4.25)
    assert np.sqrt(f2) == pytest.approx(0.05, rel=0.4)
    # beyond the model's reach (4 s) nothing is left
    assert seeing.estimate(4.25 + 4.5) is None


def test_compiled_residual_moments_and_quest_are_the_numpy_ones():
    """``residual_moments`` runs compiled (``attitude._ckernels``): against its NumPy
    reference (``_residual_moments_python``, the Monte Carlo test above checks that one) on
    fields of 3 to 60 stars; and the compiled QUEST that the noise model's fit uses against
    ``attitude.quest``.  A singular fit (no weight) is None from both."""
    from shipstar.attitude import _ckernels
    from shipstar.pipeline._conditions import _residual_moments_python

    rng = np.random.default_rng(23)
    cam = camera_preset("A2")
    for n in (3, 8, 25, 60):
        xy, cov = _field(rng, n, cam)
        w = cam.unproject(xy)
        _, W, G = direction_info(cam, xy, cov, None, w)
        wts = rng.uniform(0.1, 10.0, n)
        X, ref = residual_moments(w, wts, W, G), _residual_moments_python(w, wts, W, G)
        assert X.shape == (n, 3, 4)
        np.testing.assert_allclose(X, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
        v = w @ np.linalg.qr(rng.normal(size=(3, 3)))[0].T
        C = np.empty((3, 3))
        _ckernels.quest(np.ascontiguousarray(w * 2.0), np.ascontiguousarray(v), wts, C)
        np.testing.assert_allclose(C, quest(w, v, wts), rtol=0, atol=1e-12)
    no_weight = np.zeros(4)                               # F = 0: singular, no fit
    assert residual_moments(w[:4], no_weight, W[:4], G[:4]) is None
    assert _residual_moments_python(w[:4], no_weight, W[:4], G[:4]) is None


def test_compiled_noise_fit_is_the_numpy_one():
    """``NoiseModel._fit`` runs compiled (``attitude._ckernels.noise_fit``): against its
    NumPy reference ``_fit_python`` on windows of a floor and no floor (the constrained
    ``f^2 = 0`` branch), a shape that needs its eigenvalue raised, and too few stars."""
    rng = np.random.default_rng(29)
    cam = camera_preset("A1")
    cases = [(np.array([[1.3, 0.15], [0.15, 0.8]]), 0.05, 30, 12),     # shape and floor
             (np.array([[0.9, 0.0], [0.0, 1.1]]), 0.0, 30, 12),         # no floor: f^2 <= 0 branch
             (np.array([[0.06, 0.0], [0.0, 1.0]]), 0.0, 4, 2),          # few stars, thin shape
             (np.array([[1.0, 0.0], [0.0, 1.0]]), 0.02, 5, 3)]          # 15 stars: < min_stars
    branches = set()
    for S_true, f_true, n_stars, n_frames in cases:
        for trial in range(6):
            model = NoiseModel(window_s=4.0, min_stars=15 if n_stars < 30 else 30)
            for k in range(n_frames):
                xy, cov = _field(rng, n_stars, cam)
                z, X = _draw(rng, cam, xy, cov, S_true, f_true, 0.005)
                model.add(z, X, 0.1 * k, None)
            frames = list(model._frames)
            a, b = model._fit(frames), model._fit_python(frames)
            assert (a is None) == (b is None)
            if b is None:
                branches.add("none")
                continue
            branches.add("f2=0" if b[1] == 0.0 else "f2>0")
            if np.linalg.eigvalsh(b[0])[0] <= 0.05 * (1 + 1e-6):
                branches.add("raised")
            np.testing.assert_allclose(a[0], b[0], rtol=1e-9, atol=1e-12)
            assert a[1] == pytest.approx(b[1], rel=1e-9, abs=1e-15)
            assert a[2] == pytest.approx(b[2], rel=1e-9)
    assert branches == {"none", "f2=0", "f2>0", "raised"}, branches
