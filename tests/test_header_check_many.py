"""HeaderCheck.check_many against the one-frame checks it screens for.

The many-frame check compares every frame's header position and weather with the tables at
once and sends only the frames that may contradict through the one-frame check: with
headers placed right at the tolerances (both sides, within rounding of them), outside the
tables, in a gap, near the date line and at high latitude, it must raise the same first
error, or record the same overrides with --trust-flags, as calling the check on each
frame in order.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from shipstar._fitsio import FitsFrameInfo
from shipstar.errors import ShipstarError
from shipstar.pipeline import Track, WeatherTable
from shipstar.pipeline._header_check import (
    POSITION_TOLERANCE_DEG,
    PRESSURE_TOLERANCE_HPA,
    TEMPERATURE_TOLERANCE_C,
    HeaderCheck,
)
from shipstar.units import DAY_S

JD1 = 2461000.5


def _tables(lat0_deg: float, lon0_deg: float):
    """A track at 1 s rows with a 60 s gap (too long) in it, and a weather table at 10 s rows."""
    t = np.concatenate([np.arange(0.0, 100.0, 1.0), np.arange(160.0, 300.0, 1.0)])
    lat = lat0_deg + 1e-4 * t / 60.0
    lon = lon0_deg + 2e-4 * t / 60.0
    lon = np.remainder(lon + 180.0, 360.0) - 180.0
    track = Track.from_arrays(np.full(t.size, JD1), t / DAY_S, lat, lon, name="track t.csv")
    tw = np.arange(-10.0, 320.0, 10.0)
    from shipstar.pipeline._tables import WeatherTable as W

    weather = W("weather table w.csv", JD1, tw[0] / DAY_S, tw - tw[0], 1012.0 + 0.01 * tw, 8.0 - 0.003 * tw,
                np.zeros(tw.size))
    return track, weather, t


def _infos(rng, track, weather, n: int):
    """Frames whose header values sit at the tolerances (some just over, some under), or
    are absent, at times inside and outside the tables and in the track's gap."""
    out = []
    times = rng.uniform(-40.0, 340.0, n)
    for k, t in enumerate(times):
        jd2 = t / DAY_S
        try:
            site = track.site(JD1, jd2)
            lat, lon = math.degrees(site.lat_rad), math.degrees(site.lon_rad)
        except ShipstarError:
            lat, lon = 40.0, 179.99
        try:
            w = weather.weather(JD1, jd2)
            p, temp = w.pressure_hpa, w.temperature_c
        except ShipstarError:
            p, temp = 1012.0, 8.0
        tol_lon = POSITION_TOLERANCE_DEG / max(math.cos(math.radians(lat)), 1e-3)

        def near(v, tol):
            """None, the value, or the value off by the tolerance times 1 +- 1e-12 .. 1e-3."""
            c = rng.integers(0, 5)
            if c == 0:
                return None
            if c == 1:
                return v
            return v + rng.choice([-1.0, 1.0]) * tol * (1.0 + rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(-12, -3))

        out.append(FitsFrameInfo(f"f{k:04d}.fits", (64, 64), JD1, jd2, "DATE-AVG", "", "start", 0.01, "", "A1", "",
                                 lat_deg=near(lat, POSITION_TOLERANCE_DEG), lon_deg=near(lon, tol_lon),
                                 pressure_hpa=near(p, PRESSURE_TOLERANCE_HPA),
                                 temperature_c=near(temp, TEMPERATURE_TOLERANCE_C)))
    return out


def _one_by_one(check, infos):
    try:
        for info in infos:
            check(info)
    except ShipstarError as exc:
        return str(exc), check.overrides()
    return None, check.overrides()


def _many(check, infos):
    try:
        check.check_many(infos)
    except ShipstarError as exc:
        return str(exc), check.overrides()
    return None, check.overrides()


@pytest.mark.parametrize("lat0, lon0", [(31.9, 120.3), (-62.0, 179.999), (84.5, -179.9995)])
@pytest.mark.parametrize("trust", [False, True])
def test_many_frames_at_once_decide_as_one_by_one(lat0, lon0, trust):
    track, weather, _ = _tables(lat0, lon0)
    rng = np.random.default_rng(int(abs(lat0) * 10) + trust)
    for trial in range(12):
        infos = _infos(rng, track, weather, 40)
        if trial % 3 == 0:                              # a clean session: nothing to report
            infos = [FitsFrameInfo(i.name, i.shape_hw, i.utc_jd1, i.utc_jd2, i.time_source, "", "start", 0.01, "",
                                   "A1", "") for i in infos]

        def make():
            return HeaderCheck(names=("A1",), given_name="--sensor A1", track=track, weather=weather,
                               trust_flags=trust, sensor="A1")
        ref = _one_by_one(make(), infos)
        got = _many(make(), infos)
        assert got == ref


def test_the_first_contradiction_in_file_order_is_raised():
    """A sensor name wrong in frame 7 and a latitude wrong in frame 3: frame 3's, as before."""
    track, weather, _ = _tables(31.9, 120.3)
    infos = []
    for k in range(10):
        site = track.site(JD1, k / DAY_S)
        infos.append(FitsFrameInfo(f"f{k}.fits", (64, 64), JD1, k / DAY_S, "DATE-AVG", "", "start", 0.01, "",
                                   "B9" if k == 7 else "A1", "",
                                   lat_deg=math.degrees(site.lat_rad) + (1.0 if k == 3 else 0.0)))
    check = HeaderCheck(names=("A1",), given_name="--sensor A1", track=track, weather=weather)
    with pytest.raises(ShipstarError, match="frame f3.fits: header SITELAT"):
        check.check_many(infos)


def _agrees(table, values, one_time, t, same):
    """``table.interpolate_many(values, ...)`` at times ``t`` (s) against ``one_time(jd2)``:
    ``same(value, reference)`` where the one-time path covers the time, ``covered`` False
    where it refuses it."""
    got, ok = table.interpolate_many(values, np.full(t.size, JD1), t / DAY_S)
    for tk, v, covered in zip(t, got, ok):
        try:
            ref = one_time(tk / DAY_S)
        except ShipstarError:
            assert not covered
            continue
        assert covered and same(v, ref)


def test_interpolate_many_is_the_one_time_interpolation():
    track, weather, _ = _tables(31.9, 120.3)
    t = np.linspace(-20.0, 320.0, 701)
    _agrees(track, track.lat_rad, lambda jd2: track.site(JD1, jd2).lat_rad, t, lambda v, ref: v == ref)
    # the one-time weather is rounded to 0.01 (its refraction tables are shared)
    _agrees(weather, weather.pressure_hpa, lambda jd2: weather.weather(JD1, jd2).pressure_hpa, t,
            lambda v, ref: round(v, 2) == ref)
    fixed = WeatherTable.constant(1000.0, 5.0)
    v, ok = fixed.interpolate_many(fixed.pressure_hpa, np.array([JD1, JD1 + 9.0]), np.zeros(2))
    assert ok.all() and (v == 1000.0).all()
