"""Helpers shared by the command-line tests (tests/cli on sys.path: ``from _cli import ...``)."""

from __future__ import annotations

from shipstar.cli import main

#: A dock's site and weather as flags (seed 000's dock).
DOCK_SITE = ["--lat-deg", "31.9", "--lon-deg", "120.3", "--pressure-hpa", "1021.7", "--temperature-c", "11.1"]


def one_line_error(args, capsys):
    """``(exit code, the one stderr line)`` of ``shipstar ARGS`` run in this process."""
    try:
        code = main(args)
    except SystemExit as exc:                   # argparse's usage errors
        code = exc.code
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return code, lines[0]
