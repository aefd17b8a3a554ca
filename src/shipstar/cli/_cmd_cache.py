"""``shipstar cache info|clear``: the on-disk cache of star databases and catalogs."""

from __future__ import annotations

import argparse

from shipstar.cli._common import emit_json, float_in_range

EPILOG = """\
examples:
  shipstar cache info
  shipstar cache info --json
  shipstar cache clear --older-than-days 30
  shipstar cache clear

The cache (SHIPSTAR_CACHE_DIR, default ~/.cache/shipstar) holds the star databases of
'shipstar solve' and the pipeline (identify/stardb_*: one per camera and one per
field-of-view band of uncalibrated images), the parsed Hipparcos / navigation
catalogs (hip2_*, nav_*, hipmag_*) and Earth orientation tables (eop_*, the three most
recent).  Everything in it is rebuilt on demand.  It is kept within
400 MB and 48 files (SHIPSTAR_CACHE_MAX_MB, SHIPSTAR_CACHE_MAX_FILES): after a new
database is written, the least recently used files are removed.

info lists each file: kind, size, last use (UTC) and what it holds; --json prints one
object {"cache_dir", "total_bytes", "files": [{"path", "kind", "size_bytes",
"last_use_utc", "label"}]}.  clear removes every cache file, or with --older-than-days
N those not used for N days, and says how many bytes it freed.
"""

_days = float_in_range(0.0, None, ">= 0")


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "cache", help="list or clear the star database / catalog cache",
        description="The cache of star databases and parsed catalogs (rebuilt on demand).",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cache_command", metavar="ACTION")
    info = sub.add_parser("info", help="list the cache files: size, last use, contents",
                          epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    info.add_argument("--json", action="store_true", help="print one JSON object")
    info.set_defaults(run=run_info)
    clear = sub.add_parser("clear", help="remove cache files (all, or unused for N days)",
                           epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    clear.add_argument("--older-than-days", type=_days, default=None, metavar="N",
                       help="remove only files not used for N days")
    clear.add_argument("--json", action="store_true", help="print one JSON object")
    clear.set_defaults(run=run_clear)
    p.set_defaults(run=lambda args: (p.print_help(), 2)[1])
    return p


def _utc(t: float) -> str:
    import time

    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def _entry(f) -> dict:
    return {"path": str(f.path), "kind": f.kind, "size_bytes": int(f.size_bytes),
            "last_use_utc": _utc(f.last_use_unix_s), "label": f.label}


def _check_usable() -> None:
    """A cache directory that cannot be used is an error here (the other commands run
    without caches, slower and silent): its listing would say "0 files"."""
    from shipstar.errors import ShipstarError
    from shipstar.sky.catalog import cache_dir, cache_dir_problem

    problem = cache_dir_problem()
    if problem:
        raise ShipstarError(f"the cache directory {cache_dir()} cannot be used ({problem}): every command runs "
                            f"without caches; set SHIPSTAR_CACHE_DIR to a directory that can be written")


def run_info(args) -> int:
    from shipstar.identify._database import cache_files
    from shipstar.sky.catalog import cache_dir

    _check_usable()
    files = cache_files()
    total = sum(f.size_bytes for f in files)
    if args.json:
        emit_json({"cache_dir": str(cache_dir()), "total_bytes": int(total),
                   "files": [_entry(f) for f in files]})
        return 0
    print(f"cache {cache_dir()}: {len(files)} files, {_mb(total)}")
    for f in files:
        print(f"  {f.kind:<13} {_mb(f.size_bytes):>9}  last use {_utc(f.last_use_unix_s)}  "
              f"{f.path.name}  {f.label}")
    return 0


def run_clear(args) -> int:
    from shipstar.identify._database import clear_cache
    from shipstar.sky.catalog import cache_dir

    _check_usable()
    removed = clear_cache(args.older_than_days)
    freed = sum(f.size_bytes for f in removed)
    if args.json:
        emit_json({"cache_dir": str(cache_dir()), "removed": [_entry(f) for f in removed],
                   "freed_bytes": int(freed)})
    else:
        what = "" if args.older_than_days is None else f" unused for {args.older_than_days:g} days"
        print(f"removed {len(removed)} cache files{what} from {cache_dir()}, freed {_mb(freed)}")
    return 0
