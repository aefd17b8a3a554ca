"""Site, ship, sensors and sessions described in TOML files (docs/quickstart.md, section 4).

A project directory holds::

    site.toml           the dock: geodetic position, deflection of the vertical
    ship.toml           the ship and its sensors: camera (preset or file), installation
    cameras/<name>.toml camera models (shipstar camera format, see docs/camera.md)
    dock.toml           the dock calibration session (known ship attitude, weather)
    sea.toml            a session at sea (track and weather tables, or constants)

Session files name their site and ship files; paths are relative to the file that names
them.  Every key carries its unit (``lat_deg``, ``pressure_hpa``, ``duration_s``).
Unknown keys, missing keys, wrong types and out-of-range values raise
:class:`~shipstar.errors.ShipstarError` naming the file and the key, so a typo never
silently drops a setting.

``[simulation]`` tables are read by ``shipstar demo`` only (the simulated ship motion,
star magnitude limit, noise seed, which frames are rendered as images); real sessions
name their FITS frame directories in ``[frames]`` and their track and weather CSV files.

Public API::

    load_site(path) -> SiteConfig
    load_ship(path) -> ShipConfig
    load_session(path) -> SessionConfig          # with its site and ship
    load_project(directory) -> ProjectConfig     # dock.toml + sea.toml (and what they name)
    write_example_config(directory, overwrite=False) -> [Path]   # the demo's files
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

from shipstar.errors import ShipstarError
from shipstar.units import ASEC2RAD, DEG2RAD

__all__ = [
    "SiteConfig", "SensorEntry", "ShipConfig", "WeatherConfig", "MotionConfig", "SimulationConfig",
    "SessionConfig", "ProjectConfig", "load_site", "load_ship", "load_session", "load_project",
    "write_example_config", "example_files", "SESSION_KINDS", "FORMAT_VERSION",
]

FORMAT_VERSION = 1
SESSION_KINDS = ("dock", "sea")
_REQUIRED = object()


# ---------------------------------------------------------------------------------------
# Reading TOML tables with named, one-line errors
# ---------------------------------------------------------------------------------------

class _Table:
    """Typed access to one TOML table; :meth:`finish` refuses keys nobody asked for."""

    def __init__(self, data, where: str):
        if not isinstance(data, dict):
            raise ShipstarError(f"{where} must be a table")
        self.data, self.where, self.used = data, where, set()

    def _get(self, key: str, default):
        self.used.add(key)
        if key not in self.data:
            if default is _REQUIRED:
                raise ShipstarError(f"{self.where}: missing key {key!r}")
            return default, False
        return self.data[key], True

    def number(self, key: str, default=_REQUIRED, *, lo=-math.inf, hi=math.inf, lo_open=False) -> float:
        value, given = self._get(key, default)
        if not given:
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ShipstarError(f"{self.where}: {key} must be a finite number, got {value!r}")
        if value < lo or value > hi or (lo_open and value == lo):
            op = ">" if lo_open else ">="
            rng = f"{op} {lo:g}" if hi == math.inf else f"within [{lo:g}, {hi:g}]"
            raise ShipstarError(f"{self.where}: {key} must be {rng}, got {value!r}")
        return float(value)

    def integer(self, key: str, default=_REQUIRED, *, lo=0, hi=2**63 - 1) -> int:
        value, given = self._get(key, default)
        if not given:
            return value
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise ShipstarError(f"{self.where}: {key} must be an integer within [{lo}, {hi}], got {value!r}")
        return int(value)

    def text(self, key: str, default=_REQUIRED, *, choices=None) -> str:
        value, given = self._get(key, default)
        if not given:
            return value
        if not isinstance(value, str):
            raise ShipstarError(f"{self.where}: {key} must be a string, got {value!r}")
        if choices is not None and value not in choices:
            raise ShipstarError(f"{self.where}: {key} must be one of {', '.join(choices)}, got {value!r}")
        return value

    def table(self, key: str, required: bool = False) -> "_Table | None":
        value, given = self._get(key, _REQUIRED if required else None)
        return _Table(value, f"{self.where} [{key}]") if given else None

    def tables(self, key: str) -> list:
        value, given = self._get(key, [])
        if given and not (isinstance(value, list) and all(isinstance(v, dict) for v in value)):
            raise ShipstarError(f"{self.where}: {key} must be an array of tables [[{key}]]")
        return [_Table(v, f"{self.where} [[{key}]] #{k + 1}") for k, v in enumerate(value)]

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise ShipstarError(f"{self.where}: unknown key {unknown[0]!r}")


def _read_toml(path, what: str) -> tuple[Path, _Table]:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ShipstarError(f"{what} file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ShipstarError(f"cannot read {what} file {path}: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ShipstarError(f"{path}: not valid TOML: {' '.join(str(exc).split())}") from None
    t = _Table(data, str(path))
    fmt = t.text("format")
    if fmt != f"shipstar-{what}":
        raise ShipstarError(f"{path}: format must be 'shipstar-{what}', got {fmt!r}")
    version = t.integer("format_version")
    if version != FORMAT_VERSION:
        raise ShipstarError(f"{path}: format_version {version} is not supported (expected {FORMAT_VERSION})")
    return path, t


def _relative(base: Path, name: str) -> Path:
    p = Path(name).expanduser()
    return p if p.is_absolute() else base.parent / p


# ---------------------------------------------------------------------------------------
# Site and ship
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SiteConfig:
    """A dock or start position: geodetic (WGS84) and the deflection of the vertical."""

    name: str
    lat_deg: float
    lon_deg: float
    height_m: float = 0.0
    xi_arcsec: float = 0.0
    eta_arcsec: float = 0.0

    def site(self):
        """The :class:`shipstar.sky.apparent.Site` (validated there too)."""
        from shipstar.sky.apparent import Site

        return Site.from_deg(self.lat_deg, self.lon_deg, self.height_m, self.xi_arcsec, self.eta_arcsec)


def load_site(path) -> SiteConfig:
    """Read a ``site.toml`` (format ``shipstar-site``)."""
    path, t = _read_toml(path, "site")
    s = t.table("site", required=True)
    cfg = SiteConfig(name=s.text("name", ""), lat_deg=s.number("lat_deg", lo=-90.0, hi=90.0),
                     lon_deg=s.number("lon_deg", lo=-180.0, hi=360.0), height_m=s.number("height_m", 0.0),
                     xi_arcsec=s.number("xi_arcsec", 0.0), eta_arcsec=s.number("eta_arcsec", 0.0))
    s.finish()
    t.finish()
    try:
        cfg.site()
    except ShipstarError as exc:
        raise ShipstarError(f"{path}: {exc}") from None
    return cfg


@dataclass(frozen=True, eq=False)
class SensorEntry:
    """One star sensor on the ship.

    Attributes
    ----------
    name : str
    camera : shipstar.camera.Camera
    camera_ref : str
        As written in the file: a preset name or a path (relative to ship.toml).
    az_deg, el_deg, roll_deg : float
        Installation angles (``C_deck_from_sensor = R_y(az) R_z(-el) R_x(-roll)``): the
        design (or true, for simulation) values, or those of ``installation_file``.
    time_offset_s : float
        Exposure clock offset of this sensor (simulation).
    installation_file : Path or None
        A calibrated installation (``shipstar.calibrate.installation.save_installation``).
    """

    name: str
    camera: object
    camera_ref: str
    az_deg: float
    el_deg: float
    roll_deg: float
    time_offset_s: float = 0.0
    installation_file: Path | None = None

    def installation(self):
        """The calibrated :class:`~shipstar.calibrate.installation.Installation` (None without a file)."""
        if self.installation_file is None:
            return None
        from shipstar.calibrate.installation import load_installation

        return load_installation(self.installation_file)


@dataclass(frozen=True, eq=False)
class ShipConfig:
    """The ship and its sensors."""

    name: str
    sensors: tuple
    path: Path | None = None

    def sensor(self, name: str) -> SensorEntry:
        for s in self.sensors:
            if s.name == name:
                return s
        have = ", ".join(s.name for s in self.sensors)
        raise ShipstarError(f"no sensor {name!r} on ship {self.name!r} (have {have})")


def _camera(ref: str, base: Path, where: str):
    from shipstar.camera import PRESETS, camera_preset, load_camera

    if ref in PRESETS:
        return camera_preset(ref)
    path = _relative(base, ref)
    if not path.is_file():
        raise ShipstarError(f"{where}: camera {ref!r} is neither a preset ({', '.join(PRESETS)}) nor a file "
                            f"({path} does not exist)")
    return load_camera(path)


def _sensor_entry(s: _Table, base: Path) -> SensorEntry:
    name = s.text("name")
    if not name or not name.replace("_", "").replace("-", "").isalnum():
        raise ShipstarError(f"{s.where}: name must be letters, digits, '-' or '_', got {name!r}")
    ref = s.text("camera")
    inst_ref = s.text("installation_file", "")
    entry = SensorEntry(name=name, camera=_camera(ref, base, s.where), camera_ref=ref,
                        az_deg=s.number("az_deg", lo=-360.0, hi=360.0), el_deg=s.number("el_deg", lo=-90.0, hi=90.0),
                        roll_deg=s.number("roll_deg", 0.0, lo=-180.0, hi=180.0),
                        time_offset_s=s.number("time_offset_s", 0.0, lo=-1.0, hi=1.0),
                        installation_file=_relative(base, inst_ref) if inst_ref else None)
    s.finish()
    if entry.installation_file is not None:
        inst = entry.installation()
        if inst.sensor != name:
            raise ShipstarError(f"{s.where}: installation file {entry.installation_file} is for sensor "
                                f"{inst.sensor!r}, not {name!r}")
        entry = replace(entry, az_deg=inst.az_rad / DEG2RAD, el_deg=inst.el_rad / DEG2RAD,
                        roll_deg=inst.roll_rad / DEG2RAD)
    return entry


def load_ship(path) -> ShipConfig:
    """Read a ``ship.toml`` (format ``shipstar-ship``) and the camera files it names."""
    path, t = _read_toml(path, "ship")
    s = t.table("ship", required=True)
    name = s.text("name", "")
    s.finish()
    sensors = tuple(_sensor_entry(e, path) for e in t.tables("sensor"))
    t.finish()
    if not sensors:
        raise ShipstarError(f"{path}: no [[sensor]] tables (a ship needs at least one sensor)")
    names = [e.name for e in sensors]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ShipstarError(f"{path}: sensor name {dup[0]!r} is used twice")
    return ShipConfig(name=name, sensors=sensors, path=path)


# ---------------------------------------------------------------------------------------
# Sessions
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class WeatherConfig:
    """Weather at the sensors: constants with a linear drift, or a CSV table (real sessions)."""

    pressure_hpa: float = 1013.25
    temperature_c: float = 10.0
    relative_humidity: float = 0.0
    pressure_rate_hpa_per_s: float = 0.0
    temperature_rate_c_per_s: float = 0.0
    csv: Path | None = None


@dataclass(frozen=True)
class MotionConfig:
    """Simulated ship motion (see :class:`shipstar.simulate._session.ShipMotion`); angles in degrees."""

    heading_deg: float
    heading_rate_deg_per_s: float = 0.0
    yaw_amplitude_deg: float = 0.0
    yaw_period_s: float = 12.0
    pitch_deg: float = 0.0
    pitch_amplitude_deg: float = 0.0
    pitch_period_s: float = 6.0
    pitch_phase_deg: float = 0.0
    roll_deg: float = 0.0
    roll_amplitude_deg: float = 0.0
    roll_period_s: float = 8.0
    roll_phase_deg: float = 0.0
    speed_m_per_s: float = 0.0


@dataclass(frozen=True)
class SimulationConfig:
    """What ``shipstar demo`` simulates for a session.

    Attributes
    ----------
    true_refraction_model : str
        The atmosphere of the simulation (``"erfa"``: within 0.03'' of ray tracing).
    mag_limit : float
        Faintest Hp magnitude simulated.
    centroid_sigma_px : float
        Centroid noise of centroid-level frames (image-level frames get theirs from
        the rendered image).
    seed : int
    image_level_s : float
        Frames before this time (s since the start) are rendered and extracted; the
        rest are centroid level.
    exposure_s : float or None
        Replaces the cameras' exposure time for rendered frames (None: keep it).  At sea
        the deck turns by up to 4 deg/s, which smears an 80 ms exposure over 25-40 px.
    motion : MotionConfig or None
        Sea sessions; dock sessions hold still at the ``[dock]`` attitude.
    """

    true_refraction_model: str = "erfa"
    mag_limit: float = 8.0
    centroid_sigma_px: float = 0.1
    seed: int = 0
    image_level_s: float = 0.0
    exposure_s: float | None = None
    motion: MotionConfig | None = None


@dataclass(frozen=True, eq=False)
class SessionConfig:
    """One measurement session (dock calibration or at sea) and everything it names.

    Attributes
    ----------
    path : Path
    kind : {"dock", "sea"}
    label : str
    start_utc : str
        ISO 8601 UTC of the first frame.
    duration_s, frame_rate_hz : float
    site : SiteConfig
        The dock, or the start of the track.
    ship : ShipConfig
    dock_attitude_deg : (heading, pitch, roll) or None
        The ship's known attitude in dock (theodolite heading, precision levels).
    weather : WeatherConfig
    track_csv : Path or None
        Real sea sessions: the ship's position over time.
    frames : dict of sensor name -> Path
        Real sessions: one FITS directory per sensor.
    refraction_model, refraction : str
        Processing settings (``shipstar.pipeline.PipelineOptions``).
    simulation : SimulationConfig
    """

    path: Path
    kind: str
    label: str
    start_utc: str
    duration_s: float
    frame_rate_hz: float
    site: SiteConfig
    ship: ShipConfig
    dock_attitude_deg: tuple | None
    weather: WeatherConfig
    track_csv: Path | None
    frames: dict
    refraction_model: str
    refraction: str
    simulation: SimulationConfig = field(default_factory=SimulationConfig)

    def replace(self, **changes) -> "SessionConfig":
        return replace(self, **changes)

    def pipeline_options(self, **changes):
        """:class:`shipstar.pipeline.PipelineOptions` with this session's settings."""
        from shipstar.pipeline import PipelineOptions

        return PipelineOptions(refraction_model=self.refraction_model, refraction=self.refraction, **changes)

    def track(self):
        """:class:`shipstar.pipeline.Track`: the CSV table (its own ``xi_arcsec``,
        ``eta_arcsec`` columns), or the fixed site with its deflection of the vertical."""
        from shipstar.pipeline import Track

        if self.track_csv is not None:
            return Track.read_csv(self.track_csv)
        s = self.site
        return Track.fixed(s.lat_deg, s.lon_deg, s.height_m, s.xi_arcsec, s.eta_arcsec)

    def weather_table(self):
        """:class:`shipstar.pipeline.WeatherTable`: the CSV table, or the constants."""
        from shipstar.pipeline import WeatherTable

        w = self.weather
        if w.csv is not None:
            return WeatherTable.read_csv(w.csv)
        if w.pressure_rate_hpa_per_s or w.temperature_rate_c_per_s:
            raise ShipstarError(f"{self.path}: weather drift rates are for simulation; real sessions give a "
                                "weather csv")
        return WeatherTable.constant(w.pressure_hpa, w.temperature_c, w.relative_humidity)

    def frame_lists(self) -> list:
        """Each sensor's FITS frames (``shipstar.pipeline.scan_frames``), in ship order."""
        from shipstar.pipeline import scan_frames

        missing = [s.name for s in self.ship.sensors if s.name not in self.frames]
        if missing:
            raise ShipstarError(f"{self.path}: [frames] names no directory for sensor {missing[0]}")
        return [scan_frames(self.frames[s.name]) for s in self.ship.sensors]

    def dock_conditions(self):
        """:class:`~shipstar.calibrate.installation.DockConditions` of a dock session."""
        from shipstar.calibrate.installation import DockConditions

        if self.dock_attitude_deg is None:
            raise ShipstarError(f"{self.path}: a {self.kind} session has no [dock] attitude")
        K, p, r = self.dock_attitude_deg
        s, w = self.site, self.weather
        return DockConditions(K * DEG2RAD, p * DEG2RAD, r * DEG2RAD, s.lat_deg * DEG2RAD, s.lon_deg * DEG2RAD,
                              s.height_m, w.pressure_hpa, w.temperature_c, self.refraction_model, self.refraction,
                              xi_rad=s.xi_arcsec * ASEC2RAD, eta_rad=s.eta_arcsec * ASEC2RAD)

    def spec(self):
        """The simulated session (:class:`shipstar.simulate._session.SessionSpec`)."""
        from shipstar.simulate._session import SensorSetup, SessionSpec, ShipMotion

        sim, w = self.simulation, self.weather
        if self.site.xi_arcsec or self.site.eta_arcsec:
            raise ShipstarError(f"{self.path}: the simulator has no deflection of the vertical (site xi_arcsec = "
                                f"{self.site.xi_arcsec:g}, eta_arcsec = {self.site.eta_arcsec:g}); set both to 0 to "
                                "simulate this session")
        m = sim.motion if self.kind == "sea" else None
        if self.kind == "sea" and m is None:
            raise ShipstarError(f"{self.path}: a simulated sea session needs [simulation.ship_motion]")
        if m is None:
            K, p, r = self.dock_attitude_deg
            m = MotionConfig(heading_deg=K, pitch_deg=p, roll_deg=r)
        motion = ShipMotion(
            m.heading_deg * DEG2RAD, self.site.lat_deg * DEG2RAD, self.site.lon_deg * DEG2RAD, self.site.height_m,
            heading_rate_rad_per_s=m.heading_rate_deg_per_s * DEG2RAD, yaw_amplitude_rad=m.yaw_amplitude_deg * DEG2RAD,
            yaw_period_s=m.yaw_period_s, pitch0_rad=m.pitch_deg * DEG2RAD,
            pitch_amplitude_rad=m.pitch_amplitude_deg * DEG2RAD, pitch_period_s=m.pitch_period_s,
            pitch_phase_rad=m.pitch_phase_deg * DEG2RAD, roll0_rad=m.roll_deg * DEG2RAD,
            roll_amplitude_rad=m.roll_amplitude_deg * DEG2RAD, roll_period_s=m.roll_period_s,
            roll_phase_rad=m.roll_phase_deg * DEG2RAD, speed_m_per_s=m.speed_m_per_s)
        sensors = tuple(SensorSetup.from_deg(s.name, s.camera, s.az_deg, s.el_deg, s.roll_deg, s.time_offset_s)
                        for s in self.ship.sensors)
        return SessionSpec(
            kind=self.kind, start_utc=self.start_utc, duration_s=self.duration_s, frame_rate_hz=self.frame_rate_hz,
            sensors=sensors, motion=motion, pressure_hpa=w.pressure_hpa, temperature_c=w.temperature_c,
            relative_humidity=w.relative_humidity, temperature_rate_c_per_s=w.temperature_rate_c_per_s,
            pressure_rate_hpa_per_s=w.pressure_rate_hpa_per_s, refraction_model=sim.true_refraction_model,
            mag_limit=sim.mag_limit, centroid_sigma_px=sim.centroid_sigma_px, exposure_s=sim.exposure_s, seed=sim.seed)


