"""The dock session: simulated frames of each sensor -> pipeline -> installation calibration."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shipstar.frames import installation_angles_from_C_deck_from_sensor, wrap_pi
from shipstar.units import RAD2ASEC, RAD2DEG

__all__ = ["DockSensor", "run_dock", "CHUNK_FRAMES"]

#: Image-level frames processed per pipeline call (bounds the memory held in images).
CHUNK_FRAMES = 20


@dataclass(frozen=True, eq=False)
class DockSensor:
    """One sensor's dock calibration against its truth.

    Attributes
    ----------
    name : str
    true_deg : (3,)
        True installation (az, el, roll), deg.
    installation : shipstar.calibrate.installation.Installation
    deviations_arcsec : (M, 3)
        Each solved frame's installation angles minus the calibrated mean.
    n_frames, n_image_level, n_solved : int
    median_stars_used, median_residual_arcsec : float
    sample : SimFrame
        The first image-level frame (for the report's frame figure).
    sample_result : shipstar.pipeline.FrameResult
    """

    name: str
    true_deg: np.ndarray
    installation: object
    deviations_arcsec: np.ndarray
    n_frames: int
    n_image_level: int
    n_solved: int
    median_stars_used: float
    median_residual_arcsec: float
    sample: object
    sample_result: object

    @property
    def estimated_deg(self) -> np.ndarray:
        i = self.installation
        return np.array([i.az_rad, i.el_rad, i.roll_rad]) * RAD2DEG

    @property
    def bias_arcsec(self) -> np.ndarray:
        """Calibrated minus true (az, el, roll), arcsec."""
        return wrap_pi((self.estimated_deg - self.true_deg) / RAD2DEG) * RAD2ASEC


def _sensor_results(spec, j: int, config, inputs, image_level_s: float) -> tuple[list, object]:
    """All FrameResults of sensor ``j``, processed CHUNK_FRAMES at a time; and its first
    image-level SimFrame."""
    from shipstar._demo._frames import make_frame, n_image_level
    from shipstar.pipeline import process_sensor

    track, weather, options, start, bar, database = inputs
    n, n_img = len(spec.times_s(spec.sensors[j])), n_image_level(spec, image_level_s)
    results, sample = [], None
    for lo in range(0, n, CHUNK_FRAMES):
        chunk = [make_frame(spec, j, k, k < n_img) for k in range(lo, min(n, lo + CHUNK_FRAMES))]
        if sample is None and chunk[0].image_level:
            sample = chunk[0]
        results += process_sensor(config, [c.frame for c in chunk], track, weather, options, start_utc_jd=start,
                                  database=database, progress=lambda *_: bar.advance())
    return results, sample


def _deviations(C_hs: np.ndarray, C_hd: np.ndarray, installation) -> np.ndarray:
    """Per-frame installation angles minus the mean's, arcsec (M, 3)."""
    if len(C_hs) == 0:
        return np.zeros((0, 3))
    a, e, g = installation_angles_from_C_deck_from_sensor(C_hd.T @ C_hs)
    d = np.stack([a - installation.az_rad, e - installation.el_rad, g - installation.roll_rad], axis=-1)
    return wrap_pi(d) * RAD2ASEC


def run_dock(session_cfg, spec, image_level_s: float, bar, databases) -> tuple:
    """Process the dock session of every sensor and calibrate its installation.

    Parameters
    ----------
    session_cfg : shipstar.config.SessionConfig
        ``kind = "dock"``.
    spec : SessionSpec
        The simulated session (possibly shortened).
    image_level_s : float
    bar : Progress
    databases : dict of sensor name -> StarDatabase

    Returns
    -------
    tuple of DockSensor
    """
    from shipstar._demo._frames import n_image_level
    from shipstar.calibrate.installation import calibrate_installation
    from shipstar.pipeline import SensorConfig

    dock = session_cfg.dock_conditions()
    C_hd = dock.C_hor_from_deck
    track, weather, options = session_cfg.track(), session_cfg.weather_table(), session_cfg.pipeline_options()
    start = spec.utc_jd(0.0)
    out = []
    for j, s in enumerate(spec.sensors):
        inputs = (track, weather, options, start, bar, databases.get(s.name))
        results, sample = _sensor_results(spec, j, SensorConfig(s.name, s.camera), inputs, image_level_s)
        ok = np.array([r.solved for r in results], bool)
        C_hs = np.array([r.C_hor_from_sensor for r in results]).reshape(-1, 3, 3)
        inst = calibrate_installation(C_hs, C_hd, solved=ok, sensor=s.name, camera=s.camera.name,
                                      reasons=[r.reason for r in results], session=session_cfg.label,
                                      date_utc=spec.start_utc, dock=dock)
        used = [r for r in results if r.solved]
        true = np.array([s.install_az_rad, s.install_el_rad, s.install_roll_rad]) * RAD2DEG
        out.append(DockSensor(
            name=s.name, true_deg=true, installation=inst, deviations_arcsec=_deviations(C_hs[ok], C_hd, inst),
            n_frames=len(results), n_image_level=n_image_level(spec, image_level_s), n_solved=int(ok.sum()),
            median_stars_used=float(np.median([r.n_used for r in used])) if used else math.nan,
            median_residual_arcsec=float(np.median([r.rms_arcsec for r in used])) if used else math.nan,
            sample=sample, sample_result=results[sample.index] if sample is not None else None))
    return tuple(out)
