"""Sub-pixel centroids: a pixel-integrated Gaussian fitted by Gauss-Newton, vectorised over stars.

Model of the pixels of a fixed square window around each star (pixel (i, j) covers
[i - 0.5, i + 0.5) x [j - 0.5, j + 0.5)):

    mu_ij = b + F * E(i; x, s) * E(j; y, s),
    E(k; c, s) = Phi((k + 0.5 - c) / s) - Phi((k - 0.5 - c) / s)

(Phi the standard normal CDF): the exact integral of a Gaussian PSF over each pixel, the
same model the renderer draws. Unknowns per star: x, y, F (flux, ADU), b (local
background); the PSF sigma s is either known or fitted (5 unknowns) on the brightest
stars and then shared. Each iteration solves the weighted normal equations of all
stars at once (one batched 4x4 or 5x5 solve). The weights are 1 / variance with
``variance = noise**2 + (mu - b) / gain``: with the gain known this is the
Poisson-plus-read-noise likelihood's Fisher weighting, so the estimate reaches the
Cramer-Rao bound; without it the weights are uniform (exact for faint stars).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from shipstar.extract import _kernels
from shipstar.extract._background import median
from shipstar.extract._kernels import erf

__all__ = [
    "Windows", "gather_windows", "fit_gaussian", "window_half_px", "estimate_psf_sigma",
    "start_values", "covariance", "estimate_inv_gain", "inv_gain_from_residuals", "neighbour_ratios",
]

_SQRT2 = math.sqrt(2.0)
_SQRT2PI = math.sqrt(2.0 * math.pi)
_MAX_ITERATIONS = 8
_CONVERGED_PX = 2e-4        # a star's iterations stop when its centre moves less than this ...
_CONVERGED_CHI2 = 2.5e-3    # ... or the step lowers chi^2 by less than this: |step| < 5 % of the errors
_MAX_SHIFT_PX = 1.5          # fitted centre may move this far from the window centre pixel
_SIGMA_RANGE_PX = (0.25, 20.0)


@dataclass(frozen=True)
class Windows:
    """Pixel windows around stars: ``values``/``valid`` (N, S, S); pixel (0, 0) at (x0, y0)."""

    values: np.ndarray
    valid: np.ndarray
    x0: np.ndarray
    y0: np.ndarray
    noise: np.ndarray
    bg: np.ndarray

    @property
    def size(self) -> int:
        return self.values.shape[1]

    def take(self, index) -> "Windows":
        """The windows of the stars ``index``."""
        return Windows(values=self.values[index], valid=self.valid[index], x0=self.x0[index],
                       y0=self.y0[index], noise=self.noise[index], bg=self.bg[index])


def window_half_px(sigma_px: float) -> int:
    """Half-size of the fit window: 3 sigma, at least 2 px (7x7 for sigma = 1 px)."""
    return int(min(12, max(2, math.ceil(3.0 * sigma_px))))


def gather_windows(image, col, row, half, bg, noise) -> Windows:
    """Copy (2 half + 1)^2 windows centred on integer pixels (col, row); off-image pixels invalid
    (compiled, ``_kernels.gather``: :func:`_gather_windows_python`'s windows)."""
    values, valid = _kernels.gather(image, col, row, int(half), int(half))
    col, row = np.asarray(col), np.asarray(row)
    return Windows(values=values, valid=valid, x0=(col - half).astype(float), y0=(row - half).astype(float),
                   noise=np.asarray(noise, dtype=float), bg=np.asarray(bg, dtype=float))


def _gather_windows_python(image, col, row, half, bg, noise) -> Windows:
    """:func:`gather_windows` in NumPy (the compiled kernel's reference)."""
    height, width = image.shape
    offsets = np.arange(-half, half + 1)
    rows = row[:, None] + offsets
    cols = col[:, None] + offsets
    valid = ((rows >= 0) & (rows < height))[:, :, None] & ((cols >= 0) & (cols < width))[:, None, :]
    values = image[np.clip(rows, 0, height - 1)[:, :, None], np.clip(cols, 0, width - 1)[:, None, :]]
    return Windows(values=values.astype(float), valid=valid, x0=(col - half).astype(float),
                   y0=(row - half).astype(float), noise=np.asarray(noise, dtype=float),
                   bg=np.asarray(bg, dtype=float))


def _profile(centre, first, size, sigma):
    """Pixel fractions E and their derivatives in the centre and in sigma, each (M, size)."""
    s = sigma[:, None]
    u = first[:, None] - 0.5 + np.arange(size + 1) - centre[:, None]
    z = u / s
    cdf = 0.5 * erf(z * (1.0 / _SQRT2))
    pdf = np.exp(-0.5 * z * z) / (_SQRT2PI * s)
    upd = z * pdf
    frac = cdf[:, 1:] - cdf[:, :-1]
    d_centre = pdf[:, :-1] - pdf[:, 1:]
    d_sigma = upd[:, :-1] - upd[:, 1:]
    return frac, d_centre, d_sigma


def _jacobian(p, win, fit_sigma):
    """Model (N, P) and transposed Jacobian (N, k, P) on the flattened windows."""
    n, size = len(p), win.size
    e, de, ds = _profile(np.concatenate([p[:, 0], p[:, 1]]), np.concatenate([win.x0, win.y0]),
                         size, np.concatenate([p[:, 4], p[:, 4]]))
    ex, ey, dex, dey = e[:n, None, :], e[n:, :, None], de[:n, None, :], de[n:, :, None]
    flux = p[:, 2][:, None, None]
    shape = ey * ex
    jac_t = np.empty((n, 5 if fit_sigma else 4, size * size))
    jac_t[:, 0] = (flux * ey * dex).reshape(n, size * size)
    jac_t[:, 1] = (flux * dey * ex).reshape(n, size * size)
    jac_t[:, 2] = shape.reshape(n, size * size)
    jac_t[:, 3] = 1.0
    if fit_sigma:
        jac_t[:, 4] = (flux * (ds[n:, :, None] * ex + ey * ds[:n, None, :])).reshape(n, size * size)
    model = p[:, 3][:, None] + flux[:, :, 0] * jac_t[:, 2]
    return model, jac_t


def _cholesky(a):
    """Lower Cholesky factors of a stack (N, k, k) of positive semi-definite matrices.

    Vectorised over N (a LAPACK call per 4x4 matrix costs more than the arithmetic);
    pivots are floored at 1e-12 of the diagonal, so a singular matrix gives a huge,
    finite variance instead of an exception.
    """
    k = a.shape[1]
    low = np.zeros_like(a)
    for j in range(k):
        row = low[:, j:j + 1, :j]                                    # (N, 1, j)
        d = a[:, j, j] - (row @ row.transpose(0, 2, 1))[:, 0, 0]
        ljj = np.sqrt(np.maximum(d, 1e-12 * np.abs(a[:, j, j]) + 1e-300))
        low[:, j, j] = ljj
        if j + 1 < k:
            low[:, j + 1:, j] = (a[:, j + 1:, j] - (low[:, j + 1:, :j] @ row.transpose(0, 2, 1))[:, :, 0]) \
                / ljj[:, None]
    return low


def _cho_solve(low, b):
    """Solve (L L^T) x = b for a stack: ``low`` (N, k, k), ``b`` (N, k, m) -> (N, k, m)
    (compiled: :func:`_cho_solve_python`'s values to the bit, without its ~4 k NumPy calls)."""
    return _kernels.cho_solve(low, b)


def _cho_solve_python(low, b):
    """:func:`_cho_solve` in NumPy (the compiled kernel's reference)."""
    k = low.shape[1]
    diag = np.diagonal(low, axis1=1, axis2=2)[:, :, None]                 # (N, k, 1)
    y = np.array(b, dtype=float)
    for i in range(k):                                                   # forward: L y = b
        y[:, i] /= diag[:, i]
        if i + 1 < k:
            y[:, i + 1:] -= low[:, i + 1:, i, None] * y[:, i, None]
    for i in reversed(range(k)):                                         # back: L^T x = y
        y[:, i] /= diag[:, i]
        if i:
            y[:, :i] -= low[:, i, :i, None] * y[:, i, None]
    return y


def spd_solve(a, b):
    """Solve a x = b for stacks of symmetric positive (semi-)definite a (N, k, k), b (N, k, m).

    LAPACK's Cholesky (``np.linalg.cholesky``, a few us for the whole stack) when every
    matrix is positive definite, else :func:`_cholesky` with floored pivots (a singular
    matrix gives a huge, finite variance instead of an exception); then the vectorised
    substitutions. (``np.linalg.solve`` would be as fast single-threaded, but OpenBLAS
    threads make it 10 x slower on a busy machine.)
    """
    low = None
    if len(a) and np.all(np.isfinite(a)):
        try:
            low = np.linalg.cholesky(a)
        except np.linalg.LinAlgError:
            low = None
    return _cho_solve(_cholesky(a) if low is None else low, b)


def _spd_solve(a, g):
    """Solve a x = g for stacks a (N, k, k), g (N, k)."""
    return spd_solve(a, g[:, :, None])[:, :, 0]


def _spd_inverse(a):
    """Inverse of a stack of symmetric positive (semi-)definite matrices (N, k, k)."""
    eye = np.broadcast_to(np.eye(a.shape[1]), a.shape).copy()
    return spd_solve(a, eye)


def fit_gaussian(win, p0, *, fit_sigma=False, inv_gain=0.0, tol_px=_CONVERGED_PX, tol_chi2=_CONVERGED_CHI2):
    """Gauss-Newton fit of the pixel-integrated Gaussian, star by star (compiled: :mod:`._kernels`).

    Parameters
    ----------
    win : Windows
    p0 : (N, 5) array
        Start values (x, y, F, b, sigma) in image pixel coordinates and ADU.
    fit_sigma : bool
        Fit sigma too (5 unknowns) or keep it at ``p0[:, 4]``.
    inv_gain : float
        1 / gain (ADU per electron); 0 gives uniform weights.
    tol_px, tol_chi2 : float
        A star's iterations stop when its centre moves less than ``tol_px`` or the step
        lowers its chi^2 by less than ``tol_chi2`` (the step's squared length in units of
        the parameters' errors: 2.5e-3 is 5 %).

    Returns
    -------
    p : (N, 5) array
        Fitted parameters (their covariance: :func:`covariance`).
    ok : (N,) bool
        Converged to a finite, plausible solution.
    """
    p, step_norm = _kernels.gauss_fit(win, p0, fit_sigma=fit_sigma, inv_gain=inv_gain, tol_px=tol_px,
                                      tol_chi2=tol_chi2, max_iterations=_MAX_ITERATIONS)
    centre = np.stack([win.x0, win.y0], axis=1) + (win.size - 1) / 2.0
    ok = (np.all(np.isfinite(p), axis=1) & (step_norm < 1e-2)
          & np.all(np.abs(p[:, :2] - centre) <= _MAX_SHIFT_PX, axis=1)
          & (p[:, 4] > _SIGMA_RANGE_PX[0]) & (p[:, 4] < _SIGMA_RANGE_PX[1]))
    return p, ok


def start_values(win, sigma_px):
    """Background-subtracted centre of gravity of the central 3x3 and window flux: (N, 5)
    (compiled, ``_kernels.point_start``: :func:`_start_values_python`'s values to the bit)."""
    return _kernels.point_start(win, sigma_px)


def _start_values_python(win, sigma_px):
    """:func:`start_values` in NumPy (the compiled kernel's reference)."""
    half = win.size // 2
    excess = np.where(win.valid, win.values - win.bg[:, None, None], 0.0)
    core = np.maximum(excess[:, half - 1:half + 2, half - 1:half + 2], 0.0)
    total = core.sum(axis=(1, 2))
    safe = np.where(total > 0, total, 1.0)
    d = np.arange(-1, 2)
    dx = np.where(total > 0, (core.sum(axis=1) * d).sum(axis=1) / safe, 0.0)
    dy = np.where(total > 0, (core.sum(axis=2) * d).sum(axis=1) / safe, 0.0)
    flux = np.maximum(excess.sum(axis=(1, 2)), total)
    return np.stack([win.x0 + half + dx, win.y0 + half + dy, np.maximum(flux, 1e-9),
                     win.bg, np.full(len(total), float(sigma_px))], axis=1)


def estimate_inv_gain(win, p):
    """Inverse gain (ADU per electron) from the residuals of uniformly weighted 5-parameter fits.

    The excess variance of a star's pixels over the background's grows as
    ``(mu - b) / gain`` (shot noise); per star, the leverage-corrected squared residuals
    are regressed on the model excess (weighted, twice re-weighted); the median over the
    stars is robust to a few non-stars (cosmic rays). Returns 0 when the stars show no
    measurable shot noise (faint, background-limited stars).
    """
    n, size = len(p), win.size
    model, jac_t = _jacobian(p, win, True)
    return inv_gain_from_residuals(win.values.reshape(n, size * size), win.valid.reshape(n, size * size),
                                   win.noise, model, jac_t, p[:, 3])


def inv_gain_from_residuals(values, valid, noise, model, jac_t, bg) -> float:
    """Inverse gain from uniformly weighted fits: ``values``/``valid``/``model`` (N, P), ``jac_t`` (N, k, P).

    See :func:`estimate_inv_gain`; shared with the smeared-star fits.
    """
    n = len(values)
    w = valid / noise[:, None] ** 2
    a = (jac_t * w[:, None, :]) @ jac_t.transpose(0, 2, 1)
    leverage = w * np.sum(jac_t * (_spd_inverse(a) @ jac_t), axis=1)
    resid2 = (values - model) ** 2 / np.clip(1.0 - leverage, 0.05, 1.0)
    excess = np.maximum(model - bg[:, None], 0.0)
    extra = resid2 - noise[:, None] ** 2
    inv_gain = np.zeros(n)
    for _ in range(3):
        var = noise[:, None] ** 2 + excess * inv_gain[:, None]
        weight = valid / var ** 2
        den = np.sum(weight * excess ** 2, axis=1)
        num = np.sum(weight * excess * extra, axis=1)
        inv_gain = np.maximum(0.0, np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0))
    return _median(inv_gain) if n else 0.0


