"""Archive reprocessing on Dask: the driver behind ``shipstar measure-archive``.

A session is cut into the chunks of ``shipstar measure`` (:mod:`shipstar.pipeline._measure`:
each chunk of each sensor is one task, processed by a fresh
:class:`~shipstar.pipeline._sensor.SensorProcessor` from :data:`~shipstar.pipeline._measure.WARMUP_S`
seconds before the chunk, so that it starts with a lost-in-space solve and its first
frames see the state an uninterrupted pass would have).  Here the tasks are
``dask.distributed`` futures (:class:`DaskTasks`), run on any Dask cluster: a
``LocalCluster`` on this machine or a scheduler's address.  Their results come back to
this process whole (a chunk of one sensor: a list of frame results) and go through the
same merge, :class:`~shipstar.pipeline._engine.SessionEngine`, CSV writer and checkpoint
as ``measure``'s (:func:`~shipstar.pipeline._measure.run_measure` with ``tasks=``): the
rows are those of ``shipstar measure``, byte for byte.

A task that raises is retried by Dask (``retries``); a worker lost in the middle of a task
has it rescheduled by the scheduler (up to its ``allowed-failures``).  Every attempt is
logged on the scheduler (:data:`EVENT_TOPIC`, one event at the start of each attempt and
one per exception), and :func:`attempts_report` turns them into one line per chunk that
ran more than once.  A chunk that still fails raises :class:`ChunkFailed` naming it: the
run ends with ``OUT.partial`` holding the rows before that chunk (and ``OUT.resume``,
to continue later), never a complete-looking file with rows missing.

``dask`` is imported only here and only when a run starts (not at ``import shipstar``).
"""

from __future__ import annotations

import math
import os
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from shipstar.errors import ShipstarError

__all__ = ["ChunkFailed", "DaskTasks", "EVENT_TOPIC", "attempts_report", "connect", "describe_chunk",
           "run_archive", "ArchiveOutcome", "DEFAULT_RETRIES", "DEFAULT_RETRY_DELAY_S", "local_start_method",
           "warm_here", "warm_workers", "HeaderReader"]

#: The scheduler's event topic of every attempt (``client.get_events(EVENT_TOPIC)``).
EVENT_TOPIC = "shipstar-archive"
#: Retries of a task that raised (Dask ``retries``): three attempts in all.
DEFAULT_RETRIES = 2
#: Seconds a failed attempt waits before its retry starts.
DEFAULT_RETRY_DELAY_S = 1.0
#: Seconds between looks at the futures while none has finished.
_POLL_S = 0.05
#: Seconds between looks at the streaming tasks' queues: each look is a round trip to the
#: scheduler, and a task sends :data:`STREAM_FRAMES` results at a time (~0.2 s of its work);
#: looking every :data:`_POLL_S` cost the command ~0.2-0.4 s of CPU over a 90 s session's
#: last chunk (more with one worker, whose last tasks stream for longer).
_DRAIN_S = 0.2
#: A job (:class:`~shipstar.pipeline._measure.MeasureJob`) up to this size (pickled; 11 kB
#: with a 90-row track) goes with each task; a larger one is sent once.
_INLINE_JOB_BYTES = 1 << 20
#: Results a task of a session's last chunk sends at a time (:func:`_stream_put`): the
#: merge and fusion here keep up with the workers instead of all starting when the last
#: tasks end (a 90 s session in 30 s chunks: a third of its 4-6 s of fusion, measured).
STREAM_FRAMES = 20
#: Dask settings of a LocalCluster (and of this process): without the statistical profiler
#: (a stack sample of the busy thread every 10 ms), the GIL monitor and the 20 ms event-loop
#: tick, which together cost an idle worker and this process 4 % of a core each (measured:
#: 0.55 and 0.51 s of CPU in 15 s idle, against 0.05 and 0.10 s with these; on a slower,
#: busier day of the same host this process took 0.3-0.6 s per 10 s idle with these, most
#: of it the two workers' heartbeats, every 0.5 s for a cluster this small).
QUIET_DASK = {"distributed.worker.profile.enabled": False, "distributed.admin.system-monitor.gil.enabled": False,
              "distributed.admin.tick.interval": "1s", "distributed.worker.memory.monitor-interval": "1s",
              "distributed.admin.system-monitor.interval": "2s"}
