"""Image formation (shipstar.simulate._render) against analytic truth.

References: the normal CDF (scipy.stats.norm) and numerical quadrature for the pixel
integral, exact moments of a Gaussian convolved with a uniform segment for the smear,
Poisson + Gaussian noise moments for the noise chain, and chi-square tests of the
sampled pixel values against the exact distributions (scipy.stats.poisson, norm) and
against numpy's own Poisson and normal samplers.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, stats

from shipstar.camera import camera_preset
from shipstar.errors import ShipstarError
from shipstar.simulate._render import (
    FalseObjects,
    pixel_fractions,
    render_frame,
    render_image_e,
    star_signal_e,
)

SHAPE = (64, 80)


def small_camera(**changes):
    """Sensor A1's detector cut to 128 x 96 px (the optics do not matter here)."""
    base = dict(width_px=128, height_px=96, x0_px=63.5, y0_px=47.5)
    base.update(changes)
    return camera_preset("A1").replace(**base)


def moments(image):
    rows, cols = np.indices(image.shape)
    total = image.sum()
    cx, cy = (image * cols).sum() / total, (image * rows).sum() / total
    return total, cx, cy, (image * (cols - cx) ** 2).sum() / total, (image * (rows - cy) ** 2).sum() / total


# ---------------------------------------------------------------- PSF integral

@pytest.mark.parametrize("centre, sigma", [(10.0, 0.8), (10.37, 0.5), (9.5, 1.7), (10.2, 0.3)])
def test_pixel_fraction_is_the_integral_of_the_gaussian_over_the_pixel(centre, sigma):
    first, size = 2, 17
    frac = pixel_fractions(np.array([centre]), np.array([first]), size, sigma)[0]
    for k, value in enumerate(frac):
        lo, hi = first + k - 0.5, first + k + 0.5
        quad, _ = integrate.quad(stats.norm(centre, sigma).pdf, lo, hi, epsabs=1e-14)
        assert value == pytest.approx(quad, abs=1e-12)
    window = stats.norm(centre, sigma).cdf(first + size - 0.5) - stats.norm(centre, sigma).cdf(first - 0.5)
    assert frac.sum() == pytest.approx(window, abs=1e-12)


def test_rendered_star_is_the_product_of_pixel_integrals_not_point_samples():
    sigma, x, y, flux = 0.6, 20.3, 30.45, 1000.0
    image = render_image_e(SHAPE, [[x, y]], [flux], sigma)
    col = stats.norm(x, sigma)
    row = stats.norm(y, sigma)
    for j, i in [(30, 20), (31, 20), (30, 21), (29, 19), (32, 22)]:
        expected = flux * (col.cdf(i + 0.5) - col.cdf(i - 0.5)) * (row.cdf(j + 0.5) - row.cdf(j - 0.5))
        assert image[j, i] == pytest.approx(expected, rel=1e-10)
    # a point-sampled Gaussian would put 1/(2 pi s^2) = 0.442 of the flux in the peak pixel
    assert image[30, 20] / flux < 0.442 * 0.8


# ---------------------------------------------------------------- flux and position

def test_flux_is_conserved_and_the_centroid_is_the_true_position():
    rng = np.random.default_rng(3)
    xy = np.column_stack([12 + 10 * np.arange(6) + rng.uniform(0, 1, 6),   # well separated
                          rng.uniform(12, SHAPE[0] - 12, 6)])
    signal = rng.uniform(1e3, 1e5, 6)
    image = render_image_e(SHAPE, xy, signal, 1.1, background_e_per_px=7.5)
    assert image.sum() == pytest.approx(signal.sum() + 7.5 * image.size, rel=1e-9)
    for (x, y), s in zip(xy, signal):
        one = render_image_e(SHAPE, [[x, y]], [s], 1.1)
        total, cx, cy, vx, vy = moments(one)
        assert total == pytest.approx(s, rel=1e-9)
        assert (cx, cy) == (pytest.approx(x, abs=1e-7), pytest.approx(y, abs=1e-7))
        # variance of the pixel-integrated Gaussian: sigma^2 + 1/12 (uniform pixel)
        assert vx == pytest.approx(1.1 ** 2 + 1 / 12, rel=1e-6)


