"""Session files (``dock.toml``, ``sea.toml``): one measurement session and what it names."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from shipstar.config._ship import ShipConfig, load_ship
from shipstar.config._simulation import MotionConfig, SimulationConfig, _simulation
from shipstar.config._site import SiteConfig, load_site
from shipstar.config._toml import _read_toml, _relative, _Table
from shipstar.errors import ShipstarError
from shipstar.units import ASEC2RAD, DEG2RAD

SESSION_KINDS = ("dock", "sea")


@dataclass(frozen=True)
class WeatherConfig:
    """Weather at the sensors: constants with a linear drift, or a CSV table (real sessions)."""

    pressure_hpa: float = 1013.25
    temperature_c: float = 10.0
    relative_humidity: float = 0.0
    pressure_rate_hpa_per_s: float = 0.0
    temperature_rate_c_per_s: float = 0.0
    csv: Path | None = None


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
    w = WeatherConfig(pressure_hpa=t.number("pressure_hpa", 1013.25, limit="pressure_hpa"),
                      temperature_c=t.number("temperature_c", 10.0, limit="temperature_c"),
                      relative_humidity=t.number("relative_humidity", 0.0, limit="relative_humidity"),
                      pressure_rate_hpa_per_s=t.number("pressure_rate_hpa_per_s", 0.0, lo=-1.0, hi=1.0),
                      temperature_rate_c_per_s=t.number("temperature_rate_c_per_s", 0.0, lo=-1.0, hi=1.0),
                      csv=_relative(base, csv) if csv else None)
    t.finish()
    return w


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
    att = (t.number("heading_deg", limit="heading_deg"), t.number("pitch_deg", 0.0, limit="pitch_deg"),
           t.number("roll_deg", 0.0, limit="roll_deg"))
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