#: The environment a LocalCluster's workers start with: one BLAS thread, and not Dask's
#: ``MALLOC_TRIM_THRESHOLD_``, which fixes glibc's mmap threshold so that every image-sized
#: array is mapped and unmapped afresh (measured: 4.8 against 1.1 ms of system time a frame).
WORKER_ENVIRON = {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1}


class ChunkFailed(ShipstarError):
    """A chunk whose task failed on every attempt (or was lost with its workers)."""


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def describe_chunk(chunk, source, chunk_s: float) -> str:
    """``chunk 3 of sensor A2 (180-240 s, frames A2_01800.fits .. A2_02399.fits)``: a
    task's chunk (:class:`~shipstar.pipeline._measure._Chunk`) in words."""
    t0, t1 = chunk.index * chunk_s, (chunk.index + 1) * chunk_s
    text = f"chunk {chunk.index} of sensor {source.name} ({t0:g}-{t1:g} s"
    names = getattr(source.piece(chunk.first, chunk.hi), "names", None) if chunk.hi > chunk.first else None
    if names:
        text += f", frames {names[0]} .. {names[-1]}"
    elif chunk.hi <= chunk.first:
        text += ", no frames of its own"
    return text + ")"


# -- on the workers --------------------------------------------------------------------------

#: One chunk at a time per process: the warnings of a chunk are recorded with
#: ``warnings.catch_warnings``, which is process-wide, so a worker's further threads
#: would only mix their warnings up (give workers one thread each, ``--nthreads 1``).
_PROCESS_LOCK = threading.Lock()


def _log_event(run_id: str, k: int, what: str, reason: str = "") -> None:
    from distributed import get_worker

    try:
        worker = get_worker()
    except ValueError:                                    # pragma: no cover - not on a worker
        return
    worker.log_event(EVENT_TOPIC, {"run": run_id, "task": k, "what": what, "worker": worker.address,
                                   "reason": reason})


def _the_job(job):
    return job


@dataclass(frozen=True, eq=False)
class _Loaded:
    frames: list

    def load(self) -> list:
        return self.frames


def _check_readable(frames) -> None:
    """Every frame file of the chunk opens and reads here (raises OSError): a frame that was
    indexed but cannot be read on this worker now (a file system not mounted, a file
    server's hiccup) fails the task, to be retried, rather than becoming a failed frame."""
    for f in frames:
        if f.path is not None:
            with open(f.path, "rb") as fh:
                fh.read(1)


def _stream_put(queue: str, offset: int, items) -> None:
    """Send results ``offset ..`` of a task to the driver now, through the scheduler's queue
    ``queue`` (pickled: the queue carries msgpack data); returns once the scheduler holds
    them, so that they are queued before the task's own result is known."""
    import pickle

    from distributed import get_worker
    from distributed.utils import sync

    worker = get_worker()
    blob = pickle.dumps(items, protocol=pickle.HIGHEST_PROTOCOL)
    sync(worker.loop, worker.scheduler.queue_put, name=queue, data={"offset": offset, "items": blob})


