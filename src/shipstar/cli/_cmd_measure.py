"""``shipstar measure``: ship heading, pitch and roll over a session from calibrated sensors."""

from __future__ import annotations

import argparse
import sys

from shipstar.cli._common import (
    accuracy_warnings,
    add_date_obs_is_argument,
    add_refraction_arguments,
    add_site_arguments,
    add_weather_arguments,
    check_output_dir,
    check_output_file,
    emit_json,
    float_in_range,
)
from shipstar.errors import ShipstarError

__all__ = ["register", "run"]

EPILOG = """\
examples:
  shipstar measure --sensor A1=sea/A1 --sensor A2=sea/A2 \\
      --install A1.install.toml A2.install.toml --track sea/track.csv --weather sea/weather.csv \\
      --out attitude.csv --plots plots/ --json
  shipstar measure --sensor A1=dock/A1 --install A1.install.toml --lat-deg 31.9 --lon-deg 120.3 \\
      --xi-arcsec 4.2 --eta-arcsec -7.5 --pressure-hpa 1021.7 --temperature-c 11.1 --out a1.csv

Each --sensor NAME=DIR gives one sensor's FITS frames, in time order by file name; the
frame time is mid-exposure UTC: DATE-AVG, else DATE-OBS (the start, FITS standard) plus
EXPTIME/2 (--date-obs-is mid: DATE-OBS is already mid-exposure).  Each sensor needs an
installation file (shipstar calibrate install) naming it.  The camera is the one named
in the installation file (a preset), unless --camera NAME=FILE gives it.

A star's streak centres on its time-averaged direction, not the mid-exposure one: with
the deck accelerating that biases each attitude by |alpha| T^2/24 (3.6'' at 80 ms at
sea).  Each frame is corrected with the deck rate and acceleration fitted to the frames
and its EXPTIME (--no-streak-correction: not, for comparison).

The ship's position: --lat-deg/--lon-deg (fixed, with the deflection of the vertical
--xi-arcsec/--eta-arcsec) or --track CSV (time_utc, lat_deg, lon_deg[, height_m][,
xi_arcsec, eta_arcsec]); a levelled ship follows the plumb line, and a deflection of the
vertical left out comes back as pitch and roll bias of its size.  The weather:
--pressure-hpa and --temperature-c (fixed) or --weather CSV (time_utc, pressure_hpa,
temperature_c[, relative_humidity]); docs/file-formats.md.

Output CSV: one row per sensor frame (method single) and, with two or more sensors, per
epoch of the reference sensor for the seed's fusion rule and the joint solution, after
'#' comment lines with the Earth orientation quality and the accuracy warnings.
Failed frames are rows with solved=0 and their reason.  --truth CSV (time_utc,
heading_deg, pitch_deg, roll_deg; simulated sessions) adds error RMS to the summary.
The summary gives the Earth orientation quality (measured / predicted / extrapolated,
UT1-UTC error), how the frame times were read (date_obs_is, time_sources) and the
accuracy warnings, which are also printed one per line on stderr (e.g. a refraction
model other than the one the installation was calibrated with).
Exit codes: 0 every frame solved; 1 written, but some frames failed; 2 bad input
(including a sensor none of whose frames solved).
"""


