"""Whole simulated frames: attitude (ICRS, horizontal, or ship + installation) -> image + truth.

:func:`simulate_frame` picks the geometry from the attitude it is given:

- ``C_icrs_from_sensor`` alone: "space" geometry (:func:`simulate_stars`);
- ``C_icrs_from_sensor`` with a ``site``: the same pointing seen from the site through
  the atmosphere; the sensor's horizontal attitude is
  ``C_hor_from_icrs_approx @ C_icrs_from_sensor`` (the rigid part of the sky model);
- ``C_hor_from_sensor`` or ``ship`` (:class:`ShipPose`) with a ``site``: horizontal
  geometry (:func:`simulate_stars_horizontal`), ``C_hor_from_sensor = C_hor_from_deck
  @ C_deck_from_sensor`` for a ship.

then renders the image with :func:`render` (``_render.render_frame``).
"""

from __future__ import annotations

import dataclasses
import math
import zlib
from dataclasses import dataclass

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.frames import C_deck_from_sensor, C_hor_from_deck
from shipstar.simulate._motion import as_rate_rad_per_s
from shipstar.simulate._render import FalseObjects, render_frame
from shipstar.simulate._scene import (
    DEFAULT_MAG_LIMIT,
    SimulatedStars,
    check_camera,
    check_rotation,
    signal_e,
    simulate_stars,
    simulate_stars_horizontal,
)
from shipstar.units import DEG2RAD

__all__ = ["ShipPose", "SimulatedFrame", "simulate_frame", "render", "random_false_objects",
           "hot_pixel_seed", "J2000_UTC_ISO", "HOT_PIXEL_FRACTION"]

#: J2000.0 (2000-01-01 12:00 TT) in UTC: the default time of a "space" frame.
J2000_UTC_ISO = "2000-01-01T11:58:55.816Z"
#: Default fraction of hot pixels (about 21 on a 1024 x 1024 detector).
HOT_PIXEL_FRACTION = 2e-5
_MAX_SEED = 2**63 - 1


@dataclass(frozen=True)
class ShipPose:
    """Ship attitude and a sensor's installation angles (radians, ``docs/conventions.md``).

    Attributes
    ----------
    heading_rad, pitch_rad, roll_rad : float
        Ship heading K (from north through east), pitch psi (bow up), roll theta
        (starboard down): ``C_hor_from_deck = R_y(K) R_z(-psi) R_x(-theta)``.
    install_az_rad, install_el_rad, install_roll_rad : float
        Installation azimuth A (from the bow toward starboard), elevation E (above the
        deck) and roll gamma of the sensor: ``C_deck_from_sensor = R_y(A) R_z(-E) R_x(-gamma)``.
    """

    heading_rad: float
    pitch_rad: float
    roll_rad: float
    install_az_rad: float
    install_el_rad: float
    install_roll_rad: float

    def __post_init__(self):
        for name in ("heading_rad", "pitch_rad", "roll_rad", "install_az_rad", "install_el_rad",
                     "install_roll_rad"):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise ShipstarError(f"ShipPose.{name} must be a number, got {value!r}") from None
            if not math.isfinite(value):
                raise ShipstarError(f"ShipPose.{name} must be finite, got {value!r}")
            object.__setattr__(self, name, value)
        for name in ("pitch_rad", "install_el_rad"):
            if abs(getattr(self, name)) > 0.5 * math.pi:
                raise ShipstarError(f"{name[:-4].replace('_', ' ')} {getattr(self, name) / DEG2RAD:.6g} deg "
                                    "is outside [-90, 90]")

    @classmethod
    def from_deg(cls, heading_deg, pitch_deg, roll_deg, install_az_deg, install_el_deg,
                 install_roll_deg=0.0) -> "ShipPose":
        """From degrees."""
        vals = [heading_deg, pitch_deg, roll_deg, install_az_deg, install_el_deg, install_roll_deg]
        try:
            rad = [float(v) * DEG2RAD for v in vals]
        except (TypeError, ValueError):
            raise ShipstarError(f"ship and installation angles must be numbers (deg), got {vals!r}") from None
        return cls(*rad)

    @property
    def C_hor_from_deck(self) -> np.ndarray:
        """(3, 3) ship attitude matrix."""
        return C_hor_from_deck(self.heading_rad, self.pitch_rad, self.roll_rad)

    @property
    def C_deck_from_sensor(self) -> np.ndarray:
        """(3, 3) installation matrix."""
        return C_deck_from_sensor(self.install_az_rad, self.install_el_rad, self.install_roll_rad)

    @property
    def C_hor_from_sensor(self) -> np.ndarray:
        """(3, 3) ``C_hor_from_deck @ C_deck_from_sensor``."""
        return self.C_hor_from_deck @ self.C_deck_from_sensor

    def omega_sensor_from_deck(self, omega_deck_rad_per_s) -> np.ndarray:
        """Angular rate (3,) in sensor axes from the same rate in deck axes."""
        return self.C_deck_from_sensor.T @ as_rate_rad_per_s(omega_deck_rad_per_s, "omega_deck_rad_per_s")