def _chunk_task(job, sensor: int, piece, lo: int, keep_from: int, run_id: str, k: int,
                retry_delay_s: float = 0.0, stream: str | None = None) -> tuple:
    """A task on a Dask worker: frames ``lo ..`` of one sensor (``piece``) through a fresh
    processor; returns ``(offset, items)``: every ``(result, warnings)`` from frame
    ``keep_from`` on, but for the first ``offset`` of them, which were sent to the driver
    as they came (:func:`_stream_put` to queue ``stream``, :data:`STREAM_FRAMES` at a
    time; without ``stream`` none is, ``offset`` is 0).  After an error it waits
    ``retry_delay_s`` before raising (Dask retries at once: a transient fault gets that
    long to clear)."""
    from shipstar.pipeline._measure import process_chunk

    _log_event(run_id, k, "start")
    try:
        frames = piece.load()
        _check_readable(frames)
        with _PROCESS_LOCK:
            if stream is None:
                items = []
                for batch in process_chunk(job, sensor, _Loaded(frames), lo, keep_from, 1 << 30):
                    items.extend(batch)
                return 0, items
            sent, held = 0, []
            for batch in process_chunk(job, sensor, _Loaded(frames), lo, keep_from, STREAM_FRAMES):
                if held:                                  # the last batch is the task's result
                    _stream_put(stream, sent, held)
                    sent += len(held)
                held = batch
            return sent, held
    except Exception as exc:
        _log_event(run_id, k, "error", _one_line(exc))
        time.sleep(retry_delay_s)
        raise


def _header_task(paths, date_obs_is: str) -> tuple:
    """A task on a Dask worker: one block of a frame directory's index
    (:func:`~shipstar.pipeline._frames.read_header_block`)."""
    from shipstar.pipeline._frames import read_header_block

    return read_header_block(paths, date_obs_is)


def _warm(cameras) -> None:
    """Load the catalog and each camera's star database into this worker (cached per process)."""
    from shipstar.pipeline._measure import load_shared_data

    load_shared_data(cameras)


def warm_workers(client, cameras) -> list:
    """Start loading the catalog and the cameras' star databases on every worker now (as
    ``measure``'s worker pool does while the frames are indexed); returns the futures, to
    keep until the run ends (a released future is cancelled).  A worker that joins later
    loads them with its first task."""
    return [client.submit(_warm, tuple(cameras), key=f"shipstar-warm-{uuid.uuid4().hex[:12]}", workers=[addr],
                          allow_other_workers=False, pure=False)
            for addr in client.scheduler_info()["workers"]]


# -- on the client ---------------------------------------------------------------------------

class HeaderReader:
    """Reads the frame headers of a session's index on a Dask cluster's workers:
    ``reader(paths, date_obs_is)`` submits them now, in blocks
    (:func:`~shipstar.pipeline._frames.header_blocks`: at least 1000 files, about 4 per
    worker thread), and returns the iterator of their results in file order that
    :func:`~shipstar.pipeline._frames.scan_frames` takes as ``headers`` (a directory of a
    single block is read here).

    A night of two sensors at 10 frames/s is 720 000 files: read one by one by this
    process, their headers took ~1.7 min on the development machine before the first task
    could start, longer on a network file system (a round trip per file); the workers
    read them side by side, next to the frames.  A block whose task fails is retried
    (``retries``); one that still fails ends the indexing with a one-line error.

    Parameters
    ----------
    client : distributed.Client
    retries : int
    block_files : int, optional
        Files per block (tests); by default from the cluster's threads.
    """

    def __init__(self, client, *, retries: int = DEFAULT_RETRIES, block_files: int | None = None):
        self.client, self.retries, self.block_files = client, int(retries), block_files

    def __call__(self, paths, date_obs_is: str):
        from shipstar.pipeline._frames import header_blocks, read_header_block

        paths = list(paths)
        if self.block_files is None:
            threads = max(1, sum(self.client.nthreads().values()))
            blocks = header_blocks(paths, threads)
        else:
            blocks = [paths[lo:lo + self.block_files] for lo in range(0, len(paths), self.block_files)]
        if len(blocks) == 1:
            return iter((read_header_block(paths, date_obs_is),))
        # the workers may run in another directory: absolute paths (one directory, resolved once)
        parent = Path(paths[0]).parent.resolve()
        blocks = [[str(parent / Path(p).name) for p in block] for block in blocks]
        tag = uuid.uuid4().hex[:12]
        futures = [self.client.submit(_header_task, block, date_obs_is, key=f"shipstar-index-{tag}-{k}",
                                      retries=self.retries, pure=False, priority=1)
                   for k, block in enumerate(blocks)]
        return _HeaderBlocks(futures, blocks, date_obs_is, str(parent))


