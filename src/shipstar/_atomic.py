"""Atomic file output: a crash never leaves a half-written file that looks complete.

Every writer in shipstar (FITS frames, TOML files, CSV, HTML reports, PNG plots, caches)
goes through :func:`atomic_path`: the data are written to a temporary file beside the
target and renamed over it only when writing succeeded.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator

from shipstar.errors import ShipstarError

__all__ = ["atomic_path", "atomic_write_text", "atomic_write_bytes"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path, *, suffix: str = ".tmp", what: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it over ``path`` on success.

    On any exception inside the ``with`` block the temporary file is removed and the
    exception propagates; ``path`` is left as it was.  The final file's permissions follow
    the umask (``mkstemp`` alone would make it 0600).  ``suffix`` lets writers that choose
    the format from the file name (matplotlib, astropy) see the right extension; ``what``
    names the file in error messages ("the report", "camera file").

    Raises
    ------
    ShipstarError
        When the directory cannot be created or written.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
    except OSError as exc:
        label = f"{what} " if what else ""
        raise ShipstarError(f"cannot write {label}{path}: {exc.strerror or exc}") from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_text(path, text: str, *, newline: str | None = None, what: str = "") -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns the path."""
    with atomic_path(path, what=what) as tmp:
        with open(tmp, "w", encoding="utf-8", newline=newline) as fh:
            fh.write(text)
    return Path(path)


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)
