"""``shipstar calibrate install`` on frames of a moving ship: refused, not averaged.

The installation calibration refers every frame to the one dock attitude given; on the
sea session's frames (the ship rolling by degrees) it wrote az 183.725 / el 37.746 / roll
-2.548 deg against the true 185.109 / 39.373 / -0.226, std_az 3004'', exit 0, no warning.
Now: one line naming the scatter and the expected, exit 2, nothing written; with
``--trust-flags`` written with that line in its warnings.  Dock frames: as before.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import pytest

from shipstar.calibrate.installation import load_installation
from shipstar.simulate._session import SEED_A1_INSTALL_DEG, SEED_DOCK_HEADING_DEG

COMMON = ["--lat-deg", "31.9", "--lon-deg", "120.3", "--heading-deg", repr(SEED_DOCK_HEADING_DEG),
          "--pressure-hpa", "1021.7", "--temperature-c", "11.1", "--sensor", "A1", "--camera", "A1"]


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """A 0.3 s sea session (3 frames a sensor, the ship rolling) and a 0.3 s dock session."""
    from shipstar.simulate._session import dock_session, sea_session, write_session

    base = tmp_path_factory.mktemp("install_moving")
    write_session(sea_session(duration_s=0.3), base / "sea")
    write_session(dock_session(duration_s=0.3), base / "dock")
    return base


def _run(root, *args):
    env = dict(os.environ)
    return subprocess.run([sys.executable, "-m", "shipstar", "calibrate", "install", *args], cwd=root, env=env,
                          capture_output=True, text=True, timeout=600)


def test_sea_frames_are_refused_in_one_line(root):
    proc = _run(root, "--frames", "sea/A1", *COMMON, "--out", "sea.toml")
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    line = lines[0]
    assert line.startswith("shipstar calibrate install: error: sensor A1: the ship moved during the calibration "
                           "frames: their installation scatters "), line
    assert "expected of a still ship" in line and "rms of 3 frames" in line and "use --trust-flags" in line
    assert not (root / "sea.toml").exists()


def test_sea_frames_with_trust_flags_are_written_with_the_warning_recorded(root):
    proc = _run(root, "--frames", "sea/A1", *COMMON, "--trust-flags", "--out", "sea_trusted.toml", "--json")
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    (w,) = [w for w in rep["warnings"] if "the ship moved" in w]
    assert "written anyway" in w
    inst = load_installation(root / "sea_trusted.toml")
    assert w in inst.warnings and inst.trust_flags is True
    assert any("the ship moved" in ln for ln in proc.stderr.splitlines())


def test_dock_frames_are_unchanged(root):
    proc = _run(root, "--frames", "dock/A1", *COMMON, "--out", "dock.toml", "--json")
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["n_used"] == rep["n_frames"] == 3 and rep["warnings"] == []
    assert "the ship moved" not in proc.stderr
    true_az, true_el, true_roll = SEED_A1_INSTALL_DEG
    assert abs(rep["az_deg"] - true_az) * 3600 * math.cos(math.radians(true_el)) < 1.0
    assert abs(rep["el_deg"] - true_el) * 3600 < 1.0
    assert abs(rep["roll_deg"] - true_roll) * 3600 < 5.0
