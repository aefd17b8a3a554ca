"""Synthetic centroid frames with known truth, for tests and benchmarks.

Catalog stars of a database are projected with the camera model at a given attitude;
then centroid noise, magnitude noise (reorders the brightness ranking), dropped stars
and false stars (uniform over the image, at random brightness ranks) are applied.
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np

from shipstar.frames import C_icrs_from_sensor, matrix_from_q_wxyz

__all__ = ["SimFrame", "random_attitudes", "rotated_about_random_axis", "simulate_frame"]


@dataclass(frozen=True, eq=False)
class SimFrame:
    """One synthetic frame.

    Attributes
    ----------
    xy_px : ndarray (N, 2)
        Centroids, brightest (by noisy magnitude) first.
    mag : ndarray (N,)
        Noisy magnitudes (false stars get random ones).
    truth_row : ndarray (N,)
        Database star row of each centroid, -1 for a false star.
    C_icrs_from_sensor : ndarray (3, 3)
        True attitude.
    """

    xy_px: np.ndarray
    mag: np.ndarray
    truth_row: np.ndarray
    C_icrs_from_sensor: np.ndarray


def random_attitudes(n: int, rng) -> np.ndarray:
    """``n`` attitudes ``(n, 3, 3)`` uniform over the sky and in roll."""
    ra = rng.uniform(0.0, 2.0 * np.pi, n)
    dec = np.arcsin(rng.uniform(-1.0, 1.0, n))
    roll = rng.uniform(0.0, 2.0 * np.pi, n)
    return C_icrs_from_sensor(ra, dec, roll)


def rotated_about_random_axis(C, angle_deg: float, rng) -> np.ndarray:
    """``C @ R``: ``R`` a rotation by ``angle_deg`` about a random axis (a prior that is
    ``angle_deg`` off the truth ``C``, (3, 3))."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    a = math.radians(angle_deg) / 2
    return C @ matrix_from_q_wxyz(np.concatenate([[math.cos(a)], math.sin(a) * axis]))


def simulate_frame(db, camera, C, rng, *, sigma_px: float = 0.2, mag_sigma: float = 0.2,
                   n_drop: int = 0, n_false: int = 0, margin_px: float = 2.0) -> SimFrame:
    """Project the database stars seen by ``camera`` at attitude ``C`` and spoil them.

    Parameters
    ----------
    db : StarDatabase
    camera : Camera
    C : ndarray (3, 3)
        ``C_icrs_from_sensor``.
    sigma_px : float
        Centroid noise (Gaussian, per axis).
    mag_sigma : float
        Magnitude noise (Gaussian) before sorting by brightness.
    n_drop, n_false : int
        Stars removed at random / false stars added at random positions and ranks.
    """
    rows = db.near(C[:, 0])
    w = db.u_icrs[rows] @ C
    front = w[:, 0] > 0
    rows, w = rows[front], w[front]
    xy = camera.project(w)
    inside = camera.in_image(xy, margin_px=margin_px)
    rows, xy = rows[inside].astype(np.int64), xy[inside]
    mag = db.mag[rows].astype(float) + rng.normal(0.0, mag_sigma, rows.size)
    xy = xy + rng.normal(0.0, sigma_px, xy.shape)
    if n_drop > 0 and rows.size:
        keep = np.ones(rows.size, bool)
        keep[rng.choice(rows.size, size=min(n_drop, rows.size), replace=False)] = False
        rows, xy, mag = rows[keep], xy[keep], mag[keep]
    if n_false > 0:
        fx = rng.uniform(margin_px, camera.width_px - 1 - margin_px, n_false)
        fy = rng.uniform(margin_px, camera.height_px - 1 - margin_px, n_false)
        lo = float(np.min(mag)) if mag.size else 0.0
        hi = float(np.max(mag)) if mag.size else 7.0
        fmag = rng.uniform(lo - 0.5, hi, n_false)
        rows = np.concatenate([rows, np.full(n_false, -1)])
        xy = np.concatenate([xy, np.stack([fx, fy], 1)])
        mag = np.concatenate([mag, fmag])
    order = np.argsort(mag, kind="stable")
    return SimFrame(xy_px=xy[order], mag=mag[order], truth_row=rows[order],
                    C_icrs_from_sensor=np.asarray(C, float))
