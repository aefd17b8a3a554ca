"""Intrinsic calibration of a star sensor from star frames alone (issue 6; seed 002).

The angle between two stars does not depend on the sensor's attitude, so matched star
frames calibrate the focal length, the principal point and the Weng distortion without
any laboratory equipment (docs/calibration-intrinsic.md)::

    frames = [calibration_frame(xy_px, hip, "2024-03-15T20:16:00", site=site, weather=w), ...]
    cal = calibrate_intrinsics(frames, camera_preset("seed002"), method="joint")
    cal.camera, cal.sigma, cal.rms_after_rad, cal.supported_distortion_terms

Frames taken on the ground need their observing site (refraction changes interstar
angles by ~8'' across a 4 deg field at 45 deg elevation); frames without one are
refused unless they are declared taken above the atmosphere (``in_space=True``) or are
simulated in space (catalog places).  By default only the distortion terms the data
support are fitted (``terms="auto"``): a Weng term fitted to noise drags the principal
point along the decentring valley (20-30 px on a distortion-free 8 deg camera).

Methods:

``"cosine"``, ``"sine"``
    Seed 002: observation equations on the cosines (eq. 3a) or sines (eq. 3b-6) of the
    interstar angles, batch least squares over all frames, the two-step iteration (f and
    principal point with the distortion fixed, then the distortion with them fixed).
    With ``terms=()`` it is the seed's plain method (its ref. [11]: f and principal point
    only); with distortion terms it is the seed's "improved" method.
``"joint"``
    All parameters at once by Levenberg-Marquardt with a Huber loss, on the per-star
    directions with a free attitude per frame (``attitudes=True``, the maximum-likelihood
    problem for independent centroid errors) or on the interstar angles.

Every method reports 1-sigma uncertainties and correlations from the sandwich covariance
of its own equations (the interstar residuals are correlated: each star is in many
pairs), with the centroid noise estimated from the residuals, and which distortion terms
the data support (:mod:`shipstar.calibrate._intrinsics_select`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from shipstar.calibrate._intrinsics_io import LoadedFrames, load_calibration_frames
from shipstar.calibrate._intrinsics_model import PARAM_NAMES, TERM_FIELDS, TERMS, ParamSpace
from shipstar.calibrate._intrinsics_pairs import StarSet
from shipstar.calibrate._intrinsics_plot import plot_residuals
from shipstar.calibrate._intrinsics_refs import PLACES, reference_directions
from shipstar.camera import Camera
from shipstar.errors import ShipstarError
from shipstar.units import RAD2ASEC

__all__ = [
    "METHODS", "DISTORTION_TERMS", "PARAM_NAMES", "MAX_EDGE_SIGMA_PX_PER_PX", "REFERENCE_PLACES",
    "CalibrationFrame", "IntrinsicCalibration", "check_reference_places",
    "calibrate_intrinsics", "calibration_frame", "reference_directions", "PLACES",
    "interstar_rms_rad", "residual_vectors_px",
    "LoadedFrames", "load_calibration_frames", "plot_residuals",
]

METHODS = ("cosine", "sine", "joint")
#: Weng distortion terms by short name (``"k1"`` -> ``Distortion.k1_per_mm2``, ...)
DISTORTION_TERMS = TERMS
#: Degenerate geometry: some parameter, with 1 px centroid errors, would be uncertain by
#: more than this shift at the image corner (20 well-spread seed 002 frames: ~160 px, all
#: from the weakly observable principal point; stars only within 150 px of the centre:
#: 1.2e5 px)
MAX_EDGE_SIGMA_PX_PER_PX = 1e4
#: How a frame's reference directions were made (:attr:`CalibrationFrame.places`)
REFERENCE_PLACES = ("topocentric", "geocentric", "catalog", "")
#: A frame needs this many matched stars to contribute (3 pairs, 3 constraints)
MIN_STARS_PER_FRAME = 3
#: Independent constraints (2 per star, minus 3 per frame for its attitude) per parameter
MIN_CONSTRAINTS_PER_PARAM = 3


# ---------------------------------------------------------------------------------------
# Input frames
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class CalibrationFrame:
    """One frame's identified stars and their reference directions.

    Attributes
    ----------
    xy_px : ndarray (N, 2)
        Measured centroids (x right, y down, top-left pixel centre (0, 0)).
    v_ref : ndarray (N, 3)
        Reference directions of the same stars as the sensor sees them (apparent places,
        refracted on the ground), in any one frame of axes: only angles between them
        are used.
    hip : ndarray (N,)
        HIP numbers (-1 where unknown); used for messages and duplicate checks.
    label : str
        Where the frame came from (file name), for messages.
    camera_name : str or None
        Sensor that took the frame (FITS INSTRUME); frames of different cameras are refused.
    image_shape_hw : (int, int) or None
        Image size, checked against the camera.
    places : str
        How ``v_ref`` was made (:func:`calibration_frame` sets it): ``"topocentric"``
        (apparent places at the observing site, refracted unless the model is
        ``"none"``), ``"geocentric"`` (apparent places without a site: right only above
        the atmosphere), ``"catalog"`` (catalog directions: simulated frames in space)
        or ``""`` (given by the caller, taken as it is).
    """

    xy_px: np.ndarray
    v_ref: np.ndarray
    hip: np.ndarray = None
    label: str = ""
    camera_name: str | None = None
    image_shape_hw: tuple | None = None
    places: str = ""

    def __post_init__(self):
        where = f"frame {self.label!r}" if self.label else "frame"
        xy = _float_array(self.xy_px, 2, f"{where}: xy_px")
        v = _float_array(self.v_ref, 3, f"{where}: v_ref")
        if len(xy) != len(v):
            raise ShipstarError(f"{where}: {len(xy)} centroids but {len(v)} reference directions")
        norm = np.linalg.norm(v, axis=1)
        if np.any(norm < 1e-12):
            raise ShipstarError(f"{where}: a reference direction is the zero vector")
        hip = np.full(len(xy), -1, np.int64) if self.hip is None else np.asarray(self.hip)
        if hip.shape != (len(xy),) or hip.dtype.kind not in "iu":
            raise ShipstarError(f"{where}: hip must be {len(xy)} integers")
        known = hip[hip >= 0]
        if len(np.unique(known)) != len(known):
            dup = known[np.argmax([np.sum(known == h) for h in known])]
            raise ShipstarError(f"{where}: HIP {int(dup)} is listed twice")
        object.__setattr__(self, "xy_px", xy)
        object.__setattr__(self, "v_ref", v / norm[:, None])
        object.__setattr__(self, "hip", hip.astype(np.int64))
        if self.image_shape_hw is not None:
            object.__setattr__(self, "image_shape_hw", tuple(int(n) for n in self.image_shape_hw))
        if self.places not in REFERENCE_PLACES:
            raise ShipstarError(f"{where}: places must be one of {', '.join(map(repr, REFERENCE_PLACES))}, "
                                f"got {self.places!r}")

    def __len__(self) -> int:
        return len(self.xy_px)


def _float_array(value, ncol: int, what: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ShipstarError(f"{what} must be a numeric (N, {ncol}) array") from None
    if arr.ndim != 2 or arr.shape[1] != ncol:
        raise ShipstarError(f"{what} must have shape (N, {ncol}), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ShipstarError(f"{what} has non-finite values")
    return arr


def calibration_frame(xy_px, hip, utc, *, catalog=None, site=None, weather=None,
                      refraction_model: str = "erfa", eop=None, places: str = "apparent",
                      label: str = "", camera_name=None, image_shape_hw=None) -> CalibrationFrame:
    """A :class:`CalibrationFrame` from centroids and HIP numbers at a time.

    Rows with ``hip < 0`` (unidentified) are dropped.  ``utc`` is an ISO 8601 UTC string
    or a two-part Julian date; the reference directions come from
    :func:`reference_directions` (apparent places, refraction with a ``site``; see there
    for ``places``).
    """
    from shipstar.sky.time import utc_jd_from_iso

    xy = _float_array(xy_px, 2, f"frame {label!r}: xy_px")
    hip = np.asarray(hip)
    if hip.shape != (len(xy),) or hip.dtype.kind not in "iu":
        raise ShipstarError(f"frame {label!r}: hip must be {len(xy)} integers")
    jd1, jd2 = utc_jd_from_iso(utc) if isinstance(utc, str) else (float(utc[0]), float(utc[1]))
    keep = hip >= 0
    v = reference_directions(hip[keep], jd1, jd2, catalog=catalog, site=site, weather=weather,
                             refraction_model=refraction_model, eop=eop, places=places)
    kind = "topocentric" if site is not None else ("catalog" if places == "catalog" else "geocentric")
    return CalibrationFrame(xy[keep], v, hip[keep], label, camera_name, image_shape_hw, kind)


# ---------------------------------------------------------------------------------------
# Result
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class IntrinsicCalibration:
    """Result of :func:`calibrate_intrinsics`.

    Attributes
    ----------
    solved : bool
    reason : str
        Why not solved ("" when solved).
    method : str
    camera : Camera
        The calibrated camera (the input camera when not solved).
    fitted : tuple of str
        Parameters estimated (``PARAM_NAMES``: ``f_mm``, ``x0_px``, ``y0_px``,
        ``k1_per_mm2``, ...); the others keep their input values (distortion terms not
        fitted are zero).
    sigma : dict
        1-sigma uncertainty of each fitted parameter (same unit as the parameter).
    correlation : ndarray (P, P)
        Correlation matrix of the fitted parameters, in ``fitted`` order.
    centroid_sigma_px : float
        Centroid noise per axis estimated from the residuals.
    rms_before_rad, rms_after_rad : float
        RMS interstar-angle error (measured minus reference, all pairs of all frames)
        with the input camera and with the calibrated one.
    n_frames, n_stars, n_pairs : int
        Frames, stars and star pairs used.
    iterations : int
        Two-step cycles or Levenberg-Marquardt iterations.
    supported_distortion_terms : tuple of str
        Weng terms (short names) the data support (likelihood-ratio forward selection);
        empty when the check was not run (see ``terms_checked``) or none is supported.
    term_delta_chi2 : dict
        Chi-square drop each term brought in the selection.
    xy_px, residual_before_px, residual_after_px : ndarray (N, 2)
        Every star's centroid and its residual vector (measured minus predicted from the
        reference direction and the frame's attitude), before and after.
    frame_of_star : ndarray (N,)
    input_camera : Camera
        The camera the calibration started from (its residuals are "before").
    terms_checked : bool
        Whether the term-support check ran (``supported_distortion_terms`` means
        something only then).
    """

    solved: bool
    reason: str
    method: str
    camera: Camera
    fitted: tuple
    sigma: dict
    correlation: np.ndarray
    centroid_sigma_px: float
    rms_before_rad: float
    rms_after_rad: float
    n_frames: int
    n_stars: int
    n_pairs: int
    iterations: int
    supported_distortion_terms: tuple
    term_delta_chi2: dict = field(default_factory=dict)
    xy_px: np.ndarray = field(default=None, repr=False)
    residual_before_px: np.ndarray = field(default=None, repr=False)
    residual_after_px: np.ndarray = field(default=None, repr=False)
    frame_of_star: np.ndarray = field(default=None, repr=False)
    input_camera: Camera = field(default=None, repr=False)
    terms_checked: bool = False

    @property
    def fitted_distortion_terms(self) -> tuple:
        """Short names of the Weng terms fitted (``"k1"``, ...)."""
        by_field = {v: k for k, v in TERM_FIELDS.items()}
        return tuple(by_field[n] for n in self.fitted if n in by_field)

    @property
    def unsupported_fitted_terms(self) -> tuple:
        """Fitted Weng terms the term check found unsupported (their values are fitted
        noise); empty when the check did not run."""
        if not self.terms_checked:
            return ()
        return tuple(t for t in self.fitted_distortion_terms if t not in self.supported_distortion_terms)

    @property
    def rms_before_arcsec(self) -> float:
        return self.rms_before_rad * RAD2ASEC

    @property
    def rms_after_arcsec(self) -> float:
        return self.rms_after_rad * RAD2ASEC

    @property
    def values(self) -> dict:
        """Calibrated value of every fitted parameter."""
        full = ParamSpace.for_camera(self.camera, self.fitted)
        return dict(zip(self.fitted, (float(x) for x in full.values(self.camera))))

    def as_json_dict(self) -> dict:
        """The ``shipstar calibrate intrinsics --json`` object (null for undefined numbers)."""
        def num(x):
            return float(x) if x is not None and math.isfinite(x) else None

        cam = self.camera
        params = {"f_mm": cam.f_mm, "x0_px": cam.x0_px, "y0_px": cam.y0_px}
        params.update(cam.distortion.as_dict())
        return {
            "solved": bool(self.solved),
            **({"reason": self.reason} if not self.solved else {}),
            "method": self.method,
            "camera": cam.name,
            "parameters": {k: float(v) for k, v in params.items()},
            "fitted": list(self.fitted),
            "sigma": {k: num(v) for k, v in self.sigma.items()},
            "correlation": [[num(x) for x in row] for row in np.asarray(self.correlation)],
            "centroid_sigma_px": num(self.centroid_sigma_px),
            "rms_before_rad": num(self.rms_before_rad), "rms_before_arcsec": num(self.rms_before_arcsec),
            "rms_after_rad": num(self.rms_after_rad), "rms_after_arcsec": num(self.rms_after_arcsec),
            "n_frames": int(self.n_frames), "n_stars": int(self.n_stars), "n_pairs": int(self.n_pairs),
            "iterations": int(self.iterations),
            "terms_checked": bool(self.terms_checked),
            "supported_distortion_terms": list(self.supported_distortion_terms),
            "unsupported_fitted_terms": list(self.unsupported_fitted_terms),
            "term_delta_chi2": {k: num(v) for k, v in self.term_delta_chi2.items()},
        }


# ---------------------------------------------------------------------------------------
# Checks
# ---------------------------------------------------------------------------------------

def _resolve_terms(terms):
    """``"all"``, ``"auto"``, ``"none"`` or names -> (tuple of short names, auto?)."""
    if isinstance(terms, str):
        key = terms.strip().lower()
        if key == "all":
            return TERMS, False
        if key == "auto":
            return TERMS, True
        if key in ("none", ""):
            return (), False
        terms = [t for t in key.split(",") if t.strip()]
    by_field = {v: k for k, v in TERM_FIELDS.items()}
    out = []
    for t in terms:
        name = str(t).strip()
        short = name if name in TERMS else by_field.get(name)
        if short is None:
            raise ShipstarError(f"unknown distortion term {name!r} (terms: {', '.join(TERMS)}, "
                                "or all, auto, none)")
        if short not in out:
            out.append(short)
    return tuple(t for t in TERMS if t in out), False


def check_reference_places(frames, in_space: bool = False) -> None:
    """Refuse frames whose reference directions do not fit where they were taken.

    A frame without an observing site has no refraction in its references; on the ground
    that bends interstar angles by ~8'' across a 4 deg field at 45 deg elevation and the
    calibration absorbs it into f and the distortion.  Such ``"geocentric"`` frames pass
    only with ``in_space=True``; with it, frames with a site (``"topocentric"``) are
    refused as contradictory.  Catalog places (simulated frames in space) and frames
    whose references the caller made (``places=""``) pass.

    Raises
    ------
    ShipstarError
    """
    for k, fr in enumerate(frames):
        label = getattr(fr, "label", "") or f"#{k}"
        places = getattr(fr, "places", "")
        if places == "geocentric" and not in_space:
            raise ShipstarError(
                f"frame {label!r} has no observing site, so its reference directions have no refraction "
                "(~8'' across a 4 deg field on the ground): give the site (--lat-deg/--lon-deg, or site= to "
                "calibration_frame) or declare frames taken above the atmosphere (--in-space, in_space=True)")
        if places == "topocentric" and in_space:
            raise ShipstarError(f"frame {label!r} has an observing site (taken on the ground), but the frames "
                                "are declared taken in space (--in-space, in_space=True)")


def _check_frames(frames, camera: Camera):
    if not isinstance(camera, Camera):
        raise ShipstarError(f"camera must be a shipstar.camera.Camera, got {type(camera).__name__}")
    frames = list(frames)
    if not frames:
        raise ShipstarError("no frames to calibrate from")
    names = {}
    for k, fr in enumerate(frames):
        if not isinstance(fr, CalibrationFrame):
            raise ShipstarError(f"frames must be CalibrationFrame objects, got {type(fr).__name__}")
        label = fr.label or f"#{k}"
        if fr.camera_name is not None:
            names.setdefault(fr.camera_name, label)
        if fr.image_shape_hw is not None and fr.image_shape_hw != (camera.height_px, camera.width_px):
            h, w = fr.image_shape_hw
            raise ShipstarError(f"frame {label!r} is {w}x{h} px but camera {camera.name!r} is "
                                f"{camera.width_px}x{camera.height_px} px")
        if len(fr) and not camera.in_image(fr.xy_px, margin_px=-1.0).all():
            x, y = fr.xy_px[~camera.in_image(fr.xy_px, margin_px=-1.0)][0]
            raise ShipstarError(f"frame {label!r}: centroid ({x:.1f}, {y:.1f}) lies outside the "
                                f"{camera.width_px}x{camera.height_px} image of camera {camera.name!r}")
    if len(names) > 1:
        (a, fa), (b, fb) = list(names.items())[:2]
        raise ShipstarError(f"frames come from different cameras: {a!r} (frame {fa!r}) and "
                            f"{b!r} (frame {fb!r}); calibrate one camera at a time")
    return frames


def _star_set(frames, n_params: int) -> StarSet:
    usable = [fr for fr in frames if len(fr) >= MIN_STARS_PER_FRAME]
    stars = StarSet.build([(fr.xy_px, fr.v_ref) for fr in usable])
    constraints = int(np.sum(2 * stars.counts - 3)) if usable else 0
    need = MIN_CONSTRAINTS_PER_PARAM * n_params
    if constraints < need:
        raise ShipstarError(
            f"too few stars to calibrate {n_params} parameters: {len(usable)} usable frame(s) "
            f"(>= {MIN_STARS_PER_FRAME} identified stars) with {stars.n_stars} stars give "
            f"{constraints} independent constraints, need at least {need} "
            "(add frames or fit fewer distortion terms)")
    return stars


def _check_geometry(stars: StarSet, camera: Camera, free) -> None:
    """Refuse star sets that cannot constrain the parameters.

    From the normal matrix of the per-star equations at the starting camera: the
    uncertainty each parameter would have with 1 px centroid errors, expressed as the
    shift it causes at the image corner.  Above :data:`MAX_EDGE_SIGMA_PX_PER_PX` (or a
    numerically singular matrix) the geometry is degenerate.  At the distortion-free
    start the decentring terms are *exactly* degenerate with the principal point to first
    order (the gauge described in ``_intrinsics_solve``), so p1 and p2 are left out here.
    """
    from shipstar.calibrate._intrinsics_lsq import linearize
    from shipstar.calibrate._intrinsics_solve import initial_attitudes

    free = tuple(n for n in free if n not in (TERM_FIELDS["p1"], TERM_FIELDS["p2"]))
    space = ParamSpace.for_camera(camera, free)
    try:
        lin = linearize(stars, space, space.values(camera), "star",
                        attitudes=initial_attitudes(stars, camera))
    except np.linalg.LinAlgError:
        lin = None
    sigma = np.full(len(free), np.inf)
    if lin is not None and np.isfinite(lin.A).all():
        As = lin.A * space.scales
        eig, vec = np.linalg.eigh(As.T @ As)
        if eig[0] > eig[-1] * 1e-15:
            sigma = np.sqrt(np.diag((vec / eig) @ vec.T)) * (camera.pixel_mm / camera.f_mm)
    if np.all(sigma <= MAX_EDGE_SIGMA_PX_PER_PX):
        return
    worst = [free[i] for i in np.argsort(-sigma)[:2]]
    size = f"{np.max(sigma):.1e} px" if np.isfinite(np.max(sigma)) else "an unbounded amount"
    raise ShipstarError(
        f"degenerate star geometry: the {stars.n_stars} stars in {stars.n_frames} frame(s) cannot "
        f"constrain {' and '.join(worst)} (a 1 px centroid error would move the image corner by "
        f"{size} through them); use frames with stars spread over the whole image, or fit fewer "
        "distortion terms")


# ---------------------------------------------------------------------------------------
# Metrics
# ---------------------------------------------------------------------------------------

def _angle_errors(stars: StarSet, camera: Camera) -> np.ndarray:
    from shipstar.calibrate._intrinsics_pairs import evaluate

    full = ParamSpace.for_camera(camera, ()).full(())
    return evaluate(stars, full, camera.pixel_mm, (), "angle").r


def interstar_rms_rad(frames, camera: Camera) -> float:
    """RMS over all star pairs of all frames of (reference minus measured) interstar
    angle, the measured angles from ``camera`` (seed 002's Delta_rms)."""
    frames = _check_frames(frames, camera)
    stars = StarSet.build([(fr.xy_px, fr.v_ref) for fr in frames if len(fr) >= 2])
    if stars.n_pairs == 0:
        raise ShipstarError("no star pairs: every frame has fewer than 2 stars")
    r = _angle_errors(stars, camera)
    return float(np.sqrt(np.mean(r * r)))


def residual_vectors_px(stars: StarSet, camera: Camera) -> np.ndarray:
    """Measured minus predicted centroid (N, 2): each frame's QUEST attitude with
    ``camera``, its reference directions projected back into the image."""
    from shipstar.calibrate._intrinsics_solve import initial_attitudes

    att = initial_attitudes(stars, camera)
    v_sensor = np.einsum("nji,nj->ni", att[stars.star_frame], stars.v_ref)   # C^T v
    return stars.xy_px - camera.project(v_sensor)


# ---------------------------------------------------------------------------------------
# The calibration
# ---------------------------------------------------------------------------------------

def calibrate_intrinsics(frames, camera: Camera, *, method: str = "joint", terms="auto",
                         attitudes: bool = True, robust: bool | None = None,
                         check_terms: bool = True, max_cycles: int = 300,
                         in_space: bool = False) -> IntrinsicCalibration:
    """Calibrate focal length, principal point and Weng distortion from star frames.

    Parameters
    ----------
    frames : sequence of CalibrationFrame
        Identified stars with reference directions at their observation times.  Frames
        with fewer than 3 stars are skipped.
    camera : Camera
        The nominal camera: starting point (its distortion is ignored: every method
        starts from none), pixel pitch, image size; fixed parameters keep its values.
    method : {"cosine", "sine", "joint"}
    terms : "auto", "all", "none" or sequence of str
        Distortion terms to fit (``"k1", "k2", "k3", "p1", "p2", "s1", "s2"`` or the
        Distortion field names).  ``"auto"`` (default) fits the terms the data support
        (the check always runs); ``"all"`` is seed 002's full Weng model, whose
        unsupported terms fit noise (see ``unsupported_fitted_terms``); ``"none"`` with
        ``"cosine"``/``"sine"`` is the seed's plain method.
    attitudes : bool
        ``"joint"`` only: fit per-star directions with a free attitude per frame (True)
        or the interstar angles (False).
    robust : bool, optional
        Huber loss.  Default: True for ``"joint"``; the seed's methods are plain least
        squares (False).
    check_terms : bool
        Run the term-support check (a few extra joint fits) for explicit ``terms``.
    max_cycles : int
        Two-step cycles before giving up (``solved=False``).
    in_space : bool
        The frames were taken above the atmosphere: frames without a site are accepted
        (:func:`check_reference_places`).

    Raises
    ------
    ShipstarError
        Bad arguments, frames of different cameras or sizes, centroids outside the image,
        ground frames without a site, too few stars for the parameters, or a degenerate
        star geometry.
    """
    from shipstar.calibrate._intrinsics_select import select_terms
    from shipstar.calibrate._intrinsics_solve import all_free

    if method not in METHODS:
        raise ShipstarError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    wanted, auto = _resolve_terms(terms)
    frames = _check_frames(frames, camera)
    check_reference_places(frames, in_space)
    robust = (method == "joint") if robust is None else bool(robust)
    free = all_free([TERM_FIELDS[t] for t in wanted])
    stars = _star_set(frames, len(free))
    start = camera.replace(distortion=type(camera.distortion)())
    _check_geometry(stars, start, free)
    selection = None
    if check_terms or auto:
        try:
            selection = select_terms(stars, start, candidates=wanted if auto else TERMS, robust=robust)
        except (ShipstarError, np.linalg.LinAlgError, FloatingPointError) as exc:
            if auto:
                return _unsolved(stars, camera, method, free, None,
                                 f"the check of the distortion terms failed: {exc}")
        if auto and selection is not None:
            wanted = selection.supported
    return _run(stars, camera, start, method, wanted, attitudes, robust, max_cycles, selection)


def _rms_rad(stars: StarSet, camera: Camera) -> float:
    return float(np.sqrt(np.mean(_angle_errors(stars, camera) ** 2)))


def _unsolved(stars, camera, method, free, selection, reason) -> IntrinsicCalibration:
    """A failed calibration: the input camera, NaN uncertainties, ``reason``."""
    rms = _rms_rad(stars, camera)
    before = residual_vectors_px(stars, camera)
    nan = float("nan")
    return IntrinsicCalibration(
        solved=False, reason=reason, method=method, camera=camera, fitted=free,
        sigma={n: nan for n in free}, correlation=np.full((len(free), len(free)), nan),
        centroid_sigma_px=nan, rms_before_rad=rms, rms_after_rad=rms,
        n_frames=stars.n_frames, n_stars=stars.n_stars, n_pairs=stars.n_pairs, iterations=0,
        supported_distortion_terms=selection.supported if selection else (),
        term_delta_chi2=dict(selection.delta_chi2) if selection else {},
        xy_px=stars.xy_px, residual_before_px=before, residual_after_px=before,
        frame_of_star=stars.star_frame, input_camera=camera, terms_checked=selection is not None)


def _run(stars, camera, start, method, wanted, attitudes, robust, max_cycles, selection):
    from shipstar.calibrate._intrinsics_lsq import covariance, linearize
    from shipstar.calibrate._intrinsics_solve import all_free, joint, two_step

    fields = [TERM_FIELDS[t] for t in wanted]
    free = all_free(fields)
    kind = ("star" if attitudes else "angle") if method == "joint" else method
    try:
        if method == "joint":
            out = joint(stars, start, fields, attitudes=attitudes, robust=robust)
        else:
            out = two_step(stars, start, method, fields, max_cycles=max_cycles)
        space = ParamSpace.for_camera(out.camera, free)
        lin = linearize(stars, space, space.values(out.camera), kind, attitudes=out.attitudes,
                        robust=robust)
        cov, sigma_px, _ = covariance(lin, space.scales)
    except (ShipstarError, np.linalg.LinAlgError, FloatingPointError) as exc:
        reason = f"the fit left the range of valid cameras: {exc}"
        return _unsolved(stars, camera, method, free, selection, reason)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    if not out.converged:
        what = "two-step iteration" if method != "joint" else "least squares"
        unit = "cycles" if method != "joint" else "iterations"
        return _unsolved(stars, camera, method, free, selection,
                         f"{what} did not converge in {out.iterations} {unit}")
    if not (np.isfinite(sd).all() and math.isfinite(sigma_px) and sd.all()):
        return _unsolved(stars, camera, method, free, selection,
                         "the parameter covariance is not finite (degenerate geometry)")
    corr = cov / np.outer(sd, sd)
    return IntrinsicCalibration(
        solved=True, reason="", method=method, camera=out.camera, fitted=free,
        sigma={n: float(x) for n, x in zip(free, sd)}, correlation=corr,
        centroid_sigma_px=sigma_px, rms_before_rad=_rms_rad(stars, camera),
        rms_after_rad=_rms_rad(stars, out.camera),
        n_frames=stars.n_frames, n_stars=stars.n_stars, n_pairs=stars.n_pairs,
        iterations=out.iterations,
        supported_distortion_terms=selection.supported if selection else (),
        term_delta_chi2=dict(selection.delta_chi2) if selection else {},
        xy_px=stars.xy_px, residual_before_px=residual_vectors_px(stars, camera),
        residual_after_px=residual_vectors_px(stars, out.camera), frame_of_star=stars.star_frame,
        input_camera=camera, terms_checked=selection is not None,
    )
