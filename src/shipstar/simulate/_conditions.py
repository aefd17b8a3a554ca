"""Simulator conditions: the real sky and the real ship (issue 14, item 1).

A conditions file (TOML, ``format = "shipstar-conditions"``; examples in
``shipstar/data/conditions/``, documented in ``docs/simulation.md``) adds to a simulated
session any of:

``[cloud]``        a transmission field drifting across the sky (haze, banks, overcast spells)
``[moon]``         the Moon at its true place: scattered light and the lit disc
``[twilight]``     sky brightness from the Sun's elevation
``[seeing]``       per-star, per-frame displacements, AR(1) in time
``[hot_pixels]``   a fixed hot-pixel pattern per sensor
``[cosmic_rays]``  random hits per frame
``[trails]``       satellite and aircraft trails
``[clock.NAME]``   a clock offset and jitter the FITS times do not show
``[flexure]``      rotation of a sensor's mount relative to the reference mount
``[distortion.NAME]`` lens distortion (the camera model's Weng terms)

:func:`load_conditions` reads a file (one-line ``ShipstarError`` on any problem),
:func:`apply_conditions` attaches it to a :class:`SessionSpec` (checking the sensor
names), and ``write_session`` then renders every frame with :func:`condition_frame` and
writes the conditions' truth (``conditions.csv``, ``conditions.json`` and a
``"conditions"`` block in every frame's truth JSON).  Without conditions nothing here
runs: the simulator's output is bit for bit what it was.
"""

from __future__ import annotations

import json
import math
import zlib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.units import ASEC2RAD, DEG2RAD, RAD2ASEC, RAD2DEG

__all__ = ["Conditions", "Cloud", "MoonLight", "Twilight", "Seeing", "HotPixels", "CosmicRays", "Trails",
           "Clock", "Flexure", "load_conditions", "parse_conditions", "apply_conditions", "condition_frame",
           "conditions_file", "CONDITION_NAMES", "CONDITIONS_CSV_COLUMNS", "write_session_with_conditions",
           "centroid_frame", "simulate_centroids_with_conditions", "flexure_rotvec_rad", "true_time_s"]

#: The example files shipped in ``shipstar/data/conditions`` (``--conditions NAME``).
CONDITION_NAMES = ("cloud", "moon", "twilight", "seeing", "hot_pixels", "trails", "clock", "flexure",
                   "distortion", "realistic")
#: Columns of ``conditions.csv`` (one row per frame and sensor).
CONDITIONS_CSV_COLUMNS = (
    "time_utc", "sensor", "frame", "true_time_utc", "t_s", "true_t_s", "clock_offset_s", "transmission",
    "transmission_stars_mean", "moon_sep_deg", "moon_el_deg", "moon_in_field", "sun_el_deg",
    "sky_e_per_px_per_s", "rot_bow_arcsec", "rot_up_arcsec", "rot_starboard_arcsec", "seeing_rms_arcsec",
    "n_stars", "n_trails", "n_cosmic_rays")
_MAX_CLOCK_S = 0.1
_SEEING_TAIL = 1e-6           # AR(1) weights below this are dropped (then renormalised)
_SEEING_MAX_TERMS = 200
_GRID_NODES = 33              # background field: nodes per image side (bilinear in between)
_MOON_SUBSAMPLES = 4          # per pixel axis, for the lit disc's edge


# --------------------------------------------------------------------------- the conditions

@dataclass(frozen=True)
class Cloud:
    """A cloud layer at ``height_km`` carried by the wind; extinction (mag) along a line of
    sight = ``(haze_mag + bank_mag * s(g)) / sin(el)`` plus ``overcast_mag`` during the
    spells, ``g`` a unit Gaussian random field of length scale ``scale_km`` (64 random
    Fourier modes) at the point where the line of sight crosses the layer, and
    ``s(g) = (1 + tanh((g - g0) / edge)) / 2`` with ``P(g > g0) = cover_fraction``.
    Transmission ``10**(-0.4 extinction)``.  The sky background under cloud is
    ``T + (1 - T) sky_factor`` times the clear one."""

    haze_mag: float = 0.0
    bank_mag: float = 1.5
    cover_fraction: float = 0.3
    scale_km: float = 2.0
    height_km: float = 2.0
    wind_m_per_s: float = 10.0
    wind_from_deg: float = 270.0
    edge: float = 0.3
    overcast_s: tuple = ()
    overcast_mag: float = 6.0
    overcast_ramp_s: float = 1.0
    sky_factor: float = 0.7


@dataclass(frozen=True)
class MoonLight:
    """The Moon at its true place: scattered light (K&S 1991, times ``scatter_factor``) and the lit disc."""

    scatter_factor: float = 1.0
    disc: bool = True


@dataclass(frozen=True)
class Twilight:
    """Sky brightness from the Sun's elevation (``_skylight.TWILIGHT_TABLE``, times ``factor``)."""

    factor: float = 1.0


@dataclass(frozen=True)
class Seeing:
    """Per-star displacement, ``sigma_arcsec`` per image axis (1 sigma), AR(1) over frames with
    ``rho = exp(-frame period / correlation_time_s)``."""

    sigma_arcsec: float = 1.5
    correlation_time_s: float = 0.1


@dataclass(frozen=True)
class HotPixels:
    fraction: float = 2e-4
    e_per_s: float = 5000.0


@dataclass(frozen=True)
class CosmicRays:
    per_frame: float = 5.0
    e: float = 3000.0


@dataclass(frozen=True)
class Trails:
    """Per frame, Poisson numbers of satellite trails (segments of ``length_px``) and aircraft
    trails (lines across the whole frame)."""

    satellites_per_frame: float = 0.2
    aircraft_per_frame: float = 0.05
    satellite_mag: tuple = (3.0, 6.0)
    aircraft_mag: tuple = (0.0, 3.0)
    length_px: tuple = (100.0, 600.0)


@dataclass(frozen=True)
class Clock:
    """True mid-exposure time = header time + ``offset_s`` + N(0, ``jitter_s``) per frame."""

    offset_s: float = 0.0
    jitter_s: float = 0.0


