"""``shipstar demo`` run as a subprocess: the quick run end to end, --write-config, bad input."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import pytest

from shipstar.simulate._session import SEED_A1_INSTALL_DEG, SEED_A2_INSTALL_DEG


def _run(args, cwd, timeout=600):
    return subprocess.run([sys.executable, "-m", "shipstar", "demo", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout)


def _assert_bad_input(proc, *fragments, prefix="shipstar demo: error:"):
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert lines[0].startswith(prefix), lines[0]
    for text in fragments:
        assert text in lines[0], lines[0]
    assert proc.stdout == ""


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    cwd = tmp_path_factory.mktemp("demo")
    proc = _run(["--quick", "--out", "out", "--json", "--progress"], cwd)
    return cwd, proc


def test_quick_run_json_and_files(quick_run):
    cwd, proc = quick_run
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)                            # exactly one JSON object
    assert out["quick"] is True
    assert sorted(p.name for p in cwd.iterdir()) == ["out"]  # nothing dropped into the working directory
    files = sorted(p.relative_to(cwd / "out").as_posix() for p in (cwd / "out").rglob("*") if p.is_file())
    assert files == ["config-used/cameras/A1.toml", "config-used/cameras/A2.toml", "config-used/dock.toml",
                     "config-used/sea.toml", "config-used/ship.toml", "config-used/site.toml",
                     "dock/A1.installation.toml", "dock/A2.installation.toml", "report.html", "results.json",
                     "sea/track.csv", "sea/truth.csv", "sea/weather.csv"]
    assert json.loads((cwd / "out" / "results.json").read_text()) == out
    assert "dock calibration (frames): done" in proc.stderr  # progress goes to stderr


def test_quick_run_installation_against_truth(quick_run):
    """The calibrated installation is the simulated truth (seed 000 Tables 2-3) to within
    a few per-frame standard deviations, far inside the seed's own scatter."""
    _, proc = quick_run
    dock = json.loads(proc.stdout)["dock"]["sensors"]
    for name, true in (("A1", SEED_A1_INSTALL_DEG), ("A2", SEED_A2_INSTALL_DEG)):
        s = dock[name]
        assert s["n_solved"] == s["n_frames"] == 20 and s["n_image_level"] == 20
        assert [s["true_deg"][k] for k in ("az", "el", "roll")] == pytest.approx(true, abs=1e-9)
        for k in ("az", "el", "roll"):
            assert abs(s["bias_arcsec"][k]) <= 3.0 * s["std_arcsec"][k] + 0.05, (name, k, s)
            assert s["std_arcsec"][k] < s["seed_std_arcsec"][k]
        assert s["std_arcsec"]["roll"] > s["std_arcsec"]["az"]      # the boresight roll is the weak angle


def test_quick_run_ship_attitude_methods(quick_run):
    _, proc = quick_run
    res = json.loads(proc.stdout)
    sea = res["sea"]
    assert (sea["fore_aft_sensor"], sea["athwartship_sensor"]) == ("A1", "A2")     # A1 aft, A2 to port
    m = sea["methods"]
    assert sorted(m) == ["joint", "seed rule", "single A1", "single A2"]
    n_img = sea["sensors"]["A1"]["n_image_level"]
    assert n_img == 10
    for block in m.values():
        # every centroid-level epoch solves; a smeared image-level frame may fail (with its reason)
        assert block["n_epochs"] == 100 and block["n_solved"] >= 100 - n_img // 2
    for s in sea["sensors"].values():
        assert len(s["failures"]) == s["n_frames"] - s["n_solved"]
        assert all(int(f.split(":")[0].split("_")[1]) < n_img for f in s["failures"])      # image level only
    cen = {k: v["rms_centroid_level_arcsec"] for k, v in m.items()}
    # seed 003's rule takes pitch from the fore-aft sensor and roll from the athwartship one
    # (A2's, carried to A1's epoch time along the deck's motion fitted to both sensors'
    # frames, which smooths a little of its noise: within 10 %; A1's roll is 5x worse)
    assert cen["seed rule"]["pitch"] == pytest.approx(cen["single A1"]["pitch"], abs=0.01)
    assert cen["seed rule"]["roll"] == pytest.approx(cen["single A2"]["roll"], rel=0.1)
    assert cen["single A1"]["roll"] > 3 * cen["seed rule"]["roll"]
    for k in ("heading", "pitch", "roll"):
        assert cen["joint"][k] < min(cen["single A1"][k], cen["single A2"][k]) + 0.05
    assert m["seed rule"]["seed_rms_arcsec"] == {"heading": 8.47, "pitch": 7.16, "roll": 5.12}
    assert m["joint"]["seed_rms_arcsec"] is None


