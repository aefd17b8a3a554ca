"""Windowed extraction (``extract._windowed``) and windowed tracking in the pipeline.

References: the rendered frames' true positions (centroid errors against the
extraction's own Cramer-Rao covariance), the full-frame extraction of the same frame
(the same stars, the same centroids to a fraction of their sigma), and the session's
truth for the pipeline (the same accuracy as every frame extracted whole)."""

from __future__ import annotations

import numpy as np
import pytest

from shipstar.camera import load_camera
from shipstar.errors import ShipstarError
from shipstar.extract._core import frame_extraction
from shipstar.extract._windowed import MAX_BACKGROUND_SHIFT_SIGMA, extract_windows
from shipstar.pipeline import PipelineOptions
from shipstar.simulate._render import render_frame, star_signal_e


def _scene(smear, seed, hot_pixel_fraction=0.0):
    """An A1 frame of a grid of 49 stars (Hp 5-7.5) moving by ``smear`` during the exposure."""
    cam = load_camera("A1")
    rng = np.random.default_rng(seed)
    g = np.arange(7) * 130 + 120.0
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2) + rng.uniform(-0.5, 0.5, (49, 2))
    mag = rng.uniform(5.0, 7.5, len(xy))
    img = render_frame(cam, xy, star_signal_e(cam, mag), rng, smear_px=np.asarray(smear, float),
                       hot_pixel_fraction=hot_pixel_fraction)
    return cam, xy, img


def _tracked_scene(smear, seed):
    """``_scene``'s truth and frame, the full frame's mesh, and ``extract_windows``'s keywords."""
    cam, xy, img = _scene(smear, seed)
    _, mesh, level = frame_extraction(img, psf_sigma_px=cam.psf_sigma_px, gain_e_per_adu=cam.gain_e_per_adu,
                                      smear_px=smear)
    return xy, img, mesh, dict(mesh=mesh, saturation_adu=level, smear_px=smear, psf_sigma_px=cam.psf_sigma_px,
                               gain_e_per_adu=cam.gain_e_per_adu)


def _match(found_xy, true_xy, radius=1.5):
    d = np.linalg.norm(found_xy[:, None, :] - true_xy[None], axis=2)
    j = np.argmin(d, axis=1)
    return j, d[np.arange(len(found_xy)), j] <= radius


@pytest.mark.parametrize("smear", [(0.0, 0.0), (1.0, 0.6), (14.0, -5.0)])
def test_windows_find_the_full_frames_stars_at_the_cramer_rao_bound(smear):
    """Predictions up to 2.5 px off, and 6 over empty sky: every star the full frame finds
    is found, nothing at the empty places, the centroids within 0.35 sigma of the full
    frame's and their errors against the truth at the extraction's own bound."""
    cam, xy, img = _scene(smear, 7)
    full, mesh, level = frame_extraction(img, psf_sigma_px=cam.psf_sigma_px, gain_e_per_adu=cam.gain_e_per_adu,
                                         smear_px=smear if np.hypot(*smear) >= 1.5 else None)
    rng = np.random.default_rng(1)
    empty = np.array([[185.0, 185.0], [445.0, 575.0], [705.0, 315.0], [315.0, 835.0], [835.0, 185.0],
                      [575.0, 705.0]])
    pred = np.vstack([xy + rng.uniform(-2.5, 2.5, xy.shape), empty])
    res = extract_windows(img, pred, mesh=mesh, saturation_adu=level, smear_px=smear,
                          psf_sigma_px=cam.psf_sigma_px, gain_e_per_adu=cam.gain_e_per_adu)
    assert res.ok and res.reason == "" and res.n_predicted == len(pred)
    ex = res.extraction
    j, near = _match(ex.xy_px, xy)
    assert near.all(), ex.xy_px[~near]                           # nothing at the empty places
    jf, near_f = _match(full.xy_px, xy)
    assert set(jf[near_f]) <= set(j) and len(set(j)) == len(j)    # the full frame's stars, once each
    assert len(ex) >= 45
    # the same centroids as the full frame, to a fraction of their sigma
    k = {jj: i for i, jj in enumerate(jf[near_f])}
    both = [(i, np.flatnonzero(near_f)[k[jj]]) for i, jj in enumerate(j) if jj in k]
    w, f = np.array(both).T
    d = np.linalg.norm(ex.xy_px[w] - full.xy_px[f], axis=1) / ex.xy_sigma_px[w]
    assert np.max(d) < 0.35, np.max(d)
    # errors against the truth: RMS of the whitened errors near 1 (Cramer-Rao bound reached)
    e = ex.xy_px - xy[j]
    cov = ex.xy_cov_px2
    z2 = np.einsum("ni,nij,nj->n", e, np.linalg.inv(cov), e) / 2.0
    assert 0.6 < np.sqrt(np.mean(z2)) < 1.35, np.sqrt(np.mean(z2))


