"""Clock offsets and mount flexure estimated from the data (issue 14 item 3; pipeline._mounts).

Centroid-level sea sessions (8 s, roll 5 deg / 8 s) with the shipped ``clock`` and
``flexure`` condition files, whose true values the simulator gives.
"""

from __future__ import annotations

import csv
import io
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from shipstar.calibrate.installation import Installation
from shipstar.pipeline import PipelineOptions, SensorConfig, process_session, session_summary
from shipstar.pipeline._mounts import MONITOR_COLUMNS, MIN_EPOCHS, MonitorCsvWriter
from shipstar.pipeline._stats import attitude_errors_arcsec, method_series
from shipstar.simulate._conditions import apply_conditions, flexure_rotvec_rad, load_conditions
from shipstar.simulate._session import sea_session, simulate_centroids
from shipstar.units import RAD2ASEC

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_ship_attitude import frames_of, tables  # noqa: E402

DURATION_S = 8.0


def _run(conditions, reference=None, smooth_lag_s=0.0):
    spec = sea_session(duration_s=DURATION_S)
    if conditions is not None:
        spec = apply_conditions(spec, load_conditions(conditions))
    cf = simulate_centroids(spec)
    track, weather, truth = tables(spec)
    configs = [SensorConfig(s.name, s.camera, Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor))
               for s in spec.sensors]
    res = process_session(configs, [frames_of(cf, s.name) for s in spec.sensors], track, weather,
                          PipelineOptions(), reference=reference, smooth_lag_s=smooth_lag_s)
    return spec, res, truth


@pytest.fixture(scope="module")
def clock():
    return _run("clock")


@pytest.fixture(scope="module")
def flexure():
    return _run("flexure")


@pytest.fixture(scope="module")
def clean():
    return _run(None)


def test_clock_offset_is_found_with_its_sign_and_applied(clock):
    spec, res, truth = clock
    s = session_summary(res, truth)
    assert list(s["time_offsets_s"]) == ["A2"]
    a2 = s["time_offsets_s"]["A2"]
    assert set(a2) == {"offset_s", "sigma_s", "applied"}
    assert a2["offset_s"] == pytest.approx(0.003, abs=3e-4)            # true exposure time - header time
    assert 0 < a2["sigma_s"] < 2e-4 and a2["applied"] is True
    assert abs(a2["offset_s"] - 0.003) < 4 * a2["sigma_s"] + 5e-5      # jitter 50 us
    assert s["flexure"]["A2"]["applied"] is False                      # no flexure in clock.toml
    # applied: the joint solution's error falls from tens of arcsec to the noise
    err = attitude_errors_arcsec(method_series(res, "joint"), truth)
    first = [k for k, e in enumerate(res.epochs) if e.mounts.time_offsets_s["A2"]["applied"]][0]
    assert MIN_EPOCHS <= first < 45
    assert np.nanmax(np.abs(err[:first])) > 10.0
    assert np.all(np.sqrt(np.nanmean(err[50:] ** 2, axis=0)) < 1.0)        # once sigma < 0.15 ms


def test_clock_offset_relative_to_another_reference(clock):
    spec, _, truth = clock
    _, res, _ = _run("clock", reference="A2")
    a1 = session_summary(res, truth)["time_offsets_s"]["A1"]
    assert a1["offset_s"] == pytest.approx(-0.003, abs=3e-4)           # A1 is 3 ms early against A2


