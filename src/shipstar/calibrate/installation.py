"""Installation angles of a star sensor from dock frames (seed 000 section 3, seed 003 step 4).

In dock the ship's true attitude is known: heading K0 from the theodolite's azimuth
mark, level (psi0, theta0) from the precision levels.  Each frame's sensor attitude in
the horizontal frame then gives one installation matrix::

    C_deck_from_sensor = C_hor_from_deck(K0, psi0, theta0).T @ C_hor_from_sensor

(seed 000 eq. 17, written with shipstar's names).  Over the session the matrices are
averaged on SO(3) (chordal mean, :func:`mean_rotation`) after rejecting outlying frames,
and the installation angles (A, E, gamma) of the mean are reported with the per-frame
standard deviation of each angle (seed 000 Tables 2-3) and the standard error of the mean.

The ship must be still: every frame is referred to the one dock attitude given.  Frames
of a moving ship (at sea, rolling by degrees) give installation matrices that scatter
far beyond their measurement noise, and their mean is off by up to that scatter while
the standard error, ``std / sqrt(n)``, looks small.  :func:`calibrate_installation`
therefore tests the kept frames' scatter against what a still ship can give (a
chi-square test, :func:`still_ship_test`) and refuses a session that fails it.

Files: :func:`save_installation` / :func:`load_installation` (TOML, units in every key;
see docs/file-formats.md).
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from shipstar.calibrate._installation_mean import angle_deviations_rad, mean_rotation, robust_mean_rotation
from shipstar.calibrate._installation_model import DockConditions, Installation
from shipstar.calibrate._installation_toml import load_installation, save_installation
from shipstar.errors import AccuracyWarning, ShipstarError
from shipstar.frames import rotation_vectors_rad
from shipstar.units import ASEC2RAD, RAD2ASEC

__all__ = [
    "DockConditions",
    "Installation",
    "installation_from_frame",
    "calibrate_installation",
    "still_ship_test",
    "STILL_SHIP_ARCSEC",
    "mean_rotation",
    "robust_mean_rotation",
    "save_installation",
    "load_installation",
]


def installation_from_frame(C_hor_from_sensor, C_hor_from_deck) -> np.ndarray:
    """Installation matrices from sensor attitudes and the known ship attitude.

    ``C_deck_from_sensor = C_hor_from_deck.T @ C_hor_from_sensor`` (seed 000 eq. 17).

    Parameters
    ----------
    C_hor_from_sensor : array_like, shape (..., 3, 3)
    C_hor_from_deck : array_like, shape (..., 3, 3)
        Broadcast against the first (one dock attitude for all frames, or one per frame).

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    C_hs = np.asarray(C_hor_from_sensor, float)
    C_hd = np.asarray(C_hor_from_deck, float)
    if C_hs.shape[-2:] != (3, 3) or C_hd.shape[-2:] != (3, 3):
        raise ShipstarError(f"attitude matrices must be (..., 3, 3), got {C_hs.shape} and {C_hd.shape}")
    return np.swapaxes(C_hd, -1, -2) @ C_hs


#: Frame-to-frame scatter (1 sigma per sensor axis: about the boresight, and across it)
#: that a ship at rest in dock may add to each frame's own measurement noise: mooring
#: motion, vibration, seeing's image motion, unmodelled noise.  Seed 000's real dock night
#: (docs/calibration-dock.md) scatters 7.1'' / 5.9'' across the boresight (az cos el, el)
#: and 63.6'' about it for A1, 5.0'' / 3.1'' and 54.6'' for A2, all its noise included;
#: simulated dock frames 0.03-0.4'' and 0.5-4''.  Three times the real night's, so that no
#: dock session comes near the limit; a ship at sea rolls and pitches by degrees (the
#: simulated sea session: 2300'' and 3100'').
STILL_SHIP_ARCSEC = (200.0, 20.0)               # (about the boresight, across it), per axis


