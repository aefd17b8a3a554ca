"""``shipstar.live._replay``: frames written at their real time spacing (write, then
rename), tables growing row by row, clean stops, and the refusals.

Timing is observed with real file events (``watchfiles``, as ``shipstar live`` uses),
relative to the first frame's appearance, with tolerances that hold on a loaded 2-core
machine."""

from __future__ import annotations

import signal
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import watchfiles

from shipstar.errors import ShipstarError
from shipstar.live._replay import (
    FAST_SPEED,
    TEMP_SUFFIX,
    ReplayFrame,
    ReplayPlan,
    plan_replay,
    replay,
    session_sensor_dirs,
    session_tables,
)
from shipstar.pipeline._frames import FITS_SUFFIXES

#: Frame appearance relative to the first frame, and table rows relative to their due time (s).
TOLERANCE_S = 0.060


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory):
    """A 0.5 s sea session at 20 Hz, A2 25 ms after A1: 20 frames, A1 and A2 interleaved
    25 ms apart (~1.5 s to render)."""
    from shipstar.simulate._session import sea_session, write_session

    spec = sea_session(duration_s=0.5, frame_rate_hz=20.0)
    spec = spec.replace(sensors=(spec.sensor("A1"), replace(spec.sensor("A2"), time_offset_s=0.025)))
    out = tmp_path_factory.mktemp("replay") / "sea"
    write_session(spec, out)
    return out


@pytest.fixture(scope="module")
def track_table(session_dir, tmp_path_factory):
    """A track with a row every 0.1 s from 0.5 s before the first frame to 0.7 s after it,
    with '#' comment lines before the header and between rows."""
    lines = ["# a ship track for the replay test\n", "time_utc,lat_deg,lon_deg\n"]
    for k in range(13):
        t = (k - 5) / 10.0
        if k == 8:
            lines.append("# a comment between rows\n")
        lines.append(f"2013-03-15T12:16:{t:09.6f}Z,31.9,120.3\n" if t >= 0 else
                     f"2013-03-15T12:15:{60 + t:09.6f}Z,31.9,120.3\n")
    path = tmp_path_factory.mktemp("tables") / "track.csv"
    path.write_text("".join(lines))
    return path


class Watcher:
    """File events under a directory (``watchfiles``, every path, 1 ms step): the time of each
    event batch, and at that moment the size of each new file and the rows of ``track.csv``."""

    def __init__(self, root: Path):
        self.root = root
        self.events: list = []           # (t_monotonic, Change, relative path, size or -1)
        self.track_rows: list = []       # (t_monotonic, data rows of track.csv)
        self._stop, self._ready = threading.Event(), threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self):
        self._thread.start()
        assert self._ready.wait(10.0), "watcher did not start"
        return self

    def __exit__(self, *exc):
        time.sleep(0.1)
        self._stop.set()
        self._thread.join(10.0)

    def _run(self):
        for changes in watchfiles.watch(self.root, watch_filter=None, debounce=50, step=1, rust_timeout=20,
                                        yield_on_timeout=True, stop_event=self._stop, raise_interrupt=False):
            t = time.monotonic()
            self._ready.set()
            for change, path in changes:
                p = Path(path)
                try:                        # a temporary file may be renamed between the event and here
                    size = p.stat().st_size if p.is_file() else -1
                except FileNotFoundError:
                    size = -1
                self.events.append((t, change, p.relative_to(self.root).as_posix(), size))
            track = self.root / "track.csv"
            if track.is_file():
                rows = [ln for ln in track.read_text().splitlines() if ln and not ln.startswith("#")]
                self.track_rows.append((t, len(rows) - 1))

    def first_added(self) -> dict:
        """``{relative path: time}`` of the first 'added' event of each path."""
        out: dict = {}
        for t, change, rel, _ in self.events:
            if change == watchfiles.Change.added:
                out.setdefault(rel, t)
        return out


