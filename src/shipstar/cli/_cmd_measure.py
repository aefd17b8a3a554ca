"""``shipstar measure``: ship heading, pitch and roll over a session from calibrated sensors."""

from __future__ import annotations

import argparse
import sys

from shipstar.cli._common import (
    accuracy_warnings,
    add_date_obs_is_argument,
    add_refraction_arguments,
    add_site_arguments,
    add_windowed_argument,
    add_weather_arguments,
    check_output_dir,
    check_output_file,
    check_folders_apart,
    check_outputs_apart,
    emit_json,
    float_in_range,
    int_in_range,
)
from shipstar.cli._header_checks import add_trust_flags_argument, override_record, print_overrides
from shipstar.cli._model_inputs import (
    add_measure_uncertainty,
    add_model_input_arguments,
    apply_eop,
    humidity,
    print_measure_uncertainty,
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
epoch of the reference sensor for the seed's fusion rule and the joint solution, an
epoch's rows together, after '#' comment lines with the Earth orientation quality and
the warnings known at the start (a warning that arises later is a '# warning:' line
where it arises, and is in the summary).  Failed frames are rows with solved=0 and
their reason.

Whole nights: rows are written as they are produced, to OUT.partial, renamed to OUT when
the session is complete; memory does not grow with the session.  Ctrl-C or SIGTERM stops
after the current epoch, leaving OUT.partial with every finished row (and a checkpoint,
OUT.resume): the same command with --resume continues it to the rows an uninterrupted
run writes (with --ins, the star attitudes are kept in OUT.ins-stars and the INS is
estimated over the whole session at the end).  --workers N (default: the cores)
processes the sensors and 60 s chunks of the session in N processes; the output is the
same for every N.  --truth CSV (time_utc,
heading_deg, pitch_deg, roll_deg; simulated sessions) adds error RMS to the summary.
The summary gives the Earth orientation quality (measured / predicted / extrapolated,
UT1-UTC error), how the frame times were read (date_obs_is, time_sources) and the
accuracy warnings, which are also printed one per line on stderr (e.g. a refraction
model other than the one the installation was calibrated with).
Integrity: at every epoch the sensors' deck attitudes are checked against each other
(chi-square of their disagreement against their combined uncertainty, false alarms 1 in
a million epochs); an inconsistent epoch's fused rows say so (integrity, integrity_chi2,
suspect_sensor: the sensor that does not fit).  Frames whose folders look swapped (each
sensor's frames fit the other's installation much better) are refused at the start.
Exit codes: 0 every frame solved, every epoch fused and consistent; 1 written, but some
frames failed, epochs have no fused attitude (the first epochs before the deck's motion
is known not counted) or are inconsistent, the counts on one line on stderr; also folders
that look swapped (nothing written); 2 bad input (including a sensor none of whose
frames solved); 130 / 143 stopped by SIGINT / SIGTERM (OUT.partial kept).
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


#: ``--smooth-lag-s`` default (s): a minute of the night holds ~600 epochs of the mounts'
#: disagreement, and the engine holds ~12 MB of epochs for it.
SMOOTH_LAG_S = 60.0


