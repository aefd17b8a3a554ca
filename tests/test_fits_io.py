"""shipstar's one FITS reader (shipstar._fitsio) and the readers built on it.

References: astropy.time (mid-exposure = start + EXPTIME / 2, computed independently of
ERFA's two-part dates), astropy.io.fits headers (the quick card scan must agree), and
arrays written with known pixel values (row order).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from shipstar._fitsio import FitsFrameInfo, read_fits, read_fits_header, read_fits_image
from shipstar.errors import ShipstarError
from shipstar.extract import read_image
from shipstar.pipeline import read_fits_frame, scan_frames
from shipstar.units import DAY_S

START = "2013-03-15T12:16:00.125400"


def _image(h=6, w=5):
    return np.arange(h * w, dtype=np.uint16).reshape(h, w)


def _write(path, cards=(), data=None, extension=False):
    """A FITS file with ``cards`` in the image HDU (``extension``: primary empty, image in HDU 1)."""
    from astropy.io import fits

    data = _image() if data is None else data
    image = fits.ImageHDU(data) if extension else fits.PrimaryHDU(data)
    for key, value in cards:
        image.header[key] = value
    hdul = fits.HDUList([fits.PrimaryHDU(), image]) if extension else fits.HDUList([image])
    hdul.writeto(path, overwrite=True)
    return path


def _astropy_jd(iso, plus_s=0.0):
    """Reference: astropy.time, as one float JD split to keep microseconds."""
    from astropy.time import Time, TimeDelta

    t = Time(iso, format="isot", scale="utc") + TimeDelta(plus_s, format="sec")
    return t.jd1, t.jd2


def _seconds_apart(info: FitsFrameInfo, ref) -> float:
    return abs((info.utc_jd1 - ref[0]) + (info.utc_jd2 - ref[1])) * DAY_S


# -- time of a frame -----------------------------------------------------------------------

@pytest.mark.parametrize("cards, date_obs_is, ref_iso, plus_s, source", [
    ([("DATE-OBS", START), ("EXPTIME", 0.08)], "start", START, 0.04, "DATE-OBS+EXPTIME/2"),
    ([("DATE-OBS", START), ("EXPOSURE", 0.08)], "start", START, 0.04, "DATE-OBS+EXPOSURE/2"),
    ([("DATE-OBS", START), ("DATE-END", "2013-03-15T12:16:00.205400")], "start", START, 0.04,
     "DATE-OBS+(DATE-END-DATE-OBS)/2"),
    ([("DATE-OBS", "2013-03-15T12:16:00"), ("DATE-BEG", START), ("EXPTIME", 0.01)], "start", START, 0.005,
     "DATE-BEG+EXPTIME/2"),
    ([("DATE-OBS", "2013-03-15T12:16:00"), ("DATE-AVG", START), ("EXPTIME", 0.08)], "start", START, 0.0,
     "DATE-AVG"),
    ([("DATE-OBS", START), ("EXPTIME", 0.08)], "mid", START, 0.0, "DATE-OBS(mid)"),
    ([("DATE-OBS", START)], "mid", START, 0.0, "DATE-OBS(mid)"),
    ([("DATE-OBS", START), ("DATE-AVG", START), ("EXPTIME", 0.08)], "mid", START, 0.0, "DATE-AVG"),
])
def test_mid_exposure_time_follows_the_fits_standard(tmp_path, cards, date_obs_is, ref_iso, plus_s, source):
    for extension in (False, True):                      # quick card scan and astropy agree
        path = _write(tmp_path / f"f{extension}.fits", cards, extension=extension)
        for info in (read_fits_header(path, date_obs_is=date_obs_is),
                     read_fits(path, date_obs_is=date_obs_is)[1]):
            assert info.has_time and info.time_source == source and info.date_obs_is == date_obs_is
            assert _seconds_apart(info, _astropy_jd(ref_iso, plus_s)) < 1e-6


def test_a_start_without_exposure_gives_no_time(tmp_path):
    path = _write(tmp_path / "a.fits", [("DATE-OBS", START)])
    info = read_fits_header(path)
    assert not info.has_time and math.isnan(info.utc_jd1) and info.time_source == ""
    assert "EXPTIME" in info.time_problem and "date_obs_is='mid'" in info.time_problem
    with pytest.raises(ShipstarError, match="a.fits: DATE-OBS is the start"):
        info.mid_utc_jd()
    with pytest.raises(ShipstarError, match="EXPTIME"):
        read_fits_frame(path)
    assert read_fits_image(path).shape == (6, 5)                 # the pixels need no time
    none = read_fits_header(_write(tmp_path / "b.fits"))
    assert "b.fits has no DATE-OBS, DATE-BEG or DATE-AVG" in none.time_problem


@pytest.mark.parametrize("cards, message", [
    ([("DATE-OBS", START), ("EXPTIME", -0.1)], "EXPTIME = -0.1 s is negative"),
    ([("DATE-OBS", START), ("EXPTIME", "fast")], "EXPTIME = 'fast' is not a finite number"),
    ([("DATE-OBS", START), ("DATE-END", "2013-03-15T12:15:59")], "DATE-END is 1.1254 s before DATE-OBS"),
    ([("DATE-OBS", "yesterday"), ("EXPTIME", 0.1)], "DATE-OBS"),
    ([("DATE-OBS", START), ("EXPTIME", 0.1), ("TIMESYS", "TT")], "TIMESYS is TT"),
    ([("ROWORDER", "LEFT-RIGHT")], "ROWORDER = 'LEFT-RIGHT'"),
    ([("SITELAT", "north")], "SITELAT = 'north'"),
])
def test_bad_keywords_are_one_line_errors(tmp_path, cards, message):
    for extension in (False, True):
        path = _write(tmp_path / f"k{extension}.fits", cards, extension=extension)
        with pytest.raises(ShipstarError, match=message) as info:
            read_fits_header(path)
        assert "\n" not in str(info.value)


def test_bad_date_obs_is_is_refused(tmp_path):
    path = _write(tmp_path / "a.fits", [("DATE-OBS", START), ("EXPTIME", 0.1)])
    for call in (lambda: read_fits_header(path, date_obs_is="end"), lambda: scan_frames(tmp_path, date_obs_is="x")):
        with pytest.raises(ShipstarError, match="date_obs_is must be one of start, mid"):
            call()


# -- header keywords -----------------------------------------------------------------------

def test_quick_card_scan_agrees_with_astropy(tmp_path):
    """A primary image is read from the fixed-format cards, an extension by astropy: same info."""
    from shipstar._fitsio import _quick_primary_header

    cards = [("DATE-OBS", START), ("EXPTIME", 0.08), ("SENSOR", "O'Brien A1"), ("INSTRUME", "A1 cam"),
             ("TIMESYS", "UTC"), ("ROWORDER", "BOTTOM-UP"), ("SITELAT", "+31 54 00"), ("SITELONG", "120:18:00.36"),
             ("SITEELEV", 5.5), ("PRESSURE", 1021.7), ("TEMPERAT", -3.25), ("REFRMOD", "erfa"), ("SIMFRAME", "HOR")]
    quick = read_fits_header(_write(tmp_path / "q.fits", cards))
    assert _quick_primary_header(tmp_path / "q.fits") is not None
    slow = read_fits_header(_write(tmp_path / "x.fits", cards, extension=True))
    assert _quick_primary_header(tmp_path / "x.fits") is None
    assert quick == FitsFrameInfo(**{**slow.__dict__, "name": "q.fits"})
    assert quick.sensor == "O'Brien A1" and quick.instrume == "A1 cam" and quick.sensor_name == "O'Brien A1"
    assert quick.lat_deg == pytest.approx(31.9, abs=1e-12) and quick.lon_deg == pytest.approx(120.3001, abs=1e-12)
    assert (quick.height_m, quick.pressure_hpa, quick.temperature_c) == (5.5, 1021.7, -3.25)
    assert quick.refraction_model == "erfa" and quick.sim_frame == "hor" and quick.row_order == "bottom-up"
    assert quick.shape_hw == (6, 5) and quick.exposure_s == 0.08


def test_keywords_of_the_primary_header_are_inherited(tmp_path):
    from astropy.io import fits

    primary = fits.PrimaryHDU()
    primary.header["DATE-OBS"] = START
    primary.header["EXPTIME"] = 0.02
    fits.HDUList([primary, fits.ImageHDU(_image())]).writeto(tmp_path / "p.fits")
    info = read_fits_header(tmp_path / "p.fits")
    assert info.time_source == "DATE-OBS+EXPTIME/2" and _seconds_apart(info, _astropy_jd(START, 0.01)) < 1e-6


# -- row order -----------------------------------------------------------------------------

@pytest.mark.parametrize("roworder, flipped", [(None, False), ("TOP-DOWN", False), ("BOTTOM-UP", True)])
def test_row_order_is_honoured_by_every_reader(tmp_path, roworder, flipped):
    """Row 0 of what shipstar returns is always the top of the image (y down)."""
    stored = _image()
    top_down = stored[::-1] if flipped else stored
    cards = [("DATE-OBS", START), ("EXPTIME", 0.1)] + ([("ROWORDER", roworder)] if roworder else [])
    for extension in (False, True):
        path = _write(tmp_path / f"r{extension}.fits", cards, stored, extension=extension)
        for got in (read_fits(path)[0], read_fits_image(path), read_image(path), read_fits_frame(path)[0]):
            assert got.dtype == np.uint16 and got.dtype.isnative
            np.testing.assert_array_equal(got, top_down)


def test_a_star_near_the_top_is_found_near_the_top(tmp_path):
    """A bottom-up file of a star in the top rows: the extractor sees it at small y."""
    from shipstar.extract import extract_stars

    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:64, 0:64]
    top_down = rng.poisson(100 + 5000 * np.exp(-((xx - 40.3) ** 2 + (yy - 9.6) ** 2) / 2.0)).astype(np.uint16)
    path = _write(tmp_path / "s.fits", [("ROWORDER", "BOTTOM-UP")], top_down[::-1])
    found = extract_stars(read_image(path))
    assert len(found) == 1 and np.allclose(found.xy_px[0], [40.3, 9.6], atol=0.05)


# -- broken files --------------------------------------------------------------------------

# -- the direct reader of plain images against astropy.io.fits -----------------------------

def _astropy_pixels(path):
    """Reference: astropy.io.fits's pixels of the primary HDU, native byte order."""
    from astropy.io import fits

    with fits.open(path, memmap=False) as hdul:
        data = np.asarray(hdul[0].data)
    return data.astype(data.dtype.newbyteorder("="))