def still_ship_test(C_deck_from_sensor, mean, covariance_rad2=None, *, k_sigma: float = 5.0,
                    still_arcsec=STILL_SHIP_ARCSEC) -> dict:
    """Whether frames' installation matrices scatter as a still ship's can.

    Each frame's deviation from the mean, ``d = log(mean.T @ C)`` (sensor axes: boresight,
    then across it), is weighed by the frame's expected covariance: its own measurement
    noise (``covariance_rad2``, the attitude solution's, sensor axes; none: 0) plus
    :data:`STILL_SHIP_ARCSEC` squared (what a ship at rest may add).  The sum, chi-square on
    ``3 (n - 1)`` degrees of freedom for a still ship, is compared with its quantile at
    the Gaussian tail of ``k_sigma`` (5 sigma: 2.9e-7; limit 3.7 x the degrees of freedom
    for 2 frames, 1.6 x for 20, 1.3 x for 160).

    Parameters
    ----------
    C_deck_from_sensor : array_like, shape (n, 3, 3)
        The frames' installation matrices (n >= 2).
    mean : array_like, shape (3, 3)
    covariance_rad2 : array_like, shape (n, 3, 3), optional
    k_sigma : float
    still_arcsec : (float, float)
        The still ship's allowance about and across the boresight.

    Returns
    -------
    dict
        ``moved`` (bool), ``chi2``, ``dof``, ``limit``, ``n``; ``scatter_arcsec`` and
        ``expected_arcsec``: rms per frame about and across the boresight (per axis),
        observed and expected.
    """
    from scipy.special import chdtri, ndtr

    C = np.asarray(C_deck_from_sensor, float)
    n = len(C)
    d = rotation_vectors_rad(np.einsum("ji,mjk->mik", np.asarray(mean, float), C))    # log(mean^T C)
    allow = np.diag(np.square(np.array([still_arcsec[0], still_arcsec[1], still_arcsec[1]], float) * ASEC2RAD))
    P = np.zeros((n, 3, 3)) if covariance_rad2 is None else np.asarray(covariance_rad2, float).reshape(n, 3, 3)
    Q = P + allow
    chi2 = float(np.einsum("mi,mi->", d, np.linalg.solve(Q, d[..., None])[..., 0]))
    dof = 3 * (n - 1)
    limit = float(chdtri(dof, ndtr(-float(k_sigma)))) if dof > 0 else math.inf
    f = max(n - 1, 1)
    scatter = (math.sqrt(np.sum(d[:, 0] ** 2) / f), math.sqrt(np.sum(d[:, 1:] ** 2) / (2 * f)))
    expected = (math.sqrt(np.mean(Q[:, 0, 0])), math.sqrt(np.mean(Q[:, 1, 1] + Q[:, 2, 2]) / 2))
    return {"moved": chi2 > limit, "chi2": chi2, "dof": dof, "limit": limit, "n": n,
            "scatter_arcsec": tuple(x * RAD2ASEC for x in scatter),
            "expected_arcsec": tuple(x * RAD2ASEC for x in expected)}


def _moved_message(sensor: str, test: dict) -> str:
    """One line: the ship moved during the calibration frames (:func:`still_ship_test`)."""
    def g(x):
        return f"{x:.0f}" if x >= 100 else f"{x:.3g}"

    (s_roll, s_cross), (e_roll, e_cross) = test["scatter_arcsec"], test["expected_arcsec"]
    return (f"sensor {sensor}: the ship moved during the calibration frames: their installation scatters "
            f"{g(s_cross)}'' across the boresight and {g(s_roll)}'' about it (rms of {test['n']} frames) against "
            f"{g(e_cross)}'' and {g(e_roll)}'' expected of a still ship (chi-square {g(test['chi2'])} on "
            f"{test['dof']} degrees of freedom, {g(test['limit'])} at most); the calibration needs the ship "
            "still at the heading and level given for every frame")