def _median(values) -> float:
    """``np.median`` of a non-empty array (NaN if a value is NaN), without importing
    ``numpy.ma`` as ``np.median`` does on its first call (~15 ms of a ``shipstar solve``)."""
    x = np.asarray(values, dtype=float).reshape(-1)
    return math.nan if np.isnan(x).any() else median(x)


def estimate_psf_sigma(image, col, row, bg, noise, *, inv_gain=None, max_stars=15):
    """PSF sigma shared by the frame, and the inverse gain if not given.

    Median sigma of 5-parameter fits of the brightest stars (``col``, ``row`` (N,): their
    peak pixels, brightest first, none saturated). Returns ``(sigma_px, inv_gain)``;
    sigma is NaN when no fit converges; ``inv_gain`` is the given one or
    :func:`estimate_inv_gain` on the same fits.
    """
    col, row = col[:max_stars], row[:max_stars]
    bg, noise = bg[:max_stars], noise[:max_stars]
    sigma = 1.0
    for _ in range(3):
        half = window_half_px(sigma)
        win = gather_windows(image, col, row, half, bg, noise)
        p, ok = fit_gaussian(win, start_values(win, sigma), fit_sigma=True, inv_gain=inv_gain or 0.0,
                             tol_px=0.0, tol_chi2=1e-2)
        if not np.any(ok):
            return math.nan, (inv_gain or 0.0)
        sigma = _median(p[ok, 4])
        if window_half_px(sigma) <= half:
            break
    if inv_gain is None:
        inv_gain = estimate_inv_gain(win.take(np.flatnonzero(ok)), p[ok])
    return sigma, inv_gain


