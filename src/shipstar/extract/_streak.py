"""Smeared stars (streaks): the pixel-integrated Gaussian PSF moved along a line segment.

Model of the pixels of a rectangular window around each star (pixel (i, j) covers
[i - 0.5, i + 0.5) x [j - 0.5, j + 0.5)):

    mu_ij = b + F / n * sum_p E(i; x + t_p dx, s) * E(j; y + t_p dy, s),
    t_p = (p + 1/2) / n - 1/2,  p = 0 .. n - 1,

the PSF of :mod:`shipstar.extract._fit` integrated along the image motion (dx, dy)
during the exposure (written above with equal weights; computed with composite
3-point Gauss-Legendre on panels of <= 2 sigma, within ~1e-4 of the peak pixel).
(x, y) is the segment's midpoint: for a constant rate, the position at mid-exposure.
Per star, ``sum_p`` is one matrix product ``Ey^T Ex`` of the points' separable pixel
fractions, batched over the stars.

Unknowns: x, y, F (flux, ADU), b (local background); optionally the PSF sigma s and
the smear (dx, dy). The fit is Levenberg-Marquardt (Gauss-Newton steps, damped when
chi^2 would grow) on the weighted normal equations, ``variance = noise**2 + (mu - b) /
gain``, as for point stars.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from shipstar.extract._fit import _cho_solve, _cholesky

__all__ = ["StreakWindows", "gather_streak_windows", "streak_half_sizes", "fit_streaks",
           "streak_normal_equations", "path_points", "start_parameters"]

_SQRT2 = math.sqrt(2.0)
_SQRT2PI = math.sqrt(2.0 * math.pi)
#: Path length per panel of the composite Gauss-Legendre rule, in PSF sigmas, and nodes per panel
#: (the model then differs from the exact smeared PSF by ~1e-4 of its peak pixel).
_PANEL_SIGMAS = 2.0
_PANEL_NODES = 3
#: Half-width, in sigmas, of the pixels each path point contributes to (flux beyond: 6e-5).
_LOCAL_SIGMAS = 4.0
#: Steps per pixel of the tabulated normal CDF (cubic Hermite interpolation).
_TABLE_STEPS = 256
_SIGMA_RANGE_PX = (0.25, 20.0)
#: A star's iterations stop when its centre moves by less than this fraction of its predicted error.
_CONVERGED_FRACTION = 0.01

#: Columns of the parameter array ``p`` (N, 7).
X, Y, FLUX, BG, SIGMA, DX, DY = range(7)


@dataclass(frozen=True)
class StreakWindows:
    """Rectangular pixel windows ``values``/``valid`` (N, Wy, Wx); pixel (0, 0) at (x0, y0)."""

    values: np.ndarray
    valid: np.ndarray
    x0: np.ndarray
    y0: np.ndarray
    noise: np.ndarray
    bg: np.ndarray

    @property
    def shape(self) -> tuple:
        return self.values.shape[1:]

    def take(self, index) -> "StreakWindows":
        """The windows of the stars ``index``."""
        return StreakWindows(values=self.values[index], valid=self.valid[index], x0=self.x0[index],
                             y0=self.y0[index], noise=self.noise[index], bg=self.bg[index])

    @property
    def centre(self) -> np.ndarray:
        """(N, 2) image coordinates of each window's central pixel."""
        hy, hx = (np.array(self.shape) - 1) // 2
        return np.stack([self.x0 + hx, self.y0 + hy], axis=1)


def streak_half_sizes(smear_px, sigma_px: float, margin_px: float) -> tuple[int, int]:
    """Half-sizes (hx, hy) of windows holding a streak ``smear_px`` (2,) +- 3 sigma + ``margin_px``."""
    reach = max(3.0 * sigma_px, 2.0) + margin_px
    return (int(math.ceil(0.5 * abs(smear_px[0]) + reach)), int(math.ceil(0.5 * abs(smear_px[1]) + reach)))


def gather_streak_windows(image, col, row, hx, hy, bg, noise, bad=None) -> StreakWindows:
    """Copy (2 hy + 1, 2 hx + 1) windows centred on integer pixels (col, row).

    Off-image pixels and pixels flagged in ``bad`` ((H, W) bool, e.g. saturated or hot)
    are invalid (zero weight in the fit).
    """
    height, width = image.shape
    rows = row[:, None] + np.arange(-hy, hy + 1)
    cols = col[:, None] + np.arange(-hx, hx + 1)
    valid = ((rows >= 0) & (rows < height))[:, :, None] & ((cols >= 0) & (cols < width))[:, None, :]
    r_idx = np.clip(rows, 0, height - 1)[:, :, None]
    c_idx = np.clip(cols, 0, width - 1)[:, None, :]
    values = image[r_idx, c_idx].astype(float)
    if bad is not None:
        valid &= ~bad[r_idx, c_idx]
    return StreakWindows(values=values, valid=valid, x0=(col - hx).astype(float), y0=(row - hy).astype(float),
                         noise=np.asarray(noise, dtype=float), bg=np.asarray(bg, dtype=float))


