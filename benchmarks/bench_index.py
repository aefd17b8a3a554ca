"""Indexing a session's frames: their headers read by ``measure-archive``'s workers against
the command reading them itself.

Before its first task can start, ``shipstar measure-archive`` indexes every frame of a
session: the FITS header of each file (mid-exposure time, exposure, sensor, position and
weather cards for the header checks).  A night of two sensors at 10 frames/s is 720 000
files.  Read one by one by the command (``scan_frames``, the anchor), that is serial work
in front of the cluster; :class:`shipstar.pipeline._archive.HeaderReader` has the
cluster's workers read them in blocks, side by side, and the command only assembles the
index.

Files: ``--frames`` (default 20 000) header-only copies of one rendered frame's header
(5760 bytes each, DATE-AVG 0.1 s apart), written once to ``--dir`` or a temporary
directory: reading a header reads only those blocks.  Timed, alternately, ``--repeat``
times: ``scan_frames`` here, and with the headers read by a LocalCluster of 1 and of 2
workers (started once, before the timing; the index must be the same, frame by frame).
Printed: the medians and the ratios against reading here.

Run: ``python benchmarks/bench_index.py [--frames 20000] [--dir DIR] [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import datetime
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path


def make_files(directory: Path, n: int) -> None:
    """``n`` header-only FITS files of one sensor (a rendered frame's header, DATE-AVG stepped)."""
    from shipstar.simulate._session import sea_session, write_session

    names = sorted(directory.glob("A1_*.fits"))
    if len(names) == n:
        return
    for p in names:
        p.unlink()
    with tempfile.TemporaryDirectory() as tmp:
        write_session(sea_session(duration_s=0.1), Path(tmp) / "s")
        first = sorted((Path(tmp) / "s" / "A1").glob("*.fits"))[0]
        head = first.read_bytes()[:5760]
    key = head[head.index(b"DATE-AVG= '"):][:38]
    t0 = datetime.datetime(2013, 3, 15, 12, 16, 0)
    for k in range(n):
        t = t0 + datetime.timedelta(seconds=0.1 * k)
        card = b"DATE-AVG= '" + t.strftime("%Y-%m-%dT%H:%M:%S.%f").encode() + b"'"
        (directory / f"A1_{k:06d}.fits").write_bytes(head.replace(key, card))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=20000)
    ap.add_argument("--dir", help="directory for the files (kept)")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)
    root = Path(a.dir) if a.dir else Path(tempfile.mkdtemp(prefix="bench_index_"))
    root.mkdir(parents=True, exist_ok=True)
    make_files(root, a.frames)

    import logging

    import distributed  # noqa: F401  (configures its loggers on import; quietened below)

    from shipstar.pipeline._archive import HeaderReader, connect
    from shipstar.pipeline._frames import frame_paths, scan_frames

    logging.getLogger("distributed").setLevel(logging.ERROR)     # the scheduler here: no close-down chatter

    def index(frames):
        return [(f.label, f.utc_jd1, f.utc_jd2, f.exposure_s, f.sensor, f.time_source) for f in frames]

    reference = index(scan_frames(root))
    clusters = {w: connect(None, workers=w) for w in (1, 2)}
    times = {"here": [], 1: [], 2: []}
    print(f"{a.frames} header-only frames in {root}; {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}",
          flush=True)
    try:
        for w, (client, _) in clusters.items():            # the workers import the reader once
            assert index(scan_frames(root, headers=HeaderReader(client)(frame_paths(root), "start"))) == reference
        for r in range(a.repeat):
            order = ["here", 1, 2] if r % 2 == 0 else [2, 1, "here"]
            for k in order:
                t0 = time.perf_counter()
                if k == "here":
                    frames = scan_frames(root)
                else:
                    reader = HeaderReader(clusters[k][0])
                    frames = scan_frames(root, headers=reader(frame_paths(root), "start"))
                times[k].append(time.perf_counter() - t0)
                if index(frames) != reference:
                    raise SystemExit(f"the index read by {k} workers differs")
            print(f"  repeat {r + 1}: here {times['here'][-1]:.2f} s, 1 worker {times[1][-1]:.2f} s, "
                  f"2 workers {times[2][-1]:.2f} s", flush=True)
    finally:
        for client, cluster in clusters.values():
            client.close()
            cluster.close()
    here = statistics.median(times["here"])
    print(f"medians: read here {here:.2f} s ({here / a.frames * 1e3:.3f} ms a frame); "
          + "; ".join(f"{w} worker{'s' if w > 1 else ''} {statistics.median(times[w]):.2f} s "
                      f"({here / statistics.median(times[w]):.2f}x)" for w in (1, 2)))
    print("the index identical to reading here, frame by frame: yes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