def _weather(t: _Table | None, base: Path) -> WeatherConfig:
    if t is None:
        return WeatherConfig()
    csv = t.text("csv", "")
    w = WeatherConfig(pressure_hpa=t.number("pressure_hpa", 1013.25, lo=0.0, hi=1200.0, lo_open=True),
                      temperature_c=t.number("temperature_c", 10.0, lo=-90.0, hi=60.0),
                      relative_humidity=t.number("relative_humidity", 0.0, lo=0.0, hi=1.0),
                      pressure_rate_hpa_per_s=t.number("pressure_rate_hpa_per_s", 0.0, lo=-1.0, hi=1.0),
                      temperature_rate_c_per_s=t.number("temperature_rate_c_per_s", 0.0, lo=-1.0, hi=1.0),
                      csv=_relative(base, csv) if csv else None)
    t.finish()
    return w


def _motion(t: _Table | None) -> MotionConfig | None:
    if t is None:
        return None
    ang = dict(lo=-360.0, hi=360.0)
    per = dict(lo=0.0, hi=3600.0, lo_open=True)
    m = MotionConfig(
        heading_deg=t.number("heading_deg", **ang), heading_rate_deg_per_s=t.number("heading_rate_deg_per_s", 0.0,
                                                                                     lo=-10.0, hi=10.0),
        yaw_amplitude_deg=t.number("yaw_amplitude_deg", 0.0, lo=0.0, hi=45.0), yaw_period_s=t.number("yaw_period_s",
                                                                                                      12.0, **per),
        pitch_deg=t.number("pitch_deg", 0.0, lo=-30.0, hi=30.0),
        pitch_amplitude_deg=t.number("pitch_amplitude_deg", 0.0, lo=0.0, hi=30.0),
        pitch_period_s=t.number("pitch_period_s", 6.0, **per), pitch_phase_deg=t.number("pitch_phase_deg", 0.0, **ang),
        roll_deg=t.number("roll_deg", 0.0, lo=-45.0, hi=45.0),
        roll_amplitude_deg=t.number("roll_amplitude_deg", 0.0, lo=0.0, hi=45.0),
        roll_period_s=t.number("roll_period_s", 8.0, **per), roll_phase_deg=t.number("roll_phase_deg", 0.0, **ang),
        speed_m_per_s=t.number("speed_m_per_s", 0.0, lo=0.0, hi=50.0))
    t.finish()
    return m