def test_flexure_static_and_wave_parts_against_the_truth(flexure):
    spec, res, truth = flexure
    s = session_summary(res, truth)
    f = s["flexure"]["A2"]
    assert f["applied"] is True and f["installation_drift"] is True
    assert f["wave_amplitude_arcsec"]["bow"] == pytest.approx(20.0, rel=0.2)
    assert f["wave_amplitude_arcsec"]["up"] < 3.0 and f["wave_amplitude_arcsec"]["starboard"] < 3.0
    # the static part: static + thermal + ramp over the session (the wave part averages out)
    t = np.array([e.t_s for e in res.epochs])
    phi = np.array([flexure_rotvec_rad(spec, "A2", x) for x in t]) * RAD2ASEC
    wave = np.array([20.0, 0.0, 0.0])[None, :] * np.sin(2 * math.pi * t / 8.0)[:, None]
    static_true = (phi - wave).mean(axis=0)
    for k, ax in enumerate(("bow", "up", "starboard")):
        assert abs(f["static_arcsec"][ax] - static_true[k]) < 4 * f["static_sigma_arcsec"][ax] + 0.5
    assert s["time_offsets_s"]["A2"]["applied"] is False
    assert abs(s["time_offsets_s"]["A2"]["offset_s"]) < 5 * s["time_offsets_s"]["A2"]["sigma_s"]
    # the monitor (smoothed, causal) follows the true rotation once estimated
    late = [(e, p) for e, p in zip(res.epochs, phi) if e.index >= 40]
    d = np.array([e.mounts.monitor[0][1] - p for e, p in late])
    assert np.all(np.sqrt(np.mean(d ** 2, axis=0)) < 2.0)
    # and the joint solution, with the flexure applied, refers to A1's mount: no 20'' wave left
    err = attitude_errors_arcsec(method_series(res, "joint"), truth)
    assert np.all(np.sqrt(np.nanmean(err[60:] ** 2, axis=0)) < 1.5)        # the target


def test_nothing_is_applied_without_conditions(clean):
    _, res, truth = clean
    for e in res.epochs:
        assert not e.mounts.time_offsets_s["A2"]["applied"] and not e.mounts.flexure["A2"]["applied"]
    s = session_summary(res, truth)
    assert abs(s["time_offsets_s"]["A2"]["offset_s"]) < 5 * s["time_offsets_s"]["A2"]["sigma_s"]
    assert all(abs(v) < 2.0 for v in s["flexure"]["A2"]["wave_amplitude_arcsec"].values())
    assert s["flexure"]["A2"]["installation_drift"] is False
    json.dumps(s, allow_nan=False)


def test_monitor_csv_columns_and_rows(flexure, tmp_path):
    _, res, _ = flexure
    path = tmp_path / "monitor.csv"
    w = MonitorCsvWriter(path)
    for e in res.emissions:
        w.write(e)
    w.close()
    rows = list(csv.DictReader(io.StringIO(path.read_text())))
    assert tuple(rows[0]) == MONITOR_COLUMNS
    assert len(rows) == len(res.epochs) and {r["sensor"] for r in rows} == {"A2"}
    assert rows[0]["rot_bow_arcsec"] == "nan" and rows[0]["time_utc"] == res.epochs[0].utc_iso
    late = rows[-1]
    assert float(late["sigma_bow_arcsec"]) < 2.0 and abs(float(late["rot_bow_arcsec"])) < 30.0
    # a resumed run keeps the rows before its resume point
    w = MonitorCsvWriter(path, keep_before_s=res.epochs[10].t_s, start_utc_jd=res.start_utc_jd)
    w.close()
    assert len(path.read_text().splitlines()) == 1 + 10


# -- the fixed-lag smoother (measure --smooth-lag-s) ------------------------------------------

def _smoothed(conditions):
    return _run(conditions, smooth_lag_s=60.0)


def test_smoother_leaves_a_rigid_deck_alone(clean):
    _, causal, _ = clean
    _, smooth, _ = _smoothed(None)
    a = np.array([[e.joint.heading_rad, e.joint.pitch_rad, e.joint.roll_rad] for e in causal.epochs])
    b = np.array([[e.joint.heading_rad, e.joint.pitch_rad, e.joint.roll_rad] for e in smooth.epochs])
    np.testing.assert_array_equal(a, b)                       # the same rows, bit for bit
    assert [len(e.frames) for e in causal.emissions] == [len(e.frames) for e in smooth.emissions]


