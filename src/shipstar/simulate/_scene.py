"""Star scenes with known truth: which catalog stars a sensor sees, and where.

Two geometric levels (``docs/simulation.md``):

:func:`simulate_stars`
    "Space" geometry for a sensor attitude in ICRS: catalog directions with proper
    motion to the epoch, no aberration, no refraction.
:func:`simulate_stars_horizontal`
    A sensor on Earth with an attitude in the horizontal frame: topocentric apparent
    places from the sky model (``FrameContext.hor_from_catalog``: proper motion,
    parallax, light deflection, annual and diurnal aberration), refracted per star
    (``refract_hor``: stars appear higher), stars below 5 deg observed elevation dropped.

Both project with the camera (distortion included) and keep the stars whose centre
lies on the detector.  Signals come from the camera's photon budget
(``Camera.star_e_per_s * exposure_s``), so stars and the camera's sky background share
one zero point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.simulate._field import field_radius_rad, star_field
from shipstar.simulate._motion import as_rate_rad_per_s, earth_rate_hor_rad_per_s, smear_px_from_rate

__all__ = ["SimulatedStars", "simulate_stars", "simulate_stars_horizontal", "DEFAULT_MAG_LIMIT",
           "check_rotation", "check_camera", "signal_e"]

#: Default faintest Hipparcos Hp magnitude simulated: about where Hipparcos stops being
#: complete (V ~ 7.3-9 depending on sky region and colour).  The A1 sensor detects stars
#: to about Hp 8.4 (5 sigma), so real A1 frames hold a few more faint stars than these.
DEFAULT_MAG_LIMIT = 8.0
#: Extra search radius beyond the image's corner (rad): refraction at 5 deg elevation
#: (~10'), aberration (20'') and rounding, with room to spare.
_SEARCH_MARGIN_RAD = math.radians(0.5)
_ORTHO_TOL = 1e-9


@dataclass(frozen=True, eq=False)
class SimulatedStars:
    """Catalog stars in one frame, brightest first, with their true image positions.

    Attributes
    ----------
    hip : (N,) int64
        Hipparcos numbers.
    xy_px : (N, 2) float
        True (mid-exposure) image positions, distortion included (x right, y down,
        top-left pixel centre (0, 0)).
    mag : (N,) float
        Hipparcos Hp magnitudes.
    u_sensor : (N, 3) float
        Unit directions in the sensor frame (X boresight, Y image up, Z image right).
    signal_e : (N,) float
        Electrons collected per exposure.
    smear_px : (N, 2) float
        Image motion during the exposure (end minus start); zeros for a still sensor.
    v_ref : (N, 3) float
        The same directions in the reference frame ``ref_frame``: ICRS (astrometric, at
        the epoch) or the horizontal frame (observed, i.e. refracted).
    ref_frame : str
        ``"icrs"`` or ``"hor"``.
    refraction_rad : (N,) float
        Refraction each star got (observed minus true elevation); zeros for ``"icrs"``.
    """

    hip: np.ndarray
    xy_px: np.ndarray
    mag: np.ndarray
    u_sensor: np.ndarray
    signal_e: np.ndarray
    smear_px: np.ndarray
    v_ref: np.ndarray
    ref_frame: str
    refraction_rad: np.ndarray

    def __len__(self) -> int:
        return len(self.hip)

    def subset(self, index_or_mask) -> "SimulatedStars":
        """The stars selected by a boolean mask ``(N,)`` or an integer index."""
        sel = np.asarray(index_or_mask)
        if sel.dtype == bool and sel.shape != (len(self),):
            raise ShipstarError(f"mask has shape {sel.shape}, expected ({len(self)},)")
        if sel.dtype != bool and sel.dtype.kind not in "iu":
            raise ShipstarError(f"subset takes a boolean mask or integer index, got dtype {sel.dtype}")
        names = ("hip", "xy_px", "mag", "u_sensor", "signal_e", "smear_px", "v_ref", "refraction_rad")
        return SimulatedStars(ref_frame=self.ref_frame, **{n: getattr(self, n)[sel] for n in names})


def check_camera(camera):
    """ShipstarError unless ``camera`` is a :class:`shipstar.camera.Camera`."""
    from shipstar.camera import Camera

    if not isinstance(camera, Camera):
        raise ShipstarError(f"camera must be a shipstar.camera.Camera, got {type(camera).__name__}")
    return camera


def check_rotation(C, name: str) -> np.ndarray:
    """A finite, proper (det +1) orthonormal ``(3, 3)`` matrix (copied), else ShipstarError."""
    try:
        M = np.array(C, dtype=float)
    except (TypeError, ValueError):
        raise ShipstarError(f"{name} must be a 3x3 rotation matrix") from None
    if M.shape != (3, 3) or not np.all(np.isfinite(M)):
        raise ShipstarError(f"{name} must be a finite 3x3 rotation matrix, got shape {M.shape}")
    err = float(np.max(np.abs(M.T @ M - np.eye(3))))
    if err > _ORTHO_TOL or np.linalg.det(M) < 0:
        raise ShipstarError(f"{name} is not a rotation matrix (|C^T C - I| = {err:.2g}, det = {np.linalg.det(M):.6g})")
    return M


def signal_e(camera, mag) -> np.ndarray:
    """Electrons per exposure from magnitudes ``(N,)``: ``camera.star_e_per_s(mag) * exposure_s``."""
    return np.asarray(camera.star_e_per_s(mag), float) * camera.exposure_s


def _check_epoch(epoch_jyear) -> float:
    try:
        epoch = float(epoch_jyear)
    except (TypeError, ValueError):
        raise ShipstarError(f"epoch_jyear must be a number, got {epoch_jyear!r}") from None
    if not math.isfinite(epoch):
        raise ShipstarError(f"epoch_jyear must be finite, got {epoch_jyear!r}")
    return epoch


def _assemble(camera, catalog, idx, u_sensor, v_ref, ref_frame, refraction, omega) -> SimulatedStars:
    """Project, keep stars on the detector, sort brightest first, add signals and smear."""
    xy = camera.project(u_sensor)
    keep = camera.in_image(xy)
    order = np.argsort(catalog.mag[idx[keep]], kind="stable")
    sel = np.flatnonzero(keep)[order]
    rows = idx[sel]
    u = u_sensor[sel]
    mag = np.array(catalog.mag[rows], dtype=float)
    return SimulatedStars(
        hip=np.array(catalog.hip[rows], dtype=np.int64),
        xy_px=xy[sel],
        mag=mag,
        u_sensor=u,
        signal_e=signal_e(camera, mag),
        smear_px=smear_px_from_rate(camera, u, omega, camera.exposure_s),
        v_ref=v_ref[sel],
        ref_frame=ref_frame,
        refraction_rad=refraction[sel],
    )


def simulate_stars(camera, C_icrs_from_sensor, *, epoch_jyear: float = 2000.0,
                   mag_limit: float | None = DEFAULT_MAG_LIMIT, catalog=None,
                   omega_sensor_rad_per_s=None) -> SimulatedStars:
    """Catalog stars seen by ``camera`` at an ICRS attitude ("space" geometry).

    Parameters
    ----------
    camera : shipstar.camera.Camera
    C_icrs_from_sensor : (3, 3) array
        Sensor attitude: columns are the boresight, image-up and image-right axes in ICRS.
    epoch_jyear : float
        Julian epoch the proper motions are applied to (ERFA ``pmsafe``).
    mag_limit : float or None
        Faintest Hp magnitude (see :func:`shipstar.simulate._field.star_field`).
    catalog : StarCatalog, optional
        Stars to use instead of the navigation catalog.
    omega_sensor_rad_per_s : (3,) array, optional
        Sensor angular velocity relative to the stars, sensor axes (motion smear).

    Returns
    -------
    SimulatedStars
        ``ref_frame = "icrs"``; no aberration, no refraction.
    """
    camera = check_camera(camera)
    C = check_rotation(C_icrs_from_sensor, "C_icrs_from_sensor")
    epoch = _check_epoch(epoch_jyear)
    omega = as_rate_rad_per_s(omega_sensor_rad_per_s)
    field = star_field(mag_limit, catalog)
    idx = field.near(C[:, 0], field_radius_rad(camera) + _SEARCH_MARGIN_RAD, epoch)
    u_icrs = field.catalog.subset(idx).unit_icrs(epoch) if idx.size else np.zeros((0, 3))
    return _assemble(camera, field.catalog, idx, u_icrs @ C, u_icrs, "icrs", np.zeros(len(idx)), omega)


def simulate_stars_horizontal(camera, C_hor_from_sensor, context, weather=None,
                              refraction_model: str = "erfa", *,
                              mag_limit: float | None = DEFAULT_MAG_LIMIT, catalog=None,
                              omega_sensor_rad_per_s=None, earth_rotation: bool = True) -> SimulatedStars:
    """Catalog stars seen by ``camera`` at an attitude in the horizontal frame (on Earth).

    Parameters
    ----------
    camera : shipstar.camera.Camera
    C_hor_from_sensor : (3, 3) array
        Sensor attitude in the horizontal frame (X north, Y up, Z east).
    context : shipstar.sky.apparent.FrameContext
        Time (mid-exposure) and site.
    weather : shipstar.sky.refraction.Weather, optional
        Default ``Weather()`` (1013.25 hPa, 10 C); its wavelength is replaced by the
        camera's ``wavelength_um``.
    refraction_model : {"almanac", "erfa", "none"}
    mag_limit, catalog : see :func:`simulate_stars`.
    omega_sensor_rad_per_s : (3,) array, optional
        Sensor angular velocity relative to the horizontal frame, sensor axes (ship motion).
    earth_rotation : bool
        Add the stars' diurnal motion to the smear (the sensor turns with the Earth).

    Returns
    -------
    SimulatedStars
        ``ref_frame = "hor"``; ``v_ref`` are the observed (refracted) directions.  Stars
        below the refraction model's lower limit (5 deg observed; 10 deg for ``"erfa"``)
        are dropped.
    """
    from shipstar.sky.apparent import FrameContext
    from shipstar.sky.refraction import Weather, min_true_el_rad, refract_hor

    camera = check_camera(camera)
    C = check_rotation(C_hor_from_sensor, "C_hor_from_sensor")
    if not isinstance(context, FrameContext):
        raise ShipstarError(f"context must be a shipstar.sky.apparent.FrameContext, got {type(context).__name__}")
    weather = Weather() if weather is None else weather
    # the camera's passband sets the refraction wavelength (docs/camera.md), as in the pipeline
    weather = replace(weather, wavelength_um=camera.wavelength_um)
    el_min_true = min_true_el_rad(weather, refraction_model)      # validates weather and model
    omega = as_rate_rad_per_s(omega_sensor_rad_per_s)
    if earth_rotation:
        omega = omega + C.T @ earth_rate_hor_rad_per_s(context.site.astronomical_lat_rad)
    field = star_field(mag_limit, catalog)
    b_icrs = context.icrs_from_hor(C[:, 0][None, :])[0]
    idx = field.near(b_icrs, field_radius_rad(camera) + _SEARCH_MARGIN_RAD, _epoch_jyear(context))
    v_true = context.hor_from_catalog(field.catalog, idx) if idx.size else np.zeros((0, 3))
    up = _elevation(v_true) >= el_min_true
    idx, v_true = idx[up], v_true[up]
    if refraction_model == "none" or not idx.size:
        v_obs, refraction = v_true, np.zeros(len(idx))
    else:
        v_obs = refract_hor(v_true, weather, refraction_model)
        refraction = _elevation(v_obs) - _elevation(v_true)
    return _assemble(camera, field.catalog, idx, v_obs @ C, v_obs, "hor", refraction, omega)


def _elevation(v) -> np.ndarray:
    return np.arctan2(v[:, 1], np.hypot(v[:, 0], v[:, 2]))


def _epoch_jyear(context) -> float:
    """Julian epoch of a frame context's time (UTC taken as TT: 69 s is immaterial here)."""
    import erfa

    return float(erfa.epj(context.utc_jd1, context.utc_jd2))
