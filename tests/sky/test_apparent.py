"""Apparent places in the horizontal frame (shipstar.sky.apparent).

References (test only): astropy's AltAz frame, ERFA routines other than the ones the
code calls (``atioq``, ``bp06``, ``pnm06a``, ``numat``/``nut06a``, ``gmst06``+``ee06a``,
``c2t06a``), and analytic cases (frame axes, the celestial pole, deflection of the
vertical).  Astropy uses the same bundled IERS-A table (``astropy_iers_a`` fixture).
"""

from __future__ import annotations

import math

import erfa
import numpy as np
import pytest

from shipstar.errors import AccuracyWarning, ShipstarError
from shipstar.frames import az_el_from_unit, rot_x, rot_y, rot_z, unit_from_az_el, unit_from_ra_dec
from shipstar.sky import catalog as catalog_mod
from shipstar.sky.apparent import (
    C_hor_from_itrs,
    FrameContext,
    Site,
    frame_context,
    seed_chain,
)
from shipstar.sky.eop import EarthOrientation
from shipstar.sky.time import tt_jd_from_utc_jd, ut1_jd_from_utc_jd, utc_jd_from_iso
from shipstar.units import ASEC2RAD, DEG2RAD, MAS2RAD, RAD2ASEC, RAD2MAS

UAS2RAD = MAS2RAD / 1000.0
DOCK_TIME = "2013-03-15T12:16:00"
DOCK = dict(lat_deg=31.9, lon_deg=120.3, height_m=5.0)
EPOCHS = ["2013-03-15T12:16:00", "2019-07-01T03:00:00", "2024-12-31T23:59:30",
          "2026-06-15T00:00:00"]
LATITUDES_DEG = [-70.0, -33.9, 0.0, 31.9, 70.0]
HIGH_PM_HIP = [87937, 104214, 69673, 70890, 71683, 24186]   # Barnard, 61 Cyg A, Arcturus, ...


def _sep_rad(a, b):
    """Angle between unit vectors ``(N, 3)`` (accurate for tiny angles)."""
    return 2.0 * np.arcsin(np.clip(0.5 * np.linalg.norm(np.asarray(a) - np.asarray(b), axis=-1), 0, 1))


@pytest.fixture(scope="module")
def stars(tmp_path_factory):
    """The 240 brightest Hipparcos stars plus high-proper-motion and near stars."""
    mp = pytest.MonkeyPatch()
    mp.setenv("SHIPSTAR_CACHE_DIR", str(tmp_path_factory.mktemp("shipstar_cache")))
    full = catalog_mod.load_hipparcos()
    idx = np.concatenate([np.argsort(full.mag)[:240], full.index_of_hip(HIGH_PM_HIP)])
    yield full.subset(np.unique(idx))
    mp.undo()


def _astropy_altaz(cat, jd, lat_deg, lon_deg, height_m, **altaz_kwargs):
    """Astropy's topocentric az/el of catalog stars (space motion applied first)."""
    from astropy import units as u
    from astropy.coordinates import AltAz, Distance, EarthLocation, SkyCoord
    from astropy.time import Time

    t = Time(jd[0], jd[1], format="jd", scale="utc")
    coords = SkyCoord(
        ra=cat.ra_rad * u.rad, dec=cat.dec_rad * u.rad,
        pm_ra_cosdec=cat.pm_ra_cosdec_mas_per_yr * u.mas / u.yr,
        pm_dec=cat.pm_dec_mas_per_yr * u.mas / u.yr,
        distance=Distance(parallax=cat.parallax_mas * u.mas),
        radial_velocity=cat.rv_km_s * u.km / u.s,
        obstime=Time(2451545.0, format="jd", scale="tt"), frame="icrs",
    ).apply_space_motion(new_obstime=t)
    location = EarthLocation.from_geodetic(lon_deg * u.deg, lat_deg * u.deg, height_m * u.m)
    aa = coords.transform_to(AltAz(obstime=t, location=location, **altaz_kwargs))
    return unit_from_az_el(aa.az.rad, aa.alt.rad)


