"""Integrity monitoring: the sensors' deck attitudes checked against each other every epoch.

As a GNSS receiver checks its satellites against each other (RAIM), each epoch's
single-sensor deck attitudes ``C_k`` (carried to the epoch time, covariance ``P_k`` about
the deck axes from the sensor's attitude covariance) must agree within their combined
uncertainty.  The test statistic is

    chi2 = sum_k d_k^T Q_k^-1 d_k,   d_k = log(C_mean^T C_k),   Q_k = P_k + s_k^2 I

with ``C_mean`` the information-weighted mean attitude; for two sensors it is
``D^T (Q_1 + Q_2)^-1 D`` with ``D = log(C_1^T C_2)``.  It has ``3 (n - 1)`` degrees of
freedom for ``n`` solved sensors.  ``s_k`` is what the formal covariance does not hold:
:data:`MODEL_SIGMA_ARCSEC` (the carry between exposure times, the formal sigmas' own
error) and the sensor's installation calibration sem, in quadrature.  The epoch is
*inconsistent* when ``chi2`` exceeds the quantile of the chi-square distribution at the
false-alarm probability :data:`FALSE_ALARM_PROBABILITY` (30.66 for two sensors).

Which sensor does not fit:

- three or more sensors: leave one out; the sensor whose removal leaves the smallest
  chi2 (per degree of freedom) is named;
- two sensors: a disagreement says one of them is wrong, not which.  shipstar names the
  one whose deck attitude lies further from the weighted mean in its own uncertainty
  (``d_k^T Q_k^-1 d_k`` larger): the sensor the combined solution trusts less in the
  direction of the disagreement.  A steady disagreement (an installation off, a sensor
  moved on its mount) is therefore attributed to the less certain sensor; check both.

:func:`swap_check`: a sensor whose frames fit another installation better (two sensors'
frame folders swapped, no ``SENSOR`` header to catch it) is refused at the start of
``shipstar measure`` from the first frames that solve.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from shipstar.units import ASEC2RAD, RAD2ASEC

__all__ = ["Integrity", "check_integrity", "chi2_limit", "FALSE_ALARM_PROBABILITY", "MODEL_SIGMA_ARCSEC",
           "swap_check", "SWAP_MIN_ARCSEC", "SWAP_RATIO"]

#: Probability that an epoch whose sensors agree (errors as their covariances say) is
#: marked inconsistent: one epoch in a million (0.04 a night of 10 h at 10 epochs/s).
FALSE_ALARM_PROBABILITY = 1e-6
#: Added in quadrature (per deck axis) to each sensor's formal attitude covariance: the
#: carry between the sensors' exposure times (< 0.1'' at the seeds' sea state), the
#: formal sigmas' own error (within 35 %), streak residuals.
MODEL_SIGMA_ARCSEC = 1.0
#: Swapped folders: the given assignment's disagreement must exceed the swapped one's by
#: this factor and by :data:`SWAP_MIN_ARCSEC` (paired first frames up to 0.06 s apart
#: differ by up to 860'' at 4 deg/s; swapped sensors by tens of degrees).
SWAP_RATIO = 3.0
SWAP_MIN_ARCSEC = 3600.0


@functools.lru_cache(maxsize=None)
def chi2_limit(dof: int, p: float = FALSE_ALARM_PROBABILITY) -> float:
    """The chi-square quantile exceeded with probability ``p`` (``dof`` degrees of freedom)."""
    return _chi2_limit(int(dof), float(p))


@functools.lru_cache(maxsize=256)
def _chi2_limit(dof: int, p: float) -> float:
    # a few (dof, p) pairs, asked for every epoch: cached.  Integer dof (every caller's) by
    # the closed form below, not scipy.special.chdtri: importing scipy.special costs ~0.2 s
    # of CPU at the engine's start (measure, measure-archive's client, live); the two agree
    # to ~1e-15 (tests/test_limits.py)
    if dof >= 1 and 0.0 < p < 1.0:
        return chi2_isf_int(dof, p)
    from scipy.special import chdtri

    return float(chdtri(dof, p))


def chi2_sf_int(x: float, dof: int) -> float:
    """Survival function ``P(chi2_dof > x)`` for an integer ``dof >= 1`` (closed form).

    Even ``dof``: ``exp(-x/2) sum_{i < dof/2} (x/2)^i / i!``; odd: ``erfc(sqrt(x/2))`` plus
    ``exp(-x/2) sum_{i < (dof-1)/2} (x/2)^(i+1/2) / Gamma(i+3/2)``.  Every term is positive:
    the relative error stays near machine precision far into the tail.
    """
    if x <= 0.0:
        return 1.0
    h = 0.5 * x
    e = math.exp(-h)
    if dof % 2 == 0:
        term, total = 1.0, 1.0
        for i in range(1, dof // 2):
            term *= h / i
            total += term
        return e * total
    total = math.erfc(math.sqrt(h))
    term = math.sqrt(h) / math.gamma(1.5)          # (x/2)^(1/2) / Gamma(3/2)
    for i in range((dof - 1) // 2):
        if i:
            term *= h / (i + 0.5)
        total += e * term
    return total


def chi2_isf_int(dof: int, p: float) -> float:
    """The chi-square quantile exceeded with probability ``p`` (integer ``dof >= 1``, ``0 < p < 1``):
    Newton's method on ``log sf`` from the Wilson-Hilferty start, to machine precision."""
    k = float(dof)
    # Wilson-Hilferty: chi2/k ~ normal cube; z from a rational approximation of the normal quantile
    z = _norm_isf(p)
    x = k * max(1e-3, 1.0 - 2.0 / (9.0 * k) + z * math.sqrt(2.0 / (9.0 * k))) ** 3
    log_p = math.log(p)
    log_norm = (0.5 * k) * math.log(2.0) + math.lgamma(0.5 * k)
    for _ in range(100):
        sf = chi2_sf_int(x, dof)
        if sf <= 0.0:                              # far past the quantile: halve towards 0
            x *= 0.5
            continue
        log_pdf = (0.5 * k - 1.0) * math.log(x) - 0.5 * x - log_norm
        step = (math.log(sf) - log_p) * sf / math.exp(log_pdf)     # f / -f' of log sf - log p
        x_new = x + step
        if x_new <= 0.0:
            x_new = 0.5 * x
        if abs(x_new - x) <= 4e-16 * x:
            return x_new
        x = x_new
    return x


