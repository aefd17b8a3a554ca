"""Clock offsets and hull flexure, estimated from the sensors' own disagreement (issue 14).

At each epoch where the reference sensor (``--reference``) and another sensor ``B`` both
solved, the engine carries ``B``'s deck attitude to the epoch time and the two deck
attitudes should agree.  They do not when

- ``B``'s clock is off: its exposures really happen ``delta`` later than its headers say
  (``delta`` = true exposure time minus header time, s), so its frame is carried from the
  wrong time and its deck attitude is the deck's at ``t + delta``:
  ``C_B = C(t) exp([omega delta] x)``, ``omega`` the deck's angular velocity (deck axes);
- ``B``'s mount has turned relative to the reference mount by the small rotation
  ``phi`` (deck axes bow / up / starboard) beyond what the installation files give: the
  simulator's ``C_deck_from_sensor(t) = Exp([phi] x) C_deck_from_sensor`` gives
  ``C_B = C(t) Exp([phi] x)``.

So the disagreement ``d = log(C_ref^T C_B)`` (deck axes) is, to first order,

    d_k = phi(t_k) + omega_k delta + e_k,     phi(t) = s + G a(t)

with ``s`` (3) the static (slowly drifting) rotation of the mount, ``a = (roll, pitch)``
(deg) the deck's roll and pitch from the reference sensor (the wave-period part of the
flexure: the hull bends with the wave loads, whose rotation follows the ship's roll and
pitch angles) and ``G`` (3 x 2) its gains, and ``e_k`` the two sensors' attitude errors
(their covariances about the deck axes plus :data:`MODEL_SIGMA_ARCSEC` each, as in the
integrity check).  Angle and rate of a sinusoidal roll are in quadrature, so the clock
term and the wave flexure separate; a flexure in phase with the deck's *rate* would be
taken for a clock offset on that axis (the three axes' rates have different periods, so
one ``delta`` must fit all three).

The 10 parameters ``(s, G, delta)`` are a running weighted least-squares solution
(normal equations accumulated epoch by epoch, causal, forgetting with the time constant
:data:`MEMORY_S` so a thermal drift is followed; an epoch whose disagreement lies beyond
the chi-square gate of the prediction is not used).  The formal covariance is scaled by
the residuals' chi2 per degree of freedom when above 1.

What is applied (the rules):

- **clock**: once :data:`MIN_EPOCHS` epochs are in and ``sigma <= MAX_APPLY_SIGMA_S`` and
  ``|delta| > ENTER_SIGMAS sigma`` (5: the running estimate is looked at every epoch, so
  3 sigma would be crossed by chance in a long night), ``B``'s frame times are shifted by
  ``delta`` (the engine's pairing, motion window and carry use ``header time + delta``);
  it stays applied while ``|delta| > STAY_SIGMAS sigma`` (3);
- **flexure**: once :data:`MIN_EPOCHS` epochs are in and the 9 flexure parameters differ
  from 0 beyond the chi-square quantile at 1e-6 (stay: 1e-2), ``B``'s installation in the
  epoch's fusion (seed rule, joint solution, integrity) is ``Exp([phi_k] x) C_deck_from_sensor``
  with ``phi_k = s + G a_k`` from the epochs before (a_k: this epoch's reference roll and
  pitch).  The joint attitude then refers to the reference sensor's mount.  The estimate's
  uncertainty ``Phi = X cov X^T`` goes with it (``mount_covariance_rad2`` of the flexed
  installation): ``B``'s single attitude in the fusion has ``S_B + Phi``, and the joint
  solution eliminates ``B``'s mount error as a nuisance rotation
  (:func:`shipstar.ship._with_mount_errors`), so a poorly known mount weighs little.

How far the stated sigmas are to be trusted, from the same disagreements:

- the fit's covariance is scaled by its residuals' chi2 per degree of freedom (when above 1)
  and by ``(1 + rho) / (1 - rho)``, ``rho`` the lag-1 correlation of successive epochs'
  whitened innovations (seeing with a correlation time, a slowly changing star field: errors
  that do not average down as white noise would, :meth:`_Track.correlation_factor`);
- the **variance factor** (:meth:`MountEstimator.variance_factor`): the mean chi2 of the
  innovations per degree of freedom over the last :data:`VARIANCE_MEMORY_S` seconds.  When
  it exceeds 1 beyond chance the sensors disagree by more than their stars' sigmas say (a
  sparse, moonlit, clouded sky whose star errors the residuals do not show), and the engine
  multiplies both sensors' star covariances by it in the next epoch's fusion.  Two sensors
  cannot say which of them is optimistic, nor about an axis that only one of them measures
  well; the factor is never below 1.

Without a clock offset or flexure nothing is applied (the rows are those of a rigid deck).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.units import ASEC2RAD, RAD2ASEC, RAD2DEG

__all__ = ["MountEstimator", "MountsSnapshot", "MONITOR_COLUMNS", "MEMORY_S", "MIN_EPOCHS", "is_flexed"]

#: Forgetting time constant of the running least squares (s): a thermal drift of 10'' a
#: day moves by < 0.1'' within it; the clock offset's memory is 6000 epochs.
MEMORY_S = 600.0
#: Spread (1 sigma) of the deck's roll or pitch below which no wave gain is fitted on it (deg):
#: 180'', 50 times the weakest single-sensor roll noise, so that noise biases a gain by < 0.1 %.
MIN_WAVE_STD_DEG = 0.05
#: Epochs before anything is applied (3 s at 10 epochs/s: most of half a roll period).
MIN_EPOCHS = 30
#: Epochs before the monitor gives numbers (10 parameters).
MIN_MONITOR_EPOCHS = 12
#: Added per sensor and axis to the formal covariance (arcsec), as in the integrity check.
MODEL_SIGMA_ARCSEC = 1.0
#: Clock application: sigmas to enter and to stay applied; the largest sigma applied (s).
ENTER_SIGMAS, STAY_SIGMAS = 5.0, 3.0
MAX_APPLY_SIGMA_S = 5e-4
#: Flexure application: false-alarm probabilities to enter / to stay (9 dof).
ENTER_P, STAY_P = 1e-6, 1e-2
#: An epoch whose disagreement's chi2 (3 dof) against the prediction exceeds this is not used.
GATE_CHI2 = 30.0
#: A wave-gain group (an angle's three gains) enters the model when it differs from 0 beyond
#: the chi-square quantile (3 dof) at this false-alarm probability, and stays while beyond
#: the second (hysteresis: the running fit is tested every epoch).
GAIN_ENTER_P, GAIN_STAY_P = 1e-3, 1e-2
#: Epochs further apart than this (s) are not consecutive for the innovations' correlation.
MAX_LAG_S = 0.25
#: The largest lag-1 correlation of the innovations taken (a factor of 9 on the variance).
MAX_RHO = 0.8
#: Memory (s, forgetting time constant) of the a posteriori variance factor: the sky changes
#: (cloud, the Moon) within a minute, and 10 s hold ~300 degrees of freedom at 10 epochs/s.
VARIANCE_MEMORY_S = 10.0
#: The factor is applied when above ``1 + VARIANCE_SIGMAS sqrt(2 / dof)``: chance (3 sigma of
#: chi2's spread) does not inflate honest sigmas, so a clean night keeps its rows.
VARIANCE_SIGMAS = 3.0

MONITOR_COLUMNS = ("time_utc", "sensor", "rot_bow_arcsec", "rot_up_arcsec", "rot_starboard_arcsec",
                   "sigma_bow_arcsec", "sigma_up_arcsec", "sigma_starboard_arcsec")
_AXES = ("bow", "up", "starboard")
_NP = 10                     # s (3), G (3 x 2, column-major: roll then pitch), delta (ms)
_GAIN_COLS = (slice(3, 6), slice(6, 9))


def _num(x):
    x = float(x)
    return x if math.isfinite(x) else None


class _FlexedInstallation:
    """An installation with its mount turned: ``C_deck_from_sensor = Exp([phi] x) C``, and
    the uncertainty of ``phi``; every other attribute is the original's."""

    def __init__(self, installation, C_deck_from_sensor, mount_covariance_rad2):
        self._inst = installation
        self.C_deck_from_sensor = C_deck_from_sensor
        #: (3, 3) deck axes, rad^2: the uncertainty of the flexure estimate applied
        self.mount_covariance_rad2 = mount_covariance_rad2

    def __getattr__(self, name):
        return getattr(self._inst, name)


