"""Star extraction: find the stars in a frame and measure sub-pixel centroids.

``extract_stars(image)`` runs, on a 2-D frame in ADU:

1. background and noise on a coarse mesh (block medians and clipped RMS of a
   sub-sampled view, 3x3 median filtered, bilinear between blocks);
2. candidate pixels above ``background + 2.5 sigma`` (one comparison pass), their local
   maxima, and the detection test on each maximum's 3x3 sum (``threshold_sigma``);
   hot pixels and cosmic rays are rejected as sharper than the frame's PSF;
3. 8-connected components of the candidates (one star per component: size, peak,
   saturation, border contact, elongation);
4. the PSF sigma (and, if not given, the gain) from the brightest stars, then
   centroids: a pixel-integrated Gaussian fitted by vectorised Gauss-Newton on a fixed
   window (``refine="gaussian"``, the default) or the thresholded centre of gravity.

Frames smeared by the sensor's motion (a ship rolling at a few deg/s smears A1's stars
over up to ~40 px) take another path when ``smear_px=(dx, dy)`` is given or a smear of
3 px or more is found in the frame: a line-shaped matched filter finds the streaks, a
smear field (field rotation) is fitted to the bright ones, and each star is fitted with
the pixel-integrated Gaussian moved along its smear; the centroid is the position at
mid-exposure. A given smear is measured again from the brightest streaks unless its
error, ``smear_sigma_px``, is at most 0.05 px (a sensor's fitted motion knows it that
well); such a smear of 1.5-3 px is measured as streaks on stars found as points.

``read_image(path)`` reads FITS, PNG, TIFF, JPEG and ``.npy`` files. See
``docs/extraction.md`` for the method, the flags and the measured accuracy and speed.
"""

from __future__ import annotations

from shipstar.extract._core import STREAK_MIN_PX, extract_stars
from shipstar.extract._io import read_image
from shipstar.extract._result import (
    FLAG_EDGE,
    FLAG_ELONGATED,
    FLAG_FIT_FAILED,
    FLAG_NAMES,
    FLAG_SATURATED,
    Extraction,
    flag_names,
)

__all__ = [
    "Extraction", "extract_stars", "read_image", "flag_names", "FLAG_NAMES",
    "FLAG_SATURATED", "FLAG_EDGE", "FLAG_FIT_FAILED", "FLAG_ELONGATED", "STREAK_MIN_PX",
]