def test_flux_falling_off_the_edge_is_lost_by_the_normal_cdf():
    sigma, x, y = 1.3, 0.7, 40.2
    image = render_image_e(SHAPE, [[x, y]], [1e4], sigma)
    inside_x = stats.norm(x, sigma).cdf(SHAPE[1] - 0.5) - stats.norm(x, sigma).cdf(-0.5)
    assert image.sum() == pytest.approx(1e4 * inside_x, rel=1e-8)


def test_star_completely_off_the_image_renders_nothing():
    image = render_image_e(SHAPE, [[-30.0, 10.0], [10.0, 500.0]], [1e5, 1e5], 1.0)
    assert not image.any()


# ---------------------------------------------------------------- smear

@pytest.mark.parametrize("smear", [(6.0, 0.0), (3.0, -4.0), (0.4, 0.3)])
def test_smear_puts_the_centroid_at_the_path_midpoint_and_spreads_it_along_the_path(smear):
    # sigma 1 px: the moments of the pixel-binned Gaussian differ from the continuous ones
    # by aliasing terms ~ exp(-2 pi^2 sigma^2) (Sheppard), 3e-9 here
    sigma, x, y = 1.0, 40.3, 31.7
    image = render_image_e(SHAPE, [[x, y]], [1e4], sigma, smear_px=smear)
    total, cx, cy, vx, vy = moments(image)
    assert total == pytest.approx(1e4, rel=1e-9)
    assert cx == pytest.approx(x, abs=1e-6) and cy == pytest.approx(y, abs=1e-6)
    # a uniform motion over L adds L^2/12 of variance along it (sampled every 0.25 sigma:
    # the sampled variance is L^2/12 (1 - 1/n^2) with n points)
    n = max(1, math.ceil(math.hypot(*smear) / (0.25 * sigma)))
    for v, d in ((vx, smear[0]), (vy, smear[1])):
        assert v == pytest.approx(sigma ** 2 + 1 / 12 + d ** 2 / 12 * (1 - 1 / n ** 2), rel=1e-6)


def test_long_smears_are_rendered_in_chunks_exactly_like_point_by_point():
    # 100 px at sigma 1: 400 path points, two chunks; reference: one window per point
    sigma, xy, smear, flux = 1.0, np.array([[40.3, 31.7], [20.0, 50.2]]), np.array([[100.0, -12.0], [0.0, 3.1]]), \
        np.array([2e4, 5e3])
    shape = (80, 140)
    image = render_image_e(shape, xy, flux, sigma, smear_px=smear)
    reference = np.zeros(shape)
    for (x, y), (dx, dy), f in zip(xy, smear, flux):
        n = max(1, math.ceil(math.hypot(dx, dy) / (0.25 * sigma)))
        for k in range(n):
            t = (k + 0.5) / n - 0.5
            cx, cy = x + t * dx, y + t * dy
            fx = pixel_fractions(np.array([cx]), np.array([0]), shape[1], sigma)[0]
            fy = pixel_fractions(np.array([cy]), np.array([0]), shape[0], sigma)[0]
            reference += f / n * np.outer(fy, fx)
    inside = reference > 1e-6 * reference.max()          # the renderer cuts each point's PSF at 5 sigma
    np.testing.assert_allclose(image[inside], reference[inside], rtol=1e-9, atol=1e-9 * flux.max())
    assert abs(image.sum() - reference.sum()) < 1e-5 * flux.sum()


# ---------------------------------------------------------------- the noisy frame

def test_frame_is_12_bit_and_bright_stars_clip_at_the_adc_top():
    cam = small_camera()
    rng = np.random.default_rng(0)
    frame = render_frame(cam, [[30.0, 30.0], [90.0, 60.0]], [1e8, 5e3], rng)
    assert frame.dtype == np.uint16 and frame.shape == (96, 128)
    assert frame.max() == 4095 == cam.adc_max_adu
    assert frame[30, 30] == 4095
    assert 0 < frame[60, 90] < 4095


