"""``shipstar live``: ship attitude from frames as they arrive, out to the ship's systems."""

from __future__ import annotations

import argparse
import sys

from shipstar.cli._cmd_measure import SITE_HELPS, WEATHER_HELPS, _name_value, _non_negative
from shipstar.cli._common import (
    add_date_obs_is_argument,
    add_refraction_arguments,
    add_site_arguments,
    add_windowed_argument,
    add_weather_arguments,
    check_output_file,
    check_folders_apart,
    check_outputs_apart,
    emit_json,
    float_in_range,
    int_in_range,
)
from shipstar.cli._header_checks import add_trust_flags_argument, header_check
from shipstar.errors import ShipstarError

__all__ = ["register", "run"]

EPILOG = """\
examples:
  shipstar replay sea --to incoming                     # in one terminal (a recorded session)
  shipstar live --sensor A1=incoming/A1 --sensor A2=incoming/A2 \\
      --install A1.install.toml A2.install.toml \\
      --track incoming/track.csv --weather incoming/weather.csv \\
      --out live.csv --udp 127.0.0.1:10110 --format nmea       # in the other
  shipstar live --sensor A1=/data/A1 --install A1.install.toml --nav-udp 10111 \\
      --udp 192.168.1.20:5005 --format jsonl --stop-after-s 36000 --json

The same engine as 'shipstar measure', on frames as they appear: each --sensor NAME=DIR
is watched (file events); a frame counts when it appears under its final FITS name
(.fits, .fit, .fts, optionally .gz) complete: renamed into place, or written in place
and closed.  Hidden (dot) files and other names are ignored, and so are the frames
already there when live starts.  Same --install, --camera, --refraction, --date-obs-is,
--reference and processing options as measure.

Position, time and weather: fixed flags (--lat-deg ..., --pressure-hpa ...), CSV files
that may keep growing (--track, --weather: read as they grow), or NMEA 0183 over UDP
(--nav-udp [HOST:]PORT; GGA or RMC for position, ZDA for the date, MDA or XDR for
pressure and temperature; HOST defaults to 0.0.0.0, every interface).  A frame more
than 5 s after the last position (or 600 s after the last weather) is unsolved, with
that reason.

Outputs, all at once if asked: --out CSV (measure's attitude CSV, written as OUT.partial
while live, an epoch's rows together, flushed as they come; renamed to OUT at the
stop); --udp HOST:PORT (repeatable) with --format jsonl (one JSON object per attitude
row, keys exactly the CSV's columns, numbers as numbers, empty as null) or nmea (one
datagram per epoch: $PSSTA at full precision, $HEHDT, $PASHR; the attitude of --method
joint, seed-rule or single); docs/file-formats.md.  Every second a status line on
stderr and a status message on UDP ({"kind": "status", ...} or $PSSTS): frames in and
out per sensor, lag, unsolved reasons, latency, Earth orientation quality.  --http
[HOST:]PORT serves the read-only operator console, a web page updated 2.5 times a second
(HOST default 127.0.0.1; docs/live.md, Operator console).

A sensor that falls behind skips to its newest frames (each skipped frame an unsolved
row, reason 'skipped (behind)'); a sensor whose frames stop is fused without until it
delivers again.  Runs until SIGINT / SIGTERM (or --stop-after-s), then finishes the
frames under way, closes its files complete and prints the summary (--json: measure's,
with the latency and live counts).  Exit codes: 0 stopped cleanly; 2 bad input.
"""


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "live", help="ship attitude from frames as they arrive, out as CSV, JSON lines or NMEA over UDP",
        description="Run the measurement live: watch each sensor's directory, solve each frame as it "
                    "appears, fuse the sensors and send the attitude out as it is measured.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sensor", required=True, action="append", type=_name_value, metavar="NAME=DIR",
                   help="a sensor and the directory its frames appear in (repeat for each sensor)")
    p.add_argument("--install", required=True, action="extend", nargs="+", metavar="FILE",
                   help="installation TOML files, one per sensor")
    p.add_argument("--camera", action="append", type=_name_value, default=[], metavar="NAME=FILE",
                   help="camera preset or TOML file of a sensor (default: the installation's camera preset)")
    g = p.add_argument_group("ship position (fixed, a growing track, or NMEA over UDP)")
    add_site_arguments(g, SITE_HELPS, deflection_default=None)
    g.add_argument("--track", metavar="CSV", help="time_utc, lat_deg, lon_deg[, height_m][, xi_arcsec, eta_arcsec]; "
                                                 "read as it grows")
    g.add_argument("--nav-udp", metavar="[HOST:]PORT",
                   help="NMEA 0183 over UDP: GGA/RMC position, ZDA date, MDA/XDR weather (HOST default 0.0.0.0)")
    w = p.add_argument_group("weather (fixed, a growing table, or from --nav-udp)")
    add_weather_arguments(w, WEATHER_HELPS, humidity_default=None)
    w.add_argument("--weather", metavar="CSV", help="time_utc, pressure_hpa, temperature_c[, relative_humidity]; "
                                                   "read as it grows")
    o = p.add_argument_group("processing")
    add_refraction_arguments(o, "refraction model (default erfa; almanac = the seeds')",
                             "per-star (default) or the seed's boresight-only refraction")
    add_date_obs_is_argument(o)
    add_trust_flags_argument(o)
    o.add_argument("--reference", metavar="NAME", help="sensor whose frame times are the epochs (default first)")
    o.add_argument("--max-pair-offset-s", type=_non_negative, default=0.06,
                   help="largest time offset of paired frames (s, default 0.06)")
    o.add_argument("--no-motion-compensation", action="store_true", help="do not carry paired frames (comparison)")
    o.add_argument("--no-streak-correction", action="store_true", help="no exposure-motion correction (comparison)")
    add_windowed_argument(o)
    o.add_argument("--stale-s", type=float_in_range(0.1, 3600.0), default=2.0,
                   help="a sensor without frames this long is fused without (s, default 2)")
    r = p.add_argument_group("output")
    r.add_argument("--out", metavar="CSV", help="attitude CSV (OUT.partial while live, OUT at the stop)")
    r.add_argument("--udp", action="append", default=[], metavar="HOST:PORT", help="send to this address (repeatable)")
    r.add_argument("--format", choices=("jsonl", "nmea"), default="jsonl", help="UDP format (default jsonl)")
    r.add_argument("--method", choices=("joint", "seed-rule", "single"), default="joint",
                   help="the attitude the NMEA sentences carry (default joint; single: the reference sensor)")
    r.add_argument("--stop-after-s", type=float_in_range(0.0, None, "> 0"), metavar="S",
                   help="stop after this many seconds (default: at SIGINT / SIGTERM)")
    r.add_argument("--http", metavar="[HOST:]PORT",
                   help="serve the read-only operator console (web page) here; HOST default 127.0.0.1 "
                        "(docs/live.md, Operator console)")
    r.add_argument("--ins-udp", metavar="[HOST:]PORT",
                   help="the ship's INS as NMEA 0183 over UDP ($--ZDA, $PASHR, $--HDT, $PSXN,23; HOST default "
                        "0.0.0.0): corrected by the stars as they come and sent on --udp at the INS's rate "
                        "(method stars+ins; docs/live.md)")
    r.add_argument("--ins-convention", default="", metavar="SIGNS",
                   help="the INS's signs, e.g. roll=starboard-up,pitch=bow-down (default shipstar's; "
                        "docs/conventions.md)")
    r.add_argument("--quiet", action="store_true", help="no status line on stderr")
    r.add_argument("--json", action="store_true", help="print the summary as one JSON object at the stop")
    r.add_argument("--max-waiting", type=int_in_range(1, 100), default=2, help=argparse.SUPPRESS)
    from shipstar.cli._model_inputs import add_eop_argument

    add_eop_argument(p)
    p.set_defaults(run=run)
    return p


