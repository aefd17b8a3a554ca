"""Plate solving of one image: extract stars, identify them, fit the attitude."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.frames import ra_dec_roll_from_C_icrs_from_sensor
from shipstar.units import DEG2RAD, RAD2DEG

__all__ = ["SolveResult", "solve_image", "DEFAULT_FOV_TOLERANCE"]

#: relative FOV uncertainty assumed when only ``fov_deg`` is given
DEFAULT_FOV_TOLERANCE = 0.1


@dataclass(frozen=True, eq=False)
class SolveResult:
    """Attitude of one image.

    Attributes
    ----------
    solved : bool
    reason : str
        Why not solved ("" when solved).
    ra_deg, dec_deg, roll_deg : float
        Boresight and roll (docs/conventions.md); NaN when not solved.
    fov_deg : float
        Horizontal field of view: solved (with ``fov_deg`` input) or the camera's.
    C_icrs_from_sensor : ndarray (3, 3)
        NaN when not solved.
    matched : int
    rms_arcsec : float
    time_ms : float
        Extraction + identification + attitude (not the one-off database build / load).
    xy_px : ndarray (N, 2)
        Extracted centroids, brightest first (up to ``2 max_stars``; elongated detections
        are reported but not used).
    hip : ndarray (N,)
        HIP number of each centroid, -1 when unmatched or not used.
    identification : Identification
    image_shape_hw : tuple
        ``(height_px, width_px)`` of the image.
    date_obs : str
        Mid-exposure UTC (ISO 8601, microseconds, ``Z``) of a FITS image whose header
        gives it (:mod:`shipstar._fitsio` rules); ``""`` otherwise.
    camera_name : str
        Name of the camera model used; ``""`` with ``fov_deg`` (no camera).
    time_problem : str
        Why a FITS image has no ``date_obs`` (its header's problem, one line); ``""``
        when it has one or the image is not FITS.
    """

    solved: bool
    reason: str
    ra_deg: float
    dec_deg: float
    roll_deg: float
    fov_deg: float
    C_icrs_from_sensor: np.ndarray
    matched: int
    rms_arcsec: float
    time_ms: float
    xy_px: np.ndarray
    hip: np.ndarray
    identification: object
    image_shape_hw: tuple
    date_obs: str = ""
    camera_name: str = ""
    time_problem: str = ""

    def as_json_dict(self) -> dict:
        """The ``shipstar solve --json`` object: always the same keys, None for undefined
        numbers and for an unknown ``date_obs`` or ``camera``; ``reason`` is ``""`` when
        solved.  Its star list (``x_px``, ``y_px``, ``hip``; ``hip`` -1 when unmatched),
        time, camera and image size make it a frame for ``shipstar calibrate intrinsics``.
        """

        def num(x):
            return float(x) if math.isfinite(x) else None

        h, w = self.image_shape_hw
        return {
            "solved": bool(self.solved), "reason": str(self.reason),
            "ra_deg": num(self.ra_deg), "dec_deg": num(self.dec_deg),
            "roll_deg": num(self.roll_deg), "fov_deg": num(self.fov_deg),
            "matched": int(self.matched), "rms_arcsec": num(self.rms_arcsec),
            "time_ms": float(self.time_ms),
            "date_obs": self.date_obs or None, "camera": self.camera_name or None,
            "width_px": int(w), "height_px": int(h),
            "stars": [{"x_px": float(x), "y_px": float(y), "hip": int(hh)}
                      for (x, y), hh in zip(self.xy_px.tolist(), self.hip.tolist())],
        }


def _as_image(image):
    if isinstance(image, (str, bytes)) or hasattr(image, "__fspath__"):
        from shipstar.extract import read_image

        return read_image(image)
    arr = np.asarray(image)
    if arr.ndim != 2 or arr.size == 0:
        raise ShipstarError(f"image must be a non-empty 2-D array, got shape {arr.shape}")
    return arr


def _fits_time(image, date_obs_is: str) -> tuple[str, str]:
    """``(date_obs, time_problem)`` of an image file that is FITS (by its first bytes, as
    :func:`shipstar.extract.read_image` recognises it); ``("", "")`` for anything else.

    A header that gives no usable time (none, no exposure length, a malformed date)
    leaves ``date_obs`` empty and says why: the pixels solve without it.
    """
    if not (isinstance(image, str) or hasattr(image, "__fspath__")):
        return "", ""
    from pathlib import Path

    path = Path(image)
    try:
        with open(path, "rb") as fh:
            head = fh.read(9)
    except OSError:
        return "", ""
    if head != b"SIMPLE  =" and not head.startswith(b"\x1f\x8b"):    # FITS, gzipped FITS
        return "", ""
    from shipstar._fitsio import read_fits_header
    from shipstar.sky.time import iso_from_utc_jd

    try:
        info = read_fits_header(path, date_obs_is=date_obs_is)
    except ShipstarError as exc:
        return "", str(exc)
    if not info.has_time:
        return "", info.time_problem
    return iso_from_utc_jd(info.utc_jd1, info.utc_jd2, 6), ""


def _resolve_camera(camera):
    if camera is None or hasattr(camera, "unproject"):
        return camera
    from shipstar.camera import load_camera

    return load_camera(camera)


def solve_image(image, camera=None, fov_deg=None, *, fov_tolerance=None, mag_limit=None,
                centroid_error_px=None, threshold_sigma: float = 5.0, max_stars: int = 60,
                p_false_max: float = 1e-6, max_time_s: float = 2.0, database=None,
                date_obs_is: str = "start") -> SolveResult:
    """Extract the stars of an image, identify them (lost-in-space) and fit the attitude.

    Parameters
    ----------
    image : path or ndarray (H, W)
        FITS / PNG / TIFF / JPEG / .npy file (read by :func:`shipstar.extract.read_image`)
        or the pixel array.
    camera : Camera, str or path, optional
        Calibrated camera (or a preset name / camera TOML file).
    fov_deg : float, optional
        Without a camera: horizontal field of view of a pinhole camera with the principal
        point at the image centre.  Known to +-``fov_tolerance`` (default 10 %); the
        solver refines it from the matched stars.
    mag_limit : float, optional
        Database magnitude limit (default: adapted to the field, see build_database).
    centroid_error_px : float, optional
        Centroid error bound per axis (default 1 px; with ``fov_deg`` the solver also
        allows for the focal-length uncertainty).
    threshold_sigma, max_stars : extraction settings: the brightest ``max_stars`` point-like
        detections are used (elongated ones - roofs, trees, trails - are left out).
    p_false_max, max_time_s : see :func:`identify_lost_in_space`.
    database : StarDatabase, optional
        Use this database instead of building / loading one.
    date_obs_is : {"start", "mid"}
        What a FITS image's ``DATE-OBS`` means when its header has no ``DATE-AVG`` /
        ``DATE-BEG`` (the FITS standard: the start of the exposure); sets ``date_obs``.
    """
    from shipstar._fitsio import DATE_OBS_CHOICES
    from shipstar.identify import build_database, identify_lost_in_space

    if date_obs_is not in DATE_OBS_CHOICES:
        raise ShipstarError(f"date_obs_is must be one of {', '.join(DATE_OBS_CHOICES)}, "
                            f"got {date_obs_is!r}")
    camera = _resolve_camera(camera)
    if (camera is None) == (fov_deg is None):
        raise ShipstarError("give exactly one of camera and fov_deg")
    pixels = _as_image(image)
    date_obs, time_problem = _fits_time(image, date_obs_is)
    about = {"date_obs": date_obs, "camera_name": "" if camera is None else str(camera.name),
             "time_problem": time_problem}
    h, w = pixels.shape
    if camera is not None:
        if (w, h) != (camera.width_px, camera.height_px):
            raise ShipstarError(f"image is {w}x{h} px but camera {camera.name!r} is "
                                f"{camera.width_px}x{camera.height_px}")
        tol = 0.0 if fov_tolerance is None else float(fov_tolerance)
        fov_x = camera.fov_deg * DEG2RAD
    else:
        fov_x = float(fov_deg) * DEG2RAD
        if not math.isfinite(fov_x) or not 0.5 * DEG2RAD <= fov_x <= 60.0 * DEG2RAD:
            raise ShipstarError(f"fov_deg must be within 0.5 .. 60, got {fov_deg}")
        tol = DEFAULT_FOV_TOLERANCE if fov_tolerance is None else float(fov_tolerance)
    err = 1.0 if centroid_error_px is None else float(centroid_error_px)
    if database is None:
        if camera is not None:
            database = build_database(camera, mag_limit, fov_tolerance=tol)
        else:
            fov_y = 2.0 * math.atan(math.tan(0.5 * fov_x) * h / w)
            database = build_database((fov_x * RAD2DEG, fov_y * RAD2DEG), mag_limit,
                                      fov_tolerance=tol)
    t1 = time.perf_counter()
    from shipstar.extract import FLAG_ELONGATED, extract_stars

    extraction = extract_stars(pixels, threshold_sigma=threshold_sigma, max_stars=2 * max_stars)
    xy_all = np.asarray(extraction.xy_px, dtype=float).reshape(-1, 2)
    # elongated detections (roofs, trees, trails, blends; in a smeared frame only those
    # beyond the common smear are flagged) are not stars: leave them out
    use = np.flatnonzero((np.asarray(extraction.flags) & FLAG_ELONGATED) == 0)[:max_stars]
    xy = xy_all[use]
    ident = identify_lost_in_space(
        xy, database, camera=camera, fov_deg=None if camera is not None else fov_x * RAD2DEG,
        image_shape_hw=(h, w), centroid_error_px=err, focal_tolerance=tol,
        p_false_max=p_false_max, max_time_s=max_time_s)
    hip = np.full(xy_all.shape[0], -1, dtype=np.int64)
    hip[use] = ident.hip
    fov_solved = 2.0 * math.atan(ident.focal_scale * math.tan(0.5 * fov_x)) * RAD2DEG
    elapsed_ms = (time.perf_counter() - t1) * 1e3
    if not ident.solved:
        reason = ident.reason
        if xy.shape[0] == 0:
            reason = "no stars found in the image"
        elif xy.shape[0] < 5:
            reason = f"only {xy.shape[0]} stars found in the image: {ident.reason}"
        return SolveResult(False, reason, math.nan, math.nan, math.nan, fov_solved,
                           np.full((3, 3), np.nan), 0, math.nan, elapsed_ms, xy_all, hip,
                           ident, (h, w), **about)
    C = ident.C_icrs_from_sensor
    ra, dec, roll = ra_dec_roll_from_C_icrs_from_sensor(C)
    return SolveResult(True, "", float(ra * RAD2DEG), float(dec * RAD2DEG), float(roll * RAD2DEG),
                       fov_solved, C, ident.n_matched, ident.rms_arcsec,
                       (time.perf_counter() - t1) * 1e3, xy_all, hip, ident, (h, w), **about)
