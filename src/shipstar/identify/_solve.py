"""Plate solving of one image: extract stars, identify them, fit the attitude."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.frames import ra_dec_roll_from_C_icrs_from_sensor
from shipstar.units import DEG2RAD, RAD2DEG

__all__ = ["SolveResult", "solve_image", "solve_centroids", "DEFAULT_FOV_TOLERANCE"]

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
        Horizontal field of view: solved (with ``fov_deg`` input or blind) or the
        camera's; NaN for an unsolved blind image.
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
    fov_search : str
        How the scale was known: ``"camera"``, ``"hint"`` (``fov_deg``), ``"blind"``
        (the field-of-view bands, docs/solve.md) or ``"tracking"`` (a prior attitude).
    camera : Camera or None
        The camera model used (None for a pinhole from ``fov_deg`` or blind).
    focal_px_nominal : float
        Pinhole focal length (px) the solved ``focal_scale`` refers to (NaN with a camera).
    database : StarDatabase or None
        The database that identified the stars (None when not solved).
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
    fov_search: str = "camera"
    camera: object = None
    focal_px_nominal: float = math.nan
    database: object = None

    @property
    def p_false(self) -> float:
        """Upper bound on the probability that the match is chance (1 when not solved)."""
        return float(self.identification.p_false) if self.solved else 1.0

    @property
    def q_icrs_from_sensor_wxyz(self) -> np.ndarray:
        """Attitude as the quaternion ``q_icrs_from_sensor`` (scalar first, ``w >= 0``;
        :func:`shipstar.frames.q_wxyz_from_matrix`), shape (4,); NaN when not solved."""
        if not self.solved:
            return np.full(4, np.nan)
        from shipstar.frames import q_wxyz_from_matrix

        q = np.asarray(q_wxyz_from_matrix(self.C_icrs_from_sensor), dtype=float)
        return -q if q[0] < 0 else q

    def wcs_cards(self, sip_order: int = 4) -> list:
        """FITS WCS header cards ``(key, value, comment)`` (TAN, SIP where the camera has
        distortion); see :mod:`shipstar.identify._wcs`."""
        from shipstar.identify._wcs import wcs_cards

        if not self.solved:
            raise ShipstarError("no WCS: the image is not solved")
        return wcs_cards(self, sip_order)

    def as_json_dict(self) -> dict:
        """The ``shipstar solve --json`` object: always the same keys, None for undefined
        numbers and for an unknown ``date_obs`` or ``camera``; ``reason`` is ``""`` when
        solved.  Its star list (``x_px``, ``y_px``, ``hip``; ``hip`` -1 when unmatched),
        time, camera and image size make it a frame for ``shipstar calibrate intrinsics``.
        """

        def num(x):
            return float(x) if math.isfinite(x) else None

        h, w = self.image_shape_hw
        q = [float(v) for v in self.q_icrs_from_sensor_wxyz] if self.solved else None
        return {
            "solved": bool(self.solved), "reason": str(self.reason),
            "ra_deg": num(self.ra_deg), "dec_deg": num(self.dec_deg),
            "roll_deg": num(self.roll_deg), "fov_deg": num(self.fov_deg),
            "matched": int(self.matched), "rms_arcsec": num(self.rms_arcsec),
            "p_false": float(self.p_false), "q_icrs_from_sensor_wxyz": q,
            "fov_search": self.fov_search,
            "time_ms": float(self.time_ms),
            "date_obs": self.date_obs or None, "camera": self.camera_name or None,
            "width_px": int(w), "height_px": int(h),
            "stars": [{"x_px": float(x), "y_px": float(y), "hip": int(hh)}
                      for (x, y), hh in zip(self.xy_px.tolist(), self.hip.tolist())],
        }


def _as_image(image):
    if isinstance(image, (str, bytes)) or hasattr(image, "__fspath__"):
        from shipstar.extract._io import read_image_any

        return read_image_any(image, writable=False)       # extraction only reads it
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
                p_false_max: float = 1e-6, max_time_s=None, database=None,
                date_obs_is: str = "start", prior=None, prior_error_deg: float = 1.0) -> SolveResult:
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
        solver refines it from the matched stars.  With neither ``camera`` nor
        ``fov_deg`` the image is solved blind over the field-of-view bands
        (:mod:`shipstar.identify._blind`: short side 3.4 .. 31.5 deg).
    mag_limit : float, optional
        Database magnitude limit (default: adapted to the field, see build_database).
    centroid_error_px : float, optional
        Centroid error bound per axis (default 1 px; with ``fov_deg`` the solver also
        allows for the focal-length uncertainty).
    threshold_sigma, max_stars : extraction settings: the brightest ``max_stars`` point-like
        detections are used (elongated ones - roofs, trees, trails - are left out).
    p_false_max : float
        Largest accepted false-match probability (blind: over all hypotheses tried).
    max_time_s : float, optional
        Give up after this time (default 2 s with a camera or hint, 10 s blind).
    database : StarDatabase, optional
        Use this database instead of building / loading one (with a camera or hint).
    date_obs_is : {"start", "mid"}
        What a FITS image's ``DATE-OBS`` means when its header has no ``DATE-AVG`` /
        ``DATE-BEG`` (the FITS standard: the start of the exposure); sets ``date_obs``.
    prior : SolveResult, optional
        A previous frame's solution (same camera / field): the stars are identified by
        tracking from its attitude, with its model and database (lost-in-space if that
        fails); ``camera`` and ``fov_deg`` are then ignored.
    prior_error_deg : float
        Bound on the attitude change since ``prior``.
    """
    if date_obs_is != "start":                  # the default: no FITS reader loaded for a JPEG
        from shipstar._fitsio import DATE_OBS_CHOICES

        if date_obs_is not in DATE_OBS_CHOICES:
            raise ShipstarError(f"date_obs_is must be one of {', '.join(DATE_OBS_CHOICES)}, "
                                f"got {date_obs_is!r}")
    camera = _resolve_camera(camera)
    if camera is not None and fov_deg is not None:
        raise ShipstarError("give at most one of camera and fov_deg (neither: blind solve)")
    pixels = _as_image(image)
    date_obs, time_problem = _fits_time(image, date_obs_is)
    h, w = pixels.shape
    _check_setup(camera, fov_deg, (h, w), prior)
    t1 = time.perf_counter()
    from shipstar.extract import FLAG_ELONGATED, extract_stars

    extraction = extract_stars(pixels, threshold_sigma=threshold_sigma, max_stars=2 * max_stars)
    xy_all = np.asarray(extraction.xy_px, dtype=float).reshape(-1, 2)
    # elongated detections (roofs, trees, trails, blends; in a smeared frame only those
    # beyond the common smear are flagged) are not stars: leave them out
    use = np.flatnonzero((np.asarray(extraction.flags) & FLAG_ELONGATED) == 0)[:max_stars]
    return _identify_xy(xy_all, use, (h, w), camera, fov_deg, t1,
                        {"date_obs": date_obs, "time_problem": time_problem},
                        fov_tolerance=fov_tolerance, mag_limit=mag_limit,
                        centroid_error_px=centroid_error_px, p_false_max=p_false_max,
                        max_time_s=max_time_s, database=database, prior=prior,
                        prior_error_deg=prior_error_deg)


