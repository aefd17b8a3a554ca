"""shipstar.config: the demo's TOML files, what they load to, and every kind of bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shipstar.camera import camera_preset
from shipstar.config import (
    example_files,
    load_project,
    load_session,
    load_ship,
    load_site,
    write_example_config,
)
from shipstar.errors import ShipstarError
from shipstar.simulate._session import SEED_A1_INSTALL_DEG, SEED_A2_INSTALL_DEG, SEED_DOCK_HEADING_DEG, dock_session
from shipstar.units import DEG2RAD


@pytest.fixture()
def project_dir(tmp_path):
    write_example_config(tmp_path / "cfg")
    return tmp_path / "cfg"


def _edit(path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))


def test_example_files_load_to_the_seed_values(project_dir):
    p = load_project(project_dir)
    # seed 000: heading 46 deg 28' 28.51'', Jiangyin, 11.10 C, 1021.70 hPa, Tables 2-3
    assert p.dock.dock_attitude_deg[0] == pytest.approx(SEED_DOCK_HEADING_DEG, abs=1e-6)
    assert p.dock.dock_attitude_deg[1:] == (0.0, 0.0)
    assert (p.dock.site.lat_deg, p.dock.site.lon_deg) == (31.9, 120.3)
    assert (p.dock.weather.pressure_hpa, p.dock.weather.temperature_c) == (1021.70, 11.10)
    a1, a2 = p.ship.sensors
    assert (a1.az_deg, a1.el_deg, a1.roll_deg) == SEED_A1_INSTALL_DEG
    assert (a2.az_deg, a2.el_deg, a2.roll_deg) == SEED_A2_INSTALL_DEG
    assert a1.camera == camera_preset("A1") and a2.camera == camera_preset("A2")
    assert p.dock.duration_s == 16.0 and p.dock.frame_rate_hz == 10.0 and p.sea.duration_s == 60.0
    assert p.sea.simulation.motion.roll_amplitude_deg == 5.0 and p.sea.simulation.motion.roll_period_s == 8.0
    # rendered sea frames use 10 ms exposures like shipstar.simulate's sea_session; the dock keeps the camera's
    from shipstar.simulate._session import sea_session

    assert p.sea.spec().exposure_s == sea_session().exposure_s == 0.01
    assert p.dock.spec().exposure_s is None and p.dock.simulation.exposure_s is None


def test_dock_spec_matches_the_simulators_seed_session(project_dir):
    """The dock file describes the same night as shipstar.simulate's dock_session()."""
    mine = load_project(project_dir).dock.spec()
    ref = dock_session()
    assert mine.start_utc == ref.start_utc and mine.duration_s == ref.duration_s
    assert mine.frame_rate_hz == ref.frame_rate_hz
    assert (mine.pressure_hpa, mine.temperature_c) == (ref.pressure_hpa, ref.temperature_c)
    for s, r in zip(mine.sensors, ref.sensors):
        assert s.name == r.name and s.camera == r.camera
        np.testing.assert_allclose(s.C_deck_from_sensor, r.C_deck_from_sensor, atol=1e-15)
    # the theodolite heading is written to 1e-6 deg (0.004'')
    np.testing.assert_allclose(mine.motion.C_hor_from_deck(3.0), ref.motion.C_hor_from_deck(3.0), atol=2e-8)
    assert mine.site(0.0) == ref.site(0.0)


def test_sea_spec_motion_in_radians(project_dir):
    m = load_project(project_dir).sea.spec().motion
    assert m.roll_amplitude_rad == pytest.approx(5.0 * DEG2RAD)
    assert m.pitch_phase_rad == pytest.approx(40.0 * DEG2RAD)
    K, psi, theta = m.angles_rad(2.0)                 # a quarter of the 8 s roll period
    assert theta == pytest.approx(5.0 * DEG2RAD, rel=1e-12)
    assert psi == pytest.approx(2.0 * DEG2RAD * math.sin(2 * math.pi * 2.0 / 6.0 + 40.0 * DEG2RAD), rel=1e-12)


def test_pipeline_inputs_from_a_dock_session(project_dir):
    cfg = load_project(project_dir).dock
    opt = cfg.pipeline_options()
    assert (opt.refraction_model, opt.refraction) == ("erfa", "per-star")
    site = cfg.track().site(2456367.0, 0.01)
    assert site.lat_rad == pytest.approx(31.9 * DEG2RAD)
    w = cfg.weather_table().weather(2456367.0, 0.01)
    assert (w.pressure_hpa, w.temperature_c) == (1021.70, 11.10)
    dc = cfg.dock_conditions()
    assert dc.heading_rad == pytest.approx(SEED_DOCK_HEADING_DEG * DEG2RAD, abs=1e-8)


