"""``shipstar measure-archive``: ``shipstar measure`` over an archive of sessions, on Dask."""

from __future__ import annotations

import argparse
import sys

from shipstar.cli._common import (
    accuracy_warnings,
    add_site_arguments,
    add_weather_arguments,
    check_output_dir,
    check_output_file,
    check_folders_apart,
    check_outputs_apart,
    emit_json,
    float_in_range,
    int_in_range,
)
from shipstar.errors import ShipstarError

__all__ = ["register", "run"]

EPILOG = """\
examples:
  shipstar measure-archive --session nights/2026-03-01 --session nights/2026-03-02 \\
      --install A1.install.toml A2.install.toml --out-dir attitude/ --workers 2
  shipstar measure-archive --sensor A1=sea/A1 --sensor A2=sea/A2 --install A1.toml A2.toml \\
      --track sea/track.csv --weather sea/weather.csv --out att.csv --scheduler tcp://10.0.0.5:8786

The rows are those of 'shipstar measure' with the same inputs, byte for byte: each
session is cut into --chunk-s chunks (default 60 s), each chunk of each sensor is one
Dask task (a fresh start with a lost-in-space solve, 6.6 s of the frames before the chunk
processed again to rebuild the tracking, motion and noise-model state), and the results come back to
this process, where they are merged in time order, paired and fused, and written.

Sessions: --sensor NAME=DIR (repeat per sensor) with --out CSV for one session, as in
'shipstar measure'; or --session DIR (repeat) with --out-dir DIR for many, each DIR
holding one sub-directory of FITS frames per sensor (named as the sensors of the
installation files, or --sensors A1,A2) and, unless the position or weather is given
here, its track.csv and weather.csv (the layout 'shipstar simulate-session' writes).
Each session's CSV is OUT-DIR/NAME.csv (NAME: the directory's name); --sessions-at-once
sessions run together (default 2) so that the cluster stays busy between sessions, each
driven by a process of its own.  Each session is indexed when due (the next one while the
current ones run); one that cannot be (a bad frame, folders that look swapped) is named on
one line and the others go on.  The merging, pairing and fusion of a session run in its
driver, about a tenth of the work: each keeps about 9 single-threaded workers busy (image
frames); for a larger cluster run more sessions at once, or several commands, each with
its share of the sessions, on the same --scheduler (docs/archive.md).

Where the tasks run: a LocalCluster of --workers processes (default: the cores) with one
thread each, or --scheduler tcp://HOST:PORT (any running Dask scheduler: dask-jobqueue on
SLURM/PBS, dask-kubernetes, 'dask scheduler' + 'dask worker'; docs/archive.md).  The
workers need shipstar installed, the frames at the same paths, and their own catalog
cache.  A task that raises is retried (--retries, default 2); a worker lost in the middle
of a task has it rescheduled.  Every chunk that ran more than once is reported on stderr.
A chunk that fails on every attempt is named on one line, its session's output is left as
OUT.partial (every row before that chunk) with its checkpoint, and the exit code is 1;
the same command with --resume continues it.  Ctrl-C or SIGTERM stops after the current
epoch, leaving OUT.partial (exit 130 / 143).

Exit codes: 0 every session complete, every frame solved, every epoch fused and
consistent; 1 a chunk failed, or (as 'shipstar measure') some frames failed or epochs are
inconsistent, or folders look swapped; 2 bad input, including a scheduler that cannot
be reached; 130 / 143 stopped by SIGINT / SIGTERM.
"""


def _name_value(text: str):
    from shipstar.cli._cmd_measure import _name_value as parse

    return parse(text)


