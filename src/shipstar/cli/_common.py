"""Helpers shared by the sub-commands: argument types that validate at the edge, output
paths checked before any work, the accuracy warnings of a run, JSON out."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from shipstar._atomic import atomic_write_text  # noqa: F401  (re-exported for commands)
from shipstar.errors import ShipstarError

__all__ = ["finite_float", "latitude_deg", "longitude_deg", "deflection_arcsec", "fraction", "positive_float",
           "emit_json", "atomic_write_text", "check_output_file", "check_output_dir", "accuracy_warnings",
           "one_line"]


def finite_float(text: str) -> float:
    """argparse type: a finite float (rejects NaN and inf with a one-line message)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return value


def latitude_deg(text: str) -> float:
    """argparse type: latitude in degrees within [-90, 90]."""
    value = finite_float(text)
    if not -90.0 <= value <= 90.0:
        raise argparse.ArgumentTypeError(f"latitude must be within [-90, 90] deg, got {value}")
    return value


def longitude_deg(text: str) -> float:
    """argparse type: longitude in degrees within [-180, 360] (east positive, or 0-360)."""
    from shipstar.sky.apparent import LON_RANGE_DEG

    value = finite_float(text)
    lo, hi = LON_RANGE_DEG
    if not lo <= value <= hi:
        raise argparse.ArgumentTypeError(f"longitude must be within [{lo:g}, {hi:g}] deg, got {value}")
    return value


def deflection_arcsec(text: str) -> float:
    """argparse type: a deflection of the vertical component (arcsec) within +-120."""
    from shipstar.sky.apparent import MAX_DEFLECTION_ARCSEC

    value = finite_float(text)
    if abs(value) > MAX_DEFLECTION_ARCSEC:
        raise argparse.ArgumentTypeError(f"must be within +-{MAX_DEFLECTION_ARCSEC:g} arcsec, got {value}")
    return value


def fraction(text: str) -> float:
    """argparse type: a number within [0, 1] (e.g. relative humidity)."""
    value = finite_float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be within [0, 1], got {value}")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    value = finite_float(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value}")
    return value


def emit_json(obj, stream=None) -> None:
    """Print one JSON object (NaN is refused: it is not JSON)."""
    stream = sys.stdout if stream is None else stream
    try:
        text = json.dumps(obj, allow_nan=False)
    except ValueError as exc:
        raise ShipstarError(f"result is not finite, refusing to print it as JSON: {exc}") from None
    stream.write(text + "\n")


# ---------------------------------------------------------------------------------------
# Output paths: checked before processing, so that a bad path never costs a whole run
# ---------------------------------------------------------------------------------------

def _writable_ancestor(path: Path, flag: str, shown: Path) -> None:
    """The nearest existing ancestor of ``path`` must be a directory we may write in."""
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    p = p if p.exists() else Path(".")
    if not p.is_dir():
        raise ShipstarError(f"{flag} {shown}: {p} is a file, not a directory")
    if not os.access(p, os.W_OK | os.X_OK):
        raise ShipstarError(f"{flag} {shown}: no permission to write in {p}")


def check_output_file(path, flag: str) -> Path:
    """Refuse (ShipstarError) an output file path that cannot be written.

    The path must not be a directory, and its nearest existing parent must be a
    directory we may write in (missing directories are created when writing).
    """
    p = Path(path)
    if str(path).strip() == "" or p.name in ("", ".", ".."):
        raise ShipstarError(f"{flag} {str(path)!r} is not a file name")
    if p.is_dir():
        raise ShipstarError(f"{flag} {p} is a directory, expected a file name")
    _writable_ancestor(p.parent, flag, p)
    return p


def check_output_dir(path, flag: str, files=()) -> Path:
    """Refuse (ShipstarError) an output directory that cannot be created or written, or
    in which one of ``files`` (names) could not be written."""
    p = Path(path)
    if str(path).strip() == "":
        raise ShipstarError(f"{flag} needs a directory name")
    if p.exists() and not p.is_dir():
        raise ShipstarError(f"{flag} {p} exists and is not a directory")
    _writable_ancestor(p, flag, p)
    for name in files:
        check_output_file(p / name, flag)
    return p


# ---------------------------------------------------------------------------------------
# Warnings
# ---------------------------------------------------------------------------------------

def one_line(text) -> str:
    """A message on one line (runs of white space, newlines included, become one space)."""
    return " ".join(str(text).split())


def accuracy_warnings(args) -> list:
    """Distinct one-line messages of the :class:`~shipstar.errors.AccuracyWarning` s raised
    so far in this command (``shipstar.cli.main`` records them in ``args.caught_warnings``;
    empty when the command runs without it)."""
    from shipstar.errors import AccuracyWarning

    caught = getattr(args, "caught_warnings", None) or []
    return list(dict.fromkeys(one_line(w.message) for w in caught if issubclass(w.category, AccuracyWarning)))
