"""Star identification: which Hipparcos star is each measured star (docs/identification.md).

Public API::

    build_database(camera_or_fov, mag_limit=None, ...) -> StarDatabase   # cached on disk
    identify_lost_in_space(stars, database, ...) -> Identification      # no prior
    identify_tracking(stars, database, C_icrs_from_sensor_prior, ...) -> Identification
    solve_image(image, camera=None, fov_deg=None, ...) -> SolveResult    # extract + identify
    solve_centroids(xy_px, image_shape_hw, camera=None, fov_deg=None, ...) -> SolveResult
    deep_match(stars, sigma_px, identification, deep_catalog(database), epoch_jyear=...)
        -> DeepMatch                                                    # name every other star

``stars`` are either sensor-frame unit vectors ``(N, 3)`` (X boresight) or pixel
centroids ``xy_px (N, 2)`` (with a ``camera``, or ``fov_deg`` for a pinhole camera with
the principal point at the image centre), brightest first.  Bad arguments raise
:class:`~shipstar.errors.ShipstarError`; frames that cannot be identified (too few
stars, all false, no verified match) return ``solved=False`` with a ``reason``.
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.identify._database import DatabaseParams, StarDatabase, cached_database, params_for_field
from shipstar.identify._field import _check_error, _check_tolerance, pinhole_input
from shipstar.identify._result import Identification, failed_identification
from shipstar.identify._solve import SolveResult, solve_centroids, solve_image
from shipstar.identify._tracking import tracking, tracking_pinhole
from shipstar.units import DEG2RAD

__all__ = ["StarDatabase", "DatabaseParams", "Identification", "SolveResult", "build_database",
           "identify_lost_in_space", "identify_tracking", "solve_image", "solve_centroids",
           "DeepMatch", "deep_match", "deep_catalog"]


def __getattr__(name):
    """The deep matcher is imported on first use (``shipstar solve`` does not need it)."""
    if name in ("DeepMatch", "deep_match", "deep_catalog"):
        from shipstar.identify import _deep

        return getattr(_deep, name)
    raise AttributeError(f"module 'shipstar.identify' has no attribute {name!r}")


def _is_camera(obj) -> bool:
    return all(hasattr(obj, a) for a in ("unproject", "f_mm", "pixel_mm", "width_px", "height_px"))


def build_database(camera_or_fov, mag_limit=None, *, fov_tolerance: float = 0.0,
                   epoch_jyear: float = 2025.0, use_cache: bool = True,
                   **pattern_options) -> StarDatabase:
    """Navigation star database for a camera or a field of view (built once, cached).

    Parameters
    ----------
    camera_or_fov : Camera, float or (float, float)
        A :class:`~shipstar.camera.Camera`, or the horizontal field of view in degrees
        (square image), or ``(fov_x_deg, fov_y_deg)``.
    mag_limit : float, optional
        Faintest Hipparcos Hp magnitude.  Default: the limit at which a field holds 35
        stars on average (Hp 7.3 for camera A1, 6.7 for a 12 deg field).
    fov_tolerance : float
        Relative uncertainty of the field of view (focal length), e.g. 0.1 for +-10 %:
        patterns fit the narrowest field, verification covers the widest.
    epoch_jyear : float
        Epoch of the star positions (proper motion applied), Julian year.
    use_cache : bool
        Read / write the cache file under ``cache_dir()/identify`` (and keep it in memory).
    **pattern_options
        ``bins``, ``stars_per_field``, ``oversampling``, ``min_pattern_frac``
        (see :class:`DatabaseParams`).

    Returns
    -------
    StarDatabase
        ``.size_bytes``, ``.build_time_s``, ``.n_stars``, ``.n_patterns``.
    """
    _check_epoch(epoch_jyear)
    if _is_camera(camera_or_fov):
        cam = camera_or_fov
        fov_x, fov_y = cam.fov_deg * DEG2RAD, cam.fov_height_deg * DEG2RAD
        params = params_for_field(fov_x, fov_y, mag_limit=mag_limit, fov_tolerance=fov_tolerance,
                                  epoch_jyear=epoch_jyear, pixel_scale_rad=cam.pixel_mm / cam.f_mm,
                                  camera_name=str(cam.name), **pattern_options)
    else:
        try:
            fov = np.atleast_1d(np.asarray(camera_or_fov, dtype=float))
        except (TypeError, ValueError):
            fov = np.zeros(0)
        if fov.shape not in ((1,), (2,)):
            raise ShipstarError("camera_or_fov must be a Camera, a FOV in degrees or "
                                f"(fov_x_deg, fov_y_deg), got shape {fov.shape}")
        fov_x = fov[0] * DEG2RAD
        fov_y = fov[-1] * DEG2RAD
        params = params_for_field(fov_x, fov_y, mag_limit=mag_limit, fov_tolerance=fov_tolerance,
                                  epoch_jyear=epoch_jyear, **pattern_options)
    return cached_database(params, use_cache=use_cache)


def _check_epoch(epoch_jyear) -> None:
    if not (isinstance(epoch_jyear, (int, float)) and math.isfinite(epoch_jyear)
            and 1000.0 <= epoch_jyear <= 3000.0):
        raise ShipstarError(f"epoch_jyear must be a Julian year such as 2025.0, got {epoch_jyear!r}")


def _make_field(stars, database, camera, fov_deg, image_shape_hw, centroid_error_px,
                focal_tolerance):
    from shipstar.identify import _field

    if not isinstance(database, StarDatabase):
        raise ShipstarError(f"database must be a StarDatabase (see build_database), got "
                            f"{type(database).__name__}")
    try:
        arr = np.asarray(stars, dtype=float)
    except (TypeError, ValueError):
        raise ShipstarError("stars must be an (N, 3) array of unit vectors or (N, 2) pixel "
                            "positions") from None
    if arr.ndim != 2 or arr.shape[1] not in (2, 3):
        raise ShipstarError("stars must be an (N, 3) array of unit vectors or (N, 2) pixel "
                            f"positions, got shape {arr.shape}")
    if arr.shape[1] == 3:
        p = database.params
        cam_scale = camera.pixel_mm / camera.f_mm if camera is not None else p.pixel_scale_rad
        half_x = 0.5 * (camera.fov_deg * DEG2RAD if camera is not None else p.fov_x_rad)
        half_y = 0.5 * (camera.fov_height_deg * DEG2RAD if camera is not None else p.fov_y_rad)
        return _field.field_from_unit_vectors(
            arr, half_fov_x_rad=half_x, half_fov_y_rad=half_y,
            error_rad=float(centroid_error_px) * cam_scale, focal_tolerance=focal_tolerance)
    if camera is not None:
        return _field.field_from_camera(arr, camera, error_px=centroid_error_px,
                                        focal_tolerance=focal_tolerance)
    if fov_deg is None or image_shape_hw is None:
        raise ShipstarError("pixel positions need a camera, or fov_deg and image_shape_hw")
    fov = float(fov_deg)
    if not math.isfinite(fov) or not 0.2 <= fov <= 120.0:
        raise ShipstarError(f"fov_deg must be within 0.2 .. 120, got {fov_deg}")
    h, w = (int(v) for v in image_shape_hw)
    if h < 1 or w < 1:
        raise ShipstarError(f"image_shape_hw must be positive, got {image_shape_hw}")
    return _field.field_from_pinhole(arr, width_px=w, height_px=h, fov_x_rad=fov * DEG2RAD,
                                     error_px=centroid_error_px, focal_tolerance=focal_tolerance)


def _pinhole_input(stars, database, camera, centroid_error_px):
    """``(xy_px, cam, error_rad, bounds)`` for the compiled one-call paths
    (:func:`._field.pinhole_input`), or None: the general path."""
    if camera is None or not isinstance(database, StarDatabase):
        return None
    fast = pinhole_input(stars, camera)
    if fast is None:
        return None
    xy, cam, bounds = fast
    return xy, cam, _check_error(centroid_error_px, "centroid_error_px") * cam[2] / cam[3], bounds


def _checked_rotation(matrix, name: str) -> np.ndarray:
    """``matrix`` as a float (3, 3) array if it is a finite proper rotation.

    One test, in plain floats (it runs for every tracked frame): rows 0 and 1 orthonormal
    and row 2 their cross product (the rows of a rotation are a right-handed orthonormal
    basis), the six absolute errors summing to at most 1e-5 (a float32 rotation passes;
    a shear or scale that large would move a star by 2 arcsec, far inside any prior's
    error).  The sum is NaN or inf for non-finite input, so the test fails for that too;
    the message is chosen only then.
    """
    C = np.asarray(matrix, dtype=float)
    if C.shape == (3, 3):
        (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = C.tolist()
        err = (abs(a0 * a0 + a1 * a1 + a2 * a2 - 1.0) + abs(b0 * b0 + b1 * b1 + b2 * b2 - 1.0)
               + abs(a0 * b0 + a1 * b1 + a2 * b2) + abs(a1 * b2 - a2 * b1 - c0)
               + abs(a2 * b0 - a0 * b2 - c1) + abs(a0 * b1 - a1 * b0 - c2))
        if err <= 1e-5:
            return C
    if C.shape != (3, 3):
        raise ShipstarError(f"{name} must be a finite (3, 3) matrix, got shape {C.shape}")
    if not np.all(np.isfinite(C)):
        raise ShipstarError(f"{name} must be a finite (3, 3) matrix, got non-finite elements")
    raise ShipstarError(f"{name} is not a rotation matrix")


def _check_probability(p_false_max) -> float:
    p = float(p_false_max)
    if not math.isfinite(p) or not 0.0 < p < 1.0:
        raise ShipstarError(f"p_false_max must be within (0, 1), got {p_false_max}")
    return p


def _bad_rows_result(field, mode):
    if field.bad_rows.size:
        rows = ", ".join(str(r) for r in field.bad_rows[:5])
        more = " ..." if field.bad_rows.size > 5 else ""
        return failed_identification(field.n, mode, f"star rows {rows}{more} are not finite "
                                     "(or behind the sensor): refusing to identify")
    return None


def identify_lost_in_space(stars, database: StarDatabase, *, camera=None, fov_deg=None,
                           image_shape_hw=None, centroid_error_px: float = 1.0,
                           focal_tolerance: float = 0.0, p_false_max: float = 1e-6,
                           max_pattern_stars: int = 20, max_verify_stars: int = 60,
                           max_time_s: float = 1.0) -> Identification:
    """Identify stars with no prior attitude (pattern hashing + verification).

    Parameters
    ----------
    stars : array_like, (N, 3) or (N, 2)
        Sensor-frame unit vectors, or pixel centroids ``xy_px``; brightest first.
    database : StarDatabase
    camera : Camera, optional
        Camera of pixel centroids (or of unit vectors: image bounds and pixel scale).
        Without it, unit vectors use the database's field and pixel scale.
    fov_deg, image_shape_hw : float and (int, int), optional
        For pixel centroids without a camera: a pinhole camera with the principal point
        at the image centre and this horizontal field of view.
    centroid_error_px : float
        Bound on a centroid's error per axis (seed 004's delta); sets every gate.
    focal_tolerance : float
        Relative uncertainty of the focal length (0 for a calibrated camera, 0.1 for a
        field of view known to +-10 %); the solved scale is ``focal_scale``.
    p_false_max : float
        Largest accepted probability that the match is chance.
    max_pattern_stars : int
        Brightest stars forming patterns (all 4-subsets, brightest first).
    max_verify_stars : int
        Brightest stars used in verification.
    max_time_s : float
        Give up (``solved=False``) after this time.
    """
    from shipstar.identify._lost_in_space import LisOptions, lost_in_space, lost_in_space_pinhole

    opts = LisOptions(p_false_max=_check_probability(p_false_max),
                      max_pattern_stars=max(4, int(max_pattern_stars)),
                      max_verify_stars=max(4, int(max_verify_stars)),
                      max_time_s=float(max_time_s))
    fast = _pinhole_input(stars, database, camera, centroid_error_px)
    if fast is not None:
        xy, cam, error_rad, bounds = fast
        result = lost_in_space_pinhole(xy, cam, error_rad, _check_tolerance(focal_tolerance), bounds,
                                       database, opts)
        if result is not None:
            return result
    field = _make_field(stars, database, camera, fov_deg, image_shape_hw, centroid_error_px,
                        focal_tolerance)
    bad = _bad_rows_result(field, "lost_in_space")
    if bad is not None:
        return bad
    return lost_in_space(field, database, opts)


def identify_tracking(stars, database: StarDatabase, C_icrs_from_sensor_prior, *,
                      prior_error_deg: float = 0.2, camera=None, centroid_error_px: float = 1.0,
                      focal_scale: float = 1.0, p_false_max: float = 1e-6, min_matches: int = 3,
                      fallback: bool = True, **lost_in_space_options) -> Identification:
    """Identify stars by prediction from a prior attitude; lost-in-space if that fails.

    Parameters
    ----------
    stars, database, camera, centroid_error_px, p_false_max
        As for :func:`identify_lost_in_space`.
    C_icrs_from_sensor_prior : array_like (3, 3)
        Prior attitude (e.g. the last frame's ``C_icrs_from_sensor``).
    prior_error_deg : float
        Bound on the prior's error (motion since the last frame).
    focal_scale : float
        Focal scale of a previous lost-in-space solution (1 for a calibrated camera).
    min_matches : int
        Fewest matched stars accepted.
    fallback : bool
        Run lost-in-space when tracking fails (its result has ``mode="lost_in_space"``).
    **lost_in_space_options
        Passed to :func:`identify_lost_in_space` on fallback.
    """
    C = _checked_rotation(C_icrs_from_sensor_prior, "C_icrs_from_sensor_prior")
    err = float(prior_error_deg)
    if not math.isfinite(err) or not 0.0 <= err <= 30.0:
        raise ShipstarError(f"prior_error_deg must be within 0 .. 30, got {prior_error_deg}")
    fs = float(focal_scale)
    if not math.isfinite(fs) or not 0.5 <= fs <= 2.0:
        raise ShipstarError(f"focal_scale must be within 0.5 .. 2, got {focal_scale}")
    p_false = _check_probability(p_false_max)
    result = None
    fast = _pinhole_input(stars, database, camera, centroid_error_px) if fs == 1.0 else None
    if fast is not None:
        xy, cam, error_rad, bounds = fast
        result = tracking_pinhole(xy, cam, error_rad, bounds, database, C,
                                  prior_error_rad=err * DEG2RAD, p_false_max=p_false,
                                  min_matches=max(2, int(min_matches)))
    if result is None:
        field = _make_field(stars, database, camera, lost_in_space_options.get("fov_deg"),
                            lost_in_space_options.get("image_shape_hw"), centroid_error_px, 0.0)
        if field.bad_rows.size:
            return _bad_rows_result(field, "tracking")
        result = tracking(field, database, C, prior_error_rad=err * DEG2RAD, focal_scale=fs,
                          p_false_max=p_false, min_matches=max(2, int(min_matches)))
    if result.solved or not fallback:
        return result
    lis = identify_lost_in_space(stars, database, camera=camera, centroid_error_px=centroid_error_px,
                                 p_false_max=p_false_max, **lost_in_space_options)
    if lis.solved:
        return lis
    return failed_identification(len(result.star_index), "lost_in_space",
                                 f"tracking: {result.reason}; lost-in-space: {lis.reason}",
                                 n_patterns=lis.n_patterns, n_candidates=lis.n_candidates + 1,
                                 time_s=result.time_s + lis.time_s)
