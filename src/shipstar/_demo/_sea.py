"""The session at sea: simulated frames -> pipeline (per sensor, seed rule, joint) -> errors vs truth.

The frames are made one at a time as the stream needs them (the image-level part, the
session's first ``image_level_s``, rendered; the rest at centroid level) and go through
the streaming engine exactly as ``shipstar measure`` and ``shipstar live`` run it: each
sensor's :class:`~shipstar.pipeline.SensorProcessor`, then one
:class:`~shipstar.pipeline.SessionEngine` for the whole session, so at most a frame's
image is in memory and nothing restarts between the image-level and centroid-level
parts.  The track, weather and truth tables are written as CSV files into the output
directory and read back with the pipeline's readers, exactly as a user's files would be.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shipstar.units import RAD2ASEC, RAD2DEG

__all__ = ["MethodSeries", "SeaSensor", "SeaOutcome", "run_sea", "write_session_tables"]


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


def _frames_in_time_order(spec, n: int, n_img: int):
    """``(sensor index, k, Frame)`` of every sensor's first ``n`` frames, made as needed,
    in time order (sensor order at equal times); frames ``k < n_img`` rendered."""
    from shipstar._demo._frames import make_frame

    times = [spec.times_s(s)[:n] for s in spec.sensors]
    order = sorted((float(t[k]), j, k) for j, t in enumerate(times) for k in range(n))
    for _, j, k in order:
        yield j, k, make_frame(spec, j, k, k < n_img).frame


def _collect(emission, names, series: dict, n_img: int) -> None:
    """Add an emission's single-sensor rows and fused rows to the method series."""
    for fr in emission.frames:
        series.setdefault(f"single {fr.sensor}", []).append((fr.utc_jd1, fr.utc_jd2, fr.ship, fr.index < n_img))
    e = emission.epoch
    if e is not None and len(names) > 1:
        image_level = e.frame_index[0] < n_img
        series.setdefault("seed rule", []).append((e.utc_jd1, e.utc_jd2, e.seed_rule, image_level))
        series.setdefault("joint", []).append((e.utc_jd1, e.utc_jd2, e.joint, image_level))


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
    from shipstar._demo._frames import n_image_level
    from shipstar.pipeline import SensorConfig, SensorProcessor, SessionEngine, Track, TruthTable, WeatherTable
    from shipstar.pipeline._fusion import sensor_roles

    files = write_session_tables(spec, out_dir)
    track, weather = Track.read_csv(files["track"]), WeatherTable.read_csv(files["weather"])
    truth = TruthTable.read_csv(files["truth"])
    configs = [SensorConfig(s.name, s.camera, installations[s.name]) for s in spec.sensors]
    options = session_cfg.pipeline_options()
    names = [c.name for c in configs]
    n, n_img = min(len(spec.times_s(s)) for s in spec.sensors), n_image_level(spec, image_level_s)
    start = spec.utc_jd(0.0)
    procs = [SensorProcessor(c, track, weather, options, database=databases.get(c.name)) for c in configs]
    engine = SessionEngine(configs, options, start_utc_jd=start)
    series, frames = {f"single {name}": [] for name in names}, {name: [] for name in names}
    for j, k, frame in _frames_in_time_order(spec, n, n_img):
        fr = procs[j].process(frame, k, frame.seconds_since(*start))
        frames[names[j]].append(fr)
        bar.advance()
        for emission in engine.add(fr):
            _collect(emission, names, series, n_img)
    for emission in engine.finish():
        _collect(emission, names, series, n_img)
    fore, athw = sensor_roles(configs)
    roles = (names[fore] if fore >= 0 else "", names[athw] if athw >= 0 else "")
    start = spec.utc_jd(0.0)
    methods = tuple(_method(name, rows, truth, start) for name, rows in series.items())
    t_truth = truth.t_s + ((truth.jd1_0 - start[0]) + (truth.jd2_0 - start[1])) * 86400.0
    truth_deg = np.stack([truth.heading_rad, truth.pitch_rad, truth.roll_rad], axis=-1) * RAD2DEG
    sensors = tuple(_sensor_stats(name, frames[name], min(n, n_img)) for name in frames)
    return SeaOutcome(methods=methods, sensors=sensors,
                      truth_t_s=t_truth, truth_deg=truth_deg, sensor_tracks_deg=_boresight_tracks(spec),
                      fore_aft_sensor=roles[0], athwartship_sensor=roles[1], files=files)