def test_smoother_applies_the_clock_offset_to_the_first_epochs(clock):
    """Causally the 3 ms offset is applied after ~30 epochs and the joint solution is off by
    tens of arcsec before; smoothed, every epoch is carried from the true exposure time."""
    _, causal, truth = clock
    _, smooth, _ = _smoothed("clock")
    err_c = attitude_errors_arcsec(method_series(causal, "joint"), truth)
    err_s = attitude_errors_arcsec(method_series(smooth, "joint"), truth)
    assert np.nanmax(np.abs(err_c[:MIN_EPOCHS])) > 10.0
    assert np.all(np.sqrt(np.nanmean(err_s[:MIN_EPOCHS] ** 2, axis=0)) < 1.0)
    assert np.all(np.sqrt(np.nanmean(err_s ** 2, axis=0)) < 1.0)
    # the summary's estimate is the estimator's own, as without smoothing
    assert session_summary(smooth, truth)["time_offsets_s"] == session_summary(causal, truth)["time_offsets_s"]
    # and A2's single rows are at their true times from the first frame on, as the fusion
    from shipstar.pipeline import attitude_csv_text
    from shipstar.pipeline._output import CLOCK_OFFSET_SUFFIX

    rows = [r for r in csv.DictReader(line for line in io.StringIO(attitude_csv_text(smooth))
                                      if not line.startswith("#")) if r["method"] == "single"]
    assert all(r["time_source"].endswith(CLOCK_OFFSET_SUFFIX) == (r["sensor"] == "A2") for r in rows)


def test_smoother_monitor_and_joint_from_the_first_epoch(flexure):
    spec, causal, truth = flexure
    _, smooth, _ = _smoothed("flexure")
    t = np.array([e.t_s for e in smooth.epochs])
    phi = np.array([flexure_rotvec_rad(spec, "A2", x) for x in t]) * RAD2ASEC
    est = np.array([e.mounts.monitor[0][1] for e in smooth.epochs])
    sig = np.array([e.mounts.monitor[0][2] for e in smooth.epochs])
    # every epoch of an 8 s session gets the whole session's estimate: no NaN rows, and the
    # estimate is within its stated sigma of the truth
    assert np.all(np.isfinite(est))
    z = (est - phi) / sig
    assert np.all(np.sqrt(np.mean(z ** 2, axis=0)) < 2.0)
    err_c = attitude_errors_arcsec(method_series(causal, "joint"), truth)
    err_s = attitude_errors_arcsec(method_series(smooth, "joint"), truth)
    rms_c = np.sqrt(np.nanmean(err_c[:60] ** 2, axis=0))
    rms_s = np.sqrt(np.nanmean(err_s[:60] ** 2, axis=0))
    assert np.all(rms_s < 1.5) and rms_s.max() < 0.5 * rms_c.max()


def test_engine_flush_gives_out_held_epochs(flexure):
    from shipstar.pipeline._engine import SessionEngine

    spec, res, _ = flexure
    configs = [SensorConfig(s.name, s.camera, Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor))
               for s in spec.sensors]
    eng = SessionEngine(configs, res.options, start_utc_jd=res.start_utc_jd, smooth_lag_s=1e6)
    out = []
    for fr in sorted((fr for rs in res.frames for fr in rs), key=lambda f: (eng.t_s(f), f.sensor)):
        out += eng.add(fr)
    assert out == [] and eng.next_epoch_t_s() == pytest.approx(0.0, abs=1e-6)
    held = eng.flush()
    assert [e.epoch.index for e in held if e.epoch is not None] == list(range(len(held)))
    assert len(held) >= len(res.epochs) - 1 and eng.flush() == []


# -- the wave gains in the model (pipeline._mounts._Track.solve) ------------------------------

