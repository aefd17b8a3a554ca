"""The INS in the report (issue 15 item 6) and ``measure --ins --resume``.

A centroid-level sea session with a simulated INS (issue 15's errors) and a cloud (no star
epoch for 20 s): the report's tables against the simulated truth, its figures; the
command line's ``--ins-report``, ``--plots`` and a killed run resumed to the same
``--ins-out`` as an uninterrupted one.
"""

from __future__ import annotations

import io
import json
import math
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from shipstar.errors import ShipstarError
from shipstar.pipeline._ins import INS_CSV_COLUMNS, StarRows, estimate_ins
from shipstar.report._ins_plot import (
    INS_ERRORS_ALT,
    INS_OUTAGE_ALT,
    figure_pngs,
    ins_page,
    outage_intervals,
    plot_ins_outage,
    true_attitude_at,
)
from shipstar.simulate._ins import InsErrors, simulate_ins
from shipstar.simulate._session import sea_session
from shipstar.units import RAD2ASEC

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

DURATION_S = 60.0
OUTAGE_S = (20.0, 40.0)
ERRORS = InsErrors()                     # issue 15's: 30'', 36''/h, 5'', 5'', 20 ms
TRUE_TERMS = {"heading_bias_arcsec": 30.0, "heading_drift_arcsec_per_h": 36.0, "pitch_bias_arcsec": 5.0,
              "roll_bias_arcsec": 5.0, "time_offset_s": 0.02, "misalignment_arcsec": [0.0, 0.0, 0.0]}


def _png_size(png: bytes):
    from PIL import Image

    with Image.open(io.BytesIO(png)) as im:
        im.load()
        return im.size, im.getextrema()


def _tables(text: str) -> list:
    """Each table as ``{first cell: [other cells]}`` (header row under key ``"header"``)."""
    out = []
    for tab in re.findall(r"<table>(.*?)</table>", text):
        rows = {}
        for tr in re.findall(r"<tr[^>]*>(.*?)</tr>", tab):
            cells = re.findall(r"<t[dh][^>]*>(.*?)</t[dh]>", tr)
            rows["header" if "<th" in tr else cells[0]] = cells if "<th" in tr else cells[1:]
        out.append(rows)
    return out


@pytest.fixture(scope="module")
def session():
    from bench_ship_attitude import frames_of, tables

    from shipstar.calibrate.installation import Installation
    from shipstar.pipeline import PipelineOptions, SensorConfig, process_session
    from shipstar.simulate._session import simulate_centroids

    spec = sea_session(duration_s=DURATION_S, frame_rate_hz=5.0)
    cf = simulate_centroids(spec)
    track, weather, truth_table = tables(spec)
    configs = [SensorConfig(s.name, s.camera, Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor))
               for s in spec.sensors]
    res = process_session(configs, [frames_of(cf, s.name) for s in spec.sensors], track, weather, PipelineOptions())
    rows = StarRows()
    for e in res.epochs:
        rows.write(type("Emission", (), {"epoch": e})())
    t, a, c = rows.arrays()
    ins = simulate_ins(spec, ERRORS)

    class Log:
        t_s, angles_rad, start_utc_jd = ins.tau_s, ins.reading_rad, spec.utc_jd(0.0)

    keep = (t < OUTAGE_S[0]) | (t > OUTAGE_S[1])                      # a cloud
    sol = estimate_ins(Log, t[keep], a[keep], c[keep])
    return spec, sol, truth_table, res


def _true_errors(spec, sol):
    """Corrected attitude minus the simulated motion (arcsec), straight from the motion."""
    true = np.stack(spec.motion.angles_rad(sol.t_s), -1)
    e = sol.angles_rad - true
    e[:, 0] = (e[:, 0] + math.pi) % (2 * math.pi) - math.pi
    return e * RAD2ASEC


