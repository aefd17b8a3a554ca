"""Earth orientation and UTC parsing (shipstar.sky.eop, shipstar.sky.time).

References: astropy's own reader of the same IERS-A file (``iers.IERS_A``, test only),
astropy's leap-second table, the measured IERS series itself (back-test of the
extrapolation error model), and hand-computed Julian dates.
"""

from __future__ import annotations

import dataclasses
import math
import os

import numpy as np
import pytest

from shipstar.errors import AccuracyWarning, ShipstarError
from shipstar.sky import eop as eop_mod
from shipstar.sky.eop import EarthOrientation, earth_orientation, eop_table_info
from shipstar.sky.time import (
    iso_from_utc_jd,
    leap_second_table_expiry_mjd,
    utc_jd_from_iso,
    ut1_jd_from_utc_jd,
)
from shipstar.units import ASEC2RAD, DAY_S, RAD2ASEC

MJD0 = 2400000.5


def _jd(mjd):
    day = math.floor(mjd)
    return MJD0 + day, mjd - day


# ---------------------------------------------------------------------------------------
# Time parsing
# ---------------------------------------------------------------------------------------

def test_utc_jd_from_iso_hand_computed():
    # 2013-03-15 0h UTC is JD 2456366.5; 12:16 is 736 min = 0.511111... d.
    jd1, jd2 = utc_jd_from_iso("2013-03-15T12:16:00")
    assert jd1 + jd2 == pytest.approx(2456366.5 + 736.0 / 1440.0, abs=1e-10)
    jd1, jd2 = utc_jd_from_iso("2000-01-01T12:00:00Z")
    assert jd1 + jd2 == pytest.approx(2451545.0, abs=1e-10)


@pytest.mark.parametrize("text", [
    "2013-03-15T12:16:00.25Z", "2016-12-31T23:59:60.5", "1999-07-04 03:05:09.123456",
    "2026-11-21T05:33:04+00:00",
])
def test_utc_jd_from_iso_matches_astropy(text):
    from astropy.time import Time

    ref = Time(text.replace("+00:00", "").rstrip("Z"), scale="utc", precision=6)
    jd1, jd2 = utc_jd_from_iso(text)
    assert (jd1 - ref.jd1) + (jd2 - ref.jd2) == pytest.approx(0.0, abs=1e-11)
    back = iso_from_utc_jd(jd1, jd2, 3)
    assert back[:19] == ref.isot[:19]


@pytest.mark.parametrize("text", [
    "2013-03-15", "15/03/2013 12:16", "2013-02-30T00:00:00", "2013-03-15T25:00:00",
    "2015-12-31T23:59:60", "2013-03-15T12:16:00+08:00", "nan", "", "2013-03-15T12:16:61",
])
def test_utc_jd_from_iso_rejects(text):
    with pytest.raises(ShipstarError, match="time"):
        utc_jd_from_iso(text)


def test_tt_and_ut1_match_erfa_including_leap_second_days():
    import erfa

    from shipstar.sky.time import quiet_dubious_year, tai_minus_utc_s, tt_jd_from_utc_jd

    rng = np.random.default_rng(5)
    mjds = np.concatenate([rng.uniform(41317.0, 62500.0, 400),
                           [57753.25, 57753.99999, 57754.0, 41498.999, 41499.0, 40000.3]])
    for mjd in mjds:
        jd = _jd(mjd)
        with quiet_dubious_year():
            tt_ref = erfa.taitt(*erfa.utctai(*jd))
            ut1_ref = erfa.utcut1(*jd, -0.3)
            dat_ref = erfa.dat(*erfa.jd2cal(*jd))
        tt, ut1 = tt_jd_from_utc_jd(*jd), ut1_jd_from_utc_jd(*jd, -0.3)
        assert abs((tt[0] - tt_ref[0]) + (tt[1] - tt_ref[1])) * DAY_S < 1e-9
        assert abs((ut1[0] - ut1_ref[0]) + (ut1[1] - ut1_ref[1])) * DAY_S < 1e-9
        assert tai_minus_utc_s(mjd) == pytest.approx(dat_ref, abs=1e-12)
    assert np.allclose(tai_minus_utc_s(mjds), [tai_minus_utc_s(m) for m in mjds], atol=1e-12)


def test_leap_second_expiry_matches_astropy():
    from astropy.utils import iers

    table = iers.LeapSeconds.from_iers_leap_seconds(iers.IERS_LEAP_SECOND_FILE)
    assert leap_second_table_expiry_mjd() == pytest.approx(table.expires.mjd, abs=1e-9)


# ---------------------------------------------------------------------------------------
# Interpolation inside the table
# ---------------------------------------------------------------------------------------

