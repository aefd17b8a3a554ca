"""A flag that cannot act is refused, not ignored (found by a bad-input sweep): each was
accepted with exit 0 and its value never used, or a value no command could use."""

from __future__ import annotations

import numpy as np
import pytest

from _cli import one_line_error as _main  # tests/cli on sys.path


def _refused(args, capsys, *fragments):
    code, line = _main(args, capsys)
    assert code == 2, line
    for text in fragments:
        assert text in line, line


def test_solve_prior_error_without_track(capsys, tmp_path):
    _refused(["solve", str(tmp_path / "x.png"), "--fov-deg", "10", "--prior-error-deg", "2"], capsys,
             "--prior-error-deg bounds the attitude change between --track's inputs: give --track")


@pytest.mark.parametrize("flags", [["--ins-errors", "heading_bias_arcsec=30"],
                                   ["--ins-convention", "roll=starboard-up"], ["--ins-errors", "bogus=1"]])
def test_simulate_session_ins_flags_without_the_log(capsys, tmp_path, flags):
    _refused(["simulate-session", "--kind", "sea", "--out", str(tmp_path / "s"), "--duration-s", "1", *flags],
             capsys, "--ins-errors and --ins-convention describe the INS log: give --ins-log")
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("value", ["-8", "0", "180"])
def test_error_model_field_of_view_out_of_range(capsys, tmp_path, value):
    _refused(["error-model", "--fov-deg", value, "--out", str(tmp_path / "em")], capsys,
             f"--fov-deg must be within (0, 180) deg, got {float(value):g}")
    assert not (tmp_path / "em").exists()


@pytest.mark.parametrize("command", ["measure", "live"])
def test_relative_humidity_beside_a_weather_table(capsys, tmp_path, command):
    """The table's humidity was used and the flag's dropped without a word."""
    weather = tmp_path / "weather.csv"
    weather.write_text("time_utc,pressure_hpa,temperature_c\n2013-03-15T12:00:00Z,1021.7,11.1\n")
    (tmp_path / "A1").mkdir()
    from shipstar.calibrate.installation import Installation, save_installation

    save_installation(Installation.from_matrix("A1", "A1", np.eye(3)), tmp_path / "A1.toml")
    _refused([command, "--sensor", f"A1={tmp_path / 'A1'}", "--install", str(tmp_path / "A1.toml"),
              "--lat-deg", "31.9", "--lon-deg", "120.3", "--weather", str(weather), "--relative-humidity", "0.5",
              "--out", str(tmp_path / "o.csv")], capsys,
             "--relative-humidity goes with --pressure-hpa/--temperature-c: the --weather table gives its own")
    assert not list(tmp_path.glob("o.csv*"))


def test_calibrate_intrinsics_empty_terms(capsys, tmp_path):
    """--terms "" was taken as none (an unset variable in a script fits no distortion)."""
    _refused(["calibrate", "intrinsics", "--frames", str(tmp_path), "--camera", "A1", "--terms", "",
              "--out", str(tmp_path / "c.toml")], capsys, "--terms is empty: give auto, all, none or a list")


def test_error_model_out_that_is_a_file(capsys, tmp_path):
    """Said "cannot write --out afile: already exists" (a bad-input sweep)."""
    (tmp_path / "afile").write_text("x")
    _refused(["error-model", "--out", str(tmp_path / "afile")], capsys,
             f"--out {tmp_path / 'afile'} exists and is not a directory")
    assert (tmp_path / "afile").read_text() == "x"