# ---------------------------------------------------------------------------------------
# Against astropy's AltAz
# ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("iso", EPOCHS)
def test_matches_astropy_altaz_without_refraction(stars, astropy_iers_a, iso):
    from astropy import units as u

    jd = utc_jd_from_iso(iso)
    worst = 0.0
    for lat in LATITUDES_DEG:
        site = Site.from_deg(lat, DOCK["lon_deg"], DOCK["height_m"])
        ours = frame_context(*jd, site).hor_from_catalog(stars)
        ref = _astropy_altaz(stars, jd, lat, DOCK["lon_deg"], DOCK["height_m"], pressure=0 * u.hPa)
        worst = max(worst, float(np.max(_sep_rad(ours, ref))))
    assert len(stars) >= 240
    assert worst < 5 * MAS2RAD, worst * RAD2MAS


def test_matches_astropy_past_the_iers_table_with_the_same_eop(stars, astropy_iers_a,
                                                               past_iers_table_end):
    """2030: astropy holds the table's last UT1-UTC and uses its 50-year mean polar
    motion; give shipstar the same values."""
    from astropy import units as u
    from astropy.coordinates.builtin_frames.utils import get_polar_motion
    from astropy.time import Time

    jd = utc_jd_from_iso("2030-01-01T00:00:00")
    with past_iers_table_end():
        t = Time(*jd, format="jd", scale="utc")
        xp, yp = (float(c) for c in get_polar_motion(t))
        eop = EarthOrientation(float(t.delta_ut1_utc), xp, yp, "extrapolated", 0.35)
        for lat in (-45.0, 31.9):
            ours = frame_context(*jd, Site.from_deg(lat, 10.0), eop=eop).hor_from_catalog(stars)
            ref = _astropy_altaz(stars, jd, lat, 10.0, 0.0, pressure=0 * u.hPa)
            assert np.max(_sep_rad(ours, ref)) < 5 * MAS2RAD
    with pytest.warns(AccuracyWarning):
        default = frame_context(*jd, Site.from_deg(31.9, 10.0))
    assert default.eop.quality == "extrapolated"


@pytest.mark.parametrize("lat_deg", [-33.9, 31.9, 60.0])
def test_matches_astropy_with_the_same_refraction(stars, astropy_iers_a, lat_deg):
    from astropy import units as u

    from shipstar.sky.refraction import Weather, min_true_el_rad, refract_hor

    weather = Weather(pressure_hpa=1021.7, temperature_c=11.1, relative_humidity=0.6,
                      wavelength_um=0.65)
    jd = utc_jd_from_iso(DOCK_TIME)
    true = frame_context(*jd, Site.from_deg(lat_deg, 120.3, 5.0)).hor_from_catalog(stars)
    keep = az_el_from_unit(true)[1] > max(min_true_el_rad(weather, "erfa"), 15 * DEG2RAD)
    assert keep.sum() > 50
    ours = refract_hor(true[keep], weather, model="erfa")
    ref = _astropy_altaz(stars, jd, lat_deg, 120.3, 5.0, pressure=weather.pressure_hpa * u.hPa,
                         temperature=weather.temperature_c * u.deg_C,
                         relative_humidity=weather.relative_humidity,
                         obswl=weather.wavelength_um * u.micron)[keep]
    assert np.max(_sep_rad(ours, ref)) < 0.05 * ASEC2RAD


# ---------------------------------------------------------------------------------------
# The fast path, piece by piece
# ---------------------------------------------------------------------------------------

def test_cirs_to_hor_rotation_reproduces_erfa_atioq():
    jd = utc_jd_from_iso(DOCK_TIME)
    ctx = frame_context(*jd, Site.from_deg(**DOCK))
    rng = np.random.default_rng(7)
    ri, di = rng.uniform(0, 2 * np.pi, 500), np.arcsin(rng.uniform(-1, 1, 500))
    aob, zob, *_ = erfa.atioq(ri, di, ctx.astrom)
    ref = unit_from_az_el(aob, 0.5 * np.pi - zob)
    ours = unit_from_ra_dec(ri, di) @ ctx.C_hor_from_cirs.T
    assert np.max(_sep_rad(ours, ref)) < 1 * UAS2RAD


