"""Integrity monitoring in ``shipstar measure`` (issue 13 item 4): the sensors checked
against each other every epoch, swapped frame folders refused, exit 1 with the counts."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from shipstar.calibrate.installation import Installation, load_installation, save_installation
from shipstar.units import ASEC2RAD


def _run(args, cwd):
    return subprocess.run([sys.executable, "-m", "shipstar", "measure", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=600)


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A rendered 1 s sea session (A2 30 ms late), true installations, A2's off by 20'' in
    azimuth, and a copy of the frames without SENSOR/INSTRUME headers."""
    from astropy.io import fits

    from shipstar.simulate._session import sea_session, write_session

    root = tmp_path_factory.mktemp("integrity")
    spec = sea_session(duration_s=1.0)
    spec = spec.replace(sensors=(spec.sensors[0], replace(spec.sensors[1], time_offset_s=0.03)))
    write_session(spec, root / "sea")
    for s in spec.sensors:
        save_installation(Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor),
                          root / f"{s.name}.toml")
    a2 = load_installation(root / "A2.toml")
    save_installation(replace(a2, az_rad=a2.az_rad + 20.0 * ASEC2RAD), root / "A2_off20.toml")
    for s in ("A1", "A2"):
        (root / "nohdr" / s).mkdir(parents=True)
        for p in sorted((root / "sea" / s).glob("*.fits")):
            with fits.open(p) as hdul:
                for key in ("SENSOR", "INSTRUME"):
                    hdul[0].header.remove(key, ignore_missing=True, remove_all=True)
                hdul.writeto(root / "nohdr" / s / p.name)
    return root


TABLES = ["--track", "sea/track.csv", "--weather", "sea/weather.csv", "--workers", "1"]


def test_consistent_session_is_checked_and_ok(session):
    proc = _run(["--sensor", "A1=sea/A1", "--sensor", "A2=sea/A2", "--install", "A1.toml", "A2.toml", *TABLES,
                 "--out", "ok.csv", "--json"], session)
    assert proc.returncode == 0, proc.stderr
    integ = json.loads(proc.stdout)["integrity"]
    assert integ["n_checked"] == 8 and integ["n_inconsistent"] == 0
    assert integ["max_chi2"] < integ["chi2_limit"] == pytest.approx(30.66, abs=0.01)
    fused = [r for r in _rows(session / "ok.csv") if r["method"] == "joint" and r["solved"] == "1"]
    assert len(fused) == 8 and {r["integrity"] for r in fused} == {"ok"}
    assert all(r["suspect_sensor"] == "" and float(r["integrity_chi2"]) >= 0 for r in fused)
    singles = [r for r in _rows(session / "ok.csv") if r["method"] == "single"]
    assert {r["integrity"] for r in singles} == {""}


def test_installation_off_by_20_arcsec_marks_epochs_and_names_the_sensor(session):
    proc = _run(["--sensor", "A1=sea/A1", "--sensor", "A2=sea/A2", "--install", "A1.toml", "A2_off20.toml",
                 *TABLES, "--out", "off.csv", "--json"], session)
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert "8 of 8 epochs inconsistent" in lines[0] and "the sensor that does not fit" in lines[0], lines[0]
    summary = json.loads(proc.stdout)
    # two sensors: the disagreement says that one is wrong, not which (docs/pipeline.md, *Which
    # sensor*); every inconsistent epoch names one of them, and the line counts them
    suspects = summary["integrity"]["suspects"]
    assert summary["complete"] is True and set(suspects) <= {"A1", "A2"} and sum(suspects.values()) == 8
    assert all(f"{k} in {v}" in lines[0] for k, v in suspects.items()), lines[0]
    rows = _rows(session / "off.csv")                           # the complete output is still written
    fused = [r for r in rows if r["method"] in ("joint", "seed-rule") and r["solved"] == "1"]
    assert len(fused) == 16
    assert {r["integrity"] for r in fused} == {"inconsistent"} and {r["suspect_sensor"] for r in fused} <= {"A1", "A2"}
    assert all(float(r["integrity_chi2"]) > 30.66 for r in fused)


def test_swapped_folders_are_refused_naming_them(session):
    proc = _run(["--sensor", "A1=nohdr/A2", "--sensor", "A2=nohdr/A1", "--install", "A1.toml", "A2.toml",
                 *TABLES, "--out", "swapped.csv"], session)
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert "sensor folders look swapped: A1's frames fit A2's installation" in lines[0], lines[0]
    assert not (session / "swapped.csv").exists() and not (session / "swapped.csv.partial").exists()
    # the same folders the right way round (no SENSOR header either) pass the check
    proc = _run(["--sensor", "A1=nohdr/A1", "--sensor", "A2=nohdr/A2", "--install", "A1.toml", "A2.toml",
                 *TABLES, "--out", "unswapped.csv"], session)
    assert proc.returncode == 0, proc.stderr


def test_an_unsolved_row_exits_1_with_the_counts(session, tmp_path):
    import shutil

    from astropy.io import fits

    shutil.copytree(session / "sea", tmp_path / "sea")
    for s in ("A1", "A2"):
        shutil.copy(session / f"{s}.toml", tmp_path / f"{s}.toml")
    with fits.open(tmp_path / "sea" / "A1" / "A1_00009.fits") as hdul:      # the last A1 frame: sky noise only
        rng = np.random.default_rng(3)
        hdul[0].data = rng.poisson(110, hdul[0].data.shape).astype(np.uint16)
        hdul.writeto(tmp_path / "sea" / "A1" / "A1_00009.fits", overwrite=True)
    proc = _run(["--sensor", "A1=sea/A1", "--sensor", "A2=sea/A2", "--install", "A1.toml", "A2.toml", *TABLES,
                 "--out", "att.csv"], tmp_path)
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "1 of 20 frames unsolved (1 clouded; first: A1 A1_00009.fits" in lines[0], lines[0]
    assert "1 of 10 epochs without a fused attitude" in lines[0], lines[0]
    assert (tmp_path / "att.csv").exists()
