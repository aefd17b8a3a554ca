"""New frame files in the sensors' directories, from file-system events (watchfiles).

A thread runs :func:`watchfiles.watch` over the sensor directories (not recursive, a
millisecond's grouping) and puts ``("file", sensor, path, monotonic_s)`` on the main
loop's queue for each FITS name (:func:`shipstar._fitsio.is_fits_name`: ``.fits``,
``.fit``, ``.fts``, optionally ``.gz``; dot-files and other temporary names are ignored)
that was added or modified.  Whether the file is complete is the main loop's business
(:func:`shipstar._fitsio.file_is_complete`): a frame renamed into place is complete at
its first event, one written in place after its last write.

A directory that disappears is reported (``("dir-gone", sensor, path)``; one missing at
the start: ``("dir-wait", ...)``) and watched when it comes (back): ``("dir-back",
sensor, path)``, its frames then present taken as new.  The watch is restarted over the
directories that exist.
"""

from __future__ import annotations

import os
import queue
import threading
import time
from pathlib import Path

__all__ = ["FrameWatcher"]

#: How long a batch of file events is grouped before it is handed on (ms).
STEP_MS = 1
DEBOUNCE_MS = 20
#: How often the watch wakes up without events to check the directories (ms).
TICK_MS = 250


class FrameWatcher:
    """Watches the sensors' directories in a thread.

    Parameters
    ----------
    dirs : dict of sensor name -> Path
    events : queue.Queue
        Where the events go.
    """

    def __init__(self, dirs: dict, events: queue.Queue):
        self.dirs = {name: Path(d).resolve() for name, d in dirs.items()}
        self._by_dir = {str(d): name for name, d in self.dirs.items()}
        self.events = events
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="shipstar-live-watch", daemon=True)
        self.n_events = 0
        self._before = None                      # names present at start (until the watch is set up)

    def start(self) -> "FrameWatcher":
        # what is there now is not a new frame; what appears before the watch is set up in
        # its thread is, and the first look after the set-up finds it (_run)
        self._before = {}
        for name, d in self.dirs.items():
            try:
                self._before[name] = set(os.listdir(d))
            except OSError:
                pass
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def _run(self) -> None:
        import watchfiles

        gone: set = set()
        first = True
        while not self._stop.is_set():
            present = [name for name, d in self.dirs.items() if d.is_dir()]
            for name in set(self.dirs) - set(present) - gone:
                gone.add(name)
                self.events.put(("dir-wait" if first else "dir-gone", name, str(self.dirs[name])))
            first = False
            for name in gone & set(present):
                gone.discard(name)
                self.events.put(("dir-back", name, str(self.dirs[name])))
                self._rescan(name)
            if not present:
                time.sleep(TICK_MS / 1000.0)
                continue
            try:
                for changes in watchfiles.watch(*(self.dirs[n] for n in present), watch_filter=None,
                                                debounce=DEBOUNCE_MS, step=STEP_MS, rust_timeout=TICK_MS,
                                                yield_on_timeout=True, stop_event=self._stop, recursive=False,
                                                raise_interrupt=False):
                    if self._before is not None:           # the watch is set up: what came meanwhile
                        before, self._before = self._before, None
                        for name in present:
                            self._rescan(name, skip=before.get(name, set()))
                    self._handle(changes)
                    if any(not self.dirs[n].is_dir() for n in present) or \
                            any(self.dirs[n].is_dir() for n in gone):
                        break                                  # re-plan the watch
            except (FileNotFoundError, RuntimeError, OSError):
                time.sleep(TICK_MS / 1000.0)                   # a directory vanished under the watch

    def _handle(self, changes) -> None:
        from shipstar._fitsio import is_fits_name

        now = time.monotonic()
        for change, path in sorted(changes, key=lambda c: c[1]):
            if change.name not in ("added", "modified"):
                continue
            p = Path(path)
            name = self._by_dir.get(str(p.parent))
            if name is None or not is_fits_name(p.name):
                continue
            self.n_events += 1
            self.events.put(("file", name, str(p), now))

    def _rescan(self, name: str, skip=frozenset()) -> None:
        """Frames that appeared while a directory was away (or before the watch began),
        except the names in ``skip``."""
        from shipstar._fitsio import is_fits_name

        now = time.monotonic()
        try:
            entries = sorted(os.listdir(self.dirs[name]))
        except OSError:
            return
        for entry in entries:
            if is_fits_name(entry) and entry not in skip:
                self.events.put(("file", name, str(self.dirs[name] / entry), now))
