"""The joint fusion's compiled pieces (attitude._ckernels.common_mode, sensor_rows) against
the NumPy code they replace: the same numbers to rounding, on random sensors with and
without information matrices, model and mount covariances."""

from __future__ import annotations

import numpy as np
import pytest

import shipstar.ship as ship
from shipstar.attitude import _ckernels
from shipstar.attitude._horizontal import HorizontalAttitude
from shipstar.pipeline._motion import expm_rotvec
from shipstar.pipeline._sensor import _turned_rows
from shipstar.ship import SensorStars, fuse_joint
from shipstar.units import ASEC2RAD


def _spd(rng, scale):
    A = rng.normal(scale=scale, size=(3, 3))
    return A @ A.T + (0.1 * scale) ** 2 * np.eye(3)


def _sensors(rng, trial):
    C_hor_from_deck = expm_rotvec(rng.normal(size=3))
    out = []
    for s in range(2):
        n = int(rng.integers(4, 30))
        R = expm_rotvec(rng.normal(size=3))
        w = rng.normal(scale=0.1, size=(n, 3)) + [0.0, 0.0, 1.0]
        w /= np.linalg.norm(w, axis=1, keepdims=True)
        v = (C_hor_from_deck @ R @ w.T).T
        w = w + rng.normal(scale=2.0 * ASEC2RAD, size=w.shape)      # measured: arcseconds off
        sigma = rng.uniform(1.0, 3.0, n) * ASEC2RAD
        info = np.stack([_spd(rng, 1.0 / ASEC2RAD) for _ in range(n)]) if trial % 2 else None
        model = _spd(rng, 0.5 * ASEC2RAD) if (trial + s) % 4 else None
        mount = _spd(rng, 3.0 * ASEC2RAD) if trial % 3 == 0 else None
        out.append(SensorStars(w_sensor=w, v_hor=v, C_deck_from_sensor=R, sigma_rad=sigma, info_per_rad2=info,
                               model_covariance_rad2=model, mount_covariance_rad2=mount))
    return out


def _common_mode_args(monkeypatch, sensors):
    """The arguments fuse_joint hands _common_mode_covariance."""
    got = {}
    original = ship._common_mode_covariance

    def capture(*args):
        got["args"] = args
        return original(*args)

    monkeypatch.setattr(ship, "_common_mode_covariance", capture)
    att = fuse_joint(sensors)
    monkeypatch.setattr(ship, "_common_mode_covariance", original)
    assert att.solved
    return got["args"]


def test_common_mode_kernel_gives_the_numpy_covariance(monkeypatch):
    rng = np.random.default_rng(11)
    n_nonzero = 0
    for trial in range(120):
        args = _common_mode_args(monkeypatch, _sensors(rng, trial))
        compiled = ship._common_mode_covariance(*args)
        reference = ship._common_mode_covariance_python(*args)
        scale = np.abs(reference).max()
        np.testing.assert_allclose(compiled, reference, rtol=0.0, atol=1e-12 * scale + 1e-300)
        np.testing.assert_array_equal(compiled, compiled.T)
        n_nonzero += scale > 0
    assert n_nonzero > 60                    # most cases have a model covariance to carry


def test_common_mode_kernel_refuses_bad_rows():
    w, P = np.zeros((3, 3)), np.eye(3)
    with pytest.raises(ValueError, match="common_mode"):
        _ckernels.common_mode(w, np.empty(0), np.ones(3), np.array([0, 3], dtype=np.int64), P, P, P,
                              np.empty(0), np.zeros((3, 3)))


def _horizontal(rng, n, with_info):
    inliers = rng.random(n) > 0.3
    w = rng.normal(size=(n, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    info = np.stack([_spd(rng, 1e5) for _ in range(n)]) if with_info else None
    return HorizontalAttitude(True, "", np.eye(3), np.eye(3) * 1e-11, 1.0, rng.normal(size=n), inliers,
                              int(inliers.sum()), w, rng.normal(size=(n, 3)), rng.uniform(1e-6, 2e-6, n),
                              "per-star", "bennett", info_per_rad2=info)


@pytest.mark.parametrize("with_info", [False, True])
@pytest.mark.parametrize("with_model", [False, True])
def test_turned_rows_are_the_numpy_products(with_info, with_model):
    rng = np.random.default_rng(5)
    for n in (1, 7, 40):
        h = _horizontal(rng, n, with_info)
        model = _spd(rng, 1e-6) if with_model else None
        R = expm_rotvec(rng.normal(scale=1e-3, size=3))
        w, info, model_out, rows = _turned_rows(h, model, R)
        keep = h.inliers
        np.testing.assert_array_equal(rows, np.flatnonzero(keep))
        np.testing.assert_allclose(w, h.w_sensor[keep] @ R.T, rtol=0, atol=1e-15)
        if with_info:
            ref = R @ h.info_per_rad2[keep] @ R.T
            np.testing.assert_allclose(info, ref, rtol=1e-13, atol=1e-13 * np.abs(ref).max())
        else:
            assert info is None
        if with_model:
            np.testing.assert_allclose(model_out, R @ model @ R.T, rtol=1e-13, atol=1e-13 * np.abs(model).max())
        else:
            assert model_out is None


def test_turned_rows_decline_what_they_do_not_know():
    rng = np.random.default_rng(2)
    h = _horizontal(rng, 5, False)
    from dataclasses import replace

    assert _turned_rows(replace(h, inliers=np.arange(5)), None, np.eye(3)) is None      # not a mask
    assert _turned_rows(replace(h, inliers=h.inliers[:4]), None, np.eye(3)) is None    # wrong length


def test_deck_turning_gives_the_numpy_information():
    rng = np.random.default_rng(9)
    sensors = _sensors(rng, 1)                       # information matrices given
    for s in sensors:
        C_ds = np.asarray(s.C_deck_from_sensor, float)
        wd, Wd = ship._turned_to_deck(np.asarray(s.w_sensor, float), s.info_per_rad2, C_ds)
        np.testing.assert_allclose(wd, s.w_sensor @ C_ds.T, rtol=0, atol=1e-15)
        ref = C_ds @ s.info_per_rad2 @ C_ds.T
        np.testing.assert_allclose(Wd, ref, rtol=0, atol=1e-13 * np.abs(ref).max())
    assert ship._turned_to_deck(sensors[0].w_sensor, None, np.eye(3)) is None