class _HeaderBlocks:
    """The results of :class:`HeaderReader`'s tasks, in order (iterable once); ``futures``
    the tasks.  A frame a worker could not read but this process can is an error that
    says so: the workers do not see the frames at the same paths (a file system not
    mounted there), which reading here would not show."""

    def __init__(self, futures, blocks, date_obs_is: str, directory: str):
        self.futures, self._blocks, self._date_obs_is, self._directory = futures, blocks, date_obs_is, directory

    def __iter__(self):
        from shipstar._fitsio import read_fits_header

        for f, block in zip(self.futures, self._blocks):
            try:
                infos, error = f.result()
            except Exception as exc:
                raise ShipstarError(f"reading the frame headers in {self._directory} on the cluster failed: "
                                    f"{_one_line(exc)}") from None
            if error is not None:
                try:
                    read_fits_header(block[len(infos)], date_obs_is=self._date_obs_is)
                except ShipstarError:
                    pass                                    # the same error here: reported as reading here would
                else:
                    error = ShipstarError(f"{Path(block[len(infos)]).name} in {self._directory} reads here but not "
                                          f"on the cluster's workers ({error}): they need the frames at the same "
                                          f"paths")
            yield infos, error


class _Received:
    """The results of one streaming task, as its pieces arrive: ``take(offset, items)``
    with ``items`` its results ``offset ..`` from any attempt (every attempt gives the
    same results; one that ran again sends them again from the first).  ``items`` holds
    those not yet handed on, in order, each once; a piece past a gap waits for it."""

    def __init__(self):
        self.items: list = []
        self.n = 0                                      # results received in all
        self._early: dict = {}                          # offset -> a piece past a gap

    def take(self, offset: int, items) -> None:
        if offset > self.n:
            if len(items) > len(self._early.get(offset, ())):
                self._early[offset] = items
            return
        self._extend(offset, items)
        while True:
            ready = [off for off in self._early if off <= self.n]
            if not ready:
                return
            off = min(ready)
            self._extend(off, self._early.pop(off))

    def _extend(self, offset: int, items) -> None:
        fresh = items[self.n - offset:]
        self.items.extend(fresh)
        self.n += len(fresh)

    def pop(self) -> list:
        items, self.items = self.items, []
        return items


