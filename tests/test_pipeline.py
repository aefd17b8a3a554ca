"""Session pipeline: inputs, per-frame chain, motion compensation, fusion, outputs."""

from __future__ import annotations

import csv
import io
import math
import sys
from dataclasses import replace

import numpy as np
import pytest

from shipstar import frames as F
from shipstar.calibrate.installation import Installation
from shipstar.errors import ShipstarError
from shipstar.pipeline import (
    ATTITUDE_COLUMNS,
    Frame,
    PipelineOptions,
    SensorConfig,
    Track,
    TruthTable,
    WeatherTable,
    attitude_csv_text,
    plot_session,
    process_sensor,
    process_session,
    rms_arcsec,
    scan_frames,
    session_summary,
)
from shipstar.simulate._session import dock_session, sea_session, simulate_centroids
from shipstar.units import ASEC2RAD, DAY_S, DEG2RAD, RAD2ASEC, RAD2DEG


# -- helpers -------------------------------------------------------------------------------

def _true_configs(spec):
    return [SensorConfig(s.name, s.camera, Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor))
            for s in spec.sensors]


def _frames(centroids, spec):
    return [[Frame.from_centroids(f.utc_jd1, f.utc_jd2, f.xy_px, f.hip, f"{s.name}_{f.index:03d}")
             for f in centroids[s.name]] for s in spec.sensors]


def _image_sea_session(duration_s, exposure_s):
    """An image-level sea session rendered in memory: ``(frames per sensor, track, weather,
    truth, configs)``, the configs' cameras set to ``exposure_s`` and the true installations."""
    from shipstar.simulate._session import _sensor_frame, sea_session

    spec = sea_session(duration_s=duration_s, exposure_s=exposure_s)
    frames = [[Frame(sim.utc_jd1, sim.utc_jd2, f"{s.name}_{k:04d}", image=sim.image, exposure_s=exposure_s)
               for k, t in enumerate(spec.times_s(s)) for sim in [_sensor_frame(spec, s, k, float(t))]]
              for s in spec.sensors]
    track, weather, truth = _tables(spec)
    configs = [c.__class__(c.name, c.camera.replace(exposure_s=exposure_s), c.installation)
               for c in _true_configs(spec)]
    return spec, frames, track, weather, truth, configs


def _tables(spec):
    """Track, weather and truth tables of a simulated session, sampled from its model."""
    j1, j2 = spec.utc_jd(0.0)
    tt = np.arange(-1.0, spec.duration_s + 2.0, 0.5)
    lat, lon, h = spec.motion.position(tt)
    track = Track.from_arrays(np.full(len(tt), j1), j2 + tt / DAY_S, lat * RAD2DEG, lon * RAD2DEG, h)
    w = [spec.weather(t) for t in tt]
    weather = WeatherTable("weather", j1, j2 + tt[0] / DAY_S, tt - tt[0], np.array([x.pressure_hpa for x in w]),
                           np.array([x.temperature_c for x in w]), np.zeros(len(tt)))
    times = np.unique(np.concatenate([spec.times_s(s) for s in spec.sensors]))
    K, psi, theta = spec.motion.angles_rad(times)
    truth = TruthTable.from_arrays(np.full(len(times), j1), j2 + times / DAY_S, K * RAD2DEG, psi * RAD2DEG,
                                   theta * RAD2DEG)
    return track, weather, truth


def _sea(offset_s=0.0, duration_s=8.0, seed=0):
    spec = sea_session(duration_s=duration_s, seed=seed)
    spec = spec.replace(sensors=(spec.sensors[0], replace(spec.sensors[1], time_offset_s=offset_s)))
    return spec, simulate_centroids(spec)


@pytest.fixture(scope="module")
def sea():
    return _sea()


@pytest.fixture(scope="module")
def sea_result(sea):
    spec, cf = sea
    track, weather, truth = _tables(spec)
    return spec, process_session(_true_configs(spec), _frames(cf, spec), track, weather), truth


def _rms(summary, method):
    return np.array(summary["methods"][method]["rms_arcsec"])


# -- tables --------------------------------------------------------------------------------

def test_track_interpolates_linearly_and_refuses_extrapolation(tmp_path):
    p = tmp_path / "track.csv"
    p.write_text("time_utc,lat_deg,lon_deg,height_m\n2013-03-15T12:16:00,31.0,179.9995,10\n"
                 "2013-03-15T12:16:10Z,31.001,-179.9995,20\n")                # 146 m in 10 s: a ship
    tr = Track.read_csv(p)
    from shipstar.sky.time import utc_jd_from_iso

    site = tr.site(*utc_jd_from_iso("2013-03-15T12:16:02.5"))
    assert site.lat_rad * RAD2DEG == pytest.approx(31.00025, abs=1e-9)
    assert site.lon_rad * RAD2DEG == pytest.approx(179.99975, abs=1e-9)      # across the date line
    assert site.height_m == pytest.approx(12.5)
    assert tr.site(*utc_jd_from_iso("2013-03-15T12:16:11")).height_m == 20.0    # 1 s after the last row: held
    with pytest.raises(ShipstarError, match="outside the track"):
        tr.site(*utc_jd_from_iso("2013-03-15T12:16:11.1"))
    fixed = Track.fixed(31.9, 120.3)
    assert fixed.site(0.0, 2456367.0).lat_rad == pytest.approx(31.9 * DEG2RAD)
    # a spreadsheet's UTF-8 byte-order mark: the same track (was "missing column 'time_utc'")
    p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes())
    assert Track.read_csv(p).site(*utc_jd_from_iso("2013-03-15T12:16:02.5")).lat_rad == site.lat_rad


@pytest.mark.parametrize("text, message", [
    ("time_utc,lat_deg\n2013-03-15T12:16:00,1\n", "missing column 'lon_deg'"),
    ("time_utc,lat_deg,lon_deg\n2013-03-15T12:16:00,1,nan\n", "must be finite"),
    ("time_utc,lat_deg,lon_deg\n2013-03-15T12:16:00,1,x\n", "not a number"),
    ("time_utc,lat_deg,lon_deg\n2013-03-15T12:16:01,1,2\n2013-03-15T12:16:00,1,2\n", "increase strictly"),
    ("time_utc,lat_deg,lon_deg\nnoon,1,2\n", "line 2"),
    ("time_utc,lat_deg,lon_deg\n2013-03-15T12:16:00,95,2\n", "latitude"),
])
def test_bad_track_files(tmp_path, text, message):
    p = tmp_path / "t.csv"
    p.write_text(text)
    with pytest.raises(ShipstarError, match=message):
        Track.read_csv(p)


def test_weather_table(tmp_path):
    p = tmp_path / "w.csv"
    p.write_text("time_utc,pressure_hpa,temperature_c\n2013-03-15T12:16:00,1020,10\n2013-03-15T12:16:10,1022,12\n")
    from shipstar.sky.time import utc_jd_from_iso

    w = WeatherTable.read_csv(p).weather(*utc_jd_from_iso("2013-03-15T12:16:05"))
    assert (w.pressure_hpa, w.temperature_c, w.relative_humidity) == pytest.approx((1021.0, 11.0, 0.0))
    p.write_text("time_utc,pressure_hpa,temperature_c\n2013-03-15T12:16:00,1020,nan\n")
    with pytest.raises(ShipstarError, match="finite"):
        WeatherTable.read_csv(p)
    p.write_text("time_utc,pressure_hpa,temperature_c\n2013-03-15T12:16:00,5000,10\n")
    with pytest.raises(ShipstarError, match="pressure_hpa"):
        WeatherTable.read_csv(p)
    with pytest.raises(ShipstarError):
        WeatherTable.constant(float("nan"), 10.0)


