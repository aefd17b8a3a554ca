"""Star extraction against simulated frames with known truth and the Cramer-Rao bound.

The bound is computed here, independently of shipstar: the Fisher information of the
pixel-integrated Gaussian PSF for the unknowns (x, y, flux, background), with Poisson
noise plus read noise and ADC quantisation as Gaussian variance.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.special import erf

from shipstar.camera import camera_preset
from shipstar.errors import ShipstarError
from shipstar.extract import (
    FLAG_EDGE,
    FLAG_ELONGATED,
    FLAG_SATURATED,
    Extraction,
    extract_stars,
    flag_names,
    read_image,
)
from shipstar.extract._io import read_image_any
from shipstar.simulate._render import FalseObjects, render_frame, star_signal_e

A1 = camera_preset("A1")
# shared/ stands beside the repository (CI: a fresh clone with shared/ beside it)
REAL_IMAGES = next((d for d in (Path(__file__).resolve().parents[2] / "shared" / "real-images",
                          Path("/work/shared/real-images")) if d.is_dir()),
            Path(__file__).resolve().parents[2] / "shared" / "real-images")


def cramer_rao_px(camera, signal_e, phase_xy, half=10):
    """(bound on x, bound on y, flux SNR) of one star: Fisher information, 4 unknowns."""
    s = camera.psf_sigma_px
    edges = np.arange(-half, half + 2) - 0.5

    def profile(c):
        u = edges - c
        cdf = 0.5 * erf(u / (math.sqrt(2) * s))
        pdf = np.exp(-0.5 * (u / s) ** 2) / (math.sqrt(2 * math.pi) * s)
        return np.diff(cdf), -np.diff(pdf)

    ex, dex = profile(phase_xy[0])
    ey, dey = profile(phase_xy[1])
    bg_e = (camera.sky_e_per_px_per_s + camera.dark_e_per_s) * camera.exposure_s
    mu = bg_e + signal_e * np.outer(ey, ex)
    var = mu + camera.read_noise_e ** 2 + camera.gain_e_per_adu ** 2 / 12.0
    jac = np.stack([signal_e * np.outer(ey, dex), signal_e * np.outer(dey, ex), np.outer(ey, ex),
                    np.ones_like(mu)], axis=-1).reshape(-1, 4)
    cov = np.linalg.inv(jac.T @ (jac / var.reshape(-1)[:, None]))
    return math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1]), signal_e / math.sqrt(cov[2, 2])


def grid_frame(camera, mag, phase, seed, spacing=24):
    """A frame of identical stars on a grid (all at the same sub-pixel phase)."""
    g = np.arange(20, camera.width_px - 20, spacing, dtype=float)
    xy = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2) + phase
    signal = star_signal_e(camera, np.full(len(xy), mag))
    image = render_frame(camera, xy, signal, np.random.default_rng(seed), hot_pixel_fraction=0.0)
    return image, xy, signal[0]


def match(found_xy, true_xy, radius_px=1.0):
    """Index of the true star nearest to each found one, and whether it is within radius."""
    d2 = ((found_xy[:, None, :] - true_xy[None, :, :]) ** 2).sum(axis=2)
    j = np.argmin(d2, axis=1)
    return j, d2[np.arange(len(j)), j] <= radius_px ** 2


# ---------------------------------------------------------------- accuracy: the bound

@pytest.mark.slow
@pytest.mark.parametrize("mag", [2.5, 5.0, 7.0, 8.0, 8.7])
@pytest.mark.parametrize("phase", [(0.0, 0.0), (0.25, 0.1), (0.5, 0.5), (0.37, -0.42)])
def test_centroids_are_unbiased_and_within_15_percent_of_the_cramer_rao_bound(mag, phase):
    image, xy, signal = grid_frame(A1, mag, phase, seed=int(10 * mag) + int(100 * phase[0]))
    crb_x, crb_y, snr = cramer_rao_px(A1, signal, phase)
    assert snr >= 10.0                                          # the grid stays in the SNR >= 10 regime
    result = extract_stars(image)
    j, ok = match(result.xy_px, xy)
    assert ok.sum() >= 0.99 * len(xy) and len(set(j[ok])) == ok.sum()
    err = result.xy_px[ok] - xy[j[ok]]
    bias = err.mean(axis=0)
    rms = np.sqrt(((err - bias) ** 2).mean(axis=0))
    assert np.all(np.abs(bias) < 0.01), f"bias {bias} px"
    assert rms[0] / crb_x <= 1.15 and rms[1] / crb_y <= 1.15, f"rms/bound {rms[0] / crb_x:.3f}, {rms[1] / crb_y:.3f}"
    # the predicted errors follow the bound (gain and PSF sigma are estimated from the frame:
    # poorly when every star is faint)
    predicted = np.median(result.xy_sigma_px[ok])
    assert predicted == pytest.approx(math.hypot(crb_x, crb_y) / math.sqrt(2), rel=0.25 if snr > 15 else 0.5)


def test_psf_sigma_and_given_camera_parameters():
    image, xy, _ = grid_frame(A1, 6.0, (0.3, 0.2), seed=5, spacing=40)
    fitted = extract_stars(image)
    assert fitted.psf_sigma_px == pytest.approx(A1.psf_sigma_px, rel=0.05)
    given = extract_stars(image, psf_sigma_px=A1.psf_sigma_px, gain_e_per_adu=A1.gain_e_per_adu)
    assert given.psf_sigma_px == A1.psf_sigma_px
    j1, ok1 = match(fitted.xy_px, xy)
    j2, ok2 = match(given.xy_px, xy)
    assert ok1.all() and ok2.all() and len(fitted) == len(given) == len(xy)
    e1 = np.sqrt(np.mean((fitted.xy_px - xy[j1]) ** 2))
    e2 = np.sqrt(np.mean((given.xy_px - xy[j2]) ** 2))
    assert e1 == pytest.approx(e2, rel=0.1)


def test_centre_of_gravity_option_is_coarser_but_close():
    image, xy, signal = grid_frame(A1, 6.0, (0.3, 0.2), seed=6, spacing=40)
    crb_x, _, _ = cramer_rao_px(A1, signal, (0.3, 0.2))
    cog = extract_stars(image, refine="none")
    j, ok = match(cog.xy_px, xy)
    assert ok.all() and len(cog) == len(xy)
    err = cog.xy_px - xy[j]
    assert np.all(np.abs(err.mean(axis=0)) < 0.05)              # thresholded centroids are pulled to pixel centres
    assert np.sqrt(np.mean(err ** 2)) < 2.5 * crb_x
    assert not np.any(cog.flags & 4)                            # no fit, so no fit failure


# ---------------------------------------------------------------- detection

def a1_scene(seed, n=40, **false):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(12, 1012, size=(n, 2))
    mag = rng.uniform(3.0, 7.5, n)
    image = render_frame(A1, xy, star_signal_e(A1, mag), rng, false_objects=FalseObjects(**false))
    return image, xy, mag


def test_finds_every_star_of_an_a1_frame_and_nothing_else():
    image, xy, mag = a1_scene(11, cosmic_ray_count=6)
    result = extract_stars(image)
    j, ok = match(result.xy_px, xy)
    close = np.linalg.norm(xy[:, None] - xy[None], axis=2) + 1e9 * np.eye(len(xy))
    separable = close.min(axis=1) > 6.0
    assert set(np.flatnonzero(separable)) <= set(j[ok])
    assert ok.all(), f"{np.sum(~ok)} false detections"
    assert np.all(np.diff(result.flux_adu) <= 0)                 # brightest first
    assert result.background_adu == pytest.approx(A1.bias_adu + 19.5 / 25.0, abs=0.6)
    assert result.noise_adu == pytest.approx(math.sqrt(19.5 + 400 + 625 / 12) / 25.0, rel=0.1)


def test_hot_pixels_and_cosmic_rays_are_not_stars():
    hot = render_frame(A1, np.zeros((0, 2)), [], np.random.default_rng(3), hot_pixel_fraction=2e-4,
                       hot_pixel_e_per_s=5e4)
    assert np.count_nonzero(hot > A1.bias_adu + 20) > 100        # plenty of bright hot pixels
    assert len(extract_stars(hot)) == 0
    # cosmic rays hit 1-3 pixels: sharper than the PSF (given here, as no star shows it)
    rays = render_frame(A1, np.zeros((0, 2)), [], np.random.default_rng(4), hot_pixel_fraction=0.0,
                        false_objects=FalseObjects(cosmic_ray_count=40, cosmic_ray_e=5000.0))
    assert np.count_nonzero(rays > A1.bias_adu + 20) > 40
    assert len(extract_stars(rays, psf_sigma_px=A1.psf_sigma_px)) == 0


def test_max_stars_keeps_the_brightest():
    image, xy, mag = a1_scene(12)
    full = extract_stars(image)
    top = extract_stars(image, max_stars=5)
    assert len(top) == 5
    np.testing.assert_array_equal(top.xy_px, full.xy_px[:5])


# ---------------------------------------------------------------- flags

def test_flags_saturated_edge_and_elongated():
    xy = np.array([[300.0, 300.0], [1.2, 500.0], [700.0, 700.0]])
    signal = np.array([5e7, 3e4, 3e4])
    fo = FalseObjects(trail_xy_px=[[[100.0, 800.0], [160.0, 840.0]]], trail_signal_e=[4e5])
    image = render_frame(A1, xy, signal, np.random.default_rng(8), hot_pixel_fraction=0.0, false_objects=fo)
    result = extract_stars(image)
    names = {}
    for (x, y), flags in zip(result.xy_px, result.flags):
        names[(round(x / 50), round(y / 50))] = flag_names(flags)
    assert "saturated" in names[(6, 6)]
    assert "edge" in names[(0, 10)]
    assert names[(14, 14)] == []
    trail = [n for (kx, ky), n in names.items() if 1 <= kx <= 4 and 15 <= ky <= 17]
    assert trail and all("elongated" in n for n in trail)
    sat = np.flatnonzero(result.flags & FLAG_SATURATED)
    assert len(sat) == 1 and result.peak_adu[sat[0]] == A1.adc_max_adu
    assert np.isnan(result.xy_sigma_px[sat[0]])
    assert np.linalg.norm(result.xy_px[sat[0]] - [300.0, 300.0]) < 0.1
    edge = np.flatnonzero(result.flags & FLAG_EDGE)
    assert np.linalg.norm(result.xy_px[edge] - [1.2, 500.0], axis=1).min() < 0.2
    assert FLAG_ELONGATED in {int(f) & FLAG_ELONGATED for f in result.flags}


# ---------------------------------------------------------------- empty and bad frames

def test_an_empty_sky_gives_zero_stars_not_an_error():
    image = render_frame(A1, np.zeros((0, 2)), [], np.random.default_rng(4), hot_pixel_fraction=0.0)
    result = extract_stars(image)
    assert isinstance(result, Extraction) and len(result) == 0
    assert result.xy_px.shape == (0, 2) and result.flags.shape == (0,)
    assert math.isnan(result.psf_sigma_px)
    flat = extract_stars(np.full((64, 64), 100, dtype=np.uint16))
    assert len(flat) == 0 and flat.noise_adu > 0


@pytest.mark.parametrize("image, match_text", [
    (np.zeros((64, 64, 3), dtype=np.uint8), "2-D"),
    (np.zeros(100), "2-D"),
    (np.zeros((64, 64), dtype=bool), "dtype"),
    (np.zeros((64, 64), dtype=complex), "dtype"),
    (np.zeros((8, 64)), "at least"),
    (np.full((64, 64), np.nan), "non-finite"),
    (np.full((64, 64), 4095, dtype=np.uint16), "overexposed"),
    (np.full((64, 64), 255, dtype=np.uint8), "overexposed"),
])
def test_bad_frames_raise_one_line_errors(image, match_text):
    with pytest.raises(ShipstarError, match=match_text) as info:
        extract_stars(image)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("kwargs, match_text", [
    (dict(threshold_sigma=0.5), "threshold_sigma"),
    (dict(threshold_sigma=float("nan")), "threshold_sigma"),
    (dict(max_stars=0), "max_stars"),
    (dict(refine="moffat"), "refine"),
    (dict(psf_sigma_px=-1.0), "psf_sigma_px"),
    (dict(gain_e_per_adu=0.0), "gain_e_per_adu"),
    (dict(saturation_adu=float("inf")), "saturation_adu"),
])
def test_bad_options_raise(kwargs, match_text):
    with pytest.raises(ShipstarError, match=match_text):
        extract_stars(np.zeros((64, 64), dtype=np.uint16), **kwargs)


@pytest.mark.parametrize("value", [1e39, -4e38, np.inf, np.nan])
def test_a_few_bad_pixels_are_masked_not_fatal(value):
    """Masked (NaN) or corrupt pixels: a few are replaced by the median and the stars are the
    same as in the clean frame; a frame with more than 1 % of them is refused in one line."""
    image, _, _ = a1_scene(15, n=5)
    image = image.astype(np.float64)
    clean = extract_stars(image)
    image[3, 7] = image[40, 2] = value                     # float32 casts and sums would overflow
    masked = extract_stars(image)
    np.testing.assert_allclose(masked.xy_px, clean.xy_px, atol=1e-6)
    image[:20, :] = value                                  # 2 % of the frame (+ the pixel at row 40)
    with pytest.raises(ShipstarError, match=r"20481 of 1048576 pixels non-finite .* beyond \+-3e\+38") as info:
        extract_stars(image)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("scale", [1e30, 1e35])
def test_huge_pixel_values_within_the_range_give_the_same_stars(scale):
    """Values up to 3e38 are accepted: sums that could overflow float32 are done in float64
    (pytest turns an overflow warning into an error)."""
    image, _, _ = a1_scene(16, n=25)
    smeared, xy, _, smear = smeared_grid_frame(1.0, seed=64)
    for frame, kwargs in ((image, {}), (smeared, dict(smear_px=np.median(smear, axis=0), psf_sigma_px=A1.psf_sigma_px,
                                                     gain_e_per_adu=A1.gain_e_per_adu))):
        ref = extract_stars(frame.astype(np.float64), **kwargs)
        if "gain_e_per_adu" in kwargs:
            kwargs["gain_e_per_adu"] /= scale                   # the same electrons in scaled ADU
        big = extract_stars(frame.astype(np.float64) * scale, **kwargs)
        assert len(big) == len(ref) > 20
        d = np.linalg.norm(big.xy_px[:, None] - ref.xy_px[None], axis=2).min(axis=1)
        assert np.all(d < 0.05)                                 # the fits' convergence tolerance, at most
        np.testing.assert_allclose(big.flux_adu.sum(), scale * ref.flux_adu.sum(), rtol=1e-3)


@pytest.mark.parametrize("shape_hw", [(300, 257), (257, 300), (250, 131)])
def test_frames_of_any_size(shape_hw):
    """Frames whose size is not a multiple of the background mesh's blocks (used to raise in
    the candidate threshold, or to leave its last rows unset)."""
    height, width = shape_hw
    camera = A1.replace(width_px=width, height_px=height)
    rng = np.random.default_rng(17)
    gx, gy = np.meshgrid(np.arange(10.0, width - 10, 30.0), np.arange(10.0, height - 10, 30.0))
    xy = np.column_stack([gx.ravel(), gy.ravel()]) + rng.uniform(-0.5, 0.5, (gx.size, 2))
    xy = np.vstack([xy, [[width - 2.7, height - 3.2]]])    # in the last, partial block
    image = render_frame(camera, xy, star_signal_e(camera, np.full(len(xy), 5.0)), rng, hot_pixel_fraction=0.0)
    result = extract_stars(image)
    j, ok = match(result.xy_px, xy)
    assert ok.all() and len(set(j)) == len(result) == len(xy)


def test_big_endian_and_float_frames_give_the_same_stars():
    image, xy, _ = a1_scene(13, n=10)
    ref = extract_stars(image)
    for variant in (image.astype(">u2"), image.astype(np.float32), image.astype(np.int32)):
        other = extract_stars(variant, saturation_adu=4095)
        np.testing.assert_allclose(other.xy_px, ref.xy_px, atol=1e-6)
    # a float frame in steps of 1/4096 (normalised to 0..1): its step is the quantum (it was
    # taken as continuous, and blocks whose samples mostly share one value got zero noise)
    scaled = extract_stars(image / 4096.0, saturation_adu=4095 / 4096)
    np.testing.assert_allclose(scaled.xy_px, ref.xy_px, atol=1e-6)
    assert scaled.noise_adu * 4096 == pytest.approx(ref.noise_adu, rel=1e-9)


# ---------------------------------------------------------------- reading files

def _frame():
    image, _, _ = a1_scene(14, n=12)
    return image


def test_read_fits_png_tiff_npy_round_trip(tmp_path):
    from astropy.io import fits
    from PIL import Image

    image = _frame()
    fits.PrimaryHDU(image).writeto(tmp_path / "f.fits")             # uint16: BZERO = 32768
    Image.fromarray(image).save(tmp_path / "f.png")
    Image.fromarray(image).save(tmp_path / "f.tif")
    np.save(tmp_path / "f.npy", image)
    for name in ("f.fits", "f.png", "f.tif", "f.npy"):
        back = read_image(tmp_path / name)
        assert back.dtype == np.uint16 and back.dtype.isnative, name
        np.testing.assert_array_equal(back, image, err_msg=name)
        assert back.flags.writeable, name                  # the public reader's arrays are the caller's
        # the solver's reader (may share Pillow's bytes, read only): the same pixels
        np.testing.assert_array_equal(read_image_any(tmp_path / name, writable=False), image, err_msg=name)
    assert len(extract_stars(read_image(tmp_path / "f.fits"))) == len(extract_stars(image))


def test_read_fits_extension_cube_and_float(tmp_path):
    from astropy.io import fits

    data = np.arange(64 * 48, dtype=np.float32).reshape(48, 64)
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(data[None])]).writeto(tmp_path / "ext.fits")
    back = read_image(tmp_path / "ext.fits")
    assert back.shape == (48, 64) and back.dtype == np.float32
    np.testing.assert_array_equal(back, data)
    fits.PrimaryHDU(np.zeros((2, 8, 8))).writeto(tmp_path / "cube.fits")
    with pytest.raises(ShipstarError, match="not one 2-D image"):
        read_image(tmp_path / "cube.fits")
    table = fits.BinTableHDU.from_columns([fits.Column(name="a", format="E", array=np.zeros(3))])
    fits.HDUList([fits.PrimaryHDU(), table]).writeto(tmp_path / "table.fits")
    with pytest.raises(ShipstarError, match="no 2-D image"):
        read_image(tmp_path / "table.fits")


def test_read_colour_jpeg_and_png_as_luminance(tmp_path):
    from PIL import Image

    rgb = np.zeros((40, 50, 3), dtype=np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 200, 100, 50
    Image.fromarray(rgb).save(tmp_path / "c.png")
    Image.fromarray(rgb).save(tmp_path / "c.jpg", quality=95)
    lum = 0.299 * 200 + 0.587 * 100 + 0.114 * 50                     # ITU-R 601
    for name in ("c.png", "c.jpg"):
        back = read_image(tmp_path / name)
        assert back.shape == (40, 50) and back.dtype == np.uint8 and back.flags.writeable
        assert np.abs(back.astype(float) - lum).max() <= 2.0, name
        np.testing.assert_array_equal(read_image_any(tmp_path / name, writable=False), back, err_msg=name)
    Image.fromarray(rgb[..., 0]).save(tmp_path / "g.jpg")
    assert read_image(tmp_path / "g.jpg").dtype == np.uint8


def test_unreadable_files_raise_one_line_errors(tmp_path):
    (tmp_path / "notes.txt").write_text("not an image\n")
    (tmp_path / "bad.fits").write_bytes(b"SIMPLE  =                    T" + b" " * 50 + b"garbage")
    (tmp_path / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40)
    np.save(tmp_path / "rgb.npy", np.zeros((4, 5, 3)))
    np.save(tmp_path / "text.npy", np.array(["a", "b"]))
    cases = [("notes.txt", "not an image file"), ("bad.fits", "FITS"), ("bad.png", "PNG"),
             ("rgb.npy", "not one 2-D image"), ("text.npy", "not"), ("missing.fits", "no such file"),
             (".", "directory")]
    for name, text in cases:
        with pytest.raises(ShipstarError, match=text) as info:
            read_image(tmp_path / name)
        assert "\n" not in str(info.value), name


def huge_image_header(path, width=20000, height=20000):
    """A PNG or JPEG file (by ``path``'s suffix) of a few bytes whose header says ``width`` x
    ``height`` 8-bit grey pixels (no pixel data): what Pillow's size check reads."""
    import struct
    import zlib

    if path.suffix == ".png":
        def chunk(kind, data):
            return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

        raw = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
               + chunk(b"IEND", b""))
    else:
        sof = b"\xff\xc0" + struct.pack(">HBHHB", 11, 8, height, width, 1) + b"\x01\x11\x00"
        sos = b"\xff\xda" + struct.pack(">HB", 8, 1) + b"\x01\x00\x00\x3f\x00"
        raw = b"\xff\xd8" + sof + sos + b"\xff\xd9"
    path.write_bytes(raw)
    return path


