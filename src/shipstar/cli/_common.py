"""Helpers shared by the sub-commands: argument types that validate at the edge, JSON out."""

from __future__ import annotations

import argparse
import json
import math
import sys

from shipstar._atomic import atomic_write_text  # noqa: F401  (re-exported for commands)
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