def _simulation(t: _Table | None) -> SimulationConfig:
    from shipstar.sky.refraction import MODELS

    if t is None:
        return SimulationConfig()
    sim = SimulationConfig(
        true_refraction_model=t.text("true_refraction_model", "erfa", choices=MODELS),
        mag_limit=t.number("mag_limit", 8.0, lo=0.0, hi=12.0), centroid_sigma_px=t.number("centroid_sigma_px", 0.1,
                                                                                           lo=0.0, hi=10.0),
        seed=t.integer("seed", 0), image_level_s=t.number("image_level_s", 0.0, lo=0.0),
        exposure_s=t.number("exposure_s", None, lo=0.0, hi=10.0, lo_open=True), motion=_motion(t.table("ship_motion")))
    t.finish()
    return sim


def _frames(t: _Table | None, base: Path) -> dict:
    if t is None:
        return {}
    out = {}
    for key in list(t.data):
        out[key] = _relative(base, t.text(key))
    t.finish()
    return out


def _dock_attitude(t: _Table | None, kind: str, path: Path):
    if kind == "dock" and t is None:
        raise ShipstarError(f"{path}: a dock session needs a [dock] table (heading_deg, pitch_deg, roll_deg)")
    if t is None:
        return None
    if kind != "dock":
        raise ShipstarError(f"{path}: [dock] belongs in dock sessions only")
    att = (t.number("heading_deg", lo=0.0, hi=360.0), t.number("pitch_deg", 0.0, lo=-30.0, hi=30.0),
           t.number("roll_deg", 0.0, lo=-45.0, hi=45.0))
    t.finish()
    return att


