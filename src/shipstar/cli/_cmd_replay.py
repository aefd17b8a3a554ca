"""``shipstar replay``: write a recorded or simulated session's frames into per-sensor
directories at their real time spacing, for ``shipstar live`` (docs/live.md)."""

from __future__ import annotations

import argparse
import sys

from shipstar.cli._common import add_date_obs_is_argument, emit_json, finite_float, float_in_range
from shipstar.errors import ShipstarError

__all__ = ["register", "run", "EXIT_CODES"]

#: Exit codes of a replay stopped by a signal (128 + the signal's number).
EXIT_CODES = {"SIGINT": 130, "SIGTERM": 143}

EPILOG = """\
examples:
  shipstar simulate-session --kind sea --out sea --duration-s 16
  shipstar replay sea --to incoming            # then, elsewhere:
  shipstar live --sensor A1=incoming/A1 --sensor A2=incoming/A2 \\
      --track incoming/track.csv --weather incoming/weather.csv ...
  shipstar replay --sensor A1=night/cam1 --to incoming --speed 2 --json

Each frame (SESSION/<sensor>/*.fits, or each --sensor NAME=DIR) goes to DIR/<sensor>/
under its own name at wall time start + (t_frame - t_first) / speed, t = the frame's
mid-exposure time from its header, all sensors merged in one time order.  A frame is
copied to a hidden temporary name (.<name>.<random>.part) in its final directory ahead
of time and renamed into place (os.replace) at its due time: a reader never sees a
half-written frame under a FITS name.  Frames that appear more than 10 ms late are
counted and reported (a warning on stderr).  --speed 0: as fast as possible (no schedule).

SESSION/track.csv and SESSION/weather.csv (if present; not with --sensor) are replayed as
growing files DIR/track.csv, DIR/weather.csv: the header and the rows before the first
frame at the start, then each row appended when the replay clock reaches its time_utc
minus --table-lead-s, the rows after the last frame right after it.

DIR must be new or empty.  SIGINT / SIGTERM stop cleanly: no temporary file is left, only
whole frames; the output says what was written ("stopped", "partial": true in --json).
Exit code 0: complete; 130: stopped by SIGINT; 143: by SIGTERM; 2: bad input.
"""


def _speed(text: str) -> float:
    """argparse type: a finite speed >= 0 (0: as fast as possible)."""
    value = finite_float(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0 (or 0: as fast as possible), got {value:g}")
    return value


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "replay", help="write a session's frames into per-sensor directories at their real time spacing",
        description="Replay a recorded or simulated session for 'shipstar live': each sensor's FITS frames are "
                    "written into DIR/<sensor>/ at their real time spacing (write, then rename), the track and "
                    "weather tables grow row by row.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("session", nargs="?", metavar="SESSION",
                   help="session directory: one sub-directory of FITS frames per sensor (as simulate-session "
                        "writes), optional track.csv and weather.csv")
    p.add_argument("--sensor", action="append", default=[], metavar="NAME=DIR",
                   help="a sensor's frames directory, instead of SESSION (repeatable)")
    p.add_argument("--to", required=True, metavar="DIR", help="new (or empty) directory to write into")
    p.add_argument("--sensors", help="comma-separated subset of the sensors (default all)")
    p.add_argument("--speed", type=_speed, default=1.0,
                   help="session seconds per wall second (default 1; 0: as fast as possible)")
    p.add_argument("--start-delay-s", type=float_in_range(0.0, 3600.0), default=0.5,
                   help="wait between creating DIR's sub-directories and the first frame (s, default 0.5)")
    p.add_argument("--table-lead-s", type=float_in_range(0.0, 3600.0), default=2.0,
                   help="append a table row this long before its time (session s, default 2)")
    p.add_argument("--no-tables", action="store_true", help="do not replay track.csv and weather.csv")
    add_date_obs_is_argument(p)
    p.add_argument("--progress", action="store_true", help="progress bar on stderr (default: only on a terminal)")
    p.add_argument("--json", action="store_true", help="print one JSON object at the end")
    p.set_defaults(run=run)
    return p


def _wanted(text: str | None) -> list | None:
    if text is None:
        return None
    names = [s.strip() for s in text.split(",") if s.strip()]
    if not names or len(set(names)) != len(names):
        raise ShipstarError(f"--sensors must be a comma-separated list of distinct sensor names, got {text!r}")
    return names