def _assert_whole_frames_only(to_dir: Path, plan: ReplayPlan, n_expected=None):
    """Every file under to_dir is a whole frame of the plan (bytes identical) or a table;
    no temporary file is left."""
    sources = {f"{f.sensor}/{f.source.name}": f.source for f in plan.frames}
    found = sorted(p.relative_to(to_dir).as_posix() for p in to_dir.rglob("*") if p.is_file())
    frames = [r for r in found if not r.endswith(".csv")]
    assert not [r for r in found if Path(r).name.startswith(".")], found
    for rel in frames:
        assert (to_dir / rel).read_bytes() == sources[rel].read_bytes(), rel
    if n_expected is not None:
        assert len(frames) == n_expected
    return frames


def test_plan_merges_the_sensors_in_time_order(session_dir):
    plan = plan_replay(session_sensor_dirs(session_dir), session_tables(session_dir))
    assert plan.sensors == ("A1", "A2") and len(plan.frames) == 20
    assert [f.sensor for f in plan.frames] == ["A1", "A2"] * 10
    offsets = np.array([f.offset_s for f in plan.frames])
    np.testing.assert_allclose(offsets, 0.025 * np.arange(20), atol=1e-6)
    assert plan.span_s == pytest.approx(0.475, abs=1e-6)
    assert [t.name for t in plan.tables] == ["track.csv", "weather.csv"]
    assert [round(t, 6) for t, _ in plan.tables[0].rows] == [-1.0, 0.0, 1.0, 2.0]
    assert plan.frames_per_sensor() == {"A1": 10, "A2": 10}
    only = plan_replay(session_sensor_dirs(session_dir, ["A2"]))
    assert only.sensors == ("A2",) and only.frames[0].offset_s == 0.0 and not only.tables


def test_replay_at_speed_1_keeps_the_frame_times(session_dir, track_table, tmp_path):
    """Each frame appears once, whole, under its final name at start + (t - t_first) within
    60 ms relative to the first; temporary names are hidden and never FITS; the track grows
    row by row at its rows' times minus the lead."""
    plan = plan_replay(session_sensor_dirs(session_dir),
                       {"track.csv": track_table, "weather.csv": session_dir / "weather.csv"})
    to_dir = tmp_path / "live"
    to_dir.mkdir()                                    # empty: allowed
    lead_s = 0.1
    with Watcher(to_dir) as w:
        result = replay(plan, to_dir, speed=1.0, start_delay_s=0.3, table_lead_s=lead_s)
    assert result.stopped is None and not result.partial
    assert result.frames_by_sensor == {"A1": 10, "A2": 10}
    assert result.table_rows == {"track.csv": 13, "weather.csv": 4}
    assert result.max_late_ms < 1000 * TOLERANCE_S
    # every name ever seen: final frames, or hidden temporary names without a FITS suffix
    for _, change, rel, _ in w.events:
        name = Path(rel).name
        if name.startswith("."):
            assert not name.lower().endswith(FITS_SUFFIXES) and (name.endswith(TEMP_SUFFIX)
                                                                   or name.endswith(".tmp")), rel
        elif rel.endswith(FITS_SUFFIXES):
            assert change != watchfiles.Change.modified, f"{rel} was written under its final name"
    # whole at the moment it appeared, and identical bytes at the end
    sizes = {f"{f.sensor}/{f.source.name}": f.source.stat().st_size for f in plan.frames}
    for _, change, rel, size in w.events:
        if rel in sizes and change == watchfiles.Change.added:
            assert size == sizes[rel], rel
    _assert_whole_frames_only(to_dir, plan, 20)
    assert (to_dir / "track.csv").read_bytes() == track_table.read_bytes()
    assert (to_dir / "weather.csv").read_bytes() == (session_dir / "weather.csv").read_bytes()
    # timing, relative to the first frame's appearance
    seen = w.first_added()
    t_seen = np.array([seen[f"{f.sensor}/{f.source.name}"] for f in plan.frames])
    expected = np.array([f.offset_s for f in plan.frames])
    dev_s = (t_seen - t_seen[0]) - expected
    print(f"frame times: max |deviation| {1000 * np.abs(dev_s).max():.1f} ms, last frame {1000 * dev_s[-1]:+.1f} ms")
    assert np.abs(dev_s).max() < TOLERANCE_S, dev_s
    # the track: rows due before the first frame are there before it; later rows appear at
    # their time minus the lead; rows due after the last frame come right after it
    table = plan.tables[0]
    due_s = np.array([t for t, _ in table.rows]) - lead_s
    n_start = int(np.sum(due_s <= 0.0))
    assert min(n for t, n in w.track_rows) >= n_start
    timed = np.flatnonzero((due_s > 0.0) & (due_s <= plan.span_s))
    assert len(timed) >= 3
    for k in timed:
        t_row = min(t for t, n in w.track_rows if n >= k + 1)
        assert abs((t_row - t_seen[0]) - due_s[k]) < TOLERANCE_S, (k, t_row - t_seen[0], due_s[k])
        before = [n for t, n in w.track_rows if t < t_row]
        assert max(before) == k                       # one row at a time
    assert max(n for t, n in w.track_rows) == len(table.rows)