def test_full_well_saturates_below_the_adc_top():
    cam = small_camera(full_well_e=20000.0)             # 20000 / 25 + 100 = 900 ADU
    frame = render_frame(cam, [[30.0, 30.0]], [1e8], np.random.default_rng(1), hot_pixel_fraction=0.0)
    peak = frame[28:33, 28:33]
    assert np.all(np.abs(peak.astype(int) - 900) <= 4)   # full well + read noise (20 e = 0.8 ADU)


def test_adc_clips_at_zero_without_wrapping():
    cam = small_camera(bias_adu=0.0, read_noise_e=200.0, dark_e_per_s=0.0, sky_e_per_px_per_s=0.0)
    frame = render_frame(cam, np.zeros((0, 2)), [], np.random.default_rng(2), hot_pixel_fraction=0.0)
    assert frame.min() == 0 and frame.max() < 100      # no 65535 from negative values
    # adu = rint(R / gain) clipped at 0: P(0) = P(R < gain / 2) = Phi(12.5 / 200); 4.5 standard errors
    assert np.mean(frame == 0) == pytest.approx(stats.norm.cdf(0.5 * 25.0 / 200.0), abs=0.02)


def test_background_noise_has_the_poisson_read_and_adc_moments():
    cam = small_camera(width_px=512, height_px=512, x0_px=255.5, y0_px=255.5, gain_e_per_adu=2.0,
                       sky_e_per_px_per_s=2000.0, read_noise_e=5.0)
    frame = render_frame(cam, np.zeros((0, 2)), [], np.random.default_rng(7), hot_pixel_fraction=0.0)
    bg_e = (cam.sky_e_per_px_per_s + cam.dark_e_per_s) * cam.exposure_s
    mean_expected = cam.bias_adu + bg_e / cam.gain_e_per_adu
    var_expected = (bg_e + cam.read_noise_e ** 2) / cam.gain_e_per_adu ** 2 + 1 / 12
    values = frame.astype(float)
    assert values.mean() == pytest.approx(mean_expected, abs=0.02)
    assert values.var() == pytest.approx(var_expected, rel=0.02)


def _histogram_test(values, probabilities, first):
    """Chi-square p-value of integer ``values`` against ``probabilities`` of ``first, first + 1, ...``.

    Cells with fewer than 5 expected counts are pooled into the two tails.
    """
    n = values.size
    counts = np.bincount(values - first, minlength=len(probabilities))[:len(probabilities)]
    assert counts.sum() == n, "values outside the tabulated range"
    expected = n * probabilities
    big = np.flatnonzero(expected >= 5.0)
    lo, hi = big[0], big[-1]
    obs = np.concatenate([[counts[:lo + 1].sum()], counts[lo + 1:hi], [counts[hi:].sum()]])
    exp = np.concatenate([[expected[:lo + 1].sum()], expected[lo + 1:hi], [expected[hi:].sum()]])
    return stats.chisquare(obs, exp * obs.sum() / exp.sum()).pvalue


def test_background_counts_are_poisson_chi_square():
    # no read noise, gain 1, no bias: the ADU of an empty pixel is its photo-electron count
    cam = camera_preset("A1").replace(read_noise_e=0.0, gain_e_per_adu=1.0, bias_adu=0.0)
    frame = render_frame(cam, np.zeros((0, 2)), [], np.random.default_rng(11), hot_pixel_fraction=0.0)
    lam = (cam.sky_e_per_px_per_s + cam.dark_e_per_s) * cam.exposure_s           # 24.7 e
    values = frame.astype(np.int64).ravel()
    k = np.arange(0, 200)
    assert _histogram_test(values, stats.poisson.pmf(k, lam), 0) > 1e-3
    # mean and variance within 4 standard errors of Poisson's (1M pixels)
    n = values.size
    assert abs(values.mean() - lam) < 4.0 * math.sqrt(lam / n)
    assert abs(values.var() - lam) < 4.0 * lam * math.sqrt(2.0 / n)
    # KS on the counts spread uniformly over [k, k + 1): CDF = P(X < k) + (x - k) P(X = k)
    jittered = values[:50000] + np.random.default_rng(1).uniform(size=50000)
    continuous_cdf = lambda x: stats.poisson.cdf(np.floor(x) - 1, lam) + (x - np.floor(x)) * stats.poisson.pmf(np.floor(x), lam)
    assert stats.kstest(jittered, continuous_cdf).pvalue > 1e-3


