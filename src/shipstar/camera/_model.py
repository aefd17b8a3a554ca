"""The star sensor camera: pinhole geometry, Weng distortion and the photometric budget.

Image coordinates follow docs/conventions.md: ``xy_px`` (N, 2), x right along a row, y
down a column, the centre of the top-left pixel at (0, 0).  Sensor frame: X boresight,
Y image up, Z image right, so an ideal (undistorted) image point is::

    v_sensor ~ [f_mm, -(y - y0) * pixel_mm, (x - x0) * pixel_mm]

and the lens distortion (:class:`Distortion`) maps ideal to observed focal-plane
offsets.  See docs/camera.md for the presets and the photometric model.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import operator
from dataclasses import dataclass, field, fields

import numpy as np

from shipstar.camera._distortion import Distortion
from shipstar.errors import ShipstarError
from shipstar.units import RAD2ASEC, RAD2DEG

__all__ = ["Camera", "sky_e_per_px_per_s"]

#: unproject iterates until project(unproject(xy)) reproduces xy to this (px)
_UNPROJECT_TOL_PX = 1e-8


class _FieldError(ShipstarError):
    """A camera field is bad; ``field`` and ``problem`` let callers name the file too."""

    def __init__(self, field_name: str, problem: str):
        super().__init__(f"field {field_name!r} {problem}")
        self.field = field_name
        self.problem = problem


class _CameraFieldError(_FieldError):
    """A field error already prefixed with the camera's name."""

    def __init__(self, label: str, inner: _FieldError):
        ShipstarError.__init__(self, f"camera {label!r}: {inner}")
        self.field = inner.field
        self.problem = inner.problem


# name -> (kind, lower bound, lower bound inclusive?, upper bound or None)
_POS = (0.0, False, None)
_NONNEG = (0.0, True, None)
_FRACTION = (0.0, False, 1.0)
_SPEC: dict[str, tuple] = {
    "name": ("str",),
    "width_px": ("int", 1, True, 1 << 20),
    "height_px": ("int", 1, True, 1 << 20),
    "f_mm": ("float",) + _POS,
    "pixel_mm": ("float",) + _POS,
    "x0_px": ("float", None, True, None),
    "y0_px": ("float", None, True, None),
    "aperture_mm": ("float",) + _POS,
    "exposure_s": ("float",) + _POS,
    "frame_rate_hz": ("float",) + _POS,
    "qe": ("float",) + _FRACTION,
    "optics_transmission": ("float",) + _FRACTION,
    "photon_flux_mag0_per_s_per_m2": ("float",) + _POS,
    "read_noise_e": ("float",) + _NONNEG,
    "dark_e_per_s": ("float",) + _NONNEG,
    "sky_e_per_px_per_s": ("float",) + _NONNEG,
    "full_well_e": ("float",) + _POS,
    "gain_e_per_adu": ("float",) + _POS,
    "bias_adu": ("float",) + _NONNEG,
    "adc_bits": ("int", 1, True, 32),
    "psf_sigma_px": ("float",) + _POS,
    "notes": ("str",),
    # effective wavelength of the passband for refraction: the range shipstar.sky.refraction's
    # Weather accepts (ERFA refco's); its 1-sigma uncertainty enters the uncertainty budget
    "wavelength_um": ("float", 0.3, True, 2.5),
    "wavelength_sigma_um": ("float", 0.0, True, 1.0),
}