class DaskTasks:
    """Runs a session's tasks as Dask futures, a bounded number ahead of the merge, and
    hands each task's results back (the runner interface of
    :func:`~shipstar.pipeline._measure.run_measure`'s ``tasks``).  A finished task's
    results (~4.6 kB a frame: 2.8 MB for 60 s of one sensor at 10 frames/s) stay in its
    worker's memory until the merge needs them: this process holds one chunk at a time.
    The tasks of the session's last chunk send their results as they come instead
    (:func:`_stream_put`, through one scheduler queue per task): nothing runs after them,
    and the merge and fusion of that chunk would otherwise all come after them, with the
    workers idle.  An attempt that ran again sends its results again from the first; those
    already received are skipped (every attempt gives the same results).

    Parameters
    ----------
    client : distributed.Client
    job : MeasureJob
        Sent with each task; a large one (over ``_INLINE_JOB_BYTES`` pickled) once, as a
        task's result.
    sources : sequence of FrameSource
        Their pieces are sent with the tasks (a FITS piece: names and times only).
    order : list of _Chunk
        The tasks, in merge order.
    run_id : str
        Names this run's tasks and events on the scheduler.
    chunk_s : float
    retries : int
        Dask retries of a task that raised.
    retry_delay_s : float
        A failed attempt waits this long before it ends (and the retry starts).
    """

    def __init__(self, client, job, sources, order, *, run_id: str, chunk_s: float, retries: int = DEFAULT_RETRIES,
                 retry_delay_s: float = DEFAULT_RETRY_DELAY_S):
        from distributed import as_completed

        self.client, self.sources, self.order = client, sources, order
        self.run_id, self.chunk_s, self.retries = run_id, float(chunk_s), int(retries)
        self.retry_delay_s = float(retry_delay_s)
        # the job goes with every task (tasks without dependencies: the scheduler hands them
        # to the workers in merge order as threads free up; tasks that depend on one result
        # are all placed at once and a worker may take its last one first); a large job
        # (a long track) once, as a task's result (not scattered data: a worker lost with
        # it has it computed again, where scattered data would be gone for good)
        import pickle

        self._job_future = None
        if len(pickle.dumps(job, protocol=pickle.HIGHEST_PROTOCOL)) <= _INLINE_JOB_BYTES:
            self.job = job
        else:
            self.job = self._job_future = client.submit(_the_job, job, key=f"shipstar-job-{run_id}", pure=False)
        self.futures: dict = {}                         # task -> future, not yet finished
        self.results: dict = {}                         # task -> future, finished, not yet merged
        self.failed: dict = {}                          # task -> why, raised when the merge needs it
        last = max((c.index for c in order), default=-1)
        self.streams = {k for k, c in enumerate(order) if c.index == last}     # tasks that stream
        self.queues: dict = {}                          # streaming task -> its Queue
        self.got: dict = {}                             # streaming task -> its _Received
        self.ended: set = set()                         # streaming tasks finished, all results received
        self.done = 0
        self.next_submit = 0
        self._ac = as_completed(loop=client.loop)
        self._drained_at = -math.inf
        self._ahead, self._ahead_at = 0, -1e9
        self.closed = False

    def _window(self) -> int:
        """Tasks in flight or waiting to be merged: twice the cluster's threads plus a row
        (looked up every few seconds: an adaptive cluster grows and shrinks)."""
        now = time.monotonic()
        if now - self._ahead_at > 5.0:
            threads = sum(self.client.nthreads().values())
            self._ahead = max(8, 2 * threads + len(self.sources))
            self._ahead_at = now
        return self._ahead

    def _submit(self) -> None:
        from distributed import Queue

        window = self._window()
        while self.next_submit < len(self.order) and len(self.futures) + len(self.results) < window \
                and not self.failed:
            k, c = self.next_submit, self.order[self.next_submit]
            piece = self.sources[c.sensor].piece(c.lo, c.hi)
            stream = None
            if k in self.streams:
                stream = f"shipstar-stream-{self.run_id}-{k}"
                self.queues[k] = Queue(stream, client=self.client)
                self.got[k] = _Received()
            # the scheduler's queue hands tasks out by priority: in merge order
            f = self.client.submit(_chunk_task, self.job, c.sensor, piece, c.lo, c.keep_from, self.run_id, k,
                                   self.retry_delay_s, stream, key=f"shipstar-chunk-{self.run_id}-{k}",
                                   retries=self.retries, pure=False, priority=-k)
            self.futures[k] = f
            self._ac.add(f)
            self.next_submit += 1

    def describe(self, k: int) -> str:
        c = self.order[k]
        return describe_chunk(c, self.sources[c.sensor], self.chunk_s)

    def _drain(self, ks) -> bool:
        """What the streaming tasks among ``ks`` sent so far; True if anything came."""
        import pickle

        came = False
        for k in ks:
            q = self.queues.get(k)
            if q is None or k in self.ended:
                continue
            for msg in q.get(batch=True):
                self.got[k].take(int(msg["offset"]), pickle.loads(msg["items"]))
                came = True
        return came

    def _collect(self, f) -> None:
        k = next(kk for kk, ff in self.futures.items() if ff is f)
        if f.status == "finished":                      # its results stay on the worker until merged
            del self.futures[k]
            self.done += 1
            if k not in self.streams:
                self.results[k] = f
                return
            offset, items = f.result()                  # its earlier results are queued by now
            self._drain([k])
            if offset > self.got[k].n:                  # pragma: no cover - the scheduler lost some
                self.failed[k] = f"{self.describe(k)}: results {self.got[k].n} .. {offset - 1} it sent were lost"
                return
            self.got[k].take(offset, items)
            self.ended.add(k)
            self._close_queue(k)
            return
        if f.status == "error":
            exc = f.exception()
            attempts = self.retries + 1
            if type(exc).__name__ == "KilledWorker":
                why = "its workers died on every attempt (out of memory, or killed)"
            else:
                why = f"{attempts} attempt{'s' if attempts > 1 else ''} failed, the last with {_one_line(exc)}"
            self.failed[k] = f"{self.describe(k)}: {why}"
        else:
            self.failed[k] = f"{self.describe(k)}: its task was {f.status} (the scheduler or the cluster went away)"
        del self.futures[k]

    def _close_queue(self, k: int) -> None:
        q = self.queues.pop(k, None)
        if q is not None:
            try:
                q.close()                               # the scheduler forgets it
            except Exception:                           # pragma: no cover - the scheduler is gone
                pass

    def next_batch(self, ks, stop):
        """The results of one of tasks ``ks``: ``(k, items, done)`` (a task that streams
        may come in several pieces); None when ``stop`` was set while waiting.  Raises
        :class:`ChunkFailed`."""
        self._submit()
        while True:
            for k in ks:
                if k in self.results:
                    _, items = self.results.pop(k).result()
                    self._submit()
                    return k, items, True
                if k in self.ended:
                    self.ended.discard(k)
                    return k, self.got.pop(k).pop(), True
                if k in self.got and self.got[k].items:
                    return k, self.got[k].pop(), False
                if k in self.failed:                    # every row before it is written by now
                    raise ChunkFailed(self.failed[k])
            if stop is not None and stop.is_set():
                return None
            came, now = False, time.monotonic()
            if now - self._drained_at >= _DRAIN_S:
                came, self._drained_at = self._drain(ks), now
            ready = self._ac.next_batch(block=False)
            if not ready and not came:
                time.sleep(_POLL_S)
                continue
            for f in ready:
                self._collect(f)
            self._submit()

    def close(self, abort: bool) -> None:
        """Cancel what is still running (idempotent)."""
        if self.closed:
            return
        self.closed = True
        pending = list(self.futures.values()) + list(self.results.values())
        self.futures.clear()
        self.results.clear()
        try:
            if pending:
                self.client.cancel(pending)
            if self._job_future is not None:
                self.client.cancel([self._job_future])
        except Exception:                                  # pragma: no cover - the scheduler is gone
            pass
        for k in list(self.queues):
            self._close_queue(k)