# -- frames on disk ------------------------------------------------------------------------

def _write_fits(path, date_obs=None, data=None, exptime_s=0.08):
    from astropy.io import fits

    hdu = fits.PrimaryHDU(np.zeros((16, 16), np.uint16) if data is None else data)
    if date_obs is not None:
        hdu.header["DATE-OBS"] = date_obs
    if exptime_s is not None:
        hdu.header["EXPTIME"] = exptime_s
    hdu.writeto(path)


def test_a_frames_prior_and_site_are_worked_out_once_and_follow_the_history(sea):
    """The prior asked again for the same time and history is the same read-only array; a new
    solved frame gives the new extrapolation (not the remembered one); the site is the
    track's at each frame's time."""
    from shipstar import frames as F
    from shipstar.pipeline._sensor import SensorProcessor, extrapolate_rotation

    spec, _ = sea
    track, weather, _ = _tables(spec)
    proc = SensorProcessor(_true_configs(spec)[0], track, weather, PipelineOptions())
    C0 = np.eye(3)
    C1 = F.rot_z(0.004) @ F.rot_x(0.002)
    C2 = C1 @ F.rot_y(0.003) @ F.rot_z(-0.001)
    proc._history = [(0.0, C0), (0.1, C1)]
    first = proc._prior(0.2)
    assert proc._prior(0.2) is first and not first.flags.writeable
    np.testing.assert_array_equal(first, extrapolate_rotation(C0, C1, (0.2 - 0.1) / (0.1 - 0.0)))
    proc._history = proc._history[-1:] + [(0.2, C2)]            # as _identify appends a solved frame
    again = proc._prior(0.2)
    np.testing.assert_array_equal(again, extrapolate_rotation(C1, C2, 0.0))
    assert not np.array_equal(again, first)
    np.testing.assert_array_equal(proc._prior(0.3), extrapolate_rotation(C1, C2, (0.3 - 0.2) / (0.2 - 0.1)))
    for k in (0, 1, 1, 2):
        frame = Frame(track.jd1_0, track.jd2_0 + 0.1 * k / DAY_S, f"f{k}", xy_px=np.zeros((0, 2)))
        assert proc._site(frame) == track.site(frame.utc_jd1, frame.utc_jd2)


def test_scan_frames_reads_times_and_checks_order(tmp_path):
    from shipstar.sky.time import utc_jd_from_iso

    _write_fits(tmp_path / "f0.fits", "2013-03-15T12:16:00.000")
    _write_fits(tmp_path / "f1.fits", "2013-03-15T12:16:00.100")
    (tmp_path / "notes.txt").write_text("x")
    frames = scan_frames(tmp_path)
    assert [f.label for f in frames] == ["f0.fits", "f1.fits"]
    assert frames[1].seconds_since(frames[0].utc_jd1, frames[0].utc_jd2) == pytest.approx(0.1, abs=1e-6)
    # DATE-OBS is the start of the exposure (FITS standard): the time tag is 40 ms later
    assert frames[0].seconds_since(*utc_jd_from_iso("2013-03-15T12:16:00")) == pytest.approx(0.04, abs=1e-9)
    assert frames[0].time_source == "DATE-OBS+EXPTIME/2" and frames[0].exposure_s == 0.08
    assert frames[0].utc_iso == "2013-03-15T12:16:00.040000Z"
    mid = scan_frames(tmp_path, date_obs_is="mid")
    assert mid[0].seconds_since(*utc_jd_from_iso("2013-03-15T12:16:00")) == pytest.approx(0.0, abs=1e-9)
    assert mid[0].time_source == "DATE-OBS(mid)"
    _write_fits(tmp_path / "f2.fits", "2013-03-15T12:16:00.050")
    with pytest.raises(ShipstarError, match="out of time order: f2.fits"):
        scan_frames(tmp_path)


@pytest.mark.parametrize("exptime_s, overlap", [(2.0, True), (0.5, True), (0.1, False), (0.08, False), (None, False)])
def test_scan_frames_refuses_exposures_that_overlap(tmp_path, exptime_s, overlap):
    """An EXPTIME longer than the frames' spacing cannot be one camera's (a bad-input sweep:
    EXPTIME = 2 on 10 Hz frames with DATE-OBS alone moved every frame's time by 1 s,
    exit 0); one exposure ending as the next begins (video: 0.1 s at 10 Hz) is not."""
    for k in range(3):
        _write_fits(tmp_path / f"f{k}.fits", f"2013-03-15T12:16:00.{k}00", exptime_s=exptime_s)
    if overlap:
        with pytest.raises(ShipstarError, match=rf"frames f0.fits and f1.fits: their exposures \({exptime_s:g} "
                                                rf"and {exptime_s:g} s, EXPTIME\) overlap, their mid-exposures 0.1 s "
                                                "apart"):
            scan_frames(tmp_path)
    elif exptime_s is None:
        with pytest.raises(ShipstarError, match="EXPTIME"):                 # no time without it: as before
            scan_frames(tmp_path)
        assert len(scan_frames(tmp_path, date_obs_is="mid")) == 3
    else:
        assert len(scan_frames(tmp_path)) == 3


def test_frame_paths_are_in_the_order_of_sorted_paths(tmp_path):
    """The name-keyed sort gives the order ``sorted`` gives the Path objects themselves (the
    reference), for names of mixed lengths, cases, digits and punctuation, made in a
    shuffled order."""
    import random

    from shipstar.pipeline._frames import frame_paths, in_name_order

    names = ["A1_0010.fits", "A1_0002.fits", "A1_01.fits", "a1_0003.fits", "B.fits", "A1-0004.fits",
             "A1_0002.fit", "A1_0002.fits.gz", "Z.fts", "A1_000 5.fits", "\u00e9.fits", "_x.fits", "10.fits", "9.fits"]
    random.Random(7).shuffle(names)
    for name in names:
        (tmp_path / name).write_bytes(b"")
    (tmp_path / "notes.txt").write_text("x")
    listed = list(tmp_path.iterdir())
    assert in_name_order(listed) == sorted(listed)
    assert in_name_order(reversed(sorted(listed))) == sorted(listed)
    assert frame_paths(tmp_path) == sorted(p for p in listed if p.suffix != ".txt")


def test_scan_frames_reports_its_progress_block_by_block(tmp_path, monkeypatch):
    """The index read in blocks for its progress gives the frames of the one-block read, and
    a bad header stops it at the same frame with the same error (no block read after it)."""
    import shipstar.pipeline._frames as frames_module

    for k in range(5):
        _write_fits(tmp_path / f"f{k}.fits", f"2013-03-15T12:16:00.{k}00")
    whole = scan_frames(tmp_path)
    monkeypatch.setattr(frames_module, "PROGRESS_BLOCK_FILES", 2)
    calls = []
    blocks = scan_frames(tmp_path, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(2, 5), (4, 5), (5, 5)]
    assert [(f.label, f.utc_jd1, f.utc_jd2, f.time_source) for f in blocks] == \
        [(f.label, f.utc_jd1, f.utc_jd2, f.time_source) for f in whole]
    (tmp_path / "f2.fits").unlink()
    _write_fits(tmp_path / "f2.fits", None)                   # f2 has no DATE-OBS now
    with pytest.raises(ShipstarError) as one:
        scan_frames(tmp_path)
    calls.clear()
    read, original = [], frames_module.read_header_block
    monkeypatch.setattr(frames_module, "read_header_block",
                        lambda paths, date_obs_is: read.append([p.name for p in paths]) or original(paths, date_obs_is))
    with pytest.raises(ShipstarError) as blockwise:
        scan_frames(tmp_path, progress=lambda done, total: calls.append((done, total)))
    assert str(blockwise.value) == str(one.value) and "f2.fits has no DATE-OBS" in str(one.value)
    assert calls == [(2, 5)] and read == [["f0.fits", "f1.fits"], ["f2.fits", "f3.fits"]]


