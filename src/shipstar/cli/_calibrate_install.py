"""``shipstar calibrate install``: a sensor's installation angles from dock frames (seed 000 section 3).

This module exposes :func:`add_install_parser`; the ``calibrate`` command group
(``cli/_cmd_calibrate.py``) adds it to its sub-commands.
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
    in_range,
)

from shipstar.cli._header_checks import add_trust_flags_argument, override_record, print_overrides
from shipstar.cli._model_inputs import (
    add_model_input_arguments,
    apply_eop,
    humidity,
    installation_with_uncertainty,
    print_uncertainty,
    uncertainty_report,
)

__all__ = ["add_install_parser", "run_install"]

EPILOG = """\
example (seed 000's dock night, sensor A1):
  shipstar calibrate install --frames dock/A1 --sensor A1 --camera A1 \\
      --lat-deg 31.9 --lon-deg 120.3 --xi-arcsec 0 --eta-arcsec 0 \\
      --heading-deg 46.474586 --pitch-deg 0 --roll-deg 0 \\
      --pressure-hpa 1021.7 --temperature-c 11.1 --out A1.install.toml --json

Frames: one sensor's FITS files, in time order by file name; the frame time is
mid-exposure UTC: DATE-AVG, else DATE-OBS (the start, FITS standard) plus EXPTIME/2
(--date-obs-is mid: DATE-OBS is already mid-exposure).

The ship's true attitude comes from the theodolite (heading) and the levels (pitch,
roll).  The levels follow the plumb line, so give the dock's deflection of the vertical
(--xi-arcsec north-south, --eta-arcsec east-west; 5-30'' in most places): left out, it
goes one to one into the installation elevation and roll and comes back at sea as pitch
and roll bias.  Each frame gives C_deck_from_sensor = C_hor_from_deck.T @ C_hor_from_sensor;
the frames are averaged on SO(3) after rejecting outliers, and the installation angles
(az from the bow toward starboard, el above the deck, roll about the boresight) are
written with their per-frame std and standard error (docs/calibration-dock.md), the dock
conditions (weather, refraction model, deflection of the vertical), the Earth orientation
quality and any accuracy warnings.
The ship must be still for every frame: frames whose installation scatters more than a
still ship's can (their own noise plus 20'' across the boresight, 200'' about it; a ship
at sea rolls by degrees) are refused as "the ship moved during the calibration frames";
with --trust-flags the file is written anyway, the line recorded in its warnings.
Exit codes: 0 every frame solved and used; 1 written, but some frames failed (listed) or
were rejected as outliers of the mean (the counts on one line on stderr); 2 bad input.
"""


SITE_HELPS = {
    "lat_deg": "dock geodetic latitude (deg)",
    "lon_deg": "dock longitude, east positive (deg)",
    "height_m": "height above WGS84 (m, default 0)",
    "xi_arcsec": "deflection of the vertical at the dock, north-south (arcsec, default 0)",
    "eta_arcsec": "deflection of the vertical at the dock, east-west (arcsec, default 0)",
}
WEATHER_HELPS = {
    "pressure_hpa": "air pressure at the sensor (hPa)",
    "temperature_c": "air temperature (C)",
    "relative_humidity": "0..1 (erfa model, default 0)",
}


def add_install_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``install`` to the ``calibrate`` group's sub-parsers."""
    p = subparsers.add_parser(
        "install", help="installation angles of a star sensor from dock frames",
        description="Calibrate a star sensor's installation angles (az, el, roll) relative to the deck from "
                    "frames taken in dock with the ship's true heading and level known (seed 000 section 3).",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", required=True, metavar="DIR", help="directory of the sensor's FITS frames")
    p.add_argument("--sensor", required=True, metavar="NAME", help="sensor name, e.g. A1")
    p.add_argument("--camera", required=True, metavar="NAME|FILE", help="camera preset or camera TOML file")
    add_site_arguments(p, SITE_HELPS, required=True)
    p.add_argument("--heading-deg", required=True, type=in_range("heading_deg"),
                   help="true ship heading K0 (deg: 46.474586, 46d28m28.51s or 46:28:28.51)")
    p.add_argument("--pitch-deg", type=in_range("pitch_deg"), default=0.0, help="ship pitch psi0 from the levels (deg)")
    p.add_argument("--roll-deg", type=in_range("roll_deg"), default=0.0, help="ship roll theta0 from the levels (deg)")
    add_weather_arguments(p, WEATHER_HELPS, required=True)
    add_refraction_arguments(p, "refraction model (default erfa; almanac = the seeds' model)",
                             "per-star refraction (default) or the seed's ref. [9] boresight-only correction")
    add_date_obs_is_argument(p)
    add_trust_flags_argument(p)
    add_model_input_arguments(p, dock=True)      # --eop, input sigmas, humidity "not given" (docs/uncertainty.md)
    p.add_argument("--session", metavar="LABEL", help="session label recorded in the file (default: DIR)")
    p.add_argument("--out", required=True, metavar="FILE.toml", help="installation file to write")
    p.add_argument("--progress", action="store_true", help="progress bar on stderr (default: only on a terminal)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--at-sea", action="store_true",
                   help="re-estimate the installation from at-sea frames relative to a reference sensor instead "
                        "(other options: 'shipstar calibrate install --at-sea --help')")
    p.set_defaults(run=run_install)
    _route_at_sea(p)
    return p


def _route_at_sea(p) -> None:
    """Arguments with ``--at-sea`` go to that mode's own parser (cli/_calibrate_at_sea.py)."""
    from shipstar.cli._calibrate_at_sea import AT_SEA_FLAG, at_sea_parser

    dock_parse = p.parse_known_args

    def parse_known_args(args=None, namespace=None):
        if args is not None and AT_SEA_FLAG in args:
            return at_sea_parser(f"{p.prog} {AT_SEA_FLAG}", type(p)).parse_known_args(args, namespace)
        return dock_parse(args, namespace)

    p.parse_known_args = parse_known_args


def _process(args, camera):
    from shipstar.pipeline import PipelineOptions, SensorConfig, Track, WeatherTable, process_sensor, scan_frames
    from shipstar.cli._header_checks import header_check
    from shipstar.pipeline._progress import ProgressBar

    track = Track.fixed(args.lat_deg, args.lon_deg, args.height_m, args.xi_arcsec, args.eta_arcsec)
    weather = WeatherTable.constant(args.pressure_hpa, args.temperature_c, humidity(args)[0])
    args.header_check = header_check(args, names=(args.sensor, camera.name), camera=camera, track=track,
                                     weather=weather, given_name=f"--sensor {args.sensor} (camera {camera.name})",
                                     position_flags=True, weather_flags=True)
    frames = scan_frames(args.frames, date_obs_is=args.date_obs_is, check=args.header_check)
    options = PipelineOptions(refraction_model=args.refraction, refraction=args.refraction_mode)
    bar = ProgressBar(True if args.progress else None)
    try:
        return frames, process_sensor(SensorConfig(args.sensor, camera), frames, track, weather, options,
                                      progress=bar)
    finally:
        bar.close()


def _calibrate(args, camera, frames, results):
    import numpy as np

    from shipstar.calibrate.installation import DockConditions, calibrate_installation
    from shipstar.pipeline import eop_quality
    from shipstar.units import ASEC2RAD, DEG2RAD

    eop = eop_quality([f.utc_jd1 for f in frames], [f.utc_jd2 for f in frames])
    dock = DockConditions(args.heading_deg * DEG2RAD, args.pitch_deg * DEG2RAD, args.roll_deg * DEG2RAD,
                          args.lat_deg * DEG2RAD, args.lon_deg * DEG2RAD, args.height_m, args.pressure_hpa,
                          args.temperature_c, args.refraction, args.refraction_mode,
                          xi_rad=args.xi_arcsec * ASEC2RAD, eta_rad=args.eta_arcsec * ASEC2RAD,
                          eop_quality=eop.quality, dut1_error_s=eop.dut1_error_s,
                          polar_motion_error_arcsec=eop.polar_motion_error_arcsec)
    C_hs = np.array([r.C_hor_from_sensor for r in results])
    cov = np.array([r.horizontal.covariance_rad2 if r.solved else np.full((3, 3), np.nan) for r in results])
    record = override_record([args.header_check])
    return calibrate_installation(
        C_hs, dock.C_hor_from_deck, solved=[r.solved for r in results], sensor=args.sensor, camera=camera.name,
        reasons=[r.reason for r in results], covariance_rad2=cov.reshape(-1, 3, 3),
        if_moved="warn" if args.trust_flags else "refuse",
        moved_hint="use --trust-flags to use the heading and level given anyway",
        session=args.session or str(args.frames),
        date_utc=frames[0].utc_iso, dock=dock, warnings=tuple(accuracy_warnings(args)),
        trust_flags=bool(record), header_overrides=tuple(_override_lines(record)))


def _override_lines(record: dict) -> list:
    from shipstar.pipeline._header_check import override_lines

    return override_lines(record.get("header_overrides", []))


def _report(inst, results, out) -> dict:
    from shipstar.units import RAD2ASEC, RAD2DEG

    d = inst.dock
    return {
        "sensor": inst.sensor, "camera": inst.camera, "out": str(out),
        "az_deg": inst.az_rad * RAD2DEG, "el_deg": inst.el_rad * RAD2DEG, "roll_deg": inst.roll_rad * RAD2DEG,
        "std_arcsec": dict(zip(("az", "el", "roll"), inst.std_arcsec)),
        "sem_arcsec": dict(zip(("az", "el", "roll"), inst.sem_arcsec)),
        "n_frames": inst.n_frames, "n_used": inst.n_used, "n_failed": inst.n_failed, "n_rejected": inst.n_rejected,
        "failures": [{"frame": r.label, "time_utc": r.utc_iso, "reason": r.reason} for r in results if not r.solved],
        "xi_arcsec": d.xi_rad * RAD2ASEC, "eta_arcsec": d.eta_rad * RAD2ASEC,
        "refraction_model": d.refraction_model, "refraction_mode": d.refraction_mode,
        "eop": {"quality": d.eop_quality, "dut1_error_s": d.dut1_error_s,
                "polar_motion_error_arcsec": d.polar_motion_error_arcsec},
        "warnings": list(inst.warnings),
    }


def _print_text(rep: dict) -> None:
    s, e = rep["std_arcsec"], rep["sem_arcsec"]
    print(f"sensor {rep['sensor']} (camera {rep['camera']}): {rep['n_used']} of {rep['n_frames']} frames used, "
          f"{rep['n_failed']} failed, {rep['n_rejected']} rejected")
    for k, name in (("az", "azimuth"), ("el", "elevation"), ("roll", "roll")):
        print(f"  {name:9s} {rep[k + '_deg']:14.7f} deg   std {s[k]:8.3f}''   sem {e[k]:7.3f}''")
    for f in rep["failures"]:
        print(f"  failed: {f['frame']} ({f['time_utc']}): {f['reason']}")
    e = rep["eop"]
    print(f"  deflection of the vertical xi {rep['xi_arcsec']:.2f}'' eta {rep['eta_arcsec']:.2f}''; refraction "
          f"{rep['refraction_model']} ({rep['refraction_mode']}); Earth orientation {e['quality']} "
          f"(UT1-UTC error {e['dut1_error_s']:.2g} s)")
    print(f"written: {rep['out']}")


def run_install(args) -> int:
    from shipstar.calibrate.installation import save_installation
    from shipstar.camera import load_camera

    check_output_file(args.out, "--out")
    check_outputs_apart(args, [("--out", args.out, None)])
    camera = load_camera(args.camera)
    apply_eop(args)
    frames, results = _process(args, camera)
    inst = installation_with_uncertainty(args, camera, _calibrate(args, camera, frames, results), frames)
    save_installation(inst, args.out)
    rep = _report(inst, results, args.out)
    rep.update(uncertainty_report(inst))
    rep.update(override_record([args.header_check]))
    print_overrides("calibrate install", rep)
    if args.json:
        emit_json(rep)
    else:
        _print_text(rep)
        print_uncertainty(rep)
    if rep["failures"] or rep["n_rejected"]:
        parts = []
        if rep["failures"]:
            parts.append(f"{len(rep['failures'])} of {len(results)} frames failed "
                         f"(first: {rep['failures'][0]['frame']}: {rep['failures'][0]['reason']})")
        if rep["n_rejected"]:
            parts.append(f"{rep['n_rejected']} of {len(results)} frames rejected as inconsistent with the others "
                         f"(outliers of the mean installation)")
        print(f"shipstar calibrate install: {'; '.join(parts)}; {rep['out']} written from the "
              f"{rep['n_used']} frames used", file=sys.stderr)
        return 1
    return 0

