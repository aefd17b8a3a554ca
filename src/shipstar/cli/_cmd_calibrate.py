"""``shipstar calibrate {intrinsics,install}``: the calibration command group.

``intrinsics`` (this module): focal length, principal point and Weng distortion from
star frames (seed 002, docs/calibration-intrinsic.md).  ``install``
(``cli/_calibrate_install.py``): installation angles from dock frames.
"""

from __future__ import annotations

import argparse
import sys

from shipstar.cli._common import (
    accuracy_warnings,
    add_date_obs_is_argument,
    add_refraction_arguments,
    add_site_arguments,
    add_weather_arguments,
    check_output_file,
    check_outputs_apart,
    emit_json,
)

from shipstar.cli._header_checks import add_trust_flags_argument

__all__ = ["register"]

GROUP_EPILOG = """\
examples:
  shipstar calibrate intrinsics --frames night1/ --camera seed002 --out seed002.cal.toml
  shipstar calibrate install --frames dock/A1 --sensor A1 --camera A1 ... --out A1.install.toml

Run 'shipstar calibrate COMMAND --help' for a command's options.
"""

INTRINSICS_EPILOG = """\
example (20 frames of the night sky, taken on the ground):
  shipstar calibrate intrinsics --frames night1/ --camera seed002 --method joint \\
      --lat-deg 28.2 --lon-deg 112.9 --pressure-hpa 1008 --temperature-c 12 \\
      --out seed002.cal.toml --json

Frames: a directory of FITS images (mid-exposure UTC from DATE-AVG, else DATE-OBS, the
start, plus EXPTIME/2, or DATE-OBS itself with --date-obs-is mid; site and weather from
SITELAT/SITELONG/SITEELEV/PRESSURE/TEMPERAT when present), extracted and identified with
the nominal camera, or of JSON star lists {"stars": [{"x_px", "y_px", "hip"}], "date_obs",
"camera", "width_px", "height_px"} as 'shipstar solve --json' writes them (stars with "x",
"y", as older files have them, are read too; add --date-obs when they carry no time).
Reference directions are apparent places at the observation time with per-star
refraction at the observing site.  Frames taken on the ground need that site (the flags,
or the files'): without one they are refused, unless --in-space says they were taken
above the atmosphere (simulated frames in space, SIMFRAME = 'icrs', pass as they are).

Methods: sine / cosine = seed 002's observation equations on the sines / cosines of the
interstar angles with its two-step iteration; joint = all parameters at once, robust
(Huber), with a free attitude per frame.  --terms: auto (default: the Weng terms the data
support, by a likelihood-ratio check), all (seed 002's full Weng model: unsupported terms
fit noise and drag the principal point, a warning says so), none (f and principal point
only), or a list such as k1,k2,p1,p2 (--no-term-check skips the check for a list).
Writes the calibrated camera (TOML) and a plot of the residual vectors over the sensor.
Exit codes: 0 calibrated; 1 the fit did not converge (nothing written); 2 bad input.
"""


def register(subparsers) -> argparse.ArgumentParser:
    """Add the ``calibrate`` group with its sub-commands."""
    from shipstar.cli._calibrate_install import add_install_parser

    p = subparsers.add_parser(
        "calibrate", help="calibrate a star sensor (intrinsics, installation)",
        description="Calibrate a star sensor: its intrinsic parameters from star frames, or its "
                    "installation angles from dock frames.",
        epilog=GROUP_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="calibrate_command", metavar="{intrinsics,install}")
    _add_intrinsics_parser(sub)
    add_install_parser(sub)
    p.set_defaults(run=lambda args: _group_help(p))
    return p


def _group_help(parser) -> int:
    parser.print_help(sys.stderr)
    return 2


SITE_HELPS = {
    "lat_deg": "observing site geodetic latitude (deg)",
    "lon_deg": "observing site longitude, east positive (deg)",
    "height_m": "site height above WGS84 (m, default 0)",
}
WEATHER_HELPS = {
    "pressure_hpa": "air pressure at the sensor (hPa)",
    "temperature_c": "air temperature (C, default 10)",
    "relative_humidity": "0..1 (erfa model only, default 0)",
}


