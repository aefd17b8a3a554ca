"""NMEA 0183 sentences out and in (shipstar.live._nmea), checked against pynmea2 and an
independent XOR."""

from __future__ import annotations

import datetime
import math

import pynmea2
import pytest

from shipstar.errors import ShipstarError
from shipstar.live import _nmea as nmea
from shipstar.sky.time import utc_jd_from_iso

T0 = utc_jd_from_iso("2013-03-15T12:16:03.123456Z")


def xor_hex(body: str) -> str:
    """The checksum, computed here independently of shipstar."""
    value = 0
    for ch in body.encode("ascii"):
        value ^= ch
    return "%02X" % value


def wire(body: str, cs: str | None = None) -> str:
    """A sentence built by hand (own checksum unless ``cs`` is given)."""
    return "$" + body + "*" + (xor_hex(body) if cs is None else cs) + "\r\n"


def check_frame(s: str):
    """CR LF at the end, checksum right by our XOR and by pynmea2; returns pynmea2's parse."""
    assert s.endswith("\r\n") and s.count("\r\n") == 1 and s.startswith("$")
    body, cs = s[1:-2].rsplit("*", 1)
    assert cs == xor_hex(body)
    assert int(cs, 16) == pynmea2.NMEASentence.checksum(body)
    return pynmea2.parse(s.strip(), check=True)


# -- checksum and framing ----------------------------------------------------------------

@pytest.mark.parametrize("body", ["GPGGA,", "HEHDT,046.47,T", "PSSTA,1,2,3", "WIMDA,,,,,"])
def test_checksum_is_the_xor_of_the_body(body):
    assert nmea.checksum(body) == xor_hex(body)
    assert nmea.sentence(body) == "$" + body + "*" + xor_hex(body) + "\r\n"


def test_sentence_refuses_delimiters_inside():
    with pytest.raises(nmea.NmeaError, match=r"cannot write '\*' inside"):
        nmea.sentence("PSSTA,a*b")


def test_nmea_error_is_a_shipstar_error():
    assert issubclass(nmea.NmeaError, ShipstarError)


# -- sentences out -----------------------------------------------------------------------

def test_pssta_valid_reads_back_through_pynmea2():
    s = nmea.pssta(*T0, 46.4745861, -1.2345674, -5.5000004, 0.364, 0.2, 12.3456, "joint", 42, True)
    p = check_frame(s)
    assert isinstance(p, pynmea2.ProprietarySentence) and p.manufacturer == "SST"
    data = p.data                       # pynmea2 splits "$PSSTA" as maker SST, data[0] = "A"
    assert data[0] == "A"
    assert data[1] == "121603.123456" and data[2] == "150313"
    assert float(data[3]) == pytest.approx(46.474586, abs=1e-12)
    assert float(data[4]) == pytest.approx(-1.234567, abs=1e-12)
    assert float(data[5]) == pytest.approx(-5.5, abs=1e-12)
    assert [len(d.split(".")[1]) for d in data[3:6]] == [6, 6, 6]
    assert data[6:9] == ["0.36", "0.20", "12.35"]
    assert data[9:] == ["joint", "42", "A"]


def test_pssta_heading_wraps_to_zero_not_360():
    p = check_frame(nmea.pssta(*T0, 359.9999996, 0, 0, 1, 1, 1, "single", 5, True))
    assert p.data[3] == "0.000000"
    p = check_frame(nmea.pssta(*T0, -0.25, 0, 0, 1, 1, 1, "single", 5, True))
    assert p.data[3] == "359.750000"


def test_pssta_not_valid_has_empty_angle_and_sigma_fields():
    p = check_frame(nmea.pssta(*T0, 10.0, 1.0, 2.0, 1, 2, 3, "single", 0, False))
    assert p.data[3:9] == [""] * 6
    assert p.data[9:] == ["single", "0", "V"]


