"""shipstar.report: the HTML builder, the plot functions and the session report."""

from __future__ import annotations

import base64
import io
import math
import os
import re

import numpy as np
import pytest

from shipstar.errors import ShipstarError
from shipstar.report import (
    VERDICT_ID,
    Report,
    plot_attitude_errors,
    plot_frame_stars,
    plot_installation_histograms,
    plot_layout_sweep,
    plot_sky_chart,
    session_report,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _png_size(png: bytes) -> tuple[int, int]:
    from PIL import Image

    with Image.open(io.BytesIO(png)) as im:
        im.load()
        return im.size


def _tiny_png() -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGB", (3, 2), (10, 200, 30)).save(buf, format="PNG")
    return buf.getvalue()


# --------------------------------------------------------------------------------------
# The HTML builder
# --------------------------------------------------------------------------------------

def test_report_escapes_text_and_embeds_png_exactly():
    png = _tiny_png()
    r = Report("Ship <b>7</b> & co", subtitle="sub <i>")
    r.section("Results")
    r.paragraph("a < b")
    r.table(["method", "rms (\u2033)"], [["<joint>", "0.5"]])
    r.figure(png, "caption & more", "fig one")
    text = r.to_html()
    assert "Ship &lt;b&gt;7&lt;/b&gt; &amp; co" in text and "<b>7</b>" not in text
    assert "a &lt; b" in text and "&lt;joint&gt;" in text and "caption &amp; more" in text
    (data,) = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text)
    assert base64.b64decode(data) == png                     # embedded byte for byte
    assert f'<pre id="{VERDICT_ID}" hidden></pre>' in text
    assert "Figure 1. caption" in text


def test_report_is_self_contained():
    r = Report("t")
    r.section("a")
    r.section("b")
    r.figure(_tiny_png(), "c", "alt")
    text = r.to_html()
    assert not re.search(r"""(src|href)=["'](?!data:|#)""", text)   # only data URIs and in-page anchors
    assert "http://" not in text and "https://" not in text
    assert text.count('href="#s') == 2                      # contents lists both sections


def test_report_refuses_bad_blocks():
    r = Report("t")
    with pytest.raises(ShipstarError, match="row 0 has 1 cells, the header 2"):
        r.table(["a", "b"], [["1"]])
    with pytest.raises(ShipstarError, match="groups span 3 columns, the header 2"):
        r.table(["a", "b"], [["1", "2"]], groups=[("x", 3)])
    with pytest.raises(ShipstarError, match="not PNG data"):
        r.figure(b"GIF89a....", "c", "gif")


def test_report_write_is_atomic_and_follows_umask(tmp_path):
    r = Report("t")
    r.paragraph("hello")
    old = os.umask(0o022)
    try:
        path = r.write(tmp_path / "sub" / "r.html")
    finally:
        os.umask(old)
    assert path.read_text(encoding="utf-8") == r.to_html()
    assert (path.stat().st_mode & 0o777) == 0o644
    assert [p.name for p in path.parent.iterdir()] == ["r.html"]      # no temporary left behind
    (tmp_path / "file").write_text("x")
    with pytest.raises(ShipstarError, match="cannot write the report"):
        r.write(tmp_path / "file" / "r.html")


# --------------------------------------------------------------------------------------
# Plots
# --------------------------------------------------------------------------------------

def test_frame_stretch_puts_background_at_zero_and_stars_at_one():
    from shipstar.report._frame_plot import _stretch

    rng = np.random.default_rng(1)
    img = 100.0 + rng.normal(0.0, 3.0, (200, 200))
    img[100, 50] = 4000.0
    s = _stretch(img)
    assert s.min() >= 0.0 and s.max() == 1.0 and s[100, 50] == 1.0
    assert np.median(s) == 0.0                               # background below 1.5 sigma is black
    assert np.mean(s > 0) < 0.1