@dataclass(frozen=True)
class Flexure:
    """Rotation vector (arcsec, deck axes bow/up/starboard) of a sensor's mount relative to
    the reference mount: ``static + thermal sin(2 pi t / thermal_period + phase) + ramp t
    + wave sin(2 pi t / wave_period + wave_phase)``, t in s since the session start
    (thermal period in h, ramp per hour; wave period default: the ship's roll period)."""

    static_arcsec: tuple = (0.0, 0.0, 0.0)
    thermal_arcsec: tuple = (0.0, 0.0, 0.0)
    thermal_period_h: float = 24.0
    thermal_phase_deg: float = 0.0
    ramp_arcsec_per_h: tuple = (0.0, 0.0, 0.0)
    wave_arcsec: tuple = (0.0, 0.0, 0.0)
    wave_period_s: float | None = None
    wave_phase_deg: float = 0.0

    def rotvec_rad(self, t_s, wave_period_s: float) -> np.ndarray:
        """Rotation vectors (..., 3) in deck axes, radians."""
        t = np.asarray(t_s, float)[..., None]
        two_pi = 2.0 * math.pi
        v = (np.asarray(self.static_arcsec)
             + np.asarray(self.thermal_arcsec) * np.sin(two_pi * t / (3600.0 * self.thermal_period_h)
                                                        + self.thermal_phase_deg * DEG2RAD)
             + np.asarray(self.ramp_arcsec_per_h) * t / 3600.0
             + np.asarray(self.wave_arcsec) * np.sin(two_pi * t / wave_period_s + self.wave_phase_deg * DEG2RAD))
        return v * ASEC2RAD


@dataclass(frozen=True, eq=False)
class Conditions:
    """Everything a conditions file says (None: that condition is absent)."""

    source: str = ""
    text: str = ""
    seed: int = 0
    start_utc: str | None = None
    cloud: Cloud | None = None
    moon: MoonLight | None = None
    twilight: Twilight | None = None
    seeing: Seeing | None = None
    hot_pixels: HotPixels | None = None
    cosmic_rays: CosmicRays | None = None
    trails: Trails | None = None
    clock: dict = field(default_factory=dict)
    flexure: dict = field(default_factory=dict)
    flexure_reference: str | None = None
    distortion: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        """The parameters, defaults resolved, as written to ``conditions.json``."""
        def plain(obj):
            if obj is None:
                return None
            return {f.name: (list(getattr(obj, f.name)) if isinstance(getattr(obj, f.name), tuple)
                             else getattr(obj, f.name)) for f in fields(obj)}

        return {"source": self.source, "seed": self.seed, "start_utc": self.start_utc,
                "cloud": plain(self.cloud), "moon": plain(self.moon), "twilight": plain(self.twilight),
                "seeing": plain(self.seeing), "hot_pixels": plain(self.hot_pixels),
                "cosmic_rays": plain(self.cosmic_rays), "trails": plain(self.trails),
                "clock": {k: plain(v) for k, v in self.clock.items()},
                "flexure": ({"reference": self.flexure_reference, **{k: plain(v) for k, v in self.flexure.items()}}
                            if self.flexure else {}),
                "distortion": {k: v.as_dict() for k, v in self.distortion.items()}}


# --------------------------------------------------------------------------- reading

_REQUIRED = object()
_FORMAT_VERSION = 1


class _Table:
    """Typed access to one TOML table, one-line errors naming file, table and key; :meth:`finish`
    refuses keys nobody asked for.  (``shipstar.config._toml._Table``'s rules; the simulator
    sits below ``config`` in the layering, so it has its own.)"""

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

    def number(self, key: str, default=_REQUIRED, *, lo=-math.inf, hi=math.inf) -> float:
        value, given = self._get(key, default)
        if not given:
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ShipstarError(f"{self.where}: {key} must be a finite number, got {value!r}")
        if value < lo or value > hi:
            rng = f">= {lo:g}" if hi == math.inf else f"within [{lo:g}, {hi:g}]"
            raise ShipstarError(f"{self.where}: {key} must be {rng}, got {value!r}")
        return float(value)

    def integer(self, key: str, default=_REQUIRED, *, lo=0, hi=2**63 - 1) -> int:
        value, given = self._get(key, default)
        if not given:
            return value
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise ShipstarError(f"{self.where}: {key} must be an integer within [{lo}, {hi}], got {value!r}")
        return int(value)

    def text(self, key: str, default=_REQUIRED) -> str:
        value, given = self._get(key, default)
        if given and not isinstance(value, str):
            raise ShipstarError(f"{self.where}: {key} must be a string, got {value!r}")
        return value

    def table(self, key: str) -> "_Table | None":
        value, given = self._get(key, None)
        return _Table(value, f"{self.where} [{key}]") if given else None

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise ShipstarError(f"{self.where}: unknown key {unknown[0]!r}")

def _vector(t, key: str, default, n: int = 3, lo=-math.inf, hi=math.inf) -> tuple:
    value, given = t._get(key, default)
    if not given:
        return tuple(value)
    if (not isinstance(value, list) or len(value) != n
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        raise ShipstarError(f"{t.where}: {key} must be a list of {n} finite numbers, got {value!r}")
    if not all(lo <= v <= hi for v in value):
        raise ShipstarError(f"{t.where}: {key} values must be within [{lo:g}, {hi:g}], got {value!r}")
    return tuple(float(v) for v in value)


def _range(t, key: str, default, lo, hi) -> tuple:
    a, b = _vector(t, key, default, 2, lo, hi)
    if a > b:
        raise ShipstarError(f"{t.where}: {key} must be [min, max] with min <= max, got {[a, b]!r}")
    return a, b


def _flag(t, key: str, default: bool) -> bool:
    value, given = t._get(key, default)
    if given and not isinstance(value, bool):
        raise ShipstarError(f"{t.where}: {key} must be true or false, got {value!r}")
    return bool(value)


def _cloud(t) -> Cloud:
    spells, given = t._get("overcast_s", [])
    if given and not (isinstance(spells, list) and all(
            isinstance(s, list) and len(s) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                        and math.isfinite(v) for v in s) and s[0] < s[1]
            for s in spells)):
        raise ShipstarError(f"{t.where}: overcast_s must be a list of [start_s, end_s] pairs with start < end, "
                            f"got {spells!r}")
    c = Cloud(haze_mag=t.number("haze_mag", 0.0, lo=0.0, hi=10.0), bank_mag=t.number("bank_mag", 1.5, lo=0.0, hi=10.0),
              cover_fraction=t.number("cover_fraction", 0.3, lo=0.0, hi=1.0),
              scale_km=t.number("scale_km", 2.0, lo=0.01, hi=1000.0),
              height_km=t.number("height_km", 2.0, lo=0.1, hi=15.0),
              wind_m_per_s=t.number("wind_m_per_s", 10.0, lo=0.0, hi=100.0),
              wind_from_deg=t.number("wind_from_deg", 270.0, lo=0.0, hi=360.0),
              edge=t.number("edge", 0.3, lo=0.01, hi=5.0),
              overcast_s=tuple((float(a), float(b)) for a, b in spells),
              overcast_mag=t.number("overcast_mag", 6.0, lo=0.0, hi=20.0),
              overcast_ramp_s=t.number("overcast_ramp_s", 1.0, lo=0.0, hi=3600.0),
              sky_factor=t.number("sky_factor", 0.7, lo=0.0, hi=100.0))
    t.finish()
    return c


