"""Per-frame apparent places: shipstar's fast path against astropy, in one run.

One "frame" = a new frame time (10 frames/s) at a fixed ship position and the apparent
topocentric places (no refraction) of the same 100 bright Hipparcos stars.

- shipstar: ``frame_context(utc_jd1, utc_jd2, site)`` (Earth orientation lookup plus one
  ``erfa.apco13``) then ``ctx.hor_from_catalog(stars)`` (proper motion, parallax, light
  deflection, aberration, rotation to the horizontal frame).
- astropy, same work: ``SkyCoord`` at J2000 with proper motion, parallax and radial
  velocity, ``apply_space_motion(new_obstime=t)``, ``transform_to(AltAz(...))``.
- astropy, least work (for reference, not the same computation): a pre-built
  ``SkyCoord`` of fixed directions -> ``transform_to(AltAz(...))``, without proper
  motion or parallax.

Astropy's ``Time`` objects are built outside the timed loop.  Both use the IERS-A table
shipped with astropy-iers-data (no download).  Targets: >= 100x faster than astropy and
< 1 ms per frame.  Run: ``python benchmarks/bench_apparent.py [--frames N]``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def _setup_astropy():
    from astropy.utils import iers

    iers.conf.auto_download = False
    iers.conf.auto_max_age = None
    iers.earth_orientation_table.set(iers.IERS_A.open(iers.IERS_A_FILE))


def _time_per_frame(fn, n_frames: int, repeats: int) -> float:
    """Median over repeats of the mean seconds per frame of ``fn(k)`` for k < n_frames."""
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for k in range(n_frames):
            fn(k)
        runs.append((time.perf_counter() - t0) / n_frames)
    return statistics.median(runs)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200, help="shipstar frames per repeat")
    parser.add_argument("--astropy-frames", type=int, default=20, help="astropy frames per repeat")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)

    _setup_astropy()
    from astropy import units as u
    from astropy.coordinates import AltAz, Distance, EarthLocation, SkyCoord
    from astropy.time import Time

    from shipstar.frames import unit_from_az_el
    from shipstar.sky.apparent import Site, frame_context
    from shipstar.sky.catalog import navigation_catalog
    from shipstar.sky.time import utc_jd_from_iso
    from shipstar.units import RAD2MAS

    nav = navigation_catalog(4.0)
    stars = nav.subset(np.argsort(nav.mag, kind="stable")[:100])
    lat_deg, lon_deg, height_m = 31.9, 120.3, 5.0
    site = Site.from_deg(lat_deg, lon_deg, height_m)
    jd1, jd2 = utc_jd_from_iso("2013-03-15T12:16:00")
    dt_day = 0.1 / 86400.0                       # 10 frames/s
    n_astropy = args.astropy_frames
    times = [Time(jd1, jd2 + k * dt_day, format="jd", scale="utc") for k in range(n_astropy)]
    location = EarthLocation.from_geodetic(lon_deg * u.deg, lat_deg * u.deg, height_m * u.m)
    moving = SkyCoord(
        ra=stars.ra_rad * u.rad, dec=stars.dec_rad * u.rad,
        pm_ra_cosdec=stars.pm_ra_cosdec_mas_per_yr * u.mas / u.yr,
        pm_dec=stars.pm_dec_mas_per_yr * u.mas / u.yr,
        distance=Distance(parallax=stars.parallax_mas * u.mas),
        radial_velocity=stars.rv_km_s * u.km / u.s,
        obstime=Time(2451545.0, format="jd", scale="tt"), frame="icrs")
    fixed = SkyCoord(ra=stars.ra_rad * u.rad, dec=stars.dec_rad * u.rad, frame="icrs")

    def ours(k):
        return frame_context(jd1, jd2 + k * dt_day, site).hor_from_catalog(stars)

    def astropy_same(k):
        t = times[k]
        return moving.apply_space_motion(new_obstime=t).transform_to(
            AltAz(obstime=t, location=location, pressure=0 * u.hPa))

    def astropy_least(k):
        return fixed.transform_to(AltAz(obstime=times[k], location=location, pressure=0 * u.hPa))

    # Warm-up (imports, table parsing, caches), and the agreement of the two.
    aa = astropy_same(0)
    diff = np.linalg.norm(ours(0) - unit_from_az_el(aa.az.rad, aa.alt.rad), axis=1) * RAD2MAS
    astropy_least(0)

    t_ours = _time_per_frame(ours, args.frames, args.repeats)
    t_same = _time_per_frame(astropy_same, n_astropy, args.repeats)
    t_least = _time_per_frame(astropy_least, n_astropy, args.repeats)

    print(f"apparent places of {len(stars)} stars per frame, new frame time each frame")
    print(f"  shipstar frame_context + hor_from_catalog : {t_ours * 1e6:9.1f} us/frame")
    print(f"  astropy apply_space_motion + AltAz        : {t_same * 1e3:9.2f} ms/frame "
          f"-> shipstar {t_same / t_ours:6.0f}x faster")
    print(f"  astropy AltAz only, fixed directions      : {t_least * 1e3:9.2f} ms/frame "
          f"-> shipstar {t_least / t_ours:6.0f}x faster (less work: no proper motion/parallax)")
    print(f"  agreement with astropy: max {diff.max():.4f} mas over {len(stars)} stars")
    ok_ratio = t_same / t_ours >= 100.0
    ok_time = t_ours < 1e-3
    print(f"  target >= 100x faster than astropy doing the same work: {'met' if ok_ratio else 'NOT met'}")
    print(f"  target < 1 ms per frame: {'met' if ok_time else 'NOT met'}")
    return 0 if ok_ratio and ok_time else 1


if __name__ == "__main__":
    raise SystemExit(main())
