"""Tracking mode: identification by prediction from a prior attitude, with fallback."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shipstar.errors import ShipstarError
from shipstar.frames import matrix_from_q_wxyz
from shipstar.identify import identify_tracking
from shipstar.identify._sim import random_attitudes, simulate_frame


def _rotate(C, angle_deg, rng):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    a = math.radians(angle_deg) / 2
    return C @ matrix_from_q_wxyz(np.concatenate([[math.cos(a)], math.sin(a) * axis]))


def test_prior_within_its_error_gives_the_true_stars(db_a1, cam_a1):
    rng = np.random.default_rng(31)
    solved = 0
    for C in random_attitudes(200, rng):
        f = simulate_frame(db_a1, cam_a1, C, rng, sigma_px=rng.uniform(0.1, 0.3),
                           n_drop=int(rng.integers(0, 4)), n_false=int(rng.integers(0, 4)))
        r = identify_tracking(f.xy_px, db_a1, _rotate(C, 0.1, rng), camera=cam_a1,
                              prior_error_deg=0.2, fallback=False)
        if not r.solved:
            continue
        solved += 1
        m = r.star_index >= 0
        assert r.mode == "tracking" and np.all(r.star_index[m] == f.truth_row[m])
        assert r.n_matched >= 3 and r.p_false <= 1e-6
        err = math.degrees(math.acos(min(1.0, r.C_icrs_from_sensor[:, 0] @ C[:, 0]))) * 3600
        assert err < 3 * cam_a1.pixel_scale_arcsec
    assert solved >= 0.97 * 200


def test_wrong_prior_fails_then_falls_back_to_lost_in_space(db12, cam12):
    rng = np.random.default_rng(32)
    for C in random_attitudes(10, rng):
        f = simulate_frame(db12, cam12, C, rng, sigma_px=0.2, n_false=1)
        far = _rotate(C, 20.0, rng)
        strict = identify_tracking(f.xy_px, db12, far, camera=cam12, fallback=False)
        assert not strict.solved and strict.reason
        r = identify_tracking(f.xy_px, db12, far, camera=cam12)
        assert r.solved and r.mode == "lost_in_space"
        m = r.star_index >= 0
        assert np.all(r.star_index[m] == f.truth_row[m])


def test_false_stars_only_never_track(db12, cam12):
    rng = np.random.default_rng(33)
    for C in random_attitudes(30, rng):
        xy = rng.uniform(0, 511, size=(int(rng.integers(3, 30)), 2))
        r = identify_tracking(xy, db12, C, camera=cam12, prior_error_deg=0.5, fallback=False)
        assert not r.solved


@pytest.mark.parametrize("prior, kw, words", [
    (np.eye(3)[:2], {}, "3, 3"),
    (np.diag([1.0, 1.0, -1.0]), {}, "rotation"),
    (2 * np.eye(3), {}, "rotation"),
    (np.eye(3), {"prior_error_deg": -1.0}, "prior_error_deg"),
    (np.eye(3), {"focal_scale": 3.0}, "focal_scale"),
])
def test_bad_prior_raises(db12, prior, kw, words):
    with pytest.raises(ShipstarError, match=words):
        identify_tracking(np.zeros((5, 3)), db12, prior, **kw)