def _adu_distribution(cam, first, last):
    """Exact ADU probabilities of an empty pixel: Poisson shot noise, Gaussian read noise, ADC rounding."""
    lam = (cam.sky_e_per_px_per_s + cam.dark_e_per_s) * cam.exposure_s
    e = np.arange(0, int(lam + 20 * math.sqrt(lam) + 50))
    p_e = stats.poisson.pmf(e, lam)
    adu = np.arange(first, last + 1)
    upper = stats.norm.cdf((cam.gain_e_per_adu * (adu[:, None] + 0.5 - cam.bias_adu) - e[None, :]) / cam.read_noise_e)
    lower = stats.norm.cdf((cam.gain_e_per_adu * (adu[:, None] - 0.5 - cam.bias_adu) - e[None, :]) / cam.read_noise_e)
    return (upper - lower) @ p_e


def test_background_adu_follow_poisson_plus_read_noise_chi_square():
    cam = camera_preset("A1")                           # 24.7 e of sky and dark, 20 e read noise, 25 e/ADU
    frame = render_frame(cam, np.zeros((0, 2)), [], np.random.default_rng(12), hot_pixel_fraction=0.0)
    values = frame.astype(np.int64).ravel()
    probabilities = _adu_distribution(cam, 90, 115)
    assert probabilities.sum() == pytest.approx(1.0, abs=1e-12)
    assert _histogram_test(values, probabilities, 90) > 1e-3
    lam = (cam.sky_e_per_px_per_s + cam.dark_e_per_s) * cam.exposure_s
    var = (lam + cam.read_noise_e ** 2) / cam.gain_e_per_adu ** 2 + 1 / 12
    n = values.size
    assert abs(values.mean() - (cam.bias_adu + lam / cam.gain_e_per_adu)) < 4.0 * math.sqrt(var / n)
    assert abs(values.var() / var - 1.0) < 4.0 * math.sqrt(2.0 / n) + 0.003      # + ADC-rounding approximation
    # and against numpy's own samplers drawing the same chain pixel by pixel (two-sample chi-square)
    rng = np.random.default_rng(13)
    brute = np.rint((rng.poisson(lam, n) + cam.read_noise_e * rng.standard_normal(n)) / cam.gain_e_per_adu
                    + cam.bias_adu).astype(np.int64)
    table = np.stack([np.bincount(v - 90, minlength=26)[:26] for v in (values, brute)])
    table = table[:, table.min(axis=0) >= 5]
    assert stats.chi2_contingency(table).pvalue > 1e-3


def test_a_background_too_bright_for_the_table_goes_through_the_chain_pixel_by_pixel():
    # 1e6 e of sky: the exact ADU table would hold ~1e8 terms, so every pixel takes the chain
    from shipstar.simulate._render import _background_table

    cam = small_camera(width_px=256, height_px=256, x0_px=127.5, y0_px=127.5, sky_e_per_px_per_s=1.25e7,
                       dark_e_per_s=0.0, full_well_e=1e8, gain_e_per_adu=25.0, adc_bits=16)
    assert _background_table(1e6, cam.read_noise_e, cam.gain_e_per_adu, cam.bias_adu, cam.full_well_e, 65535) is None
    frame = render_frame(cam, [[100.0, 100.0]], [1e6], np.random.default_rng(15), hot_pixel_fraction=0.0)
    lam = cam.sky_e_per_px_per_s * cam.exposure_s
    values = np.delete(frame.ravel(), np.arange(90, 111)[:, None] * 256 + np.arange(90, 111)).astype(float)
    var = (lam + cam.read_noise_e ** 2) / cam.gain_e_per_adu ** 2 + 1 / 12
    assert abs(values.mean() - (cam.bias_adu + lam / cam.gain_e_per_adu)) < 4.0 * math.sqrt(var / values.size)
    assert abs(values.var() / var - 1.0) < 4.0 * math.sqrt(2.0 / values.size)
    assert frame[100, 100] > cam.bias_adu + lam / cam.gain_e_per_adu + 100      # the star is there


