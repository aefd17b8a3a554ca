"""Deep matching: accuracy gain, matched stars, chance matches and time, against truth.

Simulated A1 frames at image level (``shipstar.simulate.simulate_frame``, stars to
``--mag-limit``, default Hp 9, rendered with noise) -> ``extract_stars`` ->
``identify_lost_in_space`` (navigation database, Hp <= 7.32) -> ``deep_match`` against
``deep_catalog(database)`` (Hp <= 9, the database's close-pair rule), in two geometries:

* **space**: ``--frames`` random attitudes over the sky and in roll, epoch 2025.0 (the
  database's), truth ``C_icrs_from_sensor``;
* **dock**: ``--dock-frames`` frames of seed 000's dock (Jiangyin, 2013-03-15 12:16 UTC,
  heading 46.4746 deg, level, A1 installed at 185.1093 / 39.3734 / -0.2262 deg, 11.1 C,
  1021.7 hPa, ERFA refraction), 0.1 s apart, truth ``C_hor_from_sensor``.

Centroid errors: the extraction's ``xy_sigma_px`` (NaN -> 1 px) with ``--floor-px``
(default 0.03 px, the pipeline's ``centroid_floor_px``) in quadrature, as the weights;
``--noise-px`` adds that much Gaussian error per star and axis to the centroids (an
error floor the renderer does not have: its centroids reach the Cramer-Rao bound).
The truth of a detection is the simulated star nearest it, if within max(1 px, 4 sigma).

Printed per geometry: detected / identified / matched stars (median), added pairs whose
HIP is not the truth's (chance or wrong matches; 0 expected), the expected chance pairs
per frame (mean, max), ambiguous and rejected detections, and the RMS attitude error
about the sensor axes (X = roll about the boresight, Y and Z cross-boresight), arcsec:

* ``identification`` (space only): the identification's attitude (equal-weight QUEST);
* ``weighted, identified only``: the same stars weighted by their centroid errors (what
  the pipeline's attitude step makes of an identification);
* ``deep``: ``deep_match``'s attitude (space), or the pipeline's horizontal attitude
  step (``sensor_attitude_hor``, per-star refraction, weights ``sigma^-2``) over the
  deep-matched stars (dock);

and the RMS ratios.  Time: ``deep_match`` per frame (median, 90th percentile) against
the anchor ``astropy.coordinates.match_coordinates_sky`` run in the same loop on the
same frame (the detections, turned to ICRS with the identification's attitude, matched
to the same catalog stars: a bare nearest-neighbour match without the local model,
gates, ambiguity rules or attitude), and the ratio.

Usage::

    python benchmarks/bench_deep_match.py                       # 200 + 200 frames
    python benchmarks/bench_deep_match.py --floor-px 0          # Cramer-Rao weights
    python benchmarks/bench_deep_match.py --noise-px 0.03       # a 0.03 px error floor
    python benchmarks/bench_deep_match.py --frames 30 --dock-frames 30
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from shipstar.camera import camera_preset
from shipstar.extract import extract_stars
from shipstar.identify import build_database, deep_catalog, deep_match, identify_lost_in_space
from shipstar.identify._sim import random_attitudes
from shipstar.units import DEG2RAD, RAD2ASEC

DOCK_UTC_START_S = 12 * 3600 + 16 * 60
DOCK_HEADING_DEG = 46.0 + 28.0 / 60.0 + 28.51 / 3600.0
A1_INSTALL_DEG = (185.1093, 39.3734, -0.2262)


def axis_errors_arcsec(C_est, C_true) -> np.ndarray:
    """Small rotation ``C_true^T C_est`` as a rotation vector about the sensor axes (3,)."""
    d = C_true.T @ C_est
    return 0.5 * np.array([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]]) * RAD2ASEC


def truth_hip(sim, xy_px, sigma_px) -> np.ndarray:
    """HIP of the simulated star nearest each detection if within ``max(1 px, 4 sigma)``,
    else -1 (a detection whose fit failed has sigma 1 px and may be 1-2 px off)."""
    from scipy.spatial import cKDTree

    if len(sim.stars) == 0:
        return np.full(len(xy_px), -1)
    d, j = cKDTree(sim.stars.xy_px).query(xy_px)
    return np.where(d <= np.maximum(1.0, 4.0 * sigma_px), sim.stars.hip[j], -1)


def anchor_time_s(xy_px, cam, idn, catalog, dm) -> float:
    """Wall time of astropy's nearest-neighbour sky match of the same detections to the
    same catalog stars (built inside the timed call, as a user of it would)."""
    from astropy import units as u
    from astropy.coordinates import SkyCoord, match_coordinates_sky

    v_det = cam.unproject(xy_px) @ idn.C_icrs_from_sensor.T
    v_cat = catalog.unit_icrs(2025.0)[dm.catalog_index[dm.catalog_index >= 0]]
    t0 = time.perf_counter()
    det = SkyCoord(x=v_det[:, 0], y=v_det[:, 1], z=v_det[:, 2], representation_type="cartesian")
    ref = SkyCoord(x=v_cat[:, 0], y=v_cat[:, 1], z=v_cat[:, 2], representation_type="cartesian")
    idx, sep, _ = match_coordinates_sky(det, ref)
    _ = idx[sep < 10 * u.arcsec]
    return time.perf_counter() - t0


class Tally:
    """Per-geometry accumulators."""

    def __init__(self):
        self.rows = {k: [] for k in ("idn", "before", "after")}
        self.n = {k: [] for k in ("detected", "identified", "matched", "added", "ambiguous", "rejected")}
        self.wrong, self.chance, self.t_deep, self.t_anchor, self.failed = 0, [], [], [], 0
        self.gate = []

    def add(self, dm, n_det, errors, wrong, t_anchor):
        for k, e in zip(("idn", "before", "after"), errors):
            self.rows[k].append(e)
        for k, v in (("detected", n_det), ("identified", dm.n_identified), ("matched", dm.n_matched),
                     ("added", dm.n_added), ("ambiguous", dm.n_ambiguous), ("rejected", dm.n_rejected)):
            self.n[k].append(v)
        self.wrong += wrong
        self.chance.append(dm.expected_chance)
        self.gate.append(dm.gate_max_arcsec)
        self.t_deep.append(dm.time_s)
        self.t_anchor.append(t_anchor)

    def report(self, title: str, before_label: str, after_label: str, with_identification: bool = True):
        rms = {k: np.sqrt(np.mean(np.square(v), axis=0)) for k, v in self.rows.items()}
        print(f"\n== {title}: {len(self.t_deep)} frames ({self.failed} not identified) ==")
        print("stars (median): " + ", ".join(f"{k} {np.median(v):.0f}" for k, v in self.n.items())
              + f"; totals: added {sum(self.n['added'])}, ambiguous {sum(self.n['ambiguous'])}, "
              f"rejected {sum(self.n['rejected'])}")
        print(f"added pairs not the truth's star: {self.wrong}; expected chance pairs per frame: "
              f"mean {np.mean(self.chance):.4f}, max {np.max(self.chance):.4f}; gate cap (arcsec): "
              f"median {np.median(self.gate):.2f}, min {np.min(self.gate):.2f}, "
              f"frames capped {np.isfinite(self.gate).mean():.0%}")
        print("RMS error about sensor X (roll) / Y / Z, arcsec:")
        rows = ((("idn", "identification"),) if with_identification else ()) + (("before", before_label),)
        for k, label in rows + (("after", after_label),):
            print(f"  {label:38s} " + " / ".join(f"{x:7.3f}" for x in rms[k]))
        for k, label in rows:
            print(f"  ratio {label:32s} " + " / ".join(f"{x:7.3f}" for x in rms[k] / rms["after"]))
        td, ta = np.array(self.t_deep) * 1e3, np.array(self.t_anchor) * 1e3
        print(f"time per frame: deep_match median {np.median(td):.3f} ms (p90 {np.percentile(td, 90):.3f}); "
              f"astropy match_coordinates_sky median {np.median(ta):.3f} ms; ratio {np.median(td) / np.median(ta):.2f}")


def measure(image, cam, opts, rng):
    """Centroids (brightest first) with ``opts.noise_px`` extra Gaussian error per star and
    axis, and their sigmas: the extraction's with ``opts.floor_px`` in quadrature."""
    ex = extract_stars(image, psf_sigma_px=cam.psf_sigma_px, gain_e_per_adu=cam.gain_e_per_adu)
    order = np.argsort(-ex.flux_adu, kind="stable")
    sig = ex.xy_sigma_px[order]
    xy = ex.xy_px[order] + rng.normal(0.0, opts.noise_px, (len(order), 2)) if opts.noise_px > 0 else ex.xy_px[order]
    return xy, np.hypot(np.where(np.isfinite(sig), sig, 1.0), opts.floor_px)