def test_images_over_pillows_size_limit_are_refused_in_one_line(tmp_path, monkeypatch):
    """Over twice ``PIL.Image.MAX_IMAGE_PIXELS`` (Pillow's decompression-bomb limit) an image
    is refused with its pixel count and the limit; between once and twice, where Pillow
    warns of a possible bomb, it is read as any other, with no warning (pytest turns
    warnings into errors)."""
    from PIL import Image

    for name in ("big.png", "big.jpg"):
        with pytest.raises(ShipstarError, match=r"too large: 400000000 pixels, over the limit of 178956970 ") as info:
            read_image(huge_image_header(tmp_path / name))
        assert "\n" not in str(info.value) and name in str(info.value)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)
    image = np.arange(30 * 40, dtype=np.uint16).reshape(30, 40)                  # 1200 px: Pillow warns
    for ext in ("png", "tif"):
        Image.fromarray(image).save(tmp_path / f"warned.{ext}")
        Image.fromarray(np.zeros((50, 41), np.uint16)).save(tmp_path / f"bomb.{ext}")     # 2050 px > 2000
        np.testing.assert_array_equal(read_image(tmp_path / f"warned.{ext}"), image)
        np.testing.assert_array_equal(read_image_any(tmp_path / f"warned.{ext}", writable=False), image)
        with pytest.raises(ShipstarError, match=r"too large: 2050 pixels, over the limit of 2000 "):
            read_image(tmp_path / f"bomb.{ext}")


