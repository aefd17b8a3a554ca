"""The measured stars of one frame, in the sensor's tangent plane.

Identification works on tangent-plane coordinates ``t = (v_y / v_x, v_z / v_x)`` of the
sensor-frame star directions (image up, image right), computed with the *nominal*
focal length.  An uncertain focal length is a scale: with ``f_true = f_nominal / s``
the true coordinates are ``s * t``; lost-in-space estimates ``s`` per candidate and
refines it from every matched star.  For an uncalibrated lens (``fov_deg`` only) a
radial term is fitted too: ``t_true = s t (1 + k1 |t|^2)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shipstar.errors import ShipstarError

__all__ = ["StarField", "field_from_unit_vectors", "field_from_camera", "field_from_pinhole",
           "pinhole_focal_px", "camera_bounds", "pinhole_bounds", "pinhole_input"]


@dataclass(frozen=True, eq=False)
class StarField:
    """Stars of one frame, brightest first, ready for identification.

    Attributes
    ----------
    t : ndarray (N, 2)
        Tangent-plane coordinates at the nominal focal length (NaN rows allowed only
        when ``bad_rows`` lists them).
    bounds : ndarray (4,)
        Image rectangle in the tangent plane: ``y_min, y_max, z_min, z_max``.
    error_rad : float
        Bound on one centroid's error, per image axis, as an angle (seed 004's delta).
    focal_tolerance : float
        Relative uncertainty of the focal length (0 = known camera).
    xy_px : ndarray (N, 2) or None
        The pixel positions the field was made from (for reports).
    bad_rows : ndarray (B,)
        Rows whose input was not finite.
    fit_radial : bool
        Fit the radial term ``k1`` too (an uncalibrated pinhole: ``fov_deg`` only).
    """

    t: np.ndarray
    bounds: np.ndarray
    error_rad: float
    focal_tolerance: float
    bad_rows: np.ndarray
    xy_px: np.ndarray | None = None
    fit_radial: bool = False
    u0: np.ndarray | None = None

    def __post_init__(self):
        if self.u0 is None:
            t = self.t
            u0 = np.empty((t.shape[0], 3))
            u0[:, 0] = 1.0
            u0[:, 1:] = t
            u0 /= np.sqrt(np.einsum("ij,ij->i", u0, u0))[:, None]
            object.__setattr__(self, "u0", u0)

    @property
    def n(self) -> int:
        """Number of stars."""
        return int(self.t.shape[0])

    def t_true(self, scale: float = 1.0, k1: float = 0.0, rows=None) -> np.ndarray:
        """Tangent-plane coordinates ``(N, 2)`` for focal scale ``scale`` and radial ``k1``."""
        t = self.t if rows is None else self.t[rows]
        if k1 == 0.0:
            return t * scale
        return t * (scale * (1.0 + k1 * np.einsum("ij,ij->i", t, t)))[:, None]

    def unit(self, scale: float = 1.0, rows=None, k1: float = 0.0) -> np.ndarray:
        """Sensor-frame unit vectors ``(N, 3)`` of the stars for ``scale`` and ``k1``."""
        if scale == 1.0 and k1 == 0.0:
            return self.u0 if rows is None else self.u0[rows]
        t = self.t_true(scale, k1, rows)
        out = np.empty((t.shape[0], 3))
        out[:, 0] = 1.0
        out[:, 1:] = t
        out /= np.sqrt(np.einsum("ij,ij->i", out, out))[:, None]
        return out

    def box(self, scale: float = 1.0):
        """Image rectangle as ``(centre (2,), half_size (2,))`` at focal scale ``scale``."""
        y0, y1, z0, z1 = self.bounds
        return (np.array([0.5 * (y0 + y1), 0.5 * (z0 + z1)]) * scale,
                np.array([0.5 * (y1 - y0), 0.5 * (z1 - z0)]) * scale)

    @property
    def half_diagonal_tan(self) -> float:
        """Largest tangent-plane distance from the boresight to an image corner."""
        y0, y1, z0, z1 = self.bounds.tolist()
        return math.hypot(max(abs(y0), abs(y1)), max(abs(z0), abs(z1)))

    @property
    def area_tan2(self) -> float:
        """Area of the image rectangle in the tangent plane."""
        y0, y1, z0, z1 = self.bounds.tolist()
        return (y1 - y0) * (z1 - z0)


_NO_ROWS = np.empty(0, dtype=np.intp)
_NO_ROWS.setflags(write=False)


def _check_rows(arr, width: int, what: str) -> np.ndarray:
    try:
        a = np.asarray(arr, dtype=float)
    except (TypeError, ValueError):
        raise ShipstarError(f"{what} must be numbers") from None
    if a.ndim != 2 or a.shape[1] != width:
        raise ShipstarError(f"{what} must have shape (N, {width}), got {a.shape}")
    return a


def _check_error(value: float, what: str) -> float:
    value = float(value)
    if not math.isfinite(value) or value <= 0.0:
        raise ShipstarError(f"{what} must be a positive finite number, got {value}")
    return value


def _check_tolerance(value: float) -> float:
    value = float(value)
    if not math.isfinite(value) or not 0.0 <= value <= 0.5:
        raise ShipstarError(f"focal_tolerance must be within 0 .. 0.5, got {value}")
    return value


def field_from_unit_vectors(u_sensor, *, half_fov_x_rad: float, half_fov_y_rad: float,
                            error_rad: float, focal_tolerance: float = 0.0) -> StarField:
    """Field from sensor-frame unit vectors ``(N, 3)`` (X boresight), brightest first."""
    u = _check_rows(u_sensor, 3, "u_sensor")
    finite = np.all(np.isfinite(u), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = u[:, 1:] / u[:, :1]
    ok = finite & (u[:, 0] > 0.0)
    t[~ok] = np.nan
    ty, tz = np.tan(half_fov_y_rad), np.tan(half_fov_x_rad)
    return StarField(t=t, bounds=np.array([-ty, ty, -tz, tz]),
                     error_rad=_check_error(error_rad, "centroid error"),
                     focal_tolerance=_check_tolerance(focal_tolerance),
                     bad_rows=np.flatnonzero(~ok))


def _corner_points(width_px: int, height_px: int) -> np.ndarray:
    x = [-0.5, (width_px - 1) / 2.0, width_px - 0.5]
    y = [-0.5, (height_px - 1) / 2.0, height_px - 0.5]
    return np.array([(a, b) for a in x for b in y if (a, b) != (x[1], y[1])])


_BOUNDS_CACHE: dict = {}


_PINHOLE_CACHE: dict = {}


def _pinhole_camera(camera):
    """``(cam, bounds)`` of a camera without distortion (``cam = (x0_px, y0_px,
    pixel_mm, f_mm)``, ``bounds`` :func:`pinhole_bounds`), or None; cached per camera
    object (a camera is frozen; a tracker passes the same one every frame)."""
    key = id(camera)
    hit = _PINHOLE_CACHE.get(key)
    if hit is not None and hit[0] is camera:
        return hit[1]
    try:
        if not camera.distortion.is_zero:
            value = None
        else:
            value = ((float(camera.x0_px), float(camera.y0_px), float(camera.pixel_mm), float(camera.f_mm)),
                     pinhole_bounds(camera))
    except (AttributeError, TypeError, ValueError):
        return None
    if len(_PINHOLE_CACHE) > 32:
        _PINHOLE_CACHE.clear()
    _PINHOLE_CACHE[key] = (camera, value)
    return value


def pinhole_input(stars, camera):
    """``(xy_px (N, 2) float64 C-ordered, (x0_px, y0_px, pixel_mm, f_mm), bounds)`` when
    ``stars`` are pixel centroids (N, 2) and ``camera`` a camera without distortion: the
    compiled one-call paths take them with no :class:`StarField`.  None otherwise (the
    general path checks the input and builds the field)."""
    pinhole = _pinhole_camera(camera)
    if pinhole is None:
        return None
    try:
        xy = np.ascontiguousarray(stars, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    if xy.ndim != 2 or xy.shape[1] != 2:
        return None
    return xy, pinhole[0], pinhole[1]


def pinhole_bounds(camera) -> tuple:
    """:func:`camera_bounds` of a camera without distortion, as four floats: the image
    edges' tangent-plane lines."""
    scale = camera.pixel_mm / camera.f_mm
    x0, y0 = camera.x0_px, camera.y0_px
    return (-(camera.height_px - 0.5 - y0) * scale, (y0 + 0.5) * scale,
            -(x0 + 0.5) * scale, (camera.width_px - 0.5 - x0) * scale)