def _via_astropy(monkeypatch, call, path):
    """What shipstar's reader gives with its direct path switched off (astropy reads)."""
    from shipstar import _fitsio

    with monkeypatch.context() as m:
        m.setattr(_fitsio, "_quick_read", lambda *args: None)
        return call(path)


_PLAIN = [
    (np.uint8, 8, None), (np.int16, 16, None), (np.uint16, 16, 32768), (np.int32, 32, None),
    (np.uint32, 32, 2147483648), (np.float32, -32, None), (np.float64, -64, None),
]


@pytest.mark.parametrize("dtype, bitpix, bzero", _PLAIN)
@pytest.mark.parametrize("roworder, shape", [(None, (37, 53)), ("BOTTOM-UP", (37, 53)), (None, (613, 517))])
def test_plain_images_are_read_directly_as_astropy_reads_them(tmp_path, monkeypatch, dtype, bitpix, bzero, roworder,
                                                             shape):
    """Pixels and header as astropy's; (613, 517) spans several of the reader's 256 KiB
    chunks (``_cfits.read_swap``) with a partial one at the end for every BITPIX."""
    from astropy.io import fits

    from shipstar._fitsio import _quick_read

    rng = np.random.default_rng(bitpix + 100)
    info = np.iinfo(dtype) if np.dtype(dtype).kind in "ui" else None
    data = (rng.integers(info.min, info.max, size=shape, endpoint=True, dtype=dtype) if info is not None
            else rng.normal(0.0, 1e3, size=shape).astype(dtype))
    cards = [("DATE-OBS", START), ("EXPTIME", 0.08), ("SENSOR", "A1"), ("SITELAT", 31.9), ("PRESSURE", 1012.5)]
    path = _write(tmp_path / "plain.fits", cards + ([("ROWORDER", roworder)] if roworder else []), data)
    header = fits.getheader(path)
    assert header["BITPIX"] == bitpix and header.get("BZERO") == bzero         # the case this test means
    assert _quick_read(path, "start") is not None                               # ... read directly
    assert _quick_read(path, None) is not None                                  # (the pixels alone too)
    image, meta = read_fits(path)
    expected = _astropy_pixels(path)
    expected = expected[::-1] if roworder else expected
    assert image.dtype == expected.dtype == np.dtype(dtype) and image.dtype.isnative
    np.testing.assert_array_equal(image, expected)
    np.testing.assert_array_equal(read_fits_image(path), expected)
    assert meta == _via_astropy(monkeypatch, read_fits, path)[1]
    assert image.flags.writeable and image.flags.c_contiguous