def test_star_pixels_have_poisson_plus_read_noise_statistics():
    # one star, many frames: every pixel's mean and variance against the expected electrons
    cam = small_camera(width_px=32, height_px=32, x0_px=15.5, y0_px=15.5, gain_e_per_adu=1.0, read_noise_e=3.0,
                       bias_adu=100.0, psf_sigma_px=1.2)
    xy, signal = [[15.3, 16.2]], [4000.0]
    rng = np.random.default_rng(14)
    frames = np.stack([render_frame(cam, xy, signal, rng, hot_pixel_fraction=0.0) for _ in range(600)]).astype(float)
    bg = (cam.sky_e_per_px_per_s + cam.dark_e_per_s) * cam.exposure_s
    mean_e = render_image_e((32, 32), xy, signal, cam.psf_sigma_px, bg)
    var = mean_e + cam.read_noise_e ** 2 + 1 / 12
    z_mean = (frames.mean(axis=0) - cam.bias_adu - mean_e) / np.sqrt(var / len(frames))
    z_var = (frames.var(axis=0, ddof=1) / var - 1.0) / math.sqrt(2.0 / (len(frames) - 1))
    assert np.abs(z_mean).max() < 4.5 and abs(z_mean.mean()) < 4.0 / 32
    assert np.abs(z_var).max() < 5.0 and abs(z_var.mean()) < 5.0 / 32


def test_the_same_seed_gives_the_same_frame():
    cam = small_camera()
    xy, sig = [[20.5, 30.25], [70.0, 50.0]], [2e4, 3e3]
    a = render_frame(cam, xy, sig, np.random.default_rng(42))
    b = render_frame(cam, xy, sig, np.random.default_rng(42))
    c = render_frame(cam, xy, sig, np.random.default_rng(43))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_hot_pixels_are_a_fixed_pattern_of_the_sensor():
    cam = small_camera(width_px=256, height_px=256, x0_px=127.5, y0_px=127.5)
    empty = np.zeros((0, 2))
    # 1e9 e/s: every hot pixel fills its well, so the pattern is exact
    frames = [render_frame(cam, empty, [], np.random.default_rng(s), hot_pixel_fraction=1e-3,
                           hot_pixel_e_per_s=1e9, hot_pixel_seed=9) for s in (1, 2)]
    other = render_frame(cam, empty, [], np.random.default_rng(1), hot_pixel_fraction=1e-3,
                         hot_pixel_e_per_s=1e9, hot_pixel_seed=10)
    hot = [set(np.flatnonzero(f > cam.bias_adu + 50)) for f in (*frames, other)]
    assert hot[0] == hot[1]
    assert len(hot[0]) == round(1e-3 * 256 * 256)
    assert hot[0] != hot[2]


def test_signal_comes_out_as_expected_in_adu():
    cam = small_camera(read_noise_e=0.0, dark_e_per_s=0.0, sky_e_per_px_per_s=0.0, bias_adu=0.0)
    frame = render_frame(cam, [[60.0, 40.0]], [50000.0], np.random.default_rng(5), hot_pixel_fraction=0.0)
    assert frame.sum() * cam.gain_e_per_adu == pytest.approx(50000.0, rel=0.02)


# ---------------------------------------------------------------- false objects