def _pillow_luminance(path) -> np.ndarray:
    """A JPEG's luminance as Pillow decodes it (the Y plane of a colour one): the reference."""
    from PIL import Image

    with Image.open(path) as im:
        if im.mode == "RGB":
            im.draft("L", None)
        im.load()
        return np.array(im if im.mode == "L" else im.convert("L"))


def test_jpeg_read_directly_is_pillows_decode_and_the_rest_goes_to_pillow(tmp_path):
    from PIL import Image

    from shipstar.extract._io import _read_jpeg_direct

    rng = np.random.default_rng(3)
    rgb = rng.integers(0, 256, (61, 83, 3), dtype=np.uint8)
    rgb[20:30, 40:50] = 250
    grey = rng.integers(0, 4096, (47, 59)).astype(np.uint8)
    Image.fromarray(rgb).save(tmp_path / "c.jpg", quality=90)                      # YCbCr 4:2:0
    Image.fromarray(rgb).save(tmp_path / "c444.jpg", quality=97, subsampling=0)
    Image.fromarray(rgb).save(tmp_path / "p.jpg", quality=80, progressive=True)
    Image.fromarray(grey).save(tmp_path / "g.jpg")
    for name in ("c.jpg", "c444.jpg", "p.jpg", "g.jpg"):
        direct = _read_jpeg_direct(tmp_path / name)
        assert direct is not None and direct.flags.writeable, name
        np.testing.assert_array_equal(direct, _pillow_luminance(tmp_path / name), err_msg=name)
        np.testing.assert_array_equal(read_image(tmp_path / name), direct, err_msg=name)
    # CMYK: not taken directly; Pillow's luminance
    Image.fromarray(rgb).convert("CMYK").save(tmp_path / "k.jpg")
    assert _read_jpeg_direct(tmp_path / "k.jpg") is None
    np.testing.assert_array_equal(read_image(tmp_path / "k.jpg"), _pillow_luminance(tmp_path / "k.jpg"))
    # a multi-picture file (MPO, two frames): refused as before, in one line
    Image.fromarray(rgb).save(tmp_path / "two.jpg", format="MPO", save_all=True,
                              append_images=[Image.fromarray(rgb[::-1])])
    assert _read_jpeg_direct(tmp_path / "two.jpg") is None
    with pytest.raises(ShipstarError, match="2 frames") as info:
        read_image(tmp_path / "two.jpg")
    assert "\n" not in str(info.value)
    # truncated: Pillow's one-line error, not a half-decoded image
    data = (tmp_path / "c.jpg").read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data[:len(data) // 2])
    assert _read_jpeg_direct(tmp_path / "cut.jpg") is None
    with pytest.raises(ShipstarError, match="JPEG") as info:
        read_image(tmp_path / "cut.jpg")
    assert "\n" not in str(info.value)


# ---------------------------------------------------------------- real photographs

# (min, max) star counts, checked by eye on overlays of the detections: JPEG artefacts,
# vignetting, trees and a roof must not turn into hundreds of false stars.
REAL_COUNTS = {
    "crappy.jpg": (30, 90), "orion2.jpg": (60, 200), "orion_belt.jpg": (40, 130),
    "orion_trees.jpg": (40, 140), "pleiades.jpg": (35, 110), "roof.jpg": (15, 60),
    "test2_g100_e50ms.jpg": (50, 150), "virgo.jpg": (25, 90),
}


@pytest.mark.parametrize("name", sorted(REAL_COUNTS))
def test_real_photographs(name):
    image = read_image(REAL_IMAGES / name)
    # decoded by libjpeg-turbo directly: every pixel as Pillow decodes it
    from shipstar.extract._io import _read_jpeg_direct

    direct = _read_jpeg_direct(REAL_IMAGES / name)
    assert direct is not None
    np.testing.assert_array_equal(direct, _pillow_luminance(REAL_IMAGES / name))
    np.testing.assert_array_equal(image, direct)
    result = extract_stars(image)
    lo, hi = REAL_COUNTS[name]
    assert lo <= len(result) <= hi
    assert 0.5 < result.psf_sigma_px < 2.5
    good = np.flatnonzero(result.flags == 0)[:10]
    assert len(good) == 10 and np.all(result.xy_sigma_px[good] < 0.5)   # detected at >= 5 sigma
    assert np.all((result.xy_px >= -0.5) & (result.xy_px <= np.array(image.shape[::-1]) - 0.5))


# ---------------------------------------------------------------- smeared frames (a ship's motion)

#: Rotation axis of the test frames, sensor axes (X boresight): its large boresight component
#: (as for sensor A1 looking aft at 40 deg elevation while the ship rolls) adds field
#: rotation, so the smear varies over the frame (by +-2.7 px at 4 deg/s).
SMEAR_AXIS = np.array([0.76, 0.52, 0.39]) / np.linalg.norm([0.76, 0.52, 0.39])


def smeared_grid_frame(rate_deg_s, seed, camera=A1):
    """A1 frame of 324 stars on a 55 px grid turning at ``rate_deg_s`` about SMEAR_AXIS for 80 ms.

    Every other star is bright (Hp 4.5, for the bias), the others spread over Hp 6.5-9.3
    (line-integrated SNR from ~4 to ~80 at 4 deg/s). Returns image, xy, signal_e, smear (N, 2).
    """
    from shipstar.simulate import smear_px_from_rate

    rng = np.random.default_rng(seed)
    g = np.arange(40.0, 990.0, 55.0)
    xy = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2) + rng.uniform(-0.5, 0.5, (len(g) ** 2, 2))
    mag = np.where(np.arange(len(xy)) % 2 == 0, 4.5, rng.uniform(6.5, 9.3, len(xy)))
    omega = SMEAR_AXIS * math.radians(rate_deg_s)
    smear = smear_px_from_rate(camera, camera.unproject(xy), omega, camera.exposure_s)
    signal = star_signal_e(camera, mag)
    image = render_frame(camera, xy, signal, rng, smear_px=smear if rate_deg_s else None)
    return image, xy, signal, smear


def cramer_rao_smeared(camera, signal_e, xy_px, smear_px):
    """(covariance (2, 2) of x, y; flux SNR) of one smeared star: Fisher information, unknowns x, y, F, b.

    The smeared PSF is the pixel-integrated Gaussian moved uniformly along ``smear_px``
    (2,), sampled every 0.05 sigma; noise: Poisson + read noise + ADC quantisation.
    The flux SNR is the *line-integrated SNR* of the tests: F / sigma(F).
    """
    s = camera.psf_sigma_px
    n = max(1, math.ceil(math.hypot(*smear_px) / (0.05 * s)))
    t = (np.arange(n) + 0.5) / n - 0.5
    half = [int(math.ceil(abs(d) / 2 + 5 * s)) + 2 for d in smear_px]

    def profile(c, d, h):
        edges = np.rint(c) + np.arange(-h, h + 2) - 0.5
        u = edges[None, :] - (c + t * d)[:, None]
        cdf = 0.5 * erf(u / (math.sqrt(2) * s))
        pdf = np.exp(-0.5 * (u / s) ** 2) / (math.sqrt(2 * math.pi) * s)
        return np.diff(cdf, axis=1), -np.diff(pdf, axis=1)

    ex, dex = profile(xy_px[0], smear_px[0], half[0])
    ey, dey = profile(xy_px[1], smear_px[1], half[1])
    shape, d_x, d_y = ey.T @ ex / n, ey.T @ dex / n, dey.T @ ex / n
    bg_e = (camera.sky_e_per_px_per_s + camera.dark_e_per_s) * camera.exposure_s
    var = bg_e + signal_e * shape + camera.read_noise_e ** 2 + camera.gain_e_per_adu ** 2 / 12.0
    jac = np.stack([signal_e * d_x, signal_e * d_y, shape, np.ones_like(shape)], axis=-1).reshape(-1, 4)
    cov = np.linalg.inv(jac.T @ (jac / var.reshape(-1)[:, None]))
    return cov[:2, :2], signal_e / math.sqrt(cov[2, 2])


def match_one_to_one(found_xy, true_xy, radius_px):
    """Index of the found star matched to each true star (-1: none), nearest pairs first."""
    d = np.linalg.norm(found_xy[:, None, :] - true_xy[None, :, :], axis=2) if len(found_xy) else np.zeros((0, 0))
    found_of_true = np.full(len(true_xy), -1)
    used = np.zeros(len(found_xy), dtype=bool)
    for f, t in zip(*np.unravel_index(np.argsort(d, axis=None), d.shape)):
        if d[f, t] > radius_px[t]:
            continue
        if not used[f] and found_of_true[t] < 0:
            used[f], found_of_true[t] = True, f
    return found_of_true


def smeared_statistics(result, xy, signal, smear):
    """Completeness, false detections, bias and RMS / bound along and across the smear."""
    covs, snr = map(np.array, zip(*(cramer_rao_smeared(A1, s, p, d) for s, p, d in zip(signal, xy, smear))))
    found = match_one_to_one(result.xy_px, xy, 1.0 + 4.0 * np.sqrt(np.trace(covs, axis1=1, axis2=2)))
    length = np.hypot(*smear.T)
    along = np.where(length[:, None] > 0, smear / np.maximum(length, 1e-12)[:, None], [1.0, 0.0])
    across = np.stack([-along[:, 1], along[:, 0]], axis=1)
    use = (found >= 0) & (snr >= 10.0)
    use[use] &= (result.flags[found[use]] & FLAG_SATURATED) == 0
    err = result.xy_px[found[use]] - xy[use]
    out = dict(complete=np.mean(found[snr >= 10] >= 0), n10=int(np.sum(snr >= 10)),
               false=int(len(result) - np.sum(found >= 0)), n=int(use.sum()),
               n_faint=int(np.sum(use & (snr < 30.0))))
    bright = signal[use] == signal.max()
    for name, axis in (("along", along[use]), ("across", across[use])):
        e = np.sum(err * axis, axis=1)
        bound = np.sqrt(np.einsum("ni,nij,nj->n", axis, covs[use], axis))
        out[f"bias_{name}"] = float(np.mean(e[bright]))
        out[f"se_{name}"] = float(np.std(e[bright]) / math.sqrt(bright.sum()))
        out[f"ratio_{name}"] = float(np.sqrt(np.mean((e / bound) ** 2)))
        faint = snr[use] < 30.0
        out[f"faint_ratio_{name}"] = float(np.sqrt(np.mean((e[faint] / bound[faint]) ** 2)))
        predicted = np.sqrt(np.einsum("ni,nij,nj->n", axis, result.xy_cov_px2[found[use]], axis))
        out[f"predicted_{name}"] = float(np.nanmedian(predicted / bound))
    return out


