"""One star identifier behind a pipe, for bench_identify.py: cedar-solve or tetra3rs (run
by the peers' own venv, ``benchmarks/.peers-venv`` from ``make_env.sh``: their pins,
Pillow < 9 and NumPy < 2 for cedar-solve, cannot share shipstar's environment), or
shipstar (run by shipstar's venv).  Every solver thus runs the same way: its own
process, frames over the same pipe, its own solve calls timed inside it.  Nothing from
shipstar is imported unless the solver is shipstar.

Protocol: one JSON object per line on stdin, one JSON reply per line on stdout.

``{"cmd": "init", "solver": "cedar-solve" | "tetra3rs", "base": path, "catalog": path,
"max_fov_deg": float, "mag_limit": float}``
    Load the peer's database from ``base`` (cached) or generate it from the star list
    ``catalog`` (written by bench_identify.py from shipstar's database: the same stars)
    and save it there.  Reply ``{"build_time_s", "size_bytes", "n_patterns"}``.
``{"cmd": "solve", "xy": [[a, b], ...], "width_px", "height_px", "fov_estimate_deg",
"fov_max_error_deg", "timeout_s", "hint": 3x3 or null, "hint_deg"}``
    Solve one frame.  ``xy`` is already in the peer's own pixel convention (cedar-solve:
    (y, x) from the top-left corner; tetra3rs: (x, y) from the principal point).  Reply
    ``{"solved", "ra_deg", "dec_deg", "parity_flip", "rows", "ids", "time_s"}``:
    ``time_s`` is ``time.perf_counter()`` around the solve call only (the peer's own
    Python entry included, the pipe and JSON excluded), as shipstar's solves are timed;
    ``rows`` are the input rows of the matched centroids and ``ids`` their catalog ids.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time

import numpy as np


class Cedar:
    def __init__(self, req):
        import tetra3

        logging.getLogger("tetra3.Tetra3").setLevel(logging.WARNING)
        base = req["base"]
        self.t3 = tetra3.Tetra3(load_database=None)
        logging.getLogger("tetra3.Tetra3").setLevel(logging.WARNING)
        self.info = {}
        if not os.path.exists(base + ".npz"):
            t0 = time.perf_counter()
            self.t3.generate_database(max_fov=req["max_fov_deg"], save_as=base,
                                      star_catalog=req["catalog"],
                                      star_max_magnitude=req["mag_limit"],
                                      epoch_proper_motion=None)
            self.info["build_time_s"] = time.perf_counter() - t0
        self.t3.load_database(base)          # a freshly generated Tetra3 lacks num_patterns
        self.info["size_bytes"] = os.path.getsize(base + ".npz")
        self.info["n_patterns"] = int(self.t3.num_patterns or 0)

    def solve(self, req):
        yx = np.asarray(req["xy"], dtype=float).reshape(-1, 2)
        size = (req["height_px"], req["width_px"])
        t = time.perf_counter()
        res = self.t3.solve_from_centroids(yx, size, fov_estimate=req["fov_estimate_deg"],
                                           fov_max_error=req["fov_max_error_deg"],
                                           solve_timeout=req["timeout_s"] * 1000.0,
                                           return_matches=True)
        dt = time.perf_counter() - t
        if res.get("RA") is None:
            return {"solved": False, "time_s": dt}
        cent = np.asarray(res["matched_centroids"], float).reshape(-1, 2)
        rows = [int(np.argmin(np.sum((yx - c) ** 2, axis=1))) for c in cent]
        return {"solved": True, "ra_deg": float(res["RA"]), "dec_deg": float(res["Dec"]),
                "parity_flip": False, "rows": rows,
                "ids": [int(h) for h in res["matched_catID"]], "time_s": dt}


class Tetra3rs:
    def __init__(self, req):
        import tetra3rs

        base = req["base"]
        self.info = {}
        if os.path.exists(base):
            self.sdb = tetra3rs.SolverDatabase.load_from_file(base)
        else:
            t0 = time.perf_counter()
            self.sdb = tetra3rs.SolverDatabase.generate_from_gaia(
                catalog_path=req["catalog"], max_fov_deg=req["max_fov_deg"],
                star_max_magnitude=req["mag_limit"])
            self.info["build_time_s"] = time.perf_counter() - t0
            self.sdb.save_to_file(base)
        self.info["size_bytes"] = os.path.getsize(base)
        self.info["n_patterns"] = int(self.sdb.num_patterns)

    def solve(self, req):
        xy = np.asarray(req["xy"], dtype=float).reshape(-1, 2)
        kw = {}
        if req.get("hint") is not None:
            kw = {"attitude_hint": np.asarray(req["hint"], dtype=float),
                  "hint_uncertainty_deg": req["hint_deg"], "strict_hint": True}
        t = time.perf_counter()
        res = self.sdb.solve_from_centroids(xy, fov_estimate_deg=req["fov_estimate_deg"],
                                            image_width=req["width_px"],
                                            image_height=req["height_px"],
                                            fov_max_error_deg=req["fov_max_error_deg"],
                                            solve_timeout_ms=int(req["timeout_s"] * 1000), **kw)
        dt = time.perf_counter() - t
        if not res:
            return {"solved": False, "time_s": dt}
        return {"solved": True, "ra_deg": float(res.ra_deg), "dec_deg": float(res.dec_deg),
                "parity_flip": bool(res.parity_flip),
                "rows": [int(i) for i in res.matched_centroids],
                "ids": [int(h) for h in res.matched_catalog_ids], "time_s": dt}


class Shipstar:
    """shipstar, from its own venv (``init``: ``camera`` = a preset name)."""

    def __init__(self, req):
        from shipstar.camera import camera_preset
        from shipstar.identify import build_database

        self.camera = camera_preset(req["camera"])
        self.db = build_database(self.camera)
        self.info = {"size_bytes": self.db.size_bytes, "n_patterns": self.db.n_patterns}

    def solve(self, req):
        import math

        from shipstar.identify import identify_lost_in_space, identify_tracking

        xy = np.asarray(req["xy"], dtype=float).reshape(-1, 2)
        cam = self.camera
        if req.get("hint") is not None:
            prior = np.asarray(req["hint"], dtype=float)
            t = time.perf_counter()
            r = identify_tracking(xy, self.db, prior, camera=cam, prior_error_deg=req["hint_deg"],
                                  fallback=False)
            dt = time.perf_counter() - t
        else:
            fov = req["fov_estimate_deg"]
            f_mm = 0.5 * cam.width_px * cam.pixel_mm / math.tan(math.radians(0.5 * fov))
            est = cam.replace(f_mm=f_mm)
            tol = req["focal_tolerance"]
            t = time.perf_counter()
            r = identify_lost_in_space(xy, self.db, camera=est, focal_tolerance=tol,
                                       max_time_s=req["timeout_s"])
            dt = time.perf_counter() - t
        if not r.solved:
            return {"solved": False, "time_s": dt}
        m = np.flatnonzero(r.hip >= 0)
        return {"solved": True, "bore": r.C_icrs_from_sensor[:, 0].tolist(),
                "C": r.C_icrs_from_sensor.tolist(), "parity_flip": False,
                "rows": m.tolist(), "ids": r.hip[m].tolist(),
                "star_index": r.star_index.tolist(), "time_s": dt}


def main() -> int:
    solver = None
    out = sys.stdout
    for line in sys.stdin:
        req = json.loads(line)
        cmd = req.get("cmd")
        if cmd == "init":
            solver = {"cedar-solve": Cedar, "tetra3rs": Tetra3rs, "shipstar": Shipstar}[req["solver"]](req)
            reply = solver.info
        elif cmd == "solve":
            reply = solver.solve(req)
        elif cmd == "quit":
            break
        else:
            reply = {"error": f"unknown command {cmd!r}"}
        out.write(json.dumps(reply) + "\n")
        out.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
