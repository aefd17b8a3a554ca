"""``shipstar measure`` on whole nights: time per frame and peak memory against session length.

Four parts; the first three each run in a child process whose whole process tree (the main
process and its worker processes) is sampled every 50 ms for its resident memory (summed):

1. image frames (``simulate-session --kind sea``: 1024 x 1024 FITS, 2.1 MB each, both
   sensors at 10 frames/s): 60 s and 6 min (14,400 frames, 15 GB: this disk holds
   minutes, not hours), ``shipstar measure`` with ``--workers 2``;
2. ``--workers 1`` against ``--workers 2`` on the 60 s session (the anchor: the same
   command on one core; target >= 1.7x, the same CSV; also each pair corrected for the
   host's speed of the moment: the runs' wall time per second of their CPU time, whose
   ratio for the same work moves with this shared host's speed);
3. star lists, the stages after extraction (identification, sky, refraction, attitude,
   streak correction, pairing, fusion, the CSV): 60 s, 1 h and 10 h (720,000 frames), the
   centroids simulated chunk by chunk in the workers (the seeds' sea state, stars to Hp 8,
   0.1 px noise, no identities given) through the driver behind ``shipstar measure``
   (``shipstar.pipeline._measure.run_measure``) with ``--workers 2``; the simulation's own
   share of the time is measured apart and printed.

Printed per run: frames, wall time, ms per frame (all of the wall time), the steady ms
per frame (the wall time less the fixed start-up cost -- spawning the workers, imports,
the star database -- measured on a 2 s session first), peak RSS (MB, summed over
processes), and the ratios of the steady ms/frame and of the peak RSS to the 60 s run
(targets: ms/frame at 1 h within 10 % of 60 s; peak RSS independent of length, under
400 MB at 10 h).

Bytecode: the commands run with a bytecode cache of shipstar's sources compiled once
before them (``benchmarks/_procenv.py``), as an installed package has; with an editable
install and ``PYTHONDONTWRITEBYTECODE`` set (the development host) each command would
compile them again, a fixed cost of ~0.3 s that weighs on the 60 s runs' ratio.
``--no-bytecode-cache`` keeps the environment as it is.

The image sessions are read once before their timed runs (the page cache warm for every
run alike, :func:`read_once`).

4. a field at rest (dock): the image-level sensor chain on 20 minutes of night (12,000
   frames) in this process, a 1 s dock session's frames fed again with advancing times:
   ms per frame and traced memory per block of 2000 frames (targets: the last block within
   10 % and 2 MB of the first).  A sea session's moving stars hid state that grew at rest:
   the persistent-pixel map kept one entry per frame for a pixel seen in every frame
   (+1.5 ms and +1 MB a frame every 1000 frames until 2026-12-07).

Run: ``python benchmarks/bench_measure_scale.py [--parts images,workers,starlists,rest]
[--hours 10] [--workdir DIR] [--no-bytecode-cache]`` (the image sessions are rendered once into the work
directory and kept; 6 min takes ~4 min to render).  Needs ``psutil`` (``pip install
'.[bench]'``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from _procenv import command_env, precompile

#: The environment of the timed commands (``main`` sets the bytecode cache).
_ENV: dict = {}


# -- the star-list source (runs in the workers) ----------------------------------------------------

@dataclass(frozen=True, eq=False)
class _StarListPiece:
    spec: object
    sensor: int
    lo: int
    hi: int

    def load(self) -> list:
        from shipstar.pipeline import Frame
        from shipstar.simulate._session import _centroid_frame

        s = self.spec.sensors[self.sensor]
        out = []
        for k in range(self.lo, self.hi):
            rng = np.random.default_rng([self.spec.seed, self.sensor, k])       # the same frame in any chunk
            f = _centroid_frame(self.spec, s, k, self.spec._time_s(s, k), rng)
            out.append(Frame.from_centroids(f.utc_jd1, f.utc_jd2, f.xy_px, None, f"{s.name}_{k:07d}",
                                            exposure_s=self.spec.exposure_of(s)))
        return out


class StarLists:
    """A simulated sensor's star lists (:class:`shipstar.pipeline._sources.FrameSource`)."""

    def __init__(self, spec, sensor: int):
        self.spec, self.sensor = spec, sensor
        self.name = spec.sensors[sensor].name
        t = spec.times_s(spec.sensors[sensor])
        jd1, jd2 = spec.utc_jd(0.0)
        self._jd = (np.full(len(t), jd1), jd2 + t / 86400.0)

    def times_utc_jd(self):
        return self._jd

    def piece(self, lo: int, hi: int):
        return _StarListPiece(self.spec, self.sensor, lo, hi)