def test_pssta_time_is_rounded_to_the_microsecond_with_carry():
    jd = utc_jd_from_iso("2013-03-15T23:59:59.9999996Z")
    p = check_frame(nmea.pssta(*jd, 1, 2, 3, 1, 1, 1, "single", 1, True))
    assert p.data[1:3] == ["000000.000000", "160313"]


@pytest.mark.parametrize("heading, text", [(359.999999, "000.00"), (359.994, "359.99"), (46.474586, "046.47"),
                                           (-0.5, "359.50"), (720.0, "000.00"), (5.005001, "005.01")])
def test_hehdt_wraps_and_rounds(heading, text):
    s = nmea.hehdt(heading)
    p = check_frame(s)
    assert isinstance(p, pynmea2.types.talker.HDT)
    assert s.split(",")[1] == text
    assert float(p.heading) == float(text) and p.hdg_true == "T" and p.talker == "HE"
    assert 0.0 <= float(p.heading) < 360.0


def test_pashr_reads_back_with_pynmea2_field_names():
    s = nmea.pashr(*T0, 359.999, -5.126, -2.004, 0.0101, 0.0002, 0.1234, nmea.PASHR_Q_FUSED, nmea.PASHR_S_NOMINAL)
    p = check_frame(s)
    assert type(p).__name__ == "ASHRATT"
    assert p.timestamp == datetime.time(12, 16, 3, 123000, tzinfo=datetime.timezone.utc)
    assert p.true_heading == 0.0 and p.is_true_heading == "T"          # 359.999 -> 000.00, wrapped
    assert p.roll == -5.13 and p.pitch == -2.0
    assert p.heave is None
    assert p.roll_accuracy == 0.010 and p.heading_accuracy == 0.123
    assert p.pitch_accuracy == 0.001                                   # never 0.000
    assert int(p.aiding_status) == 2 and int(p.imu_status) == 2
    fields = s.split("*")[0].split(",")
    assert fields[4] == "-005.13" and fields[5] == "-002.00"            # explicit sign


def test_pashr_positive_angles_carry_a_plus_sign():
    s = nmea.pashr(*T0, 46.474586, 3.0, 0.004, 0.01, 0.01, 0.02, nmea.PASHR_Q_SINGLE, nmea.PASHR_S_DEGRADED)
    p = check_frame(s)
    fields = s.split("*")[0].split(",")
    assert fields[2] == "046.47" and fields[4] == "+003.00" and fields[5] == "+000.00"
    assert p.roll == 3.0 and p.pitch == 0.0 and int(p.aiding_status) == 1 and int(p.imu_status) == 1


def test_pashr_no_solution_has_empty_fields():
    p = check_frame(nmea.pashr(*T0, None, None, None, None, None, None, nmea.PASHR_Q_NONE, nmea.PASHR_S_NONE))
    assert type(p).__name__ == "ASHRATT"
    assert (p.true_heading, p.roll, p.pitch, p.roll_accuracy, p.pitch_accuracy, p.heading_accuracy) == (None,) * 6
    assert int(p.aiding_status) == 0 and int(p.imu_status) == 0


def test_pashr_refuses_unknown_codes():
    with pytest.raises(nmea.NmeaError, match="quality must be 0, 1 or 2"):
        nmea.pashr(*T0, 1, 1, 1, 1, 1, 1, 3, 2)
    with pytest.raises(nmea.NmeaError, match="status must be 0, 1 or 2"):
        nmea.pashr(*T0, 1, 1, 1, 1, 1, 1, 1, 5)


def test_pssts_layout_with_two_sensors():
    s = nmea.pssts(*T0, [nmea.SensorHealth("A1", 10, 9, 0.1234, 1), ("A2", 11, 11, None, 0)],
                   "extrapolated", 0.0123456)
    p = check_frame(s)
    d = p.data
    assert d[0] == "S" and d[1] == "121603.12" and d[2] == "150313"
    assert d[3] == "2"
    assert d[4:9] == ["A1", "10", "9", "0.123", "1"]
    assert d[9:14] == ["A2", "11", "11", "", "0"]
    assert d[14:] == ["X", "12.346"]
    assert len(d) == 4 + 5 * int(d[3]) + 2