def test_quick_run_error_model_agrees_with_the_pipeline(quick_run):
    """shipstar.errormodel, fed the session's star count and star noise, predicts the
    centroid-level RMS of every method to within a factor of two."""
    _, proc = quick_run
    model = json.loads(proc.stdout)["error_model_centroid_level"]
    assert sorted(model) == ["joint", "seed rule", "single A1", "single A2"]
    for name, block in model.items():
        for k in ("heading", "pitch", "roll"):
            ratio = block["measured_rms_arcsec"][k] / block["predicted_rms_arcsec"][k]
            assert 0.5 < ratio < 2.0, (name, k, block)


def test_quick_run_report(quick_run):
    cwd, _ = quick_run
    text = (cwd / "out" / "report.html").read_text(encoding="utf-8")
    alts = re.findall(r'<img src="data:image/png;base64,[A-Za-z0-9+/=]+" alt="([^"]+)"', text)
    assert alts == ["frame A1", "frame A2", "sky chart", "installation histograms", "attitude errors",
                    "error model sweep"]
    assert "54.62" in text and "8.47" in text                 # the seeds' figures beside ours


def test_human_output_and_help(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "shipstar", "demo", "--help"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and "examples:" in proc.stdout and "shipstar demo --quick" in proc.stdout


def test_write_config_then_refuse_overwrite(tmp_path):
    proc = _run(["--write-config", "my-ship", "--json"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    written = json.loads(proc.stdout)["written"]
    assert len(written) == 6 and (tmp_path / "my-ship" / "ship.toml").is_file()
    _assert_bad_input(_run(["--write-config", "my-ship"], tmp_path), "already exists", "--force")
    proc = _run(["--write-config", "my-ship", "--force"], tmp_path)
    assert proc.returncode == 0 and "shipstar demo --config my-ship" in proc.stdout


@pytest.mark.parametrize("args, fragments", [
    (["--config", "nowhere"], ("configuration directory nowhere does not exist",)),
    (["--force"], ("--force only applies to --write-config",)),
    (["--write-config", "d", "--quick"], ("--write-config only writes the files",)),
    (["--out", "a-file"], ("a-file exists and is not a directory",)),
])
def test_bad_input(tmp_path, args, fragments):
    (tmp_path / "a-file").write_text("x")
    _assert_bad_input(_run(args, tmp_path), *fragments)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]          # nothing written


def test_unknown_option(tmp_path):
    # unknown options are reported by the sub-command, in one line (shipstar/cli/__init__.py)
    _assert_bad_input(_run(["--quick", "--bogus"], tmp_path), "unrecognized arguments: --bogus",
                      prefix="shipstar demo: error:")


def test_bad_config_file_is_one_line(tmp_path):
    assert _run(["--write-config", "cfg"], tmp_path).returncode == 0
    ship = tmp_path / "cfg" / "ship.toml"
    ship.write_text(ship.read_text().replace("el_deg = 39.3734", "el_deg = 139.3734"))
    _assert_bad_input(_run(["--config", "cfg", "--quick"], tmp_path), "ship.toml", "el_deg must be within")


def _tree(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("layout, fragments", [
    # a user's session in OUT/sea beside an earlier demo's report: its frames were deleted
    ({"report.html": "<html></html>", "results.json": "{}", "sea/A1/A1_00000.fits": "frame",
      "sea/track.csv": "time_utc\n", "sea/session.toml": "x"},
     ("sea holds A1, session.toml, which the demo did not write",)),
    # a user's track in OUT/sea, no earlier demo: it was overwritten
    ({"sea/track.csv": "time_utc,lat_deg,lon_deg\n"}, ("sea is not an earlier demo's (no results.json beside it)",)),
    ({"results.json": "{}", "dock/notes.txt": "mine"}, ("dock holds notes.txt, which the demo did not write",)),
    ({"sea": "a file"}, ("is in the way of the demo's sea/ folder",)),
])
def test_a_folder_holding_what_the_demo_did_not_write_is_refused_untouched(tmp_path, layout, fragments):
    """A bad-input sweep found ``demo --out W`` deleting ``W/sea/`` (a simulated session's
    frames) whenever W held a report.html, and overwriting ``W/sea/track.csv`` otherwise."""
    out = tmp_path / "W"
    for name, text in layout.items():
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text(text)
    before = _tree(out)
    _assert_bad_input(_run(["--quick", "--out", "W"], tmp_path), *fragments)
    assert _tree(out) == before


def test_an_earlier_demos_files_are_removed_and_nothing_else(tmp_path):
    from shipstar._demo import _check_out_folder, _clean_earlier_demo

    out = tmp_path / "W"
    demo = ["report.html", "results.json", "config-used/ship.toml", "sea/track.csv", "sea/weather.csv",
            "sea/truth.csv", "dock/A1.installation.toml", "dock/A2.installation.toml"]
    mine = ["notes.txt", "other/track.csv"]
    for name in demo + mine:
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text(name)
    _check_out_folder(out)
    _clean_earlier_demo(out)
    assert sorted(_tree(out)) == mine