def test_reading_ahead_keeps_the_frames_their_order_and_its_pace(tmp_path, monkeypatch):
    """``read_ahead`` yields the very items it is given, in order, taking each from its source
    at most ``depth`` items early (a generator is not drained: a night's merged frames are not
    all listed at once); frames in memory pass through, a file that is gone is left to its
    read to report.  The index read with its headers asked ahead is the index read without."""
    import shipstar.pipeline._frames as frames_module
    from shipstar._fitsio import advise_will_read
    from shipstar.pipeline._frames import read_ahead, read_header_block

    for k in range(7):
        _write_fits(tmp_path / f"f{k}.fits", f"2013-03-15T12:16:00.{k}00")
    frames = list(scan_frames(tmp_path))
    frames[3] = replace(frames[3], path=None, image=np.zeros((4, 4)))            # in memory
    frames[5] = replace(frames[5], path=tmp_path / "gone.fits")                  # no such file
    for depth in (0, 1, 2, 10):
        taken = []

        def source():
            for f in frames:
                taken.append(f)
                yield f

        out = []
        for f in read_ahead(source(), depth):
            assert len(taken) == min(len(out) + 1 + depth, len(frames))          # its pace
            out.append(f)
        assert len(out) == len(frames) and all(a is b for a, b in zip(out, frames))
    items = [(0.1 * k, k % 2, k, f) for k, f in enumerate(frames)]
    assert list(read_ahead(iter(items), frame_of=lambda item: item[3])) == items
    for path in (None, tmp_path / "gone.fits", tmp_path):                        # nothing to advise: no error
        advise_will_read(path)
    paths = sorted(tmp_path.glob("f*.fits")) + [tmp_path / "gone.fits"]
    ahead_infos, ahead_error = read_header_block(paths)
    monkeypatch.setattr(frames_module, "INDEX_READ_AHEAD_FILES", 0)
    infos, error = read_header_block(paths)
    assert [(i.name, i.utc_jd1, i.utc_jd2) for i in ahead_infos] == [(i.name, i.utc_jd1, i.utc_jd2) for i in infos]
    assert len(infos) == 7 and str(ahead_error) == str(error) and "gone.fits" in str(error)


def test_scan_frames_bad_input(tmp_path):
    with pytest.raises(ShipstarError, match="not a directory"):
        scan_frames(tmp_path / "missing")
    with pytest.raises(ShipstarError, match="no FITS frames"):
        scan_frames(tmp_path)
    _write_fits(tmp_path / "a.fits")
    with pytest.raises(ShipstarError, match="a.fits has no DATE-OBS"):
        scan_frames(tmp_path)
    (tmp_path / "a.fits").unlink()
    _write_fits(tmp_path / "a.fits", "yesterday")
    with pytest.raises(ShipstarError, match="DATE-OBS"):
        scan_frames(tmp_path)
    (tmp_path / "a.fits").unlink()
    _write_fits(tmp_path / "a.fits", "2013-03-15T12:16:00", exptime_s=None)    # start, but how long?
    with pytest.raises(ShipstarError, match="a.fits: DATE-OBS is the start of the exposure .* no EXPTIME"):
        scan_frames(tmp_path)
    assert scan_frames(tmp_path, date_obs_is="mid")[0].time_source == "DATE-OBS(mid)"
    (tmp_path / "a.fits").write_bytes(b"SIMPLE  = garbage")
    with pytest.raises(ShipstarError, match="a.fits"):
        scan_frames(tmp_path)


def test_frame_validation():
    with pytest.raises(ShipstarError, match="no data"):
        Frame(2456367.0, 0.0, "x")
    with pytest.raises(ShipstarError, match="hip"):
        Frame.from_centroids(2456367.0, 0.0, np.zeros((3, 2)), hip=[1, 2])


def test_frames_out_of_order_in_a_session():
    spec = dock_session(duration_s=0.3)
    cf = simulate_centroids(spec)
    frames = _frames(cf, spec)[0][::-1]
    track, weather, _ = _tables(spec)
    with pytest.raises(ShipstarError, match="out of time order"):
        process_sensor(SensorConfig("A1", spec.sensors[0].camera), frames, track, weather)


def test_frames_outside_the_track_are_refused():
    spec = dock_session(duration_s=0.3)
    cf = simulate_centroids(spec)
    j1, j2 = spec.utc_jd(0.0)
    short = Track.from_arrays([j1, j1], [j2 - 3.0 / DAY_S, j2 - 2.0 / DAY_S], [31.9, 31.9], [120.3, 120.3])
    with pytest.raises(ShipstarError, match="outside the track"):                  # frames > 1 s after its end
        process_sensor(SensorConfig("A1", spec.sensors[0].camera), _frames(cf, spec)[0], short,
                       WeatherTable.constant(1021.7, 11.1))


def test_sensor_config_mismatches():
    spec = dock_session(duration_s=0.1)
    a1, a2 = spec.sensors
    inst2 = Installation.from_matrix("A2", "A2", a2.C_deck_from_sensor)
    with pytest.raises(ShipstarError, match="installation for sensor 'A2' given for sensor 'A1'"):
        SensorConfig("A1", a1.camera, inst2)
    with pytest.raises(ShipstarError, match="calibrated with camera 'A2'"):
        SensorConfig("A2", a1.camera, inst2)
    with pytest.raises(ShipstarError, match="refraction model"):
        PipelineOptions(refraction_model="fast")
    with pytest.raises(ShipstarError, match="max_pair_offset_s"):
        PipelineOptions(max_pair_offset_s=float("nan"))


# -- per-frame chain -------------------------------------------------------------------------

def test_image_frames_extract_identify_and_solve():
    """Image level: rendered dock frames through extraction, lost-in-space then tracking."""
    from shipstar.simulate import ShipPose, simulate_frame
    from shipstar.sky.apparent import Site
    from shipstar.sky.refraction import Weather

    spec = dock_session()
    s = spec.sensor("A1")
    pose = ShipPose(spec.motion.heading0_rad, 0.0, 0.0, s.install_az_rad, s.install_el_rad, s.install_roll_rad)
    frames, truth = [], []
    for k in range(3):
        sf = simulate_frame(s.camera, ship=pose, utc_iso=spec.utc_iso(0.1 * k), site=Site.from_deg(31.9, 120.3),
                            weather=Weather(1021.7, 11.1), refraction_model="erfa", seed=k)
        frames.append(Frame(sf.utc_jd1, sf.utc_jd2, f"img{k}", image=sf.image))
        truth.append(sf.C_hor_from_sensor)
    res = process_sensor(SensorConfig("A1", s.camera), frames, Track.fixed(31.9, 120.3),
                         WeatherTable.constant(1021.7, 11.1))
    assert [r.identification for r in res] == ["lost_in_space", "tracking", "tracking"]
    for r, C in zip(res, truth):
        assert r.solved and r.n_identified >= 30
        assert np.all(np.isfinite(r.C_icrs_from_sensor))
        err = F.rotation_angle_rad(r.C_hor_from_sensor.T @ C) * RAD2ASEC
        assert err < 3.0                    # roll about the boresight; bore pointing far better
        assert abs(r.C_hor_from_sensor[:, 0] @ C[:, 0] - 1.0) < (0.5 * ASEC2RAD) ** 2
        assert not r.ship.solved and "no installation" in r.ship.reason


