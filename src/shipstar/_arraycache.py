"""Cache files of NumPy arrays: read back whole, or not at all.

The caches of the catalog (``hip2_v*.npz``), the navigation stars (``nav_v*.npz``), the
Earth orientation table (``eop_v*.npz``) and the sorted magnitudes (``hipmag_v*.npy``)
only save time: a file that is missing, cut short, damaged or of the other kind is
``None`` here and the caller builds the data again.  Written atomically
(:func:`shipstar._atomic.atomic_path`), so a crash leaves the old file or none.

The file is opened here, not by ``np.load(path)``: given a path, NumPy hands its file to
the zip reader when the first bytes look like a zip and leaves it open when the zip then
cannot be read (a ``ResourceWarning``, an error under the test suite's warnings filter).
"""

from __future__ import annotations

import numpy as np

from shipstar.errors import ShipstarError

__all__ = ["read_arrays", "write_arrays", "read_array", "write_array"]


def read_arrays(path, names) -> dict | None:
    """``{name: array}`` of the ``names`` stored in the ``.npz`` file ``path``; None when the
    file is missing or unreadable, is not an ``.npz`` or lacks one of the names."""
    import zipfile                  # here: not every command reads a cache

    try:
        with open(path, "rb") as fh:
            z = np.load(fh, allow_pickle=False)
            if not isinstance(z, np.lib.npyio.NpzFile):
                return None
            with z:
                return {name: z[name] for name in names}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None


def write_arrays(path, arrays: dict) -> bool:
    """Store ``arrays`` (``{name: array}``) in the ``.npz`` file ``path``; False, leaving
    nothing behind, when the directory cannot be written."""
    from shipstar._atomic import atomic_path

    try:
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
        return True
    except (OSError, ShipstarError):
        return False


def read_array(path) -> np.ndarray | None:
    """The array stored in the ``.npy`` file ``path``; None when the file is missing or
    unreadable, or is not an ``.npy``."""
    import zipfile

    try:
        with open(path, "rb") as fh:
            a = np.load(fh, allow_pickle=False)
            if not isinstance(a, np.ndarray):
                a.close()
                return None
            return a
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        return None


def write_array(path, array) -> bool:
    """Store ``array`` in the ``.npy`` file ``path``; False, leaving nothing behind, when
    the directory cannot be written."""
    from shipstar._atomic import atomic_path

    try:
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.save(fh, array)
        return True
    except (OSError, ShipstarError):
        return False