def register(subparsers) -> argparse.ArgumentParser:
    from shipstar.cli._cmd_measure import SITE_HELPS, WEATHER_HELPS, add_processing_arguments
    from shipstar.cli._model_inputs import add_model_input_arguments

    p = subparsers.add_parser(
        "measure-archive", help="'shipstar measure' over many sessions or a long one, on a Dask cluster",
        description="Ship attitude over an archive of sessions, or one long session cut into time chunks, "
                    "processed as dask.distributed tasks (a LocalCluster here, or any Dask scheduler); the rows "
                    "are those of 'shipstar measure'.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    s = p.add_argument_group("sessions (one with --sensor, or many with --session)")
    s.add_argument("--sensor", action="append", type=_name_value, default=[], metavar="NAME=DIR",
                   help="one session: a sensor and its frames directory (repeat for each sensor)")
    s.add_argument("--session", action="append", default=[], metavar="DIR",
                   help="a session directory with one frames sub-directory per sensor (repeat)")
    s.add_argument("--sensors", metavar="A1,A2",
                   help="with --session: the sensors' sub-directories (default: the installation files' sensors)")
    p.add_argument("--install", required=True, action="extend", nargs="+", metavar="FILE",
                   help="installation TOML files, one per sensor")
    p.add_argument("--camera", action="append", type=_name_value, default=[], metavar="NAME=FILE",
                   help="camera preset or TOML file of a sensor (default: the installation's camera preset)")
    g = p.add_argument_group("ship position (fixed, or a track; with --session default DIR/track.csv)")
    add_site_arguments(g, SITE_HELPS, deflection_default=None)
    g.add_argument("--track", metavar="CSV", help="time_utc, lat_deg, lon_deg[, height_m][, xi_arcsec, eta_arcsec]")
    w = p.add_argument_group("weather (fixed, or a table; with --session default DIR/weather.csv)")
    add_weather_arguments(w, WEATHER_HELPS)
    w.add_argument("--weather", metavar="CSV", help="time_utc, pressure_hpa, temperature_c[, relative_humidity]")
    add_model_input_arguments(p, dock=False)
    o = add_processing_arguments(p)
    o.add_argument("--chunk-s", type=float_in_range(1e-3, 86400.0), default=60.0, metavar="S",
                   help="processing chunk (s, default 60): each sensor's chunk is one Dask task")
    d = p.add_argument_group("Dask")
    d.add_argument("--scheduler", metavar="ADDRESS",
                   help="a running Dask scheduler (tcp://HOST:PORT); default: a LocalCluster on this machine")
    d.add_argument("--workers", type=int_in_range(1, 256), default=None, metavar="N",
                   help="LocalCluster worker processes, one thread each (default: the cores)")
    d.add_argument("--no-pin-workers", action="store_true",
                   help="leave the LocalCluster's workers free to move between cores (default: "
                        "worker i on core i, when there are at least as many cores)")
    d.add_argument("--retries", type=int_in_range(0, 100), default=2, metavar="N",
                   help="retries of a task that raised (default 2)")
    d.add_argument("--retry-delay-s", type=float_in_range(0.0, 3600.0), default=1.0, metavar="S",
                   help="a failed attempt waits this long before its retry (s, default 1)")
    d.add_argument("--connect-timeout-s", type=float_in_range(0.1, 3600.0), default=10.0, metavar="S",
                   help="give up reaching --scheduler after this long (s, default 10)")
    d.add_argument("--sessions-at-once", type=int_in_range(1, 64), default=2, metavar="N",
                   help="sessions processed together, each driven by a process of its own (default 2)")
    r = p.add_argument_group("output")
    r.add_argument("--out", metavar="CSV", help="with --sensor: the attitude CSV to write")
    r.add_argument("--out-dir", metavar="DIR", help="with --session: write DIR/NAME.csv per session")
    r.add_argument("--truth", metavar="CSV",
                   help="with --sensor: true attitude (simulated sessions), errors in the summary")
    r.add_argument("--progress", action="store_true", help="progress bar on stderr (default: only on a terminal)")
    r.add_argument("--json", action="store_true", help="print one JSON object (the summaries)")
    r.add_argument("--resume", action="store_true",
                   help="continue stopped or failed sessions (OUT.partial and OUT.resume); with --session, "
                        "sessions already complete are skipped")
    p.set_defaults(run=run)
    return p


# -- the sessions ----------------------------------------------------------------------------

class _Session:
    """One session's command line (``args`` as ``shipstar measure`` would have it) and,
    once prepared, its job, sources and CSV comments."""

    def __init__(self, name: str, args):
        self.name, self.args = name, args
        self.job = self.sources = self.eop = self.truth = None
        self.comments, self.start_warnings, self.overrides = [], [], {}
        self.outcome = None            # ArchiveOutcome
        self.error = ""                # a one-line error (bad input found while running)
        self.swapped = ""
        self.skipped = ""
        self.resume = False
        self.not_started = ""          # the signal that stopped the command before this session began
        self.driver_pid = 0            # the process that drove it, when not this one


def _sessions(args) -> list:
    from pathlib import Path

    if bool(args.sensor) == bool(args.session):
        raise ShipstarError("give the frames either as --sensor NAME=DIR (one session) or as --session DIR "
                            "(one or more), not both")
    if args.sensor:
        if not args.out or args.out_dir:
            raise ShipstarError("with --sensor give --out CSV (--out-dir goes with --session)")
        if args.sensors:
            raise ShipstarError("--sensors goes with --session (with --sensor the sensors are named there)")
        return [_Session(Path(args.out).stem, argparse.Namespace(**vars(args)))]
    if not args.out_dir or args.out:
        raise ShipstarError("with --session give --out-dir DIR (--out goes with --sensor)")
    if args.truth:
        raise ShipstarError("--truth goes with --sensor (one session)")
    check_output_dir(args.out_dir, "--out-dir")
    if args.sensors:
        names = [n.strip() for n in args.sensors.split(",") if n.strip()]
    else:
        from shipstar.calibrate.installation import load_installation

        names = [load_installation(path).sensor for path in args.install]
    out, seen = [], {}
    for directory in args.session:
        d = Path(directory)
        if not d.is_dir():
            raise ShipstarError(f"--session {d} does not exist or is not a directory")
        name = d.name or d.resolve().name
        if name in seen:
            raise ShipstarError(f"two sessions named {name!r} ({seen[name]} and {d}): their outputs would collide")
        seen[name] = d
        a = argparse.Namespace(**vars(args))
        a.sensor = [(n, str(d / n)) for n in names]
        a.out = str(Path(args.out_dir) / f"{name}.csv")
        if args.lat_deg is None and args.lon_deg is None and not args.track:
            if not (d / "track.csv").is_file():
                raise ShipstarError(f"session {d} has no track.csv: give --track or --lat-deg/--lon-deg")
            a.track = str(d / "track.csv")
        if args.pressure_hpa is None and args.temperature_c is None and not args.weather:
            if not (d / "weather.csv").is_file():
                raise ShipstarError(f"session {d} has no weather.csv: give --weather or --pressure-hpa/--temperature-c")
            a.weather = str(d / "weather.csv")
        out.append(_Session(name, a))
    return out


def _plan_output(session) -> None:
    """Where a session's rows go: refuse to start over a stopped run (without --resume);
    with --resume continue it, skip a complete session (--session) or start afresh."""
    from pathlib import Path

    from shipstar.cli._cmd_measure import _check_partial

    a = session.args
    check_output_file(a.out, "--out")
    check_folders_apart(a)
    check_outputs_apart(a, [("--out", a.out, None)])
    out = Path(a.out)
    partial = out.with_name(out.name + ".partial")
    if not a.resume:
        _check_partial(a)
    elif a.session and not partial.exists():        # many sessions: resume those stopped, skip those done
        if out.exists():
            session.skipped = f"{out} is complete"
    else:
        session.resume = True


def _prepare(session, header_reader=None, progress=None) -> None:
    """As ``shipstar measure`` does before processing: the job, the frames' index (its
    headers read by ``header_reader``, :class:`~shipstar.pipeline._archive.HeaderReader`:
    on the cluster), the coverage and swap checks, and the CSV's comment lines; ``progress``:
    the index's progress (:func:`shipstar.cli._cmd_measure._sources`; given when the
    session is prepared before any processing, so that it has the terminal's line to itself)."""
    from shipstar.cli._cmd_measure import _check_covered, _csv_comments, _eop, _job, _override_comments, \
        _site_and_weather, _sources
    from pathlib import Path

    from dataclasses import replace

    from shipstar._codeid import code_identity, environment
    from shipstar.cli._header_checks import override_record
    from shipstar.pipeline import TruthTable
    from shipstar.pipeline._integrity import swap_check

    a = session.args
    n_caught = len(getattr(a, "caught_warnings", None) or [])
    track, weather = _site_and_weather(a)
    session.truth = TruthTable.read_csv(a.truth) if a.truth else None
    # the workers must run this code in this environment (a remote worker's other checkout: other rows)
    session.job = replace(_job(a, track, weather), code_identity=code_identity(), environment=environment())
    session.sources = _sources(a, session.job.configs, track, weather, header_reader=header_reader, progress=progress)
    for src in session.sources:                     # the workers may run in another directory
        src.directory = str(Path(src.directory).resolve())
    _check_covered(session.sources, track, weather)
    session.swapped = swap_check(session.job.configs, session.sources, track, weather, session.job.options) or ""
    if session.swapped:
        return
    session.eop = _eop(session.sources)
    here = argparse.Namespace(caught_warnings=(getattr(a, "caught_warnings", None) or [])[n_caught:])
    session.start_warnings = accuracy_warnings(here)
    session.overrides = override_record(a.header_checks)
    session.comments = _csv_comments(session.eop, session.start_warnings) + _override_comments(session.overrides)


def _stopped_by(stop) -> str:
    """What stopped the command (``SIGINT``, ``SIGTERM``...), for a session not started."""
    return getattr(stop, "reason", "") or "stopped"


def _why(exc: BaseException) -> str:
    """An exception's text on one line (its type's name when it has none)."""
    return " ".join(str(exc).split()) or type(exc).__name__


class _Preparation:
    """Sessions prepared (:func:`_prepare`) in their order by one thread of this process,
    each when taken or, with ``ahead`` 1, the next one while those taken are processed
    (in driver processes: this process's main thread then only watches them, so that the
    accuracy warnings the preparation records are its own session's).  A night's index
    (720 000 headers for two sensors at 10 frames/s, read by the workers but assembled and
    checked here) and its swap check thus no longer wait until every session of a voyage
    has been indexed, nor leave the cluster idle meanwhile.

    A session whose preparation fails gets its one-line ``error`` (or ``swapped``) and the
    others go on; once ``stop`` is set no further session is prepared (``not_started``).
    """

    def __init__(self, sessions, header_reader, stop, ahead: int = 1):
        from concurrent.futures import ThreadPoolExecutor

        self.sessions, self.reader, self.ahead, self.stop = list(sessions), header_reader, int(ahead), stop
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="shipstar-prepare")
        self._futures: list = []
        self._taken = 0
        self._fill()

    def _fill(self, upto: int | None = None) -> None:
        """Sessions set going up to ``upto`` (default: ``ahead`` beyond the last taken)."""
        upto = self._taken + self.ahead if upto is None else upto
        while len(self._futures) < min(len(self.sessions), upto):
            self._futures.append(self._pool.submit(self._one, self.sessions[len(self._futures)]))

    def _one(self, s) -> None:
        if self.stop.is_set():
            s.not_started = _stopped_by(self.stop)
            return
        try:
            _prepare(s, self.reader)
        except ShipstarError as exc:
            s.error = str(exc)
        except Exception as exc:                   # the cluster closed under a stop: not an error of its own
            if not self.stop.is_set():
                raise
            s.not_started = getattr(self.stop, "reason", "") or f"stopped ({type(exc).__name__})"

    def take(self, i: int, timeout_s: float | None = None):
        """Session ``i`` once prepared (waiting at most ``timeout_s``: None when not yet),
        then the next ones set going."""
        from concurrent.futures import TimeoutError as FutureTimeout

        self._fill(i + 1)
        try:
            self._futures[i].result(timeout=timeout_s)
        except FutureTimeout:
            return None
        self._taken = max(self._taken, i + 1)
        self._fill()
        s = self.sessions[i]
        if s.overrides:
            from shipstar.cli._header_checks import print_overrides

            print_overrides("measure-archive", s.overrides)
        return s

    def close(self) -> None:
        for f in self._futures:
            f.cancel()
        self._pool.shutdown(wait=True)