def test_a_frame_that_fails_is_reported_not_dropped():
    spec = dock_session(duration_s=0.5)
    cf = simulate_centroids(spec)
    frames = _frames(cf, spec)
    bad = frames[1][2]
    frames[1][2] = Frame.from_centroids(bad.utc_jd1, bad.utc_jd2, bad.xy_px[:1], bad.hip[:1], bad.label)
    track, weather, _ = _tables(spec)
    res = process_session(_true_configs(spec), frames, track, weather)
    fr = res.frames_of("A2")[2]
    assert not fr.solved and "identified stars" in fr.reason and not fr.ship.solved
    assert res.failures == [("A2", bad.label, fr.reason)]
    e = res.epochs[2]
    assert not e.joint.solved and not e.seed_rule.solved and bad.label in e.joint.reason
    summary = session_summary(res)
    assert summary["sensors"]["A2"]["n_failed"] == 1
    assert summary["sensors"]["A2"]["failures"][0]["frame"] == bad.label
    assert summary["methods"]["joint"]["n_solved"] == 4
    rows = list(csv.DictReader(io.StringIO(attitude_csv_text(res))))
    failed = [r for r in rows if r["solved"] == "0"]
    assert len(failed) == 3 and all(r["reason"] for r in failed)
    assert {r["method"] for r in failed} == {"single", "seed-rule", "joint"}


# -- motion compensation ---------------------------------------------------------------------

def _motion_window(m, t_end, offset_s=0.03):
    """A MotionWindow of two sensors' noise-free deck attitudes at 10 frames/s (the second
    ``offset_s`` later) up to ``t_end``."""
    from shipstar.pipeline import MotionWindow

    window = MotionWindow(2)
    cov = np.eye(3) * (0.3 * ASEC2RAD) ** 2
    for t in np.arange(0.0, t_end + 1e-9, 0.1):
        window.add(0, t, m.C_hor_from_deck(t), cov)
        window.add(1, t + offset_s, m.C_hor_from_deck(t + offset_s), cov)
    return window


def test_deck_motion_fitted_causally_to_noise_free_attitudes():
    """The deck's motion from the last 0.8 s of attitudes, nothing later: the carry over
    30 ms within 0.1'' of the true rotation (0.08'' at worst over 11 s), the rate at the
    newest frame within 2e-5 rad/s (4''/s) and the acceleration within 1e-3 rad/s^2
    (0.06'' on an 80 ms streak) at the seeds' sea state (up to 4 deg/s, 3.8 deg/s^2)."""
    m = sea_session().motion
    peak = max(np.linalg.norm(_alpha_deck(m, t)) for t in np.arange(0, 4, 0.05))
    assert peak > 3.0 * DEG2RAD
    for t in (1.0, 2.0, 2.4, 3.9):
        window = _motion_window(m, t)
        fit = window.fit([t, t + 0.03])                              # the paired frame 30 ms later
        exact = m.C_hor_from_deck(t + 0.03).T @ m.C_hor_from_deck(t)
        assert F.rotation_angle_rad(fit.rotation(t + 0.03, t).T @ exact) * RAD2ASEC < 0.1
        own = window.fit(t, sources=[0])                             # one sensor, at its newest frame
        np.testing.assert_allclose(own.omega_at(t), m.omega_deck_rad_per_s(t), atol=2e-5)
        np.testing.assert_allclose(own.alpha_at(t), _alpha_deck(m, t), atol=1e-3)
        assert own.t_last_s == pytest.approx(t) and own.t_first_s == pytest.approx(t - 0.8)


def test_motion_fit_needs_five_attitudes_and_forgets_old_ones():
    from shipstar.pipeline import MotionWindow, fit_motion

    m = sea_session().motion
    t = np.arange(0.0, 1.0, 0.1)
    cov = np.tile(np.eye(3) * (0.3 * ASEC2RAD) ** 2, (len(t), 1, 1))
    assert fit_motion(t[:4], m.C_hor_from_deck(t[:4]), cov[:4]) is None
    assert [fit_motion(t[:n], m.C_hor_from_deck(t[:n]), cov[:n]).degree for n in (5, 6, 7, 8, 9, 10)] == \
        [2, 2, 3, 3, 4, 4]                                                    # half as many coefficients
    window = _motion_window(m, 5.0)
    window.prune(5.0)
    assert len(window) == 18                                                  # 4.2..5.0 s, both sensors
    assert MotionWindow(2).fit(1.0) is None


# -- acceptance: fusion at sea ---------------------------------------------------------------

def test_joint_fusion_beats_the_seed_rule_at_sea(sea_result):
    """Seed 003: heading from the mean of two headings, pitch from the fore-aft sensor, roll from
    the athwartship one.  The joint solution must beat it on heading and match or beat it on
    pitch and roll; single sensors show the seed's pattern (A1 good pitch, A2 good roll)."""
    spec, res, truth = sea_result
    s = session_summary(res, truth)
    assert res.fore_aft_sensor == "A1" and res.athwartship_sensor == "A2"
    single1, single2 = _rms(s, "single:A1"), _rms(s, "single:A2")
    seed, joint = _rms(s, "seed-rule"), _rms(s, "joint")
    assert single1[1] < single1[0] / 3 and single2[2] < single2[1] / 3
    assert joint[0] < seed[0] / 2
    assert joint[1] <= seed[1] * 1.05 and joint[2] <= seed[2] * 1.05
    assert np.all(joint < 1.0)
    for m in ("single:A1", "single:A2", "seed-rule", "joint"):
        b = s["methods"][m]
        assert b["n_solved"] == b["n"] == 80
        # formal sigma agrees with the actual scatter (covariance propagation is right)
        np.testing.assert_allclose(b["median_sigma_arcsec"], b["rms_arcsec"], rtol=0.35)


def test_thirty_ms_offset_is_compensated():
    spec, cf = _sea(offset_s=0.03)
    track, weather, truth = _tables(spec)
    configs, frames = _true_configs(spec), _frames(cf, spec)
    comp = session_summary(process_session(configs, frames, track, weather), truth)
    raw = session_summary(process_session(configs, frames, track, weather, PipelineOptions(compensate_motion=False)),
                          truth)
    assert np.all(_rms(comp, "joint") < 0.8)
    assert np.all(_rms(comp, "seed-rule")[1:] < 1.0)
    assert np.max(_rms(raw, "joint")) > 50.0 and _rms(raw, "seed-rule")[2] > 100.0
    assert max(abs(o) for e in process_session(configs, frames, track, weather).epochs for o in e.offset_s) \
        == pytest.approx(0.03, abs=1e-6)


def test_per_star_refraction_beats_boresight_only(sea):
    """Seed 000 Tab. 4 (A2: boresight-only 73.6/102.6/7.8'' vs per-star 50.4/74.1/4.4'')."""
    spec, cf = sea
    track, weather, truth = _tables(spec)
    configs, frames = _true_configs(spec)[1:], _frames(cf, spec)[1:]
    per_star = session_summary(process_session(configs, frames, track, weather), truth)
    bore = session_summary(process_session(configs, frames, track, weather,
                                           PipelineOptions(refraction="boresight")), truth)
    assert np.all(_rms(per_star, "single:A2") < _rms(bore, "single:A2"))