def test_interpolation_matches_astropy_iers_a(astropy_iers_a):
    info = eop_table_info()
    rng = np.random.default_rng(20130315)
    mjd = np.concatenate([
        rng.uniform(info.first_mjd, info.leap_second_expiry_mjd - 1.0, 300),
        [57753.5, 57753.99999, 57754.0, 57754.25, 51178.9, info.last_measured_mjd + 0.3],
    ])
    jd1 = np.floor(mjd) + MJD0
    jd2 = mjd - np.floor(mjd)
    ref_ut1 = astropy_iers_a.ut1_utc(jd1, jd2).to_value("s")
    ref_x, ref_y = (c.to_value("arcsec") for c in astropy_iers_a.pm_xy(jd1, jd2))
    got = [earth_orientation(a, b) for a, b in zip(jd1, jd2)]
    assert np.max(np.abs([g.dut1_s for g in got] - ref_ut1)) < 1e-9
    assert np.max(np.abs([g.xp_rad * RAD2ASEC for g in got] - ref_x)) < 1e-9
    assert np.max(np.abs([g.yp_rad * RAD2ASEC for g in got] - ref_y)) < 1e-9


def test_quality_follows_the_table_flags(astropy_iers_a):
    """'measured' iff both bracketing rows are I or B for UT1 and polar motion."""
    table = astropy_iers_a
    mjd_rows = np.asarray(table["MJD"].to_value("d"))
    flags_ok = (np.asarray(table["UT1Flag"]) != "P") & (np.asarray(table["PolPMFlag"]) != "P")
    first_p = int(np.argmin(flags_ok))
    for j in (100, first_p - 3, first_p - 1, first_p, first_p + 10):
        mjd = mjd_rows[j] + 0.5
        expected = "measured" if flags_ok[j] and flags_ok[j + 1] else "predicted"
        eop = earth_orientation(*_jd(mjd))
        assert eop.quality == expected, (j, mjd)
    eop = earth_orientation(*_jd(mjd_rows[first_p] + 30.5))
    assert eop.quality == "predicted" and eop.dut1_error_s > 1e-3


def test_ut1_is_continuous_across_a_leap_second():
    """2016-12-31T23:59:60 was a leap second: UT1-UTC jumps +1 s, UT1 does not."""
    before = utc_jd_from_iso("2016-12-31T23:59:59.5")
    after = utc_jd_from_iso("2017-01-01T00:00:00.5")
    e0, e1 = earth_orientation(*before), earth_orientation(*after)
    assert e1.dut1_s - e0.dut1_s == pytest.approx(1.0, abs=1e-5)
    u0 = ut1_jd_from_utc_jd(*before, e0.dut1_s)
    u1 = ut1_jd_from_utc_jd(*after, e1.dut1_s)
    # 2 SI seconds elapse (23:59:59.5 -> :60 -> 00:00:00.5); UT1 runs at the same rate.
    assert ((u1[0] - u0[0]) + (u1[1] - u0[1])) * DAY_S == pytest.approx(2.0, abs=1e-4)


# ---------------------------------------------------------------------------------------
# Outside the table
# ---------------------------------------------------------------------------------------

def test_extrapolation_is_continuous_and_warns():
    info = eop_table_info()
    with pytest.warns(AccuracyWarning, match="no leap second is known"):
        inside = earth_orientation(*_jd(info.last_mjd))
    with pytest.warns(AccuracyWarning) as record:
        outside = earth_orientation(*_jd(info.last_mjd + 1.0 / 1440.0))
    assert any("extrapolated" in str(w.message) for w in record)
    assert outside.quality == "extrapolated"
    assert outside.dut1_s == pytest.approx(inside.dut1_s, abs=1e-5)
    assert outside.xp_rad == pytest.approx(inside.xp_rad, abs=1e-3 * ASEC2RAD)
    assert outside.yp_rad == pytest.approx(inside.yp_rad, abs=1e-3 * ASEC2RAD)
    assert outside.dut1_error_s == pytest.approx(inside.dut1_error_s, rel=0.01)


def test_extrapolation_warning_states_the_error():
    jd = utc_jd_from_iso("2030-01-01T00:00:00")
    with pytest.warns(AccuracyWarning) as record:
        eop = earth_orientation(*jd)
    text = " ".join(str(w.message) for w in record)
    assert f"{eop.dut1_error_s:.3f} s" in text
    assert f"{eop.dut1_error_s * 15.0 * 1.0027379:.2f} arcsec" in text
    assert "leap second" in text
    assert eop.quality == "extrapolated"
    # Errors grow with time past the table.
    with pytest.warns(AccuracyWarning):
        later = earth_orientation(*utc_jd_from_iso("2030-06-01T00:00:00"))
    assert later.dut1_error_s > eop.dut1_error_s > 0.1
    assert later.polar_motion_error_rad > eop.polar_motion_error_rad