def _starlist_spec(duration_s: float):
    from shipstar.simulate._session import sea_session

    # weather drifting slowly enough to stay physical over 10 h
    return sea_session(duration_s=duration_s, pressure_rate_hpa_per_s=1e-4, temperature_rate_c_per_s=-1e-4)


def _starlist_job(spec):
    from shipstar.calibrate.installation import Installation
    from shipstar.pipeline import PipelineOptions, SensorConfig, Track, WeatherTable
    from shipstar.pipeline._measure import MeasureJob
    from shipstar.units import DAY_S, RAD2DEG

    j1, j2 = spec.utc_jd(0.0)
    tt = np.arange(-1.0, spec.duration_s + 2.0, 1.0)
    lat, lon, h = spec.motion.position(tt)
    track = Track.from_arrays(np.full(len(tt), j1), j2 + tt / DAY_S, lat * RAD2DEG, lon * RAD2DEG, h)
    w = [spec.weather(t) for t in tt]
    weather = WeatherTable("weather", j1, j2 + tt[0] / DAY_S, tt - tt[0], np.array([x.pressure_hpa for x in w]),
                           np.array([x.temperature_c for x in w]), np.zeros(len(tt)))
    configs = tuple(SensorConfig(s.name, s.camera, Installation.from_matrix(s.name, s.camera.name,
                                                                            s.C_deck_from_sensor))
                    for s in spec.sensors)
    return MeasureJob(configs, track, weather, PipelineOptions(), (j1, j2), 0)


def child_starlists(duration_s: float, workers: int, out: str) -> None:
    """Run the star-list session (in the child process); print a JSON line."""
    from shipstar.pipeline._measure import run_measure

    spec = _starlist_spec(duration_s)
    job = _starlist_job(spec)
    sources = [StarLists(spec, j) for j in range(len(spec.sensors))]
    t0 = time.perf_counter()
    outcome = run_measure(job, sources, out, workers=workers)
    wall = time.perf_counter() - t0
    n = sum(len(s.times_utc_jd()[0]) for s in sources)
    t1 = time.perf_counter()
    sources[0].piece(0, 300).load()
    sim_ms = (time.perf_counter() - t1) / 300 * 1000
    print(json.dumps({"frames": n, "wall_s": wall, "complete": outcome.complete, "simulate_ms_per_frame": sim_ms,
                      "epochs": outcome.stats.n_epochs, "failed": outcome.stats.n_failed}))


# -- the parent: runs children and samples their memory ---------------------------------------------

def _tree_rss_mb(proc) -> float:
    import psutil

    try:
        procs = [proc] + proc.children(recursive=True)
    except psutil.Error:
        return 0.0
    total = 0
    for p in procs:
        try:
            total += p.memory_info().rss
        except psutil.Error:
            pass
    return total / 1e6


def run_sampled(cmd, cwd=None) -> tuple[float, float, str, str]:
    """``(wall_s, peak_rss_mb, stdout, stderr)`` of a command, its process tree sampled;
    its CPU time (with its workers') in ``LAST_CPU_S[0]``."""
    import resource

    import psutil

    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_ENV or None)
    ps = psutil.Process(proc.pid)
    peak = [0.0]
    done = threading.Event()

    def sample():
        while not done.is_set():
            peak[0] = max(peak[0], _tree_rss_mb(ps))
            time.sleep(0.05)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    out, err = proc.communicate()
    wall = time.perf_counter() - t0
    done.set()
    th.join()
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    LAST_CPU_S[0] = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"{cmd[:6]} failed ({proc.returncode}): {err[-2000:]}")
    return wall, peak[0], out, err


#: The CPU time of the last :func:`run_sampled` command and the processes it waited for (s).
LAST_CPU_S = [0.0]