@pytest.mark.parametrize("n_history", [0, 30, 70, 110, 400])
def test_headers_of_any_length_are_read_as_astropy_reads_them(tmp_path, monkeypatch, n_history):
    """Headers of 1, 2, 3, 4 and 12 blocks: the direct reader reads two blocks first and the
    rest only without an END card among them; cards, header length and pixels as astropy's."""
    from astropy.io import fits

    from shipstar._fitsio import _quick_primary_header, _quick_read

    data = np.arange(37 * 53, dtype=np.int16).reshape(37, 53)
    path = tmp_path / "long.fits"
    hdu = fits.PrimaryHDU(data)
    hdu.header["DATE-OBS"] = START
    for k in range(n_history):
        hdu.header.add_history(f"line {k} of a long processing history")
    hdu.header["EXPTIME"] = 0.08                       # after the history: read from the last block
    hdu.header["SENSOR"] = "A1"
    hdu.writeto(path)
    n_blocks = len(fits.getheader(path).tostring()) // 2880
    assert n_blocks == {0: 1, 30: 2, 70: 3, 110: 4, 400: 12}[n_history]
    assert _quick_primary_header(path) is not None
    quick = _quick_read(path, "start")
    assert quick is not None
    np.testing.assert_array_equal(quick[0], _astropy_pixels(path))
    assert quick[1].exposure_s == 0.08 and quick[1].sensor == "A1"
    assert read_fits_header(path) == _via_astropy(monkeypatch, read_fits_header, path)


