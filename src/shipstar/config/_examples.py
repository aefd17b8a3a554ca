"""The demo's configuration files, as examples to edit (``shipstar demo --write-config``)."""

from __future__ import annotations

from pathlib import Path

from shipstar.errors import ShipstarError


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


def write_example_config(directory, *, overwrite: bool = False) -> list:
    """Write the demo's configuration files into ``directory`` (created if needed).

    Refuses (ShipstarError, nothing written) when a file exists and ``overwrite`` is
    false.  Returns the paths written.
    """
    from shipstar._atomic import atomic_write_text
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
            atomic_write_text(d / rel, text)
            written.append(d / rel)
        for rel, name in cameras.items():
            (d / rel).parent.mkdir(parents=True, exist_ok=True)
            save_camera(camera_preset(name), d / rel)
            written.append(d / rel)
    except OSError as exc:
        raise ShipstarError(f"cannot write into {d}: {exc.strerror or exc}") from None
    return written
