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

Modules (private; import from ``shipstar.config``)::

    _toml         typed TOML tables with named one-line errors; format name and version
    _site         site.toml: SiteConfig, load_site
    _ship         ship.toml: SensorEntry, ShipConfig, load_ship (cameras, installation files)
    _simulation   [simulation] tables: MotionConfig, SimulationConfig
    _session      dock.toml, sea.toml: WeatherConfig, SessionConfig, load_session
    _project      a directory's dock and sea sessions: ProjectConfig, load_project
    _examples     the demo's files: example_files, write_example_config
"""

from __future__ import annotations

from shipstar.config._examples import example_files, write_example_config
from shipstar.config._project import ProjectConfig, load_project
from shipstar.config._session import SESSION_KINDS, SessionConfig, WeatherConfig, load_session
from shipstar.config._ship import SensorEntry, ShipConfig, load_ship
from shipstar.config._simulation import MotionConfig, SimulationConfig
from shipstar.config._site import SiteConfig, load_site
from shipstar.config._toml import FORMAT_VERSION

__all__ = [
    "SiteConfig", "SensorEntry", "ShipConfig", "WeatherConfig", "MotionConfig", "SimulationConfig",
    "SessionConfig", "ProjectConfig", "load_site", "load_ship", "load_session", "load_project",
    "write_example_config", "example_files", "SESSION_KINDS", "FORMAT_VERSION",
]