def solve_centroids(xy_px, image_shape_hw, camera=None, fov_deg=None, *, flux=None,
                    fov_tolerance=None, mag_limit=None, centroid_error_px=None,
                    max_stars: int = 60, p_false_max: float = 1e-6, max_time_s=None,
                    database=None, prior=None, prior_error_deg: float = 1.0) -> SolveResult:
    """Identify a list of star centroids and fit the attitude (no image).

    Parameters
    ----------
    xy_px : array_like (N, 2)
        Centroids (0-based pixels, top-left pixel centre (0, 0)), brightest first
        unless ``flux`` is given.
    image_shape_hw : (int, int)
        ``(height_px, width_px)`` of the image the centroids come from.
    flux : array_like (N,), optional
        Brightness of each centroid (any unit): the stars are used brightest first.
    camera, fov_deg, ... : as :func:`solve_image` (the brightest ``max_stars`` are used).
    """
    camera = _resolve_camera(camera)
    if camera is not None and fov_deg is not None:
        raise ShipstarError("give at most one of camera and fov_deg (neither: blind solve)")
    try:
        xy = np.asarray(xy_px, dtype=float)
        h, w = (int(v) for v in image_shape_hw)
    except (TypeError, ValueError):
        raise ShipstarError("xy_px must be an (N, 2) array of numbers and image_shape_hw "
                            "(height_px, width_px)") from None
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ShipstarError(f"xy_px must have shape (N, 2), got {xy.shape}")
    if h < 1 or w < 1:
        raise ShipstarError(f"image size must be positive, got {w}x{h} px")
    if not np.all(np.isfinite(xy)):
        raise ShipstarError("xy_px has non-finite values")
    if flux is not None:
        f = np.asarray(flux, dtype=float).reshape(-1)
        if f.shape[0] != xy.shape[0] or not np.all(np.isfinite(f)):
            raise ShipstarError(f"flux must be {xy.shape[0]} finite numbers")
        xy = xy[np.argsort(-f, kind="stable")]
    _check_setup(camera, fov_deg, (h, w), prior)
    t1 = time.perf_counter()
    return _identify_xy(xy, np.arange(min(xy.shape[0], int(max_stars))), (h, w), camera, fov_deg,
                        t1, {"date_obs": "", "time_problem": ""}, fov_tolerance=fov_tolerance,
                        mag_limit=mag_limit, centroid_error_px=centroid_error_px,
                        p_false_max=p_false_max, max_time_s=max_time_s, database=database,
                        prior=prior, prior_error_deg=prior_error_deg)


