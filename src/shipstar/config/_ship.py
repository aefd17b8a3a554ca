"""``ship.toml``: the ship and its star sensors (camera, installation angles)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from shipstar.config._toml import _read_toml, _relative, _Table
from shipstar.errors import ShipstarError
from shipstar.units import DEG2RAD


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
                        az_deg=s.number("az_deg", limit="install_az_deg"),
                        el_deg=s.number("el_deg", limit="install_el_deg"),
                        roll_deg=s.number("roll_deg", 0.0, limit="install_roll_deg"),
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
