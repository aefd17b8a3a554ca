"""A dependency-free progress bar on stderr (only on a terminal, or when asked)."""

from __future__ import annotations

import sys
import time

__all__ = ["ProgressBar"]


class ProgressBar:
    """Callable ``(label, done, total)`` that redraws one stderr line, at most 10 times a second.

    Parameters
    ----------
    enabled : bool or None
        None (default): only when stderr is a terminal.
    stream : file, optional
        Default ``sys.stderr``.
    width : int
        Characters of the bar.
    """

    def __init__(self, enabled: bool | None = None, stream=None, width: int = 30):
        self.stream = sys.stderr if stream is None else stream
        self.enabled = bool(getattr(self.stream, "isatty", lambda: False)()) if enabled is None else bool(enabled)
        self.width = int(width)
        self._last = 0.0
        self._open = False

    def __call__(self, label: str, done: int, total: int) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if done < total and now - self._last < 0.1:
            return
        self._last = now
        frac = done / total if total else 1.0
        fill = int(round(frac * self.width))
        self.stream.write(f"\r{label} [{'#' * fill}{'.' * (self.width - fill)}] {done}/{total}")
        self._open = True
        if done >= total:
            self.stream.write("\n")
            self._open = False
        self.stream.flush()

    def close(self) -> None:
        """End an unfinished line (after an error)."""
        if self.enabled and self._open:
            self.stream.write("\n")
            self.stream.flush()
            self._open = False
