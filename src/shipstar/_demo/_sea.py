"""The session at sea: simulated frames -> pipeline (per sensor, seed rule, joint) -> errors vs truth.

The image-level part of the session (its first ``image_level_s``) is processed in chunks
of ``CHUNK_FRAMES`` frames per sensor (one ``process_session`` call each, so at most a
chunk of images is in memory); the centroid-level rest in one call.  The track, weather
and truth tables are written as CSV files into the output directory and read back with
the pipeline's readers, exactly as a user's files would be.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shipstar.units import RAD2ASEC, RAD2DEG

__all__ = ["MethodSeries", "SeaSensor", "SeaOutcome", "run_sea", "CHUNK_FRAMES", "write_session_tables"]

CHUNK_FRAMES = 20


@dataclass(frozen=True, eq=False)
class MethodSeries:
    """One method's ship attitude errors over the session.

    Attributes
    ----------
    name : str
        ``"single A1"``, ``"seed rule"``, ``"joint"``.
    t_s : (M,)
    errors_arcsec : (M, 3)
        Estimated minus true (heading, pitch, roll); NaN rows where not solved.
    sigma_arcsec : (M, 3)
        Formal 1-sigma (NaN where not solved).
    image_level : (M,) bool
    """

    name: str
    t_s: np.ndarray
    errors_arcsec: np.ndarray
    sigma_arcsec: np.ndarray
    image_level: np.ndarray

    def rms_arcsec(self, subset: str = "all") -> np.ndarray:
        """RMS (3,) over ``"all"``, ``"image"`` or ``"centroid"`` level epochs (NaN if none)."""
        from shipstar.pipeline import rms_arcsec

        mask = {"all": np.ones(len(self.t_s), bool), "image": self.image_level,
                "centroid": ~self.image_level}[subset]
        return rms_arcsec(self.errors_arcsec[mask]) if mask.any() else np.full(3, np.nan)

    @property
    def n_solved(self) -> int:
        return int(np.all(np.isfinite(self.errors_arcsec), axis=1).sum())


@dataclass(frozen=True, eq=False)
class SeaSensor:
    """Frame statistics of one sensor at sea.

    ``stars_used`` and ``star_sigma_arcsec`` are medians over the solved frames of each
    level, ``{"image": ..., "centroid": ...}`` (NaN for a level with none); the star
    sigma is each frame's RMS per-star noise (1-sigma per axis) as the attitude step
    estimated it.
    """

    name: str
    n_frames: int
    n_image_level: int
    n_solved: int
    stars_used: dict
    star_sigma_arcsec: dict
    failures: tuple

    def model_inputs(self) -> tuple[float, float]:
        """(stars used, star sigma arcsec) for the error model: centroid level if any."""
        level = "centroid" if math.isfinite(self.stars_used["centroid"]) else "image"
        return self.stars_used[level], self.star_sigma_arcsec[level]


@dataclass(frozen=True, eq=False)
class SeaOutcome:
    """Everything the sea session gave (see :func:`run_sea`)."""

    methods: tuple
    sensors: tuple
    truth_t_s: np.ndarray
    truth_deg: np.ndarray
    sensor_tracks_deg: dict
    fore_aft_sensor: str
    athwartship_sensor: str
    files: dict

    def method(self, name: str) -> MethodSeries:
        return next(m for m in self.methods if m.name == name)


def _csv(path: Path, header: list, rows: list) -> Path:
    from shipstar._atomic import atomic_write_text

    atomic_write_text(path, ",".join(header) + "\n" + "".join(",".join(r) + "\n" for r in rows))
    return path


def write_session_tables(spec, out_dir: Path) -> dict:
    """``track.csv``, ``weather.csv`` (1 s steps) and ``truth.csv`` (every frame time) of a
    simulated session, in the formats the pipeline reads (docs/file-formats.md)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    t_tab = np.arange(-1.0, spec.duration_s + 2.0, 1.0)
    lat, lon, h = spec.motion.position(t_tab)
    track = [[spec.utc_iso(t), f"{a * RAD2DEG:.10f}", f"{b * RAD2DEG:.10f}", f"{c:.3f}"]
             for t, a, b, c in zip(t_tab, lat, lon, h)]
    weather = [[spec.utc_iso(t), f"{w.pressure_hpa:.4f}", f"{w.temperature_c:.4f}", f"{w.relative_humidity:.4f}"]
               for t, w in ((t, spec.weather(t)) for t in t_tab)]
    t_truth = np.unique(np.concatenate([spec.times_s(s) for s in spec.sensors]))
    K, psi, theta = spec.motion.angles_rad(t_truth)
    truth = [[spec.utc_iso(t), f"{t:.6f}", repr(float(a) * RAD2DEG), repr(float(b) * RAD2DEG), repr(float(c) * RAD2DEG)]
             for t, a, b, c in zip(t_truth, K, psi, theta)]
    return {"track": _csv(out_dir / "track.csv", ["time_utc", "lat_deg", "lon_deg", "height_m"], track),
            "weather": _csv(out_dir / "weather.csv", ["time_utc", "pressure_hpa", "temperature_c",
                                                      "relative_humidity"], weather),
            "truth": _csv(out_dir / "truth.csv", ["time_utc", "t_s", "heading_deg", "pitch_deg", "roll_deg"], truth)}