def _per_sensor(t, parse) -> dict:
    out = {}
    for name in [key for key in t.data if key not in t.used]:
        sub = t.table(name)
        if sub is None:
            continue
        out[name] = parse(sub)
    return out


def _clock(t) -> Clock:
    c = Clock(offset_s=t.number("offset_s", 0.0, lo=-_MAX_CLOCK_S, hi=_MAX_CLOCK_S),
              jitter_s=t.number("jitter_s", 0.0, lo=0.0, hi=0.01))
    t.finish()
    return c


def _flexure(t) -> Flexure:
    big = dict(lo=-3600.0, hi=3600.0)
    f = Flexure(static_arcsec=_vector(t, "static_arcsec", (0.0,) * 3, **big),
                thermal_arcsec=_vector(t, "thermal_arcsec", (0.0,) * 3, **big),
                thermal_period_h=t.number("thermal_period_h", 24.0, lo=0.01, hi=1e4),
                thermal_phase_deg=t.number("thermal_phase_deg", 0.0, lo=-360.0, hi=360.0),
                ramp_arcsec_per_h=_vector(t, "ramp_arcsec_per_h", (0.0,) * 3, **big),
                wave_arcsec=_vector(t, "wave_arcsec", (0.0,) * 3, **big),
                wave_period_s=t.number("wave_period_s", None, lo=0.1, hi=3600.0),
                wave_phase_deg=t.number("wave_phase_deg", 0.0, lo=-360.0, hi=360.0))
    t.finish()
    return f


def _distortion(t):
    from shipstar.camera._distortion import Distortion

    names = [f.name for f in fields(Distortion)]
    d = Distortion(**{n: t.number(n, 0.0, lo=-1.0, hi=1.0) for n in names})
    t.finish()
    return d


def _simple(t, cls, spec: dict):
    if t is None:
        return None
    values = {}
    for key, (kind, default, lo, hi) in spec.items():
        if kind == "number":
            values[key] = t.number(key, default, lo=lo, hi=hi)
        elif kind == "flag":
            values[key] = _flag(t, key, default)
        else:
            values[key] = _range(t, key, default, lo, hi)
    t.finish()
    return cls(**values)


def parse_conditions(text: str, source: str = "<conditions>") -> Conditions:
    """Conditions from TOML text; ``ShipstarError`` (one line, naming file, table and key) on any problem."""
    import tomllib

    from shipstar.sky.time import utc_jd_from_iso

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ShipstarError(f"{source}: not valid TOML: {' '.join(str(exc).split())}") from None
    t = _Table(data, source)
    if t.text("format") != "shipstar-conditions":
        raise ShipstarError(f"{source}: format must be 'shipstar-conditions', got {data.get('format')!r}")
    if t.integer("format_version") != _FORMAT_VERSION:
        raise ShipstarError(f"{source}: format_version {data.get('format_version')} is not supported "
                            f"(expected {_FORMAT_VERSION})")
    seed = t.integer("seed", 0)
    start_utc = None
    session = t.table("session")
    if session is not None:
        start_utc = session.text("start_utc", None)
        if start_utc is not None:
            try:
                utc_jd_from_iso(start_utc)
            except ShipstarError as exc:
                raise ShipstarError(f"{session.where}: start_utc: {exc}") from None
        session.finish()
    flex_t = t.table("flexure")
    flexure, reference = {}, None
    if flex_t is not None:
        reference = flex_t.text("reference", None)
        flexure = _per_sensor(flex_t, _flexure)
        flex_t.finish()
        if not flexure:
            raise ShipstarError(f"{flex_t.where}: give a [flexure.NAME] table per flexing sensor")
        if reference in flexure:
            raise ShipstarError(f"{flex_t.where}: the reference sensor {reference} cannot flex relative to itself")
    clock_t, dist_t = t.table("clock"), t.table("distortion")
    cond = Conditions(
        source=source, text=text, seed=seed, start_utc=start_utc,
        cloud=None if (c := t.table("cloud")) is None else _cloud(c),
        moon=_simple(t.table("moon"), MoonLight, {"scatter_factor": ("number", 1.0, 0.0, 100.0),
                                                  "disc": ("flag", True, None, None)}),
        twilight=_simple(t.table("twilight"), Twilight, {"factor": ("number", 1.0, 0.0, 100.0)}),
        seeing=_simple(t.table("seeing"), Seeing, {"sigma_arcsec": ("number", 1.5, 0.0, 60.0),
                                                   "correlation_time_s": ("number", 0.1, 1e-4, 3600.0)}),
        hot_pixels=_simple(t.table("hot_pixels"), HotPixels, {"fraction": ("number", 2e-4, 0.0, 0.01),
                                                              "e_per_s": ("number", 5000.0, 0.0, 1e7)}),
        cosmic_rays=_simple(t.table("cosmic_rays"), CosmicRays, {"per_frame": ("number", 5.0, 0.0, 1000.0),
                                                                 "e": ("number", 3000.0, 0.0, 1e6)}),
        trails=_simple(t.table("trails"), Trails, {
            "satellites_per_frame": ("number", 0.2, 0.0, 100.0), "aircraft_per_frame": ("number", 0.05, 0.0, 100.0),
            "satellite_mag": ("range", (3.0, 6.0), -5.0, 15.0), "aircraft_mag": ("range", (0.0, 3.0), -5.0, 15.0),
            "length_px": ("range", (100.0, 600.0), 1.0, 1e4)}),
        clock={} if clock_t is None else _per_sensor(clock_t, _clock),
        flexure=flexure, flexure_reference=reference,
        distortion={} if dist_t is None else _per_sensor(dist_t, _distortion))
    if clock_t is not None:
        clock_t.finish()
    if dist_t is not None:
        dist_t.finish()
    t.finish()
    return cond


def conditions_file(name_or_path) -> Path:
    """A conditions file: a path, or the name of a shipped example (``realistic``, ``cloud``, ...)."""
    p = Path(str(name_or_path)).expanduser()
    if p.suffix.lower() != ".toml" and str(name_or_path) in CONDITION_NAMES:
        from importlib.resources import files

        return Path(str(files("shipstar") / "data" / "conditions" / f"{name_or_path}.toml"))
    return p