def _name_value(text: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    return name.strip(), value.strip()


_non_negative = float_in_range(0.0)


SITE_HELPS = {
    "lat_deg": "geodetic latitude (deg)",
    "lon_deg": "longitude, east positive (deg, -180..360)",
    "height_m": "height above WGS84 (m)",
    "xi_arcsec": "deflection of the vertical, north-south (arcsec, default 0; with --lat-deg)",
    "eta_arcsec": "deflection of the vertical, east-west (arcsec, default 0; with --lat-deg)",
}
WEATHER_HELPS = {
    "pressure_hpa": "air pressure at the sensors (hPa)",
    "temperature_c": "air temperature (C)",
    "relative_humidity": "0..1 (default 0)",
}


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "measure", help="ship heading, pitch and roll from star sensor frames",
        description="Ship attitude over a session from one or more calibrated star sensors: per-frame "
                    "single-sensor attitudes, the seed's fusion rule and the joint solution (seed 003).",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sensor", required=True, action="append", type=_name_value, metavar="NAME=DIR",
                   help="a sensor and its frames directory (repeat for each sensor)")
    p.add_argument("--install", required=True, action="extend", nargs="+", metavar="FILE",
                   help="installation TOML files, one per sensor")
    p.add_argument("--camera", action="append", type=_name_value, default=[], metavar="NAME=FILE",
                   help="camera preset or TOML file of a sensor (default: the installation's camera preset)")
    g = p.add_argument_group("ship position (fixed, or a track)")
    add_site_arguments(g, SITE_HELPS, deflection_default=None)
    g.add_argument("--track", metavar="CSV", help="time_utc, lat_deg, lon_deg[, height_m][, xi_arcsec, eta_arcsec]")
    w = p.add_argument_group("weather (fixed, or a table)")
    add_weather_arguments(w, WEATHER_HELPS)
    w.add_argument("--weather", metavar="CSV", help="time_utc, pressure_hpa, temperature_c[, relative_humidity]")
    o = p.add_argument_group("processing")
    add_refraction_arguments(o, "refraction model (default erfa; almanac = the seeds')",
                             "per-star (default) or the seed's boresight-only refraction")
    add_date_obs_is_argument(o)
    o.add_argument("--reference", metavar="NAME", help="sensor whose frame times are the epochs (default first)")
    o.add_argument("--max-pair-offset-s", type=_non_negative, default=0.06,
                   help="largest time offset of paired frames (s, default 0.06)")
    o.add_argument("--no-motion-compensation", action="store_true",
                   help="do not carry paired frames to the epoch time (for comparison)")
    o.add_argument("--no-streak-correction", action="store_true",
                   help="do not turn streak centroids (exposure averages) to mid-exposure directions (for comparison)")
    r = p.add_argument_group("output")
    r.add_argument("--out", required=True, metavar="CSV", help="attitude CSV to write")
    r.add_argument("--plots", metavar="DIR", help="write attitude.png and residuals.png here")
    r.add_argument("--truth", metavar="CSV", help="true attitude (simulated sessions): errors in the summary")
    r.add_argument("--progress", action="store_true", help="progress bar on stderr (default: only on a terminal)")
    r.add_argument("--json", action="store_true", help="print one JSON object (the summary)")
    p.set_defaults(run=run)
    return p


def _site_and_weather(args):
    from shipstar.pipeline import Track, WeatherTable

    if args.track and (args.lat_deg is not None or args.lon_deg is not None):
        raise ShipstarError("give either --track or --lat-deg/--lon-deg, not both")
    if args.track and (args.xi_arcsec is not None or args.eta_arcsec is not None):
        raise ShipstarError("with --track the deflection of the vertical goes into its xi_arcsec and eta_arcsec "
                            "columns, not --xi-arcsec/--eta-arcsec")
    if args.track:
        track = Track.read_csv(args.track)
    elif args.lat_deg is None or args.lon_deg is None:
        raise ShipstarError("give the ship's position: --lat-deg and --lon-deg, or --track CSV")
    else:
        track = Track.fixed(args.lat_deg, args.lon_deg, args.height_m, args.xi_arcsec or 0.0, args.eta_arcsec or 0.0)
    fixed = [args.pressure_hpa, args.temperature_c]
    if args.weather and any(v is not None for v in fixed):
        raise ShipstarError("give either --weather or --pressure-hpa/--temperature-c, not both")
    if args.weather:
        return track, WeatherTable.read_csv(args.weather)
    if any(v is None for v in fixed):
        raise ShipstarError("give the weather: --pressure-hpa and --temperature-c, or --weather CSV")
    return track, WeatherTable.constant(args.pressure_hpa, args.temperature_c, args.relative_humidity)