def test_background_moved_since_the_full_frame_refuses_the_windows():
    """A sky brighter by more than the allowed shift (cloud lit by the Moon, twilight):
    refused with its reason, the caller extracts the frame whole; within it, accepted."""
    xy, img, mesh, kw = _tracked_scene((10.0, 4.0), 3)
    step = 2.0 * MAX_BACKGROUND_SHIFT_SIGMA * mesh.noise_adu
    brighter = (img.astype(np.int64) + int(np.ceil(step))).astype(np.uint16)
    res = extract_windows(brighter, xy, **kw)
    assert not res.ok and "background moved" in res.reason and res.background_shift_adu > step * 0.8
    same = extract_windows(img, xy, **kw)
    assert same.ok and abs(same.background_shift_adu) < 0.2 * mesh.noise_adu
    other = extract_windows(img[:512], xy, **kw)
    assert not other.ok and "mesh" in other.reason
    none = extract_windows(img, xy + 5000.0, **kw)
    assert not none.ok and none.reason == "no predicted star in the frame"


def test_windows_with_a_trusted_smear_use_it_as_it_is_and_refuse_a_bad_error(monkeypatch):
    """``smear_sigma_px`` as for ``extract_stars``: within 0.05 px the smear is not measured
    again from the windows' streaks, and the stars are found as well; a bad value is a
    one-line error."""
    from shipstar.errors import ShipstarError
    from shipstar.extract import _smeared

    xy, img, mesh, kw = _tracked_scene((10.0, 4.0), 5)
    calls = []
    refined = _smeared._refined_smear
    monkeypatch.setattr(_smeared, "_refined_smear", lambda *a, **k: calls.append(1) or refined(*a, **k))
    measured = extract_windows(img, xy, **kw)
    assert measured.ok and len(calls) == 1
    trusted = extract_windows(img, xy, smear_sigma_px=0.01, **kw)
    assert trusted.ok and len(calls) == 1
    np.testing.assert_array_equal(trusted.extraction.smear_px, kw["smear_px"])
    j, near = _match(trusted.extraction.xy_px, xy)
    assert near.all() and len(set(j)) == len(trusted.extraction) >= len(measured.extraction) - 1
    for bad in (-1.0, np.nan):
        with pytest.raises(ShipstarError, match="smear_sigma_px") as info:
            extract_windows(img, xy, smear_sigma_px=bad, **kw)
        assert "\n" not in str(info.value)


def test_hot_pixels_and_cosmic_rays_in_a_window_are_not_stars():
    """Single hot pixels (far above the threshold) at predicted places with no star, and
    one beside a star: none found as a star, the star's centroid unmoved."""
    xy, img, mesh, kw = _tracked_scene((8.0, 3.0), 5)
    clean = extract_windows(img, xy, **kw).extraction
    hot = img.copy()
    spots = np.array([[185, 185], [445, 575], [705, 315]])
    for x, y in spots:
        hot[y, x] = hot[y, x] + 60 * int(np.ceil(mesh.noise_adu))
    x0, y0 = np.rint(xy[24]).astype(int)
    hot[y0 + 6, x0 - 2] += 60 * int(np.ceil(mesh.noise_adu))      # beside a star, off its streak
    res = extract_windows(hot, np.vstack([xy, spots]), **kw)
    assert res.ok
    _, near = _match(res.extraction.xy_px, xy)
    assert near.all()
    i = np.argmin(np.linalg.norm(clean.xy_px - xy[24], axis=1))
    k = np.argmin(np.linalg.norm(res.extraction.xy_px - xy[24], axis=1))
    assert np.linalg.norm(res.extraction.xy_px[k] - clean.xy_px[i]) < 0.1 * clean.xy_sigma_px[i]