@dataclass(frozen=True, eq=False)
class SimulatedFrame:
    """A rendered frame and everything needed to know its truth.

    Attributes
    ----------
    image : (H, W) uint16
        Raw frame in ADU (12-bit for the seeds' sensors).
    stars : SimulatedStars
        Catalog stars in the frame (true mid-exposure positions).
    camera : shipstar.camera.Camera
    utc_iso : str
        Mid-exposure time, ISO 8601 UTC (``...Z``, milliseconds).
    utc_jd1, utc_jd2 : float
        The same time as a two-part UTC Julian date.
    epoch_jyear : float
        Julian epoch of the star positions.
    C_icrs_from_sensor : (3, 3)
        Sensor attitude in ICRS.  For frames on Earth this is the rigid approximation
        ``C_hor_from_icrs_approx.T @ C_hor_from_sensor`` (aberration makes the true map
        non-rigid by up to ~20''); ``C_hor_from_sensor`` is the exact truth there.
    C_hor_from_sensor : (3, 3) or None
        Sensor attitude in the horizontal frame (None for "space" frames).
    context : shipstar.sky.apparent.FrameContext or None
        Time, site and Earth orientation of a frame on Earth.
    weather : shipstar.sky.refraction.Weather or None
    refraction_model : str
        ``"almanac"``, ``"erfa"`` or ``"none"`` (always ``"none"`` in space).
    ship : ShipPose or None
    omega_sensor_rad_per_s : (3,)
        Sensor angular rate as given, sensor axes: relative to ICRS in space, to the
        horizontal frame on Earth (the Earth's rotation is then added in the smear).
    false_objects : shipstar.simulate._render.FalseObjects
    seed : int
        Seed of the noise (same seed, same image).
    mag_limit : float or None
    hot_pixel_fraction : float
    """

    image: np.ndarray
    stars: SimulatedStars
    camera: object
    utc_iso: str
    utc_jd1: float
    utc_jd2: float
    epoch_jyear: float
    C_icrs_from_sensor: np.ndarray
    C_hor_from_sensor: np.ndarray | None
    context: object | None
    weather: object | None
    refraction_model: str
    ship: ShipPose | None
    omega_sensor_rad_per_s: np.ndarray
    false_objects: FalseObjects
    seed: int
    mag_limit: float | None
    hot_pixel_fraction: float

    @property
    def frame(self) -> str:
        """``"hor"`` for a frame on Earth, ``"icrs"`` for "space" geometry."""
        return "icrs" if self.C_hor_from_sensor is None else "hor"

    @property
    def camera_name(self) -> str:
        return self.camera.name

    @property
    def exposure_s(self) -> float:
        return float(self.camera.exposure_s)


def hot_pixel_seed(camera) -> int:
    """Seed of a sensor's fixed hot-pixel pattern: CRC-32 of its name."""
    return zlib.crc32(camera.name.encode("utf-8"))


def render(camera, stars: SimulatedStars, rng, *, false_objects: FalseObjects | None = None,
           hot_pixel_fraction: float = HOT_PIXEL_FRACTION, smear: bool = True) -> np.ndarray:
    """Render simulated stars into a raw frame ``(H, W)`` uint16 (``_render.render_frame``).

    Parameters
    ----------
    camera : shipstar.camera.Camera
    stars : SimulatedStars
    rng : numpy.random.Generator
        All noise comes from it.
    false_objects : FalseObjects, optional
        Planets, satellite trails, cosmic rays (see :func:`random_false_objects`).
    hot_pixel_fraction : float
        Fraction of hot pixels; their pattern is fixed per sensor (:func:`hot_pixel_seed`).
    smear : bool
        Apply ``stars.smear_px`` (motion during the exposure).
    """
    camera = check_camera(camera)
    if not isinstance(stars, SimulatedStars):
        raise ShipstarError(f"stars must be SimulatedStars, got {type(stars).__name__}")
    smear_px = stars.smear_px if smear and np.any(stars.smear_px) else None
    return render_frame(camera, stars.xy_px, stars.signal_e, rng, smear_px=smear_px,
                        hot_pixel_fraction=hot_pixel_fraction,
                        hot_pixel_seed=hot_pixel_seed(camera), false_objects=false_objects)