def _synthetic_track(G_roll, G_pitch, seed=3, n=1200, noise_arcsec=8.0):
    """A _Track fed n epochs of d = s + G a + omega delta + e at 10 Hz (known answer)."""
    from shipstar.pipeline._mounts import _Track

    rng = np.random.default_rng(seed)
    s_true, delta_ms = np.array([3.0, -2.0, 4.0]), 3.0
    tr = _Track()
    for k in range(n):
        t = 0.1 * k
        a = np.array([5.0 * math.sin(2 * math.pi * t / 8.0), 2.0 * math.sin(2 * math.pi * t / 6.0 + 0.7)])
        omega = np.array([5.0 * 3600 * 2 * math.pi / 8 * math.cos(2 * math.pi * t / 8.0),
                          2.0 * 3600 * 2 * math.pi / 6 * math.cos(2 * math.pi * t / 6.0 + 0.7), 200.0]) * 1e-3
        y = s_true + np.asarray(G_roll) * a[0] + np.asarray(G_pitch) * a[1] + omega * delta_ms \
            + rng.normal(0, noise_arcsec, 3)
        tr.add(t, y, np.eye(3) / noise_arcsec ** 2, a, omega)
    return tr


def test_a_wave_gain_group_is_in_the_model_only_when_it_is_there():
    roll_only = _synthetic_track([4.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    assert roll_only.gains_used == [True, False]
    assert np.all(roll_only.theta[6:9] == 0.0) and np.all(roll_only.cov[6:9, :] == 0.0)
    assert roll_only.theta[3] == pytest.approx(4.0, abs=4 * math.sqrt(roll_only.cov[3, 3]))
    # the flexure at a pitched epoch: the model in use is closer to the truth than the full fit
    a = np.array([3.0, 2.0])
    full_phi = np.r_[np.eye(3), a[0] * np.eye(3), a[1] * np.eye(3)].T @ roll_only.theta_full[:9]
    used_phi, used_sig = roll_only.phi(a)
    true_phi = np.array([3.0 + 12.0, -2.0, 4.0])
    assert np.linalg.norm(used_phi - true_phi) < np.linalg.norm(full_phi - true_phi) + 0.05
    assert np.all(np.abs(used_phi - true_phi) < 4 * used_sig)
    both = _synthetic_track([4.0, 0.0, 0.0], [0.0, 3.0, 0.0])
    assert both.gains_used == [True, True]
    assert both.theta[7] == pytest.approx(3.0, abs=4 * math.sqrt(both.cov[7, 7]))
    assert abs(both.clock()[0] - 0.003) < 4 * both.clock()[1]


def test_the_applied_clock_offsets_uncertainty_travels_with_the_installation():
    """A shift of sigma_delta at deck rate omega turns the sensor's deck attitude by
    omega sigma_delta: the flexed installation carries omega omega^T sigma_delta^2."""
    from types import SimpleNamespace

    from shipstar.pipeline._mounts import MountEstimator, is_flexed
    from shipstar.units import ASEC2RAD

    tr = _synthetic_track([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    assert tr.clock_applied and tr.flex_applied                     # 3 ms; the static [3, -2, 4]''
    spec = sea_session(duration_s=1.0)
    configs = [SensorConfig(s.name, s.camera, Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor))
               for s in spec.sensors]
    est = MountEstimator(configs, 0)
    est._tracks[1] = tr
    fr_ref = SimpleNamespace(ship=SimpleNamespace(solved=True, roll_rad=0.0, pitch_rad=0.0))
    omega = np.array([0.07, 0.01, -0.02])                              # rad/s, deck axes (4 deg/s roll)
    a = np.zeros(2)
    with_rate = est.configs_for(fr_ref, omega)
    without = est.configs_for(fr_ref)
    assert is_flexed(with_rate[1]) and not is_flexed(with_rate[0])
    clock_term = with_rate[1].installation.mount_covariance_rad2 - without[1].installation.mount_covariance_rad2
    np.testing.assert_allclose(clock_term, np.outer(omega, omega) * 1e-6 * tr.cov[9, 9], rtol=1e-12)
    np.testing.assert_allclose(without[1].installation.mount_covariance_rad2, tr.phi_cov(a) * ASEC2RAD ** 2)
    np.testing.assert_array_equal(with_rate[1].installation.C_deck_from_sensor,
                                  without[1].installation.C_deck_from_sensor)
    sigma_arcsec = math.sqrt(float(omega @ clock_term @ omega) / float(omega @ omega)) / ASEC2RAD   # along omega
    assert sigma_arcsec == pytest.approx(math.sqrt(tr.cov[9, 9]) * 1e-3 * np.linalg.norm(omega) / ASEC2RAD)


def test_single_rows_of_a_sensor_with_an_applied_clock_offset_are_at_the_true_time(clock):
    """Once A2's clock offset is applied, A2's single-sensor CSV rows are stamped with the
    true exposure time (header + offset) and say so; their attitudes, which are of that
    time, then agree with the truth at it (at the header time they were off by the deck's
    rotation in 3 ms, up to ~40'')."""
    from shipstar.pipeline import attitude_csv_text
    from shipstar.pipeline._output import CLOCK_OFFSET_SUFFIX

    spec, res, _ = clock
    j1, j2 = res.start_utc_jd
    header_t_s = {fr.label: ((fr.utc_jd1 - j1) + (fr.utc_jd2 - j2)) * 86400.0 for fr in res.frames_of("A2")}
    applied_s = [e.mounts.time_offsets_s["A2"]["offset_s"] for e in res.epochs
                 if e.mounts.time_offsets_s["A2"]["applied"]]
    rows = list(csv.DictReader(line for line in io.StringIO(attitude_csv_text(res)) if not line.startswith("#")))
    singles = {s: [r for r in rows if r["method"] == "single" and r["sensor"] == s and r["solved"] == "1"]
               for s in ("A1", "A2")}
    assert not any(r["time_source"].endswith(CLOCK_OFFSET_SUFFIX) for r in singles["A1"])
    shifted = [r for r in singles["A2"] if r["time_source"].endswith(CLOCK_OFFSET_SUFFIX)]
    assert len(shifted) > 0.5 * len(singles["A2"])
    shifts = np.array([float(r["t_s"]) - header_t_s[r["frame"]] for r in shifted])
    assert np.all((shifts > min(applied_s) - 1e-6) & (shifts < max(applied_s) + 1e-6))   # the offset then
    assert np.median(shifts) == pytest.approx(0.003, abs=3e-4)

    def rms_err_arcsec(rs, t_s):
        K, psi, theta = spec.motion.angles_rad(np.asarray(t_s, float))
        est = np.radians([[float(r[c]) for c in ("heading_deg", "pitch_deg", "roll_deg")] for r in rs])
        err = np.angle(np.exp(1j * (est - np.stack([K, psi, theta], axis=1)))) * RAD2ASEC
        return np.sqrt(np.mean(err ** 2, axis=0))

    t_row = [float(r["t_s"]) for r in shifted]
    at_row = rms_err_arcsec(shifted, t_row)
    at_header = rms_err_arcsec(shifted, [header_t_s[r["frame"]] for r in shifted])
    # (A2's own heading error stays: the ship's heading hardly turns in 3 ms; pitch and roll do)
    assert np.hypot.reduce(at_header) > 15.0 and np.hypot.reduce(at_row) < 0.3 * np.hypot.reduce(at_header), \
        (at_row, at_header)
    a1 = rms_err_arcsec(singles["A1"], [float(r["t_s"]) for r in singles["A1"]])
    assert np.all(a1 < 10.0), a1                                     # the time origin is the truth's


# -- a resumed measure run: the estimator continues where it was --------------------------------

def _measure_job(conditions, smooth_lag_s):
    from shipstar.pipeline._measure import MeasureJob
    from shipstar.pipeline._sources import FrameListSource

    spec = apply_conditions(sea_session(duration_s=DURATION_S), load_conditions(conditions))
    cf = simulate_centroids(spec)
    track, weather, _ = tables(spec)
    configs = tuple(SensorConfig(s.name, s.camera, Installation.from_matrix(s.name, s.camera.name,
                                                                            s.C_deck_from_sensor))
                    for s in spec.sensors)
    job = MeasureJob(configs, track, weather, PipelineOptions(), spec.utc_jd(0.0), 0, smooth_lag_s)
    return job, [FrameListSource(s.name, frames_of(cf, s.name)) for s in spec.sensors]


@pytest.mark.parametrize("conditions, smooth_lag_s", [("clock", 0.0), ("flexure", 1.5)])
def test_a_resumed_run_writes_the_rows_of_an_uninterrupted_one(conditions, smooth_lag_s, tmp_path):
    """measure stopped after 6 s of 8 and resumed past 3.5 s (the 30 epochs the estimator
    needs to apply the clock offset or the flexure; with a lag, the epochs held for it send
    the resume back): the estimator's state comes back from the
    checkpoint, so the rows after the resume point are those of the uninterrupted run (a
    fresh estimator would go 30 epochs without the correction: tens of arcsec)."""
    import threading

    from shipstar.pipeline._measure import run_measure

    job, sources = _measure_job(conditions, smooth_lag_s)
    calls = []
    full = run_measure(job, sources, tmp_path / "full.csv", chunk_s=1.0, progress=lambda *a: calls.append(a))
    assert full.complete
    # the progress: frames done of all, after each chunk (it once showed a task's flag)
    assert calls == [(20 * (k + 1), 160) for k in range(8)]
    stop = threading.Event()
    got = run_measure(job, sources, tmp_path / "cut.csv", chunk_s=1.0, stop=stop,
                      progress=lambda done, total: stop.set() if done >= 0.75 * total else None)
    assert got.stopped and not got.complete
    resumed = run_measure(job, sources, tmp_path / "cut.csv", chunk_s=1.0, resume=True)
    assert resumed.complete and resumed.resumed_at_s >= 3.5
    assert (tmp_path / "cut.csv").read_text() == (tmp_path / "full.csv").read_text()


@pytest.mark.parametrize("name", ["clock", "flexure"])
def test_compiled_mount_step_matches_the_python_path(name, clock, flexure, monkeypatch):
    """pipeline._mounts._Track.add compiled (attitude._ckernels.mount_step, its own 10 x 10
    inverse) against its Python path (NumPy's LAPACK): the same decisions at every epoch
    (gates, applied clock offset and flexure, wave gains) and numbers to rounding."""
    import shipstar.pipeline._mounts as mounts

    _, compiled, _ = {"clock": clock, "flexure": flexure}[name]
    monkeypatch.setattr(mounts, "_COMPILED", [False])
    _, python, _ = _run(name)
    assert len(compiled.epochs) == len(python.epochs)
    for a, b in zip(compiled.epochs, python.epochs):
        fa, fb = a.mounts.flexure["A2"], b.mounts.flexure["A2"]
        for key in ("applied", "n_epochs", "n_gated", "wave_gains_in_model", "installation_drift"):
            assert fa[key] == fb[key], (a.index, key)
        assert a.mounts.time_offsets_s["A2"]["applied"] == b.mounts.time_offsets_s["A2"]["applied"]
        for x, y in ((a.mounts.time_offsets_s["A2"]["offset_s"], b.mounts.time_offsets_s["A2"]["offset_s"]),
                     *zip(fa["static_arcsec"].values(), fb["static_arcsec"].values())):
            assert (x is None and y is None) or x == pytest.approx(y, rel=1e-9, abs=1e-12)
        np.testing.assert_allclose(a.mounts.monitor[0][1], b.mounts.monitor[0][1], rtol=1e-9, atol=1e-9)
        ja = np.array([a.joint.heading_rad, a.joint.pitch_rad, a.joint.roll_rad])
        jb = np.array([b.joint.heading_rad, b.joint.pitch_rad, b.joint.roll_rad])
        np.testing.assert_allclose(ja, jb, rtol=0, atol=1e-12)          # 2e-7''