def test_report_tables_against_the_simulated_truth(session):
    spec, sol, _, _ = session
    true_att = np.stack(spec.motion.angles_rad(sol.t_s), -1)
    page = ins_page(sol, true_attitude_rad=true_att, true_terms=TRUE_TERMS)
    text = page.to_html()
    terms, corrected = _tables(text)
    assert terms["header"] == ["INS error term", "estimated", "1\u03c3", "true", "(est \u2212 true)/\u03c3"]
    for label, true in (("heading bias at the first record (\u2033)", 30.0), ("pitch bias (\u2033)", 5.0),
                        ("roll bias (\u2033)", 5.0), ("clock offset, INS minus frames (ms)", 20.0)):
        est, sig, shown_true, z = (float(x) for x in terms[label])
        assert shown_true == true and abs(est - true) < 3 * sig                 # within 3 sigma of the truth
        assert z == pytest.approx((est - true) / sig, abs=0.02)
    assert float(terms["heading bias at the first record (\u2033)"][1]) < 1.0   # arcsec: the stars pin it
    # the corrected attitude's statistics, recomputed straight from the simulated motion
    err = _true_errors(spec, sol)
    for key, sel in (("stars+ins (outside outages)", ~sol.bridged), ("ins-bridged (inside outages)", sol.bridged)):
        row = corrected[key]
        assert int(row[0]) == int(sel.sum()) > 500
        rms = np.sqrt(np.mean(err[sel] ** 2, 0))
        rz = np.sqrt(np.mean((err[sel] / sol.sigma_arcsec[sel]) ** 2, 0))
        assert [float(x) for x in row[4:7]] == pytest.approx(rms, abs=0.006)
        assert [float(x) for x in row[7:10]] == pytest.approx(rz, abs=0.006)
        assert np.all((rz > 0.8) & (rz < 1.25))                                  # honest sigmas
    assert text.count("data:image/png;base64,") == 2
    assert f'alt="{INS_ERRORS_ALT}"' in text and f'alt="{INS_OUTAGE_ALT}"' in text
    for png, size in zip(figure_pngs(page), ((1050, 980), (1050, 740))):
        got, extrema = _png_size(png)
        assert got == size and any(lo != hi for lo, hi in extrema)             # drawn, not blank


def test_report_without_truth_shows_the_sigmas(session):
    _, sol, _, _ = session
    page = ins_page(sol)
    terms, corrected = _tables(page.to_html())
    assert terms["header"] == ["INS error term", "estimated", "1\u03c3"]
    assert corrected["header"][2:] == [f"median \u03c3 {n} (\u2033)" for n in ("heading", "pitch", "roll")]
    inside = [float(x) for x in corrected["ins-bridged (inside outages)"][1:4]]
    outside = [float(x) for x in corrected["stars+ins (outside outages)"][1:4]]
    assert inside[0] > outside[0]                                                 # the heading sigma grows in the cloud
    assert len(figure_pngs(page)) == 2


def test_session_report_has_the_ins_section(session, tmp_path):
    from shipstar.report import session_report

    _, sol, table, res = session
    text = session_report(res, tmp_path / "s.html", truth=table, ins=sol).read_text(encoding="utf-8")
    assert "Inertial navigator (INS)" in text
    assert f'alt="{INS_ERRORS_ALT}"' in text and f'alt="{INS_OUTAGE_ALT}"' in text
    tabs = _tables(text)
    assert tabs[-1]["header"][-1] == "beyond 3\u03c3"                              # compared with the truth


def test_truth_table_interpolated_to_the_records(session):
    """The --truth table (rows at the frames, 5 Hz here) at the INS records: cubic, to
    within a few hundredths of an arcsec of the motion itself at 10 Hz."""
    from bench_ship_attitude import tables

    spec, sol, table, _ = session
    true = np.stack(spec.motion.angles_rad(sol.t_s), -1)
    got = true_attitude_at(sol, table)
    inside = np.isfinite(got[:, 0])
    assert inside.sum() > 0.9 * len(got) and not inside[0]                      # NaN before the first row
    d = got[inside] - true[inside]
    d[:, 0] = (d[:, 0] + math.pi) % (2 * math.pi) - math.pi
    assert np.max(np.abs(d)) * RAD2ASEC < 0.6                                     # 5 Hz rows
    fast = sea_session(duration_s=4.0, frame_rate_hz=10.0)
    _, _, table10 = tables(fast)

    class Sol:
        start_utc_jd = fast.utc_jd(0.0)
        t_s = np.linspace(0.3, 3.6, 200)

    d = true_attitude_at(Sol, table10) - np.stack(fast.motion.angles_rad(Sol.t_s), -1)
    d[:, 0] = (d[:, 0] + math.pi) % (2 * math.pi) - math.pi
    assert np.max(np.abs(d)) * RAD2ASEC < 0.05


