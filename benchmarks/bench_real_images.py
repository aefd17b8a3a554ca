"""Real night-sky photos, solved with and without a field-of-view hint: shipstar against
cedar-solve and tetra3rs.

Each image of ``/work/shared/real-images`` (README there; approximate horizontal FOV
below) is solved by

* shipstar, in this process: ``solve_image(path, fov_deg=FOV)`` (hint: +-10 %) and
  ``solve_image(path)`` (blind: the field-of-view bands, short side 3.4 .. 31.5 deg);
  its own extraction; the band databases are loaded once before timing (warm cache);
  wall ms is the whole ``solve_image`` call (read + extract + identify + fit);
* cedar-solve and tetra3rs, in their own venv (``benchmarks/.peers-venv``, made by
  ``sh benchmarks/peers/make_env.sh``; their pins clash with shipstar's), by
  ``benchmarks/peers/peer_real_images.py``: hint = the same FOV +-10 %; blind = cedar's
  default database (10-30 deg) with no estimate, tetra3rs (which always needs one) with
  15.5 +- 6.5 deg, its database's 9-22 deg range.  Their wall ms excludes the image
  decode.

The table gives, per photo and mode, each solver's boresight, matched stars and wall
time, and the largest boresight disagreement between the solvers that solved it
(arcmin).  A shipstar solution is *wrong* if it disagrees with a peer's by more than
6 arcmin (0.1 deg); the bench fails (exit 1) if shipstar leaves unsolved a photo a peer
solves in the same mode, or is wrong anywhere.

    python benchmarks/bench_real_images.py [--images DIR] [--peer-python PY]
                                           [--no-peers] [--write-reference FILE]

``--write-reference`` stores the peers' hinted solutions (cedar-solve's, else
tetra3rs') as the JSON reference of ``tests/identify/test_solve_image.py``.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from shipstar.frames import unit_from_ra_dec
from shipstar.identify import solve_image

FOV_DEG = {"orion2": 10, "orion_belt": 10, "orion_trees": 10, "pleiades": 10, "virgo": 20,
           "crappy": 10, "roof": 10, "test2_g100_e50ms": 11}
AGREE_DEG = 0.1
HERE = Path(__file__).resolve().parent
PEER_PYTHONS = (HERE / ".peers-venv" / "bin" / "python", Path("/tmp/peertry/venv/bin/python"))
PEERS = ("cedar-solve", "tetra3rs")


def _sep_deg(a, b) -> float:
    ua = unit_from_ra_dec(math.radians(a[0]), math.radians(a[1]))
    ub = unit_from_ra_dec(math.radians(b[0]), math.radians(b[1]))
    return math.degrees(math.atan2(np.linalg.norm(np.cross(ua, ub)), float(ua @ ub)))


def run_peers(python, images) -> dict:
    """``{(image, solver, mode): row}`` from peer_real_images.py in the peers' venv."""
    from shipstar.sky.catalog import cache_dir

    db = cache_dir() / "bench" / "identify" / "tetra3rs_gaia_9_22.bin"
    cmd = [str(python), str(HERE / "peers" / "peer_real_images.py"), "--tetra3rs-db", str(db)]
    cmd += [f"{p}={FOV_DEG.get(p.stem, 10)}" for p in images]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    if proc.returncode != 0:
        print(f"peers failed ({proc.returncode}): {proc.stderr.strip()[-500:]}", file=sys.stderr)
    out = {}
    for line in proc.stdout.splitlines():
        row = json.loads(line)
        out[(row["image"], row["solver"], row["mode"])] = row
    return out


def run_shipstar(path, fov, repeats: int):
    """Best-of-``repeats`` wall time and the result of one mode."""
    best, res = math.inf, None
    for _ in range(repeats):
        t = time.perf_counter()
        res = solve_image(path, fov_deg=fov)
        best = min(best, time.perf_counter() - t)
    row = {"solved": bool(res.solved), "wall_ms": 1e3 * best, "reason": res.reason}
    if res.solved:
        row.update(ra_deg=res.ra_deg, dec_deg=res.dec_deg, roll_deg=res.roll_deg,
                   fov_deg=res.fov_deg, matches=res.matched, p_false=res.p_false)
    return row