def is_flexed(config) -> bool:
    """Whether a sensor config carries a flexed installation (:meth:`MountEstimator.configs_for`)."""
    return isinstance(config.installation, _FlexedInstallation)


@dataclass(frozen=True, eq=False)
class MountsSnapshot:
    """The estimates after one epoch (``Epoch.mounts``).

    Attributes
    ----------
    monitor : tuple of (sensor, rot_arcsec (3,), sigma_arcsec (3,))
        The smoothed relative attitude of each non-reference mount at the epoch (deck
        axes bow / up / starboard; NaN before :data:`MIN_MONITOR_EPOCHS` epochs).  None
        only inside the engine, while an epoch is held for the smoothing (it is set at the
        epoch's release).
    time_offsets_s : dict
        ``{sensor: {"offset_s", "sigma_s", "applied"}}`` (the summary's ``time_offsets_s``).
    flexure : dict
        ``{sensor: {...}}`` (the summary's ``flexure``; a property, built on first read
        from ``flexure_source``: the dict, or a callable that gives it).
    """

    monitor: tuple
    time_offsets_s: dict
    #: the flexure dict, or a callable that builds it (:class:`_FlexureLater`) when read
    flexure_source: object

    @property
    def flexure(self) -> dict:
        f = self.flexure_source
        if callable(f):
            f = f()
            object.__setattr__(self, "flexure_source", f)
        return f