def test_pairing_window_and_single_sensor_session():
    spec, cf = _sea(offset_s=0.03, duration_s=0.5)
    track, weather, _ = _tables(spec)
    res = process_session(_true_configs(spec), _frames(cf, spec), track, weather,
                          PipelineOptions(max_pair_offset_s=0.01))
    assert all(e.frame_index[1] == -1 and not e.joint.solved for e in res.epochs)
    assert "pairing window" in res.epochs[0].joint.reason
    one = process_session(_true_configs(spec)[:1], _frames(cf, spec)[:1], track, weather)
    assert one.fore_aft_sensor == "" and len(one.epochs) == 5 and one.epochs[0].joint.solved
    with pytest.raises(ShipstarError, match="reference sensor"):
        process_session(_true_configs(spec), _frames(cf, spec), track, weather, reference="A9")


# -- outputs -------------------------------------------------------------------------------

def test_attitude_csv(sea_result):
    spec, res, truth = sea_result
    text = attitude_csv_text(res)
    rows = list(csv.DictReader(io.StringIO(text)))
    assert tuple(rows[0].keys()) == ATTITUDE_COLUMNS
    assert len(rows) == 2 * 80 + 2 * 80
    assert [r["method"] for r in rows[:4]] == ["single", "single", "seed-rule", "joint"]
    t = [float(r["t_s"]) for r in rows]
    assert t == sorted(t)
    assert all(r["time_source"] == "" for r in rows)
    r = rows[3]
    from shipstar.sky.time import utc_jd_from_iso

    K, psi, theta = truth.angles_rad(*utc_jd_from_iso(r["time_utc"]))
    assert abs(float(r["heading_deg"]) - K * RAD2DEG) * 3600 < 3.0
    assert abs(float(r["roll_deg"]) - theta * RAD2DEG) * 3600 < 3.0


def test_plots_are_written(sea_result, tmp_path):
    _, res, truth = sea_result
    paths = plot_session(res, tmp_path / "plots", truth)
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 10000


def test_summary_is_json_ready(sea_result):
    import json

    _, res, truth = sea_result
    s = session_summary(res, truth)
    json.dumps(s, allow_nan=False)
    assert s["methods"]["joint"]["n_compared"] == 80
    assert math.isfinite(s["sensors"]["A1"]["median_residual_rms_arcsec"])


def test_attitude_csv_times_are_microseconds_and_name_their_source():
    """A frame 30.4 ms after the start keeps its 0.4 ms (14'' of deck motion at sea) in
    ``time_utc`` and ``t_s``; ``time_source`` says how each time was read."""
    from shipstar.sky.time import utc_jd_from_iso

    spec, cf = _sea(offset_s=0.0304, duration_s=0.3)
    track, weather, _ = _tables(spec)
    frames = [[replace(f, time_source="DATE-AVG" if s.name == "A1" else "DATE-OBS+EXPTIME/2") for f in fl]
              for s, fl in zip(spec.sensors, _frames(cf, spec))]
    res = process_session(_true_configs(spec), frames, track, weather)
    rows = list(csv.DictReader(io.StringIO(attitude_csv_text(res))))
    a2 = [r for r in rows if r["method"] == "single" and r["sensor"] == "A2"]
    assert [r["time_utc"] for r in a2] == ["2013-03-15T12:16:00.030400Z", "2013-03-15T12:16:00.130400Z",
                                           "2013-03-15T12:16:00.230400Z"]
    assert [r["t_s"] for r in a2] == ["0.030400", "0.130400", "0.230400"]
    for r in rows:
        jd = utc_jd_from_iso(r["time_utc"])
        assert ((jd[0] - spec.utc_jd(0.0)[0]) + (jd[1] - spec.utc_jd(0.0)[1])) * DAY_S == pytest.approx(
            float(r["t_s"]), abs=1e-6)
        expected = "DATE-OBS+EXPTIME/2" if r["sensor"] == "A2" else "DATE-AVG"      # fused rows: A1's frame
        assert r["time_source"] == expected


def test_a_change_of_time_source_is_named_against_the_frames_before_it():
    """The warning named "the sensor's first frame's" source, but after a first change it
    compares with the frames just before (found by a bad-input sweep: DATE-BEG+... said,
    the first frame's being DATE-AVG)."""
    spec, cf = _sea(duration_s=0.4)
    track, weather, _ = _tables(spec)
    sources = ["DATE-AVG", "DATE-OBS+EXPTIME/2", "DATE-BEG+EXPTIME/2", "DATE-BEG+EXPTIME/2"]
    frames = [[replace(f, time_source=sources[k] if s.name == "A1" else "DATE-AVG") for k, f in enumerate(fl)]
              for s, fl in zip(spec.sensors, _frames(cf, spec))]
    res = process_session(_true_configs(spec), frames, track, weather)
    said = [w for e in res.emissions for w in e.warnings if "time comes from" in w]
    assert said == [f"sensor A1: frame {frames[0][1].label}'s time comes from DATE-OBS+EXPTIME/2, the frames' before "
                    "it from DATE-AVG",
                    f"sensor A1: frame {frames[0][2].label}'s time comes from DATE-BEG+EXPTIME/2, the frames' before "
                    "it from DATE-OBS+EXPTIME/2"]


# -- times to the microsecond ---------------------------------------------------------------

def test_result_times_are_microseconds():
    """Review finding: FrameResult.utc_iso, Epoch.utc_iso and the failure times of the
    summary were rounded to milliseconds (0.5 ms at 4 deg/s is 7'').  A2 30.4 ms late
    keeps its 0.4 ms everywhere."""
    spec, cf = _sea(offset_s=0.0304, duration_s=0.3)
    track, weather, _ = _tables(spec)
    frames = _frames(cf, spec)
    bad = frames[1][1]
    frames[1][1] = Frame.from_centroids(bad.utc_jd1, bad.utc_jd2, bad.xy_px[:1], bad.hip[:1], bad.label)
    res = process_session(_true_configs(spec), frames, track, weather)
    assert [fr.utc_iso for fr in res.frames_of("A2")] == ["2013-03-15T12:16:00.030400Z", "2013-03-15T12:16:00.130400Z",
                                                          "2013-03-15T12:16:00.230400Z"]
    assert res.epochs[1].utc_iso == "2013-03-15T12:16:00.100000Z"
    failure = session_summary(res)["sensors"]["A2"]["failures"][0]
    assert failure == {"frame": bad.label, "time_utc": "2013-03-15T12:16:00.130400Z", "reason": failure["reason"]}
    j1, j2 = spec.utc_jd(0.0)
    short = Track.from_arrays([j1, j1], [j2 - 2.0 / DAY_S, j2 - 0.98 / DAY_S], [31.9, 31.9], [120.3, 120.3])
    with pytest.raises(ShipstarError, match=r"frame time 2013-03-15T12:16:00\.030400Z is outside the track "
                                            r"\(2013-03-15T12:15:58\.000000Z to 2013-03-15T12:15:59\.020000Z; "
                                            r"frames may lie at most 1 s before the first row or after the last\)"):
        short.site(*spec.utc_jd(0.0304))


# -- streak centroids: time average over the exposure -> mid-exposure ---------------------

def _alpha_deck(motion, t, h=1e-3):
    """True deck angular acceleration (deck axes), central difference of the true rate."""
    return (motion.omega_deck_rad_per_s(t + h) - motion.omega_deck_rad_per_s(t - h)) / (2 * h)


