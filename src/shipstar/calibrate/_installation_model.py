"""Installation records: :class:`DockConditions` and :class:`Installation` (see installation.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.frames import C_deck_from_sensor as _C_deck_from_sensor
from shipstar.frames import C_hor_from_deck as _C_hor_from_deck
from shipstar.frames import installation_angles_from_C_deck_from_sensor

__all__ = ["DockConditions", "Installation"]


@dataclass(frozen=True)
class DockConditions:
    """The known ship attitude and conditions of a dock calibration (for the record).

    Attributes
    ----------
    heading_rad, pitch_rad, roll_rad : float
        True ship attitude (theodolite heading K0, levels psi0, theta0).
    lat_rad, lon_rad, height_m : float
        Dock position.
    pressure_hpa, temperature_c : float
        Weather used for refraction.
    refraction_model, refraction_mode : str
        e.g. ``"erfa"``, ``"per-star"``.
    xi_rad, eta_rad : float
        Deflection of the vertical used (north-south, east-west): the levels follow the
        plumb line, so it enters the installation elevation and roll one to one.
    eop_quality : str
        Worst Earth orientation quality over the session's frames (``"measured"``,
        ``"predicted"``, ``"extrapolated"``; ``""`` when not recorded).
    dut1_error_s, polar_motion_error_arcsec : float
        Largest estimated UT1 - UTC and polar motion errors over the frames (NaN when
        not recorded).
    relative_humidity : float
        Relative humidity used for refraction (NaN when not recorded).
    humidity_source : str
        ``"given"``, or ``"default"`` when 0 (dry air) was assumed (``""``: not recorded).
    wavelength_um : float
        Effective wavelength used for refraction: the camera's ``wavelength_um``.
    eop_source : str
        The IERS table Earth orientation came from (``--eop FILE`` or the packaged one).
    """

    heading_rad: float
    pitch_rad: float = 0.0
    roll_rad: float = 0.0
    lat_rad: float = math.nan
    lon_rad: float = math.nan
    height_m: float = 0.0
    pressure_hpa: float = math.nan
    temperature_c: float = math.nan
    refraction_model: str = ""
    refraction_mode: str = ""
    xi_rad: float = 0.0
    eta_rad: float = 0.0
    eop_quality: str = ""
    dut1_error_s: float = math.nan
    polar_motion_error_arcsec: float = math.nan
    relative_humidity: float = math.nan
    humidity_source: str = ""
    wavelength_um: float = math.nan
    eop_source: str = ""

    @property
    def C_hor_from_deck(self) -> np.ndarray:
        """The dock's true ship attitude matrix (seed 000 eq. 3)."""
        return _C_hor_from_deck(self.heading_rad, self.pitch_rad, self.roll_rad)


@dataclass(frozen=True)
class Installation:
    """A sensor's calibrated installation: ``C_deck_from_sensor = R_y(A) R_z(-E) R_x(-gamma)``.

    Attributes
    ----------
    sensor : str
        Sensor name (e.g. ``"A1"``); the measure step checks it against its frames.
    camera : str
        Camera model name (``Camera.name``) the frames were processed with.
    az_rad, el_rad, roll_rad : float
        Installation azimuth A (from the bow toward starboard), elevation E above the
        deck, roll gamma about the boresight (docs/conventions.md).
    std_arcsec : tuple of 3 floats
        Per-frame standard deviation of (A, E, gamma) over the frames kept (seed 000
        Tables 2-3 report this).
    sem_arcsec : tuple of 3 floats
        Standard error of the mean angles: ``std / sqrt(n_used)``.
    n_frames : int
        Frames in the session (solved or not).
    n_used : int
        Frames in the mean.
    n_failed : int
        Frames whose attitude did not solve.
    n_rejected : int
        Solved frames rejected as outliers by :func:`robust_mean_rotation`.
    session : str
        Session label (e.g. the frames directory).
    date_utc : str
        ISO 8601 UTC time of the first frame.
    dock : DockConditions or None
    warnings : tuple of str
        Accuracy warnings raised while the session was processed (e.g. extrapolated
        Earth orientation), one line each.
    trust_flags : bool
        The calibration was run with ``--trust-flags``: the flags were used where the
        frames' FITS headers contradicted them (docs/file-formats.md, "Header cross-checks").
    header_overrides : tuple of str
        With ``trust_flags``: the contradictions overridden, one line per header card.
    total_arcsec : tuple of 3 floats
        Total uncertainty of (A, E, gamma): the sem and the systematic budget in
        quadrature (docs/uncertainty.md); NaN when not computed.
    uncertainty : tuple of dict
        The budget's rows: ``{"source", "sigma", "az_arcsec", "el_arcsec", "roll_arcsec"}``.
    at_sea : dict or None
        Provenance of an installation re-estimated at sea relative to a reference sensor
        (``calibrate install --at-sea``, cli/_calibrate_at_sea.py): reference sensor, time
        span, the rotation applied (deck axes) with its sigma, the file it was applied to;
        None for a dock calibration.
    """

    sensor: str
    camera: str
    az_rad: float
    el_rad: float
    roll_rad: float
    std_arcsec: tuple = (math.nan, math.nan, math.nan)
    sem_arcsec: tuple = (math.nan, math.nan, math.nan)
    n_frames: int = 0
    n_used: int = 0
    n_failed: int = 0
    n_rejected: int = 0
    session: str = ""
    date_utc: str = ""
    dock: DockConditions | None = field(default=None)
    warnings: tuple = ()
    trust_flags: bool = False
    header_overrides: tuple = ()
    total_arcsec: tuple = (math.nan, math.nan, math.nan)
    uncertainty: tuple = ()
    at_sea: dict | None = field(default=None)

    def __post_init__(self):
        for name in ("az_rad", "el_rad", "roll_rad"):
            value = getattr(self, name)
            if not isinstance(value, (int, float, np.floating)) or not math.isfinite(float(value)):
                raise ShipstarError(f"installation {name} must be a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        if abs(self.el_rad) > 0.5 * math.pi:
            raise ShipstarError(f"installation elevation {math.degrees(self.el_rad):.6g} deg is outside [-90, 90]")
        if not isinstance(self.sensor, str) or not self.sensor:
            raise ShipstarError("installation sensor name must be a non-empty string")
        object.__setattr__(self, "warnings", tuple(" ".join(str(w).split()) for w in self.warnings))
        object.__setattr__(self, "header_overrides", tuple(" ".join(str(w).split()) for w in self.header_overrides))

    @property
    def C_deck_from_sensor(self) -> np.ndarray:
        """The installation matrix (seed 000 eq. 2), shape (3, 3), read-only.

        Made once per installation (the fusion asks for it several times every epoch);
        the angles cannot change (frozen), so neither can it."""
        C = self.__dict__.get("_C_deck_from_sensor")
        if C is None:
            C = _C_deck_from_sensor(self.az_rad, self.el_rad, self.roll_rad)
            C.setflags(write=False)
            object.__setattr__(self, "_C_deck_from_sensor", C)
        return C

    @classmethod
    def from_matrix(cls, sensor: str, camera: str, C_deck_from_sensor, **meta) -> "Installation":
        """Installation with the angles of a given matrix (metadata as keyword arguments)."""
        a, e, g = installation_angles_from_C_deck_from_sensor(np.asarray(C_deck_from_sensor, float))
        return cls(sensor=sensor, camera=camera, az_rad=float(a), el_rad=float(e), roll_rad=float(g), **meta)
