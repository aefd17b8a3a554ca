"""``--trust-flags`` and the header cross-checks of the commands that read frames.

The checks themselves are :class:`shipstar.pipeline._header_check.HeaderCheck`
(docs/file-formats.md, "Header cross-checks"); this module adds the flag, builds a
check from a command's arguments and records an override in the outputs.
"""

from __future__ import annotations

import sys

__all__ = ["add_trust_flags_argument", "header_check", "override_record", "print_overrides", "check_fits_dir"]

TRUST_HELP = ("use the position, weather, sensor and camera given even where the frames' FITS headers "
              "(SITELAT/SITELONG, PRESSURE/TEMPERAT, SENSOR/INSTRUME) contradict them; the override is "
              "recorded in the outputs (docs/file-formats.md, Header cross-checks)")


def add_trust_flags_argument(parser) -> None:
    """Add ``--trust-flags``."""
    parser.add_argument("--trust-flags", action="store_true", help=TRUST_HELP)


def header_check(args, *, names=(), given_name: str = "", camera=None, track=None, weather=None,
                 position_flags: bool = False, weather_flags: bool = False, sensor: str = "", known_cameras=()):
    """A :class:`HeaderCheck` with the command's ``--trust-flags``."""
    from shipstar.pipeline._header_check import HeaderCheck

    return HeaderCheck(names=names, given_name=given_name, camera=camera, track=track, weather=weather,
                       position_flags=position_flags, weather_flags=weather_flags,
                       trust_flags=bool(getattr(args, "trust_flags", False)), sensor=sensor,
                       known_cameras=known_cameras)


def override_record(checks) -> dict:
    """``{"trust_flags": True, "header_overrides": [...]}`` when ``--trust-flags`` was
    given (the contradictions overridden, one per card and sensor; possibly none),
    ``{}`` otherwise: the keys a command adds to its JSON output."""
    checks = [c for c in checks if c is not None]
    if not any(c.trust_flags for c in checks):
        return {}
    return {"trust_flags": True, "header_overrides": [o for c in checks for o in c.overrides()]}


def print_overrides(command: str, record: dict) -> None:
    """One stderr line per contradiction overridden by ``--trust-flags``."""
    from shipstar.pipeline._header_check import override_lines

    for line in override_lines(record.get("header_overrides", [])):
        print(f"shipstar {command}: --trust-flags: {line}", file=sys.stderr)


def check_fits_dir(directory, check, date_obs_is: str) -> None:
    """Run ``check`` on the header of every FITS frame of a directory (frames whose
    header cannot be read are left to the command's reader, which says why)."""
    from pathlib import Path

    from shipstar._fitsio import is_fits_name, read_fits_header
    from shipstar.errors import ShipstarError
    from shipstar.pipeline._frames import in_name_order

    root = Path(directory)
    if not root.is_dir():
        return
    for path in in_name_order(p for p in root.iterdir() if p.is_file() and is_fits_name(p.name)):
        try:
            info = read_fits_header(path, date_obs_is=date_obs_is)
        except ShipstarError:
            continue
        check(info)
