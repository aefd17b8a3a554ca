"""FITS frames: shipstar's one FITS reader (the image and what its header says about it).

Every FITS file shipstar reads goes through this module (``docs/file-formats.md``):

    read_fits(path, *, date_obs_is="start") -> (image (H, W), FitsFrameInfo)
    read_fits_header(path, *, date_obs_is="start") -> FitsFrameInfo      # no pixel data
    read_fits_image(path) -> image (H, W)

**Time of a frame** (FITS 4.0 sec. 9.2.2: ``DATE-OBS`` is the *start* of the
observation, which is what camera drivers write).  The mid-exposure UTC is

1. ``DATE-AVG`` when present;
2. else the start (``DATE-BEG``, else ``DATE-OBS``) plus half the exposure: half of
   ``DATE-END`` minus the start when ``DATE-END`` is present, else ``EXPTIME / 2``
   (``EXPOSURE`` when there is no ``EXPTIME``);
3. with ``date_obs_is="mid"`` (for cameras that write the mid-exposure time into
   ``DATE-OBS``, against the standard) ``DATE-OBS`` as it stands when there is neither
   ``DATE-AVG`` nor ``DATE-BEG``.

A header with a start but no exposure length gives no time (``FitsFrameInfo.time_problem``
says why) rather than a time up to half an exposure late.  ``TIMESYS`` must be UTC.

**Row order**: ``ROWORDER = 'BOTTOM-UP'`` means the first row stored is the bottom of the
image; it is flipped so that row 0 is the top (``docs/conventions.md``: y down, top-left
pixel centre (0, 0)).  Without ``ROWORDER`` (or with ``'TOP-DOWN'``) the first row stored
is taken as the top, as camera drivers and shipstar's own simulator write it.

**Plain images are read directly**: a primary HDU holding a 2-D image of BITPIX 8, 16,
32, -32 or -64, unscaled or with the unsigned offset (``BZERO`` 32768 / 2147483648,
``BSCALE`` 1: uint16 / uint32, as astropy gives them), is read from its 80-character
cards and its big-endian pixels straight into the array (~8x faster than astropy for a
1024 x 1024 16-bit frame).  Everything else -- gzip, extensions, scaled data, ``BLANK``,
long-string cards, a truncated file -- is read by astropy, which gives the same pixels
and the same :class:`FitsFrameInfo` (``tests/test_fits_io.py`` compares the two).

astropy is imported only when a file is read that way.  Its warnings (a truncated file, a header
that is not a multiple of 2880 bytes) never reach the user: a file that cannot be read
raises one :class:`~shipstar.errors.ShipstarError` line naming the file and the cause.

Stage order (``tests/test_layering.py``): just above ``sky`` (dates are parsed by
``shipstar.sky.time``), below ``simulate`` (its truth check reads the image) and every
stage that reads frames.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import re
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shipstar import _cfits
from shipstar.errors import ShipstarError

__all__ = ["FitsFrameInfo", "read_fits", "read_fits_header", "read_fits_image", "FITS_SUFFIXES",
           "DATE_OBS_CHOICES", "ROW_ORDERS", "NO_DATE_TEXT", "is_fits_name", "file_is_complete"]

FITS_SUFFIXES = (".fits", ".fit", ".fts")


def is_fits_name(name: str) -> bool:
    """A frame file's name: ``*.fits``, ``*.fit``, ``*.fts``, each optionally ``.gz``
    (any case), and not a hidden (dot) file, as temporary files being written are."""
    low = str(name).lower()
    if low.startswith("."):
        return False
    low = low[:-3] if low.endswith(".gz") else low
    return low.endswith(FITS_SUFFIXES)

#: What ``DATE-OBS`` means: the start of the exposure (FITS standard) or its middle.
DATE_OBS_CHOICES = ("start", "mid")
ROW_ORDERS = ("top-down", "bottom-up")
#: In ``FitsFrameInfo.time_problem`` when the header has no date at all (not merely an
#: incomplete one).
NO_DATE_TEXT = "has no DATE-OBS, DATE-BEG or DATE-AVG"

_DAY_S = 86400.0
_CARD = 80
_BLOCK = 2880
_MAX_HEADER_BLOCKS = 36
#: Blocks read first (most headers fit in one): the rest up to :data:`_MAX_HEADER_BLOCKS`
#: only when their END card is not among them (reading 36 blocks of every frame cost
#: 46 us against 10 us for two, in the 1800-frame scan of a session 0.06 s).
_FIRST_HEADER_BLOCKS = 2
_EXPOSURE_KEYS = ("EXPTIME", "EXPOSURE")
_QUICK_KEYS = frozenset(("NAXIS", "NAXIS1", "NAXIS2", "DATE-OBS", "DATE-BEG", "DATE-AVG", "DATE-END", "EXPTIME",
                         "EXPOSURE", "TIMESYS", "SENSOR", "INSTRUME", "ROWORDER", "SITELAT", "SITELONG",
                         "SITEELEV", "PRESSURE", "TEMPERAT", "REFRMOD", "SIMFRAME"))
#: Cards of a plain image's data (``_quick_read``).
_DATA_KEYS = frozenset(("BITPIX", "BZERO", "BSCALE", "BLANK", "GROUPS"))
#: The keys of both, as the bytes of a card -> the key.
_USED_KEYS_B = {k.encode("ascii"): k for k in (*_QUICK_KEYS, *_DATA_KEYS)}
#: Those an image read without its metadata uses (``read_fits_image``): its size, data and
#: row order; the others (times, site, weather) change from frame to frame and are not parsed.
_IMAGE_KEYS_B = {k.encode("ascii"): k for k in ("NAXIS", "NAXIS1", "NAXIS2", "ROWORDER", *_DATA_KEYS)}
#: BITPIX -> stored dtype of the plain images read directly.
_PLAIN_DTYPES = {8: ">u1", 16: ">i2", 32: ">i4", -32: ">f4", -64: ">f8"}
#: (BITPIX, BZERO) of unsigned integers stored with an offset -> (XOR of the sign bit, dtype).
_UNSIGNED = {(16, 32768.0): (0x8000, np.uint16), (32, 2147483648.0): (0x80000000, np.uint32)}
_SEXAGESIMAL = re.compile(r"^\s*([+-]?)(\d+)[: ]+(\d+)(?:[: ]+(\d+(?:\.\d*)?))?\s*$")


@dataclass(frozen=True)
class FitsFrameInfo:
    """What a FITS frame's header says about it.

    Attributes
    ----------
    name : str
        The file's name (for messages).
    shape_hw : (int, int)
        Image height and width, pixels.
    utc_jd1, utc_jd2 : float
        Two-part UTC Julian date of mid-exposure; NaN when the header gives none.
    time_source : str
        How the time was found, e.g. ``"DATE-AVG"``, ``"DATE-OBS+EXPTIME/2"``,
        ``"DATE-OBS(mid)"``; ``""`` when there is no time.
    time_problem : str
        Why there is no time (one line, names the file); ``""`` when there is one.
    date_obs_is : str
        The meaning of ``DATE-OBS`` the file was read with (``"start"`` or ``"mid"``).
    exposure_s : float
        Exposure time (``EXPTIME``/``EXPOSURE``, else ``DATE-END - DATE-BEG``); NaN if unknown.
    instrume, sensor : str
        ``INSTRUME`` and ``SENSOR`` cards, ``""`` when absent.
    row_order : str
        ``"top-down"`` or ``"bottom-up"`` (as stored; images are returned top-down).
    lat_deg, lon_deg, height_m, pressure_hpa, temperature_c : float or None
        ``SITELAT``, ``SITELONG`` (east positive), ``SITEELEV``, ``PRESSURE``,
        ``TEMPERAT``; None when absent.
    refraction_model, sim_frame : str
        ``REFRMOD`` and ``SIMFRAME`` (shipstar's simulated frames), ``""`` when absent.
    """

    name: str
    shape_hw: tuple
    utc_jd1: float
    utc_jd2: float
    time_source: str
    time_problem: str
    date_obs_is: str
    exposure_s: float
    instrume: str
    sensor: str
    row_order: str
    lat_deg: float | None = None
    lon_deg: float | None = None
    height_m: float | None = None
    pressure_hpa: float | None = None
    temperature_c: float | None = None
    refraction_model: str = ""
    sim_frame: str = ""

    @property
    def has_time(self) -> bool:
        return not self.time_problem

    @property
    def sensor_name(self) -> str:
        """``SENSOR``, else ``INSTRUME`` (``""`` when neither)."""
        return self.sensor or self.instrume

    def mid_utc_jd(self) -> tuple[float, float]:
        """``(utc_jd1, utc_jd2)`` of mid-exposure; ShipstarError (``time_problem``) when unknown."""
        if self.time_problem:
            raise ShipstarError(self.time_problem)
        return self.utc_jd1, self.utc_jd2


# ------------------------------------------------------------------ header values

def _text(value) -> str:
    return "" if value is None else str(value).strip()


def _number(value, key: str, name: str) -> float:
    if isinstance(value, bool):
        value = None
    try:
        x = float(str(value).replace("D", "E")) if isinstance(value, str) else float(value)
    except (TypeError, ValueError):
        x = math.nan
    if not math.isfinite(x):
        raise ShipstarError(f"FITS file {name}: {key} = {value!r} is not a finite number")
    return x


def _angle_deg(value, key: str, name: str) -> float:
    """Degrees from a number or a sexagesimal string (``'+31 54 00'``, ``'31:54:00.5'``)."""
    m = _SEXAGESIMAL.match(value) if isinstance(value, str) else None
    if m is None:
        return _number(value, key, name)
    deg = int(m[2]) + int(m[3]) / 60.0 + (float(m[4]) if m[4] else 0.0) / 3600.0
    return -deg if m[1] == "-" else deg


def _optional(get, key: str, name: str, convert=_number):
    value = get(key)
    return None if value is None or _text(value) == "" else convert(value, key, name)


def _date(get, key: str, name: str) -> tuple[float, float]:
    from shipstar.sky.time import utc_jd_from_iso

    try:
        return utc_jd_from_iso(_text(get(key)))
    except ShipstarError as exc:
        raise ShipstarError(f"FITS file {name}: {key}: {exc}") from None


def _exposure(get, name: str) -> tuple[float, str]:
    """``(exposure_s, keyword)`` from EXPTIME/EXPOSURE; ``(nan, "")`` when neither."""
    for key in _EXPOSURE_KEYS:
        if get(key) is not None:
            t = _number(get(key), key, name)
            if t < 0.0:
                raise ShipstarError(f"FITS file {name}: {key} = {t} s is negative")
            return t, key
    return math.nan, ""


def _plus_s(jd: tuple[float, float], seconds: float) -> tuple[float, float]:
    return jd[0], jd[1] + seconds / _DAY_S


def _seconds(a: tuple[float, float], b: tuple[float, float]) -> float:
    return ((b[0] - a[0]) + (b[1] - a[1])) * _DAY_S


def _mid_time(get, name: str, date_obs_is: str):
    """``(jd1, jd2, source, problem, exposure_s)`` of mid-exposure (module docstring rules)."""
    exposure, exp_key = _exposure(get, name)
    if get("DATE-AVG") is not None:
        return (*_date(get, "DATE-AVG", name), "DATE-AVG", "", exposure)
    start_key = "DATE-BEG" if get("DATE-BEG") is not None else "DATE-OBS"
    if get(start_key) is None:
        return (math.nan, math.nan, "", f"frame {name} {NO_DATE_TEXT} (UTC of the exposure) in its FITS header",
                exposure)
    start = _date(get, start_key, name)
    if start_key == "DATE-OBS" and date_obs_is == "mid":
        return (*start, "DATE-OBS(mid)", "", exposure)
    if get("DATE-END") is not None:
        span = _seconds(start, _date(get, "DATE-END", name))
        if span < 0.0:
            raise ShipstarError(f"FITS file {name}: DATE-END is {-span:.6g} s before {start_key}")
        exposure = span if math.isnan(exposure) else exposure
        return (*_plus_s(start, 0.5 * span), f"{start_key}+(DATE-END-{start_key})/2", "", exposure)
    if exp_key:
        return (*_plus_s(start, 0.5 * exposure), f"{start_key}+{exp_key}/2", "", exposure)
    return (math.nan, math.nan, "", f"frame {name}: {start_key} is the start of the exposure but the FITS header "
                                    "has no EXPTIME, DATE-END or DATE-AVG to find mid-exposure (if its DATE-OBS "
                                    "is mid-exposure, read it with date_obs_is='mid')", exposure)


def _row_order(get, name: str) -> str:
    text = _text(get("ROWORDER")).upper()
    if text in ("", "TOP-DOWN"):
        return "top-down"
    if text == "BOTTOM-UP":
        return "bottom-up"
    raise ShipstarError(f"FITS file {name}: ROWORDER = {text!r} is neither 'TOP-DOWN' nor 'BOTTOM-UP'")


def _info(get, shape_hw, name: str, date_obs_is: str) -> FitsFrameInfo:
    """The metadata of a frame from a header look-up ``get(key) -> value or None``."""
    if date_obs_is not in DATE_OBS_CHOICES:
        raise ShipstarError(f"date_obs_is must be one of {', '.join(DATE_OBS_CHOICES)}, got {date_obs_is!r}")
    timesys = _text(get("TIMESYS") or "UTC").upper()
    if timesys != "UTC":
        raise ShipstarError(f"frame {name}: TIMESYS is {timesys}, only UTC is supported")
    jd1, jd2, source, problem, exposure = _mid_time(get, name, date_obs_is)
    return FitsFrameInfo(
        name=name, shape_hw=tuple(int(n) for n in shape_hw), utc_jd1=jd1, utc_jd2=jd2, time_source=source,
        time_problem=problem, date_obs_is=date_obs_is, exposure_s=exposure, instrume=_text(get("INSTRUME")),
        sensor=_text(get("SENSOR")), row_order=_row_order(get, name),
        lat_deg=_optional(get, "SITELAT", name, _angle_deg), lon_deg=_optional(get, "SITELONG", name, _angle_deg),
        height_m=_optional(get, "SITEELEV", name), pressure_hpa=_optional(get, "PRESSURE", name),
        temperature_c=_optional(get, "TEMPERAT", name), refraction_model=_text(get("REFRMOD")),
        sim_frame=_text(get("SIMFRAME")).lower())


# ------------------------------------------------------------------ quick header scan

def _card_value(card: str):
    """The value of a fixed-format card: ``str`` (quoted), ``bool`` (T/F), else the text."""
    v = card[10:].strip()
    if v.startswith("'"):
        end = v.find("'", 1)
        while end != -1 and v[end + 1:end + 2] == "'":       # '' is an escaped quote
            end = v.find("'", end + 2)
        return v[1:end].replace("''", "'").rstrip() if end != -1 else v[1:]
    v = v.split("/", 1)[0].strip()
    return {"T": True, "F": False}.get(v, v)


@functools.lru_cache(maxsize=1024)
def _card_value_of(card: bytes):
    """:func:`_card_value` of an 80-byte card as read (decoded as ASCII, other bytes
    replaced), remembered: a session's frames repeat most of their cards (size, sensor,
    site, exposure), ~1.8 us a card otherwise."""
    return _card_value(card.decode("ascii", "replace"))


def _quick_cards(head: bytes, keys_b: dict = _USED_KEYS_B):
    """``(cards, header_bytes)`` of a primary 2-D image HDU from the first bytes of its file:
    the cards of ``keys_b`` (default those shipstar uses, ``_QUICK_KEYS`` and ``_DATA_KEYS``;
    ``_IMAGE_KEYS_B`` for the pixels alone) read straight from the
    80-character header cards (the standard's fixed format), ~50x faster than astropy's
    full parse, and the header's length (whole 2880-byte blocks); None when the primary
    HDU is not a plain 2-D image (astropy then reads it, which also handles extensions,
    compression and unusual cards)."""
    if not head.startswith(b"SIMPLE  ="):
        return None
    cards = {}
    for i in range(0, len(head) - _CARD + 1, _CARD):
        key = head[i:i + 8].strip()                 # compared as bytes: only the cards used are decoded
        if key == b"END":
            header_bytes = -(-(i + _CARD) // _BLOCK) * _BLOCK
            break
        if key == b"CONTINUE":                      # a long string: leave it to astropy
            return None
        if key in keys_b and head[i + 8:i + 10] == b"= ":
            cards[keys_b[key]] = _card_value_of(head[i:i + _CARD])
    else:
        return None
    if cards.get("NAXIS") != "2" or not str(cards.get("NAXIS1", "")).isdigit() \
            or not str(cards.get("NAXIS2", "")).isdigit():
        return None
    return cards, header_bytes


_END_CARD = b"END" + b" " * 77


def _read_head(fh) -> bytes:
    """The first bytes of a FITS file for its primary header: :data:`_FIRST_HEADER_BLOCKS`
    blocks, or :data:`_MAX_HEADER_BLOCKS` when no END card starts a card among them."""
    head = fh.read(_BLOCK * _FIRST_HEADER_BLOCKS)
    if len(head) == _BLOCK * _FIRST_HEADER_BLOCKS:
        i = head.find(_END_CARD)
        while i != -1 and i % _CARD:
            i = head.find(_END_CARD, i + 1)
        if i == -1:
            head += fh.read(_BLOCK * (_MAX_HEADER_BLOCKS - _FIRST_HEADER_BLOCKS))
    return head


def _quick_primary_header(path: Path) -> dict | None:
    """The cards shipstar uses of a primary 2-D image HDU (:func:`_quick_cards`), or None."""
    try:
        with open(path, "rb") as fh:
            head = _read_head(fh)
    except OSError:
        return None
    quick = _quick_cards(head)
    return None if quick is None else quick[0]


def _plain_dtype(cards: dict):
    """``(stored dtype (big-endian), unsigned offset's XOR mask or 0, dtype returned)`` of a
    plain image: BITPIX 8/16/32/-32/-64 unscaled (no BZERO/BSCALE, or 0/1), or 16/32-bit
    integers with the unsigned offset (BZERO = 2^15 / 2^31, BSCALE = 1), which astropy
    returns as uint16 / uint32; None for anything else (scaled data, BLANK, random groups)."""
    try:
        bitpix = int(str(cards.get("BITPIX", "")))
        bzero = float(str(cards.get("BZERO", "0")).replace("D", "E"))
        bscale = float(str(cards.get("BSCALE", "1")).replace("D", "E"))
    except ValueError:
        return None
    if bitpix not in _PLAIN_DTYPES or "BLANK" in cards or "GROUPS" in cards or bscale != 1.0:
        return None
    if bzero == 0.0:
        stored = np.dtype(_PLAIN_DTYPES[bitpix])
        return stored, 0, stored.newbyteorder("=")
    if (bitpix, bzero) in _UNSIGNED:
        mask, dtype = _UNSIGNED[(bitpix, bzero)]
        return np.dtype(_PLAIN_DTYPES[bitpix]), mask, np.dtype(dtype)
    return None


#: The compiled in-place byte swap serves little-endian hosts (big-endian ones: NumPy).
_LITTLE_ENDIAN = sys.byteorder == "little"

_local = threading.local()
#: Largest read buffer kept for the next frame (larger images get a fresh one).
_MAX_KEPT_BYTES = 64 * 2 ** 20


def _read_buffer(nbytes: int) -> np.ndarray:
    """A per-thread byte buffer of ``nbytes`` for the pixels as stored, reused from frame to
    frame (a fresh 2 MB array costs ~500 page faults on first touch)."""
    buf = getattr(_local, "buffer", None)
    if buf is None or buf.size < nbytes:
        buf = np.empty(nbytes, dtype=np.uint8)
        if nbytes <= _MAX_KEPT_BYTES:
            _local.buffer = buf
    return buf[:nbytes]


def _quick_read(path: Path, date_obs_is: str | None):
    """``(image, FitsFrameInfo or None)`` of a plain FITS image read directly (the header's
    cards, then the pixels straight into the array, byte-swapped in place), or None when
    it is not one that this reader takes with certainty (:func:`_plain_dtype`; gzip,
    extensions, a short file...): astropy reads those (and words their errors)."""
    try:
        with open(path, "rb") as fh:
            quick = _quick_cards(_read_head(fh), _USED_KEYS_B if date_obs_is is not None else _IMAGE_KEYS_B)
            if quick is None:
                return None
            cards, header_bytes = quick
            kind = _plain_dtype(cards)
            if kind is None:
                return None
            stored, mask, dtype = kind
            shape = (int(cards["NAXIS2"]), int(cards["NAXIS1"]))
            if min(shape) < 1:
                return None
            fh.seek(header_bytes)
            if _LITTLE_ENDIAN:
                # the pixels straight into the image, turned to native order in place (and
                # the unsigned offset's sign bit flipped) chunk by chunk as they are read
                data = np.empty(shape, dtype=dtype)
                got = -2
                if data.itemsize > 1:
                    got = _cfits.read_swap(fh.fileno(), header_bytes, data, data.size, data.itemsize, int(mask))
                if got == -2:                                # bytes, or no pread here: read, then swap
                    got = fh.readinto(data.reshape(-1).view(np.uint8))
                    if got == data.nbytes and data.itemsize > 1:
                        _cfits.swap_xor(data, data.size, data.itemsize, int(mask))
                if got != data.nbytes:
                    return None                              # truncated: astropy says so
            else:
                raw = _read_buffer(shape[0] * shape[1] * stored.itemsize)
                if fh.readinto(raw) != raw.nbytes:
                    return None
                data = None
    except (OSError, ValueError):
        return None
    if data is None:                        # a big-endian host: one NumPy pass from the read buffer
        if mask:                            # the unsigned offset: flip the sign bit of the stored integers
            data = np.empty(shape, dtype=dtype)
            np.bitwise_xor(raw.view(stored.newbyteorder(">").str.replace("i", "u")).reshape(shape),
                           dtype.type(mask), out=data)
        else:
            data = raw.view(stored).reshape(shape).astype(stored.newbyteorder("="))
    name = path.name
    row_order = _row_order(cards.get, name)
    info = None if date_obs_is is None else _info(cards.get, shape, name, date_obs_is)
    return _oriented(data, row_order, name), info


def _gzip_is_complete(path: Path) -> tuple[bool, str]:
    import gzip
    import zlib

    try:
        with gzip.open(path, "rb") as fh:
            while fh.read(1 << 20):
                pass
    except (EOFError, OSError, zlib.error) as exc:
        return False, f"gzip: {exc}"
    return True, ""


def file_is_complete(path) -> tuple[bool, str]:
    """Whether a frame file has been written to its end: ``(complete, detail)``.

    A plain FITS file is complete when it holds its header up to ``END`` and the primary
    image's ``NAXIS1 * NAXIS2 * |BITPIX| / 8`` bytes after it (the padding of the last
    block is not required); a gzipped one when it decompresses to its end.  Files whose
    primary HDU is not a plain 2-D image are taken as complete (astropy reads them, and
    says so if they are not).  ``detail`` says what is missing (one line).
    """
    path = Path(path)
    if path.name.lower().endswith(".gz"):
        return _gzip_is_complete(path)
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            head = _read_head(fh)
    except OSError as exc:
        return False, f"{type(exc).__name__}: {exc.strerror or exc}"
    if len(head) < _BLOCK:
        return False, f"{size} bytes, not yet one header block"
    if not head.startswith(b"SIMPLE  ="):
        return True, ""
    cards = {}
    for i in range(0, len(head) - _CARD + 1, _CARD):
        key = head[i:i + 8].decode("ascii", "replace").strip()
        if key == "END":
            header_bytes = -(-(i + _CARD) // _BLOCK) * _BLOCK
            break
        if key in ("NAXIS", "NAXIS1", "NAXIS2", "BITPIX") and head[i + 8:i + 10] == b"= ":
            cards[key] = _card_value(head[i:i + _CARD].decode("ascii", "replace"))
    else:
        return False, f"{size} bytes, no END card yet"
    try:
        if int(cards.get("NAXIS", 0)) != 2:
            return True, ""
        data = int(cards["NAXIS1"]) * int(cards["NAXIS2"]) * abs(int(cards["BITPIX"])) // 8
    except (KeyError, ValueError):
        return True, ""
    if size < header_bytes + data:
        return False, f"{size} of {header_bytes + data} bytes"
    return True, ""


# ------------------------------------------------------------------ astropy

def _first_line(text: str) -> str:
    lines = [s.strip() for s in str(text).splitlines() if s.strip()]
    return lines[0] if lines else ""


def _warning_detail(caught) -> str:
    """The cause astropy gave in a warning (truncation, bad header size), one line."""
    for w in caught:
        text = str(w.message)
        if "truncated" in text:
            return _first_line(text)
    for w in caught:
        lines = [s.strip() for s in str(w.message).splitlines() if s.strip()]
        if len(lines) > 1 and lines[0].startswith("Error validating header"):
            return lines[1]
    return ""


@contextlib.contextmanager
def _astropy_guard(path: Path):
    """Turn astropy's exceptions and warnings about a bad file into one ShipstarError line."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            yield
        except ShipstarError:
            raise
        except FileNotFoundError:
            raise ShipstarError(f"no such file: {path}") from None
        except IsADirectoryError:
            raise ShipstarError(f"is a directory, not a FITS file: {path}") from None
        except (OSError, ValueError, TypeError, IndexError, KeyError, EOFError, MemoryError) as exc:
            detail = _warning_detail(caught)
            text = _first_line(str(exc)) or type(exc).__name__
            if detail and "truncated" in detail:
                raise ShipstarError(f"truncated FITS file {path}: {detail}") from None
            raise ShipstarError(f"corrupt or unreadable FITS file {path}: {text}"
                                + (f" ({detail})" if detail else "")) from None


def _shape_hw(header, name: str) -> tuple[int, int]:
    naxis = int(header.get("NAXIS", 0))
    shape = tuple(int(header.get(f"NAXIS{k}", 0)) for k in range(naxis, 0, -1))
    if naxis > 2 and math.prod(shape[:-2]) != 1:
        raise ShipstarError(f"{name} holds an array of shape {shape}, not one 2-D image")
    return shape[-2:]


def _image_hdu(hdul, name: str):
    """The first HDU holding an image of 2 or more axes."""
    for hdu in hdul:
        if getattr(hdu, "is_image", False) and int(hdu.header.get("NAXIS", 0)) >= 2:
            return hdu
    raise ShipstarError(f"FITS file {name} has no 2-D image")


def _lookup(image_header, primary_header):
    """``get(key)``: the image HDU's card, else the primary header's (inherited keywords)."""
    def get(key):
        value = image_header.get(key)
        return primary_header.get(key) if value is None and primary_header is not None else value
    return get


def _open(path: Path, *, with_data: bool, date_obs_is: str | None):
    """``(image or None, FitsFrameInfo or None)``; ``date_obs_is=None``: the image only
    (only ``ROWORDER`` is read from the header)."""
    if with_data:
        quick = _quick_read(path, date_obs_is)    # None for a missing file or a directory too
        if quick is not None:
            return quick
    path = _check_path(path)                      # their messages before astropy's
    from astropy.io import fits

    name = path.name
    info = None
    with _astropy_guard(path):
        with fits.open(path, memmap=False, lazy_load_hdus=True) as hdul:
            hdu = _image_hdu(hdul, name)
            shape = _shape_hw(hdu.header, name)
            get = _lookup(hdu.header, hdul[0].header if hdu is not hdul[0] else None)
            row_order = _row_order(get, name)
            if date_obs_is is not None:
                info = _info(get, shape, name, date_obs_is)
            data = np.asarray(hdu.data) if with_data else None
    if data is not None:
        data = _oriented(data.reshape(shape), row_order, name)
    return data, info


def _oriented(data: np.ndarray, row_order: str, name: str) -> np.ndarray:
    """Native byte order, top row first."""
    if data.dtype.fields is not None or data.dtype.kind not in "uif":
        raise ShipstarError(f"FITS file {name} holds {data.dtype} data, not an image")
    if not data.dtype.isnative:
        data = data.astype(data.dtype.newbyteorder("="))
    return np.ascontiguousarray(data[::-1]) if row_order == "bottom-up" else data


def _check_path(path) -> Path:
    path = Path(path)
    if not path.exists():
        raise ShipstarError(f"no such file: {path}")
    if path.is_dir():
        raise ShipstarError(f"is a directory, not a FITS file: {path}")
    return path


# ------------------------------------------------------------------ public

#: ``os.posix_fadvise`` where the OS has it (Linux, most Unix; not macOS or Windows).
_FADVISE = getattr(os, "posix_fadvise", None)
#: ``preadv(..., RWF_NOWAIT)`` where the OS has it (Linux 4.14+): a read that fails at once
#: (``BlockingIOError``) rather than wait for the disk, i.e. a test of the page cache.
_NOWAIT = getattr(os, "RWF_NOWAIT", None) if hasattr(os, "preadv") else None


def _in_page_cache(fd: int, offset: int) -> bool:
    """Whether the byte of file ``fd`` at ``offset`` is in the OS's page cache (a one-byte
    ``preadv`` with ``RWF_NOWAIT``; ~2 us).  False where the OS or the file system cannot
    tell (the caller then advises as before)."""
    if _NOWAIT is None or offset < 0:
        return False
    try:
        return os.preadv(fd, [bytearray(1)], offset, _NOWAIT) == 1
    except OSError:                                 # BlockingIOError: not in memory; EOPNOTSUPP...
        return False


#: Bytes of a file a header read takes first (:data:`_FIRST_HEADER_BLOCKS` blocks).
HEADER_READ_BYTES = _BLOCK * _FIRST_HEADER_BLOCKS


def advise_will_read(path, length: int = 0) -> None:
    """Tell the OS that the first ``length`` bytes of the file ``path`` (0: all of it) will be
    read soon (``posix_fadvise(..., POSIX_FADV_WILLNEED)``): it starts reading them from the
    disk in the background and returns at once, so that the read itself later finds them in
    memory.  Nothing happens where the OS has no such call or the file cannot be opened (the
    read reports that).  ~5 us a call for a header; a frame not in the page cache stalled its
    read by 1.3-3.3 ms here without it, 0.8-1.1 ms with it (docs/pipeline.md *Reading
    ahead*).  A whole file (``length`` 0) whose last byte is in memory already is not
    advised: the advice walks every page of the file, ~40 us for a 2 MB frame in memory on
    some hosts, against ~3 us for the look (:func:`_in_page_cache`)."""
    if _FADVISE is None or path is None:
        return
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        if length == 0 and _in_page_cache(fd, os.fstat(fd).st_size - 1):
            return
        _FADVISE(fd, 0, int(length), os.POSIX_FADV_WILLNEED)
    except OSError:
        pass
    finally:
        os.close(fd)


def read_fits_header(path, *, date_obs_is: str = "start") -> FitsFrameInfo:
    """The metadata of a FITS frame, without reading its pixels.

    Parameters
    ----------
    path : str or Path
    date_obs_is : {"start", "mid"}
        What ``DATE-OBS`` means (module docstring); the FITS standard says ``"start"``.

    Returns
    -------
    FitsFrameInfo
        Its ``time_problem`` says why when the header gives no mid-exposure time.

    Raises
    ------
    ShipstarError
        Missing or corrupt file, no 2-D image, a malformed date or keyword.
    """
    path = Path(path)
    quick = _quick_primary_header(path)          # None for a missing file or a directory too
    if quick is not None:
        return _info(quick.get, (int(quick["NAXIS2"]), int(quick["NAXIS1"])), path.name, date_obs_is)
    return _open(_check_path(path), with_data=False, date_obs_is=date_obs_is)[1]


def read_fits(path, *, date_obs_is: str = "start") -> tuple[np.ndarray, FitsFrameInfo]:
    """The image ``(H, W)`` (top row first, native byte order) and metadata of a FITS frame.

    The image is the first HDU with 2 or more axes (extra axes of length 1 dropped);
    integer data keep their dtype (``uint16`` via ``BZERO``).

    Raises
    ------
    ShipstarError
        Missing, truncated or corrupt file, no single 2-D image, a malformed date or keyword.
    """
    return _open(Path(path), with_data=True, date_obs_is=date_obs_is)


def read_fits_image(path) -> np.ndarray:
    """Only the image ``(H, W)`` of :func:`read_fits`: of the header only ``ROWORDER`` is
    used (a frame without a time, or with unusual keywords, still gives its pixels)."""
    return _open(Path(path), with_data=True, date_obs_is=None)[0]