def test_outage_intervals_and_plot_errors():
    t = np.arange(0.0, 10.0, 0.5)
    b = np.zeros(len(t), bool)
    b[4:8] = True
    b[-2:] = True
    assert outage_intervals(t, b) == [(1.75, 3.75), (8.75, 9.75)]
    assert outage_intervals(t, np.zeros(len(t), bool)) == []
    with pytest.raises(ShipstarError, match="bridged has 3 entries"):
        outage_intervals(t, b[:3])
    with pytest.raises(ShipstarError, match="need N >= 2 records"):
        plot_ins_outage(t[:1], np.ones((1, 3)), b[:1])


def test_star_rows_spool_survives_a_crash_and_resumes_to_the_same_rows(tmp_path):
    """The epochs written before a crash (a torn last record included) are read back and
    those the resumed run gives out again are replaced: the rows of an uninterrupted run."""
    from types import SimpleNamespace as NS

    rng = np.random.default_rng(3)

    def emission(t, solved=True):
        cov = np.diag(rng.uniform(1e-12, 4e-12, 3)) + 1e-13
        joint = NS(solved=solved, heading_rad=rng.uniform(0, 6), pitch_rad=rng.normal(0, 0.05),
                   roll_rad=rng.normal(0, 0.1), covariance_rad2=cov)
        return NS(epoch=NS(t_s=t, joint=joint))

    ems = [emission(0.1 * k, solved=k % 7 != 3) for k in range(40)]
    ref = StarRows()
    for e in ems:
        ref.write(e)
    spool = tmp_path / "att.csv.ins-stars"
    first = StarRows(spool)
    for k, e in enumerate(ems[:25]):
        first.write(e)
        if k == 12:
            first.flush()                       # a checkpoint: the next epoch is at 1.3 s
    first.close()
    with open(spool, "ab") as fh:
        fh.write(b"\x00" * 37)                  # a crash in the middle of a record
    again = StarRows(spool, resume=True)
    for e in ems[13:]:                          # the resumed run gives out from the checkpoint on
        again.write(e)
    for x, y in zip(again.arrays(), ref.arrays()):
        assert np.array_equal(x, y)
    again.close()
    assert spool.stat().st_size == 80 * len(ref)
    again.discard()
    assert not spool.exists()
    with pytest.raises(ShipstarError, match="was the stopped run given --ins"):
        StarRows(spool, resume=True)


def test_a_run_begun_with_ins_keeps_its_star_attitudes_until_it_is_complete(tmp_path):
    """Resumed without --ins: the epochs are still collected (a later --resume --ins has them
    all) and deleted when the run completes; a run started over deletes an old spool."""
    from types import SimpleNamespace as NS

    from shipstar.cli._ins_args import finish_ins, ins_observer, spool_path

    out = tmp_path / "att.csv"
    rows = StarRows(spool_path(out))
    rows.add(1.0, (0.1, 0.2, 0.3), np.eye(3) * 1e-12)
    rows.close()
    args = NS(ins=None, ins_out=None, ins_report=None, ins_truth=None, resume=True, out=str(out))
    obs = ins_observer(args)
    assert len(obs) == 1 and obs.arrays()[0].tolist() == [1.0]
    summary = {}
    finish_ins(args, None, obs, summary)
    assert summary == {} and not spool_path(out).exists()
    left = StarRows(spool_path(out))
    left.flush()
    left.close()
    assert spool_path(out).exists()
    assert ins_observer(NS(**{**vars(args), "resume": False})) is None
    assert not spool_path(out).exists()