class _Prepared:
    """:class:`_Preparation`'s part for a session prepared already (one session)."""

    @staticmethod
    def take(i: int, timeout_s: float | None = None):
        return True

    @staticmethod
    def close() -> None:
        pass


def _runnable(s) -> bool:
    return s.job is not None and not (s.swapped or s.error or s.skipped or s.not_started)


def _process_all(sessions, client, args, stop, bar, prep) -> None:
    """Every session through :func:`~shipstar.pipeline._archive.run_archive`,
    ``--sessions-at-once`` at a time, each taken from ``prep`` (:class:`_Preparation`)
    once prepared.  One session runs here; several run each in a process of its own
    (:func:`_drive_in_processes`), so that their engines (the merge, the fusion, the CSV:
    ~1 ms of Python a frame) do not share this process's core."""
    from shipstar.pipeline._archive import run_archive

    todo = [s for s in sessions if not s.skipped]
    totals = {id(s): 0 for s in todo}
    done = {id(s): 0 for s in todo}

    def progress(s):
        totals[id(s)] = sum(len(src) for src in s.sources)

        def cb(n, total):
            done[id(s)] = n
            waiting = sum(1 for t in todo if not totals[id(t)] and not (t.error or t.swapped or t.not_started))
            bar("frames" if not waiting else f"frames ({waiting} more sessions to come)",
                sum(done.values()), sum(totals.values()))
        return cb

    if len(todo) > 1 and args.sessions_at_once > 1:
        _drive_in_processes(todo, client.scheduler.address, args, stop, progress, prep)
        return
    for i, s in enumerate(todo):
        if stop.is_set():
            s.not_started = s.not_started or _stopped_by(stop)
            continue
        prep.take(i)
        if not _runnable(s):
            continue
        try:
            s.outcome = run_archive(client, s.job, s.sources, s.args.out, **_run_kwargs(s, args),
                                    progress=progress(s), stop=stop)
        except ShipstarError as exc:
            s.error = str(exc)


