"""Tracking mode: identification by prediction from a prior attitude, with fallback."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shipstar.errors import ShipstarError
from shipstar.frames import matrix_from_q_wxyz
from shipstar.identify import identify_tracking
from shipstar.identify._sim import random_attitudes, rotated_about_random_axis, simulate_frame


_rotate = rotated_about_random_axis          # a prior angle_deg off the truth


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
    (np.eye(3)[[1, 0, 2]], {}, "rotation"),                        # rows swapped: a mirror
    (np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1e-3, 0.0, 1.0]]), {}, "rotation"),  # det 1, sheared
    (np.where(np.eye(3) > 0, np.nan, 0.0), {}, "non-finite"),
    (np.array([[np.inf, 0, 0], [0, 1, 0], [0, 0, 1]]), {}, "non-finite"),
    (np.eye(3), {"prior_error_deg": -1.0}, "prior_error_deg"),
    (np.eye(3), {"focal_scale": 3.0}, "focal_scale"),
])
def test_bad_prior_raises(db12, prior, kw, words):
    with pytest.raises(ShipstarError, match=words):
        identify_tracking(np.zeros((5, 3)), db12, prior, **kw)


def test_rotation_priors_within_rounding_are_accepted(db12, cam12):
    # a float32 prior, one perturbed at 1e-9 and a nested list are rotations; the prior
    # check accepts them and tracking finds the stars (reference: the simulated truth)
    rng = np.random.default_rng(35)
    (C,) = random_attitudes(1, rng)
    f = simulate_frame(db12, cam12, C, rng)
    for prior in (C.astype(np.float32), C + 1e-9 * rng.normal(size=(3, 3)), C.tolist()):
        r = identify_tracking(f.xy_px, db12, prior, camera=cam12, fallback=False)
        assert r.solved and r.mode == "tracking"
        m = r.star_index >= 0
        assert m.sum() >= 5 and np.all(r.star_index[m] == f.truth_row[m])


# -- speed-path pieces against independent references ------------------------------------

def test_the_prior_error_bound_covers_the_motion_beyond_the_common_shift():
    """``shift_gate``'s ``e``: a rotation by theta moves the image points by the centre's
    shift plus at most ``e`` (checked on the image edge and a grid, random axes)."""
    from shipstar.identify._tracking import shift_gate

    rng = np.random.default_rng(41)
    g = np.linspace(-1.0, 1.0, 9)
    for half_fov_deg in (4.3, 6.0, 15.0):
        ht = math.tan(math.radians(half_fov_deg))
        ty, tz = (a.ravel() * ht for a in np.meshgrid(g, g))
        u = np.stack([np.ones_like(ty), ty, tz], axis=1)
        h = math.hypot(ht, ht)
        for theta_deg in (0.05, 0.5, 2.0):
            theta = math.radians(theta_deg)
            e = shift_gate(theta, h, 0.0) / (2.0 * math.sqrt(2.0))
            worst = 0.0
            for _ in range(40):
                R = _rotate(np.eye(3), theta_deg * rng.uniform(0.2, 1.0), rng)
                w = u @ R                                   # the same sky seen rotated
                t = w[:, 1:] / w[:, :1]
                d = t - u[:, 1:]
                d0 = d[len(d) // 2]                         # the boresight's shift
                worst = max(worst, float(np.max(np.hypot(*(d - d0).T))))
            assert worst <= e and worst > 0.25 * e           # a bound, and not a loose one


def test_wahba_core_equals_the_svd_solution():
    """The QUEST core on prepared unit vectors (with and without a nearby frame) against
    Markley's SVD solution, including attitudes near 180 deg from the identity."""
    from shipstar.attitude import svd_attitude
    from shipstar.identify._kernels import wahba as compiled_wahba
    from shipstar.identify._verify import wahba

    rng = np.random.default_rng(42)
    for C in list(random_attitudes(30, rng)) + [np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0])]:
        w = np.c_[np.ones(12), rng.uniform(-0.08, 0.08, (12, 2))]
        w /= np.linalg.norm(w, axis=1)[:, None]
        v = w @ C.T + rng.normal(0.0, 2e-5, (12, 3))
        v /= np.linalg.norm(v, axis=1)[:, None]
        ref = svd_attitude(w, v)
        assert np.abs(wahba(w, v) - ref).max() < 1e-11
        assert np.abs(wahba(w, v, _rotate(C, 0.3, rng)) - ref).max() < 1e-11
        assert np.abs(compiled_wahba(w, v) - ref).max() < 1e-11       # the compiled QUEST
        for k in (2, 3, 4):                                            # as few stars as it sees
            assert np.abs(compiled_wahba(w[:k], v[:k]) - svd_attitude(w[:k], v[:k])).max() < 1e-9