def _installations(args) -> dict:
    from shipstar.calibrate.installation import load_installation

    names = [n for n, _ in args.sensor]
    if len(set(names)) != len(names):
        raise ShipstarError(f"each --sensor name must be given once, got {names}")
    by_sensor = {}
    for path in args.install:
        inst = load_installation(path)
        if inst.sensor not in names:
            raise ShipstarError(f"installation file {path} is for sensor {inst.sensor!r}, which is not among the "
                                f"--sensor names ({', '.join(names)})")
        if inst.sensor in by_sensor:
            raise ShipstarError(f"two installation files for sensor {inst.sensor!r}")
        by_sensor[inst.sensor] = inst
    missing = [n for n in names if n not in by_sensor]
    if missing:
        raise ShipstarError(f"no installation file for sensor {missing[0]!r}")
    return by_sensor


def _configs(args):
    from shipstar.camera import load_camera
    from shipstar.pipeline import SensorConfig, scan_frames
    from shipstar.pipeline._frames import check_sensor_name

    installs = _installations(args)
    cams = dict(args.camera)
    unknown = sorted(set(cams) - {n for n, _ in args.sensor})
    if unknown:
        raise ShipstarError(f"--camera for unknown sensor {unknown[0]!r}")
    configs, frames = [], []
    for name, directory in args.sensor:
        inst = installs[name]
        camera = load_camera(cams.get(name, inst.camera))
        configs.append(SensorConfig(name, camera, inst))
        fr = scan_frames(directory, date_obs_is=args.date_obs_is)
        check_sensor_name(fr, name, camera.name, directory)
        frames.append(fr)
    return configs, frames


def _refraction_mismatch(installs: dict, model: str, mode: str) -> list:
    """One-line messages for sensors calibrated in dock with another refraction model or
    mode: the difference enters the installation elevation and comes back as pitch/roll."""
    import math

    from shipstar.sky.refraction import Weather, refraction_rad
    from shipstar.units import RAD2ASEC, RAD2DEG

    out = []
    for name, inst in installs.items():
        d = inst.dock
        if d is None:
            continue
        if d.refraction_model and d.refraction_model != model:
            el = min(max(abs(inst.el_rad), math.radians(10.0)), math.radians(90.0))
            ok = math.isfinite(d.pressure_hpa) and math.isfinite(d.temperature_c)
            w = Weather(d.pressure_hpa, d.temperature_c) if ok else Weather()
            diff = abs(float(refraction_rad(el, w, d.refraction_model) - refraction_rad(el, w, model))) * RAD2ASEC
            out.append(f"sensor {name} was calibrated in dock with refraction model {d.refraction_model!r} but "
                       f"this run uses {model!r}: they differ by {diff:.2f}'' at its {el * RAD2DEG:.0f} deg "
                       f"elevation, which comes back as pitch/roll bias (use --refraction {d.refraction_model})")
        if d.refraction_mode and d.refraction_mode != mode:
            out.append(f"sensor {name} was calibrated in dock with {d.refraction_mode} refraction but this run "
                       f"uses {mode} (use --refraction-mode {d.refraction_mode})")
    return out


def _check_sensors_solved(result) -> None:
    for name, frames in zip(result.sensors, result.frames):
        if not any(fr.solved for fr in frames):
            reasons = sorted({fr.reason for fr in frames})
            raise ShipstarError(f"sensor {name}: none of its {len(frames)} frames solved (e.g. {reasons[0]})")