def _run_kwargs(s, args) -> dict:
    """:func:`~shipstar.pipeline._archive.run_archive`'s options for session ``s``."""
    return dict(retries=args.retries, retry_delay_s=args.retry_delay_s, truth=s.truth, comments=s.comments,
                resume=s.resume, chunk_s=args.chunk_s)


#: Signals a driver process is told of, as its stop reason (the value of a shared int).
_HALT_REASONS = {1: "SIGINT", 2: "SIGTERM", 3: "stopped"}


class _Halt:
    """A driver process's stop event: set when the command's shared ``code`` is non-zero,
    its ``reason`` the signal the command got (``run_measure``'s ``stop``)."""

    def __init__(self, code):
        self.code = code

    def is_set(self) -> bool:
        return self.code.value != 0

    @property
    def reason(self) -> str:
        return _HALT_REASONS.get(self.code.value, "")


_DRIVER: dict = {}


def _driver_init(code, updates) -> None:
    """A driver process starts: Ctrl-C and SIGTERM are the command's to handle (it tells
    the drivers through ``code``); Dask as quiet as in the command."""
    import signal

    import dask

    from shipstar.pipeline._archive import QUIET_DASK

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    dask.config.set(QUIET_DASK)
    _DRIVER.update(halt=_Halt(code), updates=updates)


