"""One worker process per sensor for ``shipstar live``.

Each worker (spawned) keeps one :class:`~shipstar.pipeline._sensor.SensorProcessor` for
its sensor all night (the tracking prior and the streak correction's motion window live
there) and processes the frames it is sent, one at a time, in the order sent.  The main
process sends a frame only when the worker has none waiting, so that it can skip to the
newest frames when a sensor falls behind (never an unbounded queue).

Messages to a worker: ``(index, Frame, t_s, Site, Weather)`` or None (stop).  Messages
back, on one queue shared by the workers: ``("ready", sensor)`` once its star database
is loaded, ``("result", sensor, index, FrameResult, warnings)`` per frame, and
``("failed", sensor, message)`` if it cannot run at all.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

__all__ = ["SensorWorkers"]


def _warm_up(config, options, database, lookup) -> None:
    """Solve one simulated frame of the sensor's camera through the whole chain (FITS
    file, extraction, lost-in-space, sky, attitude), so that the first real frame does
    not pay for imports and first-use caches (0.7 s measured, against 20 ms a frame)."""
    import tempfile
    from pathlib import Path

    import numpy as np

    from shipstar.frames import C_deck_from_sensor
    from shipstar.pipeline._frames import scan_frames
    from shipstar.pipeline._sensor import SensorProcessor
    from shipstar.simulate import simulate_frame, write_frame
    from shipstar.sky.apparent import Site
    from shipstar.sky.refraction import Weather

    site, weather = Site.from_deg(31.9, 120.3), Weather(1013.25, 10.0)
    level = C_deck_from_sensor(np.radians(200.0), np.radians(45.0), 0.0)     # a level ship heading north
    sim = simulate_frame(config.camera, C_hor_from_sensor=level, site=site,
                         weather=weather, utc_iso="2013-03-15T12:16:00", seed=0)
    with tempfile.TemporaryDirectory(prefix="shipstar-warm-up-") as tmp:
        write_frame(sim, Path(tmp) / "warm-up.fits")
        (frame,) = scan_frames(tmp)
        proc = SensorProcessor(config, None, None, options, database=database, lookup=lookup)
        for k in range(2):                                  # lost in space, then tracking
            proc.process(replace(frame, utc_jd2=frame.utc_jd2 + k * 0.1 / 86400.0), k, 0.1 * k, site=site,
                         weather=weather)
    # a still frame does not reach the smeared-frame extraction, which `extract` loads on the
    # first smeared frame (deferred for `shipstar solve`): load it here, not on the first
    # frame at sea (that frame fell behind and was skipped when it did)
    import shipstar.extract._smeared  # noqa: F401


def _worker_main(config, options, jobs, results) -> None:
    """A worker's loop (runs in the spawned process)."""
    import signal

    from shipstar.errors import AccuracyWarning
    from shipstar.pipeline._sensor import SensorProcessor
    from shipstar.pipeline._stars import default_lookup

    signal.signal(signal.SIGINT, signal.SIG_IGN)          # the main process stops us
    try:
        proc = SensorProcessor(config, None, None, options, lookup=default_lookup())
        _warm_up(config, options, proc.database, proc.lookup)
    except Exception as exc:                               # noqa: BLE001 - reported to the main process
        results.put(("failed", config.name, f"{type(exc).__name__}: {exc}"))
        return
    results.put(("ready", config.name))
    while True:
        job = jobs.get()
        if job is None:
            return
        index, frame, t_s, site, weather = job
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", AccuracyWarning)
            fr = proc.process(frame, index, t_s, site=site, weather=weather)
        messages = list(dict.fromkeys(" ".join(str(w.message).split()) for w in caught
                                      if issubclass(w.category, AccuracyWarning)))
        results.put(("result", config.name, index, replace(fr, solve_inputs=None), messages))


class SensorWorkers:
    """The sensors' worker processes and the queue their results come back on.

    Parameters
    ----------
    configs : sequence of SensorConfig
    options : PipelineOptions
    """

    def __init__(self, configs, options):
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")
        self.results = ctx.Queue()
        self._jobs = {c.name: ctx.Queue() for c in configs}
        self._procs = {c.name: ctx.Process(target=_worker_main, args=(c, options, self._jobs[c.name], self.results),
                                           name=f"shipstar-live-{c.name}", daemon=True) for c in configs}
        from shipstar.pipeline._measure import one_blas_thread_for_children

        with one_blas_thread_for_children():
            for p in self._procs.values():
                p.start()

    def send(self, sensor: str, index: int, frame, t_s: float, site, weather) -> None:
        self._jobs[sensor].put((index, frame, t_s, site, weather))

    def alive(self, sensor: str) -> bool:
        return self._procs[sensor].is_alive()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Ask every worker to stop after its current frame; terminate the ones that do not."""
        for q in self._jobs.values():
            try:
                q.put(None)
            except (OSError, ValueError):
                pass
        for p in self._procs.values():
            p.join(timeout_s)
            if p.is_alive():
                p.terminate()
                p.join(1.0)
        for q in (*self._jobs.values(), self.results):
            q.close()
            q.join_thread()
