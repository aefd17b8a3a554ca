"""``shipstar calibrate install --at-sea``: a sensor's installation re-estimated from at-sea
frames relative to the reference sensor (issue 14 item 3; pipeline/_recalibrate.py).

``calibrate install`` (cli/_calibrate_install.py) hands its arguments to
:func:`parse_at_sea` when they contain ``--at-sea``: the mode takes what ``measure`` takes
(both sensors' frame directories, both installation files, the track and the weather)
instead of the dock's theodolite heading and levels.
"""

from __future__ import annotations

import argparse

from shipstar.cli._common import (
    add_date_obs_is_argument,
    add_refraction_arguments,
    add_site_arguments,
    add_weather_arguments,
    check_output_file,
    check_folders_apart,
    check_outputs_apart,
    emit_json,
)

__all__ = ["AT_SEA_FLAG", "at_sea_parser", "run_at_sea"]

AT_SEA_FLAG = "--at-sea"

EPILOG = """\
example (A2's installation drifted; A1 is the reference):
  shipstar calibrate install --at-sea --sensor A2 --frames A1=sea/A1 --frames A2=sea/A2 \\
      --install A1.install.toml A2.install.toml --track sea/track.csv --weather sea/weather.csv \\
      --out A2.atsea.install.toml --json

Both sensors' frames are measured as 'shipstar measure' does; at every epoch where both
solved, the disagreement of their deck attitudes gives the rotation of --sensor's mount
relative to the reference mount beyond the installation files (pipeline._mounts: its
static part, with the wave-period flexure and the clock offset estimated beside it).
That rotation is applied to --sensor's installation matrix
(C_deck_from_sensor = Exp([s]x) C_deck_from_sensor_file) and the new file is written
with its uncertainty (sem: the at-sea estimate; total: with the reference sensor's own
installation uncertainty, carried over) and its provenance (at_sea = true and an
[at_sea_calibration] table: reference sensor, time span, the rotation and its sigma,
the clock offset, the file it replaces).  Needs >= 12 epochs with both solved; a minute
at sea gives ~0.3'' per axis (the ship's roll and pitch separate the static part from
the wave-period flexure).  The session is held in memory: give minutes, not hours.
Exit codes: 0 written; 2 bad input or no estimate.
"""