def attempts_report(client, run_id: str, describe) -> list:
    """One line per task of ``run_id`` that ran more than once or raised: how many times it
    started, the distinct errors its attempts raised, and how many attempts were lost with
    their worker (a start followed by neither an error nor the result, then another
    start).  ``describe(k)`` names task ``k``."""
    try:
        events = client.get_events(EVENT_TOPIC)
    except Exception:                                      # pragma: no cover - the scheduler is gone
        return []
    by_task: dict = {}
    for _, msg in events:
        if isinstance(msg, dict) and msg.get("run") == run_id:
            by_task.setdefault(msg["task"], []).append(msg)
    lines = []
    for k in sorted(by_task):
        msgs = by_task[k]
        starts = [m for m in msgs if m["what"] == "start"]
        errors = [m for m in msgs if m["what"] == "error"]
        if len(starts) <= 1 and not errors:
            continue
        lost = len(starts) - len(errors) - 1
        parts = [f"{len(starts)} attempt{'s' if len(starts) != 1 else ''}"]
        if errors:
            parts.append("raised " + "; ".join(dict.fromkeys(m["reason"] for m in errors)))
        if lost > 0:
            parts.append(f"{lost} lost with {'its worker' if lost == 1 else 'their workers'}")
        lines.append(f"{describe(k)}: " + ", ".join(parts))
    return lines


