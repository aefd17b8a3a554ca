"""shipstar._digest: CPython's own SHA-256 for cache keys gives hashlib's digests (the
cache files keep their names) and does not load OpenSSL."""

from __future__ import annotations

import hashlib
import subprocess
import sys

import numpy as np

from shipstar._digest import sha256_hex


def test_sha256_hex_is_hashlibs_digest():
    rng = np.random.default_rng(4)
    for n in (0, 1, 55, 56, 63, 64, 65, 1000, 1 << 16):
        data = rng.bytes(n)
        assert sha256_hex(data) == hashlib.sha256(data).hexdigest()
    assert sha256_hex(b"abc") == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"  # FIPS 180-2


def test_naming_a_star_database_does_not_load_openssl():
    code = ("import sys; from shipstar.identify._database import _cache_path, params_for_field; "
            "_cache_path(params_for_field(0.2, 0.15)); "
            "print('_hashlib' in sys.modules, 'hashlib' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "False"]