def at_sea_parser(prog: str, parser_class=argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The ``--at-sea`` mode's parser."""
    from shipstar.cli._cmd_measure import SITE_HELPS, WEATHER_HELPS, _name_value
    from shipstar.cli._header_checks import add_trust_flags_argument
    from shipstar.cli._model_inputs import add_model_input_arguments

    p = parser_class(prog=prog, description="Re-estimate a star sensor's installation relative to the reference "
                                            "sensor from at-sea frames (no dock session needed).",
                     epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument(AT_SEA_FLAG, dest="at_sea", action="store_true", required=True,
                   help=argparse.SUPPRESS)                # in prog: "shipstar calibrate install --at-sea"
    p.add_argument("--sensor", required=True, metavar="NAME", help="the sensor to recalibrate, e.g. A2")
    p.add_argument("--frames", required=True, action="append", type=_name_value, metavar="NAME=DIR",
                   help="a sensor and its frames directory (the sensor and the reference; repeat)")
    p.add_argument("--install", required=True, action="extend", nargs="+", metavar="FILE",
                   help="installation TOML files, one per sensor")
    p.add_argument("--camera", action="append", type=_name_value, default=[], metavar="NAME=FILE",
                   help="camera preset or TOML file of a sensor (default: the installation's camera preset)")
    p.add_argument("--reference", metavar="NAME", help="reference sensor (default: the first --frames other "
                                                       "than --sensor)")
    g = p.add_argument_group("ship position (fixed, or a track)")
    add_site_arguments(g, SITE_HELPS, deflection_default=None)
    g.add_argument("--track", metavar="CSV", help="time_utc, lat_deg, lon_deg[, height_m][, xi_arcsec, eta_arcsec]")
    w = p.add_argument_group("weather (fixed, or a table)")
    add_weather_arguments(w, WEATHER_HELPS)
    w.add_argument("--weather", metavar="CSV", help="time_utc, pressure_hpa, temperature_c[, relative_humidity]")
    add_model_input_arguments(p, dock=False)
    o = p.add_argument_group("processing")
    add_refraction_arguments(o, "refraction model (default erfa; almanac = the seeds')",
                             "per-star refraction (default) or the seed's boresight-only correction")
    add_date_obs_is_argument(o)
    add_trust_flags_argument(o)
    p.add_argument("--session", metavar="LABEL", help="session label recorded in the file (default: the frame dirs)")
    p.add_argument("--out", required=True, metavar="FILE.toml", help="installation file to write")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(run=run_at_sea)
    return p


def _order(args) -> list:
    """``args.frames`` with the reference first (measure's ``--reference`` default)."""
    from shipstar.errors import ShipstarError

    names = [n for n, _ in args.frames]
    if len(names) < 2:
        raise ShipstarError("--at-sea needs the frames of two sensors: --frames REF=DIR --frames NAME=DIR")
    if args.sensor not in names:
        raise ShipstarError(f"--sensor {args.sensor} has no --frames {args.sensor}=DIR")
    ref = args.reference or next(n for n in names if n != args.sensor)
    if ref not in names:
        raise ShipstarError(f"--reference {ref} has no --frames {ref}=DIR")
    if ref == args.sensor:
        raise ShipstarError(f"--reference and --sensor are both {ref}: recalibrate a sensor against another one")
    return sorted(args.frames, key=lambda nv: nv[0] != ref)


def run_at_sea(args) -> int:
    from shipstar.calibrate.installation import save_installation
    from shipstar.cli._cmd_measure import _configs, _site_and_weather
    from shipstar.cli._header_checks import header_check
    from shipstar.pipeline import PipelineOptions, process_session, scan_frames
    from shipstar.pipeline._recalibrate import at_sea_installation

    check_output_file(args.out, "--out")
    check_outputs_apart(args, [("--out", args.out, None)])
    check_folders_apart(args)
    args.sensor_to_calibrate = args.sensor
    args.sensor = _order(args)                       # measure's helpers read (name, dir) pairs
    track, weather = _site_and_weather(args)
    configs = _configs(args)
    frames = []
    for config, (name, directory) in zip(configs, args.sensor):
        check = header_check(args, names=(name, config.camera.name), camera=config.camera, track=track,
                             weather=weather, given_name=f"--frames {name}={directory} (camera {config.camera.name})",
                             position_flags=not args.track, weather_flags=not args.weather, sensor=name,
                             known_cameras=[c.camera.name for c in configs])
        frames.append(scan_frames(directory, date_obs_is=args.date_obs_is, check=check))
    options = PipelineOptions(refraction_model=args.refraction, refraction=args.refraction_mode)
    result = process_session(configs, frames, track, weather, options, reference=args.sensor[0][0])
    target = args.sensor_to_calibrate
    previous = next(p for p in args.install if _sensor_of(p) == target)
    inst, rep = at_sea_installation(result, configs, target, previous_installation=str(previous),
                                    session=args.session or " ".join(d for _, d in args.sensor))
    save_installation(inst, args.out)
    rep["out"] = str(args.out)
    if args.json:
        emit_json(rep)
    else:
        _print_text(rep)
    return 0


def _sensor_of(path) -> str:
    from shipstar.calibrate.installation import load_installation

    return load_installation(path).sensor


def _print_text(rep: dict) -> None:
    c, s, t = rep["change_arcsec"], rep["sem_arcsec"], rep["total_arcsec"]
    r, rs = rep["rotation_arcsec"], rep["rotation_sigma_arcsec"]
    print(f"sensor {rep['sensor']} relative to {rep['reference_sensor']}: {rep['n_epochs']} epochs "
          f"({rep['start_utc']} .. {rep['end_utc']})")
    print("  mount rotation beyond the installation file: " + ", ".join(
        f"{a} {r[a]:+.2f} +- {rs[a]:.2f}''" for a in ("bow", "up", "starboard")))
    for k, name in (("az", "azimuth"), ("el", "elevation"), ("roll", "roll")):
        print(f"  {name:9s} {rep[k + '_deg']:14.7f} deg   change {c[k]:+8.2f}''   sem {s[k]:6.2f}''   "
              f"total {t[k]:6.2f}''")
    off = rep["time_offset_s"]
    if off.get("offset_s") is not None:
        print(f"  clock offset {off['offset_s'] * 1e3:+.3f} +- {off['sigma_s'] * 1e3:.3f} ms "
              f"({'applied' if off['applied'] else 'not significant'})")
    for w in rep["warnings"]:
        print(f"  note: {w}")
    print(f"written: {rep['out']}")