def _predicted_bias_arcsec(motion, t, exposure_s):
    """Heading/pitch/roll error of an attitude solved from time-averaged directions tagged
    with mid-exposure: the deck turned by +alpha T^2 / 24 (docs/simulation.md), from the
    true motion alone (scipy's rotation vector -> matrix)."""
    from scipy.spatial.transform import Rotation

    C = motion.C_hor_from_deck(t)
    turned = C @ Rotation.from_rotvec(_alpha_deck(motion, t) * exposure_s ** 2 / 24).as_matrix()
    a0 = np.array(F.ship_angles_from_C_hor_from_deck(C))
    a1 = np.array(F.ship_angles_from_C_hor_from_deck(turned))
    return F.wrap_pi(a1 - a0) * RAD2ASEC


def _time_averaged_frames(spec, cf, exposure_s):
    """Centroid-level frames whose centroids are the stars' time-averaged images over the
    exposure (the renderer's true paths, ``exposure_path_px``, averaged piece by piece with
    ``streak_sources``' Simpson centres), plus the same noise as ``cf``."""
    from shipstar.simulate._motion import exposure_offsets_s, exposure_path_px, streak_sources

    tau = exposure_offsets_s(exposure_s)
    out = []
    for s in spec.sensors:
        frames = []
        for f in cf[s.name]:
            v_hor = s.camera.unproject(f.xy_true_px) @ f.C_hor_from_sensor.T
            path = exposure_path_px(s.camera, v_hor, spec.motion.C_hor_from_deck(f.t_s + tau) @ s.C_deck_from_sensor,
                                    tau)
            centres = streak_sources(path, np.ones(len(v_hor)))[0].reshape(len(v_hor), -1, 2)
            frames.append(Frame.from_centroids(f.utc_jd1, f.utc_jd2, centres.mean(axis=1) + (f.xy_px - f.xy_true_px),
                                               f.hip, f"{s.name}_{f.index:03d}", exposure_s=exposure_s))
        out.append(frames)
    return out


def _session_t(spec, epoch):
    """Seconds of an epoch since the simulated session's start."""
    j1, j2 = spec.utc_jd(0.0)
    return ((epoch.utc_jd1 - j1) + (epoch.utc_jd2 - j2)) * DAY_S


def _joint_errors(res, truth):
    from shipstar.pipeline import attitude_errors_arcsec, method_series

    return attitude_errors_arcsec(method_series(res, "joint"), truth)


def test_mid_exposure_vectors_undo_the_time_average():
    """Sign check on the renderer's geometry: at t = 2 s of the sea session (peak roll
    acceleration) an 80 ms exposure's time-averaged directions (a 4000-point average of the
    true path) lie ~2'' from the mid-exposure ones; the correction from the true rate and
    acceleration brings them back to < 0.01'', and the opposite sign would double the error."""
    from shipstar.pipeline._exposure import exposure_mean_offset, mid_exposure_vectors

    spec = sea_session()
    s, t, T = spec.sensor("A1"), 2.0, 0.08
    C_ds = s.C_deck_from_sensor
    u0 = F.unit_from_az_el(np.radians([10.0, 100.0, 200.0, 300.0]), np.radians([45.0, 38.0, 42.0, 36.0]))
    u0 = u0 @ (spec.motion.C_hor_from_deck(t) @ C_ds)                               # stars in the sensor frame
    v_hor = u0 @ (spec.motion.C_hor_from_deck(t) @ C_ds).T
    tau = (np.arange(4000) + 0.5) / 4000 * T - 0.5 * T
    C = spec.motion.C_hor_from_deck(t + tau) @ C_ds
    mean = np.einsum("kj,nji->kni", v_hor, C).mean(axis=1)
    mean /= np.linalg.norm(mean, axis=1)[:, None]
    omega_s = C_ds.T @ spec.motion.omega_deck_rad_per_s(t)
    alpha_s = C_ds.T @ _alpha_deck(spec.motion, t)

    def angle_arcsec(a, b):
        return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b)) * RAD2ASEC

    before = angle_arcsec(mean, u0)
    assert np.all(before > 1.5) and np.all(before < 3.7)
    mid, turn = mid_exposure_vectors(mean, omega_s, alpha_s, T)
    assert np.all(angle_arcsec(mid, u0) < 0.01)
    np.testing.assert_allclose(turn * RAD2ASEC, before, atol=0.01)
    wrong = mean + exposure_mean_offset(mean, omega_s, alpha_s, T)
    assert np.all(angle_arcsec(wrong / np.linalg.norm(wrong, axis=1)[:, None], u0) > 1.9 * before)


def test_streak_correction_at_80_ms_centroid_level():
    """8 s of the sea session with 80 ms exposures, centroids = time averages over the true
    paths.  Without the correction each epoch's joint attitude is off by the deck's
    +alpha T^2 / 24 (predicted from the true motion alone; plus the curvature term, < 0.15'');
    with it the joint RMS is back at the noise level (0.32 / 0.27 / 0.26'' with
    instantaneous centroids), and without noise within 0.2'' of the truth.  Each sensor's
    motion fit needs 5 of its frames (its first 4 are not corrected, counted in the
    summary) and is a quadratic until it has 7: epochs are compared from 0.6 s on (before,
    up to 1.9'' off without noise)."""
    spec = sea_session(exposure_s=0.08, duration_s=8.0)
    spec = spec.replace(sensors=(spec.sensors[0], replace(spec.sensors[1], time_offset_s=0.03)))
    track, weather, truth = _tables(spec)
    configs = _true_configs(spec)
    errors = {}
    for sigma_px in (0.0, 0.1):
        frames = _time_averaged_frames(spec, simulate_centroids(spec.replace(centroid_sigma_px=sigma_px)), 0.08)
        raw = process_session(configs, frames, track, weather, PipelineOptions(streak_correction=False))
        fixed = process_session(configs, frames, track, weather)
        errors[sigma_px] = (_joint_errors(raw, truth), _joint_errors(fixed, truth))
    later = np.array([_session_t(spec, e) > 0.55 for e in fixed.epochs])
    assert later.sum() == 74
    for sigma_px in (0.0, 0.1):
        assert np.all(np.isfinite(errors[sigma_px][0][later])) and np.all(np.isfinite(errors[sigma_px][1][later]))
    pred = np.array([_predicted_bias_arcsec(spec.motion, _session_t(spec, e), 0.08) for e in fixed.epochs])[later]
    assert np.max(np.abs(pred)) > 2.5
    e_raw, e_fixed = (e[later] for e in errors[0.0])
    assert np.max(np.abs(e_raw)) > 2.5 and np.max(np.abs(e_fixed)) < 0.2
    np.testing.assert_allclose(e_raw, pred, atol=0.25)                   # the sign and size of the bias
    e_raw, e_fixed = (e[later] for e in errors[0.1])
    np.testing.assert_allclose(e_raw - e_fixed, pred, atol=0.3)
    rms_raw, rms_fixed = rms_arcsec(e_raw), rms_arcsec(e_fixed)
    assert rms_raw[2] > 1.5 and rms_raw[1] > 1.0
    assert np.all(rms_fixed < 0.4)
    np.testing.assert_allclose(rms_fixed, rms_arcsec(e_raw - pred), atol=0.05)
    s = session_summary(fixed, truth)
    for name in ("A1", "A2"):
        assert s["sensors"][name]["n_streak_corrected"] == 76
        assert s["sensors"][name]["n_streak_not_corrected"] == 4
        assert 2.5 < s["sensors"][name]["max_streak_correction_arcsec"] < 3.8
    assert session_summary(raw)["sensors"]["A1"]["n_streak_corrected"] == 0


