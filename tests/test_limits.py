"""shipstar.limits: the physical ranges of every input, the degrees-minutes-seconds parser,
and the track / weather plausibility checks built on them (issue 13, items 1, 3, 8a)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from shipstar.errors import ShipstarError
from shipstar.limits import RANGES, check_range, parse_angle_deg
from shipstar.units import DAY_S


# -- ranges ------------------------------------------------------------------------------

def test_check_range_refuses_in_one_line_with_value_range_and_reason():
    with pytest.raises(ShipstarError) as info:
        check_range("pressure_hpa", 0)
    msg = str(info.value)
    assert msg.startswith("pressure_hpa must be within [500, 1100] hPa (") and msg.endswith("), got 0")
    assert "\n" not in msg
    with pytest.raises(ShipstarError, match=r"^f\.toml: az_deg must be within \[-360, 360\] deg \(.*\), got 999$"):
        check_range("install_az_deg", 999, label="az_deg", where="f.toml")
    with pytest.raises(ShipstarError, match=r"temperature_c must be within \[-60, 60\] C .*got -80"):
        check_range("temperature_c", -80.0)
    with pytest.raises(ShipstarError, match="must be finite"):
        check_range("lat_deg", float("nan"))
    with pytest.raises(ShipstarError, match="must be a number"):
        check_range("lat_deg", True)


def test_every_range_has_a_reason_and_admits_its_ends():
    for name, r in RANGES.items():
        assert r.reason and r.lo < r.hi
        assert check_range(name, r.lo) == r.lo and check_range(name, r.hi) == r.hi
        with pytest.raises(ShipstarError):
            check_range(name, r.hi + 1e-9 * max(1.0, abs(r.hi)))


# -- degrees-minutes-seconds ---------------------------------------------------------------

@pytest.mark.parametrize("text, deg", [
    ("46d28m28.51s", 46 + 28 / 60 + 28.51 / 3600),            # 46.474586111...
    ("46:28:28.51", 46.47458611111111),
    ("-46d28m28.51s", -46.47458611111111),
    ("-46:28:28.51", -46.47458611111111),
    ("46°28'28.51\"", 46.47458611111111),
    ("46d28m", 46.46666666666667),
    ("46:28.5", 46.475),
    ("-0d30m", -0.5),                                           # the sign applies to the whole angle
    ("0:0:36", 0.01),
    ("185d06m33.48s", 185.1093),
    ("46.474586", 46.474586),
    (" 12 ", 12.0),
])
def test_parse_angle_deg_hand_computed(text, deg):
    assert parse_angle_deg(text) == pytest.approx(deg, abs=1e-12)


@pytest.mark.parametrize("text", ["46d28", "46.5d28m", "46d60m", "46:28:60", "abc", "", "nan", "inf", "--5",
                                  "46d28.5m10s", "46:"])
def test_parse_angle_deg_refuses(text):
    with pytest.raises(ShipstarError, match="angle"):
        parse_angle_deg(text)


def test_toml_degrees_may_be_dms_strings_and_are_range_checked():
    from shipstar.config._toml import _Table

    t = _Table({"lat_deg": "-31d54m", "az_deg": 999, "pressure_hpa": 0, "lon_deg": "east"}, "f.toml [x]")
    assert t.number("lat_deg", limit="lat_deg") == pytest.approx(-31.9)
    with pytest.raises(ShipstarError, match=r"^f\.toml \[x\]: az_deg must be within \[-360, 360\] deg"):
        t.number("az_deg", limit="install_az_deg")
    with pytest.raises(ShipstarError, match=r"pressure_hpa must be within \[500, 1100\] hPa .*got 0$"):
        t.number("pressure_hpa", limit="pressure_hpa")
    with pytest.raises(ShipstarError, match="lon_deg must be a finite number or degrees-minutes-seconds"):
        t.number("lon_deg", limit="lon_deg")


def test_installation_file_takes_dms_and_refuses_az_999(tmp_path):
    from shipstar.calibrate.installation import load_installation

    p = tmp_path / "a.toml"
    p.write_text('sensor = "A1"\ncamera = "A1"\naz_deg = "185d06m33.48s"\nel_deg = "39:22:24.24"\nroll_deg = 0.0\n')
    inst = load_installation(p)
    assert np.degrees(inst.az_rad) == pytest.approx(185.1093, abs=1e-12)
    assert np.degrees(inst.el_rad) == pytest.approx(39.3734, abs=1e-12)
    p.write_text('sensor = "A1"\ncamera = "A1"\naz_deg = 999\nel_deg = 39.0\nroll_deg = 0.0\n')
    with pytest.raises(ShipstarError, match=r"installation file .*a\.toml: az_deg must be within \[-360, 360\] deg "
                                            r"\(.*\), got 999$"):
        load_installation(p)
    p.write_text('sensor = "A1"\ncamera = "A1"\naz_deg = 1.0\nel_deg = 39.0\nroll_deg = 0.0\n'
                 '[dock]\nheading_deg = 46.47\npressure_hpa = 0.0\n')
    with pytest.raises(ShipstarError, match=r"dock\.pressure_hpa must be within \[500, 1100\] hPa"):
        load_installation(p)
    # the calibration's date: an ISO time (date_utc = "garbage" was read; a bad-input sweep)
    base = 'sensor = "A1"\ncamera = "A1"\naz_deg = 1.0\nel_deg = 39.0\nroll_deg = 0.0\n'
    p.write_text(base + 'date_utc = "garbage"\n')
    with pytest.raises(ShipstarError, match=r"installation file .*a\.toml: date_utc: .*garbage"):
        load_installation(p)
    p.write_text(base + 'date_utc = "2013-03-15T12:16:00Z"\n')
    assert load_installation(p).date_utc == "2013-03-15T12:16:00Z"


# -- track and weather plausibility --------------------------------------------------------

T0 = (2456367.0, 0.0111111)                                    # 2013-03-15 about 12:16 UTC


def _track(t_s, lat, lon):
    from shipstar.pipeline import Track

    t = np.asarray(t_s, float)
    return Track.from_arrays(np.full(len(t), T0[0]), T0[1] + t / DAY_S, lat, lon)


def _at(t_s):
    return T0[0], T0[1] + t_s / DAY_S


@pytest.mark.parametrize("jump_deg, speed", [(10.0, "1.11195e+06 m/s"), (0.05, "5559.75 m/s")])
def test_a_track_row_jumping_in_latitude_is_refused_naming_rows_and_speed(jump_deg, speed):
    with pytest.raises(ShipstarError, match=rf"track: data rows 2 and 3 \(.*\) are .* m apart in 1 s: {re.escape(speed)} "
                                            r"\(.* kn\), faster than a ship \(at most 20.6 m/s = 40 kn"):
        _track([0, 1, 2, 3], [31.9, 31.9, 31.9 + jump_deg, 31.9 + jump_deg], [120.3] * 4)


def test_a_ship_at_20_knots_passes_and_a_zigzag_is_refused_as_acceleration():
    step = 10.0 / 111195.0                                       # 10 m/s north, rows 1 s apart
    tr = _track([0, 1, 2, 3], [31.9 + k * step for k in range(4)], [120.3] * 4)
    assert tr.site(*_at(1.5)).lat_rad == pytest.approx(np.radians(31.9 + 1.5 * step), abs=1e-15)
    zig = 17.0 / 111195.0                                        # 17 m north, back, north: 34 m/s in 1 s
    with pytest.raises(ShipstarError, match=r"data rows 1 to 3 .* change the ship's velocity by 34.* m/s in 1 s"):
        _track([0, 1, 2], [31.9, 31.9 + zig, 31.9], [120.3] * 3)


def test_coverage_one_second_beyond_the_ends_gaps_and_one_row_tables(tmp_path):
    from shipstar.pipeline import Track, WeatherTable

    tr = _track([0, 5, 20], [31.9] * 3, [120.3] * 3)
    tr.check_covers(*_at(-1.0))                                  # 1 s before the first row
    tr.check_covers(*_at(21.0))                                  # 1 s after the last
    tr.check_covers(*_at(5.0))                                   # on a row that ends a gap
    with pytest.raises(ShipstarError, match="outside the track .*at most 1 s before the first row"):
        tr.check_covers(*_at(-1.01))
    with pytest.raises(ShipstarError, match=r"falls in a gap of 15 s of the track \(rows at .* and .*; at most 10 s"):
        tr.check_covers(*_at(12.0))
    with pytest.raises(ShipstarError, match="gap of 15 s"):                  # many times at once: the first bad one
        tr.check_covers_all(*zip(*(_at(t) for t in (0.0, 4.0, 12.0, 30.0))))
    one = _track([0], [31.9], [120.3])
    one.check_covers(*_at(0.9))
    with pytest.raises(ShipstarError, match=r"outside the track: it has one row, at .*, which covers only frames "
                                            r"within 1 s of it; for a ship at a fixed place give its position"):
        one.check_covers(*_at(60.0))
    Track.fixed(31.9, 120.3).check_covers(*_at(1e6))            # said explicitly: a fixed place
    WeatherTable.constant(1021.7, 11.1).check_covers(*_at(1e6))
    p = tmp_path / "w.csv"
    p.write_text("time_utc,pressure_hpa,temperature_c\n2013-03-15T12:00:00,1021,11\n2013-03-15T14:00:00,1022,11\n")
    with pytest.raises(ShipstarError, match="gap of 7200 s of the weather table"):
        WeatherTable.read_csv(p).weather(*_at(0.0))


def test_empty_tables_and_out_of_range_rows(tmp_path):
    from shipstar.pipeline import Track, WeatherTable

    p = tmp_path / "track.csv"
    p.write_text("time_utc,lat_deg,lon_deg\n")
    with pytest.raises(ShipstarError, match=r"^track file .*track\.csv has no rows"):
        Track.read_csv(p)
    p.write_text("time_utc,pressure_hpa,temperature_c\n2013-03-15T12:16:00,0,11\n")
    with pytest.raises(ShipstarError, match=r"line 2: pressure_hpa must be within \[500, 1100\] hPa .*got 0$"):
        WeatherTable.read_csv(p)
    p.write_text("time_utc,pressure_hpa,temperature_c\n2013-03-15T12:16:00,1000,-80\n")
    with pytest.raises(ShipstarError, match=r"temperature_c must be within \[-60, 60\] C .*got -80$"):
        WeatherTable.read_csv(p)
    with pytest.raises(ShipstarError, match="pressure_hpa must be within"):
        WeatherTable.constant(0.0, 11.1)
