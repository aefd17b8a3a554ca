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

Noise is exact and fast: the pixels with only sky and dark current are drawn from their
exact ADU distribution (steps 2-5) by a table look-up (:func:`_background_table`), the
few touched by a star or false object through the chain pixel by pixel.

Photon budget: :func:`star_signal_e` uses the camera's own
(``Camera.star_e_per_s``, zero point and assumptions in ``docs/camera.md``), so that
the simulator, the error model and the camera files share one number.
"""

from __future__ import annotations

import functools
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
#: Path points per window of a smeared source (a chunk spans <= 256 x 0.25 sigma = 64 sigma).
_PATH_CHUNK_POINTS = 256
#: Cells of the guide table of the background sampler (one 16-bit draw per pixel).
_GUIDE_CELLS = 1 << 16
#: Largest (electron values x ADU values) table the exact background sampler builds.
_MAX_TABLE_TERMS = 4_000_000

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


def _smear_steps(xy, smear_px, sigma_px):
    """Validated per-source smear vectors (N, 2) and numbers of path points (N,)."""
    if smear_px is None:
        return np.zeros_like(xy), np.ones(len(xy), dtype=np.int64)
    smear = np.asarray(smear_px, dtype=float)
    if smear.shape == (2,):
        smear = np.broadcast_to(smear, xy.shape)
    if smear.shape != xy.shape or not np.all(np.isfinite(smear)):
        raise ShipstarError(f"smear_px must be a finite (2,) or ({len(xy)}, 2) array, got shape {smear.shape}")
    length = np.hypot(smear[:, 0], smear[:, 1])
    n_sub = np.maximum(1, np.ceil(length / (_SMEAR_STEP_SIGMAS * sigma_px)).astype(np.int64))
    return np.array(smear), n_sub


def _window_entries(first_x, first_y, patch, shape_hw):
    """Flat pixel indices and values of windows ``patch`` (C, Wy, Wx) at (first_x, first_y), on-image only."""
    height, width = shape_hw
    rows = first_y[:, None] + np.arange(patch.shape[1])
    cols = first_x[:, None] + np.arange(patch.shape[2])
    inside = ((rows >= 0) & (rows < height))[:, :, None] & ((cols >= 0) & (cols < width))[:, None, :]
    inside &= patch > 0.0                    # corners of a chunk window that no point reaches
    flat = rows[:, :, None] * width + cols[:, None, :]
    return flat[inside], patch[inside]


def _point_entries(xy, signal, sigma_px, shape_hw):
    """Pixel-integrated Gaussians at ``xy`` (P, 2): (flat indices, electrons) of their windows."""
    half = int(math.ceil(_WINDOW_SIGMAS * sigma_px)) + 1
    size = 2 * half + 1
    x_first = np.rint(xy[:, 0]).astype(np.int64) - half
    y_first = np.rint(xy[:, 1]).astype(np.int64) - half
    fx = pixel_fractions(xy[:, 0], x_first, size, sigma_px)
    fy = pixel_fractions(xy[:, 1], y_first, size, sigma_px) * signal[:, None]
    return _window_entries(x_first, y_first, fy[:, :, None] * fx[:, None, :], shape_hw)


def _path_entries(xy, signal, smear, n_sub, sigma_px, shape_hw):
    """Smeared sources: (flat indices, electrons) of the windows of their path chunks.

    Each source's path is sampled at ``n_sub`` points (midpoint rule, equal weights,
    centred on ``xy``); consecutive points are grouped in chunks of at most
    ``_PATH_CHUNK_POINTS``, and each chunk's window is the product sum
    ``sum_p fy_p fx_p^T = Fy^T Fx`` of the points' separable pixel fractions (one
    batched matrix product instead of one window per point).
    """
    half = int(math.ceil(_WINDOW_SIGMAS * sigma_px)) + 1
    per = int(min(_PATH_CHUNK_POINTS, n_sub.max()))
    n_chunks = -(-n_sub // per)
    src = np.repeat(np.arange(len(xy)), n_chunks)
    k = np.arange(len(src)) - np.repeat(np.cumsum(n_chunks) - n_chunks, n_chunks)
    p = k[:, None] * per + np.arange(per)                            # (C, per) point numbers
    valid = p < n_sub[src][:, None]
    p = np.where(valid, p, k[:, None] * per)                         # padding repeats the chunk's first point
    t = (p + 0.5) / n_sub[src][:, None] - 0.5
    pts = xy[src][:, None, :] + t[:, :, None] * smear[src][:, None, :]
    weight = np.where(valid, (signal / n_sub)[src][:, None], 0.0)
    first = np.rint(pts.min(axis=1)).astype(np.int64) - half          # (C, 2) chunk window corner
    size = (np.rint(pts.max(axis=1)).astype(np.int64) - first).max(axis=0) + half + 1
    fx = _chunk_fractions(pts[:, :, 0], first[:, 0], int(size[0]), half, sigma_px)
    fy = _chunk_fractions(pts[:, :, 1], first[:, 1], int(size[1]), half, sigma_px) * weight[:, :, None]
    return _window_entries(first[:, 0], first[:, 1], fy.transpose(0, 2, 1) @ fx, shape_hw)


def _chunk_fractions(centre, chunk_first, size, half, sigma_px):
    """Pixel fractions (C, per, size) of points ``centre`` (C, per) in chunk windows starting at ``chunk_first``.

    Only each point's own 2 half + 1 pixels are computed (the rest of the chunk window
    is zero), then placed at their offset in the chunk window.
    """
    n_chunks, per = centre.shape
    own = np.rint(centre).astype(np.int64) - half
    local = pixel_fractions(centre.ravel(), own.ravel(), 2 * half + 1, sigma_px)
    out = np.zeros((n_chunks * per, size))
    cols = (own - chunk_first[:, None]).reshape(-1, 1) + np.arange(2 * half + 1)
    out[np.arange(n_chunks * per)[:, None], cols] = local
    return out.reshape(n_chunks, per, size)


def _source_entries(shape_hw, xy, signal, smear, n_sub, sigma_px):
    """All sources' expected electrons as sparse (flat index, value) entries; indices may repeat."""
    point = n_sub == 1
    parts = [_point_entries(xy[point], signal[point], sigma_px, shape_hw)]
    if not np.all(point):
        smeared = ~point
        parts.append(_path_entries(xy[smeared], signal[smeared], smear[smeared], n_sub[smeared],
                                   sigma_px, shape_hw))
    return np.concatenate([f for f, _ in parts]), np.concatenate([v for _, v in parts])


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
    sigma = _check_sigma(psf_sigma_px)
    bg = np.asarray(background_e_per_px, dtype=float)
    if bg.shape not in ((), (height, width)) or not np.all(np.isfinite(bg)) or np.any(bg < 0):
        raise ShipstarError("background_e_per_px must be a finite, non-negative scalar or (H, W) array")
    smear, n_sub = _smear_steps(xy, smear_px, sigma)
    flat, value = _source_entries((height, width), xy, signal, smear, n_sub, sigma)
    image = np.bincount(flat, weights=value, minlength=height * width).astype(float).reshape(height, width)
    image += bg
    return image