def test_planet_trail_and_cosmic_rays():
    cam = small_camera(width_px=256, height_px=256, x0_px=127.5, y0_px=127.5)
    fo = FalseObjects(planet_xy_px=[[200.0, 50.0]], planet_signal_e=[1e9],
                      trail_xy_px=[[[20.0, 200.0], [120.0, 150.0]]], trail_signal_e=[2e6],
                      cosmic_ray_count=20, cosmic_ray_e=20000.0)
    quiet = dict(read_noise_e=0.0, dark_e_per_s=0.0, sky_e_per_px_per_s=0.0, bias_adu=0.0)
    frame = render_frame(cam.replace(**quiet), np.zeros((0, 2)), [], np.random.default_rng(3),
                         hot_pixel_fraction=0.0, false_objects=fo)
    assert frame[50, 200] == 4000                        # the planet saturates: full well / gain
    # the trail: light along the segment y = 200 - (x - 20) / 2, none far from it
    for x in (30, 70, 110):
        y = 200 - (x - 20) / 2
        assert frame[int(round(y)), x] > 20
        assert frame[int(round(y)) + 8, x] == 0 or frame[int(round(y)) + 8, x] > 500   # (a cosmic ray)
    trail_only = render_frame(cam.replace(**quiet), np.zeros((0, 2)), [], np.random.default_rng(3),
                              hot_pixel_fraction=0.0,
                              false_objects=FalseObjects(trail_xy_px=fo.trail_xy_px, trail_signal_e=[2e6]))
    assert trail_only.sum() * cam.gain_e_per_adu == pytest.approx(2e6, rel=0.01)
    # cosmic rays: isolated spikes of 1-3 pixels, not spread by the PSF
    rays = render_frame(cam.replace(**quiet), np.zeros((0, 2)), [], np.random.default_rng(4),
                        hot_pixel_fraction=0.0, false_objects=FalseObjects(cosmic_ray_count=20, cosmic_ray_e=20000.0))
    lit = np.count_nonzero(rays)
    assert 20 <= lit <= 60
    assert rays.sum() * cam.gain_e_per_adu == pytest.approx(20 * 20000.0 * math.exp(0.125), rel=0.5)


def test_star_signal_follows_the_camera_photon_budget():
    cam = camera_preset("A1")
    sig = star_signal_e(cam, [1.0, 6.0])
    assert sig[0] / sig[1] == pytest.approx(100.0, rel=1e-12)        # 5 mag = x100
    assert sig[1] == pytest.approx(float(cam.star_e_per_s(6.0)) * cam.exposure_s, rel=1e-12)


# ---------------------------------------------------------------- bad input

@pytest.mark.parametrize("kwargs, match", [
    (dict(xy_px=[[1.0, 2.0, 3.0]]), "shape"),
    (dict(xy_px=[[np.nan, 2.0]]), "non-finite"),
    (dict(signal_e=[-1.0]), ">= 0"),
    (dict(signal_e=[1.0, 2.0]), "shape"),
    (dict(psf_sigma_px=0.0), "psf_sigma_px"),
    (dict(shape_hw=(0, 10)), "out of range"),
    (dict(background_e_per_px=-1.0), "background"),
    (dict(smear_px=[1.0, 2.0, 3.0]), "smear_px"),
])
def test_render_image_rejects_bad_input(kwargs, match):
    args = dict(shape_hw=SHAPE, xy_px=[[10.0, 10.0]], signal_e=[100.0], psf_sigma_px=1.0)
    args.update(kwargs)
    with pytest.raises(ShipstarError, match=match):
        render_image_e(**args)


def test_render_frame_rejects_bad_input():
    cam = small_camera()
    with pytest.raises(ShipstarError, match="Generator"):
        render_frame(cam, [[1.0, 1.0]], [1.0], 42)
    with pytest.raises(ShipstarError, match="hot_pixel_fraction"):
        render_frame(cam, [[1.0, 1.0]], [1.0], np.random.default_rng(0), hot_pixel_fraction=0.5)
    with pytest.raises(ShipstarError, match="FalseObjects"):
        render_frame(cam, [[1.0, 1.0]], [1.0], np.random.default_rng(0), false_objects={"planets": 1})
    with pytest.raises(ShipstarError, match="camera has no field"):
        render_frame(object(), [[1.0, 1.0]], [1.0], np.random.default_rng(0))
    with pytest.raises(ShipstarError, match="trail_xy_px"):
        FalseObjects(trail_xy_px=[[1.0, 2.0]], trail_signal_e=[1.0])
    with pytest.raises(ShipstarError, match="cosmic_ray_count"):
        FalseObjects(cosmic_ray_count=-1)
    with pytest.raises(ShipstarError, match="magnitudes"):
        star_signal_e(cam, [np.nan])
