"""Frames -> attitude over a session, in memory: :func:`process_session` and :class:`SessionResult`.

The batch driver of the streaming engine for sessions that fit in memory (the Python API,
the demo, the tests): every sensor's frames are merged into one time order, each frame
goes through its sensor's :class:`~shipstar.pipeline._sensor.SensorProcessor` and then
the :class:`~shipstar.pipeline._engine.SessionEngine`, exactly as ``shipstar measure``
and ``shipstar live`` do, and everything is kept.  Whole nights go through
:mod:`shipstar.pipeline._measure` instead (constant memory, rows written as they come).
"""

from __future__ import annotations

from dataclasses import dataclass


from shipstar.errors import ShipstarError

__all__ = ["SessionResult", "process_session", "process_sensor"]


@dataclass(frozen=True, eq=False)
class SessionResult:
    """Everything a session gave.

    Attributes
    ----------
    sensors : tuple of str
    frames : tuple (per sensor) of tuple of FrameResult
        Every frame, solved or not (failed frames carry their reason).
    epochs : tuple of Epoch
        Fused attitudes at the reference sensor's frame times.
    reference_sensor : str
    fore_aft_sensor, athwartship_sensor : str
        Roles in the seed's fusion rule ('' when it cannot be applied).
    start_utc_jd : (float, float)
        Time origin of every ``t_s``.
    options : PipelineOptions
    emissions : tuple of Emission
        What the engine gave out, in order (the attitude CSV's row groups).
    """

    sensors: tuple
    frames: tuple
    epochs: tuple
    reference_sensor: str
    fore_aft_sensor: str
    athwartship_sensor: str
    start_utc_jd: tuple
    options: object
    emissions: tuple = ()

    def frames_of(self, sensor: str) -> tuple:
        """FrameResults of one sensor."""
        if sensor not in self.sensors:
            raise ShipstarError(f"no sensor {sensor!r} in this session (have {', '.join(self.sensors)})")
        return self.frames[self.sensors.index(sensor)]

    def t_s(self, frame_result) -> float:
        """Seconds from the session start to a frame."""
        j1, j2 = self.start_utc_jd
        return ((frame_result.utc_jd1 - j1) + (frame_result.utc_jd2 - j2)) * 86400.0

    @property
    def failures(self) -> list:
        """``[(sensor, frame label, reason), ...]`` of every frame that did not solve."""
        return [(fr.sensor, fr.label, fr.reason) for frs in self.frames for fr in frs if not fr.solved]


def _materialize(frames, name: str) -> list:
    from shipstar.pipeline._frames import Frame

    out = list(frames)
    for fr in out:
        if not isinstance(fr, Frame):
            raise ShipstarError(f"sensor {name}: frames must be shipstar.pipeline.Frame, got {type(fr).__name__}")
    for a, b in zip(out, out[1:]):
        if b.seconds_since(a.utc_jd1, a.utc_jd2) <= 0.0:
            raise ShipstarError(f"sensor {name}: frames out of time order: {b.label or '#'} ({b.utc_iso}) is not "
                                f"later than {a.label or '#'} ({a.utc_iso})")
    return out


def _check_inputs(configs, frame_lists, track, weather) -> None:
    names = [c.name for c in configs]
    if not configs:
        raise ShipstarError("no sensors given")
    if len(set(names)) != len(names):
        raise ShipstarError(f"sensor names must be unique, got {names}")
    if len(frame_lists) != len(configs):
        raise ShipstarError(f"{len(configs)} sensors but {len(frame_lists)} frame sequences")
    for name, frames in zip(names, frame_lists):
        if not frames:
            raise ShipstarError(f"sensor {name} has no frames")
        for table in (track, weather):
            if hasattr(table, "check_covers_all"):        # every frame: ends and gaps of the table
                table.check_covers_all([fr.utc_jd1 for fr in frames], [fr.utc_jd2 for fr in frames])
            else:
                for fr in (frames[0], frames[-1]):
                    table.check_covers(fr.utc_jd1, fr.utc_jd2)


def process_sensor(config, frames, track, weather, options=None, *, start_utc_jd=None, database=None,
                   lookup=None, progress=None) -> tuple:
    """Process one sensor's frames (in time order) into :class:`FrameResult` s.

    The sensor's own chain only (no pairing or fusion); frames of a sensor with an
    installation and an exposure time are streak-corrected as in :func:`process_session`.

    Parameters
    ----------
    config : SensorConfig
    frames : iterable of Frame
    track : Track
    weather : WeatherTable
    options : PipelineOptions, optional
    start_utc_jd : (float, float), optional
        Time origin (default: the first frame).
    database, lookup : optional
        Identification database and catalog lookup (built on first need).
    progress : callable(sensor, done, total), optional

    Returns
    -------
    tuple of FrameResult
    """
    from shipstar.pipeline._frames import read_ahead
    from shipstar.pipeline._options import PipelineOptions
    from shipstar.pipeline._sensor import SensorProcessor

    options = PipelineOptions() if options is None else options
    frames = _materialize(frames, config.name)
    _check_inputs([config], [frames], track, weather)
    j1, j2 = start_utc_jd if start_utc_jd is not None else (frames[0].utc_jd1, frames[0].utc_jd2)
    proc = SensorProcessor(config, track, weather, options, database=database, lookup=lookup)
    out = []
    for k, fr in enumerate(read_ahead(frames)):              # the next frames' files read meanwhile
        out.append(proc.process(fr, k, fr.seconds_since(j1, j2)))
        if progress is not None:
            progress(config.name, k + 1, len(frames))
    return tuple(out)