def _norm_isf(p: float) -> float:
    """The standard normal quantile exceeded with probability ``p`` (a start only: ~1e-3)."""
    q = min(p, 1.0 - p)
    t = math.sqrt(-2.0 * math.log(q))
    z = t - (2.515517 + 0.802853 * t + 0.010328 * t * t) / (1.0 + 1.432788 * t + 0.189269 * t * t
                                                           + 0.001308 * t ** 3)
    return z if p < 0.5 else -z


@dataclass(frozen=True)
class Integrity:
    """The consistency of one epoch's sensors.

    Attributes
    ----------
    checked : bool
        Two or more sensors solved at the epoch.
    chi2, limit : float
        Test statistic and its threshold (NaN when not checked).
    dof : int
    consistent : bool
        Not checked, or chi2 within the limit.
    suspect : str
        The sensor that does not fit ('' when consistent).
    disagreement_arcsec : float
        Largest angle between a sensor's deck attitude and the weighted mean.
    """

    checked: bool = False
    chi2: float = math.nan
    limit: float = math.nan
    dof: int = 0
    consistent: bool = True
    suspect: str = ""
    disagreement_arcsec: float = math.nan

    @property
    def label(self) -> str:
        """``''`` (not checked), ``'ok'`` or ``'inconsistent'`` (the CSV's ``integrity``)."""
        return "" if not self.checked else "ok" if self.consistent else "inconsistent"


def _log(C) -> np.ndarray:
    from shipstar.pipeline._motion import rotvec

    return rotvec(C)


def _weighted(Cs, infos):
    """``(d_k (n, 3), chi2_k (n,))`` about the information-weighted mean of ``Cs``."""
    from shipstar.pipeline._motion import expm_rotvec

    C0 = Cs[0]
    r = np.array([_log(C0.T @ C) for C in Cs])
    r_mean = np.linalg.solve(sum(infos), sum(I @ x for I, x in zip(infos, r)))
    C_mean = C0 @ expm_rotvec(r_mean)
    d = np.array([_log(C_mean.T @ C) for C in Cs])
    return d, np.array([x @ I @ x for x, I in zip(d, infos)])


#: check_integrity's weighted mean and chi2 compiled (``attitude._ckernels.integrity``);
#: ``[False]``: the NumPy path, the tests' reference.
_COMPILED = [True]


