"""Reusable full-frame work arrays, one set per thread.

A smeared frame needs a few frame-sized float32 arrays (the padded frame, the line
filter's partial sums and its output). Freshly allocated, each 4 MB array costs ~1000
page faults (~2 ms for a 1024 x 1024 frame, more than the arithmetic on it): the
allocator hands freed blocks this large back to the kernel. They are kept here instead,
keyed by purpose, and reused (a buffer only grows). The contents are undefined on
return; an array must not outlive the call that took it, nor be taken twice at once
(nothing returned to the caller refers to one).
"""

from __future__ import annotations

import threading

import numpy as np

__all__ = ["scratch", "MAX_KEPT_BYTES"]

_local = threading.local()
#: Larger arrays are allocated afresh each time, not kept (~7 arrays of this size at most
#: per thread: a 2048 x 2048 float32 frame still fits).
MAX_KEPT_BYTES = 24 * 2 ** 20


def scratch(key: str, shape: tuple, dtype) -> np.ndarray:
    """An uninitialised C-contiguous array of ``shape`` and ``dtype`` for purpose ``key``.

    A view of a per-thread buffer that only grows (shapes change from call to call: the
    stars still being fitted), so that the same memory is reused.
    """
    pool = _local.__dict__.setdefault("pool", {})
    dtype = np.dtype(dtype)
    shape = tuple(int(s) for s in shape)
    size = int(np.prod(shape, dtype=np.int64))
    if size * dtype.itemsize > MAX_KEPT_BYTES:            # a huge frame: not kept (its other costs dominate)
        return np.empty(shape, dtype=dtype)
    buf = pool.get((key, dtype.str))
    if buf is None or buf.size < size:
        buf = np.empty(max(size, 1), dtype=dtype)
        pool[(key, dtype.str)] = buf
    return buf[:size].reshape(shape)