def test_catalog_path_reproduces_erfa_atco13(stars):
    site = Site.from_deg(-20.0, -150.0, 30.0)
    rng = np.random.default_rng(11)
    times = [utc_jd_from_iso("2021-02-03T04:05:06.5"), utc_jd_from_iso("2016-12-31T23:59:60.5")]
    times += [(2400000.5, m) for m in rng.uniform(41700.0, 61500.0, 10)]
    for jd in times:
        ctx = frame_context(*jd, site)
        e = ctx.eop
        aob, zob, *_ = erfa.atco13(*stars.erfa_args(), *jd, e.dut1_s, site.lon_rad, site.lat_rad,
                                   site.height_m, e.xp_rad, e.yp_rad, 0.0, 0.0, 0.0, 0.0)
        ours = ctx.hor_from_catalog(stars)
        # Hourly interpolation of the ephemeris and of the CIP costs < 15 microarcsec.
        assert np.max(_sep_rad(ours, unit_from_az_el(aob, 0.5 * np.pi - zob))) < 15 * UAS2RAD
    # index= selects the same rows.
    sel = np.array([5, 0, 17])
    assert np.array_equal(ctx.hor_from_catalog(stars, index=sel), ours[sel])
    mask = np.zeros(len(stars), bool)
    mask[[3, 9]] = True
    assert np.array_equal(ctx.hor_from_catalog(stars, index=mask), ours[mask])
    with pytest.raises(ShipstarError, match="out of range"):
        ctx.hor_from_catalog(stars, index=[len(stars)])


def test_icrs_round_trip_and_bare_directions():
    jd = utc_jd_from_iso(DOCK_TIME)
    ctx = frame_context(*jd, Site.from_deg(**DOCK, xi_arcsec=7.0, eta_arcsec=-4.0))
    rng = np.random.default_rng(3)
    u = rng.normal(size=(300, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = ctx.hor_from_icrs(u)
    assert np.max(_sep_rad(ctx.icrs_from_hor(v), u)) < 1 * UAS2RAD
    # Bare directions are catalog stars without proper motion and parallax.
    ra, dec = np.arctan2(u[:, 1], u[:, 0]), np.arcsin(u[:, 2])
    zeros = np.zeros(len(u))
    by_args = ctx.hor_from_star_args(ra, dec, zeros, zeros, zeros, zeros)
    assert np.max(_sep_rad(by_args, v)) < 1 * UAS2RAD
    # The rigid approximation is off by the aberration only (~20.5'' at most).
    rigid = u @ ctx.C_hor_from_icrs_approx.T
    worst = np.max(_sep_rad(rigid, v)) * RAD2ASEC
    assert 0.9 * ctx.aberration_arcsec < worst < ctx.aberration_arcsec + 0.1
    assert 20.0 < ctx.aberration_arcsec < 21.2
    with pytest.raises(ShipstarError, match="shape"):
        ctx.hor_from_icrs(np.ones(4))
    with pytest.raises(ShipstarError, match="non-finite"):
        ctx.hor_from_icrs([[np.nan, 0.0, 1.0]])
    with pytest.raises(ShipstarError, match="non-finite astrometry"):
        ctx.hor_from_star_args(np.array([0.1, np.nan]), zeros[:2], zeros[:2], zeros[:2],
                               zeros[:2], zeros[:2])


# ---------------------------------------------------------------------------------------
# The horizontal frame: axes, pole, rising and setting, deflection of the vertical
# ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("lat_deg", [-60.0, 0.5, 31.9, 75.0])
def test_celestial_pole_is_north_at_the_latitude(lat_deg):
    ctx = frame_context(*utc_jd_from_iso(DOCK_TIME), Site.from_deg(lat_deg, 120.3))
    pole_gcrs = ctx.astrom["bpn"][2]          # the CIP in GCRS (row 3 of the NPB matrix)
    az, el = az_el_from_unit(ctx.C_hor_from_icrs_approx @ pole_gcrs)
    assert el == pytest.approx(lat_deg * DEG2RAD, abs=1.0 * ASEC2RAD)   # polar motion < 1''
    assert math.remainder(float(az), 2 * np.pi) == pytest.approx(0.0, abs=1.0 * ASEC2RAD / math.cos(el))


def test_stars_rise_in_the_east_and_set_in_the_west():
    site = Site.from_deg(**DOCK)
    jd1, jd2 = utc_jd_from_iso(DOCK_TIME)
    u = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])
    v0 = frame_context(jd1, jd2, site).hor_from_icrs(u)
    v1 = frame_context(jd1, jd2 + 60.0 / 86400.0, site).hor_from_icrs(u)
    az0, el0 = az_el_from_unit(v0)
    _, el1 = az_el_from_unit(v1)
    east = np.sin(az0) > 0.3
    west = np.sin(az0) < -0.3
    assert np.all(el1[east] > el0[east]) and np.all(el1[west] < el0[west])
    assert east.any() and west.any()


