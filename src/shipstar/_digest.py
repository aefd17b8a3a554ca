"""SHA-256 of short keys (cache file names) without loading OpenSSL.

``import hashlib`` loads OpenSSL's libcrypto (``_hashlib``) to offer its constructors:
5-40 ms per process on the development host (typically ~8 ms), paid by every one-shot
``shipstar solve`` only to name its cache files from a few hundred bytes of key.
CPython's own SHA-256 (the module ``hashlib`` itself falls back to: ``_sha2`` from
3.12, ``_sha256`` before) gives the same digest and loads in well under a millisecond;
it is slower on large inputs (~2x on 2 MiB), which keep ``hashlib``.
"""

from __future__ import annotations

import functools

__all__ = ["sha256_hex"]


@functools.cache
def _constructor():
    """The SHA-256 constructor (found once)."""
    try:
        from _sha2 import sha256                   # CPython >= 3.12
    except ImportError:
        try:
            from _sha256 import sha256             # CPython <= 3.11
        except ImportError:
            from hashlib import sha256             # any other Python
    return sha256


def sha256_hex(data: bytes) -> str:
    """The SHA-256 of ``data`` as 64 hex digits (``hashlib.sha256(data).hexdigest()``)."""
    return _constructor()(data).hexdigest()