def add_processing_arguments(p):
    """The ``processing`` group that ``measure`` and ``measure-archive`` share (refraction,
    frame times, pairing, motion compensation, streak correction); returns the group."""
    o = p.add_argument_group("processing")
    add_refraction_arguments(o, "refraction model (default erfa; almanac = the seeds')",
                             "per-star (default) or the seed's boresight-only refraction")
    add_date_obs_is_argument(o)
    add_trust_flags_argument(o)
    o.add_argument("--reference", metavar="NAME", help="sensor whose frame times are the epochs (default first)")
    o.add_argument("--max-pair-offset-s", type=_non_negative, default=0.06,
                   help="largest time offset of paired frames (s, default 0.06)")
    o.add_argument("--no-motion-compensation", action="store_true",
                   help="do not carry paired frames to the epoch time (for comparison)")
    o.add_argument("--no-streak-correction", action="store_true",
                   help="do not turn streak centroids (exposure averages) to mid-exposure directions (for comparison)")
    add_windowed_argument(o)
    o.add_argument("--smooth-lag-s", type=_non_negative, default=SMOOTH_LAG_S, metavar="S",
                   help=f"fuse each epoch with the mounts' flexure estimate of the epochs up to S seconds later "
                        f"(a fixed-lag smoother, default {SMOOTH_LAG_S:g}; 0: causal, as live; docs/pipeline.md)")
    return o


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
    add_model_input_arguments(p, dock=False)     # --eop, input sigmas, humidity "not given" (docs/uncertainty.md)
    o = add_processing_arguments(p)
    r = p.add_argument_group("output")
    r.add_argument("--out", required=True, metavar="CSV", help="attitude CSV to write")
    r.add_argument("--plots", metavar="DIR", help="write attitude.png and residuals.png here")
    r.add_argument("--monitor", metavar="CSV",
                   help="per epoch and non-reference sensor, the estimated rotation of its mount relative to the "
                        "reference mount (deck axes, arcsec, with sigmas; docs/pipeline.md, Clocks and flexure)")
    r.add_argument("--truth", metavar="CSV", help="true attitude (simulated sessions): errors in the summary")
    r.add_argument("--progress", action="store_true", help="progress bar on stderr (default: only on a terminal)")
    r.add_argument("--json", action="store_true", help="print one JSON object (the summary)")
    r.add_argument("--resume", action="store_true",
                   help="continue a run stopped by Ctrl-C, SIGTERM or a crash (OUT.partial and OUT.resume)")
    o.add_argument("--workers", type=int_in_range(1, 256), default=None, metavar="N",
                   help="worker processes (default: the cores; the output is the same for every N)")
    o.add_argument("--chunk-s", type=float_in_range(1e-3, 86400.0), default=60.0, metavar="S",
                   help="processing chunk (s, default 60): each sensor's chunk is one task, a checkpoint after each")
    from shipstar.cli._ins_args import add_ins_arguments

    add_ins_arguments(p)                          # --ins, --ins-out, ... (issue 15)
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
    if args.weather and getattr(args, "relative_humidity", None) is not None:
        raise ShipstarError("--relative-humidity goes with --pressure-hpa/--temperature-c: the --weather table "
                            "gives its own (column relative_humidity, 0 without it)")
    if args.weather:
        return track, WeatherTable.read_csv(args.weather)
    if any(v is None for v in fixed):
        raise ShipstarError("give the weather: --pressure-hpa and --temperature-c, or --weather CSV")
    return track, WeatherTable.constant(args.pressure_hpa, args.temperature_c, humidity(args)[0])


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


def _configs(args) -> list:
    """Each sensor's configuration (camera and installation)."""
    from shipstar.camera import load_camera
    from shipstar.pipeline import SensorConfig

    installs = _installations(args)
    cams = dict(args.camera)
    unknown = sorted(set(cams) - {n for n, _ in args.sensor})
    if unknown:
        raise ShipstarError(f"--camera for unknown sensor {unknown[0]!r}")
    return [SensorConfig(name, load_camera(cams.get(name, installs[name].camera)), installs[name])
            for name, _ in args.sensor]


def _first_frame_time(directory, date_obs_is: str) -> tuple:
    """Mid-exposure UTC of a directory's first frame by name (the session's start is the
    earliest of the sensors'; the full index, read later, checks the order)."""
    from shipstar._fitsio import read_fits_header
    from shipstar.pipeline._frames import frame_paths

    return read_fits_header(frame_paths(directory)[0], date_obs_is=date_obs_is).mid_utc_jd()