def test_pssts_refuses_bad_names_and_counts():
    with pytest.raises(nmea.NmeaError, match="sensor name"):
        nmea.pssts(*T0, [("A,1", 1, 1, 0.1, 0)])
    with pytest.raises(nmea.NmeaError, match="frames_in"):
        nmea.pssts(*T0, [("A1", -1, 1, 0.1, 0)])
    with pytest.raises(nmea.NmeaError, match="at least one sensor"):
        nmea.pssts(*T0, [])


def test_gga_formatter_reads_back():
    s = nmea.gga(*T0, -31.9000461, -179.9999999, 12.5)
    p = check_frame(s)
    assert isinstance(p, pynmea2.types.talker.GGA)
    assert p.timestamp == datetime.time(12, 16, 3, 120000, tzinfo=datetime.timezone.utc)
    assert p.latitude == pytest.approx(-31.9000461, abs=1e-6 / 60 / 2 + 1e-12)
    assert p.longitude == pytest.approx(-179.9999999, abs=1e-6 / 60 / 2 + 1e-12)
    assert p.gps_qual == 1 and p.altitude == 12.5
    assert len(s) <= 82
    fix = nmea.decode_gga(s)
    assert fix.lat_deg == pytest.approx(-31.9000461, abs=1e-8) and fix.height_m == 12.5
    assert fix.utc_time_of_day_s == pytest.approx(12 * 3600 + 16 * 60 + 3.12, abs=1e-9)


def test_latlon_minutes_carry_into_degrees():
    p = check_frame(nmea.gga(*T0, 31.99999999999, 120.99999999999, 0.0))
    assert p.lat == "3200.000000" and p.lon == "12100.000000"


def test_rmc_zda_formatters_read_back():
    p = check_frame(nmea.rmc(*T0, 31.9, 120.3, 12.3, 45.6))
    assert isinstance(p, pynmea2.types.talker.RMC)
    assert p.status == "A" and p.datestamp == datetime.date(2013, 3, 15)
    assert p.latitude == pytest.approx(31.9) and p.longitude == pytest.approx(120.3)
    assert p.spd_over_grnd == 12.3 and p.true_course == 45.6
    fix = nmea.decode_rmc(nmea.rmc(*T0, 31.9, 120.3))
    jd = utc_jd_from_iso("2013-03-15T12:16:03.12Z")
    assert (fix.utc_jd1 - jd[0]) + (fix.utc_jd2 - jd[1]) == pytest.approx(0.0, abs=1e-6 / 86400)
    p = check_frame(nmea.zda(*T0))
    assert isinstance(p, pynmea2.types.talker.ZDA)
    assert (p.day, p.month, p.year) == (15, 3, 2013)
    assert p.timestamp == datetime.time(12, 16, 3, 120000, tzinfo=datetime.timezone.utc)


def test_mda_xdr_formatters_read_back():
    p = check_frame(nmea.mda(1021.695, 11.11, 0.45))
    assert isinstance(p, pynmea2.types.talker.MDA)
    assert float(p.b_pressure_bar) * 1000 == pytest.approx(1021.70, abs=1e-9)
    assert float(p.b_pressure_inch) * 33.8639 == pytest.approx(1021.695, abs=0.01)
    assert float(p.air_temp) == 11.11 and p.bars == "B" and p.a_celsius == "C"
    assert float(p.rel_humidity) == 45.0
    assert len(p.data) == 20
    p = check_frame(nmea.xdr(1021.695, -11.11, 0.45))
    assert p.num_transducers == 3
    tr = [p.get_transducer(i) for i in range(3)]
    assert (tr[0].type, float(tr[0].value), tr[0].units) == ("P", 1.0217, "B")
    assert (tr[1].type, float(tr[1].value), tr[1].units) == ("C", -11.11, "C")
    assert (tr[2].type, float(tr[2].value), tr[2].units) == ("H", 45.0, "P")
    w = nmea.decode_xdr(nmea.xdr(1021.695, -11.11, 0.45))
    assert w == nmea.WeatherReading(pytest.approx(1021.70), pytest.approx(-11.11), pytest.approx(0.45))
    w = nmea.decode_mda(nmea.mda(1021.695, 11.11))
    assert w.pressure_hpa == pytest.approx(1021.70) and w.temperature_c == 11.11 and w.relative_humidity is None


