"""All-star attitude vs seed 004's three-star boresight, and solver timing.

Part 1 (accuracy, seed 004 sec. 2.3.3 / 3.3.3): simulate many star fields (default
1000 fields, 10-30 stars in a 12 x 12 deg, 512 x 512 pixel field as in seed 004,
centroid noise 0.1-0.3 px), solve the boresight from every 3-star combination and from
all stars, and print the fraction of 3-star combinations each all-star solution beats
(seed 004: ~90 % vector / ~97 % scalar input) and how the seed's error-bound "best 3"
ranks (seed 004: ~81 % / ~86 %).

Part 2 (speed): time QUEST, SVD and ESOQ2 per solve for 10, 20 and 50 stars against
the anchor, SciPy's ``Rotation.align_vectors`` (Kabsch/SVD), in the same run, and print
the ratios; also the per-solve cost in a batch of 1000.

Run:  python benchmarks/bench_three_star.py [--fields 1000] [--seed 1]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from shipstar.attitude import (
    all_triples,
    best_three_stars,
    boresight_from_three_radii,
    boresight_from_three_stars,
    esoq2,
    quest,
    solve_attitude,
    svd_attitude,
)
from shipstar.frames import C_icrs_from_sensor, orthonormalize
from shipstar.units import DEG2RAD, RAD2ASEC

WIDTH_PX = 512
FOV_DEG = 12.0
PIXEL_MM = 0.014
# seed 004: f = 256 / tan 6 deg pixels
F_MM = 0.5 * WIDTH_PX * PIXEL_MM / math.tan(0.5 * FOV_DEG * DEG2RAD)


def sensor_dirs(xy_mm):
    s = np.stack([np.full(xy_mm.shape[:-1], F_MM), xy_mm[..., 1], xy_mm[..., 0]], -1)
    return s / np.linalg.norm(s, axis=-1, keepdims=True)


def sep_rad(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def one_field(rng, args):
    n = int(rng.integers(args.stars_min, args.stars_max + 1))
    sigma_px = rng.uniform(args.noise_min_px, args.noise_max_px)
    C = C_icrs_from_sensor(rng.uniform(0, 2 * np.pi), math.asin(rng.uniform(-1, 1)),
                           rng.uniform(0, 2 * np.pi))
    xy_px = rng.uniform(-0.5, WIDTH_PX - 0.5, size=(n, 2)) - 0.5 * (WIDTH_PX - 1)
    xy_true = xy_px * np.array([1.0, -1.0]) * PIXEL_MM        # X right, Y up
    u = sensor_dirs(xy_true) @ C.T
    xy = xy_true + rng.normal(scale=sigma_px * PIXEL_MM, size=xy_true.shape)
    return C, u, xy, sigma_px


def ranks(err_all, err_triples):
    """Fraction of triples whose error exceeds ``err_all`` (failed triples count as worse)."""
    e = np.where(np.isfinite(err_triples), err_triples, np.inf)
    return float(np.mean(e > err_all))


def field_figures(rng, args):
    C, u, xy, sigma_px = one_field(rng, args)
    bore = C[:, 0]
    s = sensor_dirs(xy)
    T = all_triples(len(xy))
    # vector input (seed 004 ch. 3)
    tri = boresight_from_three_stars(xy[T], F_MM, u[T], max_angle_residual_arcsec=None)
    e_tri = sep_rad(tri.boresight_icrs, bore)
    sigma_rad = sigma_px * PIXEL_MM / F_MM
    sol = solve_attitude(s, u, sigma_rad=sigma_rad)
    e_quest = sep_rad(sol.C_ref_from_body[:, 0], bore)
    C_ols = orthonormalize(np.linalg.lstsq(u, s, rcond=None)[0])         # sec. 3.3.2 (1)
    e_ols = sep_rad(C_ols[:, 0], bore)
    best = best_three_stars(xy, F_MM, u)
    k = int(np.flatnonzero(np.all(T == best.indices, axis=1))[0])
    # scalar input (seed 004 ch. 2): radii only
    a = np.linalg.norm(xy, axis=-1)
    tri_r = boresight_from_three_radii(a[T], F_MM, u[T])
    e_tri_r = sep_rad(tri_r.boresight_icrs, bore)
    b = F_MM / np.sqrt(F_MM ** 2 + a ** 2)
    w_ols = np.linalg.lstsq(u, b, rcond=None)[0]                          # sec. 2.3.2 (1)
    e_ols_r = sep_rad(w_ols / np.linalg.norm(w_ols), bore)
    return {
        "vec_quest": ranks(e_quest, e_tri), "vec_ols": ranks(e_ols, e_tri),
        "vec_best3": ranks(e_tri[k], np.delete(e_tri, k)),
        "sca_ols": ranks(e_ols_r, e_tri_r), "sca_quest": ranks(e_quest, e_tri_r),
        "sca_best3": ranks(e_tri_r[k], np.delete(e_tri_r, k)),
        "err_quest": e_quest, "err_best3": e_tri[k], "err_median3": np.nanmedian(e_tri),
        "n_triples": len(T),
    }


def accuracy(args):
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    rows = [field_figures(rng, args) for _ in range(args.fields)]
    dt = time.perf_counter() - t0
    n_tri = sum(r["n_triples"] for r in rows)
    print(f"== accuracy: {args.fields} fields, {args.stars_min}-{args.stars_max} stars, "
          f"{FOV_DEG:g} deg / {WIDTH_PX} px, noise {args.noise_min_px}-{args.noise_max_px} px "
          f"({n_tri} triples, {dt:.1f} s) ==")

    def line(label, key, seed_figure):
        v = np.array([r[key] for r in rows])
        print(f"  {label:<52s} mean {100 * v.mean():5.1f} %  median {100 * np.median(v):5.1f} %"
              f"  p10 {100 * np.percentile(v, 10):5.1f} %   (seed 004: {seed_figure})")

    print(" fraction of 3-star combinations beaten, vector input (image X, Y):")
    line("all-star QUEST (Wahba, sigma-weighted)", "vec_quest", "~90 %")
    line("all-star seed OLS (sec. 3.3.2 (1): lstsq + SVD)", "vec_ols", "~90 %")
    line("error-bound best 3 (sec. 3.3.1)", "vec_best3", "~81 %")
    print(" fraction of 3-star combinations beaten, scalar input (radii only, sec. 2.1):")
    line("all-star seed OLS (sec. 2.3.2 (1))", "sca_ols", "~97 %")
    line("all-star QUEST (uses X, Y as well)", "sca_quest", "-")
    line("error-bound best 3 (sec. 2.3.1)", "sca_best3", "~86 %")
    for key, label in (("err_quest", "all-star QUEST"), ("err_best3", "best-3 (vector)"),
                       ("err_median3", "median 3-star (vector)")):
        v = np.array([r[key] for r in rows]) * RAD2ASEC
        print(f"  boresight error, {label:<24s} RMS {math.sqrt(np.mean(v ** 2)):7.3f} arcsec")


def _time_per_call(fn, repeat=5, number=300):
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t0) / number)
    return best


def speed(args):
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(args.seed + 1)
    print("== speed: per solve, best of 5 (anchor: scipy Rotation.align_vectors) ==")
    print(f"  {'stars':>5s} {'scipy':>10s} {'quest':>10s} {'svd':>10s} {'esoq2':>10s}"
          f" {'solve_att.':>11s}   ratio scipy/quest, /svd, /esoq2")
    for n in (10, 20, 50):
        C = C_icrs_from_sensor(1.0, 0.3, 2.0)
        w = sensor_dirs(rng.uniform(-3.5, 3.5, size=(n, 2)))
        v = w @ C.T
        t_ref = _time_per_call(lambda: Rotation.align_vectors(v, w))
        t = {f.__name__: _time_per_call(lambda f=f: f(w, v)) for f in (quest, svd_attitude, esoq2)}
        t_solve = _time_per_call(lambda: solve_attitude(w, v), number=100)
        tq, ts, te = t["quest"], t["svd_attitude"], t["esoq2"]
        print(f"  {n:5d} {1e6 * t_ref:8.1f}us {1e6 * tq:8.1f}us {1e6 * ts:8.1f}us"
              f" {1e6 * te:8.1f}us {1e6 * t_solve:9.1f}us   "
              f"{t_ref / tq:5.2f} {t_ref / ts:5.2f} {t_ref / te:5.2f}")
    W = sensor_dirs(rng.uniform(-3.5, 3.5, size=(1000, 20, 2)))
    V = W @ C.T
    print("  batch of 1000 x 20 stars, per solve:", end="")
    for f in (quest, svd_attitude, esoq2):
        per_solve_us = 1e6 * _time_per_call(lambda f=f: f(W, V), 3, 3) / 1000
        print(f"  {f.__name__} {per_solve_us:.2f}us", end="")
    print()


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--fields", type=int, default=1000)
    p.add_argument("--stars-min", type=int, default=10)
    p.add_argument("--stars-max", type=int, default=30)
    p.add_argument("--noise-min-px", type=float, default=0.1)
    p.add_argument("--noise-max-px", type=float, default=0.3)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--skip-accuracy", action="store_true")
    args = p.parse_args(argv)
    if not args.skip_accuracy:
        accuracy(args)
    speed(args)


if __name__ == "__main__":
    main()
