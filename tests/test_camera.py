"""Camera model: pinhole geometry against analytic cases, Weng distortion against the seed's
own formula, round trips (hypothesis), the photon budget, presets and camera files."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shipstar.camera import (
    PRESETS, Camera, Distortion, camera_preset, load_camera, save_camera, sky_e_per_px_per_s,
)
from shipstar.errors import ShipstarError
from shipstar.units import DEG2RAD, RAD2ASEC, RAD2DEG

# seed 002 Tab. 1, "improved sine" column
SEED002_G = dict(g1=1.84e-5, g2=-1.36e-5, g3=2.30e-4, g4=-1.29e-4,
                 kappa1=1.14e-5, kappa2=1.72e-8, kappa3=-1.78e-11)


def seed002_eq7(u, v, g1, g2, g3, g4, kappa1, kappa2, kappa3):
    """Seed 002 eq. 7 exactly as printed (u = x - x0, v = y - y0, here in mm)."""
    r2 = u * u + v * v
    rad = kappa1 * r2 + kappa2 * r2 ** 2 + kappa3 * r2 ** 3
    dx = (g1 + g3) * u * u + g4 * u * v + g1 * v * v + u * rad
    dy = g2 * u * u + g3 * u * v + (g2 + g4) * v * v + v * rad
    return dx, dy


def weng1992(u, v, k1, k2, k3, p1, p2, s1, s2):
    """Weng, Cohen & Herniou (1992) radial + decentring + thin-prism distortion."""
    r2 = u * u + v * v
    rad = k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    du = u * rad + p1 * (3 * u * u + v * v) + 2 * p2 * u * v + s1 * r2
    dv = v * rad + 2 * p1 * u * v + p2 * (u * u + 3 * v * v) + s2 * r2
    return du, dv


def pixel_grid(cam, n=41):
    xs = np.linspace(-0.5, cam.width_px - 0.5, n)
    ys = np.linspace(-0.5, cam.height_px - 0.5, n)
    return np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)


def angle_rad(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def random_distortion(cam, amplitudes_px):
    """Distortion whose 7 terms each reach ``amplitudes_px`` pixels at the image corner."""
    r_mm = math.hypot(cam.width_px, cam.height_px) / 2 * cam.pixel_mm
    a = [x * cam.pixel_mm for x in amplitudes_px]
    return Distortion(k1_per_mm2=a[0] / r_mm ** 3, k2_per_mm4=a[1] / r_mm ** 5, k3_per_mm6=a[2] / r_mm ** 7,
                      p1_per_mm=a[3] / r_mm ** 2, p2_per_mm=a[4] / r_mm ** 2,
                      s1_per_mm=a[5] / r_mm ** 2, s2_per_mm=a[6] / r_mm ** 2)


@pytest.fixture(scope="module")
def a1():
    return camera_preset("A1")


@pytest.fixture(scope="module")
def s002():
    return camera_preset("seed002")


# ----------------------------------------------------------------------------- analytic
class TestPinhole:
    @pytest.mark.parametrize("name", PRESETS)
    def test_boresight_lands_on_principal_point(self, name):
        cam = camera_preset(name)
        xy = cam.project(np.array([[1.0, 0.0, 0.0], [7.0, 0.0, 0.0]]))
        np.testing.assert_allclose(xy, [[cam.x0_px, cam.y0_px]] * 2, atol=1e-12)
        np.testing.assert_allclose(cam.unproject([[cam.x0_px, cam.y0_px]]), [[1.0, 0.0, 0.0]], atol=1e-15)

    @pytest.mark.parametrize("a_deg", [0.1, 1.0, 3.0, 4.3, -2.5])
    def test_angle_along_plus_z_lands_at_f_tan(self, a1, a_deg):
        a = a_deg * DEG2RAD
        xy = a1.project([[math.cos(a), 0.0, math.sin(a)]])[0]
        assert xy[0] == pytest.approx(a1.x0_px + a1.f_mm * math.tan(a) / a1.pixel_mm, abs=1e-9)
        assert xy[1] == pytest.approx(a1.y0_px, abs=1e-12)
        # and along +Y: image up is decreasing y
        xy = a1.project([[math.cos(a), math.sin(a), 0.0]])[0]
        assert xy[1] == pytest.approx(a1.y0_px - a1.f_mm * math.tan(a) / a1.pixel_mm, abs=1e-9)
        assert xy[0] == pytest.approx(a1.x0_px, abs=1e-12)

    def test_image_up_is_decreasing_y_and_right_is_increasing_x(self, a1, s002):
        for cam in (a1, s002):
            up, right = cam.project([[1.0, 0.01, 0.0], [1.0, 0.0, 0.01]])
            assert up[1] < cam.y0_px - 10 and abs(up[0] - cam.x0_px) < 1.0
            assert right[0] > cam.x0_px + 10 and abs(right[1] - cam.y0_px) < 1.0

    def test_unproject_matches_seed000_eq4(self, a1):
        # seed 000 eq. 4: W = [f, -(y - y0) D, (z - z0) D] / norm, z = column = our x
        xy = pixel_grid(a1, 9)
        W = np.stack([np.full(len(xy), a1.f_mm), -(xy[:, 1] - a1.y0_px) * a1.pixel_mm,
                      (xy[:, 0] - a1.x0_px) * a1.pixel_mm], -1)
        W /= np.linalg.norm(W, axis=1, keepdims=True)
        np.testing.assert_allclose(a1.unproject(xy), W, atol=1e-15)

    def test_behind_and_nonfinite_rows_are_nan(self, a1):
        v = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.1, 0.1], [np.nan, 0, 0], [1.0, 0.01, 0.0]])
        xy = a1.project(v)
        assert np.isfinite(xy[[0, 4]]).all() and np.isnan(xy[[1, 2, 3]]).all()
        uv = a1.unproject([[1.0, 2.0], [np.nan, 3.0], [np.inf, 0.0]])
        assert np.isfinite(uv[0]).all() and np.isnan(uv[1:]).all()

    def test_shapes(self, a1, s002):
        for cam in (a1, s002):
            assert cam.project([1.0, 0.0, 0.0]).shape == (2,)
            assert cam.project(np.zeros((0, 3))).shape == (0, 2)
            assert cam.unproject(np.zeros((0, 2))).shape == (0, 3)
            assert cam.unproject(np.full((2, 5, 2), 100.0)).shape == (2, 5, 3)
            assert cam.in_image(np.zeros((4, 2))).shape == (4,)

    @pytest.mark.parametrize("bad", [np.zeros((3, 2)), np.zeros(4), 1.0, [["a", "b", "c"]]])
    def test_bad_vector_shape_is_an_error(self, a1, bad):
        with pytest.raises(ShipstarError):
            a1.project(bad)

    def test_bad_pixel_shape_is_an_error(self, a1):
        with pytest.raises(ShipstarError, match=r"\(N, 2\)"):
            a1.unproject(np.zeros((3, 3)))

    def test_in_image_edges(self, a1):
        xy = np.array([[-0.5, 0.0], [-0.5001, 0.0], [1023.499, 1023.499], [1023.5, 5.0],
                       [5.0, 1023.5], [np.nan, 5.0]])
        assert a1.in_image(xy).tolist() == [True, False, True, False, False, False]
        assert a1.in_image([[2.0, 2.0], [3.0, 3.0]], margin_px=3.0).tolist() == [False, True]

    def test_pixel_scale(self, a1):
        assert a1.pixel_scale_arcsec == pytest.approx(0.014 / 94.938 * RAD2ASEC, rel=1e-14)
        assert a1.pixel_scale_arcsec == pytest.approx(30.4168, abs=1e-4)


class TestFieldOfView:
    def test_A1_is_8_64_deg_not_8(self, a1):
        # 1024 x 14 um at f = 94.938 mm: edge to edge through the principal point
        left = math.atan((a1.x0_px + 0.5) * a1.pixel_mm / a1.f_mm)
        right = math.atan((1023.5 - a1.x0_px) * a1.pixel_mm / a1.f_mm)
        assert a1.fov_deg == pytest.approx((left + right) * RAD2DEG, abs=1e-10)
        assert a1.fov_deg == pytest.approx(8.6355, abs=1e-4)      # seed 000 Tab. 1 says 8 x 8 deg
        top = math.atan((a1.y0_px + 0.5) * a1.pixel_mm / a1.f_mm)
        bottom = math.atan((1023.5 - a1.y0_px) * a1.pixel_mm / a1.f_mm)
        assert a1.fov_height_deg == pytest.approx((top + bottom) * RAD2DEG, abs=1e-10)

    def test_diagonal(self, a1):
        c = a1.unproject([[-0.5, -0.5], [1023.5, 1023.5], [1023.5, -0.5], [-0.5, 1023.5]])
        expected = max(angle_rad(c[0], c[1]), angle_rad(c[2], c[3])) * RAD2DEG
        assert a1.diagonal_fov_deg == pytest.approx(expected, abs=1e-12)
        assert 12.1 < a1.diagonal_fov_deg < 12.3

    def test_seed004_is_exactly_12_deg(self):
        cam = camera_preset("seed004")
        assert cam.fov_deg == pytest.approx(12.0, abs=1e-9)
        assert cam.fov_height_deg == pytest.approx(12.0, abs=1e-9)
        assert cam.f_mm / cam.pixel_mm == pytest.approx(2435.7, abs=0.05)     # seed 004: ~2435.7 px

    def test_distortion_enters_the_fov(self, s002):
        pinhole = s002.replace(distortion=Distortion())
        assert abs(s002.fov_deg - pinhole.fov_deg) * 3600 > 1.0        # a few px at the edges
        assert abs(s002.fov_deg - pinhole.fov_deg) < 0.01


# ----------------------------------------------------------------------------- distortion
class TestDistortionModel:
    def test_seed002_eq7_is_reproduced(self):
        d = Distortion.from_seed002(*SEED002_G.values())
        rng = np.random.default_rng(2)
        u, v = rng.uniform(-8, 8, (2, 500))
        dx, dy = seed002_eq7(u, v, **SEED002_G)
        du, dv = d.offsets_mm(u, v)
        np.testing.assert_allclose(du, dx, rtol=1e-12, atol=1e-18)
        np.testing.assert_allclose(dv, dy, rtol=1e-12, atol=1e-18)

    def test_classic_weng_form(self):
        coeffs = dict(k1=3e-5, k2=-2e-7, k3=4e-10, p1=1e-4, p2=-7e-5, s1=5e-5, s2=-3e-5)
        d = Distortion(*coeffs.values())
        rng = np.random.default_rng(3)
        u, v = rng.uniform(-10, 10, (2, 500))
        np.testing.assert_allclose(d.offsets_mm(u, v), weng1992(u, v, **coeffs), rtol=1e-12, atol=1e-18)

    def test_seed002_g_mapping_round_trip(self, s002):
        g = s002.distortion.seed002_g_per_mm
        np.testing.assert_allclose(g, [SEED002_G[k] for k in ("g1", "g2", "g3", "g4")], rtol=1e-12)
        assert (s002.distortion.k1_per_mm2, s002.distortion.k2_per_mm4, s002.distortion.k3_per_mm6) == \
            (SEED002_G["kappa1"], SEED002_G["kappa2"], SEED002_G["kappa3"])

    def test_jacobian_matches_finite_differences(self, s002):
        d = s002.distortion
        rng = np.random.default_rng(4)
        u, v = rng.uniform(-8, 8, (2, 50))
        h = 1e-5
        J = d.jacobian(u, v)
        obs = lambda a, b: np.stack([a + d.offsets_mm(a, b)[0], b + d.offsets_mm(a, b)[1]], -1)  # noqa: E731
        np.testing.assert_allclose(J[..., 0], (obs(u + h, v) - obs(u - h, v)) / (2 * h), atol=1e-9)
        np.testing.assert_allclose(J[..., 1], (obs(u, v + h) - obs(u, v - h)) / (2 * h), atol=1e-9)

    def test_direction_is_ideal_to_observed(self, s002):
        # a star whose ideal image is at ideal offset (u, v) is observed at (u, v) + d(u, v)
        pinhole = s002.replace(distortion=Distortion())
        v_sensor = pinhole.unproject([[2400.0, 100.0]])
        ideal_mm = (np.array([2400.0, 100.0]) - [s002.x0_px, s002.y0_px]) * s002.pixel_mm
        du, dv = seed002_eq7(*ideal_mm, **SEED002_G)
        expected = np.array([2400.0, 100.0]) + np.array([du, dv]) / s002.pixel_mm
        np.testing.assert_allclose(s002.project(v_sensor)[0], expected, atol=1e-9)

    def test_newton_converges_below_1e_6_px_over_the_sensor(self, s002):
        xy = pixel_grid(s002, 101)
        back = s002.project(s002.unproject(xy))
        assert np.abs(back - xy).max() < 1e-8
        strong = s002.replace(distortion=Distortion(**{k: 10 * v for k, v in s002.distortion.as_dict().items()}))
        back = strong.project(strong.unproject(xy))
        assert np.abs(back - xy).max() < 1e-8

    def test_seed002_inverse_convention_differs_only_at_second_order(self, s002):
        """Seed 002 eq. 6 removes d evaluated at the *observed* point (ideal = obs - d(obs));
        shipstar inverts ideal -> observed exactly.  The two differ by ~ J d, second order."""
        xy = pixel_grid(s002, 81)
        obs_mm = (xy - [s002.x0_px, s002.y0_px]) * s002.pixel_mm

        def gap_px(scale):
            g = {k: scale * v for k, v in SEED002_G.items()}
            d = Distortion.from_seed002(*g.values())
            dx, dy = seed002_eq7(obs_mm[:, 0], obs_mm[:, 1], **g)
            seed_ideal = obs_mm - np.stack([dx, dy], -1)
            return np.abs(d.undistort_mm(obs_mm) - seed_ideal).max() / s002.pixel_mm

        gap = gap_px(1.0)
        assert 0.005 < gap < 0.05          # measured 0.023 px (0.13 arcsec) for Tab. 1's lens
        assert gap_px(0.1) == pytest.approx(gap * 0.01, rel=0.05)

    def test_non_invertible_distortion_is_rejected(self, a1):
        with pytest.raises(ShipstarError, match="not invertible"):
            a1.replace(distortion=Distortion(k1_per_mm2=-5e-3))

    def test_far_outside_is_nan_not_a_warning(self, s002):
        out = s002.unproject([[1e9, 1e9], [1e5, -3e5], [1200.0, 900.0]])
        assert np.isnan(out[0]).all()
        assert np.isfinite(out[2]).all()
        assert np.isnan(out[1]).all() or abs(np.linalg.norm(out[1]) - 1) < 1e-12
        ideal = s002.distortion.undistort_mm([[1e7, 1e7], [np.nan, 0.0], [1.0, 2.0]])
        assert np.isnan(ideal[:2]).all() and np.isfinite(ideal[2]).all()

    def test_distortion_fields_validate(self):
        with pytest.raises(ShipstarError, match="k1_per_mm2"):
            Distortion(k1_per_mm2=float("nan"))
        with pytest.raises(ShipstarError, match="p1_per_mm"):
            Distortion(p1_per_mm="0.1")
        assert Distortion().is_zero and not Distortion(s2_per_mm=1e-9).is_zero

    def test_is_zero_is_made_once_and_follows_every_field(self):
        import dataclasses
        import pickle

        assert Distortion(k1_per_mm2=-0.0).is_zero
        for f in dataclasses.fields(Distortion):
            d = Distortion(**{f.name: 1e-12})
            assert not d.is_zero, f.name
            assert dataclasses.replace(d, **{f.name: 0.0}).is_zero
            assert pickle.loads(pickle.dumps(d)) == d and not pickle.loads(pickle.dumps(d)).is_zero
        # the cached flag is not a field: equality and repr are the coefficients'
        assert Distortion() == Distortion(p1_per_mm=0.0) and "_is_zero" not in repr(Distortion())
        assert Distortion().as_dict() == {f.name: 0.0 for f in dataclasses.fields(Distortion)}


# ----------------------------------------------------------------------------- round trips
amp_px = st.floats(-5.0, 5.0, allow_nan=False)


@st.composite
def sensor_pixels(draw, cam):
    n = draw(st.integers(1, 20))
    x = draw(st.lists(st.floats(-0.5, cam.width_px - 0.5), min_size=n, max_size=n))
    y = draw(st.lists(st.floats(-0.5, cam.height_px - 0.5), min_size=n, max_size=n))
    return np.stack([x, y], -1)


@st.composite
def field_vectors(draw, cam):
    """Directions whose pinhole image lies on the detector (tangent-plane sampling)."""
    n = draw(st.integers(1, 20))
    x = np.array(draw(st.lists(st.floats(-0.5, cam.width_px - 0.5), min_size=n, max_size=n)))
    y = np.array(draw(st.lists(st.floats(-0.5, cam.height_px - 0.5), min_size=n, max_size=n)))
    scale = draw(st.floats(0.01, 100.0))
    v = np.stack([np.full(n, cam.f_mm), -(y - cam.y0_px) * cam.pixel_mm, (x - cam.x0_px) * cam.pixel_mm], -1)
    return v * scale


def _check_pixel_round_trip(cam, xy):
    v = cam.unproject(xy)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-14)
    assert np.abs(cam.project(v) - xy).max() < 1e-4


def _check_vector_round_trip(cam, v):
    back = cam.unproject(cam.project(v))
    err_px = angle_rad(back, v / np.linalg.norm(v, axis=1, keepdims=True)) * RAD2ASEC / cam.pixel_scale_arcsec
    assert err_px.max() < 1e-4


class TestRoundTrips:
    @pytest.mark.parametrize("name", PRESETS)
    def test_pixel_vector_pixel(self, name):
        cam = camera_preset(name)

        @settings(max_examples=60, deadline=None)
        @given(sensor_pixels(cam))
        def check(xy):
            _check_pixel_round_trip(cam, xy)

        check()

    @pytest.mark.parametrize("name", PRESETS)
    def test_vector_pixel_vector(self, name):
        cam = camera_preset(name)

        @settings(max_examples=60, deadline=None)
        @given(field_vectors(cam))
        def check(v):
            _check_vector_round_trip(cam, v)

        check()

    @settings(max_examples=80, deadline=None)
    @given(amps=st.lists(amp_px, min_size=7, max_size=7), data=st.data())
    def test_random_distortion_both_directions(self, a1, amps, data):
        cam = a1.replace(distortion=random_distortion(a1, amps))
        _check_pixel_round_trip(cam, data.draw(sensor_pixels(cam)))
        _check_vector_round_trip(cam, data.draw(field_vectors(cam)))

    def test_whole_sensor_grid_with_and_without_distortion(self, a1, s002):
        for cam in (a1, s002, s002.replace(distortion=Distortion())):
            xy = pixel_grid(cam, 64)
            _check_pixel_round_trip(cam, xy)
            _check_vector_round_trip(cam, cam.unproject(xy) * 3.0)


# ----------------------------------------------------------------------------- photometry
class TestPhotometry:
    def test_star_budget_formula(self, a1):
        expected = 4.7e10 * math.pi * 0.025 ** 2 * 0.8 * 0.4
        assert a1.star_e_per_s(0.0) == pytest.approx(expected, rel=1e-12)
        np.testing.assert_allclose(a1.star_e_per_s([1.0, 6.0]) / a1.star_e_per_s(1.0), [1.0, 0.01], rtol=1e-12)

    @pytest.mark.parametrize("name", PRESETS)
    def test_preset_sky_is_21_mag_per_arcsec2(self, name):
        cam = camera_preset(name)
        assert cam.sky_e_per_px_per_s == pytest.approx(sky_e_per_px_per_s(cam, 21.0), rel=1e-3)

    def test_sky_model(self, a1):
        # 1 mag/arcsec^2 brighter is 10**0.4 more; per pixel it is the pixel's solid angle
        assert sky_e_per_px_per_s(a1, 20.0) / sky_e_per_px_per_s(a1, 21.0) == pytest.approx(10 ** 0.4)
        assert sky_e_per_px_per_s(a1, 0.0) == pytest.approx(a1.star_e_per_s(0.0) * a1.pixel_scale_arcsec ** 2)
        with pytest.raises(ShipstarError):
            sky_e_per_px_per_s(a1, float("nan"))

    def test_A1_psf_spreads_over_3x3_to_5x5(self, a1):
        s = a1.psf_sigma_px

        def box(n):          # flux fraction of a centred Gaussian inside n x n pixels
            return math.erf(n / 2 / (s * math.sqrt(2))) ** 2

        assert box(1) < 0.35 and box(3) > 0.8 and box(5) > 0.99

    def test_A1_detection_limit_and_saturation(self, a1):
        """The photon budget puts the 5-sigma peak-pixel limit near mag 9 and saturation near
        mag 2: a navigation catalogue to ~7.5 is detected at > 10 sigma."""
        peak_frac = math.erf(0.5 / (a1.psf_sigma_px * math.sqrt(2))) ** 2
        noise_e = math.sqrt(a1.read_noise_e ** 2 + (a1.dark_e_per_s + a1.sky_e_per_px_per_s) * a1.exposure_s)
        mags = np.linspace(-2, 12, 14001)
        peak_e = a1.star_e_per_s(mags) * a1.exposure_s * peak_frac
        limit = mags[np.argmin(np.abs(peak_e - 5 * noise_e))]
        saturation = mags[np.argmin(np.abs(peak_e - a1.full_well_e))]
        assert 8.5 < limit < 10.0
        assert 1.0 < saturation < 2.5
        assert (a1.adc_max_adu - a1.bias_adu) * a1.gain_e_per_adu == pytest.approx(a1.full_well_e, rel=0.05)


# ----------------------------------------------------------------------------- presets, files
BAD_CASES = [
    # (replace line starting with key, new line, field named in the message)
    ("f_mm", "f_mm = nan", "f_mm"),
    ("f_mm", "f_mm = inf", "f_mm"),
    ("f_mm", 'f_mm = "94.9"', "f_mm"),
    ("f_mm", "f_mm = -94.9", "f_mm"),
    ("width_px", "width_px = 1024.0", "width_px"),
    ("width_px", "width_px = 0", "width_px"),
    ("qe", "qe = true", "qe"),
    ("qe", "qe = 1.5", "qe"),
    ("adc_bits", "adc_bits = 12.5", "adc_bits"),
    ("exposure_s", "exposure_s = 0.5", "exposure_s"),        # longer than the 0.1 s frame
    ("name", "name = 3", "name"),
    ("name", "name = \"A1\"\nfocal_mm = 95.0", "focal_mm"),   # unknown key (typo)
    ("[distortion]", "[distortion]\nk1_per_mm2 = nan", "k1_per_mm2"),
    ("[distortion]", "[distortion]\nk4_per_mm8 = 1e-9", "k4_per_mm8"),
    ("[distortion]", "distortion = 3", "distortion"),
]


def _preset_text(name="A1"):
    from importlib.resources import files

    return files("shipstar").joinpath("data", "cameras", f"{name}.toml").read_text()


def _edit(text, key, new):
    lines = text.splitlines()
    i = next(i for i, line in enumerate(lines) if line.startswith(key))
    lines[i] = new
    return "\n".join(lines) + "\n"


def _assert_one_line_error(path, field, fn=load_camera):
    with pytest.raises(ShipstarError) as info:
        fn(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert field in msg and str(path) in msg, msg
    return msg


class TestPresetsAndFiles:
    def test_presets_match_the_seeds(self):
        a1, a2 = camera_preset("A1"), camera_preset("A2")
        assert (a1.width_px, a1.height_px, a1.f_mm, a1.x0_px, a1.y0_px) == (1024, 1024, 94.938, 512.556, 497.985)
        assert (a2.width_px, a2.height_px, a2.f_mm, a2.x0_px, a2.y0_px) == (1024, 1024, 94.948, 508.235, 460.915)
        for cam in (a1, a2):
            assert (cam.pixel_mm, cam.frame_rate_hz, cam.adc_bits) == (0.014, 10.0, 12)
            assert cam.distortion.is_zero
        s = camera_preset("seed002")
        assert (s.f_mm, s.x0_px, s.y0_px) == (202.986, 1489.42, 798.54)
        s4 = camera_preset("seed004")
        assert (s4.width_px, s4.height_px) == (512, 512)

    def test_preset_names(self):
        assert camera_preset("a1") is camera_preset("A1")
        assert load_camera("seed004") == camera_preset("seed004")
        with pytest.raises(ShipstarError, match="A1, A2, seed002, seed004"):
            camera_preset("A3")

    @pytest.mark.parametrize("name", PRESETS)
    def test_save_load_round_trip(self, tmp_path, name):
        cam = camera_preset(name)
        path = tmp_path / "sub" / f"{name}.toml"
        save_camera(cam, path)
        assert load_camera(path) == cam
        assert load_camera(str(path)) == cam

    def test_round_trip_of_awkward_values(self, tmp_path, a1):
        cam = a1.replace(name='odd "name" \\ with\ttab, ünïcode\nand newline\x7f',
                         f_mm=94.93800000000001, x0_px=-3e-17, notes="",
                         distortion=random_distortion(a1, [1.3, -0.7, 0.2, 2.0, -1.1, 0.05, 1e-3]))
        save_camera(cam, tmp_path / "odd.toml")
        assert load_camera(tmp_path / "odd.toml") == cam

    def test_notes_and_distortion_table_are_optional(self, tmp_path):
        text = "\n".join(line for line in _preset_text("A1").splitlines()
                         if not line.startswith(("notes", "[distortion]")))
        (tmp_path / "c.toml").write_text(text)
        cam = load_camera(tmp_path / "c.toml")
        assert cam.notes == "" and cam.distortion.is_zero

    @pytest.mark.parametrize("key, new, field", BAD_CASES)
    def test_bad_field_names_field_and_file(self, tmp_path, key, new, field):
        path = tmp_path / "bad.toml"
        path.write_text(_edit(_preset_text("A1"), key, new))
        _assert_one_line_error(path, field)

    @pytest.mark.parametrize("key", ["name", "width_px", "f_mm", "pixel_mm", "x0_px", "aperture_mm",
                                     "read_noise_e", "sky_e_per_px_per_s", "psf_sigma_px", "adc_bits"])
    def test_missing_field(self, tmp_path, key):
        path = tmp_path / "missing.toml"
        path.write_text(_edit(_preset_text("A2"), key, "# removed"))
        msg = _assert_one_line_error(path, key)
        assert "missing" in msg

    def test_not_toml_missing_file_directory(self, tmp_path):
        path = tmp_path / "broken.toml"
        path.write_text("name = \nf_mm = 3\n")
        _assert_one_line_error(path, "not valid TOML")
        _assert_one_line_error(tmp_path / "nope.toml", "no camera file")
        _assert_one_line_error(tmp_path, "cannot read")
        (tmp_path / "latin1.toml").write_bytes(b'name = "\xe9"\n')
        _assert_one_line_error(tmp_path / "latin1.toml", "cannot read")

    def test_constructor_and_replace_validate(self, a1):
        with pytest.raises(ShipstarError, match="'f_mm' must be > 0"):
            a1.replace(f_mm=0.0)
        with pytest.raises(ShipstarError, match="no field 'focal_mm'"):
            a1.replace(focal_mm=3.0)
        with pytest.raises(ShipstarError, match="bias_adu"):
            a1.replace(bias_adu=4095.0)
        with pytest.raises(ShipstarError, match="width_px"):
            a1.replace(width_px=True)
        with pytest.raises(ShipstarError, match="distortion"):
            a1.replace(distortion={"k1_per_mm2": 1e-5})
        assert a1.replace(width_px=np.int64(2048)).width_px == 2048
        plain = Camera(name="t", width_px=100, height_px=80, f_mm=50.0, pixel_mm=0.01, x0_px=49.5, y0_px=39.5)
        assert plain.distortion.is_zero and plain.qe == a1.qe and plain.fov_deg == pytest.approx(
            2 * math.atan(0.5 / 50.0) * RAD2DEG, abs=1e-12)
        with pytest.raises(ShipstarError, match="'name' must not be empty"):
            plain.replace(name=" ")
        with pytest.raises(ShipstarError):
            save_camera("A1", "/tmp/never.toml")

    def test_a_file_s_principal_point_lies_on_the_sensor(self, a1, tmp_path):
        """5000 on a 1024 px sensor was accepted (a bad-input sweep); the edge pixels'
        outer halves are the sensor's."""
        for key, value in (("x0_px", 5000.0), ("y0_px", -0.6), ("x0_px", 1023.6)):
            save_camera(a1.replace(**{key: value}), tmp_path / "c.toml")
            with pytest.raises(ShipstarError, match=rf"field '{key}' must lie on the sensor, within \[-0.5, 1023.5\] "
                                                    rf"px, got {value:g}"):
                load_camera(tmp_path / "c.toml")
        save_camera(a1.replace(x0_px=-0.5, y0_px=1023.5), tmp_path / "c.toml")
        assert load_camera(tmp_path / "c.toml").x0_px == -0.5
