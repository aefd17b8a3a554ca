"""Exceptions shipstar raises for bad input.

Every error a user can cause is a :class:`ShipstarError` (a ``ValueError``) whose
message is one self-contained line: the CLI prints it and exits non-zero, without a
traceback.  Library callers can catch it like any ``ValueError``.
"""

from __future__ import annotations

__all__ = ["ShipstarError", "AccuracyWarning"]


class ShipstarError(ValueError):
    """Bad input or an impossible request; the message is one line for a person."""


class AccuracyWarning(UserWarning):
    """A result was produced, but with a stated, larger-than-nominal error.

    Example: Earth orientation extrapolated past the end of the IERS tables.
    """