def _drive_session(address: str, k: int, job, sources, out, kwargs) -> tuple:
    """In a driver process: session ``k`` through ``run_archive`` with a client of its own to
    the scheduler at ``address``; ``("ok", ArchiveOutcome, pid)``, ``("error", message,
    pid)``, or ``("not started", reason, pid)`` when the command was stopped first."""
    import os

    from shipstar.pipeline._archive import open_client, run_archive

    halt, updates = _DRIVER["halt"], _DRIVER["updates"]
    if halt.is_set():
        return "not started", halt.reason, os.getpid()
    try:
        client = open_client(address, timeout_s=30)
    except Exception as exc:                # OSError, TimeoutError, ValueError, or Dask's own
        return "error", f"its driver process could not reach the Dask scheduler at {address} ({_why(exc)})", \
            os.getpid()
    try:
        outcome = run_archive(client, job, sources, out, **kwargs, stop=halt,
                              progress=lambda n, total: updates.put((k, n, total)))
        return "ok", outcome, os.getpid()
    except ShipstarError as exc:
        return "error", str(exc), os.getpid()
    finally:
        client.close()


def _drive_in_processes(todo, address: str, args, stop, progress, prep) -> None:
    """Sessions ``todo``, ``--sessions-at-once`` at a time, each driven by a process of its own
    (spawned: this process has threads; ~1 s to start) with its own client of the cluster's
    scheduler: the tasks of all of them share the cluster, and each session's merge, engine
    and CSV run on a core of their own, where in threads of one process they would share
    one (Python's GIL: ~1,000 frames a second for all sessions together on the development
    machine).  A stop (SIGINT, SIGTERM) is passed on: each driver ends after its current
    epoch, leaving its ``OUT.partial``; a session not started by then is reported as such.
    A session goes to a driver once ``prep`` has prepared it and a driver is free."""
    import multiprocessing
    import queue
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    from shipstar.pipeline._measure import one_blas_thread_for_children

    ctx = multiprocessing.get_context("spawn")
    code, updates = ctx.Value("i", 0), ctx.Queue()
    callbacks = {}
    codes = {v: c for c, v in _HALT_REASONS.items()}
    at_once = min(args.sessions_at_once, len(todo))

    def drain():
        while True:
            try:
                k, n, total = updates.get_nowait()
            except queue.Empty:
                return
            callbacks[k](n, total)

    ex = ProcessPoolExecutor(max_workers=at_once, mp_context=ctx, initializer=_driver_init, initargs=(code, updates))
    futures, pending, k = {}, set(), 0
    try:
        while k < len(todo) or pending:
            if stop.is_set() and code.value == 0:
                code.value = codes.get(getattr(stop, "reason", ""), 3)
            while k < len(todo) and len(pending) < at_once:
                s = todo[k]
                if stop.is_set():
                    s.not_started = s.not_started or _stopped_by(stop)
                elif prep.take(k, timeout_s=0 if pending else 0.2) is None:
                    break                           # not yet prepared: the running ones are watched meanwhile
                elif _runnable(s):
                    callbacks[k] = progress(s)
                    with one_blas_thread_for_children():    # (a process starts with its first task)
                        f = ex.submit(_drive_session, address, k, s.job, s.sources, s.args.out, _run_kwargs(s, args))
                    futures[f] = s
                    pending.add(f)
                k += 1
            if not pending:
                continue
            finished, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            drain()
            for f in finished:
                s = futures[f]
                try:
                    what, value, s.driver_pid = f.result()
                except BrokenProcessPool:
                    s.error = "its driver process died (out of memory, or killed); OUT.partial holds the rows it " \
                              "wrote, --resume continues it"
                    continue
                except Exception as exc:            # (not expected: the driver returns its errors)
                    s.error = f"its driver process failed ({_why(exc)}); OUT.partial holds the rows it wrote, " \
                              "--resume continues it"
                    continue
                if what == "ok":
                    s.outcome = value
                elif what == "error":
                    s.error = value
                else:
                    s.not_started = value
        drain()
    finally:
        ex.shutdown(wait=True)


