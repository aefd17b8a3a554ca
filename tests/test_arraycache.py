"""The array cache files (``shipstar._arraycache``): read back whole, or None.

A file cut short, damaged, of the other kind or lacking a name is None, never a partial
result, an exception or a file left open (the suite turns a ``ResourceWarning`` into an
error, so a leaked file fails the test that leaked it).
"""

import gc
import warnings

import numpy as np
import pytest

from shipstar._arraycache import read_array, read_arrays, write_array, write_arrays


@pytest.fixture
def arrays():
    rng = np.random.default_rng(5)
    return {"mjd": rng.normal(size=500), "flag": rng.normal(size=500) > 0, "key": np.array("hip2|x|format3")}


def _no_leak(fn, *args):
    """``fn(*args)`` with every ResourceWarning (a file left open) recorded and collected."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = fn(*args)
        gc.collect()
    leaks = [w for w in caught if issubclass(w.category, ResourceWarning)]
    assert not leaks, leaks
    return out


def test_round_trip_is_exact(tmp_path, arrays):
    path = tmp_path / "c.npz"
    assert write_arrays(path, arrays)
    back = read_arrays(path, ("mjd", "flag", "key"))
    assert set(back) == {"mjd", "flag", "key"}
    for name, a in arrays.items():
        assert back[name].dtype == a.dtype
        np.testing.assert_array_equal(back[name], a)
    one = tmp_path / "m.npy"
    assert write_array(one, arrays["mjd"])
    np.testing.assert_array_equal(read_array(one), arrays["mjd"])
    assert [p.name for p in tmp_path.iterdir()] != [] and not list(tmp_path.glob("*.tmp"))


def test_damaged_or_wrong_files_are_none_and_closed(tmp_path, arrays):
    npz, npy = tmp_path / "c.npz", tmp_path / "m.npy"
    write_arrays(npz, arrays)
    write_array(npy, arrays["mjd"])
    whole_zip, whole_npy = npz.read_bytes(), npy.read_bytes()
    assert _no_leak(read_arrays, npz, ("mjd", "absent")) is None          # a name it lacks
    assert _no_leak(read_arrays, npy, ("mjd",)) is None                   # an .npy, not an .npz
    assert _no_leak(read_array, npz) is None                              # an .npz, not an .npy
    assert _no_leak(read_arrays, tmp_path / "missing.npz", ("mjd",)) is None
    assert _no_leak(read_array, tmp_path / "missing.npy") is None
    for cut in (10, 40, len(whole_zip) // 2, len(whole_zip) - 30):       # starts like a zip, cut short
        npz.write_bytes(whole_zip[:cut])
        assert _no_leak(read_arrays, npz, ("mjd", "flag", "key")) is None, cut
        npy.write_bytes(whole_zip[:cut])                                  # a cut zip where an .npy should be
        assert _no_leak(read_array, npy) is None, cut
    for cut in (6, 60, len(whole_npy) // 2):
        npy.write_bytes(whole_npy[:cut])
        assert _no_leak(read_array, npy) is None, cut
    npz.write_bytes(b"\0" * 300)
    assert _no_leak(read_arrays, npz, ("mjd",)) is None


def test_a_file_in_the_way_of_the_directory_is_false(tmp_path, arrays):
    """A directory that cannot be written (here a file in its place, unwritable as root too):
    False, and nothing written."""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert write_arrays(blocker / "c.npz", arrays) is False
    assert write_array(blocker / "m.npy", arrays["mjd"]) is False
    assert blocker.read_text() == "x"