def test_no_cumulative_drift_and_speed_scales_time(tmp_path):
    """60 small frames over 2.95 session seconds at speed 4: each appears at its scaled time
    within the tolerance, the last ones with no drift, and the fitted clock rate is 1/4 to 2 %."""
    src = tmp_path / "src"
    src.mkdir()
    frames = []
    for k in range(60):
        path = src / f"f{k:03d}.fits"
        path.write_bytes(bytes([k]) * 2880)
        frames.append(ReplayFrame("S", path, round(0.05 * k, 6)))
    plan = ReplayPlan(tuple(frames), ("S",))
    to_dir = tmp_path / "out"
    to_dir.mkdir()
    with Watcher(to_dir) as w:
        result = replay(plan, to_dir, speed=4.0, start_delay_s=0.2)
    seen = w.first_added()
    t_seen = np.array([seen[f"S/{f.source.name}"] for f in frames])
    expected = np.array([f.offset_s for f in frames]) / 4.0
    dev_s = (t_seen - t_seen[0]) - expected
    rate = np.polyfit(expected, t_seen - t_seen[0], 1)[0]
    print(f"speed 4: max |deviation| {1000 * np.abs(dev_s).max():.1f} ms, clock rate {rate:.5f}, "
          f"max lateness {result.max_late_ms:.2f} ms")
    # the replay's own schedule (its lateness, measured as it writes) within the tolerance;
    # what the watcher sees adds its delivery's jitter: once in CI one event of 60 came
    # 65 ms off while the replay was at most 25 ms late, so the observed times are held to
    # the tolerance but for the odd delivery (95 % of them), and every one to twice it
    assert result.max_late_ms < 1000 * TOLERANCE_S
    assert np.percentile(np.abs(dev_s), 95) < TOLERANCE_S
    assert np.abs(dev_s).max() < 2 * TOLERANCE_S
    assert abs(dev_s[-10:].mean()) < 0.5 * TOLERANCE_S          # no drift at the end
    # the rate of the file events' times, fitted over 0.74 s: their delivery jitters by ~5-15 ms
    # on a loaded host (1.0055-1.0089 seen in 3 of 10 runs at 0.5 %); a replay that slept from
    # its last write instead of its schedule drifts by its overshoot every frame (1 ms at
    # 12.5 ms spacing: 8 %), far beyond 2 %
    assert rate == pytest.approx(1.0, abs=0.02)
    assert result.frames_written == 60 and result.speed == 4.0
    _assert_whole_frames_only(to_dir, plan, 60)


def test_fast_mode_writes_everything_without_a_schedule(session_dir, tmp_path):
    plan = plan_replay(session_sensor_dirs(session_dir), session_tables(session_dir))
    t0 = time.monotonic()
    result = replay(plan, tmp_path / "fast", speed=FAST_SPEED, start_delay_s=0.0)
    assert time.monotonic() - t0 < 5.0
    assert result.frames_written == 20 and result.max_late_ms is None and result.late_frames == 0
    assert result.to_dict()["max_late_ms"] is None and result.to_dict()["partial"] is False
    _assert_whole_frames_only(tmp_path / "fast", plan, 20)
    for name in ("track.csv", "weather.csv"):
        assert (tmp_path / "fast" / name).read_bytes() == (session_dir / name).read_bytes()


