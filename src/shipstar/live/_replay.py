"""A recorded or simulated session written into per-sensor directories at its real time
spacing (``shipstar replay``, docs/live.md), so that ``shipstar live`` can be run,
demonstrated and tested end to end.

Two steps:

:func:`plan_replay`
    Reads the frames' headers (:func:`shipstar.pipeline.scan_frames`: mid-exposure UTC)
    of every sensor directory and merges them into one time order; reads the session's
    ``track.csv`` / ``weather.csv`` (if given) into their header and timed rows.  Nothing
    is written; every problem is a one-line :class:`~shipstar.errors.ShipstarError`.
:func:`replay`
    Writes the plan into a new (or empty) directory: ``DIR/<sensor>/<file name>`` for
    each frame at wall time ``start + (t_frame - t_first) / speed``, and the tables as
    growing files ``DIR/track.csv``, ``DIR/weather.csv``.

**Write, then rename.**  A frame is first copied to a hidden temporary name in its final
directory (``.<name>.<random>.part``: a dot-file without a FITS suffix, which readers
ignore) and, at its due time, renamed into its final name with :func:`os.replace`.  A
reader therefore never sees a half-written frame under a FITS name; the copy is made
*ahead* of the due time, so the frame appears within a fraction of a millisecond of it.

**Timing.**  Every due time is computed from one start instant on ``time.monotonic()``
(no accumulated sleeps: no drift); the writer sleeps until each due time.  A frame that
appears more than :data:`LATE_THRESHOLD_MS` after its due time is *late*; the result
counts them and gives the largest lateness.  ``speed = 0`` (:data:`FAST_SPEED`) means
as fast as possible: no schedule, the frames (and table rows, interleaved in session
time order) are written one after the other, and no lateness is reported.

**Tables.**  The header (and any ``#`` comment lines before it) and every row due
before the first frame are written at the start; each later row is appended (one write,
flushed) when the replay clock (session seconds since the first frame) reaches the row's
``time_utc`` minus the lead ``table_lead_s``, so that a reader always has a row just
after the current frame.  Rows due after the last frame are appended right after it.

**Stopping.**  Run from the main thread, :func:`replay` handles SIGINT and SIGTERM (only
while it runs; the previous handlers are restored): the frame being copied is finished,
every temporary file is removed, nothing more is written, and the result says
``stopped = "SIGINT"`` (or ``"SIGTERM"``).  A ``threading.Event`` (``stop_event``)
stops it the same way from another thread (``stopped = "requested"``).
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import signal
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from shipstar._atomic import atomic_write_text
from shipstar.errors import ShipstarError
from shipstar.pipeline._frames import FITS_SUFFIXES, scan_frames
from shipstar.units import DAY_S

__all__ = ["ReplayFrame", "ReplayTable", "ReplayPlan", "ReplayResult", "plan_replay", "replay",
           "session_sensor_dirs", "session_tables", "check_sensor_name", "check_destination",
           "TABLE_NAMES", "FAST_SPEED", "LATE_THRESHOLD_MS", "TEMP_SUFFIX", "DEFAULT_START_DELAY_S",
           "DEFAULT_TABLE_LEAD_S"]

#: The session tables replayed as growing files (``track.csv``, ``weather.csv``).
TABLE_NAMES = ("track.csv", "weather.csv")
#: ``speed`` meaning "as fast as possible" (no schedule).
FAST_SPEED = 0.0
#: A frame that appears later than this after its due time counts as late (ms).
LATE_THRESHOLD_MS = 10.0
#: Suffix of the temporary (hidden) names frames are copied to before the rename.
TEMP_SUFFIX = ".part"
#: Default wall time between creating the directories and the first frame (s).
DEFAULT_START_DELAY_S = 0.5
#: Default lead of the table rows over the frames (session seconds).
DEFAULT_TABLE_LEAD_S = 2.0
#: Longest single sleep (s): how quickly a stop request is noticed while waiting.
_SLEEP_CHUNK_S = 0.02
#: Exit reasons of signals (``ReplayResult.stopped``).
_SIGNALS = (signal.SIGINT, signal.SIGTERM)


# ---------------------------------------------------------------------------------------
# The plan: what to write, when (session seconds since the first frame)
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ReplayFrame:
    """One frame to write.

    Attributes
    ----------
    sensor : str
        Sensor name: the frame goes to ``DIR/<sensor>/<source.name>``.
    source : Path
        The frame's file.
    offset_s : float
        Its mid-exposure time, seconds after the session's first frame (any sensor).
    """

    sensor: str
    source: Path
    offset_s: float


@dataclass(frozen=True)
class ReplayTable:
    """A CSV table replayed as a growing file.

    Attributes
    ----------
    name : str
        File name in the replay directory (``track.csv``, ``weather.csv``).
    source : Path
    head : str
        Leading ``#`` comment (and blank) lines and the header row, with newlines.
    rows : tuple of (float, str)
        Each data row's time (seconds after the first frame) and its text: the row with
        its newline, preceded by the comment lines just before it in the file.
    tail : str
        Comment lines after the last row ('' if none).
    """

    name: str
    source: Path
    head: str
    rows: tuple
    tail: str = ""


@dataclass(frozen=True)
class ReplayPlan:
    """Frames of all sensors in one time order, and the tables.

    Attributes
    ----------
    frames : tuple of ReplayFrame
        Sorted by ``offset_s`` (ties: sensor order, then file name); the first is at 0.
    sensors : tuple of str
        Sensor names, in the order given.
    tables : tuple of ReplayTable
    first_utc_jd : (float, float)
        Two-part UTC JD of the first frame (mid-exposure).
    """

    frames: tuple
    sensors: tuple
    tables: tuple = ()
    first_utc_jd: tuple = (math.nan, math.nan)

    @property
    def span_s(self) -> float:
        """Session seconds from the first to the last frame."""
        return self.frames[-1].offset_s if self.frames else 0.0

    def frames_per_sensor(self) -> dict:
        """``{sensor: number of frames}``."""
        out = dict.fromkeys(self.sensors, 0)
        for f in self.frames:
            out[f.sensor] += 1
        return out


def check_sensor_name(name: str) -> str:
    """A sensor name usable as a directory name in the replay directory (returned
    stripped); ShipstarError otherwise."""
    text = str(name).strip()
    if not text or text in (".", "..") or text.startswith(".") or "/" in text or "\\" in text \
            or os.sep in text or text in TABLE_NAMES:
        raise ShipstarError(f"sensor name {name!r} cannot be a directory name (no '/', not hidden, "
                            f"not {', '.join(TABLE_NAMES)})")
    return text


def _has_frames(directory: Path) -> bool:
    return any(p.suffix.lower() in FITS_SUFFIXES and not p.name.startswith(".") for p in directory.iterdir())


def session_sensor_dirs(session_dir, sensors=None) -> dict:
    """``{sensor: directory}`` of a session directory (one sub-directory of FITS frames
    per sensor, as ``shipstar simulate-session`` writes).

    Parameters
    ----------
    session_dir : str or Path
    sensors : sequence of str, optional
        Only these sub-directories (each must exist); default: every non-hidden
        sub-directory holding at least one FITS frame, in name order.

    Raises
    ------
    ShipstarError
        Missing session directory, a named sensor directory missing, or none found.
    """
    root = Path(session_dir)
    if not root.is_dir():
        raise ShipstarError(f"session directory {root} does not exist or is not a directory")
    if sensors is not None:
        out = {}
        for name in map(check_sensor_name, sensors):
            if not (root / name).is_dir():
                raise ShipstarError(f"sensor directory {root / name} does not exist")
            out[name] = root / name
        return out
    out = {p.name: p for p in sorted(root.iterdir())
           if p.is_dir() and not p.name.startswith(".") and _has_frames(p)}
    if not out:
        hint = (" (it holds FITS files itself: give --sensor NAME=DIR)" if _has_frames(root)
                else " (expected one sub-directory of FITS frames per sensor, e.g. A1/*.fits)")
        raise ShipstarError(f"no sensor directories with FITS frames in {root}{hint}")
    return out


def session_tables(session_dir) -> dict:
    """``{file name: path}`` of the session's tables (:data:`TABLE_NAMES`) that exist."""
    root = Path(session_dir)
    return {name: root / name for name in TABLE_NAMES if (root / name).is_file()}