class _Deflected:
    """A live track with a fixed deflection of the vertical (NMEA carries none)."""

    def __init__(self, track, xi_arcsec: float, eta_arcsec: float):
        from shipstar.units import ASEC2RAD

        self.track, self.xi_rad, self.eta_rad = track, xi_arcsec * ASEC2RAD, eta_arcsec * ASEC2RAD

    def site(self, utc_jd1, utc_jd2):
        from dataclasses import replace

        return replace(self.track.site(utc_jd1, utc_jd2), xi_rad=self.xi_rad, eta_rad=self.eta_rad)

    def check_covers(self, utc_jd1, utc_jd2) -> None:
        self.track.check_covers(utc_jd1, utc_jd2)


def _position_and_weather(args, report):
    """``(track, weather, tails, nav receiver or None)``."""
    from shipstar.live._nav import CsvTail, LiveTrack, LiveWeather, NavReceiver
    from shipstar.live._outputs import parse_host_port
    from shipstar.pipeline import Track, WeatherTable

    fixed_site = args.lat_deg is not None or args.lon_deg is not None
    given = [k for k, v in (("--track", args.track), ("--nav-udp", args.nav_udp), ("--lat-deg/--lon-deg", fixed_site))
             if v]
    if len(given) > 1:
        raise ShipstarError(f"give one position source, not {' and '.join(given)}")
    if not given:
        raise ShipstarError("give the ship's position: --lat-deg and --lon-deg, --track CSV or --nav-udp PORT")
    if args.track and (args.xi_arcsec is not None or args.eta_arcsec is not None):
        raise ShipstarError("with --track the deflection of the vertical goes into its xi_arcsec and eta_arcsec "
                            "columns, not --xi-arcsec/--eta-arcsec")
    tails, nav = [], None
    nav_track, nav_weather = LiveTrack(name="NMEA position"), LiveWeather(name="NMEA weather")
    if args.nav_udp:
        host, port = parse_host_port(args.nav_udp, default_host="0.0.0.0")
        nav = NavReceiver(nav_track, nav_weather, host=host, port=port, on_error=report)
    if args.track:
        track = LiveTrack(name=f"track {args.track}")
        tails.append(CsvTail(args.track, track, on_error=report))
    elif args.nav_udp:
        track = _Deflected(nav_track, args.xi_arcsec or 0.0, args.eta_arcsec or 0.0)
    else:
        if args.lat_deg is None or args.lon_deg is None:
            raise ShipstarError("give both --lat-deg and --lon-deg")
        track = Track.fixed(args.lat_deg, args.lon_deg, args.height_m, args.xi_arcsec or 0.0, args.eta_arcsec or 0.0)
    fixed = [args.pressure_hpa, args.temperature_c]
    if args.weather and any(v is not None for v in fixed):
        raise ShipstarError("give either --weather or --pressure-hpa/--temperature-c, not both")
    if args.weather and args.relative_humidity is not None:
        raise ShipstarError("--relative-humidity goes with --pressure-hpa/--temperature-c: the --weather table "
                            "gives its own (column relative_humidity, 0 without it)")
    if args.weather:
        weather = LiveWeather(name=f"weather table {args.weather}")
        tails.append(CsvTail(args.weather, weather, on_error=report))
    elif all(v is not None for v in fixed):
        weather = WeatherTable.constant(args.pressure_hpa, args.temperature_c, args.relative_humidity or 0.0)
    elif any(v is not None for v in fixed):
        raise ShipstarError("give both --pressure-hpa and --temperature-c")
    elif args.nav_udp:
        weather = nav_weather
    else:
        raise ShipstarError("give the weather: --pressure-hpa and --temperature-c, --weather CSV, or --nav-udp "
                            "(MDA or XDR)")
    return track, weather, tuple(tails), nav


