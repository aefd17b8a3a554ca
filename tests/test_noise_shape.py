"""Anisotropic centroid errors in the pipeline: the directions' information matrices
(``pipeline._sensor.direction_info``) and the error shape from residuals
(``pipeline._conditions.NoiseShape``).

References: the pinhole camera's analytic derivative at the principal point, and
residuals drawn with a known 2x2 covariance.
"""

from __future__ import annotations

import numpy as np

from shipstar.camera import camera_preset
from shipstar.pipeline._conditions import NoiseShape
from shipstar.pipeline._sensor import direction_info


def test_direction_info_at_the_principal_point_is_the_pinhole_derivative():
    cam = camera_preset("A1")
    s = cam.pixel_mm / cam.f_mm                  # rad per px at the centre
    cov = np.array([[[0.09, 0.03], [0.03, 0.04]]])
    info, whiten = direction_info(cam, np.array([[cam.x0_px, cam.y0_px]]), cov)
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


def test_direction_info_with_a_shape_scales_the_covariance():
    cam = camera_preset("A2")
    xy = np.array([[100.0, 700.0], [900.0, 50.0]])
    cov = np.array([np.diag([0.04, 0.01]), [[0.02, -0.005], [-0.005, 0.03]]])
    S = np.array([[1.7, 0.2], [0.2, 0.8]])
    info_s, _ = direction_info(cam, xy, cov, S)
    L = np.linalg.cholesky(cov)
    info_ref, _ = direction_info(cam, xy, L @ S @ np.swapaxes(L, 1, 2))
    assert np.allclose(info_s, info_ref, rtol=1e-9)


def test_noise_shape_recovers_the_error_covariance_of_whitened_residuals():
    rng = np.random.default_rng(5)
    S_true = np.array([[1.69, 0.25], [0.25, 0.81]])
    L = np.linalg.cholesky(S_true)
    shape = NoiseShape(window_s=4.0, min_stars=30)
    assert shape.matrix(0.0) is None
    m = 30                                        # stars a frame
    for k in range(40):
        z = rng.standard_normal((m, 2)) @ L.T * np.sqrt(1 - 1.5 / m)   # residuals: 3 of 2m dof fitted
        shape.add(z, 0.1 * k)
    S = shape.matrix(4.0)
    # 1200 residuals: each element within ~4 standard errors
    assert np.allclose(S, S_true, atol=0.15)
    # a misidentified star far out is left out
    shape.add(np.vstack([rng.standard_normal((m - 1, 2)) @ L.T, [[60.0, -40.0]]]), 4.0)
    assert np.allclose(shape.matrix(4.05), S_true, atol=0.15)
    # the window is in seconds: frames older than 4 s are forgotten
    assert shape.matrix(100.0) is None
