"""A progress bar on stderr: redrawn in place on a terminal, one line per stage otherwise."""

from __future__ import annotations

import sys
import time

__all__ = ["Progress"]

_WIDTH = 30


class Progress:
    """Stages of known size, each advanced with :meth:`advance`.

    Parameters
    ----------
    stream : file, optional
        Default ``sys.stderr``.
    enabled : bool
        False: print nothing.
    """

    def __init__(self, stream=None, enabled: bool = True):
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.tty = enabled and bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.perf_counter()
        self._stage, self._total, self._done, self._t_stage = "", 0, 0, self.t0

    def stage(self, name: str, total: int) -> None:
        """Start a stage of ``total`` steps."""
        self._stage, self._total, self._done, self._t_stage = name, max(int(total), 1), 0, time.perf_counter()
        self._draw()

    def advance(self, steps: int = 1) -> None:
        self._done = min(self._done + int(steps), self._total)
        if self.tty:
            self._draw()

    def finish(self, note: str = "") -> None:
        """End the stage: one final line with its duration."""
        self._done = self._total
        if not self.enabled:
            return
        dt = time.perf_counter() - self._t_stage
        text = f"{self._bar()} {self._stage}: done in {dt:.1f} s{(' (' + note + ')') if note else ''}"
        self.stream.write(("\r" + text + "\x1b[K\n") if self.tty else text + "\n")
        self.stream.flush()

    def _bar(self) -> str:
        n = int(round(_WIDTH * self._done / self._total))
        return f"[{'#' * n}{'.' * (_WIDTH - n)}] {self._done}/{self._total}"

    def _draw(self) -> None:
        if not self.tty:
            return
        elapsed = time.perf_counter() - self.t0
        self.stream.write(f"\r{self._bar()} {self._stage} ({elapsed:.0f} s)\x1b[K")
        self.stream.flush()
