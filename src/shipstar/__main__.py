"""``python -m shipstar`` runs the command line."""

from shipstar.cli import _entry

_entry()