def weighted_icrs(w, hip, sig_rad, catalog, epoch):
    from shipstar.attitude import solve_attitude

    v = catalog.unit_icrs(epoch)[catalog.index_of_hip(hip)]
    return solve_attitude(w, v, sigma_rad=sig_rad).C_ref_from_body


def run_space(n_frames, cam, db, catalog, opts, rng) -> Tally:
    from shipstar.simulate import simulate_frame

    tally, scale = Tally(), cam.pixel_mm / cam.f_mm
    for k, C_true in enumerate(random_attitudes(n_frames, rng)):
        sim = simulate_frame(cam, C_icrs_from_sensor=C_true, utc_iso="2025-01-01T00:00:00",
                             mag_limit=opts.mag_limit, seed=1000 + k)
        xy, sig = measure(sim.image, cam, opts, rng)
        idn = identify_lost_in_space(xy, db, camera=cam)
        if not idn.solved:
            tally.failed += 1
            continue
        dm = deep_match(xy, sig, idn, catalog, epoch_jyear=sim.epoch_jyear, camera=cam)
        ident = idn.hip >= 0
        C_before = weighted_icrs(dm.u_sensor[ident], idn.hip[ident], sig[ident] * scale, catalog, sim.epoch_jyear)
        errors = [axis_errors_arcsec(C, C_true) for C in (idn.C_icrs_from_sensor, C_before, dm.C_icrs_from_sensor)]
        wrong = int(np.count_nonzero(dm.added & (dm.hip != truth_hip(sim, xy, sig))))
        tally.add(dm, len(xy), errors, wrong, anchor_time_s(xy, cam, idn, catalog, dm))
    return tally


