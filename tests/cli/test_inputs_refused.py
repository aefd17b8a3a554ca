"""Inputs no ship has are refused by every command, in one line, exit code 2 (issue 13:
physical ranges, track plausibility, degrees-minutes-seconds, no abbreviated options).

Through the real command line, ``shipstar.cli.main``; the cases that need frames use a
small simulated dock session."""

from __future__ import annotations

import pytest

from shipstar.cli import build_parser

from _cli import DOCK_SITE, one_line_error as _main  # tests/cli on sys.path


# every command that takes the weather: the same ranges
WEATHER_COMMANDS = [
    ["calibrate", "install", "--frames", "d", "--sensor", "A1", "--camera", "A1", "--heading-deg", "46.47",
     "--lat-deg", "31.9", "--lon-deg", "120.3", "--out", "a.toml"],
    ["calibrate", "intrinsics", "--frames", "d", "--camera", "A1", "--lat-deg", "31.9", "--lon-deg", "120.3"],
    ["measure", "--sensor", "A1=d", "--install", "a.toml", "--lat-deg", "31.9", "--lon-deg", "120.3",
     "--out", "o.csv"],
    ["live", "--sensor", "A1=d", "--install", "a.toml", "--lat-deg", "31.9", "--lon-deg", "120.3", "--out", "o.csv"],
    ["apparent", "--time", "2013-03-15T12:16:00", "--lat-deg", "31.9", "--lon-deg", "120.3"],
    ["simulate", "--camera", "A1", "--ra-deg", "10", "--dec-deg", "20", "--time", "2013-03-15T12:16:00",
     "--lat-deg", "31.9", "--lon-deg", "120.3", "--out", "f.fits"],
]


@pytest.mark.parametrize("command", WEATHER_COMMANDS, ids=lambda c: " ".join(c[:2]).replace(" --", ""))
@pytest.mark.parametrize("flag, value, message", [
    ("--pressure-hpa", "0", "argument --pressure-hpa: pressure_hpa must be within [500, 1100] hPa ("),
    ("--temperature-c", "-80", "argument --temperature-c: temperature_c must be within [-60, 60] C ("),
])
def test_weather_out_of_range_is_refused_by_every_command(command, flag, value, message, capsys):
    code, line = _main([*command, "--pressure-hpa", "1021.7", "--temperature-c", "11.1", flag, value], capsys)
    assert code == 2
    assert message in line and line.endswith(f"got {value} (see '{line.split(':')[0]} --help')"), line


@pytest.mark.parametrize("args, message", [
    (["--pitch-deg", "95"], "argument --pitch-deg: pitch_deg must be within [-30, 30] deg ("),
    (["--roll-deg", "-50"], "argument --roll-deg: roll_deg must be within [-45, 45] deg ("),
    (["--heading-deg", "400"], "argument --heading-deg: heading_deg must be within [0, 360] deg ("),
    (["--lat-deg", "91d"], "argument --lat-deg: latitude must be within [-90, 90] deg ("),
    (["--heading-deg", "46d61m"], "minutes and seconds must be below 60"),
])
def test_calibrate_install_refuses_a_ship_no_dock_has(args, message, capsys):
    code, line = _main(["calibrate", "install", *args], capsys)
    assert code == 2 and message in line, line


def test_simulate_refuses_installation_angles_out_of_range(capsys):
    code, line = _main(["simulate", "--install-az-deg", "999"], capsys)
    assert code == 2 and "install_az_deg must be within [-360, 360] deg (" in line and "got 999" in line


def test_abbreviated_options_are_not_guessed(capsys):
    # (the case, `--ins` read as `--install`, is now a real option: `--inst` is the prefix)
    code, line = _main(["measure", "--sensor", "A1=d", "--install", "a.toml", "--inst", "x", "--out", "o.csv"],
                       capsys)
    assert code == 2 and line.startswith("shipstar measure: error: unrecognized arguments: --inst x"), line
    code, line = _main(["apparent", "--time", "2013-03-15T12:16:00", "--lat", "31.9", "--lon-deg", "120"], capsys)
    assert code == 2 and "--lat" in line and ("unrecognized arguments" in line or "required" in line), line


