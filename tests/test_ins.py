"""The INS calibrated against the stars and star outages bridged with it (issue 15).

Centroid-level sea session (roll 5 deg / 8 s) through the engine, a simulated INS log
(simulate._ins) with known errors, the Kalman filter + RTS smoother (pipeline._ins).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from shipstar.errors import ShipstarError
from shipstar.frames import AttitudeConvention
from shipstar.live._ins_input import read_ins_log
from shipstar.pipeline._ins import INS_CSV_COLUMNS, InsModel, StarRows, estimate_ins, write_ins_csv
from shipstar.simulate._ins import InsErrors, parse_ins_errors, simulate_ins, write_ins_files
from shipstar.simulate._session import sea_session
from shipstar.units import ASEC2RAD, RAD2ASEC

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

DURATION_S = 150.0
RATE_HZ = 5.0
OUTAGE_S = (60.0, 100.0)
ERRORS = InsErrors(heading_bias_arcsec=30.0, heading_drift_arcsec_per_h=36.0, pitch_bias_arcsec=5.0,
                   roll_bias_arcsec=5.0, time_offset_s=0.02, misalignment_arcsec=(0.0, 12.0, -8.0))


class _Log:
    def __init__(self, truth, spec):
        self.t_s, self.angles_rad, self.start_utc_jd = truth.tau_s, truth.reading_rad, spec.utc_jd(0.0)


def _stars(spec):
    """The joint star attitudes of a centroid-level session, as ``measure`` collects them."""
    from bench_ship_attitude import frames_of, tables

    from shipstar.calibrate.installation import Installation
    from shipstar.pipeline import PipelineOptions, SensorConfig, process_session
    from shipstar.simulate._session import simulate_centroids

    cf = simulate_centroids(spec)
    track, weather, _ = tables(spec)
    configs = [SensorConfig(s.name, s.camera, Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor))
               for s in spec.sensors]
    res = process_session(configs, [frames_of(cf, s.name) for s in spec.sensors], track, weather, PipelineOptions())
    rows = StarRows()
    for e in res.epochs:
        rows.write(type("Emission", (), {"epoch": e})())
    return rows.arrays()


@pytest.fixture(scope="module")
def session():
    spec = sea_session(duration_s=DURATION_S, frame_rate_hz=RATE_HZ)
    t, a, c = _stars(spec)
    truth = simulate_ins(spec, ERRORS)
    full = estimate_ins(_Log(truth, spec), t, a, c)
    keep = (t < OUTAGE_S[0]) | (t > OUTAGE_S[1])                      # a cloud: no star epoch
    outage = estimate_ins(_Log(truth, spec), t[keep], a[keep], c[keep])
    return spec, truth, full, outage


def _errors_vs_truth(spec, sol):
    true = np.stack(spec.motion.angles_rad(sol.t_s), -1)
    e = sol.angles_rad - true
    e[:, 0] = (e[:, 0] + math.pi) % (2 * math.pi) - math.pi
    return e * RAD2ASEC


def test_estimated_errors_within_three_sigma_of_the_truth(session):
    spec, truth, sol, _ = session
    s = sol.summary
    assert set(s) == {"heading_bias_arcsec", "heading_bias_sigma_arcsec", "heading_drift_arcsec_per_h",
                      "heading_drift_sigma_arcsec_per_h", "pitch_bias_arcsec", "pitch_bias_sigma_arcsec",
                      "roll_bias_arcsec", "roll_bias_sigma_arcsec", "time_offset_s", "time_offset_sigma_s"}
    # the misalignment about the bow is a roll bias at every attitude: folded into it (0 here)
    cases = [("heading_bias_arcsec", "heading_bias_sigma_arcsec", ERRORS.heading_bias_arcsec),
             ("heading_drift_arcsec_per_h", "heading_drift_sigma_arcsec_per_h", ERRORS.heading_drift_arcsec_per_h),
             ("pitch_bias_arcsec", "pitch_bias_sigma_arcsec", ERRORS.pitch_bias_arcsec),
             ("roll_bias_arcsec", "roll_bias_sigma_arcsec", ERRORS.roll_bias_arcsec + ERRORS.misalignment_arcsec[0]),
             ("time_offset_s", "time_offset_sigma_s", ERRORS.time_offset_s)]
    for key, skey, true in cases:
        assert abs(s[key] - true) < 3 * s[skey], (key, s[key], true, s[skey])
    assert s["time_offset_sigma_s"] < 1e-4 and abs(s["time_offset_s"] - 0.02) < 1e-3     # within 1 ms
    assert s["heading_bias_sigma_arcsec"] < 2.0 and s["pitch_bias_sigma_arcsec"] < 2.0
    d = sol.details
    for i, axis in ((1, "up"), (2, "starboard")):
        assert abs(d["misalignment_arcsec"][axis] - ERRORS.misalignment_arcsec[i]) < 3 * d["misalignment_sigma_arcsec"][axis]


def test_corrected_attitude_sigmas_are_honest(session):
    spec, _, sol, _ = session
    e = _errors_vs_truth(spec, sol)
    z = e / sol.sigma_arcsec
    rms_z = np.sqrt(np.mean(z ** 2, 0))
    assert np.all((0.8 < rms_z) & (rms_z < 1.25)), rms_z
    assert not sol.bridged[(sol.t_s > 2) & (sol.t_s < DURATION_S - 2)].any()


def test_outage_is_bridged_with_a_growing_sigma_and_reconverges(session):
    spec, _, full, sol = session
    e = _errors_vs_truth(spec, sol)
    inside = (sol.t_s > OUTAGE_S[0] + 1.5) & (sol.t_s < OUTAGE_S[1] - 1.5)
    assert sol.bridged[inside].all() and not sol.bridged[(sol.t_s > 10) & (sol.t_s < OUTAGE_S[0] - 2)].any()
    z = e[inside] / sol.sigma_arcsec[inside]
    rms_z = np.sqrt(np.mean(z ** 2, 0))
    assert np.all((0.7 < rms_z) & (rms_z < 1.4)), rms_z
    # the INS's error estimate (without its white noise) grows into the outage, largest near its middle
    s_err = sol.error_sigma_arcsec[:, 0]
    edge = np.argmin(np.abs(sol.t_s - (OUTAGE_S[0] + 1.5)))
    mid = np.argmin(np.abs(sol.t_s - 0.5 * sum(OUTAGE_S)))
    assert s_err[mid] > 1.2 * s_err[edge]
    after = (sol.t_s > OUTAGE_S[1] + 5) & (sol.t_s < DURATION_S - 5)
    same = (full.t_s > OUTAGE_S[1] + 5) & (full.t_s < DURATION_S - 5)
    assert not sol.bridged[after].any()
    assert np.allclose(sol.sigma_arcsec[after], full.sigma_arcsec[same], rtol=0.3)
    assert np.all(np.abs(z) < 5.0)


def test_filter_against_the_analytic_case():
    """Constant biases, no noise, no motion but a known roll: the estimates are exact."""
    t = np.arange(0.0, 120.0, 0.02)
    true = np.stack([np.full_like(t, 1.0), 0.02 * np.sin(t), 0.08 * np.sin(2 * math.pi * t / 8.0)], -1)
    bias = np.array([30.0, 5.0, -7.0]) * ASEC2RAD
    drift = 36.0 / 3600.0 * ASEC2RAD                                   # rad per s
    reading = true + bias
    reading[:, 0] += drift * t

    class Log:
        t_s, angles_rad, start_utc_jd = t, reading, (2456366.5, 0.0)

    st = np.arange(1.0, 119.0, 0.1)
    stars = np.stack([np.full_like(st, 1.0), 0.02 * np.sin(st), 0.08 * np.sin(2 * math.pi * st / 8.0)], -1)
    cov = np.broadcast_to(np.eye(3) * (0.01 * ASEC2RAD) ** 2, (len(st), 3, 3))
    model = InsModel(noise_arcsec=0.0, quantisation_deg=0.0, heading_random_walk_arcsec_per_sqrt_h=0.0,
                     level_random_walk_arcsec_per_sqrt_h=0.0, estimate_misalignment=False)
    s = estimate_ins(Log, st, stars, cov, model).summary
    assert s["heading_bias_arcsec"] == pytest.approx(30.0, abs=0.01)
    assert s["heading_drift_arcsec_per_h"] == pytest.approx(36.0, abs=1.0)
    assert s["pitch_bias_arcsec"] == pytest.approx(5.0, abs=0.01)
    assert s["roll_bias_arcsec"] == pytest.approx(-7.0, abs=0.01)
    assert abs(s["time_offset_s"]) < 1e-5


@pytest.mark.parametrize("convention", ["", "roll=starboard-up", "pitch=bow-down", "roll=starboard-up,pitch=bow-down"])
@pytest.mark.parametrize("kind", ["ins_csv", "ins_nmea"])
def test_sign_conventions_round_trip_through_the_files(tmp_path, convention, kind):
    spec = sea_session(duration_s=2.0)
    truth = simulate_ins(spec, InsErrors(quantisation_deg=1e-6), t0_s=0.0, t1_s=2.0)
    files = write_ins_files(spec, truth, tmp_path, convention=convention)
    log = read_ins_log(files[kind], spec.utc_jd(0.0), convention)
    assert log.n_skipped == 0 and len(log.t_s) == len(truth.tau_s)
    assert np.max(np.abs(log.t_s - truth.tau_s)) < 1e-6
    d = log.angles_rad - truth.reading_rad
    assert np.max(np.abs(d)) * RAD2ASEC < 0.01
    if convention:                                  # read with shipstar's signs: the flipped angles come out negated
        other = read_ins_log(files[kind], spec.utc_jd(0.0), "")
        flip = AttitudeConvention(convention)
        assert np.allclose(other.angles_rad[:, 1], flip.pitch_sign * truth.reading_rad[:, 1], atol=1e-7)
        assert np.allclose(other.angles_rad[:, 2], flip.roll_sign * truth.reading_rad[:, 2], atol=1e-7)


def test_each_nmea_source_signs():
    """$PASHR and $PSXN,23 give roll positive port up (shipstar's), pitch bow up; a source
    declared roll=starboard-up / pitch=bow-down is negated."""
    from shipstar.live._nmea import sentence

    start = (2456366.5, 0.5)                                        # 2013-03-15 12:00 UTC
    lines = [sentence("GPZDA,120000.00,15,03,2013,00,00"), sentence("PASHR,120000.000,10.00000,T,+2.00000,-1.00000,,,,,2,2"),
             sentence("GPZDA,120000.02,15,03,2013,00,00"), sentence("HEHDT,10.50000,T"),
             sentence("PSXN,23,3.00000,-1.50000,10.50000,0.00"),
             sentence("PASHR,120000.040,11.00000,T,+4.00000,-2.00000,,,,,2,2"),
             sentence("PASHR,120000.060,11.50000,T,+5.00000,-2.50000,,,,,2,2")]
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "ins.nmea"
        p.write_text("".join(lines))
        for conv, sr, sp in (("", 1, 1), ("roll=starboard-up,pitch=bow-down", -1, -1), ("roll=port-down", -1, 1)):
            log = read_ins_log(p, start, conv)
            assert log.n_skipped == 0
            assert np.allclose(log.t_s, [0.0, 0.02, 0.04, 0.06], atol=1e-9)
            deg = np.degrees(log.angles_rad)
            assert np.allclose(deg[:, 0], [10.0, 10.5, 11.0, 11.5])
            assert np.allclose(deg[:, 1], sp * np.array([-1.0, -1.5, -2.0, -2.5]))
            assert np.allclose(deg[:, 2], sr * np.array([2.0, 3.0, 4.0, 5.0]))


def test_bad_and_out_of_order_records_are_skipped_and_counted(tmp_path):
    rows = ["time_utc,heading_deg,pitch_deg,roll_deg",
            "2013-03-15T12:00:00.00,10,1,2", "2013-03-15T12:00:00.02,10.1,1,2",
            "2013-03-15T12:00:00.04,ten,1,2",                         # not a number
            "2013-03-15T12:00:00.01,10.2,1,2",                        # out of order
            "2013-03-15T12:00:00.06,10.3,1,99",                       # roll out of range
            "2013-03-15T12:00:00.08,10.4,1,2", "2013-03-15T12:00:00.10,10.5,1,2"]
    p = tmp_path / "ins.csv"
    p.write_text("\n".join(rows) + "\n")
    log = read_ins_log(p, (2456366.5, 0.5), "")
    assert len(log.t_s) == 4 and log.n_skipped == 3
    assert len(log.problems) == 3 and all("\n" not in m and "record skipped" in m for m in log.problems)
    assert "line 4" in log.problems[0] and "not a number" in log.problems[0]
    assert "line 5" in log.problems[1] and "out of order" in log.problems[1]
    assert "line 6" in log.problems[2] and "roll_deg 99" in log.problems[2]
    from shipstar.live._nmea import sentence

    n = tmp_path / "ins.nmea"
    good = sentence("PASHR,120000.000,10.0,T,+2.0,-1.0,,,,,2,2")
    n.write_text(good + good.replace("*", "0*", 1) + sentence("PASHR,120000.020,10.0,T,+2.0,-1.0,,,,,2,2")
                 + sentence("PASHR,120000.010,10.0,T,+2.0,-1.0,,,,,2,2") + sentence("PASHR,120000.040,1.0,T,,-1,,,,,2,2")
                 + sentence("PASHR,120000.060,10.0,T,+2.0,-1.0,,,,,2,2") + sentence("PASHR,120000.080,10.0,T,+2.0,-1.0,,,,,2,2"))
    log = read_ins_log(n, (2456366.5, 0.5), "")
    assert len(log.t_s) == 4 and log.n_skipped == 3, log.problems
    assert "checksum" in log.problems[0] and "out of order" in log.problems[1] and "roll" in log.problems[2]


def test_pynmea2_reads_the_simulated_nmea(tmp_path):
    pynmea2 = pytest.importorskip("pynmea2")
    spec = sea_session(duration_s=1.0)
    files = write_ins_files(spec, simulate_ins(spec, InsErrors(), t0_s=0.0, t1_s=0.2), tmp_path)
    truth = json.loads(files["ins_truth"].read_text())
    assert truth["time_offset_s"] == 0.02 and truth["heading_bias_arcsec"] == 30.0
    kinds = set()
    for line in files["ins_nmea"].read_text().splitlines():
        m = pynmea2.parse(line, check=True)
        kinds.add(type(m).__name__)
        if type(m).__name__ == "ASHRATT":
            assert m.is_true_heading == "T" and -45 < m.roll < 45 and -30 < m.pitch < 30
        if type(m).__name__ == "SXN23":
            assert float(m.data[2]) == pytest.approx(float(m.data[2]))
    assert kinds == {"ZDA", "ASHRATT", "HDT", "SXN23"}


def test_ins_errors_and_convention_refused_in_one_line():
    with pytest.raises(ShipstarError, match="roll must be port-up or starboard-up"):
        AttitudeConvention("roll=up")
    # a key given twice: the last one won, a sign chosen without a word (a bad-input sweep)
    with pytest.raises(ShipstarError, match=r"INS convention 'roll=port-up,ROLL=starboard-up': roll given twice"):
        AttitudeConvention("roll=port-up,ROLL=starboard-up")
    assert AttitudeConvention("roll=starboard-up,pitch=bow-down").roll_sign == -1.0
    with pytest.raises(ShipstarError, match="name=value"):
        parse_ins_errors("bias=3")
    assert parse_ins_errors("misalignment_arcsec=1/2/3,time_offset_s=0.01").misalignment_arcsec == (1.0, 2.0, 3.0)


def test_ins_csv_output(tmp_path, session):
    _, _, _, sol = session
    out = tmp_path / "ins_out.csv"
    write_ins_csv(sol, out)
    lines = out.read_text().splitlines()
    assert lines[0] == ",".join(INS_CSV_COLUMNS) and len(lines) == len(sol.t_s) + 1
    sources = {ln.rsplit(",", 1)[1] for ln in lines[1:]}
    assert sources == {"stars+ins", "ins-bridged"}


def test_simulate_session_and_measure_with_ins(tmp_path):
    """The command line: simulate-session --ins-log, measure --ins (NMEA, starboard-up) --ins-out."""
    from shipstar.calibrate.installation import Installation, save_installation

    for s in sea_session().sensors:
        save_installation(Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor), tmp_path / f"{s.name}.toml")
    run = lambda *a: subprocess.run([sys.executable, "-m", "shipstar", *a], cwd=tmp_path, capture_output=True,
                                    text=True, timeout=600)
    p = run("simulate-session", "--kind", "sea", "--out", "sea", "--duration-s", "2", "--ins-log",
            "--ins-convention", "roll=starboard-up", "--json")
    assert p.returncode == 0, p.stderr
    assert (tmp_path / "sea" / "ins.nmea").is_file() and (tmp_path / "sea" / "ins_truth.json").is_file()
    p = run("measure", "--sensor", "A1=sea/A1", "--sensor", "A2=sea/A2", "--install", "A1.toml", "A2.toml",
            "--track", "sea/track.csv", "--weather", "sea/weather.csv", "--out", "att.csv", "--workers", "1",
            "--ins", "sea/ins.nmea", "--ins-convention", "roll=starboard-up", "--ins-out", "ins_out.csv", "--json")
    assert p.returncode in (0, 1), p.stderr
    s = json.loads(p.stdout)
    assert abs(s["ins"]["time_offset_s"] - 0.02) < 3 * s["ins"]["time_offset_sigma_s"] + 1e-4
    assert abs(s["ins"]["heading_bias_arcsec"] - 30.0) < 3 * s["ins"]["heading_bias_sigma_arcsec"]
    assert (tmp_path / "ins_out.csv").read_text().startswith(",".join(INS_CSV_COLUMNS))
    p = run("measure", "--sensor", "A1=sea/A1", "--install", "A1.toml", "--track", "sea/track.csv",
            "--weather", "sea/weather.csv", "--out", "att2.csv", "--ins-out", "x.csv")
    assert p.returncode == 2 and "--ins-out needs --ins" in p.stderr and "Traceback" not in p.stderr


def test_forward_filter_live_over_udp():
    """``live --ins-udp``: NMEA datagrams in, the star epochs as the engine gives them out
    (0.2 s late), each record corrected and sent on at the INS's rate, method stars+ins."""
    import socket
    import time

    from shipstar.live._ins_live import LiveIns
    from shipstar.live._outputs import UdpOutput
    from shipstar.simulate._ins import nmea_lines
    from shipstar.sky.time import iso_from_utc_jd
    from shipstar.units import RAD2DEG

    spec = sea_session(duration_s=40.0, frame_rate_hz=5.0)
    t, a, c = _stars(spec)
    truth = simulate_ins(spec, ERRORS, t0_s=0.0, t1_s=40.0)
    start = spec.utc_jd(0.0)
    iso = [iso_from_utc_jd(start[0], start[1] + tau / 86400.0, 6) for tau in truth.tau_s]
    deg = truth.reading_rad * RAD2DEG
    sentences = list(nmea_lines(iso, deg[:, 0], deg[:, 1], deg[:, 2], 6))
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.0)
    out = UdpOutput([("127.0.0.1", rx.getsockname()[1])], "nmea", "joint", ("A1", "A2"), "A1")
    errors = []
    ins = LiveIns("127.0.0.1", 0, "", origin_utc_jd=start, on_error=errors.append)
    ins.start()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    class Joint:
        solved = True

    recs, got = [], []
    try:
        k_star = 0
        for sec in range(40):
            lo, hi = np.searchsorted(truth.tau_s, [sec, sec + 1])
            for i in range(lo, hi):                                  # one datagram per record
                tx.sendto("".join(sentences[4 * i:4 * i + 4]).encode(), ("127.0.0.1", ins.port))
            n = len(recs) + hi - lo - (1 if sec == 0 else 0)        # the last record waits for the next time
            end = time.monotonic() + 5.0
            while len(recs) < n and time.monotonic() < end:
                recs += ins.poll(out)
                time.sleep(0.005)
            while k_star < len(t) and t[k_star] < sec + 1 - 0.2:
                j = Joint()
                j.heading_rad, j.pitch_rad, j.roll_rad = a[k_star]
                j.covariance_rad2 = c[k_star]
                ep = type("Epoch", (), {"joint": j, "utc_jd1": start[0], "utc_jd2": start[1] + t[k_star] / 86400.0})
                ins.star(type("Emission", (), {"epoch": ep})())
                k_star += 1
            while True:
                try:
                    got.append(rx.recv(4096).decode())
                except BlockingIOError:
                    break
    finally:
        ins.stop()
        out.close()
        rx.close()
        tx.close()
    assert not errors
    assert len(recs) >= len(truth.tau_s) - 60
    s = ins.summary()
    assert abs(s["time_offset_s"] - 0.02) < 3 * s["time_offset_sigma_s"] + 2e-5
    assert abs(s["heading_bias_arcsec"] - 30.4) < 3 * s["heading_bias_sigma_arcsec"] + 1.0
    tc = np.array([r[0] for r in recs])
    ang = np.array([r[1] for r in recs])
    sig = np.array([r[2] for r in recs])
    e = ang - np.stack(spec.motion.angles_rad(tc), -1)
    e[:, 0] = (e[:, 0] + math.pi) % (2 * math.pi) - math.pi
    late = tc > 15.0
    rms_z = np.sqrt(np.mean((e[late] * RAD2ASEC / sig[late]) ** 2, 0))
    assert np.all((0.7 < rms_z) & (rms_z < 1.4)), rms_z
    assert len(got) >= 0.9 * len(recs)
    assert all("$PSSTA" in g and "$HEHDT" in g and "$PASHR" in g for g in got)
    # records sent before the star epochs of their second came (1 s batches here) are ins-bridged
    assert sum(",stars+ins," in g for g in got[100:]) > 0.5 * len(got[100:])
