"""``shipstar error-model`` run as a subprocess."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest


def run(*args):
    return subprocess.run([sys.executable, "-m", "shipstar", "error-model", *args],
                          capture_output=True, text=True, timeout=300)


def test_seed_sweeps_headline_layout_json(tmp_path):
    out = run("--sweep", "seed", "--layout", "--points", "91", "--mc-samples", "4000", "--step-deg", "5",
              "--out", str(tmp_path), "--json")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert len(lines) == 1
    res = json.loads(lines[0])
    # budget at the seed's base point (A0 = 0): per-source contributions and RSS
    b = res["budget"]
    rss = np.sqrt(sum(v**2 for v in b["contributions_arcsec"]["heading"].values()))
    assert b["rss_arcsec"]["heading"] == pytest.approx(rss)
    mc = res["monte_carlo"]
    for o in ("heading", "pitch", "roll"):
        assert abs(mc["rel_diff"][o]) < 0.05
    # the headline beside the seed's 112''; the seed's own composition gives 112'' on the A0 sweep
    h = res["seed001_headline"]
    assert h["seed_arcsec"] == 112.0
    assert abs(h["seed001-factors"]["per_sweep_max_arcsec"]["A0"] - 112.0) < 1.0
    assert h["shipstar"]["base_point_max_arcsec"] == pytest.approx(100 * np.sqrt(2), rel=1e-6)
    keys = [c["key"] for c in res["seed001_conclusions"]["shipstar"]]
    assert "3.1(1)" in keys and "3.2(7)" in keys and "3.3(4)" in keys
    assert len(res["sweeps"]) == 8
    for s in res["sweeps"]:
        assert (tmp_path / f"errormodel_{s['key']}.png").stat().st_size > 1000
        assert (tmp_path / f"errormodel_{s['key']}.csv").exists()
    lay = res["layout"]
    assert lay["dual"]["objective_arcsec"] < lay["single"]["objective_arcsec"]
    assert all(30.0 <= e <= 60.0 for e in lay["dual"]["el_deg"])
    assert (tmp_path / "errormodel_layout.png").exists()
    assert json.loads((tmp_path / "error_model.json").read_text()) == res


def test_single_sweep_text_output(tmp_path):
    out = run("--sweep", "E0", "--points", "31", "--mc-samples", "500", "--sensor-errors-arcsec", "3", "3", "60",
              "--out", str(tmp_path))
    assert out.returncode == 0, out.stderr
    assert "RSS of sources" in out.stdout and "Monte Carlo" in out.stdout
    rows = (tmp_path / "errormodel_sweep_E0.csv").read_text().splitlines()
    assert len(rows) == 1 + 4 * 31
    assert rows[0].startswith("curve,E0_deg,gimbal_locked")


def test_headline_printed_beside_seed_value(tmp_path):
    out = run("--sweep", "seed", "--points", "37", "--mc-samples", "500", "--out", str(tmp_path))
    assert out.returncode == 0, out.stderr
    assert "[seed: 112'']" in out.stdout and "3.3(2)" in out.stdout


@pytest.mark.parametrize("args, needle", [
    (["--sensor-errors-arcsec", "-1", "3", "100"], "errors must be"),
    (["--layout", "--el-range-deg", "70", "20"], "elevation range"),
    (["--layout", "--n-stars", "1"], "n_stars"),
    (["--sweep", "E0", "--points", "1"], "--points must be at least 2, got 1"),
    # accepted before, and a budget computed (found by a bad-input sweep)
    (["--sensor-angles-deg", "235", "95", "90"], "--sensor-angles-deg: the elevation ES must be within [-90, 90]"),
    (["--install-angles-deg", "0", "-95", "0"], "--install-angles-deg: the elevation E0 must be within [-90, 90]"),
])
def test_bad_input_is_one_line_exit_2(tmp_path, args, needle):
    out = run(*args, "--mc-samples", "200", "--out", str(tmp_path / "em"))
    assert out.returncode == 2
    assert "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    assert needle in out.stderr
    if "--points" in args or "-angles-deg" in args[0]:
        assert not (tmp_path / "em").exists()                  # refused before the directory is made


@pytest.mark.parametrize("seed", ["-1", str(2**63), "1.5"])
def test_bad_rng_seed_is_refused_before_the_out_dir_is_made(tmp_path, seed):
    out = run("--rng-seed", seed, "--mc-samples", "200", "--out", str(tmp_path / "em"))
    assert out.returncode == 2
    assert "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1 and "--rng-seed" in out.stderr
    assert not (tmp_path / "em").exists()


def test_help_has_example():
    out = run("--help")
    assert out.returncode == 0 and "shipstar error-model --sweep seed" in out.stdout
