"""The motion of a body (the deck, or one sensor) fitted to its recent attitudes, causally.

Two things need the motion between exposures:

- the *carry*: two sensors' exposures are not simultaneous (free-running clocks, or one
  trigger with a delay); at sea the deck turns by up to 4 deg/s (5 deg / 8 s roll), 425''
  in 30 ms, so a frame of sensor B at ``t_B`` is turned to the epoch time ``t`` with the
  deck's rotation over ``[t_B, t]`` before it is fused;
- the *streak correction*: a centroid is the star's direction averaged over the
  exposure, which differs from the mid-exposure one by ``(-alpha x u + omega x (omega x u))
  T^2 / 24`` (:mod:`shipstar.pipeline._exposure`): it needs the angular velocity
  ``omega`` and acceleration ``alpha`` at the frame's time.

Both come from one model, fitted to the solved attitudes ``C_k`` (with covariances ``P_k``
about the body axes) of the last :data:`MOTION_WINDOW_S` seconds and nothing later than
a given time (causal: a frame never waits for later frames)::

    C(t) = C_ref exp([r(t)] x),   r(t) = sum_j c_j ((t - t_ref) / W)^j,  j = 0..MOTION_DEGREE

``C_ref`` is the newest sample, the rotation vectors ``r_k = log(C_ref^T C_k)`` are a few
degrees at most, and the coefficients ``c_j`` (3-vectors) are the weighted least-squares
solution with information ``(P_k + floor^2 I)^-1`` (the floor,
:data:`SIGMA_FLOOR_ARCSEC`, keeps noise-free simulations from weighting one frame 1e14
times another).  Then ``omega = J(r) r'`` and ``alpha = J(r) r'' + J'(r) r'`` with the
right Jacobian ``J(r) = I - [r]x / 2 + ...``; the rotation over ``[t_a, t_b]`` is
``exp(-[r(t_a)]x) exp([r(t_b)]x)`` (body axes).

Why a polynomial of the attitudes, and these numbers (docs/pipeline.md, *Motion*): the
batch pipeline before the streaming engine interpolated rates (differences of
consecutive frames) with three-point quadratics centred on the time, using frames after
it.  Fitted causally to 0.8 s of attitudes, a quartic is as good or better at the seeds'
sea state (roll 5 deg / 8 s, pitch 2 deg / 6 s, 0.1 px centroids, 10 frames/s): joint RMS
0.27 / 0.27 / 0.23'' against 0.30 / 0.28 / 0.28'' with A2 30 ms late, 0.28 / 0.25 /
0.24'' against 0.31 / 0.28 / 0.28'' with 80 ms streaks; truncation (noise-free) below
0.02''.  A quadratic is limited by the third derivative (1.4'' over a 30 ms carry at
0.3 s); a longer window by the fifth.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from shipstar.attitude import _ckernels
from shipstar.frames import rotation_vectors_rad as rotvecs   # rotation vectors (N, 3) of (N, 3, 3)
from shipstar.units import ASEC2RAD

__all__ = ["MOTION_WINDOW_S", "MOTION_DEGREE", "MIN_MOTION_SAMPLES", "SIGMA_FLOOR_ARCSEC", "MotionFit",
           "MotionWindow", "fit_motion", "rotvecs", "rotvec", "expm_rotvec"]

#: Attitudes older than this (s) before the newest one used are not fitted.
MOTION_WINDOW_S = 0.8
#: Degree of the polynomial in time (lower with fewer samples, :func:`fit_motion`).
MOTION_DEGREE = 4
#: Fewest samples (distinct times) a fit is made from (a quadratic with two to spare).
MIN_MOTION_SAMPLES = 5
#: Added in quadrature to every attitude's sigma about each axis before weighting (arcsec).
SIGMA_FLOOR_ARCSEC = 0.01


def rotvec(C) -> np.ndarray:
    """The rotation vector (3,) of one rotation matrix (3, 3): :func:`rotvecs` in plain
    floats (the engine takes several every epoch; the array path costs ten times as much
    for one)."""
    (c00, c01, c02), (c10, c11, c12), (c20, c21, c22) = np.asarray(C, float).reshape(3, 3).tolist()
    s0, s1, s2 = c21 - c12, c02 - c20, c10 - c01
    n = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
    angle = math.atan2(0.5 * n, 0.5 * (c00 + c11 + c22 - 1.0))
    scale = angle / n if n > 0.0 else 0.5
    return np.array([s0 * scale, s1 * scale, s2 * scale])


def expm_rotvec(phi) -> np.ndarray:
    """Rotation matrix ``exp([phi x])`` (3, 3) of a rotation vector ``phi`` (3,) (Rodrigues)."""
    x, y, z = (float(v) for v in np.asarray(phi, float).reshape(3))
    a = math.sqrt(x * x + y * y + z * z)
    if a == 0.0:
        return np.eye(3)
    s, c1 = math.sin(a) / a, (1.0 - math.cos(a)) / (a * a)
    return np.array([[1.0 - c1 * (y * y + z * z), c1 * x * y - s * z, c1 * x * z + s * y],
                     [c1 * x * y + s * z, 1.0 - c1 * (x * x + z * z), c1 * y * z - s * x],
                     [c1 * x * z - s * y, c1 * y * z + s * x, 1.0 - c1 * (x * x + y * y)]])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@dataclass(frozen=True, eq=False)
class MotionFit:
    """A body's attitude over a stretch of time: ``C(t) = C_ref exp([r(t)] x)``.

    Attributes
    ----------
    t_ref_s : float
        Time origin of the polynomial (the newest sample's time).
    scale_s : float
        Time unit of the polynomial (``tau = (t - t_ref_s) / scale_s``).
    C_ref : (3, 3) array
        ``C_hor_from_body`` of the newest sample.
    coef : (D + 1, 3) array
        Polynomial coefficients of ``r`` in ``tau``, constant term first.
    t_first_s, t_last_s : float
        Times of the oldest and newest samples fitted.
    n_samples : int
    """

    t_ref_s: float
    scale_s: float
    C_ref: np.ndarray
    coef: np.ndarray
    t_first_s: float
    t_last_s: float
    n_samples: int

    @property
    def degree(self) -> int:
        return len(self.coef) - 1

    def r(self, t_s: float, derivative: int = 0) -> np.ndarray:
        """``d^k r / dt^k`` (3,) at ``t_s`` (rad, rad/s, rad/s^2 for k = 0, 1, 2)."""
        tau = (float(t_s) - self.t_ref_s) / self.scale_s
        coef = self.__dict__.get("_coef_rows")
        if coef is None:                               # plain floats: the epoch asks ~6 times
            coef = self.coef.tolist()
            object.__setattr__(self, "_coef_rows", coef)
        x = y = z = 0.0                                # the same sums, in the same order, as in NumPy
        for j in range(derivative, len(coef)):
            w = math.perm(j, derivative) * tau ** (j - derivative)
            cx, cy, cz = coef[j]
            x, y, z = x + w * cx, y + w * cy, z + w * cz
        d = self.scale_s ** derivative
        return np.array([x / d, y / d, z / d])

    def omega_at(self, t_s: float) -> np.ndarray:
        """Angular velocity (3,) rad/s of the body relative to the horizontal frame, body axes."""
        t = float(t_s)
        last = self.__dict__.get("_omega_last")     # an epoch asks ~3 times at its time (15 us each)
        if last is not None and last[0] == t:
            return last[1].copy()
        r, rd = self.r(t), self.r(t, 1)
        out = rd - 0.5 * _cross(r, rd)
        object.__setattr__(self, "_omega_last", (t, out))
        return out.copy()

    def alpha_at(self, t_s: float) -> np.ndarray:
        """Angular acceleration (3,) rad/s^2, body axes (derivative of :meth:`omega_at`)."""
        r, rdd = self.r(t_s), self.r(t_s, 2)          # d/dt of rd - r x rd / 2 (rd x rd = 0)
        return rdd - 0.5 * _cross(r, rdd)

    def C_at(self, t_s: float) -> np.ndarray:
        """``C_hor_from_body`` (3, 3) at ``t_s``."""
        return self.C_ref @ expm_rotvec(self.r(t_s))

    def rotation(self, t_from_s: float, t_to_s: float) -> np.ndarray:
        """``Delta`` (3, 3) with ``C(t_to) = C(t_from) @ Delta`` (body axes)."""
        if t_to_s == t_from_s:
            return np.eye(3)
        return expm_rotvec(self.r(t_from_s)).T @ expm_rotvec(self.r(t_to_s))


def fit_motion(t_s, C_hor_from_body, covariance_rad2, *, degree: int = MOTION_DEGREE,
               scale_s: float = MOTION_WINDOW_S) -> MotionFit | None:
    """Fit :class:`MotionFit` to attitudes.

    Parameters
    ----------
    t_s : (N,) array
        Sample times (any order; samples of several sensors may share a time).
    C_hor_from_body : (N, 3, 3) array
    covariance_rad2 : (N, 3, 3) array
        Attitude error covariance about the body axes.
    degree : int
        Polynomial degree; lowered to ``(n_times - 1) // 2`` when fewer distinct sample
        times are given (a session's first frames, after a gap): with 0.1 px centroids a
        fit with one degree of freedom to spare carried the first epochs with errors up
        to 3'', half as many coefficients as samples kept them below 0.8''.
    scale_s : float
        Time unit of the polynomial (conditioning only).

    Returns
    -------
    MotionFit or None
        None with fewer than :data:`MIN_MOTION_SAMPLES` distinct times.
    """
    t = np.ascontiguousarray(t_s, dtype=float).reshape(-1)
    n_times = _n_distinct(t)
    if n_times < MIN_MOTION_SAMPLES:
        return None
    deg = min(int(degree), (n_times - 1) // 2)
    C = np.ascontiguousarray(C_hor_from_body, dtype=float).reshape(-1, 3, 3)
    P = np.ascontiguousarray(covariance_rad2, dtype=float).reshape(-1, 3, 3)
    if C.shape[0] != t.size or P.shape[0] != t.size:
        raise ValueError("fit_motion: t_s, C_hor_from_body and covariance_rad2 must have one row per sample")
    newest = int(np.argmax(t))
    t_ref = float(t[newest])
    coef = np.empty((deg + 1, 3))
    if not (_COMPILED[0] and deg <= 9 and _ckernels.motion_fit(t, C, P, newest, deg, float(scale_s),
                                                                _FLOOR_RAD2, coef)):
        coef = _coefficients_python(t, C, P, newest, deg, scale_s)
    return MotionFit(t_ref, float(scale_s), C[newest].copy(), coef, float(t.min()), t_ref, len(t))


def _n_distinct(t) -> int:
    """``len(np.unique(t))`` of a few sample times (NaNs count as one value, as there), in
    ~1 us against ~10 us."""
    values = t.tolist()
    distinct = {v for v in values if v == v}
    return len(distinct) + (len(distinct) < len(values) and any(v != v for v in values))


#: the sigma floor as a variance (rad^2)
_FLOOR_RAD2 = (SIGMA_FLOOR_ARCSEC * ASEC2RAD) ** 2
#: ``[True]``: :func:`fit_motion`'s normal equations are formed and solved compiled
#: (``shipstar.attitude._ckernels.motion_fit``, Cholesky); the tests set ``[False]`` to run
#: :func:`_coefficients_python`, the reference, which also takes every case the compiled
#: path declines (a singular covariance, a normal matrix too ill-conditioned for Cholesky)
_COMPILED = [True]


def _coefficients_python(t, C, P, newest: int, deg: int, scale_s: float) -> np.ndarray:
    """The polynomial coefficients ``(deg + 1, 3)`` of :func:`fit_motion` in NumPy:
    ``r_k = log(C_newest^T C_k)`` weighted by ``inv(P_k + floor)``, least squares with a
    rank cut (``lstsq``, rcond 1e-13)."""
    C_ref = C[newest]
    r = rotvecs(np.einsum("ji,njk->nik", C_ref, C))                              # log(C_ref^T C_k)
    info = np.linalg.inv(0.5 * (P + np.swapaxes(P, 1, 2)) + _FLOOR_RAD2 * np.eye(3))
    tau = (t - t[newest]) / scale_s
    basis = tau[:, None] ** np.arange(deg + 1)[None, :]                          # (N, D+1)
    m = 3 * (deg + 1)
    normal = np.einsum("ki,kj,kab->iajb", basis, basis, info).reshape(m, m)
    rhs = np.einsum("ki,kab,kb->ia", basis, info, r).reshape(m)
    return np.linalg.lstsq(normal, rhs, rcond=1e-13)[0].reshape(deg + 1, 3)


class MotionWindow:
    """The last :data:`MOTION_WINDOW_S` seconds of one or more sensors' attitudes of a body.

    Samples are added in time order per source; :meth:`fit` fits the samples no later
    than each source's limit and within ``window_s`` of the newest of them.  Old samples
    are dropped by :meth:`prune`, so the memory is bounded by the window.

    Parameters
    ----------
    n_sources : int
        Sensors feeding the window.
    window_s : float
    """

    def __init__(self, n_sources: int = 1, window_s: float = MOTION_WINDOW_S):
        self.window_s = float(window_s)
        self._samples = [deque() for _ in range(n_sources)]      # (t_s, C (3, 3), P (3, 3))

    def add(self, source: int, t_s: float, C_hor_from_body, covariance_rad2) -> None:
        """Add one solved attitude of ``source`` (times increasing per source)."""
        self._samples[source].append((float(t_s), np.asarray(C_hor_from_body, float),
                                      np.asarray(covariance_rad2, float)))

    def prune(self, t_oldest_needed_s: float) -> None:
        """Drop samples older than ``t_oldest_needed_s - window_s``."""
        cut = t_oldest_needed_s - self.window_s - 1e-9
        for q in self._samples:
            while q and q[0][0] < cut:
                q.popleft()

    def __len__(self) -> int:
        return sum(len(q) for q in self._samples)

    def fit(self, limits_s, *, sources=None) -> MotionFit | None:
        """:func:`fit_motion` of the samples at or before ``limits_s[source]`` (one time per
        source, or one float for all) and within ``window_s`` of the newest of them.

        Parameters
        ----------
        limits_s : float or sequence of float
        sources : sequence of int, optional
            Only these sources (default all).
        """
        n = len(self._samples)
        limits = [float(limits_s)] * n if np.ndim(limits_s) == 0 else [float(x) for x in limits_s]
        use = range(n) if sources is None else sources
        # each source's samples are in time order: walk back from the newest (the window
        # may hold more than the fit needs: the engine keeps its smoothing lag's worth)
        newest = -math.inf
        for k in use:
            for smp in reversed(self._samples[k]):
                if smp[0] <= limits[k] + 1e-9:
                    newest = max(newest, smp[0])
                    break
        if newest == -math.inf:
            return None
        oldest = newest - self.window_s - 1e-9
        picked = []
        for k in use:
            part = []
            for smp in reversed(self._samples[k]):
                if smp[0] < oldest:
                    break
                if smp[0] <= limits[k] + 1e-9:
                    part.append(smp)
            picked.extend(reversed(part))              # in time order, as added
        if len(picked) < MIN_MOTION_SAMPLES:
            return None
        return fit_motion([s[0] for s in picked], np.array([s[1] for s in picked]),
                          np.array([s[2] for s in picked]))