def _offset_s(jd: tuple, first: tuple) -> float:
    """Seconds from ``first`` to ``jd`` (two-part JDs), to the microsecond (the files' time
    resolution: equal times stay equal)."""
    return round(((jd[0] - first[0]) + (jd[1] - first[1])) * DAY_S, 6)


def _merged_frames(sensor_dirs: dict, date_obs_is: str) -> tuple[list, tuple]:
    """All sensors' frames in one time order (ties: sensor order, then file name), and the
    first frame's UTC JD."""
    scanned = [(name, f) for name, directory in sensor_dirs.items()
               for f in scan_frames(directory, date_obs_is=date_obs_is)]
    ref = (scanned[0][1].utc_jd1, scanned[0][1].utc_jd2)
    first = min((f for _, f in scanned), key=lambda f: _offset_s((f.utc_jd1, f.utc_jd2), ref))
    first_jd = (first.utc_jd1, first.utc_jd2)
    order = {name: i for i, name in enumerate(sensor_dirs)}
    frames = [ReplayFrame(name, Path(f.path), _offset_s((f.utc_jd1, f.utc_jd2), first_jd)) for name, f in scanned]
    frames.sort(key=lambda fr: (fr.offset_s, order[fr.sensor], fr.source.name))
    return frames, first_jd