def test_site_deflection_of_the_vertical_reaches_the_pipeline(project_dir):
    """Review finding: site.toml's xi/eta were read, then dropped by track() and
    dock_conditions().  Now every frame's Site carries them, the dock record keeps them,
    and the simulator (which has no deflection) refuses such a site instead of silently
    simulating without it."""
    from shipstar.units import ASEC2RAD

    _edit(project_dir / "site.toml", "xi_arcsec = 0.0 ", "xi_arcsec = 8.5 ")
    _edit(project_dir / "site.toml", "eta_arcsec = 0.0 ", "eta_arcsec = -12.25 ")
    cfg = load_project(project_dir).dock
    site = cfg.track().site(2456367.0, 0.01)
    assert site.xi_rad == pytest.approx(8.5 * ASEC2RAD, rel=1e-12)
    assert site.eta_rad == pytest.approx(-12.25 * ASEC2RAD, rel=1e-12)
    assert site.astronomical_lat_rad == pytest.approx((31.9 + 8.5 / 3600) * DEG2RAD, rel=1e-12)
    dc = cfg.dock_conditions()
    assert (dc.xi_rad, dc.eta_rad) == (pytest.approx(8.5 * ASEC2RAD), pytest.approx(-12.25 * ASEC2RAD))
    with pytest.raises(ShipstarError, match="no deflection of the vertical.*xi_arcsec = 8.5"):
        cfg.spec()


def test_track_csv_deflection_columns_and_longitude_range(tmp_path):
    from shipstar.pipeline import Track
    from shipstar.sky.time import utc_jd_from_iso
    from shipstar.units import ASEC2RAD

    p = tmp_path / "track.csv"
    p.write_text("time_utc,lat_deg,lon_deg,xi_arcsec,eta_arcsec\n2013-03-15T12:29:59,31.9,350.0,4,-6\n"
                 "2013-03-15T12:30:01,31.9,350.0002,8,-2\n")                 # 19 m in 2 s: a ship
    site = Track.read_csv(p).site(*utc_jd_from_iso("2013-03-15T12:30:00"))
    assert (site.xi_rad / ASEC2RAD, site.eta_rad / ASEC2RAD) == (pytest.approx(6.0), pytest.approx(-4.0))
    assert site.lon_rad / DEG2RAD == pytest.approx(-9.9999, abs=1e-9)       # 350.0001 deg, normalised
    p.write_text("time_utc,lat_deg,lon_deg\n2013-03-15T12:29:00,31.9,1e308\n")
    with pytest.raises(ShipstarError, match=r"data row 1: longitude 1e\+308 deg is outside \[-180, 360\]"):
        Track.read_csv(p)
    p.write_text("time_utc,lat_deg,lon_deg,xi_arcsec\n2013-03-15T12:29:00,31.9,120,500\n")
    with pytest.raises(ShipstarError, match="deflection of the vertical xi"):
        Track.read_csv(p)
    with pytest.raises(ShipstarError, match="longitude"):
        Track.fixed(31.9, -181.0)
    assert Track.fixed(31.9, 360.0).site(0.0, 0.0).lon_rad == 0.0


def test_track_and_weather_csv_and_frames(project_dir, tmp_path):
    (project_dir / "track.csv").write_text("time_utc,lat_deg,lon_deg\n2013-03-15T12:30:29,31.9,120.3\n"
                                           "2013-03-15T12:30:31,31.9001,120.3001\n")
    (project_dir / "weather.csv").write_text("time_utc,pressure_hpa,temperature_c\n2013-03-15T12:29:00,1020,11\n"
                                             "2013-03-15T12:32:00,1022,10\n")
    sea = project_dir / "sea.toml"
    _edit(sea, "# [track]                             # real sessions: the ship's position over time\n"
               "# csv = \"track.csv\"", "[track]\ncsv = \"track.csv\"")
    _edit(sea, "pressure_rate_hpa_per_s = 0.005       # simulation: linear drift\ntemperature_rate_c_per_s = -0.01\n",
          "csv = \"weather.csv\"\n")
    _edit(sea, "# [frames]\n# A1 = \"frames/sea/A1\"", "[frames]\nA1 = \"frames/sea/A1\"")
    cfg = load_session(sea)
    from shipstar.sky.time import utc_jd_from_iso

    jd = utc_jd_from_iso("2013-03-15T12:30:30")       # half way through the tables
    assert cfg.track().site(*jd).lat_rad == pytest.approx(31.90005 * DEG2RAD, rel=1e-12)
    assert cfg.weather_table().weather(*jd).pressure_hpa == pytest.approx(1021.0)
    assert cfg.frames == {"A1": project_dir / "frames/sea/A1"}
    with pytest.raises(ShipstarError, match="no directory for sensor A2"):
        cfg.frame_lists()


def test_installation_file_replaces_the_angles(project_dir):
    from shipstar.calibrate.installation import Installation, save_installation

    save_installation(Installation("A1", "A1", 185.0 * DEG2RAD, 40.0 * DEG2RAD, 0.1 * DEG2RAD),
                      project_dir / "A1.installation.toml")
    _edit(project_dir / "ship.toml", '# installation_file = "A1.installation.toml"',
          'installation_file = "A1.installation.toml"')
    a1 = load_ship(project_dir / "ship.toml").sensor("A1")
    assert (a1.az_deg, a1.el_deg, a1.roll_deg) == pytest.approx((185.0, 40.0, 0.1), abs=1e-12)
    assert a1.installation().sensor == "A1"