def render_images(root: Path, duration_s: float) -> Path:
    from shipstar.calibrate.installation import Installation, save_installation
    from shipstar.simulate._session import sea_session, write_session

    d = root / f"sea_{duration_s:g}s"
    if not (d / "session.toml").exists():
        import shutil

        shutil.rmtree(d, ignore_errors=True)
        t0 = time.perf_counter()
        spec = sea_session(duration_s=duration_s)
        write_session(spec, d)
        for s in spec.sensors:
            save_installation(Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor),
                              d / f"{s.name}.toml")
        print(f"  rendered {d.name} in {time.perf_counter() - t0:.0f} s")
    return d


def read_once(d: Path) -> float:
    """Read every frame file of a session once (s taken): the timed runs then find them in
    the page cache, as each other's repeats do.  Without it the first run (the first pair's
    ``--workers 2``) read a session last touched long ago from disk: 9.1 s against 5.3-5.6 s
    for the same command warm, a pair of 1.00x."""
    t0 = time.perf_counter()
    for s in ("A1", "A2"):
        for p in sorted((d / s).glob("*.fits")):
            with open(p, "rb") as fh:
                while fh.read(1 << 22):
                    pass
    return time.perf_counter() - t0


def measure_images(d: Path, workers: int) -> dict:
    n = sum(len(list((d / s).glob("*.fits"))) for s in ("A1", "A2"))
    out = d / f"att_w{workers}.csv"
    for p in (out, out.with_name(out.name + ".partial"), out.with_name(out.name + ".resume")):
        p.unlink(missing_ok=True)
    cmd = [sys.executable, "-m", "shipstar", "measure", "--sensor", f"A1={d / 'A1'}", "--sensor", f"A2={d / 'A2'}",
           "--install", str(d / "A1.toml"), str(d / "A2.toml"), "--track", str(d / "track.csv"), "--weather",
           str(d / "weather.csv"), "--out", str(out), "--workers", str(workers)]
    wall, peak, _, _ = run_sampled(cmd)
    return {"frames": n, "wall_s": wall, "ms_per_frame": wall / n * 1000, "peak_rss_mb": peak, "csv": out,
            "cpu_s": LAST_CPU_S[0]}


def rest_night(root: Path, minutes: float, block: int = 2000) -> list:
    """A field at rest (dock) at image level for ``minutes`` of night, cheaply: a 1 s dock
    session's 10 A1 frames given again and again to one sensor processor (the whole chain
    per frame: extraction, the sky's tests, identification, attitude, the noise model) with
    times advancing 0.1 s a frame, on a track and weather table covering the run.  Returns
    ``[(frames, ms per frame, traced MB)]`` per block of ``block`` frames: state that grows
    with the night (a frame's cost or memory rising from block to block) shows here, which
    a sea session hides (its moving stars keep the per-pixel maps forgetting)."""
    import tracemalloc

    from shipstar._fitsio import read_fits_image
    from shipstar.calibrate.installation import Installation
    from shipstar.pipeline import Frame, PipelineOptions, SensorConfig, SensorProcessor, Track, WeatherTable, \
        scan_frames
    from shipstar.simulate._session import dock_session, write_session
    from shipstar.sky.time import iso_from_utc_jd

    d = root / "dock_1s"
    spec = dock_session(duration_s=1.0)
    spec = spec.replace(sensors=tuple(s for s in spec.sensors if s.name == "A1"))
    if not (d / "session.toml").exists():
        write_session(spec, d)
    frames = scan_frames(d / "A1")
    images = [read_fits_image(f.path) for f in frames]
    f0 = frames[0]
    n = int(minutes * 600)
    site, weather = (d / "track.csv").read_text().splitlines(), (d / "weather.csv").read_text().splitlines()
    for name, lines in (("track_rest.csv", site), ("weather_rest.csv", weather)):
        values = lines[1].split(",", 1)[1]
        rows = [lines[0]] + [f"{iso_from_utc_jd(f0.utc_jd1, f0.utc_jd2 + (k - 1.0) / 86400.0, 6)},{values}"
                             for k in range(0, int(n * 0.1) + 20, 10)]
        (d / name).write_text("\n".join(rows) + "\n")
    s = spec.sensors[0]
    proc = SensorProcessor(SensorConfig(s.name, s.camera, Installation.from_matrix(s.name, s.camera.name,
                                                                                 s.C_deck_from_sensor)),
                           Track.read_csv(d / "track_rest.csv"), WeatherTable.read_csv(d / "weather_rest.csv"),
                           PipelineOptions())
    out, t0 = [], time.perf_counter()
    tracemalloc.start()
    try:
        for k in range(n):
            t_s = 0.1 * k
            j = k % len(images)
            proc.process(Frame(f0.utc_jd1, f0.utc_jd2 + t_s / 86400.0, label=f"#{k}", image=images[j],
                               exposure_s=frames[j].exposure_s), k, t_s)
            if (k + 1) % block == 0:
                out.append((k + 1, (time.perf_counter() - t0) / block * 1000, tracemalloc.get_traced_memory()[0] / 1e6))
                t0 = time.perf_counter()
    finally:
        tracemalloc.stop()
    return out


