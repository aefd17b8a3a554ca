"""Pipeline settings (:class:`PipelineOptions`) and sensor descriptions (:class:`SensorConfig`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from shipstar.errors import ShipstarError

__all__ = ["PipelineOptions", "SensorConfig"]


def _positive(name: str, value, *, allow_none: bool = False, allow_zero: bool = False) -> None:
    if value is None and allow_none:
        return
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or value < 0 or (value == 0 and not allow_zero):
        raise ShipstarError(f"{name} must be a finite number {'>=' if allow_zero else '>'} 0, got {value!r}")


@dataclass(frozen=True)
class PipelineOptions:
    """How frames are turned into attitudes.

    Attributes
    ----------
    refraction_model : {"erfa", "almanac", "none"}
        ``"erfa"`` (default): within 0.03'' of ray tracing above 15 deg, 60x better than
        the seeds' ``"almanac"`` model there; ``"almanac"`` reproduces the seeds.
    refraction : {"per-star", "boresight", "none"}
        Per-star refraction (seed 000) or the boresight-only correction of its ref. [9].
    centroid_sigma_px : float or None
        Known centroid noise (1-sigma per axis).  None (default): each frame's noise is
        estimated from its star residuals, with relative weights from the extraction's
        per-star Cramer-Rao sigma.
    centroid_floor_px : float
        Added in quadrature to the extraction's per-star sigma (systematic floor); the
        floor estimated from recent residuals (seeing, pixel response, calibration:
        ``pipeline._conditions.NoiseFloor``) replaces it when larger.  The default 0.005 px
        is what the extraction itself needs (its brightest stars' Cramer-Rao sigma is
        0.005 px; the estimate's scatter about a zero floor is +-0.003 px): 0.03 px gave the
        brightest stars too little weight, their sigmas 1.3x too large and the
        attitude 1.3-1.7x less accurate in image-level sessions (docs/pipeline.md, *Streaks*).
    threshold_sigma : float
        Star detection threshold (``shipstar.extract.extract_stars``).
    identify_error_px : float
        Centroid error bound used by the identification gates.
    prior_error_deg : float
        Tracking: bound on the error of the predicted attitude (the prediction
        extrapolates the last two frames' rate).
    max_pair_offset_s : float
        Largest time difference between paired frames of two sensors.
    compensate_motion : bool
        Propagate the other sensors' frames to the reference sensor's frame time with
        the deck rate estimated from the frames (see docs/pipeline.md).
    streak_correction : bool
        Turn each frame's measured star directions (time averages over the exposure) to
        the mid-exposure directions with the deck's rate and angular acceleration
        estimated from the frames, and solve again (docs/pipeline.md, *Streaks*); needs
        the installation and the frame's exposure time (FITS ``EXPTIME``).
    reject_outliers : bool
    max_residual_arcsec : float or None
        Absolute star residual threshold (default: 5 sigma of the frame's scatter).
    windowed_full_frame_every : int
        Windowed tracking (``extract._windowed``, docs/pipeline.md *Windowed tracking*):
        a tracked frame's stars are measured only in windows around their predicted
        places; every frame whose index in the session is a multiple of this, the frame
        after a lost one, and a frame whose windows fall short are extracted whole (0,
        the default: every frame whole).
    """

    refraction_model: str = "erfa"
    refraction: str = "per-star"
    centroid_sigma_px: float | None = None
    centroid_floor_px: float = 0.005
    threshold_sigma: float = 5.0
    identify_error_px: float = 1.0
    prior_error_deg: float = 0.5
    max_pair_offset_s: float = 0.06
    compensate_motion: bool = True
    streak_correction: bool = True
    reject_outliers: bool = True
    max_residual_arcsec: float | None = None
    windowed_full_frame_every: int = 0

    def __post_init__(self):
        from shipstar.attitude._horizontal import REFRACTION_MODES
        from shipstar.sky.refraction import MODELS

        if self.refraction_model not in MODELS:
            raise ShipstarError(f"unknown refraction model {self.refraction_model!r}; choose one of {', '.join(MODELS)}")
        if self.refraction not in REFRACTION_MODES:
            raise ShipstarError(f"unknown refraction mode {self.refraction!r}; choose one of "
                                f"{', '.join(REFRACTION_MODES)}")
        _positive("centroid_sigma_px", self.centroid_sigma_px, allow_none=True)
        _positive("centroid_floor_px", self.centroid_floor_px, allow_zero=True)
        _positive("threshold_sigma", self.threshold_sigma)
        _positive("identify_error_px", self.identify_error_px)
        _positive("prior_error_deg", self.prior_error_deg)
        _positive("max_pair_offset_s", self.max_pair_offset_s, allow_zero=True)
        _positive("max_residual_arcsec", self.max_residual_arcsec, allow_none=True)
        n = self.windowed_full_frame_every
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise ShipstarError(f"windowed_full_frame_every must be a whole number of frames >= 0, got {n!r}")


@dataclass(frozen=True, eq=False)
class SensorConfig:
    """One sensor: its name, camera model and (after dock calibration) installation.

    Attributes
    ----------
    name : str
    camera : shipstar.camera.Camera
    installation : shipstar.calibrate.installation.Installation or None
        None while calibrating (then no ship attitude is computed).
    """

    name: str
    camera: object
    installation: object | None = None

    def __post_init__(self):
        from shipstar.camera import Camera

        if not isinstance(self.name, str) or not self.name:
            raise ShipstarError("sensor name must be a non-empty string")
        if not isinstance(self.camera, Camera):
            raise ShipstarError(f"sensor {self.name}: camera must be a shipstar.camera.Camera")
        inst = self.installation
        if inst is not None:
            if inst.sensor != self.name:
                raise ShipstarError(f"installation for sensor {inst.sensor!r} given for sensor {self.name!r}")
            if inst.camera != self.camera.name:
                raise ShipstarError(f"sensor {self.name}: installation was calibrated with camera {inst.camera!r}, "
                                    f"but the camera given is {self.camera.name!r}")