def _truncated(table, end_mjd):
    keep = table.mjd <= end_mjd
    return dataclasses.replace(table, **{
        f.name: getattr(table, f.name)[keep] for f in dataclasses.fields(table)
        if isinstance(getattr(table, f.name), np.ndarray)})


def test_extrapolation_error_model_backtest():
    """Cut the measured series at many dates, extrapolate, compare with what happened.

    The stated (rms) errors must match the actual rms errors within a factor 1.6 for UT1
    and be an upper bound (within 2x) for polar motion.
    """
    full = eop_mod._table()
    measured_end = eop_table_info().last_measured_mjd
    for days in (100.0, 365.0, 730.0):
        err_ut1, err_pm, est_ut1, est_pm = [], [], [], []
        for cut in np.arange(49700.0, measured_end - days, 150.0):
            table = _truncated(full, cut)
            eop_mod._extrapolation_model.cache_clear()
            ut1_tai, xp, yp, e_ut1, e_pm = eop_mod._extrapolated_values(table, cut + days)
            i = int(np.searchsorted(full.mjd, cut + days))
            err_ut1.append(ut1_tai - full.ut1_tai_s[i])
            err_pm.append(np.hypot(xp - full.xp_arcsec[i], yp - full.yp_arcsec[i]) / math.sqrt(2))
            est_ut1.append(e_ut1)
            est_pm.append(e_pm)
        eop_mod._extrapolation_model.cache_clear()
        rms_ut1 = math.sqrt(np.mean(np.square(err_ut1)))
        rms_pm = math.sqrt(np.mean(np.square(err_pm)))
        assert 1 / 1.6 < np.mean(est_ut1) / rms_ut1 < 1.6, (days, rms_ut1, np.mean(est_ut1))
        assert 1.0 < np.mean(est_pm) / rms_pm < 2.0, (days, rms_pm, np.mean(est_pm))


def test_refuses_before_the_table_and_past_the_horizon():
    with pytest.raises(ShipstarError, match="before the start of the IERS"):
        earth_orientation(*utc_jd_from_iso("1972-06-30T00:00:00"))
    horizon = eop_table_info().horizon_mjd
    with pytest.raises(ShipstarError, match="too far past the end of the IERS table"):
        earth_orientation(*_jd(horizon + 1.0))
    with pytest.warns(AccuracyWarning):
        near = earth_orientation(*_jd(horizon - 1.0))
    assert near.dut1_error_s <= eop_mod.MAX_DUT1_ERROR_S
    with pytest.raises(ShipstarError, match="finite"):
        earth_orientation(float("nan"), 0.0)


@pytest.mark.parametrize("kwargs, match", [
    ({"dut1_s": float("nan")}, "finite"),
    ({"dut1_s": 1.5}, "0.9 s"),
    ({"xp_rad": 5 * ASEC2RAD}, "not physical"),
    ({"quality": "guessed"}, "quality"),
    ({"dut1_error_s": -1.0}, ">= 0"),
])
def test_earth_orientation_validation(kwargs, match):
    base = dict(dut1_s=0.1, xp_rad=0.1 * ASEC2RAD, yp_rad=0.3 * ASEC2RAD, quality="measured",
                dut1_error_s=1e-5)
    base.update(kwargs)
    with pytest.raises(ShipstarError, match=match):
        EarthOrientation(**base)


# ---------------------------------------------------------------------------------------
# The table's identity (what a worker of another machine checks)
# ---------------------------------------------------------------------------------------

def altered_table_copy(path, *, change_ut1: bool):
    """A copy of the packaged IERS-A table at ``path``: byte for byte, or with its first
    row's UT1 - UTC (1973, Bulletin B: the value used) 0.1 ms larger."""
    from pathlib import Path

    from astropy_iers_data import IERS_A_FILE

    raw = Path(IERS_A_FILE).read_bytes()
    if change_ut1:
        first, rest = raw.split(b"\n", 1)
        field = first[154:165]
        assert field.strip() == b".8075000"
        first = first[:154] + field.replace(b".8075000", b".8076000") + first[165:]
        raw = first + b"\n" + rest
    path.write_bytes(raw)
    return path


def test_the_tables_identity_is_its_content_not_its_place(tmp_path, monkeypatch):
    monkeypatch.delenv(eop_mod.EOP_FILE_ENV, raising=False)
    packaged_source, packaged = eop_mod.eop_identity()
    try:
        same = altered_table_copy(tmp_path / "same.all", change_ut1=False)
        eop_mod.set_eop_file(same)
        source, digest = eop_mod.eop_identity()
        assert source == str(same) and digest == packaged and source != packaged_source
        other = altered_table_copy(tmp_path / "other.all", change_ut1=True)
        eop_mod.set_eop_file(other)
        assert eop_mod.eop_identity() == (str(other), eop_mod.eop_identity()[1])
        assert eop_mod.eop_identity()[1] != packaged                  # 0.1 ms of UT1 in 1973
    finally:
        eop_mod.set_eop_file(None)
    assert eop_mod.eop_identity() == (packaged_source, packaged)