def _read_table(name: str, path: Path, first_jd: tuple) -> ReplayTable:
    """A CSV table split into its head, its timed rows and its trailing comments."""
    from shipstar.sky.time import utc_jd_from_iso

    try:
        lines = path.read_bytes().decode("utf-8").splitlines(keepends=True)   # line endings kept
    except (OSError, UnicodeDecodeError) as exc:
        raise ShipstarError(f"cannot read {path}: {getattr(exc, 'strerror', None) or exc}") from None
    lines = [ln if ln.endswith("\n") else ln + "\n" for ln in lines]
    head, i = [], 0
    while i < len(lines) and (lines[i].startswith("#") or not lines[i].strip()):
        head.append(lines[i])
        i += 1
    if i == len(lines):
        raise ShipstarError(f"{path} has no header row")
    header = [c.strip() for c in lines[i].split(",")]
    head.append(lines[i])
    if "time_utc" not in header:
        raise ShipstarError(f"{path}: no time_utc column in the header {lines[i].strip()!r}")
    col, rows, pending = header.index("time_utc"), [], ""
    for lineno, line in enumerate(lines[i + 1:], start=i + 2):
        if line.startswith("#") or not line.strip():
            pending += line
            continue
        cells = line.split(",")
        if col >= len(cells):
            raise ShipstarError(f"{path} line {lineno}: no time_utc value")
        try:
            jd = utc_jd_from_iso(cells[col].strip())
        except ShipstarError as exc:
            raise ShipstarError(f"{path} line {lineno}: {exc}") from None
        rows.append((_offset_s(jd, first_jd), pending + line))
        pending = ""
    return ReplayTable(name, path, "".join(head), tuple(rows), pending)


def plan_replay(sensor_dirs: dict, tables: dict | None = None, *, date_obs_is: str = "start") -> ReplayPlan:
    """What to write and when: the frames of every sensor in one time order, the tables.

    Parameters
    ----------
    sensor_dirs : dict
        ``{sensor name: directory of its FITS frames}`` (at least one).
    tables : dict, optional
        ``{file name in the replay directory: CSV path}`` with a ``time_utc`` column
        (:func:`session_tables`).
    date_obs_is : {"start", "mid"}
        What the frames' DATE-OBS means (:func:`shipstar.pipeline.scan_frames`).

    Returns
    -------
    ReplayPlan

    Raises
    ------
    ShipstarError
        No sensor, a bad sensor name, a directory without frames, a frame without a usable
        time, frames out of time order, an unreadable table or time.
    """
    if not sensor_dirs:
        raise ShipstarError("no sensors to replay")
    dirs = {check_sensor_name(name): Path(d) for name, d in sensor_dirs.items()}
    if len(dirs) != len(sensor_dirs):
        raise ShipstarError(f"sensor names must be unique, got {', '.join(sensor_dirs)}")
    frames, first_jd = _merged_frames(dirs, date_obs_is)
    read = tuple(_read_table(name, Path(path), first_jd) for name, path in (tables or {}).items())
    return ReplayPlan(tuple(frames), tuple(dirs), read, first_jd)