def _pairs(pairs: list) -> dict:
    from pathlib import Path

    from shipstar.live._replay import check_sensor_name

    out = {}
    for item in pairs:
        name, sep, directory = item.partition("=")
        if not sep or not name.strip() or not directory.strip():
            raise ShipstarError(f"--sensor expects NAME=DIR, got {item!r}")
        name = check_sensor_name(name)
        if name in out:
            raise ShipstarError(f"--sensor {name} given twice")
        d = Path(directory)
        if not d.is_dir():
            raise ShipstarError(f"--sensor {name}: frames directory {d} does not exist or is not a directory")
        out[name] = d
    return out


def _sources(args) -> tuple[dict, dict]:
    """``({sensor: frames dir}, {table name: path})`` from SESSION or the --sensor pairs."""
    from shipstar.live._replay import session_sensor_dirs, session_tables

    if (args.session is None) == (not args.sensor):
        raise ShipstarError("give a SESSION directory or --sensor NAME=DIR pairs (one of them, not both)")
    wanted = _wanted(args.sensors)
    if args.session is not None:
        dirs = session_sensor_dirs(args.session, wanted)
        return dirs, ({} if args.no_tables else session_tables(args.session))
    dirs = _pairs(args.sensor)
    if wanted is not None:
        unknown = [w for w in wanted if w not in dirs]
        if unknown:
            raise ShipstarError(f"--sensors {unknown[0]} is not among the --sensor names ({', '.join(dirs)})")
        dirs = {w: dirs[w] for w in wanted}
    return dirs, {}


def _check_apart(args, dirs: dict) -> None:
    """Refuse a ``--to`` inside what is replayed (the SESSION, a sensor's frames): its
    copies would land among the frames being read (found by a bad-input sweep)."""
    from shipstar.cli._common import resolved_path

    to = resolved_path(args.to)
    sources = ([("SESSION", args.session)] if args.session is not None else []) + \
        [(f"--sensor {name}", d) for name, d in dirs.items()]
    for what, src in sources:
        src = resolved_path(src)
        if to == src or src in to.parents:
            raise ShipstarError(f"--to {args.to} is inside {what} {src}, which is being replayed: give a directory "
                                f"outside it")


def _summary_text(result) -> str:
    counts = ", ".join(f"{n} {c}" for n, c in result.frames_by_sensor.items())
    rows = ", ".join(f"{n} {c}" for n, c in result.table_rows.items())
    tables = f" and {sum(result.table_rows.values())} table rows ({rows})" if result.table_rows else ""
    speed = "as fast as possible" if result.speed == 0 else f"at speed {result.speed:g}"
    late = "" if result.max_late_ms is None else (f"; {result.late_frames} late frames, "
                                                   f"max lateness {result.max_late_ms:.1f} ms")
    head = (f"replay stopped by {result.stopped} (partial): wrote {result.frames_written} of "
            f"{result.frames_planned} frames" if result.partial else f"replayed {result.frames_written} frames")
    return f"{head} ({counts}){tables} into {result.to_dir} in {result.duration_s:.2f} s {speed}{late}"


def run(args) -> int:
    from shipstar.live._replay import LATE_THRESHOLD_MS, check_destination, plan_replay, replay
    from shipstar.pipeline._progress import ProgressBar

    dirs, tables = _sources(args)
    check_destination(args.to)
    _check_apart(args, dirs)
    plan = plan_replay(dirs, tables, date_obs_is=args.date_obs_is)
    bar = ProgressBar(True if args.progress else None)
    try:
        result = replay(plan, args.to, speed=args.speed, start_delay_s=args.start_delay_s,
                        table_lead_s=args.table_lead_s, progress=lambda done, total: bar("frames", done, total))
    finally:
        bar.close()
    if args.json:
        emit_json(result.to_dict())
    else:
        print(_summary_text(result))
    if result.late_frames:
        print(f"shipstar replay: warning: {result.late_frames} of {result.frames_written} frames appeared more "
              f"than {LATE_THRESHOLD_MS:g} ms after their due time (at most {result.max_late_ms:.1f} ms late): "
              "the disk or the machine did not keep up with --speed", file=sys.stderr)
    return EXIT_CODES.get(result.stopped, 0) if result.partial else 0
