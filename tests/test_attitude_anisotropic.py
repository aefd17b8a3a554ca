"""solve_attitude with per-direction information matrices (anisotropic centroid errors).

References: the Cramer-Rao bound of the rotation from directions with known 2x2 noise
covariances in their tangent planes, built here from its definition (the Fisher
information of the tangent-plane measurements, by finite differences of the model), and
Monte Carlo trials with that noise.
"""

from __future__ import annotations

import numpy as np
import pytest

from shipstar.attitude import solve_attitude
from shipstar.errors import ShipstarError
from shipstar.frames import C_icrs_from_sensor
from shipstar.units import ASEC2RAD, DEG2RAD

N_STARS = 12
HALF_FIELD_RAD = 4.0 * DEG2RAD


def _field(rng, n=N_STARS):
    """Unit directions in a 8 deg field around the sensor X axis, (n, 3)."""
    yz = rng.uniform(-HALF_FIELD_RAD, HALF_FIELD_RAD, (n, 2))
    w = np.column_stack([np.ones(n), yz])
    return w / np.linalg.norm(w, axis=1, keepdims=True)


def _tangent_basis(w):
    """Two orthonormal vectors (n, 2, 3) perpendicular to each direction ``w`` (n, 3)."""
    a = np.cross(w, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(w, a)
    return np.stack([a, b], axis=1)


def _streak_noise(rng, w, along_rad, across_rad, angle_rad):
    """Per-star tangent-plane covariances: ``along_rad`` along a direction at ``angle_rad``
    (a number or one per star) in each tangent basis, ``across_rad`` across; returns
    (basis (n, 2, 3), cov (n, 2, 2))."""
    T = _tangent_basis(w)
    ang = np.broadcast_to(np.asarray(angle_rad, float), (len(w),))
    c, s = np.cos(ang), np.sin(ang)
    R = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], 1)
    return T, R @ np.diag([along_rad ** 2, across_rad ** 2]) @ np.swapaxes(R, 1, 2)


def _info(T, cov2):
    """Information matrices (n, 3, 3): ``T^T cov^-1 T``."""
    return np.swapaxes(T, 1, 2) @ np.linalg.inv(cov2) @ T


def _noisy(rng, w, T, cov2):
    L = np.linalg.cholesky(cov2)
    z = rng.standard_normal((len(w), 2))
    d = np.einsum("nij,nj->ni", L, z)
    wn = w + np.einsum("ni,nij->nj", d, T)
    return wn / np.linalg.norm(wn, axis=1, keepdims=True)


def _fisher_by_finite_differences(C, w, T, cov2, h=1e-7):
    """Fisher information of the body-axis rotation error from tangent-plane measurements:
    the model ``w_i(e) = (C exp([e]x))^T v_i`` differentiated numerically."""
    v = w @ C.T
    F = np.zeros((3, 3))

    def model(e):
        t = np.linalg.norm(e)
        K = np.array([[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]])
        E = np.eye(3) + (np.sin(t) / t if t else 1.0) * K + ((1 - np.cos(t)) / t ** 2 if t else 0.5) * K @ K
        return v @ (C @ E)                      # rows (C E)^T v_i

    H = np.zeros((len(w), 2, 3))
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        d = (model(e) - model(-e)) / (2 * h)   # (n, 3)
        H[:, :, k] = np.einsum("nij,nj->ni", T, d)
    for i in range(len(w)):
        F += H[i].T @ np.linalg.inv(cov2[i]) @ H[i]
    return F


def test_covariance_is_the_cramer_rao_bound_of_anisotropic_noise():
    rng = np.random.default_rng(1)
    C = C_icrs_from_sensor(1.0, 0.3, 0.2)
    w = _field(rng)
    T, cov2 = _streak_noise(rng, w, 3.0 * ASEC2RAD, 1.0 * ASEC2RAD, 0.4)
    sigma_iso = np.sqrt(0.5 * np.trace(cov2, axis1=1, axis2=2))
    sol = solve_attitude(w, w @ C.T, sigma_rad=sigma_iso, info_per_rad2=_info(T, cov2))
    assert sol.solved
    P_ref = np.linalg.inv(_fisher_by_finite_differences(C, w, T, cov2))
    assert np.allclose(sol.covariance_rad2, P_ref, rtol=1e-5, atol=1e-12 * ASEC2RAD ** 2)


