"""The INS calibrated against the stars, and a cloud bridged with it (issue 15 acceptance).

A simulated sea session at centroid level (roll 5 deg / 8 s, both sensors, joint
solution), an INS with 30'' heading bias, 36''/h heading drift, 5'' pitch and roll bias,
a 20 ms clock offset (plus random walks 3.6 / 1''/sqrt(h), 0.5'' white noise, 50 Hz) and
a cloud: no star epoch over 3 minutes.  Prints each estimated term against the truth
with its sigma, and the corrected attitude's RMS error against the truth inside and
outside the outage with RMS(error / sigma).

    python benchmarks/bench_ins.py [--duration-s 600] [--frame-rate-hz 10] [--outage-s 240 420]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv=None) -> int:
    from bench_ship_attitude import frames_of, tables

    from shipstar.calibrate.installation import Installation
    from shipstar.pipeline import PipelineOptions, SensorConfig, process_session
    from shipstar.pipeline._ins import InsModel, StarRows, estimate_ins
    from shipstar.simulate._ins import InsErrors, simulate_ins
    from shipstar.simulate._session import sea_session, simulate_centroids
    from shipstar.units import RAD2ASEC

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration-s", type=float, default=600.0)
    ap.add_argument("--frame-rate-hz", type=float, default=10.0)
    ap.add_argument("--outage-s", type=float, nargs=2, default=(240.0, 420.0))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--misalignment-arcsec", default="0/0/0", help="bow/up/starboard")
    ap.add_argument("--heading-random-walk-arcsec-per-sqrt-h", type=float, default=3.6,
                    help="the INS's heading random walk (simulated and told to the filter; default 3.6)")
    args = ap.parse_args(argv)
    hrw = args.heading_random_walk_arcsec_per_sqrt_h

    spec = sea_session(duration_s=args.duration_s, frame_rate_hz=args.frame_rate_hz, seed=args.seed)
    errors = InsErrors(heading_bias_arcsec=30.0, heading_drift_arcsec_per_h=36.0, pitch_bias_arcsec=5.0,
                       roll_bias_arcsec=5.0, time_offset_s=0.02, seed=args.seed + 1,
                       heading_random_walk_arcsec_per_sqrt_h=hrw,
                       misalignment_arcsec=tuple(float(x) for x in args.misalignment_arcsec.split("/")))
    t0 = time.perf_counter()
    cf = simulate_centroids(spec)
    track, weather, _ = tables(spec)
    configs = [SensorConfig(s.name, s.camera, Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor))
               for s in spec.sensors]
    res = process_session(configs, [frames_of(cf, s.name) for s in spec.sensors], track, weather, PipelineOptions())
    rows = StarRows()
    for e in res.epochs:
        rows.write(type("Emission", (), {"epoch": e})())
    t, a, c = rows.arrays()
    t1 = time.perf_counter()
    truth = simulate_ins(spec, errors)

    class Log:
        t_s, angles_rad, start_utc_jd = truth.tau_s, truth.reading_rad, spec.utc_jd(0.0)

    lo, hi = args.outage_s
    keep = (t < lo) | (t > hi)
    sol = estimate_ins(Log, t[keep], a[keep], c[keep], InsModel(heading_random_walk_arcsec_per_sqrt_h=hrw))
    t2 = time.perf_counter()
    print(f"session {args.duration_s:g} s at {args.frame_rate_hz:g} Hz: {len(t)} joint epochs ({int((~keep).sum())} "
          f"dropped for the outage {lo:g}-{hi:g} s); INS {len(truth.tau_s)} records at {errors.rate_hz:g} Hz, heading random walk {hrw:g}''/sqrt(h); "
          f"pipeline {t1 - t0:.0f} s, filter + smoother {t2 - t1:.2f} s ({sol.details['iterations']} passes)")
    s = sol.summary
    m_bow = errors.misalignment_arcsec[0]
    print(f"{'term':28s} {'estimated':>12s} {'sigma':>10s} {'true':>10s} {'(est-true)/sigma':>17s}")
    ok = True
    for key, skey, true, unit in (
            ("heading_bias_arcsec", "heading_bias_sigma_arcsec", errors.heading_bias_arcsec, "''"),
            ("heading_drift_arcsec_per_h", "heading_drift_sigma_arcsec_per_h", errors.heading_drift_arcsec_per_h, "''/h"),
            ("pitch_bias_arcsec", "pitch_bias_sigma_arcsec", errors.pitch_bias_arcsec, "''"),
            ("roll_bias_arcsec", "roll_bias_sigma_arcsec", errors.roll_bias_arcsec + m_bow, "''"),
            ("time_offset_s", "time_offset_sigma_s", errors.time_offset_s, "s")):
        z = (s[key] - true) / s[skey]
        ok &= abs(z) < 3
        print(f"{key:28s} {s[key]:12.6g} {s[skey]:10.3g} {true:10.6g} {z:17.2f}")
    d = sol.details
    print("misalignment up / starboard: " + " / ".join(
        f"{d['misalignment_arcsec'][k]:.2f} +- {d['misalignment_sigma_arcsec'][k]:.2f} (true {errors.misalignment_arcsec[i]:g})"
        for i, k in ((1, "up"), (2, "starboard"))) + "''; about the bow folded into the roll bias")
    drift_ok = abs(s["heading_drift_arcsec_per_h"] - 36.0) < 3.6
    dt_ok = abs(s["time_offset_s"] - 0.02) < 1e-3
    print(f"targets: every term within 3 sigma {'yes' if ok else 'NO'}; drift within 10 % {'yes' if drift_ok else 'NO'}; "
          f"clock offset within 1 ms {'yes' if dt_ok else 'NO'}")

    true = np.stack(spec.motion.angles_rad(sol.t_s), -1)
    err = sol.angles_rad - true
    err[:, 0] = (err[:, 0] + math.pi) % (2 * math.pi) - math.pi
    err *= RAD2ASEC
    z = err / sol.sigma_arcsec
    inside = sol.bridged & (sol.t_s > lo) & (sol.t_s < hi)
    outside = ~sol.bridged & (sol.t_s > 1.0) & (sol.t_s < args.duration_s - 1.0)
    for name, sel in (("outside the outage (stars+ins)", outside), ("inside the outage (ins-bridged)", inside)):
        rms = np.sqrt(np.mean(err[sel] ** 2, 0))
        rz = np.sqrt(np.mean(z[sel] ** 2, 0))
        print(f"{name:32s} {int(sel.sum()):6d} records: RMS error h/p/r {rms[0]:.2f} / {rms[1]:.2f} / {rms[2]:.2f}'', "
              f"RMS(err/sigma) {rz[0]:.2f} / {rz[1]:.2f} / {rz[2]:.2f}, largest |err/sigma| {np.abs(z[sel]).max():.2f}, "
              f"median sigma {np.median(sol.sigma_arcsec[sel], 0).round(2).tolist()}''")
    mid = np.argmin(np.abs(sol.t_s - 0.5 * (lo + hi)))
    print(f"INS heading error estimate sigma: {sol.error_sigma_arcsec[np.argmin(np.abs(sol.t_s - lo + 1)), 0]:.2f}'' at "
          f"the outage's start, {sol.error_sigma_arcsec[mid, 0]:.2f}'' in its middle, "
          f"{sol.error_sigma_arcsec[np.argmin(np.abs(sol.t_s - hi - 1)), 0]:.2f}'' at its end")
    # the INS's slow error (bias, drift, random walk) against its estimate: the white noise left out
    ze = (sol.error_arcsec - truth.slow_error_rad * RAD2ASEC) / sol.error_sigma_arcsec
    zi = ze[inside]
    print(f"estimated INS error vs its true slow part inside the outage: RMS(err/sigma) "
          f"{' / '.join(f'{v:.2f}' for v in np.sqrt(np.mean(zi ** 2, 0)))}, largest |err/sigma| {np.abs(zi).max():.2f}; "
          f"corrected attitude samples beyond 3 sigma (white noise included): {int((np.abs(z[inside]) > 3).sum())} of "
          f"{z[inside].size}")
    rz_out = np.sqrt(np.mean(z[outside] ** 2, 0))
    print(f"targets: outside RMS(err/sigma) in 0.8-1.25 {'yes' if np.all((rz_out > 0.8) & (rz_out < 1.25)) else 'NO'}; "
          f"inside every |err| < 3 sigma: corrected attitude {'yes' if np.all(np.abs(z[inside]) < 3) else 'NO'}, "
          f"INS error estimate (no white noise) {'yes' if np.all(np.abs(zi) < 3) else 'NO'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