def test_write_refuses_to_overwrite(project_dir):
    with pytest.raises(ShipstarError, match="already exists.*--force"):
        write_example_config(project_dir)
    written = write_example_config(project_dir, overwrite=True)
    assert sorted(p.relative_to(project_dir).as_posix() for p in written) == sorted(
        [*example_files(), "cameras/A1.toml", "cameras/A2.toml"])


def test_write_into_a_file_is_refused(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(ShipstarError, match="not a directory"):
        write_example_config(tmp_path / "f")


@pytest.mark.parametrize("file, old, new, message", [
    ("site.toml", "lat_deg = 31.9", "lat_deg = 95.0", r"lat_deg must be within \[-90, 90\] deg \(.*\), got 95$"),
    ("site.toml", "lat_deg = 31.9", "lat_deg = 31.9\nlatitude_deg = 31.9", "unknown key 'latitude_deg'"),
    ("site.toml", "lon_deg = 120.3", "lon_deg = \"east\"", "lon_deg must be a finite number"),
    ("site.toml", "lon_deg = 120.3", "lon_deg = nan", "lon_deg must be a finite number"),
    ("site.toml", "format_version = 1", "format_version = 2", "format_version 2 is not supported"),
    ("site.toml", 'format = "shipstar-site"', 'format = "shipstar-ship"', "format must be 'shipstar-site'"),
    ("site.toml", "[site]", "[site", "not valid TOML"),
    ("ship.toml", 'camera = "cameras/A1.toml"', 'camera = "nope.toml"', "neither a preset"),
    ("ship.toml", 'name = "A2"', 'name = "A1"', "sensor name 'A1' is used twice"),
    ("ship.toml", 'name = "A2"', 'name = "A 2"', "name must be letters"),
    ("ship.toml", "el_deg = 35.1031", "el_deg = 91", r"el_deg must be within \[-90, 90\]"),
    ("dock.toml", "kind = \"dock\"", "kind = \"harbour\"", "kind must be one of dock, sea"),
    ("dock.toml", "duration_s = 16.0", "duration_s = 0", "duration_s must be within"),
    ("dock.toml", "start_utc = \"2013-03-15T12:16:00\"", "start_utc = \"2013-03-15 25:00\"", "start_utc"),
    ("dock.toml", "refraction_model = \"erfa\"", "refraction_model = \"magic\"", "refraction_model must be one of"),
    ("dock.toml", "heading_deg = 46.474586", "heading_deg = 361", r"heading_deg must be within \[0, 360\]"),
    ("dock.toml", "pressure_hpa = 1021.70", "pressure_hpa = -3", "pressure_hpa must be within"),
    ("dock.toml", "seed = 2013", "seed = 1.5", "seed must be an integer"),
    ("dock.toml", "site = \"site.toml\"", "site = \"elsewhere.toml\"", "site file .*elsewhere.toml does not exist"),
    ("dock.toml", "# [frames]", "[frames]\nB7 = \"x\"\n# ", "names sensor 'B7', which is not on the ship"),
    ("sea.toml", "roll_period_s = 8.0", "roll_period_s = 0.0", "roll_period_s must be"),
    ("sea.toml", "exposure_s = 0.01", "exposure_s = 0", "exposure_s must be within"),
    ("sea.toml", "[weather]", "[dock]\nheading_deg = 1.0\n[weather]", r"\[dock\] belongs in dock sessions only"),
])
def test_bad_files_name_the_file_and_key(project_dir, file, old, new, message):
    _edit(project_dir / file, old, new)
    with pytest.raises(ShipstarError, match=message) as info:
        load_project(project_dir)
    assert "\n" not in str(info.value)


def test_missing_keys_and_tables(project_dir):
    _edit(project_dir / "dock.toml", "[dock]", "[not_dock]")
    with pytest.raises(ShipstarError, match="unknown key 'not_dock'|needs a \\[dock\\] table"):
        load_project(project_dir)
    write_example_config(project_dir, overwrite=True)
    _edit(project_dir / "site.toml", "lat_deg = 31.9", "")
    with pytest.raises(ShipstarError, match="missing key 'lat_deg'"):
        load_site(project_dir / "site.toml")


def test_sea_simulation_needs_motion(project_dir):
    _edit(project_dir / "sea.toml", "[simulation.ship_motion]", "[unused]")
    text = (project_dir / "sea.toml").read_text().split("[unused]")[0]
    (project_dir / "sea.toml").write_text(text)
    cfg = load_session(project_dir / "sea.toml")
    with pytest.raises(ShipstarError, match="needs \\[simulation.ship_motion\\]"):
        cfg.spec()


def test_project_directory_must_exist(tmp_path):
    with pytest.raises(ShipstarError, match="does not exist.*--write-config"):
        load_project(tmp_path / "nowhere")