@dataclass(frozen=True, eq=False)
class ArchiveOutcome:
    """What a session's run on Dask gave.

    Attributes
    ----------
    measure : MeasureOutcome or None
        None when a chunk failed.
    failed : str
        The one-line reason (naming the chunk) when a chunk failed, else ``""``.
    attempts : tuple of str
        :func:`attempts_report`'s lines: chunks that ran more than once.
    n_tasks : int
    """

    measure: object
    failed: str
    attempts: tuple
    n_tasks: int


def run_archive(client, job, sources, out, *, retries: int = DEFAULT_RETRIES,
                retry_delay_s: float = DEFAULT_RETRY_DELAY_S, **kwargs) -> ArchiveOutcome:
    """One session through :func:`~shipstar.pipeline._measure.run_measure` with its tasks
    on Dask (``client``).

    Parameters
    ----------
    client : distributed.Client
    job : MeasureJob
    sources : sequence of FrameSource
    out : str or Path
    retries : int
        Dask retries of a task that raised.
    retry_delay_s : float
        A failed attempt waits this long before its retry.
    **kwargs
        As :func:`~shipstar.pipeline._measure.run_measure` (``truth``, ``comments``,
        ``resume``, ``chunk_s``, ``progress``, ``stop``); not ``workers``.

    Returns
    -------
    ArchiveOutcome
        A failed chunk is in ``failed`` (``OUT.partial`` and ``OUT.resume`` kept), not
        raised; every other error is raised.
    """
    from shipstar.pipeline._measure import CHUNK_S, run_measure

    run_id = uuid.uuid4().hex[:12]
    chunk_s = kwargs.get("chunk_s", CHUNK_S)
    made: list = []

    def tasks(job_, sources_, order):
        made.append(DaskTasks(client, job_, sources_, order, run_id=run_id, chunk_s=chunk_s, retries=retries,
                               retry_delay_s=retry_delay_s))
        return made[0]

    failed, outcome = "", None
    try:
        outcome = run_measure(job, sources, out, tasks=tasks, **kwargs)
    except ChunkFailed as exc:
        failed = str(exc)
    runner = made[0] if made else None
    attempts = tuple(attempts_report(client, run_id, runner.describe)) if runner is not None else ()
    return ArchiveOutcome(outcome, failed, attempts, len(runner.order) if runner is not None else 0)


def local_start_method() -> str:
    """How a LocalCluster started now would start its worker processes: ``fork`` where it
    is safe (POSIX, no other thread in this process yet: the forks happen while the
    cluster's event loop thread starts them and this thread waits), else ``spawn``.  A
    forked worker starts with this process's modules, catalog and star databases (loaded
    by :func:`warm_here`): measured on 2 busy cores, 2 workers start in 0.3-0.8 s
    against 1.4-2.1 s spawned, and close in 0.05 s against 0.5-1.0 s.  A worker the
    nanny starts again later (one that died) is spawned: this process has other threads
    by then."""
    from shipstar.pipeline._measure import _start_method

    return _start_method()


def warm_here(cameras) -> None:
    """Load the catalog and the cameras' star databases in this process (before a
    LocalCluster forks its workers from it: they start with them)."""
    _warm(tuple(cameras))


#: Attempts at one client's connection to a scheduler (:func:`open_client`).
CONNECT_ATTEMPTS = 5