# -- parse -------------------------------------------------------------------------------

def test_parse_splits_address_and_fields():
    s = nmea.parse(wire("GPGGA,121603.00,3154.000000,N,12018.000000,E,1,08,0.9,10.0,M,,M,,"))
    assert (s.talker, s.type) == ("GP", "GGA")
    assert s.fields[:3] == ("121603.00", "3154.000000", "N") and len(s.fields) == 14
    s = nmea.parse(wire("PASHR,121603.000,046.47,T,+001.00,-002.00,,0.010,0.010,0.020,1,2"))
    assert (s.talker, s.type) == ("P", "ASHR") and s.fields[0] == "121603.000"


def test_parse_refuses_bad_checksum_with_expected_and_got():
    body = "GPGGA,121603.00,3154.000000,N,12018.000000,E,1,08,0.9,10.0,M,,M,,"
    with pytest.raises(nmea.NmeaError) as e:
        nmea.parse(wire(body, "00"))
    msg = str(e.value)
    assert msg.startswith("bad checksum in '$GPGGA,121603.00,")
    assert msg.endswith(f"(expected {xor_hex(body)}, got 00)")
    assert "\n" not in msg and e.value.kind == "checksum"


def test_parse_refuses_missing_checksum():
    with pytest.raises(nmea.NmeaError) as e:
        nmea.parse("$HEHDT,046.47,T\r\n")
    assert str(e.value) == f"missing checksum in '$HEHDT,046.47,T' (expected *{xor_hex('HEHDT,046.47,T')} at the end)"
    with pytest.raises(nmea.NmeaError, match=r"bad checksum field '\*4' in"):
        nmea.parse("$HEHDT,046.47,T*4")


def test_parse_refuses_junk():
    with pytest.raises(nmea.NmeaError) as e:
        nmea.parse("hello world")
    assert str(e.value) == "no '$' at the start of 'hello world'"
    with pytest.raises(nmea.NmeaError, match="^empty sentence$"):
        nmea.parse("\r\n")
    with pytest.raises(nmea.NmeaError, match="^bad address 'GP' in"):
        nmea.parse(wire("GP,1,2"))


def test_parse_refuses_non_ascii():
    with pytest.raises(nmea.NmeaError) as e:
        nmea.parse("$HEHDT,046.47,T\u00b0*00")
    assert str(e.value).startswith("non-ASCII or control character '\u00b0' at position 16 in '$HEHDT,046.47,T\\xb0")
    assert e.value.kind == "non-ascii"


def test_parse_refuses_too_long_lines():
    body = "GPGGA," + "1" * 74                        # 1 + 80 + 3 + 2 = 86 characters
    with pytest.raises(nmea.NmeaError) as e:
        nmea.parse(wire(body))
    assert str(e.value).startswith("sentence too long: 86 characters with CR LF, NMEA 0183 allows 82, in '$GPGGA,111")
    ok = "GPGGA," + "1" * 70                          # exactly 82
    assert len(wire(ok)) == 82 and nmea.parse(wire(ok)).type == "GGA"
    assert nmea.parse(wire(body), max_chars=None).type == "GGA"


# -- decoders ----------------------------------------------------------------------------

GGA_OK = "GPGGA,121603.00,3154.000000,N,12018.000000,E,1,08,0.9,10.0,M,2.5,M,,"


def test_decode_gga_values():
    fix = nmea.decode_gga(wire(GGA_OK))
    assert fix == nmea.GgaFix(44163.0, 31.9, 120.3, 12.5, 1, 8, 0.9)


