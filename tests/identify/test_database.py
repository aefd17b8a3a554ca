"""The navigation star database: size, index consistency, sky grid, cache, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from shipstar.errors import ShipstarError
from shipstar.identify import build_database
from shipstar.identify import _database, _patterns as pat
from shipstar.sky.catalog import navigation_catalog
from shipstar.units import DEG2RAD


def test_a1_database_fits_in_5_mb(db_a1, cam_a1):
    assert db_a1.size_bytes < 5_000_000
    assert db_a1.n_patterns > 200_000
    assert 7.1 <= db_a1.params.mag_limit <= 7.5
    assert db_a1.params.fov_x_rad == pytest.approx(cam_a1.fov_deg * DEG2RAD)


def test_stars_are_the_navigation_catalog_brightest_first(db12):
    nav = navigation_catalog(db12.params.mag_limit, db12.params.min_separation_arcsec)
    assert db12.n_stars == len(nav)
    assert np.all(np.diff(db12.mag) >= 0)
    idx = nav.index_of_hip(db12.hip)
    np.testing.assert_allclose(db12.u_icrs, nav.unit_icrs(db12.params.epoch_jyear)[idx],
                               rtol=0, atol=6e-8)                     # float32 storage


def test_default_magnitude_gives_about_35_stars_a_field(db12, cam12):
    rng = np.random.default_rng(4)
    b = rng.normal(size=(3000, 3))
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    half = 0.5 * cam12.fov_deg * DEG2RAD
    counts = []
    for v in b:
        # stars inside the square field around v (any roll: use the inscribed/circumscribed
        # circles' mean area, i.e. a circle of the same area as the square)
        cosr = np.cos(np.sqrt(4 * half * half / np.pi))
        counts.append(np.count_nonzero(db12.u_icrs @ v >= cosr))
    assert 31 <= np.mean(counts) <= 39


def test_every_pattern_is_found_by_its_own_key(db12):
    rng = np.random.default_rng(5)
    rows = rng.choice(db12.n_patterns, 2000, replace=False)
    stars = db12.pattern_stars[rows].astype(np.intp)
    ratios, largest = pat.edge_ratios(pat.pattern_edges_rad(db12.u_icrs[stars]))
    probe, found = db12.lookup(pat.pattern_keys(ratios, db12.params.bins))
    hits = set(zip(probe.tolist(), found.tolist()))
    assert all((i, r) in hits for i, r in enumerate(rows.tolist()))
    assert np.all(largest <= db12.params.pattern_fov_rad + 1e-12)
    assert np.all(largest >= db12.params.min_pattern_frac * db12.params.pattern_fov_rad)


def test_sky_grid_returns_every_star_within_the_query_radius(db12):
    rng = np.random.default_rng(6)
    b = rng.normal(size=(500, 3))
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    b[:6] = np.vstack([np.eye(3), -np.eye(3)])                # cube-face centres
    cosr = np.cos(db12.query_radius_rad)
    for v in b:
        near = db12.near(v)
        assert np.all(np.diff(near.astype(np.int64)) > 0)     # brightest first, no repeats
        truth = np.flatnonzero(db12.u_icrs @ v >= cosr)
        assert set(truth.tolist()) <= set(near.tolist())


@pytest.fixture
def tmp_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(_database, "_MEMO", {})
    return tmp_path / "identify"


def test_cache_is_written_reused_and_keyed_by_parameters(tmp_cache):
    db = build_database(12.0, mag_limit=5.0)
    files = sorted(tmp_cache.glob("stardb_*.bin"))
    assert len(files) == 1
    _database._MEMO.clear()
    again = build_database(12.0, mag_limit=5.0)
    assert again is not db and again.build_time_s == db.build_time_s     # loaded, not rebuilt
    np.testing.assert_array_equal(again.pattern_stars, db.pattern_stars)
    other = build_database(12.0, mag_limit=5.2)
    assert other.n_stars > db.n_stars
    assert len(list(tmp_cache.glob("stardb_*.bin"))) == 2


def test_cache_file_with_other_parameters_or_version_is_rebuilt(tmp_cache, monkeypatch):
    db = build_database(12.0, mag_limit=5.0)
    (path,) = tmp_cache.glob("stardb_*.bin")
    raw = path.read_bytes()
    assert raw.count(b'\\"bins\\": 50') == 1                  # in the JSON header's params
    path.write_bytes(raw.replace(b'\\"bins\\": 50', b'\\"bins\\": 40'))
    _database._MEMO.clear()
    rebuilt = build_database(12.0, mag_limit=5.0)
    assert rebuilt.build_time_s != db.build_time_s
    path.write_bytes(path.read_bytes()[:-100])                    # truncated: rebuilt too
    _database._MEMO.clear()
    again = build_database(12.0, mag_limit=5.0)
    assert again.build_time_s != rebuilt.build_time_s
    np.testing.assert_array_equal(again.pattern_stars, db.pattern_stars)
    monkeypatch.setattr(_database, "DATABASE_VERSION", _database.DATABASE_VERSION + 1)
    _database._MEMO.clear()
    build_database(12.0, mag_limit=5.0)
    assert len(list(tmp_cache.glob("stardb_*.bin"))) == 2


def test_cache_file_holds_the_kernel_arrays_and_an_old_file_is_completed(tmp_cache):
    from shipstar.identify import _kernels
    from shipstar.identify._kernels import _DbBuffers

    built = build_database(12.0, mag_limit=5.0)
    assert _database.kernel_arrays(built) is None                 # built here: made in memory
    fresh = _DbBuffers(built)
    (path,) = tmp_cache.glob("stardb_*.bin")
    _database._MEMO.clear()
    db = build_database(12.0, mag_limit=5.0)
    u64, cell_u, size_q = _database.kernel_arrays(db)             # read: mapped from the file
    assert not u64.flags.writeable and not cell_u.flags.writeable and not size_q.flags.writeable
    np.testing.assert_array_equal(u64, fresh.u64)
    np.testing.assert_array_equal(cell_u, fresh.cell_u)
    np.testing.assert_array_equal(size_q, fresh.size_q)
    mapped = _DbBuffers(db)
    assert mapped.from_file and not fresh.from_file
    assert mapped.cell_u is cell_u or np.shares_memory(mapped.cell_u, cell_u)
    assert mapped.size_q is size_q or np.shares_memory(mapped.size_q, size_q)
    # in use (a process solving many frames): then copied into one 2 MB aligned region
    before = {name: np.array(getattr(mapped, name)) for name in _kernels._HOT_ARRAYS}
    for _ in range(_kernels.HUGE_PAGES_AFTER_USES):
        mapped.used()
    assert not np.shares_memory(mapped.cell_u, cell_u) and not np.shares_memory(mapped.size_q, size_q)
    assert mapped.key_hi_start.ctypes.data % (2 * 2 ** 20) == 0
    for name, values in before.items():
        got = getattr(mapped, name)
        assert got.dtype == values.dtype and not got.flags.writeable, name
        np.testing.assert_array_equal(got, values, err_msg=name)
    # a file written before the kernel arrays: read as it is, then completed once
    got = _database._read_header(path)
    head, start = got
    old = dict(head)
    del old["kernel_arrays"]
    old["data_bytes"] = max(o + int(np.prod(s)) * np.dtype(d).itemsize
                            for d, s, o in old["arrays"].values())
    old["data_bytes"] += -old["data_bytes"] % 64
    raw = path.read_bytes()
    text = __import__("json").dumps(old, sort_keys=True).encode()
    text += b" " * (-(16 + 8 + len(text)) % 64)
    path.write_bytes(raw[:16] + len(text).to_bytes(8, "little") + text
                     + raw[start:start + old["data_bytes"]])
    _database._MEMO.clear()
    again = build_database(12.0, mag_limit=5.0)
    assert again.build_time_s == built.build_time_s               # read, not rebuilt
    assert _database._read_header(path)[0].get("kernel_arrays")   # completed
    _database._MEMO.clear()
    np.testing.assert_array_equal(_database.kernel_arrays(build_database(12.0, mag_limit=5.0))[1],
                                  fresh.cell_u)
    # a file with the first two kernel arrays only (shipstar before the size steps):
    # completed the same way
    head, start = _database._read_header(path)
    part = dict(head)
    part["kernel_arrays"] = {k: v for k, v in head["kernel_arrays"].items() if k != "size_q"}
    text = __import__("json").dumps(part, sort_keys=True).encode()
    text += b" " * (-(16 + 8 + len(text)) % 64)
    raw = path.read_bytes()
    path.write_bytes(raw[:16] + len(text).to_bytes(8, "little") + text + raw[start:])
    _database._MEMO.clear()
    assert _database.kernel_arrays(build_database(12.0, mag_limit=5.0)) is None   # read, incomplete
    assert "size_q" in _database._read_header(path)[0]["kernel_arrays"]          # completed
    _database._MEMO.clear()
    np.testing.assert_array_equal(_database.kernel_arrays(build_database(12.0, mag_limit=5.0))[2],
                                  fresh.size_q)


def test_stored_kernel_arrays_that_are_not_the_stars_are_refused(tmp_cache):
    from shipstar.identify._kernels import _DbBuffers

    build_database(12.0, mag_limit=5.0)
    _database._MEMO.clear()
    db = build_database(12.0, mag_limit=5.0)
    u64, cell_u, size_q = _database.kernel_arrays(db)
    shifted = np.roll(cell_u, 1, axis=0)                          # misplaced rows
    for stored in ((u64, shifted, size_q), (u64[::-1].copy(), cell_u, size_q),
                   (2.0 * u64, cell_u, size_q), (u64, cell_u, np.roll(size_q, 1))):
        _database._KERNEL[db] = stored
        with pytest.raises(ValueError, match="inconsistent"):
            _DbBuffers(db)


def _stored_copy(db, **arrays):
    """``db`` with ``arrays`` replaced, its kernel arrays as if mapped from its cache file."""
    import dataclasses

    stored = _database.kernel_arrays(db)
    assert stored is not None
    bad = dataclasses.replace(db, **arrays)
    _database._KERNEL[bad] = stored
    return bad


def _sampled_rows(n: int) -> np.ndarray:
    """The rows of an array of ``n`` a stored database is checked on when it is opened
    (the compiled ``sampled_row``): 32 runs of 16 consecutive rows at evenly spaced
    starts, and the last row."""
    i = np.arange(32 * 16)
    return np.unique(np.minimum(np.r_[(i // 16) * (n // 32) + i % 16, n - 1], n - 1))


def test_a_stored_database_is_checked_on_a_sample_and_its_look_up_skips_rows_out_of_range(tmp_cache, cam12):
    # A database mapped from its cache file has its star rows and key order checked on a
    # sample when opened (a full pass costs more than a one-shot solve's search).  A bad row
    # in the sample is refused; one elsewhere is skipped by the compiled look-up, which
    # never reads the star arrays outside their bounds.
    from shipstar.identify import identify_lost_in_space
    from shipstar.identify._kernels import _DbBuffers
    from shipstar.identify._sim import random_attitudes, simulate_frame

    build_database(cam12)
    _database._MEMO.clear()
    db = build_database(cam12)
    assert _DbBuffers(db).from_file
    P, sampled = db.n_patterns, _sampled_rows(db.n_patterns)
    wide = db.pattern_stars.astype(np.uint32)
    # in the sample: refused
    for r in (0, int(sampled[len(sampled) // 2]), 15 * (P // 32) + 15, P - 1):      # (a run's last row)
        ps = wide.copy()
        ps[r, 1] = db.n_stars
        with pytest.raises(ValueError, match="inconsistent"):
            _DbBuffers(_stored_copy(db, pattern_stars=ps))
    # every row outside the sample pointing 2**31 rows away: opened, and the look-up reads
    # none of them (a read would fault), solving nothing wrong
    ps = wide.copy()
    outside = np.setdiff1d(np.arange(P), sampled)
    ps[outside, 2] = 2 ** 31
    bad = _stored_copy(db, pattern_stars=ps)
    assert _DbBuffers(bad).from_file
    rng = np.random.default_rng(11)
    for C in random_attitudes(5, rng):
        f = simulate_frame(db, cam12, C, rng)
        good = identify_lost_in_space(f.xy_px, db, camera=cam12)
        assert good.solved
        r = identify_lost_in_space(f.xy_px, bad, camera=cam12)
        if r.solved:
            m = r.star_index >= 0
            assert np.all(r.star_index[m] == f.truth_row[m])
    # a key bucket out of order among those sampled: refused; outside them, opened
    counts = np.diff(db.key_hi_start)
    in_sample = np.isin(np.arange(counts.size), _sampled_rows(counts.size))
    h = int(np.flatnonzero((counts >= 2) & in_sample)[0])
    a, e = int(db.key_hi_start[h]), int(db.key_hi_start[h + 1])
    key_lo = db.key_lo.copy()
    key_lo[a:e] = np.sort(key_lo[a:e])[::-1]
    if np.all(key_lo[a:e] == key_lo[a]):
        key_lo[a] = key_lo[a] + 1
    with pytest.raises(ValueError, match="not sorted"):
        _DbBuffers(_stored_copy(db, key_lo=key_lo))
    # the same outside the sample: opened (the sample is the one named above; an unsorted
    # bucket can only drop a match)
    starts = db.key_hi_start[:-1][counts > 0]                  # each non-empty bucket's own rows
    spread = np.zeros(counts.size, dtype=bool)
    spread[counts > 0] = np.maximum.reduceat(db.key_lo, starts) > np.minimum.reduceat(db.key_lo, starts)
    h = int(np.flatnonzero(spread & ~in_sample)[0])             # two distinct keys: reversed, a descent
    a, e = int(db.key_hi_start[h]), int(db.key_hi_start[h + 1])
    key_lo = db.key_lo.copy()
    key_lo[a:e] = np.sort(key_lo[a:e])[::-1]
    assert np.any(np.diff(key_lo[a:e].astype(int)) < 0)
    assert _DbBuffers(_stored_copy(db, key_lo=key_lo)).from_file


@pytest.mark.parametrize("args, kwargs, words", [
    ((0.05,), {}, "fov_x_deg"),
    ((90.0,), {}, "fov_x_deg"),
    ((10.0,), {"mag_limit": float("nan")}, "mag_limit"),
    ((10.0,), {"fov_tolerance": 0.9}, "fov_tolerance"),
    ((10.0,), {"epoch_jyear": 2451545.0}, "epoch_jyear"),
    (("ten",), {}, "camera_or_fov"),
    (((1, 2, 3),), {}, "camera_or_fov"),
])
def test_bad_arguments_raise_one_line_errors(args, kwargs, words):
    with pytest.raises(ShipstarError, match=words) as info:
        build_database(*args, **kwargs)
    assert "\n" not in str(info.value)
