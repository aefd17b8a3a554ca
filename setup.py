"""Build of shipstar's compiled kernels (plain C, Python's buffer protocol, no NumPy headers).

Everything else about the package is in ``pyproject.toml``.  The kernels are C99 compiled
by the C compiler that builds Python's own extensions (gcc here), at install time from the
sources in the package: nothing is downloaded and nothing is compiled at run time.
"""

import hashlib
from pathlib import Path

from setuptools import Extension, setup

_CFLAGS = ["-O3", "-std=c99", "-fno-math-errno", "-Wall"]

#: QUEST in C, included by the identification and attitude kernels
_QUEST_H = ["src/shipstar/_cquest.h"]
#: every module's SOURCE_SHA256 export, included by all of them
_CSOURCE_H = "src/shipstar/_csource.h"


def _kernel(name: str, source: str, depends=()) -> Extension:
    """One compiled module, which carries the SHA-256 of its C sources (``SOURCE_SHA256``:
    each file's path and bytes) for ``shipstar._codeid.code_identity``: a Dask worker whose
    kernels were built from other sources is refused by the archive's tasks."""
    depends = [_CSOURCE_H, *depends]
    digest = hashlib.sha256()
    for path in (source, *depends):
        data = Path(path).read_bytes()
        digest.update(f"{path}\0{len(data)}\0".encode() + data)
    return Extension(name, [source], extra_compile_args=_CFLAGS, depends=depends,
                     define_macros=[("SHIPSTAR_SOURCE_SHA256", f'"{digest.hexdigest()}"')])


EXTENSIONS = [
    _kernel("shipstar._cfits", "src/shipstar/_cfits.c"),
    _kernel("shipstar.extract._ckernels", "src/shipstar/extract/_ckernels.c"),
    _kernel("shipstar.identify._ckernels", "src/shipstar/identify/_ckernels.c", _QUEST_H),
    _kernel("shipstar.attitude._ckernels", "src/shipstar/attitude/_ckernels.c", _QUEST_H),
]

setup(ext_modules=EXTENSIONS)
