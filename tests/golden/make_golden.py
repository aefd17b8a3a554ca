"""Regenerate the pipeline's golden files (as sgp4 regenerates its verification output).

Two small sessions whose attitude CSV is frozen here, so that a rewrite of the pipeline
shows exactly what it changed (``tests/test_golden.py`` diffs today's output against
these files, number by number):

``measure_sea_image.csv``
    ``shipstar measure`` on a rendered 1 s sea session (A2 exposing 30 ms after A1,
    10 ms exposures, true installations): extraction, identification, pairing, the
    carry between the sensors' exposure times, fusion.
``session_streaks_80ms.csv``
    ``process_session`` on 8 s of centroid-level sea frames with 80 ms exposures whose
    centroids are the stars' time averages over the exposure (0.1 px noise, A2 30 ms
    late): the streak correction and the carry at the seeds' sea state.

Run ``python tests/golden/make_golden.py`` from the repository root to rewrite them; a
commit that changes them says why.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

HERE = Path(__file__).resolve().parent


def sea_image_session(root: Path) -> list:
    """Write the 1 s rendered sea session and the true installations under ``root``;
    return the ``shipstar measure`` arguments (without ``--out``)."""
    from shipstar.calibrate.installation import Installation, save_installation
    from shipstar.simulate._session import sea_session, write_session

    spec = sea_session(duration_s=1.0)
    spec = spec.replace(sensors=(spec.sensors[0], replace(spec.sensors[1], time_offset_s=0.03)))
    write_session(spec, root / "sea")
    for s in spec.sensors:
        save_installation(Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor),
                          root / f"{s.name}.toml")
    return ["--sensor", f"A1={root / 'sea' / 'A1'}", "--sensor", f"A2={root / 'sea' / 'A2'}",
            "--install", str(root / "A1.toml"), str(root / "A2.toml"),
            "--track", str(root / "sea" / "track.csv"), "--weather", str(root / "sea" / "weather.csv")]


def measure_csv(args: list, out: Path) -> str:
    """Run ``shipstar measure`` in a subprocess; return the CSV text."""
    proc = subprocess.run([sys.executable, "-m", "shipstar", "measure", *args, "--out", str(out)],
                          capture_output=True, text=True, timeout=600)
    if proc.returncode not in (0, 1):
        raise RuntimeError(proc.stderr)
    return out.read_text()


def streak_session_csv() -> str:
    """The 8 s centroid-level 80 ms session through ``process_session``: the CSV text."""
    sys.path.insert(0, str(HERE.parent))
    from test_pipeline import _tables, _time_averaged_frames, _true_configs

    from shipstar.pipeline import attitude_csv_text, process_session
    from shipstar.simulate._session import sea_session, simulate_centroids

    spec = sea_session(exposure_s=0.08, duration_s=8.0)
    spec = spec.replace(sensors=(spec.sensors[0], replace(spec.sensors[1], time_offset_s=0.03)))
    track, weather, _ = _tables(spec)
    frames = _time_averaged_frames(spec, simulate_centroids(spec.replace(centroid_sigma_px=0.1)), 0.08)
    return attitude_csv_text(process_session(_true_configs(spec), frames, track, weather))


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        text = measure_csv(sea_image_session(root), root / "att.csv")
    (HERE / "measure_sea_image.csv").write_text(text)
    (HERE / "session_streaks_80ms.csv").write_text(streak_session_csv())
    print(f"written: {HERE / 'measure_sea_image.csv'}, {HERE / 'session_streaks_80ms.csv'}")


if __name__ == "__main__":
    main()