@pytest.mark.parametrize("body, message", [
    ("GPGGA,121603.00,9100.000000,N,12018.000000,E,1,08,0.9,10.0,M,,M,,",
     "GGA field 2 (latitude): 91 deg is beyond 90"),
    ("GPGGA,121603.00,3161.000000,N,12018.000000,E,1,08,0.9,10.0,M,,M,,",
     "GGA field 2 (latitude): 61 minutes is not below 60"),
    ("GPGGA,126103.00,3154.000000,N,12018.000000,E,1,08,0.9,10.0,M,,M,,",
     "GGA field 1 (UTC time): minute 61 is not below 60"),
    ("GPGGA,121603.00,3154.000000,N,18118.000000,E,1,08,0.9,10.0,M,,M,,",
     "GGA field 4 (longitude): 181.3 deg is beyond 180"),
    ("GPGGA,121603.00,3154.000000,X,12018.000000,E,1,08,0.9,10.0,M,,M,,",
     "GGA field 3 (latitude direction): 'X' is not N or S"),
    ("GPGGA,121603.00,3154.000000,N,12018.000000,E,0,00,,,M,,M,,", "GGA field 6 (fix quality): 0, no fix"),
    ("GPGGA,121603.00,,,,,,,,,M,,M,,", "GGA field 6 (fix quality): empty, no fix"),
])
def test_decode_gga_refuses_nonsense(body, message):
    with pytest.raises(nmea.NmeaError) as e:
        nmea.decode_gga(wire(body))
    assert str(e.value) == message and e.value.kind == "value"


def test_decode_rmc_refuses_void_and_bad_dates():
    with pytest.raises(nmea.NmeaError, match=r"^RMC field 2 \(status\): V, void \(no valid fix\)$"):
        nmea.decode_rmc(wire("GPRMC,121603.00,V,,,,,,,150313,,,N"))
    with pytest.raises(nmea.NmeaError, match=r"^RMC field 9 \(UTC date\): 2013-02-30 does not exist$"):
        nmea.decode_rmc(wire("GPRMC,121603.00,A,3154.0000,N,12018.0000,E,0.0,0.0,300213,,,A"))
    with pytest.raises(nmea.NmeaError, match=r"^RMC field 12 \(mode\): N, data not valid$"):
        nmea.decode_rmc(wire("GPRMC,121603.00,A,3154.0000,N,12018.0000,E,0.0,0.0,150313,,,N"))


def test_decode_zda_values_and_nonsense():
    z = nmea.decode_zda(wire("GPZDA,235959.50,31,12,2016,-05,30"))
    assert z.utc_date == datetime.date(2016, 12, 31) and z.utc_time_of_day_s == 86399.5
    assert z.zone_offset_min == -330
    leap = nmea.decode_zda(wire("GPZDA,235960.50,31,12,2016,00,00"))        # the 2016 leap second
    after = nmea.decode_zda(wire("GPZDA,000000.50,01,01,2017,00,00"))
    dt_s = ((after.utc_jd1 - leap.utc_jd1) + (after.utc_jd2 - leap.utc_jd2)) * 86400
    # ERFA's quasi-JD: the leap day has 86401 s, so 23:59:60.5 is 86400.5 / 86401 of it
    assert dt_s == pytest.approx((0.5 / 86401 + 0.5 / 86400) * 86400, abs=1e-9)
    with pytest.raises(nmea.NmeaError, match=r"^ZDA field 2-4 \(UTC date\): 2013-02-29 does not exist$"):
        nmea.decode_zda(wire("GPZDA,121603.00,29,02,2013,00,00"))
    with pytest.raises(nmea.NmeaError, match="is not a valid UTC date and time"):
        nmea.decode_zda(wire("GPZDA,235960.00,15,03,2013,00,00"))              # no leap second that day
    with pytest.raises(nmea.NmeaError, match=r"^ZDA field 4 \(year\): '13' is not a year$"):
        nmea.decode_zda(wire("GPZDA,121603.00,15,03,13,00,00"))