def test_plot_frame_stars_png_and_errors():
    img = np.full((64, 80), 100, np.uint16)
    img[10, 20] = 2000
    png = plot_frame_stars(img, detected_xy_px=[[20.0, 10.0], [5.0, 5.0]], identified_xy_px=[[20.0, 10.0]],
                           identified_hip=[32349], title="t")
    assert png[:8] == PNG_MAGIC and _png_size(png) == (720, 760)
    with pytest.raises(ShipstarError, match="2-D"):
        plot_frame_stars(np.zeros(5), detected_xy_px=[], identified_xy_px=[], identified_hip=[])
    with pytest.raises(ShipstarError, match="one entry per identified star"):
        plot_frame_stars(img, detected_xy_px=[], identified_xy_px=[[1.0, 2.0]], identified_hip=[])


def test_plot_sky_chart_png_and_errors():
    tracks = {"A1": np.array([[231.0, 40.0], [231.5, 41.0]]), "A2": np.array([[359.0, 35.0], [1.0, 36.0]])}
    foot = {"A1": np.array([[228.0, 37.0], [234.0, 37.0], [234.0, 43.0], [228.0, 43.0]])}
    png = plot_sky_chart(tracks_deg=tracks, footprints_deg=foot, stars_az_el_deg=[[10.0, 20.0], [100.0, -5.0]],
                         stars_mag=[1.0, 3.0], heading_deg=46.5, title="sky")
    assert png[:8] == PNG_MAGIC and _png_size(png) == (700, 700)
    with pytest.raises(ShipstarError, match="one entry per star"):
        plot_sky_chart(tracks_deg={}, footprints_deg={}, stars_az_el_deg=[[1.0, 2.0]], stars_mag=[])


def test_plot_installation_histograms():
    rng = np.random.default_rng(2)
    png = plot_installation_histograms({"A1": rng.normal(0, 1, (50, 3)), "B": rng.normal(0, 2, (30, 3))},
                                       seed_std_arcsec={"A1": (9.18, 5.89, 63.55)})
    assert _png_size(png) == (1050, 540)
    with pytest.raises(ShipstarError, match="no sensors"):
        plot_installation_histograms({})


def test_plot_attitude_errors_linear_and_symlog():
    t = np.linspace(0, 10, 101)
    e = np.column_stack([np.sin(t), np.cos(t), 0.1 * t])
    e[3] = np.nan
    big = e.copy()
    big[:10] *= 100.0
    for kw in ({}, {"linear_limit_arcsec": 2.0, "shade_s": (0.0, 1.0), "shade_label": "images"}):
        png = plot_attitude_errors([("joint", t, e), ("single A1", t, big)], **kw)
        assert _png_size(png) == (1050, 720)
    with pytest.raises(ShipstarError, match="no series"):
        plot_attitude_errors([])
    with pytest.raises(ShipstarError, match="linear_limit_arcsec must be > 0"):
        plot_attitude_errors([("joint", t, e)], linear_limit_arcsec=0.0)


def test_layout_log_axis_labels_are_plain_numbers():
    from shipstar.report._layout_plot import _tick_label

    labels = [_tick_label(v, 0) for v in (0.3, 0.4, 0.5, 1.0, 2.0, 6.0, 10.0, 20.0, 30.0, 40.0, 100.0, 0.0)]
    assert labels == ["0.3", "", "0.5", "1", "2", "", "10", "20", "30", "", "100", ""]


def test_plot_layout_sweep():
    x = np.linspace(-10, 10, 21)
    sig = np.column_stack([1 + 0.01 * x**2, np.full_like(x, 0.5), np.full_like(x, 2.0)])
    png = plot_layout_sweep(x, [("single A1", sig), ("joint", 0.5 * sig)],
                            measured=[("joint", np.array([-1.0, 1.0]), np.array([[0.6, 0.3, 1.1], [0.5, 0.2, 0.9]]))])
    assert _png_size(png) == (1100, 440)
    with pytest.raises(ShipstarError, match="nothing to plot"):
        plot_layout_sweep(x, [])