@pytest.mark.parametrize("az_deg, sign", [(180.0, -1.0), (0.0, +1.0)])
def test_xi_moves_a_meridian_star_by_xi_in_elevation(az_deg, sign):
    """Astronomical latitude = phi + xi: the zenith moves north by xi."""
    jd = utc_jd_from_iso(DOCK_TIME)
    plain = frame_context(*jd, Site.from_deg(**DOCK))
    tilted = frame_context(*jd, Site.from_deg(**DOCK, xi_arcsec=10.0))
    u = plain.icrs_from_hor(unit_from_az_el(az_deg * DEG2RAD, 40.0 * DEG2RAD)[None])
    az, el = az_el_from_unit(tilted.hor_from_icrs(u)[0])
    assert (el - 40.0 * DEG2RAD) * RAD2ASEC == pytest.approx(sign * 10.0, abs=1e-3)
    assert math.remainder(float(az) - az_deg * DEG2RAD, 2 * np.pi) == pytest.approx(0.0, abs=1e-9)


def test_eta_moves_a_prime_vertical_star_by_eta_in_elevation():
    """Astronomical longitude = lambda + eta / cos(phi): the zenith moves east by eta."""
    jd = utc_jd_from_iso(DOCK_TIME)
    plain = frame_context(*jd, Site.from_deg(**DOCK))
    tilted = frame_context(*jd, Site.from_deg(**DOCK, eta_arcsec=10.0))
    dirs = unit_from_az_el(np.array([90.0, 270.0]) * DEG2RAD, np.full(2, 30.0 * DEG2RAD))
    _, el = az_el_from_unit(tilted.hor_from_icrs(plain.icrs_from_hor(dirs)))
    assert (el - 30.0 * DEG2RAD) * RAD2ASEC == pytest.approx([10.0, -10.0], abs=2e-3)


def test_site_keeps_the_geodetic_position_for_parallax_and_diurnal_aberration():
    jd = utc_jd_from_iso(DOCK_TIME)
    plain = frame_context(*jd, Site.from_deg(**DOCK))
    tilted = frame_context(*jd, Site.from_deg(**DOCK, xi_arcsec=20.0, eta_arcsec=20.0))
    for key in ("eb", "v"):
        assert np.array_equal(plain.astrom[key], tilted.astrom[key])


@pytest.mark.parametrize("kwargs, match", [
    (dict(lat_deg=91.0, lon_deg=0.0), r"outside \[-90, 90\]"),
    (dict(lat_deg=float("nan"), lon_deg=0.0), "finite"),
    (dict(lat_deg=10.0, lon_deg=float("inf")), "finite"),
    (dict(lat_deg=10.0, lon_deg=0.0, height_m=50000.0), "height"),
    (dict(lat_deg=10.0, lon_deg=0.0, xi_arcsec=500.0), "deflection"),
    (dict(lat_deg=90.0, lon_deg=0.0, eta_arcsec=5.0), "pole"),
    (dict(lat_deg=10.0, lon_deg=1e308), r"longitude 1e\+308 deg is outside \[-180, 360\]"),
    (dict(lat_deg=10.0, lon_deg=-180.5), r"outside \[-180, 360\]"),
    (dict(lat_deg=10.0, lon_deg=360.001), r"outside \[-180, 360\]"),
])
def test_site_validation(kwargs, match):
    with pytest.raises(ShipstarError, match=match):
        Site.from_deg(**kwargs)