def _check_setup(camera, fov_deg, shape_hw, prior) -> None:
    h, w = shape_hw
    if prior is not None:
        if not isinstance(prior, SolveResult) or not prior.solved:
            raise ShipstarError("prior must be a solved SolveResult")
        if tuple(prior.image_shape_hw) != (h, w):
            raise ShipstarError(f"image is {w}x{h} px but the prior frame was "
                                f"{prior.image_shape_hw[1]}x{prior.image_shape_hw[0]}")
        return
    if camera is not None:
        if (w, h) != (camera.width_px, camera.height_px):
            raise ShipstarError(f"image is {w}x{h} px but camera {camera.name!r} is "
                                f"{camera.width_px}x{camera.height_px}")
    elif fov_deg is not None:
        fov = float(fov_deg)
        if not math.isfinite(fov) or not 0.5 <= fov <= 60.0:
            raise ShipstarError(f"fov_deg must be within 0.5 .. 60, got {fov_deg}")


def _identify_xy(xy_all, use, shape_hw, camera, fov_deg, t1, about, *, fov_tolerance, mag_limit,
                 centroid_error_px, p_false_max, max_time_s, database, prior, prior_error_deg):
    """Identify the centroids ``xy_all[use]`` and make the :class:`SolveResult`."""
    from shipstar.identify import _check_probability

    h, w = shape_hw
    xy = xy_all[use]
    err = 1.0 if centroid_error_px is None else float(centroid_error_px)
    if not math.isfinite(err) or err <= 0.0:
        raise ShipstarError(f"centroid_error_px must be a positive number, got {centroid_error_px}")
    p_false_max = _check_probability(p_false_max)
    if prior is not None:
        ident, model = _track(xy, prior, err, p_false_max, prior_error_deg,
                              2.0 if max_time_s is None else float(max_time_s))
    elif camera is not None:
        ident, model = _solve_camera(xy, camera, err, p_false_max, fov_tolerance, mag_limit,
                                     database, 2.0 if max_time_s is None else float(max_time_s))
    else:
        ident, model = _solve_pinhole(xy, (h, w), fov_deg, err, p_false_max, fov_tolerance,
                                      mag_limit, database, max_time_s)
    cam, f_px, db, search = model
    hip = np.full(xy_all.shape[0], -1, dtype=np.int64)
    hip[use] = ident.hip
    if cam is not None:
        fov_solved = cam.fov_deg
    elif search == "blind" and not ident.solved:
        fov_solved = math.nan                       # no field of view was given or found
    else:
        fov_solved = 2.0 * math.atan(ident.focal_scale * 0.5 * w / f_px) * RAD2DEG
    about = {**about, "camera_name": "" if cam is None else str(cam.name), "fov_search": search,
             "camera": cam, "focal_px_nominal": f_px}
    if not ident.solved:
        reason = ident.reason
        if xy.shape[0] == 0:
            reason = "no stars found in the image"
        elif xy.shape[0] < 5:
            reason = f"only {xy.shape[0]} stars found in the image: {ident.reason}"
        return SolveResult(False, reason, math.nan, math.nan, math.nan, fov_solved,
                           np.full((3, 3), np.nan), 0, math.nan,
                           (time.perf_counter() - t1) * 1e3, xy_all, hip, ident, (h, w), **about)
    C = ident.C_icrs_from_sensor
    ra, dec, roll = ra_dec_roll_from_C_icrs_from_sensor(C)
    return SolveResult(True, "", float(ra * RAD2DEG), float(dec * RAD2DEG), float(roll * RAD2DEG),
                       fov_solved, C, ident.n_matched, ident.rms_arcsec,
                       (time.perf_counter() - t1) * 1e3, xy_all, hip, ident, (h, w),
                       **{**about, "database": db})