@pytest.mark.slow
@pytest.mark.parametrize("rate_deg_s", [0.0, 0.5, 1.0, 2.0, 4.0])
@pytest.mark.parametrize("given", [True, False], ids=["smear-and-camera-given", "defaults"])
def test_smeared_stars_are_complete_unbiased_and_near_the_cramer_rao_bound(rate_deg_s, given):
    image, xy, signal, smear = smeared_grid_frame(rate_deg_s, seed=50 + int(10 * rate_deg_s))
    kwargs = dict(psf_sigma_px=A1.psf_sigma_px, gain_e_per_adu=A1.gain_e_per_adu,
                  smear_px=np.median(smear, axis=0)) if given else {}
    result = extract_stars(image, **kwargs)
    st = smeared_statistics(result, xy, signal, smear)
    print(f"\nrate {rate_deg_s} deg/s, smear {np.median(np.hypot(*smear.T)):.1f} px, given={given}: " +
          ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in st.items()))
    assert st["n10"] >= 200
    assert st["complete"] >= 0.95
    assert st["false"] <= 2             # so far: faint stars found > 4 sigma along from their truth
    for name in ("along", "across"):
        assert abs(st[f"bias_{name}"]) < 0.02 and abs(st[f"bias_{name}"]) < 4 * st[f"se_{name}"] + 0.005
        assert st[f"ratio_{name}"] <= 1.3
        assert st[f"faint_ratio_{name}"] <= 1.5          # SNR 10-30 alone: the long tail of faint streaks
        assert st[f"predicted_{name}"] == pytest.approx(1.0, abs=0.15)     # xy_cov_px2 follows the bound
    if rate_deg_s >= 1.0:
        # the common smear the stars were measured with (its sign is arbitrary): estimated from
        # the frame, or the given one measured again from 12 of the brightest streaks found,
        # spread over a field whose smear varies by +-11 % (the grid's equally bright stars: the
        # first 12 found, one corner's, were 4-8 % short)
        true = np.median(smear, axis=0)
        est = result.smear_px * np.sign(result.smear_px @ true)
        assert np.hypot(*est) == pytest.approx(np.hypot(*true), rel=0.03)
        assert abs(math.atan2(est[1], est[0]) - math.atan2(true[1], true[0])) < math.radians(2.0)   # field: +-6 deg
    elif rate_deg_s == 0.0:
        assert np.all(result.smear_px == 0.0)