def _check_sigma(psf_sigma_px) -> float:
    sigma = float(psf_sigma_px)
    if not (math.isfinite(sigma) and 0.05 <= sigma <= 100.0):
        raise ShipstarError(f"psf_sigma_px must be within [0.05, 100] px, got {psf_sigma_px}")
    return sigma


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
    idx, rate = _hot_pattern(int(det.width_px * det.height_px), float(fraction), int(seed))
    return idx, rate_e_per_s * rate


@functools.lru_cache(maxsize=8)
def _hot_pattern(n_pix, fraction, seed):
    """Hot pixels (sorted flat indices) and their relative rates (log-normal, median 1), cached."""
    count = int(round(fraction * n_pix))
    pattern = np.random.default_rng(seed)
    idx = pattern.choice(n_pix, size=count, replace=False) if count else np.zeros(0, dtype=np.int64)
    rate = pattern.lognormal(0.0, 1.0, size=count)
    for arr in (idx, rate):
        arr.setflags(write=False)
    return idx, rate


def _cosmic_ray_entries(shape_hw, false_objects, rng):
    """Cosmic-ray charge (added after shot noise): 1-3 pixels in a row, random direction.

    Returns flat pixel indices and electrons (indices may repeat).
    """
    n = int(false_objects.cosmic_ray_count)
    if n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    height, width = shape_hw
    length = rng.integers(1, 4, size=n)
    direction = np.array([(1, 0), (0, 1), (1, 1), (1, -1)])[rng.integers(0, 4, size=n)]
    x0 = rng.integers(0, width, size=n)
    y0 = rng.integers(0, height, size=n)
    charge = false_objects.cosmic_ray_e * rng.lognormal(0.0, 0.5, size=n)
    step = np.arange(3)
    x = x0[:, None] + step * direction[:, 0:1]
    y = y0[:, None] + step * direction[:, 1:2]
    on = (step < length[:, None]) & (x >= 0) & (x < width) & (y >= 0) & (y < height)
    share = np.broadcast_to((charge / length)[:, None], on.shape)
    return (y * width + x)[on], share[on]


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