def calibrate_installation(C_hor_from_sensor, C_hor_from_deck, *, solved=None, sensor: str, camera: str,
                           reasons=None, k_sigma: float = 5.0, covariance_rad2=None, if_moved: str = "refuse",
                           moved_hint: str = "", **meta) -> Installation:
    """Installation angles from a dock session's per-frame sensor attitudes.

    Parameters
    ----------
    C_hor_from_sensor : array_like, shape (M, 3, 3)
        Each frame's sensor attitude in the horizontal frame (rows of unsolved frames
        may be NaN).
    C_hor_from_deck : array_like, shape (3, 3) or (M, 3, 3)
        Known ship attitude (seed 000 eq. 3), constant in dock or per frame.
    solved : array_like of bool, shape (M,), optional
        Frames whose attitude solved (default: the finite ones).
    sensor, camera : str
        Names recorded in the result.
    reasons : sequence of str, optional
        Why each unsolved frame failed (quoted in the error when too few solved).
    k_sigma : float
        Outlier threshold of :func:`robust_mean_rotation`, and the tail of the still-ship
        test (:func:`still_ship_test`).
    covariance_rad2 : array_like, shape (M, 3, 3), optional
        Each frame's attitude error covariance (sensor axes; the attitude solution's
        ``covariance_rad2``; rows of unsolved frames may be NaN): the still-ship test
        expects this noise besides :data:`STILL_SHIP_ARCSEC` (default: that alone).
    if_moved : {"refuse", "warn"}
        When the kept frames scatter more than a still ship's can (the ship moved):
        ShipstarError, or an AccuracyWarning (also added to the result's ``warnings``).
    moved_hint : str
        Appended to the refusal (e.g. how to override it).
    **meta
        ``session``, ``date_utc``, ``dock`` (:class:`DockConditions`), ``warnings`` (tuple of str).

    Returns
    -------
    Installation

    Raises
    ------
    ShipstarError
        Fewer than 2 solved frames (the message quotes the first failure reasons); the
        ship moved during the frames (``if_moved="refuse"``, one line with the scatter
        and the expected).
    """
    if if_moved not in ("refuse", "warn"):
        raise ShipstarError(f"if_moved must be 'refuse' or 'warn', got {if_moved!r}")
    C_ds_all = installation_from_frame(C_hor_from_sensor, C_hor_from_deck)
    if C_ds_all.ndim != 3:
        raise ShipstarError(f"C_hor_from_sensor must be a (M, 3, 3) stack, got shape {np.shape(C_hor_from_sensor)}")
    m = len(C_ds_all)
    finite = np.all(np.isfinite(C_ds_all), axis=(1, 2))
    ok = finite if solved is None else (np.asarray(solved, bool) & finite)
    if ok.shape != (m,):
        raise ShipstarError(f"solved must have shape ({m},), got {ok.shape}")
    if ok.sum() < 2:
        why = ""
        if reasons is not None:
            first = sorted({str(r) for r, s in zip(reasons, ok) if not s and r})[:2]
            why = ("; " + "; ".join(first)) if first else ""
        raise ShipstarError(f"sensor {sensor}: {int(ok.sum())} of {m} frames solved, at least 2 needed{why}")
    mean, keep = robust_mean_rotation(C_ds_all[ok], k_sigma=k_sigma)
    cov = None
    if covariance_rad2 is not None:
        cov = np.asarray(covariance_rad2, float)
        if cov.shape != (m, 3, 3):
            raise ShipstarError(f"covariance_rad2 must have shape ({m}, 3, 3), got {cov.shape}")
        cov = cov[ok][keep]
        if not np.all(np.isfinite(cov)):
            raise ShipstarError(f"sensor {sensor}: a solved frame has a non-finite attitude covariance")
    test = still_ship_test(C_ds_all[ok][keep], mean, cov, k_sigma=k_sigma)
    if test["moved"]:
        text = _moved_message(sensor, test)
        if if_moved == "refuse":
            raise ShipstarError(f"{text}; {moved_hint}" if moved_hint else text)
        text += "; written anyway: the installation may be off by up to the scatter, not the sem"
        warnings.warn(text, AccuracyWarning, stacklevel=2)
        meta["warnings"] = (*tuple(meta.get("warnings", ())), text)
    d = angle_deviations_rad(C_ds_all[ok][keep], mean)
    n = int(keep.sum())
    std = np.std(d, axis=0, ddof=1) * RAD2ASEC if n > 1 else np.full(3, np.nan)
    sem = std / math.sqrt(n)
    return Installation.from_matrix(
        sensor, camera, mean, std_arcsec=tuple(float(x) for x in std), sem_arcsec=tuple(float(x) for x in sem),
        n_frames=m, n_used=n, n_failed=int(m - ok.sum()), n_rejected=int(ok.sum() - n), **meta)
