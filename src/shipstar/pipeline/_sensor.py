"""One sensor's frames -> sensor attitude in the horizontal frame -> ship attitude.

Per frame (seed 003 steps 1-3, 5-6)::

    read FITS -> extract_stars -> identify (tracking after the first frame)
      -> FrameContext (erfa.apco13 once, at the frame's mid-exposure UTC -- FITS DATE-AVG,
         else DATE-OBS/DATE-BEG, the start, plus EXPTIME/2 -- and the ship's position)
      -> apparent places of the identified stars -> refraction (per star)
      -> C_hor_from_sensor (QUEST-Newton, outlier rejection, covariance)
      -> streaks: measured directions turned to mid-exposure with the sensor's motion
         fitted to its own last frames (causal), solved again
      -> ship attitude with the installation (seed 003 eq. 14-17)

Every extracted object goes to identification, ranked by flux: at sea every star is a
streak (flagged elongated), so nothing is dropped for its shape alone; objects that match
no catalog star within the gates (blends, faint hot pixels) are left unidentified.  Before
that, ``self.conditions`` (:mod:`shipstar.pipeline._conditions`) masks the Moon and the
Sun and drops trails and persistent pixels; a lost frame with too few stars for its
pointing is ``clouded``, with the Moon's mask in the image ``moon in field``; the noise
floor added to each star's sigma is estimated from the residuals (seeing).

Per-frame work outside extraction is kept small: the frame's time was read by
``scan_frames`` (only the image is read here, :func:`shipstar._fitsio.read_fits_image`),
the star database is built once per camera per process, the tracking prior is
extrapolated in plain floats and the identification's unit vectors are reused.

A frame that fails at any step gives a :class:`FrameResult` with ``solved=False`` and
the reason; it never stops the session.

The state a :class:`SensorProcessor` carries from frame to frame is bounded and explicit:
the last two solved frames' J2000 attitudes (the tracking prior) and the last
:data:`~shipstar.pipeline._motion.MOTION_WINDOW_S` seconds of its solved horizontal
attitudes (the streak correction's motion fit); with windowed tracking
(``PipelineOptions.windowed_full_frame_every``) also the last full frame's background
mesh and saturation level and the last solved frame's identified star directions (where
the next frame's windows go).  A frame's result depends on no later frame.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from shipstar.errors import ShipstarError

__all__ = ["FrameResult", "SensorProcessor", "rank_by_flux", "extrapolate_rotation", "resolve_frame",
           "ship_from_horizontal"]

_NAN33 = np.full((3, 3), np.nan)
#: Frames further apart than this (s) do not extrapolate the tracking prior.
_MAX_PRIOR_GAP_S = 2.0
#: The smear hint (:meth:`SensorProcessor._smear_hint_px`) is given from this long (px)
#: (up to the extraction's longest, ``extract._core.MAX_SMEAR_PX``) ...
SMEAR_HINT_MIN_PX = 3.0
#: ... from a motion fit at most this old (s).
_MAX_SMEAR_HINT_GAP_S = 0.5
#: A predicted smear shorter than this (px) is given as a zero hint: the frame's stars are
#: points, and the extraction does not estimate the smear (it takes a frame as smeared
#: only from ``extract._smear.AUTO_SMEAR_MIN_PX``, 3 px: a 0.5 px margin, against the
#: prediction's ~0.1 px error at 3 px).
POINT_HINT_MAX_PX = 2.5
#: A predicted smear shorter than this (px) whose stated error is within
#: ``extract._core.TRUSTED_SMEAR_SIGMA_PX`` is given as a zero hint too: the prediction is
#: then ~0.005 px off, and the margin to the 3 px is that of the extraction's own estimate
#: of the smear (~0.1 px off), which finds such frames unsmeared.
TRUSTED_POINT_HINT_MAX_PX = 2.8
#: The smear hint's error is measured on this many of the last frames: each frame's
#: prediction against the smear of the motion fitted with that frame's own attitude
#: (:meth:`SensorProcessor._smear_sigma_px`).
HINT_CHECK_FRAMES = 5
#: Windowed tracking (``PipelineOptions.windowed_full_frame_every``): the windows must
#: find at least this fraction of the stars the last full frame identified, else the
#: frame is extracted whole (cloud coming, a prediction gone wrong) ...
WINDOW_MIN_FOUND_FRACTION = 0.7
#: ... and at least this many.
WINDOW_MIN_STARS = 6
#: ... looking for each star this far (px) from its predicted place, once the places'
#: common error is removed (``extract._windowed.ACQUIRE_PX``).
WINDOW_SEARCH_PX = 2.0
#: Star databases by camera (``build_database`` costs ~7 ms even when memoised: it
#: derives the magnitude limit and digests the catalog first).
_DATABASES: dict = {}
_MAX_DATABASES = 4


def _database_for(camera):
    """The identification database of ``camera`` (built or loaded once per process)."""
    from shipstar.identify import build_database

    try:
        db = _DATABASES.get(camera)
    except TypeError:                       # an unhashable camera-like object
        return build_database(camera)
    if db is None:
        db = build_database(camera)
        if len(_DATABASES) >= _MAX_DATABASES:
            del _DATABASES[next(iter(_DATABASES))]
        _DATABASES[camera] = db
    return db


def rank_by_flux(flux) -> np.ndarray:
    """Order ``(N,)`` of the objects, largest flux first (stable; non-finite fluxes last)."""
    f = np.asarray(flux, float)
    return np.argsort(np.where(np.isfinite(f), -f, np.inf), kind="stable")


def extrapolate_rotation(C_a, C_b, ratio: float) -> np.ndarray:
    """``C_b @ exp(ratio * log(C_a^T C_b))``: the rotation from ``C_a`` to ``C_b``
    continued by ``ratio`` times itself (body-axis increment; angles below 180 deg).

    Plain-float Rodrigues (no SVD, ~10x faster than the array helpers); the product of
    two rotations is orthonormal to rounding.
    """
    R = (C_a.T @ C_b).tolist()
    sx, sy, sz = R[2][1] - R[1][2], R[0][2] - R[2][0], R[1][0] - R[0][1]
    s2 = math.sqrt(sx * sx + sy * sy + sz * sz)                      # 2 sin(angle)
    if s2 == 0.0:
        return np.array(C_b, dtype=float)
    a = math.atan2(s2, R[0][0] + R[1][1] + R[2][2] - 1.0) * ratio    # atan2(2 sin, 2 cos)
    kx, ky, kz = sx / s2, sy / s2, sz / s2
    s, c = math.sin(a), math.cos(a)
    c1 = 1.0 - c
    step = np.array([[c + c1 * kx * kx, c1 * kx * ky - s * kz, c1 * kx * kz + s * ky],
                     [c1 * kx * ky + s * kz, c + c1 * ky * ky, c1 * ky * kz - s * kx],
                     [c1 * kx * kz - s * ky, c1 * ky * kz + s * kx, c + c1 * kz * kz]])
    return C_b @ step


@dataclass(frozen=True, eq=False)
class _SolveInputs:
    """What the horizontal attitude of a frame was solved from, besides the measured vectors."""

    v_true_hor: np.ndarray          # (N, 3) unrefracted apparent places of the identified stars
    sigma_rad: float | None         # known noise (PipelineOptions.centroid_sigma_px), or None
    weights: np.ndarray | None      # (N,) relative weights from the extraction, or None
    #: (N, 3, 3) information matrices of the measured directions (sensor frame, rad^-2) from
    #: the extraction's centroid covariances (a streak's is larger along the smear), or None
    info_per_rad2: np.ndarray | None = None
    #: (N, 2, 3) maps a direction residual (sensor frame, rad) to its centroid error in units
    #: of the extraction's covariance (without the floor), ``L^-1 J+`` (``_conditions.NoiseModel``)
    whiten_per_rad: np.ndarray | None = None
    #: (N, 2, 2) ``L^-1 L^-T`` (px^-2): a floor's covariance ``f^2 I`` in those units is ``f^2 G``
    floor_gram_per_px2: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class FrameResult:
    """What one frame of one sensor gave.

    Attributes
    ----------
    sensor : str
    index : int
        Position in the sensor's frame sequence.
    label : str
        File name or ``#index``.
    utc_jd1, utc_jd2 : float
        Mid-exposure time.
    solved : bool
        The sensor's horizontal attitude solved.
    reason : str
        Why not ('' when solved).
    identification : str
        ``"given"`` (known HIP numbers), ``"tracking"``, ``"lost_in_space"`` or ``""``.
    n_detected, n_identified : int
        Stars extracted (or given) and identified.
    C_icrs_from_sensor : ndarray (3, 3)
        The identification's J2000 attitude (NaN if not identified or given).
    horizontal : shipstar.attitude._horizontal.HorizontalAttitude or None
        None when the frame failed before the attitude step.
    ship : shipstar.ship.ShipAttitude
        Single-sensor ship attitude (failed when there is no installation).
    site : shipstar.sky.apparent.Site or None
    weather : shipstar.sky.refraction.Weather or None
    elapsed_s : float
        Processing time of the frame.
    exposure_s : float
        The frame's exposure time (``Frame.exposure_s``; NaN when unknown).
    streak_correction_arcsec : float
        Largest turn of a measured star direction by the exposure-motion correction
        (time-averaged streak centroid -> mid-exposure direction, :mod:`shipstar.pipeline._exposure`);
        0 when the frame was not corrected (no exposure time, no installation, below
        0.01''), NaN when it should have been but the sensor's motion was not known yet
        (its first 4 frames, or after a gap).
    solve_inputs : _SolveInputs or None
        The reference stars and weights the attitude was solved with (to solve it again,
        :func:`resolve_frame`); None when the frame failed before the attitude step.
    time_source : str
        How the frame's time was found in its file (:attr:`Frame.time_source`).
    noise_floor_arcsec : float
        The sensor's per-star noise floor (seeing, :class:`~shipstar.pipeline._conditions.NoiseFloor`)
        estimated after this frame, arcsec; NaN for an unsolved frame.
    model_covariance_rad2 : ndarray (3, 3) or None
        The part of ``horizontal.covariance_rad2`` that is common to the frame's stars (the
        streak model's error, :func:`shipstar.pipeline._exposure.streak_model_covariance`),
        sensor axes; None when the frame was not streak-corrected.
    windowed : bool
        Its stars were measured in windows around their predicted places (windowed
        tracking, ``PipelineOptions.windowed_full_frame_every``), not in the whole frame.
    """

    sensor: str
    index: int
    label: str
    utc_jd1: float
    utc_jd2: float
    solved: bool
    reason: str
    identification: str
    n_detected: int
    n_identified: int
    C_icrs_from_sensor: np.ndarray
    horizontal: object
    ship: object
    site: object
    weather: object
    elapsed_s: float
    exposure_s: float = math.nan
    streak_correction_arcsec: float = 0.0
    solve_inputs: _SolveInputs | None = field(default=None, repr=False)
    time_source: str = ""
    noise_floor_arcsec: float = math.nan
    model_covariance_rad2: np.ndarray | None = field(default=None, repr=False)
    windowed: bool = False

    @classmethod
    def failed(cls, sensor: str, index: int, frame, reason: str) -> "FrameResult":
        """A frame that was not processed (skipped, refused, unreadable), with its reason."""
        from shipstar.ship import ShipAttitude

        return cls(sensor, index, frame.label or f"#{index}", frame.utc_jd1, frame.utc_jd2, False, reason, "", 0, 0,
                   _NAN33.copy(), None, ShipAttitude.failed(reason, "single"), None, None, 0.0, frame.exposure_s,
                   time_source=frame.time_source)

    @property
    def C_hor_from_sensor(self) -> np.ndarray:
        return self.horizontal.C_hor_from_sensor if self.solved else _NAN33.copy()

    @property
    def n_used(self) -> int:
        return int(self.horizontal.n_used) if self.solved else 0

    @property
    def rms_arcsec(self) -> float:
        return float(self.horizontal.rms_arcsec) if self.solved else math.nan

    @property
    def utc_iso(self) -> str:
        from shipstar.sky.time import iso_from_utc_jd

        return iso_from_utc_jd(self.utc_jd1, self.utc_jd2, 6)

    def seconds_since(self, jd1: float, jd2: float) -> float:
        """Seconds from the two-part UTC JD ``(jd1, jd2)`` to this frame."""
        return ((self.utc_jd1 - jd1) + (self.utc_jd2 - jd2)) * 86400.0

    def sensor_stars(self, C_deck_from_sensor, C_sensor_correction=None):
        """The frame's inlier stars as :class:`shipstar.ship.SensorStars` for joint fusion.

        ``C_sensor_correction`` (3, 3), optional, turns the measured vectors
        (``w' = C @ w``): used to carry the frame to another time (motion compensation).
        """
        from shipstar.ship import SensorStars

        h = self.horizontal
        keep = h.inliers
        if C_sensor_correction is not None:
            fast = _turned_rows(h, self.model_covariance_rad2, C_sensor_correction)
            if fast is not None:
                w, info, model, rows = fast
                return SensorStars(w_sensor=w, v_hor=h.v_hor[rows], C_deck_from_sensor=C_deck_from_sensor,
                                   sigma_rad=h.sigma_rad[rows], info_per_rad2=info, model_covariance_rad2=model)
        w = h.w_sensor[keep]
        info = None if h.info_per_rad2 is None else h.info_per_rad2[keep]
        model = self.model_covariance_rad2
        if C_sensor_correction is not None:
            R = np.asarray(C_sensor_correction, float)
            w = w @ R.T
            info = None if info is None else R @ info @ R.T
            model = None if model is None else R @ model @ R.T
        return SensorStars(w_sensor=w, v_hor=h.v_hor[keep], C_deck_from_sensor=C_deck_from_sensor,
                           sigma_rad=h.sigma_rad[keep], info_per_rad2=info, model_covariance_rad2=model)


_EMPTY = np.empty(0)


def _turned_rows(h, model, R):
    """:meth:`FrameResult.sensor_stars`'s inlier rows turned by ``R`` in one compiled call
    (``attitude._ckernels.sensor_rows``: the whole method ~9 us against ~22 us with NumPy's
    fancy indexing and stacked products; equal to rounding):
    ``(w, info or None, model or None, rows)``, or None where the NumPy path must run (an
    inlier mask or arrays not as the solver makes them)."""
    from shipstar.attitude import _ckernels

    w_all, keep, info_all = h.w_sensor, h.inliers, h.info_per_rad2
    if not (isinstance(keep, np.ndarray) and keep.dtype == np.bool_ and isinstance(w_all, np.ndarray)
            and w_all.ndim == 2 and w_all.shape[1] == 3 and keep.shape == (w_all.shape[0],)):
        return None
    if info_all is not None and not (isinstance(info_all, np.ndarray) and info_all.shape == (len(keep), 3, 3)):
        return None
    if model is not None and np.shape(model) != (3, 3):
        return None
    rows = np.flatnonzero(keep)
    m = len(rows)
    f64 = np.ascontiguousarray
    w = np.empty((m, 3))
    info = None if info_all is None else np.empty((m, 3, 3))
    model_out = None if model is None else np.empty((3, 3))
    _ckernels.sensor_rows(f64(w_all, dtype=float), _EMPTY if info_all is None else f64(info_all, dtype=float),
                          _EMPTY if model is None else f64(model, dtype=float), rows.astype(np.int64, copy=False),
                          f64(R, dtype=float), w, _EMPTY if info is None else info,
                          _EMPTY if model_out is None else model_out)
    return w, info, model_out, rows


def _cross3(a, b) -> np.ndarray:
    """``np.cross(a, b)`` of two 3-vectors, the same numbers (each component one product
    less another, rounded as NumPy rounds them), in ~1 us against NumPy's ~18 us."""
    a0, a1, a2 = (float(x) for x in a)
    b0, b1, b2 = (float(x) for x in b)
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def direction_info(camera, xy_px, cov_px2, shape=None, w_sensor=None, floor_px: float = 0.0):
    """Information matrices of the directions ``camera.unproject(xy_px)`` whose centroids
    have covariances ``cov_px2`` (N, 2, 2), times the error shape ``shape`` (2, 2), plus a
    floor ``floor_px`` in quadrature.

    With ``J`` (3 x 2) the derivative of the unit direction by the pixel position and
    ``L L^T = cov`` (Cholesky), the centroid's covariance is ``L S L^T + f^2 I`` and the
    direction's information ``J+^T (L S L^T + f^2 I)^-1 J+``, ``J+ = (J^T J)^-1 J^T``.  ``J`` is
    the pinhole's, ``(I - w w^T) [[0, 0], [0, -p], [p, 0]] w_x / f`` (x right turns the
    direction towards +Z, y down towards -Y): the distortion changes it by its gradient,
    under 1e-3 of it, and so the weights by as little.

    Parameters
    ----------
    camera : shipstar.camera.Camera
    xy_px : ndarray, shape (N, 2)
    cov_px2 : ndarray, shape (N, 2, 2)
    shape : ndarray, shape (2, 2), optional
    w_sensor : ndarray, shape (N, 3), optional
        ``camera.unproject(xy_px)`` when already known.
    floor_px : float
        1 sigma per axis, px.

    Returns
    -------
    info_per_rad2 : ndarray, shape (N, 3, 3)
        Sensor frame, rad^-2.
    whiten_per_rad : ndarray, shape (N, 2, 3)
        ``L^-1 J+``: a direction residual in units of the centroid's ``cov`` (without ``shape``
        and floor).
    floor_gram_per_px2 : ndarray, shape (N, 2, 2)
        ``G = L^-1 L^-T``: the floor's covariance in those units is ``f^2 G``.
    """
    from shipstar.attitude import _ckernels

    w = np.ascontiguousarray(camera.unproject(xy_px) if w_sensor is None else w_sensor, dtype=np.float64)
    cov = np.ascontiguousarray(cov_px2, dtype=np.float64)
    S = np.ascontiguousarray(np.eye(2) if shape is None else shape, dtype=np.float64)
    n = len(w)
    if w.shape == (n, 3) and cov.shape == (n, 2, 2) and S.shape == (2, 2):
        info, whiten, gram = np.empty((n, 3, 3)), np.empty((n, 2, 3)), np.empty((n, 2, 2))
        # compiled, in closed form: _direction_info_python's values to rounding
        if _ckernels.direction_info(w, cov, S, info, whiten, gram, n, camera.pixel_mm / camera.f_mm,
                                    float(floor_px) ** 2) == 0:
            return info, whiten, gram
    return _direction_info_python(camera, xy_px, cov_px2, shape, w, floor_px)


def _direction_info_python(camera, xy_px, cov_px2, shape=None, w_sensor=None, floor_px: float = 0.0):
    """:func:`direction_info` in NumPy (LAPACK's factors and solves: the compiled kernel's
    reference; it also raises, as LAPACK does, on a covariance not positive definite)."""
    w = camera.unproject(xy_px) if w_sensor is None else np.asarray(w_sensor, float)
    k = camera.pixel_mm / camera.f_mm * w[:, 0]                      # rad per px along each axis
    P = np.eye(3) - w[:, :, None] * w[:, None, :]
    J = np.stack([P[:, :, 2] * k[:, None], -P[:, :, 1] * k[:, None]], axis=-1)   # (N, 3, 2)
    Jt = np.swapaxes(J, 1, 2)
    Jp = np.linalg.solve(Jt @ J, Jt)                                  # (N, 2, 3)
    L = np.linalg.cholesky(np.asarray(cov_px2, float))
    whiten = np.linalg.solve(L, Jp)
    Li = np.linalg.inv(L)
    G = Li @ np.swapaxes(Li, 1, 2)
    S = np.eye(2) if shape is None else np.asarray(shape, float)
    # (L S L^T + f^2 I)^-1 = L^-T (S + f^2 G)^-1 L^-1: info = whiten^T (S + f^2 G)^-1 whiten
    Vi = np.linalg.inv(S[None] + float(floor_px) ** 2 * G)
    return np.swapaxes(whiten, 1, 2) @ Vi @ whiten, whiten, G


def _solve_hor(w_sensor, inputs: _SolveInputs, weather, options, v_ref_hor=None):
    """``sensor_attitude_hor`` of measured vectors ``w_sensor`` (N, 3) against ``inputs``
    (``v_ref_hor``: the refracted references of an earlier solve of the same stars)."""
    from shipstar.attitude._horizontal import sensor_attitude_hor

    return sensor_attitude_hor(w_sensor, inputs.v_true_hor, weather, model=options.refraction_model,
                               refraction=options.refraction, sigma_rad=inputs.sigma_rad, weights=inputs.weights,
                               info_per_rad2=inputs.info_per_rad2,
                               reject_outliers=options.reject_outliers,
                               max_residual_arcsec=options.max_residual_arcsec, v_ref_hor=v_ref_hor)


def ship_from_horizontal(h, installation):
    """Single-sensor ship attitude of a horizontal attitude ``h`` (failed when ``h`` is, or
    without an installation)."""
    from shipstar.ship import ShipAttitude, ship_attitude_from_sensor

    if not h.solved:
        return ShipAttitude.failed(h.reason, "single")
    if installation is None:
        return ShipAttitude.failed("no installation (dock calibration)", "single")
    return ship_attitude_from_sensor(h.C_hor_from_sensor, installation.C_deck_from_sensor, h.covariance_rad2,
                                     n_stars=h.n_used)


def resolve_frame(fr: FrameResult, w_sensor, installation, options, streak_correction_arcsec: float,
                  model_covariance=None) -> FrameResult:
    """``fr`` solved again from corrected measured vectors ``w_sensor`` (N, 3), one per row
    of ``fr.horizontal.w_sensor``, against the same reference stars, weights and weather.

    Parameters
    ----------
    fr : FrameResult
        A frame whose horizontal attitude was solved (``fr.solve_inputs`` set).
    w_sensor : (N, 3) array
    installation : Installation or None
    options : PipelineOptions
    streak_correction_arcsec : float
        Recorded in the result (:attr:`FrameResult.streak_correction_arcsec`).
    model_covariance : callable, optional
        ``model_covariance(C_hor_from_sensor_before, C_hor_from_sensor_after) -> (3, 3)``
        (sensor axes, rad^2; :func:`~shipstar.pipeline._exposure.streak_model_covariance`):
        when the new solve succeeds, a frame-level covariance added to its attitude's and
        recorded apart as ``model_covariance_rad2`` for the joint solution (its stars'
        weights cannot carry it); the ship attitude is computed once, from the sum.
    """
    t0 = time.perf_counter()
    # the same stars, weather and model: their refracted references are the first solve's
    h = _solve_hor(w_sensor, fr.solve_inputs, fr.weather, options, v_ref_hor=fr.horizontal.v_hor)
    extra = {}
    if model_covariance is not None and h.solved:
        cov_rad2 = model_covariance(fr.horizontal.C_hor_from_sensor, h.C_hor_from_sensor)
        h = replace(h, covariance_rad2=h.covariance_rad2 + cov_rad2)
        extra["model_covariance_rad2"] = np.asarray(cov_rad2, float)
    ship = ship_from_horizontal(h, installation)
    return replace(fr, solved=bool(h.solved), reason=h.reason, horizontal=h, ship=ship,
                   elapsed_s=fr.elapsed_s + time.perf_counter() - t0,
                   streak_correction_arcsec=float(streak_correction_arcsec), **extra)


class _SmearPrediction(NamedTuple):
    """A frame's smear prediction, kept for its check (:meth:`SensorProcessor._check_hint`)."""

    t_s: float                      # the frame's mid-exposure time, s since the session start
    exposure_s: float
    gap_s: float                    # how far the motion fit was extrapolated to it, s
    smear_px: np.ndarray            # (2,) (dx, dy) at the image centre
    omega_rad_per_s: np.ndarray     # (3,) the fit's rate at t_s, sensor axes


class SensorProcessor:
    """Processes one sensor's frames in time order (keeps the tracking state).

    Parameters
    ----------
    config : SensorConfig
    track : shipstar.pipeline._tables.Track
    weather : shipstar.pipeline._tables.WeatherTable
    options : PipelineOptions
    database : shipstar.identify.StarDatabase, optional
        Built for the camera on first need (``build_database``, disk-cached).
    lookup : StarLookup, optional
        Catalog lookup of identified stars (default: all of Hipparcos).
    """

    def __init__(self, config, track, weather, options, *, database=None, lookup=None):
        from shipstar.pipeline._stars import default_lookup

        from shipstar.pipeline._motion import MotionWindow

        self.config = config
        self.track = track
        self.weather_table = weather
        self.options = options
        self._database = database
        self.lookup = default_lookup() if lookup is None else lookup
        self._history: list = []          # (t_s, C_icrs_from_sensor) of the last solved frames
        # the last prior and site worked out (a frame's extraction and its identification or
        # attitude ask for the same ones): (t_s, the history it came from, prior) and
        # (utc_jd1, utc_jd2, site)
        self._prior_memo = None
        self._site_memo = None
        # the streak correction's motion fit: this sensor's last solved attitudes (sensor axes)
        correct = options.streak_correction and config.installation is not None
        self._motion = MotionWindow(1) if correct else None
        self._motion_fit = None           # its last fit (the next frame's smear hint)
        # the smear hint's own check: the last prediction (_SmearPrediction) and the errors
        # (px, the motion extrapolated by s) of the last HINT_CHECK_FRAMES ones
        self._smear_predicted = None
        self._hint_errors = deque(maxlen=HINT_CHECK_FRAMES)
        cam = config.camera                # the image centre's direction (sensor axes): the hint's star
        self._centre_u = cam.unproject(np.array([[0.5 * (cam.width_px - 1), 0.5 * (cam.height_px - 1)]]))[0]
        # the sky's conditions: Moon/Sun masks, trails, cloud, seeing (pipeline._conditions)
        from shipstar.pipeline._conditions import ConditionMonitor

        self.conditions = ConditionMonitor(config.camera, options)
        self._floor_used_px = options.centroid_floor_px
        self._shape = None
        # windowed tracking: the last full frame's mesh and saturation level, whether the next
        # frame must be whole (after a failure), the stars it identified; the catalog's stars
        # near the field
        self._full_frame = None
        self._whole_next = False
        self._last_full = True
        self._full_n_id = 0
        self._window_stars = None
        self._tracked = None              # (database rows (sorted), their measured ICRS directions (M, 3))

    @property
    def database(self):
        if self._database is None:
            self._database = _database_for(self.config.camera)
        return self._database

    # -- steps ---------------------------------------------------------------------------
    def _measure(self, frame, t_s: float = math.nan, site=None, index: int = 0):
        """``(xy_px (N, 2), sigma_px (N,) or None, cov_px2 (N, 2, 2) or None)``: centroids of
        the frame, largest flux first, their sigmas with the noise floor added in quadrature
        and the extraction's covariances (the floor and shape added by :meth:`_horizontal`,
        ``self._floor_used_px``, ``self._shape``; elongated objects included: at sea every
        star is a streak); the Moon and the
        Sun masked, trails and persistent pixels dropped (``self.conditions``)."""
        from shipstar._fitsio import read_fits_image
        from shipstar.extract._core import frame_extraction

        if frame.xy_px is not None:
            return np.asarray(frame.xy_px, float), None, None
        image = frame.image
        if image is None:
            image = read_fits_image(frame.path)      # the time was read by scan_frames
        cam = self.config.camera
        prior = self._prior(t_s) if math.isfinite(t_s) else None
        if prior is not None and site is None:
            try:
                site = self._site(frame)
            except ShipstarError:
                prior = None
        extrapolated = len(self._history) >= 2 and t_s - self._history[-1][0] <= _MAX_PRIOR_GAP_S
        image = self.conditions.mask(image, frame, site, prior, extrapolated=extrapolated)
        ex = self._windowed(image, frame, index, t_s, prior, extrapolated)
        self._last_full = ex is None
        if ex is None:
            ex, mesh, level = frame_extraction(image, threshold_sigma=self.options.threshold_sigma,
                                               psf_sigma_px=cam.psf_sigma_px, gain_e_per_adu=cam.gain_e_per_adu,
                                               smear_px=self._smear_hint_px(frame, t_s),
                                               smear_sigma_px=self._smear_sigma_px(t_s))
            self._full_frame, self._whole_next = (mesh, level), False
        keep = self.conditions.keep(image, ex, prior)
        order = rank_by_flux(ex.flux_adu)
        order = order[keep[order]]
        sig = ex.xy_sigma_px[order]
        known = np.isfinite(sig)
        sig = np.where(known, sig, 1.0)
        self._shape, f = self.conditions.noise_at(t_s)
        self._floor_used_px = f
        cov = np.where(known[:, None, None], ex.xy_cov_px2[order], np.eye(2))
        # a covariance that is not positive definite (or not finite) is replaced by the star's
        # scalar sigma, isotropic: the anisotropic weights never stop a frame from solving
        a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
        with np.errstate(invalid="ignore"):
            pd = np.isfinite(a) & np.isfinite(b) & np.isfinite(c) & (a > 0) & (c > 0) & (a * c - b * b > 0)
        cov = np.where(pd[:, None, None], cov, sig[:, None, None] ** 2 * np.eye(2))
        return ex.xy_px[order], np.hypot(sig, f), cov

    def _smear_hint_px(self, frame, t_s: float):
        """The smear (dx, dy) px the sensor's motion predicts at the image centre for this
        frame, or None (the extraction then measures it).

        From the motion fitted to this sensor's solved frames up to the last one
        (:meth:`_streaks`), extrapolated by at most :data:`_MAX_SMEAR_HINT_GAP_S`: a star's
        direction moves as ``du/dt = -omega x u`` during the exposure ``T``.  Given only when
        at least :data:`SMEAR_HINT_MIN_PX` long, where the extraction would find the frame
        smeared anyway (it treats estimated smears of 3 px or more as streaks): the hint
        spares it the point-source pass and the smear's estimate, which are then thrown
        away.  The extraction detects with the hint and, unless its stated error
        (:meth:`_smear_sigma_px`) is within ``extract._core.TRUSTED_SMEAR_SIGMA_PX``, measures
        the common smear again from the streaks it finds (docs/extraction.md, *Smeared
        frames*), so a hint a few per cent off costs nothing.  A predicted smear shorter than
        :data:`POINT_HINT_MAX_PX` gives ``(0, 0)``: point sources, the smear's estimate
        skipped (it would have found the frame unsmeared: the same stars); so does one
        shorter than :data:`TRUSTED_POINT_HINT_MAX_PX` whose stated error is trusted
        (:meth:`_smear_sigma_px`).
        """
        from shipstar.extract._core import MAX_SMEAR_PX, trusted_smear

        smear = self._predicted_smear_px(frame, t_s)
        if smear is None:
            return None
        length = math.hypot(*smear)
        if length < POINT_HINT_MAX_PX or (length < TRUSTED_POINT_HINT_MAX_PX
                                          and trusted_smear(self._smear_sigma_px(t_s))):
            return np.zeros(2)
        if not SMEAR_HINT_MIN_PX <= length <= MAX_SMEAR_PX:
            return None
        return smear

    def _predicted_smear_px(self, frame, t_s: float):
        """The smear (dx, dy) px at the image centre that the motion fitted to this sensor's
        solved frames predicts for this frame, of any length (None: no recent fit); kept
        for the hint's check (:meth:`_check_hint`)."""
        fit = self._motion_fit
        exposure_s = frame.exposure_s
        if fit is None or not (math.isfinite(t_s) and math.isfinite(exposure_s) and exposure_s > 0.0) \
                or not 0.0 <= t_s - fit.t_last_s <= _MAX_SMEAR_HINT_GAP_S:
            return None
        omega = fit.omega_at(t_s)
        u0 = self._centre_u
        d = _cross3(omega, u0) * (0.5 * exposure_s)                  # u(t) = u0 - (omega x u0) t
        ends = self.config.camera.project(np.array([u0 + d, u0 - d]))
        smear = ends[1] - ends[0]
        if not np.all(np.isfinite(smear)):
            return None
        self._smear_predicted = _SmearPrediction(t_s, exposure_s, t_s - fit.t_last_s, smear, omega)
        return smear

    def _check_hint(self, omega_rad_per_s, t_s: float) -> None:
        """Record the error of this frame's smear prediction against the smear of the rate
        ``omega_rad_per_s`` (3,, sensor axes) at ``t_s`` of the motion fitted with this
        frame's attitude too (its rate at ``t_s`` then interpolated, not extrapolated: a few
        0.001 px at sea, where the prediction's extrapolation over a frame period is ~0.01 px
        off).  The smears' difference at the image centre, ``|(omega - omega_predicted) x
        u0| T`` in pixels (the projection's scale there, ``f / pixel``; to first order in the
        exposure's turn)."""
        predicted, self._smear_predicted = self._smear_predicted, None
        if predicted is None or predicted.t_s != t_s:
            return
        cam = self.config.camera
        d = _cross3(np.asarray(omega_rad_per_s, float) - predicted.omega_rad_per_s, self._centre_u)
        error_px = math.sqrt(float(d @ d)) * predicted.exposure_s * cam.f_mm / cam.pixel_mm
        if math.isfinite(error_px):
            self._hint_errors.append((error_px, predicted.gap_s))

    def _smear_sigma_px(self, t_s: float):
        """The error (px) of this frame's smear prediction (:meth:`_predicted_smear_px`),
        or None when not known: the largest of the last :data:`HINT_CHECK_FRAMES` frames'
        (:meth:`_check_hint`), when there are that many and this prediction extrapolates
        the motion no further than theirs did.  The extraction takes a hint known to
        ``extract._core.TRUSTED_SMEAR_SIGMA_PX`` (0.05 px) as it is, rather than
        measuring the smear again from the frame's brightest streaks (~0.1 px off)."""
        predicted = self._smear_predicted
        errors = self._hint_errors
        if predicted is None or predicted.t_s != t_s or len(errors) < HINT_CHECK_FRAMES \
                or predicted.gap_s > max(gap for _, gap in errors) + 1e-6:
            return None
        return max(err for err, _ in errors)

    def _windowed(self, image, frame, index: int, t_s: float, prior, extrapolated: bool):
        """The frame's stars measured in windows around the catalog stars the prior
        predicts (:func:`shipstar.extract._windowed.extract_windows`), or None: the frame is
        then extracted whole (windowed tracking off, a full frame due -- every frame whose
        ``index`` in the session is a multiple of ``windowed_full_frame_every``, so that
        the same frames are whole however a night is cut into chunks -- the frame after
        a lost one, no full frame yet, a prior not extrapolated from two solved frames,
        the Moon or the Sun in the field, no motion fit, the camera's PSF or gain
        unknown, the windows refused or finding too few stars)."""
        from shipstar.extract._core import MAX_SMEAR_PX
        from shipstar.extract._windowed import extract_windows

        every = self.options.windowed_full_frame_every
        cam = self.config.camera
        if every <= 1 or index % every == 0 or self._whole_next or self._full_frame is None or prior is None \
                or not extrapolated or self.conditions.discs or cam.psf_sigma_px is None \
                or cam.gain_e_per_adu is None:
            return None
        smear = self._predicted_smear_px(frame, t_s)
        if smear is None or math.hypot(*smear) > MAX_SMEAR_PX:
            return None
        mesh, level = self._full_frame
        result = extract_windows(image, self._predicted_xy_px(prior), mesh=mesh, saturation_adu=level,
                                 smear_px=smear, psf_sigma_px=cam.psf_sigma_px, gain_e_per_adu=cam.gain_e_per_adu,
                                 threshold_sigma=self.options.threshold_sigma, search_px=WINDOW_SEARCH_PX,
                                 smear_sigma_px=self._smear_sigma_px(t_s))
        if not result.ok or len(result.extraction) < max(WINDOW_MIN_STARS,
                                                         WINDOW_MIN_FOUND_FRACTION * self._full_n_id):
            return None
        return result.extraction

    def _predicted_xy_px(self, C_icrs_from_sensor) -> np.ndarray:
        """(M, 2) pixel places of the star database's stars near the field, seen with the
        attitude ``C_icrs_from_sensor`` (off-image ones included; the windows drop them).

        A star the last solved frame identified is put where that frame saw it, turned by
        the attitude's change (its refraction, aberration and the camera's residual
        distortion then cancel: at low elevation differential refraction alone moves the
        catalog's places by pixels across a field); the others at their catalog places."""
        cam = self.config.camera
        if self._window_stars is None:
            u = np.asarray(self.database.u_icrs, dtype=float)
            corners = np.array([[0.0, 0.0], [cam.width_px - 1.0, 0.0], [0.0, cam.height_px - 1.0],
                                [cam.width_px - 1.0, cam.height_px - 1.0]])
            cos_reach = float(np.min(cam.unproject(corners) @ self._centre_u))
            self._window_stars = (u, math.cos(min(math.pi / 2, math.acos(min(1.0, cos_reach)) + 0.02)))
        u, cos_limit = self._window_stars
        C = np.asarray(C_icrs_from_sensor, dtype=float)
        rows = np.flatnonzero(u @ (C @ self._centre_u) > cos_limit)   # within reach of the image centre
        v = u[rows]
        if self._tracked is not None and len(self._tracked[0]):
            seen, v_seen = self._tracked
            k = np.minimum(np.searchsorted(seen, rows), len(seen) - 1)
            hit = seen[k] == rows
            v[hit] = v_seen[k[hit]]
        return cam.project(v @ C)                                     # sensor axes: C^T v, row-wise

    def _prior(self, t_s: float):
        """Predicted C_icrs_from_sensor at ``t_s`` from the last two solved frames (or None);
        the same (read-only) array again when asked again with the same ``t_s`` and history."""
        if not self._history:
            return None
        t_b, C_b = self._history[-1]
        if len(self._history) < 2 or t_s - t_b > _MAX_PRIOR_GAP_S:
            return C_b
        memo = self._prior_memo
        if memo is not None and memo[0] == t_s and memo[1] is self._history:
            return memo[2]
        t_a, C_a = self._history[-2]
        prior = extrapolate_rotation(C_a, C_b, (t_s - t_b) / (t_b - t_a))
        prior.flags.writeable = False
        self._prior_memo = (t_s, self._history, prior)
        return prior

    def _site(self, frame):
        """The track's :class:`~shipstar.sky.apparent.Site` at the frame's time (raises as
        :meth:`Track.site`), worked out once a frame."""
        memo = self._site_memo
        if memo is not None and memo[0] == frame.utc_jd1 and memo[1] == frame.utc_jd2:
            return memo[2]
        site = self.track.site(frame.utc_jd1, frame.utc_jd2)
        self._site_memo = (frame.utc_jd1, frame.utc_jd2, site)
        return site

    def _identify(self, frame, xy, t_s: float):
        """``(hip (N,), mode, C_icrs_from_sensor, u_sensor (N, 3) or None)``; hip -1 for
        unidentified stars; ``u_sensor`` the camera's unit vectors of ``xy``."""
        from shipstar.identify import identify_lost_in_space, identify_tracking

        if frame.hip is not None:
            return np.asarray(frame.hip, np.int64), "given", _NAN33.copy(), None
        cam, opt = self.config.camera, self.options
        prior = self._prior(t_s)
        if prior is None:
            idn = identify_lost_in_space(xy, self.database, camera=cam, centroid_error_px=opt.identify_error_px)
        else:
            idn = identify_tracking(xy, self.database, prior, camera=cam, prior_error_deg=opt.prior_error_deg,
                                    centroid_error_px=opt.identify_error_px)
        if not idn.solved:
            raise ShipstarError(f"not identified ({idn.mode}): {idn.reason}")
        self._history = (self._history + [(t_s, np.asarray(idn.C_icrs_from_sensor))])[-2:]
        if self._last_full:
            self._full_n_id = int(np.count_nonzero(np.asarray(idn.hip) >= 0))
        if self.options.windowed_full_frame_every > 1 and idn.focal_scale == 1.0 and idn.radial_k1 == 0.0:
            # where this frame saw its stars (refraction, aberration and the camera's residual
            # distortion included): the next frame's windows are put there, turned by the motion
            rows = np.asarray(idn.star_index)
            m = rows >= 0
            order = np.argsort(rows[m], kind="stable")
            v = np.asarray(idn.u_sensor, dtype=float)[m][order] @ np.asarray(idn.C_icrs_from_sensor).T
            self._tracked = (rows[m][order], v) if np.all(np.isfinite(v)) else None
        else:
            self._tracked = None             # (the camera's own projection does not hold for these)
        # a calibrated camera: the identification's unit vectors are camera.unproject(xy)
        u = idn.u_sensor if idn.focal_scale == 1.0 and idn.radial_k1 == 0.0 else None
        return np.asarray(idn.hip, np.int64), idn.mode, np.asarray(idn.C_icrs_from_sensor), u

    def _horizontal(self, frame, xy, sigma_px, hip, u_sensor=None, site=None, weather=None, cov_px2=None,
                    shape=None):
        from shipstar.sky.apparent import frame_context
        from shipstar.sky.eop import earth_orientation

        cam, opt = self.config.camera, self.options
        site = self._site(frame) if site is None else site
        weather = self.weather_table.weather(frame.utc_jd1, frame.utc_jd2) if weather is None else weather
        # the camera's passband sets the refraction wavelength (camera wavelength_um, docs/camera.md)
        weather = replace(weather, wavelength_um=cam.wavelength_um)
        rows = np.flatnonzero(hip >= 0)
        if rows.size < 2:
            raise ShipstarError(f"{rows.size} identified stars, at least 2 needed")
        # Earth orientation at the frame's own time (13 us): a frame's result must not depend on
        # which frame of the hour came first (chunks and resumes start anywhere)
        ctx = frame_context(frame.utc_jd1, frame.utc_jd2, site, earth_orientation(frame.utc_jd1, frame.utc_jd2))
        v_true = self.lookup.hor(ctx, hip[rows])
        w = cam.unproject(xy[rows]) if u_sensor is None else u_sensor[rows]
        scale = cam.pixel_mm / cam.f_mm
        sigma = None if opt.centroid_sigma_px is None else opt.centroid_sigma_px * scale
        weights = None if (sigma is not None or sigma_px is None) else sigma_px[rows] ** -2.0
        info = whiten = gram = None
        if weights is not None and cov_px2 is not None:
            info, whiten, gram = direction_info(cam, xy[rows], cov_px2[rows], shape, w, self._floor_used_px)
        inputs = _SolveInputs(v_true, sigma, weights, info, whiten, gram)
        return _solve_hor(w, inputs, weather, opt), site, weather, int(rows.size), inputs

    def _ship(self, h):
        return ship_from_horizontal(h, self.config.installation)

    def _streaks(self, fr: FrameResult, t_s: float, extracted: bool = False) -> FrameResult:
        """``fr`` with its measured directions turned to mid-exposure (or unchanged): the
        sensor's rate and acceleration at ``t_s`` from its own attitudes up to this frame.
        ``extracted``: the centroids are this pipeline's streak fits (their along-streak
        offset modelled, ``_exposure.streak_along_factor``), else given time averages.
        ``fr.ship`` is None here: a frame solved again gets the new solve's, else
        :meth:`process` makes the first solve's."""
        from shipstar.pipeline._exposure import StreakModel, streak_corrected

        h = fr.horizontal
        self._motion.add(0, t_s, h.C_hor_from_sensor, h.covariance_rad2)
        self._motion.prune(t_s)
        if not (math.isfinite(fr.exposure_s) and fr.exposure_s > 0.0):
            return fr
        fit = self._motion_fit = self._motion.fit(t_s)
        if fit is None:                          # the sensor's first frames: motion not known yet
            return replace(fr, streak_correction_arcsec=math.nan)
        omega = fit.omega_at(t_s)
        self._check_hint(omega, t_s)
        cam = self.config.camera
        model = StreakModel(cam.psf_sigma_px, cam.pixel_mm / cam.f_mm) if extracted else None
        return streak_corrected(fr, omega, fit.alpha_at(t_s), self.config.installation, self.options, model)

    # -- public ----------------------------------------------------------------------------
    def process(self, frame, index: int, t_s: float, *, site=None, weather=None) -> FrameResult:
        """Process one frame; ``t_s`` is its time in seconds since the session start.

        ``site`` (:class:`~shipstar.sky.apparent.Site`) and ``weather``
        (:class:`~shipstar.sky.refraction.Weather`), when given, are used instead of the
        track's and weather table's values at the frame's time (live operation).
        """
        from shipstar.ship import ShipAttitude

        t0 = time.perf_counter()
        label = frame.label or f"#{index}"
        n_det, n_id, mode, C_icrs = 0, 0, "", _NAN33.copy()
        measured = False
        self._last_full = True
        try:
            xy, sigma_px, cov_px2 = self._measure(frame, t_s, site, index)
            n_det, measured = len(xy), True
            hip, mode, C_icrs, u_sensor = self._identify(frame, xy, t_s)
            shape = self._shape
            h, site, weather, n_id, inputs = self._horizontal(frame, xy, sigma_px, hip, u_sensor, site, weather,
                                                              cov_px2, shape)
        except ShipstarError as exc:
            self._whole_next = True                  # windowed tracking: the next frame whole
            reason = self._lost_reason(str(exc), frame, n_det, t_s) if measured else str(exc)
            return FrameResult(self.config.name, index, label, frame.utc_jd1, frame.utc_jd2, False, reason, mode,
                               n_det, n_id, C_icrs, None, ShipAttitude.failed(reason, "single"), None, None,
                               time.perf_counter() - t0, frame.exposure_s, time_source=frame.time_source,
                               windowed=not self._last_full)
        # a frame the streak correction solves again gets its ship attitude from that solve:
        # the first solve's is made only when the correction leaves the frame as it is
        streaks = self._motion is not None and bool(h.solved)
        fr = FrameResult(self.config.name, index, label, frame.utc_jd1, frame.utc_jd2, bool(h.solved), h.reason,
                         mode, n_det, n_id, C_icrs, h, None if streaks else self._ship(h), site, weather,
                         time.perf_counter() - t0, frame.exposure_s, solve_inputs=inputs,
                         time_source=frame.time_source, windowed=not self._last_full)
        if streaks:
            fr = self._streaks(fr, t_s, extracted=frame.xy_px is None)
            if fr.ship is None:
                fr = replace(fr, ship=self._ship(fr.horizontal))
        if fr.solved:
            self.conditions.add_solved(fr, self._floor_used_px, h, t_s, self._shape)
            fr = replace(fr, noise_floor_arcsec=self.noise_floor_arcsec)
        else:
            self._whole_next = True
            reason = self._lost_reason(fr.reason, frame, n_det, t_s)
            if reason != fr.reason:
                fr = replace(fr, reason=reason, ship=ShipAttitude.failed(reason, "single"))
        return fr

    def _lost_reason(self, reason: str, frame, n_detected: int, t_s: float) -> str:
        """A lost frame's reason: the Moon's or the Sun's, ``clouded`` (too few stars for
        the pointing) or ``reason`` (``pipeline._conditions``)."""
        if frame.hip is not None:
            return reason
        return self.conditions.reason(reason, n_detected, self.database, self._prior(t_s))

    @property
    def noise_floor_arcsec(self) -> float:
        """The per-star noise floor now used (seeing, estimated from the residuals), arcsec."""
        from shipstar.units import RAD2ASEC

        cam = self.config.camera
        return self.conditions.floor_px() * cam.pixel_mm / cam.f_mm * RAD2ASEC