def load_session(path) -> SessionConfig:
    """Read a session file (format ``shipstar-session-config``) with the site and ship it names."""
    from shipstar.attitude import REFRACTION_MODES
    from shipstar.sky.refraction import MODELS
    from shipstar.sky.time import utc_jd_from_iso

    path, t = _read_toml(path, "session-config")
    kind = t.text("kind", choices=SESSION_KINDS)
    start = t.text("start_utc")
    try:
        utc_jd_from_iso(start)
    except ShipstarError as exc:
        raise ShipstarError(f"{path}: start_utc: {exc}") from None
    site = load_site(_relative(path, t.text("site")))
    ship = load_ship(_relative(path, t.text("ship")))
    cfg = SessionConfig(
        path=path, kind=kind, label=t.text("label", path.stem), start_utc=start,
        duration_s=t.number("duration_s", lo=0.0, hi=86400.0, lo_open=True),
        frame_rate_hz=t.number("frame_rate_hz", lo=0.0, hi=1000.0, lo_open=True), site=site, ship=ship,
        dock_attitude_deg=_dock_attitude(t.table("dock"), kind, path), weather=_weather(t.table("weather"), path),
        track_csv=_track(t.table("track"), path), frames=_frames(t.table("frames"), path),
        refraction_model=t.text("refraction_model", "erfa", choices=MODELS),
        refraction=t.text("refraction", "per-star", choices=REFRACTION_MODES),
        simulation=_simulation(t.table("simulation")))
    t.finish()
    unknown = sorted(set(cfg.frames) - {s.name for s in ship.sensors})
    if unknown:
        raise ShipstarError(f"{path}: [frames] names sensor {unknown[0]!r}, which is not on the ship")
    return cfg