def test_streak_correction_on_rendered_80_ms_frames():
    """Image level, the curved-path renderer (each star drawn along its true path during the
    80 ms exposure) at the sea session's peak roll acceleration (t = 1.5-2.2 s, after 0.9 s
    of frames for the motion fit): extraction,
    identification, the deck rate from the frames and the correction.  Each epoch's joint
    attitude moves by the predicted -alpha T^2 / 24 (within 0.2''), and the joint pitch and
    roll RMS drop from the bias level to below 1.2''."""
    from shipstar.simulate._session import _sensor_frame

    T = 0.08
    spec = sea_session(exposure_s=T, duration_s=2.5)
    spec = spec.replace(sensors=(spec.sensors[0], replace(spec.sensors[1], time_offset_s=0.03)))
    frames = [[_rendered(_sensor_frame(spec, s, k, float(t)), f"{s.name}_{k:03d}")
               for k, t in enumerate(spec.times_s(s)) if 0.6 <= t <= 2.2] for s in spec.sensors]
    track, weather, truth = _tables(spec)
    configs = _true_configs(spec)
    raw = process_session(configs, frames, track, weather, PipelineOptions(streak_correction=False))
    fixed = process_session(configs, frames, track, weather)
    assert all(fr.solved for frs in fixed.frames for fr in frs)
    peak = np.array([_session_t(spec, e) > 1.45 for e in fixed.epochs])
    e_raw, e_fixed = _joint_errors(raw, truth)[peak], _joint_errors(fixed, truth)[peak]
    ok = np.all(np.isfinite(e_raw), axis=1)
    assert ok.sum() >= 7
    pred = np.array([_predicted_bias_arcsec(spec.motion, _session_t(spec, e), T) for e in fixed.epochs])[peak]
    # the extraction's fitted centres lie beyond the time averages along these 13-21 px streaks
    # (k(L) > 1, docs/extraction.md, *Accelerating streaks*): the correction is more than the
    # time average's -alpha T^2 / 24 on roll, up to 1.5 x where the streaks are longest (before the
    # model: equal to it within 0.2'', and the joint RMS 0.90 / 0.88 / 0.74'', now 0.31 / 0.26 / 0.28'');
    # with the 0.005 px floor the brightest stars weigh more and one epoch moves by 0.92 x
    moved = (e_raw - e_fixed)[ok][:, 2] / pred[ok][:, 2]
    assert np.all(moved > 0.9) and np.all(moved < 2.0) and moved.max() > 1.3, moved
    rms_raw, rms_fixed = rms_arcsec(e_raw), rms_arcsec(e_fixed)
    assert rms_raw[2] > 2.5 and np.all(rms_fixed < 0.5) and rms_raw[1] > 1.2


def _rendered(sim, label):
    """A pipeline Frame of a rendered ``SimulatedFrame`` (its camera's exposure time)."""
    return Frame(sim.utc_jd1, sim.utc_jd2, label, image=sim.image, exposure_s=sim.camera.exposure_s)


def test_streak_correction_at_rest_and_without_an_exposure_time():
    """In dock (no acceleration) the correction of noise-free frames is below 0.01'' and
    nothing is solved again; with 0.1 px noise the fitted acceleration is noise and the
    corrections stay below 0.2''.  They do not make the joint RMS worse: it is 2-3 % better
    (four noise seeds), because the acceleration fitted at the newest frame carries a small
    part of that frame's own error, which the correction takes back (a light smoothing).
    Frames without an exposure time are never corrected."""
    for sigma_px in (0.0, 0.1):
        spec = dock_session(duration_s=8.0, centroid_sigma_px=sigma_px)
        track, weather, truth = _tables(spec)
        frames = [[replace(f, exposure_s=0.08) for f in fl] for fl in _frames(simulate_centroids(spec), spec)]
        fixed = process_session(_true_configs(spec), frames, track, weather)
        corrected = [fr.streak_correction_arcsec for frs in fixed.frames for fr in frs[4:]]
        assert all(math.isnan(fr.streak_correction_arcsec) for frs in fixed.frames for fr in frs[:4])
        if sigma_px == 0.0:
            assert corrected == [0.0] * 152
            continue
        raw = process_session(_true_configs(spec), frames, track, weather, PipelineOptions(streak_correction=False))
        assert max(corrected) < 0.2
        ratio = rms_arcsec(_joint_errors(fixed, truth)) / rms_arcsec(_joint_errors(raw, truth))
        assert np.all(ratio < 1.0) and np.all(ratio > 0.95), ratio
    spec, cf = _sea(duration_s=0.5)
    track, weather, _ = _tables(spec)
    res = process_session(_true_configs(spec), _frames(cf, spec), track, weather)
    assert all(fr.streak_correction_arcsec == 0.0 and math.isnan(fr.exposure_s) for frs in res.frames for fr in frs)
    with pytest.raises(ShipstarError, match="exposure_s must be >= 0"):
        Frame.from_centroids(2456367.0, 0.0, np.zeros((3, 2)), exposure_s=-0.08)


def test_attitude_csv_comment_lines_are_skipped_by_the_csv_reader(sea_result, tmp_path):
    """The CSV may start with '# ' lines (EOP quality, warnings); shipstar's CSV reader and
    astropy's (``comment="#"``) skip them, and the header row is unchanged."""
    from shipstar.pipeline import write_attitude_csv
    from shipstar.pipeline._tables import read_csv_table

    spec, res, _ = sea_result
    one = process_session(_true_configs(spec)[:1], [[Frame.from_centroids(f.utc_jd1, f.utc_jd2, f.xy_px, f.hip)
                                                     for f in simulate_centroids(spec)["A1"][:3]]],
                          *_tables(spec)[:2])
    path = tmp_path / "att.csv"
    write_attitude_csv(one, path, comments=["eop_quality = measured", "warning: two\nlines"])
    lines = path.read_text().splitlines()
    assert lines[:2] == ["# eop_quality = measured", "# warning: two lines"]
    assert lines[2] == ",".join(ATTITUDE_COLUMNS)
    jd1, jd2, cols = read_csv_table(path, ("heading_deg", "pitch_deg", "roll_deg"))
    assert len(jd1) == 3
    np.testing.assert_allclose(cols["heading_deg"], [float(r.split(",")[6]) for r in lines[3:]])
    from astropy.table import Table

    table = Table.read(path, format="ascii.csv", comment="#")
    assert tuple(table.colnames) == ATTITUDE_COLUMNS and len(table) == 3
    assert table.meta["comments"] == ["eop_quality = measured", "warning: two lines"]


