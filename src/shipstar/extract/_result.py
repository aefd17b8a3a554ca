"""The result of a star extraction and its per-star flags."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "Extraction", "FLAG_SATURATED", "FLAG_EDGE", "FLAG_FIT_FAILED", "FLAG_ELONGATED",
    "FLAG_NAMES", "flag_names",
]

#: A pixel of the star reached the saturation level; its centroid is the thresholded
#: centre of gravity of its unsaturated-and-saturated pixels, its flux a lower bound.
FLAG_SATURATED = 1
#: The star's pixels or its fit window touch the image border: centroid may be biased.
FLAG_EDGE = 2
#: The Gaussian refinement did not converge; the centroid is the centre of gravity.
FLAG_FIT_FAILED = 4
#: The star's pixels are elongated (axis ratio > 2): smear, a satellite trail, a blend. In a
#: smeared frame: longer or wider than one streak of the common smear (a trail), or sharing
#: its pixels with another detection (a blend).
FLAG_ELONGATED = 8

#: Bit -> name, as the CLI's JSON writes them.
FLAG_NAMES = {
    FLAG_SATURATED: "saturated",
    FLAG_EDGE: "edge",
    FLAG_FIT_FAILED: "fit_failed",
    FLAG_ELONGATED: "elongated",
}


def flag_names(flags: int) -> list[str]:
    """Names of the bits set in one star's ``flags`` value, e.g. ``['saturated', 'edge']``."""
    return [name for bit, name in FLAG_NAMES.items() if int(flags) & bit]


@dataclass(frozen=True)
class Extraction:
    """Stars found in one frame, brightest (largest ``flux_adu``) first.

    Attributes
    ----------
    xy_px : (N, 2) float array
        Centroids (x right, y down; centre of the top-left pixel = (0, 0)).
    flux_adu : (N,) float array
        Total star signal above the background, ADU (PSF integral when fitted).
    peak_adu : (N,) float array
        Value of the star's brightest pixel, ADU, background *included* (compare with
        the saturation level).
    npix : (N,) int array
        Connected pixels above the segmentation threshold.
    flags : (N,) int array
        Bitmask of ``FLAG_*`` values (see :func:`flag_names`).
    snr : (N,) float array
        Signal-to-noise ratio of ``flux_adu``.
    xy_sigma_px : (N,) float array
        Predicted 1-sigma centroid error per axis, ``sqrt((var_x + var_y) / 2)`` of
        ``xy_cov_px2``.
    xy_cov_px2 : (N, 2, 2) float array
        Predicted covariance of the centroid (x, y): the Cramer-Rao bound at the measured
        star, which the fit reaches (the centre of gravity does not); NaN for saturated
        point stars (centre of gravity) and failed fits. Scaled for correlated (JPEG)
        noise. A streak's is elongated: its error along the smear is larger.
    background_adu : float
        Median background level over the frame.
    noise_adu : float
        Median background noise (RMS per pixel) over the frame.
    psf_sigma_px : float
        PSF sigma used by the Gaussian refinement (given or fitted; NaN if none).
    shape_hw : tuple of int
        Image height and width.
    smear_px : (2,) float array
        Common smear (dx, dy) the stars were measured with (given or estimated; the sign
        is arbitrary); (0, 0) when the frame was treated as unsmeared.
    """

    xy_px: np.ndarray
    flux_adu: np.ndarray
    peak_adu: np.ndarray
    npix: np.ndarray
    flags: np.ndarray
    snr: np.ndarray
    xy_sigma_px: np.ndarray
    xy_cov_px2: np.ndarray
    background_adu: float
    noise_adu: float
    psf_sigma_px: float
    shape_hw: tuple
    smear_px: np.ndarray

    def __len__(self) -> int:
        return int(len(self.xy_px))