def camera_bounds(camera) -> np.ndarray:
    """Tangent-plane rectangle ``(y_min, y_max, z_min, z_max)`` spanned by the image
    edges (corners and edge midpoints, distortion included); cached per camera."""
    key = id(camera)
    hit = _BOUNDS_CACHE.get(key)
    if hit is not None and hit[0] is camera:
        return hit[1]
    if camera.distortion.is_zero:           # a pinhole: the edges' tangent-plane lines
        bounds = np.array(pinhole_bounds(camera))
    else:
        edge = camera.unproject(_corner_points(camera.width_px, camera.height_px))
        te = edge[:, 1:] / edge[:, :1]
        bounds = np.array([te[:, 0].min(), te[:, 0].max(), te[:, 1].min(), te[:, 1].max()])
    bounds.setflags(write=False)
    if len(_BOUNDS_CACHE) > 32:
        _BOUNDS_CACHE.clear()
    _BOUNDS_CACHE[key] = (camera, bounds)
    return bounds


def field_from_camera(xy_px, camera, *, error_px: float, focal_tolerance: float = 0.0) -> StarField:
    """Field from pixel centroids ``(N, 2)`` and a calibrated :class:`~shipstar.camera.Camera`."""
    xy = _check_rows(xy_px, 2, "xy_px")
    error_px = _check_error(error_px, "centroid_error_px")
    if camera.distortion.is_zero:            # compiled: the same arithmetic, one call
        from shipstar.identify._kernels import pinhole_unproject

        u, t, finite = pinhole_unproject(xy, camera.x0_px, camera.y0_px, camera.pixel_mm,
                                         camera.f_mm)
        if finite:
            return StarField(t=t, bounds=camera_bounds(camera),
                             error_rad=error_px * camera.pixel_mm / camera.f_mm,
                             focal_tolerance=_check_tolerance(focal_tolerance), bad_rows=_NO_ROWS,
                             xy_px=xy, u0=u)
    if math.isfinite(xy.sum()):              # one reduction: every value finite
        u = camera.unproject(xy)
        t = u[:, 1:] / u[:, :1]
        bad = _NO_ROWS if math.isfinite(t.sum()) else np.flatnonzero(~np.all(np.isfinite(t), axis=1))
    else:
        finite = np.all(np.isfinite(xy), axis=1)
        u = np.full((xy.shape[0], 3), np.nan)
        if np.any(finite):
            u[finite] = camera.unproject(xy[finite])
        t = u[:, 1:] / u[:, :1]
        bad = np.flatnonzero(~np.all(np.isfinite(t), axis=1))
    return StarField(t=t, bounds=camera_bounds(camera),
                     error_rad=error_px * camera.pixel_mm / camera.f_mm,
                     focal_tolerance=_check_tolerance(focal_tolerance), bad_rows=bad, xy_px=xy,
                     u0=u)