class _FlexureLater:
    """The summary's flexure entries of an epoch, built when read: the tracks' state at the
    epoch is kept (a shallow copy with the arrays the later epochs change in place copied),
    not the ~50 us an epoch of building every entry that is never read (the summary reads
    the last epoch's)."""

    def __init__(self, entries):
        self._entries = [(name, _frozen_track(tr), sems) for name, tr, sems in entries]

    def __call__(self) -> dict:
        return {name: tr.flexure_block(sems) for name, tr, sems in self._entries}


def _frozen_track(tr):
    import copy

    out = copy.copy(tr)
    out.a_sum, out.aa_sum, out.uu_lag = tr.a_sum.copy(), tr.aa_sum.copy(), tr.uu_lag.copy()
    out.gains_used = list(tr.gains_used)
    return out


_DESIGN_EYE = np.hstack([np.eye(3), np.zeros((3, _NP - 3))])
_I3 = np.arange(3)


def _design(a_deg, omega_asec_per_ms) -> np.ndarray:
    """(3, 10) regressors of one epoch: s, G (roll, pitch), delta (ms)."""
    X = _DESIGN_EYE.copy()
    X[_I3, _I3 + 3] = a_deg[0]
    X[_I3, _I3 + 6] = a_deg[1]
    X[:, 9] = omega_asec_per_ms
    return X


#: The compiled step of :class:`_Track` (``[False]``: the Python path, the tests' reference).
_COMPILED = [True]
_ZERO3 = np.zeros(3)
#: mount_step's constants, in its order.
_TRACK_PARAMS = np.array([MEMORY_S, MIN_MONITOR_EPOCHS, GATE_CHI2, MIN_EPOCHS, MAX_LAG_S, MAX_RHO, VARIANCE_MEMORY_S,
                          MIN_WAVE_STD_DEG, ENTER_SIGMAS, STAY_SIGMAS, MAX_APPLY_SIGMA_S], dtype=np.float64)
@functools.cache
def _track_limits() -> np.ndarray:
    """mount_step's chi-square limits: the gain groups' (3 dof) to stay and to enter, then
    the flexure's to stay and to enter for 0..9 dof (0 unused)."""
    from shipstar.pipeline._integrity import chi2_limit

    stay = [0.0] + [chi2_limit(k, STAY_P) for k in range(1, 10)]
    enter = [0.0] + [chi2_limit(k, ENTER_P) for k in range(1, 10)]
    return np.array([chi2_limit(3, GAIN_STAY_P), chi2_limit(3, GAIN_ENTER_P), *stay, *enter])