@functools.lru_cache(maxsize=32)
def neighbour_ratios(sigma_px: float) -> tuple[float, float]:
    """How much a star's neighbours hold at least, relative to its brightest pixel.

    For a pixel-integrated Gaussian of ``sigma_px`` at every sub-pixel phase within its
    brightest pixel, the minimum of (a) the 8 neighbours' sum over the peak and (b) the
    sum of the two faintest of the 4 edge neighbours over the peak. A hot pixel has
    (0, 0), a cosmic ray along a line of 2-3 pixels (>= 1, 0); sigma 0.8 px gives
    (3.0, 0.50), sigma 0.5 px (1.1, 0.09).
    """
    phase = np.linspace(0.0, 0.5, 11)
    u = np.array([-1.5, -0.5, 0.5, 1.5])[None, :] - phase[:, None]
    frac = np.diff(0.5 * erf(u / (_SQRT2 * sigma_px)), axis=1)      # (phases, 3): left, centre, right
    box = frac.sum(axis=1)
    c = frac[:, 1]
    peak = c[:, None] * c[None, :]
    total = (box[:, None] * box[None, :] - peak) / peak
    edges = np.stack(np.broadcast_arrays(frac[:, 0, None] * c[None, :], frac[:, 2, None] * c[None, :],
                                         c[:, None] * frac[None, :, 0], c[:, None] * frac[None, :, 2]), axis=-1)
    two_faintest = np.sort(edges, axis=-1)[..., :2].sum(axis=-1) / peak
    return float(total.min()), float(two_faintest.min())


def covariance(win, p, *, inv_gain=0.0):
    """Cramer-Rao covariance (N, 4, 4) of (x, y, F, b) at parameters ``p`` (N, 5), sigma known."""
    a, _ = _kernels.gauss_normal(win, p, fit_sigma=False, inv_gain=inv_gain)
    return _spd_inverse(a)
