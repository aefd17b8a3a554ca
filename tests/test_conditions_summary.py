"""Issue 14 item 4: availability by reason, the seeing estimate, the clock offsets and the
flexure monitor in the summary (``measure --json``) and the HTML report."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from shipstar.calibrate.installation import Installation
from shipstar.pipeline import PipelineOptions, SensorConfig, process_session, session_summary
from shipstar.pipeline._stats import _SensorStats
from shipstar.report import session_report
from shipstar.report._conditions_plot import (
    AVAILABILITY_ALT,
    MONITOR_ALT,
    monitor_series,
    monitor_series_from_csv,
    plot_availability,
    plot_mount_monitor,
)
from shipstar.simulate._conditions import apply_conditions, load_conditions
from shipstar.simulate._session import sea_session, simulate_centroids

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_ship_attitude import frames_of, tables  # noqa: E402


def _frame(solved, reason="", floor=math.nan):
    return SimpleNamespace(solved=solved, reason=reason, n_used=20, rms_arcsec=1.0, label="f", utc_iso="t",
                           streak_correction_arcsec=0.0, noise_floor_arcsec=floor)


def test_availability_counts_every_reason_and_the_seeing_median():
    st = _SensorStats()
    for f in [_frame(True, floor=1.5)] * 6 + [_frame(True, floor=1.0)] * 3 + [_frame(False, "clouded")] * 4 \
            + [_frame(False, "moon in field")] + [_frame(False, "only 3 stars identified"),
                                                  _frame(False, "only 4 stars identified")]:
        st.add(f)
    a = st.availability()
    assert a["n_frames"] == 16 and a["n_solved"] == 9 and a["solved_fraction"] == pytest.approx(9 / 16)
    assert a["unsolved_by_reason"] == {"clouded": 4, "only N stars identified": 2, "moon in field": 1}
    s = st.seeing()
    assert s["noise_floor_arcsec"] == pytest.approx(1.5, rel=2e-3) and s["noise_floor_last_arcsec"] == 1.0
    # the state continues (measure --resume)
    st2 = _SensorStats(json.loads(json.dumps(st.state())))
    st2.add(_frame(False, "only 7 stars identified"))
    assert st2.availability()["unsolved_by_reason"]["only N stars identified"] == 3
    assert st2.seeing() == s
    # at most 20 distinct failure reasons, the rest "other"
    st3 = _SensorStats()
    for k in range(25):
        st3.add(_frame(False, f"reason {chr(97 + k)}"))
    r = st3.availability()["unsolved_by_reason"]
    assert len(r) == 21 and r["other"] == 5


def test_plots_are_png_and_refuse_nothing():
    png = plot_availability({"A1": {"n_frames": 10, "n_solved": 7, "unsolved_by_reason": {"clouded": 3}},
                             "A2": {"n_frames": 10, "n_solved": 10, "unsolved_by_reason": {}}})
    assert png[:4] == b"\x89PNG"
    t = np.linspace(0, 5, 20)
    rot = np.c_[np.sin(t), np.cos(t), t]
    png = plot_mount_monitor({"A2": (t, rot, 0.1 + 0 * rot, 3 + 0 * t, 0.1 + 0 * t)}, reference="A1",
                             truth={"A2": (t, rot)})
    assert png[:4] == b"\x89PNG"
    with pytest.raises(Exception):
        plot_mount_monitor({})


@pytest.fixture(scope="module")
def realistic_session():
    """3 s centroid-level sea session under realistic.toml (clock offset, flexure, seeing)."""
    spec = apply_conditions(sea_session(duration_s=3.0), load_conditions("realistic"))
    cf = simulate_centroids(spec)
    track, weather, truth = tables(spec)
    configs = [SensorConfig(s.name, s.camera, Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor))
               for s in spec.sensors]
    res = process_session(configs, [frames_of(cf, s.name) for s in spec.sensors], track, weather, PipelineOptions())
    return res, truth


def test_summary_has_availability_and_seeing(realistic_session):
    res, truth = realistic_session
    s = session_summary(res, truth)
    cams = {x.name: x.camera for x in sea_session(duration_s=1.0).sensors}
    assert set(s["availability"]) == {"A1", "A2"}
    for name, a in s["availability"].items():
        assert a["n_frames"] == s["sensors"][name]["n_frames"]
        assert a["n_solved"] + sum(a["unsolved_by_reason"].values()) == a["n_frames"]
        cam = cams[name]                                               # never below the centroid floor
        floor_arcsec = PipelineOptions().centroid_floor_px * cam.pixel_mm / cam.f_mm * 180 / math.pi * 3600
        assert s["seeing"][name]["noise_floor_arcsec"] >= floor_arcsec * (1 - 1e-9)
    json.dumps(s, allow_nan=False)


def test_session_report_has_the_monitor_and_availability_figures(realistic_session, tmp_path):
    res, truth = realistic_session
    series = monitor_series(res)
    t, rot, sig, off, off_sig = series["A2"]
    assert len(t) == len(res.epochs) and np.isfinite(rot[-1]).all() and np.isfinite(off[-1])
    html = session_report(res, tmp_path / "r.html", truth=truth).read_text(encoding="utf-8")
    assert "Sky and mounts" in html
    assert f'alt="{AVAILABILITY_ALT}"' in html and f'alt="{MONITOR_ALT}"' in html
    assert "clock offset (ms)" in html and "seeing: noise floor" in html and "A2 vs A1" in html


def test_monitor_series_from_the_monitor_csv(realistic_session, tmp_path):
    from shipstar.pipeline._mounts import MONITOR_COLUMNS, monitor_rows

    res, _ = realistic_session
    p = tmp_path / "m.csv"
    p.write_text(",".join(MONITOR_COLUMNS) + "\n" + "".join(",".join(r) + "\n" for e in res.epochs
                                                               for r in monitor_rows(e)), encoding="utf-8")
    s = monitor_series_from_csv(p, res.start_utc_jd)
    ref = monitor_series(res)["A2"]
    np.testing.assert_allclose(s["A2"][0], ref[0], atol=1e-5)
    np.testing.assert_allclose(s["A2"][1], ref[1], atol=1e-3)