class _Track:
    """Running weighted least squares of one non-reference sensor."""

    def __init__(self):
        self.N = np.zeros((_NP, _NP))
        self.b = np.zeros(_NP)
        self.yy = 0.0
        self.n_eff = 0.0                  # forgetting-weighted epochs
        self.n = 0                        # epochs used
        self.n_gated = 0
        self.t_last = None
        self.a_sum = np.zeros(2)          # forgetting-weighted moments of the angles (deg)
        self.aa_sum = np.zeros((2, 2))
        self.theta = np.full(_NP, math.nan)       # the model in use (gain groups selected)
        self.cov = np.full((_NP, _NP), math.nan)
        self.theta_full = np.full(_NP, math.nan)  # every active parameter
        self.cov_full = np.full((_NP, _NP), math.nan)
        self.clock_applied = False
        self.flex_applied = False
        self.u_prev, self.t_prev = None, None   # the last whitened innovation and its time
        self.uu_lag = np.zeros(2)               # forgetting sums of u_k . u_k-1 and |u_k|^2
        self.vf_chi2 = 0.0                # forgetting sums of the innovations' chi2 and epochs
        self.vf_n = 0.0
        self.vf_t = None
        self.gains_used = [False, False]  # the roll and the pitch wave gains in the model
        self.keep = np.ones(_NP, bool)    # the parameters of the fit in use

    def state(self) -> dict:
        """Every attribute, JSON-able (arrays as ``{"nd": list, "dtype": str}``; floats
        round-trip exactly through JSON)."""
        return {k: ({"nd": v.tolist(), "dtype": str(v.dtype)} if isinstance(v, np.ndarray) else
                    list(v) if isinstance(v, list) else v) for k, v in vars(self).items()}

    @classmethod
    def from_state(cls, state: dict) -> "_Track":
        tr = cls()
        for k, v in state.items():
            if k not in vars(tr):
                raise ShipstarError(f"the mounts' estimator state has an unknown entry {k!r}")
            setattr(tr, k, np.array(v["nd"], dtype=v["dtype"]) if isinstance(v, dict) else
                    list(v) if isinstance(v, list) else v)
        return tr

    def active(self) -> np.ndarray:
        """The parameters estimated: the wave gains of an angle only while it spreads by more
        than :data:`MIN_WAVE_STD_DEG` (the angles are the reference sensor's own measurements:
        in dock their spread is mostly that sensor's noise, which is also in the
        disagreement, and a gain fitted on it is spurious -- errors in the variables)."""
        keep = np.ones(_NP, bool)
        if self.n_eff > 0:
            m = self.a_sum / self.n_eff
            var = np.diag(self.aa_sum / self.n_eff) - m * m
        else:
            var = np.zeros(2)
        for j, cols in enumerate((slice(3, 6), slice(6, 9))):
            if not var[j] > MIN_WAVE_STD_DEG ** 2:
                keep[cols] = False
        return keep

    def _fit(self, keep):
        """(theta (10,), cov (10, 10)) of the parameters ``keep`` (the others 0), or None."""
        every = bool(keep.all())
        N, b = (self.N, self.b) if every else (self.N[np.ix_(keep, keep)], self.b[keep])
        A = N.copy()                                    # N + 1e-9 max(1, tr N) I
        A.flat[::len(b) + 1] += 1e-9 * max(1.0, float(np.trace(N)))
        try:
            cov_k = np.linalg.inv(A)
        except np.linalg.LinAlgError:
            return None
        theta_k = cov_k @ b
        chi2 = max(0.0, self.yy - 2.0 * theta_k @ b + theta_k @ N @ theta_k)
        dof = 3.0 * self.n_eff - len(b)
        scale = max(1.0, chi2 / dof) if dof > 0 else 1.0
        scale *= self.correlation_factor()
        if every:
            return theta_k, cov_k * scale
        theta, cov = np.zeros(_NP), np.zeros((_NP, _NP))
        theta[keep] = theta_k
        cov[np.ix_(keep, keep)] = cov_k * scale
        return theta, cov

    def solve(self) -> None:
        """The fit of the model in use: every active parameter is fitted, and each angle's
        three wave gains stay in the model only while they differ from 0 beyond chance
        (:data:`GAIN_ENTER_P` to enter, :data:`GAIN_STAY_P` to stay): a gain group
        that is not there only adds its noise to every epoch's flexure (measured under
        realistic.toml, 120 s: the flexure 1.19 / 0.22 / 0.85'' off with the pitch gains,
        0.54 / 0.16 / 0.33'' without; the hull there bends with the roll only)."""
        from shipstar.pipeline._integrity import chi2_limit

        if self.n < MIN_MONITOR_EPOCHS:
            return
        active = self.active()
        full = self._fit(active)
        if full is None:
            return
        keep = active.copy()
        for j, cols in enumerate(_GAIN_COLS):
            if not active[cols].all():
                self.gains_used[j] = False
                continue
            g, C = full[0][cols], full[1][cols, cols]
            try:
                chi2 = float(g @ np.linalg.solve(C, g))
            except np.linalg.LinAlgError:
                chi2 = math.inf
            self.gains_used[j] = chi2 > chi2_limit(3, GAIN_STAY_P if self.gains_used[j] else GAIN_ENTER_P)
            keep[cols] &= self.gains_used[j]
        fit = full if np.array_equal(keep, active) else self._fit(keep)
        if fit is None:
            return
        self.theta, self.cov = fit
        self.theta_full, self.cov_full = full
        self.keep = keep

    def add(self, t_s, y_asec, info, a_deg, omega) -> None:
        """One epoch: ``y_asec`` (3,) the sensors' disagreement, ``info`` (3, 3) its
        information, ``a_deg`` (2,) roll and pitch, ``omega`` (3,) arcsec per ms.  Compiled
        (:func:`shipstar.attitude._ckernels.mount_step`: the same steps, its own 10 x 10
        inverse) unless ``_COMPILED[0]`` is False or a matrix is singular there."""
        if _COMPILED[0] and self._add_compiled(t_s, y_asec, info, a_deg, omega):
            return
        self._add_python(t_s, y_asec, info, a_deg, omega)

    def _add_compiled(self, t_s, y_asec, info, a_deg, omega) -> bool:
        from shipstar.attitude._ckernels import mount_step

        none = math.nan
        sc = np.array([self.yy, self.n_eff, self.n, self.n_gated, none if self.t_last is None else self.t_last,
                       self.clock_applied, self.flex_applied, none if self.t_prev is None else self.t_prev,
                       self.vf_chi2, self.vf_n, none if self.vf_t is None else self.vf_t,
                       self.gains_used[0], self.gains_used[1], self.u_prev is not None, float(t_s), 0.0])
        o_theta, o_theta_full, o_u = np.empty(_NP), np.empty(_NP), np.empty(3)
        o_cov, o_cov_full, o_keep = np.empty((_NP, _NP)), np.empty((_NP, _NP)), np.empty(_NP, bool)
        f64 = np.float64
        flags = mount_step(sc, self.N, self.b, self.a_sum, self.aa_sum, self.uu_lag,
                           _ZERO3 if self.u_prev is None else np.ascontiguousarray(self.u_prev, f64),
                           self.theta, self.cov, self.theta_full, self.cov_full, self.keep,
                           np.ascontiguousarray(y_asec, f64), np.ascontiguousarray(info, f64),
                           np.ascontiguousarray(a_deg, f64), np.ascontiguousarray(omega, f64),
                           _TRACK_PARAMS, _track_limits(), o_theta, o_cov, o_theta_full, o_cov_full, o_keep, o_u)
        if flags < 0:
            return False
        yy, n_eff, n, n_gated, t_last, clock, flex, t_prev, vf_chi2, vf_n, vf_t, g0, g1 = sc[:13].tolist()
        self.yy, self.n_eff, self.n, self.n_gated = yy, n_eff, int(n), int(n_gated)
        self.t_last, self.t_prev = t_last, (None if math.isnan(t_prev) else t_prev)
        self.vf_chi2, self.vf_n, self.vf_t = vf_chi2, vf_n, (None if math.isnan(vf_t) else vf_t)
        self.clock_applied, self.flex_applied = bool(clock), bool(flex)
        self.gains_used = [bool(g0), bool(g1)]
        if flags & 1:
            self.u_prev = o_u
        if flags & 2:
            self.theta, self.cov = o_theta, o_cov
        if flags & 4:
            self.theta_full, self.cov_full, self.keep = o_theta_full, o_cov_full, o_keep
        return True

    def _add_python(self, t_s, y_asec, info, a_deg, omega) -> None:
        if self.t_last is not None:
            lam = math.exp(-max(0.0, t_s - self.t_last) / MEMORY_S)
            self.N *= lam
            self.b *= lam
            self.yy *= lam
            self.n_eff *= lam
            self.a_sum *= lam
            self.aa_sum *= lam
        self.t_last = t_s
        X = _design(a_deg, omega)
        if self.n >= MIN_MONITOR_EPOCHS and np.isfinite(self.theta_full).all():
            # innovations of the full model (a gain group left out of the model in use
            # must not gate the epochs that would bring it in)
            v = y_asec - X @ self.theta_full
            S = np.linalg.inv(info) + X @ self.cov_full @ X.T
            chi2 = float(v @ np.linalg.solve(S, v))
            self._add_variance(t_s, min(chi2, GATE_CHI2))
            self._add_correlation(t_s, v, S, chi2)
            if chi2 > GATE_CHI2:
                self.n_gated += 1
                return
        self.N += X.T @ info @ X
        self.b += X.T @ info @ y_asec
        self.yy += float(y_asec @ info @ y_asec)
        self.n_eff += 1.0
        self.n += 1
        self.a_sum += a_deg
        self.aa_sum += np.outer(a_deg, a_deg)
        self.solve()
        self._rules()

    def _add_correlation(self, t_s, v, S, chi2) -> None:
        """Lag-1 products of the whitened innovations of consecutive epochs."""
        try:
            u = np.linalg.solve(np.linalg.cholesky(S), v)
        except np.linalg.LinAlgError:
            return
        if chi2 > GATE_CHI2:
            u = u * math.sqrt(GATE_CHI2 / chi2)
        prev, t_prev = self.u_prev, self.t_prev
        self.u_prev, self.t_prev = u, t_s
        if prev is None or not 0.0 < t_s - t_prev <= MAX_LAG_S:
            return
        self.uu_lag *= math.exp(-(t_s - t_prev) / MEMORY_S)
        self.uu_lag += (float(u @ prev), 0.5 * float(u @ u + prev @ prev))

    def correlation_factor(self) -> float:
        """``(1 + rho) / (1 - rho)``: how much more a slowly varying parameter's variance is
        than the white-noise fit states when successive epochs' errors correlate with lag-1
        coefficient ``rho`` (seeing with its correlation time, a star field that changes
        slowly); ``rho`` from the whitened innovations, clipped to [0, :data:`MAX_RHO`]."""
        if self.uu_lag[1] <= 0.0 or self.n < MIN_EPOCHS:
            return 1.0
        rho = min(MAX_RHO, max(0.0, self.uu_lag[0] / self.uu_lag[1]))
        return (1.0 + rho) / (1.0 - rho)

    def _add_variance(self, t_s, chi2) -> None:
        if self.vf_t is not None:
            lam = math.exp(-max(0.0, t_s - self.vf_t) / VARIANCE_MEMORY_S)
            self.vf_chi2 *= lam
            self.vf_n *= lam
        self.vf_t = t_s
        self.vf_chi2 += chi2
        self.vf_n += 1.0

    def variance_factor(self) -> float:
        """The disagreement's a posteriori variance factor (mean innovation chi2 / 3), 1.0
        unless it exceeds 1 beyond chance (:data:`VARIANCE_SIGMAS`)."""
        dof = 3.0 * self.vf_n
        if dof < 3.0 * MIN_EPOCHS:
            return 1.0
        f = self.vf_chi2 / dof
        return f if f > 1.0 + VARIANCE_SIGMAS * math.sqrt(2.0 / dof) else 1.0

    # -- what is applied ----------------------------------------------------------------
    def clock(self):
        """(offset_s, sigma_s)."""
        return self.theta[9] * 1e-3, math.sqrt(self.cov[9, 9]) * 1e-3 if np.isfinite(self.cov[9, 9]) else math.nan

    def _rules(self) -> None:
        from shipstar.pipeline._integrity import chi2_limit

        if self.n < MIN_EPOCHS or not np.isfinite(self.theta).all():
            return
        off, sig = self.clock()
        k = STAY_SIGMAS if self.clock_applied else ENTER_SIGMAS
        self.clock_applied = bool(sig <= MAX_APPLY_SIGMA_S and abs(off) > k * sig)
        keep = self.keep[:9]
        f, C = self.theta[:9][keep], self.cov[:9, :9][np.ix_(keep, keep)]
        try:
            chi2 = float(f @ np.linalg.solve(C, f))
        except np.linalg.LinAlgError:
            return
        self.flex_applied = chi2 > chi2_limit(int(keep.sum()), STAY_P if self.flex_applied else ENTER_P)

    def applied_shift_s(self) -> float:
        return float(self.clock()[0]) if self.clock_applied else 0.0

    def phi(self, a_deg):
        """(rot (3,), sigma (3,)) arcsec of the flexure model at roll/pitch ``a_deg``."""
        if not np.isfinite(self.theta).all():
            return np.full(3, math.nan), np.full(3, math.nan)
        X = _design(a_deg, np.zeros(3))[:, :9]
        rot = X @ self.theta[:9]
        sig = np.sqrt(np.maximum(0.0, np.einsum("ij,jk,ik->i", X, self.cov[:9, :9], X)))
        return rot, sig

    def phi_cov(self, a_deg) -> np.ndarray:
        """(3, 3) covariance (arcsec^2, deck axes) of the flexure model at roll/pitch ``a_deg``."""
        X = _design(a_deg, np.zeros(3))[:, :9]
        return X @ self.cov[:9, :9] @ X.T

    def a_mean(self):
        return self.a_sum / self.n_eff if self.n_eff > 0 else np.zeros(2)

    def flexure_block(self, sem_arcsec) -> dict:
        """The summary's flexure entry of this sensor."""
        rot, sig = self.phi(self.a_mean())
        out = {"n_epochs": self.n, "n_gated": self.n_gated, "applied": self.flex_applied,
               "variance_factor": _num(self.variance_factor()),
               "correlation_factor": _num(self.correlation_factor()),
               "wave_gains_in_model": {"roll": bool(self.gains_used[0]), "pitch": bool(self.gains_used[1])}}
        out["static_arcsec"] = {ax: _num(r) for ax, r in zip(_AXES, rot)}
        out["static_sigma_arcsec"] = {ax: _num(s) for ax, s in zip(_AXES, sig)}
        amp, amp_sig = np.full(3, math.nan), np.full(3, math.nan)
        if self.n_eff > 0 and np.isfinite(self.theta).all():
            m = self.a_mean()
            S = self.aa_sum / self.n_eff - np.outer(m, m)             # covariance of roll, pitch
            for i in range(3):
                idx = [3 + i, 6 + i]
                g = self.theta[idx]
                var = float(g @ S @ g)
                amp[i] = math.sqrt(2.0 * max(var, 0.0))                # sinusoid: amplitude = sqrt(2) RMS
                if var > 0:
                    grad = math.sqrt(2.0) * (S @ g) / math.sqrt(var)
                    amp_sig[i] = math.sqrt(max(0.0, float(grad @ self.cov[np.ix_(idx, idx)] @ grad)))
        out["wave_amplitude_arcsec"] = {ax: _num(x) for ax, x in zip(_AXES, amp)}
        out["wave_amplitude_sigma_arcsec"] = {ax: _num(x) for ax, x in zip(_AXES, amp_sig)}
        # the static part against the dock calibration: the installation files' sems of both
        # sensors (the calibration's own uncertainty) and this estimate's sigma
        tol = math.sqrt(sum(float(x) ** 2 for x in sem_arcsec if math.isfinite(float(x))))
        out["dock_sem_arcsec"] = _num(tol)
        comb = np.sqrt(sig ** 2 + tol ** 2)
        out["installation_drift"] = bool(np.isfinite(rot).all() and (np.abs(rot) > 3.0 * comb).any())
        return out