def _settings(args, report):
    from pathlib import Path

    from shipstar.camera import load_camera
    from shipstar.cli._cmd_measure import _installations, _refraction_mismatch
    from shipstar.live._outputs import parse_host_port, resolve_udp_destination
    from shipstar.live._run import LiveSettings
    from shipstar.pipeline import PipelineOptions, SensorConfig

    installs = _installations(args)
    cams = dict(args.camera)
    unknown = sorted(set(cams) - {n for n, _ in args.sensor})
    if unknown:
        raise ShipstarError(f"--camera for unknown sensor {unknown[0]!r}")
    configs, dirs = [], []
    for name, directory in args.sensor:
        d = Path(directory)
        if d.exists() and not d.is_dir():
            raise ShipstarError(f"--sensor {name}={directory}: not a directory")
        configs.append(SensorConfig(name, load_camera(cams.get(name, installs[name].camera)), installs[name]))
        dirs.append(d)
    names = [c.name for c in configs]
    if args.reference is not None and args.reference not in names:
        raise ShipstarError(f"reference sensor {args.reference!r} is not one of {', '.join(names)}")
    if not (args.out or args.udp or args.http):
        raise ShipstarError("give an output: --out CSV, --udp HOST:PORT and/or --http [HOST:]PORT")
    from shipstar.live._http import parse_http_address

    http = parse_http_address(args.http) if args.http else None
    udp = tuple(resolve_udp_destination(*parse_host_port(u)) for u in args.udp)
    check_folders_apart(args)
    out = None
    if args.out:
        out = check_output_file(args.out, "--out")
        check_outputs_apart(args, [("--out", args.out, None)])
        partial = out.with_name(out.name + ".partial")
        if partial.exists():
            raise ShipstarError(f"{partial} is left from an earlier live run that did not stop cleanly: move or "
                                f"delete it first")
    for message in _refraction_mismatch({c.name: c.installation for c in configs}, args.refraction,
                                        args.refraction_mode):
        report(f"warning: {message}")
    track, weather, tails, nav = _position_and_weather(args, report)
    options = PipelineOptions(refraction_model=args.refraction, refraction=args.refraction_mode,
                              max_pair_offset_s=args.max_pair_offset_s,
                              compensate_motion=not args.no_motion_compensation,
                              streak_correction=not args.no_streak_correction,
                              windowed_full_frame_every=args.windowed_full_frame_every)
    return LiveSettings(tuple(configs), tuple(dirs), options, names.index(args.reference) if args.reference else 0,
                        args.date_obs_is, track, weather, tails, nav, out, udp, args.format, args.method,
                        args.stop_after_s, stale_s=args.stale_s, max_waiting=args.max_waiting, http=http,
                        ins=_ins_receiver(args, report),
                        status_stream=None if args.quiet else sys.stderr,
                        header_checks=tuple(
                            header_check(args, names=(c.name, c.camera.name), camera=c.camera, track=track,
                                         weather=weather, sensor=c.name,
                                         known_cameras=[k.camera.name for k in configs],
                                         given_name=f"--sensor {c.name}={d} (camera {c.camera.name})",
                                         position_flags=not (args.track or args.nav_udp),
                                         weather_flags=args.pressure_hpa is not None and not args.weather)
                            for c, d in zip(configs, dirs)))


