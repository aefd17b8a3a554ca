"""The star sensor's own attitude accuracy: cross-boresight and roll-about-boresight.

For N stars with isotropic direction noise sigma (rad) on the tangent plane, the
attitude Fisher information about the sensor axes is ``F = sum_i (I - w_i w_i^T) / sigma^2``
(the Cramer-Rao bound of any unbiased attitude estimator, QUEST's covariance).  With the
stars spread uniformly on the sky over the field of view, ``F = N / sigma^2 * E[I - w w^T]``,
the expectation taken over the field (tangent-plane coordinates ``u, v`` with solid-angle
density ``(1 + u^2 + v^2)^(-3/2)``, integrated by Gauss-Legendre quadrature).  Its inverse
gives the standard results for small fields:

    sigma_cross ~ sigma / sqrt(N),       sigma_roll ~ sigma / (sqrt(N) * r_rms)

with ``r_rms`` the rms angular distance (rad) of the stars from the boresight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.units import ASEC2RAD, DEG2RAD, RAD2ASEC

__all__ = ["SensorAccuracy", "sensor_accuracy", "expected_star_count", "fov_solid_angle_sr"]


def _positive(name, value, upper=None):
    v = float(value)
    if not math.isfinite(v) or v <= 0 or (upper is not None and v >= upper):
        bound = f" and < {upper}" if upper is not None else ""
        raise ShipstarError(f"{name} must be finite, > 0{bound}, got {value}")
    return v


@dataclass(frozen=True)
class SensorAccuracy:
    """Predicted attitude accuracy of one star sensor, about its own axes.

    Attributes
    ----------
    fov_deg, fov_height_deg : float
        Full field of view across the image width / height.
    n_stars : float
        Stars used per frame.
    sigma_star_arcsec : float
        Direction noise of one star, per tangent-plane axis.
    covariance_rad2 : ndarray, shape (3, 3)
        Attitude error covariance about the sensor axes (X boresight, Y image up,
        Z image right), as :class:`shipstar.attitude.AttitudeSolution` reports it.
    sigma_cross_arcsec : float
        Cross-boresight 1-sigma, ``sqrt((P_yy + P_zz) / 2)``.
    sigma_roll_arcsec : float
        Roll about the boresight, ``sqrt(P_xx)``.
    rms_radius_rad : float
        RMS angular distance of the stars from the boresight.
    """

    fov_deg: float
    fov_height_deg: float
    n_stars: float
    sigma_star_arcsec: float
    covariance_rad2: np.ndarray
    sigma_cross_arcsec: float
    sigma_roll_arcsec: float
    rms_radius_rad: float

    def as_dict(self) -> dict:
        return {"fov_deg": self.fov_deg, "fov_height_deg": self.fov_height_deg, "n_stars": self.n_stars,
                "sigma_star_arcsec": self.sigma_star_arcsec, "sigma_cross_arcsec": self.sigma_cross_arcsec,
                "sigma_roll_arcsec": self.sigma_roll_arcsec,
                "rms_radius_deg": math.degrees(self.rms_radius_rad)}


def _field_moments(half_w_rad: float, half_h_rad: float, n_quad: int):
    """E[w w^T] and E[angle^2] over the field, stars uniform on the sky."""
    x, wq = np.polynomial.legendre.leggauss(n_quad)
    u = math.tan(half_w_rad) * x
    v = math.tan(half_h_rad) * x
    U, V = np.meshgrid(u, v, indexing="xy")
    rho2 = 1.0 + U**2 + V**2
    weight = np.outer(wq, wq) * rho2**-1.5
    weight = weight / weight.sum()
    w = np.stack([np.ones_like(U), V, U], axis=-1) / np.sqrt(rho2)[..., None]   # (X, Y up, Z right)
    Eww = np.einsum("ij,ija,ijb->ab", weight, w, w)
    ang2 = np.sum(weight * np.arctan(np.sqrt(U**2 + V**2)) ** 2)
    return Eww, ang2


def sensor_accuracy(fov_deg: float, n_stars: float, sigma_star_arcsec: float, *,
                    fov_height_deg: float | None = None, n_quad: int = 48) -> SensorAccuracy:
    """Attitude covariance of a star sensor from its field, star count and star noise.

    Parameters
    ----------
    fov_deg : float
        Full field of view across the image width (deg), in (0, 180).
    n_stars : float
        Stars used per frame (an expectation may be fractional), >= 2.
    sigma_star_arcsec : float
        1-sigma direction noise of one star per tangent-plane axis (centroid noise times
        the pixel scale), > 0.
    fov_height_deg : float, optional
        Full field of view across the height; default square.
    n_quad : int
        Gauss-Legendre nodes per axis.

    Returns
    -------
    SensorAccuracy
    """
    fw = _positive("fov_deg", fov_deg, 180.0)
    fh = fw if fov_height_deg is None else _positive("fov_height_deg", fov_height_deg, 180.0)
    n = float(n_stars)
    if not math.isfinite(n) or n < 2:
        raise ShipstarError(f"n_stars must be >= 2 (one star does not fix the roll), got {n_stars}")
    sig = _positive("sigma_star_arcsec", sigma_star_arcsec) * ASEC2RAD
    Eww, ang2 = _field_moments(0.5 * fw * DEG2RAD, 0.5 * fh * DEG2RAD, int(n_quad))
    F = n / sig**2 * (np.eye(3) - Eww)
    P = np.linalg.inv(F)
    P = 0.5 * (P + P.T)
    return SensorAccuracy(
        fov_deg=fw, fov_height_deg=fh, n_stars=n, sigma_star_arcsec=float(sigma_star_arcsec),
        covariance_rad2=P, sigma_cross_arcsec=float(np.sqrt(0.5 * (P[1, 1] + P[2, 2])) * RAD2ASEC),
        sigma_roll_arcsec=float(np.sqrt(P[0, 0]) * RAD2ASEC), rms_radius_rad=float(np.sqrt(ang2)),
    )


def fov_solid_angle_sr(fov_deg: float, fov_height_deg: float | None = None) -> float:
    """Solid angle (sr) of a rectangular field: ``4 asin(sin(a/2) sin(b/2))``."""
    fw = _positive("fov_deg", fov_deg, 180.0)
    fh = fw if fov_height_deg is None else _positive("fov_height_deg", fov_height_deg, 180.0)
    return 4.0 * math.asin(math.sin(0.5 * fw * DEG2RAD) * math.sin(0.5 * fh * DEG2RAD))


def expected_star_count(fov_deg: float, mag_limit: float, *, fov_height_deg: float | None = None) -> float:
    """Mean number of stars brighter than ``mag_limit`` in the field.

    Liebe (2002, "Accuracy performance of star trackers - a tutorial", seed 001's
    ref. [3]): ``6.57 exp(1.08 m)`` stars over the whole sky, times the field's share
    ``Omega / (4 pi)``.  A sky average: the galactic plane has several times more.
    """
    m = float(mag_limit)
    if not math.isfinite(m) or not -2.0 <= m <= 12.0:
        raise ShipstarError(f"mag_limit must be within [-2, 12], got {mag_limit}")
    return 6.57 * math.exp(1.08 * m) * fov_solid_angle_sr(fov_deg, fov_height_deg) / (4.0 * math.pi)