def random_false_objects(camera, rng, *, planets: int = 0, trails: int = 0,
                         cosmic_rays: int = 0) -> FalseObjects:
    """Random non-star objects for a frame of ``camera``.

    Planets: point sources of magnitude -2..+1 anywhere on the detector.  Satellite
    trails: 100-600 px segments at a random angle through a random point, of a
    magnitude 3..6 satellite crossing during the whole exposure.  Cosmic rays: ``cosmic_rays``
    hits of ~3000 e (placed by the renderer).

    Parameters
    ----------
    camera : shipstar.camera.Camera
    rng : numpy.random.Generator
    planets, trails, cosmic_rays : int
        Counts (0..1000).
    """
    camera = check_camera(camera)
    for name, n in (("planets", planets), ("trails", trails), ("cosmic_rays", cosmic_rays)):
        if isinstance(n, bool) or int(n) != n or not 0 <= n <= 1000:
            raise ShipstarError(f"{name} must be an integer in 0..1000, got {n!r}")
    size = np.array([camera.width_px, camera.height_px], float)
    planet_xy = rng.uniform(0.0, 1.0, (int(planets), 2)) * size - 0.5
    planet_e = signal_e(camera, rng.uniform(-2.0, 1.0, int(planets)))
    mid = rng.uniform(0.0, 1.0, (int(trails), 2)) * size - 0.5
    angle = rng.uniform(0.0, math.pi, int(trails))
    half = 0.5 * rng.uniform(100.0, 600.0, int(trails))
    step = np.stack([np.cos(angle), np.sin(angle)], axis=1) * half[:, None]
    trail_xy = np.stack([mid - step, mid + step], axis=1)
    trail_e = signal_e(camera, rng.uniform(3.0, 6.0, int(trails)))
    return FalseObjects(planet_xy_px=planet_xy, planet_signal_e=planet_e, trail_xy_px=trail_xy,
                        trail_signal_e=trail_e, cosmic_ray_count=int(cosmic_rays))


def _check_seed(seed) -> int:
    if seed is None:
        return int(np.random.SeedSequence().generate_state(1, np.uint64)[0]) & _MAX_SEED
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= _MAX_SEED:
        raise ShipstarError(f"seed must be an integer in 0..2**63-1, got {seed!r}")
    return int(seed)


def _time(utc_iso, on_earth: bool):
    """(utc_iso canonical, jd1, jd2, epoch_jyear) of the mid-exposure time."""
    import erfa

    from shipstar.sky.time import iso_from_utc_jd, tt_jd_from_utc_jd, utc_jd_from_iso

    if utc_iso is None:
        if on_earth:
            raise ShipstarError("a frame on Earth needs its mid-exposure time (utc_iso)")
        utc_iso = J2000_UTC_ISO
    jd1, jd2 = utc_jd_from_iso(utc_iso)
    tt1, tt2 = tt_jd_from_utc_jd(jd1, jd2)
    return iso_from_utc_jd(jd1, jd2, 3), jd1, jd2, float(erfa.epj(tt1, tt2))


def _attitudes(C_icrs_from_sensor, C_hor_from_sensor, ship, site):
    """Validate the attitude inputs: (C_icrs or None, C_hor or None, ship, on_earth)."""
    given = [x is not None for x in (C_icrs_from_sensor, C_hor_from_sensor, ship)]
    if sum(given) != 1:
        raise ShipstarError("give exactly one of C_icrs_from_sensor, C_hor_from_sensor and ship")
    if ship is not None and not isinstance(ship, ShipPose):
        raise ShipstarError(f"ship must be a ShipPose, got {type(ship).__name__}")
    C_icrs = None if C_icrs_from_sensor is None else check_rotation(C_icrs_from_sensor, "C_icrs_from_sensor")
    C_hor = ship.C_hor_from_sensor if ship is not None else (
        None if C_hor_from_sensor is None else check_rotation(C_hor_from_sensor, "C_hor_from_sensor"))
    on_earth = C_hor is not None or site is not None
    if on_earth and site is None:
        raise ShipstarError("an attitude in the horizontal frame needs a site")
    return C_icrs, C_hor, on_earth