def load_conditions(name_or_path) -> Conditions:
    """Read a conditions file (a path or a shipped example's name); one-line ``ShipstarError`` on any problem."""
    path = conditions_file(name_or_path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ShipstarError(f"conditions file {path} does not exist (or give one of {', '.join(CONDITION_NAMES)})") \
            from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ShipstarError(f"cannot read conditions file {path}: {exc}") from None
    return parse_conditions(text, str(path))


def apply_conditions(spec, cond: Conditions):
    """``spec`` with the conditions attached (and its start time replaced if the file gives one).

    Checks that every sensor named in the file is in the session and that the flexure
    reference is one of its sensors (default: the first)."""
    if not isinstance(cond, Conditions):
        raise ShipstarError(f"conditions must be a Conditions, got {type(cond).__name__}")
    names = [s.name for s in spec.sensors]
    for what, table in (("clock", cond.clock), ("flexure", cond.flexure), ("distortion", cond.distortion)):
        bad = [k for k in table if k not in names]
        if bad:
            raise ShipstarError(f"{cond.source}: [{what}.{bad[0]}] names no sensor of the session "
                                f"(have {', '.join(names)})")
    if cond.flexure:
        ref = cond.flexure_reference or names[0]
        if ref not in names:
            raise ShipstarError(f"{cond.source}: [flexure] reference {ref!r} is not a sensor of the session "
                                f"(have {', '.join(names)})")
        if ref in cond.flexure:
            raise ShipstarError(f"{cond.source}: [flexure.{ref}]: {ref} is the reference sensor (it does not "
                                "flex relative to itself); set [flexure] reference to another sensor")
        cond = replace(cond, flexure_reference=ref)
    changes = {"conditions": cond}
    if cond.start_utc is not None:
        changes["start_utc"] = cond.start_utc
    return spec.replace(**changes)


# --------------------------------------------------------------------------- the models

def _sensor_id(name: str) -> int:
    return zlib.crc32(name.encode("utf-8"))


def _rng(spec, cond, *keys) -> np.random.Generator:
    return np.random.default_rng([int(spec.seed), int(cond.seed), *(int(k) for k in keys)])


def _rotation(rotvec) -> np.ndarray:
    """Active rotation matrices (..., 3, 3) of rotation vectors (..., 3) (Rodrigues)."""
    from scipy.spatial.transform import Rotation

    v = np.asarray(rotvec, float)
    return Rotation.from_rotvec(v.reshape(-1, 3)).as_matrix().reshape(v.shape[:-1] + (3, 3))


def flexure_rotvec_rad(spec, sensor_name: str, t_s) -> np.ndarray:
    """The flexure rotation vector(s) (deck axes, rad) of a sensor at session times ``t_s``; zeros if none."""
    cond = spec.conditions
    f = None if cond is None else cond.flexure.get(sensor_name)
    if f is None:
        return np.zeros(np.shape(t_s) + (3,))
    period = f.wave_period_s if f.wave_period_s is not None else spec.motion.roll_period_s
    return f.rotvec_rad(t_s, period)


def true_time_s(spec, sensor_name: str, k: int, t_header_s: float) -> float:
    """True mid-exposure time (s since start) of frame ``k`` whose headers say ``t_header_s``."""
    cond = spec.conditions
    c = None if cond is None else cond.clock.get(sensor_name)
    if c is None:
        return float(t_header_s)
    jitter = c.jitter_s * _rng(spec, cond, 3, _sensor_id(sensor_name), k).standard_normal() if c.jitter_s else 0.0
    return float(t_header_s) + c.offset_s + jitter


class _CloudField:
    """The cloud transmission as a function of horizontal direction and time."""

    _MODES = 64

    def __init__(self, spec, cond: Conditions):
        from scipy.special import ndtri

        c = cond.cloud
        self.c = c
        rng = _rng(spec, cond, 1)
        k_mag = rng.rayleigh(1.0, self._MODES) * (2.0 * math.pi / c.scale_km) / math.sqrt(math.pi / 2.0)
        ang = rng.uniform(0.0, 2.0 * math.pi, self._MODES)
        self.k = np.stack([k_mag * np.cos(ang), k_mag * np.sin(ang)], axis=1)       # per km, (north, east)
        self.phase = rng.uniform(0.0, 2.0 * math.pi, self._MODES)
        self.g0 = float(ndtri(1.0 - c.cover_fraction)) if 0.0 < c.cover_fraction < 1.0 else \
            (-np.inf if c.cover_fraction >= 1.0 else np.inf)
        to = (c.wind_from_deg + 180.0) * DEG2RAD
        self.wind_km_per_s = c.wind_m_per_s / 1000.0 * np.array([math.cos(to), math.sin(to)])

    def extinction_mag(self, v_hor, t_s: float) -> np.ndarray:
        c = self.c
        v = np.asarray(v_hor, float)
        v = v / np.linalg.norm(v, axis=-1, keepdims=True)
        sin_el = np.clip(v[..., 1], math.sin(5.0 * DEG2RAD), 1.0)
        horiz = np.stack([v[..., 0], v[..., 2]], axis=-1) / sin_el[..., None]       # north, east per km of height
        r = c.height_km * horiz - self.wind_km_per_s * t_s
        g = math.sqrt(2.0 / self._MODES) * np.cos(r @ self.k.T + self.phase).sum(axis=-1)
        if np.isinf(self.g0):
            bank = np.full(g.shape, 0.0 if self.g0 > 0 else 1.0)
        else:
            bank = 0.5 * (1.0 + np.tanh((g - self.g0) / c.edge))
        spell = 0.0
        for a, b in c.overcast_s:
            ramp = max(c.overcast_ramp_s, 1e-9)
            spell = max(spell, float(np.clip(min(t_s - a, b - t_s) / ramp + 0.5, 0.0, 1.0)))
        return (c.haze_mag + c.bank_mag * bank) / sin_el + c.overcast_mag * spell

    def transmission(self, v_hor, t_s: float) -> np.ndarray:
        return 10.0 ** (-0.4 * self.extinction_mag(v_hor, t_s))


class _State:
    """Per-session caches: the cloud field, seeing innovations, hot-pixel patterns."""

    def __init__(self, spec):
        cond = spec.conditions
        self.cloud = _CloudField(spec, cond) if cond.cloud is not None else None
        self.eps: dict = {}
        self.hot: dict = {}


def _seeing_px(spec, state, sensor_name: str, k: int, hip, camera) -> np.ndarray:
    """Seeing displacements (N, 2) px of the stars ``hip`` in frame ``k``: stationary AR(1),
    ``sigma`` per axis, ``rho = exp(-period / correlation time)`` (weights truncated at 1e-6)."""
    cond = spec.conditions
    s = cond.seeing
    if s is None or s.sigma_arcsec == 0.0 or not len(hip):
        return np.zeros((len(hip), 2))
    rho = math.exp(-1.0 / (spec.frame_rate_hz * s.correlation_time_s))
    n = 1 if rho < _SEEING_TAIL else min(_SEEING_MAX_TERMS, int(math.ceil(math.log(_SEEING_TAIL) / math.log(rho))))
    w = rho ** np.arange(n)
    w *= s.sigma_arcsec / math.sqrt(float(w @ w))
    sid = _sensor_id(sensor_name)
    out = np.zeros((len(hip), 2))
    for i, h in enumerate(np.asarray(hip, np.int64)):
        for j in range(n):
            key = (sid, int(h), k - j)
            e = state.eps.get(key)
            if e is None:
                e = _rng(spec, cond, 11, sid, int(h), k - j + 1_000_000).standard_normal(2)
                state.eps[key] = e
            out[i] += w[j] * e
    if len(state.eps) > 200_000:
        state.eps = {key: v for key, v in state.eps.items() if key[2] > k - n}
    return out / camera.pixel_scale_arcsec


def _hot_pixels(spec, state, sensor_name: str, camera):
    """(flat indices, e/s) of a sensor's fixed hot pixels under the conditions (else the default pattern)."""
    from shipstar.simulate._frame import HOT_PIXEL_FRACTION, hot_pixel_seed
    from shipstar.simulate._render import _Detector, _hot_pixel_rate

    hp = spec.conditions.hot_pixels
    key = sensor_name
    if key not in state.hot:
        det = _Detector.from_camera(camera)
        if hp is None:
            state.hot[key] = _hot_pixel_rate(det, HOT_PIXEL_FRACTION, 2000.0, hot_pixel_seed(camera))
        else:
            seed = (hot_pixel_seed(camera) ^ (int(spec.conditions.seed) * 2654435761)) & 0xFFFFFFFF
            state.hot[key] = _hot_pixel_rate(det, hp.fraction, hp.e_per_s, seed)
    return state.hot[key]


def _trails(cond, camera, rng):
    """Random satellite and aircraft trails: list of (kind, (2, 2) xy_px, signal_e)."""
    tr = cond.trails
    if tr is None:
        return []
    out = []
    size = np.array([camera.width_px, camera.height_px], float)
    diag = float(np.hypot(*size))
    for kind, rate, mag in (("satellite", tr.satellites_per_frame, tr.satellite_mag),
                            ("aircraft", tr.aircraft_per_frame, tr.aircraft_mag)):
        for _ in range(int(rng.poisson(rate))):
            mid = rng.uniform(0.0, 1.0, 2) * size - 0.5
            ang = rng.uniform(0.0, math.pi)
            half = 0.5 * (rng.uniform(*tr.length_px) if kind == "satellite" else 2.0 * diag)
            step = np.array([math.cos(ang), math.sin(ang)]) * half
            e = float(camera.star_e_per_s(rng.uniform(*mag))) * camera.exposure_s
            out.append((kind, np.stack([mid - step, mid + step]), e))
    return out


def _cosmic_rays(cond, shape_hw, rng):
    """Hits: (first-pixel xy (n, 2), flat indices, electrons)."""
    cr = cond.cosmic_rays
    if cr is None:
        return np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0)
    n = int(rng.poisson(cr.per_frame))
    height, width = shape_hw
    length = rng.integers(1, 4, size=n)
    direction = np.array([(1, 0), (0, 1), (1, 1), (1, -1)])[rng.integers(0, 4, size=n)]
    x0, y0 = rng.integers(0, width, size=n), rng.integers(0, height, size=n)
    charge = cr.e * rng.lognormal(0.0, 0.5, size=n)
    step = np.arange(3)
    x = x0[:, None] + step * direction[:, 0:1]
    y = y0[:, None] + step * direction[:, 1:2]
    on = (step < length[:, None]) & (x >= 0) & (x < width) & (y >= 0) & (y < height)
    share = np.broadcast_to((charge / length)[:, None], on.shape)
    return np.stack([x0, y0], axis=1).astype(float), (y * width + x)[on], share[on]