@pytest.mark.parametrize("value", [-1, True, 1.5, "3"])
def test_windowed_option_is_a_whole_number_of_frames(value):
    with pytest.raises(ShipstarError, match="windowed_full_frame_every"):
        PipelineOptions(windowed_full_frame_every=value)


def test_windowed_tracking_in_a_sea_session_is_as_accurate_as_full_frames():
    """A 3 s image-level sea session (two sensors, 10 frames/s, 30 ms exposures) measured with
    every frame whole and with windowed tracking (a full frame every 5): most tracked
    frames windowed, every frame solved, and the joint attitudes' errors against the truth
    as small (RMS within 10 % + 0.02'' per axis)."""
    import sys
    from pathlib import Path

    from shipstar.pipeline import attitude_errors_arcsec, method_series, process_session

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_pipeline import _image_sea_session

    _, frames, track, weather, truth, configs = _image_sea_session(3.0, 0.03)
    whole = process_session(configs, frames, track, weather, PipelineOptions())
    assert not any(fr.windowed for per in whole.frames for fr in per)
    windowed = process_session(configs, frames, track, weather, PipelineOptions(windowed_full_frame_every=5))
    n = len(frames[0])
    counts = [sum(fr.windowed for fr in per) for per in windowed.frames]
    assert all(c >= 0.6 * n for c in counts) and all(len(per) == n for per in windowed.frames), counts
    assert all(fr.solved for per in windowed.frames for fr in per)

    def rms(res):
        err = attitude_errors_arcsec(method_series(res, "joint"), truth)[10:]
        return np.sqrt(np.nanmean(err ** 2, axis=0))

    assert np.all(rms(windowed) <= 1.1 * rms(whole) + 0.02), (rms(windowed), rms(whole))


@pytest.mark.parametrize("offset", [(5.0, -4.0), (-11.0, 9.0)])
def test_the_predictions_common_error_is_measured_and_removed(offset):
    """Every prediction off by the same (5, -4) px -- the predicted attitude's error -- plus
    +-0.7 px each, beyond the 2 px search: the brightest predictions' peaks measure the
    common error and every star is found where the full frame finds it; (-11, 9) px is
    beyond the windows, which are then put at the moved predictions."""
    smear = (12.0, 4.0)
    cam, xy, img = _scene(smear, 11)
    full, mesh, level = frame_extraction(img, psf_sigma_px=cam.psf_sigma_px, gain_e_per_adu=cam.gain_e_per_adu,
                                         smear_px=smear)
    rng = np.random.default_rng(2)
    pred = xy - np.array(offset) + rng.uniform(-0.7, 0.7, xy.shape)
    res = extract_windows(img, pred, mesh=mesh, saturation_adu=level, smear_px=smear,
                          psf_sigma_px=cam.psf_sigma_px, gain_e_per_adu=cam.gain_e_per_adu, search_px=2.0)
    assert res.ok
    j, near = _match(res.extraction.xy_px, xy)
    jf, near_f = _match(full.xy_px, xy)
    assert near.all() and set(jf[near_f]) <= set(j), (len(res.extraction), near_f.sum())


def test_compiled_window_peaks_are_the_numpy_reference_bit_for_bit():
    """The windows' line-filter peaks (``_windowed._peaks``), compiled, against the NumPy code
    they replaced (kept as the reference): the same offsets and SNR, bit for bit, for the
    taps of a point (3 x 3) and of streaks in every direction, searched about the centre or
    a moved one, with masked pixels; and the same refusal of taps beyond the windows."""
    from shipstar.extract._streak import StreakWindows
    from shipstar.extract._windowed import _peaks, _peaks_python, _taps

    rng = np.random.default_rng(46)
    for trial, (smear, search, centre) in enumerate([((0.0, 0.0), 2, (0, 0)), ((4.0, 1.0), 2, (0, 0)),
                                                     ((-3.0, 12.0), 3, (1, -2)), ((9.0, -9.0), 8, (0, 0)),
                                                     ((1.6, 0.2), 1, (-1, 1))]):
        taps, reach = _taps(np.array(smear), 1.0)
        n = 30
        wy, wx = 2 * (reach[1] + search + 3) + 1, 2 * (reach[0] + search + 3) + 1
        values = rng.normal(100.0, 3.0, (n, wy, wx))
        values[:, wy // 2, wx // 2] += rng.uniform(0, 200, n)
        win = StreakWindows(values=values, valid=rng.random((n, wy, wx)) > 0.05, x0=np.zeros(n), y0=np.zeros(n),
                            noise=rng.uniform(2.5, 3.5, n), bg=rng.uniform(98, 102, n))
        local = rng.normal(0, 0.5, n)
        got, want = _peaks(win, taps, search, 1.1, local, centre), _peaks_python(win, taps, search, 1.1, local, centre)
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, w, err_msg=str(trial))
    with pytest.raises(ValueError, match="too small"):
        _peaks(win, taps, wx, 1.0, local)