def _summary(session, args) -> dict:
    from shipstar._codeid import software
    from shipstar.cli._cmd_measure import _roles
    from shipstar.cli._model_inputs import add_measure_uncertainty

    a, job = session.args, session.job
    if session.skipped:
        return {"out": a.out, "complete": True, "skipped": session.skipped}
    if session.swapped or session.error:
        return {"out": a.out, "complete": False, "error": session.swapped or session.error}
    if session.outcome is None:                     # stopped before it started
        return {"out": a.out, "complete": False, "stopped": session.not_started or "stopped", "not_started": True}
    o = session.outcome
    m = o.measure
    base = {"chunks": o.n_tasks, "chunks_run_again": list(o.attempts)}
    if session.driver_pid:
        base["driver_pid"] = session.driver_pid
    if m is None:
        partial = a.out + ".partial"
        return {"out": partial, "complete": False, "failed_chunk": o.failed, **base}
    names = [c.name for c in job.configs]
    fore, athw = _roles(job.configs)
    summary = m.stats.summary(reference_sensor=names[job.reference], fore_aft_sensor=fore, athwartship_sensor=athw,
                              options=job.options)
    summary["out"] = str(m.path)
    summary["complete"] = m.complete
    summary["software"] = software()
    summary["eop"] = session.eop
    add_measure_uncertainty(summary, a, job)
    summary["date_obs_is"] = a.date_obs_is
    summary["time_sources"] = {s.name: s.time_sources() for s in session.sources}
    summary["warnings"] = list(dict.fromkeys(session.start_warnings + list(m.warnings)))
    summary.update(session.overrides)
    summary.update(base)
    if m.resumed_at_s is not None:
        summary["resumed_at_s"] = m.resumed_at_s
    if m.stopped:
        summary["stopped"] = m.stopped
    return summary