def test_degrees_minutes_seconds_on_the_command_line():
    args = build_parser().parse_args(
        ["calibrate", "install", "--frames", "d", "--sensor", "A1", "--camera", "A1",
         "--heading-deg", "46d28m28.51s", "--pitch-deg", "-0d0m36s", "--roll-deg", "-0:01:12",
         "--lat-deg", "-31:54:00", "--lon-deg", "120d18m", "--pressure-hpa", "1021.7", "--temperature-c", "11.1",
         "--out", "a.toml"])
    assert args.heading_deg == pytest.approx(46.47458611111111, abs=1e-12)
    assert args.pitch_deg == pytest.approx(-0.01, abs=1e-15)
    assert args.roll_deg == pytest.approx(-0.02, abs=1e-15)
    assert (args.lat_deg, args.lon_deg) == (pytest.approx(-31.9), pytest.approx(120.3))
    args = build_parser().parse_args(["simulate", "--ra-deg", "83d49m12s", "--dec-deg", "-5d24m", "--out", "f.fits"])
    assert (args.ra_deg, args.dec_deg) == (pytest.approx(83.82), pytest.approx(-5.4))
    args = build_parser().parse_args(["solve", "f.fits", "--fov-deg", "8d30m"])
    assert args.fov_deg == pytest.approx(8.5)


# -- files: installation, track, weather ----------------------------------------------------

def _measure(dock, capsys, monkeypatch, *args):
    monkeypatch.chdir(dock)
    return _main(["measure", "--sensor", "A1=dock/A1", "--install", "A1.toml", *args, "--out", "never.csv"], capsys)


def test_installation_file_with_az_999_is_refused(dock, capsys, monkeypatch):
    text = (dock / "A1.toml").read_text()
    start = text.index("\naz_deg = ")
    bad = text[:start] + "\naz_deg = 999" + text[text.index("\n", start + 1):]
    (dock / "bad.toml").write_text(bad)
    code, line = _measure(dock, capsys, monkeypatch, *DOCK_SITE, "--install", "bad.toml")
    assert code == 2
    assert "installation file bad.toml: az_deg must be within [-360, 360] deg (" in line and "got 999" in line, line
    assert not (dock / "never.csv").exists()


@pytest.mark.parametrize("rows, message", [
    ("2013-03-15T12:15:59,31.9,120.3\n2013-03-15T12:16:00,41.9,120.3\n",
     "are 1.11195e+06 m apart in 1 s: 1.11195e+06 m/s"),
    ("2013-03-15T12:15:59,31.9,120.3\n2013-03-15T12:16:00,31.95,120.3\n", "are 5559.75 m apart in 1 s: 5559.75 m/s"),
    ("", "track file track.csv has no rows"),
    ("2013-03-15T13:00:00,31.9,120.3\n", "it has one row, at 2013-03-15T13:00:00.000000Z, which covers only frames "
                                         "within 1 s of it; for a ship at a fixed place"),
    ("2013-03-15T12:15:50,31.9,120.3\n2013-03-15T12:16:10,31.9,120.3\n", "falls in a gap of 20 s of the track"),
])
def test_implausible_or_short_tracks_are_refused(dock, capsys, monkeypatch, rows, message):
    (dock / "track.csv").write_text("time_utc,lat_deg,lon_deg\n" + rows)
    code, line = _measure(dock, capsys, monkeypatch, "--track", "track.csv", "--pressure-hpa", "1021.7",
                          "--temperature-c", "11.1")
    assert code == 2 and message in line, line
    if "faster" in line:
        assert "data rows 1 and 2 (2013-03-15T12:15:59.000000Z and 2013-03-15T12:16:00.000000Z)" in line


def test_weather_rows_out_of_range_are_refused(dock, capsys, monkeypatch):
    (dock / "weather.csv").write_text("time_utc,pressure_hpa,temperature_c\n2013-03-15T12:16:00,0,11.1\n")
    code, line = _measure(dock, capsys, monkeypatch, "--lat-deg", "31.9", "--lon-deg", "120.3",
                          "--weather", "weather.csv")
    assert code == 2 and "weather.csv line 2: pressure_hpa must be within [500, 1100] hPa (" in line, line