def test_compiled_ring_levels_are_the_numpy_reference_bit_for_bit():
    """The windows' border-ring background (``_windowed._ring_shift``), compiled, against the
    NumPy code it replaced (kept as the reference): the same pooled level and per-window
    levels, bit for bit -- the median of the valid ring pixels (odd and even counts, integer
    data with many ties), stars in the rings left out, windows without a valid ring pixel (0),
    none at all (NaN) -- for windows of many sizes."""
    import math

    from shipstar.extract._streak import StreakWindows
    from shipstar.extract._windowed import _ring_shift, _ring_shift_python

    rng = np.random.default_rng(47)
    for trial in range(200):
        n = int(rng.integers(1, 40))
        wy, wx = (int(v) for v in rng.integers(5, 30, 2))
        values = rng.normal(100.0, 2.0, (n, wy, wx))
        if trial % 2:
            values = np.round(values)                                  # integer data: ties at the median
        values[rng.random(values.shape) < 0.02] += 500.0               # stars and hot pixels in the rings
        valid = rng.random((n, wy, wx)) > (0.1 if trial % 5 else 1.1)  # every fifth: no valid pixel
        valid[: n // 4] &= trial % 3 != 0                              # some windows without one
        win = StreakWindows(values=values, valid=valid, x0=np.zeros(n), y0=np.zeros(n),
                            noise=rng.uniform(1.0, 3.0, n), bg=rng.uniform(99.0, 101.0, n))
        (level, own), (level_ref, own_ref) = _ring_shift(win), _ring_shift_python(win)
        assert level == level_ref or (math.isnan(level) and math.isnan(level_ref)), trial
        np.testing.assert_array_equal(own, own_ref, err_msg=str(trial))


def test_compiled_crowding_test_is_the_numpy_reference():
    """The windows' crowding test (``_windowed._crowded``: bright pixels outside the star's
    footprint), compiled, against the NumPy code it replaced (kept as the reference): the
    same answer for points and streaks in every direction, stars off the window's centre,
    masked pixels, trails across the windows, and no window."""
    from shipstar.extract._streak import StreakWindows
    from shipstar.extract._windowed import _crowded, _crowded_python

    rng = np.random.default_rng(49)
    for trial in range(60):
        n, wy, wx = 40, int(rng.integers(9, 31)), int(rng.integers(9, 31))
        values = rng.normal(100.0, 3.0, (n, wy, wx))
        line = rng.random(n) < 0.3                                      # a trail across some windows
        values[line, int(rng.integers(0, wy)), :] += 60.0
        values[rng.random(values.shape) < 0.01] += 40.0
        win = StreakWindows(values=values, valid=rng.random((n, wy, wx)) > 0.05, x0=np.zeros(n), y0=np.zeros(n),
                            noise=rng.uniform(2.5, 3.5, n), bg=rng.uniform(98, 102, n))
        dx, dy = rng.integers(-3, 4, n), rng.integers(-3, 4, n)
        smear = np.zeros(2) if trial % 4 == 0 else rng.normal(0.0, 6.0, 2)
        np.testing.assert_array_equal(_crowded(win, dx, dy, smear, 1.1, 1.2),
                                      _crowded_python(win, dx, dy, smear, 1.1, 1.2), err_msg=str(trial))
    empty = StreakWindows(values=np.zeros((0, 9, 9)), valid=np.zeros((0, 9, 9), bool), x0=np.zeros(0), y0=np.zeros(0),
                          noise=np.zeros(0), bg=np.zeros(0))
    assert _crowded(empty, np.zeros(0, int), np.zeros(0, int), np.ones(2), 1.0, 1.0).shape == (0,)