def _ins_receiver(args, report):
    """``--ins-udp``: the INS receiver and forward filter (shipstar.live._ins_live), or None."""
    if not getattr(args, "ins_udp", None):
        return None
    import time

    from shipstar.live._ins_live import LiveIns
    from shipstar.live._outputs import parse_host_port
    from shipstar.sky.time import utc_jd_from_iso

    host, port = parse_host_port(args.ins_udp, default_host="0.0.0.0")
    now = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime())
    return LiveIns(host, port, args.ins_convention, origin_utc_jd=utc_jd_from_iso(now), on_error=report)


def _f(x, digits: int = 2) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def _print_text(summary: dict) -> None:
    for name, s in summary["sensors"].items():
        print(f"sensor {name}: {s.get('n_solved', 0)} of {s.get('n_frames', 0)} frames solved "
              f"({s.get('skipped_behind', 0)} skipped behind, {s.get('n_unreadable', 0)} unreadable)")
    for m, b in summary["methods"].items():
        sig = "/".join(_f(v) for v in b["median_sigma_arcsec"])
        print(f"{m:15s} {b['n_solved']:6d}/{b['n']:<6d} median sigma heading/pitch/roll {sig}''")
    i = summary.get("integrity")
    if i is not None:
        print(f"integrity: {i['n_inconsistent']} of {i['n_checked']} epochs inconsistent"
              + "".join(f"; {k} does not fit in {v}" for k, v in i["suspects"].items()))
    lat = summary["latency"]
    print(f"latency (frame appears -> row out): median {_f(lat['median_ms'], 1)} ms, p99 {_f(lat['p99_ms'], 1)} ms "
          f"over {lat['n']} rows")
    print(f"stopped: {summary['stopped'] or 'end'}; written: {summary['out'] or '-'}")


def run(args) -> int:
    from shipstar._signals import StopOnSignals
    from shipstar.live._run import run_live

    def report(text):
        print(f"shipstar live: {' '.join(str(text).split())}", file=sys.stderr, flush=True)

    settings = _settings(args, report)
    if settings.ins is not None:
        settings.ins.start()                # a port in use: one line, before anything starts
    if settings.nav is not None:
        settings.nav.start()                # a port in use: one line, before anything starts
    try:
        with StopOnSignals() as stop:
            outcome = run_live(settings, stop)
    finally:
        if settings.nav is not None:
            settings.nav.stop()
        if settings.ins is not None:
            settings.ins.stop()
    if args.out and outcome.summary.get("out") is None:
        report(f"no frame arrived before the stop ({outcome.summary.get('stopped') or 'end'}): "
               f"nothing written to {args.out}")
    if args.json:
        emit_json(outcome.summary)
    else:
        _print_text(outcome.summary)
    return 0
