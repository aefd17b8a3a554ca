"""``shipstar cache info|clear`` and the cache's automatic bound, on a temporary cache
directory.  References: the files actually on disk (os.stat), their ages set with
os.utime."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

from shipstar.identify import build_database
from shipstar.identify._database import cache_files, prune_cache


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    root = tmp_path / "cache"
    monkeypatch.setenv("SHIPSTAR_CACHE_DIR", str(root))
    return root


def _run(root, *args):
    env = dict(os.environ, SHIPSTAR_CACHE_DIR=str(root))
    return subprocess.run([sys.executable, "-m", "shipstar", "cache", *args], env=env,
                          capture_output=True, text=True, timeout=120)


def _databases(root):
    return sorted((root / "identify").glob("stardb_*"))


def test_info_lists_databases_and_clear_removes_old_ones(cache):
    build_database(30.0)                               # a small wide-field database
    build_database(40.0)
    dbs = _databases(cache)
    assert len(dbs) == 2
    proc = _run(cache, "info", "--json")
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    listed = {f["path"]: f for f in info["files"]}
    for p in dbs:
        entry = listed[str(p)]
        assert entry["kind"] == "star database" and entry["size_bytes"] == p.stat().st_size
        assert "patterns" in entry["label"] and entry["last_use_utc"].endswith("Z")
    assert info["total_bytes"] == sum(p.stat().st_size for p in cache.rglob("*") if p.is_file()
                                      and str(p) in listed)
    human = _run(cache, "info")
    assert human.returncode == 0 and str(cache) in human.stdout and dbs[0].name in human.stdout
    # one database unused for 10 days: only it goes with --older-than-days 5
    old = time.time() - 10 * 86400
    os.utime(dbs[0], (old, old))
    proc = _run(cache, "clear", "--older-than-days", "5", "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert [f["path"] for f in out["removed"]] == [str(dbs[0])]
    assert out["freed_bytes"] > 0 and _databases(cache) == [dbs[1]]
    proc = _run(cache, "clear")
    assert proc.returncode == 0 and proc.stdout.startswith("removed ")
    assert _databases(cache) == [] and cache_files(cache) == []


def test_a_used_database_is_recent_again(cache):
    build_database(30.0)
    (db,) = _databases(cache)
    old = time.time() - 3 * 86400
    os.utime(db, (old, old))
    from shipstar.identify import _database

    _database._MEMO.clear()
    build_database(30.0)                               # read from the cache: a use
    assert db.stat().st_mtime > time.time() - 60


def test_prune_removes_least_recently_used_first(cache):
    ident = cache / "identify"
    ident.mkdir(parents=True)
    now = time.time()
    paths = []
    for k in range(5):                                 # stand-in files of 1 MB, k days old
        p = ident / f"stardb_v0f0_{k}.bin"
        p.write_bytes(b"\0" * 1_000_000)
        os.utime(p, (now - k * 86400, now - k * 86400))
        paths.append(p)
    removed = prune_cache(max_mb=100, max_files=3)
    assert sorted(f.path for f in removed) == sorted(paths[3:])
    removed = prune_cache(max_mb=1.5, max_files=100, keep=(paths[1],))
    assert [f.path for f in removed] == [paths[2], paths[0]]      # oldest first; kept one stays
    assert [f.path for f in cache_files(cache)] == [paths[1]]


def test_distinct_hints_share_one_database(cache):
    """Solving with several field-of-view hints builds one band database, not one each."""
    import numpy as np

    from shipstar.identify import solve_centroids

    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 500, size=(30, 2))             # no real sky: only the database count
    for fov in (9.0, 10.0, 11.0, 12.5):
        solve_centroids(xy, (500, 500), fov_deg=fov, max_time_s=0.2)
    assert len(_databases(cache)) == 1


@pytest.mark.parametrize("args", [["clear", "--older-than-days", "-1"],
                                  ["clear", "--older-than-days", "soon"], ["purge"]])
def test_bad_input_is_one_line(cache, args):
    proc = _run(cache, *args)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_bad_cache_bound_is_refused(cache, monkeypatch):
    from shipstar.errors import ShipstarError

    monkeypatch.setenv("SHIPSTAR_CACHE_MAX_MB", "lots")
    with pytest.raises(ShipstarError, match="SHIPSTAR_CACHE_MAX_MB"):
        prune_cache()


@pytest.mark.parametrize("name, value", [("SHIPSTAR_CACHE_MAX_MB", "abc"), ("SHIPSTAR_CACHE_MAX_FILES", "-5")])
def test_a_bad_cache_bound_is_refused_at_the_first_use_of_the_cache(cache, name, value):
    """It was read only when a new database was stored, after the work, and never with every
    file there (a bad-input sweep); now any command refuses it before its work."""
    proc = subprocess.run([sys.executable, "-m", "shipstar", "apparent", "--time", "2013-03-15T12:16:00",
                           "--lat-deg", "31.9", "--lon-deg", "120.3"], capture_output=True, text=True, timeout=120,
                          env=dict(os.environ, SHIPSTAR_CACHE_DIR=str(cache), **{name: value}))
    assert proc.returncode == 2 and proc.stdout == "", proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and f"{name} must be" in lines[0] and repr(value) in lines[0], proc.stderr


def test_sorted_magnitudes_cache_is_the_catalog(cache, monkeypatch):
    """The on-disk sorted magnitudes (default magnitude limits) are the catalog's own."""
    import numpy as np

    from shipstar.identify import _database
    from shipstar.sky.catalog import load_hipparcos

    monkeypatch.setattr(_database, "_SORTED_MAG", [None, None])
    first = _database._sorted_magnitudes()                        # built, written
    (path,) = cache.glob("hipmag_v*.npy")
    monkeypatch.setattr(_database, "_SORTED_MAG", [None, None])
    again = _database._sorted_magnitudes()                        # read back
    mag = np.asarray(load_hipparcos().mag, float)
    truth = np.sort(mag[np.isfinite(mag)])
    np.testing.assert_array_equal(first, truth)
    np.testing.assert_array_equal(again, truth)
    assert str(path) in {str(f.path) for f in cache_files(cache)}
    # a damaged file, or a zip where the .npy should be, is built again (a file starting
    # like a zip was a traceback: zipfile.BadZipFile, or AttributeError on the NpzFile that
    # np.load gives for a whole zip)
    for damaged in (path.read_bytes()[:100], b"PK\x03\x04" + b"\0" * 200, _zip_bytes(np)):
        path.write_bytes(damaged)
        monkeypatch.setattr(_database, "_SORTED_MAG", [None, None])
        np.testing.assert_array_equal(_database._sorted_magnitudes(), truth)
        np.testing.assert_array_equal(np.load(path), truth)                # and written whole again


def _zip_bytes(np):
    import io

    buf = io.BytesIO()
    np.savez(buf, mag=np.arange(2000.0))
    return buf.getvalue()


@pytest.mark.parametrize("sub", [["info"], ["info", "--json"], ["clear"]])
def test_an_unusable_cache_directory_is_an_error_not_zero_files(tmp_path, sub):
    """SHIPSTAR_CACHE_DIR under a file: every command runs uncached; ``cache info`` said
    "0 files" and ``cache clear`` "removed 0", exit 0 (found by a bad-input sweep)."""
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    proc = _run(blocker / "cache", *sub)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert f"the cache directory {blocker / 'cache'} cannot be used ({blocker} is a file" in lines[0]
    assert proc.stdout == "" and blocker.read_text() == "x"
