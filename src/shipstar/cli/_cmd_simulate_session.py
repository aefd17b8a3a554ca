"""``shipstar simulate-session``: write a simulated dock or at-sea session (FITS frames + truth)."""

from __future__ import annotations

import argparse

from shipstar.cli._common import emit_json, finite_float, positive_float, rng_seed
from shipstar.errors import ShipstarError

__all__ = ["register", "run"]

EPILOG = """\
examples:
  shipstar simulate-session --kind dock --out dock --duration-s 2
  shipstar simulate-session --kind sea --out sea --duration-s 16 --offset-ms 30 --json
  shipstar simulate-session --kind sea --out real --duration-s 16 --conditions realistic

dock: seed 000's calibration night (Jiangyin 31.9 N 120.3 E, 2013-03-15 12:16 UTC, heading
46 deg 28' 28.51'', level, 11.10 C, 1021.70 hPa; A1 and A2 at seed 000 Tables 2-3).
sea:  the same ship rolling 5 deg / 8 s, pitching 2 deg / 6 s, heading drifting, 8 m/s.
Writes OUT/A1/*.fits and OUT/A2/*.fits (FITS 4.0 times with microseconds: DATE-OBS =
DATE-BEG = start of the exposure, DATE-AVG = mid-exposure, DATE-END, EXPTIME; each with a
.truth.json), OUT/truth.csv, OUT/track.csv, OUT/weather.csv and, last, OUT/session.toml
(docs/file-formats.md); a directory without session.toml is incomplete.  Stars are
rendered along their true paths during the exposure.  Each frame is ~2 MB (1024 x 1024
uint16) and takes ~25 ms to render and write.  Everything is checked before OUT is created: the
frame period must not be shorter than the exposure, --offset-ms is within +-1000 ms, and
a session larger than --max-output-gb (default 20) or than the free disk space is refused.
"""


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "simulate-session", help="write a simulated dock or at-sea session (FITS frames and truth)",
        description="Render a whole simulated session of the seeds' two-sensor ship, in dock or at sea, "
                    "as FITS frames (DATE-OBS = start, DATE-AVG = mid-exposure) plus truth, track and weather files.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--kind", required=True, choices=("dock", "sea"), help="dock calibration or at-sea session")
    p.add_argument("--out", required=True, metavar="DIR", help="new (or empty) directory to write")
    p.add_argument("--duration-s", type=positive_float, default=16.0, help="session length (s, default 16)")
    p.add_argument("--frame-rate-hz", type=positive_float, default=10.0, help="frames per second per sensor (default 10)")
    p.add_argument("--sensors", default="A1,A2", help="comma-separated subset of A1,A2 (default both)")
    p.add_argument("--offset-ms", type=finite_float, default=0.0,
                   help="A2's exposures this much later than A1's (ms, within +-1000, default 0)")
    p.add_argument("--mag-limit", type=finite_float, default=8.0, help="faintest Hp magnitude (default 8)")
    p.add_argument("--seed", type=rng_seed, default=0, help="noise seed (default 0)")
    p.add_argument("--conditions", metavar="FILE.toml",
                   help="simulate a real night (cloud, Moon, twilight, seeing, hot pixels, cosmic rays, trails, "
                        "hidden clock offsets, hull flexure, lens distortion): a conditions file or a shipped "
                        "example's name (realistic, cloud, moon, twilight, seeing, hot_pixels, trails, clock, "
                        "flexure, distortion); docs/simulation.md")
    p.add_argument("--ins-log", action="store_true",
                   help="also write the ship's inertial navigator's log: OUT/ins.csv, OUT/ins.nmea (50 Hz) and its "
                        "true errors OUT/ins_truth.json (docs/simulation.md)")
    p.add_argument("--ins-errors", default="", metavar="NAME=VALUE,...",
                   help="the INS's errors, e.g. heading_bias_arcsec=30,heading_drift_arcsec_per_h=36,"
                        "time_offset_s=0.02,misalignment_arcsec=10/-5/3 (defaults: issue 15's)")
    p.add_argument("--ins-convention", default="", metavar="SIGNS",
                   help="signs of the INS files, e.g. roll=starboard-up,pitch=bow-down (default shipstar's)")
    p.add_argument("--max-output-gb", type=positive_float, default=20.0,
                   help="refuse a session estimated to write more than this (GB, default 20)")
    p.add_argument("--progress", action="store_true", help="progress bar on stderr (default: only on a terminal)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    from shipstar.cli._model_inputs import add_eop_argument

    add_eop_argument(p)
    p.set_defaults(run=run)
    return p


def _spec(args):
    from dataclasses import replace

    from shipstar.simulate._session import MAX_TIME_OFFSET_S, dock_session, sea_session

    base = dock_session() if args.kind == "dock" else sea_session()
    wanted = [s.strip() for s in args.sensors.split(",") if s.strip()]
    known = {s.name: s for s in base.sensors}
    bad = [w for w in wanted if w not in known]
    if bad or not wanted or len(set(wanted)) != len(wanted):
        raise ShipstarError(f"--sensors must be a comma-separated subset of {', '.join(known)}, got {args.sensors!r}")
    if abs(args.offset_ms) > 1000.0 * MAX_TIME_OFFSET_S:
        raise ShipstarError(f"--offset-ms must be within +-{1000.0 * MAX_TIME_OFFSET_S:g} ms (a clock offset "
                            f"between the sensors), got {args.offset_ms:g}")
    sensors = tuple(replace(known[w], time_offset_s=args.offset_ms / 1000.0) if w == "A2" else known[w]
                    for w in wanted)
    if args.duration_s * args.frame_rate_hz > 100000:
        raise ShipstarError(f"{args.duration_s * args.frame_rate_hz:.0f} frames per sensor is too many (at most 100000)")
    try:
        return base.replace(sensors=sensors, duration_s=args.duration_s, frame_rate_hz=args.frame_rate_hz,
                            mag_limit=args.mag_limit, seed=args.seed)
    except ShipstarError as exc:
        text = str(exc).replace("frame period", "--frame-rate-hz: frame period", 1)
        raise ShipstarError(text) from None


def _check_out(path) -> None:
    from pathlib import Path

    out = Path(path)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ShipstarError(f"--out {out} exists and is not an empty directory")


def run(args) -> int:
    from shipstar.pipeline._progress import ProgressBar
    from shipstar.simulate._session import write_session

    spec = _spec(args)
    if getattr(args, "conditions", None):
        from shipstar.simulate._conditions import apply_conditions, load_conditions

        spec = apply_conditions(spec, load_conditions(args.conditions))
    if not getattr(args, "ins_log", False) and (getattr(args, "ins_errors", "") or getattr(args, "ins_convention", "")):
        raise ShipstarError("--ins-errors and --ins-convention describe the INS log: give --ins-log")
    if getattr(args, "ins_log", False):
        from shipstar.frames import AttitudeConvention
        from shipstar.simulate._ins import parse_ins_errors

        ins_errors = parse_ins_errors(args.ins_errors)           # refused before anything is written
        AttitudeConvention(args.ins_convention)
    _check_out(args.out)
    bar = ProgressBar(True if args.progress else None)
    try:
        files = write_session(spec, args.out, progress=lambda done, total: bar("frames", done, total),
                              max_output_bytes=int(args.max_output_gb * 1e9))
    finally:
        bar.close()
    if getattr(args, "ins_log", False):
        from shipstar.simulate._ins import simulate_ins, write_ins_files

        files.update(write_ins_files(spec, simulate_ins(spec, ins_errors), args.out, convention=args.ins_convention))
    report = {"kind": spec.kind, "out": str(args.out), "session": str(files["session"]),
              "exposure_s": {s.name: spec.exposure_of(s) for s in spec.sensors},
              "truth": str(files["truth"]), "track": str(files["track"]), "weather": str(files["weather"]),
              **({"conditions": str(files["conditions"])} if "conditions" in files else {}),
              **{k: str(files[k]) for k in ("ins_csv", "ins_nmea", "ins_truth") if k in files},
              "frames": {name: len(paths) for name, paths in files["frames"].items()},
              "frames_dirs": {name: str(paths[0].parent) for name, paths in files["frames"].items() if paths}}
    if args.json:
        emit_json(report)
    else:
        counts = ", ".join(f"{n} {c} frames" for n, c in report["frames"].items())
        print(f"{spec.kind} session written to {args.out}: {counts}; truth {report['truth']}")
    return 0
