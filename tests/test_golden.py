"""Today's pipeline output against the frozen golden files (tests/golden/make_golden.py).

Like sgp4's verification diff: the rows must agree field by field, the numbers to well
below what the CSV's users read (angles to 1e-6 deg = 0.0036'', sigmas and residuals to
0.002''), the rest exactly.  A change of the pipeline that moves them regenerates the
files in the same commit and says why.
"""

from __future__ import annotations

import csv
import io
import math
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "golden"))

import make_golden  # noqa: E402

TOLERANCE = {"t_s": 1e-6, "heading_deg": 1e-6, "pitch_deg": 1e-6, "roll_deg": 1e-6,
             "sigma_heading_arcsec": 2e-3, "sigma_pitch_arcsec": 2e-3, "sigma_roll_arcsec": 2e-3,
             "rms_arcsec": 2e-3}


def _split(text: str):
    lines = text.splitlines()
    # the packaged IERS table's path depends on where the environment is installed: its name counts;
    # the software line names the code's digest and the environment's versions, which change with
    # every commit and machine by design (tests/cli/test_cmd_measure.py checks it): not compared
    comments = [line if not line.startswith("# eop_source = ") else "# eop_source = " + line.rsplit("/", 1)[-1]
                for line in lines if line.startswith("#") and not line.startswith("# software = ")]
    rows = list(csv.DictReader(io.StringIO("\n".join(line for line in lines if not line.startswith("#")))))
    return comments, rows


def _diff(golden: str, now: str) -> list:
    """Human-readable differences between two attitude CSV texts (empty: the same)."""
    (c0, r0), (c1, r1) = _split(golden), _split(now)
    out = [] if c0 == c1 else [f"comment lines differ: {c0} != {c1}"]
    if len(r0) != len(r1):
        return out + [f"{len(r1)} rows, golden has {len(r0)}"]
    for k, (a, b) in enumerate(zip(r0, r1)):
        if list(a) != list(b):
            return out + [f"columns differ: {list(a)} != {list(b)}"]
        for col in a:
            x, y = a[col], b[col]
            if col in TOLERANCE and x and y:
                if not math.isclose(float(x), float(y), rel_tol=0.0, abs_tol=TOLERANCE[col]):
                    out.append(f"row {k + 2} ({a['method']} {a['sensor']} {a['frame']}) {col}: {y} != golden {x}")
            elif x != y:
                out.append(f"row {k + 2} ({a['method']} {a['sensor']} {a['frame']}) {col}: {y!r} != golden {x!r}")
    return out


def test_measure_on_a_rendered_sea_session_matches_the_golden_file(tmp_path):
    args = make_golden.sea_image_session(tmp_path)
    now = make_golden.measure_csv(args, tmp_path / "att.csv")
    diff = _diff((HERE / "golden" / "measure_sea_image.csv").read_text(), now)
    assert not diff, "\n".join(diff[:20])


@pytest.mark.slow
def test_session_with_80_ms_streaks_matches_the_golden_file():
    diff = _diff((HERE / "golden" / "session_streaks_80ms.csv").read_text(), make_golden.streak_session_csv())
    assert not diff, "\n".join(diff[:20])
