"""Frames -> ship attitude over a session (seed 003's measurement flow), see docs/pipeline.md.

Public API::

    Frame(utc_jd1, utc_jd2, label, path=|image=|xy_px=, hip=, exposure_s=)   # one sensor frame
    scan_frames(directory, date_obs_is="start") -> [Frame]   # FITS frames at mid-exposure UTC: DATE-AVG,
                                                             # else DATE-OBS (the start) + EXPTIME/2
    time_sources(frames) -> {time_source: count}             # how the frames' times were found
    SensorConfig(name, camera, installation=None)
    PipelineOptions(refraction_model="erfa", refraction="per-star", ...)
    Track.fixed(lat_deg, lon_deg, height_m, xi_arcsec, eta_arcsec) / Track.read_csv(path)   # ship position
    eop_quality(utc_jd1, utc_jd2) -> EopQuality                     # Earth orientation over the frames
    WeatherTable.constant(p, t) / WeatherTable.read_csv(path)
    process_sensor(config, frames, track, weather, options) -> (FrameResult, ...)
    process_session(configs, frames_per_sensor, track, weather, options) -> SessionResult
    session_summary(result, truth=None) -> dict;  TruthTable.read_csv(path)
    write_attitude_csv(result, path, comments=());  plot_session(result, out_dir, truth=None)

Streak centroids are time averages over the exposure; each sensor's processor turns them
to the mid-exposure directions with the sensor's rate and acceleration fitted to its own
frames up to the frame (``PipelineOptions(streak_correction=True)``, ``pipeline._exposure``).

Streaming (docs/pipeline.md, *The engine*)::

    SensorProcessor(config, track, weather, options).process(frame, index, t_s) -> FrameResult
    SessionEngine(configs, options, start_utc_jd=, reference=).add(frame_result) -> [Emission]
    fit_motion(t_s, C_hor_from_body, covariance_rad2) -> MotionFit      # the motion model
"""

from __future__ import annotations

from shipstar.pipeline._frames import Frame, read_fits_frame, scan_frames, time_sources
from shipstar.pipeline._fusion import Epoch, sensor_roles
from shipstar.pipeline._engine import Emission, SessionEngine
from shipstar.pipeline._motion import MotionFit, MotionWindow, fit_motion
from shipstar.pipeline._options import PipelineOptions, SensorConfig
from shipstar.pipeline._output import ATTITUDE_COLUMNS, attitude_csv_text, write_attitude_csv
from shipstar.pipeline._plots import plot_session
from shipstar.pipeline._sensor import FrameResult, SensorProcessor
from shipstar.pipeline._session import SessionResult, process_sensor, process_session
from shipstar.pipeline._stars import StarLookup
from shipstar.pipeline._stats import attitude_errors_arcsec, method_series, rms_arcsec, session_summary
from shipstar.pipeline._tables import EopQuality, Track, TruthTable, WeatherTable, eop_quality

__all__ = [
    "Frame", "scan_frames", "read_fits_frame", "time_sources",
    "SensorConfig", "PipelineOptions", "Track", "WeatherTable", "TruthTable", "StarLookup",
    "EopQuality", "eop_quality",
    "FrameResult", "Epoch", "SessionResult", "process_sensor", "process_session", "sensor_roles",
    "SensorProcessor", "SessionEngine", "Emission", "MotionFit", "MotionWindow", "fit_motion",
    "session_summary", "attitude_errors_arcsec", "rms_arcsec", "method_series",
    "ATTITUDE_COLUMNS", "attitude_csv_text", "write_attitude_csv", "plot_session",
]