# --------------------------------------------------------------------------------------
# The session report, on a short real session (centroid level, two sensors)
# --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def short_session():
    from shipstar.calibrate.installation import Installation
    from shipstar.pipeline import Frame, SensorConfig, Track, TruthTable, WeatherTable, process_session
    from shipstar.simulate._session import sea_session, simulate_centroids
    from shipstar.units import RAD2DEG

    spec = sea_session(duration_s=1.0, temperature_rate_c_per_s=0.0, pressure_rate_hpa_per_s=0.0, seed=5)
    cf = simulate_centroids(spec)
    t = np.arange(-1.0, 3.0, 1.0)
    lat, lon, h = spec.motion.position(t)
    jd = np.array([spec.utc_jd(x) for x in t])
    track = Track.from_arrays(jd[:, 0], jd[:, 1], lat * RAD2DEG, lon * RAD2DEG, h)
    weather = WeatherTable.constant(spec.pressure_hpa, spec.temperature_c)
    configs = [SensorConfig(s.name, s.camera, Installation(s.name, s.camera.name, s.install_az_rad,
                                                           s.install_el_rad, s.install_roll_rad))
               for s in spec.sensors]
    frames = [[Frame.from_centroids(c.utc_jd1, c.utc_jd2, c.xy_px, c.hip, f"#{c.index}") for c in cf[s.name]]
              for s in spec.sensors]
    result = process_session(configs, frames, track, weather)
    tt = spec.times_s(spec.sensors[0])
    K, psi, theta = spec.motion.angles_rad(tt)
    jdt = np.array([spec.utc_jd(x) for x in tt])
    truth = TruthTable.from_arrays(jdt[:, 0], jdt[:, 1], K * RAD2DEG, psi * RAD2DEG, theta * RAD2DEG)
    return spec, result, truth


def _table_rows(text: str) -> dict:
    rows = {}
    for tr in re.findall(r"<tr>(.*?)</tr>", text):
        cells = re.findall(r"<td[^>]*>(.*?)</td>", tr)
        if cells:
            rows[cells[0]] = cells[1:]
    return rows


def test_session_report_rms_against_an_independent_truth(short_session, tmp_path):
    from shipstar.frames import wrap_pi
    from shipstar.units import RAD2ASEC

    spec, result, truth = short_session
    path = session_report(result, tmp_path / "s.html", truth=truth, title="short")
    text = path.read_text(encoding="utf-8")
    rows = _table_rows(text)
    # joint RMS straight from the simulated motion (no pipeline statistics involved)
    err = []
    for e in result.epochs:
        assert e.joint.solved
        K, psi, theta = spec.motion.angles_rad(e.t_s)
        err.append(wrap_pi(np.array([e.joint.heading_rad - K, e.joint.pitch_rad - psi,
                                     e.joint.roll_rad - theta])) * RAD2ASEC)
    rms = np.sqrt(np.mean(np.square(err), axis=0))
    assert rows["joint"][0] == f"{len(result.epochs)}/{len(result.epochs)}"
    assert [float(x) for x in rows["joint"][4:7]] == pytest.approx(rms, abs=0.006)
    assert rows["A1"][:3] == ["10", "10", "0"]                # frames, solved, failed
    assert text.count("data:image/png;base64,") == 3 and "attitude errors" in text    # + availability, monitor


def test_session_report_without_truth_compares_with_joint(short_session, tmp_path):
    _, result, _ = short_session
    text = session_report(result, tmp_path / "s.html").read_text(encoding="utf-8")
    assert 'alt="methods minus joint"' in text and "RMS heading" not in text
    from shipstar.report._session import _methods, _minus_joint

    diffs = _minus_joint(result, _methods(result))
    assert [n for n, _, _ in diffs] == ["single A1", "single A2", "seed rule"]
    for _, _, d in diffs:
        assert np.all(np.isfinite(d)) and np.max(np.abs(d)) < 60.0   # arcsec: same ship, same epoch


def test_import_shipstar_report_is_cheap():
    import subprocess
    import sys

    code = "import sys, shipstar.report; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_numbers_are_finite_in_the_demo_table_helpers():
    from shipstar._demo._table import _f, seed_rms_arcsec

    assert _f(math.nan) == "       -" and _f(1.234) == "    1.23" and _f(-0.004) == "    0.00"
    assert _f(-0.006) == "   -0.01"
    assert seed_rms_arcsec("seed rule") == (8.47, 7.16, 5.12)
    assert seed_rms_arcsec("single A2") == (50.38, 74.12, 4.42) and seed_rms_arcsec("joint") is None
