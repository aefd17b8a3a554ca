"""The inertial navigator (INS) calibrated against the stars, and star outages bridged with it (issue 15).

**Error model** (the INS's reading minus the truth, shipstar's angles, arcsec):

``e(t) = [b_h(t), b_p(t), b_r(t)] + J(a(t)) m``,  ``b_h' = d + w_h``, ``b_p' = w_p``, ``b_r' = w_r``

with ``d`` the heading drift (arcsec/h), ``w`` white (random walks of the INS's heading and
level errors, :class:`InsModel`), ``m`` the INS body to deck misalignment (rotation
vector in deck axes bow / up / starboard, ``C_deck_from_ins = exp([m x])``) and ``J`` the
derivative of the ship's angles of ``C_hor_from_deck @ exp([m x])`` with respect to ``m``
at the attitude ``a``.  The INS stamps a reading taken at frame-clock time ``t`` with its
own clock's ``t + dt`` (``dt`` = INS clock minus frame clock).

**Measurements**: each epoch's joint star attitude ``z_k`` at frame-clock time ``t_k``
with its covariance: ``z_k = Y(t_k + dt) - e(t_k) + v_k``, ``Y`` the INS log interpolated
(cubic through 4 records).  Linearised in ``dt`` about ``dt0``:
``Y(t_k + dt0) - Ydot dt0 - z_k = e(t_k) - Ydot dt - v_k``, so ``dt`` is seen through the
ship's angular rate (at sea the roll rate, ~4 deg/s: 1 ms is 14'').  The INS's white noise
(and quantisation) is added to the star covariance.

**Estimation** (batch, ``measure --ins``): states ``x = [b_h, b_p, b_r, d, m (3), dt]``
(arcsec, arcsec/h, arcsec, ms); a Kalman filter over blocks of :attr:`InsModel.block_s`
(the star epochs in a block enter as one information update; within it the states are
taken constant but for the drift), a Rauch-Tung-Striebel smoother back over the blocks,
the whole repeated about the new ``dt0`` (Gauss-Newton) until ``dt`` moves less than
0.1 us.  Memory: ~1.2 kB per block (4 MB per hour at 1 s blocks) plus the INS records.

**Misalignment**: its constant part is the same as the biases' (a rotation about the
deck's up axis is a heading error, about the bow a roll error, about the starboard axis a
pitch error); only the ship's roll and pitch make them differ (``J`` mixes axes by
``sin(roll)``, ``sin(pitch)``: ~9 % at 5 deg of roll).  About the bow they never differ:
roll is the last rotation of ``R_y(K) R_z(-psi) R_x(-theta)``, so a misalignment about the
bow *is* a roll bias at every attitude; it is folded into ``roll_bias`` (state held at 0).
With :attr:`InsModel.estimate_misalignment` (default) the up and starboard components are
states with a prior of :attr:`InsModel.prior_misalignment_sigma_arcsec`; the heading and
pitch biases are then the INS's own errors beyond the misalignment, and their sigmas show
how well the roll separates them (at 5 deg of roll, 0.5'' in a minute).  Without it the
misalignment is folded into the biases (the constant part; its roll-modulated part is
then left in the corrected attitude).

**Output**: at each INS record, the corrected attitude ``Y - e`` at frame-clock time
``tau - dt`` with its sigma (the smoothed covariance through the record's ``H``, the
random walk since the block's time and the INS's white noise), ``source`` ``stars+ins``
when a star epoch is within :attr:`InsModel.bridge_after_s`, else ``ins-bridged``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.units import ASEC2RAD, DAY_S, RAD2ASEC, RAD2DEG

__all__ = ["InsModel", "StarRows", "InsSolution", "estimate_ins", "INS_CSV_COLUMNS", "write_ins_csv", "ForwardIns",
           "misalignment_jacobian", "interpolate_cubic"]

_H_S = 3600.0
_NX = 8
_IM = slice(4, 7)
_IDT = 7
INS_CSV_COLUMNS = ("time_utc", "heading_deg", "pitch_deg", "roll_deg", "sigma_heading_arcsec", "sigma_pitch_arcsec",
                   "sigma_roll_arcsec", "source")


@dataclass(frozen=True)
class InsModel:
    """What the filter knows of the INS (a marine fibre-optic INS by default).

    Attributes
    ----------
    heading_random_walk_arcsec_per_sqrt_h, level_random_walk_arcsec_per_sqrt_h : float
        Random walk of the heading error and of the pitch and roll errors.
    noise_arcsec : float
        White noise of a reading (per angle).
    quantisation_deg : float
        Resolution of the readings (adds ``q^2 / 12``).
    prior_bias_sigma_arcsec, prior_drift_sigma_arcsec_per_h, prior_misalignment_sigma_arcsec, prior_time_offset_sigma_s : float
    estimate_misalignment : bool
    block_s : float
        Filter step (s).
    bridge_after_s : float
        A record further than this from any star epoch is ``ins-bridged``.
    max_record_gap_s : float
        Star epochs between INS records further apart than this are not used.
    gate_chi2 : float
        Star epochs whose smoothed residual exceeds this chi-square (3 dof) are left out
        of the next pass.
    """

    heading_random_walk_arcsec_per_sqrt_h: float = 3.6
    level_random_walk_arcsec_per_sqrt_h: float = 1.0
    noise_arcsec: float = 0.5
    quantisation_deg: float = 1e-5
    prior_bias_sigma_arcsec: float = 3600.0
    prior_drift_sigma_arcsec_per_h: float = 360.0
    prior_misalignment_sigma_arcsec: float = 600.0
    prior_time_offset_sigma_s: float = 0.5
    estimate_misalignment: bool = True
    block_s: float = 1.0
    bridge_after_s: float = 1.0
    max_record_gap_s: float = 0.25
    gate_chi2: float = 30.0

    @property
    def white_var_arcsec2(self) -> float:
        q = self.quantisation_deg * 3600.0
        return self.noise_arcsec ** 2 + q * q / 12.0


class StarRows:
    """The joint star attitudes of a session, collected from the engine's emissions
    (``write``, as :class:`~shipstar.pipeline._measure.run_measure`'s monitor hook) or
    given as arrays; compact (80 bytes an epoch).

    ``spool`` (``measure --ins``: ``OUT.ins-stars``): each epoch is also appended to this
    file (10 float64: ``t_s``, heading, pitch, roll (rad), the covariance's
    ``xx yy zz xy xz yz`` (rad^2)), flushed to disk at each checkpoint (``flush``), so that
    a stopped run's epochs survive it (opened, and emptied, at the first epoch or
    checkpoint: a run refused before its first epoch leaves nothing behind).
    ``resume=True`` reads them back (a torn last
    record, after a crash, is dropped) and, at the first epoch the resumed run gives out,
    forgets those at or after its time (the run re-emits them): the rows are then exactly
    an uninterrupted run's, and the INS filter runs over the whole session at the end.
    """

    _FIELDS = 10

    def __init__(self, spool=None, *, resume: bool = False):
        from pathlib import Path

        self._t, self._a, self._c = [], [], []
        self._fh = None
        self._cut_at_next_epoch = False
        self.spool = None if spool is None else Path(spool)
        if self.spool is None:
            return
        if resume:
            if not self.spool.is_file():
                raise ShipstarError(f"--resume with --ins: {self.spool.name} (the star attitudes of the stopped run) "
                                    f"is missing: was the stopped run given --ins?  Run again without --resume")
            raw = self.spool.read_bytes()
            n = len(raw) // (8 * self._FIELDS)
            x = np.frombuffer(raw[:n * 8 * self._FIELDS], "<f8").reshape(n, self._FIELDS)
            self._t = x[:, 0].tolist()
            self._a = [tuple(r) for r in x[:, 1:4].tolist()]
            self._c = [tuple(r) for r in x[:, 4:].tolist()]
            self._fh = open(self.spool, "r+b")
            self._fh.truncate(n * 8 * self._FIELDS)
            self._fh.seek(n * 8 * self._FIELDS)
            self._cut_at_next_epoch = True

    def _open(self) -> None:
        if self._fh is None and self.spool is not None:
            self._fh = open(self.spool, "wb")

    def write(self, emission) -> None:
        e = getattr(emission, "epoch", None)
        if e is None:
            return
        self._open()
        if self._cut_at_next_epoch:
            self._cut(e.t_s)
        if not e.joint.solved:
            return
        c = np.asarray(e.joint.covariance_rad2, float)
        if not np.all(np.isfinite(c)):
            return
        self.add(e.t_s, (e.joint.heading_rad, e.joint.pitch_rad, e.joint.roll_rad), c)

    def _cut(self, t_s: float) -> None:
        """Forget the epochs at or after ``t_s`` (a resumed run gives them out again)."""
        self._cut_at_next_epoch = False
        k = int(np.searchsorted(np.asarray(self._t, float), float(t_s) - 1e-9))
        del self._t[k:], self._a[k:], self._c[k:]
        if self._fh is not None:
            self._fh.truncate(k * 8 * self._FIELDS)
            self._fh.seek(k * 8 * self._FIELDS)

    def add(self, t_s: float, angles_rad, covariance_rad2) -> None:
        self._t.append(float(t_s))
        self._a.append(tuple(float(x) for x in angles_rad))
        c = np.asarray(covariance_rad2, float)
        self._c.append((c[0, 0], c[1, 1], c[2, 2], c[0, 1], c[0, 2], c[1, 2]))
        self._open()
        if self._fh is not None:
            self._fh.write(np.array([self._t[-1], *self._a[-1], *self._c[-1]], "<f8").tobytes())

    def flush(self) -> None:
        self._open()
        if self._fh is not None and not self._fh.closed:
            import os

            self._fh.flush()
            os.fsync(self._fh.fileno())

    def close(self) -> None:
        if self._fh is not None and not self._fh.closed:
            self._fh.close()

    def discard(self) -> None:
        """Close and delete the spool file (the run is complete)."""
        self.close()
        if self.spool is not None:
            self.spool.unlink(missing_ok=True)

    def __len__(self) -> int:
        return len(self._t)

    def arrays(self):
        """(t_s (N,), angles_rad (N, 3), covariance_rad2 (N, 3, 3))."""
        t = np.asarray(self._t, float)
        a = np.asarray(self._a, float).reshape(-1, 3)
        c6 = np.asarray(self._c, float).reshape(-1, 6)
        C = np.empty((len(t), 3, 3))
        C[:, 0, 0], C[:, 1, 1], C[:, 2, 2] = c6[:, 0], c6[:, 1], c6[:, 2]
        C[:, 0, 1] = C[:, 1, 0] = c6[:, 3]
        C[:, 0, 2] = C[:, 2, 0] = c6[:, 4]
        C[:, 1, 2] = C[:, 2, 1] = c6[:, 5]
        return t, a, C


@dataclass(frozen=True, eq=False)
class InsSolution:
    """The INS's estimated errors and its corrected attitude.

    Attributes
    ----------
    summary : dict
        ``measure --json``'s ``ins`` object (exactly the issue's keys).
    details : dict
        Misalignment, counts, iterations, the model.
    t_s : (N,)
        Corrected records' frame-clock times (INS time minus the estimated offset), s since
        the log's start.
    angles_rad : (N, 3)
        Corrected heading (in [0, 2 pi)), pitch, roll.
    sigma_arcsec : (N, 3)
    bridged : (N,) bool
    error_arcsec : (N, 3)
        The estimated INS error at each record (reading minus corrected).
    error_sigma_arcsec : (N, 3)
        Its sigma (without the INS's white noise).
    """

    summary: dict
    details: dict
    t_s: np.ndarray
    angles_rad: np.ndarray
    sigma_arcsec: np.ndarray
    bridged: np.ndarray
    error_arcsec: np.ndarray
    error_sigma_arcsec: np.ndarray
    start_utc_jd: tuple = (0.0, 0.0)


def _wrap(x):
    return (x + math.pi) % (2.0 * math.pi) - math.pi


def misalignment_jacobian(angles_rad) -> np.ndarray:
    """``d angles(C_hor_from_deck(a) @ exp([m x])) / d m`` at ``m = 0``, shape (N, 3, 3)
    (rows heading / pitch / roll, columns bow / up / starboard; dimensionless)."""
    from shipstar.frames import C_hor_from_deck, ship_angles_from_C_hor_from_deck

    a = np.asarray(angles_rad, float).reshape(-1, 3)
    C = C_hor_from_deck(a[:, 0], a[:, 1], a[:, 2])
    eps = 1e-6
    J = np.empty((len(a), 3, 3))
    for j in range(3):
        phi = np.zeros(3)
        phi[j] = eps
        K = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
        E = np.eye(3) + K + 0.5 * K @ K
        angp = np.stack(ship_angles_from_C_hor_from_deck(C @ E), -1)
        angm = np.stack(ship_angles_from_C_hor_from_deck(C @ E.T), -1)
        d = angp - angm
        d[:, 0] = _wrap(d[:, 0])
        J[:, :, j] = d / (2 * eps)
    return J


def _cubic(t_rec, y_rec, t):
    """Cubic Lagrange interpolation (4 records around each ``t``) and its derivative;
    also the span of the 2 records around ``t`` (s)."""
    n = len(t_rec)
    i = np.clip(np.searchsorted(t_rec, t) - 2, 0, n - 4)
    idx = i[:, None] + np.arange(4)[None, :]
    tt = t_rec[idx]                                   # (N, 4)
    yy = y_rec[idx]                                   # (N, 4, 3)
    x = t[:, None]
    L = np.ones((len(t), 4))
    dL = np.zeros((len(t), 4))
    for j in range(4):
        others = [m for m in range(4) if m != j]
        den = np.prod([tt[:, j] - tt[:, m] for m in others], axis=0)
        f = [x[:, 0] - tt[:, m] for m in others]
        L[:, j] = f[0] * f[1] * f[2] / den
        dL[:, j] = (f[1] * f[2] + f[0] * f[2] + f[0] * f[1]) / den
    y = np.einsum("nj,njk->nk", L, yy)
    dy = np.einsum("nj,njk->nk", dL, yy)
    k = np.clip(np.searchsorted(t_rec, t), 1, n - 1)
    span = t_rec[k] - t_rec[k - 1]
    inside = (t >= t_rec[0]) & (t <= t_rec[-1])
    return y, dy, np.where(inside, span, np.inf), np.sum(L * L, 1)


#: ``(y (N, 3), dy/dt (N, 3), span_s (N,) of the 2 rows around each time (inf outside),
#: sum of squared weights (N,))``: cubic Lagrange through the 4 rows around each time.
interpolate_cubic = _cubic


def _phi(dt_h: float) -> np.ndarray:
    F = np.eye(_NX)
    F[0, 3] = dt_h
    return F


def _q(model: InsModel, dt_h: float) -> np.ndarray:
    Q = np.zeros((_NX, _NX))
    Q[0, 0] = model.heading_random_walk_arcsec_per_sqrt_h ** 2 * dt_h
    Q[1, 1] = Q[2, 2] = model.level_random_walk_arcsec_per_sqrt_h ** 2 * dt_h
    for i in range(3, _NX):
        Q[i, i] = 1e-12 * dt_h
    return Q


def _prior(model: InsModel):
    p = np.array([model.prior_bias_sigma_arcsec] * 3 + [model.prior_drift_sigma_arcsec_per_h]
                 + [1e-6] + [model.prior_misalignment_sigma_arcsec if model.estimate_misalignment else 1e-6] * 2
                 + [model.prior_time_offset_sigma_s * 1e3])
    return np.zeros(_NX), np.diag(p * p)


def _pass(model, ins_t, Y, star_t, Z, R, J, use, dt0_s, t0_s, n_blocks):
    """One Kalman filter + RTS pass linearised about ``dt0_s``; returns smoothed (x, P) per
    block and the star epochs' residual chi2."""
    y, dy, span, w2 = _cubic(ins_t, Y, star_t + dt0_s)
    ok = use & (span <= model.max_record_gap_s)
    r = (y - Z)
    r[:, 0] = _wrap(r[:, 0])
    r = r * RAD2ASEC                                   # arcsec
    ydot = dy * RAD2ASEC * 1e-3                        # arcsec per ms
    r = r - ydot * dt0_s * 1e3
    blk = np.clip(((star_t - t0_s) / model.block_s).astype(int), 0, n_blocks - 1)
    T = t0_s + (blk + 0.5) * model.block_s
    H = np.zeros((len(star_t), 3, _NX))
    H[:, 0, 0] = H[:, 1, 1] = H[:, 2, 2] = 1.0
    H[:, 0, 3] = (star_t - T) / _H_S
    H[:, :, 4:7] = J
    H[:, :, 7] = -ydot
    Rt = R * RAD2ASEC ** 2 + np.eye(3)[None] * (model.white_var_arcsec2 * w2)[:, None, None]
    Ri = np.linalg.inv(Rt)
    HtRi = np.einsum("nki,nkl->nil", H, Ri)
    Lam = np.zeros((n_blocks, _NX, _NX))
    eta = np.zeros((n_blocks, _NX))
    np.add.at(Lam, blk[ok], np.einsum("nil,nlj->nij", HtRi[ok], H[ok]))
    np.add.at(eta, blk[ok], np.einsum("nil,nl->ni", HtRi[ok], r[ok]))
    x, P = _prior(model)
    dt_h = model.block_s / _H_S
    F, Q = _phi(dt_h), _q(model, dt_h)
    xp = np.empty((n_blocks, _NX))
    Pp = np.empty((n_blocks, _NX, _NX))
    xf = np.empty((n_blocks, _NX))
    Pf = np.empty((n_blocks, _NX, _NX))
    I = np.eye(_NX)
    for j in range(n_blocks):
        if j:
            x, P = F @ x, F @ P @ F.T + Q
        xp[j], Pp[j] = x, P
        if eta[j].any() or Lam[j].any():
            Pn = np.linalg.solve(I + P @ Lam[j], P)
            x = x + Pn @ (eta[j] - Lam[j] @ x)
            P = 0.5 * (Pn + Pn.T)
        xf[j], Pf[j] = x, P
    xs, Ps = xf.copy(), Pf.copy()
    for j in range(n_blocks - 2, -1, -1):
        G = np.linalg.solve(Pp[j + 1], F @ Pf[j]).T
        xs[j] = xf[j] + G @ (xs[j + 1] - xp[j + 1])
        Ps[j] = Pf[j] + G @ (Ps[j + 1] - Pp[j + 1]) @ G.T
        Ps[j] = 0.5 * (Ps[j] + Ps[j].T)
    res = r - np.einsum("nkj,nj->nk", H, xs[blk])
    S = Rt + np.einsum("nkj,njl,nml->nkm", H, Ps[blk], H)
    chi2 = np.einsum("nk,nkl,nl->n", res, np.linalg.inv(S), res)
    return xs, Ps, chi2, ok


def estimate_ins(log, star_t_s, star_angles_rad, star_cov_rad2, model: InsModel | None = None,
                 max_iterations: int = 8) -> InsSolution:
    """The INS's errors from the stars, and the corrected attitude at every INS record.

    Parameters
    ----------
    log : shipstar.live._ins_input.InsLog or any object with ``t_s`` (INS clock, s since
        ``start_utc_jd``), ``angles_rad`` (N, 3), ``start_utc_jd``
    star_t_s : (M,)
        Star epochs' frame-clock times, s since the same start.
    star_angles_rad : (M, 3)
    star_cov_rad2 : (M, 3, 3)
    model : InsModel
    """
    model = InsModel() if model is None else model
    ins_t = np.asarray(log.t_s, float)
    Y = np.asarray(log.angles_rad, float).copy()
    Y[:, 0] = np.unwrap(Y[:, 0])
    st = np.asarray(star_t_s, float)
    Z = np.asarray(star_angles_rad, float).reshape(-1, 3)
    R = np.asarray(star_cov_rad2, float).reshape(-1, 3, 3)
    if len(ins_t) < 4:
        raise ShipstarError("the INS log has fewer than 4 records")
    inside = (st > ins_t[0] + 0.1) & (st < ins_t[-1] - 0.1)
    if inside.sum() < 10:
        raise ShipstarError(f"the INS log ({ins_t[0]:.1f} to {ins_t[-1]:.1f} s) overlaps only {int(inside.sum())} "
                            f"solved star epochs (at least 10 needed): is it the same session, its clock the same day?")
    st, Z, R = st[inside], Z[inside], R[inside]
    J = misalignment_jacobian(Z)
    t0 = min(ins_t[0], st[0]) - 1.0
    t1 = max(ins_t[-1], st[-1]) + 1.0
    n_blocks = int(math.ceil((t1 - t0) / model.block_s))
    use = np.ones(len(st), bool)
    dt0, it = 0.0, 0
    for it in range(1, max_iterations + 1):
        xs, Ps, chi2, ok = _pass(model, ins_t, Y, st, Z, R, J, use, dt0, t0, n_blocks)
        new_dt = float(xs[-1, _IDT]) * 1e-3
        gated = chi2 > model.gate_chi2
        converged = abs(new_dt - dt0) < 1e-7 and np.array_equal(use & ~gated, use) if it > 1 else False
        dt0 = new_dt
        if it > 1:
            use = use & ~gated
        if converged:
            break
    xs, Ps, chi2, ok = _pass(model, ins_t, Y, st, Z, R, J, use, dt0, t0, n_blocks)
    dt_s = float(xs[-1, _IDT]) * 1e-3
    used_t = st[ok & use]
    return _solution(model, log, ins_t, Y, xs, Ps, t0, n_blocks, dt_s, used_t, it, int(np.sum(~use)), len(st))


def _solution(model, log, ins_t, Y, xs, Ps, t0, n_blocks, dt_s, used_t, iterations, n_gated, n_star):
    t = ins_t - dt_s
    n = len(t)
    blk = np.clip(((t - t0) / model.block_s).astype(int), 0, n_blocks - 1)
    T = t0 + (blk + 0.5) * model.block_s
    dtb_h = (t - T) / _H_S
    Yd = np.gradient(Y, ins_t, axis=0) * RAD2ASEC * 1e-3 if n > 2 else np.zeros_like(Y)
    J = misalignment_jacobian(Y)
    err = np.empty((n, 3))
    var = np.empty((n, 3))
    step = 100_000
    for lo in range(0, n, step):
        sl = slice(lo, lo + step)
        m = len(t[sl])
        H = np.zeros((m, 3, _NX))
        H[:, 0, 0] = H[:, 1, 1] = H[:, 2, 2] = 1.0
        H[:, 0, 3] = dtb_h[sl]
        H[:, :, 4:7] = J[sl]
        He = H.copy()
        H[:, :, 7] = -Yd[sl]
        err[sl] = np.einsum("nkj,nj->nk", He, xs[blk[sl]])
        v = np.einsum("nkj,njl,nkl->nk", H, Ps[blk[sl]], H)
        rw = np.abs(dtb_h[sl])[:, None] * np.array([model.heading_random_walk_arcsec_per_sqrt_h ** 2,
                                                      model.level_random_walk_arcsec_per_sqrt_h ** 2,
                                                      model.level_random_walk_arcsec_per_sqrt_h ** 2])
        var[sl] = v + rw
    corrected = Y - err * ASEC2RAD
    corrected[:, 0] = np.mod(corrected[:, 0], 2.0 * math.pi)
    sigma = np.sqrt(var + model.white_var_arcsec2)
    if len(used_t):
        k = np.clip(np.searchsorted(used_t, t), 1, max(1, len(used_t) - 1))
        near = np.minimum(np.abs(t - used_t[np.clip(k - 1, 0, len(used_t) - 1)]),
                          np.abs(t - used_t[np.clip(k, 0, len(used_t) - 1)]))
        bridged = near > model.bridge_after_s
    else:
        bridged = np.ones(n, bool)
    # the error terms at the first record
    b0 = blk[0]
    d0 = dtb_h[0]
    x0, P0 = xs[b0], Ps[b0]
    g = np.zeros(_NX)
    g[0], g[3] = 1.0, d0
    hb = float(g @ x0)
    hb_s = math.sqrt(float(g @ P0 @ g) + model.heading_random_walk_arcsec_per_sqrt_h ** 2 * abs(d0))
    summary = {
        "heading_bias_arcsec": hb, "heading_bias_sigma_arcsec": hb_s,
        "heading_drift_arcsec_per_h": float(x0[3]), "heading_drift_sigma_arcsec_per_h": math.sqrt(P0[3, 3]),
        "pitch_bias_arcsec": float(x0[1]), "pitch_bias_sigma_arcsec": math.sqrt(P0[1, 1]),
        "roll_bias_arcsec": float(x0[2]), "roll_bias_sigma_arcsec": math.sqrt(P0[2, 2]),
        "time_offset_s": dt_s, "time_offset_sigma_s": math.sqrt(P0[_IDT, _IDT]) * 1e-3,
    }
    details = {
        "misalignment_estimated": bool(model.estimate_misalignment),
        "misalignment_arcsec": {a: float(x0[4 + i]) for i, a in enumerate(("bow", "up", "starboard"))},
        "misalignment_sigma_arcsec": {a: math.sqrt(P0[4 + i, 4 + i]) for i, a in enumerate(("bow", "up", "starboard"))},
        "n_records": int(n), "n_records_bridged": int(bridged.sum()), "n_star_epochs": int(n_star),
        "n_star_epochs_used": int(len(used_t)), "n_star_epochs_gated": int(n_gated), "iterations": int(iterations),
        "source": getattr(log, "source", ""), "convention": getattr(log, "convention", ""),
        "n_records_skipped": int(getattr(log, "n_skipped", 0)),
    }
    return InsSolution(summary, details, t, corrected, sigma, bridged, err, np.sqrt(var),
                       tuple(getattr(log, "start_utc_jd", (0.0, 0.0))))


def write_ins_csv(solution: InsSolution, path) -> None:
    """``--ins-out``: the corrected attitude at each INS record (:data:`INS_CSV_COLUMNS`),
    times on the frames' clock."""
    import erfa

    from shipstar._atomic import atomic_write_text

    j1, j2 = solution.start_utc_jd
    jd2 = j2 + solution.t_s / DAY_S
    with np.errstate(all="ignore"):
        ymdf = erfa.d2dtf("UTC", 6, np.full(len(jd2), j1), jd2)
    a = solution.angles_rad * RAD2DEG
    s = solution.sigma_arcsec
    src = np.where(solution.bridged, "ins-bridged", "stars+ins")
    rows = [f"{y:04d}-{mo:02d}-{d:02d}T{h:02d}:{mi:02d}:{se:02d}.{fr:06d},{K:.9f},{p:.9f},{r:.9f},{sh:.3f},{sp:.3f},"
            f"{sr:.3f},{x}\n"
            for (y, mo, d, (h, mi, se, fr)), K, p, r, sh, sp, sr, x in
            zip(zip(ymdf[0], ymdf[1], ymdf[2], ymdf[3]), a[:, 0], a[:, 1], a[:, 2], s[:, 0], s[:, 1], s[:, 2], src)]
    atomic_write_text(path, ",".join(INS_CSV_COLUMNS) + "\n" + "".join(rows))


class ForwardIns:
    """The same model, forward only (``shipstar live --ins-udp``): an extended Kalman
    filter updated at each star epoch, and the corrected attitude at each INS record
    as it comes, from the estimate so far.

    Times are seconds since any fixed origin, the same for the records (INS clock) and the
    star epochs (frame clock).  Holds the last :attr:`buffer_s` seconds of records (the
    interpolation at a star epoch) and star epochs waiting for the records around them.
    """

    def __init__(self, model: InsModel | None = None, buffer_s: float = 10.0):
        from collections import deque

        self.model = InsModel() if model is None else model
        self.x, self.P = _prior(self.model)
        self.t_state = None
        self.buffer_s = float(buffer_s)
        self._rec = deque()                     # (t, heading, pitch, roll) rad
        self._pending = deque()                 # (t, z, R) star epochs waiting for records
        self.last_star_t = -math.inf
        self.n_updates = 0
        self.n_gated = 0
        self.n_records = 0
        self.n_dropped = 0

    @property
    def dt_s(self) -> float:
        return float(self.x[_IDT]) * 1e-3

    def _propagate(self, t: float) -> None:
        if self.t_state is None:
            self.t_state = t
            return
        d = t - self.t_state
        if d > 0:
            dh = d / _H_S
            F = _phi(dh)
            self.x = F @ self.x
            self.P = F @ self.P @ F.T + _q(self.model, dh)
            self.t_state = t

    def _window(self, t: float):
        """INS angle (heading unwrapped near the records) and rate at ``t``, or None."""
        rec = self._rec
        if len(rec) < 4 or not rec[0][0] <= t <= rec[-1][0]:
            return None
        ts = np.fromiter((r[0] for r in rec), float, len(rec))
        k = int(np.searchsorted(ts, t))
        lo = min(max(k - 2, 0), len(rec) - 4)
        sub = np.array([rec[i] for i in range(lo, lo + 4)])
        if ts[min(k, len(ts) - 1)] - ts[max(k - 1, 0)] > self.model.max_record_gap_s:
            return None
        ang = sub[:, 1:].copy()
        ang[:, 0] = np.unwrap(ang[:, 0])
        y, dy, _, w2 = _cubic(sub[:, 0], ang, np.array([t]))
        return y[0], dy[0], float(w2[0])

    def add_star(self, t: float, z_rad, cov_rad2) -> None:
        """A star epoch (frame clock): used at once, or when the records around it have come."""
        self._pending.append((float(t), np.asarray(z_rad, float), np.asarray(cov_rad2, float)))
        self._try_pending()

    def _try_pending(self) -> None:
        while self._pending:
            t, z, R = self._pending[0]
            if self._rec and self._rec[-1][0] < t + self.dt_s + 0.05:
                if self._rec[-1][0] < t - self.buffer_s:      # the INS has stopped: drop it
                    self._pending.popleft()
                    self.n_dropped += 1
                    continue
                return
            self._pending.popleft()
            self._update(t, z, R)

    def _update(self, t, z, R) -> None:
        got = self._window(t + self.dt_s)
        if got is None:
            self.n_dropped += 1
            return
        y, dy, w2 = got
        self._propagate(t)
        J = misalignment_jacobian(z[None])[0]
        He = np.zeros((3, _NX))
        He[:, 0:3] = np.eye(3)
        He[:, 4:7] = J
        r = (z - y)
        r[0] = _wrap(r[0])
        r = r * RAD2ASEC + He @ self.x              # z - h(x), h = Y(t + dt) - e(x)
        H = -He
        H[:, _IDT] = dy * RAD2ASEC * 1e-3
        Rt = R * RAD2ASEC ** 2 + np.eye(3) * self.model.white_var_arcsec2 * w2
        S = H @ self.P @ H.T + Rt
        Si = np.linalg.inv(S)
        if self.n_updates > 20 and float(r @ Si @ r) > self.model.gate_chi2:
            self.n_gated += 1
            return
        K = self.P @ H.T @ Si
        self.x = self.x + K @ r
        IKH = np.eye(_NX) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ Rt @ K.T
        self.P = 0.5 * (self.P + self.P.T)
        self.n_updates += 1
        self.last_star_t = max(self.last_star_t, t)

    def add_record(self, t: float, angles_rad):
        """An INS record (INS clock): ``(frame-clock time, corrected angles (3,), sigma_arcsec
        (3,), bridged)``."""
        a = np.asarray(angles_rad, float)
        if self._rec and t <= self._rec[-1][0]:
            raise ShipstarError(f"INS record at {t:.6f} s is not later than the previous one")
        self._rec.append((float(t), *a))
        while self._rec and self._rec[0][0] < t - self.buffer_s:
            self._rec.popleft()
        self.n_records += 1
        self._try_pending()
        tc = t - self.dt_s
        d_h = 0.0 if self.t_state is None else (tc - self.t_state) / _H_S
        J = misalignment_jacobian(a[None])[0]
        H = np.zeros((3, _NX))
        H[:, 0:3] = np.eye(3)
        H[0, 3] = d_h
        H[:, 4:7] = J
        e = H @ self.x
        rate = np.zeros(3)
        if len(self._rec) >= 2:
            (t0, *a0), (t1, *a1) = self._rec[-2], self._rec[-1]
            da = np.subtract(a1, a0)
            da[0] = _wrap(da[0])
            rate = da / (t1 - t0) * RAD2ASEC * 1e-3
        H[:, _IDT] = -rate
        var = np.einsum("ij,jk,ik->i", H, self.P, H) + abs(d_h) * np.array(
            [self.model.heading_random_walk_arcsec_per_sqrt_h ** 2, self.model.level_random_walk_arcsec_per_sqrt_h ** 2,
             self.model.level_random_walk_arcsec_per_sqrt_h ** 2]) + self.model.white_var_arcsec2
        out = a - e * ASEC2RAD
        out[0] = out[0] % (2.0 * math.pi)
        bridged = not (tc - self.last_star_t <= self.model.bridge_after_s)
        return tc, out, np.sqrt(var), bridged

    def summary(self) -> dict:
        """The ``ins`` object (the estimate at the current state time)."""
        s = np.sqrt(np.diag(self.P))
        return {"heading_bias_arcsec": float(self.x[0]), "heading_bias_sigma_arcsec": float(s[0]),
                "heading_drift_arcsec_per_h": float(self.x[3]), "heading_drift_sigma_arcsec_per_h": float(s[3]),
                "pitch_bias_arcsec": float(self.x[1]), "pitch_bias_sigma_arcsec": float(s[1]),
                "roll_bias_arcsec": float(self.x[2]), "roll_bias_sigma_arcsec": float(s[2]),
                "time_offset_s": self.dt_s, "time_offset_sigma_s": float(s[_IDT]) * 1e-3}
