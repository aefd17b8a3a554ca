"""Simulated measurement sessions of a ship with star sensors: in dock and at sea.

A session is a :class:`SessionSpec`: the ship's motion (:class:`ShipMotion`: attitude and
track as functions of time), the sensors on it (:class:`SensorSetup`: camera,
installation angles, clock offset), the weather and the frame rate.  Two levels:

:func:`simulate_centroids`
    Centroid level (fast, for statistics): each frame's catalog stars from the sky
    model (apparent places, per-star refraction with the session's "true" atmosphere),
    projected by the camera, with Gaussian centroid noise; the stars' HIP numbers are
    kept (identification assumed correct).
:func:`write_session`
    Image level: every frame rendered along the stars' true paths during the exposure
    (the ship's attitude at 17 instants of it: ``_motion.exposure_path_px``, so a streak
    is the time-integrated image even when the deck accelerates) and written as FITS
    (``DATE-OBS``/``DATE-BEG`` = start, ``DATE-AVG`` = mid-exposure, ``EXPTIME``) plus
    its truth JSON, and the session's truth, track and weather as CSV files and
    ``session.toml`` (``docs/file-formats.md``).

Frame times are whole microseconds (the resolution of every time tag written), so the
times in the files are the simulated times exactly.

:func:`dock_session` is seed 000's calibration night (Jiangyin, 2013-03-15 ~20:16 local
time, heading 46 deg 28' 28.51'', level, 11.10 C, 1021.70 hPa, A1 and A2 at their Table
2-3 angles); :func:`sea_session` the same ship rolling 5 deg / 8 s and pitching
2 deg / 6 s with a drifting heading, under way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.frames import C_deck_from_sensor, C_hor_from_deck
from shipstar.units import DAY_S, DEG2RAD, RAD2DEG

__all__ = [
    "SensorSetup", "ShipMotion", "SessionSpec", "CentroidFrame",
    "dock_session", "sea_session", "simulate_centroids", "write_session",
    "SEED_DOCK_HEADING_DEG", "SEED_A1_INSTALL_DEG", "SEED_A2_INSTALL_DEG",
    "estimate_output_bytes", "MAX_TIME_OFFSET_S", "DEFAULT_MAX_OUTPUT_BYTES",
]

#: Seed 000: heading 46 deg 28' 28.51'' from the theodolite.
SEED_DOCK_HEADING_DEG = 46.0 + 28.0 / 60.0 + 28.51 / 3600.0
#: Seed 000 Tables 2 and 3: installation (azimuth, elevation, roll) in degrees.
SEED_A1_INSTALL_DEG = (185.1093, 39.3734, -0.2262)
SEED_A2_INSTALL_DEG = (274.9246, 35.1031, 0.0789)
#: Earth's mean radius (m), for the ship's track (dead reckoning over seconds).
_EARTH_RADIUS_M = 6371008.8
#: Step of the numerical angular-rate derivative (s).
_RATE_STEP_S = 1e-3
#: Largest clock offset of a sensor (s).
MAX_TIME_OFFSET_S = 1.0
#: Default cap on what :func:`write_session` may write (bytes).
DEFAULT_MAX_OUTPUT_BYTES = 20 * 10**9
#: Frame times are whole multiples of 1 / this (s): the microsecond of the files' time tags.
_PER_S = 1e6


@dataclass(frozen=True)
class SensorSetup:
    """A star sensor on the ship.

    Attributes
    ----------
    name : str
        e.g. ``"A1"``.
    camera : shipstar.camera.Camera
    install_az_rad, install_el_rad, install_roll_rad : float
        True installation angles (``C_deck_from_sensor = R_y(A) R_z(-E) R_x(-gamma)``).
    time_offset_s : float
        This sensor's exposures are this much later than the session's frame clock
        (within +-``MAX_TIME_OFFSET_S``).
    """

    name: str
    camera: object
    install_az_rad: float
    install_el_rad: float
    install_roll_rad: float
    time_offset_s: float = 0.0

    @property
    def C_deck_from_sensor(self) -> np.ndarray:
        return C_deck_from_sensor(self.install_az_rad, self.install_el_rad, self.install_roll_rad)

    @classmethod
    def from_deg(cls, name: str, camera, az_deg, el_deg, roll_deg, time_offset_s=0.0) -> "SensorSetup":
        return cls(name, camera, az_deg * DEG2RAD, el_deg * DEG2RAD, roll_deg * DEG2RAD, float(time_offset_s))


@dataclass(frozen=True)
class ShipMotion:
    """Ship attitude and position as functions of time ``t_s`` since the session start.

    ``heading = heading0 + heading_rate t + yaw_amp sin(2 pi t / yaw_period)``,
    ``pitch = pitch_amp sin(2 pi t / pitch_period + pitch_phase)``,
    ``roll = roll_amp sin(2 pi t / roll_period + roll_phase)``; the ship sails along its
    mean heading at ``speed_m_per_s`` from (lat0, lon0) on a sphere (dead reckoning).
    """

    heading0_rad: float
    lat0_rad: float
    lon0_rad: float
    height_m: float = 0.0
    heading_rate_rad_per_s: float = 0.0
    yaw_amplitude_rad: float = 0.0
    yaw_period_s: float = 12.0
    pitch0_rad: float = 0.0
    pitch_amplitude_rad: float = 0.0
    pitch_period_s: float = 6.0
    pitch_phase_rad: float = 0.0
    roll0_rad: float = 0.0
    roll_amplitude_rad: float = 0.0
    roll_period_s: float = 8.0
    roll_phase_rad: float = 0.0
    speed_m_per_s: float = 0.0

    def angles_rad(self, t_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(heading in [0, 2pi), pitch, roll) at times ``t_s`` (shape S)."""
        t = np.asarray(t_s, float)
        two_pi = 2.0 * math.pi
        K = (self.heading0_rad + self.heading_rate_rad_per_s * t
             + self.yaw_amplitude_rad * np.sin(two_pi * t / self.yaw_period_s))
        psi = self.pitch0_rad + self.pitch_amplitude_rad * np.sin(two_pi * t / self.pitch_period_s
                                                                  + self.pitch_phase_rad)
        theta = self.roll0_rad + self.roll_amplitude_rad * np.sin(two_pi * t / self.roll_period_s
                                                                  + self.roll_phase_rad)
        return np.mod(K, two_pi), psi, theta

    def C_hor_from_deck(self, t_s) -> np.ndarray:
        """Ship attitude matrices, shape S + (3, 3)."""
        return C_hor_from_deck(*self.angles_rad(t_s))

    def omega_deck_rad_per_s(self, t_s: float) -> np.ndarray:
        """Angular velocity (3,) of the deck relative to the horizontal frame, deck axes."""
        h = _RATE_STEP_S
        C0, C1 = self.C_hor_from_deck(t_s - h), self.C_hor_from_deck(t_s + h)
        S = C0.T @ C1                      # rotation over 2h, deck axes
        w = 0.5 * np.array([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]])
        return w / (2.0 * h)

    def position(self, t_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lat_rad, lon_rad, height_m) at times ``t_s``: along the mean heading at constant speed."""
        t = np.asarray(t_s, float)
        course = self.heading0_rad + 0.5 * self.heading_rate_rad_per_s * t
        dist = self.speed_m_per_s * t / _EARTH_RADIUS_M
        lat = self.lat0_rad + dist * np.cos(course)
        lon = self.lon0_rad + dist * np.sin(course) / math.cos(self.lat0_rad)
        return lat, lon, np.full(t.shape, self.height_m)


@dataclass(frozen=True)
class SessionSpec:
    """Everything that defines a simulated session.

    Attributes
    ----------
    kind : str
        ``"dock"`` or ``"sea"`` (a label).
    start_utc : str
        ISO 8601 UTC of the first frame clock tick.
    duration_s, frame_rate_hz : float
        Frames at ``k / frame_rate_hz`` (+ each sensor's offset) for ``t < duration_s``.
    sensors : tuple of SensorSetup
    motion : ShipMotion
    pressure_hpa, temperature_c, relative_humidity : float
        Weather at the start.
    temperature_rate_c_per_s, pressure_rate_hpa_per_s : float
        Linear weather drift.
    refraction_model : str
        The "true" atmosphere of the simulation (``"erfa"``: within 0.03'' of ray
        tracing above 15 deg).
    mag_limit : float
        Faintest Hp magnitude of the simulated stars.
    centroid_sigma_px : float
        Centroid noise per axis (centroid level).
    exposure_s : float or None
        Image level: replaces the cameras' exposure time (None: keep it).  At sea the
        deck turns by up to 4 deg/s, which smears an 80 ms exposure over 25-40 px; the
        sea session uses 10 ms (3-5 px).  The frame period must not be shorter.
    seed : int

    Everything is validated on construction (before anything is written): the frame
    period against each sensor's exposure, the clock offsets, and the weather and the
    ship's position over the whole time span of the frames.
    """

    kind: str
    start_utc: str
    duration_s: float
    frame_rate_hz: float
    sensors: tuple
    motion: ShipMotion
    pressure_hpa: float = 1013.25
    temperature_c: float = 10.0
    relative_humidity: float = 0.0
    temperature_rate_c_per_s: float = 0.0
    pressure_rate_hpa_per_s: float = 0.0
    refraction_model: str = "erfa"
    mag_limit: float = 8.0
    centroid_sigma_px: float = 0.1
    exposure_s: float | None = None
    seed: int = 0
    #: ``shipstar.simulate._conditions.Conditions`` (cloud, Moon, seeing, clocks, flexure, ...;
    #: images and centroids, see ``apply_conditions``) or None: the clean simulation.
    conditions: object | None = None

    def __post_init__(self):
        from shipstar.sky.time import utc_jd_from_iso

        utc_jd_from_iso(self.start_utc)
        frac = self.start_utc.strip().rstrip("Z").partition(".")[2]
        if len(frac) > 6:
            raise ShipstarError(f"session start_utc {self.start_utc!r}: give at most 6 decimals (microseconds)")
        for name in ("duration_s", "frame_rate_hz"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ShipstarError(f"session {name} must be a finite number > 0, got {v!r}")
        if not self.sensors:
            raise ShipstarError("a session needs at least one sensor")
        names = [s.name for s in self.sensors]
        if len(set(names)) != len(names):
            raise ShipstarError(f"sensor names must be unique, got {names}")
        if not (math.isfinite(self.centroid_sigma_px) and self.centroid_sigma_px >= 0):
            raise ShipstarError(f"centroid_sigma_px must be finite and >= 0, got {self.centroid_sigma_px!r}")
        if self.exposure_s is not None and not (math.isfinite(self.exposure_s) and self.exposure_s > 0):
            raise ShipstarError(f"exposure_s must be finite and > 0, got {self.exposure_s!r}")
        for s in self.sensors:
            self._check_sensor(s)
        self._check_span()

    def _check_sensor(self, s: SensorSetup) -> None:
        off = s.time_offset_s
        if isinstance(off, bool) or not isinstance(off, (int, float)) or not math.isfinite(off) \
                or abs(off) > MAX_TIME_OFFSET_S:
            raise ShipstarError(f"sensor {s.name}: time_offset_s = {off!r} s is not within "
                                f"+-{MAX_TIME_OFFSET_S:g} s (a clock offset between the sensors)")
        period_s, exposure_s = 1.0 / self.frame_rate_hz, self.exposure_of(s)
        if period_s < exposure_s:
            raise ShipstarError(f"frame period {period_s:.6g} s ({self.frame_rate_hz:g} Hz) is shorter than sensor "
                                f"{s.name}'s exposure {exposure_s:g} s: at most {1.0 / exposure_s:.6g} Hz")

    def _check_span(self) -> None:
        """The weather and the ship's position at the first and last frame times and at the
        ends of the track and weather tables (1 s margins); both drift linearly, so the ends
        bound them.  One line naming the time if impossible."""
        from shipstar.sky.refraction import min_true_el_rad

        n = self.n_frames()
        first = min(self._time_s(s, 0) for s in self.sensors)
        last = max(self._time_s(s, n - 1) for s in self.sensors)
        for t in (first, last, -1.0, self.duration_s + 1.0):
            try:
                min_true_el_rad(self.weather(t), self.refraction_model)
                self.site(t)
            except ShipstarError as exc:
                raise ShipstarError(f"the session's weather or ship position at t = {t:.6g} s (frames from "
                                    f"{first:.6g} to {last:.6g} s; both drift linearly): {exc}") from None

    def exposure_of(self, sensor: SensorSetup) -> float:
        """Exposure time (s) of a sensor's frames: the session's, else its camera's."""
        return float(sensor.camera.exposure_s if self.exposure_s is None else self.exposure_s)

    def replace(self, **changes) -> "SessionSpec":
        return replace(self, **changes)

    def sensor(self, name: str) -> SensorSetup:
        for s in self.sensors:
            if s.name == name:
                return s
        raise ShipstarError(f"no sensor {name!r} in the session (have {', '.join(s.name for s in self.sensors)})")

    def n_frames(self) -> int:
        """Frames per sensor."""
        return int(math.floor(self.duration_s * self.frame_rate_hz - 1e-9)) + 1

    def times_s(self, sensor: SensorSetup) -> np.ndarray:
        """Mid-exposure times (s since start) of a sensor's frames: ``k / frame_rate_hz +
        time_offset_s`` rounded to whole microseconds (the files' time resolution)."""
        return self._time_s(sensor, np.arange(self.n_frames()))

    def _time_s(self, sensor: SensorSetup, k):
        t = np.asarray(k) / self.frame_rate_hz + sensor.time_offset_s
        out = np.round(t * _PER_S) / _PER_S          # the float nearest to the whole microsecond
        return float(out) if out.ndim == 0 else out

    def utc_jd(self, t_s: float) -> tuple[float, float]:
        from shipstar.sky.time import utc_jd_from_iso

        jd1, jd2 = utc_jd_from_iso(self.start_utc)
        return jd1, jd2 + float(t_s) / DAY_S

    def utc_iso(self, t_s: float) -> str:
        from shipstar.sky.time import iso_from_utc_jd

        return iso_from_utc_jd(*self.utc_jd(t_s), 6)

    def weather(self, t_s: float):
        from shipstar.sky.refraction import Weather

        return Weather(pressure_hpa=self.pressure_hpa + self.pressure_rate_hpa_per_s * t_s,
                       temperature_c=self.temperature_c + self.temperature_rate_c_per_s * t_s,
                       relative_humidity=self.relative_humidity)

    def site(self, t_s: float):
        from shipstar.sky.apparent import Site

        lat, lon, h = self.motion.position(t_s)
        return Site(float(lat), float(lon), float(h))


def _seed_sensors(offset_a2_s: float = 0.0) -> tuple:
    from shipstar.camera import camera_preset

    return (SensorSetup.from_deg("A1", camera_preset("A1"), *SEED_A1_INSTALL_DEG),
            SensorSetup.from_deg("A2", camera_preset("A2"), *SEED_A2_INSTALL_DEG, time_offset_s=offset_a2_s))


def dock_session(**changes) -> SessionSpec:
    """Seed 000's dock calibration: Jiangyin, 2013-03-15 12:16 UTC (20:16 local), 16 s at 10 fps.

    Heading 46 deg 28' 28.51'', level 0, 11.10 C, 1021.70 hPa, lat 31.9 N, lon 120.3 E;
    A1 and A2 installed at seed 000 Tables 2-3.  Keyword arguments replace fields.
    """
    spec = SessionSpec(
        kind="dock", start_utc="2013-03-15T12:16:00", duration_s=16.0, frame_rate_hz=10.0,
        sensors=_seed_sensors(), motion=ShipMotion(SEED_DOCK_HEADING_DEG * DEG2RAD, 31.9 * DEG2RAD,
                                                   120.3 * DEG2RAD),
        pressure_hpa=1021.70, temperature_c=11.10)
    return replace(spec, **changes)


def sea_session(**changes) -> SessionSpec:
    """The same ship at sea: roll 5 deg / 8 s, pitch 2 deg / 6 s, heading drifting 0.05 deg/s
    with a 0.3 deg / 12 s yaw, 8 m/s along the heading; 16 s at 10 fps, slowly changing weather;
    10 ms exposures at image level (motion smear 3-5 px instead of 25-40 px at 80 ms)."""
    motion = ShipMotion(
        SEED_DOCK_HEADING_DEG * DEG2RAD, 31.9 * DEG2RAD, 120.3 * DEG2RAD, heading_rate_rad_per_s=0.05 * DEG2RAD,
        yaw_amplitude_rad=0.3 * DEG2RAD, yaw_period_s=12.0, pitch_amplitude_rad=2.0 * DEG2RAD,
        pitch_period_s=6.0, pitch_phase_rad=0.7, roll_amplitude_rad=5.0 * DEG2RAD, roll_period_s=8.0,
        speed_m_per_s=8.0)
    spec = SessionSpec(kind="sea", start_utc="2013-03-15T12:16:00", duration_s=16.0, frame_rate_hz=10.0,
                       sensors=_seed_sensors(), motion=motion, pressure_hpa=1021.70, temperature_c=11.10,
                       temperature_rate_c_per_s=-0.01, pressure_rate_hpa_per_s=0.005, exposure_s=0.01)
    return replace(spec, **changes)


# ---------------------------------------------------------------------------------------
# Centroid level
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class CentroidFrame:
    """One sensor frame at centroid level, with its truth.

    Attributes
    ----------
    sensor : str
    index : int
    t_s : float
        Mid-exposure time, seconds since the session start.
    utc_jd1, utc_jd2 : float
    hip : (N,) int64
        Hipparcos numbers of the stars (true identities), brightest first.
    xy_px : (N, 2)
        Measured centroids (truth + Gaussian noise).
    xy_true_px : (N, 2)
        True centroids (distortion included).
    C_hor_from_sensor, C_hor_from_deck : (3, 3)
        True sensor and ship attitudes.
    """

    sensor: str
    index: int
    t_s: float
    utc_jd1: float
    utc_jd2: float
    hip: np.ndarray
    xy_px: np.ndarray
    xy_true_px: np.ndarray
    C_hor_from_sensor: np.ndarray
    C_hor_from_deck: np.ndarray = field(repr=False)
    #: With ``spec.conditions``: the frame's true condition values (``_conditions.centroid_frame``).
    conditions: dict | None = field(default=None, repr=False)


def _centroid_frame(spec: SessionSpec, s: SensorSetup, k: int, t: float, rng) -> CentroidFrame:
    from shipstar.simulate._scene import simulate_stars_horizontal
    from shipstar.sky.apparent import frame_context

    jd1, jd2 = spec.utc_jd(t)
    C_hd = spec.motion.C_hor_from_deck(t)
    C_hs = C_hd @ s.C_deck_from_sensor
    ctx = frame_context(jd1, jd2, spec.site(t))
    stars = simulate_stars_horizontal(s.camera, C_hs, ctx, spec.weather(t), spec.refraction_model,
                                      mag_limit=spec.mag_limit, earth_rotation=False)
    noise = rng.normal(0.0, spec.centroid_sigma_px, stars.xy_px.shape) if spec.centroid_sigma_px else 0.0
    return CentroidFrame(s.name, k, float(t), jd1, jd2, stars.hip, stars.xy_px + noise, stars.xy_px, C_hs, C_hd)


def simulate_centroids(spec: SessionSpec) -> dict[str, list[CentroidFrame]]:
    """Centroid-level frames of every sensor: ``{sensor name: [CentroidFrame, ...]}``.

    Deterministic for a given ``spec.seed`` (each sensor gets its own noise stream).
    """
    if spec.conditions is not None:
        from shipstar.simulate._conditions import simulate_centroids_with_conditions

        return simulate_centroids_with_conditions(spec)
    out = {}
    for j, s in enumerate(spec.sensors):
        rng = np.random.default_rng([spec.seed, j])
        out[s.name] = [_centroid_frame(spec, s, k, t, rng) for k, t in enumerate(spec.times_s(s))]
    return out


# ---------------------------------------------------------------------------------------
# Image level and files
# ---------------------------------------------------------------------------------------

def _csv_text(header: list, rows: list) -> str:
    return ",".join(header) + "\n" + "".join(",".join(r) + "\n" for r in rows)


def _truth_rows(spec: SessionSpec) -> list:
    times = np.unique(np.concatenate([spec.times_s(s) for s in spec.sensors]))
    K, psi, theta = spec.motion.angles_rad(times)
    return [[spec.utc_iso(t), f"{t:.6f}", repr(float(a) * RAD2DEG), repr(float(b) * RAD2DEG), repr(float(c) * RAD2DEG)]
            for t, a, b, c in zip(times, K, psi, theta)]


def _track_rows(spec: SessionSpec) -> list:
    step = 1.0
    times = np.arange(-step, spec.duration_s + 2 * step, step)
    lat, lon, h = spec.motion.position(times)
    return [[spec.utc_iso(t), repr(float(a) * RAD2DEG), repr(float(b) * RAD2DEG), repr(float(c))]
            for t, a, b, c in zip(times, lat, lon, h)]


def _weather_rows(spec: SessionSpec) -> list:
    times = np.arange(-1.0, spec.duration_s + 2.0, 1.0)
    rows = []
    for t in times:
        w = spec.weather(t)
        rows.append([spec.utc_iso(t), repr(w.pressure_hpa), repr(w.temperature_c), repr(w.relative_humidity)])
    return rows


def _toml_exposure(spec: SessionSpec) -> list:
    """``exposure_s`` of every frame when all sensors share it (else only per sensor)."""
    values = {spec.exposure_of(s) for s in spec.sensors}
    return [f"exposure_s = {values.pop()!r}"] if len(values) == 1 else []


def _toml_text(spec: SessionSpec) -> str:
    import json

    m = spec.motion
    lines = ["# shipstar simulated session (docs/file-formats.md); angles in degrees", 'format = "shipstar-session"',
             "format_version = 1", f"kind = {json.dumps(spec.kind)}", f"start_utc = {json.dumps(spec.start_utc)}",
             f"duration_s = {spec.duration_s!r}", f"frame_rate_hz = {spec.frame_rate_hz!r}",
             f"refraction_model = {json.dumps(spec.refraction_model)}", f"mag_limit = {spec.mag_limit!r}",
             *_toml_exposure(spec),
             f"seed = {spec.seed}", "", "[ship]", f"heading0_deg = {m.heading0_rad * RAD2DEG!r}",
             f"pitch0_deg = {m.pitch0_rad * RAD2DEG!r}", f"roll0_deg = {m.roll0_rad * RAD2DEG!r}",
             f"lat0_deg = {m.lat0_rad * RAD2DEG!r}", f"lon0_deg = {m.lon0_rad * RAD2DEG!r}",
             f"height_m = {m.height_m!r}", f"roll_amplitude_deg = {m.roll_amplitude_rad * RAD2DEG!r}",
             f"roll_period_s = {m.roll_period_s!r}", f"pitch_amplitude_deg = {m.pitch_amplitude_rad * RAD2DEG!r}",
             f"pitch_period_s = {m.pitch_period_s!r}", f"heading_rate_deg_per_s = {m.heading_rate_rad_per_s * RAD2DEG!r}",
             f"speed_m_per_s = {m.speed_m_per_s!r}", "", "[weather]", f"pressure_hpa = {spec.pressure_hpa!r}",
             f"temperature_c = {spec.temperature_c!r}", f"relative_humidity = {spec.relative_humidity!r}"]
    for s in spec.sensors:
        lines += ["", "[[sensor]]", f"name = {json.dumps(s.name)}", f"camera = {json.dumps(s.camera.name)}",
                  f"az_deg = {s.install_az_rad * RAD2DEG!r}", f"el_deg = {s.install_el_rad * RAD2DEG!r}",
                  f"roll_deg = {s.install_roll_rad * RAD2DEG!r}", f"time_offset_s = {s.time_offset_s!r}",
                  f"exposure_s = {spec.exposure_of(s)!r}", f"frames_dir = {json.dumps(s.name)}"]
    return "\n".join(lines) + "\n"


def _write_text(path, text: str) -> None:
    from shipstar._atomic import atomic_write_text

    atomic_write_text(path, text)


def _curved_image(spec: SessionSpec, s: SensorSetup, t: float, camera, stars, seed: int):
    """The frame rendered along the stars' true paths (``_motion.exposure_path_px``: the
    ship's attitude and the Earth's rotation at 17 instants of the exposure; straight
    uniform paths, e.g. in dock, as one streak: ``_motion.fewest_pieces``), and the stars
    with their true end-to-end motion as ``smear_px``."""
    from shipstar.simulate._frame import HOT_PIXEL_FRACTION, hot_pixel_seed
    from shipstar.simulate._motion import (
        earth_rate_hor_rad_per_s,
        exposure_offsets_s,
        exposure_path_px,
        fewest_pieces,
        streak_sources,
    )
    from shipstar.simulate._render import render_frame

    tau = exposure_offsets_s(camera.exposure_s)
    C_hs = spec.motion.C_hor_from_deck(t + tau) @ s.C_deck_from_sensor
    lat = spec.site(t).astronomical_lat_rad
    path = exposure_path_px(camera, stars.v_ref, C_hs, tau, earth_rate_hor_rad_per_s(lat))
    xy, signal, smear = streak_sources(fewest_pieces(path), stars.signal_e)
    image = render_frame(camera, xy, signal, np.random.default_rng(seed), smear_px=smear,
                         hot_pixel_fraction=HOT_PIXEL_FRACTION, hot_pixel_seed=hot_pixel_seed(camera))
    return image, replace(stars, smear_px=path[:, -1] - path[:, 0])


def _sensor_frame(spec: SessionSpec, s: SensorSetup, k: int, t: float):
    """One rendered frame (a ``SimulatedFrame``) of sensor ``s`` at mid-exposure ``t``."""
    import erfa

    from shipstar.simulate._frame import HOT_PIXEL_FRACTION, ShipPose, SimulatedFrame
    from shipstar.simulate._render import FalseObjects
    from shipstar.simulate._scene import simulate_stars_horizontal
    from shipstar.sky.apparent import frame_context
    from shipstar.sky.time import tt_jd_from_utc_jd

    K, psi, theta = (float(a) for a in spec.motion.angles_rad(t))
    pose = ShipPose(K, psi, theta, s.install_az_rad, s.install_el_rad, s.install_roll_rad)
    omega = pose.omega_sensor_from_deck(spec.motion.omega_deck_rad_per_s(t))
    seed = int(np.random.SeedSequence([spec.seed, k, sum(map(ord, s.name))]).generate_state(1, np.uint64)[0]) >> 1
    camera = s.camera.replace(exposure_s=spec.exposure_of(s))
    jd1, jd2 = spec.utc_jd(t)
    context, weather = frame_context(jd1, jd2, spec.site(t)), replace(spec.weather(t), wavelength_um=camera.wavelength_um)
    C_hs = pose.C_hor_from_sensor
    stars = simulate_stars_horizontal(camera, C_hs, context, weather, spec.refraction_model,
                                      mag_limit=spec.mag_limit, omega_sensor_rad_per_s=omega)
    image, stars = _curved_image(spec, s, t, camera, stars, seed)
    return SimulatedFrame(
        image=image, stars=stars, camera=camera, utc_iso=spec.utc_iso(t), utc_jd1=jd1, utc_jd2=jd2,
        epoch_jyear=float(erfa.epj(*tt_jd_from_utc_jd(jd1, jd2))),
        C_icrs_from_sensor=np.asarray(context.C_hor_from_icrs_approx).T @ C_hs, C_hor_from_sensor=C_hs,
        context=context, weather=weather, refraction_model=spec.refraction_model, ship=pose,
        omega_sensor_rad_per_s=omega, false_objects=FalseObjects(), seed=seed, mag_limit=float(spec.mag_limit),
        hot_pixel_fraction=HOT_PIXEL_FRACTION)


def estimate_output_bytes(spec: SessionSpec) -> int:
    """What :func:`write_session` will write (bytes, an upper estimate): per frame the FITS
    file (3 header blocks + the padded uint16 data) and its truth JSON (4 kB + 0.5 kB per
    star, for three times the sky's mean star density to the magnitude limit)."""
    from shipstar.simulate._field import star_field

    n_sky = len(star_field(spec.mag_limit).catalog.hip)
    total = 0
    for s in spec.sensors:
        cam = s.camera
        fits_bytes = 3 * 2880 + -(-2 * cam.width_px * cam.height_px // 2880) * 2880
        fov_sr = (cam.width_px * cam.pixel_mm / cam.f_mm) * (cam.height_px * cam.pixel_mm / cam.f_mm)
        stars = 3.0 * n_sky * fov_sr / (4.0 * math.pi)
        total += spec.n_frames() * (fits_bytes + 4096 + int(512 * stars))
    truth_rows = len(spec.sensors) * spec.n_frames()
    return int(total + 120 * truth_rows + 200 * (spec.duration_s + 3) + 4096)


def _preflight(spec: SessionSpec, out, max_output_bytes) -> None:
    """Refuse before anything is created: an output over the cap or over the free space."""
    import shutil
    from pathlib import Path

    need = estimate_output_bytes(spec)
    if max_output_bytes is not None and need > max_output_bytes:
        raise ShipstarError(f"the session would write ~{_size(need)} ({len(spec.sensors)} x {spec.n_frames()} frames), "
                            f"over the cap of {_size(max_output_bytes)}: shorten it, lower the frame rate or "
                            "raise the cap")
    probe = Path(out).absolute()
    while not probe.exists():
        probe = probe.parent
    free = shutil.disk_usage(probe).free
    if need > free:
        raise ShipstarError(f"the session would write ~{_size(need)} but {probe} has only {_size(free)} free")


def _size(n_bytes: float) -> str:
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n_bytes >= scale:
            return f"{n_bytes / scale:.3g} {unit}"
    return f"{int(n_bytes)} B"


def write_session(spec: SessionSpec, out_dir, *, progress=None,
                  max_output_bytes: int | None = DEFAULT_MAX_OUTPUT_BYTES) -> dict:
    """Render every frame of a session and write it to ``out_dir``.

    Layout (docs/file-formats.md)::

        out_dir/session.toml          the spec (sensors, true installation, ship motion), written last
        out_dir/truth.csv             time_utc, t_s, heading_deg, pitch_deg, roll_deg
        out_dir/track.csv             time_utc, lat_deg, lon_deg, height_m (1 s steps)
        out_dir/weather.csv           time_utc, pressure_hpa, temperature_c, relative_humidity
        out_dir/<sensor>/<sensor>_00000.fits  (+ .truth.json)   DATE-AVG = mid-exposure,
                                      DATE-OBS = DATE-BEG = start, DATE-END, EXPTIME

    Parameters
    ----------
    spec : SessionSpec
    out_dir : str or Path
    progress : callable(done, total), optional
    max_output_bytes : int or None
        Refuse (before creating anything) a session whose estimated size
        (:func:`estimate_output_bytes`) is larger; None: no cap.  A session larger than
        the free disk space is always refused.

    Returns
    -------
    dict
        ``{"frames": {sensor: [paths]}, "truth": path, "track": path, "weather": path, "session": path}``.
    """
    from pathlib import Path

    from shipstar.simulate._fits import write_frame

    if not isinstance(spec, SessionSpec):
        raise ShipstarError(f"write_session needs a SessionSpec, got {type(spec).__name__}")
    if spec.conditions is not None:
        from shipstar.simulate._conditions import write_session_with_conditions

        return write_session_with_conditions(spec, out_dir, progress=progress, max_output_bytes=max_output_bytes)
    out = Path(out_dir)
    _preflight(spec, out, max_output_bytes)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ShipstarError(f"cannot create {out}: {exc.strerror or exc}") from None
    total = spec.n_frames() * len(spec.sensors)
    frames, done = {}, 0
    for s in spec.sensors:
        (out / s.name).mkdir(exist_ok=True)
        frames[s.name] = []
        for k, t in enumerate(spec.times_s(s)):
            path, _ = write_frame(_sensor_frame(spec, s, k, float(t)), out / s.name / f"{s.name}_{k:05d}.fits",
                                  s.name)
            frames[s.name].append(path)
            done += 1
            if progress is not None:
                progress(done, total)
    files = {"truth": out / "truth.csv", "track": out / "track.csv", "weather": out / "weather.csv",
             "session": out / "session.toml"}
    _write_text(files["truth"], _csv_text(["time_utc", "t_s", "heading_deg", "pitch_deg", "roll_deg"],
                                          _truth_rows(spec)))
    _write_text(files["track"], _csv_text(["time_utc", "lat_deg", "lon_deg", "height_m"], _track_rows(spec)))
    _write_text(files["weather"], _csv_text(["time_utc", "pressure_hpa", "temperature_c", "relative_humidity"],
                                            _weather_rows(spec)))
    _write_text(files["session"], _toml_text(spec))
    return {"frames": frames, **files}
