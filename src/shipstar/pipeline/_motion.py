"""Deck angular rate from the frames themselves, to carry a frame to another sensor's time.

Two sensors' exposures are not simultaneous (free-running clocks, or one trigger with a
delay); at sea the deck turns by up to 4 deg/s (5 deg / 8 s roll), i.e. 425'' in 30 ms.
To fuse a frame of sensor B taken at ``t_B`` with the reference sensor's frame at ``t``,
B's attitude is carried over ``t - t_B`` with the deck's angular velocity:

1. each sensor's single-sensor deck attitudes ``C_hor_from_deck(t_k)`` give rates at the
   mid-points of consecutive frames, ``omega = log(C_k^T C_k+1) / dt`` (deck axes; exact
   to second order at the mid-point), with covariance ``(P_k + P_k+1) / dt^2``;
2. at a time ``t`` every sensor's rate is interpolated (quadratic through the three nearest
   mid-points), and the sensors are combined with information weights.  Each sensor alone is weak
   about its boresight (its roll axis); the other sensor's boresight points elsewhere, so
   the combination is good about every axis;
3. the rotation over ``[t_a, t_b]`` is ``exp([omega((t_a + t_b) / 2) (t_b - t_a)] x)``
   in deck axes: ``C_hor_from_deck(t_b) = C_hor_from_deck(t_a) @ Delta``.

For the seeds' sea state and a 30 ms offset the truncation error is ~0.3'' (docs/pipeline.md).

The derivative of the same quadratics, :meth:`DeckRate.alpha_at`, is the deck's angular
acceleration: with the rate it corrects each frame's streak centroids (time averages over
the exposure) to the mid-exposure directions (:mod:`shipstar.pipeline._exposure`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shipstar.pipeline._rotation import expm_rotvec, rotvec

__all__ = ["DeckRate", "estimate_deck_rate"]

#: Consecutive frames further apart (s) give no rate sample.
MAX_RATE_GAP_S = 0.5
#: The rate is extrapolated linearly at most this far (s) beyond the first / last sample.
MAX_EXTRAPOLATION_S = 0.2
#: Half-width (s) of the window of rate samples the angular acceleration is fitted to.
ALPHA_WINDOW_S = 0.3


@dataclass(frozen=True, eq=False)
class _SensorRate:
    t_s: np.ndarray           # (M,) mid-point times
    omega: np.ndarray         # (M, 3) rad/s, deck axes
    info: np.ndarray          # (M, 3, 3) inverse covariance of omega


@dataclass(frozen=True, eq=False)
class DeckRate:
    """The deck's angular velocity relative to the horizontal frame, deck axes.

    Attributes
    ----------
    sensors : tuple of _SensorRate
        Per-sensor rate samples (empty tuple: no samples, rate taken as zero).
    """

    sensors: tuple

    @property
    def available(self) -> bool:
        return any(len(s.t_s) for s in self.sensors)

    def omega_at(self, t_s: float) -> np.ndarray:
        """Combined angular velocity (3,) rad/s at ``t_s``; zeros when no samples."""
        return self._combined(t_s, derivative=False)

    def alpha_at(self, t_s: float) -> np.ndarray:
        """Combined angular acceleration (3,) rad/s^2 at ``t_s`` (deck axes).

        The slope at ``t_s`` of one quadratic in time fitted, weighted by their
        information matrices, to every sensor's rate samples within
        :data:`ALPHA_WINDOW_S` of it (at least the three nearest of each sensor; ``t_s``
        held within :data:`MAX_EXTRAPOLATION_S` of the samples).  The derivative of the
        three-point interpolation of :meth:`omega_at` is several times noisier: in dock
        with 0.1 px centroids and 80 ms exposures its noise made the streak correction
        worsen the joint attitude by 5 %.  The window's truncation error,
        ``(d3 omega / dt3) sum(t^4) / (6 sum(t^2))``, is 0.4 % of the acceleration for the
        seeds' 8 s roll period and 1.4 % for a 4 s one.  Zeros without samples; the
        derivative of :meth:`omega_at` when no sensor has three samples.
        """
        rows = [s for s in self.sensors if len(s.t_s) >= 3]
        if not rows:
            return self._combined(t_s, derivative=True)
        lo = min(s.t_s[0] for s in rows) - MAX_EXTRAPOLATION_S
        hi = max(s.t_s[-1] for s in rows) + MAX_EXTRAPOLATION_S
        t = min(max(float(t_s), lo), hi)
        normal, rhs = np.zeros((9, 9)), np.zeros(9)
        for s in rows:
            near = np.abs(s.t_s - t)
            pick = near <= max(ALPHA_WINDOW_S, np.partition(near, 2)[2])
            tau = (s.t_s[pick] - t) / ALPHA_WINDOW_S                        # scaled for conditioning
            basis = np.stack([np.ones_like(tau), tau, tau * tau], axis=1)                  # (K, 3)
            info = s.info[pick]                                                            # (K, 3, 3)
            normal += np.einsum("ki,kj,kab->iajb", basis, basis, info).reshape(9, 9)
            rhs += np.einsum("ki,kab,kb->ia", basis, info, s.omega[pick]).reshape(9)
        coef = np.linalg.lstsq(normal, rhs, rcond=1e-12)[0]
        return coef[3:6] / ALPHA_WINDOW_S

    def _combined(self, t_s: float, derivative: bool) -> np.ndarray:
        A, b = np.zeros((3, 3)), np.zeros(3)
        for s in self.sensors:
            if len(s.t_s) == 0:
                continue
            w = _interp_quadratic(t_s, s.t_s, s.omega, derivative=derivative)
            i = int(np.argmin(np.abs(s.t_s - t_s)))
            A += s.info[i]
            b += s.info[i] @ w
        if not np.any(A):
            return np.zeros(3)
        return np.linalg.lstsq(A, b, rcond=1e-12)[0]

    def rotation(self, t_from_s: float, t_to_s: float) -> np.ndarray:
        """``Delta`` (3, 3) with ``C_hor_from_deck(t_to) = C_hor_from_deck(t_from) @ Delta``."""
        dt = t_to_s - t_from_s
        if dt == 0.0:
            return np.eye(3)
        return expm_rotvec(self.omega_at(0.5 * (t_from_s + t_to_s)) * dt)


def _interp_quadratic(t: float, ts: np.ndarray, values: np.ndarray, derivative: bool = False) -> np.ndarray:
    """Quadratic (Lagrange) interpolation of ``values`` (M, 3) through the three samples
    nearest ``t``, extrapolated at most :data:`MAX_EXTRAPOLATION_S` beyond the ends; with
    ``derivative`` its time derivative there (linear with two samples, zero with one).

    At sea the rate changes by ~3 deg/s^2 with a curvature of ~2.4 deg/s^3: linear
    interpolation between samples 0.1 s apart would be wrong by up to 5e-5 rad/s inside
    and 4e-4 rad/s just past the ends (1.4'' over a 30 ms carry); the quadratic by < 2e-5.
    """
    n = len(ts)
    if n == 1:
        return np.zeros(3) if derivative else values[0].copy()
    t = min(max(t, ts[0] - MAX_EXTRAPOLATION_S), ts[-1] + MAX_EXTRAPOLATION_S)
    if n == 2:
        if derivative:
            return (values[1] - values[0]) / (ts[1] - ts[0])
        f = (t - ts[0]) / (ts[1] - ts[0])
        return (1.0 - f) * values[0] + f * values[1]
    k = int(np.clip(np.searchsorted(ts, t) - 1, 0, n - 2))         # ts[k] <= t < ts[k+1] inside
    lo = k - 1 if (k + 2 >= n or (k >= 1 and t - ts[k - 1] < ts[k + 2] - t)) else k
    lo = int(np.clip(lo, 0, n - 3))
    x0, x1, x2 = ts[lo:lo + 3]
    d0, d1, d2 = (x0 - x1) * (x0 - x2), (x1 - x0) * (x1 - x2), (x2 - x0) * (x2 - x1)
    if derivative:
        L = np.array([(2.0 * t - x1 - x2) / d0, (2.0 * t - x0 - x2) / d1, (2.0 * t - x0 - x1) / d2])
    else:
        L = np.array([(t - x1) * (t - x2) / d0, (t - x0) * (t - x2) / d1, (t - x0) * (t - x1) / d2])
    return L @ values[lo:lo + 3]


def _sensor_rate(t_s: np.ndarray, C_hd: np.ndarray, cov: np.ndarray) -> _SensorRate:
    ts, om, info = [], [], []
    for k in range(len(t_s) - 1):
        dt = t_s[k + 1] - t_s[k]
        if not 0.0 < dt <= MAX_RATE_GAP_S:
            continue
        ts.append(0.5 * (t_s[k] + t_s[k + 1]))
        om.append(rotvec(C_hd[k].T @ C_hd[k + 1]) / dt)
        P = (cov[k] + cov[k + 1]) / dt ** 2
        info.append(np.linalg.pinv(0.5 * (P + P.T), rcond=1e-12, hermitian=True))
    if not ts:
        return _SensorRate(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3, 3)))
    return _SensorRate(np.array(ts), np.array(om), np.array(info))


def estimate_deck_rate(samples) -> DeckRate:
    """Deck rate from each sensor's solved single-sensor deck attitudes.

    Parameters
    ----------
    samples : iterable of (t_s (M,), C_hor_from_deck (M, 3, 3), covariance_deck_rad2 (M, 3, 3))
        One entry per sensor, solved frames only, in time order; the covariance is the
        attitude error about the DECK axes (``C_ds P_sensor C_ds^T``).

    Returns
    -------
    DeckRate
    """
    rates = []
    for t_s, C_hd, cov in samples:
        t_s = np.asarray(t_s, float)
        rates.append(_sensor_rate(t_s, np.asarray(C_hd, float).reshape(-1, 3, 3),
                                  np.asarray(cov, float).reshape(-1, 3, 3)))
    return DeckRate(tuple(rates))