def _sems(installation) -> list:
    return [float(s) for s in getattr(installation, "sem_arcsec", ()) if math.isfinite(float(s))]


class MountEstimator:
    """The engine's estimator of clock offsets and mount flexure (module docstring).

    Parameters
    ----------
    configs : sequence of SensorConfig
    reference : int
    """

    def __init__(self, configs, reference: int):
        self.configs = tuple(configs)
        self.reference = int(reference)
        self.others = [k for k in range(len(self.configs)) if k != self.reference]
        self._tracks = {k: _Track() for k in self.others}
        ref = getattr(self.configs[self.reference], "installation", None)
        # the dock calibration's sems of the reference and each sensor (the flexure summary's)
        self._sems = {k: _sems(ref) + _sems(self.configs[k].installation) for k in self.others}

    def state(self) -> dict:
        """The estimator's state, JSON-able (a checkpoint's: ``measure --resume`` continues
        with it, :meth:`restore`)."""
        return {str(k): tr.state() for k, tr in self._tracks.items()}

    def restore(self, state: dict) -> None:
        """Continue from :meth:`state`'s result."""
        if sorted(state) != sorted(str(k) for k in self._tracks):
            raise ShipstarError("the mounts' estimator state is for other sensors")
        self._tracks = {k: _Track.from_state(state[str(k)]) for k in self._tracks}

    def variance_factor(self) -> float:
        """The factor by which the sensors' star covariances fall short of their observed
        disagreement (the largest over the non-reference sensors; 1.0 when they agree as
        stated).  Two sensors that disagree by more than their sigmas say the sigmas are too
        small but not whose, so the engine multiplies both sensors' star covariances by it
        in the next epoch's fusion (the a posteriori variance factor of geodesy's
        adjustments).  It is never below 1: sigmas that are too large stay as stated."""
        return max([tr.variance_factor() for tr in self._tracks.values()], default=1.0)

    def shift_s(self, sensor: int) -> float:
        """The shift applied to this sensor's frame times now (s)."""
        tr = self._tracks.get(sensor)
        return tr.applied_shift_s() if tr is not None else 0.0

    def configs_for(self, fr_ref, omega_rad_per_s=None):
        """The configs of the next epoch: a sensor whose flexure or clock offset is applied
        gets a flexed installation carrying the uncertainty of what is applied (deck axes):
        the flexure's ``Phi`` and, with the deck's angular velocity ``omega_rad_per_s``
        (3,) at the epoch, the clock offset's ``omega omega^T sigma_delta^2`` (the applied
        offset's error turns the sensor's deck attitude by ``omega`` times it, as a mount
        error would: 0.02 ms at 4 deg/s is 0.25'')."""
        if fr_ref is None or not fr_ref.ship.solved:
            return self.configs
        a = self._angles(fr_ref)
        out = list(self.configs)
        from dataclasses import replace

        from shipstar.pipeline._motion import expm_rotvec

        w = None if omega_rad_per_s is None else np.asarray(omega_rad_per_s, float) * 1e-3     # rad per ms
        for k, tr in self._tracks.items():
            c = self.configs[k]
            if c.installation is None:
                continue
            C, Phi, changed = c.installation.C_deck_from_sensor, np.zeros((3, 3)), False
            if tr.flex_applied:
                rot, _ = tr.phi(a)
                C = expm_rotvec(rot * ASEC2RAD) @ C
                Phi = tr.phi_cov(a) * ASEC2RAD ** 2
                changed = True
            var_ms2 = tr.cov[9, 9]
            if tr.clock_applied and w is not None and np.isfinite(w).all() and math.isfinite(var_ms2):
                Phi = Phi + np.outer(w, w) * var_ms2
                changed = True
            if changed:
                out[k] = replace(c, installation=_FlexedInstallation(c.installation, C, Phi))
        return tuple(out)

    @staticmethod
    def _angles(fr_ref) -> np.ndarray:
        return np.array([fr_ref.ship.roll_rad, fr_ref.ship.pitch_rad]) * RAD2DEG

    def update(self, t_s: float, epoch, paired, shifts_s, configs_used, motion, *,
               with_monitor: bool = True) -> MountsSnapshot:
        """Add one fused epoch; ``shifts_s``: the time shift applied to each paired frame,
        ``configs_used``: the configs the epoch was fused with, ``motion``: the deck's motion
        fit around the epoch (None: not known).  ``with_monitor=False``: the snapshot's
        ``monitor`` is None, for a caller that sets it later (the engine's held epochs get
        the monitor of their release)."""
        from shipstar.pipeline._motion import rotvec

        ref = self.reference
        fr_ref, att_ref = paired[ref], epoch.single[ref]
        ok_ref = fr_ref is not None and att_ref.solved and fr_ref.horizontal is not None and motion is not None
        a = self._angles(fr_ref) if fr_ref is not None and fr_ref.ship.solved else None
        for k, tr in self._tracks.items():
            fr, att, c = paired[k], epoch.single[k], configs_used[k]
            if ok_ref and fr is not None and att.solved and fr.horizontal is not None and c.installation is not None:
                d = rotvec(att_ref.C_hor_from_deck.T @ att.C_hor_from_deck) * RAD2ASEC
                C_ds = c.installation.C_deck_from_sensor
                C_rs = configs_used[ref].installation.C_deck_from_sensor
                P = (C_ds @ np.asarray(fr.horizontal.covariance_rad2, float) @ C_ds.T
                     + C_rs @ np.asarray(fr_ref.horizontal.covariance_rad2, float) @ C_rs.T) * RAD2ASEC ** 2
                P = 0.5 * (P + P.T) + 2.0 * MODEL_SIGMA_ARCSEC ** 2 * np.eye(3)
                omega = motion.omega_at(t_s) * RAD2ASEC * 1e-3                    # arcsec per ms
                applied_phi = np.zeros(3)
                if c.installation is not self.configs[k].installation:         # flexed: C_eff = Exp(phi) C
                    applied_phi = rotvec(C_ds @ self.configs[k].installation.C_deck_from_sensor.T) * RAD2ASEC
                y = d + applied_phi + omega * (shifts_s[k] * 1e3)
                if np.isfinite(y).all() and np.isfinite(P).all():
                    tr.add(t_s, y, np.linalg.inv(P), a, omega)
        return MountsSnapshot(self.monitor(fr_ref) if with_monitor else None, self.time_offsets(),
                              _FlexureLater(self._flexure_entries()))

    def monitor(self, fr_ref) -> tuple:
        """``(sensor, rot_arcsec (3,), sigma_arcsec (3,))`` per non-reference sensor: the
        estimate as it stands now at the reference frame's roll and pitch (NaN without
        them or before :data:`MIN_MONITOR_EPOCHS` epochs)."""
        a = self._angles(fr_ref) if fr_ref is not None and fr_ref.ship.solved else None
        out = []
        for k, tr in self._tracks.items():
            if a is not None and tr.n >= MIN_MONITOR_EPOCHS:
                rot, sig = tr.phi(a)
            else:
                rot, sig = np.full(3, math.nan), np.full(3, math.nan)
            out.append((self.configs[k].name, rot, sig))
        return tuple(out)

    def time_offsets(self) -> dict:
        out = {}
        for k, tr in self._tracks.items():
            off, sig = tr.clock()
            out[self.configs[k].name] = {"offset_s": _num(off), "sigma_s": _num(sig), "applied": tr.clock_applied}
        return out

    def flexure(self) -> dict:
        return {name: tr.flexure_block(sems) for name, tr, sems in self._flexure_entries()}

    def _flexure_entries(self) -> list:
        return [(self.configs[k].name, tr, self._sems[k]) for k, tr in self._tracks.items()]