def test_cell_stars_are_the_sky_grid_rows(db_a1):
    from shipstar.identify._verify import cell_stars

    rng = np.random.default_rng(43)
    for d in random_attitudes(50, rng)[:, :, 0]:
        rows, u = cell_stars(db_a1, d)
        assert np.array_equal(rows, db_a1.near(d))
        ref = db_a1.u_icrs[rows].astype(float)
        assert np.abs(u - ref / np.linalg.norm(ref, axis=1)[:, None]).max() < 1e-15
        assert cell_stars(db_a1, d)[0] is rows                 # the cached arrays


# -- tracking behaviour --------------------------------------------------------------------

def _stream(n, rng, rate_deg_s=2.0, sway_deg=5.0):
    """A sensor on a ship at 10 frames/s: a steady turn plus a sway (<= ~0.4 deg a frame)."""
    C0 = random_attitudes(1, rng)[0]
    a1, a2 = (v / np.linalg.norm(v) for v in rng.normal(size=(2, 3)))

    def rot(axis, ang):
        return matrix_from_q_wxyz(np.concatenate([[math.cos(ang / 2)], math.sin(ang / 2) * axis]))

    return [C0 @ rot(a1, math.radians(rate_deg_s * 0.1 * k))
            @ rot(a2, math.radians(sway_deg) * math.sin(2 * math.pi * 0.1 * k / 8.0)) for k in range(n)]


def test_a_stream_is_tracked_frame_after_frame(db_a1, cam_a1):
    """Each frame tracked from the previous solutions extrapolated (as the pipeline does):
    every frame solved, every matched star right, the attitude within a pixel."""
    from shipstar.pipeline._sensor import extrapolate_rotation

    rng = np.random.default_rng(44)
    truth = _stream(120, rng)
    sols = [truth[0]]
    for k in range(1, len(truth)):
        f = simulate_frame(db_a1, cam_a1, truth[k], rng, sigma_px=0.2, n_drop=int(rng.integers(0, 4)),
                           n_false=int(rng.integers(0, 4)))
        prior = sols[-1] if len(sols) < 2 else extrapolate_rotation(sols[-2], sols[-1], 1.0)
        r = identify_tracking(f.xy_px, db_a1, prior, camera=cam_a1, prior_error_deg=0.5, fallback=False)
        assert r.solved, r.reason
        m = r.star_index >= 0
        assert np.all(r.star_index[m] == f.truth_row[m]) and r.n_matched >= 0.8 * np.count_nonzero(f.truth_row >= 0)
        err = math.degrees(math.acos(min(1.0, r.C_icrs_from_sensor[:, 0] @ truth[k][:, 0]))) * 3600
        assert err < cam_a1.pixel_scale_arcsec
        sols.append(r.C_icrs_from_sensor)


def test_a_prior_off_by_more_than_the_star_spacing_is_found_by_the_offset_vote(db_a1, cam_a1):
    """2 deg of prior error (~240 px, more than the typical distance between stars): the
    nearest-neighbour median fails, the vote on all offsets finds the shift."""
    from shipstar.identify._field import field_from_camera
    from shipstar.identify._tracking import tracking

    rng = np.random.default_rng(45)
    solved = votes = 0
    for C in random_attitudes(40, rng):
        f = simulate_frame(db_a1, cam_a1, C, rng, sigma_px=0.2, n_drop=int(rng.integers(0, 4)),
                           n_false=int(rng.integers(0, 4)))
        stats = {}
        r = tracking(field_from_camera(f.xy_px, cam_a1, error_px=1.0), db_a1, _rotate(C, 2.0, rng),
                     prior_error_rad=math.radians(2.0), stats=stats)
        votes += stats["voted"]
        if r.solved:
            solved += 1
            m = r.star_index >= 0
            assert np.all(r.star_index[m] == f.truth_row[m]) and r.p_false <= 1e-6
    assert solved >= 38 and votes >= 20


def test_two_stars_on_one_catalog_star_match_neither(db12, cam12):
    """A second detection 0.3 px from a star (within the fine gate, closer to the
    prediction than the star itself may be): that catalog star is ambiguous."""
    rng = np.random.default_rng(46)
    for C in random_attitudes(10, rng):
        f = simulate_frame(db12, cam12, C, rng, sigma_px=0.2)
        k = 3
        xy = np.insert(f.xy_px, k + 1, f.xy_px[k] + [0.3, 0.0], axis=0)
        truth = np.insert(f.truth_row, k + 1, -1)
        r = identify_tracking(xy, db12, _rotate(C, 0.1, rng), camera=cam12, prior_error_deg=0.2,
                              fallback=False)
        assert r.solved and r.star_index[k] == -1 and r.star_index[k + 1] == -1
        m = r.star_index >= 0
        assert np.all(r.star_index[m] == truth[m]) and r.n_matched >= np.count_nonzero(truth >= 0) - 2


