"""``shipstar error-model``: ship attitude error budget, seed 001's sweeps, sensor layout."""

from __future__ import annotations

import argparse
import json

from shipstar.cli._common import angle_deg, atomic_write_text, emit_json, finite_float, rng_seed
from shipstar.errors import ShipstarError

EPILOG = """\
examples:
  # error budget at seed 001's base point (A0 = 0), seed 001's figures 1-6, its headline
  # (100'' roll error -> 112'' heading?) and its conclusions, plots into out/
  shipstar error-model --sweep seed --out out --json

  # the same figures as the seed drew them: its factors' composition, signed sums
  shipstar error-model --sweep seed --convention seed001-factors --combine signed-sum --out out-seed

  # your own errors and installation, and the best layout of one and of two sensors
  # (8 deg field, 10 stars of 3'' each, elevation 30-60 deg, ship rolling +-10 deg)
  shipstar error-model --sensor-errors-arcsec 3 3 60 --install-errors-arcsec 5 5 20 \\
      --install-angles-deg 185 40 0 --layout --fov-deg 8 --n-stars 10 \\
      --star-sigma-arcsec 3 --el-range-deg 30 60 \\
      --ship-attitude-deg 0 10 --ship-attitude-deg 0 -10 --out out
"""

SWEEP_CHOICES = ("As", "Es", "gs", "A0", "E0", "g0", "seed")


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "error-model", help="ship attitude error model, seed 001 sweeps, sensor layout",
        description="How sensor-attitude and installation-angle errors become heading, pitch and roll "
                    "errors (linear model checked by Monte Carlo), seed 001's sensitivity sweeps, and the "
                    "installation layout that minimises the ship attitude error.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    f3 = dict(nargs=3, type=finite_float)
    p.add_argument("--sensor-errors-arcsec", metavar=("AS", "ES", "GS"), default=[3.0, 3.0, 100.0], **f3,
                   help="1-sigma errors of the sensor's horizontal azimuth, elevation, roll (default 3 3 100)")
    p.add_argument("--install-errors-arcsec", metavar=("A0", "E0", "G0"), default=[1.0, 1.0, 20.0], **f3,
                   help="1-sigma errors of the installation azimuth, elevation, roll (default 1 1 20)")
    d3 = dict(nargs=3, type=angle_deg)
    p.add_argument("--sensor-angles-deg", metavar=("AS", "ES", "GS"), default=[235.0, 45.0, 90.0], **d3,
                   help="sensor horizontal attitude of the budget point (default seed 001: 235 45 90)")
    p.add_argument("--install-angles-deg", metavar=("A0", "E0", "G0"), default=[0.0, 35.0, 0.0], **d3,
                   help="installation angles of the budget point (default seed 001: 0 35 0)")
    p.add_argument("--convention", choices=("shipstar", "seed001-factors"), default="shipstar",
                   help="observation model: seed 001 eq. 1-4 as printed (default) or the seed's factors eq. 8-38")
    p.add_argument("--combine", choices=("rss", "signed-sum"), default="rss",
                   help="how the sweep plots combine the sources: root-sum-square (default, independent errors) "
                        "or the seed's eq. 5-7 signed sum")
    p.add_argument("--sweep", choices=SWEEP_CHOICES,
                   help="sweep one angle (curves for A0 = 0/90/180/270), or 'seed': all of seed 001's "
                        "figures, its headline and conclusions")
    p.add_argument("--points", type=int, default=361, help="points per sweep (default 361)")
    p.add_argument("--lock-margin-deg", type=angle_deg, default=1.0,
                   help="flag points with ship pitch this close to +-90 deg (default 1)")
    p.add_argument("--mc-samples", type=int, default=20000, help="Monte Carlo samples (default 20000)")
    p.add_argument("--rng-seed", type=rng_seed, default=1, metavar="N",
                   help="Monte Carlo random seed, 0..2**63-1 (default 1)")
    _register_layout(p)
    p.add_argument("--out", required=True, metavar="DIR", help="directory for the JSON, CSV and PNG files")
    p.add_argument("--progress", action="store_true", help="progress bar on stderr (default: only on a terminal)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(run=run)
    return p


def _register_layout(p) -> None:
    g = p.add_argument_group("layout (with --layout)")
    g.add_argument("--layout", action="store_true", help="find the best installation of one and of two sensors")
    g.add_argument("--fov-deg", type=angle_deg, default=8.0, help="sensor field of view (default 8)")
    g.add_argument("--n-stars", type=finite_float, help="stars per frame (default: from --mag-limit)")
    g.add_argument("--mag-limit", type=finite_float, default=6.5,
                   help="magnitude limit for the expected star count (default 6.5)")
    g.add_argument("--star-sigma-arcsec", type=finite_float, default=3.0,
                   help="direction noise of one star (default 3, about 0.1 px of an 8 deg 1024 px sensor)")
    g.add_argument("--az-range-deg", nargs=2, type=angle_deg, default=[0.0, 360.0], metavar=("MIN", "MAX"),
                   help="allowed installation azimuth from the bow toward starboard (default 0 360)")
    g.add_argument("--el-range-deg", nargs=2, type=angle_deg, default=[30.0, 60.0], metavar=("MIN", "MAX"),
                   help="allowed installation elevation above the deck (default 30 60)")
    g.add_argument("--ship-attitude-deg", nargs=2, type=angle_deg, action="append", metavar=("PITCH", "ROLL"),
                   help="ship attitude to average over (repeatable; default level)")
    g.add_argument("--objective", choices=("max", "rss", "heading", "pitch", "roll"), default="max",
                   help="what to minimise: the largest of the heading/pitch/roll 1-sigma (default), their RSS, "
                        "or one of them")
    g.add_argument("--step-deg", type=angle_deg, default=2.0, help="layout grid step (default 2)")


def _deg_dict(names, values):
    return {n: float(v) for n, v in zip(names, values)}


def _budget_section(args, em):
    import numpy as np

    from shipstar.units import DEG2RAD

    errors = list(args.sensor_errors_arcsec) + list(args.install_errors_arcsec)
    s = np.array(args.sensor_angles_deg) * DEG2RAD
    i = np.array(args.install_angles_deg) * DEG2RAD
    budget = em.error_budget(s, i, errors, convention=args.convention, lock_margin_deg=args.lock_margin_deg)
    out = {"budget": budget.as_dict()}
    if not budget.gimbal_locked:
        mc = em.monte_carlo_check(s, i, errors, n_samples=args.mc_samples, rng=args.rng_seed,
                                  convention=args.convention)
        out["monte_carlo"] = mc.as_dict()
    return out


def _write_sweep(res, key, caption, out_dir, em, kind):
    import csv
    import io

    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(res.rows())
    csv_path = out_dir / f"errormodel_{key}.csv"
    atomic_write_text(csv_path, buf.getvalue())
    png_path = out_dir / f"errormodel_{key}.png"
    em.plot_sweep(res, png_path, title=caption, kind=kind)
    maxima = {o: res.max_abs(o, kind).max_arcsec for o in em.OUTPUTS}
    return {"key": key, "param": res.param, "caption": caption, "csv": str(csv_path), "png": str(png_path),
            "combine": kind, "max_arcsec": maxima, "n_gimbal_locked": res.n_gimbal_locked}


def _sweep_section(args, em, out_dir):
    kind = args.combine.replace("-", "_")
    if args.sweep != "seed":
        base = dict(zip(em.PARAMS, list(args.sensor_angles_deg) + list(args.install_angles_deg)))
        errors = list(args.sensor_errors_arcsec) + list(args.install_errors_arcsec)
        res = em.sweep(args.sweep, errors, n_points=args.points, base_deg=base, convention=args.convention,
                       lock_margin_deg=args.lock_margin_deg)
        return {"sweeps": [_write_sweep(res, f"sweep_{args.sweep}", f"effect of {args.sweep}", out_dir, em, kind)]}
    sweeps = []
    for fig in em.SEED001_FIGURES:
        res = em.seed001_sweep(fig, n_points=args.points, convention=args.convention,
                               lock_margin_deg=args.lock_margin_deg)
        sweeps.append(_write_sweep(res, fig.key, fig.caption, out_dir, em, kind))
    return {"sweeps": sweeps, "seed001_headline": _headline(args, em),
            "seed001_conclusions": _conclusions(args, em)}


def _headline(args, em):
    out = {"seed_arcsec": em.SEED001_HEADLINE_ARCSEC}
    for conv in em.CONVENTIONS:
        h = em.seed001_headline(convention=conv, n_points=args.points, lock_margin_deg=args.lock_margin_deg)
        out[conv] = {
            "max_heading_arcsec": h.max_heading_arcsec, "param": h.at.param, "at_deg": h.at.at_deg,
            "curve": h.at.curve_label, "ship_pitch_deg": h.at.ship_pitch_deg,
            "base_point_max_arcsec": h.base_point_max_arcsec, "n_gimbal_locked": h.n_gimbal_locked,
            "per_sweep_max_arcsec": {m.param: m.max_arcsec for m in h.per_sweep},
        }
    return out


def _conclusions(args, em):
    out = {}
    for model in em.MODELS:
        out[model] = [{"key": c.key, "statement": c.statement, "figure": c.figure, "held": c.held,
                       "evidence": c.evidence} for c in em.check_seed001_conclusions(model, n_points=args.points)]
    return out


def _layout_section(args, em, out_dir):
    n = args.n_stars if args.n_stars is not None else em.expected_star_count(args.fov_deg, args.mag_limit)
    sensor = em.sensor_accuracy(args.fov_deg, n, args.star_sigma_arcsec)
    kw = dict(az_range_deg=args.az_range_deg, el_range_deg=args.el_range_deg,
              install_errors_arcsec=args.install_errors_arcsec, objective=args.objective,
              ship_attitudes_deg=args.ship_attitude_deg or [(0.0, 0.0)], step_deg=args.step_deg)
    one = em.optimise_layout(sensor, n_sensors=1, **kw)
    two = em.optimise_layout(sensor, n_sensors=2, **kw)
    png = out_dir / "errormodel_layout.png"
    em.plot_layout(one, png, dual=two)
    return {"layout": {"sensor": sensor.as_dict(), "single": one.as_dict(), "dual": two.as_dict(), "png": str(png)}}


def _print_text(result) -> None:
    b = result["budget"]
    ship = ", ".join(f"{v:.3f}" for v in b["ship_angles_deg"].values())
    print(f"budget point: ship (heading, pitch, roll) = ({ship}) deg")
    print(f"ship attitude error ({result['convention']}), arcsec:   heading   pitch    roll")
    print("  RSS of sources                          " + "  ".join(f"{v:7.2f}" if v is not None else "  lock"
                                                                      for v in b["rss_arcsec"].values()))
    if "monte_carlo" in result:
        mc = result["monte_carlo"]["rms_nonlinear_arcsec"]
        print("  Monte Carlo (nonlinear chain) RMS       " + "  ".join(f"{v:7.2f}" for v in mc.values()))
    h = result.get("seed001_headline")
    if h:
        for conv in ("shipstar", "seed001-factors"):
            x = h[conv]
            print(f"seed 001 headline [{conv}]: max heading error from a 100'' roll error = "
                  f"{x['max_heading_arcsec']:.1f}'' ({x['param']} = {x['at_deg']:g} deg, {x['curve']}, "
                  f"ship pitch {x['ship_pitch_deg']:.1f} deg)  [seed: {h['seed_arcsec']:g}'']")
        for c in result["seed001_conclusions"]["shipstar"]:
            print(f"  {c['key']:8s} {'held    ' if c['held'] else 'NOT held'}  {c['statement']}")
    if "layout" in result:
        for k in ("single", "dual"):
            lay = result["layout"][k]
            places = ", ".join(f"({a:.1f}, {e:.1f})" for a, e in zip(lay["az_deg"], lay["el_deg"]))
            sig = ", ".join(f"{v:.2f}" for v in lay["sigma_arcsec"].values())
            print(f"best {k} layout (az, el) deg: {places}; heading/pitch/roll 1-sigma {sig}''")
    print(f"files in {result['out_dir']}")


#: Largest --points: a sweep's memory grows by ~20 kB a point (``--sweep seed``: 0.46 GB
#: and 33 s at 20000 points, 3.6 GB at 200000), so 10000 points stay within ~0.25 GB.
MAX_POINTS = 10000
#: Largest --mc-samples: ~0.35 kB a sample (0.8 GB at 2 million), so 1 million stay within ~0.4 GB.
MAX_MC_SAMPLES = 1_000_000


def _check_limits(args) -> None:
    """Refuse, before the output directory is made, elevations past the zenith and sizes
    whose memory would not fit a shared machine (killed with no message)."""
    for flag, names, angles in (("--sensor-angles-deg", ("AS", "ES", "GS"), args.sensor_angles_deg),
                                ("--install-angles-deg", ("A0", "E0", "G0"), args.install_angles_deg)):
        if not -90.0 <= angles[1] <= 90.0:
            raise ShipstarError(f"{flag}: the elevation {names[1]} must be within [-90, 90] deg, got {angles[1]:g}")
    if not 0.0 < args.fov_deg < 180.0:
        raise ShipstarError(f"--fov-deg must be within (0, 180) deg, got {args.fov_deg:g}")
    if args.points < 2 or args.mc_samples < 1:
        flag, value = ("--points", args.points) if args.points < 2 else ("--mc-samples", args.mc_samples)
        raise ShipstarError(f"{flag} must be at least {2 if flag == '--points' else 1}, got {value}")
    if args.points > MAX_POINTS:
        raise ShipstarError(f"--points {args.points} is above the limit of {MAX_POINTS} (a sweep takes ~20 kB a "
                            f"point: {args.points} would need ~{args.points * 20e3 / 1e9:.1f} GB); the curves are "
                            f"smooth, 361 (one a degree) resolve them")
    if args.mc_samples > MAX_MC_SAMPLES:
        raise ShipstarError(f"--mc-samples {args.mc_samples} is above the limit of {MAX_MC_SAMPLES} (~0.35 kB a "
                            f"sample: ~{args.mc_samples * 350 / 1e9:.1f} GB); the check's sampling error is "
                            f"1/sqrt(2 N), 0.07 % at the limit")


def run(args) -> int:
    import shipstar.errormodel as em
    from shipstar.pipeline._progress import ProgressBar

    from shipstar.cli._common import check_output_dir

    _check_limits(args)
    out_dir = check_output_dir(args.out, "--out")     # a file in its place: said so, not "already exists"
    bar = ProgressBar(True if args.progress else None)
    steps = 1 + bool(args.sweep) + bool(args.layout)
    out_dir.mkdir(parents=True, exist_ok=True)
    result = {
        "convention": args.convention,
        "sensor_angles_deg": _deg_dict(("As", "Es", "gs"), args.sensor_angles_deg),
        "install_angles_deg": _deg_dict(("A0", "E0", "g0"), args.install_angles_deg),
        "sensor_errors_arcsec": _deg_dict(("As", "Es", "gs"), args.sensor_errors_arcsec),
        "install_errors_arcsec": _deg_dict(("A0", "E0", "g0"), args.install_errors_arcsec),
        "out_dir": str(out_dir),
    }
    bar("error model", 0, steps)
    try:
        result.update(_budget_section(args, em))
        bar("error model", 1, steps)
        if args.sweep:
            result.update(_sweep_section(args, em, out_dir))
            bar("error model", 2, steps)
        if args.layout:
            result.update(_layout_section(args, em, out_dir))
            bar("error model", steps, steps)
    finally:
        bar.close()
    try:
        text = json.dumps(result, allow_nan=False, indent=1)
    except ValueError as exc:
        raise ShipstarError(f"result is not finite, refusing to write it as JSON: {exc}") from None
    atomic_write_text(out_dir / "error_model.json", text + "\n")
    if args.json:
        emit_json(result)
    else:
        _print_text(result)
    return 0
