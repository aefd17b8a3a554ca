"""Stop long-running commands cleanly on SIGINT / SIGTERM.

``with StopOnSignals() as stop:`` replaces the handlers of SIGINT and SIGTERM by one that
sets ``stop`` (a :class:`threading.Event`) and records which signal came in
``stop.reason`` (``"SIGINT"``, ``"SIGTERM"``); the loop checks ``stop.is_set()`` between
units of work, finishes the current one, closes its files and reports.  A second signal
of the same kind while stopping raises :class:`KeyboardInterrupt` (the impatient user).
The previous handlers are restored on exit.  Outside the main thread nothing is installed.
"""

from __future__ import annotations

import signal
import threading

__all__ = ["StopOnSignals", "EXIT_CODES"]

#: Exit code of a command stopped by each signal (128 + the signal number).
EXIT_CODES = {"SIGINT": 130, "SIGTERM": 143}


class _StopEvent(threading.Event):
    reason: str = ""


class StopOnSignals:
    """Context manager: a stop event set by SIGINT or SIGTERM."""

    def __init__(self):
        self.event = _StopEvent()
        self._old: dict = {}

    def _handler(self, signum, frame):
        name = signal.Signals(signum).name
        if self.event.is_set() and name == self.event.reason:
            raise KeyboardInterrupt
        self.event.reason = name
        self.event.set()

    def __enter__(self) -> _StopEvent:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handler)
        return self.event

    def __exit__(self, *exc) -> None:
        for sig, old in self._old.items():   # None: a handler not set from Python
            signal.signal(sig, signal.SIG_DFL if old is None else old)
        self._old.clear()
