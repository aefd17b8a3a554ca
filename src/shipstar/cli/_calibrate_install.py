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
    emit_json,
    finite_float,
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
Exit codes: 0 every frame solved; 1 written, but some frames failed (listed); 2 bad input.
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
    p.add_argument("--heading-deg", required=True, type=finite_float, help="true ship heading K0 (deg)")
    p.add_argument("--pitch-deg", type=finite_float, default=0.0, help="ship pitch psi0 from the levels (deg)")
    p.add_argument("--roll-deg", type=finite_float, default=0.0, help="ship roll theta0 from the levels (deg)")
    add_weather_arguments(p, WEATHER_HELPS, required=True)
    add_refraction_arguments(p, "refraction model (default erfa; almanac = the seeds' model)",
                             "per-star refraction (default) or the seed's ref. [9] boresight-only correction")
    add_date_obs_is_argument(p)
    p.add_argument("--session", metavar="LABEL", help="session label recorded in the file (default: DIR)")
    p.add_argument("--out", required=True, metavar="FILE.toml", help="installation file to write")
    p.add_argument("--progress", action="store_true", help="progress bar on stderr (default: only on a terminal)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(run=run_install)
    return p


def _process(args, camera):
    from shipstar.pipeline import PipelineOptions, SensorConfig, Track, WeatherTable, process_sensor, scan_frames
    from shipstar.pipeline._frames import check_sensor_name
    from shipstar.pipeline._progress import ProgressBar

    frames = scan_frames(args.frames, date_obs_is=args.date_obs_is)
    check_sensor_name(frames, args.sensor, camera.name, args.frames)
    track = Track.fixed(args.lat_deg, args.lon_deg, args.height_m, args.xi_arcsec, args.eta_arcsec)
    weather = WeatherTable.constant(args.pressure_hpa, args.temperature_c, args.relative_humidity)
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
    return calibrate_installation(
        C_hs, dock.C_hor_from_deck, solved=[r.solved for r in results], sensor=args.sensor, camera=camera.name,
        reasons=[r.reason for r in results], session=args.session or str(args.frames),
        date_utc=frames[0].utc_iso, dock=dock, warnings=tuple(accuracy_warnings(args)))


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
    camera = load_camera(args.camera)
    frames, results = _process(args, camera)
    inst = _calibrate(args, camera, frames, results)
    save_installation(inst, args.out)
    rep = _report(inst, results, args.out)
    if args.json:
        emit_json(rep)
    else:
        _print_text(rep)
    if rep["failures"]:
        print(f"shipstar calibrate install: {len(rep['failures'])} of {len(results)} frames failed "
              f"(first: {rep['failures'][0]['frame']}: {rep['failures'][0]['reason']})", file=sys.stderr)
        return 1
    return 0