def simulate_frame(camera, *, C_icrs_from_sensor=None, C_hor_from_sensor=None, ship: ShipPose | None = None,
                   utc_iso: str | None = None, site=None, weather=None, refraction_model: str = "erfa",
                   eop=None, mag_limit: float | None = DEFAULT_MAG_LIMIT, catalog=None, seed: int | None = None,
                   omega_sensor_rad_per_s=None, false_objects: FalseObjects | None = None,
                   hot_pixel_fraction: float = HOT_PIXEL_FRACTION) -> SimulatedFrame:
    """Simulate one raw frame with known truth.

    Parameters
    ----------
    camera : shipstar.camera.Camera
    C_icrs_from_sensor, C_hor_from_sensor : (3, 3) arrays, optional
    ship : ShipPose, optional
        Exactly one of the three attitudes (see the module docstring).
    utc_iso : str, optional
        Mid-exposure UTC (ISO 8601).  Required on Earth; default J2000.0 in space.
    site : shipstar.sky.apparent.Site, optional
        Required with ``C_hor_from_sensor`` or ``ship``; with ``C_icrs_from_sensor`` it
        puts the sensor on Earth.
    weather : shipstar.sky.refraction.Weather, optional
        Default ``Weather()``; on Earth only.
    refraction_model : {"almanac", "erfa", "none"}
    eop : shipstar.sky.eop.EarthOrientation, optional
        Default: from the IERS tables at ``utc_iso``.
    mag_limit, catalog : faintest magnitude and optional catalog (see :func:`simulate_stars`).
    seed : int, optional
        Noise seed; drawn at random (and recorded in the result) when not given.
    omega_sensor_rad_per_s : (3,) array, optional
        Sensor angular rate (sensor axes) relative to ICRS in space, to the horizontal
        frame on Earth; use :meth:`ShipPose.omega_sensor_from_deck` for deck rates.
    false_objects : FalseObjects, optional
    hot_pixel_fraction : float

    Returns
    -------
    SimulatedFrame
    """
    from shipstar.sky.apparent import Site, frame_context
    from shipstar.sky.refraction import Weather

    camera = check_camera(camera)
    C_icrs, C_hor, on_earth = _attitudes(C_icrs_from_sensor, C_hor_from_sensor, ship, site)
    if not on_earth and weather is not None:
        raise ShipstarError("weather needs a site (refraction applies to frames on Earth only)")
    utc_iso, jd1, jd2, epoch = _time(utc_iso, on_earth)
    seed = _check_seed(seed)
    omega = as_rate_rad_per_s(omega_sensor_rad_per_s)
    context, model = None, "none"
    if on_earth:
        if not isinstance(site, Site):
            raise ShipstarError(f"site must be a shipstar.sky.apparent.Site, got {type(site).__name__}")
        context, model = frame_context(jd1, jd2, site, eop), refraction_model
        weather = Weather() if weather is None else weather
        weather = dataclasses.replace(weather, wavelength_um=camera.wavelength_um)   # the camera's passband
        approx = np.asarray(context.C_hor_from_icrs_approx)
        C_hor = approx @ C_icrs if C_hor is None else C_hor
        C_icrs = approx.T @ C_hor if C_icrs is None else C_icrs
        stars = simulate_stars_horizontal(camera, C_hor, context, weather, model, mag_limit=mag_limit,
                                          catalog=catalog, omega_sensor_rad_per_s=omega)
    else:
        stars = simulate_stars(camera, C_icrs, epoch_jyear=epoch, mag_limit=mag_limit, catalog=catalog,
                               omega_sensor_rad_per_s=omega)
    image = render(camera, stars, np.random.default_rng(seed), false_objects=false_objects,
                   hot_pixel_fraction=hot_pixel_fraction)
    return SimulatedFrame(
        image=image, stars=stars, camera=camera, utc_iso=utc_iso, utc_jd1=jd1, utc_jd2=jd2,
        epoch_jyear=epoch, C_icrs_from_sensor=C_icrs, C_hor_from_sensor=C_hor, context=context,
        weather=weather, refraction_model=model, ship=ship, omega_sensor_rad_per_s=omega,
        false_objects=FalseObjects() if false_objects is None else false_objects, seed=seed,
        mag_limit=None if mag_limit is None else float(mag_limit),
        hot_pixel_fraction=float(hot_pixel_fraction))
