"""Pipeline inputs: one sensor frame (:class:`Frame`) and FITS frame directories (:func:`scan_frames`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.units import DAY_S

__all__ = ["Frame", "scan_frames", "read_fits_frame", "check_sensor_name", "FITS_SUFFIXES"]

FITS_SUFFIXES = (".fits", ".fit", ".fts")


@dataclass(frozen=True, eq=False)
class Frame:
    """One frame of one sensor: its mid-exposure time and its data.

    Exactly one data form is used, in this order: ``xy_px`` (centroids: extraction is
    skipped; with ``hip`` also the identification), ``image`` (an array), ``path`` (a
    FITS file, read when processed).

    Attributes
    ----------
    utc_jd1, utc_jd2 : float
        Two-part UTC Julian date of mid-exposure.
    label : str
        Name in reports (file name, or ``"#index"``).
    path : Path or None
    image : (H, W) array or None
    xy_px : (N, 2) array or None
        Measured centroids, brightest first.
    hip : (N,) int array or None
        Known identities of ``xy_px`` (-1 for none).
    sensor : str
        Sensor named in the file (FITS ``SENSOR`` or ``INSTRUME``), '' if none.
    """

    utc_jd1: float
    utc_jd2: float
    label: str = ""
    path: Path | None = None
    image: np.ndarray | None = None
    xy_px: np.ndarray | None = None
    hip: np.ndarray | None = None
    sensor: str = ""

    def __post_init__(self):
        if self.path is None and self.image is None and self.xy_px is None:
            raise ShipstarError(f"frame {self.label!r} has no data (give a path, an image or centroids)")
        if not (np.isfinite(self.utc_jd1) and np.isfinite(self.utc_jd2)):
            raise ShipstarError(f"frame {self.label!r} has a non-finite time")
        if self.hip is not None and (self.xy_px is None or len(self.hip) != len(self.xy_px)):
            raise ShipstarError(f"frame {self.label!r}: hip must match xy_px row by row")

    @classmethod
    def from_centroids(cls, utc_jd1, utc_jd2, xy_px, hip=None, label: str = "") -> "Frame":
        """A centroid-level frame (``xy_px`` (N, 2), optional known ``hip`` (N,))."""
        xy = np.asarray(xy_px, float).reshape(-1, 2)
        return cls(float(utc_jd1), float(utc_jd2), label, xy_px=xy,
                   hip=None if hip is None else np.asarray(hip, np.int64).reshape(-1))

    def seconds_since(self, jd1: float, jd2: float) -> float:
        """Seconds from the two-part UTC JD ``(jd1, jd2)`` to this frame."""
        return ((self.utc_jd1 - jd1) + (self.utc_jd2 - jd2)) * DAY_S

    @property
    def utc_iso(self) -> str:
        from shipstar.sky.time import iso_from_utc_jd

        return iso_from_utc_jd(self.utc_jd1, self.utc_jd2, 3)


def _fits_error(path: Path, exc: Exception) -> ShipstarError:
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return ShipstarError(f"corrupt or unreadable FITS file {path}: {text}")


def _image_hdu(hdul, path: Path):
    for hdu in hdul:
        data = getattr(hdu, "data", None)
        if isinstance(data, np.ndarray) and data.ndim == 2 and data.dtype.fields is None:
            return hdu
    raise ShipstarError(f"FITS file {path} has no 2-D image")


def _date_obs(header, path: Path) -> tuple[float, float]:
    from shipstar.sky.time import utc_jd_from_iso

    text = header.get("DATE-OBS")
    if text is None:
        raise ShipstarError(f"frame {path} has no DATE-OBS (mid-exposure UTC) in its FITS header")
    timesys = str(header.get("TIMESYS", "UTC")).strip().upper()
    if timesys != "UTC":
        raise ShipstarError(f"frame {path}: TIMESYS is {timesys}, only UTC is supported")
    try:
        return utc_jd_from_iso(str(text))
    except ShipstarError as exc:
        raise ShipstarError(f"frame {path}: DATE-OBS: {exc}") from None


_CARD = 80
_BLOCK = 2880
_MAX_HEADER_BLOCKS = 36


def _card_value(card: str) -> str:
    """The value of a simple FITS card (``KEY     = 'text' / comment`` or a number)."""
    v = card[10:].strip()
    if v.startswith("'"):
        end = v.find("'", 1)
        while end != -1 and v[end + 1:end + 2] == "'":       # '' is an escaped quote
            end = v.find("'", end + 2)
        return v[1:end].replace("''", "'").rstrip() if end != -1 else v[1:]
    return v.split("/", 1)[0].strip()


def _quick_primary_header(path: Path) -> dict | None:
    """DATE-OBS, TIMESYS, SENSOR, INSTRUME of a primary 2-D image HDU read straight from the
    80-character header cards (the FITS standard's fixed format), ~50x faster than
    astropy's full header parse; None when the primary HDU is not a 2-D image (then the
    caller falls back to astropy, which also handles extensions and compression)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(_BLOCK * _MAX_HEADER_BLOCKS)
    except OSError:
        return None
    if not head.startswith(b"SIMPLE  ="):
        return None
    cards = {}
    for i in range(0, len(head) - _CARD + 1, _CARD):
        card = head[i:i + _CARD].decode("ascii", "replace")
        key = card[:8].strip()
        if key == "END":
            break
        if card[8:10] == "= " and key in ("NAXIS", "DATE-OBS", "TIMESYS", "SENSOR", "INSTRUME"):
            cards[key] = _card_value(card)
    else:
        return None
    return cards if cards.get("NAXIS") == "2" else None


