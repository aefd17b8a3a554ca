"""The identity of the shipstar code a process runs (for the archive's remote workers).

A Dask worker of another machine may run another shipstar checkout than the command that
sent it tasks: its rows would differ from serial ``measure``'s without a word.  The
archive's job carries :func:`code_identity` of the command's process and every task
compares it with its own (``pipeline._measure.use_job_tables``).

The identity is the SHA-256 of the package's Python sources and data files (each file's
path within the package and its bytes; ``__pycache__`` and the compiled modules left out)
and of each compiled module's ``SOURCE_SHA256``, the digest of the C sources it was built
from (set by ``setup.py``).  So an editable install and a wheel of the same sources have
the same identity; a worker with one edited module, an older wheel, or kernels built from
other C sources has another.  The job also carries :func:`environment`, the versions the
numerics depend on besides (Python, NumPy, pyerfa and its ERFA library, the machine's
architecture), checked likewise; neither covers the C library's ``libm`` or the compiler's
version.
"""

from __future__ import annotations

import functools
from pathlib import Path

__all__ = ["code_identity", "environment", "software", "software_line", "tree_digest"]

#: The compiled modules whose C sources count (``SOURCE_SHA256``, from setup.py).
COMPILED_MODULES = ("shipstar._cfits", "shipstar.extract._ckernels", "shipstar.identify._ckernels",
                    "shipstar.attitude._ckernels")


def _counted(rel: Path) -> bool:
    """A file of the package that makes its rows: Python sources anywhere, data files."""
    if "__pycache__" in rel.parts:
        return False
    return rel.suffix == ".py" or (rel.parts[0] == "data" and len(rel.parts) > 1)


def tree_digest(root) -> str:
    """SHA-256 (hex) of the Python sources and data files under the package directory
    ``root``: each counted file's path relative to ``root`` (POSIX form) and its bytes, in
    path order."""
    import hashlib

    root = Path(root)
    digest = hashlib.sha256()
    files = sorted((rel.as_posix(), p) for p in root.rglob("*")
                   if p.is_file() and _counted(rel := p.relative_to(root)))
    for name, path in files:
        data = path.read_bytes()
        digest.update(f"{name}\0{len(data)}\0".encode() + data)
    return digest.hexdigest()


def environment() -> str:
    """The versions the rows' numerics depend on besides shipstar's own code: Python, NumPy,
    pyerfa and its ERFA library, and the machine's architecture, as one line."""
    import platform
    import sys

    import erfa
    import numpy

    return (f"python {'.'.join(map(str, sys.version_info[:3]))} {sys.implementation.name}; numpy {numpy.__version__}; "
            f"pyerfa {erfa.__version__} (erfa {erfa.version.erfa_version}); {platform.machine()}")


@functools.cache
def code_identity() -> str:
    """``"<version>:<sha256 hex>"`` of the shipstar code this process runs (see the module;
    computed once a process, ~10 ms)."""
    import hashlib
    import importlib

    import shipstar

    digest = hashlib.sha256(tree_digest(Path(shipstar.__file__).parent).encode())
    for name in COMPILED_MODULES:
        source = getattr(importlib.import_module(name), "SOURCE_SHA256", "")
        digest.update(f"\0{name}\0{source}".encode())
    return f"{shipstar.__version__}:{digest.hexdigest()}"


def software_line() -> str:
    """What made an output file, for its comment header: ``software = shipstar <version>,
    code <first 16 hex digits of the code identity>; <environment>``."""
    version, digest = code_identity().split(":")
    return f"software = shipstar {version}, code {digest[:16]}; {environment()}"


def software() -> dict:
    """The JSON summaries' ``software``: ``{"shipstar_version", "code_identity", "environment"}``."""
    import shipstar

    return {"shipstar_version": shipstar.__version__, "code_identity": code_identity(), "environment": environment()}
