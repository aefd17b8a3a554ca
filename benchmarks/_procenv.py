"""The environment of the shipstar commands a benchmark times as separate processes.

Bytecode: an installed shipstar has its ``.pyc`` files (pip compiles them at install); an
editable install writes them on its first run -- unless ``PYTHONDONTWRITEBYTECODE`` is
set (as on the development host), when every process compiles every shipstar source it
imports again (0.1-0.3 s a command here).  :func:`command_env` with a directory gives the
processes a bytecode cache of their own there (``PYTHONPYCACHEPREFIX``; nothing is
written into the source tree), filled once by :func:`precompile`: the commands start as
an installed package does.  Threads: one BLAS / OpenMP thread unless set otherwise.
"""

from __future__ import annotations

import compileall
import os
import sys
from pathlib import Path


def command_env(bytecode_dir=None) -> dict:
    """``os.environ`` for a timed command: one BLAS thread, and with ``bytecode_dir`` a
    bytecode cache there (``PYTHONDONTWRITEBYTECODE`` dropped)."""
    env = dict(os.environ)
    env.setdefault("OMP_NUM_THREADS", "1")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    if bytecode_dir is not None:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env["PYTHONPYCACHEPREFIX"] = str(bytecode_dir)
    return env


def precompile(bytecode_dir) -> None:
    """Compile shipstar's sources into ``bytecode_dir`` (the cache :func:`command_env` names),
    as ``pip install`` compiles an installed package."""
    import shipstar

    previous = sys.pycache_prefix
    sys.pycache_prefix = str(bytecode_dir)          # compileall writes where the import system will look
    try:
        compileall.compile_dir(str(Path(shipstar.__file__).parent), quiet=1)
    finally:
        sys.pycache_prefix = previous
