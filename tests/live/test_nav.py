"""Live position, time and weather (shipstar.live._nav): the growing tables, the NMEA
receiver on real UDP sockets (127.0.0.1 only) and the CSV tail."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from shipstar.errors import ShipstarError
from shipstar.live._nav import CsvTail, LiveTrack, LiveWeather, NavReceiver, SampleOrderError
from shipstar.pipeline import Track, WeatherTable
from shipstar.sky.time import iso_from_utc_jd, utc_jd_from_iso
from shipstar.units import DAY_S, RAD2DEG

LOCAL = "127.0.0.1"
T0 = utc_jd_from_iso("2013-03-15T12:16:00Z")


def at(seconds: float) -> tuple[float, float]:
    """T0 + seconds as a two-part UTC JD."""
    return T0[0], T0[1] + seconds / DAY_S


def xor_hex(body: str) -> str:
    value = 0
    for ch in body.encode("ascii"):
        value ^= ch
    return "%02X" % value


def wire(body: str, cs: str | None = None) -> str:
    return "$" + body + "*" + (xor_hex(body) if cs is None else cs) + "\r\n"


# -- LiveTrack ---------------------------------------------------------------------------

def test_track_interpolates_linearly_between_fixes():
    track = LiveTrack()
    lat = [31.9, 31.9001, 31.9003]
    lon = [120.3, 120.3002, 120.3003]
    for k in range(3):
        track.add(*at(k), lat[k], lon[k], 10.0 + k)
    for s, i, f in [(0.25, 0, 0.25), (1.0, 1, 0.0), (1.6, 1, 0.6), (2.0, 1, 1.0)]:
        site = track.site(*at(s))
        assert site.lat_rad * RAD2DEG == pytest.approx((1 - f) * lat[i] + f * lat[i + 1], abs=1e-12)
        assert site.lon_rad * RAD2DEG == pytest.approx((1 - f) * lon[i] + f * lon[i + 1], abs=1e-12)
        assert site.height_m == pytest.approx(10.0 + s, abs=1e-9)


def test_track_reads_like_the_pipeline_track():
    jd1, jd2 = zip(*(at(s) for s in (0.0, 1.0, 2.5, 4.0)))
    lat, lon = [10.0, 10.00001, 10.00002, 10.000035], [-20.0, -20.00002, -20.00004, -20.00005]   # ~2.5 m/s
    ref = Track.from_arrays(jd1, jd2, lat, lon, [1.0, 2.0, 3.0, 4.0], xi_arcsec=[4.2] * 4, eta_arcsec=[-7.5] * 4)
    live = LiveTrack()
    for row in zip(jd1, jd2, lat, lon, [1.0, 2.0, 3.0, 4.0]):
        live.add(*row, xi_arcsec=4.2, eta_arcsec=-7.5)
    for s in np.linspace(0.0, 4.0, 17):
        a, b = live.site(*at(s)), ref.site(*at(s))
        for name in ("lat_rad", "lon_rad", "height_m", "xi_rad", "eta_rad"):
            assert getattr(a, name) == pytest.approx(getattr(b, name), abs=1e-13)


def test_track_extrapolates_from_the_ship_velocity_then_refuses():
    track = LiveTrack()                                          # default 5 s
    track.add(*at(-8.2), 31.9, 120.3)
    track.add(*at(-7.2), 31.90001, 120.30002)                    # last fix 12:15:52.8
    site = track.site(*at(-7.2 + 4.0))
    assert site.lat_rad * RAD2DEG == pytest.approx(31.90001 + 4 * 0.00001, abs=1e-11)
    assert site.lon_rad * RAD2DEG == pytest.approx(120.30002 + 4 * 0.00002, abs=1e-11)
    with pytest.raises(ShipstarError) as e:
        track.site(*at(0.0))                                     # 7.2 s after the last fix
    assert str(e.value) == "no position within 5 s of 2013-03-15T12:16:00.000000Z (last fix 7.2 s earlier)"
    with pytest.raises(ShipstarError, match="last fix 7.2 s earlier"):
        track.check_covers(*at(0.0))


def test_track_refuses_times_before_the_first_fix_and_with_one_fix_only():
    track = LiveTrack(max_extrapolation_s=2.0)
    with pytest.raises(ShipstarError, match=r"^no position for 2013-03-15T12:16:00.000000Z \(none received yet\)$"):
        track.site(*T0)
    track.add(*at(3.0), 31.9, 120.3)
    with pytest.raises(ShipstarError) as e:
        track.site(*T0)
    assert str(e.value) == "no position within 2 s of 2013-03-15T12:16:00.000000Z (first kept fix 3.0 s later)"
    assert track.site(*at(3.0)).lat_rad * RAD2DEG == pytest.approx(31.9)
    with pytest.raises(ShipstarError, match="one fix only"):
        track.site(*at(4.0))


def test_track_refuses_older_and_equal_times():
    track = LiveTrack()
    track.add(*at(1.0), 31.9, 120.3)
    for s in (1.0, 0.5):
        with pytest.raises(SampleOrderError, match=r"is not after the newest one \(2013-03-15T12:16:01.000000Z\)"):
            track.add(*at(s), 31.9, 120.3)
    with pytest.raises(ShipstarError, match="latitude"):
        track.add(*at(2.0), 91.0, 120.3)
    assert len(track) == 1 and track.n_refused == 3 and track.n_added == 1


def test_track_memory_is_bounded():
    track = LiveTrack(max_samples=3600)
    for k in range(10_000):
        track.add(*at(k * 0.1), 31.9 + k * 1e-6, 120.3)
    assert len(track) == 3600 and track.n_added == 10_000
    with pytest.raises(ShipstarError, match="first kept fix"):
        track.site(*at(0.0))
    first_kept = (10_000 - 3600) * 0.1
    assert track.site(*at(first_kept)).lat_rad * RAD2DEG == pytest.approx(31.9 + 6400e-6, abs=1e-11)
    assert track.latest()["lat_deg"] == pytest.approx(31.9 + 9999e-6, abs=1e-11)


def test_track_crosses_180_degrees():
    track = LiveTrack()
    track.add(*at(0.0), -10.0, 179.9)
    track.add(*at(1.0), -10.0, -179.9)                           # 0.2 deg east, not 359.8 west
    for s, lon in [(0.25, 179.95), (0.5, 180.0), (0.75, -179.95)]:
        got = track.site(*at(s)).lon_rad * RAD2DEG
        assert got == pytest.approx(lon, abs=1e-9) or (lon == 180.0 and got == pytest.approx(-180.0, abs=1e-9))
    assert track.site(*at(3.0)).lon_rad * RAD2DEG == pytest.approx(-179.5, abs=1e-9)   # extrapolated east


def test_track_is_thread_safe():
    track = LiveTrack(max_samples=50)
    errors = []

    def writer():
        for k in range(2000):
            track.add(*at(k * 0.01), 31.9 + k * 1e-7, 120.3)

    th = threading.Thread(target=writer)
    th.start()
    while th.is_alive():
        last = track.last_utc_jd()
        if last is not None:
            try:
                track.site(*last)
            except ShipstarError as exc:
                # acceptable: the time asked for has already left the 50-fix window (the
                # writer ran on between the two calls: a slow reader on a loaded machine)
                if "first kept fix" not in str(exc):
                    errors.append(str(exc))
    th.join()
    assert not errors and len(track) == 50


# -- LiveWeather -------------------------------------------------------------------------

def test_weather_interpolates_and_rounds_like_the_weather_table():
    p, t, h = [1021.695, 1021.1, 1019.0], [11.11, 11.5, 12.003], [0.0, 0.5, 0.45]
    times = [0.0, 60.0, 150.0]
    live = LiveWeather()
    for row in zip(times, p, t, h):
        live.add(*at(row[0]), *row[1:])
    ref = WeatherTable("weather", T0[0], T0[1], np.array(times), np.array(p), np.array(t), np.array(h))
    for s in (0.0, 13.7, 60.0, 100.01, 150.0):
        assert live.weather(*at(s)) == ref.weather(*at(s))
    w = live.weather(*at(30.0))
    assert (w.pressure_hpa, w.temperature_c, w.relative_humidity) == (1021.4, 11.31, 0.25)   # 1021.3975, 11.305


def test_weather_is_held_then_refused():
    live = LiveWeather()                                        # default 600 s
    live.add(*at(0.0), 1013.0, 10.0)
    live.add(*at(10.0), 1012.0, 12.0)
    w = live.weather(*at(10.0 + 590.0))
    assert (w.pressure_hpa, w.temperature_c) == (1012.0, 12.0)
    with pytest.raises(ShipstarError) as e:
        live.check_covers(*at(710.0))
    assert str(e.value) == ("no weather within 600 s of 2013-03-15T12:27:50.000000Z "
                            "(last reading 700.0 s earlier)")
    with pytest.raises(ShipstarError, match="first kept reading 1.0 s later"):
        live.weather(*at(-1.0))
    with pytest.raises(ShipstarError, match="pressure_hpa"):
        live.add(*at(20.0), -5.0, 10.0)
    assert live.n_refused == 1 and len(live) == 2


# -- NavReceiver -------------------------------------------------------------------------

@pytest.fixture
def receiver():
    track, weather, lines = LiveTrack(), LiveWeather(), []
    rx = NavReceiver(track, weather, host=LOCAL, port=0, on_error=lines.append)
    rx.start()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent = [0]

    def send(*sentences: str):
        tx.sendto("".join(sentences).encode("ascii"), (LOCAL, rx.port))
        sent[0] += 1
        assert rx.wait_datagrams(sent[0], 5.0), "datagram not applied"

    try:
        yield rx, track, weather, lines, send
    finally:
        tx.close()
        rx.stop()


def test_receiver_applies_gga_zda_mda_xdr_and_reports_bad_sentences(receiver):
    rx, track, weather, lines, send = receiver
    gga1 = wire("GPGGA,121600.00,3154.000000,N,12018.000000,E,1,08,0.9,10.0,M,2.0,M,,")
    send(gga1)                                                   # before any date: held
    assert len(track) == 0 and rx.stats()["pending_gga"] == 1
    send(wire("GPZDA,121600.50,15,03,2013,00,00"))               # the date arrives: applied
    assert len(track) == 1
    fix = track.latest()
    assert (fix["lat_deg"], fix["lon_deg"], fix["height_m"]) == (pytest.approx(31.9), pytest.approx(120.3), 12.0)
    assert iso_from_utc_jd(fix["utc_jd1"], fix["utc_jd2"], 6) == "2013-03-15T12:16:00.000000Z"

    send(wire("GPGGA,121601.00,3154.006000,N,12018.012000,E,1,08,0.9,10.0,M,2.0,M,,"),
         wire("WIMDA,30.1706,I,1.02170,B,11.11,C,,,45.0,,,,,,,,,,,"))
    site = track.site(*at(0.5))
    assert site.lat_rad * RAD2DEG == pytest.approx(31.9 + 0.5 * 0.0001, abs=1e-10)
    assert site.lon_rad * RAD2DEG == pytest.approx(120.3 + 0.5 * 0.0002, abs=1e-10)
    assert len(weather) == 1
    stamp = weather.last_utc_jd()
    w = weather.weather(*stamp)
    assert (w.pressure_hpa, w.temperature_c, w.relative_humidity) == (1021.7, 11.11, 0.45)
    age_s = ((stamp[0] - at(1.0)[0]) + (stamp[1] - at(1.0)[1])) * DAY_S
    assert 0.0 <= age_s < 2.0                                    # stamped with the navigation clock

    send(wire("WIXDR,P,1.01500,B,BARO"))                         # new pressure, temperature kept
    assert len(weather) == 2
    w = weather.weather(*weather.last_utc_jd())
    assert (w.pressure_hpa, w.temperature_c, w.relative_humidity) == (1015.0, 11.11, 0.45)

    body = "GPGGA,121602.00,3154.012000,N,12018.024000,E,1,08,0.9,10.0,M,2.0,M,,"
    send(wire(body, "00"))
    send(wire("GPGGA,121602.00,9100.000000,N,12018.024000,E,1,08,0.9,10.0,M,2.0,M,,"))
    send(wire("WIMDA,,,0.0,B,11.1,C,,,,,,,,,,,,,,"))
    send(wire("GPGGA,121600.50,3154.000000,N,12018.000000,E,1,08,0.9,10.0,M,2.0,M,,"))   # older
    send("hello\r\n", wire("GPVTG,,T,,M,0.0,N,0.0,K,A"))
    assert len(track) == 2 and len(weather) == 2
    assert len(lines) == 5, lines
    assert lines[0].startswith("nav UDP: bad checksum in '$GPGGA,121602.00,")
    assert lines[0].endswith(f"(expected {xor_hex(body)}, got 00)")
    assert lines[1].startswith("nav UDP: GGA field 2 (latitude): 91 deg is beyond 90 in '$GPGGA,121602.00,9100")
    assert lines[2].startswith("nav UDP: MDA field 3 (pressure): 0 hPa is outside 500-1100 hPa in '$WIMDA,")
    assert lines[3].startswith("nav UDP: live track: fix at 2013-03-15T12:16:00.500000Z is not after the newest "
                               "one (2013-03-15T12:16:01.000000Z); refused in '$GPGGA,121600.50")
    assert lines[4] == "nav UDP: no '$' at the start of 'hello'"
    assert all("\n" not in line for line in lines)
    stats = rx.stats()
    assert stats["sentences"] == {"GGA": 4, "ZDA": 1, "MDA": 2, "XDR": 1, "VTG": 1}
    assert stats["errors"] == {"checksum": 1, "value": 2, "order": 1, "no-start": 1}
    assert stats["datagrams"] == 9


def test_receiver_dates_gga_across_midnight_and_skips_duplicate_epochs(receiver):
    rx, track, weather, lines, send = receiver
    send(wire("GPZDA,235959.50,15,03,2013,00,00"))
    send(wire("GPGGA,235959.90,3154.000000,N,12018.000000,E,1,08,0.9,0.0,M,,M,,"),
         wire("GPRMC,235959.90,A,3154.000000,N,12018.000000,E,0.0,0.0,150313,,,A"))   # one epoch, twice
    send(wire("GPGGA,000000.90,3154.000000,N,12018.000000,E,1,08,0.9,0.0,M,,M,,"))
    assert len(track) == 2 and not lines
    fix = track.latest()
    assert iso_from_utc_jd(fix["utc_jd1"], fix["utc_jd2"], 6) == "2013-03-16T00:00:00.900000Z"


def test_receiver_rmc_void_is_reported(receiver):
    rx, track, weather, lines, send = receiver
    send(wire("GPRMC,121603.00,V,,,,,,,150313,,,N"))
    assert lines == ["nav UDP: RMC field 2 (status): V, void (no valid fix) in '$GPRMC,121603.00,V,,,,,,,150313,,,N*"
                     + xor_hex("GPRMC,121603.00,V,,,,,,,150313,,,N") + "'"]
    assert len(track) == 0


def test_receiver_holds_weather_and_gga_until_dated_and_bounds_what_it_holds():
    track, weather, lines = LiveTrack(), LiveWeather(), []

    def on_error(line):
        lines.append(line)
        raise RuntimeError("a callback that fails must not stop the receiver")

    with NavReceiver(track, weather, host=LOCAL, port=0, on_error=on_error, max_pending=2) as rx, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        datagrams = [wire("WIXDR,P,1.01300,B,BARO,C,10.00,C,AIRT")]
        datagrams += [wire(f"GPGGA,12160{k}.00,3154.000000,N,12018.000000,E,1,08,0.9,0.0,M,,M,,") for k in range(5)]
        for d in datagrams:
            tx.sendto(d.encode("ascii"), (LOCAL, rx.port))
        assert rx.wait_datagrams(len(datagrams), 5.0)
        assert len(track) == 0 and len(weather) == 0 and rx.stats()["pending_gga"] == 2
        assert lines == ["nav UDP: GGA at 44160.00 s of day dropped: no date yet (needs ZDA or RMC), 2 held"]
        assert rx.stats()["errors"] == {"no-date": 3}
        tx.sendto(wire("GPZDA,121605.00,15,03,2013,00,00").encode("ascii"), (LOCAL, rx.port))
        assert rx.wait_datagrams(len(datagrams) + 1, 5.0)
        assert len(track) == 2                                   # the two newest held GGAs, 12:16:03 and :04
        assert iso_from_utc_jd(*track.last_utc_jd(), 6) == "2013-03-15T12:16:04.000000Z"
        assert len(weather) == 1                                 # stamped once the clock is known
        w = weather.weather(*weather.last_utc_jd())
        assert (w.pressure_hpa, w.temperature_c) == (1013.0, 10.0)


def test_second_receiver_on_the_same_port_fails_with_one_line():
    with NavReceiver(LiveTrack(), host=LOCAL, port=0) as first:
        second = NavReceiver(LiveTrack(), host=LOCAL, port=first.port)
        with pytest.raises(ShipstarError) as e:
            second.start()
        assert str(e.value) == f"UDP port {first.port} on 127.0.0.1 is in use"
        second.stop()                                            # never started: nothing to do


def test_stop_returns_promptly_and_closes_the_port():
    rx = NavReceiver(LiveTrack(), host=LOCAL, port=0).start()
    port = rx.port
    t = time.perf_counter()
    rx.stop()
    assert time.perf_counter() - t < 0.5
    rx.stop()                                                    # idempotent
    again = NavReceiver(LiveTrack(), host=LOCAL, port=port).start()   # the port is free again
    again.stop()


# -- CsvTail -----------------------------------------------------------------------------

def test_csv_tail_reads_complete_lines_only(tmp_path):
    path = tmp_path / "track.csv"
    track, lines = LiveTrack(), []
    tail = CsvTail(path, track, on_error=lines.append)
    assert tail.poll() == 0                                      # no file yet
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("# live track\ntime_utc,lat_deg,lon_deg,height_m\n2013-03-15T12:16:00.000000Z,31.9,120.3,5.0\n"
                 "2013-03-15T12:16:01.000000Z,31.9001,12")
    assert tail.poll() == 1 and len(track) == 1
    with open(path, "a", encoding="utf-8") as fh:
        fh.write("0.3002,7.0\n2013-03-15T12:16:02")
    assert tail.poll() == 1 and len(track) == 2
    site = track.site(*at(0.5))
    assert site.lat_rad * RAD2DEG == pytest.approx(31.90005, abs=1e-11)
    assert site.lon_rad * RAD2DEG == pytest.approx(120.3001, abs=1e-11)
    assert site.height_m == pytest.approx(6.0)
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(".000000Z,x,120.3,0\n# comment\n2013-03-15T12:16:00.500000Z,31.9,120.3,0\n"
                 "2013-03-15T12:16:03.000000Z,31.9003,120.3004\n2013-03-15T12:16:04.000000Z,31.9004,120.3005,1.0\n")
    assert tail.poll() == 1 and len(track) == 3
    assert lines == [
        f"{path} line 5: lat_deg is not a number: 'x'",
        f"{path} line 7: live track: fix at 2013-03-15T12:16:00.500000Z is not after the newest one "
        "(2013-03-15T12:16:01.000000Z); refused",
        f"{path} line 8: 3 fields, the header has 4",
    ]
    assert tail.n_errors == 3 and tail.n_rows == 3
    assert tail.poll() == 0


def test_csv_tail_weather_and_a_bad_header(tmp_path):
    path = tmp_path / "weather.csv"
    weather = LiveWeather()
    path.write_text("time_utc,pressure_hpa,temperature_c\n2013-03-15T12:16:00Z,1021.695,11.11\n")
    tail = CsvTail(path, weather)
    assert tail.poll() == 1
    w = weather.weather(*T0)
    assert (w.pressure_hpa, w.temperature_c, w.relative_humidity) == (1021.7, 11.11, 0.0)
    bad = tmp_path / "bad.csv"
    bad.write_text("time_utc,pressure_hpa\n2013-03-15T12:16:00Z,1021.695\n")
    tail = CsvTail(bad, LiveWeather())
    for _ in range(2):
        with pytest.raises(ShipstarError) as e:
            tail.poll()
        assert str(e.value) == f"{bad}: missing column 'temperature_c' (need time_utc, pressure_hpa, temperature_c)"


def test_csv_tail_of_a_binary_file_is_one_error_and_a_byte_order_mark_is_skipped(tmp_path):
    """A binary file given as the table: one error, as a bad header (was one "not UTF-8
    text" line each, 595 lines before the command's error; found by a bad-input sweep)."""
    binary = tmp_path / "random.bin"
    binary.write_bytes(bytes(range(128, 256)) * 40 + b"\n" + bytes(range(200, 256)) * 30 + b"\n")
    errors = []
    tail = CsvTail(binary, LiveWeather(), on_error=errors.append)
    for _ in range(2):
        with pytest.raises(ShipstarError, match=r"random.bin line 1: not UTF-8 text, so not a CSV table \(need a "
                                                r"header line time_utc, pressure_hpa, temperature_c\)"):
            tail.poll()
    assert errors == []
    path = tmp_path / "weather.csv"
    path.write_bytes(b"\xef\xbb\xbftime_utc,pressure_hpa,temperature_c\n2013-03-15T12:16:00Z,1021.695,11.11\n")
    weather = LiveWeather()
    assert CsvTail(path, weather, on_error=errors.append).poll() == 1 and errors == []
    assert weather.weather(*T0).pressure_hpa == 1021.7
