"""Frames not in the page cache: the index and the whole chain, reading ahead against not.

A night's frames (1.4 TB for two sensors) are never all in memory when they are measured:
each header of the index and each frame's pixels come from the disk.  shipstar asks the OS
for the next files before it needs them (``shipstar._fitsio.advise_will_read``, Linux's
``posix_fadvise(WILLNEED)``): the headers of the next ``INDEX_READ_AHEAD_FILES`` files while
the index is read, the files of the next ``READ_AHEAD_FRAMES`` frames while frames are
processed.  This benchmark empties the page cache before each run (it needs root: writes
``/proc/sys/vm/drop_caches``) and times, on the image-level session at sea of
``bench_throughput.py`` (400 frames of 2 MB):

- the index (``scan_frames`` of both sensors), microseconds a header;
- the whole chain (``process_session``: read, extract, identify, ... fusion), ms a frame;

each with reading ahead (shipstar as it is) and without (the anchor: both constants set to
0 for the run), alternated ``--repeat`` times; printed: medians and their ratios.  Also
printed: the chain with the files in the page cache (the last run's files read again).

Run: ``python benchmarks/bench_cold_read.py [--dir DIR] [--repeat R]``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_throughput as bt  # noqa: E402


def drop_page_cache() -> None:
    os.sync()
    with open("/proc/sys/vm/drop_caches", "w") as fh:
        fh.write("1\n")


def one_run(directory: Path, read_ahead: bool) -> tuple[float, float, int]:
    """``(us a header, ms a frame, frames)`` of one run from an empty page cache."""
    import shipstar.pipeline._frames as frames_mod
    from shipstar.pipeline import scan_frames

    saved = frames_mod.INDEX_READ_AHEAD_FILES, frames_mod.READ_AHEAD_FRAMES
    if not read_ahead:
        frames_mod.INDEX_READ_AHEAD_FILES, frames_mod.READ_AHEAD_FRAMES = 0, 0
    try:
        drop_page_cache()
        t0 = time.perf_counter()
        n = sum(len(scan_frames(directory / name)) for name in ("A1", "A2"))
        index_us = (time.perf_counter() - t0) / n * 1e6
        drop_page_cache()
        t0 = time.perf_counter()
        bt.run_chain(directory)                    # (indexes again: its headers now cold too)
        chain_ms = (time.perf_counter() - t0) / n * 1e3
    finally:
        frames_mod.INDEX_READ_AHEAD_FILES, frames_mod.READ_AHEAD_FRAMES = saved
    return index_us, chain_ms, n


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dir", type=Path, help="the session (made by bench_throughput.py if absent)")
    ap.add_argument("--frames", type=int, default=200, help="frames per sensor of a new session")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    try:
        drop_page_cache()
    except OSError as exc:
        print(f"bench_cold_read: cannot empty the page cache ({exc.strerror}): run it as root", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        directory = args.dir or Path(tmp)
        if not (directory / "track.csv").exists():
            bt.make_session(directory, args.frames)
        bt.run_chain(directory)                    # warm: imports, catalog, databases
        runs = {True: [], False: []}
        for k in range(args.repeat):
            for ahead in (False, True):
                index_us, chain_ms, n = one_run(directory, ahead)
                runs[ahead].append((index_us, chain_ms))
                print(f"repeat {k + 1} {'read ahead' if ahead else 'anchor    '}: index {index_us:6.0f} us a header, "
                      f"chain {chain_ms:5.2f} ms a frame ({n} frames, page cache emptied before each)")
        t0 = time.perf_counter()
        bt.run_chain(directory)
        warm_ms = (time.perf_counter() - t0) / n * 1e3
    med = {a: (statistics.median(r[0] for r in runs[a]), statistics.median(r[1] for r in runs[a])) for a in runs}
    print(f"\nmedians of {args.repeat}: index {med[True][0]:.0f} us a header reading ahead against "
          f"{med[False][0]:.0f} us not ({med[False][0] / med[True][0]:.2f}x faster); chain {med[True][1]:.2f} "
          f"against {med[False][1]:.2f} ms a frame ({med[False][1] / med[True][1]:.2f}x faster); "
          f"the chain with the files in memory: {warm_ms:.2f} ms a frame")
    return 0


if __name__ == "__main__":
    sys.exit(main())