def _track(t: _Table | None, base: Path) -> Path | None:
    if t is None:
        return None
    csv = t.text("csv")
    t.finish()
    return _relative(base, csv)


@dataclass(frozen=True, eq=False)
class ProjectConfig:
    """A directory's dock and sea sessions (they must describe the same ship)."""

    directory: Path
    dock: SessionConfig
    sea: SessionConfig

    @property
    def ship(self) -> ShipConfig:
        return self.dock.ship


def load_project(directory) -> ProjectConfig:
    """Read ``dock.toml`` and ``sea.toml`` of a directory (and the files they name)."""
    d = Path(directory)
    if not d.is_dir():
        raise ShipstarError(f"configuration directory {d} does not exist (write one with "
                            "'shipstar demo --write-config DIR')")
    dock, sea = load_session(d / "dock.toml"), load_session(d / "sea.toml")
    if dock.kind != "dock" or sea.kind != "sea":
        raise ShipstarError(f"{d}: dock.toml must be kind = \"dock\" and sea.toml kind = \"sea\"")
    if [s.name for s in dock.ship.sensors] != [s.name for s in sea.ship.sensors]:
        raise ShipstarError(f"{d}: dock.toml and sea.toml describe different sensors")
    return ProjectConfig(d, dock, sea)


# ---------------------------------------------------------------------------------------
# The demo's files, as examples to edit
# ---------------------------------------------------------------------------------------