# ---------------------------------------------------------------- exact fast noise

def _electron_distribution(mean_e, full_well_e):
    """Values and probabilities of ``min(Poisson(mean_e), full_well_e)`` (mass outside < 1e-40)."""
    from scipy.special import gammaln, pdtrc

    if mean_e == 0.0:
        return np.zeros(1), np.ones(1)
    spread = math.sqrt(mean_e)
    k = np.arange(max(0, math.floor(mean_e - 14.0 * spread - 10.0)), math.ceil(mean_e + 16.0 * spread + 40.0))
    pmf = np.exp(k * math.log(mean_e) - mean_e - gammaln(k + 1.0))
    pmf /= pmf.sum()                        # rounding of the exponent (1e-9 relative at 1e6 e); tails < 1e-40
    below = k < full_well_e
    if below.all():
        return k.astype(float), pmf
    top = float(pdtrc(math.ceil(full_well_e) - 1, mean_e))          # P(X >= full well)
    return np.append(k[below].astype(float), full_well_e), np.append(pmf[below], top)


@functools.lru_cache(maxsize=16)
def _background_table(mean_e, read_noise_e, gain_e_per_adu, bias_adu, full_well_e, adc_max_adu):
    """Guide table of the ADU distribution of a pixel with only background light, or None.

    The pixel's ADU is ``clip(rint((min(X, full_well) + R) / gain + bias), 0, adc_max)``
    with ``X ~ Poisson(mean_e)`` and ``R ~ N(0, read_noise^2)``; its CDF is, exactly,
    ``F(a) = sum_e P(e) Phi((gain (a + 1/2 - bias) - e) / read_noise)`` for ``a < adc_max``.
    Returns ``(first_adu, cdf, lookup, ambiguous)``: the ADU values ``first_adu + j``
    have CDF ``cdf[j]``; a draw ``u`` in cell ``c = floor(u * _GUIDE_CELLS)`` has ADU
    ``lookup[c]`` unless the cell holds a step of the CDF (``ambiguous[c]``). None when
    the table would exceed ``_MAX_TABLE_TERMS`` (very bright backgrounds).
    """
    from scipy.special import ndtr

    e_val, e_prob = _electron_distribution(mean_e, full_well_e)
    if read_noise_e > 0.0:
        reach = 14.0 * read_noise_e
        lo = int(min(max(math.floor((e_val[0] - reach) / gain_e_per_adu + bias_adu), 0), adc_max_adu))
        hi = int(min(max(math.ceil((e_val[-1] + reach) / gain_e_per_adu + bias_adu), 0), adc_max_adu))
        adu = np.arange(lo, hi + 1)
        if adu.size * e_val.size > _MAX_TABLE_TERMS:
            return None
        edge_e = gain_e_per_adu * (adu[:-1] + 0.5 - bias_adu)
        cdf = ndtr((edge_e[:, None] - e_val[None, :]) / read_noise_e) @ e_prob
    else:
        adu_of_e = np.clip(np.rint(e_val / gain_e_per_adu + bias_adu), 0, adc_max_adu).astype(np.int64)
        lo, hi = int(adu_of_e.min()), int(adu_of_e.max())
        cdf = np.cumsum(np.bincount(adu_of_e - lo, weights=e_prob, minlength=hi - lo + 1))[:-1]
    cdf = np.append(np.minimum(np.maximum.accumulate(cdf), 1.0), 1.0)
    cells = np.arange(_GUIDE_CELLS + 1) / _GUIDE_CELLS
    first = np.searchsorted(cdf, cells[:-1], side="right")           # ADU index at the cell's start
    last = np.searchsorted(cdf, cells[1:], side="left")              # ... and just before its end
    lookup = (lo + first).astype(np.uint16)
    ambiguous = first != last
    for arr in (cdf, lookup, ambiguous):
        arr.setflags(write=False)
    return lo, cdf, lookup, ambiguous


