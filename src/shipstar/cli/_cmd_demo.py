"""``shipstar demo``: the whole system on simulated frames, with an HTML report."""

from __future__ import annotations

import argparse

__all__ = ["register"]

DEFAULT_OUT = "shipstar-demo"

_EPILOG = """\
What it does:
  1. dock calibration (seed 000: Jiangyin, 2013-03-15) of sensors A1 and A2: frames rendered
     as raw images, extracted, identified, solved, averaged into installation angles;
  2. at sea, the ship rolling 5 deg / 8 s and pitching 2 deg / 6 s: each sensor's ship
     attitude, the seeds' fusion rule and the joint solution, with the calibrated installations;
  3. a results table against the truth beside the seeds' published figures, and
     OUT/report.html (one self-contained file).
  Full run: dock 16 s and sea 60 s at 10 frames/s (under 3 minutes on 2 cores);
  --quick: dock 2 s and sea 10 s (under 30 s).

Writes into OUT only: report.html, results.json, dock/<sensor>.installation.toml,
sea/{track,weather,truth}.csv and, without --config, config-used/ (the configuration it
ran). An earlier demo's outputs in OUT are replaced; an OUT/sea or OUT/dock holding
anything else (a session's frames) is refused, nothing touched.

examples:
  shipstar demo                              # full run into ./shipstar-demo
  shipstar demo --quick --out /tmp/demo --json
  shipstar demo --write-config my-ship       # the demo's TOML files, to edit for your ship
  shipstar demo --config my-ship --out my-ship-demo
"""


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "demo", help="run the whole system on simulated frames and write an HTML report",
        description="Simulate the seeds' dock calibration and a session at sea for sensors A1 and A2, process "
                    "them with the pipeline, print the results against truth beside the seeds' figures and "
                    "write an HTML report.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"output directory, created if needed (default ./{DEFAULT_OUT})")
    p.add_argument("--quick", action="store_true", help="short sessions (dock 2 s, sea 10 s): under 30 s")
    p.add_argument("--config", metavar="DIR", help="run the sessions described in DIR (see --write-config)")
    p.add_argument("--write-config", metavar="DIR",
                   help="write the demo's configuration files (site, ship, cameras, dock and sea sessions) "
                        "into DIR and exit")
    p.add_argument("--force", action="store_true", help="with --write-config: overwrite existing files")
    p.add_argument("--progress", action="store_true", help="progress bar on stderr (default: only on a terminal)")
    p.add_argument("--open", action="store_true", help="open the report in the web browser when done")
    p.add_argument("--json", action="store_true", help="print one JSON object with the results")
    p.set_defaults(run=run)
    return p


def _write_config(args) -> int:
    from shipstar.cli._common import emit_json
    from shipstar.config import write_example_config

    paths = write_example_config(args.write_config, overwrite=args.force)
    if args.json:
        emit_json({"written": [str(p) for p in paths]})
    else:
        print(f"wrote {len(paths)} files into {args.write_config}:")
        for p in paths:
            print(f"  {p}")
        print(f"edit them, then: shipstar demo --config {args.write_config}")
    return 0


def run(args) -> int:
    from shipstar.errors import ShipstarError

    if args.write_config is not None:
        if args.config is not None or args.quick or args.open:
            raise ShipstarError("--write-config only writes the files; run the demo separately")
        return _write_config(args)
    if args.force:
        raise ShipstarError("--force only applies to --write-config")
    import sys
    from pathlib import Path

    from shipstar._demo import results_dict, results_text, run_demo
    from shipstar._demo._progress import Progress
    from shipstar.cli._common import emit_json

    result = run_demo(args.out, quick=args.quick, config_dir=args.config,
                      progress=Progress(enabled=args.progress or sys.stderr.isatty()))
    url = Path(result.report_path).resolve().as_uri()
    if args.json:
        emit_json(results_dict(result))
    else:
        print(results_text(result))
        print(f"report: {url}")
    if args.open:
        import webbrowser

        webbrowser.open(url)
    return 0