def pinhole_focal_px(width_px: int, fov_x_rad: float) -> float:
    """Focal length in pixels of a pinhole camera whose horizontal FOV spans the width."""
    return 0.5 * width_px / np.tan(0.5 * fov_x_rad)


def field_from_pinhole(xy_px, *, width_px: int, height_px: int, fov_x_rad: float,
                       error_px: float, focal_tolerance: float = 0.0) -> StarField:
    """Field from pixel centroids of a pinhole camera: principal point at the image
    centre, focal length from the horizontal field of view ``fov_x_rad``."""
    xy = _check_rows(xy_px, 2, "xy_px")
    error_px = _check_error(error_px, "centroid_error_px")
    f_px = pinhole_focal_px(width_px, fov_x_rad)
    x0, y0 = (width_px - 1) / 2.0, (height_px - 1) / 2.0
    t = np.stack([-(xy[:, 1] - y0) / f_px, (xy[:, 0] - x0) / f_px], axis=1)
    ok = np.all(np.isfinite(t), axis=1)
    hy, hz = 0.5 * height_px / f_px, 0.5 * width_px / f_px
    tol = _check_tolerance(focal_tolerance)
    return StarField(t=t, bounds=np.array([-hy, hy, -hz, hz]), error_rad=error_px / f_px,
                     focal_tolerance=tol, bad_rows=np.flatnonzero(~ok), xy_px=xy,
                     fit_radial=tol > 0.0)