def _cell(row) -> str:
    if row is None:
        return f"{'-':>37}"
    if not row["solved"]:
        return f"{'not solved':>26} {row['wall_ms']:8.0f} ms"
    return (f"{row['ra_deg']:8.3f} {row['dec_deg']:+7.3f} {row['matches']:4d}"
            f"  {row['wall_ms']:8.0f} ms")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", default="/work/shared/real-images")
    ap.add_argument("--peer-python", help="python of the peers' venv (default: "
                    "benchmarks/.peers-venv, else /tmp/peertry/venv)")
    ap.add_argument("--no-peers", action="store_true", help="shipstar alone")
    ap.add_argument("--repeats", type=int, default=3, help="shipstar: best of N (default 3)")
    ap.add_argument("--write-reference", metavar="FILE", help="write the peers' hinted solutions")
    args = ap.parse_args(argv)
    images = sorted(Path(args.images).glob("*.jpg"))
    if not images:
        print(f"no *.jpg in {args.images}", file=sys.stderr)
        return 2
    peers = {}
    if not args.no_peers:
        python = Path(args.peer_python) if args.peer_python else next(
            (p for p in PEER_PYTHONS if p.exists()), None)
        if python is None:
            print("no peers' venv: run 'sh benchmarks/peers/make_env.sh' (or --no-peers)",
                  file=sys.stderr)
            return 2
        t = time.perf_counter()
        peers = run_peers(python, images)
        print(f"peers ({python}): {time.perf_counter() - t:.0f} s")
    from shipstar.identify._blind import BANDS, band_database

    for b in BANDS:                                       # warm cache: load (or build) once
        band_database(b)
    solve_image(images[0], fov_deg=FOV_DEG.get(images[0].stem, 10))     # warm imports
    failures, rows = [], []
    width = 37
    print(f"\n{'photo':<17} {'mode':<5} | " + " | ".join(f"{s:^{width}}" for s in ("shipstar", *PEERS))
          + " | max disagreement")
    print(f"{'':<17} {'':<5} | " + " | ".join(f"{'RA deg   Dec deg  stars      wall':>{width}}"
                                                for _ in range(3)) + " |   arcmin")
    counts = {(s, m): [0, 0] for s in ("shipstar", *PEERS) for m in ("hint", "blind")}
    for path in images:
        name, fov = path.stem, FOV_DEG.get(path.stem, 10)
        for mode in ("hint", "blind"):
            ship = run_shipstar(path, fov if mode == "hint" else None, args.repeats)
            cells = {"shipstar": ship, **{s: peers.get((name, s, mode)) for s in PEERS}}
            solved = {s: r for s, r in cells.items() if r is not None and r["solved"]}
            for s, r in cells.items():
                if r is not None:
                    counts[(s, mode)][1] += 1
                    counts[(s, mode)][0] += bool(r["solved"])
            pairs = [(a, b) for i, a in enumerate(solved) for b in list(solved)[i + 1:]]
            dis = max((_sep_deg((solved[a]["ra_deg"], solved[a]["dec_deg"]),
                                (solved[b]["ra_deg"], solved[b]["dec_deg"])) for a, b in pairs),
                      default=math.nan)
            print(f"{name:<17} {mode:<5} | " + " | ".join(_cell(cells[s]) for s in ("shipstar", *PEERS))
                  + f" | {60 * dis:8.2f}")
            for s in PEERS:
                if s in solved and "shipstar" not in solved:
                    failures.append(f"{name} {mode}: {s} solves it, shipstar does not ({ship['reason']})")
                if s in solved and "shipstar" in solved:
                    sep = _sep_deg((ship["ra_deg"], ship["dec_deg"]),
                                   (solved[s]["ra_deg"], solved[s]["dec_deg"]))
                    if sep > AGREE_DEG:
                        failures.append(f"{name} {mode}: shipstar disagrees with {s} by {sep:.3f} deg")
            rows.append((name, mode, cells))
    print("\nsolved (of photos run):  " + ",  ".join(
        f"{s} {m} {c[0]}/{c[1]}" for (s, m), c in counts.items() if c[1]))
    ship_ms = {m: [r["shipstar"]["wall_ms"] for _, mm, r in rows if mm == m] for m in ("hint", "blind")}
    print("shipstar wall ms (solve_image, warm, best of %d): hint median %.0f max %.0f; "
          "blind median %.0f max %.0f" % (args.repeats, np.median(ship_ms["hint"]), max(ship_ms["hint"]),
                                          np.median(ship_ms["blind"]), max(ship_ms["blind"])))
    if args.write_reference:
        reference = {}
        for name, mode, cells in rows:
            if mode != "hint":
                continue
            for s in PEERS:
                r = cells.get(s)
                if r is not None and r["solved"] and name not in reference:
                    reference[name] = {"fov_deg_nominal": FOV_DEG.get(name, 10), "solver": s,
                                       "ra_deg": r["ra_deg"], "dec_deg": r["dec_deg"],
                                       "roll_deg": r["roll_deg"], "fov_deg": r["fov_deg"]}
        Path(args.write_reference).write_text(json.dumps(reference, indent=1) + "\n")
        print(f"wrote {len(reference)} reference solutions to {args.write_reference}")
    for f in failures:
        print("FAIL", f)
    print("every photo a peer solves is solved by shipstar, none wrong" if not failures else
          f"{len(failures)} failure(s)")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
