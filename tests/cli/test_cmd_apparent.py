"""``shipstar apparent`` run as a subprocess (what a user types).

Reference for the numbers: astropy's AltAz frame (test only, offline IERS-A table) with
the same refraction constants (ERFA's ``refco``), for ``--refraction erfa``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from shipstar.units import ASEC2RAD, DEG2RAD

DOCK = ["--time", "2013-03-15T12:16:00", "--lat-deg", "31.9", "--lon-deg", "120.3"]
SIRIUS, BETELGEUSE, VEGA, CANOPUS = 32349, 27989, 91262, 30438


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    e = dict(os.environ)
    e["SHIPSTAR_CACHE_DIR"] = str(tmp_path_factory.mktemp("shipstar_cache"))
    return e


def _run(env, *args):
    return subprocess.run([sys.executable, "-m", "shipstar", "apparent", *args], env=env,
                          capture_output=True, text=True, timeout=120)


def _json(env, *args):
    proc = _run(env, *args, "--json")
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_readme_quick_start_prints_a_table(env):
    proc = _run(env, *DOCK, "--mag-limit", "2", "--pressure-hpa", "1021.7", "--temperature-c", "11.1")
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert "Earth orientation: measured" in out and "refraction: erfa, 1021.7 hPa, 11.1 C" in out
    rows = [line.split() for line in out.splitlines() if line.strip() and line.split()[0].isdigit()]
    hips = [int(r[0]) for r in rows]
    assert SIRIUS in hips and BETELGEUSE in hips
    assert all(float(r[1]) <= 2.0 for r in rows)                   # Hp within the limit
    assert all(5.0 <= float(r[3]) <= 90.0 for r in rows)            # observed, above 5 deg
    assert CANOPUS not in hips and "omitted" in out                 # Canopus is at 3.3 deg
    assert proc.stderr == ""


def test_json_matches_astropy_altaz_with_erfa_refraction(env, monkeypatch):
    from astropy import units as u
    from astropy.coordinates import AltAz, EarthLocation, SkyCoord
    from astropy.time import Time
    from astropy.utils import iers

    from shipstar.sky.catalog import load_hipparcos

    out = _json(env, *DOCK, "--height-m", "8", "--hip", str(SIRIUS), str(BETELGEUSE),
                "--refraction", "erfa", "--pressure-hpa", "1021.7", "--temperature-c", "11.1",
                "--relative-humidity", "0.5")
    assert [s["hip"] for s in out["stars"]] == [SIRIUS, BETELGEUSE]
    assert out["eop"]["quality"] == "measured" and abs(out["eop"]["dut1_s"] - 0.1836) < 1e-3
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", env["SHIPSTAR_CACHE_DIR"])
    cat = load_hipparcos()
    cat = cat.subset(cat.index_of_hip([SIRIUS, BETELGEUSE]))
    with iers.conf.set_temp("auto_download", False), iers.conf.set_temp("auto_max_age", None), \
            iers.earth_orientation_table.set(iers.IERS_A.open(iers.IERS_A_FILE)):
        t = Time("2013-03-15T12:16:00", scale="utc")
        sc = SkyCoord(ra=cat.ra_rad * u.rad, dec=cat.dec_rad * u.rad,
                      pm_ra_cosdec=cat.pm_ra_cosdec_mas_per_yr * u.mas / u.yr,
                      pm_dec=cat.pm_dec_mas_per_yr * u.mas / u.yr,
                      distance=(1000.0 / cat.parallax_mas) * u.pc,
                      radial_velocity=cat.rv_km_s * u.km / u.s,
                      obstime=Time(2451545.0, format="jd", scale="tt")).apply_space_motion(t)
        aa = sc.transform_to(AltAz(
            obstime=t, location=EarthLocation.from_geodetic(120.3 * u.deg, 31.9 * u.deg, 8 * u.m),
            pressure=1021.7 * u.hPa, temperature=11.1 * u.deg_C, relative_humidity=0.5,
            obswl=0.55 * u.micron))
    for star, az, alt in zip(out["stars"], aa.az.deg, aa.alt.deg):
        assert star["refracted"] and not star["below_horizon"]
        d_el = (star["el_deg"] - alt) * DEG2RAD
        d_az = (star["az_deg"] - az) * DEG2RAD * np.cos(alt * DEG2RAD)
        assert np.hypot(d_el, d_az) < 0.05 * ASEC2RAD


def test_named_stars_below_the_horizon_are_flagged(env):
    out = _json(env, *DOCK, "--hip", str(VEGA), str(SIRIUS))
    vega, sirius = out["stars"]
    assert vega["hip"] == VEGA and vega["el_deg"] < 0
    assert vega["below_horizon"] and not vega["refracted"]
    assert sirius["refracted"] and not sirius["below_horizon"]
    assert set(out) >= {"stars", "eop"} and set(out["eop"]) >= {"quality", "dut1_s"}


def test_refraction_none_gives_low_stars_unrefracted(env):
    out = _json(env, *DOCK, "--hip", str(CANOPUS), "--refraction", "none")
    (canopus,) = out["stars"]
    assert 0.0 < canopus["el_deg"] < 5.0 and not canopus["refracted"]


def test_extrapolated_time_warns_and_reports_quality(env):
    proc = _run(env, "--time", "2030-01-01T00:00:00", "--lat-deg", "-33.9", "--lon-deg", "18.4",
                "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["eop"]["quality"] == "extrapolated" and out["eop"]["dut1_error_s"] > 0.1
    assert out["warnings"] and "Traceback" not in proc.stderr
    assert all(line.startswith("shipstar apparent: warning: ") for line in proc.stderr.splitlines())
    assert "estimated error" in proc.stderr


@pytest.mark.parametrize("args, needle", [
    (["--time", "2013-03-15T12:16:00", "--lat-deg", "91", "--lon-deg", "120.3"], "latitude"),
    (["--time", "2013-03-15T12:16:00", "--lat-deg", "nan", "--lon-deg", "120.3"], "finite"),
    (["--time", "2013-03-15 noon", "--lat-deg", "31.9", "--lon-deg", "120.3"], "ISO 8601"),
    (["--time", "2035-01-01T00:00:00", "--lat-deg", "31.9", "--lon-deg", "120.3"], "IERS table"),
    (["--time", "1970-01-01T00:00:00", "--lat-deg", "31.9", "--lon-deg", "120.3"], "before the start"),
    (DOCK + ["--hip", "999999"], "unknown HIP"),
    (DOCK + ["--hip", str(CANOPUS)], "below"),
    (DOCK + ["--hip", str(SIRIUS), "--mag-limit", "2"], "either --hip or --mag-limit"),
    (DOCK + ["--pressure-hpa", "-5"], "pressure_hpa"),
    (DOCK + ["--xi-arcsec", "900"], "deflection"),
])
def test_bad_input_exits_2_with_one_line(env, args, needle):
    proc = _run(env, *args)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("shipstar apparent: error: ") and needle in lines[0]
    assert proc.stdout == ""