def _infos(C_hor_from_deck, covariance_deck_rad2, model_sigma_arcsec):
    """``(Cs, infos)``: the attitudes and ``inv(sym(P) + s^2 I)``; infos None when a
    covariance is not finite."""
    Cs = [np.asarray(C, float) for C in C_hor_from_deck]
    infos = []
    for P, s in zip(covariance_deck_rad2, model_sigma_arcsec):
        Q = np.asarray(P, float)
        Q = 0.5 * (Q + Q.T) + (float(s) * ASEC2RAD) ** 2 * np.eye(3)
        if not np.isfinite(Q).all():
            return Cs, None
        infos.append(np.linalg.inv(Q))
    return Cs, infos


def _compiled(C_hor_from_deck, covariance_deck_rad2, model_sigma_arcsec):
    """``(d (n, 3), chi2_k (n,))`` of :func:`_weighted` by the compiled kernel, ``"unchecked"``
    when a covariance is not finite, None when a matrix is singular there (or too many
    sensors): the NumPy path decides."""
    from shipstar.attitude._ckernels import integrity

    n = len(model_sigma_arcsec)
    if n > 16:
        return None
    C = np.ascontiguousarray(np.asarray(C_hor_from_deck, float).reshape(n, 3, 3))
    P = np.ascontiguousarray(np.asarray(covariance_deck_rad2, float).reshape(n, 3, 3))
    floor = np.array([(float(s) * ASEC2RAD) ** 2 for s in model_sigma_arcsec])
    d, chi2_k = np.empty((n, 3)), np.empty(n)
    ok = integrity(C, P, floor, d, chi2_k)
    return (d, chi2_k) if ok == 1 else "unchecked" if ok == -1 else None


def check_integrity(names, C_hor_from_deck, covariance_deck_rad2, model_sigma_arcsec=None,
                    p: float = FALSE_ALARM_PROBABILITY) -> Integrity:
    """Check the solved sensors' deck attitudes of one epoch against each other.

    Parameters
    ----------
    names : sequence of str
        The solved sensors.
    C_hor_from_deck : sequence of (3, 3) arrays
        Each sensor's deck attitude at the epoch time.
    covariance_deck_rad2 : sequence of (3, 3) arrays
        Their covariances about the deck axes.
    model_sigma_arcsec : sequence of float, optional
        Per sensor, added in quadrature about every axis (default
        :data:`MODEL_SIGMA_ARCSEC`).
    p : float
        False-alarm probability.
    """
    n = len(names)
    if n < 2:
        return Integrity()
    if model_sigma_arcsec is None:
        model_sigma_arcsec = [MODEL_SIGMA_ARCSEC] * n
    got = _compiled(C_hor_from_deck, covariance_deck_rad2, model_sigma_arcsec) if _COMPILED[0] else None
    if got == "unchecked":
        return Integrity()
    if got is None:                          # the reference path (and any singular matrix)
        Cs, infos = _infos(C_hor_from_deck, covariance_deck_rad2, model_sigma_arcsec)
        if infos is None:
            return Integrity()
        d, chi2_k = _weighted(Cs, infos)
    else:
        d, chi2_k = got
    chi2 = float(chi2_k.sum())
    dof = 3 * (n - 1)
    limit = chi2_limit(dof, p)
    worst = float(np.max(np.linalg.norm(d, axis=1))) * RAD2ASEC
    if chi2 <= limit:
        return Integrity(True, chi2, limit, dof, True, "", worst)
    if n == 2:
        suspect = names[int(np.argmax(chi2_k))]
    else:
        Cs, infos = _infos(C_hor_from_deck, covariance_deck_rad2, model_sigma_arcsec)
        left = []
        for k in range(n):
            keep = [j for j in range(n) if j != k]
            _, c = _weighted([Cs[j] for j in keep], [infos[j] for j in keep])
            left.append(float(c.sum()))
        suspect = names[int(np.argmin(left))]
    return Integrity(True, chi2, limit, dof, False, suspect, worst)


def installation_sigma_arcsec(installation) -> float:
    """:data:`MODEL_SIGMA_ARCSEC` and the installation's largest finite sem, in quadrature."""
    sems = [float(s) for s in getattr(installation, "sem_arcsec", ()) if math.isfinite(float(s))]
    return math.hypot(MODEL_SIGMA_ARCSEC, max(sems, default=0.0))