@pytest.mark.parametrize("lon_deg, expected_deg", [(-180.0, 180.0), (180.0, 180.0), (200.0, -160.0),
                                                   (359.5, -0.5), (360.0, 0.0), (-0.25, -0.25)])
def test_longitude_is_normalised_to_minus_180_plus_180(lon_deg, expected_deg):
    """Review finding: 'shipstar apparent --lon-deg 1e308' exited 0.  Longitudes within
    [-180, 360] are accepted and kept in (-180, 180]; radians far outside are refused."""
    lon = Site.from_deg(10.0, lon_deg).lon_rad
    assert -math.pi < lon <= math.pi
    assert lon == pytest.approx(expected_deg * DEG2RAD, abs=1e-15)
    with pytest.raises(ShipstarError, match="not a longitude"):
        Site(0.1, 1e308)


def test_apparent_command_refuses_a_longitude_out_of_range():
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "shipstar", "apparent", "--lat-deg", "31.9", "--lon-deg", "1e308",
                           "--time", DOCK_TIME, "--hip", "32349"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert "longitude must be within [-180, 360] deg" in lines[0] and "got 1e+308" in lines[0]


def test_frame_context_validation():
    jd = utc_jd_from_iso(DOCK_TIME)
    with pytest.raises(ShipstarError, match="site"):
        frame_context(*jd, (31.9, 120.3))
    with pytest.raises(ShipstarError, match="finite"):
        frame_context(float("nan"), 0.0, Site.from_deg(**DOCK))
    with pytest.raises(ShipstarError, match="eop"):
        frame_context(*jd, Site.from_deg(**DOCK), eop=(0.1, 0.0, 0.0))
    with pytest.raises(ShipstarError, match="before the start"):
        frame_context(*utc_jd_from_iso("1970-01-01T00:00:00"), Site.from_deg(**DOCK))
    assert isinstance(frame_context(*jd, Site.from_deg(**DOCK)), FrameContext)


# ---------------------------------------------------------------------------------------
# Seed 000 eq. 7 chain: each matrix against an independent ERFA route or analytic form
# ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def dock_chain():
    jd = utc_jd_from_iso(DOCK_TIME)
    site = Site.from_deg(**DOCK, xi_arcsec=3.0, eta_arcsec=-5.0)
    chain = seed_chain(*jd, site)
    ctx = frame_context(*jd, site)
    tt = tt_jd_from_utc_jd(*jd)
    ut1 = ut1_jd_from_utc_jd(*jd, ctx.eop.dut1_s)
    return dict(jd=jd, site=site, chain=chain, ctx=ctx, tt=tt, ut1=ut1)


def _angle(a, b):
    """Rotation angle (rad) between two rotation matrices."""
    from shipstar.frames import rotation_angle_rad

    return float(rotation_angle_rad(np.asarray(a).T @ np.asarray(b)))


def test_chain_precession_against_bp06(dock_chain):
    _, _, rbp = erfa.bp06(*dock_chain["tt"])
    assert _angle(dock_chain["chain"].C_mean_from_icrs, rbp) < 1 * UAS2RAD
    # ~13 years of precession: ~50.3''/yr * 13.2 yr along the ecliptic.
    assert 600 < _angle(dock_chain["chain"].C_mean_from_icrs, np.eye(3)) * RAD2ASEC < 700


def test_chain_nutation_against_nut06a_numat(dock_chain):
    tt = dock_chain["tt"]
    dpsi, deps = erfa.nut06a(*tt)
    rn = erfa.numat(erfa.obl06(*tt), dpsi, deps)
    assert _angle(dock_chain["chain"].C_true_from_mean, rn) < 1 * UAS2RAD
    npb = dock_chain["chain"].C_true_from_mean @ dock_chain["chain"].C_mean_from_icrs
    assert _angle(npb, erfa.pnm06a(*tt)) < 1 * UAS2RAD