def _read_header(path: Path):
    """Header of the first 2-D image HDU, without reading any data."""
    quick = _quick_primary_header(path)
    if quick is not None:
        return quick
    from astropy.io import fits

    try:
        with fits.open(path, memmap=False, lazy_load_hdus=True) as hdul:
            for hdu in hdul:
                if getattr(hdu, "is_image", False) and hdu.header.get("NAXIS", 0) == 2:
                    return hdu.header
        raise ShipstarError(f"FITS file {path} has no 2-D image")
    except ShipstarError:
        raise
    except (OSError, ValueError, TypeError, IndexError, KeyError, EOFError) as exc:
        raise _fits_error(path, exc) from None


def read_fits_frame(path) -> tuple[np.ndarray, tuple[float, float]]:
    """``(image (H, W), (utc_jd1, utc_jd2))`` of a FITS frame with DATE-OBS.

    Raises
    ------
    ShipstarError
        Missing or corrupt file, no 2-D image, no or bad DATE-OBS.
    """
    from astropy.io import fits

    path = Path(path)
    try:
        with fits.open(path, memmap=False) as hdul:
            hdu = _image_hdu(hdul, path)
            return np.asarray(hdu.data), _date_obs(hdu.header, path)
    except FileNotFoundError:
        raise ShipstarError(f"no such frame: {path}") from None
    except ShipstarError:
        raise
    except (OSError, ValueError, TypeError, IndexError, KeyError, EOFError) as exc:
        raise _fits_error(path, exc) from None


def check_sensor_name(frames, name: str, camera_name: str, where) -> None:
    """ShipstarError when a frame's file names a sensor that is neither ``name`` nor the
    camera model ``camera_name`` (simulated frames record the camera's name)."""
    other = sorted({f.sensor for f in frames if f.sensor and f.sensor not in (name, camera_name)})
    if other:
        raise ShipstarError(f"frames in {where} are from sensor {other[0]!r} (FITS SENSOR/INSTRUME), "
                            f"not {name!r}")


def scan_frames(directory) -> list[Frame]:
    """The FITS frames of a directory, in file-name order, with their DATE-OBS times.

    Parameters
    ----------
    directory : str or Path
        Holds ``*.fits`` / ``*.fit`` / ``*.fts`` frames of ONE sensor.

    Returns
    -------
    list of Frame
        ``path`` set, image not yet read.

    Raises
    ------
    ShipstarError
        Not a directory, no FITS files, a frame without DATE-OBS, or frames whose times
        do not increase strictly in file-name order (both files named).
    """
    d = Path(directory)
    if not d.is_dir():
        raise ShipstarError(f"frames directory {d} does not exist or is not a directory")
    paths = sorted(p for p in d.iterdir() if p.suffix.lower() in FITS_SUFFIXES and not p.name.startswith("."))
    if not paths:
        raise ShipstarError(f"no FITS frames (*.fits) in {d}")
    frames = []
    for p in paths:
        header = _read_header(p)
        jd1, jd2 = _date_obs(header, p)
        sensor = str(header.get("SENSOR", header.get("INSTRUME", ""))).strip()
        frames.append(Frame(jd1, jd2, p.name, path=p, sensor=sensor))
    for a, b in zip(frames, frames[1:]):
        if b.seconds_since(a.utc_jd1, a.utc_jd2) <= 0.0:
            raise ShipstarError(f"frames out of time order: {b.label} (DATE-OBS {b.utc_iso}) is not later than "
                                f"{a.label} ({a.utc_iso})")
    return frames
