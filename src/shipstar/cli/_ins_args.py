"""``measure --ins``: the INS calibrated against the stars (pipeline._ins, docs/pipeline.md *INS*)."""

from __future__ import annotations

import sys

from shipstar.errors import ShipstarError

__all__ = ["add_ins_arguments", "ins_observer", "finish_ins"]


def add_ins_arguments(p) -> None:
    from shipstar.cli._common import float_in_range

    g = p.add_argument_group("inertial navigator (INS): its errors estimated from the stars, outages bridged")
    g.add_argument("--ins", metavar="FILE",
                   help="the INS's attitude log: CSV (time_utc, heading_deg, pitch_deg, roll_deg[, rates]) or NMEA "
                        "0183 ($--ZDA, $PASHR, $--HDT, $PSXN,23); its clock may be offset (estimated)")
    g.add_argument("--ins-convention", default="", metavar="SIGNS",
                   help="the log's signs, e.g. roll=starboard-up,pitch=bow-down (default shipstar's: "
                        "roll=port-up,pitch=bow-up,heading=true; docs/conventions.md)")
    g.add_argument("--ins-out", metavar="CSV",
                   help="the corrected attitude at each INS record (time_utc, heading_deg, pitch_deg, roll_deg, "
                        "sigmas, source stars+ins or ins-bridged)")
    g.add_argument("--ins-noise-arcsec", type=float_in_range(0.0, 3600.0), default=None, metavar="X",
                   help="white noise of an INS reading (arcsec, default 0.5)")
    g.add_argument("--ins-heading-random-walk-arcsec-per-sqrt-h", type=float_in_range(0.0, 3600.0), default=None,
                   metavar="X", help="random walk of the INS's heading error (default 3.6)")
    g.add_argument("--ins-level-random-walk-arcsec-per-sqrt-h", type=float_in_range(0.0, 3600.0), default=None,
                   metavar="X", help="random walk of its pitch and roll errors (default 1)")
    g.add_argument("--ins-quantisation-deg", type=float_in_range(0.0, 1.0), default=None, metavar="X",
                   help="resolution of its readings (deg, default 1e-5; 0.01 for 2-decimal NMEA)")
    g.add_argument("--ins-no-misalignment", action="store_true",
                   help="fold the INS-to-deck misalignment into the biases (do not estimate it)")


def ins_observer(args):
    """The star rows' collector when ``--ins`` is given (checked before any work), else None."""
    from shipstar.cli._common import check_output_file

    if not getattr(args, "ins", None):
        if getattr(args, "ins_out", None):
            raise ShipstarError("--ins-out needs --ins FILE (the INS log)")
        return None
    if args.resume:
        raise ShipstarError("--ins cannot be used with --resume yet (the star attitudes before the stop are not "
                            "kept); run again without --resume")
    from pathlib import Path

    from shipstar.frames import AttitudeConvention
    from shipstar.pipeline._ins import StarRows

    AttitudeConvention(args.ins_convention)
    if not Path(args.ins).is_file():
        raise ShipstarError(f"--ins {args.ins} does not exist or is not a file")
    if args.ins_out:
        check_output_file(args.ins_out, "--ins-out")
    return StarRows()


def _model(args):
    from dataclasses import replace

    from shipstar.pipeline._ins import InsModel

    m = InsModel()
    for flag, name in (("ins_noise_arcsec", "noise_arcsec"),
                       ("ins_heading_random_walk_arcsec_per_sqrt_h", "heading_random_walk_arcsec_per_sqrt_h"),
                       ("ins_level_random_walk_arcsec_per_sqrt_h", "level_random_walk_arcsec_per_sqrt_h"),
                       ("ins_quantisation_deg", "quantisation_deg")):
        v = getattr(args, flag, None)
        if v is not None:
            m = replace(m, **{name: float(v)})
    if args.ins_no_misalignment:
        m = replace(m, estimate_misalignment=False)
    return m


def finish_ins(args, job, observer, summary: dict) -> None:
    """Read the log, estimate, write ``--ins-out``; ``summary["ins"]`` and ``summary["ins_details"]``."""
    if observer is None:
        return
    from shipstar.live._ins_input import read_ins_log
    from shipstar.pipeline._ins import estimate_ins, write_ins_csv

    log = read_ins_log(args.ins, job.start_utc_jd, args.ins_convention)
    for line in log.problems:
        print(f"shipstar measure: warning: {line}", file=sys.stderr)
    if log.n_skipped > len(log.problems):
        print(f"shipstar measure: warning: INS {args.ins}: {log.n_skipped} records skipped in all", file=sys.stderr)
    t, a, c = observer.arrays()
    sol = estimate_ins(log, t, a, c, _model(args))
    if args.ins_out:
        write_ins_csv(sol, args.ins_out)
        sol.details["out"] = str(args.ins_out)
    summary["ins"] = dict(sol.summary)
    summary["ins_details"] = dict(sol.details)
    if not args.json:
        s = sol.summary
        print(f"INS ({log.n_skipped} records skipped): heading bias {s['heading_bias_arcsec']:+.2f} +- "
              f"{s['heading_bias_sigma_arcsec']:.2f}'', drift {s['heading_drift_arcsec_per_h']:+.2f} +- "
              f"{s['heading_drift_sigma_arcsec_per_h']:.2f}''/h, pitch bias {s['pitch_bias_arcsec']:+.2f} +- "
              f"{s['pitch_bias_sigma_arcsec']:.2f}'', roll bias {s['roll_bias_arcsec']:+.2f} +- "
              f"{s['roll_bias_sigma_arcsec']:.2f}'', clock offset {s['time_offset_s'] * 1e3:+.3f} +- "
              f"{s['time_offset_sigma_s'] * 1e3:.3f} ms")