def monitor_rows(epoch) -> list:
    """The monitor CSV's rows (strings) of one epoch (none without estimates)."""
    m = getattr(epoch, "mounts", None)
    if m is None:
        return []
    rows = []
    for name, rot, sig in m.monitor:
        vals = [f"{x:.4f}" if math.isfinite(x) else "nan" for x in (*rot, *sig)]
        rows.append([epoch.utc_iso, name, *vals])
    return rows


class MonitorCsvWriter:
    """``measure --monitor CSV``: one row per epoch and non-reference sensor
    (:data:`MONITOR_COLUMNS`), written as the epochs come.

    ``keep_before_s`` (a resumed run): the rows of an existing file before this time (s
    since ``start_utc_jd``) are kept and the new rows appended after them.
    """

    def __init__(self, path, *, keep_before_s=None, start_utc_jd=None):
        from pathlib import Path

        self.path = Path(path)
        kept = []
        if keep_before_s is not None and self.path.exists():
            from shipstar.sky.time import iso_from_utc_jd

            cut = iso_from_utc_jd(start_utc_jd[0], start_utc_jd[1] + keep_before_s / 86400.0, 6)
            lines = self.path.read_text(encoding="utf-8").splitlines()[1:]
            kept = [line for line in lines if line.split(",", 1)[0] < cut]
        self._f = open(self.path, "w", encoding="utf-8", newline="")
        self._f.write(",".join(MONITOR_COLUMNS) + "\n" + "".join(line + "\n" for line in kept))

    def write(self, emission) -> None:
        e = emission.epoch
        if e is None:
            return
        for row in monitor_rows(e):
            self._f.write(",".join(row) + "\n")

    def flush(self) -> None:
        self._f.flush()

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()