@pytest.mark.parametrize("cards", [[("BSCALE", 2.0)], [("BZERO", 10.0)], [("BLANK", 7)]])
def test_scaled_images_are_left_to_astropy(tmp_path, cards):
    from astropy.io import fits

    from shipstar._fitsio import _quick_read

    data = np.arange(30, dtype=np.int16).reshape(6, 5)
    hdu = fits.PrimaryHDU(data)
    for key, value in cards:
        hdu.header[key] = value
    hdu.header["DATE-OBS"], hdu.header["EXPTIME"] = START, 0.08
    hdu.writeto(tmp_path / "scaled.fits")
    path = tmp_path / "scaled.fits"
    assert _quick_read(path, "start") is None
    image = read_fits_image(path)
    expected = _astropy_pixels(path)
    assert image.dtype == expected.dtype
    np.testing.assert_array_equal(image, expected)


def test_a_truncated_plain_image_is_left_to_astropy(tmp_path):
    from shipstar._fitsio import _quick_read

    data = _good_bytes(tmp_path)
    (tmp_path / "trunc.fits").write_bytes(data[:len(data) - 3000])
    assert _quick_read(tmp_path / "good.fits", None) is not None
    assert _quick_read(tmp_path / "trunc.fits", None) is None
    # a frame of several read chunks, cut inside its second chunk, its last one, and by one byte
    big = _write(tmp_path / "big.fits", [("DATE-OBS", START), ("EXPTIME", 0.1)],
                 np.arange(700 * 600, dtype=np.int32).reshape(700, 600)).read_bytes()
    assert _quick_read(tmp_path / "big.fits", None) is not None
    data_end = len(big) - (-700 * 600 * 4) % 2880                  # before the last block's padding
    for cut in (400_000, data_end - 3000, data_end - 1):
        (tmp_path / "cut.fits").write_bytes(big[:cut])
        assert _quick_read(tmp_path / "cut.fits", None) is None, cut