def test_stop_event_from_another_thread_leaves_whole_frames(session_dir, tmp_path):
    plan = plan_replay(session_sensor_dirs(session_dir), session_tables(session_dir))
    to_dir, stop, box = tmp_path / "out", threading.Event(), {}
    before = signal.getsignal(signal.SIGINT)

    def run():
        box["result"] = replay(plan, to_dir, speed=1.0, start_delay_s=0.1, stop_event=stop)

    thread = threading.Thread(target=run)
    thread.start()
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and len(list(to_dir.glob("A*/*.fits"))) < 5:
        time.sleep(0.002)
    stop.set()
    thread.join(10.0)
    result = box["result"]
    assert result.stopped == "requested" and result.partial
    assert 5 <= result.frames_written < 20
    frames = _assert_whole_frames_only(to_dir, plan, result.frames_written)
    assert sorted(frames) == sorted(f"{f.sensor}/{f.source.name}" for f in plan.frames[:result.frames_written])
    # a replay in another thread leaves this process's SIGINT handler as it found it (not
    # necessarily Python's default: a process started in the background by a shell without
    # job control, as CI may start pytest, begins with SIGINT ignored, SIG_IGN)
    assert signal.getsignal(signal.SIGINT) is before


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_stops_cleanly_and_the_handlers_are_restored(session_dir, tmp_path, signum):
    plan = plan_replay(session_sensor_dirs(session_dir))
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}

    def progress(done, total):
        if done == 6:
            signal.raise_signal(signum)               # handled by replay, in this (main) thread

    result = replay(plan, tmp_path / "out", speed=FAST_SPEED, start_delay_s=0.0, progress=progress)
    assert result.stopped == signal.Signals(signum).name and result.partial
    assert 6 <= result.frames_written < 20
    assert result.to_dict()["stopped"] == signal.Signals(signum).name
    _assert_whole_frames_only(tmp_path / "out", plan, result.frames_written)
    assert {s: signal.getsignal(s) for s in before} == before


def test_refusals(session_dir, tmp_path):
    plan = plan_replay(session_sensor_dirs(session_dir, ["A1"]))
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "old.txt").write_text("x")
    with pytest.raises(ShipstarError, match="not empty"):
        replay(plan, busy, speed=FAST_SPEED)
    a_file = tmp_path / "file"
    a_file.write_text("x")
    with pytest.raises(ShipstarError, match="is a file"):
        replay(plan, a_file / "sub", speed=FAST_SPEED)
    with pytest.raises(ShipstarError, match="not a directory"):
        replay(plan, a_file, speed=FAST_SPEED)
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ShipstarError, match="speed"):
            replay(plan, tmp_path / "new", speed=bad)
    with pytest.raises(ShipstarError, match="start_delay_s"):
        replay(plan, tmp_path / "new", start_delay_s=-1.0)
    assert not (tmp_path / "new").exists()
    with pytest.raises(ShipstarError, match="does not exist"):
        session_sensor_dirs(tmp_path / "missing")
    with pytest.raises(ShipstarError, match="no sensor directories"):
        session_sensor_dirs(busy)
    with pytest.raises(ShipstarError, match="A3 does not exist"):
        session_sensor_dirs(session_dir, ["A1", "A3"])
    with pytest.raises(ShipstarError, match="no FITS frames"):
        plan_replay({"A1": busy})
    with pytest.raises(ShipstarError, match="directory name"):
        plan_replay({"../x": session_dir / "A1"})
    with pytest.raises(ShipstarError, match="no sensors"):
        plan_replay({})


def test_bad_tables_are_refused(session_dir, tmp_path):
    dirs = session_sensor_dirs(session_dir, ["A1"])
    no_time = tmp_path / "a.csv"
    no_time.write_text("t,lat_deg\n1,2\n")
    with pytest.raises(ShipstarError, match="no time_utc column"):
        plan_replay(dirs, {"track.csv": no_time})
    bad_time = tmp_path / "b.csv"
    bad_time.write_text("# c\ntime_utc,lat_deg\n2013-03-15T12:16:00Z,1\nyesterday,2\n")
    with pytest.raises(ShipstarError, match="line 4"):
        plan_replay(dirs, {"track.csv": bad_time})
    empty = tmp_path / "c.csv"
    empty.write_text("# only a comment\n")
    with pytest.raises(ShipstarError, match="no header"):
        plan_replay(dirs, {"track.csv": empty})