def run(args) -> int:
    from shipstar._signals import EXIT_CODES, StopOnSignals
    from shipstar.cli._cmd_measure import _print_text
    from shipstar.cli._header_checks import print_overrides
    from shipstar.cli._model_inputs import print_measure_uncertainty
    import dask

    from shipstar.cli._cmd_measure import _configs
    from shipstar.pipeline._archive import QUIET_DASK, HeaderReader, connect, local_start_method, warm_here, \
        warm_workers
    from shipstar.pipeline._measure import default_workers
    from shipstar.pipeline._progress import ProgressBar

    import time

    where = "shipstar measure-archive"
    sessions = _sessions(args)
    for s in sessions:
        _plan_output(s)
    n_workers = args.workers or default_workers()
    bar = ProgressBar(True if args.progress else None)
    dask.config.set(QUIET_DASK)                     # this process's part (the LocalCluster's: connect)
    client = cluster = None
    timing = {"connect_s": 0.0, "process_s": 0.0}
    try:
        todo = [s for s in sessions if not s.skipped]
        cameras = [c.camera for c in _configs(todo[0].args)] if todo else []
        # the cluster first: its workers read the frames' headers (the index) side by side;
        # a scheduler's workers load the catalog and star databases meanwhile, a
        # LocalCluster's are forked from this process with them already loaded
        if todo:
            t0 = time.perf_counter()
            if args.scheduler:
                client, cluster = connect(args.scheduler, timeout_s=args.connect_timeout_s)
            else:
                method = local_start_method()
                if method == "fork":
                    warm_here(cameras)
                client, cluster = connect(None, workers=n_workers, start_method=method,
                                          pin_workers=not args.no_pin_workers)
            timing["connect_s"] = time.perf_counter() - t0
            warming = warm_workers(client, cameras)
        if len(todo) == 1:                          # one session: prepared first, an error is the command's
            _prepare(todo[0], HeaderReader(client, retries=args.retries), progress=bar)
            print_overrides("measure-archive", todo[0].overrides)
        with StopOnSignals() as stop:
            if len(todo) > 1:                       # each session prepared when due, or the next one ahead
                prep = _Preparation(todo, HeaderReader(client, retries=args.retries), stop,
                                    ahead=1 if args.sessions_at_once > 1 else 0)
            else:
                prep = _Prepared() if todo and _runnable(todo[0]) else None
            if prep is not None:
                try:
                    t1 = time.perf_counter()
                    _process_all(sessions, client, args, stop, bar, prep)
                    timing["process_s"] = time.perf_counter() - t1
                finally:
                    prep.close()
        if client is not None:
            del warming
    finally:
        bar.close()
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    summaries = {s.name: _summary(s, args) for s in sessions}
    if args.json:
        # the CPU this process used itself (all its threads: the merge, fusion and CSV, Dask's
        # client and a LocalCluster's scheduler), beside the workers' (bench_archive)
        emit_json({"sessions": summaries, "scheduler": args.scheduler or f"LocalCluster({n_workers} workers)",
                   "chunk_s": args.chunk_s, "retries": args.retries, "wall": timing,
                   "cpu": {"command_s": time.process_time()}})
    else:
        for s in sessions:
            summary = summaries[s.name]
            if len(sessions) > 1:
                print(f"session {s.name}:")
            if "methods" in summary:
                _print_text(summary, summary["out"])
                print_measure_uncertainty(summary)
            elif summary.get("skipped"):
                print(f"skipped: {summary['skipped']}")
            elif summary.get("not_started"):
                print(f"not started (stopped by {summary['stopped']})")
    code = 0
    for s in sessions:
        summary = summaries[s.name]
        tag = f"session {s.name}: " if len(sessions) > 1 else ""
        for line in summary.get("chunks_run_again", []):
            print(f"{where}: {tag}run again: {line}", file=sys.stderr)
        if summary.get("error"):
            print(f"{where}: error: {tag}{summary['error']}", file=sys.stderr)
            code = max(code, 1 if s.swapped else 2)
        elif summary.get("failed_chunk"):
            print(f"{where}: {tag}failed: {summary['failed_chunk']}; {summary['out']} holds every row before it "
                  f"(the same command with --resume continues it)", file=sys.stderr)
            code = max(code, 1)
        elif summary.get("not_started"):
            print(f"{where}: {tag}not started (stopped by {summary['stopped']}); the same command with --resume "
                  f"runs it", file=sys.stderr)
            code = max(code, EXIT_CODES.get(summary["stopped"], 1))
        elif summary.get("stopped"):
            print(f"{where}: {tag}stopped by {summary['stopped']}; {summary['out']} holds every finished row; "
                  f"the same command with --resume continues it", file=sys.stderr)
            code = max(code, EXIT_CODES.get(summary["stopped"], 1))
        elif "methods" in summary:
            problems = s.outcome.measure.stats.problems_line()
            if problems:
                print(f"{where}: {tag}{problems}", file=sys.stderr)
                code = max(code, 1)
    return code
