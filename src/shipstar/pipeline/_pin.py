"""A LocalCluster's workers each on a core of their own (imported only with ``distributed``).

A lone busy process next to an idle core is moved between the two whenever another
process (here the command, which merges and fuses the results) wakes, and each move costs
it its L2 cache. On the 2-core development machine the 1-worker ``measure-archive``'s tasks
took 26.2-28.3 s of CPU unpinned, 23.4-24.4 s with the whole command held on one core
(``taskset``), and 22.4-22.5 s with 2 workers (docs/archive.md, *Speed*).
"""

from __future__ import annotations

import os

from distributed.diagnostics.plugin import WorkerPlugin

__all__ = ["PinToCore"]


class PinToCore(WorkerPlugin):
    """Worker ``i`` (its name, as a LocalCluster numbers them) runs on ``cores[i % len]``
    only, from its start and again after a restart; workers with other names, and systems
    without ``sched_setaffinity``, are left as they are."""

    def __init__(self, cores):
        self.cores = [int(c) for c in cores]

    def setup(self, worker):
        try:
            index = int(worker.name)
        except (TypeError, ValueError):
            return
        try:
            os.sched_setaffinity(0, {self.cores[index % len(self.cores)]})
        except (AttributeError, OSError):
            pass