def _moon_disc_fraction(camera, C_hor_from_sensor, places, moon_obs_hor):
    """Lit fraction of each pixel covered by the Moon's disc: (flat indices, fractions), centre xy, radius px."""
    m = C_hor_from_sensor.T @ moon_obs_hor
    if m[0] <= 0.0:
        return None
    centre = camera.project(m)
    r_px = places.moon_radius_rad * RAD2ASEC / camera.pixel_scale_arcsec
    lo = np.floor(centre - r_px - 2).astype(int)
    hi = np.ceil(centre + r_px + 2).astype(int)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [camera.width_px - 1, camera.height_px - 1])
    if np.any(hi < lo):
        return np.zeros(0, np.int64), np.zeros(0), centre, r_px
    ns = _MOON_SUBSAMPLES
    sub = (np.arange(ns) + 0.5) / ns - 0.5
    xs = (np.arange(lo[0], hi[0] + 1)[:, None] + sub).ravel()
    ys = (np.arange(lo[1], hi[1] + 1)[:, None] + sub).ravel()
    X, Y = np.meshgrid(xs, ys)
    u = camera.unproject(np.stack([X, Y], axis=-1))
    tangent = u - (u @ m)[..., None] * m
    q = tangent / math.sin(places.moon_radius_rad)
    q2 = np.einsum("...i,...i->...", q, q)
    inside = q2 <= 1.0
    normal = q + np.sqrt(np.clip(1.0 - q2, 0.0, 1.0))[..., None] * (-m)
    s = C_hor_from_sensor.T @ places.sun_from_moon_hor
    lit = inside & (normal @ s > 0.0)
    frac = lit.reshape(len(ys) // ns, ns, len(xs) // ns, ns).mean(axis=(1, 3))
    rows, cols = np.nonzero(frac)
    flat = (rows + lo[1]) * camera.width_px + (cols + lo[0])
    return flat, frac[rows, cols], centre, r_px


# --------------------------------------------------------------------------- one frame

def _linear_weights(n_px: int, nodes: int) -> np.ndarray:
    """(n_px, nodes) weights of linear interpolation from nodes at pixel edges -0.5 .. n_px - 0.5
    to pixel centres (a bilinear field is ``A @ node_values @ B.T``)."""
    pos = (np.arange(n_px) + 0.5) / n_px * (nodes - 1)
    lo = np.minimum(np.floor(pos).astype(int), nodes - 2)
    frac = pos - lo
    w = np.zeros((n_px, nodes))
    w[np.arange(n_px), lo] = 1.0 - frac
    w[np.arange(n_px), lo + 1] += frac
    return w


def _background(spec, state, camera, C_hs, t_true, places, weather):
    """Expected sky+dark electrons per pixel (H, W), plus facts for the truth."""
    from shipstar.simulate._skylight import flux_ratio, moon_scatter_mag, observed, twilight_mag

    cond = spec.conditions
    H, W = int(camera.height_px), int(camera.width_px)
    nodes = _GRID_NODES
    gx, gy = np.linspace(-0.5, W - 0.5, nodes), np.linspace(-0.5, H - 0.5, nodes)
    X, Y = np.meshgrid(gx, gy)
    u = camera.unproject(np.stack([X, Y], axis=-1))
    v = u @ C_hs.T
    ratio = np.ones(X.shape)                                  # sky relative to the dark sky
    facts = {}
    if cond.moon is not None and places is not None:
        ratio += cond.moon.scatter_factor * flux_ratio(moon_scatter_mag(places, v))
    if cond.twilight is not None and places is not None:
        ratio += cond.twilight.factor * max(float(flux_ratio(twilight_mag(places.sun_el_rad))) - 1.0, 0.0)
    if state.cloud is not None:
        T = state.cloud.transmission(v, t_true)
        ratio *= T + (1.0 - T) * cond.cloud.sky_factor
    sky = camera.sky_e_per_px_per_s * ratio
    facts["sky_e_per_px_per_s"] = float(camera.sky_e_per_px_per_s * ratio[nodes // 2, nodes // 2])
    exposure = camera.exposure_s
    if np.all(sky == sky.flat[0]):
        bg = np.full((H, W), (sky.flat[0] + camera.dark_e_per_s) * exposure)
    else:
        bg = (_linear_weights(H, nodes) @ sky @ _linear_weights(W, nodes).T + camera.dark_e_per_s) * exposure
    facts["moon_in_field"] = False
    if cond.moon is not None and places is not None and cond.moon.disc:
        moon_obs = observed(places.moon_hor, weather, spec.refraction_model)
        disc = _moon_disc_fraction(camera, C_hs, places, moon_obs)
        if disc is not None:
            flat, frac, centre, r_px = disc
            facts["moon_xy_px"] = centre.tolist()
            facts["moon_radius_px"] = float(r_px)
            if len(flat):
                from shipstar.simulate._skylight import moon_disc_mag

                T_moon = 1.0 if state.cloud is None else float(state.cloud.transmission(moon_obs, t_true))
                rate = camera.sky_e_per_px_per_s * float(flux_ratio(moon_disc_mag(places)))
                bg.ravel()[flat] += rate * T_moon * frac * exposure
                facts["moon_in_field"] = True
                facts["moon_lit_pixels"] = int(np.count_nonzero(frac >= 0.5))
    return bg, facts


def _noisy_frame(camera, bg, xy, signal, smear, hot, rays, rng) -> np.ndarray:
    """Every pixel through the noise chain: Poisson of the expected charge, cosmic rays,
    full well, read noise, ADC (as ``_render.render_frame``, but any background image)."""
    from shipstar.simulate._render import _check_sigma, _Detector, _electrons_to_adu, _smear_steps, _source_entries

    det = _Detector.from_camera(camera)
    shape = bg.shape
    sigma = _check_sigma(det.psf_sigma_px)
    smear, n_sub = _smear_steps(xy, smear, sigma)
    flat, value = _source_entries(shape, xy, signal, smear, n_sub, sigma)
    mean = bg.ravel() + np.bincount(flat, weights=value, minlength=bg.size)
    hot_idx, hot_rate = hot
    mean[hot_idx] += hot_rate * det.exposure_s
    electrons = rng.poisson(mean).astype(float)
    np.add.at(electrons, rays[0], rays[1])
    return _electrons_to_adu(electrons, det, rng).reshape(shape)


def condition_frame(spec, state, s, k: int, t_header: float):
    """One frame of sensor ``s`` under the session's conditions: (SimulatedFrame, truth block)."""
    import erfa

    from shipstar.frames import installation_angles_from_C_deck_from_sensor
    from shipstar.simulate._frame import ShipPose, SimulatedFrame
    from shipstar.simulate._motion import (
        earth_rate_hor_rad_per_s,
        exposure_offsets_s,
        exposure_path_px,
        fewest_pieces,
        streak_sources,
    )
    from shipstar.simulate._render import FalseObjects
    from shipstar.simulate._scene import simulate_stars_horizontal
    from shipstar.simulate._skylight import moon_sun, observed
    from shipstar.sky.apparent import frame_context
    from shipstar.sky.time import tt_jd_from_utc_jd

    cond = spec.conditions
    t = true_time_s(spec, s.name, k, t_header)
    camera = s.camera.replace(exposure_s=spec.exposure_of(s))
    if s.name in cond.distortion:
        camera = camera.replace(distortion=cond.distortion[s.name])
    C_ds0 = s.C_deck_from_sensor
    phi = flexure_rotvec_rad(spec, s.name, t)
    C_ds = _rotation(phi) @ C_ds0
    K, psi, theta = (float(a) for a in spec.motion.angles_rad(t))
    pose = ShipPose(K, psi, theta, *(float(a) for a in installation_angles_from_C_deck_from_sensor(C_ds)))
    omega = pose.omega_sensor_from_deck(spec.motion.omega_deck_rad_per_s(t))
    seed = int(np.random.SeedSequence([spec.seed, k, sum(map(ord, s.name))]).generate_state(1, np.uint64)[0]) >> 1
    jd1, jd2 = spec.utc_jd(t)
    hjd1, hjd2 = spec.utc_jd(t_header)
    # the camera's passband sets the refraction wavelength, as in _session._sensor_frame
    context, weather = frame_context(jd1, jd2, spec.site(t)), replace(spec.weather(t), wavelength_um=camera.wavelength_um)
    C_hs = pose.C_hor_from_sensor
    stars = simulate_stars_horizontal(camera, C_hs, context, weather, spec.refraction_model,
                                      mag_limit=spec.mag_limit, omega_sensor_rad_per_s=omega)
    tau = exposure_offsets_s(camera.exposure_s)
    C_hs_tau = spec.motion.C_hor_from_deck(t + tau) @ _rotation(flexure_rotvec_rad(spec, s.name, t + tau)) @ C_ds0
    lat = spec.site(t).astronomical_lat_rad
    path = exposure_path_px(camera, stars.v_ref, C_hs_tau, tau, earth_rate_hor_rad_per_s(lat))
    seeing_px = _seeing_px(spec, state, s.name, k, stars.hip, camera)
    T = np.ones(len(stars)) if state.cloud is None else state.cloud.transmission(stars.v_ref, t)
    rng_c = _rng(spec, cond, 5, _sensor_id(s.name), k)
    trails = _trails(cond, camera, rng_c)
    shape = (int(camera.height_px), int(camera.width_px))
    ray_xy, ray_idx, ray_e = _cosmic_rays(cond, shape, rng_c)
    xy, signal, smear = streak_sources(fewest_pieces(path + seeing_px[:, None, :]), stars.signal_e * T)
    if trails:
        txy = np.stack([tr[1] for tr in trails])
        xy = np.concatenate([xy, txy.mean(axis=1)])
        signal = np.concatenate([signal, [tr[2] for tr in trails]])
        smear = np.concatenate([smear, txy[:, 1] - txy[:, 0]])
    places = moon_sun(context) if (cond.moon is not None or cond.twilight is not None) else None
    bg, facts = _background(spec, state, camera, C_hs, t, places, weather)
    hot = _hot_pixels(spec, state, s.name, camera)
    image = _noisy_frame(camera, bg, xy, signal, smear, hot, (ray_idx, ray_e), np.random.default_rng(seed))
    clear = stars.signal_e
    stars = replace(stars, signal_e=clear * T, smear_px=path[:, -1] - path[:, 0])
    fo = FalseObjects(trail_xy_px=np.array([tr[1] for tr in trails]).reshape(-1, 2, 2),
                      trail_signal_e=np.array([tr[2] for tr in trails], float),
                      cosmic_ray_count=int(len(ray_xy)), cosmic_ray_e=cond.cosmic_rays.e if cond.cosmic_rays else 3000.0)
    frame = SimulatedFrame(
        image=image, stars=stars, camera=camera, utc_iso=spec.utc_iso(t_header), utc_jd1=hjd1, utc_jd2=hjd2,
        epoch_jyear=float(erfa.epj(*tt_jd_from_utc_jd(jd1, jd2))),
        C_icrs_from_sensor=np.asarray(context.C_hor_from_icrs_approx).T @ C_hs, C_hor_from_sensor=C_hs,
        context=context, weather=weather, refraction_model=spec.refraction_model, ship=pose,
        omega_sensor_rad_per_s=omega, false_objects=fo, seed=seed, mag_limit=float(spec.mag_limit),
        hot_pixel_fraction=float(cond.hot_pixels.fraction if cond.hot_pixels else 2e-5))
    seeing_arcsec = seeing_px * camera.pixel_scale_arcsec
    rms = float(np.sqrt(np.mean(seeing_arcsec ** 2))) if len(seeing_arcsec) else 0.0
    boresight = C_hs[:, 0]
    block = {
        "source": Path(cond.source).name if cond.source else "",
        "header_utc_mid_exposure": spec.utc_iso(t_header), "true_utc_mid_exposure": spec.utc_iso(t),
        "t_s": float(t_header), "true_t_s": float(t), "clock_offset_s": float(t - t_header),
        "rot_bow_arcsec": float(phi[0] * RAD2ASEC), "rot_up_arcsec": float(phi[1] * RAD2ASEC),
        "rot_starboard_arcsec": float(phi[2] * RAD2ASEC),
        "C_deck_from_sensor_nominal": C_ds0.tolist(),
        "transmission": 1.0 if state.cloud is None else float(state.cloud.transmission(boresight, t)),
        "transmission_stars_mean": float(np.mean(T)) if len(T) else float("nan"),
        "seeing_rms_arcsec": rms,
        "stars": {"hip": stars.hip.tolist(), "transmission": T.tolist(), "signal_clear_e": clear.tolist(),
                  "seeing_offset_arcsec": seeing_arcsec.tolist(), "seeing_offset_px": seeing_px.tolist()},
        "trails": [{"kind": kind, "xy_px": xy_.tolist(), "signal_e": e} for kind, xy_, e in trails],
        "cosmic_rays": {"count": int(len(ray_xy)), "xy_px": ray_xy.tolist()},
        "hot_pixels": {"count": int(len(hot[0]))},
        "distortion": camera.distortion.as_dict() if s.name in cond.distortion else None,
        **facts,
    }
    if places is not None:
        moon_obs = observed(places.moon_hor, weather, spec.refraction_model)
        az = lambda v: float(np.mod(math.atan2(v[2], v[0]), 2 * math.pi) * RAD2DEG)  # noqa: E731
        el = lambda v: float(math.asin(max(-1.0, min(1.0, v[1]))) * RAD2DEG)  # noqa: E731
        block["moon"] = {"az_deg": az(moon_obs), "el_deg": el(moon_obs), "apparent_az_deg": az(places.moon_hor),
                         "apparent_el_deg": el(places.moon_hor),
                         "sep_deg": float(math.acos(max(-1.0, min(1.0, float(moon_obs @ boresight)))) * RAD2DEG),
                         "illuminated_fraction": places.illuminated_fraction,
                         "phase_angle_deg": places.phase_angle_rad * RAD2DEG,
                         "radius_arcsec": places.moon_radius_rad * RAD2ASEC}
        block["sun"] = {"az_deg": az(places.sun_hor), "el_deg": el(places.sun_hor)}
    return frame, block


# --------------------------------------------------------------------------- the session

def _write_frame_with(frame, block, path, sensor: str | None = None):
    """``write_frame`` with the conditions block added to the truth JSON."""
    from astropy.io import fits

    from shipstar.simulate._fits import _atomic_replace, fits_header_cards, truth_dict, truth_path_for

    fits_path, truth_path = Path(path), truth_path_for(path)
    hdu = fits.PrimaryHDU(np.asarray(frame.image, dtype=np.uint16))
    for key, value, comment in fits_header_cards(frame, sensor):
        hdu.header[key] = (value, comment)
    truth = truth_dict(frame, fits_path.name)
    truth["conditions"] = block
    text = json.dumps(truth, allow_nan=False, indent=1, default=float) + "\n"
    truth_path.unlink(missing_ok=True)
    _atomic_replace(fits_path, lambda tmp: hdu.writeto(tmp, overwrite=True, checksum=True))
    _atomic_replace(truth_path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    return fits_path, truth_path


def _csv_row(sensor: str, k: int, b: dict) -> list:
    moon = b.get("moon", {})
    cells = [b["header_utc_mid_exposure"], sensor, str(k), b["true_utc_mid_exposure"], f"{b['t_s']:.6f}",
             repr(b["true_t_s"]), repr(b["clock_offset_s"]), repr(b["transmission"]),
             repr(b["transmission_stars_mean"]), repr(moon.get("sep_deg", float("nan"))),
             repr(moon.get("el_deg", float("nan"))), str(int(b["moon_in_field"])),
             repr(b.get("sun", {}).get("el_deg", float("nan"))), repr(b["sky_e_per_px_per_s"]),
             repr(b["rot_bow_arcsec"]), repr(b["rot_up_arcsec"]), repr(b["rot_starboard_arcsec"]),
             repr(b["seeing_rms_arcsec"]), str(len(b["stars"]["hip"])), str(len(b["trails"])),
             str(b["cosmic_rays"]["count"])]
    return cells


def _json_safe(obj):
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


def write_session_with_conditions(spec, out_dir, *, progress=None, max_output_bytes=None) -> dict:
    """``write_session`` for a spec with conditions: the same files, every frame rendered by
    :func:`condition_frame`, plus ``conditions.toml`` (the file as given), ``conditions.json``
    (parameters with defaults, per-sensor hot pixels, reference sensor) and
    ``conditions.csv`` (:data:`CONDITIONS_CSV_COLUMNS`); ``session.toml`` last."""
    from shipstar.simulate._session import (
        _csv_text,
        _preflight,
        _toml_text,
        _track_rows,
        _truth_rows,
        _weather_rows,
        _write_text,
    )

    out = Path(out_dir)
    _preflight(spec, out, max_output_bytes)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ShipstarError(f"cannot create {out}: {exc.strerror or exc}") from None
    state = _State(spec)
    total = spec.n_frames() * len(spec.sensors)
    frames, rows, done = {}, [], 0
    for s in spec.sensors:
        (out / s.name).mkdir(exist_ok=True)
        frames[s.name] = []
        for k, t in enumerate(spec.times_s(s)):
            frame, block = condition_frame(spec, state, s, k, float(t))
            path, _ = _write_frame_with(frame, _json_safe(block), out / s.name / f"{s.name}_{k:05d}.fits",
                                        s.name)
            frames[s.name].append(path)
            rows.append(_csv_row(s.name, k, block))
            done += 1
            if progress is not None:
                progress(done, total)
    cond = spec.conditions
    files = {"truth": out / "truth.csv", "track": out / "track.csv", "weather": out / "weather.csv",
             "conditions": out / "conditions.csv", "conditions_json": out / "conditions.json",
             "conditions_toml": out / "conditions.toml", "session": out / "session.toml"}
    _write_text(files["truth"], _csv_text(["time_utc", "t_s", "heading_deg", "pitch_deg", "roll_deg"],
                                          _truth_rows(spec)))
    _write_text(files["track"], _csv_text(["time_utc", "lat_deg", "lon_deg", "height_m"], _track_rows(spec)))
    _write_text(files["weather"], _csv_text(["time_utc", "pressure_hpa", "temperature_c", "relative_humidity"],
                                            _weather_rows(spec)))
    _write_text(files["conditions"], _csv_text(list(CONDITIONS_CSV_COLUMNS), rows))
    hot = {}
    for s in spec.sensors:
        camera = s.camera.replace(exposure_s=spec.exposure_of(s))
        idx, rate = _hot_pixels(spec, state, s.name, camera)
        w = int(camera.width_px)
        hot[s.name] = {"xy_px": np.stack([idx % w, idx // w], axis=1).tolist(), "e_per_s": np.asarray(rate).tolist()}
    summary = {"schema": "shipstar.simulate.conditions/1", "session_start_utc": spec.start_utc,
               "parameters": cond.as_dict(), "hot_pixels": hot,
               "flexure_wave_period_s": {n: (f.wave_period_s or spec.motion.roll_period_s)
                                         for n, f in cond.flexure.items()}}
    _write_text(files["conditions_json"], json.dumps(_json_safe(summary), indent=1) + "\n")
    _write_text(files["conditions_toml"], cond.text)
    _write_text(files["session"], _toml_text(spec))
    return {"frames": frames, **files}


# --------------------------------------------------------------------------- centroid level

def centroid_frame(spec, state, s, k: int, t_header: float, rng):
    """One centroid-level frame under the conditions (``_session.CentroidFrame``).

    The geometric conditions act as at image level: the sky and the ship at the true time
    (clock), the flexed mount, the lens distortion, and the seeing displacement (added to
    the measured ``xy_px`` with the Gaussian centroid noise; ``xy_true_px`` stays the
    geometric position).  Cloud removes the stars it dims below the session's magnitude
    limit (``mag - 2.5 log10(T) > mag_limit``).  Moon, twilight, hot pixels, cosmic rays
    and trails act on images only.  ``conditions`` holds the frame's true values (keys as
    in the image level's truth block)."""
    from shipstar.simulate._scene import simulate_stars_horizontal
    from shipstar.simulate._session import CentroidFrame
    from shipstar.sky.apparent import frame_context

    cond = spec.conditions
    t = true_time_s(spec, s.name, k, t_header)
    camera = s.camera if s.name not in cond.distortion else s.camera.replace(distortion=cond.distortion[s.name])
    phi = flexure_rotvec_rad(spec, s.name, t)
    C_hd = spec.motion.C_hor_from_deck(t)
    C_hs = C_hd @ _rotation(phi) @ s.C_deck_from_sensor
    jd1, jd2 = spec.utc_jd(t)
    ctx = frame_context(jd1, jd2, spec.site(t))
    stars = simulate_stars_horizontal(camera, C_hs, ctx, spec.weather(t), spec.refraction_model,
                                      mag_limit=spec.mag_limit, earth_rotation=False)
    T = np.ones(len(stars)) if state.cloud is None else state.cloud.transmission(stars.v_ref, t)
    with np.errstate(divide="ignore"):
        keep = stars.mag - 2.5 * np.log10(T) <= spec.mag_limit
    stars, T_kept = stars.subset(keep), T[keep]
    seeing_px = _seeing_px(spec, state, s.name, k, stars.hip, camera)
    noise = rng.normal(0.0, spec.centroid_sigma_px, stars.xy_px.shape) if spec.centroid_sigma_px else 0.0
    hjd1, hjd2 = spec.utc_jd(t_header)
    seeing_arcsec = seeing_px * camera.pixel_scale_arcsec
    block = {"header_utc_mid_exposure": spec.utc_iso(t_header), "true_utc_mid_exposure": spec.utc_iso(t),
             "t_s": float(t_header), "true_t_s": float(t), "clock_offset_s": float(t - t_header),
             "rot_bow_arcsec": float(phi[0] * RAD2ASEC), "rot_up_arcsec": float(phi[1] * RAD2ASEC),
             "rot_starboard_arcsec": float(phi[2] * RAD2ASEC),
             "transmission": 1.0 if state.cloud is None else float(state.cloud.transmission(C_hs[:, 0], t)),
             "n_clouded_out": int(np.count_nonzero(~keep)),
             "seeing_rms_arcsec": float(np.sqrt(np.mean(seeing_arcsec ** 2))) if len(stars) else 0.0,
             "stars": {"hip": stars.hip.tolist(), "transmission": T_kept.tolist(),
                       "seeing_offset_arcsec": seeing_arcsec.tolist()}}
    return CentroidFrame(s.name, k, float(t_header), hjd1, hjd2, stars.hip, stars.xy_px + seeing_px + noise,
                         stars.xy_px, C_hs, C_hd, conditions=block)


def simulate_centroids_with_conditions(spec) -> dict:
    """``simulate_centroids`` for a spec with conditions (same noise streams per sensor)."""
    state = _State(spec)
    out = {}
    for j, s in enumerate(spec.sensors):
        rng = np.random.default_rng([spec.seed, j])
        out[s.name] = [centroid_frame(spec, state, s, k, float(t), rng) for k, t in enumerate(spec.times_s(s))]
    return out