# --------------------------------------------------------------------------------------
# The command line
# --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def sea(tmp_path_factory):
    from shipstar.calibrate.installation import Installation, save_installation
    from shipstar.simulate._ins import write_ins_files
    from shipstar.simulate._session import write_session

    root = tmp_path_factory.mktemp("ins_sea")
    spec = sea_session(duration_s=2.0)
    for s in spec.sensors:
        save_installation(Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor),
                          root / f"{s.name}.toml")
    write_session(spec, root / "sea")
    write_ins_files(spec, simulate_ins(spec, ERRORS), root / "sea")
    return root


MEASURE = ["measure", "--sensor", "A1=sea/A1", "--sensor", "A2=sea/A2", "--install", "A1.toml", "A2.toml",
           "--track", "sea/track.csv", "--weather", "sea/weather.csv", "--workers", "1", "--chunk-s", "1",
           "--ins", "sea/ins.csv"]


def _main(capsys, *args):
    """``shipstar ARGS`` in this process: (exit code, stdout, stderr)."""
    from shipstar.cli import main

    capsys.readouterr()
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def test_measure_ins_report_plots_and_a_resumed_run(sea, capsys, monkeypatch):
    monkeypatch.chdir(sea)
    code, stdout, err = _main(capsys, *MEASURE, "--out", "ref/att.csv", "--ins-out", "ref/ins.csv", "--plots",
                              "ref/plots", "--ins-report", "ref/ins.html", "--truth", "sea/truth.csv", "--ins-truth",
                              "sea/ins_truth.json", "--json")
    assert code == 0, err
    s = json.loads(stdout)
    d = s["ins_details"]
    assert d["report"] == "ref/ins.html" and d["plots"] == ["ref/plots/ins_errors.png", "ref/plots/ins_outage.png"]
    assert d["corrected"]["outside"]["n_compared"] > 50
    assert 0.5 < max(d["corrected"]["outside"]["rms_error_over_sigma"]) < 1.6
    for name in d["plots"]:
        png = (sea / name).read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20000
    terms = _tables((sea / "ref" / "ins.html").read_text(encoding="utf-8"))[0]
    est, sig, true, _ = (float(x) for x in terms["heading bias at the first record (\u2033)"])
    assert true == 30.0 and abs(est - true) < 3 * sig
    assert not (sea / "ref" / "att.csv.ins-stars").exists()                     # the spool is gone
    # killed after its first checkpoint, then resumed: the same corrected attitude
    # (without the mounts' smoothing, which holds epochs for --smooth-lag-s and is resumed in
    # tests/cli/test_cmd_measure_stream.py: the first checkpoint has rows; a rigid deck's rows
    # are those of any lag, so the reference made with the default lag still applies)
    out = sea / "k" / "att.csv"
    lag = ("--smooth-lag-s", "0")
    proc = subprocess.Popen([sys.executable, "-m", "shipstar", *MEASURE, *lag, "--out", str(out),
                             "--ins-out", "k/ins.csv"], cwd=sea, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    end = time.monotonic() + 120
    while not out.with_name("att.csv.resume").exists():
        assert proc.poll() is None and time.monotonic() < end, "the run ended before its first checkpoint"
        time.sleep(0.002)
    proc.kill()
    proc.wait(30)
    assert out.with_name("att.csv.ins-stars").stat().st_size >= 80 * 5          # the first second's epochs
    code, stdout, err = _main(capsys, *MEASURE, *lag, "--out", str(out), "--ins-out", "k/ins.csv", "--resume",
                              "--json")
    assert code == 0, err
    assert json.loads(stdout)["resumed_at_s"] > 0
    ref = (sea / "ref" / "ins.csv").read_text()
    assert ref.startswith(",".join(INS_CSV_COLUMNS)) and (sea / "k" / "ins.csv").read_text() == ref
    assert sorted(x.name for x in out.parent.iterdir()) == ["att.csv", "ins.csv"]
    code, _, err = _main(capsys, *MEASURE[:-2], "--out", "x.csv", "--ins-report", "x.html")
    assert code == 2 and "--ins-report needs --ins" in err and len(err.splitlines()) == 1
