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
    g.add_argument("--ins-report", metavar="HTML",
                   help="an HTML report of the INS: its estimated error terms with their sigmas, its error against "
                        "time with the sigma band, the corrected attitude through the longest outage (against --truth "
                        "when given); with --plots DIR the two figures also go there as ins_errors.png, ins_outage.png")
    g.add_argument("--ins-truth", metavar="JSON",
                   help="the simulated INS's true error terms (simulate-session --ins-log's ins_truth.json): a 'true' "
                        "column in --ins-report")
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
    """The star rows' collector when ``--ins`` is given (checked before any work), else None.

    A resumed run whose stopped run had ``--ins`` (``OUT.ins-stars`` exists) keeps
    collecting even without it, so that a later ``--resume --ins`` still has every epoch;
    a run completed without ``--ins`` deletes them (no INS estimate)."""
    from shipstar.cli._common import check_output_file

    if not getattr(args, "ins", None):
        for flag in ("ins_out", "ins_report", "ins_truth"):
            if getattr(args, flag, None):
                raise ShipstarError(f"--{flag.replace('_', '-')} needs --ins FILE (the INS log)")
        if getattr(args, "resume", False) and spool_path(args.out).is_file():
            from shipstar.pipeline._ins import StarRows

            return StarRows(spool_path(args.out), resume=True)    # a run begun with --ins: kept complete
        if not getattr(args, "resume", False):
            try:
                spool_path(args.out).unlink(missing_ok=True)       # a run started over: its old epochs go
            except OSError:
                pass
        return None
    from pathlib import Path

    from shipstar.frames import AttitudeConvention
    from shipstar.pipeline._ins import StarRows

    AttitudeConvention(args.ins_convention)
    if not Path(args.ins).is_file():
        raise ShipstarError(f"--ins {args.ins} does not exist or is not a file")
    if args.ins_out:
        check_output_file(args.ins_out, "--ins-out")
    if getattr(args, "ins_report", None):
        check_output_file(args.ins_report, "--ins-report")
    if getattr(args, "plots", None):
        from shipstar.cli._common import check_output_dir

        check_output_dir(args.plots, "--plots", files=PLOT_FILES)
    if getattr(args, "ins_truth", None):
        _true_terms(args.ins_truth)
    return StarRows(spool_path(args.out), resume=bool(args.resume))


#: The INS figures ``--plots DIR`` gets with ``--ins``.
PLOT_FILES = ("ins_errors.png", "ins_outage.png")


def spool_path(out):
    """The star attitudes of a run writing ``out`` (kept until the INS is estimated, so that
    ``--resume`` can run the filter over the whole session): ``OUT.ins-stars``."""
    from pathlib import Path

    out = Path(out)
    return out.with_name(out.name + ".ins-stars")


def _true_terms(path) -> dict:
    """The true error terms of ``--ins-truth`` (simulate-session's ``ins_truth.json``)."""
    import json

    try:
        with open(path, encoding="utf-8") as fh:
            d = json.load(fh)
    except (OSError, ValueError) as exc:
        raise ShipstarError(f"--ins-truth {path}: cannot read it as JSON ({exc})") from None
    if not isinstance(d, dict) or d.get("format") != "shipstar-ins-truth":
        raise ShipstarError(f"--ins-truth {path}: not a simulated INS's truth (format shipstar-ins-truth)")
    return d


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


def _finite(x):
    """NaN (not JSON) as None, in nested dicts and lists."""
    import math

    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return None if isinstance(x, float) and not math.isfinite(x) else x


def _figures(args, sol, truth, details: dict) -> None:
    """``--plots DIR`` (ins_errors.png, ins_outage.png) and ``--ins-report HTML``; the
    corrected attitude's statistics (against ``truth`` when given) in ``details``."""
    from shipstar.report._ins_plot import figure_pngs, ins_page, ins_statistics, true_attitude_at

    true_att = None if truth is None else true_attitude_at(sol, truth)
    details["corrected"] = _finite(ins_statistics(sol, true_att))
    report = getattr(args, "ins_report", None)
    if not (args.plots or report):
        return
    terms = _true_terms(args.ins_truth) if getattr(args, "ins_truth", None) else None
    page = ins_page(sol, true_attitude_rad=true_att, true_terms=terms, title=f"shipstar INS report: {args.out}")
    if args.plots:
        from pathlib import Path

        from shipstar._atomic import atomic_write_bytes

        details["plots"] = [str(atomic_write_bytes(Path(args.plots) / name, png))
                            for name, png in zip(PLOT_FILES, figure_pngs(page))]
    if report:
        details["report"] = str(page.write(report))


def finish_ins(args, job, observer, summary: dict, truth=None) -> None:
    """Read the log, estimate, write ``--ins-out``, the figures and the report;
    ``summary["ins"]`` and ``summary["ins_details"]``.  The spool of star attitudes
    (``OUT.ins-stars``) is deleted, whatever happens (the attitude CSV is complete)."""
    if observer is None:
        return
    try:
        if getattr(args, "ins", None):
            _finish(args, job, observer, summary, truth)
    finally:
        observer.discard()


def _finish(args, job, observer, summary: dict, truth) -> None:
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
    details = dict(sol.details)
    _figures(args, sol, truth, details)
    summary["ins"] = dict(sol.summary)
    summary["ins_details"] = details
    if not args.json:
        s = sol.summary
        print(f"INS ({log.n_skipped} records skipped): heading bias {s['heading_bias_arcsec']:+.2f} +- "
              f"{s['heading_bias_sigma_arcsec']:.2f}'', drift {s['heading_drift_arcsec_per_h']:+.2f} +- "
              f"{s['heading_drift_sigma_arcsec_per_h']:.2f}''/h, pitch bias {s['pitch_bias_arcsec']:+.2f} +- "
              f"{s['pitch_bias_sigma_arcsec']:.2f}'', roll bias {s['roll_bias_arcsec']:+.2f} +- "
              f"{s['roll_bias_sigma_arcsec']:.2f}'', clock offset {s['time_offset_s'] * 1e3:+.3f} +- "
              f"{s['time_offset_sigma_s'] * 1e3:.3f} ms")
        for key, block in details["corrected"].items():
            if block.get("rms_arcsec") and None not in block["rms_arcsec"]:
                print(f"INS corrected attitude {key} the outages ({block['n_compared']} records) vs truth: RMS "
                      + "/".join(f"{v:.2f}" for v in block["rms_arcsec"]) + "'', RMS(err/sigma) "
                      + "/".join(f"{v:.2f}" for v in block["rms_error_over_sigma"]) + " (heading/pitch/roll)")
        if "report" in details:
            print(f"INS report: {details['report']}")