def _sources(args, configs, track=None, weather=None, header_reader=None, progress=None) -> list:
    """Each sensor's indexed FITS frames (headers only), each header cross-checked
    (SENSOR/INSTRUME, image size, SITELAT/SITELONG, PRESSURE/TEMPERAT; ``args.header_checks``).

    ``header_reader(paths, date_obs_is)``, optional, starts reading the headers of
    ``paths`` elsewhere and returns their blocks (``scan_frames``' ``headers``): every
    sensor's are started before the first is taken (``measure-archive``: on the cluster).
    ``progress(label, done, total)``, optional: each sensor's indexing as it goes
    (:class:`~shipstar.pipeline._progress.ProgressBar`, label ``index NAME``)."""
    from shipstar.cli._header_checks import header_check
    from shipstar.pipeline._frames import frame_paths
    from shipstar.pipeline._sources import FitsDirectorySource

    headers = [None] * len(configs)
    if header_reader is not None:
        for k, (_, directory) in enumerate(args.sensor):
            try:
                headers[k] = header_reader(frame_paths(directory), args.date_obs_is)
            except ShipstarError:
                pass                                    # raised below, in the sensors' order
    sources, args.header_checks = [], []
    for config, (name, directory), given in zip(configs, args.sensor, headers):
        check = header_check(args, names=(name, config.camera.name), camera=config.camera, track=track,
                             weather=weather, given_name=f"--sensor {name}={directory} (camera {config.camera.name})",
                             position_flags=not getattr(args, "track", None),
                             weather_flags=not getattr(args, "weather", None), sensor=name,
                             known_cameras=[c.camera.name for c in configs])
        args.header_checks.append(check)
        shown = None if progress is None else (lambda done, total, name=name: progress(f"index {name}", done, total))
        sources.append(FitsDirectorySource(name, directory, date_obs_is=args.date_obs_is, check=check,
                                           headers=given, progress=shown))
    return sources


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