def _good_bytes(tmp_path):
    path = _write(tmp_path / "good.fits", [("DATE-OBS", START), ("EXPTIME", 0.1)], np.zeros((64, 64), np.uint16))
    return path.read_bytes()


def test_truncated_and_corrupt_files_are_one_line_errors(tmp_path):
    """No astropy warning escapes (pytest turns warnings into errors) and no traceback text."""
    data = _good_bytes(tmp_path)
    (tmp_path / "trunc.fits").write_bytes(data[:len(data) - 3000])
    (tmp_path / "short_header.fits").write_bytes(data[:2000])
    (tmp_path / "garbage.fits").write_bytes(b"SIMPLE  = garbage")
    cases = [("trunc.fits", "truncated FITS file .*trunc.fits: .*actual file length"),
             ("short_header.fits", "corrupt or unreadable FITS file .*short_header.fits: .*Header size"),
             ("garbage.fits", "garbage.fits"), ("missing.fits", "no such file")]
    for name, message in cases:
        for call in (read_fits, read_fits_image, read_image, read_fits_frame):
            with pytest.raises(ShipstarError, match=message) as info:
                call(tmp_path / name)
            assert "\n" not in str(info.value), (name, call)
    for call in (read_fits, read_fits_image, read_fits_header, read_fits_frame):
        with pytest.raises(ShipstarError, match="is a directory, not a FITS file"):
            call(tmp_path)
    for call in (read_fits_header,):
        with pytest.raises(ShipstarError, match="no such file"):
            call(tmp_path / "missing.fits")


def test_no_image_and_cubes(tmp_path):
    from astropy.io import fits

    table = fits.BinTableHDU.from_columns([fits.Column(name="a", format="E", array=np.zeros(3))])
    fits.HDUList([fits.PrimaryHDU(), table]).writeto(tmp_path / "table.fits")
    with pytest.raises(ShipstarError, match="no 2-D image"):
        read_fits_header(tmp_path / "table.fits")
    fits.PrimaryHDU(np.zeros((2, 8, 8))).writeto(tmp_path / "cube.fits")
    with pytest.raises(ShipstarError, match=r"shape \(2, 8, 8\), not one 2-D image"):
        read_fits(tmp_path / "cube.fits")
    fits.PrimaryHDU(np.ones((1, 8, 6), np.float32)).writeto(tmp_path / "plane.fits")
    image, info = read_fits(tmp_path / "plane.fits")
    assert image.shape == (8, 6) == info.shape_hw


# -- shipstar's own frames -----------------------------------------------------------------

def test_simulated_frames_read_back_at_their_mid_exposure_time(tmp_path):
    """The simulator writes DATE-OBS = start (FITS standard) and DATE-AVG = mid; every reader
    gets the truth time back to the microsecond, also without DATE-AVG (from DATE-BEG
    and DATE-END)."""
    from astropy.io import fits

    from shipstar.camera import camera_preset
    from shipstar.simulate import ShipPose, simulate_frame, write_frame
    from shipstar.sky.apparent import Site

    frame = simulate_frame(camera_preset("A1"), ship=ShipPose.from_deg(46.47, 1.0, -2.0, 185.1, 39.4),
                           utc_iso="2013-03-15T12:16:00.130400", site=Site.from_deg(31.9, 120.3), seed=2)
    path, _ = write_frame(frame, tmp_path / "A1_00000.fits")
    hdr = fits.getheader(path)
    assert hdr["DATE-AVG"] == "2013-03-15T12:16:00.130400" and hdr["DATE-OBS"] == "2013-03-15T12:16:00.090400"
    assert hdr["DATE-BEG"] == hdr["DATE-OBS"] and hdr["DATE-END"] == "2013-03-15T12:16:00.170400"
    assert hdr["ROWORDER"] == "TOP-DOWN" and hdr["EXPTIME"] == 0.08
    (f,) = scan_frames(tmp_path)
    assert f.time_source == "DATE-AVG" and f.exposure_s == 0.08 and f.sensor == "A1"
    assert abs(f.seconds_since(frame.utc_jd1, frame.utc_jd2)) < 1e-6
    del hdr["DATE-AVG"]
    fits.writeto(tmp_path / "b.fits", frame.image, hdr)
    info = read_fits_header(tmp_path / "b.fits")
    assert info.time_source == "DATE-BEG+(DATE-END-DATE-BEG)/2"
    assert _seconds_apart(info, (frame.utc_jd1, frame.utc_jd2)) < 1e-6
    image, jd = read_fits_frame(path)
    np.testing.assert_array_equal(image, frame.image)


