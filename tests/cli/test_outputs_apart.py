"""An output never overwrites what the command reads, nor another of its outputs
(``shipstar.cli._common.check_outputs_apart``): refused in one line, exit code 2, before
any work, the input left as it was.

A bad-input sweep found ``measure --out sea/track.csv --track sea/track.csv`` replacing the
track with the attitude CSV, ``calibrate install --out dock/A1/A1_00004.fits`` replacing a
frame with TOML (every later run on that folder failing), and ``--out X --monitor X`` losing
one of the two, all with exit code 0; ``solve`` alone checked its outputs against its input.
"""

from __future__ import annotations

import argparse

import pytest

from shipstar.cli import main
from shipstar.cli._common import check_outputs_apart
from shipstar.errors import ShipstarError

from _cli import DOCK_SITE, one_line_error as _main  # tests/cli on sys.path; the dock fixture: conftest.py


@pytest.fixture(autouse=True)
def _weather(dock):
    """A weather table beside the dock frames (an input the outputs are kept apart from)."""
    (dock / "dock" / "weather.csv").write_text("time_utc,pressure_hpa,temperature_c\n"
                                               "2013-03-15T12:00:00,1021.7,11.1\n2013-03-15T13:00:00,1021.7,11.1\n")


def _snapshot(root):
    return {p: p.read_bytes() for p in root.rglob("*") if p.is_file()}


MEASURE = ["measure", "--workers", "1", "--sensor", "A1=dock/A1", "--install", "A1.toml",
           "--lat-deg", "31.9", "--lon-deg", "120.3", "--weather", "dock/weather.csv"]


@pytest.mark.parametrize("args, message", [
    (["--out", "dock/weather.csv"], "--out dock/weather.csv is the --weather input: refusing to overwrite it"),
    (["--out", "A1.toml"], "--out A1.toml is the --install input: refusing to overwrite it"),
    (["--out", "./dock/../A1.toml"], "--out ./dock/../A1.toml is the --install input A1.toml: refusing to "
                                     "overwrite it"),
    (["--out", "dock/A1/A1_00001.fits"], "--out dock/A1/A1_00001.fits is a frame of the --sensor folder dock/A1: "
                                         "refusing to overwrite it"),
    (["--out", "dock/A1/new.fits"], "--out dock/A1/new.fits would be a frame of the --sensor folder dock/A1"),
    (["--out", "x.csv", "--monitor", "x.csv"], "--out and --monitor are the same file x.csv: give each its own"),
    (["--out", "p.csv", "--plots", "p.csv"], "--out p.csv is the --plots folder: give each its own"),
    (["--out", "r/attitude.png", "--plots", "r"], "--out and --plots are the same file r/attitude.png"),
])
def test_measure_refuses_an_output_over_an_input_or_another_output(dock, capsys, monkeypatch, args, message):
    monkeypatch.chdir(dock)
    before = _snapshot(dock)
    code, line = _main([*MEASURE, *args], capsys)
    assert code == 2 and message in line, line
    assert _snapshot(dock) == before                        # nothing written, nothing replaced


def test_outputs_beside_the_inputs_are_still_written(dock, capsys, monkeypatch):
    """The usual layouts: the CSV in the plots folder, an output with a name that is not a
    frame's in a frames folder."""
    monkeypatch.chdir(dock)
    assert main([*MEASURE, "--out", "res/a.csv", "--plots", "res"]) == 0
    assert {p.name for p in (dock / "res").iterdir()} == {"a.csv", "attitude.png", "residuals.png"}
    assert main([*MEASURE, "--out", "dock/A1/attitude.csv"]) == 0
    capsys.readouterr()


def test_calibrate_install_refuses_to_write_over_a_frame(dock, capsys, monkeypatch):
    monkeypatch.chdir(dock)
    frame = dock / "dock" / "A1" / "A1_00001.fits"
    before = frame.read_bytes()
    code, line = _main(["calibrate", "install", "--frames", "dock/A1", "--sensor", "A1", "--camera", "A1",
                        "--heading-deg", "46.474586", *DOCK_SITE, "--out", "dock/A1/A1_00001.fits"], capsys)
    assert code == 2 and line.endswith("--out dock/A1/A1_00001.fits is a frame of the --frames folder dock/A1: "
                                       "refusing to overwrite it"), line
    assert frame.read_bytes() == before


def test_calibrate_intrinsics_refuses_its_plot_on_its_out(dock, capsys, monkeypatch):
    monkeypatch.chdir(dock)
    code, line = _main(["calibrate", "intrinsics", "--frames", "dock/A1", "--camera", "A1", *DOCK_SITE,
                        "--out", "cam.png", "--plot", "cam.png"], capsys)
    assert code == 2 and "--out and --plot are the same file cam.png" in line, line
    assert not (dock / "cam.png").exists()


def test_solve_refuses_its_two_wcs_outputs_on_one_file(dock, capsys, monkeypatch):
    monkeypatch.chdir(dock)
    code, line = _main(["solve", "dock/A1/A1_00001.fits", "--camera", "A1", "--wcs-out", "w.fits",
                        "--wcs-header", "w.fits"], capsys)
    assert code == 2 and "--wcs-out and --wcs-header are the same file w.fits" in line, line
    code, line = _main(["solve", "dock/A1/A1_00001.fits", "--camera", "A1", "--wcs-header",
                        "dock/A1/A1_00001.fits"], capsys)
    assert code == 2 and "--wcs-header dock/A1/A1_00001.fits is the input: refusing to overwrite it" in line, line


def test_the_check_reads_pairs_lists_and_ignores_flags_that_are_not_paths(tmp_path):
    (tmp_path / "cam.toml").write_text("x")
    (tmp_path / "frames").mkdir()
    args = argparse.Namespace(camera=[("A1", str(tmp_path / "cam.toml"))], sensor=[("A1", str(tmp_path / "frames"))],
                              track=True, install=None, inputs=[])
    with pytest.raises(ShipstarError, match="is the --camera input"):
        check_outputs_apart(args, [("--out", tmp_path / "cam.toml", None)])
    with pytest.raises(ShipstarError, match="would be a frame of the --sensor folder"):
        check_outputs_apart(args, [("--out", tmp_path / "frames" / "x.FITS.gz", None)])
    check_outputs_apart(args, [("--out", tmp_path / "frames" / ".x.fits", None),      # hidden: not a frame
                               ("--out", tmp_path / "o.csv", None), ("--plots", None, ("a.png",))])


@pytest.mark.parametrize("command", [
    ["measure", "--workers", "1", "--out", "o.csv"],
    ["measure-archive", "--workers", "1", "--out", "o.csv"],
    ["live", "--out", "o.csv"],
])
def test_two_sensors_reading_one_folder_are_refused(dock, capsys, monkeypatch, command):
    """Frames without a SENSOR card went through as both sensors' (a bad-input sweep: live
    with two sensors watching one folder)."""
    monkeypatch.chdir(dock)
    (dock / "A2.toml").write_text((dock / "A1.toml").read_text().replace('sensor = "A1"', 'sensor = "A2"'))
    code, line = _main([command[0], "--sensor", "A1=dock/A1", "--sensor", "A2=./dock/A1/", "--install", "A1.toml",
                        "A2.toml", *DOCK_SITE, *command[1:]], capsys)
    assert code == 2 and line.endswith("--sensor A1 and --sensor A2 read the same folder ./dock/A1/: each sensor "
                                       "needs its own"), line
    assert not list(dock.glob("o.csv*"))
