"""Where a sensor's frames come from, for processing in chunks: :class:`FrameSource`.

``shipstar measure`` cuts a session into chunks of time and hands each chunk of each
sensor to a worker process.  A source says up front when its frames are (their
mid-exposure times, compact arrays) and gives a small picklable *piece* for a range of
frames that the worker loads itself (:meth:`FrameSource.piece`), so that neither the
main process nor the messages to the workers hold more than a chunk of frames:

- :class:`FitsDirectorySource`: a directory of FITS frames, indexed once by their
  headers (names and times only: ~100 bytes a frame);
- :class:`FrameListSource`: frames already in memory (the Python API, tests).

Any object with ``name``, ``times_utc_jd()`` and ``piece(lo, hi)`` whose piece has
``load() -> [Frame]`` is a source (``benchmarks/bench_measure_scale.py`` simulates its
star lists chunk by chunk).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shipstar.errors import ShipstarError

__all__ = ["FrameSource", "FrameListSource", "FitsDirectorySource"]


class FrameSource(abc.ABC):
    """A sensor's frames: times up front, frames by the chunk.

    Attributes
    ----------
    name : str
        The sensor's name.
    """

    name: str = ""

    @abc.abstractmethod
    def times_utc_jd(self) -> tuple[np.ndarray, np.ndarray]:
        """Mid-exposure UTC of every frame, two-part Julian dates ``((M,), (M,))``, increasing."""

    @abc.abstractmethod
    def piece(self, lo: int, hi: int):
        """A picklable object whose ``load()`` gives frames ``lo .. hi - 1`` (list of Frame)."""

    def __len__(self) -> int:
        return len(self.times_utc_jd()[0])


@dataclass(frozen=True, eq=False)
class _ListPiece:
    frames: tuple

    def load(self) -> list:
        return list(self.frames)


class FrameListSource(FrameSource):
    """Frames already in memory (in time order)."""

    def __init__(self, name: str, frames):
        self.name = name
        self.frames = tuple(frames)
        self._jd = (np.array([f.utc_jd1 for f in self.frames]), np.array([f.utc_jd2 for f in self.frames]))

    def times_utc_jd(self):
        return self._jd

    def piece(self, lo: int, hi: int):
        return _ListPiece(self.frames[lo:hi])


@dataclass(frozen=True, eq=False)
class _FitsPiece:
    directory: str
    names: tuple
    jd1: np.ndarray
    jd2: np.ndarray
    exposure_s: np.ndarray
    time_sources: tuple
    sensors: tuple

    def load(self) -> list:
        from shipstar.pipeline._frames import Frame

        d = Path(self.directory)
        return [Frame(float(a), float(b), n, path=d / n, sensor=s, time_source=ts, exposure_s=float(e))
                for n, a, b, e, ts, s in zip(self.names, self.jd1, self.jd2, self.exposure_s, self.time_sources,
                                             self.sensors)]


class FitsDirectorySource(FrameSource):
    """A directory of one sensor's FITS frames, indexed by their headers.

    Parameters
    ----------
    name : str
    directory : str or Path
    date_obs_is : {"start", "mid"}
    check : callable, optional
        Called with each frame's header (:func:`shipstar.pipeline.scan_frames`).
    headers : iterable of (infos, error), optional
        The headers, read elsewhere (:func:`shipstar.pipeline.scan_frames`' ``headers``).
    progress : callable, optional
        ``progress(done, total)`` as the headers are indexed (:func:`shipstar.pipeline.scan_frames`).

    Raises
    ------
    ShipstarError
        As :func:`shipstar.pipeline.scan_frames` (no frames, no time, out of order).
    """

    def __init__(self, name: str, directory, *, date_obs_is: str = "start", check=None, headers=None,
                 progress=None):
        from shipstar.pipeline._frames import scan_frames

        self.name = name
        self.directory = str(Path(directory))
        frames = scan_frames(directory, date_obs_is=date_obs_is, check=check, headers=headers, progress=progress)
        self._names = [f.label for f in frames]
        self._jd1 = np.array([f.utc_jd1 for f in frames])
        self._jd2 = np.array([f.utc_jd2 for f in frames])
        self._exposure_s = np.array([f.exposure_s for f in frames])
        kinds = sorted({f.time_source for f in frames} | {f.sensor for f in frames})
        self._words = kinds                                   # distinct strings, stored once
        code = {w: k for k, w in enumerate(kinds)}
        self._source_code = np.array([code[f.time_source] for f in frames], np.int32)
        self._sensor_code = np.array([code[f.sensor] for f in frames], np.int32)

    @property
    def sensors_named(self) -> set:
        """Sensor names the frames' headers give (FITS ``SENSOR``/``INSTRUME``)."""
        return {self._words[k] for k in np.unique(self._sensor_code)} - {""}

    def time_sources(self) -> dict:
        """``{time_source: number of frames}``."""
        codes, counts = np.unique(self._source_code, return_counts=True)
        return {(self._words[c] or "given"): int(n) for c, n in zip(codes, counts)}

    def times_utc_jd(self):
        return self._jd1, self._jd2

    def piece(self, lo: int, hi: int):
        if not 0 <= lo <= hi <= len(self._names):
            raise ShipstarError(f"frames {lo}..{hi} of {self.name} out of range (0..{len(self._names)})")
        return _FitsPiece(self.directory, tuple(self._names[lo:hi]), self._jd1[lo:hi], self._jd2[lo:hi],
                          self._exposure_s[lo:hi], tuple(self._words[c] for c in self._source_code[lo:hi]),
                          tuple(self._words[c] for c in self._sensor_code[lo:hi]))
