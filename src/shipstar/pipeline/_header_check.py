"""Cross-checks of the frames' own FITS headers against what the user gave.

A frame's header may say where and with what it was taken (``SITELAT``/``SITELONG``,
``PRESSURE``/``TEMPERAT``, ``SENSOR``/``INSTRUME``, ``NAXIS1``/``NAXIS2``).  Every
command that reads frames compares those cards with the position, weather, sensor and
camera it was given; a contradiction beyond the tolerances below is refused in one line
naming the frame, the card, both values and the tolerance, unless the user says the
flags are right (``--trust-flags``): then the flags are used and the contradictions are
recorded in the outputs (:meth:`HeaderCheck.overrides`).  docs/file-formats.md, "Header
cross-checks", gives the reasons for each tolerance.

    check = HeaderCheck(names=("A1", "A1"), camera=camera, track=track, weather=weather,
                        position_flags=True, weather_flags=True, trust_flags=False,
                        given_name="--sensor A1 (camera A1)")
    check(info)            # each FitsFrameInfo; ShipstarError on a contradiction
    check.overrides()      # with trust_flags: [{"key", "n_frames", "first"}, ...]

Each name card is compared with what it names: ``SENSOR`` with the sensor's name and
``INSTRUME`` with the camera's (``names=(sensor, camera)``), so a frame of sensor A1
given as A1 but processed with camera A2's model (0.3 deg off), or A1's frames
calibrated as sensor A2, are refused whichever card matches the other name.  Commands
with only a camera (``names=(camera,)``: ``solve``, ``calibrate intrinsics``) compare
``SENSOR`` with the camera's name (simulated frames write the camera's name there when
the sensor has no other).  ``INSTRUME`` is FITS's instrument card, which capture
software often fills with the camera's make and model: it contradicts only when it
names another camera shipstar knows (a preset, or a camera of the run's other sensors:
``known_cameras``), not any text that is not the camera's name.

The image size is checked exactly and is never overridden: no camera model describes
frames of another size.  The exposure (``EXPTIME``) is not compared with the camera
file's ``exposure_s``: that value is the simulator's photometry parameter, the pipeline
takes each frame's exposure from the frame itself, and cameras with automatic exposure
or sessions simulated with ``[simulation] exposure_s`` differ from it legitimately.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from shipstar.errors import ShipstarError

__all__ = ["HeaderCheck", "Contradiction", "POSITION_TOLERANCE_DEG", "PRESSURE_TOLERANCE_HPA",
           "TEMPERATURE_TOLERANCE_C", "TRUST_HINT", "override_lines"]

#: Largest difference of the header's position from the one given, as an arc on the
#: ground (deg; 0.02 deg = 2.2 km): above a header rounded to the arcminute (0.008 deg per
#: coordinate), a camera's GPS against the ship's (tens of metres) and a ship at 30 knots
#: over a minute of time-stamp lag (0.9 km); far below a wrong site or a typed digit.
POSITION_TOLERANCE_DEG = 0.02
#: Pressure (hPa): two barometers on one ship differ by a few hPa (1 hPa per 8 m of
#: height, calibration); a sea-level-reduced or inHg value, or another place, differs more.
PRESSURE_TOLERANCE_HPA = 5.0
#: Temperature (C): a sensor's housing against the bridge's thermometer, sun and wind.
TEMPERATURE_TOLERANCE_C = 5.0
TRUST_HINT = "use --trust-flags to use the flags anyway"


def _g(x: float) -> str:
    return f"{x:.10g}"


@dataclass(frozen=True)
class Contradiction:
    """One header card that contradicts what was given: ``key`` (the card), ``text``
    (one line naming the frame, both values and the tolerance), ``overridable``."""

    key: str
    text: str
    overridable: bool = True

    def message(self) -> str:
        return f"{self.text}; {TRUST_HINT}" if self.overridable else self.text


class HeaderCheck:
    """The header cross-checks of one sensor's frames (module docstring).

    Parameters
    ----------
    names : sequence of str
        ``(sensor_name, camera_name)`` for a command with a sensor: a frame's ``SENSOR``
        card must be the sensor's name and its ``INSTRUME`` card the camera's (each
        compared when present); ``(camera_name,)`` for a command with only a camera:
        each card present must be the camera's name; empty: not checked.
    given_name : str
        How the user named them, for messages (e.g. ``"--camera A2"``).
    camera : Camera or None
        Its ``width_px``/``height_px`` are checked against the image size.
    track, weather : optional
        Objects with ``site(jd1, jd2)`` (lat_rad, lon_rad) and ``weather(jd1, jd2)``
        (pressure_hpa, temperature_c), e.g. :class:`~shipstar.pipeline.Track` and
        :class:`~shipstar.pipeline.WeatherTable`; a frame they do not cover is not
        compared (their own checks refuse it).
    position_flags, weather_flags : bool
        The track / weather came from ``--lat-deg/--lon-deg`` / ``--pressure-hpa/
        --temperature-c`` (messages name the flags; else the table's ``name``).
    trust_flags : bool
        Record contradictions instead of refusing them.
    sensor : str
        The sensor's name, recorded with each override (``""``: none).
    known_cameras : iterable of str
        Camera names besides the presets that an ``INSTRUME`` card contradicts with when it
        is not the camera's (the run's other sensors' cameras).
    """

    def __init__(self, *, names=(), given_name: str = "", camera=None, track=None, weather=None,
                 position_flags: bool = False, weather_flags: bool = False, trust_flags: bool = False,
                 sensor: str = "", known_cameras=()):
        from shipstar.camera import PRESETS

        self.sensor = sensor
        self.known_cameras = frozenset(PRESETS) | frozenset(n for n in known_cameras if n)
        names = tuple(names)
        if len(names) > 2:
            raise ValueError(f"names must be (sensor_name, camera_name) or (camera_name,), got {names!r}")
        #: what SENSOR must say ("": only a camera: SENSOR is compared with the camera's
        #: name) and what INSTRUME must say ("": names not checked)
        self.sensor_name = (names[0] or "") if len(names) == 2 else ""
        self.camera_name = (names[-1] or "") if names else ""
        self.given_name = given_name
        self.camera = camera
        self.track = track
        self.weather = weather
        self.position_flags = position_flags
        self.weather_flags = weather_flags
        self.trust_flags = bool(trust_flags)
        self._first: dict = {}
        self._count: dict = {}

    # ------------------------------------------------------------------ the checks

    def contradictions(self, info) -> list:
        """Every :class:`Contradiction` of one frame's header (a FitsFrameInfo)."""
        out = []
        name = info.name
        cam = self.camera
        if cam is not None and tuple(info.shape_hw) != (cam.height_px, cam.width_px):
            h, w = info.shape_hw
            out.append(Contradiction(
                "NAXIS1/NAXIS2", f"frame {name}: header NAXIS1 x NAXIS2 = {w} x {h} px but camera {cam.name!r} is "
                                 f"{cam.width_px} x {cam.height_px} px (must match; no camera model describes "
                                 "frames of another size)", overridable=False))
        if self._names_differ(info):
            out += self._names(info)
        jd = (info.utc_jd1, info.utc_jd2)
        if math.isfinite(jd[0]) and math.isfinite(jd[1]):
            out += self._position(info, jd)
            out += self._weather(info, jd)
        return out

    def _instrume_differs(self, info) -> bool:
        """An ``INSTRUME`` card naming another camera shipstar knows."""
        return bool(info.instrume and self.camera_name and info.instrume != self.camera_name
                    and info.instrume in self.known_cameras)

    def _names_differ(self, info) -> bool:
        """Whether a name card of the frame contradicts (cheap; :meth:`_names` words it)."""
        want = self.sensor_name or self.camera_name
        return bool((want and info.sensor and info.sensor != want) or self._instrume_differs(info))

    def _names(self, info) -> list:
        """SENSOR against the sensor's name (with only a camera, the camera's) and INSTRUME
        against the camera's; with only a camera, the first of them that contradicts."""
        name = info.name
        if not self.sensor_name:
            for key, said, differs in (("SENSOR", info.sensor, bool(info.sensor and info.sensor != self.camera_name)),
                                       ("INSTRUME", info.instrume, self._instrume_differs(info))):
                if self.camera_name and differs:
                    return [Contradiction(key, f"frame {name}: header {key} = {said!r} but {self.given_name} "
                                               "(names must match)")]
            return []
        out = []
        if info.sensor and info.sensor != self.sensor_name:
            out.append(Contradiction("SENSOR", f"frame {name}: header SENSOR = {info.sensor!r} but the sensor is "
                                               f"{self.sensor_name!r} ({self.given_name}; SENSOR must name the "
                                               "sensor)"))
        if self._instrume_differs(info):
            out.append(Contradiction("INSTRUME", f"frame {name}: header INSTRUME = {info.instrume!r} but the camera "
                                                 f"is {self.camera_name!r} ({self.given_name}; INSTRUME must name "
                                                 "the camera)"))
        return out

    def _position(self, info, jd) -> list:
        if self.track is None or (info.lat_deg is None and info.lon_deg is None):
            return []
        try:
            site = self.track.site(*jd)
        except ShipstarError:
            return []
        lat, lon = math.degrees(site.lat_rad), math.degrees(site.lon_rad)
        out = []
        tol = POSITION_TOLERANCE_DEG
        if info.lat_deg is not None and abs(info.lat_deg - lat) > tol:
            out.append(Contradiction("SITELAT", f"frame {info.name}: header SITELAT = {_g(info.lat_deg)} deg but "
                                                f"{self._given('--lat-deg', self.track, lat)} (tolerance {tol} deg)"))
        if info.lon_deg is not None:
            d_lon = math.remainder(info.lon_deg - lon, 360.0)
            tol_lon = tol / max(math.cos(site.lat_rad), 1e-3)            # the same distance on the ground
            if abs(d_lon) > tol_lon:
                out.append(Contradiction("SITELONG", f"frame {info.name}: header SITELONG = {_g(info.lon_deg)} deg "
                                                     f"but {self._given('--lon-deg', self.track, lon)} "
                                                     f"(tolerance {tol_lon:.3g} deg of longitude, {tol} deg on the "
                                                     "ground)"))
        return out

    def _weather(self, info, jd) -> list:
        if self.weather is None or (info.pressure_hpa is None and info.temperature_c is None):
            return []
        try:
            w = self.weather.weather(*jd)
        except ShipstarError:
            return []
        out = []
        if info.pressure_hpa is not None and abs(info.pressure_hpa - w.pressure_hpa) > PRESSURE_TOLERANCE_HPA:
            out.append(Contradiction("PRESSURE", f"frame {info.name}: header PRESSURE = {_g(info.pressure_hpa)} hPa "
                                                 f"but {self._given('--pressure-hpa', self.weather, w.pressure_hpa)} "
                                                 f"(tolerance {PRESSURE_TOLERANCE_HPA:g} hPa)"))
        if info.temperature_c is not None and abs(info.temperature_c - w.temperature_c) > TEMPERATURE_TOLERANCE_C:
            out.append(Contradiction("TEMPERAT", f"frame {info.name}: header TEMPERAT = {_g(info.temperature_c)} C "
                                                 f"but {self._given('--temperature-c', self.weather, w.temperature_c)} "
                                                 f"(tolerance {TEMPERATURE_TOLERANCE_C:g} C)"))
        return out

    def _given(self, flag: str, table, value: float) -> str:
        flags = self.position_flags if table is self.track else self.weather_flags
        if flags:
            return f"{flag} {_g(value)}"
        name = getattr(table, "name", None) or getattr(getattr(table, "track", None), "name", None) or "table"
        return f"the {name} gives {_g(round(value, 6))} at the frame's time"

    # ------------------------------------------------------------------ refusing / recording

    def __call__(self, info) -> list:
        """Check one frame: ShipstarError on the first contradiction (a non-overridable
        one even with ``trust_flags``); with ``trust_flags`` the others are recorded and
        returned."""
        found = self.contradictions(info)
        for c in found:
            if not c.overridable or not self.trust_flags:
                raise ShipstarError(c.message())
        for c in found:
            self._first.setdefault(c.key, c.text)
            self._count[c.key] = self._count.get(c.key, 0) + 1
        return found

    def check_many(self, infos) -> None:
        """:meth:`__call__` on every frame of ``infos`` (a sequence of FitsFrameInfo), in
        order, with the same errors and records; the position and weather are first
        compared for all frames at once (the tables interpolated as arrays), and only the
        frames that may contradict (within a margin far above rounding: 1e-7 deg, 0.006 hPa
        / C for the weather's rounding to 0.01) go through the one-frame checks, which
        decide and word the message.  A session's 1800 frames: 0.19 -> ~0.01 s."""
        import numpy as np

        n = len(infos)
        if n == 0:
            return
        cam = self.camera
        shape = None if cam is None else (cam.height_px, cam.width_px)
        flag = np.fromiter(((shape is not None and tuple(i.shape_hw) != shape) or self._names_differ(i)
                            for i in infos), bool, n)
        jd1 = np.fromiter((i.utc_jd1 for i in infos), float, n)
        jd2 = np.fromiter((i.utc_jd2 for i in infos), float, n)

        def column(key):
            return np.fromiter((math.nan if getattr(i, key) is None else getattr(i, key) for i in infos), float, n)

        if self.track is not None:
            lat_h_deg, lon_h_deg = column("lat_deg"), column("lon_deg")
            if np.isfinite(lat_h_deg).any() or np.isfinite(lon_h_deg).any():
                lat_rad, ok = self.track.interpolate_many(self.track.lat_rad, jd1, jd2)
                lon_rad, _ = self.track.interpolate_many(self.track.lon_rad, jd1, jd2)
                d_lat_deg = np.abs(lat_h_deg - np.degrees(lat_rad))
                d_lon_deg = np.abs(np.remainder(lon_h_deg - np.degrees(lon_rad) + 180.0, 360.0) - 180.0)
                tol_lon_deg = POSITION_TOLERANCE_DEG / np.maximum(np.cos(lat_rad), 1e-3)
                flag |= ok & ((d_lat_deg > POSITION_TOLERANCE_DEG - 1e-7)
                              | (d_lon_deg > tol_lon_deg * (1.0 - 1e-9) - 1e-7))
        if self.weather is not None:
            p_h_hpa, t_h_c = column("pressure_hpa"), column("temperature_c")
            if np.isfinite(p_h_hpa).any() or np.isfinite(t_h_c).any():
                p_hpa, ok = self.weather.interpolate_many(self.weather.pressure_hpa, jd1, jd2)
                t_c, _ = self.weather.interpolate_many(self.weather.temperature_c, jd1, jd2)
                flag |= ok & ((np.abs(p_h_hpa - p_hpa) > PRESSURE_TOLERANCE_HPA - 0.006)
                              | (np.abs(t_h_c - t_c) > TEMPERATURE_TOLERANCE_C - 0.006))
        for k in np.flatnonzero(flag):
            self(infos[k])

    def overrides(self) -> list:
        """The contradictions overridden by ``trust_flags``: ``[{"key", "n_frames",
        "first"}]`` (and ``"sensor"`` when named), one per header card, in the order first met."""
        who = {"sensor": self.sensor} if self.sensor else {}
        return [{**who, "key": k, "n_frames": self._count[k], "first": t} for k, t in self._first.items()]


def override_lines(overrides) -> list:
    """One line per overridden card (for CSV comments, TOML lists, stderr)."""
    return [("sensor " + o["sensor"] + ": " if o.get("sensor") else "") + f"{o['key']} contradicted in {o['n_frames']} frame{'s' * (o['n_frames'] != 1)}, first: {o['first']}"
            for o in overrides]