def _row(label, r, start=None) -> str:
    steady = "" if start is None else f" {(r['wall_s'] - start['wall_s']) / (r['frames'] - start['frames']) * 1000:8.2f}"
    return f"{label:34s} {r['frames']:8d} {r['wall_s']:9.1f} {r['ms_per_frame']:8.2f}{steady} {r['peak_rss_mb']:11.0f}"


def _steady(r, start) -> float:
    return (r["wall_s"] - start["wall_s"]) / (r["frames"] - start["frames"]) * 1000


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", default="images,workers,starlists,rest")
    ap.add_argument("--hours", type=float, default=10.0, help="the long star-list run (default 10 h)")
    ap.add_argument("--image-minutes", type=float, default=6.0, help="the long image run (default 6 min)")
    ap.add_argument("--rest-minutes", type=float, default=20.0,
                    help="the field at rest, in this process (default 20 min of night: 12 000 frames, ~3 min)")
    ap.add_argument("--workdir", type=Path, help="where image sessions are rendered and kept")
    ap.add_argument("--repeat", type=int, default=3, help="--workers 1 / 2 pairs (default 3)")
    ap.add_argument("--no-bytecode-cache", action="store_true",
                    help="run the commands with the environment as it is (see the docstring)")
    ap.add_argument("--child-starlists", type=float, help=argparse.SUPPRESS)
    ap.add_argument("--workers", type=int, default=2, help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child_starlists:
        child_starlists(args.child_starlists, args.workers, args.out)
        return 0
    parts = set(args.parts.split(","))
    root = args.workdir or Path(tempfile.mkdtemp(prefix="shipstar-bench-scale-"))
    root.mkdir(parents=True, exist_ok=True)
    bytecode = None if args.no_bytecode_cache else Path(tempfile.mkdtemp(prefix="shipstar-bench-scale-pycache-"))
    if bytecode is not None:
        precompile(bytecode)
    _ENV.update(command_env(bytecode))
    print(f"== shipstar measure at scale ({os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}); work dir {root}")
    header = (f"{'run':34s} {'frames':>8s} {'wall s':>9s} {'ms/frame':>8s} {'steady':>8s} {'peak RSS MB':>11s}")
    if parts & {"images", "workers"}:
        print("\n-- 1/2. image frames (FITS, extraction included), measure --workers N\n" + header)
        tiny, short = render_images(root, 2.0), render_images(root, 60.0)
        print(f"  the 60 s session's frames read once (page cache) in {read_once(short):.1f} s")
        t2 = measure_images(tiny, 2)
        print(_row("images 2 s (start-up), --workers 2", t2))
        r2 = measure_images(short, 2)
        print(_row("images 60 s, --workers 2", r2, t2))
        if "workers" in parts:
            t1 = measure_images(tiny, 1)
            print(_row("images 2 s (start-up), --workers 1", t1))
            ratios, fixed, drift = [], [], []
            for k in range(args.repeat):            # alternated: this shared machine's speed drifts
                r1 = measure_images(short, 1)
                print(_row(f"images 60 s, --workers 1 (#{k + 1})", r1, t1))
                if k:
                    r2 = measure_images(short, 2)
                    print(_row(f"images 60 s, --workers 2 (#{k + 1})", r2, t2))
                ratios.append(r1["wall_s"] / r2["wall_s"])
                # the same work's CPU time moves with the shared host's speed: each run's wall
                # time per CPU second removes that drift from the pair
                fixed.append((r1["wall_s"] / r1["cpu_s"]) / (r2["wall_s"] / r2["cpu_s"]))
                drift.append(r1["cpu_s"] / r2["cpu_s"])
                same = r1["csv"].read_bytes() == r2["csv"].read_bytes()
            speedup = float(np.median(ratios))
            print(f"--workers 2 vs 1 on 60 s, wall time, pairs run back to back: {', '.join(f'{r:.2f}' for r in ratios)}"
                  f"x, median {speedup:.2f}x (target >= 1.7x: {'PASS' if speedup >= 1.7 else 'FAIL'}); "
                  f"the same CSV: {same}")
            print(f"  the pairs corrected for the host's speed (wall per CPU second): "
                  f"{', '.join(f'{r:.2f}' for r in fixed)}x, median {float(np.median(fixed)):.2f}x; the pairs' CPU "
                  f"times, 1 against 2 workers: {', '.join(f'{r:.2f}' for r in drift)} (1.00 = the same host speed)")
        if "images" in parts:
            long = render_images(root, 60.0 * args.image_minutes)
            read_once(long)
            rl = measure_images(long, 2)
            print(_row(f"images {args.image_minutes:g} min, --workers 2", rl, t2))
            print(f"{args.image_minutes:g} min / 60 s: steady ms/frame {_steady(rl, t2) / _steady(r2, t2):.3f}, "
                  f"peak RSS {rl['peak_rss_mb'] / r2['peak_rss_mb']:.3f}")
    if "rest" in parts:
        print(f"\n-- 4. a field at rest (dock frames), the sensor chain in this process, {args.rest_minutes:g} min "
              f"of night at 10 frames/s")
        blocks = rest_night(root, args.rest_minutes)
        for frames, ms, mb in blocks:
            print(f"  frames {frames - 1999:6d}-{frames:6d}: {ms:6.2f} ms/frame, traced memory {mb:6.1f} MB")
        (_, ms0, mb0), (_, ms1, mb1) = blocks[0], blocks[-1]
        print(f"targets: the last block's ms/frame within 10 % of the first: {'PASS' if ms1 <= 1.10 * ms0 else 'FAIL'} "
              f"({ms1 / ms0:.3f}); traced memory within 2 MB of the first block's: "
              f"{'PASS' if mb1 - mb0 <= 2.0 else 'FAIL'} ({mb1 - mb0:+.1f} MB)")
    if "starlists" in parts:
        print("\n-- 3. star lists (the stages after extraction), --workers 2\n" + header + "   simulate ms/frame")
        results = {}
        for duration_s in (2.0, 60.0, 3600.0, 3600.0 * args.hours):
            out = root / f"starlists_{duration_s:g}s.csv"
            for p in (out, out.with_name(out.name + ".partial"), out.with_name(out.name + ".resume")):
                p.unlink(missing_ok=True)
            wall, peak, stdout, _ = run_sampled([sys.executable, __file__, "--child-starlists", str(duration_s),
                                                 "--workers", "2", "--out", str(out)])
            info = json.loads(stdout.strip().splitlines()[-1])
            r = {"frames": info["frames"], "wall_s": wall, "ms_per_frame": wall / info["frames"] * 1000,
                 "peak_rss_mb": peak}
            results[duration_s] = r
            label = "star lists 2 s (start-up)" if duration_s == 2.0 else f"star lists {duration_s / 3600:g} h"
            print(_row(label, r, None if duration_s == 2.0 else results[2.0]) + f"   {info['simulate_ms_per_frame']:8.2f}"
                  + ("" if info["complete"] else "  INCOMPLETE"))
            out.unlink(missing_ok=True)
        start, base = results[2.0], results[60.0]
        for d, r in results.items():
            if d > 60.0:
                print(f"{d / 3600:g} h / 60 s: steady ms/frame {_steady(r, start) / _steady(base, start):.3f}, "
                      f"peak RSS {r['peak_rss_mb'] / base['peak_rss_mb']:.3f}")
        one_h = _steady(results[3600.0], start) / _steady(base, start)
        longest = results[3600.0 * args.hours]
        print(f"targets: ms/frame at 1 h within 10 % of 60 s: {'PASS' if abs(one_h - 1) <= 0.10 else 'FAIL'} "
              f"({one_h:.3f}); peak RSS at {args.hours:g} h under 400 MB: "
              f"{'PASS' if longest['peak_rss_mb'] < 400 else 'FAIL'} ({longest['peak_rss_mb']:.0f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