def _solve_camera(xy, camera, err, p_false_max, fov_tolerance, mag_limit, database, max_time_s):
    from shipstar.identify import build_database, identify_lost_in_space

    tol = 0.0 if fov_tolerance is None else float(fov_tolerance)
    if database is None:
        database = build_database(camera, mag_limit, fov_tolerance=tol)
    ident = identify_lost_in_space(xy, database, camera=camera, centroid_error_px=err,
                                   focal_tolerance=tol, p_false_max=p_false_max,
                                   max_time_s=max_time_s)
    return ident, (camera, math.nan, database, "camera")


def _solve_pinhole(xy, shape_hw, fov_deg, err, p_false_max, fov_tolerance, mag_limit, database,
                   max_time_s):
    """A pinhole camera of unknown or hinted field: the field-of-view bands' databases
    (a per-field database only for a given ``database``, an aspect ratio beyond 2:1 or a
    hint outside the bands)."""
    from shipstar.identify import _blind
    from shipstar.identify._field import pinhole_focal_px

    h, w = shape_hw
    tol = DEFAULT_FOV_TOLERANCE if fov_tolerance is None else float(fov_tolerance)
    if not math.isfinite(tol) or not 0.0 <= tol <= 0.5:
        raise ShipstarError(f"fov_tolerance must be within 0 .. 0.5, got {fov_tolerance}")
    if fov_deg is None:
        if database is not None:
            raise ShipstarError("a database needs fov_deg or a camera (a blind solve uses "
                                "the field-of-view bands' databases)")
        hyps = _blind.hypotheses(w, h, None)
        search = "blind"
        limit = 10.0 if max_time_s is None else float(max_time_s)
    else:
        wide = max(w, h) > _blind.MAX_ASPECT * min(w, h)
        hyps = [] if (database is not None or wide) else _blind.hypotheses(w, h, fov_deg, tol)
        search = "hint"
        limit = 2.0 if max_time_s is None else float(max_time_s)
    if hyps:
        ident, hyp, db, _ = _blind.solve_bands(xy, w, h, hyps, centroid_error_px=err,
                                               p_false_max=p_false_max, max_time_s=limit,
                                               mag_limit=mag_limit)
        fov_x = (hyp or hyps[0]).fov_x_rad
        return ident, (None, pinhole_focal_px(w, fov_x), db, search)
    from shipstar.identify import build_database, identify_lost_in_space

    fov_x = float(fov_deg) * DEG2RAD
    if database is None:
        fov_y = 2.0 * math.atan(math.tan(0.5 * fov_x) * h / w)
        database = build_database((fov_x * RAD2DEG, fov_y * RAD2DEG), mag_limit, fov_tolerance=tol)
    ident = identify_lost_in_space(xy, database, fov_deg=fov_x * RAD2DEG, image_shape_hw=(h, w),
                                   centroid_error_px=err, focal_tolerance=tol,
                                   p_false_max=p_false_max, max_time_s=limit)
    return ident, (None, pinhole_focal_px(w, fov_x), database, search)


def _track(xy, prior, err, p_false_max, prior_error_deg, max_time_s):
    """Tracking from a previous solution: its camera model (the pinhole at its solved
    focal scale) and database; lost-in-space with the same model if tracking fails."""
    from shipstar.identify import identify_tracking

    h, w = prior.image_shape_hw
    cam = prior.camera
    db = prior.database
    if cam is not None:
        ident = identify_tracking(xy, db, prior.C_icrs_from_sensor, prior_error_deg=prior_error_deg,
                                  camera=cam, centroid_error_px=err, p_false_max=p_false_max,
                                  max_time_s=max_time_s)
        return ident, (cam, math.nan, db, "tracking")
    f_px = prior.focal_px_nominal / prior.identification.focal_scale
    fov_deg = 2.0 * math.atan(0.5 * w / f_px) * RAD2DEG
    ident = identify_tracking(xy, db, prior.C_icrs_from_sensor, prior_error_deg=prior_error_deg,
                              centroid_error_px=err, p_false_max=p_false_max, fov_deg=fov_deg,
                              image_shape_hw=(h, w), max_time_s=max_time_s)
    return ident, (None, f_px, db, "tracking")