_SITE_TOML = """\
# shipstar site: where the dock calibration takes place (docs/quickstart.md, section 4).
# Seed 000: the Jiangyin dock, 2013-03-15.
format = "shipstar-site"
format_version = 1

[site]
name = "Jiangyin dock"
lat_deg = 31.9            # geodetic latitude (WGS84), north positive
lon_deg = 120.3           # longitude, east positive
height_m = 0.0            # above the WGS84 ellipsoid
xi_arcsec = 0.0           # deflection of the vertical, north-south (precision levels follow gravity)
eta_arcsec = 0.0          # deflection of the vertical, east-west
"""

_SHIP_TOML = """\
# shipstar ship: its star sensors, their cameras and installation (docs/quickstart.md, section 4).
# Installation: C_deck_from_sensor = R_y(az) R_z(-el) R_x(-roll) (docs/conventions.md):
#   az_deg   boresight azimuth from the bow toward starboard
#   el_deg   boresight elevation above the deck
#   roll_deg sensor roll about its boresight
# Before the dock calibration these are the design values; the demo simulates them as the
# truth.  After 'shipstar calibrate install', point installation_file at its output: its
# angles then replace the three above.
format = "shipstar-ship"
format_version = 1

[ship]
name = "seed 000 survey ship"

[[sensor]]
name = "A1"                   # looks aft (seed 000 Table 2)
camera = "cameras/A1.toml"    # a camera file (relative to this file) or a preset: A1, A2, seed002, seed004
az_deg = 185.1093
el_deg = 39.3734
roll_deg = -0.2262
time_offset_s = 0.0           # simulation: exposure clock offset of this sensor
# installation_file = "A1.installation.toml"

[[sensor]]
name = "A2"                   # looks to port (seed 000 Table 3)
camera = "cameras/A2.toml"
az_deg = 274.9246
el_deg = 35.1031
roll_deg = 0.0789
time_offset_s = 0.02          # A2 exposes 20 ms after A1: the pipeline carries it to A1's time
# installation_file = "A2.installation.toml"
"""