def test_chain_earth_rotation_against_gmst_plus_equation_of_equinoxes(dock_chain):
    tt, ut1 = dock_chain["tt"], dock_chain["ut1"]
    gast = erfa.gmst06(*ut1, *tt) + erfa.ee06a(*tt)
    assert math.remainder(dock_chain["chain"].gast_rad - gast, 2 * np.pi) == pytest.approx(0, abs=UAS2RAD)
    assert np.allclose(dock_chain["chain"].C_pef_from_true, rot_z(gast), atol=1e-12)


def test_chain_polar_motion_against_its_definition(dock_chain):
    eop = dock_chain["ctx"].eop
    sp = erfa.sp00(*dock_chain["tt"])
    ref = rot_x(-eop.yp_rad) @ rot_y(-eop.xp_rad) @ rot_z(sp)
    assert _angle(dock_chain["chain"].C_itrs_from_pef, ref) < 1e-3 * UAS2RAD
    assert _angle(dock_chain["chain"].C_itrs_from_pef, np.eye(3)) * RAD2ASEC == pytest.approx(
        math.hypot(eop.xp_rad, eop.yp_rad) * RAD2ASEC, abs=1e-3)


def test_chain_site_matrix_is_north_up_east(dock_chain):
    site = dock_chain["site"]
    lat, lon = site.astronomical_lat_rad, site.astronomical_lon_rad
    C = dock_chain["chain"].C_hor_from_itrs
    up = [math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)]
    east = [-math.sin(lon), math.cos(lon), 0.0]
    north = np.cross(up, east)
    assert np.allclose(C, np.array([north, up, east]), atol=1e-15)
    assert np.allclose(C, C_hor_from_itrs(lat, lon))
    assert lat == pytest.approx(31.9 * DEG2RAD + 3.0 * ASEC2RAD)
    assert lon == pytest.approx(120.3 * DEG2RAD - 5.0 * ASEC2RAD / math.cos(31.9 * DEG2RAD))


def test_chain_celestial_to_terrestrial_against_c2t06a(dock_chain):
    """Equinox-based chain vs ERFA's CIO-based celestial-to-terrestrial matrix."""
    ch, eop = dock_chain["chain"], dock_chain["ctx"].eop
    c2t = ch.C_itrs_from_pef @ ch.C_pef_from_true @ ch.C_true_from_mean @ ch.C_mean_from_icrs
    ref = erfa.c2t06a(*dock_chain["tt"], *dock_chain["ut1"], eop.xp_rad, eop.yp_rad)
    assert _angle(c2t, ref) < 1 * UAS2RAD


def test_chain_product_against_the_fast_path(dock_chain, stars):
    """Chain on aberrated GCRS directions == fast path; on catalog directions it misses
    proper motion, parallax, light deflection and aberration (quantified)."""
    ctx, chain = dock_chain["ctx"], dock_chain["chain"]
    assert _angle(chain.C_hor_from_icrs, ctx.C_hor_from_icrs_approx) < 15 * UAS2RAD
    a = ctx.astrom
    p = erfa.pmpx(*stars.erfa_args(), a["pmt"], a["eb"])
    p = erfa.ab(erfa.ldsun(p, a["eh"], a["em"]), a["v"], a["em"], a["bm1"])
    fast = ctx.hor_from_catalog(stars)
    via_chain = p @ chain.C_hor_from_icrs.T
    via_chain /= np.linalg.norm(via_chain, axis=1, keepdims=True)
    assert np.max(_sep_rad(via_chain, fast)) < 15 * UAS2RAD
    geometric = unit_from_ra_dec(stars.ra_rad, stars.dec_rad) @ chain.C_hor_from_icrs.T
    miss = _sep_rad(geometric, fast) * RAD2ASEC
    slow = np.hypot(stars.pm_ra_cosdec_mas_per_yr, stars.pm_dec_mas_per_yr) < 100.0
    # Aberration (20.7'' max) dominates for slow stars; Barnard's star moved ~137'' since 2000.
    assert 10.0 < np.max(miss[slow]) < 21.5
    assert np.max(miss) > 100.0
