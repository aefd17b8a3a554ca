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

from shipstar.extract import _kernels
from shipstar.extract._fit import spd_solve
from shipstar.extract._scratch import scratch

__all__ = ["StreakWindows", "StreakFit", "gather_streak_windows", "streak_half_sizes", "fit_streaks",
           "streak_normal_equations", "path_points", "start_parameters"]

_SQRT2 = math.sqrt(2.0)
_SQRT2PI = math.sqrt(2.0 * math.pi)
#: Path length per panel of the composite Gauss-Legendre rule, in PSF sigmas, and nodes per panel
#: (the model then differs from the exact smeared PSF by ~1e-4 of its peak pixel).
_PANEL_SIGMAS = 2.0
_PANEL_NODES = 3
#: Half-width, in sigmas, of the pixels each path point contributes to (flux beyond: 6e-5).
_LOCAL_SIGMAS = 4.0
#: Steps per pixel of the tabulated pixel fractions (linear interpolation).
_TABLE_STEPS = 1024
_SIGMA_RANGE_PX = (0.25, 20.0)
#: Largest move of a streak's start from its line-filter peak pixel, along and across the streak, px.
_START_ALONG_PX = 1.0
_START_ACROSS_PX = 0.5
#: A star's iterations stop when its centre moves by less than this fraction of its predicted error ...
_CONVERGED_FRACTION = 0.05
#: ... or when the step promises to lower its chi^2 by less than this (a faint streak's flat valley,
#: where Gauss-Newton creeps by ~0.1 sigma an iteration: the rest is irrelevant to its error).
_CONVERGED_CHI2 = 0.01

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
    are invalid (zero weight in the fit).  Compiled (``_kernels.gather``):
    :func:`_gather_streak_windows_python`'s windows.
    """
    values, valid = _kernels.gather(image, col, row, int(hx), int(hy), bad)
    col, row = np.asarray(col), np.asarray(row)
    return StreakWindows(values=values, valid=valid, x0=(col - hx).astype(float), y0=(row - hy).astype(float),
                         noise=np.asarray(noise, dtype=float), bg=np.asarray(bg, dtype=float))


def _gather_streak_windows_python(image, col, row, hx, hy, bg, noise, bad=None) -> StreakWindows:
    """:func:`gather_streak_windows` in NumPy (the compiled kernel's reference)."""
    height, width = image.shape
    rows = row[:, None] + np.arange(-hy, hy + 1)
    cols = col[:, None] + np.arange(-hx, hx + 1)
    valid = ((rows >= 0) & (rows < height))[:, :, None] & ((cols >= 0) & (cols < width))[:, None, :]
    # flat indices and one take (2-D fancy indexing costs ~2 x more)
    flat = np.clip(rows, 0, height - 1)[:, :, None] * width + np.clip(cols, 0, width - 1)[:, None, :]
    values = np.asarray(image).reshape(-1).take(flat).astype(float)
    if bad is not None:
        valid &= ~np.asarray(bad).reshape(-1).take(flat)
    return StreakWindows(values=values, valid=valid, x0=(col - hx).astype(float), y0=(row - hy).astype(float),
                         noise=np.asarray(noise, dtype=float), bg=np.asarray(bg, dtype=float))


@functools.lru_cache(maxsize=4)
def _gauss_legendre(n: int):
    """Gauss-Legendre nodes and weights on [-1, 1] (``leggauss`` costs ~0.2 ms a call)."""
    return np.polynomial.legendre.leggauss(n)


def path_points(length_px: float, sigma_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Nodes ``t`` (n,) in (-1/2, 1/2) and weights (n,) (sum 1) of the model's points along a path.

    Composite 3-point Gauss-Legendre on panels of at most ``_PANEL_SIGMAS`` sigma of path.
    """
    panels = max(1, int(math.ceil(length_px / (_PANEL_SIGMAS * sigma_px))))
    node, weight = _gauss_legendre(_PANEL_NODES)
    start = np.arange(panels) / panels - 0.5
    t = (start[:, None] + (node[None, :] + 1.0) / (2.0 * panels)).ravel()
    return t, np.tile(weight / (2.0 * panels), panels)


@functools.lru_cache(maxsize=8)
def _fraction_table(sigma_px: float):
    """Pixel fractions of a point, tabulated over its sub-pixel offset f = c - rint(c).

    Rows: f = -1/2 .. 1/2 in ``_TABLE_STEPS`` steps; columns: its local pixels
    j = 0 .. 2 half (pixel rint(c) - half + j), half = ceil(``_LOCAL_SIGMAS`` sigma).
    Returns the tables (4, ``_TABLE_STEPS`` + 1, 2 half + 1) -- E, its row-to-row
    difference, dE/dc, its difference: linear interpolation between rows, error < 4e-7
    of a point's flux for sigma >= 0.5 px -- and ``half``. The compiled model
    (:mod:`shipstar.extract._kernels`) reads them.
    """
    half = int(math.ceil(_LOCAL_SIGMAS * sigma_px))
    f = np.linspace(-0.5, 0.5, _TABLE_STEPS + 1)[:, None]
    z = (np.arange(2 * half + 2) - half - 0.5 - f) / sigma_px
    pdf = np.exp(-0.5 * z * z) / (_SQRT2PI * sigma_px)
    cdf = 0.5 * _kernels.erf(z * (1.0 / _SQRT2))                   # Phi(z) - 1/2: its differences
    frac, d_centre = np.diff(cdf, axis=1), pdf[:, :-1] - pdf[:, 1:]
    out = np.stack([frac, np.diff(frac, axis=0, append=frac[-1:]), d_centre,
                    np.diff(d_centre, axis=0, append=d_centre[-1:])])
    out.setflags(write=False)
    return out, half


def _common_sigma(p, fit_sigma):
    """The PSF sigma shared by all stars of ``p`` (N, 7) when the compiled model applies (not
    fitted, one for all), else None."""
    if fit_sigma or len(p) == 0:
        return None
    sigma = p[:, SIGMA]
    return float(sigma[0]) if np.ptp(sigma) == 0 else None


def start_parameters(win, col, row, sigma, smear):
    """Start parameters (N, 7): near the centre of light of each streak, its flux from the window's excess.

    The centre: the peak pixel ``col, row`` moved to the first moment of the positive
    excess over the pixels within ``1.5 sigma + 0.5`` px of the streak's segment
    (``smear`` (2,) or (N, 2)) through it, by at most ``_START_ALONG_PX`` along the
    streak and ``_START_ACROSS_PX`` across: a bright streak's fit then needs an
    iteration less, and a blended neighbour cannot pull the start over to itself.
    Compiled (``_kernels.streak_start``): :func:`_start_parameters_python`'s values to the bit.
    """
    n_star = len(col)
    smear = np.asarray(smear, dtype=float)
    sigma = np.asarray(sigma, dtype=float)
    d = np.ascontiguousarray(np.broadcast_to(smear, (n_star, 2)))
    sigma_n = np.full(n_star, float(sigma)) if sigma.ndim == 0 else sigma
    return _kernels.streak_start(win, np.asarray(col, dtype=float), np.asarray(row, dtype=float), sigma_n, d,
                                 1.5 * float(np.max(sigma)) + 0.5, _START_ALONG_PX, _START_ACROSS_PX)


def _start_parameters_python(win, col, row, sigma, smear):
    """:func:`start_parameters` in NumPy (the compiled kernel's reference)."""
    excess = np.where(win.valid, win.values - win.bg[:, None, None], 0.0)
    n_star = len(col)
    d = np.broadcast_to(np.asarray(smear, dtype=float), (n_star, 2))
    length = np.hypot(d[:, 0], d[:, 1])
    u = np.where(length[:, None] > 1e-9, d / np.maximum(length, 1e-9)[:, None], [1.0, 0.0])
    wy, wx = win.shape
    peak = np.stack([col, row], axis=1).astype(float)
    ddx = (win.x0[:, None] + np.arange(wx) - peak[:, 0, None])[:, None, :]      # (N, 1, Wx)
    ddy = (win.y0[:, None] + np.arange(wy) - peak[:, 1, None])[:, :, None]      # (N, Wy, 1)
    along = ddx * u[:, 0, None, None] + ddy * u[:, 1, None, None]
    across = ddx * u[:, 1, None, None] - ddy * u[:, 0, None, None]
    reach = 1.5 * float(np.max(sigma)) + 0.5
    near = np.maximum(np.abs(along) - 0.5 * length[:, None, None], 0.0) ** 2 + across ** 2 <= reach * reach
    w = np.where(near, np.maximum(excess, 0.0), 0.0)
    total = np.maximum(w.sum(axis=(1, 2)), 1e-300)
    shift_along = np.clip((w * along).sum(axis=(1, 2)) / total, -_START_ALONG_PX, _START_ALONG_PX)
    shift_across = np.clip((w * across).sum(axis=(1, 2)) / total, -_START_ACROSS_PX, _START_ACROSS_PX)
    centre = peak + shift_along[:, None] * u + shift_across[:, None] * np.stack([u[:, 1], -u[:, 0]], axis=1)
    p0 = np.zeros((n_star, 7))
    p0[:, X], p0[:, Y] = centre[:, 0], centre[:, 1]
    p0[:, FLUX] = np.maximum(excess.sum(axis=(1, 2)), 10.0 * win.noise)
    p0[:, BG] = win.bg
    p0[:, SIGMA] = sigma
    p0[:, DX:] = d
    return p0


def _axis_profiles(centre, first, size, sigma, want_sigma):
    """Pixel fractions of points ``centre`` (N, n) in windows of ``size`` pixels from ``first`` (N,).

    Per-star sigma (``erf`` on the fly; a common one: the compiled model, :mod:`._kernels`).
    Returns E, dE/dcentre and (if ``want_sigma``) dE/dsigma, each (N, n, size). Only
    each point's own +-``_LOCAL_SIGMAS`` sigma pixels are computed.
    """
    n_star, n_pt = centre.shape
    half = int(math.ceil(_LOCAL_SIGMAS * float(np.max(sigma))))
    m = 2 * half + 1
    near = np.rint(centre)
    own = near.astype(np.int64) - half                                  # (N, n) first local pixel
    s = sigma[:, None, None]
    z = ((near - centre)[:, :, None] - half - 0.5 + np.arange(m + 1)) / s
    pdf = np.exp(-0.5 * z * z) / (_SQRT2PI * s)
    cdf = 0.5 * _kernels.erf(z * (1.0 / _SQRT2))
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
    """Model (N, P) and transposed Jacobian (N, k, P) on the flattened windows, per-star or
    fitted sigma (``erf`` on the fly; a common, known sigma: the compiled model).

    The Jacobian is a work array (:mod:`shipstar.extract._scratch`): valid until the next call.
    """
    t, w = nodes
    n_star = len(p)
    wy, wx = win.shape
    sigma = p[:, SIGMA]
    cx = p[:, X, None] + t[None, :] * p[:, DX, None]
    cy = p[:, Y, None] + t[None, :] * p[:, DY, None]
    x0, y0 = win.x0.astype(np.intp), win.y0.astype(np.intp)
    ex = _axis_profiles(cx, x0, wx, sigma, fit_sigma)
    eyt = [(e * w[None, :, None]).transpose(0, 2, 1) for e in _axis_profiles(cy, y0, wy, sigma, fit_sigma)]
    flux = p[:, FLUX, None, None]
    k = 4 + int(fit_sigma) + 2 * int(fit_smear)
    jac_t = scratch("streak.jacobian", (n_star, k, wy, wx), float)
    np.matmul(eyt[0], ex[0], out=jac_t[:, 2])                          # the shape: sum over the points
    np.matmul(eyt[0], ex[1], out=jac_t[:, 0])
    np.matmul(eyt[1], ex[0], out=jac_t[:, 1])
    jac_t[:, :2] *= flux[:, None]
    jac_t[:, 3] = 1.0
    col = 4
    if fit_sigma:
        jac_t[:, col] = flux * (eyt[2] @ ex[0] + eyt[0] @ ex[2])
        col += 1
    if fit_smear:
        jac_t[:, col] = flux * (eyt[0] @ (t[None, :, None] * ex[1]))
        jac_t[:, col + 1] = flux * ((eyt[1] * t[None, None, :]) @ ex[0])
    jac_t = jac_t.reshape(n_star, k, wy * wx)
    model = p[:, BG, None] + p[:, FLUX, None] * jac_t[:, 2]
    return model, jac_t


def streak_normal_equations(p, win, nodes, *, fit_sigma=False, fit_smear=False, inv_gain=0.0):
    """Weighted normal matrix (N, k, k), gradient (N, k), model (N, P) and Jacobian (N, k, P).

    The Jacobian is a work array, valid until the next evaluation in the thread.
    """
    a, g, model, jac_t, _ = _normal_equations(p, win, nodes, fit_sigma, fit_smear, inv_gain)
    return a, g, model, jac_t


def _normal_equations(p, win, nodes, fit_sigma, fit_smear, inv_gain):
    """:func:`streak_normal_equations` and the pixel variances (N, P) it weighted with."""
    sigma = _common_sigma(p, fit_sigma)
    if sigma is not None:
        table, half = _fraction_table(sigma)
        a, g, model, var, jac_t = _kernels.streak_equations(p, win, nodes, table, half, fit_smear=fit_smear,
                                                            inv_gain=inv_gain)
        return a, g, model, jac_t, var
    model, jac_t = _jacobian(p, win, nodes, fit_sigma, fit_smear)
    n_star = len(p)
    var = win.noise[:, None] ** 2 + np.maximum(model - p[:, BG, None], 0.0) * inv_gain
    jw_t = np.multiply(jac_t, (win.valid.reshape(n_star, -1) / var)[:, None, :],
                       out=scratch("streak.weighted", jac_t.shape, float))
    a = jw_t @ jac_t.transpose(0, 2, 1)
    g = (jw_t @ (win.values.reshape(n_star, -1) - model)[:, :, None])[:, :, 0]
    return a, g, model, jac_t, var


@dataclass(frozen=True)
class StreakFit:
    """Result of :func:`fit_streaks`: parameters, convergence, and the normal equations there.

    Attributes
    ----------
    p : (N, 7) array
        Fitted (x, y, F, b, sigma, dx, dy).
    ok : (N,) bool
        Converged to a finite, plausible solution.
    normal : (N, k, k) array
        Weighted normal matrix (Fisher information) of the free parameters at ``p``.
    model : (N, P) array
        Model of the flattened windows at ``p``.
    """

    p: np.ndarray
    ok: np.ndarray
    normal: np.ndarray
    model: np.ndarray


def fit_streaks(win, p0, nodes, *, fit_sigma=False, fit_smear=False, inv_gain=0.0, max_iterations=20,
                tol_px=2e-4, converged_fraction=_CONVERGED_FRACTION, max_shift_px=None) -> StreakFit:
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
        ``converged_fraction`` of its predicted error (whichever is larger), or when the
        step would lower its chi^2 by less than ``_CONVERGED_CHI2``.
    max_shift_px : (2,) array, optional
        Largest accepted distance (x, y) of the fitted centre from the window centre;
        default a quarter of the window size.

    Returns
    -------
    StreakFit
        Its ``normal`` and ``model`` are those of the parameters before the last,
        negligible step of each converged star.
    """
    p = np.array(p0, dtype=float)
    free = [X, Y, FLUX, BG] + ([SIGMA] if fit_sigma else []) + ([DX, DY] if fit_smear else [])
    wy, wx = win.shape
    limit = np.array([wx, wy]) / 4.0 if max_shift_px is None else np.asarray(max_shift_px, float)
    sigma = _common_sigma(p, fit_sigma)
    if sigma is not None:                 # a common, known sigma: the compiled fit, star by star
        table, half = _fraction_table(sigma)
        p, converged, a, model = _kernels.streak_fit(
            p, win, nodes, table, half, fit_smear=fit_smear, inv_gain=inv_gain, max_iterations=max_iterations,
            tol_px=tol_px, converged_fraction=converged_fraction, converged_chi2=_CONVERGED_CHI2)
        return StreakFit(p=p, ok=converged & _plausible(p, win, limit), normal=a, model=model)
    state = _LMState(p, win, nodes, dict(fit_sigma=fit_sigma, fit_smear=fit_smear, inv_gain=inv_gain), free)
    converged = np.zeros(len(p), dtype=bool)
    active = np.arange(len(p))
    for _ in range(max_iterations):
        if active.size == 0:
            break
        step, sigma = state.step(active)
        watched = step[:, state.watched]
        done = np.all(np.abs(watched) <= np.maximum(tol_px, converged_fraction * sigma), axis=1)
        done |= np.sum(step * state.g[active], axis=1) <= _CONVERGED_CHI2
        trial = state.p[active]
        trial[:, free] += step
        trial[:, FLUX] = np.maximum(trial[:, FLUX], 1e-3 * np.abs(p0[active, FLUX]) + 1e-12)
        trial[:, SIGMA] = np.clip(trial[:, SIGMA], *_SIGMA_RANGE_PX)
        # converged: the last (negligible) step is taken without evaluating the model there again
        state.p[active[done]] = trial[done]
        converged[active[done]] = True
        active, trial = active[~done], trial[~done]
        if active.size:
            state.try_(active, trial)
    p = state.p
    return StreakFit(p=p, ok=converged & _plausible(p, win, limit), normal=state.a, model=state.model)


def _plausible(p, win, limit):
    """(N,) bool: finite parameters, the centre within ``limit`` (x, y) of the window's, sigma in range."""
    return (np.all(np.isfinite(p), axis=1) & np.all(np.abs(p[:, :2] - win.centre) <= limit, axis=1)
            & (p[:, SIGMA] > _SIGMA_RANGE_PX[0]) & (p[:, SIGMA] < _SIGMA_RANGE_PX[1]))


class _LMState:
    """Levenberg-Marquardt bookkeeping per star: accepted parameters, their normal equations, damping.

    The weights depend on the model (shot noise), so a step is judged with the weights of
    the accepted parameters (iteratively re-weighted least squares): it is kept when it
    does not raise chi^2 under those weights.
    """

    def __init__(self, p, win, nodes, opts, free):
        self.win, self.nodes, self.opts, self.free = win, nodes, opts, free
        self.p = p
        self.a, self.g, self.model, _, self.var = _normal_equations(p, win, nodes, **opts)
        self.chi2 = np.sum(self._residual2(win, self.model) / self.var, axis=1)
        self.lam = np.full(len(p), 1e-3)
        self.cap = np.maximum(0.5, 0.25 * np.hypot(p[:, DX], p[:, DY]))     # largest step of x, y
        k = self.a.shape[1]
        self.watched = [0, 1] + ([k - 2, k - 1] if opts["fit_smear"] else [])   # x, y (dx, dy): convergence
        self.last = np.zeros((len(p), k))                                   # last accepted step

    @staticmethod
    def _residual2(win, model):
        """Squared residuals (N, P) of the valid pixels."""
        n = len(model)
        return win.valid.reshape(n, -1) * (win.values.reshape(n, -1) - model) ** 2

    def step(self, idx):
        """Damped Gauss-Newton steps (M, k) of stars ``idx`` and the predicted errors (M, w) of
        the ``watched`` parameters (from the damped matrix: at most a few per cent low)."""
        a = self.a[idx]
        m, k = a.shape[:2]
        diag = np.diagonal(a, axis1=1, axis2=2)
        damped = a + (self.lam[idx, None] * diag)[:, :, None] * np.eye(k)
        n_w = len(self.watched)
        rhs = np.zeros((m, k, 1 + n_w))
        rhs[:, :, 0] = self.g[idx]
        rhs[:, self.watched, np.arange(1, n_w + 1)] = 1.0
        sol = spd_solve(damped, rhs)
        step = sol[:, :, 0]
        # a faint streak's Gauss-Newton steps may alternate (x, y overshoot by a factor 1 + q,
        # the last two steps in the ratio -q): the secant estimate of the rest is step / (1 + q)
        last = self.last[idx, :2]
        q = -np.sum(step[:, :2] * last, axis=1) / np.maximum(np.sum(last * last, axis=1), 1e-300)
        step /= 1.0 + np.clip(q, 0.0, 1.0)[:, None]
        cap = self.cap[idx, None]
        step[:, :2] = np.clip(step[:, :2], -cap, cap)
        if self.opts["fit_smear"]:
            step[:, k - 2:] = np.clip(step[:, k - 2:], -2.0 * cap, 2.0 * cap)
        return step, np.sqrt(np.abs(sol[:, self.watched, np.arange(1, n_w + 1)]))

    def try_(self, idx, trial):
        """Accept the trial parameters of the stars whose chi^2 does not grow; damp the others."""
        win = self.win if len(idx) == len(self.p) else self.win.take(idx)
        a, g, model, _, var = _normal_equations(trial, win, self.nodes, **self.opts)
        r2 = self._residual2(win, model)
        better = np.sum(r2 / self.var[idx], axis=1) <= self.chi2[idx] * (1.0 + 1e-9) + 1e-9
        acc = idx[better]
        self.last[acc] = (trial[better] - self.p[acc])[:, self.free]
        self.p[acc] = trial[better]
        self.a[acc], self.g[acc], self.model[acc], self.var[acc] = a[better], g[better], model[better], var[better]
        self.chi2[acc] = np.sum(r2[better] / var[better], axis=1)
        self.lam[acc] = np.maximum(self.lam[acc] * 0.1, 1e-6)
        self.lam[idx[~better]] *= 10.0