def test_compiled_motion_fit_matches_the_numpy_least_squares():
    """The compiled normal equations (Cholesky) against the NumPy reference (lstsq with its
    rank cut), on sea motion with unequal, correlated covariances, shared sample times (two
    sensors) and every degree: the fitted rotation and rate agree to 1e-6 arcsec / 1e-9 rad/s
    inside the window and 0.1 s past it; a singular covariance still raises as NumPy does."""
    from shipstar.pipeline import _motion

    m = sea_session().motion
    rng = np.random.default_rng(5)
    for n in (5, 7, 10, 18, 26):
        t = np.sort(np.concatenate([np.arange(n // 2) * 0.1, np.arange(n - n // 2) * 0.1 + 0.02]))
        C = m.C_hor_from_deck(t)
        A = rng.normal(size=(n, 3, 3)) * 0.5 * ASEC2RAD
        cov = A @ np.swapaxes(A, 1, 2) + np.eye(3) * (0.2 * ASEC2RAD) ** 2
        fits = []
        for compiled in (True, False):
            _motion._COMPILED[0] = compiled
            try:
                fits.append(_motion.fit_motion(t, C, cov))
            finally:
                _motion._COMPILED[0] = True
        a, b = fits
        assert a.degree == b.degree and a.n_samples == b.n_samples == n
        for ts in (t[0], 0.5 * (t[0] + t[-1]), t[-1], t[-1] + 0.1):
            np.testing.assert_allclose(a.r(ts), b.r(ts), rtol=0, atol=1e-6 * ASEC2RAD)
            np.testing.assert_allclose(a.omega_at(ts), b.omega_at(ts), rtol=0, atol=1e-9)
    singular = np.tile(-_motion._FLOOR_RAD2 * np.eye(3), (6, 1, 1))          # plus the floor: 0
    with pytest.raises(np.linalg.LinAlgError):
        _motion.fit_motion(np.arange(6) * 0.1, m.C_hor_from_deck(np.arange(6) * 0.1), singular)


def test_the_rate_asked_again_at_the_same_time_is_the_same_and_its_own_copy():
    """MotionFit.omega_at keeps its last answer (an epoch asks ~3 times at its time): the
    same numbers as a fresh computation, each call its own array."""
    from shipstar.pipeline._motion import MotionFit

    t = 2.0
    fit = _motion_window(sea_session().motion, t).fit(t, sources=[0])
    fresh = MotionFit(fit.t_ref_s, fit.scale_s, fit.C_ref, fit.coef, fit.t_first_s, fit.t_last_s, fit.n_samples)
    a = fit.omega_at(t)
    a[:] = 0.0                                            # a caller's change stays its own
    b = fit.omega_at(t)
    np.testing.assert_array_equal(b, fresh.omega_at(t))
    assert np.linalg.norm(b) > 0.0
    np.testing.assert_array_equal(fit.omega_at(t - 0.05), fresh.omega_at(t - 0.05))   # another time
    np.testing.assert_array_equal(fit.omega_at(t), b)


def test_the_engines_quick_replace_is_dataclasses_replace():
    from dataclasses import fields, replace

    from shipstar.pipeline._engine import Emission, _replaced

    e = Emission((1, 2), "epoch", ("w",), (0.0, 0.1))
    for changes in ({"epoch": "other"}, {"warnings": (), "frame_shifts_s": (0.5,)}):
        a, b = _replaced(e, **changes), replace(e, **changes)
        assert type(a) is Emission and a is not e
        assert [getattr(a, f.name) for f in fields(Emission)] == [getattr(b, f.name) for f in fields(Emission)]
    assert e.epoch == "epoch"                             # the original unchanged
    with pytest.raises(TypeError, match="no field"):
        _replaced(e, epoc="typo")


def test_a_workers_warm_up_loads_what_its_first_frame_needs():
    """load_shared_data (a worker's start; measure-archive's driver before it forks its
    LocalCluster) also parses the Earth orientation table and imports the frame's modules,
    so that a forked worker's first frame does not (~0.13 s each)."""
    import subprocess

    code = ("import sys; from shipstar.pipeline._measure import load_shared_data, FRAME_MODULES; "
            "from shipstar.sky import eop; "
            "assert eop._table.cache_info().currsize == 0; "
            "assert not any(m in sys.modules for m in FRAME_MODULES if m.startswith('shipstar.extract')); "
            "load_shared_data([]); "
            "assert eop._table.cache_info().currsize == 1; "
            "missing = [m for m in FRAME_MODULES if m not in sys.modules]; assert not missing, missing")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_one_rotation_vector_is_the_batch_formula():
    from shipstar.pipeline._motion import rotvec, rotvecs
    from shipstar.identify._sim import random_attitudes

    Cs = random_attitudes(500, np.random.default_rng(9))
    ref = rotvecs(Cs)
    one = np.array([rotvec(C) for C in Cs])
    np.testing.assert_allclose(one, ref, rtol=0, atol=1e-15)
    assert np.array_equal(rotvec(np.eye(3)), np.zeros(3))


def test_motion_fit_counts_distinct_times_as_numpy_unique():
    """``fit_motion`` lowers its degree by the number of distinct sample times: counted as
    ``len(np.unique(t))`` counts them (``-0.0`` and ``0.0`` one value, NaNs one, infinities),
    without sorting (``pipeline._motion._n_distinct``)."""
    from shipstar.pipeline._motion import _n_distinct

    rng = np.random.default_rng(3)
    pool = [0.0, -0.0, 0.1, 0.2, np.nan, 1e9, np.inf, -np.inf, 0.1 + 0.2, 0.3]
    for _ in range(3000):
        t = rng.choice(pool, int(rng.integers(0, 20)))
        assert _n_distinct(t) == len(np.unique(t)), t


def test_a_task_uses_the_runs_earth_orientation_table_or_refuses(tmp_path, monkeypatch):
    """use_job_tables (every task's start): a process started without --eop (a Dask worker of
    another machine) takes the job's table; a table that is not the job's (another
    astropy-iers-data, another file at that path), a file it cannot read or another
    Hipparcos catalog is a one-line error, never other rows."""
    from pathlib import Path

    from astropy_iers_data import IERS_A_FILE

    from shipstar.pipeline._measure import MeasureJob, job_tables, process_chunk, use_job_tables
    from shipstar.sky import eop

    packaged = Path(IERS_A_FILE).read_bytes()
    first, rest = packaged.split(b"\n", 1)                 # 1973's UT1 - UTC 0.1 ms larger
    assert first[154:165].strip() == b".8075000"
    altered = first[:154] + first[154:165].replace(b".8075000", b".8076000") + first[165:] + b"\n" + rest
    monkeypatch.delenv(eop.EOP_FILE_ENV, raising=False)
    try:
        table = tmp_path / "finals.all"
        table.write_bytes(altered)
        eop.set_eop_file(table)
        job = MeasureJob((), None, None, None, (0.0, 0.0), **job_tables())
        assert job.eop_file == str(table) and len(job.eop_digest) == 64
        eop.set_eop_file(None)                          # a worker started without --eop
        use_job_tables(job)
        assert eop.eop_source() == str(table)
        eop.set_eop_file(None)
        table.write_bytes(packaged)                     # another file at that path
        eop._table.cache_clear()
        with pytest.raises(ShipstarError, match="not the one the run was started with") as err:
            use_job_tables(job)
        assert "\n" not in str(err.value)
        with pytest.raises(ShipstarError, match="no such file"):
            use_job_tables(replace(job, eop_file=str(tmp_path / "missing.all")))
        with pytest.raises(ShipstarError, match="astropy-iers-data"):      # another packaged table
            use_job_tables(replace(job, eop_file=None, eop_digest="0" * 64))
        use_job_tables(replace(job, eop_digest=""))     # not checked (a job made by hand)
        assert job.catalog_identity.startswith("hip") or "|" in job.catalog_identity
        with pytest.raises(ShipstarError, match="Hipparcos catalog .* is not the one the run was started with"):
            use_job_tables(replace(job, eop_digest="", catalog_identity="hip2.dat|1|0"))   # another catalog
        use_job_tables(replace(job, eop_digest="", catalog_identity=""))
        with pytest.raises(ShipstarError, match="not the one the run was started with"):   # every task checks
            next(process_chunk(replace(job, eop_file=None, eop_digest="0" * 64), 0, None, 0, 0, 10))
    finally:
        eop._table.cache_clear()
        eop.set_eop_file(None)