def _f2(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def _print_text(summary: dict, out: str) -> None:
    for name, s in summary["sensors"].items():
        print(f"sensor {name}: {s['n_solved']} of {s['n_frames']} frames solved, median {_f2(s['median_stars_used'])} "
              f"stars, median residual RMS {_f2(s['median_residual_rms_arcsec'])}''")
        for f in s["failures"]:
            print(f"  failed: {f['frame']} ({f['time_utc']}): {f['reason']}")
    print("method          solved   sigma heading/pitch/roll ('')    RMS vs truth ('')")
    for m, b in summary["methods"].items():
        sig = "/".join(_f2(v) for v in b["median_sigma_arcsec"])
        rms = "/".join(_f2(v) for v in b.get("rms_arcsec", [None] * 3))
        print(f"{m:15s} {b['n_solved']:4d}/{b['n']:<4d} {sig:>28s}    {rms:>20s}")
    e = summary["eop"]
    print(f"Earth orientation: {e['quality']} (UT1-UTC error {e['dut1_error_s']:.2g} s, polar motion "
          f"{e['polar_motion_error_arcsec']:.2g}'')")
    sources = "; ".join(f"{name}: " + ", ".join(f"{k} x {n}" for k, n in src.items())
                        for name, src in summary["time_sources"].items())
    print(f"frame times (DATE-OBS = {summary['date_obs_is']} of the exposure): {sources}")
    for name, s in summary["sensors"].items():
        if s["n_streak_corrected"]:
            print(f"sensor {name}: streak correction in {s['n_streak_corrected']} frames, up to "
                  f"{s['max_streak_correction_arcsec']:.2f}''")
    print(f"written: {out}")


def _check_outputs(args) -> None:
    """Every output path, before any processing."""
    check_output_file(args.out, "--out")
    if args.plots:
        check_output_dir(args.plots, "--plots", files=("attitude.png", "residuals.png"))


def _eop(frames) -> dict:
    """Earth orientation quality over all frames (JSON summary)."""
    from shipstar.pipeline import eop_quality

    times = [(f.utc_jd1, f.utc_jd2) for fr in frames for f in fr]
    jd1, jd2 = zip(*times)
    return eop_quality(jd1, jd2).as_dict()


def _csv_comments(eop: dict, warnings: list) -> list:
    """The attitude CSV's comment lines: Earth orientation quality and accuracy warnings."""
    lines = ["shipstar measure: ship attitude (docs/file-formats.md)",
             f"eop_quality = {eop['quality']}, dut1_error_s = {eop['dut1_error_s']:.3g}, "
             f"polar_motion_error_arcsec = {eop['polar_motion_error_arcsec']:.3g}"]
    return lines + ([f"warning: {w}" for w in warnings] or ["warnings: none"])


def run(args) -> int:
    import warnings

    from shipstar.errors import AccuracyWarning
    from shipstar.pipeline import (
        PipelineOptions,
        TruthTable,
        plot_session,
        process_session,
        session_summary,
        time_sources,
        write_attitude_csv,
    )
    from shipstar.pipeline._progress import ProgressBar

    _check_outputs(args)
    track, weather = _site_and_weather(args)
    truth = TruthTable.read_csv(args.truth) if args.truth else None
    configs, frames = _configs(args)
    for message in _refraction_mismatch({c.name: c.installation for c in configs}, args.refraction,
                                        args.refraction_mode):
        warnings.warn(message, AccuracyWarning, stacklevel=1)
    options = PipelineOptions(refraction_model=args.refraction, refraction=args.refraction_mode,
                              max_pair_offset_s=args.max_pair_offset_s,
                              compensate_motion=not args.no_motion_compensation,
                              streak_correction=not args.no_streak_correction)
    bar = ProgressBar(True if args.progress else None)
    try:
        result = process_session(configs, frames, track, weather, options, reference=args.reference, progress=bar)
    finally:
        bar.close()
    _check_sensors_solved(result)
    summary = session_summary(result, truth)
    summary["out"] = str(args.out)
    summary["eop"] = _eop(frames)
    summary["date_obs_is"] = args.date_obs_is
    summary["time_sources"] = {name: time_sources(fr) for name, fr in zip(result.sensors, frames)}
    summary["warnings"] = accuracy_warnings(args)
    write_attitude_csv(result, args.out, frames, _csv_comments(summary["eop"], summary["warnings"]))
    if args.plots:
        summary["plots"] = [str(p) for p in plot_session(result, args.plots, truth)]
    if args.json:
        emit_json(summary)
    else:
        _print_text(summary, args.out)
    n_failed = len(result.failures)
    if n_failed:
        sensor, label, reason = result.failures[0]
        print(f"shipstar measure: {n_failed} frames failed (first: {sensor} {label}: {reason})", file=sys.stderr)
        return 1
    return 0