def _chunks(n: int, n_img: int) -> list:
    """``[(lo, hi, image_level), ...]`` frame index ranges: image-level chunks, then the centroid rest."""
    n_img = min(n, n_img)
    out = [(lo, min(n_img, lo + CHUNK_FRAMES), True) for lo in range(0, n_img, CHUNK_FRAMES)]
    return out + ([(n_img, n, False)] if n_img < n else [])


def _collect(result, series: dict, image_level: bool) -> None:
    from shipstar.pipeline import method_series

    parts = [(f"single {s}", method_series(result, "single", s)) for s in result.sensors]
    if len(result.sensors) > 1:
        parts += [("seed rule", method_series(result, "seed-rule")), ("joint", method_series(result, "joint"))]
    for name, rows in parts:
        series.setdefault(name, []).extend((j1, j2, att, image_level) for j1, j2, att in rows)


def _method(name: str, rows: list, truth, start) -> MethodSeries:
    from shipstar.pipeline import attitude_errors_arcsec

    err = attitude_errors_arcsec([(j1, j2, a) for j1, j2, a, _ in rows], truth)
    sig = np.array([a.sigma_rad * RAD2ASEC if a.solved else np.full(3, np.nan) for _, _, a, _ in rows]).reshape(-1, 3)
    t = np.array([((j1 - start[0]) + (j2 - start[1])) * 86400.0 for j1, j2, _, _ in rows])
    return MethodSeries(name, t, err, sig, np.array([r[3] for r in rows], bool))


def _medians(frames: list) -> tuple[float, float]:
    ok = [fr for fr in frames if fr.solved]
    if not ok:
        return math.nan, math.nan
    sig = [float(np.sqrt(np.mean(fr.horizontal.sigma_rad[fr.horizontal.inliers] ** 2))) * RAD2ASEC for fr in ok]
    return float(np.median([fr.n_used for fr in ok])), float(np.median(sig))


def _sensor_stats(name: str, frames: list, n_image: int) -> SeaSensor:
    img, cen = _medians(frames[:n_image]), _medians(frames[n_image:])
    fails = tuple(f"{fr.label}: {fr.reason}" for fr in frames if not fr.solved)
    return SeaSensor(name, len(frames), n_image, sum(fr.solved for fr in frames),
                     {"image": img[0], "centroid": cen[0]}, {"image": img[1], "centroid": cen[1]}, fails[:5])


def _boresight_tracks(spec) -> dict:
    """True boresight (az, el) in degrees of each sensor over the session, 1 s steps."""
    from shipstar.frames import az_el_from_unit

    t = np.arange(0.0, spec.duration_s + 1e-9, 1.0)
    C_hd = spec.motion.C_hor_from_deck(t)
    out = {}
    for s in spec.sensors:
        az, el = az_el_from_unit((C_hd @ s.C_deck_from_sensor)[..., :, 0])
        out[s.name] = np.stack([az, el], axis=-1) * RAD2DEG
    return out


def run_sea(session_cfg, spec, installations: dict, image_level_s: float, out_dir: Path, bar,
            databases) -> SeaOutcome:
    """Process the sea session with the dock-calibrated installations.

    Parameters
    ----------
    session_cfg : shipstar.config.SessionConfig
    spec : SessionSpec
        The simulated session (possibly shortened).
    installations : dict of sensor name -> Installation
    image_level_s : float
    out_dir : Path
        Where track.csv, weather.csv and truth.csv are written.
    bar : Progress
    databases : dict of sensor name -> StarDatabase
    """
    from shipstar._demo._frames import make_frame, n_image_level
    from shipstar.pipeline import SensorConfig, Track, TruthTable, WeatherTable, process_session

    files = write_session_tables(spec, out_dir)
    track, weather = Track.read_csv(files["track"]), WeatherTable.read_csv(files["weather"])
    truth = TruthTable.read_csv(files["truth"])
    configs = [SensorConfig(s.name, s.camera, installations[s.name]) for s in spec.sensors]
    options = session_cfg.pipeline_options()
    series, frames, roles = {}, {s.name: [] for s in spec.sensors}, ("", "")
    n, n_img = min(len(spec.times_s(s)) for s in spec.sensors), n_image_level(spec, image_level_s)
    for lo, hi, image_level in _chunks(n, n_img):
        made = [[make_frame(spec, j, k, image_level) for k in range(lo, hi)] for j in range(len(spec.sensors))]
        result = process_session(configs, [[m.frame for m in per] for per in made], track, weather, options,
                                 databases=databases, progress=lambda *_: bar.advance())
        _collect(result, series, image_level)
        for name, frs in zip(result.sensors, result.frames):
            frames[name].extend(frs)
        roles = (result.fore_aft_sensor, result.athwartship_sensor)
    start = spec.utc_jd(0.0)
    methods = tuple(_method(name, rows, truth, start) for name, rows in series.items())
    t_truth = truth.t_s + ((truth.jd1_0 - start[0]) + (truth.jd2_0 - start[1])) * 86400.0
    truth_deg = np.stack([truth.heading_rad, truth.pitch_rad, truth.roll_rad], axis=-1) * RAD2DEG
    sensors = tuple(_sensor_stats(name, frames[name], min(n, n_img)) for name in frames)
    return SeaOutcome(methods=methods, sensors=sensors,
                      truth_t_s=t_truth, truth_deg=truth_deg, sensor_tracks_deg=_boresight_tracks(spec),
                      fore_aft_sensor=roles[0], athwartship_sensor=roles[1], files=files)
