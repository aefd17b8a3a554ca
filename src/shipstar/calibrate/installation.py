"""Installation angles of a star sensor from dock frames (seed 000 section 3, seed 003 step 4).

In dock the ship's true attitude is known: heading K0 from the theodolite's azimuth
mark, level (psi0, theta0) from the precision levels.  Each frame's sensor attitude in
the horizontal frame then gives one installation matrix::

    C_deck_from_sensor = C_hor_from_deck(K0, psi0, theta0).T @ C_hor_from_sensor

(seed 000 eq. 17, written with shipstar's names).  Over the session the matrices are
averaged on SO(3) (chordal mean, :func:`mean_rotation`) after rejecting outlying frames,
and the installation angles (A, E, gamma) of the mean are reported with the per-frame
standard deviation of each angle (seed 000 Tables 2-3) and the standard error of the mean.

Files: :func:`save_installation` / :func:`load_installation` (TOML, units in every key;
see docs/file-formats.md).
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.calibrate._installation_mean import angle_deviations_rad, mean_rotation, robust_mean_rotation
from shipstar.calibrate._installation_model import DockConditions, Installation
from shipstar.calibrate._installation_toml import load_installation, save_installation
from shipstar.errors import ShipstarError
from shipstar.units import RAD2ASEC

__all__ = [
    "DockConditions",
    "Installation",
    "installation_from_frame",
    "calibrate_installation",
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


def calibrate_installation(C_hor_from_sensor, C_hor_from_deck, *, solved=None, sensor: str, camera: str,
                           reasons=None, k_sigma: float = 5.0, **meta) -> Installation:
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
        Outlier threshold of :func:`robust_mean_rotation`.
    **meta
        ``session``, ``date_utc``, ``dock`` (:class:`DockConditions`), ``warnings`` (tuple of str).

    Returns
    -------
    Installation

    Raises
    ------
    ShipstarError
        Fewer than 2 solved frames (the message quotes the first failure reasons).
    """
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
    d = angle_deviations_rad(C_ds_all[ok][keep], mean)
    n = int(keep.sum())
    std = np.std(d, axis=0, ddof=1) * RAD2ASEC if n > 1 else np.full(3, np.nan)
    sem = std / math.sqrt(n)
    return Installation.from_matrix(
        sensor, camera, mean, std_arcsec=tuple(float(x) for x in std), sem_arcsec=tuple(float(x) for x in sem),
        n_frames=m, n_used=n, n_failed=int(m - ok.sum()), n_rejected=int(ok.sum() - n), **meta)