def merged_frames(lists, start_utc_jd):
    """``(t_s, sensor index, frame index, Frame)`` of every sensor's frames, in time order
    (sensor order at equal times): the order the engine needs its input in."""
    import heapq

    def stream(s, frames):
        for k, fr in enumerate(frames):
            yield fr.seconds_since(*start_utc_jd), s, k, fr

    return heapq.merge(*(stream(s, frames) for s, frames in enumerate(lists)), key=lambda item: item[:2])


def session_start(lists) -> tuple:
    """``(utc_jd1, utc_jd2)`` of the earliest first frame of the sensors' frame lists."""
    firsts = [f[0] for f in lists if f]
    first = min(firsts, key=lambda fr: fr.seconds_since(firsts[0].utc_jd1, firsts[0].utc_jd2))
    return first.utc_jd1, first.utc_jd2


def process_session(configs, frames, track, weather, options=None, *, reference: str | None = None,
                    databases=None, lookup=None, progress=None, smooth_lag_s: float = 0.0) -> SessionResult:
    """Frames of one or more sensors -> per-frame and fused ship attitude over a session.

    One pass in time order over all sensors' frames: each frame is solved by its sensor's
    processor (with the streak correction from that sensor's motion up to the frame),
    then paired, carried to the reference sensor's frame time and fused by the
    :class:`~shipstar.pipeline._engine.SessionEngine` (docs/pipeline.md).  Everything is
    kept in memory; ``shipstar measure`` runs the same engine in constant memory.

    Parameters
    ----------
    configs : sequence of SensorConfig
        The sensors (camera and installation each).
    frames : sequence of iterables of Frame
        Each sensor's frames (FITS paths, arrays or centroids with times), in time order.
    track : Track
        Ship position over time (``Track.fixed`` in dock).
    weather : WeatherTable
        Weather over time (``WeatherTable.constant`` if it did not change).
    options : PipelineOptions, optional
    reference : str, optional
        Sensor whose frame times are the epochs (default the first).
    databases : dict of name -> StarDatabase, optional
    lookup : StarLookup, optional
    progress : callable(sensor, done, total), optional
    smooth_lag_s : float
        Fuse each epoch with the mounts' clock and flexure estimates of the epochs up to
        this many seconds later (a fixed-lag smoother; 0: causal, as ``shipstar live``;
        ``shipstar measure`` uses 60 s).

    Returns
    -------
    SessionResult

    Raises
    ------
    ShipstarError
        Duplicate sensor names, no frames, frames out of time order, frame times
        outside the track or weather tables, an unknown reference sensor.
    """
    from shipstar.pipeline._engine import SessionEngine
    from shipstar.pipeline._frames import read_ahead
    from shipstar.pipeline._options import PipelineOptions
    from shipstar.pipeline._sensor import SensorProcessor

    options = PipelineOptions() if options is None else options
    configs = list(configs)
    lists = [_materialize(f, c.name) for c, f in zip(configs, frames)]
    _check_inputs(configs, lists, track, weather)
    names = tuple(c.name for c in configs)
    ref = 0 if reference is None else (names.index(reference) if reference in names else -1)
    if ref < 0:
        raise ShipstarError(f"reference sensor {reference!r} is not one of {', '.join(names)}")
    start = session_start(lists)
    procs = [SensorProcessor(c, track, weather, options, database=(databases or {}).get(c.name), lookup=lookup)
             for c in configs]
    engine = SessionEngine(configs, options, start_utc_jd=start, reference=ref, smooth_lag_s=smooth_lag_s)
    results, emissions = [[] for _ in configs], []
    for t, s, k, frame in read_ahead(merged_frames(lists, start), frame_of=lambda item: item[3]):
        fr = procs[s].process(frame, k, t)
        results[s].append(fr)
        emissions += engine.add(fr)
        if progress is not None:
            progress(names[s], k + 1, len(lists[s]))
    emissions += engine.finish()
    fore, athw = engine.roles
    epochs = tuple(e.epoch for e in emissions if e.epoch is not None)
    return SessionResult(names, tuple(tuple(r) for r in results), epochs, names[ref],
                         names[fore] if fore >= 0 else "", names[athw] if athw >= 0 else "", start, options,
                         tuple(emissions))