def _sample_background(table, n, rng):
    """``n`` independent ADU draws (uint16) from a :func:`_background_table` distribution.

    One uniform 16-bit cell per pixel and a table look-up; the few draws in cells that
    straddle a CDF step get a fresh uniform position inside their cell and a binary
    search. Conditional on its cell, a uniform variate is uniform within the cell, so
    this is the inverse-CDF method at double precision, i.e. exact.
    """
    lo, cdf, lookup, ambiguous = table
    cells = rng.integers(0, _GUIDE_CELLS, size=n, dtype=np.uint16)
    out = lookup[cells]
    redo = np.flatnonzero(ambiguous[cells])
    if redo.size:
        u = (cells[redo] + rng.random(redo.size)) / _GUIDE_CELLS
        out[redo] = lo + np.searchsorted(cdf, u, side="right")
    return out


def _electrons_to_adu(electrons, det, rng):
    """Full well, read noise and ADC on electron counts (float array, modified in place)."""
    np.minimum(electrons, det.full_well_e, out=electrons)
    electrons += det.read_noise_e * rng.standard_normal(electrons.size)
    adu = np.rint(electrons / det.gain_e_per_adu + det.bias_adu)
    np.clip(adu, 0, det.adc_max_adu, out=adu)
    return adu.astype(np.uint16)


def _noisy_pixels(det, background_e, pixels, entries, hot, rays, rng):
    """ADU of ``pixels`` (sorted unique flat indices) through the whole noise chain.

    ``entries``, ``hot`` and ``rays`` are (flat index, electrons) pairs: expected star
    electrons (indices may repeat), hot-pixel dark charge (expected) and cosmic-ray
    charge (deposited after shot noise). Each pixel's expected charges are summed and
    drawn as one Poisson variable.
    """
    (star_idx, star_e), (hot_idx, hot_e), (ray_idx, ray_e) = entries, hot, rays
    mean = background_e + np.bincount(np.searchsorted(pixels, star_idx), weights=star_e, minlength=pixels.size)
    mean[np.searchsorted(pixels, hot_idx)] += hot_e
    electrons = rng.poisson(mean).astype(float)
    electrons += np.bincount(np.searchsorted(pixels, ray_idx), weights=ray_e, minlength=pixels.size)
    return _electrons_to_adu(electrons, det, rng)


def render_frame(camera, xy_px, signal_e, rng, *, smear_px=None, hot_pixel_fraction=2e-5,
                 hot_pixel_e_per_s=2000.0, hot_pixel_seed=0, false_objects=None) -> np.ndarray:
    """A realistic raw frame: stars, sky, dark, hot pixels, noise, saturation and the ADC.

    Exact and fast: the pixels that hold only sky and dark current (nearly all) are drawn
    in one pass from their exact ADU distribution (Poisson shot noise, full well, read
    noise, ADC; :func:`_background_table`); the pixels touched by a star, planet, trail,
    hot pixel or cosmic ray go through the noise chain one by one (Poisson of the total
    expected charge, cosmic-ray charge, full well, Gaussian read noise, ADC).

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
    n_pix = shape[0] * shape[1]
    fo = FalseObjects() if false_objects is None else false_objects
    if not isinstance(fo, FalseObjects):
        raise ShipstarError("false_objects must be a FalseObjects")
    xy, signal, smear = _scene_sources(xy_px, signal_e, smear_px, fo)
    sigma = _check_sigma(det.psf_sigma_px)
    smear, n_sub = _smear_steps(xy, smear, sigma)
    entries = _source_entries(shape, xy, signal, smear, n_sub, sigma)
    hot_idx, hot_rate = _hot_pixel_rate(det, hot_pixel_fraction, hot_pixel_e_per_s, hot_pixel_seed)
    hot = (hot_idx, hot_rate * det.exposure_s)
    background = (det.sky_e_per_px_per_s + det.dark_e_per_s) * det.exposure_s
    table = _background_table(float(background), float(det.read_noise_e), float(det.gain_e_per_adu),
                              float(det.bias_adu), float(det.full_well_e), det.adc_max_adu)
    if table is None:                                                # too bright for a table: every pixel
        frame, pixels = np.empty(n_pix, dtype=np.uint16), np.arange(n_pix)
    else:
        frame = _sample_background(table, n_pix, rng)
        touched = np.zeros(n_pix, dtype=bool)
        touched[entries[0]] = True
        touched[hot_idx] = True
        pixels = None
    rays = _cosmic_ray_entries(shape, fo, rng)
    if pixels is None:
        touched[rays[0]] = True
        pixels = np.flatnonzero(touched)
    frame[pixels] = _noisy_pixels(det, background, pixels, entries, hot, rays, rng)
    return frame.reshape(shape)