def epoch_integrity(configs, paired, singles) -> Integrity:
    """:func:`check_integrity` of an epoch's solved, carried single-sensor attitudes."""
    names, Cs, Ps, sig = [], [], [], []
    for c, fr, att in zip(configs, paired, singles):
        if fr is None or not att.solved or c.installation is None or fr.horizontal is None:
            continue
        C_ds = c.installation.C_deck_from_sensor
        names.append(c.name)
        Cs.append(att.C_hor_from_deck)
        Ps.append(C_ds @ np.asarray(fr.horizontal.covariance_rad2, float) @ C_ds.T)
        sig.append(installation_sigma_arcsec(c.installation))
    return check_integrity(names, Cs, Ps, sig)


# -- swapped frame folders --------------------------------------------------------------------

def _angle_arcsec(C_a, C_b) -> float:
    return float(np.linalg.norm(_log(np.asarray(C_a).T @ np.asarray(C_b)))) * RAD2ASEC


def swap_check(configs, sources, track, weather, options, *, max_frames: int = 5):
    """``None``, or a one-line message when two sensors' frames fit each other's installation
    much better than their own (frame folders swapped).

    From the first ``max_frames`` frames of each sensor, the first pair of frames (same
    position in each sensor's sequence, at most ``options.max_pair_offset_s`` apart) that
    solves is processed with each of the two sensors' cameras and installations: ``X`` is
    the angle between the two deck attitudes as given, ``Y`` the same with the two sensors'
    configurations exchanged.  Refused when ``X > SWAP_RATIO * Y`` and
    ``X - Y > SWAP_MIN_ARCSEC`` (or the given assignment does not solve and the exchanged
    one does and agrees within ``SWAP_MIN_ARCSEC``).
    """
    from shipstar.pipeline._sensor import SensorProcessor

    n = len(configs)
    if n < 2 or any(c.installation is None for c in configs):
        return None
    frames = [src.piece(0, min(max_frames, len(src))).load() for src in sources]
    cache: dict = {}
    # a frame's attitude in the horizontal frame depends on the camera, not on the
    # installation (a fresh processor's first frame has no motion fit to correct its
    # streaks with): sensors of the same camera model share one solve of each frame
    camera_of = [next(m for m in range(n) if configs[m].camera == configs[j].camera) for j in range(n)]

    def deck(i: int, j: int, k: int):
        """Sensor i's k-th frame processed as sensor j: C_hor_from_deck or None."""
        key = (i, camera_of[j], k)
        if key not in cache:
            proc = SensorProcessor(configs[camera_of[j]], track, weather, options)
            fr = proc.process(frames[i][k], k, 0.0)
            cache[key] = fr.horizontal.C_hor_from_sensor if fr.solved and fr.horizontal is not None else None
        C_hor_from_sensor = cache[key]
        return (None if C_hor_from_sensor is None
                else C_hor_from_sensor @ configs[j].installation.C_deck_from_sensor.T)     # hor <- deck

    for a in range(n):
        for b in range(a + 1, n):
            for k in range(min(len(frames[a]), len(frames[b]))):
                fa, fb = frames[a][k], frames[b][k]
                dt = abs(((fa.utc_jd1 - fb.utc_jd1) + (fa.utc_jd2 - fb.utc_jd2)) * 86400.0)
                if dt > options.max_pair_offset_s + 1e-9:
                    break
                ya, yb = deck(a, b, k), deck(b, a, k)
                if ya is None or yb is None:
                    continue
                Y = _angle_arcsec(ya, yb)
                xa, xb = deck(a, a, k), deck(b, b, k)
                X = _angle_arcsec(xa, xb) if xa is not None and xb is not None else math.inf
                A, B = configs[a].name, configs[b].name
                if X > SWAP_RATIO * Y and X - Y > SWAP_MIN_ARCSEC and (math.isfinite(X) or Y < SWAP_MIN_ARCSEC):
                    x_text = "no solution" if not math.isfinite(X) else f"{X:.0f}''"
                    return (f"sensor folders look swapped: {A}'s frames fit {B}'s installation and {B}'s fit "
                            f"{A}'s (disagreement {x_text} as given vs {Y:.0f}'' exchanged, frame "
                            f"{fa.label} / {fb.label}): check the --sensor NAME=DIR pairs")
                if xa is not None and xb is not None:
                    break
            # one pair checked (or none solved) for these two sensors
    return None