@pytest.mark.parametrize("body, message", [
    ("WIMDA,0.0,I,0.0,B,11.1,C,,,,,,,,,,,,,,", "MDA field 3 (pressure): 0 hPa is outside 500-1100 hPa"),
    ("WIMDA,,,-1.0,B,11.1,C,,,,,,,,,,,,,,", "MDA field 3 (pressure): -1000 hPa is outside 500-1100 hPa"),
    ("WIMDA,30.0,I,,,11.1,C,,,,,,,,,,,,,,", None),
    ("WIMDA,,,1.0,B,70.0,C,,,,,,,,,,,,,,", "MDA field 5 (air temperature): 70 C is outside -60..+60 C"),
    ("WIMDA,,,1.0,B,11.0,F,,,,,,,,,,,,,,", "MDA field 6 (air temperature unit): 'F' is not C"),
    ("WIMDA,,,1.0,B,11.0,C,,,120,,,,,,,,,,,", "MDA field 9 (relative humidity): 120 % is outside 0-100 %"),
    ("WIXDR,P,-0.5,B,BARO", "XDR field 2 (pressure): -500 hPa is outside 500-1100 hPa"),
    ("WIXDR,P,101325,P,BARO,C,-81,C,T", "XDR field 6 (air temperature): -81 C is outside -60..+60 C"),
    ("WIXDR,A,1.0,D,PITCH", "XDR: no pressure, air temperature or humidity in it"),
    ("WIXDR,P,1.0,B", "XDR: 3 fields, not groups of four (type, value, unit, id)"),
])
def test_decode_weather_refuses_nonsense(body, message):
    decode = nmea.decode_mda if "MDA" in body else nmea.decode_xdr
    if message is None:                                   # inHg only: accepted, converted
        assert decode(wire(body)).pressure_hpa == pytest.approx(30.0 * 33.8639, abs=0.01)
        return
    with pytest.raises(nmea.NmeaError) as e:
        decode(wire(body))
    assert str(e.value) == message


def test_decoders_refuse_other_sentence_types():
    with pytest.raises(nmea.NmeaError, match="^expected a GGA sentence, got HEHDT$"):
        nmea.decode_gga(nmea.hehdt(10.0))


def test_utc_jd_from_date_matches_iso():
    jd = nmea.utc_jd_from_date(datetime.date(2013, 3, 15), 12 * 3600 + 16 * 60 + 3.123456)
    ref = utc_jd_from_iso("2013-03-15T12:16:03.123456")
    assert ((jd[0] - ref[0]) + (jd[1] - ref[1])) * 86400 == pytest.approx(0.0, abs=1e-9)
    assert math.isfinite(jd[0])


def test_udp_destinations_are_resolved_once_at_the_start(capsys, tmp_path):
    """A destination whose host cannot be resolved was accepted: every datagram's send
    failed, counted in the summary but silent (a bad-input sweep); now the start refuses it
    in one line. The .invalid top-level domain never resolves (RFC 2606)."""
    from shipstar.cli import main
    from shipstar.live._outputs import resolve_udp_destination

    assert resolve_udp_destination("127.0.0.1", 10110) == ("127.0.0.1", 10110)
    assert resolve_udp_destination("localhost", 10110) == ("127.0.0.1", 10110)
    with pytest.raises(ShipstarError, match=r"UDP destination nosuchhost.invalid:10110: the host cannot be resolved"):
        resolve_udp_destination("nosuchhost.invalid", 10110)
    import numpy as np

    from shipstar.calibrate.installation import Installation, save_installation

    (tmp_path / "A1").mkdir()
    save_installation(Installation.from_matrix("A1", "A1", np.eye(3)), tmp_path / "A1.toml")
    code = main(["live", "--sensor", f"A1={tmp_path / 'A1'}", "--install", str(tmp_path / "A1.toml"),
                 "--lat-deg", "31.9", "--lon-deg", "120.3", "--pressure-hpa", "1021.7", "--temperature-c", "11.1",
                 "--udp", "nosuchhost.invalid:10110"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "nosuchhost.invalid:10110: the host cannot be resolved" in err[0], err