# -- the pipeline's per-frame helpers (pipeline/_sensor.py) ---------------------------------

def test_prior_extrapolation_matches_the_rotation_vector_helpers():
    from shipstar.pipeline._rotation import expm_rotvec, rotvec
    from shipstar.pipeline._sensor import extrapolate_rotation

    rng = np.random.default_rng(47)
    for C in random_attitudes(20, rng):
        Cb = _rotate(C, rng.uniform(0.0, 3.0), rng)
        for ratio in (0.0, 0.3, 1.0, 2.5):
            ref = Cb @ expm_rotvec(rotvec(C.T @ Cb) * ratio)
            assert np.abs(extrapolate_rotation(C, Cb, ratio) - ref).max() < 1e-13
    assert np.array_equal(extrapolate_rotation(np.eye(3), np.eye(3), 1.0), np.eye(3))


def test_rank_by_flux_is_stable_and_puts_non_finite_last():
    from shipstar.pipeline._sensor import rank_by_flux

    order = rank_by_flux([5.0, np.nan, 9.0, 5.0, -np.inf, 1.0])
    assert order.tolist() == [2, 0, 3, 5, 1, 4]


def test_the_pipeline_drops_a_trail_before_identification(db_a1, cam_a1):
    """A bright satellite trail (flagged elongated, the brightest object, 42 px long) is
    rejected before identification (pipeline/_conditions.py, extract/_artifacts.py): every
    other detection reaches it and the frame identifies."""
    from shipstar.extract import FLAG_ELONGATED, extract_stars
    from shipstar.pipeline import Frame, SensorConfig, Track, WeatherTable, process_sensor
    from shipstar.simulate._render import FalseObjects, render_frame, star_signal_e
    from shipstar.sky.time import utc_jd_from_iso

    rng = np.random.default_rng(48)
    C = random_attitudes(1, rng)[0]
    f = simulate_frame(db_a1, cam_a1, C, rng, sigma_px=0.0, mag_sigma=0.0, margin_px=8.0)
    signal = star_signal_e(cam_a1, db_a1.mag[f.truth_row])
    trail = FalseObjects(trail_xy_px=[[[300.0, 400.0], [340.0, 412.0]]], trail_signal_e=[4.0 * signal.max()])
    image = render_frame(cam_a1, f.xy_px, signal, rng, false_objects=trail)
    ex = extract_stars(image, psf_sigma_px=cam_a1.psf_sigma_px, gain_e_per_adu=cam_a1.gain_e_per_adu)
    assert np.any(ex.flags & FLAG_ELONGATED)                      # the premise
    jd = utc_jd_from_iso("2013-03-15T12:16:00")
    (res,) = process_sensor(SensorConfig("A1", cam_a1), [Frame(*jd, "trail", image=image)],
                            Track.fixed(31.9, 120.3), WeatherTable.constant(1013.0, 10.0))
    assert res.identification == "lost_in_space" and res.n_detected == len(ex.xy_px) - 1
    assert res.n_identified >= 0.8 * len(f.xy_px)


def test_the_union_bound_bounds_the_binomial_tail():
    from scipy.stats import binom

    from shipstar.identify._ckernels import tail_bound

    for n in (1, 5, 40, 58):
        for k in range(-1, n + 2):
            for p in (0.0, 1e-9, 1e-4, 0.02, 0.3, 1.0):
                exact = 1.0 if k <= 0 else float(binom.sf(k - 1, n, p))
                assert tail_bound(n, k, p) >= exact * (1 - 1e-12)
    assert tail_bound(40, 30, 1e-3) < 1e-60                      # and useful where it is used


def test_the_compiled_binomial_tail_equals_scipy():
    """The chance probabilities of the compiled search: P(Bin(n, p) >= k) against
    scipy.stats.binom.sf to 1e-10 (relative), down to ~1e-300."""
    from scipy.stats import binom

    from shipstar.identify._ckernels import binom_tail

    for n in (0, 1, 5, 23, 40, 58, 60):                  # the searches use n <= 60
        for k in range(-1, n + 2):
            for p in (0.0, 1e-12, 1e-6, 1e-3, 0.02, 0.3, 0.9, 1.0):
                exact = 1.0 if k <= 0 else (0.0 if k > n else float(binom.sf(k - 1, n, p)))
                got = binom_tail(n, k, p)
                assert abs(got - exact) <= 1e-10 * exact + 1e-300, (n, k, p, got, exact)