def test_remembered_card_values_are_the_parsed_ones():
    """_card_value_of (the quick scan's remembered parse of a card's bytes) gives what
    _card_value gives for the decoded card, again and again: quoted strings with ''
    escapes, T/F, numbers with comments, non-ASCII bytes."""
    from shipstar._fitsio import _card_value, _card_value_of

    cards = [b"SENSOR  = 'A1      '           / sensor name",
             b"OBJECT  = 'it''s   '",
             b"SIMPLE  =                    T",
             b"EXTEND  =                    F / no",
             b"EXPTIME =                 0.08 / s",
             b"SITELAT = '+31 54 00'",
             b"INSTRUME= 'caf\xe9'",
             b"NAXIS1  =                 1024"]
    for card in cards:
        card = card.ljust(80)
        want = _card_value(card.decode("ascii", "replace"))
        for _ in range(2):
            got = _card_value_of(card)
            assert got == want and type(got) is type(want)


def test_a_whole_file_in_memory_is_not_advised_again(tmp_path, monkeypatch):
    """``advise_will_read`` of a whole file asks the OS to read it ahead unless its last byte
    is in the page cache already (the advice walks every page: ~40 us a 2 MB frame in memory
    on some hosts); a header's advice is always given; the page-cache test says no past the
    end of a file, and the advice is given when it says no -- always, where the OS has no
    ``RWF_NOWAIT`` (the advice itself is recorded here, whether or not the OS has it)."""
    import os

    from shipstar import _fitsio

    path = tmp_path / "frame.bin"
    path.write_bytes(bytes(range(256)) * 64)
    assert path.read_bytes()[-1] == 255                          # read: in the page cache now
    calls = []
    monkeypatch.setattr(_fitsio, "_FADVISE", lambda fd, offset, length, advice: calls.append((offset, length)))
    if _fitsio._NOWAIT is not None:                               # Linux 4.14+: the look itself
        _fitsio.advise_will_read(path)
        assert calls == []
        _fitsio.advise_will_read(path, 5760)
        assert calls == [(0, 5760)]
        fd = os.open(path, os.O_RDONLY)
        try:
            size = os.fstat(fd).st_size
            assert _fitsio._in_page_cache(fd, size - 1) and not _fitsio._in_page_cache(fd, size)
            assert not _fitsio._in_page_cache(fd, -1)
        finally:
            os.close(fd)
        calls.clear()
    monkeypatch.setattr(_fitsio, "_NOWAIT", None)                 # an OS that cannot tell
    fd = os.open(path, os.O_RDONLY)
    try:
        assert not _fitsio._in_page_cache(fd, os.fstat(fd).st_size - 1)
    finally:
        os.close(fd)
    _fitsio.advise_will_read(path)
    monkeypatch.undo()
    monkeypatch.setattr(_fitsio, "_FADVISE", lambda fd, offset, length, advice: calls.append((offset, length)))
    monkeypatch.setattr(_fitsio, "_in_page_cache", lambda fd, offset: False)
    _fitsio.advise_will_read(path)
    assert calls == [(0, 0), (0, 0)]
