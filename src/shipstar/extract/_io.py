"""Reading frames: FITS, PNG, TIFF, JPEG and NumPy ``.npy``, recognised by their first bytes.

Integer data keep their dtype (an 8-bit JPEG stays ``uint8``, a 12-bit frame in a
16-bit PNG or FITS stays ``uint16``) so that the saturation level can be inferred.
FITS files are read by :func:`shipstar._fitsio.read_fits_image`, shipstar's one FITS
reader (rows flipped for ``ROWORDER = 'BOTTOM-UP'``, so row 0 is always the top).
Colour images become luminance with ITU-R 601 weights (Pillow's ``convert("L")``; a
colour JPEG's stored luminance is decoded directly, the same pixels but for rounding).
An 8-bit greyscale or YCbCr JPEG is decoded by libjpeg-turbo through simplejpeg (its
luminance alone, the same pixels as Pillow's, which loads in ~30 ms against ~1 ms);
Pillow reads every other JPEG (CMYK, 12-bit, multi-picture, corrupt: its errors).
An image Pillow would read is refused (one-line error) over twice Pillow's decompression-bomb
size ``PIL.Image.MAX_IMAGE_PIXELS`` (179 Mpx by default); below that it is read without
Pillow's bomb warning (which it gives from 89 Mpx).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from shipstar.errors import ShipstarError

__all__ = ["read_image", "IMAGE_FORMATS"]

IMAGE_FORMATS = ("FITS", "PNG", "TIFF", "JPEG", "NPY")

_MAGIC = (
    (b"SIMPLE  =", "FITS"),
    (b"\x1f\x8b", "FITS"),           # gzip: astropy reads .fits.gz
    (b"\x89PNG\r\n\x1a\n", "PNG"),
    (b"II*\x00", "TIFF"),
    (b"MM\x00*", "TIFF"),
    (b"\xff\xd8\xff", "JPEG"),
    (b"\x93NUMPY", "NPY"),
)


def _sniff(path: Path) -> str:
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except FileNotFoundError:
        raise ShipstarError(f"no such file: {path}") from None
    except IsADirectoryError:
        raise ShipstarError(f"is a directory, not an image: {path}") from None
    except OSError as exc:
        raise ShipstarError(f"cannot read {path}: {exc.strerror or exc}") from None
    for magic, kind in _MAGIC:
        if head.startswith(magic):
            return kind
    raise ShipstarError(f"{path} is not an image file ({', '.join(IMAGE_FORMATS)})")


def _read_fits(path: Path) -> np.ndarray:
    """The image of a FITS file by shipstar's one FITS reader (``shipstar._fitsio``: first
    HDU with 2-D data, ``ROWORDER`` applied, one-line errors for corrupt files)."""
    from shipstar._fitsio import read_fits_image

    return read_fits_image(path)


#: Pillow's decompression-bomb size (``PIL.Image.MAX_IMAGE_PIXELS``): a larger JPEG goes
#: to Pillow, which refuses it over twice that size as it does every image
_JPEG_DIRECT_MAX_PIXELS = 89_478_485


def _has_multi_picture_segment(data: bytes) -> bool:
    """Whether a JPEG's header segments (up to its first scan) hold an APP2 ``MPF`` one:
    a multi-picture file (MPO), which Pillow reads as frames (and shipstar refuses)."""
    i = 2                                            # after SOI
    while i + 4 <= len(data) and data[i] == 0xFF:
        marker = data[i + 1]
        if marker == 0xFF:                           # fill byte
            i += 1
            continue
        if marker == 0xDA:                           # start of scan: no more header segments
            return False
        n = int.from_bytes(data[i + 2:i + 4], "big")
        if marker == 0xE2 and data[i + 4:i + 8] == b"MPF\x00":
            return True
        i += 2 + n
    return False


def _read_jpeg_direct(path: Path) -> np.ndarray | None:
    """The luminance of an 8-bit greyscale or YCbCr JPEG decoded by libjpeg-turbo
    (simplejpeg, ``colorspace="GRAY"``: the Y plane alone, as Pillow's ``draft("L")``
    decodes it; the same pixels, tested on every real photo), or None when it is not one
    (CMYK, RGB, 12-bit or lossless, multi-picture, over Pillow's size limit, unreadable,
    corrupt, or simplejpeg missing): Pillow reads those and words their errors."""
    try:
        import simplejpeg
    except ImportError:
        return None
    try:
        data = path.read_bytes()
    except OSError:
        return None
    if _has_multi_picture_segment(data):
        return None
    try:
        h, w, colorspace, _ = simplejpeg.decode_jpeg_header(data)
        if colorspace not in ("Gray", "YCbCr") or h * w > _JPEG_DIRECT_MAX_PIXELS:
            return None
        arr = simplejpeg.decode_jpeg(data, colorspace="GRAY")
    except ValueError:                               # corrupt, truncated, not baseline 8-bit
        return None
    return arr.reshape(h, w) if arr.size == h * w and arr.dtype == np.uint8 else None


def _too_large(path: Path, kind: str, exc: Exception) -> str:
    """The one-line refusal of an image over Pillow's decompression-bomb limit (twice
    ``PIL.Image.MAX_IMAGE_PIXELS``), with its pixel count and the limit from Pillow's ``exc``."""
    import re

    found = re.search(r"\((\d+) pixels\) exceeds limit of (\d+) pixels", str(exc))
    if found is None:
        return f"{kind} file {path} is too large to read: {' '.join(str(exc).split())}"
    return (f"{kind} file {path} is too large: {int(found[1])} pixels, over the limit of {int(found[2])} "
            "(Pillow's decompression-bomb limit)")