@pytest.mark.slow
def test_monte_carlo_errors_follow_the_anisotropic_covariance_and_beat_scalar_weights():
    rng = np.random.default_rng(7)
    C = C_icrs_from_sensor(2.0, -0.5, 1.0)
    w = _field(rng)
    v = w @ C.T
    # streaks in several directions (a turn about the boresight streaks tangentially)
    T, cov2 = _streak_noise(rng, w, 4.0 * ASEC2RAD, 0.8 * ASEC2RAD, rng.uniform(0, np.pi, len(w)))
    info = _info(T, cov2)
    sigma_iso = np.sqrt(0.5 * np.trace(cov2, axis1=1, axis2=2))
    trials = 600
    err_a, err_s, z2_abs, z2_rel = [], [], [], []
    for _ in range(trials):
        wn = _noisy(rng, w, T, cov2)
        a = solve_attitude(wn, v, sigma_rad=sigma_iso, info_per_rad2=info, reject_outliers=False)
        r = solve_attitude(wn, v, weights=sigma_iso ** -2, info_per_rad2=info, reject_outliers=False)
        s = solve_attitude(wn, v, sigma_rad=sigma_iso, reject_outliers=False)
        D = C.T @ a.C_ref_from_body
        e = np.array([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]]) / 2
        Ds = C.T @ s.C_ref_from_body
        es = np.array([Ds[2, 1] - Ds[1, 2], Ds[0, 2] - Ds[2, 0], Ds[1, 0] - Ds[0, 1]]) / 2
        err_a.append(e)
        err_s.append(es)
        z2_abs.append(e @ np.linalg.solve(a.covariance_rad2, e))
        z2_rel.append(e @ np.linalg.solve(r.covariance_rad2, e))
    err_a, err_s = np.array(err_a), np.array(err_s)
    P = a.covariance_rad2
    # the errors' covariance is the bound: per axis within the 600-trial sampling error (~6 %)
    ratio = np.sqrt(np.mean(err_a ** 2, axis=0) / np.diag(P))
    assert np.all((ratio > 0.85) & (ratio < 1.15)), ratio
    # chi-square of the 3-D error: mean 3 with the absolute covariance and about 3 with the
    # variance factor estimated from the residuals (2N - 3 = 21 degrees of freedom)
    assert 2.6 < np.mean(z2_abs) < 3.4
    assert 2.6 < np.mean(z2_rel) < 3.9
    # weighting each axis by its own error beats scalar (QUEST) weights
    assert np.sum(np.mean(err_a ** 2, axis=0)) < 0.8 * np.sum(np.mean(err_s ** 2, axis=0))


def test_isotropic_information_gives_the_scalar_solution():
    rng = np.random.default_rng(3)
    C = C_icrs_from_sensor(0.2, 1.0, -2.0)
    w = _field(rng)
    sig = rng.uniform(0.5, 2.0, len(w)) * ASEC2RAD
    T = _tangent_basis(w)
    cov2 = sig[:, None, None] ** 2 * np.eye(2)
    wn = _noisy(rng, w, T, cov2)
    a = solve_attitude(wn, w @ C.T, sigma_rad=sig, info_per_rad2=_info(T, cov2))
    s = solve_attitude(wn, w @ C.T, sigma_rad=sig)
    # QUEST with sigma^-2 weights is already the isotropic optimum: same rotation, same covariance
    assert np.allclose(a.C_ref_from_body, s.C_ref_from_body, atol=1e-6 * ASEC2RAD)
    assert np.allclose(a.covariance_rad2, s.covariance_rad2, rtol=1e-9)


def test_bad_information_matrices_are_refused():
    w = _field(np.random.default_rng(0), 5)
    with pytest.raises(ShipstarError, match="info_per_rad2"):
        solve_attitude(w, w, info_per_rad2=np.ones((4, 3, 3)))
    bad = np.zeros((5, 3, 3))
    bad[0, 0, 0] = np.nan
    with pytest.raises(ShipstarError, match="info_per_rad2"):
        solve_attitude(w, w, info_per_rad2=bad)


def test_information_without_an_axis_falls_back_to_the_scalar_solution():
    rng = np.random.default_rng(4)
    C = C_icrs_from_sensor(0.7, 0.1, 0.3)
    w = _field(rng, 6)
    sig = np.full(len(w), 1.0 * ASEC2RAD)
    info = np.zeros((len(w), 3, 3))               # no information at all: nothing to refine with
    a = solve_attitude(w, w @ C.T, sigma_rad=sig, info_per_rad2=info)
    s = solve_attitude(w, w @ C.T, sigma_rad=sig)
    assert a.solved and a.info_per_rad2 is None
    assert np.allclose(a.C_ref_from_body, s.C_ref_from_body) and np.allclose(a.covariance_rad2, s.covariance_rad2)