def test_a_parsed_table_is_kept_by_its_content_and_read_back_whole(tmp_path, monkeypatch):
    """The parsed columns are kept in the cache directory by the file's content: a process
    reading the same bytes (at any path) gets the very columns the parse gave, without
    parsing; a damaged kept file is parsed again; a changed table is another file; only
    the three most recent are kept."""
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv(eop_mod.EOP_FILE_ENV, raising=False)
    same = altered_table_copy(tmp_path / "same.all", change_ut1=False)
    parsed = eop_mod._parse_finals(str(same))
    eop_mod._table.cache_clear()
    try:
        eop_mod._table(str(same))                                       # parsed and kept
        kept = sorted((tmp_path / "cache").glob("eop_v*_*.npz"))
        assert len(kept) == 1
        eop_mod._table.cache_clear()
        moved = (tmp_path / "moved.all")
        moved.write_bytes(same.read_bytes())
        monkeypatch.setattr(eop_mod, "_parse_finals", lambda *a: pytest.fail("parsed again"))
        table = eop_mod._table(str(moved))
        assert table.source == str(moved)
        for name in eop_mod._COLUMNS:
            a, b = getattr(table, name), getattr(parsed, name)
            assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), name
        monkeypatch.undo()
        monkeypatch.setenv("SHIPSTAR_CACHE_DIR", str(tmp_path / "cache"))
        kept[0].write_bytes(kept[0].read_bytes()[:1000])                # damaged: parsed again
        eop_mod._table.cache_clear()
        calls = []
        real = eop_mod._parse_finals
        monkeypatch.setattr(eop_mod, "_parse_finals", lambda *a: calls.append(a[0]) or real(*a))
        assert np.array_equal(eop_mod._table(str(same)).ut1_tai_s, parsed.ut1_tai_s) and calls == [str(same)]
        for k in range(3):                                              # other tables: other files
            other = altered_table_copy(tmp_path / f"other{k}.all", change_ut1=True)
            with open(other, "ab") as fh:
                fh.write(b"\n" * (k + 1))                               # blank lines: other bytes
            eop_mod._table(str(other))
        assert len(list((tmp_path / "cache").glob("eop_v*_*.npz"))) == 3
        assert eop_mod._table(str(other)).ut1_tai_s[0] != parsed.ut1_tai_s[0]
    finally:
        eop_mod._table.cache_clear()


def test_a_table_with_text_in_a_number_column_is_refused_and_not_kept(tmp_path, monkeypatch):
    """A number column holding text (or a number that is not finite) is refused by a
    one-line error naming the file, line and columns; nothing is kept or put in use."""
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv(eop_mod.EOP_FILE_ENV, raising=False)
    garbage = tmp_path / "garbage.bin"
    garbage.write_bytes(b"garbage\x00\x01")
    lines = altered_table_copy(tmp_path / "real.all", change_ut1=False).read_bytes().split(b"\n")
    bad_mjd, bad_ut1 = list(lines), list(lines)
    bad_mjd[1000] = bad_mjd[1000][:7] + b"  5xx.ab" + bad_mjd[1000][15:]
    bad_ut1[5] = bad_ut1[5][:58] + b"     1e999" + bad_ut1[5][68:]
    (tmp_path / "mjd.all").write_bytes(b"\n".join(bad_mjd))
    (tmp_path / "ut1.all").write_bytes(b"\n".join(bad_ut1))
    for name, where in [("garbage.bin", r"line 1, columns 8-15: '\\x00\\x01' is not a number"),
                        ("mjd.all", "line 1001, columns 8-15: '5xx.ab' is not a number"),
                        ("ut1.all", "line 6, columns 59-68: '1e999' is not a number")]:
        for _ in range(2):                                              # refused again: not cached
            with pytest.raises(ShipstarError, match=f"{name} is not a daily finals2000A table: {where}") as err:
                eop_mod.set_eop_file(tmp_path / name)
            assert "\n" not in str(err.value)
    assert eop_mod.EOP_FILE_ENV not in os.environ
    assert not list((tmp_path / "cache").glob("eop_v*_*.npz"))
    for path, what in ((tmp_path, "a directory, not a file"), (tmp_path / "missing.all", "no such file")):
        with pytest.raises(ShipstarError, match=f"IERS table {path}: {what}$"):   # a folder was "no such file"
            eop_mod.set_eop_file(path)