def run_dock(n_frames, cam, db, catalog, opts, rng) -> Tally:
    from shipstar.attitude import sensor_attitude_hor_from_catalog
    from shipstar.simulate import ShipPose, simulate_frame
    from shipstar.sky.apparent import Site
    from shipstar.sky.refraction import Weather
    from shipstar.sky.time import iso_from_utc_jd, utc_jd_from_iso

    pose = ShipPose.from_deg(DOCK_HEADING_DEG, 0.0, 0.0, *A1_INSTALL_DEG)
    site = Site(31.9 * DEG2RAD, 120.3 * DEG2RAD)
    weather = Weather(pressure_hpa=1021.70, temperature_c=11.10)
    jd1, jd2 = utc_jd_from_iso("2013-03-15T12:16:00")
    tally = Tally()
    for k in range(n_frames):
        utc = iso_from_utc_jd(jd1, jd2 + 0.1 * k / 86400.0, 6)
        sim = simulate_frame(cam, ship=pose, utc_iso=utc, site=site, weather=weather, mag_limit=opts.mag_limit,
                             seed=k)
        xy, sig = measure(sim.image, cam, opts, rng)
        idn = identify_lost_in_space(xy, db, camera=cam)
        if not idn.solved:
            tally.failed += 1
            continue
        dm = deep_match(xy, sig, idn, catalog, epoch_jyear=sim.epoch_jyear, camera=cam)

        def hor(rows):
            h = sensor_attitude_hor_from_catalog(dm.u_sensor[rows], dm.hip[rows], catalog, sim.context, weather,
                                                 model=sim.refraction_model, weights=sig[rows] ** -2.0)
            return h.C_hor_from_sensor

        # the identification's ICRS attitude has no horizontal counterpart without refraction
        errors = [np.full(3, np.nan)] + [axis_errors_arcsec(C, sim.C_hor_from_sensor)
                                         for C in (hor(idn.hip >= 0), hor(dm.hip >= 0))]
        wrong = int(np.count_nonzero(dm.added & (dm.hip != truth_hip(sim, xy, sig))))
        tally.add(dm, len(xy), errors, wrong, anchor_time_s(xy, cam, idn, catalog, dm))
    return tally


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=200, help="random-attitude frames (space)")
    ap.add_argument("--dock-frames", type=int, default=200, help="frames at seed 000's dock")
    ap.add_argument("--mag-limit", type=float, default=9.0, help="faintest Hp simulated")
    ap.add_argument("--floor-px", type=float, default=0.03,
                    help="floor added in quadrature to the extraction's sigma (the weights)")
    ap.add_argument("--noise-px", type=float, default=0.0,
                    help="extra Gaussian centroid error per star and axis (an error floor the renderer lacks)")
    ap.add_argument("--seed", type=int, default=2025)
    args = ap.parse_args(argv)
    cam = camera_preset("A1")
    db = build_database(cam)
    catalog = deep_catalog(db)
    print(f"A1, database Hp <= {db.params.mag_limit}, deep catalog {len(catalog)} stars "
          f"(Hp <= 9, close pairs within {db.params.min_separation_arcsec}'' excluded), "
          f"simulated stars to Hp {args.mag_limit}, sigma floor {args.floor_px} px, extra noise {args.noise_px} px")
    t0 = time.perf_counter()
    if args.frames > 0:
        run_space(args.frames, cam, db, catalog, args, np.random.default_rng(args.seed)).report(
            "space, random attitudes", "weighted, identified only (ICRS)", "deep_match")
    if args.dock_frames > 0:
        run_dock(args.dock_frames, cam, db, catalog, args, np.random.default_rng(args.seed + 1)).report(
            "seed 000 dock (horizontal frame)", "weighted hor, identified only", "weighted hor, deep-matched",
            with_identification=False)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