def path_points(length_px: float, sigma_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Nodes ``t`` (n,) in (-1/2, 1/2) and weights (n,) (sum 1) of the model's points along a path.

    Composite 3-point Gauss-Legendre on panels of at most ``_PANEL_SIGMAS`` sigma of path.
    """
    panels = max(1, int(math.ceil(length_px / (_PANEL_SIGMAS * sigma_px))))
    node, weight = np.polynomial.legendre.leggauss(_PANEL_NODES)
    start = np.arange(panels) / panels - 0.5
    t = (start[:, None] + (node[None, :] + 1.0) / (2.0 * panels)).ravel()
    return t, np.tile(weight / (2.0 * panels), panels)


@functools.lru_cache(maxsize=8)
def _cdf_table(sigma_px: float, half: int):
    """Normal CDF at a point's local pixel edges, tabulated over its sub-pixel offset f.

    Rows: f = -1/2 .. 1/2 in ``_TABLE_STEPS`` steps; columns: edges
    ``e_j = j - half - 1/2 - f``, j = 0 .. 2 half + 1. Returns (cdf, d cdf / df).
    """
    from scipy.special import ndtr

    f = np.linspace(-0.5, 0.5, _TABLE_STEPS + 1)[:, None]
    z = (np.arange(2 * half + 2) - half - 0.5 - f) / sigma_px
    cdf, slope = ndtr(z), -np.exp(-0.5 * z * z) / (_SQRT2PI * sigma_px)
    for arr in (cdf, slope):
        arr.setflags(write=False)
    return cdf, slope


def _edge_cdf(f, sigma_px, half):
    """CDF at the local edges (M, 2 half + 2) of points with offsets ``f`` (M,): cubic Hermite in f.

    Error < 1e-12 (step 1/256 px): ``erf`` itself costs ~40 ns a value, this ~5 ns.
    """
    cdf, slope = _cdf_table(float(sigma_px), int(half))
    pos = (f + 0.5) * _TABLE_STEPS
    i = np.clip(np.floor(pos).astype(np.intp), 0, _TABLE_STEPS - 1)
    w = (pos - i)[:, None]
    w2, w3 = w * w, w * w * w
    d = 1.0 / _TABLE_STEPS
    return ((2 * w3 - 3 * w2 + 1) * cdf[i] + (w3 - 2 * w2 + w) * d * slope[i]
            + (3 * w2 - 2 * w3) * cdf[i + 1] + (w3 - w2) * d * slope[i + 1])


def start_parameters(win, col, row, sigma, smear):
    """Start parameters (N, 7) at the window centres: flux from the window's excess."""
    excess = np.where(win.valid, win.values - win.bg[:, None, None], 0.0).sum(axis=(1, 2))
    p0 = np.zeros((len(col), 7))
    p0[:, X], p0[:, Y] = col, row
    p0[:, FLUX] = np.maximum(excess, 10.0 * win.noise)
    p0[:, BG] = win.bg
    p0[:, SIGMA] = sigma
    p0[:, DX:] = smear
    return p0


def _axis_profiles(centre, first, size, sigma, want_sigma):
    """Pixel fractions of points ``centre`` (N, n) in windows of ``size`` pixels from ``first`` (N,).

    Returns E, dE/dcentre and (if ``want_sigma``) dE/dsigma, each (N, n, size). Only
    each point's own +-``_LOCAL_SIGMAS`` sigma pixels are computed.
    """
    from scipy.special import erf

    n_star, n_pt = centre.shape
    half = int(math.ceil(_LOCAL_SIGMAS * float(np.max(sigma))))
    m = 2 * half + 1
    near = np.rint(centre)
    own = near.astype(np.int64) - half                                  # (N, n) first local pixel
    s = sigma[:, None, None]
    z = ((near - centre)[:, :, None] - half - 0.5 + np.arange(m + 1)) / s
    pdf = np.exp(-0.5 * z * z) / (_SQRT2PI * s)
    if want_sigma or np.ptp(sigma) > 0:
        cdf = 0.5 * erf(z * (1.0 / _SQRT2))
    else:
        cdf = _edge_cdf((centre - near).ravel(), sigma[0], half).reshape(n_star, n_pt, m + 1)
    parts = [np.diff(cdf, axis=2), pdf[:, :, :-1] - pdf[:, :, 1:]]
    if want_sigma:
        upd = z * pdf
        parts.append(upd[:, :, :-1] - upd[:, :, 1:])
    # point (s, p)'s local pixel j goes to window column own - first + j (if inside the window)
    rows = n_star * n_pt
    cols = (own - first[:, None]).reshape(-1, 1) + np.arange(m)
    inside = (cols >= 0) & (cols < size)
    flat = (np.arange(rows)[:, None] * size + cols)[inside]
    out = np.zeros((len(parts), rows * size))                            # contiguous (BLAS matmul)
    for k, part in enumerate(parts):
        out[k, flat] = part.reshape(rows, m)[inside]
    return list(out.reshape(len(parts), n_star, n_pt, size))


def _jacobian(p, win, nodes, fit_sigma, fit_smear):
    """Model (N, P) and transposed Jacobian (N, k, P) on the flattened windows."""
    t, w = nodes
    n_star = len(p)
    wy, wx = win.shape
    sigma = p[:, SIGMA]
    cx = p[:, X, None] + t[None, :] * p[:, DX, None]
    cy = p[:, Y, None] + t[None, :] * p[:, DY, None]
    ex = _axis_profiles(cx, win.x0.astype(np.int64), wx, sigma, fit_sigma)
    ey = _axis_profiles(cy, win.y0.astype(np.int64), wy, sigma, fit_sigma)
    flux = p[:, FLUX, None, None]
    eyt = np.ascontiguousarray((ey[0] * w[None, :, None]).transpose(0, 2, 1))   # (N, Wy, n), weighted
    both = eyt @ np.concatenate([ex[0], ex[1]], axis=2)                   # shape and d/dx in one product
    k = 4 + int(fit_sigma) + 2 * int(fit_smear)
    jac_t = np.empty((n_star, k, wy, wx))
    jac_t[:, 2] = both[:, :, :wx]
    jac_t[:, 0] = flux * both[:, :, wx:]
    jac_t[:, 1] = flux * (np.ascontiguousarray((ey[1] * w[None, :, None]).transpose(0, 2, 1)) @ ex[0])
    jac_t[:, 3] = 1.0
    col = 4
    if fit_sigma:
        jac_t[:, col] = flux * ((ey[2] * w[None, :, None]).transpose(0, 2, 1) @ ex[0] + eyt @ ex[2])
        col += 1
    if fit_smear:
        jac_t[:, col] = flux * (eyt @ (t[None, :, None] * ex[1]))
        jac_t[:, col + 1] = flux * ((ey[1] * (w * t)[None, :, None]).transpose(0, 2, 1) @ ex[0])
    jac_t = jac_t.reshape(n_star, k, wy * wx)
    model = p[:, BG, None] + p[:, FLUX, None] * jac_t[:, 2]
    return model, jac_t


def streak_normal_equations(p, win, nodes, *, fit_sigma=False, fit_smear=False, inv_gain=0.0):
    """Weighted normal matrix (N, k, k), gradient (N, k), model (N, P) and Jacobian (N, k, P)."""
    model, jac_t = _jacobian(p, win, nodes, fit_sigma, fit_smear)
    n_star = len(p)
    var = win.noise[:, None] ** 2 + np.maximum(model - p[:, BG, None], 0.0) * inv_gain
    jw_t = jac_t * (win.valid.reshape(n_star, -1) / var)[:, None, :]
    a = jw_t @ jac_t.transpose(0, 2, 1)
    g = (jw_t @ (win.values.reshape(n_star, -1) - model)[:, :, None])[:, :, 0]
    return a, g, model, jac_t


def fit_streaks(win, p0, nodes, *, fit_sigma=False, fit_smear=False, inv_gain=0.0, max_iterations=20,
                tol_px=2e-4, converged_fraction=_CONVERGED_FRACTION, max_shift_px=None):
    """Levenberg-Marquardt fit of the smeared PSF on all windows at once.

    Parameters
    ----------
    win : StreakWindows
    p0 : (N, 7) array
        Start values (x, y, F, b, sigma, dx, dy), image pixel coordinates and ADU.
    nodes : (t (n,), weight (n,))
        The model's points along the path (:func:`path_points` of the longest smear).
    fit_sigma, fit_smear : bool
        Also fit sigma, the smear vector (dx, dy).
    inv_gain : float
        1 / gain (ADU per electron); 0 gives uniform weights.
    tol_px, converged_fraction : float
        A star's iterations stop when its centre moves by less than ``tol_px`` or
        ``converged_fraction`` of its predicted error (whichever is larger).
    max_shift_px : (2,) array, optional
        Largest accepted distance (x, y) of the fitted centre from the window centre;
        default a quarter of the window size.

    Returns
    -------
    p : (N, 7) array
    ok : (N,) bool
        Converged to a finite, plausible solution.
    """
    p = np.array(p0, dtype=float)
    free = [X, Y, FLUX, BG] + ([SIGMA] if fit_sigma else []) + ([DX, DY] if fit_smear else [])
    wy, wx = win.shape
    limit = np.array([wx, wy]) / 4.0 if max_shift_px is None else np.asarray(max_shift_px, float)
    opts = dict(fit_sigma=fit_sigma, fit_smear=fit_smear, inv_gain=inv_gain)
    state = _LMState(p, win, nodes, opts)
    converged = np.zeros(len(p), dtype=bool)
    active = np.arange(len(p))
    for _ in range(max_iterations):
        step, sigma_xy = state.step(active)
        done = np.all(np.abs(step[:, :2]) <= np.maximum(tol_px, converged_fraction * sigma_xy), axis=1)
        trial = state.p[active]
        trial[:, free] += step
        trial[:, FLUX] = np.maximum(trial[:, FLUX], 1e-3 * np.abs(p0[active, FLUX]) + 1e-12)
        trial[:, SIGMA] = np.clip(trial[:, SIGMA], *_SIGMA_RANGE_PX)
        state.try_(active, trial)
        converged[active] = done
        active = active[~done]
        if active.size == 0:
            break
    p = state.p
    ok = (converged & np.all(np.isfinite(p), axis=1)
          & np.all(np.abs(p[:, :2] - win.centre) <= limit, axis=1)
          & (p[:, SIGMA] > _SIGMA_RANGE_PX[0]) & (p[:, SIGMA] < _SIGMA_RANGE_PX[1]))
    return p, ok


class _LMState:
    """Levenberg-Marquardt bookkeeping per star: accepted parameters, their normal equations, damping."""

    def __init__(self, p, win, nodes, opts):
        self.win, self.nodes, self.opts = win, nodes, opts
        self.p = p
        self.a, self.g, self.chi2 = self._equations(np.arange(len(p)), p)
        self.lam = np.full(len(p), 1e-3)
        self.cap = np.maximum(0.5, 0.25 * np.hypot(p[:, DX], p[:, DY]))     # largest step of x, y

    def _equations(self, idx, p):
        a, g, model, _ = streak_normal_equations(p, self.win.take(idx), self.nodes, **self.opts)
        var = self.win.noise[idx, None] ** 2 + np.maximum(model - p[:, BG, None], 0.0) * self.opts["inv_gain"]
        r2 = (self.win.values[idx].reshape(len(idx), -1) - model) ** 2 / var
        return a, g, np.sum(r2 * self.win.valid[idx].reshape(len(idx), -1), axis=1)

    def step(self, idx):
        """Damped Gauss-Newton steps (M, k) of stars ``idx`` and their predicted x, y errors (M, 2)."""
        a = self.a[idx]
        k = a.shape[1]
        damped = a + self.lam[idx, None, None] * np.eye(k) * np.diagonal(a, axis1=1, axis2=2)[:, :, None]
        low = _cholesky(damped)
        step = _cho_solve(low, self.g[idx][:, :, None])[:, :, 0]
        cap = self.cap[idx, None]
        step[:, :2] = np.clip(step[:, :2], -cap, cap)
        if self.opts["fit_smear"]:
            step[:, k - 2:] = np.clip(step[:, k - 2:], -2.0 * cap, 2.0 * cap)
        unit = np.zeros((len(idx), k, 2))
        unit[:, 0, 0] = unit[:, 1, 1] = 1.0
        cov_xy = _cho_solve(_cholesky(a), unit)
        return step, np.sqrt(np.abs(np.stack([cov_xy[:, 0, 0], cov_xy[:, 1, 1]], axis=1)))

    def try_(self, idx, trial):
        """Accept the trial parameters of the stars whose chi^2 does not grow; damp the others."""
        a, g, chi2 = self._equations(idx, trial)
        better = chi2 <= self.chi2[idx] * (1.0 + 1e-9) + 1e-9
        acc = idx[better]
        self.p[acc] = trial[better]
        self.a[acc], self.g[acc], self.chi2[acc] = a[better], g[better], chi2[better]
        self.lam[acc] = np.maximum(self.lam[acc] * 0.1, 1e-6)
        self.lam[idx[~better]] *= 10.0