_DOCK_TOML = """\
# shipstar session: the dock calibration of the installation angles (docs/calibration-procedures.md).
# Seed 000: 2013-03-15 20:16 local time (12:16 UTC), 16 s of frames at 10 frames/s.
format = "shipstar-session-config"
format_version = 1
kind = "dock"
label = "dock calibration, Jiangyin 2013-03-15"
site = "site.toml"
ship = "ship.toml"
start_utc = "2013-03-15T12:16:00"     # first frame, mid-exposure, UTC
duration_s = 16.0
frame_rate_hz = 10.0
refraction_model = "erfa"             # erfa | almanac (the seeds') | none
refraction = "per-star"               # per-star (seed 000) | boresight | none

[dock]                                # the ship's known attitude in dock
heading_deg = 46.474586               # theodolite: 46 deg 28' 28.51''
pitch_deg = 0.0                       # precision levels
roll_deg = 0.0

[weather]                             # at the sensors; or csv = "weather.csv"
pressure_hpa = 1021.70
temperature_c = 11.10
relative_humidity = 0.0

# [frames]                            # real sessions: one FITS directory per sensor
# A1 = "frames/dock/A1"
# A2 = "frames/dock/A2"

[simulation]                          # shipstar demo only
true_refraction_model = "erfa"        # the simulated atmosphere
mag_limit = 8.0                       # faintest Hp magnitude rendered
centroid_sigma_px = 0.1               # centroid noise of centroid-level frames
seed = 2013
image_level_s = 16.0                  # frames before this time are rendered and extracted
"""

