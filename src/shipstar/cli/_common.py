"""Helpers shared by the sub-commands: argument types that validate at the edge, JSON out."""

from __future__ import annotations

import argparse
import json
import math
import sys

from shipstar.errors import ShipstarError

__all__ = ["finite_float", "latitude_deg", "fraction", "positive_float", "emit_json", "atomic_write_text"]


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


def atomic_write_text(path, text: str) -> None:
    """Write a text file so that a crash never leaves a half-written file that looks complete."""
    import os
    import tempfile
    from pathlib import Path

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
