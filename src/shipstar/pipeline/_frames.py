"""Pipeline inputs: one sensor frame (:class:`Frame`) and FITS frame directories (:func:`scan_frames`).

FITS files are read by :mod:`shipstar._fitsio`: a frame's time is its mid-exposure UTC
(``DATE-AVG``, else ``DATE-BEG``/``DATE-OBS`` -- the exposure *start* in the FITS
standard -- plus half the exposure; ``date_obs_is="mid"`` for cameras that write the
mid-exposure time into ``DATE-OBS``), and images are returned top row first
(``ROWORDER``).  Each :class:`Frame` records how its time was found (``time_source``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shipstar._fitsio import FITS_SUFFIXES
from shipstar.errors import ShipstarError
from shipstar.units import DAY_S

__all__ = ["Frame", "scan_frames", "frame_paths", "read_header_block", "header_blocks", "read_fits_frame",
           "time_sources", "read_ahead", "FITS_SUFFIXES", "INDEX_BLOCK_MIN_FILES",
           "INDEX_BLOCKS_PER_WORKER", "INDEX_READ_AHEAD_FILES", "READ_AHEAD_FRAMES"]


@dataclass(frozen=True, eq=False)
class Frame:
    """One frame of one sensor: its mid-exposure time and its data.

    Exactly one data form is used, in this order: ``xy_px`` (centroids: extraction is
    skipped; with ``hip`` also the identification), ``image`` (an array), ``path`` (a
    FITS file, read when processed).

    Attributes
    ----------
    utc_jd1, utc_jd2 : float
        Two-part UTC Julian date of mid-exposure.
    label : str
        Name in reports (file name, or ``"#index"``).
    path : Path or None
    image : (H, W) array or None
    xy_px : (N, 2) array or None
        Measured centroids, brightest first.
    hip : (N,) int array or None
        Known identities of ``xy_px`` (-1 for none).
    sensor : str
        Sensor named in the file (FITS ``SENSOR`` or ``INSTRUME``), '' if none.
    time_source : str
        How the time was found in the file (e.g. ``"DATE-AVG"``, ``"DATE-OBS+EXPTIME/2"``,
        ``"DATE-OBS(mid)"``); '' for frames not read from a file.
    exposure_s : float
        Exposure time, s (from the file's ``EXPTIME``/``EXPOSURE`` or ``DATE-END`` minus the
        start; NaN when unknown: then the streak correction is not applied).
    """

    utc_jd1: float
    utc_jd2: float
    label: str = ""
    path: Path | None = None
    image: np.ndarray | None = None
    xy_px: np.ndarray | None = None
    hip: np.ndarray | None = None
    sensor: str = ""
    time_source: str = ""
    exposure_s: float = math.nan

    def __post_init__(self):
        if self.path is None and self.image is None and self.xy_px is None:
            raise ShipstarError(f"frame {self.label!r} has no data (give a path, an image or centroids)")
        if not (np.isfinite(self.utc_jd1) and np.isfinite(self.utc_jd2)):
            raise ShipstarError(f"frame {self.label!r} has a non-finite time")
        if self.hip is not None and (self.xy_px is None or len(self.hip) != len(self.xy_px)):
            raise ShipstarError(f"frame {self.label!r}: hip must match xy_px row by row")
        if not (math.isnan(self.exposure_s) or (math.isfinite(self.exposure_s) and self.exposure_s >= 0.0)):
            raise ShipstarError(f"frame {self.label!r}: exposure_s must be >= 0 (or NaN: unknown), "
                                f"got {self.exposure_s!r}")

    @classmethod
    def from_centroids(cls, utc_jd1, utc_jd2, xy_px, hip=None, label: str = "",
                       exposure_s: float = math.nan) -> "Frame":
        """A centroid-level frame (``xy_px`` (N, 2), optional known ``hip`` (N,)); with
        ``exposure_s`` the centroids are taken as time averages over the exposure (the
        streak correction applies)."""
        xy = np.asarray(xy_px, float).reshape(-1, 2)
        return cls(float(utc_jd1), float(utc_jd2), label, xy_px=xy,
                   hip=None if hip is None else np.asarray(hip, np.int64).reshape(-1), exposure_s=float(exposure_s))

    def seconds_since(self, jd1: float, jd2: float) -> float:
        """Seconds from the two-part UTC JD ``(jd1, jd2)`` to this frame."""
        return ((self.utc_jd1 - jd1) + (self.utc_jd2 - jd2)) * DAY_S

    @property
    def utc_iso(self) -> str:
        from shipstar.sky.time import iso_from_utc_jd

        return iso_from_utc_jd(self.utc_jd1, self.utc_jd2, 6)


def read_fits_frame(path, *, date_obs_is: str = "start") -> tuple[np.ndarray, tuple[float, float]]:
    """``(image (H, W), (utc_jd1, utc_jd2))`` of a FITS frame: its pixels (top row first)
    and its mid-exposure UTC (:mod:`shipstar._fitsio`: DATE-AVG, else DATE-BEG / DATE-OBS
    plus half the exposure).

    Parameters
    ----------
    path : str or Path
    date_obs_is : {"start", "mid"}
        What the files' DATE-OBS means; the FITS standard (and the default) is the start.

    Raises
    ------
    ShipstarError
        Missing, truncated or corrupt file, no 2-D image, no usable time.
    """
    from shipstar._fitsio import read_fits

    image, info = read_fits(path, date_obs_is=date_obs_is)
    return image, info.mid_utc_jd()


def in_name_order(paths) -> list:
    """The paths of one directory's files in file-name order: the order ``sorted(paths)``
    gives, keyed by the names (compared as the paths are: case-folded where the OS folds
    case), ~10 x faster than comparing ``Path`` objects (0.3 against 3.0 s for the 360,000
    frames of a 10-hour night at 10 frames/s, listed in the directory's own order)."""
    return sorted(paths, key=lambda p: os.path.normcase(p.name))


def frame_paths(directory) -> list:
    """The FITS frames of a directory (``*.fits`` / ``*.fit`` / ``*.fts``, optionally
    gzipped; hidden files left out), in file-name order, as paths.

    Raises
    ------
    ShipstarError
        Not a directory, or no FITS files in it.
    """
    from shipstar._fitsio import is_fits_name

    d = Path(directory)
    if not d.is_dir():
        raise ShipstarError(f"frames directory {d} does not exist or is not a directory")
    paths = in_name_order(p for p in d.iterdir() if is_fits_name(p.name))
    if not paths:
        raise ShipstarError(f"no FITS frames (*.fits, *.fit, *.fts, optionally .gz) in {d}")
    return paths


#: A directory's frame headers read by other processes (``measure``'s worker pool,
#: ``measure-archive``'s cluster) go in blocks of at least this many files (fewer are read
#: by the command itself: ~0.1 ms a header on the development machine, where a block's
#: round trip costs about what reading 1000 headers saves on two workers) ...
INDEX_BLOCK_MIN_FILES = 1000
#: ... and, for a larger directory, about this many blocks per worker.
INDEX_BLOCKS_PER_WORKER = 4


def header_blocks(paths, workers: int, *, min_files: int | None = None, per_worker: int | None = None) -> list:
    """``paths`` cut into consecutive blocks for ``workers`` readers: at least
    ``min_files`` each (default :data:`INDEX_BLOCK_MIN_FILES`), about ``per_worker``
    (default :data:`INDEX_BLOCKS_PER_WORKER`) per reader (one block: read it here)."""
    import math

    min_files = INDEX_BLOCK_MIN_FILES if min_files is None else min_files
    per_worker = INDEX_BLOCKS_PER_WORKER if per_worker is None else per_worker
    paths = list(paths)
    size = max(1, int(min_files), math.ceil(len(paths) / (max(1, int(per_worker)) * max(1, int(workers)))))
    return [paths[lo:lo + size] for lo in range(0, len(paths), size)] or [[]]


#: While an index is read, the OS is asked for the headers of this many files ahead of the one
#: being read (:func:`shipstar._fitsio.advise_will_read`): headers not in the page cache (a
#: night's 1.4 TB of frames never are) come ~4x faster, ~5 us a header more when they are.
INDEX_READ_AHEAD_FILES = 128
#: While frames are processed, the OS is asked for the files of this many frames ahead.
READ_AHEAD_FRAMES = 2


def read_header_block(paths, date_obs_is: str = "start") -> tuple:
    """``(infos, error)``: the headers of ``paths`` (:class:`~shipstar._fitsio.FitsFrameInfo`),
    read in order up to the first that cannot be, and that one's ShipstarError (None when
    all were read).  One block of an index (:func:`scan_frames`), read here or on another
    process or machine (``shipstar measure-archive`` has its cluster's workers read them).
    The headers of the next :data:`INDEX_READ_AHEAD_FILES` files are asked of the OS ahead."""
    from shipstar._fitsio import HEADER_READ_BYTES, advise_will_read, read_fits_header

    paths = list(paths)
    ahead = INDEX_READ_AHEAD_FILES
    for p in paths[:ahead]:
        advise_will_read(p, HEADER_READ_BYTES)
    infos = []
    for k, p in enumerate(paths):
        if k + ahead < len(paths):
            advise_will_read(paths[k + ahead], HEADER_READ_BYTES)
        try:
            infos.append(read_fits_header(p, date_obs_is=date_obs_is))
        except ShipstarError as exc:
            return infos, exc
    return infos, None


def read_ahead(items, depth: int = READ_AHEAD_FRAMES, frame_of=None):
    """``items`` (an iterable) again, in order, each taken from it ``depth`` items before it is
    yielded, and the OS asked for the whole file of each frame read from a file as it is
    taken (:func:`shipstar._fitsio.advise_will_read`), so that the disk reads the next frames
    while this one is processed.  ``frame_of(item)`` gives an item's :class:`Frame` (default:
    the item itself); frames with an image or centroids in memory are passed through."""
    from collections import deque

    from shipstar._fitsio import advise_will_read

    frame_of = (lambda item: item) if frame_of is None else frame_of
    waiting = deque()
    for item in items:
        frame = frame_of(item)
        if frame.image is None and frame.xy_px is None:
            advise_will_read(frame.path)
        waiting.append(item)
        if len(waiting) > depth:
            yield waiting.popleft()
    while waiting:
        yield waiting.popleft()


#: Headers read at a time by :func:`scan_frames` when it reports its progress (a 10-hour night
#: at 10 frames/s is 360,000 headers, ~30 s here).
PROGRESS_BLOCK_FILES = 2000


def scan_frames(directory, *, date_obs_is: str = "start", check=None, headers=None, progress=None) -> list[Frame]:
    """The FITS frames of a directory, in file-name order, with their mid-exposure times.

    Parameters
    ----------
    directory : str or Path
        Holds ``*.fits`` / ``*.fit`` / ``*.fts`` frames (each optionally gzipped,
        ``.fits.gz``) of ONE sensor; hidden (dot) files are ignored.
    date_obs_is : {"start", "mid"}
        What the files' DATE-OBS means when they have no DATE-AVG or DATE-BEG: the start
        of the exposure (the FITS standard, the default) or its middle.
    check : callable, optional
        Called with each frame's :class:`~shipstar._fitsio.FitsFrameInfo` as it is read
        (the header cross-checks, :class:`~shipstar.pipeline._header_check.HeaderCheck`).
    headers : iterable of (infos, error), optional
        The headers of :func:`frame_paths` ``(directory)``, read elsewhere with
        ``date_obs_is``: consecutive blocks in file order, each as
        :func:`read_header_block` returns it (the first block with an error is the last
        one read).  By default they are read here, as one block.
    progress : callable, optional
        ``progress(done, total)``: called with the number of headers indexed so far after
        each block (read here in blocks of :data:`PROGRESS_BLOCK_FILES`), ``done == total``
        last, when every header was read.

    Returns
    -------
    list of Frame
        ``path``, ``time_source`` and ``exposure_s`` set, image not yet read.

    Raises
    ------
    ShipstarError
        Not a directory, no FITS files, a frame without a usable time (no DATE-OBS, or a
        start without EXPTIME / DATE-END), or frames whose times do not increase strictly
        in file-name order (both files named).
    """
    from shipstar._fitsio import DATE_OBS_CHOICES

    if date_obs_is not in DATE_OBS_CHOICES:
        raise ShipstarError(f"date_obs_is must be one of {', '.join(DATE_OBS_CHOICES)}, got {date_obs_is!r}")
    paths = frame_paths(directory)
    if headers is None and progress is None:
        headers = (read_header_block(paths, date_obs_is),)
    elif headers is None:                           # blocks read one after the other, as they are taken
        headers = (read_header_block(paths[i:i + PROGRESS_BLOCK_FILES], date_obs_is)
                   for i in range(0, len(paths), PROGRESS_BLOCK_FILES))
    frames = []
    # a check that takes many frames at once (HeaderCheck.check_many) runs on the frames
    # read so far when one cannot be read, and on all of them at the end: the first error
    # in file order is raised, as one frame at a time would
    many = getattr(check, "check_many", None)
    infos = []
    try:
        for block, error in headers:
            for info in block:
                p = paths[len(frames)] if len(frames) < len(paths) else None
                if p is None or info.name != p.name:        # headers read elsewhere, of another listing
                    raise ShipstarError(f"the frames in {directory} changed while they were indexed "
                                        f"({info.name} where {p.name if p else 'no more files'} was listed)")
                jd1, jd2 = info.mid_utc_jd()
                if many is not None:
                    infos.append(info)
                elif check is not None:
                    check(info)
                frames.append(Frame(jd1, jd2, p.name, path=p, sensor=info.sensor_name,
                                    time_source=info.time_source, exposure_s=info.exposure_s))
            if error is not None:
                raise error
            if progress is not None:
                progress(len(frames), len(paths))
    except ShipstarError:
        if many is not None:
            many(infos)
        raise
    if len(frames) != len(paths):                   # a reader that lost a block
        raise ShipstarError(f"{len(paths) - len(frames)} of the {len(paths)} frame headers in {directory} "
                            f"were not read")
    if many is not None:
        many(infos)
    for a, b in zip(frames, frames[1:]):
        dt_s = b.seconds_since(a.utc_jd1, a.utc_jd2)
        if dt_s <= 0.0:
            raise ShipstarError(f"frames out of time order: {b.label} (mid-exposure {b.utc_iso}) is not later than "
                                f"{a.label} ({a.utc_iso})")
        half_s = 0.5 * (a.exposure_s + b.exposure_s)           # NaN (unknown): not compared
        if dt_s < 0.9 * half_s - 0.001:
            raise ShipstarError(f"frames {a.label} and {b.label}: their exposures ({a.exposure_s:g} and "
                                f"{b.exposure_s:g} s, EXPTIME) overlap, their mid-exposures {dt_s:g} s apart: a wrong "
                                f"EXPTIME also moves each frame's time from DATE-OBS by half of it")
    return frames


def time_sources(frames) -> dict:
    """``{time_source: number of frames}`` of a list of frames (for reports: how the time
    tags were found, e.g. ``{"DATE-OBS+EXPTIME/2": 160}``)."""
    out: dict = {}
    for f in frames:
        key = f.time_source or "given"
        out[key] = out.get(key, 0) + 1
    return out