def _check_value(name: str, value):
    """Validate and normalise one field (not ``distortion``); raises :class:`_FieldError`."""
    kind = _SPEC[name][0]
    if kind == "str":
        if not isinstance(value, str):
            raise _FieldError(name, f"must be a string, got {value!r}")
        if name == "name" and not value.strip():
            raise _FieldError(name, "must not be empty")
        return value
    if isinstance(value, bool):
        raise _FieldError(name, f"must be a number, got {value!r}")
    if kind == "int":
        try:
            value = operator.index(value)
        except TypeError:
            raise _FieldError(name, f"must be an integer, got {value!r}") from None
    else:
        if not isinstance(value, numbers.Real):
            raise _FieldError(name, f"must be a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise _FieldError(name, f"must be finite, got {value!r}")
    _, low, low_inclusive, high = _SPEC[name]
    if low is not None and (value < low or (value == low and not low_inclusive)):
        raise _FieldError(name, f"must be {'>=' if low_inclusive else '>'} {low}, got {value!r}")
    if high is not None and value > high:
        raise _FieldError(name, f"must be <= {high}, got {value!r}")
    return value


def _as_points(arr, n: int, what: str) -> np.ndarray:
    try:
        out = np.asarray(arr, dtype=float)
    except (TypeError, ValueError):
        raise ShipstarError(f"{what} must be a numeric array of shape (N, {n})") from None
    if out.ndim == 0 or out.shape[-1] != n:
        raise ShipstarError(f"{what} must have shape (N, {n}), got {out.shape}")
    return out


@dataclass(frozen=True)
class Camera:
    """A star sensor: geometry (pinhole + Weng distortion) and photometry/noise.

    Attributes
    ----------
    name : str
        Label (presets: "A1", "A2", "seed002", "seed004").
    width_px, height_px : int
        Image size (columns, rows).
    f_mm : float
        Focal length.
    pixel_mm : float
        Pixel pitch (square pixels).
    x0_px, y0_px : float
        Principal point in image coordinates (x right, y down, top-left pixel centre (0, 0)).
    distortion : Distortion
        Weng distortion, ideal -> observed focal-plane offsets in mm (default: none).
    aperture_mm, optics_transmission, qe, photon_flux_mag0_per_s_per_m2 : float
        Photon budget, see :meth:`star_e_per_s` (qe and transmission in (0, 1]).
    exposure_s, frame_rate_hz : float
        Integration time per frame (<= 1 / frame_rate_hz) and frame rate.
    read_noise_e, dark_e_per_s, sky_e_per_px_per_s, full_well_e : float
        Detector noise sources and saturation, in electrons.
    gain_e_per_adu, bias_adu : float; adc_bits : int
        Read-out: electrons per ADU, offset, ADC resolution.
    psf_sigma_px : float
        Sigma of the Gaussian (defocused) star image.
    notes : str
        Where the numbers come from.
    wavelength_um : float
        Effective wavelength of the passband for refraction (um, 0.3-2.5, default 0.55):
        every command that computes refraction for this camera's frames, and the simulator
        rendering them, use it (docs/camera.md, *Refraction wavelength*).
    wavelength_sigma_um : float
        Its 1-sigma uncertainty (um, default 0.05), propagated into the total uncertainty
        (docs/uncertainty.md).

    The photometric fields default to sensor A1's (docs/camera.md).  Every field is
    validated on construction (and by :meth:`replace`): a bad value raises
    :class:`~shipstar.errors.ShipstarError` naming the field.
    """

    name: str
    width_px: int
    height_px: int
    f_mm: float
    pixel_mm: float
    x0_px: float
    y0_px: float
    distortion: Distortion = field(default_factory=Distortion)
    aperture_mm: float = 50.0
    exposure_s: float = 0.08
    frame_rate_hz: float = 10.0
    qe: float = 0.4
    optics_transmission: float = 0.8
    photon_flux_mag0_per_s_per_m2: float = 4.7e10
    read_noise_e: float = 20.0
    dark_e_per_s: float = 200.0
    sky_e_per_px_per_s: float = 108.77
    full_well_e: float = 100000.0
    gain_e_per_adu: float = 25.0
    bias_adu: float = 100.0
    adc_bits: int = 12
    psf_sigma_px: float = 0.8
    notes: str = ""
    wavelength_um: float = 0.55
    wavelength_sigma_um: float = 0.05

    def __post_init__(self):
        label = self.name if isinstance(self.name, str) else repr(self.name)
        try:
            for f in fields(self):
                if f.name != "distortion":
                    object.__setattr__(self, f.name, _check_value(f.name, getattr(self, f.name)))
            if not isinstance(self.distortion, Distortion):
                raise _FieldError("distortion", f"must be a Distortion, got {self.distortion!r}")
            self._check_consistency()
        except _FieldError as exc:
            raise _CameraFieldError(label, exc) from None
        if not self.distortion.is_zero:
            self._check_invertible()

    def _check_consistency(self):
        if self.exposure_s > 1.0 / self.frame_rate_hz * (1.0 + 1e-9):
            raise _FieldError("exposure_s", f"({self.exposure_s} s) must not exceed the frame period "
                                            f"1/frame_rate_hz = {1.0 / self.frame_rate_hz} s")
        if self.bias_adu >= self.adc_max_adu:
            raise _FieldError("bias_adu", f"must be below the ADC maximum {self.adc_max_adu}, "
                                          f"got {self.bias_adu}")

    def _check_invertible(self):
        """The distortion must be invertible (by Newton) over the whole image."""
        xs = np.linspace(-0.5, self.width_px - 0.5, 33)
        ys = np.linspace(-0.5, self.height_px - 0.5, 33)
        xy = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)
        v = self.unproject(xy)
        back = self.project(v)
        err = np.hypot(*(back - xy).T)
        bad = ~(err < 1e-6)
        if bad.any():
            x, y = xy[np.argmax(bad)]
            raise ShipstarError(
                f"camera {self.name!r}: distortion is not invertible over the image "
                f"(no inverse at pixel ({x:.1f}, {y:.1f})); coefficients are per mm of focal plane")

    # ------------------------------------------------------------------ construction
    def replace(self, **changes) -> "Camera":
        """A copy with some fields changed (validated like the constructor)."""
        names = {f.name for f in fields(self)}
        unknown = sorted(set(changes) - names)
        if unknown:
            raise ShipstarError(f"camera {self.name!r}: no field {unknown[0]!r}")
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict:
        """Plain nested dict (what :func:`save_camera` writes): fields, ``distortion`` a sub-dict."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "distortion"}
        out["distortion"] = self.distortion.as_dict()
        return out

    # ------------------------------------------------------------------ geometry
    def project(self, v_sensor) -> np.ndarray:
        """Sensor-frame directions ``(..., 3)`` -> observed pixel positions ``(..., 2)``.

        Vectors need not be unit.  Rows with ``v_x <= 0`` (not in front of the lens) or
        non-finite components are NaN.  Points outside the image are returned as they
        fall; use :meth:`in_image`.
        """
        v = _as_points(v_sensor, 3, "v_sensor")
        vx = v[..., 0]
        front = vx > 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            u_mm = np.where(front, self.f_mm * v[..., 2] / vx, np.nan)
            w_mm = np.where(front, -self.f_mm * v[..., 1] / vx, np.nan)
        if not self.distortion.is_zero:
            du, dw = self.distortion.offsets_mm(u_mm, w_mm)
            u_mm = u_mm + du
            w_mm = w_mm + dw
        out = np.empty(v.shape[:-1] + (2,))
        out[..., 0] = self.x0_px + u_mm / self.pixel_mm
        out[..., 1] = self.y0_px + w_mm / self.pixel_mm
        return out

    def unproject(self, xy_px) -> np.ndarray:
        """Observed pixel positions ``(..., 2)`` -> unit vectors in the sensor frame ``(..., 3)``.

        The distortion is removed by Newton iteration until re-projecting the result
        reproduces ``xy_px`` to < 1e-8 px; non-finite rows, or
        rows so far outside the image that the distortion has no inverse there, are NaN.
        """
        xy = _as_points(xy_px, 2, "xy_px")
        u_mm = (xy[..., 0] - self.x0_px) * self.pixel_mm
        w_mm = (xy[..., 1] - self.y0_px) * self.pixel_mm
        if not self.distortion.is_zero:
            shape = u_mm.shape
            u_mm, w_mm = self.distortion._solve(u_mm.ravel(), w_mm.ravel(),
                                                _UNPROJECT_TOL_PX * self.pixel_mm)
            u_mm = u_mm.reshape(shape)
            w_mm = w_mm.reshape(shape)
        else:
            bad = ~np.isfinite(u_mm + w_mm)
            if bad.any():
                u_mm = np.where(bad, np.nan, u_mm)
        out = np.empty(xy.shape[:-1] + (3,))
        out[..., 0] = self.f_mm
        out[..., 1] = -w_mm
        out[..., 2] = u_mm
        out /= np.sqrt(np.einsum("...i,...i->...", out, out))[..., None]   # NaN rows stay NaN
        return out

    def in_image(self, xy_px, margin_px: float = 0.0) -> np.ndarray:
        """True where a pixel position lies on the detector, at least ``margin_px`` inside
        its edges (the edges are at -0.5 and width - 0.5); NaN rows are False.  Shape ``(...)``."""
        xy = _as_points(xy_px, 2, "xy_px")
        m = float(margin_px)
        x = xy[..., 0]
        y = xy[..., 1]
        return ((x >= -0.5 + m) & (x < self.width_px - 0.5 - m)
                & (y >= -0.5 + m) & (y < self.height_px - 0.5 - m))

    def _edge_angle_deg(self, xy_a, xy_b) -> float:
        a, b = self.unproject(np.array([xy_a, xy_b], float))
        return float(np.arctan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b)) * RAD2DEG)

    @property
    def fov_deg(self) -> float:
        """Field of view across the width: angle between the left and right image edges
        on the principal point's row (distortion included)."""
        return self._edge_angle_deg((-0.5, self.y0_px), (self.width_px - 0.5, self.y0_px))

    @property
    def fov_height_deg(self) -> float:
        """Field of view across the height, on the principal point's column."""
        return self._edge_angle_deg((self.x0_px, -0.5), (self.x0_px, self.height_px - 0.5))

    @property
    def diagonal_fov_deg(self) -> float:
        """The larger of the two corner-to-corner angles of the image."""
        w, h = self.width_px - 0.5, self.height_px - 0.5
        return max(self._edge_angle_deg((-0.5, -0.5), (w, h)),
                   self._edge_angle_deg((w, -0.5), (-0.5, h)))

    @property
    def pixel_scale_arcsec(self) -> float:
        """Angle subtended by one pixel at the principal point (where distortion has no
        first-order effect): ``pixel_mm / f_mm`` rad in arcsec."""
        return self.pixel_mm / self.f_mm * RAD2ASEC

    # ------------------------------------------------------------------ photometry
    @property
    def adc_max_adu(self) -> int:
        """Largest ADC output ``2**adc_bits - 1``."""
        return (1 << self.adc_bits) - 1

    @property
    def f_number(self) -> float:
        """Focal ratio ``f_mm / aperture_mm``."""
        return self.f_mm / self.aperture_mm

    @property
    def collecting_area_m2(self) -> float:
        """Clear aperture area (unobstructed circular pupil)."""
        return math.pi * (0.5e-3 * self.aperture_mm) ** 2

    def star_e_per_s(self, mag) -> np.ndarray:
        """Photo-electrons per second collected from a star of magnitude ``mag`` (any shape).

        ``photon_flux_mag0_per_s_per_m2 * 10**(-0.4 mag) * collecting_area_m2
        * optics_transmission * qe``; multiply by ``exposure_s`` for one frame.
        """
        m = np.asarray(mag, float)
        return (self.photon_flux_mag0_per_s_per_m2 * self.collecting_area_m2
                * self.optics_transmission * self.qe) * 10.0 ** (-0.4 * m)


def sky_e_per_px_per_s(camera: Camera, sky_mag_per_arcsec2: float) -> float:
    """Sky background electrons per pixel per second for a surface brightness (mag/arcsec^2).

    The sky is treated like a star of magnitude ``sky_mag_per_arcsec2`` per square
    arcsecond, spread over the pixel's solid angle ``pixel_scale_arcsec**2`` (the same
    zero point, transmission and QE as the stars).
    """
    sb = float(sky_mag_per_arcsec2)
    if not math.isfinite(sb):
        raise ShipstarError(f"sky_mag_per_arcsec2 must be finite, got {sky_mag_per_arcsec2!r}")
    return float(camera.star_e_per_s(sb)) * camera.pixel_scale_arcsec ** 2