def _f2(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def _print_mounts(summary: dict) -> None:
    """Clock offsets and flexure (pipeline._mounts), one line per non-reference sensor."""
    for name, c in summary.get("time_offsets_s", {}).items():
        f = summary["flexure"].get(name, {})
        if c["offset_s"] is None:
            print(f"sensor {name}: clock offset and flexure not estimated yet ({f.get('n_epochs', 0)} epochs)")
            continue
        st, ss = f["static_arcsec"], f["static_sigma_arcsec"]
        wa = f["wave_amplitude_arcsec"]
        axes = ("bow", "up", "starboard")
        print(f"sensor {name}: clock offset {c['offset_s'] * 1e3:+.3f} +- {c['sigma_s'] * 1e3:.3f} ms "
              f"({'applied' if c['applied'] else 'not applied'}); mount vs {summary['reference_sensor']}'s, static "
              + "/".join(_f2(st[a]) for a in axes) + " +- " + "/".join(_f2(ss[a]) for a in axes)
              + "'' (bow/up/starboard" + (", installation drift" if f["installation_drift"] else "")
              + "), wave amplitude " + "/".join(_f2(wa[a]) for a in axes)
              + f"'' ({'applied' if f['applied'] else 'not applied'})")


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
    i = summary.get("integrity")
    if i is not None:
        print(f"integrity: {i['n_inconsistent']} of {i['n_checked']} epochs inconsistent"
              + "".join(f"; {k} does not fit in {v}" for k, v in i["suspects"].items())
              + ("" if i["max_chi2"] is None else f" (largest chi2 {i['max_chi2']:.1f}, limit {i['chi2_limit']:.1f})"))
        for f in i["inconsistent"]:
            print(f"  inconsistent: {f['frame']} ({f['time_utc']}): {f['disagreement_arcsec']:.1f}'', "
                  f"chi2 {f['chi2']:.1f}, {f['suspect']} does not fit")
    _print_mounts(summary)
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
    """Every output path, before any processing: writable, and apart from the inputs and
    from each other."""
    from shipstar.cli._ins_args import PLOT_FILES

    check_output_file(args.out, "--out")
    if args.monitor:
        check_output_file(args.monitor, "--monitor")
    if args.plots:
        check_output_dir(args.plots, "--plots", files=("attitude.png", "residuals.png"))
    ins = bool(getattr(args, "ins", None))
    check_folders_apart(args)
    check_outputs_apart(args, [("--out", args.out, None), ("--monitor", args.monitor, None),
                               ("--plots", args.plots, ("attitude.png", "residuals.png")),
                               ("--plots", args.plots if ins else None, PLOT_FILES),
                               ("--ins-out", getattr(args, "ins_out", None), None),
                               ("--ins-report", getattr(args, "ins_report", None), None)])


def _eop(sources) -> dict:
    """Earth orientation quality over all frames (JSON summary)."""
    import numpy as np

    from shipstar.pipeline import eop_quality

    times = [s.times_utc_jd() for s in sources]
    return eop_quality(np.concatenate([t[0] for t in times]), np.concatenate([t[1] for t in times])).as_dict()


def _csv_comments(eop: dict, warnings: list) -> list:
    """The attitude CSV's comment lines known at the start: the software that writes it,
    Earth orientation quality and the warnings so far (later ones are written where they
    arise)."""
    from shipstar._codeid import software_line
    from shipstar.sky.eop import eop_source

    lines = ["shipstar measure: ship attitude (docs/file-formats.md)", software_line(),
             f"eop_quality = {eop['quality']}, dut1_error_s = {eop['dut1_error_s']:.3g}, "
             f"polar_motion_error_arcsec = {eop['polar_motion_error_arcsec']:.3g}",
             f"eop_source = {eop_source()}"]
    return lines + ([f"warning: {w}" for w in warnings] or
                    ["warnings at the start: none (a warning that arises later is written where it arises)"])


def _override_comments(record: dict) -> list:
    """The attitude CSV's comment lines of a run with --trust-flags (none without)."""
    from shipstar.pipeline._header_check import override_lines

    if not record:
        return []
    lines = override_lines(record["header_overrides"])
    return ["trust_flags = true: the flags were used where the frames' FITS headers contradict them"
            + ("" if lines else " (no contradiction found)")] + [f"header override: {line}" for line in lines]


def _check_partial(args) -> None:
    """Without --resume, refuse to start over a stopped run's output (hours of work)."""
    from pathlib import Path

    from shipstar.pipeline._measure import resume_path

    out = Path(args.out)
    partial = out.with_name(out.name + ".partial")
    if not args.resume and (partial.exists() or resume_path(out).exists()):
        raise ShipstarError(f"{partial} is the output of a stopped run: continue it with --resume, or delete "
                            f"{partial} and {resume_path(out).name} to start again")


def _job(args, track, weather):
    """The MeasureJob of the command line (what every worker needs), from the first frame
    of each sensor; the frames themselves are indexed afterwards (:func:`_sources`)."""
    import warnings

    from shipstar.errors import AccuracyWarning
    from shipstar.pipeline import PipelineOptions
    from shipstar.pipeline._measure import MeasureJob, job_tables

    configs = _configs(args)
    names = [c.name for c in configs]
    if args.reference is not None and args.reference not in names:
        raise ShipstarError(f"reference sensor {args.reference!r} is not one of {', '.join(names)}")
    for message in _refraction_mismatch({c.name: c.installation for c in configs}, args.refraction,
                                        args.refraction_mode):
        warnings.warn(message, AccuracyWarning, stacklevel=1)
    options = PipelineOptions(refraction_model=args.refraction, refraction=args.refraction_mode,
                              max_pair_offset_s=args.max_pair_offset_s,
                              compensate_motion=not args.no_motion_compensation,
                              streak_correction=not args.no_streak_correction,
                              windowed_full_frame_every=args.windowed_full_frame_every)
    firsts = [_first_frame_time(directory, args.date_obs_is) for _, directory in args.sensor]
    start = min(firsts, key=lambda jd: (jd[0] - firsts[0][0]) + jd[1])
    ref = names.index(args.reference) if args.reference else 0
    return MeasureJob(tuple(configs), track, weather, options, (float(start[0]), float(start[1])), ref,
                      smooth_lag_s=float(args.smooth_lag_s), **job_tables())


def _check_covered(sources, track, weather) -> None:
    """Before any work: every frame time lies between two rows of the track and of the
    weather (no longer apart than each allows) or within 1 s of their first or last row;
    the first frame that does not is named (shipstar.pipeline._tables, docs/conventions.md)."""
    for source in sources:
        jd1, jd2 = source.times_utc_jd()
        for table in (track, weather):
            if hasattr(table, "check_covers_all"):
                table.check_covers_all(jd1, jd2)
            else:
                for k in (0, -1):
                    table.check_covers(jd1[k], jd2[k])


def run(args) -> int:
    from shipstar._codeid import software
    from shipstar._signals import EXIT_CODES, StopOnSignals
    from shipstar.pipeline import TruthTable
    from shipstar.pipeline._integrity import swap_check
    from shipstar.pipeline._measure import WorkerPool, default_workers, run_measure
    from shipstar.pipeline._plots import plot_attitude_csv
    from shipstar.pipeline._progress import ProgressBar

    _check_outputs(args)
    _check_partial(args)
    from shipstar.cli._ins_args import finish_ins, ins_observer

    ins_rows = ins_observer(args)                 # --ins: the joint attitudes collected as they come
    apply_eop(args)
    track, weather = _site_and_weather(args)
    truth = TruthTable.read_csv(args.truth) if args.truth else None
    job = _job(args, track, weather)
    n_workers = args.workers or default_workers()
    pool = WorkerPool(job, n_workers) if n_workers > 1 else None     # warms up while the frames are indexed
    bar = ProgressBar(True if args.progress else None)
    try:
        sources = _sources(args, job.configs, track, weather, header_reader=pool.read_headers if pool else None,
                           progress=bar)
        _check_covered(sources, track, weather)
        swapped = swap_check(job.configs, sources, track, weather, job.options)
        if swapped:
            print(f"shipstar measure: error: {swapped}", file=sys.stderr)
            return 1
        eop = _eop(sources)
        start_warnings = accuracy_warnings(args)
        overrides = override_record(args.header_checks)
        print_overrides("measure", overrides)
        with StopOnSignals() as stop:
            outcome = run_measure(job, sources, args.out, truth=truth,
                                  comments=_csv_comments(eop, start_warnings) + _override_comments(overrides),
                                  workers=pool or 1, resume=args.resume, chunk_s=args.chunk_s,
                                  progress=lambda done, total: bar("frames", done, total), stop=stop,
                                  monitor=args.monitor, observer=ins_rows)
    finally:
        bar.close()
        if pool is not None:
            pool.close(abort=True)
    names = [c.name for c in job.configs]
    fore, athw = _roles(job.configs)
    summary = outcome.stats.summary(reference_sensor=names[job.reference], fore_aft_sensor=fore,
                                    athwartship_sensor=athw, options=job.options)
    summary["out"] = str(outcome.path)
    summary["complete"] = outcome.complete
    summary["software"] = software()
    summary["eop"] = eop
    add_measure_uncertainty(summary, args, job)
    summary["date_obs_is"] = args.date_obs_is
    summary["time_sources"] = {s.name: s.time_sources() for s in sources}
    summary["warnings"] = list(dict.fromkeys(start_warnings + list(outcome.warnings)))
    summary.update(overrides)
    if not outcome.stopped:
        finish_ins(args, job, ins_rows, summary, truth)
    if outcome.resumed_at_s is not None:
        summary["resumed_at_s"] = outcome.resumed_at_s
    if outcome.stopped:
        summary["stopped"] = outcome.stopped
    elif args.plots:
        summary["plots"] = [str(p) for p in plot_attitude_csv(outcome.path, args.plots, truth)]
    if args.json:
        emit_json(summary)
    else:
        _print_text(summary, str(outcome.path))
        print_measure_uncertainty(summary)
    if outcome.stopped:
        print(f"shipstar measure: stopped by {outcome.stopped} after {outcome.n_epochs_written} epochs; "
              f"{outcome.path} holds every finished row; the same command with --resume continues it",
              file=sys.stderr)
        return EXIT_CODES.get(outcome.stopped, 1)
    problems = outcome.stats.problems_line()
    if problems:
        print(f"shipstar measure: {problems}", file=sys.stderr)
        return 1
    return 0


def _roles(configs) -> tuple[str, str]:
    from shipstar.pipeline import sensor_roles

    fore, athw = sensor_roles(configs)
    return (configs[fore].name if fore >= 0 else "", configs[athw].name if athw >= 0 else "")