def open_client(address, *, timeout_s: float | None):
    """A ``distributed.Client`` of the scheduler (or cluster) ``address``, not the default one,
    connected within ``timeout_s`` (None: Dask's configured connect time-out).

    distributed (2026.8, ``Client._ensure_connected``) asserts that the scheduler's first
    reply to a new client comes alone.  The scheduler batches what it sends a client over
    2 ms and tells every client of the keys any client cancels, so a client that registers
    just as another cancels fails with a bare AssertionError.  Seen in CI: a session's
    driver connected as the session before it stopped.  Here, 27 of 400 connections failed
    so while another client cancelled in a loop.  The half-made client is closed and a new
    connection tried, up to :data:`CONNECT_ATTEMPTS` times.

    Raises
    ------
    ConnectionError
        Every attempt failed so (the OS and time-out errors of ``Client`` pass through).
    """
    from distributed import Client

    for _ in range(CONNECT_ATTEMPTS):
        try:
            return Client(address, set_as_default=False, **({} if timeout_s is None else {"timeout": timeout_s}))
        except AssertionError as exc:
            _close_half_made(exc, Client)
    raise ConnectionError(f"the scheduler's reply to a new client came out of order {CONNECT_ATTEMPTS} times")


def _close_half_made(exc: BaseException, client_type) -> None:
    """Close the client whose constructor raised ``exc`` (its loop thread would otherwise run
    on, and its finaliser wait up to twice the time-out at exit)."""
    tb, made = exc.__traceback__, None
    while tb is not None:
        candidate = tb.tb_frame.f_locals.get("self")
        if isinstance(candidate, client_type):
            made = candidate
        tb = tb.tb_next
    if made is not None:
        try:
            made.close(timeout=5)
        except Exception:                   # (it is being dropped: nothing more to do)
            pass


def connect(scheduler: str | None = None, *, workers: int = 2, threads_per_worker: int = 1,
            timeout_s: float = 10.0, start_method: str | None = None, pin_workers: bool = True):
    """A Dask client: to ``scheduler`` (``tcp://HOST:PORT``), else to a new LocalCluster of
    ``workers`` processes, started by ``start_method`` (default
    :func:`local_start_method`; restarted workers are always spawned).  ``pin_workers``:
    with at least as many cores as workers, worker ``i`` runs on core ``i`` only
    (:class:`._pin.PinToCore`).  Returns ``(client, cluster or None)``; close both after
    use.

    Raises
    ------
    ShipstarError
        The scheduler cannot be reached within ``timeout_s`` (one line).
    """
    import logging
    import signal

    import dask
    from distributed import LocalCluster

    from shipstar.pipeline._measure import one_blas_thread_for_children

    if scheduler:
        try:
            return open_client(scheduler, timeout_s=timeout_s), None
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            raise ShipstarError(f"cannot reach the Dask scheduler at {scheduler} within {timeout_s:g} s "
                                f"({_one_line(exc)})") from None
    # the workers ignore Ctrl-C (sent to the whole process group at a terminal): this process
    # stops them after writing what was finished
    main = threading.current_thread() is threading.main_thread()
    old = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    try:
        method = start_method or local_start_method()
        with one_blas_thread_for_children(), dask.config.set(QUIET_DASK), \
                dask.config.set({"distributed.nanny.pre-spawn-environ": WORKER_ENVIRON,
                                 "distributed.worker.multiprocessing-method": method}):
            # no dashboard; the scheduler's small HTTP server (health, metrics) on a free port
            # rather than 8787, which another cluster may hold; the workers' own error logs
            # (a failed attempt's traceback) silenced: the command reports every attempt
            cluster = LocalCluster(n_workers=int(workers), threads_per_worker=int(threads_per_worker),
                                   processes=True, dashboard_address=None, silence_logs=logging.CRITICAL,
                                   host="127.0.0.1", scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    finally:
        if main:        # None: a handler not set from Python, which cannot be put back
            signal.signal(signal.SIGINT, signal.SIG_DFL if old is None else old)
    client = open_client(cluster, timeout_s=None)
    cores = _cores()
    if pin_workers and cores and int(workers) <= len(cores):
        from shipstar.pipeline._pin import PinToCore

        client.register_plugin(PinToCore(cores), name="shipstar-pin-to-core")
    return client, cluster


def _cores() -> list:
    """The CPUs this process may run on (sorted), or [] where the OS cannot say."""
    try:
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return []

