"""Operating-system errors in shipstar's words, naming the user's path.

A ``PermissionError: [Errno 13] Permission denied: 'out/att.csv.partial'`` names a file
the user never gave (the partial output beside ``--out``), in Python's words.
:func:`os_error_message` says what shipstar was doing with which of the command's
paths: ``cannot write --out out/att.csv (out/att.csv.partial): permission denied``.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

__all__ = ["os_error_message"]

_REASONS = {
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.ENOENT: "no such file or directory",
    errno.EEXIST: "already exists",
    errno.ENOTDIR: "a part of the path is a file, not a directory",
    errno.EISDIR: "is a directory, not a file",
    errno.ENOSPC: "no space left on the device",
    errno.EROFS: "read-only file system",
    errno.ENAMETOOLONG: "name too long",
    errno.EMFILE: "too many open files",
    errno.ENOTEMPTY: "directory not empty",
    errno.EIO: "input/output error",
}
#: Options whose paths shipstar writes (the rest it reads).
_WRITTEN = {"out", "plots", "plot", "to", "out_dir", "report", "udp_out"}


def _user_paths(args):
    """``[(option, path), ...]`` of the command line's path-like values."""
    out = []
    for key, value in sorted(vars(args).items()):
        if key in ("run", "caught_warnings", "command") or key.endswith("_command"):
            continue
        values = value if isinstance(value, (list, tuple)) else [value]
        for v in values:
            if isinstance(v, tuple) and len(v) == 2 and all(isinstance(x, str) for x in v):
                v = v[1]                                   # NAME=PATH pairs
            if isinstance(v, (str, os.PathLike)) and str(v):
                out.append((key, str(v)))
    return out


def _related(a: Path, b: Path) -> int:
    """How closely two paths are related (0: not): the same, one inside the other, or one a
    name beside the other starting with its name (``x.csv`` and ``x.csv.partial``)."""
    if a == b:
        return 3
    if a in b.parents or b in a.parents:
        return 2
    if a.parent == b.parent and (a.name.startswith(b.name) or b.name.startswith(a.name)):
        return 1
    return 0


def os_error_message(exc: BaseException, args) -> str:
    """One line for an OSError (or MemoryError) raised while a command ran."""
    if isinstance(exc, MemoryError):
        return ("out of memory (reduce the size of the job: fewer points, samples or frames at once; "
                "see the command's --help for its limits)")
    reason = _REASONS.get(getattr(exc, "errno", None)) or (getattr(exc, "strerror", None) or str(exc) or
                                                           exc.__class__.__name__).lower()
    filename = getattr(exc, "filename", None)
    if filename is None:
        return f"{reason} ({exc.__class__.__name__})"
    failed = Path(os.fspath(filename))
    best, best_score = None, 0
    for key, value in _user_paths(args):
        p = Path(value)
        score = max(_related(failed, p), _related(failed.absolute(), p.absolute()))
        if score > best_score:
            best, best_score = (key, value), score
    if best is None:
        return f"{failed}: {reason}"
    key, value = best
    verb = "write" if key in _WRITTEN or key.endswith("_out") else "read"
    option = "--" + key.replace("_", "-")
    extra = "" if Path(value) == failed else f" ({failed})"
    return f"cannot {verb} {option} {value}{extra}: {reason}"