def _add_intrinsics_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "intrinsics", help="focal length, principal point and distortion from star frames",
        description="Calibrate a star sensor's focal length, principal point and Weng distortion "
                    "from star frames alone, by the invariance of interstar angles (seed 002).",
        epilog=INTRINSICS_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", required=True, metavar="DIR", help="directory of FITS frames or JSON star lists")
    p.add_argument("--camera", required=True, metavar="NAME|FILE", help="nominal camera: preset or TOML file")
    p.add_argument("--method", choices=("sine", "cosine", "joint"), default="joint",
                   help="sine / cosine: seed 002's two-step method; joint (default): all at once, robust")
    p.add_argument("--terms", default="auto", metavar="LIST",
                   help="distortion terms: auto (default: those the data support), all, none, or e.g. "
                        "k1,k2,p1,p2,s1,s2")
    p.add_argument("--pairs", action="store_true",
                   help="joint: fit the interstar angles instead of star directions with per-frame attitudes")
    p.add_argument("--no-term-check", action="store_true",
                   help="skip the check of which distortion terms the data support (needs explicit --terms)")
    p.add_argument("--date-obs", metavar="ISO",
                   help="UTC of frames that carry no time (ISO 8601; refused for frames with their own)")
    add_date_obs_is_argument(p, "what FITS frames' DATE-OBS means: start of the exposure (FITS standard, "
                                "default) or mid-exposure (cameras that write it so)")
    add_site_arguments(p, SITE_HELPS, deflection=False)
    add_weather_arguments(p, WEATHER_HELPS, humidity_default=None)
    add_refraction_arguments(p, "refraction model for frames with a site (default: the file's, else erfa)",
                             default=None)
    p.add_argument("--in-space", action="store_true",
                   help="the frames were taken above the atmosphere: no site, no refraction")
    add_trust_flags_argument(p)
    p.add_argument("--out", required=True, metavar="FILE.toml", help="calibrated camera file to write")
    p.add_argument("--plot", metavar="FILE.png",
                   help="residual-vector plot (default: next to --out, <name>.residuals.png)")
    p.add_argument("--no-plot", action="store_true", help="do not write the plot")
    p.add_argument("--progress", action="store_true", help="progress bar on stderr (default: only on a terminal)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    from shipstar.cli._model_inputs import add_eop_argument

    add_eop_argument(p)
    p.set_defaults(run=run_intrinsics)
    return p


def _site_and_weather(args):
    from shipstar.errors import ShipstarError
    from shipstar.sky.apparent import Site
    from shipstar.sky.refraction import Weather

    site = None
    if (args.lat_deg is None) != (args.lon_deg is None):
        raise ShipstarError("give both --lat-deg and --lon-deg (or neither)")
    if args.lat_deg is not None:
        site = Site.from_deg(args.lat_deg, args.lon_deg, args.height_m)
    weather = None
    if args.pressure_hpa is not None or args.temperature_c is not None or args.relative_humidity is not None:
        weather = Weather(pressure_hpa=1013.25 if args.pressure_hpa is None else args.pressure_hpa,
                          temperature_c=10.0 if args.temperature_c is None else args.temperature_c,
                          relative_humidity=0.0 if args.relative_humidity is None else args.relative_humidity)
    return site, weather


def _check_plot_format(path) -> None:
    """Refuse a plot file name whose extension matplotlib cannot write (it chooses the
    format by it): found only after the calibration, it was a traceback beside a camera
    file already written."""
    from pathlib import Path

    from matplotlib.backend_bases import FigureCanvasBase

    from shipstar.errors import ShipstarError

    formats = FigureCanvasBase.get_supported_filetypes()
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in formats:
        raise ShipstarError(f"--plot {path}: the plot's format is its extension, one of "
                            f"{', '.join(sorted(formats))}; got {('.' + suffix) if suffix else 'none'}")


def _default_plot_path(out: str) -> str:
    from pathlib import Path

    path = Path(out)
    stem = path.name[:-5] if path.name.lower().endswith(".toml") else path.name
    return str(path.with_name(stem + ".residuals.png"))


def _calibrated_camera(cal, args):
    notes = (f"calibrated by shipstar calibrate intrinsics: method {cal.method}, terms "
             f"{','.join(t for t in cal.fitted[3:]) or 'none'}, {cal.n_frames} frames, {cal.n_stars} stars "
             f"from {args.frames}; interstar rms {cal.rms_after_arcsec:.3f} arcsec")
    record = getattr(args, "header_record", {})
    if record:
        from shipstar.pipeline._header_check import override_lines

        lines = override_lines(record["header_overrides"])
        notes += "; trust_flags = true" + (": " + "; ".join(lines) if lines else " (no header contradiction)")
    return cal.camera.replace(notes=notes)


def _terms_text(cal) -> str:
    """What the term check said, for the text output."""
    if not cal.terms_checked:
        return "distortion terms: not checked (--no-term-check)"
    supported = ", ".join(cal.supported_distortion_terms) or "none supported by the data"
    return f"distortion terms the data support: {supported}"


def _print_table(cal, out_path, plot_path, skipped) -> None:
    print(f"camera {cal.camera.name!r}: method {cal.method}, {cal.n_frames} frames, {cal.n_stars} stars, "
          f"{cal.n_pairs} pairs")
    for name in cal.fitted:
        print(f"  {name:12s} {cal.values[name]: .8g}  +- {cal.sigma[name]:.3g}")
    print(f"  interstar rms: before {cal.rms_before_rad:.3e} rad ({cal.rms_before_arcsec:.3f}\"), "
          f"after {cal.rms_after_rad:.3e} rad ({cal.rms_after_arcsec:.3f}\")")
    print(f"  centroid noise {cal.centroid_sigma_px:.3f} px; {_terms_text(cal)}")
    for name, reason in skipped:
        print(f"  skipped {name}: {reason}")
    if out_path:
        print(f"wrote {out_path}" + (f" and {plot_path}" if plot_path else ""))
    elif not cal.solved:
        print(f"not calibrated: {cal.reason}")


def _check_arguments(args) -> None:
    """Conflicting flags and unwritable outputs, before any work."""
    from shipstar.errors import ShipstarError

    if args.plot and args.no_plot:
        raise ShipstarError("give --plot or --no-plot, not both")
    if not args.terms.strip():                  # an unset variable in a script, not "none"
        raise ShipstarError("--terms is empty: give auto, all, none or a list such as k1,k2,p1,p2")
    if args.no_term_check and args.terms.strip().lower() == "auto":
        raise ShipstarError("--no-term-check needs explicit --terms (auto chooses the terms by that check)")
    if args.in_space and (args.lat_deg is not None or args.pressure_hpa is not None
                          or args.temperature_c is not None or args.refraction is not None):
        raise ShipstarError("--in-space frames have no site, weather or refraction: drop --lat-deg/--lon-deg, "
                            "--pressure-hpa, --temperature-c and --refraction")
    check_output_file(args.out, "--out")
    plot = None if args.no_plot else args.plot or _default_plot_path(args.out)
    if plot is not None:
        check_output_file(plot, "--plot")
        _check_plot_format(plot)
    check_outputs_apart(args, [("--out", args.out, None), ("--plot", plot, None)])


def _warn_unsupported(cal) -> None:
    import warnings

    from shipstar.errors import AccuracyWarning

    if cal.solved and cal.unsupported_fitted_terms:
        warnings.warn(f"fitted distortion terms the data do not support: {', '.join(cal.unsupported_fitted_terms)} "
                      "(their values are fitted noise and move the principal point; --terms auto fits only the "
                      "supported ones)", AccuracyWarning, stacklevel=1)


def _check_headers(args, camera, site, weather) -> dict:
    """The FITS frames' headers against --camera, --lat-deg/--lon-deg and the weather
    flags (when given: without them the headers' own values are used); ShipstarError on
    a contradiction, the override record with --trust-flags."""
    from shipstar.cli._header_checks import check_fits_dir, header_check, override_record, print_overrides
    from shipstar.pipeline import Track, WeatherTable

    track = None if site is None else Track.fixed(args.lat_deg, args.lon_deg, args.height_m)
    table = None if weather is None else WeatherTable.constant(weather.pressure_hpa, weather.temperature_c,
                                                               weather.relative_humidity)
    check = header_check(args, names=(camera.name,), camera=camera, track=track, weather=table,
                         given_name=f"--camera {args.camera}", position_flags=True, weather_flags=True)
    check_fits_dir(args.frames, check, args.date_obs_is)
    record = override_record([check])
    print_overrides("calibrate intrinsics", record)
    return record


def run_intrinsics(args) -> int:
    from shipstar.calibrate.intrinsics import calibrate_intrinsics, load_calibration_frames, plot_residuals
    from shipstar.camera import load_camera, save_camera
    from shipstar.errors import ShipstarError

    _check_arguments(args)
    camera = load_camera(args.camera)
    site, weather = _site_and_weather(args)
    args.header_record = _check_headers(args, camera, site, weather)
    from shipstar.pipeline._progress import ProgressBar

    bar = ProgressBar(True if args.progress else None)
    try:
        loaded = load_calibration_frames(args.frames, camera, utc=args.date_obs, site=site, weather=weather,
                                         refraction_model=args.refraction, date_obs_is=args.date_obs_is,
                                         progress=bar)
    finally:
        bar.close()
    if not loaded.frames:
        reasons = "; ".join(f"{n}: {r}" for n, r in loaded.skipped[:3])
        raise ShipstarError(f"no usable frame in {args.frames!r} ({reasons})")
    cal = calibrate_intrinsics(loaded.frames, camera, method=args.method, terms=args.terms,
                               attitudes=not args.pairs, check_terms=not args.no_term_check,
                               in_space=args.in_space)
    _warn_unsupported(cal)
    out_path = plot_path = None
    if cal.solved:
        save_camera(_calibrated_camera(cal, args), args.out)
        out_path = args.out
        if not args.no_plot:
            plot_path = str(plot_residuals(cal, args.plot or _default_plot_path(args.out)))
    if args.json:
        obj = cal.as_json_dict()
        obj.update(frames_dir=str(args.frames), source=loaded.kind, out=out_path, plot=plot_path,
                   skipped=[{"file": n, "reason": r} for n, r in loaded.skipped], in_space=bool(args.in_space),
                   warnings=accuracy_warnings(args), **args.header_record)
        emit_json(obj)
    else:
        _print_table(cal, out_path, plot_path, loaded.skipped)
    if cal.solved and loaded.skipped:
        n = len(loaded.skipped) + len(loaded.frames)
        name, reason = loaded.skipped[0]
        print(f"shipstar calibrate intrinsics: {len(loaded.skipped)} of {n} frames skipped (first: {name}: "
              f"{reason}); {out_path} written from the other {len(loaded.frames)}", file=sys.stderr)
        return 1
    return 0 if cal.solved else 1