def test_calibration_streaks_are_spread_over_the_field():
    """``spread_over_field`` takes the brightest object of each of 3 x 3 regions first (in
    order of brightness), then each region's second brightest, and so on: of 19 objects
    whose 9 brightest sit in one corner, 12 are taken from all 9 regions -- every region's
    brightest, the two second brightest (the corner's and the middle's), the corner's third;
    fewer objects than asked: all of them, in order."""
    from shipstar.extract._smear import spread_over_field

    corner = np.array([[10 + 5 * k, 12 + 3 * k] for k in range(9)])           # brightest first
    rest = np.array([[500, 40], [900, 60], [40, 500], [500, 500], [900, 500], [40, 900], [500, 900],
                     [900, 900], [510, 510], [20, 30]])
    col, row = np.concatenate([corner, rest]).T
    pick = spread_over_field(col, row, (1000, 1000), 12)
    assert list(pick) == sorted(pick) and len(pick) == 12
    region = np.minimum(row[pick] * 3 // 1000, 2) * 3 + np.minimum(col[pick] * 3 // 1000, 2)
    assert set(region.tolist()) == set(range(9))                         # every region
    np.testing.assert_array_equal(pick, [0, 1, 2, 9, 10, 11, 12, 13, 14, 15, 16, 17])
    np.testing.assert_array_equal(spread_over_field(col[:5], row[:5], (1000, 1000), 12), np.arange(5))
    rng = np.random.default_rng(44)                      # against the rule written out, region by region
    for n_obj in (13, 40, 300):
        col, row = rng.integers(-2, 1202, n_obj), rng.integers(-2, 802, n_obj)   # (a few just off the frame)
        region = np.clip(row * 3 // 800, 0, 2) * 3 + np.clip(col * 3 // 1200, 0, 2)
        rank = [int(np.count_nonzero(region[:k] == region[k])) for k in range(n_obj)]
        expected = sorted(sorted(range(n_obj), key=lambda k: (rank[k], k))[:12])
        np.testing.assert_array_equal(spread_over_field(col, row, (800, 1200), 12), expected)


def test_line_filter_is_the_sum_along_the_digital_line():
    """The line filter (flattened shifts, taps taken in pairs) against the plain sum over its taps."""
    from shipstar.extract._matched import LineFilter, line_filter

    rng = np.random.default_rng(18)
    height, width, fill = 61, 83, 100.0
    image = rng.normal(fill, 5.0, (height, width))
    patch = (np.array([5 * width + 7, 30 * width + 40, height * width - 1]), np.array([90.0, 95.0, 99.0]))
    patched = image.copy()
    patched.reshape(-1)[patch[0]] = patch[1]
    pad = 50
    padded = np.pad(patched, pad, constant_values=fill)
    for smear in [(6.0, 2.0), (-3.0, 25.0), (24.0, -24.0), (0.0, 1.6), (40.0, 3.0), (-2.0, -17.0)]:
        for across in (0, 1, 2):
            lf = LineFilter(smear, across)
            minor = np.array([0, 1]) if lf.major == 0 else np.array([1, 0])     # (x, y) step across
            ref = np.zeros((height, width))
            for ox, oy in lf.offsets:
                for a in range(-across, across + 1):
                    dx, dy = np.array([ox, oy]) + a * minor
                    ref += padded[pad + dy:pad + dy + height, pad + dx:pad + dx + width]
            got = line_filter(image, fill, lf, patch)
            assert got.shape == (height, width) and lf.taps == len(lf.offsets) * (2 * across + 1)
            np.testing.assert_allclose(got, ref, rtol=1e-6, err_msg=f"smear {smear}, across {across}")


def test_compiled_line_filter_is_the_numpy_reference_bit_for_bit():
    """The one-call compiled line filter against the NumPy passes it replaced (kept as the
    reference): the same float32 (or float64) sums, exactly, for every pixel type the
    detection takes, long and short smears along either axis, the across half-widths 0-3,
    pixels patched, and values that need float64 sums."""
    from shipstar.extract._matched import LineFilter, _line_filter_python, line_filter

    rng = np.random.default_rng(23)
    height, width, fill = 57, 91, 1234.5
    base = rng.normal(fill, 40.0, (height, width))
    images = [np.clip(base, 0, 65535).astype(np.uint16), base.astype(np.float32), base,
              np.clip(base, 0, 255).astype(np.uint8), base.astype(np.int32), base * 1e31]
    patch = (np.array([0, 7 * width + 3, height * width - 1]), np.array([1000.0, 1100.5, 990.25]))
    # unsorted, a pixel patched twice (the last value counts, as numpy assigns), a whole row's ends
    shuffled = (np.array([height * width - 1, 7 * width + 3, 0, 20 * width, 7 * width + 3, 21 * width - 1]),
                np.array([990.25, 1100.5, 1000.0, 1500.0, 1200.0, 800.0]))
    for smear in [(0.0, 0.0), (2.2, 0.3), (6.0, 2.0), (-3.0, 25.0), (24.0, -24.0), (0.4, -9.6), (40.0, 3.0),
                  (-13.0, -4.5)]:
        for across in (0, 1, 2, 3):
            lf = LineFilter(smear, across)
            for image in images:
                for pt in (None, patch, shuffled):
                    got = line_filter(image, fill, lf, pt).copy()
                    ref = _line_filter_python(image, fill, lf, pt).copy()
                    assert got.dtype == ref.dtype
                    np.testing.assert_array_equal(got, ref, err_msg=f"{smear} {across} {image.dtype} {pt is None}")


def test_compiled_streak_peaks_are_the_numpy_reference_bit_for_bit():
    """The line filter's peaks (threshold, 3 x 3 maxima, suppression, components and their
    extents: ``_kernels.streak_peaks``) against the NumPy steps they replaced (kept as the
    reference), exactly: smeared frames with satellite trails and a bright edge (components too
    big, several peaks each: only the strongest kept), float32 and float64 filter images,
    thresholds that leave many, one or no peaks, and a frame without candidates."""
    from shipstar.extract._background import estimate_mesh
    from shipstar.extract._matched import (LineFilter, _filter_mesh, _streak_peaks_python, candidate_pixels,
                                           detect_streaks, line_filter)

    image, _, _, smear = smeared_grid_frame(3.0, seed=71)
    trails = image.astype(float)
    for r0, slope in ((100, 0.31), (700, -0.12)):                 # two trails across the frame
        cols = np.arange(image.shape[1])
        rows = np.clip(np.rint(r0 + slope * cols).astype(int), 0, image.shape[0] - 1)
        trails[rows, cols] += 400.0
    trails[:, 1000:] += 300.0                                      # a bright edge
    frames = [image, np.clip(trails, 0, 4095).astype(np.uint16), trails * 1e31]
    lf = LineFilter(np.median(smear, axis=0), across_px=1)
    n_big = n_peaks = 0
    for frame in frames:
        mesh = estimate_mesh(frame, quantum_adu=1.0 if frame.dtype.kind == "u" else 0.0)
        for threshold, segment in ((5.0, 2.5), (3.0, 2.5), (40.0, 5.0), (1e9, 2.5), (5.0, 1e9)):
            got = detect_streaks(frame, mesh, lf, threshold, segment, 1.1)
            s_image = line_filter(frame, mesh.background_adu, lf)
            mesh_s = _filter_mesh(s_image, mesh)
            idx = candidate_pixels(s_image, mesh_s, segment)
            want = _streak_peaks_python(s_image, idx, mesh_s, lf, threshold, 1.1)
            assert sorted(got) == sorted(want)
            for key in want:
                assert got[key].dtype == want[key].dtype, key
                np.testing.assert_array_equal(got[key], want[key], err_msg=f"{key} {frame.dtype} {threshold}")
            n_big += int(np.count_nonzero(want["too_big"]))
            n_peaks += len(want["col"])
    assert n_big >= 4 and n_peaks > 1000          # the cases the test is for were met


def test_compiled_point_objects_are_the_numpy_reference_bit_for_bit():
    """The point sources among the candidate pixels (3 x 3 maxima, the box test against hot
    pixels and noise, one peak a component: ``_kernels.point_objects``) against the NumPy
    steps they replaced (kept as the reference), exactly: every pixel type the detection
    takes, hot pixels and cosmic rays, blended stars (several peaks a component), flat
    saturated tops and twin peaks of equal box excess (ties: the first kept), thresholds
    that leave many, few or no objects, and a frame without candidates."""
    from shipstar.extract._background import estimate_mesh
    from shipstar.extract._point import _detect_objects_python, detect_objects

    rng = np.random.default_rng(73)
    base = np.full((300, 400), 200.0) + rng.normal(0.0, 6.0, (300, 400))
    yy, xx = np.mgrid[0:300, 0:400]
    for x0, y0, f in zip(rng.uniform(5, 395, 120), rng.uniform(5, 295, 120), rng.uniform(50, 5000, 120)):
        base += f / (2 * np.pi) * np.exp(-((xx - x0) ** 2 + (yy - y0) ** 2) / 2.0)
    for x0 in (100.0, 102.5, 104.0):                                # a blend: three peaks, one component
        base += 3000.0 / (2 * np.pi) * np.exp(-((xx - x0) ** 2 + (yy - 150.0) ** 2) / 2.0)
    base[rng.integers(0, 300, 40), rng.integers(0, 400, 40)] += 2000.0      # hot pixels, cosmic rays
    base[50:53, 60:63] = 4095.0                                     # a flat saturated top
    frames = [np.clip(base, 0, 4095).astype(np.uint16), base.astype(np.float32), base,
              np.clip(base, -100, 30000).astype(np.int16), np.clip(base / 20.0, 0, 255).astype(np.uint8),
              np.round(base).astype(np.int64), np.full((64, 64), 7, dtype=np.uint16)]
    twins = np.full((64, 64), 100, dtype=np.uint16)                 # two equal peaks in one component
    twins[29:32, 20:25] = 150
    twins[30, [21, 23]] = 400
    frames.append(twins)
    n_objects = 0
    for frame in frames:
        mesh = estimate_mesh(frame, quantum_adu=1.0 if frame.dtype.kind in "ui" else 0.0)
        for threshold in (5.0, 2.0, 50.0, 1000.0):
            got = detect_objects(frame, mesh, threshold)
            want = _detect_objects_python(frame, mesh, threshold)
            assert len(got) == len(want) == 4
            for g, w in zip(got, want):
                assert g.dtype == w.dtype
                np.testing.assert_array_equal(g, w, err_msg=f"{frame.dtype} {threshold}")
            n_objects += len(want[0])
    assert n_objects > 500                          # (the cases the test is for were met)


def test_candidate_kernels_refuse_unsorted_or_off_image_indices():
    """The C code trusts its inputs: the wrappers of the peak kernels refuse candidate indices
    that are unsorted, repeated or off the image, and mesh grids of unequal shapes."""
    from shipstar.extract._kernels import point_objects, streak_peaks

    image, bg, noise = np.zeros((8, 8), dtype=np.float32), np.zeros((2, 2)), np.ones((2, 2))
    for idx in ([5, 3], [3, 3], [-1, 2], [2, 64]):
        with pytest.raises(ValueError, match="sorted, distinct flat indices"):
            streak_peaks(image, idx, bg, noise, 4, 0.0, 1.0, (1.0, 0.0), 3.0, 2.0, (9.0, 9.0))
        with pytest.raises(ValueError, match="sorted, distinct flat indices"):
            point_objects(image, idx, bg, noise, 4, 5.0, 0.5)
    with pytest.raises(ValueError, match="mesh grids"):
        point_objects(image, [1, 2], bg, np.ones((2, 3)), 4, 5.0, 0.5)
    peaks, _, labels = point_objects(image, [1, 2], bg, noise, 4, 5.0, 0.5)   # flat: no star, one component
    assert len(peaks) == 0 and labels.tolist() == [0, 0]


def test_work_arrays_kept_between_frames_do_not_leak_into_results():
    """The line filter and the fits reuse per-thread work arrays: a frame of another size or
    with other stars in between must not change a frame's result."""
    image, xy, signal, smear = smeared_grid_frame(2.0, seed=65)
    kwargs = dict(smear_px=np.median(smear, axis=0), psf_sigma_px=A1.psf_sigma_px, gain_e_per_adu=A1.gain_e_per_adu)
    first = extract_stars(image, **kwargs)
    extract_stars(image[100:400, 50:700], **kwargs)                       # smaller: views of the same buffers
    extract_stars(smeared_grid_frame(4.0, seed=66)[0], smear_px=(20.0, 15.0))   # longer smear, more stars
    again = extract_stars(image, **kwargs)
    np.testing.assert_array_equal(again.xy_px, first.xy_px)
    np.testing.assert_array_equal(again.xy_cov_px2, first.xy_cov_px2)
    np.testing.assert_array_equal(again.flags, first.flags)


def test_objects_at_the_noise_level_do_not_outvote_a_star_in_the_smear_calibration():
    """Without a hint, ``_smear.calibrate`` (the smear from the brightest objects) uses only
    fits whose flux it measures at ``_CALIBRATION_MIN_SNR`` (5) or better: one star of
    60 000 e smeared (1.0, 1.5) px, two objects of 300 e (flux ~3 sigma) smeared (6, 4) px.
    Before, their fits (smears undetermined within ~2 px) made 2 of the 3 and the median
    (a realistic session's faint frame took an 8 px smear for a 1.7 px one that way)."""
    from shipstar.extract import _smear
    from shipstar.extract._background import estimate_mesh

    xy = np.array([[300.3, 400.6], [620.4, 210.2], [700.7, 800.1]])
    smear = np.array([[1.0, 1.5], [6.0, 4.0], [6.0, 4.0]])
    col, row = np.rint(xy).astype(np.int64).T
    for seed in range(10):
        img = render_frame(A1, xy, np.array([60000.0, 300.0, 300.0]), np.random.default_rng(seed), smear_px=smear,
                           hot_pixel_fraction=0.0)
        mesh = estimate_mesh(img, quantum_adu=1.0)
        fitted, _, _, (n_ok, _) = _smear.calibrate(img, mesh, np.zeros(img.shape, dtype=bool), col, row,
                                                   np.array([1.3, 2.9]), A1.psf_sigma_px, 1.0 / A1.gain_e_per_adu,
                                                   fit_smear=True, min_snr=_smear._CALIBRATION_MIN_SNR)
        assert n_ok == 1, (seed, n_ok)
        assert np.hypot(*(fitted - smear[0])) < 0.15, (seed, fitted)


def test_smear_hints_short_hints_and_bad_hints():
    image, xy, signal, smear = smeared_grid_frame(0.0, seed=60)
    point = extract_stars(image, psf_sigma_px=A1.psf_sigma_px)
    short = extract_stars(image, psf_sigma_px=A1.psf_sigma_px, smear_px=(1.0, 0.5))     # < 1.5 px: point sources
    np.testing.assert_array_equal(short.xy_px, point.xy_px)
    assert np.all(short.smear_px == 0.0) and short.xy_cov_px2.shape == (len(short), 2, 2)
    for bad, text in [((1.0, 2.0, 3.0), "two"), ((np.nan, 1.0), "finite"), ("left", "two"), ((300.0, 0.0), "at most")]:
        with pytest.raises(ShipstarError, match=text) as info:
            extract_stars(image, smear_px=bad)
        assert "\n" not in str(info.value)


def test_a_trusted_smear_hint_is_used_as_it_is_and_measures_as_well(monkeypatch):
    """``smear_sigma_px`` at most ``TRUSTED_SMEAR_SIGMA_PX``: the common smear is not measured
    again from the streaks (``_smeared._refined_smear`` not called) and the centroids are as
    close to the truth as with the measurement (the true smear given: the hint is exact); a
    larger stated error, or none, measures it again; a bad one is a one-line error."""
    from shipstar.extract import _smeared
    from shipstar.extract._core import TRUSTED_SMEAR_SIGMA_PX

    calls = []
    refined = _smeared._refined_smear
    monkeypatch.setattr(_smeared, "_refined_smear", lambda *a, **k: calls.append(1) or refined(*a, **k))
    image, xy, signal, smear = smeared_grid_frame(2.0, seed=67)
    kwargs = dict(psf_sigma_px=A1.psf_sigma_px, gain_e_per_adu=A1.gain_e_per_adu, smear_px=np.median(smear, axis=0))
    stats = {}
    for sigma_px, n_calls in ((TRUSTED_SMEAR_SIGMA_PX, 0), (0.0, 0), (0.2, 1), (None, 1)):
        calls.clear()
        result = extract_stars(image, smear_sigma_px=sigma_px, **kwargs)
        assert len(calls) == n_calls, sigma_px
        stats[sigma_px] = smeared_statistics(result, xy, signal, smear)
    trusted, measured = stats[TRUSTED_SMEAR_SIGMA_PX], stats[None]
    assert trusted["complete"] >= 0.95 and trusted["false"] <= 2
    for name in ("along", "across"):
        assert abs(trusted[f"bias_{name}"]) < 4 * trusted[f"se_{name}"] + 0.005
        assert trusted[f"ratio_{name}"] <= 1.3                                   # near the Cramer-Rao bound
        assert trusted[f"ratio_{name}"] <= measured[f"ratio_{name}"] * 1.02 + 0.01, (name, trusted, measured)
    for bad in (-0.1, np.nan, np.inf):
        with pytest.raises(ShipstarError, match="smear_sigma_px") as info:
            extract_stars(image, smear_sigma_px=bad, **kwargs)
        assert "\n" not in str(info.value)


def test_the_result_reports_the_smear_the_stars_were_measured_with():
    """A hint 8 % long, without a stated error: the smear measured again from the streaks
    is reported (within 3 % of the truth), not the hint; a trusted hint is reported as given."""
    image, xy, signal, smear = smeared_grid_frame(2.0, seed=69)
    true = np.median(smear, axis=0)
    kwargs = dict(psf_sigma_px=A1.psf_sigma_px, gain_e_per_adu=A1.gain_e_per_adu, smear_px=1.08 * true)
    measured = extract_stars(image, **kwargs).smear_px
    measured = measured * np.sign(measured @ true)
    assert np.hypot(*(measured - true)) <= 0.03 * np.hypot(*true), (measured, true)
    np.testing.assert_array_equal(extract_stars(image, smear_sigma_px=0.0, **kwargs).smear_px, 1.08 * true)


@pytest.mark.parametrize("seed", [70, 71])
def test_a_short_trusted_smear_is_measured_as_streaks_closer_to_the_bound_than_as_points(seed):
    """A smear of 2.8 px known to 0.05 px (``smear_sigma_px``): the stars are found as points
    (as complete, no false detection more) and fitted with the PSF moved along the smear,
    whose Cramer-Rao bound they reach; the point path's Gaussian (the frame given as
    unsmeared) is 4-15 % over it along the smear (model error), and no nearer across."""
    image, xy, signal, smear = smeared_grid_frame(0.45, seed=seed)
    assert 2.5 < np.median(np.hypot(*smear.T)) < 3.0
    kwargs = dict(psf_sigma_px=A1.psf_sigma_px, gain_e_per_adu=A1.gain_e_per_adu)
    streaks = extract_stars(image, smear_px=np.median(smear, axis=0), smear_sigma_px=0.01, **kwargs)
    points = extract_stars(image, smear_px=(0.0, 0.0), **kwargs)
    np.testing.assert_array_equal(streaks.smear_px, np.median(smear, axis=0))
    st, sp = (smeared_statistics(r, xy, signal, smear) for r in (streaks, points))
    assert st["complete"] >= sp["complete"] and st["false"] <= sp["false"]
    assert st["ratio_along"] <= 0.95 * sp["ratio_along"] and st["ratio_along"] <= 1.1, (st, sp)
    assert st["ratio_across"] <= sp["ratio_across"] + 0.01 and st["ratio_across"] <= 1.1, (st, sp)
    for name in ("along", "across"):
        assert abs(st[f"bias_{name}"]) < 4 * st[f"se_{name}"] + 0.005
        assert st[f"predicted_{name}"] == pytest.approx(1.0, abs=0.15)          # xy_cov_px2 follows the bound


def test_smeared_frames_without_stars_hot_pixels_or_cosmic_rays_give_nothing():
    rng = np.random.default_rng(61)
    fo = FalseObjects(cosmic_ray_count=40, cosmic_ray_e=8000.0)
    image = render_frame(A1, np.zeros((0, 2)), [], rng, hot_pixel_fraction=2e-4, hot_pixel_e_per_s=3e4,
                         false_objects=fo)
    assert np.count_nonzero(image > A1.bias_adu + 20) > 200         # plenty of hot pixels and cosmic rays
    for smear in [(4.0, 3.0), (20.0, -15.0), (0.0, 37.0)]:
        result = extract_stars(image, psf_sigma_px=A1.psf_sigma_px, gain_e_per_adu=A1.gain_e_per_adu, smear_px=smear)
        assert len(result) == 0, f"{len(result)} false stars with smear {smear}"
        assert result.xy_px.shape == (0, 2) and np.all(result.smear_px == smear)


def test_hot_pixels_and_cosmic_rays_do_not_disturb_smeared_stars():
    from shipstar.simulate import smear_px_from_rate

    rng = np.random.default_rng(62)
    xy = rng.uniform(40, 984, size=(40, 2))
    signal = star_signal_e(A1, rng.uniform(4.0, 7.0, 40))
    smear = smear_px_from_rate(A1, A1.unproject(xy), SMEAR_AXIS * math.radians(2.0), A1.exposure_s)
    image = render_frame(A1, xy, signal, rng, smear_px=smear, hot_pixel_fraction=2e-4, hot_pixel_e_per_s=3e4,
                         false_objects=FalseObjects(cosmic_ray_count=30, cosmic_ray_e=8000.0))
    result = extract_stars(image)                              # the smear is estimated
    found = match_one_to_one(result.xy_px, xy, np.full(len(xy), 1.0))
    close = np.linalg.norm(xy[:, None] - xy[None], axis=2) + 1e9 * np.eye(len(xy))
    isolated = close.min(axis=1) > 30.0
    assert np.all(found[isolated] >= 0)
    assert len(result) - np.sum(found >= 0) <= 1


def test_short_trusted_smears_with_hot_pixels_cosmic_rays_saturation_edges_and_a_trail():
    """The short-smear path (points found, streaks fitted): hot pixels and cosmic rays are
    not stars and do not move them, a saturated star is flagged and fitted on its wings, a
    star on the edge is flagged, a satellite trail is one elongated object."""
    from shipstar.extract import FLAG_EDGE, FLAG_SATURATED

    rng = np.random.default_rng(64)
    smear = np.array([2.2, -1.1])
    xy = np.vstack([rng.uniform(40, 984, size=(40, 2)), [[0.8, 500.0]]])        # the last: its light off the edge
    signal = np.concatenate([star_signal_e(A1, rng.uniform(4.0, 7.0, 40)), [3e5]])
    signal[0] = 3e7                                                                    # saturated
    fo = FalseObjects(cosmic_ray_count=30, cosmic_ray_e=8000.0, trail_xy_px=[[[100.0, 900.0], [400.0, 760.0]]],
                      trail_signal_e=[2e6])
    image = render_frame(A1, xy, signal, rng, smear_px=smear, hot_pixel_fraction=2e-4, hot_pixel_e_per_s=3e4,
                         false_objects=fo)
    result = extract_stars(image, psf_sigma_px=A1.psf_sigma_px, gain_e_per_adu=A1.gain_e_per_adu, smear_px=smear,
                           smear_sigma_px=0.0)
    np.testing.assert_array_equal(result.smear_px, smear)
    found = match_one_to_one(result.xy_px, xy, np.full(len(xy), 0.5))
    close = np.linalg.norm(xy[:, None] - xy[None], axis=2) + 1e9 * np.eye(len(xy))
    on_trail = np.abs(xy[:, 1] - (900.0 - 140.0 * (xy[:, 0] - 100.0) / 300.0)) < 15.0
    isolated = (close.min(axis=1) > 30.0) & ~on_trail
    assert np.all(found[isolated] >= 0)
    assert result.flags[found[0]] & FLAG_SATURATED and np.linalg.norm(result.xy_px[found[0]] - xy[0]) < 0.1
    assert result.flags[found[-1]] & FLAG_EDGE
    clean = isolated & (np.arange(len(xy)) > 0) & (np.arange(len(xy)) < len(xy) - 1)
    assert np.all(result.flags[found[clean]] == 0)
    others = np.setdiff1d(np.arange(len(result)), found)
    trail = others[(result.flags[others] & FLAG_ELONGATED) != 0]
    assert len(trail) >= 1 and len(others) - len(trail) <= 1                      # at most one noise peak
    x, y = result.xy_px[trail].T
    assert np.all((x >= 90) & (x <= 410) & (np.abs(y - (900.0 - 140.0 * (x - 100.0) / 300.0)) < 8.0))


def test_smeared_frame_flags_saturated_edge_and_trails():
    smear = np.array([18.0, 10.0])
    xy = np.array([[300.0, 300.0], [3.0, 500.0], [700.0, 700.0], [520.0, 260.0]])
    signal = np.array([3e7, 3e5, 3e5, 3e5])
    fo = FalseObjects(trail_xy_px=[[[100.0, 900.0], [400.0, 760.0]]], trail_signal_e=[2e6])
    image = render_frame(A1, xy, signal, np.random.default_rng(63), smear_px=smear, hot_pixel_fraction=0.0,
                         false_objects=fo)
    result = extract_stars(image, psf_sigma_px=A1.psf_sigma_px, gain_e_per_adu=A1.gain_e_per_adu, smear_px=smear)
    found = match_one_to_one(result.xy_px, xy, np.full(len(xy), 0.5))
    assert np.all(found >= 0)
    flags = [flag_names(result.flags[f]) for f in found]
    assert "saturated" in flags[0] and flags[1] == ["edge"] and flags[2] == [] and flags[3] == []
    # the saturated streak is fitted on its unsaturated wings
    assert np.linalg.norm(result.xy_px[found[0]] - xy[0]) < 0.1
    assert np.all(np.abs(result.xy_px[found[2:]] - xy[2:]) < 0.05)
    # the satellite trail (a different direction) is one elongated object (plus, maybe, a noise peak)
    others = np.setdiff1d(np.arange(len(result)), found)
    trail = others[(result.flags[others] & FLAG_ELONGATED) != 0]
    assert len(trail) == 1 and len(others) <= 2 and np.all(result.snr[np.setdiff1d(others, trail)] < 6.0)
    x, y = result.xy_px[trail[0]]
    assert 100 <= x <= 400 and abs(y - (900.0 - 140.0 * (x - 100.0) / 300.0)) < 8.0      # on the trail


# -- the compiled kernels against SciPy (the code they replaced) ------------------------------

def test_compiled_mesh_median_filter_is_scipy_median_filter():
    """The mesh's 3 x 3 median (``_kernels.median3``, an exchange network of 19 steps) is
    ``scipy.ndimage.median_filter(size=3, mode="nearest")``: grids of every small size, with
    many ties (integer values) and without."""
    from scipy.ndimage import median_filter

    from shipstar.extract._kernels import median3

    rng = np.random.default_rng(55)
    for trial in range(400):
        shape = tuple(int(v) for v in rng.integers(1, 13, 2))
        grid = rng.normal(size=shape) if trial % 2 else rng.integers(0, 4, shape).astype(float)
        np.testing.assert_array_equal(median3(grid), median_filter(grid, size=3, mode="nearest"), err_msg=str(trial))


def test_compiled_median_absolute_deviation_is_the_two_medians():
    """The box-noise factor's robust spread (``_kernels.median_abs_deviation``) is
    ``median(|z - median(z)|)`` with ``_background.median`` (the middle value, or the mean of
    the two): exactly, for odd and even counts, with many ties and without, and one value."""
    from shipstar.extract._background import median
    from shipstar.extract._kernels import median_abs_deviation

    rng = np.random.default_rng(56)
    for trial in range(560):
        n = int(rng.integers(1, 200)) if trial < 500 else int(rng.integers(200, 6000))
        x = rng.normal(size=n) * 10.0 ** rng.uniform(-3, 3) if trial % 3 else rng.integers(0, 5, n).astype(float)
        assert median_abs_deviation(x) == median(np.abs(x - median(x))), trial
    with pytest.raises(ValueError):
        median_abs_deviation(np.zeros(0))


def test_compiled_box_mean_and_labels_match_scipy_ndimage():
    """``_kernels.box3`` is ``scipy.ndimage.uniform_filter(size=3, mode="nearest")`` to the bit,
    ``label_runs`` numbers components as ``scipy.ndimage.label`` does (4- and 8-connected)."""
    from scipy import ndimage

    from shipstar.extract._kernels import box3, label_runs

    rng = np.random.default_rng(16)
    for _ in range(60):
        h, w = (int(n) for n in rng.integers(1, 70, size=2))
        image = (rng.normal(100.0, 30.0, size=(h, w)) * rng.choice([1e-3, 1.0, 1e4])).astype(np.float32)
        np.testing.assert_array_equal(box3(image), ndimage.uniform_filter(image, 3, mode="nearest"))
        above = image > np.quantile(image, rng.uniform(0.3, 0.8))
        idx = np.flatnonzero(above)
        for diagonal, structure in ((False, None), (True, np.ones((3, 3), dtype=bool))):
            expected, n_expected = ndimage.label(above, structure=structure)
            labels, n = label_runs(idx, w, diagonal=diagonal)
            got = np.zeros(h * w, dtype=np.int64)
            got[idx] = labels + 1
            assert n == n_expected
            np.testing.assert_array_equal(got, expected.reshape(-1))


def test_compiled_detection_passes_match_numpy():
    """Candidates, local maxima and 3 x 3 neighbours of the C kernels against plain NumPy on
    every pixel type the extraction takes."""
    from shipstar.extract._kernels import candidates, local_max, neighbours

    rng = np.random.default_rng(17)
    # sparse frames too (most rows without a candidate, runs of them, a row's last pixels), and
    # block grids that stop short of the frame (their last row and column cover the rest)
    for h, w, block, grid, sparse in ((37, 1029, 64, "short", 0.002), (64, 203, 8, "short", 0.05),
                                      (45, 70, 16, "ceil", 0.0)):
        image = rng.integers(0, 100, size=(h, w)).astype(np.float32)
        if sparse:
            image = np.where(rng.random((h, w)) < sparse, 99.0, 30.0).astype(np.float32)
            image[5, w - 3:] = 99.0
            image[h - 1, :9] = 99.0
        shape = (max(1, h // block), max(1, w // block)) if grid == "short" else (-(-h // block), -(-w // block))
        level = rng.integers(40, 60, size=shape).astype(np.float32)
        rows = np.minimum(np.arange(h) // block, level.shape[0] - 1)
        cols = np.minimum(np.arange(w) // block, level.shape[1] - 1)
        idx = np.flatnonzero(image > level[rows][:, cols])
        assert sparse == 0.0 or 0 < idx.size < h * w // 10
        np.testing.assert_array_equal(candidates(image, level, block), idx)
    for dtype in (np.uint8, np.int8, np.uint16, np.int16, np.uint32, np.int32, np.int64, np.float32, np.float64):
        h, w, block = 45, 70, 16
        image = rng.integers(0, 100, size=(h, w)).astype(dtype)
        level = rng.integers(40, 60, size=(-(-h // block), -(-w // block))).astype(dtype)
        rows = np.minimum(np.arange(h) // block, level.shape[0] - 1)
        cols = np.minimum(np.arange(w) // block, level.shape[1] - 1)
        idx = np.flatnonzero(image > level[rows][:, cols])
        np.testing.assert_array_equal(candidates(image, level, block), idx)
        padded = np.pad(image.astype(float), 1, constant_values=-np.inf)
        r, c = np.divmod(idx, w)
        is_max = np.ones(len(idx), dtype=bool)
        values = np.empty((len(idx), 8))
        for k, (dr, dc) in enumerate(((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))):
            nb = padded[r + 1 + dr, c + 1 + dc]
            is_max &= (image.reshape(-1)[idx] > nb) if (dr, dc) < (0, 0) else (image.reshape(-1)[idx] >= nb)
            values[:, k] = np.where(np.isfinite(nb), nb, image.reshape(-1)[idx])
        np.testing.assert_array_equal(local_max(image, idx), is_max)
        got_values, inside = neighbours(image, idx)
        np.testing.assert_array_equal(got_values, values)
        np.testing.assert_array_equal(inside, np.isfinite(values) & np.isfinite(
            np.stack([padded[r + 1 + dr, c + 1 + dc] for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)],
                     axis=1)))


def test_compiled_mesh_sums_and_value_step_are_the_numpy_reference_bit_for_bit():
    """The background mesh's box-noise sums (3 x 3 around a strided grid) and the samples'
    quantisation step, compiled, against the NumPy code they replaced (kept as the
    reference): the same float64 values on every pixel type, sizes not a multiple of the
    step, float frames whose sums depend on the order of the additions."""
    from shipstar.extract._background import _box_sums_python, _value_step_python
    from shipstar.extract._kernels import grid_box_sums, value_step

    rng = np.random.default_rng(29)
    for dtype in (np.uint8, np.int8, np.uint16, np.int16, np.uint32, np.int32, np.int64, np.float32, np.float64):
        for shape, step in (((64, 64), 3), ((1024, 1024), 16), ((37, 91), 5), ((200, 120), 7)):
            if np.issubdtype(dtype, np.floating):
                image = (rng.normal(0.0, 1.0, shape) * 10.0 ** rng.uniform(-3, 6, shape)).astype(dtype)
            else:
                info = np.iinfo(dtype)
                image = rng.integers(max(info.min, -2 ** 40), min(info.max, 2 ** 40), size=shape).astype(dtype)
            n_rows, n_cols = np.arange(1, shape[0] - 1, step).size, np.arange(1, shape[1] - 1, step).size
            got = grid_box_sums(image, step, n_rows, n_cols)
            np.testing.assert_array_equal(got, _box_sums_python(image, step, n_rows, n_cols),
                                          err_msg=f"{dtype} {shape} {step}")
    for samples in (np.sort(rng.normal(0, 1, (32, 32, 64)), axis=-1),
                    np.sort(np.round(rng.normal(0, 3, (8, 8, 16))) / 4096.0, axis=-1),
                    np.full((4, 4, 9), 7.0), np.zeros((3, 3, 1)), np.sort(rng.integers(0, 3, (5, 64)), axis=-1)):
        assert value_step(samples) == _value_step_python(samples)
    assert value_step(np.full((2, 5), 1.0)) == 0.0


def test_compiled_cholesky_substitutions_are_the_numpy_reference_bit_for_bit():
    """The Cholesky solve's two substitutions (``_fit._cho_solve``), compiled, against the
    NumPy code they replaced (kept as the reference): the same float64 values for stacks of
    every size the fits use (k = 2-7, one or many right-hand sides), LAPACK's factors and the
    floored ones of singular matrices, badly scaled and non-finite entries; and the solve
    itself against ``np.linalg.solve``."""
    from shipstar.extract._fit import _cho_solve, _cho_solve_python, _cholesky, spd_solve

    rng = np.random.default_rng(41)
    for k in range(2, 8):
        for m in (1, 3, k):
            n = 50
            g = rng.normal(size=(n, k, k + 3)) * 10.0 ** rng.uniform(-4, 6, (n, k, 1))
            a = g @ g.transpose(0, 2, 1)
            b = rng.normal(size=(n, k, m)) * 10.0 ** rng.uniform(-3, 3, (n, 1, 1))
            for low in (np.linalg.cholesky(a), _cholesky(a), _cholesky(np.zeros_like(a))):
                np.testing.assert_array_equal(_cho_solve(low, b), _cho_solve_python(low, b))
            bad = b.copy()
            bad[3, 0, 0], bad[7, -1, -1] = np.nan, np.inf
            with np.errstate(invalid="ignore"):                   # (inf - inf in the reference)
                expected = _cho_solve_python(low, bad)
            np.testing.assert_array_equal(_cho_solve(low, bad), expected)
            well = rng.normal(size=(n, k, k + 3))
            well = well @ well.transpose(0, 2, 1) + np.eye(k)
            np.testing.assert_allclose(spd_solve(well, b), np.linalg.solve(well, b), rtol=1e-9, atol=1e-12)
    assert _cho_solve(np.zeros((0, 4, 4)), np.zeros((0, 4, 4))).shape == (0, 4, 4)


def test_compiled_whitened_grid_sums_are_the_mesh_on_grid_values():
    """The box-noise factor's whitened sums (``_kernels.grid_box_z``) against
    ``(total - 9 bg) / (3 noise)`` with ``Mesh.on_grid``'s bilinear values: equal to rounding
    (on_grid's matrix products may fuse a multiply-add), on grids of one block per axis too."""
    from shipstar.extract._background import Mesh
    from shipstar.extract._kernels import grid_box_z

    rng = np.random.default_rng(43)
    for (ny, nx), block, step, shape in (((32, 32), 32, 16, (1024, 1024)), ((3, 5), 16, 3, (48, 80)),
                                         ((1, 4), 8, 2, (8, 32)), ((4, 1), 8, 2, (32, 8)), ((1, 1), 8, 3, (8, 8))):
        mesh = Mesh(bg=rng.uniform(90, 110, (ny, nx)), noise=rng.uniform(2, 4, (ny, nx)), block_px=block,
                    shape_hw=shape)
        rows, cols = np.arange(1, shape[0] - 1, step), np.arange(1, shape[1] - 1, step)
        total = rng.uniform(800, 1000, (rows.size, cols.size))
        bg, noise = mesh.on_grid(cols, rows)
        np.testing.assert_allclose(grid_box_z(total, mesh.bg, mesh.noise, block, step),
                                   (total - 9.0 * bg) / (3.0 * noise), rtol=1e-13, atol=1e-12)


def test_compiled_streak_start_parameters_are_the_numpy_reference_bit_for_bit():
    """The streak fits' start parameters (``_streak.start_parameters``), compiled, against the
    NumPy code they replaced (kept as the reference): the same float64 values -- the window
    sums in NumPy's pairwise order -- for random windows of every size the fits use (up to
    40 x 40: sums past NumPy's 128-element blocks), masked pixels, a common smear, one per
    star or none, and one PSF sigma or one per star."""
    from shipstar.extract._streak import StreakWindows, _start_parameters_python, start_parameters

    rng = np.random.default_rng(45)
    for trial in range(120):
        n = int(rng.integers(0, 30))
        wy, wx = (int(v) for v in rng.integers(3, 41, 2))
        values = rng.normal(100, 10, (n, wy, wx)) + rng.uniform(0, 1e4, (n, 1, 1)) * (rng.random((n, wy, wx)) < 0.2)
        col, row = rng.integers(0, 1000, n), rng.integers(0, 1000, n)
        win = StreakWindows(values=values, valid=rng.random((n, wy, wx)) > 0.1, x0=(col - wx // 2).astype(float),
                            y0=(row - wy // 2).astype(float), noise=rng.uniform(1, 5, n), bg=rng.uniform(90, 110, n))
        smear = (np.zeros(2), rng.normal(0, 10, 2), rng.normal(0, 10, (n, 2)))[trial % 3]
        sigma = rng.uniform(0.6, 2.0) if trial % 2 or n == 0 else rng.uniform(0.6, 2.0, n)
        np.testing.assert_array_equal(start_parameters(win, col, row, sigma, smear),
                                      _start_parameters_python(win, col, row, sigma, smear), err_msg=str(trial))


def test_compiled_streak_footprints_are_the_numpy_reference():
    """The streak fits' footprints (pixel counts, peaks, saturated or off the image), compiled,
    against the NumPy code they replaced (kept as the reference): windows of every size
    reaching over each edge of the image, saturated pixels or none, masked pixels, flat and
    NaN models, NaN pixel values, no star at all."""
    from shipstar.extract._kernels import streak_footprint
    from shipstar.extract._smeared import _FOOTPRINT_FRACTION, _footprint_python

    rng = np.random.default_rng(46)
    for trial in range(150):
        n = int(rng.integers(0, 25))
        wy, wx = (int(v) for v in rng.integers(1, 31, 2))
        h, w = (int(v) for v in rng.integers(8, 80, 2))
        col, row = rng.integers(-wx, w + wx, n), rng.integers(-wy, h + wy, n)
        model = rng.normal(100, 5, (n, wy * wx)) + rng.uniform(0, 1e3, (n, 1)) * (rng.random((n, wy * wx)) < 0.3)
        bg = rng.uniform(95, 105, n)
        values = rng.normal(100, 10, (n, wy, wx))
        valid = rng.random((n, wy, wx)) > 0.15
        if n and trial % 5 == 0:
            model[0] = bg[0] + 7.0                                  # a flat model: every pixel its own top
        if n > 1 and trial % 7 == 0:
            model[1, rng.integers(wy * wx)] = np.nan                # no footprint at all
        if n > 2 and trial % 4 == 0:
            values[2].flat[rng.integers(wy * wx)] = np.nan           # a NaN peak if it is in the footprint
        saturated = None if trial % 3 == 0 else rng.random((h, w)) < 0.1
        got = streak_footprint(model, bg, values, valid, col, row, (h, w), _FOOTPRINT_FRACTION, saturated)
        want = _footprint_python(model, bg, values, valid, col, row, (h, w), _FOOTPRINT_FRACTION, saturated)
        for g, e in zip(got, want):
            assert g.shape == e.shape, trial
            np.testing.assert_array_equal(g, e, err_msg=str(trial))


def test_compiled_window_gathers_are_the_numpy_reference():
    """The fits' windows (``_streak.gather_streak_windows``, ``_fit.gather_windows``), compiled,
    against the NumPy code they replaced (kept as the reference): the same float64 values and
    validity for every pixel type, windows over the frame's edges and corners, with and
    without a mask of bad pixels, and none at all."""
    from dataclasses import fields

    from shipstar.extract._fit import _gather_windows_python, gather_windows
    from shipstar.extract._streak import _gather_streak_windows_python, gather_streak_windows

    rng = np.random.default_rng(48)
    for dtype in (np.uint8, np.int8, np.uint16, np.int16, np.uint32, np.int32, np.int64, np.float32, np.float64):
        h, w = 37, 53
        if np.issubdtype(dtype, np.floating):
            image = rng.normal(0.0, 1e3, (h, w)).astype(dtype)
        else:
            info = np.iinfo(dtype)
            image = rng.integers(max(info.min, -2 ** 60), min(info.max, 2 ** 60), (h, w), endpoint=True).astype(dtype)
        for n in (0, 1, 25):
            col, row = rng.integers(-3, w + 3, n), rng.integers(-3, h + 3, n)
            bg, noise = rng.normal(size=n), rng.uniform(1, 2, n)
            for bad in (None, rng.random((h, w)) < 0.2):
                for hx, hy in ((0, 0), (3, 5), (9, 2)):
                    a = gather_streak_windows(image, col, row, hx, hy, bg, noise, bad)
                    b = _gather_streak_windows_python(image, col, row, hx, hy, bg, noise, bad)
                    for f in fields(a):
                        np.testing.assert_array_equal(getattr(a, f.name), getattr(b, f.name), err_msg=str(dtype))
            a, b = gather_windows(image, col, row, 4, bg, noise), _gather_windows_python(image, col, row, 4, bg, noise)
            for f in fields(a):
                np.testing.assert_array_equal(getattr(a, f.name), getattr(b, f.name), err_msg=f"{dtype} {f.name}")


def test_compiled_box_sums_are_the_numpy_reference_bit_for_bit():
    """The detection's 3 x 3 box sums around peaks (``_detect.box_sums``), compiled, against
    the NumPy code they replaced (kept as the reference): the same float64 sums (NumPy's
    pairwise order over the 8 neighbours; float frames of wildly different magnitudes) and
    counts, for every pixel type, peaks on the edges and in the corners."""
    from shipstar.extract._detect import _box_sums_python, box_sums

    rng = np.random.default_rng(50)
    for dtype in (np.uint8, np.int8, np.uint16, np.int16, np.uint32, np.int32, np.int64, np.float32, np.float64):
        shape = (41, 59)
        if np.issubdtype(dtype, np.floating):
            image = (rng.normal(0.0, 1.0, shape) * 10.0 ** rng.uniform(-6, 6, shape)).astype(dtype)
        else:
            info = np.iinfo(dtype)
            image = rng.integers(max(info.min, -2 ** 40), min(info.max, 2 ** 40), shape).astype(dtype)
        peaks = np.concatenate([rng.integers(0, image.size, 500), [0, shape[1] - 1, image.size - 1,
                                                                    image.size - shape[1]]])
        flat = image.reshape(-1)
        for got, want in zip(box_sums(flat, peaks, shape), _box_sums_python(flat, peaks, shape)):
            np.testing.assert_array_equal(got, want, err_msg=str(dtype))


def test_compiled_point_start_values_are_the_numpy_reference_bit_for_bit():
    """The point fits' start values (``_fit.start_values``), compiled, against the NumPy code
    they replaced (kept as the reference): the same float64 values for windows of every size
    the fits use, values and backgrounds over 6 decades, masked pixels, no window."""
    from shipstar.extract._fit import Windows, _start_values_python, start_values

    rng = np.random.default_rng(51)
    for trial in range(150):
        n, size = int(rng.integers(0, 30)), int(rng.choice([3, 5, 7, 9, 13, 17]))
        values = rng.normal(100.0, 5.0, (n, size, size)) * 10.0 ** rng.uniform(-3, 3, (n, 1, 1))
        values[:, size // 2, size // 2] += rng.uniform(0, 1e4, n)
        win = Windows(values=values, valid=rng.random((n, size, size)) > 0.1,
                      x0=rng.integers(-5, 900, n).astype(float), y0=rng.integers(-5, 900, n).astype(float),
                      noise=rng.uniform(1, 3, n), bg=rng.uniform(90, 110, n) * 10.0 ** rng.uniform(-3, 3, n))
        sigma = float(rng.uniform(0.5, 2.0))
        np.testing.assert_array_equal(start_values(win, sigma), _start_values_python(win, sigma), err_msg=str(trial))


def test_compiled_sharpness_test_is_the_numpy_reference():
    """The hot-pixel and cosmic-ray test (``_point.too_sharp``), compiled, against the NumPy code
    it replaced (kept as the reference): the same answer for single hot pixels, stars (3 x 3
    blobs), noise peaks, peaks on the frame's edges and corners, saturated peaks (never sharp),
    with and without shot noise, on integer and float frames."""
    from shipstar.extract._background import estimate_mesh
    from shipstar.extract._point import _too_sharp_python, too_sharp

    rng = np.random.default_rng(52)
    for trial in range(80):
        dtype = (np.uint16, np.float32, np.float64, np.int32)[trial % 4]
        image = rng.normal(100.0, 5.0, (60, 80))
        hot = rng.integers(0, image.size, 60)
        image.reshape(-1)[hot] += rng.uniform(0, 3000, 60)
        for q in hot[:20]:                                            # a third of them stars
            r, c = divmod(int(q), 80)
            image[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2] += rng.uniform(0, 800)
        image = image.astype(dtype) if np.dtype(dtype).kind == "f" else np.round(image).astype(dtype)
        mesh = estimate_mesh(image, quantum_adu=0.0 if np.dtype(dtype).kind == "f" else 1.0)
        peaks = np.concatenate([hot, rng.integers(0, image.size, 40), [0, 79, image.size - 1, image.size - 80]])
        saturated = rng.random(len(peaks)) < 0.1
        sigma, inv_gain = float(rng.uniform(0.6, 1.6)), float(rng.choice([0.0, 0.3]))
        np.testing.assert_array_equal(too_sharp(image, mesh, peaks, sigma, inv_gain, saturated),
                                      _too_sharp_python(image, mesh, peaks, sigma, inv_gain, saturated),
                                      err_msg=str(trial))


def test_compiled_component_statistics_are_the_numpy_reference_bit_for_bit():
    """The detected objects' statistics (``_point.component_stats``: pixel count, peak, flags,
    thresholded centre of gravity and moments), compiled, against the NumPy code they replaced
    (kept as the reference): the same values, bit for bit, on integer and float frames with
    stars on the edges, elongated blobs and saturated pixels."""
    from shipstar.extract._background import estimate_mesh
    from shipstar.extract._point import _component_stats_python, component_stats, detect_objects

    rng = np.random.default_rng(53)
    for trial in range(12):
        image = rng.normal(100.0, 4.0, (90, 120))
        for _ in range(40):
            r, c = int(rng.integers(-2, 92)), int(rng.integers(-2, 122))
            long = int(rng.integers(1, 6))
            image[max(r - 1, 0):r + 2, max(c - long, 0):c + long + 1] += rng.uniform(20, 3000)
        if trial % 2:
            image = np.round(np.minimum(image, 2000.0)).astype(np.uint16)
        mesh = estimate_mesh(image, quantum_adu=1.0 if trial % 2 else 0.0)
        peaks, star_labels, idx, labels = detect_objects(image, mesh, 5.0)
        for saturation in (np.inf, 2000.0):
            got = component_stats(image, mesh, idx, labels, star_labels, saturation)
            want = _component_stats_python(image, mesh, idx, labels, star_labels, saturation)
            assert set(got) == set(want)
            for key in want:
                np.testing.assert_array_equal(got[key], want[key], err_msg=f"{trial} {key}")


def test_saturation_test_in_the_pixels_own_type_is_the_float_comparison():
    """``at_or_above`` compares integer frames against ceil(level) in their own type (no
    float64 copy of the frame): the same mask as ``image >= level`` for every integer
    type, levels between, on and beyond the pixel values and the type's range."""
    from shipstar.extract._detect import at_or_above

    rng = np.random.default_rng(31)
    for dtype in (np.uint8, np.int8, np.uint16, np.int16, np.uint32, np.int32, np.int64, np.float32, np.float64):
        info = np.iinfo(dtype) if np.dtype(dtype).kind in "ui" else np.finfo(dtype)
        lo, hi = (float(info.min), float(info.max)) if np.dtype(dtype).kind in "ui" else (-1e6, 1e6)
        image = rng.uniform(max(lo, -1e6), min(hi, 1e6), (40, 30)).astype(dtype)
        image.flat[:4] = [image.dtype.type(info.min), image.dtype.type(info.max), 0, 1]
        for level in (lo - 1.0, lo, -0.5, 0.0, 0.25, 1.0, 254.5, 255.0, 4095.0, 65535.0, 65535.5, hi, hi + 1.0,
                      float(image.flat[7]), float(image.flat[7]) + 0.5):
            np.testing.assert_array_equal(at_or_above(image, level), image >= level, err_msg=f"{dtype} {level}")


def test_block_statistics_are_numpys_median_and_mad():
    """``_kernels.block_stats`` (the background mesh's blocks): the median and the median
    absolute deviation are ``np.median``'s to the bit (the MAD's two middle deviations found
    by bisecting the merge of the deviations below and above the median), and the RMS of
    the deviations within ``3 max(1.4826 MAD, quantum)`` is their sum in sample order; on
    quantised samples with many ties, even and odd block sizes, one sample, constant
    blocks and skewed ones."""
    from shipstar.extract._kernels import block_stats

    rng = np.random.default_rng(61)
    for trial in range(400):
        k = int(rng.integers(1, 100))
        kind = trial % 4
        if kind == 0:
            s = np.round(rng.normal(100.0, rng.uniform(0.3, 5.0), (8, k)))
        elif kind == 1:
            s = rng.normal(0.0, 1.0, (8, k))
        elif kind == 2:
            s = rng.choice([1.0, 2.0, 2.0, 3.0, 10.0], (8, k))
        else:
            s = rng.exponential(5.0, (8, k)) * rng.choice([1.0, -1.0, 1.0], (8, k))
        s[0] = 7.0                                               # a constant block
        s = np.sort(s, axis=-1)
        quantum = float(rng.choice([0.0, 0.5, 1.0]))
        med, mad, rms = block_stats(s, quantum)
        for b, v in enumerate(s):
            m = np.median(v)
            d = v - m
            a = np.median(np.abs(d))
            clip = 3.0 * max(1.4826 * a, quantum)
            total, count = 0.0, 0
            for x in d:
                if abs(x) <= clip:
                    total += x * x
                    count += 1
            assert med[b] == m and mad[b] == a, (trial, b)
            assert rms[b] == math.sqrt(total / max(count, 1)), (trial, b)
