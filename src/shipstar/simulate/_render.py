"""Image formation: star signals to a noisy 12-bit frame with known truth.

The chain, per pixel, in electrons (e):

1. stars: a Gaussian point-spread function (a slightly defocused star) integrated
   *exactly* over each pixel's area with ``erf`` (no point sampling), rendered only in
   a small window around each star; linear motion smear integrates the PSF along the
   path; satellite trails are long smears, planets bright point sources;
2. sky background and dark current (plus a fixed pattern of hot pixels);
3. shot noise (Poisson) on the total, then cosmic-ray hits (1-3 pixel spikes);
4. saturation at the full well (no blooming);
5. read noise (Gaussian), then the ADC: ``adu = round(e / gain + bias)`` clipped to
   ``0 .. 2**adc_bits - 1``.

Pixel coordinates follow ``docs/conventions.md``: ``xy_px`` is (x right, y down) with the
centre of the top-left pixel at (0, 0); pixel (i, j) = ``image[j, i]`` covers
x in [i - 0.5, i + 0.5).

Photon budget: :func:`star_signal_e` uses the camera's own
(``Camera.star_e_per_s``, zero point and assumptions in ``docs/camera.md``), so that
the simulator, the error model and the camera files share one number.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from shipstar.errors import ShipstarError

__all__ = [
    "FalseObjects",
    "star_signal_e",
    "pixel_fractions",
    "render_image_e",
    "render_frame",
]

#: Half-width of a star's render window in PSF sigmas (flux outside: < 1e-6 per axis).
_WINDOW_SIGMAS = 5.0
#: Spacing of the points that sample a smear path, in PSF sigmas.
_SMEAR_STEP_SIGMAS = 0.25
#: Points rendered per chunk (bounds the memory of the window stack).
_CHUNK_POINTS = 4096

_DETECTOR_FIELDS = (
    "width_px", "height_px", "psf_sigma_px", "exposure_s", "read_noise_e", "dark_e_per_s",
    "full_well_e", "gain_e_per_adu", "bias_adu", "adc_bits", "sky_e_per_px_per_s",
)


@dataclass(frozen=True)
class _Detector:
    """What image formation needs from a camera (the fields of ``shipstar.camera.Camera``).

    Attributes
    ----------
    width_px, height_px : int
        Image size.
    psf_sigma_px : float
        Sigma of the Gaussian PSF (defocused star), pixels.
    exposure_s : float
        Exposure time.
    read_noise_e : float
        Read noise, electrons RMS.
    dark_e_per_s : float
        Mean dark current per pixel.
    full_well_e : float
        Saturation level of a pixel, electrons.
    gain_e_per_adu : float
        Electrons per ADC unit.
    bias_adu : float
        Offset added by the ADC.
    adc_bits : int
        ADC depth (12 for the seeds' sensors); the output clips to ``0 .. 2**adc_bits - 1``.
    sky_e_per_px_per_s : float
        Sky background rate per pixel.
    """

    width_px: int
    height_px: int
    psf_sigma_px: float
    exposure_s: float
    read_noise_e: float
    dark_e_per_s: float
    full_well_e: float
    gain_e_per_adu: float
    bias_adu: float
    adc_bits: int
    sky_e_per_px_per_s: float

    def __post_init__(self):
        for name in _DETECTOR_FIELDS:
            value = getattr(self, name)
            if not isinstance(value, (int, float, np.integer, np.floating)) or not math.isfinite(value):
                raise ShipstarError(f"detector field {name} must be a finite number, got {value!r}")
        if int(self.width_px) != self.width_px or int(self.height_px) != self.height_px:
            raise ShipstarError("detector width_px and height_px must be integers")
        if self.width_px < 1 or self.height_px < 1:
            raise ShipstarError(f"detector size must be positive, got {self.width_px}x{self.height_px} px")
        for name in ("psf_sigma_px", "exposure_s", "full_well_e", "gain_e_per_adu"):
            if getattr(self, name) <= 0:
                raise ShipstarError(f"detector field {name} must be > 0, got {getattr(self, name)}")
        for name in ("read_noise_e", "dark_e_per_s", "bias_adu", "sky_e_per_px_per_s"):
            if getattr(self, name) < 0:
                raise ShipstarError(f"detector field {name} must be >= 0, got {getattr(self, name)}")
        if int(self.adc_bits) != self.adc_bits or not 1 <= self.adc_bits <= 16:
            raise ShipstarError(f"detector adc_bits must be an integer in 1..16, got {self.adc_bits}")

    @classmethod
    def from_camera(cls, camera) -> "_Detector":
        """The detector part of a ``shipstar.camera.Camera`` (or any object with these fields)."""
        missing = [n for n in _DETECTOR_FIELDS if not hasattr(camera, n)]
        if missing:
            raise ShipstarError(f"camera has no field(s) {', '.join(missing)} needed to render a frame")
        return cls(**{n: getattr(camera, n) for n in _DETECTOR_FIELDS})

    @property
    def adc_max_adu(self) -> int:
        """Largest ADC output value, ``2**adc_bits - 1``."""
        return (1 << int(self.adc_bits)) - 1


@dataclass(frozen=True)
class FalseObjects:
    """Things in a frame that are not catalogue stars.

    Attributes
    ----------
    planet_xy_px : (P, 2) array
        Planets (very bright point sources, rendered with the star PSF).
    planet_signal_e : (P,) array
        Their signals, electrons per exposure.
    trail_xy_px : (T, 2, 2) array
        Satellite trails: start and end point of each line segment.
    trail_signal_e : (T,) array
        Total electrons along each trail.
    cosmic_ray_count : int
        Number of cosmic-ray hits (random positions, 1-3 adjacent pixels each).
    cosmic_ray_e : float
        Median charge one hit deposits (log-normal spread, sigma 0.5 in ln).
    """

    planet_xy_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    planet_signal_e: np.ndarray = field(default_factory=lambda: np.zeros(0))
    trail_xy_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    trail_signal_e: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cosmic_ray_count: int = 0
    cosmic_ray_e: float = 3000.0

    def __post_init__(self):
        pxy = _as_xy(self.planet_xy_px, "planet_xy_px")
        psig = _as_signal(self.planet_signal_e, len(pxy), "planet_signal_e")
        txy = np.asarray(self.trail_xy_px, dtype=float)
        if txy.ndim != 3 or txy.shape[1:] != (2, 2) or not np.all(np.isfinite(txy)):
            raise ShipstarError(f"trail_xy_px must be a finite (T, 2, 2) array, got shape {txy.shape}")
        tsig = _as_signal(self.trail_signal_e, len(txy), "trail_signal_e")
        if int(self.cosmic_ray_count) != self.cosmic_ray_count or self.cosmic_ray_count < 0:
            raise ShipstarError(f"cosmic_ray_count must be a non-negative integer, got {self.cosmic_ray_count}")
        if not (math.isfinite(self.cosmic_ray_e) and self.cosmic_ray_e >= 0):
            raise ShipstarError(f"cosmic_ray_e must be finite and >= 0, got {self.cosmic_ray_e}")
        for name, value in (("planet_xy_px", pxy), ("planet_signal_e", psig),
                            ("trail_xy_px", txy), ("trail_signal_e", tsig)):
            object.__setattr__(self, name, value)


def _as_xy(xy_px, name="xy_px") -> np.ndarray:
    xy = np.asarray(xy_px, dtype=float)
    if xy.ndim == 1 and xy.size == 0:
        xy = xy.reshape(0, 2)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ShipstarError(f"{name} must have shape (N, 2), got {xy.shape}")
    if not np.all(np.isfinite(xy)):
        raise ShipstarError(f"{name} has non-finite positions")
    return xy


def _as_signal(signal_e, n, name="signal_e") -> np.ndarray:
    sig = np.broadcast_to(np.asarray(signal_e, dtype=float), (n,)) if np.ndim(signal_e) == 0 \
        else np.asarray(signal_e, dtype=float)
    if sig.shape != (n,):
        raise ShipstarError(f"{name} must have shape ({n},), got {sig.shape}")
    if not np.all(np.isfinite(sig)) or np.any(sig < 0):
        raise ShipstarError(f"{name} must be finite and >= 0")
    return np.array(sig, dtype=float)


def star_signal_e(camera, mag) -> np.ndarray:
    """Electrons a star of magnitude ``mag`` (N,) delivers in one exposure of ``camera``.

    ``camera.star_e_per_s(mag) * camera.exposure_s``: the camera's photon budget
    (aperture, transmission, QE and the magnitude-0 photon flux of ``docs/camera.md``).
    """
    if not (hasattr(camera, "star_e_per_s") and hasattr(camera, "exposure_s")):
        raise ShipstarError("camera has no photon budget (star_e_per_s, exposure_s); use a shipstar.camera.Camera")
    m = np.asarray(mag, dtype=float)
    if not np.all(np.isfinite(m)):
        raise ShipstarError("magnitudes must be finite")
    return np.asarray(camera.star_e_per_s(m), dtype=float) * float(camera.exposure_s)


def pixel_fractions(centre_px, first_px, size, sigma_px) -> np.ndarray:
    """Fraction of a 1-D Gaussian's integral falling on each of ``size`` consecutive pixels.

    Parameters
    ----------
    centre_px : (P,) array
        Gaussian centres.
    first_px : (P,) int array
        Index of the first pixel of each window (pixel k covers [k - 0.5, k + 0.5)).
    size : int
        Pixels per window.
    sigma_px : float
        Gaussian sigma.

    Returns
    -------
    (P, size) array: ``0.5 * (erf((k + 0.5 - c) / (sqrt(2) s)) - erf((k - 0.5 - c) / (sqrt(2) s)))``.
    """
    from scipy.special import erf

    edges = (np.asarray(first_px, dtype=float)[:, None] - 0.5 + np.arange(size + 1)
             - np.asarray(centre_px, dtype=float)[:, None])
    cdf = erf(edges * (1.0 / (math.sqrt(2.0) * sigma_px)))
    return 0.5 * np.diff(cdf, axis=1)


def _smear_points(xy, signal, smear_px, sigma_px):
    """Replace each star by points sampling its smear path (midpoint rule, equal weights)."""
    if smear_px is None:
        return xy, signal
    smear = np.asarray(smear_px, dtype=float)
    if smear.shape == (2,):
        smear = np.broadcast_to(smear, xy.shape)
    if smear.shape != xy.shape or not np.all(np.isfinite(smear)):
        raise ShipstarError(f"smear_px must be a finite (2,) or ({len(xy)}, 2) array, got shape {smear.shape}")
    length = np.hypot(smear[:, 0], smear[:, 1])
    n_sub = np.maximum(1, np.ceil(length / (_SMEAR_STEP_SIGMAS * sigma_px)).astype(int))
    star = np.repeat(np.arange(len(xy)), n_sub)
    start = np.concatenate(([0], np.cumsum(n_sub)[:-1]))
    k = np.arange(len(star)) - np.repeat(start, n_sub)
    t = (k + 0.5) / n_sub[star] - 0.5                      # in (-1/2, 1/2), symmetric
    points = xy[star] + t[:, None] * smear[star]
    return points, signal[star] / n_sub[star]


def _accumulate(flat_out, shape_hw, xy, signal, sigma_px):
    """Add pixel-integrated Gaussians at ``xy`` (P, 2) with ``signal`` (P,) into ``flat_out``."""
    height, width = shape_hw
    half = int(math.ceil(_WINDOW_SIGMAS * sigma_px)) + 1
    size = 2 * half + 1
    offsets = np.arange(size)
    for lo in range(0, len(xy), _CHUNK_POINTS):
        pts, sig = xy[lo:lo + _CHUNK_POINTS], signal[lo:lo + _CHUNK_POINTS]
        x_first = np.rint(pts[:, 0]).astype(np.int64) - half
        y_first = np.rint(pts[:, 1]).astype(np.int64) - half
        fx = pixel_fractions(pts[:, 0], x_first, size, sigma_px)
        fy = pixel_fractions(pts[:, 1], y_first, size, sigma_px) * sig[:, None]
        cols = x_first[:, None] + offsets
        rows = y_first[:, None] + offsets
        patch = fy[:, :, None] * fx[:, None, :]
        inside = ((rows >= 0) & (rows < height))[:, :, None] & ((cols >= 0) & (cols < width))[:, None, :]
        flat = rows[:, :, None] * width + cols[:, None, :]
        np.add.at(flat_out, flat[inside], patch[inside])


def render_image_e(shape_hw, xy_px, signal_e, psf_sigma_px, background_e_per_px=0.0, *,
                   smear_px=None) -> np.ndarray:
    """Noiseless expected electrons per pixel: stars (pixel-integrated Gaussian PSF) plus background.

    Parameters
    ----------
    shape_hw : (int, int)
        Image height and width, pixels.
    xy_px : (N, 2) array
        True star positions (at mid-exposure when smeared).
    signal_e : (N,) array or scalar
        Electrons each star delivers in the exposure (before any loss off the image edge).
    psf_sigma_px : float
        Gaussian PSF sigma.
    background_e_per_px : float or (H, W) array
        Expected background (sky + dark) per pixel.
    smear_px : (2,) or (N, 2) array, optional
        Image motion (dx, dy) during the exposure; each star moves uniformly from
        ``xy - smear/2`` to ``xy + smear/2`` and the PSF is integrated along the path
        (points every 0.25 sigma, so the smeared centroid is the path midpoint).

    Returns
    -------
    (H, W) float64 array of expected electrons.
    """
    height, width = _shape(shape_hw)
    xy = _as_xy(xy_px)
    signal = _as_signal(signal_e, len(xy))
    sigma = float(psf_sigma_px)
    if not (math.isfinite(sigma) and 0.05 <= sigma <= 100.0):
        raise ShipstarError(f"psf_sigma_px must be within [0.05, 100] px, got {psf_sigma_px}")
    points, weights = _smear_points(xy, signal, smear_px, sigma)
    flat = np.zeros(height * width)
    _accumulate(flat, (height, width), points, weights, sigma)
    image = flat.reshape(height, width)
    bg = np.asarray(background_e_per_px, dtype=float)
    if bg.shape not in ((), (height, width)) or not np.all(np.isfinite(bg)) or np.any(bg < 0):
        raise ShipstarError("background_e_per_px must be a finite, non-negative scalar or (H, W) array")
    image += bg
    return image


def _shape(shape_hw):
    try:
        height, width = (int(v) for v in shape_hw)
    except (TypeError, ValueError):
        raise ShipstarError(f"shape_hw must be (height, width), got {shape_hw!r}") from None
    if height < 1 or width < 1 or height * width > 1 << 28:
        raise ShipstarError(f"image shape {height}x{width} px is out of range")
    return height, width


def _hot_pixel_rate(det, fraction, rate_e_per_s, seed):
    """Fixed-pattern hot pixels (same ``seed`` = same pixels frame after frame): flat idx, e/s."""
    if not (0.0 <= fraction <= 0.1):
        raise ShipstarError(f"hot_pixel_fraction must be in [0, 0.1], got {fraction}")
    if not (math.isfinite(rate_e_per_s) and rate_e_per_s >= 0):
        raise ShipstarError(f"hot_pixel_e_per_s must be finite and >= 0, got {rate_e_per_s}")
    n_pix = det.width_px * det.height_px
    count = int(round(fraction * n_pix))
    pattern = np.random.default_rng(seed)
    idx = pattern.choice(n_pix, size=count, replace=False) if count else np.zeros(0, dtype=np.int64)
    return idx, rate_e_per_s * pattern.lognormal(0.0, 1.0, size=count)


def _add_cosmic_rays(electrons_flat, shape_hw, false_objects, rng):
    """Deposit cosmic-ray charge (after shot noise): 1-3 pixels in a row, random direction."""
    n = int(false_objects.cosmic_ray_count)
    if n == 0:
        return
    height, width = shape_hw
    length = rng.integers(1, 4, size=n)
    direction = np.array([(1, 0), (0, 1), (1, 1), (1, -1)])[rng.integers(0, 4, size=n)]
    x0 = rng.integers(0, width, size=n)
    y0 = rng.integers(0, height, size=n)
    charge = false_objects.cosmic_ray_e * rng.lognormal(0.0, 0.5, size=n)
    for step in range(3):
        on = step < length
        x = x0 + step * direction[:, 0]
        y = y0 + step * direction[:, 1]
        on &= (x >= 0) & (x < width) & (y >= 0) & (y < height)
        np.add.at(electrons_flat, y[on] * width + x[on], charge[on] / length[on])


def _scene_sources(xy_px, signal_e, smear_px, fo):
    """Stars, planets and trails as one list of (possibly smeared) sources."""
    xy = _as_xy(xy_px)
    signal = _as_signal(signal_e, len(xy))
    if smear_px is None and not len(fo.trail_xy_px):
        return np.concatenate([xy, fo.planet_xy_px]), np.concatenate([signal, fo.planet_signal_e]), None
    star_smear = np.zeros_like(xy) if smear_px is None else np.asarray(smear_px, dtype=float)
    if star_smear.shape == (2,):
        star_smear = np.broadcast_to(star_smear, xy.shape)
    if star_smear.shape != xy.shape:
        raise ShipstarError(f"smear_px must be a (2,) or ({len(xy)}, 2) array, got shape {star_smear.shape}")
    trail_mid = fo.trail_xy_px.mean(axis=1)
    trail_vec = fo.trail_xy_px[:, 1] - fo.trail_xy_px[:, 0]
    all_xy = np.concatenate([xy, fo.planet_xy_px, trail_mid])
    all_signal = np.concatenate([signal, fo.planet_signal_e, fo.trail_signal_e])
    all_smear = np.concatenate([star_smear, np.zeros_like(fo.planet_xy_px), trail_vec])
    return all_xy, all_signal, all_smear


def render_frame(camera, xy_px, signal_e, rng, *, smear_px=None, hot_pixel_fraction=2e-5,
                 hot_pixel_e_per_s=2000.0, hot_pixel_seed=0, false_objects=None) -> np.ndarray:
    """A realistic raw frame: stars, sky, dark, hot pixels, noise, saturation and the ADC.

    Parameters
    ----------
    camera : shipstar.camera.Camera
        Supplies size, PSF sigma, exposure, sky, dark, noise, full well, gain, bias and
        ADC depth.
    xy_px : (N, 2) array
        True star positions (mid-exposure).
    signal_e : (N,) array
        Star signals, electrons per exposure (see :func:`star_signal_e`).
    rng : numpy.random.Generator
        Source of all random noise (same seed, same frame).
    smear_px : (2,) or (N, 2) array, optional
        Linear image motion during the exposure (see :func:`render_image_e`).
    hot_pixel_fraction : float
        Fraction of pixels with a high dark current.
    hot_pixel_e_per_s : float
        Median dark current of a hot pixel (log-normal, sigma 1 in ln).
    hot_pixel_seed : int
        Seed of the hot-pixel pattern, fixed per sensor (not drawn from ``rng``).
    false_objects : FalseObjects, optional
        Planets, satellite trails and cosmic rays.

    Returns
    -------
    (H, W) uint16 array of ADU in ``0 .. 2**adc_bits - 1``.
    """
    det = _Detector.from_camera(camera)
    if not isinstance(rng, np.random.Generator):
        raise ShipstarError("rng must be a numpy.random.Generator (np.random.default_rng(seed))")
    shape = (int(det.height_px), int(det.width_px))
    fo = FalseObjects() if false_objects is None else false_objects
    if not isinstance(fo, FalseObjects):
        raise ShipstarError("false_objects must be a FalseObjects")
    xy, signal, smear = _scene_sources(xy_px, signal_e, smear_px, fo)
    background = (det.sky_e_per_px_per_s + det.dark_e_per_s) * det.exposure_s
    mean_e = render_image_e(shape, xy, signal, det.psf_sigma_px, background, smear_px=smear)
    hot_idx, hot_rate = _hot_pixel_rate(det, hot_pixel_fraction, hot_pixel_e_per_s, hot_pixel_seed)
    mean_flat = mean_e.reshape(-1)
    mean_flat[hot_idx] += hot_rate * det.exposure_s
    electrons = rng.poisson(mean_e).astype(np.float64).reshape(-1)
    _add_cosmic_rays(electrons, shape, fo, rng)
    np.minimum(electrons, det.full_well_e, out=electrons)
    electrons += det.read_noise_e * rng.standard_normal(electrons.size)
    adu = np.rint(electrons / det.gain_e_per_adu + det.bias_adu)
    np.clip(adu, 0, det.adc_max_adu, out=adu)
    return adu.astype(np.uint16).reshape(shape)