_SEA_TOML = """\
# shipstar session: at sea, the ship rolling and pitching (docs/quickstart.md).
format = "shipstar-session-config"
format_version = 1
kind = "sea"
label = "at sea, roll 5 deg / 8 s, pitch 2 deg / 6 s"
site = "site.toml"                    # start of the simulated track
ship = "ship.toml"
start_utc = "2013-03-15T12:30:00"
duration_s = 60.0
frame_rate_hz = 10.0
refraction_model = "erfa"
refraction = "per-star"

[weather]                             # or csv = "weather.csv" (time_utc, pressure_hpa, temperature_c)
pressure_hpa = 1021.70
temperature_c = 11.10
relative_humidity = 0.0
pressure_rate_hpa_per_s = 0.005       # simulation: linear drift
temperature_rate_c_per_s = -0.01

# [track]                             # real sessions: the ship's position over time
# csv = "track.csv"                   # time_utc, lat_deg, lon_deg[, height_m][, xi_arcsec, eta_arcsec]
# [frames]
# A1 = "frames/sea/A1"
# A2 = "frames/sea/A2"

[simulation]
true_refraction_model = "erfa"
mag_limit = 8.0
centroid_sigma_px = 0.1
seed = 2014
image_level_s = 30.0                  # rendered and extracted for the first 30 s, centroid level after
exposure_s = 0.01                     # 10 ms: the deck turns up to 4 deg/s (80 ms would smear stars 25-40 px)

[simulation.ship_motion]
heading_deg = 46.474586
heading_rate_deg_per_s = 0.05
yaw_amplitude_deg = 0.3
yaw_period_s = 12.0
pitch_amplitude_deg = 2.0
pitch_period_s = 6.0
pitch_phase_deg = 40.0
roll_amplitude_deg = 5.0
roll_period_s = 8.0
roll_phase_deg = 0.0
speed_m_per_s = 8.0
"""


def example_files() -> dict:
    """``{relative path: text}`` of the demo's TOML files other than the cameras (which
    :func:`write_example_config` writes from the presets A1 and A2 with ``save_camera``)."""
    return {"site.toml": _SITE_TOML, "ship.toml": _SHIP_TOML, "dock.toml": _DOCK_TOML, "sea.toml": _SEA_TOML}


_EXAMPLE_CAMERAS = ("A1", "A2")


def _atomic_write_text(path: Path, text: str) -> None:
    from shipstar._atomic import atomic_write_text

    atomic_write_text(path, text)


def write_example_config(directory, *, overwrite: bool = False) -> list:
    """Write the demo's configuration files into ``directory`` (created if needed).

    Refuses (ShipstarError, nothing written) when a file exists and ``overwrite`` is
    false.  Returns the paths written.
    """
    from shipstar.camera import camera_preset, save_camera

    d = Path(directory)
    if d.exists() and not d.is_dir():
        raise ShipstarError(f"{d} exists and is not a directory")
    files = example_files()
    cameras = {f"cameras/{n}.toml": n for n in _EXAMPLE_CAMERAS}
    if not overwrite:
        existing = [rel for rel in (*files, *cameras) if (d / rel).exists()]
        if existing:
            raise ShipstarError(f"{d / existing[0]} already exists (use --force to overwrite)")
    written = []
    try:
        for rel, text in files.items():
            _atomic_write_text(d / rel, text)
            written.append(d / rel)
        for rel, name in cameras.items():
            (d / rel).parent.mkdir(parents=True, exist_ok=True)
            save_camera(camera_preset(name), d / rel)
            written.append(d / rel)
    except OSError as exc:
        raise ShipstarError(f"cannot write into {d}: {exc.strerror or exc}") from None
    return written