def check_destination(to_dir) -> Path:
    """Refuse (ShipstarError) a replay directory that is not new or empty, or that cannot
    be created or written.  Nothing is created."""
    out = Path(to_dir)
    if str(to_dir).strip() == "":
        raise ShipstarError("--to needs a directory name")
    if out.exists():
        if not out.is_dir():
            raise ShipstarError(f"--to {out} exists and is not a directory")
        if any(out.iterdir()):
            raise ShipstarError(f"--to {out} is not empty: give a new or empty directory")
    probe = out
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise ShipstarError(f"--to {out}: {probe} is a file, not a directory")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise ShipstarError(f"--to {out}: no permission to write in {probe}")
    return out


# ---------------------------------------------------------------------------------------
# The result
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ReplayResult:
    """What :func:`replay` wrote.

    Attributes
    ----------
    to_dir : Path
    frames_by_sensor : dict
        ``{sensor: frames written}``.
    planned_by_sensor : dict
        ``{sensor: frames in the plan}``.
    table_rows : dict
        ``{table file name: data rows written}``.
    speed : float
        Replay speed (0: as fast as possible).
    duration_s : float
        Wall time of the whole replay, start delay included.
    session_span_s : float
        Session seconds from the first to the last frame.
    late_frames : int
        Frames that appeared more than :data:`LATE_THRESHOLD_MS` after their due time.
    max_late_ms : float or None
        Largest lateness of any frame (ms, >= 0); None at ``speed = 0`` (no schedule).
    stopped : str or None
        ``"SIGINT"``, ``"SIGTERM"``, ``"requested"`` (``stop_event``), or None when complete.
    """

    to_dir: Path
    frames_by_sensor: dict
    planned_by_sensor: dict
    table_rows: dict
    speed: float
    duration_s: float
    session_span_s: float
    late_frames: int
    max_late_ms: float | None
    stopped: str | None = None

    @property
    def frames_written(self) -> int:
        return sum(self.frames_by_sensor.values())

    @property
    def frames_planned(self) -> int:
        return sum(self.planned_by_sensor.values())

    @property
    def partial(self) -> bool:
        """True when stopped before every frame and row was written."""
        return self.stopped is not None

    def to_dict(self) -> dict:
        """The JSON summary (``shipstar replay --json``)."""
        return {"to": str(self.to_dir), "frames": dict(self.frames_by_sensor),
                "frames_written": self.frames_written, "frames_planned": self.frames_planned,
                "table_rows": dict(self.table_rows), "speed": self.speed,
                "duration_s": round(self.duration_s, 6), "session_span_s": round(self.session_span_s, 6),
                "late_frames": self.late_frames, "late_threshold_ms": LATE_THRESHOLD_MS,
                "max_late_ms": None if self.max_late_ms is None else round(self.max_late_ms, 3),
                "stopped": self.stopped, "partial": self.partial}


# ---------------------------------------------------------------------------------------
# Running it
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Event:
    """A frame to publish or a table text to append, ``due_s`` on the replay clock."""

    due_s: float
    rank: int                      # 0: table text, 1: frame (tables first at equal times)
    seq: int
    frame: ReplayFrame | None = None
    table: str = ""
    text: str = ""


def _table_chunks(table: ReplayTable, lead_s: float, last_s: float) -> tuple[str, list, str]:
    """(text written at the start, timed events, text appended after the last frame)."""
    start, events, end = table.head, [], ""
    for offset_s, text in table.rows:
        due_s = offset_s - lead_s
        if due_s <= 0.0:
            start += text
        elif due_s > last_s:
            end += text
        else:
            events.append((due_s, text))
    return start, events, end + table.tail


def _schedule(plan: ReplayPlan, lead_s: float) -> tuple[dict, list, dict]:
    """``({table: start text}, [groups of _Event with one due time, in order], {table: end text})``."""
    events = [_Event(f.offset_s, 1, k, frame=f) for k, f in enumerate(plan.frames)]
    starts, ends = {}, {}
    for t in plan.tables:
        starts[t.name], timed, ends[t.name] = _table_chunks(t, lead_s, plan.span_s)
        events += [_Event(due, 0, len(events) + j, table=t.name, text=text) for j, (due, text) in enumerate(timed)]
    events.sort(key=lambda e: (e.due_s, e.rank, e.seq))
    groups: list = []
    for e in events:
        if groups and groups[-1][0].due_s == e.due_s:
            groups[-1].append(e)
        else:
            groups.append([e])
    return starts, groups, ends


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


