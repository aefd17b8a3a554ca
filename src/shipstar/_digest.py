"""SHA-256 of short keys (cache file names) without loading OpenSSL.

``import hashlib`` loads OpenSSL's libcrypto (``_hashlib``) to offer its constructors:
5-40 ms per process on the development host (typically ~8 ms), paid by every one-shot
``shipstar solve`` only to name its cache files from a few hundred bytes of key.
CPython's own SHA-256 (the module ``hashlib`` itself falls back to: ``_sha2`` from
3.12, ``_sha256`` before) gives the same digest and loads in well under a millisecond;
it is slower on large inputs (~2x on 2 MiB), which keep ``hashlib``.
"""

from __future__ import annotations

__all__ = ["sha256_hex"]


_SHA256 = []          # the constructor, found once


def _constructor():
    if not _SHA256:
        try:
            from _sha2 import sha256                   # CPython >= 3.12
        except ImportError:
            try:
                from _sha256 import sha256             # CPython <= 3.11
            except ImportError:
                from hashlib import sha256             # any other Python
        _SHA256.append(sha256)
    return _SHA256[0]


def sha256_hex(data: bytes) -> str:
    """The SHA-256 of ``data`` as 64 hex digits (``hashlib.sha256(data).hexdigest()``)."""
    return _constructor()(data).hexdigest()
