"""Peer plate solvers on real photos, run inside the peers' venv (benchmarks/.peers-venv,
made by benchmarks/peers/make_env.sh): cedar-solve and tetra3rs, each with and without a
field-of-view hint.  Called by benchmarks/bench_real_images.py; prints one JSON object a
line:

    {"image", "solver", "mode" ("hint" | "blind"), "solved", "ra_deg", "dec_deg",
     "roll_deg", "fov_deg", "matches", "wall_ms"}

roll_deg is converted to shipstar's convention (position angle of the image's up
direction, north through east; docs/conventions.md).  wall_ms is the solve call alone
(cedar: its own extraction + solve from the PIL image; tetra3rs: its extract_centroids
+ solve_from_centroids), not the image decode.

* hint: fov_estimate = the photo's nominal FOV, +-10 %.
* blind: cedar-solve with no fov_estimate (its default database: 10-30 deg fields);
  tetra3rs needs an estimate: 15.5 deg +-6.5 (its database's 9-22 deg range).

    python peer_real_images.py --tetra3rs-db FILE IMAGE=FOV_DEG [IMAGE=FOV_DEG ...]
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

TETRA3RS_RANGE_DEG = (9.0, 22.0)


def _cedar(t3, img, fov):
    t = time.perf_counter()
    if fov is None:
        r = t3.solve_from_image(img, solve_timeout=10000)
    else:
        r = t3.solve_from_image(img, fov_estimate=fov, fov_max_error=0.1 * fov, solve_timeout=10000)
    dt = time.perf_counter() - t
    if r.get("RA") is None:
        return None, dt
    # cedar's roll runs the other way round from shipstar's
    return {"ra_deg": r["RA"], "dec_deg": r["Dec"], "roll_deg": (-r["Roll"]) % 360.0,
            "fov_deg": r["FOV"], "matches": int(r["Matches"])}, dt


def _tetra3rs_db(path):
    import tetra3rs

    path = Path(path)
    if path.exists():
        return tetra3rs.SolverDatabase.load_from_file(str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    lo, hi = TETRA3RS_RANGE_DEG
    db = tetra3rs.SolverDatabase.generate_from_gaia(max_fov_deg=hi, min_fov_deg=lo)
    db.save_to_file(str(path))
    return db


def _tetra3rs(db, gray, fov):
    import tetra3rs

    h, w = gray.shape
    if fov is None:
        lo, hi = TETRA3RS_RANGE_DEG
        est, err = 0.5 * (lo + hi), 0.5 * (hi - lo)
    else:
        est, err = fov, 0.1 * fov
    t = time.perf_counter()
    ex = tetra3rs.extract_centroids(gray, sigma_threshold=5.0, max_centroids=100)
    r = db.solve_from_centroids(ex.centroids, fov_estimate_deg=est, image_width=w, image_height=h,
                                fov_max_error_deg=err, solve_timeout_ms=10000)
    dt = time.perf_counter() - t
    if not r or r.parity_flip:
        return None, dt
    # tetra3rs' roll is the position angle of camera +Y, which points *down* the image
    return {"ra_deg": r.ra_deg, "dec_deg": r.dec_deg, "roll_deg": (r.roll_deg + 180.0) % 360.0,
            "fov_deg": r.fov_deg, "matches": int(r.num_matches)}, dt


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tetra3rs-db", required=True, help="tetra3rs database file (made if missing)")
    ap.add_argument("images", nargs="+", metavar="IMAGE=FOV_DEG")
    args = ap.parse_args(argv)
    from PIL import Image

    import tetra3

    logging.getLogger("tetra3.Tetra3").setLevel(logging.WARNING)
    t3 = tetra3.Tetra3()
    rsdb = _tetra3rs_db(args.tetra3rs_db)
    for item in args.images:
        path, fov = item.rsplit("=", 1)
        with Image.open(path) as img:
            img.load()
            gray = np.asarray(img.convert("L"), dtype=np.float32)
            for mode, hint in (("hint", float(fov)), ("blind", None)):
                for solver, fn in (("cedar-solve", lambda h: _cedar(t3, img, h)),
                                   ("tetra3rs", lambda h: _tetra3rs(rsdb, gray, h))):
                    try:
                        sol, dt = fn(hint)
                    except Exception as exc:          # a peer's crash is a result, not ours
                        sol, dt = None, float("nan")
                        print(f"{solver} {Path(path).name} {mode}: {exc!r}", file=sys.stderr)
                    row = {"image": Path(path).stem, "solver": solver, "mode": mode,
                           "solved": sol is not None, "wall_ms": 1e3 * dt, **(sol or {})}
                    print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