class _Stop:
    """Stop requests: a signal (its name) or an external event."""

    def __init__(self, event: threading.Event | None):
        self.event = event
        self.reason: str | None = None

    def __call__(self) -> bool:
        if self.reason is None and self.event is not None and self.event.is_set():
            self.reason = "requested"
        return self.reason is not None

    def on_signal(self, signum, _frame) -> None:
        self.reason = signal.Signals(signum).name


@contextlib.contextmanager
def _signal_handlers(stop: _Stop, enabled: bool):
    """SIGINT / SIGTERM set ``stop`` while inside (main thread only); old handlers restored."""
    if not enabled or threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, stop.on_signal) for s in _SIGNALS}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)


def _sleep_until(deadline: float, stop: _Stop) -> bool:
    """Sleep until ``time.monotonic() >= deadline``; False if stopped first."""
    while not stop():
        remaining = deadline - time.monotonic()
        if remaining <= 0.0:
            return True
        time.sleep(min(remaining, _SLEEP_CHUNK_S))
    return False


def _stage(frame: ReplayFrame, dest: Path, mode: int) -> Path:
    """Copy a frame to a hidden temporary file beside ``dest``; returns its path."""
    try:
        fd, name = tempfile.mkstemp(dir=dest.parent, prefix=f".{dest.name}.", suffix=TEMP_SUFFIX)
    except OSError as exc:
        raise ShipstarError(f"cannot write in {dest.parent}: {exc.strerror or exc}") from None
    os.close(fd)
    tmp = Path(name)
    try:
        shutil.copyfile(frame.source, tmp)
        os.chmod(tmp, mode)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise ShipstarError(f"cannot copy {frame.source} to {dest}: {exc.strerror or exc}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return tmp


class _Writer:
    """The replay directory's files: staged frames, published frames, growing tables."""

    def __init__(self, to_dir: Path, plan: ReplayPlan):
        self.to_dir = to_dir
        self.mode = 0o666 & ~_umask()
        self.staged: dict = {}            # event seq -> temporary path
        self.frames = dict.fromkeys(plan.sensors, 0)
        self.rows = {t.name: 0 for t in plan.tables}
        self.handles: dict = {}

    def create(self, plan: ReplayPlan, start_texts: dict) -> None:
        try:
            self.to_dir.mkdir(parents=True, exist_ok=True)
            for name in plan.sensors:
                (self.to_dir / name).mkdir(exist_ok=True)
        except OSError as exc:
            raise ShipstarError(f"cannot create {self.to_dir}: {exc.strerror or exc}") from None
        for name, text in start_texts.items():
            atomic_write_text(self.to_dir / name, text, newline="", what="table")
            self.rows[name] += _data_rows(text) - 1          # the header is not a row
            self.handles[name] = open(self.to_dir / name, "ab", buffering=0)

    def stage(self, event: _Event) -> None:
        self.staged[event.seq] = _stage(event.frame, self._dest(event.frame), self.mode)

    def publish(self, event: _Event) -> None:
        if event.frame is None:
            self.append(event.table, event.text)
            return
        os.replace(self.staged.pop(event.seq), self._dest(event.frame))
        self.frames[event.frame.sensor] += 1

    def append(self, table: str, text: str) -> None:
        if not text:
            return
        data, fh = text.encode("utf-8"), self.handles[table]
        while data:
            data = data[fh.write(data):]
        self.rows[table] += _data_rows(text)

    def close(self) -> None:
        """Remove every temporary file still staged, close the tables."""
        for tmp in self.staged.values():
            tmp.unlink(missing_ok=True)
        self.staged.clear()
        for fh in self.handles.values():
            fh.close()
        self.handles.clear()

    def _dest(self, frame: ReplayFrame) -> Path:
        return self.to_dir / frame.sensor / frame.source.name


def _data_rows(text: str) -> int:
    return sum(1 for ln in text.splitlines() if ln.strip() and not ln.startswith("#"))


def _check_options(speed: float, start_delay_s: float, table_lead_s: float) -> None:
    if not (isinstance(speed, (int, float)) and math.isfinite(speed) and speed >= 0.0):
        raise ShipstarError(f"speed must be a finite number > 0 (or {FAST_SPEED:g}: as fast as possible), "
                            f"got {speed!r}")
    if not (math.isfinite(start_delay_s) and start_delay_s >= 0.0):
        raise ShipstarError(f"start_delay_s must be finite and >= 0, got {start_delay_s!r}")
    if not (math.isfinite(table_lead_s) and table_lead_s >= 0.0):
        raise ShipstarError(f"table_lead_s must be finite and >= 0, got {table_lead_s!r}")


class _Lateness:
    """Frames' lateness against their due times."""

    def __init__(self):
        self.count = 0
        self.max_s = 0.0

    def add(self, late_s: float) -> None:
        self.max_s = max(self.max_s, late_s)
        if late_s * 1000.0 > LATE_THRESHOLD_MS:
            self.count += 1


def _run_groups(groups: list, writer: _Writer, start: float, speed: float, stop: _Stop,
                lateness: _Lateness, progress, total: int, on_frame=None) -> bool:
    """Publish every group at its due time (``start`` + due / speed; at speed 0 as soon as
    possible after ``start``), its frames staged before the wait; False if stopped first."""
    done = 0
    for group in groups:
        if stop():
            return False
        for e in group:
            if e.frame is not None:
                writer.stage(e)
        deadline = start + group[0].due_s / speed if speed > FAST_SPEED else start
        if not _sleep_until(deadline, stop):
            return False
        for e in group:
            writer.publish(e)
            if e.frame is not None:
                if on_frame is not None:
                    on_frame(e.frame.sensor, e.frame.source.name, time.monotonic())
                if speed > FAST_SPEED:
                    lateness.add(time.monotonic() - deadline)
                done += 1
                if progress is not None:
                    progress(done, total)
    return True


def replay(plan: ReplayPlan, to_dir, *, speed: float = 1.0, start_delay_s: float = DEFAULT_START_DELAY_S,
           table_lead_s: float = DEFAULT_TABLE_LEAD_S, progress=None, stop_event: threading.Event | None = None,
           handle_signals: bool = True, on_frame=None) -> ReplayResult:
    """Write a plan's frames and tables into ``to_dir`` at the session's time spacing.

    Parameters
    ----------
    plan : ReplayPlan
        From :func:`plan_replay`.
    to_dir : str or Path
        New or empty directory; ``to_dir/<sensor>/`` and the tables are created in it.
    speed : float
        Session seconds per wall second (2: twice as fast); 0 (:data:`FAST_SPEED`): as
        fast as possible, no schedule.
    start_delay_s : float
        Wall time between creating the directories (and the tables' start) and the first
        frame: time for a reader to start watching.
    table_lead_s : float
        A table row is appended when the replay clock reaches its time minus this
        (session seconds).
    progress : callable(done, total), optional
        Called after each frame.
    stop_event : threading.Event, optional
        Set it (from another thread) to stop cleanly (``stopped = "requested"``).
    handle_signals : bool
        Handle SIGINT / SIGTERM while running (only from the main thread; the previous
        handlers are restored on return).
    on_frame : callable(sensor, file_name, monotonic_s), optional
        Called as each frame appears under its name (latency measurements).

    Returns
    -------
    ReplayResult
        With ``stopped`` set (and a partial output) when stopped by a signal or
        ``stop_event``.

    Raises
    ------
    ShipstarError
        Bad options, a ``to_dir`` that is not new or empty or cannot be written, a frame
        that cannot be copied (every temporary file is removed first).
    """
    _check_options(speed, start_delay_s, table_lead_s)
    out = check_destination(to_dir)
    starts, groups, ends = _schedule(plan, table_lead_s)
    stop, lateness, writer = _Stop(stop_event), _Lateness(), _Writer(out, plan)
    t_begin = time.monotonic()
    with _signal_handlers(stop, handle_signals):
        try:
            writer.create(plan, starts)
            start = time.monotonic() + start_delay_s
            complete = _run_groups(groups, writer, start, speed, stop, lateness, progress, len(plan.frames),
                                   on_frame)
            if complete:
                for name, text in ends.items():
                    writer.append(name, text)
        finally:
            writer.close()
    return ReplayResult(out, dict(writer.frames), plan.frames_per_sensor(), dict(writer.rows), float(speed),
                        time.monotonic() - t_begin, plan.span_s, lateness.count,
                        None if speed == FAST_SPEED else lateness.max_s * 1000.0,
                        None if complete else stop.reason)