def _read_pillow(path: Path, kind: str, writable: bool) -> np.ndarray:
    import warnings

    from PIL import Image, UnidentifiedImageError

    # np.asarray shares the bytes Pillow exports (read only); np.array copies them, one
    # more image-sized allocation (a 1920 x 1080 JPEG: ~1-15 ms here, the first touch of
    # fresh pages being the slow part on this host)
    as_array = np.array if writable else np.asarray

    try:
        with warnings.catch_warnings():
            # a local frame under Pillow's hard limit is read whole, whatever its size
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                if kind == "JPEG" and im.mode == "RGB":
                    # a colour JPEG stores the 601 luminance (Y of YCbCr): decoded alone (no
                    # chroma, no RGB), the same pixels as convert("L") but for rounding
                    im.draft("L", None)
                im.load()
                if getattr(im, "n_frames", 1) > 1:
                    raise ShipstarError(f"{path} holds {im.n_frames} frames; give one frame per file")
                if im.mode in ("L", "I;16", "I;16B", "I;16L", "I", "F"):
                    arr = as_array(im)
                else:
                    arr = as_array(im.convert("L"))
    except ShipstarError:
        raise
    except Image.DecompressionBombError as exc:
        raise ShipstarError(_too_large(path, kind, exc)) from None
    except (OSError, ValueError, UnidentifiedImageError, SyntaxError) as exc:
        raise ShipstarError(f"corrupt or unreadable {kind} file {path}: {exc}") from None
    return arr


def _read_npy(path: Path) -> np.ndarray:
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise ShipstarError(f"corrupt or unreadable .npy file {path}: {exc}") from None


def read_image(path) -> np.ndarray:
    """Read one frame as a 2-D array (height, width), writable.

    Parameters
    ----------
    path : str or os.PathLike
        A FITS (first HDU with 2-D data, top row first per ``ROWORDER``; a 3-D cube only
        if it has one plane), PNG, TIFF,
        JPEG or ``.npy`` file. The format is recognised from the file's first bytes.

    Returns
    -------
    (H, W) array in native byte order: integer files keep their dtype, colour becomes
    luminance (``uint8`` for 8-bit colour).

    Raises
    ------
    ShipstarError
        Missing file, unknown format, corrupt content, or not a single 2-D image.
    """
    return read_image_any(path, writable=True)


def read_image_any(path, *, writable: bool) -> np.ndarray:
    """:func:`read_image`, with ``writable=False`` allowed to return a read-only array
    (an image that Pillow reads, a PNG or TIFF say, is then not copied out of Pillow's
    bytes: what a one-shot solve reads)."""
    path = Path(path)
    kind = _sniff(path)
    if kind == "FITS":
        arr = _read_fits(path)
    elif kind == "NPY":
        arr = _read_npy(path)
    else:
        arr = _read_jpeg_direct(path) if kind == "JPEG" else None
        if arr is None:
            arr = _read_pillow(path, kind, writable)
    if arr.ndim > 2:
        squeezed = arr.reshape(arr.shape[-2:]) if int(np.prod(arr.shape[:-2])) == 1 else arr
        if squeezed.ndim != 2:
            raise ShipstarError(f"{path} holds an array of shape {arr.shape}, not one 2-D image")
        arr = squeezed
    if arr.ndim != 2:
        raise ShipstarError(f"{path} holds an array of shape {arr.shape}, not a 2-D image")
    if arr.dtype.kind not in "uif":
        raise ShipstarError(f"{path} holds {arr.dtype} data, not an image")
    if not arr.dtype.isnative:
        arr = arr.astype(arr.dtype.newbyteorder("="))
    return arr
